"""Rectification: real frames from a moving, rolled, distorting camera -> the library camera.

The rest of jaxocean sees the sea through one ideal :class:`jaxocean.camera.Camera` per
sequence: a pinhole without roll or lens distortion at a fixed height. A ship-borne camera
(:mod:`jaxocean.io.camera_file`, :mod:`jaxocean.lens`) heaves, pitches, rolls and yaws from
frame to frame behind a distorting lens. :func:`rectify` resamples every real frame into one
*virtual* library camera (:func:`virtual_camera`: the sequence's mean pose with zero roll),
so that the frames can be treated as taken by that camera; :func:`unrectify` is the inverse
warp (a virtual image seen by the real camera of a frame: synthetic tests, and re-rendered
frames shown in the original view).

Protocol
--------
* Images are ``(T, h, w)`` or ``(T, h, w, C)`` arrays of any real dtype (display or linear
  values, whatever the caller gives), resampled in float32 (float64 when given float64);
  poses a :class:`jaxocean.lens.Pose` with ``(T,)`` leaves (scalar leaves: one pose for every
  frame). Outputs are ``(T, H, W[, C])`` for ``camera.resolution == (H, W)`` and ``valid``
  ``(T, H, W)`` bool; invalid pixels hold 0.
* Mapping of a virtual pixel ray (from the virtual camera's centre): a *sea* ray (the
  library's rule, :func:`jaxocean.camera.intersect_sea`: it goes down by more than
  ``DOWNWARD_THRESHOLD`` and hits within ``DEFAULT_MAX_DISTANCE``) is intersected with the
  mean sea plane z = 0 and the hit point is projected into the frame's real camera (its own
  height, pitch, roll, heading, east, north and distortion). This is the standard
  georectification, exact for points on z = 0. A *sky* ray maps by its direction alone
  (rotation only: a point at infinity). :func:`unrectify` applies the same rule to the real
  camera's rays and projects into the virtual camera.
* Sampling is bilinear (the outer half pixel takes the edge pixels' values). ``valid`` is
  False where a sample falls outside the source image's area ``[-1/2, w - 1/2] x
  [-1/2, h - 1/2]`` (pixel centres at integers), behind the source camera, beyond the lens's
  one-to-one radius (:func:`jaxocean.lens.max_radius`), or where ``source_mask`` (optional,
  e.g. vignetted corners or a speck on the window) is not fully True under the bilinear
  footprint.
* Anti-aliasing: when a target pixel covers more than one source pixel (640x480 -> 256x192
  covers about 2.5 at the centre), each target pixel averages a ``k x k`` grid of sub-pixel samples;
  ``k`` is the largest source-pixels-per-target-pixel ratio over the image (at the virtual
  pose, rounded up, capped at :data:`MAX_SUPERSAMPLE`), and ``supersample=k`` overrides it.
  A target pixel is valid only when all its samples are.

Accuracy of the single sea plane
--------------------------------
The mapping is exact for points on z = 0 only. Take a frame whose camera is ``dh`` higher
than the virtual camera's height ``h``, and a surface point at horizontal range ``d`` and
elevation ``eta`` (in the vertical plane of the ray, both cameras above the same ground
point). The virtual ray through it meets z = 0 at range ``x0 = d h / (h - eta)``; the real
ray through that point of z = 0 crosses the elevation ``eta`` at
``x1 = x0 (h + dh - eta) / (h + dh)``. The rectified pixel therefore shows the surface at
``x1`` instead of ``d``::

    x1 - d = eta d dh / ((h - eta) (h + dh))  ~  eta d dh / h^2

and a horizontal offset ``ds`` of the frame's camera (along the view) adds ``eta ds / h``.
The frame also sees the point from a direction that differs by about ``dh / d`` in
elevation angle (``ds h / d^2`` for the offset), which matters for shading (slopes,
reflections), not for the geometry. For a 12 m camera heaving by +-2 m, a 1 m crest at
50 m range: ``1 * 50 * 2 / (11 * 14) = 0.65 m`` of horizontal displacement (about 1 % of
the 56-100 m wavelength of 6-8 s deep-water waves, and half the 1.2 m range extent of one
pixel there for a 192-row virtual camera with a 65 degree field of view), and a view
direction off by 2 / 50 = 0.04 rad (2.3 degrees); a 1.2 m horizontal offset adds
``1 * 1.2 / 12 = 0.1 m``. The displacement grows linearly with range, a pixel's extent in
range faster (``d^2 / h`` times the pixel angle).

Speed: 150 grey 640x480 frames rectified to 192x256 (k = 3, 9 samples per pixel) take
2.5-5.3 s on this 2-core machine while other jobs kept its load average at 9-10 (the slow
benchmark in ``tests/test_rectify.py`` and a run on real footage, timed after one warm-up
call; compiling adds about 2 s once).
"""

