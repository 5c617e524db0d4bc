"""Camera files: real footage's camera model and per-frame pose (``camera.json``).

Protocol
--------
A camera file is one JSON object beside (or above) the frames it describes::

    {
      "image_size": [W, H],                                   # pixels, required
      "intrinsics": {"fx": .., "fy": .., "cx": .., "cy": ..}, # pixels, required
      "distortion": {"model": "brown-conrady", "k1": .., "k2": .., "p1": .., "p2": ..},
      "units":      {"length": "m", "angle": "rad", "time": "s", ...},
      "frame_rate_hz": 5.0,
      "frames": [
        {"file": "frames/frame_0000.png", "t": 0.0,
         "camera_height_m": 14.07, "pitch_rad": 0.320, "roll_rad": 0.012, "yaw_rad": 1.047,
         "ship_east_m": 0.0, "ship_north_m": 0.0, "index": 0},
        ...
      ],
      ... any other keys (source, license, notes, t0_utc, pose_uncertainty_1sigma, ...)
    }

* Pixels are 0-based with the centre of the top-left pixel at (0, 0) (OpenCV: ``u`` the
  column, ``v`` the row). ``intrinsics`` and ``distortion`` are those of
  :mod:`jaxocean.lens` (``distortion`` may be left out: no distortion; missing coefficients
  are 0; the only model is ``"brown-conrady"``; a coefficient the model lacks, such as
  ``k3`` or ``skew``, is refused unless it is 0). The principal point lies inside the image,
  and the radial distortion must be one-to-one out to the image's corners (every pixel has a
  ray; :func:`jaxocean.lens.max_radius`).
* ``file``: path of the frame relative to the camera file's folder; it must exist, and no
  two frames name one file.
* ``t`` [s]: strictly increasing frame times. It may be left out of every frame when
  ``frame_rate_hz`` is given (then ``t = n / frame_rate_hz`` for the n-th frame listed);
  given with both, the times' mean step is ``1 / frame_rate_hz`` within 1%.
* The pose (:class:`jaxocean.lens.Pose`): ``camera_height_m`` (> 0, the optical centre above
  mean sea level, heave included), ``pitch_rad`` (optical axis below the horizontal, in
  (-pi/2, pi/2)), ``roll_rad`` (in (-pi/2, pi/2), positive: the horizon descends to the right), ``yaw_rad``
  (the *compass heading* of the optical axis, clockwise from north, despite its name; in
  [-2 pi, 2 pi]: a larger one is taken for degrees and refused), and
  optionally ``ship_east_m`` / ``ship_north_m`` (horizontal position relative to any fixed
  origin; 0 when absent). Every frame gives these four fields, or none does (then
  ``poses`` is None, allowed with ``require_pose=False``: estimate pitch and roll from the
  horizon); the optional two are given by every frame or none.
* ``units``, when present, must say metres, radians and seconds.
* Other keys are kept (``extra`` at the top level, ``frame_extra`` per frame, e.g. ``index``)
  and written back by :func:`write_camera_file`; ``frame_rate_hz`` is derived from the times
  on writing (written when they are evenly spaced).

Errors are :class:`CameraFileError` (a :class:`jaxocean.io.exr.FileFormatError` and
:class:`jaxocean.errors.InvalidValueError`) whose message names the file and the field, e.g.
``camera.json: frames[3].pitch_rad: must lie in (-pi/2, pi/2) rad; got 1.7``; a missing
camera file is :class:`jaxocean.io.exr.MissingFileError`. Host-side code: NumPy float64.
"""

from __future__ import annotations

import json
import math
import os
import sys
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from jaxocean.errors import is_integer
from jaxocean.files import write_json
from jaxocean.io.exr import FileFormatError, require_file
from jaxocean.lens import Distortion, Intrinsics, Pose

__all__ = [
    "CAMERA_FILENAME",
    "DISTORTION_MODELS",
    "CameraFile",
    "CameraFileError",
    "read_camera_file",
    "read_camera_json",
    "camera_file_from_json",
    "write_camera_file",
    "camera_file_to_dict",
    "select",
]

CAMERA_FILENAME = "camera.json"
DISTORTION_MODELS = ("brown-conrady",)

_UNITS = {"length": "m", "angle": "rad", "time": "s"}
_PIXEL_UNIT = "px; 0-based, pixel centre at integer coordinates (OpenCV convention)"
#: the widest field of view [deg] a focal length may imply across the image: a pinhole
#: lens with Brown-Conrady distortion covers less; wider means normalised or wrong units
MAX_FIELD_OF_VIEW_DEG = 170.0

