"""The network subcommands of the ``jaxocean`` CLI: ``train-geometry``, ``predict-geometry``,
``eval-geometry`` and ``train-waves``. :func:`register` adds them to the main parser (``jaxocean.cli``),
which owns error handling and exit codes; each command returns an exit code.

* ``train-geometry DATASET --config {cpu,gpu,paper} --out RUN``: train (or resume: rerun the
  same command) a geometry model; ``RUN/model.npz`` is the best one, ``RUN/curves.png`` and
  ``RUN/history.json`` the curves.
* ``predict-geometry FRAMES... --out DIR``: per frame an EXR (the input as linear ``R G B``
  plus predicted ``normal``, ``roughness``, ``slope_variance``, ``mask``) and PNG previews of
  the normal and roughness maps. FRAMES are PNG / JPEG / 16-bit PNG / EXR files or one
  video; the camera comes from ``--scene`` or the ``--camera-*`` options. An ``--out`` that
  holds a scene (``scene.json``) or input frames the prediction would replace is refused.
* ``eval-geometry DATASET``: the model's scores on a split next to the flat-normal
  baseline (:func:`jaxocean.nn.geometry_train.evaluate`), printed and written as JSON.
* ``train-waves DATASET --config {cpu,paper} --out RUN``: train (or resume) a wave network
  (:mod:`jaxocean.nn.waves_train`); same run directory layout as ``train-geometry``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from jaxocean._cli_inputs import check_out_dir, check_out_file, positive_float, positive_int

__all__ = ["register"]

_SCORE_COLUMNS = (("within_5deg", "5deg", "{:.1%}"), ("normal_mae", "MAE rad", "{:.4f}"),
                  ("skill_along", "skill along", "{:.3f}"), ("skill_across", "across", "{:.3f}"),
                  ("log_slope_variance_mse", "log10 sv MSE", "{:.3f}"), ("image_mse", "image MSE", "{:.2e}"),
                  ("frames_per_s", "frames/s", "{:.1f}"))


def _add_training_options(p, configs, loss_terms, items: str) -> None:
    """The options every train-* command shares: dataset, config, run directory, overrides.
    ``items`` says what a batch holds, for the help of --steps-per-epoch."""
    p.add_argument("dataset", help="dataset directory (jaxocean simulate)")
    meaning = {"cpu": "under an hour on two CPU cores (default)",
               "gpu": "the recipe of the shipped gpu model, for one GPU",
               "paper": "the paper's setting, for a GPU"}
    p.add_argument("--config", choices=sorted(configs), default="cpu",
                   help="; ".join(f"{name}: {meaning.get(name, 'see docs/training.md')}" for name in sorted(configs)))
    p.add_argument("--out", required=True, help="run directory (checkpoint, curves, model.npz)")
    p.add_argument("--epochs", type=positive_int, help="override the config's number of epochs")
    p.add_argument("--steps-per-epoch", type=positive_int, help="override the config's steps per epoch (at most: an epoch "
                   f"also ends when the train split's batches run out: a batch holds {items}, e.g. one step an "
                   "epoch for 8 of them and a batch of 8)")
    p.add_argument("--losses", help=f"override the losses: '+'-joined terms of {', '.join(loss_terms)}")


def register(sub, *, add_camera_options, camera_from_args) -> dict:
    """Add the subcommands to ``sub``; returns ``{name: command}``. ``add_camera_options(p)``
    and ``camera_from_args(args, base, resolution, where)`` are the main CLI's camera
    options and their reader, shared by every command that needs a camera."""
    from jaxocean.nn.geometry_train import CONFIGS, LOSS_TERMS

    p = sub.add_parser("train-geometry", help="train a geometry network (image -> normal, roughness)",
                       description="Train a geometry network on a `jaxocean simulate` dataset. Killing it and "
                                   "running the same command again resumes where it stopped. RUN/model.npz is "
                                   "the model with the best validation score.")
    _add_training_options(p, CONFIGS, LOSS_TERMS, "frames (of every train scene; pairs of consecutive frames "
                          "with the gan loss)")
    p.add_argument("--backbone", choices=("unet", "resnet"), help="override the backbone")
    p.add_argument("--normal-head", choices=("vec", "sphere", "slope"), help="override the normal head")
    p.add_argument("--time-budget-min", type=positive_float, help="stop after this many minutes of training")
    p.add_argument("--augment", action=argparse.BooleanOptionalAction, default=None,
                   help="show the network its inputs through the display round trip of camera files (8 bits, "
                        "unknown exposure, display noise: jaxocean.nn.augment); default: the config's (on for cpu)")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("predict-geometry", help="per-pixel normal and roughness of images with a trained network",
                       description="Predict normal and roughness maps of ocean images with a geometry network "
                                   "(the shipped pretrained model unless --model). Writes DIR/frame_XXXXX.exr "
                                   "(linear RGB + normal, roughness, slope_variance, mask) and PNG previews.")
    p.add_argument("frames", nargs="+", help="image files (PNG, JPEG, EXR) or one video file")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--model", help="model file, or a shipped model: cpu (the default) or gpu (larger, more "
                                   "accurate, ~2.5x the time per frame)")
    p.add_argument("--scene", help="scene directory or scene.json holding the camera")
    p.add_argument("--space", choices=("srgb", "bruneton", "linear"), default="srgb",
                   help="tone curve of display-referred inputs (PNG, JPEG, video; default srgb)")
    p.add_argument("--exposure", type=float, default=1.0, help="exposure the display images were made with")
    add_camera_options(p, resolution=False)

    p = sub.add_parser("eval-geometry", help="score a geometry network on a dataset split (Table 1)",
                       description="Score a geometry network and the flat-normal baseline on a dataset split: "
                                   "angle errors, slope skill along and across the view, roughness and image "
                                   "errors, frames per second.")
    p.add_argument("dataset", help="dataset directory (jaxocean simulate)")
    p.add_argument("--model", help="model file, or a shipped model: cpu (the default) or gpu (larger, more "
                                   "accurate, ~2.5x the time per frame)")
    p.add_argument("--split", default="test", help="split to score (default test)")
    p.add_argument("--max-frames", type=positive_int, help="score at most this many frames")
    p.add_argument("--out", help="JSON file for the scores (with per-scene rows), e.g. scores.json")

    from jaxocean.nn.waves_train import CONFIGS as WAVE_CONFIGS
    from jaxocean.nn.waves_train import LOSS_TERMS as WAVE_LOSS_TERMS

    p = sub.add_parser("train-waves", help="train a wave-estimation network (geometry sequence -> waves)",
                       description="Train a wave network on a `jaxocean simulate` dataset (self-supervised "
                                   "through the differentiable geometry). Killing it and running the same command "
                                   "again resumes where it stopped. RUN/model.npz is the model with the best "
                                   "validation loss; fit-waves --init net --net-model RUN/model.npz uses it.")
    _add_training_options(p, WAVE_CONFIGS, WAVE_LOSS_TERMS, "train scenes")
    p.add_argument("--time-budget-min", type=positive_float, help="stop after this many minutes of training")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    def predict_cmd(args):
        return _predict(args, camera_from_args)

    return {"train-geometry": _train, "predict-geometry": predict_cmd, "eval-geometry": _eval,
            "train-waves": _train_waves}


def _train(args) -> int:
    from jaxocean.nn import geometry_train as gt
    from jaxocean.nn.augment import DisplayAugment

    config = gt.CONFIGS[args.config]
    config = gt.variant(config, losses=args.losses, backbone=args.backbone, normal_head=args.normal_head)
    changes = {k: v for k, v in (("epochs", args.epochs), ("steps_per_epoch", args.steps_per_epoch),
                                 ("time_budget_minutes", args.time_budget_min)) if v is not None}
    if args.augment is not None:
        changes["augment"] = (config.augment or DisplayAugment()) if args.augment else None
    config = config._replace(**changes)
    config.terms()
    check_out_dir(args.out)
    summary = gt.train(args.dataset, args.out, config, progress=not args.quiet)
    summary.pop("state")
    print(f"stopped: {summary['stopped']} after {summary['steps']} steps; best validation loss "
          f"{summary['best_val_loss']:.4g}")
    return _report_model(summary)


def _train_waves(args) -> int:
    from jaxocean.nn import waves_train as wt

    changes = {k: v for k, v in (("epochs", args.epochs), ("steps_per_epoch", args.steps_per_epoch),
                                 ("losses", args.losses), ("time_budget_minutes", args.time_budget_min))
               if v is not None}
    config = wt.CONFIGS[args.config]._replace(**changes)
    config.terms()
    check_out_dir(args.out)
    summary = wt.train(args.dataset, args.out, config, progress=not args.quiet)
    summary.pop("state")
    print(f"stopped: {summary['stopped']} after {summary['steps']} steps ({summary['train_s'] / 60:.1f} min); "
          f"best validation loss {summary['best_val_loss']:.4g}")
    return _report_model(summary)


def _report_model(summary) -> int:
    if summary["model"] is None:  # no finite validation loss: nothing was worth writing
        print("jaxocean: no model written: the validation loss was never finite", file=sys.stderr)
        return 1
    print(f"-> {summary['model']}")
    return 0


def _load_frames(paths, space, exposure):
    import numpy as np

    from jaxocean.io.images import is_video_file, load_image, load_video

    paths = [Path(p) for p in paths]
    if len(paths) == 1 and is_video_file(paths[0]):
        frames = load_video(paths[0], space=space, exposure=exposure)
        sources = [f"{paths[0]} frame {t}" for t in range(len(frames))]
    else:
        if any(is_video_file(p) for p in paths):
            raise ValueError("give one video file or image files, not both")
        frames = [load_image(p, space=space, exposure=exposure) for p in paths]
        sources = [str(p) for p in paths]
    for source, frame in zip(sources, frames):
        if not np.all(np.isfinite(frame)):
            raise ValueError(f"{source}: holds non-finite pixel values (NaN or inf)")
    shapes = {frame.shape for frame in frames}
    if len(shapes) > 1:
        raise ValueError(f"the frames differ in size: {sorted(shapes)}")
    return np.stack(frames)


def _refuse_replacing_inputs(out: Path, frames, n_frames: int) -> None:
    """A ``ValueError`` where predicting ``n_frames`` frames into ``out`` would replace or remove
    what is not a previous prediction: a scene's frames (``out`` holds its ``scene.json``: its
    EXR frames carry the true geometry) or an input frame."""
    from jaxocean.io.scene import SCENE_FILENAME
    from jaxocean.io.sequence import predicted_files_replaced

    if (out / SCENE_FILENAME).is_file():
        raise ValueError(f"--out {out}: holds a scene ({SCENE_FILENAME}), whose frame_XXXXX.exr files the prediction "
                         "would replace or remove; give another --out directory")
    replaced = {path.resolve() for path in predicted_files_replaced(out, n_frames)}
    hit = [frame for frame in frames if Path(frame).resolve() in replaced]
    if hit:
        raise ValueError(f"--out {out}: the prediction would replace or remove its input frame {hit[0]}"
                         f"{f' (and {len(hit) - 1} more)' if len(hit) > 1 else ''}; give another --out directory")


def _predict(args, camera_from_args) -> int:
    import imageio.v3 as iio
    import numpy as np

    from jaxocean import plots
    from jaxocean._cli_inputs import refuse_other_json
    from jaxocean.files import atomic_write
    from jaxocean.io import read_scene
    from jaxocean.io.exr import write_frame
    from jaxocean.io.sequence import fits_half, frame_name, remove_stale_frames
    from jaxocean.nn import geometry as geo

    out = check_out_dir(args.out)
    if args.scene:
        refuse_other_json(args.scene, "predict-geometry --scene needs a scene directory or scene.json holding the "
                                      "camera; or give the camera as --camera-height and --camera-pitch-deg "
                                      "(--camera-fov-deg, --camera-yaw-deg)")
    model = geo.load(args.model)
    images = _load_frames(args.frames, args.space, args.exposure)
    _refuse_replacing_inputs(out, args.frames, len(images))
    scene = read_scene(args.scene) if args.scene else None
    if scene is not None and scene.camera is None:
        raise ValueError(f"{args.scene}: the scene has no camera")
    camera = camera_from_args(args, None if scene is None else scene.camera, tuple(images.shape[1:3]),
                              where=f"frame {args.frames[0]}")
    (H, W), (Hc, Wc) = images.shape[1:3], camera.resolution
    if (H, W) != (Hc, Wc):
        frames = args.frames[0] if len(args.frames) == 1 else f"{args.frames[0]} (and the other frames)"
        raise ValueError(f"{frames}: {W}x{H} pixels (width x height), but the camera of --scene {args.scene} is "
                         f"{Wc}x{Hc}: give frames of that size, or a scene whose camera has theirs")
    pred = geo.predict(model, images, camera)
    out.mkdir(parents=True, exist_ok=True)
    stale = remove_stale_frames(out, len(images))
    if stale:
        print(f"note: removed {len(stale)} frame file(s) of a previous prediction in {out} beyond the new "
              f"{len(images)} frame(s)", file=sys.stderr)
    for t in range(len(images)):
        g = {"normal": pred.normal[t], "roughness": pred.roughness[t], "mask": pred.mask[t],
             "slope_variance": pred.slope_variance[t]}
        name = frame_name(t)
        write_frame(out / name, images[t], g, {"frame": t, "source": str(args.frames[min(t, len(args.frames) - 1)])},
                    half=fits_half(images[t]))
        for suffix, rgb in (("normal", plots.normal_to_rgb(pred.normal[t], pred.mask[t])),
                            ("roughness", plots.roughness_to_rgb(pred.roughness[t], pred.mask[t]))):
            atomic_write(out / name.replace(".exr", f"_{suffix}.png"),
                         lambda tmp, rgb=rgb: iio.imwrite(tmp, rgb, extension=".png"))
    print(f"{len(images)} frame(s) -> {out}/frame_XXXXX.exr (+ _normal.png, _roughness.png)")
    if not np.any(pred.mask):
        print("jaxocean: warning: no pixel sees the sea (the view is above the horizon): the prediction is "
              "empty; check the camera's pitch", file=sys.stderr)
    return 0


def _eval(args) -> int:
    from jaxocean.files import write_json
    from jaxocean.nn import geometry as geo
    from jaxocean.nn import geometry_train as gt

    if args.out:
        check_out_file(args.out, "scores.json")
    model = geo.load(args.model)
    rows = {"flat normal": gt.evaluate(gt.flat_method, args.dataset, args.split, max_frames=args.max_frames),
            "model": gt.evaluate(model, args.dataset, args.split, max_frames=args.max_frames)}
    header = f"{'method':<14}" + "".join(f"{title:>14}" for _, title, _ in _SCORE_COLUMNS)
    print(header)
    for name, r in rows.items():
        print(f"{name:<14}" + "".join(f"{fmt.format(r[k]):>14}" for k, _, fmt in _SCORE_COLUMNS))
    worse = [s for s, sc in rows["model"]["scenes"].items() if sc["cos_loss"] >= rows["flat normal"]["scenes"][s]["cos_loss"]]
    print(f"scenes where the model is not better than flat (mean 1 - cos): {len(worse)} of "
          f"{len(rows['model']['scenes'])}" + (f" ({worse})" if worse else ""))
    if args.out:
        write_json(args.out, {"split": args.split, "model": str(args.model or geo.PRETRAINED_PATH), "rows": rows})
        print(f"-> {args.out}", file=sys.stderr)
    return 0
