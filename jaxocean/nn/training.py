"""Training machinery shared by the networks: the epoch loop, resumable checkpoints,
validation with early stopping, loss curves, and data parallelism over local devices.

Protocol
--------
:func:`train_loop` drives a pure, jitted ``step(state, batch, key) -> (state, logs)``:

* ``state`` is a pytree (params, optimiser states, ...); ``logs`` a dict of scalars.
* ``batches(epoch)`` yields the epoch's batches (pytrees of arrays with the batch axis
  first) in a deterministic order; the loop takes at most ``steps_per_epoch`` of them.
* ``validate(state) -> dict`` with at least ``"loss"`` (lower is better) runs after every
  epoch; the best state so far is handed to ``on_best(state, scores)`` (the caller writes
  its model file there).
* The step key is ``fold_in(key, step)``: it depends on the step count alone, so nothing
  random needs saving.

Resuming. ``run_dir/checkpoint.npz`` holds ``state`` and the loop's position (epoch, batch,
step, history, best score, epochs without improvement), written atomically every
``checkpoint_every`` steps and at every epoch's end. Calling :func:`train_loop` again with
the same arguments continues from it -- the batches already consumed in the current epoch
are skipped -- so a killed run, rerun, ends where an uninterrupted run ends (tested
bit-for-bit on the CPU). A checkpoint written with other settings (``signature``) is an
error, not silently mixed; one written for another network (``network``, e.g. a wave
network's run given to the geometry network's training) is refused as such in one line.

Data parallel. With more than one local device (GPUs, or CPU devices made with
``XLA_FLAGS=--xla_force_host_platform_device_count=N``) :func:`data_parallel` puts the
state on every device and splits each batch along its first axis (``jax.sharding``:
a 1-D mesh ``"data"``); the jitted step then computes the same mean gradient as on one
device, XLA inserting the all-reduce. On several hosts call ``jax.distributed.initialize()``
first (one process per host, same command) and every process feeds its share of the batch:
see docs/training.md.

Outputs in ``run_dir``: ``checkpoint.npz``, ``history.json`` (per-epoch train and
validation scores, wall time), ``curves.png``.
"""

from __future__ import annotations

import contextlib
import json
import math
import signal
import threading
import time
from pathlib import Path
from typing import Callable

import jax
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxocean.errors import is_integer
from jaxocean.files import write_json
from jaxocean.nn.checkpoint import CheckpointError, load_tree, save_tree

__all__ = ["data_parallel", "train_loop", "loss_terms", "epoch_steps", "CHECKPOINT", "HISTORY", "CURVES"]

CHECKPOINT = "checkpoint.npz"
HISTORY = "history.json"
CURVES = "curves.png"


class DataParallel:
    """Placement of the state (replicated) and batches (split along axis 0) on local devices."""

    def __init__(self, devices=None):
        self.devices = jax.local_devices() if devices is None else list(devices)
        if not self.devices:
            raise ValueError("devices is empty: a placement needs at least one device")
        self.mesh = Mesh(np.asarray(self.devices), ("data",))
        self.replicated = NamedSharding(self.mesh, PartitionSpec())
        self.split = NamedSharding(self.mesh, PartitionSpec("data"))

    @property
    def size(self) -> int:
        return len(self.devices)

    def state(self, tree):
        return jax.device_put(tree, self.replicated)

    def batch(self, tree):
        def put(x):
            x = np.asarray(x) if not isinstance(x, jax.Array) else x
            if x.ndim == 0 or x.shape[0] % self.size:
                raise ValueError(f"batch axis {x.shape[:1]} does not split over {self.size} devices; "
                                 f"use a batch size divisible by {self.size}")
            return jax.device_put(x, self.split)

        return jax.tree.map(put, tree)


def data_parallel(devices=None) -> DataParallel:
    """The placement over ``devices`` (default: every local device; an empty list is an error)."""
    return DataParallel(devices)


