"""Photometric refinement (jaxocean.fit.photometric).

One tiny float64 scene (32 x 32 pixels, 3 frames, 3 waves, the sun's glitter in view),
rendered on the rows path the fit uses; every fit shares its shapes and configuration, so
the solver compiles once for the module.
"""

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxocean import camera as cam
from jaxocean import render, shading
from jaxocean.errors import InvalidValueError
from jaxocean.fit import _photometric_model as photometric_model
from jaxocean.fit import photometric_fit as ph
from jaxocean.fit.lighting import lighting_error
from jaxocean.fit.waves import match
from jaxocean.waves import Waves, make_waves

RES = (32, 32)
N_FRAMES = 3


def _camera():
    return cam.make_camera(height=6.0, pitch=0.9, fov=0.8, yaw=0.4, resolution=RES, dtype=jnp.float64)


@pytest.fixture(autouse=True)
def _x64():
    with jax.enable_x64(True):
        yield


@pytest.fixture(scope="module")
def scene():
    with jax.enable_x64(True):
        camera = _camera()
        truth = make_waves([0.03, 0.02, 0.012], [2.8, 3.6, 4.9], [0.4, 2.1, -1.2], [0.5, 4.0, 2.0], dtype=jnp.float64)
        light = shading.make_lighting(sun_azimuth=0.4, sun_elevation=0.45, dtype=jnp.float64)
        times = np.arange(N_FRAMES) * 0.15
        plan = render.full_plan(3)
        images = np.stack([np.asarray(render.render(truth, camera, light, t, plan=plan)) for t in times])
        # the start: phases 0.4-0.5 rad off, omega 2-3%, amplitudes 20%, directions 0.03-0.05 rad;
        # sun 0.03 rad in azimuth, colours 10-30% (not a common factor)
        start = Waves(truth.amplitude * jnp.array([1.2, 0.8, 1.2]), truth.omega * jnp.array([1.03, 0.97, 1.02]),
                      truth.theta + jnp.array([0.05, -0.05, 0.03]), truth.phase + jnp.array([0.5, -0.5, 0.4]))
        light0 = light._replace(sun_azimuth=light.sun_azimuth + 0.03, sun_color=light.sun_color * 0.8,
                                sky_color=light.sky_color * jnp.array([1.2, 0.9, 1.1]), sea_color=light.sea_color * 1.3)
    return dict(camera=camera, truth=truth, light=light, times=times, images=images, start=start, light0=light0)


def _fit(s, images=None, **kw):
    with jax.enable_x64(True):
        return ph.photometric(s["images"] if images is None else images, s["camera"], s["times"], s["start"],
                              s["light0"], **kw)


def _seen_lighting(result):
    """The lighting times the exposure: what the images determine."""
    e = result.exposure
    return result.lighting._replace(sun_color=result.lighting.sun_color * e, sky_color=result.lighting.sky_color * e,
                                    sea_color=result.lighting.sea_color * e)


@pytest.fixture(scope="module")
def clean_fit(scene):
    return _fit(scene)


@pytest.mark.slow  # a full photometric fit
def test_recovers_waves_and_lighting_from_a_perturbed_start(scene, clean_fit):
    r = clean_fit
    assert r.success, r.message
    assert r.message == ""
    start = match(scene["start"], scene["truth"]).abs_error
    assert np.min(start.phase) > 0.39 and np.min(start.amplitude) > 2e-3  # the start is far off
    m = match(r.waves, scene["truth"])
    assert m.missed.size == 0 and m.spurious.size == 0
    err = m.abs_error
    assert np.max(err.amplitude) < 1e-6 and np.max(err.omega) < 1e-6
    assert np.max(err.theta) < 1e-6 and np.max(err.phase) < 1e-5
    le = lighting_error(_seen_lighting(r), scene["light"])
    assert float(le["sun_angle_deg"]) < 1e-3
    for name in ("sun_color", "sky_color", "sea_color"):
        assert float(le[name]) < 1e-5, (name, float(le[name]))
    assert float(r.loss) < 1e-6 * float(r.loss_init)
    assert float(r.outlier_fraction) == 0.0 and not np.any(r.outliers)
    # the re-rendered frames are the images; the summary is JSON
    np.testing.assert_allclose(np.asarray(ph.rerender(r, scene["camera"], scene["times"])), scene["images"],
                               rtol=1e-6, atol=1e-9)
    d = json.loads(json.dumps(ph.fit_to_dict(r)))
    assert d["success"] is True and d["n_waves"] == 3 and d["noise_estimated"] is True
    assert d["determined"] == [True, True, True] and d["determined_energy"] == 1.0


