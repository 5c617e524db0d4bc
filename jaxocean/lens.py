"""A physical camera: pose with roll, pinhole intrinsics and a Brown--Conrady lens.

:mod:`jaxocean.camera` is the library's ideal camera (no roll, no distortion, one pose per
sequence). Real footage comes from a camera on a moving ship, described by a camera file
(:mod:`jaxocean.io.camera_file`): a pose per frame, intrinsics and lens distortion. This
module is that camera model; :mod:`jaxocean.rectify` resamples real frames into an ideal
:class:`jaxocean.camera.Camera`.

Protocol
--------
Pure ``jax.numpy`` functions, compiled with ``jax.jit`` (so an eager call and a call inside
the caller's ``jit`` give the same bits), differentiable, float32 or float64 following their
inputs. The three parameter records are ``NamedTuple`` pytrees of scalars or arrays:

* :class:`Intrinsics` ``(fx, fy, cx, cy)`` [px]: focal lengths and principal point. Pixel
  coordinates are OpenCV's: ``u`` the column (to the right), ``v`` the row (downwards), the
  centre of the top-left pixel at ``(0, 0)``. The library camera's pixel ``(i, j)`` is
  ``(v, u) = (i, j)``.
* :class:`Distortion` ``(k1, k2, p1, p2)``: Brown--Conrady radial and tangential terms in
  OpenCV's formula, on normalised coordinates ``(x, y) = (X/Z, Y/Z)``, ``r^2 = x^2 + y^2``::

      x_d = x (1 + k1 r^2 + k2 r^4) + 2 p1 x y + p2 (r^2 + 2 x^2)
      y_d = y (1 + k1 r^2 + k2 r^4) + p1 (r^2 + 2 y^2) + 2 p2 x y
      u = fx x_d + cx,   v = fy y_d + cy

* :class:`Pose` ``(height, pitch, roll, heading, east, north)``: ``height`` [m] of the
  optical centre above mean sea level; ``pitch`` [rad] of the optical axis below the
  horizontal (positive looks down); ``roll`` [rad] about the optical axis (positive: the
  image-right axis tilts up, so the horizon descends to the right); ``heading`` [rad] the
  compass bearing of the optical axis, clockwise from north; ``east``, ``north`` [m] the
  horizontal position of the optical centre. Leaves may be arrays of one shape ``(T,)`` for
  a sequence of frames (map functions over it with ``jax.vmap``, or let them broadcast).

Frames
------
World: x east, y north, z up, mean sea level z = 0. Camera: OpenCV's x right, y down,
z forward along the optical axis. :func:`rotation` is the world -> camera matrix
``R = R_roll @ R_pitch @ R_yaw``, and a world point ``P`` is at ``R (P - C)`` in the camera,
``C = (east, north, height)``::

    R_yaw   = [[cos h, -sin h, 0], [sin h, cos h, 0], [0, 0, 1]]     # h = heading
    R_pitch = [[1, 0, 0], [0, -sin p, -cos p], [0, cos p, -sin p]]
    R_roll  = [[cos r, -sin r, 0], [sin r, cos r, 0], [0, 0, 1]]

so the optical axis is ``(cos p sin h, cos p cos h, -sin p)`` in the world. With roll 0 this
is :mod:`jaxocean.camera`'s frame for ``yaw = pi/2 - heading`` (:func:`yaw_from_heading`):
:func:`pose_of` and :func:`pinhole_intrinsics` turn a library camera into this model, and
:func:`project` then agrees with :func:`jaxocean.camera.project`.

Undistortion
------------
:func:`undistort` inverts :func:`distort` in two stages of fixed length (so eager and traced
calls agree). The radial part ``r (1 + k1 r^2 + k2 r^4) = |x_d|`` is solved on its one-to-one
branch ``[0, fold radius]`` (where ``1 + 3 k1 r^2 + 5 k2 r^4`` first reaches 0) by Newton's
method kept in a bracket (bisection where a step would leave it): plain Newton from
``x = x_d`` diverged for pincushion lenses with ``k2 < 0`` (``k1 = 0.6, k2 = -0.25`` at
fx = 250, 640 x 480: up to 1e18 px), whose ``x_d`` lies beyond the fold radius. Then damped
Newton steps on the full map add the tangential terms. For ``k1 = -0.21, k2 = 0.062`` over a
640 x 480 image (fx = 376 px) the float64 round trip is exact to 1e-13 px (``tests/test_lens.py``
checks < 1e-9 px, and < 1e-3 px over random lenses that :func:`fold_problem` accepts); in
float32 to 6.1e-5 px, one rounding step of a coordinate near 640. Tangential terms can fold
the full map (Jacobian determinant <= 0) where the radial part alone is one-to-one
(:func:`fold_problem` refuses such a lens for an image it folds): there the result is the
damped iteration's best point.
Beyond the one-to-one range of a lens (e.g. ``k2 = 0``, ``k1 < 0`` at ``r^2 > 1 / (-3 k1)``) the Brown--Conrady polynomial
folds back and points far outside the field of view project *into* the image; callers that
project arbitrary points must limit the undistorted radius (:func:`max_radius`), and a lens
that folds back inside its own image has pixels with no ray: :func:`fold_problem` (host
side, on concrete values) says so, for the readers of lenses to refuse it.
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

__all__ = [
    "Intrinsics",
    "Distortion",
    "Pose",
    "rotation",
    "distort",
    "undistort",
    "max_radius",
    "fold_problem",
    "normalize_pixels",
    "camera_coordinates",
    "denormalize",
    "project",
    "pixel_rays",
    "yaw_from_heading",
    "heading_from_yaw",
    "pinhole_intrinsics",
    "pose_of",
]

# Newton iterations of undistort on the full map, from the radial inverse: quadratic
# convergence for the tangential terms; 4 reach float64 round-off at the corners of the
# strongly distorted 640 x 480 lens of the tests (r ~ 1.3), 2 more are margin.
UNDISTORT_ITERATIONS = 6
# Halvings a damped Newton step of undistort may try (a near-singular Jacobian near a fold).
_DAMPING = 4
# Safeguarded Newton steps of the radial inverse: bisection halves the bracket [0, fold
# radius] where Newton would leave it; 40 are float64 round-off from any start.
_RADIAL_STEPS = 40


class Intrinsics(NamedTuple):
    """Pinhole intrinsics [px]: focal lengths ``fx``, ``fy``; principal point ``cx``, ``cy``
    (0-based pixel centres; ``u`` column right, ``v`` row down)."""

    fx: jax.Array
    fy: jax.Array
    cx: jax.Array
    cy: jax.Array


class Distortion(NamedTuple):
    """Brown--Conrady lens distortion (OpenCV): radial ``k1``, ``k2``; tangential ``p1``, ``p2``."""

    k1: jax.Array = 0.0
    k2: jax.Array = 0.0
    p1: jax.Array = 0.0
    p2: jax.Array = 0.0


class Pose(NamedTuple):
    """Camera pose: ``height`` [m] above mean sea level, ``pitch`` [rad] below the horizontal
    (positive looks down), ``roll`` [rad] about the optical axis (positive: horizon descends to
    the right), ``heading`` [rad] compass bearing of the optical axis (clockwise from north),
    ``east``, ``north`` [m] horizontal position of the optical centre."""

    height: jax.Array
    pitch: jax.Array
    roll: jax.Array
    heading: jax.Array
    east: jax.Array = 0.0
    north: jax.Array = 0.0


def _dtype(*trees):
    """The floating dtype of the inputs (float32 unless one of them is float64)."""
    dtype = jnp.result_type(*jax.tree_util.tree_leaves(trees))
    return dtype if jnp.issubdtype(dtype, jnp.floating) else jnp.result_type(float)


def _leaves(record, dtype):
    return [jnp.asarray(value, dtype) for value in record]


# --------------------------------------------------------------------------- rotation


@jax.jit
def rotation(pose: Pose) -> jax.Array:
    """World (x east, y north, z up) -> camera (x right, y down, z forward) rotation.

    ``R_roll @ R_pitch @ R_yaw`` (module docstring). Shape ``(..., 3, 3)`` for pose leaves of
    shape ``(...)``: ``(3, 3)`` for one pose, ``(T, 3, 3)`` for a sequence.
    """
    return _rotation(pose, _dtype(pose))


def _rotation(pose: Pose, dtype) -> jax.Array:
    pitch, roll, heading = (jnp.asarray(v, dtype) for v in (pose.pitch, pose.roll, pose.heading))
    pitch, roll, heading = jnp.broadcast_arrays(pitch, roll, heading)
    sp, cp = jnp.sin(pitch), jnp.cos(pitch)
    sr, cr = jnp.sin(roll), jnp.cos(roll)
    sh, ch = jnp.sin(heading), jnp.cos(heading)
    zero = jnp.zeros_like(pitch)
    # R_pitch @ R_yaw, rows: camera x (right), y (down), z (forward) in the world
    right = jnp.stack([ch, -sh, zero], axis=-1)
    down = jnp.stack([-sp * sh, -sp * ch, -cp], axis=-1)
    forward = jnp.stack([cp * sh, cp * ch, -sp], axis=-1)
    # then R_roll mixes the first two rows
    x_axis = cr[..., None] * right - sr[..., None] * down
    y_axis = sr[..., None] * right + cr[..., None] * down
    return jnp.stack([x_axis, y_axis, forward], axis=-2)


def _rotate(R, vectors, *, transpose: bool = False) -> jax.Array:
    """``R @ v`` (or ``R^T @ v``) for ``R`` ``(..., 3, 3)`` and vectors ``(..., 3)``, leading
    shapes broadcast. Explicit sums of components: XLA:CPU runs an ``(N, 3) x (3, 3)`` dot or
    einsum about 10x slower than this elementwise form (measured at N = 442k)."""
    def entry(row, col):
        return R[..., col, row] if transpose else R[..., row, col]

    return jnp.stack([sum(vectors[..., c] * entry(row, c) for c in range(3)) for row in range(3)], axis=-1)


def _centre(pose: Pose, dtype) -> jax.Array:
    east, north, height = jnp.broadcast_arrays(*(jnp.asarray(v, dtype) for v in (pose.east, pose.north, pose.height)))
    return jnp.stack([east, north, height], axis=-1)


# --------------------------------------------------------------------------- distortion


@jax.jit
def distort(xy, distortion: Distortion) -> jax.Array:
    """Normalised undistorted coordinates ``(..., 2)`` -> distorted ones (OpenCV's formula)."""
    xy = jnp.asarray(xy)
    dtype = _dtype(xy, distortion)
    return _distort(xy.astype(dtype), *_leaves(distortion, dtype))


def _distort(xy, k1, k2, p1, p2):
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + k2 * r2)
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return jnp.stack([xd, yd], axis=-1)


