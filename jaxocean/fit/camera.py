"""Camera fit: height, pitch (and field of view) from an image and its waves.

Protocol
--------
``camera(image, waves, t, init, *, lighting=..., fit=("height", "pitch"), ...) -> CameraFit``

* ``image``   ``(H, W, 3)`` linear radiance, ``H, W`` the resolution of ``init``.
* ``waves``   the :class:`jaxocean.waves.Waves` ``(N,)`` of the scene and ``t`` [s] the frame time:
  the geometry is rendered (:func:`jaxocean.render.geometry`, on the path ``plan`` names) for
  every candidate camera, so the camera is seen through the wave pattern, the horizon
  and the change of footprint with distance.
* ``init``    a :class:`jaxocean.camera.Camera`: the starting guess, and every field that is not
  fitted (yaw, position, resolution, projection).
* ``lighting`` the known :class:`jaxocean.shading.Lighting`; or ``fit_lighting=True`` to fit
  the lighting jointly (then ``lighting`` is the starting guess, default the renderer's).

Parameterisation: ``log(height)``, ``pitch`` [rad] and ``log(tan(fov / 2))`` -- height and
field of view stay positive and ``fov`` below pi. With ``fit_lighting=True`` the sun's
azimuthal-equidistant ``(p, q)`` (see :mod:`jaxocean.fit.lighting`) are appended and the
three colours are solved in closed form (non-negative least squares) inside the residual.

Coarse to fine (``levels``, default ``(4, 2, 1)``): with every wave resolved by the normal the
loss is a narrow well in a rough plateau -- a 1% change of height moves every pixel's sea
point by a good part of the shortest resolved wavelength and the glint pattern decorrelates
(measured on the 48^2 demo scene: well +-1% in height, +-0.004 rad in pitch). At level ``s``
the model is the same renderer with Bruneton's hierarchy footprint scaled by ``s``
(``n_min = s``, ``n_max = 1.5 s``): waves shorter than ``s`` footprints go to the roughness,
the model predicts the image's local mean, and the well widens with the shortest resolved
wavelength. The fit runs at each level in turn, each starting from the previous one's
answers (see Starts); the image stays at full resolution (a box-downsampled image against a coarser
camera was measured too: its minimum is biased by several % -- the shading of a pixel is not
the mean of its sub-pixels' -- and falls outside the fine well).

Starts: ``search=(n_h, n_p)`` candidate cameras around ``init`` -- heights ``init * exp(
linspace(-height_span, height_span, n_h))`` and pitches ``init + linspace(-pitch_span,
pitch_span, n_p)`` -- and the previous level's answers are scored by each level's loss, and
the best ``n_starts`` are refined by the solver at that level; the lowest loss at the finest
level wins. A coarse level thus only proposes: where its valley is flat (a small image whose
coarse levels resolve almost nothing) its answer can drift far, and a candidate wins at the
next level (measured at 16^2: 6.7 m instead of 10 m when each level started from the
previous answer alone). With
``fit_lighting`` the sun starts from the best of the lighting fit's starts (glint estimate and
coarse grid) at each candidate camera.

The loss is the lighting fit's: weighted mean square residual in linear radiance (see
:func:`jaxocean.fit.lighting.lighting`); ``weights`` / ``mask`` as there.

Success: the final solve converged, the camera is valid (height > 0, |pitch| < pi/2, with
``fit_lighting`` the sun above the horizon) *and* the loss is plausible for a right camera::

    loss <= NOISE_FACTOR * (noise**2 + time_loss) + LOSS_FLOOR * sum(w^2 image^2) / sum(w^2)

(``time_loss``: 0 unless ``time_noise`` is given; see Time).

``noise`` is the RMS of the weighted residual the data allow at the true camera (with the
default display weights: the standard deviation of the noise on display values); ``None``
(default) takes the image as noise-free, up to the model's own consistency (``LOSS_FLOOR =
1e-6``: residual RMS 1e-3 of the image's). The fitted camera sits at a stationary point, so the
solver's convergence test passes in a wrong local minimum too; the loss tells them apart
(demo scene: 2e-13 at the truth, 1.5e-3 -- 10% of the image's weighted mean square -- in the
neighbouring minimum at -1.5% / -0.005 rad, where height and pitch trade against each other).
Measured at the truth with noise on display values: loss / noise^2 = 0.71-0.75 (sigma 0.01,
0.03; clipping and censored glints), hence ``NOISE_FACTOR = 1.5``. A fit of a noisy image
without ``noise=`` reports failure: it cannot tell noise from a wrong camera. With ``noise=``,
a neighbouring minimum whose loss is within the bound passes as well, with a standard
deviation that does not reach the truth (measured on a 16 x 16 float64 scene with display
noise 0.02, one start at 8.7 m, ``search=(1, 1)``: 8.28 +- 0.04 m against the true 10 m,
loss 1.04 noise^2, against 0.88 noise^2 at the truth): ``success`` says that the camera
explains the image to its noise, not that no other camera does; the start search
(``search``) is what looks for the right basin. With ``fit_lighting`` success also needs the
sun direction determined, by the lighting fit's rule (its glitter seen, its standard
deviation below 0.5 deg): an image without glitter (the sun behind the camera) is explained
as well by a sun anywhere with no sun colour (measured: 139 deg from the true sun on a 16^2
scene, the camera exact), and the lighting returned with it is no measurement. Likewise each
fitted colour must be determined by the lighting fit's rule (every channel's standard
deviation below 10% of its brightest, from ``J^T J`` in camera, sun and colours): with
display noise 0.01 on the 16^2 test scene the sun colour came out 27% low with a standard
deviation of 41%, camera and sun direction determined, and was reported as success.

Time: ``t`` is taken as exact unless ``time_noise=`` [s] states its error. A wrong frame
time moves the waves, and height and pitch follow them: measured on the 16^2 scene with
display noise 0.01, ``t`` off by 0.1 s gave the height 16 standard deviations off (0.16 m)
at a loss of 0.96 noise^2, within the bound (0.2 s: 45 sigma, 1.37 noise^2) -- a loss test
cannot tell such an error from noise. With ``time_noise`` the answer's linear response to
the time (``dy/dt`` of the least-squares answer) times ``time_noise`` is added to ``std`` in
quadrature, and the loss the time error leaves once the parameters have absorbed what they
can is added to the bound (the ``geometry`` term of
:func:`jaxocean.fit._plausibility.loss_bound`): a camera that the stated time error could
have moved further than the determined limits is not reported as measured.

Everything after validation is one jitted function; results are arrays only (``vmap`` with
``throw=False``).
"""

