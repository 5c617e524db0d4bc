"""Wave fitting: the component waves ``{h, omega, theta, phi}`` behind a sequence of geometry.

Protocol
--------
Inputs describe one scene (map batches of scenes with ``jax.vmap`` through :func:`refine`):

* ``normals``   ``(T, H, W, 3)`` unit normals of the normal-level waves, as
  :func:`jaxocean.render.geometry` returns them (world frame, z up);
* ``roughness`` ``(T, H, W)`` slope variance sigma^2 of the sub-pixel waves (or None);
* ``camera``    the :class:`jaxocean.camera.Camera` the geometry was seen with
  (``camera.resolution == (H, W)``);
* ``times``     ``(T,)`` frame times [s], strictly increasing, ``T >= 2``.

The model is the renderer's own: :func:`jaxocean.render.geometry` on its rows fast path
(no hit refinement, Nyquist weights per image row), so a fitted wave that is partly
sub-pixel is modelled exactly as it was rendered. Sky pixels and pixels whose normal is
not finite or faces down carry no weight.

Loss (the paper's eq. 5-7)::

    loss = mean_pixels (1 - n . n_hat) + roughness_weight * mean_pixels (rho - rho_hat)^2

and its least-squares form ``0.5 |r|^2`` with ``r = (n - n_hat)_xy / sqrt(P)`` per pixel
(``P`` valid pixel-frames; ``|dn|^2 = 2 (1 - cos)`` and the z part is of fourth order in
the slope) plus ``sqrt(2 w / P) (rho - rho_hat)`` per pixel for the roughness.

Pipeline of :func:`waves`:

1. **Spectral estimate** (:func:`spectral_estimate`): the slope field
   ``s = (-n_x/n_z, -n_y/n_z)`` is resampled onto ground grids (a pyramid of scales, each
   a ``G x G`` square anchored at the nearest sea pixel and spaced by a multiple of its
   footprint; for the orthographic camera the pixel grid itself), Fourier transformed in
   space and projected in time onto the dispersion shell ``omega^2 = g k``:
   ``P(K) = |sum_t e^{-i omega(K) t} K_hat . F_t(K)|^2``. A wave travelling along ``K``
   lights up one bin (the opposite direction stays dark), so local maxima of ``P`` give
   frequencies, directions and -- through the linear solve -- phases.
2. **Linear amplitudes and phases** (:func:`solve_amplitudes`): to first order in the
   steepness the slope field is ``sum_i w_i k_i k_hat_i (a_i sin psi0_i + b_i cos psi0_i)``
   with ``psi0 = omega t - k.X``, linear in ``(a, b) = h (cos phi, sin phi)`` once
   ``(omega, theta)`` are known (DESIGN section 6).
3. **Greedy detection with order selection**: candidates from the spectral estimate of the
   current residual plus a polar grid of waves longer than the largest ground grid are
   scored on a spread subsample of pixel-frames by the energy a single wave removes,
   refined in ``(a, b, omega, theta)`` by a single-wave Levenberg-Marquardt, solved jointly
   for ``(a, b)`` (sidelobes and repeats lose their energy there), added in batches, and
   the whole set is refined by the structured Levenberg-Marquardt below (without the
   roughness term: the observed roughness holds waves the model does not have yet). A
   batch is kept while it lowers the information criterion (``"bic"``:
   ``M ln(RSS/M) + 4 N ln M``; ``"aic"``: ``+ 8 N``; with a known ``noise`` sigma,
   ``RSS / sigma^2 + 4 N ln M``; the RSS is floored at ``M noise_floor^2``, the model's own
   floating-point precision). Optionally the final set is pruned by each wave's Wald
   statistic against the same penalty. The final refinement adds the roughness term with
   the sub-pixel tail of waves outside the set fitted by non-negative least squares.
4. **Refinement** (:func:`refine`): every parameter at once. The default solver
   ``"structured"`` is a Levenberg-Marquardt (Nielsen damping, Marquardt scaling) whose
   normal equations ``J^T J`` are accumulated frame by frame and row block by row block
   from per-wave forward-mode Jacobians (a wave's parameters touch only its own sines,
   so ``J`` is built in ``O(pixels x waves)`` and reduced by one matrix product); trial
   losses go through ``render.geometry``. Any name of :mod:`jaxocean.fit.solvers` is
   also accepted (``"lm"``, ``"gauss_newton"``, ``"dogleg"``, ``"bfgs"``, ``"lbfgsb"``,
   ``"adam"``, ``"scipy"``); they see the same residual but materialise the dense
   Jacobian, which is 20-40x slower at 128^2 x 10 frames x 60 waves.

Parameters inside the solvers are ``(a, b, log omega, theta)`` per wave: no singularity
at ``h = 0`` and ``omega > 0`` by construction.

Wave uncertainty (:class:`WaveFit` ``uncertainty``) is the Gauss-Newton covariance
``sigma^2 (J^T J)^-1`` with ``sigma^2 = RSS / (M - 4N)``, mapped to ``(h, omega, theta,
phi)``: cheap (the solver has ``J^T J``) and meaningful when the residual is noise.

Resolvability (:func:`resolvable`): a wave is individually recoverable when the image
resolves it somewhere (``lambda >= n_max x`` the smallest footprint) and at least
``cycles`` of its wavelengths fit into the part of the sea where it is resolved, measured
along its direction of travel. Longer waves are seen only as a smooth tilt field: the fit
explains them with some long waves, not with the true ones (``experiments/WAVES.md``).
"""

from __future__ import annotations

import functools
import math
import time
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, render, shading
from jaxocean._math import safe_sqrt, sincos, smoothstep
from jaxocean.errors import InvalidValueError, check_values, is_concrete
from jaxocean.surface import normal_from_sums
from jaxocean.waves import GRAVITY, Waves, validate

__all__ = [
    "WaveFit",
    "SpectralEstimate",
    "OrderSelection",
    "WaveMatch",
    "SOLVER_NAMES",
    "NOISE_FACTOR",
    "NORMAL_ERROR_FLOOR",
    "UNIT_NORMAL_TOLERANCE",
    "normal_error_bound",
    "waves",
    "refine",
    "spectral_estimate",
    "spectral_init",
    "solve_amplitudes",
    "loss",
    "predict",
    "resolvable",
    "match",
    "check_inputs",
]

#: solver names accepted by :func:`waves` / :func:`refine`: ours first, then the registry's.
SOLVER_NAMES = ("structured", "lm", "gauss_newton", "dogleg", "bfgs", "lbfgsb", "adam", "scipy")
_CRITERIA = ("bic", "aic", "holdout")
_BUCKETS = (16, 32, 64, 96, 128, 192, 256, 384, 512)
_MIN_NZ = 0.05  # normals flatter than this (|slope| > 20) are treated as invalid
UNIT_NORMAL_TOLERANCE = 1e-2
"""How far from 1 the length of a valid normal may be: float32 and half-float storage
(relative 5e-4) pass; anything else is not a unit normal."""
# plausibility of a fit (see waves(): success): the mean normal angle of a fit that explains
# its data is about sqrt(pi/2) sigma for per-component noise sigma; allowed up to 1.5x that,
# and never below 1 mrad (noise-free fits reach 1e-5 rad; half-float EXR frames ~1e-4)
NOISE_FACTOR = 1.5
NORMAL_ERROR_FLOOR = 1e-3
_CHUNK_FLOATS = 6_000_000  # per-wave Jacobian entries held at once (24 MB in float32)


# =============================================================================== results


class WaveFit(NamedTuple):
    """Result of :func:`waves` / :func:`refine` (arrays only, so ``jax.vmap`` can return it).

    * ``waves``        fitted :class:`~jaxocean.waves.Waves` ``(N,)``, sorted by frequency
      by :func:`waves` (``refine`` keeps the input order).
    * ``uncertainty``  ``Waves`` of 1-sigma standard deviations of (h, omega, theta, phi).
    * ``loss``         the paper's loss (module docstring) at the fit.
    * ``normal_error`` mean angle [rad] between fitted and observed normals.
    * ``roughness_error`` mean absolute roughness difference.
    * ``steps``        solver steps of the final refinement (``waves``: summed over the whole
      pipeline).
    * ``success``      the solver converged to its tolerances with a finite loss (and, when
      :func:`waves` selects the count, the selection stopped by itself: a fit stopped by
      ``max_waves`` is reported failed -- the sea holds more than the cap allows; and
      :func:`waves` leaves a mean normal error within :func:`normal_error_bound` of its
      ``noise``: a converged fit that does not explain the data is reported failed).
    * ``n_waves``      number of fitted waves.
    * ``time_s``       wall time [s] of the eager call (NaN under tracing).
    * ``history``      ``(max_steps + 1,)`` loss after every step, or None.
    """

    waves: Waves
    uncertainty: Waves
    loss: jax.Array
    normal_error: jax.Array
    roughness_error: jax.Array
    steps: jax.Array
    success: jax.Array
    n_waves: jax.Array
    time_s: jax.Array
    history: jax.Array | None = None


class OrderSelection(NamedTuple):
    """The path of the greedy model-order selection: one entry per tried wave count."""

    n_waves: np.ndarray
    criterion: np.ndarray
    rss: np.ndarray
    accepted: np.ndarray


class SpectralEstimate(NamedTuple):
    """Space-time spectral estimate on ``S`` ground grids (``K = 2 G`` FFT bins a side).

    ``power (S, K, K)`` dispersion-shell power, ``kx, ky (S, K, K)`` world wave vectors of
    the bins [rad/m], ``spacing (S,)`` grid spacings [m], ``extent (S,)`` grid sides [m];
    ``peaks``: ``omega, theta, power (S, n_peaks)`` of the strongest local maxima in each
    grid's usable band (power 0 marks an empty slot).
    """

    power: jax.Array
    kx: jax.Array
    ky: jax.Array
    spacing: jax.Array
    extent: jax.Array
    peak_omega: jax.Array
    peak_theta: jax.Array
    peak_power: jax.Array


class WaveMatch(NamedTuple):
    """One-to-one matching of fitted to true waves (:func:`match`).

    ``true_index``/``fit_index`` pair up matched waves; ``abs_error`` is a ``Waves`` of
    absolute errors of the pairs (angles wrapped to [-pi, pi)); ``missed`` lists true waves
    left without a partner within ``tolerance``; ``spurious`` fitted waves likewise.
    """

    true_index: np.ndarray
    fit_index: np.ndarray
    abs_error: Waves
    missed: np.ndarray
    spurious: np.ndarray


# =============================================================================== inputs


