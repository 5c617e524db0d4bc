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
* ``fold_determinant(waves, xy, t) -> (...)``: det of the horizontal Jacobian
  d(p_x, p_y)/d(x, y); the surface folds over (overhangs) where it is <= 0 (defined in
  :mod:`jaxocean.waves`, with ``phase``, and re-exported here).
* ``slope_variance(waves, weights=None) -> (sigma_x^2, sigma_y^2)`` of the waves the weights
  send to roughness: sigma_x^2 = sum cos^2 theta (1 - sqrt(1 - k^2 h^2)).
* ``on_grid(waves, x (W,), y (H,), times (T,), weights=None) -> GridSurface``: the same on a
  regular grid (row i at y[i], column j at x[j]) by the separable rank-N product, with a
  hand-written linear tangent rule so that gradients (either mode) cost a few more products.
* ``on_rows(waves, origin (R, 2), step (R, 2), n_cols, t, weights=None) -> GridSurface``: points
  evenly spaced along each row (a camera's sea hits), per-row weights; same kind of rule.

``weights`` is a per-wave factor ``(..., N)`` broadcast against the points (a
:class:`jaxocean.hierarchy.WaveWeights` picks the level each function uses), so the
hierarchy's smooth filter multiplies each wave's contribution.

Every sum over waves is a matrix product: the Jacobian needs five sums
(A_xx, A_xy, A_yy of cos psi; B_x, B_y of sin psi) and the displacement three.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean._math import inv_sqrt, materialize, safe_normalize, sincos, tiny
from jaxocean._roughness import wave_slope_variance
from jaxocean.hierarchy import WaveWeights
from jaxocean.waves import Waves, fold_determinant, phase, validate, wavenumber  # re-exported

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
    "fold_determinant",
]


def _level(weights, level: str):
    """The weight array of one hierarchy level, or the plain array the caller gave."""
    if weights is None:
        return None
    if isinstance(weights, WaveWeights):
        return getattr(weights, level)
    return jnp.asarray(weights)


def _check(waves: Waves, xy=None, t=None, weights=None, level: str | None = None):
    validate(waves)
    if waves.omega.ndim != 1:
        raise ValueError(f"surface functions take Waves with leaves (N,); got {waves.omega.shape} "
                         "(use jax.vmap for batches of seas)")
    if xy is not None and jnp.shape(xy)[-1:] != (2,):
        raise ValueError(f"xy must have a trailing axis of size 2; got shape {jnp.shape(xy)}")
    if t is not None and jnp.ndim(t) != 0:
        # an array t would broadcast against the wave axis (one time per wave): a wrong value
        raise ValueError(f"t must be one time [s] (a scalar); got shape {jnp.shape(t)}: vmap over times")
    w = _level(weights, level) if level is not None else None
    n = waves.omega.shape[-1]
    if w is not None and jnp.ndim(w) > 0 and jnp.shape(w)[-1] not in (1, n):
        raise ValueError(f"{level} weights must be per wave (..., N) with N = {n}; got shape {jnp.shape(w)}")


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
    sin_psi, cos_psi = sincos(phase(waves, xy, t))
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
    _check(waves, xy, t, weights, "displacement")
    cos_psi, sin_psi = _weighted_trig(waves, xy, t, _level(weights, "displacement"))
    sin_coeffs, cos_coeffs = _displacement_coeffs(waves)
    return _displacement_from_sums(jnp.dot(sin_psi, sin_coeffs), jnp.dot(cos_psi, cos_coeffs))


def surface_point(waves: Waves, xy, t, weights=None):
    """World position p(X, t) ``(..., 3)`` of the rest position ``xy``."""
    d = displacement(waves, xy, t, weights)
    return d + jnp.concatenate([xy, jnp.zeros_like(xy[..., :1])], axis=-1)


def normal(waves: Waves, xy, t, weights=None):
    """Unit surface normal ``(..., 3)`` at rest positions ``xy (..., 2)``."""
    _check(waves, xy, t, weights, "normal")
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
    per_wave = wave_slope_variance((waves.amplitude * wavenumber(waves)) ** 2)
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


