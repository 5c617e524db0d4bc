"""Horizon: pitch and roll recovered from synthetic sky/sea images cast through a distorting lens."""

import math

import numpy as np
import pytest
from scipy.ndimage import gaussian_filter

from jaxocean import horizon, lens
from jaxocean.errors import InvalidValueError

W, H = 320, 240
INTRINSICS = lens.Intrinsics(188.2, 188.3, 161.6, 119.5)
DISTORTION = lens.Distortion(-0.21, 0.062)  # the strong barrel distortion of the ship camera


def _image(pitch, roll, height=12.0, *, sky=True, seed=0):
    """A bright sky above the visible horizon of the pose, a dark textured sea with a few
    whitecaps below it, noise and black corners (vignetting), cast pixel by pixel through the
    lens. The edge is box-filtered over the pixel's vertical extent (anti-aliased)."""
    pose = lens.Pose(height, pitch, roll, 0.7)
    v, u = np.mgrid[0:H, 0:W]
    uv = np.stack([u, v], -1).astype(np.float64)
    elevation = [np.arcsin(np.asarray(lens.pixel_rays(uv + [0.0, dv], pose, INTRINSICS, DISTORTION))[..., 2])
                 for dv in (0.0, -0.5, 0.5)]
    rate = elevation[1] - elevation[2]  # elevation change over one pixel, upwards
    sky_fraction = np.clip((elevation[0] + horizon.dip(height)) / rate + 0.5, 0.0, 1.0) if sky else 0.0
    rng = np.random.default_rng(seed)
    sea = 0.15 + 0.2 * gaussian_filter(rng.standard_normal((H, W)), 2.0)
    for _ in range(6):  # whitecaps: bright blobs in the sea
        cu, cv = rng.uniform(0, W), rng.uniform(H / 2, H)
        sea = np.where(np.hypot(u - cu, (v - cv) * 2) < 8, 0.9, sea)
    image = sky_fraction * 0.95 + (1 - sky_fraction) * sea + 0.02 * rng.standard_normal((H, W))
    image[np.hypot(u - W / 2, v - H / 2) > 0.58 * W] = 0.0  # black corners, over the horizon's ends
    return np.clip(image, 0.0, 1.0)


def test_dip_of_the_visible_horizon():
    assert horizon.dip(12.0) == pytest.approx(math.acos(6.371e6 / (6.371e6 + 12.0)))
    assert horizon.dip(12.0) == pytest.approx(0.00194, abs=1e-5)
    with pytest.raises(ValueError, match="height"):
        horizon.dip(0.0)


@pytest.mark.parametrize("pitch, roll", [(0.30, 0.05), (0.25, -0.08), (0.36, 0.0)])
def test_pitch_and_roll_recovered_through_a_distorting_lens(pitch, roll):
    image = _image(pitch, roll)
    fit = horizon.estimate_horizon(image, INTRINSICS, DISTORTION, 12.0)
    assert fit.success, fit.message
    assert abs(fit.pitch - pitch) < 0.002 and abs(fit.roll - roll) < 0.002
    assert fit.rms_px < 0.5 and fit.n_points >= 0.6 * 160
    assert fit.points.shape == (len(fit.inliers), 2)
    # a RGB version of the same image gives the same answer (luminance of equal channels)
    rgb = horizon.estimate_horizon(np.repeat(image[..., None], 3, -1), INTRINSICS, DISTORTION, 12.0)
    assert rgb.pitch == pytest.approx(fit.pitch, abs=1e-6) and rgb.roll == pytest.approx(fit.roll, abs=1e-6)


def test_the_dip_is_part_of_the_pitch():
    # from 1000 m the horizon is 0.0177 rad below the horizontal: the fit recovers the pitch
    # with the right height and is off by about the difference in dip with a wrong one
    image = _image(0.30, 0.05, height=1000.0)
    right = horizon.estimate_horizon(image, INTRINSICS, DISTORTION, 1000.0)
    wrong = horizon.estimate_horizon(image, INTRINSICS, DISTORTION, 12.0)
    assert right.success and abs(right.pitch - 0.30) < 0.002
    assert 0.8 < (right.pitch - wrong.pitch) / (horizon.dip(1000.0) - horizon.dip(12.0)) < 1.25


def test_no_horizon_is_reported_as_failure():
    sea_only = horizon.estimate_horizon(_image(0.3, 0.05, sky=False), INTRINSICS, DISTORTION, 12.0)
    assert not sea_only.success and sea_only.message.startswith("no reliable horizon")
    flat = horizon.estimate_horizon(np.full((H, W), 0.3), INTRINSICS, DISTORTION, 12.0)
    assert not flat.success and "no horizon" in flat.message and math.isnan(flat.pitch)
    with pytest.raises(ValueError, match="gray"):
        horizon.estimate_horizon(np.zeros((4, 5, 2)), INTRINSICS, DISTORTION, 12.0)


def test_too_small_an_image_is_named_as_such():
    # "stride and step must be >= 1 and 2 step + 2 <= H" named options the caller never gave
    intr, dist = lens.Intrinsics(4.0, 4.0, 2.0, 2.0), lens.Distortion()
    with pytest.raises(ValueError, match=r"^the image is too small to find a horizon in: 4 rows \(of 4 columns\); "
                                         r"the edge scan needs at least 6 rows$"):
        horizon.estimate_horizon(np.ones((4, 4)), intr, dist, 10.0)
    with pytest.raises(ValueError, match=r"needs at least 8 rows \(2 step \+ 2 with step=3\)$"):
        horizon.horizon_points(np.ones((4, 4)), step=3)
    with pytest.raises(ValueError, match=r"stride and step must be >= 1; got stride=0"):
        horizon.horizon_points(np.ones((8, 8)), stride=0)


def test_a_lens_that_folds_back_inside_the_image_is_refused():
    # the camera-file reader refused such a lens, but estimate_horizon reported success: the
    # edge points beyond the fold undistort to meaningless rays
    intr = lens.Intrinsics(1400.0, 1400.0, 959.5, 539.5)  # a 1920 x 1080 camera
    image = np.full((1080, 1920), 0.15)
    image[:540] = 0.95  # a clean, level horizon through the principal point: success without the check
    with pytest.raises(InvalidValueError, match=r"^estimate_horizon: the lens distortion k1 = -1, k2 = 0 is not "
                                                r"one-to-one over the image: the distortion folds back"):
        horizon.estimate_horizon(image, intr, lens.Distortion(-1.0, 0.0), 12.0)
    # the same lens over the middle 160 x 160 pixels has a ray for every pixel
    small = horizon.estimate_horizon(image[460:620, 880:1040], intr._replace(cx=79.5, cy=79.5),
                                     lens.Distortion(-1.0, 0.0), 12.0)
    assert small.success, small.message
