"""Synthetic datasets: scene sampling, resumable generation, verification and loading.

Protocol
--------
A dataset is a directory::

    dataset.json                 generation settings (seed, counts, resolution, ranges, version)
    scene_00000/scene.json       waves, spectrum, camera, lighting, frame times, seed; extra:
                                 scene_index, and what the waves carry (waves_hs_m,
                                 clamped_waves: the spectrum is the requested sea, and
                                 a steep draw has its waves clamped below it)
    scene_00000/frame_00000.exr  R G B + normal.X/Y/Z, roughness, slope_variance.X/Y, mask,
                                 converged
                                 (see jaxocean.io.exr); R G B in half floats unless the
                                 frame's radiance exceeds their range (then float32);
                                 see "Storage" below
    ...
    splits.json                  {"train": [...], "val": [...], "test": [...]} scene indices
    manifest.json                every file with its size and SHA-256

* :func:`sample_scene(key, ranges, resolution, n_frames)` draws one scene from
  :class:`SceneRanges` (documented defaults below). Scene ``i`` of a dataset uses
  ``fold_in(key(seed), i)``, so scenes do not depend on the order they are made in.
* :func:`simulate(out, n_scenes, n_frames, resolution, seed, ranges)` renders every
  missing scene. A scene's ``scene.json`` is written last, atomically, after its frames: a
  scene without it is incomplete and is made again from scratch on the next run (same key,
  same files). Killing and rerunning the same command therefore finishes the dataset with
  no partial or duplicate file, byte-identical to an uninterrupted run. Rerun on a finished
  dataset, it checks each scene's files against the ``manifest.json`` it wrote (size, then
  SHA-256) and renders a scene whose files changed since again (``stats["repaired"]``), so
  the manifest it writes never vouches for a damaged file.
* :func:`check(directory)` verifies every file against ``manifest.json`` and reads every
  frame; it returns the list of problems (each naming its file).
* :class:`Dataset` loads batches by split, shuffled by key, as arrays; consecutive frame
  sequences for the temporal methods; a decoded-frame cache keeps training fed.

Splits follow the paper: 200 test scenes out of 2,000 (10% in general), the rest split 9:1
into train and validation, drawn from the seed.

Frames are rendered as :func:`jaxocean.render.render` renders them by default: plane hits
where the waves move a hit by less than half a footprint, converged ray-surface hits
otherwise (:func:`render_scene`). The image is shaded from exactly the geometry that is
stored, which is what the geometry networks and the wave fits consume.

Storage. A frame whose R G B are half floats (the default) is written with OpenEXR's PXR24
compression: lossless for the half channels, and the float32 geometry channels rounded to
24 bits (relative 2^-16 ~ 1.5e-5, far below any fit's noise floor). That halves the disk
(128^2 dataset frames: 154 KB against 244 KB with ZIP, ``experiments/bench_dataset.py``) at the
cost of bit-exactness: shading a loaded frame's geometry reproduces its half-float image to
within 1.3x the half rounding (measured on 6 default scenes at 128^2: largest relative
difference 6.2e-4 against the half rounding's 4.9e-4, on 1 pixel in 16,000). Frames
stored in float32 (``half=False``, or glitter beyond the half range) are written with ZIP
and read back bit-exact, geometry included.
"""

from __future__ import annotations

import functools
import hashlib
import json
import math
import re
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import render, shading, spectrum
from jaxocean._records import record_from_json, record_to_json
from jaxocean.errors import InvalidValueError, is_integer
from jaxocean.files import read_json, write_json
from jaxocean.io.exr import FileFormatError, IncompleteFrameWarning, read_frame, write_frame
from jaxocean.io.scene import SCENE_FILENAME, read_scene, scene_to_dict, waves_summary, write_scene
from jaxocean.io.sequence import fits_half, frame_name
from jaxocean.waves import check_phase_precision

__all__ = [
    "SceneRanges",
    "SceneSample",
    "sample_scene",
    "render_scene",
    "simulate",
    "split_scenes",
    "check",
    "Dataset",
    "Batch",
    "frame_name",
    "scene_dir",
]

DATASET_FILENAME = "dataset.json"
SPLITS_FILENAME = "splits.json"
MANIFEST_FILENAME = "manifest.json"
# what a dataset.json without splits.json or manifest.json (written last) is
_UNFINISHED = ("an unfinished dataset (its `jaxocean simulate` stopped before the end); run the same simulate "
               "command to finish it")


