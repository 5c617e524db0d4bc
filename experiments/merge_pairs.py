"""Merging close pairs of fitted waves (``fit.waves(merge_separation=...)``) on Table 2's fits.

Two sections, both from the fitted waves that ``wave_fit.py --only table2`` saved in
``experiments/results/wave_fit.json``:

1. ``offline``: for the successful scenes of the rows ``table2`` (the default) and
   ``table2_exact_heights_stall`` (``exact_height_block=True, stall_rtol=2e-3``), every pair of
   fitted waves closer than 0.25 / 0.5 Rayleigh limits merged by ``merge_close_pairs`` (the
   pair's coherent sum where the data see it) *without* a refit, and scored as Table 2 scores
   (``wave_fit.score_waves``): what the merge alone does to the count and the amplitudes.
2. ``refit``: ``fit.waves(init=<the saved exact-block fit>, exact_height_block=True,
   stall_rtol=2e-3, merge_separation=0.5)`` on the scenes given: the saved waves refined
   (the band refitted from zero), the final refinement, the merge, its refit, kept if the
   criterion does not get worse (if not, the closest half of the pairs, then the closest
   quarter: ``merge_tries`` refits at most; rows without that field merged all at once
   only); scored the same way.

Usage: ``python experiments/merge_pairs.py [--only offline,refit] [--seeds 3,4]
[--separation 0.5] [--resume]``; writes ``experiments/results/merge_pairs.json`` (sections
merged into an existing file) and ``merge_pairs.png``.
"""

from __future__ import annotations

import argparse
import sys
import time

import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402
import wave_fit  # noqa: E402

from jaxocean import fit, hierarchy  # noqa: E402
from jaxocean.fit.waves._prune import merge_close_pairs  # noqa: E402
from jaxocean.fit.waves._select import MERGE_TRIES  # noqa: E402

NAME = "merge_pairs"
SOURCES = ("table2", "table2_exact_heights_stall")
LIMITS = (0.25, 0.5)
COLUMNS = ("n_fitted", "fitted_over_separable", "n_matched", "n_separable_matched", "mae_amplitude",
           "mae_amplitude_separable", "mae_omega_separable", "mae_theta_separable")


def saved_rows(key):
    return {r["seed"]: r for r in benchutil.load_rows("wave_fit")[key]["scenes"]}


def scores(waves, determined, scene) -> dict:
    s = wave_fit.score_waves(waves, determined, scene)
    s["n_fitted"] = int(np.asarray(waves.omega).size)
    return {k: s[k] for k in COLUMNS}


def section_offline(out):
    rows = []
    for key in SOURCES:
        for seed, row in sorted(saved_rows(key).items()):
            if not row["success"]:
                continue
            scene, _ = wave_fit.dataset_scene(seed, row["resolution"])
            w = benchutil.waves_from_json(row["fitted_waves"])
            det = np.asarray(row["fitted_determined"], bool)
            entry = dict(source=key, seed=seed, saved=scores(w, det, scene))
            for limit in LIMITS:
                merged, n = merge_close_pairs(w, scene.camera, scene.times, hierarchy.DEFAULT_N_MAX, limit)
                det_m = wave_fit.fw.separable(merged, scene.camera, scene.times)
                entry[f"merged_{limit:g}"] = dict(n_merges=n, **scores(merged, det_m, scene))
            rows.append(entry)
            print(key, seed, {k: (v["n_fitted"], round(v["mae_amplitude_separable"], 6)) for k, v in entry.items()
                              if isinstance(v, dict)}, flush=True)
    out["offline"] = rows


