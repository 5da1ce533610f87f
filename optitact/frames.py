"""Frame sources for processing: image files, folders of images, ``.npy`` stacks and videos.

Every source yields ``(source, frame)`` pairs, frames as 2-D greyscale arrays
in their own dtype (8- or 16-bit images stay 8- or 16-bit; colour images and
video frames are converted to grey with OpenCV's BGR-to-grey weights).
"""

from __future__ import annotations

import os
from collections.abc import Iterator, Sequence
from pathlib import Path

import numpy as np

from .errors import InputError, ShapeError

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "expand_sources", "count_frames", "iter_frames"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg", ".pgm", ".ppm")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".wmv", ".mpg", ".mpeg")
_ARRAY_SUFFIXES = (".npy",)


def expand_sources(paths: Sequence[str | os.PathLike]) -> list[Path]:
    """Files to read, in order: each path as given, a folder as its sorted frame files.

    Raises
    ------
    FileNotFoundError
        For a path that does not exist.
    InputError
        For a file of an unknown kind, a folder without frames, or no paths.
    """
    if not paths:
        raise InputError("no frames given: pass image files, a folder, .npy stacks or a video")
    known = IMAGE_SUFFIXES + VIDEO_SUFFIXES + _ARRAY_SUFFIXES
    out: list[Path] = []
    for p in map(Path, paths):
        if p.is_dir():
            files = sorted(f for f in p.iterdir() if f.is_file() and f.suffix.lower() in known)
            if not files:
                raise InputError(f"folder {p} holds no frames (expected files ending in "
                                 f"{', '.join(known)})")
            out.extend(files)
        elif p.is_file():
            if p.suffix.lower() not in known:
                raise InputError(f"{p}: unknown frame file type {p.suffix!r}; expected one of "
                                 f"{', '.join(known)}")
            out.append(p)
        else:
            raise FileNotFoundError(f"frames not found: {p}")
    return out


def count_frames(files: Sequence[Path]) -> int | None:
    """Number of frames in the files, or None when a video does not say."""
    total = 0
    for f in files:
        suffix = f.suffix.lower()
        if suffix in _ARRAY_SUFFIXES:
            arr = np.load(f, mmap_mode="r")
            total += 1 if arr.ndim == 2 else arr.shape[0]
        elif suffix in VIDEO_SUFFIXES:
            import cv2

            cap = cv2.VideoCapture(str(f))
            n = int(cap.get(cv2.CAP_PROP_FRAME_COUNT)) if cap.isOpened() else 0
            cap.release()
            if n <= 0:
                return None
            total += n
        else:
            total += 1
    return total


def _grey(img: np.ndarray, source: str) -> np.ndarray:
    import cv2

    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return cv2.cvtColor(img, code)
    raise ShapeError(f"{source}: expected a greyscale or colour image, got shape {img.shape}")


def iter_frames(files: Sequence[Path]) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(source, frame)`` for every frame of the files, in order.

    ``source`` is the file name, with ``#k`` appended for frame ``k`` of a
    stack or video.
    """
    import cv2

    for f in files:
        suffix = f.suffix.lower()
        if suffix in _ARRAY_SUFFIXES:
            arr = np.load(f, mmap_mode="r", allow_pickle=False)
            if arr.ndim == 2:
                yield f.name, np.asarray(arr)
            elif arr.ndim == 3:
                for k in range(arr.shape[0]):
                    yield f"{f.name}#{k}", np.asarray(arr[k])
            else:
                raise ShapeError(f"{f}: expected a frame (H, W) or stack (T, H, W), got {arr.shape}")
        elif suffix in VIDEO_SUFFIXES:
            cap = cv2.VideoCapture(str(f))
            if not cap.isOpened():
                raise InputError(f"{f}: OpenCV cannot open this video")
            k = 0
            try:
                while True:
                    ok, img = cap.read()
                    if not ok:
                        break
                    yield f"{f.name}#{k}", _grey(img, f"{f}#{k}")
                    k += 1
            finally:
                cap.release()
            if k == 0:
                raise InputError(f"{f}: the video has no readable frames")
        else:
            img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise InputError(f"{f}: OpenCV cannot read this image")
            yield f.name, _grey(img, str(f))
