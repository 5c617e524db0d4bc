"""The structured Levenberg-Marquardt of the wave fit, :func:`refine` and the fit's result.

Protocol: :func:`refine` takes a scene (see :mod:`jaxocean.fit.waves`) and ``init`` waves
``(N,)`` and returns a :class:`WaveFit`; :func:`refine_kernel` is its jitted core on the
packed parameters ``y (4N,)`` with an ``active (N,)`` mask of real (not padding) waves;
:func:`registry_refine` runs a :mod:`jaxocean.fit.solvers` solver on the same residual.
:func:`normal_error_bound` is the largest mean normal angle [rad] a successful fit may leave.
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import hierarchy
from jaxocean._math import safe_sqrt, sincos
from jaxocean.errors import is_concrete
from jaxocean.fit.waves._inputs import (Samples, all_samples, check_inputs, chunked, clean_inputs, subsample,
                                        valid_weights)
from jaxocean.fit.waves._model import (ROWS, active_waves, bucket_size, height_partials, jacobian, metrics, pack,
                                       pad_waves, predict_jit, rough_data, rough_residual, surface_refine, to_waves,
                                       unpack, wave_phases)
from jaxocean.waves import GRAVITY, MAX_STEEPNESS, Waves, too_steep, validate


#: solver names accepted by :func:`waves` / :func:`refine`: ours first, then the registry's.
SOLVER_NAMES = ("structured", "lm", "gauss_newton", "dogleg", "bfgs", "lbfgsb", "adam", "scipy")
# plausibility of a fit (see waves(): success): the mean normal angle of a fit that explains
# its data is about sqrt(pi/2) sigma for per-component noise sigma; allowed up to 1.5x that,
# and never below 1 mrad (noise-free fits reach 1e-5 rad; half-float EXR frames ~1e-4)
NOISE_FACTOR = 1.5
NORMAL_ERROR_FLOOR = 1e-3
#: ridge weight on the slope amplitudes of held (long-wave band) waves, relative to the mean
#: squared normal residual of the loss
BAND_RIDGE = 1e-3
#: weight of the integrated-height residual (``waves``, heights on: the default) relative to the normal
#: residual: (normal noise / height noise)^2 for 1e-3 rad and 1 cm
HEIGHT_WEIGHT = 1e-2
#: a refinement has converged when a full Gauss-Newton step could lower chi^2 (the residual in
#: units of the stated noise variance) by less than this: the parameters are then within a
#: tenth of their 1-sigma uncertainty of the optimum, and further steps change nothing the
#: data can tell (used where a noise variance is given, ``sigma2 > 0``)
CHI2_TOL = 0.01
#: the stall test of a refinement given ``stall_rtol > 0``: it converges once its last
#: ``STALL_STEPS`` steps lowered the loss by less than ``stall_rtol`` of it in all
STALL_STEPS = 10
_CHUNK_FLOATS = 6_000_000  # per-wave Jacobian entries held at once (24 MB in float32)


class WaveFit(NamedTuple):
    """Result of :func:`waves` / :func:`refine` (arrays only, so ``jax.vmap`` can return it).

    * ``waves``        fitted :class:`~jaxocean.waves.Waves` ``(N,)``, sorted by frequency
      by :func:`waves` (``refine`` keeps the input order).
    * ``uncertainty``  ``Waves`` of 1-sigma standard deviations of (h, omega, theta, phi):
      the local curvature of the loss at the fit, scaled by its residual and, in
      :func:`waves`, by no less than the noise variance its refinement stops at (the stated
      ``noise``, else the floor: the refinement stops within a tenth of these sigmas of the
      optimum). For a wave marked ``determined`` it is the error from noise in the data
      (measured on noise-free 3-wave scenes: errors within 1.2 sigma; from the residual
      alone they were 5-30 sigma). It does not cover a model that misses part of the sea:
      with a swell the view cannot resolve and noise stated, determined waves were 5-12 sigma
      off (``converged`` False); nor the coupling with the long-wave band: on a noise-free
      2-wave 24 x 24, 4-frame scene a determined wave's phase came out 158 deg off with a
      0.008 rad sigma, the band's stand-ins compensating (the waves alone then miss the data
      by 5 deg mean normal error; with the band, 0.01 deg). For an undetermined wave (a
      stand-in for waves the window does not separate) the fitted values can lie many of
      these sigmas from any true wave, and the width is no error bar (:func:`forecast_model`
      widens it).
    * ``loss``         the paper's loss (:mod:`jaxocean.fit.waves`) at the fit.
    * ``normal_error`` mean angle [rad] between fitted and observed normals.
    * ``roughness_error`` mean absolute roughness difference.
    * ``steps``        solver steps of the final refinement (``waves``: summed over the whole
      pipeline).
    * ``success``      :func:`refine`: the solver converged to its tolerances with a finite
      loss (a converged fit can still be a local minimum: read ``normal_error``).
      :func:`waves`: the fitted waves are finite and explain the data -- they leave a mean
      normal error within :func:`normal_error_bound` of its ``noise`` -- and, when it selects
      the count, the selection stopped by its criterion (a fit stopped by ``max_waves`` is
      reported failed: the sea holds more than the cap allows), and no wave is steeper
      than ``k h = 1`` (a looping trochoid crest: no sea surface, and ``render`` refuses
      it). Whether the final refinement also met its tolerances is ``converged``.
    * ``n_waves``      number of fitted waves.
    * ``time_s``       wall time [s] of the eager call (NaN under tracing).
    * ``history``      ``(max_steps + 1,)`` loss after every step, or None.
    * ``determined``   (:func:`waves` only, else None) bool ``(N,)``: the wave is
      :func:`separable` -- resolved by the image and separated from every other fitted wave
      by the observation window, and from its own reverse twin by the frame rate
      (:func:`alias_separation`), so its parameters are measured; the others stand in for
      what the view cannot separate (waves longer than the view, close pairs, a wave whose
      frequency is a multiple of half the frame rate).
    * ``converged``    the (final) refinement met its convergence tolerances (a fit that
      explains its data to well within the noise can still be creeping along the
      ill-conditioned directions of close or long waves when its step budget ends).
    * ``long_waves``   (:func:`waves` with ``long_waves=True`` only, else None) the
      :class:`~jaxocean.fit.waves._band.LongWaveBand`: what the long-wave nuisance band
      absorbed (its fitted stand-in waves, the slope variance they explain, their mean tilt
      per frame). ``normal_error`` and ``loss`` are those of the waves and the band together.
    * ``surface``      (:func:`waves` only, else None) the forward model the fit ended on:
      ``"rows"`` (the geometry at each pixel's plane hit) or ``"hits"`` (at its converged hit
      on the displaced surface, where the waves move the pixels' hits).
    """

    waves: Waves
    uncertainty: Waves
    loss: jax.Array
    normal_error: jax.Array
    roughness_error: jax.Array
    steps: jax.Array
    success: jax.Array
    n_waves: jax.Array
    time_s: jax.Array
    history: jax.Array | None = None
    determined: np.ndarray | None = None
    long_waves: object | None = None
    converged: jax.Array | None = None
    surface: str | None = None


def _chunk_size(n_pad):
    return int(max(64, min(8192, _CHUNK_FLOATS // (30 * max(n_pad, 1)))))


def _gauss_newton(y, active, chunks: Samples, n_min, n_max, moving=False):
    """``J^T J`` over the (sub)sampled chunks (``moving``: at hits that move with the waves)."""
    n = active.shape[0]
    P = unpack(y, n)
    act = active.astype(y.dtype)

    def body(jtj, ch):
        _, J = jacobian(P, act, ch, n_min, n_max, moving)
        return jtj + J.T @ J, None

    jtj, _ = jax.lax.scan(body, jnp.zeros((4 * n, 4 * n), y.dtype), chunks)
    return jtj


def _height_gauss_newton(y, active, chunks: Samples, times, n_min, n_max):
    """``J^T J`` of the integrated-height residual (:func:`_ls_loss`) over the (sub)sampled
    chunks, at the chunks' rest positions held fixed; each frame's free level removed (the
    residual is centred per frame, so its Jacobian is too).

    Model height at a pixel-frame: z = sum_i w_i (a_i cos psi_i - b_i sin psi_i), psi_i =
    omega_i t - k_i . X, with w_i the wave's hierarchy weight at the sample's footprint (as in
    :func:`jacobian`). With W the samples' weights (``sw^2``), the centred product is
    ``J^T W J - sum_t m_t m_t^T / W_t`` with ``m_t = sum_{s in t} W_s J_s``."""
    n = active.shape[0]
    P = unpack(y, n)
    a, b = P[0], P[1]
    act = active.astype(y.dtype)

    def body(acc, ch):
        jtj, m, wt = acc
        _, _, _, _, w, dw_du, _, psi, dpsi_du, dpsi_dth = wave_phases(P, act, ch, n_min, n_max)
        sp, cp = sincos(psi)
        cn, snn = a * cp - b * sp, a * sp + b * cp  # h cos psi and h sin psi
        J = height_partials(w, cp, sp, cn, snn, dw_du, dpsi_du, dpsi_dth).reshape(ch.t.shape[0], 4 * n)
        W = ch.sw ** 2
        frame = (ch.t[:, None] == times[None, :]).astype(y.dtype) * W[:, None]  # (S, T)
        return (jtj + J.T @ (J * W[:, None]), m + frame.T @ J, wt + jnp.sum(frame, 0)), None

    zero = (jnp.zeros((4 * n, 4 * n), y.dtype), jnp.zeros((times.shape[0], 4 * n), y.dtype),
            jnp.zeros(times.shape, y.dtype))
    (jtj, m, wt), _ = jax.lax.scan(body, zero, chunks)
    return jtj - m.T @ (m / jnp.maximum(wt, 1e-30)[:, None])


# =============================================================================== structured LM


class _LMOut(NamedTuple):
    y: jax.Array
    loss: jax.Array
    steps: jax.Array
    success: jax.Array
    jtj: jax.Array
    history: jax.Array


def _ls_loss(y, active, normals, weight, times, camera, rough, tail_rows, scale, n_min, n_max, refine,
             heights=None):
    """``(0.5 |r|^2, xy)``: the loss through ``render.geometry`` (normals) plus the roughness
    rows, and the rest positions ``(T, H, W, 2)`` the model's pixels see (its hits).
    ``heights``: None, or ``(z, mask, weight[, basis])`` integrated heights ``(T, H, W)`` and
    where to use them: the model's height at each pixel's hit against them, per frame the
    level free, or (with ``basis (T, K, H, W)``, its first function the constant) the
    weighted least-squares combination of the basis functions."""
    pred = predict_jit(active_waves(y, active), camera, times, n_min, n_max, refine, heights is not None, True)
    d = (pred.normal[..., :2] - normals[..., :2])
    half = 0.5 * scale * jnp.sum(d * d * weight[..., None])
    if heights is not None:
        z, mask, rho = heights[:3]
        m = mask * weight
        e = jnp.where(m > 0, pred.z - z, 0.0)
        if len(heights) > 3:
            # the trend's per-frame coefficients at their weighted least-squares optimum (a
            # tiny ridge: a frame with too few used pixels has a singular system)
            B = heights[3]
            G = jnp.einsum("tkhw,tlhw,thw->tkl", B, B, m)
            G = G + 1e-9 * jnp.maximum(jnp.sum(m, (1, 2)), 1.0)[:, None, None] * jnp.eye(G.shape[-1], dtype=G.dtype)
            c = jnp.linalg.solve(G, jnp.einsum("tkhw,thw->tk", B, e * m)[..., None])[..., 0]
            e = e - jnp.einsum("tk,tkhw->thw", c, B)
        else:
            e = e - (jnp.sum(e * m, (1, 2)) / jnp.maximum(jnp.sum(m, (1, 2)), 1.0))[:, None, None]
        half = half + 0.5 * scale * rho * jnp.sum(e * e * m)
    rr = rough_residual(y, active, rough, tail_rows, n_min, n_max)
    return half + 0.5 * jnp.sum(rr * rr), pred.xy


def _hessian_samples(n_pad: int, m_total: int) -> int:
    """Samples for ``J^T J``: ``32 x 4 n_pad`` (32 per parameter), at least 16384, at most
    all of them; the gradient always uses every sample."""
    return int(min(m_total, max(16384, 32 * 4 * n_pad)))


def _steepness_projection(y, n, max_steepness):
    """``y`` with every wave's amplitude lowered to at most ``max_steepness / k`` (phase kept):
    the projection of a projected Levenberg-Marquardt onto the waves that exist (the
    structured LM projects onto :data:`jaxocean.waves.MAX_STEEPNESS`, what ``render`` accepts)."""
    a, b, u, th = unpack(y, n)
    k = jnp.exp(2.0 * u) / GRAVITY
    kh = k * jnp.sqrt(a * a + b * b)
    shrink = jnp.minimum(1.0, max_steepness / jnp.maximum(kh, 1e-30))
    return jnp.concatenate([a * shrink, b * shrink, u, th])


def _structured_lm(y0, active, held, normals, weight, times, camera, rough, tail_rows, *, scale, n_min, n_max,
                   max_steps, rtol, atol, hessian_samples, history_len, refine=ROWS, sigma2=0.0, xtol=1e-7,
                   heights=None, exact_heights=False, stall_rtol=0.0):
    """Levenberg-Marquardt with structured normal equations (:mod:`jaxocean.fit.waves`, step 4).

    The gradient ``J^T r`` is exact (every pixel-frame); ``J^T J`` comes from an evenly
    spread subset of ``hessian_samples`` pixel-frames, rescaled by the weight ratio. The
    accept test uses the exact loss through ``render.geometry``, so an approximate
    ``J^T J`` only slows convergence near the optimum, it does not move it. ``held (N,)``:
    waves whose ``log omega`` and ``theta`` stay fixed (only their ``a, b`` are fitted).
    ``refine``: the forward model's path (``ROWS`` or ``HITS``); on the hits path ``J^T J``
    is taken at the current hits, with their motion (:func:`jacobian`'s ``moving``).
    ``sigma2 > 0``: the noise variance per normal component; an accepted step after which a
    full Gauss-Newton step could lower chi^2 by less than :data:`CHI2_TOL` also converges.
    ``exact_heights``: the height residual's ``J^T J`` block in full (cross terms, each
    frame's level projected out: :func:`_height_gauss_newton`) rather than its diagonal.
    ``stall_rtol > 0``: the refinement also converges once its last :data:`STALL_STEPS` steps
    lowered the loss by less than ``stall_rtol`` of it in all (0: off).
    """
    n = active.shape[0]
    samples = all_samples(normals[..., :2], weight, times, camera, scale)
    size = _chunk_size(n)
    sub = subsample(samples, hessian_samples)
    ratio = jnp.sum(samples.sw ** 2) / jnp.maximum(jnp.sum(sub.sw ** 2), 1e-30)

    def hessian_chunks(xy):
        # the subsample at the model's current hits (the rows path's never move)
        if refine == ROWS:
            return chunked(sub, size)
        return chunked(subsample(all_samples(normals[..., :2], weight, times, camera, scale, xy), hessian_samples),
                       size)
    act4 = jnp.concatenate([active, active, active & ~held, active & ~held])
    dtype = y0.dtype

    def height_term(y, xy):
        # the integrated heights' J^T J from an evenly spread subsample at the current hits
        if not exact_heights:
            return 0.0
        used = heights[1] * weight
        hs = all_samples(jnp.zeros(used.shape + (2,), dtype), used, times, camera, scale * heights[2], xy)
        sub_h = subsample(hs, hessian_samples)
        ratio_h = jnp.sum(hs.sw ** 2) / jnp.maximum(jnp.sum(sub_h.sw ** 2), 1e-30)
        return _height_gauss_newton(y, active, chunked(sub_h, size), times, n_min, n_max) * ratio_h

    def normal_eq(y):
        # the exact gradient of the very loss the accept test uses (reverse mode through
        # render.geometry: the rank-N rows path, or the converged hits with their implicit
        # derivative), J^T J from the structured subsample
        # the hits come with the gradient's own forward pass, not a second render
        jtr, xy = jax.grad(f_and_hits, has_aux=True)(y)
        jtj = _gauss_newton(y, active, hessian_chunks(xy), n_min, n_max, refine != ROWS) * ratio
        jtj = jtj + height_term(y, xy)
        _, jr = jax.linearize(lambda yy: rough_residual(yy, active, rough, tail_rows, n_min, n_max), y)
        Jr = jax.vmap(jr, out_axes=1)(jnp.eye(4 * n, dtype=dtype))  # (H, 4N)
        jtj = jtj + Jr.T @ Jr + jnp.diag(jnp.concatenate([ridge + height_diag, ridge + height_diag,
                                                         jnp.zeros_like(ridge), jnp.zeros_like(ridge)]))
        # inactive (padding) parameters: identity rows, zero gradient
        jtj = jnp.where(act4[:, None] & act4[None, :], jtj, jnp.diag(jnp.where(act4, 0.0, 1.0)).astype(dtype))
        jtr = jnp.where(act4, jtr, 0.0)
        return jtj, jtr

    # a weak ridge on the held waves' slope amplitudes k (a, b): the long-wave band's
    # neighbouring wave vectors are nearly collinear over the window, and without it the
    # solver crawls along their valley (the bias is BAND_RIDGE / (1/2 + BAND_RIDGE) of a band
    # wave's amplitude)
    ridge = BAND_RIDGE * (held & active).astype(dtype) * jnp.exp(4.0 * unpack(y0, n)[2]) / GRAVITY ** 2  # k^2

    # the height residual's Gauss-Newton diagonal on the amplitudes (a, b): each moves its
    # wave's height by cos / sin of the phase, mean square 1/2 over the used pixels. Only the
    # diagonal unless ``exact_heights``: with the exact block a refinement of a few waves
    # converges in far fewer steps, but the greedy selection, whose batches get 8 steps,
    # lands in worse optima -- 3 of 8 Table 2 scenes succeed against 5 of 8 with this
    # diagonal, both measured without the selection's near-floor refinement
    # (experiments/WAVES.md; why is not measured)
    height_diag = jnp.zeros_like(ridge)
    if heights is not None and not exact_heights:
        height_diag = 0.5 * scale * heights[2] * jnp.sum(heights[1] * weight) * active.astype(dtype)

    def prior(y):
        P = unpack(y, n)
        return 0.5 * jnp.sum(ridge * (P[0] ** 2 + P[1] ** 2))

    def f_and_hits(y):
        loss, xy = _ls_loss(y, active, normals, weight, times, camera, rough, tail_rows, scale, n_min, n_max, refine,
                            heights)
        return loss + prior(y), xy

    def f(y):
        return f_and_hits(y)[0]

    eps = jnp.finfo(dtype).eps

    class S(NamedTuple):
        y: jax.Array
        f: jax.Array
        jtj: jax.Array
        jtr: jax.Array
        lam: jax.Array
        nu: jax.Array
        k: jax.Array
        done: jax.Array
        conv: jax.Array
        hist: jax.Array
        recent: jax.Array  # (STALL_STEPS,) the loss after each of the last steps, a ring
        start: jax.Array  # the start is not evaluated yet

    def cond(s):
        return s.start | ((~s.done) & (s.k < max_steps))

    # The loop's first pass evaluates the start: with the placeholder J^T r = 0 its step is
    # exactly zero, the projection puts y0 on the steepness bound, and the result is accepted.
    # The loss and the normal equations are then traced once each, not once for the start
    # and once for the steps, which on the hits path about halves the compilation
    # (measured in experiments/WAVES.md).
    def body(s):
        d = jnp.diag(s.jtj)
        dmax = jnp.max(d)
        dsc = jnp.maximum(d, 1e-9 * dmax + 1e-30)
        A = s.jtj + s.lam * jnp.diag(dsc)
        step = -jnp.linalg.solve(A, s.jtr)
        ok_step = jnp.all(jnp.isfinite(step))
        step = jnp.where(ok_step, step, 0.0)
        # projected LM: a step that would make a wave steeper than MAX_STEEPNESS stops at it
        y_try = _steepness_projection(s.y + step, n, MAX_STEEPNESS)
        step = y_try - s.y
        f_try = f(y_try)
        pred = -(step @ s.jtr) - 0.5 * step @ (s.jtj @ step)
        actual = s.f - f_try
        rho = actual / jnp.where(pred > 0, pred, 1.0)
        accept = s.start | (ok_step & jnp.isfinite(f_try) & (actual > 0) & (pred > 0) & (rho > 1e-4))

        def on_accept(_):
            jtj, jtr = normal_eq(y_try)
            lam = jnp.where(s.start, s.lam, s.lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3))
            return y_try, f_try, jtj, jtr, lam, jnp.asarray(2.0, dtype)

        def on_reject(_):
            return s.y, s.f, s.jtj, s.jtr, s.lam * s.nu, s.nu * 2.0

        y, fv, jtj, jtr, lam, nu = jax.lax.cond(accept, on_accept, on_reject, None)
        # convergence: a small relative decrease on an accepted step, a negligible step,
        # a loss at the absolute floor, or damping so large that no step can help
        rel = jnp.abs(actual) <= rtol * jnp.maximum(s.f, eps)
        small = jnp.max(jnp.abs(step) / (jnp.abs(s.y) + 1.0)) < xtol
        floor = fv - prior(y) <= atol  # the data term: the ridge is no misfit
        stalled = lam > 1e12
        # the Gauss-Newton decrement at the new point, in chi^2 units (residuals are scaled
        # by sqrt(scale)): negative or non-finite (an ill-conditioned solve) never converges
        g_step = jnp.linalg.solve(jtj + 1e-9 * jnp.max(jnp.diag(jtj)) * jnp.eye(jtj.shape[0], dtype=dtype), jtr)
        decrement = 0.5 * (jtr @ g_step)
        chi2_gain = 2.0 * decrement / (scale * jnp.where(sigma2 > 0, sigma2, 1.0))
        insignificant = (sigma2 > 0) & jnp.isfinite(chi2_gain) & (chi2_gain >= 0) & (chi2_gain <= CHI2_TOL)
        # the stall test: the loss STALL_STEPS steps ago sits in the ring slot this step takes
        k_new = s.k + 1
        slot = k_new % STALL_STEPS
        stalled_progress = ((stall_rtol > 0) & (k_new >= STALL_STEPS)
                            & (s.recent[slot] - fv <= stall_rtol * jnp.maximum(fv, eps)))
        conv = (accept & (rel | insignificant)) | small | floor | stalled | stalled_progress
        recent = jnp.where(s.start, jnp.full_like(s.recent, fv), s.recent.at[slot].set(fv))
        hist = jnp.where(jnp.arange(history_len) > s.k, fv, s.hist)
        done = conv | ~jnp.isfinite(fv)
        conv = conv & jnp.isfinite(fv)
        # the start's pass: no step taken, converged only at the absolute floor
        return S(y, fv, jtj, jtr, lam, nu, jnp.where(s.start, s.k, s.k + 1), jnp.where(s.start, floor, done),
                 jnp.where(s.start, floor, conv), jnp.where(s.start, jnp.full_like(s.hist, fv), hist), recent,
                 jnp.zeros_like(s.start))

    p = y0.shape[0]
    s0 = S(y0, jnp.asarray(jnp.inf, dtype), jnp.eye(p, dtype=dtype), jnp.zeros(p, dtype), jnp.asarray(1e-3, dtype),
           jnp.asarray(2.0, dtype), jnp.asarray(0, jnp.int32), jnp.asarray(False), jnp.asarray(False),
           jnp.zeros((history_len,), dtype), jnp.zeros((STALL_STEPS,), dtype), jnp.asarray(True))
    s = jax.lax.while_loop(cond, body, s0)
    success = s.conv & jnp.isfinite(s.f) & jnp.all(jnp.isfinite(s.y))
    return _LMOut(s.y, s.f, s.k, success, s.jtj, s.hist)


def refine_kernel(y0, active, normals, roughness, times, camera, tail_rows, rtol, atol, *, n_min, n_max,
                  max_steps, roughness_weight, hessian_samples=None, history=False, held=None, refine=ROWS,
                  sigma2=0.0, heights=None, exact_heights=False, stall_rtol=0.0):
    """The structured LM on packed parameters ``y0 (4N,)``; ``active (N,)`` marks real waves,
    ``held (N,)`` (default none) waves whose ``omega`` and ``theta`` stay fixed; ``refine``
    the forward model's path (``ROWS``; ``HITS``: the pixel-frames whose hit under ``y0``
    does not converge are left out of the whole refinement); ``sigma2``: the noise variance
    of the chi^2 convergence test (0: off); ``heights``: None or ``(z, mask, weight[, basis])``
    integrated heights the model's hits are also held to (:func:`_ls_loss`);
    ``exact_heights``: their exact Gauss-Newton block in ``J^T J`` instead of its diagonal
    (level-only heights); ``stall_rtol``: the stall test's tolerance (0: off; :data:`STALL_STEPS`).
    Returns ``(out, n_valid)``."""
    if exact_heights and (heights is None or len(heights) != 3):
        raise ValueError("exact_heights needs the integrated heights with each frame's level alone left free "
                         "(heights=(z, mask, weight), no trend basis)")
    held = jnp.zeros(active.shape, bool) if held is None else jnp.asarray(held, bool)
    if hessian_samples is None:
        hessian_samples = _hessian_samples(active.shape[0], int(np.prod(normals.shape[:3])))
    # max_steps and the roughness weight are traced (one compilation serves every step budget
    # and weight); the history's length is static and only as long as asked for
    return _refine_jit(y0, active, held, normals, roughness, times, camera, tail_rows, rtol, atol,
                       jnp.asarray(max_steps, jnp.int32), jnp.asarray(sigma2, y0.dtype), heights,
                       jnp.asarray(roughness_weight, y0.dtype), jnp.asarray(stall_rtol, y0.dtype), n_min=n_min,
                       n_max=n_max, hessian_samples=int(hessian_samples),
                       history_len=int(max_steps) + 1 if history else 1, refine=int(refine),
                       exact_heights=bool(exact_heights))


@functools.partial(jax.jit, static_argnames=("n_min", "n_max", "hessian_samples", "history_len", "refine",
                                             "exact_heights"))
def _refine_jit(y0, active, held, normals, roughness, times, camera, tail_rows, rtol, atol, max_steps, sigma2,
                heights, roughness_weight, stall_rtol, *, n_min, n_max, hessian_samples, history_len, refine,
                exact_heights):
    weight = valid_weights(normals, camera)
    normals, roughness = clean_inputs(normals, roughness, weight)
    if refine != ROWS:
        start = predict_jit(active_waves(y0, active), camera, times, n_min, n_max, refine)
        weight = weight * start.converged
    n_valid = jnp.maximum(jnp.sum(weight), 1.0)
    scale = 1.0 / n_valid
    rough = rough_data(roughness, weight, camera, n_valid, roughness_weight, tail_rows)
    out = _structured_lm(y0, active, held, normals, weight, times, camera, rough, tail_rows, scale=scale, n_min=n_min,
                         n_max=n_max, max_steps=max_steps, rtol=rtol, atol=atol, hessian_samples=hessian_samples,
                         history_len=history_len, refine=refine, sigma2=sigma2,
                         heights=heights, exact_heights=exact_heights, stall_rtol=stall_rtol)
    return out, n_valid


# =============================================================================== generic (registry) path


def registry_refine(y0, active, normals, roughness, times, camera, tail_rows, *, solver, n_min, n_max,
                    max_steps, rtol, atol, roughness_weight, history, options):
    """Refine with a registry solver; returns ``(out, n_valid, residual)``, ``residual(y, _)``
    the problem's residual (for :func:`dense_jtj`)."""
    from jaxocean.fit import solvers

    weight = valid_weights(normals, camera)
    normals, roughness = clean_inputs(normals, roughness, weight)
    n_valid = jnp.maximum(jnp.sum(weight), 1.0)
    scale = 1.0 / n_valid
    rough = rough_data(roughness, weight, camera, n_valid, roughness_weight, tail_rows)
    sw = jnp.sqrt(weight * scale)[..., None]
    residual = _registry_residual(float(n_min), float(n_max))
    args = (active, normals, sw, rough, tail_rows, camera, times)
    out = solvers.solve(solver, residual, y0, args, max_steps=max_steps, rtol=rtol, atol=atol, history=history,
                        options=options)
    return out, n_valid, lambda y, _: residual(y, args)


@functools.lru_cache(maxsize=None)
def _registry_residual(n_min: float, n_max: float):
    """The registry path's residual ``(y, args) -> r``, one function object per hierarchy:
    the data travel in ``args``, so a solver compiled for one fit serves the next of the
    same shapes (a closure over the data would be compiled again every call)."""

    def residual(y, args):
        active, normals, sw, rough, tail_rows, camera, times = args
        n_pred = predict_jit(active_waves(y, active), camera, times, n_min, n_max).normal
        r_n = ((n_pred[..., :2] - normals[..., :2]) * sw).ravel()
        return jnp.concatenate([r_n, rough_residual(y, active, rough, tail_rows, n_min, n_max)])

    return residual


# =============================================================================== uncertainty


def _uncertainty(y, jtj, active, half_rss, n_obs, sigma2_floor=0.0):
    """1-sigma of (h, omega, theta, phi) from the Gauss-Newton covariance.

    The variance of each derived quantity ``q(y)`` is the quadratic form ``g^T C g`` with
    ``g = dq/dy`` and ``C = sigma^2 (J^T J)^-1``, evaluated through the eigenvectors of the
    Jacobi-scaled ``J^T J`` as ``sigma^2 sum_k (g . v_k)^2 / lambda_k``: a sum of
    non-negative terms, where the diagonal of an explicit float32 inverse can come out
    negative (the Jacobi-scaled ``J^T J`` of a Table 2 scene at its truth has a condition
    number near 1/eps, and 13 of its 60 amplitude variances are negative that way).
    Eigenvalues below ``eps x`` the largest
    are raised to it, so directions the data do not determine get a large, finite variance;
    standard deviations are not floored (noise-free fits have 1e-10 m).
    """
    n = active.shape[0]
    dof = jnp.maximum(n_obs - 4.0 * jnp.sum(active), 1.0)
    # half_rss is 0.5 |r|^2 of residuals scaled by 1/sqrt(P); sigma^2 in those units
    # not below the noise variance the refinement stops at (CHI2_TOL is a tenth of a sigma at it)
    sigma2 = jnp.maximum(2.0 * half_rss / dof, 2.0 * sigma2_floor / n_obs)
    d = jnp.sqrt(jnp.maximum(jnp.diag(jtj), 1e-30))
    lam, vec = jnp.linalg.eigh(jtj / d[:, None] / d[None, :])
    lam = jnp.maximum(lam, jnp.finfo(jtj.dtype).eps * jnp.max(lam))
    # eigenvector rows by parameter block (a, b, log omega, theta) in unscaled coordinates:
    # (4, N, 4N), so that a quantity of wave i projects onto the eigenvectors through its own
    # parameters only
    rows = (vec / d[:, None]).reshape(4, n, 4 * n)
    a, b, u, _ = unpack(y, n)
    h2 = jnp.maximum(a * a + b * b, 1e-30)
    h = jnp.sqrt(h2)

    def std(*grad):
        # grad: ((block, d quantity / d parameter (N,)), ...) of each wave's quantity
        proj = sum(g[:, None] * rows[k] for k, g in grad)  # (N, 4N)
        return safe_sqrt(sigma2 * jnp.sum(proj * proj / lam, axis=-1), floor=0.0)

    stds = (std((0, a / h), (1, b / h)), std((2, jnp.exp(u))), std((3, jnp.ones_like(a))),
            std((0, -b / h2), (1, a / h2)))
    return Waves(*[jnp.where(active, s, 0.0) for s in stds])


# =============================================================================== refine (public)


def refine(normals, roughness, camera, times, init: Waves, *, solver: str = "structured", max_steps: int = 50,
           rtol=1e-6, atol=0.0, roughness_weight: float = 1.0, n_min=hierarchy.DEFAULT_N_MIN,
           n_max=hierarchy.DEFAULT_N_MAX, history: bool = False, options=None, tail_rows=None,
           throw: bool = False, surface: str = "rows") -> WaveFit:
    """Refine ``init`` waves (fixed count) against observed geometry; returns a :class:`WaveFit`.

    Pure and traceable for every solver but ``"scipy"``: ``jax.vmap`` over scenes (batched
    normals, roughness, cameras, times and init waves) works and returns arrays. Gradients
    of the result with respect to the data flow through the registry solvers' implicit
    adjoints; the ``"structured"`` solver's loop is not reverse-differentiable (use
    ``"lm"`` for gradients through a fit). ``tail_rows (H,)``: a fixed roughness offset per
    row for waves outside the fitted set; without it the roughness term assumes that
    ``init`` holds every wave (pass ``roughness_weight=0`` otherwise). ``throw``: raise
    :class:`jaxocean.fit.solvers.FitError` (eagerly) when the solver did not converge.
    ``surface``: the forward model -- ``"rows"`` (default: the geometry at each pixel's plane
    hit), ``"hits"`` (at its converged hit on the displaced surface, as ``render`` draws waves
    that move the hits; about 10x the cost; ``"structured"`` solver only) or ``"auto"`` (the
    renderer's choice for ``init``; eager only).
    """
    t0 = time.perf_counter()
    normals, roughness, times = check_inputs(normals, roughness, camera, times)
    validate(init, max_steepness=None)
    if init.omega.ndim != 1:
        raise ValueError(f"init must have leaves (N,); got {init.omega.shape} (vmap batches of scenes)")
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVER_NAMES}")
    if surface == "auto" and not is_concrete(init, camera):
        raise ValueError("surface='auto' chooses the model eagerly; under jit/vmap pass 'rows' or 'hits'")
    refine_ = surface_refine(surface, init if surface == "auto" else None, camera, n_min=n_min, n_max=n_max)
    if refine_ != ROWS and solver != "structured":
        raise ValueError(f"surface='hits' needs solver='structured'; got {solver!r}")
    if throw and not is_concrete(normals, init, roughness, times, camera):
        raise ValueError("fit.refine under jit/vmap cannot raise on failure: pass throw=False and read .success")
    dtype = normals.dtype
    init = Waves(*[jnp.asarray(x, dtype) for x in init])
    H = camera.resolution[0]
    tail_rows = jnp.zeros(H, dtype) if tail_rows is None else jnp.asarray(tail_rows, dtype)
    n = init.omega.shape[0]
    if roughness is None:
        roughness_weight = 0.0
    if solver == "structured":
        # pad to a bucket size so that nearby wave counts share one compilation -- traced or
        # not (the count is a shape), so a jitted call computes what the eager one does
        n_pad = bucket_size(n)
        padded, active = pad_waves(init, n_pad)
        out, n_valid = refine_kernel(pack(padded), active, normals, roughness, times, camera, tail_rows,
                                     jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), n_min=n_min, n_max=n_max,
                                     max_steps=max_steps, roughness_weight=float(roughness_weight), history=history,
                                     refine=refine_)
        y, steps, success, jtj, hist = out.y, out.steps, out.success, out.jtj, out.history
        half = out.loss
        res = fit_result(y, active, jtj, half, n_valid, normals, roughness, camera, times, steps, success,
                         hist if history else None, roughness_weight, n_min, n_max, t0, refine_)
        if n_pad != n:
            cut = lambda w: Waves(*[x[:n] for x in w])  # noqa: E731
            res = res._replace(waves=cut(res.waves), uncertainty=cut(res.uncertainty), n_waves=jnp.asarray(n))
        return maybe_throw(res, throw, max_steps)
    else:
        y0 = pack(init)
        active = jnp.ones(n, bool)
        out, n_valid, residual = registry_refine(y0, active, normals, roughness, times, camera, tail_rows,
                                                 solver=solver, n_min=n_min, n_max=n_max, max_steps=max_steps,
                                                 rtol=rtol, atol=atol, roughness_weight=roughness_weight,
                                                 history=history, options=options)
        y, steps, success, hist, half = out.params, out.steps, out.success, out.history, out.loss
        jtj = dense_jtj(residual, y)
    res = fit_result(y, active, jtj, half, n_valid, normals, roughness, camera, times, steps, success,
                     hist if history else None, roughness_weight, n_min, n_max, t0)
    return maybe_throw(res, throw, max_steps)


