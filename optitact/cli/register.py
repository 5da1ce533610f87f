"""``optitact register``: fit the camera to spots of pressed elements, write a setup file (``register``)."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

from optitact.errors import InputError

from ._args import out_file

__all__ = ["add_parsers"]


def add_parsers(sub) -> None:
    """Add ``register`` to the subcommands."""
    reg = sub.add_parser(
        "register", help="fit the camera's pose (and intrinsics) to frames of pressed elements -> setup.json",
        description="Register a real sensor: from a no-load frame and a few frames in which elements are "
                    "pressed straight down (5 to 8 per frame, spread over the rings), detect the bright spots, "
                    "match them to elements and fit the camera's pose (optionally its intrinsics and the "
                    "dome's radius) by robust least squares. Writes a setup file (sensor, camera and a "
                    "registration report: reprojection RMS in pixels, standard errors, unseen elements) "
                    "that optitact process --setup reads, and prints the report on stderr. Refuses, naming "
                    "what to add, when the frames cannot pin the camera down.")
    reg.add_argument("noload", type=Path, metavar="NOLOAD",
                     help="a frame of the unloaded sensor (image or .npy; a .npy stack is averaged)")
    reg.add_argument("pressed", type=Path, nargs="+", metavar="PRESSED",
                     help="frames with elements pressed (images, folders of them, .npy stacks)")
    reg.add_argument("--camera-intrinsics", type=Path, default=None, metavar="CAM.yml",
                     help="OpenCV calibration of the camera (cv2.FileStorage YAML/XML from "
                          "cv2.calibrateCamera or cv2.fisheye.calibrate): its K and D; default: the default "
                          "equidistant camera of the frames' size (fisheye model only)")
    reg.add_argument("--model", choices=("fisheye", "pinhole"), default=None,
                     help="the camera model of the intrinsics (default: what the file says, else "
                          "pinhole; without --camera-intrinsics: fisheye)")
    reg.add_argument("--fit-intrinsics", action="store_true",
                     help="also fit fx, fy, cx, cy (the distortion stays as given); focal length and the "
                          "camera's height trade off, so expect larger standard errors")
    reg.add_argument("--fit-dome", action="store_true",
                     help="also fit the dome's outer radius (shell thickness fixed)")
    reg.add_argument("--fit-offsets", action="store_true",
                     help="also fit each seen element's position offset (prior 0.2 mm); the setup's sensor "
                          "carries them")
    reg.add_argument("--fit-gains", action=argparse.BooleanOptionalAction, default=None,
                     help="estimate each pressed element's relative brightness (gain) from the pressed "
                          "frames, which must be presses of about equal force (one gauge setting or weight). "
                          "Default: on, skipped with a note when no press can be read against the shipped "
                          "calibration; --fit-gains makes that an error, --no-fit-gains skips it")
    reg.add_argument("--press-force", type=float, default=None, metavar="N",
                     help="the force of every press (N), when known: absolute gains instead of gains "
                          "normalised to a median of 1")
    reg.add_argument("--k", type=float, default=5.0,
                     help="spot threshold in robust noise sigmas over the no-load frame (default 5)")
    reg.add_argument("--out", type=out_file(".json"), default=Path("setup.json"), metavar="SETUP.json",
                     help="the setup file to write (default ./setup.json)")
    reg.set_defaults(run=run_register)


def _read(paths: list[Path]) -> list[np.ndarray]:
    from optitact.frames import expand_sources, iter_frames

    return [f for _, f in iter_frames(expand_sources(paths))]


def run_register(args) -> int:
    """``optitact register``: read the frames and the intrinsics, register, write the setup file."""
    from optitact.register import register

    noload = _read([args.noload])
    if not noload:
        raise InputError(f"{args.noload}: holds no frame")
    base = np.mean(np.stack(noload).astype(np.float64), axis=0)
    pressed = _read(args.pressed)
    h, w = base.shape
    if args.camera_intrinsics is not None:
        from optitact.opencv_files import read_opencv_calibration

        camera = read_opencv_calibration(args.camera_intrinsics, model=args.model)
        if camera.shape != (h, w):
            raise InputError(f"{args.camera_intrinsics}: the intrinsics are for {camera.width}x{camera.height} "
                             f"frames, but {args.noload} is {w}x{h}; calibrate the camera at the frames' size")
    elif args.model == "pinhole":
        raise InputError("--model pinhole needs --camera-intrinsics (a pinhole camera's focal length and "
                         "distortion cannot be guessed)")
    else:
        camera = None
    from optitact.register import GainsError

    if args.press_force is not None and args.fit_gains is False:
        raise InputError("--press-force is the force of the presses the gains come from; drop --no-fit-gains")
    kw = dict(camera=camera, fit_intrinsics=args.fit_intrinsics, fit_dome=args.fit_dome,
              fit_offsets=args.fit_offsets, k=args.k)
    try:
        reg = register(base, pressed, fit_gains=args.fit_gains is not False, press_force=args.press_force, **kw)
    except GainsError as exc:
        if args.fit_gains or args.press_force is not None:
            raise
        print(f"optitact: element gains not estimated ({exc})", file=sys.stderr)
        reg = register(base, pressed, **kw)
    reg.save(args.out)
    c = reg.camera
    pos = ", ".join(f"{v:.3f}" for v in c.position)
    tilt = np.degrees(np.linalg.norm(c.rvec))
    se = reg.std_errors
    print(f"optitact: registered {len(reg.element)} element views in {len(pressed)} frames: reprojection RMS "
          f"{reg.rms_px:.3f} px; camera at ({pos}) mm (+- {max(se['x_mm'], se['y_mm'], se['z_mm']):.3f}), "
          f"rotated {tilt:.3f} deg (+- {np.degrees(max(se['rvec_x'], se['rvec_y'], se['rvec_z'])):.3f}); "
          f"fx {c.fx:.2f}, fy {c.fy:.2f}, cx {c.cx:.2f}, cy {c.cy:.2f} px; "
          f"{len(reg.unseen)} element(s) unseen{': ' + str(list(reg.unseen)) if reg.unseen else ''}",
          file=sys.stderr)
    if reg.gain_force_n is not None:
        seen = sorted(set(int(e) for e in reg.element) - set(reg.gain_unfitted))
        g = np.asarray(reg.sensor.gains)[seen]
        lo, hi = seen[int(np.argmin(g))], seen[int(np.argmax(g))]
        spread = 1.4826 * np.median(np.abs(g - np.median(g))) / np.median(g)
        how = "given" if args.press_force is not None else "the median element's, from the shipped calibration"
        print(f"optitact: element gains of {len(seen)} elements at {reg.gain_force_n:.3g} N ({how}): median "
              f"{np.median(g):.3f}, robust spread {100 * spread:.1f} %, lowest {g.min():.3f} (element {lo}), "
              f"highest {g.max():.3f} (element {hi}); unseen elements keep gain 1"
              + (f"; not measured: {list(reg.gain_unfitted)}" if reg.gain_unfitted else ""), file=sys.stderr)
    print(args.out)
    return 0
