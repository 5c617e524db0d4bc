"""Detection and order selection of the wave fit: :func:`waves` (:mod:`jaxocean.fit.waves`, step 3).

Protocol: :func:`waves` takes a scene and returns a :class:`jaxocean.fit.waves.WaveFit`
(and the :class:`OrderSelection` path with ``return_selection=True``). Candidates come from
the spectral estimate of the residual plus a polar grid of long waves, are scored and
refined one by one on a subsample and solved jointly for their amplitudes
(:mod:`jaxocean.fit.waves._candidates`), added in batches while the information criterion
improves, the whole set is refined by the structured Levenberg-Marquardt of
:mod:`jaxocean.fit.waves._lm`, and optionally pruned (:mod:`jaxocean.fit.waves._prune`).
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, shading
from jaxocean._math import angle_between
from jaxocean.errors import InvalidValueError, check_nonnegative_number, check_values, is_concrete
from jaxocean.fit.waves._inputs import (all_samples, check_inputs, clean_inputs, slope_field, subsample,
                                        valid_weights)
from jaxocean.fit.waves._lm import (HEIGHT_WEIGHT, NOISE_FACTOR, NORMAL_ERROR_FLOOR, SOLVER_NAMES, WaveFit, dense_jtj,
                                    fit_result, maybe_throw, normal_error_bound, refine_kernel, registry_refine)
from jaxocean._roughness import normal_weight, observed_rows, row_roughness
from jaxocean.fit.waves._model import (HITS, ROWS, SURFACES, bucket_size, pack, pad_waves, predict_jit,
                                       surface_refine, to_waves)
from jaxocean.fit.waves._band import band_waves, summary as band_summary, view_diameter
from jaxocean.fit.waves._match import noise_cells, rayleigh_separation, resolvable, separable
from jaxocean.fit.waves._spectral import grid_frames, spectral_pyramid
from jaxocean.fit.waves._candidates import joint_amplitudes, refine_candidates, score_candidates
from jaxocean.fit.waves._prune import correlated_discount, merge_close_pairs, unseparated_weaker, wald_keep
from jaxocean.waves import GRAVITY, Waves, too_steep, validate, wavelength


_CRITERIA = ("bic", "aic", "holdout")
#: ``surface="auto"`` fits on the hits path once the model's rows-path and hits-path normals
#: differ by more than this fraction of the success bound (:func:`normal_error_bound`)
SURFACE_TOLERANCE = 0.5
#: once the data chose the rows path over the hits path (the rows path's residual no larger),
#: the hits path is tried again only when the rows path's residual has fallen this many times,
#: and at most SURFACE_TRIES times in all (each try refits on the hits path, about 10x the
#: cost per step)
SURFACE_RETRY = 4.0
SURFACE_TRIES = 3
#: ``waves`` (heights on: the default) uses the integrated heights where a pixel's footprint is at most
#: this [m] (``experiments/WAVES.md``, heights from normals: farther out they drift)
HEIGHT_FOOTPRINT = 1.0
#: what of each frame's integrated heights ``waves`` leaves free (``height_trend``): their
#: level alone, or with it a plane or a quadratic in the mean-sea-plane coordinates
HEIGHT_TRENDS = ("level", "plane", "quadratic")
#: the criterion's default noise floor: the per-component sigma of the normals whose mean
#: angle ``sqrt(pi/2) sigma`` times ``NOISE_FACTOR`` is the success bound of noise-free data
DEFAULT_NOISE_FLOOR = NORMAL_ERROR_FLOOR / (NOISE_FACTOR * math.sqrt(math.pi / 2))
#: the selection refines an accepted model longer (4x its trials' steps) before adding more
#: waves once its residual is within this factor of the noise floor: there the trials' few
#: steps, not missing waves, may be all that is left (measured on a Table 2 scene: the loop
#: reached the 96-wave cap at 1.05x the floor, and the capped fit explained its data to
#: 1.9e-4 rad after its final refinement, ``experiments/WAVES.md``)
POLISH_FACTOR = 10.0
#: the fraction of ``separation`` a candidate may stand from a model wave once the model has
#: stalled more than POLISH_FACTOR above the floor with no admissible candidate left (then
#: candidates the view does not resolve are admitted too: the data demand more waves, and
#: noise-free data resolve waves closer than the Rayleigh limit)
CROWDED_SEPARATION = 0.5
#: the candidate pool makes room for the strongest candidates the image resolves (when none
#: of the strongest is resolvable: a swell longer than the view fills the residual's
#: spectrum) only while the residual per component is more than this factor above the noise
#: (the floor, or the stated noise): near it, what the swell leaves is the long-wave band's
#: to absorb, and resolvable candidates there are stand-ins (measured on a 4-wave swell with
#: 3 waves resolvable: at 7x the floor the rule added 11 stand-ins, 14 waves for 3)
POOL_FACTOR = 100.0
#: ``merge_separation``'s refits: every close pair merged at once, then (if that refit is
#: reverted) the closest half of them, then the closest quarter
MERGE_TRIES = 3


class NoWaveFound(InvalidValueError):
    """:func:`waves` found no wave that explains more of the data than the criterion's
    penalty at the noise (a flat sea, or geometry whose waves are below its stated noise)."""


class OrderSelection(NamedTuple):
    """The path of the greedy model-order selection: one entry per tried wave count."""

    n_waves: np.ndarray
    criterion: np.ndarray
    rss: np.ndarray
    accepted: np.ndarray


@functools.partial(jax.jit, static_argnums=(4, 5, 6))
def _residual_slopes(waves_, normals, camera, times, n_min, n_max, refine):
    """Residual slopes ``(T, H, W, 2)`` of the model ``waves_``, their weight (valid sea
    pixel-frames whose model hit converged) and the rest positions ``(T, H, W, 2)`` the
    model's pixels see."""
    weight = valid_weights(normals, camera)
    normals, _ = clean_inputs(normals, None, weight)
    pred = predict_jit(waves_, camera, times, n_min, n_max, refine)
    return slope_field(normals) - slope_field(pred.normal), weight * pred.converged, pred.xy


def _surface_gap(model: Waves, camera, times, weight, n_min, n_max) -> float:
    """Mean angle [rad] between the rows path's and the hits path's normals of ``model`` over
    the valid pixels whose hit converges, on the first and the last frame (two frames keep
    the compiled hits program small; the gap is a property of the sea, not of the time)."""
    pick = np.asarray([0, times.shape[0] - 1])
    times, weight = times[pick], weight[pick]
    rows = predict_jit(model, camera, times, n_min, n_max, ROWS)
    hits = predict_jit(model, camera, times, n_min, n_max, HITS)
    wt = weight * hits.converged
    return float(jnp.sum(angle_between(rows.normal, hits.normal) * wt) / jnp.maximum(jnp.sum(wt), 1.0))


def _long_wave_grid(omega_lo, omega_hi, n_omega, n_theta, dtype):
    om = np.geomspace(omega_lo, omega_hi, n_omega)
    th = np.linspace(-np.pi, np.pi, n_theta, endpoint=False)
    O, Th = np.meshgrid(om, th, indexing="ij")
    return jnp.asarray(O.ravel(), dtype), jnp.asarray(Th.ravel(), dtype)


def _pad_to(x, n, fill):
    x = np.asarray(x)
    if x.shape[0] >= n:
        return x[:n]
    return np.concatenate([x, np.full(n - x.shape[0], fill, x.dtype)])


# =============================================================================== greedy fit


def _criterion_value(kind, rss, m, n, noise, floor2, discount=0.0):
    """``rss``: residual sum of squares of the normal components; ``m`` their number.
    ``discount``: with a stated noise correlated across the image, the part of the waves'
    explained energy that the noise could have made (:func:`_correlated_discount`), added
    back to the residual."""
    rss = max(float(rss), m * floor2, 1e-300)
    if noise is not None:
        pen = 4 * n * math.log(m) if kind != "aic" else 8 * n
        return (rss + float(discount)) / float(noise) ** 2 + pen
    if kind == "aic":
        return m * math.log(rss / m) + 8 * n
    return m * math.log(rss / m) + 4 * n * math.log(m)


def _kvec(om, th):
    k = np.asarray(om, np.float64) ** 2 / GRAVITY
    return np.stack([k * np.cos(th), k * np.sin(th)], -1)


