"""Camera pitch and roll from the visible horizon.

When a camera file gives no pose (or to check the one it gives), the sky/sea edge fixes the
camera's pitch and roll: the visible horizon of a camera ``h`` metres above mean sea level
is the set of directions at the *dip* angle ``arccos(R / (R + h))`` below the horizontal
(``R = 6.371e6`` m; 0.0019 rad at 12 m; atmospheric refraction, which lowers the dip by
about 8 %, is ignored). The heading does not change where the horizon is in the image and
is not estimated.

Protocol
--------
:func:`estimate_horizon(image, intrinsics, distortion, height, ...)` -> :class:`Horizon`.

1. ``image`` ``(H, W)`` gray (display or linear values; ``(H, W, 3)`` RGB is reduced to its
   :func:`jaxocean.radiometry.luminance`). Columns are scanned every ``stride`` pixels (each
   averaged over ``stride`` neighbouring columns). In each, the edge is the row where the
   mean of the ``step`` rows above exceeds the mean of the ``step`` rows below by the most;
   the edge's sub-pixel row is where the column crosses the level halfway between those two
   means (linear interpolation). With a clipped sky this is the crossing halfway between
   the clip level and the sea, which is where the edge lies if the sky is just at the clip
   level; a brighter sky puts the true edge up to half a pixel higher.
   A column whose largest step is below ``min_contrast`` x the image's 1-99 % intensity range
   has no clear edge and is skipped (dark vignetted corners, sea-only columns).
2. The edge points ``(u, v)`` are undistorted (:func:`jaxocean.lens.undistort`). A lens
   whose distortion folds back inside the image (:func:`jaxocean.lens.fold_problem`, the
   check the camera-file reader makes) has pixels with no ray: refused with
   :class:`jaxocean.errors.InvalidValueError`, before any work.
3. A RANSAC line through them (the horizon of a zero dip, ``inlier_px`` tolerance) gives the
   start and discards edges of other things (whitecaps, the ship, dirt on the window).
4. Gauss-Newton with Tukey weights then fits ``(pitch, roll)`` so that each point's ray lies
   at the dip below the horizontal. The residuals are in pixels: the ray's elevation error
   divided by the rate at which elevation changes down that image column.

``success`` requires at least ``min_fraction`` of the scanned columns to agree (residual
below ``3 inlier_px``), an rms residual of those below ``max_rms_px`` (1.5 px by default)
and their span to cover ``min_span`` of the image width; otherwise ``message`` says what
failed and the numbers are those of the best attempt (NaN when there was none).

Limit: ``success`` says that the edge points agree on one line, not that the line is where
sky meets sea. When the sky is hardly brighter than the sea below it and a straight step
inside the sea is stronger, that step is taken: on a tonemapped 40 x 48 render whose sky
meets the sea at 0.44 / 0.41, a step 16 rows below the horizon gave ``success`` with the
pitch 12 deg off. Real footage, where the sky is much brighter than the sea, does not do
this (the sequence below), but a pitch from the horizon of a dim-skied image needs a look.

Accuracy (measured): on the 320 x 240 synthetic images of ``tests/test_horizon.py`` (k1 =
-0.21, noise, whitecaps, vignetted corners) pitch and roll come out within 4e-4 rad, rms
residual 0.2 px. On a real 640 x 480 ship-borne sequence (150 frames, overcast clipped sky,
``experiments/real_evidence.py``) every frame succeeds; against the camera file's pitch and
roll (INS fitted to its own horizon detection, stated 1-sigma 0.002 / 0.003 rad): pitch
-0.065 deg bias, 0.037 deg scatter; roll +0.043 deg bias, 0.120 deg scatter; 30 ms a frame
on the 2-core development machine under the load of other jobs.

Angles in radians with :class:`jaxocean.lens.Pose`'s conventions: ``pitch`` of the optical
axis below the geometric horizontal (positive looks down; the dip is accounted for),
``roll`` positive when the image-right axis tilts up. Pixel coordinates are OpenCV's
(``u`` column, ``v`` row, 0-based pixel centres). Host NumPy; not traceable.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import numpy as np

from jaxocean import lens
from jaxocean.errors import InvalidValueError

__all__ = ["EARTH_RADIUS", "Horizon", "dip", "estimate_horizon", "horizon_points"]

EARTH_RADIUS = 6.371e6
"""Mean Earth radius [m]."""


class Horizon(NamedTuple):
    """Result of :func:`estimate_horizon`.

    ``pitch``, ``roll`` [rad]; ``rms_px`` of the agreeing points' residuals; ``n_points``
    agreeing points; ``success`` and ``message``; ``points (N, 2)`` every detected edge
    ``(u, v)`` and ``inliers (N,)`` bool, which of them agree with the fit.
    """

    pitch: float
    roll: float
    rms_px: float
    n_points: int
    success: bool
    message: str
    points: np.ndarray
    inliers: np.ndarray


def dip(height) -> float:
    """Angle [rad] of the visible horizon below the horizontal from ``height`` metres up."""
    if not height > 0:
        raise ValueError(f"camera height must be > 0 m; got {height}")
    return math.acos(EARTH_RADIUS / (EARTH_RADIUS + float(height)))


def horizon_points(image, *, stride: int | None = None, step: int | None = None, min_contrast: float = 0.2):
    """Sky/sea edge candidates ``(N, 2)`` as pixel ``(u, v)``, one per scanned column that has a
    clear bright-above / dark-below step (step 1 of the module docstring)."""
    gray = _gray(image)
    H, W = gray.shape
    given = "" if step is None else f" (2 step + 2 with step={step})"
    stride = max(1, W // 160) if stride is None else int(stride)
    step = max(2, H // 120) if step is None else int(step)
    if stride < 1 or step < 1:
        raise ValueError(f"stride and step must be >= 1; got stride={stride}, step={step}")
    if 2 * step + 2 > H:
        # the default step is the user's too: name the image size the scan needs
        raise ValueError(f"the image is too small to find a horizon in: {H} rows (of {W} columns); the edge scan "
                         f"needs at least {2 * step + 2} rows{given}")
    lo, hi = np.percentile(gray, [1.0, 99.0])
    contrast = hi - lo
    if not contrast > 0:
        return np.zeros((0, 2))
    n_col = W // stride
    cols = gray[:, : n_col * stride].reshape(H, n_col, stride).mean(axis=2)  # (H, n_col)
    u = np.arange(n_col) * stride + (stride - 1) / 2.0
    c = np.concatenate([np.zeros((1, n_col)), np.cumsum(cols, axis=0)])
    # boundary between rows b-1 and b, b = step .. H-step: mean of rows [b-step, b) minus [b, b+step)
    b = np.arange(step, H - step + 1)
    above = (c[b] - c[b - step]) / step
    below = (c[b + step] - c[b]) / step
    drop = above - below  # (nb, n_col)
    best = np.argmax(drop, axis=0)
    strength = drop[best, np.arange(n_col)]
    clear = strength >= min_contrast * contrast
    # sub-pixel: where the column crosses the level halfway between the means above and below,
    # searched from `step` rows above the boundary to `step` rows below it (linear interpolation
    # between the last row at or above the level and the next one)
    level = 0.5 * (above[best, np.arange(n_col)] + below[best, np.arange(n_col)])
    boundary = b[best]  # between rows boundary-1 and boundary
    rows = np.clip(boundary[None, :] + np.arange(-step, step)[:, None], 0, H - 2)  # (2 step, n_col)
    idx = np.arange(n_col)[None, :]
    upper, lower = cols[rows, idx], cols[rows + 1, idx]
    crossing = (upper >= level) & (lower < level)
    # the crossing nearest the boundary
    distance = np.where(crossing, np.abs(rows + 0.5 - boundary[None, :]), np.inf)
    k = np.argmin(distance, axis=0)
    found = np.isfinite(distance[k, np.arange(n_col)])
    r = rows[k, np.arange(n_col)]
    hi_v, lo_v = upper[k, np.arange(n_col)], lower[k, np.arange(n_col)]
    v = r + (hi_v - level) / np.where(found, hi_v - lo_v, 1.0)
    keep = clear & found
    return np.stack([u[keep], v[keep]], axis=-1)


def estimate_horizon(image, intrinsics: lens.Intrinsics, distortion: lens.Distortion, height: float, *,
                     stride: int | None = None, step: int | None = None,
                     min_contrast: float = 0.2, inlier_px: float = 1.5, max_rms_px: float = 1.5,
                     min_fraction: float = 0.25, min_span: float = 0.5, ransac_trials: int = 300,
                     seed: int = 0) -> Horizon:
    """Pitch and roll of a camera ``height`` metres above the sea from the horizon in ``image``
    (see the module docstring for the method and the meaning of each option)."""
    gray = _gray(image)
    H, W = gray.shape
    folds = lens.fold_problem(distortion, intrinsics, (W, H))
    if folds is not None:  # the edge points beyond the fold would undistort to meaningless rays
        raise InvalidValueError(f"estimate_horizon: the lens distortion {folds}")
    dip_angle = dip(height)
    points = horizon_points(gray, stride=stride, step=step, min_contrast=min_contrast)
    n_scanned = W // (max(1, W // 160) if stride is None else int(stride))
    empty = np.zeros(len(points), bool)
    if len(points) < 2:
        return Horizon(math.nan, math.nan, math.nan, 0, False,
                       f"no horizon: {len(points)} of {n_scanned} columns have a clear bright-above/dark-below "
                       f"edge", points, empty)
    fy = float(intrinsics.fy)
    xy, scale = _undistorted(points, intrinsics, distortion)
    line = _ransac_line(xy, inlier_px / fy, ransac_trials, seed)
    if line is None:
        return Horizon(math.nan, math.nan, math.nan, 0, False, "no two distinct edge points to fit a line",
                       points, empty)
    slope, intercept = line
    roll = math.atan(slope)
    pitch = math.atan(-intercept * math.cos(roll))  # the zero-dip horizon: y = tan(r) x - tan(p) / cos(r)
    params = np.array([pitch, roll])
    params = _gauss_newton(params, xy, scale, dip_angle, inlier_px)
    residual = _residual_px(params, xy, scale, dip_angle)
    inliers = np.abs(residual) < 3 * inlier_px
    n = int(inliers.sum())
    rms = float(np.sqrt(np.mean(residual[inliers] ** 2))) if n else math.nan
    span = float(np.ptp(points[inliers, 0]) / W) if n else 0.0
    problems = []
    if n < min_fraction * n_scanned:
        problems.append(f"only {n} of {n_scanned} columns agree (need {min_fraction:.0%})")
    if not rms < max_rms_px:
        problems.append(f"rms residual {rms:.2f} px >= {max_rms_px} px")
    if span < min_span:
        problems.append(f"the agreeing points span {span:.0%} of the width (need {min_span:.0%})")
    success = not problems
    message = (f"horizon fitted: {n} of {n_scanned} columns agree, rms {rms:.2f} px, span {span:.0%}" if success
               else "no reliable horizon: " + "; ".join(problems))
    return Horizon(float(params[0]), float(params[1]), rms, n, success, message, points, inliers)


# --------------------------------------------------------------------------- helpers


def _gray(image) -> np.ndarray:
    image = np.asarray(image, np.float64)
    if image.ndim == 3 and image.shape[-1] == 3:
        from jaxocean.radiometry import luminance

        image = np.asarray(luminance(image), np.float64)
    if image.ndim != 2:
        raise ValueError(f"estimate_horizon expects an (H, W) gray or (H, W, 3) RGB image; got shape {image.shape}")
    if not np.all(np.isfinite(image)):
        raise ValueError("the image holds non-finite values")
    return image


def _undistorted(points, intrinsics, distortion):
    """Undistorted normalised coordinates ``(N, 2)`` of pixel points, and ``(N, 2)`` the same
    for the points half a pixel up and down (for the pixel scale of the residuals)."""
    uv = np.concatenate([points, points - [0.0, 0.5], points + [0.0, 0.5]])
    # padded to a multiple of 512 points, so that images of one size share one compilation
    padded = np.zeros((-(-len(uv) // 512) * 512, 2))
    padded[:len(uv)] = uv
    xy = np.asarray(_undistort_pixels(padded, intrinsics, distortion), np.float64)
    n = len(points)
    return xy[:n], (xy[n:2 * n], xy[2 * n:3 * n])


@jax.jit
def _undistort_pixels(uv, intrinsics, distortion):
    return lens.undistort(lens.normalize_pixels(uv, intrinsics), distortion)


def _up(pitch, roll):
    """World up in camera coordinates (the third column of :func:`jaxocean.lens.rotation`)."""
    return np.array([math.sin(roll) * math.cos(pitch), -math.cos(roll) * math.cos(pitch), -math.sin(pitch)])


def _elevation(up, xy):
    ray = np.concatenate([xy, np.ones((len(xy), 1))], axis=1)
    return np.arcsin(np.clip(ray @ up / np.linalg.norm(ray, axis=1), -1.0, 1.0))


def _residual_px(params, xy, scale, dip_angle):
    """Signed distance in pixels (down the column) from each point to the horizon of ``params``."""
    up = _up(*params)
    above, below = scale
    rate = _elevation(up, above) - _elevation(up, below)  # elevation change over one pixel (upwards)
    rate = np.where(np.abs(rate) > 1e-12, rate, 1e-12)
    return (_elevation(up, xy) + dip_angle) / rate


def _ransac_line(xy, tol, trials, seed):
    """Best-consensus line ``y = a + b x`` (returned as ``(b, a)``), refitted by least squares
    on its inliers; None if the points do not define one."""
    n = len(xy)
    x, y = xy[:, 0], xy[:, 1]
    rng = np.random.default_rng(seed)
    i = rng.integers(0, n, trials)
    j = rng.integers(0, n, trials)
    ok = np.abs(x[i] - x[j]) > 1e-9
    if not ok.any():
        return None
    i, j = i[ok], j[ok]
    b = (y[j] - y[i]) / (x[j] - x[i])
    a = y[i] - b * x[i]
    count = (np.abs(y[None, :] - a[:, None] - b[:, None] * x[None, :]) < tol).sum(axis=1)
    best = int(np.argmax(count))
    inl = np.abs(y - a[best] - b[best] * x) < tol
    if inl.sum() >= 2 and np.ptp(x[inl]) > 0:
        b_fit, a_fit = np.polyfit(x[inl], y[inl], 1)
        return float(b_fit), float(a_fit)
    return float(b[best]), float(a[best])


def _gauss_newton(params, xy, scale, dip_angle, inlier_px, iterations: int = 20):
    """IRLS Gauss-Newton on (pitch, roll) with Tukey biweight (cut-off ``3 inlier_px``)."""
    cutoff = 3.0 * inlier_px
    eps = 1e-6
    for _ in range(iterations):
        r = _residual_px(params, xy, scale, dip_angle)
        w = np.where(np.abs(r) < cutoff, (1 - (r / cutoff) ** 2) ** 2, 0.0)
        if w.sum() == 0:
            break
        J = np.stack([(_residual_px(params + eps * e, xy, scale, dip_angle) - r) / eps for e in np.eye(2)], axis=1)
        JTw = J.T * w
        delta = np.linalg.lstsq(JTw @ J + 1e-12 * np.eye(2), -JTw @ r, rcond=None)[0]
        params = params + delta
        if np.max(np.abs(delta)) < 1e-9:
            break
    return params
