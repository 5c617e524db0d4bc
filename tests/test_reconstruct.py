"""jaxocean.reconstruct and the `reconstruct` command: stage 1 on synthetic and real frames,
the result file's contract, conventions and input errors; a 2-frame end-to-end run."""

import dataclasses
import json
import math
from pathlib import Path
from types import SimpleNamespace

import jax.numpy as jnp
import numpy as np
import pytest

import jaxocean as jo
from jaxocean import camera as cam
from jaxocean import footage
from jaxocean import lens
from jaxocean import reconstruct as rc
from jaxocean import render
from jaxocean.errors import InvalidValueError
from jaxocean.io import camera_file as cf
from jaxocean.io.images import save_png
from jaxocean.io.scene import scene_to_dict, write_scene

CLIP = Path(__file__).resolve().parents[1] / "experiments" / "data" / "ship_pacific_2014_clip"


def _scene(tmp_path, *, res=32, frames=2):
    waves = jo.make_waves([0.05, 0.03], [2.5, 3.2], [0.3, 1.1], [0.0, 1.0])
    camera = cam.make_camera(height=8.0, pitch=0.7, fov=0.8, resolution=(res, res))
    light = jo.make_lighting(sun_azimuth=2.5, sun_elevation=0.5)
    times = np.arange(frames) * 0.25
    files = [save_png(tmp_path / f"frame_{i:05d}.png", np.asarray(render.render(waves, camera, light, t)))
             for i, t in enumerate(times)]
    scene_json = write_scene(tmp_path, scene_to_dict(camera=camera, times=times))
    return files, scene_json, camera, times


def test_direction_conventions():
    # travelling toward +y (north): 0 deg from north, 90 deg counter-clockwise from +x
    assert rc.direction_deg(math.pi / 2, compass=True) == pytest.approx(0.0)
    assert rc.direction_deg(math.pi / 2, compass=False) == pytest.approx(90.0)
    # toward +x (east): 90 deg clockwise from north
    assert rc.direction_deg(0.0, compass=True) == pytest.approx(90.0)
    assert rc.direction_deg(-math.pi / 2, compass=False) == pytest.approx(270.0)


@pytest.mark.slow  # loads and rectifies a rendered sequence
def test_scene_sequence_keeps_the_scene_camera(tmp_path):
    files, scene_json, camera, times = _scene(tmp_path)
    seq, rep = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    assert rep.success and rep.name == "radiometry"
    assert seq.camera.resolution == (32, 32)
    assert float(seq.camera.pitch) == pytest.approx(float(camera.pitch))
    np.testing.assert_allclose(seq.times, times)
    # the rectification into the scene's own camera is the identity up to interpolation
    truth = np.asarray(render.render(jo.make_waves([0.05, 0.03], [2.5, 3.2], [0.3, 1.1], [0.0, 1.0]), camera,
                                     jo.make_lighting(sun_azimuth=2.5, sun_elevation=0.5), times[0]))
    sea = np.asarray(cam.intersect_sea(camera).mask) & seq.usable[0]
    rel = np.abs(seq.images[0] - truth)[sea] / np.maximum(truth[sea], 1e-3)
    assert np.median(rel) < 0.02  # 8-bit quantisation of the tone-mapped value


def test_scene_view_at_a_wider_working_aspect_stays_inside_the_frames(tmp_path):
    # a 32 x 48 scene at the working width 32 is worked on at 16 x 32: with the scene's
    # vertical field of view kept, a quarter of the view's columns lay outside every frame
    camera = cam.make_camera(height=8.0, pitch=0.5, fov=0.6, resolution=(32, 48))
    times = np.arange(2) * 0.25
    files = [save_png(tmp_path / f"frame_{i:05d}.png", np.full((32, 48, 3), 0.2, np.float32)) for i in range(2)]
    scene_json = write_scene(tmp_path, scene_to_dict(camera=camera, times=times))
    seq, rep = rc.load_sequence(files, scene_json, width=32, response="bruneton", evidence_width=None)
    assert seq.camera.resolution == (16, 32) and float(seq.camera.pitch) == pytest.approx(0.5)
    # the horizontal field of view is the scene's, the vertical one narrower
    assert math.tan(float(seq.camera.fov) / 2) * 2 == pytest.approx(math.tan(0.3) * 48 / 32, rel=1e-5)
    assert rep.success and seq.usable.all()


def test_frames_must_match_the_camera_file(tmp_path):
    files, scene_json, camera, _ = _scene(tmp_path)
    with pytest.raises(InvalidValueError, match="2 times"):
        rc.load_sequence(files[:1] * 3, scene_json)
    # a scene's times pair with the frames in the order given: not backwards, not a still
    with pytest.raises(InvalidValueError, match="in the order of the times"):
        rc.load_sequence(files[::-1], scene_json)
    with pytest.raises(InvalidValueError, match="a frame is given twice"):
        rc.load_sequence(files[:1] * 2, scene_json)
    # a scene whose times do not increase is named with its field (was camera_file.select's
    # "the selected frames' times must increase strictly", naming no file)
    backwards = tmp_path / "backwards"
    write_scene(backwards, scene_to_dict(camera=camera, times=[0.5, 0.25]))
    with pytest.raises(InvalidValueError, match=r"backwards/scene\.json: times\[1\]: .* must increase strictly; got "
                                                r"0\.25 after 0\.5"):
        rc.load_sequence(files, backwards)
    # the Python entry point checks its output before minutes of work, as the command does
    (tmp_path / "a_file").write_text("")
    with pytest.raises(ValueError, match="exists and is not a directory"):
        rc.reconstruct(files, scene_json, out=tmp_path / "a_file")
    with pytest.raises(ValueError, match="step"):
        rc.load_sequence(files, scene_json, step=0)
    # not an index error from the camera file's select, and not the last frame sliced off
    with pytest.raises(ValueError, match=r"step must be an int >= 1; got 1\.5"):
        rc.load_sequence(files, scene_json, step=1.5)
    for count in (-1, 0, 2.0):
        with pytest.raises(ValueError, match=r"max_frames must be an int >= 1 .*got " + repr(count)):
            rc.load_sequence(files, scene_json, max_frames=count)


