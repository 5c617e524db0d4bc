"""jaxocean.io: OpenEXR frames, scene.json, images and video.

What must hold: every channel and every metadata value round-trips (float32 bit for bit,
half within half precision); nothing partial is ever visible under a final name; bad
inputs are refused before a byte is written; every broken file is reported by name.
"""

import json
import os
import subprocess
import sys
import textwrap

import imageio.v3 as iio
import jax
import jax.numpy as jnp
import numpy as np
import OpenEXR
import pytest
from hypothesis import given
from hypothesis import strategies as st

import jaxocean
from jaxocean.camera import make_camera, make_orthographic
from jaxocean.errors import InvalidValueError
from jaxocean.io import (
    FileFormatError,
    FrameError,
    MissingFileError,
    SceneError,
    SceneFileError,
    atomic_write,
    exr,
    images,
    load_image,
    load_video,
    read_frame,
    read_scene,
    save_png,
    scene_from_dict,
    scene_to_dict,
    write_frame,
    write_scene,
)
from jaxocean.render import Geometry
from jaxocean.shading import make_lighting, tonemap
from jaxocean.spectrum import Spectrum
from jaxocean.waves import make_waves

H, W = 6, 10


def random_frame(seed=0, *, as_jax=False):
    """A linear image and a render.Geometry with awkward values: negatives, tiny roughness,
    a slope variance that is zero on one axis in places."""
    rng = np.random.default_rng(seed)
    image = rng.uniform(0.0, 30.0, (H, W, 3)).astype(np.float32)
    normal = rng.normal(size=(H, W, 3)).astype(np.float32)
    normal /= np.linalg.norm(normal, axis=-1, keepdims=True)
    roughness = np.exp(rng.uniform(np.log(2e-5), np.log(0.3), (H, W))).astype(np.float32)
    split = np.where(rng.random((H, W)) < 0.2, 0.0, rng.uniform(0.0, 1.0, (H, W))).astype(np.float32)
    slope_variance = np.stack([roughness * split, roughness * (1 - split)], -1)
    mask = rng.random((H, W)) > 0.3
    zeros = np.zeros((H, W, 2), np.float32)
    geometry = Geometry(normal=normal, roughness=roughness, slope_variance=slope_variance, mask=mask,
                        xy=zeros, position=np.zeros((H, W, 3), np.float32), footprint=zeros[..., 0])
    if as_jax:
        image, geometry = jax.tree.map(jnp.asarray, (image, geometry))
    return image, geometry


def write_raw_exr(path, channels):
    """An EXR written around jaxocean (the binding replaces the dict's values: copy it)."""
    OpenEXR.File({"compression": OpenEXR.ZIP_COMPRESSION}, dict(channels)).write(str(path))


# --------------------------------------------------------------------------- frames


def test_float32_frame_round_trips_bit_exact(tmp_path):
    # JAX inputs, a Geometry NamedTuple: the per-channel copies must undo the strided
    # views (the binding writes rgb[..., c] silently wrong), so equality is bitwise.
    image, geometry = random_frame(as_jax=True)
    path = write_frame(tmp_path / "frame.exr", image, geometry, half=False)
    frame = read_frame(path, expect_resolution=(H, W))
    for name, expected in [("image", image), ("normal", geometry.normal), ("roughness", geometry.roughness),
                           ("slope_variance", geometry.slope_variance)]:
        got = getattr(frame, name)
        assert got.dtype == np.float32 and got.shape == expected.shape, name
        np.testing.assert_array_equal(got.view(np.uint32), np.asarray(expected).view(np.uint32), err_msg=name)
    assert frame.mask.dtype == bool
    np.testing.assert_array_equal(frame.mask, geometry.mask)
    assert frame.meta == {}
    assert os.listdir(tmp_path) == ["frame.exr"]


def test_half_frame_stores_rgb_as_half_and_geometry_as_float32(tmp_path):
    image, geometry = random_frame(1)
    path = write_frame(tmp_path / "frame.exr", image, {"normal": geometry.normal,
                                                        "roughness": geometry.roughness,
                                                        "slope_variance": geometry.slope_variance,
                                                        "mask": geometry.mask.astype(np.float32)})
    raw = OpenEXR.File(str(path), separate_channels=True)
    assert raw.header()["compression"] == OpenEXR.ZIP_COMPRESSION
    types = {name: c.pixels.dtype for name, c in raw.channels().items()}
    geometry_values = exr.NORMAL_CHANNELS + ("roughness",) + exr.SLOPE_VARIANCE_CHANNELS
    assert types == {**{name: np.dtype(np.float16) for name in exr.RGB_CHANNELS + ("mask",)},
                     **{name: np.dtype(np.float32) for name in geometry_values}}

    frame = read_frame(path)
    # Half: 11 significant bits; subnormal below 6.1e-5 with an absolute step of 6e-8.
    assert frame.image.dtype == np.float32
    np.testing.assert_allclose(frame.image, image, rtol=2.0**-11, atol=3e-8)
    assert not np.array_equal(frame.image, image)  # it really was stored as half
    # the geometry the image is shaded from is exact
    for got, expected in [(frame.normal, geometry.normal), (frame.roughness, geometry.roughness),
                          (frame.slope_variance, geometry.slope_variance)]:
        np.testing.assert_array_equal(got.view(np.uint32), expected.view(np.uint32))
    np.testing.assert_array_equal(frame.mask, geometry.mask)


