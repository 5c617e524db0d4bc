"""Ray-surface hits: where each pixel ray meets the displaced trochoid surface.

Protocol
--------
``refine_hits(waves, origin, direction, xy0, t, weights, max_iterations=..., tolerance=...) -> Hits``

* ``origin`` ``(3,)`` or ``(..., 3)`` ray origins [m], broadcastable to ``direction (..., 3)``:
  ray directions that go down (``direction[..., 2] < 0``; callers substitute a safe ray
  for sky pixels).
* ``xy0 (..., 2)`` the start [m], normally the mean-sea-plane hits.
* ``weights (..., N)`` per-point displacement weights (the hierarchy's displacement level).
* ``t`` scalar time [s].
* ``Hits.xy (..., 2)`` rest positions X [m] whose surface point lies on the ray;
  ``Hits.converged (..., 2)`` bool; ``Hits.iterations`` the iterations the loop ran.

A rest position X is displaced to ``p(X, t) = (X + d_xy(X, t), d_z(X, t))``. Its pixel ray
``O + s D`` passes through p when X is a fixed point of::

    F(X) = r_xy(d_z(X)) - d_xy(X),     r_xy(z) = O_xy + (z - O_z) / D_z D_xy

(the ray's horizontal position at the surface height, less the horizontal displacement).

Value: damped Newton iterations ``X <- X + (I - J)^-1 (F(X) - X)`` with ``J = dF/dX`` (2 x 2
per point; F and J from one pass over the waves, eight sums of the same sines), from ``xy0``
until each point's step is below ``tolerance``, at most ``max_iterations`` times. Points
that have converged stop moving, so a point's path is its own: it does not depend on its
neighbours (nor on a ``vmap`` batch) beyond float rounding, which differs with the shape of
the buffer a point is evaluated in. Once few points still move, the loop continues on a
gathered buffer of those points only (see ``_iterate``), so the cost follows the points
that are still moving rather than the slowest one. A Newton step is at most
``NEWTON_DAMPING`` plain fixed-point steps ``F(X) - X`` long, and near a fold (``det(I - J) <
MIN_CONDITION``) the plain step is taken instead. The last Newton step leaves an error of
about the square of ``tolerance``: the result is the fixed point itself, not "k
iterations", and it is the same under ``jit`` and eager calls (under ``vmap`` to float rounding). Steps are cut short at
the edge of the disc of radius ``sum(h w) (1 + cot(incidence))`` around ``xy0``, where every
hit must lie; a path that crosses a fold is flagged: it may end at any of several hits. (Measured on a
steep close view -- 12 waves of kh up to 0.3, camera 8 m, pitch 35 deg, 32 x 40 pixels, float64:
every pixel converged, median 5 and at most 24 iterations; the plain fixed-point iteration
left 182 of 1280 pixels unconverged after 200.)

Derivative (forward and reverse mode): the implicit function theorem at the hit,
``dX = (I - J)^-1 dF`` with ``dF`` the derivative of F at fixed X with respect to the waves,
the ray, ``t`` and the weights -- exact at the fixed point, and cheap (one 2 x 2 solve per
point, no differentiation through the loop).

Where the fixed point is not a unique, attracting solution -- a ray grazing a crest near the
horizon, where it meets the surface more than once (occlusion is not modelled) -- the
iteration does not converge, or converges where ``I - J`` is nearly singular (a height change
of a micrometre moves the hit by metres). Those points are flagged ``converged=False``:
their ``xy`` is the last iterate, not a surface point, and carries no derivative. Callers
report the flag (:attr:`jaxocean.render.Geometry.converged`) and fits leave such pixels out.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import surface
from jaxocean._math import sincos
from jaxocean.waves import Waves, wavenumber

__all__ = ["Hits", "refine_hits", "hit_residual", "hit_reach", "step", "DEFAULT_TOLERANCE", "MAX_ITERATIONS",
           "MIN_CONDITION"]

DEFAULT_TOLERANCE = 1e-4  # m: a point has converged when its fixed-point step is this small
MAX_ITERATIONS = 32
NEWTON_DAMPING = 10.0  # a Newton step is at most this many fixed-point steps long
# det(I - J) below this: the hit moves by more than ~1 / MIN_CONDITION times the ray's own
# change -- the fixed point is near a fold (grazing ray), flagged as not unique
MIN_CONDITION = 0.05
# the loop's buffer shrinks by this factor when at most 1 / COMPACTION of its points still
# move, down to MIN_COMPACTED points (see _iterate)
COMPACTION = 4
MIN_COMPACTED = 64


class Hits(NamedTuple):
    """Refined ray-surface hits (see the module docstring)."""

    xy: jax.Array
    converged: jax.Array
    iterations: jax.Array


def _ray_point_at_height(origin, direction, z):
    s = (z - origin[..., 2]) / direction[..., 2]
    return origin[..., :2] + s[..., None] * direction[..., :2]


def step(waves: Waves, origin, direction, xy, t, weights):
    """The fixed-point map F(X) (see the module docstring), ``(..., 2)`` [m]."""
    d = surface.displacement(waves, xy, t, weights)
    return _ray_point_at_height(origin, direction, d[..., 2]) - d[..., :2]


def hit_residual(waves: Waves, origin, direction, xy, t, weights=None):
    """Horizontal distance [m] between the surface point p(xy, t) and its pixel ray, taken at
    the point's own height: zero when ``xy`` is a hit."""
    return jnp.linalg.norm(step(waves, origin, direction, xy, t, weights) - xy, axis=-1)