def test_scene_frames_are_ordered_by_their_numbers(tmp_path):
    # frame_2 comes before frame_10 (the names compared as text put frame_10 first, which is
    # the order a shell's frame_* gives: it was taken for time order, frame_10 at t = 0.5)
    camera = cam.make_camera(height=8.0, pitch=0.5, fov=0.6, resolution=(16, 16))
    named = [save_png(tmp_path / f"frame_{i}.png", np.full((16, 16, 3), 0.2, np.float32)) for i in range(11)]
    scene_json = write_scene(tmp_path, scene_to_dict(camera=camera, times=np.arange(11) * 0.25))
    by_text = sorted(named, key=lambda f: f.name)
    with pytest.raises(InvalidValueError, match="in the order of the times"):
        rc.load_sequence(by_text, scene_json, width=16, response="bruneton", evidence_width=None)
    seq, _ = rc.load_sequence(named, scene_json, width=16, response="bruneton", evidence_width=None)
    assert seq.files == tuple(str(f) for f in named)


def _camera_file(tmp_path, files, camera, times, *, pose: bool):
    fy = (camera.resolution[0] / 2) / math.tan(float(camera.fov) / 2)
    H, W = camera.resolution
    frames = [dict({"file": Path(f).name, "t": float(t)},
                   **({"camera_height_m": float(camera.height), "pitch_rad": float(camera.pitch), "roll_rad": 0.0,
                       "yaw_rad": 0.0} if pose else {})) for f, t in zip(files, times)]
    path = tmp_path / "camera.json"
    path.write_text(json.dumps({"image_size": [W, H], "intrinsics": {"fx": fy, "fy": fy, "cx": (W - 1) / 2,
                                                                     "cy": (H - 1) / 2}, "frames": frames}))
    return path


def test_camera_height_only_without_poses(tmp_path):
    # a camera height given beside a pose (or a scene's camera) is refused, not silently ignored
    files, scene_json, camera, times = _scene(tmp_path)
    with pytest.raises(InvalidValueError, match="applies only to a camera file without poses"):
        rc.load_sequence(files, scene_json, width=32, height=30.0)
    posed = _camera_file(tmp_path, files, camera, times, pose=True)
    with pytest.raises(InvalidValueError, match="applies only to a camera file without poses"):
        rc.load_sequence([], posed, width=32, height=30.0)
    # a file without poses and no height: the error says what to give
    bare = _camera_file(tmp_path, files, camera, times, pose=False)
    with pytest.raises(cf.CameraFileError, match=r"no frame gives a pose .*--camera-height"):
        rc.load_sequence([], bare, width=32)


@pytest.mark.slow  # rectifies the real clip's frames
@pytest.mark.skipif(not CLIP.exists(), reason="the real clip is not in this checkout")
def test_sea_view_of_real_footage_lies_inside_every_frame():
    camera_file = cf.read_camera_file(CLIP / "camera.json")
    view = rc.sea_view(camera_file, width=64)
    # top edge below the horizon by the margin, the source's aspect
    assert float(view.pitch) - float(view.fov) / 2 == pytest.approx(footage.HORIZON_MARGIN, abs=1e-6)
    assert view.resolution == (48, 64)
    heading = lens.heading_from_yaw(float(view.yaw))
    assert math.degrees(float(heading)) % 360 == pytest.approx(57.0, abs=4.0)  # ENE, as the file says
    seq, rep = rc.load_sequence([], CLIP / "camera.json", width=64, max_frames=3)
    assert rep.success, rep.message
    assert seq.gray and seq.compass and seq.images.shape == (3, 48, 64, 3)
    sea = np.asarray(cam.intersect_sea(view).mask)
    assert seq.usable[:, sea].mean() > 0.9


def test_sea_view_of_a_camera_that_sees_no_horizon_lies_inside_every_frame():
    # looking 1 rad down with a 0.9 rad field of view, the frames' top edge lies 0.55 rad
    # below the horizon: the view starts there, not 0.05 rad below the horizon (its top 40 %
    # was seen by no frame, and 54 % of the sea still passed for usable)
    fy, H, W = 40.0, 38, 48
    pitch = np.array([1.0, 1.02, 0.98])
    poses = lens.Pose(np.full(3, 10.0), pitch, np.zeros(3), np.full(3, 0.3), np.zeros(3), np.zeros(3))
    camera_file = cf.CameraFile(Path("camera.json"), (W, H), lens.Intrinsics(fy, fy, (W - 1) / 2, (H - 1) / 2),
                                lens.Distortion(), ("a.png",) * 3, np.arange(3.0), poses)
    view = rc.sea_view(camera_file, width=32)
    highest = float(np.max(pitch)) - math.atan((H - 1) / 2 / fy)  # the lowest top edge of the frames
    lowest = float(np.min(pitch)) + math.atan((H - 1) / 2 / fy)
    top, bottom = float(view.pitch) - float(view.fov) / 2, float(view.pitch) + float(view.fov) / 2
    assert top == pytest.approx(highest + footage.BOTTOM_MARGIN, abs=1e-5)
    assert bottom == pytest.approx(lowest - footage.BOTTOM_MARGIN, abs=1e-5)
    # a frame that sees the horizon keeps the view's top just below it
    level = camera_file._replace(poses=poses._replace(pitch=pitch - 0.6))
    view = rc.sea_view(level, width=32)
    assert float(view.pitch) - float(view.fov) / 2 == pytest.approx(footage.HORIZON_MARGIN, abs=1e-6)


@pytest.mark.skipif(not CLIP.exists(), reason="the real clip is not in this checkout")
def test_unlisted_frame_is_refused(tmp_path):
    stray = tmp_path / "frame_9999.png"
    stray.write_bytes((CLIP / "frames" / "frame_0000.png").read_bytes())
    with pytest.raises(InvalidValueError, match="not listed"):
        rc.load_sequence([stray], CLIP / "camera.json")


