"""The spectral start of the wave fit (:mod:`jaxocean.fit.waves`, steps 1 and 2).

Protocol: :func:`spectral_estimate` turns a scene's normals into the dispersion-shell power
on a pyramid of ground grids (:class:`SpectralEstimate`); :func:`solve_amplitudes` solves
the amplitudes and phases of waves of known ``omega, theta (N,)`` linearly;
:func:`spectral_peaks` pools the ``N`` strongest distinct peaks of every scale (with their
power and sub-bin offset); :func:`spectral_init` solves their amplitudes into ``N`` starting
waves.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxocean import hierarchy
from jaxocean._ground_grid import grid_frames, hann, resample
from jaxocean._math import safe_sqrt, sincos, smoothstep
from jaxocean.errors import check_values
from jaxocean.fit.waves._inputs import check_inputs, clean_inputs, plane_hits, slope_field, valid_weights
from jaxocean.fit.waves._model import phase_of, wrap_angle
from jaxocean.waves import GRAVITY, Waves


class SpectralEstimate(NamedTuple):
    """Space-time spectral estimate on ``S`` ground grids (``K = 2 G`` FFT bins a side).

    ``power (S, K, K)`` dispersion-shell power, ``kx, ky (S, K, K)`` world wave vectors of
    the bins [rad/m], ``spacing (S,)`` grid spacings [m], ``extent (S,)`` grid sides [m];
    ``peaks``: ``omega, theta, power (S, n_peaks)`` of the strongest local maxima in each
    grid's usable band (power 0 marks an empty slot), and ``peak_offset (S, n_peaks, 2)``
    the sub-bin position of each maximum from a parabola through the log power of its four
    neighbours, as ``(d log omega, d theta)`` [-, rad] to add to ``omega, theta``.
    """

    power: jax.Array
    kx: jax.Array
    ky: jax.Array
    spacing: jax.Array
    extent: jax.Array
    peak_omega: jax.Array
    peak_theta: jax.Array
    peak_power: jax.Array
    peak_offset: jax.Array


# =============================================================================== linear amplitudes


def solve_amplitudes(normals, camera, times, omega, theta, *, n_min=hierarchy.DEFAULT_N_MIN,
                     n_max=hierarchy.DEFAULT_N_MAX, ridge=1e-6, active=None) -> Waves:
    """Amplitudes and phases of waves of known ``omega, theta (N,)`` by one linear solve.

    To first order in the steepness the slope field is linear in ``(a_i, b_i) = h_i (cos
    phi_i, sin phi_i)`` (:mod:`jaxocean.fit.waves`, step 2); the ``2N`` unknowns are solved jointly by
    least squares over every valid pixel-frame (normal equations, relative ``ridge``).
    ``active (N,)`` bool (default all): the waves to solve; the others take no part and get
    amplitude 0 (a subset solved at a fixed shape, without a compilation per subset).
    """
    normals, _, times = check_inputs(normals, None, camera, times)
    dtype = normals.dtype
    omega = jnp.atleast_1d(jnp.asarray(omega, dtype))
    theta = jnp.atleast_1d(jnp.asarray(theta, dtype))
    if omega.shape != theta.shape or omega.ndim != 1:
        raise ValueError(f"omega and theta must be (N,) of one shape; got {omega.shape}, {theta.shape}")
    check_values(omega > 0, "omega must be > 0 rad/s", omega)
    if active is not None and jnp.shape(active) != omega.shape:
        raise ValueError(f"active must be (N,) = {omega.shape}; got {jnp.shape(active)}")
    a, b = _solve_ab(normals, camera, times, omega, theta, n_min, n_max, ridge, active)
    return Waves(safe_sqrt(a * a + b * b), omega, wrap_angle(theta), phase_of(a, b))


@functools.partial(jax.jit, static_argnums=(5, 6))
def _solve_ab(normals, camera, times, omega, theta, n_min, n_max, ridge, active=None):
    weight = valid_weights(normals, camera)
    normals, _ = clean_inputs(normals, None, weight)
    s = slope_field(normals)
    xy, fp_row, _ = plane_hits(camera)
    # the camera's float64 leaves (x64 on) must not promote the float32 normals' sums
    xy, fp_row = xy.astype(normals.dtype), fp_row.astype(normals.dtype)
    n = omega.shape[0]
    k = omega * omega / GRAVITY
    khat = jnp.stack([jnp.cos(theta), jnp.sin(theta)], -1)  # (N, 2)
    amp = smoothstep(n_min, n_max, (2 * jnp.pi / k)[None, :] / fp_row[:, None]) * k  # (H, N)
    if active is not None:  # an inactive wave's columns are zero: it gets 0 and moves no other
        amp = amp * jnp.asarray(active, amp.dtype)[None, :]

    def frame(carry, inp):
        gram, rhs = carry
        t, st, wt = inp
        psi0 = omega * t - jnp.einsum("hwd,nd->hwn", xy, k[:, None] * khat)  # (H, W, N)
        sn, cs = sincos(psi0)
        sn, cs = sn * amp[:, None, :], cs * amp[:, None, :]
        # design (H, W, 2 comps, 2N): column i -> k_hat_i * amp * sin, column N+i -> * cos
        U = jnp.concatenate([sn[..., None, :] * khat.T[None, None], cs[..., None, :] * khat.T[None, None]], -1)
        U = U * jnp.sqrt(wt)[..., None, None]
        U = U.reshape(-1, 2 * n)
        r = (st * jnp.sqrt(wt)[..., None]).reshape(-1)
        return (gram + U.T @ U, rhs + U.T @ r), None

    zero = (jnp.zeros((2 * n, 2 * n), normals.dtype), jnp.zeros(2 * n, normals.dtype))
    (gram, rhs), _ = jax.lax.scan(frame, zero, (times, s, weight))
    d = jnp.diag(gram)
    gram = gram + ridge * jnp.diag(jnp.maximum(d, 1e-30)) + 1e-30 * jnp.eye(2 * n, dtype=gram.dtype)
    x = jnp.linalg.solve(gram, rhs)
    return x[:n], x[n:]


# =============================================================================== spectral estimate


def _power_one_scale(slopes, weight, times, camera, anchor, e_u, e_v, d, level, use_box, grid, surface=None):
    s_g, v_g, X = resample(slopes, weight, camera, anchor, e_u, e_v, d, level, use_box, grid, surface, times)
    dtype = slopes.dtype
    win = hann(grid, dtype)
    wmap = win[:, None] * win[None, :] * jnp.min(v_g, axis=0)  # (G, G): the same support in every frame
    f = s_g * wmap[None, :, :, None]
    mean = jnp.sum(f, axis=(1, 2), keepdims=True) / jnp.maximum(jnp.sum(wmap), 1e-30)
    f = f - mean * wmap[None, :, :, None]  # remove the mean tilt inside the window
    K = 2 * grid
    F = jnp.fft.ifft2(f, s=(K, K), axes=(1, 2)) * (K * K)  # (T, K, K, 2): sum f e^{+i kappa . x}
    m = jnp.fft.fftfreq(K, 1.0 / K).astype(dtype)
    kap = 2 * jnp.pi * m / (K * d)
    ku, kv = kap[:, None], kap[None, :]
    kx = ku * e_u[0] + kv * e_v[0]
    ky = ku * e_u[1] + kv * e_v[1]
    kk = jnp.sqrt(kx * kx + ky * ky)
    kk_safe = jnp.where(kk > 0, kk, 1.0)
    om = jnp.sqrt(GRAVITY * kk)
    proj = F[..., 0] * (kx / kk_safe) + F[..., 1] * (ky / kk_safe)  # (T, K, K)
    t = times - times[0]
    phase = jnp.exp(-1j * om[None] * t[:, None, None])
    C = jnp.sum(phase * proj, axis=0)
    power = jnp.where(kk > 0, jnp.abs(C) ** 2, 0.0) / jnp.maximum(jnp.sum(wmap ** 2), 1e-30)
    return power.astype(dtype), kx, ky, kk, jnp.sum(wmap > 0)


def _sub_bin_offset(power, idx, kxp, kyp, e_u, e_v, d):
    """``(d log omega, d theta) (n, 2)`` of the peaks at flat indices ``idx``: the vertex of a
    parabola through the log power of each peak and its neighbours along both grid axes
    (at most half a bin), as a change of the wave vector ``(kxp, kyp)``."""
    K = power.shape[0]
    i, j = idx // K, idx % K
    logp = jnp.log(jnp.maximum(power, 1e-30))

    def vertex(lm, l0, lp):
        curv = lm - 2 * l0 + lp  # < 0 at a strict maximum
        return jnp.clip(0.5 * (lm - lp) / jnp.where(curv < 0, curv, -1.0), -0.5, 0.5) * (curv < 0)

    l0 = logp[i, j]
    du = vertex(logp[(i - 1) % K, j], l0, logp[(i + 1) % K, j])
    dv = vertex(logp[i, (j - 1) % K], l0, logp[i, (j + 1) % K])
    bin_k = 2 * jnp.pi / (K * d)
    dkx = bin_k * (du * e_u[0] + dv * e_v[0])
    dky = bin_k * (du * e_u[1] + dv * e_v[1])
    k2 = jnp.maximum(kxp * kxp + kyp * kyp, 1e-24)
    # omega = sqrt(g k): d log omega = d k / (2 k); d theta = (k x dk) / k^2
    return jnp.stack([0.5 * (kxp * dkx + kyp * dky) / k2, (kxp * dky - kyp * dkx) / k2], -1)


def _peaks(power, kk, k_lo, k_hi, n_peaks):
    nb = [jnp.roll(jnp.roll(power, di, 0), dj, 1) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]
    is_max = jnp.all(jnp.stack([power > q for q in nb]), axis=0)
    ok = is_max & (kk >= k_lo) & (kk <= k_hi)
    val = jnp.where(ok, power, 0.0).ravel()
    top, idx = jax.lax.top_k(val, n_peaks)
    return top, idx


@functools.partial(jax.jit, static_argnames=("scales", "grid", "n_peaks"))
def spectral_pyramid(slopes, weight, times, camera, *, scales, grid, n_peaks, surface=None):
    anchors, e_u, e_v, spacing, fallback = grid_frames(camera, scales, grid)
    out = []
    for g in range(scales):
        d = spacing[g]
        power, kx, ky, kk, support = _power_one_scale(slopes, weight, times, camera, anchors[g], e_u, e_v, d, g,
                                                      fallback[g], grid, surface)
        k_lo = 1.5 * 2 * jnp.pi / (grid * d)
        k_hi = 0.9 * jnp.pi / d
        # a grid with (almost) no valid point has no peaks
        power = jnp.where(support >= grid * grid // 8, power, 0.0)
        top, idx = _peaks(power, kk, k_lo, k_hi, n_peaks)
        kxp, kyp = kx.ravel()[idx], ky.ravel()[idx]
        kp = jnp.sqrt(kxp * kxp + kyp * kyp)
        om = jnp.sqrt(GRAVITY * jnp.maximum(kp, 1e-12))
        offset = _sub_bin_offset(power, idx, kxp, kyp, e_u, e_v, d)
        out.append((power, kx, ky, om, jnp.arctan2(kyp, kxp), top, offset))
    stack = [jnp.stack([o[i] for o in out]) for i in range(7)]
    return SpectralEstimate(power=stack[0], kx=stack[1], ky=stack[2], spacing=spacing, extent=spacing * grid,
                            peak_omega=stack[3], peak_theta=stack[4], peak_power=stack[5], peak_offset=stack[6])


def spectral_estimate(normals, camera, times, *, scales: int | None = None, grid: int = 64,
                      n_peaks: int = 32) -> SpectralEstimate:
    """Space-time spectral estimate of an observed sequence (:mod:`jaxocean.fit.waves`, step 1).

    ``scales`` ground grids of ``grid x grid`` points (default: 1 for the orthographic
    camera, 4 for a perspective one; see ``grid_frames``: grid ``s`` is spaced 0.75 x
    2^s x the nearest footprint and starts where the image's footprint reaches that
    scale). Traceable (static ``scales``, ``grid``, ``n_peaks``).
    """
    normals, _, times = check_inputs(normals, None, camera, times)
    if scales is None:
        scales = 1 if camera.projection == "orthographic" else 4
    return _spectral_from_normals(normals, times, camera, scales, grid, n_peaks)


@functools.partial(jax.jit, static_argnums=(3, 4, 5))
def _spectral_from_normals(normals, times, camera, scales, grid, n_peaks):
    weight = valid_weights(normals, camera)
    normals, _ = clean_inputs(normals, None, weight)
    return spectral_pyramid(slope_field(normals), weight, times, camera, scales=scales, grid=grid, n_peaks=n_peaks)


def spectral_init(normals, camera, times, n_waves: int, *, scales: int | None = None, grid: int = 64,
                  n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX) -> Waves:
    """The ``n_waves`` strongest spectral peaks (all scales pooled, duplicates within the
    finest resolution dropped), with amplitudes and phases from :func:`solve_amplitudes`.

    One shot and traceable: no greedy subtraction (use :func:`waves` for that).
    """
    normals, _, times = check_inputs(normals, None, camera, times)
    om, th = _strongest_peaks(normals, camera, times, n_waves, scales, grid)[:2]
    a, b = _solve_ab(normals, camera, times, om, th, n_min, n_max, 1e-6)
    return Waves(safe_sqrt(a * a + b * b), om, wrap_angle(th), phase_of(a, b))


class SpectralPeaks(NamedTuple):
    """The ``n`` strongest distinct peaks of a :class:`SpectralEstimate`, every scale
    pooled: ``omega, theta, power (n,)`` (power 0: no peak) and ``offset (n, 2)`` their
    sub-bin ``(d log omega, d theta)``."""

    omega: jax.Array
    theta: jax.Array
    power: jax.Array
    offset: jax.Array


def spectral_peaks(normals, camera, times, n: int, *, scales: int | None = None, grid: int = 64) -> SpectralPeaks:
    """The ``n`` peaks :func:`spectral_init` starts from, with their powers and sub-bin
    offsets (traceable; static ``n``, ``scales``, ``grid``)."""
    normals, _, times = check_inputs(normals, None, camera, times)
    return SpectralPeaks(*_strongest_peaks(normals, camera, times, n, scales, grid))


def _strongest_peaks(normals, camera, times, n, scales, grid):
    """:func:`_pool_peaks` of the estimate of checked inputs (``scales`` None: the default)."""
    if scales is None:
        scales = 1 if camera.projection == "orthographic" else 4
    return _pool_peaks(_spectral_from_normals(normals, times, camera, scales, grid, max(n, 8)), n)


def _pool_peaks(est: SpectralEstimate, n):
    """Top ``n`` peaks over all scales, suppressing repeats of one wave vector:
    ``omega, theta, power (n,)`` and ``offset (n, 2)``."""
    om = est.peak_omega.ravel()
    th = est.peak_theta.ravel()
    pw = est.peak_power.ravel()
    offset = est.peak_offset.reshape(-1, 2)
    # the scales' powers compete as they are (not normalised per scale)
    k = om * om / GRAVITY
    kx, ky = k * jnp.cos(th), k * jnp.sin(th)
    res = jnp.repeat(2 * jnp.pi / est.extent, est.peak_power.shape[1])
    order = jnp.argsort(-pw)
    keep = jnp.zeros(pw.shape, bool)

    def body(i, keep):
        j = order[i]
        d = jnp.sqrt((kx - kx[j]) ** 2 + (ky - ky[j]) ** 2)
        dup = jnp.any(keep & (d < jnp.maximum(res, res[j])))
        return keep.at[j].set((pw[j] > 0) & ~dup)

    keep = jax.lax.fori_loop(0, pw.shape[0], body, keep)
    score = jnp.where(keep, pw, -1.0)
    _, idx = jax.lax.top_k(score, n)
    return om[idx], th[idx], jnp.maximum(score[idx], 0.0), offset[idx]

