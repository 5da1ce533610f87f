"""Frame sources for processing: image files, folders of images, ``.npy`` stacks and videos.

Every source yields ``(source, frame)`` pairs, frames as 2-D greyscale arrays
in their own dtype (8- or 16-bit images stay 8- or 16-bit; colour images and
video frames are converted to grey with OpenCV's BGR-to-grey weights). Two
kinds of video skip the conversion: 8-bit grey ones (FFV1, raw) are read as
grey (the same levels), and Motion JPEG ones as their luma plane, the grey
image of those weights without the round trip through BGR (the same levels
on grey content, within the round trip's rounding of one level on colour;
see :func:`_luma_reader`).

Lossy and truncated sources
---------------------------
Force estimation reads grey levels, so lossy compression biases it: the same
frames stored as Motion JPEG read about 0.71 N where the lossless frames read
0.63 N (truth 0.6 N). Reading a video whose codec is not a known lossless one
(:data:`LOSSLESS_CODECS`: FFV1, PNG, HuffYUV, raw, ...; MJPG, H.264, MPEG-4,
VP9 ... are lossy) or a lossy image (JPEG, lossy WebP) warns once per file
(:class:`FramesWarning`). A video that ends before the frame count its header
announces (a cut or truncated recording) warns with both counts.

Frame size
----------
A frame's size is checked against :data:`optitact.optics.camera.MAX_FRAME_PIXELS`
before its pixels are read (from the PNG, JPEG, BMP or WebP header, the
video's properties or the ``.npy`` header), so a huge image is refused with
a clear :class:`~optitact.errors.InputError` instead of filling the memory.
"""

from __future__ import annotations

import os
import queue
import struct
import threading
import warnings
from collections.abc import Iterable, Iterator, Sequence
from contextlib import ExitStack, contextmanager
from pathlib import Path

import numpy as np

from optitact._validate import integer
from optitact.optics.camera import check_frame_size
from optitact.errors import InputError, OptitactWarning, ShapeError

__all__ = ["IMAGE_SUFFIXES", "VIDEO_SUFFIXES", "LOSSLESS_CODECS", "FramesWarning", "check_codec",
           "expand_sources", "count_frames", "iter_frames", "read_ahead", "read_ahead_depth", "ReadAhead",
           "to_grey"]

IMAGE_SUFFIXES = (".png", ".tif", ".tiff", ".bmp", ".jpg", ".jpeg", ".pgm", ".ppm", ".webp")
VIDEO_SUFFIXES = (".mp4", ".avi", ".mov", ".mkv", ".m4v", ".wmv", ".mpg", ".mpeg")
_ARRAY_SUFFIXES = (".npy",)
_END = object()  # read_ahead: the items are done
_GREY8 = int.from_bytes(b"Y800", "little")  # OpenCV's CAP_PROP_CODEC_PIXEL_FORMAT of 8-bit grey video
#: OpenCV's CAP_PROP_CODEC_PIXEL_FORMAT of 8-bit YUV formats whose first plane is the luma at full size
_PLANAR_YUV = frozenset(int.from_bytes(t, "little") for t in (b"I420", b"YV12", b"Y42B", b"444P", b"NV12",
                                                                 b"NV21"))
#: Video codecs (as :data:`LOSSLESS_CODECS` names them) whose YUV is full range (JPEG's): their luma
#: plane is the grey image that OpenCV's BGR read and ``cvtColor`` give (see :func:`_luma_reader`).
FULL_RANGE_CODECS = frozenset({"mjpg"})
#: Grey levels that :func:`read_ahead_depth` lets a batch run decode ahead of the frames being processed.
READ_AHEAD_BYTES = 64 << 20

