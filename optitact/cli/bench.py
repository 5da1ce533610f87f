"""``optitact bench render|pipeline|accuracy|stability|realism|process|live|drift``: one JSON object on stdout.

The benchmarks themselves live in the studies layer (:mod:`optitact.studies`),
imported when a bench runs.
"""

from __future__ import annotations

import json
from pathlib import Path

from optitact.cli._args import (image_size_parent, int_at_least, pattern_choices, plot_parent, positive_int,
                                seed_parent, size, variant_parent)

#: argparse %-formats help strings (``%%`` is a literal ``%``) but prints descriptions as they are:
#: a description must write ``%``, a help string ``%%``.

__all__ = ["add_parsers"]


def add_parsers(sub) -> None:
    """Add ``bench`` (render, pipeline, accuracy, stability) to the subcommands."""
    bench = sub.add_parser(
        "bench", help="benchmarks (time side by side with error)",
        description="Benchmarks that report run time together with the error it buys; "
                    "medians over repeats in one run. Output: one JSON object on stdout.")
    bsub = bench.add_subparsers(dest="bench", required=True, metavar="BENCH", help="which benchmark")
    brender = bsub.add_parser(
        "render", parents=[image_size_parent(), variant_parent(),
                           plot_parent("save error against time (log-log) per mode")],
        help="render time against the error it leaves, per mode and setting",
        description="For fixed load cases (1, 5 and 41 loaded elements, light and heavy), render "
                    "with each mode (brute: path-traced full frames; pixels: path-traced, only the "
                    "pixels the pipeline reads for the loaded elements, over the cached no-load "
                    "frame; adaptive: pixels with passes until each element reaches a target "
                    "relative standard error; two_stage: guided light to the patches from a cached "
                    "table, patches traced in closed form as emitters) at several settings, and "
                    "compare the readings with a converged reference (cached on disk after the "
                    "first run): G relative error, u error (mm) and the force error through the "
                    "shipped calibration (% FS). Prints the rows, the Pareto front per case, the "
                    "one-time costs, and the speed-up at equal error and the seconds of a "
                    "41-element frame at the target error. The first run measures the two-stage "
                    "table and the references (minutes); later runs reuse them.")
    brender.add_argument("--spp", type=positive_int, nargs="+", default=[16, 64, 256],
                         help="samples per pixel for brute and pixels (default 16 64 256)")
    brender.add_argument("--targets", type=float, nargs="+", default=[0.02, 0.01, 0.005],
                         help="target relative errors for adaptive (default 0.02 0.01 0.005)")
    brender.add_argument("--n-sub", type=positive_int, nargs="+", default=[4, 8],
                         help="sub-pixel rays per side for two_stage (default 4 8)")
    brender.add_argument("--modes", nargs="+", choices=("brute", "pixels", "adaptive", "two_stage"),
                         default=["brute", "pixels", "adaptive", "two_stage"],
                         help="render modes (default all four)")
    brender.add_argument("--reference-spp", type=positive_int, default=4096,
                         help="samples per pixel of the converged references (default 4096)")
    brender.add_argument("--cases", nargs="+", default=None,
                         help="load cases (default all: 1-light 1-heavy 5-light 5-heavy 41)")
    brender.add_argument("--repeats", type=positive_int, default=1,
                         help="renders per row; medians and RMS over them (default 1)")
    brender.add_argument("--target", type=float, default=0.5,
                         help="force error (%% FS) for the headline figures (default 0.5)")
    bpipe = bsub.add_parser(
        "pipeline", parents=[seed_parent()],
        help="per-frame cost of the fast and reference pipelines vs one pass over the frame",
        description="At each size and number of loaded elements, render a frame two-stage (the contact "
                    "patches over a dark background, milliseconds), expose it with several noise seeds, "
                    "and time side by side in each repeat: the fast pipeline frame by frame (compiled "
                    "kernel and NumPy fallback; warm, after five untimed passes as on a stream, and its "
                    "first pass after the long stacks), a long stack on one thread and on every core, one "
                    "pass over the frame (np.count_nonzero(frame > t)) frame by frame and over the stack, "
                    "and the reference; report CPU and wall medians per frame, the ratios to one pass, the "
                    "fast-vs-reference differences, the precompute cold and cached and the start-up "
                    "to a first frame. One JSON object on stdout.")
    bpipe.add_argument("--size", nargs="+", default=["320x240", "640x480", "1280x960", "1920x1440"],
                       metavar="WxH", help="frame sizes (default 320x240 640x480 1280x960 1920x1440)")
    bpipe.add_argument("--loads", nargs="+", type=int, choices=(1, 5, 41), default=[1, 5, 41],
                       help="elements loaded (default 1 5 41)")
    bpipe.add_argument("--frames", type=positive_int, default=16,
                       help="distinct noisy frames per size and load (default 16)")
    bpipe.add_argument("--repeats", type=positive_int, default=5,
                       help="timing repeats; medians are reported (default 5)")
    bpipe.add_argument("--no-startup", dest="startup", action="store_false",
                       help="skip the start-up timing (a fresh optitact process per size)")
    bacc = bsub.add_parser(
        "accuracy", parents=[seed_parent("seed of the calibration set; the held-out set uses seed + 1000"),
                             variant_parent(),
                             plot_parent("save estimated vs true forces of both models as PNG")],
        help="force errors of both models on a held-out synthetic set",
        description="Fit both models on a calibration set and report force errors on a held-out "
                    "set (disjoint seeds, independent forces) at the nominal CCD noise. Sets "
                    "are generated once and cached in the user cache folder, or given.")
    bacc.add_argument("--frames", type=positive_int, default=100,
                      help="calibration frames (default 100)")
    bacc.add_argument("--test-frames", type=positive_int, default=30,
                      help="held-out frames (default 30)")
    bacc.add_argument("--single-frames", type=positive_int, default=None, metavar="N",
                      help="frames of the single family's held-out set, one element loaded in each "
                           "(default 30 x --test-frames: about as many samples as a family loading all)")
    bacc.add_argument("--spp", type=positive_int, default=64,
                      help="samples per pixel of the calibration set (default 64)")
    bacc.add_argument("--test-spp", type=positive_int, default=None,
                      help="samples per pixel of the held-out set (default: --spp); Monte Carlo "
                           "noise is the simulation's, not the sensor's")
    bacc.add_argument("--size", default="640x480", metavar="WxH", help="frame size (default 640x480)")
    bacc.add_argument("--render-mode", choices=("two_stage", "pixels", "full"), default="two_stage",
                      help="how the calibration frames are rendered (default two_stage)")
    bacc.add_argument("--test-render-mode", choices=("two_stage", "pixels", "full"), default="pixels",
                      help="how the held-out frames are rendered (default pixels: path-traced)")
    bacc.add_argument("--calibration-set", type=Path, default=None, metavar="SET.zarr",
                      help="use this calibration set instead of generating one")
    bacc.add_argument("--design-pattern", choices=pattern_choices(), default="blend",
                      help="load pattern of the calibration set (default blend: every family in turn, so "
                           "that the joint model sees the cross-talk between elements)")
    bacc.add_argument("--families", nargs="+", default=None, metavar="FAMILY",
                      help="load-pattern families of the held-out sets, each its own set: independent, "
                           "uniform, single, clustered, checkerboard, shear, or all (default: all)")
    bacc.add_argument("--validation-frames", type=int, default=60, metavar="N",
                      help="frames of the validation set (rendered like the held-out sets, blend pattern, "
                           "seed + 900) on which each model's own error is measured for the error bars; 0: "
                           "none (default 60: ten frames of each family)")
    bacc.add_argument("--floor-frames", type=int, default=4, metavar="N",
                      help="frames of each held-out set rendered again with other seeds, for each model's "
                           "error floor there: the RMSE a perfect calibration would show on those frames "
                           "(the single family: 10 x N; 0: none; default 4)")
    bacc.add_argument("--test-set", type=Path, default=None, metavar="SET.zarr",
                      help="use this held-out set instead of generating one")
    bstab = bsub.add_parser(
        "stability", parents=[seed_parent()],
        help="stress cases of every stage and the noise sweep against the Cramer-Rao bound",
        description="Run the generated stress cases (frames, readings at the edge, calibration files "
                    "and fits, accumulation, renderer inputs) and the Monte Carlo noise sweep of G "
                    "and u against the Cramer-Rao bound. Output: one JSON object with cases, "
                    "failures, noise_sweep and nominal.")
    bstab.add_argument("--cases", type=positive_int, default=10000,
                       help="generated stress cases (default 10000)")

    breal = bsub.add_parser(
        "realism", parents=[seed_parent("seed of the first stand-in sensor"), variant_parent(),
                            plot_parent("save force errors against presses and registration errors as PNG")],
        help="a stand-in for a real sensor: registration and press calibrations against its own floor",
        description="Draw stand-in sensors with manufacturing and assembly errors the code under test is not "
                    "told (camera off axis and tilted, focal length, principal point, fisheye distortion, "
                    "dome radius and shell, element positions and brightness, non-uniform rim light), render "
                    "their frames (two-stage, their own camera), register each one from a no-load frame "
                    "and six frames of equal presses, and report the pose, focal length, offset and gain "
                    "errors against the hidden truth. On the first --force-sensors of them, report held-out "
                    "force errors (RMSE in % of full scale per axis) with the nominal model and the shipped "
                    "calibration, after registration, after calibrations from N gauge presses per element "
                    "(each element's own shape refined from the shipped one, the earlier group refinement, and "
                    "from scratch), after calibrations fitted to a force/torque sensor's totals of N frames of "
                    "objects pressed on the dome, and with the stand-in's own synthetic calibration (the "
                    "matched floor), with the 90 % interval coverage of each calibration's own error model. "
                    "The stand-ins have, switchable, physics the package does not model: per-element rubber "
                    "stiffness and nonlinearity, lens blur, vignetting and pixel response non-uniformity. "
                    "The first run path-traces the no-load frame of the "
                    "default camera once (about a minute, cached); then about a minute per force stand-in.")
    breal.add_argument("--sensors", type=positive_int, default=10,
                       help="stand-ins registered (default 10)")
    breal.add_argument("--force-sensors", type=int, default=2,
                       help="of those, how many get the force study (default 2)")
    breal.add_argument("--presses", type=positive_int, nargs="+", default=[2, 5, 10, 20], metavar="N",
                       help="presses per element of the measured calibrations (default 2 5 10 20)")
    breal.add_argument("--wrench-frames", type=positive_int, nargs="*", default=[50, 100, 200, 400],
                       metavar="N",
                       help="frames of the wrench protocol (random objects pressed near every element in turn, "
                            "a six-axis F/T sensor's totals with 0.5 %% noise, no single-element presses) "
                            "of the "
                            "calibrations fitted to totals (default 50 100 200 400; none: skip)")
    breal.add_argument("--effects", nargs="*", default=None, metavar="EFFECT",
                       help="physics of a real sensor the package does not model, in the stand-ins: any of "
                            "stiffness, nonlinearity, blur, vignetting, prnu (default all; none: give the "
                            "option alone)")
    breal.add_argument("--test-frames", type=positive_int, default=40,
                       help="held-out frames per stand-in, every element loaded (default 40)")
    breal.add_argument("--size", default="640x480", metavar="WxH", help="frame size (default 640x480)")

    bproc = bsub.add_parser(
        "process", parents=[seed_parent()],
        help="optitact process on a whole video against decoding the video alone",
        description="Make a recording of the dome once per size and codec (two-stage renders exposed by the "
                    "CCD model, a no-load stretch then all 41 elements loaded; kept in the cache folder), "
                    "then time side by side in each repeat three fresh processes on it: optitact process "
                    "(with the shipped calibration at its camera's size, readings alone elsewhere), the "
                    "decode loop a user would write (cv2.VideoCapture read + cvtColor) and that loop run "
                    "as process reads frames (OpenCV's worker pool off, one OpenBLAS thread, grey video "
                    "read as grey and Motion JPEG as its luma plane). Reports "
                    "median wall and CPU seconds (the OS's accounting of each child) and the medians of "
                    "the per-repeat ratios. One JSON object on stdout.")
    bproc.add_argument("--size", nargs="+", default=["640x480", "1280x960"], metavar="WxH",
                       help="frame sizes (default 640x480 1280x960)")
    bproc.add_argument("--codec", nargs="+", choices=("MJPG", "FFV1"), default=["MJPG"],
                       help="video codecs (default MJPG: what USB cameras record)")
    bproc.add_argument("--frames", type=int_at_least(6, "an integer >= 6"), default=500,
                       help="frames per recording (default 500)")
    bproc.add_argument("--repeats", type=positive_int, default=5,
                       help="timed runs of each command; medians are reported (default 5)")

    blive = bsub.add_parser(
        "live", parents=[seed_parent(), plot_parent("save the latencies and dropped frames per rate")],
        help="live stream latency and dropped frames, with and without the viewer and the recorder",
        description="Play a lossless video of analytic contact spots (the shipped calibration's 640x480 "
                    "camera) at each frame rate, as a camera's driver hands frames over, through the loop of "
                    "optitact process --camera (newest-frame policy, drift tracking, the rows written), "
                    "alone, with the Rerun view (logged to an .rrd file), with the MCAP recorder (lossless "
                    "frames) and with both, side by side in one run. Reports per rate and configuration "
                    "the median and 99th-percentile latency from capture to forces and from capture to the "
                    "viewer's SDK (ms), frames processed and dropped, CPU ms per frame and bytes per frame "
                    "written; and the pipeline and forces alone on the same frames. Needs the live extra "
                    "for the viewer and recorder rows. One JSON object on stdout.")
    blive.add_argument("--rates", type=float, nargs="+", default=[30.0, 60.0, 120.0], metavar="FPS",
                       help="frame rates to play the video at (default 30 60 120)")
    blive.add_argument("--seconds", type=float, default=10.0,
                       help="seconds per run (default 10)")
    blive.add_argument("--configs", nargs="+", default=None,
                       choices=("forces", "forces + viewer", "forces + recorder", "forces + viewer + recorder"),
                       metavar="CONFIG",
                       help="which of: 'forces', 'forces + viewer', 'forces + recorder', "
                            "'forces + viewer + recorder' (default all)")

    bdrift = bsub.add_parser(
        "drift", parents=[seed_parent(), plot_parent("save the Fz error and contact flags over time")],
        help="an hour of drift read with a fixed baseline and with drift tracking",
        description="Simulate an hour of a sensor at work (frames of analytic spots consistent with a "
                    "calibration, over the no-load light): the rim light drifting -3 %% over the hour, a "
                    "black-level step of +2 DN at 20 minutes, the camera creeping 0.3 px, random contacts "
                    "about a third of the time including a press held for 5 minutes, read noise and 8-bit "
                    "frames. Reads it three ways on the same seed: without drift, with drift and a fixed "
                    "baseline, with drift and drift tracking (optitact.pipeline.drift). Reports Fz, Fx, Fy "
                    "RMSE (N and %% of 1 N), false and missed contacts, the error per time bin, the ratio "
                    "tracked / no drift and what tracking prevents. One JSON object on stdout."
                    .replace("%%", "%"))
    bdrift.add_argument("--minutes", type=float, default=60.0, help="length of the run (default 60)")
    bdrift.add_argument("--fps", type=float, default=1.0, help="frames per second (default 1)")
    bdrift.add_argument("--size", default="320x240", metavar="WxH", help="frame size (default 320x240)")
    bdrift.add_argument("--baseline-frames", type=positive_int, default=64,
                        help="no-load frames averaged into the baseline (default 64)")

    for name, p in (("render", brender), ("pipeline", bpipe), ("accuracy", bacc), ("stability", bstab),
                    ("realism", breal), ("process", bproc), ("live", blive), ("drift", bdrift)):
        p.add_argument("--json", action="store_true",
                       help="print the result as one JSON object on stdout (what every bench prints; "
                            "the flag is accepted so that scripts can say so)")
        p.set_defaults(run=BENCHES[name])