from __future__ import annotations

import dataclasses
import functools
import math
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, render, shading
from jaxocean.errors import check_finite, check_nonnegative_number, is_concrete, is_integer
from jaxocean.fit import _plausibility
from jaxocean.fit import _image_inputs as inp
from jaxocean.fit import _photometry as ph
from jaxocean.fit import lighting as lf
from jaxocean.fit import solvers
from jaxocean.fit.solvers import FitError
from jaxocean.shading import Lighting
from jaxocean.waves import Waves, validate

__all__ = ["CAMERA_FIELDS", "CameraFit", "camera"]

CAMERA_FIELDS = ("height", "pitch", "fov")
DEFAULT_LEVELS = (4.0, 2.0, 1.0)
#: solver steps of every level but the last: they only propose starts for the next level.
#: Measured on the 48^2 demo scene (float32, quiet machine): 30 steps in all instead of 97,
#: 3.1 s instead of 6.8 s after compilation, the same answer; 20 of 20 random starts within
#: +-15% height / +-0.04 rad pitch still recover the camera (experiments/LIGHTING.md).
DEFAULT_COARSE_STEPS = 12
#: success needs ``loss <= NOISE_FACTOR * noise**2 + LOSS_FLOOR * (weighted mean square image)``
#: (the rule of :mod:`jaxocean.fit._plausibility`, the same as fit.lighting's)
NOISE_FACTOR = _plausibility.NOISE_FACTOR
LOSS_FLOOR = _plausibility.LOSS_FLOOR
#: a fitted height is determined when its standard deviation at the stated noise is below
#: this fraction of it; pitch and fov when theirs is below DETERMINED_ANGLE_DEG. A field the
#: image does not constrain (the height over a flat sea: every height looks alike) keeps its
#: start and must not be reported as measured.
DETERMINED_HEIGHT_REL = 0.01
DETERMINED_ANGLE_DEG = 0.1


