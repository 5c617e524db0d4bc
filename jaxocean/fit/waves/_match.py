"""Scoring and matching of fitted waves (:mod:`jaxocean.fit.waves`): eager NumPy helpers.

Protocol: :func:`resolvable` says which waves ``(N,)`` a camera's image resolves
individually, :func:`separable` which of those the observation window also separates from
every other wave of the set (the waves a fit determines) and :func:`rayleigh_separation` by how
much; :func:`match` pairs fitted with true waves one to one and returns the absolute errors of
the pairs (:class:`WaveMatch`); :func:`forecast_model` turns a fit into the model and
frequency uncertainties of :func:`jaxocean.forecast.forecast`'s damped forecast
(:func:`frequency_cell`: what a window that does not separate a wave knows of its frequency);
:func:`noise_cells` says how many pixels carry one independent observation of each wave when
the normals' errors are correlated across the image.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, spacetime
from jaxocean.fit.waves._band import view_diameter
from jaxocean.waves import GRAVITY, Waves, validate


class WaveMatch(NamedTuple):
    """One-to-one matching of fitted to true waves (:func:`match`).

    ``true_index``/``fit_index`` pair up matched waves; ``abs_error`` is a ``Waves`` of
    absolute errors of the pairs (for theta and phase the absolute difference wrapped to
    the circle, in [0, pi]); ``missed`` lists true waves left without a partner within
    ``tolerance``; ``spurious`` fitted waves likewise.
    """

    true_index: np.ndarray
    fit_index: np.ndarray
    abs_error: Waves
    missed: np.ndarray
    spurious: np.ndarray


# =============================================================================== evaluation helpers


def _sea_view(waves_: Waves, camera, max_distance):
    """The validated waves' ``omega`` [rad/s] and ``theta`` [rad] ``(N,)`` (float64) and the
    camera's sea pixels: footprints ``(P,)`` [m] and sea-plane points ``xy`` ``(P, 2)`` [m]."""
    validate(waves_, max_steepness=None)
    hit = cam.intersect_sea(camera, max_distance=max_distance)
    mask = np.asarray(hit.mask)
    return (np.asarray(waves_.omega, np.float64), np.asarray(waves_.theta, np.float64),
            np.asarray(hit.footprint)[mask], np.asarray(hit.xy)[mask])


def noise_cells(waves_: Waves, camera, correlation: float, *, n_max=hierarchy.DEFAULT_N_MAX,
                max_distance=cam.DEFAULT_MAX_DISTANCE) -> np.ndarray:
    """Pixels per independent observation of each wave, ``(N,)`` >= 1 (eager, NumPy), for
    normal errors correlated as ``exp(-d / l)`` over ``d`` pixels (``correlation = l``).

    Such errors have the power spectrum ``2 pi l^2 / (1 + (kappa l)^2)^(3/2)`` [px^2] times
    their variance at ``kappa`` rad per pixel (white noise: 1), so a wave of wavenumber
    ``k`` [rad/m] sees, at a pixel of footprint ``f``, the error power of ``kappa = k f``
    cells. The count is the harmonic mean of that over the sea pixels that resolve the wave
    (:func:`resolvable`'s rule; all sea pixels when none does), floored at 1 (white noise):
    a wave removes ``c`` times less chi^2 than its energy in units of the per-pixel
    variance would say. ``correlation = 0``: ones.
    """
    om, _, fp, _ = _sea_view(waves_, camera, max_distance)
    if not correlation > 0:
        return np.ones(om.shape)
    lam = 2 * np.pi * GRAVITY / om ** 2
    out = np.ones(om.shape)
    for i in range(om.size):
        sel = fp * n_max <= lam[i]
        f = fp[sel] if sel.any() else fp
        kappa_l = (2 * np.pi / lam[i]) * f * correlation
        cells = 2 * np.pi * correlation ** 2 / (1.0 + kappa_l ** 2) ** 1.5
        out[i] = max(1.0, 1.0 / float(np.mean(1.0 / cells)))
    return out


