"""Photographs to waves: the stages of ``jaxocean reconstruct``.

Protocol
--------
:func:`reconstruct` runs six stages; each is a function of its own, usable alone, that
returns ``(value, StageReport)``. A :class:`StageReport` holds the stage's ``name``,
``success``, wall time ``seconds``, a ``message`` (why it failed, or what it chose) and a
JSON-safe ``details`` dict.

1. :func:`load_sequence` (``radiometry``, :mod:`jaxocean.footage`): the frames and their
   camera file (or ``scene.json``) as linear radiance, saturated pixels masked, every frame
   resampled into one ideal camera (:func:`sea_view` by default).
2. :func:`geometry_stage` (``geometry``): per-frame normal and roughness from the shipped
   geometry network (:mod:`jaxocean.nn.geometry`).
3. :func:`lighting_stage` (``lighting``): sun, sky and sea colours with the geometry held
   fixed (:func:`jaxocean.fit.lighting`); ``overcast`` fits no sun term.
4. :func:`waves_stage` (``waves``): the component waves behind the geometry sequence
   (:func:`jaxocean.fit.waves`), confirmed only where the images themselves show
   dispersive waves (:func:`space_time_evidence`).
5. :func:`photometric_stage` (``photometric``): waves, lighting and exposure refined jointly
   against the images themselves through the renderer, with a robust loss and an outlier
   mask (:func:`jaxocean.fit.photometric`).
6. :func:`sea_stage` (``spectrum``): Hs, Tp, direction and spreading of the waves with
   uncertainties or bounds (:func:`jaxocean.fit.spectrum`), the mean square slope, and the
   evidence that the images hold linear waves (:func:`jaxocean.spacetime.dispersion_check`);
   :func:`outlook_stage` (``forecast``): forecast frames and re-rendered views.

Units: metres, seconds, radians in the library; ``result.json`` (:func:`result_dict`) gives
directions in degrees, as the direction the waves travel *toward*: clockwise from north when
the camera file gives compass headings, else from the library's +x counter-clockwise.
"""

from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Any, NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import forecast as fc
from jaxocean import radiometry
from jaxocean import shading
from jaxocean._math import slope_from_normal
from jaxocean._stages import StageReport, timed
from jaxocean.errors import InvalidValueError, is_integer
from jaxocean.files import json_safe
from jaxocean.footage import DEFAULT_WIDTH, Sequence, load_sequence, sea_view
from jaxocean.waves import Waves, wavenumber

# the input stage (jaxocean.footage) is re-exported: every stage is reachable from this module
__all__ = ["STAGES", "StageReport", "Sequence", "Reconstruction", "load_sequence", "sea_view", "geometry_stage",
           "space_time_evidence", "geometry_sea_spectrum",
           "lighting_stage", "waves_stage", "photometric_stage", "sea_stage", "outlook_stage", "reconstruct",
           "result_dict", "direction_deg"]

STAGES = ("radiometry", "geometry", "lighting", "waves", "photometric", "spectrum", "forecast")

#: the steepest wave the later stages are given (k h = 1 loops the trochoid's crest)
MAX_STEEPNESS = 0.9
#: the shipped geometry network's error per normal component (x, y), the noise the wave fit
#: is told: its mean angle error on the held-out test split of its dataset, given as 8-bit
#: Bruneton-tone-mapped frames with display noise sigma 0-0.01 (what this pipeline reads), is
#: 0.113-0.115 rad, i.e. sigma = 0.115 / sqrt(pi / 2) per component for a Gaussian error
#: (experiments/NETS.md)
GEOMETRY_NOISE = 0.092
#: the correlation length of that error, as a fraction of the view's width: the network's
#: normal errors are smooth (their autocorrelation on 4 dataset scenes at 128^2 is 0.24-0.55
#: at 8 px and 0.13-0.45 at 16 px; fitted as exp(-d / l) on 3 test scenes x both shipped
#: networks, 8-bit frames with display noise 0.01, l = 5-23 px: short on the rough scene
#: whose error is large, long on the calm ones). The lighting stage draws Gaussian fields of
#: this length: errors taken as independent average out over the glitter and let a wrong sun
#: pass (experiments/LIGHTING.md), and 1/8 of the width (16 px at 128) errs on the correlated
#: side. The wave stage takes it as the exponential's ``l`` (``fit.waves``'
#: ``noise_correlation``): taken as independent, smooth errors pay the order selection's
#: penalty over many pixels and become waves
GEOMETRY_CORRELATION = 0.125
#: how far [factor] the wave stage's peak period may lie from the images' own (space-time
#: evidence) for the images to confirm the waves
PEAK_PERIOD_FACTOR = 2.0
#: how much longer the sea's peak period may be than the images': image brightness follows
#: the slopes, whose spectrum peaks at a higher frequency than the elevation's (5^(1/4) =
#: 1.50 times for Pierson-Moskowitz). Measured: the `gpu` network's waves of a 6.1 s sea
#: peaked at 6.6 s, the images at 3.16 s within their band (2.1 times)
SLOPE_PEAK_RATIO = 5 ** 0.25


class Reconstruction(NamedTuple):
    sequence: Sequence
    geometry: Any
    lighting: Any
    waves: Any
    photometric: Any
    sea: dict
    outlook: dict
    stages: dict


