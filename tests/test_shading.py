"""Tests for jaxocean.shading: reference values, physics (reciprocity, energy, glitter),
the lighting-linear decomposition, gradients at the domain edges, and input errors."""

import math

import hypothesis.strategies as st
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import example, given
from jax.test_util import check_grads

from jaxocean import shading
from jaxocean.errors import InvalidValueError
from jaxocean.shading import (
    MIN_COSINE,
    MIN_SLOPE_VARIANCE,
    MIN_SLOPE_VARIANCE_AXIS,
    Lighting,
    erfc_approx,
    inverse_tonemap,
    make_lighting,
    mean_fresnel,
    ocean_brdf,
    projected_variance,
    shade_components,
    shade_pixel,
    sky_pixel,
    sky_radiance,
    smith_lambda,
    sun_direction,
    sun_radiance_factor,
    tangent_frame,
    tonemap,
)

UP = (0.0, 0.0, 1.0)

# Jitted entry points: one compilation per test graph instead of eager dispatch (and
# compilation) of every primitive. Validation is tested on the eager functions below.
shade_pixel_jit = jax.jit(shade_pixel)
shade_components_jit = jax.jit(shade_components)
ocean_brdf_jit = jax.jit(ocean_brdf)
sun_radiance_factor_jit = jax.jit(sun_radiance_factor)
erfc_approx_jit = jax.jit(erfc_approx)
smith_lambda_jit = jax.jit(smith_lambda)
mean_fresnel_jit = jax.jit(mean_fresnel)
tangent_frame_jit = jax.jit(tangent_frame)
projected_variance_jit = jax.jit(projected_variance)
tonemap_jit = jax.jit(tonemap, static_argnames="mode")
inverse_tonemap_jit = jax.jit(inverse_tonemap, static_argnames="mode")


def direction(azimuth, elevation):
    """Unit vector from azimuth / elevation (numpy, independent of the library)."""
    azimuth, elevation = np.broadcast_arrays(np.asarray(azimuth, float), np.asarray(elevation, float))
    return np.stack([np.cos(elevation) * np.cos(azimuth), np.cos(elevation) * np.sin(azimuth),
                     np.sin(elevation)], axis=-1)


def random_unit_vectors(rng, n, min_z):
    """Random unit vectors with z >= min_z."""
    v = rng.normal(size=(n, 3))
    v[:, 2] = np.abs(v[:, 2]) + min_z * np.linalg.norm(v, axis=1) * 2
    v /= np.linalg.norm(v, axis=1, keepdims=True)
    assert (v[:, 2] >= min_z).all()
    return v


# --------------------------------------------------------------------------- reference values


def test_erfc_approx_against_exact_erfc(x64):
    x = np.linspace(0.0, 5.0, 50001)
    exact = np.array([math.erfc(v) for v in x])
    error = np.abs(np.asarray(erfc_approx_jit(jnp.asarray(x))) - exact)
    # measured: max absolute error 2.16e-3 (near x = 0.18), relative error <= 0.28%
    assert error.max() < 2.2e-3
    assert (error / exact).max() < 3e-3
    # exact at 0, and the negative half-line by erfc(x) = 2 - erfc(-x)
    assert float(erfc_approx_jit(0.0)) == pytest.approx(1.0, abs=1e-15)
    xn = -x[::100]
    exact_n = np.array([math.erfc(v) for v in xn])
    assert np.abs(np.asarray(erfc_approx_jit(jnp.asarray(xn))) - exact_n).max() < 2.2e-3


