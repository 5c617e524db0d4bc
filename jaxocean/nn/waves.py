"""Wave-estimation network: a sequence of geometry to the component waves (Xie et al. 2024, §4.4).

Protocol
--------
A model is a :class:`WaveNetModel` ``(config, params)``: :class:`WaveNetConfig` (static,
hashable) and a params pytree ``{"encoder": ..., "mlp": ...}``.

Inputs (one scene; :func:`apply` takes a batch with a leading ``B`` axis):

* ``normals`` ``(T, H, W, 3)`` unit normals, world frame, z up (what
  :func:`jaxocean.render.geometry` and the geometry network return);
* ``roughness`` ``(T, H, W)`` slope variance (or None: the renderer's floor);
* ``camera`` the :class:`jaxocean.camera.Camera` of the geometry (``resolution == (H, W)``,
  H and W multiples of ``config.size_multiple``);
* ``times`` ``(T,)`` frame times [s], strictly increasing; ``T`` must equal
  ``config.frames`` (the network was trained on that many frames; pass a window).

Network input per pixel (:func:`features`), ``5 T + 7`` channels: per frame the normal
(3) and ``log10`` of the roughness (1, offset by 3), per frame its time ``t_i - t_0`` [s]
as a constant channel (the spacing is an input, not a constant of the model), and the
camera channels of :func:`jaxocean.nn.geometry.camera_channels` (view across / along /
up, log footprint, sea mask) plus the sea-plane point ``xy / 100 m``. Sky pixels and
invalid normals (non-finite or facing down) are set to the flat normal.

Network: a UNet (:func:`jaxocean.nn.backbones.UNet`) over the stacked frames, features
pooled over the sea pixels (mean and max) into a global vector, joined with the frame
times, and an MLP to ``slots`` wave slots, each ``(omega, theta, presence)``:

* ``omega`` = ``exp(log omega_lo + (log omega_hi - log omega_lo) sigmoid(raw))``: the
  band of waves this camera shows individually, ``omega_hi`` the shortest wave at normal
  level (wavelength ``(n_min + 0.1 (n_max - n_min))`` x the smallest sea footprint,
  :mod:`jaxocean.hierarchy`), ``omega_lo`` the wave one wavelength long across the sea's
  extent (diagonal of its bounding box on the plane), at least ``config.omega_min`` and at
  most ``omega_hi / 2``: positive, and never a wave the geometry cannot contain;
* ``theta`` = ``atan2`` of two outputs (direction of travel, world frame);
* ``presence`` = ``sigmoid(raw)`` in (0, 1).

Anchored slots (``config.anchors``, the ``cpu`` config): slot ``i`` starts at the ``i``-th
strongest peak of the space-time periodogram (:func:`jaxocean.fit.waves.spectral_peaks`,
moved to its sub-bin vertex; :func:`slot_anchors`), and one MLP shared by every slot maps
the global vector joined with that anchor's features (place in the band, direction in the
world and against the view, share of the peaks' power, rank, sub-bin offset) to a bounded
step ``omega = omega_a exp(0.15 tanh(raw))``, ``theta = theta_a + 0.25 tanh(raw)`` and a
presence (0 where the periodogram has fewer peaks than slots). The network then chooses
and refines waves the data show instead of placing them from nothing.

Amplitude and phase of the slots are not regressed: they are linear in the slope field
given ``(omega, theta)`` (:func:`jaxocean.fit.waves.solve_amplitudes`, one least-squares
solve of every slot jointly on the input normals and times, relative ridge
``config.ridge``), a differentiable layer of the model. The amplitude is then made
physical and weighted by the presence: ``h = presence (s / k) tanh(k h_ls / s)`` with
``k = omega^2 / g`` and ``s = config.max_steepness < 1``, so ``k h < 1`` always. Phases
are absolute (the wave model's time origin ``t = 0``, as every ``Waves``).

* :func:`init(key, config)` -> :class:`WaveNetModel`;
* :func:`apply(model, normals, roughness, camera, times)` on a batch -> :class:`WaveSlots`
  (every slot, ``(B, slots)`` leaves);
* :func:`predict(model, normals, roughness, camera, times, threshold=0.5)` for one scene
  -> ``Waves`` of the slots whose presence exceeds ``threshold``, sorted by frequency, their
  amplitudes and phases solved again jointly without the other slots and without the
  presence weight;
* :func:`save` / :func:`load` (``load(None)`` is the shipped pretrained model).

Units: lengths metres, times seconds, angles radians. :func:`apply` is jittable and
differentiable; params are float32.
"""

