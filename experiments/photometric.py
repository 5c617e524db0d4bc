"""Photometric refinement (``fit.photometric``): wave and lighting recovery from 8-bit frames.

What it measures, per synthetic scene (:func:`jaxocean.io.dataset.sample_scene` with
``--waves`` (20) wave trains, Hs 0.2-0.8 m, camera 10-30 m high (``--rough``: the dataset's
full ranges), 64^2 pixels, ``--frames`` (8) frames, float32), under three conditions:

* ``rows, sigma 0.01``: frames rendered on the rows path (the fit's own model, exact);
* ``rows, sigma 0``: the same, 8-bit quantisation only;
* ``default plan, sigma 0.01``: frames rendered as the renderer does by default (converged
  hits where the waves move a hit by half a footprint or more: every scene drawn here), so
  the fit's rows model is an approximation.

1. The frames are scaled by a random exposure in [0.5, 2], tone mapped (Bruneton), given
   Gaussian display noise of that sigma and quantised to 8 bits, then brought back to linear
   radiance with the inverse tone map at exposure 1 (the exposure is unknown to the fit).
   Pixels at display value >= 254/255 are masked (saturated).
2. The start: ``fit.waves`` (at most ``--max-waves`` 48) on the scene's true geometry
   (normals, roughness: noise-free, from the same render path), then perturbed -- phases
   +-0.3 rad, omega +-2%, amplitudes +-15%, directions +-0.03 rad (uniform) -- and the true
   lighting perturbed: colours x U(0.8, 1.25) per channel, sun +-2 deg in azimuth and
   elevation (the colours not scaled by the exposure: the fit sets the scale).
3. ``fit.photometric`` (defaults: Cauchy IRLS, 4 rounds of at most 20 LM steps, noise
   estimated from the frames).

Reported: mean absolute errors (h, omega, theta, phase) of the waves matched one to one
(``fit.waves.match``, 10% wave-vector tolerance) to the *resolvable* true waves
(``fit.waves.resolvable``), for ``fit.waves`` on the true geometry, the perturbed start and
the refinement; the lighting error (sun angle, largest relative channel error of exposure x
colour against the true colour x the applied exposure); the success flag and message,
robust scale, estimated noise, image spread, determined slope-energy share, outlier
fraction, steps and seconds (compilation included: the solver compiles once per wave
count; ``warm_seconds`` repeats the first scene's fit).

Usage: ``nice -n 10 python experiments/photometric.py [--scenes 3] [--waves 20] [--frames 8] [--rough]``;
writes ``experiments/results/photometric.json`` and ``photometric.png``.
"""

from __future__ import annotations

import argparse
import math
import sys
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import render, shading  # noqa: E402
from jaxocean.fit import lighting_error  # noqa: E402
from jaxocean.fit import photometric_fit as ph  # noqa: E402
from jaxocean.fit import waves_fit as fw  # noqa: E402
from jaxocean.io import dataset  # noqa: E402
from jaxocean.waves import Waves  # noqa: E402

NAME = "photometric"


def display_frames(images, exposure, noise, rng):
    """8-bit display frames of linear ``images`` at ``exposure`` with Gaussian display noise,
    back to linear radiance at exposure 1; and the unsaturated mask."""
    d = np.asarray(shading.tonemap(jnp.asarray(images) * exposure))
    d = np.clip(np.round((d + noise * rng.standard_normal(d.shape)) * 255.0), 0, 255) / 255.0
    mask = np.all(d < 254.0 / 255.0, axis=-1)
    linear = np.asarray(shading.inverse_tonemap(jnp.asarray(d, jnp.float32)))
    return linear, mask, d


def perturb_waves(w: Waves, rng) -> Waves:
    n = w.omega.shape[0]
    u = lambda s: rng.uniform(-s, s, n).astype(np.float32)  # noqa: E731
    return Waves(w.amplitude * (1 + u(0.15)), w.omega * (1 + u(0.02)), w.theta + u(0.03), w.phase + u(0.3))


