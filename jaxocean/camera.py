"""Cameras: the ``Camera`` pytree, pixel rays, sea-plane intersection and pixel footprint.

Protocol
--------
``Camera`` is a frozen dataclass registered as a pytree. Its data leaves are scalars (a
batch of cameras has leaves of one shape ``(B,)`` and is mapped with ``jax.vmap``); its
static fields fix the image size and the projection, so cameras in one batch share them.

* ``height``      ch [m] above mean sea level (the camera's z), > 0
* ``pitch``       ctheta [rad] of the optical axis below the horizon; positive looks down,
                  in (-pi/2, pi/2]
* ``yaw``         azimuth [rad] of the viewing direction, from +x counter-clockwise
* ``fov``         vertical field of view [rad], in (0, pi)
* ``x``, ``y``    ground position [m] of the camera
* ``ortho_width`` [m] of sea across the image width (orthographic projection only)
* ``resolution``  static ``(H, W)`` pixels
* ``projection``  static ``"perspective"`` (pinhole) or ``"orthographic"`` (top-down)

Every function below is a pure function of the camera: jittable, vmappable, float32 by
default and float64 under ``jax_enable_x64``, with finite gradients with respect to every
leaf (``height``, ``pitch``, ``yaw``, ``fov``, ...) for every pixel, sky pixels included.

Conventions
-----------
World frame: z up, mean sea level z = 0, x east, y north, azimuths from +x counter-clockwise.
Image: row ``i = 0`` is the top of the image, column ``j = 0`` the left; pixel ``(i, j)``
has its centre at pixel coordinates ``(i, j)`` (what :func:`project` returns).

Perspective camera frame (no roll)::

    forward f = (cos p cos yaw, cos p sin yaw, -sin p)
    right   r = (sin yaw, -cos yaw, 0)
    up      u = r x f

Pixel ``(i, j)`` looks along the unnormalised direction ``D = f + s_u r + s_v u`` with
``s_u = (2 (j + 1/2) / W - 1) tan(fov/2) W / H`` and ``s_v = (1 - 2 (i + 1/2) / H) tan(fov/2)``:
square pixels of angular size ``2 tan(fov/2) / H`` at the image centre.

The orthographic camera looks straight down (-z) from ``height``. It uses the frame above
at pitch pi/2 -- ``f = -z``, ``r = (sin yaw, -cos yaw, 0)``, ``u = (cos yaw, sin yaw, 0)`` --
so in both projections the top of the image faces azimuth ``yaw`` (``yaw = pi/2`` gives a
north-up map). Its pixels are square ground cells of ``ortho_width / W`` metres centred on
``(x, y)``.

Sea hits
--------
:func:`intersect_sea` intersects every pixel ray with the plane z = 0. A ray whose unit
direction has ``z >= -DOWNWARD_THRESHOLD`` (it does not clearly go down), or whose hit is
farther than ``max_distance``, is a *sky* pixel: ``mask`` is False there, ``direction`` and
``view`` keep the true ray (sky shading needs it), and ``xy``, ``distance`` and ``footprint``
report the point straight below the camera (distance = height, the nadir footprint) with
their gradients stopped, so sky pixels are finite and carry zero geometric gradient.
"""

from __future__ import annotations

import dataclasses
import math
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean._math import materialize, safe_divide, safe_norm, safe_normalize, safe_sqrt
from jaxocean.errors import check_values, is_concrete

__all__ = [
    "PROJECTIONS",
    "DOWNWARD_THRESHOLD",
    "DEFAULT_MAX_DISTANCE",
    "Camera",
    "CameraFrame",
    "SeaHit",
    "make_camera",
    "make_orthographic",
    "validate_camera",
    "compute_dtype",
    "camera_to_dict",
    "camera_frame",
    "camera_position",
    "pixel_angle",
    "pixel_rays",
    "intersect_sea",
    "project",
    "horizon_row",
]

PROJECTIONS = ("perspective", "orthographic")

