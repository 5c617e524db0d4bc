"""Pytrees of arrays on disk: atomic ``.npz`` files with JSON metadata.

Protocol
--------
* ``save_tree(path, tree, meta) -> Path``: the leaves of ``tree`` (arrays, NumPy or JAX,
  any dtype NumPy can store; PRNG keys as their key data) in flattening order as ``leaf_0,
  leaf_1, ...`` plus ``__meta__`` (the JSON of ``meta`` with the leaves' shapes and dtypes),
  written through :func:`jaxocean.files.atomic_write` -- a crash leaves the previous file.
* ``load_tree(path, template) -> (tree, meta)``: the leaves put back into ``template``'s
  structure (a pytree of the same structure, e.g. a freshly initialised model), checked
  leaf by leaf for shape and dtype. ``load_tree(path, None, meta_only=True)`` reads the
  metadata alone.
* ``save_model`` / ``load_model``: a network's parameters with its config and a format tag
  (``{"format": ..., "config": config.to_json()}`` in the metadata); loading checks the tag
  and rebuilds the config before the parameters are read into a fresh initialisation, and
  refuses parameters that hold NaN or inf (a diverged training predicts NaN).
* ``nonfinite_arrays(params) -> list[int]``: the flattening indices of the floating leaves
  that hold NaN or inf (what ``load_model`` refuses, and a network's ``predict`` checks
  for a model built in memory).

Every problem -- missing file, not an npz, truncated, another structure -- raises
:class:`CheckpointError` naming the file. Host-side only.
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

import jax
import numpy as np

from jaxocean.files import atomic_write

__all__ = ["CheckpointError", "save_tree", "load_tree", "save_model", "load_model", "model_path",
           "nonfinite_arrays"]


class CheckpointError(ValueError):
    """A checkpoint or model file that cannot be used; the message names the file."""

    def __init__(self, path, reason: str):
        self.path = Path(path)
        super().__init__(f"{path}: {reason}")


def _host(leaf):
    if isinstance(leaf, jax.Array) and jax.dtypes.issubdtype(leaf.dtype, jax.dtypes.prng_key):
        return np.asarray(jax.random.key_data(leaf)), "key"
    return np.asarray(leaf), "array"


def save_tree(path, tree, meta: dict | None = None) -> Path:
    leaves = jax.tree.leaves(tree)
    arrays, kinds = zip(*[_host(x) for x in leaves]) if leaves else ((), ())
    info = dict(meta or {})
    info["leaves"] = [{"shape": list(a.shape), "dtype": str(a.dtype), "kind": k} for a, k in zip(arrays, kinds)]
    payload = {f"leaf_{i}": a for i, a in enumerate(arrays)}
    payload["__meta__"] = np.frombuffer(json.dumps(info).encode(), np.uint8)

    def write(tmp: Path):
        with open(tmp, "wb") as f:
            np.savez(f, **payload)

    return atomic_write(path, write)


_READ_ERRORS = (OSError, ValueError, KeyError, zipfile.BadZipFile, EOFError, UnicodeDecodeError)


def _read(path: Path, meta_only: bool):
    """``(meta, arrays)`` of a checkpoint, every array read (the file is closed on return)."""
    if not path.exists():
        raise CheckpointError(path, "no such file")
    if path.is_dir():  # a run directory given for its model, say
        hint = f"; its model is {path / 'model.npz'}" if (path / "model.npz").is_file() else ""
        raise CheckpointError(path, f"is a directory, not a model or checkpoint file{hint}")
    if path.is_file():
        with open(path, "rb") as f:
            if f.read(4) != b"PK\x03\x04":  # np.load would try it as a pickle and say so
                raise CheckpointError(path, "not a jaxocean checkpoint (those are .npz files, zip archives)")
    try:
        # our own file handle: np.load leaves its own open when the zip is bad
        with open(path, "rb") as f, np.load(f, allow_pickle=False) as data:
            meta = json.loads(bytes(data["__meta__"]).decode())
            n = len(meta.get("leaves", []))
            arrays = [] if meta_only else [np.asarray(data[f"leaf_{i}"]) for i in range(n)]
    except _READ_ERRORS as err:
        raise CheckpointError(path, f"not a readable jaxocean checkpoint (corrupt or truncated?): {err}") from None
    return meta, arrays


def load_tree(path, template, *, meta_only: bool = False):
    path = Path(path)
    meta, arrays = _read(path, meta_only)
    if meta_only:
        return meta
    leaves, treedef = jax.tree.flatten(template)
    stored = meta.get("leaves", [])
    if len(stored) != len(leaves):
        raise CheckpointError(path, f"holds {len(stored)} arrays but the model expects {len(leaves)} "
                              "(another architecture or version)")
    out = []
    for i, (leaf, info, arr) in enumerate(zip(leaves, stored, arrays)):
        if info["kind"] == "key":
            out.append(jax.random.wrap_key_data(arr))
            continue
        want = np.shape(leaf)
        if arr.shape != tuple(want):
            raise CheckpointError(path, f"array {i} has shape {arr.shape}, the model expects {tuple(want)} "
                                  "(another architecture)")
        want_dtype = np.dtype(leaf.dtype if hasattr(leaf, "dtype") else np.result_type(leaf))
        if arr.dtype != want_dtype:
            raise CheckpointError(path, f"array {i} is {arr.dtype}, the model expects {want_dtype}")
        out.append(arr)
    return jax.tree.unflatten(treedef, out), meta


def save_model(path, params, config, fmt: str, meta: dict | None = None) -> Path:
    """Write a network's ``params`` with its ``config`` (``to_json()``) and format tag."""
    return save_tree(path, params, {"format": fmt, "config": config.to_json(), **(meta or {})})


