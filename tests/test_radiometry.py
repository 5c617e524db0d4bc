"""Radiometry: response round trips, exact 8/16-bit reads, saturation masks, gray input,
frame-size errors."""

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxocean import radiometry
from jaxocean.errors import InvalidValueError
from jaxocean.io.exr import FileFormatError, write_frame
from jaxocean.io.images import load_display
from jaxocean.radiometry import Response

RESPONSES = [Response("srgb"), Response("gamma", 2.2), Response("gamma", 0.8), Response("linear"),
             Response("bruneton")]


@pytest.mark.parametrize("response", RESPONSES, ids=lambda r: f"{r.kind}-{r.gamma}")
def test_display_round_trip_for_every_response(response):
    # bruneton's display is capped at 1 - 2^-10 (its radiance would be infinite at 1)
    top = 0.999 if response.kind == "bruneton" else 1.0
    x = np.linspace(0.0, top, 2001)
    for exposure in (1.0, 0.37):
        linear = radiometry.to_linear(x, response, exposure)
        back = np.asarray(radiometry.to_display(linear, response, exposure))
        # bruneton's two pieces miss each other by 3.4e-5 at the knee (shading.inverse_tonemap)
        np.testing.assert_allclose(back, x, atol=5e-5 if response.kind == "bruneton" else 2e-6)
    # monotone and zero at zero
    linear = np.asarray(radiometry.to_linear(x, response))
    assert linear[0] == 0 and np.all(np.diff(linear) > 0)
    # jit gives the same values
    np.testing.assert_array_equal(jax.jit(lambda d: radiometry.to_linear(d, response))(x), linear)


def test_gamma_response_is_the_power_law_with_finite_gradients():
    response = Response("gamma", 2.2)
    np.testing.assert_allclose(radiometry.to_linear(np.array([0.5]), response), [0.5 ** 2.2], rtol=1e-6)
    g = jax.grad(lambda v: radiometry.to_display(v, response))(0.0)
    assert np.isfinite(g)
    with pytest.raises(ValueError, match="gamma"):
        radiometry.to_linear(np.array([0.5]), Response("gamma", 0.0))
    with pytest.raises(ValueError, match="unknown response kind 'log'"):
        radiometry.to_linear(np.array([0.5]), Response("log"))


def test_8_and_16_bit_png_read_back_exactly(tmp_path):
    rng = np.random.default_rng(0)
    gray8 = rng.integers(0, 256, (9, 7), dtype=np.uint8)
    rgb8 = rng.integers(0, 256, (9, 7, 3), dtype=np.uint8)
    gray16 = rng.integers(0, 65536, (9, 7), dtype=np.uint16)
    for name, pixels, top in (("g8.png", gray8, 255), ("c8.png", rgb8, 255), ("g16.png", gray16, 65535)):
        iio.imwrite(tmp_path / name, pixels)
        display = load_display(tmp_path / name)
        assert display.values.shape == pixels.shape and display.bits == top.bit_length()
        np.testing.assert_array_equal(np.round(display.values.astype(np.float64) * top), pixels)
    frames = radiometry.load_frames([tmp_path / "g16.png"] * 2, response=Response("linear"))
    assert frames.gray and frames.bits == 16 and frames.linear.shape == (2, 9, 7)
    np.testing.assert_array_equal(np.round(frames.linear[1].astype(np.float64) * 65535), gray16)


def test_16_bit_colour_png_is_refused_not_truncated(tmp_path):
    # Pillow decodes a 16-bit RGB PNG to 8 bits; write one by hand and expect a clear error
    import struct
    import zlib

    pixels = np.full((2, 3, 3), 40000, dtype=">u2")
    raw = b"".join(b"\x00" + pixels[i].tobytes() for i in range(2))

    def chunk(tag, data):
        return struct.pack(">I", len(data)) + tag + data + struct.pack(">I", zlib.crc32(tag + data) & 0xFFFFFFFF)

    header = struct.pack(">IIBBBBB", 3, 2, 16, 2, 0, 0, 0)
    path = tmp_path / "c16.png"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", header) + chunk(b"IDAT", zlib.compress(raw))
                     + chunk(b"IEND", b""))
    with pytest.raises(FileFormatError, match="16-bit colour PNG"):
        load_display(path)


