"""``optitact demo``, ``optitact render`` and the overlay picture they draw."""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

from optitact import __version__
from optitact.optics.camera import FisheyeCamera
from optitact.optics.ccd import CCD
from optitact.optics.contact import Contacts, contact_patches
from optitact.optics.sensor import DomeSensor

from optitact.cli._args import out_file, out_folder, render_parents

__all__ = ["add_parsers", "display_levels", "display_view", "overlay"]

#: ``render --indenter``'s grammar: :data:`optitact.forces.indenter.SPEC_GRAMMAR` (not imported by the parser).
_INDENTER_GRAMMAR = ("sphere:radius=R | flat:radius=R | edge:length=L,tip_radius=r[,angle=DEG] | "
                     "cylinder:radius=R,length=L, each optionally with ,spin=DEG")

#: No-load frames the demo renders (once, cached) for its baseline.
NOLOAD_FRAMES = 4

#: ``display_view``: the black level is this percentile of the frame (its dark offset), white this
#: percentile of the pixels above it (the spots), and the levels between follow this gamma.
VIEW_BLACK_PERCENTILE = 1.0
VIEW_WHITE_PERCENTILE = 99.0
VIEW_GAMMA = 0.5


def add_parsers(sub) -> None:
    """Add ``demo`` and ``render`` to the subcommands."""
    demo = sub.add_parser(
        "demo", parents=render_parents(spp=64),
        help="render the 41-element dome under a sample load and estimate its forces",
        description="Render the default 41-element dome under a sample indenter load on the "
                    "fastest Mitsuba variant here, apply the CCD model, read the frame with the "
                    "pipeline and the shipped calibration, and write frame.png (the raw frame, "
                    "for processing), frame_view.png (the same frame brightened for viewing "
                    "only), overlay.png (the contact model's patches), forces.png (the estimated "
                    "force field), estimated_forces.csv, radiance.npy and forces.json (true and "
                    "estimated forces, settings, timings) into a folder, whose path is printed on "
                    "stdout. The no-load baseline renders are cached in the user cache folder. With "
                    "--setup it renders and processes the setup's sensor and camera instead (e.g. a "
                    "sensor registered by optitact register: its camera model and pose, element "
                    "offsets and gains), path-traced at the camera's own size, and estimates forces "
                    "with the shipped calibration transferred to them.")
    demo.add_argument("--setup", type=Path, default=None, metavar="SETUP.json",
                      help="the sensor and camera of a setup file (from optitact register); the frame is "
                           "the camera's size (--width/--height must match it or be left out)")
    demo.add_argument("--out", type=out_folder, default=Path("optitact-demo"),
                      help="output folder, created if missing (default ./optitact-demo)")
    demo.set_defaults(run=run_demo)

    rend = sub.add_parser(
        "render", parents=render_parents(spp=64),
        help="render a frame for forces given in a CSV file or made by an object pressed into the dome",
        description="Render one camera frame of the dome for element-local forces read from a "
                    "CSV file (41 rows of fx, fy, fz in N, or element, fx, fy, fz; optional "
                    "header), or made by an object pressed into the dome (--indenter, with --at and "
                    "--depth or --force; the contact model of optitact.forces.indenter), and write it "
                    "as PNG (or .npy). Output names are checked before rendering.")
    source = rend.add_mutually_exclusive_group(required=True)
    source.add_argument("--forces", type=Path, default=None, metavar="FILE.csv",
                        help="element-local forces, one row per element; with an element column only the "
                             "loaded elements (the header alone: no load)")
    source.add_argument("--indenter", type=_indenter_spec, default=None, metavar="SPEC",
                        help="press an object into the dome instead: " + _INDENTER_GRAMMAR
                             + " (mm, deg); e.g. sphere:radius=5")
    rend.add_argument("--at", type=_numbers("POLAR,AZIMUTH", 2), default=None, metavar="POLAR,AZIMUTH",
                      help="with --indenter: where it touches the feeler tips, polar angle from the dome "
                           "axis and azimuth from +x (deg; default 0,0, the apex); it presses towards the "
                           "dome centre")
    push = rend.add_mutually_exclusive_group()
    push.add_argument("--depth", type=float, default=None, metavar="MM",
                      help="with --indenter: how far it is pushed in beyond touching (mm)")
    push.add_argument("--force", type=float, default=None, metavar="N",
                      help="with --indenter: the pressing force to reach (N); the depth is solved for")
    rend.add_argument("--slide", type=_numbers("DX,DY[,DZ]", 2, 3), default=None, metavar="DX,DY[,DZ]",
                      help="with --indenter: slide it after pressing (mm): DX,DY along its own x, y axes "
                           "(tangent to the dome where it touches), or DX,DY,DZ in the sensor frame; "
                           "--slide=-0.1,0 for a negative first value")
    rend.add_argument("--friction", type=float, default=None, metavar="MU",
                      help="with --indenter: Coulomb friction coefficient of the slide (default 0.5)")
    rend.add_argument("--forces-out", type=out_file(".csv"), default=None, metavar="FILE.csv",
                      help="with --indenter: also write the element forces as a CSV file that --forces "
                           "reads")
    rend.add_argument("--setup", type=Path, default=None, metavar="SETUP.json",
                      help="render the sensor and camera of a setup file (from optitact register: its "
                           "camera model and pose, element offsets and gains) at the camera's size "
                           "(--width/--height must match it or be left out)")
    rend.add_argument("--out", type=out_file(".png", ".npy"), required=True, metavar="FRAME.png",
                      help="where to write the frame: .png (lossless, 8 or 16 bit) or .npy; a missing "
                           "folder is created")
    rend.add_argument("--radiance", type=out_file(".npy"), default=None, metavar="FILE.npy",
                      help="also save the noiseless float32 radiance image")
    rend.add_argument("--view", type=out_file(".png"), default=None, metavar="VIEW.png",
                      help="also save an 8-bit copy of the frame brightened for viewing (dark "
                           f"offset black, the brightest spots white, gamma {VIEW_GAMMA:g}); never "
                           "use it as data")
    rend.set_defaults(run=run_render)