class SceneRanges(NamedTuple):
    """Uniform ranges (lo, hi) the scenes are drawn from (SI units, radians).

    Seas: JONSWAP with probability ``1 - pm_fraction``, otherwise Pierson-Moskowitz
    (gamma = 1); Hs, Tp, gamma, Mitsuyasu s_max and mean direction as below; ``n_waves``
    wave trains from :func:`jaxocean.spectrum.sample_waves`. Cameras: perspective, height,
    pitch below the horizon, vertical field of view, yaw 0 (the mean wave direction is
    random). Lighting: sun azimuth / elevation, and colours scaled around the defaults of
    :mod:`jaxocean.shading` by factors in ``*_scale`` (sun) or per channel (sky, sea).
    Frames: ``frame_dt`` seconds apart.
    """

    hs: tuple = (0.3, 2.5)
    tp: tuple = (3.0, 8.0)
    gamma: tuple = (1.0, 5.0)
    pm_fraction: float = 0.3
    s_max: tuple = (5.0, 25.0)
    theta_mean: tuple = (-math.pi, math.pi)
    n_waves: int = 60
    camera_height: tuple = (5.0, 30.0)
    pitch: tuple = (0.35, 1.2)
    fov: tuple = (0.6, 1.0)
    sun_azimuth: tuple = (-math.pi, math.pi)
    sun_elevation: tuple = (0.15, 1.2)
    sun_scale: tuple = (0.5, 1.5)
    sky_color: tuple = ((0.2, 0.35, 0.6), (0.5, 0.7, 1.0))
    sea_color: tuple = ((0.0, 0.02, 0.03), (0.03, 0.08, 0.1))
    frame_dt: tuple = (0.1, 0.2)

    def to_json(self) -> dict:
        return record_to_json(self)

    @classmethod
    def from_json(cls, d: dict) -> "SceneRanges":
        return record_from_json(cls, d, "scene range").validate()

    def validate(self) -> "SceneRanges":
        """``self`` if every range is a pair ``lo <= hi`` of finite numbers (per channel for
        the colours) inside its field's physical domain (:data:`RANGE_DOMAINS`); otherwise
        ``ValueError`` naming the field. A reversed pair would draw ``lo`` for every scene."""
        for name, (low, high) in RANGE_DOMAINS.items():
            value = getattr(self, name)
            if name in ("pm_fraction", "n_waves"):
                _check_in_domain(name, value, low, high, integer=name == "n_waves")
                continue
            pair = np.asarray(value, float) if _is_number_pair(value) else None
            if pair is None or pair.shape != ((2, 3) if name.endswith("_color") else (2,)):
                shape = "[lo, hi], each three numbers (RGB)" if name.endswith("_color") else "[lo, hi]"
                raise ValueError(f"scene range {name!r} must be a pair {shape}; got {value!r}")
            for v in pair.ravel():
                _check_in_domain(name, float(v), low, high)
            if np.any(pair[0] > pair[1]):
                raise ValueError(f"scene range {name!r} is reversed (lo > hi); got {value!r}")
        return self


# the physical domain of each field of SceneRanges (inclusive bounds unless marked open below)
RANGE_DOMAINS = {
    "hs": (0.0, math.inf), "tp": (0.0, math.inf), "gamma": (1.0, 20.0), "pm_fraction": (0.0, 1.0),
    "s_max": (0.0, math.inf), "theta_mean": (-4 * math.pi, 4 * math.pi), "n_waves": (1, 100_000),
    "camera_height": (0.0, math.inf), "pitch": (0.0, math.pi / 2), "fov": (0.0, math.pi),
    "sun_azimuth": (-4 * math.pi, 4 * math.pi), "sun_elevation": (0.0, math.pi / 2),
    "sun_scale": (0.0, math.inf), "sky_color": (0.0, math.inf), "sea_color": (0.0, math.inf),
    "frame_dt": (0.0, math.inf),
}
# lower bounds that are excluded: a zero height, period, field of view... is not a scene
_OPEN_BELOW = {"hs", "tp", "s_max", "camera_height", "pitch", "fov", "sun_elevation", "frame_dt"}


