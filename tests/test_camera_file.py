"""jaxocean.io.camera_file: reading, validating, subsetting and writing camera files.

Every test builds its own small camera file (and frame files) in tmp_path."""

import copy
import json
import math

import numpy as np
import pytest

from jaxocean.errors import InvalidValueError
from jaxocean.io.camera_file import (
    CameraFile,
    CameraFileError,
    camera_file_to_dict,
    read_camera_file,
    select,
    write_camera_file,
)
from jaxocean.io.exr import FileFormatError, MissingFileError
from jaxocean.lens import Distortion, Intrinsics

N_FRAMES = 5


def _camera_dict(n=N_FRAMES):
    frames = [
        {"file": f"frames/frame_{k:04d}.png", "index": 10 + k, "t": 0.2 * k,
         "camera_height_m": 12.0 + 0.1 * k, "pitch_rad": 0.30 + 0.01 * k, "roll_rad": -0.02 + 0.01 * k,
         "yaw_rad": 1.0 + 0.001 * k, "ship_east_m": 0.15 * k, "ship_north_m": -0.04 * k}
        for k in range(n)
    ]
    return {
        "source": "a test", "license": "none", "notes": "synthetic",
        "units": {"length": "m", "angle": "rad", "time": "s", "pixel": "px"},
        "image_size": [64, 48],
        "intrinsics": {"fx": 40.0, "fy": 40.5, "cx": 31.5, "cy": 23.5},
        "distortion": {"model": "brown-conrady", "k1": -0.2, "k2": 0.06, "p1": 0.0, "p2": 0.0},
        "frame_rate_hz": 5.0,
        "t0_utc": "2000-01-01T00:00:00Z",
        "frames": frames,
        "pose_uncertainty_1sigma": {"pitch_rad": 0.002},
    }


def _write(folder, data, *, make_frames=True):
    folder.mkdir(parents=True, exist_ok=True)
    if make_frames:
        for frame in data.get("frames", []):
            if isinstance(frame, dict) and isinstance(frame.get("file"), str):
                file = folder / frame["file"]
                file.parent.mkdir(parents=True, exist_ok=True)
                file.write_bytes(b"not really a png")
    path = folder / "camera.json"
    path.write_text(json.dumps(data))
    return path


def test_read_valid_file(tmp_path):
    path = _write(tmp_path / "clip", _camera_dict())
    cf = read_camera_file(path)
    assert isinstance(cf, CameraFile)
    assert cf.path == path and cf.image_size == (64, 48) and cf.headings
    assert cf.intrinsics == Intrinsics(40.0, 40.5, 31.5, 23.5)
    assert cf.distortion == Distortion(-0.2, 0.06, 0.0, 0.0)
    assert all(f.is_absolute() and f.is_file() for f in cf.files)
    assert cf.files[3] == (tmp_path / "clip" / "frames" / "frame_0003.png").resolve()
    np.testing.assert_allclose(cf.times, 0.2 * np.arange(N_FRAMES))
    assert cf.times.dtype == np.float64
    np.testing.assert_allclose(cf.poses.height, 12.0 + 0.1 * np.arange(N_FRAMES))
    np.testing.assert_allclose(cf.poses.heading, 1.0 + 0.001 * np.arange(N_FRAMES))
    np.testing.assert_allclose(cf.poses.north, -0.04 * np.arange(N_FRAMES))
    assert all(leaf.shape == (N_FRAMES,) and leaf.dtype == np.float64 for leaf in cf.poses)
    # unknown keys are kept, not interpreted
    assert cf.extra["notes"] == "synthetic" and cf.extra["pose_uncertainty_1sigma"] == {"pitch_rad": 0.002}
    assert cf.frame_extra[2] == {"index": 12}
    # a folder means its camera.json
    assert read_camera_file(tmp_path / "clip").files == cf.files


def test_coefficients_fixed_at_zero_are_accepted(tmp_path):
    data = _camera_dict()
    data["distortion"]["k3"] = 0.0
    data["intrinsics"]["skew"] = 0
    read = read_camera_file(_write(tmp_path / "a", data))
    assert read.distortion == Distortion(-0.2, 0.06, 0.0, 0.0)
    assert read.intrinsics == Intrinsics(40.0, 40.5, 31.5, 23.5)


def test_optional_parts(tmp_path):
    data = _camera_dict()
    del data["distortion"], data["units"]
    for frame in data["frames"]:
        del frame["ship_east_m"], frame["ship_north_m"], frame["t"]
    cf = read_camera_file(_write(tmp_path, data))
    assert cf.distortion == Distortion()
    np.testing.assert_array_equal(cf.poses.east, 0.0)
    np.testing.assert_allclose(cf.times, np.arange(N_FRAMES) / 5.0)  # from frame_rate_hz


