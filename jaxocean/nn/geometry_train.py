"""Training and evaluating geometry networks on a `jaxocean simulate` dataset.

Protocol
--------
* :class:`TrainConfig` -- everything a run depends on: the model architecture
  (:class:`~jaxocean.nn.geometry.GeometryConfig`), the losses, the schedule. :data:`CONFIGS`
  holds the named ones: ``"cpu"`` (trains in under an hour on two CPU cores: the default
  shipped model), ``"gpu"`` (a larger UNet on whole frames for one GPU: the shipped ``gpu``
  model) and ``"paper"`` (the paper's setting, for a GPU). :func:`variant` derives the
  ablation rows.
* Losses (``TrainConfig.losses``, "+"-joined terms):

  - ``image`` -- the paper's eq. 3 through the renderer: the predicted normal and slope
    variances are shaded (:func:`jaxocean.shading.shade_pixel`, the scene's known camera
    and lighting) and compared with the input image, both compressed as ``log1p(I / m)``
    (``m`` the input's sea median per channel) so that sun glints do not drown the rest;
  - ``gan`` -- eq. 4's four least-squares discriminators (spatial on normals and on
    log slope variances, temporal on consecutive frames of each), updated alternately with
    the networks;
  - ``supervised`` -- ``1 - cos`` to the true normal and the squared error of ``log10``
    slope variances (the synthetic data carry the truth).

* :func:`train(dataset, out, config)` runs :func:`jaxocean.nn.training.train_loop`, writes
  ``out/model.npz`` (best validation score) and returns the summary.
* :func:`evaluate(model_or_method, dataset, split)` scores a method on a split (see
  :mod:`jaxocean.nn.metrics`), overall and per scene, with frames per second.

Batches are random ``crop x crop`` windows of the frames (the networks are fully
convolutional and run on whole frames at inference); validation uses whole frames.
"""

from __future__ import annotations

import functools
import time
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxocean import camera as cam
from jaxocean import render, shading
from jaxocean._records import record_to_json
from jaxocean._sea_scale import compress, sea_median
from jaxocean.files import write_json
from jaxocean.io.dataset import Dataset
from jaxocean.nn import augment as aug
from jaxocean.nn import discriminators as disc
from jaxocean.nn import geometry as geo
from jaxocean.nn import metrics
from jaxocean.nn.training import check_split_holds_batch, data_parallel, epoch_steps, loss_terms, train_loop

__all__ = ["TrainConfig", "CONFIGS", "LOSS_TERMS", "variant", "train", "evaluate", "flat_method", "model_method",
           "augmented_method", "pixel_method"]

LOSS_TERMS = ("image", "gan", "supervised")
_DISC_DEPTH = 3


class TrainConfig(NamedTuple):
    name: str = "cpu"
    model: geo.GeometryConfig = geo.GeometryConfig()
    losses: str = "supervised"
    epochs: int = 25
    steps_per_epoch: int = 200
    batch_size: int = 8
    crop: int = 64
    learning_rate: float = 1e-3
    image_weight: float = 0.1  # alpha of eq. 4
    gan_weight: float = 0.02  # beta_1 = beta_2
    temporal_weight: float = 0.02  # gamma_1 = gamma_2
    roughness_weight: float = 0.1
    val_frames: int = 48
    patience: int = 6
    time_budget_minutes: float | None = 50.0
    seed: int = 0
    augment: aug.DisplayAugment | None = None  # display round trip of the input frames (None: off)

    def terms(self) -> tuple:
        return loss_terms(self.losses, LOSS_TERMS)

    def to_json(self) -> dict:
        d = self._asdict()
        d["model"] = self.model.to_json()
        d["augment"] = None if self.augment is None else record_to_json(self.augment)
        return d


