"""jaxocean.rectify: real (rolled, distorted, heaving) frames <-> the library's virtual camera.

The scenes are analytic: the sea is a texture on the plane z = 0 and the sky a function of
direction, so every camera's true image is known exactly and the only error left is the
resampling's."""

import math
import os
import time

import jax.numpy as jnp
import numpy as np
import pytest

from jaxocean import camera as cam
from jaxocean import lens, rectify
from jaxocean.io.camera_file import CameraFile
from jaxocean.lens import Distortion, Intrinsics, Pose

# A quarter-size version of a ship-borne 640 x 480 camera with strong barrel distortion.
W_REAL, H_REAL = 160, 120
K_REAL = Intrinsics(94.12, 94.15, 80.54, 59.74)
D_REAL = Distortion(-0.21, 0.062)
POSES = Pose(
    height=np.array([12.0, 13.9, 10.3]),
    pitch=np.array([0.31, 0.27, 0.34]),
    roll=np.array([math.radians(4), -0.03, 0.05]),
    heading=np.array([1.0, 1.06, 0.95]),
    east=np.array([0.0, 1.2, -0.8]),
    north=np.array([0.0, -0.5, 0.9]),
)


def _sea_texture(xy):
    """Smooth brightness of the sea plane: wavelengths of 53 to 89 m, longer than a pixel's
    footprint in range out to 100 m (d^2 / h x pixel angle: 20 m for the virtual cameras)."""
    x, y = xy[..., 0], xy[..., 1]
    return 0.5 + 0.2 * np.sin(2 * np.pi * x / 67.0) * np.cos(2 * np.pi * y / 53.0) + 0.1 * np.sin(2 * np.pi * (x + y) / 89.0)


def _sky_texture(d):
    """Brightness of the sky by direction: elevation and azimuth gradients."""
    elevation = np.arcsin(np.clip(d[..., 2], -1, 1))
    azimuth = np.arctan2(d[..., 1], d[..., 0])
    return 2.0 + 3.0 * elevation + 0.5 * np.sin(3 * azimuth)


def _truth(origin, directions):
    """True image of rays from ``origin``: sea texture where they hit z = 0, else sky; also
    the hit distance (inf for sky)."""
    down = directions[..., 2] < -cam.DOWNWARD_THRESHOLD
    t = np.where(down, origin[2] / np.where(down, -directions[..., 2], 1), np.inf)
    hit = origin + np.where(down, t, 0)[..., None] * directions
    return np.where(down, _sea_texture(hit[..., :2]), _sky_texture(directions)), t


def _real_frames(poses=POSES):
    """Analytic real frames ``(T, H_REAL, W_REAL)`` and their hit distances."""
    v, u = np.meshgrid(np.arange(H_REAL, dtype=float), np.arange(W_REAL, dtype=float), indexing="ij")
    frames, distances = [], []
    for t in range(len(poses.height)):
        pose = Pose(*(leaf[t] for leaf in poses))
        rays = np.asarray(lens.pixel_rays(np.stack([u, v], -1), pose, K_REAL, D_REAL))
        image, distance = _truth(np.array([pose.east, pose.north, pose.height]), rays)
        frames.append(image)
        distances.append(distance)
    return np.stack(frames), np.stack(distances)


def _virtual_truth(camera):
    origin, directions = cam.pixel_rays(camera)
    return _truth(np.asarray(origin, np.float64), np.asarray(directions, np.float64))


def _near_horizon(camera, rows=2):
    """Virtual pixels within ``rows`` of the horizon, where sea and sky textures jump."""
    H, W = camera.resolution
    return np.abs(np.arange(H)[:, None] - float(cam.horizon_row(camera))) < rows + np.zeros((1, W))