def _whitecaps(images, camera, fraction, seed):
    """Images with saturated white discs over ``fraction`` of the sea pixels; and their mask."""
    rng = np.random.default_rng(seed)
    T, H, W, _ = images.shape
    sea = np.asarray(cam.intersect_sea(camera).mask)
    yy, xx = np.mgrid[:H, :W]
    blobs = np.zeros((T, H, W), bool)
    while blobs[:, sea].mean() < fraction:
        t, cy, cx = rng.integers(T), rng.uniform(0, H), rng.uniform(0, W)
        blobs[t] |= (yy - cy) ** 2 + (xx - cx) ** 2 <= rng.uniform(1.0, 2.5) ** 2
    blobs &= sea[None]
    out = images.copy()
    out[blobs] = 2.0  # white, far above the sea (~0.05) and the sky (~0.6)
    return out, blobs


def test_robust_fit_ignores_whitecaps_and_reports_them(scene):
    images, blobs = _whitecaps(scene["images"], scene["camera"], 0.05, seed=1)
    robust = _fit(scene, images)
    plain = _fit(scene, images, robust=None)
    m = match(robust.waves, scene["truth"]).abs_error
    assert np.max(m.amplitude) < 1e-5 and np.max(m.omega) < 1e-4 and np.max(m.phase) < 1e-3
    assert float(lighting_error(_seen_lighting(robust), scene["light"])["sun_angle_deg"]) < 0.01
    recall = np.sum(robust.outliers & blobs) / np.sum(blobs)
    false_alarms = np.sum(robust.outliers & ~blobs) / np.sum(~blobs)
    assert recall > 0.8 and false_alarms < 0.01, (recall, false_alarms)
    assert robust.success, robust.message
    assert np.all(np.asarray(robust.weights)[blobs] < ph.OUTLIER_WEIGHT)
    # least squares is pulled by the blobs: its waves are visibly worse
    pm = match(plain.waves, scene["truth"])
    assert pm.missed.size > 0 or np.max(pm.abs_error.phase) > 100 * np.max(m.phase)
    assert not plain.success and "exceeds" in plain.message
    assert np.all(np.asarray(plain.weights)[np.asarray(plain.weights) > 0] == 1.0)


def test_a_sequence_the_model_cannot_explain_fails(scene):
    shuffled = _fit(scene, scene["images"][[2, 0, 1]])
    assert not shuffled.success and shuffled.message
    rng = np.random.default_rng(3)
    noise = 0.05 * np.exp(0.3 * rng.standard_normal(scene["images"].shape))
    pure = _fit(scene, noise)
    assert not pure.success
    assert "no structure above the noise" in pure.message or "explain too little" in pure.message
    # rows of one value (a calm sea quantised to a few codes): said as such, not as noise
    flat = _fit(scene, np.full_like(np.asarray(scene["images"]), 0.05))
    assert not flat.success and "spread about each row's median is 0" in flat.message, flat.message


@pytest.mark.slow  # a photometric fit of 32x32 frames
def test_a_flat_sea_does_not_explain_small_textured_frames():
    # 32 x 32 frames of a 60-wave sea: the noise estimate takes in the wave texture (0.12 of
    # the images' 0.29), and the IRLS scale is floored at it. The success test holds the
    # residual's own trimmed scale to the noise and to the images' spread; with the floored
    # scale a flat sea passed (and in reconstruct a wave grown on it gave the headline Hs)
    from jaxocean import spectrum

    with jax.enable_x64(False):
        waves = spectrum.sample_waves(jax.random.key(0), spectrum.Spectrum(hs=1.0, tp=5.0, gamma=3.3, theta_mean=0.35,
                                                                           s_max=10.0), 60).waves
        camera = cam.make_camera(height=12.0, pitch=0.35, fov=0.8, resolution=(32, 32))
        light = shading.make_lighting(sun_azimuth=0.1, sun_elevation=0.35)
        times = jnp.array([0.0, 0.1, 0.2])
        frames = jax.vmap(lambda t: render.render(waves, camera, light, t))(times)
        flat = Waves(jnp.array([1e-4]), jnp.array([1.2]), jnp.array([0.3]), jnp.array([0.0]))
        result = ph.photometric(frames, camera, times, flat, light, fit=("exposure",))
    assert float(result.noise) > 0.3 * float(result.signal_scale)  # the case: an inflated noise estimate
    assert float(result.robust_scale) <= 1.5 * float(result.noise)  # which the floored scale passed
    assert not result.success
    assert "explain too little" in result.message and "exceeds 1.5 x the noise" in result.message, result.message
    assert float(result.residual_scale) > 0.8 * float(result.signal_scale)