CONFIGS = {
    # two CPU cores, under an hour: UNet sub-networks on 64^2 crops, inputs through the
    # display round trip that camera files take (8 bits, unknown exposure, display noise);
    # the augmented validation is noisier from epoch to epoch, hence the longer patience
    "cpu": TrainConfig(augment=aug.DisplayAugment(), patience=10),
    # one GPU: the cpu recipe with a 2.05 M-parameter UNet (normal 32-256, roughness 16-64) on
    # whole 128^2 frames, batches of 32, and a dataset of ~1,200 scenes (the shipped "gpu"
    # model: this config, 4,000 steps in 5.4 minutes on one H200)
    "gpu": TrainConfig(name="gpu", model=geo.GeometryConfig(widths=(32, 64, 128, 256), roughness_widths=(16, 32, 64)),
                       epochs=20, batch_size=32, crop=128, val_frames=96, patience=8, time_budget_minutes=None,
                       augment=aug.DisplayAugment()),
    # the paper: ResNet-VecN, image + GAN losses, 200 epochs of whole 128^2 frames (a GPU)
    "paper": TrainConfig(name="paper", model=geo.GeometryConfig(backbone="resnet", normal_head="vec",
                                                                 roughness_widths=(32,)),
                         losses="image+gan", image_weight=1.0, epochs=200, steps_per_epoch=1000, batch_size=16, crop=128,
                         learning_rate=2e-4, val_frames=400, patience=20, time_budget_minutes=None),
}


def variant(config: TrainConfig, *, losses=None, backbone=None, normal_head=None, **changes) -> TrainConfig:
    """``config`` with other losses / backbone / head (an ablation row)."""
    model = config.model
    if backbone is not None:
        model = model._replace(backbone=backbone)
    if normal_head is not None:
        model = model._replace(normal_head=normal_head)
    return config._replace(model=model.validate(), losses=config.losses if losses is None else losses, **changes)


# --------------------------------------------------------------------------- batches


class _Views(NamedTuple):
    feats: jax.Array  # (N, h, w, C)
    mask: jax.Array  # (N, h, w)
    view: jax.Array  # (N, h, w, 3) world frame, toward the camera
    yaw: jax.Array  # (N,)


def _scene_inputs(images, camera, color):
    """Features, mask and world view vectors of one scene's frames ``(S, H, W, 3)``."""
    feats, mask = jax.vmap(lambda im: geo.features(im, camera, color))(images)
    view = jnp.broadcast_to(cam.intersect_sea(camera).view, images.shape[:-1] + (3,)).astype(jnp.float32)
    return feats, mask, view


def _crop(key, arrays, crop, H, W):
    """The same random window of every array ``(S, H, W, ...)``: ``crop`` pixels along each
    axis, or the whole axis where it is shorter."""
    if crop >= H and crop >= W:
        return arrays
    ch, cw = min(crop, H), min(crop, W)
    ky, kx = jax.random.split(key)
    y0 = jax.random.randint(ky, (), 0, H - ch + 1)
    x0 = jax.random.randint(kx, (), 0, W - cw + 1)
    return [jax.lax.dynamic_slice_in_dim(jax.lax.dynamic_slice_in_dim(a, y0, ch, 1), x0, cw, 2) for a in arrays]


def _prepare(batch, key, color, crop, augment=None):
    """Device-side batch: features etc. of every frame, cropped; leading axes (B, S). With
    ``augment`` (a :class:`~jaxocean.nn.augment.DisplayAugment`) the features are made from
    each sample's display round trip; ``image`` stays the true radiance (the image loss
    compares with the renderer under the known lighting)."""
    images = batch["image"]
    B, S, H, W, _ = images.shape

    def one(k, im, normal, sv, camera, lighting):
        seen = im
        if augment is not None:
            k, k_aug = jax.random.split(k)
            seen = aug.augment(k_aug, im, augment)
        feats, mask, view = _scene_inputs(seen, camera, color)
        yaw = jnp.broadcast_to(jnp.asarray(camera.yaw, jnp.float32), (S,))
        feats, mask, view, im, normal, sv = _crop(k, [feats, mask, view, im, normal, sv], crop, H, W)
        return dict(feats=feats, mask=mask, view=view, yaw=yaw, image=im, normal=normal, sv=sv,
                    lighting=jax.tree.map(lambda x: jnp.broadcast_to(x, (S,) + jnp.shape(x)), lighting))

    return jax.vmap(one)(jax.random.split(key, B), images, batch["normal"], batch["slope_variance"],
                         batch["camera"], batch["lighting"])


