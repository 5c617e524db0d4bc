"""Pruning statistics of the wave fit's selection (:mod:`jaxocean.fit.waves._select`).

Protocol: from a fitted model's packed parameters ``y (4 N,)`` and normal matrix
``jtj (4 N, 4 N)`` (the structured solver's, residuals scaled by ``1 / sqrt(P)``),
:func:`wald_keep` says which waves pay the information criterion's penalty and
:func:`correlated_discount` how much of the explained RSS correlated noise could have made;
:func:`unseparated_weaker` marks the weaker wave of each pair the observation window does not
separate, and :func:`merge_close_pairs` replaces each much closer pair by the one wave the pair
draws together (eager, NumPy, outside any gradient).
"""

from __future__ import annotations

import math

import numpy as np

from jaxocean import camera as cam
from jaxocean.fit.waves._match import rayleigh_separation
from jaxocean.waves import GRAVITY, Waves


def _deletion_cost(y, jtj, active, n):
    """``(n,)``: the increase of ``|r|^2`` (the solver's scaled residual) that deleting each
    of the first ``n`` waves (``a = b = 0``, the rest refitted) would cost, to second order:
    ``x^T cov_xx^-1 x`` with ``x = (a, b)`` and ``cov = (J^T J)^-1`` over every parameter
    (NaN where the solve fails, 0 for inactive waves)."""
    n_all = active.shape[0]
    p = 4 * n_all
    act = np.asarray(active)
    A = np.asarray(jtj, np.float64)
    # a column without information (omega and theta of a wave whose amplitude went to 0)
    # is scaled as an identity row instead of dividing by its zero norm
    has = np.diag(A) > 1e-300
    d = np.where(has, np.sqrt(np.where(has, np.diag(A), 1.0)), 1.0)
    scaled = np.where(has[:, None] & has[None, :], A / d[:, None] / d[None, :], np.eye(p))
    cov = np.linalg.pinv(scaled + 1e-9 * np.eye(p)) / d[:, None] / d[None, :]
    yy = np.asarray(y, np.float64).reshape(4, n_all)
    cost = np.zeros(n)
    for i in np.nonzero(act[:n])[0]:
        idx = [i, n_all + i]
        C = cov[np.ix_(idx, idx)]
        x = yy[:2, i]
        try:
            cost[i] = float(x @ np.linalg.solve(C, x))
        except np.linalg.LinAlgError:
            cost[i] = np.nan
    return cost


def correlated_discount(y, jtj, active, n, cells, m):
    """The RSS a model's first ``n`` waves explain that noise correlated across the image
    could have made: ``sum_i D_i (1 - 1 / c_i)`` with ``D_i`` the RSS increase of deleting
    wave ``i`` (:func:`_deletion_cost`, residuals scaled by ``1/sqrt(P)``, ``P = m / 2``) and
    ``c_i`` its pixels per independent observation (:func:`noise_cells`). Added to the RSS it
    makes each wave's chi^2 gain ``D_i / (c_i sigma^2)``: the generalised least-squares
    chi^2 of waves that each sit in one band of the noise's spectrum. 0 when every
    ``c_i = 1`` (white noise)."""
    cells = np.asarray(cells, np.float64)[:n]
    if n == 0 or np.all(cells <= 1.0):
        return 0.0
    cost = np.nan_to_num(_deletion_cost(y, jtj, active, n), nan=0.0) * (m / 2.0)
    return float(np.sum(np.maximum(cost, 0.0) * (1.0 - 1.0 / cells)))


def wald_keep(y, jtj, active, half, n_obs, criterion, noise, floor2, cells=None):
    """Keep a wave when deleting it (a = b = 0) would cost more than the criterion's penalty
    (with correlated noise, in units of each wave's noise: ``cells`` times the per-pixel
    variance)."""
    n = active.shape[0]
    act = np.asarray(active)
    m = n_obs
    # residual variance in the solver's units (residuals scaled by 1/sqrt(P), P = m / 2)
    sigma2 = max(2.0 * float(half) / max(m - 4 * act.sum(), 1.0), floor2 / (m / 2.0))
    if noise is not None:
        sigma2 = float(noise) ** 2 / (m / 2.0)
    sigma2 = max(sigma2, 1e-300)
    cells = np.ones(n) if cells is None else np.concatenate([np.asarray(cells, np.float64),
                                                              np.ones(max(n - len(cells), 0))])[:n]
    # x^T cov^-1 x is the RSS increase of deleting the wave; in units of sigma^2 it is the
    # Wald statistic, compared with the criterion's penalty for 4 parameters
    wald = _deletion_cost(y, jtj, active, n)
    pen = 8.0 if criterion == "aic" else 4.0 * math.log(m)
    return ~np.isfinite(wald) | (wald / (sigma2 * cells) >= pen) | ~act