#: Video codecs (FOURCC, lower case, spaces stripped; "" is raw video) that store frames exactly.
LOSSLESS_CODECS = frozenset({
    "", "raw", "dib", "rgba", "bgra", "rgb", "y800", "y8", "y16", "grey", "gray",  # uncompressed
    "ffv1", "ffvh", "hfyu", "png", "mpng", "lags", "magy", "zlib", "mszh",  # lossless coders
    "ulrg", "ulra", "uly0", "uly2", "uly4", "ulh0", "ulh2", "ulh4",  # Ut Video
})
_LOSSY_NAMES = {"mjpg": "Motion JPEG", "avc1": "H.264", "h264": "H.264", "x264": "H.264",
                "hevc": "H.265", "hvc1": "H.265", "hev1": "H.265", "h265": "H.265",
                "fmp4": "MPEG-4", "mp4v": "MPEG-4", "xvid": "MPEG-4", "divx": "MPEG-4",
                "dx50": "MPEG-4", "mp42": "MPEG-4", "mp43": "MPEG-4", "vp80": "VP8", "vp90": "VP9",
                "vp08": "VP8", "vp09": "VP9", "av01": "AV1", "mpg1": "MPEG-1", "mpg2": "MPEG-2",
                "wmv3": "WMV", "wmv2": "WMV"}


class FramesWarning(OptitactWarning):
    """Frames that can be read but may give wrong forces: lossy compression, a truncated video."""


#: Files already warned about as lossy in this process: (path, size, mtime_ns).
_WARNED: set = set()


def _warn_once(f: Path, message: str) -> None:
    try:
        st = f.stat()
        key = (str(f.resolve()), st.st_size, st.st_mtime_ns)
    except OSError:
        key = (str(f), None, None)
    if key not in _WARNED:
        _WARNED.add(key)
        warnings.warn(message, FramesWarning, stacklevel=3)


def expand_sources(paths: Sequence[str | os.PathLike]) -> list[Path]:
    """Files to read, in order: each path as given, a folder as its sorted frame files.

    Lossy files are accepted (a warning comes when they are read, see
    :func:`iter_frames`); record frames for force estimation as PNG/TIFF or
    with a lossless video codec (FFV1, PNG, raw).

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


def _load_npy(f: Path) -> np.ndarray:
    """The ``.npy`` file memory-mapped, checked to hold a frame (H, W) or a stack (T, H, W)."""
    try:
        arr = np.load(f, mmap_mode="r", allow_pickle=False)
    except (ValueError, EOFError, SyntaxError) as exc:
        if "allow_pickle" in str(exc) or "Python objects" in str(exc):
            raise InputError(f"{f}: holds Python objects, not grey levels") from None
        raise InputError(f"{f}: truncated or corrupt .npy file (numpy could not read it: "
                         f"{str(exc).splitlines()[0][:120]})") from None
    if arr.ndim not in (2, 3):
        raise ShapeError(f"{f}: wrong shape: expected (H, W) or (T, H, W), got {arr.shape}")
    check_frame_size(arr.shape[-1], arr.shape[-2], str(f))
    return arr


def count_frames(files: Sequence[Path]) -> int | None:
    """Number of frames in the files, or None when a video does not say.

    A video's count is the one its header announces; :func:`iter_frames`
    warns when fewer frames can be read.
    """
    total = 0
    for f in files:
        suffix = f.suffix.lower()
        if suffix in _ARRAY_SUFFIXES:
            arr = _load_npy(f)
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


def to_grey(img: np.ndarray, source: str) -> np.ndarray:
    """A decoded image as a greyscale frame ``(H, W)``.

    Parameters
    ----------
    img : (H, W), (H, W, 1), (H, W, 3) or (H, W, 4) ndarray
        A greyscale image, or a colour one in OpenCV's BGR or BGRA channel
        order (as ``cv2.imread`` and ``cv2.VideoCapture`` return it).
    source : str
        Where the image came from, for the error message (e.g. ``"clip.mp4#12"``).

    Returns
    -------
    (H, W) ndarray
        The image itself when greyscale (its single channel as a view),
        else ``cv2.cvtColor``'s grey conversion, of the image's dtype.

    Raises
    ------
    ShapeError
        Any other shape.
    """
    import cv2

    if img.ndim == 2:
        return img
    if img.ndim == 3 and img.shape[2] == 1:
        return img[:, :, 0]
    if img.ndim == 3 and img.shape[2] in (3, 4):
        code = cv2.COLOR_BGR2GRAY if img.shape[2] == 3 else cv2.COLOR_BGRA2GRAY
        return cv2.cvtColor(img, code)
    raise ShapeError(f"{source}: expected a greyscale or colour image, got shape {img.shape}")


def _jpeg_size(head: bytes) -> tuple[int, int] | None:
    """(width, height) from a JPEG's first start-of-frame marker, if within ``head``."""
    i = 2
    while i + 9 <= len(head) and head[i] == 0xFF:
        marker = head[i + 1]
        length = struct.unpack(">H", head[i + 2:i + 4])[0]
        if 0xC0 <= marker <= 0xCF and marker not in (0xC4, 0xC8, 0xCC):
            h, w = struct.unpack(">HH", head[i + 5:i + 9])
            return w, h
        i += 2 + length
    return None