from __future__ import annotations

import math
from functools import partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean import lens
from jaxocean.camera import DEFAULT_MAX_DISTANCE, DOWNWARD_THRESHOLD, Camera, make_camera, validate_camera
from jaxocean.lens import Distortion, Intrinsics, Pose

__all__ = [
    "MAX_SUPERSAMPLE",
    "Rectified",
    "virtual_camera",
    "supersample_factor",
    "rectify",
    "unrectify",
    "warp_to_frame",
]

# At most MAX_SUPERSAMPLE^2 samples per target pixel (a 7x reduction still gets a sample
# per source pixel; the cost grows as k^2).
MAX_SUPERSAMPLE = 8


class Rectified(NamedTuple):
    """Resampled ``images`` ``(T, H, W[, C])`` (0 where invalid) and ``valid`` ``(T, H, W)`` bool."""

    images: jax.Array
    valid: jax.Array


# --------------------------------------------------------------------------- the virtual camera


def virtual_camera(source, intrinsics: Intrinsics | None = None, image_size=None, *, resolution, fov=None) -> Camera:
    """The library camera that a sequence of real frames is rectified into.

    Args:
        source: a :class:`jaxocean.io.camera_file.CameraFile` (its poses, intrinsics and
            image size; then ``intrinsics`` and ``image_size`` stay None), or a
            :class:`jaxocean.lens.Pose` of ``(T,)`` (or scalar) leaves, given with
            ``intrinsics`` and ``image_size = (W, H)``.
        resolution: ``(H, W)`` of the virtual camera.
        fov: vertical field of view [rad]; default: the real camera's at the image centre,
            ``2 atan(H / (2 fy))``.

    Returns:
        A perspective :class:`jaxocean.camera.Camera` (float32 leaves, or float64 under
        x64) at the mean height, mean pitch, circular-mean heading (as library yaw,
        :func:`jaxocean.lens.yaw_from_heading`), mean east / north as ``x`` / ``y``; it has
        no roll.
    """
    poses = _source_poses(source)
    if hasattr(source, "intrinsics"):
        if intrinsics is not None or image_size is not None:
            raise ValueError("virtual_camera: give a CameraFile alone, or poses with intrinsics and image_size")
        intrinsics, image_size = source.intrinsics, source.image_size
    if intrinsics is None or image_size is None:
        raise ValueError("virtual_camera: poses need intrinsics and image_size = (W, H)")
    _, H_real = _image_size(image_size)
    leaves = {name: np.asarray(value, np.float64).ravel() for name, value in poses._asdict().items()}
    heading = math.atan2(np.mean(np.sin(leaves["heading"])), np.mean(np.cos(leaves["heading"])))
    if fov is None:
        fov = 2 * math.atan(H_real / (2 * float(intrinsics.fy)))
    return make_camera(
        height=float(np.mean(leaves["height"])), pitch=float(np.mean(leaves["pitch"])),
        yaw=float(lens.yaw_from_heading(heading)), fov=float(fov), resolution=tuple(resolution),
        x=float(np.mean(leaves["east"])), y=float(np.mean(leaves["north"])),
    )