def resolvable(waves_: Waves, camera, *, cycles: float = 1.0, n_min=hierarchy.DEFAULT_N_MIN,
               n_max=hierarchy.DEFAULT_N_MAX, max_distance=cam.DEFAULT_MAX_DISTANCE) -> np.ndarray:
    """Which waves the image resolves individually: bool ``(N,)`` (eager, NumPy).

    A wave is resolvable when its normal weight is 1 (``lambda >= n_max x footprint``) on
    some sea pixels, and the extent of those pixels on the sea, measured along the wave's
    direction of travel, holds at least ``cycles`` wavelengths.
    """
    om, th, fp, xy = _sea_view(waves_, camera, max_distance)
    lam = 2 * np.pi * GRAVITY / om ** 2
    out = np.zeros(om.shape, bool)
    for i in range(om.size):
        sel = fp * n_max <= lam[i]
        if not sel.any():
            continue
        proj = xy[sel] @ np.array([np.cos(th[i]), np.sin(th[i])])
        out[i] = (proj.max() - proj.min()) >= cycles * lam[i]
    return out


def separable(waves_: Waves, camera, times, *, n_max=hierarchy.DEFAULT_N_MAX,
              max_distance=cam.DEFAULT_MAX_DISTANCE) -> np.ndarray:
    """Which waves are resolvable (:func:`resolvable`) *and* separated from every other wave
    of ``waves_`` by the observation window: bool ``(N,)`` (eager, NumPy).

    Waves ``i`` and ``j`` are separated when ``|omega_i - omega_j| T >= 2 pi`` (``T`` the
    observed duration ``times[-1] - times[0]`` [s]) or ``|k_i - k_j| L_ij >= 2 pi`` (``L_ij``
    the extent, along ``k_i - k_j``, of the sea pixels that resolve both waves, or the
    shorter-footprint ones resolving wave ``i`` when none resolves both): the Rayleigh limit
    (:func:`rayleigh_separation` >= 1). Closer pairs are one blurred peak in any space-time
    spectrum of the data, and a fit explains them with waves whose split the data do not
    determine. A wave must also be separated from its own frame-rate alias
    (:func:`alias_separation` >= 1): the frames cannot tell which way it travels.
    """
    ok = resolvable(waves_, camera, n_max=n_max, max_distance=max_distance)
    sep = rayleigh_separation(waves_, waves_, camera, times, n_max=n_max, max_distance=max_distance)
    np.fill_diagonal(sep, np.inf)
    return ok & np.all(sep >= 1.0, axis=1) & (alias_separation(waves_, times) >= 1.0)


def alias_separation(waves_: Waves, times) -> np.ndarray:
    """Separation ``(N,)`` of each wave from its reverse twin in units of the window's
    Rayleigh limit, for frames a constant ``dt`` apart (:func:`jaxocean.spacetime.uniformly_spaced`;
    eager, NumPy; ``inf`` for other times or a single frame).

    The twin ``(theta + pi, -phi)`` at the same ``omega`` is the wave at frequency ``-omega``,
    which the frames alias onto ``omega`` when ``omega dt`` is a multiple of ``pi`` (the twin's
    trochoid then equals the wave's in every frame: heights and horizontal displacements
    alike). The separation is ``min_m |2 omega - 2 pi m / dt| T / (2 pi)`` over ``m >= 1``
    (``T`` the observed duration); ``m = 0``, a wave observed for less than half its period,
    is left to the long-wave rules."""
    omega = np.asarray(waves_.omega, np.float64)
    t = np.asarray(times, np.float64).ravel()
    rate = _frame_rate(t)
    if rate is None:
        return np.full(omega.shape, np.inf)  # irregular frames (or one) do not alias onto one frequency
    return _alias_gap(2 * omega, rate) * float(t[-1] - t[0]) / (2 * np.pi)


def _frame_rate(t):
    """``2 pi / dt`` [rad/s] of frames ``t (T,)`` a constant ``dt`` apart; None for others."""
    return 2 * np.pi / float(np.mean(np.diff(t))) if spacetime.uniformly_spaced(t) else None


def _alias_gap(both, frame_rate):
    """``|both - m frame_rate|`` for the nearest ``m >= 1``: how far a frequency sum
    ``omega_i + omega_j`` is from making wave ``i`` the frames' image of wave ``j``'s twin."""
    m = np.maximum(np.round(both / frame_rate), 1.0)
    return np.abs(both - m * frame_rate)


