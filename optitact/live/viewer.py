"""The live view: a stream's frames, element regions, forces and their time series in Rerun.

:func:`open_view` opens a :class:`LiveView`; its :meth:`LiveView.log` takes
the :class:`~optitact.live.stream.LiveFrame` objects of
:func:`~optitact.live.stream.stream` one by one (``optitact process --camera 0
--calibration cal.json --view`` is that loop behind a command line). What the
viewer shows, frame by frame:

- the camera's view (2-D): the grey frame as the camera took it, the
  element regions drawn over it (their outlines, a geodesic circle of the
  pipeline's region radius around each element centre, projected through
  the dome as the pipeline reads them), the elements in contact (green;
  saturated orange, clamped red) and a shear arrow per element from its
  centre: the estimated shear ``(Fx, Fy)`` laid onto the dome at
  ``scale_mm_per_n`` and seen by the camera, coloured by ``Fz``; without a
  calibration the centroid shift ``u`` (times ``shift_scale``) instead;
- the dome (3-D, sensor frame, mm): its outer surface as a wireframe, the
  element centres and the camera, and with a calibration a force arrow per
  element (from the element centre, the force the object exerts on it
  times ``scale_mm_per_n``), coloured by ``Fz`` on a fixed scale, with the
  90 % interval of each contact element's force as an ellipsoid around the
  arrow's tip (half-axes ``1.645 stderr`` along the element's own axes);
  without a calibration the elements in contact;
- time series: the resultant force ``(Fx, Fy, Fz)`` (sensor frame, summed
  over the contact elements, :attr:`optitact.forces.ForceField.resultant`),
  the normal force ``Fz`` of a few chosen elements (without a calibration
  their ``G``), and the stream's frames processed and dropped and its
  latency (ms).

Why Rerun: it is pip-installable (``rerun-sdk``, the ``live`` extra), its
native viewer and its web viewer show the same data live or from an
``.rrd`` file, offline, with nothing to set up; an ``.rrd`` file keeps the
whole session (frames, forces, timelines) for replay with ``rerun
FILE.rrd`` and for reading back in Python; and robotics uses it (LeRobot
visualises its data sets with it), so the sensor's forces can sit beside a
robot's other streams.

Everything that does not change (the regions, the dome, the blueprint
that arranges the views) is computed and logged once, when the view opens;
a frame logs the image and a few arrays of one row per element (about a
millisecond a frame at 640x480, see :meth:`LiveView.log`).

Entity paths
------------
Timelines: ``frame`` (sequence, :attr:`LiveFrame.index`), ``capture_time``
(duration, :attr:`LiveFrame.timestamp`) and, when the wall clock is known,
``wall_time`` (timestamp). Rerun adds ``log_time``. Arrays with one row per
element are in element order (instance ``i`` is element ``i``).

====================  ===============================================================  ==========
path                  what                                                             when
====================  ===============================================================  ==========
``camera/image``      the grey frame (``Image``, colour model L, the frame's dtype)    per frame
``camera/regions``    region outlines in pixels ``(x = col, y = row)`` (LineStrips2D)  static
``camera/centres``    element centres in pixels (Points2D)                             static
``camera/contact``    elements in contact, saturated or clamped (Points2D)             per frame
``camera/shear``      shear (or ``u``) arrows from the element centres (Arrows2D)      per frame
``dome``              view coordinates: right-handed, z up (the sensor frame)          static
``dome/surface``      the outer dome surface as parallels and meridians                static
``dome/elements``     element centres on the outer surface (Points3D, mm)              static
``dome/camera``       the camera's projection centre (Points3D)                        static
``dome/forces``       force arrows, one per element (Arrows3D; with forces)            per frame
``dome/interval``     90 % intervals of the contact elements (Ellipsoids3D)            per frame
``dome/contact``      elements in contact (Points3D; without forces)                   per frame
``forces/resultant``  ``Fx, Fy, Fz`` of the resultant, N (Scalars)                     per frame
``forces/elements``   ``Fz`` of the chosen elements, N (Scalars)                       per frame
``readings/G``        ``G`` of the chosen elements (Scalars; without forces)           per frame
``stats/frames``      frames processed (given to :meth:`LiveView.log`) and dropped     per frame
``stats/latency_ms``  the latency passed to :meth:`LiveView.log`, ms                   when given
====================  ===============================================================  ==========

Examples
--------
>>> from optitact.live.stream import stream
>>> from optitact.live.viewer import open_view
>>> with open_view("session.rrd", calibration=cal) as view:  # doctest: +SKIP
...     for lf in stream(0, calibration=cal, seconds=10):
...         view.log(lf)
"""