from __future__ import annotations

import functools
import importlib.resources
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import camera as cam
from jaxocean import hierarchy, shading
from jaxocean._records import record_from_json, record_to_json, register_static
from jaxocean.errors import check_values, is_concrete
from jaxocean.nn import backbones
from jaxocean.nn import layers as nl
from jaxocean.nn.checkpoint import load_model, load_tree, model_path, save_model
from jaxocean.nn.geometry import camera_channels
from jaxocean.waves import GRAVITY, Waves

__all__ = [
    "WaveNetConfig",
    "WaveNetModel",
    "WaveSlots",
    "SlotAnchors",
    "init",
    "features",
    "apply",
    "slot_anchors",
    "predict",
    "slots_to_waves",
    "save",
    "load",
    "model_info",
    "PRETRAINED",
    "PRETRAINED_PATH",
]

PRETRAINED_PATH = Path(str(importlib.resources.files("jaxocean.nn") / "pretrained" / "waves_cpu.npz"))
PRETRAINED = {"cpu": PRETRAINED_PATH}  # shipped models by name, as jaxocean.nn.geometry.PRETRAINED
_FORMAT = "jaxocean.nn.waves/1"
_MIN_NZ = 1e-3  # normals with n_z below this are invalid (facing down or grazing)
_XY_SCALE = 100.0  # m: sea-plane coordinates enter the network divided by this


class WaveNetConfig(NamedTuple):
    """Architecture of a wave-estimation network (static and hashable)."""

    frames: int = 6  # T: frames per input sequence
    slots: int = 16  # N: wave slots
    widths: tuple = (16, 32, 64)  # UNet levels
    hidden: int = 128  # MLP width (two hidden layers)
    omega_min: float = 0.3  # rad/s: lowest slot frequency
    max_steepness: float = 0.8  # s: k h < s
    ridge: float = 1e-3  # relative ridge of the amplitude solve
    anchors: bool = False  # slots anchored on the periodogram's peaks (see the module docstring)

    def validate(self) -> "WaveNetConfig":
        if not isinstance(self.frames, int) or self.frames < 2:
            raise ValueError(f"frames must be an int >= 2 (frequency comes from the motion); got {self.frames!r}")
        if not isinstance(self.slots, int) or self.slots < 1:
            raise ValueError(f"slots must be a positive int; got {self.slots!r}")
        if not 0.0 < self.max_steepness < 1.0:
            raise ValueError(f"max_steepness must be in (0, 1); got {self.max_steepness}")
        if not self.omega_min > 0:
            raise ValueError(f"omega_min must be > 0 rad/s; got {self.omega_min}")
        return self

    @property
    def in_channels(self) -> int:
        return 5 * self.frames + 7

    @property
    def size_multiple(self) -> int:
        return 2 ** (len(self.widths) - 1)

    def to_json(self) -> dict:
        return record_to_json(self)

    @classmethod
    def from_json(cls, d: dict) -> "WaveNetConfig":
        return record_from_json(cls, d, "wave network config").validate()


# a pytree node without leaves (the config is its static aux data), as GeometryConfig:
# jax.jit(apply)(model, ...) traces the params alone
register_static(WaveNetConfig)


class WaveNetModel(NamedTuple):
    """A wave network: its ``config`` (static under ``jax.jit``) and ``params``."""

    config: WaveNetConfig
    params: dict


