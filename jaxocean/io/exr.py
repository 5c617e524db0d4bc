"""OpenEXR frames: one file per frame, linear radiance plus per-pixel geometry.

Protocol
--------
Each frame is one single-part, scanline OpenEXR file of ``H x W`` pixels, row 0 at the top
(the camera's image convention). Its channels:

=====================================  =============================================  ==========
channel                                meaning                                         units
=====================================  =============================================  ==========
``R``, ``G``, ``B``                    linear radiance: no tone map, no gamma          scene-linear
``normal.X``, ``normal.Y``,            unit macro-surface normal, world frame (z up)   --
``normal.Z``
``roughness``                          sub-pixel slope variance sigma^2 =              dimensionless
                                       sigma_x^2 + sigma_y^2 (floored at
                                       ``shading.MIN_SLOPE_VARIANCE``)
``slope_variance.X``,                  the anisotropic pair (sigma_x^2, sigma_y^2)     dimensionless
``slope_variance.Y``                   the image was shaded with
``mask``                               1 where the pixel sees the sea, 0 for sky        0 / 1
``converged``                          1 where the pixel's geometry is exact (its       0 / 1
                                       ray-surface hit converged to a unique point,
                                       :attr:`jaxocean.render.Geometry.converged`),
                                       0 where it is not (a ray grazing a crest)
=====================================  =============================================  ==========

``R G B`` are always there; ``normal.X/Y/Z``, ``roughness`` and ``mask`` (the
:data:`GEOMETRY_CHANNELS`) are written together or not at all (a file with some of them is
reported as incomplete). ``slope_variance.X/Y`` (:data:`SLOPE_VARIANCE_CHANNELS`) are written
with the geometry whenever it has a ``slope_variance`` (a :class:`jaxocean.render.Geometry`
does: every frame jaxocean renders carries them). They are what the renderer shades with, so
``render.shade(f.normal, f.roughness, camera, lighting, slope_variance=f.slope_variance)``
of a read frame ``f`` reproduces its ``R G B`` to the precision they are stored in; the
scalar ``roughness`` alone shades isotropically (sigma^2 / 2 per axis) and does not. A file
with geometry but without them (written before they were stored, or by another tool) still
reads: ``Frame.slope_variance`` is None and :func:`read_frame` warns
(:class:`IncompleteFrameWarning`) unless ``warn_incomplete=False``. Channels outside this
list are ignored on reading, so files from other tools load as long as they carry ``R G B``.
A grayscale image -- one luminance channel ``Y`` (:data:`GRAY_CHANNEL`) and no ``R G B`` --
is no frame (it has no colour to fit), but :func:`read_radiance` reads it as ``(H, W)``
radiance, and with it :func:`jaxocean.io.images.load_image` and
:func:`jaxocean.radiometry.load_frames` (the ``reconstruct`` command).
``converged`` (:data:`CONVERGED_CHANNEL`) is written with the geometry whenever it has a
``converged`` flag that is not None; a file without it reads with ``Frame.converged`` None,
without a warning (unknown, not False).

Pixel types. ``R G B``, ``mask`` and ``converged`` are half (float16) by default, float32 with
``half=False``. The geometry values ``normal``, ``roughness`` and ``slope_variance`` are
always float32 and, with a lossless compression, read back bit-exact: the sun glitter is so sensitive to the normal that
half-float normals (2.4e-4 rounding) move glint pixels by up to ~3% -- a frame could not
reproduce its own image. Half floats keep 11 significant bits (relative error <= 2^-11 ~
4.9e-4) for magnitudes in [6.1e-5, 65504]; below 6.1e-5 they are subnormal with an absolute
step of 6e-8, and values above 65504 would become inf, so :func:`write_frame` refuses them
(write such frames with ``half=False``). Float32 frames read back bit-exact. ZIP compression
(lossless) is the default; any OpenEXR compression can be named (``"none"``, ``"piz"``,
``"zstd"``, ...; ``"pxr24"``, ``"b44"``, ``"dwaa"`` ... are lossy). ``"pxr24"`` keeps the
half channels exact and rounds float32 ones to 24 bits (relative 2^-16): datasets use it for
their half-float frames (:mod:`jaxocean.io.dataset`, "Storage"), at 0.54-0.63x the size of
ZIP (measured on 128^2 dataset frames).

Metadata. ``meta`` is a small flat dict (scene id, frame index, time, ...) stored as header
attributes named ``"jaxocean.<key>"``: a ``str`` as a string attribute, an ``int`` as a
32-bit int attribute, a ``float`` as a one-element double vector -- OpenEXR's scalar
``float`` attribute has 32 bits and would turn a frame time of 0.1 into 0.10000000149.
Every value round-trips exactly.

Atomicity and resuming. A frame is written to a hidden temporary file in the destination
directory (``.{name}.tmp-{pid}``), flushed to disk, then renamed over the final name
(:func:`jaxocean.files.atomic_write`). A file under a frame's final name is therefore always complete, even
if the process dies mid-write: a generator that is restarted can skip every frame whose file
exists. A killed process may leave its temporary file behind; it is never read and may be
deleted. Everything is validated (shapes, finite values, half range, metadata) before the
first byte is written.

Errors. Reading reports the file by name: :class:`MissingFileError` (also a
``FileNotFoundError``) for a missing file, :class:`FrameError` for a file that is not an
OpenEXR file (recognised by its first bytes: a PNG, JPEG, GIF, TIFF or JSON file is named as
such), a corrupt or truncated file, a missing ``R``/``G``/``B`` channel, an incomplete
geometry channel set, mismatched channel sizes or an unexpected resolution. All are
``ValueError`` subclasses via :class:`jaxocean.errors.InvalidValueError`. What the OpenEXR
library itself prints while decoding (it reports damaged files on stdout and stderr) is
captured and, for a damaged file, its first line goes into the error message instead (after
a read that succeeds, what was captured is printed after all: nothing another thread printed
meanwhile is lost); reads are serialised by a lock while they redirect file descriptors 1
and 2.
"""