def test_16_bit_colour_tiff_is_refused_or_read_exactly_never_truncated(tmp_path):
    # without tifffile, Pillow decodes a 16-bit RGB TIFF to 8 bits; it loaded as 8-bit values
    # (bits 8, off by up to 1/510) without a word
    import struct

    pixels = np.arange(2 * 3 * 3, dtype=np.uint16).reshape(2, 3, 3) * 3001
    data = pixels.astype("<u2").tobytes()
    # little-endian baseline TIFF: one strip of 16-bit RGB after the header and one IFD
    tags = [(256, 3, 1, 3), (257, 3, 1, 2), (258, 3, 3, 0), (262, 3, 1, 2), (273, 4, 1, 0), (277, 3, 1, 3),
            (278, 3, 1, 2), (279, 4, 1, len(data))]
    ifd_size = 2 + 12 * len(tags) + 4
    bits_at, data_at = 8 + ifd_size, 8 + ifd_size + 6
    tags = [(tag, kind, count, {258: bits_at, 273: data_at}.get(tag, value)) for tag, kind, count, value in tags]
    ifd = struct.pack("<H", len(tags)) + b"".join(
        struct.pack("<HHI", tag, kind, count) + (struct.pack("<HH", value, 0) if kind == 3 and count == 1
                                                 else struct.pack("<I", value)) for tag, kind, count, value in tags)
    (tmp_path / "c16.tif").write_bytes(b"II*\x00" + struct.pack("<I", 8) + ifd + struct.pack("<I", 0)
                                       + struct.pack("<3H", 16, 16, 16) + data)
    try:
        display = load_display(tmp_path / "c16.tif")
    except FileFormatError as error:
        assert "16-bit colour TIFF" in str(error) and "c16.tif" in str(error)
    else:  # a reader that keeps the 16 bits (tifffile)
        assert display.bits == 16
        np.testing.assert_array_equal(np.round(display.values.astype(np.float64) * 65535), pixels)


def test_saturated_pixels_are_masked():
    display = np.array([[0.0, 0.5, 254 / 255, 1.0]])
    np.testing.assert_array_equal(radiometry.saturation_mask(display), [[True, True, True, False]])
    np.testing.assert_array_equal(radiometry.saturation_mask(display, low=0.5 / 255), [[False, True, True, False]])
    np.testing.assert_array_equal(radiometry.saturation_mask(display, high=0.9), [[True, True, False, False]])
    # 16 bits: 65534/65535 is not clipped, 1.0 is
    np.testing.assert_array_equal(radiometry.saturation_mask(np.array([65534 / 65535, 1.0]), bits=16),
                                  [True, False])
    # colour: any clipped channel makes the pixel unusable
    rgb = np.array([[[0.2, 0.3, 0.4], [0.2, 1.0, 0.4], [1.0, 1.0, 1.0]]])
    np.testing.assert_array_equal(radiometry.saturation_mask(rgb), [[True, False, False]])
    # a NaN pixel carries no value; bits is a positive int
    np.testing.assert_array_equal(radiometry.saturation_mask(np.array([[0.5, np.nan, 1.0]])), [[True, False, False]])
    for bits in (-8, 0, 2.5, True):
        with pytest.raises(ValueError, match="bits must be an int >= 1"):
            radiometry.saturation_mask(display, bits=bits)


def test_black_level_is_the_bottom_code_of_the_files_bit_depth(tmp_path):
    # the black level of 8-bit files, 0.5 / 255 as a display value, masked the 16-bit codes
    # 1-128 too: "bottom" scales it with the bit depth, as the top code does
    assert radiometry.bottom_code(8) == 0.5 / 255 and radiometry.bottom_code(16) == 0.5 / 65535
    assert radiometry.bottom_code(None) == 0.0
    codes = np.array([[0, 1, 100, 128, 129, 40000, 65535]], np.uint16)
    iio.imwrite(tmp_path / "deep.png", codes)
    deep = radiometry.load_frames([tmp_path / "deep.png"], low="bottom")
    np.testing.assert_array_equal(deep.usable[0], [[False, True, True, True, True, True, False]])
    iio.imwrite(tmp_path / "shallow.png", np.array([[0, 1, 128, 255]], np.uint8))
    shallow = radiometry.load_frames([tmp_path / "shallow.png"], low="bottom")
    np.testing.assert_array_equal(shallow.usable[0], [[False, True, True, False]])
    with pytest.raises(ValueError, match="low must be a display value, None or 'bottom'"):
        radiometry.saturation_mask(codes / 65535.0, bits=16, low="black")


@pytest.mark.parametrize("response", ["srgb", "gamma", "linear", "bruneton"])
def test_to_display_refuses_non_finite_radiance(response):
    # the curves would map NaN to a display value (sRGB: -0.055, outside [0, 1])
    for bad in (np.nan, np.inf):
        with pytest.raises(InvalidValueError, match="linear image must be finite"):
            radiometry.to_display(jnp.array([0.1, bad]), radiometry.Response(response))