def test_geometry_without_slope_variance_reads_with_a_warning(tmp_path):
    # a frame written before slope_variance.X/Y were stored (or by another tool): still read,
    # with the missing channels named; callers that report it themselves can silence it
    image, geometry = random_frame(4)
    path = write_frame(tmp_path / "old.exr", image, geometry._asdict() | {"slope_variance": None})
    assert exr.SLOPE_VARIANCE_CHANNELS[0] not in OpenEXR.File(str(path), separate_channels=True).channels()
    with pytest.warns(exr.IncompleteFrameWarning, match=r"old\.exr: no slope_variance\.X/slope_variance\.Y"):
        frame = read_frame(path)
    assert frame.slope_variance is None
    np.testing.assert_array_equal(frame.roughness, geometry.roughness)
    quiet = read_frame(path, warn_incomplete=False)  # warnings are errors in this suite
    assert quiet.slope_variance is None and quiet.normal is not None


def test_negative_or_misshapen_slope_variance_is_refused(tmp_path):
    image, geometry = random_frame(5)
    bad = geometry.slope_variance.copy()
    bad[1, 2, 0] = -1e-6
    with pytest.raises(InvalidValueError, match=r"'slope_variance\.X'.*>= 0"):
        write_frame(tmp_path / "f.exr", image, geometry._replace(slope_variance=bad))
    with pytest.raises(ValueError, match="slope_variance"):
        write_frame(tmp_path / "f.exr", image, geometry._replace(slope_variance=bad[..., :1]))
    assert os.listdir(tmp_path) == []


def test_rendered_frame_reproduces_its_image_from_its_geometry(tmp_path):
    """render -> write -> read -> shade equals the stored image, to the storage precision.

    The scene has sub-pixel waves travelling along one direction, so sigma_x^2 and
    sigma_y^2 differ several-fold: the scalar roughness alone (isotropic sigma^2 / 2 per
    axis) misses the glitter by far more than the storage precision. With half RGB the
    stored image is the render rounded to half (relative error <= 2^-11, absolute 3e-8 below
    6.1e-5); the geometry is float32 and exact, so re-shading it differs from the stored
    image by that rounding plus float32 evaluation-order noise (measured ~1e-6 relative).
    Float32 RGB: the float32 noise alone.
    """
    from jaxocean import render

    waves = make_waves([0.2, 0.05, 0.01, 0.004], [1.0, 2.2, 4.5, 7.0], [0.1, 0.15, 0.05, 0.1], [0.0, 1.0, 2.0, 3.0])
    cam = make_camera(height=10.0, pitch=0.35, fov=0.8, resolution=(24, 32))
    light = make_lighting(sun_azimuth=0.1, sun_elevation=0.4)
    geo = render.geometry(waves, cam, 0.7, plan=render.full_plan(4))
    image = np.asarray(render.shade(geo.normal, geo.roughness, cam, light, slope_variance=geo.slope_variance))
    sv = np.asarray(geo.slope_variance)[np.asarray(geo.mask)]
    assert np.sum(sv[:, 0]) > 10 * np.sum(sv[:, 1])  # anisotropic: the test can tell the two shadings apart
    isotropic = np.asarray(render.shade(geo.normal, geo.roughness, cam, light))
    assert np.max(np.abs(isotropic - image) / np.maximum(np.abs(image), 1e-3)) > 0.1

    for half, rtol in ((True, 2.0**-11 + 1e-5), (False, 1e-5)):
        frame = read_frame(write_frame(tmp_path / f"half_{half}.exr", image, geo, half=half))
        shaded = render.shade(frame.normal, frame.roughness, cam, light, slope_variance=frame.slope_variance)
        np.testing.assert_allclose(np.asarray(shaded), frame.image, rtol=rtol, atol=3e-8, err_msg=f"half={half}")


def test_frame_without_geometry_reads_none(tmp_path):
    image, _ = random_frame(2)
    frame = read_frame(write_frame(tmp_path / "f.exr", image, half=False))
    np.testing.assert_array_equal(frame.image, image)
    assert (frame.normal, frame.roughness, frame.mask) == (None, None, None)
    assert sorted(OpenEXR.File(str(tmp_path / "f.exr"), separate_channels=True).channels()) == ["B", "G", "R"]


def test_metadata_attributes_round_trip_exactly(tmp_path):
    meta = {"scene": "north-sea/07 ☃", "frame": 42, "offset": -(2**31), "time": 0.1,
            "dt": 1 / 30, "np_index": np.int64(7), "np_time": np.float32(0.25)}
    image, geometry = random_frame(3)
    frame = read_frame(write_frame(tmp_path / "f.exr", image, geometry, meta))
    expected = {**meta, "np_index": 7, "np_time": 0.25}
    assert frame.meta == expected
    assert type(frame.meta["time"]) is float and frame.meta["time"] == 0.1  # not 0.10000000149
    assert type(frame.meta["frame"]) is int
    assert OpenEXR.File(str(tmp_path / "f.exr"), header_only=True).header()["jaxocean.frame"] == 42


@given(st.dictionaries(
    st.text(st.characters(codec="utf-8", exclude_characters="\x00"), min_size=1, max_size=20),
    st.one_of(st.text(st.characters(codec="utf-8", exclude_characters="\x00"), max_size=30),
              st.integers(-(2**31), 2**31 - 1),
              st.floats(allow_nan=False, allow_infinity=False)),
    max_size=5,
))
def test_any_valid_metadata_round_trips(tmp_path_factory, meta):
    path = tmp_path_factory.mktemp("meta") / "f.exr"
    frame = read_frame(write_frame(path, np.zeros((2, 3, 3), np.float32), meta=meta))
    assert frame.meta == meta
    assert {k: type(v) for k, v in frame.meta.items()} == {k: type(v) for k, v in meta.items()}


@pytest.mark.parametrize(
    "meta, error",
    [({"flag": True}, ValueError), ({"big": 2**31}, ValueError), ({"t": float("nan")}, InvalidValueError),
     ({"list": [1, 2]}, ValueError), ({"": 1}, ValueError), ({3: 1}, ValueError),
     ({"a" * 250 + "1": 1, "a" * 250 + "2": 2}, ValueError)],  # was cut to one key of 246
)
def test_bad_metadata_is_refused_before_writing(tmp_path, meta, error):
    with pytest.raises(error):
        write_frame(tmp_path / "out" / "f.exr", np.zeros((2, 3, 3)), meta=meta)
    assert os.listdir(tmp_path) == []


