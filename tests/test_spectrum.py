import math
import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import example, given
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxocean.errors import InvalidValueError
from jaxocean.spectrum import (MOMENT_BAND, SAMPLE_BAND, SampledSea, Spectrum, SteepnessWarning, cos2s,
                               directional_density, jonswap, jonswap_normalisation, mitsuyasu,
                               mitsuyasu_s, moments, pierson_moskowitz, sample_waves, spectrum_density,
                               wind_sea_state, wind_spectrum)
from jaxocean.waves import GRAVITY, Waves, steepness

SEAS = [  # (hs, tp, gamma): calm swell to storm, PM to very peaked
    (0.5, 4.0, 1.0),
    (2.0, 8.0, 1.0),
    (2.0, 8.0, 3.3),
    (6.0, 12.0, 3.3),
    (1.0, 6.0, 7.0),
    (3.0, 10.0, 1.5),
]


def omega_p(tp):
    return 2 * np.pi / tp


def periodic_integral(f, n=4096):
    """int_{-pi}^{pi} f: the rectangle rule is spectrally accurate for smooth periodic f."""
    theta = np.linspace(-np.pi, np.pi, n, endpoint=False)
    return np.sum(np.asarray(f(jnp.asarray(theta)))) * (2 * np.pi / n)


# ---------------------------------------------------------------------------------------
# frequency spectra


@pytest.mark.parametrize("hs, tp, gamma", SEAS)
def test_hs_and_tp_recovered_from_moments(hs, tp, gamma):
    m = moments(Spectrum(hs, tp, gamma))
    np.testing.assert_allclose(m.hs, hs, rtol=1e-3)  # brief asks 1%; the default band loses 6e-5
    np.testing.assert_allclose(m.tp, tp, rtol=5e-3)
    np.testing.assert_allclose(m.tm01, 2 * np.pi * m.m0 / m.m1, rtol=1e-6)
    assert m.tm01 < m.tp  # the w^-5 tail pulls the mean period below the peak period


def test_moments_of_a_callable_agree_with_closed_forms():
    hs, tp = 2.0, 8.0
    wp = omega_p(tp)
    # band from 0 exercises the panel reaching back to omega_min = 0
    m = moments(lambda w: pierson_moskowitz(w, hs=hs, tp=tp), band=(0.0, 40 * wp))
    # PM over (0, X wp): m0 = Hs^2/16 exp(-5/4 X^-4)  (substitute u = x^-4)
    np.testing.assert_allclose(m.m0, hs**2 / 16 * np.exp(-1.25 / 40**4), rtol=1e-5)
    # m1 of PM to infinity = Hs^2/16 wp (5/4)^(1/4) Gamma(3/4); the tail beyond 40 wp is 4e-6
    from math import gamma as gamma_fn
    np.testing.assert_allclose(m.m1, hs**2 / 16 * wp * 1.25**0.25 * gamma_fn(0.75), rtol=1e-4)
    np.testing.assert_allclose(m.tp, tp, rtol=1e-4)


def test_spectrum_peaks_at_omega_p():
    for hs, tp, gamma in SEAS:
        w = jnp.asarray(omega_p(tp) * np.linspace(0.5, 2.0, 30001))
        s = jonswap(w, hs=hs, tp=tp, gamma=gamma)
        np.testing.assert_allclose(w[jnp.argmax(s)], omega_p(tp), rtol=5e-3)


def test_jonswap_with_gamma_one_is_pm_exactly():
    w = jnp.linspace(0.0, 5.0, 257)
    np.testing.assert_array_equal(jonswap(w, hs=2.5, tp=7.0, gamma=1.0), pierson_moskowitz(w, hs=2.5, tp=7.0))
    spec = Spectrum(2.5, 7.0, gamma=1.0)
    np.testing.assert_array_equal(spectrum_density(spec, w), pierson_moskowitz(w, hs=2.5, tp=7.0))
    assert jonswap_normalisation(1.0) == 1.0


def test_pm_closed_form():
    hs, tp = 3.0, 9.0
    wp = omega_p(tp)
    w = np.array([0.5, 0.8, 1.0, 1.3, 3.0]) * wp
    expected = 5 / 16 * hs**2 * wp**4 * w**-5 * np.exp(-1.25 * (wp / w) ** 4)
    np.testing.assert_allclose(pierson_moskowitz(jnp.asarray(w), hs=hs, tp=tp), expected, rtol=2e-5)


