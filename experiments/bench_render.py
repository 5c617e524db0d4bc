"""Benchmark of the per-pixel renderer against the surface grid path.

Measures, float32, median after compilation (compile time apart), peak memory from XLA:

* ``render`` forward and forward+gradient (sum of the tone-mapped image wrt all lighting
  leaves and all wave parameters) at 256 x 256 with 60 waves sampled from a JONSWAP sea,
  plus scaling with resolution {64, 128, 256, 512} and N {15, 60, 240};
* ``on_grid`` for the same number of wave x pixel evaluations (one frame): the target is
  render <= 3 x on_grid, judged on the median over 7 rounds of alternating blocks of 11 calls
  of the four functions (back-to-back runs drift: the render median moved 3.2-5.0 ms over
  five runs; see ``benchutil.interleaved_medians``);
* the hierarchy skip: a distant view rendered with the plan (sub-pixel waves evaluated for
  roughness only) against the plan-free path.

Usage: ``python experiments/bench_render.py [--quick]``; writes
``experiments/results/bench_render.{json,png}``.
"""

from __future__ import annotations

import argparse
import sys

import jax
import jax.numpy as jnp

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import camera as cam  # noqa: E402
from jaxocean import render, shading, spectrum, surface  # noqa: E402

TARGET_RATIO = 3.0


def jonswap_sea(n, seed=0, hs=1.5, tp=6.0, band=None):
    spec = spectrum.Spectrum(hs=hs, tp=tp, gamma=3.3, theta_mean=0.3, s_max=10.0)
    return spectrum.sample_waves(jax.random.key(seed), spec, n, band=band).waves


def measure(n, res, repeats, camera_kw=None, interleaved=0):
    waves = jonswap_sea(n)
    camera = cam.make_camera(**(camera_kw or dict(height=10.0, pitch=0.5, fov=0.8)), resolution=(res, res))
    light = shading.make_lighting()
    rows = []
    plan = render.full_plan(n)  # every wave evaluated: a fair comparison

    def fwd(waves, light):
        return render.render(waves, camera, light, 0.5, plan=plan)

    def loss(waves, light):
        return jnp.sum(shading.tonemap(fwd(waves, light)))

    grad = jax.value_and_grad(loss, argnums=(0, 1))
    x = jnp.linspace(-30, 30, res)

    def grid(waves, x):
        g = surface.on_grid(waves, x, x, jnp.zeros(1))
        return g.displacement, g.normal

    def grid_loss(waves, x):
        d, nrm = grid(waves, x)
        return jnp.sum(d * d) + jnp.sum(nrm[..., :2] ** 2)

    calls = (("render", "forward", fwd, (waves, light)), ("render", "forward+grad", grad, (waves, light)),
             ("on_grid", "forward", grid, (waves, x)), ("on_grid", "forward+grad", jax.value_and_grad(grid_loss), (waves, x)))
    for name, mode, fn, args in calls:
        r = benchutil.time_jitted(fn, *args, repeats=repeats)
        rows.append(dict(path=name, mode=mode, n_waves=n, res=res, pixels_per_s=res * res / r["median_s"],
                         ns_per_wave_pixel=r["median_s"] / (n * res * res) * 1e9, **r))
    if interleaved:
        # the same four calls timed round-robin: the ratios the target is judged on
        med = benchutil.interleaved_medians({(p, m): (fn, args) for p, m, fn, args in calls}, rounds=interleaved)
        for row in rows:
            row["interleaved_median_s"] = med[row["path"], row["mode"]]
    return rows


def skip_saving(repeats):
    """A distant view of a broad spectrum (0.5 to 30 peak frequencies: wavelengths from 150 m
    down to 8 cm): most short waves are sub-pixel everywhere in the image."""
    omega_p = 2 * jnp.pi / 7.0
    waves = jonswap_sea(240, hs=2.0, tp=7.0, band=(0.5 * omega_p, 30 * omega_p))
    camera = cam.make_camera(height=150.0, pitch=0.25, fov=0.5, resolution=(256, 256))
    light = shading.make_lighting()
    plan = render.plan(waves, camera, refine=0)
    full = render.full_plan(240)
    out = {}
    for name, p in (("skip", plan), ("all_waves", full)):
        r = benchutil.time_jitted(lambda w, l: render.render(w, camera, l, 0.5, plan=p), waves, light,
                                  repeats=repeats)
        out[name] = r
    err = float(jnp.max(jnp.abs(render.render(waves, camera, light, 0.5, plan=plan)
                                - render.render(waves, camera, light, 0.5, plan=full))))
    return dict(n_waves=240, active=len(plan.active), refine=plan.refine, max_abs_image_difference=err,
                speedup=out["all_waves"]["median_s"] / out["skip"]["median_s"],
                skip_median_s=out["skip"]["median_s"], all_median_s=out["all_waves"]["median_s"])