def perturb_lighting(light, rng):
    f = lambda: jnp.asarray(np.exp(rng.uniform(math.log(0.8), math.log(1.25), 3)), jnp.float32)  # noqa: E731
    d = math.radians(2.0)
    return light._replace(sun_azimuth=light.sun_azimuth + rng.uniform(-d, d),
                          sun_elevation=light.sun_elevation + rng.uniform(-d, d),
                          sun_color=light.sun_color * f(), sky_color=light.sky_color * f(),
                          sea_color=light.sea_color * f())


def wave_errors(fitted: Waves, truth: Waves) -> dict:
    m = fw.match(fitted, truth)
    e = m.abs_error
    out = dict(matched=int(m.true_index.size), of=int(truth.omega.shape[0]), spurious=int(m.spurious.size))
    for name in Waves._fields:
        v = np.asarray(getattr(e, name))
        out[name] = float(v.mean()) if v.size else None
    return out


def seen_lighting_error(light, exposure, truth, truth_exposure) -> dict:
    e, t = float(exposure), float(truth_exposure)
    fitted = light._replace(sun_color=light.sun_color * e, sky_color=light.sky_color * e, sea_color=light.sea_color * e)
    true = truth._replace(sun_color=truth.sun_color * t, sky_color=truth.sky_color * t, sea_color=truth.sea_color * t)
    return {k: float(v) for k, v in lighting_error(fitted, true).items()}


def run_scene(seed: int, args, figure_data: dict | None) -> dict:
    rng = np.random.default_rng(seed)
    ranges = dataset.SceneRanges(n_waves=args.waves)
    if not args.rough:
        ranges = ranges._replace(hs=(0.2, 0.8), camera_height=(10.0, 30.0))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the sampler's steepness clamp warning
        scene = dataset.sample_scene(jax.random.key(seed), ranges, resolution=(args.size, args.size),
                                     n_frames=args.frames)
    images, geo = dataset.render_scene(scene, plan=None if args.render == "rows" else "auto")
    exposure = float(np.exp(rng.uniform(math.log(0.5), math.log(2.0))))
    linear, mask, display = display_frames(images, exposure, args.noise, rng)
    camera, times, truth = scene.camera, np.asarray(scene.times), scene.waves
    resolvable = np.asarray(fw.resolvable(truth, camera))
    truth_res = Waves(*[x[resolvable] for x in truth])

    t0 = time.perf_counter()
    wf = fw.waves(geo.normal, geo.roughness, camera, times, max_waves=args.max_waves)
    t_waves = time.perf_counter() - t0
    start = perturb_waves(wf.waves, rng)
    light0 = perturb_lighting(scene.lighting, rng)
    result = ph.photometric(linear, camera, times, start, light0, mask=mask, progress=args.verbose)
    row = dict(condition=args.condition, render=args.render, noise_display=args.noise, seed=seed,
               n_true=int(truth.omega.shape[0]), n_resolvable=int(resolvable.sum()),
               n_fitted=int(wf.n_waves), fit_waves_success=bool(wf.success), fit_waves_seconds=t_waves,
               exposure_applied=exposure, masked_fraction=float(1 - mask.mean()),
               plan_refine=int(render.plan(truth, camera).refine),
               waves_fit_waves=wave_errors(wf.waves, truth_res), waves_start=wave_errors(start, truth_res),
               waves_refined=wave_errors(result.waves, truth_res),
               lighting_start=seen_lighting_error(light0, 1.0, scene.lighting, exposure),
               lighting_refined=seen_lighting_error(result.lighting, result.exposure, scene.lighting, exposure),
               **{k: v for k, v in ph.fit_to_dict(result).items() if k not in ("waves", "lighting", "criteria")})
    if figure_data is not None and not figure_data:
        t0 = time.perf_counter()
        again = ph.photometric(linear, camera, times, start, light0, mask=mask)
        row["warm_seconds"] = time.perf_counter() - t0
        row["warm_steps"] = int(again.steps)
        model = np.asarray(ph.rerender(result, camera, times))
        figure_data.update(display=display, model=np.asarray(shading.tonemap(jnp.asarray(model) * exposure)),
                           residual=np.asarray(ph.residual(linear, camera, times, result.waves, result.lighting,
                                                           result.exposure, mask=mask))[..., 1],
                           outliers=np.asarray(result.outliers), mask=mask)
    return row


