"""The command line's readers and checks of its input (:mod:`jaxocean.cli`).

* Argument types for ``argparse``: :func:`resolution_arg` (``N`` or ``HxW``),
  :func:`index_list`, :func:`number_list`, :func:`positive_int`, :func:`positive_float`,
  and :class:`DeprecatedAlias` (a former option name that still works and says so).
* Checks made before any work, raising ``ValueError`` (exit 2) with a message naming the
  input: :func:`check_memory` (a render's estimated peak memory, :func:`render_bytes`,
  against :func:`available_memory`), :func:`check_out_dir`, :func:`check_out_file`,
  :func:`refuse_other_json` (a JSON file of another kind than the command takes, named by
  :func:`jaxocean.io.scene.json_kind`), :func:`refuse_out_over_source`, :func:`check_frames`,
  :func:`check_increasing`.
* Readers: :func:`scene_from_args` / :func:`scene_from_file` (a ``SceneSample``; the file's with its seed),
  :func:`lighting_from_file`, :func:`camera_from_args` and
  :func:`lighting_from_args` (``--camera-*``, ``--res``, ``--lighting``, ``--sun-*``).

Angles on the command line are degrees; the library's values are radians.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

import numpy as np

from jaxocean.files import read_json
from jaxocean.io.scene import refuse_other_kind

__all__ = ["resolution_arg", "parse_list", "index_list", "number_list", "positive_int", "positive_float",
           "fov_degrees", "pitch_degrees", "sun_elevation_degrees",
           "DeprecatedAlias", "render_bytes", "available_memory", "check_memory", "check_out_dir", "check_out_file",
           "refuse_out_over_source",
           "refuse_other_json", "scene_from_args", "scene_from_file", "lighting_from_file",
           "radians_or_none", "camera_from_args", "lighting_from_args", "check_frames", "check_increasing",
           "gigabytes"]


def resolution_arg(text: str):
    try:  # "16x" or "x16" is neither N nor HxW: int("") refuses the empty side
        parts = [int(p) for p in text.lower().split("x")]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < 1:
        raise argparse.ArgumentTypeError(f"resolution must be N or HxW with positive integers; got {text!r}")
    return tuple(parts)


def parse_list(text: str, convert, valid, expected: str):
    """Comma- or space-separated values: ``convert`` each; all must pass ``valid``."""
    try:
        values = [convert(p) for p in text.replace(",", " ").split()]
    except ValueError:
        values = []
    if not values or not all(valid(v) for v in values):
        raise argparse.ArgumentTypeError(f"expected {expected}; got {text!r}")
    return tuple(values)


def index_list(text: str):
    return parse_list(text, int, lambda v: v >= 0, "comma-separated frame indices >= 0, e.g. 0,1,5")


def number_list(text: str):
    return parse_list(text, float, math.isfinite, "comma-separated finite numbers, e.g. 0,1.5,10")


def positive_int(text: str):
    try:
        value = int(text)
    except ValueError:
        value = 0
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer; got {text!r}")
    return value


SEED_LIMIT = 2 ** 63  # seeds pass through int64 (the wave draw, the dataset's splits)


def seed_arg(text: str):
    try:
        value = int(text)
    except ValueError:
        value = -1
    if not 0 <= value < SEED_LIMIT:
        raise argparse.ArgumentTypeError(f"expected an integer seed in [0, 2^63); got {text!r}")
    return value


class DeprecatedAlias(argparse.Action):
    """A former option name kept working: stores into the new option's ``dest`` and says so."""

    def __init__(self, option_strings, dest, *, new: str, **kwargs):
        self.new = new
        kwargs.update(default=argparse.SUPPRESS, help=argparse.SUPPRESS)  # hidden; the new option's default holds
        super().__init__(option_strings, dest, **kwargs)

    def __call__(self, parser, namespace, values, option_string=None):
        print(f"jaxocean: note: {option_string} is deprecated; use {self.new}", file=sys.stderr)
        setattr(namespace, self.dest, values)


def fov_degrees(text: str):
    """A vertical field of view in degrees, in (0, 180)."""
    return _degrees_between(text, 0.0, 180.0, "a field of view in degrees, in (0, 180)")


def pitch_degrees(text: str):
    """A camera pitch below the horizon in degrees, in (-90, 90)."""
    return _degrees_between(text, -90.0, 90.0, "a pitch in degrees below the horizon, in (-90, 90)")


def sun_elevation_degrees(text: str):
    """A sun elevation in degrees, in [-90, 90] (the library checks it in radians)."""
    return _degrees_between(text, -90.0, 90.0, "a sun elevation in degrees, in [-90, 90]", closed=True)