def _distort_jacobian(xy, k1, k2, p1, p2):
    """``d(x_d, y_d) / d(x, y)`` as four ``(...)`` arrays (a, b; c, d)."""
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + k2 * r2)
    d_radial_dr2 = k1 + 2 * k2 * r2  # d radial / d r2; d r2 / dx = 2x
    a = radial + 2 * x * x * d_radial_dr2 + 2 * p1 * y + 6 * p2 * x
    b = 2 * x * y * d_radial_dr2 + 2 * p1 * x + 2 * p2 * y
    c = 2 * x * y * d_radial_dr2 + 2 * p1 * x + 2 * p2 * y
    d = radial + 2 * y * y * d_radial_dr2 + 6 * p1 * y + 2 * p2 * x
    return a, b, c, d


def _fold_radius(k1, k2):
    """The undistorted radius where ``d r_d / d r = 1 + 3 k1 r^2 + 5 k2 r^4`` first drops to 0
    (its smallest positive root in ``s = r^2``, ``2 / (-3 k1 + sqrt(9 k1^2 - 20 k2))``, a form
    that is exact for ``k2 = 0`` too), inf where it stays positive."""
    disc = 9 * k1 * k1 - 20 * k2
    denominator = -3 * k1 + jnp.sqrt(jnp.maximum(disc, 0))
    folds = (disc >= 0) & (denominator > 0)
    return jnp.where(folds, jnp.sqrt(2 / jnp.where(folds, denominator, 1)), jnp.inf)