def test_jonswap_peak_enhancement_against_goda():
    # DNV-RP-C205 sec. 3.5.5.2 / Goda (2000): normalising factor A ~ 1 - 0.287 ln(gamma), so
    # S_J(wp) / S_PM(wp) = gamma A ~ 3.3 * 0.657 = 2.17 for gamma = 3.3. Our A is the exact
    # quadrature (0.6558), 0.2% from Goda's fit.
    for gamma in (1.5, 3.3):
        np.testing.assert_allclose(jonswap_normalisation(gamma), 1 - 0.287 * np.log(gamma), rtol=0.01)
    wp = omega_p(8.0)
    ratio = jonswap(wp, hs=2.0, tp=8.0, gamma=3.3) / pierson_moskowitz(wp, hs=2.0, tp=8.0)
    np.testing.assert_allclose(ratio, 3.3 * (1 - 0.287 * np.log(3.3)), rtol=0.01)
    # a batch of gammas gives a batch of factors, one per sea
    batch = jonswap_normalisation(jnp.array([1.0, 1.5, 3.3]))
    np.testing.assert_allclose(batch, [1.0, jonswap_normalisation(1.5), jonswap_normalisation(3.3)], rtol=1e-6)


def test_wind_form_equals_hs_tp_form():
    for u in (5.0, 10.0, 20.0):
        hs, tp = wind_sea_state(u)
        w = jnp.linspace(0.0, 4.0, 401)
        s_wind = wind_spectrum(w, wind_speed=u)
        np.testing.assert_allclose(pierson_moskowitz(w, hs=hs, tp=tp), s_wind, rtol=1e-5,
                                   atol=1e-6 * float(jnp.max(s_wind)))
        # and the literal paper eq. 2 (gamma = 1): alpha g^2 w^-5 exp(-beta (g / (U w))^4)
        wn = np.linspace(0.3, 4.0, 50)
        literal = 8.1e-3 * GRAVITY**2 * wn**-5 * np.exp(-0.74 * (GRAVITY / (u * wn)) ** 4)
        np.testing.assert_allclose(wind_spectrum(jnp.asarray(wn), wind_speed=u), literal, rtol=2e-5,
                                   atol=1e-6 * literal.max())  # float32 underflows where float64 does not


def test_wind_sea_published_reference_values():
    # Stewart, Introduction to Physical Oceanography (2008) sec. 16.3, after Pierson &
    # Moskowitz (1964): wp = 0.877 g / U19.5 and H_1/3 = 0.21 U19.5^2 / g.
    u = 15.0
    hs, tp = wind_sea_state(u)
    np.testing.assert_allclose(2 * np.pi / tp, 0.877 * GRAVITY / u, rtol=1e-3)
    np.testing.assert_allclose(hs, 0.21 * u**2 / GRAVITY, rtol=0.01)
    # the spectrum's own moments agree with the closed form
    wp = 2 * np.pi / float(tp)
    m = moments(lambda w: wind_spectrum(w, wind_speed=u), band=(0.2 * wp, 200 * wp))
    np.testing.assert_allclose(m.hs, hs, rtol=1e-4)
    np.testing.assert_allclose(m.tp, tp, rtol=1e-3)


# ---------------------------------------------------------------------------------------
# directional spreading


@pytest.mark.parametrize("s", [0.0, 0.5, 1.0, 2.0, 10.0, 75.0])
def test_cos2s_integrates_to_one(s):
    np.testing.assert_allclose(periodic_integral(lambda t: cos2s(t, theta_mean=0.7, s=s)), 1.0, rtol=1e-5)
    # mean resultant length of cos-2s: E[cos(theta - theta_mean)] = s / (s + 1)
    mean_cos = periodic_integral(lambda t: jnp.cos(t - 0.7) * cos2s(t, theta_mean=0.7, s=s))
    np.testing.assert_allclose(mean_cos, s / (s + 1), atol=1e-5)


