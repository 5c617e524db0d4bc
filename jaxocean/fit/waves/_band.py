"""The long-wave band of the wave fit: the part of the sea the view cannot separate into waves.

Waves longer than the view (less than one cycle across the sea pixels along their
direction) are not individually identifiable: over the window they are a smooth, slowly
moving slope field, and a free wave fit explains that field with dozens of spurious waves.
:func:`waves` therefore models it explicitly, as a fixed *band* of ``B`` nuisance waves on a
polar grid of wave vectors -- ``n_wavelengths`` wavelengths spaced geometrically from
``shortest x`` to ``longest x`` the view's diameter ``D`` (the diagonal of the sea pixels'
ground bounding box) and ``n_directions`` directions -- each with its frequency on the
dispersion shell ``omega^2 = g k``. Only their ``(a, b) = h (cos phi, sin phi)`` are free:
they are fitted jointly with the resolved waves by the same structured Levenberg-Marquardt,
through the renderer's own model, with ``omega`` and ``theta`` held. At the short end
neighbouring band wave vectors are about half a Rayleigh cell (``2 pi / D``) apart in
wavenumber and 0.75 of one in direction, so the band spans the smooth fields the window
cannot resolve, and nothing finer.

Measured (``experiments/WAVES.md``): on Table 2 dataset scenes the long true waves (15-22
of 60, 18-350 m) leave a mean normal residual of 1.4e-3 to 2.6e-2 rad; the slope field of
a per-frame quadratic elevation (5 coefficients a frame, 50 for 10 frames) removes at best
a factor 3 of it, a band of 4 x 12 wave vectors (96 coefficients for the whole sequence) a
factor 10-60 in a linear least-squares probe. The default band has 6 rings (144
coefficients): with 4, rings 2.25x apart in wavelength, a Table 2 scene's stalled selection
kept adding waves 0.8-1.6 view diameters long, between the first two rings, up to the
96-wave cap; with 6 it stopped by its criterion at 79 waves, within its error bound.

Protocol: :func:`view_diameter` gives a camera's view diameter ``D``; :func:`band_waves`
builds the band ``Waves (B,)`` (zero amplitude) for it; :func:`summary` turns fitted band
waves into a :class:`LongWaveBand` (what the band absorbed).
Lengths in metres, angles in radians, frequencies in rad/s.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean.waves import GRAVITY, Waves

N_WAVELENGTHS = 6
N_DIRECTIONS = 12
SHORTEST = 0.7  # the band's shortest wavelength, in view diameters
LONGEST = 8.0  # its longest


class LongWaveBand(NamedTuple):
    """What the long-wave nuisance band of :func:`jaxocean.fit.waves.waves` absorbed.

    * ``waves``          the fitted band ``Waves (B,)`` (fixed omega, theta; fitted h, phi):
      stand-ins for the sea the view cannot separate, not measured waves.
    * ``slope_variance`` mean over sea pixel-frames of the squared horizontal normal
      component of the band alone [rad^2] (about the slope variance it explains).
    * ``frame_slope``    ``(T, 2)`` the band's mean normal-slope ``(s_x, s_y)`` per frame
      (its tilt of the patch) [rad].
    * ``diameter``       the view diameter ``D`` [m] the band's wavelengths are scaled by.
    """

    waves: Waves
    slope_variance: jax.Array
    frame_slope: jax.Array
    diameter: jax.Array


def view_diameter(camera) -> float:
    """Diagonal [m] of the ground bounding box of the camera's sea pixels (eager)."""
    hit = cam.intersect_sea(camera)
    xy = np.asarray(hit.xy, np.float64)[np.asarray(hit.mask)]
    if xy.shape[0] == 0:
        return 1.0
    return float(max(np.hypot(*np.ptp(xy, axis=0)), 1e-6))


def band_waves(diameter: float, dtype, *, n_wavelengths: int = N_WAVELENGTHS, n_directions: int = N_DIRECTIONS,
               shortest: float = SHORTEST, longest: float = LONGEST) -> Waves:
    """The band's ``n_wavelengths x n_directions`` waves (zero amplitude) for a view of
    ``diameter`` [m] (:func:`view_diameter`)."""
    lam = np.geomspace(shortest * diameter, longest * diameter, n_wavelengths)
    om = np.sqrt(GRAVITY * 2 * math.pi / lam)
    th = np.linspace(-math.pi, math.pi, n_directions, endpoint=False) + math.pi / n_directions
    O, Th = np.meshgrid(om, th, indexing="ij")
    zero = jnp.zeros(O.size, dtype)
    return Waves(zero, jnp.asarray(O.ravel(), dtype), jnp.asarray(Th.ravel(), dtype), zero)


def summary(band: Waves, normals_of_band, weight, diameter: float) -> LongWaveBand:
    """:class:`LongWaveBand` of fitted band waves; ``normals_of_band (T, H, W, 3)`` are the
    band's own normals (the forward model of ``band`` alone), ``weight (T, H, W)`` the valid
    sea pixel-frames, ``diameter`` [m] the view diameter the band was built for."""
    nxy = normals_of_band[..., :2]
    wsum = jnp.maximum(jnp.sum(weight, axis=(1, 2)), 1.0)  # (T,)
    var = jnp.sum(jnp.sum(nxy * nxy, -1) * weight) / jnp.maximum(jnp.sum(weight), 1.0)
    tilt = jnp.sum(nxy * weight[..., None], axis=(1, 2)) / wsum[:, None]
    return LongWaveBand(band, var, tilt, jnp.asarray(diameter, nxy.dtype))
