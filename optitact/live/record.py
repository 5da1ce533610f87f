"""Recordings of a live stream as MCAP files that robotics tools open, and their replay.

``optitact process --camera 0 --calibration cal.json --record run.mcap`` writes
an `MCAP <https://mcap.dev>`_ file (the ROS 2 bag format since Iron, read by
``ros2 bag``, Foxglove, Rerun, PlotJuggler and the ``mcap`` Python reader)
holding, per processed frame, stamped with the frame's capture time:

- ``/optitact/camera/image``, ``sensor_msgs/msg/Image``: the frame as the
  capture gave it (``frames="lossless"``, the default);
- ``/optitact/camera/compressed``, ``sensor_msgs/msg/CompressedImage``: the
  frame as JPEG (``frames="lossy"``);
- ``/optitact/elements``, ``optitact_msgs/msg/ElementForces``: per element the
  readings (G, u), forces and their standard errors, contact, clamped and
  saturated flags (:data:`ELEMENT_MSG`);
- ``/optitact/wrench``, ``geometry_msgs/msg/WrenchStamped``: the resultant
  force (N) and its moment about the sensor's origin (N mm), sensor frame;
- ``/optitact/stream``, ``optitact_msgs/msg/StreamStatus``: frame index,
  baseline flag, dropped frames, latency and the drift tracker's state
  (:data:`STATUS_MSG`).

Messages are in ROS 2 encoding (CDR) with their definitions embedded, so
tools that do not know ``optitact_msgs`` decode them too.
Every message's ``header.stamp`` and its MCAP ``log_time`` are the capture's
wall-clock time (:attr:`~optitact.live.stream.LiveFrame.wall_time`, monotonic
within a stream); ``publish_time`` is when its forces were ready. The file's
``optitact`` metadata record says what made it (version, source, sensor,
camera, pipeline options, frame storage), and attachments hold the
calibration (``calibration.json``) and an explicit baseline
(``baseline.npy``), so :func:`read_recording` can re-process the frames
with the same or a better calibration (``optitact process run.mcap``).

Frames
------
``"lossless"`` stores each frame as a raw ``sensor_msgs/msg/Image``
(``mono8``, ``mono16`` or ``bgr8``, as the capture delivered it; a colour
image whose three channels are equal, as a decoder returns a grey camera's
video, is stored once as ``mono8`` — the grey frame the pipeline reads is
the same to the bit), and the file's chunks are compressed with Zstandard
(MCAP's own compression, transparent to every reader): lossless for 1.5 to
2.6 ms of CPU a 640x480 frame (``optitact bench live``), on the recorder's own
thread. ``"lossy"``
stores JPEG (quality :data:`JPEG_QUALITY`): a tenth of the size or less (5.5 kB
against 81 kB a 640x480 frame of spots on a dark dome), but
its 8x8 blocks and ringing change G and the centroids, so re-processed
forces differ (the recorder says so, as ``process`` does for lossy videos).
``"none"`` stores no frames: the forces only, for long runs; such a
recording cannot be re-processed.

Writing
-------
Frames go to a writer thread through a queue, so the forces' latency does not
include compression and disk; the queue holds at most
:data:`QUEUE_FRAMES` frames, and a stream that outruns the disk waits rather
than lose a frame. The file is written as ``NAME.partial.mcap`` and renamed to
``NAME`` when the recording stops cleanly (the stream's end, ``--max-frames``,
``--seconds``, Ctrl-C); a crash leaves the partial file, whose complete chunks
``mcap recover`` (or :func:`read_recording`) reads.
"""

from __future__ import annotations

import io
import json
import os
import queue
import threading
import time
from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from optitact.errors import InputError

__all__ = ["ELEMENT_MSG", "FRAME_STORAGE", "JPEG_QUALITY", "QUEUE_FRAMES", "Recorder", "Recording",
           "RecordingCapture", "STATUS_MSG", "TOPICS", "read_recording"]

