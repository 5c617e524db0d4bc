"""The wave fit's model and its Jacobian (:mod:`jaxocean.fit.waves`).

Protocol: parameters are ``y (4N,)`` = ``(a, b, log omega, theta)`` per wave with ``(a, b) =
h (cos phi, sin phi)`` (:func:`pack` / :func:`to_waves`); :func:`predict` is the forward
model (``render.geometry`` with every wave evaluated, on the rows path or, where the waves
move a pixel's hit, the hits path: :class:`Predicted`); :func:`jacobian` is the hand-written
residual Jacobian of the normals at fixed rest positions on flat samples (exact on the rows
path; on the hits path it omits the motion of the hit, an approximation the solver only
uses for its curvature); :func:`roughness_rows` the model's sub-pixel roughness per image row; :func:`loss`
the paper's loss (eq. 5-7) and :func:`metrics` the loss, mean normal angle [rad] and mean
absolute roughness difference of a fit.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxocean import hierarchy, render, shading
from jaxocean._math import angle_between, safe_sqrt, sincos
from jaxocean._roughness import row_roughness
from jaxocean.errors import is_concrete
from jaxocean.fit.waves._inputs import (Samples, check_inputs, clean_inputs, plane_hits, valid_weights)
from jaxocean.surface import normal_from_sums
from jaxocean.waves import GRAVITY, Waves, validate


#: padded wave counts: every count of a size class shares one compiled program. A step of
#: the structured LM costs about the square of the padded count (its J^T J), so the classes
#: are closer where default fits end (up to 96 waves plus the long-wave band's, 72 by default):
#: measured on the hits path of a 128^2, 10-frame scene, 1.5 s a step at 160 against 1.8 s at 192
BUCKETS = (16, 32, 64, 96, 128, 160, 192, 256, 384, 512)


# =============================================================================== parameters


def pack(w: Waves):
    """Waves -> parameter vector ``(4N,)`` = (a, b, log omega, theta)."""
    return jnp.concatenate([w.amplitude * jnp.cos(w.phase), w.amplitude * jnp.sin(w.phase), jnp.log(w.omega),
                            w.theta])


def unpack(y, n):
    return y.reshape(4, n)


def phase_of(a, b):
    """The phase ``atan2(b, a)`` in ``[0, 2 pi)`` of ``(a, b) = h (cos phi, sin phi)``, with
    finite gradients everywhere: 0 (value and gradient) at ``a = b = 0``, where a zero
    amplitude has no phase and ``atan2``'s gradient is NaN."""
    ok = a * a + b * b > 1e-30
    return jnp.mod(jnp.where(ok, jnp.arctan2(jnp.where(ok, b, 0.0), jnp.where(ok, a, 1.0)), 0.0), 2 * jnp.pi)


def to_waves(y, n) -> Waves:
    a, b, u, th = unpack(y, n)
    return Waves(safe_sqrt(a * a + b * b), jnp.exp(u), wrap_angle(th), phase_of(a, b))


def active_waves(y, active) -> Waves:
    """The waves of packed parameters ``y (4N,)`` with the inactive (padding) ones silenced."""
    w = to_waves(y, active.shape[0])
    return w._replace(amplitude=w.amplitude * active)


def wrap_angle(theta):
    return jnp.mod(theta + jnp.pi, 2 * jnp.pi) - jnp.pi


def bucket_size(n: int) -> int:
    for b in BUCKETS:
        if n <= b:
            return b
    return int(64 * math.ceil(n / 64))


def pad_waves(w: Waves, n_pad: int):
    n = w.omega.shape[-1]
    pad = n_pad - n
    if pad == 0:
        return w, jnp.ones(n, bool)
    dtype = w.omega.dtype
    z = jnp.zeros(pad, dtype)
    padded = Waves(jnp.concatenate([w.amplitude, z]), jnp.concatenate([w.omega, jnp.ones(pad, dtype)]),
                   jnp.concatenate([w.theta, z]), jnp.concatenate([w.phase, z]))
    return padded, jnp.arange(n_pad) < n


