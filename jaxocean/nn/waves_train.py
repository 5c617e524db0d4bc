"""Training the wave-estimation network (:mod:`jaxocean.nn.waves`) on a `jaxocean simulate` dataset.

Protocol
--------
* :class:`TrainConfig` -- the model architecture (:class:`~jaxocean.nn.waves.WaveNetConfig`),
  the losses and the schedule. :data:`CONFIGS` holds ``"cpu"`` (32 x 32 frames, 6 frames,
  32 slots anchored on the periodogram's peaks, geometry + supervised losses, 6,000 steps
  within a 40-minute budget on two CPU cores) and ``"paper"`` (the paper's setting: 128 x
  128, 10 frames, 60 free slots, for a GPU).
* Losses (``TrainConfig.losses``, "+"-joined terms):

  - ``geometry`` -- the paper's eq. 5-7 through the library's differentiable geometry:
    the predicted waves are rendered by :func:`jaxocean.render.geometry` (its rows path with
    every slot evaluated, a static ``RenderPlan``) at the input's frame times and compared
    with the input, ``L = L_cos + alpha L_2`` (:func:`jaxocean.fit.waves.loss`:
    ``L_cos = mean (1 - n . n_hat)``, ``L_2`` the mean squared roughness difference, over
    valid sea pixel-frames), divided per scene by the same loss of the flat sea, so that
    calm and rough scenes weigh alike (1 = nothing explained, 0 = everything). It compares
    geometry, not parameter lists, so it does not depend on the order of the slots. Plus
    ``presence_weight`` x the summed presence of a scene's slots (the number of slots on):
    a slot must explain more than that fraction of the scene to stay on (the model uses no
    more waves than the scene needs).
  - ``supervised`` -- for the ablation: a symmetric Chamfer distance in wave-vector space
    between the slots and the scene's true waves that the camera resolves
    (:func:`jaxocean.fit.waves.resolvable`), relative distances ``|k - k_true| / |k_true|``,
    true waves weighted by their slope energy ``(k h)^2``, slots by their presence;
    permutation-free as well.

* :func:`train(dataset, out, config)` runs :func:`jaxocean.nn.training.train_loop`
  (progress, resumable checkpoints, history and curves, early stopping, time budget, data
  parallel), writes ``out/model.npz`` (best validation loss) and returns the summary.
* :func:`evaluate_loss(model, dataset, split)` -- the mean normalised geometry loss and mean
  number of waves (presence > 0.5) of a split.

Every batch item is a scene's first ``frames`` frames (one window per scene); an anchored
model's anchors (:func:`jaxocean.nn.waves.slot_anchors`) are computed once per scene, when it
is first loaded.
"""

from __future__ import annotations

import functools
from pathlib import Path
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax

from jaxocean.files import write_json
from jaxocean.io.dataset import Dataset
from jaxocean.nn import waves as wn
from jaxocean.nn.training import check_split_holds_batch, data_parallel, epoch_steps, loss_terms, train_loop
from jaxocean.waves import GRAVITY, Waves

__all__ = ["TrainConfig", "CONFIGS", "LOSS_TERMS", "geometry_loss", "supervised_loss", "make_step", "init_state",
           "train", "evaluate_loss"]

LOSS_TERMS = ("geometry", "supervised")


class TrainConfig(NamedTuple):
    name: str = "cpu"
    model: wn.WaveNetConfig = wn.WaveNetConfig(slots=32, anchors=True)
    losses: str = "geometry+supervised"
    epochs: int = 60
    steps_per_epoch: int = 100
    batch_size: int = 8
    learning_rate: float = 1e-3
    roughness_weight: float = 1.0  # alpha of eq. 7 (beta = 1)
    presence_weight: float = 1e-3
    supervised_weight: float = 1.0
    patience: int = 15
    time_budget_minutes: float | None = 40.0
    seed: int = 0

    def terms(self) -> tuple:
        return loss_terms(self.losses, LOSS_TERMS)

    def to_json(self) -> dict:
        d = self._asdict()
        d["model"] = self.model.to_json()
        return d


