"""Argument types and the parent parsers that the subcommands share."""

from __future__ import annotations

import argparse
import os
from pathlib import Path

from optitact.errors import InputError


def int_at_least(minimum: int, what: str):
    """An argparse type: an integer >= ``minimum``."""

    def parse(text: str) -> int:
        try:
            v = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if v < minimum:
            raise argparse.ArgumentTypeError(f"expected {what}, got {v}")
        return v

    return parse


positive_int = int_at_least(1, "a positive integer")
seed_int = int_at_least(0, "a non-negative integer")


def size(text: str) -> tuple[int, int]:
    """``"640x480"`` -> ``(640, 480)``; InputError otherwise (a one-line CLI error)."""
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise InputError(f"--size must look like 640x480 (WIDTHxHEIGHT), got {text!r}") from None
    return w, h


def _writable_place(path: Path) -> str | None:
    """Why ``path`` cannot be written as a new or replaced file or folder, or None if it can.

    A missing parent folder is fine when it can be created (the writers create
    it): the nearest existing ancestor must be a folder this user may write in.
    """
    parent = path.parent
    while not parent.exists():
        if parent == parent.parent:  # pragma: no cover - a missing filesystem root
            return f"no folder of {path} exists"
        parent = parent.parent
    if not parent.is_dir():
        return f"{parent} is a file, not a folder"
    if not os.access(parent, os.W_OK | os.X_OK):
        return f"folder {parent} is not writable"
    return None


def out_file(*suffixes: str):
    """An argparse type for an output file: one of ``suffixes``, not a folder, in a writable place.

    Checked when the command line is parsed, before any long work; a missing
    parent folder is created by the writer.

    Examples
    --------
    >>> out_file(".png", ".npy")("frame.jpg")
    Traceback (most recent call last):
    ...
    argparse.ArgumentTypeError: expected a file name ending in .png or .npy, got 'frame.jpg'
    """
    accepted = " or ".join(suffixes)

    def parse(text: str) -> Path:
        path = Path(text)
        if path.suffix.lower() not in suffixes:
            raise argparse.ArgumentTypeError(f"expected a file name ending in {accepted}, got {text!r}")
        if path.is_dir():
            raise argparse.ArgumentTypeError(f"{text!r} is a folder; expected a file name ending in {accepted}")
        why = _writable_place(path)
        if why is not None:
            raise argparse.ArgumentTypeError(f"cannot write {text!r}: {why}")
        return path

    return parse


def out_folder(text: str) -> Path:
    """An argparse type for an output folder: an existing folder, or one that can be created."""
    path = Path(text)
    if path.exists() and not path.is_dir():
        raise argparse.ArgumentTypeError(f"{text!r} exists and is not a folder; name a folder (it is "
                                         f"created if missing)")
    why = _writable_place(path) if not path.exists() else (
        None if os.access(path, os.W_OK | os.X_OK) else f"folder {path} is not writable")
    if why is not None:
        raise argparse.ArgumentTypeError(f"cannot write into {text!r}: {why}")
    return path


def _parent() -> argparse.ArgumentParser:
    return argparse.ArgumentParser(add_help=False)


def seed_parent(what: str = "seed") -> argparse.ArgumentParser:
    """``--seed`` (default 0)."""
    p = _parent()
    p.add_argument("--seed", type=seed_int, default=0, help=f"{what} (default 0)")
    return p


def variant_parent() -> argparse.ArgumentParser:
    """``--variant``: the Mitsuba variant."""
    p = _parent()
    p.add_argument("--variant", default=None,
                   help="Mitsuba variant (default: fastest that works: cuda_ad_rgb > llvm_ad_rgb > scalar_rgb)")
    return p


def image_size_parent() -> argparse.ArgumentParser:
    """``--width`` and ``--height`` of the camera image."""
    p = _parent()
    p.add_argument("--width", type=positive_int, default=640, help="image width (default 640)")
    p.add_argument("--height", type=positive_int, default=480, help="image height (default 480)")
    return p


