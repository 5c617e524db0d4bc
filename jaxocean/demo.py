"""The demo's inverse stages: lighting fit and re-editing; wave fit and forecast.

Protocol: each stage takes what the render stage produced (or builds its own small scene),
runs the library's fits eagerly, writes a figure and returns a JSON-able summary dict.
Called by ``jaxocean demo`` (:mod:`jaxocean.cli`); usable from a notebook too.

* :func:`lighting_stage` (the paper's Fig. 10 and 15): fit sun direction and colours to
  frame 0 from a random start, re-render with the fit, show the display-space error map and
  re-edited views (lower camera, other view angle, lower sun).
* :func:`waves_stage` (Fig. 11-13): a small swell scene (``n_waves`` waves, 64^2, 8 frames,
  orthographic-like steep view) whose geometry is fitted by :func:`jaxocean.fit.waves`
  (spectral start, order selection, structured LM); the recovered waves against the truth,
  and a forecast strip (truth / forecast normals at frames 0, 100, 500).

* :func:`reconstruct_stage` (the mission's path): the rendered scene written as 8-bit PNG
  frames; everything but the frames and the camera forgotten; :func:`jaxocean.reconstruct.
  reconstruct` run on them; its forecast shown beside the truth's.
* :func:`real_stage`: ``reconstruct`` on a short clip of real ship-borne footage.

Sizes are small on purpose: the demo must run in a few minutes on a laptop CPU.
"""

from __future__ import annotations

import math
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import forecast as fc
from jaxocean import plots, render, shading

__all__ = ["lighting_stage", "waves_stage", "reconstruct_stage", "real_stage"]


def lighting_stage(out: Path, scene, image, geometry, *, seed: int = 5) -> dict:
    """Fit the lighting of ``image (H, W, 3)`` (frame 0 of ``scene``) given its ``geometry``
    (a :class:`jaxocean.render.Geometry` of that frame); write ``lighting_fit.png``."""
    from jaxocean import fit

    init = fit.random_lighting(jax.random.key(seed))
    t0 = time.perf_counter()
    result = fit.lighting(image, geometry, scene.camera, init=init, throw=False)
    wall = time.perf_counter() - t0
    model = render.shade(geometry.normal, geometry.roughness, scene.camera, result.lighting,
                         slope_variance=geometry.slope_variance)
    error = np.abs(np.asarray(shading.tonemap(model)) - np.asarray(shading.tonemap(image))).max(-1)
    t = float(scene.times[0])
    edits = [("camera 5 m high", dict(camera_height=5.0)),
             ("view 8 deg below horizon", dict(camera_pitch=math.radians(8.0))),
             ("sun elevation 8 deg", dict(sun_elevation=math.radians(8.0)))]
    views = [(label, fit.reedit(scene.waves, scene.camera, result.lighting, t, **kw)) for label, kw in edits]
    truth, fitted = fit.lighting_to_dict(scene.lighting), fit.lighting_to_dict(result.lighting)
    sun_error = float(fit.lighting_error(result.lighting, scene.lighting)["sun_angle_deg"])
    row_fit = [plots.display(image), plots.display(model), plots.log_to_rgb(error, vmin=1e-6, vmax=1e-1)]
    edit_titles = ", ".join(e for e, _ in edits)
    row_edit = [plots.display(v) for _, v in views]
    path = plots.contact_sheet(out / "lighting_fit.png", [row_fit, row_edit],
                               col_titles=["observed", "re-rendered with the fit",
                                           "|display error|, log10 from -6 to -1"],
                               row_titles=["fit", "re-edited"],
                               title=f"lighting fit from a random start: {int(result.steps)} LM steps, sun "
                                     f"{sun_error:.1e} deg off\nre-edited views: {edit_titles}")
    return dict(success=bool(result.success), steps=int(result.steps), loss=float(result.loss),
                wall_s_with_compile=wall, sun_error_deg=sun_error, max_display_error=float(error.max()),
                fitted=fitted, truth=truth, figure=str(path))


