"""``optitact process``: camera frames to a readings (or forces) CSV (:mod:`optitact.pipeline.batch`)."""

from __future__ import annotations

import contextlib
import sys
from contextlib import closing, nullcontext
from dataclasses import replace
from pathlib import Path

import numpy as np

from optitact.optics.camera import FisheyeCamera
from optitact.errors import InputError
from optitact.live.stream import POLICIES
from optitact.optics.sensor import DomeSensor

from optitact.cli._args import (calibration_on_setup, check_frame_size, int_at_least, positive_int,
                                read_setup)

__all__ = ["add_parsers"]


def add_parsers(sub) -> None:
    """Add ``process`` to the subcommands."""
    proc = sub.add_parser(
        "process", help="camera frames -> per-element readings CSV (G, u, contact)",
        description="Process camera frames of the dome into per-element readings: integrated "
                    "grey value G (grey level x mm^2 on the dome), centroid shift u (mm, "
                    "element-local x, y), contact and saturation flags; one CSV row per frame "
                    "and element. FRAMES are image files (PNG/TIFF/..., 8 or 16 bit), folders "
                    "of them (sorted by name), .npy frames or stacks, or videos (OpenCV); colour "
                    "is converted to grey. The no-load baseline is --baseline, or else the mean "
                    "of the first --baseline-frames frames (default 1: the stream must start "
                    "unloaded, and at least one frame must follow). With --calibration the CSV "
                    "also has element-local fx, fy, fz and global fx_global, fy_global, fz_global "
                    "(N) per element, and READINGS.per_frame.csv beside it has one row per frame: "
                    "elements in contact, total normal force, resultant (global, N) and centre of "
                    "pressure (mm). Files appear when the run is complete; a failed run keeps the "
                    "rows done so far as READINGS.partial.csv and says so.")
    proc.add_argument("frames", nargs="*", type=Path, metavar="FRAMES",
                      help="image files, folders, .npy stacks or video files (or --camera)")
    proc.add_argument("--out", type=Path, required=True, metavar="READINGS.csv",
                      help="the table to write: READINGS.csv, or READINGS.parquet (columnar, the columnar "
                           "extra) for long recordings (its folder must exist; with --calibration also "
                           "READINGS.per_frame.csv/.parquet)")
    proc.add_argument("--baseline", type=Path, default=None, metavar="FRAME",
                      help="no-load frame (image or .npy; a .npy stack is averaged)")
    proc.add_argument("--baseline-frames", type=int_at_least(0, "an integer >= 0"), default=1,
                      help="without --baseline: average this many first frames as the no-load "
                           "baseline (default 1; 0 subtracts nothing)")
    proc.add_argument("--setup", type=Path, default=None, metavar="FILE.json",
                      help="JSON holding 'sensor' and 'camera' parameters (e.g. the forces.json "
                           "that optitact demo writes); default: the default dome and a fisheye "
                           "camera of the frames' size")
    proc.add_argument("--fov", type=float, default=140.0,
                      help="without --setup: camera field of view across the shorter side (deg, "
                           "default 140)")
    proc.add_argument("--camera-z", type=float, default=-5.0,
                      help="without --setup: camera height on the dome axis (mm, default -5)")
    proc.add_argument("--method", choices=("fast", "reference"), default="fast",
                      help="fast (default) or the step-by-step reference")
    proc.add_argument("--filter", choices=("none", "gaussian", "median"), default=None,
                      help="denoising before the threshold (default none)")
    proc.add_argument("--filter-size", type=float, default=None,
                      help="Gaussian sigma in pixels (default 1) or median window (default 3)")
    proc.add_argument("--noise-sigma", type=float, default=None,
                      help="noise of frame - baseline per pixel, grey levels (default 0.5)")
    proc.add_argument("--k", type=float, default=None,
                      help="threshold in noise sigmas (default 3)")
    proc.add_argument("--bits", type=int_at_least(1, "a bit depth (1 to 16)"), default=None, metavar="N",
                      help="bit depth of the frames' grey levels, e.g. 12 for 12-bit data in 16-bit "
                           "files; needed for 16-bit files with a calibration made for 8-bit frames "
                           "(16-bit frames of 8-bit ones are read as frame / 257, other depths are "
                           "refused). Default: the calibration's, else not checked")
    proc.add_argument("--calibration", type=Path, default=None, metavar="CAL.json",
                      help="also estimate forces with this calibration (adds fx, fy, fz, fx_global, "
                           "fy_global, fz_global, clamped columns and the per-frame table); it "
                           "fixes the sensor, camera and pipeline options. 'default' uses the "
                           "shipped calibration, transferred to a --setup's sensor and camera (their "
                           "element gains folded in); a calibration file for another sensor or camera "
                           "is refused")
    proc.add_argument("--plot", type=Path, default=None, metavar="PLOT.png",
                      help="with --calibration: save a force-field plot of the last frame")
    proc.add_argument("--stderr", action="store_true",
                      help="with --calibration: also write each force's standard error (fx_se, fy_se, fz_se, "
                           "N): the calibration's own model error (measured on validation frames where its "
                           "file has it: calibrate fit --validation; that holds those frames' noise too), plus "
                           "each frame's shot and read noise propagated through the calibration when "
                           "--dn-per-electron is given")
    proc.add_argument("--dn-per-electron", type=float, default=None, metavar="G",
                      help="with --stderr: the camera's conversion gain (grey levels per electron; "
                           "optitact.pipeline.uncertainty.PixelNoise.estimate measures it from a no-load and a "
                           "pressed stack; 0.0128 for the synthetic 8-bit CCD)")
    proc.add_argument("--noise", type=Path, default=None, metavar="NOISE.json",
                      help="with --stderr, instead of --dn-per-electron: the camera's measured noise model "
                           "(conversion gain, the variance of lit pixels and how the noise grows with the "
                           "signal), as optitact calibrate noise writes it; the dark noise is the pipeline's "
                           "own, measured on the baseline it subtracts")
    proc.add_argument("--scheduler", default=None, metavar="ADDRESS",
                      help="process the files on a Dask distributed cluster, one task per file "
                           "(scheduler address); the baseline comes from --baseline or the first "
                           "frames, and the CSV is the same as a local run's")
    proc.add_argument("--batch", type=positive_int, default=32,
                      help="frames processed together (default 32)")
    live = proc.add_argument_group(
        "live streams and recordings", "instead of FRAMES, read an OpenCV capture (cv2.VideoCapture) and "
                        "write the rows as they come: to READINGS.partial.csv, flushed after every frame, "
                        "renamed to READINGS.csv when the stream stops cleanly (its end, --max-frames, "
                        "--seconds, Ctrl-C); colour frames are converted to grey (OpenCV's BGR2GRAY). A "
                        "recording made with --record (FRAMES = one RUN.mcap) is replayed the same way, frame "
                        "by frame with its recorded capture times and its baseline, into READINGS.csv or "
                        ".parquet")
    live.add_argument("--camera", default=None, metavar="INDEX|URL",
                      help="a camera's device index (0, 1, ...), a GStreamer pipeline, an RTSP/HTTP URL or a "
                           "video file")
    live.add_argument("--policy", choices=POLICIES, default=None,
                      help="all: process every frame; newest: when processing falls behind, take the newest "
                           "frame and count the skipped ones as dropped (default: all for a video file, newest "
                           "for a device or URL)")
    live.add_argument("--view", nargs="?", const="auto", default=None, metavar="native|web|VIEW.rrd",
                      help="show the stream in Rerun (the live extra): the frame with the element regions "
                           "and shear arrows, the dome in 3-D with a force arrow per element and its 90%% "
                           "interval, "
                           "the resultant and chosen elements over time, frames processed/dropped and latency. "
                           "native: spawn Rerun's viewer (needs a display); web: serve Rerun's web viewer on "
                           "localhost (its address is printed); VIEW.rrd: write the viewer's log to a file "
                           "(open it with: rerun VIEW.rrd). Default: native with a display, else web. Also "
                           "plays a recording (optitact process RUN.mcap --view)")
    live.add_argument("--record", type=Path, default=None, metavar="RUN.mcap",
                      help="also record the stream as MCAP (the record extra, part of live): each frame, the "
                           "per-element "
                           "readings, forces, standard errors and contact flags, the resultant as a ROS 2 "
                           "geometry_msgs/msg/WrenchStamped and the stream's state, stamped with the capture "
                           "time; ros2 bag, Foxglove and Rerun open it, and optitact process RUN.mcap "
                           "re-processes its frames (e.g. with a better --calibration)")
    live.add_argument("--frames", choices=("lossless", "lossy", "none"), default="lossless",
                      dest="record_frames",
                      help="with --record: store the frames losslessly (default: raw images in "
                           "Zstandard-compressed chunks), as JPEG (lossy: a tenth of the size or less, but "
                           "re-processed forces differ) or not at all (forces only; cannot be re-processed)")
    live.add_argument("--drift", choices=("track", "off"), default="track",
                      help="track: follow slow drift of the rim light, the black level and a sub-pixel creep "
                           "of the camera against the dome while elements are unloaded, never absorbing a "
                           "press; both tables end with the tracked drift_gain, drift_offset, drift_shift_x, "
                           "drift_shift_y and drift_flag (1, with a warning, where the change is beyond what "
                           "tracking follows) (default). A longer baseline (--baseline-frames 60, unloaded) "
                           "lets it follow the light finer. off: keep the first baseline")
    live.add_argument("--max-frames", type=positive_int, default=None, metavar="N",
                      help="stop after N frames (baseline frames included)")
    live.add_argument("--seconds", type=float, default=None, metavar="S",
                      help="stop after S seconds")

    proc.set_defaults(run=run_process)


