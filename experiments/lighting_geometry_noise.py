"""The lighting fit's success flag on geometry with a stated normal error (reconstruct's stage 3).

Reconstruct fits the lighting of a frame with the geometry network's normals held fixed;
their error (``reconstruct.GEOMETRY_NOISE`` = 0.084 rad per tangent component) is not image
noise. ``fit.lighting(..., normal_noise=sigma)`` propagates it through the shading (the JVP
of the model image with respect to each pixel's normal at the fitted lighting) into the loss
bound and the fitted fields' standard deviations. This script measures whether the flag is
then informative and never a false success.

Views: ``--scenes`` scenes of :func:`jaxocean.io.dataset.sample_scene` (64^2, float32, the
dataset's ranges except the pitch, 0.15-0.9 rad below the horizon, so that part of the
views have the horizon in the image), each with the sun *front* (azimuth 0, the direction
the camera looks), *beside* (pi/2), *behind* (pi) at the scene's elevation and colours, and
*overcast* (sun colour 0; fitted as reconstruct does for overcast footage: sky and sea
colours only). The truth is rendered noise-free by ``render.render(..., with_geometry=True)``.

Geometry given to the fit: the true normals tilted about their tangent axes (``--sigmas``:
0.084 rad, the network's stated error, and smaller ones, to see where the flag can pass) by

* ``independent``: Gaussian, sigma per component, independent per pixel;
* ``smooth``: a Gaussian random field of the same sigma per component, correlated over
  ``--length`` pixels (white noise through a Gaussian filter of ``length / sqrt(2)`` pixels,
  so that the correlation is ``exp(-d^2 / (2 length^2))``), like a network's error;

with the slope variances unchanged. Fits (``fit.lighting`` defaults otherwise, ``noise=None``):

* ``image noise only``: the flag as it was (no ``normal_noise``);
* ``normal_noise``: ``normal_noise=sigma``, errors taken as independent;
* ``normal_noise + correlation``: also ``normal_correlation=length`` (smooth errors only).

Per fit: success, each field's determined flag, sun angle error [deg], colour errors (the
largest channel error relative to the colour's brightest channel, the scale of
``determined``; also the largest relative error per channel, ``color_err_channel``). *False success*: success with the sun more than 2 deg off (sun
fitted) or a fitted colour more than 10% off. *False determined*: a field flagged
determined with that error (also when the fit as a whole fails).

Usage: ``python experiments/lighting_geometry_noise.py [--scenes 6] [--sigmas 0.084 0.03 0.01]
[--length 6]``; writes ``experiments/results/lighting_geometry_noise.{json,png}``.
"""

from __future__ import annotations

import argparse
import math
import os
import sys
import time

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import camera as cam  # noqa: E402
from jaxocean import fit, render, shading  # noqa: E402
from jaxocean.io import dataset  # noqa: E402

SUNS = {"front": 0.0, "beside": math.pi / 2, "behind": math.pi, "overcast": None}
SUN_BAR_DEG = 2.0
COLOR_BAR = 0.1
COLORS = ("sun_color", "sky_color", "sea_color")


def perturb(normal, sea, sigma, length, key):
    """The unit normals ``(H, W, 3)`` tilted on the sea by ``sigma`` [rad] per tangent axis,
    independent per pixel (``length`` 0) or correlated over ``length`` pixels."""
    H, W = normal.shape[:2]
    ab = np.asarray(jax.random.normal(key, (2, H, W)), np.float64)
    if length > 0:
        from scipy.ndimage import gaussian_filter

        ab = np.stack([gaussian_filter(f, length / math.sqrt(2), mode="reflect") for f in ab])
        ab = ab / ab[:, np.asarray(sea)].std(axis=1)[:, None, None]
    n = jnp.asarray(normal)
    t_x, t_y = shading.tangent_frame(n)
    tilted = n + sigma * (ab[0][..., None] * t_x + ab[1][..., None] * t_y)
    tilted = tilted / jnp.linalg.norm(tilted, axis=-1, keepdims=True)
    return jnp.where(jnp.asarray(sea)[..., None], tilted, n).astype(normal.dtype)


def view(i, sun, args):
    ranges = dataset.SceneRanges(pitch=(0.15, 0.9))
    s = dataset.sample_scene(jax.random.PRNGKey(1000 + i), ranges, resolution=(args.side, args.side))
    light = s.lighting
    if SUNS[sun] is None:
        light = light._replace(sun_color=jnp.zeros(3, light.sun_color.dtype))
    else:
        light = light._replace(sun_azimuth=jnp.asarray(SUNS[sun], light.sun_azimuth.dtype))
    image, geo = render.render(s.waves, s.camera, light, 0.0, with_geometry=True)
    horizon = float(s.camera.pitch) < 0.5 * float(s.camera.fov)
    return s, light, image, geo, horizon


