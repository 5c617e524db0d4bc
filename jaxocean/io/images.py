"""Images and videos as linear radiance, and PNG previews.

Observed ocean images come in two kinds:

* **Display-referred** (PNG, JPEG, GIF, video): pixel values are what a screen shows, i.e.
  linear radiance after exposure and a tone curve. :func:`load_image` and :func:`load_video`
  bring them back to linear radiance in two steps:

  1. integers to display values in [0, 1]: ``uint8 / 255``, ``uint16 / 65535`` (floats are
     taken as display values already, and a float file outside [0, 1] is refused; signed
     integers are refused); a gray image is repeated over R, G, B and an alpha channel is
     dropped; CMYK and other colour models Pillow decodes are converted to RGB; an EXIF
     orientation (a phone's portrait photo stored sideways) is applied, so the pixels are the
     image as displayed (files Pillow reads: JPEG, PNG, WebP, ... and TIFF unless tifffile is
     installed);
  2. ``radiance = jaxocean.shading.inverse_tonemap(display, exposure, mode=space)``:
     ``space="srgb"`` (photographs and most video: the sRGB transfer curve),
     ``"bruneton"`` (images made by :func:`save_png` or the paper's renderer) or
     ``"linear"`` (display value = radiance x exposure). ``exposure`` is the one the image
     was tone-mapped with. Saturated pixels (display 1) have no unique radiance and come
     back at the lower bound of what they could be (see ``inverse_tonemap``).

* **Scene-referred** (OpenEXR): the ``R G B`` channels already are linear radiance and are
  returned as they are (a grayscale file's one ``Y`` channel is repeated over R, G, B);
  ``space`` and ``exposure`` do not apply.

Everything is returned as float32 NumPy arrays on the host, ``(H, W, 3)`` per image and
``(T, H, W, 3)`` per video. Video needs an imageio plugin for its container (PyAV or
imageio-ffmpeg for MP4, MOV, AVI, ...); GIF is read by Pillow, which imageio always has.

Step 1 alone is :func:`load_display` (one image) and :func:`load_display_video` (every frame
of a video): display values in [0, 1] that keep the channel count -- a gray file stays
``(H, W)``, colour is ``(H, W, 3)``, alpha dropped -- together with the file's bit depth
(:class:`Display`), for callers that choose their own response curve and mask clipped
pixels (:mod:`jaxocean.radiometry`).
"""

from __future__ import annotations

import importlib.util
from pathlib import Path
from typing import NamedTuple

import imageio.v3 as iio
import numpy as np

from jaxocean.errors import MissingDependencyError, check_finite
from jaxocean.files import atomic_write
from jaxocean.io.exr import FileFormatError, read_radiance, require_file
from jaxocean.shading import TONEMAP_MODES, inverse_tonemap, tonemap

__all__ = ["VIDEO_SUFFIXES", "Display", "is_video_file", "load_display", "load_display_video", "load_image",
           "load_video", "save_png"]

VIDEO_SUFFIXES = (".mp4", ".m4v", ".mov", ".avi", ".mkv", ".webm", ".mpg", ".mpeg", ".wmv", ".flv")
"""Containers that imageio reads only through a video plugin (PyAV or imageio-ffmpeg)."""

_EXR_SUFFIX = ".exr"


def is_video_file(path) -> bool:
    """Whether a frames argument naming this one file means every frame in it: a video
    container (:data:`VIDEO_SUFFIXES`) or a GIF (an animation; one GIF of one frame too)."""
    return Path(path).suffix.lower() in VIDEO_SUFFIXES + (".gif",)

# Formats Pillow decodes: naming the plugin makes a broken file fail there, with Pillow's
# message, instead of imageio probing every other backend (some warn while they fail).
_PILLOW_SUFFIXES = (".png", ".jpg", ".jpeg", ".gif", ".bmp", ".webp")


class Display(NamedTuple):
    """Display values of a decoded file.

    ``values``: float32 in [0, 1] (integers divided by their type's maximum; floats as they
    are), ``(H, W)`` gray or ``(H, W, 3)`` colour, with a leading ``T`` axis for a video.
    ``bits``: 8 or 16 for integer pixels (the quantisation step is ``1 / (2^bits - 1)``),
    None for float pixels.
    """

    values: np.ndarray
    bits: int | None


def load_display(path) -> Display:
    """Decode one display-referred image (PNG, JPEG, ...) to :class:`Display` values.

    Gray (and gray + alpha) files give ``(H, W)``, colour (and colour + alpha) files
    ``(H, W, 3)``. OpenEXR files are scene-referred and have no display values: use
    :func:`load_image` for them.

    Raises:
        MissingFileError: no such file.
        FileFormatError: a file imageio cannot decode, or an OpenEXR file, naming it.
    """
    path = require_file(path, "image file")
    if path.suffix.lower() == _EXR_SUFFIX:
        raise FileFormatError(path, "an OpenEXR file holds linear radiance, not display values (use load_image)")
    values, bits = _decode_image(path)
    return Display(values.astype(np.float32), bits)