# ----------------------------------------------------------------------------- stages 2-5

def geometry_stage(seq: Sequence, *, model=None):
    """Stage 2: per-frame geometry from the geometry network (``model``: a
    :class:`~jaxocean.nn.geometry.GeometryModel`, a model file, a shipped model's name --
    ``"cpu"``, ``"gpu"`` -- or None, the default shipped one). Success: every sea pixel got a
    finite normal and roughness."""
    from jaxocean.nn import geometry as geo_net

    def run():
        m = model if isinstance(model, geo_net.GeometryModel) else geo_net.load(model)
        pred = geo_net.predict(m, seq.images[..., 0] if seq.gray else seq.images, seq.camera)
        sea = np.asarray(pred.mask)
        finite = np.isfinite(pred.normal).all(-1) & np.isfinite(pred.roughness)
        ok = bool(finite[sea].all())
        mss_resolved, mss_sub = _mean_square_slopes(pred)
        details = dict(mean_square_slope=mss_resolved + mss_sub, mean_square_slope_resolved=mss_resolved,
                       mean_square_slope_subpixel=mss_sub)
        return pred, ok, "" if ok else "non-finite network output on sea pixels", details

    return timed("geometry", run)


class _Geo(NamedTuple):
    normal: Any
    roughness: Any
    slope_variance: Any
    mask: Any


def _looks_overcast(seq: Sequence, frame: int) -> bool:
    """The default of ``lighting_stage``'s ``overcast``: gray footage, or more than 20% of the
    sea pixels of ``frame`` saturated at the top. (Pixels outside the source frame, or
    crushed to black, are unusable too but say nothing of the sky.)"""
    if seq.gray:
        return True
    sea = np.asarray(cam.intersect_sea(seq.camera).mask)
    if not sea.any():
        return True
    clipped = ~radiometry.saturation_mask(np.asarray(seq.display[frame]))
    return bool(np.mean(clipped[sea]) > 0.2)


def lighting_stage(seq: Sequence, geometry, *, frame: int | None = None, overcast: bool | None = None,
                   normal_noise: float = GEOMETRY_NOISE, correlation: float = GEOMETRY_CORRELATION):
    """Stage 3: the lighting of one frame (default the middle one) with its geometry held
    fixed. ``overcast`` (None: decided from the footage -- gray footage, or more than 20% of
    the sea pixels saturated at the top) fixes the sun colour at 0 and fits the sky and sea
    colours.
    The fit is told the geometry's error per normal component (``normal_noise`` [rad],
    :func:`jaxocean.fit.lighting`), correlated over ``correlation`` times the view's width:
    success means the lighting explains the frame as well as geometry of that accuracy
    allows, and that geometry determines every fitted field."""
    from jaxocean import fit

    n = len(seq.times)
    if frame is not None and not (is_integer(frame, 0) and frame < n):
        raise ValueError(f"lighting_stage: frame must be an index in [0, {n}) of the sequence's {n} frames; "
                         f"got {frame!r}")
    i = n // 2 if frame is None else int(frame)

    def run():
        over = _looks_overcast(seq, i) if overcast is None else overcast
        g = _Geo(geometry.normal[i], geometry.roughness[i], geometry.slope_variance[i], geometry.mask[i])
        kw = {}
        if over:
            kw = dict(init=shading.make_lighting(sun_color=(0.0, 0.0, 0.0)), fit=("sky_color", "sea_color"))
        length = float(correlation) * seq.camera.resolution[1]
        result = fit.lighting(seq.images[i], g, seq.camera, mask=seq.usable[i], throw=False,
                              normal_noise=normal_noise, normal_correlation=length, **kw)
        details = fit.fit_to_dict(result)
        details.update(overcast=over, frame=int(i), normal_noise_rad=float(normal_noise),
                       normal_correlation_px=length)
        msg = "overcast sky: no sun term" if over else ""
        if not result.success:
            why = fit.lighting_fit.failure_message(result, normal_noise=normal_noise)
            msg = (msg + "; " if msg else "") + why
        return result, bool(result.success), msg, details

    return timed("lighting", run)


def space_time_evidence(seq: Sequence):
    """Whether the images themselves hold dispersive waves:
    :func:`jaxocean.spacetime.dispersion_check` on the sequence's fine luminance (its
    working frames without one), or None when the sequence is shorter than
    ``spacetime.MIN_FRAMES`` (the evidence is missing, not negative)."""
    from jaxocean import spacetime

    if len(seq.times) < spacetime.MIN_FRAMES:
        return None
    images, usable, camera = seq.fine or (seq.images.mean(-1), seq.usable, seq.camera)
    return spacetime.dispersion_check(images, camera, seq.times, mask=usable)


