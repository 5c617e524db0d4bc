"""jaxocean.lens: the pose convention of the camera-file schema, Brown--Conrady distortion,
projection and its agreement with the library camera."""

import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from jax.test_util import check_grads

from jaxocean import camera as cam
from jaxocean import lens
from jaxocean.lens import Distortion, Intrinsics, Pose

# The strongly distorted 640 x 480 lens of a ship-borne camera (barrel, k1 = -0.21).
K_REAL = Intrinsics(376.4972, 376.5988, 323.1564, 239.9721)
D_REAL = Distortion(-0.208895, 0.062032)
W_REAL, H_REAL = 640, 480


def _pixel_grid(W, H, dtype=np.float64):
    u, v = np.meshgrid(np.arange(W, dtype=dtype), np.arange(H, dtype=dtype))
    return np.stack([u, v], axis=-1)


def _readme_rotation(pitch, roll, yaw):
    """The schema's reference R_cw, transcribed literally."""
    cy, sy, cp, sp, cr, sr = np.cos(yaw), np.sin(yaw), np.cos(pitch), np.sin(pitch), np.cos(roll), np.sin(roll)
    R_yaw = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    R_pitch = np.array([[1, 0, 0], [0, -sp, -cp], [0, cp, -sp]])
    R_roll = np.array([[cr, -sr, 0], [sr, cr, 0], [0, 0, 1]])
    return R_roll @ R_pitch @ R_yaw


# --------------------------------------------------------------------------- distortion


def test_undistort_inverts_distort_over_the_image(x64):
    uv = _pixel_grid(W_REAL, H_REAL)
    xy_d = lens.normalize_pixels(uv, K_REAL)
    xy = lens.undistort(xy_d, D_REAL)
    back = lens.denormalize(lens.distort(xy, D_REAL), K_REAL)
    error = float(np.abs(np.asarray(back) - uv).max())
    # measured: 1.1e-13 px (float64 round-off at coordinates of 640 px)
    assert error < 1e-9
    # and the distortion is not trivial: corners move by tens of pixels
    undistorted_uv = lens.denormalize(xy, K_REAL)
    assert float(np.abs(np.asarray(undistorted_uv) - uv).max()) > 50


@pytest.mark.parametrize("fx, k1, k2", [(300.0, -0.4, 0.1), (250.0, -0.4, 0.1), (300.0, -0.3, 0.05),
                                         (300.0, 0.5, 0.3), (400.0, 1.0, 1.0)])
def test_undistort_inverts_strong_barrel_and_pincushion_over_the_full_frame(x64, fx, k1, k2):
    # plain Newton from x_d left 0.02 px at k1 = -0.4, k2 = 0.1, fx = 300 after 6 steps (5.6 px
    # at k1 = -0.3, k2 = 0.05): the radial slope 1 + 3 k1 r^2 + 5 k2 r^4 dips near 0 on the way
    intrinsics = Intrinsics(fx, fx, (W_REAL - 1) / 2, (H_REAL - 1) / 2)
    distortion = Distortion(k1, k2)
    assert lens.fold_problem(distortion, intrinsics, (W_REAL, H_REAL)) is None  # a valid lens
    u, v = np.meshgrid(np.linspace(-0.5, W_REAL - 0.5, 321), np.linspace(-0.5, H_REAL - 0.5, 241))
    uv = np.stack([u, v], -1)  # every edge, the corners included
    xy = lens.undistort(lens.normalize_pixels(uv, intrinsics), distortion)
    back = np.asarray(lens.denormalize(lens.distort(xy, distortion), intrinsics))
    assert float(np.abs(back - uv).max()) < 1e-3
    # and the values do not depend on tracing (a fixed count of steps)
    jitted = jax.jit(lambda q, d: lens.undistort(q, d))(lens.normalize_pixels(uv, intrinsics), distortion)
    np.testing.assert_array_equal(np.asarray(jitted), np.asarray(xy))


