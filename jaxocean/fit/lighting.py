"""Image-based lighting fit: sun direction and the sun, sky and sea colours.

Protocol
--------
``lighting(image, geometry, camera, ...) -> LightingFit``

* ``image``     ``(H, W, 3)`` linear radiance (what an EXR frame stores), ``H, W`` the
  camera's resolution.
* ``geometry``  per-pixel geometry of the same frame: a :class:`jaxocean.render.Geometry`,
  a :class:`jaxocean.io.Frame` read from an EXR, or anything with ``normal (H, W, 3)``,
  ``roughness (H, W)`` and optionally ``slope_variance (H, W, 2)`` (anisotropic; else
  isotropic ``roughness / 2`` per axis, as :func:`jaxocean.render.shade`) and ``mask``.
* ``camera``    the :class:`jaxocean.camera.Camera` that saw it: views and the sea / sky
  mask come from it, exactly as in :func:`jaxocean.render.shade`.

The model is the renderer's own (:func:`jaxocean.shading.shade_components`)::

    image = sun_color * B_sun(L) + sky_color * S + sea_color * E

with ``B_sun`` the sun glitter per unit colour (it depends on the sun direction ``L`` only),
``S = F_mean * sky(R) / sky_color`` on the sea and the sky weight on sky pixels, and
``E = 1 - F_mean`` on the sea (0 on the sky). ``S`` and ``E`` do not depend on the lighting.

The loss is the weighted mean square of the residual in linear radiance,
``loss = sum(w^2 (model - image)^2) / sum(w^2)`` over pixels and channels, with
``w = weights * mask``. The default ``weights="display"`` is :func:`tonemap_weights` of the
observed image: the tone map's slope at the observed radiance, i.e. the Gauss-Newton
weighting of a loss on tone-mapped display values -- the image loss a viewer (and the
paper) sees, and the right weighting for noise added to display values -- while the problem
stays linear in the colours. It also keeps a few glints of radiance 1e3-1e4 from dominating
the fit: with uniform weights (``weights="uniform"``, plain linear MSE) float32 rounding at
those pixels costs the sky and sea colours 0.1-4% (measured), with display weights 1e-5.

Parameterisation (well conditioned, constraints built in):

* sun direction: azimuthal-equidistant coordinates ``(p, q) = (pi/2 - elevation) *
  (cos azimuth, sin azimuth)``: smooth through the zenith (where azimuth / elevation are
  singular), equally scaled in every direction; the horizon is the circle ``|(p, q)| = pi/2``.
* colours: non-negative. ``structure="varpro"`` solves them exactly (non-negative least
  squares) for every sun direction; ``structure="plain"`` carries them as parameters, as
  ``exp(s)`` for the unbounded solvers and raw with a lower bound 0 for ``lbfgsb``.

Structures (``structure=``):

* ``"varpro"`` (default): variable projection. For a sun direction the image is linear in
  the (fitted) colours; they are solved in closed form, per channel, by an exact
  non-negative least-squares solve of at most three unknowns (every active set
  enumerated), inside the residual. The solver then searches the two sun angles only.
  Starts (``glint=True``): the ``init`` sun; the *glint* estimate (the sea's mirror
  direction averaged over the brightest 1% of sea pixels, where the normal is the half
  vector) and a ray of elevations along its azimuth; the mirror directions of the 32
  brightest glint pixels, one candidate each; the 8 best points of a coarse grid over the
  sky hemisphere (scored on a sub-sampled image); and the answers of short LM solves on the
  *rough pixels alone* (slope variance >= 1e-2, then >= 1e-3), each started from the best
  candidates of its level. All are scored by the full image's loss; the best ``n_starts``
  are refined and the lowest loss wins.

  Why the rough-pixel solves: with the horizon in view the glitter is a band of far,
  rough pixels (the waves filtered into the slope variance), mostly saturated and
  censored, plus near, resolved pixels with lobes 0.003 rad wide. Those near pixels that
  are dark exclude every sun direction within a fraction of a degree of their mirror
  direction, and they surround the sun: the full loss is a well < 1 deg wide in a
  plateau that no grid or averaged glint estimate hits (measured on the horizon view of
  ``experiments/LIGHTING.md``: the glint estimate 5-17 deg off, the grid's best minimum 54
  deg off at loss 4e-4 against 1e-33 at the truth). On the rough pixels alone the model is
  still exact and the loss is smooth with a basin of many degrees; its minimum is the sun
  (noise-free), or next to it.
* ``"plain"``: every fitted parameter at once from ``init`` alone -- the formulation of the
  paper's Adam baseline, kept for comparison charts (it fails from most random starts).

Solvers: any name of :data:`jaxocean.fit.solvers.SOLVER_NAMES` (``"lm"`` by default).

Everything after validation is one jitted function of arrays (static: the names, sizes and
tolerances), so a fit compiles once per image size and configuration, and runs under
``jax.vmap`` over images, geometries, cameras or initial guesses with ``throw=False``
(results are arrays only; ``wall_time`` is NaN when traced).

Success: ``success`` is True only when the answer explains the data and the data determine
it -- every one of: the solver converged; the loss is finite and at most
:func:`jaxocean.fit._plausibility.loss_bound` ``= 1.5 noise^2 + 1e-6 x`` (weighted mean
square image) for the stated ``noise`` (``None``: noise-free; the rule of
:func:`jaxocean.fit.camera`); the sun is above the horizon; and every fitted field is
``determined``: its Gauss-Newton standard deviation at that noise (``std``, from ``J^T J``
of the residual in the fitted fields at the answer) is below 0.5 deg for the sun direction
(whose glitter must also carry >= 1e-8 of the weighted image energy) and below 10% of the
colour's brightest channel for a colour. A converged wrong stationary point (a local
minimum) leaves a loss far above the bound: it is a failure, not an answer. Otherwise
``success=False``; called eagerly with ``throw=True`` (the default) it raises
:class:`jaxocean.fit.solvers.FitError` carrying the result and saying why
(:func:`failure_message`): the residual and its bound, "sun direction undetermined: no sun
glitter in the image" (the colours that are determined are still fitted and flagged), an
undetermined colour, or the solver's own failure.

Geometry with a stated error (``normal_noise=`` [rad per tangent component], optionally
correlated over ``normal_correlation`` pixels): the fit is unchanged, and the error is
propagated through the shading at the answer by sampling. :data:`GEOMETRY_SAMPLES` fixed
draws (a fixed key: the result is a deterministic function of the inputs) of Gaussian
fields of that size and correlation tilt the normals, and for each:

* the model image is rendered; the draws' mean square change of it (``geometry_loss``)
  joins the image noise's in the bound, ``1.5 (noise^2 + geometry_loss) + 1e-6 x``;
* the model image of the given normals is refitted on the tilted normals (one Gauss-Newton
  step, :func:`jaxocean.fit._plausibility.gauss_newton_step`, exact for the linear
  colours; the glitter's slope variances widened by ``normal_noise^2``); the RMS of these
  shifts, bias included, is added in quadrature to each field's ``std``.

A bound loosened by a large normal error thus comes with a large ``std``: a sun the stated
geometry cannot place within 0.5 deg, or a colour it biases by 10%, is undetermined and the
fit fails. Success then says: this lighting explains the frame as well as geometry of the
stated accuracy allows, and that geometry determines every fitted field
(``experiments/LIGHTING.md``: 0 false successes in 144 synthetic fits with the error stated
as it is; errors that are smooth but stated as independent let wrong answers pass). The
per-field ``determined`` of a failed fit is not that safe: the darkest colour's bias is
underestimated at large errors (measured: sea colours 13-37% off flagged determined at
0.084 rad). Why sampling and not a JVP of the shading: the glitter lobes of resolved pixels
are narrower (0.003-0.05 rad) than a network's normal error (0.084 rad), and Fresnel and the
sky reflection are strongly curved at grazing views, so derivatives at the given normals
misjudge both the residual and the colours' bias (measured: with a first- plus second-order
propagation, overcast colours 30-43% off were flagged determined). Why a refit on tilted
normals and not draws around the given ones: normals with an error are rougher than the
truth, and the colours' bias has the opposite sign; and a draw moves a narrow glint by more
than its width, a change the sharp lobe's Jacobian barely sees (measured: a sun 74 deg off
flagged determined, std 0.07 deg).

Validation: shapes and names -> ``ValueError``; NaN/inf pixels, negative weights, an empty
selection, no sea pixel while sun or sea colour are fitted, and a geometry mask that
disagrees with the camera -> :class:`jaxocean.errors.InvalidValueError` (when concrete).
"""