@pytest.mark.slow  # float64 gradient checks through the images
def test_residual_is_jit_consistent_and_its_loss_has_exact_gradients(scene):
    with jax.enable_x64(True):
        camera, times, images, light = scene["camera"], scene["times"], scene["images"], scene["light0"]
        waves = scene["start"]

        def res(w, li, e):
            return ph.residual(images, camera, times, w, li, e)

        eager = res(waves, light, 1.1)
        jitted = jax.jit(res)(waves, light, 1.1)
        np.testing.assert_allclose(np.asarray(jitted), np.asarray(eager), rtol=1e-12, atol=1e-13)
        assert eager.shape == (N_FRAMES,) + RES + (3,)

        def loss(x):
            w = waves._replace(amplitude=waves.amplitude.at[0].set(x[0]), omega=waves.omega.at[1].set(x[1]),
                               phase=waves.phase.at[2].set(x[2]))
            li = light._replace(sun_elevation=x[3])
            return jnp.sum(res(w, li, jnp.exp(x[4])) ** 2)

        x = jnp.array([0.033, 3.55, 2.3, 0.46, 0.1])
        # forward mode: the derivatives the solver uses
        check_grads(loss, (x,), order=1, modes=("fwd",), eps=1e-6, atol=1e-6, rtol=1e-6)


def test_structured_jacobian_matches_finite_differences(scene, monkeypatch):
    """The solver's chain-rule Jacobian (shading x the wave fit's normal Jacobian x row
    roughness, lighting by forward mode) against central differences of the residual."""
    res = {}
    solve = ph._solve

    def spy(y, w, d, st, max_steps, rtol):
        if not res:  # the start of the first round
            res.update(y=y, d=d, st=st)
        return solve(y, w, d, st, max_steps, rtol)

    monkeypatch.setattr(ph, "_solve", spy)
    _fit(scene, rounds=1)
    y, d, st = res["y"], res["d"], res["st"]
    r, J = jax.jit(photometric_model.frame_jacobian, static_argnames="st")(y, 1, d, st)
    frame = jax.jit(lambda z: photometric_model.frame_residual(z, 1, d, st).reshape(-1))
    np.testing.assert_allclose(np.asarray(r), np.asarray(frame(y)), rtol=0, atol=1e-14)
    eps = 1e-6
    fd = np.stack([(np.asarray(frame(y.at[k].add(eps))) - np.asarray(frame(y.at[k].add(-eps)))) / (2 * eps)
                   for k in range(y.shape[0])], -1)
    assert J.shape == fd.shape == (RES[0] * RES[1] * 3, 4 * 3 + 2 + 8 + 1)
    scale = np.max(np.abs(fd), axis=0)
    assert np.all(np.max(np.abs(np.asarray(J) - fd), axis=0) <= 1e-5 * scale + 1e-9)


