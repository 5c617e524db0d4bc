"""Ocean shading: the Bruneton 2010 ocean BRDF, per pixel, in linear RGB.

Protocol
--------
Inputs are per-pixel geometry and one :class:`Lighting`; outputs are linear radiance.

* ``normal``  ``(..., 3)`` unit macro-surface normal of the pixel (world frame).
* ``sigma2_x``, ``sigma2_y``  ``(...)`` sub-pixel slope variances along the tangent axes
  ``T_x``, ``T_y`` of :func:`tangent_frame` (dimensionless). Each is clamped at
  ``MIN_SLOPE_VARIANCE_AXIS`` so that the roughness ``sigma2_x + sigma2_y`` is at least
  ``MIN_SLOPE_VARIANCE`` (docs/design.md, *Slope variance*): a perfectly flat, unfiltered sea is a very
  narrow lobe, never a Dirac, and every term stays finite.
* ``view``  ``(..., 3)`` unit vector from the surface point towards the camera.
* ``light`` ``(..., 3)`` unit vector from the surface point towards the sun
  (:func:`sun_direction`).
* ``Lighting``  scalar angles (radians) and three ``(3,)`` linear RGB colours; a batch of
  lightings comes from ``vmap``.

Conventions: world frame with z up, x east, y north; azimuths are measured from +x
counter-clockwise, elevations from the horizontal plane upwards. Every direction vector
points *away* from the surface point.

Every function is elementwise over the leading axes ``(...)`` (arguments broadcast),
jittable and vmappable, float32 by default and float64 under ``jax_enable_x64``. Values and
gradients are finite over the whole valid domain -- flat sea, zero roughness, grazing views,
the sun on or below the horizon, a normal parallel to +x -- by clamping and the double-
``where`` pattern (docs/design.md, *Gradient safety*).

The image model (Bruneton, Neyret & Holzschuch 2010, "Real-time realistic ocean lighting
using seamless transitions from geometry to BRDF")::

    image = sun_color * B_sun + F_mean * sky(R) + (1 - F_mean) * sea_color

* ``B_sun`` (:func:`sun_radiance_factor`) is the sun's glitter: the BRDF times the
  cosine of the sun, so that ``sun_color`` is the sun's irradiance on a plane facing it.
* ``F_mean`` (:func:`mean_fresnel`) is the roughness-averaged Fresnel reflectance of the
  view direction and ``R = 2 (N.V) N - V`` the mirror direction: the reflected sky.
* ``(1 - F_mean) * sea_color`` is the light refracted out of the water.

The image is linear in the three colours and ``F_mean`` does not depend on the lighting at
all; :func:`shade_components` returns the three terms so that a lighting fit can solve the
colours in closed form (docs/design.md, *Inverse methods*), and :func:`shade_pixel` is that decomposition
composed -- one implementation of the physics.

Display: :func:`tonemap` maps linear radiance to display values in [0, 1]
(Bruneton's curve, sRGB, or a plain clip) and :func:`inverse_tonemap` undoes it where the
curve is invertible, to bring 8-bit images back to linear radiance. A gray image is the
luminance of the RGB model, with the Rec. 709 weights :data:`LUMINANCE`.
"""

from __future__ import annotations

import math
from typing import NamedTuple

import jax.numpy as jnp
import numpy as np

from jaxocean._math import components, dot_last, inv_sqrt, materialize, smoothstep, tiny
from jaxocean.errors import InvalidValueError, check_values, is_concrete

__all__ = [
    "MIN_SLOPE_VARIANCE",
    "MIN_SLOPE_VARIANCE_AXIS",
    "UNIT_NORMAL_TOLERANCE",
    "MIN_COSINE",
    "SUN_HORIZON_FADE",
    "FRESNEL_NORMAL",
    "DEFAULT_SUN_AZIMUTH",
    "DEFAULT_SUN_ELEVATION",
    "DEFAULT_SUN_COLOR",
    "DEFAULT_SKY_COLOR",
    "DEFAULT_SEA_COLOR",
    "LUMINANCE",
    "TONEMAP_MODES",
    "Lighting",
    "ShadingTerms",
    "make_lighting",
    "validate_lighting",
    "check_horizon_gradient",
    "check_unit_normals",
    "sun_direction",
    "reflect",
    "erfc_approx",
    "smith_lambda",
    "tangent_frame",
    "projected_variance",
    "ocean_brdf",
    "sun_radiance_factor",
    "mean_fresnel",
    "sky_radiance",
    "sky_weight",
    "sky_pixel",
    "shade_components",
    "pixel_terms",
    "shade_pixel",
    "tonemap",
    "inverse_tonemap",
]

MIN_SLOPE_VARIANCE = 2e-5
"""Floor of the scalar roughness sigma^2 = sigma_x^2 + sigma_y^2 (docs/design.md, *Slope variance*)."""

