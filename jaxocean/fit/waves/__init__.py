"""Wave fitting: the component waves ``{h, omega, theta, phi}`` behind a sequence of geometry.

Protocol
--------
Inputs describe one scene (map batches of scenes with ``jax.vmap`` through :func:`refine`):

* ``normals``   ``(T, H, W, 3)`` unit normals of the normal-level waves, as
  :func:`jaxocean.render.geometry` returns them (world frame, z up);
* ``roughness`` ``(T, H, W)`` slope variance sigma^2 of the sub-pixel waves (or None);
* ``camera``    the :class:`jaxocean.camera.Camera` the geometry was seen with
  (``camera.resolution == (H, W)``);
* ``times``     ``(T,)`` frame times [s], strictly increasing, ``T >= 2``.

The model is the renderer's own: :func:`jaxocean.render.geometry` with every wave
evaluated, so a fitted wave that is partly sub-pixel is modelled exactly as it was
rendered. ``surface=`` picks the path: ``"rows"`` (the geometry at each pixel's
mean-sea-plane hit, Nyquist weights per image row: GEMM speed), ``"hits"`` (at the pixel's
converged hit on the displaced surface: what a camera sees and ``render`` draws when the
waves move the hits) or ``"auto"`` (:func:`waves`' default: the rows path until the model
moves the hits by ``render``'s rule, then the hits path). Sky pixels, pixels whose normal
is not finite or faces down, and on the hits path pixels whose model hit does not converge
carry no weight (set pixels whose observed hit did not converge to NaN).

Loss (the paper's eq. 5-7)::

    loss = mean_pixels (1 - n . n_hat) + roughness_weight * mean_pixels (rho - rho_hat)^2

and its least-squares form ``0.5 |r|^2`` with ``r = (n - n_hat)_xy / sqrt(P)`` per pixel
(``P`` valid pixel-frames; ``|dn|^2 = 2 (1 - cos)`` and the z part is of fourth order in
the slope) plus ``sqrt(2 w / P) (rho - rho_hat)`` per pixel for the roughness.

Pipeline of :func:`waves`:

1. **Spectral estimate** (:func:`spectral_estimate`): the slope field
   ``s = (-n_x/n_z, -n_y/n_z)`` is resampled onto ground grids (a pyramid of scales, each
   a ``G x G`` square anchored at the nearest sea pixel and spaced by a multiple of its
   footprint; for the orthographic camera the pixel grid itself), Fourier transformed in
   space and projected in time onto the dispersion shell ``omega^2 = g k``:
   ``P(K) = |sum_t e^{-i omega(K) t} K_hat . F_t(K)|^2``. A wave travelling along ``K``
   lights up one bin (the opposite direction stays dark), so local maxima of ``P`` give
   frequencies, directions and -- through the linear solve -- phases.
   :func:`spectral_peaks` pools the strongest distinct maxima of every scale with their
   power and the sub-bin vertex of a parabola through their neighbours' log power (the
   wave network's anchors); :func:`spectral_init` solves their amplitudes.
2. **Linear amplitudes and phases** (:func:`solve_amplitudes`): to first order in the
   steepness the slope field is ``sum_i w_i k_i k_hat_i (a_i sin psi0_i + b_i cos psi0_i)``
   with ``psi0 = omega t - k.X``, linear in ``(a, b) = h (cos phi, sin phi)`` once
   ``(omega, theta)`` are known (docs/design.md, Inverse methods).
3. **Greedy detection with order selection**: candidates from the spectral estimate of the
   current residual plus a polar grid of waves longer than the largest ground grid are
   scored on a spread subsample of pixel-frames by the energy a single wave removes,
   refined in ``(a, b, omega, theta)`` by a single-wave Levenberg-Marquardt, solved jointly
   for ``(a, b)`` (sidelobes and repeats lose their energy there), added in batches, and
   the whole set is refined by the structured Levenberg-Marquardt below (without the
   roughness term: the observed roughness holds waves the model does not have yet). The
   part of the sea the view cannot separate into waves -- waves longer than the view -- is
   modelled by a long-wave band (:mod:`jaxocean.fit.waves._band`: nuisance waves of fixed
   wave vector, 6 wavelengths x 12 directions by default, only their amplitudes and phases
   fitted, jointly with the waves), and a candidate becomes a wave only if the image
   resolves it and it stands at least ``separation`` Rayleigh limits
   (:func:`rayleigh_separation`) from every model wave. A
   batch is kept while it lowers the information criterion (``"bic"``:
   ``M ln(RSS/M) + 4 N ln M``; ``"aic"``: ``+ 8 N``; with a known ``noise`` sigma,
   ``RSS / sigma^2 + 4 N ln M``; the RSS is floored at ``M noise_floor^2``, by default the
   noise whose mean normal angle is the success bound of noise-free data). The selection
   stops once the model explains the data to that floor; within ``POLISH_FACTOR`` (10) of
   it, an accepted model whose trial ran out of steps is refined 4x longer before more
   waves are tried, so that the trials' missing steps are not taken for missing waves. A
   model stalled more than ``POLISH_FACTOR`` above the floor with no admissible candidate
   may add candidates the view does not resolve or that stand ``CROWDED_SEPARATION`` (0.5)
   x ``separation`` from its waves. Where none of the strongest candidates is resolvable (a
   swell longer than the view fills the residual's spectrum) while the residual is more
   than ``POOL_FACTOR`` (100) above the noise, half of the candidates are the strongest
   resolvable ones. On the hits path the residual is resampled for
   detection at the model's rest positions (grid point ``X`` of frame ``t`` read at the
   pixel that sees the model's surface point ``p(X, t)``), where waves riding on the
   model's longer waves are plane waves.
   Optionally the final set is pruned by each wave's Wald statistic against the same penalty. The final
   refinement adds the roughness term with the sub-pixel tail of waves outside the set
   fitted by non-negative least squares.
4. **Refinement** (:func:`refine`): every parameter at once. The default solver
   ``"structured"`` is a Levenberg-Marquardt (Nielsen damping, Marquardt scaling), projected
   onto the waves that exist (a step or start that would make a wave steeper than ``k h =
   1``, a looping trochoid crest, stops at that limit), whose
   normal equations ``J^T J`` are accumulated frame by frame and row block by row block
   from a hand-written per-wave Jacobian (a wave's parameters touch only its own sines,
   so ``J`` is built in ``O(pixels x waves)`` and reduced by one matrix product; on the
   hits path it adds the motion of the hit, ``dX/dp = (I - dF/dX)^-1 dF/dp``); trial
   losses and the gradient go through ``render.geometry``. Any name of :mod:`jaxocean.fit.solvers` is
   also accepted (``"lm"``, ``"gauss_newton"``, ``"dogleg"``, ``"bfgs"``, ``"lbfgsb"``,
   ``"adam"``, ``"scipy"``); they see the same residual but materialise the dense
   Jacobian, which is 20-40x slower at 128^2 x 10 frames x 60 waves.

Parameters inside the solvers are ``(a, b, log omega, theta)`` per wave: no singularity
at ``h = 0`` and ``omega > 0`` by construction.

Wave uncertainty (:class:`WaveFit` ``uncertainty``) is the Gauss-Newton covariance
``sigma^2 (J^T J)^-1`` with ``sigma^2 = max(RSS / (M - 4N), noise^2)`` (``noise`` the stated
noise, else the floor: the variance at which the refinement judges its steps, so a fit of
noise-free data does not report the tiny spread of its residual), mapped to ``(h, omega,
theta, phi)``: cheap (the solver has ``J^T J``) and meaningful when the residual is noise.
:func:`refine` has no noise and uses the residual's variance alone.

Noise correlated across the image (``noise_correlation=``, :func:`noise_cells`): a
network's normal errors are smooth, and taken as independent pixels they pay the criterion's
penalty over many pixels and become waves. Each wave is then scored at the noise in its own
band of the spectrum: ``c`` pixels per independent observation, the power of errors
correlated as ``exp(-d / l)`` at the wave's wavenumber in pixels relative to white noise.

Resolvability (:func:`resolvable`): a wave is individually recoverable when the image
resolves it somewhere (``lambda >= n_max x`` the smallest footprint) and at least
``cycles`` of its wavelengths fit into the part of the sea where it is resolved, measured
along its direction of travel. Longer waves are seen only as a smooth tilt field: the fit
explains them with some long waves, not with the true ones (``experiments/WAVES.md``).

Forecasting a fit (:func:`forecast_model`): the fitted waves with the long-wave band, and a
frequency uncertainty per component -- the fit's own for determined waves, the window's
Rayleigh cell (:func:`frequency_cell`) for the stand-ins -- for the least-squares forecast
of :func:`jaxocean.forecast.forecast` (``window=``, ``frequency_sigma=``), drawn on the fit's
own surface path (:func:`forecast_plan`, ``plan=``).
"""