# --------------------------------------------------------------------------- atomicity


class CrashingFile:
    """Stands in for OpenEXR.File: writes a real file, cuts it in half, then fails --
    a process that is interrupted in the middle of writing."""

    real_file = OpenEXR.File

    def __init__(self, header, channels):
        self.file = self.real_file(header, channels)

    def write(self, path):
        self.file.write(path)
        with open(path, "r+b") as f:
            f.truncate(os.path.getsize(path) // 2)
        raise RuntimeError("simulated crash mid-write")


def test_crash_mid_write_leaves_no_final_and_no_temporary_file(tmp_path, monkeypatch):
    image, geometry = random_frame(4)
    monkeypatch.setattr(exr.OpenEXR, "File", CrashingFile)
    with pytest.raises(RuntimeError, match="simulated crash"):
        write_frame(tmp_path / "frame.exr", image, geometry)
    assert os.listdir(tmp_path) == []


def test_crash_while_overwriting_keeps_the_old_frame(tmp_path, monkeypatch):
    old, _ = random_frame(5)
    new, _ = random_frame(6)
    path = write_frame(tmp_path / "frame.exr", old, half=False)
    monkeypatch.setattr(exr.OpenEXR, "File", CrashingFile)
    with pytest.raises(RuntimeError):
        write_frame(path, new, half=False)
    monkeypatch.undo()
    np.testing.assert_array_equal(read_frame(path).image, old)
    assert os.listdir(tmp_path) == ["frame.exr"]


def test_killed_process_never_exposes_a_partial_file(tmp_path):
    # A process that dies mid-write cannot clean up: its temporary may stay, but nothing
    # appears under the final name.
    script = textwrap.dedent(f"""
        import os
        from jaxocean.io.exr import atomic_write
        def write(temporary):
            with open(temporary, "wb") as f:
                f.write(b"half a frame")
                f.flush()
            os._exit(3)
        atomic_write({str(tmp_path / "frame.exr")!r}, write)
    """)
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, timeout=60)
    assert result.returncode == 3, result.stderr.decode()
    names = os.listdir(tmp_path)
    assert "frame.exr" not in names
    assert len(names) == 1 and names[0].startswith(".frame.exr.tmp-")


def test_atomic_write_replaces_and_cleans_up(tmp_path):
    target = tmp_path / "sub" / "a.txt"
    assert atomic_write(target, lambda p: p.write_text("one")) == target
    atomic_write(target, lambda p: p.write_text("two"))
    assert target.read_text() == "two"

    def failing(p):
        p.write_text("partial")
        raise OSError("disk full")

    with pytest.raises(OSError, match="disk full"):
        atomic_write(target, failing)
    assert target.read_text() == "two"
    assert os.listdir(target.parent) == ["a.txt"]


# --------------------------------------------------------------------------- refused inputs


@pytest.mark.parametrize("channel", ["R", "G", "B", "normal.Y", "roughness"])
def test_nan_is_refused_before_anything_is_written(tmp_path, channel):
    image, geometry = random_frame(7)
    if channel in "RGB":
        image[2, 3, "RGB".index(channel)] = np.nan
    elif channel == "normal.Y":
        geometry.normal[0, 0, 1] = np.inf
    else:
        geometry.roughness[1, 1] = np.nan
    with pytest.raises(InvalidValueError, match=f"'{channel}'"):
        write_frame(tmp_path / "frames" / "f.exr", image, geometry)
    assert os.listdir(tmp_path) == []


def test_half_overflow_is_refused_and_float32_accepts_it(tmp_path):
    image = np.full((2, 3, 3), 1e5, np.float32)
    with pytest.raises(InvalidValueError, match="half=False"):
        write_frame(tmp_path / "f.exr", image)
    assert os.listdir(tmp_path) == []
    np.testing.assert_array_equal(read_frame(write_frame(tmp_path / "f.exr", image, half=False)).image, image)


def test_values_beyond_float32_and_negative_roughness_are_refused(tmp_path):
    # a finite float64 beyond float32 was stored as inf (geometry is float32 whatever half is)
    with pytest.raises(InvalidValueError, match="'R': values beyond the float32 range"):
        write_frame(tmp_path / "f.exr", np.full((2, 2, 3), 1e300), half=False)
    geometry = dict(normal=np.full((2, 2, 3), 1e200), roughness=np.ones((2, 2)), mask=np.ones((2, 2)))
    with pytest.raises(InvalidValueError, match="'normal.X': values beyond the float32 range"):
        write_frame(tmp_path / "f.exr", np.ones((2, 2, 3)), geometry)
    geometry = dict(normal=np.zeros((2, 2, 3)) + [0, 0, 1], roughness=-np.ones((2, 2)), mask=np.ones((2, 2)))
    with pytest.raises(InvalidValueError, match="a roughness must be >= 0"):
        write_frame(tmp_path / "f.exr", np.ones((2, 2, 3)), geometry)
    assert os.listdir(tmp_path) == []


