import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxocean import camera as cam
from jaxocean import hierarchy, render, shading, surface
from jaxocean.errors import InvalidValueError
from jaxocean.waves import GRAVITY, Waves, make_waves


def sea(n=8, seed=0, max_kh=0.25, omega=(0.8, 3.0), dtype=np.float32):
    rng = np.random.default_rng(seed)
    om = rng.uniform(*omega, n)
    amp = rng.uniform(0.2, 1.0, n) * max_kh / n * GRAVITY / om**2
    return make_waves(amp.astype(dtype), om.astype(dtype), rng.uniform(-np.pi, np.pi, n).astype(dtype),
                      rng.uniform(0, 2 * np.pi, n).astype(dtype))


def lighting(dtype=np.float32, **kw):
    return shading.make_lighting(**kw)


CAM = dict(height=8.0, pitch=0.3, fov=0.7, resolution=(12, 16))  # horizon inside the image


def test_shade_of_geometry_equals_render():
    waves, c, light = sea(), cam.make_camera(**CAM), lighting()
    geo = render.geometry(waves, c, 1.3)
    img = render.render(waves, c, light, 1.3)
    np.testing.assert_allclose(img, render.shade(geo.normal, geo.roughness, c, light,
                                                 slope_variance=geo.slope_variance), rtol=1e-6)
    assert img.shape == (12, 16, 3) and np.all(np.isfinite(img)) and np.all(np.asarray(img) >= 0)


def test_rows_path_equals_per_pixel_evaluation():
    waves, c = sea(20, seed=1, omega=(0.8, 6.0)), cam.make_camera(**CAM)
    geo = render.geometry(waves, c, 0.7, plan=None)
    hit = cam.intersect_sea(c)
    ws = hierarchy.weights(waves, hit.footprint)
    mask = np.asarray(hit.mask)
    np.testing.assert_allclose(np.asarray(geo.normal)[mask], np.asarray(surface.normal(waves, hit.xy, 0.7, ws))[mask],
                               atol=2e-5)
    sx2, sy2 = surface.slope_variance(waves, ws)
    rough = np.maximum(np.asarray(sx2 + sy2), shading.MIN_SLOPE_VARIANCE)
    np.testing.assert_allclose(np.asarray(geo.roughness)[mask], rough[mask], rtol=1e-4)
    # the footprint really is constant along rows (what the rows path relies on)
    fp = np.asarray(hit.footprint)[mask.all(axis=1)]
    np.testing.assert_allclose(fp, fp[:, :1].repeat(fp.shape[1], 1), rtol=1e-4)


def test_flat_sea_with_sun_off_is_fresnel_blend_of_sky_and_sea():
    waves = make_waves(np.zeros(2), [1.0, 2.0], [0.0, 1.0])
    c = cam.make_camera(**CAM)
    light = lighting(sun_color=(0.0, 0.0, 0.0))
    img = np.asarray(render.render(waves, c, light, 0.0))
    hit = cam.intersect_sea(c)
    cos_v = np.asarray(hit.view)[..., 2]
    # a flat sea clamps each axis to MIN_SLOPE_VARIANCE_AXIS; shading.mean_fresnel is checked
    # against an independent scalar transcription in test_shading
    f_mean = np.asarray(shading.mean_fresnel(cos_v, shading.MIN_SLOPE_VARIANCE_AXIS))
    expect = f_mean[..., None] * np.asarray(light.sky_color) + (1 - f_mean[..., None]) * np.asarray(light.sea_color)
    mask = np.asarray(hit.mask)
    np.testing.assert_allclose(img[mask], expect[mask], rtol=1e-4)
    np.testing.assert_allclose(img[~mask], np.broadcast_to(light.sky_color, img[~mask].shape), rtol=1e-6)
    assert (~mask).any() and mask.any()  # the horizon is inside this image


