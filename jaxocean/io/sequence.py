"""Writing a rendered sequence: the directory layout of :mod:`jaxocean.io` in one call.

``write_sequence(out, scene, images (T, H, W, 3), geometry, ...)`` writes, for frame ``f``,
``frame_XXXXX.exr`` (linear RGB + normal / roughness / slope_variance / mask channels) and a
tone-mapped ``frame_XXXXX.png`` preview, then ``normal_00000.png`` / ``roughness_00000.png``
of the first frame and ``scene.json``. ``scene`` is anything with ``waves``, ``camera``,
``lighting``, ``spectrum`` (may be None) and ``times (T,)`` attributes (a
:class:`jaxocean.io.scene.Scene` or a dataset :class:`~jaxocean.io.dataset.SceneSample`);
``geometry`` has ``normal (T, H, W, 3)``, ``roughness (T, H, W)``, ``mask (T, H, W)`` and
(as a :class:`jaxocean.render.Geometry` does) ``slope_variance (T, H, W, 2)``, which is
stored so that each frame's geometry reproduces its image (:mod:`jaxocean.io.exr`).
Every file is written atomically (:func:`jaxocean.io.exr.atomic_write`). The CLI's
``render``, ``demo`` and ``forecast`` and :func:`jaxocean.fit.reedit_scene` all write
through here.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from jaxocean.io.exr import atomic_write, write_frame
from jaxocean.io.images import save_png
from jaxocean.io.scene import scene_to_dict, write_scene

__all__ = ["HALF_MAX", "frame_name", "write_sequence"]

#: the largest finite half float: brighter radiance forces a float32 EXR
HALF_MAX = 65504.0


def frame_name(index: int) -> str:
    """``frame_XXXXX.exr`` for a frame index (the dataset and sequence naming)."""
    return f"frame_{int(index):05d}.exr"


def write_sequence(out, scene, images, geometry, *, half: bool = True, seed=None, progress: bool = True,
                   frame_ids=None, extra=None, exposure: float = 1.0) -> list[Path]:
    """Write the sequence (module docstring); returns the PNG preview paths.

    Files are numbered 0, 1, ... in order; ``frame_ids`` (default the same numbers) go into
    each EXR's ``frame`` metadata. Sequences with radiance beyond the half-float range
    (bright glints) are written as float32 with a note on stderr. ``exposure``: of the PNG
    previews.
    """
    import imageio.v3 as iio
    from tqdm.auto import tqdm

    from jaxocean import plots

    out = Path(out)
    images = np.asarray(images, np.float32)
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images must be (T, H, W, 3); got shape {images.shape}")
    n_frames = images.shape[0]
    normal, roughness, mask = (np.asarray(geometry.normal), np.asarray(geometry.roughness),
                               np.asarray(geometry.mask))
    slope_var = getattr(geometry, "slope_variance", None)
    slope_var = None if slope_var is None else np.asarray(slope_var)
    if normal.shape != images.shape or roughness.shape != images.shape[:-1]:
        raise ValueError(f"geometry shapes {normal.shape}, {roughness.shape} do not match images {images.shape}")
    if slope_var is not None and slope_var.shape != images.shape[:-1] + (2,):
        raise ValueError(f"geometry.slope_variance shape {slope_var.shape} does not match images {images.shape}")
    times = np.atleast_1d(np.asarray(scene.times, np.float64))
    if times.shape != (n_frames,):
        raise ValueError(f"scene.times must be ({n_frames},) to match the images; got shape {times.shape}")
    if half and not np.abs(images).max() < HALF_MAX:
        print("note: radiance beyond the half-float range; writing float32 EXR", file=sys.stderr)
        half = False
    frame_ids = range(n_frames) if frame_ids is None else frame_ids
    out.mkdir(parents=True, exist_ok=True)
    pngs = []
    for f in tqdm(range(n_frames), desc="write", unit="frame", disable=not progress):
        g = {"normal": normal[f], "roughness": roughness[f], "mask": mask[f],
             "slope_variance": None if slope_var is None else slope_var[f]}
        meta = {"frame": int(frame_ids[f]), "time": float(times[f])}
        write_frame(out / frame_name(f), images[f], g, meta, half=half)
        pngs.append(save_png(out / frame_name(f).replace(".exr", ".png"), images[f], exposure=exposure))
    for name, rgb in (("normal_00000.png", plots.normal_to_rgb(normal[0], mask[0])),
                      ("roughness_00000.png", plots.roughness_to_rgb(roughness[0], mask[0]))):
        atomic_write(out / name, lambda temporary, rgb=rgb: iio.imwrite(temporary, rgb, extension=".png"))
    write_scene(out, scene_to_dict(waves=scene.waves, camera=scene.camera, lighting=scene.lighting,
                                   spectrum=getattr(scene, "spectrum", None), times=times, seed=seed, extra=extra))
    return pngs
