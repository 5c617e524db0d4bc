"""Display augmentation: linear training frames turned into what a camera file gives.

A geometry network trained on the renderer's linear radiance meets, in use, frames that a
camera (or ``experiments/reconstruct.py``) wrote as display values: the radiance times an
unknown exposure, through a response curve, with display noise, clipped to [0, 1] and
quantised to 8 bits. ``jaxocean reconstruct`` turns them back into radiance relative to the
unknown exposure (:func:`jaxocean.radiometry.to_linear`, ``exposure=1``) before its
geometry stage. This module makes training frames take the same round trip, so the network
sees at training the kind of input it is given there.

Protocol
--------
* :class:`DisplayAugment` (static, hashable): the ranges a sample's round trip is drawn
  from -- the response kinds (:data:`jaxocean.radiometry.RESPONSE_KINDS`, drawn uniformly),
  the exposure range (log-uniform), the display-noise range (uniform, standard deviation in
  units of the display range [0, 1]), the bit depth (None: no quantisation) and the fraction
  of samples left as they are (linear radiance, as OpenEXR frames give it).
* :func:`display_roundtrip(key, linear, response, exposure, noise, bits=8)` -> linear: one
  round trip with given settings, ``to_display(linear, response, exposure)``, plus
  Gaussian noise of standard deviation ``noise``, clipped to [0, 1], rounded to ``bits``
  bits, then ``to_linear(display, response)``. The result is radiance times ``exposure``
  where nothing clipped and there is no noise or quantisation (exact up to rounding);
  saturated pixels come back at the response's lower bound (``1`` for srgb, gamma and
  linear, ``6.93`` for bruneton; see :mod:`jaxocean.radiometry`).
* :func:`draw(key, config)` -> :class:`DisplayParams` (response index into
  ``config.responses``, exposure, noise, clean flag): one sample's settings.
* :func:`augment(key, linear, config)`: :func:`draw` then :func:`display_roundtrip` (or
  the input unchanged when the sample is drawn clean) for one sample ``(..., H, W[, 3])``
  -- every frame of a sample shares its response, exposure and noise level (one camera),
  the noise itself is independent per pixel, channel and frame. ``jax.vmap`` it over a
  batch with split keys.

Everything is pure JAX, jittable and deterministic per key: the same key gives the same
result, traced or not. Shapes are unchanged; values are float32 radiance >= 0.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxocean import radiometry
from jaxocean._records import register_static

__all__ = ["DisplayAugment", "DisplayParams", "display_roundtrip", "draw", "augment"]


class DisplayAugment(NamedTuple):
    """Ranges of the display round trip (see the module docstring)."""

    responses: tuple = ("srgb", "gamma", "bruneton")  # drawn uniformly; "gamma" uses ``gamma``
    gamma: float = 2.2
    exposure: tuple = (0.5, 2.0)  # log-uniform
    noise: tuple = (0.0, 0.03)  # uniform, standard deviation in display units
    bits: int | None = 8
    clean_fraction: float = 0.2  # samples passed through unchanged

    def validate(self) -> "DisplayAugment":
        if not self.responses or any(r not in radiometry.RESPONSE_KINDS for r in self.responses):
            raise ValueError(f"responses must be kinds of {radiometry.RESPONSE_KINDS}; got {self.responses!r}")
        lo, hi = self.exposure
        if not 0 < lo <= hi:
            raise ValueError(f"exposure range must satisfy 0 < low <= high; got {self.exposure}")
        lo, hi = self.noise
        if not 0 <= lo <= hi:
            raise ValueError(f"noise range must satisfy 0 <= low <= high; got {self.noise}")
        if self.bits is not None and not 1 <= int(self.bits) <= 16:
            raise ValueError(f"bits must be None or 1..16; got {self.bits}")
        if not 0 <= self.clean_fraction <= 1:
            raise ValueError(f"clean_fraction must be in [0, 1]; got {self.clean_fraction}")
        return self

    def responses_of(self) -> tuple:
        """The :class:`jaxocean.radiometry.Response` of each kind in ``responses``."""
        return tuple(radiometry.Response(kind, self.gamma) for kind in self.responses)


# static, as GeometryConfig: jax.jit(augment)(key, linear, config) traces the key and images alone
register_static(DisplayAugment)


class DisplayParams(NamedTuple):
    """One sample's round trip: ``response`` (int index into ``DisplayAugment.responses``),
    ``exposure``, ``noise`` (display units) and ``clean`` (bool: left unchanged)."""

    response: jax.Array
    exposure: jax.Array
    noise: jax.Array
    clean: jax.Array


def display_roundtrip(key, linear, response: radiometry.Response, exposure=1.0, noise=0.0, bits: int | None = 8):
    """``linear`` radiance -> display (``response``, ``exposure``) + noise, clipped and
    quantised -> radiance relative to the exposure, as ``reconstruct`` loads it.

    ``response`` is static; ``exposure`` and ``noise`` may be traced scalars. ``key`` draws
    the noise (drawn always, scaled by ``noise``: 0 adds nothing)."""
    linear = jnp.asarray(linear, jnp.float32)
    display = radiometry.to_display(linear, response, exposure)
    display = display + noise * jax.random.normal(key, linear.shape, linear.dtype)
    display = jnp.clip(display, 0.0, 1.0)
    if bits is not None:
        levels = 2.0 ** int(bits) - 1.0
        display = jnp.round(display * levels) / levels
    return radiometry.to_linear(display, response).astype(jnp.float32)


def draw(key, config: DisplayAugment) -> DisplayParams:
    """One sample's settings drawn from ``config``'s ranges."""
    k_resp, k_exp, k_noise, k_clean = jax.random.split(key, 4)
    lo, hi = config.exposure
    log_e = jax.random.uniform(k_exp, (), jnp.float32, jnp.log(lo), jnp.log(hi))
    return DisplayParams(jax.random.randint(k_resp, (), 0, len(config.responses)), jnp.exp(log_e),
                         jax.random.uniform(k_noise, (), jnp.float32, *config.noise),
                         jax.random.uniform(k_clean, ()) < config.clean_fraction)


def augment(key, linear, config: DisplayAugment):
    """One sample ``(..., H, W[, 3])`` through a round trip drawn from ``config`` (module
    docstring)."""
    k_draw, k_noise = jax.random.split(key)
    p = draw(k_draw, config)
    linear = jnp.asarray(linear, jnp.float32)
    branches = [lambda x, r=r: display_roundtrip(k_noise, x, r, p.exposure, p.noise, config.bits)
                for r in config.responses_of()]
    out = jax.lax.switch(p.response, branches, linear)
    return jnp.where(p.clean, linear, out)
