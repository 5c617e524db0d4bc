"""Where the lighting fit fails: success rate against five stress axes.

Each sweep point fits P problems (random true colours, random sun as stated, random
initial guesses) on the 64^2 scene of ``lighting_fit.py`` (float64, noise-free unless
stated) with several methods:

* ``default``      ``fit.lighting`` as shipped: variable projection (colours by NNLS in the
                   residual), LM on the two sun angles from the best of init / glint
                   estimate / 24x24 sky grid (2 starts refined);
* ``display space`` the default followed by the display-space refinement
                   (``space="display"``; noise axis only);
* ``from init``    the same two-angle LM from the initial guess alone (no glint, no grid);
* ``plain LM``     LM on all 11 parameters from the initial guess (log colours);
* ``Adam-400``     the paper's baseline on the plain parameters (init-distance sweep only).

Success (noise-free): sun within 0.01 deg and every colour within 1e-4 relative. With noise
the bar is the noise-limited one: sun within 0.5 deg, colours within 5%. Also recorded: the
rate of *false successes* (the fit reports success but misses the bar) -- a failed fit must
be reported as failed.

Axes: (1) distance of the initial guess (sun angle d, colours off by a factor e^(d/60 deg));
(2) noise sigma on the tone-mapped image; (3) sun elevation (glitter saturating at low sun,
leaving the frame at high sun); (4) view angle (pitch, down to grazing) with the sun at the
mirror elevation; (5) roughness (the slope variance scaled from mirror-like to very rough).

Horizon sweep (``--horizon``, its own results): a 30-wave sea (steepness k h 0.02-0.2 per
wave, omega 0.8-3 rad/s), camera 10 m high, pitch 20 deg, vertical fov 50 deg (the horizon
in the image), 48^2, float64, noise-free, the default colours -- with the sun in front of
the camera (azimuth 0 and 0.3 rad off the view), at the frame's edge (0.6 rad), beside it
(pi/2) and behind it (pi), at elevations 0.15, 0.3, 0.45 and 0.7 rad, on
``--seas`` sea states (random waves per seed), one random initial guess each. Per problem the
true sun's glitter fraction (its share of the weighted image energy) puts it in one of three
bins: *in frame* (>= 1e-3), *flank only* (1e-8 to 1e-3: only the lobe's edge is in the
frame) and *none* (< 1e-8, the library's own "seen" threshold); *recovered* = sun within 0.01 deg and every colour within 1e-4 (the noise-free bar
above); *false success* = reported success and not recovered. Where no glitter is in the
frame the right outcome is a failure that says the sun direction is undetermined with the
sky and sea colours still right (1e-4) and flagged determined.

Usage: ``python experiments/stability_lighting.py [--quick]``; writes
``experiments/results/stability_lighting.{json,png}``; ``--horizon [--seas N]`` runs the
horizon sweep alone and writes ``stability_lighting_horizon.{json,png}``.
"""

from __future__ import annotations

import argparse
import functools
import math
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402
import lighting_fit as lfx  # noqa: E402

from jaxocean import fit, shading  # noqa: E402

METHODS = {
    "default": dict(),
    "display space": dict(space="display"),
    "from init": dict(grid=0, glint=False, n_starts=1),
    "plain LM": dict(structure="plain"),
    "Adam-400": dict(solver="adam", structure="plain", options={"learning_rate": 0.03}),
}


@functools.lru_cache(maxsize=None)
def _fitter(method: str):
    kw = METHODS[method]

    # the problems of a point are fitted one after another inside the compiled program
    # (batching="sequential": each with its own step count; lock-step vmap is ~5x slower on a
    # CPU, see lighting_fit.py's batch section). Adam runs a fixed 400 steps: vectorised.
    batching = "vectorized" if kw.get("solver") == "adam" else "sequential"

    def one(img, init, geo, camera):  # weights: the shipped default ("display", saturated pixels censored)
        return fit.lighting(img, geo, camera, init=init, throw=False, batching=batching, **kw)

    return jax.jit(jax.vmap(one, in_axes=(0, 0, None, None)))


