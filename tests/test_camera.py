"""Tests for jaxocean.camera: rays, sea hits, footprint, projection, gradients, validation."""

import dataclasses
import math

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxocean.camera import (
    DEFAULT_MAX_DISTANCE,
    DOWNWARD_THRESHOLD,
    Camera,
    SeaHit,
    camera_frame,
    camera_position,
    horizon_row,
    intersect_sea,
    make_camera,
    make_orthographic,
    pixel_angle,
    pixel_rays,
    project,
    validate_camera,
)
from jaxocean.errors import InvalidValueError


def pixel_grid(resolution):
    """(H, W, 2) integer pixel coordinates (i, j): the pixel centres."""
    H, W = resolution
    i, j = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    return np.stack([i, j], axis=-1).astype(float)


def hit_points(hit: SeaHit):
    """(H, W, 3) hit positions on z = 0."""
    return jnp.concatenate([hit.xy, jnp.zeros_like(hit.distance)[..., None]], axis=-1)


def rotate_z(vectors, angle):
    c, s = np.cos(angle), np.sin(angle)
    rotation = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    return np.asarray(vectors)[..., :3] @ rotation.T


# --------------------------------------------------------------------------- rays


@pytest.mark.parametrize("camera", [
    make_camera(height=12.0, pitch=0.4, yaw=1.1, fov=1.2, resolution=(9, 13)),
    make_orthographic(50.0, (6, 10), x=3.0, y=-2.0, yaw=0.7),
])
def test_directions_are_unit(camera):
    origins, directions = pixel_rays(camera)
    assert directions.shape == camera.resolution + (3,)
    assert jnp.broadcast_shapes(origins.shape, directions.shape) == directions.shape
    np.testing.assert_allclose(np.linalg.norm(directions, axis=-1), 1.0, rtol=1e-6)


def test_centre_direction_of_odd_image_is_forward():
    camera = make_camera(pitch=0.6, yaw=-2.3, fov=0.9, resolution=(7, 11))
    _, directions = pixel_rays(camera)
    forward = camera_frame(camera).forward
    np.testing.assert_allclose(directions[3, 5], forward, atol=1e-6)
    np.testing.assert_allclose(forward, [math.cos(0.6) * math.cos(-2.3), math.cos(0.6) * math.sin(-2.3),
                                         -math.sin(0.6)], atol=1e-6)


def test_frame_is_right_handed_and_right_is_to_the_right():
    camera = make_camera(pitch=0.3, yaw=0.0, resolution=(5, 5))
    forward, right, up = camera_frame(camera)
    np.testing.assert_allclose(np.cross(right, up), -forward, atol=1e-6)  # r x u = -f for u = r x f
    assert up[2] > 0  # up tilts upward
    # facing east (yaw 0), the right of the image is south (-y)
    _, directions = pixel_rays(camera)
    assert directions[2, -1, 1] < 0 < directions[2, 0, 1]


def test_top_row_looks_higher_than_bottom_row():
    _, directions = pixel_rays(make_camera(pitch=0.2, fov=1.0, resolution=(16, 9)))
    dz = np.asarray(directions[..., 2])
    assert np.all(np.diff(dz, axis=0) < 0)  # z decreases strictly from the top row down


def test_yaw_rotates_everything_about_z():
    base = dict(height=7.0, pitch=0.45, fov=0.9, resolution=(8, 10), x=4.0, y=-3.0)
    yaw, turn = 0.3, 1.25
    before, after = make_camera(yaw=yaw, **base), make_camera(yaw=yaw + turn, **base)
    np.testing.assert_allclose(pixel_rays(after)[1], rotate_z(pixel_rays(before)[1], turn), atol=1e-6)
    hit0, hit1 = intersect_sea(before), intersect_sea(after)
    camera_xy = np.array([4.0, -3.0])
    expected_xy = rotate_z(np.pad(np.asarray(hit0.xy) - camera_xy, ((0, 0), (0, 0), (0, 1))), turn)[..., :2]
    np.testing.assert_allclose(hit1.xy - camera_xy, expected_xy, rtol=1e-5, atol=1e-4)
    np.testing.assert_allclose(hit1.distance, hit0.distance, rtol=1e-5)
    np.testing.assert_allclose(hit1.footprint, hit0.footprint, rtol=1e-5)
    np.testing.assert_array_equal(hit1.mask, hit0.mask)