def test_undistort_without_newton_steps_leaves_the_tangential_part(x64):
    # the convergence checks are real: the radial start alone misses the tangential terms
    D = Distortion(D_REAL.k1, D_REAL.k2, 0.002, -0.003)
    xy_d = lens.normalize_pixels(np.array([[0.0, 0.0], [639.0, 479.0]]), K_REAL)
    back = lens.denormalize(lens.distort(lens.undistort(xy_d, D, iterations=0), D), K_REAL)
    assert float(np.abs(np.asarray(back) - [[0.0, 0.0], [639.0, 479.0]]).max()) > 1e-3


def test_distort_matches_opencv_formula_with_tangential_terms(x64):
    x, y = 0.3, -0.2
    k1, k2, p1, p2 = -0.2, 0.05, 0.001, -0.002
    r2 = x * x + y * y
    radial = 1 + k1 * r2 + k2 * r2 * r2
    expected = [x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x),
                y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y]
    got = lens.distort(jnp.array([x, y]), Distortion(k1, k2, p1, p2))
    np.testing.assert_allclose(got, expected, rtol=1e-14)
    # and the round trip holds with tangential terms too
    xy_d = jnp.array([[0.5, 0.4], [-0.6, 0.1]])
    np.testing.assert_allclose(lens.distort(lens.undistort(xy_d, Distortion(k1, k2, p1, p2)), Distortion(k1, k2, p1, p2)),
                               xy_d, atol=1e-12)


def test_max_radius():
    # k2 = 0, k1 < 0: r_d(r) = r (1 + k1 r^2) turns back at r = 1 / sqrt(-3 k1)
    assert float(lens.max_radius(Distortion(-0.21))) == pytest.approx(1 / math.sqrt(0.63), rel=1e-6)
    assert float(lens.max_radius(D_REAL)) == 10.0  # monotonic for every radius
    # pincushion with k2 < 0: the slope 1 + 3 k1 s + 5 k2 s^2 (s = r^2) vanishes at its positive root
    k1, k2 = 0.6, -0.25
    s = (-3 * k1 - math.sqrt(9 * k1 * k1 - 20 * k2)) / (10 * k2)
    assert float(lens.max_radius(Distortion(k1, k2))) == pytest.approx(math.sqrt(s), rel=1e-6)
    assert float(lens.max_radius(Distortion(k1, k2), limit=1.0)) == 1.0


def test_float32_follows_inputs():
    uv = _pixel_grid(W_REAL, H_REAL, np.float32)
    xy = lens.undistort(lens.normalize_pixels(uv, K_REAL), D_REAL)
    assert xy.dtype == jnp.float32
    # measured: 6.1e-5 px, one float32 rounding step at coordinates near 640
    assert float(np.abs(np.asarray(lens.denormalize(lens.distort(xy, D_REAL), K_REAL)) - uv).max()) < 2e-4
    uv, _ = lens.project(jnp.ones((2, 3), jnp.float32), Pose(10.0, 0.3, 0.0, 1.0), K_REAL, D_REAL)
    assert uv.dtype == jnp.float32


# --------------------------------------------------------------------------- rotation


@pytest.mark.parametrize("pitch, roll, heading", [(0.3, 0.0, 1.0), (0.31, 0.07, 5.9), (-0.2, -0.1, 2.5)])
def test_rotation_is_the_schema_matrix(x64, pitch, roll, heading):
    R = np.asarray(lens.rotation(Pose(12.0, pitch, roll, heading)))
    np.testing.assert_allclose(R, _readme_rotation(pitch, roll, heading), atol=1e-15)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-14)
    # the optical axis in the world
    axis = R.T @ [0, 0, 1]
    np.testing.assert_allclose(
        axis, [np.cos(pitch) * np.sin(heading), np.cos(pitch) * np.cos(heading), -np.sin(pitch)], atol=1e-15)


def test_rotation_of_a_sequence(x64):
    poses = Pose(np.full(4, 12.0), np.linspace(0.1, 0.4, 4), np.linspace(-0.1, 0.1, 4), np.linspace(0, 6, 4))
    R = lens.rotation(poses)
    assert R.shape == (4, 3, 3)
    for t in range(4):
        np.testing.assert_allclose(R[t], _readme_rotation(poses.pitch[t], poses.roll[t], poses.heading[t]), atol=1e-15)


