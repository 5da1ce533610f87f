"""``optitact calibrate generate|fit``: synthetic calibration sets and fitted curves."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from ._args import image_size_parent, plot_parent, positive_int, render_mode_choices, seed_parent, spp_parent, \
    variant_parent

__all__ = ["add_parsers"]


def add_parsers(sub) -> None:
    """Add ``calibrate`` (with ``generate`` and ``fit``) to the subcommands."""
    cal = sub.add_parser(
        "calibrate", help="synthetic calibration sets and fitted curves",
        description="Generate a synthetic calibration set (rendered frames with known forces, "
                    "resumable) and fit calibration curves to it.")
    csub = cal.add_subparsers(dest="calibrate", required=True, metavar="STEP",
                              help="generate a set, or fit curves to one")
    gen = csub.add_parser(
        "generate", parents=[spp_parent(64), seed_parent("seed of the whole set"), image_size_parent(),
                             variant_parent()],
        help="render a calibration set into a Zarr store (resumable)",
        description="Render FRAMES frames, each loading all 41 elements with independent forces "
                    "(Sobol design plus pure-normal and pure-shear sweeps), read them with the "
                    "pipeline and store readings, true forces, seeds and settings in a Zarr "
                    "store. Killing the job and running the same command again finishes the set, "
                    "identical to an uninterrupted run. Progress bar with frames/s and ETA on "
                    "stderr.")
    gen.add_argument("--frames", type=positive_int, default=200, help="frames (default 200)")
    gen.add_argument("--out", type=Path, required=True, metavar="SET.zarr", help="the store")
    gen.add_argument("--fz-max", type=float, default=1.0, help="largest normal force, N (default 1)")
    gen.add_argument("--shear-max", type=float, default=0.5,
                     help="largest shear magnitude, N (default 0.5)")
    gen.add_argument("--mu-max", type=float, default=0.35,
                     help="largest shear/normal ratio (default 0.35; the feeler tips at ~0.37)")
    gen.add_argument("--keep-frames", action="store_true", help="also store the frames")
    gen.add_argument("--render-mode", choices=render_mode_choices(), default="two_stage",
                     help="two_stage (default): guided light from a table (shipped for the default "
                          "camera, else measured once and cached, announced with its time), patches "
                          "traced as emitters, ~0.05 s/frame, no Monte Carlo "
                          "noise; pixels: path-trace only the pixels the pipeline reads; full: "
                          "path-trace whole frames (--spp applies to path tracing and the baseline)")
    gen.add_argument("--table-spp", type=positive_int, default=None, metavar="N",
                     help="two_stage: samples per pixel of the one-time emission table measured for a "
                          "sensor or camera that has none shipped (the default 640x480 camera's ships "
                          "with optitact, measured at 4096; another N measures a new one; default "
                          "4096, 11 min on 2 busy CPU cores). Fewer samples are faster (not "
                          "proportionally) and cost accuracy: error of an element's G against the "
                          "4096-spp table, median (95th percentile), 1.0 %% (3.5 %%) at 256, 0.5 %% "
                          "(1.8 %%) at 512, 0.5 %% (1.3 %%) at 1024")
    gen.add_argument("--scheduler", default=None, metavar="ADDRESS",
                     help="run the frames on a Dask distributed cluster (scheduler address, e.g. "
                          "tcp://host:8786); the set is identical to a local one (default: here)")
    gen.set_defaults(run=run_generate)
    fitp = csub.add_parser(
        "fit", parents=[plot_parent("save g(G), the shear curves and residuals as PNG")],
        help="fit calibration curves to a set",
        description="Fit per-element curves Fz = g(G) and the shear curves (model ohka: "
                    "Fx = f(ux), Fy = f(uy); model coupled: (Fx, Fy) = u g(G) / (a + b sqrt(g(G))))"
                    " to a calibration set and write them as JSON; --plot saves the curves with "
                    "their residuals.")
    fitp.add_argument("set", type=Path, metavar="SET.zarr", help="a calibration set")
    fitp.add_argument("--model", choices=("ohka", "coupled"), default="coupled",
                      help="curve model (default coupled)")
    fitp.add_argument("--out", type=Path, required=True, metavar="CAL.json",
                      help="the calibration file to write")
    fitp.add_argument("--partial", action="store_true",
                      help="fit the finished frames of an incomplete set (a killed or running generate); "
                           "without it an incomplete set is refused with how many frames are done")
    fitp.set_defaults(run=run_fit)


def run_generate(args) -> int:
    """``optitact calibrate generate``: prints the store's path on stdout."""
    from optitact.calib import Design, generate
    from optitact.camera import FisheyeCamera

    design = Design(fz_max=args.fz_max, shear_max=args.shear_max, mu_max=args.mu_max)
    cs = generate(args.out, frames=args.frames, camera=FisheyeCamera(width=args.width, height=args.height),
                  spp=args.spp, seed=args.seed, design=design, keep_frames=args.keep_frames,
                  variant=args.variant, render_mode=args.render_mode, scheduler=args.scheduler,
                  table_spp=args.table_spp)
    print(f"optitact: calibration set {args.out}: {int(cs.done.sum())} of {len(cs)} frames "
          f"done", file=sys.stderr)
    print(args.out)
    return 0


def run_fit(args) -> int:
    """``optitact calibrate fit``: prints the calibration's path on stdout."""
    from optitact.calib import fit

    cal = fit(args.set, model=args.model, partial=args.partial)
    cal.save(args.out)
    r = cal.residuals
    prov = cal.provenance
    print(f"optitact: fitted {args.model} on {int(np.sum(r['n']))} samples from {prov['frames']} of "
          f"{prov['frames_in_set']} frames; median RMS residual "
          f"Fx {np.median(r['fx']):.4f} N, Fy {np.median(r['fy']):.4f} N, Fz {np.median(r['fz']):.4f} "
          f"N; wrote {args.out}", file=sys.stderr)
    if args.plot is not None:
        from optitact.calib import CalibrationSet
        from optitact.calib.plots import plot_fit

        cs = CalibrationSet(args.set)
        plot_fit(cal, cs.readings(), cs.forces(), args.plot)
        print(f"optitact: wrote {args.plot}", file=sys.stderr)
    print(args.out)
    return 0
