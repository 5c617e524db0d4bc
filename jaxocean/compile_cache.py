"""XLA's persistent compilation cache for jaxocean's programs.

A default ``fit.waves`` of a 128² x 10-frame scene spends about a quarter of its first run in
XLA compilation (``experiments/bench_fit_cost.py``); the renderer, the lighting fit and the
networks compile for tens of seconds too. With the persistent cache on, compiled programs are
written to disk and a later process (a new notebook kernel, the next command) loads them
instead of compiling again. The command line turns it on for every command; in Python call
:func:`enable` once, before the first computation.

* :func:`folder` -> the cache folder from the environment, or None when turned off:
  ``$JAXOCEAN_COMPILE_CACHE`` names it (default ``$XDG_CACHE_HOME/jaxocean/xla``, i.e.
  ``~/.cache/jaxocean/xla``); ``0`` or an empty value turns it off.
* :func:`enable(path=None)` -> the folder in use (``path``, else :func:`folder`), or None.
"""

from __future__ import annotations

import os
from pathlib import Path

__all__ = ["folder", "enable", "MIN_COMPILE_TIME_S"]

#: programs that compile faster than this are not written (reading many tiny entries
#: would cost more than compiling them)
MIN_COMPILE_TIME_S = 1.0


def folder() -> Path | None:
    """The cache folder the environment asks for (see the module docstring), or None."""
    value = os.environ.get("JAXOCEAN_COMPILE_CACHE")
    if value is not None and value.strip() in ("", "0"):
        return None
    if value:
        return Path(value)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "jaxocean" / "xla"


def enable(path=None) -> Path | None:
    """Turn on JAX's persistent compilation cache in ``path`` (default :func:`folder`; None
    when the environment turns it off, and then nothing changes). Returns the folder."""
    import jax

    cache = Path(path) if path is not None else folder()
    if cache is None:
        return None
    jax.config.update("jax_compilation_cache_dir", str(cache))
    jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_TIME_S)
    return cache