def test_a_sequence_that_fails_its_checks_leaves_the_previous_one_whole(tmp_path):
    # the previous scene.json was removed and frame 0 overwritten before frame 1's NaN was
    # found, leaving old and new frames mixed; a camera of another resolution was accepted
    from types import SimpleNamespace

    from jaxocean.io.sequence import write_sequence
    from jaxocean.shading import make_lighting
    from jaxocean.waves import make_waves

    camera = make_camera(height=12.0, pitch=0.35, fov=0.8, resolution=(3, 4))
    normal = np.zeros((3, 3, 4, 3)) + [0.0, 0.0, 1.0]
    geometry = SimpleNamespace(normal=normal, roughness=np.full((3, 3, 4), 0.01), mask=np.ones((3, 3, 4), bool),
                               slope_variance=np.full((3, 3, 4, 2), 0.005), converged=None)
    scene = SimpleNamespace(waves=make_waves([0.3], [1.1], [0.1], [0.5]), camera=camera,
                            lighting=make_lighting(sun_azimuth=0.1, sun_elevation=0.35), spectrum=None,
                            times=np.arange(3) * 0.1)
    images = np.random.default_rng(0).uniform(0, 1, (3, 3, 4, 3))
    out = tmp_path / "s"
    write_sequence(out, scene, images, geometry, progress=False)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    bad = images * 0.5
    bad[1, 0, 0, 0] = np.nan
    with pytest.raises(InvalidValueError, match="'R'"):
        write_sequence(out, scene, bad, geometry, progress=False)
    with pytest.raises(ValueError, match="exposure must be"):
        write_sequence(out, scene, images * 0.5, geometry, progress=False, exposure=0.0)
    with pytest.raises(ValueError, match="seed"):
        write_sequence(out, scene, images * 0.5, geometry, progress=False, seed=1.5)
    other = SimpleNamespace(**{**vars(scene), "camera": make_camera(height=12.0, pitch=0.35, fov=0.8,
                                                                    resolution=(30, 40))})
    with pytest.raises(ValueError, match=r"camera is \(30, 40\) \(H, W\) but the images are \(3, 4\)"):
        write_sequence(out, other, images, geometry, progress=False)
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before


@pytest.mark.parametrize("field, value", [
    ("image", np.zeros((H, W))),
    ("normal", np.zeros((H, W + 1, 3))),
    ("roughness", np.zeros((H, W, 1))),
    ("mask", np.zeros((W, H), bool)),
])
def test_mismatched_shapes_are_refused(tmp_path, field, value):
    image, geometry = random_frame(8)
    geometry = geometry._asdict()
    if field == "image":
        image = value
    else:
        geometry[field] = value
    with pytest.raises(ValueError, match=field):
        write_frame(tmp_path / "f.exr", image, geometry)
    assert os.listdir(tmp_path) == []


def test_soft_mask_and_unknown_compression_are_refused(tmp_path):
    image, geometry = random_frame(9)
    soft = geometry._replace(mask=np.full((H, W), 0.5))
    with pytest.raises(InvalidValueError, match="mask"):
        write_frame(tmp_path / "f.exr", image, soft)
    with pytest.raises(ValueError, match="compression"):
        write_frame(tmp_path / "f.exr", image, compression="gzip")
    with pytest.raises(ValueError, match="roughness"):
        write_frame(tmp_path / "f.exr", image, {"normal": geometry.normal, "mask": geometry.mask})
    assert os.listdir(tmp_path) == []


def test_other_compressions_round_trip(tmp_path):
    image, geometry = random_frame(10)
    for compression in ("none", "piz", "zips"):
        frame = read_frame(write_frame(tmp_path / f"{compression}.exr", image, geometry, half=False,
                                       compression=compression))
        np.testing.assert_array_equal(frame.roughness, geometry.roughness)


# --------------------------------------------------------------------------- broken files


def test_missing_frame_is_reported_by_name(tmp_path):
    path = tmp_path / "frame_00007.exr"
    with pytest.raises(MissingFileError, match="frame_00007.exr") as info:
        read_frame(path)
    assert isinstance(info.value, FileNotFoundError) and isinstance(info.value, FileFormatError)