MIN_SLOPE_VARIANCE_AXIS = 0.5 * MIN_SLOPE_VARIANCE
UNIT_NORMAL_TOLERANCE = 1e-2
"""How far from 1 the length of a normal given to the public functions may be: float32 and
half-float storage (relative 5e-4) pass; anything else is not a unit normal."""
"""Floor of each axis' slope variance; it makes the scalar floor hold."""

MIN_COSINE = 0.01
"""Bruneton's floor ``z = max(cos, 0.01)`` for the cosines in the BRDF denominator."""

SUN_HORIZON_FADE = 0.01
"""The sun's glitter fades out smoothly as ``L_z`` goes from this value to 0: about the
sun disk's angular diameter (0.0093 rad) setting below the horizon."""

FRESNEL_NORMAL = 0.02
"""Fresnel reflectance of water at normal incidence (refractive index 1.33)."""

# Smith's v = cot(theta) / (sqrt(2) sigma) is capped here: Lambda(8) ~ 1e-31 is 0 for any
# purpose, and the cap keeps v finite where cos(theta) -> 1 (v -> infinity).
_SMITH_V_MAX = 8.0

_SQRT_PI = math.sqrt(math.pi)

# Bruneton's tone map: (a L)^(1/2.2) below the knee, 1 - exp(-L) above; at the knee the two
# pieces have the same slope and values 3.4e-5 apart (his constants, kept as published).
_BRUNETON_SCALE = 0.38317
_BRUNETON_KNEE = 1.413
_BRUNETON_GAMMA = 2.2
_BRUNETON_KNEE_DISPLAY = 1.0 - math.exp(-_BRUNETON_KNEE)
# 1 - exp(-L) reaches 1 only at L = infinity: display values above this are "saturated" and
# invert to the finite lower bound -log(2^-10) ~ 6.93 of the radiance.
_BRUNETON_MAX_DISPLAY = 1.0 - 2.0**-10

# sRGB opto-electronic transfer function (IEC 61966-2-1).
_SRGB_LINEAR_LIMIT = 0.0031308
_SRGB_DISPLAY_LIMIT = 0.04045
_SRGB_SLOPE = 12.92
_SRGB_GAMMA = 2.4

# Defaults: a clear mid-morning sky. The sun's irradiance is about ten times pi times the
# sky radiance (a typical clear-sky ratio) and the sea's upwelling radiance is dark
# blue-green; with the Bruneton tone map at exposure 1 the sky reflection lands in the middle
# of the display range and sun glitter saturates only near the mirror direction.
DEFAULT_SUN_AZIMUTH = 0.5
DEFAULT_SUN_ELEVATION = 0.6
DEFAULT_SUN_COLOR = (20.0, 18.0, 15.0)
DEFAULT_SKY_COLOR = (0.35, 0.55, 0.9)
DEFAULT_SEA_COLOR = (0.01, 0.04, 0.06)

LUMINANCE = (0.2126, 0.7152, 0.0722)
"""Rec. 709 weights of linear RGB: the library models a gray image as the luminance
``LUMINANCE . RGB`` of the RGB image model (:func:`jaxocean.radiometry.luminance`,
:mod:`jaxocean.fit.photometric`, the gray geometry network of :mod:`jaxocean.nn.geometry`)."""


# --------------------------------------------------------------------------- lighting


class Lighting(NamedTuple):
    """Sun, sky and sea lighting of a scene (a registered pytree).

    * ``sun_azimuth``   [rad] from +x counter-clockwise, shape ``()``.
    * ``sun_elevation`` [rad] above the horizon, in [-pi/2, pi/2], shape ``()``.
    * ``sun_color``     ``(3,)`` linear RGB irradiance of the sun on a plane facing it.
    * ``sky_color``     ``(3,)`` linear RGB sky radiance at the zenith.
    * ``sea_color``     ``(3,)`` linear RGB radiance refracted out of the water.

    The paper's ``Dsun = [x, y]`` is this azimuth / elevation pair.
    """

    sun_azimuth: jnp.ndarray
    sun_elevation: jnp.ndarray
    sun_color: jnp.ndarray
    sky_color: jnp.ndarray
    sea_color: jnp.ndarray


_COLOR_FIELDS = ("sun_color", "sky_color", "sea_color")
_ANGLE_FIELDS = ("sun_azimuth", "sun_elevation")