def section_refit(args, out):
    rows = [r for r in out.get("refit", []) if args.resume]
    done = {(r["seed"], r["merge_separation"]) for r in rows}
    saved = saved_rows("table2_exact_heights_stall")
    for seed in args.seeds:
        if (seed, args.separation) in done:
            continue
        row = saved[seed]
        scene, geo = wave_fit.dataset_scene(seed, row["resolution"])
        init = benchutil.waves_from_json(row["fitted_waves"])
        t0 = time.perf_counter()
        res = fit.waves(geo.normal, geo.roughness, scene.camera, scene.times, init=init, exact_height_block=True,
                        stall_rtol=2e-3, merge_separation=args.separation, verbose=True)
        det = np.asarray(res.determined, bool)
        entry = dict(seed=seed, merge_separation=args.separation, merge_tries=MERGE_TRIES,
                     n_init=int(np.asarray(init.omega).size),
                     success=bool(res.success), normal_error_rad=float(res.normal_error),
                     saved_normal_error_rad=row["normal_error_rad"], time_s=time.perf_counter() - t0,
                     saved=scores(init, np.asarray(row["fitted_determined"], bool), scene),
                     refit=scores(res.waves, det, scene),
                     fitted_waves=benchutil.waves_to_json(res.waves), fitted_determined=det.tolist())
        entry["refit"].update(wave_fit.score_sea_both(res.waves, det, scene, geo))
        rows.append(entry)
        print({k: entry[k] for k in ("seed", "n_init", "success", "normal_error_rad", "time_s")}, entry["refit"],
              flush=True)
        if args.resume:  # keep what runs on other seeds saved meanwhile
            mine = {(r["seed"], r["merge_separation"]) for r in rows}
            saved_out = benchutil.load_rows(NAME, {}) or {}
            rows += [r for r in saved_out.get("refit", []) if (r["seed"], r["merge_separation"]) not in mine]
            out.update({k: v for k, v in saved_out.items() if k != "refit"})
        out["refit"] = rows
        benchutil.save(NAME, out)


def plot(out):
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(11, 3.8))
    offline = out.get("offline", [])
    for ax, col, label in ((axes[0], "mae_amplitude_separable", "MAE h, separable true waves [m]"),
                           (axes[1], "fitted_over_separable", "fitted / separable")):
        labels = []
        for x, e in enumerate(offline):
            labels.append(f"{'exact' if e['source'] != 'table2' else 'default'}\n{e['seed']}")
            ax.plot([x], [e["saved"][col]], "ko", ms=5, label="saved fit" if x == 0 else None)
            for limit, mark in zip(LIMITS, ("s", "^")):
                ax.plot([x], [e[f"merged_{limit:g}"][col]], mark, color="C0" if limit == LIMITS[0] else "C1",
                        label=f"merged < {limit:g} Rayleigh, no refit" if x == 0 else None)
        for r in out.get("refit", []):
            i = next((j for j, e in enumerate(offline) if e["source"] == SOURCES[1] and e["seed"] == r["seed"]), None)
            if i is not None:
                ax.plot([i], [r["refit"][col]], "*", color="C3", ms=11,
                        label=f"merged < {r['merge_separation']:g} and refitted" if r is out["refit"][0] else None)
        ax.set_xticks(range(len(offline)), labels, fontsize=7)
        ax.set_ylabel(label)
        if col == "mae_amplitude_separable":
            ax.set_yscale("log")
            ax.axhline(5e-4, color="k", ls=":", lw=1, label="target 5e-4 m")
        else:
            ax.axhline(1.5, color="k", ls=":", lw=1, label="target 1.5x")
        ax.legend(fontsize=7)
    fig.suptitle("Merging close pairs of fitted waves (Table 2's successful scenes; default and exact-block fits)")
    benchutil.save_figure(fig, NAME)


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--only", default="offline,refit")
    parser.add_argument("--seeds", default="3,4", help="refit: comma-separated Table 2 scene seeds")
    parser.add_argument("--separation", type=float, default=0.5, help="refit: merge_separation")
    parser.add_argument("--resume", action="store_true")
    args = parser.parse_args()
    args.seeds = [int(s) for s in args.seeds.split(",") if s]
    out = benchutil.load_rows(NAME, {}) or {}
    only = set(args.only.split(","))
    if "offline" in only:
        section_offline(out)
        benchutil.save(NAME, out)
    if "refit" in only:
        section_refit(args, out)
    plot(out)
    print(benchutil.save(NAME, out))


if __name__ == "__main__":
    main()