@pytest.mark.slow  # a fine reference render
def test_subpixel_waves_render_as_brdf_of_flat_normal_and_their_slope_variance():
    # wavelengths of a few cm, seen from 30 m: every wave is sub-pixel
    waves = sea(10, seed=2, omega=(25.0, 40.0), max_kh=0.4)
    c = cam.make_camera(height=30.0, pitch=0.9, fov=0.5, resolution=(8, 8))
    light = lighting()
    geo = render.geometry(waves, c, 0.4)
    np.testing.assert_allclose(geo.normal, np.broadcast_to([0.0, 0.0, 1.0], geo.normal.shape), atol=1e-6)
    sx2, sy2 = surface.slope_variance(waves)
    np.testing.assert_allclose(geo.slope_variance[..., 0], np.full((8, 8), sx2), rtol=1e-5)
    hit = cam.intersect_sea(c)
    flat = jnp.broadcast_to(jnp.array([0.0, 0.0, 1.0]), (8, 8, 3))
    expect = shading.shade_pixel(flat, sx2, sy2, hit.view, light)
    np.testing.assert_allclose(render.render(waves, c, light, 0.4), expect, rtol=1e-5)
    assert render.plan(waves, c).active == ()  # no wave needs a sine


def test_glitter_is_where_the_sun_reflects_and_moves_with_the_sun():
    waves = sea(12, seed=3, omega=(4.0, 12.0), max_kh=0.15)
    c = cam.make_camera(height=20.0, pitch=0.6, fov=0.8, yaw=0.0, resolution=(40, 40))
    hit = cam.intersect_sea(c)

    def glitter_centre(elevation):
        light = lighting(sun_azimuth=0.0, sun_elevation=elevation)  # sun straight ahead
        img = np.asarray(render.render(waves, c, light, 0.0)).sum(-1)
        img[~np.asarray(hit.mask)] = 0
        w = img / img.sum()
        return (w * np.arange(40)[:, None]).sum(), img

    row_high, img_high = glitter_centre(0.6)
    row_low, _ = glitter_centre(0.3)
    # a low sun reflects closer to the horizon (smaller row index)
    assert row_low < row_high - 2
    # brightest pixels lie near the mirror row of the sun: where the view elevation equals the sun's
    elev = -np.arcsin(np.asarray(hit.direction)[..., 2])
    mirror_row = np.argmin(np.abs(elev[:, 20] - 0.6))
    assert abs(np.unravel_index(np.argmax(img_high), img_high.shape)[0] - mirror_row) <= 6


def test_plan_chooses_the_path_by_the_traceable_rule():
    # plan()'s host-side choice is needs_refinement(), the rule applied under tracing
    close = (sea(6, seed=4, omega=(0.6, 1.5), max_kh=0.3), cam.make_camera(height=6.0, pitch=1.1, fov=0.6,
                                                                            resolution=(10, 10)))
    far = (sea(6, seed=4, omega=(0.6, 1.5), max_kh=0.01), cam.make_camera(height=200.0, pitch=0.7, fov=0.4,
                                                                             resolution=(10, 10)))
    for (waves, c), needed in ((close, True), (far, False)):
        assert bool(render.needs_refinement(waves, c)) is needed
        assert bool(jax.jit(render.needs_refinement)(waves, c)) is needed
        assert render.plan(waves, c).refine == (render.MAX_REFINE_ITERATIONS if needed else 0)


def test_refinement_puts_the_hit_on_the_displaced_surface(x64):
    waves = sea(6, seed=4, omega=(0.6, 1.5), max_kh=0.3, dtype=np.float64)
    c = cam.make_camera(height=6.0, pitch=1.1, fov=0.6, resolution=(10, 10), dtype=np.float64)
    p = render.plan(waves, c, 0.8)
    assert p.refine > 0  # a close view: metre-high waves shift the hit by many pixels
    geo = render.geometry(waves, c, 0.8, plan=p)
    assert np.asarray(geo.converged).all()
    origin, direction = cam.pixel_rays(c)
    # distance of the surface point from its pixel ray
    rel = np.asarray(geo.position) - np.asarray(origin)
    along = (rel * np.asarray(direction)).sum(-1, keepdims=True)
    miss = np.linalg.norm(rel - along * np.asarray(direction), axis=-1)
    assert miss.max() <= 1e-7  # the Newton loop stops at a 1e-4 m step: the hit is exact to ~its square
    unrefined = render.geometry(waves, c, 0.8, plan=p._replace(refine=0))
    rel0 = np.asarray(unrefined.position) - np.asarray(origin)
    miss0 = np.linalg.norm(rel0 - (rel0 * np.asarray(direction)).sum(-1, keepdims=True) * np.asarray(direction), axis=-1)
    assert miss0.max() > 100 * miss.max()


