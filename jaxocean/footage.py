"""Footage as the reconstruction reads it: frames and their camera resampled into one ideal
camera, as linear radiance (stage 1 of ``jaxocean reconstruct``, :mod:`jaxocean.reconstruct`).

Protocol
--------
:func:`load_sequence(frames, camera_path, ...)` -> ``(Sequence, StageReport)``
(:class:`jaxocean._stages.StageReport`):

* ``frames``: PNG / JPEG / 16-bit PNG / EXR files, or one video; RGB or gray. Display values
  become linear radiance through a documented response (:mod:`jaxocean.radiometry`: sRGB by
  default, a gamma, linear, or the library's tone map); the exposure stays unknown (the fitted
  colours absorb it). Saturated and black pixels are masked.
* ``camera_path``: a camera file (:mod:`jaxocean.io.camera_file`: pinhole intrinsics,
  Brown-Conrady distortion, a pose per frame) or a synthetic ``scene.json``. Frames without
  a pose get pitch and roll from the visible horizon (:mod:`jaxocean.horizon`) at a given
  camera height.
* Every frame is resampled (:mod:`jaxocean.rectify`) into one ideal library
  :class:`~jaxocean.camera.Camera`: no lens distortion, no roll, one pose. By default it is
  :func:`sea_view`: the sea from just below the horizon to the lowest view every frame has,
  ``width`` pixels across and a height that is a multiple of 16.
* The stage succeeds when at least :data:`MIN_USABLE` of the sea pixels are usable over all
  frames and :data:`MIN_FRAME_USABLE` in every frame (:func:`usable_share`): an average
  alone would let a frame that sees none of the view pass.

The :class:`Sequence` holds the linear images ``(T, H, W, 3)``, the usable-pixel mask, the
display values for reports, the camera, the times [s] and, for the space-time evidence, the
same frames' luminance at a finer width. Metres, seconds, radians.
"""

from __future__ import annotations

import dataclasses
import math
import re
from pathlib import Path
from typing import Any, NamedTuple, Sequence as Seq

import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean._stages import timed
from jaxocean.errors import InvalidValueError, is_integer
from jaxocean.io.exr import MissingFileError, require_file
from jaxocean.io.images import is_video_file

__all__ = ["Sequence", "load_sequence", "sea_view", "usable_share", "DEFAULT_WIDTH", "HORIZON_MARGIN",
           "BOTTOM_MARGIN", "EVIDENCE_WIDTH", "BLACK_LEVEL", "MIN_USABLE", "MIN_FRAME_USABLE"]

#: default working width [px] of the rectified view; the height follows the view's aspect,
#: rounded to a multiple of 16 (the geometry network halves the size four times)
DEFAULT_WIDTH = 128
#: the rectified view's top edge sits this far [rad] below the horizon (the sky carries no
#: wave information and, in footage, is often clipped)
HORIZON_MARGIN = 0.05
#: and its bottom edge this far [rad] inside the lowest view of every frame
BOTTOM_MARGIN = 0.03
#: width [px] of the view the space-time evidence is computed in (at most the source's)
EVIDENCE_WIDTH = 320
#: display values at or below the bottom code of the frames' bit depth are black: masked
#: (:func:`jaxocean.radiometry.bottom_code`: 0.5 / 255 for 8-bit files, 0.5 / 65535 for 16-bit)
BLACK_LEVEL = "bottom"
#: stage 1 fails when less than this share of the working view's sea pixels, over all frames,
#: is usable
MIN_USABLE = 0.5
#: or when any one frame has less than this share usable: that frame sees (next to) none of
#: the working view, whatever the average over the frames
MIN_FRAME_USABLE = 0.05