@pytest.mark.parametrize("camera", [
    make_camera(height=15.0, pitch=0.25, yaw=0.8, fov=0.9, resolution=(12, 16), x=1.0, y=2.0),
    make_orthographic(30.0, (6, 9), x=-5.0, y=4.0, yaw=2.0),
])
def test_project_inverts_the_sea_hits(camera):
    hit = intersect_sea(camera)
    assert hit.mask.any()
    pixels = project(camera, hit_points(hit))
    grid = pixel_grid(camera.resolution)
    np.testing.assert_allclose(np.asarray(pixels)[hit.mask], grid[hit.mask], atol=2e-3)


def test_project_inverts_rays_above_the_horizon_too():
    camera = make_camera(pitch=0.05, yaw=-0.4, fov=1.0, resolution=(10, 6))
    origins, directions = pixel_rays(camera)
    points = origins + 37.0 * directions
    np.testing.assert_allclose(project(camera, points), pixel_grid(camera.resolution), atol=1e-3)
    behind = origins - 5.0 * camera_frame(camera).forward
    assert np.all(np.isfinite(project(camera, behind)))


@pytest.mark.parametrize("offset", [-5.0, 0.0])
def test_project_puts_points_on_the_axis_behind_the_camera_off_the_image(offset):
    # pitch 0, yaw 0: the frame is exact, so a point on the optical axis behind the camera
    # (or the camera itself) has zero offsets and depth <= 0; it landed on the image centre
    camera = make_camera(height=10.0, pitch=0.0, yaw=0.0, fov=0.8, resolution=(9, 9))
    point = camera_position(camera) + offset * camera_frame(camera).forward
    i, j = np.asarray(project(camera, point))
    assert np.isfinite(i) and np.isfinite(j)
    assert not (-0.5 <= i <= 8.5 and -0.5 <= j <= 8.5), (i, j)


# --------------------------------------------------------------------------- sea hits


def test_hits_lie_on_the_sea_and_on_their_ray():
    camera = make_camera(height=20.0, pitch=0.3, yaw=2.0, fov=1.0, resolution=(12, 16), x=5.0, y=-1.0)
    hit = intersect_sea(camera)
    origins, directions = pixel_rays(camera)
    np.testing.assert_allclose(hit.direction, directions, atol=1e-7)
    np.testing.assert_allclose(hit.view, -directions, atol=1e-7)
    along_ray = origins + hit.distance[..., None] * hit.direction
    sea = np.asarray(hit.mask)
    assert sea.sum() > sea.size // 2
    np.testing.assert_allclose(np.asarray(along_ray)[sea][:, 2], 0.0, atol=1e-6 * np.asarray(hit.distance)[sea].max())
    np.testing.assert_allclose(np.asarray(along_ray)[sea][:, :2], np.asarray(hit.xy)[sea],
                               rtol=1e-5, atol=1e-4)


def test_footprint_straight_down_is_height_times_pixel_angle():
    camera = make_camera(height=23.0, pitch=math.pi / 2, yaw=0.4, fov=0.7, resolution=(9, 15))
    hit = intersect_sea(camera)
    assert hit.mask.all()
    np.testing.assert_allclose(hit.footprint[4, 7], 23.0 * pixel_angle(camera), rtol=1e-5)
    np.testing.assert_allclose(pixel_angle(camera), 2 * math.tan(0.35) / 9, rtol=1e-6)
    np.testing.assert_allclose(hit.distance[4, 7], 23.0, rtol=1e-6)


def test_footprint_grows_toward_the_horizon():
    hit = intersect_sea(make_camera(height=8.0, pitch=0.15, fov=0.8, resolution=(24, 10)))
    footprint, sea = np.asarray(hit.footprint), np.asarray(hit.mask)
    assert sea[-1].all() and not sea[0].any()
    for column in range(footprint.shape[1]):
        rows = footprint[sea[:, column], column]
        assert len(rows) > 10
        assert np.all(np.diff(rows) < 0)  # smaller toward the bottom of the image


def test_footprint_matches_finite_differences(x64):
    camera = make_camera(height=10.0, pitch=0.5, yaw=0.3, fov=0.9, resolution=(48, 64))
    hit = intersect_sea(camera)
    X = np.asarray(hit.xy)
    dX_dj = (X[1:-1, 2:] - X[1:-1, :-2]) / 2  # central differences between neighbouring hits
    dX_di = (X[2:, 1:-1] - X[:-2, 1:-1]) / 2
    estimate = np.sqrt(np.abs(dX_dj[..., 0] * dX_di[..., 1] - dX_dj[..., 1] * dX_di[..., 0]))
    footprint = np.asarray(hit.footprint)[1:-1, 1:-1]
    # away from the horizon: the hit within 20 camera heights
    near = np.asarray(hit.mask)[2:, 1:-1] & (np.asarray(hit.distance)[:-2, 1:-1] < 200.0)
    assert near.sum() > 1000
    np.testing.assert_allclose(footprint[near], estimate[near], rtol=0.03)