def _is_number_pair(value) -> bool:
    if not isinstance(value, (list, tuple)) or len(value) != 2:
        return False
    leaves = [v for item in value for v in (item if isinstance(item, (list, tuple)) else [item])]
    return all(isinstance(v, (int, float, np.integer, np.floating)) and not isinstance(v, bool) for v in leaves)


def _check_in_domain(name, value, low, high, integer=False):
    ok_type = isinstance(value, (int, np.integer) if integer else (int, float, np.integer, np.floating))
    if not ok_type or isinstance(value, bool) or not math.isfinite(value):
        kind = "an integer" if integer else "a finite number"
        raise ValueError(f"scene range {name!r} must be {kind}; got {value!r}")
    below = value <= low if name in _OPEN_BELOW else value < low
    if below or value > high:
        bound = f"{'>' if name in _OPEN_BELOW else '>='} {low:g}"
        domain = bound if math.isinf(high) else f"{bound} and <= {high:g}"
        raise ValueError(f"scene range {name!r} must be {domain}; got {value!r}")


class SceneSample(NamedTuple):
    """One scene: ``waves`` drawn from ``spectrum`` (the requested sea; None when the waves
    come from elsewhere), ``camera``, ``lighting``, frame ``times`` [s], and
    ``clamped_waves``: how many of the waves :func:`sample_scene`'s draw lowered to the
    steepness limit (None when not drawn here), so the waves carry less than ``spectrum.hs``."""

    waves: object
    spectrum: spectrum.Spectrum
    camera: cam.Camera
    lighting: shading.Lighting
    times: jnp.ndarray
    clamped_waves: int | None = None


def _uniform(key, lo_hi, shape=()):
    lo, hi = (jnp.asarray(v, jnp.float32) for v in lo_hi)
    return jax.random.uniform(key, shape or jnp.shape(lo), jnp.float32, lo, hi)


def sample_scene(key, ranges: SceneRanges = SceneRanges(), resolution=(128, 128), n_frames: int = 10) -> SceneSample:
    """Draw one scene (waves, spectrum, camera, lighting, frame times) from ``ranges``."""
    ranges.validate()
    keys = jax.random.split(key, 16)
    is_pm = jax.random.uniform(keys[0]) < ranges.pm_fraction
    spec = spectrum.Spectrum(
        hs=_uniform(keys[1], ranges.hs), tp=_uniform(keys[2], ranges.tp),
        gamma=jnp.where(is_pm, 1.0, _uniform(keys[3], ranges.gamma)).astype(jnp.float32),
        theta_mean=_uniform(keys[4], ranges.theta_mean), s_max=_uniform(keys[5], ranges.s_max))
    with warnings.catch_warnings():
        # the default ranges fold about 1 scene in 10 (docs/design.md, Waves): a training set
        # spans such seas on purpose, one warning per scene would only be noise
        warnings.simplefilter("ignore", spectrum.FoldingWarning)
        sea = spectrum.sample_waves(keys[6], spec, ranges.n_waves)  # clamps waves above the steepness limit
    camera = cam.make_camera(height=float(_uniform(keys[7], ranges.camera_height)),
                             pitch=float(_uniform(keys[8], ranges.pitch)), fov=float(_uniform(keys[9], ranges.fov)),
                             resolution=tuple(resolution))
    lighting = shading.make_lighting(
        sun_azimuth=float(_uniform(keys[10], ranges.sun_azimuth)),
        sun_elevation=float(_uniform(keys[11], ranges.sun_elevation)),
        sun_color=tuple(np.asarray(shading.DEFAULT_SUN_COLOR) * float(_uniform(keys[12], ranges.sun_scale))),
        sky_color=tuple(float(v) for v in _uniform(keys[13], ranges.sky_color)),
        sea_color=tuple(float(v) for v in _uniform(keys[14], ranges.sea_color)))
    times = jnp.arange(n_frames, dtype=jnp.float32) * _uniform(keys[15], ranges.frame_dt)
    return SceneSample(sea.waves, spec, camera, lighting, times, int(sea.n_clamped))


#: EXR compression of half-float frames (module docstring, "Storage"); float32 frames use ZIP
HALF_FRAME_COMPRESSION = "pxr24"


