"""``optitact process``: camera frames to a readings (or forces) CSV (:func:`optitact.batch.process_files`)."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np

from optitact.camera import FisheyeCamera
from optitact.errors import InputError
from optitact.sensor import DomeSensor

from ._args import int_at_least, positive_int

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
    proc.add_argument("frames", nargs="+", type=Path, metavar="FRAMES",
                      help="image files, folders, .npy stacks or video files")
    proc.add_argument("--out", type=Path, required=True, metavar="READINGS.csv",
                      help="the CSV file to write (its folder must exist; with --calibration also "
                           "READINGS.per_frame.csv)")
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
                           "shipped calibration")
    proc.add_argument("--plot", type=Path, default=None, metavar="PLOT.png",
                      help="with --calibration: save a force-field plot of the last frame")
    proc.add_argument("--scheduler", default=None, metavar="ADDRESS",
                      help="process the files on a Dask distributed cluster, one task per file "
                           "(scheduler address); the baseline comes from --baseline or the first "
                           "frames, and the CSV is the same as a local run's")
    proc.add_argument("--batch", type=positive_int, default=32,
                      help="frames processed together (default 32)")

    proc.set_defaults(run=run_process)


def _setup(path: Path) -> tuple[DomeSensor, FisheyeCamera]:
    """The sensor and camera of a ``--setup`` JSON file."""
    setup = json.loads(path.read_text())
    if not isinstance(setup, dict) or "sensor" not in setup or "camera" not in setup:
        raise InputError(f"{path}: expected a JSON object with 'sensor' and 'camera'")
    return DomeSensor.from_dict(setup["sensor"]), FisheyeCamera.from_dict(setup["camera"])


def _load_baseline(path: Path) -> np.ndarray:
    from optitact.frames import expand_sources, iter_frames

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


def run_process(args) -> int:
    """``optitact process``: build the pipeline (and calibration) from the options, then process_files."""
    from optitact.batch import process_files
    from optitact.frames import expand_sources, iter_frames
    from optitact.io import per_frame_path
    from optitact.pipeline import Pipeline

    _check_out(args.out, "--out")
    _check_out(args.plot, "--plot")
    files = expand_sources(args.frames)
    first = next(iter_frames(files[:1]), None)
    if first is None:
        raise InputError("the frames hold no frame")
    if args.setup is not None:
        sensor, camera = _setup(args.setup)
    else:
        sensor = DomeSensor.default()
        h, w = first[1].shape[:2]
        camera = FisheyeCamera(width=w, height=h, fov_deg=args.fov, z=args.camera_z)
    given = {k: v for k, v in (("filter", args.filter), ("filter_size", args.filter_size),
                                 ("noise_sigma", args.noise_sigma), ("k", args.k)) if v is not None}
    if args.filter == "median" and args.filter_size is not None:  # a window: an integer number of pixels
        if not float(args.filter_size).is_integer():
            raise InputError(f"filter_size (--filter-size) of a median must be an odd integer window, "
                             f"got {args.filter_size:g}")
        given["filter_size"] = int(args.filter_size)
    baseline = None if args.baseline is None else _load_baseline(args.baseline)
    cal = None
    if args.calibration is not None:
        from optitact.calib import Calibration, CalibrationMismatchError, default_calibration

        cal = (default_calibration() if str(args.calibration) == "default"
               else Calibration.load(args.calibration))
        if given:
            raise InputError(f"the calibration fixes the pipeline options "
                             f"({cal.pipeline_options}); drop {', '.join(sorted(given))}")
        cal.check(sensor=sensor if args.setup is not None else None,
                  camera=camera if args.setup is not None else None)
        if first[1].shape[:2] != cal.camera.shape:
            raise CalibrationMismatchError(
                f"{first[0]}: the calibration (fingerprint {cal.fingerprint}) is for "
                f"{cal.camera.width}x{cal.camera.height} frames, got "
                f"{first[1].shape[1]}x{first[1].shape[0]}")
        camera = cal.camera
        pipe = cal.pipeline(method=args.method, bits=args.bits)
    elif args.plot is not None:
        raise InputError("--plot needs --calibration (it plots estimated forces)")
    else:
        pipe = Pipeline(sensor, camera, method=args.method, bits=args.bits, **given)
    n_base = 0 if baseline is not None else args.baseline_frames
    how = (f"baseline {args.baseline}" if baseline is not None else
           f"baseline = mean of the first {n_base} frame(s)" if n_base else "no baseline")
    print(f"optitact: processing {camera.width}x{camera.height} frames, {how}", file=sys.stderr)
    done = process_files(files, pipeline=pipe, calibration=cal, baseline=baseline, baseline_frames=n_base,
                         out=args.out, batch=args.batch, scheduler=args.scheduler, progress=True)
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