from __future__ import annotations

import contextlib
import ctypes
import io
import os
import sys
import tempfile
import threading
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np
import OpenEXR

from jaxocean.errors import InvalidValueError, check_finite
from jaxocean.files import atomic_write

__all__ = [
    "RGB_CHANNELS",
    "GRAY_CHANNEL",
    "NORMAL_CHANNELS",
    "GEOMETRY_CHANNELS",
    "SLOPE_VARIANCE_CHANNELS",
    "CONVERGED_CHANNEL",
    "META_PREFIX",
    "COMPRESSIONS",
    "FileFormatError",
    "MissingFileError",
    "FrameError",
    "IncompleteFrameWarning",
    "Frame",
    "atomic_write",
    "write_frame",
    "read_frame",
    "read_radiance",
]

RGB_CHANNELS = ("R", "G", "B")
GRAY_CHANNEL = "Y"
"""The one channel of a grayscale OpenEXR image: OpenEXR's luminance channel."""
_CHROMA_CHANNELS = ("RY", "BY")  # OpenEXR's luminance-chroma images: Y alone is not their radiance
NORMAL_CHANNELS = ("normal.X", "normal.Y", "normal.Z")
GEOMETRY_CHANNELS = NORMAL_CHANNELS + ("roughness", "mask")
"""The geometry channels written together or not at all."""
SLOPE_VARIANCE_CHANNELS = ("slope_variance.X", "slope_variance.Y")
"""The anisotropic slope variance (sigma_x^2, sigma_y^2): written with the geometry when it
has one, optional on reading (older files lack it)."""
CONVERGED_CHANNEL = "converged"
"""Per-pixel 0 / 1: the hit converged (written with the geometry when it has the flag)."""
_FLOAT32_CHANNELS = frozenset(NORMAL_CHANNELS + ("roughness",) + SLOPE_VARIANCE_CHANNELS)
"""Stored as float32 whatever ``half`` says (module docstring, "Pixel types")."""
META_PREFIX = "jaxocean."
"""Header attributes of the ``meta`` dict are named ``META_PREFIX + key``."""

# "zip" -> OpenEXR.ZIP_COMPRESSION, ... ("none" for NO_COMPRESSION): every compression this
# OpenEXR build knows.
_COMPRESSION_BY_NAME = {
    ("none" if name == "NO_COMPRESSION" else name.removesuffix("_COMPRESSION").lower()): value
    for name, value in OpenEXR.Compression.__members__.items()
    if name.endswith("_COMPRESSION")
}
COMPRESSIONS = tuple(_COMPRESSION_BY_NAME)
"""Names accepted by ``write_frame(compression=...)``."""

