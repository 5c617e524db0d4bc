"""Scene metadata: ``scene.json`` beside the frames.

Protocol
--------
A scene file is one JSON object::

    {
      "version":  "0.1.0",                       # jaxocean.__version__ of the writer
      "waves":    {"amplitude": [...], "omega": [...], "theta": [...], "phase": [...]},
      "camera":   {"height": 10.0, "pitch": 0.35, ..., "resolution": [H, W],
                   "projection": "perspective"},
      "lighting": {"sun_azimuth": ..., "sun_elevation": ..., "sun_color": [r, g, b], ...},
      "spectrum": {"hs": ..., "tp": ..., "gamma": ..., "theta_mean": ..., "s_max": ...},
      "times":    [t0, t1, ...],                 # frame times [s]
      "seed":     0,                             # the integer the scene was drawn from
      "extra":    {...}                          # free JSON data of the caller
    }

Every section but ``version`` may be ``null``. A pytree section holds exactly its type's
fields (a missing or unknown key is an error; only fields with a default, such as
``Spectrum.gamma``, may be left out), each a number or a nested list of numbers in the
leaf's shape, so batched pytrees ``(B, ...)`` are stored too. The camera's static fields
``resolution`` and ``projection`` are stored with it. Units are those of the pytrees:
metres, seconds, radians, linear RGB.

Precision: numbers are written with Python's shortest exact float64 repr, so every float32
and float64 value survives the round trip bit for bit. Leaves are read back as JAX arrays of
JAX's default float dtype (float32, float64 under ``jax_enable_x64``): float32 scenes are
restored exactly, float64 scenes exactly under x64. Non-finite numbers are refused (strict
JSON has none).

Writes are atomic (:func:`jaxocean.files.write_json`); reading errors name the file
(:class:`SceneError`, :class:`jaxocean.io.exr.MissingFileError`). :func:`json_kind` names
the other JSON files jaxocean writes (a lighting fit, a dataset's settings, a camera file,
...), and :func:`refuse_other_kind` refuses one where a scene is expected, by that name:
the command line and the library read such files with the same words.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxocean.camera import Camera, camera_to_dict, validate_camera
from jaxocean.errors import InvalidValueError, check_finite
from jaxocean.files import write_json
from jaxocean.io.exr import FileFormatError, MissingFileError, require_file
from jaxocean.shading import Lighting, validate_lighting
from jaxocean.spectrum import Spectrum, validate_spectrum
from jaxocean.waves import Waves, validate

__all__ = [
    "SCENE_FILENAME",
    "Scene",
    "SceneError",
    "SceneFileError",
    "scene_to_dict",
    "scene_from_dict",
    "write_scene",
    "read_scene",
    "json_kind",
    "refuse_other_kind",
    "waves_summary",
]

SCENE_FILENAME = "scene.json"

_SECTIONS = ("waves", "camera", "lighting", "spectrum", "times", "seed", "extra")
_CAMERA_STATIC = tuple(f.name for f in dataclasses.fields(Camera) if f.metadata.get("static"))
_CAMERA_LEAVES = tuple(f.name for f in dataclasses.fields(Camera) if not f.metadata.get("static"))

# NamedTuple pytrees stored field by field, with their validators. Waves are checked for
# structure and finiteness only: steepness is a modelling limit, and a scene that was
# written must read back.
_NAMEDTUPLE_SECTIONS = {
    "waves": (Waves, lambda waves: validate(waves, max_steepness=None)),
    "lighting": (Lighting, validate_lighting),
    "spectrum": (Spectrum, validate_spectrum),
}


class Scene(NamedTuple):
    """A scene read by :func:`scene_from_dict` / :func:`read_scene`.

    ``waves``, ``camera``, ``lighting``, ``spectrum``: the pytrees (JAX arrays of the
    default float dtype) or None; ``times``: ``(T,)`` frame times [s] or None; ``seed``: int
    or None; ``version``: the jaxocean version that wrote it; ``extra``: the caller's JSON
    data or None.
    """

    waves: Waves | None
    camera: Camera | None
    lighting: Lighting | None
    spectrum: Spectrum | None
    times: Any
    seed: int | None
    version: str
    extra: dict | None


class SceneError(InvalidValueError):
    """A scene dict or ``scene.json`` that does not follow the protocol.

    :func:`read_scene` raises the :class:`jaxocean.io.exr.FileFormatError` subclass
    :class:`SceneFileError`, whose message names the file.
    """


class SceneFileError(FileFormatError, SceneError):
    """A ``scene.json`` that cannot be read; the message names the file."""


# --------------------------------------------------------------------------- to JSON


def scene_to_dict(*, waves=None, camera=None, lighting=None, spectrum=None, times=None, seed=None,
                  extra=None) -> dict:
    """A JSON-safe dict of a scene (the module docstring gives the layout).

    Every argument is optional. The pytrees are validated first (their own validators;
    waves without the steepness limit) and must be finite; ``times`` is a 1-D array-like of
    frame times [s]; ``seed`` an int; ``extra`` a dict that ``json.dumps`` can write.

    Returns:
        a dict of str, int, float, list and None only; ``version`` is this jaxocean's.
    """
    import jaxocean  # at call time: jaxocean/__init__ may import this module

    scene = {"version": jaxocean.__version__}
    for name, value in (("waves", waves), ("lighting", lighting), ("spectrum", spectrum)):
        scene[name] = None if value is None else _namedtuple_to_json(value, name)
    scene["camera"] = None if camera is None else _camera_to_json(camera)
    scene["times"] = None if times is None else _times_to_json(times)
    scene["seed"] = None if seed is None else _seed(seed)
    scene["extra"] = None if extra is None else _extra(extra)
    return scene


def _namedtuple_to_json(value, section: str) -> dict:
    cls, check = _NAMEDTUPLE_SECTIONS[section]
    if not isinstance(value, cls):
        raise ValueError(f"scene {section} must be a {cls.__name__}; got {type(value).__name__}")
    check(value)
    return {name: _leaf_to_json(leaf, f"{section}.{name}") for name, leaf in zip(cls._fields, value)}


def _camera_to_json(camera: Camera) -> dict:
    validate_camera(camera)
    for name in _CAMERA_LEAVES:
        _leaf_to_json(getattr(camera, name), f"camera.{name}")  # real and finite, or a ValueError naming it
    return camera_to_dict(camera)


def _leaf_to_json(leaf, where: str):
    """A real array -> a float or nested lists of floats, exactly (float64 repr)."""
    array = np.asarray(leaf)
    if array.dtype.kind not in "iuf":
        raise ValueError(f"scene {where} must be real numbers; got dtype {array.dtype}")
    check_finite(array, f"scene {where}")
    return array.astype(np.float64).tolist()


def _times_to_json(times) -> list:
    if np.ndim(times) != 1:
        raise ValueError(f"scene times must be a 1-D sequence of frame times; got shape {np.shape(times)}")
    if np.size(times) == 0:
        raise ValueError("scene times must hold at least one frame time (pass times=None for a scene without frames)")
    return _leaf_to_json(times, "times")


def _seed(seed) -> int:
    if isinstance(seed, np.integer):
        seed = int(seed)
    if isinstance(seed, bool) or not isinstance(seed, int):
        raise ValueError(f"scene seed must be an int; got {seed!r}")
    return seed


def waves_summary(waves, clamped_waves: int | None = None) -> dict:
    """What drawn waves carry, for a scene file's ``extra`` beside the requested ``spectrum``:
    ``waves_hs_m``, the significant wave height ``4 sqrt(sum h^2 / 2)`` [m] of the waves
    themselves (the sampled band, after the steepness clamp), and ``clamped_waves``, how many
    of them the draw lowered to the steepness limit (None: not known)."""
    amplitude = np.asarray(waves.amplitude, np.float64)
    return {"waves_hs_m": float(4.0 * np.sqrt(np.sum(amplitude ** 2) / 2.0)),
            "clamped_waves": None if clamped_waves is None else int(clamped_waves)}


def _extra(extra) -> dict:
    if not isinstance(extra, dict):
        raise ValueError(f"scene extra must be a dict; got {type(extra).__name__}")
    try:
        json.dumps(extra, allow_nan=False)
    except (TypeError, ValueError) as error:
        raise ValueError(f"scene extra must be JSON-serialisable with finite numbers: {error}") from None
    return extra


# --------------------------------------------------------------------------- from JSON


def json_kind(data) -> str | None:
    """What parsed JSON ``data`` that is not a scene file is, when it is one jaxocean writes;
    None for anything else (a scene, a malformed scene, JSON of no known kind)."""
    if not isinstance(data, dict):
        return None
    if {"scenes", "frames", "ranges"} <= data.keys():  # dataset.json carries a version too
        return "a dataset's settings (dataset.json; its scenes are the scene_XXXXX directories beside it)"
    if "version" in data:
        return None
    if "lighting" in data and ("rms_residual" in data or "loss" in data):
        return "a lighting fit result (jaxocean fit-lighting)"
    if "files" in data:
        return "a dataset manifest (manifest.json)"
    if {"train", "val", "test"} <= data.keys():
        return "a dataset's splits (splits.json)"
    if "outputs" in data and "frames" in data:
        return "a demo summary (summary.json; its scene is the render directory beside it)"
    if _is_camera_file(data):
        return ("a camera file (camera.json of real footage: intrinsics and a pose per frame; "
                "jaxocean reconstruct --camera takes it)")
    return None


def _is_camera_file(data) -> bool:
    return isinstance(data, dict) and {"image_size", "intrinsics"} <= data.keys()


def refuse_other_kind(data, path, needs: str, *, camera_file_ok: bool = False) -> None:
    """:class:`SceneFileError` ``"<path>: this is <kind>; <needs>"`` when the parsed JSON
    ``data`` of the file ``path`` is one of the other files :func:`json_kind` names, where
    a scene (or, with ``camera_file_ok``, a camera file) is expected; ``needs`` says what
    the caller takes instead. Anything else passes, for the scene's or camera file's own
    reader to judge."""
    if camera_file_ok and _is_camera_file(data):
        return
    kind = json_kind(data)
    if kind is not None:
        raise SceneFileError(path, f"this is {kind}; {needs}")


def scene_from_dict(d: dict) -> Scene:
    """Rebuild a :class:`Scene` from a dict in the layout of :func:`scene_to_dict`.

    Raises:
        SceneError: a missing ``version``, an unknown top-level key, a section with missing
            or unknown keys, non-numeric leaves; the pytrees' own validation errors (NaN,
            bad shapes, camera under the sea, ...) are reported as ``SceneError`` too,
            naming the section.
    """
    if not isinstance(d, dict):
        raise SceneError(f"a scene must be a JSON object; got {type(d).__name__}")
    _check_keys(d, required=("version",), optional=_SECTIONS, where="scene")
    if not isinstance(d["version"], str):
        raise SceneError(f"scene version must be a string; got {d['version']!r}")
    sections = {}
    for name in _SECTIONS:
        value = d.get(name)
        if value is None:
            sections[name] = None
            continue
        try:
            sections[name] = _SECTION_READERS[name](value, name)
        except SceneError:
            raise
        except ValueError as error:  # the pytrees' validators, with the section named
            raise SceneError(f"scene {name}: {error}") from error
    return Scene(version=d["version"], **sections)


def _check_keys(d, *, required, optional, where: str) -> None:
    if not isinstance(d, dict):
        raise SceneError(f"{where} must be a JSON object; got {type(d).__name__}")
    missing = [key for key in required if key not in d]
    unknown = [key for key in d if key not in required and key not in optional]
    if missing:
        raise SceneError(f"{where} is missing key(s) {missing}")
    if unknown:
        raise SceneError(f"{where} has unknown key(s) {unknown}; expected {list(required) + list(optional)}")


def _leaf_from_json(value, where: str):
    expected = f"{where} must be a number or nested lists of numbers of one shape"
    try:
        # bool is a number to NumPy; in a scene it is a mistake (at any depth of the lists).
        array = np.asarray(value, dtype=object if _holds_bool(value) else None)
    except ValueError:  # ragged lists
        raise SceneError(f"{expected}; got {value!r:.80}") from None
    if array.dtype.kind not in "iuf":
        raise SceneError(f"{expected}; got {value!r:.80}")
    if not np.all(np.isfinite(array)):  # Python's json reads NaN and Infinity; strict JSON has none
        raise SceneError(f"{where} must be finite; got {value!r:.80}")
    # The default float dtype, requested explicitly so that integers become floats; float32
    # without x64 (exact for float32 scenes), float64 with it.
    dtype = jnp.result_type(float)
    if np.any(np.abs(array.astype(np.float64)) > np.finfo(dtype).max):
        raise SceneError(f"{where} must be finite in {np.dtype(dtype).name}, the precision scenes are read in; "
                         f"got {value!r:.80}")
    return jnp.asarray(array, dtype=dtype)


def _holds_bool(value) -> bool:
    """Whether ``value`` is a bool or nested lists holding one."""
    if isinstance(value, list):
        return any(_holds_bool(v) for v in value)
    return isinstance(value, bool)


def _namedtuple_from_json(d, section: str):
    cls, check = _NAMEDTUPLE_SECTIONS[section]
    required = [name for name in cls._fields if name not in cls._field_defaults]
    _check_keys(d, required=required, optional=cls._field_defaults, where=f"scene {section}")
    leaves = {
        name: _leaf_from_json(d[name] if name in d else cls._field_defaults[name], f"scene {section}.{name}")
        for name in cls._fields
    }
    return check(cls(**leaves))


def _camera_from_json(d, section: str) -> Camera:
    _check_keys(d, required=_CAMERA_LEAVES + _CAMERA_STATIC, optional=(), where="scene camera")
    leaves = {name: _leaf_from_json(d[name], f"scene camera.{name}") for name in _CAMERA_LEAVES}
    resolution = d["resolution"]
    # A list of ints becomes the static tuple in Camera.__post_init__; validate_camera
    # rejects anything else.
    camera = Camera(**leaves, resolution=resolution, projection=d["projection"])
    return validate_camera(camera)


def _times_from_json(value, section: str):
    times = _leaf_from_json(value, "scene times")
    if times.ndim != 1:
        raise SceneError(f"scene times must be a list of numbers; got shape {times.shape}")
    if times.size == 0:
        raise SceneError("scene times must hold at least one frame time (leave 'times' out of a scene without frames)")
    return times


def _seed_from_json(value, section: str) -> int:
    if isinstance(value, bool) or not isinstance(value, int):
        raise SceneError(f"scene seed must be an integer; got {value!r}")
    return value


def _extra_from_json(value, section: str) -> dict:
    try:
        return _extra(value)
    except ValueError as error:
        raise SceneError(str(error)) from None


_SECTION_READERS = {
    "waves": _namedtuple_from_json,
    "lighting": _namedtuple_from_json,
    "spectrum": _namedtuple_from_json,
    "camera": _camera_from_json,
    "times": _times_from_json,
    "seed": _seed_from_json,
    "extra": _extra_from_json,
}


# --------------------------------------------------------------------------- files


def _scene_path(dir_or_path) -> Path:
    """``.../scene.json`` for a directory, the path itself for a ``*.json`` file."""
    path = Path(dir_or_path)
    return path if path.suffix.lower() == ".json" else path / SCENE_FILENAME


def write_scene(dir_or_path, scene_dict) -> Path:
    """Write ``scene.json`` atomically.

    Args:
        dir_or_path: a directory (``scene.json`` is written in it, created if needed) or a
            path ending in ``.json``.
        scene_dict: the output of :func:`scene_to_dict` (or a :class:`Scene`). It is checked
            with :func:`scene_from_dict` first, so a file that cannot be read back is never
            written.

    Returns:
        the written path.
    """
    if isinstance(scene_dict, Scene):
        scene_dict = scene_to_dict(**{name: getattr(scene_dict, name) for name in _SECTIONS})
    scene_from_dict(scene_dict)
    return write_json(_scene_path(dir_or_path), scene_dict)


def _refuse_directory_of_scenes(path: Path) -> None:
    """:class:`MissingFileError` naming the scene directories in ``path`` when it is a
    directory without a scene file of its own but with scenes one level down (a dataset's root)."""
    if not path.is_dir() or (path / SCENE_FILENAME).exists():
        return
    inner = sorted(found.parent.name for found in path.glob(f"*/{SCENE_FILENAME}"))
    if inner:
        listed = ", ".join(inner[:3]) + (f", ... ({len(inner)} in all)" if len(inner) > 3 else "")
        raise MissingFileError(path / SCENE_FILENAME, f"no such scene file: {path} holds scene directories "
                                                      f"({listed}); give one of them, e.g. {path / inner[0]}")


def read_scene(path) -> Scene:
    """Read a scene file (a directory means its ``scene.json``).

    Raises:
        MissingFileError: no such file (for a directory of scene directories, a dataset's root
            say, the message names them: give one).
        SceneFileError: a file that is neither ``*.json`` nor a directory (a frame, say), malformed
            JSON (with line and column) or a dict that :func:`scene_from_dict` rejects; the
            message names the file.
    """
    if Path(path).is_file() and Path(path).suffix.lower() != ".json":  # a frame, say: not a scene directory
        raise SceneFileError(path, f"not a scene file or directory; give the scene's directory ({Path(path).parent}) "
                                   f"or its {SCENE_FILENAME}")
    _refuse_directory_of_scenes(Path(path))
    path = require_file(_scene_path(path), "scene file")
    try:
        d = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as error:
        raise SceneFileError(path, f"not UTF-8 text ({error})") from error
    except json.JSONDecodeError as error:
        where = f"line {error.lineno}, column {error.colno}"
        raise SceneFileError(path, f"malformed JSON: {error.msg} at {where}") from error
    try:
        return scene_from_dict(d)
    except SceneError as error:
        raise SceneFileError(path, str(error)) from error