# A pixel is sea only if its unit ray has z < -DOWNWARD_THRESHOLD (about 0.006 degrees
# below horizontal): this keeps the ray parameter t = -height / D_z, and the footprint that
# grows like |D_z|^-1.5, far from overflow, and the division away from D_z = 0.
DOWNWARD_THRESHOLD = 1e-4

# Sea hits beyond 100 km are sky: Earth's curvature hides a flat sea long before that (the
# geometric horizon of a 10 m camera is 11 km), and float32 positions lose centimetres there.
DEFAULT_MAX_DISTANCE = 1e5  # m

_DATA_FIELDS = ("height", "pitch", "yaw", "fov", "x", "y", "ortho_width")
_META_FIELDS = ("resolution", "projection")


@jax.tree_util.register_dataclass
@dataclasses.dataclass(frozen=True)
class Camera:
    """A pinhole (``"perspective"``) or top-down (``"orthographic"``) camera over the sea.

    Build one with :func:`make_camera` or :func:`make_orthographic`; see the module
    docstring for the frame and pixel conventions.
    """

    height: jax.Array
    pitch: jax.Array
    yaw: jax.Array
    fov: jax.Array
    x: jax.Array = 0.0
    y: jax.Array = 0.0
    ortho_width: jax.Array = 1.0
    resolution: tuple[int, int] = dataclasses.field(default=(128, 128), metadata=dict(static=True))
    projection: str = dataclasses.field(default="perspective", metadata=dict(static=True))

    def __post_init__(self):
        # Static fields must be hashable for jit: accept a list or NumPy integers for the
        # resolution and store a tuple of ints. Anything else is left for validate_camera.
        res = self.resolution
        if isinstance(res, (list, tuple)) and all(_is_int(n) for n in res):
            object.__setattr__(self, "resolution", tuple(int(n) for n in res))


class CameraFrame(NamedTuple):
    """Orthonormal camera axes in world coordinates, each ``(3,)``."""

    forward: jax.Array
    right: jax.Array
    up: jax.Array


class SeaHit(NamedTuple):
    """Pixel rays intersected with the mean sea plane z = 0 (see :func:`intersect_sea`).

    Attributes:
        xy: ``(H, W, 2)`` hit position on the sea [m].
        distance: ``(H, W)`` distance from the camera to the hit along the ray [m].
        footprint: ``(H, W)`` square root of the pixel's area on the sea [m].
        mask: ``(H, W)`` bool, True where the ray reaches the sea (False: sky).
        view: ``(H, W, 3)`` unit vector from the hit toward the camera (``-direction``).
        direction: ``(H, W, 3)`` unit ray direction, away from the camera.
    """

    xy: jax.Array
    distance: jax.Array
    footprint: jax.Array
    mask: jax.Array
    view: jax.Array
    direction: jax.Array


# --------------------------------------------------------------------------- construction


def make_camera(
    height=10.0,
    pitch=0.35,
    yaw=0.0,
    fov=0.8,
    resolution=(128, 128),
    *,
    x=0.0,
    y=0.0,
    dtype=None,
) -> Camera:
    """A validated perspective camera.

    Args:
        height: metres above mean sea level.
        pitch: radians of the optical axis below the horizon (positive looks down).
        yaw: azimuth of the viewing direction, radians from +x counter-clockwise.
        fov: vertical field of view, radians.
        resolution: ``(H, W)`` pixels.
        x, y: ground position of the camera, metres.
        dtype: float dtype of the leaves; default: that of the inputs (float32, or
            float64 under ``jax_enable_x64``).

    Array-valued arguments broadcast to one batch shape (every leaf gets it), ready for
    ``jax.vmap``.
    """
    return _build(
        dict(height=height, pitch=pitch, yaw=yaw, fov=fov, x=x, y=y, ortho_width=1.0),
        resolution,
        "perspective",
        dtype,
    )