class CameraFit(NamedTuple):
    """Result of :func:`camera` (a pytree of arrays; batched under ``vmap``).

    ``camera`` the fitted camera (other fields as ``init``); ``lighting`` the lighting used
    (fitted when ``fit_lighting``); ``loss`` (at the finest level), ``wall_time`` as in
    :class:`jaxocean.fit.lighting.LightingFit`; ``steps`` summed over the levels (each level's
    winning start); ``success`` also needs a plausible loss (module docstring); ``history``
    ``(levels, max_steps + 1)``, the winning start's at each level. ``std`` ``{field: ()}``:
    the Gauss-Newton standard deviation of each fitted camera field (height [m], pitch and
    fov [rad]) at the stated noise (without one, at the loss floor), the stated
    ``time_noise``'s effect added in quadrature; ``determined``
    ``{field: () bool}``: below :data:`DETERMINED_HEIGHT_REL` of the height or
    :data:`DETERMINED_ANGLE_DEG`. With ``fit_lighting`` both also hold ``"sun_direction"``:
    the RMS standard deviation [rad] of the sun's ``(p, q)``, determined as
    :func:`jaxocean.fit.lighting.lighting` determines it (below its ``DETERMINED_SUN_DEG``,
    and its glitter seen), and each colour ``(3,)`` (determined as fit.lighting determines
    a colour). ``success`` needs every entry of ``determined``.
    """

    camera: cam.Camera
    lighting: Lighting
    loss: jax.Array
    steps: jax.Array
    success: jax.Array
    wall_time: jax.Array
    history: Any = None
    std: Any = None
    determined: Any = None


class _Static(NamedTuple):
    fit: tuple
    fit_lighting: bool
    solver: str
    max_steps: int
    rtol: float
    atol: float
    search: tuple
    height_span: float
    pitch_span: float
    n_starts: int
    grid: int
    history: bool
    options: tuple
    levels: tuple  # hierarchy scales, coarse to fine (the last is 1)
    coarse_steps: int  # solver steps at every level but the last
    plans: tuple  # one render.RenderPlan or None per level (static)


def _pack(camera, fit):
    parts = {"height": jnp.log(camera.height), "pitch": camera.pitch, "fov": jnp.log(jnp.tan(camera.fov / 2))}
    return jnp.stack([parts[n] for n in fit])


def _unpack(y, init, fit):
    values = {}
    for i, n in enumerate(fit):
        if n == "height":
            values[n] = jnp.exp(y[i])
        elif n == "pitch":
            values[n] = y[i]
        else:
            values[n] = 2 * jnp.arctan(jnp.exp(y[i]))
    return dataclasses.replace(init, **values)


def _data(y, args, fit, plan, scale=1.0):
    """Lighting-independent terms at camera ``y`` with the hierarchy's footprint scaled by
    ``scale``: waves shorter than ``scale * n_min`` footprints go to the roughness."""
    image, weight, waves, t, init, hg = args[:6]
    c = _unpack(y[: len(fit)], init, fit)
    geo = render.geometry(waves, c, t, plan=plan, n_min=scale * hierarchy.DEFAULT_N_MIN,
                          n_max=scale * hierarchy.DEFAULT_N_MAX)
    # pixels whose ray-surface hit is not unique (grazing rays) have no exact model: left out
    usable = geo.converged.reshape(geo.converged.shape + (1,) * (jnp.ndim(weight) - 2))
    return ph.prepare(image, geo.normal, geo.slope_variance, c, jnp.where(usable, weight, 0.0), hg)