def _radial_inverse(rho, k1, k2, iterations):
    """The undistorted radius ``r`` with ``r (1 + k1 r^2 + k2 r^4) = rho`` on the one-to-one
    branch ``[0, fold radius]``: Newton's method kept inside a bracket (a step that leaves it
    bisects instead), so it converges from any start however strongly the lens bends; a
    ``rho`` beyond the fold's reach gives the fold radius."""
    fold = _fold_radius(k1, k2)
    # without a fold (k1 >= 0, or k2 > 9 k1^2 / 20) r_d = r q(r^2) >= r min q, and
    # min q = 1 - k1^2 / (4 k2) > 4/9 for k1 < 0: rho / min q brackets the root tightly
    least_q = jnp.where(k1 < 0, 1 - k1 * k1 / (4 * jnp.where(k2 > 0, k2, 1)), 1.0)
    hi = jnp.where(jnp.isfinite(fold), fold, rho / jnp.maximum(least_q, 4 / 9))
    lo = jnp.zeros_like(hi)

    def step(_, state):
        r, lo, hi, last_step = state
        s = r * r
        excess = r * (1 + s * (k1 + k2 * s)) - rho
        slope = 1 + s * (3 * k1 + 5 * k2 * s)
        lo, hi = jnp.where(excess < 0, r, lo), jnp.where(excess < 0, hi, r)
        newton_step = excess / jnp.where(slope > 0, slope, 1)
        # Newton where it stays in the bracket and at least halves the step before last
        # (Numerical Recipes' rtsafe), else bisection: Newton alone cycles between the two
        # ends of the branch for pincushion lenses
        newton_ok = (slope > 0) & (r - newton_step >= lo) & (r - newton_step <= hi) \
            & (2 * jnp.abs(newton_step) <= jnp.abs(last_step))
        return (jnp.where(newton_ok, r - newton_step, (lo + hi) / 2), lo, hi,
                jnp.where(newton_ok, newton_step, (hi - lo) / 2))

    r0 = jnp.minimum(rho, hi)
    return jax.lax.fori_loop(0, iterations, step, (r0, lo, hi, 2 * hi))[0]