def _plot_curves(path: Path, history: list) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxocean.plots import save_figure

    keys = sorted({k for h in history for k in h.get("train", {})})
    val_keys = sorted({k for h in history for k in h.get("val", {}) if k != "loss"})
    # the geometry networks' panel shows their slope skills; another network its other scores
    panel_keys = [k for k in val_keys if k.startswith("skill")] or val_keys
    fig, axes = plt.subplots(1, 2, figsize=(10, 3.6))
    ep = [h["epoch"] + 1 for h in history]
    for k in keys:
        axes[0].plot(ep, [h["train"].get(k, np.nan) for h in history], label=f"train {k}")
    if history and "val" in history[0]:
        axes[0].plot(ep, [h["val"].get("loss", np.nan) for h in history], "k--", label="val loss")
    axes[0].set_yscale("log")
    axes[0].set_xlabel("epoch")
    axes[0].legend(fontsize=7)
    for k in panel_keys:
        axes[1].plot(ep, [h["val"].get(k, np.nan) for h in history], label=f"val {k}")
    axes[1].set_xlabel("epoch")
    is_skill = any(k.startswith("skill") for k in panel_keys)
    axes[1].set_ylabel("slope skill" if is_skill else "validation scores")
    if panel_keys and not is_skill:
        axes[1].set_yscale("log")
    if panel_keys:
        axes[1].legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path, dpi=90)


def loss_terms(spec: str, allowed: tuple) -> tuple:
    """The terms of a ``"+"``-joined loss specification (``"image+gan"``), each one of
    ``allowed``; ``ValueError`` otherwise."""
    terms = tuple(spec.split("+"))
    bad = [t for t in terms if t not in allowed]
    if bad or not terms:
        raise ValueError(f"losses must be '+'-joined terms of {allowed}; got {spec!r}")
    return terms