def _render(args) -> dict:
    from optitact.studies.bench_render import bench_render

    return bench_render(tuple(args.spp), modes=tuple(args.modes), targets=tuple(args.targets),
                        n_subs=tuple(args.n_sub), reference_spp=args.reference_spp, width=args.width,
                        height=args.height, repeats=args.repeats, cases=args.cases,
                        target_pct_fs=args.target, variant=args.variant, plot=args.plot)


def _pipeline(args) -> dict:
    from optitact.studies.bench_pipeline import bench_pipeline

    return bench_pipeline([size(s) for s in args.size], loads=args.loads, n_frames=args.frames,
                          repeats=args.repeats, seed=args.seed, startup=args.startup)


def _process(args) -> dict:
    from optitact.studies.bench_process import bench_process

    return bench_process([size(s) for s in args.size], codecs=tuple(args.codec), frames=args.frames,
                         repeats=args.repeats, seed=args.seed)


def _accuracy(args) -> dict:
    from optitact.calib.patterns import FAMILIES
    from optitact.studies.bench_accuracy import bench_accuracy

    if args.families is None:
        families = ("independent",) if args.test_set is not None else FAMILIES
    else:
        families = FAMILIES if "all" in args.families else tuple(args.families)
    return bench_accuracy(families=families, frames=args.frames, test_frames=args.test_frames, spp=args.spp,
                          test_spp=args.test_spp, size=size(args.size),
                          calibration_set=args.calibration_set, test_set=args.test_set, seed=args.seed,
                          variant=args.variant, plot=args.plot, render_mode=args.render_mode,
                          test_render_mode=args.test_render_mode, design_pattern=args.design_pattern,
                          validation_frames=args.validation_frames, single_frames=args.single_frames,
                          floor_frames=args.floor_frames)