def _source_poses(source) -> Pose:
    poses = getattr(source, "poses", source)
    if poses is None:
        raise ValueError("virtual_camera: the camera file gives no poses (estimate them first)")
    if not isinstance(poses, Pose):
        raise ValueError(f"virtual_camera: expected a CameraFile or a lens.Pose; got {type(source).__name__}")
    return poses


def _image_size(image_size) -> tuple[int, int]:
    if len(image_size) != 2 or not all(int(n) == n and n > 0 for n in image_size):
        raise ValueError(f"image_size must be two positive ints (W, H); got {image_size!r}")
    return int(image_size[0]), int(image_size[1])


# --------------------------------------------------------------------------- geometry


def _virtual_params(camera: Camera):
    """Pose and pinhole intrinsics of a library camera, as :mod:`jaxocean.lens` sees it."""
    return lens.pose_of(camera), lens.pinhole_intrinsics(camera)


def _subpixel_offsets(k: int) -> np.ndarray:
    """The ``k`` offsets ``(a + 1/2)/k - 1/2`` of a ``k``-point grid across one pixel."""
    return (np.arange(k) + 0.5) / k - 0.5


def _sample_grid(H: int, W: int, k: int, dtype) -> jax.Array:
    """``(k * k, H, W, 2)`` pixel coordinates ``(u, v)`` of every sub-pixel sample.

    The sample axis leads: XLA:CPU vectorises along the long pixel axes then (measured: a
    trailing ``(k, k)`` made k = 3 cost 22x k = 1 instead of about 9x)."""
    o = _subpixel_offsets(k)
    v = o[:, None, None, None] + np.arange(H)[None, None, :, None]
    u = o[None, :, None, None] + np.arange(W)[None, None, None, :]
    v, u = np.broadcast_arrays(v, u)
    return jnp.asarray(np.stack([u, v], axis=-1).reshape(k * k, H, W, 2), dtype)


def _directions_to_pixels(vectors, pose, intrinsics, distortion, radius_limit):
    """World vectors ``(..., 3)`` (directions, or points relative to the camera centre) to
    pixel coordinates ``(..., 2)`` of a camera rotated by ``pose``, and ``ok``: in front of it
    and within the lens's one-to-one radius ``radius_limit`` (undistorted)."""
    dtype = vectors.dtype
    p = lens._rotate(lens._rotation(pose, dtype), vectors)
    x, y, depth = p[..., 0], p[..., 1], p[..., 2]
    in_front = depth > 0
    safe_depth = jnp.where(in_front, depth, 1)
    xy = jnp.stack([x / safe_depth, y / safe_depth], axis=-1)
    inside_lens = xy[..., 0] ** 2 + xy[..., 1] ** 2 <= radius_limit**2
    xy_d = lens._distort(xy, *lens._leaves(distortion, dtype))
    return lens.denormalize(xy_d, intrinsics), in_front & inside_lens


def _map_rays(origin, directions, pose, intrinsics, distortion, radius_limit):
    """Where rays ``origin + t directions`` (``(..., 3)``, unit) land in another camera.

    Sea rays (the library's rule) go through their hit on z = 0, sky rays by direction.
    Returns ``uv`` ``(..., 2)`` in the other camera and ``ok`` ``(...)``: in front of it and
    within the lens's one-to-one radius (the image bounds are checked by the sampler).
    """
    d_z = directions[..., 2]
    sea = d_z < -DOWNWARD_THRESHOLD
    t = origin[2] / jnp.where(sea, -d_z, 1)
    sea = sea & (t <= DEFAULT_MAX_DISTANCE)
    hit_from_camera = origin + t[..., None] * directions - lens._centre(pose, directions.dtype)
    # sea: the hit point relative to the other camera; sky: the direction (at infinity)
    vectors = jnp.where(sea[..., None], hit_from_camera, directions)
    return _directions_to_pixels(vectors, pose, intrinsics, distortion, radius_limit)