_POSE_FIELDS = ("camera_height_m", "pitch_rad", "roll_rad", "yaw_rad")
_OFFSET_FIELDS = ("ship_east_m", "ship_north_m")
_FRAME_FIELDS = ("file", "t") + _POSE_FIELDS + _OFFSET_FIELDS
_TOP_FIELDS = ("image_size", "intrinsics", "distortion", "units", "frame_rate_hz", "frames")
# evenly spaced times, within this fraction of a step, get a frame_rate_hz on writing
_EVEN_SPACING = 1e-6
#: frame_rate_hz beside per-frame times: their mean step must be 1 / frame_rate_hz within this fraction
RATE_TOLERANCE = 0.01


class CameraFileError(FileFormatError):
    """A camera file that does not follow the protocol; the message names the file and the
    field (also an :class:`jaxocean.errors.InvalidValueError`)."""


class CameraFile(NamedTuple):
    """A camera file read by :func:`read_camera_file`.

    * ``path``        the JSON file (:class:`pathlib.Path`).
    * ``image_size``  ``(W, H)`` pixels.
    * ``intrinsics``  :class:`jaxocean.lens.Intrinsics` (Python floats).
    * ``distortion``  :class:`jaxocean.lens.Distortion` (Python floats).
    * ``files``       tuple of ``T`` absolute frame paths.
    * ``times``       ``(T,)`` float64 frame times [s], strictly increasing.
    * ``poses``       :class:`jaxocean.lens.Pose` of ``(T,)`` float64 arrays, or None.
    * ``headings``    True: ``poses.heading`` is a compass bearing (clockwise from north).
    * ``extra``       dict of the file's other top-level keys (None: none).
    * ``frame_extra`` tuple of ``T`` dicts of each frame's other keys (None: none).
    """

    path: Path
    image_size: tuple[int, int]
    intrinsics: Intrinsics
    distortion: Distortion
    files: tuple[Path, ...]
    times: np.ndarray
    poses: Pose | None
    headings: bool = True
    extra: dict | None = None
    frame_extra: tuple[dict, ...] | None = None


# --------------------------------------------------------------------------- reading


class _Fields:
    """Typed access to a JSON object, raising CameraFileError that names file and field."""

    def __init__(self, path: Path):
        self.path = path

    def fail(self, field: str, problem: str):
        raise CameraFileError(self.path, f"{field}: {problem}")

    def mapping(self, value, field: str) -> dict:
        if not isinstance(value, dict):
            self.fail(field, f"must be a JSON object; got {_kind(value)}")
        return value

    def number(self, parent: dict, key: str, field: str, *, required=True, default=None) -> float:
        if key not in parent:
            if required:
                self.fail(field, "missing")
            return default
        value = parent[key]
        if isinstance(value, bool) or not isinstance(value, (int, float)):
            self.fail(field, f"must be a number; got {_kind(value)}")
        if isinstance(value, int) and abs(value) > sys.float_info.max:  # JSON's integers are unbounded
            self.fail(field, "must be finite; got an integer beyond the floating-point range")
        if not math.isfinite(value):
            self.fail(field, f"must be finite; got {value}")
        return float(value)


def _kind(value) -> str:
    if value is None:
        return "null"
    if isinstance(value, bool):
        return f"a boolean ({str(value).lower()})"
    if isinstance(value, str):
        return f"a string ({value!r})"
    return {dict: "an object", list: "an array"}.get(type(value), f"{type(value).__name__} {value!r}")


def read_camera_file(path, *, require_pose: bool = True, check_files: bool = True) -> CameraFile:
    """Read and validate a camera file (a directory means its ``camera.json``).

    Args:
        path: the JSON file, or the folder holding ``camera.json``.
        require_pose: when True, every frame must give a pose; when False, a file whose
            frames give no pose reads with ``poses=None`` (a pose on some frames but not
            others is an error either way).
        check_files: check that every listed frame exists.

    Raises:
        MissingFileError: no such camera file.
        CameraFileError: malformed JSON, or any field outside the protocol (module
            docstring); the message names the file and the field.
    """
    path, data = read_camera_json(path)
    return camera_file_from_json(data, path, require_pose=require_pose, check_files=check_files)