def render_scene(scene: SceneSample, plan="auto"):
    """Images ``(T, H, W, 3)`` and ``Geometry`` with a leading frame axis (``position`` None,
    as from ``render(..., with_geometry=True)``), one compiled call per frame.

    ``plan="auto"`` renders what :func:`jaxocean.render.render` renders by default (the rows
    path or converged hits, by :func:`jaxocean.render.needs_refinement`) with every wave
    evaluated, so a dataset compiles at most twice; ``None`` forces the rows path; or a
    :class:`jaxocean.render.RenderPlan`.
    """
    n = scene.waves.omega.shape[-1]
    # the frames are rendered under jit, where render's own check cannot see the times
    check_phase_precision(scene.waves, jnp.reshape(jnp.asarray(scene.times), (-1, 1)))
    if isinstance(plan, str):
        if plan != "auto":
            raise ValueError(f"plan must be 'auto', None or a RenderPlan; got {plan!r}")
        plan = render.full_plan(n, render.plan(scene.waves, scene.camera).refine)
    elif plan is None:
        plan = render.full_plan(n)
    return _render_frames(scene.waves, scene.camera, scene.lighting, scene.times, plan)


def _render_frames(waves, camera, lighting, times, plan):
    # frame by frame, not lax.map: the hits path's loops inside a scan ran 2.8x slower on
    # XLA:CPU (measured: 1350 ms against 487 ms for 10 frames at 128^2, same images)
    frames = [_render_frame(waves, camera, lighting, t, plan) for t in times]
    return jax.tree.map(lambda *a: jnp.stack(a), *frames)


@functools.partial(jax.jit, static_argnames=("plan",))
def _render_frame(waves, camera, lighting, t, plan):
    # render() shades the geometry it returns; it skips the positions (not stored), 10% of a
    # hits-path frame (measured 24.4 ms against 27.1 ms at 128^2, same images)
    return render.render(waves, camera, lighting, t, plan=plan, with_geometry=True)


def scene_dir(root, index: int) -> Path:
    return Path(root) / f"scene_{index:05d}"


def split_scenes(n_scenes: int, seed: int, test_scenes: int | None = None) -> dict:
    """Scene indices per split: 10% test (200 of 2,000), the rest train:val = 9:1."""
    rng = np.random.default_rng(seed)  # host-side bookkeeping, not model randomness
    order = rng.permutation(n_scenes)
    n_test = round(n_scenes * 0.1) if test_scenes is None else test_scenes
    rest = order[n_test:]
    n_val = round(len(rest) * 0.1)
    return {"train": sorted(int(i) for i in rest[n_val:]), "val": sorted(int(i) for i in rest[:n_val]),
            "test": sorted(int(i) for i in order[:n_test])}