def normal_error_bound(noise=None) -> float:
    """Largest mean normal angle [rad] a successful :func:`waves` fit may leave:
    ``max(NOISE_FACTOR sqrt(pi/2) noise, NORMAL_ERROR_FLOOR)`` (sqrt(pi/2) sigma is the mean
    angle of per-component Gaussian noise sigma on near-vertical normals). Without
    ``noise`` the data are taken to be noise-free up to storage precision: noisy geometry
    (network predictions, real images) needs ``noise=`` or it is reported failed."""
    sigma = 0.0 if noise is None else float(noise)
    return max(NOISE_FACTOR * math.sqrt(math.pi / 2) * sigma, NORMAL_ERROR_FLOOR)


def maybe_throw(res: WaveFit, throw: bool, max_steps, capped: bool = False, unexplained_bound=None):
    if throw and is_concrete(res.success) and not bool(res.success):
        from jaxocean.fit.solvers import FitError

        steep = too_steep(res.waves)
        if steep.any():
            raise FitError(f"{int(steep.sum())} of {steep.size} fitted waves are steeper than k h = 1 (looping "
                           "crests: no sea surface, and render refuses them); the fit explains the data with waves "
                           "that cannot exist (noisy geometry without noise=?); the result is attached as .result",
                           res)
        if unexplained_bound is not None and not capped:
            raise FitError(f"wave fit leaves a mean normal error of {float(res.normal_error):.3e} rad, above "
                           f"{unexplained_bound:.1e} rad for its noise: the {int(res.n_waves)} waves do not explain "
                           "the data (waves near the Nyquist limit? noisy geometry without noise=?); the result "
                           "is attached as .result", res)
        if capped:
            raise FitError(f"wave fit stopped at max_waves={int(res.n_waves)} while the criterion still accepted "
                           f"waves (normal error {float(res.normal_error):.3e} rad): raise max_waves; the result "
                           "is attached as .result", res)
        raise FitError(f"wave fit did not converge within {max_steps} steps (loss {float(res.loss):.3e}, "
                       f"{int(res.n_waves)} waves); the result is attached as .result", res)
    return res