class Sequence(NamedTuple):
    """Stage 1's output: the observed sequence in one ideal camera.

    * ``images``   ``(T, H, W, 3)`` linear radiance (gray footage: R = G = B = luminance),
      up to the unknown exposure.
    * ``usable``   ``(T, H, W)`` bool: inside the source frame and not saturated.
    * ``display``  ``(T, H, W, 3)`` the rectified display values in [0, 1] (for reports).
    * ``camera``   the ideal :class:`~jaxocean.camera.Camera` every frame was resampled into.
    * ``times``    ``(T,)`` [s], strictly increasing.
    * ``gray``     the footage was grayscale.
    * ``compass``  the camera file gave compass headings (directions reported from north).
    * ``files``    the frame files used.
    * ``response`` the :class:`jaxocean.radiometry.Response` that made display values linear.
    * ``fine``     ``(images (T, H2, W2), usable (T, H2, W2), camera)``: the same frames'
      luminance rectified at ``evidence_width`` (the space-time evidence needs the
      footage's own resolution, which the working view gives up), or None.
    """

    images: np.ndarray
    usable: np.ndarray
    display: np.ndarray
    camera: cam.Camera
    times: np.ndarray
    gray: bool
    compass: bool
    files: tuple
    response: Any = None
    fine: Any = None



def sea_view(camera_file, *, width: int = DEFAULT_WIDTH, horizon_margin: float = HORIZON_MARGIN,
             bottom_margin: float = BOTTOM_MARGIN) -> cam.Camera:
    """The ideal camera a camera file's frames are resampled into: the frames' mean height,
    heading and ground position, no roll, and a pitch and vertical field of view that span
    from ``horizon_margin`` below the horizon (or ``bottom_margin`` inside the highest view
    any frame has, where that is lower: a camera looking down steeply sees no horizon) down
    to ``bottom_margin`` inside the lowest view any frame has (so every pixel is seen in
    every frame, barring roll at the corners); ``width`` pixels across, the height from the
    source's aspect (a multiple of 16)."""
    from jaxocean import lens

    poses = camera_file.poses
    W_src, H_src = camera_file.image_size
    # the depression angles of the bottom-centre and top-centre pixels in each frame
    uv = jnp.asarray([[(W_src - 1) / 2.0, H_src - 1.0], [(W_src - 1) / 2.0, 0.0]])
    lows, highs = [], []
    for i in range(len(camera_file.times)):
        pose = lens.Pose(*(np.asarray(f)[i] for f in poses))
        rays = np.asarray(lens.pixel_rays(uv, pose, camera_file.intrinsics, camera_file.distortion))
        low, high = (-math.asin(float(np.clip(ray[2], -1, 1))) for ray in rays)
        lows.append(low), highs.append(high)
    bottom = min(lows) - bottom_margin
    top = max(horizon_margin, max(highs) + bottom_margin)
    if bottom <= top + 0.1:
        raise InvalidValueError(f"the frames see too little sea below the horizon (lowest view "
                                f"{math.degrees(min(lows)):.1f} deg below it) for a sea view")
    fov, pitch = bottom - top, (bottom + top) / 2
    H = _working_height(width, W_src, H_src)
    heading = math.atan2(float(np.mean(np.sin(poses.heading))), float(np.mean(np.cos(poses.heading))))
    return cam.make_camera(height=float(np.mean(poses.height)), pitch=pitch,
                           yaw=float(lens.yaw_from_heading(heading)), fov=fov, resolution=(H, int(width)),
                           x=float(np.mean(poses.east)), y=float(np.mean(poses.north)))