# =============================================================================== forward model


#: ``refine`` of the fit's two forward models: the rows path (geometry at each pixel's
#: mean-sea-plane hit) and the hits path (at its converged hit on the displaced surface)
ROWS = 0
HITS = render.MAX_REFINE_ITERATIONS


SURFACES = ("auto", "rows", "hits")


def surface_refine(surface: str, waves_: Waves | None, camera, *, n_min=hierarchy.DEFAULT_N_MIN,
                   n_max=hierarchy.DEFAULT_N_MAX) -> int:
    """``refine`` of the forward model for ``surface``: ``"rows"`` -> ``ROWS``, ``"hits"`` ->
    ``HITS``, ``"auto"`` -> what ``render.geometry(plan="auto")`` picks for ``waves_`` (the hits
    path where they move some pixel's hit by half a footprint or more; ``ROWS`` without waves)."""
    if surface not in SURFACES:
        raise ValueError(f"surface must be one of {SURFACES}; got {surface!r}")
    if surface != "auto":
        return ROWS if surface == "rows" else HITS
    if waves_ is None or waves_.omega.shape[0] == 0:
        return ROWS
    return HITS if bool(render.needs_refinement(waves_, camera, n_min=n_min, n_max=n_max)) else ROWS


class Predicted(NamedTuple):
    """The model's geometry of a sequence: ``normal (T, H, W, 3)``, ``roughness (T, H, W)``,
    ``xy (T, H, W, 2)`` the rest position [m] each pixel sees (the plane hit on the rows path,
    the converged hit's on the hits path) and ``converged (T, H, W)`` (False where a hit did
    not converge: no exact value there, see :class:`jaxocean.render.Geometry`)."""

    normal: jax.Array
    roughness: jax.Array
    xy: jax.Array
    converged: jax.Array
    z: jax.Array | None = None  # (T, H, W) height [m] of each pixel's hit, with ``with_z`` only


def predict(waves_: Waves, camera, times, *, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX,
            surface: str = "rows"):
    """The fit's forward model: normals ``(T, H, W, 3)`` and roughness ``(T, H, W)`` of
    ``waves_`` at ``times`` (``render.geometry`` with every wave evaluated). ``surface``:
    ``"rows"`` (the geometry at each pixel's mean-sea-plane hit), ``"hits"`` (at its converged
    hit on the displaced surface: what a camera sees) or ``"auto"`` (``render``'s choice for
    ``waves_``: the sea as ``render`` and ``jaxocean simulate`` draw it; eager only)."""
    validate(waves_, max_steepness=None)
    if surface == "auto" and not is_concrete(waves_, camera):
        raise ValueError("surface='auto' chooses the model eagerly; under jit/vmap pass 'rows' or 'hits'")
    refine = surface_refine(surface, waves_, camera, n_min=n_min, n_max=n_max)
    times = jnp.atleast_1d(jnp.asarray(times, waves_.omega.dtype))
    p = predict_jit(waves_, camera, times, n_min, n_max, refine)
    return p.normal, p.roughness


@functools.partial(jax.jit, static_argnums=(3, 4, 5, 6, 7))
def predict_jit(waves_, camera, times, n_min, n_max, refine=ROWS, with_z=False, unroll=False) -> Predicted:
    # ``with_z``: also the hits' heights (a jitted output is always computed, so the
    # displacement is evaluated only for the fits that use it). ``unroll``: the hits path
    # frame by frame in the program, not in a loop over frames: inside the LM's loop that ran
    # 1.4x faster on XLA:CPU (8 steps of a 64-wave refinement at 128^2, 10 frames: 1.9 s
    # against 2.6 s) and compiled 3x slower; a single evaluation runs as fast either way.
    plan = render.full_plan(waves_.omega.shape[-1], refine)

    def one(t):
        g = render.geometry(waves_, camera, t, plan=plan, n_min=n_min, n_max=n_max)
        return Predicted(g.normal, g.roughness, g.xy, g.converged & g.mask, g.position[..., 2] if with_z else None)

    if refine == ROWS or not unroll:
        return jax.lax.map(one, times)
    return jax.tree.map(lambda *a: jnp.stack(a), *[one(times[i]) for i in range(times.shape[0])])