def chart(rows, skip, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    for ax, (axis, base) in zip(axes[:2], (("res", dict(n_waves=60)), ("n_waves", dict(res=256)))):
        for p, style in (("render", "-"), ("on_grid", "--")):
            for mode, color in (("forward", "C0"), ("forward+grad", "C3")):
                sel = sorted((r for r in rows if r["path"] == p and r["mode"] == mode
                              and all(r[k] == v for k, v in base.items())), key=lambda r: r[axis])
                if sel:
                    ax.plot([r[axis] for r in sel], [r["ns_per_wave_pixel"] for r in sel], style, marker="o",
                            color=color, label=f"{p} {mode}")
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel(axis)
        ax.set_ylabel("ns per wave x pixel")
        ax.legend(fontsize=8)
    axes[2].bar(["all waves", "with skip"], [skip["all_median_s"] * 1e3, skip["skip_median_s"] * 1e3],
                color=["C7", "C2"])
    axes[2].set_ylabel("ms per 256x256 frame")
    axes[2].set_title(f"distant view, 240 waves: {skip['active']} need sines ({skip['speedup']:.1f}x)", fontsize=9)
    fig.suptitle("jaxocean render vs on_grid (same wave x pixel work); target render <= 3x on_grid")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--skip-only", action="store_true", help="only the hierarchy-skip measurement; merges into "
                    "an existing results file")
    args = ap.parse_args(argv)
    if args.skip_only:
        import json
        path = benchutil.RESULTS / "bench_render.json"
        saved = json.loads(path.read_text())
        skip = skip_saving(5)
        saved["meta"]["summary"]["skip"] = skip
        saved["meta"].pop("machine", None)
        print("skip:", skip)
        out = benchutil.save("bench_render", saved["rows"], saved["meta"])
        chart(saved["rows"], skip, out.with_suffix(".png"))
        return
    reps = 3 if args.quick else 21  # medians of 5 swung by 1.5x between quiet runs
    configs = [(60, 256)] + ([] if args.quick else [(60, r) for r in (64, 128, 512)] + [(n, 256) for n in (15, 240)])
    rows = []
    for n, res in configs:
        rows += measure(n, res, reps, interleaved=(2 if args.quick else 7) if (n, res) == (60, 256) else 0)
        benchutil.print_table(rows[-4:], ["path", "mode", "n_waves", "res", "ns_per_wave_pixel", "pixels_per_s",
                                          "median_s", "compile_s", "peak_bytes"])
    skip = skip_saving(reps)
    base = {(r["path"], r["mode"]): r for r in rows if (r["n_waves"], r["res"]) == (60, 256)}
    summary = dict(
        ratio_forward=base["render", "forward"]["median_s"] / base["on_grid", "forward"]["median_s"],
        ratio_grad=base["render", "forward+grad"]["median_s"] / base["on_grid", "forward+grad"]["median_s"],
        ratio_forward_interleaved=(base["render", "forward"]["interleaved_median_s"]
                                   / base["on_grid", "forward"]["interleaved_median_s"]),
        ratio_grad_interleaved=(base["render", "forward+grad"]["interleaved_median_s"]
                                / base["on_grid", "forward+grad"]["interleaved_median_s"]),
        target_ratio=TARGET_RATIO, skip=skip)
    # judged on the alternating-block timing (same drift for both paths; benchutil.interleaved_medians)
    summary["target_met"] = summary["ratio_forward_interleaved"] <= TARGET_RATIO
    print("\nsummary:", summary)
    out = benchutil.save("bench_render", rows, dict(summary=summary))
    chart(rows, skip, out.with_suffix(".png"))
    print("wrote", out, out.with_suffix(".png"))


if __name__ == "__main__":
    main()