def _degrees_between(text, low, high, what, closed: bool = False):
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (low <= value <= high if closed else low < value < high):
        raise argparse.ArgumentTypeError(f"expected {what}; got {text!r}")
    return value


def positive_float(text: str):
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not value > 0 or not math.isfinite(value):
        raise argparse.ArgumentTypeError(f"expected a positive number; got {text!r}")
    return value



# What a render holds, in float32 values: per pixel and frame the image (3) and the
# Geometry's normal (3), roughness (1), slope variance (2), mask (1), rest position (2),
# world position (3) and footprint (1); per pixel, one frame's working set. Measured on the
# CPU backend (peak RSS above the baseline, 60 waves, 128x192 to 512x768 pixels): 54 bytes
# per pixel and frame and 1.8-2.0 KB per pixel, besides ~200 MB for the compiled program.
_VALUES_PER_PIXEL_FRAME = 16
_WORKING_VALUES_PER_PIXEL = 512


def render_bytes(resolution, n_frames: int) -> int:
    """Estimated peak memory [bytes] of rendering ``n_frames`` frames of ``resolution``."""
    pixels = int(resolution[0]) * int(resolution[1])
    return 4 * pixels * (_VALUES_PER_PIXEL_FRAME * int(n_frames) + _WORKING_VALUES_PER_PIXEL)


