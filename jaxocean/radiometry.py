"""Radiometry: display values to linear radiance, and which pixels can be trusted.

The first stage of reconstructing real footage. A camera writes *display values*: the scene
radiance times an unknown exposure, passed through a response curve and quantised to 8 or
16 bits. This module undoes the curve and marks the pixels the curve clipped.

Protocol
--------
* :class:`Response` ``(kind, gamma)``: the response curve, ``kind`` one of
  :data:`RESPONSE_KINDS`:

  - ``"srgb"``: the sRGB transfer curve (photographs, most video);
  - ``"gamma"``: ``display = L^(1/gamma)``, so ``L = display^gamma`` (``gamma > 0``);
  - ``"linear"``: ``display = L`` (raw sensor values);
  - ``"bruneton"``: the tone curve of the library's renderer (:func:`jaxocean.shading.tonemap`).

* :func:`to_linear(display, response, exposure=1.0)` -> radiance, and :func:`to_display` its
  inverse. Both are elementwise, jittable and differentiable (``response`` is a Python
  constant, closed over). The exposure of real footage is unknown: with the default
  ``exposure=1`` the result is radiance *relative* to it, and the stages downstream fit the
  scale (a single positive factor per sequence) together with the lighting. The srgb /
  linear / bruneton curves are those of :mod:`jaxocean.shading`; a display value at the top
  of the range has no unique radiance and maps to the lower bound of what it could be
  (``1 / exposure`` for srgb, gamma and linear; ``6.93 / exposure`` for bruneton), so such
  pixels must be masked (:func:`saturation_mask`).
* :func:`saturation_mask(display, bits=8, high=None, low=None)` -> bool ``(..., H, W)``: True
  where a pixel is usable, i.e. not clipped at the top (any channel of an RGB pixel) and,
  when ``low`` is given, not crushed to black (no channel at or below ``low``; ``low="bottom"``
  is the bottom code of the file's bit depth, :func:`bottom_code`).
* :func:`luminance(rgb)`: ``(..., 3) -> (...)`` with the Rec. 709 weights of
  :data:`jaxocean.shading.LUMINANCE`, the weights by which the library models a gray
  image as the luminance of its RGB model.
* :func:`load_frames(paths_or_video, response=...)` -> :class:`Frames`: PNG / JPEG / 16-bit
  gray PNG / OpenEXR (``R G B``, or ``Y`` alone for gray) files (one frame each) or one video
  file, all of one size.

Shapes: ``display`` and ``linear`` are ``(T, H, W)`` for gray footage and ``(T, H, W, 3)``
for colour; ``usable`` is ``(T, H, W)``. Values are float32 NumPy arrays on the host.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple, Sequence

import jax.numpy as jnp
import numpy as np

from jaxocean.errors import check_values, is_concrete
from jaxocean.io.exr import FileFormatError, read_radiance, require_file
from jaxocean.io.images import VIDEO_SUFFIXES, is_video_file, load_display, load_display_video
from jaxocean.shading import LUMINANCE, inverse_tonemap, tonemap

__all__ = [
    "RESPONSE_KINDS",
    "Response",
    "Frames",
    "to_linear",
    "to_display",
    "saturation_mask",
    "bottom_code",
    "luminance",
    "load_frames",
]

RESPONSE_KINDS = ("srgb", "gamma", "linear", "bruneton")
"""The response curves :class:`Response` can name."""

_EXR_SUFFIX = ".exr"


class Response(NamedTuple):
    """A camera response curve: ``kind`` in :data:`RESPONSE_KINDS`; ``gamma`` (> 0) is used by
    ``kind="gamma"`` only (``linear = display ** gamma``; 2.2 is the usual display gamma)."""

    kind: str = "srgb"
    gamma: float = 2.2


class Frames(NamedTuple):
    """A loaded image sequence.

    * ``display``: display values in [0, 1], float32, ``(T, H, W)`` gray or ``(T, H, W, 3)``;
      None for OpenEXR input, which holds radiance and no display values.
    * ``linear``: radiance relative to the unknown exposure (:func:`to_linear` of ``display``;
      the file's own values for OpenEXR), the same shape.
    * ``usable``: bool ``(T, H, W)``: not clipped (:func:`saturation_mask`); for OpenEXR,
      finite and non-negative in every channel.
    * ``gray``: True when the frames have one channel (a gray file, or a video whose decoded
      R, G and B are equal everywhere, which is how decoders return gray footage).
    * ``bits``: 8 or 16 for integer files, None for float files (OpenEXR).
    * ``paths``: the files read, one per frame (one entry, the video, for a video).
    """

    display: np.ndarray | None
    linear: np.ndarray
    usable: np.ndarray
    gray: bool
    bits: int | None
    paths: tuple


def _check_response(response: Response) -> Response:
    if not isinstance(response, Response):
        raise TypeError(f"response must be a radiometry.Response; got {type(response).__name__}")
    if response.kind not in RESPONSE_KINDS:
        raise ValueError(f"unknown response kind {response.kind!r}; expected one of {RESPONSE_KINDS}")
    if response.kind == "gamma" and not (np.isfinite(response.gamma) and response.gamma > 0):
        raise ValueError(f"Response gamma must be finite and > 0; got {response.gamma}")
    return response


def _power(x, exponent):
    """``x ** exponent`` for ``x >= 0`` with a finite (zero) gradient at ``x = 0``."""
    positive = x > 0
    return jnp.where(positive, jnp.where(positive, x, 1.0) ** exponent, 0.0)


def to_linear(display, response: Response = Response(), exposure=1.0):
    """Display values in [0, 1] -> linear radiance ``L`` with ``display = curve(L * exposure)``.

    With the default ``exposure=1`` the radiance is relative to the camera's unknown exposure
    (see the module docstring). Values outside [0, 1] are clipped first. A concrete NaN/inf
    input raises :class:`jaxocean.errors.InvalidValueError`.
    """
    kind = _check_response(response).kind
    if kind != "gamma":
        return inverse_tonemap(display, exposure, mode=kind)
    display = jnp.asarray(display)
    if is_concrete(display):
        check_values(np.isfinite(display), "display image must be finite", display)
    if is_concrete(exposure):
        check_values(np.asarray(exposure) > 0, "exposure must be > 0", exposure)
    return _power(jnp.clip(display, 0.0, 1.0), response.gamma) / exposure


def to_display(linear, response: Response = Response(), exposure=1.0):
    """Linear radiance -> display values in [0, 1]: the inverse of :func:`to_linear`
    (``curve(max(L * exposure, 0))``, clipped at 1 for srgb, gamma and linear). A concrete
    NaN/inf input raises :class:`jaxocean.errors.InvalidValueError` (as :func:`to_linear`):
    the curves would map it to a display value."""
    kind = _check_response(response).kind
    if is_concrete(linear):
        check_values(np.isfinite(np.asarray(linear)), "linear image must be finite", linear)
    if kind != "gamma":
        return tonemap(linear, exposure, mode=kind)
    if is_concrete(exposure):
        check_values(np.asarray(exposure) > 0, "exposure must be > 0", exposure)
    exposed = jnp.clip(jnp.asarray(linear) * exposure, 0.0, 1.0)
    return _power(exposed, 1.0 / response.gamma)


def bottom_code(bits: int | None) -> float:
    """The display value at or below which a pixel of a ``bits``-bit file is black: half a
    quantisation step, ``0.5 / (2^bits - 1)`` (``0.5 / 255`` for 8 bits, ``0.5 / 65535`` for
    16: a threshold in display values must scale with the depth, or it would mask the 16-bit
    codes 1-128 as black); 0.0 for float data (``bits=None``)."""
    return 0.0 if bits is None else 0.5 / (2.0 ** int(bits) - 1.0)


def saturation_mask(display, *, bits: int | None = 8, high=None, low=None, channel_axis: bool | None = None):
    """Usable pixels of display values: bool, the shape of ``display`` without a colour axis.

    Args:
        display: display values in [0, 1], ``(..., H, W)`` gray or ``(..., H, W, 3)`` colour.
        bits: the quantisation of the source (8 or 16; None for float data). It sets the
            default ``high``.
        high: a pixel with any channel ``>= high`` is clipped. Default: the top code value,
            ``1 - 0.5 / (2^bits - 1)`` (1.0 for ``bits=None``).
        low: when given, a pixel with any channel ``<= low`` is crushed to black and masked
            too; ``"bottom"``: the bottom code of ``bits`` (:func:`bottom_code`: ``0.5 / 255``
            for 8 bits, ``0.5 / 65535`` for 16, 0 for ``bits=None``).
        channel_axis: whether the last axis is colour. Default: True when it has length 3
            and ``display.ndim >= 3``; pass it explicitly for a gray image 3 pixels wide.

    A pixel with a non-finite channel is not usable either.
    """
    display = np.asarray(display)
    if bits is not None and not (isinstance(bits, (int, np.integer)) and not isinstance(bits, bool) and bits >= 1):
        raise ValueError(f"bits must be an int >= 1 (8 or 16 for image files) or None; got {bits!r}")
    if high is None:
        high = 1.0 - bottom_code(bits)  # the top code; 1.0 for float data
    if isinstance(low, str):
        if low != "bottom":
            raise ValueError(f"low must be a display value, None or 'bottom'; got {low!r}")
        low = bottom_code(bits)
    if channel_axis is None:
        channel_axis = display.ndim >= 3 and display.shape[-1] == 3
    bad = (display >= high) | ~np.isfinite(display)  # a NaN pixel carries no value either
    if low is not None:
        bad = bad | (display <= low)
    if channel_axis:
        bad = np.any(bad, axis=-1)
    return ~bad


def luminance(rgb):
    """Luminance ``(...)`` of linear RGB ``(..., 3)`` with the weights the library models gray
    images by (:data:`jaxocean.shading.LUMINANCE`, Rec. 709)."""
    rgb = jnp.asarray(rgb)
    if rgb.shape[-1:] != (3,):
        raise ValueError(f"luminance expects (..., 3) RGB; got shape {rgb.shape}")
    return rgb @ jnp.asarray(LUMINANCE, rgb.dtype if jnp.issubdtype(rgb.dtype, jnp.floating) else jnp.float32)


def load_frames(paths_or_video, *, response: Response = Response(), high=None, low=None) -> Frames:
    """Load an image sequence as :class:`Frames`.

    Args:
        paths_or_video: a sequence of image files (PNG, JPEG, 16-bit gray PNG, OpenEXR with
            ``R G B`` or ``Y`` alone, one frame each, in time order), or one video file (a
            single path, or a sequence holding one path with a video suffix,
            :data:`jaxocean.io.images.VIDEO_SUFFIXES`, or ``.gif``).
        response: the display response curve (ignored for OpenEXR, which is radiance).
        high, low: clipping thresholds passed to :func:`saturation_mask` with the files'
            bit depth (``low="bottom"``: black at the bottom code of that depth).

    Raises:
        ValueError: no files; a video among other files; files of mixed kinds
            (display-referred and OpenEXR) or bit depths; frames of different sizes or
            channel counts (naming the first file that differs).
        MissingFileError / FileFormatError: a missing or undecodable file, naming it.
    """
    _check_response(response)
    if isinstance(paths_or_video, (str, Path)):
        paths = [Path(paths_or_video)]
    else:
        paths = [Path(p) for p in paths_or_video]
    if not paths:
        raise ValueError("load_frames needs at least one file")
    suffixes = {p.suffix.lower() for p in paths}
    videos = [p for p in paths if p.suffix.lower() in VIDEO_SUFFIXES]
    if videos and len(paths) > 1:
        raise ValueError(f"load_frames reads one video file or a list of image files; got the video "
                         f"{str(videos[0])!r} among {len(paths)} files")
    if len(paths) == 1 and is_video_file(paths[0]):
        decoded = load_display_video(paths[0])
        display, gray = _gray_video(decoded.values)
        return _display_frames(display, gray, decoded.bits, response, high, low, tuple(paths))
    if _EXR_SUFFIX in suffixes:
        if suffixes != {_EXR_SUFFIX}:
            raise ValueError(f"load_frames got OpenEXR and display-referred files together ({sorted(suffixes)}); "
                             "one sequence must be one kind")
        images = [read_radiance(require_file(p, "frame file")) for p in paths]
        _check_same_shape(images, paths)
        linear = np.stack(images).astype(np.float32)
        gray = linear.ndim == 3  # grayscale files: one Y channel each
        finite = np.isfinite(linear) & (linear >= 0)
        usable = finite if gray else np.all(finite, axis=-1)
        return Frames(None, linear, usable, gray, None, tuple(paths))
    decoded = [load_display(p) for p in paths]
    _check_same_shape([d.values for d in decoded], paths)
    for path, d in zip(paths, decoded):
        if d.bits != decoded[0].bits:
            raise FileFormatError(path, f"{d.bits}-bit pixels, while {str(paths[0])!r} has {decoded[0].bits}-bit "
                                        "pixels: one sequence must have one bit depth")
    display = np.stack([d.values for d in decoded])
    return _display_frames(display, display.ndim == 3, decoded[0].bits, response, high, low, tuple(paths))


def _display_frames(display, gray, bits, response, high, low, paths) -> Frames:
    linear = np.asarray(to_linear(display, response), np.float32)
    usable = saturation_mask(display, bits=bits, high=high, low=low, channel_axis=not gray)
    return Frames(display.astype(np.float32), linear, usable, bool(gray), bits, paths)


def _gray_video(values: np.ndarray) -> tuple[np.ndarray, bool]:
    """A decoded video ``(T, H, W[, 3])`` -> (values, gray): colour with R = G = B everywhere
    becomes ``(T, H, W)``."""
    if values.ndim == 3:
        return values, True
    if np.array_equal(values[..., 0], values[..., 1]) and np.array_equal(values[..., 0], values[..., 2]):
        return values[..., 0], True
    return values, False


def _check_same_shape(images: Sequence[np.ndarray], paths: Sequence[Path]) -> None:
    shape = np.shape(images[0])
    for image, path in zip(images, paths):
        if np.shape(image) != shape:
            raise FileFormatError(path, f"frame of shape {np.shape(image)} differs from the first frame "
                                        f"{str(paths[0])!r}, {shape} (all frames must share one size and "
                                        f"channel count)")