def test_virtual_camera_from_poses_and_from_a_camera_file(tmp_path):
    camera = rectify.virtual_camera(POSES, K_REAL, (W_REAL, H_REAL), resolution=(48, 64))
    assert camera.resolution == (48, 64) and camera.projection == "perspective"
    assert float(camera.height) == pytest.approx(POSES.height.mean(), rel=1e-6)
    assert float(camera.pitch) == pytest.approx(POSES.pitch.mean(), rel=1e-6)
    assert float(camera.x) == pytest.approx(POSES.east.mean(), abs=1e-6)
    assert float(camera.y) == pytest.approx(POSES.north.mean(), abs=1e-6)
    assert float(camera.yaw) == pytest.approx(math.pi / 2 - POSES.heading.mean(), abs=1e-5)
    assert float(camera.fov) == pytest.approx(2 * math.atan(H_REAL / (2 * K_REAL.fy)), rel=1e-6)
    file = CameraFile(path=tmp_path / "camera.json", image_size=(W_REAL, H_REAL), intrinsics=K_REAL,
                      distortion=D_REAL, files=(), times=np.arange(3.0), poses=POSES)
    same = rectify.virtual_camera(file, resolution=(48, 64), fov=0.9)
    assert float(same.height) == float(camera.height) and float(same.fov) == pytest.approx(0.9)
    with pytest.raises(ValueError, match="CameraFile alone"):
        rectify.virtual_camera(file, K_REAL, (W_REAL, H_REAL), resolution=(48, 64))
    with pytest.raises(ValueError, match="need intrinsics"):
        rectify.virtual_camera(POSES, resolution=(48, 64))


def test_circular_mean_heading():
    poses = POSES._replace(heading=np.array([6.2, 0.1, 0.05]))  # across north
    camera = rectify.virtual_camera(poses, K_REAL, (W_REAL, H_REAL), resolution=(8, 8))
    expected = math.atan2(np.sin(poses.heading).mean(), np.cos(poses.heading).mean())
    assert float(lens.heading_from_yaw(camera.yaw)) == pytest.approx(expected % (2 * math.pi), abs=1e-5)
    assert abs(expected) < 0.1


def test_identity(x64):
    # the real camera is the virtual camera: rectify returns the image to interpolation accuracy
    camera = cam.make_camera(12.0, 0.3, 0.5, 0.9, (48, 64), x=1.0, y=2.0, dtype=np.float64)
    pose, K = lens.pose_of(camera), lens.pinhole_intrinsics(camera)
    truth, _ = _virtual_truth(camera)
    images = np.stack([truth, 2 * truth])
    out = rectify.rectify(images, Pose(*(float(v) for v in pose)), K, Distortion(), camera)
    assert out.images.shape == (2, 48, 64) and out.valid.shape == (2, 48, 64)
    assert bool(out.valid.all())
    np.testing.assert_allclose(out.images, images, atol=1e-9)
    # the supersampling factor for a 1:1 mapping is 1
    assert rectify.supersample_factor(Pose(*(float(v) for v in pose)), K, Distortion(), (64, 48), camera) == 1


def test_rectify_real_frames_matches_the_virtual_truth():
    frames, _ = _real_frames()
    camera = rectify.virtual_camera(POSES, K_REAL, (W_REAL, H_REAL), resolution=(48, 64))
    # one sample per pixel: the truth is the texture at the pixel centre, not an average
    out = rectify.rectify(frames, POSES, K_REAL, D_REAL, camera, image_size=(W_REAL, H_REAL), supersample=1)
    truth, distance = _virtual_truth(camera)
    compare = np.asarray(out.valid) & ~_near_horizon(camera) & ((distance < 100) | ~np.isfinite(distance))
    assert compare.mean() > 0.6
    error = np.abs(np.asarray(out.images) - truth)[np.asarray(compare)]
    # measured: 3.5e-5 median, 0.023 max (sea values 0.2-0.8, sky 2-5): bilinear
    # interpolation of the real frames only
    assert np.median(error) < 2e-4 and error.max() < 0.05
    # the same without the lens model is wrong by far more: the check has teeth
    wrong = rectify.rectify(frames, POSES, K_REAL, Distortion(), camera, supersample=1)
    both = np.asarray(compare & wrong.valid)
    # (measured 0.0092 median)
    assert np.median(np.abs(np.asarray(wrong.images) - truth)[both]) > 20 * np.median(error)


