"""Live streams: forces from a camera, a network stream or a recording, frame by frame.

:func:`stream` opens an OpenCV capture (:class:`cv2.VideoCapture`: a device
index, a GStreamer pipeline, an RTSP/HTTP URL or a video file), turns every
frame it takes into readings with a :class:`~optitact.pipeline.frame_pipeline.Pipeline` (and into a
:class:`~optitact.forces.ForceField` with a calibration) and yields them as
:class:`LiveFrame` objects. ``optitact process --camera`` is this generator
behind a command line, writing the rows as they come.

Which frames are processed
--------------------------
``policy="all"`` processes every frame in order: the capture waits for the
consumer (the default for video files and capture objects, where nothing is
lost by waiting). ``policy="newest"`` reads the capture on a thread of its own
that keeps only the latest frame: a consumer that falls behind gets the newest
frame and the ones it skipped are counted as dropped (the default for devices
and URLs, whose drivers would otherwise queue stale frames).

Colour frames are converted to grey as :mod:`optitact.io.frames` converts colour
images and videos (OpenCV's ``COLOR_BGR2GRAY`` weights, 0.299 R + 0.587 G +
0.114 B).

Examples
--------
>>> import numpy as np, optitact
>>> from optitact.live.stream import stream
>>> class Frames:  # any object with read() and release(), like cv2.VideoCapture
...     def __init__(self, frames): self.frames = list(frames)
...     def read(self): return (True, self.frames.pop(0)) if self.frames else (False, None)
...     def release(self): pass
>>> cam = optitact.optics.camera.FisheyeCamera(width=80, height=60)
>>> pipe = optitact.pipeline.frame_pipeline.Pipeline(optitact.optics.sensor.DomeSensor.default(), cam)
>>> [(f.index, f.readings.G.shape) for f in stream(Frames(np.zeros((3, 60, 80), np.uint8)),
...                                                    pipeline=pipe)]
[(0, (41,)), (1, (41,)), (2, (41,))]
"""

from __future__ import annotations

import os
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from urllib.parse import urlsplit, urlunsplit

import numpy as np

from optitact._validate import integer, positive
from optitact.errors import InputError, ShapeError
from optitact.io.frames import check_codec, to_grey
from optitact.io.tables import ReadingsWriter
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.readings import Readings

__all__ = ["POLICIES", "LiveFrame", "LiveWriter", "frame_policy", "is_recording_source", "open_capture",
           "source_label", "stream", "warm_up"]

#: How :func:`stream` takes frames from a capture: every one in order, or the newest (dropping the rest).
POLICIES = ("all", "newest")

#: Seconds the consumer waits for the reader thread to stop when the stream is closed.
_JOIN_SECONDS = 5.0


@dataclass(frozen=True, eq=False)
class LiveFrame:
    """One processed frame of a live stream.

    Attributes
    ----------
    index : int
        The frame's number in the capture, counted from 0 over every frame
        read (dropped ones included, so dropped frames leave gaps).
    timestamp : float
        Seconds from the start of the stream to the moment the capture
        returned this frame (``time.perf_counter`` clock: monotonic).
    source : str
        The frame's name as the CSV's ``source`` column writes it:
        ``LABEL#index`` (see :func:`source_label`).
    frame : (H, W) ndarray
        The grey frame, in the capture's dtype.
    readings : Readings
        Its readings ``(E,)``.
    forces : ForceField or None
        With a calibration, the estimated force field (element-local
        ``forces.local`` in N, ``forces.clamped``); else None.
    dropped : int
        Frames dropped so far by the ``"newest"`` policy (always 0 with
        ``"all"``).
    baseline : bool
        The frame is one of the frames averaged into the no-load baseline.
    wall_time : float
        The same moment on the wall clock: seconds since the epoch
        (``time.time()`` at the start of the stream plus ``timestamp``, so
        it never steps back with the clock); NaN when not known. A replayed
        recording gives each frame its recorded capture time.
    image : ndarray or None
        The image as the capture delivered it (colour, if it was), before
        the conversion to grey: what a recording stores.
    latency : float
        Seconds from the capture to the forces (readings) being ready; NaN
        for a replayed recording, whose capture times are the recorded ones.
    drift : DriftState or None
        With drift tracking, the tracker's state at this frame
        (:class:`optitact.pipeline.drift.DriftState`).
    """

    index: int
    timestamp: float
    source: str
    frame: np.ndarray
    readings: Readings
    forces: object | None
    dropped: int
    baseline: bool = False
    wall_time: float = float("nan")
    image: np.ndarray | None = None
    latency: float = float("nan")
    drift: object | None = None