def check_inputs(normals, roughness, camera, times):
    """Validate a scene for fitting; returns ``(normals, roughness, times)`` as arrays.

    Structure -> ``ValueError``: camera missing or not a Camera, normals not ``(T, H, W, 3)``
    matching the camera's resolution, roughness not ``(T, H, W)``, times not ``(T,)``, fewer
    than two frames. Values (when concrete) -> :class:`InvalidValueError`: frame times not
    strictly increasing or not finite, no valid sea pixel, normals that are not unit vectors
    (``| |n| - 1 | > UNIT_NORMAL_TOLERANCE`` on a valid sea pixel: an image's RGB values passed
    as normals, say), negative roughness.
    """
    if camera is None:
        raise ValueError("fit.waves needs the camera the geometry was seen with (camera=None given)")
    if not isinstance(camera, cam.Camera):
        raise ValueError(f"camera must be a jaxocean Camera; got {type(camera).__name__}")
    cam.validate_camera(camera)
    normals = jnp.asarray(normals)
    if not jnp.issubdtype(normals.dtype, jnp.floating):
        normals = normals.astype(jnp.result_type(float))
    H, W = camera.resolution
    if normals.ndim != 4 or normals.shape[1:] != (H, W, 3):
        raise ValueError(f"normals must be (T, H, W, 3) with (H, W) = camera.resolution = {(H, W)}; "
                         f"got {normals.shape}")
    T = normals.shape[0]
    if T < 2:
        raise ValueError(f"a wave fit needs a sequence of at least 2 frames (frequency comes from the motion); "
                         f"got {T}")
    times = jnp.asarray(times, normals.dtype)
    if times.shape != (T,):
        raise ValueError(f"times must be (T,) = ({T},), one per frame; got shape {times.shape}")
    if roughness is not None:
        roughness = jnp.asarray(roughness, normals.dtype)
        if roughness.shape != (T, H, W):
            raise ValueError(f"roughness must be (T, H, W) = {(T, H, W)}; got {roughness.shape}")
    if is_concrete(times):
        t = np.asarray(times)
        check_values(np.isfinite(t), "frame times must be finite", t)
        check_values(np.diff(t) > 0, "frame times must be strictly increasing", np.diff(t))
    if is_concrete(normals, camera):
        valid = np.asarray(_weights(normals, camera)) > 0
        if not bool(np.any(valid)):
            raise InvalidValueError("no valid sea pixel: every pixel is sky or has a non-finite/downward normal")
        length = np.linalg.norm(np.asarray(normals, np.float64)[valid], axis=-1)
        off = np.abs(length - 1.0) > UNIT_NORMAL_TOLERANCE
        if off.any():
            raise InvalidValueError(
                f"normals must be unit vectors (| |n| - 1 | <= {UNIT_NORMAL_TOLERANCE:g}); {int(off.sum())} of "
                f"{off.size} sea pixel-frames are not (|n| from {length.min():.4g} to {length.max():.4g}). "
                f"An image is not geometry: pass normals from render.geometry, a geometry network or an EXR "
                f"frame's normal.X/Y/Z channels")
    if roughness is not None and is_concrete(roughness):
        r = np.asarray(roughness)
        finite = np.isfinite(r)
        check_values(~finite | (r >= 0), "roughness must be >= 0", r)
    return normals, roughness, times


def _weights(normals, camera):
    """Per pixel-frame validity ``(T, H, W)`` in {0, 1}: sea, finite, facing up."""
    hit = cam.intersect_sea(camera)
    finite = jnp.all(jnp.isfinite(normals), axis=-1)
    ok = finite & (jnp.where(finite, normals[..., 2], 0.0) > _MIN_NZ)
    return (ok & hit.mask[None]).astype(normals.dtype)


def _clean(normals, roughness, weight):
    """Replace invalid entries by harmless values (they carry zero weight)."""
    up = jnp.zeros(3, normals.dtype).at[2].set(1.0)
    normals = jnp.where(weight[..., None] > 0, normals, up)
    if roughness is None:
        roughness = jnp.full(normals.shape[:-1], shading.MIN_SLOPE_VARIANCE, normals.dtype)
    roughness = jnp.where((weight > 0) & jnp.isfinite(roughness), roughness, 0.0)
    return normals, roughness


def _slopes(normals):
    """Slope field ``(-n_x / n_z, -n_y / n_z)`` ``(..., 2)``; normals must face up (cleaned)."""
    nz = jnp.maximum(normals[..., 2:3], _MIN_NZ)
    return -normals[..., :2] / nz


