"""Wave trains: the ``Waves`` pytree, deep-water dispersion and steepness.

Protocol
--------
``Waves(amplitude, omega, theta, phase)`` is a registered pytree (a NamedTuple) whose four
leaves share one shape ``(..., N)``: a trailing wave axis, optional leading batch axes that
come from ``vmap`` or stacking.

* ``amplitude`` h  [m]      >= 0
* ``omega``     w  [rad/s]  > 0
* ``theta``     direction of travel [rad], from +x counter-clockwise
* ``phase``     phi [rad]; the paper's waves have phi = 0

Deep-water dispersion: k = w^2 / g, wave vector k (cos theta, sin theta), wavelength
2 pi / k, steepness k h (<= 1 for a trochoid without loops). ``phase(waves, xy, t)`` is
psi = w t - k.X + phi at rest positions ``xy (..., 2)``; ``fold_determinant(waves, xy, t)``
the trochoid surface's horizontal Jacobian determinant there (<= 0: the sum of waves folds).
"""

from __future__ import annotations

from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxocean.errors import InvalidValueError, check_values, is_concrete

__all__ = [
    "GRAVITY",
    "Waves",
    "make_waves",
    "wavenumber",
    "wave_vector",
    "wavelength",
    "period",
    "steepness",
    "total_steepness",
    "phase",
    "fold_determinant",
    "too_steep",
    "MAX_STEEPNESS",
    "MAX_PHASE_ERROR",
    "check_phase_precision",
    "validate",
    "n_waves",
]

GRAVITY = 9.81  # m/s^2


class Waves(NamedTuple):
    """Component wave trains with a trailing wave axis ``(..., N)``."""

    amplitude: jnp.ndarray
    omega: jnp.ndarray
    theta: jnp.ndarray
    phase: jnp.ndarray


def make_waves(amplitude, omega, theta, phase=None, dtype=None) -> Waves:
    """Build ``Waves`` from array-likes, broadcasting ``phase`` (default 0) and validating.

    ``dtype`` defaults to that of ``amplitude``, promoted to the default float type when it
    is not floating (so that integers such as ``make_waves([1], [2], [0])`` are accepted)."""
    amplitude = jnp.asarray(amplitude, dtype)
    if dtype is None and not jnp.issubdtype(amplitude.dtype, jnp.floating):
        amplitude = amplitude.astype(jnp.result_type(float))
    dtype = amplitude.dtype if dtype is None else dtype
    omega = jnp.asarray(omega, dtype)
    theta = jnp.asarray(theta, dtype)
    phase = jnp.zeros_like(omega) if phase is None else jnp.asarray(phase, dtype)
    if phase.ndim == 0:  # one phase for every wave
        phase = jnp.broadcast_to(phase, omega.shape)
    waves = Waves(amplitude, omega, theta, phase)
    validate(waves)
    return waves


def n_waves(waves: Waves) -> int:
    return waves.omega.shape[-1]


#: the steepest trochoid: beyond k h = 1 the crest loops and the surface folds over itself
MAX_STEEPNESS = 1.0


def too_steep(waves: Waves, max_steepness: float = MAX_STEEPNESS) -> np.ndarray:
    """bool ``(..., N)`` (NumPy, eager): waves with ``k h > max_steepness``, up to a relative
    1e-5 so that waves clamped to the limit in float32 pass."""
    # NumPy, not jnp: inside a trace even concrete inputs would become tracers
    kh = np.asarray(waves.omega) ** 2 / GRAVITY * np.asarray(waves.amplitude)
    return kh > max_steepness * (1 + 1e-5)


def validate(waves: Waves, *, max_steepness: float | None = MAX_STEEPNESS) -> Waves:
    """Check structure (always) and values (when concrete). Returns ``waves`` unchanged.

    Structure: four leaves of one shape with at least one axis, floating dtype -> ``ValueError``.
    Values: h >= 0, w > 0, everything finite, k h <= ``max_steepness`` (None skips it) ->
    :class:`jaxocean.errors.InvalidValueError`.
    """
    if not isinstance(waves, Waves):
        raise ValueError(f"expected a jaxocean.Waves, got {type(waves).__name__}")
    shapes = {name: jnp.shape(leaf) for name, leaf in zip(Waves._fields, waves)}
    if len(set(shapes.values())) != 1:
        raise ValueError(f"Waves leaves must share one shape (..., N); got {shapes}")
    if len(shapes["omega"]) == 0:
        raise ValueError("Waves leaves need a trailing wave axis (N,); got scalars")
    for name, leaf in zip(Waves._fields, waves):
        if not jnp.issubdtype(jnp.result_type(leaf), jnp.floating):
            raise ValueError(f"Waves.{name} must be floating point; got {jnp.result_type(leaf)}")
    if not is_concrete(waves):
        return waves
    for name, leaf in zip(Waves._fields, waves):
        check_values(np.isfinite(leaf), f"Waves.{name} must be finite", leaf)
    check_values(np.asarray(waves.amplitude) >= 0, "Waves.amplitude must be >= 0 m", waves.amplitude)
    check_values(np.asarray(waves.omega) > 0, "Waves.omega must be > 0 rad/s", waves.omega)
    if max_steepness is not None:
        check_values(~too_steep(waves, max_steepness),
                     f"wave steepness k*h must be <= {max_steepness} (no looping trochoid crests)",
                     np.asarray(waves.omega) ** 2 / GRAVITY * np.asarray(waves.amplitude))
    return waves