def is_recording_source(source) -> bool:
    """Whether ``source`` names an MCAP recording (a path ending in ``.mcap``), replayed frame by frame."""
    return isinstance(source, (str, os.PathLike)) and os.fspath(source).lower().endswith(".mcap")


def _device_index(source) -> int | None:
    """The device index a source names (an int, or a string of digits), else None."""
    if isinstance(source, bool):
        return None
    if isinstance(source, (int, np.integer)):
        return int(source)
    if isinstance(source, str) and source.strip().isdigit():
        return int(source.strip())
    return None


def _is_capture(source) -> bool:
    return callable(getattr(source, "read", None)) and callable(getattr(source, "release", None))


def source_label(source) -> str:
    """How messages and the CSV's ``source`` column name a capture source.

    A device index is ``camera N``, a video file its file name (as
    ``optitact process FILE`` names it, so both tables agree), a URL itself
    without any user name and password, a GStreamer pipeline itself, and a
    capture object ``capture``.

    Examples
    --------
    >>> source_label(0), source_label("rtsp://user:secret@10.0.0.2:554/live")
    ('camera 0', 'rtsp://10.0.0.2:554/live')
    """
    index = _device_index(source)
    if index is not None:
        return f"camera {index}"
    if _is_capture(source):
        return "capture"
    text = os.fspath(source)
    if "://" in text:
        parts = urlsplit(text)
        host = parts.netloc.rpartition("@")[2]
        return urlunsplit(parts._replace(netloc=host))
    if "!" not in text and Path(text).is_file():
        return Path(text).name
    return text


def _is_file_source(source) -> bool:
    if _device_index(source) is not None or _is_capture(source):
        return False
    text = os.fspath(source)
    return "://" not in text and "!" not in text


def open_capture(source, *, size: tuple[int, int] | None = None):
    """An opened :class:`cv2.VideoCapture` for a device index, pipeline, URL or video file.

    Parameters
    ----------
    source : int, str or path-like
        A device index (``0``, or ``"0"``), a GStreamer pipeline (a string
        with ``!``), a URL (``rtsp://``, ``http://``, ...) or a video file.
    size : (height, width), optional
        For a device: ask it for frames of this size (the calibration's),
        which the driver may or may not grant.

    Raises
    ------
    FileNotFoundError
        ``source`` names a file that does not exist.
    InputError
        The capture does not open.
    """
    import cv2

    index = _device_index(source)
    if index is None and _is_file_source(source) and not Path(os.fspath(source)).is_file():
        raise FileNotFoundError(f"camera source not found: {os.fspath(source)} is neither a device "
                                f"index, a URL, a GStreamer pipeline nor an existing video file")
    cap = cv2.VideoCapture(index if index is not None else os.fspath(source))
    if not cap.isOpened():
        cap.release()
        what = (f"camera {index}" if index is not None else source_label(source))
        why = ("no such device, or OpenCV lacks the backend" if index is not None else
               "OpenCV cannot read this file (unknown format, or a truncated or corrupt file)"
               if _is_file_source(source) else
               "the stream is unreachable, or OpenCV lacks the backend (FFmpeg, GStreamer)")
        raise InputError(f"could not open {what} (cv2.VideoCapture): {why}")
    if index is None and _is_file_source(source):
        check_codec(Path(os.fspath(source)), cap)  # a recording read as a stream: the same warning
    if index is not None and size is not None:
        cap.set(cv2.CAP_PROP_FRAME_WIDTH, size[1])
        cap.set(cv2.CAP_PROP_FRAME_HEIGHT, size[0])
    return cap