def plot(rows, fig_data, name):
    plt = benchutil.pyplot()
    fig, axes = plt.subplots(2, 4, figsize=(15, 8))
    t = 0
    panels = [("display frame (8-bit, noise)", fig_data["display"][t], None),
              ("refined model, same tone map", np.clip(fig_data["model"][t], 0, 1), None),
              ("residual log1p(I/s), green", fig_data["residual"][t], "coolwarm"),
              ("outliers (white), masked (gray)", fig_data["outliers"][t] * 1.0 + (~fig_data["mask"][t]) * 0.5, "gray")]
    for ax, (title, img, cmap) in zip(axes[0], panels):
        if cmap == "coolwarm":
            v = max(float(np.percentile(np.abs(img), 99)), 1e-6)
            ax.imshow(img, cmap=cmap, vmin=-v, vmax=v)
        else:
            ax.imshow(img, cmap=cmap, vmin=0, vmax=1)
        ax.set_title(title, fontsize=9)
        ax.axis("off")
    labels = ["fit.waves (true geometry)", "perturbed start", "photometric"]
    keys = ["waves_fit_waves", "waves_start", "waves_refined"]
    for ax, field in zip(axes[1], ("amplitude", "omega", "theta", "phase")):
        x = np.arange(len(rows))
        for j, (lab, key) in enumerate(zip(labels, keys)):
            vals = [r[key][field] if r[key][field] is not None else np.nan for r in rows]
            ax.bar(x + (j - 1) * 0.27, vals, 0.27, label=lab)
        ax.set_yscale("log")
        ax.set_xticks(x, [f"{r['condition']}\nseed {r['seed']}" + ("" if r["success"] else " (failed)")
                          for r in rows], fontsize=6, rotation=90)
        ax.set_title(f"mean |error| of matched resolvable waves: {field}", fontsize=9)
    axes[1][0].legend(fontsize=8)
    benchutil.save_figure(fig, name)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--scenes", type=int, default=3)
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--waves", type=int, default=20)
    p.add_argument("--frames", type=int, default=8)
    p.add_argument("--size", type=int, default=64)
    p.add_argument("--noise", type=float, default=0.01, help="display noise of the noisy conditions")
    p.add_argument("--max-waves", type=int, default=48, help="fit.waves' cap")
    p.add_argument("--rough", action="store_true",
                   help="the dataset's full ranges (Hs 0.3-2.5 m, camera 5-30 m) instead of Hs 0.2-0.8 m, 10-30 m")
    p.add_argument("--out", default=NAME)
    p.add_argument("--verbose", action="store_true")
    args = p.parse_args(argv)
    conditions = [("rows", args.noise), ("rows", 0.0), ("auto", args.noise)]
    rows, fig_data = [], {}
    for render_path, noise in conditions:
        args.render, args.noise = render_path, noise
        args.condition = f"{'rows' if render_path == 'rows' else 'default plan'}, sigma {noise:g}"
        for i in range(args.scenes):
            row = run_scene(args.seed + i, args, fig_data)
            rows.append(row)
            print(f"[{args.condition}] seed {row['seed']}: {row['n_fitted']} waves fitted ({row['n_resolvable']} of "
                  f"{row['n_true']} resolvable), success {row['success']} [{row['message']}], {row['seconds']:.1f} s, "
                  f"{row['steps']} steps; phase err start {row['waves_start']['phase']} -> "
                  f"{row['waves_refined']['phase']}; sun {row['lighting_start']['sun_angle_deg']:.3f} -> "
                  f"{row['lighting_refined']['sun_angle_deg']:.3f} deg", flush=True)
            benchutil.save(args.out, rows, meta=dict(vars(args), conditions=conditions))
    plot(rows, fig_data, args.out)

if __name__ == "__main__":
    main()