def test_smith_lambda_limits_and_monotonicity(x64):
    c = jnp.linspace(MIN_COSINE, 1.0, 2001)
    for sigma2 in (1e-4, 1e-2, 0.3):
        lam = np.asarray(smith_lambda_jit(c, sigma2))
        assert np.isfinite(lam).all() and (lam >= 0).all()
        assert lam[-1] == pytest.approx(0.0, abs=1e-30)  # c = 1: v = inf
        assert np.all(np.diff(lam) <= 0)  # increasing as c decreases...
        assert lam[0] > lam[len(lam) // 2]  # ...strictly over the range
    # against Lambda with the exact erfc, where it is not vanishingly small
    c = np.linspace(0.05, 0.95, 91)
    for sigma2 in (1e-2, 0.1):
        v = c / np.sqrt(2 * sigma2 * (1 - c * c))
        exact = np.array([(math.exp(-t * t) - t * math.sqrt(math.pi) * math.erfc(t)) / (2 * t * math.sqrt(math.pi))
                          for t in v])
        np.testing.assert_allclose(np.asarray(smith_lambda_jit(c, sigma2)), exact, atol=1.5e-3 * (1 + exact.max()))
    # clamps: c below MIN_COSINE and sigma2 below the floor are clamped, not NaN
    assert float(smith_lambda_jit(0.0, 0.01)) == float(smith_lambda_jit(MIN_COSINE, 0.01))
    assert float(smith_lambda_jit(0.3, 0.0)) == float(smith_lambda_jit(0.3, MIN_SLOPE_VARIANCE_AXIS))


_smith_lambda_grad = jax.jit(jax.grad(smith_lambda, argnums=(0, 1)))


@pytest.mark.parametrize("cos_theta", [0.0, 0.3, 1.0 - 1e-12, 1.0])
@pytest.mark.parametrize("sigma2", [0.0, MIN_SLOPE_VARIANCE_AXIS, 0.05])
def test_smith_lambda_gradient_finite_at_edges(x64, cos_theta, sigma2):
    grads = _smith_lambda_grad(jnp.float64(cos_theta), jnp.float64(sigma2))
    assert all(np.isfinite(g) for g in grads)
    with jax.enable_x64(False):
        grads = _smith_lambda_grad(jnp.float32(cos_theta), jnp.float32(sigma2))
        assert all(np.isfinite(g) for g in grads)


def test_mean_fresnel_limits(x64):
    # normal incidence on a smooth sea: water's 0.02; grazing: total reflection
    assert float(mean_fresnel_jit(1.0, 0.0)) == pytest.approx(0.02, abs=1e-12)
    # (sigma^2 = 0 is clamped to 1e-5 per axis, which costs 0.4% at grazing)
    assert float(mean_fresnel_jit(0.0, 0.0)) == pytest.approx(1.0, abs=5e-3)
    c = jnp.linspace(0.0, 1.0, 101)
    f = np.asarray(mean_fresnel_jit(c, 0.01))
    assert np.all(np.diff(f) < 0) and (f >= 0.02).all() and (f <= 1).all()
    # roughness lowers the grazing reflectance (facets tilt towards the viewer)
    assert float(mean_fresnel_jit(0.0, 0.1)) < float(mean_fresnel_jit(0.0, 0.001))
    # the power (1 - c)^p is gradient-safe at c = 1, also for p < 1 (very rough)
    for sigma2 in (0.0, 0.01, 1.0):
        g = jax.grad(mean_fresnel, argnums=(0, 1))(1.0, sigma2)
        assert all(np.isfinite(x) for x in g)


def test_tangent_frame_is_right_handed_orthonormal(x64):
    rng = np.random.default_rng(0)
    n = np.concatenate([random_unit_vectors(rng, 50, 0.0), [[1.0, 0, 0], [-1.0, 0, 0], [0, 0, 1.0]]])
    t_x, t_y = map(np.asarray, tangent_frame_jit(jnp.asarray(n)))
    np.testing.assert_allclose(np.cross(t_x, t_y), n, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(t_x, axis=-1), 1, atol=1e-12)
    np.testing.assert_allclose(np.sum(t_x * n, -1), 0, atol=1e-12)
    flat_x, flat_y = tangent_frame_jit(jnp.asarray(UP))
    np.testing.assert_allclose(flat_x, [1, 0, 0])
    np.testing.assert_allclose(flat_y, [0, 1, 0])


def test_projected_variance_flat_sea(x64):
    # on a flat sea the tangent axes are world x, y: sigma2_V = sx cos^2(az) + sy sin^2(az)
    azimuth = np.linspace(0, 2 * np.pi, 13)
    v = direction(azimuth, 0.4)
    got = projected_variance_jit(jnp.asarray(v), jnp.asarray(UP), 0.02, 0.005)
    np.testing.assert_allclose(got, 0.02 * np.cos(azimuth) ** 2 + 0.005 * np.sin(azimuth) ** 2, rtol=1e-12)
    # straight down the normal the azimuth is undefined: the mean
    assert float(projected_variance_jit(jnp.asarray(UP), jnp.asarray(UP), 0.02, 0.005)) == pytest.approx(0.0125)


# --------------------------------------------------------------------------- shading model


def reference_mean_fresnel(cos_theta, sigma2):
    """Scalar transcription of Bruneton's mean Fresnel (sigma_V = sqrt of the variance)."""
    sigma = math.sqrt(sigma2)
    return 0.02 + 0.98 * (1 - cos_theta) ** (5 * math.exp(-2.69 * sigma)) / (1 + 22.7 * sigma**1.5)


def test_flat_sea_without_sun_is_fresnel_mix_of_sky_and_sea(x64):
    lighting = make_lighting(sun_color=(0.0, 0.0, 0.0), sky_color=(0.3, 0.5, 0.9), sea_color=(0.02, 0.05, 0.04))
    for azimuth, elevation in [(0.0, 1.5), (1.0, 0.6), (-2.0, 0.2), (3.0, 0.02)]:
        v = direction(azimuth, elevation)
        # sigma^2 = 0 is clamped to the floor on each axis
        pixel = np.asarray(shade_pixel_jit(jnp.asarray(UP), 0.0, 0.0, jnp.asarray(v), lighting))
        f = reference_mean_fresnel(math.sin(elevation), MIN_SLOPE_VARIANCE_AXIS)
        # the public F_mean itself (test_render builds its expected image from it)
        assert float(mean_fresnel_jit(math.sin(elevation), MIN_SLOPE_VARIANCE_AXIS)) == pytest.approx(f, rel=1e-12)
        np.testing.assert_allclose(pixel, f * np.array([0.3, 0.5, 0.9]) + (1 - f) * np.array([0.02, 0.05, 0.04]),
                                   rtol=1e-12)
    # an anisotropic flat sea: the projected variance enters F_mean
    v = direction(0.7, 0.1)
    pixel = np.asarray(shade_pixel_jit(jnp.asarray(UP), 0.04, 0.001, jnp.asarray(v), lighting))
    f = reference_mean_fresnel(math.sin(0.1), 0.04 * math.cos(0.7) ** 2 + 0.001 * math.sin(0.7) ** 2)
    np.testing.assert_allclose(pixel, f * np.array([0.3, 0.5, 0.9]) + (1 - f) * np.array([0.02, 0.05, 0.04]),
                               rtol=1e-12)


def test_sun_factor_matches_scalar_transcription(x64):
    """B_sun against an independent scalar transcription of Bruneton's formula."""
    n = np.array([0.1, -0.2, 1.0])
    n /= np.linalg.norm(n)
    v = direction(2.9, 0.5)
    tilted = n + np.array([0.05, 0.03, 0.0])  # the facet that mirrors the sun into the view
    tilted /= np.linalg.norm(tilted)
    light = 2 * (v @ tilted) * tilted - v
    sx, sy = 0.02, 0.008
    # frame, half vector, slopes
    tx = np.array([1.0, 0, 0]) - n[0] * n
    tx /= np.linalg.norm(tx)
    ty = np.cross(n, tx)
    h = (v + light) / np.linalg.norm(v + light)
    zx, zy = h @ tx / (h @ n), h @ ty / (h @ n)
    p = math.exp(-0.5 * (zx**2 / sx + zy**2 / sy)) / (2 * math.pi * math.sqrt(sx * sy))
    fresnel = 0.02 + 0.98 * (1 - v @ h) ** 5

    def lam(d):
        c = d @ n
        s2 = (sx * (d @ tx) ** 2 + sy * (d @ ty) ** 2) / ((d @ tx) ** 2 + (d @ ty) ** 2)
        nu = c / math.sqrt(2 * s2 * (1 - c * c))
        erfc = 2 * math.exp(-nu * nu) / (2.319 * nu + math.sqrt(4 + 1.52 * nu * nu))
        return max(0.0, (math.exp(-nu * nu) - nu * math.sqrt(math.pi) * erfc) / (2 * nu * math.sqrt(math.pi)))

    expected = fresnel * p / (4 * (v @ n) * (h @ n) ** 4 * (1 + lam(light) + lam(v)))
    assert expected > 1e-3  # a point inside the glitter lobe, not a trivial zero
    got = sun_radiance_factor_jit(jnp.asarray(n), sx, sy, jnp.asarray(v), jnp.asarray(light))
    assert float(got) == pytest.approx(expected, rel=1e-10)


def test_brdf_reciprocity(x64):
    rng = np.random.default_rng(1)
    n_samples = 400
    normals = random_unit_vectors(rng, n_samples, 0.6)
    sx = 10 ** rng.uniform(-4, -1, n_samples)
    sy = 10 ** rng.uniform(-4, -1, n_samples)
    views = random_unit_vectors(rng, n_samples, 0.05)
    # half the lights at random, half mirrored about half vectors inside the slope lobe
    t_x, t_y = map(np.asarray, tangent_frame_jit(jnp.asarray(normals)))
    zeta = rng.normal(size=(n_samples, 2)) * np.sqrt(np.stack([sx, sy], -1))
    half = normals + zeta[:, :1] * t_x + zeta[:, 1:] * t_y
    half /= np.linalg.norm(half, axis=-1, keepdims=True)
    lights = 2 * np.sum(views * half, -1, keepdims=True) * half - views
    lights[::2] = random_unit_vectors(rng, n_samples // 2, 0.05)
    keep = (lights[:, 2] > 0.05) & (np.sum(lights * normals, -1) > 0)
    normals, sx, sy, views, lights = normals[keep], sx[keep], sy[keep], views[keep], lights[keep]
    forward = np.asarray(ocean_brdf_jit(normals, sx, sy, views, lights))
    backward = np.asarray(ocean_brdf_jit(normals, sx, sy, lights, views))
    assert (forward > 1e-2).sum() > 100  # many samples inside the lobes
    np.testing.assert_allclose(forward, backward, rtol=1e-12, atol=1e-300)
    # B_sun = rho * z_L above the horizon fade
    b = np.asarray(sun_radiance_factor_jit(normals, sx, sy, views, lights))
    z_light = np.maximum(np.sum(lights * normals, -1), MIN_COSINE)
    fade_done = lights[:, 2] >= shading.SUN_HORIZON_FADE
    np.testing.assert_allclose(b[fade_done], (forward * z_light)[fade_done], rtol=1e-12, atol=1e-300)


def _directional_albedo(view, sigma2_x, sigma2_y):
    """Integral of rho(L, V) cos(theta_L) over the hemisphere of L, for a flat sea (N = +z).

    Quadrature over the half-vector slopes zeta on a +-8 sigma grid, which follows the lobe
    however narrow: H = normalize(zeta_x, zeta_y, 1), d omega_H = (H.N)^3 d zeta and
    d omega_L = 4 (V.H) d omega_H. Also returns the integral of the slope pdf (should be 1).
    """
    n = 301
    unit = jnp.linspace(-8.0, 8.0, n)
    zeta_x, zeta_y = jnp.meshgrid(unit * jnp.sqrt(sigma2_x), unit * jnp.sqrt(sigma2_y), indexing="ij")
    d_area = (unit[1] - unit[0]) ** 2 * jnp.sqrt(sigma2_x * sigma2_y)
    half = jnp.stack([zeta_x, zeta_y, jnp.ones_like(zeta_x)], -1)
    half = half / jnp.linalg.norm(half, axis=-1, keepdims=True)
    v_h = half @ view
    light = 2 * v_h[..., None] * half - view
    rho = ocean_brdf(jnp.asarray(UP), sigma2_x, sigma2_y, view, light)
    valid = (light[..., 2] > 0) & (v_h > 0)
    albedo = jnp.sum(jnp.where(valid, rho * light[..., 2] * 4 * v_h * half[..., 2] ** 3, 0.0)) * d_area
    pdf = jnp.exp(-0.5 * (zeta_x**2 / sigma2_x + zeta_y**2 / sigma2_y)) / (2 * jnp.pi * jnp.sqrt(sigma2_x * sigma2_y))
    return albedo, jnp.sum(pdf) * d_area


def test_energy_conservation(x64):
    views = jnp.asarray(direction(np.array([0.0, 1.0] * 5), np.repeat([0.02, 0.1, 0.3, 0.7, 1.5], 2)))
    albedo_of = jax.jit(jax.vmap(_directional_albedo, in_axes=(0, None, None)))
    maxima = {}
    for sigma2 in (1e-3, 1e-2, 0.1):
        for sigma2_x, sigma2_y in ((sigma2, sigma2), (sigma2, 0.3 * sigma2), (0.3 * sigma2, sigma2)):
            albedo, pdf_mass = map(np.asarray, albedo_of(views, jnp.float64(sigma2_x), jnp.float64(sigma2_y)))
            np.testing.assert_allclose(pdf_mass, 1.0, atol=1e-6)  # the quadrature resolves the lobe
            assert (albedo <= 1.0).all() and (albedo > 0).all()
            # near-normal views reflect water's normal-incidence Fresnel, 0.02
            np.testing.assert_allclose(albedo[-2:], 0.02, atol=1e-3)
            maxima[(sigma2_x, sigma2_y)] = albedo.max()
    # measured maximum ~0.77 (grazing view, sigma2 = (3e-4, 1e-3)); all well below 1
    assert max(maxima.values()) < 0.8


def test_glitter_peaks_at_the_mirror_direction(x64):
    azimuth, elevation = np.meshgrid(np.linspace(-np.pi, np.pi, 721), np.linspace(0.02, 1.55, 154), indexing="ij")
    views = jnp.asarray(direction(azimuth, elevation))

    def brightest(sun_azimuth, sun_elevation):
        light = jnp.asarray(direction(sun_azimuth, sun_elevation))
        b = np.asarray(sun_radiance_factor_jit(jnp.asarray(UP), 1e-4, 1e-4, views, light))
        i = np.unravel_index(np.argmax(b), b.shape)
        return azimuth[i], elevation[i]

    for sun_az, sun_el in [(0.5, 0.6), (2.0, 0.3), (-1.2, 1.0)]:
        az, el = brightest(sun_az, sun_el)
        mirror_az = (sun_az + np.pi + np.pi) % (2 * np.pi) - np.pi
        assert abs((az - mirror_az + np.pi) % (2 * np.pi) - np.pi) < 0.02
        assert abs(el - sun_el) < 0.02


def test_sun_below_horizon_gives_no_glitter(x64):
    views = jnp.asarray(direction(np.linspace(-3, 3, 50), 0.3))
    for elevation in (0.0, -0.001, -0.5):
        light = jnp.asarray(direction(1.0, elevation))
        assert np.all(np.asarray(sun_radiance_factor_jit(jnp.asarray(UP), 0.01, 0.01, views, light)) == 0)
    light = jnp.asarray(direction(1.0, 0.05))
    assert np.asarray(sun_radiance_factor_jit(jnp.asarray(UP), 0.01, 0.01, views, light)).max() > 0


def _random_pixels(rng, n):
    normals = random_unit_vectors(rng, n, 0.7)
    views = random_unit_vectors(rng, n, 0.05)
    return normals, 10 ** rng.uniform(-4, -1, n), 10 ** rng.uniform(-4, -1, n), views


def test_image_is_linear_in_the_colours(x64):
    rng = np.random.default_rng(2)
    normals, sx, sy, views = _random_pixels(rng, 100)
    lighting = make_lighting(sun_azimuth=2.0, sun_elevation=0.4)
    for horizon_gradient in (0.0, 0.7):
        def shade(light, g=jnp.float64(horizon_gradient)):
            return (shade_components_jit(normals, sx, sy, views, light, horizon_gradient=g),
                    np.asarray(shade_pixel_jit(normals, sx, sy, views, light, horizon_gradient=g)))

        terms, image = shade(lighting)
        f = np.asarray(terms.fresnel)[:, None]
        np.testing.assert_allclose(
            image,
            np.asarray(terms.sun)[:, None] * np.asarray(lighting.sun_color) + f * np.asarray(terms.reflected)
            + (1 - f) * np.asarray(lighting.sea_color),
            rtol=1e-12)
        # doubling the sky adds exactly F_mean * sky(R)
        _, image2 = shade(lighting._replace(sky_color=2 * lighting.sky_color))
        np.testing.assert_allclose(image2 - image, f * np.asarray(terms.reflected), rtol=1e-9, atol=1e-15)
        # F_mean does not depend on the lighting; B_sun not on the colours
        terms2, _ = shade(make_lighting(sun_azimuth=-1.0, sun_elevation=1.2, sun_color=(1, 2, 3), sky_color=(3, 2, 1)))
        np.testing.assert_array_equal(terms2.fresnel, terms.fresnel)
        terms3, _ = shade(lighting._replace(sun_color=jnp.asarray([1.0, 2.0, 3.0]), sea_color=jnp.zeros(3)))
        np.testing.assert_array_equal(terms3.sun, terms.sun)


def test_sky_radiance_gradient_formula(x64):
    lighting = make_lighting(sky_color=(0.2, 0.4, 0.8))
    d = jnp.asarray(direction(0.3, np.array([np.pi / 2, 0.5, 0.0, -0.3])))
    np.testing.assert_allclose(sky_radiance(d, lighting), np.tile([0.2, 0.4, 0.8], (4, 1)))
    weight = 1 + 0.5 * (1 - np.clip(np.sin([np.pi / 2, 0.5, 0.0, -0.3]), 0, 1))
    np.testing.assert_allclose(sky_radiance(d, lighting, horizon_gradient=0.5),
                               weight[:, None] * np.array([0.2, 0.4, 0.8]), rtol=1e-12)
    np.testing.assert_array_equal(sky_pixel(d, lighting, horizon_gradient=0.5),
                                  sky_radiance(d, lighting, horizon_gradient=0.5))
    with pytest.raises(InvalidValueError, match="horizon_gradient"):
        sky_radiance(d, lighting, horizon_gradient=-2.0)


def test_dtypes_jit_and_vmap():
    rng = np.random.default_rng(3)
    normals, sx, sy, views = (jnp.asarray(a, jnp.float32) for a in _random_pixels(rng, 64))
    lighting = make_lighting()
    image = shade_pixel_jit(normals, sx, sy, views, lighting)
    assert image.dtype == jnp.float32 and image.shape == (64, 3)
    # a batch of lightings (the lighting fit's coarse grid) comes from vmap
    elevations = jnp.linspace(0.1, 1.2, 5)
    batch = jax.vmap(lambda el: lighting._replace(sun_elevation=el))(elevations)
    images = jax.jit(jax.vmap(shade_pixel, in_axes=(None, None, None, None, 0)))(normals, sx, sy, views, batch)
    assert images.shape == (5, 64, 3) and images.dtype == jnp.float32
    np.testing.assert_allclose(images[2], shade_pixel_jit(normals, sx, sy, views, lighting._replace(
        sun_elevation=elevations[2])), rtol=1e-5)
    # and 64-bit under x64 (colour inputs stay (3,), pixels broadcast)
    with jax.enable_x64(True):
        lighting64 = make_lighting()
        assert lighting64.sun_color.dtype == jnp.float64
        assert shade_pixel_jit(*(jnp.asarray(a, jnp.float64) for a in (normals, sx, sy, views)),
                               lighting64).dtype == jnp.float64


def test_default_scene_tonemaps_to_mid_range():
    lighting = make_lighting()
    # a flat sea seen 0.2 rad below the horizon, all around (same shapes as above: one compile)
    views = jnp.asarray(direction(np.linspace(-np.pi, np.pi, 64), 0.2), jnp.float32)
    normals = jnp.broadcast_to(jnp.asarray(UP, jnp.float32), views.shape)
    roughness = jnp.full(64, 0.01, jnp.float32)
    display = np.asarray(tonemap_jit(shade_pixel_jit(normals, roughness, roughness, views, lighting)))
    sky = np.asarray(tonemap_jit(sky_pixel(jnp.asarray(UP, jnp.float32), lighting)))
    assert 0.05 < np.median(display) < 0.6 and display.max() > 0.8  # dim sea, saturating glitter
    assert 0.3 < sky.mean() < 0.8 and sky[2] > sky[0]  # a blue sky, mid-range
    np.testing.assert_allclose(np.linalg.norm(sun_direction(lighting)), 1, rtol=1e-6)


# --------------------------------------------------------------------------- tone mapping


def test_tonemap_curves(x64):
    x = jnp.asarray([0.0, 0.5, 1.0, 2.0, 10.0])
    expected = [0.0, (0.38317 * 0.5) ** (1 / 2.2), (0.38317) ** (1 / 2.2), 1 - math.exp(-2), 1 - math.exp(-10)]
    np.testing.assert_allclose(tonemap_jit(x), expected, rtol=1e-12)
    np.testing.assert_allclose(tonemap_jit(x, exposure=2.0), tonemap_jit(2 * x), rtol=1e-12)
    np.testing.assert_allclose(tonemap_jit(jnp.asarray([0.001, 0.5, 2.0]), mode="srgb"),
                               [0.01292, 1.055 * 0.5 ** (1 / 2.4) - 0.055, 1.0], rtol=1e-12)
    np.testing.assert_allclose(tonemap_jit(jnp.asarray([-1.0, 0.5, 2.0]), mode="linear"), [0, 0.5, 1])
    values = np.asarray(tonemap_jit(jnp.linspace(-1, 100, 1001)))
    assert (values >= 0).all() and (values <= 1).all() and np.all(np.diff(values) >= -1e-4)


@pytest.mark.parametrize("mode", ["bruneton", "srgb", "linear"])
def test_inverse_tonemap_round_trip(x64, mode):
    # exposed radiance up to 6 (Bruneton: display 0.9975, below the saturation clip)
    radiance = jnp.linspace(0.0, 0.45 if mode != "bruneton" else 3.0, 301)
    # Bruneton's two pieces miss each other by 3e-5 at the knee L = 1.413: skip that sliver
    radiance = radiance[jnp.abs(radiance - 1.413) > 1e-3]
    back = inverse_tonemap_jit(tonemap_jit(radiance, exposure=2.0, mode=mode), exposure=2.0, mode=mode)
    np.testing.assert_allclose(back, radiance, rtol=1e-9, atol=1e-12)
    assert np.isfinite(np.asarray(inverse_tonemap_jit(jnp.asarray([0.0, 1.0, 2.0]), mode=mode))).all()
    g = jax.grad(lambda y: inverse_tonemap_jit(y, mode=mode).sum())(jnp.asarray([0.0, 0.5, 1.0]))
    assert np.isfinite(np.asarray(g)).all()
    with pytest.raises(InvalidValueError, match="finite"):
        inverse_tonemap(jnp.asarray([0.2, np.nan]), mode=mode)


def test_tonemap_gradient_safe_at_zero(x64):
    for mode in ("bruneton", "srgb", "linear"):
        g = jax.grad(lambda x, m=mode: tonemap_jit(x, mode=m).sum())(jnp.asarray([0.0, -1.0, 1e-30, 1.413]))
        assert np.isfinite(np.asarray(g)).all()
    with jax.enable_x64(False):
        g = jax.grad(lambda x: tonemap_jit(x).sum())(jnp.asarray([0.0, 1e-30, 0.3], jnp.float32))
        assert np.isfinite(np.asarray(g)).all()


# --------------------------------------------------------------------------- gradients


GRAD_TOL = dict(order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-5, rtol=1e-5)


@jax.jit
def _shade_masked(args, base, mask):
    """``shade_pixel`` at ``base + mask * (args - base)``.

    ``check_grads`` on ``args`` then probes only the inputs where ``mask`` is 1, and every
    mask shares one compilation (the mask is data, not a change of the traced function).
    """
    normal, sigma2_x, sigma2_y, view, lighting, horizon_gradient = jax.tree.map(
        lambda a, b, m: b + m * (a - b), args, base, mask)
    return shade_pixel(normal, sigma2_x, sigma2_y, view, lighting, horizon_gradient=horizon_gradient)


def test_check_grads_shade_pixel(x64):
    normal = jnp.asarray([0.08, -0.05, 1.0])
    normal = normal / jnp.linalg.norm(normal)
    view = jnp.asarray(direction(3.3, 0.55))
    sx, sy = jnp.float64(0.02), jnp.float64(0.012)
    lighting = make_lighting(sun_azimuth=0.2, sun_elevation=0.5, sun_color=(2.0, 1.8, 1.5))
    assert float(shade_components_jit(normal, sx, sy, view, lighting).sun) > 0.01  # inside the glitter lobe
    setting = lighting._replace(sun_elevation=jnp.float64(0.004))  # inside the horizon fade
    for args in [(normal, sx, sy, view, lighting, jnp.float64(0.5)),
                 (normal, sx, sy, view, setting, jnp.float64(0.0))]:
        leaves, treedef = jax.tree.flatten(args)
        # all inputs at once, then one leaf at a time (so that a small wrong partial cannot
        # hide behind a large one): normal, sigma2_x, sigma2_y, view, the five Lighting
        # leaves and horizon_gradient
        masks = [[jnp.ones_like(leaf) for leaf in leaves]]
        masks += [[jnp.ones_like(leaf) if j == i else jnp.zeros_like(leaf) for j, leaf in enumerate(leaves)]
                  for i in range(len(leaves))]
        for mask in masks:
            mask = jax.tree.unflatten(treedef, mask)
            check_grads(lambda a, m=mask, b=args: _shade_masked(a, b, m), (args,), **GRAD_TOL)


def test_check_grads_tonemap(x64):
    x = jnp.asarray([0.01, 0.3, 1.0, 1.6, 4.0])
    for mode in ("bruneton", "srgb"):
        check_grads(lambda y, m=mode: tonemap_jit(y, exposure=0.2, mode=m), (x,), **GRAD_TOL)
        check_grads(lambda e, m=mode: tonemap_jit(x, exposure=e, mode=m), (jnp.asarray(0.2),), **GRAD_TOL)
    check_grads(lambda y: inverse_tonemap_jit(y), (jnp.asarray([0.05, 0.4, 0.9]),), **GRAD_TOL)


@jax.jit
def _value_and_grads(normal, sigma2_x, sigma2_y, view, lighting):
    def loss(*args):
        return jnp.sum(tonemap_jit(shade_pixel(*args)))

    return loss(normal, sigma2_x, sigma2_y, view, lighting), jax.grad(loss, argnums=(0, 1, 2, 3, 4))(
        normal, sigma2_x, sigma2_y, view, lighting)


edge_normals = st.sampled_from([UP, (1.0, 0.0, 0.0), (-1.0, 0.0, 0.0), (0.0, 1.0, 0.0),
                                (1.0, 0.0, 1e-7), (0.3, -0.2, 0.93), (0.0, 0.0, -1.0)])
edge_variances = st.sampled_from([0.0, -1e-3, 1e-7, MIN_SLOPE_VARIANCE_AXIS, 1e-3, 0.2, 2.0])
edge_view_z = st.sampled_from([0.0, 1e-7, 1e-3, 0.01, 0.3, 1.0])
edge_elevations = st.sampled_from([0.0, -1e-6, -0.01, 1e-6, 0.005, 0.6, np.pi / 2, -np.pi / 2])


def _check_finite_at(dtype, normal, sx, sy, view_z, view_az, sun_el, sun_az):
    view = jnp.asarray([math.sqrt(1 - view_z**2) * math.cos(view_az),
                        math.sqrt(1 - view_z**2) * math.sin(view_az), view_z], dtype)
    lighting = make_lighting(sun_azimuth=sun_az, sun_elevation=sun_el, dtype=dtype)
    value, grads = _value_and_grads(jnp.asarray(normal, dtype), jnp.asarray(sx, dtype), jnp.asarray(sy, dtype),
                                    view, lighting)
    assert np.isfinite(value)
    for leaf in jax.tree_util.tree_leaves(grads):
        assert leaf.dtype == dtype
        assert np.isfinite(np.asarray(leaf)).all()


def edge_case(test):
    # explicit examples first: V = N = +z with the sun at the zenith (projected variance
    # falls back to the mean, H = N, a mirror glint at zero roughness), and a grazing view
    # over a vertical facet with the sun exactly on the horizon
    test = example(normal=UP, sx=0.0, sy=0.0, view_z=1.0, view_az=0.0, sun_el=np.pi / 2, sun_az=0.0)(test)
    test = example(normal=(1.0, 0.0, 0.0), sx=0.0, sy=1e-3, view_z=0.0, view_az=0.0, sun_el=0.0, sun_az=0.0)(test)
    return given(normal=edge_normals, sx=edge_variances, sy=edge_variances, view_z=edge_view_z,
                 view_az=st.floats(-np.pi, np.pi), sun_el=edge_elevations, sun_az=st.floats(-np.pi, np.pi))(test)


@edge_case
def test_values_and_gradients_finite_at_domain_edges_float32(normal, sx, sy, view_z, view_az, sun_el, sun_az):
    _check_finite_at(jnp.float32, normal, sx, sy, view_z, view_az, sun_el, sun_az)


@edge_case
def test_values_and_gradients_finite_at_domain_edges_float64(x64, normal, sx, sy, view_z, view_az, sun_el, sun_az):
    _check_finite_at(jnp.float64, normal, sx, sy, view_z, view_az, sun_el, sun_az)


# --------------------------------------------------------------------------- bad input


def test_bad_lighting_is_rejected_with_the_value():
    with pytest.raises(InvalidValueError, match=r"sun_color must be >= 0.*-1\.0"):
        make_lighting(sun_color=(-1.0, 1.0, 1.0))
    with pytest.raises(InvalidValueError, match=r"sky_color must be finite.*nan"):
        make_lighting(sky_color=(0.1, float("nan"), 0.3))
    with pytest.raises(ValueError, match=r"sea_color.*shape \(3,\).*\(2,\)"):
        make_lighting(sea_color=(0.1, 0.2))
    with pytest.raises(InvalidValueError, match=r"sun_elevation.*2\.0"):
        make_lighting(sun_elevation=2.0)
    with pytest.raises(ValueError, match="scalar angle"):
        make_lighting(sun_azimuth=(0.1, 0.2))
    with pytest.raises(ValueError, match="floating point"):
        shading.validate_lighting(Lighting(0.5, 0.6, jnp.ones(3, jnp.int32), jnp.ones(3), jnp.ones(3)))
    with pytest.raises(ValueError, match="Lighting"):
        shading.validate_lighting((0.5, 0.6, jnp.ones(3), jnp.ones(3), jnp.ones(3)))
    # the public shading entry points validate too (eagerly)
    bad = make_lighting()._replace(sea_color=jnp.asarray([0.1, -0.5, 0.1]))
    with pytest.raises(InvalidValueError, match=r"sea_color.*-0\.5"):
        shade_pixel(jnp.asarray(UP), 0.01, 0.01, jnp.asarray(UP), bad)
    with pytest.raises(ValueError, match=r"view must have shape \(\.\.\., 3\)"):
        shade_pixel(jnp.asarray(UP), 0.01, 0.01, jnp.ones((4, 2)), make_lighting())


def test_bad_tonemap_arguments():
    with pytest.raises(ValueError, match=r"unknown tone-map mode 'aces'.*bruneton"):
        tonemap(jnp.ones(3), mode="aces")
    with pytest.raises(ValueError, match="'gamma'"):
        inverse_tonemap(jnp.ones(3), mode="gamma")
    with pytest.raises(InvalidValueError, match=r"exposure must be > 0.*-1\.0"):
        tonemap(jnp.ones(3), exposure=-1.0)


def test_public_names():
    # clamping each axis at the per-axis floor is what keeps the scalar roughness at its floor
    assert MIN_SLOPE_VARIANCE == 2 * MIN_SLOPE_VARIANCE_AXIS
    for name in shading.__all__:
        assert hasattr(shading, name), name


def test_check_unit_normals_rejects_nan_outside_where():
    n = np.zeros((2, 2, 3))
    n[..., 2] = 1.0
    n[0, 1] = np.nan
    with pytest.raises(InvalidValueError, match=r"1 of 4 are not \(\|n\| from 1 to 1, 1 NaN/inf\)"):
        shading.check_unit_normals(n, "normals")
    with pytest.raises(InvalidValueError, match=r"all NaN/inf"):
        shading.check_unit_normals(np.full((2, 3), np.nan), "normals")
    shading.check_unit_normals(n, "normals", where=np.isfinite(n).all(-1))  # NaN as "no data": left out