def _check_evidence_times(seq: Sequence) -> None:
    """The space-time evidence (:func:`space_time_evidence`, stages 4-6) needs uniformly spaced
    frames once there are ``spacetime.MIN_FRAMES`` of them, which a camera file need not give
    (a dropped frame): refused after stage 1, not minutes later."""
    from jaxocean import spacetime

    times = np.asarray(seq.times, np.float64)
    if len(times) < spacetime.MIN_FRAMES or spacetime.uniformly_spaced(times):
        return
    steps = np.diff(times)
    typical = float(np.median(steps))
    n = int(np.argmax(np.abs(steps - typical)))  # the step farthest from the usual one
    raise InvalidValueError(
        f"the space-time evidence of stages 4-6 needs uniformly spaced frames, and the step from frame {n} "
        f"(t = {times[n]:.6g} s, {Path(seq.files[n]).name}) to frame {n + 1} (t = {times[n + 1]:.6g} s) is "
        f"{steps[n]:.6g} s against {typical:.6g} s elsewhere (a dropped frame?): give a uniformly spaced run of "
        f"frames (FRAMES, step, max_frames)")


def _evidence_of(seq: Sequence, evidence):
    """A stage's ``evidence`` argument: ``"auto"`` computes :func:`space_time_evidence`,
    anything else (a check, or None for none) is taken as given."""
    return space_time_evidence(seq) if isinstance(evidence, str) and evidence == "auto" else evidence


def _images_confirm(check, waves: Waves, details: dict, why: list) -> bool:
    """Whether the images' space-time evidence ``check`` (None: too few frames for it, which
    confirms nothing and denies nothing) confirms ``waves``: the images show dispersive
    waves, and the waves put their peak period within ``PEAK_PERIOD_FACTOR`` of the images'
    (``SLOPE_PEAK_RATIO`` times that on the longer side: the images' peak is the slopes';
    only the lower side where that peak sits at the band's long-wave edge, and the sea's
    may be longer). Records ``images_show_dispersion`` (and ``peak_period_s``) in
    ``details`` and appends the reason to ``why`` when it does not."""
    from jaxocean import fit

    details["images_show_dispersion"] = None if check is None else bool(check.success)
    if check is None:
        return True
    if not check.success:
        why.append(f"the images show no dispersive waves to confirm them (space-time evidence: {check.message})")
        return False
    tp_fit = float(fit.sea_state(waves).tp)
    tp_img = float(check.peak_period_s)
    low = tp_img / PEAK_PERIOD_FACTOR
    high = math.inf if check.peak_at_band_edge else tp_img * PEAK_PERIOD_FACTOR * SLOPE_PEAK_RATIO
    details["peak_period_s"] = tp_fit
    if not low <= tp_fit <= high:
        why.append(f"the waves' peak period {tp_fit:.3g} s is not the images' ({tp_img:.3g} s, space-time evidence)")
        return False
    return True


def waves_stage(seq: Sequence, geometry, *, frames: int | None = 16, max_waves: int = 24, init=None,
                noise: float = GEOMETRY_NOISE, correlation: float = GEOMETRY_CORRELATION, evidence="auto"):
    """Stage 4: the component waves behind the geometry sequence (``frames`` of them, spread
    evenly; None: all), at most ``max_waves``, with the order selection and success test of
    :func:`jaxocean.fit.waves` told the geometry's ``noise`` (per normal component),
    correlated over ``correlation`` times the view's width (``noise_correlation``).

    Success also needs the images to confirm that they hold dispersive waves
    (``evidence``: a :func:`space_time_evidence` result, None when there is none, or
    ``"auto"`` to compute it): the fit tests the waves against the network's geometry at
    the network's *average* error, and where the network is far worse than that (measured:
    a rough scene, 0.29 rad against 0.115) waves that explain its geometry are not in the
    sea. Images with no energy on the dispersion shell cannot confirm them, nor can images
    confirm waves whose peak period is below ``1 / PEAK_PERIOD_FACTOR`` (1/2) of theirs or
    above ``PEAK_PERIOD_FACTOR x SLOPE_PEAK_RATIO`` (3.0) times it (measured: one 17 s wave
    "explaining" a network's geometry of a 5.5 s sea whose images peak at 2.8 s within
    their band).
    ``init``: starting :class:`Waves` (e.g. a wave network's answer), else the fit's
    spectral start."""
    from jaxocean import fit

    idx = _spread(len(seq.times), frames)

    def run():
        check = _evidence_of(seq, evidence)
        shows_dispersion = None if check is None else bool(check.success)
        kw = {} if init is None else dict(init=init)
        length = float(correlation) * seq.camera.resolution[1]
        try:
            result = fit.waves(geometry.normal[idx], geometry.roughness[idx], seq.camera, seq.times[idx],
                               max_waves=max_waves, noise=noise, noise_correlation=length, **kw)
        except fit.NoWaveFound as error:
            # nothing to hand on but a flat sea: the later stages start from it and say so
            flat = _flat_sea_fit(geometry.normal[idx], seq.camera, seq.times[idx])
            details = dict(n_waves=0, frames=len(idx), normal_error_rad=float(flat.normal_error),
                           normal_noise_rad=float(noise), normal_correlation_px=length, determined=0, capped_waves=0,
                           surface="rows", images_show_dispersion=shows_dispersion)
            return flat, False, str(error), details
        n = int(result.n_waves)
        details = dict(n_waves=n, frames=len(idx), normal_error_rad=float(result.normal_error),
                       normal_noise_rad=float(noise), normal_correlation_px=length,
                       determined=int(np.sum(result.determined)) if result.determined is not None else None,
                       surface=result.surface)
        why = [] if result.success else [f"stopped at the cap of {max_waves} waves" if n >= max_waves
                                         else "the waves do not explain the geometry within its noise"]
        confirmed = _images_confirm(check, result.waves, details, why)
        # a fit to noisy geometry can explain the noise with waves too steep to exist (looping
        # crests, k h > 1): they are reported and capped so that the later stages can render
        waves, capped = _cap_steepness(result.waves, why)
        details["capped_waves"] = capped
        return (result._replace(waves=waves), bool(result.success) and not capped and confirmed, "; ".join(why),
                details)

    return timed("waves", run)


