"""Photometric refinement: waves, lighting and exposure fitted jointly to an image sequence.

Protocol
--------
``photometric(images, camera, times, waves, lighting, *, fit=("waves", "lighting", "exposure"),
...) -> PhotometricFit``

* ``images``  ``(T, H, W, 3)`` linear RGB radiance, or ``(T, H, W)`` gray, taken as the
  luminance ``LUMINANCE . RGB`` of the RGB model (:data:`jaxocean.shading.LUMINANCE`,
  Rec. 709), with an unknown overall exposure.
* ``camera``  the :class:`jaxocean.camera.Camera` the frames are rectified to
  (``camera.resolution == (H, W)``); ``times`` ``(T,)`` frame times [s], strictly increasing.
* ``waves``   the start :class:`jaxocean.waves.Waves` ``(N,)`` (e.g. from ``fit.waves``);
  ``lighting`` the start :class:`jaxocean.shading.Lighting` (e.g. from ``fit.lighting``).
* ``mask``    ``(T, H, W)`` bool, the usable pixels (unsaturated, inside the frame); default all.

Model: frame ``i`` is ``exposure * render(waves, camera, lighting, times[i])``
(:func:`jaxocean.render.render` with the explicit static plan ``RenderPlan(all N waves,
refine=0)``: the rows path, the plane-hit model ``fit.waves`` also fits; ``refine=`` picks the
hits path instead), its luminance for gray images. The render gradients are exact JAX
gradients (forward mode). Only sea pixels enter the loss: sky pixels carry no information
about the waves, and the model's uniform (or horizon-gradient) sky rarely matches a real
sky's brightness, while the sky radiance the sea reflects -- what constrains the sky colour
here -- is measured by the sea pixels themselves (``sky=True`` adds the sky pixels).

Comparison space: ``c(I) = log1p(I / s)`` (:func:`jaxocean._sea_scale.compress`), ``s`` the
per-channel median of the observed images over the used sea pixels. The residual is
``c(model) - c(image)``. Chosen over tone-mapped display values because it does not depend
on the unknown exposure (image and model are compared on the image's own scale; a tone map
acts after the exposure, so its loss would change with the fitted exposure), it is a
relative error near the sea's level (``dI / (s + I)``), and it compresses glints and
saturated whitecaps logarithmically, so an outlier's residual is O(1), not O(1e3).

Parameters (one vector, solved jointly):

* waves: ``(a, b, log omega, theta)`` per wave, ``(a, b) = h (cos phi, sin phi)`` (as
  :mod:`jaxocean.fit.waves`);
* sun direction: the azimuthal-equidistant ``(p, q)`` of :mod:`jaxocean.fit.lighting`
  (not with ``overcast=True``: then the sun colour is fixed at 0 and the sun is not fitted);
* colours: log factors on the start colours, one per channel (RGB) or one per colour (gray
  images see only each colour's luminance); the sun, sky and sea colours (sky and sea when
  overcast). A start channel at 0 is started at 1e-4 of the brightest start colour;
* exposure: ``log exposure``, or one per frame with ``per_frame_exposure=True`` (a camera
  on automatic exposure); the gauge below then holds frame by frame.

Exposure gauge: the image is linear in the colours, so a common factor of all colours is
the exposure. With both ``"lighting"`` and ``"exposure"`` fitted the colour factors are
constrained to a zero mean of their logs (an orthonormal basis of that subspace is the
parameter): the colours keep the start's geometric-mean brightness and the exposure
carries the common scale. With ``"lighting"`` alone the exposure stays at ``exposure``
(kwarg, default 1) and the colours carry the scale; with ``"exposure"`` alone the colours
stay at the start. Before solving, the fitted scale (exposure, else the colours) is set
so that the model's sea median matches the images' (one closed-form step).

Robust loss (``robust="cauchy"``, ``"huber"``, ``"tukey"``; ``None``: plain least squares):
iteratively reweighted least squares. Each of ``rounds`` rounds fixes the scale ``sigma =
1.4826 median |r|`` (the MAD of the residuals over used pixels and channels, floored at the
noise level (*Noise* below): without the floor, on 8-bit frames the scale can collapse onto
the pixels a fit reproduces exactly and mark the rest outliers) and per-pixel weights ``w(u)`` of ``u = rms_channels(r) / (c sigma)``
(Cauchy ``1 / (1 + u^2)``, ``c = 2.385``; Huber ``min(1, 1 / u)``, ``c = 1.345``; Tukey
``(1 - u^2)^2`` for ``u < 1`` else 0, ``c = 4.685``), then minimises ``sum w r^2`` by
Levenberg-Marquardt (Nielsen damping, Marquardt scaling) on normal equations accumulated
frame by frame. On the rows path the Jacobian is exact and structured: the derivative of
each pixel's residual with respect to its normal and slope variance (forward mode through
:func:`jaxocean.render.shade`) times the wave fit's hand-written Jacobian of the normal
(:func:`jaxocean.fit.waves._model.jacobian`: each wave touches only its own sines) and the
row roughness' Jacobian; the lighting and exposure columns by forward mode through the
shading. On the hits path (``refine > 0``) forward mode runs through the whole renderer.
Trial steps are accepted on the exact loss. The ``outliers`` are the used pixels whose
final weight is below ``OUTLIER_WEIGHT`` (for Cauchy ``|r| > 4.8 sigma``); with
``robust=None`` they are marked by the Cauchy rule at the final scale, the weights are 1.
The model and its Jacobian are :mod:`jaxocean.fit._photometric_model`; the robust weights
and the noise and spread estimates :mod:`jaxocean.fit._robust`.

``loss`` and ``loss_init``: the mean over used pixels of the robust function ``(c sigma)^2
rho(u)`` (``rho`` ~ ``u^2 / 2`` for small ``u``; plain ``r^2 / 2`` for ``robust=None``), both
at the final scale ``sigma``, so they compare like with like.

Noise (the level the success test holds the residual to), in the comparison space (about
the relative radiance noise near the sea's level): ``noise=`` as given, or estimated from
the images by Immerkaer's operator (the 3x3 kernel ``[[1,-2,1],[-2,4,-2],[1,-2,1]]``, which
cancels planes and ramps, noise gain 6) over pixels whose 3x3 neighbourhood is used sea,
all frames and channels, with a trimmed scale: the mean of ``|K * c(image)|`` below its
90th percentile over 0.6573 (that truncated mean of a unit half-normal) over 6. Trimmed, not
a median, because on 8-bit frames most neighbourhoods of the dark sea are flat and a
median is 0. Wave texture near the pixel scale adds
to it, so the estimate is an upper bound of the noise: a lenient residual test, which is why
the success test also asks the waves to explain the images' structure.

Success: ``success`` is True only when every one of these holds (``message`` names each
that fails):

* the loss is finite and no worse than at the start (``loss <= loss_init``);
* ``residual_scale <= SCALE_FACTOR (1.5) * max(noise, NOISE_FLOOR)``: the residual of what the
  model keeps is at the noise level (``NOISE_FLOOR = 1e-3``: the model's own consistency).
  ``residual_scale`` is the residual's trimmed scale, the estimator of the noise and of
  ``signal_scale`` below; not the IRLS scale ``robust_scale``, which is floored at the noise,
  nor a MAD, which glints' heavy tails shrink: either let a flat sea pass on small textured
  frames, whose noise estimate the texture inflates;
* ``outlier_fraction <= MAX_OUTLIER_FRACTION (0.2)``: the model produces most of the image;
* the images hold structure above the noise: ``signal_scale >= STRUCTURE_RATIO (1.05) *
  max(noise, NOISE_FLOOR)``, ``signal_scale`` the trimmed scale (as the noise's) of
  ``c(image)`` about its per-row median (the view-dependent mean); pure noise fails here;
* the fitted waves explain that structure: the residual's spread above the noise,
  ``sqrt(max(residual_scale^2 - noise^2, 0))``, is at most ``EXPLAINED_RATIO (0.5)`` of the
  images', ``sqrt(signal_scale^2 - noise^2)``;
* the images determine the waves: the waves whose Gauss-Newton standard deviations (from
  ``J^T W J`` at the answer, the noise per residual element ``max(noise, robust_scale,
  NOISE_FLOOR)``) are below ``DETERMINED_STD`` (relative amplitude 0.2, ``log omega`` 0.02,
  ``theta`` 0.05 rad) hold at least ``DETERMINED_ENERGY (0.9)`` of the fitted slope energy
  ``sum (k h)^2``, and a wave counts only if the view resolves it
  (:func:`jaxocean.fit.waves.resolvable`: at least one wavelength of sea along its
  direction, on pixels finer than it) and the frames tell which way it travels
  (:func:`jaxocean.fit.waves.alias_separation` >= 1, the wave fit's rule: where ``omega dt``
  is a multiple of pi its reverse twin ``(theta + pi, -phi)`` makes the same frames, a
  second minimum as deep whose Gauss-Newton covariance is as small). At low signal to noise
  a fit can reach the noise level with waves the images do not pin down, and a wave longer
  than the view can stand in for a tilt with a small covariance; this is what reports it.

Not checked: the rows path's own error for waves tall enough to move a pixel's hit by a
footprint (render's ``needs_refinement``), beyond what it adds to the residual.

Everything after validation runs in two jitted functions (one IRLS round; the final
statistics) with static configuration, compiled once per shape and configuration; the fit
itself is eager (host loop over rounds, ``progress=True`` prints them). :func:`residual` is
the comparison-space residual as a jittable function of the inputs, :func:`rerender` the
fitted model's frames, :func:`fit_to_dict` a JSON-safe summary.
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
from jaxocean import render, shading
from jaxocean._sea_scale import compress, sea_median
from jaxocean.errors import InvalidValueError, check_nonnegative_number, is_concrete, require_eager
from jaxocean.fit._image_inputs import fit_dtype
from jaxocean.fit._photometry import sun_to_pq
from jaxocean.fit._photometric_model import (COLOR_NAMES, Data, Static, all_residuals, frame_jacobian, layout,
                                            model_frames, pack_params, unpack)
from jaxocean.fit._plausibility import parameter_std
from jaxocean.fit._robust import (CODES, OUTLIER_WEIGHT, ROBUST_LOSSES, SCALE_FLOOR, irls_weights, noise_estimate,
                                  robust_statistics, signal_scale)
from jaxocean.fit.lighting import lighting_to_dict
from jaxocean.fit.solvers import FitError
from jaxocean.fit.waves import alias_separation, resolvable
from jaxocean.fit.waves._model import pack, to_waves
from jaxocean.shading import Lighting
from jaxocean.waves import Waves, validate

__all__ = [
    "PHOTOMETRIC_FIELDS",
    "ROBUST_LOSSES",
    "OUTLIER_WEIGHT",
    "SCALE_FACTOR",
    "NOISE_FLOOR",
    "MAX_OUTLIER_FRACTION",
    "EXPLAINED_RATIO",
    "STRUCTURE_RATIO",
    "DETERMINED_STD",
    "DETERMINED_ENERGY",
    "SCALE_FLOOR",
    "PhotometricFit",
    "photometric",
    "residual",
    "rerender",
    "estimate_noise",
    "mean_exposure",
    "fit_to_dict",
]

PHOTOMETRIC_FIELDS = ("waves", "lighting", "exposure")
#: success needs residual_scale <= SCALE_FACTOR * max(noise, NOISE_FLOOR)
SCALE_FACTOR = 1.5
NOISE_FLOOR = 1e-3
#: success needs outlier_fraction <= MAX_OUTLIER_FRACTION
MAX_OUTLIER_FRACTION = 0.2
#: success needs the residual's spread above the noise <= EXPLAINED_RATIO x the images' (module docstring)
EXPLAINED_RATIO = 0.5
#: success needs signal_scale >= STRUCTURE_RATIO * max(noise, NOISE_FLOOR)
STRUCTURE_RATIO = 1.05
#: a wave is determined when its standard deviations are below these (relative amplitude,
#: log omega, theta [rad]); success needs the determined waves to hold DETERMINED_ENERGY of
#: the fitted slope energy
DETERMINED_STD = {"amplitude": 0.2, "log_omega": 0.02, "theta": 0.05}
DETERMINED_ENERGY = 0.9


class PhotometricFit(NamedTuple):
    """Result of :func:`photometric`.

    * ``waves``      fitted :class:`~jaxocean.waves.Waves` ``(N,)`` (start order).
    * ``lighting``   fitted :class:`~jaxocean.shading.Lighting` (sun colour 0 when overcast).
    * ``exposure``   ``()`` the exposure: images ~ ``exposure * render(waves, lighting)``;
      ``(T,)`` one per frame with ``per_frame_exposure=True``.
    * ``outliers``   ``(T, H, W)`` bool: used pixels the model cannot produce (final weight
      below :data:`OUTLIER_WEIGHT`).
    * ``weights``    ``(T, H, W)`` final IRLS weights (0 on unused pixels).
    * ``loss_init``, ``loss`` ``()`` the robust loss at the start and at the answer, both at
      the final scale (module docstring).
    * ``robust_scale`` ``()`` final IRLS scale: the residual's MAD floored at the noise level.
    * ``residual_scale`` ``()`` the residual's trimmed scale (comparison space; the estimator
      of ``noise`` and ``signal_scale``): what the success test holds to them.
    * ``noise``      ``()`` the noise level of the success test (given or estimated).
    * ``outlier_fraction`` ``()`` outliers over used pixels.
    * ``steps``      total Levenberg-Marquardt steps over the rounds.
    * ``seconds``    wall time of the call [s], compilation included on a first call.
    * ``success``    bool: the fit explains the data (module docstring, *Success*).
    * ``message``    empty on success, else which criteria failed and by how much.
    * ``signal_scale`` ``()`` the images' own spread about the per-row median (comparison space).
    * ``sea_scale``  ``(C,)`` the per-channel sea median ``s`` of the comparison space.
    * ``noise_estimated`` bool: ``noise`` was estimated from the images.
    * ``determined`` ``(N,)`` bool (None when the waves are not fitted): the view resolves
      the wave, the frames separate it from its reverse twin, and its Gauss-Newton standard
      deviations are below :data:`DETERMINED_STD`; ``determined_energy`` the determined
      waves' share of the slope energy.
    """

    waves: Waves
    lighting: Lighting
    exposure: jax.Array
    outliers: jax.Array
    weights: jax.Array
    loss_init: jax.Array
    loss: jax.Array
    robust_scale: jax.Array
    noise: jax.Array
    outlier_fraction: jax.Array
    steps: int
    seconds: float
    success: bool
    message: str
    signal_scale: jax.Array = None
    sea_scale: jax.Array = None
    noise_estimated: bool = True
    determined: np.ndarray | None = None
    determined_energy: float = 1.0
    residual_scale: jax.Array = None


# --------------------------------------------------------------------------- solver


def _normal_equations(y, w, d: Data, st: Static):
    """``(0.5 sum w r^2, J^T W J, J^T W r)`` over frames, ``w (T, H, W)`` pixel weights,
    normalised by the number of used pixel-channels."""
    P = y.shape[0]
    C = d.target.shape[-1]
    norm = 1.0 / jnp.maximum(C * jnp.sum(d.used), 1.0)

    def body(carry, i):
        f, jtj, jtr = carry
        r, J = frame_jacobian(y, i, d, st)
        wv = jnp.repeat(w[i].reshape(-1), C) * norm
        return (f + 0.5 * jnp.sum(wv * r * r), jtj + (J * wv[:, None]).T @ J, jtr + J.T @ (wv * r)), None

    zero = (jnp.zeros((), y.dtype), jnp.zeros((P, P), y.dtype), jnp.zeros(P, y.dtype))
    out, _ = jax.lax.scan(body, zero, jnp.arange(d.target.shape[0]))
    return out


def _weighted_loss(y, w, d: Data, st: Static):
    r = all_residuals(y, d, st)
    C = d.target.shape[-1]
    return 0.5 * jnp.sum(w[..., None] * r * r) / jnp.maximum(C * jnp.sum(d.used), 1.0)


def _lm(y0, w, d: Data, st: Static, max_steps: int, rtol: float):
    """Levenberg-Marquardt on ``0.5 sum w r^2`` (weights fixed): Nielsen damping, Marquardt
    scaling; the normal equations are recomputed only after an accepted step (at the top of
    the next step: one compiled copy of the Jacobian). Returns ``(y, f, steps, J^T W J)``,
    the last at the last point where it was computed (the answer or the step before)."""
    dtype = y0.dtype
    P = y0.shape[0]

    def cond(s):
        return (~s[7]) & (s[6] < max_steps)

    def body(s):
        y, f, jtj, jtr, lam, nu, k, _, stale = s
        f, jtj, jtr = jax.lax.cond(stale, lambda: _normal_equations(y, w, d, st), lambda: (f, jtj, jtr))
        diag = jnp.diag(jtj)
        dsc = jnp.maximum(diag, 1e-9 * jnp.max(diag) + 1e-30)
        step = -jnp.linalg.solve(jtj + lam * jnp.diag(dsc), jtr)
        ok = jnp.all(jnp.isfinite(step))
        step = jnp.where(ok, step, 0.0)
        y_try = y + step
        f_try = _weighted_loss(y_try, w, d, st)
        pred = -(step @ jtr) - 0.5 * step @ (jtj @ step)
        actual = f - f_try
        rho = actual / jnp.where(pred > 0, pred, 1.0)
        accept = ok & jnp.isfinite(f_try) & (actual > 0) & (pred > 0) & (rho > 1e-4)
        y2 = jnp.where(accept, y_try, y)
        f2 = jnp.where(accept, f_try, f)
        lam2 = jnp.where(accept, lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3), lam * nu)
        nu2 = jnp.where(accept, 2.0, 2.0 * nu).astype(dtype)
        rel = accept & (actual <= rtol * jnp.maximum(f, jnp.finfo(dtype).tiny))
        small = jnp.max(jnp.abs(step) / (jnp.abs(y) + 1.0)) < 1e-9
        done = rel | small | (lam2 > 1e12) | (f2 <= 0)
        return y2, f2, jtj, jtr, lam2, nu2, k + 1, done, accept

    s0 = (y0, jnp.asarray(jnp.inf, dtype), jnp.zeros((P, P), dtype), jnp.zeros(P, dtype), jnp.asarray(1e-3, dtype),
          jnp.asarray(2.0, dtype), jnp.asarray(0, jnp.int32), jnp.asarray(False), jnp.asarray(True))
    s = jax.lax.while_loop(cond, body, s0)
    return s[0], s[1], s[6], s[2]


_solve = jax.jit(_lm, static_argnames=("st", "max_steps", "rtol"))
_residuals = jax.jit(all_residuals, static_argnames=("st",))


def _align_scale(y, d: Data, st: Static):
    """``y`` with the fitted common scale (exposure, else the colours) set so that the
    model's sea median matches the images' (mean over channels of the log ratio); the
    model is read back from its residual, ``s expm1(r + c(image))``."""
    lay, _ = layout(st)
    if not st.fit_exposure and not (st.colors and not st.gauge):
        return y
    r = _residuals(y, d, st)
    model = d.scale * jnp.expm1(r + d.target)
    log_ratio = float(jnp.mean(jnp.log(d.scale) - jnp.log(_sea_median(model, d.used))))
    if not math.isfinite(log_ratio):
        return y
    return y.at[lay["exposure"] if st.fit_exposure else lay["colors"]].add(log_ratio)


# --------------------------------------------------------------------------- statistics


def estimate_noise(images, mask=None, sea_scale=None):
    """Noise standard deviation of ``images`` ``(T, H, W[, 3])`` in the comparison space
    ``log1p(I / s)`` (module docstring, *Noise*): Immerkaer's operator over the pixels
    whose 3x3 neighbourhood is in ``mask`` (default all). ``sea_scale`` ``(C,)``: ``s``
    (default the per-channel median over ``mask``). NaN when no neighbourhood is usable."""
    images = jnp.asarray(images)
    if images.ndim == 3:
        images = images[..., None]
    if images.ndim != 4:
        raise ValueError(f"images must be (T, H, W) or (T, H, W, 3); got {images.shape}")
    used = jnp.ones(images.shape[:3], images.dtype) if mask is None else jnp.asarray(mask).astype(images.dtype)
    if used.shape != images.shape[:3]:
        raise ValueError(f"mask must be {images.shape[:3]}; got {used.shape}")
    if sea_scale is None:
        sea_scale = _sea_median(images, used)
    return noise_estimate(compress(images, jnp.asarray(sea_scale, images.dtype)), used)


def _sea_median(images, used):
    T, H, W, C = images.shape
    return sea_median(images.reshape(T * H, W, C), used.reshape(T * H, W) > 0)


# --------------------------------------------------------------------------- validation


def _check_fit(fit) -> tuple:
    if isinstance(fit, str):
        fit = (fit,)
    fit = tuple(fit)
    unknown = [f for f in fit if f not in PHOTOMETRIC_FIELDS]
    if unknown or not fit:
        raise ValueError(f"fit= must be a non-empty subset of {PHOTOMETRIC_FIELDS}; got {fit!r}")
    return tuple(f for f in PHOTOMETRIC_FIELDS if f in fit)


def _check_images(images, camera, times, mask):
    """``(images (T, H, W, C), gray, times (T,), mask (T, H, W) bool or None)``, checked."""
    cam.validate_camera(camera)
    images = fit_dtype(images, "images are")
    H, W = camera.resolution
    if images.ndim == 4 and images.shape[-1] == 3:
        gray = False
    elif images.ndim == 3:
        gray = True
        images = images[..., None]
    else:
        raise ValueError(f"images must be (T, H, W, 3) linear RGB or (T, H, W) gray; got shape {images.shape}")
    T = images.shape[0]
    if images.shape[1:3] != (H, W):
        raise ValueError(f"images are {images.shape[1:3]} (H, W) but the camera's resolution is {(H, W)}")
    times = jnp.asarray(times, images.dtype)
    if times.shape != (T,):
        raise ValueError(f"times must be (T,) = ({T},), one per frame; got shape {times.shape}")
    if T < 1:
        raise ValueError("images hold no frame")
    if is_concrete(times):
        tt = np.asarray(times)
        if not np.all(np.isfinite(tt)):
            raise ValueError("times must be finite")
        if T > 1 and not np.all(np.diff(tt) > 0):
            raise ValueError(f"times must be strictly increasing; got {tt.tolist()}")
    if mask is not None:
        mask = jnp.asarray(mask)
        if mask.shape != (T, H, W):
            raise ValueError(f"mask must be (T, H, W) = {(T, H, W)}; got {mask.shape}")
        if mask.dtype != jnp.bool_:
            raise ValueError(f"mask must be bool; got {mask.dtype}")
    return images, gray, times, mask


def _used_pixels(images, camera, mask, sky: bool):
    """``(T, H, W)`` float: mask and finite and (sea unless ``sky``)."""
    used = jnp.all(jnp.isfinite(images), axis=-1)
    if mask is not None:
        used = used & mask
    if not sky:
        used = used & cam.intersect_sea(camera).mask[None]
    return used.astype(images.dtype)


# --------------------------------------------------------------------------- public API


def photometric(images, camera, times, waves: Waves, lighting: Lighting, *, fit=PHOTOMETRIC_FIELDS, mask=None,
                robust: str | None = "cauchy", horizon_gradient=0.0, overcast: bool = False, noise: float | None = None,
                max_steps: int = 20, rounds: int = 4, rtol: float | None = None, exposure: float = 1.0,
                per_frame_exposure: bool = False, sky: bool = False, refine: int = 0, progress: bool = False,
                throw: bool = False) -> PhotometricFit:
    """Refine ``waves``, ``lighting`` and the exposure against an image sequence.

    Args:
        images: ``(T, H, W, 3)`` linear RGB or ``(T, H, W)`` gray (luminance of the RGB
            model); its dtype (float32 / float64) is the fit's.
        camera: the frames' :class:`~jaxocean.camera.Camera` (resolution ``(H, W)``).
        times: ``(T,)`` frame times [s], strictly increasing.
        waves: start :class:`~jaxocean.waves.Waves` ``(N,)``; lighting: start :class:`Lighting`.
        fit: the parts fitted, a subset of :data:`PHOTOMETRIC_FIELDS` (the exposure gauge:
            module docstring).
        mask: ``(T, H, W)`` bool usable pixels (default all); only sea pixels are used
            unless ``sky=True``, and only finite ones (a NaN pixel is left out; a frame
            with no usable pixel is an error).
        robust: ``"cauchy"`` (default), ``"huber"``, ``"tukey"`` or None (least squares).
        horizon_gradient: the sky model's, as in :func:`jaxocean.render.render`.
        overcast: no sun term: the sun colour is fixed at 0 and the sun is not fitted.
        noise: the noise standard deviation in the comparison space ``log1p(I / s)`` (about
            the relative radiance noise near the sea's level), for the success test; None:
            estimated from the images (module docstring, *Noise*).
        max_steps: Levenberg-Marquardt steps per IRLS round; rounds: IRLS rounds (1 with
            ``robust=None``). rtol: relative loss decrease that ends a round (default 1e-6
            in float32, 1e-9 in float64).
        exposure: the start exposure (and the exposure used when it is not fitted).
        per_frame_exposure: fit one exposure per frame (cameras on automatic exposure)
            instead of one for the sequence; needs ``"exposure"`` in ``fit``.
        refine: 0 (default) the render's rows path; > 0 the hits path with at most that
            many hit iterations (slower; for waves tall enough to move a hit by a footprint).
        progress: print each round (scale, loss, steps, seconds).
        throw: raise :class:`jaxocean.fit.solvers.FitError` (carrying the result) when the
            fit does not explain the data.

    Returns:
        :class:`PhotometricFit`.
    """
    t_start = time.perf_counter()
    fit = _check_fit(fit)
    if robust is not None and robust not in ROBUST_LOSSES:
        raise ValueError(f"robust must be one of {tuple(ROBUST_LOSSES)} or None; got {robust!r}")
    images, gray, times, mask = _check_images(images, camera, times, mask)
    dtype = images.dtype
    validate(waves, max_steepness=None)
    if waves.omega.ndim != 1:
        raise ValueError(f"waves must have leaves (N,); got {waves.omega.shape}")
    shading.validate_lighting(lighting)
    shading.check_horizon_gradient(horizon_gradient)
    if noise is not None:
        check_nonnegative_number(noise, "noise must be a finite number >= 0 (or None)")
    if not (isinstance(max_steps, (int, np.integer)) and max_steps >= 1 and isinstance(rounds, (int, np.integer))
            and rounds >= 1):
        raise ValueError(f"max_steps and rounds must be positive ints; got {max_steps!r}, {rounds!r}")
    if not (math.isfinite(exposure) and exposure > 0):
        raise ValueError(f"exposure must be a finite number > 0; got {exposure!r}")
    if not (isinstance(refine, (int, np.integer)) and refine >= 0):
        raise ValueError(f"refine must be an int >= 0; got {refine!r}")
    if per_frame_exposure and "exposure" not in fit:
        raise ValueError("per_frame_exposure=True fits the exposure: include 'exposure' in fit")
    require_eager("fit.photometric", "a host loop over IRLS rounds", images, times, waves, lighting, camera)

    used = _used_pixels(images, camera, mask, sky)
    img = np.asarray(images)
    if np.any(np.asarray(used)[..., None] * (img < 0) > 0):
        raise InvalidValueError("images hold negative radiance on used pixels (linear radiance is >= 0)")
    if float(jnp.sum(used)) == 0:
        raise InvalidValueError("no usable sea pixel: the mask excludes every pixel the camera sees of the sea")
    empty = np.flatnonzero(np.asarray(jnp.sum(used, axis=(1, 2))) == 0)
    if empty.size:  # such a frame would drop out of the fit without a word
        raise InvalidValueError(f"frame(s) {empty.tolist()} hold no usable sea pixel (all masked or non-finite): "
                                "leave them out of images and times")
    images = jnp.where(used[..., None] > 0, images, 0.0)

    waves = Waves(*[jnp.asarray(x, dtype) for x in waves])
    lighting = Lighting(*[jnp.asarray(x, dtype) for x in lighting])
    colors0 = jnp.stack([lighting.sun_color, lighting.sky_color, lighting.sea_color])
    if overcast:
        colors0 = colors0.at[0].set(0.0)
    fit_lighting = "lighting" in fit
    colors = (("sky_color", "sea_color") if overcast else COLOR_NAMES) if fit_lighting else ()
    if colors:
        floor = 1e-4 * jnp.max(colors0)
        if not float(floor) > 0:
            raise InvalidValueError("the start lighting has every colour at 0: nothing to scale from")
        rows = [COLOR_NAMES.index(n) for n in colors]
        colors0 = colors0.at[jnp.asarray(rows)].set(jnp.maximum(colors0[jnp.asarray(rows)], floor))
    fit_exposure = "exposure" in fit
    gauge = bool(colors) and fit_exposure
    k = len(colors) * (1 if gray else 3)
    if gauge:
        u, _, _ = np.linalg.svd(np.eye(k) - 1.0 / k)
        basis = jnp.asarray(u[:, :k - 1], dtype)
    else:
        basis = jnp.eye(max(k, 1), dtype=dtype)
    n = int(waves.omega.shape[0])
    if rtol is None:
        rtol = 1e-9 if dtype == jnp.float64 else 1e-6
    st = Static(n_waves=n, fit_waves="waves" in fit, fit_sun=fit_lighting and not overcast, colors=colors,
                 gray=gray, fit_exposure=fit_exposure, n_exposure=int(times.shape[0]) if per_frame_exposure else 1,
                 gauge=gauge, plan=render.full_plan(n, int(refine)))

    scale = _sea_median(images, used)
    target = compress(images, scale)
    d = Data(target=target, used=used, times=times, camera=camera, scale=scale,
              hg=jnp.asarray(horizon_gradient, dtype), waves0=pack(waves).astype(dtype),
              pq0=sun_to_pq(lighting.sun_azimuth, lighting.sun_elevation).astype(dtype), colors0=colors0,
              log_exposure0=jnp.asarray(math.log(exposure), dtype), basis=basis)

    code = jnp.asarray(CODES.index(robust), jnp.int32)
    estimated = noise is None
    noise_val = noise_estimate(target, used) if estimated else jnp.asarray(noise, dtype)
    floor = jnp.where(jnp.isfinite(noise_val), noise_val, 0.0)
    y_init = pack_params(d, st)
    y = _align_scale(y_init, d, st)
    steps, prev = 0, math.inf
    for rnd in range(1 if robust is None else int(rounds)):
        t0 = time.perf_counter()
        sc, w = irls_weights(_residuals(y, d, st), used, code, floor)
        y, f, n_steps, jtj = _solve(y, w, d, st, int(max_steps), float(rtol))
        steps += int(n_steps)
        sc = float(sc)
        if progress:
            print(f"photometric round {rnd + 1}: scale {sc:.4g}, weighted loss {float(f):.4g}, "
                  f"{int(n_steps)} steps, {time.perf_counter() - t0:.2f} s", flush=True)
        if int(n_steps) <= 1 and abs(sc - prev) <= 0.01 * sc:
            break
        prev = sc
    w, outliers, loss, loss_init, rscale, frac, residual = robust_statistics(_residuals(y, d, st), _residuals(y_init, d, st),
                                                                   used, code, floor)
    waves_fit, light_fit, exp_fit = unpack(y, d, st)
    signal = signal_scale(target, used)
    sigma = max(float(noise_val) if math.isfinite(float(noise_val)) else 0.0, float(rscale), NOISE_FLOOR)
    if st.fit_waves:
        determined, energy = _determined_waves(y, jtj, sigma, used, target.shape[-1], n, camera,
                                               np.asarray(times))
    else:
        determined, energy = None, 1.0
    message = _verdict(float(loss), float(loss_init), float(residual), float(noise_val), float(frac), float(signal),
                       estimated, energy)
    result = PhotometricFit(waves=waves_fit, lighting=light_fit, exposure=exp_fit, outliers=outliers, weights=w,
                            loss_init=loss_init, loss=loss, robust_scale=rscale, noise=noise_val,
                            outlier_fraction=frac, steps=steps, seconds=time.perf_counter() - t_start,
                            success=not message, message=message, signal_scale=signal, sea_scale=scale,
                            noise_estimated=estimated, determined=determined, determined_energy=energy,
                            residual_scale=residual)
    if throw and not result.success:
        raise FitError(f"photometric refinement does not explain the images: {message}", result)
    return result


def _verdict(loss, loss_init, rscale, noise, frac, signal, estimated, energy) -> str:
    """Empty when every success criterion holds, else why not (module docstring). ``rscale``
    is the residual's trimmed scale (``residual_scale``), not the IRLS scale floored at the
    noise: a noise estimate that wave texture inflates would hide any residual below it."""
    reasons = []
    if not math.isfinite(loss):
        reasons.append(f"the loss is not finite ({loss})")
    elif not loss <= loss_init:
        reasons.append(f"the loss rose from the start ({loss_init:.4g} -> {loss:.4g})")
    source = "estimated from the images" if estimated else "given"
    level = max(noise, NOISE_FLOOR)
    if not math.isfinite(noise):
        reasons.append("the noise could not be estimated (no used 3x3 sea neighbourhood): pass noise=")
    elif not rscale <= SCALE_FACTOR * level:
        reasons.append(f"residual scale {rscale:.3g} exceeds {SCALE_FACTOR} x the noise {level:.3g} ({source})")
    if not frac <= MAX_OUTLIER_FRACTION:
        reasons.append(f"outliers are {frac:.1%} of the used pixels, above {MAX_OUTLIER_FRACTION:.0%}: the model "
                       "cannot produce much of the image (whitecaps, spray, objects, a wrong start?)")
    if math.isfinite(noise):
        if not signal > 0:
            reasons.append("the images hold no structure: their spread about each row's median is 0 (rows of one "
                           "value, e.g. a calm sea quantised to a few display codes)")
        elif not signal >= STRUCTURE_RATIO * level:
            reasons.append(f"the images hold no structure above the noise: their spread {signal:.3g} is below "
                           f"{STRUCTURE_RATIO} x the noise {level:.3g} ({source})")
        else:
            excess_signal = math.sqrt(signal ** 2 - level ** 2)
            excess_residual = math.sqrt(max(rscale ** 2 - level ** 2, 0.0))
            if not excess_residual <= EXPLAINED_RATIO * excess_signal:
                reasons.append(f"the waves explain too little of the images: the residual's spread above the noise "
                               f"{excess_residual:.3g} is above {EXPLAINED_RATIO} x the images' {excess_signal:.3g}")
    if not energy >= DETERMINED_ENERGY:
        reasons.append(f"the images do not determine the waves: the determined waves hold {energy:.0%} of the fitted "
                       f"slope energy, below {DETERMINED_ENERGY:.0%} (noise, too many waves, or waves the view "
                       "cannot separate)")
    return "; ".join(reasons)


def _determined_waves(y, jtj, sigma, used, channels, n, camera, times):
    """``(determined (N,) NumPy bool, energy float)``: the waves :func:`_pinned_down` by the
    data that the view also resolves (:func:`jaxocean.fit.waves.resolvable`: a wave longer
    than the sea the view shows along its direction, or shorter than its pixels, stands in
    for a tilt or a texture whatever its local standard deviations say) and that the frames
    ``times (T,)`` separate from their reverse twins (:func:`jaxocean.fit.waves.alias_separation`:
    the twin is another minimum, which no local covariance sees), and their share of the
    slope energy ``sum (k h)^2``."""
    w = to_waves(y[:4 * n], n)
    ok = np.asarray(_pinned_down(y, jtj, jnp.asarray(sigma, y.dtype), used, channels, n)) & resolvable(w, camera)
    ok = ok & (alias_separation(w, times) >= 1.0)
    slope_energy = np.asarray(w.amplitude * w.omega ** 2, np.float64) ** 2
    return ok, float(np.sum(slope_energy[ok]) / max(float(np.sum(slope_energy)), 1e-30))


@functools.partial(jax.jit, static_argnames=("channels", "n"))
def _pinned_down(y, jtj, sigma, used, channels, n):
    """``(N,)`` bool: the waves whose Gauss-Newton standard deviations at noise ``sigma`` (per
    residual element) are below :data:`DETERMINED_STD` (relative amplitude
    ``sqrt((var a + var b) / 2) / h``, ``log omega``, ``theta`` [rad])."""
    norm = 1.0 / jnp.maximum(channels * jnp.sum(used), 1.0)  # the normal equations' normalisation
    sd = parameter_std(jtj, sigma * sigma * norm)[:4 * n].reshape(4, n)
    w = to_waves(y[:4 * n], n)
    rel_h = jnp.sqrt(0.5 * (sd[0] ** 2 + sd[1] ** 2)) / jnp.maximum(w.amplitude, 1e-30)
    return (rel_h < DETERMINED_STD["amplitude"]) & (sd[2] < DETERMINED_STD["log_omega"]) & (
        sd[3] < DETERMINED_STD["theta"])


def residual(images, camera, times, waves: Waves, lighting: Lighting, exposure=1.0, *, mask=None,
             horizon_gradient=0.0, sea_scale=None, sky: bool = False, refine: int = 0):
    """The comparison-space residual ``c(exposure * render) - c(image)`` ``(T, H, W, C)``
    of :func:`photometric` (``C = 3``, or 1 for gray images), 0 on unused pixels;
    ``exposure`` ``()`` or one per frame ``(T,)``.

    ``sea_scale`` ``(C,)``: the ``s`` of ``c(I) = log1p(I / s)`` (default the images'
    per-channel sea median over the used pixels). Jittable and differentiable in every
    array argument (validation of values only when concrete)."""
    images, gray, times, mask = _check_images(images, camera, times, mask)
    validate(waves, max_steepness=None)
    shading.validate_lighting(lighting)
    if jnp.ndim(exposure) not in (0, 1) or (jnp.ndim(exposure) == 1 and jnp.shape(exposure) != times.shape):
        raise ValueError(f"exposure must be a scalar or one per frame {times.shape}; got shape {jnp.shape(exposure)}")
    dtype = images.dtype
    used = _used_pixels(images, camera, mask, sky)
    images = jnp.where(used[..., None] > 0, images, 0.0)
    scale = _sea_median(images, used) if sea_scale is None else jnp.asarray(sea_scale, dtype)
    model = model_frames(waves, lighting, jnp.asarray(exposure, dtype), camera, times,
                          jnp.asarray(horizon_gradient, dtype), gray, render.full_plan(waves.omega.shape[0], refine))
    return used[..., None] * (compress(model, scale) - compress(images, scale))


def rerender(result: PhotometricFit, camera, times, *, horizon_gradient=0.0, gray: bool = False, refine: int = 0):
    """The fitted model's frames ``exposure * render(waves, camera, lighting, t)``: ``(T, H,
    W, 3)`` linear RGB, or ``(T, H, W)`` luminance with ``gray=True``. Any camera and times
    (new views, forecasts); with the fit's own they are what the fit compared. Per-frame
    exposures apply frame by frame when ``times`` has as many frames, else their geometric
    mean."""
    times = jnp.atleast_1d(jnp.asarray(times, result.waves.omega.dtype))
    cam.validate_camera(camera)
    exposure = jnp.asarray(result.exposure)
    if exposure.ndim and exposure.shape != times.shape:
        exposure = jnp.asarray(mean_exposure(result), times.dtype)
    out = model_frames(result.waves, result.lighting, exposure, camera, times,
                        jnp.asarray(horizon_gradient, times.dtype), gray,
                        render.full_plan(result.waves.omega.shape[0], refine))
    return out[..., 0] if gray else out


def mean_exposure(result: PhotometricFit) -> float:
    """The fit's exposure as one number: itself, or the geometric mean of per-frame ones
    (for frames and times the fit did not see)."""
    return float(np.exp(np.mean(np.log(np.asarray(result.exposure, np.float64)))))


def fit_to_dict(result: PhotometricFit) -> dict:
    """A JSON-safe summary of a :class:`PhotometricFit` (no per-pixel arrays): waves as
    lists, the lighting (:func:`jaxocean.fit.lighting.lighting_to_dict`), exposure, losses,
    scales, noise (and whether it was estimated), outlier fraction, steps, seconds,
    success and message, and the success thresholds."""
    def f(x):
        x = float(x)
        return x if math.isfinite(x) else None

    w = result.waves
    return {
        "waves": {name: [float(v) for v in np.asarray(getattr(w, name))] for name in Waves._fields},
        "n_waves": int(np.asarray(w.omega).shape[0]),
        "lighting": lighting_to_dict(result.lighting),
        "exposure": (f(result.exposure) if np.ndim(result.exposure) == 0
                     else [f(e) for e in np.asarray(result.exposure)]),
        "loss_init": f(result.loss_init),
        "loss": f(result.loss),
        "robust_scale": f(result.robust_scale),
        "residual_scale": None if result.residual_scale is None else f(result.residual_scale),
        "noise": f(result.noise),
        "noise_estimated": bool(result.noise_estimated),
        "determined": None if result.determined is None else [bool(v) for v in np.asarray(result.determined)],
        "determined_energy": f(result.determined_energy),
        "signal_scale": None if result.signal_scale is None else f(result.signal_scale),
        "outlier_fraction": f(result.outlier_fraction),
        "steps": int(result.steps),
        "seconds": float(result.seconds),
        "success": bool(result.success),
        "message": str(result.message),
        "criteria": {"scale_factor": SCALE_FACTOR, "noise_floor": NOISE_FLOOR,
                     "max_outlier_fraction": MAX_OUTLIER_FRACTION, "explained_ratio": EXPLAINED_RATIO,
                     "structure_ratio": STRUCTURE_RATIO, "determined_std": DETERMINED_STD,
                     "determined_energy": DETERMINED_ENERGY,
                     "outlier_weight": OUTLIER_WEIGHT},
    }