@partial(jax.jit, static_argnames=("iterations",))
def undistort(xy_distorted, distortion: Distortion, *, iterations: int = UNDISTORT_ITERATIONS) -> jax.Array:
    """Distorted normalised coordinates ``(..., 2)`` -> undistorted ones: :func:`distort`'s
    inverse. The radial part is solved first on the one-to-one branch (a bracketed Newton
    iteration on ``r`` in ``[0, fold radius]``), then ``iterations`` damped Newton steps on the
    full map add the tangential terms (module docstring). A fixed number of steps, so eager
    and traced calls agree; differentiable through the Newton steps (the radial start
    carries the gradient of the identity only)."""
    xy_distorted = jnp.asarray(xy_distorted)
    dtype = _dtype(xy_distorted, distortion)
    target = xy_distorted.astype(dtype)
    params = _leaves(distortion, dtype)

    k1, k2 = params[0][..., None], params[1][..., None]
    rho = jnp.sqrt(jnp.sum(target * target, axis=-1, keepdims=True))
    r = _radial_inverse(rho, k1, k2, _RADIAL_STEPS)
    start = jax.lax.stop_gradient(jnp.where(rho > 0, target * (r / jnp.where(rho > 0, rho, 1)), target))

    def step(_, xy):
        residual = _distort(xy, *params) - target
        a, b, c, d = _distort_jacobian(xy, *params)
        det = a * d - b * c
        dx = (d * residual[..., 0] - b * residual[..., 1]) / det
        dy = (a * residual[..., 1] - c * residual[..., 0]) / det
        newton = jnp.stack([dx, dy], axis=-1)
        # damped: the longest of the steps 1, 1/2, ... 1/2^_DAMPING that reduces the residual
        # (where the Jacobian is nearly singular a full step can throw x far off)
        size = jnp.sum(residual * residual, axis=-1)
        best, best_size = xy, size
        for k in range(_DAMPING, -1, -1):
            candidate = xy - newton * 0.5 ** k
            r = _distort(candidate, *params) - target
            candidate_size = jnp.sum(r * r, axis=-1)
            better = candidate_size <= best_size if k == 0 else candidate_size < best_size
            best = jnp.where(better[..., None], candidate, best)
            best_size = jnp.where(better, candidate_size, best_size)
        return best

    return jax.lax.fori_loop(0, int(iterations), step, target + (start - jax.lax.stop_gradient(target)))


def max_radius(distortion: Distortion, *, limit: float = 10.0) -> jax.Array:
    """The undistorted radius up to which the radial distortion is one-to-one.

    The smallest ``r > 0`` where ``d r_d / d r = 1 + 3 k1 r^2 + 5 k2 r^4`` drops to 0 (a closed
    form, the one :func:`undistort` solves within), capped at ``limit``. Points beyond it are
    outside any image this lens makes, though :func:`project` may put them inside; tangential
    terms are ignored.
    """
    dtype = _dtype(distortion)
    k1, k2, _, _ = _leaves(distortion, dtype)
    return jnp.minimum(_fold_radius(k1, k2), jnp.asarray(limit, dtype))