_HALF_MAX = float(np.finfo(np.float16).max)  # 65504
_INT32_RANGE = (-(2**31), 2**31 - 1)


# --------------------------------------------------------------------------- errors


class FileFormatError(InvalidValueError):
    """A file that cannot be used as what it should be; the message names the file.

    ``path`` is the offending file, ``problem`` what is wrong with it.
    """

    def __init__(self, path, problem: str):
        self.path = os.fspath(path)
        self.problem = problem
        super().__init__(f"{self.path}: {problem}")

    def __reduce__(self):
        # Rebuild from (path, problem), not from the formatted message, so that the error
        # survives pickling (multiprocessing data loaders send it between processes).
        return type(self), (self.path, self.problem)


class MissingFileError(FileFormatError, FileNotFoundError):
    """The file does not exist (catchable as ``FileNotFoundError`` too)."""


class FrameError(FileFormatError):
    """An OpenEXR frame file that is corrupt, truncated or misses protocol channels, or a
    file that is not OpenEXR at all."""


class IncompleteFrameWarning(UserWarning):
    """A frame with geometry but without ``slope_variance.X/Y``: shading its geometry uses
    the isotropic roughness and need not reproduce its image."""


def require_file(path, what: str) -> Path:
    """``Path(path)``, or :class:`MissingFileError` if it is not an existing file."""
    path = Path(path)
    if path.is_dir():
        article = "an" if what[:1].lower() in "aeiou" else "a"  # "an EXR frame file", "a video file"
        raise MissingFileError(path, f"a directory, not {article} {what} (give the files in it, e.g. {path / '*'})")
    if not path.is_file():
        raise MissingFileError(path, f"no such {what}")
    return path


# --------------------------------------------------------------------------- writing


class Frame(NamedTuple):
    """One frame read by :func:`read_frame`: NumPy arrays on the host.

    * ``image``     ``(H, W, 3)`` float32 linear radiance (R, G, B).
    * ``normal``    ``(H, W, 3)`` float32 unit normals, or None if the file has no geometry.
    * ``roughness`` ``(H, W)`` float32 slope variance sigma^2, or None.
    * ``mask``      ``(H, W)`` bool, True where the pixel sees the sea, or None.
    * ``meta``      dict of the ``jaxocean.*`` header attributes, prefix removed.
    * ``slope_variance`` ``(H, W, 2)`` float32 (sigma_x^2, sigma_y^2) the image was shaded
      with, or None when the file has no such channels (no geometry, or an older file).
    * ``converged`` ``(H, W)`` bool, False on pixels whose ray-surface hit did not converge
      to a unique point (:attr:`jaxocean.render.Geometry.converged`; the pixels a fit or a
      loss can trust are ``mask & converged``), or None when the file has no such channel.

    A frame is a geometry-like: ``render.shade(f.normal, f.roughness, camera, lighting,
    slope_variance=f.slope_variance)`` and ``fit.lighting(f.image, f, camera)`` use the
    anisotropic slope variance when the file has it.
    """

    image: np.ndarray
    normal: np.ndarray | None
    roughness: np.ndarray | None
    mask: np.ndarray | None
    meta: dict
    slope_variance: np.ndarray | None = None
    converged: np.ndarray | None = None