def _sun_and_colors(y, data, light, fit, fit_lighting):
    """Sun direction and colours of parameters ``y``: with ``fit_lighting`` the sun's ``(p, q)``
    after the camera fields and the colours projected at ``data``, else the known ``light``'s."""
    fixed = {n: getattr(light, n) for n in ph.COLOR_FIELDS}
    if not fit_lighting:
        return shading.sun_direction(light), fixed
    direction = ph.pq_to_direction(y[len(fit):])
    return direction, ph.project_colors(data, direction, fixed, ph.COLOR_FIELDS)


def _residual(y, args, fit, fit_lighting, plan, scale):
    data = _data(y, args, fit, plan, scale)
    direction, colors = _sun_and_colors(y, data, args[6], fit, fit_lighting)
    return ph.residual_from_model(data, ph.model(data, direction, colors))


@functools.lru_cache(maxsize=None)
def _bound(fit: tuple, fit_lighting: bool, plan, scale: float):
    def fn(y, args):
        return _residual(y, args, fit, fit_lighting, plan, scale)

    return solvers.dense_jacobian(fn)


def _candidates(init, st: _Static, dtype):
    n_h, n_p = st.search
    fh = np.exp(np.linspace(-st.height_span, st.height_span, n_h)) if n_h > 1 else np.ones(1)
    dp = np.linspace(-st.pitch_span, st.pitch_span, n_p) if n_p > 1 else np.zeros(1)
    rows = []
    for a in fh:
        for b in dp:
            rows.append((a, b))
    rows.sort(key=lambda r: (abs(math.log(r[0])), abs(r[1])))  # init first
    y0 = _pack(init, st.fit)
    out = []
    for a, b in rows:
        y = y0
        if "height" in st.fit:
            y = y.at[st.fit.index("height")].add(math.log(a))
        if "pitch" in st.fit:
            y = y.at[st.fit.index("pitch")].add(float(b))  # a Python float keeps a float32 y float32 under x64
        out.append(y)
    return jnp.stack(out).astype(dtype)


def _sun_start(y_cam, args, st: _Static):
    """Best sun (p, q) at a candidate camera: lighting-fit starts scored at that geometry
    (the coarsest level's)."""
    data = _data(y_cam, args, st.fit, st.plans[0], st.levels[0])
    light = args[6]
    fixed = {n: getattr(light, n) for n in ph.COLOR_FIELDS}
    init_pq = ph.sun_to_pq(light.sun_azimuth, light.sun_elevation).astype(data.target.dtype)
    return ph.starts(data, init_pq, fixed, ph.COLOR_FIELDS, grid=st.grid, n_starts=1)[0]


def _score(fn, y, args):
    r = fn(y, args)
    loss = jnp.sum(r * r)
    return jnp.where(jnp.isfinite(loss), loss, jnp.inf)