def make_lighting(
    sun_azimuth=DEFAULT_SUN_AZIMUTH,
    sun_elevation=DEFAULT_SUN_ELEVATION,
    sun_color=DEFAULT_SUN_COLOR,
    sky_color=DEFAULT_SKY_COLOR,
    sea_color=DEFAULT_SEA_COLOR,
    dtype=None,
) -> Lighting:
    """Build and validate a :class:`Lighting` from array-likes.

    ``dtype`` defaults to the default float type (float32, or float64 under x64), so that
    integer colours such as ``(1, 1, 1)`` are accepted.
    """
    dtype = jnp.zeros(()).dtype if dtype is None else dtype
    lighting = Lighting(
        *(jnp.asarray(x, dtype) for x in (sun_azimuth, sun_elevation, sun_color, sky_color, sea_color))
    )
    return validate_lighting(lighting)


def validate_lighting(lighting: Lighting) -> Lighting:
    """Check structure (always) and values (when concrete). Returns ``lighting`` unchanged.

    Structure -> ``ValueError``: a :class:`Lighting`, floating leaves, scalar angles, colours
    of shape ``(3,)`` (batches of lightings come from ``vmap``).
    Values -> :class:`jaxocean.errors.InvalidValueError`: every leaf finite, colours >= 0,
    elevation in [-pi/2, pi/2].
    """
    if not isinstance(lighting, Lighting):
        raise ValueError(f"expected a jaxocean Lighting, got {type(lighting).__name__}")
    for name, leaf in zip(Lighting._fields, lighting):
        if not jnp.issubdtype(jnp.result_type(leaf), jnp.floating):
            raise ValueError(f"Lighting.{name} must be floating point; got {jnp.result_type(leaf)}")
    for name in _ANGLE_FIELDS:
        shape = jnp.shape(getattr(lighting, name))
        if shape != ():
            raise ValueError(f"Lighting.{name} must be a scalar angle in radians; got shape {shape}")
    for name in _COLOR_FIELDS:
        shape = jnp.shape(getattr(lighting, name))
        if shape != (3,):
            raise ValueError(f"Lighting.{name} must be linear RGB of shape (3,); got shape {shape}")
    if not is_concrete(lighting):
        return lighting
    for name, leaf in zip(Lighting._fields, lighting):
        check_values(np.isfinite(leaf), f"Lighting.{name} must be finite", leaf)
    for name in _COLOR_FIELDS:
        leaf = getattr(lighting, name)
        check_values(np.asarray(leaf) >= 0, f"Lighting.{name} must be >= 0 (linear RGB radiance)", leaf)
    elevation = np.asarray(lighting.sun_elevation)
    check_values(np.abs(elevation) <= np.pi / 2,
                 "Lighting.sun_elevation must be in [-pi/2, pi/2] rad", elevation)
    return lighting


def sun_direction(lighting: Lighting):
    """Unit vector towards the sun, ``(cos el cos az, cos el sin az, sin el)``, shape ``(3,)``."""
    azimuth, elevation = lighting.sun_azimuth, lighting.sun_elevation
    cos_el = jnp.cos(elevation)
    return jnp.stack([cos_el * jnp.cos(azimuth), cos_el * jnp.sin(azimuth), jnp.sin(elevation)], axis=-1)


# --------------------------------------------------------------------------- geometry


# Per-pixel vectors are handled internally as tuples of three ``(...)`` component arrays
# (structure of arrays): XLA:CPU then evaluates the whole pixel model as one elementwise
# loop in which every per-pixel value is computed once, instead of strided ``(..., 3)``
# arrays whose slices re-derive their producers per component (measured: shading forward
# 3-4x, its gradient ~10x faster). The public functions stack / unstack at the boundary.


def _split(v):
    """``(..., 3)`` array -> tuple of its three components (:func:`jaxocean._math.components`:
    reverse mode without a pad-and-add fusion)."""
    return components(jnp.asarray(v))


def _join(v):
    """Tuple of three components -> ``(..., 3)`` array."""
    return jnp.stack(jnp.broadcast_arrays(*v), axis=-1)


def _vdot(a, b):
    return a[0] * b[0] + a[1] * b[1] + a[2] * b[2]


def _vnormalize(v, fallback):
    """:func:`jaxocean._math.safe_normalize` on component tuples (``fallback`` a tuple too;
    a NaN stays NaN)."""
    sq = _vdot(v, v)
    ok = sq > tiny(sq)
    inv = jnp.where(ok, inv_sqrt(jnp.where(ok, sq, 1.0)), 0.0 * sq)  # 0 * NaN: NaN
    keep = ok | jnp.isnan(sq)
    return tuple(jnp.where(keep, c * inv, f) for c, f in zip(v, fallback))


def _check_vectors(**vectors) -> None:
    for name, v in vectors.items():
        if jnp.shape(v)[-1:] != (3,):
            raise ValueError(f"{name} must have shape (..., 3); got {jnp.shape(v)}")


def reflect(direction, normal):
    """Mirror ``direction`` about ``normal``: ``2 (N.d) N - d`` (both point away from the surface)."""
    direction, normal = jnp.asarray(direction), jnp.asarray(normal)
    return 2.0 * dot_last(normal, direction)[..., None] * normal - direction


