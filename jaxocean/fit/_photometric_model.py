"""The photometric refinement's model (:mod:`jaxocean.fit.photometric`): parameters, residual, Jacobian.

Protocol: :class:`Static` (hashable: what is fitted, the render plan) and :class:`Data` (a
pytree: the target ``c(image) (T, H, W, C)``, used pixels ``(T, H, W)``, times ``(T,)``,
camera, start values) define one fit; its parameters are one vector ``y (P,)`` laid out by
:func:`layout` (waves ``(a, b, log omega, theta)`` per wave, sun ``(p, q)``, colour log
factors, log exposure), read back by :func:`unpack`. :func:`frame_residual` is frame ``i``'s
comparison-space residual ``(H, W, C)``; :func:`frame_jacobian` its exact Jacobian
``(H W C, P)`` (chain rule through the geometry on the rows path, forward mode through the
whole renderer on the hits path). Units as :mod:`jaxocean.fit.photometric`.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp

from jaxocean import camera as cam
from jaxocean import hierarchy, render, surface
from jaxocean._sea_scale import compress
from jaxocean.fit._photometry import pq_to_sun
from jaxocean.fit.waves._inputs import Samples
from jaxocean.fit.waves._model import jacobian as wave_jacobian
from jaxocean.fit.waves._model import to_waves
from jaxocean.shading import LUMINANCE, Lighting

_BLOCK = 8  # forward-mode Jacobian columns per vmapped block (see solvers.value_and_jacobian)
COLOR_NAMES = ("sun_color", "sky_color", "sea_color")


class Static(NamedTuple):
    """Hashable configuration of the jitted pieces."""

    n_waves: int
    fit_waves: bool
    fit_sun: bool
    colors: tuple  # fitted colour names
    gray: bool
    fit_exposure: bool
    n_exposure: int  # fitted log exposures: 1, or one per frame
    gauge: bool
    plan: render.RenderPlan


class Data(NamedTuple):
    """Arrays of one fit (a pytree)."""

    target: jax.Array  # (T, H, W, C) c(image)
    used: jax.Array  # (T, H, W) float 0/1
    times: jax.Array  # (T,)
    camera: cam.Camera
    scale: jax.Array  # (C,) sea median
    hg: jax.Array  # () horizon gradient
    waves0: jax.Array  # (4N,) packed start waves
    pq0: jax.Array  # (2,)
    colors0: jax.Array  # (3, 3) start colours (floored), rows sun / sky / sea
    log_exposure0: jax.Array  # ()
    basis: jax.Array  # (k, k - 1) zero-mean basis (gauge) or (k, k) identity


def model_frames(waves_, light, exposure, camera, times, hg, gray, plan):
    """``exposure * render`` of every frame, ``(T, H, W, C)`` (``C = 1`` gray); ``exposure``
    ``()`` or one per frame ``(T,)``."""
    def one(args):
        t, e = args
        img = e * render.render(waves_, camera, light, t, horizon_gradient=hg, plan=plan)
        return img @ jnp.asarray(LUMINANCE, img.dtype)[:, None] if gray else img

    return jax.lax.map(one, (times, jnp.broadcast_to(exposure, times.shape)))


def frame_exposure(exposure, i):
    """Frame ``i``'s exposure of a common ``()`` or per-frame ``(T,)`` exposure."""
    return exposure[i] if exposure.ndim else exposure


def n_color_params(st: Static) -> int:
    return len(st.colors) * (1 if st.gray else 3)


def layout(st: Static):
    """Slices of the parameter vector: waves, sun (p, q), colour coordinates, log exposure."""
    sizes = [("waves", 4 * st.n_waves if st.fit_waves else 0), ("sun", 2 if st.fit_sun else 0),
             ("colors", (n_color_params(st) - (1 if st.gauge else 0)) if st.colors else 0),
             ("exposure", st.n_exposure if st.fit_exposure else 0)]
    out, i = {}, 0
    for name, n in sizes:
        out[name] = slice(i, i + n)
        i += n
    return out, i


