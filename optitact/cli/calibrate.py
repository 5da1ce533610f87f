"""``optitact calibrate generate|fit|test|noise``: calibration sets, fitted curves, held-out reports, noise."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from optitact.errors import InputError

from optitact.cli._args import (calibration_on_setup, check_frame_size, image_size_parent, int_at_least,
                                out_file, pattern_choices, plot_parent, positive_int, render_mode_choices,
                                seed_parent, spp_parent, variant_parent)

__all__ = ["add_parsers"]


def add_parsers(sub) -> None:
    """Add ``calibrate`` (with ``generate``, ``fit``, ``test`` and ``noise``) to the subcommands."""
    cal = sub.add_parser(
        "calibrate", help="synthetic calibration sets and fitted curves",
        description="Generate a synthetic calibration set (rendered frames with known forces, "
                    "resumable) and fit calibration curves to it or to frames of your own presses; "
                    "test a calibration on held-out presses; measure the camera's pixel noise.")
    csub = cal.add_subparsers(dest="calibrate", required=True, metavar="STEP",
                              help="generate a set, fit curves (to a set or to measured presses), "
                                   "test a calibration, or measure the camera's noise")
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
    gen.add_argument("--setup", type=Path, default=None, metavar="SETUP.json",
                     help="the sensor and camera of a setup file (e.g. from optitact register): a set "
                          "for your registered sensor (any camera model renders two-stage, with the "
                          "shipped emission table and its element gains); --width/--height do not apply")
    gen.add_argument("--pattern", choices=pattern_choices(), default="independent",
                     help="how loads spread over the elements (default independent: each its own random "
                          "load; blend: every family in turn, which a joint fit (calibrate fit --joint) "
                          "needs to see the cross-talk between elements)")
    gen.add_argument("--render-mode", choices=render_mode_choices(), default=None,
                     help="two_stage (default; pixels for a --setup camera two_stage cannot take): "
                          "guided light from a table (shipped for the default "
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
        help="fit calibration curves to a set, or to frames of measured presses",
        description="Fit per-element curves Fz = g(G) and the shear curves (model ohka: "
                    "Fx = f(ux), Fy = f(uy); model coupled: (Fx, Fy) = u g(G) / (a + b sqrt(g(G))))"
                    " to a calibration set, or to your own presses: --frames FRAMES --forces gauge.csv "
                    "(one row per frame and pressed element: frame, element, fx, fy, fz in N, "
                    "element-local unless a frame_of_reference column says global; frame is the file "
                    "name as optitact process names it in its source column, e.g. press_001.png or "
                    "clip.avi#12, or a 0-based index into the frames in order; elements and frames "
                    "without a row are unloaded; a unit in brackets, 'Fz (mN)', is converted: N, mN, kN, "
                    "gf, kgf, lbf, ozf). From scratch each element needs 8 presses; --start refines a "
                    "calibration from as few as 2 per element: every element's own curve shape, shrunk "
                    "toward the start by a prior shared over each ring whose strength 5-fold "
                    "cross-validation over the presses chooses; the held-out presses give the calibration "
                    "its error model (--method groups: the earlier gain, shear scale and centroid shift). "
                    "Or fit to a six-axis force/torque sensor's totals of objects pressed on the dome: "
                    "--frames FRAMES --wrench ft.csv --ft-pose X,Y,Z[,RX,RY,RZ] (with --forces too where "
                    "there are single presses). The figures go to stderr and the file's provenance. Write "
                    "the curves as JSON; --plot saves them with their residuals.")
    fitp.add_argument("set", type=Path, nargs="?", default=None, metavar="SET.zarr",
                      help="a calibration set (or give --frames and --forces)")
    fitp.add_argument("--model", choices=("ohka", "coupled"), default=None,
                      help="curve model (default coupled; a refinement keeps the start's)")
    fitp.add_argument("--out", type=Path, required=True, metavar="CAL.json",
                      help="the calibration file to write")
    fitp.add_argument("--joint", action="store_true",
                      help="also fit the cross-talk between elements (the joint inversion: every element's "
                           "force solved with its neighbours'); the set should be a --pattern blend one")
    fitp.add_argument("--validation", type=Path, default=None, metavar="VAL.zarr",
                      help="a finished set the fit does not see (other seeds; rendered like the frames the "
                           "calibration will read, e.g. --render-mode pixels): the calibration's own error is "
                           "measured on it (a floor plus parts growing with Fz and with the shear, per axis, "
                           "times a scale per ring of elements) and kept in the file for the error bars "
                           "(process --stderr); it holds the validation frames' noise too, so give "
                           "--dn-per-electron to process only for noisier frames")
    fitp.add_argument("--partial", action="store_true",
                      help="fit the finished frames of an incomplete set (a killed or running generate); "
                           "without it an incomplete set is refused with how many frames are done")
    _presses_arguments(fitp)
    fitp.add_argument("--setup", type=Path, default=None, metavar="FILE.json",
                      help="with --frames: the sensor and camera (e.g. from optitact register); default "
                           "the start's, else the default sensor and a camera of the frames' size")
    fitp.add_argument("--start", default=None, metavar="default|CAL.json",
                      help="with --frames: refine this calibration ('default': the shipped one, transferred "
                           "to --setup's sensor) instead of fitting from scratch (with --wrench: default "
                           "'default')")
    fitp.add_argument("--method", choices=("shapes", "groups"), default="shapes",
                      help="how --start is refined: 'shapes' (default) fits every element's own curve shape "
                           "(force scale and exponent, shear scale, brightness gradient, centroid shift), "
                           "shrunk toward the start by a prior whose strength 5-fold cross-validation over the "
                           "presses chooses, and keeps the held-out errors as the calibration's error model "
                           "(process --stderr is honest with no validation step); 'groups' is the earlier "
                           "refinement (a gain, a shear scale and a centroid shift per element, each kept "
                           "where it beats the start)")
    fitp.add_argument("--wrench", type=Path, default=None, metavar="FT.csv",
                      help="a six-axis force/torque sensor's totals of frames among --frames, one row per "
                           "frame: frame, fx, fy, fz, tx, ty, tz (N and N m, or units in brackets: 'Tz "
                           "(N·mm)'), the wrench the object exerts on the dome in the F/T sensor's frame, "
                           "about its origin; each element's curves are fitted so that the element forces, "
                           "summed, match them (with --forces' presses too where given). Needs --ft-pose")
    fitp.add_argument("--ft-pose", default=None, metavar="X,Y,Z[,RX,RY,RZ]|POSE.json",
                      help="with --wrench: the F/T sensor's origin in the dome's frame (mm; origin at the "
                           "dome's base centre, z up through the apex) and its rotation vector (deg) taking "
                           "F/T axes to the dome's, e.g. 0,0,-30 for one 30 mm below the base, axes aligned; "
                           "or a JSON file {\"position_mm\": [x, y, z], \"rotation_deg\": [rx, ry, rz]}")
    fitp.set_defaults(run=run_fit)
    test = csub.add_parser(
        "test", parents=[plot_parent("save estimated vs true forces of the pressed elements as PNG")],
        help="held-out errors of a calibration on frames of measured presses",
        description="Read held-out frames with the calibration's pipeline, estimate the forces and "
                    "compare them with the gauge's (CSV as for fit): RMSE per axis in N and in % of "
                    "full scale (the largest held-out Fz, and the largest shear component for Fx and "
                    "Fy), per ring, the bias, the worst elements, and the forces estimated on "
                    "unloaded elements.")
    test.add_argument("--calibration", required=True, metavar="default|CAL.json",
                      help="the calibration to test ('default': the shipped one)")
    _presses_arguments(test, required=True)
    test.add_argument("--setup", type=Path, default=None, metavar="SETUP.json",
                      help="the sensor and camera of a setup file (from optitact register): the shipped "
                           "calibration ('default') is transferred to them; a calibration file must be "
                           "made for them")
    test.add_argument("--json", action="store_true", help="print the report as one JSON object on stdout")
    test.add_argument("--validated", type=Path, default=None, metavar="OUT.json",
                      help="also write the calibration with its error measured on these presses (a floor plus "
                           "parts growing with Fz and with the shear, per axis, times a scale per ring of "
                           "elements; kept for process --stderr), "
                           "e.g. on presses of your own sensor that the calibration was not fitted on")
    test.set_defaults(run=run_test)
    noise = csub.add_parser(
        "noise", help="measure the camera's pixel noise from no-load and pressed frames -> NOISE.json "
                      "(for process --stderr --noise)",
        description="Measure the camera's noise per pixel (the photon-transfer curve) from two stacks of "
                    "frames at the same camera settings: NOLOAD frames of the unloaded sensor and PRESSED "
                    "frames under one press that does not change between them (a weight resting on the "
                    "sensor; 2 frames each at least, 20 or more for a steady estimate). Over the pixels "
                    "the press lights, the pressed frames' variance beyond the no-load one grows with "
                    "the mean signal: its slope is the conversion gain (grey levels per electron), its "
                    "intercept the variance every lit pixel has beyond read and shot noise (rounding); "
                    "the no-load frames' temporal noise is the read noise. Saturated pixels (at the "
                    "largest grey level of 8- or 16-bit frames) carry no noise and are left out; both "
                    "stacks must be of one bit depth. Writes them as JSON, which "
                    "process --stderr --noise reads to give each frame's noise in the forces' standard "
                    "errors; prints the model as one JSON object on stdout.")
    noise.add_argument("--noload", type=Path, nargs="+", required=True, metavar="FRAMES",
                       help="frames of the unloaded sensor: image files, folders, .npy stacks or videos")
    noise.add_argument("--pressed", type=Path, nargs="+", required=True, metavar="FRAMES",
                       help="frames under one unchanging press, at the same camera settings")
    noise.add_argument("--out", type=out_file(".json"), required=True, metavar="NOISE.json",
                       help="the noise file to write")
    noise.add_argument("--min-signal", type=float, default=20.0, metavar="DN",
                       help="only pixels whose mean signal (pressed minus no-load) is above this many grey "
                            "levels enter the fit (default 20: below a few levels of noise, rounding bends "
                            "the line)")
    noise.add_argument("--exponent", default="1", metavar="E|fit",
                       help="the power of the signal the noise variance grows with: 1 (default) is a "
                            "camera's shot noise; 'fit' measures it too (noise that is not shot noise, "
                            "e.g. a path tracer's)")
    noise.set_defaults(run=run_noise)


def _presses_arguments(p, *, required: bool = False) -> None:
    """``--frames``, ``--forces``, ``--baseline`` and ``--baseline-frames``."""
    p.add_argument("--frames", type=Path, nargs="+", default=None, required=required, metavar="FRAMES",
                   help="frames of the presses: image files, folders, .npy stacks or videos, in order")
    p.add_argument("--forces", type=Path, default=None, required=required, metavar="GAUGE.csv",
                   help="the gauge's forces: frame, element, fx, fy, fz [, frame_of_reference]; in N, or in "
                        "the unit the header names: 'Fz (mN)' (N, mN, kN, gf, kgf, lbf, ozf)")
    p.add_argument("--baseline", type=Path, default=None, metavar="NOLOAD",
                   help="no-load frame(s) (default: the first --baseline-frames frames)")
    p.add_argument("--baseline-frames", type=int_at_least(0, "an integer >= 0"), default=1, metavar="N",
                   help="without --baseline: average this many first frames (not pressed) as the no-load "
                        "baseline (default 1; 0 subtracts nothing)")


def _baseline(args):
    if args.baseline is None:
        return None, args.baseline_frames
    from optitact.io.frames import expand_sources, iter_frames

    return np.stack([f for _, f in iter_frames(expand_sources([args.baseline]))]), 0


def run_generate(args) -> int:
    """``optitact calibrate generate``: prints the store's path on stdout."""
    from optitact.calib.sets import Design, generate
    from optitact.optics.camera import FisheyeCamera

    from optitact.cli._args import read_setup

    design = Design(fz_max=args.fz_max, shear_max=args.shear_max, mu_max=args.mu_max, pattern=args.pattern)
    if args.setup is not None:
        sensor, camera = read_setup(args.setup)
    else:
        sensor, camera = None, FisheyeCamera(width=args.width, height=args.height)
    mode = "two_stage" if args.render_mode is None else args.render_mode
    cs = generate(args.out, frames=args.frames, sensor=sensor, camera=camera,
                  spp=args.spp, seed=args.seed, design=design, keep_frames=args.keep_frames,
                  variant=args.variant, render_mode=mode, scheduler=args.scheduler,
                  table_spp=args.table_spp)
    print(f"optitact: calibration set {args.out}: {int(cs.done.sum())} of {len(cs)} frames "
          f"done", file=sys.stderr)
    print(args.out)
    return 0


