"""One function, one value: traced and eager calls agree, and gradients are those of the
value returned (float64, central differences), for views that need the converged
ray-surface hits, views with the horizon in the image and far views on the rows path."""

import functools

import jax.flatten_util

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxocean import camera as cam
from jaxocean import hierarchy, raycast, render, shading, spectrum
from jaxocean.fit import camera_fit
from jaxocean.waves import GRAVITY, make_waves

RES = (12, 16)


def _sea(n=10, seed=0, kh=(0.05, 0.25), omega=(1.0, 3.5)):
    rng = np.random.default_rng(seed)
    om = rng.uniform(*omega, n)
    amp = rng.uniform(*kh, n) / (om**2 / GRAVITY) / np.sqrt(n / 4)
    return make_waves(amp, om, rng.uniform(-np.pi, np.pi, n), rng.uniform(0, 2 * np.pi, n))


def _camera(height, pitch, yaw=0.3, fov=0.7):
    return cam.make_camera(height=height, pitch=pitch, yaw=yaw, fov=fov, resolution=RES, dtype=jnp.float64)


def _light():
    return shading.make_lighting(sun_azimuth=0.4, sun_elevation=0.6, dtype=jnp.float64)


# (height, pitch, fov): close and steep (hits path), horizon in view (hits path), far (rows path)
VIEWS = {"close": (6.0, 0.9, 0.6), "horizon": (8.0, 0.3, 0.7), "far": (300.0, 0.8, 0.3)}
# the close view's float64 hits path takes about 20 s a test on 2 cores: slow tier
VIEW_PARAMS = [pytest.param(name, marks=pytest.mark.slow) if name == "close" else name for name in VIEWS]


def _view(name):
    h, p, f = VIEWS[name]
    return _camera(h, p, fov=f)


@pytest.mark.parametrize("name", VIEW_PARAMS)
def test_jit_equals_eager_for_render_geometry_and_shade(x64, name):
    waves, c, light = _sea(), _view(name), _light()
    expect_hits = name != "far"
    assert (render.plan(waves, c).refine > 0) is expect_hits
    eager = render.render(waves, c, light, 1.3)
    traced = jax.jit(lambda w, c, l, t: render.render(w, c, l, t))(waves, c, light, 1.3)
    np.testing.assert_allclose(traced, eager, rtol=1e-12, atol=1e-13)
    geo = render.geometry(waves, c, 1.3)
    geo_jit = jax.jit(lambda w, c, t: render.geometry(w, c, t))(waves, c, 1.3)
    np.testing.assert_array_equal(geo_jit.converged, geo.converged)
    good = np.asarray(geo.converged)
    np.testing.assert_allclose(np.asarray(geo_jit.normal)[good], np.asarray(geo.normal)[good], rtol=1e-12, atol=1e-13)
    shaded = render.shade(geo.normal, geo.roughness, c, light, slope_variance=geo.slope_variance)
    shaded_jit = jax.jit(lambda n, r, s, c, l: render.shade(n, r, c, l, slope_variance=s))(
        geo.normal, geo.roughness, geo.slope_variance, c, light)
    np.testing.assert_allclose(shaded_jit, shaded, rtol=1e-12, atol=1e-13)
    np.testing.assert_allclose(shaded, eager, rtol=1e-12, atol=1e-13)  # render = shade(geometry)


def test_jit_equals_eager_geometry_on_sky_pixels_when_the_plan_drops_waves(x64):
    # the eager plan evaluates only the waves some sea pixel shows; sky pixels must not tell
    waves = spectrum.sample_waves(jax.random.key(0), spectrum.Spectrum(1.2, 5.5, 3.3, 0.4, 10.0), 6).waves
    c = cam.make_camera(height=12.0, pitch=0.35, fov=0.8, resolution=(10, 12))
    assert len(render.plan(waves, c, 0.3).active) < 6 and not bool(np.all(render.geometry(waves, c, 0.3).mask))
    eager = render.geometry(waves, c, 0.3)
    traced = jax.jit(lambda w, c: render.geometry(w, c, 0.3))(waves, c)
    for field in ("normal", "position", "roughness", "slope_variance", "xy", "footprint", "mask"):
        np.testing.assert_allclose(np.asarray(getattr(traced, field)), np.asarray(getattr(eager, field)),
                                   rtol=1e-12, atol=1e-13, err_msg=field)
    sky = ~np.asarray(eager.mask)
    np.testing.assert_array_equal(np.asarray(eager.normal)[sky], np.broadcast_to([0.0, 0.0, 1.0], (sky.sum(), 3)))