def usable_share(usable, sea, files) -> tuple[float, np.ndarray, str | None]:
    """``(share, per_frame, problem)``: the share of the sea pixels (``sea (H, W)`` bool) that
    ``usable (T, H, W)`` marks, over all frames and per frame ``(T,)``, and None when they
    pass stage 1's check (:data:`MIN_USABLE` over all frames, :data:`MIN_FRAME_USABLE` in
    each), else what fails, naming the frames (``files``, one per frame) that see too little."""
    usable, sea = np.asarray(usable, bool), np.asarray(sea, bool)
    per_frame = usable[:, sea].mean(axis=1) if sea.any() else np.zeros(len(usable))
    share = float(per_frame.mean())  # every frame has the same sea pixels: the mean over all of them
    if share < MIN_USABLE:
        return share, per_frame, f"only {share:.0%} of the sea pixels are usable (saturated or outside the frames)"
    blind = np.flatnonzero(per_frame < MIN_FRAME_USABLE)
    if blind.size:
        named = ", ".join(f"frame {int(i)} ({files[int(i)]}: {per_frame[i]:.0%})" for i in blind[:3])
        more = f" and {blind.size - 3} more" if blind.size > 3 else ""
        return share, per_frame, (f"{blind.size} of {len(per_frame)} frames see next to none of the working view "
                                  f"(under {MIN_FRAME_USABLE:.0%} of its sea usable: saturated or outside the "
                                  f"frame): {named}{more}; {share:.0%} usable over all frames")
    return share, per_frame, None


def _working_height(width: int, W_src: int, H_src: int) -> int:
    """The source's aspect at ``width`` pixels, rounded to a multiple of 16 (the geometry
    network halves the image four times)."""
    if width % 16:
        raise ValueError(f"the working width must be a multiple of 16 (the geometry network halves the image "
                         f"four times); got {width}")
    return max(16, int(round(width * H_src / W_src / 16)) * 16)


def _scene_of(data, path: Path):
    """The :class:`~jaxocean.io.scene.Scene` of a camera JSON that is a synthetic
    ``scene.json`` (a ``camera`` and no ``intrinsics``), else None."""
    from jaxocean.io.scene import SceneError, SceneFileError, scene_from_dict

    if not (isinstance(data, dict) and "camera" in data and "intrinsics" not in data):
        return None
    try:
        return scene_from_dict(data)
    except SceneError as error:
        raise SceneFileError(path, str(error)) from error


def _frame_files(frames, listed: Seq[Path], where) -> list:
    """Match the given frame paths to the camera file's list (by resolved path, else by
    name); every given frame must be listed."""
    if not frames:
        return list(range(len(listed)))
    by_path = {Path(p).resolve(): i for i, p in enumerate(listed)}
    by_name = {Path(p).name: i for i, p in enumerate(listed)}
    out = []
    for f in frames:
        i = by_path.get(Path(f).resolve(), by_name.get(Path(f).name))
        if i is None:
            raise InvalidValueError(f"frame {f} is not listed in the camera file {where}")
        out.append(i)
    if np.any(np.diff(out) <= 0):
        raise InvalidValueError("frames must be given in the camera file's (time) order, each once")
    return out


def _name_order(stem: str) -> tuple:
    """The key that orders frame names by their numbers as numbers: ``frame_2`` before
    ``frame_10`` (a shell's ``frame_*`` lists ``frame_10`` first)."""
    parts = re.split(r"(\d+)", stem)  # text, number, text, ...: like parts at like places
    return tuple((0, int(part), "") if part.isdigit() else (1, 0, part) for part in parts) + ((2, 0, stem),)


def _scene_frames(folder: Path) -> list:
    """A scene directory's frames: its ``frame_*.exr`` files, else its ``frame_*.png`` ones,
    in name order (:func:`_name_order`)."""
    for suffix in (".exr", ".png"):
        found = sorted(folder.glob(f"frame_*{suffix}"), key=lambda path: _name_order(path.stem))
        if found:
            return found
    return []


def _check_scene_frame_order(frames, where) -> None:
    """A ``scene.json`` pairs the given frames with its times in the order given: each frame
    once, in name order, numbers compared as numbers (``render`` writes ``frame_00000``,
    ``frame_00001``, ...; ``frame_2`` comes before ``frame_10``), or time would run backwards
    or a still frame pass for a sequence."""
    stems = [Path(f).stem for f in frames]
    if len({Path(f).resolve() for f in frames}) < len(frames) or len(set(stems)) < len(stems):
        raise InvalidValueError(f"a frame is given twice; the frames of {where} pair with its times, each once")
    if stems != sorted(stems, key=_name_order):
        raise InvalidValueError(f"frames must be given in the order of the times of {where} (frame_00000, "
                                f"frame_00001, ...; numbers in order of value, frame_2 before frame_10); got "
                                f"{[Path(f).name for f in frames]}")