from __future__ import annotations

import math
import os
import socket
import uuid
from pathlib import Path
from urllib.parse import quote

import numpy as np

from optitact._optional import require
from optitact._validate import integer, positive, real_number
from optitact.errors import InputError, ShapeError
from optitact.optics.camera import Camera
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.regions import default_region_radius
from optitact.pipeline.uncertainty import Z90

__all__ = ["FORCE_RANGE", "GRPC_PORT", "VIEW_TARGETS", "WEB_PORT", "LiveView", "default_elements", "open_view"]

#: What :func:`open_view` accepts, as its messages name it: Rerun's native viewer, its web viewer, or a
#: file (any path ending in ``.rrd``).
VIEW_TARGETS = ("native", "web", "FILE.rrd")

#: Rerun's default port of its web viewer (``target="web"``).
WEB_PORT = 9090
#: Rerun's default port of its gRPC server (``target="web"``; the native viewer listens on it too).
GRPC_PORT = 9876

#: The default range (N) of ``Fz`` that the force colours span (below: the first colour, above: the last).
FORCE_RANGE = (0.0, 1.0)

# Viridis at nine evenly spaced stops; the colour scale of Fz (perceptually even, readable in grey).
_VIRIDIS = np.array([(68, 1, 84), (71, 44, 122), (59, 81, 139), (44, 113, 142), (33, 144, 141),
                     (39, 173, 129), (92, 200, 99), (170, 220, 50), (253, 231, 37)], float)
_CONTACT_RGB = np.array([(40, 200, 90), (255, 150, 0), (230, 30, 30)], np.uint8)  # contact, saturated, clamped
_SERIES_RGB = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
               (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]
_SHIFT_RGB = (0, 200, 230)
_OUTLINE_POINTS = 48  # points per region outline
_JACOBIAN_STEP_MM = 0.01  # central-difference step of the pixels' derivative along the dome


def default_elements(sensor: DomeSensor) -> tuple[int, ...]:
    """The elements whose normal force the view plots by default: the first of each ring, at most 4.

    Ring 0 of the default sensor is the apex, so the default is the centre
    element and the first element (on the +x side) of each of the next three
    rings: ``(0, 1, 9, 25)``.

    Examples
    --------
    >>> default_elements(DomeSensor.default())
    (0, 1, 9, 25)
    """
    starts = np.concatenate([[0], np.cumsum(sensor.ring_counts)[:-1]])
    return tuple(int(i) for i, n in zip(starts, sensor.ring_counts, strict=True) if n > 0)[:4]


def _check_elements(elements, n: int) -> np.ndarray:
    if isinstance(elements, (int, np.integer)) and not isinstance(elements, bool):
        elements = [elements]
    try:
        items = list(elements)
    except TypeError:
        raise TypeError(f"elements must be a sequence of element indices, "
                        f"got {type(elements).__name__}") from None
    idx = [integer(i, "elements") for i in items]
    if not idx:
        raise InputError("elements must name at least one element")
    bad = [i for i in idx if not 0 <= i < n]
    if bad:
        raise InputError(f"elements must be element indices from 0 to {n - 1}, got {bad}")
    if len(set(idx)) != len(idx):
        raise InputError(f"elements must not repeat an element, got {idx}")
    return np.array(idx, np.intp)


def _target(target) -> tuple[str, Path | None]:
    """``(kind, path)`` of a view target: ``("native", None)``, ``("web", None)`` or ``("rrd", path)``."""
    accepted = "'native' (Rerun's native viewer), 'web' (its web viewer) or a FILE.rrd path to write"
    if isinstance(target, str) and target in ("native", "web"):
        return target, None
    if isinstance(target, (str, os.PathLike)):
        text = os.fspath(target)
        if isinstance(text, str) and text.lower().endswith(".rrd"):
            path = Path(text)
            if path.is_dir():
                raise InputError(f"view target {text!r} is a folder; give a file name ending in .rrd")
            if not path.parent.is_dir():
                raise FileNotFoundError(f"view target {text!r}: folder {str(path.parent)!r} does not exist")
            return "rrd", path
    raise InputError(f"view target must be one of {accepted}; got {target!r}")