@pytest.mark.parametrize("s", [0.5, 3.9, 4.1, 63.0, 65.0, 1e3, 1e4, 1e6])
def test_cos2s_normalisation_is_accurate_for_narrow_spreading(s):
    # Q(s) = Gamma(s + 1) / (2 sqrt(pi) Gamma(s + 1/2)) was a difference of float32 gammaln:
    # D integrated to 1.004 at s = 1e4 and 1.099 at s = 1e6
    exact = math.exp(math.lgamma(s + 1.0) - math.lgamma(s + 0.5)) / (2.0 * math.sqrt(math.pi))
    peak = float(cos2s(jnp.float32(0.3), theta_mean=jnp.float32(0.3), s=jnp.float32(s)))
    assert peak == pytest.approx(exact, rel=2e-6)


@pytest.mark.parametrize("w_over_wp", [0.0, 0.3, 0.8, 1.0, 1.7, 5.0])
def test_mitsuyasu_integrates_to_one(w_over_wp):
    wp = 1.2
    d = periodic_integral(lambda t: mitsuyasu(t, w_over_wp * wp, theta_mean=-2.0, omega_p=wp, s_max=25.0))
    np.testing.assert_allclose(d, 1.0, rtol=1e-5)


def test_mitsuyasu_s_shape():
    s = mitsuyasu_s(jnp.array([0.0, 0.5, 1.0, 2.0]), omega_p=1.0, s_max=10.0)
    np.testing.assert_allclose(s, [0.0, 10 * 0.5**5, 10.0, 10 * 2**-2.5], rtol=1e-6)


def test_directional_density_integrates_to_m0():
    spec = Spectrum(2.0, 8.0, 3.3, theta_mean=1.0, s_max=10.0)
    wp = omega_p(8.0)
    w = jnp.linspace(0.2 * wp, 10 * wp, 2001)
    theta = jnp.linspace(-np.pi, np.pi, 512, endpoint=False)
    dens = directional_density(spec, w[:, None], theta[None, :])
    per_w = jnp.sum(dens, axis=1) * (2 * np.pi / 512)
    np.testing.assert_allclose(per_w, spectrum_density(spec, w), rtol=1e-4, atol=1e-8)
    np.testing.assert_allclose(jnp.trapezoid(per_w, w), 2.0**2 / 16, rtol=2e-3)


# ---------------------------------------------------------------------------------------
# sampling

SEA = Spectrum(hs=2.0, tp=8.0, gamma=3.3, theta_mean=0.5, s_max=10.0)


def sample_band(spec):
    return SAMPLE_BAND[0] * omega_p(spec.tp), SAMPLE_BAND[1] * omega_p(spec.tp)


def test_sampling_is_reproducible_by_key():
    a = sample_waves(jax.random.key(1), SEA, 60)
    b = sample_waves(jax.random.key(1), SEA, 60)
    c = sample_waves(jax.random.key(2), SEA, 60)
    assert isinstance(a, SampledSea) and isinstance(a.waves, Waves)
    for leaf_a, leaf_b in zip(a.waves, b.waves):
        np.testing.assert_array_equal(leaf_a, leaf_b)
    for name in ("omega", "theta", "phase"):
        assert not np.array_equal(getattr(a.waves, name), getattr(c.waves, name)), name


# (one compiled sampler per (n, bins): the pairs are reused between tests to keep them fast)
@pytest.mark.parametrize("n, bins", [(60, "geometric"), (240, "linear")])
def test_sampled_energy_equals_band_m0(key, n, bins):
    sea = sample_waves(key, SEA, n, bins=bins)
    m0_band = moments(SEA, sample_band(SEA)).m0
    energy = jnp.sum(sea.waves.amplitude**2) / 2
    # exact bin energies: measured |error| ~2e-7 at N = 60 and 240 (float32 rounding)
    np.testing.assert_allclose(energy, m0_band, rtol=1e-4)
    np.testing.assert_allclose(sea.band_m0, m0_band, rtol=1e-4)
    assert int(sea.n_clamped) == 0
    np.testing.assert_allclose(sea.total_steepness, jnp.sum(steepness(sea.waves)), rtol=1e-6)


