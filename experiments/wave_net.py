"""The wave-estimation network against the paper's Table 2 and the direct wave fit.

On the test split of a `jaxocean simulate` dataset (scenes the network never saw), each
scene's first ``T`` frames (``T = model.config.frames``) of noise-free geometry are given to:

* **spectral peaks (no network)** -- the baseline every row must beat, as the flat normal
  is the geometry networks': the ``slots`` strongest peaks of the space-time periodogram
  (:func:`jaxocean.fit.waves.spectral_init`: one shot, no training, no greedy subtraction)
  with their amplitudes and phases from one least-squares solve;
* **net** -- :func:`jaxocean.nn.waves.predict` (slots with presence > 0.5);
* **net + spectrum** -- the net's waves with every amplitude replaced by its frequency
  bin's energy under the spectrum fitted to them (:func:`jaxocean.fit.spectrum` with the
  scene's roughness, then :func:`jaxocean.fit.correct_amplitudes` with no wave marked
  reliable: the paper's eq. 2 correction as this library reads it);
* **fit.waves (default)** -- :func:`jaxocean.fit.waves` from its spectral start;
* **fit.waves (net start)** -- ``fit.waves(..., init="net")``: the network's waves are the
  selection's first trial model (``--prune``: both fit rows with ``prune=True``).

Columns, per row: MSE and MAE of h [m], omega [rad/s], theta [rad] over the waves matched
one to one to the scene's true *resolvable* waves (:func:`jaxocean.fit.waves.match`,
relative wave-vector distance <= 0.1, as ``experiments/wave_fit.py`` scores ``fit.waves``),
pooled over the matched pairs of every scene; waves found (matched / resolvable) and waves
returned; the geometry error of the re-synthesised sequence (mean normal angle to the
input over valid sea pixel-frames [deg], and the normalised eq. 5-7 loss of
:func:`jaxocean.nn.waves_train.geometry_loss`); wall time per scene (after a warm-up
scene that compiles every path; timings are host wall clock on a shared machine). The
spectral and net rows are scored on ``--scenes`` test scenes, every row on the first
``--fit-scenes`` of them.

Writes ``experiments/results/wave_net.json``, ``wave_net.png`` (speed-accuracy chart) and
``wave_net_fig7.png`` (predicted against true amplitude, frequency and direction of the
matched waves of one test scene: the paper's Fig. 7).

    python experiments/wave_net.py --data out/waves32big --scenes 48 --fit-scenes 8
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import benchutil  # noqa: E402

from jaxocean import camera as cam  # noqa: E402
from jaxocean import fit  # noqa: E402
from jaxocean._math import angle_between  # noqa: E402
from jaxocean.fit.waves import match, resolvable, spectral_init  # noqa: E402
from jaxocean.fit.waves import predict as render_waves  # noqa: E402
from jaxocean.io.dataset import Dataset  # noqa: E402
from jaxocean.nn import waves as wn  # noqa: E402
from jaxocean.nn import waves_train as wt  # noqa: E402
from jaxocean.waves import Waves  # noqa: E402

PAPER = {"mse_amplitude": 4e-5, "mse_omega": 0.0352, "mse_theta": 0.0843,
         "mae_amplitude": 0.00518, "mae_omega": 0.131, "mae_theta": 0.227}
ROWS = ("spectral peaks (no network)", "net", "net + spectrum", "fit.waves (default)", "fit.waves (net start)")
FAST_ROWS = ROWS[:3]  # scored on every --scenes scene; the fit rows on the first --fit-scenes
FIELDS = ("amplitude", "omega", "theta")


def scene_inputs(data: Dataset, s: int, T: int):
    sc = data.scene(s)
    fr = [data.frame(s, f) for f in range(T)]
    normals = np.stack([x.normal for x in fr]).astype(np.float32)
    rough = np.stack([x.roughness for x in fr]).astype(np.float32)
    times = np.asarray(sc.times, np.float32)[:T]
    return sc, normals, rough, times


def geometry_error(w: Waves, normals, rough, camera, times) -> dict:
    if w.omega.shape[0] == 0:
        w = Waves(*(np.asarray([v], np.float32) for v in (0.0, 1.0, 0.0, 0.0)))
    wj = Waves(*(jnp.asarray(x, jnp.float32) for x in w))
    n_pred, _ = render_waves(wj, camera, jnp.asarray(times))
    mask = np.asarray(cam.intersect_sea(camera).mask)[None] & np.all(np.isfinite(normals), -1) & (normals[..., 2] > 1e-3)
    ang = np.asarray(angle_between(n_pred, jnp.asarray(normals)))
    loss = float(wt.geometry_loss(wj, jnp.asarray(normals), jnp.asarray(rough), camera, jnp.asarray(times)))
    return {"normal_error_deg": math.degrees(float(np.mean(ang[mask]))), "geometry_loss": loss}


def _short(x):
    """Values as a list of floats to 6 significant digits (float32 data: the JSON stays small)."""
    return [float(f"{v:.6g}") for v in np.asarray(x, float).ravel()]


def score(w: Waves, truth: Waves) -> dict:
    m = match(w, truth)
    return {"errors": {f: _short(getattr(m.abs_error, f)) for f in FIELDS},
            "matched": int(m.true_index.size), "returned": int(np.size(w.omega)),
            "pairs": {"true": m.true_index.tolist(), "fit": m.fit_index.tolist()}}


def spectrum_corrected(w: Waves, camera, rough):
    sea = fit.spectrum(w, camera=camera, roughness=rough)
    return fit.correct_amplitudes(w, sea.spectrum, reliable=None)


PRUNE = False  # the fits' default; --prune: both rows prune


def run_scene(model, data, s, T, methods) -> dict:
    sc, normals, rough, times = scene_inputs(data, s, T)
    ok = np.asarray(resolvable(sc.waves, sc.camera))
    truth = Waves(*(np.asarray(x, np.float64)[ok] for x in sc.waves))
    row = {"scene": int(s), "n_resolvable": int(ok.sum()), "camera_height": float(sc.camera.height),
           "camera_pitch": float(sc.camera.pitch), "hs": float(sc.spectrum.hs), "tp": float(sc.spectrum.tp)}
    for name in methods:
        t0 = time.perf_counter()
        try:
            if name == "spectral peaks (no network)":
                w = spectral_init(jnp.asarray(normals), sc.camera, jnp.asarray(times), model.config.slots)
            elif name == "net":
                w = wn.predict(model, normals, rough, sc.camera, times)
            elif name == "net + spectrum":
                w = wn.predict(model, normals, rough, sc.camera, times)
                w = spectrum_corrected(Waves(*(jnp.asarray(x, jnp.float32) for x in w)), sc.camera, rough)
            elif name == "fit.waves (default)":
                w = fit.waves(normals, rough, sc.camera, times, prune=PRUNE).waves
            else:
                w = fit.waves(normals, rough, sc.camera, times, init="net", net=model, prune=PRUNE).waves
            jax.block_until_ready(w)
            err = None
        except Exception as e:  # noqa: BLE001 -- a method that fails on a scene is a result, recorded
            w, err = Waves(*(np.zeros(0),) * 4), f"{type(e).__name__}: {e}"
        wall = time.perf_counter() - t0
        w = Waves(*(np.asarray(x, np.float64) for x in w))
        r = score(w, truth) | geometry_error(w, normals, rough, sc.camera, times) | {"time_s": wall, "error": err}
        r["waves"] = {f: _short(getattr(w, f)) for f in w._fields}
        row[name] = r
    row["truth"] = {f: _short(getattr(truth, f)) for f in truth._fields}
    return row


def summarise(rows, methods) -> dict:
    out = {"paper": dict(PAPER, time_s=None, found_fraction=None, returned=None)}
    for name in methods:
        errs = {f: np.concatenate([np.asarray(r[name]["errors"][f]) for r in rows]) for f in FIELDS}
        s = {}
        for f in FIELDS:
            e = errs[f]
            s[f"mse_{f}"] = float(np.mean(e ** 2)) if e.size else None
            s[f"mae_{f}"] = float(np.mean(e)) if e.size else None
        s["pairs"] = int(errs["omega"].size)
        s["found_fraction"] = sum(r[name]["matched"] for r in rows) / max(sum(r["n_resolvable"] for r in rows), 1)
        s["found_per_scene"] = float(np.mean([r[name]["matched"] for r in rows]))
        s["returned"] = float(np.mean([r[name]["returned"] for r in rows]))
        s["normal_error_deg"] = float(np.mean([r[name]["normal_error_deg"] for r in rows]))
        s["geometry_loss"] = float(np.mean([r[name]["geometry_loss"] for r in rows]))
        s["time_s"] = float(np.mean([r[name]["time_s"] for r in rows]))
        s["time_s_median"] = float(np.median([r[name]["time_s"] for r in rows]))
        s["failures"] = sum(r[name]["error"] is not None for r in rows)
        out[name] = s
    return out


def targets(summary) -> dict:
    net, d, ns = summary.get("net"), summary.get("fit.waves (default)"), summary.get("fit.waves (net start)")
    t = {}
    if net:
        t["net_beats_paper_mae"] = {f: (net[f"mae_{f}"] is not None and net[f"mae_{f}"] < PAPER[f"mae_{f}"])
                                    for f in FIELDS}
    if d and ns:
        t["net_start_as_accurate"] = {f: (ns[f"mae_{f}"] is not None and d[f"mae_{f}"] is not None
                                          and ns[f"mae_{f}"] <= d[f"mae_{f}"]) for f in FIELDS}
        t["net_start_as_accurate"]["found"] = ns["found_fraction"] >= d["found_fraction"]
        t["net_start_time_ratio"] = ns["time_s"] / max(d["time_s"], 1e-9)
        t["net_start_at_most_a_third"] = t["net_start_time_ratio"] <= 1 / 3
    return t


def print_summary(summary) -> None:
    cols = ["mse_amplitude", "mse_omega", "mse_theta", "mae_amplitude", "mae_omega", "mae_theta", "found_fraction",
            "returned", "normal_error_deg", "geometry_loss", "time_s"]
    benchutil.print_table([{"row": k, **{c: v.get(c) for c in cols}} for k, v in summary.items()], ["row"] + cols)


def plot_speed(summary, fname="wave_net"):
    plt = benchutil.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    colors = dict(zip(ROWS, ("tab:gray", "tab:blue", "tab:cyan", "tab:red", "tab:green")))
    for ax, f in zip(axes, FIELDS):
        for name, s in summary.items():
            if name == "paper":
                ax.axhline(s[f"mae_{f}"], color="k", ls="--", label="paper Table 2 (no time given)")
                continue
            if s.get(f"mae_{f}") is None:
                continue
            ax.scatter([s["time_s"]], [s[f"mae_{f}"]], color=colors.get(name), s=50,
                       label=f"{name} ({s['found_fraction']:.0%} found)")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xlabel("wall time per scene [s]")
        ax.set_title(f"MAE {f} ({'m' if f == 'amplitude' else 'rad/s' if f == 'omega' else 'rad'})")
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    return benchutil.save_figure(fig, fname)


def plot_fig7(row, methods, fname="wave_net_fig7"):
    plt = benchutil.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    truth = row["truth"]
    marks = dict(zip(ROWS, ("^", "o", "s", "x", "+")))
    for ax, f in zip(axes, FIELDS):
        tv = np.asarray(truth[f])
        lo, hi = (float(tv.min()), float(tv.max())) if tv.size else (0.0, 1.0)
        for name in methods:
            r = row[name]
            ti, fi = np.asarray(r["pairs"]["true"], int), np.asarray(r["pairs"]["fit"], int)
            if ti.size == 0:
                continue
            pv = np.asarray(r["waves"][f])[fi]
            ax.scatter(tv[ti], pv, marker=marks.get(name, "o"), label=f"{name} ({ti.size} matched)")
            lo, hi = min(lo, float(pv.min())), max(hi, float(pv.max()))
        ax.plot([lo, hi], [lo, hi], "k:", lw=1)
        ax.set_xlabel(f"true {f}")
        ax.set_ylabel(f"predicted {f}")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"test scene {row['scene']}: matched waves ({row['n_resolvable']} resolvable true waves)")
    fig.tight_layout()
    return benchutil.save_figure(fig, fname)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--data", default="out/waves32big")
    p.add_argument("--model", help="wave network file (default: the shipped model)")
    p.add_argument("--scenes", type=int, default=48, help="test scenes for the spectral and net rows (the first of the split)")
    p.add_argument("--fit-scenes", type=int, default=8,
                   help="of those, the first scenes that also get the two fit.waves rows (minutes each)")
    p.add_argument("--prune", action="store_true",
                   help="both fit rows with prune=True (results as wave_net_prune.json / .png)")
    p.add_argument("--name", help="results name (default wave_net, or wave_net_prune with --prune)")
    args = p.parse_args(argv)
    global PRUNE
    PRUNE = bool(args.prune)
    name = args.name or ("wave_net_prune" if args.prune else "wave_net")
    data = Dataset(args.data)
    model = wn.load(args.model)
    T = model.config.frames
    scenes = data.splits["test"][: args.scenes]
    # warm-up: compile every path on a validation scene (not scored)
    t0 = time.perf_counter()
    run_scene(model, data, data.splits["val"][0], T, ROWS if args.fit_scenes else FAST_ROWS)
    warm = time.perf_counter() - t0
    print(f"warm-up (compilation) {warm:.0f} s", flush=True)
    rows = []
    for i, s in enumerate(scenes):
        methods = ROWS if i < args.fit_scenes else FAST_ROWS
        rows.append(run_scene(model, data, s, T, methods))
        r = rows[-1]
        print(f"scene {s}: resolvable {r['n_resolvable']}; " + "; ".join(
            f"{m} {r[m]['matched']}/{r[m]['returned']} in {r[m]['time_s']:.2f} s" for m in methods), flush=True)
    n_fit = min(args.fit_scenes, len(rows))
    summary_all = summarise(rows, FAST_ROWS)
    summary_fit = summarise(rows[:n_fit], ROWS) if n_fit else {}
    print(f"fast rows, {len(rows)} test scenes:")
    print_summary(summary_all)
    t = targets(summary_all)
    if n_fit:
        print(f"every row, the first {n_fit} test scenes:")
        print_summary(summary_fit)
        t |= {k: v for k, v in targets(summary_fit).items() if k != "net_beats_paper_mae"}
        t["net_beats_paper_mae_fit_scenes"] = targets(summary_fit)["net_beats_paper_mae"]
    print(t)
    meta = {"data": args.data, "model": str(args.model or wn.PRETRAINED_PATH), "model_info": wn.model_info(args.model),
            "frames": T, "warmup_s": warm, "summary_fast_rows": summary_all, "net_scenes": len(rows),
            "summary_every_row": summary_fit, "fit_scenes": n_fit, "targets": t,
            "load_avg": list(os.getloadavg())}
    benchutil.save(name, rows, meta | {"prune": args.prune})
    plot_speed(summary_fit or summary_all, name)
    fitted = rows[:n_fit] or rows
    best = max(fitted, key=lambda r: r["net"]["matched"])
    plot_fig7(best, [m for m in ROWS if m in best], name + "_fig7")


if __name__ == "__main__":
    main()
