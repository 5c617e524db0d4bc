import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxocean import hierarchy
from jaxocean.errors import InvalidValueError
from jaxocean.waves import make_waves, wavelength


def _waves_with_wavelengths(lams, dtype=None):
    omega = np.sqrt(2 * np.pi * 9.81 / np.asarray(lams))
    return make_waves(np.full(len(lams), 0.01), omega, np.zeros(len(lams)), dtype=dtype)


def test_filter_levels_follow_wavelength_over_footprint():
    waves = _waves_with_wavelengths([0.5, 1.0, 1.25, 1.5, 3.0])
    w = hierarchy.weights(waves, 1.0)
    # lambda/fp = 0.5 -> roughness, 1.5 and above -> normal, midpoint 1.25 -> smoothstep(0.5) = 0.5
    np.testing.assert_allclose(w.normal, [0.0, 0.0, 0.5, 1.0, 1.0], atol=2e-5)
    np.testing.assert_allclose(w.roughness, 1.0 - np.asarray(w.normal), atol=1e-7)
    np.testing.assert_allclose(w.displacement, w.normal)


def test_grid_cell_sets_displacement_level_and_shapes_broadcast():
    waves = _waves_with_wavelengths([0.5, 2.0, 8.0])
    footprint = jnp.array([[0.25, 1.0], [4.0, 100.0]])
    w = hierarchy.weights(waves, footprint, grid_cell=4.0)
    assert w.normal.shape == (2, 2, 3)
    np.testing.assert_allclose(w.displacement[0, 0], [0.0, 0.0, 1.0], atol=1e-6)  # only 8 m >= 1.5 cells
    np.testing.assert_allclose(w.normal[0, 0], [1.0, 1.0, 1.0], atol=1e-6)
    np.testing.assert_allclose(w.normal[1, 1], [0.0, 0.0, 0.0], atol=1e-6)


def test_all_resolved_and_bad_input():
    waves = _waves_with_wavelengths([1.0, 2.0])
    w = hierarchy.all_resolved(waves)
    np.testing.assert_array_equal(w.normal, [1, 1])
    np.testing.assert_array_equal(w.roughness, [0, 0])
    with pytest.raises(InvalidValueError, match=r"footprint must be > 0.*-1\.0"):
        hierarchy.weights(waves, jnp.array([1.0, -1.0]))
    with pytest.raises(ValueError, match="n_max > n_min"):
        hierarchy.weights(waves, 1.0, n_min=2.0, n_max=1.0)


@pytest.mark.parametrize("n_min", [0.0, -1.0, float("nan")])
def test_nonpositive_n_min_is_rejected(n_min):
    # n_min <= 0 gave a wave a tenth of a footprint long a share of the normal (aliasing)
    waves = _waves_with_wavelengths([0.1, 1.0])
    with pytest.raises(ValueError, match="n_min must be a finite number of footprints > 0"):
        hierarchy.weights(waves, 1.0, n_min=n_min, n_max=1.5)


def test_infinite_n_max_is_rejected():
    waves = _waves_with_wavelengths([1.0, 2.0])
    with pytest.raises(ValueError, match="finite n_max > n_min"):
        hierarchy.weights(waves, 1.0, n_max=float("inf"))


@pytest.mark.parametrize("omega", [0.0, float("nan")])
def test_invalid_waves_are_rejected(omega):
    # a NaN frequency gave NaN weights and omega = 0 (an infinite wavelength) a wave resolved
    # by every pixel, without a word
    waves = _waves_with_wavelengths([1.0, 2.0])
    with pytest.raises(InvalidValueError, match="Waves.omega must be"):
        hierarchy.weights(waves._replace(omega=waves.omega.at[1].set(omega)), 1.0)


@pytest.mark.parametrize("grid_cell", [0.0, -1.0, float("nan")])
def test_nonpositive_or_nan_grid_cell_is_rejected(grid_cell):
    # a grid cell <= 0 or NaN sent every wave to (or out of) the displacement silently
    waves = _waves_with_wavelengths([1.0, 2.0])
    with pytest.raises(InvalidValueError, match="grid_cell must be > 0"):
        hierarchy.weights(waves, 1.0, grid_cell=grid_cell)


def test_weight_gradients_match_finite_differences(x64):
    waves = _waves_with_wavelengths([1.1, 1.3, 1.45])  # inside the transition band

    def f(amp, omega, footprint):
        w = make_waves(amp, omega, jnp.zeros_like(omega))
        ws = hierarchy.weights(w, footprint, grid_cell=footprint * 0.9)
        return ws.normal, ws.roughness, ws.displacement

    check_grads(f, (waves.amplitude, waves.omega, jnp.array(1.0)), order=1, modes=("fwd", "rev"),
                eps=1e-6, atol=1e-6, rtol=1e-6)


@given(ratio=st.floats(0.5, 2.0), footprint=st.floats(1e-3, 1e3))
def test_weights_finite_with_finite_gradients_at_filter_edges(ratio, footprint):
    # ratios 1.0 and 1.5 are the smoothstep edges: the derivative is continuous (zero) there
    lam = ratio * footprint
    omega = jnp.sqrt(2 * jnp.pi * 9.81 / jnp.array([lam, 1.0 * footprint, 1.5 * footprint]))

    def total(omega, fp):
        w = make_waves(jnp.zeros(3), omega, jnp.zeros(3))
        return jnp.sum(hierarchy.weights(w, fp).normal)

    val, grads = jax.value_and_grad(total, argnums=(0, 1))(omega, jnp.asarray(footprint, jnp.float32))
    assert np.isfinite(val)
    assert all(np.all(np.isfinite(g)) for g in grads)
    assert 0.0 <= float(val) <= 3.0 + 1e-6
    w = make_waves(jnp.zeros(3), omega, jnp.zeros(3))
    # the waves built here have the wavelengths the edges need (k = omega^2 / g)
    np.testing.assert_allclose(np.asarray(wavelength(w)), [lam, footprint, 1.5 * footprint], rtol=1e-5)
