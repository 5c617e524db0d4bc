"""Writing a rendered sequence: the directory layout of :mod:`jaxocean.io` in one call.

``write_sequence(out, scene, images (T, H, W, 3), geometry, ...)`` writes, for frame ``f``,
``frame_XXXXX.exr`` (linear RGB + normal / roughness / slope_variance / mask channels) and a
tone-mapped ``frame_XXXXX.png`` preview, then ``normal_00000.png`` / ``roughness_00000.png``
of the first frame and ``scene.json``. ``scene`` is anything with ``waves``, ``camera``,
``lighting``, ``spectrum`` (may be None) and ``times (T,)`` attributes (a
:class:`jaxocean.io.scene.Scene` or a dataset :class:`~jaxocean.io.dataset.SceneSample`);
``geometry`` has ``normal (T, H, W, 3)``, ``roughness (T, H, W)``, ``mask (T, H, W)`` and
(as a :class:`jaxocean.render.Geometry` does) ``slope_variance (T, H, W, 2)``, which is
stored so that each frame's geometry reproduces its image (:mod:`jaxocean.io.exr`), and
``converged (T, H, W)`` (where the ray-surface hits are exact), stored when not None.
When the scene has a spectrum, ``scene.json``'s ``extra`` also says what its waves carry
(:func:`jaxocean.io.scene.waves_summary`: ``waves_hs_m``, and ``clamped_waves``, the waves a
draw lowered to the steepness limit, when ``scene`` says).
Every file is written atomically (:func:`jaxocean.files.atomic_write`). The CLI's
``render``, ``demo`` and ``forecast`` and :func:`jaxocean.fit.reedit_scene` all write
through here.

A directory holds one sequence. Writing into a directory that holds a previous one replaces
it: its ``scene.json`` is removed first (the directory is incomplete until the new one is
written, last), and its ``frame_XXXXX.exr`` / ``.png`` beyond the new frame count are
removed, so no stale frame of the old scene is left beside the new ones. No other file is
touched. Every frame, the scene, the exposure and the camera's resolution are checked before
the previous sequence is touched: a write that fails on its inputs leaves it whole.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path

import numpy as np

from jaxocean import plots
from jaxocean.files import atomic_write
from jaxocean.errors import check_number
from jaxocean.io.exr import checked_frame, write_frame
from jaxocean.io.images import save_png
from jaxocean.io.scene import SCENE_FILENAME, scene_from_dict, scene_to_dict, waves_summary, write_scene

__all__ = ["HALF_MAX", "fits_half", "frame_name", "remove_stale_frames", "predicted_files_replaced", "write_sequence"]

#: the largest finite half float: brighter radiance forces a float32 EXR
HALF_MAX = 65504.0


def fits_half(values) -> bool:
    """Whether every value is finite and below :data:`HALF_MAX` in magnitude, i.e. can be
    stored as half floats; writers fall back to float32 where it cannot."""
    return bool(np.abs(np.asarray(values)).max() < HALF_MAX)

# a frame's files: frame_XXXXX.exr / .png, and the _normal / _roughness previews of predictions
_FRAME_FILE = re.compile(r"frame_(\d{5,})(_normal|_roughness)?\.(exr|png)")


def frame_name(index: int) -> str:
    """``frame_XXXXX.exr`` for a frame index (the dataset and sequence naming)."""
    return f"frame_{int(index):05d}.exr"


def write_sequence(out, scene, images, geometry, *, half: bool = True, seed=None, progress: bool = True,
                   frame_ids=None, extra=None, exposure: float = 1.0) -> list[Path]:
    """Write the sequence (module docstring); returns the PNG preview paths.

    A previous sequence in ``out`` is replaced (module docstring); ``out`` must not be a
    file (ValueError). Files are numbered 0, 1, ... in order; ``frame_ids`` (default the
    same numbers) go into each EXR's ``frame`` metadata. Sequences with radiance beyond the
    half-float range (bright glints) are written as float32 with a note on stderr.
    ``exposure``: of the PNG previews.
    """
    import imageio.v3 as iio
    from tqdm.auto import tqdm

    out = Path(out)
    images = np.asarray(images, np.float32)
    if images.ndim != 4 or images.shape[-1] != 3:
        raise ValueError(f"images must be (T, H, W, 3); got shape {images.shape}")
    n_frames = images.shape[0]
    normal, roughness, mask = (np.asarray(geometry.normal), np.asarray(geometry.roughness),
                               np.asarray(geometry.mask))
    slope_var = getattr(geometry, "slope_variance", None)
    slope_var = None if slope_var is None else np.asarray(slope_var)
    converged = getattr(geometry, "converged", None)
    converged = None if converged is None else np.asarray(converged)
    if normal.shape != images.shape or roughness.shape != images.shape[:-1]:
        raise ValueError(f"geometry shapes {normal.shape}, {roughness.shape} do not match images {images.shape}")
    if slope_var is not None and slope_var.shape != images.shape[:-1] + (2,):
        raise ValueError(f"geometry.slope_variance shape {slope_var.shape} does not match images {images.shape}")
    if converged is not None and converged.shape != images.shape[:-1]:
        raise ValueError(f"geometry.converged shape {converged.shape} does not match images {images.shape}")
    times = np.atleast_1d(np.asarray(scene.times, np.float64))
    if times.shape != (n_frames,):
        raise ValueError(f"scene.times must be ({n_frames},) to match the images; got shape {times.shape}")
    if n_frames < 1:
        raise ValueError("images hold no frame: nothing to write")
    resolution = getattr(scene.camera, "resolution", None)
    if resolution is not None and tuple(resolution) != images.shape[1:3]:
        raise ValueError(f"the scene's camera is {tuple(resolution)} (H, W) but the images are {images.shape[1:3]}")
    check_number(exposure, "exposure must be a finite number > 0", low_open=True)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a directory; a sequence is written into a directory")
    frame_ids = range(n_frames) if frame_ids is None else frame_ids
    frames = [({"normal": normal[f], "roughness": roughness[f], "mask": mask[f],
                "slope_variance": None if slope_var is None else slope_var[f],
                "converged": None if converged is None else converged[f]},
               {"frame": int(frame_ids[f]), "time": float(times[f])}) for f in range(n_frames)]
    # everything is checked before the previous sequence is touched: a failure leaves it whole
    for f, (g, meta) in enumerate(frames):
        checked_frame(images[f], g, meta, half=False)
    spec = getattr(scene, "spectrum", None)
    if spec is not None:  # drawn waves: what they carry beside the requested sea (io.scene.waves_summary)
        extra = {**waves_summary(scene.waves, getattr(scene, "clamped_waves", None)), **(extra or {})}
    scene_dict = scene_to_dict(waves=scene.waves, camera=scene.camera, lighting=scene.lighting,
                               spectrum=spec, times=times, seed=seed, extra=extra)
    scene_from_dict(scene_dict)
    if half and not fits_half(images):
        print("note: radiance beyond the half-float range; writing float32 EXR", file=sys.stderr)
        half = False
    out.mkdir(parents=True, exist_ok=True)
    stale = _remove_previous(out, n_frames)
    if stale:
        print(f"note: replacing the previous scene in {out}: removed {len(stale)} frame file(s) beyond the new "
              f"{n_frames} frame(s)", file=sys.stderr)
    pngs = []
    for f in tqdm(range(n_frames), desc="write", unit="frame", disable=not progress):
        g, meta = frames[f]
        write_frame(out / frame_name(f), images[f], g, meta, half=half)
        pngs.append(save_png(out / frame_name(f).replace(".exr", ".png"), images[f], exposure=exposure))
    for name, rgb in (("normal_00000.png", plots.normal_to_rgb(normal[0], mask[0])),
                      ("roughness_00000.png", plots.roughness_to_rgb(roughness[0], mask[0]))):
        atomic_write(out / name, lambda temporary, rgb=rgb: iio.imwrite(temporary, rgb, extension=".png"))
    write_scene(out, scene_dict)
    return pngs


def _remove_previous(out: Path, n_frames: int) -> list[Path]:
    """Remove a previous sequence's ``scene.json`` and its frame files numbered ``>= n_frames``
    (the others are overwritten); returns the removed frame files."""
    (out / SCENE_FILENAME).unlink(missing_ok=True)
    return remove_stale_frames(out, n_frames)


def remove_stale_frames(out, n_frames: int) -> list[Path]:
    """Remove the frame files in directory ``out`` (``frame_XXXXX.exr`` / ``.png`` and their
    ``_normal`` / ``_roughness`` previews) numbered ``>= n_frames``: what a previous, longer
    sequence left that the new one does not overwrite. Returns the removed files."""
    stale = _frame_files(out, lambda index, kind: index >= n_frames)
    for path in stale:
        path.unlink()
    return stale


def predicted_files_replaced(out, n_frames: int) -> list[Path]:
    """The files in directory ``out`` that writing ``n_frames`` predicted frames replaces or
    removes: ``frame_XXXXX.exr`` and its ``_normal`` / ``_roughness`` previews below
    ``n_frames`` (a prediction writes no ``frame_XXXXX.png``), and every frame file from
    ``n_frames`` on (:func:`remove_stale_frames`). Empty where ``out`` is not a directory."""
    return _frame_files(out, lambda index, kind: index >= n_frames or kind != "png")


def _frame_files(out, keep) -> list[Path]:
    """The frame files in directory ``out`` for which ``keep(index, kind)`` holds; ``kind`` is
    ``"exr"``, ``"png"`` or ``"_normal"`` / ``"_roughness"`` (a preview)."""
    out = Path(out)
    if not out.is_dir():
        return []
    return sorted(path for path in out.iterdir()
                  if (m := _FRAME_FILE.fullmatch(path.name)) and path.is_file()
                  and keep(int(m.group(1)), m.group(2) or m.group(3)))