def _indenter_spec(text: str):
    """An argparse type: ``--indenter`` text as ``(shape, spin_deg)`` (the indenter module's ``parse_spec``)."""
    from optitact.errors import InputError
    from optitact.forces.indenter import parse_spec

    try:
        return parse_spec(text)
    except InputError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def _numbers(form: str, *counts: int):
    """An argparse type: comma-separated finite numbers, as many as one of ``counts``."""

    def parse(text: str) -> tuple[float, ...]:
        try:
            values = tuple(float(v) for v in text.split(","))
        except ValueError:
            values = ()
        if len(values) not in counts or not all(np.isfinite(values)):
            raise argparse.ArgumentTypeError(f"expected {form} (finite numbers, comma-separated), got {text!r}")
        return values

    return parse


def _indenter_forces(sensor: DomeSensor, args) -> np.ndarray:
    """``--indenter``: the element forces of the object pressed at ``--at``; a summary on stderr."""
    from optitact.errors import InputError
    from optitact.forces.indenter import Pose, press

    if args.depth is None and args.force is None:
        raise InputError("--indenter needs --depth MM (how far it is pushed in) or --force N (the pressing "
                         "force)")
    shape, spin = args.indenter
    polar, azimuth = (0.0, 0.0) if args.at is None else args.at
    pose = Pose.touching(sensor, polar, azimuth, spin_deg=spin)
    ind = press(sensor, shape, pose, depth=args.depth, force=args.force, slide=args.slide,
                friction=0.5 if args.friction is None else args.friction)
    print(f"optitact: indenter {shape.spec} spin {spin:g} deg at polar {polar:g} deg, azimuth {azimuth:g} deg: "
          f"depth {ind.depth:.4g} mm, pressing force {ind.normal_force:.4g} N, {ind.n_contact} of "
          f"{sensor.n_elements} elements in contact ({int(ind.slipping.sum())} slipping)", file=sys.stderr)
    for i in np.flatnonzero(ind.contact):
        fx, fy, fz = ind.forces[i]
        print(f"optitact:   element {i:2d}: fx {fx:+.4f} N, fy {fy:+.4f} N, fz {fz:+.4f} N"
              + (" (slipping)" if ind.slipping[i] else ""), file=sys.stderr)
    return ind.forces


def _render_frame(sensor: DomeSensor, forces: np.ndarray, args, camera=None) -> dict:
    from optitact.render.backend import active_variant
    from optitact.render import render

    camera = FisheyeCamera(width=args.width, height=args.height) if camera is None else camera
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