def _bilinear(image, mask, uv):
    """Sample ``image`` ``(h, w[, C])`` at ``uv`` ``(..., 2)``: values ``(...[, C])`` and
    ``ok`` ``(...)``: inside the image's area ``[-1/2, w - 1/2] x [-1/2, h - 1/2]`` (the
    outer half pixel takes the edge pixels' values) and, when ``mask`` ``(h, w)`` is given,
    every neighbour with a positive weight True."""
    h, w = image.shape[:2]
    u, v = uv[..., 0], uv[..., 1]
    ok = (u >= -0.5) & (u <= w - 0.5) & (v >= -0.5) & (v <= h - 0.5)
    u = jnp.clip(u, 0, w - 1)
    v = jnp.clip(v, 0, h - 1)
    u0 = jnp.clip(jnp.floor(u), 0, max(w - 2, 0))
    v0 = jnp.clip(jnp.floor(v), 0, max(h - 2, 0))
    fu, fv = u - u0, v - v0
    i0, j0 = v0.astype(jnp.int32), u0.astype(jnp.int32)
    i1, j1 = jnp.minimum(i0 + 1, h - 1), jnp.minimum(j0 + 1, w - 1)
    if mask is not None:
        for i, j, weight in ((i0, j0, (1 - fu) * (1 - fv)), (i0, j1, fu * (1 - fv)),
                             (i1, j0, (1 - fu) * fv), (i1, j1, fu * fv)):
            ok = ok & (mask[i, j] | (weight <= 0))
    # one gather per neighbour from the flattened image (XLA:CPU gathers rows of a 2-D
    # table faster than it does 2-D indices)
    flat = image.reshape(h * w, -1)
    corner = [jnp.take(flat, i * w + j, axis=0) for i, j in ((i0, j0), (i0, j1), (i1, j0), (i1, j1))]
    fu, fv = fu[..., None], fv[..., None]
    top = corner[0] * (1 - fu) + corner[1] * fu
    bottom = corner[2] * (1 - fu) + corner[3] * fu
    values = top * (1 - fv) + bottom * fv
    return (values if image.ndim == 3 else values[..., 0]), ok


def supersample_factor(poses: Pose, intrinsics: Intrinsics, distortion: Distortion, image_size, camera: Camera,
                       *, inverse: bool = False) -> int:
    """The ``k`` of the ``k x k`` sub-pixel grid: the largest number of source pixels one
    target pixel spans (along either image axis, over the target pixels whose samples land
    in the source image), rounded up and capped at :data:`MAX_SUPERSAMPLE`. Measured by
    direction at the mean pose (heave and offsets change it little).

    ``inverse=False``: target = the virtual camera, source = the real frames (rectify);
    ``inverse=True``: the other way round (unrectify).
    """
    leaves = [np.asarray(leaf, np.float64) for leaf in poses]
    mean = Pose(*(float(np.mean(leaf)) for leaf in leaves))
    mean = mean._replace(heading=float(np.angle(np.mean(np.exp(1j * leaves[3])))))
    v_pose, v_intrinsics = _virtual_params(camera)
    W_real, H_real = _image_size(image_size)
    real = (mean, intrinsics, distortion, (H_real, W_real))
    virtual = (v_pose, v_intrinsics, Distortion(), tuple(camera.resolution))
    (src_pose, src_intr, src_dist, (H_src, W_src)), (dst_pose, dst_intr, dst_dist, (H_dst, W_dst)) = (
        (virtual, real) if inverse else (real, virtual))
    # target pixel centres on a grid of at most 64 x 64, and their neighbours half a pixel
    # away on either side, mapped by direction into the source camera
    v, u = np.meshgrid(np.linspace(0, H_dst - 1, min(H_dst, 64)), np.linspace(0, W_dst - 1, min(W_dst, 64)),
                       indexing="ij")
    uv = np.stack([u, v], -1)
    with jax.enable_x64(True):
        radius = float(lens.max_radius(src_dist))
        spans = []
        for step in ([0.5, 0.0], [0.0, 0.5]):
            ends = []
            for sign in (-1, 1):
                rays = lens.pixel_rays(uv + sign * np.asarray(step), dst_pose, dst_intr, dst_dist)
                uv_src, ok = _directions_to_pixels(rays, src_pose, src_intr, src_dist, radius)
                uv_src, ok = np.array(uv_src), np.array(ok)
                ok &= (uv_src[..., 0] >= -0.5) & (uv_src[..., 0] <= W_src - 0.5)
                ok &= (uv_src[..., 1] >= -0.5) & (uv_src[..., 1] <= H_src - 0.5)
                ends.append((uv_src, ok))
            (a, ok_a), (b, ok_b) = ends
            spans.append(np.where(ok_a & ok_b, np.abs(b - a).max(axis=-1), 0.0))
    ratio = float(np.max(spans))
    return int(min(MAX_SUPERSAMPLE, max(1, math.ceil(ratio - 1e-3))))