def test_frames_matched_by_name_are_the_ones_read(tmp_path):
    # frames given from another folder pair with the camera file's entries of their names,
    # and are the files read (not the listed files of those names); a video is read as given
    import imageio.v3 as iio

    files, _, camera, times = _scene(tmp_path)
    posed = _camera_file(tmp_path, files, camera, times, pose=True)
    (tmp_path / "gray").mkdir()
    gray = [tmp_path / "gray" / Path(f).name for f in files]
    for f, g in zip(files, gray):
        iio.imwrite(g, iio.imread(f)[..., 0])
    seq, rep = rc.load_sequence(gray, posed, width=32)
    assert rep.success and seq.gray
    assert seq.files == tuple(str(g.resolve()) for g in gray)
    video = tmp_path / "clip.gif"
    iio.imwrite(video, np.stack([iio.imread(f) for f in files]), duration=100, loop=0)
    seq, _ = rc.load_sequence([video], posed, width=32)
    assert seq.files == (str(video.resolve()),) * len(times)
    # the frames given are the ones read: the listed files need not exist (they were refused as
    # missing, though never read)
    for f in files:
        Path(f).unlink()
    seq, rep = rc.load_sequence(gray, posed, width=32, evidence_width=None)
    assert rep.success and seq.files == tuple(str(g.resolve()) for g in gray)
    with pytest.raises(cf.CameraFileError, match=r"frames\[0\]\.file: no such frame file"):
        rc.load_sequence([], posed, width=32)


@pytest.mark.parametrize("channels", ["RGB", "Y"])
def test_non_finite_exr_pixels_are_masked_not_fatal(tmp_path, channels):
    # OpenEXR pixels that are NaN or inf (a half float's overflow) are unusable, as
    # radiometry.load_frames marks them; the display made for the reports raised on them.
    # A grayscale OpenEXR (one Y channel) is gray footage (it was refused for missing R G B)
    import OpenEXR

    camera = cam.make_camera(height=8.0, pitch=0.7, fov=0.8, resolution=(16, 16))
    files, times = [tmp_path / f"frame_{i:05d}.exr" for i in range(2)], np.arange(2) * 0.25
    for i, file in enumerate(files):
        image = np.full((16, 16, 3), 0.2, np.float32)
        image[8, 8 - 4 * i] = (math.nan, math.inf)[i]
        OpenEXR.File({"type": OpenEXR.scanlineimage},
                     {name: np.ascontiguousarray(image[..., c]) for c, name in enumerate(channels)}).write(str(file))
    posed = _camera_file(tmp_path, files, camera, times, pose=True)
    seq, rep = rc.load_sequence(files, posed, width=16, evidence_width=None)
    assert rep.success, rep.message
    assert seq.gray == (channels == "Y") and seq.images.shape == (2, 16, 16, 3)
    assert np.isfinite(seq.images).all() and np.isfinite(seq.display).all()
    assert not seq.usable.all() and seq.usable.mean() > 0.5


def test_exif_rotated_frames_are_read_upright_and_sized_against_the_camera_file(tmp_path):
    # a portrait photo stored sideways (EXIF orientation 6: turn it clockwise to display) is
    # read upright, so the camera file describes the upright image; one describing the stored
    # pixels is refused with the reason
    from PIL import Image

    camera = cam.make_camera(height=8.0, pitch=0.7, fov=0.8, resolution=(32, 16))  # upright: 16 wide, 32 tall
    files, times = [tmp_path / f"frame_{i:05d}.png" for i in range(2)], np.arange(2) * 0.25
    rng = np.random.default_rng(3)
    for file in files:
        upright = rng.integers(60, 200, (32, 16, 3), dtype=np.uint8)
        image = Image.fromarray(np.ascontiguousarray(np.rot90(upright)))  # stored turned counter-clockwise
        exif = image.getexif()
        exif[0x0112] = 6
        image.save(file, exif=exif.tobytes())
    seq, rep = rc.load_sequence(files, _camera_file(tmp_path, files, camera, times, pose=True), width=16,
                                evidence_width=None)
    assert rep.success, rep.message
    sideways = _camera_file(tmp_path, files, dataclasses.replace(camera, resolution=(16, 32)), times, pose=True)
    with pytest.raises(InvalidValueError, match=r"the frames are 16x32 pixels; the camera file .* says 32x16 \(the "
                                                r"frames are read as displayed, their EXIF orientation applied"):
        rc.load_sequence(files, sideways, width=16, evidence_width=None)


@pytest.mark.slow  # the whole pipeline compiles every stage (about 2 min)
def test_reconstruct_command_end_to_end(tmp_path):
    from jaxocean import cli

    files, scene_json, _, _ = _scene(tmp_path / "in")
    out = tmp_path / "out"
    code = cli.main(["reconstruct", *map(str, files), "--camera", str(scene_json), "--out", str(out),
                     "--width", "32", "--response", "bruneton", "--max-waves", "2", "--wave-frames", "2"])
    assert code in (0, 1)
    data = json.loads((out / "result.json").read_text())
    for key in ("hs_m", "tp_s", "direction_deg", "peak_observed", "hs_std_m", "tp_std_s", "direction_std_deg"):
        assert key in data["spectrum"]
    assert data["spectrum"]["success"] is data["stages"]["spectrum"]["success"]
    assert set(data["stages"]) == set(rc.STAGES)
    for stage in data["stages"].values():
        assert isinstance(stage["success"], bool) and stage["seconds"] >= 0
    assert code == (0 if all(s["success"] for s in data["stages"].values()) else 1)
    assert all(w["omega_rad_s"] > 0 and w["amplitude_m"] > 0 for w in data["waves"])
    page = (out / "report.html").read_text()
    # which surface model the wave fit ended on, in the result and on the page
    surface = data["stages"]["waves"]["details"]["surface"]
    assert surface in ("rows", "hits") and f"({surface})" in page
    for figure in ("frames.png", "sea.png", "forecast.png"):
        assert (out / figure).stat().st_size > 0 and figure in page
    # the forecast is the wave fit's least-squares forecast unless the fit found no wave
    found = data["stages"]["waves"]["details"]["n_waves"] > 0
    assert data["stages"]["forecast"]["details"]["forecast"] == ("least-squares (damped)" if found
                                                                  else "as fitted (no wave fit)")
    assert data["waves"] or not found