@pytest.mark.parametrize("damage", ["garbage", "header only", "half", "last byte"])
def test_corrupt_or_truncated_frame_is_reported_by_name(tmp_path, capfd, damage):
    path = tmp_path / "frame_00003.exr"
    if damage == "garbage":
        path.write_bytes(b"not an exr file at all " * 40)
    else:
        image, geometry = random_frame(11)
        data = write_frame(path, image, geometry).read_bytes()
        cut = {"header only": 200, "half": len(data) // 2, "last byte": len(data) - 1}[damage]
        path.write_bytes(data[:cut])
    with pytest.raises(FrameError, match="frame_00003.exr") as info:
        read_frame(path)
    assert info.value.path == str(path)
    # OpenEXR's own report (C++ on stderr, the binding on stdout) is not printed; the error
    # says what it found
    assert capfd.readouterr() == ("", "")
    if damage in ("half", "last byte"):
        assert "EXR_ERR" in str(info.value)


def test_output_printed_during_a_good_read_is_kept(tmp_path, capfd, monkeypatch):
    # reads redirect stdout / stderr to catch OpenEXR's reports on damaged files; what is
    # printed meanwhile (another thread's output, say) still appears after a read that succeeds
    image, geometry = random_frame(6)
    path = write_frame(tmp_path / "f.exr", image, geometry)
    original = OpenEXR.File

    def chatty(*args, **kwargs):
        print("from python")
        os.write(2, b"from a file descriptor\n")
        return original(*args, **kwargs)

    monkeypatch.setattr(OpenEXR, "File", chatty)
    capfd.readouterr()
    np.testing.assert_array_equal(read_frame(path).mask, geometry.mask)
    assert capfd.readouterr() == ("from python\n", "from a file descriptor\n")


@pytest.mark.parametrize("kind, data", [
    ("a PNG image", None),
    ("a JSON file", b'{"version": "0.1.0"}'),
    ("empty file", b""),
])
def test_other_file_types_are_named_not_called_corrupt(tmp_path, kind, data):
    path = tmp_path / "frame.exr"
    if data is None:
        iio.imwrite(path, np.zeros((4, 5, 3), np.uint8), extension=".png")
    else:
        path.write_bytes(data)
    with pytest.raises(FrameError, match=f"frame.exr: {kind}") as info:
        read_frame(path)
    assert "expected an OpenEXR frame" in str(info.value) and "corrupt" not in str(info.value)


def test_missing_rgb_channel_is_named_with_the_file(tmp_path):
    path = tmp_path / "rg.exr"
    write_raw_exr(path, {name: np.zeros((4, 5), np.float32) for name in "RG"})
    with pytest.raises(FrameError, match=r"rg\.exr.*'B'"):
        read_frame(path)


def test_grayscale_exr_reads_as_gray_radiance_but_is_no_frame(tmp_path):
    # a Y-only OpenEXR (a grayscale image) was refused for missing R G B, though gray frames
    # are accepted: it reads as (H, W) radiance, and load_image repeats it over R, G, B
    luminance = np.linspace(0.0, 3.0, 20, dtype=np.float32).reshape(4, 5)
    write_raw_exr(tmp_path / "gray.exr", {"Y": luminance})
    np.testing.assert_array_equal(exr.read_radiance(tmp_path / "gray.exr"), luminance)
    np.testing.assert_array_equal(load_image(tmp_path / "gray.exr"), np.repeat(luminance[..., None], 3, -1))
    with pytest.raises(FrameError, match=r"gray\.exr: a grayscale image \(one 'Y' channel\), not a frame"):
        read_frame(tmp_path / "gray.exr")  # a frame (with geometry, for the fits) stays R G B
    # a file with R G B is colour whatever else it holds; a luminance-chroma image is no gray one
    write_raw_exr(tmp_path / "rgby.exr", {name: np.full((4, 5), i, np.float32) for i, name in enumerate("RGBY")})
    assert exr.read_radiance(tmp_path / "rgby.exr").shape == (4, 5, 3)
    write_raw_exr(tmp_path / "yc.exr", {"Y": luminance, "RY": luminance, "BY": luminance})
    with pytest.raises(FrameError, match=r"yc\.exr: a luminance-chroma image"):
        load_image(tmp_path / "yc.exr")
    write_raw_exr(tmp_path / "rg.exr", {name: luminance for name in "RG"})
    with pytest.raises(FrameError, match=r"rg\.exr: missing channel\(s\) \['B'\]; an image needs"):
        exr.read_radiance(tmp_path / "rg.exr")


def test_a_directory_given_for_a_file_is_named_with_its_article(tmp_path):
    with pytest.raises(MissingFileError, match="a directory, not an EXR frame file"):
        read_frame(tmp_path)
    with pytest.raises(MissingFileError, match="a directory, not an image file"):
        load_image(tmp_path)
    with pytest.raises(MissingFileError, match="a directory, not a video file"):
        load_video(tmp_path)


def test_partial_geometry_is_named_with_the_file(tmp_path):
    path = tmp_path / "partial.exr"
    names = ["R", "G", "B", "normal.X", "normal.Y", "normal.Z"]
    write_raw_exr(path, {name: np.zeros((4, 5), np.float32) for name in names})
    with pytest.raises(FrameError, match=r"partial\.exr.*'roughness', 'mask'"):
        read_frame(path)


def test_foreign_exr_with_extra_channels_reads(tmp_path):
    path = tmp_path / "rgba.exr"
    planes = {name: np.full((4, 5), i, np.float32) for i, name in enumerate("RGBA")}
    write_raw_exr(path, planes)
    frame = read_frame(path)
    np.testing.assert_array_equal(frame.image, np.stack([planes[c] for c in "RGB"], -1))
    assert frame.normal is None


def test_exr_whose_pixels_cover_part_of_the_image_is_refused(tmp_path):
    path = tmp_path / "crop.exr"
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage,
              "dataWindow": ((2, 3), (9, 8)), "displayWindow": ((0, 0), (15, 15))}
    OpenEXR.File(header, {c: np.ones((6, 8), np.float32) for c in "RGB"}).write(str(path))
    # read as they are, the 6 x 8 pixels would be a crop of the 16 x 16 image the camera sees
    with pytest.raises(FrameError, match=r"crop\.exr: pixels cover the data window \(\(2, 3\), \(9, 8\)\) but "
                                         r"the image is the display window \(\(0, 0\), \(15, 15\)\)"):
        read_frame(path)


def test_resolution_mismatch_is_reported(tmp_path):
    image, _ = random_frame(12)
    path = write_frame(tmp_path / "f.exr", image)
    assert read_frame(path, expect_resolution=(H, W)).image.shape == (H, W, 3)
    with pytest.raises(FrameError, match=rf"f\.exr.*\({H}, {W}\).*\({W}, {H}\)"):
        read_frame(path, expect_resolution=(W, H))


def test_errors_survive_pickling(tmp_path):
    import pickle

    error = FrameError(tmp_path / "f.exr", "truncated")
    again = pickle.loads(pickle.dumps(error))
    assert type(again) is FrameError and str(again) == str(error) and again.path == error.path


# --------------------------------------------------------------------------- scenes


def example_scene():
    rng = np.random.default_rng(0)
    waves = make_waves(rng.uniform(0.01, 0.1, 7).astype(np.float32), rng.uniform(0.8, 3.0, 7).astype(np.float32),
                       rng.uniform(-3, 3, 7).astype(np.float32), rng.uniform(-3, 3, 7).astype(np.float32))
    camera = make_camera(height=12.345678, pitch=0.3141592, yaw=1.1, fov=0.7, resolution=(48, 64), x=3.3, y=-0.1)
    lighting = make_lighting(sun_azimuth=0.123456789, sun_elevation=0.5, sun_color=(20.1, 18.2, 15.3),
                             sky_color=(0.3, 0.5, 0.9), sea_color=(0.01, 0.05, 0.08))
    spectrum = Spectrum(hs=jnp.float32(1.7), tp=jnp.float32(8.3), gamma=jnp.float32(3.3),
                        theta_mean=jnp.float32(0.2), s_max=jnp.float32(25.0))
    times = jnp.arange(5, dtype=jnp.float32) / 30
    return dict(waves=waves, camera=camera, lighting=lighting, spectrum=spectrum, times=times, seed=1234,
                extra={"note": "test", "n": [1, 2]})


