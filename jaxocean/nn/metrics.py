"""Scores of predicted per-pixel geometry against the truth (the paper's Table 1 and more).

Protocol
--------
Inputs have leading axes ``(...)`` (frames, batch) over images ``(H, W)``: ``normal``
``(..., H, W, 3)`` unit vectors in the world frame, ``slope_variance (..., H, W, 2)``,
``mask (..., H, W)`` bool (sea pixels; only they are scored), ``yaw (...)`` the camera
yaw (radians) that defines the along-view direction ``(cos yaw, sin yaw)``.

* :func:`normal_scores` -> dict of sums over sea pixels (combine them over batches with
  :func:`merge`, then :func:`finish`): angle error, ``1 - cos``, counts within 1/2/5/10/15
  degrees, slope errors along and across the view, and the true slopes' sum and sum of
  squares about their mean (``*_m2``) that the skill needs.
* :func:`merge(a, b)` -> the sums of both batches: added, the ``*_m2`` by Chan et al.'s
  pairwise rule (in float64), so that the skill's denominator never comes from
  ``sum s^2 - (sum s)^2 / N``, which cancels catastrophically in float32 for slopes whose
  mean is large against their spread.
* :func:`finish(sums)` -> the scores: ``normal_mae`` (mean angle error, radians: the
  paper's "normal MAE"), ``cos_loss`` (mean ``1 - cos``: its "CosSim loss"),
  ``within_{k}deg`` (fraction), ``skill_along`` / ``skill_across`` / ``skill`` (the slope
  skill R^2 = 1 - sum |s - s_hat|^2 / sum |s - mean(s)|^2, slope ``s = (-n_x/n_z,
  -n_y/n_z)``; 1 when exact, 0 for the true slopes' mean; the flat prediction scores
  ``-N |mean(s)|^2 / sum |s - mean(s)|^2 <= 0`` over N pixels, 0 only where the true slopes
  average 0) and ``unfolded_skill_*`` the same over pixels whose true normal is tilted
  less than 60 degrees (``unfolded_fraction`` of them), ``roughness_mse`` (of sigma^2 =
  sum of the pair, dimensionless), ``log_slope_variance_mse`` (of log10 of each variance,
  decades^2), ``image_mse`` (display values in [0, 1]). With no sea pixel every score is
  NaN: nothing was compared (as :func:`jaxocean.forecast.geometry_error`).

The angle between two normals is :func:`jaxocean._math.angle_between` (``atan2``, exact
for equal normals, where ``arccos`` of the dot product loses half the digits).

Host and device agnostic (jnp); sums are float64 on the host when accumulated there.
"""

from __future__ import annotations

import math

import jax.numpy as jnp
import numpy as np

from jaxocean._math import angle_between, slope_from_normal

__all__ = ["THRESHOLDS_DEG", "UNFOLDED_MIN_COS", "slopes", "normal_scores", "roughness_scores", "image_scores", "merge",
           "finish"]

THRESHOLDS_DEG = (1, 2, 5, 10, 15)
# the slope -n_xy / n_z diverges as a facet turns vertical (trochoid crests fold where k h
# approaches 1): a handful of such pixels can outweigh a whole test split in a pooled sum of
# squares, so the skill is also reported over pixels tilted less than 60 degrees
UNFOLDED_MIN_COS = 0.5


def slopes(normal):
    """Surface slope ``(-n_x / n_z, -n_y / n_z)`` ``(..., 2)``."""
    return slope_from_normal(normal, 1e-3)


def _along_across(slope, yaw):
    c, s = jnp.cos(yaw)[..., None, None], jnp.sin(yaw)[..., None, None]
    along = slope[..., 0] * c + slope[..., 1] * s
    across = slope[..., 0] * s - slope[..., 1] * c
    return along, across