# --------------------------------------------------------------------------- resampling


def _check_images(images, image_size, what):
    images = jnp.asarray(images)
    if images.ndim not in (3, 4):
        raise ValueError(f"{what}: images must be (T, h, w) or (T, h, w, C); got shape {images.shape}")
    if images.ndim == 3 and images.shape[-1] == 3:
        raise ValueError(f"{what}: images of shape {images.shape} read as frames 3 pixels wide; one RGB frame "
                         "is images[None] (a sequence (T, h, w, C))")
    if not (jnp.issubdtype(images.dtype, jnp.floating) or jnp.issubdtype(images.dtype, jnp.integer)):
        raise ValueError(f"{what}: images must be real numbers; got dtype {images.dtype}")
    if image_size is not None:
        W, H = _image_size(image_size)
        if images.shape[1:3] != (H, W):
            raise ValueError(f"{what}: images of {images.shape[2]}x{images.shape[1]} (w x h) do not match the "
                             f"camera's image_size {W}x{H}")
    dtype = jnp.float64 if images.dtype == jnp.float64 else jnp.float32
    return images.astype(dtype)


def _check_poses(poses: Pose, T: int, what: str) -> Pose:
    if not isinstance(poses, Pose):
        raise ValueError(f"{what}: poses must be a lens.Pose; got {type(poses).__name__}")
    out = []
    for name, leaf in poses._asdict().items():
        leaf = np.asarray(leaf, np.float64)
        if leaf.ndim == 0:
            leaf = np.full(T, float(leaf))
        if leaf.shape != (T,):
            raise ValueError(f"{what}: Pose.{name} must be a scalar or have shape ({T},) for {T} frames; "
                             f"got {leaf.shape}")
        if not np.all(np.isfinite(leaf)):
            raise ValueError(f"{what}: Pose.{name} must be finite")
        out.append(leaf)
    if np.any(out[0] <= 0):
        raise ValueError(f"{what}: Pose.height must be > 0 (camera above mean sea level)")
    return Pose(*out)


def _check_intrinsics(intrinsics: Intrinsics, shape_hw, what):
    h, w = shape_hw
    fx, fy, cx, cy = (float(v) for v in intrinsics)
    if not all(math.isfinite(v) for v in (fx, fy, cx, cy)):
        raise ValueError(f"{what}: intrinsics must be finite; got fx={fx}, fy={fy}, cx={cx}, cy={cy}")
    if not (fx > 0 and fy > 0):
        raise ValueError(f"{what}: focal lengths must be > 0; got fx={fx}, fy={fy}")
    if not (-0.5 <= cx <= w - 0.5 and -0.5 <= cy <= h - 0.5):
        raise ValueError(f"{what}: the principal point ({cx}, {cy}) lies outside the {w}x{h} images: "
                         "intrinsics and images do not belong together")


def _check_distortion(distortion: Distortion, what):
    # a non-finite coefficient maps every pixel to NaN: all invalid, silently
    values = [float(v) for v in distortion]
    if not all(math.isfinite(v) for v in values):
        raise ValueError(f"{what}: distortion coefficients must be finite; got {dict(zip(Distortion._fields, values))}")


