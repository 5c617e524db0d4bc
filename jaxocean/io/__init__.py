"""File formats: OpenEXR frames, ``scene.json``, images and video (docs/design.md, *Files*).

A rendered or observed sequence is a directory::

    scene.json           waves, camera, lighting, spectrum, frame times, seed, version
    frame_00000.exr      R G B linear radiance [+ normal.X/Y/Z, roughness, slope_variance.X/Y, mask,
                         converged]
    frame_00001.exr
    ...

* :mod:`jaxocean.io.exr`     -- :func:`write_frame` / :func:`read_frame` and the channel
  protocol; :func:`read_radiance` for any OpenEXR image (colour or grayscale).
* :mod:`jaxocean.io.scene`   -- :func:`scene_to_dict` / :func:`scene_from_dict`,
  :func:`write_scene` / :func:`read_scene`.
* :mod:`jaxocean.io.sequence` -- :func:`write_sequence`: a rendered sequence (EXR + PNG
  per frame, geometry previews, ``scene.json``) in one call.
* :mod:`jaxocean.io.camera_file` -- :func:`read_camera_file` / :func:`write_camera_file`:
  real footage's intrinsics, lens distortion and per-frame pose (``camera.json``).
* :mod:`jaxocean.io.images`  -- :func:`load_image` / :func:`load_video` (display-referred
  pixels back to linear radiance) and :func:`save_png` previews.

Writes are atomic (:func:`jaxocean.files.atomic_write`, re-exported here as
:func:`atomic_write`): a file under its final name is always complete, so an interrupted job
resumes by skipping the files that exist. Reading errors name the file
(:class:`FileFormatError`, :class:`MissingFileError`). This is host-side code: readers
return NumPy arrays (frames, images) or JAX pytrees (scenes); nothing here is jitted.
"""

from jaxocean.io import camera_file, exr, images, scene, sequence
from jaxocean.io.camera_file import CameraFile, CameraFileError, read_camera_file, write_camera_file
from jaxocean.io.exr import (
    COMPRESSIONS,
    GEOMETRY_CHANNELS,
    GRAY_CHANNEL,
    META_PREFIX,
    NORMAL_CHANNELS,
    RGB_CHANNELS,
    SLOPE_VARIANCE_CHANNELS,
    FileFormatError,
    Frame,
    FrameError,
    IncompleteFrameWarning,
    MissingFileError,
    atomic_write,
    read_frame,
    read_radiance,
    write_frame,
)
from jaxocean.io.images import VIDEO_SUFFIXES, load_image, load_video, save_png
from jaxocean.io.scene import (
    SCENE_FILENAME,
    Scene,
    SceneError,
    SceneFileError,
    read_scene,
    scene_from_dict,
    scene_to_dict,
    write_scene,
)
from jaxocean.io.sequence import HALF_MAX, frame_name, write_sequence

__all__ = [
    "camera_file",
    "exr",
    "images",
    "scene",
    "sequence",
    # frames
    "RGB_CHANNELS",
    "GRAY_CHANNEL",
    "NORMAL_CHANNELS",
    "GEOMETRY_CHANNELS",
    "SLOPE_VARIANCE_CHANNELS",
    "META_PREFIX",
    "COMPRESSIONS",
    "Frame",
    "write_frame",
    "read_frame",
    "read_radiance",
    "atomic_write",
    # errors
    "FileFormatError",
    "MissingFileError",
    "FrameError",
    "IncompleteFrameWarning",
    "SceneError",
    "SceneFileError",
    # scenes
    "SCENE_FILENAME",
    "Scene",
    "scene_to_dict",
    "scene_from_dict",
    "write_scene",
    "read_scene",
    # sequences
    "HALF_MAX",
    "frame_name",
    "write_sequence",
    # camera files
    "CameraFile",
    "CameraFileError",
    "read_camera_file",
    "write_camera_file",
    # images and video
    "VIDEO_SUFFIXES",
    "load_image",
    "load_video",
    "save_png",
]