class WaveSlots(NamedTuple):
    """Every slot of a prediction: ``waves`` (``Waves`` with ``(..., N)`` leaves, amplitude
    already weighted by the presence) and ``presence (..., N)`` in (0, 1)."""

    waves: Waves
    presence: jax.Array


def _networks(config: WaveNetConfig):
    encoder = backbones.UNet(config.widths)
    out = (3, 0.01) if config.anchors else (4 * config.slots, 0.1)
    mlp = nl.serial(nl.Dense(config.hidden), nl.Relu, nl.Dense(config.hidden), nl.Relu,
                    nl.Dense(out[0], w_scale=out[1]))
    return encoder, mlp


def _slot_bias(config: WaveNetConfig):
    """Initial slot outputs spread over the band (log frequency) and the circle (direction,
    golden-ratio steps), presence 0.88: an untrained model starts from distinct waves."""
    n = config.slots
    frac = (np.arange(n) + 0.5) / n
    ang = 2 * np.pi * np.mod(np.arange(n) * 0.6180339887, 1.0)
    raw = np.stack([np.log(frac / (1 - frac)), np.cos(ang), np.sin(ang), np.full(n, 2.0)], -1)
    return jnp.asarray(raw.reshape(-1), jnp.float32)


def init(key, config: WaveNetConfig = WaveNetConfig()) -> WaveNetModel:
    config = config.validate()
    encoder, mlp = _networks(config)
    k1, k2 = jax.random.split(key)
    (_, _, _, width), p_enc = encoder.init(k1, (-1, 32, 32, config.in_channels))
    extra = _ANCHOR_FEATURES if config.anchors else 0
    _, p_mlp = mlp.init(k2, (-1, 2 * width + config.frames + extra))
    last = dict(p_mlp[-1])
    # anchored: no change of the peak, presence sigmoid(3) = 0.95; free: slots spread out
    last["b"] = jnp.asarray([0.0, 0.0, 3.0], jnp.float32) if config.anchors else _slot_bias(config)
    p_mlp = p_mlp[:-1] + (last,)
    return WaveNetModel(config, {"encoder": p_enc, "mlp": p_mlp})


# --------------------------------------------------------------------------- inputs


def _check_scene(config: WaveNetConfig, normals, roughness, camera, times) -> None:
    """Structure checks of one scene (shapes only: traceable)."""
    if not isinstance(camera, cam.Camera):
        raise ValueError(f"camera must be a jaxocean Camera; got {type(camera).__name__}")
    H, W = camera.resolution
    T = config.frames
    if normals.ndim != 4 or normals.shape[1:] != (H, W, 3):
        raise ValueError(f"normals must be (T, H, W, 3) with (H, W) = camera.resolution = {(H, W)}; "
                         f"got {tuple(normals.shape)}")
    if normals.shape[0] != T:
        raise ValueError(f"this wave network takes sequences of exactly {T} frames (config.frames); got "
                         f"{normals.shape[0]} -- pass a window of {T} frames")
    if roughness is not None and tuple(roughness.shape) != (T, H, W):
        raise ValueError(f"roughness must be (T, H, W) = {(T, H, W)}; got {tuple(roughness.shape)}")
    if tuple(times.shape) != (T,):
        raise ValueError(f"times must be (T,) = ({T},); got {tuple(times.shape)}")
    m = config.size_multiple
    if H % m or W % m:
        raise ValueError(f"the network needs H and W divisible by {m} (its UNet has {len(config.widths)} "
                         f"levels); got {(H, W)}")


def _check_normals(normals, camera) -> None:
    """Values of one scene's normals (concrete): every frame needs valid sea pixels (the
    network would read an all-invalid frame as a flat sea), and those must be unit vectors
    (an image's RGB passed as normals would be read as slopes)."""
    if not is_concrete(normals):
        return
    valid = np.asarray(_valid(normals, camera_channels(camera)[1]))
    empty = np.flatnonzero(~valid.any(axis=(1, 2)))
    if empty.size:
        raise ValueError(f"frame {int(empty[0])} has no valid sea normal (all NaN, sky or facing down): "
                         f"nothing to estimate waves from")
    shading.check_unit_normals(normals, "normals", where=valid, counted=" valid sea pixels")