@pytest.mark.parametrize("n, bins", [(60, "geometric"), (240, "linear")])
def test_sampled_frequencies_stratified_in_band(key, n, bins):
    lo, hi = sample_band(SEA)
    sea = sample_waves(key, SEA, n, bins=bins)
    w = np.asarray(sea.waves.omega)
    edges = lo * (hi / lo) ** np.linspace(0, 1, n + 1) if bins == "geometric" else np.linspace(lo, hi, n + 1)
    rtol = 1e-6
    assert np.all(w >= edges[:-1] * (1 - rtol)) and np.all(w <= edges[1:] * (1 + rtol))
    assert np.all(np.diff(w) > 0)
    # the jitter really moves within the bins (not all at one end)
    frac = (w - edges[:-1]) / np.diff(edges)
    assert 0.2 < frac.mean() < 0.8 and frac.std() > 0.15
    assert np.all((sea.waves.phase >= 0) & (sea.waves.phase < 2 * np.pi))
    assert np.all((sea.waves.theta >= -np.pi) & (sea.waves.theta < np.pi))


def test_custom_band(key):
    sea = sample_waves(key, SEA, 60, band=(0.6, 2.0))
    assert float(sea.waves.omega.min()) >= 0.6 and float(sea.waves.omega.max()) <= 2.0
    np.testing.assert_allclose(sea.band_m0, moments(SEA, (0.6, 2.0)).m0, rtol=1e-4)


N_DIRECTIONS = 1000  # one compiled size for the direction tests


@pytest.mark.parametrize("theta_mean", [0.3, np.pi - 0.05])  # the second wraps around +-pi
def test_directions_follow_the_spreading(key, theta_mean):
    spec = Spectrum(1.0, 6.0, 3.3, theta_mean=theta_mean, s_max=25.0)
    sea = sample_waves(key, spec, N_DIRECTIONS)
    th = np.asarray(sea.waves.theta)
    circ_mean = np.angle(np.mean(np.exp(1j * th)))
    assert abs(np.angle(np.exp(1j * (circ_mean - theta_mean)))) < 0.03
    # per-wave cos-2s: E[cos(theta - theta_mean)] = s / (s + 1) with s = s(w_i); the
    # standard error of the mean over 1000 waves is 0.016, so allow 3 of them (s -> 2 s
    # would move it by 0.1, a uniform spread by 0.64)
    s = np.asarray(mitsuyasu_s(sea.waves.omega, omega_p=omega_p(6.0), s_max=25.0))
    cos_dev = np.cos(th - theta_mean)
    stderr = cos_dev.std() / np.sqrt(th.size)
    assert 0.01 < stderr < 0.02
    np.testing.assert_allclose(cos_dev.mean(), np.mean(s / (s + 1)), atol=3 * stderr)


def test_narrow_swell_is_narrower_than_wind_sea(key):
    def spread(s_max):
        th = sample_waves(key, Spectrum(1.0, 6.0, 3.3, theta_mean=0.0, s_max=s_max), N_DIRECTIONS).waves.theta
        return 1 - np.abs(np.mean(np.exp(1j * np.asarray(th))))  # circular variance

    assert spread(75.0) < 0.5 * spread(10.0)


def test_steepness_clamp_warns_and_limits(key):
    with pytest.warns(SteepnessWarning, match=r"max_steepness=0\.01"):
        sea = sample_waves(key, SEA, 60, max_steepness=0.01)
    kh = np.asarray(steepness(sea.waves))
    assert np.all(kh <= 0.01 * (1 + 1e-5))
    assert int(sea.n_clamped) == int(np.sum(np.isclose(kh, 0.01, rtol=1e-5)))
    assert int(sea.n_clamped) > 0
    np.testing.assert_allclose(sea.total_steepness, kh.sum(), rtol=1e-5)
    assert float(jnp.sum(sea.waves.amplitude**2) / 2) < float(sea.band_m0)  # clamping removed energy


def test_steepness_error_policy_raises(key):
    with pytest.raises(InvalidValueError, match=r"k\*h above max_steepness=0\.01"):
        sample_waves(key, SEA, 60, max_steepness=0.01, steepness_policy="error")
    with warnings.catch_warnings():  # within the limit: no warning, no error
        warnings.simplefilter("error")
        sample_waves(key, SEA, 60, steepness_policy="error")