def tangent_frame(normal):
    """Tangent axes ``(T_x, T_y)``, each ``(..., 3)``, of the unit ``normal``.

    ``T_x = normalize(e_x - (e_x.N) N)`` is +x projected onto the tangent plane and
    ``T_y = N x T_x`` completes a right-handed frame ``(T_x, T_y, N)``. For ``N = +z`` this is
    ``(e_x, e_y)``, so ``sigma2_x``/``sigma2_y`` are the slope variances along world x/y.
    Where ``N`` is parallel to ``e_x`` the projection vanishes and ``T_x`` falls back to
    ``e_y`` (any tangent will do; the frame is necessarily discontinuous there).
    """
    t_x, t_y = _tangent_frame(_split(normal))
    return _join(t_x), _join(t_y)


def _tangent_frame(n):
    # tangent_frame on component tuples
    t_x = _vnormalize((1.0 - n[0] * n[0], -n[0] * n[1], -n[0] * n[2]), fallback=(0.0, 1.0, 0.0))
    t_y = (n[1] * t_x[2] - n[2] * t_x[1], n[2] * t_x[0] - n[0] * t_x[2], n[0] * t_x[1] - n[1] * t_x[0])
    return t_x, t_y


def projected_variance(direction, normal, sigma2_x, sigma2_y):
    """Slope variance seen along ``direction``'s azimuth in the tangent plane, ``(...)``.

    ``sigma2_d = (sigma2_x (d.T_x)^2 + sigma2_y (d.T_y)^2) / ((d.T_x)^2 + (d.T_y)^2)``: exact for
    the anisotropic Gaussian slope distribution. Where ``d`` is parallel to ``N`` the azimuth
    is undefined and the mean ``(sigma2_x + sigma2_y) / 2`` is used. No clamping here.
    """
    return _projected_variance(_split(direction), *_tangent_frame(_split(normal)), sigma2_x, sigma2_y)


def _projected_variance(direction, t_x, t_y, sigma2_x, sigma2_y):
    # the formula of projected_variance, on component tuples, for callers holding the frame
    a2 = _vdot(direction, t_x) ** 2
    b2 = _vdot(direction, t_y) ** 2
    total = a2 + b2
    ok = total > tiny(total)
    projected = (sigma2_x * a2 + sigma2_y * b2) / jnp.where(ok, total, 1.0)
    return jnp.where(ok, projected, 0.5 * (sigma2_x + sigma2_y))


# --------------------------------------------------------------------------- BRDF terms


def _erfc_scaled(a):
    """``erfc(a) exp(a^2)`` of Bruneton's approximation for ``a >= 0``: the exponential is
    left to the caller, which shares it (Smith's Lambda needs ``exp(-v^2)`` twice)."""
    return 2.0 / (2.319 * a + jnp.sqrt(4.0 + 1.52 * a * a))


def erfc_approx(x):
    """Bruneton's closed-form ``erfc(x) ~ 2 exp(-x^2) / (2.319 x + sqrt(4 + 1.52 x^2))``.

    The approximation is for ``x >= 0`` (where the BRDF uses it); negative ``x`` uses
    ``erfc(x) = 2 - erfc(-x)``, which joins with matching value and slope at 0. Absolute
    error below 2e-3 on the real line (tests/test_shading.py measures it).
    """
    x = jnp.asarray(x)
    a = jnp.where(x >= 0, x, -x)  # |x| with slope 1 (not 0) at x = 0
    upper = jnp.exp(-a * a) * _erfc_scaled(a)
    return jnp.where(x >= 0, upper, 2.0 - upper)


def smith_lambda(cos_theta, sigma2):
    """Smith's shadowing function ``Lambda`` for Gaussian slopes of variance ``sigma2``.

    ``v = c / sqrt(2 sigma2 (1 - c^2))`` and
    ``Lambda = max(0, (exp(-v^2) - v sqrt(pi) erfc(v)) / (2 v sqrt(pi)))`` with
    :func:`erfc_approx`. ``Lambda -> 0`` as ``c -> 1`` and grows as ``c`` decreases; the
    shadowing-masking term is ``1 / (1 + Lambda_L + Lambda_V)``.

    ``c`` is clamped to ``[MIN_COSINE, 1]`` (Bruneton's floor, finite at grazing angles),
    ``sigma2`` at ``MIN_SLOPE_VARIANCE_AXIS``, and ``v`` is capped at 8 where
    ``Lambda ~ 1e-31``: this keeps value and gradient finite at ``c = 1`` (``v = inf``).
    """
    c = jnp.clip(cos_theta, MIN_COSINE, 1.0)
    sigma2 = jnp.maximum(sigma2, MIN_SLOPE_VARIANCE_AXIS)
    den = 2.0 * sigma2 * (1.0 - c * c)
    # v < V_MAX  <=>  den V_MAX^2 > c^2; this also excludes den = 0 (c = 1) from the sqrt,
    # and the switch to V_MAX is continuous.
    below_cap = den * _SMITH_V_MAX**2 > c * c
    # (inv_sqrt: XLA:CPU rewrites c / sqrt(den) into a slow rsqrt, see jaxocean._math.inv_sqrt)
    v = jnp.where(below_cap, c * inv_sqrt(jnp.where(below_cap, den, 1.0)), _SMITH_V_MAX)
    # v > 0, so erfc(v) = exp(-v^2) erfc_scaled(v): one exponential for both terms
    lam = jnp.exp(-v * v) * (1.0 - v * _SQRT_PI * _erfc_scaled(v)) / (2.0 * v * _SQRT_PI)
    return jnp.maximum(lam, 0.0)