def _sha256(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _read_settings(path: Path) -> dict:
    """``dataset.json`` with the fields every reader uses checked (scenes, frames, resolution)."""
    settings = read_json(path, "dataset settings file")
    resolution = settings.get("resolution")
    problems = [f"{key!r} must be an integer >= {low}; got {settings.get(key, 'nothing')!r}"
                for key, low in (("scenes", 1), ("frames", 1)) if not is_integer(settings.get(key), low)]
    if not (isinstance(resolution, list) and len(resolution) == 2 and all(is_integer(r, 1) for r in resolution)):
        problems.append(f"'resolution' must be [height, width] in pixels; got {resolution!r}")
    if problems:
        raise FileFormatError(path, "; ".join(problems))
    return settings


def _read_splits(path: Path, n_scenes: int) -> dict:
    """``splits.json``: each split a list of distinct scene indices in [0, n_scenes), the
    splits disjoint (a scene in two splits would score a model on what it trained on)."""
    splits = read_json(path, "dataset splits file")
    seen: dict = {}
    for name, scenes in splits.items():
        if not (isinstance(scenes, list) and all(is_integer(i, 0) and i < n_scenes for i in scenes)):
            raise FileFormatError(path, f"split {name!r} must be a list of scene indices in [0, {n_scenes}); "
                                        f"got {scenes!r:.80}")
        for i in scenes:
            if i in seen:
                raise FileFormatError(path, f"scene {i} is in split {seen[i]!r} and again in {name!r}")
            seen[i] = name
    return splits


def _read_manifest(path: Path) -> dict:
    """``manifest.json``'s ``files``: relative path -> {"bytes": int, "sha256": 64 hex digits}."""
    files = read_json(path, "dataset manifest").get("files")
    if not isinstance(files, dict):
        raise FileFormatError(path, f"'files' must map relative paths to sizes and hashes; got {files!r:.80}")
    for rel, entry in files.items():
        if Path(rel).is_absolute() or ".." in Path(rel).parts:
            raise FileFormatError(path, f"{rel!r}: manifest paths are relative to the dataset and stay inside it")
        if not (isinstance(entry, dict) and is_integer(entry.get("bytes"), 0)
                and isinstance(entry.get("sha256"), str) and re.fullmatch(r"[0-9a-f]{64}", entry["sha256"])):
            raise FileFormatError(path, f"{rel!r}: an entry must be {{\"bytes\": size, \"sha256\": 64 hex "
                                        f"digits}}; got {entry!r:.80}")
    return files


def _settings(n_scenes, n_frames, resolution, seed, ranges, half):
    import jaxocean

    settings = {"scenes": int(n_scenes), "frames": int(n_frames), "resolution": [int(r) for r in resolution],
                "seed": int(seed), "half": bool(half), "ranges": ranges.to_json(), "version": jaxocean.__version__}
    return json.loads(json.dumps(settings))  # the form it takes on disk, for comparisons


def _scene_complete(directory: Path, n_frames: int) -> bool:
    return (directory / SCENE_FILENAME).exists() and all((directory / frame_name(f)).exists()
                                                         for f in range(n_frames))


def _scene_files(out: Path, index: int, n_frames: int) -> list:
    """Scene ``index``'s files as (path relative to ``out``, path), scene.json first."""
    d = scene_dir(out, index)
    names = [SCENE_FILENAME] + [frame_name(f) for f in range(n_frames)]
    return [(str((d / name).relative_to(out)), d / name) for name in names]


def _file_entry(path: Path) -> dict:
    return {"bytes": path.stat().st_size, "sha256": _sha256(path)}


def _matches_manifest(out: Path, index: int, n_frames: int, recorded: dict, known: dict) -> bool:
    """Whether a complete scene's files are those ``recorded`` (a manifest's ``files``):
    sizes first, then hashes, which go into ``known`` for the new manifest."""
    files = _scene_files(out, index, n_frames)
    if any(rel not in recorded or path.stat().st_size != recorded[rel]["bytes"] for rel, path in files):
        return False
    entries = {rel: _file_entry(path) for rel, path in files}
    if any(entries[rel]["sha256"] != recorded[rel]["sha256"] for rel in entries):
        return False
    known.update(entries)
    return True


def simulate(out, n_scenes: int, n_frames: int = 10, resolution=(128, 128), seed: int = 0,
             ranges: SceneRanges = SceneRanges(), *, half: bool = True, progress: bool = True,
             writers: int = 2) -> dict:
    """Generate (or finish) a dataset in ``out``; returns timing statistics.

    Raises ``InvalidValueError`` if ``out`` holds a dataset made with other settings.
    """
    if n_scenes < 1 or n_frames < 1:
        raise InvalidValueError(f"need at least one scene and one frame; got scenes={n_scenes}, frames={n_frames}")
    if not (is_integer(seed, 0) and seed < 2 ** 63):  # it passes through int64 (splits, scene keys)
        raise InvalidValueError(f"seed must be an integer in [0, 2^63); got {seed!r}")
    ranges.validate()
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    settings = _settings(n_scenes, n_frames, resolution, seed, ranges, half)
    settings_path = out / DATASET_FILENAME
    if settings_path.exists():
        existing = read_json(settings_path, "dataset settings file")
        if existing != settings:
            changed = sorted(k for k in settings if existing.get(k) != settings[k])
            raise InvalidValueError(f"{settings_path}: dataset was made with other settings ({', '.join(changed)}); "
                                    "use a new --out directory or the same settings to resume")
    else:
        write_json(settings_path, settings)

    todo = [i for i in range(n_scenes) if not _scene_complete(scene_dir(out, i), n_frames)]
    # a finished run's manifest vouches for its scenes: one whose files changed since (a
    # truncated or damaged frame) is rendered again rather than written into a new manifest
    manifest_path = out / MANIFEST_FILENAME
    recorded = _read_manifest(manifest_path) if manifest_path.exists() else None
    known: dict = {}
    missing = set(todo)
    repaired = [] if recorded is None else [i for i in range(n_scenes) if i not in missing
                                            and not _matches_manifest(out, i, n_frames, recorded, known)]
    todo = sorted(todo + repaired)
    stats = dict(scenes=n_scenes, generated=len(todo), skipped=n_scenes - len(todo), repaired=repaired,
                 render_s=0.0, write_s=0.0)
    base = jax.random.key(seed)
    pool = ThreadPoolExecutor(max_workers=max(1, writers))
    pending = []
    t_start = time.perf_counter()
    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=len(todo), unit="scene", desc="simulate", smoothing=0.05)
    try:
        for i in todo:
            t0 = time.perf_counter()
            scene = sample_scene(jax.random.fold_in(base, i), ranges, resolution, n_frames)
            images, geo = jax.device_get(render_scene(scene))
            stats["render_s"] += time.perf_counter() - t0
            pending.append(pool.submit(_write_scene_files, out, i, seed, scene, images, geo, half))
            # keep at most `writers` scenes in flight: bounded memory, errors surface early
            while len(pending) > max(1, writers):
                stats["write_s"] += pending.pop(0).result()
            if bar is not None:
                bar.update(1)
        for f in pending:
            stats["write_s"] += f.result()
    finally:
        pool.shutdown(wait=True)
        if bar is not None:
            bar.close()
    stats["wall_s"] = time.perf_counter() - t_start
    write_json(out / SPLITS_FILENAME, split_scenes(n_scenes, seed))
    _write_manifest(out, n_scenes, n_frames, known)
    stats["frames_per_s"] = stats["generated"] * n_frames / max(stats["wall_s"], 1e-9)
    stats["bytes"] = sum(p.stat().st_size for p in out.rglob("*") if p.is_file())
    return stats