def normal_scores(pred, true, mask, yaw) -> dict:
    cos = jnp.clip(jnp.sum(pred * true, -1), -1.0, 1.0)
    m = jnp.broadcast_to(mask, cos.shape).astype(jnp.float32)
    angle = angle_between(pred, true)
    out = {"pixels": m.sum(), "angle_sum": (angle * m).sum(), "one_minus_cos_sum": ((1 - cos) * m).sum()}
    for k in THRESHOLDS_DEG:
        out[f"within_{k}deg_count"] = ((angle <= math.radians(k)) * m).sum()
    pa, pc = _along_across(slopes(pred), yaw)
    ta, tc = _along_across(slopes(true), yaw)
    unfolded = m * (true[..., 2] >= UNFOLDED_MIN_COS)
    out["unfolded_pixels"] = unfolded.sum()
    for name, p, t in (("along", pa, ta), ("across", pc, tc)):
        for prefix, w in (("", m), ("unfolded_", unfolded)):
            total = (t * w).sum()
            mean = total / jnp.maximum(w.sum(), 1.0)
            out[f"{prefix}{name}_err_sq"] = (jnp.square(p - t) * w).sum()
            out[f"{prefix}{name}_sum"] = total
            # about the batch's mean (two passes): sum t^2 - (sum t)^2 / N loses every digit
            # in float32 when the slopes' mean is large against their spread
            out[f"{prefix}{name}_m2"] = (jnp.square(t - mean) * w).sum()
    return out


def roughness_scores(pred_sv, true_sv, mask, floor: float) -> dict:
    m = jnp.broadcast_to(mask, pred_sv.shape[:-1]).astype(jnp.float32)
    r_err = jnp.square(pred_sv.sum(-1) - true_sv.sum(-1))
    lp = jnp.log10(jnp.maximum(pred_sv, floor))
    lt = jnp.log10(jnp.maximum(true_sv, floor))
    return {"roughness_err_sq": (r_err * m).sum(), "log_sv_err_sq": (jnp.square(lp - lt).mean(-1) * m).sum()}


def image_scores(pred_display, true_display, mask) -> dict:
    m = jnp.broadcast_to(mask, pred_display.shape[:-1]).astype(jnp.float32)
    return {"image_err_sq": (jnp.square(pred_display - true_display).mean(-1) * m).sum()}


_COUNTS = {"": "pixels", "unfolded_": "unfolded_pixels"}


def merge(a: dict, b: dict) -> dict:
    """The sums of two batches' :func:`normal_scores` (and the other scores' sums) as one,
    in float64: every sum added, each ``*_m2`` (sum of squares about the mean) merged by
    Chan et al.'s rule ``m2_a + m2_b + n_a n_b / (n_a + n_b) (mean_a - mean_b)^2``. An
    empty ``a`` (``{}``) starts an accumulation."""
    a = {k: float(np.asarray(v, np.float64)) for k, v in a.items()}
    b = {k: float(np.asarray(v, np.float64)) for k, v in b.items()}
    if not a:
        return b
    out = {k: a.get(k, 0.0) + b.get(k, 0.0) for k in a.keys() | b.keys()}
    for key in out:
        if not key.endswith("_m2"):
            continue
        prefix = "unfolded_" if key.startswith("unfolded_") else ""
        na, nb = a[_COUNTS[prefix]], b[_COUNTS[prefix]]
        if na > 0 and nb > 0:
            total = key[:-len("_m2")] + "_sum"
            delta = a[total] / na - b[total] / nb
            out[key] += na * nb / (na + nb) * delta ** 2
    return out


def finish(sums: dict) -> dict:
    """Turn accumulated sums into scores (see the module docstring)."""
    s = {k: float(np.asarray(v, np.float64)) for k, v in sums.items()}
    # no pixel: every mean is NaN, not the 0 of an empty sum (a perfect score)
    n = s["pixels"] if s["pixels"] > 0 else math.nan
    out = {"normal_mae": s["angle_sum"] / n, "cos_loss": s["one_minus_cos_sum"] / n}
    for k in THRESHOLDS_DEG:
        out[f"within_{k}deg"] = s[f"within_{k}deg_count"] / n
    for prefix in _COUNTS:
        if f"{prefix}along_m2" not in s:
            continue
        err, var = 0.0, 0.0
        for name in ("along", "across"):
            v = s[f"{prefix}{name}_m2"]
            out[f"{prefix}skill_{name}"] = 1.0 - s[f"{prefix}{name}_err_sq"] / v if v > 0 else float("nan")
            err, var = err + s[f"{prefix}{name}_err_sq"], var + v
        out[f"{prefix}skill"] = 1.0 - err / var if var > 0 else float("nan")
    if "unfolded_pixels" in s:
        out["unfolded_fraction"] = s["unfolded_pixels"] / n
    if "roughness_err_sq" in s:
        out["roughness_mse"] = s["roughness_err_sq"] / n
        out["log_slope_variance_mse"] = s["log_sv_err_sq"] / n
    if "image_err_sq" in s:
        out["image_mse"] = s["image_err_sq"] / n
    return out