def spp_parent(default: int = 64, what: str = "samples per pixel") -> argparse.ArgumentParser:
    """``--spp``."""
    p = _parent()
    p.add_argument("--spp", type=positive_int, default=default, help=f"{what} (default {default})")
    return p


def render_parents(*, spp: int = 64) -> list[argparse.ArgumentParser]:
    """What rendering a frame takes: spp, seed, ADC bits, variant and image size."""
    bits = _parent()
    bits.add_argument("--bits", type=int, choices=(8, 10, 12, 16), default=8,
                      help="ADC bit depth of the frame (default 8; >8 bits write 16-bit PNG)")
    return [spp_parent(spp), seed_parent("seed of the render and the camera noise"), bits, variant_parent(),
            image_size_parent()]


def plot_parent(help: str) -> argparse.ArgumentParser:
    """``--plot PLOT.png``."""
    p = _parent()
    p.add_argument("--plot", type=out_file(".png"), default=None, metavar="PLOT.png", help=help)
    return p


def pattern_choices() -> tuple[str, ...]:
    """Load patterns of a calibration design (:data:`optitact.calib.patterns.PATTERNS`; not imported here)."""
    return ("independent", "uniform", "single", "clustered", "checkerboard", "shear", "blend")


def render_mode_choices() -> tuple[str, ...]:
    """How calibration frames can be rendered."""
    return ("two_stage", "pixels", "full")


def calibration_on_setup(cal, setup, *, shipped: bool, setup_path):
    """``cal`` for a ``--setup``'s sensor and camera: the shipped one transferred, any other checked.

    The shipped calibration is made for the package's own sensor and camera; on a setup's
    (registered) sensor it is :meth:`Calibration.transferred` (and the command says so). A
    calibration file is refused when it was made for another sensor or camera
    (``CalibrationMismatchError``, naming what differs). Without a setup, ``cal`` as it is.
    """
    import sys

    if setup is None:
        return cal
    sensor, camera = setup
    if shipped and (cal.sensor != sensor or cal.camera != camera):
        cal = cal.transferred(sensor, camera)
        print(f"optitact: the shipped calibration is transferred to the setup's sensor and camera "
              f"({setup_path}: fingerprint {cal.fingerprint}, element gains folded into G)", file=sys.stderr)
    cal.check(sensor=sensor, camera=camera)
    return cal


def check_frame_size(args, cal, source: str, shape: tuple[int, ...]) -> None:
    """Frames (or a ``--baseline``) of ``shape`` (H, W, ...) must be the calibration's; else say what to do.

    ``args`` has the command's ``calibration`` and ``setup`` (``process``, ``calibrate test``).
    """
    if cal is None or tuple(shape[:2]) == cal.camera.shape:
        return
    from optitact.calib.document import CalibrationMismatchError

    got, made = f"{source}: the frames are {shape[1]}x{shape[0]}", f"{cal.camera.width}x{cal.camera.height}"
    if args.setup is not None:
        raise CalibrationMismatchError(
            f"{got}, but the setup's camera ({args.setup}) makes {made} frames: give frames of that camera, "
            f"or register the camera that took these (optitact register ... --out setup.json)")
    if str(args.calibration) == "default":
        raise CalibrationMismatchError(
            f"{got}; the shipped calibration ('default') is for the default camera's {made} frames. For "
            f"frames of another camera, register it (optitact register NOLOAD.png PRESSED.png... "
            f"--camera-intrinsics CAM.yml --out setup.json) and add --setup setup.json: the shipped "
            f"calibration is then transferred to your camera and sensor")
    raise CalibrationMismatchError(
        f"{got}; the calibration {args.calibration} (fingerprint {cal.fingerprint}) is for {made} frames of "
        f"the camera it was made with: give frames of that camera, or calibrate this one (optitact register "
        f"... --out setup.json, then --calibration default --setup setup.json, or calibrate fit --setup "
        f"setup.json --start default)")


def read_setup(path: Path) -> tuple:
    """``(sensor, camera)`` of a ``--setup`` JSON file (:func:`optitact.registration.setup.read_setup`)."""
    from optitact.registration.setup import read_setup as read

    setup = read(path)
    return setup.sensor, setup.camera