def test_no_pose(tmp_path):
    data = _camera_dict()
    for frame in data["frames"]:
        for name in ("camera_height_m", "pitch_rad", "roll_rad", "yaw_rad", "ship_east_m", "ship_north_m"):
            del frame[name]
    path = _write(tmp_path, data)
    assert read_camera_file(path, require_pose=False).poses is None
    with pytest.raises(CameraFileError, match=r"frames\[0\]\.camera_height_m: missing: no frame gives a pose"):
        read_camera_file(path)


def _error_cases():
    def edit(fn):
        data = _camera_dict()
        fn(data)
        return data

    def set_frame(k, key, value):
        return lambda d: d["frames"][k].__setitem__(key, value)

    def delete(*keys):
        def fn(d):
            target = d
            for key in keys[:-1]:
                target = target[key]
            del target[keys[-1]]
        return fn

    return [
        ("missing image_size", edit(delete("image_size")), r"image_size: missing"),
        ("bad image_size", edit(lambda d: d.__setitem__("image_size", [64.0, 48])), r"image_size: must be two positive"),
        ("missing intrinsics", edit(delete("intrinsics")), r"intrinsics: missing"),
        ("missing fy", edit(delete("intrinsics", "fy")), r"intrinsics\.fy: missing"),
        ("string cx", edit(lambda d: d["intrinsics"].__setitem__("cx", "31.5")), r"intrinsics\.cx: must be a number; got a string"),
        ("fx <= 0", edit(lambda d: d["intrinsics"].__setitem__("fx", 0.0)), r"intrinsics\.fx: focal length must be > 0"),
        ("fy < 0", edit(lambda d: d["intrinsics"].__setitem__("fy", -3.0)), r"intrinsics\.fy: focal length must be > 0"),
        ("normalised fx", edit(lambda d: d["intrinsics"].__setitem__("fx", 0.9)),
         r"intrinsics\.fx: 0\.9 px gives a field of view of 17\d\.\d deg .* not normalised"),
        ("principal point outside", edit(lambda d: d["intrinsics"].__setitem__("cy", 480.0)),
         r"intrinsics\.cy: the principal point must lie inside the image, in \[-0\.5, 47\.5\] px .*got 480\.0"),
        # the radial terms fold back at r = 0.577 (r_d = 0.385), short of the corners at 0.996:
        # the outer pixels have no ray, and the horizon and the view's lowest ray came out wrong
        ("lens not one-to-one", edit(lambda d: d["distortion"].update(k1=-1.0, k2=0.0)),
         r"distortion: k1 = -1, k2 = 0 is not one-to-one over the image: .* folds back at the undistorted radius "
         r"0\.57[67], where it reaches 0\.385, and the image's farthest corner lies at 0\.996"),
        ("roll in degrees", edit(set_frame(2, "roll_rad", 3.0)), r"frames\[2\]\.roll_rad: must lie in \(-pi/2, pi/2\) rad; got 3\.0"),
        ("unknown model", edit(lambda d: d["distortion"].__setitem__("model", "fisheye")),
         r"distortion\.model: unknown distortion model 'fisheye'"),
        ("k3 not modelled", edit(lambda d: d["distortion"].__setitem__("k3", 0.5)),
         r"distortion\.k3: the lens model has no 'k3' term .*got 0\.5"),
        ("skew not modelled", edit(lambda d: d["intrinsics"].__setitem__("skew", 0.1)),
         r"intrinsics\.skew: the lens model has no 'skew' term"),
        ("unknown lens field", edit(lambda d: d["distortion"].__setitem__("k_1", 0.1)),
         r"distortion\.k_1: unknown field; distortion holds model, k1, k2, p1, p2"),
        ("bool k1", edit(lambda d: d["distortion"].__setitem__("k1", True)), r"distortion\.k1: must be a number; got a boolean"),
        ("degrees", edit(lambda d: d["units"].__setitem__("angle", "deg")), r"units\.angle: must be 'rad'"),
        ("missing frames", edit(delete("frames")), r"frames: missing"),
        ("empty frames", edit(lambda d: d.__setitem__("frames", [])), r"frames: must be a non-empty array"),
        ("frame not object", edit(lambda d: d["frames"].__setitem__(1, 3)), r"frames\[1\]: must be a JSON object"),
        ("missing file", edit(delete("frames", 2, "file")), r"frames\[2\]\.file: missing"),
        ("missing t", edit(delete("frames", 2, "t")), r"frames\[2\]\.t: missing"),
        # one image at two times (a pose of another frame for it, when frames are given) passed
        ("file listed twice", edit(set_frame(3, "file", "frames/../frames/frame_0001.png")),
         r"frames\[3\]\.file: 'frames/\.\./frames/frame_0001\.png' is frames\[1\]'s file too"),
        ("null t", edit(set_frame(1, "t", None)), r"frames\[1\]\.t: must be a number; got null"),
        ("equal times", edit(set_frame(3, "t", 0.4)), r"frames\[3\]\.t: frame times must increase strictly"),
        ("decreasing times", edit(set_frame(4, "t", 0.1)), r"frames\[4\]\.t: frame times must increase strictly"),
        ("pitch too large", edit(set_frame(3, "pitch_rad", 1.7)), r"frames\[3\]\.pitch_rad: must lie in \(-pi/2, pi/2\) rad; got 1\.7"),
        ("pitch = pi/2", edit(set_frame(0, "pitch_rad", math.pi / 2)), r"frames\[0\]\.pitch_rad: must lie in"),
        ("pitch too small", edit(set_frame(2, "pitch_rad", -1.6)), r"frames\[2\]\.pitch_rad: must lie in"),
        ("height 0", edit(set_frame(1, "camera_height_m", 0.0)), r"frames\[1\]\.camera_height_m: the camera must be above"),
        ("height < 0", edit(set_frame(4, "camera_height_m", -2.0)), r"frames\[4\]\.camera_height_m: the camera must be above"),
        ("missing roll", edit(delete("frames", 3, "roll_rad")), r"frames\[3\]\.roll_rad: missing \(other frames"),
        ("pose on some frames", edit(lambda d: [d["frames"][k].pop(name) for k in (1, 2)
                                                 for name in ("camera_height_m", "pitch_rad", "roll_rad", "yaw_rad")]),
         r"frames\[1\]\.camera_height_m: missing \(other frames"),
        ("offset on some frames", edit(delete("frames", 4, "ship_north_m")), r"frames\[4\]\.ship_north_m: missing"),
        ("string yaw", edit(set_frame(2, "yaw_rad", "1.0")), r"frames\[2\]\.yaw_rad: must be a number"),
        # a compass heading in degrees passed for radians: 270 rad is a valid angle, 3.0 rad off
        ("heading in degrees", edit(set_frame(2, "yaw_rad", 270.0)),
         r"frames\[2\]\.yaw_rad: a heading must lie in \[-2pi, 2pi\] rad \(degrees\?\); got 270\.0"),
        ("frame_rate <= 0", edit(lambda d: d.__setitem__("frame_rate_hz", 0)), r"frame_rate_hz: must be > 0"),
        ("frame_rate against times", edit(lambda d: d.__setitem__("frame_rate_hz", 100.0)),
         r"frame_rate_hz: 100\.0 Hz disagrees with the frames' times \(mean step 0\.2 s, 5 Hz\)"),
    ]


