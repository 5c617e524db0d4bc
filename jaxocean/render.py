"""The composed per-pixel renderer: ``geometry()``, ``shade()`` and ``render()``.

Protocol
--------
Raster-free: every pixel casts its camera ray, meets the sea, evaluates the hierarchical
geometry there and is shaded.

* ``geometry(waves, camera, t, ...) -> Geometry`` -- per pixel ``(H, W, ...)``: unit
  ``normal`` of the normal-level waves, ``roughness`` sigma^2 = sigma_x^2 + sigma_y^2 of the
  sub-pixel waves (clamped at ``shading.MIN_SLOPE_VARIANCE``), the anisotropic pair
  ``slope_variance (H, W, 2)``, the sea ``mask`` (False: sky), the rest position ``xy`` and
  world ``position`` of the hit, and the ``footprint`` [m]; on sky pixels ``normal`` is
  (0, 0, 1) and ``position`` the plane point (xy, 0). What the geometry networks predict.
* ``shade(normal, roughness, camera, lighting, ...) -> (H, W, 3)`` linear RGB from geometry
  alone (the differentiable loss of the paper's eq. 3); sky pixels show the sky.
* ``render(waves, camera, lighting, t, ...)`` = ``shade(geometry(...))``; vmap it over frame
  times and over batches of scenes.

Waves ``(N,)``, camera a :class:`jaxocean.camera.Camera`, ``t`` a scalar [s].

Two evaluation paths:

* **rows** (``RenderPlan.refine == 0``): the geometry at each pixel's mean-sea-plane hit. For
  a pinhole camera without roll (and the orthographic one) those hits are affine along each
  image row and the footprint is constant along it, so the Nyquist weights are per row and
  the wave sums are the rank-N product of :func:`jaxocean.surface.on_rows` -- GEMM speed, no
  per-pixel sines. Exact where the displacement-level waves move the hit by less than half a
  footprint; otherwise an approximation.
* **hits** (``refine > 0``): each pixel's hit on the displaced surface, the converged fixed
  point of :func:`jaxocean.raycast.refine_hits` (at most ``refine`` iterations, derivative by
  the implicit function theorem); the normal is evaluated per pixel there.
  ``Geometry.converged`` is False where a ray grazes a crest and the hit is not unique.

``plan="auto"`` (the default) picks the rows path when the displacement-level waves shift
every hit by less than half a footprint (bound: sum(h) (1 + cot(incidence)), a function of
the waves and the camera, not of the time) and the hits path otherwise. With concrete inputs
:func:`plan` makes that choice on the host and also skips the waves whose weights vanish
over the whole image (they are evaluated for their roughness only: no sines); under
``jit``/``vmap``/``grad`` the same choice is made inside the compiled function
(``lax.cond``; under ``vmap`` both paths are evaluated and one selected) and every wave is
evaluated. Either way the value is the same function of the inputs: a traced call equals the
eager one, and gradients are those of the image that is returned. Pass an explicit
:class:`RenderPlan` (static) to fix the path, e.g. one plan for a whole dataset or fit.
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, raycast, shading, surface
from jaxocean._math import components, materialize_cotangent
from jaxocean.errors import check_finite, check_values, is_concrete, is_integer
from jaxocean.raycast import hit_residual, refine_hits
from jaxocean.waves import Waves, check_phase_precision, validate

__all__ = ["Geometry", "RenderPlan", "full_plan", "plan", "needs_refinement", "geometry", "shade", "render",
           "refine_hits", "hit_residual", "MAX_REFINE_ITERATIONS"]

MAX_REFINE_ITERATIONS = raycast.MAX_ITERATIONS  # the cap plan() gives the hits path


class Geometry(NamedTuple):
    """Per-pixel hierarchical geometry, ``(H, W, ...)``.

    ``converged`` is False on sea pixels whose ray-surface hit did not converge to a unique
    fixed point (a ray grazing a crest, see :mod:`jaxocean.raycast`): their values come from
    the last iterate and carry no derivative through the hit. It is True on the rows path and
    on sky pixels; the pixels a fit can use are ``mask & converged``.
    """

    normal: jnp.ndarray
    roughness: jnp.ndarray
    slope_variance: jnp.ndarray
    mask: jnp.ndarray
    xy: jnp.ndarray
    position: jnp.ndarray
    footprint: jnp.ndarray
    converged: jnp.ndarray | None = None


class RenderPlan(NamedTuple):
    """Static evaluation plan: indices of the waves evaluated with sines, and ``refine``: 0 for
    the rows path (plane hits), else the hits path with at most ``refine`` fixed-point
    iterations (the hits are converged, not a fixed count: see :mod:`jaxocean.raycast`)."""

    active: tuple
    refine: int


def full_plan(n_waves: int, refine: int = 0) -> RenderPlan:
    """Every one of ``n_waves`` waves evaluated (no skipping) with ``refine`` hit-refinement
    iterations: one static plan for every scene of that size, so the kernels compile once
    (datasets, fits, forecasts, benchmarks)."""
    if not is_integer(n_waves, 1) or not is_integer(refine, 0):
        raise ValueError(f"full_plan needs n_waves >= 1 and refine >= 0, integers; got n_waves={n_waves!r}, "
                         f"refine={refine!r}")
    return RenderPlan(active=tuple(range(int(n_waves))), refine=int(refine))


def _check_inputs(waves: Waves, camera):
    validate(waves)
    if waves.omega.ndim != 1:
        raise ValueError(f"render functions take Waves with leaves (N,); got {waves.omega.shape} (vmap batches)")
    if waves.omega.shape[0] == 0:
        raise ValueError("render functions need at least one wave; a flat sea is one wave of zero amplitude")
    cam.validate_camera(camera)
    wave_dtype, camera_dtype = jnp.result_type(waves.omega), cam.compute_dtype(camera)
    if jnp.finfo(wave_dtype).bits > jnp.finfo(camera_dtype).bits:
        # the hits' fixed-point iteration carries the camera's precision
        raise ValueError(f"waves are {wave_dtype} but the camera is {camera_dtype}: make the camera with "
                         f"dtype={wave_dtype} (or the waves {camera_dtype})")


def plan(waves: Waves, camera, t=0.0, *, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX,
         grid_cell=None, refine="auto", max_distance=cam.DEFAULT_MAX_DISTANCE):
    """The cheapest exact plan for rendering ``waves`` through ``camera`` (concrete inputs only).

    * ``active``: waves with a nonzero normal or displacement weight at some sea pixel (the
      others contribute zero; skipping them changes nothing but the time).
    * ``refine``: 0 (rows path) where :func:`needs_refinement` is False, else
      ``MAX_REFINE_ITERATIONS`` -- the same choice ``plan="auto"`` makes under tracing. An int
      ``refine`` is used as given. ``t`` is accepted (and checked) for symmetry with
      :func:`geometry`: the choice does not depend on the time.
    """
    _check_inputs(waves, camera)
    _check_time(waves, t)
    if not is_concrete(waves, camera):
        raise ValueError("render.plan needs concrete inputs; inside jit pass plan=RenderPlan(...), plan=None "
                         "or plan='auto' (chosen inside the compiled function)")
    # concrete inputs inside an outer trace (jit over the time only, say): computed now, not
    # staged into the caller's function, so that the plan is the same as an eager call's
    with jax.ensure_compile_time_eval():
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
        needed = bool(_needs_refinement(waves, hit, grid_cell, n_min=n_min, n_max=n_max))
    return RenderPlan(active=active, refine=MAX_REFINE_ITERATIONS if needed else 0)


def needs_refinement(waves: Waves, camera, *, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX,
                     grid_cell=None, max_distance=cam.DEFAULT_MAX_DISTANCE):
    """True (a bool array, traceable) when the displacement-level waves can move some sea
    pixel's hit by half its footprint or more: bound sum(h w_disp) (1 + cot(incidence)), the
    weights taken at the image's smallest footprint. The rule ``plan="auto"`` follows."""
    _check_inputs(waves, camera)
    return _needs_refinement(waves, cam.intersect_sea(camera, max_distance=max_distance), grid_cell,
                             n_min=n_min, n_max=n_max)


