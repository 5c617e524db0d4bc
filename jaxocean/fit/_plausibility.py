"""What a fit's final loss must be for its answer to explain the data, and which fitted
parameters the data determine. Shared by the image fits (lighting, camera).

Protocol
--------
Every image fit minimises the weighted mean square residual

    loss = sum(w^2 (model - image)^2) / sum(w^2)        (linear radiance squared)

over pixels and channels, ``w`` the fit's weights (``(H, W, 3)``, 0 on unused pixels).

* ``noise`` [same units as ``w * image``; >= 0]: the RMS of the weighted residual the data
  allow at the true parameters. With the default display weights (the tone map's slope) and
  noise added to display values this is about the noise's standard deviation; with uniform
  weights it is the standard deviation of the noise in linear radiance. ``0`` (what the
  fits use for ``noise=None``): the image is noise-free.
* :func:`loss_bound`: the largest loss a right answer can leave::

      bound = NOISE_FACTOR * (noise^2 + geometry) + LOSS_FLOOR * sum(w^2 image^2) / sum(w^2)

  ``geometry`` [loss units, >= 0; default None: 0] is the loss that errors of the *model's
  inputs* leave at the right answer, added in quadrature to the image noise: for a fit
  whose geometry (normals) carries a stated error, the mean square residual that the error
  propagates into the model image (``fit.lighting``'s ``normal_noise``: the model rendered
  with the normals tilted by draws of the stated error). None: the image-noise rule above,
  bit for bit.

  ``LOSS_FLOOR`` (1e-6: a residual RMS of 1e-3 of the image's) is the models' own
  consistency (rounding, float32 storage, hit refinement); ``NOISE_FACTOR = 1.5`` leaves
  room above the expected ``noise^2`` (fit.camera measured loss / noise^2 = 0.71-0.75 at
  the truth with noise on display values). A stationary point of the loss passes every
  convergence test, a wrong one included: this bound is what tells them apart.
* :func:`parameter_std`: standard deviations of the parameters at the answer from the
  Gauss-Newton covariance ``s^2 (J^T J)^+``, given ``J^T J (P, P)`` with ``J (M, P)`` the Jacobian of the
  normalised residual vector ``r = w (model - image) / sqrt(sum(w^2))`` (so that
  ``loss = |r|^2``) and ``s^2 = (noise^2 + LOSS_FLOOR * energy) / n`` the variance of one of
  its ``n`` used elements (those with ``w > 0``). Computed from the eigenvectors of the
  column-scaled ``J^T J`` as non-negative quadratic forms; a direction with no data (a
  vanishing column, e.g. the sun's angles when no glitter is in view, or a combination of
  columns that cancels) gets a huge standard deviation (``inf`` for an exactly zero
  column), never a negative variance.
* :func:`gauss_newton_step`: ``-(J^T J)^+ J^T r`` with the same regularised pseudo-inverse:
  how far a residual ``r`` moves a least-squares answer (first order); a direction without
  information does not move.

All functions are jittable and vmappable; shapes as stated, float32 or float64.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["NOISE_FACTOR", "LOSS_FLOOR", "energy", "loss_bound", "noise_variance", "parameter_std",
           "gauss_newton_step"]

#: success needs ``loss <= NOISE_FACTOR * noise**2 + LOSS_FLOOR * (weighted mean square image)``
NOISE_FACTOR = 1.5
LOSS_FLOOR = 1e-6


def energy(image, weight):
    """Weighted mean square of ``image`` ``(H, W, 3)`` under ``weight`` (same shape): ``()``."""
    w2 = weight * weight
    return jnp.sum(w2 * image * image) / jnp.sum(w2)


def loss_bound(image, weight, noise, geometry=None):
    """The largest loss a right answer can leave (module docstring), ``()``. ``geometry``
    ``()`` [loss units]: the loss the errors of the model's inputs leave (None: 0, the
    image-noise rule exactly)."""
    var = noise * noise if geometry is None else noise * noise + geometry
    return NOISE_FACTOR * var + LOSS_FLOOR * energy(image, weight)


def noise_variance(image, weight, noise):
    """``s^2``: the variance of one used element of the normalised residual, ``()``."""
    n = jnp.sum(weight > 0)
    return (noise * noise + LOSS_FLOOR * energy(image, weight)) / jnp.maximum(n, 1)


def parameter_std(jtj, variance):
    """Standard deviations ``(P,)`` of the parameters of a least-squares answer.

    ``jtj (P, P)`` is ``J^T J`` of the normalised residual at the answer, ``variance ()``
    the variance of one residual element (:func:`noise_variance`). ``J^T J`` is scaled to
    a unit diagonal (column norms ``d``), decomposed ``V diag(lam) V^T``, and ``var_i =
    variance * sum_j V_ij^2 / max(lam_j, P eps max(lam)) / d_i^2``: a direction without
    information gets the largest variance the working precision can state (about ``1 /
    (P eps)`` in scaled units), never a negative one; a zero column gives ``inf``.
    """
    has, d, lam, vec = _scaled_eigen(jtj)
    var_scaled = jnp.sum(vec * vec / lam[None, :], axis=1)
    var = jnp.where(has, variance * var_scaled / (d * d), jnp.inf)
    return jnp.sqrt(var)


def gauss_newton_step(jtj, jtr):
    """``-(J^T J)^+ J^T r`` ``(P,)`` for ``jtj (P, P)`` and ``jtr (P,)``, with the regularised
    pseudo-inverse of :func:`parameter_std`: the first-order change of a least-squares answer
    when its residual changes by ``r``. A parameter without information (zero column)
    does not move."""
    has, d, lam, vec = _scaled_eigen(jtj)
    g = jnp.where(has, jax.lax.stop_gradient(jtr) / d, 0.0)
    step = vec @ ((vec.T @ g) / lam)
    return jnp.where(has, -step / d, 0.0)


def _scaled_eigen(jtj):
    """``(has, d, lam, vec)``: the columns with information, the column norms, and the
    eigen-decomposition of ``J^T J`` scaled to a unit diagonal, its eigenvalues floored at
    ``P eps max(lam)``."""
    jtj = jax.lax.stop_gradient(jtj)
    dtype = jtj.dtype
    diag = jnp.diagonal(jtj)
    has = diag > jnp.finfo(dtype).tiny
    d = jnp.where(has, jnp.sqrt(jnp.where(has, diag, 1.0)), 1.0)
    scaled = jtj / (d[:, None] * d[None, :])
    scaled = jnp.where(has[:, None] & has[None, :], scaled, jnp.eye(jtj.shape[0], dtype=dtype))
    lam, vec = jnp.linalg.eigh(scaled)
    floor = jnp.finfo(dtype).eps * jnp.max(lam) * lam.shape[0]
    return has, d, jnp.maximum(lam, floor), vec
