"""Benchmark of the surface model: separable ``on_grid`` against the per-point path.

Measures forward and forward+gradient (sum-of-squares loss of displacement and normal, wrt
all four wave parameters) on float32, median after compilation, compile time apart, peak
memory from XLA's accounting. Base case N = 60 waves, 256 x 256 grid, 10 frames; scaling
tables vary one of N in {15, 60, 240}, grid in {64, 128, 256, 512}, frames in {1, 10, 50}.

The per-point path evaluates ``surface.displacement`` and ``surface.normal`` (reductions as
dot products) at the same points, one frame at a time under ``lax.map`` so that its
(H, W, N) intermediates stay bounded. In the base case the plain-autodiff product
(``surface._on_grid_reference``, the implementation before on_grid's custom tangent rule) is
timed too, in the same run.

Other jobs may run on the machine: the 1/5/15-minute load averages before and after the run are
stored in the JSON meta, and the summary gives the forward+grad / forward ratio of the same
run, which is less sensitive to load than either time.

Usage: ``python experiments/bench_surface.py [--quick]``; writes
``experiments/results/bench_surface.{json,png}``.
"""

from __future__ import annotations

import argparse
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import surface  # noqa: E402
from jaxocean.waves import GRAVITY, Waves  # noqa: E402

TARGET_FWD_NS, TARGET_GRAD_NS = 1.5, 6.0
PER_POINT_MAX_WORK = 4e7  # wave x pixel x frame evaluations: the base case, and smaller
BASE = (60, 256, 10)


def make_sea(n, seed=0):
    rng = np.random.default_rng(seed)
    omega = rng.uniform(0.8, 4.0, n)
    amp = rng.uniform(0, 0.3 / n, n) * 3 * GRAVITY / omega**2
    return Waves(*(jnp.asarray(a, jnp.float32) for a in
                   (amp, omega, rng.uniform(-np.pi, np.pi, n), rng.uniform(0, 2 * np.pi, n))))


# positions and times are arguments, not closure constants: XLA compiles captured arrays
# into the program as literals, which was measured to slow the per-point path 2x


def grid_fn(waves, x, y, times):
    g = surface.on_grid(waves, x, y, times)
    return g.displacement, g.normal


def plain_grid_fn(waves, x, y, times):
    return surface._on_grid_reference(waves, x, y, times)


def point_fn(waves, x, y, times):
    xx, yy = jnp.meshgrid(x, y)
    xy = jnp.stack([xx, yy], -1)
    return jax.lax.map(lambda t: (surface.displacement(waves, xy, t), surface.normal(waves, xy, t)), times)


def with_grad(fwd):
    def loss(waves, *args):
        d, n = fwd(waves, *args)
        return jnp.sum(d * d) + jnp.sum(n[..., :2] ** 2)
    return jax.value_and_grad(loss)


def measure(n, res, frames, repeats):
    waves = make_sea(n)
    x = jnp.linspace(-30, 30, res, dtype=jnp.float32)
    y = jnp.linspace(-30, 30, res, dtype=jnp.float32)
    times = jnp.arange(frames, dtype=jnp.float32) * 0.1
    work = n * res * res * frames
    rows = []
    paths = [("on_grid", grid_fn)]
    if (n, res, frames) == BASE:
        paths.append(("on_grid_plain_autodiff", plain_grid_fn))
    if work <= PER_POINT_MAX_WORK:  # beyond this the per-point gradient needs several GB and minutes
        paths.append(("per_point", point_fn))
    for path, fwd in paths:
        for mode, fn in (("forward", fwd), ("forward+grad", with_grad(fwd))):
            r = benchutil.time_jitted(fn, waves, x, y, times, repeats=repeats)
            rows.append(dict(path=path, mode=mode, n_waves=n, grid=res, frames=frames,
                             ns_per_wave_pixel_frame=r["median_s"] / work * 1e9, **r))
    return rows


