"""Heights from normals (:func:`jaxocean.fit.heights`) on the Table 2 dataset scenes.

What it measures, per scene and frame (noise-free geometry as the dataset writes it, 128²,
10 frames, :func:`wave_fit.dataset_scene`; the truth from ``render.geometry``'s converged
hits):

* the height error [m rms over valid pixels] after removing its mean: what the normals
  determine;
* that mean, the window's *level* (the true mean height over the valid pixels): what they
  do not;
* the distance [m rms] from each pixel's true hit to three estimates of it: the mean-sea-plane
  hit (what the rows path of ``fit.waves`` assumes), the integrated hit, and the integrated
  hit moved along its ray by the true level (what a model of the level would add);
* the same three against the pixel's true *rest* position (the trochoid's own coordinates,
  which a wave model evaluates at): the horizontal displacement of the waves is left in;
* the time per frame.

Usage: ``python experiments/height_integration.py [--scenes N]``; writes
``experiments/results/height_integration.json`` and ``.png``.
"""

from __future__ import annotations

import argparse
import sys
import time

import jax
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402
from wave_fit import dataset_scene  # noqa: E402

from jaxocean import camera as cam  # noqa: E402
from jaxocean import fit, render  # noqa: E402

NAME = "height_integration"
NEAR_FOOTPRINT = 0.5  # [m]: the near field, where the pixels sample the resolved waves finely


def rms(e, ok):
    return float(np.sqrt(np.mean(np.sum(np.atleast_3d(e) ** 2, -1)[ok])))


def _errors(hm, i, true, ok, plane, q) -> dict:
    pos = np.asarray(true.position, np.float64)
    rest = np.asarray(true.xy, np.float64)
    z = np.asarray(hm.z[i], np.float64)
    level = float(np.mean(pos[..., 2][ok]))
    err = (z - pos[..., 2])[ok]
    xy = np.asarray(hm.xy[i], np.float64)
    leveled = xy + (level - float(np.mean(z[ok]))) * q
    return dict(z_error_m=float(np.sqrt(np.mean((err - err.mean()) ** 2))), level_m=level,
                level_error_m=float(err.mean()), z_std_m=float(np.std(pos[..., 2][ok])),
                hit_error_plane_m=rms(plane - pos[..., :2], ok), hit_error_integrated_m=rms(xy - pos[..., :2], ok),
                hit_error_leveled_m=rms(leveled - pos[..., :2], ok),
                rest_error_plane_m=rms(plane - rest, ok), rest_error_integrated_m=rms(xy - rest, ok),
                rest_error_leveled_m=rms(leveled - rest, ok), pixels=int(ok.sum()),
                converged=bool(hm.converged[i]), residual=float(hm.residual[i]))


def measure(seed: int) -> dict:
    scene, geo = dataset_scene(seed, 128)
    camera = scene.camera
    hm = jax.block_until_ready(fit.heights(geo.normal, camera))  # compiles
    t0 = time.perf_counter()
    hm = jax.block_until_ready(fit.heights(geo.normal, camera))
    seconds = (time.perf_counter() - t0) / len(scene.times)
    plane = np.asarray(cam.intersect_sea(camera).xy, np.float64)
    _, direction = cam.pixel_rays(camera)
    d = np.asarray(direction, np.float64)
    q = d[..., :2] / np.where(np.abs(d[..., 2:3]) > 1e-9, d[..., 2:3], -1.0)
    footprint = np.asarray(cam.intersect_sea(camera).footprint, np.float64)
    frames = []
    for i, t in enumerate(np.asarray(scene.times)):
        true = render.geometry(scene.waves, camera, t)
        valid = np.asarray(hm.valid[i]) & np.asarray(true.converged) & np.asarray(true.mask)
        frame = {}
        for region, ok in (("near", valid & (footprint <= NEAR_FOOTPRINT)), ("all", valid)):
            frame.update({f"{region}_{k}" if k.endswith("_m") or k == "pixels" else k: v for k, v in
                          _errors(hm, i, true, ok, plane, q).items()})
        frames.append(frame)
    summary = {k: float(np.median([f[k] for f in frames])) for k in frames[0] if k.endswith(("_m", "pixels"))}
    return dict(seed=seed, hs=float(scene.spectrum.hs),
                camera_height=float(camera.height), camera_pitch=float(camera.pitch),
                seconds_per_frame=seconds, all_converged=all(f["converged"] for f in frames),
                median=summary, frames=frames)


def chart(rows) -> None:
    plt = benchutil.pyplot()
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    x = np.arange(len(rows))
    labels = [f"{r['seed']}" for r in rows]
    ax = axes[0]
    for key, label in (("all_z_std_m", "height std (truth)"), ("all_level_m", "|window level| (lost)"),
                       ("near_z_error_m", "height error after the level: near field"),
                       ("all_z_error_m", "the same: every pixel")):
        vals = [abs(r["median"][key]) for r in rows]
        ax.semilogy(x, vals, "o-", label=label)
    ax.set_xticks(x, labels)
    ax.set_xlabel("Table 2 scene (seed)")
    ax.set_ylabel("m (median over 10 frames)")
    ax.set_title("heights from normals")
    ax.legend(fontsize=8)
    ax = axes[1]
    w = 0.13
    for j, (key, label) in enumerate((("near_hit_error_plane_m", "hit: plane"),
                                      ("near_hit_error_integrated_m", "hit: integrated"),
                                      ("near_hit_error_leveled_m", "hit: integrated + true level"),
                                      ("near_rest_error_plane_m", "rest: plane"),
                                      ("near_rest_error_integrated_m", "rest: integrated"),
                                      ("near_rest_error_leveled_m", "rest: integrated + true level"))):
        ax.bar(x + (j - 2.5) * w, [r["median"][key] for r in rows], w, label=label)
    ax.set_xticks(x, labels)
    ax.set_xlabel("Table 2 scene (seed)")
    ax.set_ylabel("position error [m rms]")
    ax.set_title(f"where each ray meets the sea (footprint <= {NEAR_FOOTPRINT} m)")
    ax.legend(fontsize=7)
    benchutil.save_figure(fig, NAME)


def main(argv=None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scenes", type=int, default=8)
    args = parser.parse_args(argv)
    rows = []
    for seed in range(args.scenes):
        rows.append(measure(seed))
        m = rows[-1]["median"]
        print(f"scene {seed}: z err near {m['near_z_error_m']:.4f} all {m['all_z_error_m']:.4f} m "
              f"(std {m['all_z_std_m']:.3f}, level {m['all_level_m']:+.3f}, level err near "
              f"{m['near_level_error_m']:+.3f}); near hit err plane {m['near_hit_error_plane_m']:.3f} "
              f"integrated {m['near_hit_error_integrated_m']:.3f} +level {m['near_hit_error_leveled_m']:.3f}; "
              f"near rest err plane {m['near_rest_error_plane_m']:.3f} integrated "
              f"{m['near_rest_error_integrated_m']:.3f}; near pixels {m['near_pixels']:.0f}; "
              f"{rows[-1]['seconds_per_frame'] * 1e3:.0f} ms/frame", flush=True)
        benchutil.save(NAME, rows)
    chart(rows)


if __name__ == "__main__":
    main()
