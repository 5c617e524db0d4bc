"""Writing files: atomic replacement and strict JSON, for every writer in jaxocean.

Protocol
--------
* ``atomic_write(path, write) -> Path``: ``write(temporary_path)`` creates the file, which
  then replaces ``path`` in one rename. Readers see the old file or the complete new one.
* ``json_safe(data)``: ``data`` (dicts, lists, tuples, NumPy / JAX scalars and arrays,
  Python numbers, strings, booleans, None) as plain Python values that strict JSON can
  hold: arrays become nested lists, and every non-finite float (NaN, inf) becomes None
  (``null``), so a failed fit's NaN parameters are written as null.
* ``write_json(path, data) -> Path``: ``json_safe(data)`` as indented strict JSON with a
  final newline, written through :func:`atomic_write`.
* ``read_json(path, what) -> dict``: a JSON object from a file; every failure
  (``FileNotFoundError``, or ``ValueError`` for text that is not UTF-8, malformed JSON with
  its line and column, or a value that is not an object) names the file and ``what`` it is.

This module sits below :mod:`jaxocean.io` and :mod:`jaxocean.plots` (it imports nothing of
jaxocean), so both write through it without importing each other. Host-side only.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Callable

import numpy as np

__all__ = ["atomic_write", "json_safe", "read_json", "write_json"]


def atomic_write(path, write: Callable[[Path], Any]) -> Path:
    """Create or replace ``path`` atomically: ``write(temporary_path)`` then rename.

    ``write`` receives the path of a temporary file in the destination directory
    (``.{name}.tmp-{pid}``; same directory, so the final rename never crosses file systems)
    and must create it. The file is flushed to disk, then ``os.replace``-d onto ``path``:
    readers see either the old file or the complete new one, never a partial file. If
    ``write`` raises, the temporary file is removed and ``path`` is left as it was. Missing
    parent directories are created.

    Returns:
        ``path`` as a :class:`pathlib.Path`.
    """
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    temporary = path.with_name(f".{path.name}.tmp-{os.getpid()}")
    try:
        write(temporary)
        _fsync(temporary)
        os.replace(temporary, path)
    except BaseException:
        # BaseException: a KeyboardInterrupt mid-write must not leave the temporary behind.
        temporary.unlink(missing_ok=True)
        raise
    _fsync_directory(path.parent)
    return path


def _fsync(path: Path) -> None:
    """Flush a file's data to disk, so that the rename can never expose an empty file after
    a power cut (the rename may reach the disk before the data otherwise)."""
    fd = os.open(path, os.O_RDONLY)
    try:
        os.fsync(fd)
    finally:
        os.close(fd)


def _fsync_directory(directory: Path) -> None:
    """Persist the rename itself; best effort (not every platform can open a directory)."""
    try:
        fd = os.open(directory, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def json_safe(data):
    """``data`` as plain Python values strict JSON can hold; non-finite floats become None.

    Dicts keep their keys; lists and tuples become lists; NumPy / JAX arrays and scalars
    become (nested lists of) Python ``float`` / ``int`` / ``bool``. Anything else (strings,
    None, ...) is returned as is, and ``json.dumps`` reports what it cannot write.
    """
    if isinstance(data, dict):
        return {key: json_safe(value) for key, value in data.items()}
    if isinstance(data, (list, tuple)):
        return [json_safe(value) for value in data]
    if isinstance(data, (bool, int, str)) or data is None:
        return data
    if isinstance(data, float):
        return data if math.isfinite(data) else None
    if hasattr(data, "__array__") or isinstance(data, np.generic):
        array = np.asarray(data)
        if array.dtype.kind in "iub":
            return array.tolist()
        if array.dtype.kind == "f":
            return json_safe(array.astype(np.float64).tolist())
    return data


def write_json(path, data) -> Path:
    """``data`` as indented strict JSON (:func:`json_safe`: non-finite numbers as null), with
    a final newline, written atomically; returns the path."""
    text = json.dumps(json_safe(data), indent=1, allow_nan=False) + "\n"
    return atomic_write(path, lambda temporary: temporary.write_text(text, encoding="utf-8"))


def read_json(path, what: str) -> dict:
    """The JSON object in ``path``, a ``what`` (e.g. "dataset settings file"); errors name both."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no such {what}" + (" (a directory)" if path.is_dir() else ""))
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as error:
        raise ValueError(f"{path}: a {what} must be UTF-8 text ({error})") from None
    except json.JSONDecodeError as error:
        raise ValueError(f"{path}: malformed JSON in this {what}: {error.msg} at line {error.lineno}, "
                         f"column {error.colno}") from None
    if not isinstance(data, dict):
        raise ValueError(f"{path}: a {what} must be a JSON object; got {type(data).__name__}")
    return data