def chart(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(14, 4), sharey=True)
    for ax, (axis, base) in zip(axes, (("n_waves", dict(grid=256, frames=10)), ("grid", dict(n_waves=60, frames=10)),
                                       ("frames", dict(n_waves=60, grid=256)))):
        for p, style in (("on_grid", "-"), ("per_point", "--")):
            for mode, color in (("forward", "C0"), ("forward+grad", "C3")):
                sel = sorted((r for r in rows if r["path"] == p and r["mode"] == mode
                              and all(r[k] == v for k, v in base.items())), key=lambda r: r[axis])
                if sel:
                    ax.plot([r[axis] for r in sel], [r["ns_per_wave_pixel_frame"] for r in sel], style, color=color,
                            marker="o", label=f"{p} {mode}")
        ax.axhline(TARGET_FWD_NS, color="C0", lw=0.8, ls=":")
        ax.axhline(TARGET_GRAD_NS, color="C3", lw=0.8, ls=":")
        ax.set_xscale("log", base=2)
        ax.set_yscale("log")
        ax.set_xlabel(axis)
        ax.set_title(f"varying {axis} ({', '.join(f'{k}={v}' for k, v in base.items())})", fontsize=9)
    axes[0].set_ylabel("ns per wave x pixel x frame (median)")
    axes[0].legend(fontsize=8)
    fig.suptitle("jaxocean surface: on_grid (separable GEMM) vs per-point; dotted = targets (1.5 / 6 ns)")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="base case only, fewer repeats")
    args = ap.parse_args(argv)
    load_start = os.getloadavg()
    print("load average (1, 5, 15 min) at start:", load_start)
    configs = [BASE]
    if not args.quick:
        configs += [(n, 256, 10) for n in (15, 240)] + [(60, g, 10) for g in (64, 128, 512)] + \
                   [(60, 256, f) for f in (1, 50)]
    rows = []
    for n, res, frames in configs:
        reps = 3 if n * res * res * frames > 2e8 else 7
        rows += measure(n, res, frames, 2 if args.quick else reps)
        benchutil.print_table([r for r in rows if (r["n_waves"], r["grid"], r["frames"]) == (n, res, frames)], ["path", "mode", "n_waves", "grid", "frames", "ns_per_wave_pixel_frame",
                                          "median_s", "compile_s", "peak_bytes"])
    load_end = os.getloadavg()
    base = {(r["path"], r["mode"]): r for r in rows if (r["n_waves"], r["grid"], r["frames"]) == BASE}
    summary = dict(
        base_case="N=60, 256x256, 10 frames, float32",
        on_grid_forward_ns=base["on_grid", "forward"]["ns_per_wave_pixel_frame"],
        on_grid_grad_ns=base["on_grid", "forward+grad"]["ns_per_wave_pixel_frame"],
        on_grid_grad_over_forward=base["on_grid", "forward+grad"]["median_s"] / base["on_grid", "forward"]["median_s"],
        plain_autodiff_grad_ns=base["on_grid_plain_autodiff", "forward+grad"]["ns_per_wave_pixel_frame"],
        custom_rule_speedup_grad=(base["on_grid_plain_autodiff", "forward+grad"]["median_s"]
                                  / base["on_grid", "forward+grad"]["median_s"]),
        grid_speedup_forward=base["per_point", "forward"]["median_s"] / base["on_grid", "forward"]["median_s"],
        grid_speedup_grad=base["per_point", "forward+grad"]["median_s"] / base["on_grid", "forward+grad"]["median_s"],
        targets_ns=dict(forward=TARGET_FWD_NS, forward_grad=TARGET_GRAD_NS),
    )
    summary["targets_met"] = (summary["on_grid_forward_ns"] <= TARGET_FWD_NS
                              and summary["on_grid_grad_ns"] <= TARGET_GRAD_NS)
    print("\nsummary:", summary)
    out = benchutil.save("bench_surface", rows, dict(summary=summary, quick=args.quick,
                                                     loadavg_1_5_15min=dict(start=load_start, end=load_end)))
    chart(rows, out.with_suffix(".png"))
    print("wrote", out, out.with_suffix(".png"))


if __name__ == "__main__":
    main()