def _image_header(f: Path) -> tuple[tuple[int, int] | None, str | None]:
    """``((width, height) or None, lossy format name or None)`` from an image file's header."""
    with open(f, "rb") as fh:
        head = fh.read(65536)
    if head[:8] == b"\x89PNG\r\n\x1a\n" and head[12:16] == b"IHDR":
        return struct.unpack(">II", head[16:24]), None
    if head[:2] == b"BM" and len(head) >= 26:
        w, h = struct.unpack("<ii", head[18:26])
        return (abs(w), abs(h)), None
    if head[:3] == b"\xff\xd8\xff":
        return _jpeg_size(head), "JPEG"
    if head[:4] == b"RIFF" and head[8:12] == b"WEBP":
        lossy = b"VP8 " in head[12:]  # a lossy (VP8) bitstream, alone or inside a VP8X container
        return None, "lossy WebP" if lossy else None
    return None, None


def iter_frames(files: Sequence[Path]) -> Iterator[tuple[str, np.ndarray]]:
    """Yield ``(source, frame)`` for every frame of the files, in order.

    ``source`` is the file name, with ``#k`` appended for frame ``k`` of a
    stack or video.

    Warns
    -----
    FramesWarning
        Once per file for a lossy source (a JPEG or lossy WebP image, a video
        whose codec, read from its FOURCC, is not in :data:`LOSSLESS_CODECS`):
        compression changes grey levels and biases the forces estimated from
        them. And when a video ends before the frame count its header
        announces (naming the file and both counts).

    Raises
    ------
    InputError
        For an unreadable, truncated or corrupt file, or a frame larger than
        :data:`optitact.optics.camera.MAX_FRAME_PIXELS` (checked from the header,
        before the pixels are read).
    ShapeError
        For a ``.npy`` file that is not (H, W) or (T, H, W).
    """
    import cv2

    for f in files:
        suffix = f.suffix.lower()
        if suffix in _ARRAY_SUFFIXES:
            arr = _load_npy(f)
            if arr.ndim == 2:
                yield f.name, np.asarray(arr)
            else:
                for k in range(arr.shape[0]):
                    yield f"{f.name}#{k}", np.asarray(arr[k])
        elif suffix in VIDEO_SUFFIXES:
            yield from _video_frames(f, cv2)
        else:
            size, lossy = _image_header(f)
            if size is not None:
                check_frame_size(size[0], size[1], str(f))
            if lossy is not None:
                _warn_once(f, f"{f}: {lossy} is a lossy format: compression changes the grey levels "
                              f"and biases the estimated forces; use PNG or TIFF frames")
            img = cv2.imread(str(f), cv2.IMREAD_UNCHANGED)
            if img is None:
                raise InputError(f"{f}: OpenCV cannot read this image")
            yield f.name, to_grey(img, str(f))


