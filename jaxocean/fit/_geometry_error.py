"""A stated error of the geometry, propagated through the shading by sampling (the lighting
fit's ``normal_noise=``; see :mod:`jaxocean.fit.lighting`).

Protocol: :func:`normal_noise_map` turns ``normal_noise`` (None, a number or an ``(H, W)``
map, [rad per tangent component]) into an ``(H, W)`` array; :func:`tilt_fields` draws
``(GEOMETRY_SAMPLES, 2, H, W)`` unit-variance Gaussian tilt fields, independent per pixel or
correlated over a length in pixels; :func:`widen_glitter` widens the sun glitter's slope pdf
of :class:`jaxocean.fit._photometry.Data` by the error; :func:`effect` is what the error does
to a fit at its answer: ``(geometry_loss (), shifts (GEOMETRY_SAMPLES, P))`` -- the mean
square change of the model image and the shift of the fitted fields per draw.
"""

from __future__ import annotations

import math

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import shading
from jaxocean._math import safe_normalize
from jaxocean.errors import InvalidValueError, is_concrete
from jaxocean.fit import _photometry as ph
from jaxocean.fit import _plausibility
from jaxocean.fit._photometry import pq_to_direction

__all__ = ["GEOMETRY_SAMPLES", "normal_noise_map", "tilt_fields", "widen_glitter", "effect"]

#: draws of the stated normal error (``normal_noise``) the fit propagates through the shading
GEOMETRY_SAMPLES = 32


def normal_noise_map(normal_noise, resolution, dtype):
    """``normal_noise`` (None, a number or an ``(H, W)`` map) as an ``(H, W)`` array (zeros
    for None, which the fit does not read); values are checked when concrete."""
    H, W = resolution
    if normal_noise is None:
        return jnp.zeros((H, W), dtype)
    sigma = jnp.asarray(normal_noise, dtype)
    if sigma.ndim == 0:
        sigma = jnp.full((H, W), sigma, dtype)
    if sigma.shape != (H, W):
        raise ValueError(f"normal_noise must be a number or an (H, W) = {(H, W)} map; got shape {sigma.shape}")
    if is_concrete(sigma):
        s = np.asarray(sigma)
        if not np.all(np.isfinite(s)) or np.any(s < 0):
            raise InvalidValueError(f"normal_noise must be finite and >= 0 [rad]; got values in "
                                    f"[{np.nanmin(s):g}, {np.nanmax(s):g}]")
    return sigma


def tilt_fields(key, shape, length: float, dtype):
    """``(GEOMETRY_SAMPLES, 2, H, W)`` standard normal tilt fields (two tangent axes),
    independent per pixel (``length = 0``) or correlated as ``exp(-d^2 / (2 length^2))`` over
    ``d`` pixels: white noise on a larger grid through a separable Gaussian filter of
    ``length / sqrt(2)`` pixels (two 1-D convolutions), normalised to unit variance
    (stationary up to the image's edges)."""
    H, W = shape
    if length <= 0:
        return jax.random.normal(key, (GEOMETRY_SAMPLES, 2, H, W), dtype)
    width = length / math.sqrt(2.0)
    radius = int(math.ceil(4.0 * width))
    x = np.arange(-radius, radius + 1, dtype=np.float64)
    kernel = np.exp(-0.5 * (x / width) ** 2)
    kernel = jnp.asarray(kernel / np.sqrt(np.sum(kernel**2)), dtype)  # unit variance per axis
    white = jax.random.normal(key, (GEOMETRY_SAMPLES * 2, 1, H + 2 * radius, W + 2 * radius), dtype)
    dims = ("NCHW", "OIHW", "NCHW")
    rows = jax.lax.conv_general_dilated(white, kernel[None, None, :, None], (1, 1), "VALID", dimension_numbers=dims)
    both = jax.lax.conv_general_dilated(rows, kernel[None, None, None, :], (1, 1), "VALID", dimension_numbers=dims)
    return both.reshape(GEOMETRY_SAMPLES, 2, H, W)