def _flat_sea_fit(normals, camera, times):
    """The :class:`~jaxocean.fit.WaveFit` of a flat sea (one wave of zero amplitude, what
    the renderer takes for no waves), scored against ``normals`` as :func:`fit.refine`
    scores any waves (no step taken), reported failed with no wave counted."""
    from jaxocean import fit

    dtype = jnp.asarray(normals).dtype
    one = lambda v: jnp.asarray([v], dtype)  # noqa: E731
    flat = Waves(one(0.0), one(1.0), one(0.0), one(0.0))
    scored = fit.refine(normals, None, camera, times, flat, max_steps=0, roughness_weight=0.0)
    return scored._replace(success=jnp.asarray(False), n_waves=jnp.asarray(0), determined=np.zeros(1, bool))


def _cap_steepness(waves: Waves, why: list):
    """``(waves, count)``: amplitudes of waves steeper than :data:`MAX_STEEPNESS` capped
    there, and how many; a note is appended to ``why`` when any was."""
    k = np.asarray(wavenumber(waves))
    kh = k * np.asarray(waves.amplitude)
    steep = kh > MAX_STEEPNESS
    if not steep.any():
        return waves, 0
    why.append(f"{int(steep.sum())} of {kh.size} waves steeper than k h = {MAX_STEEPNESS} (up to {kh.max():.2f}; "
               f"k h > 1 loops the crest): amplitudes capped there for the later stages")
    capped = np.where(steep, MAX_STEEPNESS / k, np.asarray(waves.amplitude))
    return waves._replace(amplitude=jnp.asarray(capped, waves.amplitude.dtype)), int(steep.sum())


def _spread(n: int, k: int | None) -> np.ndarray:
    if k is not None and k < 1:
        raise ValueError(f"frames must be >= 1 (or None for all {n}); got {k}")
    if k is None or k >= n:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, k)).astype(int))


def photometric_stage(seq: Sequence, waves: Waves, lighting, *, frames: int | None = 16, overcast: bool = False,
                      max_steps: int | None = None, rounds: int | None = None, per_frame_exposure: bool = False,
                      evidence="auto"):
    """Stage 5: waves, lighting and exposure refined jointly against the images through the
    renderer with a robust loss (:func:`jaxocean.fit.photometric`); ``per_frame_exposure``:
    one exposure per frame (a camera on automatic exposure).

    Success: the fit's own, and the images' space-time evidence confirms the refined waves
    as it must stage 4's (``evidence`` as in :func:`waves_stage`): images that show no
    dispersive waves confirm none, however well a few long waves render them (measured: two
    1.5 m waves of 10 and 17 s "explaining" 1.75 s of a 1.2 m, 5.5 s sea at 64 px)."""
    from jaxocean.fit import photometric_fit as ph

    idx = _spread(len(seq.times), frames)

    def run():
        check = _evidence_of(seq, evidence)
        kw = {k: v for k, v in (("max_steps", max_steps), ("rounds", rounds)) if v is not None}
        images = seq.images[idx][..., 0] if seq.gray else seq.images[idx]
        result = ph.photometric(images, seq.camera, seq.times[idx], waves, lighting, mask=seq.usable[idx],
                                overcast=overcast, per_frame_exposure=per_frame_exposure, **kw)
        details = ph.fit_to_dict(result)
        details.update(frames=len(idx), times=[float(t) for t in seq.times[idx]])
        why = [str(result.message)] if result.message else []
        confirmed = _images_confirm(check, result.waves, details, why)
        waves_, capped = _cap_steepness(result.waves, why)
        details["capped_waves"] = capped
        return (result._replace(waves=waves_), bool(result.success) and not capped and confirmed, "; ".join(why),
                details)

    return timed("photometric", run)


# ----------------------------------------------------------------------------- stage 6

def direction_deg(theta, compass: bool) -> float:
    """A library direction of travel [rad, from +x counter-clockwise] in the report's
    convention [deg]: clockwise from north when ``compass``, else from +x counter-clockwise;
    in [0, 360)."""
    d = math.degrees(math.pi / 2 - theta) if compass else math.degrees(theta)
    return d % 360.0


def _hs_uncertainty(waves: Waves, std: Waves | None) -> float:
    """1-sigma of Hs = 4 sqrt(sum h^2 / 2) from the amplitudes' standard deviations (delta
    method); NaN when none are known."""
    if std is None:
        return float("nan")
    h, sh = np.asarray(waves.amplitude, np.float64), np.asarray(std.amplitude, np.float64)
    m0 = np.sum(h ** 2) / 2
    if m0 <= 0 or not np.all(np.isfinite(sh)):
        return float("nan")
    return float(4 * np.sqrt(np.sum((h * sh) ** 2)) / (2 * np.sqrt(m0)))


