"""Scoring and matching of fitted waves (:mod:`jaxocean.fit.waves`): eager NumPy helpers.

Protocol: :func:`resolvable` says which waves ``(N,)`` a camera's image resolves
individually; :func:`match` pairs fitted with true waves one to one and returns the
absolute errors of the pairs (:class:`WaveMatch`).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy
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


def resolvable(waves_: Waves, camera, *, cycles: float = 1.0, n_min=hierarchy.DEFAULT_N_MIN,
               n_max=hierarchy.DEFAULT_N_MAX, max_distance=cam.DEFAULT_MAX_DISTANCE) -> np.ndarray:
    """Which waves the image resolves individually: bool ``(N,)`` (eager, NumPy).

    A wave is resolvable when its normal weight is 1 (``lambda >= n_max x footprint``) on
    some sea pixels, and the extent of those pixels on the sea, measured along the wave's
    direction of travel, holds at least ``cycles`` wavelengths.
    """
    validate(waves_, max_steepness=None)
    hit = cam.intersect_sea(camera, max_distance=max_distance)
    mask = np.asarray(hit.mask)
    fp = np.asarray(hit.footprint)[mask]
    xy = np.asarray(hit.xy)[mask]
    om = np.asarray(waves_.omega, np.float64)
    th = np.asarray(waves_.theta, np.float64)
    lam = 2 * np.pi * GRAVITY / om ** 2
    out = np.zeros(om.shape, bool)
    for i in range(om.size):
        sel = fp * n_max <= lam[i]
        if not sel.any():
            continue
        proj = xy[sel] @ np.array([np.cos(th[i]), np.sin(th[i])])
        out[i] = (proj.max() - proj.min()) >= cycles * lam[i]
    return out


def match(fitted: Waves, truth: Waves, *, tolerance: float = 0.1) -> WaveMatch:
    """Match fitted to true waves one to one (Hungarian assignment on the relative
    wave-vector distance ``|k_fit - k_true| / |k_true|``); pairs farther than
    ``tolerance`` are left unmatched. Eager, NumPy."""
    from scipy.optimize import linear_sum_assignment

    def kv(w):
        om = np.asarray(w.omega, np.float64)
        th = np.asarray(w.theta, np.float64)
        k = om ** 2 / GRAVITY
        return np.stack([k * np.cos(th), k * np.sin(th)], -1), k

    kf, _ = kv(fitted)
    kt, k_true = kv(truth)
    cost = np.linalg.norm(kf[None, :, :] - kt[:, None, :], axis=-1) / k_true[:, None]
    ti, fi = linear_sum_assignment(cost)
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