def run_fit(args) -> int:
    """``optitact calibrate fit``: prints the calibration's path on stdout."""
    from optitact.calib.fit import fit

    if args.wrench is not None or args.ft_pose is not None:
        return _run_fit_wrench(args)
    if args.frames is not None or args.forces is not None:
        return _run_fit_presses(args)
    if args.set is None:
        raise InputError("give a calibration set (SET.zarr), or frames of presses with --frames and --forces")
    for name in ("setup", "start", "baseline"):
        if getattr(args, name) is not None:
            raise InputError(f"--{name} is for fitting presses (--frames and --forces), not a set")
    if args.joint and args.set is None:
        raise InputError("--joint fits a calibration set (it needs every element's force in every frame)")
    cal = fit(args.set, model=args.model or "coupled", partial=args.partial, joint=args.joint)
    if args.validation is not None:
        cal = _validated(cal, args.set, args.validation)
    cal.save(args.out)
    r = cal.residuals
    prov = cal.provenance
    print(f"optitact: fitted {cal.model} on {int(np.sum(r['n']))} samples from {prov['frames']} of "
          f"{prov['frames_in_set']} frames; median RMS residual "
          f"Fx {np.median(r['fx']):.4f} N, Fy {np.median(r['fy']):.4f} N, Fz {np.median(r['fz']):.4f} "
          f"N; wrote {args.out}", file=sys.stderr)
    if args.plot is not None:
        from optitact.calib.sets import CalibrationSet
        from optitact.calib.plots import plot_fit

        cs = CalibrationSet(args.set)
        plot_fit(cal, cs.readings(), cs.forces(), args.plot)
        print(f"optitact: wrote {args.plot}", file=sys.stderr)
    print(args.out)
    return 0