CONFIGS = {
    # two CPU cores: 32^2 frames, 6 frames, 32 slots anchored on the periodogram's peaks; the
    # cosine decay spans the steps that fit the 40-minute budget (0.25 s a step here), so it
    # ends decayed
    "cpu": TrainConfig(),
    # the paper: 60 waves from 10 frames of 128^2 geometry, 100 epochs (a GPU)
    "paper": TrainConfig(name="paper", model=wn.WaveNetConfig(frames=10, slots=60, widths=(32, 64, 128, 256),
                                                              hidden=512),
                         epochs=100, steps_per_epoch=1000, batch_size=16, learning_rate=3e-4, patience=20,
                         time_budget_minutes=None),
}


# --------------------------------------------------------------------------- losses


def _flat_waves(dtype=jnp.float32):
    return Waves(*(jnp.asarray([v], dtype) for v in (0.0, 1.0, 0.0, 0.0)))


def geometry_loss(waves_: Waves, normals, roughness, camera, times, roughness_weight: float = 1.0):
    """Eq. 5-7 of one scene, divided by the same loss of the flat sea (traceable)."""
    from jaxocean.fit.waves import loss

    full = loss(waves_, normals, roughness, camera, times, roughness_weight=roughness_weight)
    flat = loss(_flat_waves(normals.dtype), normals, roughness, camera, times, roughness_weight=roughness_weight)
    return full / jnp.maximum(jax.lax.stop_gradient(flat), 1e-12)


def _kvec(omega, theta):
    k = omega * omega / GRAVITY
    return jnp.stack([k * jnp.cos(theta), k * jnp.sin(theta)], -1), k


def supervised_loss(slots: wn.WaveSlots, truth: Waves, true_weight):
    """Symmetric Chamfer distance (relative wave-vector distance) of one scene's slots to
    its true waves; ``true_weight (M,)`` >= 0 (zero: a wave to ignore)."""
    kp, _ = _kvec(slots.waves.omega, slots.waves.theta)
    kt, k_true = _kvec(truth.omega, truth.theta)
    d = jnp.sqrt(jnp.sum(jnp.square(kp[None] - kt[:, None]), -1) + 1e-12) / k_true[:, None]  # (M, N)
    e = true_weight * jnp.square(k_true * truth.amplitude)
    to_slot = jnp.sum(e * jnp.min(d, 1)) / jnp.maximum(jnp.sum(e), 1e-30)
    big = jnp.where(true_weight[:, None] > 0, d, 1e3)
    p = slots.presence
    to_true = jnp.sum(p * jnp.minimum(jnp.min(big, 0), 10.0)) / jnp.maximum(jnp.sum(p), 1e-6)
    return to_slot + to_true


# --------------------------------------------------------------------------- training


def _optimizer(config: TrainConfig, total_steps: int):
    schedule = optax.cosine_decay_schedule(config.learning_rate, max(total_steps, 1), alpha=0.05)
    return optax.chain(optax.clip_by_global_norm(1.0), optax.adam(schedule))


def init_state(config: TrainConfig, key):
    model = wn.init(key, config.model)
    total = config.epochs * config.steps_per_epoch
    return {"params": model.params, "opt": _optimizer(config, total).init(model.params)}


def _losses(config: TrainConfig, params, batch, key, train: bool):
    terms = config.terms()
    model = wn.WaveNetModel(config.model, params)
    slots = wn.apply(model, batch["normal"], batch["roughness"], batch["camera"], batch["times"],
                     anchors=batch.get("anchors"), key=key, train=train)
    geo = jax.vmap(lambda w, n, r, c, t: geometry_loss(w, n, r, c, t, config.roughness_weight))(
        slots.waves, batch["normal"], batch["roughness"], batch["camera"], batch["times"])
    presence = jnp.mean(slots.presence)
    logs = {"geometry": jnp.mean(geo), "presence": presence, "waves": jnp.mean(jnp.sum(slots.presence > 0.5, -1))}
    loss = config.presence_weight * presence * config.model.slots
    if "geometry" in terms:
        loss = loss + logs["geometry"]
    if "supervised" in terms:
        sup = jax.vmap(supervised_loss)(slots, batch["waves"], batch["resolvable"])
        logs["supervised"] = jnp.mean(sup)
        loss = loss + config.supervised_weight * logs["supervised"]
    logs["loss"] = loss
    return loss, logs