def run_point(method, images, inits, truths, geo, camera, noisy=False):
    t0 = time.perf_counter()
    res = jax.block_until_ready(_fitter(method)(images, inits, geo, camera))
    wall = time.perf_counter() - t0
    e = lfx.errors(res.lighting, truths)
    if noisy:
        ok = (e["sun_angle_deg"] < 0.5) & np.all([e[n] < 0.05 for n in fit.COLOR_FIELDS], 0)
    else:
        ok = lfx.success_of(e)
    reported = np.asarray(res.success)
    return dict(method=method, n=int(ok.size), success=float(ok.mean()), reported=float(reported.mean()),
                false_success=float(np.mean(reported & ~ok)),
                sun_deg_median=float(np.median(e["sun_angle_deg"])),
                steps_median=float(np.median(np.asarray(res.steps))), wall_s_with_compile=wall,
                loadavg_1min=os.getloadavg()[0])


def truths_and_inits(key, P, *, azimuth=(-0.35, 0.35), elevation=(0.09, 0.6)):
    k1, k2 = jax.random.split(key)
    truths = [fit.random_lighting(k, sun_azimuth=azimuth, sun_elevation=elevation, dtype=jnp.float64)
              for k in jax.random.split(k1, P)]
    inits = [fit.random_lighting(k, dtype=jnp.float64) for k in jax.random.split(k2, P)]
    return lfx.stack(truths), lfx.stack(inits)


def offset_init(key, truth, degrees):
    """An initial guess ``degrees`` from the true sun (random direction, kept above the
    horizon) with colours off by a random factor of e^(+-degrees / 60)."""
    k1, k2 = jax.random.split(key)
    pq = fit.sun_to_pq(truth.sun_azimuth, truth.sun_elevation)
    ang = jax.random.uniform(k1, (), truth.sun_azimuth.dtype, 0, 2 * math.pi)
    pq = pq + math.radians(degrees) * jnp.stack([jnp.cos(ang), jnp.sin(ang)])
    r = jnp.linalg.norm(pq)
    pq = jnp.where(r > math.radians(89.0), pq * math.radians(89.0) / r, pq)
    az, el = fit.pq_to_sun(pq)
    signs = jnp.where(jax.random.bernoulli(k2, 0.5, (3, 3)), 1.0, -1.0)
    f = jnp.exp(signs * degrees / 60.0)
    return truth._replace(sun_azimuth=az, sun_elevation=el, sun_color=truth.sun_color * f[0],
                          sky_color=truth.sky_color * f[1], sea_color=truth.sea_color * f[2])


def sweep_init_distance(P, scene, rows, methods):
    waves, camera, geo = scene
    truths, _ = truths_and_inits(jax.random.key(11), P)
    images = jax.vmap(lambda t: lfx.shade(geo, camera, t))(truths)
    for d in (1.0, 3.0, 10.0, 30.0, 60.0, 100.0):
        keys = jax.random.split(jax.random.key(int(d * 10)), P)
        inits = jax.vmap(lambda k, t: offset_init(k, t, d))(keys, truths)
        for m in methods:
            k = P // 2 if m == "Adam-400" else P  # Adam-400 is slow: half the problems
            sub = lambda t, k=k: jax.tree.map(lambda a: a[:k], t)  # noqa: E731
            r = run_point(m, images[:k], sub(inits), sub(truths), geo, camera)
            rows.append(dict(axis="init distance [deg]", x=d, **r))
            print(f"  init {d:5.0f} deg  {m:10s} success {r['success']:.2f} reported {r['reported']:.2f}")


def sweep_noise(P, scene, rows, methods):
    waves, camera, geo = scene
    truths, inits = truths_and_inits(jax.random.key(12), P)
    clean = jax.vmap(lambda t: lfx.shade(geo, camera, t))(truths)
    for sigma in (0.0, 0.003, 0.01, 0.03, 0.1):
        keys = jax.random.split(jax.random.key(int(sigma * 1e4) + 1), P)
        imgs, _ = jax.vmap(lambda k, c: lfx.noisy_observation(k, c, sigma))(keys, clean)
        for m in methods:
            r = run_point(m, imgs, inits, truths, geo, camera, noisy=True)
            rows.append(dict(axis="noise sigma (display)", x=sigma, **r))
            print(f"  noise {sigma:5.3f}  {m:10s} success {r['success']:.2f} reported {r['reported']:.2f}")


