"""Gallery: a contact sheet of rendered scenes with their normal and roughness maps.

Scenes: calm and windy seas, low and high sun, near and far cameras. Each row shows the
tone-mapped image, the normal map and the roughness map; the frames are also written as
OpenEXR (linear radiance + geometry channels) beside the sheet.

Usage: ``python experiments/gallery.py [--res 160x240]``; writes
``experiments/results/gallery.png`` and ``experiments/results/gallery/*.exr``.
"""

from __future__ import annotations

import argparse
import sys

import jax
import numpy as np

sys.path.insert(0, __file__.rsplit("/", 1)[0])
import benchutil  # noqa: E402

from jaxocean import camera, plots, render, shading, spectrum  # noqa: E402
from jaxocean.io import write_frame  # noqa: E402

SCENES = [
    # name, (hs, tp, gamma), camera (height, pitch deg, fov deg), sun (azimuth deg, elevation deg)
    ("calm sea, high sun, near", (0.3, 3.5, 3.3), (6.0, 25.0, 50.0), (0.0, 55.0)),
    ("calm sea, low sun, far", (0.3, 3.5, 3.3), (40.0, 12.0, 40.0), (0.0, 12.0)),
    ("windy sea, high sun, near", (2.2, 7.0, 2.0), (12.0, 30.0, 50.0), (20.0, 50.0)),
    ("windy sea, low sun, far", (2.2, 7.0, 2.0), (60.0, 10.0, 40.0), (-5.0, 8.0)),
    ("swell, sun near zenith, top-down", (1.0, 8.0, 5.0), (25.0, 90.0, 50.0), (90.0, 75.0)),
]


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--res", default="160x240")
    ap.add_argument("--waves", type=int, default=120)
    args = ap.parse_args(argv)
    res = tuple(int(v) for v in args.res.split("x"))
    out_dir = benchutil.RESULTS / "gallery"
    rows, titles = [], []
    for i, (name, (hs, tp, gamma), (height, pitch, fov), (az, el)) in enumerate(SCENES):
        sea = spectrum.Spectrum(hs=hs, tp=tp, gamma=gamma, theta_mean=0.3, s_max=12.0)
        waves = spectrum.sample_waves(jax.random.key(i), sea, args.waves).waves
        cam = camera.make_camera(height=height, pitch=np.deg2rad(min(pitch, 89.9)), fov=np.deg2rad(fov),
                                 resolution=res)
        light = shading.make_lighting(sun_azimuth=np.deg2rad(az), sun_elevation=np.deg2rad(el))
        plan = render.plan(waves, cam, refine=0)
        geo = render.geometry(waves, cam, 0.0, plan=plan)
        img = render.shade(geo.normal, geo.roughness, cam, light, slope_variance=geo.slope_variance)
        write_frame(out_dir / f"scene_{i}.exr", np.asarray(img), geo, {"name": name})
        rows.append([plots.display(img), plots.normal_to_rgb(geo.normal, geo.mask),
                     plots.roughness_to_rgb(geo.roughness, geo.mask)])
        titles.append(f"{name}\n{len(plan.active)}/{args.waves} waves need sines")
        print(f"{name}: {len(plan.active)} of {args.waves} waves resolved somewhere in the image")
    path = plots.contact_sheet(benchutil.RESULTS / "gallery.png", rows,
                               col_titles=["image (Bruneton tone map)", "normal", "roughness (log10 sigma^2)"],
                               row_titles=titles, title="jaxocean gallery")
    print("wrote", path, "and", out_dir)


if __name__ == "__main__":
    main()
