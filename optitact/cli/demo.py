"""``optitact demo``, ``optitact render`` and the overlay picture they draw."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

from optitact import __version__
from optitact.camera import FisheyeCamera
from optitact.ccd import CCD
from optitact.contact import Contacts, contact_patches
from optitact.sensor import DomeSensor

from ._args import render_parents

__all__ = ["add_parsers", "overlay"]

#: No-load frames the demo renders (once, cached) for its baseline.
NOLOAD_FRAMES = 4


def add_parsers(sub) -> None:
    """Add ``demo`` and ``render`` to the subcommands."""
    demo = sub.add_parser(
        "demo", parents=render_parents(spp=64),
        help="render the 41-element dome under a sample load and estimate its forces",
        description="Render the default 41-element dome under a sample indenter load on the "
                    "fastest Mitsuba variant here, apply the CCD model, read the frame with the "
                    "pipeline and the shipped calibration, and write frame.png, overlay.png (the "
                    "contact model's patches), forces.png (the estimated force field), "
                    "estimated_forces.csv, radiance.npy and forces.json (true and estimated "
                    "forces, settings, timings) into a folder, whose path is printed on stdout. "
                    "The no-load baseline renders are cached in the user cache folder.")
    demo.add_argument("--out", type=Path, default=Path("optitact-demo"),
                      help="output folder (default ./optitact-demo)")
    demo.set_defaults(run=run_demo)

    rend = sub.add_parser(
        "render", parents=render_parents(spp=64), help="render a frame for forces given in a CSV file",
        description="Render one camera frame of the dome for element-local forces read from a "
                    "CSV file (41 rows of fx, fy, fz in N, or element, fx, fy, fz; optional "
                    "header) and write it as PNG.")
    rend.add_argument("--forces", type=Path, required=True, metavar="FILE.csv",
                      help="element-local forces, one row per element")
    rend.add_argument("--out", type=Path, required=True, metavar="FRAME.png",
                      help="where to write the frame")
    rend.add_argument("--radiance", type=Path, default=None, metavar="FILE.npy",
                      help="also save the noiseless float32 radiance image")
    rend.set_defaults(run=run_render)


def _render_frame(sensor: DomeSensor, forces: np.ndarray, args) -> dict:
    from optitact.render import active_variant, render

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




def _estimate(sensor: DomeSensor, r: dict, args) -> dict | None:
    """Demo step 2: no-load baseline (cached render), pipeline and the shipped calibration."""
    from optitact._cache import cached_render
    from optitact.calib import default_calibration

    cal = default_calibration()
    if cal.camera != r["camera"] or cal.sensor != sensor:
        print(f"optitact: the shipped calibration is for {cal.camera.width}x{cal.camera.height} "
              f"frames; skipping the force estimate", file=sys.stderr)
        return None
    baseline = []
    for k in range(NOLOAD_FRAMES):  # their mean and per-pixel noise (see Pipeline)
        empty = cached_render(sensor, np.zeros((sensor.n_elements, 3)), camera=r["camera"],
                              spp=args.spp, seed=args.seed + 1 + k, variant=args.variant)
        baseline.append(r["ccd"].expose(empty, seed=args.seed + 1 + k))
    baseline = np.stack(baseline)
    readings = cal.pipeline(baseline=baseline).process(r["frame"])
    return {"field": cal.apply(readings), "readings": readings, "calibration": cal}


def run_demo(args) -> int:
    from optitact.io import write_json, write_npy, write_png
    from optitact.loads import indenter_load

    sensor = DomeSensor.default()
    forces = indenter_load(sensor)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    r = _render_frame(sensor, forces, args)
    contacts = contact_patches(sensor, forces)
    write_png(out / "frame.png", r["frame"])
    write_png(out / "overlay.png", overlay(r["frame"], sensor, r["camera"], contacts, forces))
    write_npy(out / "radiance.npy", r["radiance"])
    est = _estimate(sensor, r, args)
    written = ["frame.png", "overlay.png", "radiance.npy", "forces.json"]
    meta = {
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
    }
    if est is not None:
        from optitact.forces import ForceField

        field = est["field"]
        field.to_csv(out / "estimated_forces.csv")
        field.save_plot(out / "forces.png", r["frame"], r["camera"],
                        title="estimated forces (shipped calibration)")
        written += ["estimated_forces.csv", "forces.png"]
        truth = ForceField(sensor, forces)
        err = field.local - forces
        meta["estimated_forces_local_n"] = field.local
        meta["estimate_rmse_n"] = {k: float(np.sqrt(np.mean(err[:, i] ** 2)))
                                   for i, k in enumerate(("fx", "fy", "fz"))}
        meta["resultant_n"] = {"true": truth.resultant, "estimated": field.resultant}
        print("optitact: resultant force (N): true ({:+.3f}, {:+.3f}, {:+.3f}), estimated "
              "({:+.3f}, {:+.3f}, {:+.3f})".format(*truth.resultant, *field.resultant),
              file=sys.stderr)
    write_json(out / "forces.json", meta)
    print(f"optitact: wrote {', '.join(written)} to {out}", file=sys.stderr)
    print(out)
    return 0




def run_render(args) -> int:
    from optitact.io import read_forces_csv, write_npy, write_png

    sensor = DomeSensor.default()
    forces = read_forces_csv(args.forces, sensor.n_elements)
    r = _render_frame(sensor, forces, args)
    write_png(args.out, r["frame"])
    if args.radiance is not None:
        write_npy(args.radiance, r["radiance"])
    print(f"optitact: wrote {args.out}", file=sys.stderr)
    return 0