def _write_scene_files(out: Path, index: int, seed: int, scene: SceneSample, images, geo, half: bool) -> float:
    t0 = time.perf_counter()
    directory = scene_dir(out, index)
    (directory / SCENE_FILENAME).unlink(missing_ok=True)  # incomplete until written again, last
    for f in range(images.shape[0]):
        frame_geo = {"normal": geo.normal[f], "roughness": geo.roughness[f], "mask": geo.mask[f],
                     "slope_variance": geo.slope_variance[f], "converged": geo.converged[f]}
        # a frame whose glitter exceeds the half-float range keeps its RGB in float32
        # (exact values, same reader) rather than failing the dataset
        frame_half = half and fits_half(images[f])
        write_frame(directory / frame_name(f), images[f], frame_geo,
                    {"scene": index, "frame": f, "time": float(scene.times[f])}, half=frame_half,
                    compression=HALF_FRAME_COMPRESSION if frame_half else "zip")
    write_scene(directory, scene_to_dict(waves=scene.waves, camera=scene.camera, lighting=scene.lighting,
                                         spectrum=scene.spectrum, times=scene.times, seed=seed,
                                         extra={"scene_index": index,
                                                **waves_summary(scene.waves, scene.clamped_waves)}))
    return time.perf_counter() - t0


def _write_manifest(out: Path, n_scenes: int, n_frames: int, known: dict | None = None) -> None:
    """``manifest.json`` of every scene's files; ``known``: entries already hashed (scenes not rewritten)."""
    known = known or {}
    files = {}
    for i in range(n_scenes):
        for rel, p in _scene_files(out, i, n_frames):
            files[rel] = known[rel] if rel in known else _file_entry(p)
    write_json(out / MANIFEST_FILENAME, {"files": files})