def load_sequence(frames, camera_path, *, width: int = DEFAULT_WIDTH, response: str = "srgb", gamma: float = 2.2,
                  step: int = 1, max_frames: int | None = None, height: float | None = None,
                  full_view: bool = False, evidence_width: int | None = EVIDENCE_WIDTH):
    """Stage 1 of ``reconstruct`` (module docstring). ``frames``: paths (or one video path, or empty to take
    the camera file's list; given frames pair with its entries by path, else by name, and are
    the files read, so the listed ones need not exist); ``camera_path``: a camera file or a
    ``scene.json`` (then the frames must be the scene's, one per time), or a directory
    holding one. ``step`` / ``max_frames`` thin the sequence.
    ``height``: the camera height [m] when the camera file gives no pose (pitch and roll
    then come from the horizon). ``full_view``: keep the camera's own view (sky and all)
    instead of :func:`sea_view`. ``evidence_width``: the width of ``Sequence.fine`` (None:
    no fine sequence). Returns ``(Sequence, StageReport)``."""
    from jaxocean import lens, radiometry, rectify
    from jaxocean.io import camera_file as cf_io
    from jaxocean.io.scene import SCENE_FILENAME, SceneFileError, refuse_other_kind

    camera_path = Path(camera_path)
    if camera_path.is_dir() and not (camera_path / cf_io.CAMERA_FILENAME).exists():
        if not (camera_path / SCENE_FILENAME).is_file():
            raise MissingFileError(camera_path, f"a directory with neither a camera file ({cf_io.CAMERA_FILENAME}) "
                                                f"nor a scene ({SCENE_FILENAME})")
        camera_path = camera_path / SCENE_FILENAME  # a scene directory, as render and reedit read one
    frames = [Path(f) for f in (frames or [])]
    if not is_integer(step, 1):
        raise ValueError(f"step must be an int >= 1; got {step!r}")
    # a negative count would slice frames off the end: max_frames=-1 dropped the last one
    if max_frames is not None and not is_integer(max_frames, 1):
        raise ValueError(f"max_frames must be an int >= 1 (or None: every frame); got {max_frames!r}")

    video = len(frames) == 1 and is_video_file(frames[0])
    for f in frames:  # a missing file is named as such, before any count of frames
        require_file(f, "video file" if video else "frame file")

    def run():
        details, scene_camera = {}, None
        resp = radiometry.Response(response, gamma)

        def load(paths):
            # black pixels (vignetted corners, crushed shadows) carry no radiance either
            return radiometry.load_frames(paths, response=resp, low=BLACK_LEVEL)

        loaded = load(frames) if video else None
        n_video = None if loaded is None else len(loaded.linear)
        json_path, data = cf_io.read_camera_json(camera_path)  # read once: a scene or a camera file
        # another file jaxocean writes (a lighting fit has a "camera" too) is named as what it is
        refuse_other_kind(data, json_path, "the camera takes a camera file (camera.json: intrinsics and a pose "
                                           "per frame) or a synthetic scene.json", camera_file_ok=True)
        scene = _scene_of(data, json_path)
        if scene is not None:
            if scene.camera is None or scene.times is None:
                raise InvalidValueError(f"{camera_path} has no camera or no times")
            times = np.asarray(scene.times, np.float64)
            if np.any(np.diff(times) <= 0):  # the camera file's rule (a scene may hold any times)
                n = int(np.argmax(np.diff(times) <= 0)) + 1
                raise SceneFileError(json_path, f"times[{n}]: the frame times of a sequence must increase strictly; "
                                                f"got {times[n]:g} after {times[n - 1]:g}")
            listed = frames or _scene_frames(camera_path.parent)
            count = n_video if video else len(listed)
            if count != len(times):
                raise InvalidValueError(f"{count} frames given for the {len(times)} times of {camera_path}")
            if frames and not video:
                _check_scene_frame_order(frames, camera_path)
            if height is not None:
                raise InvalidValueError(f"{camera_path} is a scene.json: its camera gives the height "
                                        f"({float(scene.camera.height):.6g} m); a camera height ({height} m) "
                                        f"applies only to a camera file without poses")
            scene_camera = scene.camera
            H, W = scene.camera.resolution
            pose0 = lens.pose_of(scene.camera)
            poses = lens.Pose(*(np.full(len(times), float(v)) for v in pose0))
            camera_file = cf_io.CameraFile(camera_path, (W, H), lens.pinhole_intrinsics(scene.camera),
                                           lens.Distortion(), tuple(listed) * (len(times) if video else 1), times,
                                           poses, False)
        else:
            camera_file = cf_io.camera_file_from_json(data, json_path, require_pose=height is None,
                                                      check_files=not frames)
            if camera_file.poses is not None and height is not None:
                raise InvalidValueError(f"{camera_path}: every frame gives a pose with its camera_height_m; a camera "
                                        f"height ({height} m) applies only to a camera file without poses (pitch "
                                        f"and roll then come from the horizon): leave it out, or edit the file")
            if video:
                if n_video != len(camera_file.times):
                    raise InvalidValueError(f"the video {frames[0]} has {n_video} frames; the camera file "
                                            f"{camera_path} lists {len(camera_file.times)}")
                # every frame comes from the video, not from the files the camera file lists
                camera_file = camera_file._replace(files=(frames[0].resolve(),) * n_video)
            else:
                camera_file = cf_io.select(camera_file, _frame_files(frames, camera_file.files, camera_path))
                if frames:  # the frames given are read (a frame matched by name may lie in another folder)
                    camera_file = camera_file._replace(files=tuple(f.resolve() for f in frames))
        idx = np.arange(0, len(camera_file.times), step)[:max_frames]
        if len(idx) < 2:
            raise InvalidValueError(f"reconstruct needs at least 2 frames; {len(idx)} selected")
        camera_file = cf_io.select(camera_file, idx)
        if video:
            loaded = loaded._replace(display=None if loaded.display is None else loaded.display[idx],
                                     linear=loaded.linear[idx], usable=loaded.usable[idx])
        else:
            loaded = load(list(camera_file.files))
        if loaded.display is None:  # OpenEXR: radiance; shown through the library's tone map
            resp = radiometry.Response("bruneton")
            # its unusable pixels (NaN, inf, negative: masked) hold 0, as rectify's invalid ones
            # do, so that the display and the horizon see finite values
            usable = loaded.usable if loaded.gray else loaded.usable[..., None]  # gray: (T, H, W)
            linear = np.where(usable, loaded.linear, 0).astype(np.float32)
            loaded = loaded._replace(linear=linear,
                                     display=np.asarray(radiometry.to_display(linear, resp), np.float32))
        W_src, H_src = camera_file.image_size
        if loaded.linear.shape[1:3] != (H_src, W_src):
            # frames are read upright (their EXIF orientation applied): a camera file made from
            # the stored, sideways pixels has width and height swapped
            turned = (" (the frames are read as displayed, their EXIF orientation applied: the camera file must "
                      "describe the upright image)" if loaded.linear.shape[1:3] == (W_src, H_src) else "")
            raise InvalidValueError(f"the frames are {loaded.linear.shape[2]}x{loaded.linear.shape[1]} pixels; the "
                                    f"camera file {camera_path} says {W_src}x{H_src}{turned}")
        if camera_file.poses is None:
            from jaxocean import horizon as hz

            pitch, roll = [], []
            for i in range(len(idx)):
                h = hz.estimate_horizon(loaded.linear[i], camera_file.intrinsics, camera_file.distortion, height)
                if not h.success:
                    raise InvalidValueError(f"frame {camera_file.files[i]} has no pose and its horizon could not "
                                            f"be found: {h.message}")
                pitch.append(h.pitch), roll.append(h.roll)
            n = len(idx)
            camera_file = camera_file._replace(poses=lens.Pose(np.full(n, float(height)), np.asarray(pitch),
                                                               np.asarray(roll), np.zeros(n), np.zeros(n),
                                                               np.zeros(n)), headings=False)
            details["pose_from_horizon"] = True
        H = _working_height(width, W_src, H_src)
        if full_view:
            camera = rectify.virtual_camera(camera_file, resolution=(H, int(width)))
        elif scene_camera is not None:
            # the scene's own view, at the working width; where the working aspect is wider
            # than the scene's, the field of view narrows so that the view stays inside its frames
            H_scene, W_scene = scene_camera.resolution
            fov = 2 * jnp.arctan(jnp.tan(scene_camera.fov / 2) * min(1.0, W_scene * H / (H_scene * width)))
            camera = scene_camera if scene_camera.resolution == (H, width) else dataclasses.replace(
                scene_camera, resolution=(H, int(width)), fov=fov.astype(jnp.asarray(scene_camera.fov).dtype))
        else:
            camera = sea_view(camera_file, width=width)
        linear = loaded.linear if loaded.linear.ndim == 4 else loaded.linear[..., None]
        display = loaded.display if loaded.display.ndim == 4 else loaded.display[..., None]
        stack = np.concatenate([linear, display, loaded.usable[..., None].astype(linear.dtype)], -1)
        rect = rectify.rectify(stack, camera_file.poses, camera_file.intrinsics, camera_file.distortion, camera)
        c = linear.shape[-1]
        images, disp = rect.images[..., :c], rect.images[..., c:2 * c]
        usable = rect.valid & (rect.images[..., -1] > 0.999)
        if c == 1:
            images, disp = (np.repeat(a, 3, -1) for a in (images, disp))
        fine = None
        if evidence_width is not None:
            fine_width = min(16 * (int(evidence_width) // 16), 16 * (W_src // 16))
            fine_camera = dataclasses.replace(camera, resolution=(_working_height(fine_width, W_src, H_src),
                                                                  fine_width))
            gray = linear[..., 0] if c == 1 else np.asarray(radiometry.luminance(linear))
            fr = rectify.rectify(np.stack([gray, loaded.usable.astype(gray.dtype)], -1), camera_file.poses,
                                 camera_file.intrinsics, camera_file.distortion, fine_camera)
            fine = (np.asarray(fr.images[..., 0], np.float32), np.asarray(fr.valid & (fr.images[..., 1] > 0.999)),
                    fine_camera)
        seq = Sequence(np.asarray(images, np.float32), np.asarray(usable), np.clip(np.asarray(disp, np.float32), 0, 1),
                       camera, np.asarray(camera_file.times, np.float64), bool(loaded.gray),
                       bool(camera_file.headings), tuple(str(f) for f in camera_file.files), resp, fine)
        sea = np.asarray(cam.intersect_sea(camera).mask)
        frac, shares, problem = usable_share(usable, sea, seq.files)
        details.update(frames=len(idx), resolution=list(camera.resolution), source_size=[W_src, H_src],
                       response=response, gray=bool(loaded.gray), usable_sea_fraction=frac,
                       usable_sea_fraction_min=float(shares.min()),
                       camera=cam.camera_to_dict(camera, degrees=True),
                       duration_s=float(seq.times[-1] - seq.times[0]))
        msg = problem or (f"{len(idx)} frames at {camera.resolution[1]}x{camera.resolution[0]}, {frac:.0%} of the "
                          f"sea usable")
        return seq, problem is None, msg, details

    return timed("radiometry", run)