def read_camera_json(path) -> tuple[Path, Any]:
    """``(path, data)``: the camera file's path (a directory means its ``camera.json``) and
    its parsed, not yet validated JSON -- for callers that look at the JSON before deciding
    how to read it (``reconstruct`` also accepts a ``scene.json``); validate it with
    :func:`camera_file_from_json`. Raises as :func:`read_camera_file` does for a missing
    file or malformed JSON."""
    path = Path(path)
    if path.is_dir():
        path = path / CAMERA_FILENAME
    path = require_file(path, "camera file")
    try:
        return path, json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as error:
        raise CameraFileError(path, f"not UTF-8 text ({error})") from error
    except json.JSONDecodeError as error:
        raise CameraFileError(path, f"malformed JSON: {error.msg} at line {error.lineno}, column {error.colno}") from error
    except ValueError as error:  # e.g. an integer literal longer than Python converts
        raise CameraFileError(path, f"malformed JSON: {error}") from error


def camera_file_from_json(data, path, *, require_pose: bool = True, check_files: bool = True) -> CameraFile:
    """Validate the parsed JSON ``data`` of the camera file at ``path`` (frame paths are
    relative to its folder; errors name it): :func:`read_camera_file` without the reading."""
    path = Path(path)
    f = _Fields(path)
    data = f.mapping(data, "top level")

    size = data.get("image_size")
    if "image_size" not in data:
        f.fail("image_size", "missing")
    if (not isinstance(size, list) or len(size) != 2
            or not all(is_integer(n, 1) for n in size)):
        f.fail("image_size", f"must be two positive integers [W, H]; got {size!r}")
    image_size = (size[0], size[1])

    if "intrinsics" not in data:
        f.fail("intrinsics", "missing")
    k = f.mapping(data["intrinsics"], "intrinsics")
    _refuse_unmodelled(f, k, "intrinsics", Intrinsics._fields, zero_allowed=("skew",))
    intrinsics = Intrinsics(*(f.number(k, name, f"intrinsics.{name}") for name in Intrinsics._fields))
    for name, extent in (("fx", image_size[0]), ("fy", image_size[1])):
        focal = getattr(intrinsics, name)
        if focal <= 0:
            f.fail(f"intrinsics.{name}", f"focal length must be > 0 px; got {focal}")
        fov = 2.0 * math.degrees(math.atan(0.5 * extent / focal))
        if fov > MAX_FIELD_OF_VIEW_DEG:
            f.fail(f"intrinsics.{name}", f"{focal} px gives a field of view of {fov:.1f} deg across the image's "
                                         f"{extent} px (a pinhole lens with Brown-Conrady distortion covers at most "
                                         f"{MAX_FIELD_OF_VIEW_DEG:g}); focal lengths are in pixels, not normalised")

    for name, extent in (("cx", image_size[0]), ("cy", image_size[1])):
        centre = getattr(intrinsics, name)
        if not -0.5 <= centre <= extent - 0.5:
            f.fail(f"intrinsics.{name}", f"the principal point must lie inside the image, in [-0.5, {extent - 0.5}] "
                                         f"px for its {extent} px; got {centre}")

    distortion = Distortion()
    if data.get("distortion") is not None:
        d = f.mapping(data["distortion"], "distortion")
        model = d.get("model")
        if model not in DISTORTION_MODELS:
            f.fail("distortion.model", f"unknown distortion model {model!r}; known: {list(DISTORTION_MODELS)}")
        _refuse_unmodelled(f, d, "distortion", ("model",) + Distortion._fields, zero_allowed=("k3",))
        distortion = Distortion(*(f.number(d, name, f"distortion.{name}", required=False, default=0.0)
                                  for name in Distortion._fields))
        _check_one_to_one(f, distortion, intrinsics, image_size)

    if data.get("units") is not None:
        units = f.mapping(data["units"], "units")
        for name, unit in _UNITS.items():
            if name in units and units[name] != unit:
                f.fail(f"units.{name}", f"must be {unit!r}; got {units[name]!r}")

    frame_rate = f.number(data, "frame_rate_hz", "frame_rate_hz", required=False)
    if frame_rate is not None and frame_rate <= 0:
        f.fail("frame_rate_hz", f"must be > 0; got {frame_rate}")

    if "frames" not in data:
        f.fail("frames", "missing")
    frames = data["frames"]
    if not isinstance(frames, list) or not frames:
        f.fail("frames", f"must be a non-empty array of frame objects; got {_kind(frames)}")
    frames = [f.mapping(frame, f"frames[{n}]") for n, frame in enumerate(frames)]

    files = []
    for n, frame in enumerate(frames):
        name = frame.get("file")
        if not isinstance(name, str) or not name:
            f.fail(f"frames[{n}].file", "missing" if "file" not in frame else f"must be a path string; got {_kind(name)}")
        file = (path.parent / name).resolve()
        if check_files and not file.is_file():
            f.fail(f"frames[{n}].file", f"no such frame file {str(file)!r}")
        if file in files:  # one image at two times would pass a still frame for motion
            f.fail(f"frames[{n}].file", f"{name!r} is frames[{files.index(file)}]'s file too; each frame is a "
                                        f"file of its own")
        files.append(file)

    times = _times(f, frames, frame_rate)
    poses = _poses(f, frames, require_pose)
    extra = {key: value for key, value in data.items() if key not in _TOP_FIELDS}
    frame_extra = tuple({key: value for key, value in frame.items() if key not in _FRAME_FIELDS} for frame in frames)
    return CameraFile(
        path=path, image_size=image_size, intrinsics=intrinsics, distortion=distortion, files=tuple(files),
        times=times, poses=poses, headings=True, extra=extra or None,
        frame_extra=frame_extra if any(frame_extra) else None,
    )