def _core(image, weight, waves, t, init, hg, light, noise, time_noise, st: _Static):
    args = (image, weight, waves, t, init, hg, light)
    dtype = image.dtype
    fns = [_bound(st.fit, st.fit_lighting, plan, scale) for plan, scale in zip(st.plans, st.levels)]
    cands = _candidates(init, st, dtype)
    if st.fit_lighting:
        suns = jax.lax.map(lambda y: _sun_start(y, args, st), cands)
        cands = jnp.concatenate([cands, suns], -1)

    spec = solvers.get_solver(st.solver)
    cands = jax.lax.stop_gradient(cands)
    answers = cands[:0]
    steps, hists = jnp.zeros((), jnp.int32), []
    for level, fn in enumerate(fns):
        limit = st.max_steps if level == len(fns) - 1 else min(st.coarse_steps, st.max_steps)
        # each level refines the n_starts best (by its own loss) of the search candidates and
        # the previous level's answers: a coarse level only proposes starts (module docstring)
        pool = jnp.concatenate([answers, cands], 0)
        losses = jax.lax.map(lambda y: _score(fn, y, args), pool)
        starts = jax.lax.stop_gradient(pool[jnp.argsort(losses)[: st.n_starts]])

        def run_one(y0, fn=fn, limit=limit):
            return solvers.solve(st.solver, fn, y0, args, max_steps=limit, rtol=st.rtol, atol=st.atol,
                                 history=st.history, options=dict(st.options))

        outs = jax.lax.map(run_one, starts) if spec.traceable else ph.host_map(run_one, starts)
        best = jnp.argmin(jnp.where(jnp.isfinite(outs.loss), outs.loss, jnp.inf))
        out = jax.tree.map(lambda a: a[best], outs)
        answers = outs.params
        steps = steps + out.steps
        if out.history is not None:  # coarse levels' shorter histories padded with their last loss
            hists.append(jnp.pad(out.history, (0, st.max_steps - limit), mode="edge"))
    y = out.params
    c = _unpack(y[: len(st.fit)], init, st.fit)
    if st.fit_lighting:  # the fitted sun with its projected colours at the finest level's geometry
        data = _data(y, args, st.fit, st.plans[-1], st.levels[-1])
        direction, colors = _sun_and_colors(y, data, args[6], st.fit, True)
        light = ph.finish(data, y[len(st.fit):], colors)
    else:
        light = args[6]
    loss = 2 * out.loss
    hist = None if out.history is None else 2 * jnp.stack(hists)
    success = out.success & jnp.isfinite(loss) & (c.height > 0) & (jnp.abs(c.pitch) < jnp.pi / 2)
    std, determined, time_loss = _uncertainty(fns[-1], y, args, c, st.fit, image, weight, noise, time_noise)
    bound = _plausibility.loss_bound(image, weight, noise, time_loss)
    success = success & (loss <= bound)
    if st.fit_lighting:
        success = success & (light.sun_elevation > 0)
        std["sun_direction"], determined["sun_direction"] = _sun_uncertainty(data, direction, colors, std.pop("_pq"))
        colors_std, colors_determined = _color_uncertainty(y, args, st, colors, image, weight, noise)
        std.update(colors_std)
        determined.update(colors_determined)
    else:
        std.pop("_pq")
    for name in determined:
        success = success & determined[name]
    return c, light, loss, steps, success, hist, std, determined, bound


def _uncertainty(fn, y, args, camera_at, fit, image, weight, noise, time_noise):
    """``(std, determined, time_loss)`` of the fitted camera fields: Gauss-Newton standard
    deviations from ``J^T J`` of the residual at the answer (every fitted parameter, the
    sun's too, marginalised), at the noise of :func:`jaxocean.fit._plausibility.noise_variance`,
    with the shift a frame-time error of ``time_noise`` [s] makes added in quadrature;
    ``time_loss`` the loss that time error leaves once the parameters absorb what they can."""
    y = jax.lax.stop_gradient(y)
    jac = jax.jacfwd(lambda p: fn(p, args))(y).reshape(-1, y.shape[0])
    sd = _plausibility.parameter_std(jac.T @ jac, _plausibility.noise_variance(image, weight, noise))
    # a wrong frame time moves the waves, and height and pitch follow them (0.1 s: 16 sigma
    # in height, at 1.3x the loss): the answer's linear response dy/dt to the time
    t = jax.lax.stop_gradient(args[3])
    dr_dt = jax.jvp(lambda tt: fn(y, args[:3] + (tt,) + args[4:]).reshape(-1), (t,), (jnp.ones_like(t),))[1]
    dy_dt = -jnp.linalg.lstsq(jac, dr_dt)[0]
    shift = dy_dt * time_noise
    sd = jnp.where(time_noise > 0, jnp.sqrt(sd * sd + shift * shift), sd)
    time_loss = jnp.sum((dr_dt + jac @ dy_dt) ** 2) * time_noise * time_noise
    std, determined = {"_pq": sd[len(fit):]}, {}  # the sun's (p, q) follow the camera fields
    for i, name in enumerate(fit):
        if name == "height":  # y holds log(height)
            std[name] = camera_at.height * sd[i]
            determined[name] = sd[i] < DETERMINED_HEIGHT_REL
        else:  # pitch itself; fov through log(tan(fov / 2)), d fov / d y = sin(fov)
            std[name] = sd[i] if name == "pitch" else jnp.sin(camera_at.fov) * sd[i]
            determined[name] = std[name] < math.radians(DETERMINED_ANGLE_DEG)
    return std, determined, time_loss


