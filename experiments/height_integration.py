"""Heights from normals (:func:`jaxocean.fit.heights`) on the Table 2 dataset scenes.

What it measures, per scene and frame (noise-free geometry as the dataset writes it, 128²,
10 frames, :func:`wave_fit.dataset_scene`; the truth from ``render.geometry``'s converged
hits):

* the height error [m rms over valid pixels] after removing its mean: what the normals
  determine;
* that mean, the window's *level* (the true mean height over the valid pixels): what they
  do not;
* the distance [m rms] from each pixel's true hit to three estimates of it: the mean-sea-plane
  hit (what the rows path of ``fit.waves`` assumes), the integrated hit, and the integrated
  hit moved along its ray by the true level (what a model of the level would add);
* the same three against the pixel's true *rest* position (the trochoid's own coordinates,
  which a wave model evaluates at): the horizontal displacement of the waves is left in;
* the time per frame.

With ``--steps``, instead, why the integration goes wrong on steep seas (first frame of each
scene, pixels of footprint at most 1 m, the ones ``fit.waves`` uses):

* the rms slope, and the misfit of the integration's own equations at the *true* hits and
  heights (each neighbouring pair held to its mean slope times the distance between its
  hits), in slope units, between pixels along the view (down the image's columns): its rms,
  and its mean, which tilts the heights;
* a defect correction: the integration's error on a model of the sea (its normals'
  integrated heights less its heights at its hits) taken off the data's heights, with the
  model all the true waves, the resolvable ones, the separable ones, or the 10 / 20 / 30
  steepest (``k h``): how good the correction is as a function of how much of the sea a
  fit would hold.

Usage: ``python experiments/height_integration.py [--scenes N] [--steps]``; writes
``experiments/results/height_integration.json`` and ``.png`` (``--steps``:
``height_integration_steps.json`` and ``.png``).
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402
from wave_fit import dataset_scene  # noqa: E402

from jaxocean import camera as cam  # noqa: E402
from jaxocean import fit, render  # noqa: E402
from jaxocean.fit.waves import resolvable, separable  # noqa: E402
from jaxocean.waves import steepness  # noqa: E402

NAME = "height_integration"
STEPS_NAME = "height_integration_steps"
USED_FOOTPRINT = 1.0  # [m]: where fit.waves holds the model to the heights (HEIGHT_FOOTPRINT)
STEEPEST = (10, 20, 30)
NEAR_FOOTPRINT = 0.5  # [m]: the near field, where the pixels sample the resolved waves finely


def rms(e, ok):
    return float(np.sqrt(np.mean(np.sum(np.atleast_3d(e) ** 2, -1)[ok])))


def _errors(hm, i, true, ok, plane, q) -> dict:
    pos = np.asarray(true.position, np.float64)
    rest = np.asarray(true.xy, np.float64)
    z = np.asarray(hm.z[i], np.float64)
    level = float(np.mean(pos[..., 2][ok]))
    err = (z - pos[..., 2])[ok]
    xy = np.asarray(hm.xy[i], np.float64)
    leveled = xy + (level - float(np.mean(z[ok]))) * q
    return dict(z_error_m=float(np.sqrt(np.mean((err - err.mean()) ** 2))), level_m=level,
                level_error_m=float(err.mean()), z_std_m=float(np.std(pos[..., 2][ok])),
                hit_error_plane_m=rms(plane - pos[..., :2], ok), hit_error_integrated_m=rms(xy - pos[..., :2], ok),
                hit_error_leveled_m=rms(leveled - pos[..., :2], ok),
                rest_error_plane_m=rms(plane - rest, ok), rest_error_integrated_m=rms(xy - rest, ok),
                rest_error_leveled_m=rms(leveled - rest, ok), pixels=int(ok.sum()),
                converged=bool(hm.converged[i]), residual=float(hm.residual[i]))


def measure(seed: int) -> dict:
    scene, geo = dataset_scene(seed, 128)
    camera = scene.camera
    hm = jax.block_until_ready(fit.heights(geo.normal, camera))  # compiles
    t0 = time.perf_counter()
    hm = jax.block_until_ready(fit.heights(geo.normal, camera))
    seconds = (time.perf_counter() - t0) / len(scene.times)
    plane = np.asarray(cam.intersect_sea(camera).xy, np.float64)
    _, direction = cam.pixel_rays(camera)
    d = np.asarray(direction, np.float64)
    q = d[..., :2] / np.where(np.abs(d[..., 2:3]) > 1e-9, d[..., 2:3], -1.0)
    footprint = np.asarray(cam.intersect_sea(camera).footprint, np.float64)
    frames = []
    for i, t in enumerate(np.asarray(scene.times)):
        true = render.geometry(scene.waves, camera, t)
        valid = np.asarray(hm.valid[i]) & np.asarray(true.converged) & np.asarray(true.mask)
        frame = {}
        for region, ok in (("near", valid & (footprint <= NEAR_FOOTPRINT)), ("all", valid)):
            frame.update({f"{region}_{k}" if k.endswith("_m") or k == "pixels" else k: v for k, v in
                          _errors(hm, i, true, ok, plane, q).items()})
        frames.append(frame)
    summary = {k: float(np.median([f[k] for f in frames])) for k in frames[0] if k.endswith(("_m", "pixels"))}
    return dict(seed=seed, hs=float(scene.spectrum.hs),
                camera_height=float(camera.height), camera_pitch=float(camera.pitch),
                seconds_per_frame=seconds, all_converged=all(f["converged"] for f in frames),
                median=summary, frames=frames)


def measure_steps(seed: int) -> dict:
    scene, geo = dataset_scene(seed, 128)
    camera, t = scene.camera, float(np.asarray(scene.times)[0])
    hit = cam.intersect_sea(camera)
    sea = np.asarray(hit.mask)
    footprint = np.where(sea, np.asarray(hit.footprint, np.float64), np.inf)
    true = render.geometry(scene.waves, camera, t)
    pos = np.asarray(true.position, np.float64)
    normal = np.asarray(geo.normal[0], np.float64)
    data = fit.heights(geo.normal[0], camera)
    z_data = np.asarray(data.z, np.float64)
    used = np.asarray(data.valid) & np.asarray(true.converged) & sea & (footprint <= USED_FOOTPRINT)
    row = dict(seed=seed, hs=float(scene.spectrum.hs), error_m=float(np.std((z_data - pos[..., 2])[used])))
    slope = -normal[..., :2] / normal[..., 2:3]
    row["slope_rms"] = float(np.sqrt(np.mean(np.sum(slope[used] ** 2, -1))))
    # the integration's equations between vertical neighbours at the true hits, in slope units
    # (over the pair's mean-sea-plane spacing, as fit.heights weighs them)
    pair = used[1:] & used[:-1]
    step = np.sum(0.5 * (slope[1:] + slope[:-1]) * (pos[1:, :, :2] - pos[:-1, :, :2]), -1)
    spacing = np.linalg.norm(np.asarray(hit.xy)[1:] - np.asarray(hit.xy)[:-1], axis=-1)
    misfit = ((pos[1:, :, 2] - pos[:-1, :, 2] - step) / np.where(pair, spacing, 1.0))[pair]
    row["step_misfit_rms"] = float(np.sqrt(np.mean(misfit ** 2)))
    row["step_misfit_mean"] = float(np.mean(misfit))
    kh = np.asarray(steepness(scene.waves))
    models = {"all": np.ones(kh.shape, bool), "resolvable": np.asarray(resolvable(scene.waves, camera)),
              "separable": np.asarray(separable(scene.waves, camera, scene.times))}
    for k in STEEPEST:
        models[f"steepest_{k}"] = np.isin(np.arange(kh.size), np.argsort(-kh)[:k])
    for name, keep in models.items():
        model = jax.tree.map(lambda a: a[np.flatnonzero(keep)], scene.waves)
        g = render.geometry(model, camera, t, plan=render.full_plan(int(keep.sum()), 8))
        own = fit.heights(np.where(np.asarray(g.converged)[..., None], np.asarray(g.normal), np.nan), camera)
        defect = np.asarray(own.z, np.float64) - np.asarray(g.position[..., 2], np.float64)
        ok = used & np.asarray(own.valid) & np.asarray(g.converged)
        row[f"corrected_{name}_m"] = float(np.std((z_data - defect - pos[..., 2])[ok]))  # level free
        row[f"waves_{name}"] = int(keep.sum())
    return row


def chart_steps(rows) -> None:
    plt = benchutil.pyplot()
    fig, ax = plt.subplots(figsize=(9, 4))
    x = np.arange(len(rows))
    keys = ["error_m"] + [f"corrected_{n}_m" for n in
                          ["all", "resolvable", "separable"] + [f"steepest_{k}" for k in reversed(STEEPEST)]]
    w = 0.8 / len(keys)
    for j, key in enumerate(keys):
        label = "as integrated" if key == "error_m" else "corrected by: " + key[10:-2].replace("_", " ")
        ax.bar(x + (j - len(keys) / 2 + 0.5) * w, [r[key] for r in rows], w, label=label)
    ax.set_yscale("log")
    ax.set_xticks(x, [f"{r['seed']}\nslope {r['slope_rms']:.2f}" for r in rows])
    ax.set_xlabel("Table 2 scene (seed), rms slope")
    ax.set_ylabel(f"height error [m rms], footprint <= {USED_FOOTPRINT} m")
    ax.set_title("integrated heights, and less the integration's error on a model of the sea")
    ax.legend(fontsize=7)
    benchutil.save_figure(fig, STEPS_NAME)


def chart(rows) -> None:
    plt = benchutil.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(rows))
    labels = [f"{r['seed']}" for r in rows]
    ax = axes[0]
    for key, label in (("all_z_std_m", "height std (truth)"), ("all_level_m", "|window level| (lost)"),
                       ("near_z_error_m", "height error after the level: near field"),
                       ("all_z_error_m", "the same: every pixel")):
        vals = [abs(r["median"][key]) for r in rows]
        ax.semilogy(x, vals, "o-", label=label)
    ax.set_xticks(x, labels)
    ax.set_xlabel("Table 2 scene (seed)")
    ax.set_ylabel("m (median over 10 frames)")
    ax.set_title("heights from normals")
    ax.legend(fontsize=8)
    ax = axes[1]
    w = 0.13
    for j, (key, label) in enumerate((("near_hit_error_plane_m", "hit: plane"),
                                      ("near_hit_error_integrated_m", "hit: integrated"),
                                      ("near_hit_error_leveled_m", "hit: integrated + true level"),
                                      ("near_rest_error_plane_m", "rest: plane"),
                                      ("near_rest_error_integrated_m", "rest: integrated"),
                                      ("near_rest_error_leveled_m", "rest: integrated + true level"))):
        ax.bar(x + (j - 2.5) * w, [r["median"][key] for r in rows], w, label=label)
    ax.set_xticks(x, labels)
    ax.set_xlabel("Table 2 scene (seed)")
    ax.set_ylabel("position error [m rms]")
    ax.set_title(f"where each ray meets the sea (footprint <= {NEAR_FOOTPRINT} m)")
    ax.legend(fontsize=7)
    benchutil.save_figure(fig, NAME)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=8)
    parser.add_argument("--steps", action="store_true", help="the integration's step misfit and its defect correction")
    args = parser.parse_args(argv)
    rows = []
    if args.steps:
        for seed in range(args.scenes):
            rows.append(measure_steps(seed))
            r = rows[-1]
            print(f"scene {seed}: slope rms {r['slope_rms']:.3f}; step misfit rms {r['step_misfit_rms']:.4f} mean "
                  f"{r['step_misfit_mean']:+.4f}; error {r['error_m']:.4f} m, corrected: "
                  + ", ".join(f"{k[10:-2]} {v:.4f}" for k, v in r.items() if k.startswith("corrected_")), flush=True)
            benchutil.save(STEPS_NAME, rows)
        chart_steps(rows)
        return
    for seed in range(args.scenes):
        rows.append(measure(seed))
        m = rows[-1]["median"]
        print(f"scene {seed}: z err near {m['near_z_error_m']:.4f} all {m['all_z_error_m']:.4f} m "
              f"(std {m['all_z_std_m']:.3f}, level {m['all_level_m']:+.3f}, level err near "
              f"{m['near_level_error_m']:+.3f}); near hit err plane {m['near_hit_error_plane_m']:.3f} "
              f"integrated {m['near_hit_error_integrated_m']:.3f} +level {m['near_hit_error_leveled_m']:.3f}; "
              f"near rest err plane {m['near_rest_error_plane_m']:.3f} integrated "
              f"{m['near_rest_error_integrated_m']:.3f}; near pixels {m['near_pixels']:.0f}; "
              f"{rows[-1]['seconds_per_frame'] * 1e3:.0f} ms/frame", flush=True)
        benchutil.save(NAME, rows)
    chart(rows)


if __name__ == "__main__":
    main()
