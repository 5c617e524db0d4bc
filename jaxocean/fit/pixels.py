"""Per-pixel inversion of the shading model: each sea pixel's slope and roughness from its
colour alone, with the camera and lighting known.

Protocol
--------
:func:`invert(image, camera, lighting)` -> :class:`PixelFit`:

* unknowns per sea pixel: the world slope ``s = (s_x, s_y)`` (normal
  ``normalize(-s_x, -s_y, 1)``) and ``log sigma^2`` of an isotropic slope variance;
* residual: ``log1p(shade / m) - log1p(I / m)`` over R, G, B (``m`` the image's sea median
  per channel, as the geometry networks compare images), three equations for three
  unknowns;
* solver: ``iterations`` Levenberg-Marquardt steps per pixel (3 x 3 normal equations,
  Jacobian by forward mode), vmapped over the pixels, from the flat sea at the floor
  roughness. A fixed iteration count, so ``jit(invert) == invert``.

``PixelFit.residual (H, W)`` is each pixel's RMS residual and ``explained`` where it is
below ``tolerance``. A pixel that explains its colour is not necessarily right: one colour
constrains the along-view slope through the Fresnel term and the glitter but barely the
across-view slope, so many slopes explain it (the network uses neighbours; this does not).
This is the baseline a user would write first (the geometry networks' Table 1).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import shading
from jaxocean._math import normal_from_slope
from jaxocean._sea_scale import compress, sea_median
from jaxocean.errors import InvalidValueError, is_concrete

__all__ = ["PixelFit", "invert"]


class PixelFit(NamedTuple):
    """``normal (H, W, 3)``, ``slope_variance (H, W, 2)`` (isotropic pair), ``residual
    (H, W)`` RMS of the compressed colour residual, ``explained (H, W)`` bool, ``mask (H, W)``."""

    normal: jax.Array
    slope_variance: jax.Array
    residual: jax.Array
    explained: jax.Array
    mask: jax.Array


def _pixel_residual(u, target, view, lighting, scale):
    var = 0.5 * jnp.exp(u[2])
    color = shading.shade_pixel(normal_from_slope(u[:2]), var, var, view, lighting)
    return compress(color, scale) - target


def _solve_pixel(target, view, lighting, scale, iterations):
    u0 = jnp.asarray([0.0, 0.0, jnp.log(2 * shading.MIN_SLOPE_VARIANCE_AXIS) + 2.0], target.dtype)

    def body(_, carry):
        u, lam = carry
        r = _pixel_residual(u, target, view, lighting, scale)
        J = jax.jacfwd(_pixel_residual)(u, target, view, lighting, scale)
        JtJ = J.T @ J
        step = jnp.linalg.solve(JtJ + lam * (jnp.diag(jnp.diag(JtJ)) + 1e-9 * jnp.eye(3)), -J.T @ r)
        step = jnp.clip(step, -0.5, 0.5)
        trial = u + step
        trial = trial.at[2].set(jnp.clip(trial[2], jnp.log(2 * shading.MIN_SLOPE_VARIANCE_AXIS), jnp.log(0.5)))
        better = jnp.sum(_pixel_residual(trial, target, view, lighting, scale) ** 2) < jnp.sum(r ** 2)
        return jnp.where(better, trial, u), jnp.where(better, lam * 0.3, lam * 4.0)

    u, _ = jax.lax.fori_loop(0, iterations, body, (u0, jnp.asarray(1e-2, target.dtype)))
    return u, jnp.sqrt(jnp.mean(_pixel_residual(u, target, view, lighting, scale) ** 2))


@functools.partial(jax.jit, static_argnames=("iterations",))
def _invert(image, camera, lighting, tolerance, iterations):
    hit = cam.intersect_sea(camera)
    mask = hit.mask
    scale = sea_median(image, mask)
    target = compress(image, scale)
    H, W = mask.shape
    solve = jax.vmap(lambda t, v: _solve_pixel(t, v, lighting, scale, iterations))
    u, res = solve(target.reshape(-1, 3), hit.view.reshape(-1, 3))
    u, res = u.reshape(H, W, 3), res.reshape(H, W)
    normal = normal_from_slope(u[..., :2])
    up = jnp.asarray([0.0, 0.0, 1.0], image.dtype)
    normal = jnp.where(mask[..., None], normal, up)
    var = jnp.where(mask, 0.5 * jnp.exp(u[..., 2]), shading.MIN_SLOPE_VARIANCE_AXIS)
    res = jnp.where(mask, res, 0.0)
    return PixelFit(normal, jnp.stack([var, var], -1), res, mask & (res <= tolerance), mask)


def invert(image, camera, lighting, *, tolerance: float = 1e-3, iterations: int = 30) -> PixelFit:
    """Invert each sea pixel of a linear image ``(H, W, 3)`` (module docstring)."""
    cam.validate_camera(camera)
    shading.validate_lighting(lighting)
    image = jnp.asarray(image)
    if image.shape != tuple(camera.resolution) + (3,):
        raise ValueError(f"image must be (H, W, 3) = {tuple(camera.resolution) + (3,)} for this camera; "
                         f"got {image.shape}")
    if iterations < 1:
        raise ValueError(f"iterations must be >= 1; got {iterations}")
    if is_concrete(image, camera):
        # a NaN/inf sea pixel would come back as a NaN residual, silently (the sky is not used)
        bad = ~np.isfinite(np.asarray(image)).all(-1) & np.asarray(cam.intersect_sea(camera).mask)
        if bad.any():
            first = np.argwhere(bad)[0].tolist()
            raise InvalidValueError(f"image has {int(bad.sum())} NaN/inf sea pixel(s) (first at (row, col) = "
                                    f"{first}); fit.pixels.invert needs finite linear radiance")
    return _invert(image, camera, lighting, jnp.asarray(tolerance, image.dtype), iterations)