def rayleigh_separation(new: Waves, waves_: Waves, camera, times, *, n_max=hierarchy.DEFAULT_N_MAX,
                        max_distance=cam.DEFAULT_MAX_DISTANCE) -> np.ndarray:
    """Separation ``(M, N)`` of each of ``new (M,)`` from each of ``waves_ (N,)`` in units of
    the window's Rayleigh limit: ``max(|omega_i - omega_j| T, |k_i - k_j| L_ij) / (2 pi)``
    with ``T`` and ``L_ij`` as in :func:`separable` (eager, NumPy); below 1 the window does
    not separate the pair. For frames a constant ``dt`` apart, also from each wave's reverse
    twin aliased by the frame rate (wave vector ``-k_j``, frequency ``2 pi m / dt - omega_j``,
    ``m >= 1``; :func:`alias_separation`): the smaller of the two. Such a twin makes the same
    frames as wave ``j``, so a wave close to it is not separated from ``j`` either."""
    om_n, th_n, fp, xy = _sea_view(new, camera, max_distance)
    om_s, th_s, _, _ = _sea_view(waves_, camera, max_distance)
    t = np.asarray(times, np.float64).ravel()
    duration = float(t[-1] - t[0])
    frame_rate = _frame_rate(t)
    k_n, k_s = om_n ** 2 / GRAVITY, om_s ** 2 / GRAVITY
    kv_n = np.stack([k_n * np.cos(th_n), k_n * np.sin(th_n)], -1)
    kv_s = np.stack([k_s * np.cos(th_s), k_s * np.sin(th_s)], -1)
    lam_n, lam_s = 2 * np.pi / k_n, 2 * np.pi / k_s
    reach = fp * n_max  # (P,) the shortest wavelength each pixel resolves

    def limits(i, dk, d_om):
        # (N,) separations of new wave i from wave vectors and frequencies dk, d_om away
        n = np.linalg.norm(dk, axis=-1)
        proj = xy @ (dk / np.maximum(n, 1e-12)[:, None]).T  # (P, N)
        sel = reach[:, None] <= np.minimum(lam_n[i], lam_s)[None, :]
        own = reach <= lam_n[i]
        sel = np.where(sel.any(0)[None, :], sel, own[:, None])
        has = sel.any(0)
        hi = np.max(np.where(sel, proj, -np.inf), axis=0)
        lo = np.min(np.where(sel, proj, np.inf), axis=0)
        extent = np.where(has, hi - lo, 0.0)
        return np.maximum(np.abs(d_om) * duration, n * extent) / (2 * np.pi)

    out = np.zeros((om_n.size, om_s.size))
    for i in range(om_n.size):
        out[i] = limits(i, kv_n[i] - kv_s, om_n[i] - om_s)
        if frame_rate is not None:
            # the twin stands at 2 pi m / dt - omega_j
            out[i] = np.minimum(out[i], limits(i, kv_n[i] + kv_s, _alias_gap(om_n[i] + om_s, frame_rate)))
    return out


def match(fitted: Waves, truth: Waves, *, tolerance: float = 0.1) -> WaveMatch:
    """Match fitted to true waves one to one: the most pairs whose relative wave-vector
    distance ``|k_fit - k_true| / |k_true|`` is at most ``tolerance``, and among those
    the assignment of least total distance (Hungarian); the rest are missed (true) or
    spurious (fitted). Eager, NumPy."""
    from scipy.optimize import linear_sum_assignment

    def kv(w):
        om = np.asarray(w.omega, np.float64)
        th = np.asarray(w.theta, np.float64)
        k = om ** 2 / GRAVITY
        return np.stack([k * np.cos(th), k * np.sin(th)], -1), k

    kf, _ = kv(fitted)
    kt, k_true = kv(truth)
    cost = np.linalg.norm(kf[None, :, :] - kt[:, None, :], axis=-1) / k_true[:, None]
    # every pair beyond the tolerance costs the same, more than all pairs within it together:
    # an unmatchable true wave then cannot pull a fitted wave from the true wave it fits
    # (with raw distances the assignment trades a close pair for two far ones when that
    # lowers the sum)
    far = 2.0 * tolerance * (min(cost.shape) + 1) + 1.0
    ti, fi = linear_sum_assignment(np.where(cost <= tolerance, cost, far))
    ok = cost[ti, fi] <= tolerance
    ti, fi = ti[ok], fi[ok]

    def arr(w, name, idx):
        return np.asarray(getattr(w, name), np.float64)[idx]

    def ang(x):
        return np.abs(np.mod(x + np.pi, 2 * np.pi) - np.pi)

    err = Waves(
        amplitude=np.abs(arr(fitted, "amplitude", fi) - arr(truth, "amplitude", ti)),
        omega=np.abs(arr(fitted, "omega", fi) - arr(truth, "omega", ti)),
        theta=ang(arr(fitted, "theta", fi) - arr(truth, "theta", ti)),
        phase=ang(arr(fitted, "phase", fi) - arr(truth, "phase", ti)),
    )
    missed = np.setdiff1d(np.arange(kt.shape[0]), ti)
    spurious = np.setdiff1d(np.arange(kf.shape[0]), fi)
    return WaveMatch(ti, fi, err, missed, spurious)