def make_orthographic(width_m, resolution, x=0.0, y=0.0, yaw=0.0, height=10.0, *, dtype=None) -> Camera:
    """A validated top-down camera: ``width_m`` metres of sea across ``resolution = (H, W)``.

    Ground cells are ``width_m / W`` metres square, centred on ``(x, y)``; the top of the
    image faces azimuth ``yaw`` (``yaw = pi/2``: north up, east right). ``height`` only
    sets the hit distance.
    """
    return _build(
        # pitch pi/2 records "looking straight down"; fov is unused by this projection.
        dict(height=height, pitch=math.pi / 2, yaw=yaw, fov=0.8, x=x, y=y, ortho_width=width_m),
        resolution,
        "orthographic",
        dtype,
    )


def _build(values: dict, resolution, projection: str, dtype) -> Camera:
    dtype = _float_dtype(*values.values()) if dtype is None else dtype
    leaves = jnp.broadcast_arrays(*(jnp.asarray(v, dtype) for v in values.values()))
    camera = Camera(**dict(zip(values, leaves)), resolution=resolution, projection=projection)
    return validate_camera(camera)


def _is_int(n) -> bool:
    return isinstance(n, (int, np.integer)) and not isinstance(n, (bool, np.bool_))


def _float_dtype(*values):
    """The floating dtype the camera computes in: the inputs' own, promoted to float if needed."""
    dtype = jnp.result_type(*values)
    return dtype if jnp.issubdtype(dtype, jnp.inexact) else jnp.result_type(float)


def camera_to_dict(camera: Camera, *, degrees: bool = False) -> dict:
    """A JSON-ready dict of a camera: every leaf (``height``, ``pitch``, ``yaw``, ``fov``,
    ``x``, ``y``, ``ortho_width``) as a float, or nested lists of floats for a batched camera
    (float64 values, exact), plus ``resolution`` ``[H, W]`` and ``projection``. The leaves are
    what ``scene.json`` stores (:mod:`jaxocean.io.scene` reads them back).

    ``degrees=True`` adds ``pitch_deg``, ``yaw_deg`` and ``fov_deg`` for a person reading a
    report (the radians stay the values a reader uses). Host-side: the leaves must be concrete.
    """
    out = {f.name: np.asarray(getattr(camera, f.name), np.float64).tolist()
           for f in dataclasses.fields(Camera) if not f.metadata.get("static")}
    out["resolution"] = list(camera.resolution)
    out["projection"] = camera.projection
    if degrees:
        for name in ("pitch", "yaw", "fov"):
            out[f"{name}_deg"] = np.degrees(np.asarray(out[name], np.float64)).tolist()
    return out


# --------------------------------------------------------------------------- validation


def validate_camera(camera: Camera) -> Camera:
    """Check structure (always) and values (when concrete). Returns ``camera`` unchanged.

    Structure -> ``ValueError``: not a ``Camera``, resolution not two positive ints,
    unknown projection, non-real leaves or leaves of different shapes.
    Values -> :class:`jaxocean.errors.InvalidValueError`: any leaf NaN/inf, height <= 0
    (camera under the sea), fov outside (0, pi), pitch outside (-pi/2, pi/2], and for the
    orthographic projection ortho_width <= 0.
    """
    if not isinstance(camera, Camera):
        raise ValueError(f"expected a jaxocean Camera, got {type(camera).__name__}")
    res = camera.resolution
    if not (isinstance(res, tuple) and len(res) == 2 and all(_is_int(n) and n > 0 for n in res)):
        raise ValueError(f"Camera.resolution must be two positive ints (H, W); got {res!r}")
    if camera.projection not in PROJECTIONS:
        raise ValueError(f"Camera.projection must be one of {PROJECTIONS}; got {camera.projection!r}")
    shapes = {name: jnp.shape(getattr(camera, name)) for name in _DATA_FIELDS}
    if len(set(shapes.values())) != 1:
        raise ValueError(f"Camera leaves must share one (batch) shape; got {shapes}")
    for name in _DATA_FIELDS:
        dtype = jnp.result_type(getattr(camera, name))
        if jnp.issubdtype(dtype, jnp.complexfloating) or not jnp.issubdtype(dtype, jnp.number):
            raise ValueError(f"Camera.{name} must be real; got dtype {dtype}")
    if not is_concrete(camera):
        return camera

    values = {name: np.asarray(getattr(camera, name)) for name in _DATA_FIELDS}
    for name, value in values.items():
        check_values(np.isfinite(value), f"Camera.{name} must be finite", value)
    height, pitch, fov = values["height"], values["pitch"], values["fov"]
    check_values(height > 0, "camera under the sea: Camera.height must be > 0 m above mean sea level", height)
    # Bounds in the leaf's own dtype: float32(pi/2) rounds above pi/2 and must still pass.
    half_pi = np.asarray(np.pi / 2, pitch.dtype if pitch.dtype.kind == "f" else np.float64)
    check_values((pitch > -half_pi) & (pitch <= half_pi),
                 "Camera.pitch must lie in (-pi/2, pi/2] rad below the horizon", pitch)
    pi = np.asarray(np.pi, fov.dtype if fov.dtype.kind == "f" else np.float64)
    check_values((fov > 0) & (fov < pi), "Camera.fov must lie in (0, pi) rad", fov)
    if camera.projection == "orthographic":
        check_values(values["ortho_width"] > 0, "Camera.ortho_width must be > 0 m", values["ortho_width"])
    return camera