def _scene(camera):
    """Plane hits ``xy (H, W, 2)``, per-row footprint ``(H,)`` (the centre column, as the
    renderer's rows path uses) and the sea mask."""
    hit = cam.intersect_sea(camera)
    W = camera.resolution[1]
    return hit.xy, hit.footprint[:, W // 2], hit.mask


# =============================================================================== parameters


def _pack(w: Waves):
    """Waves -> parameter vector ``(4N,)`` = (a, b, log omega, theta)."""
    return jnp.concatenate([w.amplitude * jnp.cos(w.phase), w.amplitude * jnp.sin(w.phase), jnp.log(w.omega),
                            w.theta])


def _unpack(y, n):
    return y.reshape(4, n)


def _to_waves(y, n) -> Waves:
    a, b, u, th = _unpack(y, n)
    r2 = a * a + b * b
    ok = r2 > 1e-30
    phase = jnp.where(ok, jnp.arctan2(jnp.where(ok, b, 0.0), jnp.where(ok, a, 1.0)), 0.0)
    phase = jnp.mod(phase, 2 * jnp.pi)
    return Waves(safe_sqrt(r2), jnp.exp(u), _wrap(th), phase)


def _wrap(theta):
    return jnp.mod(theta + jnp.pi, 2 * jnp.pi) - jnp.pi


def _bucket(n: int) -> int:
    for b in _BUCKETS:
        if n <= b:
            return b
    return int(64 * math.ceil(n / 64))


def _pad_waves(w: Waves, n_pad: int):
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


def _plan(n):
    return render.full_plan(n)


def predict(waves_: Waves, camera, times, *, n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX):
    """Normals ``(T, H, W, 3)`` and roughness ``(T, H, W)`` of ``waves_`` at ``times``: the
    fit's forward model (``render.geometry``'s rows path with every wave evaluated)."""
    validate(waves_, max_steepness=None)
    times = jnp.atleast_1d(jnp.asarray(times, waves_.omega.dtype))
    return _predict(waves_, camera, times, n_min, n_max)


@functools.partial(jax.jit, static_argnums=(3, 4))
def _predict(waves_, camera, times, n_min, n_max):
    plan = _plan(waves_.omega.shape[-1])

    def one(t):
        g = render.geometry(waves_, camera, t, plan=plan, n_min=n_min, n_max=n_max)
        return g.normal, g.roughness

    return jax.lax.map(one, times)


def _nxy(sums):
    return normal_from_sums(sums[0], sums[1], sums[2], sums[3], sums[4])[:2]


class _Samples(NamedTuple):
    """Pixel-frames as flat samples ``(M, ...)``: time, rest position, row footprint,
    observed normal x, y (or residual slopes), and the sqrt of the residual weight."""

    t: jax.Array
    xy: jax.Array
    fp: jax.Array
    target: jax.Array
    sw: jax.Array


def _samples(normals_xy, weight, times, camera, scale=1.0) -> _Samples:
    """Every pixel-frame as a sample; ``normals_xy (T, H, W, 2)``."""
    T, H, W = weight.shape
    xy, fp_row, _ = _scene(camera)
    return _Samples(
        t=jnp.broadcast_to(times[:, None, None], (T, H, W)).reshape(-1),
        xy=jnp.broadcast_to(xy[None], (T, H, W, 2)).reshape(-1, 2),
        fp=jnp.broadcast_to(fp_row[None, :, None], (T, H, W)).reshape(-1),
        target=normals_xy.reshape(-1, 2),
        sw=jnp.sqrt(weight * scale).reshape(-1),
    )


def _subsample(s: _Samples, count: int) -> _Samples:
    """A deterministic, evenly spread subset of ``count`` samples (a golden-ratio stride
    through the flattened (T, H, W) order, so no row, column or frame is favoured)."""
    m = s.t.shape[0]
    if count >= m:
        return s
    stride = int(round(m * 0.6180339887498949)) | 1
    while math.gcd(stride, m) != 1:
        stride += 2
    idx = (np.arange(count, dtype=np.int64) * stride) % m
    return jax.tree.map(lambda x: x[idx], s)


def _chunked(s: _Samples, size: int) -> _Samples:
    """Reshape samples into ``(C, size, ...)`` chunks, padding with zero-weight samples."""
    m = s.t.shape[0]
    c = -(-m // size)
    pad = c * size - m

    def rs(x, fill):
        if pad:
            x = jnp.concatenate([x, jnp.full((pad,) + x.shape[1:], fill, x.dtype)])
        return x.reshape((c, size) + x.shape[1:])

    # padding: zero weight, a unit footprint (nothing divides by zero)
    return _Samples(rs(s.t, 0.0), rs(s.xy, 0.0), rs(s.fp, 1.0), rs(s.target, 0.0), rs(s.sw, 0.0))


def _chunk_size(n_pad):
    return int(max(64, min(8192, _CHUNK_FLOATS // (30 * max(n_pad, 1)))))


def _jacobian(P, act, s: _Samples, n_min, n_max):
    """Residual ``r (S*2,)`` and its Jacobian ``J (S*2, 4N)`` for samples ``s`` (hand-written
    chain rule: each wave's parameters touch only its own sine and cosine).

    Model per wave: C = w k (a cos psi0 - b sin psi0), S = w k (a sin psi0 + b cos psi0),
    sums (A_xx, A_xy, A_yy, B_x, B_y) = sum (c^2 C, c s C, s^2 C, c S, s S), normal from the
    sums; ``P = (a, b, log omega, theta) (4, N)``.
    """
    a, b, u, th = P[0], P[1], P[2], P[3]
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
    dpsi_du = om * s.t[:, None] - 2.0 * k * proj
    dpsi_dth = k * (sn * s.xy[:, :1] - c * s.xy[:, 1:])
    dwk_du = k * dw_du + 2.0 * wk
    j_a = e(wk) * (alpha * e(cp) + beta * e(sp))
    j_b = e(wk) * (beta * e(cp) - alpha * e(sp))
    j_u = alpha * e(dwk_du * cn - S * dpsi_du) + beta * e(dwk_du * snn + C * dpsi_du)
    j_t = (beta * e(C) - alpha * e(S)) * e(dpsi_dth) + alpha_t * e(C) + beta_t * e(S)
    J = jnp.stack([j_a, j_b, j_u, j_t], axis=2) * s.sw[:, None, None, None]  # (S, 2, 4, N)
    return r, J.reshape(r.shape[0], -1)


def _gradient(y, active, chunks: _Samples, n_min, n_max):
    """``J^T r`` and ``0.5 |r|^2`` over every sample."""
    n = active.shape[0]
    P = _unpack(y, n)
    act = active.astype(y.dtype)

    def body(carry, ch):
        jtr, half = carry
        r, J = _jacobian(P, act, ch, n_min, n_max)
        return (jtr + J.T @ r, half + 0.5 * jnp.sum(r * r)), None

    zero = (jnp.zeros(4 * n, y.dtype), jnp.zeros((), y.dtype))
    (jtr, half), _ = jax.lax.scan(body, zero, chunks)
    return jtr, half


def _gauss_newton(y, active, chunks: _Samples, n_min, n_max):
    """``J^T J`` over the (sub)sampled chunks."""
    n = active.shape[0]
    P = _unpack(y, n)
    act = active.astype(y.dtype)

    def body(jtj, ch):
        _, J = _jacobian(P, act, ch, n_min, n_max)
        return jtj + J.T @ J, None

    jtj, _ = jax.lax.scan(body, jnp.zeros((4 * n, 4 * n), y.dtype), chunks)
    return jtj


def _roughness_rows(y, active, fp_row, n_min, n_max):
    """Model roughness per image row ``(H,)`` from the fitted waves (no floor)."""
    w = _to_waves(y, active.shape[0])
    w = w._replace(amplitude=w.amplitude * active)
    lam = 2 * jnp.pi * GRAVITY / (w.omega * w.omega)
    rough_w = 1.0 - smoothstep(n_min, n_max, lam / fp_row[:, None])  # (H, N)
    kh2 = (w.amplitude * w.omega * w.omega / GRAVITY) ** 2
    per_wave = kh2 / (1.0 + safe_sqrt(1.0 - kh2))
    return rough_w @ per_wave


class _Rough(NamedTuple):
    """Roughness data per image row: ``target (H,)`` mean observed roughness minus the
    (fixed) tail, ``sw (H,)`` sqrt of the residual weight, ``fp (H,)`` footprints."""

    target: jax.Array
    sw: jax.Array
    fp: jax.Array


def _rough_data(roughness, weight, camera, n_valid, roughness_weight, tail_rows=None) -> _Rough:
    _, fp_row, _ = _scene(camera)
    count = jnp.sum(weight, axis=(0, 2))  # (H,)
    mean = jnp.sum(roughness * weight, axis=(0, 2)) / jnp.maximum(count, 1.0)
    if tail_rows is not None:
        mean = mean - tail_rows
    sw = jnp.sqrt(2.0 * roughness_weight * count / n_valid)
    return _Rough(mean, sw, fp_row)


def _rough_residual(y, active, rough: _Rough, tail_rows, n_min, n_max):
    model = _roughness_rows(y, active, rough.fp, n_min, n_max)
    total = jnp.maximum(model + tail_rows, shading.MIN_SLOPE_VARIANCE) - tail_rows
    return (total - rough.target) * rough.sw


# =============================================================================== losses


def loss(waves_: Waves, normals, roughness, camera, times, *, roughness_weight=1.0,
         n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX):
    """The paper's loss (eq. 5-7) of ``waves_`` against observed geometry: mean ``1 - cos``
    of the normal angle plus ``roughness_weight`` times the mean squared roughness
    difference, over valid sea pixel-frames. Differentiable in the waves and the data."""
    normals, roughness, times = check_inputs(normals, roughness, camera, times)
    validate(waves_, max_steepness=None)
    return _metrics(waves_, normals, roughness, camera, times, roughness_weight, n_min, n_max)[0]


def _metrics(waves_, normals, roughness, camera, times, roughness_weight, n_min, n_max):
    weight = _weights(normals, camera)
    normals, roughness = _clean(normals, roughness, weight)
    n_pred, r_pred = _predict(waves_, camera, times, n_min, n_max)
    n_valid = jnp.maximum(jnp.sum(weight), 1.0)
    cos = jnp.clip(jnp.sum(n_pred * normals, -1), -1.0, 1.0)
    one_minus = jnp.sum((1.0 - cos) * weight) / n_valid
    rough = jnp.sum((r_pred - roughness) ** 2 * weight) / n_valid
    # angle from the cross product's norm: finite gradient at zero error
    cross = jnp.cross(n_pred, normals)
    angle = jnp.arctan2(safe_sqrt(jnp.sum(cross * cross, -1)), cos)
    return (one_minus + roughness_weight * rough, jnp.sum(angle * weight) / n_valid,
            jnp.sum(jnp.abs(r_pred - roughness) * weight) / n_valid)


# =============================================================================== structured LM


class _LMOut(NamedTuple):
    y: jax.Array
    loss: jax.Array
    steps: jax.Array
    success: jax.Array
    jtj: jax.Array
    history: jax.Array


def _ls_loss(y, active, normals, weight, times, camera, rough, tail_rows, scale, n_min, n_max):
    """``0.5 |r|^2`` through ``render.geometry`` (normals) plus the roughness rows."""
    n = active.shape[0]
    w = _to_waves(y, n)
    w = w._replace(amplitude=w.amplitude * active)
    n_pred, _ = _predict(w, camera, times, n_min, n_max)
    d = (n_pred[..., :2] - normals[..., :2])
    half = 0.5 * scale * jnp.sum(d * d * weight[..., None])
    rr = _rough_residual(y, active, rough, tail_rows, n_min, n_max)
    return half + 0.5 * jnp.sum(rr * rr)


def _hessian_samples(n_pad: int, m_total: int) -> int:
    """Samples for ``J^T J``: all of them on small problems, else ~128 per parameter
    (>= 16384); the gradient always uses every sample."""
    return int(min(m_total, max(16384, 32 * 4 * n_pad)))


def _structured_lm(y0, active, normals, weight, times, camera, rough, tail_rows, *, scale, n_min, n_max,
                   max_steps, rtol, atol, hessian_samples, history_len, xtol=1e-7):
    """Levenberg-Marquardt with structured normal equations (see the module docstring).

    The gradient ``J^T r`` is exact (every pixel-frame); ``J^T J`` comes from an evenly
    spread subset of ``hessian_samples`` pixel-frames, rescaled by the weight ratio. The
    accept test uses the exact loss through ``render.geometry``, so an approximate
    ``J^T J`` only slows convergence near the optimum, it does not move it.
    """
    n = active.shape[0]
    samples = _samples(normals[..., :2], weight, times, camera, scale)
    size = _chunk_size(n)
    sub = _subsample(samples, hessian_samples)
    sub_chunks = _chunked(sub, size)
    ratio = jnp.sum(samples.sw ** 2) / jnp.maximum(jnp.sum(sub.sw ** 2), 1e-30)
    act4 = jnp.tile(active, 4)
    dtype = y0.dtype

    def normal_eq(y):
        # the exact gradient of the very loss the accept test uses (reverse mode through
        # render.geometry's rank-N rows path), J^T J from the structured subsample
        jtr = jax.grad(f)(y)
        jtj = _gauss_newton(y, active, sub_chunks, n_min, n_max) * ratio
        _, jr = jax.linearize(lambda yy: _rough_residual(yy, active, rough, tail_rows, n_min, n_max), y)
        Jr = jax.vmap(jr, out_axes=1)(jnp.eye(4 * n, dtype=dtype))  # (H, 4N)
        jtj = jtj + Jr.T @ Jr
        # inactive (padding) parameters: identity rows, zero gradient
        jtj = jnp.where(act4[:, None] & act4[None, :], jtj, jnp.diag(jnp.where(act4, 0.0, 1.0)).astype(dtype))
        jtr = jnp.where(act4, jtr, 0.0)
        return jtj, jtr

    def f(y):
        return _ls_loss(y, active, normals, weight, times, camera, rough, tail_rows, scale, n_min, n_max)

    f0 = f(y0)
    jtj0, jtr0 = normal_eq(y0)
    hist0 = jnp.full((history_len,), f0)
    eps = jnp.finfo(dtype).eps

    class S(NamedTuple):
        y: jax.Array
        f: jax.Array
        jtj: jax.Array
        jtr: jax.Array
        lam: jax.Array
        nu: jax.Array
        k: jax.Array
        done: jax.Array
        conv: jax.Array
        hist: jax.Array

    def cond(s):
        return (~s.done) & (s.k < max_steps)

    def body(s):
        d = jnp.diag(s.jtj)
        dmax = jnp.max(d)
        dsc = jnp.maximum(d, 1e-9 * dmax + 1e-30)
        A = s.jtj + s.lam * jnp.diag(dsc)
        step = -jnp.linalg.solve(A, s.jtr)
        ok_step = jnp.all(jnp.isfinite(step))
        step = jnp.where(ok_step, step, 0.0)
        y_try = s.y + step
        f_try = f(y_try)
        pred = -(step @ s.jtr) - 0.5 * step @ (s.jtj @ step)
        actual = s.f - f_try
        rho = actual / jnp.where(pred > 0, pred, 1.0)
        accept = ok_step & jnp.isfinite(f_try) & (actual > 0) & (pred > 0) & (rho > 1e-4)

        def on_accept(_):
            jtj, jtr = normal_eq(y_try)
            lam = s.lam * jnp.maximum(1.0 / 3.0, 1.0 - (2.0 * rho - 1.0) ** 3)
            return y_try, f_try, jtj, jtr, lam, jnp.asarray(2.0, dtype)

        def on_reject(_):
            return s.y, s.f, s.jtj, s.jtr, s.lam * s.nu, s.nu * 2.0

        y, fv, jtj, jtr, lam, nu = jax.lax.cond(accept, on_accept, on_reject, None)
        # convergence: a small relative decrease on an accepted step, a negligible step,
        # a loss at the absolute floor, or damping so large that no step can help
        rel = jnp.abs(actual) <= rtol * jnp.maximum(s.f, eps)
        small = jnp.max(jnp.abs(step) / (jnp.abs(s.y) + 1.0)) < xtol
        floor = fv <= atol
        stalled = lam > 1e12
        conv = (accept & rel) | small | floor | stalled
        hist = jnp.where(jnp.arange(history_len) > s.k, fv, s.hist)
        return S(y, fv, jtj, jtr, lam, nu, s.k + 1, conv | ~jnp.isfinite(fv), conv & jnp.isfinite(fv), hist)

    s0 = S(y0, f0, jtj0, jtr0, jnp.asarray(1e-3, dtype), jnp.asarray(2.0, dtype), jnp.asarray(0, jnp.int32),
           f0 <= atol, f0 <= atol, hist0)
    s = jax.lax.while_loop(cond, body, s0)
    success = s.conv & jnp.isfinite(s.f) & jnp.all(jnp.isfinite(s.y))
    return _LMOut(s.y, s.f, s.k, success, s.jtj, s.hist)


def _refine_kernel(y0, active, normals, roughness, times, camera, tail_rows, rtol, atol, *, n_min, n_max,
                   max_steps, roughness_weight, hessian_samples=None, history=False):
    if hessian_samples is None:
        hessian_samples = _hessian_samples(active.shape[0], int(np.prod(normals.shape[:3])))
    # max_steps is traced (one compilation serves every step budget); the history's length
    # is static and only as long as asked for
    return _refine_jit(y0, active, normals, roughness, times, camera, tail_rows, rtol, atol,
                       jnp.asarray(max_steps, jnp.int32), n_min=n_min, n_max=n_max,
                       roughness_weight=roughness_weight, hessian_samples=int(hessian_samples),
                       history_len=int(max_steps) + 1 if history else 1)


@functools.partial(jax.jit, static_argnames=("n_min", "n_max", "roughness_weight", "hessian_samples", "history_len"))
def _refine_jit(y0, active, normals, roughness, times, camera, tail_rows, rtol, atol, max_steps, *, n_min, n_max,
                roughness_weight, hessian_samples, history_len):
    weight = _weights(normals, camera)
    normals, roughness = _clean(normals, roughness, weight)
    n_valid = jnp.maximum(jnp.sum(weight), 1.0)
    scale = 1.0 / n_valid
    rough = _rough_data(roughness, weight, camera, n_valid, roughness_weight, tail_rows)
    out = _structured_lm(y0, active, normals, weight, times, camera, rough, tail_rows, scale=scale, n_min=n_min,
                         n_max=n_max, max_steps=max_steps, rtol=rtol, atol=atol, hessian_samples=hessian_samples,
                         history_len=history_len)
    return out, n_valid


# =============================================================================== generic (registry) path


def _registry_refine(y0, active, normals, roughness, times, camera, tail_rows, *, solver, n_min, n_max,
                     max_steps, rtol, atol, roughness_weight, history, options):
    from jaxocean.fit import solvers

    weight = _weights(normals, camera)
    normals, roughness = _clean(normals, roughness, weight)
    n_valid = jnp.maximum(jnp.sum(weight), 1.0)
    scale = 1.0 / n_valid
    rough = _rough_data(roughness, weight, camera, n_valid, roughness_weight, tail_rows)
    n = active.shape[0]
    sw = jnp.sqrt(weight * scale)[..., None]

    def residual(y, args):
        w = _to_waves(y, n)
        w = w._replace(amplitude=w.amplitude * active)
        n_pred, _ = _predict(w, camera, times, n_min, n_max)
        r_n = ((n_pred[..., :2] - normals[..., :2]) * sw).ravel()
        return jnp.concatenate([r_n, _rough_residual(y, active, rough, tail_rows, n_min, n_max)])

    out = solvers.solve(solver, residual, y0, None, max_steps=max_steps, rtol=rtol, atol=atol, history=history,
                        options=options)
    return out, n_valid, residual


# =============================================================================== uncertainty


def _uncertainty(y, jtj, active, half_rss, n_obs):
    """1-sigma of (h, omega, theta, phi) from the Gauss-Newton covariance.

    The variance of each derived quantity ``q(y)`` is the quadratic form ``g^T C g`` with
    ``g = dq/dy`` and ``C = sigma^2 (J^T J)^-1``, evaluated through the eigenvectors of the
    Jacobi-scaled ``J^T J`` as ``sigma^2 sum_k (g . v_k)^2 / lambda_k``: a sum of
    non-negative terms. (The diagonal of an explicit float32 inverse gave negative amplitude
    variances -- reported as a standard deviation of 0 -- for 13 of the 60 waves at the
    truth of a Table 2 scene, among them the worst-determined long waves: its Jacobi-scaled
    ``J^T J`` has a condition number near 1/eps.) Eigenvalues below ``eps x`` the largest
    are raised to it, so directions the data do not determine get a large, finite variance;
    standard deviations are not floored (noise-free fits have 1e-10 m).
    """
    n = active.shape[0]
    dof = jnp.maximum(n_obs - 4.0 * jnp.sum(active), 1.0)
    # half_rss is 0.5 |r|^2 of residuals scaled by 1/sqrt(P); sigma^2 in those units
    sigma2 = 2.0 * half_rss / dof
    d = jnp.sqrt(jnp.maximum(jnp.diag(jtj), 1e-30))
    lam, vec = jnp.linalg.eigh(jtj / d[:, None] / d[None, :])
    lam = jnp.maximum(lam, jnp.finfo(jtj.dtype).eps * jnp.max(lam))
    # eigenvector rows by parameter block (a, b, log omega, theta) in unscaled coordinates:
    # (4, N, 4N), so that a quantity of wave i projects onto the eigenvectors through its own
    # parameters only
    rows = (vec / d[:, None]).reshape(4, n, 4 * n)
    a, b, u, _ = _unpack(y, n)
    h2 = jnp.maximum(a * a + b * b, 1e-30)
    h = jnp.sqrt(h2)

    def std(*grad):
        # grad: ((block, d quantity / d parameter (N,)), ...) of each wave's quantity
        proj = sum(g[:, None] * rows[k] for k, g in grad)  # (N, 4N)
        return safe_sqrt(sigma2 * jnp.sum(proj * proj / lam, axis=-1), floor=0.0)

    stds = (std((0, a / h), (1, b / h)), std((2, jnp.exp(u))), std((3, jnp.ones_like(a))),
            std((0, -b / h2), (1, a / h2)))
    return Waves(*[jnp.where(active, s, 0.0) for s in stds])


# =============================================================================== refine (public)


def refine(normals, roughness, camera, times, init: Waves, *, solver: str = "structured", max_steps: int = 50,
           rtol=1e-6, atol=0.0, roughness_weight: float = 1.0, n_min=hierarchy.DEFAULT_N_MIN,
           n_max=hierarchy.DEFAULT_N_MAX, history: bool = False, options=None, tail_rows=None,
           throw: bool = False) -> WaveFit:
    """Refine ``init`` waves (fixed count) against observed geometry; returns a :class:`WaveFit`.

    Pure and traceable for every solver but ``"scipy"``: ``jax.vmap`` over scenes (batched
    normals, roughness, cameras, times and init waves) works and returns arrays. Gradients
    of the result with respect to the data flow through the registry solvers' implicit
    adjoints; the ``"structured"`` solver's loop is not reverse-differentiable (use
    ``"lm"`` for gradients through a fit). ``tail_rows (H,)``: a fixed roughness offset per
    row for waves outside the fitted set; without it the roughness term assumes that
    ``init`` holds every wave (pass ``roughness_weight=0`` otherwise). ``throw``: raise
    :class:`jaxocean.fit.solvers.FitError` (eagerly) when the solver did not converge.
    """
    t0 = time.perf_counter()
    normals, roughness, times = check_inputs(normals, roughness, camera, times)
    validate(init, max_steepness=None)
    if init.omega.ndim != 1:
        raise ValueError(f"init must have leaves (N,); got {init.omega.shape} (vmap batches of scenes)")
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVER_NAMES}")
    if throw and not is_concrete(normals, init, roughness, times, camera):
        raise ValueError("fit.refine under jit/vmap cannot raise on failure: pass throw=False and read .success")
    dtype = normals.dtype
    init = Waves(*[jnp.asarray(x, dtype) for x in init])
    H = camera.resolution[0]
    tail_rows = jnp.zeros(H, dtype) if tail_rows is None else jnp.asarray(tail_rows, dtype)
    n = init.omega.shape[0]
    if roughness is None:
        roughness_weight = 0.0
    if solver == "structured":
        # pad to a bucket size so that nearby wave counts share one compilation -- traced or
        # not (the count is a shape), so a jitted call computes what the eager one does
        n_pad = _bucket(n)
        padded, active = _pad_waves(init, n_pad)
        out, n_valid = _refine_kernel(_pack(padded), active, normals, roughness, times, camera, tail_rows,
                                      jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), n_min=n_min, n_max=n_max,
                                      max_steps=max_steps, roughness_weight=float(roughness_weight), history=history)
        y, steps, success, jtj, hist = out.y, out.steps, out.success, out.jtj, out.history
        half = out.loss
        res = _result(y, active, jtj, half, n_valid, normals, roughness, camera, times, steps, success,
                      hist if history else None, roughness_weight, n_min, n_max, t0)
        if n_pad != n:
            cut = lambda w: Waves(*[x[:n] for x in w])  # noqa: E731
            res = res._replace(waves=cut(res.waves), uncertainty=cut(res.uncertainty), n_waves=jnp.asarray(n))
        return _maybe_throw(res, throw, max_steps)
    else:
        y0 = _pack(init)
        active = jnp.ones(n, bool)
        out, n_valid, residual = _registry_refine(y0, active, normals, roughness, times, camera, tail_rows,
                                                  solver=solver, n_min=n_min, n_max=n_max, max_steps=max_steps,
                                                  rtol=rtol, atol=atol, roughness_weight=roughness_weight,
                                                  history=history, options=options)
        y, steps, success, hist, half = out.params, out.steps, out.success, out.history, out.loss
        jtj = _dense_jtj(residual, y)
    res = _result(y, active, jtj, half, n_valid, normals, roughness, camera, times, steps, success,
                  hist if history else None, roughness_weight, n_min, n_max, t0)
    return _maybe_throw(res, throw, max_steps)


def normal_error_bound(noise=None) -> float:
    """Largest mean normal angle [rad] a successful :func:`waves` fit may leave:
    ``max(NOISE_FACTOR sqrt(pi/2) noise, NORMAL_ERROR_FLOOR)`` (sqrt(pi/2) sigma is the mean
    angle of per-component Gaussian noise sigma on near-vertical normals). Without
    ``noise`` the data are taken to be noise-free up to storage precision: noisy geometry
    (network predictions, real images) needs ``noise=`` or it is reported failed."""
    sigma = 0.0 if noise is None else float(noise)
    return max(NOISE_FACTOR * math.sqrt(math.pi / 2) * sigma, NORMAL_ERROR_FLOOR)


def _maybe_throw(res: WaveFit, throw: bool, max_steps, capped: bool = False, unexplained_bound=None):
    if throw and is_concrete(res.success) and not bool(res.success):
        from jaxocean.fit.solvers import FitError

        if unexplained_bound is not None and not capped:
            raise FitError(f"wave fit leaves a mean normal error of {float(res.normal_error):.3e} rad, above "
                           f"{unexplained_bound:.1e} rad for its noise: the {int(res.n_waves)} waves do not explain "
                           "the data (waves near the Nyquist limit? noisy geometry without noise=?); the result "
                           "is attached as .result", res)
        if capped:
            raise FitError(f"wave fit stopped at max_waves={int(res.n_waves)} while the criterion still accepted "
                           f"waves (normal error {float(res.normal_error):.3e} rad): raise max_waves; the result "
                           "is attached as .result", res)
        raise FitError(f"wave fit did not converge within {max_steps} steps (loss {float(res.loss):.3e}, "
                       f"{int(res.n_waves)} waves); the result is attached as .result", res)
    return res


def _dense_jtj(residual, y):
    # the solvers' blocked forward-mode Jacobian: jax.jacfwd's single vmap of 4N JVPs hits
    # the XLA:CPU float32 miscompile described in jaxocean.fit.solvers
    from jaxocean.fit.solvers import _value_and_jacfwd

    _, J = _value_and_jacfwd(residual, y, None)
    return J.T @ J


def _result(y, active, jtj, half, n_valid, normals, roughness, camera, times, steps, success, hist,
            roughness_weight, n_min, n_max, t0):
    n = active.shape[0]
    w = _to_waves(y, n)
    unc = _uncertainty(y, jtj, active, half, 2.0 * n_valid)
    lval, nerr, rerr = _metrics(w, normals, roughness, camera, times, roughness_weight, n_min, n_max)
    elapsed = time.perf_counter() - t0 if is_concrete(y) else float("nan")
    return WaveFit(waves=w, uncertainty=unc, loss=lval, normal_error=nerr, roughness_error=rerr,
                   steps=jnp.asarray(steps, jnp.int32), success=jnp.asarray(success), n_waves=jnp.asarray(n),
                   time_s=jnp.asarray(elapsed, y.dtype), history=hist)


# =============================================================================== linear amplitudes


def solve_amplitudes(normals, camera, times, omega, theta, *, n_min=hierarchy.DEFAULT_N_MIN,
                     n_max=hierarchy.DEFAULT_N_MAX, ridge=1e-6) -> Waves:
    """Amplitudes and phases of waves of known ``omega, theta (N,)`` by one linear solve.

    To first order in the steepness the slope field is linear in ``(a_i, b_i) = h_i (cos
    phi_i, sin phi_i)`` (module docstring, step 2); the ``2N`` unknowns are solved jointly by
    least squares over every valid pixel-frame (normal equations, relative ``ridge``).
    """
    normals, _, times = check_inputs(normals, None, camera, times)
    dtype = normals.dtype
    omega = jnp.atleast_1d(jnp.asarray(omega, dtype))
    theta = jnp.atleast_1d(jnp.asarray(theta, dtype))
    if omega.shape != theta.shape or omega.ndim != 1:
        raise ValueError(f"omega and theta must be (N,) of one shape; got {omega.shape}, {theta.shape}")
    check_values(omega > 0, "omega must be > 0 rad/s", omega)
    a, b = _solve_ab(normals, camera, times, omega, theta, n_min, n_max, ridge)
    return Waves(safe_sqrt(a * a + b * b), omega, _wrap(theta), jnp.mod(jnp.arctan2(b, a), 2 * jnp.pi))


@functools.partial(jax.jit, static_argnums=(5, 6))
def _solve_ab(normals, camera, times, omega, theta, n_min, n_max, ridge):
    weight = _weights(normals, camera)
    normals, _ = _clean(normals, None, weight)
    s = _slopes(normals)
    xy, fp_row, _ = _scene(camera)
    n = omega.shape[0]
    k = omega * omega / GRAVITY
    khat = jnp.stack([jnp.cos(theta), jnp.sin(theta)], -1)  # (N, 2)
    amp = smoothstep(n_min, n_max, (2 * jnp.pi / k)[None, :] / fp_row[:, None]) * k  # (H, N)

    def frame(carry, inp):
        gram, rhs = carry
        t, st, wt = inp
        psi0 = omega * t - jnp.einsum("hwd,nd->hwn", xy, k[:, None] * khat)  # (H, W, N)
        sn, cs = sincos(psi0)
        sn, cs = sn * amp[:, None, :], cs * amp[:, None, :]
        # design (H, W, 2 comps, 2N): column i -> k_hat_i * amp * sin, column N+i -> * cos
        U = jnp.concatenate([sn[..., None, :] * khat.T[None, None], cs[..., None, :] * khat.T[None, None]], -1)
        U = U * jnp.sqrt(wt)[..., None, None]
        U = U.reshape(-1, 2 * n)
        r = (st * jnp.sqrt(wt)[..., None]).reshape(-1)
        return (gram + U.T @ U, rhs + U.T @ r), None

    zero = (jnp.zeros((2 * n, 2 * n), normals.dtype), jnp.zeros(2 * n, normals.dtype))
    (gram, rhs), _ = jax.lax.scan(frame, zero, (times, s, weight))
    d = jnp.diag(gram)
    gram = gram + ridge * jnp.diag(jnp.maximum(d, 1e-30)) + 1e-30 * jnp.eye(2 * n, dtype=gram.dtype)
    x = jnp.linalg.solve(gram, rhs)
    return x[:n], x[n:]


# =============================================================================== spectral estimate


def _hann(n, dtype):
    i = jnp.arange(n, dtype=dtype)
    return 0.5 - 0.5 * jnp.cos(2 * jnp.pi * (i + 0.5) / n)


def _grid_frames(camera, scales, grid):
    """Anchors ``(S, 2)``, unit axes ``e_u, e_v (2,)``, spacings ``(S,)`` and a flag ``(S,)``
    telling whether a grid sits where the pixels are finer than it (then the slopes are
    box-filtered before sampling, against aliasing).

    Perspective: grid ``s`` is spaced ``0.75 f_s`` with ``f_s = 2^s`` x the nearest sea
    footprint and starts at the nearest image row whose footprint reaches ``f_s``, looking
    along the camera's yaw: a pyramid that walks from the near field to the far field, so
    that long waves are seen over many wavelengths. Orthographic: one grid over the image.
    """
    H, W = camera.resolution
    dtype = jnp.result_type(camera.height, float)
    yaw = jnp.asarray(camera.yaw, dtype)
    e_u = jnp.stack([jnp.cos(yaw), jnp.sin(yaw)])
    e_v = jnp.stack([jnp.sin(yaw), -jnp.cos(yaw)])
    levels = 2.0 ** jnp.arange(scales, dtype=dtype)
    if camera.projection == "orthographic":
        cell = jnp.asarray(camera.ortho_width, dtype) / W
        d0 = cell * max(1.0, min(H, W) / grid)
        centre = jnp.stack([jnp.asarray(camera.x, dtype), jnp.asarray(camera.y, dtype)])
        spacing = d0 * levels
        anchors = centre[None] - 0.5 * grid * spacing[:, None] * e_u[None]
        return anchors, e_u, e_v, spacing, levels > 1
    hit = cam.intersect_sea(camera)
    row_sea = jnp.any(hit.mask, axis=1)
    fp_row = jnp.where(row_sea, hit.footprint[:, W // 2], 0.0)
    near = H - 1 - jnp.argmax(row_sea[::-1])
    f0 = hit.footprint[near, W // 2]
    target = f0 * levels  # (S,)
    rows = jnp.arange(H)
    reach = row_sea[None, :] & (fp_row[None, :] >= target[:, None] * 0.999)  # (S, H)
    # the nearest (largest index) row that reaches the target footprint, else the near row
    row = jnp.where(jnp.any(reach, axis=1), jnp.max(jnp.where(reach, rows[None, :], -1), axis=1), near)
    fallback = ~jnp.any(reach, axis=1) & (levels > 1)
    anchors = hit.xy[row, W // 2]
    spacing = 0.75 * target
    return anchors, e_u, e_v, spacing, fallback


def _box(img, size):
    if size == 1:
        return img
    window = (size, size) + (1,) * (img.ndim - 2)
    return jax.lax.reduce_window(img, 0.0, jax.lax.add, window, (1,) * img.ndim, "SAME") / float(size * size)


def _resample(slopes, weight, camera, anchor, e_u, e_v, d, level, use_box, grid):
    """Slopes ``(T, G, G, 2)`` and validity ``(T, G, G)`` on one ground grid. Where
    ``use_box``, the image is first box-filtered over ``2^level`` pixels (against aliasing of
    a coarse grid in the near field)."""
    dtype = slopes.dtype
    size = 2 ** level
    T = weight.shape[0]
    sw = jnp.moveaxis(slopes * weight[..., None], 0, -1)  # (H, W, 2, T)
    sw = sw.reshape(sw.shape[0], sw.shape[1], -1)  # (H, W, 2T)
    wt = jnp.moveaxis(weight, 0, -1)  # (H, W, T)
    if size > 1:
        sw = jnp.where(use_box, _box(sw, size), sw)
        wt = jnp.where(use_box, _box(wt, size), wt)
    iu = (jnp.arange(grid, dtype=dtype) + 0.5)
    iv = (jnp.arange(grid, dtype=dtype) - grid / 2 + 0.5)
    X = anchor + d * (iu[:, None, None] * e_u + iv[None, :, None] * e_v)  # (G, G, 2)
    P3 = jnp.concatenate([X, jnp.zeros_like(X[..., :1])], -1)
    ij = cam.project(camera, P3)  # (G, G, 2)
    coords = [ij[..., 0], ij[..., 1]]

    def sample(img2d):
        return jax.scipy.ndimage.map_coordinates(img2d, coords, order=1, mode="constant", cval=0.0)

    s_g = jax.vmap(sample, in_axes=-1, out_axes=-1)(sw).reshape(grid, grid, 2, T)
    w_g = jax.vmap(sample, in_axes=-1, out_axes=-1)(wt)  # (G, G, T)
    valid = w_g > 0.999
    s_g = jnp.where(valid[:, :, None, :], s_g / jnp.where(valid, w_g, 1.0)[:, :, None, :], 0.0)
    return jnp.moveaxis(s_g, -1, 0), jnp.moveaxis(valid.astype(dtype), -1, 0), X


def _power_one_scale(slopes, weight, times, camera, anchor, e_u, e_v, d, level, use_box, grid):
    s_g, v_g, X = _resample(slopes, weight, camera, anchor, e_u, e_v, d, level, use_box, grid)
    dtype = slopes.dtype
    win = _hann(grid, dtype)
    wmap = win[:, None] * win[None, :] * jnp.min(v_g, axis=0)  # (G, G): the same support in every frame
    f = s_g * wmap[None, :, :, None]
    mean = jnp.sum(f, axis=(1, 2), keepdims=True) / jnp.maximum(jnp.sum(wmap), 1e-30)
    f = f - mean * wmap[None, :, :, None]  # remove the mean tilt inside the window
    K = 2 * grid
    F = jnp.fft.ifft2(f, s=(K, K), axes=(1, 2)) * (K * K)  # (T, K, K, 2): sum f e^{+i kappa . x}
    m = jnp.fft.fftfreq(K, 1.0 / K).astype(dtype)
    kap = 2 * jnp.pi * m / (K * d)
    ku, kv = kap[:, None], kap[None, :]
    kx = ku * e_u[0] + kv * e_v[0]
    ky = ku * e_u[1] + kv * e_v[1]
    kk = jnp.sqrt(kx * kx + ky * ky)
    kk_safe = jnp.where(kk > 0, kk, 1.0)
    om = jnp.sqrt(GRAVITY * kk)
    proj = F[..., 0] * (kx / kk_safe) + F[..., 1] * (ky / kk_safe)  # (T, K, K)
    t = times - times[0]
    phase = jnp.exp(-1j * om[None] * t[:, None, None])
    C = jnp.sum(phase * proj, axis=0)
    power = jnp.where(kk > 0, jnp.abs(C) ** 2, 0.0) / jnp.maximum(jnp.sum(wmap ** 2), 1e-30)
    return power.astype(dtype), kx, ky, kk, jnp.sum(wmap > 0)


def _peaks(power, kk, k_lo, k_hi, n_peaks):
    nb = [jnp.roll(jnp.roll(power, di, 0), dj, 1) for di in (-1, 0, 1) for dj in (-1, 0, 1) if (di, dj) != (0, 0)]
    is_max = jnp.all(jnp.stack([power > q for q in nb]), axis=0)
    ok = is_max & (kk >= k_lo) & (kk <= k_hi)
    val = jnp.where(ok, power, 0.0).ravel()
    top, idx = jax.lax.top_k(val, n_peaks)
    return top, idx


@functools.partial(jax.jit, static_argnames=("scales", "grid", "n_peaks"))
def _spectral(slopes, weight, times, camera, *, scales, grid, n_peaks):
    anchors, e_u, e_v, spacing, fallback = _grid_frames(camera, scales, grid)
    out = []
    for g in range(scales):
        d = spacing[g]
        power, kx, ky, kk, support = _power_one_scale(slopes, weight, times, camera, anchors[g], e_u, e_v, d, g,
                                                      fallback[g], grid)
        k_lo = 1.5 * 2 * jnp.pi / (grid * d)
        k_hi = 0.9 * jnp.pi / d
        # a grid with (almost) no valid point has no peaks
        power = jnp.where(support >= grid * grid // 8, power, 0.0)
        top, idx = _peaks(power, kk, k_lo, k_hi, n_peaks)
        kxp, kyp = kx.ravel()[idx], ky.ravel()[idx]
        kp = jnp.sqrt(kxp * kxp + kyp * kyp)
        om = jnp.sqrt(GRAVITY * jnp.maximum(kp, 1e-12))
        out.append((power, kx, ky, om, jnp.arctan2(kyp, kxp), top))
    stack = [jnp.stack([o[i] for o in out]) for i in range(6)]
    return SpectralEstimate(power=stack[0], kx=stack[1], ky=stack[2], spacing=spacing, extent=spacing * grid,
                            peak_omega=stack[3], peak_theta=stack[4], peak_power=stack[5])


def spectral_estimate(normals, camera, times, *, scales: int | None = None, grid: int = 64,
                      n_peaks: int = 32) -> SpectralEstimate:
    """Space-time spectral estimate of an observed sequence (module docstring, step 1).

    ``scales`` ground grids of ``grid x grid`` points (default: 1 for the orthographic
    camera, 4 for a perspective one; see ``_grid_frames``: grid ``s`` is spaced 0.75 x
    2^s x the nearest footprint and starts where the image's footprint reaches that
    scale). Traceable (static ``scales``, ``grid``, ``n_peaks``).
    """
    normals, _, times = check_inputs(normals, None, camera, times)
    if scales is None:
        scales = 1 if camera.projection == "orthographic" else 4
    return _spectral_from_normals(normals, times, camera, scales, grid, n_peaks)


@functools.partial(jax.jit, static_argnums=(3, 4, 5))
def _spectral_from_normals(normals, times, camera, scales, grid, n_peaks):
    weight = _weights(normals, camera)
    normals, _ = _clean(normals, None, weight)
    return _spectral(_slopes(normals), weight, times, camera, scales=scales, grid=grid, n_peaks=n_peaks)


def spectral_init(normals, camera, times, n_waves: int, *, scales: int | None = None, grid: int = 64,
                  n_min=hierarchy.DEFAULT_N_MIN, n_max=hierarchy.DEFAULT_N_MAX) -> Waves:
    """The ``n_waves`` strongest spectral peaks (all scales pooled, duplicates within the
    finest resolution dropped), with amplitudes and phases from :func:`solve_amplitudes`.

    One shot and traceable: no greedy subtraction (use :func:`waves` for that).
    """
    normals, _, times = check_inputs(normals, None, camera, times)
    if scales is None:
        scales = 1 if camera.projection == "orthographic" else 4
    est = _spectral_from_normals(normals, times, camera, scales, grid, max(n_waves, 8))
    om, th = _pool_peaks(est, n_waves)
    a, b = _solve_ab(normals, camera, times, om, th, n_min, n_max, 1e-6)
    return Waves(safe_sqrt(a * a + b * b), om, _wrap(th), jnp.mod(jnp.arctan2(b, a), 2 * jnp.pi))


def _pool_peaks(est: SpectralEstimate, n):
    """Top ``n`` peaks over all scales, suppressing repeats of one wave vector."""
    om = est.peak_omega.ravel()
    th = est.peak_theta.ravel()
    pw = est.peak_power.ravel()
    # normalise each scale's power by its maximum so that coarse grids compete fairly
    k = om * om / GRAVITY
    kx, ky = k * jnp.cos(th), k * jnp.sin(th)
    res = jnp.repeat(2 * jnp.pi / est.extent, est.peak_power.shape[1])
    order = jnp.argsort(-pw)
    keep = jnp.zeros(pw.shape, bool)

    def body(i, keep):
        j = order[i]
        d = jnp.sqrt((kx - kx[j]) ** 2 + (ky - ky[j]) ** 2)
        dup = jnp.any(keep & (d < jnp.maximum(res, res[j])))
        return keep.at[j].set((pw[j] > 0) & ~dup)

    keep = jax.lax.fori_loop(0, pw.shape[0], body, keep)
    score = jnp.where(keep, pw, -1.0)
    _, idx = jax.lax.top_k(score, n)
    return om[idx], th[idx]


# =============================================================================== candidate scoring


def _single_wave_stats(om, th, s: _Samples, n_min, n_max):
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
def _score(omega, theta, s: _Samples, n_min, n_max):
    """Energy each single candidate wave removes from the residual slopes, and its (a, b)."""

    def one(x):
        return _energy_ab(_single_wave_stats(x[0], x[1], s, n_min, n_max))

    return jax.lax.map(one, (omega, theta), batch_size=32)


def _single_wave_jac(p, s: _Samples, n_min, n_max):
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
def _refine_candidates(omega, theta, s: _Samples, n_min, n_max, iters):
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
        return jnp.exp(p[2]), _wrap(p[3]), e, a, b

    return jax.vmap(one)(omega, theta)


@functools.partial(jax.jit, static_argnums=(4, 5))
def _joint_ab(omega, theta, valid, s: _Samples, n_min, n_max):
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


@functools.partial(jax.jit, static_argnums=(4, 5))
def _residual_slopes(waves_, normals, camera, times, n_min, n_max):
    weight = _weights(normals, camera)
    normals, _ = _clean(normals, None, weight)
    pred, _ = _predict(waves_, camera, times, n_min, n_max)
    return _slopes(normals) - _slopes(pred), weight


def _long_wave_grid(omega_lo, omega_hi, n_omega, n_theta, dtype):
    om = np.geomspace(omega_lo, omega_hi, n_omega)
    th = np.linspace(-np.pi, np.pi, n_theta, endpoint=False)
    O, Th = np.meshgrid(om, th, indexing="ij")
    return jnp.asarray(O.ravel(), dtype), jnp.asarray(Th.ravel(), dtype)


def _pad_to(x, n, fill):
    x = np.asarray(x)
    if x.shape[0] >= n:
        return x[:n]
    return np.concatenate([x, np.full(n - x.shape[0], fill, x.dtype)])


# =============================================================================== greedy fit


def _criterion_value(kind, rss, m, n, noise, floor2):
    """``rss``: residual sum of squares of the normal components; ``m`` their number."""
    rss = max(float(rss), m * floor2, 1e-300)
    if noise is not None:
        pen = 4 * n * math.log(m) if kind != "aic" else 8 * n
        return rss / float(noise) ** 2 + pen
    if kind == "aic":
        return m * math.log(rss / m) + 8 * n
    return m * math.log(rss / m) + 4 * n * math.log(m)


def _kvec(om, th):
    k = np.asarray(om, np.float64) ** 2 / GRAVITY
    return np.stack([k * np.cos(th), k * np.sin(th)], -1)


def waves(normals, roughness, camera, times, *, n_waves: int | None = None, init: Waves | None = None,
          solver: str = "structured", max_waves: int = 96, criterion: str = "bic", noise=None,
          noise_floor=None, batch: int = 12, inner_steps: int = 8, max_steps: int = 100, rtol=1e-6, atol=0.0,
          roughness_weight: float = 1.0, omega_min: float = 0.3, scales: int | None = None, grid: int = 64,
          score_samples: int = 32768, prune: bool = False, n_min=hierarchy.DEFAULT_N_MIN,
          n_max=hierarchy.DEFAULT_N_MAX,
          throw: bool = False, history: bool = False, return_selection: bool = False, verbose: bool = False):
    """Recover the component waves behind a sequence of geometry (module docstring).

    * ``n_waves``: fit exactly this many waves (no order selection); ``None`` selects the
      count by ``criterion`` (``"bic"``, ``"aic"`` or ``"holdout"``: the last frame is held
      out and a batch is kept while it lowers the held-out normal error), up to
      ``max_waves``. ``noise``: known noise sigma of the normal components (used instead of
      the residual estimate). ``noise_floor``: the smallest residual sigma the criterion
      believes in (default ``200 eps`` of the dtype: 1.2e-5 in float32, the precision of
      a phase ``k . X`` of a few thousand radians), so that noise-free data stop adding waves
      once the model is explained to its floating-point precision.
    * ``init``: starting waves; then no spectral initialisation, and waves are added only
      if ``n_waves`` asks for more.
    * ``prune``: after the greedy stage, drop waves whose Wald statistic is below the
      criterion's penalty, refit, and keep the smaller model only if the criterion improves
      (off by default: with correlated long waves a refit can land in a worse optimum).
    * ``solver``: ``"structured"`` (default) or a registry name (module docstring).
    * ``throw``: raise :class:`jaxocean.fit.solvers.FitError` (carrying the result) when the
      final refinement did not converge; otherwise read ``success``.

    Eager only (data-dependent wave counts); returns a :class:`WaveFit` with waves sorted by
    frequency, or ``(WaveFit, OrderSelection)`` with ``return_selection=True``. For a fixed
    count under ``jit``/``vmap`` use :func:`spectral_init` then :func:`refine`.
    """
    t0 = time.perf_counter()
    normals, roughness, times = check_inputs(normals, roughness, camera, times)
    if not is_concrete(normals, camera, times):
        raise ValueError("fit.waves selects the number of waves eagerly; under jit/vmap use "
                         "fit.spectral_init + fit.refine with a fixed count")
    if solver not in SOLVER_NAMES:
        raise ValueError(f"unknown solver {solver!r}; expected one of {SOLVER_NAMES}")
    if criterion not in _CRITERIA:
        raise ValueError(f"unknown criterion {criterion!r}; expected one of {_CRITERIA}")
    if n_waves is not None and (not isinstance(n_waves, (int, np.integer)) or n_waves < 1):
        raise ValueError(f"n_waves must be a positive int or None; got {n_waves!r}")
    if noise is not None:
        check_values(np.asarray(noise) > 0, "noise must be > 0", noise)
    dtype = normals.dtype
    floor2 = (200 * float(jnp.finfo(dtype).eps) if noise_floor is None else float(noise_floor)) ** 2
    H = camera.resolution[0]
    tail_rows = jnp.zeros(H, dtype)
    rw = 0.0 if roughness is None else float(roughness_weight)
    T = normals.shape[0]

    holdout = criterion == "holdout" and n_waves is None
    if holdout and T < 3:
        raise ValueError("criterion='holdout' needs at least 3 frames (one is held out)")
    fit_n, fit_r, fit_t = (normals[:-1], None if roughness is None else roughness[:-1], times[:-1]) if holdout \
        else (normals, roughness, times)

    weight = _weights(fit_n, camera)
    m_obs = 2.0 * float(jnp.sum(weight))
    path_n, path_c, path_rss, path_acc = [], [], [], []
    total_steps = 0

    def run_lm(w: Waves, steps: int):
        # no roughness term while waves are missing: the observed roughness holds the
        # sub-pixel share of waves the model does not have yet, and would pull the others
        n = w.omega.shape[0]
        n_pad = _bucket(n)
        wp, active = _pad_waves(w, n_pad)
        out, _ = _refine_kernel(_pack(wp), active, fit_n, None, fit_t, camera, tail_rows,
                                jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), n_min=n_min, n_max=n_max,
                                max_steps=steps, roughness_weight=0.0)
        fitted = jax.tree.map(lambda x: x[:n], _to_waves(out.y, n_pad))
        return fitted, out

    def rss_of(out):
        # out.loss = 0.5 |r|^2 with residuals scaled by 1/sqrt(P): the RSS is loss * m
        return float(out.loss) * m_obs

    def score_of(w: Waves, out):
        if holdout:
            pred, _ = _predict(w, camera, times[-1:], n_min, n_max)
            wt = _weights(normals[-1:], camera)
            d = pred[..., :2] - normals[-1:, ..., :2]
            return float(jnp.sum(d * d * wt[..., None]) / jnp.maximum(jnp.sum(wt), 1.0))
        return _criterion_value(criterion, rss_of(out), m_obs, w.omega.shape[0], noise, floor2)

    # ---- start
    empty = Waves(*(jnp.zeros(0, dtype),) * 4)
    current = empty if init is None else Waves(*[jnp.asarray(x, dtype) for x in validate(init, max_steepness=None)])
    limit = n_waves if n_waves is not None else (current.omega.shape[0] if init is not None else max_waves)
    if init is not None and n_waves is None:
        limit = current.omega.shape[0]

    n_scales = scales if scales is not None else (1 if camera.projection == "orthographic" else 4)
    anchors, _, _, spacing, _ = _grid_frames(camera, n_scales, grid)
    spacing = np.asarray(spacing)
    coarse_extent = float(spacing[-1]) * grid
    om_long_hi = math.sqrt(GRAVITY * 1.5 * 2 * math.pi / coarse_extent) * 1.3
    long_om, long_th = _long_wave_grid(min(omega_min, 0.5 * om_long_hi), om_long_hi, 10, 36, dtype)
    res_scale = 2 * math.pi / (spacing * grid)  # FFT resolution of each grid [rad/m]
    # the finest wave-vector resolution the whole image allows: two waves closer than this
    # are one wave to the data (the longest sea baseline in the image)
    hit = cam.intersect_sea(camera)
    sea_xy = np.asarray(hit.xy)[np.asarray(hit.mask)]
    baseline = float(np.max(np.linalg.norm(sea_xy - sea_xy.mean(0), axis=1))) * 2.0
    k_res = 2 * math.pi / max(baseline, 1e-6)

    if current.omega.shape[0] > 0:
        current, best_out = run_lm(current, inner_steps if limit > current.omega.shape[0] else max_steps)
        total_steps += int(best_out.steps)
        best_score = score_of(current, best_out)
        rss_now = rss_of(best_out)
    elif holdout:
        wt = _weights(normals[-1:], camera)
        cn, _ = _clean(normals[-1:], None, wt)
        best_score = float(jnp.sum(cn[..., :2] ** 2 * wt[..., None]) / jnp.maximum(jnp.sum(wt), 1.0))
        rss_now = float("nan")
    else:
        cn, _ = _clean(fit_n, None, weight)
        rss_now = float(jnp.sum(cn[..., :2] ** 2 * weight[..., None]))
        best_score = _criterion_value(criterion, rss_now, m_obs, 0, noise, floor2)
    path_n.append(current.omega.shape[0])
    path_c.append(best_score)
    path_rss.append(rss_now)
    path_acc.append(True)

    n_cand = batch + 8
    cur_batch = batch
    timing = dict(detect=0.0, refine=0.0, lm=0.0)
    while current.omega.shape[0] < limit:
        n_cur = current.omega.shape[0]
        t_a = time.perf_counter()
        if n_cur > 0:
            resid, wt = _residual_slopes(current, fit_n, camera, fit_t, n_min, n_max)
        else:
            wt = weight
            resid = _slopes(_clean(fit_n, None, wt)[0])
        smp = _samples(resid, wt, fit_t, camera)
        smp_score = _subsample(smp, score_samples)
        est = _spectral(resid, wt, fit_t, camera, scales=n_scales, grid=grid, n_peaks=16)
        c_om = jnp.concatenate([est.peak_omega.ravel(), long_om])
        c_th = jnp.concatenate([est.peak_theta.ravel(), long_th])
        valid = np.concatenate([np.asarray(est.peak_power.ravel()) > 0, np.ones(long_om.shape, bool)])
        c_res = np.concatenate([np.repeat(res_scale, est.peak_power.shape[1]),
                                np.full(long_om.shape, res_scale[-1])])
        c_om = jnp.where(jnp.asarray(valid), c_om, 1.0)
        energy, _, _ = _score(c_om, c_th, smp_score, n_min, n_max)
        energy = np.where(valid, np.asarray(energy), -np.inf)
        # distinct candidates: the strongest first, dropping repeats of a wave vector within
        # the resolution of the grid that found it
        kc = _kvec(np.asarray(c_om), np.asarray(c_th))
        picked = []
        for j in np.argsort(-energy):
            if len(picked) >= n_cand or not np.isfinite(energy[j]) or energy[j] <= 0:
                break
            if all(np.hypot(*(kc[j] - kc[i])) > 0.5 * max(c_res[i], c_res[j]) for i in picked):
                picked.append(j)
        if not picked:
            break
        pj = np.asarray(picked)
        t_b = time.perf_counter()
        timing["detect"] += t_b - t_a
        smp_ref = _subsample(smp, 2 * score_samples)
        r_om, r_th, e_ref, a_ref, b_ref = (np.asarray(x) for x in _refine_candidates(
            jnp.asarray(_pad_to(np.asarray(c_om)[pj], n_cand, 1.0)), jnp.asarray(_pad_to(np.asarray(c_th)[pj], n_cand, 0.0)),
            smp_ref, n_min, n_max, 8))
        e_ref = np.where(np.arange(n_cand) < pj.size, e_ref, -np.inf)
        # a candidate is worth a trial only if it would explain more than the criterion's
        # penalty for 4 parameters in units of the residual variance (energies are on a
        # subsample: rescale to all samples)
        sub_w = float(jnp.sum(smp_ref.sw ** 2))
        e_all = e_ref * (float(jnp.sum(smp.sw ** 2)) / max(sub_w, 1e-30))
        rss_cur = float(jnp.sum(smp.sw ** 2 * jnp.sum(smp.target ** 2, -1)))  # slope-space residual
        sig2 = max(rss_cur / m_obs, floor2) if noise is None else float(noise) ** 2
        pen = 8.0 if criterion == "aic" else 4.0 * math.log(m_obs)
        e_ref = np.where((e_all >= pen * sig2) | (n_waves is not None), e_ref, -np.inf)
        kr = _kvec(r_om, r_th)
        k_old = _kvec(current.omega, current.theta) if n_cur else np.zeros((0, 2))
        n_add = min(cur_batch, limit - n_cur)
        chosen = []
        for j in np.argsort(-e_ref):
            if len(chosen) >= n_add or not np.isfinite(e_ref[j]) or e_ref[j] <= 0:
                break
            kn = np.hypot(*kr[j])
            sep = max(0.02 * kn, 0.7 * k_res)
            if k_old.size and np.min(np.hypot(*(k_old - kr[j]).T)) < sep:
                continue  # a wave the model already has
            if any(np.hypot(*(kr[j] - kr[i])) < max(sep, 0.5 * res_scale[0]) for i in chosen):
                continue
            if r_om[j] < 0.5 * omega_min:
                continue
            chosen.append(j)
        if not chosen:
            break
        ch = np.asarray(chosen)
        # one joint linear solve of the chosen candidates: drop those whose share of the
        # explained energy does not pay the criterion's penalty
        nb = _bucket(ch.size)
        a_j, b_j, part = (np.asarray(x) for x in _joint_ab(
            jnp.asarray(_pad_to(r_om[ch], nb, 1.0), dtype), jnp.asarray(_pad_to(r_th[ch], nb, 0.0), dtype),
            jnp.asarray(np.arange(nb) < ch.size, dtype), smp_ref, n_min, n_max))
        a_j, b_j, part = a_j[:ch.size], b_j[:ch.size], part[:ch.size] * (e_all[ch] / np.maximum(e_ref[ch], 1e-300))
        if n_waves is None:
            part = np.where(np.isfinite(part), part, 0.0)
            ok = part >= pen * sig2
            if not ok.any():
                ok = part >= part.max()
            ch, a_j, b_j = ch[ok], a_j[ok], b_j[ok]
        add = Waves(jnp.asarray(np.hypot(a_j, b_j), dtype), jnp.asarray(r_om[ch], dtype),
                    jnp.asarray(r_th[ch], dtype), jnp.asarray(np.mod(np.arctan2(b_j, a_j), 2 * np.pi), dtype))
        trial = jax.tree.map(lambda x, y: jnp.concatenate([x, y]), current, add)
        t_c = time.perf_counter()
        timing["refine"] += t_c - t_b
        trial, out = run_lm(trial, inner_steps)
        timing["lm"] += time.perf_counter() - t_c
        total_steps += int(out.steps)
        sc = score_of(trial, out)
        accepted = n_waves is not None or sc < best_score
        path_n.append(trial.omega.shape[0])
        path_c.append(sc)
        path_rss.append(rss_of(out))
        path_acc.append(bool(accepted))
        if verbose:
            print(f"  waves {trial.omega.shape[0]:4d}  criterion {sc:.6g}  rss/m {rss_of(out) / m_obs:.3e}  "
                  f"{'kept' if accepted else 'rejected'}  ({time.perf_counter() - t0:.0f} s; "
                  + ", ".join(f"{k} {v:.0f} s" for k, v in timing.items()) + ")", flush=True)
        if accepted:
            current, best_score = trial, sc
            if n_waves is None and not holdout and rss_of(out) / m_obs <= floor2:
                break  # explained to the floating-point floor: nothing left to find
        elif cur_batch > 1:
            cur_batch = max(1, cur_batch // 2)
        else:
            break

    # ---- final refinement on every frame, then pruning by the Wald statistic: a pruned
    # model is refitted and kept only if the criterion does not get worse
    if current.omega.shape[0] == 0:
        raise InvalidValueError("no wave found in the data (the normals show a flat sea)")

    rough_info = roughness is not None and rw > 0 and _roughness_informative(roughness, camera)

    def final_fit(w: Waves):
        # with informative roughness, alternate: the sub-pixel tail (non-negative least
        # squares over virtual wavelengths) for the current waves, then the waves for that tail
        tail = tail_rows
        out = None
        for _ in range(1):
            if rough_info:
                tail = _nnls_tail(w, roughness, camera, n_min, n_max, dtype)
            out = _final_once(w, tail)
            w = jax.tree.map(lambda x: x[:w.omega.shape[0]], _to_waves(out["y"], out["n_pad"]))
        out["tail"] = tail
        return out

    def _final_once(w: Waves, tail):
        if solver == "structured":
            n_pad = _bucket(w.omega.shape[0])
            wp, active = _pad_waves(w, n_pad)
            out, n_valid = _refine_kernel(_pack(wp), active, normals, roughness, times, camera, tail,
                                          jnp.asarray(rtol, dtype), jnp.asarray(atol, dtype), n_min=n_min,
                                          n_max=n_max, max_steps=max_steps, roughness_weight=rw if rough_info
                                          else 0.0, history=history)
            return dict(y=out.y, jtj=out.jtj, half=out.loss, steps=out.steps, success=out.success, hist=out.history,
                        active=active, n_valid=n_valid, n_pad=n_pad)
        active = jnp.ones(w.omega.shape[0], bool)
        o, n_valid, residual = _registry_refine(_pack(w), active, normals, roughness, times, camera, tail,
                                                solver=solver, n_min=n_min, n_max=n_max, max_steps=max_steps,
                                                rtol=rtol, atol=atol, roughness_weight=rw if rough_info else 0.0,
                                                history=history, options=None)
        return dict(y=o.params, jtj=_dense_jtj(residual, o.params), half=o.loss, steps=o.steps, success=o.success,
                    hist=o.history, active=active, n_valid=n_valid, n_pad=w.omega.shape[0])

    m_all = 2.0 * float(jnp.sum(_weights(normals, camera)))

    def crit(fit_, n):
        return _criterion_value(criterion if criterion != "holdout" else "bic", float(fit_["half"]) * m_all, m_all,
                                n, noise, floor2)

    best = final_fit(current)
    total_steps += int(best["steps"])
    if n_waves is None and prune:
        for _ in range(2):
            n_cur = current.omega.shape[0]
            keep = _wald_keep(best["y"], best["jtj"], best["active"], best["half"], 2.0 * float(best["n_valid"]),
                              criterion, noise, floor2)[:n_cur]
            if keep.all() or keep.sum() == 0:
                break
            fitted = jax.tree.map(lambda x: x[:n_cur], _to_waves(best["y"], best["n_pad"]))
            pruned = jax.tree.map(lambda x: x[np.nonzero(keep)[0]], fitted)
            trial = final_fit(pruned)
            total_steps += int(trial["steps"])
            better = crit(trial, pruned.omega.shape[0]) <= crit(best, n_cur)
            if verbose:
                print(f"  pruning {int((~keep).sum())} of {n_cur} waves (Wald statistic below the penalty): "
                      f"{'kept' if better else 'reverted'}", flush=True)
            if not better:
                break
            current, best = pruned, trial
    y, jtj, half, success, hist = best["y"], best["jtj"], best["half"], best["success"], best["hist"]
    active, n_valid = best["active"], best["n_valid"]
    rw = rw if rough_info else 0.0
    result = _result(y, active, jtj, half, n_valid, normals, roughness, camera, times, total_steps, success,
                     hist if history else None, rw, n_min, n_max, t0)
    n_fit = current.omega.shape[0]
    result = _sorted(result, n_fit)
    # the loop ran into the cap, not into the criterion: the count was not selected
    capped = n_waves is None and init is None and n_fit >= max_waves
    # converged is not enough: the fit must explain the data to their noise (measured: one
    # wave 1.25-2 footprints long, aliased by the start, "converged" at 0.05-0.12 rad)
    bound = normal_error_bound(noise)
    unexplained = not float(result.normal_error) <= bound
    result = result._replace(time_s=jnp.asarray(time.perf_counter() - t0, dtype),
                             success=jnp.asarray(result.success) & (not capped) & (not unexplained))
    _maybe_throw(result, throw, max_steps, capped, bound if unexplained else None)
    if return_selection:
        sel = OrderSelection(np.asarray(path_n), np.asarray(path_c), np.asarray(path_rss), np.asarray(path_acc))
        return result, sel
    return result


def _roughness_informative(roughness, camera):
    """True when some sea rows show roughness clearly above the renderer's floor."""
    r = np.asarray(roughness, np.float64)
    mask = np.asarray(cam.intersect_sea(camera).mask)
    vals = r[:, mask]
    vals = vals[np.isfinite(vals)]
    return bool(vals.size and np.percentile(vals, 90) > 2.0 * shading.MIN_SLOPE_VARIANCE)


def _nnls_tail(w: Waves, roughness, camera, n_min, n_max, dtype, n_virtual=24):
    """Per-row roughness ``(H,)`` of the sub-pixel waves that are not in ``w``: a
    non-negative combination of virtual waves at fixed wavelengths (each contributing
    ``1 - w_n(lambda_j / fp)`` per row) fitted to the observed roughness minus the share of
    ``w``. Host-side (SciPy NNLS), outside any gradient."""
    from scipy.optimize import nnls

    hit = cam.intersect_sea(camera)
    H, W = camera.resolution
    mask = np.asarray(hit.mask)
    fp_row = np.asarray(hit.footprint)[:, W // 2].astype(np.float64)
    r = np.asarray(roughness, np.float64)
    rows = mask.any(1)
    obs = np.array([np.nanmean(r[:, i][:, mask[i]]) if rows[i] else 0.0 for i in range(H)])
    om = np.asarray(w.omega, np.float64)
    h = np.asarray(w.amplitude, np.float64)
    k = om * om / GRAVITY
    lam = 2 * np.pi / k
    q = np.clip((lam[None, :] / fp_row[:, None] - n_min) / (n_max - n_min), 0, 1)
    kh2 = np.minimum((k * h) ** 2, 1.0)
    share = (1 - q * q * (3 - 2 * q)) @ (kh2 / (1 + np.sqrt(1 - kh2)))
    fp_sea = fp_row[rows]
    lam_v = np.geomspace(0.5 * n_min * fp_sea.min(), n_max * fp_sea.max(), n_virtual)
    qv = np.clip((lam_v[None, :] / fp_row[:, None] - n_min) / (n_max - n_min), 0, 1)
    B = 1 - qv * qv * (3 - 2 * qv)
    target = obs - share
    tail = np.zeros(H)
    if rows.any():
        v, _ = nnls(B[rows], np.maximum(target[rows], 0.0))
        tail = B @ v
    return jnp.asarray(np.where(rows, tail, 0.0), dtype)


def _wald_keep(y, jtj, active, half, n_obs, criterion, noise, floor2):
    """Keep a wave when deleting it (a = b = 0) would cost more than the criterion's penalty."""
    n = active.shape[0]
    p = 4 * n
    act = np.asarray(active)
    m = n_obs
    # residual variance in the solver's units (residuals scaled by 1/sqrt(P), P = m / 2)
    sigma2 = max(2.0 * float(half) / max(m - 4 * act.sum(), 1.0), floor2 / (m / 2.0))
    if noise is not None:
        sigma2 = float(noise) ** 2 / (m / 2.0)
    sigma2 = max(sigma2, 1e-300)
    A = np.asarray(jtj, np.float64)
    d = np.sqrt(np.maximum(np.diag(A), 1e-300))
    cov = np.linalg.pinv(A / d[:, None] / d[None, :] + 1e-9 * np.eye(p)) / d[:, None] / d[None, :]
    yy = np.asarray(y, np.float64).reshape(4, n)
    pen = 8.0 if criterion == "aic" else 4.0 * math.log(m)
    keep = np.ones(n, bool)
    for i in np.nonzero(act)[0]:
        idx = [i, n + i]
        C = cov[np.ix_(idx, idx)]
        x = yy[:2, i]
        try:
            wald = float(x @ np.linalg.solve(C, x))
        except np.linalg.LinAlgError:
            continue
        # x^T cov^-1 x is the RSS increase of deleting the wave; in units of sigma^2 it is
        # the Wald statistic, compared with the criterion's penalty for 4 parameters
        keep[i] = wald / sigma2 >= pen or not np.isfinite(wald)
    return keep


def _sorted(result: WaveFit, n: int) -> WaveFit:
    order = np.argsort(np.asarray(result.waves.omega)[:n])
    pick = lambda w: Waves(*[jnp.asarray(x)[:n][order] for x in w])  # noqa: E731
    return result._replace(waves=pick(result.waves), uncertainty=pick(result.uncertainty),
                           n_waves=jnp.asarray(n))


# =============================================================================== evaluation helpers


def resolvable(waves_: Waves, camera, *, cycles: float = 1.0, n_min=hierarchy.DEFAULT_N_MIN,
               n_max=hierarchy.DEFAULT_N_MAX, max_distance=cam.DEFAULT_MAX_DISTANCE) -> np.ndarray:
    """Which waves the image resolves individually: bool ``(N,)`` (eager, NumPy).

    A wave is resolvable when its normal weight is 1 (``lambda >= n_max x footprint``) on
    some sea pixels, and the extent of those pixels on the sea, measured along the wave's
    direction of travel, holds at least ``cycles`` wavelengths.
    """
    validate(waves_, max_steepness=None)
    hit = cam.intersect_sea(camera, max_distance=max_distance)
    mask = np.asarray(hit.mask)
    fp = np.asarray(hit.footprint)[mask]
    xy = np.asarray(hit.xy)[mask]
    om = np.asarray(waves_.omega, np.float64)
    th = np.asarray(waves_.theta, np.float64)
    lam = 2 * np.pi * GRAVITY / om ** 2
    out = np.zeros(om.shape, bool)
    for i in range(om.size):
        sel = fp * n_max <= lam[i]
        if not sel.any():
            continue
        proj = xy[sel] @ np.array([np.cos(th[i]), np.sin(th[i])])
        out[i] = (proj.max() - proj.min()) >= cycles * lam[i]
    return out


def match(fitted: Waves, truth: Waves, *, tolerance: float = 0.1) -> WaveMatch:
    """Match fitted to true waves one to one (Hungarian assignment on the relative
    wave-vector distance ``|k_fit - k_true| / |k_true|``); pairs farther than
    ``tolerance`` are left unmatched. Eager, NumPy."""
    from scipy.optimize import linear_sum_assignment

    def kv(w):
        om = np.asarray(w.omega, np.float64)
        th = np.asarray(w.theta, np.float64)
        k = om ** 2 / GRAVITY
        return np.stack([k * np.cos(th), k * np.sin(th)], -1), k

    kf, _ = kv(fitted)
    kt, k_true = kv(truth)
    cost = np.linalg.norm(kf[None, :, :] - kt[:, None, :], axis=-1) / k_true[:, None]
    ti, fi = linear_sum_assignment(cost)
    ok = cost[ti, fi] <= tolerance
    ti, fi = ti[ok], fi[ok]

    def arr(w, name, idx):
        return np.asarray(getattr(w, name), np.float64)[idx]

    def ang(x):
        return np.abs(np.mod(x + np.pi, 2 * np.pi) - np.pi)

    err = Waves(
        amplitude=np.abs(arr(fitted, "amplitude", fi) - arr(truth, "amplitude", ti)),
        omega=np.abs(arr(fitted, "omega", fi) - arr(truth, "omega", ti)),
        theta=ang(arr(fitted, "theta", fi) - arr(truth, "theta", ti)),
        phase=ang(arr(fitted, "phase", fi) - arr(truth, "phase", ti)),
    )
    missed = np.setdiff1d(np.arange(kt.shape[0]), ti)
    spurious = np.setdiff1d(np.arange(kf.shape[0]), fi)
    return WaveMatch(ti, fi, err, missed, spurious)