def _nxy(sums):
    return normal_from_sums(sums[0], sums[1], sums[2], sums[3], sums[4])[:2]


def wave_phases(P, act, s: Samples, n_min, n_max):
    """What :func:`jacobian` and the height residual's Jacobian share, per sample and wave
    ``(S, N)`` (``c, sn, om, k (N,)``): ``(om, k, c, sn, w, dw_du, proj, psi0, dpsi_du,
    dpsi_dth)`` -- the hierarchy weight ``w`` at the sample's footprint and its derivative
    in log omega, the projection ``k_hat . X``, the phase ``psi0 = omega t - k k_hat . X``
    and its derivatives in log omega and theta."""
    u, th = P[2], P[3]
    om = jnp.exp(u)
    k = om * om / GRAVITY
    c, sn = jnp.cos(th), jnp.sin(th)
    x = (2 * jnp.pi / k)[None, :] / s.fp[:, None]  # (S, N) wavelength / footprint
    width = n_max - n_min
    q = jnp.clip((x - n_min) / width, 0.0, 1.0)
    w = q * q * (3.0 - 2.0 * q) * act
    # d(lambda/fp)/d log omega = -2 lambda/fp; x clipped where the smoothstep is flat anyway
    dw_du = 6.0 * q * (1.0 - q) / width * (-2.0 * jnp.clip(x, n_min, n_max)) * act
    proj = s.xy[:, :1] * c + s.xy[:, 1:] * sn  # (S, N)
    psi0 = om * s.t[:, None] - k * proj
    dpsi_du = om * s.t[:, None] - 2.0 * k * proj
    dpsi_dth = k * (sn * s.xy[:, :1] - c * s.xy[:, 1:])
    return om, k, c, sn, w, dw_du, proj, psi0, dpsi_du, dpsi_dth


def height_partials(w, cp, sp, cn, snn, dw_du, dpsi_du, dpsi_dth):
    """``(S, 4, N)``: the derivatives of each wave's vertical displacement ``d_z = w h cos(psi)
    = w (a cos psi0 - b sin psi0)`` in ``(a, b, log omega, theta)`` (``cn = h cos psi``,
    ``snn = h sin psi``)."""
    return jnp.stack([w * cp, -w * sp, dw_du * cn - w * snn * dpsi_du, -w * snn * dpsi_dth], 1)