def _swell(n_waves: int, seed: int):
    """A swell of ``n_waves`` long-crested trains, well resolved by a 64^2 view of 24 m."""
    from jaxocean.waves import make_waves

    rng = np.random.default_rng(seed)
    omega = np.sort(rng.uniform(3.0, 5.0, n_waves))  # 2.5 to 6.8 m: 3 to 8 wavelengths across the view
    lam = 2 * np.pi * 9.81 / omega ** 2
    amplitude = 0.04 * lam / (2 * np.pi) * rng.uniform(0.4, 1.0, n_waves)  # k h between 0.016 and 0.04
    theta = 0.5 + rng.uniform(-0.9, 0.9, n_waves)
    phase = rng.uniform(0, 2 * np.pi, n_waves)
    return make_waves(amplitude, omega, theta, phase)


def waves_stage(out: Path, *, n_waves: int = 4, seed: int = 0, resolution: int = 64, frames: int = 8,
                forecast_frames=(0, 100, 500)) -> dict:
    """Fit a small swell's waves from its geometry and forecast it; write ``wave_fit.png``."""
    from jaxocean import fit
    from jaxocean.fit import waves_fit

    truth = _swell(n_waves, seed)
    camera = cam.make_camera(height=20.0, pitch=1.2, fov=0.9, resolution=(resolution, resolution))
    times = np.arange(frames) * 0.12
    # the sea as render draws it (the hits path where the swell moves the pixels' hits)
    normals, roughness = waves_fit.predict(truth, camera, times, surface="auto")
    t0 = time.perf_counter()
    # prune: drop waves the Wald statistic calls insignificant, then the weaker wave of each pair
    # the window does not separate (each refit, kept if the BIC agrees)
    result = fit.waves(normals, roughness, camera, times, prune=True)
    wall = time.perf_counter() - t0
    match = fit.match(result.waves, truth)
    f_times = jnp.asarray(fc.frame_times(times, forecast_frames), normals.dtype)
    # drawn as the camera sees them: the truth as render draws it, the fit on the path it was
    # fitted on; the least-squares forecast (waves and long-wave band, damped outside the
    # fitted window by their frequency uncertainty)
    true_geo = fc.forecast(truth, f_times, camera, plan="auto").geometry
    model, sigma, window = waves_fit.forecast_model(result, camera, times)
    fit_geo = fc.forecast(model, f_times, camera, plan=waves_fit.forecast_plan(result, model.omega.shape[0]),
                          window=window, frequency_sigma=sigma).geometry
    err = np.asarray(fc.geometry_error(fit_geo, true_geo).normal, float)
    rows = [[plots.normal_to_rgb(true_geo.normal[i], true_geo.mask[i]),
             plots.normal_to_rgb(fit_geo.normal[i], fit_geo.mask[i])] for i in range(len(forecast_frames))]
    strip = plots.contact_sheet(out / "forecast_strip.png", rows, col_titles=["true normals", "forecast normals"],
                                row_titles=[f"frame {f}: {np.degrees(e):.3f} deg" for f, e in
                                            zip(forecast_frames, err)],
                                title=f"forecast of {int(result.n_waves)} fitted waves (mean normal error per frame)")
    chart = _wave_chart(out / "wave_fit.png", truth, result.waves)
    return dict(n_true=n_waves, n_fitted=int(result.n_waves), success=bool(result.success),
                matched=int(match.true_index.size), wall_s_with_compile=wall,
                max_abs_error=dict(amplitude=_max(match.abs_error.amplitude), omega=_max(match.abs_error.omega),
                                   theta=_max(match.abs_error.theta)),
                forecast_frames=list(forecast_frames), forecast_normal_error_deg=np.degrees(err).tolist(),
                figures=[str(chart), str(strip)])


def _max(x):
    x = np.asarray(x)
    return float(np.max(np.abs(x))) if x.size else None