def _valid(normals, mask):
    finite = jnp.all(jnp.isfinite(normals), -1)
    return finite & (jnp.where(finite, normals[..., 2], 0.0) > _MIN_NZ) & mask[None]


def features(normals, roughness, camera, times):
    """Network input ``(H, W, 5 T + 7)`` of one scene and the sea mask ``(H, W)``."""
    chans, mask = camera_channels(camera)
    hit = cam.intersect_sea(camera)
    normals = jnp.asarray(normals, jnp.float32)
    T, H, W = normals.shape[:3]
    ok = _valid(normals, mask)
    up = jnp.asarray([0.0, 0.0, 1.0], jnp.float32)
    n = jnp.where(ok[..., None], normals, up)
    if roughness is None:
        r = jnp.full((T, H, W), shading.MIN_SLOPE_VARIANCE, jnp.float32)
    else:
        r = jnp.asarray(roughness, jnp.float32)
    r = jnp.where(ok & jnp.isfinite(r), r, shading.MIN_SLOPE_VARIANCE)
    logr = (jnp.log10(jnp.maximum(r, 1e-6)) + 3.0) * ok
    t = jnp.asarray(times, jnp.float32)
    t = t - t[0]
    per_frame = jnp.concatenate([n, logr[..., None]], -1)  # (T, H, W, 4)
    per_frame = jnp.moveaxis(per_frame, 0, 2).reshape(H, W, 4 * T)
    tmaps = jnp.broadcast_to(t, (H, W, T))
    xy = hit.xy.astype(jnp.float32) / _XY_SCALE * mask[..., None]
    return jnp.concatenate([per_frame, tmaps, chans.astype(jnp.float32), xy], -1), mask


def _omega_band(config: WaveNetConfig, camera):
    """``(omega_lo, omega_hi)`` of the slots for ``camera``: the shortest wave the camera
    shows at normal level (see the module docstring)."""
    hit = cam.intersect_sea(camera)
    fp_min = jnp.min(jnp.where(hit.mask, hit.footprint, jnp.inf))
    fp_min = jnp.where(jnp.isfinite(fp_min), fp_min, 1.0)
    n_lo = hierarchy.DEFAULT_N_MIN + 0.1 * (hierarchy.DEFAULT_N_MAX - hierarchy.DEFAULT_N_MIN)
    om_hi = jnp.sqrt(2 * jnp.pi * GRAVITY / (n_lo * fp_min))
    # the longest wave: one wavelength across the sea's extent (a longer one is a tilt)
    m = hit.mask[..., None]
    lo_xy = jnp.min(jnp.where(m, hit.xy, jnp.inf), (0, 1))
    hi_xy = jnp.max(jnp.where(m, hit.xy, -jnp.inf), (0, 1))
    extent = jnp.sqrt(jnp.sum(jnp.square(jnp.where(jnp.isfinite(hi_xy - lo_xy), hi_xy - lo_xy, 1.0))))
    om_lo = jnp.maximum(jnp.sqrt(2 * jnp.pi * GRAVITY / jnp.maximum(extent, 1e-3)), config.omega_min)
    om_lo = jnp.minimum(om_lo, 0.5 * om_hi)
    return om_lo.astype(jnp.float32), om_hi.astype(jnp.float32)


def _slot_outputs(config: WaveNetConfig, raw, om_lo, om_hi):
    """Raw MLP outputs ``(N, 4)`` of one scene -> ``omega``, ``theta``, ``presence`` ``(N,)``."""
    log_lo, log_hi = jnp.log(om_lo), jnp.log(om_hi)
    omega = jnp.exp(log_lo + (log_hi - log_lo) * jax.nn.sigmoid(raw[:, 0]))
    c, s = raw[:, 1], raw[:, 2]
    # atan2 of a vector kept away from the origin (a finite gradient everywhere): the
    # squared length is compared, as sqrt(r^2 + 1e-12) is never below 1e-6
    theta = jnp.arctan2(s, c + 1e-6 * (c * c + s * s < 1e-12))
    return omega, theta, jax.nn.sigmoid(raw[:, 3])