def _check_camera(camera: Camera, what):
    validate_camera(camera)
    if camera.projection != "perspective" or jnp.shape(camera.height) != ():
        raise ValueError(f"{what}: the virtual camera must be one perspective camera")


def _leaf_array(record, dtype):
    return jnp.asarray(np.asarray([float(v) for v in record]), dtype)


@partial(jax.jit, static_argnames=("k", "resolution", "inverse"))
def _resample(images, source_mask, poses, intrinsics, distortion, v_pose, v_intrinsics, radius, *, k, resolution,
              inverse):
    """The shared kernel of rectify (``inverse=False``) and unrectify (``inverse=True``)."""
    dtype = images.dtype
    H, W = resolution
    grid = _sample_grid(H, W, k, dtype)  # (k * k, H, W, 2) target pixel coordinates
    v_pose = Pose(*v_pose)
    v_intrinsics = Intrinsics(*v_intrinsics)
    intrinsics = Intrinsics(*intrinsics)
    distortion = Distortion(*distortion)
    if not inverse:
        v_rays = lens.pixel_rays(grid, v_pose, v_intrinsics, Distortion(), iterations=0)
        v_origin = lens._centre(v_pose, dtype)

    def one(args):
        image, pose_leaves = args
        pose = Pose(*pose_leaves)
        if inverse:
            # real pixel rays into the virtual camera; the virtual image is the source
            rays = lens.pixel_rays(grid, pose, intrinsics, distortion)
            uv, ok = _map_rays(lens._centre(pose, dtype), rays, v_pose, v_intrinsics, Distortion(), jnp.inf)
        else:
            uv, ok = _map_rays(v_origin, v_rays, pose, intrinsics, distortion, radius)
        values, inside = _bilinear(image, source_mask, uv)
        ok = ok & inside
        # The mean over the k^2 samples as a dot product: XLA:CPU fuses a reduction with
        # the gathers and projection that produce it into slow scalar code, but never fuses
        # a dot (see _math.materialize). Measured on this loaded 2-core machine at k = 3,
        # 192 x 256: 72-97 ms per frame with jnp.mean / jnp.all, 17 ms with the dots.
        n = values.shape[0]
        mean = jnp.tensordot(jnp.full((n,), 1 / n, dtype), values, axes=1)
        valid = jnp.tensordot(jnp.ones((n,), dtype), ok.astype(dtype), axes=1) > n - 0.5
        # a non-finite source pixel makes every output it feeds invalid, not a valid NaN
        valid = valid & (jnp.all(jnp.isfinite(mean), axis=-1) if mean.ndim == 3 else jnp.isfinite(mean))
        mean = jnp.where(valid[..., None] if mean.ndim == 3 else valid, mean, 0)
        return mean, valid

    pose_stack = jnp.stack([jnp.asarray(leaf, dtype) for leaf in poses], axis=-1)
    return jax.lax.map(one, (images, pose_stack))


def rectify(images, poses: Pose, intrinsics: Intrinsics, distortion: Distortion, camera: Camera, *,
            supersample: int | None = None, image_size=None, source_mask=None) -> Rectified:
    """Resample real frames into the virtual library camera (module docstring).

    Args:
        images: ``(T, h, w)`` or ``(T, h, w, C)`` real frames.
        poses: :class:`jaxocean.lens.Pose`, leaves ``(T,)`` or scalars.
        intrinsics, distortion: the real camera's lens (:mod:`jaxocean.lens`).
        camera: the virtual perspective :class:`jaxocean.camera.Camera` (e.g.
            :func:`virtual_camera`); its resolution ``(H, W)`` is the output's.
        supersample: ``k`` of the ``k x k`` sub-pixel grid; default
            :func:`supersample_factor`.
        image_size: ``(W, H)`` the intrinsics belong to (a camera file's); when given, the
            images must have it.
        source_mask: optional ``(h, w)`` bool, True where the real frames' pixels are usable.

    Returns:
        :class:`Rectified` ``(images (T, H, W[, C]), valid (T, H, W))``.

    Raises:
        ValueError: wrong ndim, images that do not match ``image_size`` or the intrinsics
            (principal point outside them), non-finite intrinsics, distortion or poses,
            poses not of ``T`` frames, a batched or
            orthographic camera, ``supersample < 1``.
    """
    return _warp(images, poses, intrinsics, distortion, camera, supersample=supersample, image_size=image_size,
                 source_mask=source_mask, inverse=False, what="rectify")