from __future__ import annotations

import functools
import math
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import shading
from jaxocean._math import angle_between
from jaxocean.errors import InvalidValueError, check_nonnegative_number, is_concrete
from jaxocean.files import json_safe
from jaxocean.fit import _geometry_error as geometry_error
from jaxocean.fit import _image_inputs as inp
from jaxocean.fit import _photometry as ph
from jaxocean.fit import _plausibility, solvers
from jaxocean.fit._geometry_error import GEOMETRY_SAMPLES
from jaxocean.fit._image_inputs import tonemap_weights
from jaxocean.fit._photometry import COLOR_FIELDS, nnls_small, pq_to_direction, pq_to_sun, sun_to_pq
from jaxocean.fit.solvers import FitError
from jaxocean.shading import Lighting

__all__ = [
    "FIT_FIELDS",
    "COLOR_FIELDS",
    "DETERMINED_SUN_DEG",
    "DETERMINED_COLOR_REL",
    "glitter_share",
    "color_determined",
    "GEOMETRY_SAMPLES",
    "STRUCTURES",
    "COLOR_RANGES",
    "LightingFit",
    "lighting",
    "failure_message",
    "random_lighting",
    "tonemap_weights",
    "lighting_error",
    "sun_to_pq",
    "pq_to_sun",
    "pq_to_direction",
    "nnls_small",
    "fit_to_dict",
    "lighting_to_dict",
    "lighting_from_dict",
]

FIT_FIELDS = ("sun_direction", "sun_color", "sky_color", "sea_color")
STRUCTURES = ("varpro", "plain")

#: Ranges of the random colours of :func:`random_lighting` (log-uniform per channel), linear RGB.
COLOR_RANGES = {"sun_color": (1.0, 40.0), "sky_color": (0.05, 1.0), "sea_color": (0.002, 0.1)}

_HALF_PI = math.pi / 2
_ROUGH_LEVELS = (1e-2, 1e-3)
#: the sun is "seen" when its glitter carries at least this fraction of the (weighted) image
#: energy; below it (a sun behind the camera lights the sea through the BRDF's far tails,
#: 1e-20 and less) its direction is undetermined and the fit is reported as failed
SUN_SEEN = 1e-8
#: a fitted sun direction is determined when its standard deviation (RMS angle) is below this [deg]
DETERMINED_SUN_DEG = 0.5
#: a fitted colour is determined when every channel's standard deviation is below this
#: fraction of the colour's brightest channel
DETERMINED_COLOR_REL = 0.1


class LightingFit(NamedTuple):
    """Result of :func:`lighting` (a pytree of arrays; batched under ``vmap``).

    * ``lighting``  the fitted :class:`jaxocean.shading.Lighting` (fields not fitted keep
      their ``init`` values).
    * ``loss``      ``()`` weighted mean squared residual (linear radiance squared).
    * ``steps``     ``()`` int32 solver steps (of the winning start).
    * ``success``   ``()`` bool: the answer explains the data and every fitted field is
      determined (module docstring, *Success*): the solver converged, the loss is finite
      and at most ``loss_bound``, the sun is above the horizon, and ``determined`` holds for
      every fitted field.
    * ``wall_time`` ``()`` seconds of the call, compilation included on a first call (NaN
      when traced).
    * ``history``   ``(max_steps + 1,)`` loss after each step (winning start), or None
      unless ``history=True``.
    * ``determined`` ``{field: () bool}`` for every name of :data:`FIT_FIELDS`: the field's
      standard deviation at the stated noise is below :data:`DETERMINED_SUN_DEG` (sun
      direction; and its glitter carries at least 1e-8 of the weighted image energy) or
      :data:`DETERMINED_COLOR_REL` of the colour's brightest channel (every channel).
      Fields not fitted are given: True.
    * ``std``       ``{field: array}``: ``"sun_direction"`` ``()`` [rad], the RMS angular
      error ``sqrt(var p + var q)`` of the sun's ``(p, q)``; each colour ``(3,)`` [linear
      RGB]. Gauss-Newton standard deviations at the answer for noise ``noise`` (noise-free:
      the models' own consistency, ``LOSS_FLOOR``); see :mod:`jaxocean.fit._plausibility`.
      With ``normal_noise``: the RMS error the image noise and the stated normal error
      allow together (module docstring). 0 for fields not fitted.
    * ``loss_bound`` ``()`` the largest loss a right answer can leave at the stated noise.
    * ``glitter``   ``()`` the weighted energy of the fitted sun's glitter over that of the
      image (0: the sun lights no selected pixel).
    * ``geometry_loss`` ``()`` the loss the stated normal error (``normal_noise``) leaves at
      the answer, included in ``loss_bound`` (0 when no normal error is stated).
    """

    lighting: Lighting
    loss: jax.Array
    steps: jax.Array
    success: jax.Array
    wall_time: jax.Array
    history: Any = None
    determined: Any = None
    std: Any = None
    loss_bound: Any = None
    glitter: Any = None
    geometry_loss: Any = None