def _clamp_variances(sigma2_x, sigma2_y):
    return (jnp.maximum(sigma2_x, MIN_SLOPE_VARIANCE_AXIS), jnp.maximum(sigma2_y, MIN_SLOPE_VARIANCE_AXIS))


def ocean_brdf(normal, sigma2_x, sigma2_y, view, light):
    """The ocean BRDF ``rho(L, V)`` [1/sr], ``(...)``, symmetric in ``L`` and ``V``.

    ``H = normalize(L + V)``, slopes ``zeta = (H.T_x, H.T_y) / (H.N)``,
    ``p = exp(-(zeta_x^2 / sigma2_x + zeta_y^2 / sigma2_y) / 2) / (2 pi sigma_x sigma_y)``,
    ``F = 0.02 + 0.98 (1 - V.H)^5`` (Schlick), and

        rho = F p / (4 z_L z_V (H.N)^4 (1 + Lambda(z_L, sigma2_L) + Lambda(z_V, sigma2_V)))

    with ``z = max(cos, MIN_COSINE)`` and the projected variances of
    :func:`projected_variance`. ``H.N`` is floored at ``MIN_COSINE`` too: a half vector
    below the tangent plane then has huge slopes and ``p = 0``, instead of a spurious
    glint from a sign flip. Slope variances are clamped per axis.
    """
    n = _split(normal)
    sigma2_x, sigma2_y = _clamp_variances(sigma2_x, sigma2_y)
    return _ocean_brdf(n, *_tangent_frame(n), sigma2_x, sigma2_y, _split(view), _split(light))


def _ocean_brdf(n, t_x, t_y, sigma2_x, sigma2_y, view, light):
    # ocean_brdf on component tuples, frame given, variances clamped
    half = _vnormalize(tuple(a + b for a, b in zip(light, view)), fallback=n)
    h_n = jnp.maximum(_vdot(half, n), MIN_COSINE)
    zeta_x = _vdot(half, t_x) / h_n
    zeta_y = _vdot(half, t_y) / h_n
    slope_pdf = jnp.exp(-0.5 * (zeta_x**2 / sigma2_x + zeta_y**2 / sigma2_y)) * inv_sqrt(sigma2_x * sigma2_y) / (
        2.0 * jnp.pi
    )
    fresnel = FRESNEL_NORMAL + (1.0 - FRESNEL_NORMAL) * jnp.clip(1.0 - _vdot(view, half), 0.0, 1.0) ** 5
    z_light = jnp.maximum(_vdot(light, n), MIN_COSINE)
    z_view = jnp.maximum(_vdot(view, n), MIN_COSINE)
    shadowing = (1.0 + smith_lambda(z_light, _projected_variance(light, t_x, t_y, sigma2_x, sigma2_y))
                 + smith_lambda(z_view, _projected_variance(view, t_x, t_y, sigma2_x, sigma2_y)))
    return fresnel * slope_pdf / (4.0 * z_light * z_view * h_n**4 * shadowing)


def sun_radiance_factor(normal, sigma2_x, sigma2_y, view, light):
    """Sun glitter factor ``B_sun``, ``(...)``, so that ``L_sun = sun_color * B_sun``.

    ``B_sun = rho(L, V) z_L`` (:func:`ocean_brdf` times the clamped sun cosine), i.e.
    Bruneton's ``F p / (4 z_V (H.N)^4 (1 + Lambda_L + Lambda_V))``, multiplied by
    ``smoothstep(0, SUN_HORIZON_FADE, L_z)``: zero once the sun is below the horizon, with a
    C1 fade (finite gradients in the elevation) while the sun disk sets.
    """
    n = _split(normal)
    sigma2_x, sigma2_y = _clamp_variances(sigma2_x, sigma2_y)
    return _sun_radiance_factor(n, *_tangent_frame(n), sigma2_x, sigma2_y, _split(view), _split(light))