def _validated(cal, set_path, val_path):
    """``cal`` with its error measured on the finished set ``val_path`` (never the fitted set itself)."""
    from optitact.calib.sets import CalibrationSet

    vs = CalibrationSet(val_path)
    if Path(val_path).resolve() == Path(set_path).resolve() or vs.attrs["seed"] == cal.provenance.get("seed"):
        raise InputError(f"--validation must be a set the fit did not see (another seed), got {val_path}")
    if not vs.complete:
        raise InputError(f"--validation set {val_path} is not finished ({int(vs.done.sum())} of "
                         f"{len(vs.done)} frames done)")
    cal.check(vs.sensor, vs.camera)
    mode = vs.attrs.get("render_mode", "full")
    out = cal.validated(vs.readings(), vs.forces(),
                        source=f"{int(vs.done.sum())} frames of {Path(val_path).name} ({mode}, "
                               f"{vs.attrs['spp']} spp, seed {vs.attrs['seed']}), noise included")
    m = out.error_model
    print(f"optitact: error measured on {m.samples} validation samples: floor Fx {m.floor_n[0]:.4f}, Fy "
          f"{m.floor_n[1]:.4f}, Fz {m.floor_n[2]:.4f} N, plus Fx {m.relative[0]:.4f}, Fy {m.relative[1]:.4f}, "
          f"Fz {m.relative[2]:.4f} N per N of Fz and Fx {m.shear[0]:.4f}, Fy {m.shear[1]:.4f}, "
          f"Fz {m.shear[2]:.4f} N per N of shear, and Fz {m.shear2[2]:.4f} N per N² of shear"
          + _ring_scales(m, out.sensor.element_ring), file=sys.stderr)
    return out


