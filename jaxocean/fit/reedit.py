"""Re-editing fitted scenes (new camera, new light) and ocean style transfer.

Protocol
--------
* :func:`edit_camera` / :func:`edit_lighting` -- a copy of a camera / lighting with some
  fields replaced (radians, metres), validated.
* :func:`reedit` ``(waves, camera, lighting, times, **edits) -> (T, H, W, 3)`` (or
  ``(H, W, 3)`` for a scalar time): the scene rendered with the edits applied -- camera
  height, pitch, field of view, yaw, resolution; sun azimuth, elevation, colours. The
  paper's Fig. 15-16 (change camera height, view angle, sun direction).
* :func:`reedit_scene` ``(scene_dir, out_dir, ...)`` -- the same for a scene directory
  (``scene.json`` with waves, camera, lighting, times), writing EXR frames with geometry,
  PNG previews and the edited ``scene.json`` into ``out_dir``. Angles in **degrees** here,
  as on the command line.
* :func:`style_transfer` ``(a, b) -> StyleTransfer`` -- fit the lighting and sea colour on
  frame A (``(image, geometry, camera)``) and render scene B (``(waves, camera, t)``) with
  them. By default the sun keeps its azimuth *relative to the view* (so the glitter lands
  where it did in A); ``sun="absolute"`` keeps the world azimuth.

Rendering goes through :func:`jaxocean.render.render` with a plan computed once for the new
camera (concrete inputs), frames mapped with ``jax.vmap`` over time.
"""

from __future__ import annotations

import dataclasses
import math
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import render, shading
from jaxocean.errors import InvalidValueError, is_concrete, is_integer
from jaxocean.fit import lighting as lf
from jaxocean.shading import Lighting
from jaxocean.waves import check_phase_precision

__all__ = ["StyleTransfer", "edit_camera", "edit_lighting", "reedit", "reedit_scene", "style_transfer"]


def edit_camera(camera: cam.Camera, *, height=None, pitch=None, yaw=None, fov=None, resolution=None) -> cam.Camera:
    """``camera`` with the given fields replaced (metres, radians, ``(H, W)``); validated."""
    changes = {k: jnp.asarray(v, jnp.result_type(camera.height)) for k, v in
               dict(height=height, pitch=pitch, yaw=yaw, fov=fov).items() if v is not None}
    if resolution is not None:
        changes["resolution"] = tuple(int(n) for n in resolution)
    return cam.validate_camera(dataclasses.replace(camera, **changes))


def edit_lighting(lighting: Lighting, *, sun_azimuth=None, sun_elevation=None, sun_color=None, sky_color=None,
                  sea_color=None) -> Lighting:
    """``lighting`` with the given fields replaced (radians, linear RGB); validated."""
    dtype = jnp.result_type(lighting.sun_azimuth)
    changes = {k: jnp.asarray(v, dtype) for k, v in
               dict(sun_azimuth=sun_azimuth, sun_elevation=sun_elevation, sun_color=sun_color,
                    sky_color=sky_color, sea_color=sea_color).items() if v is not None}
    return shading.validate_lighting(lighting._replace(**changes))


def reedit(waves, camera: cam.Camera, lighting: Lighting, times, *, camera_height=None, camera_pitch=None,
           camera_fov=None, camera_yaw=None, resolution=None, sun_azimuth=None, sun_elevation=None, sun_color=None,
           sky_color=None, sea_color=None, horizon_gradient=0.0):
    """Render ``waves`` at ``times`` through the edited camera and lighting.

    Edits default to the given ``camera`` / ``lighting`` (e.g. a fit's). ``times``: a finite
    scalar or ``(T,)``, concrete (the render is planned from them). Returns linear RGB
    ``(T, H, W, 3)``, or ``(H, W, 3)`` when ``times`` is a scalar.
    """
    camera = edit_camera(camera, height=camera_height, pitch=camera_pitch, fov=camera_fov, yaw=camera_yaw,
                         resolution=resolution)
    lighting = edit_lighting(lighting, sun_azimuth=sun_azimuth, sun_elevation=sun_elevation, sun_color=sun_color,
                             sky_color=sky_color, sea_color=sea_color)
    times = jnp.asarray(times, waves.omega.dtype)
    if times.ndim > 1:
        raise ValueError(f"times must be a scalar or (T,); got shape {times.shape}")
    if not is_concrete(times):
        raise ValueError("fit.reedit plans the render from concrete times (eager); inside jit call "
                         "jaxocean.render.render with a plan")
    if times.size == 0:
        raise ValueError("times holds no time: nothing to render")
    if not np.all(np.isfinite(np.asarray(times))):
        # the frames are rendered under vmap, where render's own check cannot see the values
        raise InvalidValueError(f"times must be finite; got {np.asarray(times).tolist()}")
    scalar = times.ndim == 0
    times = jnp.atleast_1d(times)
    check_phase_precision(waves, times[:, None])  # nor their phases' precision
    plan = render.plan(waves, camera, times[0])
    frames = jax.vmap(lambda t: render.render(waves, camera, lighting, t, plan=plan,
                                              horizon_gradient=horizon_gradient))(times)
    return frames[0] if scalar else frames


