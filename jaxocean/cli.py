"""The ``jaxocean`` command.

Subcommands (each has ``--help``):

* ``render``    one scene (options or a ``scene.json``) -> EXR + PNG frames and scene.json
* ``simulate``  a synthetic dataset (resumable; progress bar with scenes/s and ETA)
* ``check``     verify a dataset against its manifest; lists every bad file
* ``demo``      the main job: a JONSWAP scene rendered, with maps and a contact sheet
* ``fit-lighting``  sun direction and sun / sky / sea colours of one EXR frame -> fit.json
* ``reedit``    re-render a scene under a new camera and / or light (a fit's, or edited)
* ``fit-waves`` the component waves behind a scene's normal / roughness frames -> waves.json
* ``forecast``  render waves (a ``waves.json`` or ``scene.json``) at future frames
* ``reconstruct`` photographs + camera file -> geometry, lighting, waves, spectrum, forecast;
  ``result.json`` and ``report.html`` (:mod:`jaxocean.reconstruct`, :mod:`jaxocean.report`)

Compiled programs are kept between runs in XLA's persistent cache (``~/.cache/jaxocean/xla``;
``JAXOCEAN_COMPILE_CACHE`` names another folder, ``0`` turns it off).

Exit codes: 0 success, 1 a check found problems or a fit did not succeed (its JSON is
still written, with ``success: false``), 2 bad input (the message names it), 130
interrupted (the message says what was kept; ``simulate``, ``train-geometry`` and
``train-waves`` resume). Errors print
``jaxocean: error: ...`` on stderr, not a traceback. Every file is written atomically
(:func:`jaxocean.files.atomic_write`).

Bad input refused before any work: a resolution and frame count whose render would not fit
in memory (estimated from ``H x W x frames``, compared with the available memory), counts
below 1, an ``--out`` directory that is an existing file, the directory of the scene that
``reedit`` or ``forecast`` reads (its frames would be replaced), a dataset directory that does
not exist, a file of another kind than the command takes (a PNG for an EXR frame, a
lighting fit for a scene: the message says which it is), the waves of a fit that reported
failure (``forecast``, unless ``--allow-failed``).

One vocabulary: every command names the camera ``--camera-height`` [m],
``--camera-pitch-deg``, ``--camera-fov-deg`` and ``--camera-yaw-deg`` [deg]; ``--res`` is
``N`` or ``HxW``. An output directory holds one scene: rendering into one that holds a
previous scene replaces that scene's files (:func:`jaxocean.io.write_sequence`).

JSON written by the fits:

* ``fit-lighting``: :func:`jaxocean.fit.fit_to_dict` (``lighting`` in radians and degrees,
  ``loss``, ``rms_residual``, ``steps``, ``success``, ``wall_time_s``) plus ``frame`` (the
  input path) and ``camera`` (``height`` [m], ``pitch`` / ``fov`` / ``yaw`` [rad] and
  ``*_deg``, ``resolution``). ``reedit --lighting`` and ``forecast --lighting`` read it.
* ``fit-waves``: a scene file (:mod:`jaxocean.io.scene` layout, readable by
  :func:`jaxocean.io.read_scene`) with the fitted ``waves``, the scene's ``camera``,
  ``lighting`` and ``times``, and ``extra.wave_fit``: ``source``, ``frames``, ``n_waves``,
  ``loss`` (the paper's loss), ``normal_error_deg``, ``roughness_error``, ``steps``,
  ``success``, ``time_s``, ``uncertainty`` (1-sigma per wave field; null where undefined)
  and, when the scene holds its true waves, ``match`` (matched / missed / spurious and the
  largest absolute errors). ``forecast`` reads it.
"""

from __future__ import annotations

import argparse
import functools
import json
import math
import sys
import time
import warnings
from pathlib import Path

import numpy as np

from jaxocean import _cli_inputs as inputs
from jaxocean import compile_cache
from jaxocean.files import json_safe, read_json, write_json

__all__ = ["main", "build_parser"]

EXIT_OK, EXIT_PROBLEMS, EXIT_INPUT, EXIT_INTERRUPTED = 0, 1, 2, 130


_FLOAT32_HELP = ("store R G B as float32 instead of half floats, every channel exact (half-float dataset "
                 "frames keep their float32 geometry to 24 bits, PXR24)")
_OUT_DIR_NOTE = ("The output directory holds one scene: rendering into a directory that holds a previous one "
                 "replaces its files (frame_*.exr / .png, normal_00000.png, roughness_00000.png, scene.json; "
                 "frames beyond the new count are removed) and leaves every other file alone.")


def _add_camera_edits(p, *, resolution: bool = True):
    g = p.add_argument_group("camera (each option replaces that field of the scene's camera)")
    g.add_argument("--camera-height", type=float, help="camera height above the sea [m]")
    g.add_argument("--camera-pitch-deg", type=inputs.pitch_degrees, help="camera pitch below the horizon [deg]")
    g.add_argument("--camera-fov-deg", type=inputs.fov_degrees, help="vertical field of view [deg]")
    g.add_argument("--camera-yaw-deg", type=float, help="viewing azimuth [deg from +x]")
    if resolution:
        g.add_argument("--res", type=inputs.resolution_arg, help="output resolution N or HxW")


def _add_lighting_edits(p):
    g = p.add_argument_group("lighting (applied on top of the scene's or --lighting's)")
    g.add_argument("--lighting", metavar="FIT_JSON",
                   help="lighting from a `jaxocean fit-lighting` JSON (or a scene.json)")
    g.add_argument("--allow-failed-lighting", action="store_true",
                   help="use the lighting of a fit-lighting result that reported failure (refused otherwise)")
    g.add_argument("--sun-azimuth", type=float, help="sun azimuth [deg from +x]")
    g.add_argument("--sun-elevation", type=inputs.sun_elevation_degrees, help="sun elevation [deg]")


_SCENE_OPTION_DEFAULTS = {
    "hs": 1.2, "tp": 5.5, "gamma": 3.3, "wave_direction": 20.0, "spreading": 10.0, "waves": 60, "seed": 0,
    "camera_height": 12.0, "camera_pitch_deg": 20.0, "camera_fov_deg": 45.0, "camera_yaw_deg": 0.0,
    "res": (128, 192), "sun_azimuth": 10.0, "sun_elevation": 25.0, "frames": 24, "dt": 0.1,
}


#: the demo's frame step [s] unless --dt is given: its 24 frames span 8 s, long enough for the
#: images' space-time evidence and the geometry's spectrum to separate waves of a 5.5 s sea
#: from a still pattern (0.1 s, the other commands' default, spans 2.4 s: too short for either)
DEMO_DT = 1 / 3