def test_orthographic_footprint_is_the_cell_and_hits_form_the_grid():
    H, W, width, x0, y0, height = 4, 6, 12.0, 10.0, -20.0, 30.0
    camera = make_orthographic(width, (H, W), x=x0, y=y0, yaw=math.pi / 2, height=height)
    hit = intersect_sea(camera)
    cell = width / W
    assert hit.mask.all()
    np.testing.assert_allclose(hit.footprint, cell, rtol=1e-6)
    np.testing.assert_allclose(hit.distance, height, rtol=1e-6)
    np.testing.assert_allclose(hit.direction, np.broadcast_to([0.0, 0.0, -1.0], (H, W, 3)), atol=1e-7)
    # yaw = pi/2: north up, east right
    i, j = np.meshgrid(np.arange(H), np.arange(W), indexing="ij")
    expected = np.stack([x0 + (j + 0.5 - W / 2) * cell, y0 + (H / 2 - i - 0.5) * cell], axis=-1)
    np.testing.assert_allclose(hit.xy, expected, atol=1e-5)
    assert float(pixel_angle(camera)) == 0.0
    assert float(horizon_row(camera)) == -np.inf


def test_orthographic_yaw_zero_puts_the_azimuth_zero_at_the_top():
    hit = intersect_sea(make_orthographic(4.0, (4, 4)))
    assert hit.xy[0, 2, 0] > 0 > hit.xy[-1, 2, 0]  # top row is east of the bottom row
    assert hit.xy[2, 0, 1] > 0 > hit.xy[2, -1, 1]  # left column is north of the right one


# --------------------------------------------------------------------------- horizon and sky


def test_horizon_splits_sky_from_sea():
    camera = make_camera(height=10.0, pitch=0.1, yaw=0.5, fov=0.8, resolution=(32, 12), x=2.0, y=3.0)
    row = float(horizon_row(camera))
    assert 5 < row < 15
    expected = (math.tan(0.4) - math.tan(0.1)) / (2 * math.tan(0.4)) * 32 - 0.5
    np.testing.assert_allclose(row, expected, rtol=1e-5)
    hit = intersect_sea(camera)
    rows = np.arange(32)
    mask = np.asarray(hit.mask)
    assert not mask[rows < row].any()
    assert mask[rows > row + 0.25].all()
    # the ray z changes sign at the horizon row
    _, directions = pixel_rays(camera)
    dz = np.asarray(directions[:, 0, 2])
    assert np.all(dz[rows < row] > 0) and np.all(dz[rows > row] < 0)
    # sky pixels: finite, the point below the camera
    sky = ~mask
    for field in hit:
        assert np.all(np.isfinite(np.asarray(field)))
    np.testing.assert_allclose(np.asarray(hit.xy)[sky], np.broadcast_to([2.0, 3.0], (sky.sum(), 2)), atol=1e-6)
    np.testing.assert_allclose(np.asarray(hit.distance)[sky], 10.0)
    np.testing.assert_allclose(np.asarray(hit.footprint)[sky], 10.0 * float(pixel_angle(camera)), rtol=1e-6)


GRADIENT_RESOLUTION = (9, 12)  # one for all tests, so the jitted gradient below compiles once


@jax.jit
@jax.grad
def geometry_gradient(camera, geometry_weights, direction_weight):
    """Gradient wrt the camera of weighted sums of the geometric outputs and the rays."""
    hit = intersect_sea(camera)
    geometry = hit.xy[..., 0] + 0.3 * hit.xy[..., 1] + hit.distance + hit.footprint
    return jnp.sum(geometry_weights * geometry) + direction_weight * jnp.sum(hit.direction)


def test_sky_gradients_are_finite_and_geometric_ones_zero():
    camera = make_camera(height=10.0, pitch=0.1, fov=0.8, resolution=GRADIENT_RESOLUTION)
    sky = ~intersect_sea(camera).mask
    assert sky.any() and (~sky).any()
    for leaf in jax.tree_util.tree_leaves(geometry_gradient(camera, sky.astype(jnp.float32), 0.0)):
        assert float(leaf) == 0.0
    grads = geometry_gradient(camera, jnp.ones(GRADIENT_RESOLUTION), 1.0)
    assert all(np.isfinite(leaf) for leaf in jax.tree_util.tree_leaves(grads))
    assert float(grads.pitch) != 0.0 and float(grads.height) != 0.0