def display_levels(frame: np.ndarray) -> tuple[float, float]:
    """The grey levels :func:`display_view` shows as black and as white.

    Black is the :data:`VIEW_BLACK_PERCENTILE` percentile of the frame (the
    dark offset: most of a frame is unlit), white the
    :data:`VIEW_WHITE_PERCENTILE` percentile of the pixels above black (the
    spots), so a few bright pixels set the scale and the dark offset stays
    black.
    """
    img = np.asarray(frame, dtype=np.float64)
    lo = float(np.percentile(img, VIEW_BLACK_PERCENTILE))
    lit = img[img > lo]
    hi = float(np.percentile(lit, VIEW_WHITE_PERCENTILE)) if lit.size else lo + 1.0
    return lo, max(hi, lo + 1e-12)


def display_view(frame: np.ndarray, *, gamma: float = VIEW_GAMMA) -> np.ndarray:
    """An 8-bit copy of ``frame`` brightened for viewing: never use it as data.

    Grey levels from black to white (:func:`display_levels`) are stretched
    to 0-255 with a power law of exponent ``gamma`` (< 1 lifts dim spots).
    ``frame`` itself is not changed.

    Examples
    --------
    >>> frame = np.full((4, 100), 4, np.uint8)
    >>> frame[0, :4] = (8, 20, 68, 200)
    >>> [round(v, 2) for v in display_levels(frame)]
    [4.0, 196.04]
    >>> display_view(frame)[0, :5].tolist()
    [37, 74, 147, 255, 0]
    """
    lo, hi = display_levels(frame)
    img = np.asarray(frame, dtype=np.float64)
    return np.round(np.clip((img - lo) / (hi - lo), 0.0, 1.0) ** gamma * 255.0).astype(np.uint8)