def test_world_up_is_image_up_without_roll(x64):
    pitch = 0.3
    R = np.asarray(lens.rotation(Pose(12.0, pitch, 0.0, 0.9)))
    np.testing.assert_allclose(R @ [0, 0, 1], [0, -np.cos(pitch), -np.sin(pitch)], atol=1e-15)
    # a point above the optical axis projects above the principal point (smaller v)
    axis = R.T @ [0, 0, 1]
    above = np.array([0, 0, 12.0]) + 20 * axis + [0, 0, 3.0]
    uv, in_front = lens.project(above, Pose(12.0, pitch, 0.0, 0.9), K_REAL)
    assert bool(in_front) and float(uv[1]) < K_REAL.cy - 10
    assert float(uv[0]) == pytest.approx(K_REAL.cx, abs=1e-9)


def _horizon_ends(roll):
    """Pixel rows of the horizon 25 degrees left and right of the optical axis."""
    heading, pitch = 1.0, 0.05
    pose = Pose(12.0, pitch, roll, heading)
    far = 1e7
    points = np.array([[far * np.sin(heading + s), far * np.cos(heading + s), 0.0] for s in (-0.44, 0.44)])
    uv, in_front = lens.project(points, pose, K_REAL)
    assert bool(in_front.all())
    assert float(uv[0, 0]) < float(uv[1, 0])  # left then right
    return float(uv[0, 1]), float(uv[1, 1])


def test_positive_roll_lowers_the_right_end_of_the_horizon(x64):
    left, right = _horizon_ends(0.0)
    assert right == pytest.approx(left, abs=1e-6)
    left, right = _horizon_ends(math.radians(4))
    assert right > left + 10  # the right end is lower in the image (larger v)
    left, right = _horizon_ends(-math.radians(4))
    assert right < left - 10


# --------------------------------------------------------------------------- the library camera


@pytest.mark.parametrize("height, pitch, yaw, fov, res, xy", [
    (10.0, 0.35, 0.0, 0.8, (48, 64), (0.0, 0.0)),
    (12.25, 0.31, 0.55, 1.1, (96, 128), (3.0, -2.0)),
    (30.0, 1.2, -2.0, 0.4, (33, 17), (-50.0, 10.0)),
    (5.0, -0.1, 3.5, 1.5, (20, 40), (1.0, 1.0)),
])
def test_project_agrees_with_the_library_camera(x64, height, pitch, yaw, fov, res, xy):
    c = cam.make_camera(height, pitch, yaw, fov, res, x=xy[0], y=xy[1], dtype=np.float64)
    pose, K = lens.pose_of(c), lens.pinhole_intrinsics(c)
    assert float(pose.roll) == 0.0
    origins, directions = cam.pixel_rays(c)
    rng = np.random.default_rng(1)
    points = origins + rng.uniform(1, 200, res)[..., None] * directions
    # plus random points anywhere in front of the camera
    points = np.concatenate([np.asarray(points).reshape(-1, 3),
                             np.asarray(origins) + rng.normal(size=(50, 3)) * 40 + 60 * np.asarray(cam.camera_frame(c).forward)])
    ij = np.asarray(cam.project(c, points))
    uv, in_front = lens.project(points, pose, K, Distortion())
    keep = np.asarray(in_front)
    assert keep.sum() > res[0] * res[1]
    np.testing.assert_allclose(np.asarray(uv)[keep][:, ::-1], ij[keep], atol=1e-4)
    # and pixel_rays reproduces the library's rays at the pixel centres
    i, j = np.meshgrid(np.arange(res[0], dtype=float), np.arange(res[1], dtype=float), indexing="ij")
    rays = lens.pixel_rays(np.stack([j, i], -1), pose, K)
    np.testing.assert_allclose(rays, directions, atol=1e-12)


def test_pinhole_intrinsics_values():
    c = cam.make_camera(10.0, 0.3, 0.0, 0.9, (96, 128))
    K = lens.pinhole_intrinsics(c)
    f = 48 / math.tan(0.45)
    np.testing.assert_allclose([K.fx, K.fy, K.cx, K.cy], [f, f, 63.5, 47.5], rtol=1e-6)
    with pytest.raises(ValueError, match="perspective"):
        lens.pinhole_intrinsics(cam.make_orthographic(10.0, (8, 8)))