def _refuse_unmodelled(f: _Fields, mapping: dict, field: str, known, zero_allowed=()) -> None:
    """A coefficient the lens model does not have would be dropped and the pixels mapped with
    the wrong lens: refused, except those in ``zero_allowed`` when exactly 0 (OpenCV writes
    ``k3 = 0`` and ``skew = 0`` for calibrations that fixed them)."""
    for key in mapping:
        if key in known:
            continue
        if key in zero_allowed:
            value = f.number(mapping, key, f"{field}.{key}")
            if value == 0:
                continue
            f.fail(f"{field}.{key}", f"the lens model has no {key!r} term ({', '.join(known)}); only 0 can "
                                     f"be given; got {value} (recalibrate without it)")
        f.fail(f"{field}.{key}", f"unknown field; {field} holds {', '.join(known)}")


def _check_one_to_one(f: _Fields, distortion: Distortion, intrinsics: Intrinsics, image_size) -> None:
    """Every pixel must have a ray (:func:`jaxocean.lens.fold_problem`)."""
    from jaxocean.lens import fold_problem

    problem = fold_problem(distortion, intrinsics, image_size)
    if problem is not None:
        f.fail("distortion", problem)


def _times(f: _Fields, frames: list[dict], frame_rate) -> np.ndarray:
    given = ["t" in frame for frame in frames]
    if not any(given) and frame_rate is not None:
        return np.arange(len(frames), dtype=np.float64) / frame_rate
    times = np.array([f.number(frame, "t", f"frames[{n}].t") for n, frame in enumerate(frames)], np.float64)
    steps = np.diff(times)
    if np.any(steps <= 0):
        n = int(np.argmax(steps <= 0)) + 1
        f.fail(f"frames[{n}].t", f"frame times must increase strictly; got {times[n]} after {times[n - 1]}")
    if frame_rate is not None and len(times) > 1 and not abs(steps.mean() * frame_rate - 1) <= RATE_TOLERANCE:
        f.fail("frame_rate_hz", f"{frame_rate} Hz disagrees with the frames' times (mean step {steps.mean():.6g} s, "
                                f"{1 / steps.mean():.6g} Hz): give one of them, or make them agree")
    return times


def _poses(f: _Fields, frames: list[dict], require_pose: bool) -> Pose | None:
    def consistent(fields):
        present = [[name in frame for name in fields] for frame in frames]
        if not any(any(row) for row in present):
            return False
        for n, row in enumerate(present):
            for name, here in zip(fields, row):
                if not here:
                    f.fail(f"frames[{n}].{name}", "missing (other frames or fields give a pose; every frame must give "
                           f"all of {list(fields)})")
        return True

    if not consistent(_POSE_FIELDS):
        if require_pose:
            f.fail("frames[0].camera_height_m", f"missing: no frame gives a pose ({', '.join(_POSE_FIELDS)}); "
                                                "give the camera height (reconstruct --camera-height) to take "
                                                "pitch and roll from the horizon")
        return None
    values = {name: np.array([f.number(frame, name, f"frames[{n}].{name}") for n, frame in enumerate(frames)])
              for name in _POSE_FIELDS}
    if consistent(_OFFSET_FIELDS):
        for name in _OFFSET_FIELDS:
            values[name] = np.array([f.number(frame, name, f"frames[{n}].{name}") for n, frame in enumerate(frames)])
    else:
        values.update({name: np.zeros(len(frames)) for name in _OFFSET_FIELDS})

    def check(name, ok, requirement):
        if not np.all(ok):
            n = int(np.argmin(ok))
            f.fail(f"frames[{n}].{name}", f"{requirement}; got {values[name][n]}")

    check("camera_height_m", values["camera_height_m"] > 0, "the camera must be above mean sea level (> 0 m)")
    for name in ("pitch_rad", "roll_rad"):
        check(name, (values[name] > -np.pi / 2) & (values[name] < np.pi / 2), "must lie in (-pi/2, pi/2) rad")
    # a compass heading in degrees (0-360) lies beyond a turn but for the first 6 degrees
    check("yaw_rad", np.abs(values["yaw_rad"]) <= 2 * np.pi, "a heading must lie in [-2pi, 2pi] rad (degrees?)")
    pitch = values["pitch_rad"]
    return Pose(height=values["camera_height_m"], pitch=pitch, roll=values["roll_rad"], heading=values["yaw_rad"],
                east=values["ship_east_m"], north=values["ship_north_m"])


