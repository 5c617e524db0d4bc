"""The trochoid (Gerstner) sea surface: displacement, analytic normals, slope variance.

Protocol
--------
Waves have leaves ``(N,)`` (batch them with ``jax.vmap``). Positions ``xy`` are rest
(Lagrangian) positions X on the mean sea plane, shape ``(..., 2)`` [m]; ``t`` a scalar [s].
Per wave, with k = w^2/g, k^ = (cos theta, sin theta) and phase psi = w t - k k^.X + phi
(paper eq. 1):

    p(X, t) = X + sum_i h_i (cos theta_i sin psi_i, sin theta_i sin psi_i, cos psi_i)

* ``displacement(waves, xy, t, weights=None) -> (..., 3)``: p - (X, 0).
* ``normal(waves, xy, t, weights=None) -> (..., 3)``: unit normal, the normalised cross
  product of the Jacobian columns dp/dx and dp/dy (exact, not a finite difference).
* ``slope_variance(waves, weights=None) -> (sigma_x^2, sigma_y^2)`` of the waves the weights
  send to roughness: sigma_x^2 = sum cos^2 theta (1 - sqrt(1 - k^2 h^2)).
* ``on_grid(waves, x (W,), y (H,), times (T,), weights=None) -> GridSurface``: the same on a
  regular grid (row i at y[i], column j at x[j]) by the separable rank-N product.

``weights`` is a per-wave factor ``(..., N)`` broadcast against the points (a
:class:`jaxocean.hierarchy.WaveWeights` picks the level each function uses), so the
hierarchy's smooth filter multiplies each wave's contribution.

Every sum over waves is a matrix product: the Jacobian needs five sums
(A_xx, A_xy, A_yy of cos psi; B_x, B_y of sin psi) and the displacement three.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxocean._math import materialize, safe_normalize, safe_sqrt
from jaxocean.hierarchy import WaveWeights
from jaxocean.waves import Waves, validate, wavenumber

__all__ = [
    "displacement",
    "normal",
    "surface_point",
    "slope_variance",
    "on_grid",
    "on_rows",
    "GridSurface",
    "phase",
    "normal_from_sums",
]


def _level(weights, level: str):
    """The weight array of one hierarchy level, or the plain array the caller gave."""
    if weights is None:
        return None
    if isinstance(weights, WaveWeights):
        return getattr(weights, level)
    return jnp.asarray(weights)


def _check(waves: Waves, xy=None):
    validate(waves)
    if waves.omega.ndim != 1:
        raise ValueError(f"surface functions take Waves with leaves (N,); got {waves.omega.shape} "
                         "(use jax.vmap for batches of seas)")
    if xy is not None and jnp.shape(xy)[-1:] != (2,):
        raise ValueError(f"xy must have a trailing axis of size 2; got shape {jnp.shape(xy)}")


def phase(waves: Waves, xy, t):
    """psi = w t - k.X + phi, shape ``(..., N)`` for ``xy (..., 2)``."""
    k = wavenumber(waves)
    kx, ky = k * jnp.cos(waves.theta), k * jnp.sin(waves.theta)
    kvec = jnp.stack([kx, ky], axis=0)  # (2, N): X.k as one dot
    return waves.omega * t + waves.phase - jnp.dot(xy, kvec)


def _displacement_coeffs(waves: Waves):
    h, c, s = waves.amplitude, jnp.cos(waves.theta), jnp.sin(waves.theta)
    return jnp.stack([h * c, h * s], axis=-1), h[:, None]  # sin-coeffs (N, 2), cos-coeffs (N, 1)


def _normal_coeffs(waves: Waves):
    hk = waves.amplitude * wavenumber(waves)
    c, s = jnp.cos(waves.theta), jnp.sin(waves.theta)
    cos_coeffs = jnp.stack([hk * c * c, hk * c * s, hk * s * s], axis=-1)  # A_xx, A_xy, A_yy
    sin_coeffs = jnp.stack([hk * c, hk * s], axis=-1)  # B_x, B_y
    return sin_coeffs, cos_coeffs


def _weighted_trig(waves, xy, t, w):
    psi = phase(waves, xy, t)
    cos_psi, sin_psi = jnp.cos(psi), jnp.sin(psi)
    if w is not None:
        cos_psi, sin_psi = cos_psi * w, sin_psi * w
    return materialize(cos_psi, sin_psi)  # each sine once, not once per reduced channel


def _displacement_from_sums(sin_sums, cos_sums):
    return jnp.concatenate([sin_sums, cos_sums], axis=-1)


def normal_from_sums(a_xx, a_xy, a_yy, b_x, b_y):
    """Unit normal from the five wave sums of the Jacobian.

    dp/dx = (1 - A_xx, -A_xy, B_x), dp/dy = (-A_xy, 1 - A_yy, B_y); n = dp/dx x dp/dy.
    At a trochoid cusp (k h = 1 at a crest) the cross product vanishes and the normal falls
    back to +z with finite gradients.
    """
    n = jnp.stack([
        -a_xy * b_y - b_x * (1.0 - a_yy),
        -b_x * a_xy - (1.0 - a_xx) * b_y,
        (1.0 - a_xx) * (1.0 - a_yy) - a_xy * a_xy,
    ], axis=-1)
    return safe_normalize(n)


def displacement(waves: Waves, xy, t, weights=None):
    """Trochoid displacement p(X, t) - (X, 0) at rest positions ``xy (..., 2)`` -> ``(..., 3)``."""
    _check(waves, xy)
    cos_psi, sin_psi = _weighted_trig(waves, xy, t, _level(weights, "displacement"))
    sin_coeffs, cos_coeffs = _displacement_coeffs(waves)
    return _displacement_from_sums(jnp.dot(sin_psi, sin_coeffs), jnp.dot(cos_psi, cos_coeffs))


def surface_point(waves: Waves, xy, t, weights=None):
    """World position p(X, t) ``(..., 3)`` of the rest position ``xy``."""
    d = displacement(waves, xy, t, weights)
    return d + jnp.concatenate([xy, jnp.zeros_like(xy[..., :1])], axis=-1)


def normal(waves: Waves, xy, t, weights=None):
    """Unit surface normal ``(..., 3)`` at rest positions ``xy (..., 2)``."""
    _check(waves, xy)
    cos_psi, sin_psi = _weighted_trig(waves, xy, t, _level(weights, "normal"))
    sin_coeffs, cos_coeffs = _normal_coeffs(waves)
    a = jnp.dot(cos_psi, cos_coeffs)
    b = jnp.dot(sin_psi, sin_coeffs)
    return normal_from_sums(a[..., 0], a[..., 1], a[..., 2], b[..., 0], b[..., 1])


def slope_variance(waves: Waves, weights=None):
    """Slope variance ``(sigma_x^2, sigma_y^2)`` of the waves weighted into roughness.

    Per wave 1 - sqrt(1 - k^2 h^2), written as k^2 h^2 / (1 + sqrt(1 - k^2 h^2)) to avoid
    cancellation for gentle waves; finite (value and gradient) up to k h = 1.
    ``weights (..., N)`` gives ``(...)`` maps; ``None`` means every wave is sub-pixel.
    Not clamped: the renderer applies the minimum roughness.
    """
    _check(waves)
    kh2 = (waves.amplitude * wavenumber(waves)) ** 2
    per_wave = kh2 / (1.0 + safe_sqrt(1.0 - kh2))
    w = _level(weights, "roughness")
    if w is not None:
        per_wave = per_wave * w
    c2 = jnp.cos(waves.theta) ** 2
    return jnp.sum(per_wave * c2, axis=-1), jnp.sum(per_wave * (1.0 - c2), axis=-1)


class GridSurface(NamedTuple):
    """Surface on a regular grid: displacement and normal ``(T, H, W, 3)``; slope variance
    ``(T, H, W, 2)`` of the roughness-level waves (uniform over a regular grid)."""

    displacement: jnp.ndarray
    normal: jnp.ndarray
    slope_variance: jnp.ndarray

    @property
    def roughness(self):
        """Scalar roughness map sigma^2 = sigma_x^2 + sigma_y^2, ``(T, H, W)``."""
        return jnp.sum(self.slope_variance, axis=-1)


def _channel_coeffs(waves: Waves, weights):
    """Coefficients of the eight wave sums, weighted per level: (cos (..., 4, N), sin (..., 4, N)).

    cos channels: A_xx, A_xy, A_yy, d_z; sin channels: B_x, B_y, d_x, d_y. Weight arrays
    ``(..., N)`` give per-row (or per-grid) coefficients with the same leading axes.
    """
    disp_sin, disp_cos = _displacement_coeffs(waves)
    norm_sin, norm_cos = _normal_coeffs(waves)
    w_disp, w_norm = _level(weights, "displacement"), _level(weights, "normal")
    if w_disp is not None:
        disp_sin, disp_cos = disp_sin * w_disp[..., None], disp_cos * w_disp[..., None]
    if w_norm is not None:
        norm_sin, norm_cos = norm_sin * w_norm[..., None], norm_cos * w_norm[..., None]
    lead = jnp.broadcast_shapes(norm_cos.shape[:-1], disp_cos.shape[:-1])  # (..., N)

    def join(a, b):
        return jnp.concatenate([jnp.broadcast_to(a, lead + a.shape[-1:]), jnp.broadcast_to(b, lead + b.shape[-1:])], -1)

    cos_coeffs, sin_coeffs = join(norm_cos, disp_cos), join(norm_sin, disp_sin)
    # computed once, not inside every element of the wave-sum factors (see materialize)
    return materialize(jnp.swapaxes(cos_coeffs, -1, -2), jnp.swapaxes(sin_coeffs, -1, -2))


def _separable_lhs(cos_coeffs, sin_coeffs, cos_a, sin_a):
    """Left factor ``(..., 8, 2N)`` of the separable product for phases psi = a + b.

    [C cos a, -C sin a] @ [cos b; sin b] = sum C cos psi and [C sin a, C cos a] @ [cos b; sin b]
    = sum C sin psi, so one right factor [cos b; sin b] ``(2N, ...)`` serves all channels.
    ``cos_a``/``sin_a`` are ``(..., N)``; coefficients broadcast against them.
    """
    cos_a, sin_a = materialize(cos_a, sin_a)  # sines once, not 8x (see materialize)
    ca, sa = cos_a[..., None, :], sin_a[..., None, :]
    lhs_cos = jnp.concatenate([cos_coeffs * ca, -cos_coeffs * sa], -1)
    lhs_sin = jnp.concatenate([sin_coeffs * sa, sin_coeffs * ca], -1)
    return jnp.concatenate([lhs_cos, lhs_sin], axis=-2)


def _surface_from_sums(sums):
    """Displacement and normal ``(..., 3)`` from the channel-major sums ``(8, ...)``."""
    a_xx, a_xy, a_yy, d_z, b_x, b_y, d_x, d_y = sums
    return jnp.stack([d_x, d_y, d_z], axis=-1), normal_from_sums(a_xx, a_xy, a_yy, b_x, b_y)


def _check_weight_shape(weights, shape, fn: str):
    for level in ("displacement", "normal"):
        w = _level(weights, level)
        if w is not None and jnp.shape(w) != shape:
            raise ValueError(f"{fn} needs {level} weights of shape {shape}; got {jnp.shape(w)}")


def on_grid(waves: Waves, x, y, times, weights=None) -> GridSurface:
    """Displacement, normal and slope variance on the grid ``y (H,) x x (W,)`` at ``times (T,)``.

    Separable rank-N product: with a = w t + phi - k_y y (per t, row, wave) and b = -k_x x
    (per column, wave), all eight wave sums are ONE matrix product of ``(T*H*8, 2N)`` by
    ``(2N, W)`` -- no per-pixel sin/cos. ``weights`` must be per-wave ``(N,)`` (a regular
    grid has one footprint).
    """
    _check(waves)
    x, y, times = jnp.asarray(x), jnp.asarray(y), jnp.atleast_1d(jnp.asarray(times))
    if x.ndim != 1 or y.ndim != 1 or times.ndim != 1:
        raise ValueError(f"x, y, times must be 1-D; got shapes {x.shape}, {y.shape}, {times.shape}")
    n = waves.omega.shape[-1]
    _check_weight_shape(weights, (n,), "on_grid (per-wave)")

    k = wavenumber(waves)
    kx, ky = k * jnp.cos(waves.theta), k * jnp.sin(waves.theta)
    a = (waves.omega * times[:, None] + waves.phase)[:, None, :] - y[None, :, None] * ky  # (T, H, N)
    b = -x[:, None] * kx  # (W, N)
    rhs = jnp.concatenate([jnp.cos(b), jnp.sin(b)], axis=-1).T  # (2N, W)
    lhs = _separable_lhs(*_channel_coeffs(waves, weights), jnp.cos(a), jnp.sin(a))  # (T, H, 8, 2N)
    # keep the matmul's natural (T, H, 8, W) layout: a channel-major output costs a transpose
    # that was measured 5x slower than the product itself
    sums = jnp.einsum("thcm,mw->thcw", lhs, rhs)
    disp, nrm = _surface_from_sums(sums[:, :, c] for c in range(8))
    sx2, sy2 = slope_variance(waves, _level(weights, "roughness") if weights is not None
                              else jnp.zeros_like(waves.amplitude))
    slope_var = jnp.broadcast_to(jnp.stack([sx2, sy2]), disp.shape[:-1] + (2,))
    return GridSurface(displacement=disp, normal=nrm, slope_variance=slope_var)


def _power_table(start, angle, count: int):
    """(cos, sin) of start_phase + m * angle for m = 0 .. count-1, stacked on axis -2.

    ``start`` is the pair (cos, sin) of the start phase, ``angle`` ``(..., N)``. Built by
    doubling -- the table so far, rotated by 2^level * angle, is appended -- so only the two
    sines of ``angle`` are evaluated and there is no sequential loop; rounding grows with
    log2(count) (<= 1e-6 in float32 for the sizes used here).
    """
    step_cos, step_sin = materialize(jnp.cos(angle), jnp.sin(angle))
    table_cos, table_sin = start[0][..., None, :], start[1][..., None, :]
    while table_cos.shape[-2] < count:
        rot_cos, rot_sin = step_cos[..., None, :], step_sin[..., None, :]
        table_cos, table_sin = (jnp.concatenate([table_cos, table_cos * rot_cos - table_sin * rot_sin], -2),
                                jnp.concatenate([table_sin, table_sin * rot_cos + table_cos * rot_sin], -2))
        step_cos, step_sin = step_cos * step_cos - step_sin * step_sin, 2.0 * step_sin * step_cos
    # the finished table is read by every channel of the product: computed once (materialize)
    return materialize(table_cos[..., :count, :], table_sin[..., :count, :])


def on_rows(waves: Waves, origin, step, n_cols: int, t, weights=None, *, block: int | None = None) -> GridSurface:
    """The surface at points that are evenly spaced along each row: X = origin[r] + j * step[r].

    ``origin``, ``step``: ``(R, 2)`` [m]; ``n_cols`` static; ``t`` scalar. Per-row weights
    ``(R, N)`` (a :class:`WaveWeights` with per-row arrays). Returns a ``GridSurface`` with
    ``(R, n_cols, ...)`` arrays (no time axis).

    This is the geometry of a pinhole camera without roll looking at the sea plane: along an
    image row the hit points are affine in the column and the footprint is constant. The
    phase is psi = alpha_r + j beta_r; splitting j = B a + b (B ~ 2 sqrt(n_cols)) gives
    e^{i psi} = e^{i(alpha + B a beta)} e^{i b beta}, so per row the eight wave sums are a
    product of ``(8 A, 2N)`` by ``(2N, B)`` and only R (A + B) N sines are evaluated.
    """
    _check(waves)
    origin, step = jnp.asarray(origin), jnp.asarray(step)
    if origin.ndim != 2 or origin.shape[-1] != 2 or step.shape != origin.shape:
        raise ValueError(f"origin and step must both be (R, 2); got {origin.shape} and {step.shape}")
    rows, n = origin.shape[0], waves.omega.shape[-1]
    _check_weight_shape(weights, (rows, n), "on_rows (per-row)")
    # B ~ 2 sqrt(W): the (R, W/B, 8, 2N) factor is built elementwise (memory-bound) and the
    # (R, B, 2N) tables feed per-row GEMMs; this balance measured fastest at W = 128..256
    block = max(1, min(n_cols, int(round(2 * n_cols ** 0.5)))) if block is None else int(block)
    n_blocks = -(-n_cols // block)

    kvec = jnp.stack([wavenumber(waves) * jnp.cos(waves.theta), wavenumber(waves) * jnp.sin(waves.theta)])
    alpha = waves.omega * t + waves.phase - jnp.dot(origin, kvec)  # (R, N)
    beta = -jnp.dot(step, kvec)  # (R, N)
    # e^{i(alpha + B a beta)} and e^{i b beta} as power tables: 3 R N sines instead of
    # R (A + B) N
    coarse_cos, coarse_sin = _power_table((jnp.cos(alpha), jnp.sin(alpha)), block * beta, n_blocks)  # (R, A, N)
    one = jnp.ones_like(beta)
    fine_cos, fine_sin = _power_table((one, jnp.zeros_like(beta)), beta, block)  # (R, B, N)
    cos_coeffs, sin_coeffs = _channel_coeffs(waves, weights)  # (R, 4, N) or (4, N)
    if cos_coeffs.ndim == 3:
        cos_coeffs, sin_coeffs = cos_coeffs[:, None], sin_coeffs[:, None]  # broadcast over blocks
    lhs = _separable_lhs(cos_coeffs, sin_coeffs, coarse_cos, coarse_sin)  # (R, A, 8, 2N)
    rhs = jnp.concatenate([fine_cos, fine_sin], axis=-1)  # (R, B, 2N)
    sums = jnp.einsum("racm,rbm->racb", lhs, rhs)  # (R, A, 8, B)
    disp, nrm = _surface_from_sums(sums[:, :, c].reshape(rows, n_blocks * block)[:, :n_cols] for c in range(8))
    sx2, sy2 = slope_variance(waves, _level(weights, "roughness") if weights is not None
                              else jnp.zeros_like(waves.amplitude))
    slope_var = jnp.broadcast_to(jnp.stack([sx2, sy2], -1)[..., None, :], disp.shape[:-1] + (2,))
    return GridSurface(displacement=disp, normal=nrm, slope_variance=slope_var)
