"""The stage protocol of ``jaxocean reconstruct``, shared by its input stage
(:mod:`jaxocean.footage`) and the stages after it (:mod:`jaxocean.reconstruct`).

A stage is a function that returns ``(value, StageReport)``; :func:`timed` runs the body of
one and times it. The body returns ``(value, success, message, details)``.
"""

from __future__ import annotations

import time
from typing import NamedTuple

__all__ = ["StageReport", "timed"]


class StageReport(NamedTuple):
    """A stage's ``name``, ``success``, wall time ``seconds``, a ``message`` (why it failed,
    or what it chose) and a JSON-safe ``details`` dict."""

    name: str
    success: bool
    seconds: float
    message: str = ""
    details: dict = {}


def timed(name, fn):
    """Run ``fn() -> (value, success, message, details)``; return ``(value, StageReport)``."""
    t0 = time.perf_counter()
    value, success, message, details = fn()
    return value, StageReport(name, bool(success), time.perf_counter() - t0, message, details)
