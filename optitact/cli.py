"""Command-line interface: ``optitact demo``, ``optitact render`` and ``optitact bench``.

Messages and progress bars go to stderr; ``demo`` prints the folder it wrote
on stdout. Bad input is a one-line ``optitact: error: ...`` and exit code 2.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from . import __version__
from .camera import FisheyeCamera
from .ccd import CCD
from .contact import Contacts, contact_patches
from .sensor import DomeSensor

__all__ = ["main", "overlay"]


def _int_at_least(minimum: int, what: str):
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


_positive_int = _int_at_least(1, "a positive integer")
_seed = _int_at_least(0, "a non-negative integer")


def _add_render_options(p: argparse.ArgumentParser, *, spp: int) -> None:
    p.add_argument("--spp", type=_positive_int, default=spp,
                   help=f"samples per pixel (default {spp})")
    p.add_argument("--seed", type=_seed, default=0,
                   help="seed of the render and the camera noise (default 0)")
    p.add_argument("--bits", type=int, choices=(8, 10, 12, 16), default=8,
                   help="ADC bit depth of the frame (default 8; >8 bits write 16-bit PNG)")
    p.add_argument("--variant", default=None,
                   help="Mitsuba variant (default: fastest that works: cuda_ad_rgb > "
                        "llvm_ad_rgb > scalar_rgb)")
    p.add_argument("--width", type=_positive_int, default=640, help="image width (default 640)")
    p.add_argument("--height", type=_positive_int, default=480,
                   help="image height (default 480)")


def _parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="optitact",
        description="Optical three-axis tactile sensing: render synthetic frames of the dome "
                    "sensor, process frames into forces.")
    parser.add_argument("--version", action="version", version=f"optitact {__version__}")
    sub = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")

    demo = sub.add_parser(
        "demo", help="render the 41-element dome under a sample load",
        description="Render the default 41-element dome under a sample indenter load on the "
                    "fastest Mitsuba variant here, apply the CCD model, and write frame.png, "
                    "overlay.png, radiance.npy and forces.json (the forces used, the settings "
                    "and timings) into a folder, whose path is printed on stdout.")
    demo.add_argument("--out", type=Path, default=Path("optitact-demo"),
                      help="output folder (default ./optitact-demo)")
    _add_render_options(demo, spp=64)

    rend = sub.add_parser(
        "render", help="render a frame for forces given in a CSV file",
        description="Render one camera frame of the dome for element-local forces read from a "
                    "CSV file (41 rows of fx, fy, fz in N, or element, fx, fy, fz; optional "
                    "header) and write it as PNG.")
    rend.add_argument("--forces", type=Path, required=True, metavar="FILE.csv",
                      help="element-local forces, one row per element")
    rend.add_argument("--out", type=Path, required=True, metavar="FRAME.png",
                      help="where to write the frame")
    rend.add_argument("--radiance", type=Path, default=None, metavar="FILE.npy",
                      help="also save the noiseless float32 radiance image")
    _add_render_options(rend, spp=64)

    bench = sub.add_parser(
        "bench", help="benchmarks (time side by side with error)",
        description="Benchmarks that report run time together with the error it buys; "
                    "medians over repeats in one run. Output: one JSON object on stdout.")
    bsub = bench.add_subparsers(dest="bench", required=True, metavar="BENCH")
    brender = bsub.add_parser(
        "render", help="full-frame render time and Monte Carlo noise per spp",
        description="Render the demo load at several spp, each several times with its own "
                    "seed; report median time and the noise of spot pixels and of the summed "
                    "spot radiance.")
    brender.add_argument("--spp", type=_positive_int, nargs="+", default=[16, 64, 256],
                         help="samples per pixel to measure (default 16 64 256)")
    brender.add_argument("--repeats", type=_int_at_least(2, "an integer >= 2"), default=3,
                         help="renders per spp (default 3)")
    brender.add_argument("--width", type=_positive_int, default=640)
    brender.add_argument("--height", type=_positive_int, default=480)
    brender.add_argument("--variant", default=None, help="Mitsuba variant (default: fastest)")
    brender.add_argument("--json", action="store_true",
                         help="print only the JSON object (the default output is JSON too)")
    return parser


def _render_frame(sensor: DomeSensor, forces: np.ndarray, args) -> dict:
    from .render import active_variant, render

    camera = FisheyeCamera(width=args.width, height=args.height)
    ccd = CCD(bits=args.bits)
    t0 = time.perf_counter()
    radiance = render(sensor, forces, camera=camera, spp=args.spp, seed=args.seed,
                      variant=args.variant, progress=True)
    seconds = time.perf_counter() - t0
    info = active_variant()
    if info["note"]:
        print(info["note"], file=sys.stderr)
    frame = ccd.expose(radiance, seed=args.seed)
    print(f"optitact: rendered {camera.width}x{camera.height} at {args.spp} spp on "
          f"{info['variant']} in {seconds:.2f} s", file=sys.stderr)
    return {"radiance": radiance, "frame": frame, "camera": camera, "ccd": ccd,
            "variant": info["variant"], "render_seconds": seconds}


def overlay(frame: np.ndarray, sensor: DomeSensor, camera: FisheyeCamera, contacts: Contacts,
            forces: np.ndarray) -> np.ndarray:
    """BGR uint8 picture of a frame with element centres, predicted patches and shear arrows.

    Element centres are grey dots, the contact model's patches green
    circles (projected with the closed-form camera), and each loaded
    element's shear a red arrow (1 mm on the dome per 0.1 N).
    """
    import cv2

    img = frame.astype(np.float64)
    top = max(float(np.percentile(img, 99.9)), 1.0)
    base = np.clip(img / top * 255.0, 0, 255).astype(np.uint8)
    out = cv2.cvtColor(base, cv2.COLOR_GRAY2BGR)

    def pt(rc):
        return (int(round(rc[1])), int(round(rc[0])))

    centres = camera.project(sensor.element_positions, sensor)
    for rc in centres:
        cv2.circle(out, pt(rc), 1, (160, 160, 160), -1, cv2.LINE_AA)
    touching = contacts.radii > 0
    if touching.any():
        idx = np.argwhere(touching)
        centre_px = camera.project(contacts.centers[touching], sensor)
        radii = contacts.radii[touching]
        edge = np.stack([radii, np.zeros_like(radii)], axis=1)  # a point on each patch's rim
        rim = sensor.dome_point(idx[:, 0], sensor.cone_offsets[idx[:, 1]]
                                + contacts.slide[idx[:, 0]] + edge)
        rad_px = np.linalg.norm(camera.project(rim, sensor) - centre_px, axis=1)
        for rc, r in zip(centre_px, rad_px, strict=True):
            cv2.circle(out, pt(rc), max(int(round(r)), 1), (0, 200, 0), 1, cv2.LINE_AA)
    for i in np.nonzero(forces[:, 2] > 0)[0]:
        shear = forces[i, :2]
        if np.hypot(*shear) < 1e-6:
            continue
        tip = sensor.dome_point(np.array([i]), (shear * 10.0)[None, :])
        cv2.arrowedLine(out, pt(centres[i]), pt(camera.project(tip, sensor)[0]), (0, 0, 255), 1,
                        cv2.LINE_AA, tipLength=0.3)
    return out


def _demo(args) -> int:
    from .io import write_json, write_png
    from .loads import indenter_load

    sensor = DomeSensor.default()
    forces = indenter_load(sensor)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    r = _render_frame(sensor, forces, args)
    contacts = contact_patches(sensor, forces)
    write_png(out / "frame.png", r["frame"])
    write_png(out / "overlay.png", overlay(r["frame"], sensor, r["camera"], contacts, forces))
    np.save(out / "radiance.npy", r["radiance"])
    write_json(out / "forces.json", {
        "forces_local_n": forces,
        "columns": ["fx", "fy", "fz"],
        "load": "indenter_load(sensor) with its defaults",
        "variant": r["variant"],
        "spp": args.spp,
        "seed": args.seed,
        "render_seconds": round(r["render_seconds"], 3),
        "sensor": sensor.to_dict(),
        "camera": r["camera"].to_dict(),
        "ccd": r["ccd"].to_dict(),
        "version": __version__,
    })
    print(f"optitact: wrote frame.png, overlay.png, radiance.npy, forces.json to {out}",
          file=sys.stderr)
    print(out)
    return 0


def _render(args) -> int:
    from .io import read_forces_csv, write_png

    sensor = DomeSensor.default()
    forces = read_forces_csv(args.forces, sensor.n_elements)
    r = _render_frame(sensor, forces, args)
    write_png(args.out, r["frame"])
    if args.radiance is not None:
        np.save(args.radiance, r["radiance"])
    print(f"optitact: wrote {args.out}", file=sys.stderr)
    return 0


def _bench(args) -> int:
    import json

    from .bench import bench_render

    result = bench_render(tuple(args.spp), repeats=args.repeats, width=args.width,
                          height=args.height, variant=args.variant)
    print(json.dumps(result))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the ``optitact`` command; returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        return {"demo": _demo, "render": _render, "bench": _bench}[args.command](args)
    except (ValueError, TypeError, OSError) as exc:
        print(f"optitact: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
