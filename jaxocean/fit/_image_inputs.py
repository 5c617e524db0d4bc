"""Input checks and pixel weights common to the image fits (fit.lighting, fit.camera).

Public within the package, not part of the user API (``tonemap_weights`` and
``WEIGHT_MODES`` are re-exported by :mod:`jaxocean.fit.lighting`).

Protocol
--------
* ``check_image(image, camera) -> image``: a floating ``(H, W, 3)`` array; the camera validated.
* ``check_resolution(image, camera)``: ``ValueError`` unless ``image``'s ``(H, W)`` is the camera's.
* ``check_tracing(name, traced, throw, spec, solver)``: ``ValueError`` for ``throw=True`` or a
  host solver under ``jit`` / ``vmap``.
* ``solver_limits(solver, dtype, max_steps, rtol, atol) -> (max_steps, rtol, atol)`` with the
  defaults filled in (50 steps, 400 for Adam; 1e-6 in float32, 1e-10 in float64).
* ``pixel_weights(weights, mask, resolution, dtype, image=None, exposure=1.0, tonemap=...,
  saturation=None) -> (H, W, 3)``: residual weights from ``"display"`` (the tone map's slope,
  :func:`tonemap_weights`), ``"uniform"`` or an array, zero outside ``mask``.
* ``validate_values(image, weight, geo_mask, camera, fit, used=None)``: value checks before
  any work on concrete inputs (NaN pixels selected, empty selection, geometry made with
  another camera, no sea pixel) -> :class:`jaxocean.errors.InvalidValueError`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import shading
from jaxocean.errors import InvalidValueError, check_values, is_concrete

__all__ = ["WEIGHT_MODES", "check_image", "check_resolution", "check_tracing", "solver_limits", "pixel_weights",
           "validate_values", "tonemap_weights"]

_DEFAULT_TOL = {"float32": (1e-6, 1e-6), "float64": (1e-10, 1e-10)}
_DEFAULT_MAX_STEPS = {"adam": 400}


def check_image(image, camera):
    """``image`` as a floating ``(H, W, 3)`` array matching the validated ``camera``'s
    resolution (integers become the default float dtype). Shared by every image fit."""
    image = jnp.asarray(image)
    if image.ndim != 3 or image.shape[-1] != 3:
        raise ValueError(f"image must be (H, W, 3) linear RGB; got shape {image.shape}")
    cam.validate_camera(camera)
    return fit_dtype(image, "image is")


def fit_dtype(array, subject: str):
    """``array`` in the dtype the fit runs in: integers become the default float dtype;
    float32 and float64 stay; any other float (float16) is refused, ``subject`` ("image is",
    "images are") opening the message. Shared by every image fit."""
    array = jnp.asarray(array)
    if not jnp.issubdtype(array.dtype, jnp.floating):
        return array.astype(jnp.zeros(()).dtype)
    if array.dtype not in (jnp.float32, jnp.float64):
        raise ValueError(f"{subject} {array.dtype}: the fits run in float32 or float64 (the input's dtype is the "
                         f"fit's); pass it as .astype(jnp.float32)")
    return array


def check_resolution(image, camera) -> None:
    if tuple(image.shape[:2]) != tuple(camera.resolution):
        raise ValueError(f"image is {image.shape[:2]} (H, W) but the camera's resolution is {camera.resolution}")


def check_tracing(name: str, traced: bool, throw: bool, spec, solver: str) -> None:
    """Under jit/vmap a fit can neither raise on failure nor use a host solver."""
    if traced and throw:
        raise ValueError(f"{name} under jit/vmap cannot raise on failure: pass throw=False and read .success")
    if traced and not spec.traceable:
        raise ValueError(f"solver {solver!r} runs on the host and cannot be used under jit/vmap")


def solver_limits(solver: str, dtype, max_steps, rtol, atol) -> tuple[int, float, float]:
    """``(max_steps, rtol, atol)`` with the defaults of ``solver`` and the working precision
    filled in (50 steps, 400 for Adam; tolerances 1e-6 in float32, 1e-10 in float64)."""
    if max_steps is None:
        max_steps = _DEFAULT_MAX_STEPS.get(solver, 50)
    d_rtol, d_atol = _DEFAULT_TOL["float64" if dtype == jnp.float64 else "float32"]
    return int(max_steps), float(d_rtol if rtol is None else rtol), float(d_atol if atol is None else atol)


WEIGHT_MODES = ("display", "uniform")


def pixel_weights(weights, mask, resolution, dtype, image=None, exposure=1.0, tonemap="bruneton", saturation=None):
    H, W = resolution
    w = jnp.ones((H, W, 3), dtype)
    if isinstance(weights, str):
        if weights not in WEIGHT_MODES:
            raise ValueError(f"weights must be an array or one of {WEIGHT_MODES}; got {weights!r}")
        if weights == "uniform":
            weights = None
        else:  # the tone map's slope at the observed radiance (NaN pixels: checked later)
            finite = jnp.where(jnp.isfinite(image), image, 0.0)
            weights = tonemap_weights(finite, exposure, tonemap)
            if saturation is not None:
                weights = jnp.where(shading.tonemap(finite, exposure, tonemap) > saturation, 0.0, weights)
    if weights is not None:
        weights = jnp.asarray(weights, dtype)
        if weights.shape == (H, W):
            weights = weights[..., None]
        if weights.shape not in ((H, W, 1), (H, W, 3)):
            raise ValueError(f"weights must be (H, W) or (H, W, 3) = {(H, W, 3)}; got {weights.shape}")
        if is_concrete(weights):
            check_values(np.isfinite(np.asarray(weights)), "weights must be finite", weights)
            check_values(np.asarray(weights) >= 0, "weights must be >= 0", weights)
        w = w * weights
    if mask is not None:
        mask = jnp.asarray(mask)
        if mask.shape != (H, W):
            raise ValueError(f"mask must be (H, W) = {(H, W)}; got {mask.shape}")
        w = jnp.where(mask[..., None], w, 0.0)
    return w


def validate_values(image, weight, geo_mask, camera, fit, used=None):
    """Value checks before any work (concrete inputs only). ``used``: the pixels the caller
    selected (mask), ``weight``: their weights."""
    if not is_concrete(image, weight, camera, used):
        return
    img = np.asarray(image)
    w = np.asarray(weight)
    bad = ~np.isfinite(img)
    used_bad = bad & ((w > 0) if used is None else (np.asarray(used) > 0))
    if used_bad.any():
        n = int(np.any(used_bad, axis=-1).sum())
        first = np.argwhere(np.any(used_bad, axis=-1))[0].tolist()
        raise InvalidValueError(f"image has {n} NaN/inf pixel(s) (first at (row, col) = {first}); "
                                f"exclude them with mask= (and set their values to 0)")
    if not (w > 0).any():
        chosen = (np.ones(img.shape, bool) if used is None else np.asarray(used) > 0)
        hint = (" (the display weights vanish where the image is <= 0, and it is <= 0 on every selected pixel: "
                "is it linear radiance?)" if chosen.any() and np.all(img[chosen] <= 0) else "")
        raise InvalidValueError("the pixel selection is empty: mask/weights exclude every pixel" + hint)
    sea = np.asarray(cam.intersect_sea(camera).mask)
    if geo_mask is not None and is_concrete(geo_mask):
        gm = np.asarray(geo_mask).astype(bool)
        n = int((gm != sea).sum())
        if n:
            raise InvalidValueError(f"geometry.mask disagrees with the camera's sea mask on {n} pixel(s): "
                                    f"was the geometry made with another camera?")
    # the lighting fields the sea shows, and the camera fields (seen through the waves)
    needs_sea = [f for f in fit if f in ("sun_direction", "sun_color", "sea_color", "height", "pitch", "fov")]
    if needs_sea and not (np.any(w > 0, axis=-1) & sea).any():
        raise InvalidValueError(f"no selected pixel sees the sea: cannot fit {needs_sea}")


def tonemap_weights(image, exposure=1.0, mode: str = "bruneton"):
    """Per-pixel residual weights ``(H, W, 3)``: the slope of :func:`jaxocean.shading.tonemap`
    at ``image``. With them, a linear-radiance residual approximates the residual of the
    tone-mapped display values (to first order), so noise added to display values is
    weighted correctly while the fit stays linear in the colours. Saturated pixels get
    (almost) zero weight."""
    image = jnp.asarray(image)
    _, slope = jax.jvp(lambda x: shading.tonemap(x, exposure, mode), (image,), (jnp.ones_like(image),))
    return slope