def test_result_json_lists_no_wave_for_the_flat_sea():
    # the flat sea a failed wave stage hands on (one zero-amplitude stand-in) is no wave of
    # result.json, as it is none of the sea state and of the sea figure
    camera = cam.make_camera(height=8.0, pitch=0.7, fov=0.8, resolution=(16, 16))
    stage = SimpleNamespace(success=False, seconds=0.0, message="no wave found", details={})
    seq = SimpleNamespace(compass=False, camera=camera, times=np.arange(2) * 0.1, files=("a.png", "b.png"))
    result = SimpleNamespace(sequence=seq, stages={"waves": stage, "spectrum": stage},
                             sea={"waves": jo.make_waves([0.0], [1.0], [0.0]), "hs_m": math.nan})
    assert rc.result_dict(result)["waves"] == []
    result.sea["waves"] = jo.make_waves([0.1, 0.0], [1.0, 2.0], [0.0, 0.5])
    assert [w["amplitude_m"] for w in rc.result_dict(result)["waves"]] == pytest.approx([0.1, 0.0])


def test_steep_waves_are_capped_and_reported():
    waves = jo.make_waves([0.5, 0.01], [4.0, 1.0], [0.0, 1.0])
    waves = waves._replace(amplitude=np.asarray([1.5 * 9.81 / 16.0, 0.01], np.float32))  # k h = 1.5, 0.001
    why = []
    capped, count = rc._cap_steepness(waves, why)
    assert count == 1 and "1 of 2 waves steeper" in why[0]
    kh = np.asarray(jo.waves.wavenumber(capped)) * np.asarray(capped.amplitude)
    np.testing.assert_allclose(kh, [rc.MAX_STEEPNESS, 0.01 * 1.0 / 9.81], rtol=1e-5)
    same, none = rc._cap_steepness(jo.make_waves([0.01], [1.0], [0.0]), why)
    assert none == 0 and len(why) == 1


@pytest.mark.slow  # compiles the lighting fit with a stated normal error
def test_lighting_stage_states_the_network_error_and_says_why_it_fails(tmp_path):
    from jaxocean import render as rd

    files, scene_json, _, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    waves = jo.make_waves([0.05, 0.03], [2.5, 3.2], [0.3, 1.1], [0.0, 1.0])
    geos = [rd.geometry(waves, seq.camera, t) for t in times]
    stack = rc._Geo(*(np.stack([np.asarray(getattr(g, f)) for g in geos])
                      for f in ("normal", "roughness", "slope_variance", "mask")))
    result, rep = rc.lighting_stage(seq, stack, overcast=False)
    assert rep.details["normal_noise_rad"] == rc.GEOMETRY_NOISE
    assert rep.details["normal_correlation_px"] == pytest.approx(rc.GEOMETRY_CORRELATION * 32)
    assert rep.details["geometry_loss"] > 0
    # the sun is behind the camera (azimuth 2.5 rad): its direction cannot be determined, and
    # the stage says so in the fit's own words
    assert not rep.success and "sun direction undetermined" in rep.message


@pytest.mark.slow  # a wave fit of the network geometry
def test_geometry_with_no_wave_above_its_noise_hands_a_flat_sea_on(tmp_path):
    # the waves stage on geometry that shows no wave at the stated noise: a failed stage that
    # says why, and a flat sea (one wave of zero amplitude) the later stages can render
    files, scene_json, camera, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    shape = (len(seq.times),) + tuple(seq.camera.resolution)
    up = np.zeros(shape + (3,), np.float32)
    up[..., 2] = 1.0
    flat = SimpleNamespace(normal=jnp.asarray(up), roughness=jnp.full(shape, 1e-3, jnp.float32))
    wfit, rep = rc.waves_stage(seq, flat, frames=None, max_waves=4)
    assert not rep.success and "no wave found" in rep.message
    assert rep.details["n_waves"] == 0 and rep.details["normal_error_rad"] == pytest.approx(0.0, abs=1e-6)
    assert rep.details["surface"] == "rows"
    # the fit was told the network's error and its correlation across the view
    assert rep.details["normal_noise_rad"] == rc.GEOMETRY_NOISE
    assert rep.details["normal_correlation_px"] == pytest.approx(rc.GEOMETRY_CORRELATION * 32)
    assert float(jnp.max(wfit.waves.amplitude)) == 0.0 and not bool(wfit.success)
    g = render.geometry(wfit.waves, seq.camera, 0.0)
    sea = np.asarray(g.mask)
    np.testing.assert_allclose(np.asarray(g.normal)[sea][:, 2], 1.0, atol=1e-6)
    # no wave, no sea state: the flat sea's one zero-amplitude wave lends it no period
    flat = SimpleNamespace(normal=flat.normal, roughness=flat.roughness, mask=jnp.ones(shape, bool))
    (sea_state, _, _), rep = rc.sea_stage(seq, wfit.waves, flat, waves_ok=False, evidence=None)
    assert not rep.success and "no wave was found" in sea_state["bound"]
    assert all(math.isnan(sea_state[k]) for k in ("hs_m", "tp_s", "direction_deg", "waves_hs_m"))