def sea_stage(seq: Sequence, waves: Waves, geometry, *, std: Waves | None = None, determined=None,
              waves_ok: bool = True, evidence="auto"):
    """Stage 6a: the sea state. Hs, Tp and the mean direction of ``waves`` and of the
    JONSWAP spectrum fitted to them (:func:`jaxocean.fit.spectrum`); whether the peak lies
    in the observed band (else Hs and Tp are bounds); the spreading; the mean square slope
    of the geometry; and the space-time evidence (:func:`jaxocean.spacetime.dispersion_check`)
    computed from the images alone (sequences of at least ``spacetime.MIN_FRAMES`` frames).
    Success: the spectrum fit succeeded, the waves before it did (``waves_ok``) and the
    images show dispersive waves (when the check could run). ``evidence``: the check
    (:func:`space_time_evidence`) when already computed, else ``"auto"``. ``determined``:
    bool ``(N,)``, the waves whose parameters the wave fit measured (its ``determined``):
    only their energies can show the spectral peak (None: every wave's).

    The geometry's own space-time spectrum (:func:`geometry_sea_spectrum`) is reported
    beside (``geometry_spectrum``). Where no wave is confirmed (``waves_ok`` False) it
    gives the headline numbers instead (``source``): the Hs of
    the band the view resolves (a lower bound on the sea's), its peak period (a lower bound
    where the peak sits at the band's long-wave edge) and the mean direction; success then
    needs the images' dispersion check and the geometry spectrum's own (its off-shell floor
    below half of its shell power)."""
    from jaxocean import fit

    def run():
        check = _evidence_of(seq, evidence)
        geo_sea = geometry_sea_spectrum(seq, geometry, check)
        state = fit.sea_state(waves)
        # a flat sea handed on (no wave found) is no sea state: its one zero-amplitude wave
        # has a period, but no wave of the sea
        no_waves = not bool(np.any(np.asarray(waves.amplitude) > 0))
        n_reliable = 0 if no_waves else int(np.sum(fit.resolvable(waves, seq.camera)))
        sf = None
        hs_std_waves = _hs_uncertainty(waves, std)
        nan = math.nan
        # the geometry's spectrum speaks where the waves cannot: none confirmed
        from_geometry = (geo_sea is not None and geo_sea.success and check is not None and bool(check.success)
                         and not waves_ok)
        if from_geometry:
            hs, tp, theta, spread, gam = geo_sea.hs_band_m, geo_sea.peak_period_s, geo_sea.direction, nan, nan
            observed = not geo_sea.peak_at_band_edge
            if not observed and math.isfinite(check.peak_period_s):
                # both peaks bound Tp from below (the images' is the slope's, whose peak lies at
                # or above the elevation's frequency): the longer bound holds
                tp = max(tp, float(check.peak_period_s))
            hs_std, tp_std, theta_std, spread_std, gam_std = geo_sea.hs_band_std_m, nan, geo_sea.direction_std, nan, nan
            alpha = geo_sea.tail_alpha
        elif n_reliable >= fit.spectrum_fit.MIN_WAVES:
            sf = fit.spectrum(waves, camera=seq.camera, roughness=geometry.roughness, determined=determined)
            s = sf.spectrum
            hs, tp, theta, spread, gam = (float(x) for x in (s.hs, s.tp, s.theta_mean, s.s_max, s.gamma))
            observed, alpha = bool(sf.peak_observed), float(sf.alpha)
            # the spectrum fit's scatter and the waves' own amplitude errors, independent
            hs_std = math.hypot(sf.hs_std, hs_std_waves) if math.isfinite(hs_std_waves) else sf.hs_std
            tp_std, theta_std, spread_std, gam_std = sf.tp_std, sf.theta_std, sf.s_max_std, sf.gamma_std
        elif no_waves:
            hs, tp, theta, spread, gam, alpha = nan, nan, nan, nan, nan, nan
            observed = False
            hs_std, tp_std, theta_std, spread_std, gam_std = nan, nan, nan, nan, nan
        else:  # too few resolved waves for a spectrum: the waves' own bulk numbers, marked as bounds
            hs, tp, theta, spread, gam, alpha = float(state.hs), float(state.tp), float(state.theta_mean), nan, nan, nan
            observed = False
            hs_std, tp_std, theta_std, spread_std, gam_std = hs_std_waves, nan, nan, nan, nan
        # waves that no stage confirmed give no headline sea state (they stay reported as
        # waves_hs_m / waves_tp_s and in the spectrum fit's own fields): no number at all
        # rather than the sea state of waves that do not explain the data
        unconfirmed = not waves_ok and not from_geometry and not no_waves
        if unconfirmed:
            hs, tp, theta, spread, gam, alpha = nan, nan, nan, nan, nan, nan
            hs_std, tp_std, theta_std, spread_std, gam_std = nan, nan, nan, nan, nan
            observed = False
        sea = dict(
            hs_m=hs, hs_std_m=hs_std, tp_s=tp, tp_std_s=tp_std,
            direction_deg=direction_deg(theta, seq.compass), direction_std_deg=math.degrees(theta_std),
            direction_convention="clockwise from north" if seq.compass else "counter-clockwise from +x",
            spreading_s_max=spread, spreading_std=spread_std, gamma=gam, gamma_std=gam_std, peak_observed=observed,
            tail_alpha=alpha,
            source=("space-time spectrum of the geometry" if from_geometry else None if no_waves or unconfirmed
                    else "spectrum fit of the waves" if sf is not None else "the fitted waves"),
            bound=(_geometry_bound(geo_sea) if from_geometry
                   else "no sea state: no wave was confirmed (the wave fit failed and the photometric refinement "
                        "did not succeed) and the geometry's own spectrum, with the images' dispersion check, "
                        "gives none" if unconfirmed
                   else None if observed
                   else f"Hs and Tp are not estimates: no JONSWAP spectrum explains the waves' energies (misfit "
                        f"{sf.misfit:.3g} above its bound {sf.misfit_bound:.3g}); they are the closest one's"
                   if sf is not None and not sf.misfit <= sf.misfit_bound
                   else "Hs and Tp are bounds, not estimates: the waves the fit determined do not show the "
                        "spectral peak (it lies outside their band, or one beyond it explains them as well)"
                   if sf is not None else "no wave was found: no sea state" if no_waves
                   else "Hs and Tp are those of the fitted waves alone (too few resolved waves for a spectrum)"),
            omega_band=None if sf is None else [float(x) for x in sf.omega_band],
            waves_hs_m=nan if no_waves else float(state.hs), waves_tp_s=nan if no_waves else float(state.tp),
            resolved_waves=n_reliable,
            mean_square_slope=sum(_mean_square_slopes(geometry)),
            spectrum_success=sf is not None and bool(sf.success),
            spectrum_misfit=None if sf is None else float(sf.misfit),
            geometry_spectrum=None if geo_sea is None else _geometry_sea_dict(geo_sea, seq.compass),
            dispersion=None if check is None else _check_dict(check, seq.compass),
            dispersion_peak_period_s=None if check is None else float(check.peak_period_s),
            dispersion_direction_deg=None if check is None else direction_deg(float(check.peak_direction),
                                                                             seq.compass),
            dispersion_note=None if check is not None else f"not computed: {_missing_evidence(seq)}",
        )
        # too short a sequence for the space-time check: the evidence is missing, not negative
        ok = sea["spectrum_success"] and (check is None or bool(check.success)) and waves_ok
        why = []
        if from_geometry:
            # the geometry's spectrum, confirmed by the images: its own test stands
            return (sea, check, sf), True, geo_sea.message, sea
        if geo_sea is not None and not geo_sea.success and not waves_ok:
            why.append(geo_sea.message)
        if not waves_ok:
            why.append("the wave fit failed, so the spectrum describes waves that do not explain the data")
        if sf is None:
            why.append(f"{n_reliable} resolved waves: a spectrum needs {fit.spectrum_fit.MIN_WAVES}")
        elif not sf.success:
            why.append("no single JONSWAP spectrum explains the fitted waves")
        if check is None:
            why.append(f"no space-time evidence: {_missing_evidence(seq)}")
        elif not check.success:
            why.append(f"the images show little energy on the dispersion shell ({check.message})")
        return (sea, check, sf), ok, "; ".join(why), sea

    return timed("spectrum", run)


