"""How much one pixel's colour says about its slope, along and across the view.

For every sea pixel of the test scenes' first frames, at the true geometry, the derivative of
the pixel's linear RGB with respect to the slope along the view and across it
(``jax.jacfwd`` of ``shading.shade_pixel`` through the normal ``normalize(-s_x, -s_y, 1)``),
relative to the pixel's value. With the stored frames' own noise -- half-float rounding,
a relative standard deviation of ``2**-11 / sqrt(3)`` per channel (uniform rounding, unit
roundoff 2**-11) -- and the scene's slope variance as a Gaussian prior per pixel, the
joint posterior covariance of the two slope components (roughness and lighting known) gives
a per-pixel skill for each:

    skill_pixel = 1 - mean(posterior variance) / prior variance

i.e. what an estimator that sees each pixel alone (with the lighting known) could reach.
A network sees neighbours too and the sea is spatially coherent, so this is not an upper
bound for it; it says where the information is and how unevenly it is split between the two
components. Writes experiments/results/geometry_identifiability.json and .png.
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from jaxocean import camera as cam  # noqa: E402
from jaxocean import plots, shading  # noqa: E402
from jaxocean._math import normal_from_slope  # noqa: E402
from jaxocean.files import write_json  # noqa: E402
from jaxocean.io.dataset import Dataset  # noqa: E402

HALF_NOISE = 2.0 ** -11 / math.sqrt(3.0)


def _pixel_color(slope, sv, view, lighting):
    return shading.shade_pixel(normal_from_slope(slope), sv[0], sv[1], view, lighting)


@jax.jit
def _sensitivity(slope, sv, view, lighting, along, across):
    color = jax.vmap(lambda s, v, w: _pixel_color(s, v, w, lighting))(slope, sv, view)
    J = jax.vmap(jax.jacfwd(lambda s, v, w: _pixel_color(s, v, w, lighting)))(slope, sv, view)  # (N, 3, 2)
    rel = J / jnp.maximum(color, 1e-12)[..., None]
    return rel @ along, rel @ across  # (N, 3) relative change per unit slope


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--out", default=str(HERE / "results" / "geometry_identifiability"))
    args = ap.parse_args(argv)
    data = Dataset(args.dataset)
    rows = []
    for s in data.splits["test"]:
        scene, frame = data.scene(s), data.frame(s, 0)
        mask = frame.mask > 0.5
        view = np.asarray(cam.intersect_sea(scene.camera).view)[mask]
        yaw = float(scene.camera.yaw)
        along = np.array([math.cos(yaw), math.sin(yaw)])
        across = np.array([math.sin(yaw), -math.cos(yaw)])
        # unfloored: the few overturned facets (n_z < 0) of folding crests count as they are
        slope = -frame.normal[mask][:, :2] / frame.normal[mask][:, 2:3]
        d_along, d_across = (np.asarray(x) for x in _sensitivity(slope, frame.slope_variance[mask], view,
                                                                 scene.lighting, along.astype(np.float32),
                                                                 across.astype(np.float32)))
        s_along, s_across = slope @ along, slope @ across
        row = {"scene": s, "pitch_deg": math.degrees(float(scene.camera.pitch)),
               "height_m": float(scene.camera.height)}
        priors = np.array([max(float(np.var(s_along)), 1e-12), max(float(np.var(s_across)), 1e-12)])
        D = np.stack([d_along, d_across], -1)  # (N, 3 channels, 2 components)
        # joint posterior of both components per pixel: the three channels respond almost in
        # proportion (through the Fresnel term), so together they pin one slope direction
        info = np.einsum("nci,ncj->nij", D, D) / HALF_NOISE ** 2
        post = np.linalg.inv(np.diag(1.0 / priors)[None] + info)
        for i, (name, d) in enumerate((("along", d_along), ("across", d_across))):
            row[f"skill_pixel_{name}"] = 1.0 - float(np.mean(post[:, i, i])) / priors[i]
            row[f"sensitivity_{name}_median"] = float(np.median(np.sqrt(np.sum(d ** 2, -1))))
            row[f"slope_std_{name}"] = math.sqrt(priors[i])
        rows.append(row)
    summary = {k: float(np.median([r[k] for r in rows])) for k in rows[0] if k not in ("scene",)}
    write_json(args.out + ".json", {"noise_relative": HALF_NOISE, "rows": rows, "median": summary})
    _chart(args.out + ".png", rows)
    for k, v in summary.items():
        print(f"{k:<32} {v:.4g}")


def _chart(path, rows):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    p = [r["pitch_deg"] for r in rows]
    for name, m in (("along", "o"), ("across", "x")):
        axes[0].scatter(p, [r[f"sensitivity_{name}_median"] for r in rows], marker=m, label=name)
        axes[1].scatter(p, [r[f"skill_pixel_{name}"] for r in rows], marker=m, label=name)
    axes[0].set_yscale("log")
    axes[0].set_ylabel("median |d log I / d slope| per pixel")
    axes[1].set_ylabel("per-pixel skill (half-float noise)")
    for a in axes:
        a.set_xlabel("camera pitch below the horizon [deg]")
        a.legend()
    fig.tight_layout()
    plots.save_figure(fig, path)


if __name__ == "__main__":
    main()