def overlay(frame: np.ndarray, sensor: DomeSensor, camera: FisheyeCamera, contacts: Contacts | None,
            forces: np.ndarray, *, title: str | None = None) -> np.ndarray:
    """BGR uint8 picture of a frame with element centres, predicted patches and shear arrows.

    Element centres are grey dots, the contact model's patches green
    circles (projected with the closed-form camera), and each loaded
    element's shear a red arrow (1 mm on the dome per 0.1 N). Small frames
    are enlarged (nearest pixel) so the marks and text are legible; a title
    band sits above the picture and a legend with the scales and units
    below it. ``contacts=None`` (estimated forces, as a live view draws):
    no patches, and no patch line in the legend.
    """
    import cv2

    h, w = frame.shape[:2]
    s = max(1, -(-560 // w))  # integer enlargement: at least 560 px wide
    lo, hi = display_levels(frame)
    base = display_view(frame)
    if s > 1:
        base = cv2.resize(base, (w * s, h * s), interpolation=cv2.INTER_NEAREST)
    pic = cv2.cvtColor(base, cv2.COLOR_GRAY2BGR)
    grey, green, red = (160, 160, 160), (0, 200, 0), (0, 0, 255)

    def pt(rc):  # (row, col) of the frame -> (x, y) of the enlarged picture
        return (int(round((rc[1] + 0.5) * s - 0.5)), int(round((rc[0] + 0.5) * s - 0.5)))

    centres = camera.project(sensor.element_positions, sensor)
    for rc in centres:
        cv2.circle(pic, pt(rc), max(1, s // 2), grey, -1, cv2.LINE_AA)
    touching = contacts.radii > 0 if contacts is not None else np.zeros((0,), bool)
    if touching.any():
        idx = np.argwhere(touching)
        centre_px = camera.project(contacts.centers[touching], sensor)
        radii = contacts.radii[touching]
        edge = np.stack([radii, np.zeros_like(radii)], axis=1)  # a point on each patch's rim
        rim = sensor.dome_point(idx[:, 0], sensor.cone_offsets[idx[:, 1]]
                                + contacts.slide[idx[:, 0]] + edge)
        rad_px = np.linalg.norm(camera.project(rim, sensor) - centre_px, axis=1)
        for rc, r in zip(centre_px, rad_px, strict=True):
            cv2.circle(pic, pt(rc), max(int(round(r * s)), 1), green, 1, cv2.LINE_AA)
    for i in np.nonzero(forces[:, 2] > 0)[0]:
        shear = forces[i, :2]
        if np.hypot(*shear) < 1e-6:
            continue
        tip = sensor.dome_point(np.array([i]), (shear * 10.0)[None, :])
        cv2.arrowedLine(pic, pt(centres[i]), pt(camera.project(tip, sensor)[0]), red, 1,
                        cv2.LINE_AA, tipLength=0.3)

    font, scale, line = cv2.FONT_HERSHEY_SIMPLEX, 0.45, 20
    width = w * s
    head = np.full((30, width, 3), 40, np.uint8)
    cv2.putText(head, title or "frame with element centres, predicted contact patches and shear",
                (8, 20), font, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    legend = [
        ("dot", grey, f"element centre ({sensor.n_elements} elements)"),
        *([("circle", green, "contact patch predicted by the contact model (one per pressing cone)")]
          if contacts is not None else []),
        ("arrow", red, "shear force on a loaded element: 1 mm on the dome per 0.1 N"),
        (None, None, f"image: the {w}x{h} px frame, grey levels {lo:.0f}-{hi:.0f} shown black to white "
                     f"(gamma {VIEW_GAMMA:g}), for display only"),
    ]
    foot = np.full((line * len(legend) + 8, width, 3), 40, np.uint8)
    for k, (mark, colour, text) in enumerate(legend):
        y = 14 + k * line
        if mark == "dot":
            cv2.circle(foot, (18, y - 4), 3, colour, -1, cv2.LINE_AA)
        elif mark == "circle":
            cv2.circle(foot, (18, y - 4), 6, colour, 1, cv2.LINE_AA)
        elif mark == "arrow":
            cv2.arrowedLine(foot, (8, y - 4), (30, y - 4), colour, 1, cv2.LINE_AA, tipLength=0.35)
        cv2.putText(foot, text, (40 if mark else 8, y), font, scale, (255, 255, 255), 1, cv2.LINE_AA)
    return np.concatenate([head, pic, foot], axis=0)


def _noload_baseline(sensor: DomeSensor, camera: FisheyeCamera, ccd: CCD, args, *,
                     seconds_per_frame: float) -> np.ndarray:
    """The demo's no-load baseline: NOLOAD_FRAMES cached renders, announced and with a progress bar.

    Those not in the cache yet are full renders (``seconds_per_frame``, the
    loaded frame's time, is the estimate), and only they are announced; later
    runs read them from the cache.
    """
    from tqdm import tqdm

    from optitact.io.cache import cache_dir
    from optitact.render.cache import cached_render, render_cache_path

    zero = np.zeros((sensor.n_elements, 3))
    todo = sum(not render_cache_path(sensor, zero, camera=camera, spp=args.spp, seed=args.seed + 1 + k,
                                     variant=args.variant).is_file() for k in range(NOLOAD_FRAMES))
    where = cache_dir() / "renders"
    if todo:
        which = (f"{NOLOAD_FRAMES} renders at {args.spp} spp, about {todo * seconds_per_frame:.0f} s on the "
                 f"first run" if todo == NOLOAD_FRAMES else
                 f"{todo} of {NOLOAD_FRAMES} renders at {args.spp} spp still to make, about "
                 f"{todo * seconds_per_frame:.0f} s")
        print(f"optitact: no-load baseline: {which} (one render took {seconds_per_frame:.1f} s); cached in "
              f"{where}, so later runs take seconds", file=sys.stderr)
    else:
        print(f"optitact: no-load baseline: {NOLOAD_FRAMES} renders at {args.spp} spp, read from the cache "
              f"({where})", file=sys.stderr)
    baseline = []
    for k in tqdm(range(NOLOAD_FRAMES), desc="no-load baseline", unit="frame", file=sys.stderr,
                  disable=not todo):
        empty = cached_render(sensor, zero, camera=camera,
                              spp=args.spp, seed=args.seed + 1 + k, variant=args.variant)
        baseline.append(ccd.expose(empty, seed=args.seed + 1 + k))
    return np.stack(baseline)


def _shipped_calibration(sensor: DomeSensor, args, camera=None):
    """The shipped calibration if it fits the demo's sensor and camera, else None (and a note why).

    For a ``--setup`` (``camera`` given) it is transferred to the setup's
    sensor and camera (:meth:`Calibration.transferred`). Called before
    rendering: a force estimate needs matplotlib for forces.png, so a missing
    ``plot`` extra is reported now, not after minutes of renders.
    """
    from optitact._optional import require
    from optitact.calib.shipped import default_calibration

    cal = default_calibration()
    if camera is not None:
        if cal.sensor != sensor or cal.camera != camera:
            cal = cal.transferred(sensor, camera)
            print(f"optitact: the shipped calibration is transferred to the setup's sensor and camera "
                  f"(fingerprint {cal.fingerprint})", file=sys.stderr)
    elif cal.camera != FisheyeCamera(width=args.width, height=args.height) or cal.sensor != sensor:
        print(f"optitact: the shipped calibration is for {cal.camera.width}x{cal.camera.height} "
              f"frames; skipping the force estimate", file=sys.stderr)
        return None
    require("matplotlib.figure", purpose="the demo's forces.png")
    return cal


def _setup(args, argv_size: bool):
    """``(sensor, camera)`` of ``--setup`` (camera None without one); the size options must agree."""
    if args.setup is None:
        return DomeSensor.default(), None
    from optitact.cli._args import read_setup

    sensor, camera = read_setup(args.setup)
    if argv_size and (args.width, args.height) != (camera.width, camera.height):
        from optitact.errors import InputError

        raise InputError(f"--width/--height {args.width}x{args.height}: the setup's camera ({args.setup}) "
                         f"makes {camera.width}x{camera.height} frames; leave the size out with --setup")
    return sensor, camera


def _estimate(sensor: DomeSensor, r: dict, args, cal) -> dict | None:
    """Demo step 2: no-load baseline (cached render), pipeline and the shipped calibration."""
    if cal is None:
        return None
    baseline = _noload_baseline(sensor, r["camera"], r["ccd"], args,  # their mean and noise (see Pipeline)
                                seconds_per_frame=r["render_seconds"])
    readings = cal.pipeline(baseline=baseline, bits=r["ccd"].bits).process(r["frame"])
    return {"field": cal.apply(readings), "readings": readings, "calibration": cal}


def run_demo(args) -> int:
    from optitact.io.files import write_json, write_npy, write_png
    from optitact.optics.loads import indenter_load

    sensor, camera = _setup(args, (args.width, args.height) != (640, 480))
    forces = indenter_load(sensor)
    out = args.out
    out.mkdir(parents=True, exist_ok=True)
    cal = _shipped_calibration(sensor, args, camera)
    r = _render_frame(sensor, forces, args, camera)
    contacts = contact_patches(sensor, forces)
    write_png(out / "frame.png", r["frame"])
    write_png(out / "frame_view.png", display_view(r["frame"]))
    title = (f"optitact demo: indenter load, total Fz {forces[:, 2].sum():.2f} N; {args.spp} spp, "
             f"{r['variant']}")
    write_png(out / "overlay.png", overlay(r["frame"], sensor, r["camera"], contacts, forces, title=title))
    write_npy(out / "radiance.npy", r["radiance"])
    est = _estimate(sensor, r, args, cal)
    written = ["frame.png", "frame_view.png (viewing only)", "overlay.png", "radiance.npy", "forces.json"]
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
        "setup": None if args.setup is None else str(args.setup),
        "version": __version__,
    }
    if est is not None:
        from optitact.forces import ForceField

        field = est["field"]
        field.to_csv(out / "estimated_forces.csv")
        field.save_plot(out / "forces.png", r["frame"], r["camera"],
                        title="estimated forces (shipped calibration"
                              + (", transferred to the setup)" if camera is not None else ")"))
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
    from optitact.io.tables import read_forces_csv
    from optitact.io.files import write_npy, write_png

    if args.indenter is None:
        given = [name for name in ("at", "depth", "force", "slide", "friction", "forces_out")
                 if getattr(args, name) is not None]
        if given:
            from optitact.errors import InputError

            raise InputError(f"{', '.join('--' + g.replace('_', '-') for g in given)}: only with --indenter "
                             f"(the forces of --forces are given)")
    sensor, camera = _setup(args, (args.width, args.height) != (640, 480))
    if args.indenter is None:
        forces = read_forces_csv(args.forces, sensor.n_elements)
    else:
        forces = _indenter_forces(sensor, args)
        if args.forces_out is not None:
            from optitact.io.tables import write_forces_csv

            write_forces_csv(args.forces_out, forces)
    r = _render_frame(sensor, forces, args, camera)
    if args.out.suffix.lower() == ".npy":
        write_npy(args.out, r["frame"])
    else:
        write_png(args.out, r["frame"])
    written = [str(args.out)]
    if args.radiance is not None:
        write_npy(args.radiance, r["radiance"])
        written.append(str(args.radiance))
    if args.view is not None:
        write_png(args.view, display_view(r["frame"]))
        written.append(f"{args.view} (viewing only)")
    if args.indenter is not None and args.forces_out is not None:
        written.append(f"{args.forces_out} (the element forces)")
    print(f"optitact: wrote {', '.join(written)}", file=sys.stderr)
    return 0