def _checked(camera: Camera) -> Camera:
    """Validate, and insist on one camera: batches go through ``jax.vmap``."""
    validate_camera(camera)
    if jnp.shape(camera.height) != ():
        raise ValueError(
            f"this function takes one camera (scalar leaves); got leaves of shape "
            f"{jnp.shape(camera.height)} -- map a batch of cameras with jax.vmap"
        )
    return camera


# --------------------------------------------------------------------------- geometry


def camera_frame(camera: Camera) -> CameraFrame:
    """The camera's forward, right and up unit vectors in world coordinates.

    The orthographic camera uses the frame at pitch pi/2 exactly (forward = -z), whatever
    its ``pitch`` leaf says.
    """
    return _frame(_checked(camera))


def camera_position(camera: Camera) -> jax.Array:
    """World position ``(x, y, height)`` of the camera (the centre of an orthographic one)."""
    return _position(_checked(camera))


def pixel_angle(camera: Camera) -> jax.Array:
    """Angular size [rad] of one pixel at the image centre, ``2 tan(fov/2) / H``.

    Zero for the orthographic camera, whose rays are parallel.
    """
    return _pixel_angle(_checked(camera))


def compute_dtype(camera: Camera):
    """The floating dtype every function of ``camera`` computes in (its leaves' own)."""
    return _float_dtype(*jax.tree_util.tree_leaves(camera))


def _frame(camera: Camera) -> CameraFrame:
    dtype = compute_dtype(camera)
    yaw = jnp.asarray(camera.yaw, dtype)
    if camera.projection == "orthographic":
        # Exact 0 and 1 rather than cos/sin(pi/2), which is off by 1e-8 in float32.
        cos_pitch, sin_pitch = jnp.zeros((), dtype), jnp.ones((), dtype)
    else:
        pitch = jnp.asarray(camera.pitch, dtype)
        cos_pitch, sin_pitch = jnp.cos(pitch), jnp.sin(pitch)
    cos_yaw, sin_yaw = jnp.cos(yaw), jnp.sin(yaw)
    forward = jnp.stack([cos_pitch * cos_yaw, cos_pitch * sin_yaw, -sin_pitch])
    right = jnp.stack([sin_yaw, -cos_yaw, jnp.zeros_like(yaw)])
    # computed once (see _math.materialize): XLA:CPU otherwise re-evaluates the sines and
    # cosines in every per-pixel loop that reads the frame (10-26 ns each)
    return CameraFrame(*materialize(forward, right, jnp.cross(right, forward)))


def _position(camera: Camera) -> jax.Array:
    dtype = compute_dtype(camera)
    return jnp.stack([jnp.asarray(v, dtype) for v in (camera.x, camera.y, camera.height)])


