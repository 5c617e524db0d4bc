"""The whole pipeline on held-out synthetic scenes written as 8-bit PNG (issue: reconstruct).

    python experiments/reconstruct.py DATASET [--scenes 3] [--variants clean,noise01,noise03,jpeg]

For each of the first ``--scenes`` scenes of DATASET's test split (a ``jaxocean simulate``
dataset; its scenes were never trained on): ``--frames`` frames rendered at the scene's
camera, tone-mapped with an exposure drawn from [0.5, 2] that the pipeline is not told,
written as 8-bit PNG -- clean, with Gaussian display noise (sigma 0.01 / 0.03 of the display
range, added before quantisation) or JPEG-compressed (quality 85) -- and reconstructed from
the frames and the camera alone (:func:`jaxocean.reconstruct.reconstruct`, response
``bruneton``, the tone curve used). Scored against the truth:

* Table 1 (geometry, stage 2): the network's normals and roughness on the PNG frames --
  mean angle error, within 5 / 10 / 15 deg, slope skill along / across the view, log10 slope
  variance MSE -- beside the flat-normal baseline.
* Table 2 (waves): fitted waves matched one to one to the true *resolvable* waves
  (:func:`jaxocean.fit.match`, relative wave-vector tolerance 0.1): matched count, MAE of h,
  omega, theta, for the stage-4 waves (the paper's two steps) and the stage-5 waves (after
  the photometric refinement), with the paper's Table 2 row; Hs, Tp and direction errors.
* The time of every stage; a chart of wave accuracy against total time per stage set.

Writes ``experiments/results/NAME.json`` and ``.png`` (``--name``, default ``reconstruct``). CPU heavy: about 5-10 minutes
per run on this 2-core machine.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import imageio.v3 as iio
import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"
PAPER_TABLE2 = dict(mae_h=0.00518, mae_omega=0.131, mae_theta=0.227)
VARIANTS = dict(clean=(0.0, False), noise01=(0.01, False), noise03=(0.03, False), jpeg=(0.0, True))


def _write_frames(folder: Path, images, exposure: float, noise: float, jpeg: bool, rng) -> list:
    from jaxocean import shading

    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for i, img in enumerate(np.asarray(images)):
        display = np.asarray(shading.tonemap(img, exposure))
        display = np.clip(display + noise * rng.standard_normal(display.shape), 0, 1)
        codes = np.round(display * 255).astype(np.uint8)
        path = folder / f"frame_{i:05d}.{'jpg' if jpeg else 'png'}"
        if jpeg:
            iio.imwrite(path, codes, extension=".jpg", quality=85)
        else:
            iio.imwrite(path, codes)
        files.append(path)
    return files


def _wave_scores(fitted, truth, camera) -> dict:
    from jaxocean import fit

    keep = np.asarray(fit.resolvable(truth, camera))
    true_res = type(truth)(*(np.asarray(x)[keep] for x in truth))
    # a wave of zero amplitude is no wave (the flat sea a stage hands on when it found none)
    real = np.asarray(fitted.amplitude) > 0
    fitted = type(fitted)(*(np.asarray(x)[real] for x in fitted))
    m = fit.match(fitted, true_res)
    n = int(m.true_index.size)
    err = m.abs_error
    mae = (lambda x: float(np.mean(np.abs(np.asarray(x)))) if n else None)
    return dict(resolvable=int(keep.sum()), fitted=int(np.asarray(fitted.omega).size), matched=n,
                mae_h=mae(err.amplitude), mae_omega=mae(err.omega), mae_theta=mae(err.theta))


def _geometry_scores(pred, truth_geo, camera) -> dict:
    import jax.numpy as jnp

    from jaxocean.nn import metrics

    mask = jnp.asarray(truth_geo.mask)
    yaw = jnp.broadcast_to(jnp.asarray(camera.yaw, jnp.float32), mask.shape[:1])
    out = {}
    for name, normal in (("net", pred.normal), ("flat", np.broadcast_to([0.0, 0.0, 1.0], pred.normal.shape))):
        sums = metrics.normal_scores(jnp.asarray(normal, jnp.float32), jnp.asarray(truth_geo.normal), mask, yaw)
        if name == "net":
            sums.update(metrics.roughness_scores(jnp.asarray(pred.slope_variance), jnp.asarray(truth_geo.slope_variance),
                                                 mask, 1e-6))
        out[name] = {k: v for k, v in metrics.finish(sums).items()
                     if k in ("normal_mae", "within_5deg", "within_10deg", "within_15deg", "skill_along",
                              "skill_across", "log_slope_variance_mse")}
    return out


def _sea_errors(sea: dict, truth_waves, spectrum) -> dict:
    from jaxocean import fit
    from jaxocean.reconstruct import direction_deg

    true_dir = direction_deg(float(spectrum.theta_mean), False)
    d = (sea["direction_deg"] - true_dir + 180) % 360 - 180
    return dict(hs=sea["hs_m"], hs_true=float(spectrum.hs), tp=sea["tp_s"], tp_true=float(spectrum.tp),
                direction_error_deg=float(d), peak_observed=sea["peak_observed"],
                waves_hs_true=float(fit.sea_state(truth_waves).hs))


def run_one(dataset, index: int, variant: str, work: Path, *, frames: int, dt: float, seed: int,
            geometry_model=None) -> dict:
    import jax

    from jaxocean import render
    from jaxocean import reconstruct as rc
    from jaxocean.io.scene import read_scene, scene_to_dict, write_scene

    scene = read_scene(Path(dataset) / f"scene_{index:05d}" / "scene.json")
    times = np.arange(frames) * dt
    rng = np.random.default_rng(seed + index)
    exposure = float(np.exp(rng.uniform(np.log(0.5), np.log(2.0))))
    images = np.stack([np.asarray(render.render(scene.waves, scene.camera, scene.lighting, t)) for t in times])
    geo = jax.tree.map(lambda *xs: np.stack(xs),
                       *[render.geometry(scene.waves, scene.camera, t) for t in times])
    noise, jpeg = VARIANTS[variant]
    folder = work / f"scene_{index:05d}_{variant}"
    files = _write_frames(folder, images, exposure, noise, jpeg, rng)
    camera_json = write_scene(folder, scene_to_dict(camera=scene.camera, times=times))
    t0 = time.perf_counter()
    result = rc.reconstruct(files, camera_json, out=folder / "out", response="bruneton", progress=True,
                            wave_frames=min(frames, 8), max_waves=16, geometry_model=geometry_model)
    wall = time.perf_counter() - t0
    stages = {n: dict(success=r.success, seconds=r.seconds) for n, r in result.stages.items()}
    row = dict(scene=index, variant=variant, geometry_model=geometry_model or "cpu", exposure=exposure, wall_s=wall,
               stages=stages,
               table1=_geometry_scores(result.geometry, geo, scene.camera),
               stage4=_wave_scores(result.waves.waves, scene.waves, scene.camera),
               # stage 5's waves whether or not it reported success (its flag is in stages)
               final=_wave_scores(result.photometric.waves if result.photometric is not None
                                  else result.sea["waves"], scene.waves, scene.camera),
               sea=_sea_errors(result.sea, scene.waves, scene.spectrum),
               dispersion_ratio=(result.sea.get("dispersion") or {}).get("ratio"))
    return row


def _chart(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxocean import plots

    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    for ax, key, label in ((axes[0], "mae_h", "MAE h [m]"), (axes[1], "mae_omega", "MAE omega [rad/s]")):
        for which, marker, stage_names in (("stage4", "o", ("radiometry", "geometry", "lighting", "waves")),
                                           ("final", "s", None)):
            xs, ys = [], []
            for r in rows:
                names = stage_names or tuple(r["stages"])
                xs.append(sum(r["stages"][n]["seconds"] for n in names if n in r["stages"]))
                ys.append(r[which][key] if r[which][key] is not None else np.nan)
            ax.scatter(xs, ys, marker=marker, label="stages 1-4 (two-step)" if which == "stage4" else
                       "stages 1-6 (with photometric refinement)")
        ax.axhline(PAPER_TABLE2[key], color="k", ls="--", label="paper Table 2")
        ax.set_xlabel("pipeline time per scene [s] (this 2-core CPU)")
        ax.set_ylabel(label)
        ax.set_yscale("log")
        ax.legend(fontsize=7)
    fig.suptitle("reconstruct on 8-bit PNG frames: wave accuracy (matched resolvable waves) against time")
    fig.tight_layout()
    return plots.save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("dataset")
    ap.add_argument("--scenes", type=int, default=3)
    ap.add_argument("--variants", default="clean,noise01,noise03,jpeg")
    ap.add_argument("--frames", type=int, default=32)
    ap.add_argument("--dt", type=float, default=0.25)
    ap.add_argument("--work", default=None, help="folder for the frames and each run's outputs (default "
                    "out/reconstruct_experiment/NAME, so runs under other names never overwrite each other)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--name", default="reconstruct", help="results file stem (finished runs in it are kept when "
                    "they were made with the same settings; --fresh redoes them)")
    ap.add_argument("--fresh", action="store_true", help="ignore the finished runs in the results file")
    ap.add_argument("--geometry-model", default=None, help="stage 2's network: a shipped model's name (cpu, gpu) or "
                    "a model file (default: reconstruct's default, cpu)")
    args = ap.parse_args(argv)
    splits = json.loads((Path(args.dataset) / "splits.json").read_text())
    scenes = splits["test"][: args.scenes]
    out_json = RESULTS / f"{args.name}.json"
    work = Path(args.work or f"out/reconstruct_experiment/{args.name}")
    settings = dict(dataset=str(args.dataset), frames=args.frames, dt=args.dt, seed=args.seed,
                    geometry_model=args.geometry_model)
    rows = []
    if out_json.exists() and not args.fresh:  # resume: keep the finished runs made with these settings
        previous = json.loads(out_json.read_text())
        if previous.get("settings") != settings:
            sys.exit(f"{out_json} holds runs made with other settings ({previous.get('settings')}, now {settings}): "
                     f"pass --fresh to redo them, or another --name")
        rows = previous.get("rows", [])
        print(f"keeping {len(rows)} finished run(s) from {out_json} (--fresh redoes them)", flush=True)
    done = {(r["scene"], r["variant"]) for r in rows}
    for index in scenes:
        for variant in args.variants.split(","):
            if (index, variant) in done:
                continue
            print(f"--- scene {index} {variant}", flush=True)
            rows.append(run_one(args.dataset, index, variant, work, frames=args.frames, dt=args.dt,
                                seed=args.seed, geometry_model=args.geometry_model))
            RESULTS.mkdir(exist_ok=True)
            out_json.write_text(json.dumps(dict(settings=settings, paper_table2=PAPER_TABLE2, rows=rows), indent=1))
    _chart(rows, RESULTS / f"{args.name}.png")
    print(json.dumps(rows, indent=1))


if __name__ == "__main__":
    sys.exit(main())