class SlotAnchors(NamedTuple):
    """Where an anchored model's slots start (:func:`slot_anchors`): leaves ``(..., N)``
    and ``features (..., N, 9)``."""

    omega: jax.Array  # (N,) rad/s
    theta: jax.Array  # (N,) rad
    on: jax.Array  # (N,) bool: a peak (False: fewer peaks than slots)
    features: jax.Array  # (N, _ANCHOR_FEATURES)


_ANCHOR_FEATURES = 9
_ANCHOR_STEP = (0.15, 0.25)  # the network moves an anchor by at most this d log omega, d theta [rad]


def slot_anchors(config: WaveNetConfig, normals, camera, times) -> SlotAnchors:
    """The anchors of one scene's slots (``config.anchors``; traceable): the ``config.slots`` strongest periodogram peaks
    (:func:`jaxocean.fit.waves.spectral_peaks`) at their sub-bin positions, and per anchor its
    place in the band, direction (world and against the view), share of the peaks' power,
    rank and sub-bin offset. A function of the input alone (no gradient flows through it), so
    training computes it once per scene and passes it to :func:`apply`."""
    from jaxocean.fit.waves import spectral_peaks

    pk = jax.lax.stop_gradient(spectral_peaks(normals, camera, times, config.slots))
    on = pk.power > 0
    lo, hi = _omega_band(config, camera)
    omega = jnp.where(on, pk.omega * jnp.exp(pk.offset[:, 0]), lo)
    theta = jnp.where(on, pk.theta + pk.offset[:, 1], 0.0)
    place = jnp.clip((jnp.log(omega) - jnp.log(lo)) / (jnp.log(hi) - jnp.log(lo)), -1.0, 2.0)
    share = jnp.log10(pk.power / jnp.maximum(jnp.sum(pk.power), 1e-30) + 1e-6) / 6.0
    against_view = theta - jnp.asarray(camera.yaw, theta.dtype)
    rank = jnp.arange(config.slots, dtype=theta.dtype) / config.slots
    feats = jnp.stack([place, jnp.cos(theta), jnp.sin(theta), jnp.cos(against_view), jnp.sin(against_view), share,
                       rank, pk.offset[:, 0] / 0.1, pk.offset[:, 1] / 0.1], -1)
    return SlotAnchors(omega, theta, on, (feats * on[:, None]).astype(jnp.float32))


def _anchored_outputs(raw, anchors: SlotAnchors):
    """Raw per-slot outputs ``(N, 3)`` -> ``omega``, ``theta``, ``presence`` ``(N,)``: each
    anchor moved by a bounded step (``_ANCHOR_STEP``); a slot without a peak is off."""
    omega = anchors.omega * jnp.exp(_ANCHOR_STEP[0] * jnp.tanh(raw[:, 0]))
    theta = anchors.theta + _ANCHOR_STEP[1] * jnp.tanh(raw[:, 1])
    return omega, theta, jax.nn.sigmoid(raw[:, 2]) * anchors.on


def _amplitudes(config: WaveNetConfig, normals, camera, times, omega, theta, active=None):
    """Amplitude and phase by the linear solve (of the ``active`` slots; default all), the
    amplitude made physical: ``(s / k) tanh(k h / s)``, so ``k h < s`` always."""
    from jaxocean.fit.waves import solve_amplitudes

    w = solve_amplitudes(normals, camera, times, omega, theta, ridge=config.ridge, active=active)
    k = omega * omega / GRAVITY
    s = config.max_steepness
    return (s / k) * jnp.tanh(k * w.amplitude / s), w.phase