def _load_baseline(path: Path) -> np.ndarray:
    from optitact.io.frames import expand_sources, iter_frames

    return np.stack([f for _, f in iter_frames(expand_sources([path]))])


def _check_out(path: Path | None, option: str) -> None:
    """An output file's name, checked before any work: not a folder, in a folder that exists."""
    if path is None:
        return
    if path.is_dir():
        raise InputError(f"{option} {path} is a folder; expected the name of a file to write in it "
                         f"(e.g. {path / ('readings.csv' if option == '--out' else 'plot.png')})")
    if not path.parent.is_dir():
        raise InputError(f"{option} {path}: the folder {path.parent} does not exist (create it first)")


def _check_not_inputs(args, files) -> None:
    """Refuse an output (``--out``, its per-frame and partial tables, ``--plot``) that is an input file."""
    from optitact.io.frames import expand_sources
    from optitact.io.tables import refuse_overwriting_inputs, table_files

    outputs = {f"--out's {k}" if k != "table" else "--out": v
               for k, v in table_files(args.out, forces=args.calibration is not None).items()}
    if args.plot is not None:
        outputs["--plot"] = args.plot
    inputs = list(files)
    for given in (args.setup, args.noise, args.calibration, args.camera):
        if given is not None:
            inputs.append(Path(given))
    if args.baseline is not None:
        inputs += expand_sources([args.baseline]) if args.baseline.is_dir() else [args.baseline]
    refuse_overwriting_inputs(outputs, inputs)


