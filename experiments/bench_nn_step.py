"""Train-step speed of a network written with jaxocean.nn against the same network in PyTorch.

The network of the comparison: a 4-block, 32-channel GroupNorm ResNet at full resolution
(stem conv-GN-ReLU, four residual blocks conv-GN-ReLU-conv-GN + x, ReLU, 1x1 head to 3
channels), 64x64 inputs with 3 channels, batch 8, MSE loss, Adam. Also timed: the train
step of the geometry model's ``cpu`` config (jaxocean.nn.geometry_train) and its 128^2
inference.

On a machine with more than one core, the same JAX step also runs with its batch split over
one XLA host device per core (a subprocess started with
``XLA_FLAGS=--xla_force_host_platform_device_count=N``): XLA:CPU runs each convolution on
one core, and the split is how a JAX step uses the others (as PyTorch's threads do).

PyTorch is optional and not a dependency: pass ``--torch-python PATH`` (a Python with torch
installed, e.g. a scratch venv). Its steps run in a persistent subprocess, interleaved round
by round with the JAX steps, so that both see the same machine load; the ratio is taken from
the same rounds. Medians over rounds after compilation (JAX) / warm-up (PyTorch); compile
time reported apart. Writes experiments/results/bench_nn_step.json and .png.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent

TORCH_WORKER = r"""
import sys, time, torch
torch.manual_seed(0)
C, B, H = 32, 8, 64
class Block(torch.nn.Module):
    def __init__(s):
        super().__init__()
        s.c1 = torch.nn.Conv2d(C, C, 3, padding=1); s.n1 = torch.nn.GroupNorm(8, C)
        s.c2 = torch.nn.Conv2d(C, C, 3, padding=1); s.n2 = torch.nn.GroupNorm(8, C)
    def forward(s, x):
        return torch.relu(x + s.n2(s.c2(torch.relu(s.n1(s.c1(x))))))
net = torch.nn.Sequential(torch.nn.Conv2d(3, C, 3, padding=1), torch.nn.GroupNorm(8, C), torch.nn.ReLU(),
                          *[Block() for _ in range(4)], torch.nn.Conv2d(C, 3, 1))
opt = torch.optim.Adam(net.parameters(), 1e-3)
x = torch.randn(B, 3, H, H); y = torch.randn(B, 3, H, H)
def step():
    opt.zero_grad(); loss = ((net(x) - y) ** 2).mean(); loss.backward(); opt.step()
for _ in range(3):
    step()
print(json.dumps({"threads": torch.get_num_threads(), "version": torch.__version__}), flush=True)
for line in sys.stdin:
    n = int(line)
    ts = []
    for _ in range(n):
        t = time.perf_counter(); step(); ts.append(time.perf_counter() - t)
    print(json.dumps(ts), flush=True)
""".replace("import sys, time, torch", "import sys, time, json, torch")


def _jax_resnet_step():
    """The ResNet train step, its batch split over every local device (one device unless
    ``XLA_FLAGS=--xla_force_host_platform_device_count=N`` made N of the host)."""
    import jax
    import jax.numpy as jnp
    import optax

    from jaxocean.nn import backbones
    from jaxocean.nn import layers as nl
    from jaxocean.nn.training import data_parallel

    parallel = data_parallel()
    net = nl.serial(backbones.ResNet(32, 4, downsample=0), nl.Conv(3, 1))
    _, params = net.init(jax.random.key(0), (8, 64, 64, 3))
    x, y = parallel.batch((jax.random.normal(jax.random.key(1), (8, 64, 64, 3)),
                           jax.random.normal(jax.random.key(2), (8, 64, 64, 3))))
    opt = optax.adam(1e-3)

    @jax.jit
    def step(params, state, x, y):
        loss, g = jax.value_and_grad(lambda p: jnp.mean((net.apply(p, x) - y) ** 2))(params)
        u, state = opt.update(g, state)
        return optax.apply_updates(params, u), state, loss

    carry = parallel.state([params, opt.init(params)])

    def run():
        carry[0], carry[1], loss = step(*carry, x, y)
        jax.block_until_ready(loss)

    return run


# the same JAX step in a subprocess whose host is split into one XLA device per core (the
# flag must be set before JAX starts): XLA:CPU runs each convolution on one core, so a
# batch split over two devices runs on both cores
JAX_DEVICES_WORKER = r"""
import json, sys, time
sys.path.insert(0, sys.argv[1])
from bench_nn_step import DEVICE_JOBS
runs = {name: make() for name, make in DEVICE_JOBS.items()}
for run in runs.values():
    run(); run()
import jax
print(json.dumps({"devices": jax.device_count()}), flush=True)
for line in sys.stdin:
    name, n = line.rsplit(" ", 1)
    ts = []
    for _ in range(int(n)):
        t = time.perf_counter(); runs[name](); ts.append(time.perf_counter() - t)
    print(json.dumps(ts), flush=True)
"""


def _geometry_step(dataset):
    import jax

    from jaxocean.io.dataset import Dataset
    from jaxocean.nn import geometry_train as gt

    config = gt.CONFIGS["cpu"]
    data = Dataset(dataset)
    batch = gt._batch_dict(next(data.batches(jax.random.key(0), "train", config.batch_size)))
    step = gt.make_step(config)
    carry = [gt.init_state(config, jax.random.key(0))]

    def run():
        carry[0], logs = step(carry[0], batch, jax.random.key(1))
        jax.block_until_ready(logs["loss"])

    return run


def _geometry_inference(frames=1):
    """``predict`` of the shipped model on ``frames`` 128^2 frames at once (one batch of
    ``predict``'s 8 at most), spread over every local device."""
    import jax
    import numpy as np

    from jaxocean import camera as cam
    from jaxocean.nn import geometry as geo

    model = geo.load() if geo.PRETRAINED_PATH.exists() else geo.init(jax.random.key(0))
    camera = cam.make_camera(height=10.0, pitch=0.6, fov=0.8, resolution=(128, 128))
    image = np.random.default_rng(0).uniform(0.02, 0.2, (frames, 128, 128, 3)).astype(np.float32)

    def run():
        jax.block_until_ready(geo.predict(model, image, camera).normal)

    return run


#: the jobs also timed in a subprocess with one XLA host device per core
DEVICE_JOBS = {"jaxocean.nn ResNet step": _jax_resnet_step,
               "geometry inference, a batch of 8 128^2 frames": lambda: _geometry_inference(8)}


def _time(fn, n):
    ts = []
    for _ in range(n):
        t = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t)
    return ts