def _sun_radiance_factor(n, t_x, t_y, sigma2_x, sigma2_y, view, light):
    # sun_radiance_factor on component tuples, frame given, variances clamped
    z_light = jnp.maximum(_vdot(light, n), MIN_COSINE)
    above_horizon = smoothstep(0.0, SUN_HORIZON_FADE, light[2])
    return _ocean_brdf(n, t_x, t_y, sigma2_x, sigma2_y, view, light) * z_light * above_horizon


def _safe_power(base, exponent):
    """``base ** exponent`` for ``base >= 0``, 0 at ``base <= tiny``: finite gradients in both
    arguments (``d/dbase`` of ``x^p`` with ``p < 1`` is infinite at 0, ``d/dp`` is ``log 0``)."""
    ok = base > tiny(base)
    return jnp.where(ok, jnp.exp(exponent * jnp.log(jnp.where(ok, base, 1.0))), 0.0)


def mean_fresnel(cos_theta_v, sigma2_v):
    """Roughness-averaged Fresnel reflectance ``F_mean`` of the view direction, ``(...)``.

    ``F_mean = 0.02 + 0.98 (1 - cos)^(5 exp(-2.69 sigma_V)) / (1 + 22.7 sigma_V^1.5)`` with
    ``sigma_V = sqrt(sigma2_v)`` the slope standard deviation along the view azimuth
    (:func:`projected_variance`). Takes the *variance*, clamped at
    ``MIN_SLOPE_VARIANCE_AXIS``, like every other function here. ``cos`` is clipped to
    ``[0, 1]``; the power is gradient-safe as ``1 - cos -> 0``. 0.02 at normal incidence on a
    smooth sea, about 1 at grazing.
    """
    c = jnp.clip(cos_theta_v, 0.0, 1.0)
    sigma2_v = jnp.maximum(sigma2_v, MIN_SLOPE_VARIANCE_AXIS)
    sigma_v = jnp.sqrt(sigma2_v)
    exponent = 5.0 * jnp.exp(-2.69 * sigma_v)
    # sigma_V^1.5 = sigma_V sqrt(sigma_V): a square root instead of a general power (log + exp)
    return FRESNEL_NORMAL + (1.0 - FRESNEL_NORMAL) * _safe_power(1.0 - c, exponent) / (
        1.0 + 22.7 * sigma_v * jnp.sqrt(sigma_v)
    )


# --------------------------------------------------------------------------- sky and pixel


def check_unit_normals(normals, what: str, where=None, counted: str = "", hint: str = "") -> None:
    """``InvalidValueError`` when concrete ``normals (..., 3)`` (on the pixels ``where``,
    default all) are not unit vectors within :data:`UNIT_NORMAL_TOLERANCE`: "``what`` must
    be unit vectors ..." with how many (``counted``: of what) are not and ``hint``. The one
    check of every public function that takes normals. NaN/inf normals are no unit vectors:
    callers that read NaN as "no data" leave those pixels out of ``where``."""
    if not is_concrete(normals, where):
        return
    length = np.linalg.norm(np.asarray(normals, np.float64), axis=-1)
    if where is not None:
        length = length[np.asarray(where, bool)]
    off = ~(np.abs(length - 1.0) <= UNIT_NORMAL_TOLERANCE)  # NaN counts
    if off.any():
        finite = length[np.isfinite(length)]
        span = f"|n| from {finite.min():.4g} to {finite.max():.4g}" if finite.size else "|n| all NaN/inf"
        nonfinite = int(length.size - finite.size)
        span += f", {nonfinite} NaN/inf" if nonfinite and finite.size else ""
        raise InvalidValueError(
            f"{what} must be unit vectors (| |n| - 1 | <= {UNIT_NORMAL_TOLERANCE:g}); {int(off.sum())} of {off.size}"
            f"{counted} are not ({span}){hint}")


def check_horizon_gradient(horizon_gradient) -> None:
    """Raise unless a concrete ``horizon_gradient`` is >= -1 (NaN included): the check of
    every public function that takes the sky model's gradient."""
    if is_concrete(horizon_gradient):
        check_values(np.asarray(horizon_gradient) >= -1.0,
                     "horizon_gradient must be >= -1 (sky radiance must stay >= 0)", horizon_gradient)


def sky_weight(d_z, horizon_gradient):
    """Sky radiance per unit ``sky_color`` towards a direction whose z component is ``d_z``
    (:func:`sky_radiance` without the colour), ``(...)``."""
    return 1.0 + horizon_gradient * (1.0 - jnp.clip(d_z, 0.0, 1.0))


