"""Input checks and sampling of the wave fit (:mod:`jaxocean.fit.waves`).

Protocol: :func:`check_inputs` validates one scene (normals ``(T, H, W, 3)``, roughness
``(T, H, W)`` or None, a :class:`jaxocean.camera.Camera` of resolution ``(H, W)``, frame
times ``(T,)`` [s]); :func:`valid_weights` marks the pixel-frames that carry weight (sea,
finite, normal facing up); :func:`all_samples` flattens pixel-frames into :class:`Samples`
(time [s], rest position ``(M, 2)`` [m], row footprint [m], target ``(M, 2)``, sqrt weight)
for the structured Jacobian and the candidate scoring; :func:`subsample` and :func:`chunked`
pick and block them.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import shading
from jaxocean._math import slope_from_normal
from jaxocean.errors import InvalidValueError, check_values, is_concrete


MIN_NZ = 0.05  # normals flatter than this (|slope| > 20) are treated as invalid
UNIT_NORMAL_TOLERANCE = shading.UNIT_NORMAL_TOLERANCE  # the one tolerance of every public function


# =============================================================================== inputs


def check_inputs(normals, roughness, camera, times):
    """Validate a scene for fitting; returns ``(normals, roughness, times)`` as arrays.

    Structure -> ``ValueError``: camera missing or not a Camera, normals not ``(T, H, W, 3)``
    matching the camera's resolution, roughness not ``(T, H, W)``, times not ``(T,)``, fewer
    than two frames. Values (when concrete) -> :class:`InvalidValueError`: frame times not
    strictly increasing or not finite, no valid sea pixel, normals that are not unit vectors
    (``| |n| - 1 | > UNIT_NORMAL_TOLERANCE`` on a valid sea pixel: an image's RGB values passed
    as normals, say), negative roughness.
    """
    if camera is None:
        raise ValueError("fit.waves needs the camera the geometry was seen with (camera=None given)")
    if not isinstance(camera, cam.Camera):
        raise ValueError(f"camera must be a jaxocean Camera; got {type(camera).__name__}")
    cam.validate_camera(camera)
    normals = jnp.asarray(normals)
    if not jnp.issubdtype(normals.dtype, jnp.floating):
        normals = normals.astype(jnp.result_type(float))
    H, W = camera.resolution
    if normals.ndim != 4 or normals.shape[1:] != (H, W, 3):
        raise ValueError(f"normals must be (T, H, W, 3) with (H, W) = camera.resolution = {(H, W)}; "
                         f"got {normals.shape}")
    T = normals.shape[0]
    if T < 2:
        raise ValueError(f"a wave fit needs a sequence of at least 2 frames (frequency comes from the motion); "
                         f"got {T}")
    times = jnp.asarray(times, normals.dtype)
    if times.shape != (T,):
        raise ValueError(f"times must be (T,) = ({T},), one per frame; got shape {times.shape}")
    if roughness is not None:
        roughness = jnp.asarray(roughness, normals.dtype)
        if roughness.shape != (T, H, W):
            raise ValueError(f"roughness must be (T, H, W) = {(T, H, W)}; got {roughness.shape}")
    if is_concrete(times):
        t = np.asarray(times)
        check_values(np.isfinite(t), "frame times must be finite", t)
        # the times themselves in the message (each one not after the time before it), not their steps
        check_values(np.concatenate([[True], np.diff(t) > 0]), "frame times must be strictly increasing", t)
    if is_concrete(normals, camera):
        valid = np.asarray(valid_weights(normals, camera)) > 0
        if not bool(np.any(valid)):
            raise InvalidValueError("no valid sea pixel: every pixel is sky or has a non-finite/downward normal")
        shading.check_unit_normals(normals, "normals", where=valid, counted=" sea pixel-frames",
                                   hint=". An image is not geometry: pass normals "
                                        "from render.geometry, a geometry network or an EXR frame's normal.X/Y/Z "
                                        "channels")
    if roughness is not None and is_concrete(roughness):
        r = np.asarray(roughness)
        finite = np.isfinite(r)
        check_values(~finite | (r >= 0), "roughness must be >= 0", r)
    return normals, roughness, times


def valid_weights(normals, camera):
    """Per pixel-frame validity ``(T, H, W)`` in {0, 1}: sea, finite, facing up."""
    hit = cam.intersect_sea(camera)
    finite = jnp.all(jnp.isfinite(normals), axis=-1)
    ok = finite & (jnp.where(finite, normals[..., 2], 0.0) > MIN_NZ)
    return (ok & hit.mask[None]).astype(normals.dtype)


def clean_inputs(normals, roughness, weight):
    """Replace invalid entries by harmless values (they carry zero weight)."""
    up = jnp.zeros(3, normals.dtype).at[2].set(1.0)
    normals = jnp.where(weight[..., None] > 0, normals, up)
    if roughness is None:
        roughness = jnp.full(normals.shape[:-1], shading.MIN_SLOPE_VARIANCE, normals.dtype)
    roughness = jnp.where((weight > 0) & jnp.isfinite(roughness), roughness, 0.0)
    return normals, roughness


def slope_field(normals):
    """Slope field ``(-n_x / n_z, -n_y / n_z)`` ``(..., 2)``; normals must face up (cleaned)."""
    return slope_from_normal(normals, MIN_NZ)


def plane_hits(camera, hit=None):
    """Plane hits ``xy (H, W, 2)``, per-row footprint ``(H,)`` (the centre column, as the
    renderer's rows path uses) and the sea mask; ``hit``: the camera's
    ``intersect_sea``, when the caller has it."""
    hit = cam.intersect_sea(camera) if hit is None else hit
    W = camera.resolution[1]
    return hit.xy, hit.footprint[:, W // 2], hit.mask


# =============================================================================== sampling


class Samples(NamedTuple):
    """Pixel-frames as flat samples ``(M, ...)``: time, rest position, row footprint,
    observed normal x, y (or residual slopes), the sqrt of the residual weight, and the
    pixel ray's horizontal run per unit height ``(M, 2)`` (what moves a hit with the surface)."""

    t: jax.Array
    xy: jax.Array
    fp: jax.Array
    target: jax.Array
    sw: jax.Array
    ray: jax.Array


def all_samples(normals_xy, weight, times, camera, scale=1.0, positions=None) -> Samples:
    """Every pixel-frame as a sample; ``normals_xy (T, H, W, 2)``; ``positions (T, H, W, 2)``
    the rest position each pixel-frame sees (None: the plane hits, the rows path's)."""
    T, H, W = weight.shape
    hit = cam.intersect_sea(camera)
    xy, fp_row, _ = plane_hits(camera, hit)
    xy = jnp.broadcast_to(xy[None], (T, H, W, 2)) if positions is None else positions
    down = jnp.minimum(hit.direction[..., 2:], -1e-6)  # sky rays carry no weight
    run = jnp.where(hit.mask[..., None], hit.direction[..., :2] / down, 0.0)
    return Samples(
        t=jnp.broadcast_to(times[:, None, None], (T, H, W)).reshape(-1),
        xy=xy.reshape(-1, 2),
        fp=jnp.broadcast_to(fp_row[None, :, None], (T, H, W)).reshape(-1),
        target=normals_xy.reshape(-1, 2),
        sw=jnp.sqrt(weight * scale).reshape(-1),
        ray=jnp.broadcast_to(run[None], (T, H, W, 2)).reshape(-1, 2),
    )


def subsample(s: Samples, count: int) -> Samples:
    """A deterministic, evenly spread subset of ``count`` samples (a golden-ratio stride
    through the flattened (T, H, W) order, so no row, column or frame is favoured)."""
    m = s.t.shape[0]
    if count >= m:
        return s
    stride = int(round(m * 0.6180339887498949)) | 1
    while math.gcd(stride, m) != 1:
        stride += 2
    idx = (np.arange(count, dtype=np.int64) * stride) % m
    return jax.tree.map(lambda x: x[idx], s)


def chunked(s: Samples, size: int) -> Samples:
    """Reshape samples into ``(C, size, ...)`` chunks, padding with zero-weight samples."""
    m = s.t.shape[0]
    c = -(-m // size)
    pad = c * size - m

    def rs(x, fill):
        if pad:
            x = jnp.concatenate([x, jnp.full((pad,) + x.shape[1:], fill, x.dtype)])
        return x.reshape((c, size) + x.shape[1:])

    # padding: zero weight, a unit footprint (nothing divides by zero)
    return Samples(rs(s.t, 0.0), rs(s.xy, 0.0), rs(s.fp, 1.0), rs(s.target, 0.0), rs(s.sw, 0.0), rs(s.ray, 0.0))