def check(directory, *, read_frames: bool = True, progress: bool = False) -> list[str]:
    """Verify a dataset: every manifest file present with its size and hash, every frame
    readable with the resolution and channels of ``dataset.json``, every scene.json valid.

    Returns the problems found (empty when the dataset is sound), each naming its file.
    """
    directory = Path(directory)
    problems = []
    for name in (DATASET_FILENAME, MANIFEST_FILENAME, SPLITS_FILENAME):
        if not (directory / name).exists():
            # simulate writes the splits and the manifest last: without them, its run stopped early
            unfinished = name != DATASET_FILENAME and (directory / DATASET_FILENAME).exists()
            problems.append(f"{directory / name}: missing" + (f": {_UNFINISHED}" if unfinished else ""))
    if problems:
        return problems
    try:
        settings = _read_settings(directory / DATASET_FILENAME)
        files = _read_manifest(directory / MANIFEST_FILENAME)
        _read_splits(directory / SPLITS_FILENAME, settings["scenes"])
    except (FileFormatError, ValueError) as err:  # the files that say what to check for
        return [str(err)]
    resolution = tuple(settings["resolution"])
    items = sorted(files.items())
    if progress:
        from tqdm.auto import tqdm
        items = tqdm(items, unit="file", desc="check")
    for rel, entry in items:
        path = directory / rel
        if not path.is_file():  # a directory there failed the hashing with "Is a directory", as no dataset
            problems.append(f"{path}: missing" if not path.exists() else f"{path}: not a file")
            continue
        if path.stat().st_size != entry["bytes"]:
            problems.append(f"{path}: size {path.stat().st_size} differs from the manifest's {entry['bytes']}")
            continue
        if _sha256(path) != entry["sha256"]:
            problems.append(f"{path}: content differs from the manifest (SHA-256 mismatch)")
            continue
        try:
            if path.name == SCENE_FILENAME:
                read_scene(path)
            elif read_frames:
                # a dataset written before slope_variance was stored is still sound (the loader notes it)
                frame = read_frame(path, expect_resolution=resolution, warn_incomplete=False)
                if frame.normal is None:
                    problems.append(f"{path}: no geometry channels")
        except (FileFormatError, InvalidValueError, ValueError) as err:
            problems.append(str(err) if str(path) in str(err) else f"{path}: {err}")
    expected = {f"scene_{i:05d}/{n}" for i in range(settings["scenes"])
                for n in [SCENE_FILENAME] + [frame_name(f) for f in range(settings["frames"])]}
    for rel in sorted(expected - set(files)):
        problems.append(f"{directory / rel}: not in the manifest")
    for rel in sorted(set(files) - expected):
        problems.append(f"{directory / rel}: in the manifest but not one of the {settings['scenes']} scene(s) x "
                        f"{settings['frames']} frame(s) of {DATASET_FILENAME}")
    on_disk = {str(p.relative_to(directory)) for p in directory.glob("scene_*/*") if p.is_file()}
    on_disk |= {str(p.relative_to(directory)) for p in directory.glob("scene_*") if p.is_file()}
    for rel in sorted(on_disk - set(files) - expected):
        problems.append(f"{directory / rel}: not in the manifest (a file the dataset does not hold)")
    return problems


class Batch(NamedTuple):
    """A training batch: ``image (B, S, H, W, 3)``, ``normal (B, S, H, W, 3)``,
    ``roughness (B, S, H, W)``, ``mask (B, S, H, W)``, ``times (B, S)``, and the scenes'
    ``waves``, ``camera``, ``lighting`` pytrees with a leading ``B`` axis (S = sequence length);
    ``slope_variance (B, S, H, W, 2)`` the images were shaded with (pass it to
    ``render.shade``), or None when a frame of the batch lacks it (a dataset written before
    it was stored; :class:`Dataset` warns once); ``converged (B, S, H, W)`` bool, False where
    the frame's ray-surface hit is not exact (:attr:`jaxocean.render.Geometry.converged`: a
    loss should use ``mask & converged``), or None when a frame of the batch lacks it."""

    image: np.ndarray
    normal: np.ndarray
    roughness: np.ndarray
    mask: np.ndarray
    times: np.ndarray
    waves: object
    camera: object
    lighting: object
    slope_variance: np.ndarray | None = None
    converged: np.ndarray | None = None