def _pixel_angle(camera: Camera) -> jax.Array:
    if camera.projection == "orthographic":
        return jnp.zeros((), compute_dtype(camera))
    return 2 * _half_extents(camera)[1] / camera.resolution[0]


def _nadir_footprint(camera: Camera) -> jax.Array:
    """Footprint [m] of the pixel straight below the camera: height x pixel angle for the
    pinhole, the ground cell for the orthographic camera."""
    if camera.projection == "orthographic":
        return 2 * _half_extents(camera)[0] / camera.resolution[1]
    return _position(camera)[2] * _pixel_angle(camera)


def _half_extents(camera: Camera):
    """Half the image's width and height on its projection plane.

    Perspective: in units of the focal length (tangents), so that ``D = f + s_u a r + s_v b u``.
    Orthographic: in metres on the ground, so that ``O = centre + s_u a r + s_v b u``.
    Both with ``s_u, s_v`` in [-1, 1] across the image (see :func:`_ndc_grid`).
    """
    H, W = camera.resolution
    dtype = compute_dtype(camera)
    if camera.projection == "orthographic":
        half_width = jnp.asarray(camera.ortho_width, dtype) / 2
        return half_width, half_width * H / W
    half_height = jnp.tan(jnp.asarray(camera.fov, dtype) / 2)
    # computed once, not per pixel in every loop that reads it (measured: the tangent
    # re-evaluated in nine per-pixel loops made intersect_sea 3.3 ms at 256^2)
    return materialize(half_height * W / H, half_height)


def _ndc_grid(resolution, dtype):
    """Pixel-centre coordinates ``s_u = 2 (j + 1/2) / W - 1`` and ``s_v = 1 - 2 (i + 1/2) / H``.

    Both ``(H, W)``; ``s_u`` grows to the right, ``s_v`` upward (row 0 is the top).
    """
    H, W = resolution
    # Integer numerators, so the centre of an odd image is exactly 0 (its ray is exactly
    # the forward axis) even when the compiler turns the division into a multiplication.
    s_u = (2 * jnp.arange(W, dtype=dtype) + (1 - W)) / W
    s_v = ((H - 1) - 2 * jnp.arange(H, dtype=dtype)) / H
    return jnp.broadcast_to(s_u[None, :], (H, W)), jnp.broadcast_to(s_v[:, None], (H, W))


def _pixel_from_ndc(s_u, s_v, resolution):
    """Inverse of :func:`_ndc_grid`: fractional pixel coordinates ``(..., 2)`` as ``(i, j)``."""
    H, W = resolution
    return jnp.stack([(1 - s_v) * H / 2 - 0.5, (s_u + 1) * W / 2 - 0.5], axis=-1)


class _RayField(NamedTuple):
    """Rays ``O + t D`` of every pixel with their derivatives along the pixel grid.

    ``origin`` and ``direction`` (unnormalised) broadcast to ``(H, W, 3)``; the four
    derivatives are ``(3,)``: the image is a linear map of the pixel index, so they are the
    same for every pixel.
    """

    origin: jax.Array
    direction: jax.Array
    d_origin_dj: jax.Array
    d_origin_di: jax.Array
    d_direction_dj: jax.Array
    d_direction_di: jax.Array


def _ray_field(camera: Camera) -> _RayField:
    H, W = camera.resolution
    dtype = compute_dtype(camera)
    forward, right, up = _frame(camera)
    half_u, half_v = _half_extents(camera)
    s_u, s_v = _ndc_grid(camera.resolution, dtype)
    # The image-plane offset of each pixel centre and its change per column / row
    # (d s_u / dj = 2 / W, d s_v / di = -2 / H).
    offset = (s_u * half_u)[..., None] * right + (s_v * half_v)[..., None] * up
    d_offset_dj = (2 * half_u / W) * right
    d_offset_di = (-2 * half_v / H) * up
    centre = _position(camera)
    zero = jnp.zeros(3, dtype)
    if camera.projection == "orthographic":
        # Parallel rays: the offset moves the origin, the direction is fixed.
        return _RayField(centre + offset, forward, d_offset_dj, d_offset_di, zero, zero)
    # Pinhole: one origin, the offset turns the direction.
    return _RayField(centre, forward + offset, zero, zero, d_offset_dj, d_offset_di)


