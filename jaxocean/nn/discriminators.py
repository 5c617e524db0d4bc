"""Patch discriminators and the least-squares GAN losses of the paper's eq. 4.

Protocol
--------
* :func:`PatchDiscriminator(width, depth)` is a :class:`~jaxocean.nn.layers.Layer` from maps
  ``(B, H, W, C)`` to patch logits ``(B, H / 2**depth, W / 2**depth, 1)``: ``depth``
  stride-2 ``conv - GroupNorm - LeakyReLU`` blocks and a 1x1 head (PatchGAN, Isola et al.
  2017). A spatial discriminator sees one map (normals: 3 channels; log slope variances:
  2); a temporal one sees two consecutive frames concatenated along channels.
* :func:`discriminator_loss(real, fake)` and :func:`generator_loss(fake)` are the
  least-squares GAN losses (Mao et al. 2017): ``E[(D(real) - 1)^2] + E[D(fake)^2]`` and
  ``E[(D(fake) - 1)^2]``, averaged over the patches where ``weight`` (the sea fraction of
  each patch, ``(B, h, w)``) is positive. Least squares rather than the log loss because
  it does not saturate when the discriminator wins early, which on small CPU runs it does.
"""

from __future__ import annotations

import jax.numpy as jnp

from jaxocean.nn import layers as nl

__all__ = ["PatchDiscriminator", "patch_weight", "discriminator_loss", "generator_loss"]


def PatchDiscriminator(width: int = 16, depth: int = 3) -> nl.Layer:
    blocks = []
    for i in range(depth):
        w = width * 2 ** i
        blocks += [nl.Conv(w, 4, 2), nl.GroupNorm(max(1, min(8, w // 2))), nl.LeakyRelu(0.2)]
    return nl.serial(*blocks, nl.Conv(1, 1, w_scale=0.5))


def patch_weight(mask, depth: int):
    """Sea fraction of each discriminator patch ``(B, H / 2**depth, W / 2**depth)``."""
    f = 2 ** depth
    B, H, W = mask.shape
    Hp, Wp = -(-H // f), -(-W // f)
    m = jnp.pad(mask.astype(jnp.float32), ((0, 0), (0, Hp * f - H), (0, Wp * f - W)))
    return m.reshape(B, Hp, f, Wp, f).mean((2, 4))


def _mean(x, weight):
    return jnp.sum(x * weight) / jnp.maximum(jnp.sum(weight), 1.0)


def discriminator_loss(real_logits, fake_logits, weight):
    return _mean(jnp.square(real_logits[..., 0] - 1.0), weight) + _mean(jnp.square(fake_logits[..., 0]), weight)


def generator_loss(fake_logits, weight):
    return _mean(jnp.square(fake_logits[..., 0] - 1.0), weight)