from jaxocean.fit.waves._band import LongWaveBand
from jaxocean.fit.waves._inputs import UNIT_NORMAL_TOLERANCE, check_inputs
from jaxocean.fit.waves._lm import (NOISE_FACTOR, NORMAL_ERROR_FLOOR, SOLVER_NAMES, WaveFit, normal_error_bound,
                                    refine)
from jaxocean.fit.waves._match import (WaveMatch, alias_separation, forecast_model, forecast_plan, frequency_cell,
                                       match, noise_cells, rayleigh_separation, resolvable, separable)
from jaxocean.fit.waves._model import loss, predict
from jaxocean.fit.waves._select import HEIGHT_TRENDS, NoWaveFound, OrderSelection, waves
from jaxocean.fit.waves._spectral import (SpectralEstimate, SpectralPeaks, solve_amplitudes, spectral_estimate,
                                         spectral_init, spectral_peaks)

__all__ = [
    "WaveFit",
    "SpectralEstimate",
    "OrderSelection",
    "NoWaveFound",
    "WaveMatch",
    "LongWaveBand",
    "SOLVER_NAMES",
    "HEIGHT_TRENDS",
    "NOISE_FACTOR",
    "NORMAL_ERROR_FLOOR",
    "UNIT_NORMAL_TOLERANCE",
    "normal_error_bound",
    "waves",
    "refine",
    "spectral_estimate",
    "spectral_init",
    "spectral_peaks",
    "SpectralPeaks",
    "solve_amplitudes",
    "loss",
    "predict",
    "resolvable",
    "separable",
    "rayleigh_separation",
    "alias_separation",
    "match",
    "frequency_cell",
    "noise_cells",
    "forecast_model",
    "forecast_plan",
    "check_inputs",
]