def widen_glitter(data: ph.Data, normal_noise):
    """``data`` whose sun glitter has its slope pdf widened by the stated normal error
    (``normal_noise (H, W)`` [rad], variance added per axis): the mean glitter of normals
    known to that accuracy, whose sun-direction Jacobian measures how far a glint can move.
    The glitter lobes of resolved pixels are far narrower than a network's normal error,
    and the sharp lobe's Jacobian barely sees a glint moved by more than its width. The
    sky and sea terms are the fit's own: they are linear in their colours, and the colours'
    sensitivity must be the one the fit used."""
    sigma2 = jax.lax.stop_gradient(normal_noise) ** 2
    sx2, sy2 = data.sx2 + sigma2, data.sy2 + sigma2
    lambda_view = shading.smith_lambda(data.z_view, shading.projected_variance(data.view, data.normal, sx2, sy2))
    return data._replace(sx2=sx2, sy2=sy2, lambda_view=lambda_view, pdf_norm=1.0 / (2.0 * jnp.pi * jnp.sqrt(sx2 * sy2)))


def effect(prepare_at, normal_equations, normal, weight, used, pq, colors, normal_noise, *, correlation: float,
           space: str, exposure: float, tonemap: str):
    """What the stated normal error does to the fit at the answer ``(pq, colors)``:
    ``(geometry_loss (), shifts (GEOMETRY_SAMPLES, P))``.

    ``prepare_at(normal)`` gives the fit's :class:`~jaxocean.fit._photometry.Data` on other
    normals; ``normal_equations(data, pq, colors)`` its ``(J^T J, J^T r)`` of the fitted
    fields (``P`` parameters). The error is propagated by sampling, not by derivatives: the
    normals are tilted about their tangent axes by ``GEOMETRY_SAMPLES`` fixed draws (key 0:
    the result is a deterministic function of the inputs) of Gaussian fields of standard
    deviation ``normal_noise (H, W)`` [rad per axis], correlated over ``correlation`` pixels.

    * ``geometry_loss``: the mean square, over the draws, of the change of the model image
      at the answer, in the reported loss's residual (the linear one, or with
      ``space="display"`` the tone-mapped one over the ``used`` pixels): the residual a
      right lighting leaves when the normals are off by the stated error.
    * ``shifts``: for each draw, how far the fitted fields move when the model image at the
      given normals is fitted on the tilted normals (one Gauss-Newton step,
      :func:`jaxocean.fit._plausibility.gauss_newton_step`: exact for the colours, which are
      linear; the glitter widened by the error, :func:`widen_glitter`). This emulates the
      fit's own situation -- data from one set of normals, the model on normals off by the
      error -- bias included: normals with an error are rougher than the truth, and Fresnel
      and the sky reflection are strongly curved at grazing views, so the colours' error is
      mostly a bias, which a symmetric spread around the given normals does not show."""
    sigma = jax.lax.stop_gradient(normal_noise)
    normal = safe_normalize(normal)
    direction = pq_to_direction(pq)
    t_x, t_y = shading.tangent_frame(normal)
    fields = tilt_fields(jax.random.PRNGKey(0), normal.shape[:2], correlation, normal.dtype)
    base = ph.model(prepare_at(normal), direction, colors)

    stated = (sigma > 0)[..., None]

    def sample(ab):
        tilted = normal + sigma[..., None] * (ab[0][..., None] * t_x + ab[1][..., None] * t_y)
        data = prepare_at(tilted)
        # pixels without a stated error change by exactly 0 (not by the rounding of a second
        # evaluation): normal_noise=0 is the plain fit's bound and std, bit for bit
        model = jnp.where(stated, ph.model(data, direction, colors), base)
        if space == "display":
            shown = used * (shading.tonemap(model, exposure, tonemap) - shading.tonemap(base, exposure, tonemap))
            loss = jnp.sum(shown * shown) / jnp.sum(used)
        else:
            loss = jnp.sum((weight * (model - base)) ** 2) / jnp.sum(weight * weight)
        jtj, jtr = normal_equations(widen_glitter(data._replace(target=jnp.where(stated, base, model)), sigma), pq,
                                    colors)
        return loss, _plausibility.gauss_newton_step(jtj, jtr)

    losses, shifts = jax.lax.map(sample, fields)
    return jax.lax.stop_gradient(jnp.mean(losses)), jax.lax.stop_gradient(shifts)