def _sun_uncertainty(data: ph.Data, direction, colors, sd_pq):
    """``(std, determined)`` of a jointly fitted sun direction, as :func:`jaxocean.fit.lighting.lighting`
    reports it: ``std`` [rad] the RMS of the standard deviations ``sd_pq (2,)`` of its ``(p, q)``,
    determined below ``DETERMINED_SUN_DEG`` and where its glitter is seen (above ``SUN_SEEN``
    of the weighted image energy in ``data``, the finest level's, with the fitted ``direction``
    and ``colors``). An image that shows no glitter (a sun behind the camera) is explained as
    well with the sun anywhere, or with no sun at all."""
    glitter = lf.glitter_share(data, ph.columns(data, direction)["sun_color"], colors["sun_color"])
    std = jnp.sqrt(jnp.sum(sd_pq * sd_pq))
    return std, (std < math.radians(lf.DETERMINED_SUN_DEG)) & (glitter > lf.SUN_SEEN)


def _color_uncertainty(y, args, st: _Static, colors, image, weight, noise):
    """``(std, determined)`` of the jointly fitted colours, ``{name: (3,)}`` and ``{name: ()
    bool}``: Gauss-Newton standard deviations from ``J^T J`` of the residual in the camera
    fields, the sun's ``(p, q)`` and the nine colour channels (all marginalised; the colours
    are solved in closed form inside the fit, so the fit's own Jacobian has no column for
    them), determined as :func:`jaxocean.fit.lighting.lighting` determines a colour. A colour
    the image does not show (the sea's under a bright sky reflection, say) is no measurement.
    ``colors``: the fitted ones at ``y``."""
    n = y.shape[0]

    def residual(p):
        at = _data(p[:n], args, st.fit, st.plans[-1], st.levels[-1])
        cols = {name: p[n + 3 * i: n + 3 * i + 3] for i, name in enumerate(ph.COLOR_FIELDS)}
        return ph.residual_from_model(at, ph.model(at, ph.pq_to_direction(p[len(st.fit):n]), cols))

    p = jax.lax.stop_gradient(jnp.concatenate([y] + [colors[name] for name in ph.COLOR_FIELDS]))
    jac = jax.jacfwd(residual)(p).reshape(-1, p.shape[0])
    sd = _plausibility.parameter_std(jac.T @ jac, _plausibility.noise_variance(image, weight, noise))
    std = {name: sd[n + 3 * i: n + 3 * i + 3] for i, name in enumerate(ph.COLOR_FIELDS)}
    return std, {name: lf.color_determined(std[name], colors[name]) for name in ph.COLOR_FIELDS}


_core_jit = jax.jit(_core, static_argnames=("st",))