def test_far_view_needs_no_refinement_and_skips_subpixel_waves():
    rng = np.random.default_rng(5)
    om = np.concatenate([rng.uniform(0.5, 1.0, 4), rng.uniform(20, 30, 6)])  # long swell + capillary ripples
    waves = make_waves(0.02 * GRAVITY / om**2, om, rng.uniform(-3, 3, 10))
    c = cam.make_camera(height=200.0, pitch=0.7, fov=0.4, resolution=(16, 16))
    p = render.plan(waves, c)
    assert p.refine == 0
    assert p.active == (0, 1, 2, 3)
    full = render.geometry(waves, c, 2.0, plan=None)
    skipped = render.geometry(waves, c, 2.0, plan=p)
    np.testing.assert_allclose(skipped.normal, full.normal, atol=1e-6)
    np.testing.assert_allclose(skipped.roughness, full.roughness, rtol=1e-6)


@pytest.mark.slow  # compiles batched renders
def test_vmap_over_frames_and_scenes():
    waves, c, light = sea(), cam.make_camera(**CAM), lighting()
    times = jnp.array([0.0, 0.5, 1.0])
    frames = jax.vmap(lambda t: render.render(waves, c, light, t))(times)
    # plan="auto" under vmap makes the eager call's choice (this view needs the hits path)
    assert render.plan(waves, c).refine > 0
    for i, t in enumerate(times):
        np.testing.assert_allclose(frames[i], render.render(waves, c, light, t), rtol=1e-5, atol=1e-6)
    batch = jax.tree.map(lambda *a: jnp.stack(a), sea(seed=1), sea(seed=2))
    imgs = jax.vmap(lambda w: render.render(w, c, light, 0.3))(batch)
    np.testing.assert_allclose(imgs[1], render.render(sea(seed=2), c, light, 0.3), rtol=1e-5, atol=1e-6)


# ------------------------------------------------------------------ gradients (x64)

def _grad_setup():
    waves = sea(4, seed=6, omega=(1.0, 4.0), dtype=np.float64)
    c = cam.make_camera(height=5.0, pitch=0.2, fov=0.6, resolution=(6, 8), dtype=np.float64)
    light = shading.make_lighting(sun_azimuth=0.2, sun_elevation=0.5)
    light = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), light)
    return waves, c, light


@pytest.mark.slow  # float64 finite differences through render
def test_render_gradients_wrt_waves_lighting_and_camera(x64):
    waves, c, light = _grad_setup()
    assert (~np.asarray(cam.intersect_sea(c).mask)).any()  # horizon inside the image

    def by_waves(amp, omega, theta, phase):
        return render.render(Waves(amp, omega, theta, phase), c, light, 0.6, plan=None)

    check_grads(jax.jit(by_waves), tuple(waves), order=1, modes=("rev",), eps=1e-6, atol=1e-4, rtol=1e-4)

    def by_light(az, el, sun, sky, sea_color):
        return render.render(waves, c, shading.Lighting(az, el, sun, sky, sea_color), 0.6, plan=None)

    check_grads(jax.jit(by_light), tuple(light), order=1, modes=("rev",), eps=1e-6, atol=1e-4, rtol=1e-4)

    def by_camera(height, pitch):
        cc = cam.make_camera(height=height, pitch=pitch, fov=0.6, resolution=(6, 8), dtype=np.float64)
        return render.render(waves, cc, light, 0.6, plan=None)

    check_grads(jax.jit(by_camera), (jnp.float64(5.0), jnp.float64(0.2)), order=1, modes=("rev",), eps=1e-7,
                atol=1e-4, rtol=1e-4)