def sweep_elevation(P, scene, rows, methods):
    waves, camera, geo = scene
    for el in (1.0, 3.0, 6.0, 12.0, 20.0, 30.0, 40.0, 50.0, 65.0, 80.0, 88.0):
        e = math.radians(el)
        truths, inits = truths_and_inits(jax.random.key(13 + int(el)), P, elevation=(e, e + 1e-9))
        images = jax.vmap(lambda t: lfx.shade(geo, camera, t))(truths)
        for m in methods:
            r = run_point(m, images, inits, truths, geo, camera)
            rows.append(dict(axis="sun elevation [deg]", x=el, **r))
            print(f"  elevation {el:4.0f}  {m:10s} success {r['success']:.2f} reported {r['reported']:.2f}"
                  f" false {r['false_success']:.2f}")


def sweep_pitch(P, n, rows, methods):
    for pitch in (0.03, 0.06, 0.1, 0.2, 0.35, 0.6, 0.9):
        waves, camera, geo = lfx.make_scene(100, n, pitch=pitch, dtype=jnp.float64)
        truths, inits = truths_and_inits(jax.random.key(14), P, elevation=(0.7 * pitch, 1.3 * pitch))
        images = jax.vmap(lambda t: lfx.shade(geo, camera, t))(truths)
        for m in methods:
            r = run_point(m, images, inits, truths, geo, camera)
            rows.append(dict(axis="view angle (pitch) [rad]", x=pitch, **r))
            print(f"  pitch {pitch:4.2f}  {m:10s} success {r['success']:.2f} reported {r['reported']:.2f}")


def sweep_roughness(P, n, rows, methods):
    for scale in (1e-3, 1e-2, 0.1, 1.0, 10.0):
        waves, camera, geo = lfx.make_scene(100, n, roughness_scale=scale, dtype=jnp.float64)
        truths, inits = truths_and_inits(jax.random.key(15), P)
        images = jax.vmap(lambda t: lfx.shade(geo, camera, t))(truths)
        med = float(np.median(np.asarray(geo.roughness)[np.asarray(geo.mask)]))
        for m in methods:
            r = run_point(m, images, inits, truths, geo, camera)
            rows.append(dict(axis="roughness scale", x=scale, median_roughness=med, **r))
            print(f"  roughness x{scale:g} (median {med:.1e})  {m:10s} success {r['success']:.2f}"
                  f" reported {r['reported']:.2f}")


HORIZON_AZIMUTHS = (("front", 0.0), ("front, 0.3 rad", 0.3), ("frame edge, 0.6 rad", 0.6),
                    ("beside", math.pi / 2), ("behind", math.pi))
HORIZON_ELEVATIONS = (0.15, 0.3, 0.45, 0.7)


def horizon_scene(seed, n=48, n_waves=30):
    """The horizon view (module docstring) on the sea state of ``seed``: waves, camera, geometry."""
    from jaxocean import camera as cam
    from jaxocean import render
    from jaxocean.waves import GRAVITY, make_waves

    rng = np.random.default_rng(seed)
    om = np.sort(rng.uniform(0.8, 3.0, n_waves))
    amp = rng.uniform(0.02, 0.2, n_waves) * GRAVITY / om**2
    waves = make_waves(amp, om, rng.uniform(-1.0, 1.0, n_waves), rng.uniform(0, 2 * np.pi, n_waves),
                       dtype=jnp.float64)
    camera = cam.make_camera(height=10.0, pitch=math.radians(20), fov=math.radians(50), resolution=(n, n),
                             dtype=jnp.float64)
    return waves, camera, render.geometry(waves, camera, 0.0, plan=None)


def _glitter_fraction(geo, camera, truth, image):
    from jaxocean.fit import _image_inputs as inp
    from jaxocean.fit import _photometry as ph

    w = inp.pixel_weights("display", None, image.shape[:2], image.dtype, image, 1.0, "bruneton", 0.9)
    data = ph.prepare(image, geo.normal, geo.slope_variance, camera, w, 0.0)
    b = ph.sun_term(data, shading.sun_direction(truth))[..., None] * truth.sun_color
    return float(jnp.sum((w * b) ** 2) / jnp.sum((w * image) ** 2))


