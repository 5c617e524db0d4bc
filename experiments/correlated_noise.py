"""Wave fitting on normals whose errors are smooth across the image (a network's kind of error).

The base problem of ``stability_waves.py`` (a 15-wave JONSWAP sea, Hs 0.6 m, Tp 4 s, seen
from a perspective camera 10 m high, 64^2 pixels, 10 frames 0.15 s apart, the normals as
`render` draws them, at most ``MAX_WAVES`` = 32 waves) with Gaussian noise of sigma per
normal component, correlated across the image as ``exp(-d / l)`` over ``d`` pixels and
independent between frames (drawn by FFT with the field's power spectrum
``(1 + (kappa l)^2)^(-3/2)``). Each noisy sequence is
fitted twice, told the noise sigma both times: as independent pixels (``white``) and with
its correlation length (``aware``: ``noise_correlation=l``), and the noise-free sequence
once (``reference``). Scored against the waves the image resolves (found, spurious, as in
``stability_waves.py``), by success, and against every true wave (``unmatched``: fitted waves that
match none; the noise-free fit has a few, stand-ins for waves the view does not resolve).
A *wrong success*: success reported with more unmatched waves than the noise-free fit has.

Usage: ``python experiments/correlated_noise.py [--seeds K] [--quick]``; writes
``experiments/results/correlated_noise.json`` and ``.png``.
"""

from __future__ import annotations

import argparse
import json
import sys
import time

import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402
import stability_waves as sw  # noqa: E402

from jaxocean import fit  # noqa: E402
from jaxocean.errors import InvalidValueError  # noqa: E402
from jaxocean.fit import waves_fit as fw  # noqa: E402

SIGMAS = (0.01, 0.03)
LENGTHS = (2.0, 6.0)
RES, FRAMES, N_WAVES = 64, 10, 15
#: the order selection's cap (some 10 of the 15 waves are resolvable: a fit at the cap has
#: taken noise for waves, and reports failure)
MAX_WAVES = 32


def smooth_noise(shape, sigma, length, seed):
    """``shape = (T, H, W, 2)`` Gaussian fields of standard deviation ``sigma``, correlated as
    ``exp(-d / length)`` over ``d`` pixels in ``(H, W)``, independent per frame and component."""
    T, H, W, C = shape
    rng = np.random.default_rng(seed)
    Hp, Wp = 2 * H, 2 * W  # padded: the periodic field's wrap-around stays outside the crop
    ky = 2 * np.pi * np.fft.fftfreq(Hp)[:, None]
    kx = 2 * np.pi * np.fft.fftfreq(Wp)[None, :]
    amplitude = (1.0 + (ky ** 2 + kx ** 2) * length ** 2) ** -0.75
    white = rng.standard_normal((T, C, Hp, Wp))
    field = np.real(np.fft.ifft2(np.fft.fft2(white) * amplitude))[:, :, :H, :W]
    field = np.moveaxis(field, 1, -1)
    return sigma * field / field.std()


def _scored(truth, camera, normals, rough, times, **kw):
    """One fit: found and spurious against the resolvable waves, ``unmatched`` against all."""
    ok = np.asarray(fw.resolvable(truth, camera))
    visible = type(truth)(*(np.asarray(x)[ok] for x in truth))
    t0 = time.perf_counter()
    try:
        r = fit.waves(normals, rough, camera, times, max_waves=MAX_WAVES, **kw)
    except InvalidValueError:  # no wave found: a measured outcome
        return dict(n_resolvable=int(ok.sum()), n_fitted=0, found=0.0, spurious=0, unmatched=0, success=False,
                    time_s=time.perf_counter() - t0)
    wall = time.perf_counter() - t0
    m = fw.match(r.waves, visible)
    return dict(n_resolvable=int(ok.sum()), n_fitted=int(r.n_waves), found=float(m.true_index.size / max(ok.sum(), 1)),
                spurious=int(m.spurious.size), unmatched=int(fw.match(r.waves, truth).spurious.size),
                success=bool(r.success), time_s=wall)