def _add_scene_options(p, **defaults):
    """The scene options of command ``p``; ``defaults`` replace :data:`_SCENE_OPTION_DEFAULTS`'
    for this command (its help says them)."""
    # defaults are filled in by _scene_option_values, so that an option given beside a SCENE
    # file (which sets every one of them) is seen and refused, not silently ignored
    defaults = {**_SCENE_OPTION_DEFAULTS, **defaults}
    p.set_defaults(scene_option_defaults=defaults)
    g = p.add_argument_group("scene (used when no SCENE file is given)")
    g.add_argument("--hs", type=float, default=None, help="significant wave height [m] (default 1.2)")
    g.add_argument("--tp", type=float, default=None, help="peak period [s] (default 5.5)")
    g.add_argument("--gamma", type=float, default=None, help="JONSWAP peak enhancement; 1 = Pierson-Moskowitz")
    g.add_argument("--wave-direction", type=float, default=None, help="mean wave direction [deg from +x]")
    g.add_argument("--spreading", type=float, default=None, help="Mitsuyasu s_max (larger = narrower)")
    g.add_argument("--waves", type=inputs.positive_int, default=None, help="number of wave trains (default 60)")
    g.add_argument("--seed", type=inputs.seed_arg, default=None, help="random seed for the wave draw")
    g.add_argument("--camera-height", type=float, default=None, help="camera height above the sea [m]")
    g.add_argument("--camera-pitch-deg", type=inputs.pitch_degrees, default=None,
                   help="camera pitch below the horizon [deg] (default 20)")
    g.add_argument("--camera-fov-deg", type=inputs.fov_degrees, default=None,
                   help="vertical field of view [deg] (default 45)")
    g.add_argument("--camera-yaw-deg", type=float, default=None, help="viewing azimuth [deg from +x] (default 0)")
    g.add_argument("--pitch", dest="camera_pitch_deg", type=inputs.pitch_degrees, action=inputs.DeprecatedAlias,
                   new="--camera-pitch-deg")
    g.add_argument("--fov", dest="camera_fov_deg", type=inputs.fov_degrees, action=inputs.DeprecatedAlias,
                   new="--camera-fov-deg")
    g.add_argument("--res", type=inputs.resolution_arg, default=None, help="HxW pixels (default 128x192)")
    g.add_argument("--sun-azimuth", type=float, default=None, help="sun azimuth [deg from +x]; the camera looks "
                   "along +x unless --camera-yaw-deg turns it")
    g.add_argument("--sun-elevation", type=inputs.sun_elevation_degrees, default=None,
                   help="sun elevation [deg]")
    g.add_argument("--frames", type=inputs.positive_int, default=None, help=f"number of frames (default {defaults['frames']})")
    g.add_argument("--dt", type=inputs.positive_float, default=None, help=f"time between frames [s] (default {defaults['dt']:.4g})")


def _scene_option_values(args, scene_file=None) -> None:
    """Fill the scene options' defaults (the command's, :func:`_add_scene_options`) into
    ``args``; with a ``scene_file``, refuse any that was given (the file sets them all)."""
    defaults = args.scene_option_defaults
    given = [name for name in defaults if getattr(args, name) is not None]
    if scene_file and given:
        options = ", ".join("--" + name.replace("_", "-") for name in given)
        raise ValueError(f"{options}: scene options apply only without a SCENE; {scene_file} sets the scene "
                         f"(edit it, or use reedit to change its camera or light)")
    for name, default in defaults.items():
        if getattr(args, name) is None:
            setattr(args, name, default)