def _missing_evidence(seq: Sequence) -> str:
    """Why :func:`sea_stage` has no space-time check (``dispersion_note`` in ``result.json``
    says it, so that the check's null fields are not read as a failed check)."""
    from jaxocean import spacetime

    if len(seq.times) < spacetime.MIN_FRAMES:
        return f"it needs {spacetime.MIN_FRAMES} frames, {len(seq.times)} given"
    return "none was given"


def geometry_sea_spectrum(seq: Sequence, geometry, check=None):
    """:func:`jaxocean.spacetime.sea_spectrum` of the geometry sequence (every frame), with
    the Doppler velocity of the images' dispersion check ``check`` where it succeeded; None
    for a sequence shorter than ``spacetime.MIN_FRAMES``."""
    from jaxocean import spacetime

    if len(seq.times) < spacetime.MIN_FRAMES:
        return None
    current = tuple(check.current) if check is not None and check.success else (0.0, 0.0)
    return spacetime.sea_spectrum(np.asarray(geometry.normal), seq.camera, seq.times,
                                  mask=np.asarray(geometry.mask), current=current)


def _geometry_bound(geo_sea) -> str:
    hs = f"Hs is that of the waves {geo_sea.band_m[0]:.3g}-{geo_sea.band_m[1]:.2g} m long the view resolves"
    if geo_sea.peak_at_band_edge:
        return (hs + ", a lower bound; Tp is a lower bound (the longer of the geometry's and the images' peak "
                "periods): the spectral peak lies beyond the band's longest waves")
    return hs + " (a lower bound; the peak lies inside the band)"