def fold_problem(distortion: Distortion, intrinsics: Intrinsics, image_size) -> str | None:
    """None when every pixel of an image of ``image_size = (W, H)`` has a ray; else what is
    wrong, in words that name the lens. The radial distortion ``r (1 + k1 r^2 + k2 r^4)``
    must not fold back (:func:`max_radius`) before it reaches the image's farthest corner, or
    the pixels beyond the fold (the view's lowest rays, the horizon's ends) undistort to
    meaningless rays; nor may the tangential terms fold the full map inside that range (its
    Jacobian determinant <= 0: measured, k1 = -0.54, k2 = 0.132, p = (0.001, -0.002) at
    fx = 158 on 640 x 480 passes the radial test and folds). Host side: concrete scalar leaves."""
    limit = 10.0
    r = float(max_radius(Distortion(*(np.float64(v) for v in distortion)), limit=limit))
    (W, H), (fx, fy, cx, cy) = image_size, (float(v) for v in intrinsics)
    corner = max(math.hypot((u - cx) / fx, (v - cy) / fy) for u in (-0.5, W - 0.5) for v in (-0.5, H - 0.5))
    if r >= limit:
        return _tangential_fold(distortion, r, corner)
    k1, k2 = float(distortion.k1), float(distortion.k2)
    reach = r * (1 + k1 * r * r + k2 * r ** 4)
    if corner <= reach:
        return _tangential_fold(distortion, r, corner)
    return (f"k1 = {k1:g}, k2 = {k2:g} is not one-to-one over the image: the distortion folds back "
            f"at the undistorted radius {r:.3g}, where it reaches {reach:.3g}, and the "
            f"image's farthest corner lies at {corner:.3g} (normalised, (u - cx) / fx): the pixels "
            f"beyond have no ray (check the coefficients' signs, and that they belong to these "
            f"intrinsics)")


def _tangential_fold(distortion: Distortion, fold_radius: float, corner: float) -> str | None:
    """What is wrong when the full map (tangential terms included) folds within the undistorted
    radius the image reaches (:func:`_radial_inverse` of ``corner``, 5% beyond, at most
    ``fold_radius``): its Jacobian determinant sampled on a polar grid; None where it stays > 0."""
    k1, k2, p1, p2 = (float(v) for v in distortion)
    if p1 == 0 and p2 == 0:
        return None  # the radial test above is exact for a radial lens
    r_image = min(1.05 * float(_radial_inverse(np.float64(corner), k1, k2, _RADIAL_STEPS)), fold_radius)
    radius, angle = np.meshgrid(np.linspace(0.0, r_image, 256), np.linspace(0.0, 2 * np.pi, 512, endpoint=False))
    xy = np.stack([radius * np.cos(angle), radius * np.sin(angle)], -1)
    a, b, c, d = _distort_jacobian(xy, k1, k2, p1, p2)
    least = float(np.min(a * d - b * c))
    if least > 0:
        return None
    return (f"p1 = {p1:g}, p2 = {p2:g} with k1 = {k1:g}, k2 = {k2:g} is not one-to-one over the image: "
            f"the tangential terms fold the distortion (Jacobian determinant down to {least:.3g}) within "
            f"the undistorted radius {r_image:.3g} the image reaches: some pixels have no ray (check the "
            f"coefficients' signs, and that they belong to these intrinsics)")


# --------------------------------------------------------------------------- projection


@jax.jit
def normalize_pixels(uv, intrinsics: Intrinsics) -> jax.Array:
    """Pixel coordinates ``(u, v)`` ``(..., 2)`` -> distorted normalised ``((u - cx)/fx, (v - cy)/fy)``."""
    uv = jnp.asarray(uv)
    dtype = _dtype(uv, intrinsics)
    fx, fy, cx, cy = _leaves(intrinsics, dtype)
    uv = uv.astype(dtype)
    return jnp.stack([(uv[..., 0] - cx) / fx, (uv[..., 1] - cy) / fy], axis=-1)


@jax.jit
def denormalize(xy_distorted, intrinsics: Intrinsics) -> jax.Array:
    """Distorted normalised coordinates ``(..., 2)`` -> pixel coordinates ``(u, v)``."""
    xy_distorted = jnp.asarray(xy_distorted)
    dtype = _dtype(xy_distorted, intrinsics)
    fx, fy, cx, cy = _leaves(intrinsics, dtype)
    xy_distorted = xy_distorted.astype(dtype)
    return jnp.stack([fx * xy_distorted[..., 0] + cx, fy * xy_distorted[..., 1] + cy], axis=-1)