@pytest.mark.slow  # a 16-frame wave fit and sea spectrum
def test_the_geometry_spectrum_gives_the_sea_state_where_no_wave_was_confirmed(tmp_path):
    # no wave confirmed, 16 s of geometry, images that show dispersion: the headline numbers
    # come from the geometry's space-time spectrum, marked as what they are
    files, scene_json, _, _ = _scene(tmp_path, res=64)
    seq, _ = rc.load_sequence(files, scene_json, width=64, response="bruneton")
    seq = seq._replace(times=np.arange(64) * 0.25)
    truth = jo.make_waves([0.03, 0.02], [3.6, 4.4], [0.3, 1.1], [0.0, 1.0])  # 4.8 m and 3.2 m long
    geos = [render.geometry(truth, seq.camera, t) for t in seq.times]
    stack = SimpleNamespace(normal=np.stack([np.asarray(g.normal) for g in geos]),
                            roughness=np.stack([np.asarray(g.roughness) for g in geos]),
                            mask=np.stack([np.asarray(g.mask) for g in geos]))
    flat = jo.make_waves([0.0], [1.0], [0.0])

    def images(shows):
        return SimpleNamespace(success=shows, message="stub", peak_period_s=2.0, peak_direction=0.5,
                               peak_at_band_edge=True, current=np.zeros(2))

    (sea, _, _), rep = rc.sea_stage(seq, flat, stack, waves_ok=False, evidence=images(True))
    assert rep.success, rep.message
    assert sea["source"] == "space-time spectrum of the geometry" and sea["geometry_spectrum"]["success"]
    geo = sea["geometry_spectrum"]
    hs_true = 4 * math.sqrt((0.03 ** 2 + 0.02 ** 2) / 2)  # both waves lie in the band
    assert geo["band_m"][0] > 2 * math.pi * 9.81 / 3.6 ** 2 > 2 * math.pi * 9.81 / 4.4 ** 2 > geo["band_m"][1]
    assert sea["hs_m"] == geo["hs_band_m"] and abs(sea["hs_m"] - hs_true) < 2 * sea["hs_std_m"]
    assert sea["tail_alpha"] == geo["tail_alpha"]
    # the energy-weighted direction of travel (library azimuth 0.55 rad), within its sigma
    assert abs((sea["direction_deg"] - math.degrees(0.55) + 180) % 360 - 180) < sea["direction_std_deg"]
    if geo["peak_at_band_edge"]:  # the longer of the two lower bounds on Tp
        assert not sea["peak_observed"] and "lower bound" in sea["bound"]
        assert sea["tp_s"] == max(geo["peak_period_s"], 2.0)
    else:
        assert sea["tp_s"] == pytest.approx(2 * math.pi / 3.6, rel=0.15)
    # images that show no dispersion confirm nothing: no sea state
    (sea, _, _), rep = rc.sea_stage(seq, flat, stack, waves_ok=False, evidence=images(False))
    assert not rep.success and math.isnan(sea["hs_m"]) and sea["source"] is None
    assert sea["geometry_spectrum"]["success"]  # reported beside, as evidence


@pytest.mark.slow  # the sea stage run twice
def test_waves_that_explain_the_geometry_need_the_images_to_confirm_them(tmp_path, monkeypatch):
    # a wave fit that succeeds on the geometry: the stage succeeds when the images carry
    # no space-time evidence either way (too few frames), and fails, saying why, when they
    # show no dispersive waves
    from jaxocean import fit

    files, scene_json, camera, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    truth = jo.make_waves([0.05, 0.03], [2.5, 3.2], [0.3, 1.1], [0.0, 1.0])
    geos = [render.geometry(truth, seq.camera, t) for t in seq.times]
    stack = SimpleNamespace(normal=jnp.stack([g.normal for g in geos]), roughness=jnp.stack([g.roughness for g in geos]))
    good = fit.refine(stack.normal, None, seq.camera, seq.times, truth, max_steps=0)
    good = good._replace(success=jnp.asarray(True), determined=np.ones(2, bool), surface="rows")
    monkeypatch.setattr(fit, "waves", lambda *a, **k: good)
    assert rc.space_time_evidence(seq) is None  # 2 frames: no evidence, not negative evidence
    _, rep = rc.waves_stage(seq, stack, frames=None)
    assert rep.success and rep.details["images_show_dispersion"] is None
    flat_images = SimpleNamespace(success=False, message="ratio 1.05 (success needs > 2)")
    _, rep = rc.waves_stage(seq, stack, frames=None, evidence=flat_images)
    assert not rep.success and rep.details["images_show_dispersion"] is False
    assert "show no dispersive waves" in rep.message and "ratio 1.05" in rep.message
    # images that show waves confirm them only where they peak near the waves' peak period
    tp = float(fit.sea_state(truth).tp)

    def images(period, edge):
        return SimpleNamespace(success=True, message="dispersive", peak_period_s=period, peak_at_band_edge=edge)

    assert rc.waves_stage(seq, stack, frames=None, evidence=images(1.2 * tp, False))[1].success
    # the images peak at the slopes' period, shorter than the sea's: 2.5 times shorter is
    # within 2 x 1.5, 3.5 times is not
    assert rc.waves_stage(seq, stack, frames=None, evidence=images(tp / 2.5, False))[1].success
    _, rep = rc.waves_stage(seq, stack, frames=None, evidence=images(tp / 3.5, False))
    assert not rep.success and "is not the images'" in rep.message
    _, rep = rc.waves_stage(seq, stack, frames=None, evidence=images(3.0 * tp, False))
    assert not rep.success and "is not the images'" in rep.message
    assert rep.details["peak_period_s"] == pytest.approx(tp)
    # a peak at the band's long-wave edge bounds the sea's from below only
    assert rc.waves_stage(seq, stack, frames=None, evidence=images(0.3 * tp, True))[1].success
    assert not rc.waves_stage(seq, stack, frames=None, evidence=images(3.0 * tp, True))[1].success



def test_unconfirmed_waves_give_no_headline_sea_state(tmp_path):
    # waves that no stage confirmed (stage 4 failed, no stage 5) and no geometry spectrum
    # (2 frames): Hs, Tp and the direction are null, not the sea state of those waves
    files, scene_json, camera, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    waves = jo.make_waves([1.5, 0.05], [0.4, 2.5], [0.3, 1.1], [0.0, 1.0])  # a 385 m, 1.5 m "wave"
    geo = SimpleNamespace(normal=jnp.tile(jnp.asarray([0.0, 0.0, 1.0]), (len(times), 32, 32, 1)),
                          roughness=jnp.full((len(times), 32, 32), 1e-3), mask=jnp.ones((len(times), 32, 32), bool))
    (sea, _, _), rep = rc.sea_stage(seq, waves, geo, waves_ok=False, evidence=None)
    assert not rep.success
    assert all(math.isnan(sea[k]) for k in ("hs_m", "tp_s", "direction_deg", "hs_std_m", "tail_alpha"))
    assert sea["source"] is None and "no wave was confirmed" in sea["bound"] and not sea["peak_observed"]
    # the waves' own numbers stay reported, under their own names
    assert sea["waves_hs_m"] == pytest.approx(float(jo.fit.sea_state(waves).hs))
    # the same waves, confirmed: their numbers are the headline
    (sea, _, _), _ = rc.sea_stage(seq, waves, geo, waves_ok=True, evidence=None)
    assert sea["hs_m"] == pytest.approx(sea["waves_hs_m"]) and sea["source"] == "the fitted waves"