def test_round_trip_through_a_rolled_distorted_camera():
    # render with the library camera, warp into a real camera (roll 4 deg, k1 = -0.21,
    # 1.9 m higher), rectify back, compare on valid interior pixels
    camera = cam.make_camera(12.0, 0.31, math.pi / 2 - 1.0, 0.9, (60, 80))
    truth, distance = _virtual_truth(camera)
    pose = Pose(13.9, 0.33, math.radians(4), 1.03, 0.7, -0.4)
    real = rectify.warp_to_frame(truth, pose, K_REAL, D_REAL, (W_REAL, H_REAL), camera, supersample=1)
    assert real.images.shape == (H_REAL, W_REAL) and real.valid.shape == (H_REAL, W_REAL)
    back = rectify.rectify(real.images[None], pose, K_REAL, D_REAL, camera, source_mask=np.asarray(real.valid),
                           supersample=1)
    interior = np.asarray(back.valid[0]) & ~_near_horizon(camera, rows=3) & (distance < 100)
    assert interior.mean() > 0.5
    error = np.abs(np.asarray(back.images[0]) - truth)[interior]
    # measured: 1.8e-4 median, 0.035 max (two bilinear resamplings)
    assert np.median(error) < 1e-3 and error.max() < 0.06
    # and the warped frame itself is the real camera's analytic image
    frames, real_distance = _real_frames(Pose(*([v] for v in pose)))
    inside = np.asarray(real.valid) & (real_distance[0] < 100)
    # measured: 1.5e-4 median
    assert np.median(np.abs(np.asarray(real.images) - frames[0])[inside]) < 1e-3


def test_sky_maps_by_direction_only():
    # frames at very different heights and positions: the sky is unchanged by them
    poses = POSES._replace(height=np.array([5.0, 40.0, 12.0]), east=np.array([0.0, 300.0, -50.0]))
    frames, distance = _real_frames(poses)
    camera = rectify.virtual_camera(poses, K_REAL, (W_REAL, H_REAL), resolution=(48, 64))
    out = rectify.rectify(frames, poses, K_REAL, D_REAL, camera)
    truth, v_distance = _virtual_truth(camera)
    sky = np.asarray(out.valid) & ~np.isfinite(v_distance)[None] & ~_near_horizon(camera, rows=4)[None]
    assert sky.sum() > 500
    # each frame's sky region shows the same directions (the texture is exact there)
    for t in range(3):
        assert np.median(np.abs(np.asarray(out.images[t]) - truth)[sky[t]]) < 0.01


def test_valid_mask_is_the_frame_footprint():
    # a virtual camera wider than the real one: what the real frame does not see is invalid
    pose = Pose(12.0, 0.3, math.radians(4), 1.0)
    camera = cam.make_camera(12.0, 0.3, math.pi / 2 - 1.0, 1.6, (48, 64))
    frames = np.ones((1, H_REAL, W_REAL))
    out = rectify.rectify(frames, pose, K_REAL, D_REAL, camera, supersample=1)
    valid = np.asarray(out.valid[0])
    assert valid[24, 32] and not valid[0, 0] and not valid[-1, -1]
    # independently: project every virtual pixel centre (sea by its hit, sky by direction)
    hit = cam.intersect_sea(camera)
    origin = np.asarray(cam.camera_position(camera), np.float64)
    points = np.where(np.asarray(hit.mask)[..., None],
                      np.concatenate([np.asarray(hit.xy), np.zeros((48, 64, 1))], -1),
                      origin + 1e9 * np.asarray(hit.direction))
    uv, in_front = lens.project(points, pose, K_REAL, D_REAL)
    uv = np.asarray(uv)
    expected = (np.asarray(in_front) & (uv[..., 0] >= -0.5) & (uv[..., 0] <= W_REAL - 0.5)
                & (uv[..., 1] >= -0.5) & (uv[..., 1] <= H_REAL - 0.5))
    assert 0.2 < expected.mean() < 0.9
    # ties at the border may round either way in float32
    assert np.mean(valid != expected) < 0.01
    # invalid pixels hold 0, valid ones the frame's 1
    np.testing.assert_allclose(np.asarray(out.images[0])[valid], 1.0, rtol=1e-6)
    assert np.all(np.asarray(out.images[0])[~valid] == 0)