@functools.partial(jax.jit, static_argnames=("n_min", "n_max"))
def _needs_refinement(waves, hit, grid_cell, *, n_min, n_max):
    mask = hit.mask
    fp_min = jnp.min(jnp.where(mask, hit.footprint, jnp.inf))
    fp_min = jnp.where(jnp.isfinite(fp_min), fp_min, 1.0)  # no sea pixel: nothing to refine
    w_disp = hierarchy.weights(waves, fp_min[None], n_min=n_min, n_max=n_max, grid_cell=grid_cell).displacement[0]
    shift = raycast.hit_reach(waves, hit.direction, w_disp)  # plane-hit error bound [m]
    return jnp.any(mask & (shift >= 0.5 * hit.footprint))


_make_plan = plan  # geometry()'s `plan` argument shadows the function's name


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


@functools.partial(jax.jit, static_argnames=("n_min", "n_max", "active", "refine", "max_distance"))
def _geometry(waves, camera, t, grid_cell, *, n_min, n_max, active, refine, max_distance):
    return _geometry_at(waves, camera, t, grid_cell, cam.intersect_sea(camera, max_distance=max_distance),
                        n_min=n_min, n_max=n_max, active=active, refine=refine)


def _geometry_at(waves, camera, t, grid_cell, hit, *, n_min, n_max, active, refine, positions=True):
    """The body of :func:`geometry` given the camera's sea hits (shared with :func:`_shade_at`
    inside :func:`render`'s single compiled function). ``refine``: 0 (rows path), a positive
    iteration cap (hits path) or ``"auto"`` (the choice of :func:`needs_refinement`, made
    here). ``positions=False`` (the renderer, which shades normals only): the displacement is
    not computed (on the rows path 5 of the product's 8 channels; on the hits path the
    per-pixel displacement at the hit) and ``position`` is None."""
    kw = dict(n_min=n_min, n_max=n_max, active=active, positions=positions)
    if refine == "auto":
        needed = _needs_refinement(waves, hit, grid_cell, n_min=n_min, n_max=n_max)
        rows = functools.partial(_rows_geometry, **kw)
        hits = functools.partial(_hits_geometry, refine=MAX_REFINE_ITERATIONS, **kw)
        return jax.lax.cond(needed, hits, rows, waves, camera, t, grid_cell, hit)
    if refine == 0:
        return _rows_geometry(waves, camera, t, grid_cell, hit, **kw)
    return _hits_geometry(waves, camera, t, grid_cell, hit, refine=refine, **kw)


