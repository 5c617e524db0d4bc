"""Wave fitting: where it fails. Success and error against the sea and the observation.

Each axis varies one thing around a base problem: a JONSWAP sea (Hs 0.6 m, Tp 4 s, gamma
3.3, s_max 15) of ``N`` waves, seen from a perspective camera 10 m high, 0.8 rad below the
horizon, fov 0.8 rad, 10 frames 0.15 s apart, 64^2 pixels, noise-free normals and roughness.
The fit is the full pipeline ``fit.waves`` (spectral start, greedy BIC order selection,
structured LM) on the geometry as `render` draws it (`fit.waves.predict(..., surface="auto")`: the hits
path where the waves move the hits). Scored against the true waves the image *resolves*
(:func:`jaxocean.fit.waves.resolvable`): the fraction found (one-to-one match within 10%),
the mean absolute errors (h, omega, theta) of the matched pairs, spurious waves, success.

Axes: ``waves`` N = 4, 15, 60, 240; ``frames`` 2, 3, 10; ``noise`` sigma = 0, 0.003, 0.01,
0.03 on the normals' x, y components (renormalised; ``noise=sigma`` passed to the fit, so the
BIC knows it); ``resolution`` 32, 64, 128; ``nyquist``: one wave on an orthographic view
whose wavelength is 1 to 8 footprints (the renderer sends it from normals to roughness
between n_max = 1.5 and n_min = 1 footprints).

Usage: ``python experiments/stability_waves.py [--quick] [--only waves,frames,...] [--no-heights]
[--seeds K]``; writes ``experiments/results/stability_waves.json`` and ``.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings

import jax
import jax.numpy as jnp
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import camera as cam  # noqa: E402
from jaxocean import fit, spectrum  # noqa: E402
from jaxocean.errors import InvalidValueError  # noqa: E402
from jaxocean.fit import waves_fit as fw  # noqa: E402
from jaxocean.waves import GRAVITY, make_waves  # noqa: E402

AXES = ("nyquist", "frames", "noise", "waves", "resolution")
SEA = spectrum.Spectrum(hs=0.6, tp=4.0, gamma=3.3, theta_mean=0.4, s_max=15.0)
NAME = "stability_waves"


def base_camera(res):
    return cam.make_camera(height=10.0, pitch=0.8, fov=0.8, yaw=0.0, resolution=(res, res))


def sampled(seed, n):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return spectrum.sample_waves(jax.random.key(seed), SEA, n).waves


def add_noise(normals, sigma, seed):
    if sigma <= 0:
        return normals
    eps = sigma * jax.random.normal(jax.random.key(1000 + seed), normals.shape[:-1] + (2,), normals.dtype)
    n = normals.at[..., :2].add(eps)
    return n / jnp.linalg.norm(n, axis=-1, keepdims=True)


def score(truth, camera, normals, rough, times, noise=None, heights=True):
    ok = np.asarray(fw.resolvable(truth, camera))
    visible = jax.tree.map(lambda x: x[ok], truth)
    t0 = time.perf_counter()
    try:
        r = fit.waves(normals, rough, camera, times, noise=noise, heights=heights)
    except InvalidValueError as exc:  # e.g. "no wave found": a measured failure, not a crash
        return dict(n_true=int(ok.size), n_resolvable=int(ok.sum()), n_fitted=0, found=0.0, spurious=0,
                    success=False, mae_amplitude=float("nan"), mae_omega=float("nan"), mae_theta=float("nan"),
                    normal_error_rad=float("nan"), time_s=time.perf_counter() - t0, error=str(exc))
    wall = time.perf_counter() - t0
    m = fw.match(r.waves, visible)
    mae = {f: float(np.mean(np.abs(getattr(m.abs_error, f)))) if m.true_index.size else float("nan")
           for f in ("amplitude", "omega", "theta")}
    return dict(n_true=int(ok.size), n_resolvable=int(ok.sum()), n_fitted=int(r.n_waves),
                found=float(m.true_index.size / max(ok.sum(), 1)), spurious=int(m.spurious.size),
                success=bool(r.success), mae_amplitude=mae["amplitude"], mae_omega=mae["omega"],
                mae_theta=mae["theta"], normal_error_rad=float(r.normal_error), time_s=wall)


def problem(seed, *, n=15, frames=10, res=64, noise=0.0, heights=True):
    truth = sampled(seed, n)
    camera = base_camera(res)
    times = np.arange(frames) * 0.15
    normals, rough = fw.predict(truth, camera, times, surface="auto")  # as render draws it
    return score(truth, camera, add_noise(normals, noise, seed), rough, times, noise=noise or None, heights=heights)


def nyquist_problem(seed, ratio, res, heights=True):
    width = 16.0
    camera = cam.make_orthographic(width, (res, res))
    footprint = width / res
    lam = ratio * footprint
    k = 2 * np.pi / lam
    om = float(np.sqrt(GRAVITY * k))
    rng = np.random.default_rng(seed)
    truth = make_waves([0.2 / k], [om], [rng.uniform(-np.pi, np.pi)], [rng.uniform(0, 2 * np.pi)])
    times = np.arange(10) * 0.05
    normals, rough = fw.predict(truth, camera, times, surface="auto")  # as render draws it
    row = score(truth, camera, normals, rough, times, heights=heights)
    row["wavelength_px"] = ratio
    return row


#: the argument of :func:`problem` each axis but ``nyquist`` varies
_PROBLEM_ARGUMENT = dict(waves="n", frames="frames", noise="noise", resolution="res")


def run_axis(axis, values, seeds, quick, res, on_row=None, heights=True):
    rows = []
    for v in values:
        for seed in range(seeds):
            if axis == "nyquist":
                row = nyquist_problem(seed, v, 32 if quick else 48, heights=heights)
            else:
                row = problem(seed, **{"res": res, _PROBLEM_ARGUMENT[axis]: v}, heights=heights)
            row.update(axis=axis, value=v, seed=seed)
            rows.append(row)
            benchutil.print_table([row], ["axis", "value", "seed", "n_resolvable", "n_fitted", "found", "spurious",
                                          "mae_amplitude", "mae_omega", "mae_theta", "time_s"])
            if on_row is not None:
                on_row(rows)  # nothing lost if a later problem crashes or the run is stopped
    return rows


VALUES = dict(waves=(4, 15, 60, 240), frames=(2, 3, 10), noise=(0.0, 0.003, 0.01, 0.03), resolution=(32, 64, 128),
              nyquist=(1.0, 1.25, 1.5, 2.0, 3.0, 5.0, 8.0))
QUICK = dict(waves=(4, 15), frames=(2, 10), noise=(0.0, 0.01), resolution=(32, 64), nyquist=(1.25, 2.0, 5.0))


def plot(out, name=NAME):
    plt = benchutil.pyplot()

    axes_present = [a for a in AXES if a in out]
    fig, axes = plt.subplots(2, len(axes_present), figsize=(3.6 * len(axes_present), 6.4), squeeze=False)
    for j, a in enumerate(axes_present):
        rows = out[a]
        vals = sorted({r["value"] for r in rows})
        found = [np.mean([r["found"] for r in rows if r["value"] == v]) for v in vals]
        om = [np.nanmean([r["mae_omega"] for r in rows if r["value"] == v]) for v in vals]
        x = np.arange(len(vals))
        axes[0, j].bar(x, found)
        axes[0, j].set_ylim(0, 1.05)
        axes[0, j].set_title(f"{a}: resolvable waves found")
        axes[1, j].semilogy(x, np.maximum(om, 1e-9), "o-")
        axes[1, j].axhline(0.013, color="k", ls=":", lw=1)
        axes[1, j].set_title(f"{a}: MAE omega [rad/s]")
        for ax in axes[:, j]:
            ax.set_xticks(x)
            ax.set_xticklabels([str(v) for v in vals])
    benchutil.save_figure(fig, name)


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--quick", action="store_true")
    parser.add_argument("--seeds", type=int, default=0, help="problems per point (default 2; 1 with --quick)")
    parser.add_argument("--only", default=",".join(AXES))
    parser.add_argument("--no-heights", dest="heights", action="store_false",
                        help="fit from the slopes alone (fit.waves(heights=False)); "
                             "default: slopes and integrated heights")
    parser.add_argument("--name", default=NAME, help="results file stem under experiments/results (default "
                        f"{NAME}; a separate name keeps a full-size run apart from --quick rows)")
    args = parser.parse_args(argv)
    seeds = args.seeds or (1 if args.quick else 2)
    only = [a for a in args.only.split(",") if a]
    bad = set(only) - set(AXES)
    if bad:
        parser.error(f"unknown axes {sorted(bad)}; choose from {AXES}")
    out = benchutil.load_rows(args.name, {})
    res = 32 if args.quick else 64
    meta = dict(quick=args.quick, seeds=seeds, heights=args.heights,
                sea={k: float(v) for k, v in SEA._asdict().items()})

    def save(axis, rows):
        out[axis] = list(rows)
        benchutil.save(args.name, out, meta=meta)

    for a in only:
        print(f"== {a}", flush=True)
        save(a, run_axis(a, (QUICK if args.quick else VALUES)[a], seeds, args.quick, res,
                         on_row=lambda rows, a=a: save(a, rows), heights=args.heights))
        plot(out, args.name)


if __name__ == "__main__":
    main()