def one_fit(image, geo, normal, camera, light, sun, sigma, corr):
    g = geo._replace(normal=normal)
    kw = {}
    if SUNS[sun] is None:
        kw = dict(init=shading.make_lighting(sun_color=(0.0, 0.0, 0.0)), fit=("sky_color", "sea_color"))
    if sigma is not None:
        kw["normal_noise"] = sigma
        if corr:
            kw["normal_correlation"] = corr
    t0 = time.perf_counter()
    r = fit.lighting(image, g, camera, throw=False, **kw)
    secs = time.perf_counter() - t0
    err = fit.lighting_error(r.lighting, light)
    fitted = kw.get("fit", fit.FIT_FIELDS)
    bad = {"sun_direction": float(err["sun_angle_deg"]) > SUN_BAR_DEG} if "sun_direction" in fitted else {}
    color_err = {c: colour_error(getattr(r.lighting, c), getattr(light, c)) for c in COLORS if c in fitted}
    for c in COLORS:
        if c in fitted:
            bad[c] = color_err[c] > COLOR_BAR
    det = {n: bool(r.determined[n]) for n in fitted}
    return dict(success=bool(r.success), loss=float(r.loss), loss_bound=float(r.loss_bound),
                geometry_loss=float(r.geometry_loss), glitter=float(r.glitter),
                sun_std_deg=math.degrees(float(r.std["sun_direction"])) if "sun_direction" in fitted else None,
                sun_err_deg=float(err["sun_angle_deg"]) if "sun_direction" in fitted else None,
                color_err=color_err, color_err_channel={c: float(err[c]) for c in COLORS if c in fitted},
                determined=det, wrong={n: bool(b) for n, b in bad.items()},
                false_success=bool(r.success) and any(bad.values()),
                false_determined=[n for n in fitted if det[n] and bad[n]], seconds=secs)


def colour_error(fitted, truth):
    """A colour's error relative to its brightest channel (the scale of ``determined``):
    ``max |fitted - truth| / max(truth)``."""
    f, t = np.asarray(fitted, np.float64), np.asarray(truth, np.float64)
    return float(np.max(np.abs(f - t)) / np.max(t))