def _flat(x):
    """(B, S, ...) -> (B S, ...)"""
    return jax.tree.map(lambda a: a.reshape((-1,) + a.shape[2:]), x)


def _sea_mean(x, mask):
    m = mask.astype(x.dtype)
    return jnp.sum(x * m) / jnp.maximum(jnp.sum(m), 1.0)


def _image_loss(pred: geo.GeometryPrediction, d):
    def shade_one(normal, sv, view, lighting):
        return shading.shade_pixel(normal, sv[..., 0], sv[..., 1], view, lighting)

    rendered = jax.vmap(shade_one)(pred.normal, pred.slope_variance, d["view"], d["lighting"])
    image = d["image"]
    scale = jax.vmap(sea_median)(image, d["mask"])[:, None, None, :]
    err = jnp.square(compress(rendered, scale) - compress(image, scale)).mean(-1)
    return _sea_mean(err, d["mask"])


def _supervised_losses(pred: geo.GeometryPrediction, d):
    cos_loss = _sea_mean(1.0 - jnp.sum(pred.normal * d["normal"], -1), d["mask"])
    floor = shading.MIN_SLOPE_VARIANCE_AXIS
    lp = jnp.log10(jnp.maximum(pred.slope_variance, floor))
    lt = jnp.log10(jnp.maximum(d["sv"], floor))
    return cos_loss, _sea_mean(jnp.square(lp - lt).mean(-1), d["mask"])


def _disc_inputs(normal, sv, mask):
    """Spatial inputs of D_n / D_r for frames ``(B, S, h, w, .)`` and temporal ones (pairs)."""
    floor = shading.MIN_SLOPE_VARIANCE_AXIS
    m = mask[..., None].astype(normal.dtype)
    n_map = normal * m
    r_map = (jnp.log10(jnp.maximum(sv, floor)) - jnp.log10(floor)) * m
    spatial = (_flat(n_map), _flat(r_map))
    temporal = (jnp.concatenate([n_map[:, :-1], n_map[:, 1:]], -1), jnp.concatenate([r_map[:, :-1], r_map[:, 1:]], -1))
    return spatial, tuple(_flat(t) for t in temporal)


def _disc_nets():
    return {name: disc.PatchDiscriminator() for name in ("normal", "roughness", "normal_t", "roughness_t")}


def _disc_logits(dparams, spatial, temporal):
    nets = _disc_nets()
    ins = dict(zip(("normal", "roughness"), spatial)) | dict(zip(("normal_t", "roughness_t"), temporal))
    return {k: nets[k].apply(dparams[k], ins[k]) for k in nets}


# --------------------------------------------------------------------------- training


def _optimizer(config: TrainConfig, total_steps: int):
    schedule = optax.cosine_decay_schedule(config.learning_rate, max(total_steps, 1), alpha=0.05)
    return optax.adam(schedule, b1=0.9, b2=0.999, eps=1e-8)


def init_state(config: TrainConfig, key):
    """The training state: network params, their Adam state and (with ``gan``) the four
    discriminators and theirs."""
    model = geo.init(key, config.model)
    total = config.epochs * config.steps_per_epoch
    state = {"g": model.params, "g_opt": _optimizer(config, total).init(model.params)}
    if "gan" in config.terms():
        crop = config.crop
        ch = {"normal": 3, "roughness": 2, "normal_t": 6, "roughness_t": 4}
        keys = jax.random.split(jax.random.fold_in(key, 1), 4)
        dparams = {k: net.init(kk, (-1, crop, crop, ch[k]))[1] for (k, net), kk in zip(_disc_nets().items(), keys)}
        state["d"] = dparams
        state["d_opt"] = optax.adam(config.learning_rate, b1=0.5, b2=0.999, eps=1e-8).init(dparams)
    return state