def test_shade_gradients_wrt_normal_and_roughness(x64):
    waves, c, light = _grad_setup()
    geo = render.geometry(waves, c, 0.2, plan=None)

    def f(normal, roughness):
        return render.shade(normal, roughness, c, light)

    check_grads(jax.jit(f), (geo.normal, geo.roughness + 1e-3), order=1, modes=("fwd", "rev"), eps=1e-7, atol=1e-4,
                rtol=1e-4)


_FINITE_WAVES = sea(4, seed=7)


@jax.jit
@functools.partial(jax.value_and_grad, argnums=(0, 1, 2, 3, 4))
def _tonemapped_total(amplitude, sun_color, elevation, height, pitch):
    c = cam.make_camera(height=height, pitch=pitch, fov=0.9, resolution=(6, 6))
    light = shading.make_lighting()._replace(sun_color=sun_color, sun_elevation=elevation)
    img = render.render(_FINITE_WAVES._replace(amplitude=amplitude), c, light, 0.3, plan=None)
    return jnp.sum(shading.tonemap(img))


@given(elevation=st.floats(-0.05, 1.5), pitch=st.floats(-0.2, 1.5), amp_scale=st.sampled_from([0.0, 1.0]),
       height=st.floats(0.5, 50.0))
def test_values_and_gradients_finite_everywhere(elevation, pitch, amp_scale, height):
    # amp_scale 0: a flat sea, roughness at its clamp; pitch < 0 and elevation < 0: the horizon
    # in the image and the sun below it
    val, grads = _tonemapped_total(_FINITE_WAVES.amplitude * amp_scale, shading.make_lighting().sun_color,
                                   jnp.float32(elevation), jnp.float32(height), jnp.float32(pitch))
    assert np.isfinite(val)
    assert all(np.all(np.isfinite(g)) for g in grads)


def test_bad_inputs_raise_before_work():
    waves, c, light = sea(), cam.make_camera(**CAM), lighting()
    with pytest.raises(InvalidValueError, match="under the sea"):
        render.render(waves, cam.make_camera(**{**CAM, "height": -1.0}), light, 0.0)
    with pytest.raises(InvalidValueError, match="fov"):
        render.render(waves, cam.make_camera(**{**CAM, "fov": 0.0}), light, 0.0)
    with pytest.raises(InvalidValueError, match="sun_color"):
        render.render(waves, c, lighting(sun_color=(1.0, -1.0, 1.0)), 0.0)
    normal = jnp.zeros((12, 16, 3)).at[..., 2].set(1.0)
    with pytest.raises(InvalidValueError, match="normal contains 1 NaN"):
        render.shade(normal.at[3, 4, 0].set(jnp.nan), jnp.full((12, 16), 1e-3), c, light)
    with pytest.raises(ValueError, match=r"normal must be \(H, W, 3\)"):
        render.shade(normal[:5], jnp.full((12, 16), 1e-3), c, light)
    with pytest.raises(ValueError, match=r"roughness must be \(H, W\)"):
        render.shade(normal, jnp.full((16, 12), 1e-3), c, light)
    with pytest.raises(ValueError, match="plan must be"):
        render.geometry(waves, c, 0.0, plan="fast")
    # a NaN grid cell gave NaN positions, a negative one dropped the displacement, silently
    for grid_cell in (float("nan"), -1.0, 0.0):
        with pytest.raises(InvalidValueError, match="grid_cell must be > 0"):
            render.geometry(waves, c, 0.0, grid_cell=grid_cell)
        with pytest.raises(InvalidValueError, match="grid_cell must be > 0"):
            render.render(waves, c, light, 0.0, grid_cell=grid_cell, plan=None)
    no_waves = jax.tree.map(lambda x: x[:0], waves)
    with pytest.raises(ValueError, match="at least one wave; a flat sea is one wave of zero amplitude"):
        render.render(no_waves, c, light, 0.0)
    with pytest.raises(ValueError, match="shade needs roughness"):
        render.shade(normal, None, c, light)
    # a negative variance is no surface (it was clamped to the floor without a word)
    with pytest.raises(InvalidValueError, match=r"roughness \(slope variance\) must be >= 0; got \[-0.001.*first at index \[2, 3\]"):
        render.shade(normal, jnp.full((12, 16), 1e-3).at[2, 3].set(-1e-3), c, light)
    with pytest.raises(InvalidValueError, match="slope_variance must be >= 0"):
        render.shade(normal, None, c, light, slope_variance=jnp.full((12, 16, 2), -1e-4))
    # a zero vector was shaded as the flat sea, (0, 0, 5) as (0, 0, 1), (0, 0, -1) without a word
    rough = jnp.full((12, 16), 1e-3)
    for bad, message in ((jnp.zeros_like(normal), "normal must be unit vectors.*a zero vector is no normal"), (5 * normal, "unit vectors"),
                         (-normal, r"normal must point up \(n_z >= 0")):
        with pytest.raises(InvalidValueError, match=message):
            render.shade(bad, rough, c, light)
    # one time, finite: several times are a vmap, not a silently wrong frame
    with pytest.raises(ValueError, match=r"t must be one time \[s\] \(a scalar\); got shape \(2,\)"):
        render.render(waves, c, light, jnp.array([0.1, 0.2]))
    with pytest.raises(InvalidValueError, match="t contains 1 NaN"):
        render.geometry(waves, c, jnp.nan)
    # a plan names the waves it renders
    n = waves.omega.shape[0]
    with pytest.raises(ValueError, match=f"RenderPlan.active must index the {n} waves"):
        render.render(waves, c, light, 0.0, plan=render.RenderPlan(active=(n,), refine=0))


