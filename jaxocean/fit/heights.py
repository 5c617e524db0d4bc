"""Surface heights from a normal map: perspective normal integration.

A normal map fixes the surface's slopes at each pixel's hit, and the hit moves along the
pixel's ray with the height it meets the surface at. Both are linear in the heights: a ray
from the camera with unit direction ``d`` meets the level ``z`` at
``xy(z) = xy0 + z q`` with ``xy0`` its mean-sea-plane hit and ``q = d_xy / d_z``, and the
surface between neighbouring pixels ``i, j`` rises by their mean slope ``s = -n_xy / n_z``
times the distance between their hits::

    z_j - z_i = s_ij . (xy_j(z_j) - xy_i(z_i))

:func:`heights` solves these equations over every pair of valid neighbours (rows and
columns) in least squares, by conjugate gradients on the normal equations (matrix-free; jit,
vmap and reverse mode through ``jax.scipy.sparse.linalg.cg``). Normals say nothing about
the level: the heights are fixed to mean zero over the valid pixels weighted by
1 / footprint^2, so the nearest, finest-sampled sea sets it (a sea region cut off from the
rest by invalid pixels is held near zero by a weak ridge). The *mean level of the window*
is therefore lost -- over a view shorter than the longest waves it moves with them --
and so is the hits' shift that level causes along the rays (``q`` times it).

Measured on the eight Table 2 dataset scenes (noise-free geometry, 128², 10 frames;
``experiments/height_integration.py``, ``experiments/WAVES.md``): where a pixel's footprint
is at most 0.5 m, heights to 0.03-1.2 cm rms after the level on six scenes and 3.2 cm on the
Hs 2.5 m scene; on the steepest (rms slope 0.31) they are off by 28 cm. On such a sea, seen
at a low angle, the faces toward the camera are sampled densely and those away from it
sparsely, so each pair's mean slope is biased and the heights tilt (the equations above
miss the true heights by +0.018 on average along the view). Farther out, where the pixels
no longer sample the resolved waves, the heights can drift by metres (2 m on the Hs 2.5 m
scene), which is why the level is set by the nearest sea. The level itself, which the
normals cannot give, was 0.04-0.25 m from the truth. 50-100 ms a frame on 2 CPU cores.

Protocol: ``heights(normals (..., H, W, 3), camera) -> HeightMap`` (a leading frame axis is
mapped over). Heights and positions in metres, world frame (z up, the mean sea plane z = 0).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxocean import camera as cam

#: smallest upward normal component a pixel may have to be integrated (a normal closer to
#: the horizontal gives no usable slope)
MIN_NORMAL_Z = 0.05
#: smallest cosine between a pixel's ray and its facet's normal for the pixel to be
#: integrated (a ray grazing its facet, near an occluding crest, has no stable hit)
MIN_INCIDENCE = 0.05
#: the weak ridge on every valid pixel's height, relative to the equations' mean weight
RIDGE = 1e-6


class HeightMap(NamedTuple):
    """Result of :func:`heights`; each field has the normals' leading axes.

    * ``z``         ``(..., H, W)`` surface height [m] at each pixel's hit, its level set
      by the nearest sea (mean zero over the valid pixels weighted by 1 / footprint^2);
      0 where not valid.
    * ``xy``        ``(..., H, W, 2)`` the hit's horizontal position [m] at that height
      (the plane hit where not valid).
    * ``valid``     ``(..., H, W)`` bool: a sea pixel with a finite normal whose ``n_z``
      exceeds :data:`MIN_NORMAL_Z` and whose ray meets its facet at a cosine above
      :data:`MIN_INCIDENCE`.
    * ``residual``  ``(...)`` rms misfit of the equations between neighbours, in slope
      units (height difference over the pixels' spacing; zero for normals of a surface the
      pixels sample finely).
    * ``converged`` ``(...)`` bool: the solver's relative residual reached its tolerance (False
      where no pixel was valid: nothing was integrated).
    """

    z: jax.Array
    xy: jax.Array
    valid: jax.Array
    residual: jax.Array
    converged: jax.Array


def heights(normals, camera, *, tol: float | None = None, max_iter: int | None = None) -> HeightMap:
    """Heights [m] at each pixel's hit from a unit normal map ``(..., H, W, 3)`` seen by
    ``camera`` (see the module docstring); invalid pixels (sky, non-finite normals, normals
    within :data:`MIN_NORMAL_Z` of the horizontal, rays grazing their facet) are left out.

    ``tol``: the conjugate gradients' relative residual (default 1e-10 in float64, 1e-5 in
    float32); ``max_iter``: its iteration cap (default ``10 (H + W)``: 128² needs about 1,000
    iterations).
    """
    normals = jnp.asarray(normals)
    H, W = (int(r) for r in camera.resolution)
    if normals.ndim < 3 or normals.shape[-3:] != (H, W, 3):
        raise ValueError(f"normals must have shape (..., {H}, {W}, 3) for a {H}x{W} camera; got {normals.shape}")
    if not jnp.issubdtype(normals.dtype, jnp.floating):
        raise ValueError(f"normals must be floating point; got {normals.dtype}")
    dtype = normals.dtype
    if tol is None:
        tol = 1e-10 if dtype == jnp.float64 else 1e-5
    if max_iter is None:
        max_iter = 10 * (H + W)
    if not (tol > 0 and int(max_iter) >= 1):
        raise ValueError(f"tol must be > 0 and max_iter >= 1; got {tol}, {max_iter}")
    hit = cam.intersect_sea(camera)
    _, direction = cam.pixel_rays(camera)
    sea = jnp.asarray(hit.mask)
    xy0 = jnp.asarray(hit.xy, dtype)
    d = jnp.asarray(direction, dtype)
    dz = jnp.where(sea, d[..., 2], -1.0)
    q = jnp.where(sea[..., None], d[..., :2] / dz[..., None], 0.0)
    lead = normals.shape[:-3]
    flat = normals.reshape((-1, H, W, 3))
    footprint = jnp.where(sea, jnp.asarray(hit.footprint, dtype), 1.0)
    out = _integrate_frames(flat, sea, xy0, d, q, footprint, tol=float(tol), max_iter=int(max_iter))
    return jax.tree.map(lambda a: a.reshape(lead + a.shape[1:]), out)


@functools.partial(jax.jit, static_argnames=("tol", "max_iter"))
def _integrate_frames(normals, sea, xy0, d, q, footprint, *, tol, max_iter):
    # one compiled solve per shape, eager or traced alike
    return jax.vmap(lambda n: _integrate(n, sea, xy0, d, q, footprint, tol, max_iter))(normals)


def _neighbour_pairs(ok, s, xy0, q, axis):
    """Coefficients ``(c_i, c_j, b)`` of the equations ``c_j z_j + c_i z_i = b`` between
    each pixel and its neighbour along ``axis`` (zero where either is not valid), the two
    slices that pick ``i`` and ``j``, and how many equations there are."""
    lo = [slice(None), slice(None)]
    hi = [slice(None), slice(None)]
    lo[axis], hi[axis] = slice(None, -1), slice(1, None)
    lo, hi = tuple(lo), tuple(hi)
    both = ok[lo] & ok[hi]
    slope = 0.5 * (s[lo] + s[hi])
    c_j = 1.0 - jnp.sum(slope * q[hi], -1)
    c_i = -(1.0 - jnp.sum(slope * q[lo], -1))
    b = jnp.sum(slope * (xy0[hi] - xy0[lo]), -1)
    # each equation in slope units (divided by the pair's plane-hit spacing): a far pair
    # spans metres of sea whose waves its two slopes do not sample
    spacing = jnp.linalg.norm(xy0[hi] - xy0[lo], axis=-1)
    w = jnp.where(both, 1.0 / jnp.where(both, jnp.maximum(spacing, 1e-6), 1.0), 0.0)
    return (c_i * w, c_j * w, b * w), (lo, hi), jnp.sum(both.astype(s.dtype))


def _integrate(normal, sea, xy0, d, q, footprint, tol, max_iter):
    finite = jnp.all(jnp.isfinite(normal), -1)
    n = jnp.where(finite[..., None], normal, jnp.asarray([0.0, 0.0, 1.0], normal.dtype))
    # a ray that grazes its facet meets it at a point its slope cannot place (the
    # linearisation's factor 1 - s.q = n.d / (n_z d_z) goes to zero)
    grazing = -jnp.sum(n * d, -1) < MIN_INCIDENCE
    ok = sea & finite & (n[..., 2] > MIN_NORMAL_Z) & ~grazing
    s = jnp.where(ok[..., None], -n[..., :2] / jnp.where(ok, n[..., 2], 1.0)[..., None], 0.0)
    pairs = [_neighbour_pairs(ok, s, xy0, q, axis) for axis in (0, 1)]
    okf = ok.astype(s.dtype)
    count = jnp.maximum(jnp.sum(okf), 1.0)

    def forward(z):
        return [c_i * z[lo] + c_j * z[hi] for (c_i, c_j, _), (lo, hi), _ in pairs]

    def adjoint(rs):
        out = jnp.zeros(ok.shape, s.dtype)
        for ((c_i, c_j, _), (lo, hi), _), r in zip(pairs, rs):
            out = out.at[lo].add(c_i * r).at[hi].add(c_j * r)
        return out

    def normal_op(z):
        # the equations' normal matrix, the level's gauge (a rank-one term), the ridge and
        # identity rows on invalid pixels (their height stays 0)
        return adjoint(forward(z)) + gauge * jnp.sum(gauge * z) + ridge * okf * z + (1.0 - okf) * z

    # the level: mean zero weighted by 1 / footprint^2, i.e. set by the nearest, finest
    # sampled sea (measured: where a pixel's footprint exceeds ~1 m on a steep sea, the
    # slopes it sees are biased toward the camera and the far field drifts by metres)
    inv = okf / footprint ** 2
    gauge = inv / jnp.maximum(jnp.sum(inv), jnp.finfo(s.dtype).tiny)
    # a weak ridge fixes the level of sea pixels cut off from the rest (each would otherwise
    # be a free constant); RIDGE of the equations' mean weight biases no resolved mode
    mean_w = sum(jnp.sum(c_j ** 2) for (_, c_j, _), _, _ in pairs) / jnp.maximum(count, 1.0)
    ridge = RIDGE * mean_w
    rhs = adjoint([b for (_, _, b), _, _ in pairs])
    z, _ = jax.scipy.sparse.linalg.cg(normal_op, rhs, tol=tol, maxiter=max_iter)
    z = z * okf
    misfit = [r - b for r, ((_, _, b), _, _) in zip(forward(z), pairs)]
    n_eq = jnp.maximum(sum(count_ for _, _, count_ in pairs), 1.0)
    residual = jnp.sqrt(sum(jnp.sum(m ** 2) for m in misfit) / n_eq)
    rel = jnp.linalg.norm(normal_op(z) - rhs) / jnp.maximum(jnp.linalg.norm(rhs), jnp.finfo(s.dtype).tiny)
    # nothing to integrate (no valid pixel): nothing converged either
    return HeightMap(z, xy0 + z[..., None] * q, ok, residual, (rel <= 10.0 * tol) & jnp.any(ok))
