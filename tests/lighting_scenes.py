"""Scenes shared by the lighting-fit and camera-fit tests: a small sea whose short waves are
sub-pixel roughness on a 16x16 image, and three lightings (the third with the sun behind the
camera)."""

import numpy as np

from jaxocean.waves import GRAVITY, make_waves


def small_sea(n=16, seed=0, scale=1.0):
    """Waves from 0.9 to 14 rad/s: the short ones are sub-pixel roughness on a 16x16 image, so
    the sun's glitter is a broad, visible lobe."""
    rng = np.random.default_rng(seed)
    om = np.geomspace(0.9, 14.0, n)
    amp = scale * rng.uniform(0.5, 1.0, n) * 0.25 / 6 * GRAVITY / om**2
    return make_waves(amp, om, rng.uniform(-0.6, 0.6, n) + 0.3, rng.uniform(0, 2 * np.pi, n))


TRUTHS = [
    dict(sun_azimuth=0.05, sun_elevation=0.25, sun_color=(20.0, 18.0, 15.0), sky_color=(0.35, 0.55, 0.9),
         sea_color=(0.01, 0.04, 0.06)),
    dict(sun_azimuth=-0.15, sun_elevation=0.12, sun_color=(8.0, 5.0, 3.0), sky_color=(0.6, 0.5, 0.4),
         sea_color=(0.03, 0.02, 0.05)),
    # sun behind the camera: no glitter in view, the direction is undetermined
    dict(sun_azimuth=3.0, sun_elevation=0.5, sun_color=(20.0, 18.0, 15.0), sky_color=(0.35, 0.55, 0.9),
         sea_color=(0.01, 0.04, 0.06)),
]