@functools.lru_cache(maxsize=8)
def make_step(config: TrainConfig, total_steps: int | None = None):
    """The jitted ``step(state, batch, key) -> (state, logs)`` of ``config`` (one compiled
    function per config); the learning rate decays over ``total_steps`` (default: every
    epoch's ``steps_per_epoch``)."""
    terms = config.terms()
    total = config.epochs * config.steps_per_epoch if total_steps is None else total_steps
    g_opt = _optimizer(config, total)
    d_opt = optax.adam(config.learning_rate, b1=0.5, b2=0.999, eps=1e-8)

    def g_loss(gparams, dparams, d, key):
        fd = _flat({k: v for k, v in d.items() if k != "lighting"})
        fd["lighting"] = _flat(d["lighting"])
        pred = geo.apply(geo.GeometryModel(config.model, gparams), fd["feats"], fd["yaw"], fd["mask"], key=key,
                         train=True)
        logs, loss = {}, 0.0
        if "supervised" in terms:
            cos_loss, rough = _supervised_losses(pred, fd)
            loss = loss + cos_loss + config.roughness_weight * rough
            logs |= {"cos": cos_loss, "logsv": rough}
        if "image" in terms:
            img = _image_loss(pred, fd)
            loss = loss + config.image_weight * img
            logs["image"] = img
        if "gan" in terms:
            B, S = d["mask"].shape[:2]
            normal = pred.normal.reshape((B, S) + pred.normal.shape[1:])
            sv = pred.slope_variance.reshape((B, S) + pred.slope_variance.shape[1:])
            spatial, temporal = _disc_inputs(normal, sv, d["mask"])
            logits = _disc_logits(dparams, spatial, temporal)
            w_s = disc.patch_weight(fd["mask"], _DISC_DEPTH)
            w_t = disc.patch_weight(_flat(d["mask"][:, 1:]), _DISC_DEPTH)
            gen = {k: disc.generator_loss(v, w_t if k.endswith("_t") else w_s) for k, v in logits.items()}
            loss = loss + config.gan_weight * (gen["normal"] + gen["roughness"]) \
                + config.temporal_weight * (gen["normal_t"] + gen["roughness_t"])
            logs["gan_g"] = sum(gen.values())
            logs["_fake"] = (jax.lax.stop_gradient(normal), jax.lax.stop_gradient(sv))
        logs["loss"] = loss
        return loss, logs

    def d_loss(dparams, fake, d):
        real_s, real_t = _disc_inputs(d["normal"], d["sv"], d["mask"])
        fake_s, fake_t = _disc_inputs(*fake, d["mask"])
        lr, lf = _disc_logits(dparams, real_s, real_t), _disc_logits(dparams, fake_s, fake_t)
        w_s = disc.patch_weight(_flat(d["mask"]), _DISC_DEPTH)
        w_t = disc.patch_weight(_flat(d["mask"][:, 1:]), _DISC_DEPTH)
        return sum(disc.discriminator_loss(lr[k], lf[k], w_t if k.endswith("_t") else w_s) for k in lr)

    @jax.jit
    def step(state, batch, key):
        k_prep, k_drop = jax.random.split(key)
        d = _prepare(batch, k_prep, config.model.color, config.crop, config.augment)
        (_, logs), grads = jax.value_and_grad(g_loss, has_aux=True)(state["g"], state.get("d"), d, k_drop)
        updates, g_state = g_opt.update(grads, state["g_opt"], state["g"])
        new = dict(state, g=optax.apply_updates(state["g"], updates), g_opt=g_state)
        if "gan" in terms:
            fake = logs.pop("_fake")
            dl, dgrads = jax.value_and_grad(d_loss)(state["d"], fake, d)
            dupd, d_state = d_opt.update(dgrads, state["d_opt"], state["d"])
            new |= {"d": optax.apply_updates(state["d"], dupd), "d_opt": d_state}
            logs["gan_d"] = dl
        return new, logs

    return step


def _batch_dict(b):
    return {"image": b.image, "normal": b.normal, "slope_variance": b.slope_variance, "camera": b.camera,
            "lighting": b.lighting}