# --------------------------------------------------------------------------- parameterisation


# --------------------------------------------------------------------------- small NNLS


# --------------------------------------------------------------------------- data


# --------------------------------------------------------------------------- starts


# --------------------------------------------------------------------------- plain structure


def _plain_layout(fit: tuple):
    """Slices of the plain parameter vector: (p, q) then 3 per fitted colour."""
    layout, i = {}, 0
    if "sun_direction" in fit:
        layout["sun_direction"] = slice(0, 2)
        i = 2
    for n in COLOR_FIELDS:
        if n in fit:
            layout[n] = slice(i, i + 3)
            i += 3
    return layout, i


def _plain_unpack(y, init_pq, init_colors, fit, log_colors):
    layout, _ = _plain_layout(fit)
    pq = y[layout["sun_direction"]] if "sun_direction" in layout else init_pq
    colors = {}
    for n in COLOR_FIELDS:
        if n in layout:
            s = y[layout[n]]
            colors[n] = jnp.exp(jnp.clip(s, -60.0, 60.0)) if log_colors else s
        else:
            colors[n] = init_colors[n]
    return pq, colors


def _plain_pack(init_pq, init_colors, fit, log_colors, dtype):
    parts = []
    if "sun_direction" in fit:
        parts.append(init_pq)
    for n in COLOR_FIELDS:
        if n in fit:
            c = jnp.maximum(init_colors[n], 1e-6)
            parts.append(jnp.log(c) if log_colors else c)
    return jnp.concatenate(parts).astype(dtype)


def _plain_residual(y, args):
    data, init_pq, init_colors, fit, log_colors = args[0], args[1], args[2], args[3], args[4]
    pq, colors = _plain_unpack(y, init_pq, init_colors, fit, log_colors)
    return ph.residual_from_model(data, ph.model(data, pq_to_direction(pq), colors))


def _display_residual(y, args):
    data, init_pq, init_colors, observed, used, fit, exposure, mode = args
    pq, colors = _plain_unpack(y, init_pq, init_colors, fit, True)
    model = ph.model(data, pq_to_direction(pq), colors)
    r = used * (shading.tonemap(model, exposure, mode) - observed)
    return r.reshape(-1) / jnp.sqrt(jnp.sum(used))


@functools.lru_cache(maxsize=None)
def _display_bound(fit: tuple, exposure: float, mode: str):
    """The display residual of scaled parameters ``z = y / scale`` (``scale`` the last arg)."""
    def fn(z, args):
        return _display_residual(args[-1] * z, (*args[:-1], fit, exposure, mode))

    return solvers.dense_jacobian(fn)


def _refine_display(data, used, pq, colors, init_colors, st: _Static):
    """Stage 2 of ``space="display"``: every fitted parameter by least squares on the
    tone-mapped values, from the linear-space solution (unbiased under display noise)."""
    dtype = data.target.dtype
    observed = shading.tonemap(data.target, st.exposure, st.tonemap)
    # The colours are refined as logs. A channel the linear NNLS put on its bound (0) would
    # start at log(1e-6), where its Jacobian column vanishes (~1e-6) and the solver cannot
    # move it (measured: sea red stuck at 0, 80% off); start such channels at a tenth of the
    # colour's brightest channel instead.
    colors = {n: jnp.maximum(c, 0.1 * jnp.max(c)) if n in st.fit else c for n, c in colors.items()}
    y0 = _plain_pack(pq, colors, st.fit, True, dtype)
    args = (data, pq, colors, observed, used)
    # Scale every parameter so that its Jacobian column has unit norm at the start (the sun
    # angles' columns are ~100x the colours'). Without it the LM's damping, sized for the
    # angles, crawls along the colours: in float32 its trust region only grows when a step's
    # actual-to-predicted reduction ratio exceeds 0.99, which rounding of the loss rarely
    # lets through (measured at 64^2: 50 steps, loss down 1%, every refinement out of steps).
    _, jac = solvers.value_and_jacobian(lambda y, a: _display_residual(y, (*a, st.fit, st.exposure, st.tonemap)),
                                       jax.lax.stop_gradient(y0), jax.lax.stop_gradient(args))
    col = jnp.sqrt(jnp.sum(jac * jac, axis=0))
    scale = jnp.where(col > jnp.finfo(dtype).tiny / jnp.finfo(dtype).eps, 1.0 / jnp.where(col > 0, col, 1.0), 1.0)
    scale = jax.lax.stop_gradient(scale)
    out = solvers.solve(st.solver if solvers.get_solver(st.solver).traceable else "lm",
                        _display_bound(st.fit, st.exposure, st.tonemap), y0 / scale,
                        (*args, scale), max_steps=st.max_steps, rtol=st.rtol, atol=st.atol,
                        options=dict(st.options))
    out = out._replace(params=out.params * scale)
    pq2, colors2 = _plain_unpack(out.params, pq, colors, st.fit, True)
    colors2 = {n: colors2[n] if n in st.fit else init_colors[n] for n in COLOR_FIELDS}
    return pq2, colors2, out