def _geometry_sea_dict(geo_sea, compass: bool) -> dict:
    return dict(hs_band_m=geo_sea.hs_band_m, hs_band_std_m=geo_sea.hs_band_std_m,
                peak_period_s=geo_sea.peak_period_s, peak_at_band_edge=geo_sea.peak_at_band_edge,
                direction_deg=direction_deg(geo_sea.direction, compass) if math.isfinite(geo_sea.direction) else None,
                direction_std_deg=math.degrees(geo_sea.direction_std), spread_deg=math.degrees(geo_sea.spread),
                tail_alpha=geo_sea.tail_alpha, floor_fraction=geo_sea.noise_fraction,
                band_m=[float(x) for x in geo_sea.band_m], success=geo_sea.success, message=geo_sea.message,
                k_rad_m=[float(x) for x in geo_sea.spectrum.get("k", [])],
                elevation_m2=[float(x) for x in geo_sea.spectrum.get("elevation", [])])


def _check_dict(check, compass: bool) -> dict:
    """The dispersion check's fields for ``result.json``; its peak direction in the report's
    convention [deg] (:func:`direction_deg`), as every direction there."""
    out = {}
    for name in ("shell_fraction", "null_fraction", "ratio", "peak_period_s", "peak_wavelength_m", "success",
                 "message"):
        v = getattr(check, name, None)
        out[name] = v if isinstance(v, (str, bool, type(None))) else float(v)
    out["peak_direction_deg"] = direction_deg(float(check.peak_direction), compass)
    return out


def _mean_square_slopes(geometry) -> tuple:
    """``(resolved, sub-pixel)`` mean square slope over the sea pixels of every frame: of the
    normals, and the roughness (slope variance) below the pixel."""
    sea = np.asarray(geometry.mask)
    slope = np.asarray(slope_from_normal(jnp.asarray(geometry.normal), 1e-6))
    return float(np.mean((slope ** 2).sum(-1)[sea])), float(np.mean(np.asarray(geometry.roughness)[sea]))


def outlook_stage(seq: Sequence, waves: Waves, lighting, *, exposure: float = 1.0, ahead=(2.0, 10.0, 30.0),
                  height_factor: float = 0.5, sun_elevation: float = math.radians(25.0), model=None, plan="rows",
                  waves_ok: bool = True):
    """Stage 6b: forecast frames ``ahead`` seconds after the last observed frame, and the
    last frame re-rendered from a camera ``height_factor`` times as high and under a new sun
    (``sun_elevation``, from behind the camera; an overcast fit gets a sun 20 times its sky);
    linear images in the footage's units (times ``exposure``). ``model``: None (forecast
    ``waves`` as they are) or ``(waves, frequency_sigma, window)`` of
    :func:`jaxocean.fit.waves.forecast_model`: the least-squares forecast of a wave fit,
    drawn with ``plan`` (:func:`jaxocean.fit.waves.forecast_plan`: the fit's surface path).

    Success: ``waves_ok``, some stage confirmed the waves (as :func:`sea_stage`'s): frames
    drawn from waves that explain no data are drawn all the same, but forecast nothing."""
    from jaxocean import fit

    def run():
        t_end = float(seq.times[-1])
        times = np.asarray([t_end + a for a in ahead])
        if model is None:
            fcast = fc.forecast(waves, times, seq.camera, lighting)
        else:
            fcast = fc.forecast(model[0], times, seq.camera, lighting, window=model[2], frequency_sigma=model[1],
                                plan=plan)
        light = lighting
        if float(np.max(np.asarray(lighting.sun_color))) <= 0:
            light = lighting._replace(sun_color=20.0 * jnp.asarray(lighting.sky_color))
        lower = fit.reedit(waves, seq.camera, lighting, t_end, camera_height=height_factor * float(seq.camera.height))
        sun = fit.reedit(waves, seq.camera, light, t_end, sun_azimuth=float(seq.camera.yaw) + math.pi,
                         sun_elevation=sun_elevation)
        out = dict(times=times, forecast=exposure * np.asarray(fcast.image), lower=exposure * np.asarray(lower),
                   new_sun=exposure * np.asarray(sun),
                   normals=np.asarray(fcast.geometry.normal))
        why = "" if waves_ok else ("the forecast draws waves no stage confirmed (the wave fit failed and the "
                                   "photometric refinement did not succeed): it forecasts nothing")
        return out, waves_ok, why, dict(ahead_s=list(ahead), camera_height_m=height_factor * float(seq.camera.height),
                                        sun_elevation_deg=math.degrees(sun_elevation),
                                        forecast="least-squares (damped)" if model is not None
                                        else "as fitted (no wave fit)")

    return timed("forecast", run)


# ----------------------------------------------------------------------------- pipeline