def test_heading_and_yaw():
    assert float(lens.yaw_from_heading(0.0)) == pytest.approx(math.pi / 2)  # north
    assert float(lens.yaw_from_heading(math.pi / 2)) == pytest.approx(0.0, abs=1e-7)  # east = +x
    for heading in (0.1, 1.0, 3.0, 6.0):
        assert float(lens.heading_from_yaw(lens.yaw_from_heading(heading))) == pytest.approx(heading, abs=1e-6)
    assert 0 <= float(lens.heading_from_yaw(3.0)) < 2 * math.pi


# --------------------------------------------------------------------------- rays and gradients


def test_pixel_rays_invert_project(x64):
    pose = Pose(12.3, 0.31, 0.07, 1.0, east=1.5, north=-0.7)
    uv = _pixel_grid(W_REAL, H_REAL)[::16, ::16]
    rays = lens.pixel_rays(uv, pose, K_REAL, D_REAL)
    np.testing.assert_allclose(jnp.linalg.norm(rays, axis=-1), 1.0, atol=1e-14)
    points = jnp.array([pose.east, pose.north, pose.height]) + 37.0 * rays
    back, in_front = lens.project(points, pose, K_REAL, D_REAL)
    assert bool(in_front.all())
    np.testing.assert_allclose(back, uv, atol=1e-9)


def test_project_behind_camera_is_flagged_and_finite(x64):
    pose = Pose(10.0, 0.3, 0.0, 0.0)
    behind = np.array([0.0, -50.0, 0.0])  # heading north, so south is behind
    uv, in_front = lens.project(behind, pose, K_REAL, D_REAL)
    assert not bool(in_front) and bool(jnp.isfinite(uv).all())


def test_project_is_jittable_and_equal(x64):
    pose = Pose(12.0, 0.3, 0.05, 1.0, 0.5, 0.2)
    points = jnp.array([[10.0, 20.0, 0.0], [30.0, 5.0, 1.0]])
    eager = lens.project(points, pose, K_REAL, D_REAL)
    jitted = jax.jit(lens.project)(points, pose, K_REAL, D_REAL)
    np.testing.assert_array_equal(eager[0], jitted[0])
    rays = lens.pixel_rays(eager[0], pose, K_REAL, D_REAL)
    np.testing.assert_array_equal(jax.jit(lens.pixel_rays)(eager[0], pose, K_REAL, D_REAL), rays)


def test_project_gradients_wrt_pose(x64):
    points = jnp.array([[10.0, 20.0, 0.0], [30.0, 5.0, 1.0], [3.0, 40.0, -0.5]])

    def uv_of(height, pitch, roll, heading, east, north):
        return lens.project(points, Pose(height, pitch, roll, heading, east, north), K_REAL, D_REAL)[0]

    check_grads(uv_of, (12.0, 0.3, 0.05, 0.6, 0.5, -0.2), order=1, modes=("fwd", "rev"))


def test_pixel_rays_gradients(x64):
    uv = jnp.array([[100.0, 300.0], [600.0, 50.0]])

    def rays_of(pitch, roll, heading, k1):
        return lens.pixel_rays(uv, Pose(12.0, pitch, roll, heading), K_REAL, Distortion(k1, 0.062))

    check_grads(rays_of, (0.3, 0.05, 0.6, -0.21), order=1, modes=("fwd", "rev"))


