"""Forecasting (jaxocean.forecast): phase advance, re-rendering at later times, error metric."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxocean import camera as cam
from jaxocean import forecast as fc
from jaxocean import render, shading
from jaxocean.errors import InvalidValueError
from jaxocean.waves import make_waves

RES = (12, 12)


def sea():
    return make_waves([0.05, 0.02, 0.01], [1.2, 2.0, 3.1], [0.3, 1.9, -2.2], [0.5, 4.0, 2.0])


def camera():
    return cam.make_camera(height=6.0, pitch=0.5, fov=0.8, resolution=RES)


def test_advance_is_a_phase_shift_that_composes():
    w = sea()
    a = fc.advance(fc.advance(w, 1.3), 2.4)
    b = fc.advance(w, 3.7)
    np.testing.assert_allclose(np.exp(1j * np.asarray(a.phase)), np.exp(1j * np.asarray(b.phase)), atol=1e-5)
    np.testing.assert_array_equal(a.omega, w.omega)
    assert np.all((np.asarray(b.phase) >= 0) & (np.asarray(b.phase) < 2 * np.pi))
    # times broadcast to a (T, N) stack
    stack = fc.advance(w, jnp.asarray([[0.0], [1.0]]))
    assert stack.phase.shape == (2, 3)


def test_forecast_geometry_equals_rendering_the_advanced_waves_at_zero():
    w, c = sea(), camera()
    times = jnp.asarray([0.0, 0.7, 5.0])
    out = fc.forecast(w, times, c, shading.make_lighting())
    assert out.geometry.normal.shape == (3, *RES, 3) and out.image.shape == (3, *RES, 3)
    plan = render.RenderPlan(active=(0, 1, 2), refine=0)
    for i, t in enumerate(np.asarray(times)):
        # the sea at time t == the advanced sea at time 0 == the original sea rendered at t
        direct = render.geometry(w, c, float(t), plan=plan)
        shifted = render.geometry(jax.tree.map(lambda x, i=i: x[i], out.waves), c, 0.0, plan=plan)
        np.testing.assert_allclose(out.geometry.normal[i], direct.normal, atol=2e-5)
        np.testing.assert_allclose(shifted.normal, direct.normal, atol=2e-4)
    assert np.all(np.isfinite(np.asarray(out.image)))


def test_forecast_without_camera_and_bad_inputs():
    w = sea()
    out = fc.forecast(w, 2.0)
    assert out.geometry is None and out.image is None and out.waves.phase.shape == (1, 3)
    with pytest.raises(ValueError, match="needs a camera"):
        fc.forecast(w, [0.0, 1.0], None, shading.make_lighting())
    with pytest.raises(ValueError, match="leaves \\(N,\\)"):
        fc.forecast(jax.tree.map(lambda x: jnp.stack([x, x]), w), [0.0])
    with pytest.raises(InvalidValueError, match="finite"):
        fc.forecast(w, [0.0, np.nan])
    # a finite time beyond float32 is named as such, not cast to inf first (with a warning)
    with pytest.raises(InvalidValueError, match=r"float32 range .*1e\+300"):
        fc.forecast(w, [0.0, 1e300])
    with pytest.raises(ValueError, match="plan must be"):
        fc.forecast(w, [0.0], camera(), plan="fast")


def test_frame_times_and_their_errors():
    np.testing.assert_allclose(fc.frame_times([1.0, 1.1, 1.2], [0, 100, 500]), [1.0, 11.0, 51.0])
    with pytest.raises(ValueError, match="T >= 2"):
        fc.frame_times([1.0], [0])
    with pytest.raises(InvalidValueError, match="strictly increasing"):
        fc.frame_times([1.0, 0.5], [0])


def test_geometry_error_is_zero_for_identical_and_known_for_tilted_normals():
    w, c = sea(), camera()
    out = fc.forecast(w, [0.0, 1.0], c)
    err = fc.geometry_error(out.geometry, out.geometry)
    # |n x n| is zero up to float32 rounding of a fused multiply-add: ~1e-8 rad, not 1e-3
    np.testing.assert_allclose(err.normal, 0.0, atol=1e-6)
    np.testing.assert_allclose(err.roughness, 0.0, atol=0)
    up = jnp.zeros((1, 2, 2, 3)).at[..., 2].set(1.0)
    tilt = jnp.zeros((1, 2, 2, 3)).at[..., 0].set(np.sin(0.1)).at[..., 2].set(np.cos(0.1))
    r = jnp.zeros((1, 2, 2))
    np.testing.assert_allclose(fc.geometry_error((tilt, r + 0.01), (up, r)).normal, [0.1], rtol=1e-5)
    np.testing.assert_allclose(fc.geometry_error((tilt, r + 0.01), (up, r)).roughness, [0.01], rtol=1e-5)
    with pytest.raises(ValueError, match="shapes differ"):
        fc.geometry_error((up, r), (up[:, :1], r[:, :1]))
    # a Geometry's pixels whose hit did not converge are left out by default
    g = out.geometry
    bad = g._replace(normal=g.normal.at[:, 0, 0].set(jnp.asarray([1.0, 0.0, 0.0])),
                     converged=jnp.ones(g.mask.shape, bool).at[:, 0, 0].set(False))
    assert bool(g.mask[0, 0, 0])
    np.testing.assert_allclose(fc.geometry_error(bad, g).normal, 0.0, atol=1e-6)
    assert float(fc.geometry_error(bad._replace(converged=None), g).normal[0]) > 1e-3
    # pixels outside the mask may hold NaN (unconverged hits): they are left out, not NaN
    holed = tilt.at[0, 0, 0].set(jnp.nan)
    mask = jnp.ones((1, 2, 2), bool).at[0, 0, 0].set(False)
    err = fc.geometry_error((holed, r.at[0, 0, 0].set(jnp.nan)), (up, r), mask)
    np.testing.assert_allclose(err.normal, [0.1], rtol=1e-5)
    np.testing.assert_allclose(err.roughness, [0.0], atol=0)
    # no pixel counted: nothing was compared, so no score (a perfect 0 would be a lie)
    empty = fc.geometry_error((tilt, r), (up, r), jnp.zeros((1, 2, 2), bool))
    assert np.isnan(float(empty.normal[0])) and np.isnan(float(empty.roughness[0]))


def test_forecast_is_differentiable_in_the_waves(x64):
    w = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), sea())
    c = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64) if isinstance(x, jax.Array) else x, camera())

    def loss(amplitude):
        out = fc.forecast(w._replace(amplitude=amplitude), jnp.asarray([0.0, 3.0]), c)
        return jnp.sum(out.geometry.normal[..., :2] ** 2)

    g = jax.grad(loss)(w.amplitude)
    assert np.all(np.isfinite(np.asarray(g))) and float(jnp.max(jnp.abs(g))) > 0
    eps = 1e-6
    e0 = jnp.zeros(3).at[0].set(eps)
    fd = (loss(w.amplitude + e0) - loss(w.amplitude - e0)) / (2 * eps)
    np.testing.assert_allclose(float(g[0]), float(fd), rtol=1e-5)


def test_damping_is_one_inside_the_window_and_gaussian_in_the_distance_outside():
    sigma = jnp.asarray([0.0, 0.5, 2.0])
    times = jnp.asarray([-1.0, 0.0, 0.4, 1.0, 3.0])
    d = np.asarray([1.0, 0.0, 0.0, 0.0, 2.0])  # distance outside (0, 1)
    expected = np.exp(-0.5 * (np.asarray(sigma)[None, :] * d[:, None]) ** 2)
    np.testing.assert_allclose(fc.damping(sigma, times, (0.0, 1.0)), expected, rtol=1e-6)
    # a frequency not known at all: the wave is kept inside the window, gone outside (no NaN)
    unknown = fc.damping(jnp.asarray([jnp.inf]), times, (0.0, 1.0))
    np.testing.assert_array_equal(np.asarray(unknown)[:, 0], [0.0, 1.0, 1.0, 1.0, 0.0])
    np.testing.assert_array_equal(np.asarray(jax.jit(fc.damping, static_argnums=2)(
        jnp.asarray([jnp.inf]), times, (0.0, 1.0))), np.asarray(unknown))
    # ... and no NaN gradient: the times and the window are shared by every wave, so an
    # infinite sigma made the whole Jacobian NaN (the sigma = 0 wave's too)
    mixed = jnp.asarray([0.0, 0.05, jnp.inf])
    jac = jax.jacrev(lambda t: fc.damping(mixed, t, (0.0, 1.0)))(times)
    assert np.all(np.isfinite(np.asarray(jac)))
    np.testing.assert_array_equal(np.asarray(jac)[:, [0, 2]], 0.0)  # never damped / a constant 0 or 1
    assert np.isfinite(float(jax.grad(lambda hi: fc.damping(mixed, times, (0.0, hi)).sum())(1.0)))


def test_auto_plan_damped_forecast_is_the_same_eager_and_traced(x64):
    # the plan rule depends on the amplitudes, which damping changes frame by frame: one
    # host-side plan of the undamped waves put every frame on the hits path eagerly, the
    # compiled function chose per frame (the image differed by 5 of 4,000 on frame 2)
    w = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64),
                     make_waves([0.25, 0.6, 0.3], [2.0, 1.3, 1.7], [0.5, -1.0, 2.0], [0.1, 0.2, 0.3]))
    c = cam.make_camera(height=8.0, pitch=0.3, fov=0.7, resolution=(10, 12), dtype=jnp.float64)
    light = shading.make_lighting(sun_azimuth=0.2, sun_elevation=0.4, dtype=jnp.float64)
    f = lambda w: fc.forecast(w, jnp.array([0.5, 3.0]), c, light, plan="auto", window=(0.0, 1.0),  # noqa: E731
                              frequency_sigma=jnp.full(3, 1.25))
    eager, traced = f(w), jax.jit(f)(w)
    np.testing.assert_allclose(traced.geometry.normal, eager.geometry.normal, atol=1e-10)
    np.testing.assert_allclose(traced.image, eager.image, rtol=1e-9)


def test_damped_wave_is_the_expected_wave_under_a_gaussian_frequency_error(x64):
    # the least-squares forecast: E_e[a cos(psi + e d)] over e ~ N(0, sigma^2) (Gauss-Hermite
    # quadrature, exact for this integrand to double precision) is the damped wave
    w = jax.tree.map(lambda x: jnp.asarray(x, jnp.float64), sea())
    sigma = jnp.asarray([0.05, 0.3, 0.0], jnp.float64)
    window, t = (0.0, 1.5), 6.0
    damped = fc.forecast(w, t, window=window, frequency_sigma=sigma).waves
    plain = fc.forecast(w, t).waves
    nodes, weights = np.polynomial.hermite_e.hermegauss(60)
    weights = weights / weights.sum()
    d = t - window[1]
    expect = [np.sum(weights * a * np.cos(p + nodes * s * d))
              for a, p, s in zip(np.asarray(plain.amplitude[0]), np.asarray(plain.phase[0]), np.asarray(sigma))]
    got = np.asarray(damped.amplitude[0]) * np.cos(np.asarray(damped.phase[0]))
    np.testing.assert_allclose(got, expect, rtol=1e-10, atol=1e-14)


def test_damped_forecast_keeps_the_window_is_jittable_and_differentiable(x64):
    w, c = sea(), camera()
    sigma = jnp.asarray([0.0, 0.4, 1.0])
    times = jnp.asarray([0.0, 0.5, 4.0])
    plain = fc.forecast(w, times, c)
    damped = fc.forecast(w, times, c, window=(0.0, 0.5), frequency_sigma=sigma)
    # inside the window nothing changes; outside, the damped sea is flatter
    np.testing.assert_array_equal(damped.geometry.normal[:2], plain.geometry.normal[:2])
    slope = lambda g: float(jnp.mean(jnp.sum(g.normal[2, ..., :2] ** 2, -1)))  # noqa: E731
    assert slope(damped.geometry) < 0.9 * slope(plain.geometry)
    jitted = jax.jit(lambda s: fc.forecast(w, times, c, window=(0.0, 0.5), frequency_sigma=s).geometry.normal)
    np.testing.assert_allclose(jitted(sigma), damped.geometry.normal, atol=1e-6)
    check_grads(lambda s: fc.damping(s, jnp.asarray([-0.3, 0.2, 2.0]), (0.0, 0.5)),
                (jnp.asarray([0.1, 0.7, 1.3]),), order=2, modes=("fwd", "rev"))


def test_damped_forecast_bad_inputs():
    w = sea()
    with pytest.raises(ValueError, match="go together"):
        fc.forecast(w, 1.0, window=(0.0, 1.0))
    with pytest.raises(ValueError, match="go together"):
        fc.forecast(w, 1.0, frequency_sigma=jnp.zeros(3))
    with pytest.raises(ValueError, match="one entry per wave"):
        fc.forecast(w, 1.0, window=(0.0, 1.0), frequency_sigma=jnp.zeros(2))
    with pytest.raises(InvalidValueError, match="frequency_sigma must be >= 0"):
        fc.forecast(w, 1.0, window=(0.0, 1.0), frequency_sigma=jnp.asarray([0.1, -0.1, 0.0]))
    with pytest.raises(InvalidValueError, match="t_first <= t_last"):
        fc.forecast(w, 1.0, window=(2.0, 1.0), frequency_sigma=jnp.zeros(3))


def test_advance_refuses_non_finite_times():
    w = sea()
    for dt in (np.nan, np.inf, [[0.0], [np.nan]]):
        with pytest.raises(InvalidValueError, match="finite"):
            fc.advance(w, dt)
    # traced times are not inspected; the jitted advance is the eager one
    np.testing.assert_array_equal(jax.jit(fc.advance)(w, 2.5).phase, fc.advance(w, 2.5).phase)


def test_forecast_refuses_times_whose_float32_phases_are_lost():
    w = sea()  # omega up to 3.1 rad/s: omega t ~ 3e6 rad at t = 1e6 s, rounded by ~0.4 rad in float32
    fc.forecast(w, [0.0, 1e4])  # near times are fine
    with pytest.raises(InvalidValueError, match="too far from t = 0 for float32"):
        fc.forecast(w, [0.0, 1e6])
    with pytest.raises(InvalidValueError, match="too far from t = 0"):
        fc.advance(w, 1e7)
    # a damped forecast draws no wave of unknown frequency far outside the window: nothing to round
    out = fc.forecast(w, [1e7], window=(0.0, 1.0), frequency_sigma=jnp.full(3, jnp.inf))
    assert np.all(np.asarray(out.waves.amplitude) == 0)


def test_frame_times_error_shows_the_times_not_their_steps():
    # [0, 0.2, 0.1]: the time 0.1 at index 2 does not follow 0.2 (its step, -0.1, is no frame time)
    with pytest.raises(InvalidValueError, match=r"strictly increasing; got \[0\.1\] \(first at index \[2\]"):
        fc.frame_times([0.0, 0.2, 0.1], [0])