def train_loop(run_dir, *, state, step: Callable, batches: Callable, validate: Callable, epochs: int,
               steps_per_epoch: int, key, signature: dict, checkpoint_every: int = 200, patience: int = 5,
               time_budget_s: float | None = None, on_best: Callable | None = None, parallel: DataParallel | None = None,
               progress: bool = True, stop_after_steps: int | None = None, network: str | None = None) -> dict:
    """Run (or resume) training; returns ``{"state", "history", "best", "stopped", "steps"}``.

    ``stopped`` says why it ended: ``"epochs"``, ``"early_stopping"``, ``"time_budget"`` (read
    after every step: the epoch it cuts short is validated and saved first), or
    ``"step_limit"`` (``stop_after_steps``: end the process after that many steps of this
    call, as a crash would -- used to test resuming). Ctrl-C saves the checkpoint after the
    step in progress and raises ``KeyboardInterrupt``. Counts below 1 are a ``ValueError``.
    ``network`` names what is trained (``"geometry"``, ``"waves"``), kept in the checkpoint:
    a run directory of another network is a :class:`CheckpointError` that says so, not a
    list of every setting that differs (a checkpoint without one is compared by its settings
    alone).
    """
    for name, value in (("epochs", epochs), ("steps_per_epoch", steps_per_epoch), ("patience", patience),
                        ("checkpoint_every", checkpoint_every)):
        if not is_integer(value, 1):
            raise ValueError(f"{name} must be a positive integer; got {value!r}")
    if time_budget_s is not None and not (isinstance(time_budget_s, (int, float)) and time_budget_s > 0):
        raise ValueError(f"the time budget must be a positive number of seconds or None; got {time_budget_s!r}")
    run_dir = Path(run_dir)
    run_dir.mkdir(parents=True, exist_ok=True)
    ckpt = run_dir / CHECKPOINT
    signature = json.loads(json.dumps(signature))
    pos = {"epoch": 0, "batch": 0, "step": 0, "history": [], "best": math.inf, "bad_epochs": 0, "train_s": 0.0,
           "epoch_logs": {}}
    if ckpt.exists():
        meta = load_tree(ckpt, None, meta_only=True)
        if network is not None and meta.get("network") not in (None, network):
            raise CheckpointError(ckpt, f"belongs to the training of a {meta['network']} network, not of a "
                                  f"{network} network; use a new --out directory")
        if meta.get("signature") != signature:
            changed = _differences(meta.get("signature"), signature)
            raise CheckpointError(ckpt, f"was written by a run with other settings ({'; '.join(changed[:4])}"
                                  f"{'; ...' if len(changed) > 4 else ''}); use a new --out directory or the same "
                                  "settings to resume")
        state, _ = load_tree(ckpt, state)
        pos = meta["position"]
    parallel = parallel or data_parallel()
    state = parallel.state(state)

    def save():
        save_tree(ckpt, state, {"signature": signature, "position": pos, "network": network})

    bar = None
    if progress:
        from tqdm.auto import tqdm
        bar = tqdm(total=epochs * steps_per_epoch, initial=pos["epoch"] * steps_per_epoch + pos["batch"],
                   unit="step", desc="train", smoothing=0.05)
    taken = 0
    t_start = time.perf_counter() - pos["train_s"]
    interrupted = _Interrupt()
    try:
        with interrupted:
            while pos["epoch"] < epochs and not pos.get("stopped"):  # a finished run stays finished
                it = batches(pos["epoch"])
                for _ in range(pos["batch"]):  # resume mid-epoch: skip what was consumed
                    next(it)
                logs_sum = {k: float(v) for k, v in pos["epoch_logs"].items()}
                while pos["batch"] < steps_per_epoch:
                    try:
                        batch = next(it)
                    except StopIteration:
                        break
                    state, logs = step(state, parallel.batch(batch), jax.random.fold_in(key, pos["step"]))
                    logs = {k: float(v) for k, v in logs.items()}
                    for k, v in logs.items():
                        logs_sum[k] = logs_sum.get(k, 0.0) + v
                    pos["batch"] += 1
                    pos["step"] += 1
                    taken += 1
                    pos["epoch_logs"] = logs_sum
                    if bar is not None:
                        bar.update(1)
                        bar.set_postfix({k: f"{v:.3g}" for k, v in list(logs.items())[:3]})
                    if pos["step"] % checkpoint_every == 0:
                        pos["train_s"] = time.perf_counter() - t_start
                        save()
                    if stop_after_steps is not None and taken >= stop_after_steps:
                        return {"state": state, "history": pos["history"], "best": pos["best"], "stopped": "step_limit",
                                "steps": pos["step"]}
                    if interrupted.requested:  # Ctrl-C: keep every step taken, then stop
                        pos["train_s"] = time.perf_counter() - t_start
                        save()
                        raise KeyboardInterrupt
                    if time_budget_s is not None and time.perf_counter() - t_start >= time_budget_s:
                        break  # the budget ends the epoch early: validated, saved, then stopped below
                n = max(pos["batch"], 1)
                scores = {k: float(v) for k, v in validate(state).items()}
                pos["train_s"] = time.perf_counter() - t_start
                pos["history"].append({"epoch": pos["epoch"], "train": {k: v / n for k, v in logs_sum.items()},
                                       "val": scores, "wall_s": pos["train_s"], "steps": pos["step"]})
                if scores["loss"] < pos["best"]:
                    pos["best"], pos["bad_epochs"] = scores["loss"], 0
                    if on_best is not None:
                        on_best(state, scores, pos)
                else:
                    pos["bad_epochs"] += 1
                pos["epoch"] += 1
                pos["batch"] = 0
                pos["epoch_logs"] = {}
                # why it stops goes into the checkpoint: running the command again is then a
                # no-op, not one more epoch past the patience or the budget
                if pos["bad_epochs"] >= patience:
                    pos["stopped"] = "early_stopping"
                elif time_budget_s is not None and pos["train_s"] >= time_budget_s:
                    pos["stopped"] = "time_budget"
                # the history before the checkpoint: a run killed between the two redoes the
                # epoch and writes it again; the other way round an ended run kept a history
                # (and curves) without its last epoch, the rerun having nothing left to do
                write_json(run_dir / HISTORY, pos["history"])
                _plot_curves(run_dir / CURVES, pos["history"])
                save()
                if bar is not None:
                    bar.write(f"epoch {pos['epoch']}: " + ", ".join(f"{k} {v:.4g}" for k, v in scores.items()))
    finally:
        if bar is not None:
            bar.close()
    return {"state": state, "history": pos["history"], "best": pos["best"], "stopped": pos.get("stopped", "epochs"),
            "steps": pos["step"]}