@pytest.mark.parametrize("name, data, pattern", _error_cases(), ids=[case[0] for case in _error_cases()])
def test_errors_name_the_file_and_the_field(tmp_path, name, data, pattern):
    path = _write(tmp_path, data)
    with pytest.raises(CameraFileError, match=pattern) as info:
        read_camera_file(path)
    assert str(info.value).startswith(str(path) + ": ")
    assert isinstance(info.value, FileFormatError) and isinstance(info.value, InvalidValueError)


def test_non_finite_values(tmp_path):
    # strict JSON has no NaN, but Python's json writes and reads it: it must be refused
    data = _camera_dict()
    data["frames"][2]["roll_rad"] = float("nan")
    with pytest.raises(CameraFileError, match=r"frames\[2\]\.roll_rad: must be finite; got nan"):
        read_camera_file(_write(tmp_path / "a", data))
    data = _camera_dict()
    data["intrinsics"]["cy"] = float("inf")
    with pytest.raises(CameraFileError, match=r"intrinsics\.cy: must be finite"):
        read_camera_file(_write(tmp_path / "b", data))


def test_integers_beyond_the_float_range(tmp_path):
    # JSON integers are unbounded: one too large for a float is refused like inf, naming the
    # field (it raised OverflowError), and one too long for Python to parse names the file
    data = _camera_dict()
    data["frames"][1]["camera_height_m"] = 10**400
    with pytest.raises(CameraFileError, match=r"frames\[1\]\.camera_height_m: must be finite; got an integer"):
        read_camera_file(_write(tmp_path / "a", data))
    path = _write(tmp_path / "b", _camera_dict())
    path.write_text(path.read_text().replace('"fx": 40.0', '"fx": ' + "9" * 5000))
    with pytest.raises(CameraFileError, match="malformed JSON") as info:
        read_camera_file(path)
    assert str(info.value).startswith(str(path) + ": ")


def test_frames_absent_on_disk(tmp_path):
    path = _write(tmp_path, _camera_dict())
    (tmp_path / "frames" / "frame_0003.png").unlink()
    with pytest.raises(CameraFileError, match=r"frames\[3\]\.file: no such frame file .*frame_0003\.png"):
        read_camera_file(path)
    assert len(read_camera_file(path, check_files=False).files) == N_FRAMES