def _require_complete(data: Dataset):
    n_train, n_val = len(data.splits.get("train", [])), len(data.splits.get("val", []))
    if n_train < 1 or n_val < 1:
        # split_scenes keeps a tenth for test and a tenth of the rest for validation
        raise ValueError(f"{data.root}: training needs scenes in the train and the validation split; it has "
                         f"{n_train} and {n_val} (simulate at least 7 scenes)")
    b = next(iter(data.batches(jax.random.key(0), "train", 1)))
    if b.slope_variance is None:
        raise ValueError(f"{data.root}: frames lack slope_variance channels (written by an older jaxocean); "
                         "regenerate the dataset with `jaxocean simulate`")


def train(dataset, out, config: TrainConfig | str = "cpu", *, progress: bool = True, parallel=None,
          stop_after_steps: int | None = None, **overrides) -> dict:
    """Train (or resume) a geometry model on ``dataset``; the best model goes to
    ``out/model.npz``. ``overrides`` replace :class:`TrainConfig` fields."""
    if isinstance(config, str):
        if config not in CONFIGS:
            raise ValueError(f"unknown config {config!r}; known: {sorted(CONFIGS)}")
        config = CONFIGS[config]
    config = config._replace(**overrides)
    terms = config.terms()
    if config.augment is not None:
        config.augment.validate()
    data = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    _require_complete(data)
    parallel = parallel or data_parallel()
    if config.batch_size % parallel.size:
        raise ValueError(f"batch size {config.batch_size} does not split over {parallel.size} devices")
    out = Path(out)
    key = jax.random.key(config.seed)
    state = init_state(config, key)
    sequence = 2 if "gan" in terms else 1  # the temporal discriminators see consecutive frames
    if data.n_frames < sequence:
        raise ValueError(f"the 'gan' loss needs at least 2 frames per scene (its temporal discriminators compare "
                         f"consecutive frames); {data.root} has {data.n_frames} (simulate with --frames 2 or more, "
                         f"or train without gan)")

    def batches(epoch):
        for b in data.batches(jax.random.fold_in(key, 1000 + epoch), "train", config.batch_size, sequence):
            yield _batch_dict(b)

    val_windows = data.windows("val")[: config.val_frames]
    if not val_windows or not data.windows("train"):
        raise ValueError(f"{data.root}: the dataset's train or validation split is empty "
                         f"({len(data.splits['train'])} / {len(data.splits['val'])} scenes); simulate at least 7 scenes")
    n_windows = len(data.windows("train", sequence))
    check_split_holds_batch(data.root, "train", n_windows, "frames" if sequence == 1 else f"runs of {sequence} frames",
                            config.batch_size)
    steps_per_epoch = epoch_steps(config.steps_per_epoch, n_windows, config.batch_size)
    step = make_step(config, config.epochs * steps_per_epoch)

    def validate(state):
        model = geo.GeometryModel(config.model, state["g"])
        method = model_method(model) if config.augment is None else \
            augmented_method(model, config.augment, jax.random.fold_in(key, 3))
        scores = _score_frames(method, data, val_windows)
        loss = scores["cos_loss"] if "supervised" in terms else scores["image_loss"]
        return {"loss": loss, **{k: scores[k] for k in ("cos_loss", "image_loss", "skill_along", "skill_across",
                                                        "within_5deg", "log_slope_variance_mse")}}

    def on_best(state, scores, pos):
        geo.save(out / "model.npz", geo.GeometryModel(config.model, jax.device_get(state["g"])),
                 {"train_config": config.to_json(), "val": scores, "epoch": pos["epoch"], "steps": pos["step"],
                  "train_s": pos["train_s"], "dataset": str(data.root)})

    signature = {"config": config.to_json(), "dataset": data.settings, "devices": parallel.size}
    budget = None if config.time_budget_minutes is None else 60.0 * config.time_budget_minutes
    t0 = time.perf_counter()
    result = train_loop(out, state=state, step=step, batches=batches, validate=validate, epochs=config.epochs,
                        steps_per_epoch=steps_per_epoch, key=jax.random.fold_in(key, 2), signature=signature,
                        patience=config.patience, time_budget_s=budget, on_best=on_best, parallel=parallel,
                        progress=progress, stop_after_steps=stop_after_steps, network="geometry")
    summary = {"config": config.to_json(), "stopped": result["stopped"], "steps": result["steps"],
               "best_val_loss": result["best"], "wall_s_this_call": time.perf_counter() - t0,
               "train_s": result["history"][-1]["wall_s"] if result["history"] else None,
               "model": str(out / "model.npz") if (out / "model.npz").exists() else None}
    if result["stopped"] != "step_limit":
        write_json(out / "summary.json", summary)
    summary["state"] = result["state"]
    return summary


