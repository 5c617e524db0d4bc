"""Bruneton's Nyquist hierarchy: which waves go to displacement, normal or roughness.

Protocol
--------
``weights(waves, footprint, *, n_min=1.0, n_max=1.5, grid_cell=None) -> WaveWeights``

* ``waves``: :class:`jaxocean.waves.Waves` with leaves ``(N,)`` (validated: finite, omega > 0).
* ``footprint``: pixel footprint on the sea [m], any shape ``(...)`` (a scalar for a regular
  grid, ``(H, W)`` for a perspective image).
* ``n_min``, ``n_max``: finite, ``0 < n_min < n_max`` (else ``ValueError``).
* returns ``WaveWeights(displacement, normal, roughness)``, each ``(..., N)`` in [0, 1].

With lambda_i the wavelength, a wave's weight in the per-pixel normal is
``w_n = smoothstep(n_min, n_max, lambda_i / footprint)``: waves spanning more than ``n_max``
footprints are resolved by the normal, waves shorter than ``n_min`` footprints are
sub-pixel and go to roughness with weight ``1 - w_n``. Displacement uses the same filter with
the geometry grid's cell size (``grid_cell``, default: the footprint itself). The filter is
C1 in lambda and in the footprint, so gradients flow through it to every wave parameter.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp

from jaxocean._roughness import normal_weight
from jaxocean.errors import check_number, check_values
from jaxocean.waves import Waves, validate, wavelength

__all__ = ["WaveWeights", "weights", "all_resolved", "DEFAULT_N_MIN", "DEFAULT_N_MAX"]

DEFAULT_N_MIN = 1.0
DEFAULT_N_MAX = 1.5


class WaveWeights(NamedTuple):
    """Per-wave weights of the three hierarchy levels, each ``(..., N)``."""

    displacement: jnp.ndarray
    normal: jnp.ndarray
    roughness: jnp.ndarray


def weights(waves: Waves, footprint, *, n_min: float = DEFAULT_N_MIN, n_max: float = DEFAULT_N_MAX,
            grid_cell=None) -> WaveWeights:
    """Per-wave displacement / normal / roughness weights for pixels of size ``footprint``."""
    validate(waves, max_steepness=None)  # a NaN omega gave NaN weights, omega = 0 a wave resolved everywhere
    # n_min <= 0 gave every sub-pixel wave, however short, a share of the normal (aliased)
    check_number(n_min, "n_min must be a finite number of footprints > 0", low_open=True)
    if not (n_max > n_min and math.isfinite(n_max)):
        raise ValueError(f"need a finite n_max > n_min; got n_min={n_min}, n_max={n_max}")
    check_values(jnp.asarray(footprint) > 0, "footprint must be > 0 m", footprint)
    if grid_cell is not None:
        check_values(jnp.asarray(grid_cell) > 0, "grid_cell must be > 0 m", grid_cell)
    lam = wavelength(waves)
    w_normal = normal_weight(lam, footprint, n_min, n_max)
    cell = footprint if grid_cell is None else grid_cell
    w_disp = w_normal if grid_cell is None else jnp.broadcast_to(
        normal_weight(lam, cell, n_min, n_max), jnp.broadcast_shapes(jnp.shape(cell), jnp.shape(footprint)) + lam.shape)
    return WaveWeights(displacement=w_disp, normal=w_normal, roughness=1.0 - w_normal)


def all_resolved(waves: Waves) -> WaveWeights:
    """Weights that send every wave to displacement and normal, none to roughness: ``(N,)``."""
    one = jnp.ones_like(waves.amplitude)
    return WaveWeights(displacement=one, normal=one, roughness=jnp.zeros_like(one))