def available_memory():
    """``(bytes, what)``: the memory a render may use -- the host's available memory
    (``/proc/meminfo`` MemAvailable, else the physical memory) and, on an accelerator, its
    memory limit, whichever is smaller -- or ``(None, None)`` when neither can be told."""
    limits = []
    try:
        with open("/proc/meminfo", encoding="ascii") as meminfo:
            for line in meminfo:
                if line.startswith("MemAvailable:"):
                    limits.append((int(line.split()[1]) * 1024, "the available memory (MemAvailable)"))
                    break
    except (OSError, ValueError, IndexError):
        pass
    if not limits:
        try:
            limits.append((os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE"), "the physical memory"))
        except (ValueError, OSError, AttributeError):
            pass
    try:
        import jax

        stats = jax.local_devices()[0].memory_stats() or {}
        if stats.get("bytes_limit"):
            limits.append((int(stats["bytes_limit"]), f"the {jax.local_devices()[0].platform} memory limit"))
    except Exception:  # a backend without memory statistics: the host's figure stands
        pass
    return min(limits) if limits else (None, None)


def gigabytes(n: float) -> str:
    gib = n / 2**30
    return f"{gib:,.0f} GiB" if gib >= 100 else f"{gib:.3g} GiB"


def check_memory(resolution, n_frames: int, what: str) -> None:
    """ValueError (exit 2) before any work when the render cannot fit in memory."""
    need = render_bytes(resolution, n_frames)
    limit, source = available_memory()
    if limit is not None and need > limit:
        raise ValueError(f"{what}: {resolution[0]}x{resolution[1]} pixels x {n_frames} frame(s) needs about "
                         f"{gigabytes(need)} of memory, more than {source} ({gigabytes(limit)}); "
                         f"use a smaller --res or fewer frames")


#: bytes per pixel and frame a dataset takes on disk at the least (compressed EXR of image
#: and geometry: measured 9.5 at 128^2 and 5.5 at 1024^2 in half floats), so that a size
#: refused by :func:`check_disk` is one the disk cannot hold whatever the compression does
DATASET_MIN_BYTES_PER_PIXEL = {True: 4.0, False: 8.0}  # half floats, float32


def check_disk(out, need: float, what: str) -> None:
    """ValueError (exit 2) before any work when ``need`` bytes more than ``out`` already
    holds (a resumed run keeps its files) cannot fit on the disk that will hold ``out``."""
    import shutil

    out = Path(out)
    held = sum(f.stat().st_size for f in out.rglob("*") if f.is_file()) if out.is_dir() else 0
    parent = out
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    free = shutil.disk_usage(parent).free
    if need - held > free:
        raise ValueError(f"{what}: needs at least {gigabytes(need - held)} of disk for {out}, more than the "
                         f"{gigabytes(free)} free there; use fewer scenes or frames, or a smaller --res")


def _check_out_parents(path: Path) -> None:
    """``--out`` whose nearest existing parent is a directory: one that is a file would make
    the write fail only after the work (a file cannot hold a directory)."""
    for parent in path.parents:
        if parent.exists():
            if not parent.is_dir():
                raise ValueError(f"--out {path}: {parent} is a file, not a directory; give a path in a directory")
            return


def _out_path(path, what: str) -> Path:
    """``--out`` as a path, refusing an empty one: ``Path("")`` is the current directory, and an
    empty ``--out`` is far more often an unset shell variable than a wish to write there."""
    if not str(path).strip():
        raise ValueError(f"--out is empty (an unset shell variable?); give {what}")
    return Path(path)


def check_out_dir(path) -> Path:
    """``--out`` of a command that writes a directory: not empty, not an existing file, nor
    under one."""
    path = _out_path(path, "the directory to write ('.' for the current one)")
    if path.exists() and not path.is_dir():
        raise ValueError(f"--out {path}: exists and is not a directory (this command writes a directory there)")
    _check_out_parents(path)
    return path


def refuse_out_over_source(out, source, command: str) -> None:
    """ValueError when ``--out`` is the directory whose scene.json ``source`` (a scene file or
    its directory) is: the scene written there would replace the frames and scene it is made
    from, which are then lost (an output directory holds one scene)."""
    from jaxocean.io.scene import SCENE_FILENAME

    source = Path(source)
    source_file = source / SCENE_FILENAME if source.is_dir() else source
    if source_file.resolve() == (Path(out) / SCENE_FILENAME).resolve():
        raise ValueError(f"--out {out}: holds the scene {command} reads ({source_file}); writing there would "
                         f"replace the frames it is made from. Give another directory")


def check_out_file(path, example: str) -> Path:
    """``--out`` of a command that writes one JSON file: not an existing directory, nor under a
    file, not empty. ``example``: the command's usual file name, suggested in the directory."""
    path = _out_path(path, f"the JSON file to write, e.g. {example}")
    _check_out_parents(path)
    if path.is_dir():
        raise ValueError(f"--out {path}: is a directory; give the JSON file to write, e.g. {path / example}")
    return path


def refuse_other_json(path, needs: str, *, camera_file_ok: bool = False) -> None:
    """ValueError naming what ``path`` is when it is a JSON file of another kind than a scene
    (or than a camera file, with ``camera_file_ok``): the file read by
    :func:`jaxocean.io.scene.refuse_other_kind`, which ``reconstruct`` shares."""
    path = Path(path)
    if not path.is_file():
        return
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, json.JSONDecodeError):
        return  # read_scene reports it
    refuse_other_kind(data, path, needs, camera_file_ok=camera_file_ok)


# ----------------------------------------------------------------------------- scenes, cameras and lighting


def scene_from_args(args):
    import jax

    from jaxocean import camera, shading, spectrum
    from jaxocean.io.dataset import SceneSample

    spec = spectrum.Spectrum(hs=args.hs, tp=args.tp, gamma=args.gamma, theta_mean=np.deg2rad(args.wave_direction),
                             s_max=args.spreading)
    sea = spectrum.sample_waves(jax.random.key(args.seed), spec, args.waves)  # clamps waves above the steepness limit
    cam = camera.make_camera(height=args.camera_height, pitch=np.deg2rad(args.camera_pitch_deg),
                             fov=np.deg2rad(args.camera_fov_deg), yaw=np.deg2rad(args.camera_yaw_deg),
                             resolution=args.res)
    light = shading.make_lighting(sun_azimuth=np.deg2rad(args.sun_azimuth),
                                  sun_elevation=np.deg2rad(args.sun_elevation))
    import jax.numpy as jnp
    return SceneSample(sea.waves, spec, cam, light, jnp.arange(args.frames, dtype=jnp.float32) * args.dt,
                       int(sea.n_clamped))


def refuse_damped_forecast(scene, path, command: str) -> None:
    """A damped least-squares forecast's frames come from the fitted waves, the long-wave
    stand-ins and per-frame damping, which its scene.json's waves alone do not reproduce:
    ``command`` would work from another sea than its frames show."""
    if isinstance(scene.extra, dict) and scene.extra.get("forecast_damped") is True:
        raise ValueError(f"{path}: its frames are a damped least-squares forecast (fitted waves, long-wave "
                         f"stand-ins, damping outside the fitted window) that its scene.json's waves do not "
                         f"reproduce; {command} the fit-waves result it came from ({scene.extra.get('forecast_from')}), "
                         f"or a forecast made with --undamped")


def scene_from_file(path):
    """The ``SceneSample`` of a scene file and the seed it was drawn with (None if unknown)."""
    from jaxocean.io.dataset import SceneSample
    from jaxocean.io.scene import read_scene

    refuse_other_json(path, "render needs a scene.json (waves, camera, lighting and times) or its directory")
    sc = read_scene(path)
    refuse_damped_forecast(sc, path, "render")
    missing = [n for n in ("waves", "camera", "lighting", "times") if getattr(sc, n) is None]
    if missing:
        raise ValueError(f"{path}: scene has no {', '.join(missing)}; render needs waves, camera, lighting and times")
    return SceneSample(sc.waves, sc.spectrum, sc.camera, sc.lighting, sc.times), sc.seed


def lighting_from_file(path, allow_failed: bool = False):
    """The lighting of a ``fit-lighting`` JSON (or of a scene.json's ``lighting``). A fit that
    reported failure (``success: false``: its lighting need not explain the frame, and an
    undetermined sun can be anywhere) is refused unless ``allow_failed``, then used with a
    warning."""
    from jaxocean.fit.lighting import lighting_from_dict
    from jaxocean.io.scene import SCENE_FILENAME

    if Path(path).is_dir():  # a scene directory, as every scene argument takes: its scene.json
        path = Path(path) / SCENE_FILENAME
    data = read_json(path, "lighting file")
    if "lighting" in data and not isinstance(data["lighting"], dict):
        raise ValueError(f"{path}: holds no lighting (lighting: {json.dumps(data['lighting'])}); give a "
                         f"`jaxocean fit-lighting` JSON or a scene.json with a lighting")
    if isinstance(data, dict) and data.get("success") is False:
        determined = data.get("determined") if isinstance(data.get("determined"), dict) else {}
        undetermined = [name.replace("_", " ") for name, ok in determined.items() if ok is False]
        detail = f"; undetermined: {', '.join(undetermined)}" if undetermined else ""
        if not allow_failed:
            raise ValueError(f"{path}: the lighting fit reported failure (success: false{detail}); its lighting need "
                             "not explain the frame. Pass --allow-failed-lighting to use it anyway")
        print(f"jaxocean: warning: using the lighting of a failed fit ({path}: success: false{detail})",
              file=sys.stderr)
    try:
        return lighting_from_dict(data)
    except (TypeError, ValueError) as error:
        raise ValueError(f"{path}: {error}") from None


def radians_or_none(degrees):
    return None if degrees is None else math.radians(degrees)


def camera_from_args(args, base, resolution, where: str):
    """``base`` with the --camera-* / --res options applied; without a base, a new camera from
    the options (height and pitch needed; fov 45 deg, yaw 0 by default) of ``--res`` or else
    ``resolution``."""
    from jaxocean import camera as cam
    from jaxocean.fit.reedit import edit_camera

    if base is not None:
        return edit_camera(base, height=args.camera_height, pitch=radians_or_none(args.camera_pitch_deg),
                           fov=radians_or_none(args.camera_fov_deg), yaw=radians_or_none(args.camera_yaw_deg),
                           resolution=getattr(args, "res", None))
    resolution = getattr(args, "res", None) or resolution
    missing = [flag for flag, value in (("--camera-height", args.camera_height),
                                        ("--camera-pitch-deg", args.camera_pitch_deg)) if value is None]
    if missing:
        raise ValueError(f"{where} has no camera: give {' and '.join(missing)} (--camera-fov-deg defaults to 45, "
                         f"--camera-yaw-deg to 0){' or --scene' if where.startswith('frame') else ''}")
    if resolution is None:
        raise ValueError(f"{where} has no camera: give --res too")
    return cam.make_camera(height=args.camera_height, pitch=math.radians(args.camera_pitch_deg),
                           fov=math.radians(45.0 if args.camera_fov_deg is None else args.camera_fov_deg),
                           yaw=radians_or_none(args.camera_yaw_deg or 0.0), resolution=resolution)


def lighting_from_args(args, base):
    """``--lighting`` (else ``base``, else the default lighting) with --sun-* applied."""
    from jaxocean import shading
    from jaxocean.fit.reedit import edit_lighting

    light = lighting_from_file(args.lighting, args.allow_failed_lighting) if args.lighting else base
    light = shading.make_lighting() if light is None else light
    return edit_lighting(light, sun_azimuth=radians_or_none(args.sun_azimuth),
                         sun_elevation=radians_or_none(args.sun_elevation))


def check_increasing(values, what: str) -> None:
    """ValueError unless ``values`` (frame indices or times) increase strictly, each once: they
    are a time sequence, and the scene a command writes from them must be one too (fit-waves
    and forecast refuse one whose times do not increase)."""
    if any(b <= a for a, b in zip(values, values[1:])):
        raise ValueError(f"{what} must increase strictly (a time sequence, each once); got "
                         f"{','.join(f'{v:g}' for v in values)}")


def check_frames(frames, n: int, where: str):
    """``frames`` (or all ``n``) as a list, every index < n, increasing strictly: the frames
    are a time sequence, and the scene a command writes from them must be one too."""
    if frames is None:
        return list(range(n))
    check_increasing(frames, "frame indices")
    bad = [f for f in frames if f >= n]
    if bad:
        raise ValueError(f"{where} has {n} frame(s) (indices 0..{n - 1}); no frame {bad[0]}")
    return list(frames)