def _sky(direction, lighting: Lighting, horizon_gradient):
    return sky_weight(direction[..., 2], horizon_gradient)[..., None] * lighting.sky_color


def sky_radiance(direction, lighting: Lighting, *, horizon_gradient=0.0):
    """Analytic sky radiance towards ``direction`` ``(..., 3)``, linear RGB ``(..., 3)``.

    ``sky(d) = sky_color * (1 + horizon_gradient * (1 - clip(d_z, 0, 1)))``: ``sky_color`` at
    the zenith, ``(1 + horizon_gradient) * sky_color`` at and below the horizon. The default
    0 is a uniform sky (the paper's); positive values brighten the horizon, values down to
    -1 darken it. Linear in ``sky_color``.
    """
    _check_vectors(direction=direction)
    validate_lighting(lighting)
    check_horizon_gradient(horizon_gradient)
    return _sky(direction, lighting, horizon_gradient)


def sky_pixel(direction, lighting: Lighting, *, horizon_gradient=0.0):
    """Radiance of a pixel whose ray (``direction``, pointing from the camera into the scene)
    misses the sea: the sky, linear RGB ``(..., 3)``.

    The sun disk is not drawn: its 0.0093 rad diameter is below a pixel at usual fields of
    view, and a disk edge would make the image non-differentiable in the sun direction. The
    sun is seen through its glitter on the sea (:func:`sun_radiance_factor`).
    """
    return sky_radiance(direction, lighting, horizon_gradient=horizon_gradient)


class ShadingTerms(NamedTuple):
    """The lighting-linear decomposition of a pixel (see :func:`shade_components`).

    * ``sun``       ``(...)``    ``B_sun``: sun glitter per unit ``sun_color``.
    * ``fresnel``   ``(...)``    ``F_mean``: independent of the lighting.
    * ``reflected`` ``(..., 3)`` sky radiance in the mirror direction ``R``, linear in
      ``sky_color`` (equal to it for the default uniform sky).
    """

    sun: jnp.ndarray
    fresnel: jnp.ndarray
    reflected: jnp.ndarray


def shade_components(normal, sigma2_x, sigma2_y, view, lighting: Lighting, *, horizon_gradient=0.0) -> ShadingTerms:
    """Per-pixel shading terms such that

        image = sun_color * sun + fresnel * reflected + (1 - fresnel) * sea_color

    (:func:`shade_pixel`). The image is linear in the three colours: ``sun`` depends on the
    sun direction only, ``fresnel`` on no lighting parameter, and ``reflected`` is
    ``sky_color`` times a lighting-independent weight. A lighting fit can therefore solve
    the colours in closed form and search only the two sun angles.

    ``normal`` and ``view`` are normalised here (so un-normalised normals, e.g. a cross
    product of tangents, are fine); slope variances are clamped per axis.
    """
    _check_vectors(normal=normal, view=view)
    validate_lighting(lighting)
    check_horizon_gradient(horizon_gradient)
    sun, fresnel, reflected = pixel_terms(_split(normal), sigma2_x, sigma2_y, _split(view), lighting,
                                          horizon_gradient)
    return ShadingTerms(sun, fresnel, reflected[..., None] * lighting.sky_color)


def pixel_terms(normal, sigma2_x, sigma2_y, view, lighting: Lighting, horizon_gradient):
    """:func:`shade_components` on component tuples, for callers that hold the geometry as
    separate arrays (the renderer): ``normal`` and ``view`` are tuples of three ``(...)``
    arrays, normalised here; returns ``(sun, fresnel, reflected)``, each ``(...)``, with the
    reflected sky per unit ``sky_color`` (:func:`sky_weight` of the mirror direction). No validation (the callers did it)."""
    up = (0.0, 0.0, 1.0)
    n = _vnormalize(normal, fallback=up)
    view = _vnormalize(view, fallback=up)
    sigma2_x, sigma2_y = _clamp_variances(sigma2_x, sigma2_y)
    t_x, t_y = _tangent_frame(n)
    # the sun's direction once: XLA:CPU otherwise re-evaluates its sines per pixel in the gradient
    sun = _sun_radiance_factor(n, t_x, t_y, sigma2_x, sigma2_y, view, materialize(*_split(sun_direction(lighting))))
    n_v = _vdot(view, n)
    fresnel = mean_fresnel(n_v, _projected_variance(view, t_x, t_y, sigma2_x, sigma2_y))
    # z of the mirror direction R = 2 (N.V) N - V (see reflect)
    reflected = sky_weight(2.0 * n_v * n[2] - view[2], horizon_gradient)
    return sun, fresnel, reflected