def _joint_loss(weights, waves, t, params):
    """sum(w * render) as a function of every camera and lighting parameter at once."""
    h, p, yaw, fov, az, el, sun, sky, sea = params
    c = cam.Camera(height=h, pitch=p, yaw=yaw, fov=fov, x=jnp.zeros_like(h), y=jnp.zeros_like(h),
                   ortho_width=jnp.ones_like(h), resolution=RES)
    light = shading.Lighting(az, el, sun, sky, sea)
    return jnp.sum(weights * render.render(waves, c, light, t))


def _params(c, light):
    return tuple(jnp.asarray(v, jnp.float64) for v in (c.height, c.pitch, c.yaw, c.fov, *light))


def _check_joint_gradient(waves, c, light, t, seed=0):
    img, geo = render.render(waves, c, light, t, with_geometry=True)
    # pixels whose hit is not unique carry no exact derivative (flagged): weight them out
    usable = np.asarray(geo.converged)
    rng = np.random.default_rng(seed)
    weights = jnp.asarray(rng.normal(size=img.shape) * usable[..., None])
    params = _params(c, light)
    grads = jax.grad(_joint_loss, argnums=3)(weights, waves, t, params)
    flat, unravel = jax.flatten_util.ravel_pytree(params)
    g = np.asarray(jax.flatten_util.ravel_pytree(grads)[0])

    def f(x):
        return float(_joint_loss(weights, waves, t, unravel(jnp.asarray(x))))

    x0 = np.asarray(flat)
    fd = np.empty_like(x0)
    for i in range(x0.size):
        eps = 1e-6 * max(1.0, abs(x0[i]))
        hi, lo = x0.copy(), x0.copy()
        hi[i] += eps
        lo[i] -= eps
        fd[i] = (f(hi) - f(lo)) / (2 * eps)
    scale = np.abs(fd).max()
    np.testing.assert_allclose(g, fd, rtol=2e-5, atol=2e-6 * scale)
    return usable


@pytest.mark.parametrize("name", VIEW_PARAMS)
def test_gradient_wrt_camera_and_lighting_jointly_matches_central_differences(x64, name):
    usable = _check_joint_gradient(_sea(seed=1), _view(name), _light(), 1.3)
    assert usable.mean() > 0.5


@given(height=st.floats(3.0, 40.0), pitch=st.floats(0.15, 1.3), yaw=st.floats(-3.0, 3.0),
       fov=st.floats(0.4, 1.0), az=st.floats(-3.0, 3.0), el=st.floats(0.2, 1.2))
def test_gradient_over_random_views(height, pitch, yaw, fov, az, el):
    with jax.enable_x64(True):
        c = _camera(height, pitch, yaw=yaw, fov=fov)
        light = shading.make_lighting(sun_azimuth=az, sun_elevation=el, dtype=jnp.float64)
        waves = _sea(seed=2)
        eager = render.render(waves, c, light, 0.7)
        np.testing.assert_allclose(jax.jit(render.render)(waves, c, light, 0.7), eager, rtol=1e-12, atol=1e-13)
        _check_joint_gradient(waves, c, light, 0.7)


@pytest.mark.slow  # float64 gradients at the horizon of a steep sea
def test_grazing_rays_are_flagged_and_carry_no_gradient(x64):
    # a steep sea seen from 8 m with the horizon in view: near the horizon the rays graze the
    # crests and meet the surface more than once
    waves = _sea(12, seed=0, kh=(0.05, 0.3))
    c = cam.make_camera(height=8.0, pitch=0.35, fov=0.87, resolution=(32, 40), dtype=jnp.float64)
    geo = render.geometry(waves, c, 1.3)
    mask, ok = np.asarray(geo.mask), np.asarray(geo.converged)
    flagged = mask & ~ok
    assert flagged.any() and ok[mask].mean() > 0.5
    assert ok[~mask].all()  # sky pixels are not hit failures
    # the flagged pixels lie toward the horizon (top rows): grazing incidence
    rows = np.nonzero(flagged)[0]
    assert np.median(rows) < np.median(np.nonzero(mask & ok)[0])

    def hit_xy(h):
        return render.geometry(waves, cam.make_camera(height=h, pitch=0.35, fov=0.87, resolution=(32, 40)), 1.3).xy

    d_xy = np.asarray(jax.jacfwd(hit_xy)(jnp.float64(8.0)))
    assert np.all(d_xy[flagged] == 0.0) and np.all(np.isfinite(d_xy))
    assert np.abs(d_xy[mask & ok]).max() > 0