def _random_accepted_lenses(count, seed=3):
    """Seeded lenses that fold_problem accepts over a 640 x 480 frame: strong barrel,
    pincushion with negative k2 (folding just beyond the corners), tangential terms; each
    checked here too for a full-map Jacobian determinant > 0 inside the frame."""
    rng = np.random.default_rng(seed)
    found = []
    while len(found) < count:
        k1, k2 = rng.uniform(-0.6, 0.7), rng.uniform(-0.3, 0.2)
        p1, p2 = rng.uniform(-0.003, 0.003, 2) * rng.integers(0, 2)
        f = rng.uniform(150, 600)
        K = Intrinsics(f, f * rng.uniform(0.98, 1.02), 319.5 + rng.uniform(-8, 8), 239.5 + rng.uniform(-8, 8))
        D = Distortion(k1, k2, p1, p2)
        if lens.fold_problem(D, K, (W_REAL, H_REAL)) is not None:
            continue
        grid = np.linspace(-4, 4, 801)
        xy = np.stack(np.meshgrid(grid, grid), -1)
        corner = lens.undistort(lens.normalize_pixels(np.array([[-0.5, -0.5], [639.5, 479.5], [-0.5, 479.5],
                                                                 [639.5, -0.5]]), K), Distortion(k1, k2))
        inside = np.hypot(xy[..., 0], xy[..., 1]) <= 1.05 * float(jnp.linalg.norm(corner, axis=-1).max())
        a, b, c, d = lens._distort_jacobian(jnp.asarray(xy), *(jnp.float64(v) for v in D))
        assert float(jnp.min(jnp.where(inside, a * d - b * c, 1.0))) > 0, (D, K)  # fold_problem's promise
        found.append((D, K))
    return found


def test_fold_problem_names_tangential_terms_that_fold_the_frame(x64):
    # the radial test alone passed this lens, whose full map folds inside the frame (Jacobian
    # determinant -0.0048): pixels with no inverse; 0.135 for k2 is one-to-one
    K = Intrinsics(158.0, 158.0, 319.5, 239.5)
    problem = lens.fold_problem(Distortion(-0.54, 0.132, 0.001, -0.002), K, (W_REAL, H_REAL))
    assert problem is not None and "p1 = 0.001, p2 = -0.002" in problem and "tangential" in problem
    assert lens.fold_problem(Distortion(-0.54, 0.132), K, (W_REAL, H_REAL)) is None
    assert lens.fold_problem(Distortion(-0.54, 0.135, 0.001, -0.002), K, (W_REAL, H_REAL)) is None


def test_undistort_inverts_any_accepted_lens_over_the_frame(x64):
    # Newton from x = x_d diverged (80-460 px, up to 1e18 px) for pincushion lenses with
    # negative k2 whose fold lies just beyond the frame, e.g. k1 = 0.6, k2 = -0.25 at fx = 250
    lenses = [(Distortion(0.6, -0.25), Intrinsics(250.0, 250.0, 319.5, 239.5)),
              (Distortion(-0.54, 0.135, 0.001, -0.002), Intrinsics(158.0, 158.0, 319.5, 239.5))]
    lenses += _random_accepted_lenses(12)
    uv = _pixel_grid(W_REAL, H_REAL)[::4, ::4]
    uv = np.concatenate([uv.reshape(-1, 2), [[-0.5, -0.5], [639.5, 479.5], [-0.5, 479.5], [639.5, -0.5]]])
    for D, K in lenses:
        xy_d = lens.normalize_pixels(uv, K)
        xy = lens.undistort(xy_d, D)
        error = float(np.abs(np.asarray(lens.denormalize(lens.distort(xy, D), K)) - uv).max())
        assert error < 1e-3, (D, K, error)
        np.testing.assert_array_equal(jax.jit(lens.undistort)(xy_d, D), xy)


def test_undistort_gradients_are_finite_near_the_fold(x64):
    xy_d = jnp.array([[1.6, 0.0], [1.1, -0.9], [0.0, 0.0], [0.3, 0.2]])
    K_args = (0.6, -0.25, 0.001, -0.002)

    def total(k1, k2, p1, p2, xy_d):
        return jnp.sum(lens.undistort(xy_d, Distortion(k1, k2, p1, p2)))

    grads = jax.grad(total, argnums=(0, 1, 2, 3, 4))(*K_args, xy_d)
    assert all(bool(jnp.isfinite(g).all()) for g in grads)
    check_grads(lambda k1, k2: lens.undistort(xy_d[1:], Distortion(k1, k2, 0.001, -0.002)), (0.6, -0.25),
                order=1, modes=("fwd", "rev"))