def shade_pixel(normal, sigma2_x, sigma2_y, view, lighting: Lighting, *, horizon_gradient=0.0):
    """Linear RGB radiance ``(..., 3)`` of sea pixels: :func:`shade_components` composed,
    ``sun_color * B_sun + F_mean * sky(R) + (1 - F_mean) * sea_color``."""
    terms = shade_components(normal, sigma2_x, sigma2_y, view, lighting, horizon_gradient=horizon_gradient)
    fresnel = terms.fresnel[..., None]
    return (terms.sun[..., None] * lighting.sun_color + fresnel * terms.reflected
            + (1.0 - fresnel) * lighting.sea_color)


# --------------------------------------------------------------------------- tone mapping


def _bruneton(x):
    return jnp.where(
        x < _BRUNETON_KNEE,
        _safe_power(_BRUNETON_SCALE * x, 1.0 / _BRUNETON_GAMMA),
        1.0 - jnp.exp(-x),
    )


def _bruneton_inverse(y):
    y = jnp.clip(y, 0.0, _BRUNETON_MAX_DISPLAY)
    return jnp.where(
        y < _BRUNETON_KNEE_DISPLAY,
        _safe_power(y, _BRUNETON_GAMMA) / _BRUNETON_SCALE,
        -jnp.log1p(-y),
    )


def _srgb(x):
    x = jnp.clip(x, 0.0, 1.0)
    return jnp.where(
        x <= _SRGB_LINEAR_LIMIT,
        _SRGB_SLOPE * x,
        1.055 * _safe_power(x, 1.0 / _SRGB_GAMMA) - 0.055,
    )


def _srgb_inverse(y):
    y = jnp.clip(y, 0.0, 1.0)
    return jnp.where(
        y <= _SRGB_DISPLAY_LIMIT,
        y / _SRGB_SLOPE,
        _safe_power((y + 0.055) / 1.055, _SRGB_GAMMA),
    )


def _clip01(x):
    return jnp.clip(x, 0.0, 1.0)


# mode -> (linear exposed radiance -> display, display -> linear exposed radiance)
_TONEMAPS = {
    "bruneton": (_bruneton, _bruneton_inverse),
    "srgb": (_srgb, _srgb_inverse),
    "linear": (_clip01, _clip01),
}
TONEMAP_MODES = tuple(_TONEMAPS)


def _tonemap_pair(mode: str, exposure):
    if mode not in _TONEMAPS:
        raise ValueError(f"unknown tone-map mode {mode!r}; expected one of {TONEMAP_MODES}")
    if is_concrete(exposure):
        check_values(np.asarray(exposure) > 0, "tone-map exposure must be > 0", exposure)
    return _TONEMAPS[mode]


def tonemap(image, exposure=1.0, mode: str = "bruneton"):
    """Linear radiance -> display values in [0, 1], elementwise (per channel).

    The radiance is first scaled, ``L = max(image * exposure, 0)``, then:

    * ``"bruneton"`` (default): ``(0.38317 L)^(1/2.2)`` for ``L < 1.413``, else
      ``1 - exp(-L)``: highlights roll off instead of clipping (the pieces meet with equal
      slopes and a 3.4e-5 step at the knee, Bruneton's published constants).
    * ``"srgb"``: ``clip(L, 0, 1)`` then the sRGB transfer function.
    * ``"linear"``: ``clip(L, 0, 1)``.

    Gradients are finite everywhere, including at ``L = 0`` where ``L^(1/2.2)`` has an
    infinite slope (the gradient there is 0). An unknown ``mode`` raises ``ValueError``.
    Values are not checked (this runs inside the fits' losses, on masked images): a NaN maps
    to some display value; :func:`jaxocean.radiometry.to_display` checks them.
    """
    forward, _ = _tonemap_pair(mode, exposure)
    return forward(jnp.maximum(jnp.asarray(image) * exposure, 0.0))


def inverse_tonemap(display, exposure=1.0, mode: str = "bruneton"):
    """Display values in [0, 1] -> linear radiance: the inverse of :func:`tonemap`.

    Exact where the curve is strictly monotone. Clipped values have no unique inverse and
    map to the lower bound of the radiance: ``display >= 1`` gives ``1 / exposure`` for
    ``"srgb"`` and ``"linear"``; for ``"bruneton"`` display values are clipped to
    ``1 - 2^-10`` (``L <= 6.93 / exposure``). Negative values map to 0.

    Bruneton's two pieces do not quite meet: at the knee ``L = 1.413`` the power piece is
    3.4e-5 above ``1 - exp(-L)``. Display values in that sliver invert to within 3e-4 of
    the knee; everywhere else the round trip is exact to rounding.

    A NaN/inf input raises :class:`jaxocean.errors.InvalidValueError` when concrete.
    """
    _, inverse = _tonemap_pair(mode, exposure)
    display = jnp.asarray(display)
    if is_concrete(display):
        check_values(np.isfinite(display), "display image must be finite", display)
    return inverse(display) / exposure