def main(argv=None):
    import numpy as np

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--torch-python", help="a Python interpreter with torch installed (optional)")
    ap.add_argument("--dataset", help="a jaxocean dataset, to time the geometry model's train step too")
    ap.add_argument("--rounds", type=int, default=6)
    ap.add_argument("--steps", type=int, default=8, help="steps per round")
    ap.add_argument("--out", default=str(HERE / "results" / "bench_nn_step"))
    args = ap.parse_args(argv)
    sys.path.insert(0, str(HERE.parent))

    jobs = {"jaxocean.nn ResNet step": _jax_resnet_step()}
    if args.dataset:
        jobs["geometry cpu-config step (64^2 crops, batch 8)"] = _geometry_step(args.dataset)
    jobs["geometry inference, one 128^2 frame"] = _geometry_inference()
    jobs["geometry inference, a batch of 8 128^2 frames"] = _geometry_inference(8)
    compile_s = {name: _time(fn, 1)[0] for name, fn in jobs.items()}
    # name -> (persistent subprocess timing its jobs on request, round by round; its job)
    workers = {}
    cores = os.cpu_count() or 1
    if cores > 1:
        flags = (os.environ.get("XLA_FLAGS", "") + f" --xla_force_host_platform_device_count={cores}").strip()
        proc = subprocess.Popen(
            [sys.executable, "-c", JAX_DEVICES_WORKER, str(HERE)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
            text=True, env=dict(os.environ, XLA_FLAGS=flags, PYTHONPATH=str(HERE.parent)))
        for job in DEVICE_JOBS:
            split = "batch split" if "step" in job else "frames split"
            workers[f"{job}, {split} over {cores} host devices"] = (proc, job)
    if args.torch_python:
        proc = subprocess.Popen(
            [args.torch_python, "-c", TORCH_WORKER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True,
            env=dict(os.environ, PYTHONWARNINGS="ignore"))
        workers["PyTorch ResNet step"] = (proc, None)
    procs = {id(proc): proc for proc, _ in workers.values()}
    info = {name: json.loads(proc.stdout.readline()) for name, (proc, job) in workers.items()
            if job is None or job == next(iter(DEVICE_JOBS))}
    torch_info = info.get("PyTorch ResNet step")
    rounds = {name: [] for name in list(jobs) + list(workers)}
    for _ in range(args.rounds):
        for name, fn in jobs.items():
            rounds[name].append(float(np.median(_time(fn, args.steps))))
        for name, (proc, job) in workers.items():
            proc.stdin.write(f"{args.steps}\n" if job is None else f"{job} {args.steps}\n")
            proc.stdin.flush()
            rounds[name].append(float(np.median(json.loads(proc.stdout.readline()))))
    for proc in procs.values():
        proc.stdin.close()
        proc.wait()
    torch_proc = workers.get("PyTorch ResNet step")
    medians = {name: float(np.median(v)) for name, v in rounds.items()}
    result = {"median_s": medians, "per_round_median_s": rounds, "compile_s": compile_s, "torch": torch_info,
              "workers": info, "load_average": os.getloadavg(), "cpu_count": os.cpu_count(),
              "frames_per_s": {name: (8 if "batch of 8" in name else 1) / v for name, v in medians.items()
                               if "inference" in name}}
    if torch_proc:
        for name in [n for n in rounds if n.startswith("jaxocean.nn ResNet step")]:
            ratios = [j / t for j, t in zip(rounds[name], rounds["PyTorch ResNet step"])]
            key = "" if name == "jaxocean.nn ResNet step" else "_devices"
            result[f"jax{key}_over_torch_per_round"] = ratios
            result[f"jax{key}_over_torch_median"] = float(np.median(ratios))
    from jaxocean.files import write_json

    write_json(args.out + ".json", result)
    _chart(args.out + ".png", rounds)
    for name, v in medians.items():
        fps = result["frames_per_s"].get(name)
        print(f"{name:<72} {1000 * v:9.1f} ms" + (f"  ({fps:.1f} frames/s)" if fps else ""))
    if torch_proc:
        split = (f", batch split over {cores} host devices {result['jax_devices_over_torch_median']:.2f}"
                 if "jax_devices_over_torch_median" in result else "")
        print(f"JAX / PyTorch (same rounds): one device {result['jax_over_torch_median']:.2f}{split}; "
              f"load average {os.getloadavg()}")


def _chart(path, rounds):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxocean import plots

    fig, ax = plt.subplots(figsize=(8, 3.5))
    names = list(rounds)
    for i, name in enumerate(names):
        ax.scatter([i] * len(rounds[name]), [1000 * v for v in rounds[name]], s=14)
    ax.set_xticks(range(len(names)))
    ax.set_xticklabels(names, rotation=12, fontsize=7)
    ax.set_ylabel("ms per call (median of each round)")
    ax.set_yscale("log")
    fig.tight_layout()
    plots.save_figure(fig, path)


if __name__ == "__main__":
    main()
