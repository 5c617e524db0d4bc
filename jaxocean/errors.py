"""Errors raised at jaxocean's public boundary, in two tiers.

* Structural problems (wrong shapes, dtypes, unknown names) raise ``ValueError`` at trace
  time, naming the offending value.
* Value problems (negative amplitude, omega <= 0, NaN input, camera under the sea) raise
  :class:`InvalidValueError` (a ``ValueError``) before any work is done -- when the inputs
  are concrete. Under ``jit`` the values are tracers and cannot be inspected; validate the
  inputs once outside the compiled function (every public entry point does when called
  eagerly).
* An input that needs an optional package which is not installed (a video container
  without an imageio video plugin) raises :class:`MissingDependencyError` (an
  ``ImportError``) that names the input and what to install.
"""

from __future__ import annotations

import math

import jax
import numpy as np

__all__ = ["InvalidValueError", "MissingDependencyError", "is_concrete", "require_eager", "is_integer",
           "check_values", "check_finite", "check_number", "check_nonnegative_number"]


class InvalidValueError(ValueError):
    """A value outside the physical or numerical domain of a public function."""


class MissingDependencyError(ImportError):
    """An input that needs an optional package which is not installed; the message names the
    input and what to install (the command line reports it as an input error)."""


def is_concrete(*xs) -> bool:
    """True when no leaf of ``xs`` is a tracer (values can be inspected)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree_util.tree_leaves(xs))


def require_eager(name: str, why: str, *xs) -> None:
    """``ValueError`` when a function that runs on the host (``why``: what it does there) is
    given tracers: under jit / vmap it would fail deep inside NumPy or a host loop."""
    if not is_concrete(*xs):
        raise ValueError(f"{name} runs eagerly ({why}); call it outside jit/vmap")


def check_values(ok, message: str, value=None) -> None:
    """Raise ``InvalidValueError(message)`` where ``ok`` is concrete and not all true.

    ``value`` (array-like) is summarised in the message: the first offending entries.
    """
    if not is_concrete(ok, value):
        return
    ok = np.asarray(ok)
    if ok.all():
        return
    if value is not None:
        bad = np.broadcast_to(np.asarray(value), ok.shape)[~ok]
        index = np.argwhere(~ok)[0].tolist() if ok.ndim else []
        message = f"{message}; got {bad[:4].tolist()} (first at index {index}, {bad.size} offending)"
    raise InvalidValueError(message)


def check_finite(x, name: str) -> None:
    """Raise if a concrete array contains NaN or inf."""
    if not is_concrete(x):
        return
    arr = np.asarray(x)
    if not np.all(np.isfinite(arr)):
        n = int(np.size(arr) - np.isfinite(arr).sum())
        raise InvalidValueError(f"{name} contains {n} NaN/inf value(s) of {arr.size}")


def check_number(value, message: str, low: float = 0.0, high: float = math.inf, *, low_open: bool = False,
                 high_open: bool = False) -> None:
    """Raise ``ValueError(message + "; got " + repr(value))`` unless ``value`` is a finite real
    scalar (Python or NumPy) in ``[low, high]`` (an end excluded where ``low_open`` /
    ``high_open``): a setting, not data (no arrays, never traced)."""
    ok = isinstance(value, (int, float, np.floating, np.integer)) and math.isfinite(value)
    if not (ok and (value > low if low_open else value >= low) and (value < high if high_open else value <= high)):
        raise ValueError(f"{message}; got {value!r}")


def is_integer(value, low: float = -math.inf) -> bool:
    """Whether ``value`` is a Python or NumPy integer (not a bool) ``>= low``: a count or an
    index given as a setting or read from a file."""
    return isinstance(value, (int, np.integer)) and not isinstance(value, bool) and value >= low


def check_nonnegative_number(value, message: str) -> None:
    """:func:`check_number` with its default range: finite and ``>= 0``."""
    check_number(value, message)
