"""Robust statistics of image residuals for the photometric refinement (:mod:`jaxocean.fit.photometric`).

Protocol: residuals ``r (T, H, W, C)`` in the comparison space ``log1p(I / s)`` and pixel
weights ``used (T, H, W)`` (1 where a pixel enters the fit). A robust loss is chosen by its
integer ``code`` (index into :data:`CODES`: least squares, Cauchy, Huber, Tukey), a runtime
argument so that one compiled program serves every loss. :func:`irls_weights` gives one
IRLS round's scale (the MAD, floored at the noise level) and weights ``w(u)`` of
``u = rms_channels(r) / (c sigma)``; :func:`robust_statistics` the weights, outliers, losses,
outlier fraction and the residual's trimmed scale at an answer; :func:`noise_estimate` (Immerkaer's operator) and
:func:`signal_scale` the noise and the spread of an image sequence about its row medians.
All dimensionless (comparison-space units).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

#: robust loss -> tuning constant c (95% efficiency at Gaussian noise)
ROBUST_LOSSES = {"cauchy": 2.385, "huber": 1.345, "tukey": 4.685}
#: a used pixel is an outlier when its final IRLS weight is below this
OUTLIER_WEIGHT = 0.2
#: the IRLS scale never goes below this (comparison-space units)
SCALE_FLOOR = 1e-6
_MAD = 1.4826
_TRIM = 0.9  # noise and spread estimates: mean |x| below this quantile of |x| ...
_TRIMMED_HALF_NORMAL = 0.6573  # ... over its value for unit Gaussian noise, 2 (phi(0) - phi(1.645)) / 0.9

#: robust loss codes (a runtime argument: one compiled program serves every loss)
CODES = (None, "cauchy", "huber", "tukey")
_C = (ROBUST_LOSSES["cauchy"], ROBUST_LOSSES["cauchy"], ROBUST_LOSSES["huber"], ROBUST_LOSSES["tukey"])


def _pixel_u(r, scale, code):
    """``u = rms_channels(r) / (c sigma)`` per pixel ``(T, H, W)``; ``c`` of ``code``
    (Cauchy's for least squares)."""
    c = jnp.asarray(_C, r.dtype)[code]
    return jnp.sqrt(jnp.mean(r * r, axis=-1)) / (c * scale)


def _weight(u, code):
    return jnp.select([code == 0, code == 1, code == 2],
                      [jnp.ones_like(u), 1.0 / (1.0 + u * u), jnp.minimum(1.0, 1.0 / jnp.maximum(u, 1e-30))],
                      jnp.where(u < 1.0, (1.0 - u * u) ** 2, 0.0))


def _rho(u, code):
    """Robust function per unit ``(c sigma)^2``."""
    return jnp.select([code == 0, code == 1, code == 2],
                      [0.5 * u * u, 0.5 * jnp.log1p(u * u), jnp.where(u <= 1.0, 0.5 * u * u, u - 0.5)],
                      jnp.where(u < 1.0, (1.0 - (1.0 - u * u) ** 3) / 6.0, 1.0 / 6.0))


def _mad(r, used):
    """``1.4826 median |r|`` over used pixels and channels."""
    a = jnp.where(used[..., None] > 0, jnp.abs(r), jnp.nan)
    return _MAD * jnp.nanmedian(a)


def _robust_loss(r, used, scale, code):
    c = jnp.asarray(_C, r.dtype)[code]
    u = _pixel_u(r, scale, code)
    return jnp.sum(used * _rho(u, code)) * (c * scale) ** 2 / jnp.maximum(jnp.sum(used), 1.0)


@jax.jit
def irls_weights(r, used, code, floor):
    """``(scale, weights (T, H, W))`` of residuals ``r``: one IRLS round's; the scale is
    floored at ``floor`` (the noise level)."""
    scale = jnp.maximum(_mad(r, used), jnp.maximum(floor, SCALE_FLOOR))
    return scale, used * _weight(_pixel_u(r, scale, code), code)


@jax.jit
def robust_statistics(r, r_init, used, code, floor):
    """Scale, weights, outliers, the two losses, the outlier fraction and the residual's
    trimmed scale at the answer: the success test's measure of what the model leaves, by the
    estimator of :func:`noise_estimate` and :func:`signal_scale` (a MAD is smaller on
    heavy-tailed residuals such as glints, and the IRLS scale is floored at the noise)."""
    scale, w = irls_weights(r, used, code, floor)
    rule = used * _weight(_pixel_u(r, scale, jnp.maximum(code, 1)), jnp.maximum(code, 1))
    outliers = (used > 0) & (rule < OUTLIER_WEIGHT)
    loss = _robust_loss(r, used, scale, code)
    loss_init = _robust_loss(r_init, used, scale, code)
    frac = jnp.sum(outliers) / jnp.maximum(jnp.sum(used), 1.0)
    return w, outliers, loss, loss_init, scale, frac, _trimmed_sigma(r, jnp.broadcast_to(used[..., None] > 0, r.shape))


def _trimmed_sigma(x, valid):
    """Standard deviation of zero-mean ``x`` from the mean of ``|x|`` over the ``valid``
    entries below the 90th percentile of ``|x|``, divided by that truncated mean of a unit
    half-normal (0.6573): robust to 10% outliers, and unlike a median it does not collapse to
    0 on 8-bit data whose values are mostly equal."""
    a = jnp.where(valid, jnp.abs(x), jnp.nan)
    q = jnp.nanquantile(a, _TRIM)
    keep = valid & (jnp.abs(x) <= q)
    return jnp.sum(jnp.where(keep, jnp.abs(x), 0.0)) / jnp.maximum(jnp.sum(keep), 1) / _TRIMMED_HALF_NORMAL


@jax.jit
def noise_estimate(target, used):
    """Immerkaer's noise estimate of ``target (T, H, W, C)`` over used 3x3 neighbourhoods."""
    k = ((1.0, -2.0, 1.0), (-2.0, 4.0, -2.0), (1.0, -2.0, 1.0))
    T, H, W, C = target.shape
    conv = sum(k[i][j] * target[:, i:H - 2 + i, j:W - 2 + j] for i in range(3) for j in range(3))
    ok = functools.reduce(jnp.logical_and, [used[:, i:H - 2 + i, j:W - 2 + j] > 0 for i in range(3) for j in range(3)])
    sigma = _trimmed_sigma(conv, jnp.broadcast_to(ok[..., None], conv.shape)) / 6.0
    return jnp.where(jnp.any(ok), sigma, jnp.nan)


@jax.jit
def signal_scale(target, used):
    """Spread of ``target`` about its per-row median over used pixels (all frames, columns)."""
    T, H, W, C = target.shape
    valid = jnp.broadcast_to(used[..., None] > 0, target.shape)
    t = jnp.where(valid, target, jnp.nan)
    rows = jnp.nanmedian(jnp.moveaxis(t, 1, 0).reshape(H, T * W, C), axis=1)  # (H, C)
    return _trimmed_sigma(jnp.where(valid, target - rows[None, :, None, :], 0.0), valid)