def _wave_chart(path: Path, truth, fitted) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(9, 4))
    ax = fig.add_subplot(1, 2, 1, projection="polar")
    scale = float(np.max(np.asarray(truth.amplitude)))
    for w, marker, label in ((truth, "o", "true"), (fitted, "x", "fitted")):
        ax.scatter(np.asarray(w.theta), np.asarray(w.omega), s=200 * np.asarray(w.amplitude) / scale + 8,
                   marker=marker, label=label, alpha=0.8)
    plots.polar_room(ax, np.concatenate([np.asarray(truth.omega), np.asarray(fitted.omega)]))
    ax.set_title("direction (angle) and omega [rad/s] (radius);\nsize ~ amplitude", fontsize=9)
    ax.legend(fontsize=8, loc="lower left")
    ax = fig.add_subplot(1, 2, 2)
    ax.scatter(np.asarray(truth.omega), np.asarray(truth.amplitude), marker="o", label="true")
    ax.scatter(np.asarray(fitted.omega), np.asarray(fitted.amplitude), marker="x", label="fitted")
    ax.set_xlabel("omega [rad/s]")
    ax.set_ylabel("amplitude [m]")
    ax.legend(fontsize=8)
    ax.set_title("recovered waves against the truth", fontsize=9)
    fig.tight_layout()
    return plots.save_figure(fig, path, dpi=110)


#: the demo's reconstruct settings: small, so that `make demo` stays within a few minutes on a
#: laptop CPU (the command's defaults are larger)
DEMO_RECONSTRUCT = dict(width=64, wave_frames=6, max_waves=8, refine_steps=8, refine_rounds=2)


def reconstruct_stage(out: Path, scene, images) -> dict:
    """Write ``images (T, H, W, 3)`` of ``scene`` as 8-bit PNG frames with a camera-and-times
    ``scene.json`` (no waves, no lighting), reconstruct them, and compare the forecast with
    the truth's (``reconstruct_vs_truth.png``; the re-rendered views are in the reconstruct report)."""
    from jaxocean import fit
    from jaxocean import reconstruct as rc
    from jaxocean.io.images import save_png
    from jaxocean.io.scene import scene_to_dict, write_scene

    frames_dir = out / "png_frames"
    frames_dir.mkdir(parents=True, exist_ok=True)
    files = [save_png(frames_dir / f"frame_{i:05d}.png", img) for i, img in enumerate(np.asarray(images))]
    camera_json = write_scene(frames_dir, scene_to_dict(camera=scene.camera, times=scene.times))
    result = rc.reconstruct(files, camera_json, out=out / "reconstruct", response="bruneton", **DEMO_RECONSTRUCT)
    seq, outlook = result.sequence, result.outlook
    true_fc = fc.forecast(scene.waves, outlook["times"], seq.camera, scene.lighting)
    state = fit.sea_state(scene.waves)
    true_sea = dict(hs=state.hs, tp=state.tp)
    got = result.sea
    sea = ("no sea state" if got["hs_m"] is None or not np.isfinite(got["hs_m"]) else
           f"Hs {got['hs_m']:.2f} m, Tp {got['tp_s']:.1f} s{'' if got['peak_observed'] else ' (bounds)'}")
    rows = [[plots.display(t), plots.display(np.clip(f, 0, None))] for t, f in
            zip(np.asarray(true_fc.image), outlook["forecast"])]
    path = plots.contact_sheet(out / "reconstruct_vs_truth.png", rows, col_titles=["truth", "reconstructed"],
                               row_titles=[f"+{t - float(seq.times[-1]):.0f} s" for t in outlook["times"]],
                               title=f"forecast from 8-bit PNG frames: {sea}; true "
                                     f"{true_sea['hs']:.2f} m, {true_sea['tp']:.1f} s")
    return dict(stages={n: dict(success=r.success, seconds=r.seconds, message=r.message)
                        for n, r in result.stages.items()},
                hs_m=got["hs_m"], tp_s=got["tp_s"], source=got["source"], bound=got["bound"], truth=true_sea,
                report=str(out / "reconstruct" / "report.html"), figure=str(path))


def real_stage(out: Path, clip_dir: Path) -> dict:
    """``reconstruct`` on the frames and camera file in ``clip_dir``; its report in
    ``out/real``."""
    from jaxocean import reconstruct as rc

    result = rc.reconstruct([], Path(clip_dir) / "camera.json", out=out / "real", **DEMO_RECONSTRUCT)
    return dict(stages={n: dict(success=r.success, seconds=r.seconds, message=r.message)
                        for n, r in result.stages.items()},
                hs_m=result.sea["hs_m"], tp_s=result.sea["tp_s"], direction_deg=result.sea["direction_deg"],
                source=result.sea["source"], bound=result.sea["bound"], report=str(out / "real" / "report.html"))