def unpack(y, d: Data, st: Static):
    """``(waves, lighting, exposure)`` of parameters ``y``."""
    lay, _ = layout(st)
    yw = y[lay["waves"]] if st.fit_waves else d.waves0
    waves_ = to_waves(yw, st.n_waves)
    pq = y[lay["sun"]] if st.fit_sun else d.pq0
    az, el = pq_to_sun(pq)
    colors = [d.colors0[i] for i in range(3)]
    if st.colors:
        s = d.basis @ y[lay["colors"]]
        per = 1 if st.gray else 3
        for j, name in enumerate(st.colors):
            i = COLOR_NAMES.index(name)
            colors[i] = colors[i] * jnp.exp(s[j * per:(j + 1) * per])
    if st.fit_exposure:
        log_e = y[lay["exposure"]]
        exposure = jnp.exp(log_e[0] if st.n_exposure == 1 else log_e)
    else:
        exposure = jnp.exp(d.log_exposure0)
    return waves_, Lighting(az, el, *colors), exposure


def pack_params(d: Data, st: Static):
    lay, n = layout(st)
    parts = []
    if st.fit_waves:
        parts.append(d.waves0)
    if st.fit_sun:
        parts.append(d.pq0)
    if st.colors:
        parts.append(jnp.zeros(lay["colors"].stop - lay["colors"].start, d.target.dtype))
    if st.fit_exposure:
        parts.append(jnp.broadcast_to(d.log_exposure0, (st.n_exposure,)))
    return jnp.concatenate(parts).astype(d.target.dtype)


def frame_residual(y, i, d: Data, st: Static):
    """Comparison-space residual of frame ``i``, ``(H, W, C)`` (unweighted)."""
    waves_, light, exposure = unpack(y, d, st)
    img = frame_exposure(exposure, i) * render.render(waves_, d.camera, light, d.times[i], horizon_gradient=d.hg,
                                                      plan=st.plan)
    if st.gray:
        img = img @ jnp.asarray(LUMINANCE, img.dtype)[:, None]
    return compress(img, d.scale) - d.target[i]


def all_residuals(y, d: Data, st: Static):
    return jax.lax.map(lambda i: frame_residual(y, i, d, st), jnp.arange(d.target.shape[0]))


