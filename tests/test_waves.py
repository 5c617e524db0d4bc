import jax.numpy as jnp
import numpy as np
import pytest

from jaxocean.errors import InvalidValueError
from jaxocean.waves import (GRAVITY, Waves, make_waves, period, steepness, total_steepness, validate,
                            wave_vector, wavelength, wavenumber)


def test_deep_water_dispersion_reference_values():
    # a 10 s swell: k = (2 pi / 10)^2 / g = 0.04024 rad/m, wavelength 156.1 m (g T^2 / 2 pi)
    omega = 2 * np.pi / 10.0
    np.testing.assert_allclose(wavenumber(omega), 0.0402430, rtol=1e-5)
    np.testing.assert_allclose(wavelength(omega), GRAVITY * 100 / (2 * np.pi), rtol=1e-5)
    np.testing.assert_allclose(period(omega), 10.0, rtol=1e-6)


def test_wave_vector_and_steepness():
    w = make_waves([0.5, 0.1], [1.0, 2.0], [0.0, np.pi / 2])
    kv = np.asarray(wave_vector(w))
    np.testing.assert_allclose(kv[0], [1 / GRAVITY, 0.0], atol=1e-7)
    np.testing.assert_allclose(kv[1], [0.0, 4 / GRAVITY], atol=1e-6)
    np.testing.assert_allclose(steepness(w), [0.5 / GRAVITY, 0.4 / GRAVITY], rtol=1e-6)
    np.testing.assert_allclose(total_steepness(w), 0.9 / GRAVITY, rtol=1e-6)
    np.testing.assert_array_equal(w.phase, [0.0, 0.0])



def test_make_waves_broadcasts_the_phase():
    # the docstring promises it; a scalar phase was a "leaves must share one shape" error
    w = make_waves([0.5, 0.1], [1.0, 2.0], [0.0, 1.0], 0.25)
    np.testing.assert_array_equal(w.phase, [0.25, 0.25])
    assert w.phase.dtype == w.amplitude.dtype


@pytest.mark.parametrize(
    "kwargs, match",
    [
        (dict(amplitude=[0.1, -0.2], omega=[1.0, 1.0], theta=[0, 0]), r"amplitude must be >= 0.*-0\.2"),
        (dict(amplitude=[0.1, 0.2], omega=[1.0, 0.0], theta=[0, 0]), r"omega must be > 0.*0\.0"),
        (dict(amplitude=[0.1, 0.2], omega=[1.0, -1.0], theta=[0, 0]), r"omega must be > 0.*-1\.0"),
        (dict(amplitude=[0.1, np.nan], omega=[1.0, 1.0], theta=[0, 0]), r"amplitude must be finite.*nan"),
        (dict(amplitude=[0.1, 0.2], omega=[1.0, 1.0], theta=[0, np.inf]), r"theta must be finite.*inf"),
        (dict(amplitude=[20.0], omega=[1.0], theta=[0]), r"steepness k\*h must be <= 1"),
    ],
)
def test_bad_values_are_named(kwargs, match):
    with pytest.raises(InvalidValueError, match=match):
        make_waves(**kwargs)


def test_structural_errors():
    with pytest.raises(ValueError, match="share one shape"):
        validate(Waves(jnp.ones(3), jnp.ones(2), jnp.ones(3), jnp.ones(3)))
    with pytest.raises(ValueError, match="trailing wave axis"):
        validate(Waves(*(jnp.asarray(1.0),) * 4))
    with pytest.raises(ValueError, match="floating point"):
        validate(Waves(jnp.ones(2, int), jnp.ones(2), jnp.ones(2), jnp.ones(2)))
    with pytest.raises(ValueError, match="expected a jaxocean.Waves"):
        validate((1.0, 2.0))


def test_make_waves_accepts_integer_array_likes_as_the_default_float():
    waves = make_waves([1], [2], [0], [3])
    assert all(jnp.issubdtype(leaf.dtype, jnp.floating) for leaf in waves)
    np.testing.assert_array_equal(waves.omega, [2.0])
    with pytest.raises(ValueError, match="floating point"):  # an explicit integer dtype is still refused
        make_waves([1], [2], [0], dtype=jnp.int32)