def test_source_mask_and_channels():
    frames, _ = _real_frames()
    camera = rectify.virtual_camera(POSES, K_REAL, (W_REAL, H_REAL), resolution=(48, 64))
    colour = np.stack([frames, 2 * frames, 3 * frames], axis=-1)
    out = rectify.rectify(colour, POSES, K_REAL, D_REAL, camera)
    grey = rectify.rectify(frames, POSES, K_REAL, D_REAL, camera)
    assert out.images.shape == (3, 48, 64, 3)
    np.testing.assert_allclose(out.images[..., 2], 3 * np.asarray(grey.images), rtol=1e-5, atol=1e-6)
    np.testing.assert_array_equal(out.valid, grey.valid)
    mask = np.ones((H_REAL, W_REAL), bool)
    mask[:, W_REAL // 2:] = False  # the right half of every frame is unusable
    masked = rectify.rectify(frames, POSES, K_REAL, D_REAL, camera, source_mask=mask)
    fraction = np.asarray(masked.valid).mean() / np.asarray(grey.valid).mean()
    assert 0.3 < fraction < 0.7
    assert not np.asarray(masked.valid)[:, 24, -5:].any()  # the right side is gone
    assert not (np.asarray(masked.valid) & ~np.asarray(grey.valid)).any()
    # a NaN source pixel makes the outputs it feeds invalid (they were valid NaN)
    holed = np.array(frames)
    holed[:, H_REAL // 2, W_REAL // 2] = np.nan
    out = rectify.rectify(holed, POSES, K_REAL, D_REAL, camera)
    lost = np.asarray(grey.valid) & ~np.asarray(out.valid)
    assert 0 < lost.sum() <= 3 * 16 and np.all(np.isfinite(np.asarray(out.images)))
    np.testing.assert_array_equal(np.asarray(out.images)[~lost], np.asarray(grey.images)[~lost])


def test_supersampling_anti_aliases():
    # a 4x smaller virtual camera: a k x k average, and a fine texture (period ~ 2 source
    # pixels) averages out instead of aliasing
    pose = Pose(12.0, 0.3, 0.0, 1.0)
    camera = cam.make_camera(12.0, 0.3, math.pi / 2 - 1.0, 2 * math.atan(H_REAL / (2 * K_REAL.fy)), (30, 40))
    k = rectify.supersample_factor(pose, K_REAL, D_REAL, (W_REAL, H_REAL), camera)
    assert 4 <= k <= 6
    assert rectify.supersample_factor(pose, K_REAL, D_REAL, (W_REAL, H_REAL),
                                      cam.make_camera(12.0, 0.3, 0.57, 0.1, (300, 400))) == 1
    checker = ((np.arange(H_REAL)[:, None] + np.arange(W_REAL)[None]) % 2).astype(float)[None]
    smooth = rectify.rectify(checker, pose, K_REAL, D_REAL, camera)
    aliased = rectify.rectify(checker, pose, K_REAL, D_REAL, camera, supersample=1)
    valid = np.asarray(smooth.valid[0])
    assert np.std(np.asarray(smooth.images[0])[valid]) < 0.5 * np.std(np.asarray(aliased.images[0])[valid])
    assert np.mean(np.asarray(smooth.images[0])[valid]) == pytest.approx(0.5, abs=0.05)


def test_errors():
    frames, _ = _real_frames()
    camera = rectify.virtual_camera(POSES, K_REAL, (W_REAL, H_REAL), resolution=(24, 32))
    with pytest.raises(ValueError, match=r"\(T, h, w\) or \(T, h, w, C\)"):
        rectify.rectify(frames[0], POSES, K_REAL, D_REAL, camera)
    with pytest.raises(ValueError, match=r"read as frames 3 pixels wide; one RGB frame is images\[None\]"):
        rectify.rectify(np.stack([frames[0]] * 3, axis=-1), POSES, K_REAL, D_REAL, camera)
    with pytest.raises(ValueError, match=r"images of 160x120 \(w x h\) do not match the camera's image_size 640x480"):
        rectify.rectify(frames, POSES, K_REAL, D_REAL, camera, image_size=(640, 480))
    with pytest.raises(ValueError, match="principal point .* outside"):
        rectify.rectify(frames[:, :40, :40], POSES, K_REAL, D_REAL, camera)
    with pytest.raises(ValueError, match=r"Pose.height must be a scalar or have shape \(2,\)"):
        rectify.rectify(frames[:2], POSES, K_REAL, D_REAL, camera)
    with pytest.raises(ValueError, match="supersample must be a positive int"):
        rectify.rectify(frames, POSES, K_REAL, D_REAL, camera, supersample=0)
    with pytest.raises(ValueError, match="one perspective camera"):
        rectify.rectify(frames, POSES, K_REAL, D_REAL, cam.make_orthographic(50.0, (24, 32)))
    with pytest.raises(ValueError, match="source_mask must be bool"):
        rectify.rectify(frames, POSES, K_REAL, D_REAL, camera, source_mask=np.ones((10, 10), bool))
    with pytest.raises(ValueError, match="image_size"):
        rectify.unrectify(np.zeros((3, 24, 32)), POSES, K_REAL, D_REAL, None, camera)
    with pytest.raises(ValueError, match="do not match"):
        rectify.unrectify(np.zeros((3, 20, 32)), POSES, K_REAL, D_REAL, (W_REAL, H_REAL), camera)
    # non-finite lens parameters are refused as non-finite poses are (a NaN coefficient made
    # every pixel invalid, silently; a NaN principal point was said to lie outside the images)
    with pytest.raises(ValueError, match=r"distortion coefficients must be finite; got \{'k1': nan"):
        rectify.rectify(frames, POSES, K_REAL, D_REAL._replace(k1=math.nan), camera)
    with pytest.raises(ValueError, match="distortion coefficients must be finite"):
        rectify.unrectify(np.zeros((3, 24, 32)), POSES, K_REAL, D_REAL._replace(p2=math.inf), (W_REAL, H_REAL),
                          camera)
    with pytest.raises(ValueError, match="intrinsics must be finite; got fx=94.12, fy=94.15, cx=nan"):
        rectify.rectify(frames, POSES, K_REAL._replace(cx=math.nan), D_REAL, camera)


@pytest.mark.slow
def test_speed_of_a_real_sized_sequence():
    # 150 grey 640 x 480 frames -> 192 x 256, the size of real ship-borne footage
    T = int(os.environ.get("RECTIFY_BENCH_FRAMES", "150"))
    K = Intrinsics(376.4972, 376.5988, 323.1564, 239.9721)
    D = Distortion(-0.208895, 0.062032)
    rng = np.random.default_rng(0)
    poses = Pose(12 + rng.normal(0, 1, T), 0.31 + rng.normal(0, 0.03, T), rng.normal(0, 0.05, T),
                 1.0 + rng.normal(0, 0.03, T), rng.normal(0, 1, T), rng.normal(0, 1, T))
    frames = rng.random((T, 480, 640), dtype=np.float32)
    camera = rectify.virtual_camera(poses, K, (640, 480), resolution=(192, 256))
    rectify.rectify(frames[:2], Pose(*(leaf[:2] for leaf in poses)), K, D, camera).images.block_until_ready()
    start = time.perf_counter()
    out = rectify.rectify(frames, poses, K, D, camera)
    out.images.block_until_ready()
    elapsed = time.perf_counter() - start
    print(f"rectify {T} frames 640x480 -> 192x256: {elapsed:.2f} s")
    assert jnp.asarray(out.valid).mean() > 0.9
    assert elapsed < 30