def problem(seed):
    truth = sw.sampled(seed, N_WAVES)
    camera = sw.base_camera(RES)
    times = np.arange(FRAMES) * 0.15
    normals, rough = fw.predict(truth, camera, times, surface="auto")
    return truth, camera, times, normals, rough


def reference(seed):
    truth, camera, times, normals, rough = problem(seed)
    row = _scored(truth, camera, normals, rough, times)
    row.update(seed=seed, sigma=0.0, length_px=0.0, fit="reference", wrong_success=False)
    return row


def run(seed, sigma, length, unmatched_reference):
    truth, camera, times, normals, rough = problem(seed)
    noisy = np.asarray(normals, np.float64)
    noisy[..., :2] += smooth_noise(noisy[..., :2].shape, sigma, length, 100 + seed)
    noisy = (noisy / np.linalg.norm(noisy, axis=-1, keepdims=True)).astype(np.float32)
    rows = []
    for kind, ell in (("white", 0.0), ("aware", length)):
        row = _scored(truth, camera, noisy, rough, times, noise=sigma, noise_correlation=ell)
        row.update(seed=seed, sigma=sigma, length_px=length, fit=kind,
                   wrong_success=bool(row["success"] and row["unmatched"] > unmatched_reference))
        rows.append(row)
    return rows


def _reference_unmatched(rows, seed):
    return next(r["unmatched"] for r in rows if r["fit"] == "reference" and r["seed"] == seed)


def chart(rows, path):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from jaxocean import plots

    fig, axes = plt.subplots(1, 3, figsize=(14, 4))
    cases = sorted({(r["sigma"], r["length_px"]) for r in rows if r["fit"] != "reference"})
    x = np.arange(len(cases))
    labels = [f"sigma {s:g}\nl {ell:g} px" for s, ell in cases]
    for j, (kind, offset) in enumerate((("white", -0.18), ("aware", 0.18))):
        for ax, key, title in ((axes[0], "spurious", "spurious waves (mean over seeds)"),
                               (axes[1], "found", "resolvable waves found (fraction)"),
                               (axes[2], "wrong_success", "wrong successes (fraction of seeds)")):
            vals = [np.mean([float(r[key]) for r in rows if (r["sigma"], r["length_px"]) == c and r["fit"] == kind])
                    for c in cases]
            ax.bar(x + offset, vals, width=0.36, label="independent pixels" if kind == "white" else
                   "noise_correlation = l")
            ax.set_title(title)
            ax.set_xticks(x, labels, fontsize=7)
    axes[0].legend(fontsize=8)
    fig.suptitle(f"fit.waves on {RES}^2 x {FRAMES} frames of a {N_WAVES}-wave sea with noise smooth over l pixels")
    fig.tight_layout()
    return plots.save_figure(fig, path)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, default=1)
    ap.add_argument("--quick", action="store_true", help="one seed, sigma 0.01, l 4 px")
    args = ap.parse_args(argv)
    sigmas, lengths, seeds = ((0.01,), (4.0,), 1) if args.quick else (SIGMAS, LENGTHS, args.seeds)
    name = "correlated_noise_quick" if args.quick else "correlated_noise"
    rows = []
    columns = ["sigma", "length_px", "seed", "fit", "n_resolvable", "n_fitted", "found", "spurious", "unmatched",
               "success", "wrong_success", "time_s"]
    for seed in range(seeds):
        rows.append(reference(seed))
        benchutil.print_table(rows[-1:], columns)
        for sigma in sigmas:
            for length in lengths:
                rows += run(seed, sigma, length, _reference_unmatched(rows, seed))
                benchutil.print_table(rows[-2:], columns)
                benchutil.RESULTS.mkdir(exist_ok=True)
                (benchutil.RESULTS / f"{name}.json").write_text(json.dumps(dict(rows=rows), indent=1))
    chart(rows, benchutil.RESULTS / f"{name}.png")


if __name__ == "__main__":
    sys.exit(main())