def assert_trees_equal(a, b):
    assert jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b)):
        x, y = np.asarray(x), np.asarray(y)
        assert x.dtype == y.dtype == np.float32 and x.shape == y.shape
        np.testing.assert_array_equal(x, y)


def test_scene_json_round_trips_every_pytree_exactly(tmp_path):
    original = example_scene()
    path = write_scene(tmp_path, scene_to_dict(**original))
    assert path == tmp_path / "scene.json" and os.listdir(tmp_path) == ["scene.json"]
    scene = read_scene(tmp_path)
    for name in ("waves", "camera", "lighting", "spectrum", "times"):
        assert_trees_equal(getattr(scene, name), original[name])
    # Static camera fields are part of the tree structure, compared above; state them too.
    assert scene.camera.resolution == (48, 64) and scene.camera.projection == "perspective"
    assert scene.seed == 1234 and scene.extra == original["extra"]
    assert scene.version == jaxocean.__version__
    # The file is plain JSON with lists of numbers, and a Scene can be written again.
    assert json.loads(path.read_text())["waves"]["omega"] == np.asarray(original["waves"].omega, np.float64).tolist()
    again = read_scene(write_scene(tmp_path / "again.json", scene))
    for name in ("waves", "camera", "lighting", "spectrum", "times"):
        assert_trees_equal(getattr(again, name), original[name])


def test_orthographic_camera_and_empty_sections_round_trip():
    camera = make_orthographic(40.0, (32, 16), x=1.5, yaw=np.pi / 2)
    scene = scene_from_dict(json.loads(json.dumps(scene_to_dict(camera=camera))))
    assert_trees_equal(scene.camera, camera)
    assert scene.camera.projection == "orthographic"
    assert (scene.waves, scene.lighting, scene.spectrum, scene.times, scene.seed, scene.extra) == (None,) * 6


@given(st.lists(st.floats(width=32, allow_nan=False, allow_infinity=False), min_size=1, max_size=20))
def test_scene_numbers_are_exact_for_any_float32(values):
    times = np.asarray(values, np.float32)
    text = json.dumps(scene_to_dict(times=times))
    np.testing.assert_array_equal(np.asarray(scene_from_dict(json.loads(text)).times), times)


def test_float64_scene_is_exact_under_x64(x64):
    waves = make_waves([0.1, 1 / 3], [1.0, np.pi / 2], [0.1, 0.7], dtype=jnp.float64)
    scene = scene_from_dict(json.loads(json.dumps(scene_to_dict(waves=waves))))
    for got, expected in zip(scene.waves, waves):
        assert got.dtype == jnp.float64
        np.testing.assert_array_equal(got, expected)


def test_malformed_scene_json_is_reported_by_name(tmp_path):
    path = tmp_path / "scene.json"
    path.write_text('{"version": "0.1.0", "seed": 3,,}')
    with pytest.raises(SceneFileError, match=r"scene\.json: malformed JSON.*line 1") as info:
        read_scene(path)
    assert isinstance(info.value, SceneError) and isinstance(info.value, FileFormatError)


@pytest.mark.parametrize("edit, message", [
    (lambda d: d["waves"].pop("omega"), r"waves is missing key\(s\) \['omega'\]"),
    (lambda d: d.pop("version"), r"missing key\(s\) \['version'\]"),
    (lambda d: d["camera"].update(zoom=2.0), r"camera has unknown key\(s\) \['zoom'\]"),
    (lambda d: d.update(wave=None), r"unknown key\(s\) \['wave'\]"),
    (lambda d: d["lighting"].update(sun_color="red"), r"lighting\.sun_color must be a number"),
    (lambda d: d["camera"].update(height=-1.0), r"camera: .*under the sea"),
    (lambda d: d["camera"].update(resolution=[48.5, 64]), r"camera: .*resolution"),
    (lambda d: d.update(seed=1.5), r"seed must be an integer"),
    (lambda d: d.update(times=[]), r"times must hold at least one frame time"),
    (lambda d: d.update(times=[0.0, 1e300]), r"times must be finite in float32"),  # inf once read
    (lambda d: d["lighting"].update(sun_color=[1e39, 1.0, 1.0]), r"lighting\.sun_color must be finite in float32"),
    # a bool inside the lists is a mistake as much as a bare one (NumPy would read true as 1.0)
    (lambda d: d["lighting"].update(sun_color=[True, 1.0, 1.0]), r"lighting\.sun_color must be a number"),
    (lambda d: d.update(times=[0.0, False]), r"times must be a number"),
])
def test_invalid_scene_content_is_reported_with_the_file(tmp_path, edit, message):
    d = scene_to_dict(**example_scene())
    edit(d)
    path = tmp_path / "scene.json"
    path.write_text(json.dumps(d))
    with pytest.raises(SceneFileError, match=r"scene\.json: .*" + message):
        read_scene(path)
    with pytest.raises(SceneError, match=message):  # the same check without a file
        scene_from_dict(d)


def test_scene_nan_is_refused_at_both_ends(tmp_path):
    with pytest.raises(InvalidValueError, match="times"):
        scene_to_dict(times=[0.0, np.nan])
    with pytest.raises(ValueError, match="at least one frame time"):
        scene_to_dict(times=[])
    path = tmp_path / "scene.json"
    path.write_text('{"version": "0.1.0", "times": [0.0, NaN]}')  # Python's json accepts NaN
    with pytest.raises(SceneFileError, match="times"):
        read_scene(path)
    with pytest.raises(MissingFileError, match="elsewhere"):
        read_scene(tmp_path / "elsewhere")


