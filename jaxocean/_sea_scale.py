"""Radiance relative to the sea's own level: the comparison space of the geometry networks'
inputs and image loss and of the per-pixel inversion.

* ``sea_median(image, mask) -> (C,)``: per-channel median of ``image (H, W, C)`` over the sea
  pixels ``mask (H, W)``; 1 for a channel with no sea pixel or a non-positive median.
* ``compress(image, scale)``: ``log1p(max(I, 0) / scale)``, which keeps sun glints (10^4
  times the sea) from drowning the rest while staying linear near the sea's level and free
  of the exposure.

Elementwise / per image, jittable and vmappable.
"""

from __future__ import annotations

import jax.numpy as jnp

__all__ = ["sea_median", "compress"]


def sea_median(image, mask):
    sea = jnp.where(mask[..., None], image, jnp.nan)
    median = jnp.nanmedian(sea.reshape(-1, image.shape[-1]), axis=0)
    return jnp.where(jnp.isfinite(median) & (median > 0), median, 1.0)


def compress(image, scale):
    return jnp.log1p(jnp.maximum(image, 0.0) / scale)