def hit_reach(waves: Waves, direction, weights=None):
    """Radius [m] of the disc around a ray's plane hit in which every hit of the ray lies:
    ``sum(h w) (1 + cot(incidence))`` -- the surface point is within ``sum(h w)`` of the mean
    plane vertically and of its rest position horizontally. ``direction (..., 3)`` unit rays
    going down; ``weights`` the displacement weights, ``(..., N)`` or ``(N,)`` (None: all 1)."""
    amplitude = jnp.abs(waves.amplitude) if weights is None else jnp.abs(waves.amplitude) * weights
    down = jnp.maximum(-direction[..., 2], jnp.finfo(direction.dtype).tiny)
    cot = jnp.linalg.norm(direction[..., :2], axis=-1) / down
    return jnp.sum(amplitude, axis=-1) * (1.0 + cot)


def _step_jacobian(waves, origin, direction, xy, t, weights):
    """``F(X)`` and ``J = dF/dX`` per point from one pass over the waves: ``(..., 2)`` and the
    columns ``(dF/dx, dF/dy)``.

    With s = D_xy / D_z (the ray's horizontal run per unit of height), ``dF/dX = s (grad d_z)^T
    - d(d_xy)/dX``: the gradient of d_z is (B_x, B_y) = sum w h k (cos theta, sin theta) sin psi
    and ``-d(d_xy)/dX`` is the symmetric [[A_xx, A_xy], [A_xy, A_yy]] = sum w h k k^ k^^T cos psi
    -- the same sines and cosines as the displacement, so F and J are eight sums of one
    ``sincos`` of the phases (two products ``(..., N) x (N, 4)``), not a displacement and two
    JVPs of it (measured 2.8-4.4 ms against 34-48 ms at 128^2, N = 60, float32).
    """
    k = wavenumber(waves)
    h, c, s = waves.amplitude, jnp.cos(waves.theta), jnp.sin(waves.theta)
    hk = h * k
    sin_psi, cos_psi = sincos(surface.phase(waves, xy, t))
    if weights is not None:
        sin_psi, cos_psi = sin_psi * weights, cos_psi * weights
    a = jnp.dot(cos_psi, jnp.stack([h, hk * c * c, hk * c * s, hk * s * s], -1))  # d_z, A_xx, A_xy, A_yy
    b = jnp.dot(sin_psi, jnp.stack([h * c, h * s, hk * c, hk * s], -1))  # d_x, d_y, B_x, B_y
    slope = direction[..., :2] / direction[..., 2:]
    value = _ray_point_at_height(origin, direction, a[..., 0]) - b[..., :2]
    jx = jnp.stack([slope[..., 0] * b[..., 2] + a[..., 1], slope[..., 1] * b[..., 2] + a[..., 2]], -1)
    jy = jnp.stack([slope[..., 0] * b[..., 3] + a[..., 2], slope[..., 1] * b[..., 3] + a[..., 3]], -1)
    return value, jx, jy