class _Newest:
    """A reader thread that keeps only the capture's latest frame; counts the frames nobody took.

    The thread owns the capture and releases it when it stops (end of stream,
    an error, or :meth:`stop`), so the capture is never released while a read
    is under way.
    """

    def __init__(self, cap, t0: float) -> None:
        self.cap, self.t0 = cap, t0
        self.cond = threading.Condition()
        self.slot = None  # (index, timestamp, image) not yet taken
        self.read = 0  # frames read
        self.dropped = 0
        self.ended = False
        self.error: BaseException | None = None
        self.stopping = False
        self.thread = threading.Thread(target=self._run, name="optitact-live-reader", daemon=True)
        self.thread.start()

    def _run(self) -> None:
        try:
            while not self.stopping:
                ok, img = self.cap.read()
                t = time.perf_counter() - self.t0
                if not ok:
                    break
                with self.cond:
                    if self.slot is not None:
                        self.dropped += 1
                    self.slot = (self.read, t, img)
                    self.read += 1
                    self.cond.notify_all()
        except BaseException as exc:  # noqa: BLE001 - handed to the consumer, which raises it
            self.error = exc
        finally:
            self.cap.release()
            with self.cond:
                self.ended = True
                self.cond.notify_all()

    def take(self):
        """The newest frame not yet taken ``(index, timestamp, image)``; None at the end of the stream."""
        with self.cond:
            while self.slot is None and not self.ended:
                self.cond.wait()
            item, self.slot = self.slot, None
            if item is None and self.error is not None:
                raise self.error
            return item

    def stop(self) -> None:
        """Ask the thread to stop after its current read, and wait for it (a few seconds at most)."""
        self.stopping = True
        self.thread.join(_JOIN_SECONDS)


def _check_size(image: np.ndarray, pipe: Pipeline, calibration, label: str) -> None:
    h, w = pipe.camera.shape
    if image.shape != (h, w):
        error = ShapeError
        made = "the camera model is for"
        if calibration is not None:
            from optitact.calib.document import CalibrationMismatchError as error

            made = f"the calibration (fingerprint {calibration.fingerprint}) was made for"
        raise error(f"{label}: {made} {w}x{h} frames, got {image.shape[1]}x{image.shape[0]} "
                         f"(shape {image.shape}); use a camera mode of that size, or a calibration "
                         f"and setup made for this one")