def reedit_scene(scene_dir, out_dir, *, camera_height=None, camera_pitch_deg=None, camera_fov_deg=None,
                 camera_yaw_deg=None, resolution=None, sun_azimuth_deg=None, sun_elevation_deg=None,
                 lighting: Lighting | None = None, frames=None, exposure=1.0, half: bool = True,
                 progress: bool = True) -> Path:
    """Re-render a scene directory with edits; write ``out_dir/frame_XXXXX.exr`` (+ ``.png``) and
    ``out_dir/scene.json``. Each frame's EXR ``frame`` metadata and the scene's
    ``extra.reedited_frames`` give the index of the scene frame it re-renders.

    Args:
        scene_dir: a directory with ``scene.json`` (or the json path) holding waves, camera,
            lighting and (optionally) times; missing times mean one frame at t = 0.
        out_dir: output directory (created).
        camera_height: metres; ``camera_pitch_deg``, ``camera_fov_deg``, ``camera_yaw_deg``,
            ``sun_azimuth_deg``, ``sun_elevation_deg``: degrees; ``resolution``: ``(H, W)``.
        lighting: a lighting to use instead of the scene's (e.g. a fit's), edits apply on top.
        frames: indices of the scene's times to render, increasing (default all).
        exposure: of the PNG previews; ``half``: EXR pixel type (float32 where the radiance
            exceeds the half range); ``progress``: a progress bar while writing.

    Returns:
        ``out_dir`` as a Path. Written by :func:`jaxocean.io.write_sequence` (atomic files,
        the same layout as ``jaxocean render``).
    """
    from jaxocean import io  # host-side I/O, imported on use

    scene = io.read_scene(scene_dir)
    if scene.waves is None or scene.camera is None or (scene.lighting is None and lighting is None):
        raise ValueError(f"{scene_dir}: scene.json needs waves, camera and lighting to re-render")
    light = scene.lighting if lighting is None else lighting
    times = np.zeros(1) if scene.times is None else np.atleast_1d(np.asarray(scene.times))
    frame_ids = list(range(times.size)) if frames is None else list(frames)
    # indices into the scene's times, as a time sequence (the scene written from them is one)
    if not frame_ids or not all(is_integer(f, 0) and f < times.size for f in frame_ids):
        raise ValueError(f"{scene_dir}: frames must be indices 0..{times.size - 1} of the scene's {times.size} "
                         f"frame(s); got {frame_ids}")
    if any(b <= a for a, b in zip(frame_ids, frame_ids[1:])):
        raise ValueError(f"frames must increase strictly (a time sequence); got {frame_ids}")
    frame_ids = [int(f) for f in frame_ids]
    times = times[np.asarray(frame_ids, dtype=int)]

    def rad(deg):
        return None if deg is None else math.radians(deg)

    camera = edit_camera(scene.camera, height=camera_height, pitch=rad(camera_pitch_deg), fov=rad(camera_fov_deg),
                         yaw=rad(camera_yaw_deg), resolution=resolution)
    light = edit_lighting(light, sun_azimuth=rad(sun_azimuth_deg), sun_elevation=rad(sun_elevation_deg))
    plan = render.plan(scene.waves, camera, float(times[0]))
    geos, images = [], []
    for t in times:  # one frame at a time: the plan is static, the kernels compile once
        geo = render.geometry(scene.waves, camera, float(t), plan=plan)
        geos.append(geo)
        images.append(render.shade(geo.normal, geo.roughness, camera, light, slope_variance=geo.slope_variance))
    geometry = jax.tree.map(lambda *x: np.stack([np.asarray(a) for a in x]), *geos)
    edited = scene._replace(camera=camera, lighting=light, times=times)
    out = Path(out_dir)
    io.write_sequence(out, edited, np.stack([np.asarray(i) for i in images]), geometry, half=half,
                      seed=scene.seed, progress=progress, exposure=exposure, frame_ids=frame_ids,
                      extra={"reedited_from": str(scene_dir), "reedited_frames": frame_ids})
    return out


class StyleTransfer(NamedTuple):
    """Result of :func:`style_transfer`: ``image`` ``(H, W, 3)`` scene B in A's style, the
    ``lighting`` used for it, and A's lighting ``fit``."""

    image: jax.Array
    lighting: Lighting
    fit: lf.LightingFit


def style_transfer(a, b, *, sun: str = "relative", **fit_kwargs) -> StyleTransfer:
    """Fit lighting and sea colour on frame ``a = (image, geometry, camera)`` and render scene
    ``b = (waves, camera, t)`` with them.

    ``sun="relative"`` (default) keeps the sun's azimuth relative to the camera yaw (the
    glitter stays where it was in A's view); ``"absolute"`` keeps its world azimuth.
    ``fit_kwargs`` go to :func:`jaxocean.fit.lighting.lighting`.
    """
    if sun not in ("relative", "absolute"):
        raise ValueError(f"sun must be 'relative' or 'absolute'; got {sun!r}")
    if len(a) != 3 or len(b) != 3:
        raise ValueError("style_transfer takes a = (image, geometry, camera) and b = (waves, camera, t)")
    image_a, geometry_a, camera_a = a
    waves_b, camera_b, t_b = b
    result = lf.lighting(image_a, geometry_a, camera_a, **fit_kwargs)
    light = result.lighting
    if sun == "relative":
        az = light.sun_azimuth - jnp.asarray(camera_a.yaw, light.sun_azimuth.dtype) + jnp.asarray(
            camera_b.yaw, light.sun_azimuth.dtype)
        light = light._replace(sun_azimuth=jnp.arctan2(jnp.sin(az), jnp.cos(az)))
    light = jax.tree.map(lambda x: jnp.asarray(x, waves_b.omega.dtype), light)
    image = render.render(waves_b, camera_b, light, t_b)
    return StyleTransfer(image, light, result)