def reconstruct(frames, camera_path, *, out=None, width: int = DEFAULT_WIDTH, response: str = "srgb",
                gamma: float = 2.2, step: int = 1, max_frames: int | None = None, height: float | None = None,
                wave_frames: int | None = 16, max_waves: int = 24, overcast: bool | None = None,
                refine: bool = True, refine_steps: int | None = None, refine_rounds: int | None = None,
                per_frame_exposure: bool = False, geometry_model=None, progress: bool = True) -> Reconstruction:
    """Run every stage (module docstring) and, with ``out``, write ``result.json``, the
    report and its figures there (:mod:`jaxocean.report`). A stage that fails does not stop
    the pipeline while its output exists; its flag says what the later numbers rest on.
    ``refine=False`` skips stage 5 (the two-step method of the paper); ``refine_steps`` /
    ``refine_rounds``: its Levenberg-Marquardt steps per IRLS round and its rounds (None:
    :func:`jaxocean.fit.photometric`'s defaults); ``per_frame_exposure``: stage 5 fits one
    exposure per frame (the forecast and re-edited views use their geometric mean).
    ``geometry_model``: stage 2's network
    (:func:`geometry_stage`; None: the default shipped model)."""
    if out is not None and Path(out).exists() and not Path(out).is_dir():  # before minutes of work
        raise ValueError(f"out {out}: exists and is not a directory (reconstruct writes its report there)")
    stages = {}

    def say(report):
        stages[report.name] = report
        if progress:
            flag = "ok  " if report.success else "FAIL"
            print(f"[{flag}] {report.name:<12s} {report.seconds:7.1f} s  {report.message}", flush=True)

    seq, rep = load_sequence(frames, camera_path, width=width, response=response, gamma=gamma, step=step,
                             max_frames=max_frames, height=height)
    say(rep)
    _check_evidence_times(seq)
    geometry, rep = geometry_stage(seq, model=geometry_model)
    say(rep)
    light, rep = lighting_stage(seq, geometry, overcast=overcast)
    say(rep)
    over = bool(rep.details.get("overcast", False))
    # the images' own evidence of dispersive waves: confirms stage 4 and joins stage 6 (its
    # time is stage 4's)
    t_evidence = time.perf_counter()
    evidence = space_time_evidence(seq)
    t_evidence = time.perf_counter() - t_evidence
    wfit, rep = waves_stage(seq, geometry, frames=wave_frames, max_waves=max_waves, evidence=evidence)
    rep = rep._replace(seconds=rep.seconds + t_evidence)
    say(rep)
    waves, waves_ok, lighting = wfit.waves, rep.success, light.lighting
    photo = None
    if refine:
        photo, rep = photometric_stage(seq, waves, lighting, frames=wave_frames, overcast=over,
                                       max_steps=refine_steps, rounds=refine_rounds,
                                       per_frame_exposure=per_frame_exposure, evidence=evidence)
        say(rep)
        if rep.success:
            waves, lighting = photo.waves, photo.lighting
        waves_ok = waves_ok or rep.success
    refined = photo is not None and stages["photometric"].success
    determined = wfit.determined
    if refined and photo.determined is not None:
        determined = photo.determined
    (sea, check, sfit), rep = sea_stage(seq, waves, geometry, std=None if refined else wfit.uncertainty,
                                        determined=determined, waves_ok=waves_ok, evidence=evidence)
    say(rep)
    from jaxocean.fit.photometric import mean_exposure

    # the least-squares forecast: each wave damped outside the fitted window by what the window
    # measured of its frequency. Stage 4's waves come with its long-wave band; waves refined
    # against the images (stage 5, same order, no band) with stage 5's own `determined` and
    # stage 4's frequency uncertainties
    model, plan = None, "rows"
    if int(wfit.n_waves) > 0 and wfit.determined is not None:
        from jaxocean.fit.waves import forecast_model, forecast_plan

        basis = wfit
        if refined:
            basis = wfit._replace(waves=photo.waves, long_waves=None, determined=determined)
        model = forecast_model(basis, seq.camera, np.asarray(seq.times)[_spread(len(seq.times), wave_frames)])
        plan = forecast_plan(basis, model[0].omega.shape[0])
    outlook, rep = outlook_stage(seq, waves, lighting, exposure=mean_exposure(photo) if refined else 1.0,
                                 model=model, plan=plan, waves_ok=waves_ok)
    say(rep)
    result = Reconstruction(seq, geometry, light, wfit, photo, dict(sea, waves=waves, check=check, spectrum_fit=sfit),
                            outlook, stages)
    if out is not None:
        from jaxocean import report

        report.write(Path(out), result)
    return result


def result_dict(result: Reconstruction) -> dict:
    """The JSON-safe summary ``result.json`` holds (module docstring)."""
    seq = result.sequence
    sea = {k: v for k, v in result.sea.items() if k not in ("waves", "check", "spectrum_fit")}
    waves = result.sea["waves"]
    listed = [dict(amplitude_m=float(h), omega_rad_s=float(w), period_s=2 * math.pi / float(w),
                   direction_deg=direction_deg(float(t), seq.compass), phase_rad=float(p))
              for h, w, t, p in zip(*(np.asarray(x, np.float64) for x in waves))]
    if not np.any(np.asarray(waves.amplitude) > 0):
        listed = []  # a flat sea handed on (no wave found): its zero-amplitude stand-in is no wave
    stages = {name: dict(success=r.success, seconds=r.seconds, message=r.message, details=json_safe(r.details))
              for name, r in result.stages.items()}
    # the flag beside the numbers, for scripts that read only this section
    sea["success"] = bool(result.stages["spectrum"].success) if "spectrum" in result.stages else False
    return dict(spectrum=json_safe(sea), waves=listed, stages=stages, success=all(r.success for r in
                                                                                     result.stages.values()),
                camera=cam.camera_to_dict(seq.camera, degrees=True), times_s=[float(t) for t in seq.times],
                files=list(seq.files))
