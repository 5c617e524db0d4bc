import json
from pathlib import Path

import jax
import numpy as np
import pytest

from jaxocean.errors import InvalidValueError
from jaxocean.io import dataset

SMALL = dict(n_scenes=3, n_frames=2, resolution=(12, 16), seed=7)
RANGES = dataset.SceneRanges(n_waves=8)


def _files(root: Path):
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()}


@pytest.fixture(scope="module")
def clean(tmp_path_factory):
    root = tmp_path_factory.mktemp("clean")
    stats = dataset.simulate(root, ranges=RANGES, progress=False, **SMALL)
    return root, stats


def test_simulate_check_load_cycle(clean):
    root, stats = clean
    assert stats["generated"] == 3 and stats["skipped"] == 0
    assert dataset.check(root) == []
    ds = dataset.Dataset(root)
    split = ds.splits
    assert sorted(split["train"] + split["val"] + split["test"]) == [0, 1, 2]
    batch = next(ds.batches(jax.random.key(0), "train", batch_size=1, sequence=2))
    assert batch.image.shape == (1, 2, 12, 16, 3) and batch.normal.shape == (1, 2, 12, 16, 3)
    assert batch.roughness.shape == (1, 2, 12, 16) and batch.mask.dtype == bool
    assert batch.waves.omega.shape == (1, 8) and batch.times.shape == (1, 2)
    assert np.all(np.diff(batch.times[0]) > 0)
    # normals are unit where the sea is seen (stored as float32)
    n = batch.normal[batch.mask]
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-5)
    assert batch.slope_variance.shape == (1, 2, 12, 16, 2)


def test_loaded_geometry_reproduces_the_images(clean):
    # the loader hands out what each image was shaded with: re-shading a batch gives its
    # images to the half-float RGB storage (relative 2^-11) plus the 24-bit geometry's
    # (PXR24: relative 2^-16 in the normal, amplified in the glitter; measured <= 1.4e-4)
    from jaxocean import render

    root, _ = clean
    ds = dataset.Dataset(root)
    batch = next(ds.batches(jax.random.key(1), "train", batch_size=1))
    camera, lighting = (jax.tree.map(lambda x: x[0], tree) for tree in (batch.camera, batch.lighting))
    shaded = render.shade(batch.normal[0, 0], batch.roughness[0, 0], camera, lighting,
                          slope_variance=batch.slope_variance[0, 0])
    np.testing.assert_allclose(np.asarray(shaded), batch.image[0, 0], rtol=2.0**-11 + 2.5e-4, atol=3e-8)


def test_half_frames_store_the_geometry_to_24_bits_and_float32_frames_exactly(clean, tmp_path):
    # PXR24 for half-float frames: the geometry is the rendered one rounded to 24 bits (not
    # bit-exact, relative error <= 2^-16), the half channels exact; float32 frames are exact
    root, _ = clean
    exact = tmp_path / "exact"
    dataset.simulate(exact, ranges=RANGES, progress=False, half=False, **SMALL)
    scene = dataset.sample_scene(jax.random.fold_in(jax.random.key(SMALL["seed"]), 0), RANGES,
                                 SMALL["resolution"], SMALL["n_frames"])
    images, geo = dataset.render_scene(scene)
    normal = np.asarray(geo.normal[0], np.float32)
    half = dataset.Dataset(root).frame(0, 0)
    full = dataset.Dataset(exact).frame(0, 0)
    np.testing.assert_array_equal(full.normal, normal)
    np.testing.assert_array_equal(full.image, np.asarray(images[0], np.float32))
    np.testing.assert_array_equal(half.image, np.asarray(images[0], np.float16).astype(np.float32))
    np.testing.assert_array_equal(half.mask, full.mask)
    assert not np.array_equal(half.normal, normal)  # rounded: the test can tell the two apart
    np.testing.assert_allclose(half.normal, normal, rtol=2.0**-16, atol=2.0**-16 * np.abs(normal).max())


def test_frames_without_slope_variance_load_with_one_warning(clean, tmp_path):
    import shutil

    from jaxocean.io import IncompleteFrameWarning, read_frame, write_frame

    root, _ = clean
    old = tmp_path / "old"
    shutil.copytree(root, old)
    for path in old.glob("scene_*/frame_*.exr"):  # as written before slope_variance was stored
        frame = read_frame(path)
        write_frame(path, frame.image, frame._replace(slope_variance=None), frame.meta)
    assert dataset.check(old, read_frames=True) != []  # hashes changed, but no warning from check
    ds = dataset.Dataset(old)
    with pytest.warns(IncompleteFrameWarning, match="slope_variance") as record:
        batches = list(ds.batches(jax.random.key(0), "train", batch_size=1, sequence=2))
    assert len(record) == 1 and len(batches) >= 1
    assert all(b.slope_variance is None and b.normal.shape == (1, 2, 12, 16, 3) for b in batches)