def jacobian(P, act, s: Samples, n_min, n_max, moving: bool = False):
    """Residual ``r (S*2,)`` and its Jacobian ``J (S*2, 4N)`` for samples ``s`` (hand-written
    chain rule: each wave's parameters touch only its own sine and cosine).

    Model per wave: C = w k (a cos psi0 - b sin psi0), S = w k (a sin psi0 + b cos psi0),
    sums (A_xx, A_xy, A_yy, B_x, B_y) = sum (c^2 C, c s C, s^2 C, c S, s S), normal from the
    sums; ``P = (a, b, log omega, theta) (4, N)``.

    ``moving``: the samples' rest positions are hits (the hits path) and move with the
    parameters: the hit X solves X = F(X) = o + (d_z(X) - o_z) s - d_xy(X) with s the ray's
    horizontal run per unit height (``s.ray``), so dX/dp = (I - dF/dX)^-1 dF/dp (implicit
    function theorem) and the normals gain (dn/dX) dX/dp. Exact at a converged hit.
    """
    a, b = P[0], P[1]
    om, k, c, sn, w, dw_du, proj, psi0, dpsi_du, dpsi_dth = wave_phases(P, act, s, n_min, n_max)
    sp, cp = sincos(psi0)
    wk = w * k
    cn, snn = a * cp - b * sp, a * sp + b * cp
    C, S = wk * cn, wk * snn
    cc, cs, ss = c * c, c * sn, sn * sn
    sums = jnp.stack([C @ cc, C @ cs, C @ ss, S @ c, S @ sn])  # (5, S)
    G = jax.vmap(jax.jacfwd(_nxy), in_axes=1)(sums)  # (S, 2, 5)
    nrm = jax.vmap(_nxy, in_axes=1)(sums)  # (S, 2)
    r = ((nrm - s.target) * s.sw[:, None]).reshape(-1)
    g = [G[:, :, i:i + 1] for i in range(5)]  # (S, 2, 1) each
    alpha = g[0] * cc + g[1] * cs + g[2] * ss  # (S, 2, N)
    beta = g[3] * c + g[4] * sn
    alpha_t = g[0] * (-2.0 * cs) + g[1] * (cc - ss) + g[2] * (2.0 * cs)
    beta_t = -g[3] * sn + g[4] * c
    e = lambda z: z[:, None, :]  # noqa: E731  (S, N) -> (S, 1, N)
    dwk_du = k * dw_du + 2.0 * wk
    j_a = e(wk) * (alpha * e(cp) + beta * e(sp))
    j_b = e(wk) * (beta * e(cp) - alpha * e(sp))
    j_u = alpha * e(dwk_du * cn - S * dpsi_du) + beta * e(dwk_du * snn + C * dpsi_du)
    j_t = (beta * e(C) - alpha * e(S)) * e(dpsi_dth) + alpha_t * e(C) + beta_t * e(S)
    J = jnp.stack([j_a, j_b, j_u, j_t], axis=2)  # (S, 2, 4, N)
    if moving:
        J = J + _hit_motion(G, C, S, w, k, c, sn, cp, sp, cn, snn, dw_du, dpsi_du, dpsi_dth, s.ray)
    J = J * s.sw[:, None, None, None]
    return r, J.reshape(r.shape[0], -1)


def _hit_motion(G, C, S, w, k, c, sn, cp, sp, cn, snn, dw_du, dpsi_du, dpsi_dth, ray):
    """``(dn_xy/dX) dX/dp (S, 2, 4, N)``: the normals' change through the motion of the hit
    (see :func:`jacobian`). Displacement per wave: d_z = w h cos(psi), d_xy = w h sin(psi)
    (cos theta, sin theta), with h cos(psi) = a cos psi0 - b sin psi0 =: cn and h sin(psi) =: snn."""
    # d(sums)/dX (S, 5, 2): dC/dX = k S khat, dS/dX = -k C khat
    kS, kC = S * k, C * k
    cc, cs, ss = c * c, c * sn, sn * sn
    dsums = jnp.stack([jnp.stack([kS @ (cc * c), kS @ (cc * sn)], -1),
                       jnp.stack([kS @ (cs * c), kS @ (cs * sn)], -1),
                       jnp.stack([kS @ (ss * c), kS @ (ss * sn)], -1),
                       jnp.stack([-(kC @ (c * c)), -(kC @ (c * sn))], -1),
                       jnp.stack([-(kC @ (sn * c)), -(kC @ (sn * sn))], -1)], axis=1)
    dn_dX = jnp.einsum("sij,sjk->sik", G, dsums)  # (S, 2, 2)
    # dF/dX = s (grad d_z)^T - d(d_xy)/dX, grad d_z = (B_x, B_y), -d(d_xy)/dX = A
    b = jnp.stack([S @ c, S @ sn], -1)  # (S, 2)
    a_xx, a_xy, a_yy = C @ cc, C @ cs, C @ ss
    A = jnp.stack([jnp.stack([a_xx, a_xy], -1), jnp.stack([a_xy, a_yy], -1)], -2)
    dF_dX = ray[:, :, None] * b[:, None, :] + A
    eye = jnp.eye(2, dtype=A.dtype)
    move = jnp.einsum("sij,sjk->sik", dn_dX, jnp.linalg.inv(eye - dF_dX))  # (S, 2, 2)
    # dF/dp per wave: s d(d_z)/dp - d(d_xy)/dp, with d(d_xy) = khat d(w snn) (+ theta's turn)
    dz = height_partials(w, cp, sp, cn, snn, dw_du, dpsi_du, dpsi_dth)  # (S, 4, N)
    dh = jnp.stack([w * sp, w * cp, dw_du * snn + w * cn * dpsi_du, w * cn * dpsi_dth], 1)  # along khat
    turn = w * snn  # d(khat)/dtheta = (-sin, cos)
    dF_x = ray[:, 0, None, None] * dz - c * dh
    dF_y = ray[:, 1, None, None] * dz - sn * dh
    dF_x = dF_x.at[:, 3].add(sn * turn)
    dF_y = dF_y.at[:, 3].add(-c * turn)
    dF = jnp.stack([dF_x, dF_y], 1)  # (S, 2, 4, N)
    return jnp.einsum("sij,sjpn->sipn", move, dF)


