"""``optitact register``: fit the camera to spots of pressed elements, write a setup file (``register``)."""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

from optitact.errors import InputError, OptitactWarning

from optitact.cli._args import out_file

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
                    "that optitact process --setup reads, and prints the report on stderr: every fitted "
                    "parameter with its standard error, the elements with no spot and the spots found but "
                    "rejected (and why), each gain with its standard error. Refuses, naming what to add, when "
                    "the frames cannot pin the camera down; warns when they pin something down only loosely, "
                    "when the RMS is beyond the spots' noise, when the camera model looks wrong, and when the "
                    "gains are not measured meaningfully.")
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
                     help="also fit the dome's outer radius (shell thickness fixed), with a prior of 1 %% "
                          "around the designed radius: the spots hardly tell it from the camera's height")
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
    from optitact.io.frames import expand_sources, iter_frames

    return [f for _, f in iter_frames(expand_sources(paths))]


def _registered(register, *args, **kw):
    """``register(*args, **kw)`` and the warnings it issued (to print after the report)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", OptitactWarning)
        reg = register(*args, **kw)
    return reg, caught


def _pm(value: float, se: float, digits: int) -> str:
    return f"{value:.{digits}f} +- {se:.{digits}f}"


def _report(reg, n_frames: int, press_force) -> list[str]:
    """The registration report: every fitted parameter with its standard error, what was seen and not."""
    c, se = reg.camera, reg.std_errors
    lines = [f"registered {len(reg.element)} element views in {n_frames} frames: reprojection RMS "
             f"{reg.rms_px:.3f} px (the spots' centroid noise explains {reg.centroid_noise_px:.3f} px)"]
    pos = ", ".join(f"{a} {_pm(v, se[a + '_mm'], 3)}" for a, v in zip("xyz", c.position, strict=True))
    rot = ", ".join(f"{a} {_pm(np.degrees(v), np.degrees(se['rvec_' + a]), 3)}"
                    for a, v in zip("xyz", c.rvec, strict=True))
    lines.append(f"camera centre (mm): {pos}; rotation vector (deg): {rot}; tilt "
                 f"{np.degrees(np.linalg.norm(c.rvec)):.3f} deg")
    if "fx" in se:
        lines.append("intrinsics (px, fitted): " + ", ".join(f"{k} {_pm(getattr(c, k), se[k], 2)}"
                                                           for k in ("fx", "fy", "cx", "cy")))
    else:
        lines.append(f"intrinsics (px, as given): fx {c.fx:.2f}, fy {c.fy:.2f}, cx {c.cx:.2f}, cy {c.cy:.2f}")
    if "outer_radius_mm" in se:
        lines.append(f"dome outer radius: {_pm(reg.sensor.outer_radius, se['outer_radius_mm'], 3)} mm")
    offsets = sorted({int(k.split("_")[1]) for k in se if k.startswith("offset_")})
    if offsets:
        lines.append("element offsets (mm, x, y +- larger SE): " + "; ".join(
            f"{e}: {reg.element_offsets[e, 0]:+.3f}, {reg.element_offsets[e, 1]:+.3f} +- "
            f"{max(se[f'offset_{e}_x_mm'], se[f'offset_{e}_y_mm']):.3f}" for e in offsets))
    no_spot = reg.no_spot
    lines.append(f"{len(no_spot)} element(s) with no spot" + (f": {list(no_spot)}" if no_spot else ""))
    if reg.rejected:
        lines.append(f"found but rejected ({len(reg.rejected)}): " + "; ".join(map(_rejection, reg.rejected)))
    if reg.gain_force_n is not None:
        seen = sorted(set(int(e) for e in reg.element) - set(reg.gain_unfitted))
        g = np.asarray(reg.sensor.gains)[seen]
        lo, hi = seen[int(np.argmin(g))], seen[int(np.argmax(g))]
        spread = 1.4826 * np.median(np.abs(g - np.median(g))) / np.median(g)
        how = "given" if press_force is not None else "the median element's, from the shipped calibration"
        each = "; ".join(f"{e}: {_pm(reg.sensor.gains[e], se[f'gain_{e}'], 3)}" for e in seen)
        lines.append(f"element gains of {len(seen)} elements at {reg.gain_force_n:.3g} N ({how}): median "
                     f"{np.median(g):.3f}, robust spread {100 * spread:.1f} %, lowest {g.min():.3f} (element "
                     f"{lo}), highest {g.max():.3f} (element {hi}); unseen elements keep gain 1"
                     + (f"; not measured: {list(reg.gain_unfitted)}" if reg.gain_unfitted else "")
                     + f"; each (+- standard error): {each}")
    return lines


def _rejection(x: dict) -> str:
    where = f"frame {x['frame']}, at ({x['row']:.1f}, {x['col']:.1f}) px"
    if x["reason"] == "outlier":
        return (f"element {x['element']} ({where}: {x['distance_px']:.2f} px from where the fitted camera puts "
                f"it, an outlier of the fit)")
    near = f"near element {x['element']}" if x["element"] is not None else "near no element"
    if x["reason"] == "compact":
        return f"a spot {near} ({where}: too compact for an element's ring, a reflection or a hot pixel?)"
    return (f"a spot cluster {near} ({where}: {x['distance_px']:.1f} px from its predicted centre, outside its "
            f"{x['gate_px']:.1f} px gate)")


def run_register(args) -> int:
    """``optitact register``: read the frames and the intrinsics, register, write the setup file."""
    from optitact.registration.pose import register

    noload = _read([args.noload])
    if not noload:
        raise InputError(f"{args.noload}: holds no frame")
    if len({f.shape for f in noload}) > 1:
        raise InputError(f"{args.noload}: its frames differ in size ({sorted({f.shape for f in noload})}); "
                         f"give no-load frames of one size")
    base = np.stack(noload)  # averaged by register, which checks its kind and bit depth first
    pressed = _read(args.pressed)
    h, w = base.shape[-2:]
    if args.camera_intrinsics is not None:
        from optitact.optics.opencv_files import read_opencv_calibration

        camera = read_opencv_calibration(args.camera_intrinsics, model=args.model)
        if camera.shape != (h, w):
            raise InputError(f"{args.camera_intrinsics}: the intrinsics are for {camera.width}x{camera.height} "
                             f"frames, but {args.noload} is {w}x{h}; calibrate the camera at the frames' size")
    elif args.model == "pinhole":
        raise InputError("--model pinhole needs --camera-intrinsics (a pinhole camera's focal length and "
                         "distortion cannot be guessed)")
    else:
        camera = None
    from optitact.errors import GainsError

    if args.press_force is not None and args.fit_gains is False:
        raise InputError("--press-force is the force of the presses the gains come from; drop --no-fit-gains")
    kw = dict(camera=camera, fit_intrinsics=args.fit_intrinsics, fit_dome=args.fit_dome,
              fit_offsets=args.fit_offsets, k=args.k)
    try:
        reg, caught = _registered(register, base, pressed, fit_gains=args.fit_gains is not False,
                                  press_force=args.press_force, **kw)
    except GainsError as exc:
        if args.fit_gains or args.press_force is not None:
            raise
        print(f"optitact: element gains not estimated ({exc})", file=sys.stderr)
        reg, caught = _registered(register, base, pressed, **kw)
    reg.save(args.out)
    for line in _report(reg, len(pressed), args.press_force):
        print(f"optitact: {line}", file=sys.stderr)
    for w in caught:  # after the report they qualify, one "optitact: warning:" line each
        warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    print(args.out)
    return 0
