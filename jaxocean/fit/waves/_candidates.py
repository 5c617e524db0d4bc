"""Candidate scoring of the wave fit's selection (:mod:`jaxocean.fit.waves._select`).

Protocol: a candidate is a wave vector ``(omega [rad/s], theta [rad])``; each is scored by
the energy its single-wave least-squares fit explains of the residual slopes of a
:class:`~jaxocean.fit.waves._inputs.Samples` subsample (:func:`score_candidates`), refined
in ``(omega, theta)`` by Gauss-Newton on that energy (:func:`refine_candidates`), and the
chosen ones are solved jointly for their amplitudes (:func:`joint_amplitudes`). Shapes:
``(C,)`` candidates, ``(S,)`` samples; all jitted, with ``n_min``, ``n_max`` static.
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from jaxocean._math import sincos, smoothstep
from jaxocean.fit.waves._inputs import Samples
from jaxocean.fit.waves._model import wrap_angle
from jaxocean.waves import GRAVITY


def _single_wave_stats(om, th, s: Samples, n_min, n_max):
    """Sufficient statistics of the single-wave least-squares fit of residual slopes
    ``s.target`` along ``k_hat``: ``(su, sv, uu, vv, uv)`` with templates
    ``u = w k sin psi0``, ``v = w k cos psi0`` (weights ``s.sw^2``)."""
    k = om * om / GRAVITY
    c, sn = jnp.cos(th), jnp.sin(th)
    amp = smoothstep(n_min, n_max, (2 * jnp.pi / k) / s.fp) * k
    psi0 = om * s.t - k * (c * s.xy[:, 0] + sn * s.xy[:, 1])
    rk = s.target[:, 0] * c + s.target[:, 1] * sn
    sp, cp = sincos(psi0)
    wa = s.sw * s.sw * amp
    wa2 = wa * amp
    return (jnp.sum(wa * sp * rk), jnp.sum(wa * cp * rk), jnp.sum(wa2 * sp * sp), jnp.sum(wa2 * cp * cp),
            jnp.sum(wa2 * sp * cp))


def _energy_ab(stats):
    su, sv, uu, vv, uv = stats
    det = uu * vv - uv * uv
    ok = det > 1e-9 * (uu * vv) + 1e-30
    det = jnp.where(ok, det, 1.0)
    a = jnp.where(ok, (vv * su - uv * sv) / det, 0.0)
    b = jnp.where(ok, (uu * sv - uv * su) / det, 0.0)
    return a * su + b * sv, a, b


@functools.partial(jax.jit, static_argnums=(3, 4))
def score_candidates(omega, theta, s: Samples, n_min, n_max):
    """Energy each single candidate wave removes from the residual slopes, and its (a, b)."""

    def one(x):
        return _energy_ab(_single_wave_stats(x[0], x[1], s, n_min, n_max))

    return jax.lax.map(one, (omega, theta), batch_size=32)


def _single_wave_jac(p, s: Samples, n_min, n_max):
    """Residual ``(S, 2)`` and Jacobian ``(S, 2, 4)`` of one linear slope template
    ``w k (a sin psi0 + b cos psi0) k_hat`` against ``s.target``; ``p = (a, b, log omega,
    theta)``."""
    a, b, u, th = p[0], p[1], p[2], p[3]
    om = jnp.exp(u)
    k = om * om / GRAVITY
    c, sn = jnp.cos(th), jnp.sin(th)
    x = (2 * jnp.pi / k) / s.fp
    width = n_max - n_min
    q = jnp.clip((x - n_min) / width, 0.0, 1.0)
    w = q * q * (3.0 - 2.0 * q)
    dw_du = 6.0 * q * (1.0 - q) / width * (-2.0 * jnp.clip(x, n_min, n_max))
    proj = c * s.xy[:, 0] + sn * s.xy[:, 1]
    psi0 = om * s.t - k * proj
    sp, cp = sincos(psi0)
    amp = w * k
    lin = a * sp + b * cp
    dlin = a * cp - b * sp  # d lin / d psi0
    khat = jnp.stack([c, sn])
    kperp = jnp.stack([-sn, c])
    model = (amp * lin)[:, None] * khat
    r = (model - s.target) * s.sw[:, None]
    d_amp_du = k * dw_du + 2.0 * amp
    dpsi_du = om * s.t - 2.0 * k * proj
    dpsi_dth = k * (sn * s.xy[:, 0] - c * s.xy[:, 1])
    ja = (amp * sp)[:, None] * khat
    jb = (amp * cp)[:, None] * khat
    ju = (d_amp_du * lin + amp * dlin * dpsi_du)[:, None] * khat
    jt = (amp * dlin * dpsi_dth)[:, None] * khat + (amp * lin)[:, None] * kperp
    J = jnp.stack([ja, jb, ju, jt], -1) * s.sw[:, None, None]
    return r, J


@functools.partial(jax.jit, static_argnums=(3, 4, 5))
def refine_candidates(omega, theta, s: Samples, n_min, n_max, iters):
    """Single-wave Levenberg-Marquardt in (a, b, log omega, theta) on the residual slopes,
    vmapped over candidates; returns refined (omega, theta), removed energy, (a, b)."""

    def one(om, th):
        e0, a0, b0 = _energy_ab(_single_wave_stats(om, th, s, n_min, n_max))
        p0 = jnp.stack([a0, b0, jnp.log(om), th])

        def rss(p):
            r, _ = _single_wave_jac(p, s, n_min, n_max)
            return jnp.sum(r * r)

        def step(carry, _):
            p, f, lam = carry
            r, J = _single_wave_jac(p, s, n_min, n_max)
            J = J.reshape(-1, 4)
            A = J.T @ J
            g = J.T @ r.reshape(-1)
            d = jnp.maximum(jnp.diag(A), 1e-12 * jnp.max(jnp.diag(A)) + 1e-30)
            dp = -jnp.linalg.solve(A + lam * jnp.diag(d), g)
            dp = dp.at[2:].set(jnp.clip(dp[2:], -0.05, 0.05))
            p_new = p + jnp.where(jnp.all(jnp.isfinite(dp)), dp, 0.0)
            f_new = rss(p_new)
            ok = f_new < f
            return (jnp.where(ok, p_new, p), jnp.where(ok, f_new, f), jnp.where(ok, lam * 0.3, lam * 4.0)), None

        (p, _, _), _ = jax.lax.scan(step, (p0, rss(p0), jnp.asarray(1e-3, p0.dtype)), None, length=iters)
        e, a, b = _energy_ab(_single_wave_stats(jnp.exp(p[2]), p[3], s, n_min, n_max))
        return jnp.exp(p[2]), wrap_angle(p[3]), e, a, b

    return jax.vmap(one)(omega, theta)


@functools.partial(jax.jit, static_argnums=(4, 5))
def joint_amplitudes(omega, theta, valid, s: Samples, n_min, n_max):
    """Joint least-squares (a, b) of ``B`` candidate waves on residual slopes, and each
    one's partial energy (the RSS increase if it alone were dropped): sidelobes and
    repeats of one wave lose their energy once the main lobe is in the same solve."""
    B = omega.shape[0]
    k = omega * omega / GRAVITY
    khat = jnp.stack([jnp.cos(theta), jnp.sin(theta)], -1)  # (B, 2)
    amp = smoothstep(n_min, n_max, (2 * jnp.pi / k)[None, :] / s.fp[:, None]) * k * valid  # (S, B)
    psi0 = omega * s.t[:, None] - (s.xy @ (k[:, None] * khat).T)  # (S, B)
    sw = s.sw[:, None, None]
    sp, cp = sincos(psi0)
    U = jnp.concatenate([(amp * sp)[:, None, :] * khat.T[None], (amp * cp)[:, None, :]
                         * khat.T[None]], -1) * sw  # (S, 2, 2B)
    U = U.reshape(-1, 2 * B)
    r = (s.target * s.sw[:, None]).reshape(-1)
    G = U.T @ U
    G = G + 1e-7 * jnp.diag(jnp.diag(G)) + jnp.diag(jnp.where(jnp.tile(valid, 2) > 0, 0.0, 1.0)).astype(G.dtype)
    x = jnp.linalg.solve(G, U.T @ r)
    Ginv = jnp.linalg.inv(G)
    idx = jnp.stack([jnp.arange(B), jnp.arange(B) + B], -1)  # (B, 2)
    blocks = Ginv[idx[:, :, None], idx[:, None, :]]  # (B, 2, 2)
    xb = x[idx]  # (B, 2)
    partial = jnp.einsum("bi,bi->b", xb, jnp.linalg.solve(blocks, xb[..., None])[..., 0])
    return x[:B], x[B:], partial