def unrectify(images_virtual, poses: Pose, intrinsics: Intrinsics, distortion: Distortion, image_size,
              camera: Camera, *, supersample: int | None = None, source_mask=None) -> Rectified:
    """The inverse warp: virtual-camera images ``(T, H, W[, C])`` seen by each frame's real
    camera, ``(T, h, w[, C])`` for ``image_size = (w, h)``, and ``valid`` ``(T, h, w)``.

    The same rule as :func:`rectify` with the cameras' roles swapped: each real pixel's ray
    (through its hit on z = 0 if it goes down, else by direction) is projected into the
    virtual camera. ``source_mask`` ``(H, W)`` marks usable virtual pixels.
    """
    return _warp(images_virtual, poses, intrinsics, distortion, camera, supersample=supersample,
                 image_size=image_size, source_mask=source_mask, inverse=True, what="unrectify")


def warp_to_frame(image_virtual, pose: Pose, intrinsics: Intrinsics, distortion: Distortion, image_size,
                  camera: Camera, *, supersample: int | None = None) -> Rectified:
    """One virtual image ``(H, W[, C])`` seen by one real camera (scalar ``pose``):
    :func:`unrectify` of a single frame, ``(h, w[, C])`` and ``valid`` ``(h, w)``."""
    image_virtual = jnp.asarray(image_virtual)
    out = unrectify(image_virtual[None], pose, intrinsics, distortion, image_size, camera, supersample=supersample)
    return Rectified(out.images[0], out.valid[0])


def _warp(images, poses, intrinsics, distortion, camera, *, supersample, image_size, source_mask, inverse, what):
    _check_camera(camera, what)
    if inverse:
        images = _check_images(images, camera.resolution[::-1], what)
        if image_size is None:
            raise ValueError(f"{what}: image_size (W, h) of the real camera is required")
        W_real, H_real = _image_size(image_size)
        resolution = (H_real, W_real)
    else:
        images = _check_images(images, image_size, what)
        H_real, W_real = images.shape[1:3]
        resolution = tuple(camera.resolution)
    _check_intrinsics(intrinsics, (H_real, W_real), what)
    _check_distortion(distortion, what)
    T = images.shape[0]
    poses = _check_poses(poses, T, what)
    if supersample is None:
        k = supersample_factor(poses, intrinsics, distortion, (W_real, H_real), camera, inverse=inverse)
    else:
        k = int(supersample)
        if k != supersample or k < 1:
            raise ValueError(f"{what}: supersample must be a positive int; got {supersample!r}")
    if source_mask is not None:
        source_mask = jnp.asarray(source_mask)
        if source_mask.dtype != jnp.bool_ or source_mask.shape != images.shape[1:3]:
            raise ValueError(f"{what}: source_mask must be bool of shape {images.shape[1:3]}; got "
                             f"{source_mask.dtype} {source_mask.shape}")
    dtype = images.dtype
    v_pose, v_intrinsics = _virtual_params(camera)
    with jax.enable_x64(True):
        radius = float(lens.max_radius(distortion))
    values, valid = _resample(
        images, source_mask, tuple(jnp.asarray(leaf, dtype) for leaf in poses), _leaf_array(intrinsics, dtype),
        _leaf_array(distortion, dtype), _leaf_array(v_pose, dtype), _leaf_array(v_intrinsics, dtype),
        jnp.asarray(radius, dtype), k=k, resolution=resolution, inverse=inverse)
    return Rectified(values, valid)