def _given(args) -> dict:
    """The pipeline options given on the command line."""
    given = {k: v for k, v in (("filter", args.filter), ("filter_size", args.filter_size),
                                 ("noise_sigma", args.noise_sigma), ("k", args.k)) if v is not None}
    if args.filter == "median" and args.filter_size is not None:  # a window: an integer number of pixels
        if not float(args.filter_size).is_integer():
            raise InputError(f"filter_size (--filter-size) of a median must be an odd integer window, "
                             f"got {args.filter_size:g}")
        given["filter_size"] = int(args.filter_size)
    return given


def _calibration(args, given: dict, setup):
    """The ``--calibration`` (None without one), checked against ``--setup`` and the options.

    The shipped ``default`` calibration is transferred to a ``--setup``'s sensor and camera
    (:meth:`Calibration.transferred`); a calibration file made for another sensor or camera is refused.
    """
    if args.calibration is None:
        if args.plot is not None:
            raise InputError("--plot needs --calibration (it plots estimated forces)")
        return None
    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import default_calibration

    shipped = str(args.calibration) == "default"
    cal = default_calibration() if shipped else Calibration.load(args.calibration)
    if given:
        raise InputError(f"the calibration fixes the pipeline options "
                         f"({cal.pipeline_options}); drop {', '.join(sorted(given))}")
    return calibration_on_setup(cal, setup, shipped=shipped, setup_path=args.setup)


def _pipeline(args, given: dict, cal, setup, shape):
    """The pipeline of the options, for frames of ``shape`` (H, W) (used without --setup and calibration)."""
    from optitact.pipeline.frame_pipeline import Pipeline

    if cal is not None:
        return cal.pipeline(method=args.method, bits=args.bits)
    sensor, camera = setup if setup is not None else (
        DomeSensor.default(), FisheyeCamera(width=shape[1], height=shape[0], fov_deg=args.fov, z=args.camera_z))
    _check_filter(given, camera.shape)
    return Pipeline(sensor, camera, method=args.method, bits=args.bits, **given)