# predict's solve of the kept slots alone (fixed shape: one compilation for every subset)
_kept_amplitudes = jax.jit(_amplitudes, static_argnums=0)


def apply(model: WaveNetModel, normals, roughness, camera, times, *, anchors: SlotAnchors | None = None, key=None,
          train: bool = False) -> WaveSlots:
    """Every slot for a batch: ``normals (B, T, H, W, 3)``, ``roughness (B, T, H, W)`` or
    None, ``camera`` a Camera with ``(B,)`` leaves, ``times (B, T)``; for an anchored model
    ``anchors`` (:func:`slot_anchors` of each scene, ``(B, N)`` leaves) or None (computed)."""
    config = model.config
    normals = jnp.asarray(normals, jnp.float32)
    times = jnp.asarray(times, jnp.float32)
    if normals.ndim != 5:
        raise ValueError(f"apply takes a batch of normals (B, T, H, W, 3); got {tuple(normals.shape)} "
                         "(use predict for one scene)")
    one = jax.tree.map(lambda x: x[0], camera)
    _check_scene(config, normals[0], None if roughness is None else roughness[0], one, times[0])
    rough_in = roughness if roughness is not None else None
    feats, mask = jax.vmap(lambda n, r, c, t: features(n, r, c, t), in_axes=(0, 0 if rough_in is not None else None,
                                                                             0, 0))(normals, rough_in, camera, times)
    encoder, mlp = _networks(config)
    k1, k2 = (None, None) if key is None else jax.random.split(key)
    f = encoder.apply(model.params["encoder"], feats, key=k1, train=train)  # (B, H, W, w0)
    m = mask[..., None].astype(f.dtype)
    mean = jnp.sum(f * m, (1, 2)) / jnp.maximum(jnp.sum(m, (1, 2)), 1.0)
    mx = jnp.max(jnp.where(m > 0, f, -1e4), (1, 2))
    mx = jnp.where(mx > -1e3, mx, 0.0)
    t_rel = times - times[:, :1]
    g = jnp.concatenate([mean, mx, t_rel], -1)
    if config.anchors:
        if anchors is None:
            anchors = jax.vmap(lambda n, c, t: slot_anchors(config, n, c, t))(normals, camera, times)
        B, N = g.shape[0], config.slots
        per_slot = jnp.concatenate([jnp.broadcast_to(g[:, None], (B, N, g.shape[-1])), anchors.features], -1)
        raw = mlp.apply(model.params["mlp"], per_slot.reshape(B * N, -1), key=k2, train=train).reshape(B, N, 3)
        omega, theta, presence = jax.vmap(_anchored_outputs)(raw, anchors)
    else:
        raw = mlp.apply(model.params["mlp"], g, key=k2, train=train).reshape(-1, config.slots, 4)
        omega, theta, presence = jax.vmap(lambda r, c: _slot_outputs(config, r, *_omega_band(config, c)))(raw, camera)

    def per_scene(n_i, cam_i, t_i, omega_i, theta_i, presence_i):
        h, phase = _amplitudes(config, n_i, cam_i, t_i, omega_i, theta_i)
        return WaveSlots(Waves(presence_i * h, omega_i, theta_i, phase), presence_i)

    return jax.vmap(per_scene)(normals, camera, times, omega, theta, presence)


def slots_to_waves(slots: WaveSlots, threshold: float = 0.5) -> Waves:
    """The waves of one scene's slots (leaves ``(N,)``) whose presence exceeds ``threshold``,
    sorted by frequency (eager, NumPy float64 leaves)."""
    keep = np.asarray(slots.presence) > threshold
    w = Waves(*[np.asarray(x, np.float64)[keep] for x in slots.waves])
    order = np.argsort(w.omega)
    return Waves(*[x[order] for x in w])


