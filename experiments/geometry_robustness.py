"""Geometry networks on display-referred input: the test split as `reconstruct` sees camera files.

    python experiments/geometry_robustness.py DATASET --model NAME=PATH [--model NAME=PATH ...]

Every test frame of DATASET (a ``jaxocean simulate`` dataset) is scored in several input
variants, each made by :func:`jaxocean.nn.augment.display_roundtrip` -- the frame tone-mapped
with an exposure the model is not told (log-uniform in [0.5, 2], drawn per scene from a fixed
key, the range of ``experiments/reconstruct.py``), Gaussian display noise added, clipped,
quantised to 8 bits and turned back into radiance relative to the exposure with
:func:`jaxocean.radiometry.to_linear`, as stage 1 of ``jaxocean reconstruct`` does:

* ``linear``: the stored half-float radiance, as in Table 1 of NETS.md;
* ``bruneton 8-bit, sigma 0 / 0.01 / 0.03``: the library's tone curve (the response
  ``experiments/reconstruct.py`` writes its PNG frames with);
* ``srgb 8-bit, sigma 0.01``: the sRGB curve (``reconstruct``'s default response).

Rows: the flat normal and every ``--model``. Columns: within 5 deg, normal MAE [rad],
1 - cos, slope skill along / across the view over pixels tilted < 60 deg, median per-scene
skill, log10 slope-variance MSE, and the number of test scenes where the model's 1 - cos is
below flat's. Writes ``experiments/results/geometry_robustness.json`` and ``.png``.
"""

from __future__ import annotations

import argparse
import functools
import math
import sys
import time
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from jaxocean import plots, radiometry  # noqa: E402
from jaxocean.files import write_json  # noqa: E402
from jaxocean.io.dataset import Dataset  # noqa: E402
from jaxocean.nn import augment as aug  # noqa: E402
from jaxocean.nn import geometry as geo  # noqa: E402
from jaxocean.nn import geometry_train as gt  # noqa: E402

# name -> (response kind or None for the stored radiance, display noise sigma)
VARIANTS = {"linear": (None, 0.0), "bruneton 8-bit, sigma 0": ("bruneton", 0.0),
            "bruneton 8-bit, sigma 0.01": ("bruneton", 0.01), "bruneton 8-bit, sigma 0.03": ("bruneton", 0.03),
            "srgb 8-bit, sigma 0.01": ("srgb", 0.01)}
EXPOSURE = (0.5, 2.0)
COLUMNS = ("within_5deg", "normal_mae", "cos_loss", "unfolded_skill_along", "unfolded_skill_across",
           "median_scene_skill_along", "median_scene_skill_across", "log_slope_variance_mse")


@functools.partial(jax.jit, static_argnums=(2, 3))
def _degrade(key, images, kind, noise):
    k_exp, k_noise = jax.random.split(key)
    exposure = jnp.exp(jax.random.uniform(k_exp, (), jnp.float32, math.log(EXPOSURE[0]), math.log(EXPOSURE[1])))
    return aug.display_roundtrip(k_noise, images, radiometry.Response(kind), exposure, noise, bits=8)


def variant_method(method, kind, noise, key=jax.random.key(2024)):
    """``method`` shown each scene's frames through the variant's round trip (one exposure per
    scene, key ``fold_in(key, scene.seed)``: the same frames for every method)."""
    if kind is None:
        return method

    def wrapped(images, scene):
        k = jax.random.fold_in(key, int(scene.seed))
        return method(np.asarray(_degrade(k, jnp.asarray(images), kind, noise)), scene)

    return wrapped


def _row(r, flat_scenes):
    row = {k: r[k] for k in COLUMNS if not k.startswith("median")}
    sc = r["scenes"]
    for c in ("along", "across"):
        row[f"median_scene_skill_{c}"] = float(np.median([v[f"skill_{c}"] for v in sc.values()]))
    row["scenes_better_than_flat"] = int(sum(v["cos_loss"] < flat_scenes[s]["cos_loss"] for s, v in sc.items()))
    row["scenes"] = len(sc)
    row["per_scene_cos_loss"] = {str(s): v["cos_loss"] for s, v in sc.items()}
    return row


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--model", action="append", default=[], help="NAME=PATH of a model (repeatable)")
    ap.add_argument("--out", default=str(HERE / "results" / "geometry_robustness"))
    args = ap.parse_args(argv)
    data = Dataset(args.dataset)
    models = dict(m.split("=", 1) for m in args.model) or {"shipped": str(geo.PRETRAINED_PATH)}
    t0 = time.perf_counter()
    flat = gt.evaluate(gt.flat_method, data, "test")
    flat_row = _row(flat, flat["scenes"])
    table = {}
    for vname, (kind, noise) in VARIANTS.items():
        table[vname] = {"flat normal": flat_row}
        for name, path in models.items():
            method = variant_method(gt.model_method(geo.load(path)), kind, noise)
            table[vname][name] = _row(gt.evaluate(method, data, "test"), flat["scenes"])
            print(f"{vname:<28} {name:<34}" + " ".join(f"{table[vname][name][c]:.4g}" for c in COLUMNS)
                  + f"  beats flat on {table[vname][name]['scenes_better_than_flat']}/{table[vname][name]['scenes']}",
                  flush=True)
    result = {"dataset": str(args.dataset), "dataset_settings": data.settings, "test_scenes": len(data.splits["test"]),
              "frames": flat["frames"], "models": models, "exposure_range": list(EXPOSURE),
              "variants": {k: {"response": v[0], "noise_sigma": v[1], "bits": None if v[0] is None else 8}
                           for k, v in VARIANTS.items()},
              "table": table, "wall_s": time.perf_counter() - t0,
              "units": {"normal_mae": "radians", "cos_loss": "mean 1 - cos over sea pixels",
                        "unfolded_skill_*": "slope skill over pixels whose true normal is tilted < 60 deg",
                        "noise_sigma": "standard deviation in display units (range [0, 1])"}}
    write_json(args.out + ".json", result)
    _chart(args.out + ".png", table, ["flat normal"] + list(models))


def _chart(path, table, names):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    variants = list(table)
    panels = (("cos_loss", "mean 1 - cos (lower is better)"), ("within_5deg", "within 5 deg"),
              ("unfolded_skill_along", "slope skill along, tilt < 60 deg"),
              ("scenes_better_than_flat", "test scenes better than flat"))
    fig, axes = plt.subplots(1, len(panels), figsize=(17, 4.2))
    x = np.arange(len(variants))
    w = 0.8 / len(names)
    for ax, (col, title) in zip(axes, panels):
        for i, name in enumerate(names):
            vals = [table[v][name][col] for v in variants]
            if col == "scenes_better_than_flat" and name == "flat normal":
                continue
            ax.bar(x + (i - (len(names) - 1) / 2) * w, np.maximum(vals, -1) if "skill" in col else vals, w,
                   label=name, color=f"C{i}")
        ax.set_xticks(x, [v.replace(", ", "\n") for v in variants], fontsize=6)
        ax.set_title(title, fontsize=9)
        ax.axhline(0, color="k", lw=0.5)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    plots.save_figure(fig, path)


if __name__ == "__main__":
    main()