def _check_options(args) -> None:
    """The options that need no frame, checked before any is read: numbers in range, extras installed."""
    import math

    if args.filter_size is not None and not (math.isfinite(args.filter_size) and args.filter_size > 0):
        raise InputError(f"--filter-size must be a finite number of pixels > 0, got {args.filter_size:g}")
    if args.filter_size is not None and args.filter in (None, "none"):
        raise InputError(f"--filter-size {args.filter_size:g} sizes a filter: add --filter gaussian (sigma, "
                         f"px) or --filter median (window, px); without one it would be ignored")
    if args.stderr and args.calibration is None:
        raise InputError("--stderr gives the forces' standard errors: it needs --calibration")
    if args.noise is not None and args.stderr:
        from optitact.pipeline.uncertainty import PixelNoise

        PixelNoise.load(args.noise)  # a bad noise file is named before any frame is read
    if args.dn_per_electron is not None:
        from optitact.pipeline.uncertainty import PixelNoise

        try:
            PixelNoise(args.dn_per_electron)
        except InputError as exc:
            raise InputError(f"--dn-per-electron: {exc}") from None
    if args.plot is not None:
        from optitact._optional import require

        require("matplotlib.figure", purpose="--plot")


def _check_filter(given: dict, shape: tuple[int, int]) -> None:
    """``--filter-size``: the filter's window must fit in frames of ``shape`` (H, W)."""
    import math

    from optitact.pipeline.imageops import filter_radius

    method, size = given.get("filter"), given.get("filter_size")
    if method not in ("gaussian", "median") or size is None:
        return
    side = min(shape)
    if method == "median":
        window = size
    else:  # 3 sigma on each side; a sigma wider than the frame is refused before its kernel is made
        window = 2 * filter_radius(method, size) + 1 if size <= side else size
    if window > side:
        frames = f"the {shape[1]}x{shape[0]} frames' shorter side ({side} px)"
        if method == "median":
            raise InputError(f"--filter-size {size}: a median window of {size} px is wider than {frames}; "
                             f"the filter must fit in the frame (3 or 5 px smooth pixel noise)")
        most = math.floor((side - 1) // 2 / 3 * 100) / 100
        raise InputError(f"--filter-size {size:g}: a gaussian of sigma {size:g} px reads 3 sigma on each side, "
                         f"wider than {frames}; the filter must fit in the frame (sigma at most {most:g} px "
                         f"here; about 1 px smooths pixel noise)")


def _baseline_note(args, baseline) -> tuple[int, str]:
    n_base = 0 if baseline is not None else args.baseline_frames
    return n_base, (f"baseline {args.baseline}" if baseline is not None else
                    f"baseline = mean of the first {n_base} frame(s)" if n_base else "no baseline")


def _noise(args, cal):
    """What ``--stderr``/``--dn-per-electron``/``--noise`` ask for: None, ``"model"`` or a PixelNoise."""
    for given, option in ((args.dn_per_electron, "--dn-per-electron"), (args.noise, "--noise")):
        if given is not None and not args.stderr:
            raise InputError(f"{option} is for --stderr")
    if args.dn_per_electron is not None and args.noise is not None:
        raise InputError("give the camera's noise as --dn-per-electron or as --noise, not both")
    if not args.stderr:
        return None
    if cal is None:
        raise InputError("--stderr gives the forces' standard errors: it needs --calibration")
    if args.dn_per_electron is None and args.noise is None:
        print("optitact: --stderr without --dn-per-electron or --noise: the calibration's model error only "
              "(give the camera's noise to add each frame's)", file=sys.stderr)
        return "model"
    from optitact.pipeline.uncertainty import PixelNoise

    if args.noise is None:
        return PixelNoise(args.dn_per_electron)
    # the dark part is the pipeline's own noise of frame - baseline, measured on the baseline it subtracts
    # (one frame: twice the variance of a frame; the file's is that of a frame minus a long stack's mean)
    return replace(PixelNoise.load(args.noise), read_sigma=None)


def run_process(args) -> int:
    """``optitact process``: build the pipeline (and calibration) from the options, then process_files."""
    import cv2

    from optitact.io.frames import expand_sources, iter_frames, read_ahead, read_ahead_depth

    # OpenCV's worker threads would busy-wait between frames for a colour conversion that takes
    # a tenth of a millisecond; video decoding keeps its own (FFmpeg's) threads
    cv2.setNumThreads(1)
    _check_out(args.out, "--out")
    _check_out(args.plot, "--plot")
    _check_options(args)
    from optitact.live.stream import is_recording_source

    replay = any(is_recording_source(f) for f in args.frames or [])
    if args.camera is not None or replay:
        if args.stderr or args.dn_per_electron is not None or args.noise is not None:
            raise InputError("--stderr, --dn-per-electron and --noise work on frame files; a --camera stream "
                             "or a replayed recording writes forces without standard errors (a --record "
                             "recording holds the calibration's)")
        return _run_live(args)
    if (args.policy is not None or args.view is not None or args.max_frames is not None
            or args.seconds is not None or args.record is not None):
        raise InputError("--policy, --view, --record, --max-frames and --seconds are options of a --camera "
                         "stream or a replayed recording (RUN.mcap)")
    if not args.frames:
        raise InputError("no frames given: pass image files, a folder, .npy stacks or a video, or "
                         "--camera INDEX|URL for a live stream")
    files = expand_sources(args.frames)
    pairs = iter_frames(files)
    first = next(pairs, None)
    if first is None:
        raise InputError("the frames hold no frame")
    if args.scheduler is not None:  # the cluster reads the files
        pairs.close()
        frames = None
    else:  # the next frames decode while the calibration and the pipeline are made
        frames = read_ahead(_prepend(first, pairs), depth=read_ahead_depth(first[1].shape[:2], args.batch))
    with closing(frames) if frames is not None else nullcontext():
        return _process_files(args, files, first, frames)


def _prepend(first, rest):
    """``first``, then the items of the generator ``rest``; closing this closes ``rest``."""
    try:
        yield first
        yield from rest
    finally:
        rest.close()


def _process_files(args, files, first, frames) -> int:
    """``optitact process`` on files: the pipeline (and calibration), then process_files on ``frames``."""
    from optitact.pipeline.batch import process_files
    from optitact.io.tables import per_frame_path

    setup = None if args.setup is None else read_setup(args.setup)
    given = _given(args)
    baseline = None if args.baseline is None else _load_baseline(args.baseline)
    cal = _calibration(args, given, setup)
    _check_not_inputs(args, files)
    check_frame_size(args, cal, first[0], first[1].shape)
    if baseline is not None:
        check_frame_size(args, cal, str(args.baseline), baseline.shape[1:])
    pipe = _pipeline(args, given, cal, setup, first[1].shape[:2])
    camera = pipe.camera
    n_base, how = _baseline_note(args, baseline)
    print(f"optitact: processing {camera.width}x{camera.height} frames, {how}", file=sys.stderr)
    done = process_files(files, pipeline=pipe, calibration=cal, baseline=baseline, baseline_frames=n_base,
                         out=args.out, batch=args.batch, scheduler=args.scheduler, progress=True,
                         noise=_noise(args, cal), frames=frames)
    if args.plot is not None:
        field = cal.apply(done.last_readings)
        field.save_plot(args.plot, done.last_frame, camera, title="estimated forces (last frame)")
        print(f"optitact: wrote the force-field plot of the last frame to {args.plot}", file=sys.stderr)
    where = "on the cluster" if args.scheduler is not None else "here"
    also = f" and per-frame resultants to {per_frame_path(args.out)}" if cal else ""
    print(f"optitact: wrote {'forces' if cal else 'readings'} of {done.n_frames} frames to {args.out}{also} "
          f"({done.n_frames / max(done.seconds, 1e-9):.0f} frames/s {where}, including reading)",
          file=sys.stderr)
    return 0


# ----------------------------------------------------------------------------- live streams
def view_target(given: str) -> str:
    """The ``--view`` target: ``auto`` becomes ``native`` where a display is, else ``web``."""
    import os

    if given != "auto":
        return given
    if sys.platform.startswith("linux") and not any(os.environ.get(v) for v in ("DISPLAY", "WAYLAND_DISPLAY")):
        return "web"
    return "native"


class _CtrlC:
    """The first Ctrl-C asks the loop to stop after the current frame; a second one interrupts at once."""

    def __init__(self) -> None:
        self.requested = False
        self._old = None

    def _handle(self, signum, frame) -> None:
        import signal

        self.requested = True
        signal.signal(signal.SIGINT, signal.default_int_handler)
        print("optitact: Ctrl-C: stopping after this frame (Ctrl-C again stops at once)", file=sys.stderr)

    def __enter__(self) -> _CtrlC:
        import signal
        import threading

        if threading.current_thread() is threading.main_thread():
            self._old = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc) -> None:
        import signal

        if self._old is not None:
            signal.signal(signal.SIGINT, self._old)


