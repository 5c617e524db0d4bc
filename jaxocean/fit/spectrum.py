"""Sea-state fitting: the directional spectrum behind fitted waves and the roughness.

Protocol
--------
``spectrum(waves, *, camera=None, roughness=None, reliable=None, ...) -> SpectrumFit``
estimates a :class:`jaxocean.spectrum.Spectrum` ``(hs, tp, gamma, theta_mean, s_max)``
from component waves (usually :func:`jaxocean.fit.waves`' result) and, when given, the
observed roughness of the sub-pixel tail:

* **Frequency spectrum** (Hs, Tp, gamma). Waves drawn by
  :func:`jaxocean.spectrum.sample_waves` carry the energy of a frequency bin each
  (``h^2 / 2 = int_bin S``), one wave per bin. The reliable waves (default: those
  :func:`jaxocean.fit.waves.resolvable` by ``camera``, else all), sorted by frequency,
  get bins whose edges are the geometric midpoints between neighbours; the model's
  cumulative bin energies ``int_{e_0}^{e_i} S`` (Gauss-Legendre per bin) are matched to
  the data's cumulative ``sum_{j<=i} h_j^2/2``, relative to the total. The cumulative form
  is insensitive to where inside its bin each wave's frequency was jittered. For each
  ``(Tp, gamma)`` on a coarse grid ``Hs^2`` is solved in closed form (the energies are
  linear in it); the best grid point starts a least-squares fit in ``(log Hs, log Tp,
  z)`` with ``gamma = 1 + z^2`` (``solver``, default the registry's ``"lm"``; a bounded
  solver such as ``"lbfgsb"`` fits ``gamma`` in ``[1, 10]`` directly -- measured on 60
  waves drawn from one JONSWAP spectrum: the same optimum as ``"lm"`` to float32 rounding,
  in 21 steps against 12). The fit runs in float64 whatever JAX's default precision.
* **Roughness** (optional, needs ``camera``). Per image row, the observed roughness
  (frame and column mean) is compared with the model's sub-pixel slope variance,
  ``sum_fitted (1 - w_n) k^2 h^2 / 2`` plus ``int (1 - w_n(lambda/fp)) k^2 S dw`` over the
  tail above the fitted waves up to the band's end (``band``, default the sampler's
  ``(0.5, 8) x wp``). Rows at the renderer's floor carry no information and are skipped.
* **Directions** (theta_mean, s_max): maximum likelihood of the reliable waves'
  directions under the Mitsuyasu spreading ``D(theta; w_i)`` of their own frequency
  (each sampled wave is one draw), each wave's log-likelihood weighted by its energy
  ``h^2`` (normalised to mean 1), by a grid over ``theta_mean`` x ``s_max`` refined by a
  parabola in each. The weights depend on the wave's amplitude, not its direction, so the
  estimate stays consistent; they keep the many small waves a fit adds for what it cannot
  resolve (their directions are not draws from the spreading) from deciding the mean
  direction. Measured on four dataset scenes fitted by ``fit.waves``
  (``experiments/WAVES.md``): mean-direction errors 2-11 deg weighted, 18-52 deg unweighted.
  The weights leave ``n_eff = (sum h^2)^2 / sum h^4`` effective waves; with fewer than
  :data:`MIN_DIRECTION_WAVES` (3) the direction is not determined (NaN standard deviations,
  no success): one dominant wave's direction is not the sea's. The directions' second
  circular moment about the fitted mean is then held against the fitted spreading's
  (:func:`direction_misfit`): two wave systems from directions far apart put their energy
  on both sides of a mean between them, where a single spreading expects it, and fail.

Only the peak makes Hs and Tp separately identifiable: if the fitted waves stop above the
peak (the camera sees a patch shorter than the peak wavelength), the tail fixes only the
Phillips level ``alpha ~ Hs^2 wp^4``. ``SpectrumFit.peak_observed`` says whether the fitted
peak lies inside the band of reliable frequencies *and* the energies rule out every spectrum
whose peak lies at or beyond the band's edges: the best of those (a grid over Tp and gamma,
Hs in closed form) must leave more than ``misfit_bound``. A peak fitted just inside the
band's long-wave edge that a peak beyond it explains as well is not observed (measured on
the waves fitted to two dataset scenes from their slopes, whose true peak lay below the
band, ``experiments/WAVES.md``: the free fit put a peak just inside, Tp 18 and 27 standard
deviations off). The test sees the waves only: where a wave fit lost energy near the band's
edge, a peak inside can explain the waves better than any beyond (two default fits of the
same table: Tp 10 and 37 standard deviations off, with every wave's energy taken as
measured). Hence ``determined``: given the wave fit's mask of measured waves, a bin's
energy counts as measured only where its wave and both neighbours (whose frequencies set
its edges) are determined; the alternatives' misfit is then taken over the measured bins
alone (each other bin holds the alternative's own energy), from the measured bins' edges,
and the peak must lie between those edges. Fewer than :data:`MIN_WAVES` measured bins show
no peak. On Table 2's fits the determined waves sit in the tail, so their peaks are bounds
(``experiments/WAVES.md``). ``success`` says that one spectrum explains the waves, not
that the waves hold the sea's energy. Where a peak beyond the band explains the energies
as well as the one inside, the answer keeps the inside one, the shortest Tp and least Hs
that explain them (beyond the long-wave edge, longer periods and more energy below the
band do too): lower estimates (upper ones for the short-wave edge), not strict bounds --
where the stand-ins placed the peak right, the energies they carry can put Hs above the
sea's (Table 2 scene 7: 11%). When the fitted peak lies outside the band,
the fit drifts along
the ``alpha`` valley (measured on a dataset scene: Tp 137 s, Hs 510 m for a 5 s, 0.7 m
sea), so Hs and gamma are refitted with the peak pinned to the band's nearer edge: for a
peak below the band, Tp becomes the longest period the reliable waves cover and Hs the
level that matches the in-band energies there -- lower estimates when the true peak is
longer. ``alpha`` is the identifiable quantity: with the peak observed, the free fit's;
without, the level of the measured bins at or above :data:`TAIL_START` times the reported
peak frequency (which lies at or above the sea's when Tp is a lower bound), matched to the
tail ``alpha g^2 omega^-5`` by the ratio of their energies (the free fit's level moves with
its misplaced peak: on Table 2's default fits, errors -32% to +166% from the free fit,
-26% to +9% from the measured tail, ``experiments/WAVES.md``); with fewer than
:data:`MIN_WAVES` such bins the free fit's.

``correct_amplitudes(waves, spectrum, reliable=None)`` is the spectrum correction:
waves that the image cannot resolve individually (too long for the view, or flagged
unreliable) get the amplitude of their bin's energy under the fitted spectrum,
``h = sqrt(2 int_bin S)``, while resolved waves keep their fitted amplitudes. (Our
reading of the paper's spectrum correction, which rescales the network's wave amplitudes
to the spectrum; the paper gives no formula we could check.)
``tail_waves(key, spectrum, omega_from, n_waves)`` draws the sub-pixel tail from the
fitted spectrum, for re-rendering roughness.
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple, Optional

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, shading
from jaxocean import spectrum as spec
from jaxocean._roughness import normal_weight, observed_rows, row_roughness
from jaxocean.errors import InvalidValueError, check_values, require_eager
from jaxocean.waves import GRAVITY, Waves, validate

__all__ = ["SpectrumFit", "spectrum", "correct_amplitudes", "tail_waves", "sea_state", "SeaState", "NOISE_FACTOR",
           "ENERGY_FLOOR", "ROUGHNESS_FLOOR", "MIN_DIRECTION_WAVES", "DIRECTION_STD_BROADENING",
           "DIRECTION_Z_MAX", "S_MAX_GRID", "TAIL_START",
           "direction_misfit"]


class SpectrumFit(NamedTuple):
    """Result of :func:`spectrum`.

    * ``spectrum``       the fitted :class:`~jaxocean.spectrum.Spectrum`.
    * ``loss``           final value of the energy (and roughness) objective.
    * ``success``        the solver converged *and* the fitted spectrum explains the data:
      ``misfit <= misfit_bound`` and, with roughness, ``roughness_misfit <=
      roughness_bound`` (see :func:`spectrum`), and the waves' energies give at least
      :data:`MIN_DIRECTION_WAVES` effective waves for the direction fit, and their
      directions fit one spreading (``direction_misfit``, and ``s_max`` above the lower end of
      :data:`S_MAX_GRID`, the broadest spreading the fit allows). A converged fit of waves that no
      single JONSWAP / Mitsuyasu spectrum describes (two wave systems of different periods,
      or of one period from directions 2 rad or more apart) is reported failed.
    * ``steps``          solver steps.
    * ``n_waves``        number of waves the frequency and direction fits used.
    * ``omega_band``     ``(lo, hi)`` [rad/s] of the reliable waves' bins.
    * ``peak_observed``  the fitted spectrum explains the energies (``misfit <=
      misfit_bound``: no peak is observed by a spectrum that does not), its peak frequency
      lies inside ``omega_band`` (with ``determined``: inside the measured bins' band) and
      the measured energies rule out a peak at or beyond either edge: the best such
      spectrum's misfit (``edge_peak_misfit``) exceeds ``misfit_bound``. If not, Hs and Tp are bounds: a
      peak fitted outside the band is pinned to its nearer edge and Hs refitted; one inside
      is kept (module docstring).
    * ``edge_peak_misfit`` the least ``misfit`` of a spectrum whose peak lies at or beyond
      an edge of ``omega_band`` (over a grid of Tp up to 4 times past the
      edge (:data:`EDGE_REACH`) and of gamma, Hs in closed form); with ``determined``, of
      the measured bins and their band; NaN with fewer than :data:`MIN_WAVES` of them.
    * ``alpha``          Phillips tail level ``A(gamma) (5/16) Hs^2 wp^4 / g^2`` with
      ``A`` the JONSWAP normalisation (identifiable even when the peak is not observed:
      then the measured tail's level, module docstring).
    * ``time_s``         wall time.
    * ``misfit``         RMS of the cumulative-energy residual at the answer (a fraction of
      the reliable waves' total energy).
    * ``misfit_bound``   the largest ``misfit`` a right answer leaves for the stated noise.
    * ``roughness_misfit`` RMS relative roughness residual over the informative rows (NaN
      when no roughness was fitted); ``roughness_bound`` its bound.
    * ``hs_std``, ``tp_std`` [m, s], ``gamma_std``: 1-sigma of the fitted values from the
      scatter of the data about the answer (sandwich covariance of the least-squares fit,
      the per-bin energy errors independent: :func:`spectrum`); NaN for a value that was
      held (``tp_std`` when the peak is not observed and Tp is pinned: it is a bound;
      ``gamma_std`` when ``gamma`` was given).
    * ``theta_std`` [rad], ``s_max_std``: 1-sigma of the direction fit (sandwich covariance
      of the weighted maximum likelihood, times ``sqrt(n_eff / (n_eff - 2))`` for its
      ``n_eff`` effective waves; ``theta_std`` at the spreading two of ``s_max``'s standard
      deviations broader, :data:`DIRECTION_STD_BROADENING`); NaN where the likelihood has no
      interior maximum or the waves' energies give fewer than :data:`MIN_DIRECTION_WAVES`
      effective waves.
    * ``direction_misfit`` z-score of the directions' second circular moment against the
      fitted spreading's (:func:`direction_misfit`); ``success`` needs ``|z| <=``
      :data:`DIRECTION_Z_MAX`. NaN when the directions are not determined.
    """

    spectrum: spec.Spectrum
    loss: float
    success: bool
    steps: int
    n_waves: int
    omega_band: tuple
    peak_observed: bool
    alpha: float
    time_s: float
    misfit: float = float("nan")
    misfit_bound: float = float("nan")
    roughness_misfit: float = float("nan")
    roughness_bound: float = float("nan")
    hs_std: float = float("nan")
    tp_std: float = float("nan")
    gamma_std: float = float("nan")
    theta_std: float = float("nan")
    s_max_std: float = float("nan")
    direction_misfit: float = float("nan")
    edge_peak_misfit: float = float("nan")


class SeaState(NamedTuple):
    """Bulk parameters of a set of waves: ``hs = 4 sqrt(sum h^2/2)``, ``tp`` the period of
    the most energetic wave per log-frequency, ``theta_mean`` the energy-weighted circular
    mean direction, ``m0`` the variance."""

    hs: float
    tp: float
    theta_mean: float
    m0: float


_GL = np.polynomial.legendre.leggauss(8)

#: what the eager functions of this module do on the host (their error under jit says it)
_EAGER = "NumPy, data-dependent selections"

#: how far past an edge of the band (a factor on its period) the alternative peaks of the
#: ``peak_observed`` test reach: at 4x the band sees the spectrum's ``omega^-5`` tail alone
EDGE_REACH = np.geomspace(1.0, 4.0, 40)
#: the peak enhancements of those alternatives
EDGE_GAMMAS = (1.0, 1.5, 2.0, 3.3, 5.0, 7.0, 10.0)

#: the fewest reliable waves a spectrum is fitted to (peak, width and level need three)
MIN_WAVES = 3
#: where the peak is not observed, ``alpha`` is read from the measured bins at or above this
#: multiple of the peak frequency: there JONSWAP is within 8% of its ``omega^-5`` tail
#: (``exp(-5/64)``), and the peak enhancement has vanished
TAIL_START = 2.0
#: the smallest effective number of waves ``(sum h^2)^2 / sum h^4`` (the energy weights'
#: Kish size) that determines the mean direction and spreading: below it the direction's
#: standard deviations are NaN and ``success`` is False. Measured (360 seas drawn from
#: random JONSWAP / Mitsuyasu spectra, 3-40 waves, directions fitted back): with fewer than
#: 3 effective waves half the mean directions were more than 3 sigma off, however narrow the
#: sandwich said they were; from 3 to 4, 2% after the small-sample factor below
MIN_DIRECTION_WAVES = 3.0
#: ``theta_std`` is the sandwich's standard deviation of the mean direction at the spreading
#: this many standard deviations of ``log s_max`` broader than the fitted one: its value at
#: the fitted ``s_max`` times ``exp(DIRECTION_STD_BROADENING sigma_log_s / 2)`` (it scales as
#: ``s^-1/2``). A few waves that happen to
#: cluster look narrower than their spreading, and the sandwich at that spreading claims a
#: precision the sample does not have. Measured (2500 seas: 3-24 waves drawn from random
#: JONSWAP / Mitsuyasu spectra, ``s_max`` 2-80, directions fitted back with the true peak;
#: ``tests/test_fit_waves.py`` repeats a smaller draw): at the fitted ``s_max`` the errors'
#: RMS z-score was 2.37 / 1.80 / 1.46 / 1.46 for 3-4 / 4-5 / 5-7 / 7-12 effective waves,
#: 3.4-9.1% beyond 3 sigma (9.1% at 3-4 effective waves; 13.5% and 28% of the fits whose
#: ``s_max`` came out 2-4x and over 4x too large); with the rule 0.97 / 0.93 / 0.83 / 0.84,
#: 0.3-1.7% beyond 3 sigma
DIRECTION_STD_BROADENING = 2.0

#: success needs ``misfit <= sqrt(NOISE_FACTOR noise^2 + ENERGY_FLOOR^2)``. Measured (float32,
#: waves drawn by spectrum.sample_waves from random JONSWAP spectra and fitted back): 10-60
#: waves leave a cumulative-energy RMS of 0.004-0.019, their high-frequency tails alone
#: (peak pinned) 0.001-0.021, 60 waves with 10% amplitude noise 0.006-0.010; two superposed
#: wave systems 0.11-0.12, and the resolvable subset of a dataset scene whose gaps miss much
#: of the energy 0.15-0.20 (its Hs and Tp come out 13-15% low).
NOISE_FACTOR = 1.5
ENERGY_FLOOR = 0.04
#: success needs ``|direction_misfit| <= DIRECTION_Z_MAX``. Measured (waves drawn from 100
#: random JONSWAP / Mitsuyasu spectra, 12-60 waves, fitted back): |z| <= 1.14, RMS 0.45 (the
#: fitted spreading absorbs part of the scatter); two 30-wave systems of one Tp from
#: directions 2.0 and 3.0 rad apart: -2.2 and -3.9; 1.0 and 1.5 rad apart -0.2 and -1.1, which
#: one broad spreading describes about as well
DIRECTION_Z_MAX = 2.0
#: the ``s_max`` grid of the direction fit. A fit at its lower end wants a spreading broader
#: than ``cos^1`` of the half angle, nearly isotropic: no single spreading describes the
#: directions (measured: two 40-wave systems of one Tp from opposite directions ended there
#: on 5 of 12 draws, two of them passing the ``DIRECTION_Z_MAX`` test with a mean direction
#: at right angles to both), so ``success`` is refused there
S_MAX_GRID = (0.5, 150.0)
#: the same for the relative roughness residual of the rows, ``sqrt(NOISE_FACTOR
#: roughness_noise^2 + ROUGHNESS_FLOOR^2)``: the true waves of four dataset scenes with their
#: own roughness leave 0.00-0.08
ROUGHNESS_FLOOR = 0.2


def _bin_edges(omega):
    """Geometric-midpoint bin edges ``(n + 1,)`` of sorted frequencies ``(n,)``."""
    om = np.asarray(omega, np.float64)
    if om.size == 1:
        return np.array([om[0] / 1.05, om[0] * 1.05])
    mid = np.sqrt(om[1:] * om[:-1])
    first = om[0] ** 2 / mid[0]
    last = om[-1] ** 2 / mid[-1]
    return np.concatenate([[first], mid, [last]])


def _bin_energy(params, edges):
    """``int S`` over each bin ``[edges[i], edges[i+1]]`` for ``params = (log hs, log tp, gamma)``."""
    x, w = (jnp.asarray(v, edges.dtype) for v in _GL)
    a, b = edges[:-1, None], edges[1:, None]
    half = 0.5 * (b - a)
    nodes = a + half * (x + 1.0)
    sp = spec.Spectrum(hs=jnp.exp(params[0]), tp=jnp.exp(params[1]), gamma=params[2])
    dens = spec._jonswap_kernel(nodes, sp.hs, sp.tp, sp.gamma, 0.07, 0.09)
    return jnp.sum(half * w * dens, axis=-1)


def _tail_roughness(params, fp_row, omega_from, band_hi_rel, n_min, n_max, n=96):
    """``int_{omega_from}^{band_hi wp} (1 - w_n(lambda/fp)) k^2 S dw`` per row ``(H,)``."""
    tp = jnp.exp(params[1])
    wp = 2 * jnp.pi / tp
    hi = band_hi_rel * wp
    lo = jnp.minimum(omega_from, hi)
    t = (jnp.arange(n) + 0.5) / n
    om = lo * (hi / lo) ** t  # geometric midpoints
    dom = om * jnp.log(hi / lo) / n
    dens = spec._jonswap_kernel(om, jnp.exp(params[0]), tp, params[2], 0.07, 0.09)
    k = om * om / GRAVITY
    lam = 2 * jnp.pi / k
    w_r = 1.0 - normal_weight(lam, fp_row, n_min, n_max)
    return (w_r * (k * k * dens * dom)[None, :]).sum(-1)


#: residual blocks (bins, roughness rows) are padded to a multiple of this many entries, so
#: that fits of nearby sizes share one compiled solver (the padding's entries are zero)
_PAD = 16


def _padded(n: int) -> int:
    return -(-n // _PAD) * _PAD


class _Rough(NamedTuple):
    """The informative roughness rows :func:`spectrum` fits, ``(R,)`` each (padded to ``R``
    = a multiple of ``_PAD``), and the scalars of their residual."""

    footprint: jax.Array  # (R,) pixel footprint [m]
    observed: jax.Array  # (R,) observed slope variance
    fitted_share: jax.Array  # (R,) the fitted waves' sub-pixel share of it
    mask: jax.Array  # (R,) 1 for the rows, 0 for the padding
    scale: jax.Array  # () weight of the rows against the energies
    omega_from: jax.Array  # () where the tail above the fitted waves starts [rad/s]
    band_hi: jax.Array  # () the band's upper end, in units of wp


class _Data(NamedTuple):
    """What :func:`spectrum`'s residual compares, as arrays (passed as the solver's ``args``,
    so that one compiled solver serves every fit of the same size)."""

    edges: jax.Array  # (n + 1,) bin edges; the padding's bins have zero width at the last edge
    total: jax.Array  # () the data's total energy
    cum: jax.Array  # (n,) the data's cumulative energies, relative to the total
    mask: jax.Array  # (n,) 1 for the bins, 0 for the padding
    gamma: jax.Array  # () the fixed peak enhancement (unused when it is fitted)
    rough: Optional[_Rough]  # the informative roughness rows, or None


class _Problem(NamedTuple):
    to_params: object  # (y, data) -> p = (log hs, log tp, gamma)
    energy_residual: object  # (p, data) -> (n,)
    roughness_residual: object  # (p, data) -> (R,)
    residual_p: object  # (p, data) -> r
    residual: object  # (y, data) -> r
    residual_free: object  # (y_free, (data, y, idx)) -> r: only the entries idx of y vary
    sum_squares: object  # jitted (M, len y), data -> (M,)


@functools.lru_cache(maxsize=None)
def _problem(bounded: bool, fixed_gamma: bool, n_min: float, n_max: float) -> _Problem:
    """The residuals of :func:`spectrum` as functions of the parameters and the data, built
    once per configuration: the solvers compile per function object, so closures over one
    fit's data would be compiled again for every fit."""

    def to_params(y, d):
        # unbounded solvers see gamma = 1 + z^2 (>= 1 by construction); bounded ones gamma
        if fixed_gamma:
            return jnp.stack([y[0], y[1], d.gamma.astype(y.dtype)])
        return y if bounded else jnp.stack([y[0], y[1], 1.0 + y[2] * y[2]])

    def energy_residual(p, d):
        # cumulative bin energies of the model against the data's, relative to the total
        return (jnp.cumsum(_bin_energy(p, d.edges)) / d.total - d.cum) * d.mask

    def roughness_residual(p, d):
        # relative roughness residual of the informative rows
        rows = d.rough
        model = rows.fitted_share + _tail_roughness(p, rows.footprint, rows.omega_from, rows.band_hi, n_min, n_max)
        return (jnp.maximum(model, shading.MIN_SLOPE_VARIANCE) - rows.observed) / rows.observed * rows.mask

    def residual_p(p, d):
        r = energy_residual(p, d)
        if d.rough is not None:
            r = jnp.concatenate([r, roughness_residual(p, d) * d.rough.scale])
        return r

    def residual(y, d):
        return residual_p(to_params(y, d), d)

    def residual_free(y_free, args):
        d, y, idx = args
        return residual(y.at[idx].set(y_free), d)

    sum_squares = jax.jit(jax.vmap(lambda y, d: jnp.sum(residual(y, d) ** 2), in_axes=(0, None)))
    return _Problem(to_params, energy_residual, roughness_residual, residual_p, residual, residual_free,
                    sum_squares)


#: the bin energies of many spectra ``(M, 3)`` over one set of edges ``(n + 1,)``: ``(M, n)``
_bin_energies = jax.jit(jax.vmap(_bin_energy, in_axes=(0, None)))


def sea_state(waves: Waves) -> SeaState:
    """Bulk parameters of a set of waves (eager, NumPy): see :class:`SeaState`."""
    require_eager("fit.sea_state", _EAGER, waves)
    validate(waves, max_steepness=None)
    if np.size(waves.omega) == 0:
        raise InvalidValueError("sea_state needs at least one wave; got none")
    h = np.asarray(waves.amplitude, np.float64)
    om = np.asarray(waves.omega, np.float64)
    th = np.asarray(waves.theta, np.float64)
    e = 0.5 * h * h
    m0 = float(e.sum())
    order = np.argsort(om)
    edges = _bin_edges(om[order])
    dens = e[order] / np.diff(edges)  # energy per rad/s
    tp = float(2 * np.pi / om[order][np.argmax(dens)])
    theta_mean = float(np.arctan2(np.sum(e * np.sin(th)), np.sum(e * np.cos(th))))
    return SeaState(hs=4.0 * math.sqrt(m0), tp=tp, theta_mean=theta_mean, m0=m0)


def spectrum(waves: Waves, *, camera=None, roughness=None, reliable=None, determined=None, band=spec.SAMPLE_BAND,
             gamma=None,
             solver: str = "lm", max_steps: int = 200, roughness_weight: float = 1.0, noise=None,
             roughness_noise=None, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX) -> SpectrumFit:
    """Fit a JONSWAP / Mitsuyasu :class:`~jaxocean.spectrum.Spectrum` to waves (module
    docstring). ``waves``: leaves ``(N,)``; ``reliable``: bool ``(N,)`` of waves to trust
    (default: resolvable by ``camera`` when given, else all); ``determined``: bool ``(N,)``
    of waves whose parameters were measured (:func:`jaxocean.fit.waves`' ``determined``;
    default: every reliable wave), which alone can show a peak (``peak_observed``, module
    docstring); ``roughness``: observed
    ``(T, H, W)`` or ``(H, W)`` sub-pixel slope variance (needs ``camera``); ``band``: the
    sampling band in units of wp (its upper end bounds the roughness tail, so it matters
    only with ``roughness``); ``gamma``: fix the peak enhancement (None fits it).

    ``noise``: the RMS error of the waves' cumulative energy as a fraction of their total
    (None: 0, waves exact up to the sampling of the spectrum into bins); ``roughness_noise``
    the relative RMS error of the row-mean roughness (None: 0). ``success`` requires the
    answer's RMS residuals within ``sqrt(NOISE_FACTOR noise^2 + ENERGY_FLOOR^2)`` and
    ``sqrt(NOISE_FACTOR roughness_noise^2 + ROUGHNESS_FLOOR^2)``: a spectrum that leaves
    more does not explain the waves, however well the solver converged.

    Uncertainties (``hs_std`` ... ``s_max_std``) describe how far the answer moves with the
    scatter the data show about it. The fit minimises the *cumulative* energy residual, whose
    entries share every bin's error; with the per-bin errors independent of variance
    ``s^2`` (estimated from the differenced residual, ``n - p`` degrees of freedom) the
    covariance of the parameters is the sandwich ``A^-1 J^T Sigma J A^-1``, ``A = J^T J``,
    ``Sigma = s^2 L L^T`` (``L`` the cumulative sum), the roughness rows with their own
    variance; errors in where the bins end (frequencies jittered inside their bins) do not
    accumulate, so the same sandwich with independent cumulative errors is computed too
    and the larger standard deviation kept. The direction's is the sandwich of the weighted
    likelihood, ``H^-1 (sum w^2 g g^T) H^-1`` over the waves' score ``g`` and the Hessian
    ``H``. Neither counts the model's own error (a sea that is not one JONSWAP / Mitsuyasu
    spectrum): ``success`` says whether the answer explains the data.
    Eager (the wave selection is data dependent). The fit runs in float64 whatever JAX's
    default precision; the spectrum returned has the default float dtype. Its residual is
    padded to multiples of 16 bins and rows, so fits of nearby sizes share compiled programs."""
    from jaxocean.fit import solvers
    from jaxocean.fit.waves import resolvable

    t0 = time.perf_counter()
    require_eager("fit.spectrum", _EAGER, waves, camera, roughness, reliable, determined)
    validate(waves, max_steepness=None)
    if waves.omega.ndim != 1:
        raise ValueError(f"fit.spectrum takes Waves with leaves (N,); got {waves.omega.shape}")
    if roughness is not None and camera is None:
        raise ValueError("fitting the roughness tail needs the camera (its footprints)")
    if roughness is not None:
        r_shape = tuple(np.shape(roughness))
        if len(r_shape) not in (2, 3) or r_shape[-2:] != tuple(camera.resolution):
            raise ValueError(f"roughness must be (T, H, W) or (H, W) with (H, W) = {tuple(camera.resolution)}, the "
                             f"camera's resolution; got shape {r_shape}")
        # NaN marks a pixel without data (ignored); a negative slope variance is no data at all
        check_values(~(np.asarray(roughness) < 0), "roughness (slope variance) must be >= 0 (NaN: no data)",
                     roughness)
    if band is not None:
        try:
            lo_rel, hi_rel = (float(v) for v in band)
        except (TypeError, ValueError):
            raise ValueError(f"band must be (lo, hi) in units of wp; got {band!r}") from None
        if not (math.isfinite(lo_rel) and math.isfinite(hi_rel) and 0 < lo_rel < hi_rel):
            raise ValueError(f"band must be (lo, hi) in units of wp with 0 < lo < hi; got {band!r}")
    n = waves.omega.shape[0]
    if reliable is None:
        reliable = resolvable(waves, camera) if camera is not None else np.ones(n, bool)
    reliable = _wave_mask(reliable, "reliable", n)
    determined = _wave_mask(np.ones(n, bool) if determined is None else determined, "determined", n)
    if reliable.sum() < MIN_WAVES:
        raise InvalidValueError(f"fit.spectrum needs at least {MIN_WAVES} reliable waves; got {int(reliable.sum())}")
    # bins are set by distinct frequencies, and the energies are relative to their total: waves
    # at fewer frequencies, or without energy, have no spectral shape (no starting point either)
    n_freq = np.unique(np.asarray(waves.omega, np.float64)[reliable]).size
    if n_freq < MIN_WAVES:
        raise InvalidValueError(f"fit.spectrum needs reliable waves at {MIN_WAVES} or more distinct frequencies "
                                f"(a peak, its width and a level); got {n_freq}")
    if not np.any(np.asarray(waves.amplitude)[reliable] > 0):
        raise InvalidValueError("fit.spectrum: the reliable waves carry no energy (every amplitude is 0)")
    if gamma is not None:
        check_values(np.isfinite(gamma) & (np.asarray(gamma) >= 1), "gamma must be finite and >= 1", gamma)
    check_values(np.isfinite(roughness_weight) & (np.asarray(roughness_weight) >= 0),
                 "roughness_weight must be finite and >= 0", roughness_weight)
    for name, value in (("noise", noise), ("roughness_noise", roughness_noise)):
        if value is not None:
            check_values(np.asarray(value) >= 0, f"{name} must be >= 0", value)

    # the fit runs in float64 whatever the caller's precision: it is small (3 parameters, one
    # residual per wave and image row), and in float32 the LM's stopping test sits at the
    # residuals' rounding, so that fits at their answer ran to the step limit (measured: 2
    # of 60 float32 seas of 20-45 waves)
    out_dtype = jnp.result_type(float)
    with jax.enable_x64(True):
        h = np.asarray(waves.amplitude, np.float64)[reliable]
        om = np.asarray(waves.omega, np.float64)[reliable]
        th = np.asarray(waves.theta, np.float64)[reliable]
        order = np.argsort(om)
        h, om, th = h[order], om[order], th[order]
        edges = _bin_edges(om)
        e_data = 0.5 * h * h
        # a bin's energy is measured where its wave is determined and so are the neighbours
        # whose frequencies set its edges (a stand-in's frequency is not measured)
        det = determined[reliable][order]
        measured = det & np.r_[True, det[:-1]] & np.r_[det[1:], True]
        cum_data = np.cumsum(e_data)
        total = cum_data[-1]
        dtype = jnp.float64
        n_bins, n_bins_pad = len(om), _padded(len(om))
        edges_j = jnp.asarray(np.r_[edges, np.full(n_bins_pad - n_bins, edges[-1])], dtype)
        cum_j = jnp.asarray(np.r_[cum_data / total, np.ones(n_bins_pad - n_bins)], dtype)
        bin_mask = jnp.asarray(np.arange(n_bins_pad) < n_bins, dtype)

        # roughness rows (optional)
        rough_rows = None
        if roughness is not None:
            hit = cam.intersect_sea(camera)
            W = camera.resolution[1]
            fp_row = np.asarray(hit.footprint)[:, W // 2]
            r_row, rows = observed_rows(roughness, hit.mask)
            fitted_share = np.asarray(row_roughness(np.asarray(waves.omega) ** 2 / GRAVITY, waves.amplitude, fp_row,
                                                    n_min, n_max), np.float64)
            informative = rows & (r_row > 2.0 * shading.MIN_SLOPE_VARIANCE)
            if informative.any():
                # padded with copies of the first row, masked out
                n_rows = int(informative.sum())
                pad = np.r_[np.flatnonzero(informative), np.full(_padded(n_rows) - n_rows, np.argmax(informative))]
                rough_rows = (jnp.asarray(fp_row[pad], dtype), jnp.asarray(r_row[pad], dtype),
                              jnp.asarray(fitted_share[pad], dtype), jnp.asarray(np.arange(pad.size) < n_rows, dtype))
        band_hi = float(band[1]) if band is not None else 10.0
        om_top = float(edges[-1])
        if rough_rows is not None:
            scale = math.sqrt(roughness_weight * len(om) / n_rows)
            rough_rows = _Rough(*rough_rows, *(jnp.asarray(v, dtype) for v in (scale, om_top, band_hi)))
        data = _Data(edges_j, jnp.asarray(total, dtype), cum_j, bin_mask,
                     jnp.asarray(1.0 if gamma is None else gamma, dtype), rough_rows)
        # the residual's entries of the bins and the rows, without the padding's
        unpadded = np.r_[np.arange(n_bins), n_bins_pad + np.arange(n_rows if rough_rows is not None else 0)]

        bounded = solvers.get_solver(solver).bounded
        problem = _problem(bool(bounded), gamma is not None, float(n_min), float(n_max))

        def to_params(y):
            return problem.to_params(y, data)

        def from_params(p):
            p = np.asarray(p, np.float64)
            if gamma is not None:
                return p[:2]
            return p if bounded else np.array([p[0], p[1], math.sqrt(max(p[2] - 1.0, 0.0))])

        def grid(tps, gammas=(1.0, 2.0, 3.3, 5.0, 7.0), known=None):
            # spectra over a (Tp, gamma) grid with Hs^2 in closed form (energies are linear in
            # Hs^2), evaluated in one vectorised call: their parameters p (M, 3), whether each is
            # admissible (M,), and the RMS of each one's cumulative-energy residual (M,).
            # ``known`` (n,): the bins whose data energy is taken as measured; each other bin
            # holds the model's own energy (no residual), and the residual is relative to the
            # total so completed (default: every bin, the data's total)
            known = np.ones(len(om), bool) if known is None else known
            gammas = np.asarray(gammas if gamma is None else [float(gamma)], np.float64)
            G, TP = np.meshgrid(gammas, tps, indexing="ij")
            p0 = jnp.asarray(np.stack([np.zeros(G.size), np.log(TP.ravel()), G.ravel()], -1), dtype)
            e1 = np.asarray(_bin_energies(p0, edges_j), np.float64)[:, :n_bins]
            c1, c_data = np.cumsum(e1 * known, axis=-1), np.cumsum(e_data * known)
            ok = np.all(np.isfinite(e1), axis=-1) & (c1[:, -1] > 0)
            hs2 = np.where(ok, np.sum(c1 * c_data, -1) / np.maximum(np.sum(c1 * c1, -1), 1e-300), 0.0)
            ok &= hs2 > 0
            params = np.stack([0.5 * np.log(np.maximum(hs2, 1e-300)), np.log(TP.ravel()), G.ravel()], -1)
            completed = c_data[-1] + hs2 * np.sum(e1 * ~known, -1)
            rms = np.sqrt(np.mean(((c1 * hs2[:, None] - c_data) / completed[:, None]) ** 2, -1))
            return params, ok, np.where(ok & np.isfinite(rms), rms, np.inf)

        def grid_start(tps):
            # the grid's best point (energies and roughness) as a solver vector y
            starts, ok, _ = grid(tps)
            starts_j = jnp.asarray(np.stack([from_params(p) for p in starts]), dtype)
            vals = np.asarray(problem.sum_squares(starts_j, data), np.float64)
            vals = np.where(ok & np.isfinite(vals), vals, np.inf)
            if not np.isfinite(vals).any():
                raise InvalidValueError("fit.spectrum found no admissible starting point (check the waves)")
            return starts_j[int(np.argmin(vals))]

        def least_squares(y0, free):
            # least squares over the entries ``free`` of y (the others stay at y0's values)
            idx = jnp.asarray(np.flatnonzero(free))
            lower = jnp.asarray([math.log(1e-3), math.log(0.3), 1.0][: y0.shape[0]], dtype)[idx]
            upper = jnp.asarray([math.log(50.0), math.log(60.0), 10.0][: y0.shape[0]], dtype)[idx]
            # jaxopt's tolerance is a projected-gradient norm; optimistix's Cauchy test holds
            # every residual's change below atol + rtol |r| (the cumulative residuals' entries
            # are up to 1, and round at 2e-16 here)
            atol = 1e-5 if bounded else 1e-9
            out = solvers.solve(solver, problem.residual_free, y0[idx], (data, y0, idx), max_steps=max_steps,
                                rtol=1e-6, atol=atol, lower=lower if bounded else None,
                                upper=upper if bounded else None)
            y_solver = y0.at[idx].set(out.params)
            return out, np.asarray(to_params(y_solver), np.float64), y_solver

        free = np.ones(2 if gamma is not None else 3, bool)
        out, y, y_solver = least_squares(grid_start(np.geomspace(2 * np.pi / (om[-1]), 2 * np.pi / (0.3 * om[0]), 48)),
                                         free)
        wp = 2 * math.pi / math.exp(y[1])
        # the tail level: JONSWAP in Hs-Tp form carries the normalisation A(gamma) into its tail
        alpha = float(spec.jonswap_normalisation(y[2])) * 5.0 / 16.0 * math.exp(2 * y[0]) * wp ** 4 / GRAVITY ** 2
        bound = math.sqrt(NOISE_FACTOR * (0.0 if noise is None else float(noise)) ** 2 + ENERGY_FLOOR ** 2)
        # the best spectra with their peak at or beyond the band's long-wave and short-wave edge:
        # a peak inside the band is observed only if the energies rule both out (module docstring)
        # the edges are those of the measured bins (with ``determined``: module docstring)
        inside = bool(edges[0] <= wp <= edges[-1])
        if measured.sum() >= MIN_WAVES:
            first, last = np.flatnonzero(measured)[[0, -1]]
            lo_m, hi_m = edges[first], edges[last + 1]
            edge_misfit = min(float(np.min(grid(2 * np.pi / e * f, EDGE_GAMMAS, measured)[2]))
                              for e, f in ((lo_m, EDGE_REACH), (hi_m, 1.0 / EDGE_REACH)))
            peak_observed = bool(lo_m <= wp <= hi_m) and not edge_misfit <= bound
        else:  # too few measured energies to show a peak
            edge_misfit, peak_observed = float("nan"), False
        if not inside:
            # only alpha is determined, and the solver drifts along its valley: refit Hs and
            # gamma with the peak pinned to the band's nearer edge (module docstring)
            wp = float(np.clip(wp, edges[0], edges[-1]))
            free[1] = False
            out, y, y_solver = least_squares(grid_start(np.array([2 * math.pi / wp])), free)
        elif not peak_observed:
            # a peak inside that one beyond an edge explains as well: the fitted peak is the
            # nearest to the band's middle that explains the energies, so Hs and Tp are bounds
            # (module docstring); Tp is held in the covariance, as a pinned Tp is
            free[1] = False
        hs_fit, tp_fit = math.exp(y[0]), math.exp(y[1])
        g_fit = float(y[2])
        wp = 2 * math.pi / tp_fit
        tail = measured & (om >= TAIL_START * wp)
        if not peak_observed and tail.sum() >= MIN_WAVES:
            # the level of the measured tail: int_bin alpha g^2 w^-5 dw = alpha g^2 (a^-4 - b^-4) / 4
            unit = GRAVITY ** 2 / 4.0 * (edges[:-1][tail] ** -4.0 - edges[1:][tail] ** -4.0)
            alpha = float(np.sum(e_data[tail]) / np.sum(unit))
        fitted_density = np.asarray(spec._jonswap_kernel(edges_j, hs_fit, tp_fit, g_fit, 0.07, 0.09),
                                    np.float64)[:n_bins + 1]
        # the covariance in the spectrum's own parameters: through the solver's z (gamma = 1 + z^2)
        # gamma's standard deviation would vanish at gamma = 1, where d gamma / d z = 0
        free_p = np.array([free[0], free[1], gamma is None])
        std_p = _least_squares_std(lambda p: problem.residual_p(p, data), to_params(y_solver), free_p, n_bins,
                                   edge_cov=_edge_covariance(edges, fitted_density, total), keep=unpadded)
        hs_std, tp_std = hs_fit * std_p[0], tp_fit * std_p[1]
        gamma_std = float(std_p[2])  # NaN when gamma was given

        theta_mean, s_max, theta_std, s_max_std, directions_determined = _direction_mle(om, th, wp, weight=h * h)
        dir_misfit = (direction_misfit(om, th, wp, theta_mean, s_max, weight=h * h) if directions_determined
                      else float("nan"))
        one_spreading = not abs(dir_misfit) > DIRECTION_Z_MAX  # NaN (no variance to test) passes
        # a spreading broader than the grid's broadest: no single spreading (S_MAX_GRID)
        one_spreading = one_spreading and s_max > S_MAX_GRID[0] * (1 + 1e-9)
        fitted = spec.Spectrum(hs=jnp.asarray(hs_fit, out_dtype), tp=jnp.asarray(tp_fit, out_dtype),
                               gamma=jnp.asarray(g_fit, out_dtype), theta_mean=jnp.asarray(theta_mean, out_dtype),
                               s_max=jnp.asarray(s_max, out_dtype))
        # success: converged, and the answer explains the data to their stated noise
        p_solver = to_params(y_solver)
        misfit = float(np.sqrt(np.mean(np.asarray(problem.energy_residual(p_solver, data), np.float64)[:n_bins] ** 2)))
        rough_misfit = rough_bound = float("nan")
        explained = misfit <= bound
        if rough_rows is not None and roughness_weight > 0:
            rough_misfit = float(np.sqrt(np.mean(np.asarray(problem.roughness_residual(p_solver, data),
                                                            np.float64)[:n_rows] ** 2)))
            rn = 0.0 if roughness_noise is None else float(roughness_noise)
            rough_bound = math.sqrt(NOISE_FACTOR * rn ** 2 + ROUGHNESS_FLOOR ** 2)
            explained = explained and rough_misfit <= rough_bound
        # a mean direction and spreading need several waves of weight: one dominant wave's
        # direction is not the sea's
        return SpectrumFit(spectrum=fitted, loss=float(out.loss),
                           success=bool(out.success) and explained and directions_determined and one_spreading,
                           steps=int(out.steps), n_waves=int(len(om)), omega_band=(float(edges[0]), float(edges[-1])),
                           # energies no spectrum of this family explains show no peak of it: the
                           # edge test above is passed by every spectrum then, the one fitted too
                           peak_observed=peak_observed and misfit <= bound, alpha=float(alpha),
                           time_s=time.perf_counter() - t0,
                           misfit=misfit, misfit_bound=bound, roughness_misfit=rough_misfit,
                           roughness_bound=rough_bound,
                           hs_std=float(hs_std), tp_std=float(tp_std), gamma_std=float(gamma_std),
                           theta_std=theta_std, s_max_std=s_max_std, direction_misfit=dir_misfit,
                           edge_peak_misfit=edge_misfit)


def _wave_mask(mask, name: str, n: int) -> np.ndarray:
    """``mask`` as a bool array ``(n,)``, one entry per wave (a clear error otherwise)."""
    mask = np.asarray(mask, bool)
    if mask.shape != (n,):
        raise ValueError(f"{name} must be a bool mask (N,) = ({n},); got {mask.shape}")
    return mask


def _edge_covariance(edges, density, total) -> np.ndarray:
    """Covariance ``(n, n)`` of the model's cumulative energies (relative to ``total``) from
    not knowing where each wave's frequency bin ends.

    A sampled wave's frequency is uniform inside its bin (log-width ``d``: variance ``d^2 /
    12`` of its log), and the fit's edges are the geometric midpoints of neighbours
    (:func:`_bin_edges`: a linear map ``B`` of the log frequencies), so the log edges have
    covariance ``B diag(d^2 / 12) B^T``. The model's cumulative energy up to bin ``i`` moves
    with its upper edge and the first edge only, by ``S(e) e / total`` per unit log edge
    (``density``: the fitted ``S`` at ``edges``). The fit absorbs most of what these errors
    do to the residual, so the residual's own scatter misses them (measured: Tp 5x its
    standard deviation off on seas drawn with 20 waves, before this term)."""
    n = edges.size - 1
    log_width = np.log(edges[1:] / edges[:-1])
    B = np.zeros((n + 1, n))
    if n == 1:
        B[:, 0] = 1.0
    else:
        B[np.arange(1, n), np.arange(0, n - 1)] = 0.5
        B[np.arange(1, n), np.arange(1, n)] = 0.5
        B[0, :2] = (1.5, -0.5)
        B[n, n - 2:] = (-0.5, 1.5)
    log_edge_cov = B @ np.diag(log_width ** 2 / 12.0) @ B.T
    slope = density * edges / total  # d(cumulative) / d(log edge)
    G = np.zeros((n, n + 1))
    G[:, 0] = -slope[0]
    G[np.arange(n), np.arange(1, n + 1)] = slope[1:]
    return G @ log_edge_cov @ G.T


def _least_squares_std(residual, y, free, n_energy: int, edge_cov=None, keep=None) -> np.ndarray:
    """1-sigma of every entry of ``y`` (NaN where not ``free``) from the sandwich covariance
    of the least-squares fit of ``residual``'s entries ``keep`` (default all; the padding of
    :func:`spectrum`'s residual is left out after evaluating it, so the evaluation keeps its
    compiled shapes; :func:`spectrum`'s docstring): their first ``n_energy`` are cumulative
    energies, the rest roughness rows (independent). ``edge_cov`` ``(n_energy, n_energy)``:
    the cumulative energies' covariance from the bins' unknown edges
    (:func:`_edge_covariance`), added to the independent errors' (default 0)."""
    idx = np.flatnonzero(free)
    y = jnp.asarray(y)
    idx_j = jnp.asarray(idx)
    r_free = lambda yf: residual(y.at[idx_j].set(yf))  # noqa: E731
    keep = slice(None) if keep is None else keep
    J = np.asarray(jax.jacfwd(r_free)(y[idx_j]), np.float64)[keep]
    r = np.asarray(r_free(y[idx_j]), np.float64)[keep]
    p = idx.size
    dof = max(n_energy - p, 1)
    a_inv = np.linalg.pinv(J.T @ J)
    n_rough = r.size - n_energy

    def sandwich(energy_cov):
        sigma = np.zeros((r.size, r.size))
        sigma[:n_energy, :n_energy] = energy_cov
        if n_rough:
            sigma[n_energy:, n_energy:] = np.eye(n_rough) * float(np.sum(r[n_energy:] ** 2)) / max(n_rough - p, 1)
        return np.sqrt(np.maximum(np.diag(a_inv @ (J.T @ sigma @ J) @ a_inv), 0.0))

    # errors of each bin's energy (an amplitude error) accumulate along the cumulative
    # residual; errors of where a bin ends (a frequency jittered inside its bin) do not
    L = np.tril(np.ones((n_energy, n_energy)))
    per_bin = np.diff(r[:n_energy], prepend=0.0)
    accumulating = sandwich(float(np.sum(per_bin ** 2)) / dof * (L @ L.T))
    independent = sandwich(float(np.sum(r[:n_energy] ** 2)) / dof * np.eye(n_energy)
                           + (0.0 if edge_cov is None else edge_cov))
    std = np.full(np.shape(free), np.nan)
    std[idx] = np.maximum(accumulating, independent)
    return std


def _spreading_s(om, wp, s_max):
    """Mitsuyasu's ``s`` of each frequency (:func:`jaxocean.spectrum.mitsuyasu_s`'s law) in
    float64 NumPy, for the direction fit's grid and finite differences."""
    x = om / wp
    return s_max * np.where(x > 1, x ** -2.5, x ** 5)


def _mean_one(om, weight=None):
    """The direction fit's per-wave weights (default 1) scaled to mean 1."""
    weight = np.ones_like(om) if weight is None else np.asarray(weight, np.float64)
    return weight * (weight.size / max(float(np.sum(weight)), 1e-300))


def _spreading_loglik(theta_mean, s_max, om, th, wp):
    """Per-wave log-likelihood of the directions ``th`` under the Mitsuyasu spreading of
    their frequencies ``om``; ``theta_mean``, ``s_max`` broadcast against a trailing wave axis."""
    s = _spreading_s(om, wp, s_max)
    log_q = _lgamma(s + 1) - _lgamma(s + 0.5) - math.log(2 * math.sqrt(math.pi))
    c2 = 0.5 * (1 + np.cos(th - theta_mean))
    return log_q + s * np.log(np.maximum(c2, 1e-300))


def _cos_moment(s, n: int):
    """``E[cos(n phi)]`` under the spreading ``D ~ cos^(2s)(phi / 2)``:
    ``Gamma(s+1)^2 / (Gamma(s+1-n) Gamma(s+1+n)) = prod_{k=1..n} (s+1-k) / (s+k)``."""
    out = np.ones_like(s)
    for k in range(1, n + 1):
        out = out * (s + 1 - k) / (s + k)
    return out


def direction_misfit(om, th, wp, theta_mean, s_max, weight=None) -> float:
    """How far the waves' directions are from one Mitsuyasu spreading, as a z-score.

    The statistic is the weighted second circular moment about the mean direction,
    ``sum w cos(2 (th - theta_mean))``, against its expectation under each wave's own
    spreading ``s(omega)`` (the first moment is what the fit of ``theta_mean`` and
    ``s_max`` matches), divided by its standard deviation for independent draws (weights
    ``w`` as in the direction fit: normalised energies). Two wave systems from different
    directions put their energy away from the mean on both sides: their second moment is
    far below what the broad spreading fitted between them expects. NaN when the weights
    leave no variance."""
    weight = _mean_one(om, weight)
    s = _spreading_s(om, wp, s_max)
    m2, m4 = _cos_moment(s, 2), _cos_moment(s, 4)
    variance = np.maximum(0.5 * (1 + m4) - m2 ** 2, 0.0)
    scale = math.sqrt(float(np.sum(weight ** 2 * variance)))
    if not scale > 0:
        return float("nan")
    return float(np.sum(weight * (np.cos(2 * (th - theta_mean)) - m2)) / scale)


def _direction_mle(om, th, wp, weight=None):
    """Maximum-likelihood ``(theta_mean, s_max, theta_std, s_max_std, determined)`` of
    directions under Mitsuyasu spreading, each wave's log-likelihood scaled by ``weight``
    (normalised to mean 1; default 1); the standard deviations from the sandwich covariance
    (NaN at the edge of the ``s_max`` grid, without an interior maximum, or not
    ``determined``: the weights give fewer than :data:`MIN_DIRECTION_WAVES` effective waves)."""
    weight = _mean_one(om, weight)
    n_eff = float(np.sum(weight) ** 2 / max(float(np.sum(weight * weight)), 1e-300))  # Kish's effective size
    determined = n_eff >= MIN_DIRECTION_WAVES
    th_grid = np.linspace(-np.pi, np.pi, 360, endpoint=False)
    s_grid = np.geomspace(*S_MAX_GRID, 48)
    ll = np.sum(weight * _spreading_loglik(th_grid[:, None, None], s_grid[None, :, None], om, th, wp), -1)  # (T, S)
    i, j = np.unravel_index(np.argmax(ll), ll.shape)

    def parabola(f_m, f_0, f_p):
        den = f_m - 2 * f_0 + f_p
        return 0.0 if den >= 0 else float(np.clip(0.5 * (f_m - f_p) / den, -0.5, 0.5))

    dt = th_grid[1] - th_grid[0]
    theta = th_grid[i] + dt * parabola(ll[(i - 1) % 360, j], ll[i, j], ll[(i + 1) % 360, j])
    if 0 < j < len(s_grid) - 1:
        ls = np.log(s_grid)
        s_best = math.exp(ls[j] + (ls[1] - ls[0]) * parabola(ll[i, j - 1], ll[i, j], ll[i, j + 1]))
    else:
        s_best = float(s_grid[j])
    theta = float(np.mod(theta + np.pi, 2 * np.pi) - np.pi)
    if not 0 < j < len(s_grid) - 1:
        return theta, s_best, float("nan"), float("nan"), determined
    # sandwich covariance in (theta, log s_max) from per-wave central differences
    eps = 1e-3
    f = lambda dt_, dl: _spreading_loglik(theta + dt_, s_best * math.exp(dl), om, th, wp)  # noqa: E731
    f0 = f(0.0, 0.0)
    g = np.stack([(f(eps, 0) - f(-eps, 0)) / (2 * eps), (f(0, eps) - f(0, -eps)) / (2 * eps)], -1)  # (n, 2)
    h_tt = (f(eps, 0) - 2 * f0 + f(-eps, 0)) / eps ** 2
    h_ll = (f(0, eps) - 2 * f0 + f(0, -eps)) / eps ** 2
    h_tl = (f(eps, eps) - f(eps, -eps) - f(-eps, eps) + f(-eps, -eps)) / (4 * eps * eps)
    hess = np.array([[np.sum(weight * h_tt), np.sum(weight * h_tl)], [np.sum(weight * h_tl), np.sum(weight * h_ll)]])
    if not np.all(np.linalg.eigvalsh(hess) < 0):
        return theta, s_best, float("nan"), float("nan"), determined
    h_inv = np.linalg.inv(hess)
    cov = h_inv @ ((weight[:, None] * g).T @ (weight[:, None] * g)) @ h_inv
    if not determined:
        return theta, s_best, float("nan"), float("nan"), determined
    # the sandwich from n_eff effective waves and 2 fitted parameters underestimates the
    # scatter by about sqrt((n_eff - 2) / n_eff); and a few waves that happen to cluster look
    # narrower than their spreading (the concentration's estimate is biased high, and the
    # direction's sandwich at it is too small): the direction's standard deviation is taken
    # at a broader spreading (DIRECTION_STD_BROADENING)
    inflate = math.sqrt(n_eff / (n_eff - 2.0))
    sigma_log_s = inflate * float(np.sqrt(cov[1, 1]))
    theta_std = inflate * float(np.sqrt(cov[0, 0])) * math.exp(0.5 * DIRECTION_STD_BROADENING * sigma_log_s)
    return theta, s_best, theta_std, s_best * sigma_log_s, determined


def _lgamma(x):
    from scipy.special import gammaln

    return gammaln(x)


def correct_amplitudes(waves: Waves, spectrum_: spec.Spectrum, *, reliable=None) -> Waves:
    """The spectrum correction: waves not marked ``reliable`` (bool ``(N,)``; default none)
    get ``h = sqrt(2 int_bin S)`` of the fitted spectrum over their frequency bin
    (geometric midpoints between neighbouring frequencies; waves at one frequency share
    its bin's energy equally); reliable waves keep their amplitude. Order of the waves is
    kept. Steepness is capped at k h = 0.9 (no looping crests). Eager (NumPy)."""
    require_eager("fit.correct_amplitudes", _EAGER, waves, spectrum_, reliable)
    validate(waves, max_steepness=None)
    spec.validate_spectrum(spectrum_)
    if waves.omega.ndim != 1:
        raise ValueError(f"correct_amplitudes takes Waves with leaves (N,); got {waves.omega.shape}")
    n = waves.omega.shape[0]
    if n == 0:
        raise InvalidValueError("correct_amplitudes needs at least one wave; got none")
    reliable = np.zeros(n, bool) if reliable is None else _wave_mask(reliable, "reliable", n)
    om = np.asarray(waves.omega, np.float64)
    # one bin per distinct frequency: a bin per wave would give tied waves zero-width bins
    # (all of one frequency: every amplitude 0)
    freqs, group, count = np.unique(om, return_inverse=True, return_counts=True)
    edges = _bin_edges(freqs)
    params = jnp.asarray([math.log(float(spectrum_.hs)), math.log(float(spectrum_.tp)), float(spectrum_.gamma)])
    e = np.asarray(_bin_energy(params, jnp.asarray(edges, params.dtype)), np.float64)
    h_spec = np.sqrt(2.0 * np.maximum(e, 0.0)[group] / count[group])
    k = om * om / GRAVITY
    h_spec = np.minimum(h_spec, 0.9 / k)
    h = np.where(reliable, np.asarray(waves.amplitude, np.float64), h_spec)
    return waves._replace(amplitude=jnp.asarray(h, waves.amplitude.dtype))


def tail_waves(key, spectrum_: spec.Spectrum, omega_from, n_waves: int, *, band=spec.SAMPLE_BAND) -> Waves:
    """``n_waves`` waves of the fitted spectrum's tail above ``omega_from`` [rad/s] up to the
    band's end (``band[1] x wp``), drawn by :func:`jaxocean.spectrum.sample_waves`: the
    sub-pixel waves to add back when re-rendering roughness from a fit."""
    spec.validate_spectrum(spectrum_)
    wp = 2 * math.pi / float(spectrum_.tp)
    hi = float(band[1]) * wp
    lo = float(omega_from)
    if not lo < hi:
        raise InvalidValueError(f"omega_from={lo:g} rad/s is above the band's end {hi:g} rad/s: no tail to draw")
    return spec.sample_waves(key, spectrum_, n_waves, band=(lo, hi)).waves