def sweep_horizon(seas, n, rows):
    fitter = jax.jit(jax.vmap(lambda img, init, geo, camera: fit.lighting(
        img, geo, camera, init=init, throw=False, batching="sequential"), in_axes=(0, 0, None, None)))
    for label, az in HORIZON_AZIMUTHS:
        recs = []
        t0 = time.perf_counter()
        for sea in range(seas):
            waves, camera, geo = horizon_scene(1000 + sea, n)
            truths = [shading.make_lighting(sun_azimuth=az, sun_elevation=el, dtype=jnp.float64)
                      for el in HORIZON_ELEVATIONS]
            images = jnp.stack([lfx.shade(geo, camera, t) for t in truths])
            keys = jax.random.split(jax.random.key(100 * sea + int(10 * az)), len(truths))
            inits = lfx.stack([fit.random_lighting(k, dtype=jnp.float64) for k in keys])
            res = jax.block_until_ready(fitter(images, inits, geo, camera))
            e = lfx.errors(res.lighting, lfx.stack(truths))
            ok = lfx.success_of(e)
            for i, (t, img) in enumerate(zip(truths, images)):
                recs.append(dict(
                    sea=sea, elevation=float(t.sun_elevation), glitter=_glitter_fraction(geo, camera, t, img),
                    recovered=bool(ok[i]), reported=bool(res.success[i]), sun_deg=float(e["sun_angle_deg"][i]),
                    color_rel=float(max(e[c][i] for c in fit.COLOR_FIELDS)),
                    sky_sea_rel=float(max(e["sky_color"][i], e["sea_color"][i])),
                    determined={k: bool(v[i]) for k, v in res.determined.items()},
                    loss=float(res.loss[i]), loss_bound=float(res.loss_bound[i]), steps=int(res.steps[i])))
        wall = time.perf_counter() - t0
        inside = [r for r in recs if r["glitter"] >= 1e-3]
        flank = [r for r in recs if 1e-8 <= r["glitter"] < 1e-3]
        outside = [r for r in recs if r["glitter"] < 1e-8]
        row = dict(axis="sun position (horizon in view)", position=label, azimuth=az, n=len(recs),
                   in_frame=len(inside),
                   recovered_in_frame=float(np.mean([r["recovered"] for r in inside])) if inside else None,
                   reported_success=float(np.mean([r["reported"] for r in recs])),
                   false_success=int(sum(r["reported"] and not r["recovered"] for r in recs)),
                   missed_reported_failed=int(sum((not r["reported"]) and not r["recovered"] for r in inside)),
                   flank_only=len(flank), flank_recovered=int(sum(r["recovered"] and r["reported"] for r in flank)),
                   flank_reported_failed=int(sum(not r["reported"] for r in flank)),
                   out_of_frame=len(outside),
                   undetermined_said=int(sum((not r["reported"]) and not r["determined"]["sun_direction"]
                                             for r in outside)),
                   sky_sea_right_out_of_frame=int(sum(r["sky_sea_rel"] < 1e-4 and r["determined"]["sky_color"]
                                                      and r["determined"]["sea_color"] for r in outside)),
                   wall_s_with_compile=wall, loadavg_1min=os.getloadavg()[0], problems=recs)
        rows.append(row)
        print(f"  {label:22s} n {row['n']:3d} in frame {row['in_frame']:3d} recovered {row['recovered_in_frame']} "
              f"false {row['false_success']} flank {row['flank_only']} (recovered {row['flank_recovered']}, failed "
              f"{row['flank_reported_failed']}) none {row['out_of_frame']} undetermined said {row['undetermined_said']} "
              f"sky/sea right {row['sky_sea_right_out_of_frame']} ({wall:.0f} s)", flush=True)


