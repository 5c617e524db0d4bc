"""Dataset generation benchmark: a measured fraction of the paper-size dataset.

The paper's dataset is 2,000 scenes x 10 frames. This script generates ``--scenes`` scenes
(default 100) at 128^2 and a smaller set at 256^2 with ``jaxocean.io.dataset.simulate``,
reports wall time, frames/s, bytes on disk and where the time goes (render vs EXR encode +
write, the latter on writer threads overlapping the rendering), and extrapolates to 2,000
scenes: a one-scene run first (compilation and one scene, timed apart), then the measured
scenes with the kernels compiled, so the paper size is the first scene plus 1,999 times
the measured per-scene time -- the compilation counted once, as in a real run. Target on the 2-core machine: 128^2 paper size in <= 10 min and <= 3 GB.
Each row also says how many of its scenes take the converged-hits path (``render.plan``),
which costs far more per frame than the rows path (``bench_hits.py``), and the machine's
load average when the run started (the machine is shared), and the process's CPU time per
scene: on a shared machine the wall time is inflated by other jobs, while CPU time / cores is
the least wall time the same work can take with the cores to itself (``paper_size_cpu_bound_s``:
every core busy all the time); the measured wall time, inflated by other jobs, bounds it from above.
It also measures the loader: frames/s from a cold (decode from disk) and a warm (decoded
cache) read.

Usage: ``python experiments/bench_dataset.py [--scenes 100] [--quick]``; writes
``experiments/results/bench_dataset.{json,png}``.
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

import jax

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import render  # noqa: E402
from jaxocean.io import dataset  # noqa: E402

PAPER_SCENES, FRAMES = 2000, 10
TARGET_S, TARGET_BYTES = 600.0, 3e9
CORES = os.cpu_count() or 1


def hits_scenes(scenes: int, res: int) -> int:
    """How many of the first ``scenes`` default scenes (seed 0) render on the hits path."""
    base = jax.random.key(0)
    return sum(render.plan(s.waves, s.camera).refine > 0
               for s in (dataset.sample_scene(jax.random.fold_in(base, i), resolution=(res, res), n_frames=FRAMES)
                         for i in range(scenes)))


def generate(root: Path, scenes: int, res: int):
    load = os.getloadavg()[0]
    first = dataset.simulate(root.with_name(root.name + "_first"), 1, FRAMES, (res, res), seed=0, progress=False)
    cpu0 = time.process_time()
    stats = dataset.simulate(root, scenes, FRAMES, (res, res), seed=0, progress=False)
    cpu_per_scene_s = (time.process_time() - cpu0) / scenes
    per_scene_s = stats["wall_s"] / scenes
    return dict(res=res, scenes=scenes, hits_scenes=hits_scenes(scenes, res), load_at_start=load,
                first_scene_s=first["wall_s"], per_scene_s=per_scene_s, cpu_per_scene_s=cpu_per_scene_s,
                paper_size_cpu_bound_s=first["wall_s"] + cpu_per_scene_s * (PAPER_SCENES - 1) / CORES,
                frames=scenes * FRAMES, wall_s=stats["wall_s"],
                frames_per_s=stats["frames_per_s"], render_s=stats["render_s"], write_s_threads=stats["write_s"],
                bytes=stats["bytes"], bytes_per_frame=stats["bytes"] / (scenes * FRAMES),
                paper_size_s=first["wall_s"] + per_scene_s * (PAPER_SCENES - 1), paper_size_bytes=stats["bytes"] / scenes * PAPER_SCENES)


def loader(root: Path):
    ds = dataset.Dataset(root)
    out = {}
    for label in ("cold", "warm"):
        n, t0 = 0, time.perf_counter()
        for batch in ds.batches(jax.random.key(0), "train", batch_size=8, sequence=1):
            n += batch.image.shape[0]
        out[f"{label}_frames_per_s"] = n / (time.perf_counter() - t0)
    return out


def chart(rows, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 3.8))
    labels = [f"{r['res']}^2" for r in rows]
    axes[0].bar(labels, [r["paper_size_s"] / 60 for r in rows], color="C0")
    axes[0].axhline(TARGET_S / 60, color="C3", ls=":", label="target (128^2)")
    axes[0].set_ylabel("minutes for 2,000 x 10 frames (extrapolated)")
    axes[0].legend()
    axes[1].bar(labels, [r["paper_size_bytes"] / 1e9 for r in rows], color="C2")
    axes[1].axhline(TARGET_BYTES / 1e9, color="C3", ls=":")
    axes[1].set_ylabel("GB on disk (extrapolated)")
    fig.suptitle("jaxocean simulate: paper-size dataset cost on this machine")
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenes", type=int, default=100)
    ap.add_argument("--quick", action="store_true")
    args = ap.parse_args(argv)
    scenes = 20 if args.quick else args.scenes
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for res, n in ((128, scenes), (256, max(5, scenes // 5))):
            root = Path(tmp) / f"ds{res}"
            rows.append(generate(root, n, res))
            if res == 128:
                rows[-1].update(loader(root))
            benchutil.print_table(rows[-1:], ["res", "scenes", "hits_scenes", "load_at_start", "first_scene_s",
                                              "wall_s", "cpu_per_scene_s", "paper_size_cpu_bound_s", "frames_per_s", "render_s", "write_s_threads",
                                              "bytes_per_frame", "paper_size_s", "paper_size_bytes"])
            shutil.rmtree(root)
    r128 = rows[0]
    summary = dict(paper_128_minutes=r128["paper_size_s"] / 60, paper_128_gb=r128["paper_size_bytes"] / 1e9,
                   target_met=r128["paper_size_s"] <= TARGET_S and r128["paper_size_bytes"] <= TARGET_BYTES,
                   paper_128_minutes_cpu_bound=r128["paper_size_cpu_bound_s"] / 60,
                   loader_cold_fps=r128.get("cold_frames_per_s"), loader_warm_fps=r128.get("warm_frames_per_s"),
                   note="measured on a fraction with the kernels compiled, extrapolated linearly to 2,000 "
                        "scenes; plus the first scene's run (compilation included). The cpu bound is the process's CPU "
                        "time over the cores: a lower bound on the wall time with the cores to itself; the measured "
                        "wall time on the shared machine is an upper bound")
    print("\nsummary:", summary)
    out = benchutil.save("bench_dataset", rows, dict(summary=summary))
    chart(rows, out.with_suffix(".png"))
    print("wrote", out)


if __name__ == "__main__":
    main()