@pytest.mark.slow  # the sea stage end to end
def test_the_sea_stage_hands_the_determined_mask_to_the_spectrum_fit(tmp_path, monkeypatch):
    # only the waves the fit measured can show the spectral peak (fit.spectrum's determined)
    files, scene_json, camera, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    waves = jo.make_waves([0.05, 0.04, 0.03, 0.02], [2.5, 3.0, 3.5, 4.0], [0.3, 0.5, 0.7, 0.9], [0.0] * 4)
    geo = SimpleNamespace(normal=jnp.tile(jnp.asarray([0.0, 0.0, 1.0]), (len(times), 32, 32, 1)),
                          roughness=jnp.full((len(times), 32, 32), 1e-3), mask=jnp.ones((len(times), 32, 32), bool))
    seen = {}
    from jaxocean import fit  # jaxocean loads its fit package lazily: jo.fit exists only once imported
    real = fit.spectrum

    def spy(w, **kw):
        seen.update(kw)
        return real(w, **kw)

    monkeypatch.setattr(fit, "spectrum", spy)
    monkeypatch.setattr(fit, "resolvable", lambda w, c: np.ones(w.omega.shape, bool))
    mask = np.array([True, True, False, True])
    (sea, _, sfit), _ = rc.sea_stage(seq, waves, geo, determined=mask, waves_ok=True, evidence=None)
    np.testing.assert_array_equal(seen["determined"], mask)
    assert sea["tail_alpha"] == sfit.alpha


def test_the_photometric_stage_needs_the_images_to_confirm_its_waves(tmp_path, monkeypatch):
    # a refinement that renders the images within their noise does not confirm waves the
    # images' space-time spectrum denies (no energy on the dispersion shell)
    from jaxocean.fit import photometric_fit as ph

    files, scene_json, camera, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    waves = jo.make_waves([0.05, 0.03], [2.5, 3.2], [0.3, 1.1], [0.0, 1.0])
    fitted = SimpleNamespace(success=True, message="", waves=waves, _replace=lambda **k: SimpleNamespace(**k))
    monkeypatch.setattr(ph, "photometric", lambda *a, **k: fitted)
    monkeypatch.setattr(ph, "fit_to_dict", lambda result: {})
    _, rep = rc.photometric_stage(seq, waves, jo.make_lighting(), evidence=None)
    assert rep.success and rep.details["images_show_dispersion"] is None
    flat_images = SimpleNamespace(success=False, message="ratio 1.29 (success needs > 2)")
    _, rep = rc.photometric_stage(seq, waves, jo.make_lighting(), evidence=flat_images)
    assert not rep.success and "show no dispersive waves" in rep.message and "ratio 1.29" in rep.message


def test_overcast_is_chosen_for_clipped_sea_not_for_pixels_outside_the_frame(tmp_path):
    files, scene_json, camera, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    assert not rc._looks_overcast(seq, 0)
    # half the view outside the source frame: unusable, not clipped
    outside = seq.usable.copy()
    outside[:, :, :16] = False
    display = seq.display.copy()
    display[:, :, :16] = 0.0
    assert not rc._looks_overcast(seq._replace(usable=outside, display=display), 0)
    # half the view saturated: an overcast sky's glare
    display[:, :, :16] = 1.0
    assert rc._looks_overcast(seq._replace(display=display), 0)
    assert rc._looks_overcast(seq._replace(gray=True), 0)

def test_the_sea_figure_of_no_wave_draws_no_wave(tmp_path):
    # the flat sea a failed wave stage hands on: no stem at its zero-amplitude stand-in
    from jaxocean import report

    flat = SimpleNamespace(sea={"waves": jo.make_waves([0.0], [1.0], [0.0]), "spectrum_fit": None},
                           sequence=SimpleNamespace(compass=True))
    path = report._sea_figure(tmp_path / "sea.png", flat)
    assert Path(path).stat().st_size > 0
    # with the geometry's spectrum: its radial spectrum and its mean direction are drawn
    flat.sea["geometry_spectrum"] = dict(k_rad_m=[0.5, 0.6, 0.7], elevation_m2=[1e-3, 5e-4, 2e-4],
                                         direction_deg=150.0, direction_std_deg=30.0, peak_period_s=2.8)
    path = report._sea_figure(tmp_path / "sea_geometry.png", flat)
    assert Path(path).stat().st_size > Path(tmp_path / "sea.png").stat().st_size


def _flat_geometry(n_frames, size=32):
    """A stage-2 geometry stand-in: a flat, smooth sea over the whole view."""
    return SimpleNamespace(normal=np.tile(np.asarray([0.0, 0.0, 1.0], np.float32), (n_frames, size, size, 1)),
                           roughness=np.full((n_frames, size, size), 1e-3, np.float32),
                           mask=np.ones((n_frames, size, size), bool))


def _figure_titles(monkeypatch, draw):
    """The axes titles and texts of the figure ``draw()`` saves (captured before it closes)."""
    from jaxocean import plots

    seen = {}
    save = plots.save_figure

    def capture(fig, path, **kw):
        seen["titles"] = [ax.get_title() for ax in fig.axes]
        seen["texts"] = [t.get_text() for ax in fig.axes for t in ax.texts]
        return save(fig, path, **kw)

    monkeypatch.setattr(plots, "save_figure", capture)
    draw()
    return seen


