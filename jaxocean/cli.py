"""The ``jaxocean`` command.

Subcommands (each has ``--help``):

* ``render``    one scene (options or a ``scene.json``) -> EXR + PNG frames and scene.json
* ``simulate``  a synthetic dataset (resumable; progress bar with scenes/s and ETA)
* ``check``     verify a dataset against its manifest; lists every bad file
* ``demo``      the main job: a JONSWAP scene rendered, with maps and a contact sheet

Exit codes: 0 success, 1 a check found problems, 2 bad input (the message names it),
130 interrupted. Errors print ``jaxocean: error: ...`` on stderr, not a traceback.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

__all__ = ["main", "build_parser"]

EXIT_OK, EXIT_PROBLEMS, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


def _resolution(text: str):
    try:
        parts = [int(p) for p in text.lower().replace("x", " ").split()]
    except ValueError:
        parts = []
    if len(parts) == 1:
        parts = parts * 2
    if len(parts) != 2 or min(parts) < 1:
        raise argparse.ArgumentTypeError(f"resolution must be N or HxW with positive integers; got {text!r}")
    return tuple(parts)


def _add_scene_options(p):
    g = p.add_argument_group("scene (used when no SCENE file is given)")
    g.add_argument("--hs", type=float, default=1.2, help="significant wave height [m] (default 1.2)")
    g.add_argument("--tp", type=float, default=5.5, help="peak period [s] (default 5.5)")
    g.add_argument("--gamma", type=float, default=3.3, help="JONSWAP peak enhancement; 1 = Pierson-Moskowitz")
    g.add_argument("--wave-direction", type=float, default=20.0, help="mean wave direction [deg from +x]")
    g.add_argument("--spreading", type=float, default=10.0, help="Mitsuyasu s_max (larger = narrower)")
    g.add_argument("--waves", type=int, default=60, help="number of wave trains (default 60)")
    g.add_argument("--seed", type=int, default=0, help="random seed for the wave draw")
    g.add_argument("--camera-height", type=float, default=12.0, help="camera height above the sea [m]")
    g.add_argument("--pitch", type=float, default=20.0, help="camera pitch below the horizon [deg]")
    g.add_argument("--fov", type=float, default=45.0, help="vertical field of view [deg]")
    g.add_argument("--res", type=_resolution, default=(128, 192), help="HxW pixels (default 128x192)")
    g.add_argument("--sun-azimuth", type=float, default=10.0, help="sun azimuth [deg from +x]; the camera looks along +x")
    g.add_argument("--sun-elevation", type=float, default=25.0, help="sun elevation [deg]")
    g.add_argument("--frames", type=int, default=24, help="number of frames (default 24)")
    g.add_argument("--dt", type=float, default=0.1, help="time between frames [s]")


def build_parser():
    ap = argparse.ArgumentParser(prog="jaxocean", description="Dynamic ocean inverse modeling with "
                                 "differentiable rendering, in JAX.")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("render", help="render one scene to EXR + PNG frames",
                       description="Render one scene (from options, or a scene.json / scene directory).")
    p.add_argument("scene", nargs="?", help="scene.json or a directory holding one (optional)")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--float32", action="store_true", help="write float32 EXR instead of half")
    _add_scene_options(p)

    p = sub.add_parser("simulate", help="generate a synthetic dataset (resumable)",
                       description="Generate a synthetic dataset: images, normals, roughness, waves, cameras and "
                                   "lighting (see jaxocean.io.dataset.SceneRanges for the ranges). Killing it and "
                                   "running the same command again finishes the dataset.")
    p.add_argument("--out", required=True, help="dataset directory")
    p.add_argument("--scenes", type=int, default=2000, help="number of scenes (default 2000)")
    p.add_argument("--frames", type=int, default=10, help="frames per scene (default 10)")
    p.add_argument("--res", type=_resolution, default=(128, 128), help="resolution N or HxW (default 128)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--waves", type=int, default=None, help="wave trains per scene (default 60)")
    p.add_argument("--ranges", help="JSON file overriding SceneRanges fields, e.g. {\"hs\": [0.5, 2.0]}")
    p.add_argument("--float32", action="store_true", help="float32 EXR instead of half")
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("check", help="verify a dataset against its manifest",
                       description="Verify every file of a dataset (size, SHA-256, readable, resolution, "
                                   "channels). Exit code 1 when problems are found.")
    p.add_argument("directory")
    p.add_argument("--quick", action="store_true", help="hashes and scene files only, do not decode frames")

    p = sub.add_parser("demo", help="the main job: render a default scene with maps and a contact sheet",
                       description="Render a default JONSWAP scene: an animation (EXR + PNG + GIF), normal and "
                                   "roughness maps and a contact sheet.")
    p.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    _add_scene_options(p)
    return ap


# ----------------------------------------------------------------------------- commands


def _scene_from_args(args):
    import jax

    from jaxocean import camera, shading, spectrum
    from jaxocean.io.dataset import SceneSample

    spec = spectrum.Spectrum(hs=args.hs, tp=args.tp, gamma=args.gamma, theta_mean=np.deg2rad(args.wave_direction),
                             s_max=args.spreading)
    waves = spectrum.sample_waves(jax.random.key(args.seed), spec, args.waves).waves
    cam = camera.make_camera(height=args.camera_height, pitch=np.deg2rad(args.pitch), fov=np.deg2rad(args.fov),
                             resolution=args.res)
    light = shading.make_lighting(sun_azimuth=np.deg2rad(args.sun_azimuth),
                                  sun_elevation=np.deg2rad(args.sun_elevation))
    import jax.numpy as jnp
    return SceneSample(waves, spec, cam, light, jnp.arange(args.frames, dtype=jnp.float32) * args.dt)


def _scene_from_file(path):
    from jaxocean.io.dataset import SceneSample
    from jaxocean.io.scene import read_scene

    sc = read_scene(path)
    missing = [n for n in ("waves", "camera", "lighting", "times") if getattr(sc, n) is None]
    if missing:
        raise ValueError(f"{path}: scene has no {', '.join(missing)}; render needs waves, camera, lighting and times")
    return SceneSample(sc.waves, sc.spectrum, sc.camera, sc.lighting, sc.times)


def _write_sequence(out: Path, scene, images, geo, *, half=True, seed=None, progress=True):
    """EXR + PNG per frame, normal / roughness PNGs and scene.json; returns PNG paths."""
    import imageio.v3 as iio
    from tqdm.auto import tqdm

    from jaxocean import plots
    from jaxocean.io import save_png, scene_to_dict, write_frame, write_scene
    from jaxocean.io.dataset import frame_name

    out.mkdir(parents=True, exist_ok=True)
    pngs = []
    for f in tqdm(range(images.shape[0]), desc="write", unit="frame", disable=not progress):
        g = {"normal": geo.normal[f], "roughness": geo.roughness[f], "mask": geo.mask[f]}
        write_frame(out / frame_name(f), images[f], g, {"frame": f, "time": float(scene.times[f])}, half=half)
        pngs.append(save_png(out / frame_name(f).replace(".exr", ".png"), images[f]))
    iio.imwrite(out / "normal_00000.png", plots.normal_to_rgb(geo.normal[0], geo.mask[0]))
    iio.imwrite(out / "roughness_00000.png", plots.roughness_to_rgb(geo.roughness[0], geo.mask[0]))
    write_scene(out, scene_to_dict(waves=scene.waves, camera=scene.camera, lighting=scene.lighting,
                                   spectrum=scene.spectrum, times=scene.times, seed=seed))
    return pngs


def cmd_render(args):
    import jax

    from jaxocean.io.dataset import render_scene

    scene = _scene_from_file(args.scene) if args.scene else _scene_from_args(args)
    t0 = time.perf_counter()
    images, geo = jax.device_get(render_scene(scene))
    render_s = time.perf_counter() - t0
    _write_sequence(Path(args.out), scene, images, geo, half=not args.float32,
                    seed=None if args.scene else args.seed)
    print(f"rendered {images.shape[0]} frame(s) of {images.shape[1]}x{images.shape[2]} in {render_s:.2f} s "
          f"(compile included) -> {args.out}")
    return EXIT_OK


def cmd_simulate(args):
    from jaxocean.io.dataset import SceneRanges, simulate

    ranges = SceneRanges()
    if args.ranges:
        ranges = SceneRanges.from_json({**ranges.to_json(), **json.loads(Path(args.ranges).read_text())})
    if args.waves is not None:
        ranges = ranges._replace(n_waves=args.waves)
    stats = simulate(args.out, args.scenes, args.frames, args.res, args.seed, ranges, half=not args.float32,
                     progress=not args.quiet)
    print(f"{stats['generated']} scene(s) generated, {stats['skipped']} already complete; "
          f"{stats['frames_per_s']:.1f} frames/s; {stats['bytes'] / 1e6:.1f} MB in {args.out}")
    return EXIT_OK


def cmd_check(args):
    from jaxocean.io.dataset import check

    problems = check(args.directory, read_frames=not args.quick, progress=True)
    for p in problems:
        print(p)
    if problems:
        print(f"{len(problems)} problem(s) found in {args.directory}", file=sys.stderr)
        return EXIT_PROBLEMS
    print(f"{args.directory}: OK")
    return EXIT_OK


def cmd_demo(args):
    import imageio.v3 as iio
    import jax

    from jaxocean import plots
    from jaxocean.io.dataset import render_scene

    out = Path(args.out)
    scene = _scene_from_args(args)
    print(f"demo: {args.waves} waves from JONSWAP(Hs={args.hs} m, Tp={args.tp} s, gamma={args.gamma}), "
          f"{args.frames} frames of {args.res[0]}x{args.res[1]}")
    t0 = time.perf_counter()
    images, geo = jax.device_get(render_scene(scene))
    render_s = time.perf_counter() - t0
    render_dir = out / "render"
    _write_sequence(render_dir, scene, images, geo, seed=args.seed)
    frames = [plots.display(img) for img in images]
    iio.imwrite(out / "animation.gif", np.stack(frames), duration=int(1000 * args.dt), loop=0)
    picks = sorted({0, len(frames) // 2, len(frames) - 1})
    rows = [[frames[f], plots.normal_to_rgb(geo.normal[f], geo.mask[f]),
             plots.roughness_to_rgb(geo.roughness[f], geo.mask[f])] for f in picks]
    sheet = plots.contact_sheet(out / "contact_sheet.png", rows, col_titles=["image (tone-mapped)", "normal",
                                                                             "roughness (log10 sigma^2)"],
                                row_titles=[f"t = {float(scene.times[f]):.1f} s" for f in picks],
                                title="jaxocean demo: JONSWAP sea, per-pixel hierarchical geometry")
    summary = {"frames": int(images.shape[0]), "resolution": list(args.res), "waves": args.waves,
               "render_s_with_compile": render_s, "outputs": {"frames": str(render_dir), "animation":
                                                             str(out / "animation.gif"), "contact_sheet": str(sheet)}}
    (out / "summary.json").write_text(json.dumps(summary, indent=1))
    print(f"rendered in {render_s:.2f} s (compile included)\n  frames:        {render_dir}/frame_*.exr|png\n"
          f"  animation:     {out / 'animation.gif'}\n  contact sheet: {sheet}")
    return EXIT_OK


COMMANDS = {"render": cmd_render, "simulate": cmd_simulate, "check": cmd_check, "demo": cmd_demo}


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from jaxocean.errors import InvalidValueError

    try:
        return COMMANDS[args.command](args)
    except KeyboardInterrupt:
        print("jaxocean: interrupted (completed files are kept; run the same command to resume)", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (InvalidValueError, ValueError, FileNotFoundError, json.JSONDecodeError) as err:
        print(f"jaxocean: error: {err}", file=sys.stderr)
        return EXIT_INPUT


if __name__ == "__main__":
    sys.exit(main())
