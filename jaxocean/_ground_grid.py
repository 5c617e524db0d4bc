"""Square ground grids on the mean sea plane and image sequences resampled onto them.

Shared by the wave fit's spectral start (:mod:`jaxocean.fit.waves`) and the dispersion check
(:mod:`jaxocean.spacetime`).

* ``grid_frames(camera, scales, grid)``: a pyramid of ``scales`` grids of ``grid x grid``
  points in front of a camera: anchors ``(S, 2)`` [m], unit axes ``e_u`` (along the camera's
  yaw), ``e_v`` (to its right) ``(2,)``, spacings ``(S,)`` [m] and a flag ``(S,)`` telling
  whether a grid is coarser than the pixels where it sits (then sample it box-filtered).
* ``grid_points(anchor, e_u, e_v, spacing, grid) -> (G, G, 2)``: point ``(a, b)`` is
  ``anchor + spacing ((a + 1/2) e_u + (b - G/2 + 1/2) e_v)``: the grid starts at the anchor
  and is centred across the view.
* ``resample(values, weight, camera, anchor, e_u, e_v, spacing, level, use_box, grid)``:
  per-pixel ``values (T, H, W, C)`` with weights ``(T, H, W)`` in [0, 1] -> ``(T, G, G, C)``
  on the grid (bilinear, weight-normalised), validity ``(T, G, G)`` (every contributing pixel
  had weight 1) and the points ``(G, G, 2)``; box-filtered over ``2^level`` pixels first
  where ``use_box``.
* ``hann(n, dtype)``: the periodic-centred Hann window ``0.5 - 0.5 cos(2 pi (i + 1/2) / n)``.

Jittable (static ``scales``, ``grid``, ``level``); metres and radians.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from jaxocean import camera as cam
from jaxocean.surface import surface_point

__all__ = ["hann", "grid_frames", "grid_points", "box_filter", "resample"]


def hann(n, dtype):
    i = jnp.arange(n, dtype=dtype)
    return 0.5 - 0.5 * jnp.cos(2 * jnp.pi * (i + 0.5) / n)


def grid_frames(camera, scales, grid):
    """Anchors ``(S, 2)``, unit axes ``e_u, e_v (2,)``, spacings ``(S,)`` and a flag ``(S,)``
    telling whether a grid sits where the pixels are finer than it (then the values are
    box-filtered before sampling, against aliasing).

    Perspective: grid ``s`` is spaced ``0.75 f_s`` with ``f_s = 2^s`` x the nearest sea
    footprint and starts at the nearest image row whose footprint reaches ``f_s``, looking
    along the camera's yaw: a pyramid that walks from the near field to the far field, so
    that long waves are seen over many wavelengths. Orthographic: one grid over the image.
    """
    H, W = camera.resolution
    dtype = jnp.result_type(camera.height, float)
    yaw = jnp.asarray(camera.yaw, dtype)
    e_u = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)])
    e_v = jnp.stack([jnp.sin(yaw), -jnp.cos(yaw)])
    levels = 2.0 ** jnp.arange(scales, dtype=dtype)
    if camera.projection == "orthographic":
        cell = jnp.asarray(camera.ortho_width, dtype) / W
        d0 = cell * max(1.0, min(H, W) / grid)
        centre = jnp.stack([jnp.asarray(camera.x, dtype), jnp.asarray(camera.y, dtype)])
        spacing = d0 * levels
        anchors = centre[None] - 0.5 * grid * spacing[:, None] * e_u[None]
        return anchors, e_u, e_v, spacing, levels > 1
    hit = cam.intersect_sea(camera)
    row_sea = jnp.any(hit.mask, axis=1)
    fp_row = jnp.where(row_sea, hit.footprint[:, W // 2], 0.0)
    near = H - 1 - jnp.argmax(row_sea[::-1])
    f0 = hit.footprint[near, W // 2]
    target = f0 * levels  # (S,)
    rows = jnp.arange(H)
    reach = row_sea[None, :] & (fp_row[None, :] >= target[:, None] * 0.999)  # (S, H)
    # the nearest (largest index) row that reaches the target footprint, else the near row
    row = jnp.where(jnp.any(reach, axis=1), jnp.max(jnp.where(reach, rows[None, :], -1), axis=1), near)
    fallback = ~jnp.any(reach, axis=1) & (levels > 1)
    anchors = hit.xy[row, W // 2]
    spacing = 0.75 * target
    return anchors, e_u, e_v, spacing, fallback


def grid_points(anchor, e_u, e_v, spacing, grid):
    dtype = jnp.result_type(anchor, float)
    iu = jnp.arange(grid, dtype=dtype) + 0.5
    iv = jnp.arange(grid, dtype=dtype) - grid / 2 + 0.5
    return anchor + spacing * (iu[:, None, None] * e_u + iv[None, :, None] * e_v)  # (G, G, 2)


def box_filter(img, size):
    """Mean over ``size x size`` pixels (the first two axes), same shape."""
    if size == 1:
        return img
    window = (size, size) + (1,) * (img.ndim - 2)
    return jax.lax.reduce_window(img, 0.0, jax.lax.add, window, (1,) * img.ndim, "SAME") / float(size * size)


def resample(values, weight, camera, anchor, e_u, e_v, spacing, level, use_box, grid, surface=None, times=None):
    """``values (T, H, W, C)`` and validity ``(T, G, G)`` on one ground grid (module docstring).

    ``surface`` (``Waves``, with the frame ``times (T,)``): the grid's points are rest
    positions of that trochoid surface, and frame ``t`` is sampled at the pixel that sees
    the surface point of each at time ``t`` (so that waves riding on the surface's longer
    waves are plane waves on the grid); None: the mean sea plane's points."""
    dtype = values.dtype
    size = 2 ** level
    T = weight.shape[0]
    sw = jnp.moveaxis(values * weight[..., None], 0, -1)  # (H, W, C, T)
    wt = jnp.moveaxis(weight, 0, -1)  # (H, W, T)
    if size > 1:
        sw = jnp.where(use_box, box_filter(sw, size), sw)
        wt = jnp.where(use_box, box_filter(wt, size), wt)
    X = grid_points(anchor, e_u, e_v, spacing, grid).astype(dtype)
    if surface is None:  # the plane's points: one projection serves every frame
        ij = jnp.broadcast_to(cam.project(camera, jnp.concatenate([X, jnp.zeros_like(X[..., :1])], -1)),
                              (T, grid, grid, 2))
    else:
        ij = cam.project(camera, jax.vmap(lambda t: surface_point(surface, X, t))(jnp.asarray(times, dtype)))

    def sample(img2d, coords):
        return jax.scipy.ndimage.map_coordinates(img2d, [coords[..., 0], coords[..., 1]], order=1, mode="constant",
                                                 cval=0.0)

    per_channel = jax.vmap(sample, in_axes=(-1, None), out_axes=-1)  # (H, W, C), coords -> (G, G, C)
    s_g = jax.vmap(per_channel, in_axes=(-1, 0), out_axes=-1)(sw, ij)  # (G, G, C, T)
    w_g = jax.vmap(sample, in_axes=(-1, 0), out_axes=-1)(wt, ij)  # (G, G, T)
    valid = w_g > 0.999
    s_g = jnp.where(valid[:, :, None, :], s_g / jnp.where(valid, w_g, 1.0)[:, :, None, :], 0.0)
    return jnp.moveaxis(s_g, -1, 0), jnp.moveaxis(valid.astype(dtype), -1, 0), X