def stream(source, *, calibration=None, pipeline: Pipeline | Callable | None = None, baseline=None,
           baseline_frames: int = 1, policy: str | None = None, max_frames: int | None = None,
           seconds: float | None = None, track: Callable | None = None) -> Iterator[LiveFrame]:
    """Yield readings (and forces) of a live source's frames as they arrive.

    Parameters
    ----------
    source : int, str, path-like or capture object
        A device index (``0``), a GStreamer pipeline, a URL (RTSP, HTTP) or a
        video file, opened with :class:`cv2.VideoCapture`; or an object with
        ``read() -> (ok, image)`` and ``release()`` (an opened
        ``cv2.VideoCapture`` among them).
    calibration : Calibration, optional
        Estimate forces: each :class:`LiveFrame` holds a ForceField. It fixes
        the sensor, camera and pipeline options.
    pipeline : Pipeline or callable, optional
        Turns frames into readings; default ``calibration.pipeline()``, or
        without a calibration the default sensor and a
        :class:`~optitact.optics.camera.FisheyeCamera` of the first frame's size. A
        callable is given the first frame's ``(H, W)`` and returns the
        pipeline (e.g. to size the camera).
    baseline : (H, W) or (T, H, W) array_like, optional
        No-load frame(s) for the pipeline's baseline.
    baseline_frames : int
        Without ``baseline`` (and a pipeline without one): the mean of the
        first ``baseline_frames`` frames of the stream is the no-load
        baseline (default 1: the sensor is unloaded when the stream starts;
        0 subtracts nothing). Those frames are yielded too, with
        ``baseline=True``.
    policy : {"all", "newest"}, optional
        Process every frame (``"all"``; default for video files and capture
        objects), or only the newest when processing falls behind
        (``"newest"``; default for devices and URLs: the frames skipped are
        counted in :attr:`LiveFrame.dropped`).
    max_frames : int, optional
        Stop after yielding this many frames (baseline frames included).
    seconds : float, optional
        Stop after this many seconds.
    track : callable, optional
        Drift tracking: called once with the pipeline when its baseline is
        in place, it returns a tracker whose ``process(frame, t)`` (``t``:
        the capture time, s) gives ``(readings, state)`` (e.g. ``lambda p:
        optitact.pipeline.drift.DriftTracker(p)``); every later frame goes
        through it and :attr:`LiveFrame.drift` holds its state.

    Yields
    ------
    LiveFrame

    Raises
    ------
    InputError
        The capture does not open, or the stream ends before the
        ``baseline_frames`` are read (nothing is yielded then).
    ShapeError
        A frame of another size than the pipeline's camera, naming both
        sizes (with a calibration: ``CalibrationMismatchError``, an
        InputError).
    FileNotFoundError
        A video file that does not exist.

    Notes
    -----
    The capture is opened at the first ``next()`` and released when the
    stream ends, when the generator is closed (``close()``, leaving a
    ``for`` loop by ``break`` then dropping the generator, or garbage
    collection) or when an error, ``KeyboardInterrupt`` included, leaves it.
    A capture object passed in is released too.
    """
    policy = frame_policy(source, policy)  # a recording is a file: every frame, in order
    n_base = integer(baseline_frames, "baseline_frames", minimum=0)
    if max_frames is not None:
        max_frames = integer(max_frames, "max_frames", minimum=1)
    if seconds is not None:
        seconds = positive(seconds, "seconds")
    if pipeline is None and calibration is not None:
        pipeline = calibration.pipeline()
    if isinstance(pipeline, Pipeline):
        if baseline is not None:
            pipeline, n_base = pipeline.with_baseline(baseline), 0
        elif pipeline.baseline is not None:
            n_base = 0
    elif pipeline is not None and not callable(pipeline):
        raise TypeError(f"pipeline must be a Pipeline or a callable, got {type(pipeline).__name__}")
    size = pipeline.camera.shape if isinstance(pipeline, Pipeline) else None
    if track is not None and not callable(track):
        raise TypeError(f"track must be a callable (pipeline -> tracker), got {type(track).__name__}")
    label = source_label(source)
    if is_recording_source(source):
        from optitact.live.record import RecordingCapture

        source = RecordingCapture(source)
    return _frames(source, label, calibration, pipeline, baseline, n_base, policy, max_frames, seconds, size,
                   track)


def frame_policy(source, policy: str | None) -> str:
    """The frame policy for ``source``: ``policy`` checked, or ``"all"`` for files and ``"newest"`` for cameras.

    Raises
    ------
    InputError
        ``policy`` is not one of :data:`POLICIES`.
    """
    if policy is None:
        return "all" if _is_file_source(source) or _is_capture(source) else "newest"
    if policy not in POLICIES:
        raise InputError(f"policy must be one of {', '.join(POLICIES)}, got {policy!r}")
    return policy


def _default_pipeline(shape: tuple[int, int]) -> Pipeline:
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.sensor import DomeSensor

    return Pipeline(DomeSensor.default(), FisheyeCamera(width=shape[1], height=shape[0]))