def _ring_scales(model, ring) -> str:
    """``"; times Fx/Fy/Fz a/b/c on ring 0, ..."`` of an error model's scale per ring (or "")."""
    if model.element_scale is None:
        return ""
    first = [int(np.flatnonzero(ring == r)[0]) for r in np.unique(ring)]
    return "; times Fx/Fy/Fz " + ", ".join(
        "/".join(f"{v:.2f}" for v in model.element_scale[e]) + f" on ring {r}" for r, e in enumerate(first))


def _run_fit_presses(args) -> int:
    """``optitact calibrate fit --frames ... --forces ...``."""
    from optitact.calib.gauge import measure_presses
    from optitact.calib.press_fit import fit_measured, starting_calibration

    if args.frames is None or args.forces is None:
        raise InputError("fitting presses needs both --frames and --forces")
    if args.set is not None or args.partial:
        raise InputError("give a calibration set or --frames/--forces, not both")
    start = starting_calibration(args.start)
    pipe = _presses_pipeline(args.setup, start, args.frames)
    base, n_base = _baseline(args)
    p = measure_presses(args.frames, args.forces, pipeline=pipe, baseline=base, baseline_frames=n_base,
                        progress=True)
    cal = fit_measured(p, pipe, model=args.model, start=start, forces=args.forces, method=args.method)
    cal.save(args.out)
    r = cal.residuals
    n_press = np.asarray(cal.provenance["presses_per_element"])
    how = (f"fitted {cal.model} from scratch" if start is None else
           f"refined {args.start}: each element's own shape" if cal.provenance["fit"] == "shapes" else
           f"refined {args.start} on {len(cal.provenance['refined_elements'])} elements")
    print(f"optitact: {how} from {int(p.pressed.sum())} presses in {len(p.sources)} frames "
          f"({int(n_press.min())}-{int(n_press.max())} per element); median RMS residual Fx "
          f"{np.median(r['fx']):.4f} N, Fy {np.median(r['fy']):.4f} N, Fz {np.median(r['fz']):.4f} N; "
          f"wrote {args.out}", file=sys.stderr)
    if start is not None:
        (_print_shapes if cal.provenance["fit"] == "shapes" else _print_refinement)(cal)
    if args.plot is not None:
        from optitact.calib.plots import plot_fit

        plot_fit(cal, p.readings, p.forces, args.plot)
        print(f"optitact: wrote {args.plot}", file=sys.stderr)
    print(args.out)
    return 0