def load_display_video(path) -> Display:
    """Decode every frame of a video (or animated GIF) to :class:`Display` values
    ``(T, H, W)`` or ``(T, H, W, 3)`` (the channel count the decoder gives: most video
    decoders give colour even for gray footage).

    Raises:
        MissingFileError: no such file.
        MissingDependencyError: (an ``ImportError``) a video container
            (:data:`VIDEO_SUFFIXES`) and no imageio video plugin installed; the message says
            what to install.
        FileFormatError: undecodable file, no frames, or frames of different sizes.
    """
    values, bits = _decode_video(require_file(path, "video file"))
    return Display(values.astype(np.float32), bits)


def load_image(path, *, space: str = "srgb", exposure=1.0) -> np.ndarray:
    """Load one image as linear radiance ``(H, W, 3)`` float32 (see the module docstring).

    Args:
        path: a PNG, JPEG, ... file (display-referred) or an OpenEXR file (linear: ``R G B``,
            or ``Y`` alone for gray).
        space: the tone curve the display-referred image was made with, one of
            ``"srgb"`` (default), ``"bruneton"``, ``"linear"``.
        exposure: the exposure it was made with, > 0.

    Raises:
        MissingFileError: no such file.
        FileFormatError: a file imageio (or OpenEXR) cannot decode, naming it.
        ValueError: unknown ``space``.
    """
    _check_space(space)
    path = require_file(path, "image file")
    if path.suffix.lower() == _EXR_SUFFIX:
        return _rgb(read_radiance(path), 2)  # the image alone: no geometry used
    return _to_linear(_rgb(_decode_image(path)[0], 2), space, exposure)


def load_video(path, *, space: str = "srgb", exposure=1.0) -> np.ndarray:
    """Load every frame of a video (or animated GIF) as linear radiance ``(T, H, W, 3)`` float32.

    Frames are decoded one by one (imageio's frame iterator) and converted as in
    :func:`load_image`.

    Raises:
        MissingFileError: no such file.
        MissingDependencyError: (an ``ImportError``) a video container
            (:data:`VIDEO_SUFFIXES`) and no imageio video plugin installed; the message says
            what to install.
        FileFormatError: undecodable file, no frames, or frames of different sizes.
        ValueError: unknown ``space``.
    """
    _check_space(space)
    return _to_linear(_rgb(_decode_video(require_file(path, "video file"))[0], 3), space, exposure)


def save_png(path, linear_image, exposure=1.0, mode: str = "bruneton") -> Path:
    """Tone-map linear radiance ``(H, W, 3)`` and save it as an 8-bit PNG, atomically.

    ``display = jaxocean.shading.tonemap(linear_image, exposure, mode)``, rounded to the
    nearest of 256 levels. :func:`load_image` with ``space=mode`` and the same exposure
    inverts it up to that quantisation (half a level, 1/510, in the display domain).

    Returns:
        the written path.
    """
    _check_space(mode)
    if Path(path).suffix.lower() != ".png":
        raise ValueError(f"save_png writes PNG files; name the file .png (got {str(path)!r})")
    image = np.asarray(linear_image)
    if image.ndim != 3 or image.shape[-1] != 3 or 0 in image.shape or image.dtype.kind not in "iuf":
        raise ValueError(f"save_png expects a real (H, W, 3) linear RGB image; got {image.dtype} {image.shape}")
    check_finite(image, "linear_image")
    display = np.asarray(tonemap(image, exposure, mode), dtype=np.float64)
    levels = np.round(np.clip(display, 0.0, 1.0) * 255).astype(np.uint8)
    # The temporary name does not end in .png, so the format is named explicitly.
    return atomic_write(path, lambda temporary: iio.imwrite(temporary, levels, extension=".png"))


def _check_space(space: str) -> None:
    if space not in TONEMAP_MODES:
        raise ValueError(f"unknown display space {space!r}; expected one of {TONEMAP_MODES}")


def _plugin(path: Path) -> str | None:
    """The imageio plugin for ``path``: Pillow for its formats, and for TIFF when tifffile
    (imageio's first choice, which reads more kinds of TIFF) is not installed; else imageio's
    choice."""
    suffix = path.suffix.lower()
    if suffix in _PILLOW_SUFFIXES or (suffix in (".tif", ".tiff") and importlib.util.find_spec("tifffile") is None):
        return "pillow"
    return None


def _video_plugin_available() -> bool:
    return any(importlib.util.find_spec(module) is not None for module in ("av", "imageio_ffmpeg"))