class ReadAhead:
    """Items of an iterable in order, produced up to ``depth`` ahead by a background thread.

    Made by :func:`read_ahead`. The thread starts at once, so a caller can
    begin decoding a video and go on building what will process its frames.
    An exception of the items (a corrupt frame, a warning turned into an
    error) is raised by ``next``, at the item where it happened. :meth:`close`
    (or leaving a ``with`` block) stops the thread and closes the items'
    iterator there (a video is released); one dropped unclosed does the
    same when it is collected.
    """

    def __init__(self, items: Iterable, depth: int) -> None:
        depth = integer(depth, "depth", minimum=1)
        self._slots: queue.Queue = queue.Queue(depth)
        self._stop = threading.Event()
        self._done = False
        # the thread holds no reference to this object: one dropped unclosed is collected, and stops it
        self._worker = threading.Thread(target=_produce, args=(iter(items), self._slots, self._stop),
                                        name="optitact-read-ahead", daemon=True)
        self._worker.start()

    def __iter__(self) -> ReadAhead:
        return self

    def __next__(self):
        if self._done:
            raise StopIteration
        ok, item = self._slots.get()
        if not ok:
            self.close()
            raise item
        if item is _END:
            self.close()
            raise StopIteration
        return item

    def close(self) -> None:
        """Stop the thread (the items' iterator is closed there); the remaining items are dropped."""
        self._done = True
        self._stop.set()
        while self._worker.is_alive():  # unblock a producer waiting for a free slot
            try:
                self._slots.get_nowait()
            except queue.Empty:
                self._worker.join(0.01)

    def __enter__(self) -> ReadAhead:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def __del__(self) -> None:
        stop = getattr(self, "_stop", None)  # None: the constructor failed
        if stop is not None:
            stop.set()  # the thread closes the items' iterator and ends within PUT_WAIT


#: Seconds a :class:`ReadAhead` thread waits for a free slot before it looks whether it was stopped.
PUT_WAIT = 0.05


def _produce(source: Iterator, slots: queue.Queue, stop: threading.Event) -> None:
    """A :class:`ReadAhead`'s thread: the items into ``slots``, then their end or exception, until ``stop``."""

    def offer(entry) -> bool:
        while not stop.is_set():
            try:
                slots.put(entry, timeout=PUT_WAIT)
                return True
            except queue.Full:
                pass
        return False

    try:
        for item in source:
            if not offer((True, item)):
                return
        offer((True, _END))
    except BaseException as exc:  # handed to the consumer, raised there
        offer((False, exc))
    finally:
        close = getattr(source, "close", None)
        if close is not None:
            close()