class Dataset:
    """Reads a dataset directory for training.

    ``Dataset(root).batches(key, split="train", batch_size=8, sequence=1)`` yields
    :class:`Batch` items in a key-shuffled order of (scene, first frame) windows. Decoded
    frames are kept in an in-memory cache up to ``cache_bytes`` (default 2 GiB), so epochs
    after the first read from memory. Frames without ``slope_variance`` channels (a dataset
    written before they were stored) load with ``slope_variance`` None; the first such frame
    raises one :class:`jaxocean.io.exr.IncompleteFrameWarning` per ``Dataset``.
    """

    def __init__(self, root, cache_bytes: int = 2 << 30):
        self.root = Path(root)
        if (self.root / DATASET_FILENAME).exists() and not (self.root / SPLITS_FILENAME).exists():
            # simulate writes its splits last: an interrupted one left its settings alone
            raise FileFormatError(self.root / SPLITS_FILENAME, f"missing: {_UNFINISHED}")
        for name in (DATASET_FILENAME, SPLITS_FILENAME):
            if not (self.root / name).exists():
                raise FileFormatError(self.root / name, "missing: not a jaxocean dataset (run `jaxocean simulate`)")
        self.settings = _read_settings(self.root / DATASET_FILENAME)
        self.splits = _read_splits(self.root / SPLITS_FILENAME, self.settings["scenes"])
        self.resolution = tuple(self.settings["resolution"])
        self.n_frames = self.settings["frames"]
        self._cache: dict = {}
        self._cache_bytes = 0
        self._cache_limit = cache_bytes
        self._scenes: dict = {}
        self._warned_incomplete = False

    def scene(self, index: int):
        if index not in self._scenes:
            self._scenes[index] = read_scene(scene_dir(self.root, index))
        return self._scenes[index]

    def frame(self, scene_index: int, frame_index: int):
        key = (scene_index, frame_index)
        if key in self._cache:
            return self._cache[key]
        path = scene_dir(self.root, scene_index) / frame_name(frame_index)
        frame = read_frame(path, expect_resolution=self.resolution, warn_incomplete=False)
        if frame.normal is not None and frame.slope_variance is None and not self._warned_incomplete:
            self._warned_incomplete = True
            warnings.warn(f"{self.root}: frames without slope_variance.X/Y channels (first: {path}; written "
                          f"before they were stored): Batch.slope_variance is None, and shading their geometry "
                          f"with the isotropic roughness does not reproduce their images", IncompleteFrameWarning,
                          stacklevel=2)
        size = sum(a.nbytes for a in (frame.image, frame.normal, frame.roughness, frame.mask, frame.slope_variance,
                                      frame.converged) if a is not None)
        if self._cache_bytes + size <= self._cache_limit:
            self._cache[key] = frame
            self._cache_bytes += size
        return frame

    def scenes_of(self, split: str) -> list:
        """The scene indices of ``split``; ``ValueError`` for a split the dataset does not have."""
        if split not in self.splits:
            raise ValueError(f"unknown split {split!r}; have {sorted(self.splits)}")
        return self.splits[split]

    def windows(self, split: str, sequence: int = 1):
        scenes = self.scenes_of(split)
        if not 1 <= sequence <= self.n_frames:
            raise ValueError(f"sequence must be in [1, {self.n_frames}]; got {sequence}")
        return [(s, f) for s in scenes for f in range(self.n_frames - sequence + 1)]

    def batches(self, key, split: str = "train", batch_size: int = 8, sequence: int = 1, drop_last: bool = True):
        windows = self.windows(split, sequence)
        order = np.asarray(jax.random.permutation(key, len(windows)))
        stop = len(order) - (len(order) % batch_size if drop_last else 0)
        for start in range(0, stop, batch_size):
            chosen = [windows[i] for i in order[start:start + batch_size]]
            yield self._batch(chosen, sequence)

    def _batch(self, chosen, sequence):
        frames = [[self.frame(s, f + k) for k in range(sequence)] for s, f in chosen]
        scenes = [self.scene(s) for s, _ in chosen]

        def stack(field):
            return np.stack([np.stack([getattr(fr, field) for fr in seq]) for seq in frames])

        def stack_tree(trees):
            return jax.tree.map(lambda *leaves: np.stack([np.asarray(x) for x in leaves]), *trees)

        times = np.stack([np.asarray(sc.times)[f:f + sequence] for sc, (_, f) in zip(scenes, chosen)])
        complete = all(fr.slope_variance is not None for seq in frames for fr in seq)
        return Batch(image=stack("image"), normal=stack("normal"), roughness=stack("roughness"), mask=stack("mask"),
                     times=times, waves=stack_tree([sc.waves for sc in scenes]),
                     camera=stack_tree([sc.camera for sc in scenes]),
                     lighting=stack_tree([sc.lighting for sc in scenes]),
                     slope_variance=stack("slope_variance") if complete else None,
                     converged=stack("converged") if all(fr.converged is not None for seq in frames for fr in seq)
                     else None)