# --------------------------------------------------------------------------- evaluation


def model_method(model: geo.GeometryModel):
    """A scoring method ``(images (T, H, W, 3), scene) -> GeometryPrediction`` from a model
    (it uses the scene's camera only)."""
    return lambda images, scene: geo.predict(model, images, scene.camera)


def augmented_method(model: geo.GeometryModel, config: aug.DisplayAugment, key):
    """A scoring method that shows the model each scene's frames through a display round
    trip drawn from ``config`` (:func:`jaxocean.nn.augment.augment`) with the key
    ``fold_in(key, scene.seed)``: the same frames every call (the validation of an
    augmented run)."""
    def method(images, scene):
        k = jax.random.fold_in(key, 0 if scene.seed is None else int(scene.seed))
        return geo.predict(model, np.asarray(_augment_jit(k, jnp.asarray(images), config)), scene.camera)

    return method


@functools.partial(jax.jit, static_argnums=2)
def _augment_jit(key, images, config):
    return aug.augment(key, images, config)


def pixel_method(images, scene):
    """The per-pixel least-squares inversion of the shading with the scene's known camera
    and lighting (:func:`jaxocean.fit.pixels.invert`), frame by frame."""
    from jaxocean.fit import pixels

    fits = [pixels.invert(im, scene.camera, scene.lighting) for im in images]
    return geo.GeometryPrediction(*[np.stack([np.asarray(getattr(f, name)) for f in fits])
                                    for name in ("normal", "slope_variance")],
                                  np.stack([np.asarray(f.slope_variance).sum(-1) for f in fits]),
                                  np.stack([np.asarray(f.mask) for f in fits]))


def flat_method(images, scene):
    """The flat-sea baseline: normal (0, 0, 1) and the roughness floor everywhere."""
    T = images.shape[0]
    _, mask = geo.camera_channels(scene.camera)
    mask = np.broadcast_to(np.asarray(mask), (T,) + mask.shape)
    normal = np.zeros(images.shape, np.float32)
    normal[..., 2] = 1
    sv = np.full(images.shape[:-1] + (2,), shading.MIN_SLOPE_VARIANCE_AXIS, np.float32)
    return geo.GeometryPrediction(normal, sv, sv.sum(-1), mask)


@jax.jit
def _frame_scores(pred_normal, pred_sv, true_normal, true_sv, image, camera, lighting):
    hit = cam.intersect_sea(camera)
    mask = hit.mask[None]
    yaw = jnp.broadcast_to(jnp.asarray(camera.yaw, jnp.float32), pred_normal.shape[:1])
    sums = metrics.normal_scores(pred_normal, true_normal, mask, yaw)
    sums |= metrics.roughness_scores(pred_sv, true_sv, mask, shading.MIN_SLOPE_VARIANCE_AXIS)
    rendered = jax.vmap(lambda n, s: render.shade(n, None, camera, lighting, slope_variance=s))(pred_normal, pred_sv)
    sums |= metrics.image_scores(shading.tonemap(rendered), shading.tonemap(image), mask)
    d = {"image": image, "view": jnp.broadcast_to(hit.view, image.shape), "mask": jnp.broadcast_to(mask, image.shape[:-1]),
         "lighting": jax.tree.map(lambda x: jnp.broadcast_to(x, (image.shape[0],) + jnp.shape(x)), lighting)}
    pred = geo.GeometryPrediction(pred_normal, pred_sv, pred_sv.sum(-1), d["mask"])
    sums["image_loss_sum"] = _image_loss(pred, d) * jnp.sum(d["mask"])
    return sums