def build_parser():
    ap = argparse.ArgumentParser(prog="jaxocean", description="Dynamic ocean inverse modeling with "
                                 "differentiable rendering, in JAX.")
    sub = ap.add_subparsers(dest="command", required=True, metavar="COMMAND")

    p = sub.add_parser("render", help="render one scene to EXR + PNG frames",
                       description="Render one scene (from options, or a scene.json / scene directory). " + _OUT_DIR_NOTE)
    p.add_argument("scene", nargs="?", help="scene.json or a directory holding one (optional)")
    p.add_argument("--out", required=True, help="output directory (one scene: a previous one there is replaced)")
    p.add_argument("--float32", action="store_true", help=_FLOAT32_HELP)
    _add_scene_options(p)

    p = sub.add_parser("simulate", help="generate a synthetic dataset (resumable)",
                       description="Generate a synthetic dataset: images, normals, roughness, waves, cameras and "
                                   "lighting (see jaxocean.io.dataset.SceneRanges for the ranges). Killing it and "
                                   "running the same command again finishes the dataset.")
    p.add_argument("--out", required=True, help="dataset directory")
    p.add_argument("--scenes", type=inputs.positive_int, default=2000, help="number of scenes (default 2000)")
    p.add_argument("--frames", type=inputs.positive_int, default=10, help="frames per scene (default 10)")
    p.add_argument("--res", type=inputs.resolution_arg, default=(128, 128), help="resolution N or HxW (default 128)")
    p.add_argument("--seed", type=inputs.seed_arg, default=0)
    p.add_argument("--waves", type=inputs.positive_int, default=None, help="wave trains per scene (default 60)")
    p.add_argument("--ranges", help="JSON file overriding SceneRanges fields, e.g. {\"hs\": [0.5, 2.0]}")
    p.add_argument("--float32", action="store_true", help=_FLOAT32_HELP)
    p.add_argument("--quiet", action="store_true", help="no progress bar")

    p = sub.add_parser("check", help="verify a dataset against its manifest",
                       description="Verify every file of a dataset (size, SHA-256, readable, resolution, "
                                   "channels). Exit code 1 when problems are found, 2 when DIRECTORY is not a "
                                   "dataset at all.")
    p.add_argument("directory", help="dataset directory (made by `jaxocean simulate`)")
    p.add_argument("--quick", action="store_true", help="hashes and scene files only, do not decode frames")

    p = sub.add_parser("demo", help="the main job: render a scene, reconstruct it from its frames, and more "
                                    "stages (--stages)",
                       description="Render a default JONSWAP scene: an animation (EXR + PNG + GIF), normal and "
                                   "roughness maps and a contact sheet; then the other --stages (by default "
                                   "reconstruct and real): reconstruct its frames from 8-bit PNG "
                                   "(reconstruct_vs_truth.png, reconstruct/), reconstruct real footage (real/, "
                                   "with --real); on request, fit the lighting of its first frame from a random "
                                   "start and re-edit it (lighting_fit.png), and fit the waves of a small swell "
                                   "from its geometry and forecast it (wave_fit.png, forecast_strip.png). Summary "
                                   "in summary.json. The demo's frames are 1/3 s apart unless --dt is given (24 "
                                   "frames: 8 s, long enough to separate the waves from a still pattern).")
    p.add_argument("--out", default="out/demo", help="output directory (default out/demo)")
    p.add_argument("--stages", default="render,reconstruct,real",
                   help="comma-separated stages: render (always), reconstruct (the rendered frames as 8-bit PNG, "
                        "everything but the frames and the camera forgotten, reconstructed, its forecast beside the "
                        "truth's in reconstruct_vs_truth.png, its re-edited views in reconstruct/report.html), "
                        "real (reconstruct on the clip of real footage given by --real), "
                        "lighting (lighting fit from the true geometry -> re-render -> error map -> re-edited "
                        "views), waves (wave fit of a small swell from its true geometry -> forecast strip); "
                        "default render,reconstruct,real")
    p.add_argument("--real", help="directory with a camera.json and its frames (real footage) for the real stage")
    _add_scene_options(p, dt=DEMO_DT)

    p = sub.add_parser("fit-lighting", help="fit sun direction and colours to one EXR frame",
                       description="Fit the sun direction and the sun, sky and sea colours to one EXR frame with "
                                   "geometry channels (normal, roughness, mask), given the camera that saw it: "
                                   "from --scene, or from the --camera-* options (height and pitch needed, field "
                                   "of view 45 deg and yaw 0 by default). Writes jaxocean.fit.fit_to_dict JSON; "
                                   "exit code 1 when the fit does not succeed (its JSON's success: converging is not "
                                   "enough; the JSON is written anyway).")
    p.add_argument("frame", help="EXR frame with normal.X/Y/Z, roughness and mask channels")
    p.add_argument("--scene", help="scene directory or scene.json holding the frame's camera")
    p.add_argument("--out", required=True, help="output JSON file")
    _add_camera_edits(p, resolution=False)

    p = sub.add_parser("reedit", help="re-render a scene under a new camera or light",
                       description="Re-render a scene directory (scene.json with waves, camera, lighting, times) "
                                   "with a new camera and/or light: EXR + PNG frames and the edited scene.json. "
                                   "Angles in degrees. " + _OUT_DIR_NOTE)
    p.add_argument("scene", help="scene directory or scene.json")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--frames", type=inputs.index_list, help="indices of the scene's frames, e.g. 0,1 (default all)")
    p.add_argument("--float32", action="store_true", help=_FLOAT32_HELP)
    _add_camera_edits(p)
    _add_lighting_edits(p)

    p = sub.add_parser("fit-waves", help="fit the component waves behind a scene's geometry frames",
                       description="Fit the wave trains {h, omega, theta, phi} to the normal and roughness "
                                   "channels of a scene's EXR frames (jaxocean.fit.waves; at least two frames). "
                                   "Writes a scene-format JSON with the fitted waves, the scene's camera, lighting "
                                   "and times, and the fit's report under extra.wave_fit; compares with the "
                                   "scene's own waves when it has them. Exit code 1 when the fit does not "
                                   "succeed (extra.wave_fit.success: converging is not enough; the JSON is written "
                                   "anyway). Compilation takes a minute on a CPU.")
    p.add_argument("scene", help="scene directory (scene.json + frame_XXXXX.exr)")
    p.add_argument("--out", required=True, help="output JSON file (e.g. waves.json)")
    p.add_argument("--frames", type=inputs.index_list, help="frame indices to fit, e.g. 0,1,2 (default all)")
    p.add_argument("--n-waves", type=int, help="fit exactly this many waves (default: chosen by BIC)")
    p.add_argument("--max-waves", type=int, default=96, help="most waves the order selection tries (default 96)")
    p.add_argument("--noise", type=float, help="noise sigma of the normals' x/y components when known (order "
                   "selection and the success test use it; default: noise-free up to storage precision, so a fit "
                   "leaving more than 1 mrad mean normal error is reported failed)")
    p.add_argument("--noise-correlation", type=float, default=0.0, metavar="PX",
                   help="correlation length [px] of the --noise across the image (errors correlated as "
                        "exp(-d/PX), e.g. a network's smooth normal errors): each wave then pays the order "
                        "selection's penalty at the noise in its own band of the spectrum (default 0: independent "
                        "pixels)")
    p.add_argument("--verbose", action="store_true", help="print the fit's order-selection steps")
    p.add_argument("--init", choices=("spectral", "net"), default="spectral",
                   help="start: spectral (default: greedy detection from the space-time spectrum) or net (the "
                        "wave network's waves from the first frames as the first trial model, admitted and tested "
                        "as the selection's first batch; then the same selection and refinement)")
    p.add_argument("--net-model", help="wave network file for --init net (default: the shipped model)")
    p.add_argument("--no-heights", dest="heights", action="store_false",
                   help="fit the slopes alone, without the normals' integrated heights (fit.heights), which by "
                        "default pin the heights of the long waves that move the pixels' hits on rough seas")
    p.add_argument("--height-trend", default="level", choices=("level", "plane", "quadratic"),
                   help="what of each frame's integrated heights is left free: the level (default), or also a "
                        "plane or a quadratic over the sea plane (steep seas seen at a low angle bias the "
                        "integration by such a trend)")

    p = sub.add_parser("forecast", help="render waves at future frames",
                       description="Evolve waves (a fit-waves JSON or any scene.json) to the given frames or "
                                   "times and render them as render draws them (the converged hits where the "
                                   "waves move them). A fit-waves result is forecast by the least-squares "
                                   "forecast (see --undamped): EXR + PNG per frame (numbered in output order; each "
                                   "file's metadata and scene.json's extra.forecast_frames give the requested "
                                   "frame index) and scene.json (of a least-squares forecast it holds the fitted "
                                   "waves without the long-wave stand-ins and the damping, which its frames "
                                   "include: extra.forecast_damped marks it, and render, reedit and forecast "
                                   "refuse it). Camera and lighting come from the JSON unless "
                                   "replaced by the options; the default lighting is jaxocean.shading's. "
                                   + _OUT_DIR_NOTE)
    p.add_argument("waves", help="JSON with waves (fit-waves output or scene.json)")
    p.add_argument("--out", required=True, help="output directory (one scene: a previous one there is replaced)")
    p.add_argument("--allow-failed", action="store_true", help="forecast the waves of a fit-waves result that "
                   "reported failure (refused otherwise: its waves need not explain the frames)")
    when = p.add_mutually_exclusive_group(required=True)
    when.add_argument("--frames", type=inputs.index_list, help="frame indices, increasing, e.g. 0,100,500")
    when.add_argument("--times", type=inputs.number_list,
                      help="times [s], increasing, e.g. 0,10,50 (a list that starts negative takes =: --times=-5,10)")
    p.add_argument("--fps", type=inputs.positive_float,
                   help="frames per second for --frames (default: the JSON's frame "
                        "interval; frame 0 is its first time)")
    p.add_argument("--undamped", action="store_true",
                   help="with a fit-waves result: extrapolate every fitted wave's phase as fitted, without the "
                        "long-wave band. Default: the least-squares forecast (jaxocean.forecast), the fit's waves "
                        "and band with each one damped outside the fitted window by its frequency uncertainty, so "
                        "that what the window did not measure fades instead of being extrapolated")
    p.add_argument("--float32", action="store_true", help=_FLOAT32_HELP)
    _add_camera_edits(p)
    _add_lighting_edits(p)

    p = sub.add_parser("reconstruct", help="photographs to waves: geometry, lighting, waves, spectrum, forecast",
                       description="Reconstruct the sea behind a sequence of photographs (jaxocean.reconstruct): "
                                   "radiometry and rectification into one ideal camera, geometry from the shipped "
                                   "network, lighting, waves, photometric refinement against the images, spectrum, "
                                   "forecast and re-edited views. Writes result.json, report.html and its figures "
                                   "into --out; prints every stage's flag and time. Exit code 1 when a stage "
                                   "failed (everything is written anyway; the report says which).")
    p.add_argument("frames", nargs="*", help="frame files (PNG / JPEG / 16-bit gray PNG / EXR) or one video; default: "
                                             "every frame the camera file lists")
    p.add_argument("--camera", required=True, help="camera file (intrinsics, distortion, a pose per frame) or a "
                                                   "synthetic scene.json, or a directory holding one")
    p.add_argument("--out", required=True, help="output directory")
    p.add_argument("--width", type=int, default=128, help="width [px] of the rectified working view (default 128)")
    p.add_argument("--response", default="srgb", choices=("srgb", "gamma", "linear", "bruneton"),
                   help="display response of 8/16-bit frames (default srgb)")
    p.add_argument("--gamma", type=inputs.positive_float,
                   help="exponent for --response gamma (default 2.2)")
    p.add_argument("--step", type=int, default=1, help="use every STEP-th frame (default 1)")
    p.add_argument("--max-frames", type=int, help="use at most this many frames")
    p.add_argument("--wave-frames", type=int, default=16, help="frames the wave fits use, spread evenly (default 16)")
    p.add_argument("--max-waves", type=int, default=24, help="most waves the wave fit tries (default 24)")
    p.add_argument("--camera-height", type=inputs.positive_float,
                   help="camera height [m] when the camera file gives no pose "
                        "(pitch and roll then come from the horizon)")
    sky = p.add_mutually_exclusive_group()
    sky.add_argument("--overcast", dest="overcast", action="store_true", default=None,
                     help="no sun term (default: decided from the footage)")
    sky.add_argument("--sunny", dest="overcast", action="store_false", help="fit a sun term")
    p.add_argument("--no-refine", action="store_true", help="skip the photometric refinement (stage 5)")
    p.add_argument("--per-frame-exposure", action="store_true",
                   help="stage 5 fits one exposure per frame (a camera on automatic exposure)")
    p.add_argument("--geometry-model", default=None, help="stage 2's network: a model file, or a shipped model: cpu "
                   "(the default) or gpu (larger, more accurate, ~2.5x the time per frame)")
    from jaxocean.nn import cli as nn_cli

    COMMANDS.update(nn_cli.register(sub, add_camera_options=_add_camera_edits,
                                    camera_from_args=inputs.camera_from_args))
    return ap