def _run_live(args) -> int:
    """``optitact process --camera`` (or ``RUN.mcap``): stream, write the rows as they come, print a summary."""
    import time

    from optitact.io.tables import partial_path, per_frame_path
    from optitact.live.stream import LiveWriter, frame_policy, source_label, stream

    recording = None
    if args.camera is None:  # a recording replayed
        if len(args.frames) != 1:
            raise InputError(f"a recording (RUN.mcap) is replayed alone: give one, without other frames; got "
                             f"{len(args.frames)} inputs")
        source = args.frames[0]
        if args.policy is not None or args.seconds is not None:
            raise InputError("--policy and --seconds are for a live --camera stream; a recording is replayed "
                             "frame by frame (--max-frames stops early)")
        from optitact.live.record import read_recording

        recording = read_recording(source)
        if recording.frames == "none":
            raise InputError(f"{source}: the recording holds no frames (made with --frames none), so it cannot "
                             f"be re-processed; its forces are in its /optitact/elements topic")
    else:
        if args.frames:
            raise InputError("give FRAMES or --camera, not both")
        source = args.camera
    if args.scheduler is not None:
        raise InputError("--scheduler processes files on a cluster; a --camera stream is processed here")
    if args.seconds is not None and not args.seconds > 0:
        raise InputError(f"--seconds must be > 0, got {args.seconds:g}")
    if args.record is not None:
        _check_out(args.record, "--record")
        if recording is not None and Path(args.record).resolve() == Path(source).resolve():
            raise InputError(f"--record {args.record} is the recording being replayed; name another file")
    from optitact._optional import require

    if args.view is not None:
        require("rerun", purpose="--view (the live view)")
    if args.record is not None:
        for module in ("mcap", "mcap_ros2.writer"):
            require(module, purpose="--record (MCAP recordings)")
    setup = None if args.setup is None else read_setup(args.setup)
    given = _given(args)
    baseline = None if args.baseline is None else _load_baseline(args.baseline)
    if baseline is None and recording is not None and recording.baseline is not None:
        baseline = recording.baseline  # the baseline the stream was processed with
        print("optitact: the recording's own baseline (given to the live stream with --baseline)",
              file=sys.stderr)
    cal = _calibration(args, given, setup)
    _check_not_inputs(args, [Path(source)] if recording is not None else [])
    if baseline is not None:
        check_frame_size(args, cal, str(args.baseline or source), baseline.shape[-2:])
    built: list = []  # the pipeline in use (for the view and the recorder)
    if cal is not None or setup is not None:
        pipe = _pipeline(args, given, cal, setup, None)
        built.append(pipe)
    else:  # a camera model of the first frame's size
        def pipe(shape):
            built.append(_pipeline(args, given, None, None, shape))
            return built[-1]
    n_base, how = _baseline_note(args, baseline)
    track = None
    if args.drift == "track":
        from optitact.pipeline.drift import DriftTracker

        track = DriftTracker
    frames = stream(source, calibration=cal, pipeline=pipe, baseline=baseline, baseline_frames=n_base,
                    policy=args.policy, max_frames=args.max_frames, seconds=args.seconds, track=track)
    label = source_label(source)
    if recording is not None:
        which = f"a recording of {recording.n_frames} frames ({recording.frames}), frame by frame"
    else:
        which = ("every frame" if frame_policy(source, args.policy) == "all"
                 else "the newest frame, dropping the others when behind")
    rows = (f"rows go to {partial_path(args.out)} as they come, renamed to {args.out} at the end"
            if args.out.suffix.lower() != ".parquet" else f"rows go to {args.out} when the stream stops")
    print(f"optitact: reading {label} ({which}), {how}, drift {'tracked' if track else 'not tracked'}; {rows}; "
          f"Ctrl-C stops", file=sys.stderr)
    reason, last, n, n_b, flagged = "the stream ended", None, 0, 0, False
    view = recorder = None
    views = contextlib.ExitStack()  # the view outlives the tables: a web viewer keeps serving after the end
    try:
        t0 = time.perf_counter()
        with contextlib.ExitStack() as stack:
            out = stack.enter_context(LiveWriter(args.out, calibration=cal, drift=track is not None))
            ctrl_c = stack.enter_context(_CtrlC())
            opened = bool(built)  # a known pipeline: the viewer and recorder start before the first frame
            if opened:
                view, recorder = _outputs(args, stack, views, built[-1], cal, label, baseline)
            try:
                for lf in frames:
                    if not opened:  # a camera model of the first frame's size: known now
                        view, recorder = _outputs(args, stack, views, built[-1], cal, label, baseline)
                        opened = True
                    out.write(lf)
                    if recorder is not None:
                        recorder.write(lf)
                    if view is not None:
                        view.log(lf, latency_s=lf.latency)
                    last, n, n_b = lf, n + 1, n_b + lf.baseline
                    if lf.drift is not None and lf.drift.flag and not flagged:
                        print(f"optitact: warning: drift beyond what tracking follows at {lf.source} "
                              f"({lf.drift.reason}); take a new baseline with the sensor unloaded",
                              file=sys.stderr)
                    flagged = bool(lf.drift is not None and lf.drift.flag)
                    if ctrl_c.requested:
                        reason = "stopped by Ctrl-C"
                        break
            except KeyboardInterrupt:
                reason = "stopped by Ctrl-C"
            finally:
                frames.close()
            seconds = time.perf_counter() - t0
            if n == 0 and reason == "the stream ended":
                raise InputError(f"{label}: the stream gave no frame")
        if reason == "the stream ended" and args.max_frames is not None and n >= args.max_frames:
            reason = f"--max-frames {args.max_frames} reached"
        elif reason == "the stream ended" and args.seconds is not None and seconds >= args.seconds:
            reason = f"--seconds {args.seconds:g} reached"
        if args.plot is not None and last is not None:
            last.forces.save_plot(args.plot, last.frame, built[-1].camera,
                                  title=f"estimated forces (last frame, {last.source})")
            print(f"optitact: wrote the force-field plot of the last frame to {args.plot}", file=sys.stderr)
        dropped = last.dropped if last is not None else 0
        also = f" and per-frame resultants to {per_frame_path(args.out)}" if cal else ""
        what = "forces" if cal else "readings"
        print(f"optitact: {reason}: {n} frames processed ({n_b} of them baseline), {dropped} dropped, "
              f"{n / max(seconds, 1e-9):.1f} frames/s; wrote {what} of {n} frames to {args.out}{also}",
              file=sys.stderr)
        if recorder is not None:
            slow = recorder.waited > 0.05
            waited = f"; the stream waited {recorder.waited:.1f} s for the disk" if slow else ""
            print(f"optitact: recorded {n} frames ({args.record_frames} frames) to {args.record}{waited}",
                  file=sys.stderr)
        if view is not None and getattr(view, "path", None) is not None:
            print(f"optitact: wrote the view to {view.path} (open it with: rerun {view.path})", file=sys.stderr)
        if view is not None and getattr(view, "url", None) and reason != "stopped by Ctrl-C":
            # the web viewer's server lives in this process: keep the session there until the user is done
            print(f"optitact: --view: the web viewer keeps the session at {view.url}; Ctrl-C quits",
                  file=sys.stderr)
            try:
                while True:
                    time.sleep(0.5)
            except KeyboardInterrupt:
                pass
    finally:
        views.close()
    return 0


def _outputs(args, stack, views, pipe, cal, label: str, baseline):
    """The ``--record`` and ``--view`` of a stream, closed with ``stack`` and ``views``."""
    view = recorder = None
    if args.record is not None:
        from optitact.live.record import Recorder

        if args.record_frames == "lossy":
            print("optitact: --frames lossy: JPEG changes G and the centroids, so forces re-processed from "
                  "this recording will differ from these (--frames lossless keeps them)", file=sys.stderr)
        recorder = stack.enter_context(Recorder(args.record, frames=args.record_frames, source=label,
                                                calibration=cal, sensor=pipe.sensor, camera=pipe.camera,
                                                options=pipe.options(), baseline=baseline))
    if args.view is not None:
        from optitact.live.viewer import open_view

        target = view_target(args.view)
        view = views.enter_context(open_view(target, sensor=pipe.sensor, camera=pipe.camera, calibration=cal,
                                             name="optitact"))
        if getattr(view, "url", None):
            print(f"optitact: --view: the web viewer is at {view.url}", file=sys.stderr)
    return view, recorder
