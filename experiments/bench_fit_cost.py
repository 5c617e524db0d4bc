"""Where a default ``fit.waves`` spends its time: XLA compilation against execution.

For each scene (``wave_fit.dataset_scene``: the Table 2 scenes, 128^2, 10 frames) a fresh
process fits it twice with the defaults: *cold* (every program compiled in the fit, as in a
new Python session without a persistent compilation cache) and *warm* (the same fit again in
the same process: every program already compiled, what a second scene of the same size and
wave buckets costs, or a new session with ``jax_compilation_cache_dir`` set, as the command
line sets it). The compilation time is the sum of JAX's backend-compile events during the fit
(``/jax/core/compile/backend_compile_duration``); the rest is tracing, execution and Python.

Usage: ``python experiments/bench_fit_cost.py [--seeds 0,3]``; writes
``experiments/results/bench_fit_cost.json`` and ``.png``. Run it on a quiet machine: each
fit takes minutes on a 2-core CPU.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
import benchutil  # noqa: E402

WORKER = r"""
import json, sys, time
sys.path.insert(0, sys.argv[2])
from jax import monitoring
import wave_fit
from jaxocean import fit

compile_s = []
def on_event(event, duration, **kw):
    if event == "/jax/core/compile/backend_compile_duration":
        compile_s.append(duration)
monitoring.register_event_duration_secs_listener(on_event)

scene, geo = wave_fit.dataset_scene(int(sys.argv[1]), 128)
out = {}
for run in ("cold", "warm"):
    compile_s.clear()
    t0 = time.perf_counter()
    result = fit.waves(geo.normal, geo.roughness, scene.camera, scene.times)
    wall = time.perf_counter() - t0
    out[run] = dict(wall_s=wall, compile_s=float(sum(compile_s)), n_compiles=len(compile_s),
                    n_waves=int(result.n_waves), success=bool(result.success),
                    normal_error_rad=float(result.normal_error))
print("RESULT " + json.dumps(out), flush=True)
"""


def one_scene(seed: int) -> dict:
    proc = subprocess.run([sys.executable, "-c", WORKER, str(seed), str(HERE)], capture_output=True, text=True)
    for line in proc.stdout.splitlines():
        if line.startswith("RESULT "):
            return dict(seed=seed, **json.loads(line[len("RESULT "):]))
    raise RuntimeError(f"scene {seed} failed:\n{proc.stderr[-3000:]}")


def plot(rows):
    plt = benchutil.pyplot()
    fig, ax = plt.subplots(figsize=(1.6 + 1.4 * len(rows), 3.6))
    labels, comp, rest = [], [], []
    for r in rows:
        for run in ("cold", "warm"):
            labels.append(f"scene {r['seed']}\n{run}")
            comp.append(r[run]["compile_s"])
            rest.append(r[run]["wall_s"] - r[run]["compile_s"])
    x = range(len(labels))
    ax.bar(x, rest, color="tab:blue", label="execution, tracing, Python")
    ax.bar(x, comp, bottom=rest, color="tab:orange", label="XLA compilation")
    ax.axhline(120, color="k", ls="--", lw=0.8, label="target 2 min")
    ax.set_xticks(list(x), labels, fontsize=8)
    ax.set_ylabel("wall time of fit.waves [s]")
    ax.set_title("default wave fit, 128² x 10 frames", fontsize=9)
    ax.legend(fontsize=7)
    benchutil.save_figure(fig, "bench_fit_cost")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", default="0", help="comma-separated dataset scene seeds")
    args = ap.parse_args(argv)
    rows = []
    for seed in (int(s) for s in args.seeds.split(",")):
        row = one_scene(seed)
        print(json.dumps(row), flush=True)
        rows.append(row)
    benchutil.save("bench_fit_cost", rows, dict(resolution=128, n_frames=10, dtype="float32"))
    plot(rows)


if __name__ == "__main__":
    main()
