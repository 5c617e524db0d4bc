"""The composed per-pixel renderer: ``geometry()``, ``shade()`` and ``render()``.

Protocol
--------
Raster-free: every pixel casts its camera ray, meets the sea, evaluates the hierarchical
geometry there and is shaded.

* ``geometry(waves, camera, t, ...) -> Geometry`` -- per pixel ``(H, W, ...)``: unit
  ``normal`` of the normal-level waves, ``roughness`` sigma^2 = sigma_x^2 + sigma_y^2 of the
  sub-pixel waves (clamped at ``shading.MIN_SLOPE_VARIANCE``), the anisotropic pair
  ``slope_variance (H, W, 2)``, the sea ``mask`` (False: sky), the rest position ``xy`` and
  world ``position`` of the hit, and the ``footprint`` [m]. What the geometry networks predict.
* ``shade(normal, roughness, camera, lighting, ...) -> (H, W, 3)`` linear RGB from geometry
  alone (the differentiable loss of the paper's eq. 3); sky pixels show the sky.
* ``render(waves, camera, lighting, t, ...)`` = ``shade(geometry(...))``; vmap it over frame
  times and over batches of scenes.

Waves ``(N,)``, camera a :class:`jaxocean.camera.Camera`, ``t`` a scalar [s].

Two evaluation paths give the same geometry:

* **rows** (no refinement): for a pinhole camera without roll (and the orthographic one) the
  sea-plane hits are affine along each image row and the footprint is constant along it,
  so the Nyquist weights are per row and the wave sums are the rank-N product of
  :func:`jaxocean.surface.on_rows` -- GEMM speed, no per-pixel sines.
* **points** (``refine > 0``): the ray hit is refined by fixed-point iteration against the
  displaced surface (horizontal and vertical displacement of the displacement-level
  waves), then the normal is evaluated per pixel at the refined rest position.

:func:`plan` inspects concrete inputs once and returns a static :class:`RenderPlan`: the
waves that matter at the image footprint (a wave whose normal and displacement weights are
zero over the whole image is evaluated for its roughness only: no sines) and the number of
refinement iterations the scene needs (zero when the largest displacement is under half a
pixel). Inside ``jit``/``vmap`` pass a plan explicitly, or get the full, plan-free path.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, shading, surface
from jaxocean._math import components, materialize_cotangent
from jaxocean.errors import check_finite, is_concrete
from jaxocean.waves import Waves, validate, wavenumber

__all__ = ["Geometry", "RenderPlan", "full_plan", "plan", "bucket_refine", "geometry", "shade", "render", "refine_hits",
           "hit_residual",
           "DEFAULT_REFINE_TOLERANCE", "MAX_REFINE_ITERATIONS"]

DEFAULT_REFINE_TOLERANCE = 1e-4  # m: how close the refined hit must be to the surface
MAX_REFINE_ITERATIONS = 32


class Geometry(NamedTuple):
    """Per-pixel hierarchical geometry, ``(H, W, ...)``."""

    normal: jnp.ndarray
    roughness: jnp.ndarray
    slope_variance: jnp.ndarray
    mask: jnp.ndarray
    xy: jnp.ndarray
    position: jnp.ndarray
    footprint: jnp.ndarray


class RenderPlan(NamedTuple):
    """Static evaluation plan: indices of the waves evaluated with sines, refinement iterations."""

    active: tuple
    refine: int


def full_plan(n_waves: int, refine: int = 0) -> RenderPlan:
    """Every one of ``n_waves`` waves evaluated (no skipping) with ``refine`` hit-refinement
    iterations: one static plan for every scene of that size, so the kernels compile once
    (datasets, fits, forecasts, benchmarks)."""
    return RenderPlan(active=tuple(range(int(n_waves))), refine=int(refine))


def _check_inputs(waves: Waves, camera):
    validate(waves)
    if waves.omega.ndim != 1:
        raise ValueError(f"render functions take Waves with leaves (N,); got {waves.omega.shape} (vmap batches)")
    cam.validate_camera(camera)


def plan(waves: Waves, camera, t=0.0, *, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX,
         grid_cell=None, tolerance=DEFAULT_REFINE_TOLERANCE, refine="auto", max_distance=cam.DEFAULT_MAX_DISTANCE):
    """The cheapest exact plan for rendering ``waves`` through ``camera`` (concrete inputs only).

    * ``active``: waves with a nonzero normal or displacement weight at some sea pixel.
    * ``refine``: 0 if the displacement-level waves shift every hit by less than half a
      footprint (bound: sum(h) (1 + cot(incidence))); otherwise the fewest fixed-point
      iterations whose worst hit residual at time ``t`` is within ``tolerance`` metres,
      measured, then rounded up to a power of two (:func:`bucket_refine`: the count is
      static, so views and times whose counts differ a little share one compilation), and
      capped at MAX_REFINE_ITERATIONS: where the ray grazes a crest the fixed point has
      several solutions and may not converge -- occlusion is not modelled.
    """
    _check_inputs(waves, camera)
    if not is_concrete(waves, camera):
        raise ValueError("render.plan needs concrete inputs; inside jit pass plan=RenderPlan(...) or plan=None")
    hit = cam.intersect_sea(camera, max_distance=max_distance)
    mask = np.asarray(hit.mask)
    if not mask.any():
        return RenderPlan(active=(), refine=0)
    fp = np.asarray(hit.footprint)[mask]
    ws = hierarchy.weights(waves, jnp.asarray([fp.min(), fp.max()]), n_min=n_min, n_max=n_max,
                           grid_cell=grid_cell)
    # weights are monotone in the footprint: the smallest footprint gives the largest weights
    w_disp, w_norm = np.asarray(ws.displacement[0]), np.asarray(ws.normal[0])
    active = tuple(int(i) for i in np.nonzero((w_disp > 0) | (w_norm > 0))[0])
    if refine != "auto":
        return RenderPlan(active=active, refine=int(refine))
    direction = np.asarray(hit.direction)[mask]
    cot = np.linalg.norm(direction[:, :2], axis=-1) / np.maximum(-direction[:, 2], 1e-6)
    shift = float(np.sum(np.asarray(waves.amplitude) * w_disp)) * (1.0 + cot)  # plane-hit error bound [m]
    if np.all(shift < 0.5 * fp):
        return RenderPlan(active=active, refine=0)
    # the analytic contraction bound of the fixed point is loose at oblique views, so measure:
    # iterate once up to the cap and take the first count whose worst residual meets tolerance
    residuals = np.asarray(_refine_residuals(waves, camera, jnp.asarray(t, waves.omega.dtype), grid_cell,
                                             n_min=n_min, n_max=n_max, max_distance=max_distance))
    ok = np.nonzero(residuals <= tolerance)[0]
    refine = int(ok[0]) + 1 if ok.size else MAX_REFINE_ITERATIONS
    return RenderPlan(active=active, refine=bucket_refine(refine))


def bucket_refine(count: int) -> int:
    """A refinement count rounded up to a power of two, at most MAX_REFINE_ITERATIONS (0 stays 0).

    The count is a static argument of the compiled renderer: rounding it up lets nearby
    cameras and frame times reuse one compilation (fit.camera's random starts measured 17-32
    iterations, each count compiled anew); more iterations of the contracting fixed point
    only bring the hits closer to the surface."""
    if count <= 0:
        return 0
    return min(1 << (int(count) - 1).bit_length(), MAX_REFINE_ITERATIONS)


_make_plan = plan  # geometry()'s `plan` argument shadows the function's name


@functools.partial(jax.jit, static_argnames=("n_min", "n_max", "max_distance"))
def _refine_residuals(waves, camera, t, grid_cell, *, n_min, n_max, max_distance):
    """Worst hit residual [m] over sea pixels after 1 .. MAX_REFINE_ITERATIONS iterations."""
    hit = cam.intersect_sea(camera, max_distance=max_distance)
    ws = hierarchy.weights(waves, hit.footprint, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
    origin, direction = _sea_rays(camera, hit)

    def step(xy, _):
        xy = _refine_step(waves, origin, direction, xy, t, ws.displacement)
        res = hit_residual(waves, origin, direction, xy, t, ws.displacement)
        return xy, jnp.max(jnp.where(hit.mask, res, 0.0))

    _, res = jax.lax.scan(step, hit.xy, None, length=MAX_REFINE_ITERATIONS)
    return res


def _select(waves: Waves, active):
    idx = np.asarray(active, dtype=np.int32)
    return jax.tree.map(lambda a: a[idx], waves)


def _sea_rays(camera, hit):
    """Ray origins ``(H, W, 3)`` and directions, sky rays replaced by a straight-down ray
    (first half of a double where: nothing divides by a ray's z ~ 0)."""
    origin, _ = cam.pixel_rays(camera)
    down = jnp.zeros(3, hit.direction.dtype).at[2].set(-1.0)
    direction = jnp.where(hit.mask[..., None], hit.direction, down)
    return jnp.broadcast_to(origin, direction.shape), direction


def _ray_point_at_height(origin, direction, z):
    s = (z - origin[..., 2]) / direction[..., 2]
    return origin[..., :2] + s[..., None] * direction[..., :2]


def _refine_step(waves, origin, direction, xy, t, weights):
    d = surface.displacement(waves, xy, t, weights)
    return _ray_point_at_height(origin, direction, d[..., 2]) - d[..., :2]


def hit_residual(waves: Waves, origin, direction, xy, t, weights=None):
    """Horizontal distance [m] between the surface point p(xy, t) and its pixel ray, taken at
    the point's own height: zero when the refined hit lies on the displaced surface."""
    d = surface.displacement(waves, xy, t, weights)
    p_xy = xy + d[..., :2]
    return jnp.linalg.norm(_ray_point_at_height(origin, direction, d[..., 2]) - p_xy, axis=-1)


def refine_hits(waves: Waves, origin, direction, xy0, t, weights, iterations: int):
    """Fixed-point refinement of rest positions X so that p(X, t) lies on each pixel ray.

    Iterates X <- r_xy(d_z(X)) - d_xy(X), with r the ray point at the height of the
    displaced surface. ``origin`` broadcastable to ``direction (..., 3)``; ``xy0 (..., 2)`` the
    plane hits; ``weights`` per-pixel displacement weights ``(..., N)``. Rays must go down
    (callers substitute a safe ray for sky pixels).
    """
    origin = jnp.broadcast_to(origin, direction.shape)
    xy, _ = jax.lax.scan(lambda xy, _: (_refine_step(waves, origin, direction, xy, t, weights), None), xy0, None,
                         length=iterations)
    return xy


@functools.partial(jax.jit, static_argnames=("n_min", "n_max", "active", "refine", "max_distance"))
def _geometry(waves, camera, t, grid_cell, *, n_min, n_max, active, refine, max_distance):
    return _geometry_at(waves, camera, t, grid_cell, cam.intersect_sea(camera, max_distance=max_distance),
                        n_min=n_min, n_max=n_max, active=active, refine=refine)


def _geometry_at(waves, camera, t, grid_cell, hit, *, n_min, n_max, active, refine, positions=True):
    """The body of :func:`geometry` given the camera's sea hits (shared with :func:`_shade_at`
    inside :func:`render`'s single compiled function). ``positions=False`` (the renderer,
    which shades normals only): on the rows path the three displacement sums are not
    computed (5 of the product's 8 channels) and ``position`` is None."""
    H, W = camera.resolution
    mask = hit.mask
    evaluated = waves if active is None else _select(waves, active)
    if refine == 0:
        # rows path: footprint and plane hits per row (exact for the no-roll pinhole and the
        # orthographic camera); the centre column stands for the row
        fp_row = hit.footprint[:, W // 2]
        ws_all = hierarchy.weights(waves, fp_row, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
        ws = hierarchy.weights(evaluated, fp_row, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
        origin = hit.xy[:, 0]
        step = (hit.xy[:, -1] - hit.xy[:, 0]) / max(W - 1, 1)
        rows = surface.on_rows(evaluated, origin, step, W, t, ws, with_displacement=positions)
        sx2, sy2 = surface.slope_variance(waves, ws_all)
        slope_var = jnp.broadcast_to(jnp.stack([sx2, sy2], -1)[:, None, :], (H, W, 2))
        xy, disp, normal = hit.xy, rows.displacement, rows.normal
    else:
        ws_all = hierarchy.weights(waves, hit.footprint, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
        ws = hierarchy.weights(evaluated, hit.footprint, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
        origin, direction = _sea_rays(camera, hit)
        xy = refine_hits(evaluated, origin, direction, hit.xy, t, ws.displacement, refine)
        disp = surface.displacement(evaluated, xy, t, ws)
        normal = surface.normal(evaluated, xy, t, ws)
        sx2, sy2 = surface.slope_variance(waves, ws_all)
        slope_var = jnp.stack([sx2, sy2], -1)
    position = None if disp is None else disp + jnp.concatenate([xy, jnp.zeros_like(xy[..., :1])], -1)
    roughness = jnp.maximum(slope_var[..., 0] + slope_var[..., 1], shading.MIN_SLOPE_VARIANCE)
    return Geometry(normal=normal, roughness=roughness, slope_variance=slope_var, mask=mask, xy=xy,
                    position=position, footprint=hit.footprint)


def _static_plan(waves, camera, t, plan, n_min, n_max, grid_cell, max_distance):
    """``(active, refine)`` static arguments from a ``plan`` argument (see :func:`geometry`)."""
    if isinstance(plan, str):
        if plan != "auto":
            raise ValueError(f"plan must be 'auto', None or a RenderPlan; got {plan!r}")
        plan = _make_plan(waves, camera, t, n_min=n_min, n_max=n_max, grid_cell=grid_cell,
                          max_distance=max_distance) if is_concrete(waves, camera, t) else None
    active, refine = (None, 0) if plan is None else (tuple(plan.active), int(plan.refine))
    if active is not None and len(active) == 0:
        active = (0,)  # nothing resolvable: evaluate one wave (its weights are zero) to keep shapes static
    return active, refine


def geometry(waves: Waves, camera, t, *, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX,
             grid_cell=None, plan: RenderPlan | None | str = "auto", max_distance=cam.DEFAULT_MAX_DISTANCE) -> Geometry:
    """Per-pixel hierarchical geometry of ``waves`` at time ``t`` seen by ``camera``.

    ``plan``: ``"auto"`` (default) computes :func:`plan` when the inputs are concrete and
    uses the full, unrefined path under tracing; ``None`` forces the full unrefined path; a
    :class:`RenderPlan` is used as given (static: recompiles per distinct plan).
    """
    _check_inputs(waves, camera)
    active, refine = _static_plan(waves, camera, t, plan, n_min, n_max, grid_cell, max_distance)
    return _geometry(waves, camera, jnp.asarray(t, waves.omega.dtype), grid_cell, n_min=n_min, n_max=n_max,
                     active=active, refine=refine, max_distance=max_distance)


@functools.partial(jax.jit, static_argnames=("max_distance",))
def _shade(normal, slope_var, camera, lighting, horizon_gradient, *, max_distance):
    return _shade_at(normal, slope_var, cam.intersect_sea(camera, max_distance=max_distance), lighting,
                     horizon_gradient)


def _shade_at(normal, slope_var, hit, lighting, horizon_gradient):
    """The body of :func:`shade` given the camera's sea hits."""
    mask = hit.mask
    # per-pixel components (see shading.pixel_terms): one elementwise pass for the whole
    # pixel model. Double where: sky pixels are shaded as a flat sea seen from the zenith,
    # then discarded.
    # (components: per-pixel vectors split so that reverse mode does not pad and add them)
    up = (0.0, 0.0, 1.0)
    view = tuple(jnp.where(mask, c, u) for c, u in zip(components(hit.view), up))
    nrm = tuple(jnp.where(mask, c, u) for c, u in zip(components(normal), up))
    sun, fresnel, reflected = shading.pixel_terms(nrm, *components(slope_var), view, lighting, horizon_gradient)
    # image = sun_color * B_sun + F_mean sky(R) + (1 - F_mean) sea_color on the sea, sky(D) on
    # the sky: linear in the three colours, so a sum of three rank-1 products (per-pixel
    # coefficient x colour). Dots make XLA compute the pixel model once, not once per output
    # channel; and separate (H W, 1) x (1, 3) dots, not one (H W, 3) x (3, 3) dot of stacked
    # coefficients, since the stack's fusion re-evaluates the shared per-pixel terms (normal,
    # tangent frame) in each of its three slices (measured 1.4 ms against 3.4 ms at 256^2)
    coeffs = (jnp.where(mask, sun, 0.0),
              jnp.where(mask, fresnel * reflected, shading.sky_weight(hit.direction[..., 2], horizon_gradient)),
              jnp.where(mask, 1.0 - fresnel, 0.0))
    colors = (lighting.sun_color, lighting.sky_color, lighting.sea_color)
    H, W = mask.shape
    image = sum(jnp.dot(c.reshape(H * W, 1), jnp.reshape(color, (1, 3))) for c, color in zip(coeffs, colors))
    return image.reshape(H, W, 3)


def shade(normal, roughness, camera, lighting, *, slope_variance=None, horizon_gradient=0.0,
          max_distance=cam.DEFAULT_MAX_DISTANCE):
    """Linear RGB image ``(H, W, 3)`` from per-pixel geometry alone.

    ``normal (H, W, 3)``, ``roughness (H, W)`` = sigma^2, isotropic unless the anisotropic
    ``slope_variance (H, W, 2)`` is given (then ``roughness`` is ignored). Views and the
    sky mask come from ``camera``.
    """
    cam.validate_camera(camera)
    shading.validate_lighting(lighting)
    shading._check_horizon_gradient(horizon_gradient)
    H, W = camera.resolution
    normal = jnp.asarray(normal)
    if normal.shape != (H, W, 3):
        raise ValueError(f"normal must be (H, W, 3) = {(H, W, 3)} for this camera; got {normal.shape}")
    if slope_variance is None:
        roughness = jnp.asarray(roughness, normal.dtype)
        if roughness.shape != (H, W):
            raise ValueError(f"roughness must be (H, W) = {(H, W)}; got {roughness.shape}")
        check_finite(roughness, "roughness")
        slope_variance = jnp.stack([roughness, roughness], -1) * 0.5
    else:
        slope_variance = jnp.asarray(slope_variance, normal.dtype)
        if slope_variance.shape != (H, W, 2):
            raise ValueError(f"slope_variance must be (H, W, 2) = {(H, W, 2)}; got {slope_variance.shape}")
        check_finite(slope_variance, "slope_variance")
    check_finite(normal, "normal")
    return _shade(normal, slope_variance, camera, lighting, jnp.asarray(horizon_gradient, normal.dtype),
                  max_distance=max_distance)


def render(waves: Waves, camera, lighting, t, *, horizon_gradient=0.0, n_min=hierarchy.DEFAULT_N_MIN,
           n_max=hierarchy.DEFAULT_N_MAX, grid_cell=None, plan: RenderPlan | None | str = "auto",
           max_distance=cam.DEFAULT_MAX_DISTANCE):
    """Linear RGB image ``(H, W, 3)``: ``shade(geometry(waves, camera, t))``, one compiled
    function (the camera's ray-sea intersection computed once for both). Keyword
    arguments as in :func:`geometry` and :func:`shade`."""
    _check_inputs(waves, camera)
    shading.validate_lighting(lighting)
    shading._check_horizon_gradient(horizon_gradient)
    active, refine = _static_plan(waves, camera, t, plan, n_min, n_max, grid_cell, max_distance)
    dtype = waves.omega.dtype
    return _render(waves, camera, lighting, jnp.asarray(t, dtype), jnp.asarray(horizon_gradient, dtype), grid_cell,
                   n_min=n_min, n_max=n_max, active=active, refine=refine, max_distance=max_distance)


@functools.partial(jax.jit, static_argnames=("n_min", "n_max", "active", "refine", "max_distance"))
def _render(waves, camera, lighting, t, horizon_gradient, grid_cell, *, n_min, n_max, active, refine, max_distance):
    hit = cam.intersect_sea(camera, max_distance=max_distance)
    geo = _geometry_at(waves, camera, t, grid_cell, hit, n_min=n_min, n_max=n_max, active=active, refine=refine,
                       positions=False)
    # in reverse mode the normal's cotangent computed once (see materialize_cotangent)
    return _shade_at(materialize_cotangent(geo.normal), geo.slope_variance, hit, lighting, horizon_gradient)