# ----------------------------------------------------------------------------- commands


def _rgb(values) -> str:
    return "(" + ", ".join(f"{float(v):.4g}" for v in np.asarray(values)) + ")"


def cmd_render(args):
    import jax

    from jaxocean.io.dataset import render_scene

    _scene_option_values(args, args.scene)
    out = inputs.check_out_dir(args.out)
    if not args.scene:
        inputs.check_memory(args.res, args.frames, "render")
    # a scene file keeps its own draw's seed, as reedit keeps it
    scene, seed = inputs.scene_from_file(args.scene) if args.scene else (inputs.scene_from_args(args), args.seed)
    if args.scene:
        inputs.check_memory(scene.camera.resolution, int(np.size(scene.times)), f"render {args.scene}")
    t0 = time.perf_counter()
    images, geo = jax.device_get(render_scene(scene))
    render_s = time.perf_counter() - t0
    from jaxocean.io import write_sequence
    write_sequence(out, scene, images, geo, half=not args.float32, seed=seed)
    print(f"rendered {images.shape[0]} frame(s) of {images.shape[1]}x{images.shape[2]} in {render_s:.2f} s "
          f"(compile included) -> {args.out}")
    _warn_if_sky_only(geo.mask)
    return EXIT_OK


def _warn_if_sky_only(mask) -> None:
    """The warning of a render whose frames' sea ``mask`` holds no sea pixel."""
    from jaxocean.camera import DEFAULT_MAX_DISTANCE

    if not np.any(mask):
        print(f"jaxocean: warning: no pixel sees the sea (the view is above the horizon, or the sea lies more than "
              f"{DEFAULT_MAX_DISTANCE / 1e3:g} km away): the frames show sky only, and nothing can be fitted from "
              f"them", file=sys.stderr)


def cmd_simulate(args):
    from jaxocean.io.dataset import SceneRanges, simulate

    inputs.check_out_dir(args.out)
    inputs.check_memory(args.res, args.frames, "simulate")
    per_pixel = inputs.DATASET_MIN_BYTES_PER_PIXEL[not args.float32]
    inputs.check_disk(args.out, per_pixel * args.scenes * args.frames * args.res[0] * args.res[1], "simulate")
    ranges = SceneRanges()
    if args.ranges:
        overrides = read_json(args.ranges, "ranges file")
        try:
            ranges = SceneRanges.from_json({**ranges.to_json(), **overrides})
        except ValueError as error:
            raise ValueError(f"--ranges {args.ranges}: {error}") from None
    if args.waves is not None:
        ranges = ranges._replace(n_waves=args.waves)
    stats = simulate(args.out, args.scenes, args.frames, args.res, args.seed, ranges, half=not args.float32,
                     progress=not args.quiet)
    if stats["repaired"]:
        print(f"jaxocean: note: scene(s) {', '.join(map(str, stats['repaired']))} differed from the dataset's "
              f"manifest.json (a file changed or damaged since it was written): rendered again", file=sys.stderr)
    print(f"{stats['generated']} scene(s) generated, {stats['skipped']} already complete; "
          f"{stats['frames_per_s']:.1f} frames/s; {stats['bytes'] / 1e6:.1f} MB in {args.out}")
    if args.scenes < 7:  # the splits keep a tenth for test and a tenth of the rest for validation
        print(f"jaxocean: note: {args.scenes} scene(s) leave the validation split empty: train-geometry and "
              f"train-waves need at least 7", file=sys.stderr)
    elif args.scenes < 10:
        print(f"jaxocean: note: {args.scenes} scenes leave fewer than 8 in the train split: train-waves (its "
              f"configs' batches hold 8 or more scenes) needs at least 10", file=sys.stderr)
    return EXIT_OK


def cmd_check(args):
    from jaxocean.io.dataset import DATASET_FILENAME, MANIFEST_FILENAME, SPLITS_FILENAME, check

    directory = Path(args.directory)
    if not directory.is_dir():
        raise FileNotFoundError(f"{directory}: no such directory" if not directory.exists() else
                                f"{directory}: not a directory; check takes a dataset directory (jaxocean simulate)")
    names = (DATASET_FILENAME, MANIFEST_FILENAME, SPLITS_FILENAME)
    if not any((directory / name).exists() for name in names):
        raise ValueError(f"{directory}: not a jaxocean dataset (none of {', '.join(names)}); check takes a "
                         f"directory made by `jaxocean simulate`")
    problems = check(directory, read_frames=not args.quick, progress=True)
    for p in problems:
        print(p)
    if problems:
        print(f"{len(problems)} problem(s) found in {args.directory}", file=sys.stderr)
        return EXIT_PROBLEMS
    print(f"{args.directory}: OK")
    return EXIT_OK


#: the figures each demo stage writes into --out (besides its directories)
_DEMO_FIGURES = {"lighting": ("lighting_fit.png",), "waves": ("wave_fit.png", "forecast_strip.png"),
                 "reconstruct": ("reconstruct_vs_truth.png",)}