def test_max_distance_turns_far_hits_into_sky():
    camera = make_camera(height=10.0, pitch=0.2, fov=0.8, resolution=(16, 8))
    far = intersect_sea(camera)
    near = intersect_sea(camera, max_distance=60.0)
    np.testing.assert_array_equal(near.mask, far.mask & (far.distance <= 60.0))
    assert far.mask.sum() > near.mask.sum() > 0
    everything = intersect_sea(camera, max_distance=float("inf"))
    assert everything.mask.sum() >= far.mask.sum()


def test_grazing_rays_just_below_the_threshold_are_sky():
    # a pitch that puts the centre row's ray exactly on the horizon: D_z = 0 there
    camera = make_camera(height=10.0, pitch=0.0, fov=0.5, resolution=GRADIENT_RESOLUTION)
    hit = intersect_sea(camera, max_distance=float("inf"))
    assert float(hit.direction[4, 0, 2]) == 0.0  # exactly horizontal: a naive -h / D_z is inf
    assert not hit.mask[4].any() and hit.mask[5].all()
    assert np.all(np.asarray(hit.direction[hit.mask][:, 2]) < -DOWNWARD_THRESHOLD)
    for field in hit:
        assert np.all(np.isfinite(np.asarray(field)))
    grads = geometry_gradient(camera, jnp.ones(GRADIENT_RESOLUTION), 1.0)
    assert all(np.isfinite(leaf) for leaf in jax.tree_util.tree_leaves(grads))
    assert DEFAULT_MAX_DISTANCE == 1e5


# --------------------------------------------------------------------------- gradients


def test_check_grads_of_sea_geometry(x64):
    base = make_camera(height=5.0, pitch=0.2, yaw=-1.0, fov=0.9, resolution=(6, 8), x=1.5, y=-0.5)
    sky = ~intersect_sea(base).mask
    assert sky[0].all() and not sky[-1].any()  # the top row sees the sky: mask it out

    def geometry(height, pitch, yaw, fov):
        camera = dataclasses.replace(base, height=height, pitch=pitch, yaw=yaw, fov=fov)
        hit = intersect_sea(camera)
        sea_geometry = jnp.concatenate([hit.xy, hit.distance[..., None], hit.footprint[..., None],
                                        project(camera, hit_points(hit) + 0.1)], axis=-1)
        return jnp.concatenate([jnp.where(sky[..., None], 0.0, sea_geometry).ravel(),
                                jnp.atleast_1d(horizon_row(camera))])

    check_grads(jax.jit(geometry), (base.height, base.pitch, base.yaw, base.fov), order=1, modes=("fwd", "rev"))


def _masked_loss(camera):
    hit = intersect_sea(camera)
    sea = hit.mask
    value = jnp.where(sea, hit.distance + hit.footprint + hit.xy.sum(-1), 0.0).sum()
    return value + hit.direction.sum() + horizon_row(camera)


_outputs_and_grad = jax.jit(lambda camera: (intersect_sea(camera), jax.grad(_masked_loss)(camera)))


@given(
    height=st.floats(0.5, 100.0),
    pitch=st.floats(-0.3, 1.5),
    fov=st.floats(0.1, 2.5),
    yaw=st.floats(-math.pi, math.pi),
)
def test_outputs_and_gradients_are_finite_everywhere(height, pitch, fov, yaw):
    camera = make_camera(height=height, pitch=pitch, yaw=yaw, fov=fov, resolution=(12, 10))
    hit, grads = _outputs_and_grad(camera)
    for array in (*hit, *jax.tree_util.tree_leaves(grads)):
        assert np.all(np.isfinite(np.asarray(array)))
    assert np.all(np.asarray(hit.footprint) > 0)
    assert np.isfinite(float(horizon_row(camera)))


def test_straight_down_float32_is_finite():
    # float32(pi/2) > pi/2, so cos p < 0: the horizon must still be far above, not below
    camera = make_camera(pitch=math.pi / 2, resolution=(12, 10))
    assert np.isfinite(float(horizon_row(camera))) and float(horizon_row(camera)) < -1e6
    grads = _outputs_and_grad(camera)[1]
    assert all(np.isfinite(leaf) for leaf in jax.tree_util.tree_leaves(grads))


# --------------------------------------------------------------------------- batching and dtypes