@functools.lru_cache(maxsize=8)
def make_step(config: TrainConfig, total_steps: int | None = None):
    """The jitted ``step(state, batch, key) -> (state, logs)`` of ``config``; the learning
    rate decays over ``total_steps`` (default: every epoch's ``steps_per_epoch``)."""
    opt = _optimizer(config, config.epochs * config.steps_per_epoch if total_steps is None else total_steps)

    @jax.jit
    def step(state, batch, key):
        (_, logs), grads = jax.value_and_grad(lambda p: _losses(config, p, batch, key, True), has_aux=True)(
            state["params"])
        updates, opt_state = opt.update(grads, state["opt"], state["params"])
        return {"params": optax.apply_updates(state["params"], updates), "opt": opt_state}, logs

    return step


@functools.lru_cache(maxsize=8)
def _eval_fn(config: TrainConfig):
    return jax.jit(lambda params, batch: _losses(config, params, batch, None, False)[1])


class _Scenes:
    """Per-scene arrays of a dataset split: the first ``frames`` frames' normals and
    roughness, times, camera, true waves and their resolvable flags (cached)."""

    def __init__(self, data: Dataset, model: wn.WaveNetConfig):
        frames = model.frames
        if data.n_frames < frames:
            raise ValueError(f"{data.root}: scenes have {data.n_frames} frames; the network takes {frames}")
        self.data, self.frames, self.model = data, frames, model
        self._cache: dict = {}

    def item(self, s: int) -> dict:
        if s not in self._cache:
            from jaxocean.fit.waves import resolvable

            sc = self.data.scene(s)
            fr = [self.data.frame(s, f) for f in range(self.frames)]
            self._cache[s] = {"normal": np.stack([x.normal for x in fr]).astype(np.float32),
                              "roughness": np.stack([x.roughness for x in fr]).astype(np.float32),
                              "times": np.asarray(sc.times, np.float32)[:self.frames],
                              "camera": sc.camera,
                              "waves": Waves(*[np.asarray(x, np.float32) for x in sc.waves]),
                              "resolvable": resolvable(sc.waves, sc.camera).astype(np.float32)}
            if self.model.anchors:  # a function of the input: once per scene, not once per step
                item = self._cache[s]
                item["anchors"] = jax.device_get(_anchors_jit(self.model, item["normal"], sc.camera, item["times"]))
        return self._cache[s]

    def batch(self, scenes) -> dict:
        items = [self.item(s) for s in scenes]
        return jax.tree.map(lambda *a: np.stack([np.asarray(x) for x in a]), *items)


@functools.partial(jax.jit, static_argnums=0)
def _anchors_jit(model: wn.WaveNetConfig, normals, camera, times):
    return wn.slot_anchors(model, normals, camera, times)


def _resolve(config) -> TrainConfig:
    if isinstance(config, str):
        if config not in CONFIGS:
            raise ValueError(f"unknown config {config!r}; known: {sorted(CONFIGS)}")
        config = CONFIGS[config]
    return config


def evaluate_loss(model: wn.WaveNetModel, dataset, split: str = "val", *, config: TrainConfig | None = None,
                  batch_size: int = 8, scenes=None) -> dict:
    """Mean normalised geometry loss and waves per scene of ``model`` on a split."""
    data = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    config = (config or CONFIGS["cpu"])._replace(model=model.config)
    if scenes is None:
        scenes = data.scenes_of(split)
    if not len(scenes):
        raise ValueError(f"{data.root}: no scene to evaluate (scenes per split: "
                         f"{', '.join(f'{k} {len(v)}' for k, v in data.splits.items())})")
    return _mean_logs(config, model.params, _Scenes(data, model.config), scenes, batch_size)