def _print_refinement(cal) -> None:
    """What a refinement kept per group and its held-out RMSE against the start's, on stderr."""
    prov = cal.provenance
    names = {"gain": "gain", "shear_scale": "shear scale", "centroid_shift": "centroid shift"}
    n_el = len(prov["refined_elements"])
    kept = ", ".join(f"{names[g]} on {len(ids)}" for g, ids in prov["kept_groups"].items())
    held = prov["held_out"]
    rmse = held.get("rmse_n")
    figures = ", ".join(f"{k.capitalize()} {rmse['start'][k]:.4f} -> {rmse['refined'][k]:.4f} N"
                        for k in ("fx", "fy", "fz"))
    print(f"optitact: kept per element only what beat the start on held-out presses ({held['folds']}): "
          f"{kept} of {n_el} elements; held-out RMSE over {held['samples']} presses, start -> refined: "
          f"{figures}", file=sys.stderr)


def _presses_pipeline(setup, start, frames):
    """The pipeline that reads the presses: the setup's sensor and camera, the start's options."""
    from optitact.calib.press_fit import default_pipeline
    from optitact.pipeline.frame_pipeline import Pipeline

    if setup is None:
        return start.pipeline() if start is not None else default_pipeline(frames)
    from optitact.cli._args import read_setup

    sensor, camera = read_setup(setup)
    if start is None:
        return Pipeline(sensor, camera)
    if sensor.n_elements != len(start.g):
        raise InputError(f"--setup {setup}: the sensor has {sensor.n_elements} elements, the starting "
                         f"calibration {len(start.g)}")
    return Pipeline(sensor, camera, readings_bits=start.intensity.bits,
                    **start.reading_options)