class _Static(NamedTuple):
    """Hashable configuration of the jitted core."""

    fit: tuple
    free: tuple
    solver: str
    structure: str
    max_steps: int
    rtol: float
    atol: float
    grid: int
    n_starts: int
    glint: bool
    history: bool
    options: tuple
    space: str
    exposure: float
    tonemap: str
    geometry: bool = False  # a normal error is stated (normal_noise given)
    correlation: float = 0.0  # its correlation length [px]


def _final(data: ph.Data, pq, init_colors, free, colors=None):
    """One evaluation at the solution: colours (projected unless given), the loss
    ``0.5 |r|^2`` and the sun's glitter share (:func:`glitter_share`)."""
    direction = pq_to_direction(pq)
    cols = ph.columns(data, direction)
    if colors is None:
        colors = ph.project_colors(data, direction, init_colors, free, cols)
    model = sum(cols[name][..., None] * colors[name] for name in COLOR_FIELDS)
    r = ph.residual_from_model(data, model)
    return colors, 0.5 * jnp.sum(r * r), glitter_share(data, cols["sun_color"], colors["sun_color"])


def glitter_share(data: ph.Data, sun_column, sun_color):
    """The weighted energy of the sun's glitter ``sun_column (H, W) * sun_color (3,)`` (the
    sun's column of :func:`jaxocean.fit._photometry.columns` times its colour) over that of
    the image ``data.target``: the sun is seen above :data:`SUN_SEEN` (this fit's and the
    joint camera fit's rule)."""
    sun = sun_column[..., None] * sun_color
    return jnp.sum((data.weight * sun) ** 2) / jnp.sum((data.weight * data.target) ** 2)


def _solve_core(data: ph.Data, used, init: Lighting, st: _Static):
    """Everything after preparation; with ``space="display"`` a display-space refinement
    follows (its loss is the reported one, its steps are added)."""
    pq, colors, loss, steps, success, hist, glitter = _solve_linear(data, init, st)
    if st.space == "display":
        init_colors = {n: getattr(init, n).astype(data.target.dtype) for n in COLOR_FIELDS}
        pq, colors, out = _refine_display(data, used, pq, colors, init_colors, st)
        _, _, glitter = _final(data, pq, init_colors, st.free, colors)
        loss, steps, success = 2 * out.loss, steps + out.steps, success & out.success
    return pq, colors, loss, steps, success, hist, glitter


def _solve_linear(data: ph.Data, init: Lighting, st: _Static):
    """The linear-radiance fit: returns (pq, colors, loss, steps, success, history, glitter share)."""
    dtype = data.target.dtype
    init_pq = sun_to_pq(init.sun_azimuth, init.sun_elevation).astype(dtype)
    init_colors = {n: getattr(init, n).astype(dtype) for n in COLOR_FIELDS}
    options = dict(st.options)
    spec = solvers.get_solver(st.solver)

    if st.structure == "varpro":
        if "sun_direction" not in st.fit:
            colors, half_loss, glitter = _final(data, init_pq, init_colors, st.free)
            loss = 2 * half_loss
            hist = jnp.full((st.max_steps + 1,), loss) if st.history else None
            return init_pq, colors, loss, jnp.asarray(0, jnp.int32), jnp.isfinite(loss), hist, glitter
        starts = ph.starts(data, init_pq, init_colors, st.free, grid=st.grid, n_starts=st.n_starts, glint=st.glint,
                         rough_levels=_ROUGH_LEVELS if st.glint else (), tol=(st.rtol, st.atol))

        def run_one(y0):
            return solvers.solve(st.solver, ph.varpro_bound(st.free), y0, (data, init_colors),
                                 max_steps=st.max_steps, rtol=st.rtol, atol=st.atol,
                                 history=st.history, options=options)

        # lax.map, not vmap: one un-batched copy of the solver loop (batching its while loop
        # and conds doubles the compiled program); under an outer vmap it is batched anyway
        outs = jax.lax.map(run_one, starts) if spec.traceable else ph.host_map(run_one, starts)
        losses = jnp.where(jnp.isfinite(outs.loss), outs.loss, jnp.inf)
        best = jnp.argmin(losses)
        out = jax.tree.map(lambda a: a[best], outs)
        pq = out.params
        # the loss of the colours returned (not the solver's copy of it)
        colors, half_loss, glitter = _final(data, pq, init_colors, st.free)
        out = out._replace(loss=half_loss)
    else:
        log_colors = not spec.bounded
        y0 = _plain_pack(init_pq, init_colors, st.fit, log_colors, dtype)
        lower = upper = None
        if spec.bounded:
            layout, n = _plain_layout(st.fit)
            lower = jnp.zeros(n, dtype)
            upper = jnp.full(n, jnp.inf, dtype)
            if "sun_direction" in layout:
                lower = lower.at[0:2].set(-_HALF_PI)
                upper = upper.at[0:2].set(_HALF_PI)
        out = solvers.solve(st.solver, _plain_bound(st.fit, log_colors), y0, (data, init_pq, init_colors),
                            max_steps=st.max_steps, rtol=st.rtol, atol=st.atol, lower=lower, upper=upper,
                            history=st.history, options=options)
        pq, colors = _plain_unpack(out.params, init_pq, init_colors, st.fit, log_colors)
        _, _, glitter = _final(data, pq, init_colors, st.free, colors)
    # 0.5 |r|^2 -> weighted mean square
    loss = 2 * out.loss
    hist = None if out.history is None else 2 * out.history
    return pq, colors, loss, out.steps, out.success, hist, glitter


@functools.lru_cache(maxsize=None)
def _plain_bound(fit: tuple, log_colors: bool):
    def fn(y, args):
        return _plain_residual(y, (args[0], args[1], args[2], fit, log_colors))

    return solvers.dense_jacobian(fn)


def _normal_equations(data: ph.Data, pq, colors, st: _Static):
    """``(J^T J (P, P), J^T r (P,))`` of the linear-colour residual of the fitted fields at
    ``(pq, colors)`` (layout of :func:`_plain_layout`; built column by column, ``O(pixels)``
    memory)."""
    data, pq, colors = jax.lax.stop_gradient((data, pq, colors))
    dtype = data.target.dtype
    layout, n = _plain_layout(st.fit)
    parts = [pq] if "sun_direction" in layout else []
    parts += [colors[c] for c in COLOR_FIELDS if c in layout]
    y = jnp.concatenate(parts).astype(dtype)

    def residual(y):
        return _plain_residual(y, (data, pq, colors, st.fit, False))

    r, jvp = jax.linearize(residual, y)
    vjp = jax.linear_transpose(jvp, y)
    jtj = jax.lax.map(lambda e: vjp(jvp(e))[0], jnp.eye(n, dtype=dtype))
    return jtj, vjp(r)[0]