def _port(value, name: str) -> int:
    port = integer(value, name, minimum=1)
    if port > 65535:
        raise InputError(f"{name} must be a port number from 1 to 65535, got {port}")
    return port


def _check_free(port: int, name: str) -> None:
    """InputError unless a server can listen on ``port`` of 127.0.0.1."""
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
        except OSError as exc:
            raise InputError(f"port {port} ({name}) is not free on 127.0.0.1 ({exc.strerror}): another "
                             f"viewer or program listens on it; choose another {name}") from None


def _colormap(lo: float, hi: float) -> tuple[np.ndarray, float, float]:
    """A 256-entry RGB table of viridis, and the offset and gain that map a force onto its index."""
    stops = np.linspace(0.0, 1.0, len(_VIRIDIS))
    t = np.linspace(0.0, 1.0, 256)
    lut = np.stack([np.interp(t, stops, _VIRIDIS[:, c]) for c in range(3)], axis=1)
    return np.rint(lut).astype(np.uint8), lo, 255.0 / (hi - lo)


def _quaternions(frames: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, w)`` of the rotations from the element frames to the sensor frame."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_matrix(np.transpose(frames, (0, 2, 1))).as_quat()


def _dome_wireframe(radius: float, step_deg: float = 15.0, meridians: int = 12) -> list[np.ndarray]:
    """Parallels every ``step_deg`` down to the base and ``meridians`` meridians of a hemisphere (mm)."""
    az = np.linspace(0.0, 2.0 * np.pi, 121)
    strips = []
    for polar in np.deg2rad(np.arange(step_deg, 90.0 + 1e-9, step_deg)):
        strips.append(radius * np.stack([np.sin(polar) * np.cos(az), np.sin(polar) * np.sin(az),
                                         np.full_like(az, np.cos(polar))], axis=1))
    polar = np.linspace(0.0, np.pi / 2.0, 31)
    for a in 2.0 * np.pi * np.arange(meridians) / meridians:
        strips.append(radius * np.stack([np.sin(polar) * np.cos(a), np.sin(polar) * np.sin(a), np.cos(polar)],
                                        axis=1))
    return strips