@jax.jit
def camera_coordinates(points, pose: Pose) -> jax.Array:
    """World points ``(..., 3)`` in the camera frame ``R (P - C)`` ``(..., 3)`` (x right, y down,
    z forward). Pose leaves broadcast against the points' leading shape."""
    points = jnp.asarray(points)
    dtype = _dtype(points, pose)
    R = _rotation(pose, dtype)
    relative = points.astype(dtype) - _centre(pose, dtype)
    return _rotate(R, relative)


@jax.jit
def project(points, pose: Pose, intrinsics: Intrinsics, distortion: Distortion = Distortion()):
    """World points ``(..., 3)`` -> pixel coordinates ``uv`` ``(..., 2)`` (column, row) and
    ``in_front`` ``(...)`` bool (depth along the optical axis > 0).

    Pose leaves broadcast against the points' leading shape (a scalar pose projects any
    array of points; for a sequence, ``jax.vmap`` over the pose or give its leaves trailing
    unit axes). ``uv`` of points not in front is finite but meaningless (the depth is
    replaced by 1): mask them with ``in_front``. Beyond the lens's one-to-one radius
    (:func:`max_radius`) distortion folds points back towards the image.
    """
    if jnp.shape(points)[-1:] != (3,):
        raise ValueError(f"project expects points of shape (..., 3); got {jnp.shape(points)}")
    p = camera_coordinates(points, pose)
    dtype = p.dtype
    depth = p[..., 2]
    in_front = depth > 0
    safe_depth = jnp.where(in_front, depth, 1)
    xy = p[..., :2] / safe_depth[..., None]
    xy_d = _distort(xy, *_leaves(distortion, dtype))
    return denormalize(xy_d, intrinsics), in_front


@partial(jax.jit, static_argnames=("iterations",))
def pixel_rays(uv, pose: Pose, intrinsics: Intrinsics, distortion: Distortion = Distortion(), *,
               iterations: int = UNDISTORT_ITERATIONS) -> jax.Array:
    """Unit world directions ``(..., 3)`` of the rays through pixel coordinates ``uv`` ``(..., 2)``
    (they start at the optical centre ``(east, north, height)``): the inverse of
    :func:`project`. Pose leaves broadcast against ``uv``'s leading shape."""
    xy = undistort(normalize_pixels(uv, intrinsics), distortion, iterations=iterations)
    dtype = _dtype(xy, pose)
    xy = xy.astype(dtype)
    d_cam = jnp.concatenate([xy, jnp.ones_like(xy[..., :1])], axis=-1)
    d_cam = d_cam / jnp.sqrt(jnp.sum(d_cam * d_cam, axis=-1, keepdims=True))
    R = _rotation(pose, dtype)
    return _rotate(R, d_cam, transpose=True)


# --------------------------------------------------------------------------- the library camera


def yaw_from_heading(heading):
    """Library azimuth (from +x = east, counter-clockwise) of a compass heading (clockwise
    from north): ``pi/2 - heading``."""
    return math.pi / 2 - jnp.asarray(heading)


def heading_from_yaw(yaw):
    """Compass heading in ``[0, 2 pi)`` of a library azimuth: ``(pi/2 - yaw) mod 2 pi``."""
    return jnp.mod(math.pi / 2 - jnp.asarray(yaw), 2 * math.pi)


def pinhole_intrinsics(camera) -> Intrinsics:
    """Intrinsics of a perspective :class:`jaxocean.camera.Camera`: ``fx = fy = (H/2) /
    tan(fov/2)``, ``cx = (W - 1)/2``, ``cy = (H - 1)/2`` (pixel ``(i, j)`` is ``(v, u)``)."""
    if camera.projection != "perspective":
        raise ValueError(f"pinhole_intrinsics needs a perspective camera; got {camera.projection!r}")
    H, W = camera.resolution
    f = (H / 2) / jnp.tan(jnp.asarray(camera.fov) / 2)
    dtype = f.dtype
    return Intrinsics(f, f, jnp.full_like(f, (W - 1) / 2, dtype=dtype), jnp.full_like(f, (H - 1) / 2, dtype=dtype))


def pose_of(camera) -> Pose:
    """The :class:`Pose` of a :class:`jaxocean.camera.Camera`: its height and pitch, roll 0,
    heading ``pi/2 - yaw`` (not wrapped, so it is differentiable and exact), east = x,
    north = y."""
    height = jnp.asarray(camera.height)
    return Pose(height=height, pitch=jnp.asarray(camera.pitch), roll=jnp.zeros_like(height),
                heading=yaw_from_heading(camera.yaw), east=jnp.asarray(camera.x),
                north=jnp.asarray(camera.y))