def _solve_2x2(jx, jy, rhs):
    """``(I - J)^-1 rhs`` per point and ``det(I - J)``; J's columns ``jx, jy``."""
    a, c = 1.0 - jx[..., 0], -jx[..., 1]  # first column of I - J
    b, d = -jy[..., 0], 1.0 - jy[..., 1]  # second column
    det = a * d - b * c
    safe = jnp.where(jnp.abs(det) > 0, det, 1.0)
    x = (d * rhs[..., 0] - b * rhs[..., 1]) / safe
    y = (a * rhs[..., 1] - c * rhs[..., 0]) / safe
    return jnp.stack([x, y], -1), det


def _fraction_inside(offset, delta, radius):
    """The largest ``a`` in [0, 1] with ``|offset + a delta| <= radius`` (``|offset| <= radius``)."""
    b2 = jnp.sum(delta * delta, axis=-1)
    ab = jnp.sum(offset * delta, axis=-1)
    c = jnp.sum(offset * offset, axis=-1) - radius * radius  # <= 0 inside
    root = (-ab + jnp.sqrt(jnp.maximum(ab * ab - b2 * c, 0.0))) / jnp.maximum(b2, jnp.finfo(b2.dtype).tiny)
    return jnp.clip(root, 0.0, 1.0)


def _compaction_sizes(n: int) -> tuple:
    """Buffer sizes of the loop's levels for ``n`` points: n, n / COMPACTION, ... down to
    MIN_COMPACTED (see :func:`_iterate`)."""
    sizes = [n]
    while sizes[-1] // COMPACTION >= MIN_COMPACTED:
        sizes.append(sizes[-1] // COMPACTION)
    return tuple(sizes)


def _iterate(waves, origin, direction, xy0, t, weights, active, max_iterations, tolerance):
    """The damped Newton loop (values only); see the module docstring.

    Points are flattened to ``(P,)``. The loop runs over all of them while more than
    ``P / COMPACTION`` are still moving; then the unfinished ones (in index order, padded
    with finished dummies) are gathered into a buffer of that size and the loop goes on
    there, and so on down the levels of :func:`_compaction_sizes`; results are scattered
    back. A point's iterates are its own arithmetic whatever buffer it is in, so this
    changes the cost and, through the float rounding of the sums over the waves in buffers
    of another shape, the value by a few ulps only (measured: converged hits within 1.5e-5 m
    of the uncompacted loop in float32, the same flags, on seven 128^2 views): the
    stragglers -- typically grazing rays whose Newton path cycles until the cap -- no longer
    keep every point's iteration going.
    """
    shape = xy0.shape[:-1]
    n = math.prod(shape)
    flat = lambda a: a.reshape((n,) + a.shape[len(shape):])  # noqa: E731
    eps = jnp.finfo(xy0.dtype).eps
    reach = hit_reach(waves, direction, weights) + tolerance
    flat_weights = None if weights is None else flat(jnp.broadcast_to(weights, shape + weights.shape[-1:]))
    points = (flat(origin), flat(direction), flat(xy0), flat(reach), flat_weights)

    def newton(xy, done, strayed, points):
        origin, direction, xy0, reach, weights = points
        value, jx, jy = _step_jacobian(waves, origin, direction, xy, t, weights)
        fixed = value - xy  # the plain fixed-point step
        newton, det = _solve_2x2(jx, jy, fixed)
        size, fixed_size = jnp.linalg.norm(newton, axis=-1), jnp.linalg.norm(fixed, axis=-1)
        # damping: Newton steps at most NEWTON_DAMPING fixed-point steps long; near a fold
        # (det(I - J) small) the fixed-point step itself
        scale = jnp.minimum(1.0, NEWTON_DAMPING * fixed_size / jnp.maximum(size, jnp.finfo(size.dtype).tiny))
        use_newton = det >= MIN_CONDITION
        delta = jnp.where(use_newton[..., None], newton * scale[..., None], fixed)
        # keep the path inside the disc where every hit lies: a step that would leave it is
        # cut short at its edge (same direction)
        delta = delta * _fraction_inside(xy - xy0, delta, reach)[..., None]
        new = xy + delta
        # float rounding of a hit far away (|X| ~ km in float32) is larger than a fixed
        # tolerance: the test allows a few ulps of the position on top
        small = use_newton & (jnp.linalg.norm(delta, axis=-1) <= tolerance + 64 * eps * jnp.linalg.norm(new, axis=-1))
        # a path that crossed a fold may end at any of several hits
        strayed = strayed | (~done & ~use_newton)
        return jnp.where(done[..., None], xy, new), done | small, strayed

    def solve(xy, done, strayed, k, points, sizes):
        """Iterate on this level's buffer until at most ``sizes[1]`` points are unfinished
        (none on the last level) or the cap; then hand them to the next level."""
        stop = sizes[1] if len(sizes) > 1 else 0

        def cond(state):
            _, done, _, k = state
            return (k < max_iterations) & (jnp.sum(~done) > stop)

        def body(state):
            xy, done, strayed, k = state
            return (*newton(xy, done, strayed, points), k + 1)

        xy, done, strayed, k = jax.lax.while_loop(cond, body, (xy, done, strayed, k))
        if len(sizes) == 1:
            return xy, done, strayed, k
        size = sizes[1]
        idx = jnp.nonzero(~done, size=size, fill_value=sizes[0])[0]  # out of range: padding
        pad = idx >= sizes[0]
        take = lambda a: None if a is None else jnp.take(a, idx, axis=0, mode="clip")  # noqa: E731
        sub = solve(take(xy), take(done) | pad, take(strayed), k, tuple(take(a) for a in points), sizes[1:])
        put = lambda a, b: a.at[idx].set(b, mode="drop")  # noqa: E731
        return put(xy, sub[0]), put(done, sub[1]), put(strayed, sub[2]), sub[3]

    start = (points[2], flat(~active), jnp.zeros((n,), bool), jnp.zeros((), jnp.int32))
    xy, done, strayed, k = solve(*start, points, _compaction_sizes(n))
    xy = xy.reshape(xy0.shape)
    _, jx, jy = _step_jacobian(waves, origin, direction, xy, t, weights)
    _, det = _solve_2x2(jx, jy, jnp.zeros_like(xy))
    return xy, (done & ~strayed).reshape(shape) & (det >= MIN_CONDITION), k


@jax.custom_jvp
def _implicit(xy, ok, waves, origin, direction, t, weights):
    """``xy`` (a converged fixed point) with the implicit-function derivative; see the docstring."""
    return xy


@_implicit.defjvp
def _implicit_jvp(primals, tangents):
    xy, ok, waves, origin, direction, t, weights = primals
    _, _, d_waves, d_origin, d_direction, d_t, d_weights = tangents

    def f(waves, origin, direction, t, weights):
        return step(waves, origin, direction, xy, t, weights)

    _, d_f = jax.jvp(f, (waves, origin, direction, t, weights), (d_waves, d_origin, d_direction, d_t, d_weights))
    _, jx, jy = _step_jacobian(waves, origin, direction, xy, t, weights)
    d_xy, _ = _solve_2x2(jx, jy, d_f)
    return xy, jnp.where(ok[..., None], d_xy, 0.0)


def refine_hits(waves: Waves, origin, direction, xy0, t, weights, *, active=None,
                max_iterations: int = MAX_ITERATIONS, tolerance: float = DEFAULT_TOLERANCE) -> Hits:
    """Rest positions whose displaced surface point lies on each ray (see the module docstring).

    ``active (...)`` bool (default: every point) marks the points to solve; the others keep
    ``xy0`` and count as converged. ``max_iterations`` (static) bounds the loop;
    ``tolerance`` [m] is the step below which a point has converged.
    """
    direction = jnp.asarray(direction)
    origin = jnp.broadcast_to(jnp.asarray(origin, direction.dtype), direction.shape)
    xy0 = jnp.asarray(xy0, direction.dtype)
    if origin.shape[:-1] != xy0.shape[:-1] or xy0.shape[-1] != 2 or direction.shape[-1] != 3:
        raise ValueError(f"refine_hits: direction (..., 3), xy0 (..., 2) and origin broadcastable to direction; "
                         f"got {direction.shape}, {xy0.shape}, {jnp.shape(origin)}")
    if int(max_iterations) < 1:
        raise ValueError(f"max_iterations must be >= 1; got {max_iterations}")
    active = jnp.ones(xy0.shape[:-1], bool) if active is None else jnp.broadcast_to(active, xy0.shape[:-1])
    t = jnp.asarray(t, direction.dtype)
    frozen = jax.lax.stop_gradient
    xy, ok, k = _iterate(frozen(waves), frozen(origin), frozen(direction), frozen(xy0), frozen(t),
                         frozen(weights), active, int(max_iterations), float(np.float64(tolerance)))
    return Hits(xy=_implicit(xy, ok, waves, origin, direction, t, weights), converged=ok | ~active, iterations=k)