def cmd_demo(args):
    import imageio.v3 as iio
    import jax

    from jaxocean import plots
    from jaxocean.io.dataset import render_scene

    _scene_option_values(args)
    stages = {s.strip() for s in args.stages.split(",") if s.strip()}
    unknown = stages - {"render", "lighting", "waves", "reconstruct", "real"}
    if unknown:
        raise ValueError(f"unknown demo stages {sorted(unknown)}; choose from render, reconstruct, real, lighting, "
                         f"waves")
    if args.real is not None and "real" not in stages:
        raise ValueError(f"--real {args.real}: the real stage is not among --stages {args.stages}; add real to "
                         f"--stages to reconstruct the clip, or leave --real out")
    if "real" in stages and args.real is not None and not (Path(args.real) / "camera.json").is_file():
        raise ValueError(f"--real {args.real}: no camera.json there")
    out = inputs.check_out_dir(args.out)
    inputs.check_memory(args.res, args.frames, "demo")
    scene = inputs.scene_from_args(args)
    # a previous demo's figures are not this run's: removed, so that a stage not run now (or one
    # that stops before its figure) leaves none beside a summary.json that does not list it
    stale = []
    for stage, names in _DEMO_FIGURES.items():
        for path in (out / name for name in names):
            if path.is_file():
                path.unlink()
                if stage not in stages:
                    stale.append(path)
    if stale:
        print(f"note: removed {len(stale)} figure(s) of a previous demo in {out} from stages not run now: "
              f"{', '.join(p.name for p in stale)}", file=sys.stderr)
    print(f"demo: {args.waves} waves from JONSWAP(Hs={args.hs} m, Tp={args.tp} s, gamma={args.gamma}), "
          f"{args.frames} frames of {args.res[0]}x{args.res[1]}")
    t0 = time.perf_counter()
    images, geo = jax.device_get(render_scene(scene))
    render_s = time.perf_counter() - t0
    render_dir = out / "render"
    from jaxocean.io import write_sequence
    write_sequence(render_dir, scene, images, geo, seed=args.seed)
    frames = [plots.display(img) for img in images]
    iio.imwrite(out / "animation.gif", np.stack(frames), duration=int(1000 * args.dt), loop=0)
    picks = sorted({0, len(frames) // 2, len(frames) - 1})
    rows = [[frames[f], plots.normal_to_rgb(geo.normal[f], geo.mask[f]),
             plots.roughness_to_rgb(geo.roughness[f], geo.mask[f])] for f in picks]
    sheet = plots.contact_sheet(out / "contact_sheet.png", rows, col_titles=["image (tone-mapped)", "normal",
                                                                             "roughness (log10 sigma^2)"],
                                row_titles=[f"t = {float(scene.times[f]):.3g} s" for f in picks],
                                title="jaxocean demo: JONSWAP sea, per-pixel hierarchical geometry")
    summary = {"frames": int(images.shape[0]), "resolution": list(args.res), "waves": args.waves,
               "render_s_with_compile": render_s, "outputs": {"frames": str(render_dir), "animation":
                                                             str(out / "animation.gif"), "contact_sheet": str(sheet)}}
    print(f"rendered in {render_s:.2f} s (compile included)\n  frames:        {render_dir}/frame_*.exr|png\n"
          f"  animation:     {out / 'animation.gif'}\n  contact sheet: {sheet}")
    write_json(out / "summary.json", summary)  # what is done is kept if a later stage fails
    from jaxocean import demo

    if "lighting" in stages:
        print("lighting: fit sun and colours to frame 0 from a random start, re-render, re-edit ...", flush=True)
        frame0 = jax.tree.map(lambda x: x[0], geo)
        summary["lighting_fit"] = r = demo.lighting_stage(out, scene, images[0], frame0)
        print(f"  {'succeeded' if r['success'] else 'FAILED'} in {r['steps']} steps "
              f"({r['wall_s_with_compile']:.1f} s with compile): sun {r['sun_error_deg']:.2e} deg off, "
              f"max display error {r['max_display_error']:.1e}\n  figure:        {r['figure']}")
        write_json(out / "summary.json", summary)
    if "waves" in stages:
        print("waves: fit a 4-wave swell from 8 frames of its geometry, then forecast frames 0, 100, 500 ...",
              flush=True)
        summary["wave_fit"] = r = demo.waves_stage(out)
        err = r["max_abs_error"]
        print(f"  {r['n_fitted']} waves fitted for {r['n_true']} true ({r['matched']} matched; "
              f"{r['wall_s_with_compile']:.1f} s with compile); max |error| h {err['amplitude']:.1e} m, "
              f"omega {err['omega']:.1e} rad/s, theta {err['theta']:.1e} rad\n  forecast normal error "
              + ", ".join(f"frame {f}: {e:.3f} deg" for f, e in zip(r["forecast_frames"],
                                                                      r["forecast_normal_error_deg"]))
              + "\n  figures:       " + ", ".join(r["figures"]))
        write_json(out / "summary.json", summary)
    if "reconstruct" in stages:
        print("reconstruct: the frames as 8-bit PNG, only the frames and the camera kept, reconstructed ...",
              flush=True)
        summary["reconstruct"] = r = demo.reconstruct_stage(out, scene, images)
        print(f"  Hs {_value(r['hs_m'], '.2f', ' m')} (true {r['truth']['hs']:.2f} m), "
              f"Tp {_value(r['tp_s'], '.1f', ' s')} (true {r['truth']['tp']:.1f} s)" + _sea_caveat(r)
              + f"\n  report:        {r['report']}\n  figure:        {r['figure']}")
        write_json(out / "summary.json", summary)
    if "real" in stages:
        if args.real is None:
            print("real: skipped (no --real clip given)")
        else:
            print(f"real: reconstruct on the real footage in {args.real} ...", flush=True)
            summary["real"] = r = demo.real_stage(out, Path(args.real))
            print(f"  Hs {_value(r['hs_m'], '.2f', ' m')}, Tp {_value(r['tp_s'], '.1f', ' s')}, toward "
                  f"{_value(r['direction_deg'], '.0f', ' deg')}"
                  + _sea_caveat(r) + f"\n  report:        {r['report']}")
            write_json(out / "summary.json", summary)
    return EXIT_OK


def _value(x, spec: str, unit: str = "") -> str:
    """``x`` formatted by ``spec`` followed by ``unit``, or ``n/a`` where there is no number
    (None or NaN)."""
    return "n/a" if x is None or not math.isfinite(x) else format(x, spec) + unit


def _sea_caveat(r) -> str:
    """What a demo's sea-state line must say beside its numbers: a failed spectrum stage,
    and the bound."""
    failed = "" if r["stages"]["spectrum"]["success"] else " (the spectrum stage failed: not a measurement)"
    return failed + (f"; {r['bound']}" if r["bound"] else "")


def cmd_fit_lighting(args):
    from jaxocean import fit
    from jaxocean.camera import camera_to_dict
    from jaxocean.io import read_frame, read_scene

    inputs.check_out_file(args.out, "fit.json")
    frame = read_frame(args.frame, warn_incomplete=False)
    if frame.normal is None:
        raise ValueError(f"{args.frame}: the frame has no normal channels (normal.X/Y/Z, roughness, mask); "
                         f"fit-lighting needs the geometry it was rendered with")
    if frame.slope_variance is None:
        print(f"jaxocean: note: {args.frame} has no slope_variance.X/Y channels (an older or foreign file): the fit "
              f"shades its geometry with the isotropic roughness, which does not reproduce an image rendered with "
              f"anisotropic slope variance; the fitted lighting (colours above all) can be off. Re-render the frame "
              f"to fit it exactly", file=sys.stderr)
    if args.scene:
        inputs.refuse_other_json(args.scene, "--scene takes the frame's scene directory or scene.json (its camera)")
    scene = read_scene(args.scene) if args.scene else None
    # a scene without a camera takes it from the options, as a frame without a scene does
    camera = inputs.camera_from_args(args, None if scene is None else scene.camera, tuple(frame.image.shape[:2]),
                                     where=f"frame {args.frame}" if scene is None else f"the scene {args.scene}")
    print(f"fitting the lighting of {args.frame} ({frame.image.shape[0]}x{frame.image.shape[1]}; "
          f"compilation included)")
    result = fit.lighting(frame.image, frame, camera, throw=False)
    report = {**fit.fit_to_dict(result), "frame": str(args.frame), "camera": camera_to_dict(camera, degrees=True)}
    light = report["lighting"]
    print(f"  sun azimuth   {light['sun_azimuth_deg']:8.3f} deg\n"
          f"  sun elevation {light['sun_elevation_deg']:8.3f} deg\n"
          f"  sun colour {_rgb(light['sun_color'])}  sky colour {_rgb(light['sky_color'])}  "
          f"sea colour {_rgb(light['sea_color'])}\n"
          f"  rms residual {report['rms_residual']:.3e} after {report['steps']} step(s), "
          f"{report['wall_time_s']:.2f} s; success: {report['success']}")
    if scene is not None and scene.lighting is not None:
        err = fit.lighting_error(result.lighting, scene.lighting)
        print(f"  vs the scene's lighting: sun direction off by {float(err['sun_angle_deg']):.3g} deg; largest "
              f"relative colour errors sun {float(err['sun_color']):.2g}, sky {float(err['sky_color']):.2g}, "
              f"sea {float(err['sea_color']):.2g}")
    write_json(args.out, report)
    print(f"-> {args.out}")
    if not report["success"]:
        print(f"jaxocean: the lighting fit failed: {fit.lighting_fit.failure_message(result)} "
              f"(the JSON has the fitted values and which parameters the image determines)", file=sys.stderr)
        return EXIT_PROBLEMS
    return EXIT_OK


def cmd_reedit(args):
    from jaxocean.fit import reedit_scene
    from jaxocean.io import read_scene

    inputs.check_out_dir(args.out)
    inputs.refuse_out_over_source(args.out, args.scene, "reedit")
    inputs.refuse_other_json(args.scene, "reedit needs a scene: a scene directory or scene.json with waves, camera, "
                                   "lighting and times")
    scene = read_scene(args.scene)
    inputs.refuse_damped_forecast(scene, args.scene, "reedit")
    n = 1 if scene.times is None else int(np.size(scene.times))
    frames = inputs.check_frames(args.frames, n, f"scene {args.scene}")
    if scene.camera is not None:
        inputs.check_memory(args.res or scene.camera.resolution, len(frames), "reedit")
    lighting = inputs.lighting_from_file(args.lighting, args.allow_failed_lighting) if args.lighting else None
    t0 = time.perf_counter()
    out = reedit_scene(args.scene, args.out, camera_height=args.camera_height, camera_pitch_deg=args.camera_pitch_deg,
                       camera_fov_deg=args.camera_fov_deg, camera_yaw_deg=args.camera_yaw_deg, resolution=args.res,
                       sun_azimuth_deg=args.sun_azimuth, sun_elevation_deg=args.sun_elevation, lighting=lighting,
                       frames=frames, half=not args.float32)
    edited = read_scene(out)
    print(f"re-rendered {len(frames)} frame(s) of {args.scene} in {time.perf_counter() - t0:.2f} s (compile "
          f"included): camera height {float(edited.camera.height):.3g} m, pitch "
          f"{math.degrees(float(edited.camera.pitch)):.3g} deg, {edited.camera.resolution[0]}x"
          f"{edited.camera.resolution[1]}; sun azimuth {math.degrees(float(edited.lighting.sun_azimuth)):.3g} deg, "
          f"elevation {math.degrees(float(edited.lighting.sun_elevation)):.3g} deg -> {out}")
    from jaxocean.camera import intersect_sea

    _warn_if_sky_only(intersect_sea(edited.camera).mask)  # the renderer's sea pixels
    return EXIT_OK


def _read_geometry_frames(scene_dir: Path, frames, resolution):
    """``(normals (T, H, W, 3), roughness (T, H, W))`` of the scene's frames, with a progress bar.

    fit.waves models the scalar roughness (its sub-pixel term), which every frame stores
    exactly; the anisotropic slope variance, when a frame has it, is not part of that model.
    Pixels whose stored ``converged`` flag is 0 (no exact ray-surface hit) are set to NaN:
    the fit leaves them out.
    """
    from tqdm.auto import tqdm

    from jaxocean.io import read_frame
    from jaxocean.io.dataset import frame_name

    normals, roughness = [], []
    for f in tqdm(frames, desc="read", unit="frame"):
        frame = read_frame(scene_dir / frame_name(f), expect_resolution=resolution, warn_incomplete=False)
        if frame.normal is None:
            raise ValueError(f"{scene_dir / frame_name(f)}: the frame has no normal / roughness channels; "
                             f"fit-waves needs the geometry frames")
        normal = np.asarray(frame.normal, np.float32)
        if getattr(frame, "converged", None) is not None:
            normal = np.where(np.asarray(frame.converged, bool)[..., None], normal, np.nan)
        normals.append(normal)
        roughness.append(frame.roughness)
    return np.stack(normals), np.stack(roughness)


def _match_report(fitted, truth) -> dict:
    from jaxocean.fit.waves import match

    m = match(fitted, truth)
    err = m.abs_error
    worst = {} if m.true_index.size == 0 else {
        "amplitude": float(np.max(err.amplitude)), "omega": float(np.max(err.omega)),
        "theta_deg": math.degrees(float(np.max(err.theta))), "phase_deg": math.degrees(float(np.max(err.phase)))}
    return {"true_waves": int(np.size(truth.omega)), "matched": int(m.true_index.size),
            "missed": m.missed.tolist(), "spurious": m.spurious.tolist(), "max_abs_error": worst}


def cmd_fit_waves(args):
    from jaxocean.fit.waves import NoWaveFound
    from jaxocean.fit.waves import waves as fit_waves
    from jaxocean.io import read_scene, scene_to_dict

    if args.n_waves is not None and args.n_waves < 1:
        raise ValueError(f"--n-waves must be >= 1; got {args.n_waves}")
    if args.net_model and args.init != "net":
        raise ValueError("--net-model is used with --init net only")
    if args.max_waves < 1:
        raise ValueError(f"--max-waves must be >= 1; got {args.max_waves}")
    if args.noise is not None and not (np.isfinite(args.noise) and args.noise > 0):
        raise ValueError(f"--noise must be a finite sigma > 0 (fit.waves' own bound); got {args.noise}")
    if not (np.isfinite(args.noise_correlation) and args.noise_correlation >= 0):
        raise ValueError(f"--noise-correlation must be a finite number of pixels >= 0; got {args.noise_correlation}")
    if args.noise_correlation > 0 and args.noise is None:
        raise ValueError("--noise-correlation is the correlation of --noise: give --noise too")
    inputs.check_out_file(args.out, "waves.json")
    inputs.refuse_other_json(args.scene, "fit-waves needs a scene directory (scene.json and its frame_XXXXX.exr files)")
    scene_dir = Path(args.scene)
    scene_dir = scene_dir.parent if scene_dir.suffix.lower() == ".json" else scene_dir
    scene = read_scene(scene_dir)
    missing = [name for name in ("camera", "times") if getattr(scene, name) is None]
    if missing:
        raise ValueError(f"{scene_dir}: the scene has no {' and '.join(missing)}; fit-waves needs both")
    all_times = np.asarray(scene.times, np.float64)
    frames = inputs.check_frames(args.frames, all_times.size, f"scene {scene_dir}")
    if len(frames) < 2:
        raise ValueError(f"fit-waves needs at least two frames (the waves' frequencies come from their motion); "
                         f"got {len(frames)}")
    times = all_times[frames]
    if not np.all(np.diff(times) > 0):
        raise ValueError(f"the selected frames' times must increase; got {times.tolist()}")
    normals, roughness = _read_geometry_frames(scene_dir, frames, scene.camera.resolution)
    print(f"fitting waves to {len(frames)} frame(s) of {normals.shape[1]}x{normals.shape[2]} "
          f"({'n = ' + str(args.n_waves) if args.n_waves else 'count chosen by BIC'}; compilation included)")
    inputs_report = {"source": str(scene_dir), "frames": frames, "noise": args.noise,
                     "noise_correlation_px": float(args.noise_correlation)}

    def write_result(waves, report):
        write_json(args.out, scene_to_dict(waves=waves, camera=scene.camera, lighting=scene.lighting,
                                            times=all_times, extra={"wave_fit": report}))
        print(f"-> {args.out}")

    try:
        result = fit_waves(normals, roughness, scene.camera, times, n_waves=args.n_waves, max_waves=args.max_waves,
                           noise=args.noise, noise_correlation=args.noise_correlation, throw=False,
                           verbose=args.verbose,
                           init="net" if args.init == "net" else None, net=args.net_model, heights=args.heights,
                           height_trend=args.height_trend)
    except NoWaveFound as error:  # a fit that found nothing, not bad input: exit 1 with its JSON
        write_result(None, {**inputs_report, "n_waves": 0, "success": False, "message": str(error)})
        print(f"jaxocean: the wave fit failed: {error}; see extra.wave_fit in the JSON", file=sys.stderr)
        return EXIT_PROBLEMS
    w = result.waves
    finite = all(bool(np.all(np.isfinite(np.asarray(leaf)))) for leaf in w)
    success = bool(result.success) and finite
    report = {**inputs_report, "n_waves": int(result.n_waves),
              "loss": json_safe(float(result.loss)),
              "normal_error_deg": json_safe(math.degrees(float(result.normal_error))),
              "roughness_error": json_safe(float(result.roughness_error)), "steps": int(result.steps),
              "success": success, "converged": bool(result.converged), "time_s": json_safe(float(result.time_s)),
              "uncertainty": {name: json_safe(np.ravel(leaf)) for name, leaf in zip(w._fields, result.uncertainty)}}
    if finite and result.determined is not None:
        from jaxocean.fit.waves import forecast_model

        # what `forecast` needs for the least-squares forecast: the band's stand-ins and the
        # frequency uncertainty of every component (waves, then band)
        model, sigma, window = forecast_model(result, scene.camera, times)
        n = int(result.n_waves)
        report["determined"] = [bool(d) for d in np.asarray(result.determined)]
        report["forecast"] = {"window_s": list(window), "frequency_sigma": json_safe(np.asarray(sigma, np.float64)),
                              "band": {name: json_safe(np.asarray(leaf[n:], np.float64))
                                       for name, leaf in zip(model._fields, model)}}
    print(f"  {report['n_waves']} wave(s); loss {float(result.loss):.3e}, mean normal error "
          f"{float(np.degrees(result.normal_error)):.3g} deg, roughness error {float(result.roughness_error):.3g}; "
          f"{report['steps']} step(s), {float(result.time_s):.1f} s; success: {success}")
    if finite:
        for h, om, th, ph in zip(*(np.asarray(leaf, np.float64) for leaf in w)):
            print(f"    h {h:8.4f} m  omega {om:7.4f} rad/s  theta {math.degrees(th):8.2f} deg  "
                  f"phi {math.degrees(ph):8.2f} deg")
    if scene.waves is not None and finite:
        report["match"] = m = _match_report(w, scene.waves)
        worst = m["max_abs_error"]
        print(f"  vs the scene's {m['true_waves']} true wave(s): {m['matched']} matched, {len(m['missed'])} missed, "
              f"{len(m['spurious'])} spurious" + (f"; largest errors |dh| {worst['amplitude']:.3g} m, |domega| "
                                                   f"{worst['omega']:.3g} rad/s, |dtheta| {worst['theta_deg']:.3g} "
                                                   f"deg, |dphi| {worst['phase_deg']:.3g} deg" if worst else ""))
    write_result(w if finite else None, report)
    if not success:
        from jaxocean.fit.waves import normal_error_bound
        from jaxocean.waves import too_steep

        bound = normal_error_bound(args.noise)
        steep = int(too_steep(w).sum()) if finite else 0
        why = ("non-finite waves" if not finite else
               f"stopped at --max-waves {args.max_waves}" if args.n_waves is None and result.n_waves >= args.max_waves
               else f"the waves leave a mean normal error of {float(result.normal_error):.3g} rad, above "
                    f"{bound:.3g} rad for the stated noise" if not float(result.normal_error) <= bound
               else f"{steep} of {int(result.n_waves)} fitted waves are steeper than k h = 1 (looping crests: no "
                    f"sea surface; noisy geometry without --noise?)" if steep
               else "the fit reported failure")
        print(f"jaxocean: the wave fit failed: {why}; see extra.wave_fit in the JSON", file=sys.stderr)
        return EXIT_PROBLEMS
    return EXIT_OK


def cmd_forecast(args):
    import jax
    import jax.numpy as jnp

    from jaxocean.forecast import forecast, frame_times
    from jaxocean.io import read_scene
    from jaxocean.io.dataset import SceneSample
    from jaxocean.waves import Waves

    inputs.check_out_dir(args.out)
    inputs.refuse_out_over_source(args.out, args.waves, "forecast")
    inputs.refuse_other_json(args.waves, "forecast needs waves (a fit-waves result or a scene.json)")
    scene = read_scene(args.waves)
    if scene.waves is None:
        raise ValueError(f"{args.waves}: no waves to forecast (expected a fit-waves JSON or a scene.json)")
    inputs.refuse_damped_forecast(scene, args.waves, "forecast")
    wave_fit = (scene.extra or {}).get("wave_fit") if isinstance(scene.extra, dict) else None
    # only a JSON true vouches for the waves: a false, a missing or a hand-edited "false" does not
    if isinstance(wave_fit, dict) and wave_fit.get("success") is not True:
        error = wave_fit.get("normal_error_deg")
        flag = json.dumps(wave_fit["success"]) if "success" in wave_fit else "missing"
        detail = "" if not isinstance(error, (int, float)) else f", mean normal error {error:.3g} deg"
        if not args.allow_failed:
            raise ValueError(f"{args.waves}: the wave fit does not report success (success: {flag}{detail}); its "
                             f"waves need not explain the frames. Pass --allow-failed to forecast them anyway")
        print(f"jaxocean: warning: forecasting the waves of a fit that does not report success ({args.waves}: "
              f"success: {flag}{detail})", file=sys.stderr)
    if args.fps is not None and args.times is not None:
        raise ValueError("--fps applies to --frames; --times are already in seconds")
    known = None if scene.times is None else np.asarray(scene.times, np.float64)
    # the forecast is written as a scene, whose times must run forward
    inputs.check_increasing(args.frames if args.times is None else args.times,
                            "--frames" if args.times is None else "--times")
    if args.times is not None:
        times, frame_ids = np.asarray(args.times, np.float64), list(range(len(args.times)))
    else:
        frame_ids = list(args.frames)
        if args.fps is not None:
            t0 = 0.0 if known is None else float(known[0])
            times = t0 + np.asarray(frame_ids, np.float64) / args.fps
        elif known is not None and known.size >= 2:
            try:
                times = frame_times(known, frame_ids)
            except ValueError as error:
                raise ValueError(f"{args.waves}: {error}; its times are no frame clock: give --fps or --times") \
                    from None
        else:
            raise ValueError(f"{args.waves} holds no frame clock (two or more times); give --fps or --times")
    camera = inputs.camera_from_args(args, scene.camera, None, where=f"{args.waves}")
    inputs.check_memory(camera.resolution, len(times), "forecast")
    lighting = inputs.lighting_from_args(args, scene.lighting)
    model, damp = scene.waves, {}
    stored = wave_fit.get("forecast") if isinstance(wave_fit, dict) else None
    if stored is not None and not args.undamped:
        # the fit's whole model (waves and long-wave band), each component damped outside the
        # fitted window by its frequency uncertainty: the least-squares forecast
        try:
            band = Waves(*(np.asarray(stored["band"][name], np.float64) for name in Waves._fields))
            sigma = np.asarray(stored["frequency_sigma"], np.float64)
            window = tuple(float(w) for w in stored["window_s"])
        except (KeyError, TypeError, ValueError) as error:
            raise ValueError(f"{args.waves}: wave_fit.forecast is malformed ({type(error).__name__}: {error}); it "
                             f"needs window_s, frequency_sigma and band (re-run fit-waves, or pass --undamped)") \
                from None
        if len(window) != 2 or any(leaf.ndim != 1 or leaf.shape != band.omega.shape for leaf in band):
            raise ValueError(f"{args.waves}: wave_fit.forecast needs window_s [t_first, t_last] and band lists of "
                             f"one length; got window_s of {len(window)} and band lengths "
                             f"{[np.shape(leaf) for leaf in band]}")
        band = Waves(*(jnp.asarray(leaf, scene.waves.omega.dtype) for leaf in band))
        model = Waves(*(jnp.concatenate([a, b]) for a, b in zip(scene.waves, band)))
        if sigma.shape != model.omega.shape:
            raise ValueError(f"{args.waves}: wave_fit.forecast.frequency_sigma has {sigma.size} entries for "
                             f"{model.omega.shape[0]} waves and band stand-ins")
        damp = dict(window=window, frequency_sigma=jnp.asarray(sigma, model.omega.dtype))
        print(f"least-squares forecast: {np.size(scene.waves.omega)} wave(s) and {band.omega.shape[0]} long-wave "
              f"stand-in(s), each damped outside the fitted window ({damp['window'][0]:.4g}-{damp['window'][1]:.4g} "
              f"s) by its frequency uncertainty (--undamped: extrapolate every fitted wave as it is)")
    print(f"forecasting {np.size(model.omega)} wave(s) at t = "
          f"{', '.join(f'{t:.4g}' for t in times)} s ({camera.resolution[0]}x{camera.resolution[1]})")
    t0 = time.perf_counter()
    # drawn as a camera sees it (render's own choice of the hits or rows path, as `simulate` draws)
    result = jax.device_get(forecast(model, times, camera, lighting, plan="auto", **damp))
    render_s = time.perf_counter() - t0
    sample = SceneSample(scene.waves, None, camera, lighting, times)
    from jaxocean.io import write_sequence
    write_sequence(Path(args.out), sample, result.image, result.geometry, half=not args.float32,
                    frame_ids=frame_ids,
                    extra={"forecast_frames": frame_ids if args.times is None else None,
                           "forecast_from": str(args.waves), "forecast_damped": bool(damp)})
    print(f"rendered {len(times)} frame(s) in {render_s:.2f} s (compile included) -> {args.out}")
    for i, (f, t) in enumerate(zip(frame_ids, times)):
        label = f"frame {f}, " if args.times is None else ""
        print(f"  frame_{i:05d}.exr/png: {label}t = {t:.4g} s")
    _warn_if_sky_only(result.geometry.mask)
    return EXIT_OK


# What an interrupted command leaves, and what running it again does.
def cmd_reconstruct(args) -> int:
    from jaxocean import reconstruct

    out = inputs.check_out_dir(args.out)
    inputs.refuse_other_json(args.camera, "--camera takes a camera file (camera.json: intrinsics and a pose per "
                                          "frame) or a synthetic scene.json", camera_file_ok=True)
    for name in ("step", "wave_frames", "max_waves", "width"):
        if getattr(args, name) is not None and getattr(args, name) < 1:
            raise ValueError(f"--{name.replace('_', '-')} must be >= 1; got {getattr(args, name)}")
    if args.max_frames is not None and args.max_frames < 2:
        raise ValueError(f"--max-frames must be >= 2; got {args.max_frames}")
    if args.gamma is not None and args.response != "gamma":
        raise ValueError(f"--gamma is the exponent of --response gamma; the response is {args.response}")
    if args.per_frame_exposure and args.no_refine:
        raise ValueError("--per-frame-exposure sets stage 5's exposures, and --no-refine skips stage 5: give one")
    gamma = {} if args.gamma is None else {"gamma": args.gamma}  # None: the library's default exponent
    result = reconstruct.reconstruct(args.frames, args.camera, out=out, width=args.width, response=args.response,
                                     step=args.step, max_frames=args.max_frames, **gamma,
                                     height=args.camera_height, wave_frames=args.wave_frames,
                                     max_waves=args.max_waves, overcast=args.overcast, refine=not args.no_refine,
                                     per_frame_exposure=args.per_frame_exposure, geometry_model=args.geometry_model)
    failed = [n for n, r in result.stages.items() if not r.success]
    print(f"wrote {out / 'report.html'} and {out / 'result.json'}"
          + (f"; failed stages: {', '.join(failed)}" if failed else ""))
    return EXIT_PROBLEMS if failed else EXIT_OK


_INTERRUPTED = {
    "simulate": "completed scenes are kept; run the same command to resume",
    "render": "frames written so far are kept; running the command again renders every frame again",
    "demo": "files written so far are kept; running the command again starts over",
    "reedit": "frames written so far are kept; running the command again renders every frame again",
    "forecast": "frames written so far are kept; running the command again renders every frame again",
    "fit-lighting": "nothing was written; running the command again starts the fit over",
    "fit-waves": "nothing was written; running the command again starts the fit over",
    "train-geometry": "the last checkpoint is kept; run the same command to resume",
    "train-waves": "the last checkpoint is kept; run the same command to resume",
    "predict-geometry": "frames written so far are kept; running the command again predicts every frame again",
    "eval-geometry": "nothing was written; running the command again starts over",
    "reconstruct": "files written so far are kept; running the command again starts over",
}

COMMANDS = {"render": cmd_render, "simulate": cmd_simulate, "check": cmd_check, "demo": cmd_demo,
            "fit-lighting": cmd_fit_lighting, "reedit": cmd_reedit, "fit-waves": cmd_fit_waves,
            "forecast": cmd_forecast, "reconstruct": cmd_reconstruct}


def _format_warning(message, category, filename, lineno, line=None, *, default):
    """jaxocean's own warnings (a steep wave draw, an incomplete EXR frame) as the CLI's other
    warnings: one ``jaxocean: warning:`` line, not Python's file and source line."""
    if category.__module__.split(".")[0] == "jaxocean":
        return f"jaxocean: warning: {message}\n"
    return default(message, category, filename, lineno, line)


#: the commands that run the geometry network over many frames: there the CPU is split into
#: one XLA device per core and :func:`jaxocean.nn.geometry.predict` spreads each batch of
#: frames over them (XLA:CPU runs one convolution on one core)
#: (not ``reconstruct``: on the real 150-frame clip its geometry stage gains under a second
#: and its other stages' float64 values change in the 12th digit with the device count)
_SPLIT_FRAMES = ("predict-geometry", "eval-geometry")


def _one_cpu_device_per_core() -> None:
    """One CPU device per core, unless the user chose a count (``XLA_FLAGS``'s
    ``--xla_force_host_platform_device_count`` or ``jax_num_cpu_devices``) or JAX already
    runs (``main`` called from Python: its devices are fixed; only the speed differs). Work
    not split over devices runs on the first one, as before."""
    import os

    import jax

    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else (os.cpu_count() or 1)
    if (cores < 2 or "xla_force_host_platform_device_count" in os.environ.get("XLA_FLAGS", "")
            or jax.config.jax_num_cpu_devices != -1):
        return
    try:
        jax.config.update("jax_num_cpu_devices", cores)
    except RuntimeError:  # JAX's backends are running already
        pass


def main(argv=None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    from jaxocean.errors import InvalidValueError, MissingDependencyError

    if args.command in _SPLIT_FRAMES:
        _one_cpu_device_per_core()
    # compiled programs kept between runs: a second ``reconstruct`` or ``demo`` skips most of
    # the minutes of compilation (jaxocean.compile_cache)
    compile_cache.enable()

    try:
        with warnings.catch_warnings():
            warnings.formatwarning = functools.partial(_format_warning, default=warnings.formatwarning)
            return COMMANDS[args.command](args)
    except KeyboardInterrupt:
        print(f"jaxocean: interrupted ({_INTERRUPTED[args.command]})", file=sys.stderr)
        return EXIT_INTERRUPTED
    except (InvalidValueError, ValueError, FileNotFoundError, json.JSONDecodeError) as err:
        print(f"jaxocean: error: {err}", file=sys.stderr)
        return EXIT_INPUT
    except (FileExistsError, IsADirectoryError, NotADirectoryError, PermissionError, MissingDependencyError) as err:
        # a path argument that cannot be written or read as given, or not read without a package
        print(f"jaxocean: error: {err}", file=sys.stderr)
        return EXIT_INPUT


if __name__ == "__main__":
    sys.exit(main())
