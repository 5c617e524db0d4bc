"""The photometric model of one frame given its geometry, common to the image fits.

Used by :mod:`jaxocean.fit.lighting` and :mod:`jaxocean.fit.camera`; public within the
package, not part of the user API (the user-facing names are re-exported by fit.lighting).

Protocol
--------
The image is linear in the three colours (Bruneton 2010, the renderer's own model)::

    model = sun_color * B_sun(sun) + sky_color * S + sea_color * E

* ``prepare(image (H, W, 3), normal (H, W, 3), slope_var (H, W, 2), camera, weight (H, W, 3),
  horizon_gradient) -> Data``: the lighting-independent per-pixel terms (``S``, ``E``, the
  view-only factors of the sun BRDF), so that a residual evaluates only the sun-dependent part.
* ``sun_term(data, direction (3,)) -> (H, W)``: ``B_sun`` for a unit sun vector.
* ``columns(data, direction)``, ``model(data, direction, colors)``,
  ``residual_from_model(data, model) -> (H W 3,)``: weighted residual over ``sqrt(sum w^2)``,
  so ``sum r^2`` is the weighted mean square error.
* ``project_colors(data, direction, fixed, free) -> {name: (3,)}``: variable projection,
  the non-negative least-squares colours of ``free`` for a sun direction
  (:func:`nnls_small`, exact for up to three unknowns, plus one refinement step).
* ``starts(data, init_pq, fixed, free, *, grid, n_starts, ...) -> (n_starts, 2)``: the
  lowest-loss candidate suns (glint estimate, its azimuth ray, mirror directions of the
  brightest glints, a sky grid, short solves on the rough pixels).
* ``varpro_bound(free)``: the variable-projection residual of the sun's ``(p, q)`` with a
  dense Jacobian (:func:`jaxocean.fit.solvers.dense_jacobian`); ``finish(data, pq, colors)
  -> Lighting``; ``host_map(fn, starts)``: ``fn`` over starts on the host (host solvers).
* ``sun_to_pq`` / ``pq_to_sun`` / ``pq_to_direction``: the sun's azimuthal-equidistant
  parameterisation ``(p, q) = (pi/2 - elevation) (cos azimuth, sin azimuth)``.

Angles in radians; arrays float32 or float64 (the image's dtype); every function is
jittable and differentiable.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import shading
from jaxocean._math import safe_norm, safe_normalize, smoothstep
from jaxocean.fit import solvers
from jaxocean.shading import Lighting

__all__ = ["COLOR_FIELDS", "Data", "prepare", "sun_term", "columns", "model", "residual_from_model",
           "project_colors", "nnls_small", "starts", "varpro_bound", "finish", "host_map", "sun_to_pq",
           "pq_to_sun", "pq_to_direction"]

COLOR_FIELDS = ("sun_color", "sky_color", "sea_color")

_HALF_PI = math.pi / 2
_GLINT_QUANTILE = 0.99
_GRID_PIXELS = 4096
_MIRROR_K = 32
_GRID_KEEP = 8
_ROUGH_STARTS = 2
_ROUGH_STEPS = 30
_ROUGH_GRID = 12


def sun_to_pq(azimuth, elevation):
    """Sun azimuth / elevation [rad] -> azimuthal-equidistant ``(p, q)``, shape ``(..., 2)``."""
    r = _HALF_PI - jnp.asarray(elevation)
    return jnp.stack([r * jnp.cos(azimuth), r * jnp.sin(azimuth)], axis=-1)


def pq_to_sun(pq):
    """``(p, q)`` -> ``(azimuth, elevation)`` [rad]; azimuth 0 at the zenith (where it is undefined)."""
    pq = jnp.asarray(pq)
    p, q = pq[..., 0], pq[..., 1]
    r = safe_norm(pq)
    ok = r > 0
    azimuth = jnp.where(ok, jnp.arctan2(jnp.where(ok, q, 0.0), jnp.where(ok, p, 1.0)), 0.0)
    return azimuth, _HALF_PI - r


def pq_to_direction(pq):
    """``(p, q)`` -> unit vector towards the sun, ``(..., 3)``: ``(sin r p/r, sin r q/r, cos r)``,
    ``r = |(p, q)|`` the zenith angle. Smooth everywhere, the zenith included."""
    pq = jnp.asarray(pq)
    r = safe_norm(pq)
    s = jnp.sinc(r / jnp.pi)  # sin(r) / r, exact and smooth at 0
    return jnp.concatenate([s[..., None] * pq, jnp.cos(r)[..., None]], axis=-1)


def nnls_small(gram, rhs, ridge=None):
    """Exact non-negative least squares ``min_{x >= 0} x^T G x - 2 b^T x`` for a few unknowns.

    ``gram (..., k, k)`` symmetric positive semi-definite, ``rhs (..., k)``; returns
    ``x (..., k)``. Every one of the ``2^k`` active sets is solved and the best feasible one
    kept -- exact (the NNLS optimum is the least-squares solution on its own support that
    also satisfies the KKT conditions; the set with the smallest KKT violation is taken),
    branch free, jittable, vmappable and differentiable almost everywhere. Columns are scaled to unit
    norm first; ``ridge`` (default ``8 eps``) keeps empty columns solvable (their ``x`` is 0).
    """
    gram, rhs = jnp.asarray(gram), jnp.asarray(rhs)
    k = gram.shape[-1]
    dtype = gram.dtype
    d, ridge = _column_scale(gram, ridge)
    gn = gram / (d[..., :, None] * d[..., None, :])
    bn = rhs / d
    masks = np.array([[(s >> i) & 1 for i in range(k)] for s in range(2**k)], dtype=bool)  # (2^k, k)
    m = jnp.asarray(masks, dtype)
    eye = jnp.eye(k, dtype=dtype)
    g_sub = gn[..., None, :, :] * m[:, :, None] * m[:, None, :] + eye * (1 - m)[:, :, None] + ridge * eye
    b_sub = bn[..., None, :] * m
    x_sub = _small_solve(g_sub, b_sub) * m  # (..., 2^k, k)
    # Pick the active set by its KKT violation, not by comparing objective values: those
    # differ by less than float32 resolution when a few bright pixels dominate |y|^2.
    # On the support x >= 0; off it the gradient G x - b >= 0 (no descent into x_i > 0).
    grad = jnp.einsum("...ij,...sj->...si", gn, x_sub) - bn[..., None, :]
    violation = jnp.sum(m * jnp.maximum(-x_sub, 0) + (1 - m) * jnp.maximum(-grad, 0), axis=-1)
    # ties (degenerate problems): prefer the larger support, i.e. the later subset index
    best = (2**k - 1) - jnp.argmin(violation[..., ::-1], axis=-1)
    x = jnp.take_along_axis(x_sub, best[..., None, None], axis=-2)[..., 0, :]
    return x / d


def _small_solve(a, b):
    """``a^-1 b`` for ``k <= 3`` by cofactors: elementwise arithmetic (cheap to compile and
    to differentiate, unlike a batched LU), fine for the well-conditioned scaled systems here."""
    k = a.shape[-1]
    if k == 1:
        return b / a[..., 0]
    if k == 2:
        det = a[..., 0, 0] * a[..., 1, 1] - a[..., 0, 1] * a[..., 1, 0]
        x0 = a[..., 1, 1] * b[..., 0] - a[..., 0, 1] * b[..., 1]
        x1 = a[..., 0, 0] * b[..., 1] - a[..., 1, 0] * b[..., 0]
        return jnp.stack([x0, x1], -1) / det[..., None]
    if k != 3:
        raise AssertionError(k)
    c0 = jnp.cross(a[..., 1, :], a[..., 2, :])  # rows of the adjugate's transpose
    c1 = jnp.cross(a[..., 2, :], a[..., 0, :])
    c2 = jnp.cross(a[..., 0, :], a[..., 1, :])
    det = jnp.sum(a[..., 0, :] * c0, -1)
    # a^-1 = [c0 c1 c2] / det (columns), so a^-1 b = (c0 b0 + c1 b1 + c2 b2) / det
    x = c0 * b[..., 0:1] + c1 * b[..., 1:2] + c2 * b[..., 2:3]
    return x / det[..., None]


class Data(NamedTuple):
    """Lighting-independent per-pixel terms, ``(H, W, ...)`` (sky pixels hold a flat sea
    seen from the zenith in the geometric fields, as in :func:`jaxocean.render.shade`).

    Besides the geometry, the view-only factors of the sun BRDF are precomputed (tangent
    frame, ``z_V``, Smith's ``Lambda_V``, the slope-pdf normalisation): the residual then
    evaluates only the sun-dependent half of :func:`jaxocean.shading.sun_radiance_factor`,
    which halves the compiled program and the work per step (tests check the two agree).
    """

    normal: jax.Array  # unit
    sx2: jax.Array  # clamped slope variances
    sy2: jax.Array
    view: jax.Array  # unit
    sea: jax.Array  # bool
    sky_term: jax.Array  # S
    sea_term: jax.Array  # E
    target: jax.Array  # (H, W, 3)
    weight: jax.Array  # (H, W, 3), w (residual = w (model - target))
    t_x: jax.Array  # tangent frame
    t_y: jax.Array
    z_view: jax.Array  # max(V.N, MIN_COSINE)
    lambda_view: jax.Array  # Smith Lambda of the view
    pdf_norm: jax.Array  # 1 / (2 pi sigma_x sigma_y)


def prepare(image, normal, slope_var, camera, weight, horizon_gradient) -> Data:
    dtype = image.dtype
    hit = cam.intersect_sea(camera)
    sea = hit.mask
    up = jnp.zeros(3, dtype).at[2].set(1.0)
    view = jnp.where(sea[..., None], hit.view.astype(dtype), up)
    # pixels the fit does not use may hold no geometry (NaN): a flat sea there, whose weight 0
    # then leaves it out (0 * NaN would be NaN); the used pixels keep theirs, NaN included,
    # so a traced NaN shows in the loss
    unused = ~jnp.any(weight > 0, axis=-1, keepdims=True)
    no_normal = unused & ~jnp.all(jnp.isfinite(normal), -1, keepdims=True)
    normal = jnp.where(sea[..., None] & ~no_normal, normal, up)
    slope_var = jnp.where(unused & ~jnp.all(jnp.isfinite(slope_var), -1, keepdims=True), 0.0, slope_var)
    normal, view = safe_normalize(normal), safe_normalize(view)
    floor = shading.MIN_SLOPE_VARIANCE_AXIS
    sx2 = jnp.maximum(slope_var[..., 0], floor)
    sy2 = jnp.maximum(slope_var[..., 1], floor)
    ones, zeros = jnp.ones(3, dtype), jnp.zeros(3, dtype)
    unit = Lighting(jnp.zeros((), dtype), jnp.ones((), dtype), ones, ones, zeros)
    terms = shading.shade_components(normal, sx2, sy2, view, unit, horizon_gradient=horizon_gradient)
    sky_weight = shading.sky_radiance(hit.direction.astype(dtype), unit, horizon_gradient=horizon_gradient)[..., 0]
    sky_term = jnp.where(sea, terms.fresnel * terms.reflected[..., 0], sky_weight)
    sea_term = jnp.where(sea, 1.0 - terms.fresnel, 0.0)
    t_x, t_y = shading.tangent_frame(normal)
    z_view = jnp.maximum(_dot(view, normal), shading.MIN_COSINE)
    lambda_view = shading.smith_lambda(z_view, shading.projected_variance(view, normal, sx2, sy2))
    pdf_norm = 1.0 / (2.0 * jnp.pi * jnp.sqrt(sx2 * sy2))
    return Data(normal, sx2, sy2, view, sea, sky_term, sea_term, image, weight, t_x, t_y, z_view, lambda_view,
                 pdf_norm)


def _dot(a, b):
    return jnp.sum(a * b, axis=-1)


def sun_term(data: Data, light):
    """``B_sun`` of every pixel for the unit sun vector ``light`` (3,): the sun-dependent part of
    :func:`jaxocean.shading.sun_radiance_factor` on the precomputed view terms (same formula,
    Bruneton 2010: ``F p / (4 z_V (H.N)^4 (1 + Lambda_L + Lambda_V))`` times the horizon fade)."""
    n, v = data.normal, data.view
    half = safe_normalize(light + v, fallback=n)
    h_n = jnp.maximum(_dot(half, n), shading.MIN_COSINE)
    zeta_x = _dot(half, data.t_x) / h_n
    zeta_y = _dot(half, data.t_y) / h_n
    slope_pdf = jnp.exp(-0.5 * (zeta_x**2 / data.sx2 + zeta_y**2 / data.sy2)) * data.pdf_norm
    fresnel = shading.FRESNEL_NORMAL + (1.0 - shading.FRESNEL_NORMAL) * jnp.clip(1.0 - _dot(v, half), 0.0, 1.0) ** 5
    z_light = jnp.maximum(_dot(light, n), shading.MIN_COSINE)
    a2 = _dot(light, data.t_x) ** 2
    b2 = _dot(light, data.t_y) ** 2
    total = a2 + b2
    ok = total > jnp.finfo(total.dtype).tiny
    var_light = jnp.where(ok, (data.sx2 * a2 + data.sy2 * b2) / jnp.where(ok, total, 1.0), 0.5 * (data.sx2 + data.sy2))
    shadowing = 1.0 + shading.smith_lambda(z_light, var_light) + data.lambda_view
    brdf = fresnel * slope_pdf / (4.0 * z_light * data.z_view * h_n**4 * shadowing)
    b = brdf * z_light * smoothstep(0.0, shading.SUN_HORIZON_FADE, light[..., 2])
    return jnp.where(data.sea, b, 0.0)


def columns(data: Data, direction):
    """``{name: (H, W)}`` of the three colour columns for a sun direction."""
    return {"sun_color": sun_term(data, direction), "sky_color": data.sky_term, "sea_color": data.sea_term}


def model(data: Data, direction, colors: dict):
    cols = columns(data, direction)
    return sum(cols[name][..., None] * colors[name] for name in COLOR_FIELDS)


def _norm2(data: Data):
    return jnp.sum(data.weight * data.weight)


def residual_from_model(data: Data, model):
    return (data.weight * (model - data.target)).reshape(-1) / jnp.sqrt(_norm2(data))


def project_colors(data: Data, direction, fixed: dict, free: tuple, cols=None):
    """Variable projection: the non-negative least-squares colours of ``free`` for a sun
    direction, the others held at ``fixed``. Returns ``{name: (3,)}`` for all three."""
    cols = columns(data, direction) if cols is None else cols
    known = sum((cols[n][..., None] * fixed[n] for n in COLOR_FIELDS if n not in free),
                jnp.zeros_like(data.target))
    colors = {n: fixed[n] for n in COLOR_FIELDS if n not in free}
    if not free:
        return colors
    a = jnp.stack([cols[n] for n in free], axis=-1).reshape(-1, len(free))  # (P, k)
    w2 = (data.weight * data.weight).reshape(-1, 3)  # (P, 3)
    y = (data.target - known).reshape(-1, 3)
    gram = jnp.einsum("pc,pi,pj->cij", w2, a, a)
    rhs = jnp.einsum("pc,pi,pc->ci", w2, a, y)
    x = nnls_small(gram, rhs)  # (3 channels, k)
    # One step of iterative refinement: the normal equations square the condition of the
    # columns (sky and sea terms are nearly collinear: cond(gram) up to 2e6), which in
    # float32 costs the colours 1e-5..7e-5 relative even at the exact sun direction; the
    # correction from the residual computed pixel by pixel brings that to 4e-7..6e-6
    # (measured on the 128^2 accuracy problems).
    r = y - jnp.einsum("pi,ci->pc", a, x)
    x = _refine_on_support(gram, x, jnp.einsum("pc,pi,pc->ci", w2, a, r))
    for i, n in enumerate(free):
        colors[n] = x[:, i]
    return colors


def _column_scale(gram, ridge=None):
    """Column norms ``d`` of a Gram matrix ``(..., k, k)`` (1 for empty columns) and the
    ridge (default ``8 eps``) of the unit-norm problem: the scaling of :func:`nnls_small`."""
    dtype = gram.dtype
    ridge = 8 * jnp.finfo(dtype).eps if ridge is None else ridge
    diag = jnp.diagonal(gram, axis1=-2, axis2=-1)
    ok = diag > jnp.finfo(dtype).tiny
    return jnp.where(ok, jnp.sqrt(jnp.where(ok, diag, 1.0)), 1.0), ridge


def _refine_on_support(gram, x, correction_rhs, ridge=None):
    """``max(x + G_S^-1 b_S, 0)`` on the support ``S`` of ``x`` (``x > 0``): one step of
    iterative refinement of a non-negative least-squares solution, ``b = A^T W (y - A x)``
    the gradient of the residual computed from the pixels. Columns scaled as in
    :func:`nnls_small`."""
    k = gram.shape[-1]
    dtype = gram.dtype
    d, ridge = _column_scale(gram, ridge)
    m = (x > 0).astype(dtype)
    eye = jnp.eye(k, dtype=dtype)
    g = gram / (d[..., :, None] * d[..., None, :]) * m[..., :, None] * m[..., None, :] + eye * (1 - m)[..., :, None] \
        + ridge * eye
    dx = _small_solve(g, correction_rhs / d * m) * m / d
    return jnp.maximum(x + dx, 0.0)


def _varpro_residual(pq, args):
    data, fixed, free = args[0], args[1], args[2]
    direction = pq_to_direction(pq)
    colors = project_colors(data, direction, fixed, free)
    return residual_from_model(data, model(data, direction, colors))


def _varpro_loss(data, pq, fixed, free):
    r = _varpro_residual(pq, (data, fixed, free))
    return jnp.sum(r * r)


def _glint_excess(data: Data):
    """``(excess (H, W), mirror (H, W, 3), candidate (H, W) bool)``: the radiance (summed over
    channels) that a sun-free fit (non-negative sky and sea colours) leaves unexplained, the
    mirror direction of the view about each pixel's normal, and the sea pixels whose mirror
    direction is above the horizon and whose pixel is finite."""
    sea_ok = data.sea & jnp.all(jnp.isfinite(data.target), axis=-1)
    target = jnp.where(sea_ok[..., None], data.target, 0.0)
    a = jnp.stack([data.sky_term, data.sea_term], -1).reshape(-1, 2)
    w2 = (data.weight * data.weight).reshape(-1, 3)
    y = target.reshape(-1, 3)
    x = nnls_small(jnp.einsum("pc,pi,pj->cij", w2, a, a), jnp.einsum("pc,pi,pc->ci", w2, a, y))  # (3, 2)
    excess = jnp.sum(target - (a @ x.T).reshape(target.shape), axis=-1)
    r = shading.reflect(data.view, data.normal)
    return excess, r, sea_ok & (r[..., 2] > 0)


def _direction_pq(direction, dtype):
    """Unit directions ``(..., 3)`` -> ``(p, q)`` with the elevation raised to at least 0.02 rad."""
    direction = direction.at[..., 2].set(jnp.maximum(direction[..., 2], 0.02))
    direction = safe_normalize(direction)
    el = jnp.arcsin(jnp.clip(direction[..., 2], -1.0, 1.0))
    az = jnp.arctan2(direction[..., 1], direction[..., 0])
    return sun_to_pq(az, el).astype(dtype)


def _glint_pq(data: Data, dtype):
    """Sun estimate from the glints: where a glint is, the sun lies in the mirror direction of
    the view about the macro normal. Glints are the pixels the sky and sea alone cannot
    explain: the excess over a sun-free fit (non-negative sky and sea colours), so bright
    sky reflections near the horizon do not count; saturated pixels do (they are glints)."""
    excess, r, cand = _glint_excess(data)
    e = jnp.where(cand, excess, jnp.nan)
    any_cand = jnp.any(cand)
    thr = jnp.maximum(jnp.nanquantile(jnp.where(any_cand, e, 0.0), _GLINT_QUANTILE), 0.0)
    w = jnp.where(e > thr, e - thr, 0.0)  # NaN compares False
    w = jnp.where(jnp.sum(w) > 0, w, jnp.where(e >= thr, 1.0, 0.0))
    return _direction_pq(safe_normalize(jnp.sum(w[..., None] * r, axis=(0, 1))), dtype)


def _mirror_pq(data: Data, k: int, dtype):
    """``(k, 2)`` candidates: the mirror directions of the ``k`` sea pixels with the largest
    glint excess, one each (not averaged). A glint pixel whose normal's slope lobe is
    narrow lies within about its slope spread of the sun, and the brightest glints are the
    narrowest (the lobe's peak scales as ``1 / sigma^2``)."""
    excess, r, cand = _glint_excess(data)
    score = jnp.where(cand, excess, -jnp.inf).reshape(-1)
    k = min(k, score.shape[0])
    _, idx = jax.lax.top_k(score, k)
    return _direction_pq(r.reshape(-1, 3)[idx], dtype)


_RAY_ELEVATIONS = np.radians(np.geomspace(0.2, 60.0, 16))


def _glint_ray(glint_pq, dtype):
    """Candidates along the glint estimate's azimuth (16 elevations, 0.2 to 60 deg,
    geometric). The glint's azimuth is accurate but its elevation is biased for a low sun
    (measured at 1 deg: estimates of 2.4-4.2 deg), where the glitter is a band a few pixels
    high at the horizon and the loss is flat until within ~0.5 deg of the sun; no cell of
    the sky grid lies that close to the horizon."""
    az, _ = pq_to_sun(glint_pq)
    el = jnp.asarray(_RAY_ELEVATIONS, dtype)
    return sun_to_pq(jnp.broadcast_to(az, el.shape), el).astype(dtype)


def _grid_pq(n: int, dtype):
    """A square ``n x n`` grid of (p, q) over the upper hemisphere (cells of pi / n rad)."""
    c = (np.arange(n) + 0.5) / n * math.pi - _HALF_PI
    p, q = np.meshgrid(c, c, indexing="ij")
    pq = np.stack([p.reshape(-1), q.reshape(-1)], -1)
    pq = pq[(pq**2).sum(-1) < (_HALF_PI * 0.999) ** 2]
    return jnp.asarray(pq, dtype)


def _subsample(data: Data, stride: int) -> Data:
    if stride == 1:
        return data
    return jax.tree.map(lambda a: a[::stride, ::stride], data)


def _losses(data, cands, fixed, free):
    """Variable-projection losses ``(n,)`` of candidate suns ``(n, 2)`` (non-finite -> inf)."""
    losses = jax.lax.map(lambda pq: _varpro_loss(data, pq, fixed, free), cands, batch_size=64)
    return jnp.where(jnp.isfinite(losses), losses, jnp.inf)


def _rough_only(data: Data, threshold) -> Data:
    """``data`` with the weight of every sea pixel smoother than ``threshold`` (slope variance
    ``sigma_x^2 + sigma_y^2``) set to 0; sky pixels keep theirs."""
    keep = ~data.sea | (data.sx2 + data.sy2 >= threshold)
    return data._replace(weight=jnp.where(keep[..., None], data.weight, 0.0))


def starts(data, init_pq, fixed, free, *, grid: int, n_starts: int, glint: bool = True,
            rough_levels: tuple = (), tol: tuple = (1e-6, 1e-6)):
    """The ``n_starts`` lowest-loss candidates (no gradient: the solution, not the path to it,
    is differentiated). Candidates: ``init``; with ``glint`` the glint estimate, the ray along
    its azimuth and the mirror directions of the brightest glints (scored on the full image);
    the best of the ``grid`` (scored on a sub-sampled image); and with ``rough_levels`` the
    answers of short solves on the rough pixels alone (module docstring, *Starts*)."""
    data, init_pq, fixed = jax.lax.stop_gradient((data, init_pq, fixed))
    dtype = data.target.dtype
    H, W = data.target.shape[:2]
    stride = max(1, math.ceil(math.sqrt(H * W / _GRID_PIXELS)))
    small = _subsample(data, stride)
    cands = [init_pq[None]]
    if glint:
        g = _glint_pq(data, dtype)
        cands.append(g[None])
        cands.append(_glint_ray(g, dtype))
        cands.append(_mirror_pq(data, _MIRROR_K, dtype))
    cands = jnp.concatenate(cands, 0)
    losses = _losses(data, cands, fixed, free)
    grid_pq = _grid_pq(grid, dtype) if grid > 0 else cands[:0]
    if grid > 0:
        best = grid_pq[jnp.argsort(_losses(small, grid_pq, fixed, free))[:_GRID_KEEP]]
        cands = jnp.concatenate([cands, best], 0)
        losses = jnp.concatenate([losses, _losses(data, best, fixed, free)], 0)
    if rough_levels:
        pool = jnp.concatenate([cands, _grid_pq(_ROUGH_GRID, dtype)], 0)

        def level(seeds, threshold):
            rough = _rough_only(data, threshold)
            trial = jnp.concatenate([seeds, pool], 0)
            starts = trial[jnp.argsort(_losses(_subsample(rough, stride), trial, fixed, free))[:_ROUGH_STARTS]]
            outs = jax.lax.map(lambda y0: solvers.solve("lm", varpro_bound(free), y0, (rough, fixed),
                                                        max_steps=_ROUGH_STEPS, rtol=tol[0], atol=tol[1]).params,
                               starts)
            return outs, outs

        seeds0 = jnp.broadcast_to(init_pq, (_ROUGH_STARTS, 2))
        _, found = jax.lax.scan(level, seeds0, jnp.asarray(rough_levels, dtype))
        found = _clip_pq(found.reshape(-1, 2))
        cands = jnp.concatenate([cands, found], 0)
        losses = jnp.concatenate([losses, _losses(data, found, fixed, free)], 0)
    order = jnp.argsort(losses)
    return cands[order[:n_starts]]


def _clip_pq(pq):
    """``(p, q)`` pulled inside the horizon circle (``|(p, q)| <= 0.999 pi / 2``)."""
    r = safe_norm(pq)
    limit = _HALF_PI * 0.999
    return jnp.where((r > limit)[..., None], pq * (limit / jnp.maximum(r, limit))[..., None], pq)


def finish(data, pq, colors):
    az, el = pq_to_sun(pq)
    dtype = data.target.dtype
    return Lighting(az.astype(dtype), el.astype(dtype), colors["sun_color"].astype(dtype),
                    colors["sky_color"].astype(dtype), colors["sea_color"].astype(dtype))


@functools.lru_cache(maxsize=None)
def varpro_bound(free: tuple):
    def fn(pq, args):
        return _varpro_residual(pq, (args[0], args[1], free))

    return solvers.dense_jacobian(fn)


def host_map(fn, starts):
    outs = [fn(starts[i]) for i in range(starts.shape[0])]
    return jax.tree.map(lambda *xs: jnp.stack(xs), *outs)