def _frames(source, label, cal, pipe, baseline, n_base: int, policy: str, max_frames, seconds, size, track):
    """The generator behind :func:`stream` (its arguments checked)."""
    if isinstance(pipe, Pipeline):
        warm_up(pipe, cal)
    cap = source if _is_capture(source) else open_capture(source, size=size)
    t0, wall0 = time.perf_counter(), time.time()
    reader = _Newest(cap, t0) if policy == "newest" else None
    stamped = reader is None and hasattr(cap, "read_stamped")  # a recording: its own indices and times
    count = 0

    def take():
        nonlocal count
        if reader is not None:
            item = reader.take()
            return None if item is None else (*item, None)
        if stamped:
            ok, img, index, t, wall = cap.read_stamped()
            return (index, t, img, wall) if ok else None
        ok, img = cap.read()
        if not ok:
            return None
        count += 1
        return count - 1, time.perf_counter() - t0, img, None

    tracker = None

    def live(pipe, index, t, wall, img, frame, dropped, is_baseline):
        nonlocal tracker
        if track is not None and tracker is None and pipe.baseline is not None:
            tracker = track(pipe)
        if tracker is not None:
            readings, state = tracker.process(frame, t)
        else:
            readings, state = pipe.process(frame), None
        forces = cal.apply(readings) if cal is not None else None
        latency = time.perf_counter() - t0 - t if wall is None else float("nan")
        return LiveFrame(index=index, timestamp=t, source=f"{label}#{index}", frame=frame, readings=readings,
                         forces=forces, dropped=dropped, baseline=is_baseline,
                         wall_time=wall0 + t if wall is None else wall, image=img, latency=latency,
                         drift=state)

    try:
        head: list = []
        done = 0
        while max_frames is None or done < max_frames:
            if seconds is not None and time.perf_counter() - t0 >= seconds:
                break
            item = take()
            if item is None:
                if len(head) < n_base:
                    raise InputError(f"{label}: the stream ended after {len(head)} frame(s), before the "
                                     f"{n_base} baseline frame(s) (--baseline-frames) were read; pass a "
                                     f"no-load frame as the baseline (--baseline) or fewer baseline frames")
                break
            index, t, img, wall = item
            frame = to_grey(img, f"{label}#{index}")
            if not isinstance(pipe, Pipeline):
                pipe = (pipe or _default_pipeline)(frame.shape)
                if baseline is not None:
                    pipe, n_base = pipe.with_baseline(baseline), 0
                elif pipe.baseline is not None:
                    n_base = 0
            _check_size(frame, pipe, cal, f"{label}#{index}")
            dropped = reader.dropped if reader is not None else 0
            if len(head) < n_base:  # a baseline frame: processed once the baseline is complete
                head.append((index, t, wall, img, frame, dropped))
                if len(head) < n_base:
                    continue
                pipe = pipe.with_baseline(np.stack([h[4] for h in head]))
                for index, t, wall, img, frame, dropped in head:
                    yield live(pipe, index, t, wall, img, frame, dropped, True)
                    done += 1
                    if max_frames is not None and done >= max_frames:
                        return
                continue
            yield live(pipe, index, t, wall, img, frame, dropped, False)
            done += 1
    finally:
        if reader is not None:
            reader.stop()
        else:
            cap.release()


def warm_up(pipe: Pipeline, calibration=None) -> None:
    """Load what the first frame would: the compiled kernel and the calibration's curves, on a dark frame.

    A stream calls this before it opens the capture, so that the first
    frames are not dropped while the kernel loads from its cache (most of a
    second). Frames of a dtype the pipeline refuses are skipped silently.
    """
    dtype = pipe.baseline_dtype or (np.uint16 if (pipe.bits or pipe.readings_bits or 8) > 8 else np.uint8)
    try:
        readings = pipe.process(np.zeros(pipe.camera.shape, dtype))
    except (InputError, TypeError, ValueError):
        return
    if calibration is not None:
        calibration.apply(readings)