def test_bad_inputs_raise_clear_errors(scene):
    s = scene
    with jax.enable_x64(True):
        args = (s["images"], s["camera"], s["times"], s["start"], s["light0"])
        with pytest.raises(ValueError, match="resolution"):
            ph.photometric(s["images"][:, :16], *args[1:])
        with pytest.raises(ValueError, match="times must be"):
            ph.photometric(s["images"], s["camera"], s["times"][:2], *args[3:])
        with pytest.raises(ValueError, match="strictly increasing"):
            ph.photometric(s["images"], s["camera"], np.array([0.0, 0.3, 0.2]), *args[3:])
        with pytest.raises(ValueError, match="mask must be"):
            ph.photometric(*args, mask=np.ones((N_FRAMES,) + RES, bool)[:, :8])
        with pytest.raises(ValueError, match="mask must be bool"):
            ph.photometric(*args, mask=np.ones((N_FRAMES,) + RES))
        with pytest.raises(ValueError, match="fit= must be"):
            ph.photometric(*args, fit=("waves", "camera"))
        with pytest.raises(ValueError, match="robust must be"):
            ph.photometric(*args, robust="l1")
        with pytest.raises(ValueError, match="images must be"):
            ph.photometric(s["images"][..., :2], *args[1:])
        with pytest.raises(InvalidValueError, match="negative radiance"):
            ph.photometric(-s["images"], *args[1:])
        with pytest.raises(InvalidValueError, match="no usable sea pixel"):
            ph.photometric(*args, mask=np.zeros((N_FRAMES,) + RES, bool))
        # a frame of NaN (or masked whole) would drop out of the fit without a word
        nan_frame = np.array(s["images"])
        nan_frame[1] = np.nan
        with pytest.raises(InvalidValueError, match=r"frame\(s\) \[1\] hold no usable sea pixel"):
            ph.photometric(nan_frame, *args[1:])
        with pytest.raises(ValueError, match="images are float16: the fits run in float32 or float64"):
            ph.photometric(jnp.asarray(s["images"], jnp.float16), *args[1:])
        for bad in (-1.0, float("nan"), "0.1"):
            with pytest.raises(ValueError, match=r"noise must be a finite number >= 0 \(or None\)"):
                ph.photometric(*args, noise=bad)
        with pytest.raises(ValueError, match="noise must be"):
            ph.photometric(*args, noise=-1.0)
        with pytest.raises(ValueError, match="include 'exposure' in fit"):
            ph.photometric(*args, fit=("waves",), per_frame_exposure=True)
        with pytest.raises(ValueError, match="one per frame"):
            ph.residual(*args, exposure=jnp.ones(N_FRAMES + 1))
        with pytest.raises(ValueError, match=r"fit.photometric runs eagerly \(a host loop over IRLS rounds\)"):
            jax.jit(lambda images: ph.photometric(images, *args[1:]))(s["images"])


@pytest.mark.slow  # two photometric fits
def test_per_frame_exposure_is_recovered_where_one_exposure_cannot_explain(scene):
    # a camera on automatic exposure: each frame scaled by its own factor. One exposure for
    # the sequence cannot explain the frames; one per frame recovers the factors' ratios
    # (the overall scale is the gauge the exposure shares with the colours)
    s = scene
    gains = np.array([1.0, 1.35, 0.8])
    images = s["images"] * gains[:, None, None, None]
    with jax.enable_x64(True):
        args = (images, s["camera"], s["times"], s["truth"], s["light"])
        per = ph.photometric(*args, fit=("exposure",), per_frame_exposure=True)
        # the best single exposure is about the gains' geometric mean: it leaves each frame
        # off by its gain's ratio to it, percents of radiance against a noise-free fit
        common = ph.residual(*args, exposure=ph.mean_exposure(per))
        own = ph.residual(*args, exposure=per.exposure)
    assert np.asarray(per.exposure).shape == (N_FRAMES,)
    ratio = np.asarray(per.exposure) / float(per.exposure[0])
    np.testing.assert_allclose(ratio, gains / gains[0], rtol=1e-3)
    assert per.success
    assert float(jnp.sqrt(jnp.mean(own ** 2))) < 0.01 * float(jnp.sqrt(jnp.mean(common ** 2)))
    # the result's frames carry each frame's exposure; other times their geometric mean
    with jax.enable_x64(True):
        again = ph.rerender(per, s["camera"], s["times"])
        np.testing.assert_allclose(np.asarray(again), images, rtol=2e-3, atol=1e-6)
        later = ph.rerender(per, s["camera"], [1.0])
        mean = float(np.exp(np.mean(np.log(np.asarray(per.exposure)))))
        one = ph.rerender(per._replace(exposure=jnp.asarray(mean)), s["camera"], [1.0])
        np.testing.assert_allclose(np.asarray(later), np.asarray(one), rtol=1e-12)
    assert isinstance(ph.fit_to_dict(per)["exposure"], list)