METHODS = (("image noise only", None, 0.0), ("normal_noise", "sigma", 0.0),
           ("normal_noise + correlation", "sigma", "length"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--scenes", type=int, default=6)
    ap.add_argument("--side", type=int, default=64)
    ap.add_argument("--sigmas", type=float, nargs="+", default=[0.084, 0.03, 0.01])
    ap.add_argument("--length", type=float, default=6.0)
    ap.add_argument("--out", default="lighting_geometry_noise")
    args = ap.parse_args()
    rows, t_start = [], time.perf_counter()
    for i in range(args.scenes):
        for sun in SUNS:
            s, light, image, geo, horizon = view(i, sun, args)
            sea = cam.intersect_sea(s.camera).mask
            for size, (kind, length) in ((a, b) for a in args.sigmas for b in (("independent", 0.0),
                                                                                 ("smooth", args.length))):
                normal = perturb(geo.normal, sea, size, length, jax.random.PRNGKey(7 * i + (kind == "smooth")))
                angle = np.degrees(np.arccos(np.clip(np.sum(np.asarray(normal) * np.asarray(geo.normal), -1), -1, 1)))
                for method, sig, corr in METHODS:
                    if kind == "independent" and corr:
                        continue
                    sigma = None if sig is None else size
                    corr = args.length if corr else 0.0
                    out = one_fit(image, geo, normal, s.camera, light, sun, sigma, corr)
                    out.update(scene=i, sun=sun, sigma=size, perturbation=kind, method=method, horizon=horizon,
                               pitch=float(s.camera.pitch), fov=float(s.camera.fov),
                               sun_elevation_deg=math.degrees(float(light.sun_elevation)),
                               mean_tilt_deg=float(angle[np.asarray(sea)].mean()))
                    rows.append(out)
                    print(f"scene {i} {sun:8s} {size:.3f} {kind:11s} {method:27s} success={out['success']!s:5s} "
                          f"sun err={out['sun_err_deg']} std={out['sun_std_deg']} det={out['determined']} "
                          f"loss/bound={out['loss'] / out['loss_bound']:.3g} {out['seconds']:.1f}s", flush=True)
    summary = summarise(rows)
    for line in table(summary):
        print(line)
    meta = dict(args=vars(args), wall_s=time.perf_counter() - t_start, load=os.getloadavg(),
                sun_bar_deg=SUN_BAR_DEG, color_bar=COLOR_BAR, summary=summary)
    benchutil.save(args.out, rows, meta)
    chart(rows, args)


def _key(r):
    return r["sigma"], r["perturbation"], r["method"], "overcast" if r["sun"] == "overcast" else "sun"


def summarise(rows):
    out, keys = [], []
    for r in rows:
        if _key(r) not in keys:
            keys.append(_key(r))
    for key in keys:
        g = [r for r in rows if _key(r) == key]
        sigma, pert, method, kind = key
        ok = [r for r in g if r["success"]]
        entry = dict(sigma=sigma, perturbation=pert, method=method, fit=kind, views=len(g), successes=len(ok),
                     false_successes=sum(r["false_success"] for r in g),
                     false_determined=sum(bool(r["false_determined"]) for r in g),
                     success_by_sun={sun: f"{sum(r['success'] for r in g if r['sun'] == sun)}/"
                                          f"{sum(r['sun'] == sun for r in g)}" for sun in SUNS
                                     if any(r["sun"] == sun for r in g)},
                     determined={n: sum(r["determined"].get(n, False) for r in g)
                                 for n in ("sun_direction",) + COLORS})
        if ok:
            if ok[0]["sun_err_deg"] is not None:
                e = np.array([r["sun_err_deg"] for r in ok])
                entry["sun_err_deg_median_max"] = [float(np.median(e)), float(e.max())]
            for c in COLORS:
                e = [r["color_err"][c] for r in ok if c in r["color_err"]]
                if e:
                    entry[f"{c}_err_median_max"] = [float(np.median(e)), float(np.max(e))]
        out.append(entry)
    return out


def table(summary):
    yield ("| sigma [rad] | perturbation | flag | fit | success | false successes | fields falsely determined | "
           "sun error of successes (median / max) [deg] | colour errors of successes (max) |")
    yield "|---|---|---|---|---|---|---|---|---|"
    for e in summary:
        sun = e.get("sun_err_deg_median_max")
        cols = ", ".join(f"{c.split('_')[0]} {e[c + '_err_median_max'][1]:.3f}" for c in COLORS
                         if c + "_err_median_max" in e)
        yield (f"| {e['sigma']:g} | {e['perturbation']} | {e['method']} | {e['fit']} | {e['successes']}/{e['views']} "
               f"({', '.join(f'{k} {v}' for k, v in e['success_by_sun'].items())}) | {e['false_successes']} | "
               f"{e['false_determined']} | {'-' if sun is None else f'{sun[0]:.2f} / {sun[1]:.2f}'} | {cols or '-'} |")


def chart(rows, args):
    plt = benchutil.pyplot()
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.6))
    marks = {"front": "o", "beside": "s", "behind": "^"}
    colours = {sig: f"C{k}" for k, sig in enumerate(args.sigmas)}
    panels = (("independent", "normal_noise"), ("smooth", "normal_noise"), ("smooth", "normal_noise + correlation"))
    for ax, (pert, method) in zip(axes, panels):
        for r in rows:
            if (r["perturbation"], r["method"]) != (pert, method) or r["sun"] == "overcast":
                continue
            c = colours[r["sigma"]]
            ax.scatter(min(max(r["sun_std_deg"], 1e-3), 1e3), max(r["sun_err_deg"], 1e-3), marker=marks[r["sun"]],
                       edgecolors=c, facecolors=c if r["success"] else "none", s=36)
        ax.axvline(fit.lighting_fit.DETERMINED_SUN_DEG, color="k", lw=0.8, ls=":")
        ax.axhline(SUN_BAR_DEG, color="k", lw=0.8, ls="--")
        ax.set_xscale("log"), ax.set_yscale("log")
        ax.set_xlabel("reported sun std [deg] (dotted: determined below)")
        ax.set_ylabel("sun angle error [deg] (dashed: false-success bar)")
        ax.set_title(f"{pert} tilt, fit told: {method}" + (f" ({args.length:g} px)" if "corr" in method else ""),
                     fontsize=9)
    handles = [plt.Line2D([], [], ls="", marker="o", color=c, label=f"sigma {sig:g} rad") for sig, c in colours.items()]
    handles += [plt.Line2D([], [], ls="", marker=mk, color="k", mfc="none", label=f"sun {s}") for s, mk in marks.items()]
    axes[0].legend(handles=handles, fontsize=7, loc="lower right", title="filled: success", title_fontsize=7)
    benchutil.save_figure(fig, args.out)


if __name__ == "__main__":
    main()