def run_test(args) -> int:
    """``optitact calibrate test``: the held-out report on stderr (or JSON on stdout)."""
    import json

    from optitact.calib.gauge import measure_presses
    from optitact.calib.held_out import press_report
    from optitact.calib.press_fit import starting_calibration

    cal = starting_calibration(args.calibration)
    if args.setup is not None:
        from optitact.registration.setup import read_setup

        setup = read_setup(args.setup)
        cal = calibration_on_setup(cal, (setup.sensor, setup.camera),
                                   shipped=str(args.calibration) == "default", setup_path=args.setup)
    base, n_base = _baseline(args)
    _check_sizes(args, cal, base)
    p = measure_presses(args.frames, args.forces, pipeline=cal.pipeline(), baseline=base,
                        baseline_frames=n_base, progress=True)
    rep = press_report(cal, p.readings, p.forces, p.pressed)
    rep["calibration"] = str(args.calibration)
    if args.validated is not None:
        names = sorted({Path(str(f)).name for f in args.frames})
        source = (f"{rep['presses']} presses of {Path(str(args.forces)).name} on "
                  f"{', '.join(names[:3])}{' ...' if len(names) > 3 else ''}, noise included")
        forces = np.where(p.pressed[..., None], p.forces, 0.0)  # only the gauge's presses count
        out = cal.validated(p.readings, forces, source=source)
        out.save(args.validated)
        rep["validated"] = {"path": str(args.validated), "error_model": out.error_model.to_dict()}
        print(f"optitact: wrote {args.validated} (the calibration with its error measured on "
              f"{out.error_model.samples} presses)", file=sys.stderr)
    if args.plot is not None:
        from optitact.calib.plots import plot_errors

        est, _ = cal.forces(p.readings)
        plot_errors(p.forces[p.pressed], {cal.model: est[p.pressed]}, args.plot)
        print(f"optitact: wrote {args.plot}", file=sys.stderr)
    if args.json:
        print(json.dumps(rep))
        return 0
    pct = rep["rmse_pct_fs"]
    lines = [f"{rep['presses']} presses on {rep['elements_pressed']} elements; RMSE "
             + ", ".join(f"{k.capitalize()} {rep['rmse_n'][k]:.4f} N"
                         + (f" ({pct[k]:.2f} % FS)" if pct[k] is not None else "") for k in ("fx", "fy", "fz")),
             "bias " + ", ".join(f"{k.capitalize()} {v:+.4f} N" for k, v in rep["bias_n"].items())]
    lines += [f"ring {r['ring']}: {r['presses']} presses, RMSE "
              + ", ".join(f"{k.capitalize()} {v:.4f}" for k, v in r["rmse_n"].items()) + " N"
              for r in rep["per_ring"] if r["rmse_n"] is not None]
    lines.append("worst elements: " + ", ".join(f"{w['element']} ({w['rms_error_n']:.4f} N)"
                                                 for w in rep["worst_elements"]))
    lines.append("90 % intervals hold " + ", ".join(f"{k.capitalize()} {v:.2f}" for k, v in
                                                    rep["coverage_90"].items()) + " of the true forces; "
                 "errors in standard errors (RMS, 1 when they are right) "
                 + ", ".join(f"{k.capitalize()} {v:.2f}" for k, v in rep["error_ratio"].items()))
    un = rep["unloaded"]
    lines.append(f"unloaded: {un['samples']} samples, RMSE " + ", ".join(
        f"{k.capitalize()} {v:.4f}" for k, v in un["rmse_n"].items()) + f" N, contact seen in "
        f"{100 * un['contact_rate']:.1f} %")
    for line in lines:
        print(f"optitact: {line}", file=sys.stderr)
    return 0


def _check_sizes(args, cal, baseline) -> None:
    """The presses' first frame (and a --baseline) must be of the calibration's camera; else what to do."""
    from optitact.io.frames import expand_sources, iter_frames

    frames = iter_frames(expand_sources(args.frames))
    first = next(frames, None)
    frames.close()  # one frame read: a video is released at once
    if first is not None:
        check_frame_size(args, cal, first[0], first[1].shape)
    if baseline is not None:
        check_frame_size(args, cal, str(args.baseline), baseline.shape[1:])