# --------------------------------------------------------------------------- subsets and writing


def select(camera_file: CameraFile, indices) -> CameraFile:
    """The camera file of a subset of its frames: ``indices`` (ints, a slice or a boolean
    mask) pick files, times, poses and per-frame extras, in the order given; the result's
    times must still increase."""
    n_frames = len(camera_file.files)
    picked = np.arange(n_frames)[indices] if isinstance(indices, slice) else np.asarray(indices)
    if picked.dtype == bool:
        if picked.shape != (n_frames,):
            raise ValueError(f"select: a boolean mask needs {n_frames} entries; got shape {picked.shape}")
        picked = np.flatnonzero(picked)
    picked = np.atleast_1d(picked)
    if picked.size == 0:
        raise ValueError("select: no frames selected")
    if picked.dtype.kind not in "iu" or picked.ndim != 1:
        raise ValueError(f"select: indices must be a 1-D array of ints, a slice or a mask; got {indices!r}")
    if picked.min() < -n_frames or picked.max() >= n_frames:
        raise ValueError(f"select: indices out of range for {n_frames} frames: {picked.tolist()}")
    times = camera_file.times[picked]
    if np.any(np.diff(times) <= 0):
        raise ValueError("select: the selected frames' times must increase strictly (pick frames in time order)")
    poses = None if camera_file.poses is None else Pose(*(np.asarray(leaf)[picked] for leaf in camera_file.poses))
    frame_extra = (None if camera_file.frame_extra is None
                   else tuple(camera_file.frame_extra[n] for n in picked.tolist()))
    return camera_file._replace(files=tuple(camera_file.files[n] for n in picked.tolist()), times=times,
                                poses=poses, frame_extra=frame_extra)


def camera_file_to_dict(camera_file: CameraFile, folder) -> dict[str, Any]:
    """The JSON object of a camera file whose frame paths are written relative to ``folder``."""
    folder = Path(folder).resolve()
    data: dict[str, Any] = {}
    data.update(camera_file.extra or {})
    data["units"] = dict(_UNITS, pixel=_PIXEL_UNIT)
    data["image_size"] = [int(n) for n in camera_file.image_size]
    data["intrinsics"] = {name: float(value) for name, value in camera_file.intrinsics._asdict().items()}
    data["distortion"] = {"model": DISTORTION_MODELS[0],
                          **{name: float(value) for name, value in camera_file.distortion._asdict().items()}}
    times = np.asarray(camera_file.times, np.float64)
    steps = np.diff(times)
    if steps.size and np.all(np.abs(steps - steps.mean()) <= _EVEN_SPACING * steps.mean()):
        data["frame_rate_hz"] = float(1 / steps.mean())
    else:
        data.pop("frame_rate_hz", None)
    frames = []
    for n, file in enumerate(camera_file.files):
        frame = {"file": Path(os.path.relpath(Path(file).resolve(), folder)).as_posix(), "t": float(times[n])}
        if camera_file.poses is not None:
            pose = camera_file.poses
            for name, leaf in zip(_POSE_FIELDS + _OFFSET_FIELDS,
                                  (pose.height, pose.pitch, pose.roll, pose.heading, pose.east, pose.north)):
                frame[name] = float(np.broadcast_to(np.asarray(leaf, np.float64), times.shape)[n])
        if camera_file.frame_extra is not None:
            frame.update({key: value for key, value in camera_file.frame_extra[n].items() if key not in frame})
        frames.append(frame)
    data["frames"] = frames
    return data


def write_camera_file(path, camera_file: CameraFile) -> Path:
    """Write ``camera_file`` to ``path`` (a directory means its ``camera.json``), atomically.

    Frame paths are written relative to the new file's folder (they keep pointing at the
    same files); poses, times and extras are written as float64 exactly. Returns the path.
    """
    path = Path(path)
    if path.is_dir():
        path = path / CAMERA_FILENAME
    if not camera_file.headings:
        raise ValueError("write_camera_file: the schema stores compass headings; got headings=False")
    return write_json(path, camera_file_to_dict(camera_file, path.parent))