def test_read_scene_of_a_frame_file_names_the_scene_directory(tmp_path):
    # a frame given for its scene: not ".../frame_00000.exr/scene.json: no such scene file"
    frame = tmp_path / "frame_00000.exr"
    frame.write_bytes(b"not read")
    with pytest.raises(SceneFileError, match=r"frame_00000\.exr: not a scene file or directory; give the scene's "
                                             r"directory \(" + str(tmp_path) + r"\) or its scene\.json"):
        read_scene(frame)


def test_read_scene_of_a_dataset_root_names_its_scene_directories(tmp_path):
    # a dataset's root said only ".../scene.json: no such scene file", no hint of what to give
    for i in range(5):
        write_scene(tmp_path / f"scene_{i:05d}", scene_to_dict(times=[0.0, 0.1]))
    with pytest.raises(MissingFileError, match=r"holds scene directories \(scene_00000, scene_00001, scene_00002, "
                                               r"\.\.\. \(5 in all\)\); give one of them, e\.g\. .*scene_00000"):
        read_scene(tmp_path)
    assert read_scene(tmp_path / "scene_00003").times is not None


# --------------------------------------------------------------------------- images and video


@pytest.mark.parametrize("mode, exposure", [("bruneton", 1.0), ("bruneton", 2.5), ("srgb", 0.7), ("linear", 1.3)])
def test_png_round_trip_is_within_8_bit_quantisation(tmp_path, mode, exposure):
    rng = np.random.default_rng(13)
    linear = np.exp(rng.uniform(np.log(1e-3), np.log(5.0), (16, 24, 3))).astype(np.float32)
    path = save_png(tmp_path / "preview.png", linear, exposure=exposure, mode=mode)
    assert os.listdir(tmp_path) == ["preview.png"]
    assert iio.imread(path).dtype == np.uint8
    loaded = load_image(path, space=mode, exposure=exposure)
    assert loaded.shape == (16, 24, 3) and loaded.dtype == np.float32
    # In the display domain the only loss is rounding to 256 levels (plus float32 slack).
    error = np.abs(np.asarray(tonemap(loaded, exposure, mode)) - np.asarray(tonemap(linear, exposure, mode)))
    assert error.max() <= 0.5 / 255 + 1e-5
    unsaturated = tonemap(linear, exposure, mode) < 0.98
    np.testing.assert_allclose(loaded[unsaturated], linear[unsaturated], rtol=0.1, atol=2e-3 / exposure)