@pytest.mark.slow  # float64 finite differences through the hits
def test_converged_hits_lie_on_the_surface_and_their_derivative_is_implicit(x64):
    waves = _sea(6, seed=4, kh=(0.1, 0.3), omega=(0.6, 1.5))
    c = _view("close")
    hit = cam.intersect_sea(c)
    ws = hierarchy.weights(waves, hit.footprint)
    origin, direction = cam.pixel_rays(c)
    hits = raycast.refine_hits(waves, origin, direction, hit.xy, 0.8, ws.displacement)
    ok = np.asarray(hits.converged)
    assert ok.mean() > 0.95  # metre-high waves seen from 6 m: a Newton cycle or two near the top row
    residual = np.asarray(raycast.hit_residual(waves, origin, direction, hits.xy, 0.8, ws.displacement))
    assert residual[ok].max() < 1e-8
    assert residual[~ok].min() > 1e-3  # what is flagged really is not a hit

    # derivative of the hit with respect to the waves, the ray direction and the time
    rows = (slice(3, 5), slice(4, 7))
    assert ok[rows].all()

    def fn(amplitude, direction, t):
        w = waves._replace(amplitude=amplitude)
        return raycast.refine_hits(w, origin, direction, hit.xy[rows], t, ws.displacement[rows]).xy

    check_grads(fn, (waves.amplitude, direction[rows], jnp.float64(0.8)), order=1, modes=("fwd", "rev"),
                atol=1e-5, rtol=1e-5)


def test_the_hit_does_not_depend_on_the_iteration_cap_once_converged(x64):
    waves, c = _sea(seed=3), _view("close")
    a = render.geometry(waves, c, 0.4, plan=render.full_plan(10, 32))
    b = render.geometry(waves, c, 0.4, plan=render.full_plan(10, 64))
    ok = np.asarray(a.converged)
    assert ok.mean() > 0.95
    np.testing.assert_allclose(np.asarray(a.normal)[ok], np.asarray(b.normal)[ok], rtol=0, atol=1e-13)
    # too small a cap: the hits that did not converge say so
    few = render.geometry(waves, c, 0.4, plan=render.full_plan(10, 1))
    assert not np.asarray(few.converged)[np.asarray(few.mask)].all()