def test_the_report_labels_frame_times_to_the_frame_step():
    # 0.25 s steps were labelled "t = 0.2 s" (one decimal), 30 fps frames all "t = 0.0 s"
    from jaxocean import report

    assert [report._time_label(t, [0.0, 0.25]) for t in (0.0, 0.25)] == ["0.00", "0.25"]
    thirty = np.arange(3) / 30
    assert len({report._time_label(t, thirty) for t in thirty}) == 3
    assert report._time_label(12.0, [10.0, 12.0]) == "12.0"


def test_the_forecast_figure_does_not_title_the_re_edited_views_with_forecast_times(tmp_path, monkeypatch):
    # the re-edited views (at the last frame) sat under the forecast's "+2 s" / "+10 s" titles
    from jaxocean import report

    monkeypatch.setattr(report, "_display", lambda linear, seq: np.clip(linear, 0.0, 1.0))
    frame = np.full((4, 4, 3), 0.5)
    result = SimpleNamespace(sequence=SimpleNamespace(times=np.array([0.0, 0.25])),
                             outlook=dict(times=np.array([2.25, 10.25, 30.25]), forecast=np.stack([frame] * 3),
                                          lower=frame, new_sun=frame))
    seen = _figure_titles(monkeypatch, lambda: report._forecast_figure(tmp_path / "forecast.png", result))
    titles = seen["titles"]
    assert titles[:3] == ["+2 s", "+10 s", "+30 s"]
    assert titles[3:5] == ["lower camera, t = 0.25 s (last frame)", "new sun, t = 0.25 s (last frame)"]


def test_stage_frame_arguments_are_checked(tmp_path):
    # a frame index outside the sequence, or a count of frames below 1, is refused up front
    # with the argument named (not an IndexError from the middle of the stage)
    files, scene_json, _, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    geo = SimpleNamespace(normal=np.tile(np.asarray([0.0, 0.0, 1.0], np.float32), (len(times), 32, 32, 1)),
                          roughness=np.full((len(times), 32, 32), 1e-3, np.float32),
                          slope_variance=np.full((len(times), 32, 32, 2), 5e-4, np.float32),
                          mask=np.ones((len(times), 32, 32), bool))
    for frame in (len(times), -1):
        with pytest.raises(ValueError, match="frame must be an index"):
            rc.lighting_stage(seq, geo, frame=frame)
    for frames in (0, -2):
        with pytest.raises(ValueError, match="frames must be >= 1"):
            rc.waves_stage(seq, geo, frames=frames, evidence=None)
        with pytest.raises(ValueError, match="frames must be >= 1"):
            rc.photometric_stage(seq, jo.make_waves([0.0], [1.0], [0.0]), jo.make_lighting(), frames=frames,
                                 evidence=None)


def test_the_dispersion_check_reports_its_direction_in_degrees(tmp_path):
    # result.json gives every direction in degrees in the report's convention: the images'
    # dispersion check too, not its library azimuth in radians
    files, scene_json, _, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    geo = _flat_geometry(len(times))
    check = SimpleNamespace(success=False, message="stub", ratio=1.0, shell_fraction=0.1, null_fraction=0.1,
                            peak_period_s=2.0, peak_direction=0.5, peak_wavelength_m=6.0, peak_at_band_edge=False,
                            current=np.zeros(2))
    flat = jo.make_waves([0.0], [1.0], [0.0])
    for compass in (False, True):
        (sea, _, _), _ = rc.sea_stage(seq._replace(compass=compass), flat, geo, waves_ok=False, evidence=check)
        assert "peak_direction" not in sea["dispersion"]
        assert sea["dispersion"]["peak_direction_deg"] == pytest.approx(rc.direction_deg(0.5, compass))
        assert sea["dispersion"]["peak_direction_deg"] == sea["dispersion_direction_deg"]
        assert sea["dispersion_note"] is None


def test_the_report_headline_shows_nan_numbers_as_missing():
    # an estimate the run could not make (NaN in the result) printed as "Hs = nan m"
    from jaxocean import report

    sea = {"hs_m": float("nan"), "hs_std_m": None, "tp_s": 6.0, "tp_std_s": float("nan"),
           "direction_deg": float("nan"), "success": False}
    page = report._html({"spectrum": sea, "stages": {}}, [])
    assert "nan" not in page.lower()
    assert "Hs = n/a m" in page and "Tp = 6 s &plusmn; n/a" in page


def test_a_dispersion_check_without_enough_frames_is_reported_not_computed(tmp_path):
    # with fewer frames than the space-time check needs, the report's headline read "n/a times
    # more energy on the dispersion shell" and result.json gave nulls with no reason
    from jaxocean import report

    files, scene_json, _, times = _scene(tmp_path)
    seq, _ = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    geo = _flat_geometry(len(times))
    (sea, check, _), rep = rc.sea_stage(seq, jo.make_waves([0.0], [1.0], [0.0]), geo, waves_ok=False)
    assert check is None and sea["dispersion"] is None and sea["dispersion_peak_period_s"] is None
    assert sea["dispersion_note"] == f"not computed: it needs 8 frames, {len(times)} given"
    assert f"no space-time evidence: it needs 8 frames, {len(times)} given" in rep.message
    page = report._html({"spectrum": sea, "stages": {}}, [])
    assert f"space-time spectrum: not computed: it needs 8 frames, {len(times)} given" in page
    assert "n/a times more energy" not in page