def _uncertainty(data: ph.Data, pq, colors, st: _Static, noise, shifts=None):
    """``(std, determined)`` dicts of the answer (see :class:`LightingFit`): Gauss-Newton
    standard deviations from ``J^T J`` of the linear-colour residual of the fitted fields at
    the stated noise; with ``shifts`` (:func:`jaxocean.fit._geometry_error.effect`) the RMS shift of each field
    under the stated normal error is added in quadrature, so that ``std`` is the RMS error
    the image noise and the geometry's error allow together."""
    dtype = data.target.dtype
    layout, _ = _plain_layout(st.fit)
    jtj, _ = _normal_equations(data, pq, colors, st)
    sd = _plausibility.parameter_std(jtj, _plausibility.noise_variance(data.target, data.weight, noise))
    if shifts is not None:
        ms = jnp.mean(shifts * shifts, axis=0)
        sd = jnp.where(ms > 0, jnp.sqrt(sd * sd + ms), sd)
    std, determined = {}, {}
    for name in FIT_FIELDS:
        if name not in layout:
            std[name] = jnp.zeros(() if name == "sun_direction" else (3,), dtype)
            determined[name] = jnp.asarray(True)
        elif name == "sun_direction":
            sl = sd[layout[name]]
            std[name] = jnp.sqrt(jnp.sum(sl * sl))
            determined[name] = std[name] < math.radians(DETERMINED_SUN_DEG)
        else:
            std[name] = sd[layout[name]]
            determined[name] = color_determined(std[name], colors[name])
    return std, determined


def color_determined(std, color):
    """Whether a fitted colour ``(3,)`` with standard deviations ``std (3,)`` is determined:
    every channel's below :data:`DETERMINED_COLOR_REL` of its brightest channel (this fit's
    and the joint camera fit's rule)."""
    return jnp.all(std < DETERMINED_COLOR_REL * jnp.max(color))


def _fit_arrays(image, normal, slope_var, camera, weight, used, horizon_gradient, init, noise, normal_noise,
                st: _Static):
    data = ph.prepare(image, normal, slope_var, camera, weight, horizon_gradient)
    pq, colors, loss, steps, success, hist, glitter = _solve_core(data, used, init, st)
    light = ph.finish(data, pq, colors)
    if st.geometry:
        def prepare_at(n):
            return ph.prepare(image, n, slope_var, camera, weight, horizon_gradient)

        geometry_loss, shifts = geometry_error.effect(
            prepare_at, functools.partial(_normal_equations, st=st), normal, weight, used, pq, colors, normal_noise,
            correlation=st.correlation, space=st.space, exposure=st.exposure, tonemap=st.tonemap)
    else:
        geometry_loss, shifts = None, None
    if st.space == "display":  # the reported loss is the display-space MSE over the used pixels
        bound = _plausibility.loss_bound(shading.tonemap(data.target, st.exposure, st.tonemap), used, noise,
                                         geometry_loss)
    else:
        bound = _plausibility.loss_bound(data.target, data.weight, noise, geometry_loss)
    std, determined = _uncertainty(data, pq, colors, st, noise, shifts)
    if "sun_direction" in st.fit:
        # the sun direction is only determined where its glitter is seen: a fit that explains
        # the image without any sun light (zero sun colour or no glitter on a selected
        # pixel) has not found the sun, whatever its standard deviation says
        determined["sun_direction"] = determined["sun_direction"] & (glitter > SUN_SEEN)
    success = success & jnp.isfinite(loss) & (light.sun_elevation > 0) & (loss <= bound)
    for name in st.fit:
        success = success & determined[name]
    geometry_loss = jnp.zeros((), loss.dtype) if geometry_loss is None else geometry_loss
    return light, loss, steps, success, hist, determined, std, bound, glitter, geometry_loss


_fit_jit = jax.jit(_fit_arrays, static_argnames=("st",))


@functools.lru_cache(maxsize=None)
def _fit_sequential(st: _Static):
    """The fit with a sequential batching rule: under ``vmap`` the images are fitted one after
    the other (``lax.map``) inside the compiled program, each with its own number of solver
    steps, instead of in lock-step (where every image runs as many steps as the slowest and
    both branches of every solver ``cond`` are computed). Forward-mode AD only."""
    return jax.custom_batching.sequential_vmap(functools.partial(_fit_arrays, st=st))


# --------------------------------------------------------------------------- public API


def _geometry_fields(geometry, resolution, dtype):
    """``(normal (H, W, 3), slope_variance (H, W, 2), mask or None)`` from a geometry-like."""
    H, W = resolution
    for attr in ("normal", "roughness"):
        if not hasattr(geometry, attr):
            raise ValueError(f"geometry must have a '{attr}' field (a render.Geometry or io.Frame); "
                             f"got {type(geometry).__name__}")
    if geometry.normal is None:
        raise ValueError("geometry has no normals (an EXR frame without geometry channels?)")
    normal = jnp.asarray(geometry.normal, dtype)
    if normal.shape != (H, W, 3):
        raise ValueError(f"geometry.normal must be (H, W, 3) = {(H, W, 3)} to match the image; got {normal.shape}")
    slope_var = getattr(geometry, "slope_variance", None)
    if slope_var is not None:
        slope_var = jnp.asarray(slope_var, dtype)
        if slope_var.shape != (H, W, 2):
            raise ValueError(f"geometry.slope_variance must be (H, W, 2) = {(H, W, 2)}; got {slope_var.shape}")
    else:
        rough = jnp.asarray(geometry.roughness, dtype)
        if rough.shape != (H, W):
            raise ValueError(f"geometry.roughness must be (H, W) = {(H, W)} to match the image; got {rough.shape}")
        slope_var = 0.5 * jnp.stack([rough, rough], -1)
    mask = getattr(geometry, "mask", None)
    if mask is not None:
        mask = jnp.asarray(mask)
        if mask.shape != (H, W):
            raise ValueError(f"geometry.mask must be (H, W) = {(H, W)}; got {mask.shape}")
    return normal, slope_var, mask