def roughness_rows(y, active, fp_row, n_min, n_max):
    """Model roughness per image row ``(H,)`` from the fitted waves (no floor):
    :func:`jaxocean._roughness.row_roughness` of the active waves at the row footprints."""
    w = to_waves(y, active.shape[0])
    return row_roughness(w.omega * w.omega / GRAVITY, w.amplitude * active, fp_row, n_min, n_max)


class RoughRows(NamedTuple):
    """Roughness data per image row: ``target (H,)`` mean observed roughness minus the
    (fixed) tail, ``sw (H,)`` sqrt of the residual weight, ``fp (H,)`` footprints."""

    target: jax.Array
    sw: jax.Array
    fp: jax.Array


def rough_data(roughness, weight, camera, n_valid, roughness_weight, tail_rows=None) -> RoughRows:
    _, fp_row, _ = plane_hits(camera)
    count = jnp.sum(weight, axis=(0, 2))  # (H,)
    mean = jnp.sum(roughness * weight, axis=(0, 2)) / jnp.maximum(count, 1.0)
    if tail_rows is not None:
        mean = mean - tail_rows
    sw = jnp.sqrt(2.0 * roughness_weight * count / n_valid)
    return RoughRows(mean, sw, fp_row)


def rough_residual(y, active, rough: RoughRows, tail_rows, n_min, n_max):
    model = roughness_rows(y, active, rough.fp, n_min, n_max)
    total = jnp.maximum(model + tail_rows, shading.MIN_SLOPE_VARIANCE) - tail_rows
    return (total - rough.target) * rough.sw


# =============================================================================== losses


def loss(waves_: Waves, normals, roughness, camera, times, *, roughness_weight=1.0,
         n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX, refine: int = ROWS):
    """The paper's loss (eq. 5-7) of ``waves_`` against observed geometry: mean ``1 - cos``
    of the normal angle plus ``roughness_weight`` times the mean squared roughness
    difference, over valid sea pixel-frames (and, on the hits path, converged hits).
    Differentiable in the waves and the data."""
    normals, roughness, times = check_inputs(normals, roughness, camera, times)
    validate(waves_, max_steepness=None)
    return metrics(waves_, normals, roughness, camera, times, roughness_weight, n_min, n_max, refine)[0]


def metrics(waves_, normals, roughness, camera, times, roughness_weight, n_min, n_max, refine=ROWS):
    weight = valid_weights(normals, camera)
    normals, roughness = clean_inputs(normals, roughness, weight)
    pred = predict_jit(waves_, camera, times, n_min, n_max, refine)
    n_pred, r_pred = pred.normal, pred.roughness
    weight = weight * pred.converged
    n_valid = jnp.maximum(jnp.sum(weight), 1.0)
    cos = jnp.clip(jnp.sum(n_pred * normals, -1), -1.0, 1.0)
    one_minus = jnp.sum((1.0 - cos) * weight) / n_valid
    rough = jnp.sum((r_pred - roughness) ** 2 * weight) / n_valid
    angle = angle_between(n_pred, normals)
    return (one_minus + roughness_weight * rough, jnp.sum(angle * weight) / n_valid,
            jnp.sum(jnp.abs(r_pred - roughness) * weight) / n_valid)