class LiveView:
    """A Rerun recording of a live stream: the camera's view, the dome's forces and their time series.

    Made by :func:`open_view` (the same arguments); see the module for what
    is shown and where it is logged.

    Attributes
    ----------
    target : str
        ``"native"``, ``"web"`` or the ``.rrd`` file's path.
    url : str or None
        The web viewer's address to open in a browser (``target="web"``);
        None otherwise.
    path : Path or None
        The ``.rrd`` file (a file target); None otherwise.
    recording : rerun.RecordingStream
        The view's own recording (not Rerun's global one), for logging more
        beside the sensor (a robot's joints, say) on the same timelines.
    sensor : DomeSensor
    camera : Camera
    elements : tuple of int
        The elements whose ``Fz`` (or ``G``) is plotted.
    scale_mm_per_n : float
        Length of the force arrows per newton (mm/N): in 3-D, and of the
        shear laid onto the dome in the camera's view.
    frames : int
        Frames logged so far.
    """

    def __init__(self, target, *, sensor: DomeSensor | None = None, camera: Camera | None = None,
                 calibration=None, elements=None, name: str = "optitact", radius: float | None = None,
                 scale_mm_per_n: float = 10.0, shift_scale: float = 5.0,
                 force_range: tuple[float, float] = FORCE_RANGE, image_every: int = 1, window_s: float = 10.0,
                 web_port: int = WEB_PORT, grpc_port: int = GRPC_PORT) -> None:
        kind, path = _target(target)
        rr = require("rerun", purpose="the live view")
        self._rr = rr
        if calibration is not None:
            calibration.check(sensor, camera)  # a CalibrationMismatchError unless they are its own
            sensor = calibration.sensor if sensor is None else sensor
            camera = calibration.camera if camera is None else camera
        if sensor is None:
            sensor = DomeSensor.default()
        if not isinstance(sensor, DomeSensor):
            raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
        if not isinstance(camera, Camera):
            raise TypeError("camera must be a Camera (e.g. a FisheyeCamera): the one that takes the frames"
                            if camera is None else f"camera must be a Camera, got {type(camera).__name__}")
        if not isinstance(name, str) or not name:
            raise InputError(f"name must be a non-empty string, got {name!r}")
        self.sensor, self.camera = sensor, camera
        self.scale_mm_per_n = positive(scale_mm_per_n, "scale_mm_per_n")
        self.shift_scale = positive(shift_scale, "shift_scale")
        lo, hi = (real_number(v, "force_range") for v in force_range)
        if not hi > lo:
            raise InputError(f"force_range must be (low, high) with high > low, got {force_range!r}")
        self.force_range = (lo, hi)
        self.image_every = integer(image_every, "image_every", minimum=1)
        self.window_s = positive(window_s, "window_s")
        web_port, grpc_port = _port(web_port, "web_port"), _port(grpc_port, "grpc_port")
        n = sensor.n_elements
        self.elements = tuple(int(i) for i in _check_elements(default_elements(sensor) if elements is None
                                                               else elements, n))
        self._chosen = np.array(self.elements, np.intp)
        if radius is None:
            options = getattr(calibration, "pipeline_options", None) or {}
            radius = options.get("radius") or default_region_radius(sensor)
        self.radius = positive(radius, "radius")
        self.with_forces = calibration is not None

        self._geometry()
        self._lut, self._lo, self._gain = _colormap(lo, hi)
        self.frames = 0
        self._closed = False

        self.target = str(path) if kind == "rrd" else kind
        self.path, self.url = path, None
        rec = rr.RecordingStream(name, recording_id=uuid.uuid4())
        self.recording = rec
        if kind == "rrd":
            rec.save(path)
        elif kind == "native":
            rec.spawn(port=grpc_port, connect=True, hide_welcome_screen=True)
        else:
            _check_free(grpc_port, "grpc_port")  # Rerun only logs an error when its gRPC server cannot listen
            sink = rr.GrpcServerSink(bind_ip="127.0.0.1", port=grpc_port)
            rec.set_sinks(sink)
            try:
                rr.serve_web_viewer(web_port=web_port, open_browser=False, connect_to=sink.uri)
            except RuntimeError as exc:
                rec.disconnect()
                raise InputError(f"the web viewer cannot listen on port {web_port} ({exc}); choose another "
                                 f"web_port") from None
            self.url = f"http://localhost:{web_port}/?url={quote(sink.uri, safe=':/')}"
        rec.send_blueprint(self._blueprint(live=kind != "rrd"), make_active=True, make_default=True)
        self._log_static()

    # ------------------------------------------------------------------ set-up, once
    def _geometry(self) -> None:
        """The static geometry: element centres and regions in pixels, pixels per mm along the dome."""
        s, cam = self.sensor, self.camera
        n = s.n_elements
        e = np.arange(n)
        self._shape = cam.shape
        centres = cam.project(s.element_positions, s, outside="nan")[:, ::-1]  # (x, y) = (col, row)
        self._centres = centres.astype(np.float32)
        h = _JACOBIAN_STEP_MM
        steps = np.array([(h, 0.0), (-h, 0.0), (0.0, h), (0.0, -h)])
        px = cam.project(s.dome_point(np.repeat(e, 4), np.tile(steps, (n, 1))), s, outside="nan")
        px = px.reshape(n, 4, 2)[..., ::-1]
        jac = np.stack([px[:, 0] - px[:, 1], px[:, 2] - px[:, 3]], axis=-1) / (2.0 * h)  # (n, 2 xy, 2 mm)
        #: Pixels (x, y) per mm of tangent offset at each element centre: the arrows' map onto the image.
        self._jacobian = np.nan_to_num(jac)
        ang = np.linspace(0.0, 2.0 * np.pi, _OUTLINE_POINTS + 1)
        ring = self.radius * np.stack([np.cos(ang), np.sin(ang)], axis=1)
        pts = s.dome_point(np.repeat(e, len(ring)), np.tile(ring, (n, 1)))
        outline = cam.project(pts, s, outside="nan").reshape(n, len(ring), 2)[..., ::-1]
        self._outlines = [o[np.isfinite(o).all(axis=1)] for o in outline]
        self._outlines = [o for o in self._outlines if len(o) >= 2]
        self._positions = s.element_positions.astype(np.float32)
        self._quats = _quaternions(s.element_frames).astype(np.float32)

    def _blueprint(self, *, live: bool):
        rrb = require("rerun.blueprint", purpose="the live view")
        h, w = self._shape
        lo, hi = self.force_range
        boundary = rrb.TimeRangeBoundary
        window = rrb.VisibleTimeRange("capture_time", start=boundary.cursor_relative(seconds=-self.window_s),
                                      end=boundary.cursor_relative())

        def series(origin: str, title: str):
            return rrb.TimeSeriesView(origin=origin, name=title, time_ranges=window)

        what = "shear" if self.with_forces else "centroid shift"
        scale = f"{self.scale_mm_per_n:g} mm/N" if self.with_forces else f"x {self.shift_scale:g}"
        camera = rrb.Spatial2DView(origin="camera", name=f"camera ({what} on the dome, {scale})",
                                   visual_bounds=rrb.VisualBounds2D(x_range=[-0.5, w - 0.5],
                                                                    y_range=[-0.5, h - 0.5]))
        dome = rrb.Spatial3DView(origin="dome", name=(f"dome (force {self.scale_mm_per_n:g} mm/N, colour Fz "
                                                      f"{lo:g} to {hi:g} N, 90 % ellipsoids)")
                                 if self.with_forces else "dome (elements in contact)")
        plots = [series("forces/resultant", "resultant force (N, sensor frame)"),
                 series("forces/elements", "Fz of chosen elements (N)")] if self.with_forces else \
            [series("readings/G", "G of chosen elements")]
        stats = rrb.Vertical(series("stats/frames", "frames"), series("stats/latency_ms", "latency (ms)"),
                             name="stream")
        return rrb.Blueprint(
            rrb.Vertical(rrb.Horizontal(camera, dome), rrb.Horizontal(*plots, stats), row_shares=[3, 2]),
            rrb.BlueprintPanel(state="collapsed"), rrb.SelectionPanel(state="collapsed"),
            rrb.TimePanel(timeline="capture_time", play_state="following" if live else None),
            auto_layout=False, auto_views=False)

    def _log_static(self) -> None:
        rr, rec, s = self._rr, self.recording, self.sensor
        labels = [str(i) for i in range(s.n_elements)]
        rec.log("camera/regions", rr.LineStrips2D(self._outlines, radii=0.6, colors=(255, 255, 255, 90),
                                                  draw_order=10.0), static=True)
        rec.log("camera/centres", rr.Points2D(self._centres, radii=1.2, colors=(200, 200, 200), labels=labels,
                                              show_labels=False, draw_order=11.0), static=True)
        rec.log("dome", rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
        rec.log("dome/surface", rr.LineStrips3D(_dome_wireframe(s.outer_radius), radii=0.03,
                                                colors=(150, 150, 150, 120)), static=True)
        rec.log("dome/elements", rr.Points3D(self._positions, radii=0.25, colors=(200, 200, 200), labels=labels,
                                             show_labels=False), static=True)
        rec.log("dome/camera", rr.Points3D(self.camera.position[None], radii=0.6, colors=(255, 255, 255),
                                           labels=["camera"]), static=True)
        names = [f"Fz {i}" if self.with_forces else f"G {i}" for i in self.elements]
        colours = [_SERIES_RGB[k % len(_SERIES_RGB)] for k in range(len(names))]
        if self.with_forces:
            rec.log("forces/resultant", rr.SeriesLines(names=["Fx", "Fy", "Fz"],
                                                       colors=[(220, 50, 50), (50, 170, 50), (50, 90, 220)]),
                    static=True)
            rec.log("forces/elements", rr.SeriesLines(names=names, colors=colours), static=True)
        else:
            rec.log("readings/G", rr.SeriesLines(names=names, colors=colours), static=True)
        rec.log("stats/frames", rr.SeriesLines(names=["processed", "dropped"],
                                               colors=[(50, 90, 220), (220, 50, 50)]), static=True)
        rec.log("stats/latency_ms", rr.SeriesLines(names=["latency (ms)"], colors=[(120, 120, 120)]),
                static=True)
        # The per-frame entities' fixed properties, once: a frame logs only what changes.
        rec.log("camera/contact", rr.Points2D.from_fields(radii=3.0, draw_order=12.0), static=True)
        shift_colour = None if self.with_forces else _SHIFT_RGB
        rec.log("camera/shear", rr.Arrows2D.from_fields(radii=1.0, draw_order=13.0, colors=shift_colour),
                static=True)
        if self.with_forces:
            rec.log("dome/forces", rr.Arrows3D.from_fields(radii=0.15), static=True)
            rec.log("dome/interval", rr.Ellipsoids3D.from_fields(fill_mode="MajorWireframe", line_radii=0.03),
                    static=True)
        else:
            rec.log("dome/contact", rr.Points3D.from_fields(radii=0.8, colors=_CONTACT_RGB[0]), static=True)

    # ------------------------------------------------------------------ per frame
    def _colours(self, fz: np.ndarray) -> np.ndarray:
        k = np.clip((fz - self._lo) * self._gain + 0.5, 0.0, 255.0).astype(np.intp)
        return self._lut[k]

    def log(self, frame, latency_s: float | None = None) -> None:
        """Log one frame of the stream: its image, overlays, forces and time series.

        Parameters
        ----------
        frame : LiveFrame
            A frame of :func:`~optitact.live.stream.stream` (or any object with
            its ``index``, ``timestamp``, ``wall_time``, ``frame``,
            ``readings``, ``forces`` and ``dropped``).
        latency_s : float, optional
            The frame's latency (s), plotted in ms; not plotted when None.

        Raises
        ------
        ShapeError
            The frame is not of the camera's size, or its readings not of
            the sensor's elements.
        RuntimeError
            The view is closed.

        Notes
        -----
        The image goes to Rerun as it is (grey, no colour conversion; Rerun
        copies its bytes once); the rest is a few arrays of one row per
        element, the static parts logged at open. Measured on a two-core
        machine with the shipped calibration and 640x480 ``uint8`` frames
        paced at 60 frames a second: about 1.4 ms a call (median), against
        0.7 ms for the pipeline and forces of the same frame; Rerun's own
        calls are most of it. ``image_every=2`` saves about 0.2 ms and the
        few stalls of several ms when Rerun's batcher takes the images.
        """
        if self._closed:
            raise RuntimeError("this live view is closed")
        rr, rec = self._rr, self.recording
        image, readings, forces = frame.frame, frame.readings, frame.forces
        if image.shape != self._shape:
            raise ShapeError(f"frame {frame.index}: the view is for {self._shape[1]}x{self._shape[0]} frames "
                             f"(its camera's), got shape {image.shape}")
        n = self.sensor.n_elements
        if readings.G.shape != (n,):
            raise ShapeError(f"frame {frame.index}: readings of {n} elements expected, got G of shape "
                             f"{readings.G.shape}")
        self.frames += 1
        rec.set_time("frame", sequence=int(frame.index))
        rec.set_time("capture_time", duration=float(frame.timestamp))
        wall = float(frame.wall_time)
        if math.isfinite(wall):
            rec.set_time("wall_time", timestamp=wall)
        if (self.frames - 1) % self.image_every == 0:
            rec.log("camera/image", rr.Image(image, color_model="L"))

        contact = readings.contact if forces is None else forces.contact
        state = np.where(readings.saturated, 1, 0)
        if forces is not None:
            state = np.where(forces.clamped, 2, state)
        flagged = np.flatnonzero(contact | (state > 0))
        rec.log("camera/contact", rr.Points2D(self._centres[flagged], colors=_CONTACT_RGB[state[flagged]]))
        if forces is not None:
            local = forces.local
            colours = self._colours(local[:, 2])
            shear_px = np.einsum("eij,ej->ei", self._jacobian, local[:, :2] * self.scale_mm_per_n)
            rec.log("camera/shear", rr.Arrows2D(origins=self._centres, vectors=shear_px, colors=colours))
            tips = forces.global_forces * self.scale_mm_per_n
            rec.log("dome/forces", rr.Arrows3D(origins=self._positions, vectors=tips, colors=colours))
            idx = np.flatnonzero(forces.contact) if forces.stderr is not None else np.zeros(0, np.intp)
            half = (Z90 * self.scale_mm_per_n) * forces.stderr[idx] if idx.size else np.zeros((0, 3))
            rec.log("dome/interval", rr.Ellipsoids3D(centers=self._positions[idx] + tips[idx], half_sizes=half,
                                                     quaternions=self._quats[idx], colors=colours[idx]))
            rec.log("forces/resultant", rr.Scalars(forces.resultant))
            rec.log("forces/elements", rr.Scalars(local[self._chosen, 2]))
        else:
            shift_px = np.einsum("eij,ej->ei", self._jacobian, readings.u * self.shift_scale)
            rec.log("camera/shear", rr.Arrows2D(origins=self._centres, vectors=shift_px))
            rec.log("dome/contact", rr.Points3D(self._positions[np.flatnonzero(contact)]))
            rec.log("readings/G", rr.Scalars(readings.G[self._chosen]))
        rec.log("stats/frames", rr.Scalars([float(self.frames), float(frame.dropped)]))
        if latency_s is not None:
            rec.log("stats/latency_ms", rr.Scalars(1e3 * float(latency_s)))

    # ------------------------------------------------------------------ the end
    def close(self) -> None:
        """Flush what was logged and close the target (a file is complete then); again does nothing.

        The native viewer keeps the data it received; the web viewer's page
        keeps it too, but its gRPC server stops (the page that serves the
        viewer stays until the process ends: Rerun has no way to stop it).
        """
        if self._closed:
            return
        self._closed = True
        self.recording.flush()
        self.recording.disconnect()

    def __enter__(self) -> LiveView:
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        self.close()

    def __repr__(self) -> str:
        state = "closed" if self._closed else "open"
        return f"LiveView(target={self.target!r}, frames={self.frames}, {state})"


def open_view(target, *, sensor: DomeSensor | None = None, camera: Camera | None = None, calibration=None,
              elements=None, name: str = "optitact", **options) -> LiveView:
    """Open a live view of a stream in Rerun: its native viewer, its web viewer or an ``.rrd`` file.

    Parameters
    ----------
    target : str or path-like
        ``"native"``: spawn Rerun's native viewer (``rerun``, needs a
        display) and stream to it. ``"web"``: serve Rerun's web viewer and
        the gRPC server it reads from, on this machine (print
        :attr:`LiveView.url` and open it in a browser; nothing opens by
        itself). A path ending in ``.rrd``: write the recording to that
        file (replace it), for ``rerun FILE.rrd`` later (or while it is
        written).
    sensor : DomeSensor, optional
        Default the calibration's, else ``DomeSensor.default()``.
    camera : Camera, optional
        The camera that takes the frames; default the calibration's (one of
        the two is needed).
    calibration : Calibration, optional
        The frames carry forces: the view shows them (3-D arrows, intervals,
        resultant, the chosen elements' ``Fz``). Without one: the readings
        (``u`` arrows, contact, ``G``).
    elements : sequence of int, optional
        Elements whose ``Fz`` (without a calibration ``G``) is plotted over
        time; default :func:`default_elements` (the centre and the first
        element of each ring, at most 4).
    name : str
        The recording's application id: the name the viewer shows.
    **options
        ``radius`` (the regions' radius, mm; default the calibration's
        pipeline's, else :func:`~optitact.pipeline.regions.default_region_radius`),
        ``scale_mm_per_n`` (arrow length per newton, default 10),
        ``shift_scale`` (the ``u`` arrows' length per mm of shift, default 5),
        ``force_range`` (the ``Fz`` that the colours span, default
        :data:`FORCE_RANGE`, 0 to 1 N), ``image_every`` (log the image of
        every n-th frame only, default 1: every frame), ``window_s`` (the
        seconds the time series show, default 10), ``web_port`` and
        ``grpc_port`` (default :data:`WEB_PORT` 9090 and :data:`GRPC_PORT`
        9876, Rerun's; ``grpc_port`` is the native viewer's port too).

    Returns
    -------
    LiveView

    Raises
    ------
    InputError
        An unknown target (the message lists :data:`VIEW_TARGETS`), or an
        option out of range.
    FileNotFoundError
        An ``.rrd`` path in a folder that does not exist.
    MissingExtraError
        Rerun is not installed (``pip install 'optitact[live]'``).
    CalibrationMismatchError
        ``sensor`` or ``camera`` is not the calibration's.

    Notes
    -----
    The gRPC server of ``"web"`` listens on 127.0.0.1 only; Rerun's page
    server listens on every interface but serves only the viewer's code, so
    the data stay on this machine (to watch from another one, forward both
    ports over SSH). The view logs to a recording of its own, never Rerun's
    global one, so views do not mix.
    """
    return LiveView(target, sensor=sensor, camera=camera, calibration=calibration, elements=elements, name=name,
                    **options)