def _validate_geometry(normal, slope_var, used, camera) -> None:
    """``InvalidValueError`` when concrete geometry is not geometry on the sea pixels the fit
    uses: normals that are not finite unit vectors, slope variances that are not finite and
    >= 0."""
    if not is_concrete(normal, slope_var, used, camera):
        return
    pixels = np.any(np.asarray(used) > 0, axis=-1) & np.asarray(cam.intersect_sea(camera).mask)
    hint = (". An image is not geometry: pass normals from render.geometry, a geometry network or an EXR "
            "frame's normal.X/Y/Z channels")
    n = np.asarray(normal)
    finite = np.isfinite(n).all(-1)
    if (pixels & ~finite).any():
        first = np.argwhere(pixels & ~finite)[0].tolist()
        raise InvalidValueError(f"geometry.normal is not finite on {int((pixels & ~finite).sum())} fitted sea "
                                f"pixel(s) (first at (row, col) = {first}); exclude pixels without geometry with mask=")
    shading.check_unit_normals(n, "geometry.normal", where=pixels, counted=" fitted sea pixels", hint=hint)
    sv = np.asarray(slope_var)
    bad = pixels & ~(np.isfinite(sv) & (sv >= 0)).all(-1)
    if bad.any():
        first = np.argwhere(bad)[0].tolist()
        raise InvalidValueError(f"geometry slope variance (roughness) must be finite and >= 0; it is not on "
                                f"{int(bad.sum())} fitted sea pixel(s) (first at (row, col) = {first})")


def _check_fit_names(fit) -> tuple:
    if isinstance(fit, str):
        fit = (fit,)
    fit = tuple(fit)
    unknown = [f for f in fit if f not in FIT_FIELDS]
    if unknown:
        raise ValueError(f"unknown lighting field(s) {unknown} in fit=; expected a subset of {FIT_FIELDS}")
    if not fit:
        raise ValueError(f"fit= names nothing to fit; expected a non-empty subset of {FIT_FIELDS}")
    return tuple(f for f in FIT_FIELDS if f in fit)  # canonical order: static config is hashable