# =============================================================================== forecasting


def frequency_cell(omega, camera, times) -> np.ndarray:
    """1-sigma frequency uncertainty [rad/s] ``(N,)`` of waves the observation window does
    not separate: their frequency is known only to within its Rayleigh cell, ``|d omega| <
    2 pi / T`` in time and ``|d omega| < pi g / (omega L)`` through the dispersion relation
    in space (``T`` the observed duration, ``L`` the view's diameter,
    :func:`view_diameter`), taken as uniform: the half-width over
    ``sqrt 3`` (eager, NumPy)."""
    om = np.asarray(omega, np.float64)
    t = np.asarray(times, np.float64)
    duration = float(t[-1] - t[0])
    half = np.minimum(2 * np.pi / duration, np.pi * GRAVITY / (np.maximum(om, 1e-12) * view_diameter(camera)))
    return half / np.sqrt(3.0)


def forecast_model(result, camera, times):
    """What a fit (:class:`~jaxocean.fit.waves.WaveFit` of :func:`~jaxocean.fit.waves.waves`)
    says about the sea outside its window, for :func:`jaxocean.forecast.forecast`'s damped
    forecast: ``(model, frequency_sigma, window)``.

    * ``model``: the fitted waves followed by the long-wave band's stand-ins (the model
      that explained the frames);
    * ``frequency_sigma`` ``(N,)`` [rad/s]: for a determined wave its fitted 1-sigma
      uncertainty; for the others -- stand-ins for what the window does not separate, whose
      fitted frequencies are one choice within a Rayleigh cell -- and for a determined wave
      without a finite uncertainty, :func:`frequency_cell`;
    * ``window``: ``(times[0], times[-1])``.

    ``forecast(model, t, camera, window=window, frequency_sigma=frequency_sigma)`` then keeps
    every wave inside the window (the frames are explained) and, outside it, the expected
    sea given what the window measured."""
    if result.determined is None:
        raise ValueError("forecast_model needs a fit of fit.waves (with `determined`); refine() does not say "
                         "which waves the window determines")
    waves_, det = result.waves, np.asarray(result.determined, bool)
    t = np.asarray(times, np.float64)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"times must be the fitted frames' times (T,), T >= 2; got shape {t.shape}")
    own = (np.full(det.shape, np.nan) if result.uncertainty is None
           else np.asarray(result.uncertainty.omega, np.float64))
    sigma = np.where(det & np.isfinite(own), own, frequency_cell(waves_.omega, camera, t))
    band = None if result.long_waves is None else result.long_waves.waves
    if band is not None and band.omega.shape[0]:
        waves_ = Waves(*(np.concatenate([np.asarray(a), np.asarray(b)]) for a, b in zip(waves_, band)))
        sigma = np.concatenate([sigma, frequency_cell(band.omega, camera, t)])
    model = Waves(*(np.asarray(x, np.asarray(result.waves.omega).dtype) for x in waves_))
    return model, sigma.astype(model.omega.dtype), (float(t[0]), float(t[-1]))


def forecast_plan(result, n_waves: int):
    """The render plan that draws a fit's forecast model (:func:`forecast_model`, ``n_waves``
    components) on the surface path the fit explained its frames with: every wave, with the
    renderer's hit refinement where the fit ended on the hits path (``result.surface ==
    "hits"``), without it on the rows path."""
    from jaxocean import render

    return render.full_plan(n_waves, render.MAX_REFINE_ITERATIONS if result.surface == "hits" else 0)