def write_frame(path, image, geometry=None, meta=None, *, half: bool = True, compression: str = "zip") -> Path:
    """Write one frame as an OpenEXR file, atomically (see the module docstring).

    Args:
        path: destination file (conventionally ``frame_00000.exr``); parent directories
            are created.
        image: ``(H, W, 3)`` linear radiance, NumPy or JAX, any real dtype.
        geometry: optional per-pixel geometry: a :class:`jaxocean.render.Geometry`, or any
            object or dict with ``normal (H, W, 3)``, ``roughness (H, W)`` and ``mask
            (H, W)`` (bool, or numbers 0 / 1), and optionally ``slope_variance (H, W, 2)``
            (>= 0; stored as ``slope_variance.X/Y`` when present and not None) and
            ``converged (H, W)`` (bool or 0 / 1; stored as ``converged`` when present and
            not None).
        meta: optional flat dict ``{str: str | int | float}`` stored as header attributes
            ``jaxocean.<key>`` (keys of at most 246 bytes); ints must fit 32 bits, floats must be finite.
        half: store ``R G B``, ``mask`` and ``converged`` as half floats (default) or, with False, as
            float32 (bit-exact round trip). Geometry values are float32 either way.
        compression: one of :data:`COMPRESSIONS`; ``"zip"`` (lossless) by default.

    Returns:
        the written path.

    Raises:
        ValueError: wrong shapes, dtypes, compression name or metadata types.
        InvalidValueError: NaN/inf values (naming the channel), |R G B| > 65504 with
            ``half=True``, values beyond the float32 range, a mask or converged flag that is
            not 0/1, a negative roughness or slope variance. Nothing is written in either case.
    """
    header, channels = checked_frame(image, geometry, meta, half=half, compression=compression)

    def write(temporary: Path) -> None:
        # OpenEXR.File replaces the values of the dicts it is given: hand it copies.
        OpenEXR.File(dict(header), dict(channels)).write(os.fspath(temporary))

    return atomic_write(path, write)


def checked_frame(image, geometry=None, meta=None, *, half: bool = True, compression: str = "zip"):
    """``(header, channels)`` that :func:`write_frame` would write, after every check it
    makes (its Raises); nothing is written. A writer of many frames checks them all first."""
    if compression not in _COMPRESSION_BY_NAME:
        raise ValueError(f"unknown EXR compression {compression!r}; expected one of {COMPRESSIONS}")
    planes = _frame_planes(image, geometry)
    types = {name: np.float32 if name in _FLOAT32_CHANNELS or not half else np.float16 for name in planes}
    for name, plane in planes.items():
        if types[name] == np.float16:
            _check_half_range(plane, name)
    with np.errstate(over="ignore"):
        channels = {name: np.ascontiguousarray(plane, dtype=types[name]) for name, plane in planes.items()}
    for name, channel in channels.items():  # finite float64 values beyond float32 would store inf
        if not np.all(np.isfinite(channel)):
            raise InvalidValueError(f"EXR channel {name!r}: values beyond the float32 range (|x| > 3.4e38); "
                                    f"largest {float(np.max(np.abs(planes[name]))):g}")
    header = {
        "compression": _COMPRESSION_BY_NAME[compression],
        "type": OpenEXR.scanlineimage,
        **_meta_to_header(meta),
    }
    return header, channels


def _frame_planes(image, geometry) -> dict[str, np.ndarray]:
    """Validate the frame and split it into named, finite ``(H, W)`` planes (views of the inputs).

    Each plane is cut from its source array and copied later by ``np.ascontiguousarray``:
    the OpenEXR binding writes a strided view such as ``rgb[..., 0]`` silently wrong.
    """
    image = _real_array(image, "image")
    if image.ndim != 3 or image.shape[-1] != 3 or 0 in image.shape:
        raise ValueError(f"image must be (H, W, 3) linear RGB; got shape {image.shape}")
    resolution = image.shape[:2]
    planes = {name: image[..., c] for c, name in enumerate(RGB_CHANNELS)}
    if geometry is not None:
        normal = _real_array(_geometry_field(geometry, "normal"), "normal")
        roughness = _real_array(_geometry_field(geometry, "roughness"), "roughness")
        mask = _mask_plane(_geometry_field(geometry, "mask"))
        slope_var = _geometry_field(geometry, "slope_variance", required=False)
        converged = _geometry_field(geometry, "converged", required=False)
        fields = [("normal", normal, resolution + (3,)), ("roughness", roughness, resolution),
                  ("mask", mask, resolution)]
        if slope_var is not None:
            slope_var = _real_array(slope_var, "slope_variance")
            fields.append(("slope_variance", slope_var, resolution + (2,)))
        if converged is not None:
            converged = _mask_plane(converged, "converged")
            fields.append(("converged", converged, resolution))
        for name, array, shape in fields:
            if array.shape != shape:
                raise ValueError(f"geometry.{name} must have shape {shape} to match the image; got {array.shape}")
        planes.update({name: normal[..., c] for c, name in enumerate(NORMAL_CHANNELS)})
        planes.update(roughness=roughness, mask=mask)
        if slope_var is not None:
            planes.update({name: slope_var[..., c] for c, name in enumerate(SLOPE_VARIANCE_CHANNELS)})
        if converged is not None:
            planes[CONVERGED_CHANNEL] = converged
    for name, plane in planes.items():
        check_finite(plane, f"EXR channel {name!r}")
    if "roughness" in planes and not np.all(planes["roughness"] >= 0):
        raise InvalidValueError(f"EXR channel 'roughness': a roughness must be >= 0; "
                                f"got {float(np.min(planes['roughness'])):g}")
    for name in SLOPE_VARIANCE_CHANNELS:
        if name in planes and not np.all(planes[name] >= 0):
            raise InvalidValueError(f"EXR channel {name!r}: a slope variance must be >= 0; "
                                    f"got {float(np.min(planes[name])):g}")
    return planes