def lighting(image, geometry, camera, *, init: Lighting | None = None, fit=FIT_FIELDS, solver: str = "lm",
             structure: str = "varpro", weights="display", mask=None, exposure=1.0, tonemap: str = "bruneton",
             saturation: float | None = 0.9, space: str = "linear", horizon_gradient=0.0, max_steps: int | None = None,
             rtol: float | None = None, atol: float | None = None, grid: int = 24, n_starts: int = 2,
             glint: bool = True, noise: float | None = None, normal_noise=None, normal_correlation: float = 0.0,
             batching: str = "vectorized", history: bool = False, throw: bool = True,
             options: dict | None = None) -> LightingFit:
    """Fit sun direction and colours to ``image`` given its ``geometry`` and ``camera``.

    Args:
        image: ``(H, W, 3)`` linear radiance; its dtype (float32 / float64) is the fit's.
        geometry: ``render.Geometry``, ``io.Frame`` or any object with ``normal``,
            ``roughness`` (and optionally ``slope_variance``, ``mask``) of shape ``(H, W, ...)``.
        camera: the frame's camera (resolution ``(H, W)``).
        init: starting :class:`Lighting`, and the values of the fields not fitted
            (default :func:`jaxocean.shading.make_lighting`'s defaults).
        fit: the fields to fit, a subset of :data:`FIT_FIELDS`.
        solver: a name of :data:`jaxocean.fit.solvers.SOLVER_NAMES`.
        structure: ``"varpro"`` (default: colours in closed form, search the two sun
            angles from several starts) or ``"plain"`` (all parameters from ``init``).
        weights: ``"display"`` (default): :func:`tonemap_weights` of ``image`` with
            ``exposure`` and ``tonemap``, so that the loss is (to first order) the mean
            squared error of the tone-mapped display image; ``"uniform"``: plain linear-
            radiance MSE; or ``(H, W)`` / ``(H, W, 3)`` non-negative weights.
            ``mask``: ``(H, W)`` bool, pixels used (default all).
        saturation: with ``weights="display"``, pixels whose tone-mapped value exceeds this
            get weight 0 (censored: a saturated glint says little about its radiance, and
            noise on it inverts to a radiance far too low); None keeps them.
        space: ``"linear"`` (default) or ``"display"``: after the linear-space fit, refine
            every fitted parameter by least squares on the tone-mapped values (``exposure``,
            ``tonemap``). Noise on display values makes the inverse tone map biased
            (dark pixels) and censored (bright ones); the refinement removes that bias. The
            reported ``loss`` is then the MSE of the tone-mapped images.
        horizon_gradient: the sky model's, as in :func:`jaxocean.render.shade`.
        max_steps: solver step limit (default 50; 400 for ``"adam"``).
        rtol, atol: tolerances (default 1e-6 in float32, 1e-10 in float64).
        grid: ``"varpro"``: the coarse start grid has ``grid x grid`` cells over the sky
            (0: no grid). ``n_starts``: how many of the best starts are refined.
            ``glint``: include the glint estimate among the starts (``grid=0, glint=False,
            n_starts=1`` starts from ``init`` alone).
        noise: the RMS of the weighted residual the data allow at the true lighting (with
            the default display weights: about the standard deviation of the noise on
            display values; with ``weights="uniform"`` that of linear radiance); ``None``
            (default, as the command line passes): noise-free up to the model's own
            consistency. It sets the success test's loss bound and the standard deviations
            of ``std`` / ``determined`` (module docstring, *Success*).
        normal_noise: the error of ``geometry.normal`` [rad]: the standard deviation of each
            of the two tangent components of the unit normal's error (a tilt about each
            axis of :func:`jaxocean.shading.tangent_frame`), a number ``>= 0`` or an ``(H,
            W)`` map. None (default): the normals are exact, and the fit is the one without
            this argument. Given, the stated error is propagated through the shading at the
            fitted lighting by :data:`GEOMETRY_SAMPLES` fixed draws of it (module docstring):
            its expected residual ``geometry_loss`` is added to the image noise's in the loss
            bound (``1.5 (noise^2 + geometry_loss) + 1e-6 x``), and its effect on the fitted
            fields (spread and bias) to their ``std`` (so a sun the stated normal error can
            move by more than 0.5 deg, or a colour by more than 10%, is undetermined, and the
            fit fails, however low its loss). The fitted lighting itself is unchanged.
        normal_correlation: the correlation length [px] of the normal errors across the image
            (Gaussian: ``exp(-d^2 / (2 length^2))``; ``0``, the default: independent per
            pixel). Correlated errors do not average out over the glitter: they raise
            ``std``, not ``geometry_loss``. Only with ``normal_noise``.
        batching: how ``jax.vmap`` batches the fit: ``"vectorized"`` (default; every
            transformation works) or ``"sequential"`` (the images of a batch are fitted one
            after another inside the compiled program -- several times faster on a CPU,
            where lock-step iterations waste work; forward-mode differentiation only).
        history: record the loss after every step (scripted runs; not differentiable).
        throw: raise :class:`FitError` when the fit fails (eager calls only; under
            ``jit`` / ``vmap`` pass ``throw=False`` and read ``success``).
        options: passed to the solver (e.g. ``{"learning_rate": 0.02}`` for Adam).

    Returns:
        :class:`LightingFit`.
    """
    image = inp.check_image(image, camera)
    shading.check_horizon_gradient(horizon_gradient)
    dtype = image.dtype
    inp.check_resolution(image, camera)
    fit = _check_fit_names(fit)
    spec = solvers.get_solver(solver)
    if structure not in STRUCTURES:
        raise ValueError(f"unknown structure {structure!r}; expected one of {STRUCTURES}")
    if noise is not None:
        check_nonnegative_number(noise, "noise must be a finite number >= 0 (or None)")
    check_nonnegative_number(normal_correlation, "normal_correlation must be a finite number of pixels >= 0")
    if normal_correlation > 0 and normal_noise is None:
        raise ValueError("normal_correlation is the correlation of normal_noise: pass normal_noise= too")
    if not isinstance(grid, int) or grid < 0 or not isinstance(n_starts, int) or n_starts < 1:
        raise ValueError(f"grid must be an int >= 0 and n_starts an int >= 1; got {grid!r}, {n_starts!r}")
    normal, slope_var, geo_mask = _geometry_fields(geometry, image.shape[:2], dtype)
    normal_noise_map = geometry_error.normal_noise_map(normal_noise, image.shape[:2], dtype)
    if space not in ("linear", "display"):
        raise ValueError(f"space must be 'linear' or 'display'; got {space!r}")
    weight = inp.pixel_weights(weights, mask, image.shape[:2], dtype, image, exposure, tonemap, saturation)
    used = inp.pixel_weights("uniform", mask, image.shape[:2], dtype)
    init = shading.make_lighting(dtype=dtype) if init is None else init
    shading.validate_lighting(init)
    init = jax.tree.map(lambda a: jnp.asarray(a, dtype), init)
    traced = not is_concrete(image, normal, slope_var, weight, init, camera, normal_noise_map)
    inp.check_tracing("fit.lighting", traced, throw, spec, solver)
    inp.validate_values(image, weight, geo_mask, camera, fit, used)
    _validate_geometry(normal, slope_var, used, camera)
    # NaN pixels that are excluded must not leak into the sums (0 * NaN = NaN), traced or not
    image = jnp.where(used > 0, image, 0.0)

    max_steps, rtol, atol = inp.solver_limits(solver, dtype, max_steps, rtol, atol)
    free = tuple(n for n in COLOR_FIELDS if n in fit)
    st = _Static(fit=fit, free=free, solver=solver, structure=structure, max_steps=max_steps, rtol=rtol, atol=atol,
                 grid=int(grid), n_starts=int(n_starts), glint=bool(glint), history=bool(history),
                 options=tuple(sorted((options or {}).items())), space=space, exposure=float(exposure),
                 tonemap=str(tonemap), geometry=normal_noise is not None, correlation=float(normal_correlation))
    hg = jnp.asarray(horizon_gradient, dtype)
    if batching not in ("vectorized", "sequential"):
        raise ValueError(f"batching must be 'vectorized' or 'sequential'; got {batching!r}")
    if not spec.traceable:
        run = _fit_arrays
    elif batching == "sequential":
        seq = _fit_sequential(st)

        def run(*a, st):
            return seq(*a)
    else:
        run = _fit_jit
    t0 = time.perf_counter()
    noise_arr = jnp.asarray(0.0 if noise is None else noise, dtype)
    light, loss, steps, success, hist, determined, std, bound, glitter, geometry_loss = run(
        image, normal, slope_var, camera, weight, used, hg, init, noise_arr, normal_noise_map, st=st)
    if traced:
        wall = jnp.asarray(jnp.nan, dtype)
    else:
        jax.block_until_ready((light, loss))
        wall = jnp.asarray(time.perf_counter() - t0, dtype)
    result = LightingFit(light, loss, steps, success, wall, hist, determined, std, bound, glitter, geometry_loss)
    if throw and not bool(success):
        raise FitError(failure_message(result, solver=solver, structure=structure, noise=noise,
                                       normal_noise=normal_noise), result)
    return result


def _noise_text(noise, normal_noise) -> str:
    text = "noise-free" if noise is None else f"noise={noise:g}"
    if normal_noise is None:
        return text
    nn = f"{normal_noise:g}" if np.ndim(normal_noise) == 0 else "a map"
    return f"{text}, normal_noise={nn} rad"