def predict(model: WaveNetModel, normals, roughness, camera, times, *, threshold: float = 0.5,
            return_slots: bool = False):
    """The waves of one scene (``Waves`` with ``(n,)`` leaves: the slots with presence above
    ``threshold``, amplitudes and phases solved again jointly without the other slots and
    the presence weight), or ``(Waves, WaveSlots)`` with ``return_slots=True`` (every slot
    as :func:`apply` gives it). Inputs as in the
    module docstring; ``ValueError`` names a wrong shape, frame count or resolution, frame
    times that are not finite and strictly increasing (in float32, the model's precision) and
    a negative roughness (NaN: no data, as an invalid normal)."""
    normals = jnp.asarray(normals, jnp.float32)
    times_np = np.asarray(times, np.float64)
    rough = None if roughness is None else jnp.asarray(roughness, jnp.float32)
    _check_scene(model.config, normals, rough, camera, times_np)
    # increasing in float32 (the network's precision) implies increasing in float64
    if not (np.all(np.isfinite(times_np)) and np.all(np.diff(times_np.astype(np.float32)) > 0)):
        raise ValueError(f"times must be finite and strictly increasing in float32, the network's precision; got "
                         f"{times_np} (times that increase only in float64: subtract a time origin, the phases are "
                         "then relative to it)")
    if not 0.0 <= threshold < 1.0:
        raise ValueError(f"threshold must be in [0, 1); got {threshold}")
    _check_normals(normals, camera)
    if rough is not None:  # as fit.waves: a slope variance below 0 is no geometry, not one to clamp
        r = np.asarray(rough)
        check_values(~np.isfinite(r) | (r >= 0), "roughness (slope variance) must be >= 0 (NaN: no data)", r)
    slots = _predict_jit(model.config, model.params, normals[None], None if rough is None else rough[None],
                         jax.tree.map(lambda x: jnp.asarray(x)[None], camera), jnp.asarray(times_np, jnp.float32)[None])
    slots = jax.tree.map(lambda x: x[0], slots)
    # finite inputs give finite slots (the outputs are bounded maps): a NaN is the model's,
    # and dropping its slots at the threshold would answer "no waves"
    check_values(np.all([np.all(np.isfinite(np.asarray(x))) for x in jax.tree.leaves(slots)]),
                 "the wave network's outputs are not finite: its parameters hold NaN or inf (a diverged "
                 "training?)")
    # the kept slots' amplitudes and phases solved again without the others and without
    # the presence weight that training needs (measured on the test split: MAE h 0.0063 ->
    # 0.0060 m, geometry loss 0.627 -> 0.619)
    keep = slots.presence > threshold
    h, phase = _kept_amplitudes(model.config, normals, camera, jnp.asarray(times_np, jnp.float32),
                                slots.waves.omega, slots.waves.theta, keep)
    w = slots_to_waves(slots._replace(waves=slots.waves._replace(amplitude=h, phase=phase)), threshold)
    return (w, slots) if return_slots else w


@functools.partial(jax.jit, static_argnums=0)
def _predict_jit(config, params, normals, roughness, camera, times):
    return apply(WaveNetModel(config, params), normals, roughness, camera, times)


# --------------------------------------------------------------------------- files


def save(path, model: WaveNetModel, meta: dict | None = None) -> Path:
    """Write a model (params and config) to ``path`` (``.npz``), atomically."""
    return save_model(path, model.params, model.config, _FORMAT, meta)


def load(path=None) -> WaveNetModel:
    """A model written by :func:`save`; ``None`` (or ``"cpu"``) loads the shipped pretrained model.

    Raises :class:`jaxocean.nn.checkpoint.CheckpointError` naming the file when it is
    missing, corrupt or not a wave network of this version."""
    config, params = load_model(model_path(path, PRETRAINED, PRETRAINED_PATH), fmt=_FORMAT, what="a wave network",
                                config_from_json=WaveNetConfig.from_json,
                                init_params=lambda c: init(jax.random.key(0), c).params)
    return WaveNetModel(config, params)


def model_info(path=None) -> dict:
    """The metadata stored with a model (config, training summary)."""
    return load_tree(model_path(path, PRETRAINED, PRETRAINED_PATH), None, meta_only=True)