def _frames_by_scene(windows) -> dict:
    """``{scene: [frame, ...]}`` of ``(scene, frame)`` windows, in their order."""
    by_scene: dict = {}
    for s, f in windows:
        by_scene.setdefault(s, []).append(f)
    return by_scene


def _score_frames(method, data: Dataset, windows, per_scene: bool = False, timing: dict | None = None):
    by_scene = _frames_by_scene(windows)
    total: dict = {}
    scenes = {}
    for s, frames in by_scene.items():
        sc = data.scene(s)
        fr = [data.frame(s, f) for f in frames]
        if any(x.slope_variance is None for x in fr):  # the scores compare against it
            raise ValueError(f"{data.root}: scene {s}'s frames lack slope_variance channels (written by an older "
                             "jaxocean); regenerate the dataset with `jaxocean simulate`")
        images = np.stack([x.image for x in fr])
        t0 = time.perf_counter()
        pred = method(images, sc)
        jax.block_until_ready(pred.normal)
        if timing is not None:
            timing["s"] = timing.get("s", 0.0) + time.perf_counter() - t0
            timing["frames"] = timing.get("frames", 0) + len(frames)
        sums = _frame_scores(jnp.asarray(pred.normal), jnp.asarray(pred.slope_variance),
                             jnp.asarray(np.stack([x.normal for x in fr])),
                             jnp.asarray(np.stack([x.slope_variance for x in fr])), jnp.asarray(images),
                             sc.camera, sc.lighting)
        sums = {k: float(v) for k, v in sums.items()}
        if per_scene:
            scenes[s] = _finish(sums)
        total = metrics.merge(total, sums)
    out = _finish(total)
    if per_scene:
        out["scenes"] = scenes
    return out


def _finish(sums):
    out = metrics.finish(sums)
    out["image_loss"] = sums["image_loss_sum"] / sums["pixels"] if sums["pixels"] > 0 else float("nan")  # as finish
    return out


def evaluate(method, dataset, split: str = "test", *, max_frames: int | None = None,
             frames_per_scene: int | None = None, warmup: bool = True) -> dict:
    """Scores of ``method`` (a :class:`~jaxocean.nn.geometry.GeometryModel`, or a function
    ``(images (T, H, W, 3), scene) -> GeometryPrediction`` of a scene's frames) on ``split``, overall and per scene, with
    ``frames_per_s`` of the method alone (after one warm-up call that compiles it).
    ``frames_per_scene`` scores only each scene's first frames; ``max_frames`` caps the total."""
    data = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    if isinstance(method, geo.GeometryModel):
        method = model_method(method)
    windows = [(s, f) for s, f in data.windows(split) if frames_per_scene is None or f < frames_per_scene]
    windows = windows[:max_frames]
    if not windows:
        sizes = ", ".join(f"{name} {len(scenes)}" for name, scenes in data.splits.items())
        raise ValueError(f"{data.root}: the {split!r} split holds no frame to score (scenes per split: {sizes}); "
                         "choose another split (--split), or simulate more scenes (the test split holds 10% of them)")
    if warmup:  # compile for every frame count a scene is scored with (max_frames can cut the last one short)
        by_scene = _frames_by_scene(windows)
        for s in {len(frames): s for s, frames in reversed(by_scene.items())}.values():
            images = np.stack([data.frame(s, f).image for f in by_scene[s]])
            jax.block_until_ready(method(images, data.scene(s)).normal)
    timing: dict = {}
    out = _score_frames(method, data, windows, per_scene=True, timing=timing)
    out["frames_per_s"] = timing["frames"] / max(timing["s"], 1e-9)
    out["frames"] = timing["frames"]
    return out