def unseparated_weaker(w: Waves, camera, times, n_max) -> np.ndarray:
    """``(N,)`` bool: the waves within one Rayleigh limit (:func:`rayleigh_separation`) of
    a stronger wave that is itself kept, going from the strongest down."""
    sep = rayleigh_separation(w, w, camera, times, n_max=n_max)
    amp = np.abs(np.asarray(w.amplitude))
    drop = np.zeros(amp.size, bool)
    for i in np.argsort(-amp, kind="stable"):
        drop[i] = bool(np.any((sep[i] < 1.0) & ~drop & (np.arange(amp.size) != i) & (amp >= amp[i])))
    return drop


def merge_close_pairs(w: Waves, camera, times, n_max, limit: float,
                      max_merges: int | None = None) -> tuple[Waves, int]:
    """Merge, closest pair first, every two waves of ``w (N,)`` closer than ``limit``
    Rayleigh limits (:func:`rayleigh_separation`) into one, at most ``max_merges`` times
    (None: no limit); returns the waves (merged ones in the place of the pair's first) and
    the number of merges.

    Two waves that close draw one wave over the observation window, and the data fix that
    wave, not the split between the two (a fit lets the pair drift apart in amplitude). The
    merged wave is the pair's coherent sum where the data see it, at the centre ``c`` of the
    sea pixels and the middle ``t_c`` of the frames: complex amplitude
    ``z = sum_i h_i exp(i (omega_i t_c - k_i . c + phi_i))``, wave vector the pair's mean
    weighted by ``|z_i|^2``, ``omega`` on the dispersion shell ``omega^2 = g |k|``."""
    h = np.asarray(w.amplitude, np.float64)
    om = np.asarray(w.omega, np.float64)
    th = np.asarray(w.theta, np.float64)
    hit = cam.intersect_sea(camera)
    centre = np.asarray(hit.xy)[np.asarray(hit.mask)].mean(0)
    t_c = float(np.mean(np.asarray(times, np.float64)))
    kv = (om ** 2 / GRAVITY)[:, None] * np.stack([np.cos(th), np.sin(th)], -1)
    z = h * np.exp(1j * (om * t_c - kv @ centre + np.asarray(w.phase, np.float64)))
    alive = np.ones(h.size, bool)
    n_merged = 0
    while alive.sum() > 1 and (max_merges is None or n_merged < max_merges):
        idx = np.nonzero(alive)[0]
        cur = _from_complex(kv[idx], z[idx], centre, t_c, w.omega.dtype)
        sep = rayleigh_separation(cur, cur, camera, times, n_max=n_max)
        np.fill_diagonal(sep, np.inf)
        a, b = np.unravel_index(np.argmin(sep), sep.shape)
        if not sep[a, b] < limit:
            break
        i, j = idx[min(a, b)], idx[max(a, b)]
        e_i, e_j = abs(z[i]) ** 2, abs(z[j]) ** 2
        kv[i] = (e_i * kv[i] + e_j * kv[j]) / max(e_i + e_j, 1e-300)
        z[i] = z[i] + z[j]
        alive[j] = False
        n_merged += 1
    return _from_complex(kv[alive], z[alive], centre, t_c, w.omega.dtype), n_merged


def _from_complex(kv, z, centre, t_c, dtype) -> Waves:
    """Waves of wave vectors ``kv (N, 2)`` with complex amplitudes ``z (N,)`` at ``(centre, t_c)``."""
    k = np.linalg.norm(kv, axis=-1)
    om = np.sqrt(GRAVITY * k)
    phase = np.mod(np.angle(z) - om * t_c + kv @ centre, 2 * np.pi)
    return Waves(*(np.asarray(x, dtype) for x in (np.abs(z), om, np.arctan2(kv[:, 1], kv[:, 0]), phase)))