def plot_horizon(rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(9, 4.5))
    x = np.arange(len(rows))
    n = np.array([r["n"] for r in rows], float)
    rec = np.array([(r["recovered_in_frame"] or 0.0) * r["in_frame"] for r in rows]) / n
    miss = np.array([r["missed_reported_failed"] for r in rows]) / n
    undet = np.array([r["undetermined_said"] for r in rows]) / n
    flank_ok = np.array([r["flank_recovered"] for r in rows]) / n
    flank_failed = np.array([r["flank_reported_failed"] for r in rows]) / n
    false = np.array([r["false_success"] for r in rows]) / n
    parts = [(rec, "C2", "glitter in frame: recovered, success"),
             (miss, "C1", "glitter in frame: missed, reported failed"),
             (flank_ok, "C8", "flank only: recovered, success"),
             (flank_failed, "C7", "flank only: reported failed"),
             (undet, "C0", "no glitter: 'sun direction undetermined'"),
             (false, "C3", "false success")]
    bottom = np.zeros(len(rows))
    for v, c, label in parts:
        ax.bar(x, v, bottom=bottom, color=c, label=label)
        bottom = bottom + v
    ax.set_xticks(x, [r["position"] for r in rows])
    ax.set(ylabel="fraction of problems", ylim=(0, 1.05))
    ax.legend(fontsize=8, loc="lower left")
    ax.set_title("fit.lighting, horizon in view (48^2, float64, noise-free; sun < 0.01 deg and colours < 1e-4)",
                 fontsize=9)
    benchutil.save_figure(fig, "stability_lighting_horizon")


def plot(rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.lines import Line2D

    axes_names = list(dict.fromkeys(r["axis"] for r in rows))
    fig, axes = plt.subplots(2, 3, figsize=(14, 8))
    axes = axes.ravel()
    colors = dict(zip(METHODS, ("C0", "C4", "C1", "C2", "C3")))
    for ax, name in zip(axes, axes_names):
        rs = [r for r in rows if r["axis"] == name]
        for m in METHODS:
            pts = [r for r in rs if r["method"] == m]
            if not pts:
                continue
            x = [max(p["x"], 1e-4) for p in pts]
            ax.plot(x, [p["success"] for p in pts], "o-", color=colors[m])
            ax.plot(x, [p["false_success"] for p in pts], "x:", color=colors[m], alpha=0.8)
        if name.startswith(("init", "noise", "roughness")):
            ax.set_xscale("log")
        ax.set(xlabel=name, ylim=(-0.03, 1.03), ylabel="rate")
        ax.grid(True, alpha=0.3)
    for ax in axes[len(axes_names):]:
        ax.axis("off")
    handles = [Line2D([], [], color=colors[m], marker="o", label=f"{m}: correct") for m in METHODS]
    handles += [Line2D([], [], color="k", marker="x", ls=":",
                       label="same colour, x: false success\n(reported success, wrong answer)")]
    axes[-1].legend(handles=handles, loc="center", fontsize=10)
    fig.suptitle("Lighting fit: where methods fail (64x64, float64, 16 problems per point; "
                 "noise-free bar: sun < 0.01 deg,\ncolours < 1e-4; noise bar: sun < 0.5 deg, colours < 5%; "
                 "0 noise plotted at 1e-4)")
    fig.tight_layout()
    fig.savefig(benchutil.RESULTS / "stability_lighting.png", dpi=110)
    plt.close(fig)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--horizon", action="store_true", help="run the horizon sweep alone")
    parser.add_argument("--seas", type=int, default=4, help="sea states of the horizon sweep")
    args = parser.parse_args(argv)
    if args.horizon:
        rows = []
        t0 = time.perf_counter()
        with jax.enable_x64(True):
            print("[sun position, horizon in view]")
            sweep_horizon(args.seas, 48, rows)
        benchutil.save("stability_lighting_horizon", rows, dict(seas=args.seas, resolution=48))
        plot_horizon(rows)
        print(f"done in {time.perf_counter() - t0:.0f} s")
        return
    P = 6 if args.quick else 16
    n = 48 if args.quick else 64
    rows = []
    t0 = time.perf_counter()
    with jax.enable_x64(True):
        scene = lfx.make_scene(100, n, dtype=jnp.float64)
        print("[init distance]")
        sweep_init_distance(P, scene, rows, ("default", "from init", "plain LM", "Adam-400"))
        print("[noise]")
        sweep_noise(P, scene, rows, ("default", "display space", "from init"))
        print("[sun elevation]")
        sweep_elevation(P, scene, rows, ("default", "from init"))
        print("[view angle]")
        sweep_pitch(P, n, rows, ("default", "from init"))
        print("[roughness]")
        sweep_roughness(P, n, rows, ("default", "from init"))
    name = "stability_lighting_quick" if args.quick else "stability_lighting"
    benchutil.save(name, rows, dict(quick=args.quick, problems_per_point=P, resolution=n))
    plot(rows)
    print(f"done in {time.perf_counter() - t0:.0f} s")


if __name__ == "__main__":
    main()