def _real_array(x, name: str, kinds: str = "iuf") -> np.ndarray:
    array = np.asarray(x)
    if array.dtype.kind not in kinds:
        raise ValueError(f"{name} must be real numbers; got dtype {array.dtype}")
    return array


def _geometry_field(geometry, name: str, *, required: bool = True):
    try:
        return geometry[name] if isinstance(geometry, dict) else getattr(geometry, name)
    except (KeyError, AttributeError):
        if not required:
            return None
        raise ValueError(
            f"geometry needs fields 'normal', 'roughness' and 'mask'; {type(geometry).__name__} has no {name!r}"
        ) from None


def _mask_plane(mask, name: str = "mask") -> np.ndarray:
    mask = _real_array(mask, name, kinds="biuf")
    if mask.dtype != bool:
        # A soft or garbled mask is a bug upstream: refuse it rather than threshold it here.
        check_finite(mask, f"EXR channel {name!r}")
        if not np.all((mask == 0) | (mask == 1)):
            raise InvalidValueError(f"geometry.{name} must be bool or 0/1")
    return mask.astype(np.float32)


def _check_half_range(plane: np.ndarray, name: str) -> None:
    largest = float(np.max(np.abs(plane), initial=0.0))
    if largest > _HALF_MAX:
        raise InvalidValueError(
            f"EXR channel {name!r} holds {largest:g}, beyond the half-float range "
            f"(|x| <= {_HALF_MAX:g}); write this frame with half=False"
        )


_MAX_ATTRIBUTE_NAME = 255  # bytes, OpenEXR's long-name limit


def _meta_to_header(meta) -> dict:
    """``{key: value}`` -> ``{"jaxocean.key": attribute}`` (see the module docstring)."""
    header = {}
    for key, value in (meta or {}).items():
        if not isinstance(key, str) or not key:
            raise ValueError(f"meta keys must be non-empty strings; got {key!r}")
        if len((META_PREFIX + key).encode()) > _MAX_ATTRIBUTE_NAME:
            # the binding would cut the name, and two long keys could become one
            raise ValueError(f"meta key {key[:20]!r}... is too long: EXR attribute names hold "
                             f"{_MAX_ATTRIBUTE_NAME - len(META_PREFIX)} bytes after {META_PREFIX!r}")
        if isinstance(value, np.generic):
            value = value.item()
        if isinstance(value, bool) or not isinstance(value, (str, int, float)):
            raise ValueError(f"meta[{key!r}] must be a str, int or float; got {type(value).__name__}")
        if isinstance(value, int) and not _INT32_RANGE[0] <= value <= _INT32_RANGE[1]:
            # The binding would store an out-of-range int as 0 without a word.
            raise ValueError(f"meta[{key!r}] = {value} does not fit the 32-bit EXR int attribute; store it as a str")
        if isinstance(value, float):
            if not np.isfinite(value):
                raise InvalidValueError(f"meta[{key!r}] must be finite; got {value}")
            value = np.array([value], dtype=np.float64)  # a double vector: exact, unlike "float"
        header[META_PREFIX + key] = value
    return header


def _meta_from_header(header: dict) -> dict:
    meta = {}
    for name, value in header.items():
        if not name.startswith(META_PREFIX):
            continue
        if isinstance(value, np.ndarray) and value.shape == (1,) and value.dtype.kind == "f":
            value = float(value[0])
        meta[name.removeprefix(META_PREFIX)] = value
    return meta