def _stability(args) -> dict:
    from optitact.studies.bench_stability import bench_stability

    return bench_stability(cases=args.cases, seed=args.seed, progress=True)


def _realism(args) -> dict:
    from optitact.studies.bench_realism import bench_realism

    if args.force_sensors < 0 or args.force_sensors > args.sensors:
        from optitact.errors import InputError

        raise InputError(f"--force-sensors must be from 0 to --sensors ({args.sensors}), got "
                         f"{args.force_sensors}")
    from optitact.studies.bench_realism import EFFECTS

    effects = EFFECTS if args.effects is None else tuple(args.effects)
    bad = [e for e in effects if e not in EFFECTS]
    if bad:
        from optitact.errors import InputError

        raise InputError(f"--effects: unknown {', '.join(bad)}; valid: {', '.join(EFFECTS)}")
    return bench_realism(sensors=args.sensors, force_sensors=args.force_sensors, ns=tuple(args.presses),
                         test_frames=args.test_frames, size=size(args.size), seed=args.seed,
                         variant=args.variant, plot=args.plot, effects=effects,
                         wrench_counts=tuple(args.wrench_frames))


def _live(args) -> dict:
    from optitact.studies.bench_live import bench_live

    return bench_live(rates=tuple(args.rates), seconds=args.seconds, configs=args.configs, seed=args.seed,
                      plot=args.plot)


def _drift(args) -> dict:
    from optitact.studies.bench_drift import drift_hour

    width, height = size(args.size)
    return drift_hour(minutes=args.minutes, fps=args.fps, width=width, height=height, seed=args.seed,
                      progress=True, plot=args.plot, baseline_frames=args.baseline_frames)


def _printing(bench):
    def run(args) -> int:
        if getattr(args, "plot", None) is not None:  # before minutes of work, not after
            from optitact._optional import require

            require("matplotlib.figure", purpose="--plot")
        print(json.dumps(bench(args)))
        return 0

    run.__doc__ = f"Print the JSON result of {bench.__name__[1:]} (``optitact bench``)."
    return run


#: ``optitact bench NAME`` -> the command.
BENCHES = {"render": _printing(_render), "pipeline": _printing(_pipeline), "accuracy": _printing(_accuracy),
           "stability": _printing(_stability), "realism": _printing(_realism), "process": _printing(_process),
           "live": _printing(_live), "drift": _printing(_drift)}