def load_model(path, *, fmt: str, what: str, config_from_json, init_params):
    """``(config, params)`` of a file written by :func:`save_model` with tag ``fmt``.
    ``what`` names the kind in the error ("a wave network"); ``config_from_json`` rebuilds
    the config; ``init_params(config)`` gives the parameter structure to fill (evaluated
    abstractly: only its shapes and dtypes are read, so no initialiser is compiled or run)."""
    meta = load_tree(path, None, meta_only=True)
    if meta.get("format") != fmt:
        raise CheckpointError(path, f"not {what} (format {meta.get('format')!r}, expected {fmt!r})")
    try:
        config = config_from_json(meta["config"])
    except (KeyError, TypeError, ValueError) as err:
        raise CheckpointError(path, f"bad model config: {err}") from None
    # jax.eval_shape: the initialisers' random draws compiled one program per parameter
    # shape (24 programs, 6.5 s on 2 cores for the shipped geometry model) only to be replaced
    params, _ = load_tree(path, jax.eval_shape(lambda: init_params(config)))
    bad = nonfinite_arrays(params)
    if bad:
        raise CheckpointError(path, f"array {bad[0]} holds NaN or inf ({len(bad)} such array(s)): the parameters "
                              "of a diverged training, not a usable model")
    return config, params


def nonfinite_arrays(params) -> list[int]:
    """Flattening indices of the floating-point leaves of ``params`` holding NaN or inf."""
    def dtype(leaf):
        return leaf.dtype if hasattr(leaf, "dtype") else np.result_type(leaf)

    return [i for i, leaf in enumerate(jax.tree.leaves(params))
            if jax.dtypes.issubdtype(dtype(leaf), np.inexact) and not np.all(np.isfinite(np.asarray(leaf)))]


def model_path(path, shipped: dict, default: Path) -> Path:
    """Where a network's model is: ``None`` -> ``default`` (the shipped model), a name of
    ``shipped`` -> that shipped model, else the file ``path`` (``CheckpointError`` naming the
    shipped models when there is no such file: a misspelt name, say)."""
    if path is None:
        return default
    if isinstance(path, str) and path in shipped:
        return shipped[path]
    if not Path(path).exists():
        names = ", ".join(repr(name) for name in shipped)
        raise CheckpointError(path, f"no such file, nor the name of a shipped model ({names})")
    return Path(path)