# --------------------------------------------------------------------------- reading

_EXR_MAGIC = b"\x76\x2f\x31\x01"
# First bytes of files that are easily passed where a frame is expected.
_OTHER_FORMATS = (
    (b"\x89PNG\r\n\x1a\n", "a PNG image"),
    (b"\xff\xd8\xff", "a JPEG image"),
    (b"GIF87a", "a GIF image"),
    (b"GIF89a", "a GIF image"),
    (b"II*\x00", "a TIFF image"),
    (b"MM\x00*", "a TIFF image"),
    (b"{", "a JSON file"),
)
_EXPECTED = "expected an OpenEXR frame (.exr: linear R G B, with normal / roughness / mask channels for the fits)"
_DECODE_LOCK = threading.Lock()


def _check_magic(path: Path) -> None:
    """:class:`FrameError` naming what the file is when it is not OpenEXR (by its first bytes)."""
    with open(path, "rb") as file:
        head = file.read(8)
    if head.startswith(_EXR_MAGIC):
        return
    if not head:
        raise FrameError(path, f"empty file (0 bytes); {_EXPECTED}")
    what = next((name for magic, name in _OTHER_FORMATS if head.startswith(magic)), None)
    if what is None and len(head) < len(_EXR_MAGIC) and _EXR_MAGIC.startswith(head):
        raise FrameError(path, f"truncated OpenEXR file ({len(head)} bytes)")
    what = what or f"not an OpenEXR file (it starts with bytes {head[:4].hex(' ')}, not {_EXR_MAGIC.hex(' ')})"
    if what.startswith("a "):
        what = f"{what}, not an OpenEXR file"
    raise FrameError(path, f"{what}; {_EXPECTED}")


class _Captured:
    """What was printed during :func:`_captured_output`, per stream."""

    stdout = ""
    stderr = ""

    @property
    def text(self) -> str:
        return self.stdout + self.stderr

    def replay(self) -> None:
        """Print it after all (a read that succeeded: nothing of another thread is lost)."""
        for text, stream in ((self.stdout, sys.stdout), (self.stderr, sys.stderr)):
            if text:
                with contextlib.suppress(Exception):
                    stream.write(text)
                    stream.flush()


@contextlib.contextmanager
def _captured_output():
    """Capture what native code and Python print on stdout / stderr during the block.

    The OpenEXR binding reports damaged files itself: from C++ on file descriptor 2 and
    through Python's ``sys.stdout``. Both descriptors and both Python streams are redirected
    into temporary files; the text is in the yielded :class:`_Captured` afterwards. A lock
    serialises the redirection (descriptors are process-wide). Where descriptors 1 / 2
    cannot be duplicated (closed), only the Python streams are redirected.
    """
    captured = _Captured()
    with _DECODE_LOCK, tempfile.TemporaryFile() as sink_out, tempfile.TemporaryFile() as sink_err:
        for stream in (sys.stdout, sys.stderr):
            with contextlib.suppress(Exception):
                stream.flush()
        try:
            saved = [os.dup(1), os.dup(2)]
        except OSError:
            saved = None
        python_out, python_err = io.StringIO(), io.StringIO()
        try:
            if saved is not None:
                os.dup2(sink_out.fileno(), 1)
                os.dup2(sink_err.fileno(), 2)
            with contextlib.redirect_stdout(python_out), contextlib.redirect_stderr(python_err):
                yield captured
        finally:
            if saved is not None:
                _flush_c_streams()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
                for fd in saved:
                    os.close(fd)
            texts = []
            for python_text, sink in ((python_out, sink_out), (python_err, sink_err)):
                sink.seek(0)
                texts.append(python_text.getvalue() + sink.read().decode("utf-8", errors="replace"))
            captured.stdout, captured.stderr = texts


def _flush_c_streams() -> None:
    """``fflush(NULL)``: C stdio buffers (which C++ ``std::cout`` writes through) reach the
    redirected descriptor before it is restored. Best effort."""
    with contextlib.suppress(Exception):
        ctypes.CDLL(None).fflush(None)


