"""Copy a short clip out of a camera-file sequence: frames unchanged, camera file subset.

Usage: ``python experiments/make_real_clip.py SRC_DIR DST_DIR [--start 0] [--every 2]
[--frames 30] [--overwrite]``.

``SRC_DIR`` holds ``camera.json`` (:mod:`jaxocean.io.camera_file`) and its frames. The clip
is frames ``start, start + every, ...`` (``--frames`` of them): each frame file is copied
byte for byte to the same path relative to ``DST_DIR`` (frames must lie under ``SRC_DIR``),
the camera file is :func:`jaxocean.io.camera_file.select` of those frames written with
:func:`jaxocean.io.camera_file.write_camera_file` (times, poses and the file's other keys
kept; ``frame_rate_hz`` becomes the clip's own), and a ``LICENSE.md`` / ``README.md`` beside
the source camera file is copied too (edit the copied README to describe the clip). The
result is read back and validated before the script reports it.
"""

from __future__ import annotations

import argparse
import shutil
import sys
from pathlib import Path

from jaxocean.io.camera_file import CAMERA_FILENAME, read_camera_file, select, write_camera_file

BESIDE = ("LICENSE.md", "README.md")


def make_clip(src: Path, dst: Path, *, start: int, every: int, frames: int, overwrite: bool = False) -> Path:
    """Write the clip; returns the new camera file's path."""
    source = read_camera_file(src)
    src_dir = source.path.parent.resolve()
    dst = Path(dst).resolve()
    if dst == src_dir:
        raise SystemExit("make_real_clip: DST_DIR must differ from SRC_DIR")
    if (dst / CAMERA_FILENAME).exists() and not overwrite:
        raise SystemExit(f"make_real_clip: {dst / CAMERA_FILENAME} exists (use --overwrite)")
    if start < 0 or every < 1 or frames < 1:
        raise SystemExit("make_real_clip: need --start >= 0, --every >= 1, --frames >= 1")
    indices = list(range(start, start + every * frames, every))
    if indices[-1] >= len(source.files):
        raise SystemExit(f"make_real_clip: frame {indices[-1]} asked for; the sequence has {len(source.files)}")
    clip = select(source, indices)
    copied = []
    for file in clip.files:
        try:
            relative = file.relative_to(src_dir)
        except ValueError:
            raise SystemExit(f"make_real_clip: frame {file} does not lie under {src_dir}") from None
        target = dst / relative
        target.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(file, target)
        copied.append(target)
    path = write_camera_file(dst / CAMERA_FILENAME, clip._replace(files=tuple(copied)))
    for name in BESIDE:
        if (src_dir / name).is_file():
            shutil.copyfile(src_dir / name, dst / name)
    check = read_camera_file(path)  # every frame present, every field valid
    assert check.files == tuple(copied)
    return path


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("src", type=Path, help="folder holding camera.json and its frames")
    parser.add_argument("dst", type=Path, help="folder to write the clip to")
    parser.add_argument("--start", type=int, default=0, help="first frame (index in the camera file)")
    parser.add_argument("--every", type=int, default=2, help="keep every n-th frame")
    parser.add_argument("--frames", type=int, default=30, help="number of frames in the clip")
    parser.add_argument("--overwrite", action="store_true", help="replace an existing camera.json in DST_DIR")
    args = parser.parse_args(argv)
    path = make_clip(args.src, args.dst, start=args.start, every=args.every, frames=args.frames,
                     overwrite=args.overwrite)
    clip = read_camera_file(path)
    span = clip.times[-1] - clip.times[0]
    print(f"{path}: {len(clip.files)} frames, t = {clip.times[0]:.2f} ... {clip.times[-1]:.2f} s ({span:.2f} s), "
          f"poses {'present' if clip.poses is not None else 'absent'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
