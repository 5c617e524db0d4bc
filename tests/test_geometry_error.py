"""The stated geometry error's draws (jaxocean.fit._geometry_error)."""

import math

import jax
import numpy as np
import pytest

from jaxocean.fit import _geometry_error as ge


def test_tilt_fields_have_unit_variance_and_the_stated_correlation():
    length = 4.0
    f = np.asarray(ge.tilt_fields(jax.random.PRNGKey(3), (64, 72), length, np.float32), np.float64)
    assert f.shape == (ge.GEOMETRY_SAMPLES, 2, 64, 72)
    assert f.var() == pytest.approx(1.0, rel=0.1)
    # correlation exp(-d^2 / (2 L^2)) at lags 2, 4 and 8 pixels, along both image axes
    for lag in (2, 4, 8):
        expected = math.exp(-lag**2 / (2 * length**2))
        along_x = np.mean(f[..., lag:] * f[..., :-lag]) / f.var()
        along_y = np.mean(f[..., lag:, :] * f[..., :-lag, :]) / f.var()
        assert along_x == pytest.approx(expected, abs=0.05)
        assert along_y == pytest.approx(expected, abs=0.05)
    # the two tangent axes are independent draws
    assert abs(np.mean(f[:, 0] * f[:, 1])) < 0.05


def test_uncorrelated_tilt_fields_are_white():
    f = np.asarray(ge.tilt_fields(jax.random.PRNGKey(0), (32, 32), 0.0, np.float32), np.float64)
    assert f.shape == (ge.GEOMETRY_SAMPLES, 2, 32, 32)
    assert abs(np.mean(f[..., 1:] * f[..., :-1])) < 0.03


def test_normal_noise_map_shapes_and_errors():
    assert ge.normal_noise_map(None, (4, 5), np.float32).shape == (4, 5)
    assert np.all(np.asarray(ge.normal_noise_map(0.1, (4, 5), np.float32)) == np.float32(0.1))
    with pytest.raises(ValueError, match="a number or an"):
        ge.normal_noise_map(np.ones((3, 3)), (4, 5), np.float32)
    with pytest.raises(Exception, match="finite and >= 0"):
        ge.normal_noise_map(-1.0, (4, 5), np.float32)