class LiveWriter:
    """Write live frames as CSV rows the moment they come: on disk after every frame.

    The same tables as ``optitact process`` writes
    (:class:`~optitact.io.tables.ReadingsWriter`: one row per frame and element,
    with a calibration the force columns and ``NAME.per_frame.csv``), each
    row ending with the frame's capture time: ``time_s`` (seconds from the
    start of the stream, :attr:`LiveFrame.timestamp`, monotonic) and
    ``wall_time`` (:attr:`LiveFrame.wall_time` as ISO 8601 in UTC, e.g.
    ``2025-01-31T09:15:02.123456+00:00``). A live stream has no end to wait
    for, so the rows go to
    :func:`~optitact.io.tables.partial_path` (``NAME.partial.csv``) and are flushed
    after every frame: a reader (``tail -f``, pandas) sees them as they come,
    and a crash or a killed process leaves them there. A clean stop (the
    ``with`` block ends without an error, which is how ``optitact process
    --camera`` ends a Ctrl-C, the end of the stream and ``--max-frames``)
    renames them to ``NAME`` (replacing an older file). An error keeps them
    as ``NAME.partial.csv`` and says so in its message. Each frame's rows
    are written whole, so the file always ends on a whole frame, even when
    the disk fills; a second writer of the same ``NAME`` is refused while
    this one is open (see :class:`~optitact.io.tables.ReadingsWriter`).

    A ``path`` ending in ``.parquet`` (a replayed recording, or a long run
    read only when it ends) writes Parquet instead: readable once the
    stream stops, since Parquet's footer comes last (rows go to a hidden
    temporary file until then, see :class:`~optitact.io.tables.ReadingsWriter`).

    Parameters
    ----------
    path : path-like
        The CSV (or Parquet) file.
    calibration : Calibration, optional
        Write the force columns and the per-frame table.
    drift : bool
        The stream tracks drift: both tables end with the tracker's state
        (:data:`~optitact.io.tables.ReadingsWriter.DRIFT_COLUMNS`; a frame before tracking
        starts, a baseline frame, reads gain 1, offset and shift 0, no flag).
    """

    def __init__(self, path: str | os.PathLike, *, calibration=None, drift: bool = False) -> None:
        self.with_forces = calibration is not None
        parquet = Path(path).suffix.lower() == ".parquet"
        self._writer = ReadingsWriter(path, forces=self.with_forces, visible=not parquet, times=True,
                                      drift=drift, sensor=calibration.sensor if self.with_forces else None)
        self.path = self._writer.path

    @property
    def paths(self) -> list[Path]:
        """The files a clean stop leaves: ``NAME`` (and ``NAME.per_frame.csv`` with forces)."""
        return self._writer.paths

    @property
    def frames(self) -> int:
        """Frames written so far."""
        return self._writer.frames

    def write(self, frame: LiveFrame) -> None:
        """Write one frame's rows and flush them to disk."""
        drift = None
        if self._writer.with_drift:
            d = frame.drift
            drift = [(1.0, 0.0, 0.0, 0.0, False) if d is None
                     else (d.gain, d.offset, d.shift_x, d.shift_y, d.flag)]
        if self.with_forces:
            if frame.forces is None:
                raise ValueError("this writer has force columns: the frame has no forces (no calibration)")
            self._writer.write(frame.readings, [frame.source], frame.forces.local, frame.forces.clamped,
                               time_s=[frame.timestamp], wall_time=[frame.wall_time], drift=drift)
        else:
            self._writer.write(frame.readings, [frame.source], time_s=[frame.timestamp],
                               wall_time=[frame.wall_time], drift=drift)
        if self._writer.format == "csv":  # Parquet gathers rows into row groups (it flushes them itself)
            self._writer.flush()

    def close(self) -> None:
        """A clean stop: rename the rows to their final names."""
        self._writer.close()

    def __enter__(self) -> LiveWriter:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self._writer.__exit__(exc_type, exc, tb)