def test_missing_and_malformed_files(tmp_path):
    with pytest.raises(MissingFileError, match="no such camera file"):
        read_camera_file(tmp_path / "nothing.json")
    bad = tmp_path / "camera.json"
    bad.write_text('{"image_size": [64, 48],')
    with pytest.raises(CameraFileError, match="malformed JSON"):
        read_camera_file(bad)
    bad.write_text("[1, 2]")
    with pytest.raises(CameraFileError, match="top level: must be a JSON object"):
        read_camera_file(bad)


def test_write_read_round_trip(tmp_path):
    cf = read_camera_file(_write(tmp_path / "src", _camera_dict()))
    out = write_camera_file(tmp_path / "elsewhere" / "camera.json", cf)
    back = read_camera_file(out)
    assert back.files == cf.files  # relative paths point at the same frames
    assert back.image_size == cf.image_size and back.intrinsics == cf.intrinsics and back.distortion == cf.distortion
    np.testing.assert_array_equal(back.times, cf.times)
    for a, b in zip(back.poses, cf.poses):
        np.testing.assert_array_equal(a, b)  # exact float64
    assert back.extra == cf.extra and back.frame_extra == cf.frame_extra
    written = json.loads(out.read_text())
    assert written["frame_rate_hz"] == pytest.approx(5.0)
    assert written["frames"][0]["file"] == "../src/frames/frame_0000.png"
    assert written["units"]["angle"] == "rad"


def test_select(tmp_path):
    cf = read_camera_file(_write(tmp_path / "src", _camera_dict()))
    sub = select(cf, slice(1, None, 2))
    assert sub.files == (cf.files[1], cf.files[3])
    np.testing.assert_array_equal(sub.times, cf.times[[1, 3]])
    np.testing.assert_array_equal(sub.poses.pitch, cf.poses.pitch[[1, 3]])
    assert sub.frame_extra == ({"index": 11}, {"index": 13})
    mask = np.array([True, False, False, True, True])
    assert select(cf, mask).files == tuple(cf.files[k] for k in (0, 3, 4))
    # written, a subset gets the frame rate of its own spacing, or none when uneven
    written = json.loads(write_camera_file(tmp_path / "sub.json", sub).read_text())
    assert written["frame_rate_hz"] == pytest.approx(2.5)
    written = json.loads(write_camera_file(tmp_path / "uneven.json", select(cf, [0, 1, 3])).read_text())
    assert "frame_rate_hz" not in written
    with pytest.raises(ValueError, match="increase strictly"):
        select(cf, [3, 1])
    with pytest.raises(ValueError, match="out of range"):
        select(cf, [0, 7])
    with pytest.raises(ValueError, match="no frames"):
        select(cf, [])


def test_to_dict_is_readable_again(tmp_path):
    cf = read_camera_file(_write(tmp_path, _camera_dict()))
    data = camera_file_to_dict(cf, tmp_path)
    mutated = copy.deepcopy(data)
    mutated["frames"][0]["pitch_rad"] = 2.0
    with pytest.raises(CameraFileError, match=r"frames\[0\]\.pitch_rad"):
        read_camera_file(_write(tmp_path / "m", mutated | {"frames": [
            {**fr, "file": "../" + fr["file"]} for fr in mutated["frames"]]}, make_frames=False))


def test_make_real_clip_script(tmp_path):
    import importlib.util
    from pathlib import Path

    script = Path(__file__).resolve().parents[1] / "experiments" / "make_real_clip.py"
    spec = importlib.util.spec_from_file_location("make_real_clip", script)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    src = tmp_path / "src"
    _write(src, _camera_dict())
    (src / "LICENSE.md").write_text("licence text")
    (src / "frames" / "frame_0003.png").write_bytes(b"frame three")
    path = module.make_clip(src, tmp_path / "clip", start=1, every=2, frames=2)
    clip = read_camera_file(path)
    assert [f.name for f in clip.files] == ["frame_0001.png", "frame_0003.png"]
    assert all(f.parent == (tmp_path / "clip" / "frames").resolve() for f in clip.files)
    assert clip.files[1].read_bytes() == b"frame three"  # copied unchanged
    np.testing.assert_array_equal(clip.times, [0.2 * 1, 0.2 * 3])  # as the source wrote them
    assert clip.frame_extra == ({"index": 11}, {"index": 13})
    assert (tmp_path / "clip" / "LICENSE.md").read_text() == "licence text"
    assert json.loads(path.read_text())["frame_rate_hz"] == pytest.approx(2.5)
    with pytest.raises(SystemExit, match="exists"):
        module.make_clip(src, tmp_path / "clip", start=1, every=2, frames=2)
    with pytest.raises(SystemExit, match="the sequence has 5"):
        module.make_clip(src, tmp_path / "other", start=1, every=2, frames=3)