def pixel_rays(camera: Camera):
    """Ray origins and unit directions of every pixel centre.

    Returns:
        ``(origins, directions)``: origins ``(3,)`` for the perspective camera (one
        pinhole) or ``(H, W, 3)`` for the orthographic one, so always broadcastable to
        ``(H, W, 3)``; directions ``(H, W, 3)``, unit length.
    """
    return _pixel_rays(_checked(camera))


# The public functions validate eagerly, then call a compiled body: one compilation per
# (resolution, projection, dtype) instead of dispatching dozens of small ops one by one.
@jax.jit
def _pixel_rays(camera: Camera):
    rays = _ray_field(camera)
    H, W = camera.resolution
    return rays.origin, safe_normalize(jnp.broadcast_to(rays.direction, (H, W, 3)))


def intersect_sea(camera: Camera, *, max_distance=DEFAULT_MAX_DISTANCE) -> SeaHit:
    """Intersect every pixel ray with the mean sea plane z = 0.

    A pixel is sea (``mask`` True) when its unit ray has ``z < -DOWNWARD_THRESHOLD`` and
    the hit lies within ``max_distance`` metres of the camera. Sky pixels keep their true
    ``direction`` and ``view``; their ``xy``, ``distance`` and ``footprint`` are those of the
    point straight below the camera (``distance = height``; footprint ``height * pixel_angle``,
    or the cell size for the orthographic camera) with zero gradient.

    The footprint is analytic: the square root of the area of the pixel's quadrilateral on
    the sea, from the Jacobian of the hit with respect to the pixel index. With
    ``X = O + t D``, ``t = -O_z / D_z`` and ``O_z`` the same for every pixel::

        dX/dj = dO/dj + t (dD/dj - D (dD_z/dj) / D_z)      (likewise d/di)
        area  = |(dX/dj x dX/di)_z|

    (``dO`` vanishes for the pinhole, ``dD`` for the orthographic camera, whose footprint is
    thus the ground cell size.)

    Args:
        camera: one camera (map batches with ``jax.vmap``).
        max_distance: hits farther than this [m] count as sky; may be ``inf``.

    Returns:
        :class:`SeaHit` with ``(H, W, ...)`` fields.
    """
    _checked(camera)
    check_values(jnp.asarray(max_distance) > 0, "max_distance must be > 0 m", max_distance)
    return _intersect_sea(camera, max_distance)


@jax.jit
def _intersect_sea(camera: Camera, max_distance) -> SeaHit:
    rays = _ray_field(camera)
    H, W = camera.resolution
    origin = jnp.broadcast_to(rays.origin, (H, W, 3))
    raw_direction = jnp.broadcast_to(rays.direction, (H, W, 3))
    direction = safe_normalize(raw_direction)
    goes_down = direction[..., 2] < -DOWNWARD_THRESHOLD

    # Double where, first half: rays that do not go down are swapped for a straight-down
    # stand-in before dividing by D_z, so neither values nor gradients ever see D_z ~ 0.
    straight_down = jnp.zeros(3, direction.dtype).at[2].set(-1)
    D = jnp.where(goes_down[..., None], raw_direction, straight_down)
    D_z = D[..., 2]
    t = -origin[..., 2] / D_z  # ray parameter along the unnormalised D
    hit = origin + t[..., None] * D
    distance = t * safe_norm(D)

    def d_hit(d_origin, d_direction):
        # d/dpixel of X = O + t D with t = -O_z / D_z and dO_z = 0 (see the docstring).
        return d_origin + t[..., None] * (d_direction - D * (d_direction[2] / D_z)[..., None])

    dX_dj = d_hit(rays.d_origin_dj, rays.d_direction_dj)
    dX_di = d_hit(rays.d_origin_di, rays.d_direction_di)
    area = jnp.abs(dX_dj[..., 0] * dX_di[..., 1] - dX_dj[..., 1] * dX_di[..., 0])
    footprint = safe_sqrt(area)

    mask = goes_down & (distance <= max_distance)
    # Second half: sky pixels report the stand-in (nadir) geometry, cut off from the
    # gradient. The stand-in already puts xy below the camera at distance = height; its
    # footprint would depend on the pitch, so the nadir footprint replaces it.
    return SeaHit(
        xy=_sea_or_frozen(mask[..., None], hit[..., :2], hit[..., :2]),
        distance=_sea_or_frozen(mask, distance, distance),
        footprint=_sea_or_frozen(mask, footprint, jnp.broadcast_to(_nadir_footprint(camera), (H, W))),
        mask=mask,
        view=-direction,
        direction=direction,
    )