def _display(pixels, path) -> tuple[np.ndarray, int | None]:
    """Decoded pixels ``(H, W)``, ``(H, W, 1|2|3|4)`` -> display values ``(H, W)`` (gray) or
    ``(H, W, 3)`` in [0, 1], float64, and the bit depth (None for floats)."""
    pixels = np.asarray(pixels)
    if pixels.ndim == 2:
        pixels = pixels[..., None]
    if pixels.ndim == 4:
        raise FileFormatError(path, f"an animation of {pixels.shape[0]} frames, not one image: read it with "
                                    f"load_video (the commands take it as a video file)")
    if pixels.ndim != 3 or pixels.shape[-1] not in (1, 2, 3, 4):
        raise FileFormatError(path, f"not an image of 1-4 channels: decoded shape {pixels.shape}")
    # Gray (+ alpha) -> gray; RGB (+ alpha) -> RGB: the alpha channel is not radiance.
    colour = pixels[..., 0] if pixels.shape[-1] <= 2 else pixels[..., :3]
    if colour.dtype.kind == "u":
        top = np.iinfo(colour.dtype).max
        return colour / float(top), int(top).bit_length()
    if colour.dtype.kind == "f":
        # float pixels are taken as display values, so they must be ones
        if colour.size and not (np.all(np.isfinite(colour)) and 0.0 <= colour.min() and colour.max() <= 1.0):
            raise FileFormatError(path, f"float pixels must be display values in [0, 1]; this file holds "
                                        f"[{np.nanmin(colour):.4g}, {np.nanmax(colour):.4g}]"
                                        f"{' and NaN or inf' if not np.all(np.isfinite(colour)) else ''} (scene-"
                                        f"referred radiance belongs in an OpenEXR file)")
        return colour.astype(np.float64), None
    if colour.dtype.kind == "b":  # 1-bit images: black and white display values
        return colour.astype(np.float64), None
    raise FileFormatError(path, f"unsupported pixel type {colour.dtype} (signed or complex pixels have no display "
                                f"range): save 8- or 16-bit unsigned images")


def _rgb(display: np.ndarray, gray_ndim: int) -> np.ndarray:
    """Gray display values (``gray_ndim`` axes) repeated over R, G, B; colour as it is."""
    return np.broadcast_to(display[..., None], display.shape + (3,)) if display.ndim == gray_ndim else display


# Pillow modes whose channels are not R, G, B (+ alpha) or gray: decoded through Pillow's
# conversion to RGB (a CMYK JPEG's four channels would otherwise be read as RGBA).
_CONVERT_TO_RGB = ("CMYK", "YCbCr", "LAB", "HSV")


def _decode_image(path: Path) -> tuple[np.ndarray, int | None]:
    try:
        plugin = _plugin(path)
        mode = iio.immeta(path, plugin=plugin).get("mode") if plugin == "pillow" else None
        options = {"mode": "RGB"} if mode in _CONVERT_TO_RGB else {}
        if plugin == "pillow":
            options["rotate"] = True  # the EXIF orientation: the image as displayed, not as stored
        pixels = iio.imread(path, plugin=plugin, **options)
    except (OSError, ValueError) as error:
        raise FileFormatError(path, f"cannot read the image ({error})") from error
    if np.asarray(pixels).dtype == np.uint8 and (stored := _stored_bit_depth(path, plugin)) is not None:
        # Pillow decodes 16-bit gray PNG and TIFF as uint16 but 16-bit colour as 8 bits, silently.
        kind, bits = stored
        if bits > 8:
            raise FileFormatError(path, f"a {bits}-bit colour {kind}, which Pillow decodes to 8 bits only; convert "
                                        f"it to 16-bit gray {kind}(s), OpenEXR, or 8-bit {kind} explicitly")
    return _display(pixels, path)


def _stored_bit_depth(path: Path, plugin: str | None) -> tuple[str, int] | None:
    """``(kind, bits)``: the bits per sample a PNG file's header or, read through Pillow, a
    TIFF file's tags give (the largest over its samples), with the format's name; None for
    other files."""
    with open(path, "rb") as stream:
        head = stream.read(25)
    if len(head) == 25 and head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return "PNG", head[24]
    if plugin == "pillow" and head[:4] in (b"II*\x00", b"MM\x00*"):
        from PIL import Image

        with Image.open(path) as image:
            bits = image.tag_v2.get(258, 1)  # BitsPerSample: one value per sample, 1 when absent
        return "TIFF", max(bits) if isinstance(bits, tuple) else int(bits)
    return None


def _decode_video(path: Path) -> tuple[np.ndarray, int | None]:
    if path.suffix.lower() in VIDEO_SUFFIXES and not _video_plugin_available():
        raise MissingDependencyError(
            f"reading the video {str(path)!r} needs an imageio video plugin, and neither PyAV nor "
            f"imageio-ffmpeg is installed: pip install 'imageio[pyav]' (or 'imageio[ffmpeg]')"
        )
    try:
        decoded = [_display(frame, path) for frame in iio.imiter(path, plugin=_plugin(path))]
    except (OSError, ValueError) as error:
        raise FileFormatError(path, f"cannot read the video ({error})") from error
    if not decoded:
        raise FileFormatError(path, "the video has no frames")
    shapes = {frame.shape for frame, _ in decoded}
    if len(shapes) != 1:
        raise FileFormatError(path, f"frames of different sizes {sorted(shapes)}")
    return np.stack([frame for frame, _ in decoded]), decoded[0][1]


def _to_linear(display: np.ndarray, space: str, exposure) -> np.ndarray:
    """Display values in [0, 1] -> linear radiance, float32 on the host."""
    return np.asarray(inverse_tonemap(display, exposure, mode=space), dtype=np.float32)