#: How a recorder stores the frames: raw (lossless, compressed chunks), JPEG, or not at all.
FRAME_STORAGE = ("lossless", "lossy", "none")

#: JPEG quality of ``frames="lossy"``.
JPEG_QUALITY = 90

#: Frames the writer thread's queue holds before the stream waits for the disk.
QUEUE_FRAMES = 240

#: The topics a recording writes.
TOPICS = {"image": "/optitact/camera/image", "compressed": "/optitact/camera/compressed",
          "elements": "/optitact/elements", "wrench": "/optitact/wrench", "stream": "/optitact/stream"}

#: The name of the recording's metadata record.
METADATA = "optitact"

_HEADER = """================================================================================
MSG: std_msgs/Header
builtin_interfaces/Time stamp
string frame_id
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""

_IMAGE_MSG = """std_msgs/Header header
uint32 height
uint32 width
string encoding
uint8 is_bigendian
uint32 step
uint8[] data
""" + _HEADER

_COMPRESSED_MSG = """std_msgs/Header header
string format
uint8[] data
""" + _HEADER

_WRENCH_MSG = """std_msgs/Header header
geometry_msgs/Wrench wrench
================================================================================
MSG: geometry_msgs/Wrench
Vector3 force
Vector3 torque
================================================================================
MSG: geometry_msgs/Vector3
float64 x
float64 y
float64 z
""" + _HEADER

#: ``optitact_msgs/msg/ElementForces``: one frame's elements (arrays of E, element order of the sensor).
ELEMENT_MSG = """# One processed frame of an optitact sensor: per element, in the sensor's element order.
std_msgs/Header header
uint64 frame                 # the frame's number in the capture (dropped frames leave gaps)
string source                # LABEL#frame, as the CSV's source column
float64[] g                  # integrated grey value G (grey level x mm^2)
float64[] ux                 # centroid shift (mm)
float64[] uy
bool[] contact
bool[] saturated
float64[] fx                 # element-local force (N); empty without a calibration
float64[] fy
float64[] fz
float64[] fx_stderr          # its standard error (N): the calibration's model error
float64[] fy_stderr
float64[] fz_stderr
bool[] clamped               # the reading was outside the calibration's fitted range
""" + _HEADER

#: ``optitact_msgs/msg/StreamStatus``: the stream's state at a frame.
STATUS_MSG = """# The live stream's state at one frame.
std_msgs/Header header
uint64 frame
float64 time_s               # seconds from the start of the stream to the capture (monotonic clock)
bool baseline                # the frame is one of the no-load baseline frames
uint64 dropped               # frames dropped so far (newest-frame policy)
float64 latency              # capture to forces (s); NaN when not measured (a replay)
bool drift_tracking          # drift tracking is on
float64 drift_gain           # tracked light gain against the baseline (1: none)
float64 drift_offset         # tracked black-level offset (grey levels)
float64 drift_shift_x        # tracked camera shift against the dome (px)
float64 drift_shift_y
bool drift_flag              # the change exceeds what tracking can follow
string drift_reason
""" + _HEADER

_ENCODINGS = {("uint8", 1): "mono8", ("uint16", 1): "mono16", ("uint8", 3): "bgr8", ("uint16", 3): "bgr16",
              ("uint8", 4): "bgra8"}
_DECODINGS = {v: k for k, v in _ENCODINGS.items()}


def _require_mcap():
    from optitact._optional import require

    require("mcap", purpose="MCAP recordings")
    return require("mcap_ros2.writer", purpose="MCAP recordings")


def _stamp(t: float) -> dict:
    ns = _ns(t)
    return {"sec": ns // 1_000_000_000, "nanosec": ns % 1_000_000_000}


def _ns(t: float) -> int:
    return int(round(t * 1e9)) if np.isfinite(t) else 0


def stored_image(image: np.ndarray) -> np.ndarray:
    """The image a lossless recording stores: ``image``, or its first channel when all three are equal."""
    if image.ndim == 3 and image.shape[2] == 3:
        c0 = image[:, :, 0]
        if np.array_equal(c0, image[:, :, 1]) and np.array_equal(c0, image[:, :, 2]):
            return np.ascontiguousarray(c0)
    if image.ndim == 3 and image.shape[2] == 1:
        return image[:, :, 0]
    return image


def _image_message(image: np.ndarray, header: dict) -> dict:
    image = np.ascontiguousarray(stored_image(image))
    channels = 1 if image.ndim == 2 else image.shape[2]
    enc = _ENCODINGS.get((image.dtype.name, channels))
    if enc is None:
        raise InputError(f"a lossless recording stores 8- or 16-bit grey or BGR frames, got {image.dtype} "
                         f"with {channels} channel(s)")
    if image.dtype.itemsize > 1 and image.dtype.byteorder == ">":
        image = image.astype(image.dtype.newbyteorder("<"))
    return {"header": header, "height": image.shape[0], "width": image.shape[1], "encoding": enc,
            "is_bigendian": 0, "step": image.strides[0], "data": image.tobytes()}


def _jpeg_message(image: np.ndarray, header: dict) -> dict:
    import cv2

    img = stored_image(image)
    if img.dtype != np.uint8:
        raise InputError(f"a lossy recording stores 8-bit frames as JPEG, got {img.dtype}; record "
                         f"16-bit frames losslessly (--frames lossless)")
    ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, JPEG_QUALITY])
    if not ok:
        raise InputError(f"JPEG encoding failed for a frame of shape {img.shape}")
    return {"header": header, "format": "jpeg", "data": buf.tobytes()}


class Recorder:
    """Write a live stream's frames, forces and state to an MCAP file, on a thread of its own.

    Parameters
    ----------
    path : path-like
        The ``.mcap`` file (its folder must exist).
    frames : {"lossless", "lossy", "none"}
        How frames are stored (see the module's notes; default lossless).
    source : str
        The stream's label (``camera 0``, a file name), for the metadata.
    calibration : Calibration, optional
        Attached as ``calibration.json``; its sensor and camera go in the metadata.
    sensor, camera : optional
        Without a calibration, the sensor and camera of the pipeline, for the metadata.
    options : dict, optional
        The pipeline's options (:meth:`~optitact.pipeline.frame_pipeline.Pipeline.options`).
    baseline : array_like, optional
        An explicit no-load baseline (``--baseline``), attached as ``baseline.npy``.

    Raises
    ------
    InputError
        ``frames`` not one of :data:`FRAME_STORAGE`, a path not ending in ``.mcap``, its folder
        missing, or another recorder writing it.
    MissingExtraError
        The ``mcap`` packages are not installed (the ``live`` extra).
    """

    def __init__(self, path, *, frames: str = "lossless", source: str = "", calibration=None,
                 sensor=None, camera=None, options: dict | None = None, baseline=None) -> None:
        if frames not in FRAME_STORAGE:
            raise InputError(f"frames must be one of {', '.join(FRAME_STORAGE)}, got {frames!r}")
        self.path = Path(path)
        if self.path.suffix.lower() != ".mcap":
            raise InputError(f"--record writes an MCAP file: the name must end in .mcap, got {self.path}")
        if not self.path.parent.is_dir():
            raise InputError(f"{self.path}: the folder {self.path.parent} does not exist")
        writer_mod = _require_mcap()
        from mcap.writer import CompressionType

        self.frames_mode = frames
        #: Where the recording is written until it stops cleanly.
        self.partial = self.path.with_name(self.path.stem + ".partial.mcap")
        try:
            self._file = open(self.partial, "xb")  # noqa: SIM115 - closed by close()/the thread
        except FileExistsError:
            raise InputError(f"{self.partial} exists: another recording is being written there, or an "
                             f"interrupted one was left (read it with optitact.live.record.read_recording, "
                             f"then move or delete it)") from None
        self._writer = writer_mod.Writer(self._file, compression=CompressionType.ZSTD)
        w = self._writer
        self._schemas = {
            "image": w.register_msgdef("sensor_msgs/msg/Image", _IMAGE_MSG),
            "compressed": w.register_msgdef("sensor_msgs/msg/CompressedImage", _COMPRESSED_MSG),
            "elements": w.register_msgdef("optitact_msgs/msg/ElementForces", ELEMENT_MSG),
            "wrench": w.register_msgdef("geometry_msgs/msg/WrenchStamped", _WRENCH_MSG),
            "stream": w.register_msgdef("optitact_msgs/msg/StreamStatus", STATUS_MSG),
        }
        from optitact import __version__

        if calibration is not None:
            sensor, camera = calibration.sensor, calibration.camera
        meta = {"version": __version__, "source": source, "frames": frames,
                "created": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()),
                "sensor": json.dumps(sensor.to_dict()) if sensor is not None else "",
                "camera": json.dumps(camera.to_dict()) if camera is not None else "",
                "options": json.dumps(options or {}, default=str),
                "calibration_fingerprint": calibration.fingerprint if calibration is not None else ""}
        self._meta = meta
        self._attachments: list[tuple[str, str, bytes]] = []
        if calibration is not None:
            self._attachments.append(("calibration.json", "application/json",
                                      json.dumps(calibration.to_dict()).encode()))
        if baseline is not None:
            buf = io.BytesIO()
            np.save(buf, np.asarray(baseline), allow_pickle=False)
            self._attachments.append(("baseline.npy", "application/x-npy", buf.getvalue()))
        self.with_forces = calibration is not None
        self.sensor = sensor
        self._queue: queue.Queue = queue.Queue(maxsize=QUEUE_FRAMES)
        self._error: BaseException | None = None
        #: Frames written so far.
        self.written = 0
        #: Seconds the stream waited for a full queue.
        self.waited = 0.0
        self._closed = False
        self._thread = threading.Thread(target=self._run, name="optitact-recorder", daemon=True)
        self._thread.start()

    # ------------------------------------------------------------------ the writer thread
    def _run(self) -> None:
        try:
            started = False
            while True:
                item = self._queue.get()
                if item is None:
                    break
                if not started:
                    self._start(item)
                    started = True
                self._write(item)
                self.written += 1
            if not started:
                self._start(None)
        except BaseException as exc:  # noqa: BLE001 - raised in the stream's thread by write/close
            self._error = exc
            while True:  # unblock a waiting producer; nothing more is written
                try:
                    if self._queue.get_nowait() is None:
                        break
                except queue.Empty:
                    time.sleep(0.01)

    def _start(self, first) -> None:
        # the stream's start on the wall clock: a replay gives each frame its time_s back
        start = first.wall_time - first.timestamp if first is not None else float("nan")
        self._writer.add_metadata(METADATA, self._meta | {"stream_start": repr(float(start))})
        for name, media, data in self._attachments:
            self._writer.add_attachment(create_time=time.time_ns(), log_time=time.time_ns(), name=name,
                                        media_type=media, data=data)

    def _write(self, lf) -> None:
        w, s = self._writer, self._schemas
        t_ns = _ns(lf.wall_time)
        latency, drift = float(lf.latency), lf.drift
        pub = _ns(lf.wall_time + latency) if np.isfinite(latency) else t_ns
        header = {"stamp": _stamp(lf.wall_time), "frame_id": "optitact_sensor"}
        image = lf.image if getattr(lf, "image", None) is not None else lf.frame
        if self.frames_mode == "lossless":
            msg = _image_message(image, {"stamp": header["stamp"], "frame_id": "optitact_camera"})
            w.write_message(TOPICS["image"], s["image"], msg, log_time=t_ns, publish_time=pub,
                            sequence=lf.index)
        elif self.frames_mode == "lossy":
            msg = _jpeg_message(image, {"stamp": header["stamp"], "frame_id": "optitact_camera"})
            w.write_message(TOPICS["compressed"], s["compressed"], msg, log_time=t_ns, publish_time=pub,
                            sequence=lf.index)
        r, f = lf.readings, lf.forces
        empty: list = []
        elements = {"header": header, "frame": lf.index, "source": lf.source, "g": r.G.tolist(),
                    "ux": r.u[:, 0].tolist(), "uy": r.u[:, 1].tolist(), "contact": r.contact.tolist(),
                    "saturated": r.saturated.tolist()}
        if f is not None:
            se = f.stderr if f.stderr is not None else np.full(f.local.shape, np.nan)
            elements |= {"fx": f.local[:, 0].tolist(), "fy": f.local[:, 1].tolist(),
                         "fz": f.local[:, 2].tolist(),
                         "fx_stderr": se[:, 0].tolist(), "fy_stderr": se[:, 1].tolist(),
                         "fz_stderr": se[:, 2].tolist(), "clamped": f.clamped.tolist()}
        else:
            elements |= {k: empty for k in ("fx", "fy", "fz", "fx_stderr", "fy_stderr", "fz_stderr", "clamped")}
        w.write_message(TOPICS["elements"], s["elements"], elements, log_time=t_ns, publish_time=pub,
                        sequence=lf.index)
        if f is not None:
            force, moment = f.resultant, f.moment
            wrench = {"header": header, "wrench": {
                "force": dict(zip("xyz", map(float, force), strict=True)),
                "torque": dict(zip("xyz", map(float, moment), strict=True))}}
            w.write_message(TOPICS["wrench"], s["wrench"], wrench, log_time=t_ns, publish_time=pub,
                            sequence=lf.index)
        status = {"header": header, "frame": lf.index, "time_s": float(lf.timestamp),
                  "baseline": bool(lf.baseline),
                  "dropped": int(lf.dropped),
                  "latency": float(latency), "drift_tracking": drift is not None}
        d = drift
        status |= {"drift_gain": float(d.gain) if d is not None else 1.0,
                   "drift_offset": float(d.offset) if d is not None else 0.0,
                   "drift_shift_x": float(d.shift_x) if d is not None else 0.0,
                   "drift_shift_y": float(d.shift_y) if d is not None else 0.0,
                   "drift_flag": bool(d.flag) if d is not None else False,
                   "drift_reason": str(d.reason) if d is not None else ""}
        w.write_message(TOPICS["stream"], s["stream"], status, log_time=t_ns, publish_time=pub,
                        sequence=lf.index)

    # ------------------------------------------------------------------ the stream's side
    def _raise(self) -> None:
        if self._error is not None:
            err = self._error
            raise OSError(f"{self.partial}: the recording stopped: {err}") from err

    def write(self, lf) -> None:
        """Queue one :class:`~optitact.live.stream.LiveFrame` (waits while the queue is full).

        Its :attr:`~optitact.live.stream.LiveFrame.latency` gives the moment its forces were ready
        (``publish_time``), and its ``drift`` the drift tracker's state.
        """
        self._raise()
        if self.with_forces and lf.forces is None:
            raise ValueError("this recording has forces: the frame has none (no calibration)")
        try:
            self._queue.put_nowait(lf)
        except queue.Full:
            t = time.perf_counter()
            while True:
                self._raise()
                try:
                    self._queue.put(lf, timeout=0.1)
                    break
                except queue.Full:
                    continue
            self.waited += time.perf_counter() - t

    def close(self) -> Path:
        """Write what is queued, finish the file and rename it to :attr:`path`; returns it."""
        if self._closed:
            return self.path
        self._closed = True
        self._queue.put(None)
        self._thread.join()
        try:
            self._raise()
            self._writer.finish()
        finally:
            self._file.close()
        os.replace(self.partial, self.path)
        return self.path

    def abandon(self) -> Path:
        """Stop after what is queued and finish the file, but keep it as :attr:`partial` (an error)."""
        if not self._closed:
            self._closed = True
            self._queue.put(None)
            self._thread.join()
            try:
                if self._error is None:
                    self._writer.finish()
            finally:
                self._file.close()
        return self.partial

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is None or issubclass(exc_type, KeyboardInterrupt):
            self.close()
        else:
            self.abandon()


# ----------------------------------------------------------------------------- reading
@dataclass(frozen=True)
class Recording:
    """What :func:`read_recording` finds in an MCAP file: its metadata, attachments and frames' storage.

    Attributes
    ----------
    path : Path
    metadata : dict
        The ``optitact`` metadata record (strings), empty for an MCAP another tool wrote.
    frames : str
        ``"lossless"``, ``"lossy"`` or ``"none"``: which image topic holds frames.
    n_frames : int
        Frames (image messages) in the file.
    attachments : dict
        Name -> bytes (``calibration.json``, ``baseline.npy``).
    """

    path: Path
    metadata: dict
    frames: str
    n_frames: int
    attachments: dict = field(repr=False)

    @property
    def baseline(self) -> np.ndarray | None:
        """The explicit baseline the stream was processed with, if one was given."""
        data = self.attachments.get("baseline.npy")
        return None if data is None else np.load(io.BytesIO(data), allow_pickle=False)

    @property
    def calibration(self):
        """The calibration the stream was processed with, or None."""
        data = self.attachments.get("calibration.json")
        if data is None:
            return None
        from optitact.calib.fit import Calibration

        return Calibration.from_dict(json.loads(data))

    def images(self) -> Iterator[tuple[int, float, float, np.ndarray]]:
        """``(frame, time_s, wall_time, image)`` of every stored frame, in log-time order.

        ``time_s`` is the stream's own time of the capture as the live stream had it (from
        ``/optitact/stream``), or NaN where the recording does not say.
        """
        if self.frames == "none":
            raise InputError(f"{self.path}: the recording holds no frames (it was made with --frames none); "
                             f"only its forces can be read")
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        topic = TOPICS["image"] if self.frames == "lossless" else TOPICS["compressed"]
        pending: dict[int, tuple[float, np.ndarray]] = {}
        with open(self.path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _schema, channel, message, decoded in reader.iter_decoded_messages(
                    topics=[topic, TOPICS["stream"]], log_time_order=True):
                if channel.topic == topic:
                    if pending:  # an image whose status never came: its time from the wall clock
                        (index, (wall, image)), = pending.items()
                        pending.clear()
                        yield index, float("nan"), wall, image
                    pending[message.sequence] = (message.log_time / 1e9, _decode_image(decoded))
                elif message.sequence in pending:
                    wall, image = pending.pop(message.sequence)
                    yield message.sequence, float(getattr(decoded, "time_s", float("nan"))), wall, image
            for index, (wall, image) in pending.items():
                yield index, float("nan"), wall, image

    def messages(self, topic: str) -> Iterator:
        """The decoded ROS 2 messages of a topic (``TOPICS[...]``), in log-time order."""
        from mcap.reader import make_reader
        from mcap_ros2.decoder import DecoderFactory

        with open(self.path, "rb") as f:
            reader = make_reader(f, decoder_factories=[DecoderFactory()])
            for _schema, _channel, message, decoded in reader.iter_decoded_messages(topics=[topic],
                                                                                   log_time_order=True):
                yield message, decoded


def _decode_image(decoded) -> np.ndarray:
    if hasattr(decoded, "encoding"):
        dtype, channels = _DECODINGS.get(decoded.encoding, (None, None))
        if dtype is None:
            raise InputError(f"an image of encoding {decoded.encoding!r}; optitact reads "
                             f"{', '.join(_DECODINGS)}")
        dt = np.dtype(dtype).newbyteorder(">" if decoded.is_bigendian else "<")
        flat = np.frombuffer(bytes(decoded.data), dt)
        rows = flat.reshape(decoded.height, decoded.step // dt.itemsize)
        img = rows[:, :decoded.width * channels]
        img = img.reshape(decoded.height, decoded.width) if channels == 1 else img.reshape(
            decoded.height, decoded.width, channels)
        return img.astype(dt.newbyteorder("="), copy=True)
    import cv2

    img = cv2.imdecode(np.frombuffer(bytes(decoded.data), np.uint8), cv2.IMREAD_UNCHANGED)
    if img is None:
        raise InputError(f"a compressed image of format {decoded.format!r} that OpenCV cannot decode")
    return img


def read_recording(path) -> Recording:
    """Open an MCAP recording: its metadata, attachments and how many frames it holds.

    Raises
    ------
    FileNotFoundError
        No such file.
    InputError
        Not an MCAP file, or one without an optitact image topic nor ``sensor_msgs`` images.
    MissingExtraError
        The ``mcap`` packages are not installed (the ``live`` extra).
    """
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"recording not found: {path}")
    _require_mcap()
    from mcap.exceptions import McapError
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as f:
            reader = make_reader(f)
            summary = reader.get_summary()
            counts: dict[str, int] = {}
            metadata: dict = {}
            attachments: dict = {}
            if summary is not None and summary.statistics is not None:
                for cid, n in summary.statistics.channel_message_counts.items():
                    counts[summary.channels[cid].topic] = n
            for meta in reader.iter_metadata():
                if meta.name == METADATA:
                    metadata = dict(meta.metadata)
            for att in reader.iter_attachments():
                attachments[att.name] = bytes(att.data)
            if not counts:  # no summary (an interrupted recording): count by reading
                f.seek(0)
                for _schema, channel, _message in make_reader(f).iter_messages():
                    counts[channel.topic] = counts.get(channel.topic, 0) + 1
    except McapError as exc:
        raise InputError(f"{path}: not a readable MCAP file ({exc})") from exc
    if counts.get(TOPICS["image"]):
        frames, n = "lossless", counts[TOPICS["image"]]
    elif counts.get(TOPICS["compressed"]):
        frames, n = "lossy", counts[TOPICS["compressed"]]
    else:
        frames, n = "none", 0
    if not metadata and frames == "none":
        raise InputError(f"{path}: an MCAP file without optitact's topics ({', '.join(TOPICS.values())}); "
                         f"found {', '.join(sorted(counts)) or 'no messages'}")
    return Recording(path=path, metadata=metadata, frames=frames, n_frames=n, attachments=attachments)


class RecordingCapture:
    """A recording's frames as a capture (``read()``, ``release()``), with their recorded capture times.

    :func:`~optitact.live.stream.stream` takes it like a ``cv2.VideoCapture``,
    and through :meth:`read_stamped` gives each frame its recorded index and
    capture time rather than the replay's clock.
    """

    def __init__(self, path) -> None:
        self.recording = read_recording(path)
        if self.recording.frames == "none":
            raise InputError(f"{self.recording.path}: the recording holds no frames (made with --frames none), "
                             f"so it cannot be re-processed; record with --frames lossless")
        self._items = self.recording.images()
        start = float(self.recording.metadata.get("stream_start", "nan"))
        #: The recorded stream's start on the wall clock (None: the first frame's time).
        self.start: float | None = start if np.isfinite(start) else None

    def read_stamped(self):
        """``(ok, image, index, seconds since the stream's start, wall time)`` of the next frame.

        The seconds are those the live stream had (recorded with each frame), so a replay's
        ``time_s`` and its drift tracker's clock are the live ones to the bit.
        """
        item = next(self._items, None)
        if item is None:
            return False, None, -1, float("nan"), float("nan")
        index, t, wall, image = item
        if self.start is None:
            self.start = wall if np.isnan(t) else wall - t
        return True, image, index, (wall - self.start) if np.isnan(t) else t, wall

    def read(self):
        """``(ok, image)`` of the next frame, like ``cv2.VideoCapture.read``."""
        ok, image, *_ = self.read_stamped()
        return ok, image

    def release(self) -> None:
        """Stop reading."""
        self._items.close()
