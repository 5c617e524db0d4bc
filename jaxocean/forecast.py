"""Forecasting: evolve fitted waves in time and re-render them with any camera or light.

Protocol
--------
Linear (deep-water) wave trains evolve by their phase alone: a wave seen at time ``t`` is
the same wave ``dt`` seconds later with its phase advanced by ``omega dt``. So a forecast
needs no integration: :func:`advance` shifts phases, and :func:`forecast` evaluates the
sea at any times ``(T,)`` [s]:

* ``forecast(waves, times) -> Forecast`` with ``waves`` of leaves ``(T, N)``: the state of
  every wave at each time, re-expressed at ``t = 0`` (``phase + omega t``, wrapped);
* ``forecast(waves, times, camera)`` adds the per-pixel hierarchical ``geometry``
  (a :class:`jaxocean.render.Geometry` with a leading ``(T,)`` axis) seen by ``camera``;
* ``forecast(waves, times, camera, lighting)`` adds the linear RGB ``image (T, H, W, 3)``.

The camera and the light need not be those of the observation: that is the paper's
re-editing (its Fig. 15-16). Rendering goes through :func:`jaxocean.render.geometry`;
``plan="rows"`` (default) evaluates every wave on the rows fast path (no hit refinement,
the fit's own model), ``plan="auto"`` lets the renderer choose as :func:`jaxocean.render.render` does
(converged hits for close views; the same choice under ``jit``), or pass a :class:`jaxocean.render.RenderPlan`.

Uncertain frequencies: a fitted wave whose frequency is known to ``sigma`` [rad/s] has, a
time ``d`` outside the observed window, a phase known to ``sigma d``. For a Gaussian phase
error the expected wave is the wave times ``exp(-(sigma d)^2 / 2)`` (``E cos(psi + e) =
exp(-var e / 2) cos psi``), so ``forecast(..., window=(t_first, t_last), frequency_sigma=sigma)``
returns that conditional mean -- the least-squares forecast -- instead of extrapolating
phases it does not know: inside the window every wave is kept, far outside it only the
waves whose frequencies are measured remain. :func:`damping` gives the factors;
``jaxocean.fit.waves.forecast_model`` the fit's model and its ``sigma``.

Precision: the phases ``omega t`` are computed in the waves' dtype; concrete times so far from
``t = 0`` that they are rounded by more than :data:`MAX_PHASE_ERROR` (float32: ``|omega t|``
beyond ~8e5 rad) are refused (:func:`check_phase_precision`), except for waves damped to nothing.

Frames: :func:`frame_times` turns frame indices (``0, 100, 500``) into times on the
observed sequence's clock (``t0 + f dt`` with ``dt`` the median frame interval).
Errors: :func:`geometry_error` gives the per-frame mean normal angle and mean absolute
roughness difference between two geometry sequences (the paper's Fig. 13 metric).
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, render, shading
from jaxocean._math import angle_between
from jaxocean.errors import check_values, is_concrete
from jaxocean.waves import MAX_PHASE_ERROR, Waves, check_phase_precision, validate

__all__ = ["Forecast", "GeometryError", "MAX_PHASE_ERROR", "advance", "check_phase_precision", "damping", "forecast",
           "frame_times", "geometry_error"]


class Forecast(NamedTuple):
    """A forecast at ``times (T,)``: advanced ``waves`` (leaves ``(T, N)``), and when a camera
    (and light) was given, ``geometry`` (``Geometry`` with leading ``(T,)``) and ``image``
    ``(T, H, W, 3)`` linear RGB; None otherwise."""

    times: jax.Array
    waves: Waves
    geometry: render.Geometry | None = None
    image: jax.Array | None = None


class GeometryError(NamedTuple):
    """Per-frame errors ``(T,)``: mean normal angle [rad] and mean absolute roughness
    difference over the pixels that are sea, with converged hits, in both sequences."""

    normal: jax.Array
    roughness: jax.Array


def advance(waves: Waves, dt) -> Waves:
    """The same sea ``dt`` seconds later, expressed at ``t = 0``: phases ``phi + omega dt``
    wrapped to [0, 2 pi). ``dt`` may be an array: it broadcasts against the wave axis as
    ``(..., 1)`` (so ``dt (T, 1)`` gives leaves ``(T, N)``)."""
    validate(waves, max_steepness=None)
    dt = jnp.asarray(dt, waves.omega.dtype)
    if is_concrete(dt):
        check_values(np.isfinite(np.asarray(dt)), "dt must be finite [s]", dt)
    check_phase_precision(waves, dt)
    return _advance(waves, dt)


def _advance(waves: Waves, dt) -> Waves:
    phase = jnp.mod(waves.phase + waves.omega * dt, 2 * jnp.pi)
    shape = jnp.broadcast_shapes(phase.shape, waves.omega.shape)
    return Waves(*(jnp.broadcast_to(x, shape) for x in (waves.amplitude, waves.omega, waves.theta)),
                 jnp.broadcast_to(phase, shape))


def damping(frequency_sigma, times, window):
    """Amplitude factors ``(T, N)`` of the least-squares forecast (module docstring):
    ``exp(-(sigma_i d(t))^2 / 2)`` with ``d(t)`` the distance [s] of each of ``times (T,)``
    outside ``window = (t_first, t_last)`` (0 inside it) and ``frequency_sigma (N,)`` the
    waves' 1-sigma frequency uncertainties [rad/s] (0: known exactly, never damped; inf: not
    known at all, 1 inside the window and 0 outside)."""
    sigma = jnp.asarray(frequency_sigma)
    times = jnp.atleast_1d(jnp.asarray(times, sigma.dtype))
    if sigma.ndim != 1 or times.ndim != 1:
        raise ValueError(f"frequency_sigma must be (N,) and times (T,); got {sigma.shape} and {times.shape}")
    lo, hi = (jnp.asarray(w, sigma.dtype) for w in window)
    if is_concrete(sigma, lo, hi):
        check_values(np.asarray(sigma) >= 0, "frequency_sigma must be >= 0 [rad/s] (no NaN)", sigma)
        check_values(np.asarray(hi - lo) >= 0, "window must be (t_first, t_last) with t_first <= t_last",
                     np.asarray(hi - lo))
    d = jnp.maximum(jnp.maximum(lo - times, times - hi), 0.0)[:, None]
    # inside the window the factor is 1 whatever sigma is (inf * 0 would be NaN); an infinite
    # sigma is 0 outside it. Both by where on safe operands, so that no NaN reaches the
    # gradients (the times and the window are shared by every wave)
    outside = d > 0
    known = jnp.isfinite(sigma)[None, :]
    x = jnp.where(outside & known, jnp.where(known, sigma[None, :], 0.0) * d, 0.0)
    return jnp.where(outside & ~known, 0.0, jnp.exp(-0.5 * x ** 2))


def frame_times(times, frames):
    """Times [s] of frame indices ``frames`` on the clock of an observed sequence ``times``:
    ``times[0] + f * dt`` with ``dt`` the median frame interval (needs >= 2 times)."""
    t = np.asarray(times, np.float64)
    if t.ndim != 1 or t.size < 2:
        raise ValueError(f"need the observed frame times (T,), T >= 2; got shape {t.shape}")
    # the times themselves in the message (each one not after the time before it), not their steps
    check_values(np.concatenate([[True], np.diff(t) > 0]), "frame times must be strictly increasing", t)
    f = np.asarray(frames, np.float64)
    check_values(np.isfinite(f), "frame indices must be finite", f)
    return t[0] + f * float(np.median(np.diff(t)))


def forecast(waves: Waves, times, camera=None, lighting=None, *, plan="rows", n_min=hierarchy.DEFAULT_N_MIN,
             n_max=hierarchy.DEFAULT_N_MAX, horizon_gradient=0.0, window=None, frequency_sigma=None) -> Forecast:
    """Evolve ``waves`` (leaves ``(N,)``) to ``times (T,)``; re-render when given a camera (and
    a lighting). See the module docstring. ``window=(t_first, t_last)`` [s] and
    ``frequency_sigma (N,)`` [rad/s], given together: each wave's amplitude at each time
    scaled by :func:`damping` (the least-squares forecast of waves whose frequencies are
    uncertain; the returned ``waves`` carry the scaled amplitudes). Jittable (with a static
    ``plan``) and differentiable in the waves, camera and lighting."""
    validate(waves, max_steepness=None)
    if waves.omega.ndim != 1:
        raise ValueError(f"forecast takes Waves with leaves (N,); got {waves.omega.shape} (vmap batches)")
    if is_concrete(times):
        # checked before the cast to the waves' dtype, which turns a finite 1e300 into inf
        raw = np.asarray(times, np.float64)
        largest = float(np.finfo(np.dtype(waves.omega.dtype)).max)
        check_values(np.abs(raw) <= largest, f"forecast times must be finite and within the waves' "
                     f"{np.dtype(waves.omega.dtype).name} range (|t| <= {largest:.3g} s)", raw)
    times = jnp.atleast_1d(jnp.asarray(times, waves.omega.dtype))
    if times.ndim != 1:
        raise ValueError(f"times must be a scalar or (T,); got shape {times.shape}")
    if (window is None) != (frequency_sigma is None):
        raise ValueError("window and frequency_sigma go together: give both (a damped forecast) or neither")
    scale = None
    if frequency_sigma is not None:
        if jnp.shape(frequency_sigma) != waves.omega.shape:
            raise ValueError(f"frequency_sigma must have one entry per wave {waves.omega.shape}; "
                             f"got {jnp.shape(frequency_sigma)}")
        scale = damping(jnp.asarray(frequency_sigma, waves.omega.dtype), times, window)
    # the phases of the waves each frame draws (a wave damped to nothing draws none)
    check_phase_precision(waves if scale is None else waves._replace(amplitude=waves.amplitude * scale),
                          times[:, None])
    advanced = _advance(waves, times[:, None])
    if scale is not None:
        advanced = advanced._replace(amplitude=advanced.amplitude * scale)
    if camera is None:
        if lighting is not None:
            raise ValueError("rendering an image needs a camera (lighting given without camera)")
        return Forecast(times, advanced)
    cam.validate_camera(camera)
    if isinstance(plan, str) and plan == "rows":
        plan = render.full_plan(waves.omega.shape[0])
    elif isinstance(plan, str) and plan == "auto":
        # one host-side plan for every frame when it can be made; under tracing the renderer
        # applies the same rule inside the compiled function (render.geometry). Damped waves
        # differ from frame to frame and the rule depends on their amplitudes: then every
        # frame takes the rule in the compiled function, eager or traced alike
        if is_concrete(waves, camera) and scale is None:
            plan = render.plan(waves, camera, n_min=n_min, n_max=n_max)
    elif plan is not None and not isinstance(plan, render.RenderPlan):
        raise ValueError(f"plan must be 'rows', 'auto', None or a RenderPlan; got {plan!r}")

    def one(args):
        t, factor = args
        w = waves if factor is None else waves._replace(amplitude=waves.amplitude * factor)
        return render.geometry(w, camera, t, plan=plan, n_min=n_min, n_max=n_max)

    geo = jax.lax.map(one, (times, scale))
    image = None
    if lighting is not None:
        shading.validate_lighting(lighting)

        def shade_one(g):
            return render.shade(g.normal, g.roughness, camera, lighting, slope_variance=g.slope_variance,
                                horizon_gradient=horizon_gradient)

        image = jax.lax.map(shade_one, geo)
    return Forecast(times, advanced, geo, image)


def geometry_error(predicted, truth, mask=None) -> GeometryError:
    """Per-frame mean normal angle [rad] and mean |roughness difference| between two
    geometry sequences (each a ``Geometry`` with leading ``(T,)``, or a pair ``(normal (T,
    H, W, 3), roughness (T, H, W))``). ``mask (H, W)`` or ``(T, H, W)``: pixels to count
    (default: the pixels that are sea with a converged hit in every ``Geometry`` given, else
    all). A frame with no pixel to count has NaN errors: nothing was compared."""
    pn, pr, pm = _unpack_geometry(predicted)
    tn, tr, tm = _unpack_geometry(truth)
    if pn.shape != tn.shape:
        raise ValueError(f"normal shapes differ: {pn.shape} vs {tn.shape}")
    if mask is None:
        mask = jnp.ones(pn.shape[:-1], bool)
        for m in (pm, tm):
            if m is not None:
                mask = mask & m
    mask = jnp.broadcast_to(jnp.asarray(mask, bool), pn.shape[:-1]).astype(pn.dtype)
    # pixels left out may hold NaN (unconverged hits): they count as zero, not as NaN
    angle = jnp.where(mask > 0, angle_between(pn, tn), 0.0)
    count = jnp.sum(mask, axis=(-2, -1))
    safe_count = jnp.maximum(count, 1.0)
    normal = jnp.sum(angle, axis=(-2, -1)) / safe_count
    rough = jnp.sum(jnp.where(mask > 0, jnp.abs(pr - tr), 0.0), axis=(-2, -1)) / safe_count
    return GeometryError(jnp.where(count > 0, normal, jnp.nan), jnp.where(count > 0, rough, jnp.nan))


def _unpack_geometry(g):
    if isinstance(g, render.Geometry):
        # the pixels a geometry vouches for: sea, with a converged hit (render.Geometry)
        mask = jnp.asarray(g.mask) if g.converged is None else jnp.asarray(g.mask) & jnp.asarray(g.converged)
        return jnp.asarray(g.normal), jnp.asarray(g.roughness), mask
    try:
        normal, roughness = g
    except (TypeError, ValueError):
        raise ValueError("expected a Geometry or a pair (normal, roughness)") from None
    return jnp.asarray(normal), jnp.asarray(roughness), None
