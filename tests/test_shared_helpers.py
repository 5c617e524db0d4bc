"""The small modules several others use: jaxocean.files (atomic writes, strict JSON),
jaxocean._roughness (per-row roughness), _math.angle_between, camera.camera_to_dict."""

from __future__ import annotations

import json
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxocean import _roughness, camera, hierarchy, surface
from jaxocean._math import angle_between
from jaxocean.files import json_safe, write_json
from jaxocean.io import scene as scene_io
from jaxocean.waves import make_waves, wavenumber


def test_json_safe_turns_non_finite_numbers_into_null_and_arrays_into_lists():
    data = {"a": math.nan, "b": [1.0, math.inf, (2, -math.inf)], "c": np.array([1.5, np.nan]),
            "d": jnp.float32(2.5), "e": np.int64(3), "f": "text", "g": None, "h": True}
    out = json_safe(data)
    assert out == {"a": None, "b": [1.0, None, [2, None]], "c": [1.5, None], "d": 2.5, "e": 3, "f": "text",
                   "g": None, "h": True}
    json.dumps(out, allow_nan=False)  # strict JSON


def test_write_json_is_strict_and_replaces_atomically(tmp_path):
    path = tmp_path / "sub" / "out.json"
    write_json(path, {"loss": math.nan, "x": [1.0]})
    assert path.read_text().endswith("\n") and json.loads(path.read_text()) == {"loss": None, "x": [1.0]}
    with pytest.raises(TypeError):
        write_json(path, {"bad": object()})
    assert json.loads(path.read_text()) == {"loss": None, "x": [1.0]}  # the old file is intact
    assert sorted(p.name for p in path.parent.iterdir()) == ["out.json"]  # no temporary left


def test_row_roughness_equals_the_surface_slope_variance_under_hierarchy_weights():
    waves = make_waves([0.01, 0.02, 0.005, 0.03], [6.0, 3.0, 9.0, 2.0], [0.1, 1.0, -2.0, 0.5])
    footprint = jnp.array([0.2, 0.5, 1.0, 3.0, 10.0])
    rows = _roughness.row_roughness(wavenumber(waves), waves.amplitude, footprint, 1.0, 1.5)
    sx2, sy2 = surface.slope_variance(waves, hierarchy.weights(waves, footprint))
    np.testing.assert_allclose(rows, sx2 + sy2, rtol=1e-6)
    # a wave far below the footprint adds 1 - sqrt(1 - k^2 h^2) in full
    kh = float(wavenumber(waves)[2] * 0.005)
    assert float(_roughness.wave_slope_variance(jnp.asarray(kh * kh))) == pytest.approx(1 - math.sqrt(1 - kh * kh),
                                                                                          rel=1e-6)


def test_angle_between_matches_arccos_and_has_a_finite_gradient_at_zero():
    jax.config.update("jax_enable_x64", True)
    try:
        rng = np.random.default_rng(0)
        a = rng.normal(size=(20, 3))
        b = rng.normal(size=(20, 3))
        a /= np.linalg.norm(a, axis=-1, keepdims=True)
        b /= np.linalg.norm(b, axis=-1, keepdims=True)
        np.testing.assert_allclose(angle_between(jnp.asarray(a), jnp.asarray(b)),
                                   np.arccos(np.clip(np.sum(a * b, -1), -1, 1)), rtol=1e-9)
        n = jnp.asarray([0.0, 0.6, 0.8])
        assert float(angle_between(n, n)) < 1e-15  # n x n is zero up to a fused multiply-add's rounding
        g = jax.grad(lambda x: angle_between(x, n))(n)
        assert bool(jnp.all(jnp.isfinite(g)))
        tilt = 1e-4  # small angles: exact where arccos of the dot product loses half the digits
        m = jnp.asarray([0.0, math.sin(tilt), math.cos(tilt)])
        assert float(angle_between(m, jnp.asarray([0.0, 0.0, 1.0]))) == pytest.approx(tilt, rel=1e-10)
    finally:
        jax.config.update("jax_enable_x64", False)


def test_camera_to_dict_is_what_scene_json_stores_and_adds_degrees_on_request():
    cam = camera.make_camera(height=7.0, pitch=0.4, fov=0.9, yaw=0.2, resolution=(12, 16))
    d = camera.camera_to_dict(cam)
    assert d["resolution"] == [12, 16] and d["projection"] == "perspective" and "pitch_deg" not in d
    assert scene_io.scene_to_dict(camera=cam)["camera"] == d
    back = scene_io.scene_from_dict(scene_io.scene_to_dict(camera=cam)).camera
    assert back.resolution == cam.resolution and float(back.pitch) == pytest.approx(0.4)
    deg = camera.camera_to_dict(cam, degrees=True)
    assert deg["pitch_deg"] == pytest.approx(math.degrees(float(cam.pitch)))
    assert deg["fov_deg"] == pytest.approx(math.degrees(float(cam.fov)))


def test_slope_and_normal_are_inverse_maps():
    from jaxocean._math import normal_from_slope, slope_from_normal

    slope = jnp.asarray([[0.0, 0.0], [0.3, -0.2], [-2.0, 5.0]])
    normal = normal_from_slope(slope)
    np.testing.assert_allclose(jnp.linalg.norm(normal, axis=-1), 1.0, rtol=1e-6)
    np.testing.assert_allclose(normal[0], [0.0, 0.0, 1.0])
    np.testing.assert_allclose(slope_from_normal(normal, 1e-3), slope, rtol=1e-5, atol=1e-6)
    # a vertical facet: the floor bounds the slope
    np.testing.assert_allclose(slope_from_normal(jnp.asarray([1.0, 0.0, 0.0]), 0.05), [-20.0, 0.0])


def test_fits_half_is_the_half_float_range():
    from jaxocean.io.sequence import HALF_MAX, fits_half

    assert fits_half(np.full((2, 2), -65503.0)) and not fits_half(np.asarray([0.0, HALF_MAX]))
    assert not fits_half(np.asarray([1.0, np.nan])) and not fits_half(np.asarray([np.inf]))


def test_sea_median_ignores_the_sky_and_falls_back_to_one():
    from jaxocean._sea_scale import compress, sea_median

    image = jnp.stack([jnp.full((4, 4), 0.2), jnp.full((4, 4), 0.05), jnp.zeros((4, 4))], -1).at[0].set(9.0)
    mask = jnp.ones((4, 4), bool).at[0].set(False)  # row 0: sky, brighter than the sea
    np.testing.assert_allclose(sea_median(image, mask), [0.2, 0.05, 1.0])  # no positive median: 1
    np.testing.assert_allclose(sea_median(image, jnp.zeros((4, 4), bool)), [1.0, 1.0, 1.0])
    np.testing.assert_allclose(compress(image[1, 1], sea_median(image, mask)), [math.log(2.0)] * 2 + [0.0], rtol=1e-6)