def _rows_geometry(waves, camera, t, grid_cell, hit, *, n_min, n_max, active, positions):
    """Rows path: footprint and plane hits per row (exact for the no-roll pinhole and the
    orthographic camera); the centre column stands for the row."""
    H, W = camera.resolution
    evaluated = waves if active is None else _select(waves, active)
    fp_row = hit.footprint[:, W // 2]
    ws_all = hierarchy.weights(waves, fp_row, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
    ws = hierarchy.weights(evaluated, fp_row, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
    origin = hit.xy[:, 0]
    step = (hit.xy[:, -1] - hit.xy[:, 0]) / max(W - 1, 1)
    rows = surface.on_rows(evaluated, origin, step, W, t, ws, with_displacement=positions)
    sx2, sy2 = surface.slope_variance(waves, ws_all)
    slope_var = jnp.broadcast_to(jnp.stack([sx2, sy2], -1)[:, None, :], (H, W, 2))
    return _assemble(hit, hit.xy, rows.displacement, rows.normal, slope_var, jnp.ones(hit.mask.shape, bool))


def _hits_geometry(waves, camera, t, grid_cell, hit, *, n_min, n_max, active, positions, refine):
    """Hits path: each pixel's converged hit on the displaced surface, geometry per pixel."""
    evaluated = waves if active is None else _select(waves, active)
    ws_all = hierarchy.weights(waves, hit.footprint, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
    ws = hierarchy.weights(evaluated, hit.footprint, n_min=n_min, n_max=n_max, grid_cell=grid_cell)
    origin, direction = _sea_rays(camera, hit)
    hits = refine_hits(evaluated, origin, direction, hit.xy, t, ws.displacement, active=hit.mask,
                       max_iterations=refine)
    disp = surface.displacement(evaluated, hits.xy, t, ws) if positions else None
    normal = surface.normal(evaluated, hits.xy, t, ws)
    sx2, sy2 = surface.slope_variance(waves, ws_all)
    return _assemble(hit, hits.xy, disp, normal, jnp.stack([sx2, sy2], -1), hits.converged)


def _assemble(hit, xy, disp, normal, slope_var, converged):
    # sky pixels get the flat sea's normal and the plane point: what the surface would give
    # there depends on which waves a plan evaluates, and an eager call (whose plan may drop
    # waves no sea pixel shows) must equal a traced one
    sea = hit.mask[..., None]
    plane = jnp.concatenate([xy, jnp.zeros_like(xy[..., :1])], -1)
    normal = jnp.where(sea, normal, jnp.asarray([0.0, 0.0, 1.0], normal.dtype))
    position = None if disp is None else jnp.where(sea, disp + plane, plane)
    roughness = jnp.maximum(slope_var[..., 0] + slope_var[..., 1], shading.MIN_SLOPE_VARIANCE)
    return Geometry(normal=normal, roughness=roughness, slope_variance=slope_var, mask=hit.mask, xy=xy,
                    position=position, footprint=hit.footprint, converged=converged)


def _check_time(waves, t):
    """Raise unless ``t`` is one time [s]: a scalar, and where concrete finite and near
    enough ``t = 0`` for the phases ``omega t`` in the waves' dtype
    (:func:`jaxocean.waves.check_phase_precision`)."""
    if jnp.ndim(t) != 0:
        raise ValueError(f"t must be one time [s] (a scalar); got shape {jnp.shape(t)}: vmap over times to render "
                         "several frames")
    check_finite(t, "t")
    check_phase_precision(waves, t)


def _static_plan(waves, camera, t, plan, n_min, n_max, grid_cell, max_distance):
    """``(active, refine)`` static arguments from a ``plan`` argument (see :func:`geometry`),
    after checking the time ``t`` (:func:`_check_time`)."""
    _check_time(waves, t)
    if grid_cell is not None:
        check_values(jnp.asarray(grid_cell) > 0, "grid_cell must be > 0 m (the geometry grid's cell size)", grid_cell)
    if isinstance(plan, str):
        if plan != "auto":
            raise ValueError(f"plan must be 'auto', None or a RenderPlan; got {plan!r}")
        if not is_concrete(waves, camera, grid_cell):
            return None, "auto"  # the same rule, applied inside the compiled function
        plan = _make_plan(waves, camera, t, n_min=n_min, n_max=n_max, grid_cell=grid_cell,
                          max_distance=max_distance)
    elif plan is not None and not isinstance(plan, RenderPlan):
        raise ValueError(f"plan must be 'auto', None or a RenderPlan; got {plan!r}")
    active, refine = (None, 0) if plan is None else (tuple(plan.active), int(plan.refine))
    if refine < 0:
        raise ValueError(f"RenderPlan.refine must be >= 0; got {refine}")
    n_waves = waves.omega.shape[0]
    if active is not None and any(not 0 <= int(i) < n_waves for i in active):
        raise ValueError(f"RenderPlan.active must index the {n_waves} waves (0 to {n_waves - 1}); got {active}")
    if active is not None and len(active) == 0:
        active = (0,)  # nothing resolvable: evaluate one wave (its weights are zero) to keep shapes static
    return active, refine


def geometry(waves: Waves, camera, t, *, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX,
             grid_cell=None, plan: RenderPlan | None | str = "auto", max_distance=cam.DEFAULT_MAX_DISTANCE) -> Geometry:
    """Per-pixel hierarchical geometry of ``waves`` at time ``t`` seen by ``camera``.

    ``plan``: ``"auto"`` (default) chooses the path by :func:`needs_refinement` -- on the
    host with concrete inputs (:func:`plan`, which also skips vanishing waves), inside the
    compiled function under tracing: the same value either way; ``None`` forces the rows
    path with every wave; a :class:`RenderPlan` is used as given (static: recompiles per
    distinct plan).
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
    sky mask come from ``camera``. Normals that are not unit vectors (within
    ``shading.UNIT_NORMAL_TOLERANCE``) or point down, and negative variances, are errors
    (concrete inputs); below
    ``shading.MIN_SLOPE_VARIANCE_AXIS`` per axis the shading uses that floor.
    """
    cam.validate_camera(camera)
    shading.validate_lighting(lighting)
    shading.check_horizon_gradient(horizon_gradient)
    H, W = camera.resolution
    normal = jnp.asarray(normal)
    if normal.shape != (H, W, 3):
        raise ValueError(f"normal must be (H, W, 3) = {(H, W, 3)} for this camera; got {normal.shape}")
    if slope_variance is None:
        if roughness is None:
            raise ValueError("shade needs roughness (H, W) or slope_variance (H, W, 2); got neither")
        roughness = jnp.asarray(roughness, normal.dtype)
        if roughness.shape != (H, W):
            raise ValueError(f"roughness must be (H, W) = {(H, W)}; got {roughness.shape}")
        check_finite(roughness, "roughness")
        check_values(roughness >= 0, "roughness (slope variance) must be >= 0", roughness)
        slope_variance = jnp.stack([roughness, roughness], -1) * 0.5
    else:
        slope_variance = jnp.asarray(slope_variance, normal.dtype)
        if slope_variance.shape != (H, W, 2):
            raise ValueError(f"slope_variance must be (H, W, 2) = {(H, W, 2)}; got {slope_variance.shape}")
        check_finite(slope_variance, "slope_variance")
        check_values(slope_variance >= 0, "slope_variance must be >= 0", slope_variance)
    check_finite(normal, "normal")
    shading.check_unit_normals(normal, "normal", hint=": an image or a zero vector is no normal")
    if is_concrete(normal):
        check_values(normal[..., 2] >= 0.0, "normal must point up (n_z >= 0: the sea's side)", normal[..., 2])
    return _shade(normal, slope_variance, camera, lighting, jnp.asarray(horizon_gradient, normal.dtype),
                  max_distance=max_distance)


def render(waves: Waves, camera, lighting, t, *, horizon_gradient=0.0, n_min=hierarchy.DEFAULT_N_MIN,
           n_max=hierarchy.DEFAULT_N_MAX, grid_cell=None, plan: RenderPlan | None | str = "auto",
           max_distance=cam.DEFAULT_MAX_DISTANCE, with_geometry: bool = False):
    """Linear RGB image ``(H, W, 3)``: ``shade(geometry(waves, camera, t))``, one compiled
    function (the camera's ray-sea intersection computed once for both). Keyword
    arguments as in :func:`geometry` and :func:`shade`. ``with_geometry=True`` returns
    ``(image, Geometry)`` (``position`` None on the rows path) -- among it the per-pixel
    ``converged`` flag of the hits, which says where the image is not exact."""
    _check_inputs(waves, camera)
    shading.validate_lighting(lighting)
    shading.check_horizon_gradient(horizon_gradient)
    active, refine = _static_plan(waves, camera, t, plan, n_min, n_max, grid_cell, max_distance)
    dtype = waves.omega.dtype
    image, geo = _render(waves, camera, lighting, jnp.asarray(t, dtype), jnp.asarray(horizon_gradient, dtype),
                         grid_cell, n_min=n_min, n_max=n_max, active=active, refine=refine,
                         max_distance=max_distance)
    return (image, geo) if with_geometry else image


@functools.partial(jax.jit, static_argnames=("n_min", "n_max", "active", "refine", "max_distance"))
def _render(waves, camera, lighting, t, horizon_gradient, grid_cell, *, n_min, n_max, active, refine, max_distance):
    hit = cam.intersect_sea(camera, max_distance=max_distance)
    geo = _geometry_at(waves, camera, t, grid_cell, hit, n_min=n_min, n_max=n_max, active=active, refine=refine,
                       positions=False)
    # in reverse mode the normal's cotangent computed once (see materialize_cotangent)
    image = _shade_at(materialize_cotangent(geo.normal), geo.slope_variance, hit, lighting, horizon_gradient)
    return image, geo._replace(position=None)