def _sea_or_frozen(mask, sea_value, sky_value):
    """``sea_value`` where ``mask``; elsewhere ``sky_value`` with its gradient stopped."""
    return jnp.where(mask, sea_value, jax.lax.stop_gradient(sky_value))


def project(camera: Camera, points) -> jax.Array:
    """World points ``(..., 3)`` to fractional pixel coordinates ``(..., 2)`` as ``(i, j)``.

    The inverse of :func:`pixel_rays`: a point on the ray of pixel ``(i, j)`` projects to
    ``(i, j)`` exactly; coordinates outside ``[-0.5, H - 0.5] x [-0.5, W - 0.5]`` are off the
    image. Perspective points at or behind the camera plane (depth <= 0) are projected as if
    at a tiny positive depth, i.e. far outside the image, never to NaN.
    """
    _checked(camera)
    points = jnp.asarray(points)
    if points.ndim < 1 or points.shape[-1] != 3:
        raise ValueError(f"project expects points of shape (..., 3); got {points.shape}")
    return _project(camera, points)


@jax.jit
def _project(camera: Camera, points) -> jax.Array:
    forward, right, up = _frame(camera)
    half_u, half_v = _half_extents(camera)
    relative = points - _position(camera)
    along_right = jnp.sum(relative * right, axis=-1)
    along_up = jnp.sum(relative * up, axis=-1)
    if camera.projection == "perspective":
        depth = jnp.sum(relative * forward, axis=-1)
        # a point on the optical axis at or behind the camera (the camera itself included)
        # would divide 0 by 0 into the image centre: offset it upward, off the image like
        # every other point behind the camera plane
        on_axis_behind = (depth <= 0) & (along_right == 0) & (along_up == 0)
        along_up = jnp.where(on_axis_behind, 1.0, along_up)
        depth = jnp.maximum(depth, 0)
        along_right = safe_divide(along_right, depth)
        along_up = safe_divide(along_up, depth)
    return _pixel_from_ndc(along_right / half_u, along_up / half_v, camera.resolution)


def horizon_row(camera: Camera) -> jax.Array:
    """Fractional row of the horizon (rays with z = 0); it may lie outside the image.

    Rows above it (smaller ``i``) see the sky. The camera has no roll, so the horizon is a
    horizontal line: ``D_z = -sin p + s_v tan(fov/2) cos p = 0`` gives
    ``s_v = tan p / tan(fov/2)``. Looking straight down it is far above the image (a large
    negative row, finite); the orthographic camera has none and returns ``-inf``.
    """
    return _horizon_row(_checked(camera))


@jax.jit
def _horizon_row(camera: Camera) -> jax.Array:
    dtype = compute_dtype(camera)
    if camera.projection == "orthographic":
        return jnp.full((), -jnp.inf, dtype)
    pitch = jnp.asarray(camera.pitch, dtype)
    # cos p is floored at 0 (float32 pi/2 has cos p = -4e-8) and safe_divide floors it
    # further to a tiny positive number, so pitch -> pi/2 sends the row to -huge, not NaN.
    s_v = safe_divide(jnp.sin(pitch), jnp.maximum(jnp.cos(pitch), 0) * _half_extents(camera)[1])
    return _pixel_from_ndc(jnp.zeros_like(s_v), s_v, camera.resolution)[..., 0]
