"""Shared timing, memory and reporting helpers for the benchmarks in ``experiments/``.

Protocol: ``time_jitted(fn, *args)`` compiles ``fn`` once (timed separately), then reports
the median wall time of ``repeats`` calls with ``jax.block_until_ready``; peak memory is
XLA's own accounting of the compiled program (arguments + outputs + temporaries), which is
deterministic on the CPU backend. ``save(name, rows, meta)`` writes
``experiments/results/NAME.json``; charts go beside it as PNG.
"""

from __future__ import annotations

import json
import os
import platform
import time
from pathlib import Path

import jax
import numpy as np

RESULTS = Path(__file__).resolve().parent / "results"


def time_jitted(fn, *args, repeats: int = 5, min_time: float = 0.0):
    """Return ``dict(compile_s, median_s, min_s, repeats, peak_bytes)`` for ``jax.jit(fn)(*args)``."""
    jitted = jax.jit(fn)
    t0 = time.perf_counter()
    compiled = jitted.lower(*args).compile()
    compile_s = time.perf_counter() - t0
    jax.block_until_ready(compiled(*args))  # first run: allocation, page faults
    times = []
    while len(times) < repeats or sum(times) < min_time:
        t0 = time.perf_counter()
        jax.block_until_ready(compiled(*args))
        times.append(time.perf_counter() - t0)
    mem = compiled.memory_analysis()
    peak = None
    if mem is not None:
        peak = int(mem.argument_size_in_bytes + mem.output_size_in_bytes + mem.temp_size_in_bytes
                   - getattr(mem, "alias_size_in_bytes", 0))
    return dict(compile_s=compile_s, median_s=float(np.median(times)), min_s=float(np.min(times)),
                repeats=len(times), peak_bytes=peak)


def interleaved_medians(calls: dict, rounds: int = 7, block: int = 11) -> dict:
    """Median seconds of each ``name -> (fn, args)`` after compilation: ``rounds`` rounds, each
    timing ``block`` consecutive calls of every function in turn; the median over rounds of
    each block's median.

    Consecutive blocks of repeats drift on this machine (measured: the same render 3.2-5.0
    ms median across five back-to-back runs); alternating the blocks exposes every function
    to the same drift, so their *ratios* are stabler. Blocks, not single calls in turn: a
    call right after a different, larger one runs with cold caches (measured: on_grid 1.4 ms
    in blocks, 2.3-2.8 ms alternating call by call with the renderer), which would bias
    every ratio towards the larger function.
    """
    compiled = {name: jax.jit(fn).lower(*args).compile() for name, (fn, args) in calls.items()}
    for name, (_, args) in calls.items():
        jax.block_until_ready(compiled[name](*args))
    medians = {name: [] for name in calls}
    for _ in range(rounds):
        for name, (_, args) in calls.items():
            times = []
            for _ in range(block):
                t0 = time.perf_counter()
                jax.block_until_ready(compiled[name](*args))
                times.append(time.perf_counter() - t0)
            medians[name].append(float(np.median(times)))
    return {name: float(np.median(m)) for name, m in medians.items()}


def machine_info() -> dict:
    """The machine, and its 1/5/15-minute load average when the results are saved (the
    development machine also runs other jobs: loaded runs are slower)."""
    return dict(platform=platform.platform(), processor=platform.processor(), cpus=os.cpu_count(),
                jax=jax.__version__, backend=jax.default_backend(),
                devices=[str(d) for d in jax.devices()], load_average=list(os.getloadavg()))


def load_rows(name: str, default=None):
    """The ``rows`` of a saved ``experiments/results/NAME.json`` (sections accumulate across
    runs), or ``default`` when there is no such file."""
    path = RESULTS / f"{name}.json"
    if not path.exists():
        return default
    return json.loads(path.read_text()).get("rows", default)


def save(name: str, rows, meta: dict | None = None) -> Path:
    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.json"
    payload = dict(meta=dict(machine=machine_info(), **(meta or {})), rows=rows)
    tmp = path.with_suffix(f".json.{os.getpid()}.tmp")  # runs sharing a file never share a temporary
    tmp.write_text(json.dumps(payload, indent=1))
    tmp.replace(path)
    return path


def waves_to_json(waves) -> dict:
    """A ``Waves`` as JSON lists, one per field (how results rows store fitted waves)."""
    return {f: np.asarray(getattr(waves, f), float).tolist() for f in waves._fields}


def waves_from_json(d: dict):
    """The float32 ``Waves`` that :func:`waves_to_json` stored."""
    import jax.numpy as jnp

    from jaxocean.waves import Waves

    return Waves(*(jnp.asarray(d[f], jnp.float32) for f in Waves._fields))


def print_table(rows, columns) -> None:
    widths = [max(len(c), *(len(_fmt(r.get(c))) for r in rows)) for c in columns]
    print("  ".join(c.rjust(w) for c, w in zip(columns, widths)))
    for r in rows:
        print("  ".join(_fmt(r.get(c)).rjust(w) for c, w in zip(columns, widths)))


def _fmt(v) -> str:
    if isinstance(v, float):
        return f"{v:.4g}"
    return str(v)


def pyplot():
    """matplotlib.pyplot on the non-interactive Agg backend (benchmarks write PNGs only)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def save_figure(fig, name: str, dpi: int = 110) -> Path:
    """Lay out ``fig``, write ``experiments/results/NAME.png`` and close it."""
    import matplotlib.pyplot as plt

    RESULTS.mkdir(parents=True, exist_ok=True)
    path = RESULTS / f"{name}.png"
    fig.tight_layout()
    fig.savefig(path, dpi=dpi)
    plt.close(fig)
    return path