def waves(normals, roughness, camera, times, *, n_waves: int | None = None, init: Waves | str | None = None,
          net=None, net_threshold: float = 0.5,
          solver: str = "structured", max_waves: int = 96, criterion: str = "bic", noise=None,
          noise_floor=None, noise_correlation: float = 0.0, batch: int = 12, inner_steps: int = 8,
          max_steps: int = 100, rtol=1e-6, atol=None, stall_rtol: float = 0.0,
          roughness_weight: float = 1.0, omega_min: float = 0.3, scales: int | None = None, grid: int = 64,
          score_samples: int = 32768, prune: bool = False, long_waves: bool = True, separation: float = 0.5,
          surface: str = "auto", heights: bool | None = None, height_trend: str = "level",
          exact_height_block: bool = False, merge_separation: float = 0.0, n_min=hierarchy.DEFAULT_N_MIN,
          n_max=hierarchy.DEFAULT_N_MAX, throw: bool = False, history: bool = False, return_selection: bool = False,
          verbose: bool = False):
    """Recover the component waves behind a sequence of geometry (:mod:`jaxocean.fit.waves`).

    * ``n_waves``: fit exactly this many waves (no order selection); ``None`` selects the
      count by ``criterion`` (``"bic"``, ``"aic"`` or ``"holdout"``: the last frame is held
      out and a batch is kept while it lowers the held-out normal error), up to
      ``max_waves``. ``noise``: known noise sigma of the normal components (used instead of
      the residual estimate). ``noise_floor``: the smallest residual sigma the criterion
      believes in (default :data:`DEFAULT_NOISE_FLOOR` = 5.3e-4: the per-component sigma
      whose mean normal angle is the success bound ``normal_error_bound()`` of noise-free
      data), so that noise-free data stop adding waves once the model explains them as
      well as ``success`` asks; a smaller floor (down to ``200 eps`` of the dtype, 2.4e-5
      in float32, the precision of a phase ``k . X`` of a few thousand radians) makes the
      selection go on explaining the long-wave band's residual with more waves.
      ``noise_correlation``: the correlation length ``l`` [px] of the stated ``noise``
      across the image (errors correlated as ``exp(-d / l)``, e.g. a network's smooth
      normal errors; 0: independent pixels). Each wave then counts ``c`` pixels per
      independent observation (:func:`noise_cells`: the noise's power at the wave's
      wavenumber in pixels, relative to white noise), so its explained energy pays the
      criterion's penalty only at ``c`` times the per-pixel noise variance -- in the
      selection, the Wald pruning and the wave's reported ``uncertainty`` (scaled by
      ``sqrt(c)``). Without it, structure far below the per-pixel noise is significant
      over many pixels, and smooth errors become waves. The success bound stays the
      per-pixel one.
    * ``init``: starting waves; then no spectral initialisation, and waves are added only
      if ``n_waves`` asks for more. ``init="net"``: the waves of the wave network
      (:func:`jaxocean.nn.waves.predict` on the first ``config.frames`` frames: the slots
      with presence above ``net_threshold``, their amplitudes and phases solved on the
      data) are the first trial model: refined like any batch and kept if the criterion
      improves on the flat sea; the selection then goes on as from the default start, on
      the residual they leave. ``net``: a
      :class:`~jaxocean.nn.waves.WaveNetModel` or a model file; None is the shipped model.
    * ``prune``: after the greedy stage, drop waves whose Wald statistic is below the
      criterion's penalty, refit, and keep the smaller model only if the criterion does not
      get worse; then the same for the weaker wave of each pair the window does not separate
      (:func:`rayleigh_separation` below 1), which the Wald statistic, a second-order
      estimate, keeps. Off by default: with correlated long waves a refit can land in a
      worse optimum, and each step costs a final refit (on six 32² dataset scenes
      started from the network it kept 3 of 12 prunings and cost half again the fit's time).
    * ``long_waves``: model the part of the sea the view cannot separate into waves -- waves
      longer than the view -- by the long-wave band of :mod:`jaxocean.fit.waves._band`
      (nuisance waves of fixed wave vector, 6 wavelengths x 12 directions by default, whose
      amplitudes and phases are fitted jointly), and add as waves only candidates that the
      image resolves (:func:`resolvable`) and that stand at least ``separation`` Rayleigh
      limits (:func:`rayleigh_separation`) from every wave already in the model and from
      each other (a model stalled more than ``POLISH_FACTOR`` above the floor with none
      left may add candidates that the view does not resolve or that stand
      ``CROWDED_SEPARATION`` x ``separation`` from its waves); what the band absorbed is
      returned in ``WaveFit.long_waves``. Needs ``solver="structured"``. ``False``: every
      candidate may become a wave (closer than 0.7 of the whole image's wave-vector
      resolution to a model wave excepted), no band.
    * ``solver``: ``"structured"`` (default) or a registry name (:mod:`jaxocean.fit.waves`, step 4).
    * ``surface``: the forward model. ``"rows"``: the geometry at each pixel's mean-sea-plane
      hit (``render``'s rows path). ``"hits"``: at the pixel's converged hit on the displaced
      surface (its hits path: what ``render``, ``jaxocean simulate`` and a camera see when
      the waves move the hits; about 10x the cost per step; ``solver="structured"`` only).
      ``"auto"`` (default): the rows path until it leaves the data unexplained at their
      noise while the fitted model's (waves and band) normals on the two paths differ by
      more than ``SURFACE_TOLERANCE`` (0.5) of the success bound -- a difference the data
      can see at their noise -- and either the model moves some pixel's hit by half a
      footprint (``render``'s rule: it draws the hits path there) or the model refitted on
      the hits path explains the data better than on the rows path: the hits path from
      then on (data rendered on the rows path, as ``render`` does where no wave moves a hit
      by half a footprint, stay on it; after a refusal the paths are weighed again once
      the residual has fallen ``SURFACE_RETRY`` = 4 times, at most ``SURFACE_TRIES`` = 3
      times). With a registry solver ``"auto"`` stays on the rows path.
    * ``heights``: also hold the model to the normals' own integrated heights
      (:func:`jaxocean.fit.heights`, where a pixel's footprint is at most
      ``HEIGHT_FOOTPRINT`` = 1 m): the model's height at each pixel's hit against them,
      each frame's level free, weighted ``HEIGHT_WEIGHT`` = 0.01 relative to the normals
      ((1 mrad / 1 cm)^2). Slopes barely constrain the heights of long waves and of the
      long-wave band, and on the hits path those heights move every pixel's hit; the
      integrated heights pin them (on the dataset's rough scenes the difference between a
      failed fit and a successful one: ``experiments/WAVES.md``). ``None`` (default): on
      with the ``structured`` solver, which alone can use them; ``True`` with another
      solver is an error; ``False``: slopes alone.
    * ``height_trend``: what of each frame's integrated heights is left free besides the
      level, which normals cannot give: ``"level"`` (default) nothing more; ``"plane"`` or
      ``"quadratic"`` also a plane or a quadratic in the pixels' mean-sea-plane positions,
      fitted away per frame. On a steep sea seen at a low angle the integration is biased
      (the faces toward the camera are sampled densely, those away sparsely) and most of
      that bias is such a trend: on the two steepest Table 2 scenes the heights are off by
      0.25 and 0.31 m after the level, 0.11 and 0.12 m after a plane and 0.07 m after a
      quadratic, and a fit started from the true waves keeps them with ``"quadratic"``
      (2e-6 and 1.8e-4 rad) but leaves them with ``"level"`` (0.0073 and 0.012 rad);
      from the default start the fit still fails on both (``experiments/WAVES.md``). What
      it costs: the heights no longer pin the waves longer than the view as firmly (a trend
      over the view is what such a wave looks like).
    * ``max_steps``: the step budget of the final refinement on every frame (and of each
      pruning refit). Noise-free fits spend all 100 and are still creeping; a budget of 30
      takes 12-56% less time on the Table 2 scenes but leaves scene 4 at 1.13e-3 rad
      (failed, against 6.2e-4) and doubles the frequency errors of scenes 4 and 6
      (``experiments/WAVES.md``).
    * ``exact_height_block``: the final refinement (and each pruning refit) takes the
      integrated heights' exact Gauss-Newton block (cross terms, each frame's level
      projected out) into its ``J^T J`` instead of the diagonal the selection's trials use.
      On Table 2 it explains every scene's data better at the same 100 steps (scene 5:
      1.16e-4 rad against 2.5e-4) and brings frequencies and directions closer, but some
      separable amplitudes farther, in about 10% more time (``experiments/WAVES.md``).
      With it the amplitude part of each step is predicted to within 1% (scene 5's rows
      path), so its refinement reaches a slow, steady descent that ``stall_rtol`` can stop.
      Needs the heights with ``height_trend="level"``.
    * ``stall_rtol``: the final refinement (and each pruning refit) also stops, converged,
      once its last 10 steps lowered the loss by less than this fraction of it in all (0,
      the default: never). At ``2e-3``, 100 more steps at that pace would lower the mean
      normal error by under 1%. With ``exact_height_block=True`` on Table 2 it stopped the
      final refinements of scenes 0, 5 and 1 after 38, 44 and 70 steps, for 11% less time
      over the eight scenes than 100 steps, with the same successes and normal errors (to
      12%); under the default's diagonal block the loss keeps falling by 0.5% or more every
      10 steps (scene 5), so there it does not fire. The structured solver's only.
    * ``merge_separation``: after the final refinement (and any pruning), merge every pair
      of fitted waves closer than this many Rayleigh limits (:func:`rayleigh_separation`)
      into the one wave the pair draws over the window (their coherent sum at the view's
      centre and the frames' middle, :func:`merge_close_pairs`), refit, and keep the merged
      model if the criterion does not get worse (0, the default: never; at most 1); if it
      gets worse, the closest half of those pairs is tried, then the closest quarter
      (:data:`MERGE_TRIES` refits at most). Such a
      pair is marked undetermined either way; merged, its amplitude is the data's. On Table 2
      scene 3, with ``exact_height_block=True, stall_rtol=2e-3`` and 0.5, 18 pairs merged
      and the refit explained the data better than the 59 waves before it: 41 waves
      (2.27x -> 1.58x the separable true waves), their amplitudes' error 1.0e-3 -> 1.2e-4
      m, one more final refinement's time (``experiments/WAVES.md``).
    * ``rtol``, ``atol``: the refinements' convergence tolerances (relative decrease of the
      loss on an accepted step; absolute loss). A refinement also converges when a full
      Gauss-Newton step could lower chi^2 (the residual in units of ``noise^2``, or of
      ``noise_floor^2`` without ``noise``) by less than ``CHI2_TOL`` = 0.01: the parameters
      are then within a tenth of their 1-sigma uncertainty of the optimum. ``atol`` None:
      ``noise_floor^2 / 1000`` (or ``noise^2 / 1000``), a mean squared normal residual per
      component a thousandth of the
      noise the criterion believes in: past it the fit explains the data 30 times better
      than asked, and the long-wave band's nearly collinear amplitudes would keep a
      float32 refinement crawling for hundreds of steps.
    * ``throw``: raise :class:`jaxocean.fit.solvers.FitError` (carrying the result) whenever
      ``success`` is False -- the selection stopped at ``max_waves``, the fit leaves a mean
      normal error above :func:`normal_error_bound` of ``noise``, or the waves are not
      finite; the message says which. Otherwise read ``success`` (and ``converged``, whether
      the final refinement met its tolerances).

    Raises :class:`NoWaveFound` (an :class:`~jaxocean.errors.InvalidValueError`) when no
    candidate pays the criterion's penalty at the noise: there is no wave to return.

    Eager only (data-dependent wave counts); returns a :class:`WaveFit` with waves sorted by
    frequency, or ``(WaveFit, OrderSelection)`` with ``return_selection=True``. For a fixed
    count under ``jit``/``vmap`` use :func:`spectral_init` then :func:`refine`.
    """
    t0 = time.perf_counter()
    normals, roughness, times = check_inputs(normals, roughness, camera, times)
    if not is_concrete(normals, camera, times):
        raise ValueError("fit.waves selects the number of waves eagerly; under jit/vmap use "
                         "fit.spectral_init + fit.refine with a fixed count")
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVER_NAMES}")
    if criterion not in _CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}; expected one of {_CRITERIA}")
    if n_waves is not None and (not isinstance(n_waves, (int, np.integer)) or n_waves < 1):
        raise ValueError(f"n_waves must be a positive int or None; got {n_waves!r}")
    if noise is not None:
        check_values(np.asarray(noise) > 0, "noise must be > 0", noise)
    check_nonnegative_number(noise_correlation, "noise_correlation must be a finite number of pixels >= 0")
    check_nonnegative_number(stall_rtol, "stall_rtol must be a finite number >= 0 (0: no stall test)")
    if (isinstance(merge_separation, bool) or not isinstance(merge_separation, (int, float, np.floating))
            or not 0.0 <= merge_separation <= 1.0):
        raise ValueError("merge_separation must be a number of Rayleigh limits in [0, 1] (0: no merging); "
                         f"got {merge_separation!r}")
    if stall_rtol > 0 and solver != "structured":
        raise ValueError(f"stall_rtol is the structured solver's stall test; solver={solver!r} has none (pass 0)")
    if noise_correlation > 0 and noise is None:
        raise ValueError("noise_correlation is the correlation of the stated noise: pass noise= too")
    if long_waves and solver != "structured":
        raise ValueError(f"long_waves=True (the long-wave band) needs solver='structured'; got {solver!r} "
                         "(pass long_waves=False to refine with a registry solver)")
    check_values(np.asarray(separation) >= 0, "separation must be >= 0 (Rayleigh limits)", separation)
    if surface not in SURFACES:
        raise ValueError(f"surface must be one of {SURFACES}; got {surface!r}")
    if surface == "hits" and solver != "structured":
        raise ValueError(f"surface='hits' needs solver='structured'; got {solver!r}")
    if heights is None:
        heights = solver == "structured"
    if heights and solver != "structured":
        raise ValueError(f"heights=True needs solver='structured'; got {solver!r}")
    if height_trend not in HEIGHT_TRENDS:
        raise ValueError(f"height_trend must be one of {HEIGHT_TRENDS}; got {height_trend!r}")
    if height_trend != "level" and not heights:
        raise ValueError(f"height_trend={height_trend!r} needs the heights (heights=False, or a registry solver)")
    if exact_height_block and (not heights or height_trend != "level"):
        raise ValueError("exact_height_block=True needs the integrated heights with the default "
                         f"height_trend='level' (got heights={heights}, height_trend={height_trend!r})")
    dtype = normals.dtype
    floor2 = (DEFAULT_NOISE_FLOOR if noise_floor is None else float(noise_floor)) ** 2
    # the noise variance of the refinements' chi^2 convergence test: the stated noise, or the
    # floor that noise-free data are held to
    sigma2 = floor2 if noise is None else float(noise) ** 2
    if atol is None:
        # the loss 0.5 mean |dn_xy|^2 is the per-component mean square residual
        atol = sigma2 / 1000.0
    H = camera.resolution[0]
    tail_rows = jnp.zeros(H, dtype)
    rw = 0.0 if roughness is None else float(roughness_weight)
    T = normals.shape[0]

    holdout = criterion == "holdout" and n_waves is None
    if holdout and T < 3:
        raise ValueError("criterion='holdout' needs at least 3 frames (one is held out)")
    fit_n, fit_t = (normals[:-1], times[:-1]) if holdout else (normals, times)
    fit_r = None if roughness is None else (roughness[:-1] if holdout else roughness)
    height_data = _height_data(normals, camera, dtype, height_trend) if heights else None
    fit_h = height_data if height_data is None or not holdout else tuple(
        x[:-1] if x.ndim else x for x in height_data)

    weight = valid_weights(fit_n, camera)
    m_obs = 2.0 * float(jnp.sum(weight))
    path_n, path_c, path_rss, path_acc = [], [], [], []
    total_steps = 0

    # the long-wave band (fitted amplitudes carried from one accepted model to the next)
    diameter = view_diameter(camera) if long_waves else None
    band = band_waves(diameter, dtype) if long_waves else None
    n_band = 0 if band is None else band.omega.shape[0]

    # the forward model's path: fixed by `surface`, or (auto) switched to the hits path for
    # good once the model's two paths differ and the data prefer the hits path (the waves
    # that move the hits are the strongest, found first)
    # rows_kept_at: the rows path's residual when the data last chose it over the hits path
    state = dict(refine=HITS if surface == "hits" else ROWS, rows_kept_at=math.inf, tries=0)

    def update_surface(w: Waves, band_: Waves | None, rss: float | None) -> bool:
        """Switch to the hits path when the model's rows-path and hits-path normals differ
        by more than ``SURFACE_TOLERANCE`` of the success bound (below that the data cannot
        tell them apart), unless the data chose the rows path at no more than
        ``SURFACE_RETRY`` times ``rss`` (the model's residual sum of squares on it, None:
        unknown) or ``SURFACE_TRIES`` times already; True when it switched (the caller
        refits there and switches back if the data prefer the rows path). A rows path that
        explains the data to their noise is tried too: a model error within the noise of
        each pixel still biases the parameters by many of their sigmas, which shrink with
        the pixel count (a 2-wave sea seen from above, fitted on the rows path to 0.2 of the
        noise floor's variance: a determined wave's phase 19 sigma off). The gap decides
        whether to weigh the paths, not whether the waves move a hit by half a footprint
        (render's rule for images, which :func:`try_hits` weighs too): a
        2-wave sea 7-10 m long, 8 cm high, seen from above at 0.5 m pixels moves no hit that
        far, yet its two paths' normals differ by 1.8e-3 rad, and fitted on the rows path
        its hits-path normals took 6 waves, 4 of them spurious and marked determined."""
        if not (surface == "auto" and solver == "structured" and state["refine"] == ROWS and w.omega.shape[0]):
            return False
        if state["tries"] >= SURFACE_TRIES or (rss is not None and rss * SURFACE_RETRY > state["rows_kept_at"]):
            return False
        model = model_of(w, band_)
        gap = _surface_gap(model, camera, fit_t, weight, n_min, n_max)
        if not gap > SURFACE_TOLERANCE * normal_error_bound(noise):
            return False
        state["refine"] = HITS
        state["tries"] += 1
        if verbose:
            print(f"  the model moves the hits (rows and hits paths differ by {gap:.2e} rad): refitting on the "
                  "hits path", flush=True)
        return True

    def try_hits(w: Waves, band_: Waves | None, rss: float | None):
        """Where :func:`update_surface` switches, refit ``w`` on the hits path and keep it if
        the model leaves the data unexplained and moves a hit by half a footprint; else refit
        it on the rows path with the same steps too and keep the path that explains the data
        better: ``(waves, band, out)`` of that fit (None where it does not switch). Equal
        steps, because ``w`` comes from a short trial: against its residual a longer refit on
        either path wins (measured: one clean wave at
        two frames per period, 8 steps from its start at 17x the noise floor, moved to the
        hits path and took 12 stand-ins; 32 more steps on the rows path explain it). Back on
        the rows path the data are its own (rendered on it, as ``render`` does where no wave
        moves a hit by half a footprint; and the band's heights, which its slopes barely
        fix, can move the hits on a sea the rows path explains: measured 0.11 m on one short
        wave fitted to 3e-6 rad, 4 waves and a failure on the hits path)."""
        nonlocal total_steps
        if not update_surface(w, band_, rss):
            return None
        h_fit = run_lm(w, band_, 4 * inner_steps)
        total_steps += int(h_fit[2].steps)
        if ((rss is None or rss > sigma2 * m_obs)
                and surface_refine("auto", model_of(w, band_), camera, n_min=n_min, n_max=n_max) == HITS):
            # a model that leaves the data unexplained and moves a hit by half a footprint:
            # render itself draws the hits path there, and a camera always sees it, while
            # the comparison below is decided by the waves still missing (measured on a
            # 128^2 dataset scene: 11 waves refitted on each path explained it 0.6% better
            # on the rows path, and the selection crept on there to the cap with a mean
            # normal error of 0.11 rad). Where the rows path explains the data the rule is
            # not trusted: the band's heights can move the hits there (docstring above)
            if verbose:
                print("  the model moves a hit by half a footprint: on the hits path", flush=True)
            return h_fit
        state["refine"] = ROWS
        r_fit = run_lm(w, band_, 4 * inner_steps)
        total_steps += int(r_fit[2].steps)
        if rss_of(h_fit[2]) < rss_of(r_fit[2]):
            state["refine"] = HITS
            return h_fit
        state["rows_kept_at"] = rss_of(r_fit[2])
        if verbose:
            print(f"  the hits path explains the data no better (rss/m {rss_of(h_fit[2]) / m_obs:.3e} against "
                  f"{rss_of(r_fit[2]) / m_obs:.3e} on the rows path): staying on the rows path", flush=True)
        return r_fit

    def model_of(w: Waves, band_: Waves | None) -> Waves:
        # the model's waves padded to a bucket size with zero-amplitude waves: every
        # prediction of a size class shares one compiled program (a long process fitting
        # many scenes would otherwise compile one per wave count, and the hits path's
        # programs are large enough to exhaust the JIT's code memory)
        full = with_band(w, band_)[0]
        return pad_waves(full, bucket_size(full.omega.shape[0]))[0]

    def with_band(w: Waves, band_: Waves | None):
        # the model's waves: the resolved ones first, then the band; and the held mask
        n = w.omega.shape[0]
        if band_ is None:
            return w, None
        full = jax.tree.map(lambda x, y: jnp.concatenate([x, y]), w, band_)
        n_pad = bucket_size(n + n_band)
        return full, jnp.arange(n_pad) >= n

    def split(y, n, n_pad):
        fitted = to_waves(y, n_pad)
        return (jax.tree.map(lambda x: x[:n], fitted),
                None if band is None else jax.tree.map(lambda x: x[n:n + n_band], fitted))

    def run_lm(w: Waves, band_: Waves | None, steps: int):
        # no roughness term while waves are missing: the observed roughness holds the
        # sub-pixel share of waves the model does not have yet, and would pull the others
        n = w.omega.shape[0]
        full, held = with_band(w, band_)
        n_pad = bucket_size(full.omega.shape[0])
        wp, active = pad_waves(full, n_pad)
        # the roughness passed with weight 0: the same compiled kernel as the final fit's
        out, _ = refine_kernel(pack(wp), active, fit_n, fit_r, fit_t, camera, tail_rows,
                               jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), n_min=n_min, n_max=n_max,
                               max_steps=steps, roughness_weight=0.0, held=held, refine=state["refine"],
                               sigma2=sigma2, heights=fit_h)
        fitted, band_fit = split(out.y, n, n_pad)
        return fitted, band_fit, out

    def judge(trial: Waves, trial_band: Waves | None, out):
        """``(criterion, kept)`` of a trial model against the best so far (always kept with a
        fixed count), recorded on the selection's path."""
        sc = score_of(trial, trial_band, out)
        accepted = n_waves is not None or sc < best_score
        path_n.append(trial.omega.shape[0])
        path_c.append(sc)
        path_rss.append(rss_of(out))
        path_acc.append(bool(accepted))
        return sc, accepted

    def adopt(w: Waves, band_: Waves | None, out, sc):
        """``(waves, band, out, criterion, rss)`` of an accepted trial model, refitted where
        :func:`try_hits` switches paths (later trials are scored against the refit on the
        path chosen)."""
        on_hits = try_hits(w, band_, rss_of(out))
        if on_hits is not None:
            w, band_, out = on_hits
            sc = score_of(w, band_, out)
        return w, band_, out, sc, rss_of(out)

    def admissible(w: Waves) -> np.ndarray:
        """Indices of ``w`` the selection would admit together, steepest (largest slope
        amplitude k h) first: resolved by the image and ``separation`` Rayleigh limits from
        every steeper admitted wave (with the long-wave band; all of them without it)."""
        order = np.argsort(-np.asarray(w.amplitude * w.omega ** 2))
        if not long_waves:
            return order
        order = order[np.asarray(resolvable(w, camera, n_max=n_max))[order]]
        apart = rayleigh_separation(w, w, camera, fit_t, n_max=n_max)
        kept = []
        for i in order:
            if all(apart[i, j] >= separation for j in kept):
                kept.append(i)
        return np.asarray(kept, int)

    def seed_from(w: Waves, most: int):
        """``(waves, band, out)``: ``w`` admitted and refined as the first trial model (None:
        no wave admitted). After each refinement, waves it moved out of admission (a twin of
        a steeper wave, or one the image no longer resolves: the band's) and, choosing the
        count, waves whose Wald statistic at the flat sea's residual variance does not pay
        the criterion's penalty are dropped and the rest refined again (twice at most)."""
        nonlocal total_steps
        # the Wald test at the noise level the selection's first batch is judged at: the
        # flat sea's residual (or the stated noise), so that, as there, only waves strong
        # against all that is still unexplained enter at once
        level = math.sqrt(max(flat_rss / m_obs, floor2)) if noise is None else noise
        w = Waves(*[jnp.asarray(x, dtype) for x in w])
        pick = admissible(w)[:most]
        band_fit = band
        for _ in range(3):
            if not pick.size:
                return None
            w, band_fit, out = run_lm(jax.tree.map(lambda x: x[np.sort(pick)], w), band_fit, inner_steps)
            total_steps += int(out.steps)
            n = w.omega.shape[0]
            keep = np.zeros(n, bool)
            keep[admissible(w)] = True
            if n_waves is None:
                active = jnp.arange(bucket_size(n + n_band)) < n + n_band
                keep &= wald_keep(out.y, out.jtj, active, out.loss, m_obs, criterion, level, floor2, cells_of(w))[:n]
            if keep.all():
                break
            pick = np.nonzero(keep)[0]
        return w, band_fit, out

    def cells_of(w: Waves) -> np.ndarray:
        # pixels per independent observation of each wave (ones: white noise)
        if not noise_correlation > 0 or w.omega.shape[0] == 0:
            return np.ones(w.omega.shape[0])
        return noise_cells(w, camera, float(noise_correlation), n_max=n_max)

    def discount_of(w: Waves, y, jtj, n_pad, m):
        n = w.omega.shape[0]
        if not noise_correlation > 0 or n == 0:
            return 0.0
        return correlated_discount(y, jtj, jnp.arange(n_pad) < n + n_band, n, cells_of(w), m)

    def rss_of(out):
        # out.loss = 0.5 |r|^2 with residuals scaled by 1/sqrt(P): the RSS is loss * m
        return float(out.loss) * m_obs

    def score_of(w: Waves, band_: Waves | None, out):
        if holdout:
            pred = predict_jit(model_of(w, band_), camera, times[-1:], n_min, n_max, state["refine"])
            wt = valid_weights(normals[-1:], camera) * pred.converged
            d = pred.normal[..., :2] - normals[-1:, ..., :2]
            return float(jnp.sum(d * d * wt[..., None]) / jnp.maximum(jnp.sum(wt), 1.0))
        n_pad = out.y.shape[0] // 4
        return _criterion_value(criterion, rss_of(out), m_obs, w.omega.shape[0], noise, floor2,
                                discount_of(w, out.y, out.jtj, n_pad, m_obs))

    # ---- start
    empty = Waves(*(jnp.zeros(0, dtype),) * 4)
    net_start = None
    if isinstance(init, str):
        net_start = _net_start(init, net, net_threshold, normals, roughness, camera, times)
        init = None
    current = empty if init is None else Waves(*[jnp.asarray(x, dtype) for x in validate(init, max_steepness=None)])
    selecting = init is None  # the count is chosen by the criterion
    limit = n_waves if n_waves is not None else (max_waves if selecting else current.omega.shape[0])

    n_scales = scales if scales is not None else (1 if camera.projection == "orthographic" else 4)
    _, _, _, spacing, _ = grid_frames(camera, n_scales, grid)
    spacing = np.asarray(spacing)
    coarse_extent = float(spacing[-1]) * grid
    om_long_hi = math.sqrt(GRAVITY * 1.5 * 2 * math.pi / coarse_extent) * 1.3
    long_om, long_th = _long_wave_grid(min(omega_min, 0.5 * om_long_hi), om_long_hi, 10, 36, dtype)
    res_scale = 2 * math.pi / (spacing * grid)  # FFT resolution of each grid [rad/m]
    # the finest wave-vector resolution the whole image allows: two waves closer than this
    # are one wave to the data (the longest sea baseline in the image)
    hit = cam.intersect_sea(camera)
    sea_xy = np.asarray(hit.xy)[np.asarray(hit.mask)]
    baseline = float(np.max(np.linalg.norm(sea_xy - sea_xy.mean(0), axis=1))) * 2.0
    k_res = 2 * math.pi / max(baseline, 1e-6)

    update_surface(current, band, None)
    cn, _ = clean_inputs(fit_n, None, weight)
    flat_rss = float(jnp.sum(cn[..., :2] ** 2 * weight[..., None]))  # the flat sea's, on the fitted frames
    if current.omega.shape[0] > 0:
        current, band, best_out = run_lm(current, band, inner_steps if limit > current.omega.shape[0] else max_steps)
        total_steps += int(best_out.steps)
        best_score = score_of(current, band, best_out)
        rss_now = rss_of(best_out)
    elif holdout:
        wt = valid_weights(normals[-1:], camera)
        cn, _ = clean_inputs(normals[-1:], None, wt)
        best_score = float(jnp.sum(cn[..., :2] ** 2 * wt[..., None]) / jnp.maximum(jnp.sum(wt), 1.0))
        rss_now = float("nan")
    else:
        rss_now = flat_rss
        best_score = _criterion_value(criterion, rss_now, m_obs, 0, noise, floor2)
    path_n.append(current.omega.shape[0])
    path_c.append(best_score)
    path_rss.append(rss_now)
    path_acc.append(True)
    # the network's waves as the first trial model, admitted as the selection admits its
    # first batch (seed_from): measured on a clean 4-wave swell, the network's 6 waves all
    # entered untested and 2 of them stayed, with the test the 4 true ones alone
    seeded = None if net_start is None else seed_from(net_start, limit)
    if seeded is not None:
        trial, trial_band, out = seeded
        sc, accepted = judge(trial, trial_band, out)
        if verbose:
            print(f"  network start: waves {trial.omega.shape[0]:4d}  criterion {sc:.6g}  rss/m "
                  f"{rss_of(out) / m_obs:.3e}  {'kept' if accepted else 'rejected'}", flush=True)
        if accepted:
            current, band, out, best_score, rss_now = adopt(trial, trial_band, out, sc)

    n_cand = batch + 8
    cur_batch = batch
    polished_at = math.inf  # the residual at the last longer refinement
    timing = dict(detect=0.0, refine=0.0, lm=0.0)
    while current.omega.shape[0] < limit:
        n_cur = current.omega.shape[0]
        t_a = time.perf_counter()
        positions = rest_surface = None
        if n_cur > 0:
            model = model_of(current, band)
            resid, wt, xy = _residual_slopes(model, fit_n, camera, fit_t, n_min, n_max, state["refine"])
            if state["refine"] != ROWS:
                positions, rest_surface = xy, model
        else:
            wt = weight
            resid = slope_field(clean_inputs(fit_n, None, wt)[0])
        smp = all_samples(resid, wt, fit_t, camera, positions=positions)
        smp_score = subsample(smp, score_samples)
        # on the hits path the grids hold the model's rest positions: a wave riding on the
        # model's longer waves (moved by their orbits and by the parallax of their heights) is
        # a plane wave there, not on the mean sea plane
        est = spectral_pyramid(resid, wt, fit_t, camera, scales=n_scales, grid=grid, n_peaks=16,
                               surface=rest_surface)
        c_om = jnp.concatenate([est.peak_omega.ravel(), long_om])
        c_th = jnp.concatenate([est.peak_theta.ravel(), long_th])
        valid = np.concatenate([np.asarray(est.peak_power.ravel()) > 0, np.ones(long_om.shape, bool)])
        c_res = np.concatenate([np.repeat(res_scale, est.peak_power.shape[1]), np.full(long_om.shape, res_scale[-1])])
        c_om = jnp.where(jnp.asarray(valid), c_om, 1.0)
        energy, _, _ = score_candidates(c_om, c_th, smp_score, n_min, n_max)
        energy = np.where(valid, np.asarray(energy), -np.inf)
        # distinct candidates: the strongest first, dropping repeats of a wave vector within
        # the resolution of the grid that found it
        kc = _kvec(np.asarray(c_om), np.asarray(c_th))
        order = np.argsort(-energy)
        order = order[np.isfinite(energy[order]) & (energy[order] > 0)]

        def distinct(passes):
            picked = []
            for pool, size in passes:
                for j in pool:
                    if len(picked) >= size:
                        break
                    if j not in picked and all(np.hypot(*(kc[j] - kc[i])) > 0.5 * max(c_res[i], c_res[j])
                                               for i in picked):
                        picked.append(j)
            return picked

        picked = distinct([(order, n_cand)])
        # (an unknown residual, the holdout criterion's empty model, counts as far above it)
        if long_waves and picked and not rss_now / m_obs <= POOL_FACTOR * max(sigma2, floor2):
            # a swell longer than the view can fill the residual's spectrum with near-copies
            # that cannot become waves (measured on a 32^2 dataset scene: the 20 strongest
            # were all 70-90 m long in a 40 m view, and the fit reported a flat sea over its
            # 32 resolvable waves): then half of the candidates are the strongest the image
            # resolves
            def resolved(idx):
                idx = idx[np.asarray(c_om)[idx] > 0]
                zero = jnp.zeros(idx.size, dtype)
                return idx[resolvable(Waves(zero, c_om[idx], c_th[idx], zero), camera, n_max=n_max)]

            # the whole list is checked only when the pool holds no resolvable candidate
            if not resolved(np.asarray(picked)).size:
                picked = distinct([(order, n_cand // 2), (resolved(order), n_cand)])
                if verbose:
                    print(f"  none of the {n_cand} strongest candidates is resolvable at rss/m "
                          f"{rss_now / m_obs:.3e}: half of them are the strongest resolvable", flush=True)
        if not picked:
            if verbose:
                print("  stop: the residual's spectrum holds no candidate with positive energy", flush=True)
            break
        pj = np.asarray(picked)
        t_b = time.perf_counter()
        timing["detect"] += t_b - t_a
        smp_ref = subsample(smp, 2 * score_samples)
        r_om, r_th, e_ref, _, _ = (np.asarray(x) for x in refine_candidates(
            jnp.asarray(_pad_to(np.asarray(c_om)[pj], n_cand, 1.0)),
            jnp.asarray(_pad_to(np.asarray(c_th)[pj], n_cand, 0.0)), smp_ref, n_min, n_max, 8))
        e_ref = np.where(np.arange(n_cand) < pj.size, e_ref, -np.inf)
        # a candidate is worth a trial only if it would explain more than the criterion's
        # penalty for 4 parameters in units of the residual variance (energies are on a
        # subsample: rescale to all samples)
        sub_w = float(jnp.sum(smp_ref.sw ** 2))
        e_all = e_ref * (float(jnp.sum(smp.sw ** 2)) / max(sub_w, 1e-30))
        rss_cur = float(jnp.sum(smp.sw ** 2 * jnp.sum(smp.target ** 2, -1)))  # slope-space residual
        sig2 = max(rss_cur / m_obs, floor2) if noise is None else float(noise) ** 2
        pen = 8.0 if criterion == "aic" else 4.0 * math.log(m_obs)
        # with correlated noise each candidate pays at its own noise level
        cand_cells = cells_of(Waves(jnp.zeros(n_cand, dtype), jnp.asarray(np.maximum(r_om, 1e-3), dtype),
                                    jnp.asarray(r_th, dtype), jnp.zeros(n_cand, dtype)))
        e_ref = np.where((e_all >= pen * sig2 * cand_cells) | (n_waves is not None), e_ref, -np.inf)
        kr = _kvec(r_om, r_th)
        k_old = _kvec(current.omega, current.theta) if n_cur else np.zeros((0, 2))
        n_add = min(cur_batch, limit - n_cur)
        chosen = []
        if long_waves:
            # what the view can separate: resolved by the image, and at least `separation`
            # Rayleigh limits from every model wave and every other chosen candidate; a
            # model stalled far above the floor may add candidates closer to its waves, or
            # ones the view does not resolve (CROWDED_SEPARATION: the data demand them)
            cand = Waves(jnp.zeros(n_cand, dtype), jnp.asarray(np.maximum(r_om, 1e-3), dtype),
                         jnp.asarray(r_th, dtype), jnp.zeros(n_cand, dtype))
            resolved = resolvable(cand, camera, n_max=n_max)
            to_model = (np.min(rayleigh_separation(cand, current, camera, fit_t, n_max=n_max), 1) if n_cur
                        else np.full(n_cand, np.inf))
            mutual = rayleigh_separation(cand, cand, camera, fit_t, n_max=n_max)
            crowded = (n_waves is None and not holdout and n_cur > 0
                       and rss_now / m_obs > POLISH_FACTOR * floor2)
            for relaxed in ((False, True) if crowded else (False,)):
                level = CROWDED_SEPARATION * separation if relaxed else separation
                for j in np.argsort(-e_ref):
                    if len(chosen) >= n_add or not np.isfinite(e_ref[j]) or e_ref[j] <= 0:
                        break
                    if (r_om[j] >= 0.5 * omega_min and (resolved[j] or relaxed) and to_model[j] >= level
                            and all(mutual[j, i] >= separation for i in chosen)):
                        chosen.append(j)
                if chosen:
                    if verbose and relaxed:
                        # each: wavelength in view diameters, direction, and why it was not admissible
                        lam = np.asarray(wavelength(cand.omega)) / diameter
                        why = [" ".join(w for w, on in (("unresolved", not resolved[j]),
                                                        ("crowded", to_model[j] < separation)) if on)
                               for j in chosen]
                        print(f"  stalled at rss/m {rss_now / m_obs:.3e}: {len(chosen)} candidate(s) the view "
                              f"does not resolve or within {level:.3g} Rayleigh limits of a model wave: "
                              + ", ".join(f"{lam[j]:.2f} D at {math.degrees(r_th[j]):.0f} deg ({w})"
                                          for j, w in zip(chosen, why)), flush=True)
                    break
        else:
            for j in np.argsort(-e_ref):
                if len(chosen) >= n_add or not np.isfinite(e_ref[j]) or e_ref[j] <= 0:
                    break
                if r_om[j] < 0.5 * omega_min:
                    continue
                kn = np.hypot(*kr[j])
                sep = max(0.02 * kn, 0.7 * k_res)
                if k_old.size and np.min(np.hypot(*(k_old - kr[j]).T)) < sep:
                    continue  # a wave the model already has
                if any(np.hypot(*(kr[j] - kr[i])) < max(sep, 0.5 * res_scale[0]) for i in chosen):
                    continue
                chosen.append(j)
        if not chosen:
            if verbose:
                print("  stop: no candidate pays the criterion's penalty and is resolvable and separated from "
                      "the model's waves", flush=True)
            break
        ch = np.asarray(chosen)
        # one joint linear solve of the chosen candidates: drop those whose share of the
        # explained energy does not pay the criterion's penalty
        nb = bucket_size(ch.size)
        a_j, b_j, part = (np.asarray(x) for x in joint_amplitudes(
            jnp.asarray(_pad_to(r_om[ch], nb, 1.0), dtype), jnp.asarray(_pad_to(r_th[ch], nb, 0.0), dtype),
            jnp.asarray(np.arange(nb) < ch.size, dtype), smp_ref, n_min, n_max))
        a_j, b_j, part = a_j[:ch.size], b_j[:ch.size], part[:ch.size] * (e_all[ch] / np.maximum(e_ref[ch], 1e-300))
        if n_waves is None:
            part = np.where(np.isfinite(part), part, 0.0)
            ok = part >= pen * sig2 * cand_cells[ch]
            if not ok.any():
                ok = part >= part.max()
            ch, a_j, b_j = ch[ok], a_j[ok], b_j[ok]
        add = Waves(jnp.asarray(np.hypot(a_j, b_j), dtype), jnp.asarray(r_om[ch], dtype),
                    jnp.asarray(r_th[ch], dtype), jnp.asarray(np.mod(np.arctan2(b_j, a_j), 2 * np.pi), dtype))
        trial = jax.tree.map(lambda x, y: jnp.concatenate([x, y]), current, add)
        t_c = time.perf_counter()
        timing["refine"] += t_c - t_b
        trial, trial_band, out = run_lm(trial, band, inner_steps)
        jax.block_until_ready(out.loss)  # dispatch is asynchronous: time the work, not the call
        timing["lm"] += time.perf_counter() - t_c
        total_steps += int(out.steps)
        sc, accepted = judge(trial, trial_band, out)
        if verbose:
            print(f"  waves {trial.omega.shape[0]:4d}  criterion {sc:.6g}  rss/m {rss_of(out) / m_obs:.3e}  "
                  f"{'kept' if accepted else 'rejected'}  ({time.perf_counter() - t0:.0f} s; "
                  + ", ".join(f"{k} {v:.0f} s" for k, v in timing.items()) + ")", flush=True)
        if accepted:
            current, band, out, best_score, rss_now = adopt(trial, trial_band, out, sc)
            if (n_waves is None and not holdout and floor2 < rss_now / m_obs <= POLISH_FACTOR * floor2
                    and rss_now < 0.5 * polished_at and int(out.steps) >= inner_steps):
                # the trial ran out of steps near the floor: refine longer before adding waves
                # (again only once the residual has halved)
                polished_at = rss_now
                p_waves, p_band, p_out = run_lm(current, band, 4 * inner_steps)
                total_steps += int(p_out.steps)
                if verbose:
                    print(f"  refined {p_waves.omega.shape[0]} waves longer: rss/m {rss_now / m_obs:.3e} -> "
                          f"{rss_of(p_out) / m_obs:.3e}  ({int(p_out.steps)} steps; "
                          f"{time.perf_counter() - t0:.0f} s)", flush=True)
                if rss_of(p_out) < rss_now:
                    current, band, best_score = p_waves, p_band, score_of(p_waves, p_band, p_out)
                    rss_now = rss_of(p_out)
            if n_waves is None and not holdout and rss_now / m_obs <= floor2:
                break  # explained to the noise floor: nothing left to find
        elif cur_batch > 1 and len(chosen) > 1:
            # a smaller batch; halving past the candidates that were there to choose from
            # (a batch no smaller would choose the same ones and be rejected again; one
            # rejected candidate would be chosen alone again from the same residual)
            cur_batch //= 2
            while cur_batch > 1 and cur_batch >= len(chosen):
                cur_batch //= 2
        else:
            break

    # ---- final refinement on every frame, then pruning by the Wald statistic: a pruned
    # model is refitted and kept only if the criterion does not get worse
    if current.omega.shape[0] == 0:
        sigma = float(noise) if noise is not None else math.sqrt(floor2)
        level = (f"the stated noise ({sigma:.3g} per normal component)" if noise is not None
                 else f"the noise floor ({sigma:.3g} per normal component)")
        spread = math.sqrt(rss_now / m_obs) if math.isfinite(rss_now) else math.nan
        if spread > 3.0 * sigma:
            # not a flat sea: slopes far above the noise that no resolvable wave explains
            raise NoWaveFound(f"no wave found: no candidate explains more of the normals than the {criterion} "
                              f"criterion asks at {level}, yet the normals spread {spread:.3g} per component about "
                              f"the flat sea, {spread / sigma:.3g} times that level: noise above it (state it with "
                              "noise=) or waves the view does not resolve, not a flat sea")
        raise NoWaveFound(f"no wave found: no candidate explains more of the normals than the {criterion} "
                          f"criterion asks at {level}; the geometry shows a flat sea at that noise")

    rough_info = roughness is not None and rw > 0 and _roughness_informative(roughness, camera)

    def final_fit(w: Waves, band_: Waves | None):
        # with informative roughness, the sub-pixel tail of the waves outside ``w`` (non-negative
        # least squares over virtual wavelengths) is fitted first and then held fixed
        tail = _nnls_tail(w, roughness, camera, n_min, n_max, dtype) if rough_info else tail_rows
        return _final_once(w, band_, tail)

    def _final_once(w: Waves, band_: Waves | None, tail):
        if solver == "structured":
            full, held = with_band(w, band_)
            n_pad = bucket_size(full.omega.shape[0])
            wp, active = pad_waves(full, n_pad)
            out, n_valid = refine_kernel(pack(wp), active, normals, roughness, times, camera, tail,
                                         jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), n_min=n_min,
                                         n_max=n_max, max_steps=max_steps, roughness_weight=rw if rough_info
                                         else 0.0, history=history, held=held, refine=state["refine"],
                                         sigma2=sigma2, heights=height_data, exact_heights=exact_height_block,
                                         stall_rtol=stall_rtol)
            return dict(y=out.y, jtj=out.jtj, half=out.loss, steps=out.steps, success=out.success, hist=out.history,
                        active=active, n_valid=n_valid, n_pad=n_pad, band=split(out.y, w.omega.shape[0], n_pad)[1])
        active = jnp.ones(w.omega.shape[0], bool)
        o, n_valid, residual = registry_refine(pack(w), active, normals, roughness, times, camera, tail,
                                               solver=solver, n_min=n_min, n_max=n_max, max_steps=max_steps,
                                               rtol=rtol, atol=atol, roughness_weight=rw if rough_info else 0.0,
                                               history=history, options=None)
        return dict(y=o.params, jtj=dense_jtj(residual, o.params), half=o.loss, steps=o.steps, success=o.success,
                    hist=o.history, active=active, n_valid=n_valid, n_pad=w.omega.shape[0], band=None)

    m_all = 2.0 * float(jnp.sum(valid_weights(normals, camera)))

    def crit(fit_, w):
        return _criterion_value(criterion if criterion != "holdout" else "bic", float(fit_["half"]) * m_all, m_all,
                                w.omega.shape[0], noise, floor2,
                                discount_of(w, fit_["y"], fit_["jtj"], fit_["n_pad"], m_all))

    on_hits = try_hits(current, band, rss_now if math.isfinite(rss_now) else None)
    if on_hits is not None:
        current, band = on_hits[:2]
    t_final = time.perf_counter()
    best = final_fit(current, band)
    total_steps += int(best["steps"])
    if verbose:
        print(f"  final refinement of {current.omega.shape[0]} waves on every frame: {int(best['steps'])} of "
              f"{max_steps} steps, rss/m {float(best['half']):.3e}, "
              f"{'converged' if bool(best['success']) else 'not converged'} "
              f"({time.perf_counter() - t_final:.0f} s; {time.perf_counter() - t0:.0f} s in all)", flush=True)

    def fitted_now() -> Waves:
        return jax.tree.map(lambda x: x[:current.omega.shape[0]], to_waves(best["y"], best["n_pad"]))

    def try_model(smaller: Waves, what: str) -> bool:
        """Refit the smaller model ``smaller``; keep it if the criterion does not get worse.
        Returns whether it was kept."""
        nonlocal current, best, total_steps
        trial = final_fit(smaller, best["band"])
        total_steps += int(trial["steps"])
        better = crit(trial, smaller) <= crit(best, current)
        if verbose:
            print(f"  {what}: {int(trial['steps'])} steps, rss/m {float(trial['half']):.3e}, "
                  f"{'kept' if better else 'reverted'}", flush=True)
        if better:
            current, best = smaller, trial
        return better

    if n_waves is None and prune:
        def try_without(drop, why):
            """Refit without the waves ``drop`` marks (:func:`try_model`)."""
            pruned = jax.tree.map(lambda x: x[np.nonzero(~drop)[0]], fitted_now())
            return try_model(pruned, why.format(int(drop.sum()), current.omega.shape[0]))

        for _ in range(2):
            n_cur = current.omega.shape[0]
            keep = wald_keep(best["y"], best["jtj"], best["active"], best["half"], 2.0 * float(best["n_valid"]),
                             criterion, noise, floor2, cells_of(current))[:n_cur]
            if keep.all() or keep.sum() == 0 or not try_without(~keep, "pruning {} of {} waves (Wald statistic "
                                                                        "below the penalty)"):
                break
        # the Wald statistic is a second-order estimate: for two waves the window does not
        # separate, it misses that the stronger can move to take over the weaker (measured:
        # a 0.013 m wave 0.05 rad/s beside a 0.072 m one, Wald statistic 2.4e4 times the
        # penalty, while the true single wave explains the data to the floor). Each such
        # pair's weaker wave is dropped in one refit, kept if the criterion does not get worse
        merge = unseparated_weaker(fitted_now(), camera, times, n_max)
        if merge.any():
            try_without(merge, "merging {} of {} waves into a stronger wave the window does not separate them from")
    if n_waves is None and merge_separation > 0:
        # a pair much closer than the window's Rayleigh limit draws one wave, and the final
        # refinement lets its split drift (Table 2 scene 3: two fitted waves 0.5% and 1.3% from
        # a true wave of 0.0090 m, at 0.0143 and 0.0111 m); merged, the pair is that one wave
        # if merging every such pair at once is reverted, the closest half of them are
        # tried, then the closest quarter: on Table 2 scenes 1, 4 and 6, 13-15 pairs
        # merged in one go raised the residual a hundredfold
        n_cur = current.omega.shape[0]
        limit_merges = None
        for _ in range(MERGE_TRIES):
            merged, n_merged = merge_close_pairs(fitted_now(), camera, times, n_max, merge_separation,
                                                 max_merges=limit_merges)
            if not n_merged or try_model(Waves(*(jnp.asarray(x) for x in merged)),
                                         f"merging {'the closest ' * bool(limit_merges)}{n_merged} "
                                         f"pair{'s' * (n_merged > 1)} of the {n_cur} waves (closer than "
                                         f"{merge_separation:g} Rayleigh limits)"):
                break
            if n_merged == 1:
                break
            limit_merges = n_merged // 2
    y, jtj, half, success, hist = best["y"], best["jtj"], best["half"], best["success"], best["hist"]
    active, n_valid = best["active"], best["n_valid"]
    rw = rw if rough_info else 0.0
    result = fit_result(y, active, jtj, half, n_valid, normals, roughness, camera, times, total_steps, success,
                        hist if history else None, rw, n_min, n_max, t0, state["refine"], sigma2=sigma2)
    n_fit = current.omega.shape[0]
    result = _sorted(result, n_fit)
    if noise_correlation > 0:
        # each wave's estimate is as uncertain as the noise in its band of the spectrum
        root = jnp.asarray(np.sqrt(cells_of(result.waves)), dtype)
        result = result._replace(uncertainty=Waves(*(u * root for u in result.uncertainty)))
    # the loop ran into the cap, not into the criterion: the count was not selected
    capped = n_waves is None and selecting and n_fit >= max_waves
    # success is explaining the data to their noise: converged is not enough (measured: one
    # wave 1.25-2 footprints long, aliased by the start, "converged" at 0.05-0.12 rad), nor
    # needed (noise-free fits explain their data 10-60x better than the bound while the
    # final refinement still creeps along close pairs; `converged` reports that)
    bound = normal_error_bound(noise)
    unexplained = not float(result.normal_error) <= bound
    finite = all(bool(np.all(np.isfinite(np.asarray(leaf)))) for leaf in result.waves)
    absorbed = None
    if best["band"] is not None:
        band_normals = predict_jit(best["band"], camera, times, n_min, n_max, state["refine"]).normal
        absorbed = band_summary(best["band"], band_normals, valid_weights(normals, camera), diameter)
    result = result._replace(time_s=jnp.asarray(time.perf_counter() - t0, dtype),
                             success=jnp.asarray(finite and not capped and not unexplained
                                                 and not too_steep(result.waves).any()),
                             converged=jnp.asarray(result.success),
                             determined=separable(result.waves, camera, times, n_max=n_max), long_waves=absorbed,
                             surface="rows" if state["refine"] == ROWS else "hits")
    maybe_throw(result, throw, max_steps, capped, bound if unexplained else None)
    if return_selection:
        sel = OrderSelection(np.asarray(path_n), np.asarray(path_c), np.asarray(path_rss), np.asarray(path_acc))
        return result, sel
    return result


def _height_data(normals, camera, dtype, trend="level"):
    """``(z, mask, weight)`` for :func:`refine_kernel`: the normals' integrated heights
    ``(T, H, W)``, where they are used (valid, footprint at most :data:`HEIGHT_FOOTPRINT`:
    farther out the pixels no longer sample the waves and the integration drifts), and
    :data:`HEIGHT_WEIGHT`; with a ``trend`` other than ``"level"`` also the basis
    ``(T, K, H, W)`` whose per-frame coefficients the fit leaves free (:func:`_trend_basis`)."""
    from jaxocean.fit.heights import heights as integrate

    hm = integrate(normals, camera)  # non-finite normals are left out there
    hit = cam.intersect_sea(camera)
    near = jnp.asarray(hit.footprint) <= HEIGHT_FOOTPRINT
    mask = (hm.valid & near[None]).astype(dtype)
    data = (hm.z.astype(dtype), mask, jnp.asarray(HEIGHT_WEIGHT, dtype))
    if trend == "level":
        return data
    basis = _trend_basis(jnp.asarray(hit.xy), near & jnp.asarray(hit.mask), trend).astype(dtype)
    return data + (jnp.broadcast_to(basis, (normals.shape[0],) + basis.shape),)


def _trend_basis(xy, used, trend):
    """``(K, H, W)``: 1, u, v (``"plane"``) and u^2, v^2, u v (``"quadratic"``), with
    ``(u, v)`` the mean-sea-plane positions ``xy (H, W, 2)`` standardised over the ``used``
    pixels (zero elsewhere), so that the per-frame normal equations stay well conditioned."""
    used = used & jnp.all(jnp.isfinite(xy), -1)
    count = jnp.maximum(jnp.sum(used), 1)
    xy = jnp.where(used[..., None], xy, 0.0)
    mean = jnp.sum(xy, (0, 1)) / count
    std = jnp.sqrt(jnp.sum(jnp.where(used[..., None], (xy - mean) ** 2, 0.0), (0, 1)) / count)
    u, v = jnp.moveaxis(jnp.where(used[..., None], (xy - mean) / jnp.maximum(std, 1e-6), 0.0), -1, 0)
    terms = [jnp.ones_like(u), u, v] + ([u * u, v * v, u * v] if trend == "quadratic" else [])
    return jnp.stack(terms) * used


def _net_start(init: str, net, threshold, normals, roughness, camera, times) -> Waves:
    """The wave network's waves as the start (``init="net"``)."""
    from jaxocean.nn import waves as wn

    if init != "net":
        raise ValueError(f"init must be Waves, None or 'net'; got {init!r}")
    model = net if isinstance(net, wn.WaveNetModel) else wn.load(net)
    T = model.config.frames
    if normals.shape[0] < T:
        raise ValueError(f"init='net': the wave network takes {T} frames; the sequence has {normals.shape[0]}")
    w = wn.predict(model, normals[:T], None if roughness is None else roughness[:T], camera, times[:T],
                   threshold=threshold)
    return w if w.omega.shape[0] else None


def _roughness_informative(roughness, camera):
    """True when some sea rows show roughness clearly above the renderer's floor."""
    r = np.asarray(roughness, np.float64)
    mask = np.asarray(cam.intersect_sea(camera).mask)
    vals = r[:, mask]
    vals = vals[np.isfinite(vals)]
    return bool(vals.size and np.percentile(vals, 90) > 2.0 * shading.MIN_SLOPE_VARIANCE)


def _nnls_tail(w: Waves, roughness, camera, n_min, n_max, dtype, n_virtual=24):
    """Per-row roughness ``(H,)`` of the sub-pixel waves that are not in ``w``: a
    non-negative combination of virtual waves at fixed wavelengths (each contributing
    ``1 - w_n(lambda_j / fp)`` per row) fitted to the observed roughness minus the share of
    ``w``. Host-side (SciPy NNLS), outside any gradient."""
    from scipy.optimize import nnls

    hit = cam.intersect_sea(camera)
    H, W = camera.resolution
    mask = np.asarray(hit.mask)
    fp_row = np.asarray(hit.footprint)[:, W // 2].astype(np.float64)
    obs, rows = observed_rows(roughness, mask)
    share = np.asarray(row_roughness(np.asarray(w.omega) ** 2 / GRAVITY, w.amplitude, fp_row, n_min, n_max),
                       np.float64)
    fp_sea = fp_row[rows]
    lam_v = np.geomspace(0.5 * n_min * fp_sea.min(), n_max * fp_sea.max(), n_virtual)
    B = 1.0 - np.asarray(normal_weight(lam_v, fp_row, n_min, n_max), np.float64)  # (H, n_virtual)
    target = obs - share
    tail = np.zeros(H)
    if rows.any():
        v, _ = nnls(B[rows], np.maximum(target[rows], 0.0))
        tail = B @ v
    return jnp.asarray(np.where(rows, tail, 0.0), dtype)


def _sorted(result: WaveFit, n: int) -> WaveFit:
    order = np.argsort(np.asarray(result.waves.omega)[:n])
    pick = lambda w: Waves(*[jnp.asarray(x)[:n][order] for x in w])  # noqa: E731
    return result._replace(waves=pick(result.waves), uncertainty=pick(result.uncertainty),
                           n_waves=jnp.asarray(n))