def test_waves_finer_than_the_camera_are_refused(x64):
    # float64 waves through a float32 camera: a clear error, not a type error deep in the hits'
    # iteration; the other way round the camera's precision is simply more than needed
    waves = sea(dtype=np.float64)
    c32 = cam.make_camera(**CAM, dtype=jnp.float32)
    with pytest.raises(ValueError, match="waves are float64 but the camera is float32"):
        render.render(waves, c32, lighting(), 0.0)
    image = render.render(sea(), cam.make_camera(**CAM, dtype=jnp.float64), lighting(), 0.0)
    assert np.all(np.isfinite(np.asarray(image)))


def test_far_future_times_are_refused_where_concrete():
    # float32 phases omega t at t = 1e7 s are rounded by radians: refused as forecast refuses
    # them (render, geometry, plan), while a traced time is not checked: jit(f)(t) == f(t)
    waves, c, light = sea(2), cam.make_camera(**CAM), lighting()
    for call in (lambda t: render.render(waves, c, light, t), lambda t: render.geometry(waves, c, t),
                 lambda t: render.plan(waves, c, t)):
        with pytest.raises(InvalidValueError, match="too far from t = 0 for float32"):
            call(1e7)
    eager = render.geometry(waves, c, 10.0, plan=None)
    traced = jax.jit(lambda t: render.geometry(waves, c, t, plan=None))(10.0)
    np.testing.assert_array_equal(np.asarray(eager.normal), np.asarray(traced.normal))


def test_plan_checks_its_time_and_full_plan_its_sizes():
    waves, c = sea(2), cam.make_camera(**CAM)
    with pytest.raises(InvalidValueError, match="t contains 1 NaN"):
        render.plan(waves, c, float("nan"))
    with pytest.raises(ValueError, match=r"t must be one time \[s\] \(a scalar\)"):
        render.plan(waves, c, jnp.array([0.0, 1.0]))
    for n, refine in ((-1, 0), (0, 0), (2.5, 0), (2, -1)):
        with pytest.raises(ValueError, match="full_plan needs n_waves >= 1 and refine >= 0"):
            render.full_plan(n, refine)
    assert render.full_plan(np.int64(2), np.int64(3)) == render.RenderPlan(active=(0, 1), refine=3)
