"""Sub-pixel roughness of waves: the Nyquist filter and each wave's slope variance.

Used by :mod:`jaxocean.hierarchy` (the filter), :mod:`jaxocean.surface` (slope variance),
and the fits that model roughness per image row (:mod:`jaxocean.fit.waves`,
:mod:`jaxocean.fit.spectrum`). Public within the package; not part of the user API.

Protocol
--------
Pure ``jax.numpy`` functions, float32 or float64, finite in value and gradient over their
whole input range. Wave quantities are ``(N,)`` (or ``(..., N)``); a footprint is any shape
``(...)`` [m] and broadcasts against a trailing wave axis.

* ``normal_weight(wavelength (N,), footprint (...), n_min, n_max) -> (..., N)``:
  Bruneton's filter ``w_n = smoothstep(n_min, n_max, lambda / footprint)``, a wave's weight in
  the per-pixel normal; its weight in the roughness is ``1 - w_n``.
* ``wave_slope_variance(kh2) -> same shape``: the slope variance one trochoid wave of
  steepness ``k h`` (given as ``kh2 = (k h)^2``) adds when it is sub-pixel,
  ``1 - sqrt(1 - k^2 h^2)``, written as ``k^2 h^2 / (1 + sqrt(1 - k^2 h^2))`` to avoid
  cancellation for gentle waves. Beyond ``kh2 = 1`` (a looping crest, outside the model)
  it continues as ``kh2``: finite, with a gradient that leads a fit back.
* ``row_roughness(wavenumber (N,), amplitude (N,), footprint (...), n_min, n_max) -> (...)``:
  the scalar roughness sigma^2 = sigma_x^2 + sigma_y^2 of the waves the filter sends to
  roughness at each footprint (a camera's image rows, say), without the renderer's floor
  ``shading.MIN_SLOPE_VARIANCE``. This equals the sum of the pair
  :func:`jaxocean.surface.slope_variance` returns for the roughness weights of
  :func:`jaxocean.hierarchy.weights`.
* ``observed_rows(roughness (T, H, W) or (H, W), mask (H, W)) -> (row_mean (H,), rows (H,))``:
  host-side (NumPy) mean observed roughness of each image row over its sea pixels and frames
  (NaN ignored; 0 where a row has no sea pixel), and which rows have sea pixels: the data
  the per-row roughness fits compare :func:`row_roughness` with.
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from jaxocean._math import safe_sqrt, smoothstep

__all__ = ["normal_weight", "wave_slope_variance", "row_roughness", "observed_rows"]


def normal_weight(wavelength, footprint, n_min, n_max):
    """Weight ``(..., N)`` of each wave in the per-pixel normal at each footprint ``(...)``
    [m]: ``smoothstep(n_min, n_max, wavelength / footprint)``, C1 in both."""
    return smoothstep(n_min, n_max, jnp.asarray(wavelength) / jnp.asarray(footprint)[..., None])


def wave_slope_variance(kh2):
    """Sub-pixel slope variance ``1 - sqrt(1 - kh2)`` of waves with ``kh2 = (k h)^2``."""
    return kh2 / (1.0 + safe_sqrt(1.0 - kh2))


def row_roughness(wavenumber, amplitude, footprint, n_min, n_max):
    """Roughness sigma^2 ``(...)`` of the sub-pixel waves at each footprint ``(...)`` [m]
    (no floor): ``sum_i (1 - w_n,i) (1 - sqrt(1 - k_i^2 h_i^2))``."""
    k = jnp.asarray(wavenumber)
    weight = 1.0 - normal_weight(2.0 * jnp.pi / k, footprint, n_min, n_max)
    return jnp.sum(weight * wave_slope_variance((amplitude * k) ** 2), axis=-1)


def observed_rows(roughness, mask):
    """Mean observed roughness per image row ``(H,)`` over the row's sea pixels (``mask (H,
    W)``) and every frame of ``roughness (T, H, W)`` or ``(H, W)``, NaN ignored, 0 on rows
    without sea; and the bool ``(H,)`` of rows with sea. NumPy (host side)."""
    r = np.asarray(roughness, np.float64)
    r = r[None] if r.ndim == 2 else r
    mask = np.asarray(mask, bool)
    rows = mask.any(1)
    vals = np.where(mask[None], r, np.nan)
    count = np.sum(np.isfinite(vals), axis=(0, 2))
    mean = np.nansum(vals, axis=(0, 2)) / np.maximum(count, 1)
    return np.where(rows & (count > 0), mean, 0.0), rows
