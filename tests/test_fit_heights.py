"""jaxocean.fit.heights: perspective normal integration against the renderer's own hits."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxocean import camera as cam
from jaxocean import fit, render
from jaxocean.waves import make_waves

SWELL = make_waves([0.12, 0.05, 0.03], [1.3, 2.0, 2.6], [0.2, 1.4, -0.8], [0.0, 1.0, 2.0])  # 36, 15, 9 m


def _view(res=48):
    return cam.make_camera(height=10.0, pitch=0.9, fov=0.8, resolution=(res, res))


def _level_free(z, valid, gauge):
    """Heights with the weighted mean ``gauge`` removed over ``valid`` pixels."""
    w = np.where(valid, gauge, 0.0)
    return z - np.sum(w * z) / np.sum(w)


def test_heights_are_the_surface_at_each_hit_up_to_the_level():
    camera = _view()
    g = render.geometry(SWELL, camera, 0.7)  # converged hits on the displaced surface
    hm = fit.heights(g.normal, camera)
    valid = np.asarray(hm.valid)
    assert valid.sum() > 0.9 * np.asarray(g.mask).sum() and bool(hm.converged)
    gauge = 1.0 / np.asarray(cam.intersect_sea(camera).footprint) ** 2
    true = np.asarray(g.position)[..., 2]
    err = _level_free(np.asarray(hm.z), valid, gauge) - _level_free(true, valid, gauge)
    # the swell is 0.4 m high: heights to a few millimetres (trapezoid rule between hits)
    assert np.sqrt(np.mean(err[valid] ** 2)) < 0.01 * np.ptp(true[valid])
    # the level the normals cannot give is the only thing between the hits and the truth:
    # with it, the hits are much closer than the plane hits
    level = np.sum(np.where(valid, gauge, 0) * (true - np.asarray(hm.z))) / np.sum(np.where(valid, gauge, 0))
    _, d = cam.pixel_rays(camera)
    q = np.asarray(d)[..., :2] / np.asarray(d)[..., 2:3]
    hits = np.asarray(hm.xy) + level * q
    plane = np.asarray(cam.intersect_sea(camera).xy)
    true_xy = np.asarray(g.position)[..., :2]
    e_int = np.linalg.norm(hits - true_xy, axis=-1)[valid]
    e_plane = np.linalg.norm(plane - true_xy, axis=-1)[valid]
    assert np.sqrt(np.mean(e_int ** 2)) < 0.05 * np.sqrt(np.mean(e_plane ** 2))


def test_a_flat_sea_has_zero_height_and_plane_hits():
    camera = _view(16)
    up = jnp.zeros((16, 16, 3)).at[..., 2].set(1.0)
    hm = fit.heights(up, camera)
    sea = np.asarray(cam.intersect_sea(camera).mask)
    np.testing.assert_allclose(np.asarray(hm.z), 0.0, atol=1e-7)
    np.testing.assert_allclose(np.asarray(hm.xy)[sea], np.asarray(cam.intersect_sea(camera).xy)[sea], atol=1e-6)
    assert float(hm.residual) < 1e-7


@pytest.mark.slow  # height integration compiled eager and jitted
def test_frames_are_mapped_and_jit_gives_the_eager_value():
    camera = _view(24)
    normals = jnp.stack([render.geometry(SWELL, camera, t).normal for t in (0.0, 0.4)])
    both = fit.heights(normals, camera)
    assert both.z.shape == (2, 24, 24) and both.xy.shape == (2, 24, 24, 2) and both.converged.shape == (2,)
    one = fit.heights(normals[1], camera)
    np.testing.assert_allclose(np.asarray(both.z[1]), np.asarray(one.z), atol=1e-6)
    jitted = jax.jit(lambda n: fit.heights(n, camera).z)(normals)
    np.testing.assert_allclose(np.asarray(jitted), np.asarray(both.z), atol=1e-6)


def test_invalid_pixels_are_left_out():
    camera = _view(24)
    n = np.array(render.geometry(SWELL, camera, 0.0).normal)
    n[10:12, 5:9] = np.nan
    hm = fit.heights(jnp.asarray(n), camera)
    assert not np.asarray(hm.valid)[10:12, 5:9].any()
    assert np.all(np.asarray(hm.z)[10:12, 5:9] == 0.0) and np.all(np.isfinite(np.asarray(hm.z)))


def test_nothing_to_integrate_is_not_converged():
    camera = _view(16)
    hm = fit.heights(jnp.full((16, 16, 3), jnp.nan), camera)
    assert not np.asarray(hm.valid).any() and not bool(hm.converged)


def test_bad_inputs_say_what_is_wrong():
    camera = _view(16)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 16, 16, 3\)"):
        fit.heights(jnp.zeros((16, 15, 3)), camera)
    with pytest.raises(ValueError, match="floating point"):
        fit.heights(jnp.zeros((16, 16, 3), jnp.int32), camera)
    with pytest.raises(ValueError, match="tol must be > 0"):
        fit.heights(jnp.zeros((16, 16, 3)), camera, tol=0.0)
