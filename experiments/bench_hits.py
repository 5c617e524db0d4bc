"""Cost and coverage of the converged ray-surface hits (``render.plan(...).refine > 0``).

For a JONSWAP sea (60 waves, Hs 1.5 m, Tp 6 s) at 128 x 128, float32, over views from close
and steep to the horizon in the image, measures:

* the path ``plan="auto"`` takes (rows or hits), Newton iterations the loop ran, and the
  share of sea pixels whose hit is flagged (``Geometry.converged`` False: grazing rays);
* ``render`` forward, median after compilation (compile time apart), on that path and on
  the rows path (``plan=None``) for the same view: the price of exact hits. The two are
  also timed in alternating blocks in the same run (``benchutil.interleaved_medians``),
  whose ratio ``hits_over_rows`` is what to compare across runs on a shared machine;
* ``refine_hits`` alone (the Newton loop) and its share of the frame;
* ``render`` forward + gradient with respect to the camera height and pitch and the sun
  angles under ``plan="auto"`` (traced: the path is chosen inside the compiled function).

Usage: ``python experiments/bench_hits.py [--quick]``; writes
``experiments/results/bench_hits.{json,png}``.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import sys

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import camera as cam  # noqa: E402
from jaxocean import hierarchy, raycast, render, shading, spectrum  # noqa: E402

# (name, height [m], pitch [rad], vertical fov [rad])
VIEWS = [
    ("steep 5 m", 5.0, 1.2, 0.8),
    ("oblique 10 m", 10.0, 0.6, 0.8),
    ("low 10 m, horizon in view", 10.0, 0.3, 0.8),
    ("high 40 m", 40.0, 0.7, 0.6),
    ("far 300 m", 300.0, 0.8, 0.3),
]


def jonswap_sea(n, seed=0, hs=1.5, tp=6.0):
    spec = spectrum.Spectrum(hs=hs, tp=tp, gamma=3.3, theta_mean=0.3, s_max=10.0)
    return spectrum.sample_waves(jax.random.key(seed), spec, n).waves


def measure(name, height, pitch, fov, waves, light, res, repeats):
    c = cam.make_camera(height=height, pitch=pitch, fov=fov, resolution=res)
    plan = render.plan(waves, c)
    row = dict(view=name, height_m=height, pitch_rad=pitch, fov_rad=fov, path="hits" if plan.refine else "rows")
    geo = render.geometry(waves, c, 0.0)
    mask, ok = np.asarray(geo.mask), np.asarray(geo.converged)
    row["sea_pixels"] = int(mask.sum())
    row["flagged_fraction"] = float((mask & ~ok).sum() / max(mask.sum(), 1))
    hit = cam.intersect_sea(c)
    ws = hierarchy.weights(waves, hit.footprint)
    origin, direction = render._sea_rays(c, hit)
    hits_args = (waves, origin, direction, hit.xy, ws.displacement, hit.mask)
    if plan.refine:
        row["iterations"] = int(raycast.refine_hits(waves, origin, direction, hit.xy, 0.0, ws.displacement,
                                                    active=hit.mask).iterations)
    fixed = dict(active=plan.active, refine=plan.refine)

    def auto_fn(w, c, l):
        return render.render(w, c, l, 0.0, plan=render.RenderPlan(**fixed))

    def rows_fn(w, c, l):
        return render.render(w, c, l, 0.0, plan=None)

    auto = benchutil.time_jitted(auto_fn, waves, c, light, repeats=repeats)
    rows = benchutil.time_jitted(rows_fn, waves, c, light, repeats=repeats)
    calls = {"auto": (auto_fn, (waves, c, light)), "rows": (rows_fn, (waves, c, light))}
    if plan.refine:
        calls["refine"] = (lambda w, o, d, xy, wd, m: raycast.refine_hits(w, o, d, xy, 0.0, wd, active=m).xy,
                           hits_args)
    alternating = benchutil.interleaved_medians(calls, rounds=5, block=max(3, repeats // 2))
    row.update(hits_over_rows=alternating["auto"] / alternating["rows"],
               alternating_render_ms=1e3 * alternating["auto"], alternating_rows_ms=1e3 * alternating["rows"])
    if plan.refine:
        row.update(refine_ms=1e3 * alternating["refine"], refine_share=alternating["refine"] / alternating["auto"])

    def loss(p, w, c, l):
        cc = dataclasses.replace(c, height=p[0], pitch=p[1])
        ll = l._replace(sun_azimuth=p[2], sun_elevation=p[3])
        return jnp.sum(render.render(w, cc, ll, 0.0))

    p0 = jnp.stack([c.height, c.pitch, light.sun_azimuth, light.sun_elevation])
    grad = benchutil.time_jitted(jax.grad(loss), p0, waves, c, light, repeats=repeats)
    row.update(render_ms=1e3 * auto["median_s"], render_compile_s=auto["compile_s"],
               rows_path_ms=1e3 * rows["median_s"], grad_auto_ms=1e3 * grad["median_s"],
               grad_compile_s=grad["compile_s"])
    return row


def chart(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (ax, bx) = plt.subplots(1, 2, figsize=(11, 4))
    names = [r["view"] for r in rows]
    x = np.arange(len(rows))
    ax.bar(x - 0.2, [r["render_ms"] for r in rows], 0.4, label="plan='auto' (path shown)")
    ax.bar(x + 0.2, [r["rows_path_ms"] for r in rows], 0.4, label="rows path (plan=None)")
    for i, r in enumerate(rows):
        label = r["path"] + (f"\n{r.get('iterations', 0)} it, {r['hits_over_rows']:.0f}x rows" if r["path"] == "hits"
                             else "")
        ax.text(i - 0.2, r["render_ms"], label, ha="center", va="bottom", fontsize=7)
    ax.set_xticks(x, names, rotation=20, ha="right", fontsize=7)
    ax.set_ylabel("render forward [ms], median")
    ax.legend(fontsize=7)
    bx.bar(x, [100 * r["flagged_fraction"] for r in rows])
    bx.set_xticks(x, names, rotation=20, ha="right", fontsize=7)
    bx.set_ylabel("sea pixels flagged (hit not unique) [%]")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--quick", action="store_true", help="64^2, 3 repeats")
    args = ap.parse_args(argv)
    res = (64, 64) if args.quick else (128, 128)
    repeats = 3 if args.quick else 11
    waves = jonswap_sea(60)
    light = shading.make_lighting(sun_azimuth=0.4, sun_elevation=0.5)
    rows = []
    load_start = list(os.getloadavg())  # the machine is shared: loaded runs are slower
    for view in VIEWS:
        rows.append(measure(*view, waves, light, res, repeats))
        print(rows[-1], flush=True)
    out = benchutil.save("bench_hits", rows, dict(resolution=res, n_waves=60, dtype="float32",
                                                  load_average_at_start=load_start))
    chart(rows, benchutil.RESULTS / "bench_hits.png")
    print("wrote", out)


if __name__ == "__main__":
    main()