def test_load_frames_masks_clipping_and_handles_gray_and_colour(tmp_path):
    gray = np.array([[10, 255], [0, 128]], np.uint8)
    iio.imwrite(tmp_path / "a.png", gray)
    iio.imwrite(tmp_path / "b.png", gray[::-1])
    frames = radiometry.load_frames([tmp_path / "a.png", tmp_path / "b.png"], response=Response("gamma", 2.0))
    assert frames.gray and frames.bits == 8 and frames.display.shape == (2, 2, 2)
    np.testing.assert_array_equal(frames.usable[0], [[True, False], [True, True]])
    np.testing.assert_array_equal(frames.usable[1], [[True, True], [True, False]])
    np.testing.assert_allclose(frames.linear[0], (gray / 255.0) ** 2, rtol=1e-6)
    rgb = np.zeros((2, 2, 3), np.uint8)
    rgb[0, 0] = (255, 3, 3)
    iio.imwrite(tmp_path / "c.png", rgb)
    colour = radiometry.load_frames([tmp_path / "c.png"])
    assert not colour.gray and colour.linear.shape == (1, 2, 2, 3)
    np.testing.assert_array_equal(colour.usable[0], [[False, True], [True, True]])


def test_load_frames_reads_exr_as_radiance_and_a_gif_video(tmp_path):
    image = np.random.default_rng(1).uniform(0, 3, (4, 5, 3)).astype(np.float32)
    write_frame(tmp_path / "f.exr", image, half=False)
    frames = radiometry.load_frames([tmp_path / "f.exr"])
    assert frames.display is None and frames.bits is None and frames.usable.all()
    np.testing.assert_array_equal(frames.linear[0], image)
    video = np.stack([np.full((4, 6), v, np.uint8) for v in (0, 100, 255)])
    iio.imwrite(tmp_path / "clip.gif", video)
    clip = radiometry.load_frames(tmp_path / "clip.gif", response=Response("linear"))
    assert clip.gray and clip.linear.shape == (3, 4, 6)
    np.testing.assert_allclose(clip.linear[:, 0, 0], [0, 100 / 255, 1.0], atol=1e-6)
    assert clip.usable[:2].all() and not clip.usable[2].any()


def test_load_frames_reads_grayscale_exr_as_gray_footage(tmp_path):
    # OpenEXR files of one Y channel were refused (missing R G B): they are gray radiance
    import OpenEXR

    luminance = np.random.default_rng(2).uniform(0, 3, (2, 4, 5)).astype(np.float32)
    luminance[1, 2, 3] = np.nan
    paths = [tmp_path / f"f{i}.exr" for i in range(2)]
    for path, plane in zip(paths, luminance):
        OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, {"Y": plane.copy()}).write(str(path))
    frames = radiometry.load_frames(paths)
    assert frames.gray and frames.display is None and frames.linear.shape == (2, 4, 5)
    np.testing.assert_array_equal(frames.linear, luminance)
    assert frames.usable.shape == (2, 4, 5) and frames.usable.sum() == frames.usable.size - 1
    assert not frames.usable[1, 2, 3]


def test_a_frame_of_another_size_is_named(tmp_path):
    iio.imwrite(tmp_path / "f0.png", np.zeros((4, 5), np.uint8))
    iio.imwrite(tmp_path / "f1.png", np.zeros((4, 5), np.uint8))
    iio.imwrite(tmp_path / "f2.png", np.zeros((4, 6), np.uint8))
    with pytest.raises(FileFormatError, match=r"f2\.png.*\(4, 6\).*f0\.png"):
        radiometry.load_frames([tmp_path / f"f{i}.png" for i in range(3)])
    iio.imwrite(tmp_path / "rgb.png", np.zeros((4, 5, 3), np.uint8))
    with pytest.raises(FileFormatError, match=r"rgb\.png"):
        radiometry.load_frames([tmp_path / "f0.png", tmp_path / "rgb.png"])
    iio.imwrite(tmp_path / "deep.png", np.zeros((4, 5), np.uint16))
    with pytest.raises(FileFormatError, match=r"deep\.png: 16-bit pixels"):
        radiometry.load_frames([tmp_path / "f0.png", tmp_path / "deep.png"])
    with pytest.raises(ValueError, match="at least one"):
        radiometry.load_frames([])
    with pytest.raises(ValueError, match=r"one video file.*clip\.mp4"):
        radiometry.load_frames([tmp_path / "clip.mp4", tmp_path / "f0.png"])


def test_luminance_uses_the_library_weights():
    from jaxocean.shading import LUMINANCE

    rgb = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [0.5, 0.5, 0.5]])
    np.testing.assert_allclose(radiometry.luminance(rgb), list(LUMINANCE) + [0.5], rtol=1e-6)
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        radiometry.luminance(np.ones((4, 2)))