def wavenumber(waves_or_omega):
    """Deep-water wavenumber k = w^2 / g [rad/m] (a formula, even in w: the domain w > 0 of
    a wave is checked where waves are made, :func:`make_waves` and :func:`validate`)."""
    omega = waves_or_omega.omega if isinstance(waves_or_omega, Waves) else waves_or_omega
    return omega * omega / GRAVITY


def wave_vector(waves: Waves):
    """Wave vectors ``(..., N, 2)`` = k (cos theta, sin theta) [rad/m]."""
    k = wavenumber(waves)
    return jnp.stack([k * jnp.cos(waves.theta), k * jnp.sin(waves.theta)], axis=-1)


def wavelength(waves_or_omega):
    """Wavelength 2 pi / k [m]."""
    return 2 * jnp.pi / wavenumber(waves_or_omega)


def period(waves_or_omega):
    omega = waves_or_omega.omega if isinstance(waves_or_omega, Waves) else waves_or_omega
    return 2 * jnp.pi / omega


def steepness(waves: Waves):
    """Per-wave steepness k h (dimensionless), shape ``(..., N)``."""
    return wavenumber(waves) * waves.amplitude


def total_steepness(waves: Waves):
    """Sum of k h over the wave axis: a trochoid sea can fold where this exceeds 1."""
    return jnp.sum(steepness(waves), axis=-1)


def phase(waves: Waves, xy, t):
    """psi = w t - k.X + phi, shape ``(..., N)`` for rest positions ``xy (..., 2)`` [m]."""
    k = wavenumber(waves)
    kvec = jnp.stack([k * jnp.cos(waves.theta), k * jnp.sin(waves.theta)], axis=0)  # (2, N): X.k as one dot
    return waves.omega * t + waves.phase - jnp.dot(xy, kvec)


def fold_determinant(waves: Waves, xy, t):
    """Determinant ``(...)`` of the trochoid surface's horizontal Jacobian d(p_x, p_y)/d(x, y)
    at rest positions ``xy (..., 2)``: ``(1 - A_xx)(1 - A_yy) - A_xy^2`` with
    ``A = sum h k cos(psi) k^ k^T`` (the vertical component of the unnormalised normal of
    :func:`jaxocean.surface.normal`). 1 on a flat sea; <= 0 where the surface folds over itself
    (neighbouring water particles cross). Its worst case over all phases is
    ``1 - total_steepness``; its minimum over rest positions and times is how close a sea
    comes to folding."""
    hk_cos = steepness(waves) * jnp.cos(phase(waves, xy, t))  # (..., N)
    c, s = jnp.cos(waves.theta), jnp.sin(waves.theta)
    a_xx, a_xy, a_yy = jnp.dot(hk_cos, c * c), jnp.dot(hk_cos, c * s), jnp.dot(hk_cos, s * s)
    return (1.0 - a_xx) * (1.0 - a_yy) - a_xy * a_xy


#: the largest rounding error [rad] of the phases ``omega t`` that rendering and forecasts accept
MAX_PHASE_ERROR = 0.1


def check_phase_precision(waves: Waves, dt) -> None:
    """InvalidValueError when concrete times ``dt`` [s] (broadcast against the wave axis, as
    in :func:`jaxocean.forecast.advance`) are so far from ``t = 0`` that the phases
    ``omega dt`` of the waves with an amplitude, in their dtype, are rounded by more than
    :data:`MAX_PHASE_ERROR` (about ``|omega dt| eps``; float32 beyond ``|omega dt|`` ~ 8e5
    rad, e.g. ``dt`` = 1.6e5 s at 5 rad/s): the frames would show the waves at wrong phases.
    Rendering, re-editing and forecasting call it where their times are concrete."""
    if not is_concrete(waves, dt):
        return
    dtype = np.dtype(jnp.result_type(waves.omega))
    omega_t = np.abs(np.asarray(waves.omega, np.float64) * np.asarray(dt, np.float64))
    omega_t = np.where(np.asarray(waves.amplitude) != 0, omega_t, 0.0)
    if omega_t.size == 0 or not np.all(np.isfinite(omega_t)):
        return
    error = float(np.max(omega_t) * np.finfo(dtype).eps)
    if error > MAX_PHASE_ERROR:
        raise InvalidValueError(
            f"times up to |t| = {np.max(np.abs(np.asarray(dt))):.4g} s are too far from t = 0 for {dtype.name} "
            f"phases: omega t (up to {np.max(omega_t):.4g} rad) is rounded by up to {error:.2g} rad there, so the "
            f"waves would be drawn at wrong phases; use times nearer t = 0, or enable jax_enable_x64")