def camera(image, waves: Waves, t, init: cam.Camera, *, lighting: Lighting | None = None, fit=("height", "pitch"),
           fit_lighting: bool = False, solver: str = "lm", weights="display", mask=None, exposure=1.0,
           tonemap: str = "bruneton", saturation: float | None = 0.9, horizon_gradient=0.0,
           max_steps: int | None = None, rtol: float | None = None, atol: float | None = None,
           search=(7, 5), height_span: float = 0.15, pitch_span: float = 0.04, n_starts: int = 2, grid: int = 16,
           levels=DEFAULT_LEVELS, coarse_steps: int | None = DEFAULT_COARSE_STEPS, noise: float | None = None,
           time_noise: float | None = None, plan="auto", history: bool = False, throw: bool = True,
           options: dict | None = None) -> CameraFit:
    """Fit camera height and pitch (and ``fov``) to ``image`` of ``waves`` at time ``t``.

    Args:
        image: ``(H, W, 3)`` linear radiance; its dtype is the fit's.
        waves, t: the scene's waves ``(N,)`` and the frame time [s].
        init: starting camera (resolution ``(H, W)``); unfitted fields are kept.
        lighting: the scene's lighting (known), or the starting guess with ``fit_lighting``.
        fit: camera fields to fit, a subset of :data:`CAMERA_FIELDS`.
        fit_lighting: also fit sun direction and colours (jointly).
        solver, weights, mask, exposure, tonemap, saturation, horizon_gradient, max_steps, rtol, atol,
            history, throw, options: as in :func:`jaxocean.fit.lighting.lighting`.
        search, height_span, pitch_span, n_starts: the start candidates, scored at the coarsest
            level (module docstring).
        levels: hierarchy footprint scales, decreasing, ending in 1: the coarse-to-fine
            sequence of models (module docstring); ``(1,)`` fits the full model alone.
        coarse_steps: solver step limit at every level but the last (they only propose
            starts; :data:`DEFAULT_COARSE_STEPS`); ``None``: ``max_steps``.
        noise: RMS of the weighted residual the data allow at the true camera (display-space
            noise std with the default weights), for the success test; None: noise-free.
        time_noise: the standard deviation [s] of the error of ``t`` (module docstring, Time);
            None: ``t`` is exact.
        grid: the sun grid of the lighting starts (``fit_lighting`` only).
        plan: how the geometry is evaluated for every candidate camera: ``"auto"`` (default)
            uses the path :func:`jaxocean.render.plan` picks at ``init`` (rows or converged
            hits, as :func:`jaxocean.render.render` does by default) for every candidate, with
            every wave evaluated (a wave skipped at ``init`` may matter at the fitted camera);
            concrete inputs only (under ``jit``/``vmap`` pass a plan). ``None``: the rows path;
            or a :class:`jaxocean.render.RenderPlan`. The model must match the way the image
            was made: the hits path differs from the rows path. Pixels whose hit does not
            converge to a unique point (``Geometry.converged`` False) are left out of the loss.

    Returns:
        :class:`CameraFit`.
    """
    image = inp.check_image(image, init)
    shading.check_horizon_gradient(horizon_gradient)
    dtype = image.dtype
    if init.projection != "perspective":
        raise ValueError("camera fits need a perspective camera (an orthographic one has no height or pitch to see)")
    inp.check_resolution(image, init)
    if isinstance(fit, str):
        fit = (fit,)
    unknown = [f for f in fit if f not in CAMERA_FIELDS]
    if unknown or not fit:
        raise ValueError(f"fit= must be a non-empty subset of {CAMERA_FIELDS}; got {tuple(fit)}")
    fit = tuple(f for f in CAMERA_FIELDS if f in fit)
    validate(waves)
    check_finite(t, "t (the frame time [s])")  # a NaN time rendered NaN at every candidate: a garbage camera
    if waves.omega.ndim != 1:
        raise ValueError(f"waves must have leaves (N,); got {waves.omega.shape}")
    spec = solvers.get_solver(solver)
    levels = tuple(float(s) for s in levels)
    if coarse_steps is not None and (not isinstance(coarse_steps, (int, np.integer)) or coarse_steps < 1):
        raise ValueError(f"coarse_steps must be a positive int or None; got {coarse_steps!r}")
    if not levels or levels[-1] != 1.0 or any(a <= b for a, b in zip(levels, levels[1:])):
        raise ValueError(f"levels must be decreasing hierarchy scales ending in 1; got {levels!r}")
    if noise is not None and not (math.isfinite(noise) and noise >= 0):
        raise ValueError(f"noise must be a finite number >= 0 (or None); got {noise!r}")
    if len(search) != 2 or any(not is_integer(n, 1) for n in search):
        raise ValueError(f"search must be two positive ints (n_heights, n_pitches); got {search!r}")
    check_nonnegative_number(height_span, "height_span must be a finite number >= 0")
    if time_noise is not None:
        check_nonnegative_number(time_noise, "time_noise must be a finite number >= 0 s (or None)")
    check_nonnegative_number(pitch_span, "pitch_span must be a finite number >= 0 rad")
    if not is_integer(n_starts, 1) or not is_integer(grid, 0):
        raise ValueError(f"n_starts must be an int >= 1 and grid an int >= 0; got {n_starts!r}, {grid!r}")
    if lighting is None:
        if not fit_lighting:
            raise ValueError("pass the scene's lighting=, or fit_lighting=True to fit it jointly")
        lighting = shading.make_lighting(dtype=dtype)
    shading.validate_lighting(lighting)
    lighting = jax.tree.map(lambda a: jnp.asarray(a, dtype), lighting)
    waves = jax.tree.map(lambda a: jnp.asarray(a, dtype), waves)
    init = jax.tree.map(lambda a: jnp.asarray(a, dtype), init)
    weight = inp.pixel_weights(weights, mask, image.shape[:2], dtype, image, exposure, tonemap, saturation)
    traced = not is_concrete(image, weight, waves, init, lighting, t)
    inp.check_tracing("fit.camera", traced, throw, spec, solver)
    used = inp.pixel_weights("uniform", mask, image.shape[:2], dtype)
    inp.validate_values(image, weight, None, init, fit + (("sun_direction",) if fit_lighting else ()), used)
    image = jnp.where(used > 0, image, 0.0)  # excluded NaN pixels stay out of the sums, traced or not
    if isinstance(plan, str):
        if plan != "auto":
            raise ValueError(f"plan must be 'auto', None or a RenderPlan; got {plan!r}")
        if traced:
            raise ValueError("plan='auto' needs concrete inputs; under jit/vmap pass plan=RenderPlan(...) or None")
        n = waves.omega.shape[0]
        plans = tuple(render.full_plan(n, render.plan(
            waves, init, t, n_min=s * hierarchy.DEFAULT_N_MIN, n_max=s * hierarchy.DEFAULT_N_MAX).refine)
            for s in levels)
    else:
        if plan is not None:
            plan = render.RenderPlan(active=tuple(int(i) for i in plan.active), refine=int(plan.refine))
        plans = (plan,) * len(levels)
    max_steps, rtol, atol = inp.solver_limits(solver, dtype, max_steps, rtol, atol)
    st = _Static(fit=fit, fit_lighting=bool(fit_lighting), solver=solver, max_steps=max_steps, rtol=rtol, atol=atol,
                 search=tuple(int(n) for n in search), height_span=float(height_span), pitch_span=float(pitch_span),
                 n_starts=int(n_starts), grid=int(grid), history=bool(history),
                 options=tuple(sorted((options or {}).items())), levels=levels,
                 coarse_steps=max_steps if coarse_steps is None else int(coarse_steps), plans=plans)
    run = _core_jit if spec.traceable else _core
    t0 = time.perf_counter()
    c, light, loss, steps, success, hist, std, determined, bound = run(
        image, weight, waves, jnp.asarray(t, dtype), init, jnp.asarray(horizon_gradient, dtype), lighting,
        jnp.asarray(0.0 if noise is None else noise, dtype),
        jnp.asarray(0.0 if time_noise is None else time_noise, dtype), st)
    if traced:
        wall = jnp.asarray(jnp.nan, dtype)
    else:
        jax.block_until_ready(loss)
        wall = jnp.asarray(time.perf_counter() - t0, dtype)
    result = CameraFit(c, light, loss, steps, success, wall, hist, std, determined)
    if throw and not bool(success):
        undetermined = [name for name in determined if not bool(determined[name])]
        bound = float(bound)
        if float(loss) > bound:
            why = f"the answer does not explain the image (loss {float(loss):.3e} above its bound {bound:.3e})"
        elif undetermined:
            why = (f"{', '.join(undetermined)} undetermined: the image does not constrain "
                   f"{'it' if len(undetermined) == 1 else 'them'}")
        else:
            why = f"did not converge (solver {solver!r})"
        raise FitError(f"camera fit failed: {why}; loss {float(loss):.3e} after {int(steps)} steps", result)
    return result