def test_package_exports():
    import jaxocean.fit as fit

    assert fit.photometric is ph.photometric and fit.PhotometricFit is ph.PhotometricFit
    assert fit.photometric_fit is ph


@pytest.mark.slow
def test_gray_overcast_sequence(scene):
    """Gray frames (the luminance), no sun: the waves and the two colours' luminances."""
    with jax.enable_x64(True):
        light = scene["light"]._replace(sun_color=jnp.zeros(3))
        plan = render.full_plan(3)
        lum = jnp.asarray((0.2126, 0.7152, 0.0722))
        images = np.stack([np.asarray(render.render(scene["truth"], scene["camera"], light, t, plan=plan) @ lum)
                           for t in scene["times"]])
        r = ph.photometric(images, scene["camera"], scene["times"], scene["start"], scene["light0"], overcast=True)
    assert r.success, r.message
    assert float(r.lighting.sun_color.max()) == 0.0
    err = match(r.waves, scene["truth"]).abs_error
    assert np.max(err.phase) < 1e-4 and np.max(err.amplitude) < 1e-6
    seen = _seen_lighting(r)
    for name in ("sky_color", "sea_color"):
        assert abs(float(getattr(seen, name) @ lum) / float(getattr(light, name) @ lum) - 1) < 1e-5
    assert r.outliers.shape == images.shape


def test_a_wave_the_view_does_not_resolve_is_never_determined():
    # a covariance that pins every parameter down (J^T J = 1e12 I) determines the three
    # resolvable waves, but not a 1.5 m wave 385 m long in this 6 m high view, which can only
    # stand in for a tilt of the patch
    from jaxocean.fit.waves import resolvable
    from jaxocean.fit.waves._model import pack

    camera = _camera()
    waves = make_waves([0.03, 0.02, 0.012, 1.5], [2.8, 3.6, 4.9, 0.4], [0.4, 2.1, -1.2, 0.3], [0.5, 4.0, 2.0, 1.0],
                       dtype=jnp.float64)
    assert resolvable(waves, camera).tolist() == [True, True, True, False]
    y = pack(waves)
    used = jnp.ones((N_FRAMES,) + RES, bool)
    ok, energy = ph._determined_waves(y, 1e12 * jnp.eye(y.size + 5), 1e-3, used, 3, 4, camera,
                                      np.arange(N_FRAMES) * 0.15)
    assert ok.tolist() == [True, True, True, False]
    slope = np.asarray(waves.amplitude * waves.omega ** 2) ** 2
    assert energy == pytest.approx(slope[:3].sum() / slope.sum())


@pytest.mark.slow  # two photometric fits
def test_a_wave_at_its_frame_rate_alias_is_not_determined(scene):
    # frames pi / omega apart: the second wave and its reverse twin (theta + pi, -phi) make the
    # same frames, so a fit started at the twin explains the images to the noise with that
    # wave travelling backwards. Its covariance is as small as at the truth (another minimum):
    # it was reported determined and the fit a success with a direction off by pi
    from jaxocean.fit.waves import alias_separation

    camera, truth, light = scene["camera"], scene["truth"], scene["light"]
    times = np.arange(6) * np.pi / float(truth.omega[1])
    assert (alias_separation(truth, times) >= 1.0).tolist() == [True, False, True]
    twin = truth._replace(theta=truth.theta.at[1].add(np.pi), phase=truth.phase.at[1].set(2 * np.pi - truth.phase[1]))
    plan = render.full_plan(3)
    images = np.stack([np.asarray(render.render(truth, camera, light, t, plan=plan)) for t in times])
    assert np.allclose(images, np.stack([np.asarray(render.render(twin, camera, light, t, plan=plan)) for t in times]),
                       rtol=0.0, atol=1e-12)
    r = ph.photometric(images, camera, times, twin._replace(phase=twin.phase + 0.1), light, robust=None)
    assert np.cos(float(r.waves.theta[1] - truth.theta[1])) < -0.9999  # the twin explains the frames...
    assert float(r.residual_scale) < 1e-3
    assert r.determined.tolist() == [True, False, True]  # ...but the frames cannot tell it from the truth
    assert not r.success and "do not determine the waves" in r.message