def test_frames_not_uniformly_spaced_are_refused_before_the_stages_that_need_it(monkeypatch):
    # a camera file may give any increasing times (a dropped frame), but the space-time
    # evidence of stages 4-6 needs a uniform step: refused after stage 1 with the step named,
    # not with spacetime's ValueError after the geometry and lighting stages
    times = np.where(np.arange(8) >= 5, np.arange(8) * 0.25 + 0.25, np.arange(8) * 0.25)  # frame 5 is late
    seq = SimpleNamespace(times=times, files=tuple(f"/x/frame_{i:05d}.png" for i in range(8)))
    report = rc.StageReport("radiometry", True, 0.0, "", {})
    monkeypatch.setattr(rc, "load_sequence", lambda *a, **k: (seq, report))
    monkeypatch.setattr(rc, "geometry_stage", lambda *a, **k: pytest.fail("stage 2 ran"))
    with pytest.raises(InvalidValueError, match=r"uniformly spaced .* frame 4 \(t = 1 s, frame_00004\.png\) to "
                                                r"frame 5 \(t = 1\.5 s\) is 0\.5 s against 0\.25 s"):
        rc.reconstruct([], "camera.json", progress=False)
    # fewer frames than the evidence needs: no evidence, so no uniform step needed; and a
    # uniform step passes
    rc._check_evidence_times(SimpleNamespace(times=times[:7], files=seq.files[:7]))
    rc._check_evidence_times(SimpleNamespace(times=np.arange(8) * 0.2, files=seq.files))


def test_scene_directory_reads_as_its_scene_json(tmp_path):
    # a scene directory (as render and reedit take one) said "camera.json: no such camera file";
    # now its scene.json is read (three frames for its two times: refused before any work)
    camera = cam.make_camera(height=8.0, pitch=0.7, fov=0.8, resolution=(16, 16))
    files = [save_png(tmp_path / f"frame_{i:05d}.png", np.full((16, 16, 3), 0.3)) for i in range(3)]
    write_scene(tmp_path, scene_to_dict(camera=camera, times=[0.0, 0.25]))
    with pytest.raises(InvalidValueError, match=r"3 frames given for the 2 times of .*scene\.json"):
        rc.load_sequence(files, tmp_path)
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match=r"empty: a directory with neither a camera file \(camera\.json\) "
                                                r"nor a scene \(scene\.json\)"):
        rc.load_sequence(files, tmp_path / "empty")


def test_reconstruct_from_python_names_a_fit_result_given_as_its_camera(tmp_path):
    # only the CLI named it; reconstruct() said "scene is missing key(s) ['version']"
    from jaxocean.fit import lighting_to_dict
    from jaxocean.io.scene import SceneFileError

    camera = cam.make_camera(height=8.0, pitch=0.7, fov=0.8, resolution=(16, 16))
    files = [save_png(tmp_path / f"frame_{i:05d}.png", np.full((16, 16, 3), 0.3)) for i in range(2)]
    fit_json = tmp_path / "fit.json"  # the layout `jaxocean fit-lighting` writes
    fit_json.write_text(json.dumps({"lighting": lighting_to_dict(jo.make_lighting()), "loss": 0.0, "rms_residual": 0.0,
                                    "steps": 3, "success": True, "wall_time_s": 0.1, "frame": str(files[0]),
                                    "camera": cam.camera_to_dict(camera, degrees=True)}))
    with pytest.raises(SceneFileError, match=r"fit\.json: this is a lighting fit result \(jaxocean fit-lighting\); "
                                             r"the camera takes a camera file"):
        rc.reconstruct(files, fit_json, progress=False)
    # and a dataset's settings, which carry a version as a scene does
    settings = tmp_path / "dataset.json"
    settings.write_text(json.dumps({"version": "0.1.0", "scenes": 2, "frames": 2, "ranges": {}}))
    with pytest.raises(SceneFileError, match=r"this is a dataset's settings"):
        rc.load_sequence(files, settings)


def test_a_frame_that_sees_none_of_the_view_fails_stage_one():
    # the share was averaged over the frames: nine clear frames and one that saw none of the
    # working view (90 % on average) passed
    sea = np.zeros((8, 8), bool)
    sea[3:] = True
    usable = np.ones((10, 8, 8), bool)
    usable[6] = False
    files = [f"frame_{i:05d}.png" for i in range(10)]
    share, per_frame, problem = footage.usable_share(usable, sea, files)
    assert share == pytest.approx(0.9) and per_frame[6] == 0.0
    assert problem == ("1 of 10 frames see next to none of the working view (under 5% of its sea usable: saturated "
                       "or outside the frame): frame 6 (frame_00006.png: 0%); 90% usable over all frames")
    # a partial frame passes; a low share over all frames is named as before
    usable[6, 5:] = True
    assert footage.usable_share(usable, sea, files)[2] is None
    usable[:8] = False
    assert footage.usable_share(usable, sea, files)[2] == ("only 20% of the sea pixels are usable (saturated or "
                                                           "outside the frames)")


def test_stage_one_names_a_frame_outside_the_working_view(tmp_path):
    # through load_sequence: the second of three frames is saturated all over (white)
    files, scene_json, camera, times = _scene(tmp_path, frames=3)
    save_png(files[1], np.full((32, 32, 3), 1e6))
    seq, rep = rc.load_sequence(files, scene_json, width=32, response="bruneton")
    assert not rep.success and "frame 1 (" in rep.message and "frame_00001.png: 0%)" in rep.message
    assert rep.details["usable_sea_fraction"] > 0.5 and rep.details["usable_sea_fraction_min"] == 0.0


@pytest.mark.slow  # the forecast stage end to end
def test_the_forecast_of_waves_no_stage_confirmed_is_not_a_success():
    # the forecast stage drew the waves of a failed wave fit (stage 5 not succeeding) and
    # reported success: its flag said the forecast rested on waves that explain the data
    camera = cam.make_camera(height=8.0, pitch=0.7, fov=0.8, resolution=(16, 16))
    seq = SimpleNamespace(camera=camera, times=np.arange(2) * 0.25)
    waves = jo.make_waves([0.05, 0.03], [2.5, 3.2], [0.3, 1.1], [0.0, 1.0])
    light = jo.make_lighting(sun_azimuth=2.5, sun_elevation=0.5)
    out, rep = rc.outlook_stage(seq, waves, light, ahead=(2.0,), waves_ok=False)
    assert not rep.success and "no stage confirmed" in rep.message
    assert out["forecast"].shape == (1, 16, 16, 3)  # drawn all the same
    _, rep = rc.outlook_stage(seq, waves, light, ahead=(2.0,))
    assert rep.success and rep.message == ""