def test_load_image_reads_exr_as_linear_and_png_gray_and_alpha(tmp_path):
    image, _ = random_frame(14)
    np.testing.assert_array_equal(load_image(write_frame(tmp_path / "f.exr", image, half=False)), image)
    rgba = np.zeros((3, 4, 4), np.uint8)
    rgba[..., :3], rgba[..., 3] = 255, 7
    iio.imwrite(tmp_path / "rgba.png", rgba)
    np.testing.assert_allclose(load_image(tmp_path / "rgba.png", space="linear"), np.ones((3, 4, 3)))
    gray = np.full((3, 4), 65535 // 5, np.uint16)
    iio.imwrite(tmp_path / "gray.png", gray)
    np.testing.assert_allclose(load_image(tmp_path / "gray.png", space="linear", exposure=2.0),
                               np.full((3, 4, 3), 0.1), rtol=1e-4)


@pytest.mark.parametrize("suffix", [".jpg", ".png"])
def test_load_image_applies_the_exif_orientation(tmp_path, suffix):
    # a phone stores a portrait photo sideways with EXIF orientation 6 (turn 90 deg clockwise
    # to display it): it was read sideways, 2 x 4 instead of the displayed 4 x 2
    from PIL import Image

    stored = np.zeros((2, 4, 3), np.uint8)
    stored[0, 0] = 255  # top-left as stored: top-right once turned clockwise
    image = Image.fromarray(stored)
    exif = image.getexif()
    exif[0x0112] = 6  # Orientation
    image.save(tmp_path / f"photo{suffix}", exif=exif.tobytes(), **({"quality": 100} if suffix == ".jpg" else {}))
    for display in (load_image(tmp_path / f"photo{suffix}", space="linear"),
                    images.load_display(tmp_path / f"photo{suffix}").values):
        assert display.shape == (4, 2, 3)
        assert display[0, 1].min() > 0.9 and display[0, 0].max() < 0.1 and display[3].max() < 0.1


def test_unreadable_image_is_reported_by_name(tmp_path):
    path = tmp_path / "photo.png"
    path.write_bytes(b"definitely not a png")
    with pytest.raises(FileFormatError, match=r"photo\.png"):
        load_image(path)
    with pytest.raises(MissingFileError, match=r"nothing\.jpg"):
        load_image(tmp_path / "nothing.jpg")
    with pytest.raises(ValueError, match="display space"):
        load_image(path, space="aces")


def test_gif_video_loads_as_linear_frames(tmp_path):
    palette = np.array([[0, 0, 0], [255, 0, 0], [0, 128, 255], [10, 200, 30], [255, 255, 255]], np.uint8)
    frames = palette[np.random.default_rng(15).integers(0, len(palette), (3, 5, 7))]
    iio.imwrite(tmp_path / "clip.gif", frames, loop=0, duration=100)
    video = load_video(tmp_path / "clip.gif", space="linear")
    assert video.shape == (3, 5, 7, 3) and video.dtype == np.float32
    np.testing.assert_allclose(video, frames / 255.0, atol=1e-6)
    srgb = load_video(tmp_path / "clip.gif")  # default: sRGB-encoded display values
    np.testing.assert_allclose(srgb[frames == 128], 0.2158605, rtol=1e-4)  # sRGB decode of 128/255
    with pytest.raises(FileFormatError, match="an animation of 3 frames, not one image: read it with load_video"):
        load_image(tmp_path / "clip.gif")


def test_video_without_a_plugin_says_what_to_install(tmp_path, monkeypatch):
    path = tmp_path / "clip.mp4"
    path.write_bytes(b"\x00" * 64)
    monkeypatch.setattr(images, "_video_plugin_available", lambda: False)
    with pytest.raises(ImportError, match=r"clip\.mp4.*pip install 'imageio\[pyav\]'"):
        load_video(path)


def test_save_png_refuses_nan_and_bad_shapes(tmp_path):
    with pytest.raises(InvalidValueError, match="linear_image"):
        save_png(tmp_path / "p.png", np.full((2, 2, 3), np.nan))
    with pytest.raises(ValueError, match="H, W, 3"):
        save_png(tmp_path / "p.png", np.zeros((2, 2)))
    with pytest.raises(ValueError, match=r"save_png writes PNG files; name the file \.png"):
        save_png(tmp_path / "p.jpg", np.zeros((2, 2, 3)))  # PNG bytes in a .jpg file before
    assert os.listdir(tmp_path) == []


def test_cmyk_jpeg_loads_as_its_rgb(tmp_path):
    from PIL import Image

    rgb = np.zeros((8, 8, 3), np.uint8)
    rgb[..., 0], rgb[..., 2] = 200, 30
    Image.fromarray(rgb).convert("CMYK").save(tmp_path / "cmyk.jpg", quality=100)
    # its four channels C, M, Y, K were read as R, G, B, alpha before: (0, 0.78, 0.88)
    np.testing.assert_allclose(images.load_display(tmp_path / "cmyk.jpg").values, rgb / 255.0, atol=2 / 255)


def test_float_and_signed_pixels_outside_the_display_range_are_refused(tmp_path):
    from PIL import Image

    Image.fromarray(np.full((4, 4), 0.25, np.float32), mode="F").save(tmp_path / "ok.tif")
    assert np.all(images.load_display(tmp_path / "ok.tif").values == 0.25)
    Image.fromarray(np.full((4, 4), 2.5, np.float32), mode="F").save(tmp_path / "radiance.tif")
    with pytest.raises(FileFormatError, match=r"radiance\.tif: float pixels must be display values in \[0, 1\]; "
                                              r"this file holds \[2\.5, 2\.5\]"):
        images.load_display(tmp_path / "radiance.tif")
    Image.fromarray(np.full((4, 4), 300, np.int32), mode="I").save(tmp_path / "signed.tif")
    with pytest.raises(FileFormatError, match=r"signed\.tif: unsupported pixel type int32"):
        images.load_display(tmp_path / "signed.tif")  # scaled by 2^31 - 1 to black before


def test_converged_flag_round_trips_and_older_files_read_none(tmp_path):
    # Geometry.converged (False where a ray's hit is not exact) is a 0/1 channel; a file
    # without it (older, or written without the flag) reads with converged None, silently
    image, geometry = random_frame(5)
    converged = np.random.default_rng(5).random((H, W)) > 0.25
    path = write_frame(tmp_path / "f.exr", image, geometry._replace(converged=converged))
    raw = OpenEXR.File(str(path), separate_channels=True).channels()
    assert raw[exr.CONVERGED_CHANNEL].pixels.dtype == np.float16  # 0 / 1 exact in half
    frame = read_frame(path)
    assert frame.converged.dtype == bool
    np.testing.assert_array_equal(frame.converged, converged)
    old = read_frame(write_frame(tmp_path / "old.exr", image, geometry))  # converged None: no channel
    assert exr.CONVERGED_CHANNEL not in OpenEXR.File(str(tmp_path / "old.exr"), separate_channels=True).channels()
    assert old.converged is None and old.slope_variance is not None  # no warning (they are errors here)
    with pytest.raises(InvalidValueError, match="converged must be bool or 0/1"):
        write_frame(tmp_path / "bad.exr", image, geometry._replace(converged=converged * 0.5))
    with pytest.raises(ValueError, match="geometry.converged must have shape"):
        write_frame(tmp_path / "bad.exr", image, geometry._replace(converged=converged[:, :3]))
    rgb = {name: image[..., c].copy() for c, name in enumerate(exr.RGB_CHANNELS)}
    write_raw_exr(tmp_path / "flag_only.exr", rgb | {exr.CONVERGED_CHANNEL: converged.astype(np.float32)})
    with pytest.raises(exr.FrameError, match="flag_only.exr: incomplete geometry: has 'converged'"):
        read_frame(tmp_path / "flag_only.exr")


def test_rendered_frame_keeps_its_converged_flags(tmp_path):
    # a view whose grazing rays have no unique hit: the flags written are the flags read
    from jaxocean import render
    from jaxocean.waves import GRAVITY

    rng = np.random.default_rng(0)
    om = rng.uniform(1.0, 3.5, 12)
    waves = make_waves(rng.uniform(0.05, 0.3, 12) / (om**2 / GRAVITY) / np.sqrt(3), om,
                       rng.uniform(-np.pi, np.pi, 12), rng.uniform(0, 2 * np.pi, 12))
    cam = make_camera(height=8.0, pitch=0.35, fov=0.87, resolution=(32, 40))
    image, geo = render.render(waves, cam, make_lighting(), 1.3, with_geometry=True)
    flagged = np.asarray(geo.mask) & ~np.asarray(geo.converged)
    assert flagged.any()
    frame = read_frame(write_frame(tmp_path / "f.exr", image, geo))
    np.testing.assert_array_equal(frame.converged, np.asarray(geo.converged))