def _stack(files: list[Path], option: str) -> np.ndarray:
    """The frames of ``files`` (expanded sources: files, stacks, videos) as one (T, H, W) stack.

    The frames must be of one size and dtype, and grey levels (integer or float, not bool).
    """
    from optitact.io.frames import iter_frames

    frames = [(name, f) for name, f in iter_frames(files)]
    if not frames:
        raise InputError(f"{option}: the frames hold no frame")
    first, shape, dtype = frames[0][0], frames[0][1].shape, frames[0][1].dtype
    for name, f in frames:
        if f.dtype.kind not in "uif":
            raise InputError(f"{option}: {name} holds {f.dtype} values; expected grey levels (uint8, uint16 "
                             f"or float frames)")
        if f.shape != shape:
            raise InputError(f"{option}: {name} is {f.shape[1]}x{f.shape[0]}, the first frame "
                             f"{shape[1]}x{shape[0]}: the frames must be of one camera")
        if f.dtype != dtype:
            raise InputError(f"{option}: {name} is {f.dtype}, the first frame ({first}) {dtype}: the frames "
                             f"must be of one bit depth")
    return np.stack([f for _, f in frames])


def _noise_files(args) -> tuple[list[Path], list[Path]]:
    """The --noload and --pressed files, expanded; InputError if a file is in both."""
    from optitact.io.frames import expand_sources

    noload, pressed = expand_sources(args.noload), expand_sources(args.pressed)
    seen = {p.resolve(): p for p in noload}
    for p in pressed:
        if p.resolve() in seen:
            raise InputError(f"{p} is given as --pressed and as --noload ({seen[p.resolve()]}); the noise "
                             f"is measured from two different recordings: frames without load and frames "
                             f"under one constant load")
    return noload, pressed


def run_noise(args) -> int:
    """``optitact calibrate noise``: the pixel noise model as JSON on stdout, written to --out."""
    import json

    from optitact.pipeline.uncertainty import PixelNoise, saturated_pixels

    if args.exponent == "fit":
        exponent = "fit"
    else:
        try:
            exponent = float(args.exponent)
        except ValueError:
            raise InputError(f"--exponent must be a number or 'fit', got {args.exponent!r}") from None
    if not (np.isfinite(args.min_signal) and args.min_signal >= 0):
        raise InputError(f"--min-signal must be a finite number of grey levels >= 0, got {args.min_signal:g}")
    noload_files, pressed_files = _noise_files(args)
    noload, pressed = _stack(noload_files, "--noload"), _stack(pressed_files, "--pressed")
    if noload.shape[1:] != pressed.shape[1:]:
        raise InputError(f"--noload frames are {noload.shape[2]}x{noload.shape[1]}, --pressed ones "
                         f"{pressed.shape[2]}x{pressed.shape[1]}: they must be of one camera")
    if noload.dtype != pressed.dtype and not (noload.dtype.kind == pressed.dtype.kind == "f"):
        raise InputError(f"--noload frames ({noload_files[0]}) are {noload.dtype} "
                         f"({8 * noload.dtype.itemsize}-bit), --pressed frames ({pressed_files[0]}) "
                         f"{pressed.dtype} ({8 * pressed.dtype.itemsize}-bit): record both at one bit depth "
                         f"and camera setting")
    model = PixelNoise.estimate(noload, pressed, min_signal=args.min_signal, exponent=exponent)
    signal = pressed.mean(axis=0, dtype=np.float64) - noload.mean(axis=0, dtype=np.float64)
    saturated = saturated_pixels(noload, pressed)
    measured = {"noload": [str(p) for p in args.noload], "pressed": [str(p) for p in args.pressed],
                "noload_frames": len(noload), "pressed_frames": len(pressed),
                "min_signal": args.min_signal, "exponent": args.exponent,
                "pixels_fitted": int(np.count_nonzero((signal > args.min_signal) & ~saturated)),
                "pixels_saturated": int(np.count_nonzero(saturated)), "dtype": str(pressed.dtype)}
    model.save(args.out, measured=measured)
    left_out = f" ({measured['pixels_saturated']} saturated pixels left out)" if saturated.any() else ""
    print(f"optitact: {measured['pixels_fitted']} lit pixels{left_out}: conversion gain "
          f"{model.dn_per_electron:.5g} grey levels per electron (signal^{model.exponent:g}), lit variance "
          f"{model.lit_variance:.3g}, read noise {model.read_sigma:.3g} grey levels; wrote {args.out}",
          file=sys.stderr)
    print(json.dumps(model.to_dict()))
    return 0