def test_vmap_over_cameras_equals_the_loop():
    heights, pitches, yaws = [5.0, 10.0, 40.0], [0.1, 0.5, 1.2], [0.0, 1.0, -2.0]
    batch = make_camera(height=jnp.array(heights), pitch=jnp.array(pitches), yaw=jnp.array(yaws),
                        fov=0.9, resolution=(6, 7))
    assert batch.fov.shape == (3,)
    batched = jax.vmap(intersect_sea)(batch)
    batched_rows = jax.vmap(horizon_row)(batch)
    for b, (h, p, y) in enumerate(zip(heights, pitches, yaws)):
        single = make_camera(height=h, pitch=p, yaw=y, fov=0.9, resolution=(6, 7))
        for name, got, want in zip(SeaHit._fields, batched, intersect_sea(single)):
            np.testing.assert_allclose(got[b], want, rtol=1e-5, atol=1e-5, err_msg=name)
        np.testing.assert_allclose(batched_rows[b], horizon_row(single), rtol=1e-5)


def test_jit_matches_eager():
    camera = make_camera(height=4.0, pitch=0.3, yaw=0.2, fov=1.1, resolution=(7, 9))
    for got, want in zip(jax.jit(intersect_sea)(camera), intersect_sea(camera)):
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-5)


def test_float32_default_and_float64_capable():
    assert intersect_sea(make_camera(resolution=(4, 4))).footprint.dtype == jnp.float32
    with jax.enable_x64(True):
        camera = make_camera(resolution=(4, 4))
        assert camera.height.dtype == jnp.float64
        hit = intersect_sea(camera)
        assert hit.xy.dtype == hit.footprint.dtype == hit.direction.dtype == jnp.float64
        assert project(camera, hit_points(hit)).dtype == jnp.float64


# --------------------------------------------------------------------------- bad input


@pytest.mark.parametrize("height", [0.0, -2.5])
def test_camera_under_the_sea_is_rejected(height):
    with pytest.raises(InvalidValueError, match="under the sea") as info:
        make_camera(height=height)
    assert str(height) in str(info.value)


@pytest.mark.parametrize("kwargs, match", [
    (dict(fov=0.0), "fov"),
    (dict(fov=-0.5), "fov"),
    (dict(fov=math.pi), "fov"),
    (dict(pitch=1.6), "pitch"),
    (dict(pitch=-math.pi / 2), "pitch"),
    (dict(height=float("nan")), "height must be finite"),
    (dict(pitch=float("nan")), "pitch must be finite"),
    (dict(x=float("inf")), "x must be finite"),
])
def test_bad_values_are_rejected(kwargs, match):
    with pytest.raises(InvalidValueError, match=match):
        make_camera(**kwargs)


def test_bad_values_are_rejected_at_every_entry_point():
    camera = Camera(height=jnp.float32(-1.0), pitch=jnp.float32(0.3), yaw=jnp.float32(0.0),
                    fov=jnp.float32(0.8), resolution=(4, 4))
    for function in (pixel_rays, intersect_sea, horizon_row, pixel_angle, camera_frame,
                     lambda c: project(c, jnp.zeros(3))):
        with pytest.raises(InvalidValueError, match="under the sea"):
            function(camera)
    with pytest.raises(InvalidValueError, match="ortho_width"):
        make_orthographic(0.0, (4, 4))
    with pytest.raises(InvalidValueError, match="max_distance"):
        intersect_sea(make_camera(resolution=(4, 4)), max_distance=0.0)


@pytest.mark.parametrize("resolution", [(0, 4), (4,), (4, 4, 4), (4.0, 4), (True, 4), "64x64", 64])
def test_bad_resolution_is_a_structural_error(resolution):
    with pytest.raises(ValueError, match="resolution") as info:
        make_camera(resolution=resolution)
    assert not isinstance(info.value, InvalidValueError)


def test_structural_errors():
    with pytest.raises(ValueError, match="fisheye"):
        validate_camera(dataclasses.replace(make_camera(resolution=(4, 4)), projection="fisheye"))
    with pytest.raises(ValueError, match="Camera"):
        validate_camera({"height": 1.0})
    with pytest.raises(ValueError, match="vmap"):
        intersect_sea(make_camera(height=jnp.array([1.0, 2.0]), resolution=(4, 4)))
    with pytest.raises(ValueError, match=r"\(\.\.\., 3\)"):
        project(make_camera(resolution=(4, 4)), jnp.zeros((5, 2)))
    # a list resolution is normalised to a hashable tuple (jit needs static fields hashable)
    assert make_camera(resolution=[3, np.int64(5)]).resolution == (3, 5)