def failure_message(result: LightingFit, *, solver: str = "lm", structure: str = "varpro", noise=None,
                    normal_noise=None) -> str:
    """Why a (single, concrete) :class:`LightingFit` failed, in one line: the first of a
    non-finite loss, a residual above what the noise (and the stated normal error) allows, an
    undetermined field (the sun direction without glitter in the image, or a standard
    deviation above the threshold), a sun below the horizon, or the solver's own test.
    Empty for a success."""
    if bool(result.success):
        return ""
    loss, bound = float(result.loss), float(result.loss_bound)
    noise_text = _noise_text(noise, normal_noise)
    undetermined = [n for n in FIT_FIELDS if not bool(result.determined[n])]
    if not math.isfinite(loss):
        return f"lighting fit failed: loss {loss} is not finite (solver {solver!r}, structure {structure!r})"
    if loss > bound:
        return (f"lighting fit does not explain the image: residual loss {loss:.3e} (RMS {math.sqrt(loss):.3g}) "
                f"exceeds {bound:.3e}, what the stated noise allows ({noise_text}); a wrong local minimum, or "
                f"pass the image's noise=")
    if "sun_direction" in undetermined:
        determined = [n for n in COLOR_FIELDS if n not in undetermined]
        keep = f"; the determined colours ({', '.join(determined)}) are in the result" if determined else ""
        if float(result.glitter) <= SUN_SEEN:
            return f"sun direction undetermined: no sun glitter in the image{keep}"
        return (f"sun direction undetermined: its standard deviation {math.degrees(float(result.std['sun_direction'])):.3g}"
                f" deg at the stated noise ({noise_text}) exceeds {DETERMINED_SUN_DEG} deg{keep}")
    if undetermined:
        return (f"lighting fit: {', '.join(undetermined)} undetermined (standard deviation above "
                f"{DETERMINED_COLOR_REL:.0%} of the colour at the stated noise, {noise_text})")
    if not float(result.lighting.sun_elevation) > 0:
        return f"lighting fit failed: the fitted sun is below the horizon (elevation {float(result.lighting.sun_elevation):.3g} rad)"
    return (f"lighting fit did not converge (solver {solver!r}, structure {structure!r}): loss {loss:.3e} after "
            f"{int(result.steps)} steps")


# --------------------------------------------------------------------------- helpers


def random_lighting(key, *, sun_azimuth=(-math.pi, math.pi), sun_elevation=(math.radians(1.0), math.radians(89.0)),
                    ranges: dict | None = None, dtype=None) -> Lighting:
    """A random :class:`Lighting`: azimuth and elevation uniform in the given ranges [rad],
    each colour channel log-uniform in ``ranges`` (default :data:`COLOR_RANGES`)."""
    ranges = {**COLOR_RANGES, **(ranges or {})}
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    k_az, k_el, k_sun, k_sky, k_sea = jax.random.split(key, 5)
    az = jax.random.uniform(k_az, (), dtype, *sun_azimuth)
    el = jax.random.uniform(k_el, (), dtype, *sun_elevation)

    def color(k, name):
        lo, hi = ranges[name]
        return jnp.exp(jax.random.uniform(k, (3,), dtype, math.log(lo), math.log(hi)))

    return Lighting(az, el, color(k_sun, "sun_color"), color(k_sky, "sky_color"), color(k_sea, "sea_color"))


def lighting_error(fitted: Lighting, truth: Lighting) -> dict:
    """Errors of a fitted lighting: ``sun_angle_deg`` (angle between the sun directions) and,
    per colour, the largest relative channel error. Works on batches (leading axes)."""
    def vec(light):
        return shading.sun_direction(light) if jnp.ndim(light.sun_azimuth) == 0 else jax.vmap(shading.sun_direction)(light)

    out = {"sun_angle_deg": jnp.degrees(angle_between(vec(fitted), vec(truth)))}
    for n in COLOR_FIELDS:
        f, t = getattr(fitted, n), getattr(truth, n)
        out[n] = jnp.max(jnp.abs(f - t) / jnp.maximum(jnp.abs(t), jnp.finfo(jnp.asarray(t).dtype).tiny), axis=-1)
    return out


def lighting_to_dict(light: Lighting) -> dict:
    """A JSON-safe dict of a (single) :class:`Lighting`: sun angles in radians and degrees,
    colours as lists (the inverse of :func:`lighting_from_dict`)."""
    return {
        "sun_azimuth": float(light.sun_azimuth),
        "sun_elevation": float(light.sun_elevation),
        "sun_azimuth_deg": math.degrees(float(light.sun_azimuth)),
        "sun_elevation_deg": math.degrees(float(light.sun_elevation)),
        "sun_color": [float(x) for x in np.asarray(light.sun_color)],
        "sky_color": [float(x) for x in np.asarray(light.sky_color)],
        "sea_color": [float(x) for x in np.asarray(light.sea_color)],
    }


def fit_to_dict(result) -> dict:
    """A JSON-safe dict of a (single) fit result: the lighting, loss, steps, success, time;
    for a :class:`LightingFit` also ``determined``, ``std`` (non-finite values as None; the
    sun's also in degrees, ``sun_direction_deg``), ``loss_bound`` and ``glitter``."""
    out = {
        "lighting": lighting_to_dict(result.lighting),
        "loss": float(result.loss),
        "rms_residual": float(np.sqrt(max(float(result.loss), 0.0))),
        "steps": int(result.steps),
        "success": bool(result.success),
        "wall_time_s": float(result.wall_time),
    }
    if hasattr(result, "camera"):
        out["camera"] = cam.camera_to_dict(result.camera, degrees=True)
    if getattr(result, "determined", None) is not None:
        out["determined"] = {n: bool(v) for n, v in result.determined.items()}
        out["std"] = json_safe(dict(result.std))
        sd = out["std"].get("sun_direction")
        out["std"]["sun_direction_deg"] = None if sd is None else math.degrees(sd)
        out["loss_bound"] = float(result.loss_bound)
        out["glitter"] = float(result.glitter)
        if getattr(result, "geometry_loss", None) is not None:
            out["geometry_loss"] = float(result.geometry_loss)
    return out


def lighting_from_dict(d: dict, dtype=None) -> Lighting:
    """The :class:`Lighting` of a :func:`fit_to_dict` output (or of its ``"lighting"`` entry)."""
    d = d.get("lighting", d) if isinstance(d, dict) else d
    if not isinstance(d, dict):  # a scene's "lighting": null, say
        raise ValueError(f"expected a lighting dict (the output of fit_to_dict or its 'lighting' entry); got {d!r:.80}")
    try:
        return shading.make_lighting(d["sun_azimuth"], d["sun_elevation"], d["sun_color"], d["sky_color"],
                                     d["sea_color"], dtype=dtype)
    except KeyError as error:
        raise ValueError(f"lighting dict lacks {error.args[0]!r}; expected the output of fit_to_dict") from None
