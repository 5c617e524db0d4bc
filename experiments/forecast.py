"""Forecast: how long fitted waves keep predicting the ocean (the paper's Fig. 13).

For each scene of ``experiments/results/wave_fit.json`` (section ``table2``: dataset scenes,
128^2, 10 observed frames, waves fitted by ``fit.waves``; or, with ``--fit``, scenes fitted
here), the fitted waves are advanced to frames 0 ... 500 on the observed clock
(:func:`jaxocean.forecast.frame_times`) and their geometry re-rendered with the scene's
camera; the true geometry at the same times comes from the true 60 waves. Metric: the mean
normal angle over sea pixels (:func:`jaxocean.forecast.geometry_error`). Baseline:
*persistence* (the observed frame 0 held still for every later frame) shows how fast the
sea decorrelates. Targets: the error at frames 100 and 500 below half of persistence on
every scene (``met.persistence``), and within 2x of frame 0 (``met.frame0``).

Where a row holds the fitted long-wave band (``band_waves``), the forecast of the fitted waves
*and* the band's stand-ins together is scored too (``normal_error_with_band_rad``).

Usage: ``python experiments/forecast.py [--frames 0,10,50,100,200,500] [--section table2_slopes]
[--fit --scenes N | --fit --seeds 1,4] [--name STEM]``; writes
``experiments/results/forecast.json`` and ``forecast.png`` (``forecast_slopes.*`` for
``--section table2_slopes``: the waves of ``fit.waves(heights=False)``; ``STEM.*`` with
``--name``).
"""

from __future__ import annotations

import argparse
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402
import wave_fit  # noqa: E402

from jaxocean import fit  # noqa: E402
from jaxocean import forecast as fc  # noqa: E402

TARGET_RATIO = 2.0  # to frame 0
TARGET_PERSISTENCE = 0.5  # to persistence


def scene_rows(args):
    if not args.fit:
        rows = benchutil.load_rows("wave_fit", {}).get(args.section, {}).get("scenes", [])
        rows = [r for r in rows if "fitted_waves" in r]
        if rows:
            return rows[: args.scenes or None]
        print("no fitted waves in wave_fit.json: fitting here")
    rows = []
    seeds = [int(s) for s in args.seeds.split(",") if s] or list(range(args.scenes or 2))
    for seed in seeds:
        scene, geo = wave_fit.dataset_scene(seed, args.resolution)
        r = fit.waves(geo.normal, geo.roughness, scene.camera, scene.times,
                      heights=args.section == "table2")
        row = dict(seed=seed, resolution=args.resolution, success=bool(r.success),
                   fitted_waves=benchutil.waves_to_json(r.waves))
        if r.long_waves is not None:
            row["band_waves"] = benchutil.waves_to_json(r.long_waves.waves)
        rows.append(row)
    return rows


def one_scene(row, frames):
    scene, geo = wave_fit.dataset_scene(row["seed"], row["resolution"])
    fitted = benchutil.waves_from_json(row["fitted_waves"])
    times = jnp.asarray(fc.frame_times(np.asarray(scene.times), frames), jnp.float32)
    truth = fc.forecast(scene.waves, times, scene.camera).geometry
    pred = fc.forecast(fitted, times, scene.camera).geometry
    err = fc.geometry_error(pred, truth)
    frame0 = jax.tree.map(lambda x: jnp.broadcast_to(x[:1], x.shape), truth)
    persistence = fc.geometry_error(frame0, truth)
    normal = np.asarray(err.normal, float)
    out = dict(seed=row["seed"], frames=list(map(int, frames)), times=np.asarray(times, float).tolist(),
               normal_error_rad=normal.tolist(), roughness_error=np.asarray(err.roughness, float).tolist(),
               ratio_to_frame0=(normal / normal[0]).tolist(),
               persistence_rad=np.asarray(persistence.normal, float).tolist())
    if "band_waves" in row:
        # the fitted waves and the long-wave band's stand-ins together: everything the fit
        # explained at frame 0, advanced by the band waves' own dispersion
        band = benchutil.waves_from_json(row["band_waves"])
        both = jax.tree.map(lambda a, b: jnp.concatenate([a, b]), fitted, band)
        err_b = fc.geometry_error(fc.forecast(both, times, scene.camera).geometry, truth)
        out["normal_error_with_band_rad"] = np.asarray(err_b.normal, float).tolist()
    return out