def test_sample_waves_jits_and_vmaps_and_matches_eager(key):
    # one compilation: a batch of seas (leading axis by vmap) under jit, n_waves static
    @jax.jit
    def sample_batch(keys, seas, max_steepness):
        return jax.vmap(lambda k, s: sample_waves(k, s, 60, max_steepness=max_steepness))(keys, seas)

    other = Spectrum(1.0, 6.0, 1.0, theta_mean=-1.0, s_max=25.0)
    seas = jax.tree_util.tree_map(lambda *v: jnp.array(v), SEA, other)
    keys = jax.random.split(key, 2)
    batch = sample_batch(keys, seas, 1.0)
    assert batch.waves.omega.shape == (2, 60)
    for i, sea in enumerate((SEA, other)):
        eager = sample_waves(keys[i], sea, 60)
        for leaf_b, leaf_e in zip(jax.tree_util.tree_leaves(batch), jax.tree_util.tree_leaves(eager)):
            np.testing.assert_allclose(leaf_b[i], leaf_e, rtol=2e-6, atol=1e-7)
    # without vmap a batch of seas is named as such (it crashed in the band check)
    with pytest.raises(ValueError, match=r"sample_waves takes one sea .*jax.vmap\(sample_waves"):
        sample_waves(keys[0], seas, 60)
    with pytest.raises(ValueError, match="moments takes one sea"):
        moments(seas)
    np.testing.assert_allclose(jax.vmap(moments)(seas).hs, [moments(SEA).hs, moments(other).hs], rtol=1e-6)
    # under jit the steepness check cannot warn (warnings are errors here): it clamps and counts
    clamped = sample_batch(keys, seas, 0.01)
    assert np.all(clamped.n_clamped > 0)
    assert float(jnp.max(steepness(clamped.waves))) <= 0.01 * (1 + 1e-5)
    # nor under grad, where the count is concrete but the steepness is not (it crashed)
    grads = jax.grad(lambda s: sample_waves(keys[0], s, 60, max_steepness=0.01).waves.amplitude.sum())(SEA)
    assert all(np.isfinite(float(g)) for g in grads) and float(grads.hs) > 0


def test_moments_jit():
    m = jax.jit(moments)(SEA)
    np.testing.assert_allclose(m.hs, 2.0, rtol=1e-3)


def test_sampling_is_differentiable_in_the_spectrum(key):
    def summary(fields):
        waves = sample_waves(key, Spectrum(*fields), 60).waves
        return jnp.sum(waves.amplitude**2) / 2 + jnp.sum(jnp.sin(waves.theta))

    grads = jax.grad(summary)(tuple(SEA))
    assert all(np.isfinite(g) for g in grads), grads
    # sum h^2/2 = m0 = Hs^2/16 * (fraction in band) and directions do not depend on Hs, so
    # d summary / d Hs = 2 m0 / Hs
    m0 = float(sample_waves(key, SEA, 60).band_m0)
    np.testing.assert_allclose(grads[0], 2 * m0 / SEA.hs, rtol=1e-4)
    assert grads[3] != 0 and grads[4] != 0  # directions respond to theta_mean and s_max


def test_float64(x64, key):
    sea = sample_waves(key, SEA, 60)
    assert sea.waves.omega.dtype == jnp.float64 and sea.waves.amplitude.dtype == jnp.float64
    np.testing.assert_allclose(jnp.sum(sea.waves.amplitude**2) / 2, moments(SEA, sample_band(SEA)).m0, rtol=1e-9)
    m = moments(Spectrum(2.0, 8.0, 1.0))
    assert m.m0.dtype == jnp.float64
    np.testing.assert_allclose(m.m0, 0.25 * np.exp(-1.25 / MOMENT_BAND[1] ** 4), rtol=1e-9)



def test_spectra_keep_float32_omega_with_python_parameters_under_x64(x64):
    # a function returns the dtype of its inputs; Python floats are weak (jonswap's
    # normalisation used to promote the result to float64)
    omega = jnp.array([0.5, 1.0, 2.0], jnp.float32)
    for gamma in (1.0, 3.3):
        s = jonswap(omega, hs=1.5, tp=6.0, gamma=gamma)
        assert s.dtype == jnp.float32
        np.testing.assert_allclose(s, jonswap(omega.astype(jnp.float64), hs=1.5, tp=6.0, gamma=gamma), rtol=1e-5)
    assert pierson_moskowitz(omega, hs=1.5, tp=6.0).dtype == jnp.float32
    assert jonswap(omega.astype(jnp.float64), hs=1.5, tp=6.0).dtype == jnp.float64


# ---------------------------------------------------------------------------------------
# gradients