def dense_jtj(residual, y):
    """``J^T J`` of ``residual(y, None)`` by the solvers' blocked forward-mode Jacobian
    (:func:`jaxocean.fit.solvers.value_and_jacobian`: jax.jacfwd's single vmap of 4N JVPs
    hits the XLA:CPU float32 miscompile described there)."""
    from jaxocean.fit.solvers import value_and_jacobian

    _, J = value_and_jacobian(residual, y, None)
    return J.T @ J


def fit_result(y, active, jtj, half, n_valid, normals, roughness, camera, times, steps, success, hist,
               roughness_weight, n_min, n_max, t0, refine=ROWS, sigma2=0.0):
    n = active.shape[0]
    w = to_waves(y, n)
    unc = _uncertainty(y, jtj, active, half, 2.0 * n_valid, sigma2)
    lval, nerr, rerr = metrics(w, normals, roughness, camera, times, roughness_weight, n_min, n_max, refine)
    elapsed = time.perf_counter() - t0 if is_concrete(y) else float("nan")
    return WaveFit(waves=w, uncertainty=unc, loss=lval, normal_error=nerr, roughness_error=rerr,
                   steps=jnp.asarray(steps, jnp.int32), success=jnp.asarray(success), n_waves=jnp.asarray(n),
                   time_s=jnp.asarray(elapsed, y.dtype), history=hist, converged=jnp.asarray(success))