def _mean_logs(config, params, scenes: _Scenes, indices, batch_size):
    fn = _eval_fn(config)
    sums, n = {}, 0
    for i in range(0, len(indices), batch_size):
        chunk = list(indices[i:i + batch_size])
        logs = fn(params, scenes.batch(chunk))
        for k, v in logs.items():
            sums[k] = sums.get(k, 0.0) + float(v) * len(chunk)
        n += len(chunk)
    return {k: v / max(n, 1) for k, v in sums.items()}


def train(dataset, out, config: TrainConfig | str = "cpu", *, progress: bool = True, parallel=None,
          stop_after_steps: int | None = None, **overrides) -> dict:
    """Train (or resume) a wave network on ``dataset``; the best model goes to
    ``out/model.npz``. ``overrides`` replace :class:`TrainConfig` fields."""
    config = _resolve(config)._replace(**overrides)
    config.terms()
    config.model.validate()
    data = dataset if isinstance(dataset, Dataset) else Dataset(dataset)
    if any(r % config.model.size_multiple for r in data.resolution):
        raise ValueError(f"{data.root}: resolution {data.resolution} is not a multiple of "
                         f"{config.model.size_multiple} (the network's UNet)")
    scenes = _Scenes(data, config.model)
    train_ids, val_ids = list(data.splits["train"]), list(data.splits["val"])
    check_split_holds_batch(data.root, "train", len(train_ids), "scenes", config.batch_size)
    if not val_ids:
        raise ValueError(f"{data.root}: the validation split holds no scene; simulate at least 7 scenes")
    parallel = parallel or data_parallel()
    if config.batch_size % parallel.size:
        raise ValueError(f"batch size {config.batch_size} does not split over {parallel.size} devices")
    out = Path(out)
    key = jax.random.key(config.seed)
    state = init_state(config, key)
    steps_per_epoch = epoch_steps(config.steps_per_epoch, len(train_ids), config.batch_size)
    step = make_step(config, config.epochs * steps_per_epoch)

    def batches(epoch):
        order = np.asarray(jax.random.permutation(jax.random.fold_in(key, 1000 + epoch), len(train_ids)))
        for i in range(0, len(order) - config.batch_size + 1, config.batch_size):
            yield scenes.batch([train_ids[j] for j in order[i:i + config.batch_size]])

    def validate(state):
        logs = _mean_logs(config, state["params"], scenes, val_ids, config.batch_size)
        return {"loss": logs["loss"], "geometry": logs["geometry"], "waves": logs["waves"]}

    best_meta: dict = {}

    def on_best(state, scores, pos):
        best_meta.update(val=scores, steps=pos["step"], wall_s=pos["train_s"])  # over every call of a resumed run
        wn.save(out / "model.npz", wn.WaveNetModel(config.model, jax.device_get(state["params"])),
                {"train_config": config.to_json(), "dataset": str(data.root), "best": best_meta})

    result = train_loop(out, state=state, step=step, batches=batches, validate=validate, epochs=config.epochs,
                        # the step keys are a stream of their own: fold_in(key, s) would give step
                        # 1000 + e epoch e's shuffle key as its dropout key
                        steps_per_epoch=steps_per_epoch, key=jax.random.fold_in(key, 2),
                        # as train-geometry: the sharded step's rounding depends on the device count, so a
                        # resume on another count would not end where the uninterrupted run ends
                        signature={"config": config.to_json(), "dataset": data.settings, "devices": parallel.size},
                        patience=config.patience,
                        time_budget_s=None if config.time_budget_minutes is None else 60 * config.time_budget_minutes,
                        on_best=on_best, parallel=parallel, progress=progress, stop_after_steps=stop_after_steps,
                        network="waves")
    hist = result["history"]
    summary = {"config": config.to_json(), "dataset": str(data.root), "stopped": result["stopped"],
               "steps": result["steps"], "best_val_loss": result["best"],
               "model": str(out / "model.npz") if (out / "model.npz").exists() else None,
               "train_s": hist[-1]["wall_s"] if hist else 0.0, "epochs": len(hist)}
    if result["stopped"] != "step_limit":
        write_json(out / "summary.json", summary)
    summary["state"] = result["state"]
    return summary