def _decode_problem(path: Path, error: Exception, printed: str) -> str:
    """The most telling line of what OpenEXR said (printed text first), without the path."""
    lines = [line.strip() for line in printed.splitlines() if line.strip()]
    lines = [line.removeprefix(f"{path}:").removeprefix(f"{os.fspath(path)}:").strip() for line in lines]
    telling = [line for line in lines if "EXR_ERR" in line] or lines
    return telling[0] if telling else str(error)


def _read_pixels(path, what: str) -> tuple[dict, dict]:
    """``(header, {channel: pixels})`` of an OpenEXR file whose pixels cover its image (the
    decoding part of :func:`read_frame`'s Raises; ``what`` names the file kind when it is
    missing)."""
    path = require_file(path, what)
    _check_magic(path)
    error = None
    with _captured_output() as printed:
        try:
            exr = OpenEXR.File(os.fspath(path), separate_channels=True)
            header = exr.header()
            # The binding reads pixel data lazily: truncation surfaces here, not at opening.
            pixels = {name: channel.pixels for name, channel in exr.channels().items()}
        except (RuntimeError, ValueError, OSError) as caught:
            error = caught
    if error is None:
        printed.replay()
    else:
        raise FrameError(path, f"corrupt or truncated OpenEXR file ({_decode_problem(path, error, printed.text)})"
                         ) from error

    data_window = tuple(tuple(int(v) for v in corner) for corner in header["dataWindow"])
    display_window = tuple(tuple(int(v) for v in corner) for corner in header["displayWindow"])
    if data_window != display_window:
        # the pixels cover another rectangle than the image's: taken as they are, they would
        # be a crop (or padding) that the camera's view does not know about
        raise FrameError(path, f"pixels cover the data window {data_window} but the image is the display window "
                               f"{display_window} ((x, y) min, max corners): crop or pad it to one window")
    return header, pixels


def _is_gray(pixels: dict) -> bool:
    """A grayscale image: a ``Y`` channel and none of ``R G B``."""
    return GRAY_CHANNEL in pixels and not any(name in pixels for name in RGB_CHANNELS)


def _check_same_size(path, pixels: dict, names) -> tuple:
    """The common shape of the channels ``names``, or :class:`FrameError`."""
    shapes = {name: np.shape(pixels[name]) for name in names}
    if len(set(shapes.values())) != 1:
        raise FrameError(path, f"channels of different sizes (subsampled?): {shapes}")
    return shapes[names[0]]


def _stack(pixels: dict, names) -> np.ndarray:
    return np.stack([np.asarray(pixels[name], dtype=np.float32) for name in names], axis=-1)


def read_radiance(path) -> np.ndarray:
    """The linear radiance of an OpenEXR image, float32, without its geometry: ``(H, W, 3)``
    from ``R G B``, or ``(H, W)`` from a grayscale image's one ``Y`` channel
    (:data:`GRAY_CHANNEL`; a file with ``R G B`` is read as colour whatever else it holds).

    Raises:
        MissingFileError: no such file.
        FrameError: not OpenEXR, corrupt or truncated, neither ``R G B`` nor ``Y`` (nor a
            luminance-chroma ``Y RY BY`` image: its colour is not in ``Y``), channels of
            different sizes. The message names the file.
    """
    _, pixels = _read_pixels(path, "EXR image file")
    if _is_gray(pixels):
        chroma = [name for name in _CHROMA_CHANNELS if name in pixels]
        if chroma:
            raise FrameError(path, f"a luminance-chroma image ({GRAY_CHANNEL!r} with {chroma}): save it as "
                                   f"{list(RGB_CHANNELS)} (colour) or {GRAY_CHANNEL!r} alone (gray)")
        return np.asarray(pixels[GRAY_CHANNEL], dtype=np.float32)
    missing = [name for name in RGB_CHANNELS if name not in pixels]
    if missing:
        raise FrameError(path, f"missing channel(s) {missing}; an image needs {list(RGB_CHANNELS)} (colour) or "
                               f"{GRAY_CHANNEL!r} alone (gray)")
    _check_same_size(path, pixels, RGB_CHANNELS)
    return _stack(pixels, RGB_CHANNELS)