def _print_shapes(cal) -> None:
    """What a shape fit found: the prior's strength, the elements pinned down, held-out errors, error model."""
    prov = cal.provenance
    n_el = len(cal.g)
    pinned = prov["normal_curve_pinned"]
    loose = [e for e in range(n_el) if e not in set(pinned)]
    held = prov["held_out"]
    rmse = held.get("rmse_n")
    st = prov["strength"]
    parts = [f"prior strength: normal curve {st['normal']:.3g}, shear {st['shear']:.3g} (of "
             f"{len(prov['cv_scores'])} pairs tried, by held-out {held['folds']})",
             f"normal curve pinned down by the observations on {len(pinned)} of {n_el} elements"
             + (f" (the prior holds on {', '.join(map(str, loose[:12]))}{' ...' if len(loose) > 12 else ''})"
                if loose else "")]
    if "wrench_rms" in held:
        w = held["wrench_rms"]
        parts.append(f"held-out wrench RMS over {w['frames']} frames, start -> fitted: force "
                     f"{w['start']['force_n']:.4f} -> {w['refined']['force_n']:.4f} N, torque "
                     f"{1000 * w['start']['torque_nm']:.3f} -> {1000 * w['refined']['torque_nm']:.3f} N mm")
    if held["samples"]:
        parts.append(f"held-out RMSE over {held['samples']} presses, start -> fitted: " + ", ".join(
            f"{k.capitalize()} {rmse['start'][k]:.4f} -> {rmse['refined'][k]:.4f} N"
            for k in ("fx", "fy", "fz")))
    m = cal.error_model
    if m is not None:
        parts.append(f"error model from {m.source}: floor Fx {m.floor_n[0]:.4f}, Fy {m.floor_n[1]:.4f}, "
                     f"Fz {m.floor_n[2]:.4f} N plus Fz {m.relative[2]:.4f} N per N of Fz"
                     + _ring_scales(m, cal.sensor.element_ring))
    for p in parts:
        print(f"optitact: {p}", file=sys.stderr)


def _run_fit_wrench(args) -> int:
    """``optitact calibrate fit --frames ... --wrench FT.csv --ft-pose ... [--forces GAUGE.csv]``."""
    from optitact.calib.press_fit import starting_calibration
    from optitact.calib.wrench import SensorPose
    from optitact.calib.wrench_fit import fit_wrench_frames

    if args.frames is None or args.wrench is None or args.ft_pose is None:
        raise InputError("fitting to force/torque totals needs --frames, --wrench and --ft-pose (the F/T "
                         "sensor's pose relative to the dome, e.g. 0,0,-30)")
    if args.set is not None or args.partial:
        raise InputError("give a calibration set or --frames/--wrench, not both")
    if args.method != "shapes":
        raise InputError("--wrench fits each element's shape (--method shapes); --method groups is for presses")
    start = starting_calibration("default" if args.start is None else args.start)
    pipe = _presses_pipeline(args.setup, start, args.frames)
    pose = SensorPose.parse(args.ft_pose, sensor=pipe.sensor)
    base, n_base = _baseline(args)
    cal = fit_wrench_frames(args.frames, args.wrench, pose, pipeline=pipe, start=start, forces=args.forces,
                            baseline=base, baseline_frames=n_base, progress=True)
    cal.save(args.out)
    prov = cal.provenance
    counts = np.asarray(prov["wrench_frames_per_element"])
    print(f"optitact: refined {args.start or 'default'}: each element's own shape, from "
          f"{prov['wrench_frames']} "
          f"force/torque frames ({int(counts.min())}-{int(counts.max())} loading each element)"
          + (f" and {int(np.sum(prov['presses_per_element']))} presses" if args.forces is not None else "")
          + f"; wrote {args.out}", file=sys.stderr)
    _print_shapes(cal)
    print(args.out)
    return 0
