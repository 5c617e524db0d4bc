import json

import pytest

from jaxocean import cli


@pytest.mark.parametrize("command", ["render", "simulate", "check", "demo"])
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