def _differences(old, new, where: str = "") -> list:
    """``"key: old -> new"`` for each setting (dotted key) that differs between two JSON trees."""
    if isinstance(old, dict) and isinstance(new, dict):
        return [d for k in sorted(set(old) | set(new), key=str)
                for d in _differences(old.get(k, "(none)"), new.get(k, "(none)"), f"{where}.{k}" if where else str(k))]

    def short(value):
        text = json.dumps(value)
        return text if len(text) <= 60 else text[:57] + "..."

    return [] if old == new else [f"{where or 'settings'}: {short(old)} -> {short(new)}"]


def check_split_holds_batch(root, split: str, count: int, unit: str, batch_size: int) -> None:
    """A ``ValueError`` naming the dataset unless ``split`` (``count`` of ``unit``) fills a batch:
    an epoch drops the last, incomplete batch, so a smaller split would train no step. With
    ``unit == "scenes"`` (a batch item is a scene) only more scenes help: the message says how many."""
    if count < batch_size:
        more = (f"at least {scenes_for_train_split(batch_size)} scenes"
                if unit == "scenes" else "more scenes or frames")
        raise ValueError(f"{root}: the {split} split ({count} {unit}) must hold a batch ({batch_size}); simulate "
                         f"{more}, or train with a smaller batch")


def epoch_steps(steps_per_epoch: int, items: int, batch_size: int) -> int:
    """The steps an epoch takes: ``steps_per_epoch`` at most, fewer when the train split's
    ``items`` run out first (the last, incomplete batch is dropped). What the progress bar
    counts and the learning-rate schedule spans: a schedule over steps that are never taken
    would not decay (a 25 x 200-step cosine on 15 batches an epoch ended at 99% of its rate)."""
    return max(1, min(steps_per_epoch, items // batch_size))


def scenes_for_train_split(train_scenes: int) -> int:
    """The fewest scenes a `jaxocean simulate` dataset needs for ``train_scenes`` scenes in its
    train split and one in its validation split (:func:`jaxocean.io.dataset.split_scenes`)."""
    from jaxocean.io.dataset import split_scenes

    n = 1
    while True:
        splits = split_scenes(n, 0)  # the split sizes depend on the number of scenes alone
        if len(splits["train"]) >= train_scenes and splits["val"]:
            return n
        n += 1


class _Interrupt(contextlib.AbstractContextManager):
    """Ctrl-C during training sets ``requested``, which the loop reads between steps (it then
    saves the checkpoint and raises ``KeyboardInterrupt``). Python's default handler raises
    wherever the main thread is, and JAX's garbage-collection callback swallows an interrupt
    raised inside it, so a run could ignore Ctrl-C. A second Ctrl-C interrupts at once. Off the
    main thread (where signals cannot be handled) nothing changes."""

    def __init__(self):
        self.requested = False
        self._previous = None

    def _handle(self, signum, frame):
        if self.requested:
            raise KeyboardInterrupt
        self.requested = True

    def __enter__(self):
        if threading.current_thread() is threading.main_thread():
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc):
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
        return False