def read_ahead_depth(shape: tuple[int, int], batch: int) -> int:
    """Frames of ``shape`` to decode ahead of batches of ``batch``: 4 batches, within ``READ_AHEAD_BYTES``."""
    h, w = shape
    return max(2, min(4 * batch, READ_AHEAD_BYTES // (2 * h * w)))  # frames of up to 16 bits: 2 bytes a pixel


def read_ahead(items: Iterable, depth: int) -> ReadAhead:
    """``items`` in order, produced up to ``depth`` ahead by a background thread (:class:`ReadAhead`).

    Frames decode (OpenCV releases the GIL) while the caller works on the
    ones before them.

    Raises
    ------
    InputError
        ``depth`` below 1.
    """
    return ReadAhead(items, depth)


def _fourcc(cap, cv2) -> str:
    """The FOURCC of the opened video ``cap``'s codec, as four characters."""
    return (int(cap.get(cv2.CAP_PROP_FOURCC)) & 0xFFFFFFFF).to_bytes(4, "little").decode("latin-1")


def _codec_name(cap, cv2) -> str:
    """The codec's FOURCC as :data:`LOSSLESS_CODECS` and :data:`FULL_RANGE_CODECS` name it."""
    return _fourcc(cap, cv2).strip(" \0").lower()


@contextmanager
def _quiet_opencv(cv2):
    """OpenCV's log level at ERROR or quieter for the block (restored after the last such block ends).

    Read as its luma plane, a YUV video makes OpenCV warn at every frame that its pixel format
    "will be treated as 8UC1", which is what is asked for here.
    """
    global _quiet_blocks, _quiet_saved
    log = getattr(getattr(cv2, "utils", None), "logging", None)
    if log is None:  # an OpenCV without its logging module: its warnings stay as they are
        yield
        return
    with _quiet_lock:
        if _quiet_blocks == 0:
            _quiet_saved = log.getLogLevel()
            log.setLogLevel(min(_quiet_saved, log.LOG_LEVEL_ERROR))
        _quiet_blocks += 1
    try:
        yield
    finally:
        with _quiet_lock:
            _quiet_blocks -= 1
            if _quiet_blocks == 0:
                log.setLogLevel(_quiet_saved)


_quiet_lock = threading.Lock()
_quiet_blocks = 0
_quiet_saved = None


def _luma_reader(f: Path, cap, cv2) -> tuple:
    """``(capture, first frame, luma)`` of a full-range planar-YUV video: read as its luma plane if that works.

    The luma plane of a JPEG-coded frame is its grey image: OpenCV's default
    read converts it to BGR, and ``cvtColor`` back to grey with the same
    weights, which gives the luma again up to the round trip's rounding
    (identical levels on grey content; a fifth less decoding time at
    640x480). OpenCV hands the plane over when its conversion is turned off
    (``CAP_PROP_CONVERT_RGB``), for formats it calls unsupported. So frame
    0 is read both ways: the luma read is kept when it has the frame's shape
    and is within one grey level of the converted frame everywhere;
    otherwise (another OpenCV build, another plane layout) the video is read
    converted, as any other (``luma`` False). ``cap`` is open with nothing
    read; the capture not returned is released.
    """
    raw = cv2.VideoCapture(str(f))
    try:
        raw.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        ok_raw, luma = raw.read()
        ok, img = cap.read()
    except BaseException:
        raw.release()
        raise
    grey = to_grey(img, f"{f}#0") if ok else None
    if (ok and ok_raw and luma.dtype == np.uint8 and luma.shape == grey.shape
            and grey.dtype == np.uint8 and np.abs(luma.astype(np.int16) - grey).max() <= 1):
        cap.release()
        return raw, luma, True
    raw.release()
    return cap, img if ok else None, False


def check_codec(f: Path, cap) -> None:
    """Warn (once per file) when the opened video ``cap`` of file ``f`` uses a codec not known to be lossless.

    A lossy codec (MJPG, H.264, MPEG-4, ...) changes grey levels and biases
    the estimated forces; lossless ones are listed in ``LOSSLESS_CODECS``.
    """
    import cv2

    codec, name = _fourcc(cap, cv2), _codec_name(cap, cv2)
    if name not in LOSSLESS_CODECS:
        what = (f"is lossy ({_LOSSY_NAMES[name]})" if name in _LOSSY_NAMES
                else "is not known to be lossless")
        _warn_once(f, f"{f}: video codec {codec.strip(chr(0))!r} {what}: compression changes the "
                      f"grey levels and biases the estimated forces; record with a lossless "
                      f"codec (FFV1, PNG, raw)")


def _video_frames(f: Path, cv2) -> Iterator[tuple[str, np.ndarray]]:
    """The frames of one video, with the lossy-codec and truncation warnings of :func:`iter_frames`."""
    cap = cv2.VideoCapture(str(f))
    if not cap.isOpened():
        raise InputError(f"{f}: OpenCV cannot open this video (unknown format, or a truncated or "
                         f"corrupt file)")
    k, held = 0, ExitStack()
    try:
        check_frame_size(int(cap.get(cv2.CAP_PROP_FRAME_WIDTH)), int(cap.get(cv2.CAP_PROP_FRAME_HEIGHT)),
                         str(f))
        announced = int(cap.get(cv2.CAP_PROP_FRAME_COUNT))
        check_codec(f, cap)
        pixels = int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT))
        first = None
        if pixels == _GREY8:
            # decoded as 8-bit grey: read it as it is, not converted to BGR and back (the same
            # grey levels; a quarter less decoding time)
            cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
        elif pixels in _PLANAR_YUV and _codec_name(cap, cv2) in FULL_RANGE_CODECS:
            held.enter_context(_quiet_opencv(cv2))
            cap, first, luma = _luma_reader(f, cap, cv2)
            if not luma:  # read converted after all: OpenCV's warnings as they were
                held.close()
        colour, name = None, f.name
        while True:
            if first is not None:
                ok, img, first = True, first, None
            else:
                ok, img = cap.read(colour)
            if not ok:
                break
            grey = to_grey(img, f"{f}#{k}")
            # a colour frame is converted to a new grey array: the next frame is decoded into the
            # same colour one (no allocation, which takes the GIL in the middle of decoding)
            colour = img if img.ndim == 3 and img.shape[2] in (3, 4) else None
            yield f"{name}#{k}", grey
            k += 1
    finally:
        cap.release()
        held.close()
    if k == 0:
        raise InputError(f"{f}: the video has no readable frames")
    if 0 < k < announced:
        warnings.warn(f"{f}: read {k} of the {announced} frames its header announces; the video "
                      f"is truncated or corrupt after frame {k - 1}", FramesWarning, stacklevel=3)