@pytest.mark.slow  # compiles the camera fit residual and its gradient in float64
def test_camera_fit_residual_is_the_same_traced_and_eager_with_exact_gradient(x64):
    waves, c, light = _sea(seed=5), _view("close"), _light()
    plan = render.full_plan(10, render.plan(waves, c).refine)
    assert plan.refine > 0
    image = render.render(waves, c, light, 0.5)
    weight = jnp.ones(RES + (3,), jnp.float64)
    args = (image, weight, waves, jnp.float64(0.5), c, jnp.float64(0.0), light)
    fn = functools.partial(camera_fit._residual, fit=("height", "pitch"), fit_lighting=False, plan=plan, scale=1.0)
    y = camera_fit._pack(c, ("height", "pitch")) + jnp.array([0.02, -0.01])
    r = fn(y, args)
    np.testing.assert_allclose(jax.jit(fn)(y, args), r, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(fn(camera_fit._pack(c, ("height", "pitch")), args), 0.0, atol=1e-10)
    check_grads(lambda y: fn(y, args), (y,), order=1, modes=("fwd", "rev"), atol=1e-5, rtol=1e-5, eps=1e-6)


def test_traced_auto_plan_under_vmap_matches_each_eager_call(x64):
    # a batch mixing a view that needs the hits path with one on the rows path
    waves, light = _sea(seed=6), _light()
    cams = [_view("close"), _view("far")]
    batch = jax.tree.map(lambda *a: jnp.stack(a), *cams)
    imgs = jax.vmap(lambda c: render.render(waves, c, light, 0.2))(batch)
    for i, c in enumerate(cams):
        np.testing.assert_allclose(imgs[i], render.render(waves, c, light, 0.2), rtol=1e-11, atol=1e-13)


def test_one_pass_jacobian_equals_autodiff_of_the_fixed_point_map(x64):
    # F and dF/dX come from one pass over the waves (eight sums); autodiff of F is the reference
    waves, c = _sea(8, seed=7, kh=(0.1, 0.3)), _view("close")
    hit = cam.intersect_sea(c)
    ws = hierarchy.weights(waves, hit.footprint)
    origin, direction = cam.pixel_rays(c)
    origin = jnp.broadcast_to(origin, direction.shape)
    xy = hit.xy + 0.3 * jnp.sin(hit.xy[..., ::-1])  # off the fixed point: a generic X
    for weights in (ws.displacement, None):
        value, jx, jy = raycast._step_jacobian(waves, origin, direction, xy, 0.6, weights)
        np.testing.assert_allclose(value, raycast.step(waves, origin, direction, xy, 0.6, weights), rtol=0, atol=1e-12)

        def f(p, i, j):
            return raycast.step(waves, origin[i, j], direction[i, j], p, 0.6, None if weights is None else weights[i, j])

        for i, j in ((0, 0), (5, 7), (11, 15)):
            jac = np.asarray(jax.jacfwd(f)(xy[i, j], i, j))  # jac[:, m] = dF/dX_m
            np.testing.assert_allclose(np.stack([jx[i, j], jy[i, j]], -1), jac, rtol=1e-10, atol=1e-12)


@pytest.mark.slow  # compiles the hit loop twice in float64
def test_compacting_the_loop_changes_the_cost_not_the_hits(x64, monkeypatch):
    # the loop gathers the points still moving into smaller buffers; with compaction off
    # (one level) every hit and flag is the same, to float rounding
    waves = _sea(12, seed=0, kh=(0.05, 0.3))
    c = cam.make_camera(height=8.0, pitch=0.35, fov=0.87, resolution=(32, 40), dtype=jnp.float64)
    hit = cam.intersect_sea(c)
    ws = hierarchy.weights(waves, hit.footprint)
    origin, direction = render._sea_rays(c, hit)
    assert len(raycast._compaction_sizes(32 * 40)) > 2
    args = (waves, origin, direction, hit.xy, 1.3, ws.displacement)
    compacted = raycast.refine_hits(*args, active=hit.mask)
    monkeypatch.setattr(raycast, "COMPACTION", 10**9)
    assert raycast._compaction_sizes(32 * 40) == (32 * 40,)
    jax.clear_caches()
    plain = raycast.refine_hits(*args, active=hit.mask)
    ok = np.asarray(plain.converged)
    np.testing.assert_array_equal(compacted.converged, ok)
    assert (~ok[np.asarray(hit.mask)]).sum() > 0  # grazing pixels: the stragglers compaction is for
    np.testing.assert_allclose(np.asarray(compacted.xy)[ok], np.asarray(plain.xy)[ok], rtol=0, atol=1e-9)
    assert int(compacted.iterations) == int(plain.iterations)


@pytest.mark.parametrize("name", ["close", "far"])
def test_jit_over_the_time_alone_with_concrete_waves_and_camera_equals_eager(x64, name):
    # waves and camera closed over (concrete), only the time traced: the host plan must not
    # be staged into the caller's jit (it read a tracer into NumPy and crashed)
    waves, c, light = _sea(n=3), _view(name), _light()
    eager = render.render(waves, c, light, 0.7)
    traced = jax.jit(lambda t: render.render(waves, c, light, t))(0.7)
    np.testing.assert_allclose(traced, eager, rtol=1e-12, atol=1e-13)
    geo = jax.jit(lambda t: render.geometry(waves, c, t).normal)(0.7)
    np.testing.assert_allclose(geo, render.geometry(waves, c, 0.7).normal, rtol=1e-12, atol=1e-13)
