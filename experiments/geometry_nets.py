"""The paper's Table 1 redone: image -> per-pixel normal and roughness, on the test split.

Rows: the paper's three variants (quoted); the flat-normal baseline; the per-pixel
least-squares inversion of the shading with known lighting (jaxocean.fit.pixels); every
trained model given with --model NAME=PATH (the shipped one by default). Columns: the
paper's (roughness MSE, image MSE, normal MAE, CosSim loss, within 5/10/15 deg) plus within
1/2 deg, the slope skill along / across the view and overall, frames per second, training
time and steps. Also, per test scene, the model's slope skill against the camera pitch
(what one image can say about the slope depends on the view) and whether it beats flat.

Usage::

    python experiments/geometry_nets.py out/geo128 --model cpu=jaxocean/nn/pretrained/geometry_cpu.npz \\
        --model "image+gan (400 steps)=runs/ablation/unet_slope_image+gan/model.npz" ...

Writes experiments/results/geometry_nets.json and .png (error against inference time, skill
against pitch, error maps of one test frame like the paper's Fig. 5).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent))

from jaxocean import plots  # noqa: E402
from jaxocean.files import write_json  # noqa: E402
from jaxocean.io.dataset import Dataset  # noqa: E402
from jaxocean.nn import geometry as geo  # noqa: E402
from jaxocean.nn import geometry_train as gt  # noqa: E402

PAPER = {  # Xie et al. 2024, Table 1 (their test split; units as printed there)
    "paper ResNet-VecN": dict(roughness_mse=0.0170, image_mse=0.0161, normal_mae=0.1667, cos_loss=0.0113,
                              within_5deg=0.381, within_10deg=0.782, within_15deg=0.934),
    "paper ResNet-SphereN": dict(roughness_mse=0.0169, image_mse=0.0181, normal_mae=0.2394, cos_loss=0.0141,
                                 within_5deg=0.300, within_10deg=0.706, within_15deg=0.902),
    "paper UNet-VecN": dict(roughness_mse=0.0187, image_mse=0.0331, normal_mae=0.2912, cos_loss=0.0323,
                            within_5deg=0.278, within_10deg=0.684, within_15deg=0.880),
}
COLUMNS = ("within_1deg", "within_2deg", "within_5deg", "within_10deg", "within_15deg", "normal_mae", "cos_loss",
           "skill_along", "skill_across", "skill", "unfolded_skill_along", "unfolded_skill_across", "unfolded_skill",
           "unfolded_fraction", "median_scene_skill_along", "median_scene_skill_across", "roughness_mse",
           "log_slope_variance_mse", "image_mse",
           "frames_per_s")


def _row_summary(r):
    return {k: r.get(k) for k in COLUMNS + ("frames", "train_s", "steps", "losses", "architecture")}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dataset")
    ap.add_argument("--model", action="append", default=[], help="NAME=PATH of a trained model (repeatable)")
    ap.add_argument("--pixel-frames", type=int, default=1, help="frames per scene for the slow per-pixel inversion")
    ap.add_argument("--frames-per-scene", type=int, default=None, help="frames per test scene for the other rows")
    ap.add_argument("--out", default=str(HERE / "results" / "geometry_nets"))
    args = ap.parse_args(argv)
    data = Dataset(args.dataset)
    models = dict(m.split("=", 1) for m in args.model) or {"shipped (cpu config)": str(geo.PRETRAINED_PATH)}

    rows, full = {}, {}
    t0 = time.perf_counter()
    full["flat normal"] = gt.evaluate(gt.flat_method, data, "test", frames_per_scene=args.frames_per_scene)
    full["per-pixel inversion (known lighting)"] = gt.evaluate(gt.pixel_method, data, "test",
                                                               frames_per_scene=args.pixel_frames)
    for name, path in models.items():
        model = geo.load(path)
        info = geo.model_info(path)
        r = gt.evaluate(model, data, "test", frames_per_scene=args.frames_per_scene)
        tc = info.get("train_config", {})
        r |= {"train_s": info.get("train_s"), "steps": info.get("steps"), "losses": tc.get("losses"),
              "architecture": f"{model.config.backbone}-{model.config.normal_head}", "path": path}
        full[name] = r
    for name, r in full.items():
        rows[name] = _row_summary(r)
    flat_scenes = full["flat normal"]["scenes"]
    per_scene = {}
    for name in models:
        sc = full[name]["scenes"]
        per_scene[name] = {str(s): {"pitch": float(data.scene(s).camera.pitch),
                                    "height": float(data.scene(s).camera.height),
                                    "skill_along": v["skill_along"], "skill_across": v["skill_across"],
                                    "cos_loss": v["cos_loss"], "flat_cos_loss": flat_scenes[s]["cos_loss"],
                                    "beats_flat": v["cos_loss"] < flat_scenes[s]["cos_loss"]}
                           for s, v in sc.items()}
        rows[name]["scenes_better_than_flat"] = sum(v["beats_flat"] for v in per_scene[name].values())
        for c in ("along", "across"):
            rows[name][f"median_scene_skill_{c}"] = float(np.median([v[f"skill_{c}"] for v in per_scene[name].values()]))
        rows[name]["scenes"] = len(per_scene[name])
    result = {"dataset": str(args.dataset), "dataset_settings": data.settings, "test_scenes": len(data.splits["test"]),
              "paper": PAPER, "rows": rows, "per_scene": per_scene, "wall_s": time.perf_counter() - t0,
              "units": {"normal_mae": "radians (mean angle between predicted and true normal)",
                        "cos_loss": "mean 1 - cos", "roughness_mse": "sigma^2 = sum of the slope-variance pair",
                        "log_slope_variance_mse": "log10 of each slope variance, decades^2",
                        "image_mse": "Bruneton-tonemapped display values in [0, 1], sea pixels",
                        "frames_per_s": "128^2 frames, this machine, method alone after compilation"}}
    write_json(args.out + ".json", result)
    _chart(args.out + ".png", data, rows, per_scene, models)
    _print(rows)


def _print(rows):
    cols = ("within_5deg", "within_1deg", "normal_mae", "skill_along", "skill_across", "unfolded_skill_along",
            "unfolded_skill_across", "median_scene_skill_along", "median_scene_skill_across", "log_slope_variance_mse",
            "image_mse", "frames_per_s")
    print(f"{'method':<44}" + "".join(f"{c[-12:]:>13}" for c in cols))
    for name, r in rows.items():
        print(f"{name:<44}" + "".join(f"{(r.get(c) if r.get(c) is not None else math.nan):>13.4g}" for c in cols))


def _chart(path, data, rows, per_scene, models):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig = plt.figure(figsize=(15, 8.5))
    ax = fig.add_subplot(2, 3, 1)
    for i, (name, r) in enumerate(rows.items()):
        ax.scatter(1.0 / r["frames_per_s"], math.degrees(r["normal_mae"]), color=f"C{i}", label=name)
    ax.set_xscale("log")
    ax.set_xlabel("seconds per 128x128 frame (this CPU)")
    ax.set_ylabel("mean normal angle error [deg]")
    ax.set_title("error against inference time")
    ax.legend(fontsize=6)
    ax = fig.add_subplot(2, 3, 2)
    for i, (name, r) in enumerate(rows.items()):
        color = f"C{i}"
        ax.scatter(1.0 / r["frames_per_s"], max(r["unfolded_skill_along"], -1), marker="o", color=color, label=name)
        ax.scatter(1.0 / r["frames_per_s"], max(r["unfolded_skill_across"], -1), marker="x", color=color)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_xscale("log")
    ax.set_xlabel("seconds per frame")
    ax.set_ylabel("slope skill, tilt < 60 deg (o along, x across)")
    ax.set_title("slope skill against inference time")
    ax = fig.add_subplot(2, 3, 3)
    for name in list(models)[:1]:  # the first model (the shipped one by default)
        ps = per_scene[name].values()
        ax.scatter([math.degrees(v["pitch"]) for v in ps], np.clip([v["skill_along"] for v in ps], -1, 1), s=12,
                   label=f"{name} along")
        ax.scatter([math.degrees(v["pitch"]) for v in ps], np.clip([v["skill_across"] for v in ps], -1, 1), s=12,
                   marker="x", label=f"{name} across (clipped at -1)")
    ax.axhline(0, color="k", lw=0.5)
    ax.set_ylim(-1.05, 1.05)
    ax.set_xlabel("camera pitch below the horizon [deg]")
    ax.set_ylabel("slope skill per test scene")
    ax.set_title("what one image says about the slope")
    ax.legend(fontsize=6)
    # error maps of one test frame (the paper's Fig. 5)
    s = data.splits["test"][0]
    scene, frame = data.scene(s), data.frame(s, 0)
    best = geo.load(next(iter(models.values())))
    pred = geo.predict(best, frame.image, scene.camera)
    mask = frame.mask > 0.5
    err = np.degrees(np.arccos(np.clip(np.sum(pred.normal * frame.normal, -1), -1, 1)))
    flat_err = np.degrees(np.arccos(np.clip(frame.normal[..., 2], -1, 1)))
    panels = [("input", np.asarray(plots.display(frame.image))), ("true normal", plots.normal_to_rgb(frame.normal, mask)),
              (f"{next(iter(models))} normal", plots.normal_to_rgb(pred.normal, mask))]
    sub = fig.add_gridspec(2, 6)[1, :].subgridspec(1, 5)
    for i, (title, img) in enumerate(panels):
        a = fig.add_subplot(sub[0, i])
        a.imshow(img)
        a.set_title(title, fontsize=8)
        a.axis("off")
    vmax = float(np.percentile(flat_err[mask], 99))
    for i, (title, e) in enumerate((("flat: angle error", flat_err), ("model: angle error", err))):
        a = fig.add_subplot(sub[0, 3 + i])
        im = a.imshow(np.where(mask, e, np.nan), vmin=0, vmax=vmax, cmap="magma")
        a.set_title(f"{title} [deg]", fontsize=8)
        a.axis("off")
        fig.colorbar(im, ax=a, fraction=0.046)
    fig.tight_layout()
    plots.save_figure(fig, path)


if __name__ == "__main__":
    main()
