"""Command-line interface: ``optitact demo``, ``render``, ``process`` and ``bench``.

Messages and progress bars go to stderr; ``demo`` prints the folder it wrote
on stdout. Bad input is a one-line ``optitact: error: ...`` and exit code 2.
"""

from __future__ import annotations

import argparse
import itertools
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

#: No-load frames the demo renders (once, cached) for its baseline.
NOLOAD_FRAMES = 4


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
        "demo", help="render the 41-element dome under a sample load and estimate its forces",
        description="Render the default 41-element dome under a sample indenter load on the "
                    "fastest Mitsuba variant here, apply the CCD model, read the frame with the "
                    "pipeline and the shipped calibration, and write frame.png, overlay.png (the "
                    "contact model's patches), forces.png (the estimated force field), "
                    "estimated_forces.csv, radiance.npy and forces.json (true and estimated "
                    "forces, settings, timings) into a folder, whose path is printed on stdout. "
                    "The no-load baseline renders are cached in the user cache folder.")
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

    proc = sub.add_parser(
        "process", help="camera frames -> per-element readings CSV (G, u, contact)",
        description="Process camera frames of the dome into per-element readings: integrated "
                    "grey value G (grey level x mm^2 on the dome), centroid shift u (mm, "
                    "element-local x, y), contact and saturation flags; one CSV row per frame "
                    "and element. FRAMES are image files (PNG/TIFF/..., 8 or 16 bit), folders "
                    "of them (sorted by name), .npy frames or stacks, or videos (OpenCV); colour "
                    "is converted to grey. The no-load baseline is --baseline, or else the mean "
                    "of the first --baseline-frames frames (default 1: the stream must start "
                    "unloaded).")
    proc.add_argument("frames", nargs="+", type=Path, metavar="FRAMES",
                      help="image files, folders, .npy stacks or video files")
    proc.add_argument("--out", type=Path, required=True, metavar="READINGS.csv",
                      help="where to write the readings")
    proc.add_argument("--baseline", type=Path, default=None, metavar="FRAME",
                      help="no-load frame (image or .npy; a .npy stack is averaged)")
    proc.add_argument("--baseline-frames", type=_int_at_least(0, "an integer >= 0"), default=1,
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
    proc.add_argument("--calibration", type=Path, default=None, metavar="CAL.json",
                      help="also estimate forces with this calibration (adds fx, fy, fz, clamped "
                           "columns); it fixes the sensor, camera and pipeline options. "
                           "'default' uses the shipped calibration")
    proc.add_argument("--plot", type=Path, default=None, metavar="PLOT.png",
                      help="with --calibration: save a force-field plot of the last frame")
    proc.add_argument("--scheduler", default=None, metavar="ADDRESS",
                      help="process the files on a Dask distributed cluster, one task per file "
                           "(scheduler address); the baseline comes from --baseline or the first "
                           "frames, and the CSV is the same as a local run's")
    proc.add_argument("--batch", type=_positive_int, default=32,
                      help="frames processed together (default 32)")

    cal = sub.add_parser(
        "calibrate", help="synthetic calibration sets and fitted curves",
        description="Generate a synthetic calibration set (rendered frames with known forces, "
                    "resumable) and fit calibration curves to it.")
    csub = cal.add_subparsers(dest="calibrate", required=True, metavar="STEP")
    gen = csub.add_parser(
        "generate", help="render a calibration set into a Zarr store (resumable)",
        description="Render FRAMES frames, each loading all 41 elements with independent forces "
                    "(Sobol design plus pure-normal and pure-shear sweeps), read them with the "
                    "pipeline and store readings, true forces, seeds and settings in a Zarr "
                    "store. Killing the job and running the same command again finishes the set, "
                    "identical to an uninterrupted run. Progress bar with frames/s and ETA on "
                    "stderr.")
    gen.add_argument("--frames", type=_positive_int, default=200, help="frames (default 200)")
    gen.add_argument("--out", type=Path, required=True, metavar="SET.zarr", help="the store")
    gen.add_argument("--spp", type=_positive_int, default=64, help="samples per pixel (default 64)")
    gen.add_argument("--seed", type=_seed, default=0, help="seed of the whole set (default 0)")
    gen.add_argument("--fz-max", type=float, default=1.0, help="largest normal force, N (default 1)")
    gen.add_argument("--shear-max", type=float, default=0.5,
                     help="largest shear magnitude, N (default 0.5)")
    gen.add_argument("--mu-max", type=float, default=0.35,
                     help="largest shear/normal ratio (default 0.35; the feeler tips at ~0.37)")
    gen.add_argument("--keep-frames", action="store_true", help="also store the frames")
    gen.add_argument("--render-mode", choices=("two_stage", "pixels", "full"), default="two_stage",
                     help="two_stage (default): guided light from a cached table (measured on first "
                          "use, minutes), patches traced as emitters, ~0.05 s/frame, no Monte Carlo "
                          "noise; pixels: path-trace only the pixels the pipeline reads; full: "
                          "path-trace whole frames (--spp applies to path tracing and the baseline)")
    gen.add_argument("--scheduler", default=None, metavar="ADDRESS",
                     help="run the frames on a Dask distributed cluster (scheduler address, e.g. "
                          "tcp://host:8786); the set is identical to a local one (default: here)")
    gen.add_argument("--width", type=_positive_int, default=640, help="image width (default 640)")
    gen.add_argument("--height", type=_positive_int, default=480,
                     help="image height (default 480)")
    gen.add_argument("--variant", default=None, help="Mitsuba variant (default: fastest)")
    fitp = csub.add_parser(
        "fit", help="fit calibration curves to a set",
        description="Fit per-element curves Fz = g(G) and the shear curves (model ohka: "
                    "Fx = f(ux), Fy = f(uy); model coupled: (Fx, Fy) = u g(G) / (a + b sqrt(g(G))))"
                    " to a calibration set and write them as JSON; --plot saves the curves with "
                    "their residuals.")
    fitp.add_argument("set", type=Path, metavar="SET.zarr", help="a calibration set")
    fitp.add_argument("--model", choices=("ohka", "coupled"), default="coupled",
                      help="curve model (default coupled)")
    fitp.add_argument("--out", type=Path, required=True, metavar="CAL.json")
    fitp.add_argument("--plot", type=Path, default=None, metavar="FIT.png",
                      help="save g(G), the shear curves and residuals as PNG")

    bench = sub.add_parser(
        "bench", help="benchmarks (time side by side with error)",
        description="Benchmarks that report run time together with the error it buys; "
                    "medians over repeats in one run. Output: one JSON object on stdout.")
    bsub = bench.add_subparsers(dest="bench", required=True, metavar="BENCH")
    brender = bsub.add_parser(
        "render", help="render time against the error it leaves, per mode and setting",
        description="For fixed load cases (1, 5 and 41 loaded elements, light and heavy), render "
                    "with each mode (brute: path-traced full frames; pixels: path-traced, only the "
                    "pixels the pipeline reads for the loaded elements, over the cached no-load "
                    "frame; adaptive: pixels with passes until each element reaches a target "
                    "relative standard error; two_stage: guided light to the patches from a cached "
                    "table, patches traced in closed form as emitters) at several settings, and "
                    "compare the readings with a converged reference (cached on disk after the "
                    "first run): G relative error, u error (mm) and the force error through the "
                    "shipped calibration (%% FS). Prints the rows, the Pareto front per case, the "
                    "one-time costs, and the speed-up at equal error and the seconds of a "
                    "41-element frame at the target error. The first run measures the two-stage "
                    "table and the references (minutes); later runs reuse them.")
    brender.add_argument("--spp", type=_positive_int, nargs="+", default=[16, 64, 256],
                         help="samples per pixel for brute and pixels (default 16 64 256)")
    brender.add_argument("--targets", type=float, nargs="+", default=[0.02, 0.01, 0.005],
                         help="target relative errors for adaptive (default 0.02 0.01 0.005)")
    brender.add_argument("--n-sub", type=_positive_int, nargs="+", default=[4, 8],
                         help="sub-pixel rays per side for two_stage (default 4 8)")
    brender.add_argument("--modes", nargs="+", choices=("brute", "pixels", "adaptive", "two_stage"),
                         default=["brute", "pixels", "adaptive", "two_stage"],
                         help="render modes (default all four)")
    brender.add_argument("--reference-spp", type=_positive_int, default=4096,
                         help="samples per pixel of the converged references (default 4096)")
    brender.add_argument("--cases", nargs="+", default=None,
                         help="load cases (default all: 1-light 1-heavy 5-light 5-heavy 41)")
    brender.add_argument("--repeats", type=_positive_int, default=1,
                         help="renders per row; medians and RMS over them (default 1)")
    brender.add_argument("--target", type=float, default=0.5,
                         help="force error (%% FS) for the headline figures (default 0.5)")
    brender.add_argument("--width", type=_positive_int, default=640)
    brender.add_argument("--height", type=_positive_int, default=480)
    brender.add_argument("--variant", default=None, help="Mitsuba variant (default: fastest)")
    brender.add_argument("--plot", type=Path, default=None, metavar="PLOT.png",
                         help="save error against time (log-log) per mode")
    brender.add_argument("--json", action="store_true",
                         help="print only the JSON object (the default output is JSON too)")
    bpipe = bsub.add_parser(
        "pipeline", help="frames/s of the fast and reference pipelines vs one pass over the frame",
        description="Render (once, then cached in the user cache folder) a frame with all 41 "
                    "elements loaded at each size, expose it with several noise seeds, and time "
                    "the fast pipeline frame by frame and as a batch, the reference pipeline, and "
                    "one pass over the frame (np.count_nonzero(frame > t)), side by side in each "
                    "repeat; report medians and the fast-vs-reference differences.")
    bpipe.add_argument("--size", nargs="+", default=["640x480", "480x480"], metavar="WxH",
                       help="frame sizes (default 640x480 480x480)")
    bpipe.add_argument("--frames", type=_positive_int, default=16,
                       help="distinct noisy frames per size (default 16)")
    bpipe.add_argument("--repeats", type=_positive_int, default=5,
                       help="timing repeats; medians are reported (default 5)")
    bpipe.add_argument("--spp", type=_positive_int, default=64,
                       help="samples per pixel of the renders (default 64)")
    bpipe.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    bpipe.add_argument("--variant", default=None, help="Mitsuba variant (default: fastest)")
    bpipe.add_argument("--json", action="store_true",
                       help="print only the JSON object (the default output is JSON too)")
    bacc = bsub.add_parser(
        "accuracy", help="force errors of both models on a held-out synthetic set",
        description="Fit both models on a calibration set and report force errors on a held-out "
                    "set (disjoint seeds, independent forces) at the nominal CCD noise. Sets "
                    "are generated once and cached in the user cache folder, or given.")
    bacc.add_argument("--frames", type=_positive_int, default=100,
                      help="calibration frames (default 100)")
    bacc.add_argument("--test-frames", type=_positive_int, default=30,
                      help="held-out frames (default 30)")
    bacc.add_argument("--spp", type=_positive_int, default=64,
                      help="samples per pixel of the calibration set (default 64)")
    bacc.add_argument("--test-spp", type=_positive_int, default=None,
                      help="samples per pixel of the held-out set (default: --spp); Monte Carlo "
                           "noise is the simulation's, not the sensor's")
    bacc.add_argument("--size", default="640x480", metavar="WxH", help="frame size (default 640x480)")
    bacc.add_argument("--render-mode", choices=("two_stage", "pixels", "full"), default="two_stage",
                      help="how the calibration frames are rendered (default two_stage)")
    bacc.add_argument("--test-render-mode", choices=("two_stage", "pixels", "full"), default="pixels",
                      help="how the held-out frames are rendered (default pixels: path-traced)")
    bacc.add_argument("--calibration-set", type=Path, default=None, metavar="SET.zarr",
                      help="use this calibration set instead of generating one")
    bacc.add_argument("--test-set", type=Path, default=None, metavar="SET.zarr",
                      help="use this held-out set instead of generating one")
    bacc.add_argument("--seed", type=_seed, default=0,
                      help="seed of the calibration set; the held-out set uses seed + 1000")
    bacc.add_argument("--variant", default=None, help="Mitsuba variant (default: fastest)")
    bacc.add_argument("--plot", type=Path, default=None, metavar="ERRORS.png",
                      help="save estimated vs true forces of both models as PNG")
    bacc.add_argument("--json", action="store_true",
                      help="print only the JSON object (the default output is JSON too)")
    bstab = bsub.add_parser(
        "stability", help="stress cases of every stage and the noise sweep against the Cramer-Rao bound",
        description="Run the generated stress cases (frames, readings at the edge, calibration files "
                    "and fits, accumulation, renderer inputs) and the Monte Carlo noise sweep of G "
                    "and u against the Cramer-Rao bound. Output: one JSON object with cases, "
                    "failures, noise_sweep and nominal.")
    bstab.add_argument("--cases", type=_positive_int, default=10000,
                       help="generated stress cases (default 10000)")
    bstab.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    bstab.add_argument("--json", action="store_true",
                       help="print only the JSON object (the default output is JSON too)")
    exp = sub.add_parser(
        "experiment", help="simulated experiments with the other tactile sensors and the robotic finger",
        description="Run one simulated experiment and print its figures as one JSON object: "
                    + "; ".join(f"{k}: {v[1]}" for k, v in EXPERIMENTS.items())
                    + ". Small sizes by default (seconds); --full runs the published sizes.")
    exp.add_argument("name", choices=sorted(EXPERIMENTS), help="which experiment")
    exp.add_argument("--full", action="store_true", help="full size (minutes) instead of a quick run")
    exp.add_argument("--seed", type=_seed, default=0, help="seed (default 0)")
    exp.add_argument("--plot", type=Path, default=None, metavar="PLOT.png", help="save the figures as PNG")
    exp.add_argument("--json", action="store_true",
                     help="print only the JSON object (the default output is JSON too)")
    return parser


#: ``optitact experiment NAME``: module (with ``experiment`` and ``plot_experiment``) and what it does.
EXPERIMENTS = {
    "tracing": ("optitact.taxels.tracing",
                "piezoresistive 16x16 finger pad, active tracing of pipes, diameter from the width"),
    "palpation": ("optitact.taxels.palpation",
                  "8x8 thread-electrode arrays on a gripper, DTW k-NN recognition of palpated objects"),
    "wire": ("optitact.taxels.optopad", "5x5 optoelectronic pad, wire shape and diameter"),
    "fingertip": ("optitact.taxels.fingertip",
                  "non-coplanar 25-unit fingertip, 3-D force decoupling and object recognition"),
    "finger": ("optitact.finger", "the dome sensor on a 3-DOF finger: friction, slip, contour tracing"),
}


def _experiment(args) -> int:
    import importlib
    import json

    module = importlib.import_module(EXPERIMENTS[args.name][0])
    result = module.experiment(seed=args.seed, full=args.full, progress=True)
    if args.plot is not None:
        module.plot_experiment(result, args.plot)
        result = {**result, "plot": str(args.plot)}
    print(json.dumps(result))
    return 0


def _size(text: str) -> tuple[int, int]:
    try:
        w, h = (int(v) for v in text.lower().split("x"))
    except ValueError:
        raise ValueError(f"--size must look like 640x480 (WIDTHxHEIGHT), got {text!r}") from None
    return w, h


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


def _estimate(sensor: DomeSensor, r: dict, args) -> dict | None:
    """Demo step 2: no-load baseline (cached render), pipeline and the shipped calibration."""
    from ._cache import cached_render
    from .calib import default_calibration

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
        from .forces import ForceField

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


def _load_baseline(path: Path) -> np.ndarray:
    from .frames import expand_sources, iter_frames

    frames = [f for _, f in iter_frames(expand_sources([path]))]
    return np.stack(frames)


def _process(args) -> int:
    from tqdm import tqdm

    from .frames import count_frames, expand_sources, iter_frames
    from .io import ReadingsWriter
    from .pipeline import Pipeline

    files = expand_sources(args.frames)
    total = count_frames(files)
    frames = iter_frames(files)
    first = next(frames, None)
    if first is None:
        raise ValueError("the frames hold no frame")
    if args.setup is not None:
        import json

        setup = json.loads(args.setup.read_text())
        if not isinstance(setup, dict) or "sensor" not in setup or "camera" not in setup:
            raise ValueError(f"{args.setup}: expected a JSON object with 'sensor' and 'camera'")
        sensor = DomeSensor.from_dict(setup["sensor"])
        camera = FisheyeCamera.from_dict(setup["camera"])
    else:
        sensor = DomeSensor.default()
        h, w = first[1].shape[:2]
        camera = FisheyeCamera(width=w, height=h, fov_deg=args.fov, z=args.camera_z)
    given = {k: v for k, v in (("filter", args.filter), ("filter_size", args.filter_size),
                                 ("noise_sigma", args.noise_sigma), ("k", args.k)) if v is not None}
    baseline = None if args.baseline is None else _load_baseline(args.baseline)
    cal = None
    if args.calibration is not None:
        from .calib import Calibration, default_calibration

        cal = (default_calibration() if str(args.calibration) == "default"
               else Calibration.load(args.calibration))
        if given:
            raise ValueError(f"the calibration fixes the pipeline options "
                             f"({cal.pipeline_options}); drop {', '.join(sorted(given))}")
        cal.check(sensor=sensor if args.setup is not None else None,
                  camera=camera if args.setup is not None else None)
        if first[1].shape[:2] != cal.camera.shape:
            from .calib import CalibrationMismatchError

            raise CalibrationMismatchError(
                f"{first[0]}: the calibration (fingerprint {cal.fingerprint}) is for "
                f"{cal.camera.width}x{cal.camera.height} frames, got "
                f"{first[1].shape[1]}x{first[1].shape[0]}")
        sensor, camera = cal.sensor, cal.camera
        pipe = cal.pipeline(baseline=baseline, method=args.method)
    elif args.plot is not None:
        raise ValueError("--plot needs --calibration (it plots estimated forces)")
    else:
        pipe = Pipeline(sensor, camera, baseline=baseline, method=args.method, **given)
    n_base = 0 if baseline is not None else args.baseline_frames
    how = (f"baseline {args.baseline}" if baseline is not None else
           f"baseline = mean of the first {n_base} frame(s)" if n_base else "no baseline")
    print(f"optitact: processing {camera.width}x{camera.height} frames, {how}", file=sys.stderr)

    def stream():
        yield first
        yield from frames

    if args.scheduler is not None:
        if n_base and pipe.baseline is None:
            base = [f for _, f in itertools.islice(stream(), n_base)]
            if len(base) < n_base:
                raise ValueError(f"the frames end after {len(base)}, before the {n_base} baseline frames")
            pipe = pipe.with_baseline(np.stack(base))
        return _process_distributed(args, files, pipe, cal, camera, total)
    t0 = time.perf_counter()
    held: list[tuple[str, np.ndarray]] = []
    last: dict = {}
    with ReadingsWriter(args.out, forces=cal is not None) as out, \
            tqdm(total=total, unit="frame", desc="process", file=sys.stderr) as bar:
        def flush():
            names = [n for n, _ in held]
            stack = np.stack([f for _, f in held])
            r = pipe.process(stack)
            if cal is None:
                out.write(r, names)
            else:
                f, clamped = cal.forces(r)
                out.write(r, names, f, clamped)
                last.update(frame=stack[-1], readings=r[-1])
            bar.update(len(held))
            held.clear()

        for name, frame in stream():
            if frame.shape != camera.shape:
                raise ValueError(f"{name}: expected a {camera.height}x{camera.width} frame for "
                                 f"this camera, got {frame.shape}")
            held.append((name, frame))
            if n_base and pipe.baseline is None:
                if len(held) == n_base:
                    pipe = pipe.with_baseline(np.stack([f for _, f in held]))
                    flush()
                continue
            if len(held) >= args.batch:
                flush()
        if n_base and pipe.baseline is None:
            raise ValueError(f"the frames end after {len(held)}, before the {n_base} baseline "
                             f"frames")
        if held:
            flush()
        n = out.frames
    seconds = time.perf_counter() - t0
    if args.plot is not None and last:
        field = cal.apply(last["readings"])
        field.save_plot(args.plot, last["frame"], camera,
                        title="estimated forces (last frame)")
        print(f"optitact: wrote the force-field plot of the last frame to {args.plot}",
              file=sys.stderr)
    print(f"optitact: wrote {'forces' if cal else 'readings'} of {n} frames to {args.out} "
          f"({n / max(seconds, 1e-9):.0f} frames/s including reading)", file=sys.stderr)
    return 0


def _read_file(pipe, cal, path, batch: int, shape) -> list:
    """Readings (and forces) of every frame of one file: a task of ``process --scheduler``."""
    from .frames import iter_frames

    out, held = [], []

    def flush():
        stack = np.stack([f for _, f in held])
        r = pipe.process(stack)
        f = cal.forces(r) if cal is not None else (None, None)
        out.append(([n for n, _ in held], r, *f))
        held.clear()

    for name, frame in iter_frames([path]):
        if frame.shape != shape:
            raise ValueError(f"{name}: expected a {shape[0]}x{shape[1]} frame for this camera, "
                             f"got {frame.shape}")
        held.append((name, frame))
        if len(held) >= batch:
            flush()
    if held:
        flush()
    return out


def _process_distributed(args, files, pipe, cal, camera, total) -> int:
    """``optitact process --scheduler``: one task per file on a Dask cluster, rows written here in order."""
    from distributed import Client
    from tqdm import tqdm

    from .io import ReadingsWriter

    t0 = time.perf_counter()
    with Client(args.scheduler) as client, ReadingsWriter(args.out, forces=cal is not None) as out, \
            tqdm(total=total, unit="frame", desc="process", file=sys.stderr) as bar:
        [p] = client.scatter([pipe], broadcast=True, hash=False)
        futures = [client.submit(_read_file, p, cal, f, args.batch, camera.shape, retries=3, pure=False)
                   for f in files]
        for fut in futures:  # in file order: the CSV is the same as a local run's
            for names, r, forces, clamped in fut.result():
                if cal is None:
                    out.write(r, names)
                else:
                    out.write(r, names, forces, clamped)
                bar.update(len(names))
        n = out.frames
    seconds = time.perf_counter() - t0
    print(f"optitact: wrote {'forces' if cal else 'readings'} of {n} frames to {args.out} "
          f"({n / max(seconds, 1e-9):.0f} frames/s on the cluster, including reading)", file=sys.stderr)
    return 0


def _calibrate(args) -> int:
    from .calib import Design, fit, generate

    if args.calibrate == "generate":
        design = Design(fz_max=args.fz_max, shear_max=args.shear_max, mu_max=args.mu_max)
        cs = generate(args.out, frames=args.frames, camera=FisheyeCamera(width=args.width,
                                                                        height=args.height),
                      spp=args.spp, seed=args.seed, design=design, keep_frames=args.keep_frames,
                      variant=args.variant, render_mode=args.render_mode, scheduler=args.scheduler)
        print(f"optitact: calibration set {args.out}: {int(cs.done.sum())} of {len(cs)} frames "
              f"done", file=sys.stderr)
        print(args.out)
        return 0
    cal = fit(args.set, model=args.model)
    cal.save(args.out)
    r = cal.residuals
    print(f"optitact: fitted {args.model} on {int(np.sum(r['n']))} samples; median RMS residual "
          f"Fx {np.median(r['fx']):.4f} N, Fy {np.median(r['fy']):.4f} N, Fz {np.median(r['fz']):.4f} "
          f"N; wrote {args.out}", file=sys.stderr)
    if args.plot is not None:
        from .calib import CalibrationSet
        from .calib.plots import plot_fit

        cs = CalibrationSet(args.set)
        plot_fit(cal, cs.readings(), cs.forces(), args.plot)
        print(f"optitact: wrote {args.plot}", file=sys.stderr)
    print(args.out)
    return 0


def _bench(args) -> int:
    import json

    from .bench import bench_pipeline, bench_render

    if args.bench == "stability":
        from .stability import run_stability

        print(json.dumps(run_stability(n_cases=args.cases, seed=args.seed, progress=True)))
        return 0
    if args.bench == "accuracy":
        from .bench import bench_accuracy

        result = bench_accuracy(frames=args.frames, test_frames=args.test_frames, spp=args.spp,
                                test_spp=args.test_spp, size=_size(args.size),
                                calibration_set=args.calibration_set,
                                test_set=args.test_set, seed=args.seed, variant=args.variant,
                                plot=args.plot, render_mode=args.render_mode,
                                test_render_mode=args.test_render_mode)
    elif args.bench == "pipeline":
        result = bench_pipeline([_size(s) for s in args.size], n_frames=args.frames,
                                repeats=args.repeats, spp=args.spp, seed=args.seed,
                                variant=args.variant)
    else:
        result = bench_render(tuple(args.spp), modes=tuple(args.modes), targets=tuple(args.targets),
                              n_subs=tuple(args.n_sub), reference_spp=args.reference_spp, width=args.width,
                              height=args.height, repeats=args.repeats, cases=args.cases,
                              target_pct_fs=args.target, variant=args.variant, plot=args.plot)
    print(json.dumps(result))
    return 0


def main(argv: list[str] | None = None) -> int:
    """Run the ``optitact`` command; returns the exit code."""
    parser = _parser()
    args = parser.parse_args(argv)
    try:
        commands = {"demo": _demo, "render": _render, "process": _process,
                    "calibrate": _calibrate, "bench": _bench, "experiment": _experiment}
        return commands[args.command](args)
    except (ValueError, TypeError, OSError) as exc:
        print(f"optitact: error: {exc}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