def _blocked_jvps(fn, primal, tangents):
    """``(fn(primal), stack of jvp(fn, primal, tangent))`` for a pytree ``tangents`` with a
    leading axis ``K``: ``_BLOCK`` tangents per vmapped block, the blocks in a ``lax.map``
    (one compiled copy of the JVP; blocks of 8 also avoid the XLA:CPU float32 miscompile
    of wide vmapped JVPs described in :mod:`jaxocean.fit.solvers`). Outputs ``(K, ...)``."""
    K = jax.tree_util.tree_leaves(tangents)[0].shape[0]
    nb = -(-K // _BLOCK)
    pad = nb * _BLOCK - K
    blocks = jax.tree.map(lambda a: jnp.concatenate([a, jnp.zeros((pad,) + a.shape[1:], a.dtype)])
                          .reshape((nb, _BLOCK) + a.shape[1:]), tangents)
    out, cols = jax.lax.map(lambda V: jax.vmap(lambda v: jax.jvp(fn, (primal,), (v,)), out_axes=(None, 0))(V),
                            blocks)
    return out[0], cols.reshape((nb * _BLOCK,) + cols.shape[2:])[:K]


def _frame_jacobian_dense(y, i, d: Data, st: Static):
    """``(r (M,), J (M, P))`` of frame ``i`` by forward mode through the whole renderer
    (every parameter's tangent through the wave sums: the hits path's Jacobian)."""
    fn = lambda z: frame_residual(z, i, d, st).reshape(-1)  # noqa: E731
    r, cols = _blocked_jvps(fn, y, jnp.eye(y.shape[0], dtype=y.dtype))
    return r, cols.T


def frame_jacobian(y, i, d: Data, st: Static):
    """``(r (M,), J (M, P))`` of frame ``i``, exact, for the rows path by the chain rule
    through the geometry (each wave touches only its own sines):

    * ``d r / d normal`` (two tangents on the unit sphere) and ``d r / d slope_variance``
      (two) per pixel, and the lighting and exposure columns: forward mode through
      :func:`jaxocean.render.shade` alone, the geometry held;
    * ``d normal_xy / d wave`` per pixel: the wave fit's hand-written Jacobian of the rows
      path's normal (:func:`jaxocean.fit.waves._model.jacobian`);
    * ``d slope_variance / d wave`` per row: forward mode through the row roughness.

    Without fitted waves only the shading's columns. The hits path (``refine > 0``) uses
    :func:`_frame_jacobian_dense`."""
    if st.plan.refine != 0:
        return _frame_jacobian_dense(y, i, d, st)
    lay, P = layout(st)
    n = st.n_waves if st.fit_waves else 0
    dtype = y.dtype
    waves_, _, _ = unpack(y, d, st)
    t = d.times[i]
    geo = render.geometry(waves_, d.camera, t, plan=st.plan)
    normal, sv = geo.normal, geo.slope_variance
    H, W = d.camera.resolution

    def shaded(args):
        nrm, var, z = args
        _, light, exposure = unpack(z, d, st)
        img = frame_exposure(exposure, i) * render.shade(nrm, None, d.camera, light, slope_variance=var,
                                                          horizon_gradient=d.hg)
        if st.gray:
            img = img @ jnp.asarray(LUMINANCE, img.dtype)[:, None]
        return compress(img, d.scale) - d.target[i]

    # tangents: normal along x and y on the unit sphere, slope variance x and y, then the
    # non-wave parameters
    nz = jnp.maximum(normal[..., 2], 1e-6)
    zero_n, zero_v = jnp.zeros_like(normal), jnp.zeros_like(sv)
    ex = jnp.stack([jnp.ones_like(nz), jnp.zeros_like(nz), -normal[..., 0] / nz], -1)
    ey = jnp.stack([jnp.zeros_like(nz), jnp.ones_like(nz), -normal[..., 1] / nz], -1)
    one_x = jnp.zeros_like(sv).at[..., 0].set(1.0)
    one_y = jnp.zeros_like(sv).at[..., 1].set(1.0)
    n_other = P - 4 * n
    other = jnp.eye(P, dtype=dtype)[4 * n:]  # (n_other, P)
    t_n = jnp.concatenate([jnp.stack([ex, ey, zero_n, zero_n]), jnp.broadcast_to(zero_n, (n_other,) + normal.shape)])
    t_v = jnp.concatenate([jnp.stack([zero_v, zero_v, one_x, one_y]), jnp.broadcast_to(zero_v, (n_other,) + sv.shape)])
    t_y = jnp.concatenate([jnp.zeros((4, P), dtype), other])
    r, cols = _blocked_jvps(shaded, (normal, sv, y), (t_n, t_v, t_y))  # r (H, W, C), cols (4 + n_other, H, W, C)
    S, C = H * W, r.shape[-1]
    J_other = jnp.moveaxis(cols[4:], 0, -1).reshape(S * C, n_other)
    if not st.fit_waves:
        return r.reshape(-1), J_other

    # d normal_xy / d wave per pixel (the wave fit's rows-path model)
    hit = cam.intersect_sea(d.camera)
    samples = Samples(t=jnp.full((S,), t, dtype), xy=hit.xy.reshape(S, 2),
                      fp=jnp.broadcast_to(hit.footprint[:, W // 2][:, None], (H, W)).reshape(S),
                      target=jnp.zeros((S, 2), dtype), sw=jnp.ones((S,), dtype), ray=jnp.zeros((S, 2), dtype))
    _, jn = wave_jacobian(y[:4 * n].reshape(4, n), jnp.ones(n, dtype), samples, hierarchy.DEFAULT_N_MIN,
                          hierarchy.DEFAULT_N_MAX)
    jn = jn.reshape(H, W, 2, 4 * n) * hit.mask[..., None, None]
    # d slope_variance / d wave per row
    fp_row = hit.footprint[:, W // 2]

    def row_sv(yw):
        w = to_waves(yw, n)
        return jnp.stack(surface.slope_variance(w, hierarchy.weights(w, fp_row)), -1)  # (H, 2)

    _, jsv = _blocked_jvps(row_sv, y[:4 * n], jnp.eye(4 * n, dtype=dtype))  # (4N, H, 2)
    jsv = jnp.moveaxis(jsv, 0, -1) * jnp.any(hit.mask, axis=1)[:, None, None]  # (H, 2, 4N)
    jw = (cols[0][..., None] * jn[:, :, None, 0] + cols[1][..., None] * jn[:, :, None, 1]
          + cols[2][..., None] * jsv[:, None, None, 0] + cols[3][..., None] * jsv[:, None, None, 1])  # (H, W, C, 4N)
    return r.reshape(-1), jnp.concatenate([jw.reshape(S * C, 4 * n), J_other], axis=1)