def _channel_coeffs(waves: Waves, weights, with_displacement: bool = True):
    """Coefficients of the eight wave sums, weighted per level: (cos (..., 4, N), sin (..., 4, N)).

    cos channels: A_xx, A_xy, A_yy, d_z; sin channels: B_x, B_y, d_x, d_y. Weight arrays
    ``(..., N)`` give per-row (or per-grid) coefficients with the same leading axes.
    ``with_displacement=False``: the normal's five only, (cos (..., 3, N), sin (..., 2, N)).
    """
    norm_sin, norm_cos = _normal_coeffs(waves)
    w_disp, w_norm = _level(weights, "displacement"), _level(weights, "normal")
    if w_norm is not None:
        norm_sin, norm_cos = norm_sin * w_norm[..., None], norm_cos * w_norm[..., None]
    if not with_displacement:
        channels = materialize(*(norm_cos[..., c] for c in range(3)), *(norm_sin[..., c] for c in range(2)))
        return jnp.stack(channels[:3], -2), jnp.stack(channels[3:], -2)
    disp_sin, disp_cos = _displacement_coeffs(waves)
    if w_disp is not None:
        disp_sin, disp_cos = disp_sin * w_disp[..., None], disp_cos * w_disp[..., None]
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
    (per column, wave), e^{i psi} = e^{i a} e^{i b} and all eight wave sums are ONE matrix
    product of ``L = [cos a, sin a]`` ``(T*H, 2N)`` by a right factor ``(2N, 8*W)`` that
    carries the per-channel coefficients -- no per-pixel sin/cos. ``weights`` must be
    per-wave ``(N,)`` (a regular grid has one footprint).

    Differentiable in both modes through a hand-written linear tangent rule (see
    :func:`_grid_surface`): reverse mode costs three products of the forward's size.
    """
    _check(waves)
    x, y, times = jnp.asarray(x), jnp.asarray(y), jnp.atleast_1d(jnp.asarray(times))
    if x.ndim != 1 or y.ndim != 1 or times.ndim != 1:
        raise ValueError(f"x, y, times must be 1-D; got shapes {x.shape}, {y.shape}, {times.shape}")
    n = waves.omega.shape[-1]
    _check_weight_shape(weights, (n,), "on_grid (per-wave)")

    a, b = _grid_phases(waves, x, y, times)
    disp, nrm = _grid_surface(*_channel_coeffs(waves, weights), a, b)
    sx2, sy2 = slope_variance(waves, _level(weights, "roughness") if weights is not None
                              else jnp.zeros_like(waves.amplitude))
    slope_var = jnp.broadcast_to(jnp.stack([sx2, sy2]), disp.shape[:-1] + (2,))
    return GridSurface(displacement=disp, normal=nrm, slope_variance=slope_var)


def _grid_phases(waves: Waves, x, y, times):
    """The two phase factors of a regular grid: a ``(T, H, N)`` and b ``(W, N)``, psi = a + b."""
    k = wavenumber(waves)
    # per-wave, computed once: XLA would otherwise re-evaluate sin(theta) in every element of a
    kx, ky = materialize(k * jnp.cos(waves.theta), k * jnp.sin(waves.theta))
    a = (waves.omega * times[:, None] + waves.phase)[:, None, :] - y[None, :, None] * ky  # (T, H, N)
    b = -x[:, None] * kx  # (W, N)
    return a, b


def _grid_right_factor(cos_coeffs, sin_coeffs, cos_b, sin_b):
    """Right factor ``R (2N, 8, W)`` of the wide product: sums[th, c, w] = [cos a, sin a][th] . R[:, c, w].

    Channel c of the cos group (A_xx, A_xy, A_yy, d_z; coefficients C) needs
    sum C cos(a + b) = cos a . (C cos b) + sin a . (-C sin b); channel c of the sin group
    (B_x, B_y, d_x, d_y; coefficients S) needs sum S sin(a + b) = cos a . (S sin b) + sin a . (S cos b).
    Bilinear in (coefficients, [cos b, sin b]); ``(4, N)`` coefficients, ``(W, N)`` factors.
    """
    cb, sb = cos_b.T[:, None, :], sin_b.T[:, None, :]  # (N, 1, W)
    cc, sc = cos_coeffs.T[:, :, None], sin_coeffs.T[:, :, None]  # (N, 4, 1)
    with_cos_a = jnp.concatenate([cc * cb, sc * sb], axis=1)  # (N, 8, W)
    with_sin_a = jnp.concatenate([-cc * sb, sc * cb], axis=1)
    return jnp.concatenate([with_cos_a, with_sin_a], axis=0)


def _grid_sums(cos_coeffs, sin_coeffs, a, b):
    """The eight wave sums ``(T, H, 8, W)`` (channel-major per row, the product's natural layout)
    and the factors they were built from: ``L (T*H, 2N)``, ``R (2N, 8, W)``, cos b, sin b."""
    t, h, n = a.shape
    w = b.shape[0]
    sin_a, cos_a = sincos(a)
    lhs = jnp.concatenate([cos_a, sin_a], axis=-1).reshape(t * h, 2 * n)  # each sine once
    sin_b, cos_b = sincos(b)
    cos_b, sin_b = materialize(cos_b, sin_b)  # read by all eight channels of R
    rhs = _grid_right_factor(cos_coeffs, sin_coeffs, cos_b, sin_b)
    sums = jnp.dot(lhs, rhs.reshape(2 * n, 8 * w)).reshape(t, h, 8, w)
    return sums, lhs, rhs, cos_b, sin_b


def _grid_jacobian_cross(a_xx, a_xy, a_yy, b_x, b_y):
    """The unnormalised normal m = dp/dx x dp/dy as three arrays (see :func:`normal_from_sums`)."""
    return (-a_xy * b_y - b_x * (1.0 - a_yy),
            -b_x * a_xy - (1.0 - a_xx) * b_y,
            (1.0 - a_xx) * (1.0 - a_yy) - a_xy * a_xy)


def _split_channels(channels):
    """The Jacobian's five sums and the displacement ``(d_x, d_y, d_z)`` (None when only the
    normal's five channels were computed) from the channel list: cos group then sin group,
    8 channels (A_xx, A_xy, A_yy, d_z, B_x, B_y, d_x, d_y) or 5 (A_xx, A_xy, A_yy, B_x, B_y)."""
    if len(channels) == 8:
        a_xx, a_xy, a_yy, d_z, b_x, b_y, d_x, d_y = channels
        return (a_xx, a_xy, a_yy, b_x, b_y), (d_x, d_y, d_z)
    return tuple(channels), None


def _grid_outputs(sums):
    """Displacement (None without its channels), unit normal ``(T, H, W, 3)`` and 1/|m|
    ``(T, H, W)`` from the sums ``(T, H, C, W)``, C = 8 or 5 (see :func:`_split_channels`).

    The same formula as :func:`normal_from_sums` (+z and a zero 1/|m| at a cusp), written per
    component so that XLA does one pass instead of stacking m first.
    """
    (a_xx, a_xy, a_yy, b_x, b_y), disp = _split_channels([sums[:, :, c] for c in range(sums.shape[2])])
    m0, m1, m2 = _grid_jacobian_cross(a_xx, a_xy, a_yy, b_x, b_y)
    sq = m0 * m0 + m1 * m1 + m2 * m2
    ok = sq > tiny(sq)
    inv = jnp.where(ok, inv_sqrt(jnp.where(ok, sq, 1.0)), 0.0)
    nrm = jnp.stack([jnp.where(ok, m0 * inv, 0.0), jnp.where(ok, m1 * inv, 0.0), jnp.where(ok, m2 * inv, 1.0)], -1)
    return None if disp is None else jnp.stack(disp, axis=-1), nrm, inv


@jax.custom_jvp
def _grid_surface(cos_coeffs, sin_coeffs, a, b):
    """(displacement, normal) ``(T, H, W, 3)`` from channel coefficients ``(4, N)`` x 2 and phases
    a ``(T, H, N)``, b ``(W, N)``. The core of :func:`on_grid`; see its tangent rule below."""
    disp, nrm, _ = _grid_outputs(_grid_sums(cos_coeffs, sin_coeffs, a, b)[0])
    return disp, nrm


@_grid_surface.defjvp
def _grid_surface_jvp(primals, tangents):
    """Linear tangent rule whose transpose (reverse mode) is cheap.

    Plain autodiff of the product stored and re-read several ``(T, H, 8, W)`` intermediates
    (channel slices transpose to pads that are summed) and transposed the whole cotangent for
    the second product (measured 10.9 ns per wave x pixel x frame against 1.7 forward). Here
    the tangent of each channel is its own pair of products, ds_c = dL R_c + L dR_c, with
    dL = [-sin a, cos a] da and dR the tangent of the bilinear right factor, so the transpose
    JAX derives is dL* = sum_c G_c R_c^T and dR_c* = L^T G_c: the per-axis factor tables
    reused, two GEMMs of the forward's size in all, and each channel's cotangent G_c an
    elementwise expression of the saved sums, 1/|m| and the output cotangents (no concatenated
    or transposed ``(T, H, 8, W)`` array). The normal's tangent is dn = (dm - n (n . dm)) / |m|,
    zero at a cusp (where the normal is the constant +z).

    Being a linear jvp (not a custom_vjp), it serves forward mode (jvp, jacfwd) and higher
    orders as well; tests check it against autodiff of :func:`_on_grid_reference` to 1e-10.
    """
    cos_coeffs, sin_coeffs, a, b = primals
    d_cos_coeffs, d_sin_coeffs, d_a, d_b = tangents
    t, h, n = a.shape
    w = b.shape[0]
    sums, lhs, rhs, cos_b, sin_b = _grid_sums(cos_coeffs, sin_coeffs, a, b)
    disp, nrm, inv = _grid_outputs(sums)

    cos_a, sin_a = lhs[:, :n].reshape(a.shape), lhs[:, n:].reshape(a.shape)
    d_lhs = jnp.concatenate([-sin_a * d_a, cos_a * d_a], axis=-1).reshape(t * h, 2 * n)
    d_rhs = (_grid_right_factor(d_cos_coeffs, d_sin_coeffs, cos_b, sin_b)
             + _grid_right_factor(cos_coeffs, sin_coeffs, -sin_b * d_b, cos_b * d_b))
    d_sums = [(jnp.dot(d_lhs, rhs[:, c]) + jnp.dot(lhs, d_rhs[:, c])).reshape(t, h, w) for c in range(8)]

    return (disp, nrm), _output_tangents(sums, nrm, inv, d_sums)


def _output_tangents(sums, nrm, inv, d_sums):
    """Tangents of :func:`_grid_outputs` (displacement or None, unit normal): the sums
    ``(T, H, C, W)``, the normal and 1/|m| it returned, and the C channel tangents ``d_sums``,
    each ``(T, H, W)``. dn = (dm - n (n . dm)) / |m| (zero at a cusp: the normal is the constant +z)."""
    (a_xx, a_xy, a_yy, b_x, b_y), _ = _split_channels([sums[:, :, c] for c in range(sums.shape[2])])
    (da_xx, da_xy, da_yy, db_x, db_y), d_disp = _split_channels(d_sums)
    dm0 = -(da_xy * b_y + a_xy * db_y) - (db_x * (1.0 - a_yy) - b_x * da_yy)
    dm1 = -(db_x * a_xy + b_x * da_xy) - ((1.0 - a_xx) * db_y - da_xx * b_y)
    dm2 = -da_xx * (1.0 - a_yy) - (1.0 - a_xx) * da_yy - 2.0 * a_xy * da_xy
    n0, n1, n2 = nrm[..., 0], nrm[..., 1], nrm[..., 2]
    proj = n0 * dm0 + n1 * dm1 + n2 * dm2
    d_nrm = jnp.stack([(dm0 - n0 * proj) * inv, (dm1 - n1 * proj) * inv, (dm2 - n2 * proj) * inv], axis=-1)
    return None if d_disp is None else jnp.stack(d_disp, axis=-1), d_nrm


def _on_grid_reference(waves: Waves, x, y, times, weights=None):
    """(displacement, normal) of :func:`on_grid` by plain autodiff-able code: the previous
    ``(T*H*8, 2N) @ (2N, W)`` product and :func:`normal_from_sums`. For tests only."""
    x, y, times = jnp.asarray(x), jnp.asarray(y), jnp.atleast_1d(jnp.asarray(times))
    k = wavenumber(waves)
    kx, ky = k * jnp.cos(waves.theta), k * jnp.sin(waves.theta)
    a = (waves.omega * times[:, None] + waves.phase)[:, None, :] - y[None, :, None] * ky
    b = -x[:, None] * kx
    rhs = jnp.concatenate([jnp.cos(b), jnp.sin(b)], axis=-1).T
    lhs = _separable_lhs(*_channel_coeffs(waves, weights), jnp.cos(a), jnp.sin(a))
    sums = jnp.einsum("thcm,mw->thcw", lhs, rhs)
    return _surface_from_sums(sums[:, :, c] for c in range(8))


def on_rows(waves: Waves, origin, step, n_cols: int, t, weights=None, *, block: int | None = None,
            with_displacement: bool = True) -> GridSurface:
    """The surface at points that are evenly spaced along each row: X = origin[r] + j * step[r].

    ``origin``, ``step``: ``(R, 2)`` [m]; ``n_cols`` static; ``t`` scalar. Per-row weights
    ``(R, N)`` (a :class:`WaveWeights` with per-row arrays). Returns a ``GridSurface`` with
    ``(R, n_cols, ...)`` arrays (no time axis).

    This is the geometry of a pinhole camera without roll looking at the sea plane: along an
    image row the hit points are affine in the column and the footprint is constant. The
    phase is psi = alpha_r + j beta_r; splitting the columns into blocks of ``block`` (odd,
    ~ 2 sqrt(n_cols)) around centres c_a, j = c_a + b with |b| < B, gives
    e^{i psi} = e^{i(alpha + c_a beta)} e^{i b beta}; the offsets -b and +b share their
    table (cos is even, sin odd), so per row the wave sums are products of ``(C A, N)`` by
    ``(N, B)`` and only R (A + B) N sines are evaluated (instead of R A B N).

    Differentiable in both modes through a hand-written linear tangent rule (see
    :func:`_row_surface_jvp`): the tables are differentiated in closed form; the tangent is
    twice the forward's batched products, and reverse mode their transposes.

    ``with_displacement=False`` computes the normal's five sums only (5/8 of the product;
    for a renderer that does not need hit positions) and returns ``displacement=None``.
    """
    _check(waves, t=t)
    if not (isinstance(n_cols, (int, np.integer)) and n_cols >= 1):
        raise ValueError(f"n_cols must be a positive int; got {n_cols!r}")
    origin, step = jnp.asarray(origin), jnp.asarray(step)
    if origin.ndim != 2 or origin.shape[-1] != 2 or step.shape != origin.shape:
        raise ValueError(f"origin and step must both be (R, 2); got {origin.shape} and {step.shape}")
    rows, n = origin.shape[0], waves.omega.shape[-1]
    _check_weight_shape(weights, (rows, n), "on_rows (per-row)")
    half, n_blocks = _row_layout(n_cols, block)
    width = 2 * half - 1
    disp, nrm = _row_surface(*_row_inputs(waves, origin, step, t, weights, with_displacement), half, n_blocks)
    disp, nrm = (None if x is None else x.reshape(rows, n_blocks * width, 3)[:, :n_cols] for x in (disp, nrm))
    sx2, sy2 = slope_variance(waves, _level(weights, "roughness") if weights is not None
                              else jnp.zeros_like(waves.amplitude))
    slope_var = jnp.broadcast_to(jnp.stack([sx2, sy2], -1)[..., None, :], nrm.shape[:-1] + (2,))
    return GridSurface(displacement=disp, normal=nrm, slope_variance=slope_var)


def _row_inputs(waves: Waves, origin, step, t, weights, with_displacement: bool = True):
    """Per-row channel coefficients ``(R, 4, N)`` x 2 (``(R, 3, N)``, ``(R, 2, N)`` without the
    displacement) and the phase psi = alpha + j beta of the points X = origin + j step:
    alpha, beta ``(R, N)``."""
    kvec = jnp.stack([wavenumber(waves) * jnp.cos(waves.theta), wavenumber(waves) * jnp.sin(waves.theta)])
    alpha = waves.omega * t + waves.phase - jnp.dot(origin, kvec)
    beta = -jnp.dot(step, kvec)
    rows = origin.shape[0]
    cos_coeffs, sin_coeffs = (jnp.broadcast_to(c, (rows,) + c.shape[-2:])
                              for c in _channel_coeffs(waves, weights, with_displacement))
    return cos_coeffs, sin_coeffs, alpha, beta


def _row_layout(n_cols: int, block: int | None) -> tuple[int, int]:
    """``(B, A)``: fine half-width B (offsets |b| < B: blocks of 2B - 1 columns) and the number
    of blocks A covering ``n_cols``. ``block`` (columns per block) is rounded up to odd; by
    default A ~ sqrt(n_cols) / 2 blocks of ~ 2 sqrt(n_cols) columns, the balance between the
    per-block left factor (built elementwise, memory-bound) and the per-row GEMMs that
    measured fastest at 128-512 columns."""
    if block is None:
        n_blocks = max(1, int(round(n_cols / (2.0 * n_cols ** 0.5))))
        width = -(-n_cols // n_blocks)
    else:
        width = max(1, min(int(block), n_cols))
    half = width // 2 + 1  # 2 half - 1 >= width, odd
    return half, -(-n_cols // (2 * half - 1))


def _row_tables(alpha, beta, half: int, n_blocks: int):
    """(cos, sin) of the coarse phases alpha + c_a beta at the block centres c_a = (2B - 1) a +
    B - 1, ``(R, A, N)``, and of the fine phases b beta, b = 0 .. B - 1, ``(R, B, N)``:
    R (A + B) N sines by :func:`jaxocean._math.sincos` (fused polynomials: measured 1.6x
    faster for the whole geometry than power tables built by doubling from 3 R N library
    sines, whose concatenations are memory passes)."""
    dtype = alpha.dtype
    coarse = alpha[:, None, :] + _block_centres(half, n_blocks, dtype)[None, :, None] * beta[:, None, :]
    # computed once, not inside each of the four left factors that read them (see materialize)
    coarse_sin, coarse_cos = materialize(*sincos(coarse))
    fine_sin, fine_cos = sincos(jnp.arange(half, dtype=dtype)[None, :, None] * beta[:, None, :])
    return coarse_cos, coarse_sin, fine_cos, fine_sin


def _block_centres(half: int, n_blocks: int, dtype):
    return (2 * half - 1) * jnp.arange(n_blocks, dtype=dtype) + (half - 1)


def _row_factors(cos_coeffs, sin_coeffs, coarse_cos, coarse_sin):
    """Per channel group, the left factors (K u, K v) ``(R, A, C_g, N)`` with
    sum_n K cos(a + b) = (K cos a) cos b + (-K sin a) sin b (cos group: u, v = cos a, -sin a) and
    sum_n K sin(a + b) = (K sin a) cos b + (K cos a) sin b (sin group: u, v = sin a, cos a).
    Returns ``((K, u, v), ...)`` for the two groups; u, v ``(R, A, 1, N)``, K ``(R, 1, C_g, N)``."""
    cos_a, sin_a = (x[:, :, None, :] for x in (coarse_cos, coarse_sin))
    return ((cos_coeffs[:, None], cos_a, -sin_a), (sin_coeffs[:, None], sin_a, cos_a))


def _products(left, fine):
    """Batched products ``(R, A, C, N) x (R, B, N) -> (R, A, C, B)``."""
    return jnp.einsum("racn,rbn->racb", left, fine)


def _mirrored(even, odd):
    """A block's columns b = -(B-1) .. B-1 from the parts of the sums that are even and odd in
    b, each ``(R, A, C, B)`` for b = 0 .. B - 1: even - odd (reversed, b < 0), then even + odd."""
    return jnp.concatenate([jnp.flip((even - odd)[..., 1:], axis=-1), even + odd], axis=-1)


def _row_sums(cos_coeffs, sin_coeffs, tables):
    """The wave sums ``(R, A, C, 2B - 1)`` of every row, C = 8 or 5 channels (the on_grid layout
    with T = R, H = A, W = block columns). Per channel group, the left factors carrying the
    coefficients times the fine tables: (K u) . cos(b beta) is even in b and (K v) . sin(b beta)
    odd, so the products over b >= 0 give both halves of a block (half the multiply-adds and
    table of products over every column). Separate products with K = N, no concatenated
    factors: the concatenations of one (R, A, C, 2N) x (R, B, 2N) product were whole-array
    copies."""
    coarse_cos, coarse_sin, fine_cos, fine_sin = tables
    groups = [_mirrored(_products(k * u, fine_cos), _products(k * v, fine_sin))
              for k, u, v in _row_factors(cos_coeffs, sin_coeffs, coarse_cos, coarse_sin)]
    return jnp.concatenate(groups, axis=2)


@functools.partial(jax.custom_jvp, nondiff_argnums=(4, 5))
def _row_surface(cos_coeffs, sin_coeffs, alpha, beta, half: int, n_blocks: int):
    """(displacement, normal) ``(R, A, 2B - 1, 3)`` of the columns j = c_a + b of every row, from
    the per-row channel coefficients ``(R, 4, N)`` x 2 and phases psi = alpha + j beta ``(R, N)``.
    Coefficients of the normal's channels only (``(R, 3, N)``, ``(R, 2, N)``) give a None
    displacement. The core of :func:`on_rows`; see its tangent rule below."""
    tables = _row_tables(alpha, beta, half, n_blocks)
    disp, nrm, _ = _grid_outputs(_row_sums(cos_coeffs, sin_coeffs, tables))
    return disp, nrm


@_row_surface.defjvp
def _row_surface_jvp(half, n_blocks, primals, tangents):
    """Linear tangent rule, the per-row counterpart of :func:`_grid_surface_jvp`.

    Plain autodiff saved the tables' intermediates and transposed the batched products
    (measured 5x the forward, with the earlier doubling tables). Here the tables are
    differentiated in closed form -- d(e^{i phi}) = i e^{i phi} dphi with the linear phase
    tangents da = dalpha + c_a dbeta (coarse) and db = b dbeta (fine). Per channel group with
    left factors (K u, K v) (see :func:`_row_factors`; du = v da, dv = -u da for both groups),
    the even and odd parts E = (K u) . cos b, O = (K v) . sin b have the tangents

        dE = (dK u + K v da) . cos b - (K u) . (sin b db)
        dO = (dK v - K u da) . sin b + (K v) . (cos b db)

    (even and odd in b again, so mirrored like the values): four batched products per group
    where the forward has two, and their transposes in reverse mode; the outputs' tangents are
    those of on_grid (:func:`_output_tangents`). Linear, so it serves forward mode and
    higher orders too; tests check it against autodiff of :func:`_on_rows_reference`.
    """
    cos_coeffs, sin_coeffs, alpha, beta = primals
    d_cos_coeffs, d_sin_coeffs, d_alpha, d_beta = tangents
    tables = _row_tables(alpha, beta, half, n_blocks)
    coarse_cos, coarse_sin, fine_cos, fine_sin = tables
    sums = _row_sums(cos_coeffs, sin_coeffs, tables)
    disp, nrm, inv = _grid_outputs(sums)

    dtype = alpha.dtype
    # outer products as einsums: their transposes are then dots, not reductions over a short
    # middle axis (which XLA:CPU hands to a reduction kernel measured at 50 ms for (R, A, 4, N))
    d_coarse = (jnp.einsum("a,rn->ran", jnp.ones(n_blocks, dtype), d_alpha)
                + jnp.einsum("a,rn->ran", _block_centres(half, n_blocks, dtype), d_beta))[:, :, None, :]
    d_fine = jnp.einsum("b,rn->rbn", jnp.arange(half, dtype=dtype), d_beta)  # (R, B, N)
    fine_cos_d, fine_sin_d = fine_cos * d_fine, fine_sin * d_fine
    d_groups = []
    for (k, u, v), d_k in zip(_row_factors(cos_coeffs, sin_coeffs, coarse_cos, coarse_sin),
                              (d_cos_coeffs[:, None], d_sin_coeffs[:, None])):
        d_k = jnp.concatenate([d_k] * n_blocks, axis=1)  # per-block copies: transposed, a sum of slices
        ku, kv = k * u, k * v
        d_even = _products(d_k * u + kv * d_coarse, fine_cos) - _products(ku, fine_sin_d)
        d_odd = _products(d_k * v - ku * d_coarse, fine_sin) + _products(kv, fine_cos_d)
        d_groups.append(_mirrored(d_even, d_odd))
    d_sums = jnp.concatenate(d_groups, axis=2)
    return (disp, nrm), _output_tangents(sums, nrm, inv, [d_sums[:, :, c] for c in range(sums.shape[2])])


def _on_rows_reference(waves: Waves, origin, step, n_cols: int, t, weights=None, *, block: int):
    """(displacement, normal) of :func:`on_rows` by plain autodiff-able code: the same tables
    and products, differentiated by JAX, and :func:`normal_from_sums`. For tests only."""
    rows = origin.shape[0]
    half, n_blocks = _row_layout(n_cols, block)
    cos_coeffs, sin_coeffs, alpha, beta = _row_inputs(waves, origin, step, t, weights)
    sums = _row_sums(cos_coeffs, sin_coeffs, _row_tables(alpha, beta, half, n_blocks))
    width = 2 * half - 1
    return _surface_from_sums(sums[:, :, c].reshape(rows, n_blocks * width)[:, :n_cols] for c in range(8))