def read_frame(path, *, expect_resolution=None, warn_incomplete: bool = True) -> Frame:
    """Read a frame written by :func:`write_frame` (or any OpenEXR file with ``R G B``).

    Args:
        path: the ``.exr`` file.
        expect_resolution: optional ``(H, W)``; a frame of another size is an error.
        warn_incomplete: warn (:class:`IncompleteFrameWarning`) when the file has geometry
            but no ``slope_variance.X/Y`` channels; ``Frame.slope_variance`` is None either
            way, so a caller that reports it itself passes False.

    Returns:
        a :class:`Frame` of float32 NumPy arrays (the mask as bool: channel value > 0.5),
        geometry fields None when the file has no geometry channels, ``slope_variance``
        None when it has no slope-variance channels, ``converged`` None when it has no
        ``converged`` channel (bool otherwise: channel value > 0.5).

    Raises:
        MissingFileError: no such file.
        FrameError: the file is not OpenEXR (a PNG, JPEG, ... is named as such), is corrupt
            or truncated, lacks a channel of ``R G B`` (a grayscale ``Y`` image is named as
            such: :func:`read_radiance` reads it), has only part of the geometry (or
            slope-variance) channels, has channels of different sizes, or is not
            ``expect_resolution``. The message names the file (and the channels); what
            the OpenEXR library prints about a damaged file does not reach stdout / stderr.
    """
    header, pixels = _read_pixels(path, "EXR frame file")
    if _is_gray(pixels):
        raise FrameError(path, f"a grayscale image (one {GRAY_CHANNEL!r} channel), not a frame: a frame needs "
                               f"{list(RGB_CHANNELS)} (load_image and reconstruct read a grayscale image)")
    missing_rgb = [name for name in RGB_CHANNELS if name not in pixels]
    if missing_rgb:
        raise FrameError(path, f"missing channel(s) {missing_rgb}; a frame needs {list(RGB_CHANNELS)}")
    present_geometry = [name for name in GEOMETRY_CHANNELS if name in pixels]
    if present_geometry and len(present_geometry) != len(GEOMETRY_CHANNELS):
        missing = [name for name in GEOMETRY_CHANNELS if name not in pixels]
        raise FrameError(path, f"incomplete geometry: has {present_geometry} but is missing channel(s) {missing}")
    present_slope = [name for name in SLOPE_VARIANCE_CHANNELS if name in pixels]
    if present_slope and (len(present_slope) != len(SLOPE_VARIANCE_CHANNELS) or not present_geometry):
        missing = [name for name in SLOPE_VARIANCE_CHANNELS + GEOMETRY_CHANNELS if name not in pixels]
        raise FrameError(path, f"incomplete geometry: has {present_slope} but is missing channel(s) {missing}")

    has_converged = CONVERGED_CHANNEL in pixels
    if has_converged and not present_geometry:
        raise FrameError(path, f"incomplete geometry: has {CONVERGED_CHANNEL!r} but is missing channel(s) "
                               f"{list(GEOMETRY_CHANNELS)}")
    used = (RGB_CHANNELS + (GEOMETRY_CHANNELS if present_geometry else ()) + tuple(present_slope)
            + ((CONVERGED_CHANNEL,) if has_converged else ()))
    resolution = _check_same_size(path, pixels, used)
    if expect_resolution is not None and tuple(resolution) != tuple(expect_resolution):
        raise FrameError(path, f"resolution {tuple(resolution)} (H, W), expected {tuple(expect_resolution)}")

    if not present_geometry:
        return Frame(_stack(pixels, RGB_CHANNELS), None, None, None, _meta_from_header(header))
    if not present_slope and warn_incomplete:
        warnings.warn(f"{path}: no {'/'.join(SLOPE_VARIANCE_CHANNELS)} channels (an older or foreign file): "
                      f"Frame.slope_variance is None, and shading its geometry uses roughness / 2 per axis, "
                      f"which does not reproduce an image rendered with anisotropic slope variance",
                      IncompleteFrameWarning, stacklevel=2)
    return Frame(
        image=_stack(pixels, RGB_CHANNELS),
        normal=_stack(pixels, NORMAL_CHANNELS),
        roughness=np.asarray(pixels["roughness"], dtype=np.float32),
        mask=np.asarray(pixels["mask"]) > 0.5,
        meta=_meta_from_header(header),
        slope_variance=_stack(pixels, SLOPE_VARIANCE_CHANNELS) if present_slope else None,
        converged=np.asarray(pixels[CONVERGED_CHANNEL]) > 0.5 if has_converged else None,
    )