def test_spectrum_gradients(x64):
    w = jnp.array([0.3, 0.6, 0.75, 0.9, 1.4, 3.0])  # wp = 0.785: both sides of the peak
    grads = dict(order=1, modes=("fwd", "rev"))
    check_grads(lambda om, hs, tp: pierson_moskowitz(om, hs=hs, tp=tp), (w, 2.0, 8.0), **grads)
    # gamma = 1 (PM) included: the formula is smooth through it
    for gamma in (1.0, 3.3):
        check_grads(lambda om, hs, tp, g: jonswap(om, hs=hs, tp=tp, gamma=g), (w, 2.0, 8.0, gamma), **grads)
    check_grads(lambda om, u, g: wind_spectrum(om, wind_speed=u, gamma=g), (w, 9.0, 3.3), **grads)


def test_spreading_gradients(x64):
    theta = jnp.array([-2.5, -1.0, 0.0, 0.4, 2.0, 3.0])
    for s in (0.5, 2.0, 10.0):
        check_grads(lambda t, m: cos2s(t, theta_mean=m, s=s), (theta, 0.3), order=1, modes=("fwd", "rev"))
    check_grads(lambda s: cos2s(theta, theta_mean=0.3, s=s), (4.0,), order=1, modes=("fwd", "rev"))
    # exactly opposite the mean direction cos((theta - theta_mean)/2) = 0: finite, not NaN
    for s in (0.3, 2.0):
        g = jax.grad(lambda t, m: cos2s(t, theta_mean=m, s=s), argnums=(0, 1))(0.3 + np.pi, 0.3)
        assert np.all(np.isfinite(g))


@jax.jit
def _values_and_grads(omega):
    def spectra(om, hs, tp, gamma, u):
        return (jonswap(om, hs=hs, tp=tp, gamma=gamma) + pierson_moskowitz(om, hs=hs, tp=tp)
                + wind_spectrum(om, wind_speed=u, gamma=gamma)
                + mitsuyasu(0.4 + om, om, theta_mean=0.0, omega_p=2 * jnp.pi / tp, s_max=gamma * 3))

    args = (omega, 2.0, 8.0, 3.3, 10.0)
    return spectra(*args), jax.grad(spectra, argnums=(0, 1, 2, 3, 4))(*args)


@given(st.floats(0.0, 20.0))
@example(0.0)
@example(1e-30)
@example(float(np.pi - 0.4))  # mitsuyasu argument exactly opposite the mean
def test_values_and_gradients_finite_from_zero(omega):
    value, grads = _values_and_grads(jnp.float32(omega))
    assert np.isfinite(value) and value >= 0
    assert all(np.isfinite(g) for g in grads), grads


def test_zero_frequency_is_zero_with_zero_gradient():
    ds = jax.grad(lambda w: jonswap(w, hs=2.0, tp=8.0))(0.0)
    assert jonswap(0.0, hs=2.0, tp=8.0) == 0.0 and ds == 0.0


# ---------------------------------------------------------------------------------------
# bad input


@pytest.mark.parametrize(
    "call, match",
    [
        (lambda: moments(SEA, (2.0, 1.0)), r"band=\(2\.0, 1\.0\)"),
        (lambda: moments(SEA, (1.0, 1.0)), r"band=\(1\.0, 1\.0\)"),
        (lambda: moments(SEA, (-0.5, 1.0)), r"band=\(-0\.5, 1\.0\)"),
        (lambda: moments(SEA, (0.1, np.inf)), r"band=\(0\.1, inf\)"),
        (lambda: sample_waves(jax.random.key(0), SEA, 10, band=(0.0, 2.0)), r"band=\(0\.0, 2\.0\).*0 < omega_min"),
        (lambda: pierson_moskowitz(1.0, hs=-1.0, tp=8.0), r"hs .*> 0 m.*-1\.0"),
        (lambda: pierson_moskowitz(1.0, hs=0.0, tp=8.0), r"hs .*> 0 m.*0\.0"),
        (lambda: jonswap(1.0, hs=2.0, tp=-3.0), r"tp .*> 0 s.*-3\.0"),
        (lambda: jonswap(1.0, hs=np.nan, tp=8.0), r"hs .*nan"),
        (lambda: jonswap(1.0, hs=2.0, tp=8.0, gamma=0.0), r"gamma .*> 0.*0\.0"),
        (lambda: moments(Spectrum(2.0, 8.0, gamma=0.5)), r"gamma .*>= 1.*0\.5"),
        (lambda: jonswap(jnp.array([1.0, np.nan]), hs=2.0, tp=8.0), r"omega .*nan"),
        (lambda: spectrum_density(Spectrum(2.0, 0.0), 1.0), r"Spectrum\.tp.*0\.0"),
        (lambda: moments(Spectrum(-2.0, 8.0)), r"Spectrum\.hs.*-2\.0"),
        (lambda: sample_waves(jax.random.key(0), Spectrum(2.0, 8.0, s_max=0.0), 10), r"s_max.*0\.0"),
        (lambda: sample_waves(jax.random.key(0), Spectrum(2.0, np.nan), 10), r"Spectrum\.tp.*nan"),
        (lambda: wind_sea_state(-3.0), r"wind_speed.*-3\.0"),
        (lambda: cos2s(0.0, theta_mean=0.0, s=-1.0), r"s must be.*-1\.0"),
    ],
)
def test_bad_values_are_named(call, match):
    with pytest.raises(InvalidValueError, match=match):
        call()


