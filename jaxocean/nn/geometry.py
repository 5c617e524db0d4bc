"""Geometry networks: one ocean image to per-pixel normal and sub-pixel roughness.

Protocol
--------
A model is a :class:`GeometryModel` ``(config, params)``: :class:`GeometryConfig` (static,
hashable: architecture and input mode) and a params pytree ``{"normal": ..., "roughness":
...}`` for its two sub-networks (the paper's sub-net1 and sub-net2, Xie et al. 2024 §4.3).

* :func:`init(key, config)` -> :class:`GeometryModel`.
* :func:`features(image, camera, color)` -> ``(H, W, C)`` network input: the image
  compressed as ``log1p(I / m)`` with ``m`` the per-channel median of the sea pixels (so
  exposure and sky brightness drop out), or its luminance for ``color="gray"``; then the
  per-pixel camera channels: the unit view vector in the camera's horizontal frame
  (across, along, up), ``log`` of the pixel footprint in metres and the sea mask.
* :func:`apply(model, feats, camera_yaw, mask)` -> :class:`GeometryPrediction` for a batch
  ``(B, H, W, C)``: ``normal (B, H, W, 3)`` unit, world frame; ``slope_variance (B, H, W,
  2)`` along the world tangent axes of :func:`jaxocean.shading.tangent_frame` (what
  :func:`jaxocean.render.shade` takes), at least ``shading.MIN_SLOPE_VARIANCE_AXIS``;
  ``roughness = sum`` of the pair. Sky pixels get the flat normal and the floor.
* :func:`predict(model, images, camera)` does both for a sequence ``(T, H, W, 3)`` of linear
  RGB images (or ``(T, H, W)`` gray) seen by one camera; :func:`load` / :func:`save` read and
  write models (``load(None)`` is the shipped pretrained model).

Normal heads (``GeometryConfig.normal_head``), all in the camera's horizontal frame (x
across the view to the right, y along the view, z up) and rotated to the world by the yaw:

* ``"vec"`` (the paper's VecN): a 3-vector ``a``, normal = ``normalize(a + (0, 0, 1))``;
* ``"sphere"`` (SphereN): polar and azimuth angles;
* ``"slope"``: the surface slope ``s = (-n_x / n_z, -n_y / n_z)``, normal =
  ``normalize(-s_x, -s_y, 1)`` -- the quantity the slope skill scores.

The roughness head predicts ``log`` of the slope variances along and across the view
above the floor (``log sigma2 = log(floor) + softplus(raw)``); they are mapped to the
world axes by the yaw as a covariance diagonal (exact for yaw 0, the dataset's cameras).

Units: radiance linear, lengths metres, angles radians. Everything is jittable and
vmappable; params are float32.
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
from jaxocean import shading
from jaxocean._math import normal_from_slope, safe_normalize
from jaxocean._records import record_from_json, record_to_json, register_static
from jaxocean._sea_scale import compress, sea_median
from jaxocean.errors import InvalidValueError, is_integer
from jaxocean.nn import backbones
from jaxocean.nn import layers as nl
from jaxocean.nn.checkpoint import load_model, load_tree, model_path, nonfinite_arrays, save_model
from jaxocean.nn.training import data_parallel

__all__ = [
    "GeometryConfig",
    "GeometryModel",
    "GeometryPrediction",
    "NORMAL_HEADS",
    "COLOR_MODES",
    "init",
    "features",
    "camera_channels",
    "apply",
    "predict",
    "save",
    "load",
    "PRETRAINED_PATH",
    "PRETRAINED",
    "LUMINANCE",
]

NORMAL_HEADS = ("vec", "sphere", "slope")
COLOR_MODES = ("rgb", "gray")
LUMINANCE = shading.LUMINANCE  # re-exported: Rec. 709 weights, gray images as the luminance of the RGB model
_SLOPE_FLOOR = shading.MIN_SLOPE_VARIANCE_AXIS
# package data (pyproject's package-data), found wherever the package is installed
PRETRAINED_PATH = Path(str(importlib.resources.files("jaxocean.nn") / "pretrained" / "geometry_cpu.npz"))
#: the shipped models by name: ``"cpu"`` (the default, trained by the ``cpu`` config on two
#: CPU cores) and ``"gpu"`` (a 2.05 M-parameter UNet trained by the ``gpu`` config on one GPU;
#: more accurate on every input measured, about 2.5x the CPU time per frame)
PRETRAINED = {"cpu": PRETRAINED_PATH, "gpu": PRETRAINED_PATH.with_name("geometry_gpu.npz")}
_FORMAT = "jaxocean.nn.geometry/1"


class GeometryConfig(NamedTuple):
    """Architecture of a geometry model (static and hashable)."""

    backbone: str = "unet"
    normal_head: str = "slope"
    widths: tuple = (16, 32, 64)  # UNet levels of the normal sub-network
    resnet_width: int = 32
    resnet_blocks: int = 4
    roughness_widths: tuple = (8, 16, 32)  # UNet levels (or ResNet width = first) of the roughness sub-network
    color: str = "rgb"

    def validate(self) -> "GeometryConfig":
        if self.backbone not in ("unet", "resnet"):
            raise ValueError(f"backbone must be 'unet' or 'resnet'; got {self.backbone!r}")
        if self.normal_head not in NORMAL_HEADS:
            raise ValueError(f"normal_head must be one of {NORMAL_HEADS}; got {self.normal_head!r}")
        if self.color not in COLOR_MODES:
            raise ValueError(f"color must be one of {COLOR_MODES}; got {self.color!r}")
        for name in ("widths", "roughness_widths"):
            widths = getattr(self, name)
            if not (isinstance(widths, tuple) and widths and all(is_integer(w, 1) for w in widths)):
                raise ValueError(f"{name} must be a non-empty tuple of channel counts >= 1; got {widths!r}")
        for name in ("resnet_width", "resnet_blocks"):
            if not is_integer(getattr(self, name), 1):
                raise ValueError(f"{name} must be an integer >= 1; got {getattr(self, name)!r}")
        return self

    @property
    def in_channels(self) -> int:
        return (3 if self.color == "rgb" else 1) + 5

    @property
    def size_multiple(self) -> int:
        if self.backbone == "unet":
            return 2 ** (max(len(self.widths), len(self.roughness_widths)) - 1)
        return 2

    def to_json(self) -> dict:
        return record_to_json(self)

    @classmethod
    def from_json(cls, d: dict) -> "GeometryConfig":
        return record_from_json(cls, d, "geometry config").validate()


# a pytree node without leaves (the config is its static aux data): jax.jit(apply)(model, ...)
# traces the params alone, and jax.tree.map over a model maps its params
register_static(GeometryConfig)


class GeometryModel(NamedTuple):
    """A geometry network: its ``config`` (static under ``jax.jit``) and ``params``."""

    config: GeometryConfig
    params: dict


class GeometryPrediction(NamedTuple):
    """Per-pixel geometry: ``normal (..., H, W, 3)``, ``slope_variance (..., H, W, 2)``,
    ``roughness (..., H, W)``, ``mask (..., H, W)`` (True on the sea)."""

    normal: jax.Array
    slope_variance: jax.Array
    roughness: jax.Array
    mask: jax.Array


def _head_channels(head: str) -> int:
    return {"vec": 3, "sphere": 2, "slope": 2}[head]


def _networks(config: GeometryConfig):
    if config.backbone == "unet":
        normal = backbones.UNet(config.widths)
        rough = backbones.UNet(config.roughness_widths)
    else:
        normal = backbones.ResNet(config.resnet_width, config.resnet_blocks)
        rough = backbones.ResNet(config.roughness_widths[0], max(1, config.resnet_blocks // 2))
    # small last layers: an untrained model predicts a nearly flat sea at the roughness floor
    return (nl.serial(normal, nl.Conv(_head_channels(config.normal_head), 1, w_scale=0.1)),
            nl.serial(rough, nl.Conv(2, 1, w_scale=0.1)))


def init(key, config: GeometryConfig = GeometryConfig()) -> GeometryModel:
    config = config.validate()
    normal_net, rough_net = _networks(config)
    shape = (-1, 64, 64, config.in_channels)
    k1, k2 = jax.random.split(key)
    _, p_normal = normal_net.init(k1, shape)
    _, p_rough = rough_net.init(k2, shape)
    return GeometryModel(config, {"normal": p_normal, "roughness": p_rough})


# --------------------------------------------------------------------------- inputs


def _horizontal_axes(yaw):
    """Unit vectors across (right) and along the view, horizontal, world frame, ``(..., 3)``."""
    c, s = jnp.cos(yaw), jnp.sin(yaw)
    z = jnp.zeros_like(c)
    return jnp.stack([s, -c, z], -1), jnp.stack([c, s, z], -1)


def camera_channels(camera):
    """Per-pixel camera inputs ``(H, W, 5)`` (view across / along / up, log footprint, mask)
    and the sea mask ``(H, W)`` bool."""
    hit = cam.intersect_sea(camera)
    across, along = _horizontal_axes(jnp.asarray(camera.yaw, hit.view.dtype))
    view = jnp.stack([hit.view @ across, hit.view @ along, hit.view[..., 2]], -1)
    chans = jnp.concatenate([view, jnp.log(hit.footprint)[..., None], hit.mask[..., None].astype(view.dtype)], -1)
    return chans, hit.mask


def features(image, camera, color: str = "rgb"):
    """Network input ``(H, W, C)`` for one linear image ``(H, W, 3)`` (or ``(H, W)`` gray)."""
    chans, mask = camera_channels(camera)
    image = jnp.asarray(image, jnp.float32)
    if color == "gray":
        if image.ndim == 3:
            image = image @ jnp.asarray(LUMINANCE, image.dtype)
        image = image[..., None]
    return jnp.concatenate([compress(image, sea_median(image, mask)), chans.astype(jnp.float32)], -1), mask


def _check_features(config: GeometryConfig, feats) -> None:
    if feats.ndim != 4 or feats.shape[-1] != config.in_channels:
        raise ValueError(f"model ({config.color}) takes features (B, H, W, {config.in_channels}); got {feats.shape}")


# --------------------------------------------------------------------------- outputs


def _local_normal(head: str, raw):
    if head == "vec":
        return safe_normalize(raw + jnp.asarray([0.0, 0.0, 1.0], raw.dtype))
    if head == "sphere":
        polar, azimuth = raw[..., 0], raw[..., 1]
        sp = jnp.sin(polar)
        return jnp.stack([sp * jnp.cos(azimuth), sp * jnp.sin(azimuth), jnp.cos(polar)], -1)
    return normal_from_slope(raw)


def _pad_to(x, multiple: int):
    H, W = x.shape[1:3]
    ph, pw = -H % multiple, -W % multiple
    if ph or pw:
        x = jnp.pad(x, ((0, 0), (0, ph), (0, pw), (0, 0)), mode="edge")
    return x


def apply(model: GeometryModel, feats, yaw, mask, *, key=None, train: bool = False) -> GeometryPrediction:
    """Geometry for a batch of features ``(B, H, W, C)`` with camera ``yaw (B,)`` and sea
    ``mask (B, H, W)``."""
    config = model.config
    _check_features(config, feats)
    H, W = feats.shape[1:3]
    normal_net, rough_net = _networks(config)
    x = _pad_to(feats, config.size_multiple)
    k1, k2 = (None, None) if key is None else jax.random.split(key)
    raw_n = normal_net.apply(model.params["normal"], x, key=k1, train=train)[:, :H, :W]
    raw_r = rough_net.apply(model.params["roughness"], x, key=k2, train=train)[:, :H, :W]
    across, along = _horizontal_axes(jnp.asarray(yaw, raw_n.dtype))
    across, along = across[:, None, None, :], along[:, None, None, :]
    local = _local_normal(config.normal_head, raw_n)
    up = jnp.asarray([0.0, 0.0, 1.0], raw_n.dtype)
    normal = local[..., :1] * across + local[..., 1:2] * along + local[..., 2:] * up
    log_sv = jnp.log(_SLOPE_FLOOR) + jax.nn.softplus(raw_r)  # (across, along), floor built in
    sv_across, sv_along = jnp.exp(log_sv[..., 0]), jnp.exp(log_sv[..., 1])
    cx2, cy2 = across[..., 0] ** 2, across[..., 1] ** 2  # world x / y components squared
    sv = jnp.stack([sv_across * cx2 + sv_along * (1 - cx2), sv_across * cy2 + sv_along * (1 - cy2)], -1)
    m = mask[..., None]
    normal = jnp.where(m, normal, up)
    sv = jnp.where(m, sv, _SLOPE_FLOOR)
    return GeometryPrediction(normal, sv, sv.sum(-1), mask)


def predict(model: GeometryModel, images, camera, *, batch_size: int = 8, devices=None) -> GeometryPrediction:
    """Geometry of linear images seen by ``camera``: a sequence ``(T, H, W, 3)`` (RGB) or
    ``(T, H, W)`` (gray), or one image ``(H, W, 3)`` / ``(H, W)``. The result has the same
    leading axes. A gray input to an RGB model is taken as equal R, G, B; an RGB input to a
    gray model as its luminance. A model whose parameters hold NaN or inf is refused
    (``InvalidValueError``). Each batch of ``batch_size`` frames is split over ``devices``
    (default: every local device: GPUs, or the CPU split by
    ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` or ``jax_num_cpu_devices``, which
    the ``predict-geometry`` and ``eval-geometry`` commands set to one device per core)."""
    if not isinstance(batch_size, int) or isinstance(batch_size, bool) or batch_size < 1:
        raise ValueError(f"batch_size must be a positive integer; got {batch_size!r}")
    images = np.asarray(images, np.float32)
    given = images.shape
    H, W = camera.resolution
    single = images.shape in ((H, W), (H, W, 3))
    if single:
        images = images[None]
    if images.ndim == 4 or images.shape[1:] != (H, W):
        if images.ndim != 4 or images.shape[1:] != (H, W, 3):
            raise ValueError(f"images must be (T, {H}, {W}, 3) or (T, {H}, {W}), or one image ({H}, {W}, 3) or "
                             f"({H}, {W}), for this camera (resolution {(H, W)}); got {given}")
    else:
        images = np.repeat(images[..., None], 3, -1)
    if images.shape[0] == 0:
        raise ValueError("images is an empty sequence (T = 0)")
    if not np.all(np.isfinite(images)):
        raise ValueError("images hold non-finite values")
    # a NaN parameter gives NaN maps (or, behind the sky mask, none at all): refused, as the
    # wave network refuses its non-finite outputs
    bad = nonfinite_arrays(model.params)
    if bad:
        raise InvalidValueError(f"the geometry model's parameters hold NaN or inf (array {bad[0]}, {len(bad)} in all; "
                                "a diverged training?)")
    # the frames of a batch split over the devices, the parameters replicated: XLA:CPU runs
    # one convolution on one core, so on this 2-core CPU a batch of 8 128² frames split over
    # two host devices runs 1.5x as many frames a second (experiments/NETS.md, Speed). The
    # maps are one device's to float32 rounding (each device's share is a smaller
    # convolution, which XLA may sum in another order: unit normals within 3e-7 measured;
    # bit for bit on the shipped model's batches of 8)
    placement = data_parallel(devices)
    params = placement.state(model.params)
    outs = []
    for i in range(0, len(images), batch_size):
        chunk = images[i:i + batch_size]
        # a batch padded with copies of its last frame to a multiple of the devices; each
        # frame's maps are computed alone, so the padding changes no value
        pad = -len(chunk) % placement.size
        chunk = np.concatenate([chunk, np.repeat(chunk[-1:], pad, 0)]) if pad else chunk
        out = _predict_jit(model.config, params, placement.batch(chunk), camera)
        outs.append(jax.tree.map(lambda x, n=len(chunk) - pad: x[:n], out))
    pred = GeometryPrediction(*[np.concatenate([np.asarray(getattr(o, f)) for o in outs])
                                for f in GeometryPrediction._fields])
    return GeometryPrediction(*[a[0] for a in pred]) if single else pred


@functools.partial(jax.jit, static_argnums=0)
def _predict_jit(config, params, images, camera):
    feats, mask = jax.vmap(lambda im: features(im, camera, config.color))(images)
    yaw = jnp.broadcast_to(jnp.asarray(camera.yaw, jnp.float32), images.shape[:1])
    return apply(GeometryModel(config, params), feats, yaw, mask)


# --------------------------------------------------------------------------- files


def save(path, model: GeometryModel, meta: dict | None = None) -> Path:
    """Write a model (params and config) to ``path`` (``.npz``), atomically."""
    return save_model(path, model.params, model.config, _FORMAT, meta)


def load(path=None) -> GeometryModel:
    """A model written by :func:`save`; ``None`` loads the shipped pretrained model (``cpu``),
    a name of :data:`PRETRAINED` (``"cpu"``, ``"gpu"``) that shipped model.

    Raises :class:`jaxocean.nn.checkpoint.CheckpointError` naming the file when it is
    missing, corrupt or not a geometry model of this version."""
    config, params = load_model(model_path(path, PRETRAINED, PRETRAINED_PATH), fmt=_FORMAT, what="a geometry model",
                                config_from_json=GeometryConfig.from_json,
                                init_params=lambda c: init(jax.random.key(0), c).params)
    return GeometryModel(config, params)


def model_info(path=None) -> dict:
    """The metadata stored with a model (config, training summary)."""
    return load_tree(model_path(path, PRETRAINED, PRETRAINED_PATH), None, meta_only=True)