def test_resume_after_crash_equals_clean_run(clean, tmp_path, monkeypatch):
    root, _ = clean
    original = dataset._write_scene_files

    def crash_on_scene_two(out, index, *args, **kwargs):
        if index == 2:
            raise KeyboardInterrupt("simulated kill")
        return original(out, index, *args, **kwargs)

    monkeypatch.setattr(dataset, "_write_scene_files", crash_on_scene_two)
    with pytest.raises(KeyboardInterrupt):
        dataset.simulate(tmp_path, ranges=RANGES, progress=False, **SMALL)
    assert not (tmp_path / "scene_00002" / "scene.json").exists()
    assert not (tmp_path / "manifest.json").exists()
    monkeypatch.setattr(dataset, "_write_scene_files", original)
    stats = dataset.simulate(tmp_path, ranges=RANGES, progress=False, **SMALL)
    assert stats["skipped"] == 2 and stats["generated"] == 1
    assert _files(tmp_path) == _files(root)  # byte-identical, no stray temporary files


def test_rerun_renders_again_scenes_that_differ_from_the_manifest(clean, tmp_path):
    # a finished dataset rerun: a damaged file is not blessed into a new manifest
    root, _ = clean
    copy = _copy(root, tmp_path)
    truncated = copy / "scene_00001" / "frame_00001.exr"
    truncated.write_bytes(truncated.read_bytes()[:100])
    flipped = copy / "scene_00002" / "frame_00000.exr"
    data = bytearray(flipped.read_bytes())
    data[len(data) // 2] ^= 0xFF  # same size, one byte changed
    flipped.write_bytes(bytes(data))
    stats = dataset.simulate(copy, ranges=RANGES, progress=False, **SMALL)
    assert stats["repaired"] == [1, 2] and stats["generated"] == 2 and stats["skipped"] == 1
    assert _files(copy) == _files(root)  # rendered again, byte-identical, manifest as before
    assert dataset.check(copy) == []


def test_check_names_corrupt_and_missing_files(clean, tmp_path):
    import shutil

    root, _ = clean
    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    flipped = copy / "scene_00001" / "frame_00001.exr"
    data = bytearray(flipped.read_bytes())
    data[len(data) // 2] ^= 0xFF  # same size, one byte changed
    flipped.write_bytes(bytes(data))
    truncated = copy / "scene_00002" / "frame_00000.exr"
    truncated.write_bytes(truncated.read_bytes()[:100])
    (copy / "scene_00000" / "frame_00000.exr").unlink()
    problems = dataset.check(copy)
    assert any("scene_00001/frame_00001.exr" in p and "SHA-256" in p for p in problems)
    assert any("scene_00002/frame_00000.exr" in p and "size 100" in p for p in problems)
    assert any("scene_00000/frame_00000.exr: missing" in p for p in problems)
    assert len(problems) == 3


def test_check_names_a_directory_where_the_manifest_has_a_file(clean, tmp_path):
    # a directory of the recorded size in a frame's place stopped check with "[Errno 21] Is
    # a directory" (exit code 2, "not a dataset") instead of reporting the problem
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(clean[0], copy)
    frame = copy / "scene_00001" / "frame_00000.exr"
    frame.unlink()
    frame.mkdir()
    manifest = json.loads((copy / "manifest.json").read_text())
    manifest["files"]["scene_00001/frame_00000.exr"]["bytes"] = frame.stat().st_size
    (copy / "manifest.json").write_text(json.dumps(manifest))
    assert dataset.check(copy, read_frames=False) == [f"{frame}: not a file"]


def _copy(root, tmp_path):
    import shutil

    copy = tmp_path / "copy"
    shutil.copytree(root, copy)
    return copy


@pytest.mark.parametrize("name, edit, message", [
    ("manifest.json", lambda d: {"files": 5}, "'files' must map relative paths"),
    ("manifest.json", lambda d: {"files": {k: {"bytes": v["bytes"]} for k, v in d["files"].items()}},
     "an entry must be"),
    ("manifest.json", lambda d: {"files": {**d["files"], "../elsewhere.exr": {"bytes": 1, "sha256": "0" * 64}}},
     "stay inside it"),
    ("dataset.json", lambda d: {k: v for k, v in d.items() if k != "resolution"}, "'resolution' must be"),
    ("dataset.json", lambda d: {**d, "frames": "2"}, "'frames' must be an integer"),
    ("splits.json", lambda d: {**d, "test": [0, 99]}, "split 'test' must be a list of scene indices in"),
    ("splits.json", lambda d: {**d, "test": d["train"][:1]}, "again in 'test'"),
])
def test_check_and_loader_name_a_malformed_dataset_file(clean, tmp_path, name, edit, message):
    copy = _copy(clean[0], tmp_path)
    path = copy / name
    path.write_text(json.dumps(edit(json.loads(path.read_text()))))
    problems = dataset.check(copy, read_frames=False)
    assert len(problems) == 1 and str(path) in problems[0] and message in problems[0], problems
    if name != "manifest.json":
        with pytest.raises(InvalidValueError, match=message):
            dataset.Dataset(copy)


def test_check_reports_scenes_and_files_the_dataset_does_not_hold(clean, tmp_path):
    import shutil

    copy = _copy(clean[0], tmp_path)
    shutil.copytree(copy / "scene_00002", copy / "scene_00003")  # a fourth scene of a 3-scene dataset
    manifest = json.loads((copy / "manifest.json").read_text())
    extra = {k.replace("scene_00002", "scene_00003"): v for k, v in manifest["files"].items() if "scene_00002" in k}
    (copy / "manifest.json").write_text(json.dumps({"files": {**manifest["files"], **extra}}))
    shutil.copy(copy / "scene_00000" / "frame_00001.exr", copy / "scene_00000" / "frame_00002.exr")
    problems = dataset.check(copy, read_frames=False)
    assert sum("scene_00003" in p and "not one of the 3 scene(s) x 2 frame(s)" in p for p in problems) == 3
    assert sum("scene_00000/frame_00002.exr: not in the manifest" in p for p in problems) == 1
    assert len(problems) == 4, problems


@pytest.mark.parametrize("seed", [-1, 2**63, 1.5, True])
def test_simulate_refuses_a_seed_outside_int64(tmp_path, seed):
    with pytest.raises(InvalidValueError, match=r"seed must be an integer in \[0, 2\^63\)"):
        dataset.simulate(tmp_path / "d", ranges=RANGES, progress=False, **{**SMALL, "seed": seed})
    assert not (tmp_path / "d").exists()


def test_other_settings_refuse_to_mix(clean):
    root, _ = clean
    with pytest.raises(InvalidValueError, match="other settings.*resolution"):
        dataset.simulate(root, ranges=RANGES, progress=False, **{**SMALL, "resolution": (8, 8)})


def test_paper_splits():
    s = dataset.split_scenes(2000, seed=0)
    assert len(s["test"]) == 200 and len(s["val"]) == 180 and len(s["train"]) == 1620
    assert not set(s["test"]) & set(s["train"]) and not set(s["val"]) & set(s["train"])
    assert dataset.split_scenes(2000, seed=0) == s and dataset.split_scenes(2000, seed=1) != s


def test_scene_sampling_respects_ranges():
    r = dataset.SceneRanges(n_waves=5)
    for i in range(4):
        sc = dataset.sample_scene(jax.random.key(i), r, (8, 8), 3)
        assert r.camera_height[0] <= float(sc.camera.height) <= r.camera_height[1]
        assert r.pitch[0] <= float(sc.camera.pitch) <= r.pitch[1]
        assert r.hs[0] <= float(sc.spectrum.hs) <= r.hs[1]
        assert sc.waves.omega.shape == (5,) and sc.times.shape == (3,)
        dt = np.diff(np.asarray(sc.times))
        assert np.all((dt >= r.frame_dt[0] - 1e-6) & (dt <= r.frame_dt[1] + 1e-6))
    with pytest.raises(ValueError, match="unknown scene range"):
        dataset.SceneRanges.from_json({"wind": [1, 2]})


@pytest.mark.parametrize("field, value, message", [
    ("hs", (2.0, 0.5), "'hs' is reversed"),  # uniform(lo > hi) would give every scene lo
    ("hs", 1.0, "'hs' must be a pair"),
    ("hs", (0.5, "2"), "'hs' must be a pair"),
    ("hs", (-1.0, 0.5), "'hs' must be > 0"),
    ("pitch", (0.3, 2.0), "'pitch' must be > 0 and <= 1.5708"),
    ("sky_color", ((0.1, 0.2, 0.3), (0.2, 0.1, 0.4)), "'sky_color' is reversed"),
    ("sea_color", (0.0, 0.1), "'sea_color' must be a pair"),
    ("frame_dt", (0.1, float("nan")), "'frame_dt' must be a finite number"),
    ("n_waves", 0, "'n_waves' must be >= 1"),
    ("pm_fraction", 1.5, "'pm_fraction' must be >= 0 and <= 1"),
])
def test_ranges_outside_their_domain_are_refused_before_any_work(tmp_path, field, value, message):
    with pytest.raises(ValueError, match=message):
        dataset.SceneRanges.from_json({**dataset.SceneRanges().to_json(), field: value})
    with pytest.raises(ValueError, match=message):
        dataset.simulate(tmp_path / "ds", 1, 1, (8, 8), 0, dataset.SceneRanges()._replace(**{field: value}),
                         progress=False)
    assert not (tmp_path / "ds").exists()
    with pytest.raises(ValueError, match=message):
        dataset.sample_scene(jax.random.key(0), dataset.SceneRanges()._replace(**{field: value}), (8, 8), 1)


def test_a_single_value_range_gives_that_value():
    sc = dataset.sample_scene(jax.random.key(3), dataset.SceneRanges(hs=(1.25, 1.25), n_waves=4), (8, 8), 1)
    assert float(sc.spectrum.hs) == pytest.approx(1.25)


def test_a_malformed_dataset_file_is_named(tmp_path):
    (tmp_path / "dataset.json").write_text("{")
    (tmp_path / "splits.json").write_text("{}")
    with pytest.raises(ValueError, match=r"dataset.json: malformed JSON in this dataset settings file.*line 1"):
        dataset.Dataset(tmp_path)


def test_dataset_json_records_settings(clean):
    root, _ = clean
    settings = json.loads((root / "dataset.json").read_text())
    assert settings["resolution"] == [12, 16] and settings["ranges"]["n_waves"] == 8


def test_frames_brighter_than_half_floats_are_stored_exactly(tmp_path):
    # a sun this bright puts glitter beyond 65504: the frame keeps float32 RGB instead of failing
    ranges = dataset.SceneRanges(sun_scale=(20000.0, 20001.0), sun_azimuth=(0.0, 0.01), sun_elevation=(0.55, 0.6),
                                 pitch=(0.55, 0.6))
    dataset.simulate(tmp_path, 1, 1, (24, 24), seed=1, ranges=ranges, progress=False)
    scene = dataset.sample_scene(jax.random.fold_in(jax.random.key(1), 0), ranges, (24, 24), 1)
    images, _ = dataset.render_scene(scene)
    assert float(np.abs(images).max()) > 65504.0
    frame = dataset.Dataset(tmp_path).frame(0, 0)
    np.testing.assert_array_equal(frame.image, np.asarray(images[0], np.float32))


def test_loaded_converged_flags_are_the_rendered_ones(clean):
    # Batch.converged: where each frame's ray-surface hits are exact, as render_scene made them
    root, _ = clean
    ds = dataset.Dataset(root)
    batch = next(ds.batches(jax.random.key(2), "train", batch_size=1, sequence=2))
    assert batch.converged.shape == (1, 2, 12, 16) and batch.converged.dtype == bool
    index = next(s for s in ds.splits["train"]
                 if np.array_equal(np.asarray(ds.scene(s).times)[:2], batch.times[0]))
    scene = dataset.sample_scene(jax.random.fold_in(jax.random.key(SMALL["seed"]), index), RANGES,
                                 SMALL["resolution"], SMALL["n_frames"])
    _, geo = dataset.render_scene(scene)
    np.testing.assert_array_equal(batch.converged[0], np.asarray(geo.converged))


def test_a_clamped_draw_stores_the_hs_its_waves_carry(tmp_path):
    # scene.json held the requested Hs (spectrum.hs) beside waves the steepness limit had
    # clamped well below it, and nothing said so
    from jaxocean import spectrum
    from jaxocean.io.scene import read_scene

    steep = dataset.SceneRanges(hs=(10.0, 10.0), tp=(3.0, 3.0), n_waves=8, camera_height=(30.0, 30.0))
    with pytest.warns(spectrum.SteepnessWarning):
        dataset.simulate(tmp_path, 1, 1, (8, 8), seed=0, ranges=steep, progress=False)
    scene = read_scene(dataset.scene_dir(tmp_path, 0))
    amplitude = np.asarray(scene.waves.amplitude, np.float64)
    assert float(scene.spectrum.hs) == pytest.approx(10.0)  # the requested sea
    assert scene.extra["clamped_waves"] > 0
    assert scene.extra["waves_hs_m"] == pytest.approx(4 * np.sqrt(np.sum(amplitude ** 2) / 2), rel=1e-6)
    assert scene.extra["waves_hs_m"] < 0.9 * 10.0  # 7.8 m
    # an unclamped draw says so too
    calm = dataset.sample_scene(jax.random.key(0), dataset.SceneRanges(hs=(0.3, 0.3), tp=(8.0, 8.0), n_waves=8),
                                (8, 8), 1)
    assert calm.clamped_waves == 0