@pytest.mark.parametrize(
    "call, match",
    [
        # a zero width was NaN, a negative one a wrong normalisation (Hs 1.23 for 1)
        (lambda: jonswap(1.0, hs=1.0, tp=5.0, sigma_a=0.0), r"sigma_a .*> 0.*0\.0"),
        (lambda: jonswap(1.0, hs=1.0, tp=5.0, sigma_a=-0.07), r"sigma_a .*> 0.*-0\.07"),
        (lambda: wind_spectrum(1.0, wind_speed=10.0, sigma_b=np.nan), r"sigma_b .*nan"),
        # a negative alpha was a negative spectrum, a negative beta NaN, a zero beta a ZeroDivisionError
        (lambda: wind_spectrum(1.0, wind_speed=10.0, alpha=-8.1e-3), r"alpha .*> 0.*-0\.0081"),
        (lambda: wind_spectrum(1.0, wind_speed=10.0, beta=-0.74), r"beta .*> 0.*-0\.74"),
        (lambda: wind_sea_state(10.0, beta=0.0), r"beta .*> 0.*0\.0"),
        (lambda: wind_sea_state(10.0, alpha=-1.0), r"alpha .*> 0.*-1\.0"),
    ],
)
def test_bad_spectrum_shape_constants_are_named(call, match):
    with pytest.raises(InvalidValueError, match=match):
        call()


def test_structural_errors():
    with pytest.raises(ValueError, match="needs band"):
        moments(lambda w: w)
    with pytest.raises(ValueError, match="bins must be one of"):
        sample_waves(jax.random.key(0), SEA, 10, bins="cubic")
    with pytest.raises(ValueError, match="steepness_policy must be one of"):
        sample_waves(jax.random.key(0), SEA, 10, steepness_policy="ignore")
    with pytest.raises(ValueError, match="n_waves must be >= 1"):
        sample_waves(jax.random.key(0), SEA, 0)
    with pytest.raises(ValueError, match="expected a jaxocean.spectrum.Spectrum"):
        sample_waves(jax.random.key(0), (2.0, 8.0), 10)
    with pytest.raises(ValueError, match="band must be a pair"):
        moments(SEA, 3.0)


def test_sample_waves_warns_when_the_sampled_sea_folds():
    import warnings

    from jaxocean import surface
    from jaxocean.spectrum import FoldingWarning, SteepnessWarning

    # a steep short sea: each wave is clamped to k h <= 1 but the sum folds the trochoid
    steep = Spectrum(hs=2.5, tp=3.0, gamma=3.3, theta_mean=0.0, s_max=10.0)
    with pytest.warns(FoldingWarning, match="fold the trochoid surface"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", SteepnessWarning)  # the clamping one; FoldingWarning is caught above
            warnings.simplefilter("always", FoldingWarning)
            sea = sample_waves(jax.random.key(0), steep, 60)
    assert float(sea.total_steepness) > 1
    xy = np.random.default_rng(0).uniform(0, 200, (20000, 2)).astype(np.float32)
    assert float(jnp.min(surface.fold_determinant(sea.waves, xy, 0.0))) <= 0
    # a gentle sea draws no warning (pytest turns warnings into errors)
    gentle = sample_waves(jax.random.key(0), Spectrum(hs=0.3, tp=8.0, gamma=1.0, theta_mean=0.0, s_max=10.0), 60)
    assert float(gentle.total_steepness) < 1
