import json
import math
import os
import subprocess
import sys

import jax
import numpy as np
import pytest

from jaxocean import _cli_inputs, cli, compile_cache


@pytest.mark.parametrize("command", ["render", "simulate", "check", "demo", "fit-lighting", "reedit", "fit-waves",
                                     "forecast"])
def test_every_subcommand_has_help(command, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main([command, "--help"])
    assert exit_info.value.code == 0
    assert "usage: jaxocean " + command in capsys.readouterr().out


def test_usage_errors_exit_2(capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["render", "--out", "x", "--res", "0x5"])
    assert exit_info.value.code == 2
    assert "resolution must be N or HxW" in capsys.readouterr().err


@pytest.mark.parametrize("text", ["16x", "x16", "16xx16", "16x16x"])
def test_a_resolution_with_a_missing_side_is_refused(text):
    # "16x" was read as 16x16
    with pytest.raises(Exception, match="resolution must be N or HxW"):
        _cli_inputs.resolution_arg(text)
    assert _cli_inputs.resolution_arg(" 16X24 ") == (16, 24) and _cli_inputs.resolution_arg("8") == (8, 8)


def test_bad_values_exit_2_with_message(tmp_path, capsys):
    code = cli.main(["render", "--out", str(tmp_path / "r"), "--camera-height", "-3", "--frames", "1",
                     "--res", "8", "--waves", "4"])
    assert code == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxocean: error:") and "under the sea" in err
    assert not (tmp_path / "r").exists()  # nothing written half-way


def test_render_writes_frames_and_scene(tmp_path, capsys):
    out = tmp_path / "r"
    assert cli.main(["render", "--out", str(out), "--frames", "2", "--res", "8x12", "--waves", "6"]) == 0
    assert sorted(p.name for p in out.glob("frame_*")) == ["frame_00000.exr", "frame_00000.png", "frame_00001.exr",
                                                           "frame_00001.png"]
    scene = json.loads((out / "scene.json").read_text())
    assert scene["camera"]["resolution"] == [8, 12] and len(scene["times"]) == 2
    # the scene file renders again, to the same frames
    again = tmp_path / "again"
    assert cli.main(["render", str(out / "scene.json"), "--out", str(again)]) == 0
    assert (again / "frame_00001.exr").read_bytes() == (out / "frame_00001.exr").read_bytes()


def test_simulate_then_check_exit_codes(tmp_path, capsys):
    root = tmp_path / "ds"
    assert cli.main(["simulate", "--out", str(root), "--scenes", "2", "--frames", "1", "--res", "8",
                     "--waves", "4", "--quiet"]) == 0
    assert cli.main(["check", str(root)]) == 0
    (root / "scene_00001" / "frame_00000.exr").write_bytes(b"garbage")
    assert cli.main(["check", str(root)]) == 1
    assert "scene_00001/frame_00000.exr" in capsys.readouterr().out


# ----------------------------------------------------------------------------- fits, re-editing, forecasts
# One tiny scene (16 x 16 pixels, 3 frames, 2 waves) rendered once with `render`; the sun is
# in front of the camera so that its glitter is in view.

SUN_AZIMUTH, SUN_ELEVATION = 0.4, 0.8  # rad


@pytest.fixture(scope="module")
def tiny_scene(tmp_path_factory):
    from jaxocean import camera, io, shading
    from jaxocean.waves import make_waves

    root = tmp_path_factory.mktemp("cli_scene")
    waves = make_waves([0.03, 0.02], [2.8, 3.6], [0.4, 2.1], [0.5, 4.0])
    cam = camera.make_camera(height=6.0, pitch=0.9, fov=0.8, yaw=0.4, resolution=(16, 16))
    light = shading.make_lighting(sun_azimuth=SUN_AZIMUTH, sun_elevation=SUN_ELEVATION)
    io.write_scene(root / "spec", io.scene_to_dict(waves=waves, camera=cam, lighting=light, times=[0.0, 0.15, 0.3]))
    assert cli.main(["render", str(root / "spec"), "--out", str(root / "scene")]) == 0
    return root / "scene"


@pytest.mark.slow  # the fit-lighting command end to end
def test_fit_lighting_says_what_the_frame_determines(tiny_scene, tmp_path, capsys):
    # 16 x 16 pixels of a steep view hold almost no glitter: the sun is not determined (its
    # colour comes out ~1e-4 of the truth), the sky and sea colours are. The fit says so and
    # exits 1 instead of reporting a success
    out = tmp_path / "fit.json"
    assert cli.main(["fit-lighting", str(tiny_scene / "frame_00000.exr"), "--scene", str(tiny_scene),
                     "--out", str(out)]) == 1
    fit = json.loads(out.read_text())
    assert fit["success"] is False and fit["rms_residual"] < 1e-3
    assert fit["determined"] == {"sea_color": True, "sky_color": True, "sun_color": False, "sun_direction": False}
    assert fit["lighting"]["sky_color"] == pytest.approx([0.35, 0.55, 0.9], rel=1e-3)
    assert fit["camera"]["resolution"] == [16, 16]
    captured = capsys.readouterr()
    assert "sun elevation" in captured.out and "vs the scene's lighting" in captured.out
    assert "sun direction undetermined" in captured.err
    # the same camera given by options (same shapes: no recompilation)
    again = tmp_path / "again.json"
    assert cli.main(["fit-lighting", str(tiny_scene / "frame_00000.exr"), "--camera-height", "6",
                     "--camera-pitch-deg", repr(math.degrees(0.9)), "--camera-fov-deg", repr(math.degrees(0.8)),
                     "--camera-yaw-deg", repr(math.degrees(0.4)), "--out", str(again)]) == 1
    light, first = json.loads(again.read_text())["lighting"], fit["lighting"]
    assert light["sky_color"] == pytest.approx(first["sky_color"], rel=1e-6)


# The command's default scene (60 JONSWAP waves) at 16 x 16 pixels: its sub-pixel waves make the
# slope variance strongly anisotropic, so shading its geometry needs slope_variance.X/Y.


@pytest.fixture(scope="module")
def default_scene(tmp_path_factory):
    out = tmp_path_factory.mktemp("cli_default") / "render"
    assert cli.main(["render", "--out", str(out), "--frames", "1", "--res", "16"]) == 0
    return out


def test_render_of_a_scene_file_refuses_the_scene_options(tiny_scene, tmp_path, capsys):
    out = tmp_path / "r"
    assert cli.main(["render", str(tiny_scene), "--hs", "3", "--frames", "2", "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "--hs, --frames: scene options apply only without a SCENE" in err and not out.exists()


def test_render_of_a_scene_file_keeps_its_seed(tmp_path):
    # re-rendering a drawn scene keeps the seed its waves were drawn from (reedit keeps it too)
    first, again = tmp_path / "first", tmp_path / "again"
    assert cli.main(["render", "--out", str(first), "--frames", "1", "--res", "8", "--waves", "2", "--seed", "7"]) == 0
    assert cli.main(["render", str(first), "--out", str(again)]) == 0
    assert json.loads((again / "scene.json").read_text())["seed"] == 7


def test_render_names_camera_angles_in_degrees_and_warns_of_a_sky_only_view(tmp_path, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["render", "--out", str(tmp_path / "a"), "--camera-fov-deg", "200"])
    assert exit_info.value.code == 2 and "a field of view in degrees, in (0, 180); got '200'" in capsys.readouterr().err
    assert cli.main(["render", "--out", str(tmp_path / "b"), "--res", "8x8", "--frames", "1", "--waves", "2",
                     "--camera-pitch-deg=-50"]) == 0
    assert "warning: no pixel sees the sea" in capsys.readouterr().err


def test_python_dash_m_runs_the_command():
    run = subprocess.run([sys.executable, "-m", "jaxocean", "--help"], capture_output=True, text=True, timeout=120)
    assert run.returncode == 0 and "usage: jaxocean" in run.stdout


def test_rendered_frame_reproduces_its_image(default_scene):
    from jaxocean import io, render

    frame, scene = io.read_frame(default_scene / "frame_00000.exr"), io.read_scene(default_scene)
    sv = frame.slope_variance[frame.mask]
    assert np.sum(sv[:, 0]) > 1.5 * np.sum(sv[:, 1]) or np.sum(sv[:, 1]) > 1.5 * np.sum(sv[:, 0])
    shaded = render.shade(frame.normal, frame.roughness, scene.camera, scene.lighting,
                          slope_variance=frame.slope_variance)
    # R G B are stored as half floats (relative rounding 2^-11), the geometry as float32
    np.testing.assert_allclose(np.asarray(shaded), frame.image, rtol=2.0**-11 + 1e-5, atol=3e-8)


@pytest.mark.slow  # the fit-lighting command end to end
def test_fit_lighting_of_its_own_frame_is_exact(default_scene, tmp_path, capsys):
    # the command that reported success with the sun colour 87% off while frames stored only
    # the scalar roughness
    from jaxocean import fit, io

    out = tmp_path / "fit.json"
    assert cli.main(["fit-lighting", str(default_scene / "frame_00000.exr"), "--scene", str(default_scene),
                     "--out", str(out)]) == 0
    assert "note:" not in capsys.readouterr().err
    result = json.loads(out.read_text())
    err = fit.lighting_error(fit.lighting_from_dict(result), io.read_scene(default_scene).lighting)
    assert result["success"] is True and float(err["sun_angle_deg"]) < 1e-2
    for name in ("sun_color", "sky_color", "sea_color"):
        assert float(err[name]) < 2e-3, name


def test_fit_lighting_notes_a_frame_without_slope_variance(default_scene, tmp_path, capsys, monkeypatch):
    from jaxocean import fit, io

    frame = io.read_frame(default_scene / "frame_00000.exr")
    io.write_frame(tmp_path / "old.exr", frame.image, frame._replace(slope_variance=None))

    def stop(*args, **kwargs):  # the note comes before the (slow) fit
        raise ValueError("fit skipped")

    monkeypatch.setattr(fit, "lighting", stop)
    assert cli.main(["fit-lighting", str(tmp_path / "old.exr"), "--scene", str(default_scene),
                     "--out", str(tmp_path / "fit.json")]) == 2
    err = capsys.readouterr().err
    assert "old.exr has no slope_variance.X/Y channels" in err and "isotropic roughness" in err


def test_fit_lighting_takes_the_camera_options_for_a_scene_without_a_camera(tiny_scene, tmp_path, capsys,
                                                                             monkeypatch):
    import json

    from jaxocean import fit

    data = json.loads((tiny_scene / "scene.json").read_text())
    del data["camera"]
    (tmp_path / "scene.json").write_text(json.dumps(data))
    frame = str(tiny_scene / "frame_00000.exr")
    assert cli.main(["fit-lighting", frame, "--scene", str(tmp_path), "--out", str(tmp_path / "a.json")]) == 2
    assert f"the scene {tmp_path} has no camera: give --camera-height and --camera-pitch-deg" in \
        capsys.readouterr().err
    seen = {}

    def stop(image, geometry, camera, **kwargs):
        seen["camera"] = camera
        raise ValueError("fit skipped")

    monkeypatch.setattr(fit, "lighting", stop)  # refused before the options were looked at
    assert cli.main(["fit-lighting", frame, "--scene", str(tmp_path), "--camera-height", "7",
                     "--camera-pitch-deg", "40", "--out", str(tmp_path / "a.json")]) == 2
    assert "fit skipped" in capsys.readouterr().err
    assert float(seen["camera"].height) == pytest.approx(7.0)
    assert float(seen["camera"].pitch) == pytest.approx(np.radians(40.0))


def test_fit_lighting_bad_inputs_exit_2(tiny_scene, tmp_path, capsys):
    from jaxocean import io

    frame = str(tiny_scene / "frame_00000.exr")
    assert cli.main(["fit-lighting", frame, "--out", str(tmp_path / "a.json")]) == 2
    assert "has no camera: give --camera-height and --camera-pitch-deg" in capsys.readouterr().err
    io.write_frame(tmp_path / "rgb.exr", np.ones((16, 16, 3), np.float32))  # no geometry channels
    assert cli.main(["fit-lighting", str(tmp_path / "rgb.exr"), "--scene", str(tiny_scene),
                     "--out", str(tmp_path / "b.json")]) == 2
    assert "no normal channels" in capsys.readouterr().err
    assert not list(tmp_path.glob("*.json"))


@pytest.mark.slow  # the reedit command end to end (about 50 s on 2 cores)
def test_reedit_with_new_camera_and_sun(tiny_scene, tmp_path, capsys):
    out = tmp_path / "edited"
    light = {"lighting": {"sun_azimuth": 1.0, "sun_elevation": 1.0, "sun_color": [5.0, 5.0, 4.0],
                          "sky_color": [0.2, 0.3, 0.4], "sea_color": [0.01, 0.02, 0.03]}}  # fit-lighting's layout
    (tmp_path / "light.json").write_text(json.dumps(light))
    # the sun moved behind the camera (which looks towards 23 deg)
    assert cli.main(["reedit", str(tiny_scene), "--lighting", str(tmp_path / "light.json"), "--camera-height", "5",
                     "--sun-elevation", "20", "--sun-azimuth", "203", "--frames", "0,2", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.glob("frame_*")) == ["frame_00000.exr", "frame_00000.png", "frame_00001.exr",
                                                           "frame_00001.png"]
    scene = json.loads((out / "scene.json").read_text())
    assert scene["camera"]["height"] == 5.0 and scene["camera"]["pitch"] == pytest.approx(0.9)
    assert scene["lighting"]["sun_elevation"] == pytest.approx(math.radians(20))
    assert scene["lighting"]["sun_azimuth"] == pytest.approx(math.radians(203))
    assert scene["lighting"]["sky_color"] == pytest.approx([0.2, 0.3, 0.4])
    assert scene["times"] == pytest.approx([0.0, 0.3])
    # no glitter in view: the lighting fit reports failure with exit code 1 and still writes its JSON
    fit = tmp_path / "fit.json"
    assert cli.main(["fit-lighting", str(out / "frame_00000.exr"), "--scene", str(out), "--out", str(fit)]) == 1
    assert json.loads(fit.read_text())["success"] is False
    assert "sun direction undetermined: no sun glitter in the image" in capsys.readouterr().err
    # that failed fit's lighting is refused by reedit, unless asked for (then with a warning)
    again = tmp_path / "again"
    assert cli.main(["reedit", str(tiny_scene), "--lighting", str(fit), "--frames", "0", "--out", str(again)]) == 2
    err = capsys.readouterr().err
    assert "lighting fit reported failure" in err and "sun direction" in err and "--allow-failed-lighting" in err
    assert not again.exists()
    assert cli.main(["reedit", str(tiny_scene), "--lighting", str(fit), "--allow-failed-lighting", "--frames", "0",
                     "--out", str(again)]) == 0
    assert "warning: using the lighting of a failed fit" in capsys.readouterr().err


def test_reedit_bad_inputs_exit_2(tiny_scene, tmp_path, capsys):
    out = tmp_path / "edited"
    assert cli.main(["reedit", str(tiny_scene), "--frames", "0,7", "--out", str(out)]) == 2
    assert "no frame 7" in capsys.readouterr().err
    # the scene it writes must be a time sequence (forecast and fit-waves refuse one that is not)
    assert cli.main(["reedit", str(tiny_scene), "--frames", "1,0", "--out", str(out)]) == 2
    assert "frame indices must increase strictly" in capsys.readouterr().err
    assert cli.main(["reedit", str(tiny_scene), "--camera-height", "-1", "--out", str(out)]) == 2
    assert "under the sea" in capsys.readouterr().err
    (tmp_path / "broken.json").write_text("{")
    assert cli.main(["reedit", str(tiny_scene), "--lighting", str(tmp_path / "broken.json"), "--out", str(out)]) == 2
    assert "broken.json" in capsys.readouterr().err
    assert not out.exists()


def test_reedit_and_forecast_warn_of_a_sky_only_view(tiny_scene, tmp_path, capsys):
    # as render does: a camera that sees only sky renders frames nothing can be fitted from
    assert cli.main(["reedit", str(tiny_scene), "--frames", "0", "--camera-pitch-deg=-40",
                     "--out", str(tmp_path / "r")]) == 0
    assert "warning: no pixel sees the sea" in capsys.readouterr().err
    assert cli.main(["forecast", str(tiny_scene), "--times", "0", "--camera-pitch-deg=-40",
                     "--out", str(tmp_path / "f")]) == 0
    assert "warning: no pixel sees the sea" in capsys.readouterr().err
    assert cli.main(["reedit", str(tiny_scene), "--frames", "0", "--out", str(tmp_path / "sea")]) == 0
    assert "no pixel sees the sea" not in capsys.readouterr().err
    # a camera so high that every sea hit lies beyond the renderer's 100 km: not "above the horizon" alone
    assert cli.main(["reedit", str(tiny_scene), "--frames", "0", "--camera-height", "2e5",
                     "--out", str(tmp_path / "high")]) == 0
    assert "or the sea lies more than 100 km away" in capsys.readouterr().err


def test_lighting_of_a_scene_directory_and_of_a_scene_without_one(tiny_scene, tmp_path, capsys):
    # --lighting takes "a fit-lighting JSON (or a scene.json)": its directory too, as every scene argument
    out = tmp_path / "r"
    assert cli.main(["reedit", str(tiny_scene), "--frames", "0", "--lighting", str(tiny_scene), "--out", str(out)]) == 0
    scene = json.loads((tiny_scene / "scene.json").read_text())
    edited = json.loads((out / "scene.json").read_text())["lighting"]
    for name, value in scene["lighting"].items():
        assert edited[name] == pytest.approx(value)
    scene["lighting"] = None
    (tmp_path / "dark.json").write_text(json.dumps(scene))
    assert cli.main(["reedit", str(tiny_scene), "--lighting", str(tmp_path / "dark.json"),
                     "--out", str(tmp_path / "x")]) == 2
    assert "dark.json: holds no lighting (lighting: null)" in capsys.readouterr().err


def test_scene_commands_given_a_frame_file_name_its_directory(tiny_scene, tmp_path, capsys):
    frame = str(tiny_scene / "frame_00000.exr")
    for argv in (["fit-waves", frame, "--out", str(tmp_path / "w.json")], ["reedit", frame, "--out", str(tmp_path)],
                 ["forecast", frame, "--times", "1", "--out", str(tmp_path)]):
        assert cli.main(argv) == 2
        assert f"not a scene file or directory; give the scene's directory ({tiny_scene})" in capsys.readouterr().err


def test_forecast_renders_requested_frames(tiny_scene, tmp_path, capsys):
    from jaxocean import io

    out = tmp_path / "fc"
    assert cli.main(["forecast", str(tiny_scene / "scene.json"), "--frames", "0,100,500", "--out", str(out)]) == 0
    assert sorted(p.name for p in out.glob("frame_*.exr")) == ["frame_00000.exr", "frame_00001.exr",
                                                               "frame_00002.exr"]
    assert len(list(out.glob("frame_*.png"))) == 3
    scene = json.loads((out / "scene.json").read_text())
    assert scene["times"] == pytest.approx([0.0, 15.0, 75.0])  # the scene's clock: 0.15 s per frame
    assert scene["extra"]["forecast_frames"] == [0, 100, 500]
    last = io.read_frame(out / "frame_00002.exr")
    assert last.meta["frame"] == 500 and last.meta["time"] == pytest.approx(75.0)
    # frame 0 of the forecast is the rendered frame 0 (same waves, camera, light)
    np.testing.assert_allclose(io.read_frame(out / "frame_00000.exr").image,
                               io.read_frame(tiny_scene / "frame_00000.exr").image, rtol=2e-3, atol=1e-4)
    assert "frame_00002.exr/png: frame 500, t = 75 s" in capsys.readouterr().out


def test_reedit_and_forecast_refuse_to_write_over_the_scene_they_read(tiny_scene, tmp_path, capsys):
    # reedit SCENE --out SCENE --frames 1 replaced the source's frames by one re-edited frame
    # (frames 0 and 2 lost) and its scene.json by one "reedited_from" itself
    import shutil

    scene = tmp_path / "scene"
    shutil.copytree(tiny_scene, scene)
    before = {p.name: p.read_bytes() for p in scene.iterdir()}
    for argv in (["reedit", str(scene), "--frames", "1", "--out", str(scene)],
                 ["reedit", str(scene / "scene.json"), "--out", str(scene / ".")],
                 ["forecast", str(scene), "--frames", "0,5", "--out", str(scene)]):
        assert cli.main(argv) == 2
        assert "holds the scene" in capsys.readouterr().err
    assert {p.name: p.read_bytes() for p in scene.iterdir()} == before


def test_forecast_bad_inputs_exit_2(tiny_scene, tmp_path, capsys):
    from jaxocean import io

    io.write_scene(tmp_path / "nowaves.json", io.scene_to_dict(times=[0.0, 0.1]))
    out = tmp_path / "fc"
    assert cli.main(["forecast", str(tmp_path / "nowaves.json"), "--frames", "0,1", "--out", str(out)]) == 2
    assert "no waves to forecast" in capsys.readouterr().err
    scene = json.loads((tiny_scene / "scene.json").read_text())
    scene["times"] = None
    (tmp_path / "noclock.json").write_text(json.dumps(scene))
    assert cli.main(["forecast", str(tmp_path / "noclock.json"), "--frames", "0,1", "--out", str(out)]) == 2
    assert "give --fps or --times" in capsys.readouterr().err
    with pytest.raises(SystemExit) as exit_info:
        cli.main(["forecast", str(tiny_scene / "scene.json"), "--frames", "0,-1", "--out", str(out)])
    assert exit_info.value.code == 2
    assert not out.exists()


@pytest.mark.parametrize("option, values", [("--frames", "5,2,9"), ("--frames", "2,2"), ("--times", "1,0.5")])
def test_forecast_refuses_frames_or_times_that_do_not_increase(tiny_scene, tmp_path, capsys, option, values):
    # the forecast is written as a scene: 5,2,9 wrote times 0.75, 0.3, 1.35 s, which fit-waves
    # and forecast then refuse to read as a sequence
    out = tmp_path / "fc"
    assert cli.main(["forecast", str(tiny_scene / "scene.json"), option, values, "--out", str(out)]) == 2
    assert capsys.readouterr().err == (f"jaxocean: error: {option} must increase strictly (a time sequence, each "
                                       f"once); got {values}\n")
    assert not out.exists()


def test_forecast_frames_of_a_scene_without_a_frame_clock_name_the_scene(tiny_scene, tmp_path, capsys):
    scene = json.loads((tiny_scene / "scene.json").read_text())
    scene["times"] = [0.0, 0.5, 0.5]
    (tmp_path / "repeated.json").write_text(json.dumps(scene))
    assert cli.main(["forecast", str(tmp_path / "repeated.json"), "--frames", "0,1", "--out", str(tmp_path / "f")]) == 2
    err = capsys.readouterr().err
    assert "repeated.json: frame times must be strictly increasing; got [0.5] (first at index [2]" in err
    assert "--fps or --times" in err


def test_fit_waves_bad_inputs_exit_2(tiny_scene, tmp_path, capsys):
    out = tmp_path / "waves.json"
    assert cli.main(["fit-waves", str(tiny_scene), "--frames", "1", "--out", str(out)]) == 2
    assert "at least two frames" in capsys.readouterr().err
    assert cli.main(["fit-waves", str(tiny_scene), "--frames", "0,3", "--out", str(out)]) == 2
    assert "no frame 3" in capsys.readouterr().err
    assert cli.main(["fit-waves", str(tmp_path / "nowhere"), "--out", str(out)]) == 2
    assert cli.main(["fit-waves", str(tiny_scene), "--noise", "-0.1", "--out", str(out)]) == 2
    assert "--noise must be a finite sigma" in capsys.readouterr().err
    assert cli.main(["fit-waves", str(tiny_scene), "--noise-correlation", "4", "--out", str(out)]) == 2
    assert "give --noise too" in capsys.readouterr().err
    assert cli.build_parser().parse_args(["fit-waves", str(tiny_scene), "--out", str(out)]).heights
    assert not cli.build_parser().parse_args(["fit-waves", str(tiny_scene), "--out", str(out), "--no-heights"]).heights
    parse = cli.build_parser().parse_args
    assert parse(["fit-waves", str(tiny_scene), "--out", str(out)]).height_trend == "level"
    from jaxocean.fit import waves_fit

    for trend in waves_fit.HEIGHT_TRENDS:  # the parser's literal list covers the library's
        assert parse(["fit-waves", str(tiny_scene), "--out", str(out), "--height-trend", trend]).height_trend == trend
    with pytest.raises(SystemExit):
        parse(["fit-waves", str(tiny_scene), "--out", str(out), "--height-trend", "cubic"])
    capsys.readouterr()
    assert not out.exists()


def test_fit_waves_on_a_dataset_root_names_its_scene_directories(tmp_path, capsys):
    from jaxocean import io

    for i in range(2):
        io.write_scene(tmp_path / "data" / f"scene_{i:05d}", io.scene_to_dict(times=[0.0, 0.1]))
    assert cli.main(["fit-waves", str(tmp_path / "data"), "--out", str(tmp_path / "waves.json")]) == 2
    assert (f"holds scene directories (scene_00000, scene_00001); give one of them, e.g. "
            f"{tmp_path / 'data' / 'scene_00000'}\n") in capsys.readouterr().err


@pytest.mark.slow  # the fit-waves command's order selection
def test_fit_waves_that_finds_no_wave_exits_1_with_its_json(tiny_scene, tmp_path, capsys):
    # at a stated noise far above the waves' slopes the fit finds nothing: a failed fit
    # (exit 1, JSON written, as the help and the README say), not bad input (exit 2)
    out = tmp_path / "waves.json"
    assert cli.main(["fit-waves", str(tiny_scene), "--noise", "1.0", "--out", str(out)]) == 1
    assert "no wave found" in capsys.readouterr().err
    data = json.loads(out.read_text())
    report = data["extra"]["wave_fit"]
    assert report["success"] is False and report["n_waves"] == 0 and "no wave found" in report["message"]
    assert data["waves"] is None and data["camera"]["resolution"] == [16, 16]


def test_fit_waves_failure_names_steep_waves(tiny_scene, tmp_path, capsys, monkeypatch):
    # fit.waves fails a fit that explains the data with looping crests (k h > 1); the
    # command must say so, not claim a normal error above the bound that it is below
    import importlib

    from jaxocean.waves import Waves

    fw = importlib.import_module("jaxocean.fit.waves")  # the package (jaxocean.fit.waves is also the function's name)

    steep = Waves(*(np.asarray(v, np.float32) for v in ([0.5, 0.01], [6.0, 3.0], [0.0, 1.0], [0.0, 0.0])))  # k h 1.8
    zeros = Waves(*(np.zeros(2, np.float32) for _ in range(4)))

    def fake(normals, roughness, camera, times, **kwargs):
        return fw.WaveFit(steep, zeros, loss=np.float32(1e-9), normal_error=np.float32(1e-5),
                          roughness_error=np.float32(0.0), steps=np.int32(3), success=np.bool_(False),
                          n_waves=np.int32(2), time_s=np.float32(0.1), converged=np.bool_(True))

    monkeypatch.setattr(fw, "waves", fake)
    out = tmp_path / "waves.json"
    assert cli.main(["fit-waves", str(tiny_scene), "--n-waves", "2", "--out", str(out)]) == 1
    err = capsys.readouterr().err
    assert "1 of 2 fitted waves are steeper than k h = 1" in err
    assert "above" not in err
    assert json.loads(out.read_text())["extra"]["wave_fit"]["success"] is False


@pytest.mark.slow  # the wave fit compiles for about a minute on a CPU
def test_fit_waves_then_forecast(tiny_scene, tmp_path, capsys):
    out = tmp_path / "waves.json"
    assert cli.main(["fit-waves", str(tiny_scene), "--n-waves", "2", "--out", str(out)]) == 0
    data = json.loads(out.read_text())
    report = data["extra"]["wave_fit"]
    assert report["success"] is True and report["n_waves"] == 2 and report["frames"] == [0, 1, 2]
    assert report["normal_error_deg"] < 0.5
    assert report["match"]["matched"] == 2 and report["match"]["max_abs_error"]["omega"] < 1e-2
    assert len(data["waves"]["omega"]) == 2 and data["camera"]["resolution"] == [16, 16]
    assert "2 matched" in capsys.readouterr().out
    # what the least-squares forecast needs: the band and a frequency sigma per component
    stored = report["forecast"]
    n_band = len(stored["band"]["omega"])
    assert len(stored["frequency_sigma"]) == 2 + n_band and min(stored["frequency_sigma"]) >= 0
    assert stored["window_s"] == pytest.approx([data["times"][0], data["times"][2]])
    assert len(report["determined"]) == 2
    # the fitted waves forecast like any scene: damped by default, as fitted with --undamped
    assert cli.main(["forecast", str(out), "--frames", "0,10", "--fps", "5", "--camera-height", "8",
                     "--out", str(tmp_path / "fc")]) == 0
    assert "least-squares forecast: 2 wave(s)" in capsys.readouterr().out
    assert json.loads((tmp_path / "fc" / "scene.json").read_text())["times"] == pytest.approx([0.0, 2.0])
    assert cli.main(["forecast", str(out), "--frames", "0,10", "--undamped", "--out", str(tmp_path / "fc2")]) == 0
    assert "least-squares" not in capsys.readouterr().out
    # the damped forecast's scene.json holds the fitted waves only, which do not draw its
    # frames: rendering, re-editing or forecasting it again is refused; the undamped one's do
    for command in (["render", str(tmp_path / "fc")], ["reedit", str(tmp_path / "fc"), "--camera-height", "9"],
                    ["forecast", str(tmp_path / "fc"), "--frames", "0"]):
        assert cli.main(command + ["--out", str(tmp_path / "again")]) == 2
        assert "damped least-squares forecast" in capsys.readouterr().err and not (tmp_path / "again").exists()
    assert cli.main(["render", str(tmp_path / "fc2"), "--out", str(tmp_path / "again")]) == 0


def test_demo_render_stage_and_bad_stage(tmp_path, capsys):
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out), "--stages", "render", "--frames", "2", "--res", "8x12",
                     "--waves", "4"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["frames"] == 2 and "lighting_fit" not in summary
    assert (out / "contact_sheet.png").exists() and (out / "animation.gif").exists()
    # the demo's own frame step (its 24 frames span 8 s), not the other commands' 0.1 s
    from jaxocean.io.scene import read_scene
    assert np.diff(np.asarray(read_scene(out / "render" / "scene.json").times)) == pytest.approx(cli.DEMO_DT)
    assert cli.main(["demo", "--out", str(tmp_path / "d2"), "--stages", "render,paint", "--frames", "1",
                     "--res", "8", "--waves", "4"]) == 2
    assert "unknown demo stages ['paint']" in capsys.readouterr().err
    # a clip given for a stage that does not run is refused, not silently ignored
    assert cli.main(["demo", "--out", str(tmp_path / "d3"), "--stages", "render", "--real", str(tmp_path),
                     "--frames", "1", "--res", "8", "--waves", "4"]) == 2
    assert "the real stage is not among --stages" in capsys.readouterr().err and not (tmp_path / "d3").exists()


@pytest.mark.slow  # the lighting fit compiles for about half a minute on a CPU
def test_demo_lighting_stage(tmp_path, capsys):
    # the demo's waves stage (a 64^2, 8-frame default fit: four minutes on a 2-core CPU) is
    # left to `make demo`; its parts (fit.waves, forecast, the CLI's fit-waves -> forecast)
    # are tested on their own
    out = tmp_path / "demo"
    assert cli.main(["demo", "--out", str(out), "--frames", "2", "--res", "48x64", "--waves", "12",
                     "--stages", "render,lighting"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["lighting_fit"]["success"] and summary["lighting_fit"]["sun_error_deg"] < 0.01
    assert (out / "lighting_fit.png").exists() and "wave_fit" not in summary


# ----------------------------------------------------------------------------- refused before any work (issue 13)


def test_render_refuses_sizes_memory_cannot_hold(tmp_path, capsys, monkeypatch):
    out = tmp_path / "x"
    assert cli.main(["render", "--out", str(out), "--res", "99999x99999"]) == 2  # aborted inside XLA before
    err = capsys.readouterr().err
    assert err.startswith("jaxocean: error: render: 99999x99999 pixels x 24 frame(s) needs about") and "GiB" in err
    assert err.count("\n") == 1 and not out.exists()
    # the estimate is compared with what the machine reports, here a 50 MiB limit
    monkeypatch.setattr(_cli_inputs, "available_memory", lambda: (50 * 2**20, "the test's limit"))
    assert _cli_inputs.render_bytes((256, 256), 100) > 50 * 2**20
    assert cli.main(["simulate", "--out", str(out), "--res", "256", "--frames", "100", "--quiet"]) == 2
    assert "more than the test's limit (0.0488 GiB)" in capsys.readouterr().err and not out.exists()


def test_simulate_refuses_a_dataset_the_disk_cannot_hold(tmp_path, capsys, monkeypatch):
    import shutil
    from collections import namedtuple

    usage = namedtuple("usage", "total used free")
    monkeypatch.setattr(shutil, "disk_usage", lambda path: usage(2**30, 0, 2**20))  # 1 MiB free
    out = tmp_path / "data"
    # 20 scenes x 4 frames x 64^2 pixels at >= 4 bytes each: 1.25 MiB
    assert cli.main(["simulate", "--out", str(out), "--res", "64", "--scenes", "20", "--frames", "4", "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "simulate: needs at least" in err and "of disk" in err and not out.exists()


@pytest.mark.parametrize("argv, message", [
    (["render", "--out", "x", "--frames", "0"], "argument --frames: expected a positive integer; got '0'"),
    (["render", "--out", "x", "--waves", "-1"], "argument --waves: expected a positive integer"),
    (["render", "--out", "x", "--dt", "0"], "argument --dt: expected a positive number"),
    (["simulate", "--out", "x", "--scenes", "0"], "argument --scenes: expected a positive integer"),
    (["demo", "--frames", "0"], "argument --frames: expected a positive integer"),
    (["render", "--out", "x", "--seed", str(2**70)], "argument --seed: expected an integer seed in [0, 2^63)"),
    (["simulate", "--out", "x", "--seed", "-1"], "argument --seed: expected an integer seed in [0, 2^63)"),
])
def test_counts_below_one_are_usage_errors(argv, message, capsys):
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    assert exit_info.value.code == 2 and message in capsys.readouterr().err


def test_out_that_is_a_file_exits_2(tmp_path, capsys):
    existing = tmp_path / "taken"
    existing.write_text("not a directory")
    for argv in (["render", "--out", str(existing), "--frames", "1", "--res", "8", "--waves", "4"],
                 ["simulate", "--out", str(existing), "--scenes", "1", "--frames", "1", "--res", "8", "--quiet"]):
        assert cli.main(argv) == 2  # a FileExistsError traceback, exit 1 before
        assert f"--out {existing}: exists and is not a directory" in capsys.readouterr().err
    assert existing.read_text() == "not a directory"
    assert cli.main(["fit-lighting", str(existing), "--out", str(tmp_path), "--camera-height", "5",
                     "--camera-pitch-deg", "30"]) == 2
    assert "is a directory; give the JSON file to write" in capsys.readouterr().err


@pytest.mark.parametrize("argv, example", [
    (["fit-lighting", "frame.exr"], "fit.json"),
    (["fit-waves", "scene"], "waves.json"),  # it suggested fit.json, a fit-lighting result's name
    (["eval-geometry", "dataset"], "scores.json"),
])
def test_out_directory_for_a_json_file_suggests_the_commands_file(tmp_path, capsys, argv, example):
    assert cli.main(argv + ["--out", str(tmp_path)]) == 2
    assert f"--out {tmp_path}: is a directory; give the JSON file to write, e.g. {tmp_path / example}\n" in \
        capsys.readouterr().err


@pytest.mark.parametrize("argv, expected", [
    (["render", "--frames", "1", "--res", "8", "--waves", "4"], "give the directory to write ('.' for the current"),
    (["simulate", "--scenes", "1", "--frames", "1", "--res", "8", "--quiet"], "give the directory to write"),
    (["fit-waves", "scene"], "give the JSON file to write, e.g. waves.json"),
    (["train-geometry", "dataset"], "give the directory to write"),
])
def test_empty_out_is_refused_not_the_current_directory(tmp_path, monkeypatch, capsys, argv, expected):
    monkeypatch.chdir(tmp_path)  # Path("") is the current directory: it wrote there
    assert cli.main(argv + ["--out", ""]) == 2
    err = capsys.readouterr().err
    assert "--out is empty (an unset shell variable?); " + expected in err, err
    assert not list(tmp_path.iterdir())


def test_render_replaces_the_previous_scene_in_its_directory(tmp_path, capsys):
    out = tmp_path / "r"
    out.mkdir()
    for f in range(5):  # an older, longer scene
        (out / f"frame_{f:05d}.exr").write_bytes(b"old")
        (out / f"frame_{f:05d}.png").write_bytes(b"old")
    (out / "notes.txt").write_text("mine")
    (out / "frame_00009.txt").write_text("mine too")
    assert cli.main(["render", "--out", str(out), "--frames", "2", "--res", "8x12", "--waves", "6"]) == 0
    assert sorted(p.name for p in out.iterdir()) == ["frame_00000.exr", "frame_00000.png", "frame_00001.exr",
                                                     "frame_00001.png", "frame_00009.txt", "normal_00000.png",
                                                     "notes.txt", "roughness_00000.png", "scene.json"]
    assert (out / "frame_00001.exr").read_bytes()[:4] == b"\x76\x2f\x31\x01"
    assert "removed 6 frame file(s) beyond the new 2 frame(s)" in capsys.readouterr().err


@pytest.mark.slow  # simulate, check and two training commands
def test_an_interrupted_simulate_is_named_unfinished_by_check_and_training(tmp_path, capsys, monkeypatch):
    from jaxocean.io import dataset

    calls = []

    def render_then_interrupt(scene):
        calls.append(scene)
        if len(calls) == 2:  # Ctrl-C while rendering the second scene
            raise KeyboardInterrupt
        return render_scene(scene)

    render_scene = dataset.render_scene
    monkeypatch.setattr(dataset, "render_scene", render_then_interrupt)
    root = tmp_path / "ds"
    args = ["--out", str(root), "--scenes", "3", "--frames", "1", "--res", "8", "--waves", "4", "--quiet"]
    assert cli.main(["simulate", *args]) == 130
    capsys.readouterr()
    # not "not a jaxocean dataset": the same simulate command finishes it
    assert cli.main(["check", str(root)]) == 1
    assert "splits.json: missing: an unfinished dataset" in capsys.readouterr().out
    assert cli.main(["eval-geometry", str(root)]) == 2
    err = capsys.readouterr().err
    assert "an unfinished dataset" in err and "run the same simulate command to finish it" in err


def test_an_out_under_a_file_is_refused_before_any_work(tmp_path, capsys):
    note = tmp_path / "notes.txt"
    note.write_text("mine")
    # a directory to write (render), and a JSON file (eval-geometry: refused before its dataset is read)
    for argv in (["render", "--out", str(note / "scene"), "--frames", "1", "--res", "8", "--waves", "2"],
                 ["eval-geometry", str(tmp_path / "no_dataset"), "--out", str(note / "sub" / "scores.json")]):
        assert cli.main(argv) == 2, argv
        assert f"{note} is a file, not a directory" in capsys.readouterr().err, argv
    assert note.read_text() == "mine"


def test_check_of_a_path_that_is_no_dataset_exits_2(tmp_path, capsys):
    assert cli.main(["check", str(tmp_path / "nope_dir")]) == 2
    assert capsys.readouterr().err == f"jaxocean: error: {tmp_path / 'nope_dir'}: no such directory\n"
    assert cli.main(["check", str(tmp_path)]) == 2
    assert "not a jaxocean dataset" in capsys.readouterr().err
    (tmp_path / "dataset.json").write_text("{}")  # a damaged dataset is a problem found: exit 1
    assert cli.main(["check", str(tmp_path)]) == 1
    assert "manifest.json: missing" in capsys.readouterr().out


def test_damaged_or_foreign_frame_is_one_line(tiny_scene, tmp_path, capfd):
    import imageio.v3 as iio

    data = (tiny_scene / "frame_00000.exr").read_bytes()
    (tmp_path / "cut.exr").write_bytes(data[:len(data) // 2])
    iio.imwrite(tmp_path / "photo.exr", np.zeros((16, 16, 3), np.uint8), extension=".png")
    capfd.readouterr()
    for name, what in (("cut.exr", "corrupt or truncated OpenEXR file ((EXR_ERR"),
                       ("photo.exr", "a PNG image, not an OpenEXR file; expected an OpenEXR frame")):
        assert cli.main(["fit-lighting", str(tmp_path / name), "--scene", str(tiny_scene),
                         "--out", str(tmp_path / "fit.json")]) == 2
        out, err = capfd.readouterr()  # file descriptors: what OpenEXR prints from C++ shows here
        assert out == "" and err.startswith(f"jaxocean: error: {tmp_path / name}: {what}") and err.count("\n") == 1


@pytest.mark.parametrize("command", ["render", "demo", "fit-lighting", "reedit", "forecast"])
def test_every_command_names_the_camera_alike(command, capsys):
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    text = capsys.readouterr().out
    for option in ("--camera-height", "--camera-pitch-deg", "--camera-fov-deg", "--camera-yaw-deg"):
        assert option in text, option
    assert ("--res" in text) == (command != "fit-lighting")  # a frame has its own resolution
    assert "--pitch " not in text and "--fov " not in text


def test_render_camera_options_and_the_old_names(tmp_path, capsys):
    out = tmp_path / "r"
    assert cli.main(["render", "--out", str(out), "--frames", "2", "--res", "8x12", "--waves", "6",
                     "--camera-pitch-deg", "30", "--camera-fov-deg", "50", "--camera-yaw-deg", "10"]) == 0
    camera = json.loads((out / "scene.json").read_text())["camera"]
    assert [camera["pitch"], camera["fov"], camera["yaw"]] == pytest.approx([math.radians(a) for a in (30, 50, 10)])
    # the former render-only names still work, with a note
    args = cli.build_parser().parse_args(["render", "--out", "o", "--pitch", "31", "--fov", "51"])
    assert (args.camera_pitch_deg, args.camera_fov_deg) == (31.0, 51.0)
    assert "--pitch is deprecated; use --camera-pitch-deg" in capsys.readouterr().err
    args = cli.build_parser().parse_args(["render", "--out", "o"])
    cli._scene_option_values(args)  # the defaults, filled in once the command knows there is no SCENE
    assert args.camera_pitch_deg == 20.0


@pytest.mark.parametrize("command, argv, message", [
    ("simulate", ["simulate", "--out", "{tmp}/ds", "--scenes", "1", "--frames", "1", "--res", "8", "--quiet"],
     "completed scenes are kept; run the same command to resume"),
    ("fit-waves", ["fit-waves", "{scene}", "--out", "{tmp}/w.json"],
     "nothing was written; running the command again starts the fit over"),
    ("render", ["render", "--out", "{tmp}/r", "--frames", "1", "--res", "8", "--waves", "4"],
     "running the command again renders every frame again"),
])
def test_interrupt_says_what_a_rerun_does(command, argv, message, tiny_scene, tmp_path, capsys, monkeypatch):
    def interrupted(args):
        raise KeyboardInterrupt

    monkeypatch.setitem(cli.COMMANDS, command, interrupted)
    argv = [a.format(tmp=tmp_path, scene=tiny_scene) for a in argv]
    assert cli.main(argv) == 130
    err = capsys.readouterr().err
    assert message in err and (command == "simulate" or "resume" not in err)


def test_forecast_refuses_a_failed_fit_and_other_json(tiny_scene, tmp_path, capsys):
    from jaxocean import io

    scene = io.read_scene(tiny_scene)
    failed = tmp_path / "waves.json"  # what fit-waves writes when its fit failed
    io.write_scene(failed, io.scene_to_dict(waves=scene.waves, camera=scene.camera, lighting=scene.lighting,
                                            times=scene.times, extra={"wave_fit": {"success": False,
                                                                                   "normal_error_deg": 2.5}}))
    out = tmp_path / "fc"
    assert cli.main(["forecast", str(failed), "--frames", "0", "--out", str(out)]) == 2  # ran, exit 0 before
    err = capsys.readouterr().err
    assert "the wave fit does not report success (success: false, mean normal error 2.5 deg)" in err
    assert "--allow-failed" in err and not out.exists()
    assert cli.main(["forecast", str(failed), "--frames", "0", "--out", str(out), "--allow-failed"]) == 0
    assert "warning: forecasting the waves of a fit that does not report success" in capsys.readouterr().err
    assert (out / "frame_00000.exr").exists()
    # only a JSON true vouches for the waves: a hand-edited "false" or no flag at all does not
    for wave_fit, shown in (({"success": "false"}, 'success: "false"'), ({"normal_error_deg": 0.1}, "success: missing")):
        edited = tmp_path / "edited.json"
        io.write_scene(edited, io.scene_to_dict(waves=scene.waves, camera=scene.camera, lighting=scene.lighting,
                                                times=scene.times, extra={"wave_fit": wave_fit}))
        assert cli.main(["forecast", str(edited), "--frames", "0", "--out", str(tmp_path / "fc2")]) == 2
        assert shown in capsys.readouterr().err
    # a lighting fit's JSON is named as such, not as a scene missing 'version'
    light = tmp_path / "fit.json"
    light.write_text(json.dumps({"lighting": {"sun_azimuth": 0.1}, "loss": 1e-6, "rms_residual": 1e-3,
                                 "success": True, "frame": "f.exr"}))
    assert cli.main(["forecast", str(light), "--frames", "0", "--out", str(tmp_path / "fc2")]) == 2
    assert capsys.readouterr().err == (f"jaxocean: error: {light}: this is a lighting fit result (jaxocean "
                                       f"fit-lighting); forecast needs waves (a fit-waves result or a scene.json)\n")


def test_forecast_names_a_malformed_least_squares_section(tiny_scene, tmp_path, capsys):
    from jaxocean import io

    scene = io.read_scene(tiny_scene)
    good = {"window_s": [0.0, 0.3], "frequency_sigma": [0.01, 0.01, 0.1],
            "band": {"amplitude": [0.01], "omega": [1.5], "theta": [0.2], "phase": [0.3]}}
    broken = ({k: v for k, v in good.items() if k != "window_s"}, "malformed (KeyError: 'window_s')",
              dict(good, band=dict(good["band"], omega=[1.5, 2.0])), "band lists of one length")
    for forecast_section, message in zip(broken[::2], broken[1::2]):
        edited = tmp_path / "waves.json"
        io.write_scene(edited, io.scene_to_dict(waves=scene.waves, camera=scene.camera, lighting=scene.lighting,
                                                times=scene.times, extra={"wave_fit": {
                                                    "success": True, "forecast": forecast_section}}))
        assert cli.main(["forecast", str(edited), "--frames", "0", "--out", str(tmp_path / "fc")]) == 2
        assert message in capsys.readouterr().err


def test_compile_cache_folder(monkeypatch, tmp_path):
    monkeypatch.setenv("JAXOCEAN_COMPILE_CACHE", "0")
    assert compile_cache.folder() is None
    monkeypatch.setenv("JAXOCEAN_COMPILE_CACHE", str(tmp_path / "c"))
    assert compile_cache.folder() == tmp_path / "c"
    monkeypatch.delenv("JAXOCEAN_COMPILE_CACHE")
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    assert compile_cache.folder() == tmp_path / "jaxocean" / "xla"


def test_compile_cache_enable_sets_jax_and_respects_off(monkeypatch, tmp_path):
    import jax

    calls = []
    monkeypatch.setattr(jax.config, "update", lambda name, value: calls.append((name, value)))
    monkeypatch.setenv("JAXOCEAN_COMPILE_CACHE", "0")
    assert compile_cache.enable() is None and calls == []
    assert compile_cache.enable(tmp_path / "x") == tmp_path / "x"
    assert calls == [("jax_compilation_cache_dir", str(tmp_path / "x")),
                     ("jax_persistent_cache_min_compile_time_secs", compile_cache.MIN_COMPILE_TIME_S)]


def test_demo_sea_lines_say_when_the_spectrum_failed_and_what_is_a_bound():
    from jaxocean import cli

    failed = cli._sea_caveat({"stages": {"spectrum": {"success": False}}, "bound": None})
    assert "failed: not a measurement" in failed
    bound = cli._sea_caveat({"stages": {"spectrum": {"success": True}}, "bound": "Hs is a lower bound"})
    assert bound == "; Hs is a lower bound"
    # no sea state is no number, not "nan"
    assert cli._value(float("nan"), ".2f", " m") == cli._value(None, ".1f") == "n/a"
    assert cli._value(1.234, ".2f", " m") == "1.23 m"


@pytest.mark.parametrize("extra, message", [
    (["--gamma", "1.8"], "--gamma is the exponent of --response gamma; the response is srgb"),
    (["--per-frame-exposure", "--no-refine"], "--per-frame-exposure sets stage 5's exposures, and --no-refine"),
])
def test_reconstruct_refuses_options_it_would_ignore(extra, message, tmp_path, capsys):
    # an option with no effect on the run asked for is an error, not silently dropped
    assert cli.main(["reconstruct", "--camera", str(tmp_path / "none.json"), "--out", str(tmp_path / "out"),
                     *extra]) == 2
    assert message in capsys.readouterr().err


@pytest.mark.parametrize("command", ["render", "demo", "reedit", "forecast"])
def test_sun_elevation_out_of_range_is_named_in_degrees(command, tmp_path, capsys):
    # --sun-elevation 100 reached the library and came back as "[-pi/2, pi/2] rad; got
    # [1.745...]": the user gave degrees
    argv = [command] + (["scene.json"] if command in ("reedit", "forecast") else []) + \
        (["--frames", "0"] if command == "forecast" else []) + ["--out", str(tmp_path / "o"), "--sun-elevation", "100"]
    with pytest.raises(SystemExit) as exit_info:
        cli.main(argv)
    err = capsys.readouterr().err
    assert exit_info.value.code == 2 and "a sun elevation in degrees, in [-90, 90]; got '100'" in err
    assert "rad" not in err and not (tmp_path / "o").exists()
    assert _cli_inputs.sun_elevation_degrees("90") == 90.0 and _cli_inputs.sun_elevation_degrees("-90") == -90.0


def test_reedit_of_some_frames_names_their_source_frames(tiny_scene, tmp_path):
    from jaxocean import io

    # reedit --frames 1,2 wrote frame metadata 0, 1 beside the times of frames 1 and 2
    out = tmp_path / "edited"
    assert cli.main(["reedit", str(tiny_scene), "--frames", "1,2", "--out", str(out)]) == 0
    source = [io.read_frame(tiny_scene / f"frame_0000{i}.exr").meta for i in (1, 2)]
    edited = [io.read_frame(out / f"frame_0000{i}.exr").meta for i in (0, 1)]
    assert [m["frame"] for m in edited] == [1, 2]
    assert [m["time"] for m in edited] == pytest.approx([m["time"] for m in source])
    assert json.loads((out / "scene.json").read_text())["extra"]["reedited_frames"] == [1, 2]


def test_demo_help_names_what_its_default_stages_write(capsys):
    # the description promised a lighting fit and a wave fit, which run only when asked for
    with pytest.raises(SystemExit):
        cli.main(["demo", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "(by default reconstruct and real)" in out and "reconstruct_vs_truth.png" in out
    assert "on request, fit the lighting" in out
    # its --dt help says the demo's own default step, not the other commands' 0.1 s
    assert "time between frames [s] (default 0.3333)" in out and "(default 0.1)" not in out


def test_demo_rerun_with_fewer_stages_leaves_no_old_figure(tmp_path, capsys):
    # a figure of a previous demo's stage stayed in --out beside a summary.json without it
    out = tmp_path / "demo"
    out.mkdir()
    for name in ("lighting_fit.png", "wave_fit.png", "forecast_strip.png", "reconstruct_vs_truth.png"):
        (out / name).write_bytes(b"old")
    (out / "mine.png").write_bytes(b"user's")
    assert cli.main(["demo", "--out", str(out), "--stages", "render", "--frames", "1", "--res", "8",
                     "--waves", "2"]) == 0
    assert sorted(p.name for p in out.glob("*.png")) == ["contact_sheet.png", "mine.png"]
    assert "removed 4 figure(s) of a previous demo" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["fit-lighting", "fit-waves"])
def test_fit_help_says_exit_1_means_no_success(command, capsys):
    # the help said "exit code 1 when the fit does not converge"; a converged fit that leaves a
    # field undetermined (no glitter: the sun) exits 1 too
    with pytest.raises(SystemExit):
        cli.main([command, "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "Exit code 1 when the fit does not succeed".lower() in out.lower() and "not converge" not in out


def test_demo_contact_sheet_rows_name_their_times(tmp_path, monkeypatch):
    # with --dt 0.01 every row read "t = 0.0 s"
    from jaxocean import plots

    seen = {}
    real = plots.contact_sheet
    monkeypatch.setattr(plots, "contact_sheet", lambda path, rows, **kw: seen.update(kw) or real(path, rows, **kw))
    assert cli.main(["demo", "--out", str(tmp_path / "demo"), "--stages", "render", "--frames", "3", "--dt", "0.01",
                     "--res", "8", "--waves", "2"]) == 0
    assert seen["row_titles"] == ["t = 0 s", "t = 0.01 s", "t = 0.02 s"]


def test_fit_lighting_names_a_fit_result_given_as_its_scene(tiny_scene, tmp_path, capsys):
    # --scene fit.json (a fit-lighting result) said only "scene is missing key(s) ['version']"
    (tmp_path / "fit.json").write_text(json.dumps({"lighting": {}, "rms_residual": 0.0, "success": True}))
    assert cli.main(["fit-lighting", str(tiny_scene / "frame_00000.exr"), "--scene", str(tmp_path / "fit.json"),
                     "--out", str(tmp_path / "again.json")]) == 2
    err = capsys.readouterr().err
    assert "this is a lighting fit result (jaxocean fit-lighting)" in err and "--scene takes" in err
    assert not (tmp_path / "again.json").exists()


def test_reconstruct_names_a_fit_result_given_as_its_camera(tmp_path, capsys):
    # --camera fit.json (a fit-lighting result) said only "scene is missing key(s) ['version']"
    (tmp_path / "fit.json").write_text(json.dumps({"lighting": {}, "rms_residual": 0.0, "success": True,
                                                   "camera": {"height": 10.0}}))
    assert cli.main(["reconstruct", "--camera", str(tmp_path / "fit.json"), "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert "this is a lighting fit result (jaxocean fit-lighting)" in err and "--camera takes a camera file" in err


def test_a_dataset_json_is_named_as_such(tmp_path, capsys):
    # dataset.json carries a version, as a scene does: it was read as a scene with unknown keys
    settings = tmp_path / "dataset.json"
    settings.write_text(json.dumps({"scenes": 2, "frames": 2, "resolution": [8, 8], "seed": 0, "half": True,
                                    "ranges": {}, "version": "0.1.0"}))
    assert cli.main(["render", str(settings), "--out", str(tmp_path / "out")]) == 2
    assert "this is a dataset's settings (dataset.json" in capsys.readouterr().err
    assert cli.main(["reconstruct", "--camera", str(settings), "--out", str(tmp_path / "run")]) == 2
    assert "this is a dataset's settings (dataset.json" in capsys.readouterr().err


def test_demo_help_claims_only_what_reconstruct_vs_truth_shows(capsys):
    # the help promised the reconstruction "forecast and re-edited beside the truth"; the figure
    # holds the forecast rows only (the re-edited views are in the reconstruct report)
    with pytest.raises(SystemExit):
        cli.main(["demo", "--help"])
    out = " ".join(capsys.readouterr().out.split())
    assert "re-edited beside the truth" not in out and "re-edited views in reconstruct/report.html" in out


def test_render_and_reedit_refuse_far_future_times(tiny_scene, tmp_path, capsys):
    # each frame renders under jit, where render's own check cannot see the time: a scene at
    # t = 1e7 s (float32 phases rounded by radians) rendered wrong phases without a word
    spec = json.loads((tiny_scene / "scene.json").read_text())
    spec["times"] = [1e7]
    (tmp_path / "far").mkdir()
    (tmp_path / "far" / "scene.json").write_text(json.dumps(spec))
    for command in ("render", "reedit"):
        assert cli.main([command, str(tmp_path / "far"), "--out", str(tmp_path / command)]) == 2
        assert "too far from t = 0 for float32" in capsys.readouterr().err
        assert not (tmp_path / command).exists()


@pytest.mark.filterwarnings("default::UserWarning")  # shown, as outside the test suite, not raised
def test_render_prints_a_steep_draw_as_a_cli_warning(tmp_path, capsys, monkeypatch):
    # a library warning was printed by Python with its file and source line. The suite records
    # warnings instead of showing them: shown here as Python shows them, through formatwarning
    # (the camera under the sea stops the command after the draw, before any rendering)
    import warnings

    monkeypatch.setattr(warnings, "showwarning", lambda message, category, filename, lineno, file=None, line=None:
                        sys.stderr.write(warnings.formatwarning(message, category, filename, lineno, line)))
    assert cli.main(["render", "--out", str(tmp_path / "a"), "--res", "8x8", "--frames", "1", "--waves", "2",
                     "--tp", "0.001", "--camera-height=-1"]) == 2
    err = capsys.readouterr().err
    assert "jaxocean: warning: 2 of 2 sampled waves have k*h above max_steepness" in err
    assert "SteepnessWarning" not in err and ".py:" not in err, err


def test_render_stores_the_hs_its_clamped_waves_carry(tmp_path):
    # scene.json's spectrum is the requested sea; a steep draw's waves carry less, and say so
    from jaxocean import spectrum
    from jaxocean.io.scene import read_scene

    with pytest.warns(spectrum.SteepnessWarning):
        assert cli.main(["render", "--out", str(tmp_path / "a"), "--res", "8x8", "--frames", "1", "--waves", "8",
                         "--hs", "10", "--tp", "3", "--camera-height", "30"]) == 0
    scene = read_scene(tmp_path / "a")
    amplitude = np.asarray(scene.waves.amplitude, np.float64)
    assert float(scene.spectrum.hs) == pytest.approx(10.0)
    assert scene.extra["clamped_waves"] > 0
    assert scene.extra["waves_hs_m"] == pytest.approx(4 * np.sqrt(np.sum(amplitude ** 2) / 2), rel=1e-6)
    assert scene.extra["waves_hs_m"] < 0.9 * 10.0


def test_reconstruct_of_a_video_without_a_plugin_exits_2_saying_what_to_install(tmp_path, capsys, monkeypatch):
    # an MP4 without PyAV or imageio-ffmpeg ended in a traceback of an ImportError
    from jaxocean.io import images

    monkeypatch.setattr(images, "_video_plugin_available", lambda: False)
    (tmp_path / "clip.mp4").write_bytes(b"\x00" * 64)
    (tmp_path / "camera.json").write_text("{}")
    assert cli.main(["reconstruct", str(tmp_path / "clip.mp4"), "--camera", str(tmp_path / "camera.json"),
                     "--out", str(tmp_path / "run")]) == 2
    err = capsys.readouterr().err
    assert err.startswith("jaxocean: error: reading the video") and "pip install 'imageio[pyav]'" in err


@pytest.mark.parametrize("flags, expected", [(None, "cores"), ("--xla_force_host_platform_device_count=1", 1)])
def test_the_network_commands_split_the_cpu_into_one_device_per_core_unless_told(flags, expected):
    cores = len(os.sched_getaffinity(0))
    expected = cores if expected == "cores" else expected
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", "JAX_NUM_CPU_DEVICES")}
    if flags:
        env["XLA_FLAGS"] = flags
    script = "import jax; from jaxocean import cli; cli._one_cpu_device_per_core(); print(jax.local_device_count())"
    run = subprocess.run([sys.executable, "-c", script], env=dict(env, JAX_PLATFORMS="cpu"), capture_output=True,
                         text=True, timeout=120)
    assert run.returncode == 0, run.stderr[-2000:]
    assert int(run.stdout.split()[-1]) == expected
    # in a process whose JAX runs already the devices stay as they are, without an error
    before = jax.local_device_count()
    cli._one_cpu_device_per_core()
    assert jax.local_device_count() == before