def plot(rows, name):
    plt = benchutil.pyplot()

    fig, ax = plt.subplots(figsize=(7, 4.2))
    for i, r in enumerate(rows):
        f = np.maximum(np.asarray(r["frames"]), 0.5)
        ax.plot(f, np.degrees(r["normal_error_rad"]), "o-", color=f"C{i}", label=f"forecast, scene {r['seed']}")
        ax.plot(f[1:], np.degrees(r["persistence_rad"][1:]), "x:", color=f"C{i}", label=f"persistence, scene {r['seed']}")
    ax.set(xscale="log", xlabel="frame (frame 0 plotted at 0.5)", ylabel="mean normal error [deg]",
           title="forecast error against horizon (Fig. 13 redone)")
    ax.legend(fontsize=7)
    benchutil.save_figure(fig, name)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--frames", default="0,10,50,100,200,500")
    parser.add_argument("--fit", action="store_true", help="fit the scenes here instead of reading wave_fit.json")
    parser.add_argument("--scenes", type=int, default=0)
    parser.add_argument("--seeds", default="", help="--fit: comma-separated scene seeds (default 0..scenes-1)")
    parser.add_argument("--name", default="", help="results file stem (default forecast, or forecast_slopes for "
                        "--section table2_slopes)")
    parser.add_argument("--resolution", type=int, default=128)
    parser.add_argument("--section", default="table2", choices=("table2", "table2_slopes"),
                        help="which Table 2 run of wave_fit.json to forecast from")
    args = parser.parse_args(argv)
    name = args.name or ("forecast" if args.section == "table2" else "forecast_slopes")
    frames = [int(f) for f in args.frames.split(",")]
    if frames[0] != 0:
        parser.error("--frames must start with 0 (the reference frame)")
    rows = [one_scene(r, frames) for r in scene_rows(args)]
    for r in rows:
        band = r.get("normal_error_with_band_rad", [float("nan")] * len(r["frames"]))
        benchutil.print_table([dict(seed=r["seed"], frame=f, err_deg=float(np.degrees(e)), ratio=q,
                                    with_band_deg=float(np.degrees(b)), persistence_deg=float(np.degrees(p)))
                               for f, e, q, b, p in zip(r["frames"], r["normal_error_rad"], r["ratio_to_frame0"],
                                                        band, r["persistence_rad"])],
                              ["seed", "frame", "err_deg", "ratio", "with_band_deg", "persistence_deg"])
    horizons = [f for f in (100, 500) if f in frames]
    worst = {f: max(r["ratio_to_frame0"][r["frames"].index(f)] for r in rows) for f in horizons}
    worst_persistence = {f: max(r["normal_error_rad"][r["frames"].index(f)] / r["persistence_rad"][r["frames"].index(f)]
                                for r in rows) for f in horizons}
    summary = dict(worst_ratio=worst, worst_ratio_to_persistence=worst_persistence,
                   met=dict(frame0={str(f): v <= TARGET_RATIO for f, v in worst.items()},
                            persistence={str(f): v < TARGET_PERSISTENCE for f, v in worst_persistence.items()}))
    print(summary)
    benchutil.save(name, dict(scenes=rows, summary=summary),
                   meta=dict(section=args.section, target_ratio=TARGET_RATIO, target_persistence=TARGET_PERSISTENCE))
    plot(rows, name)


if __name__ == "__main__":
    main()
