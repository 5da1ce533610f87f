"""Benchmark: force errors of both calibration models on a held-out synthetic set.

Not library code: ``optitact bench accuracy`` runs it.
"""

from __future__ import annotations

import sys

import numpy as np

from optitact._validate import integer
from optitact.errors import InputError
from optitact.optics.camera import FisheyeCamera
from optitact.pipeline.uncertainty import coverage, coverage_spread, error_ratio

__all__ = ["SINGLE_FRAMES_FACTOR", "bench_accuracy"]

#: The ``single`` family's held-out set has this many times ``test_frames``
#: frames. Each of its frames loads one element where the others load 10-41:
#: with 30 samples its coverage could only be 26/30, 27/30 or 28/30 near 0.9,
#: a spread of 0.05 over its frames; with 900 it is about 0.01, as the
#: other families' are with 30 frames (path-traced at 256 spp, about four
#: minutes of rendering here, once).
SINGLE_FRAMES_FACTOR = 30


def bench_accuracy(*, frames: int = 100, test_frames: int = 30, spp: int = 64,
                   test_spp: int | None = None, size: tuple[int, int] = (640, 480),
                   calibration_set=None, test_set=None, seed: int = 0,
                   variant: str | None = None, plot=None, contact_min_n: float = 0.01,
                   render_mode: str = "two_stage", test_render_mode: str = "pixels",
                   families=("independent",), design_pattern: str = "independent",
                   validation_frames: int = 60, single_frames: int | None = None,
                   floor_frames: int = 4) -> dict:
    """Force errors of both calibration models on a held-out synthetic set.

    Parameters
    ----------
    frames, test_frames : int
        Frames of the calibration set and of each held-out set (41 samples
        each) but the ``single`` family's (``single_frames``).
    spp : int
        Samples per pixel of the calibration renders.
    test_spp : int, optional
        Samples per pixel of the held-out renders (default ``spp``). Monte
        Carlo noise is a property of the simulation, not of the sensor; a
        higher ``test_spp`` measures the calibration against frames whose
        noise is the camera's.
    size : (int, int)
        Frame width and height.
    calibration_set, test_set : path-like, optional
        Existing sets to use; by default they are generated (resumably) in
        the user cache folder, the held-out one with seed ``seed + 1000``
        (disjoint seeds, independently drawn forces).
    seed : int
    variant : str, optional
    plot : path-like, optional
        PNG of estimated vs true forces per model.
    contact_min_n : float
        A true normal force at or above this (N) should read as contact;
        below it, as none (for ``contact_flag_error_rate``).
    render_mode, test_render_mode : str
        How the calibration and the held-out frames are rendered (see
        :func:`optitact.calib.sets.generate`); by default the calibration comes
        from the two-stage light transport and is tested on path-traced frames.
    families : sequence of str
        Load-pattern families of held-out sets (:data:`optitact.calib.patterns.FAMILIES`),
        each its own set of ``test_frames`` frames with its own seed (``seed +
        1000`` for ``independent``, ``seed + 1000 + 100 k`` for the k-th
        family of ``FAMILIES``); default only ``independent``.
    design_pattern : str
        Load pattern of the calibration set (:data:`optitact.calib.patterns.PATTERNS`);
        ``"blend"`` shows the fit every family, which the joint model needs.
    validation_frames : int
        Frames of the validation set (0: none; none either with a given
        ``test_set``): rendered like the held-out sets (``test_render_mode``,
        ``test_spp``) with the ``blend`` pattern and seed ``seed + 900``, it
        measures each model's own error
        (:meth:`~optitact.calib.fit.Calibration.validated`) for the error bars;
        neither the curves nor any held-out set see it. Default 60: ten
        frames of each family (with 20, the error models' floors rested on
        about three frames a family).
    single_frames : int, optional
        Frames of the ``single`` family's held-out set, each loading one
        element (default :data:`SINGLE_FRAMES_FACTOR` times ``test_frames``).
    floor_frames : int
        Frames of each held-out set made again with other seeds to measure
        each model's error floor there (:func:`render_floor`; the ``single``
        family's: ten times as many, as they load one element each; 0: none).

    Returns
    -------
    dict
        ``{"models": {"ohka": {...}, "coupled": {...}}, ...}`` with, per model,
        ``fx_rmse_n``, ``fy_rmse_n``, ``fz_rmse_n``, the same as % of full
        scale (``fz_max`` for Fz, ``shear_max`` for Fx and Fy),
        ``fx/fy/fz_bias_pct_fs``, ``per_ring`` (RMSE % FS per axis),
        ``max_abs_error_n``, ``contact_flag_error_rate``, ``clamped_rate``
        and ``coverage_90`` (per axis: the fraction of true forces inside
        the estimate's 90 % interval, ``+- 1.645`` standard errors of
        :meth:`~optitact.calib.fit.Calibration.stderr`: the frames' pixel noise,
        measured (:func:`frame_noise`), through
        :func:`optitact.pipeline.uncertainty.reading_errors`, plus the model's error
        measured on the validation set; without one, the fit residuals), ``coverage_90_sd`` (its
        standard deviation over the frames drawn again with replacement:
        :func:`optitact.pipeline.uncertainty.coverage_spread`), ``error_ratio`` (the errors in
        those standard errors, root mean square: 1 when they are right, whatever the
        tails; :func:`optitact.pipeline.uncertainty.error_ratio`), ``error_ratio_per_ring`` (the
        same per ring of elements) and ``coverage_90_fit_residuals``
        (the same with the fit residuals as the model error), over every loaded
        element sample (``Fz > 0``) of the
        first family's held-out set; ``families``: the same per family;
        with ``floor_frames``, per family and model also
        ``fx/fy/fz_floor_pct_fs`` (the RMSE a perfect calibration would show
        on those renders) and ``fx/fy/fz_beyond_floor_pct_fs`` (``sqrt(RMSE^2 -
        floor^2)``: the model's own error), and per family ``floor`` (how it
        was measured); ``coverage_90_pooled`` (with several families and frames): per model,
        ``coverage_90``, ``coverage_90_sd`` and ``error_ratio`` over every family's samples
        together, with their ``samples`` and ``frames``; and
        ``worst_family``: per model and axis, the family with the largest RMSE.
    """
    from optitact.io.cache import cache_dir
    from optitact.calib.curves import MODELS
    from optitact.calib.sets import CalibrationSet, Design, generate
    from optitact.calib.fit import fit
    from optitact.calib.patterns import FAMILIES
    from optitact.calib.plots import plot_errors

    width, height = size
    camera = FisheyeCamera(width=integer(width, "width", minimum=2),
                           height=integer(height, "height", minimum=2))
    set_dir = cache_dir() / "sets"

    def get(given, n, s, tag, n_spp, mode, design=None, keep_frames=False):
        if given is not None:
            return CalibrationSet(given)
        # held-out sets keep their frames: the standard errors come from their pixels
        path = set_dir / f"{tag}-{width}x{height}-f{n}-spp{n_spp}-seed{s}-{mode}{'-frames' * keep_frames}.zarr"
        print(f"optitact: bench accuracy: {tag} set {path}", file=sys.stderr)
        if path.exists():
            cached = CalibrationSet(path)
            if cached.complete:  # made earlier (possibly by an older version): use as is
                return cached
        return generate(path, frames=n, camera=camera, spp=n_spp, seed=s, variant=variant, render_mode=mode,
                        design=design, keep_frames=keep_frames)

    test_spp = spp if test_spp is None else integer(test_spp, "test_spp", minimum=1)
    families = tuple(families)
    single_frames = (SINGLE_FRAMES_FACTOR * test_frames if single_frames is None
                     else integer(single_frames, "single_frames", minimum=1))
    floor_frames = integer(floor_frames, "floor_frames", minimum=0)
    if not families or any(f not in FAMILIES for f in families):
        raise InputError(f"families must be some of {FAMILIES}, got {families!r}")
    if test_set is not None and len(families) > 1:
        raise InputError("--test-set is one held-out set: give one family with it")
    cs = get(calibration_set, frames, seed, "calibration" if design_pattern == "independent"
             else f"calibration-{design_pattern}", spp, render_mode, Design(pattern=design_pattern))
    sets = {}
    for fam in families:
        k = FAMILIES.index(fam)
        n = test_frames if fam != "single" else single_frames
        sets[fam] = get(test_set, n, seed + 1000 + 100 * k, "test" if k == 0 else f"test-{fam}",
                        test_spp, test_render_mode, Design(pattern=fam), keep_frames=True)
        if sets[fam].attrs["seed"] == cs.attrs["seed"]:
            raise InputError("the held-out set must have another seed than the calibration set")
    ts = sets[families[0]]
    truth = ts.forces()
    design = cs.attrs["design"]
    fs = np.array([design["shear_max"], design["shear_max"], design["fz_max"]])
    out: dict = {"size": f"{camera.width}x{camera.height}", "spp": int(cs.attrs["spp"]),
                 "test_spp": int(ts.attrs["spp"]),
                 "calibration_set": {"path": str(cs.path), "frames": int(cs.done.sum()),
                                     "seed": cs.attrs["seed"],
                                     "render_mode": cs.attrs.get("render_mode", "full")},
                 "test_set": {"path": str(ts.path), "frames": int(ts.done.sum()),
                              "seed": ts.attrs["seed"], "samples": int(truth[..., 0].size),
                              "render_mode": ts.attrs.get("render_mode", "full")},
                 "full_scale_n": {"fx": fs[0], "fy": fs[1], "fz": fs[2]},
                 "ccd": ts.attrs["ccd"], "models": {}}
    estimates = {}
    cals = {model: fit(cs, model=model) for model in MODELS}
    try:  # the coupled curves with the cross-talk between elements, solved jointly per frame
        cals["joint"] = fit(cs, model="coupled", joint=True)
    except InputError as exc:
        out["joint_refused"] = str(exc)
    ring = cals[MODELS[0]].sensor.element_ring
    out["families"] = {}
    pooled: dict = {}  # model -> per family (estimates, truth, stderr, loaded) of its coverage_90
    with_frames = any(fset.attrs.get("keep_frames") for fset in sets.values())
    if with_frames:  # one renderer, spp and CCD for every held-out set
        noise, out["frame_noise"] = frame_noise(ts)
    validated = {}
    if validation_frames and test_set is None and with_frames:
        vs = get(None, integer(validation_frames, "validation_frames", minimum=1), seed + 900, "validation",
                 test_spp, test_render_mode, Design(pattern="blend"), keep_frames=True)
        v_read, v_truth = vs.readings(), vs.forces()
        v_err = _reading_errors(vs, v_read, noise)
        source = (f"{len(v_truth)} validation frames ({vs.attrs.get('render_mode')}, {vs.attrs['spp']} spp, "
                  f"blend, seed {vs.attrs['seed']})")
        validated = {model: cal.validated(v_read, v_truth, v_err, source=source) for model, cal in cals.items()}
        out["validation_set"] = {"path": str(vs.path), "frames": int(vs.done.sum()), "seed": vs.attrs["seed"],
                                 "render_mode": vs.attrs.get("render_mode"), "pattern": "blend",
                                 "error_models": {m: c.error_model.to_dict() for m, c in validated.items()}}
    elif test_set is not None:
        print("optitact: bench accuracy: a given held-out set: no validation set, so coverage_90 uses the fit "
              "residuals as the model error", file=sys.stderr)
    for fam, fset in sets.items():
        f_truth, f_read = fset.forces(), fset.readings()
        out["families"][fam] = {"set": {"path": str(fset.path), "frames": int(fset.done.sum()),
                                        "seed": fset.attrs["seed"]}, "models": {}}
        errors = _reading_errors(fset, f_read, noise) if with_frames else None
        for model, cal in cals.items():
            est, clamped = cal.forces(f_read)
            if fam == families[0]:
                estimates[model] = est
            scores = _scores(est, f_truth, clamped, f_read, fs, ring, contact_min_n)
            if errors is not None:
                for key, c in (("coverage_90_fit_residuals", cal), ("coverage_90", validated.get(model))):
                    if c is None:  # no validation set: the fit residuals' coverage is the one there is
                        scores[key] = scores["coverage_90_fit_residuals"]
                        continue
                    se, loaded = c.stderr(f_read, errors, forces=est), f_truth[..., 2] > 0
                    scores[key] = _per_axis(coverage(est, f_truth, se, where=loaded))
                    if key == "coverage_90":  # its spread over the frames drawn: is a miss beyond luck?
                        scores["coverage_90_sd"] = _per_axis(coverage_spread(est, f_truth, se, where=loaded,
                                                                             seed=seed))
                        scores["error_ratio"] = _per_axis(error_ratio(est, f_truth, se, where=loaded))
                        scores["error_ratio_per_ring"] = [
                            {"ring": int(r), "samples": int(np.sum(at)),
                             **_per_axis(error_ratio(est, f_truth, se, where=at))}
                            for r in np.unique(ring) if np.any(at := loaded & (ring == r))]
                        pooled.setdefault(model, []).append((est, f_truth, se, loaded))
            out["families"][fam]["models"][model] = scores
        if floor_frames:
            try:
                floors = render_floor(fset, cals, floor_frames * (10 if fam == "single" else 1), fs)
            except InputError as exc:  # frames this version cannot make again: no floor, and why
                print(f"optitact: bench accuracy: no floor for {fam}: {exc}", file=sys.stderr)
                out["families"][fam]["floor"] = {"refused": str(exc)}
                floors = {}
            for model, fl in floors.items():
                scores = out["families"][fam]["models"][model]
                for ax in ("fx", "fy", "fz"):
                    f, r = fl[f"{ax}_floor_pct_fs"], scores[f"{ax}_rmse_pct_fs"]
                    scores[f"{ax}_floor_pct_fs"] = f
                    scores[f"{ax}_beyond_floor_pct_fs"] = round(float(np.sqrt(max(r * r - f * f, 0.0))), 3)
            for fl in list(floors.values())[:1]:  # how it was measured: the same for every model
                out["families"][fam]["floor"] = {k: fl[k] for k in ("frames", "samples", "from")}
    out["models"] = out["families"][families[0]]["models"]
    if len(families) > 1 and pooled:  # every family's frames together: the "over the held-out families"
        out["coverage_90_pooled"] = {}
        for model, parts in pooled.items():
            est, f_truth, se, loaded = (np.concatenate(a) for a in zip(*parts, strict=True))
            out["coverage_90_pooled"][model] = {
                "coverage_90": _per_axis(coverage(est, f_truth, se, where=loaded)),
                "coverage_90_sd": _per_axis(coverage_spread(est, f_truth, se, where=loaded, seed=seed)),
                "error_ratio": _per_axis(error_ratio(est, f_truth, se, where=loaded)),
                "samples": int(loaded.sum()), "frames": int(len(loaded))}
    out["worst_family"] = {model: {ax: max(((fam, out["families"][fam]["models"][model][f"{ax}_rmse_pct_fs"])
                                            for fam in families), key=lambda kv: kv[1])
                                   for ax in ("fx", "fy", "fz")} for model in cals}
    if plot is not None:
        if len(families) > 1:
            _plot_families(out, plot)
        else:
            plot_errors(truth, estimates, plot)
        out["plot"] = str(plot)
    return out


def _reading_errors(fset, readings, noise):
    """The readings' covariance from the set's stored frames and ``noise``, or None for a set without frames."""
    from optitact.pipeline.frame_pipeline import Pipeline
    from optitact.pipeline.uncertainty import reading_errors

    if not fset.attrs.get("keep_frames") or not fset.has_array("frames"):
        print(f"optitact: bench accuracy: {fset.path} holds no frames; no coverage_90", file=sys.stderr)
        return None
    pipe = Pipeline(fset.sensor, fset.camera, baseline=fset.array("baseline"), **fset.attrs.get("pipeline", {}))
    return reading_errors(pipe, fset.array("frames")[fset.done], noise, readings)


def frame_noise(fset, *, repeats: int = 4, frame: int = 0):
    """The pixel noise of a set's frames, measured as a user measures a camera's (a ``PixelNoise``).

    Two-stage frames carry the CCD's noise alone (:meth:`PixelNoise.from_ccd`).
    Path-traced frames also carry the renderer's Monte Carlo noise, which
    grows with the signal, but more slowly than shot noise: the
    photon-transfer fit of :meth:`PixelNoise.estimate` measures both
    together, its exponent too (``exponent="fit"``; from 2 grey levels of
    signal, where the Monte Carlo noise is already above a grey level and the
    spots' rims are, which weigh most in the centroids), from the set's
    no-load stack and ``repeats`` renders of one of its loads (``frame``)
    with other seeds (render and CCD), made as the set made its frames
    (kept in the user cache folder, ``bench-noise``).
    A camera's straight line, fitted from 20 grey levels up, set 16 grey
    levels squared at 3 grey levels of signal and 20 at 10, where 8 renders
    of one load measured 3 and 9.

    Returns
    -------
    noise : PixelNoise
    info : dict
        How it was obtained, for the bench's JSON.
    """
    from optitact.pipeline.uncertainty import PixelNoise

    mode = fset.attrs.get("render_mode", "full")
    if mode == "two_stage":
        noise = PixelNoise.from_ccd(fset.ccd)
        return noise, {"from": "the CCD model (two-stage frames: no Monte Carlo noise)",
                       "dn_per_electron": noise.dn_per_electron}
    forces = fset.forces()[frame]
    seeds = np.random.SeedSequence([int(fset.attrs["seed"]), 77, frame]).generate_state(repeats)
    pressed = _made_again(fset, [forces] * repeats, seeds, ("frame",), "bench-noise")["frame"]
    noise = PixelNoise.estimate(fset.array("baseline"), pressed, min_signal=2.0, exponent="fit")
    ccd = PixelNoise.from_ccd(fset.ccd)
    return noise, {"from": f"PixelNoise.estimate: the set's {len(fset.array('baseline'))} no-load frames and "
                           f"{repeats} renders of its frame {frame} with other seeds",
                   "dn_per_electron": round(noise.dn_per_electron, 6), "read_sigma": round(noise.read_sigma, 4),
                   "lit_variance": round(noise.lit_variance, 4), "exponent": noise.exponent,
                   "ccd_dn_per_electron": round(ccd.dn_per_electron, 6)}


def _maker(fset, *, keep_frames: bool = False):
    """A :class:`~optitact.calib.sets.FrameMaker` that makes frames as ``fset`` made its own.

    Raises
    ------
    InputError
        Two-stage frames made with another emission table than the shipped one.
    """
    from optitact.calib.sets import FrameMaker
    from optitact.io.files import json_fingerprint

    table = None
    if fset.attrs.get("render_mode", "full") == "two_stage":
        from optitact.render.emission import shipped_table

        table = shipped_table(fset.sensor)
        made = fset.attrs.get("two_stage_table")
        if table is None or json_fingerprint(table.to_dict()["radiance"], 16) != made:
            raise InputError(f"{fset.path}: its two-stage frames were made with an emission table other than "
                             f"the shipped one, which cannot be made again here")
    return FrameMaker(sensor=fset.sensor, camera=fset.camera, ccd=fset.ccd,
                      pipeline_options=fset.attrs.get("pipeline", {}), baseline=fset.array("baseline"),
                      background=np.asarray(fset.array("baseline_radiance"), np.float64).mean(axis=0),
                      render_mode=fset.attrs.get("render_mode", "full"), spp=int(fset.attrs["spp"]),
                      variant=None, table=table, keep_frames=keep_frames)


def _made_again(fset, forces, seeds, names, kind: str) -> dict:
    """``fset``'s frames of ``forces`` (k, E, 3) made again with ``seeds``: the outputs ``names`` stacked.

    Renders take seconds each, so they are kept in the user cache folder
    (subfolder ``kind``), keyed by the set, the loads and the seeds.
    """
    from optitact.io.cache import cached_arrays
    from optitact.io.files import json_fingerprint

    forces = np.asarray(forces, dtype=np.float64)

    def render() -> dict:
        maker = _maker(fset, keep_frames="frame" in names)
        made = [maker(f, int(s)) for f, s in zip(forces, seeds, strict=True)]
        return {k: np.stack([m[k] for m in made]) for k in names}

    def check(a: dict) -> None:
        if any(len(a[k]) != len(forces) for k in names):
            raise ValueError("not these renders")

    key = {"set": dict(fset.attrs), "forces": json_fingerprint(forces.tolist(), 16),
           "seeds": [int(s) for s in seeds], "names": list(names)}
    return cached_arrays(kind, key, render, check)


def render_floor(fset, cals: dict, frames: int, fs) -> dict:
    """Each model's error floor on a held-out set: its forces' spread between renders of the same loads.

    The first ``frames`` frames of ``fset`` are made again as the set made
    them (same loads and renderer, other render and CCD seeds) and read by
    every calibration in ``cals``. Two renders of one load differ by the
    noise of both, so ``rms(F2 - F1) / sqrt(2)`` over the loaded samples is
    the RMSE a perfect calibration would show on one render: the part of a
    held-out RMSE that no calibration can remove (the frames' Monte Carlo
    noise and the camera's). What a model shows above it,
    ``sqrt(RMSE^2 - floor^2)``, is its own. The re-renders' readings are kept
    in the user cache folder (``bench-floor``), keyed by the set and its loads.

    Returns
    -------
    dict
        Per model ``{"fx_floor_pct_fs", "fy_floor_pct_fs", "fz_floor_pct_fs"}``
        (% of ``fs``), with ``frames`` and ``samples`` (loaded samples).
    """
    from optitact.pipeline.readings import Readings

    if fset.attrs.get("render_mode", "full") == "two_stage":
        seeds_note = "two-stage frames: no Monte Carlo noise, the camera's alone"
    else:
        seeds_note = "path-traced frames: their Monte Carlo noise and the camera's"
    n = min(int(frames), int(fset.done.sum()))
    truth = fset.forces()[:n]
    seeds = np.random.SeedSequence([int(fset.attrs["seed"]), 78]).generate_state(n)
    a = _made_again(fset, truth, seeds, ("G", "u", "contact", "saturated"), "bench-floor")
    second = Readings(a["G"], a["u"], a["contact"], a["saturated"])
    first = fset.readings()[:n]
    loaded = truth[..., 2] > 0
    out = {}
    for model, cal in cals.items():
        diff = (cal.forces(second)[0] - cal.forces(first)[0])[loaded]
        floor = np.sqrt(np.mean(diff**2, axis=0) / 2.0)
        out[model] = {f"{ax}_floor_pct_fs": round(float(100 * floor[i] / fs[i]), 3)
                      for i, ax in enumerate(("fx", "fy", "fz"))}
        out[model] |= {"frames": n, "samples": int(loaded.sum()), "from": seeds_note}
    return out


def _scores(est, truth, clamped, readings, fs, ring, contact_min_n) -> dict:
    """RMSE (N and % FS), bias and per-ring RMSE over the loaded samples; flag and clamp rates over all."""
    loaded = truth[..., 2] > 0
    err = (est - truth)[loaded]
    rmse = np.sqrt(np.mean(err**2, axis=0))
    bias = err.mean(axis=0)
    e_of = np.nonzero(loaded)[1]
    should = truth[..., 2] >= contact_min_n
    out = {}
    for i, ax in enumerate(("fx", "fy", "fz")):
        out[f"{ax}_rmse_n"] = round(float(rmse[i]), 5)
        out[f"{ax}_rmse_pct_fs"] = round(float(100 * rmse[i] / fs[i]), 3)
        out[f"{ax}_bias_pct_fs"] = round(float(100 * bias[i] / fs[i]), 3)
    out["per_ring"] = [{"ring": int(r), "samples": int(np.sum(ring[e_of] == r)),
                        **{f"{ax}_rmse_pct_fs": round(float(100 * np.sqrt(np.mean(err[ring[e_of] == r, i] ** 2))
                                                            / fs[i]), 3)
                           for i, ax in enumerate(("fx", "fy", "fz"))}}
                       for r in np.unique(ring) if np.any(ring[e_of] == r)]
    out["max_abs_error_n"] = round(float(np.abs(err).max()), 5) if err.size else 0.0
    out["contact_flag_error_rate"] = round(float(np.mean(readings.contact != should)), 5)
    out["clamped_rate"] = round(float(np.mean(clamped)), 5)
    return out


#: Targets of the accuracy bench (% of full scale): Fz of 1 N, Fx and Fy of 0.5 N.
TARGET_PCT_FS = {"fx": 1.0, "fy": 1.0, "fz": 0.5}


def _per_axis(values) -> dict:
    """``{"fx": ..., "fy": ..., "fz": ...}`` of three values, rounded to 4 decimals."""
    return {ax: round(float(v), 4) for ax, v in zip(("fx", "fy", "fz"), values, strict=True)}


def _plot_families(out: dict, path):
    """RMSE (% FS) per family, one panel per axis, one bar per model, with the targets; and the coverage.

    A fourth panel (when the held-out sets kept their frames) shows, per family and
    axis, the fraction of true forces inside the last model's 90 % intervals.
    """
    from optitact._optional import require
    from optitact.io.files import atomic_write_png_figure

    require("matplotlib", purpose="the accuracy plot")
    from matplotlib.figure import Figure

    fams = list(out["families"])
    models = list(out["families"][fams[0]]["models"])
    last = models[-1]
    with_coverage = "coverage_90" in out["families"][fams[0]]["models"][last]
    fig = Figure(figsize=(20 if with_coverage else 15, 4.8))
    axes = fig.subplots(1, 4 if with_coverage else 3)
    width = 0.8 / len(models)
    x = np.arange(len(fams))
    for ax, axis in zip(axes, ("fx", "fy", "fz"), strict=False):
        for i, model in enumerate(models):
            vals = [out["families"][f]["models"][model][f"{axis}_rmse_pct_fs"] for f in fams]
            ax.bar(x + (i - (len(models) - 1) / 2) * width, vals, width, label=model)
        floors = [out["families"][f]["models"][last].get(f"{axis}_floor_pct_fs", np.nan) for f in fams]
        if not np.all(np.isnan(floors)):  # what no calibration can remove from these renders
            ax.scatter(x, floors, marker="_", s=900, linewidths=2, color="k", zorder=3,
                       label=f"{last}: floor (re-renders)")
        ax.axhline(TARGET_PCT_FS[axis], color="k", ls=":", lw=1, label=f"target {TARGET_PCT_FS[axis]:g} % FS")
        ax.set_xticks(x)
        ax.set_xticklabels(fams, rotation=30, ha="right")
        ax.set_ylim(0, 1.3 * ax.get_ylim()[1])  # room for the legend above the bars
        ax.set_ylabel(f"{axis.upper()} RMSE (% of full scale)")
        ax.set_title(f"{axis.upper()}: held-out error per load family")
        ax.legend(fontsize=8, ncol=2, loc="upper center")
    if with_coverage:  # per family, then every family's samples together, with the spread over frames
        ax = axes[3]
        w = 0.8 / 3
        groups = [out["families"][f]["models"][last] for f in fams]
        labels = list(fams)
        if last in out.get("coverage_90_pooled", {}):
            groups.append(out["coverage_90_pooled"][last])
            labels.append("all (pooled)")
        xc = np.arange(len(groups))
        for i, axis in enumerate(("fx", "fy", "fz")):
            vals = [g["coverage_90"][axis] for g in groups]
            sd = [g.get("coverage_90_sd", {}).get(axis, np.nan) for g in groups]
            ax.bar(xc + (i - 1) * w, vals, w, yerr=sd, capsize=2, label=axis.upper(), color=f"C{i + 4}")
        ax.axhspan(0.88, 0.92, color="0.85", zorder=0, label="0.88-0.92")
        ax.axhline(0.9, color="k", ls=":", lw=1)
        ax.set_xticks(xc)
        ax.set_xticklabels(labels, rotation=30, ha="right")
        low = min(g["coverage_90"][a] for g in groups for a in ("fx", "fy", "fz"))
        ax.set_ylim(min(0.8, np.floor(20 * low - 0.5) / 20), 1.0)  # the 0.88-0.92 band large enough to read
        ax.set_ylabel("fraction of true forces inside")
        # without a validation set the intervals hold the fit residuals as the model error
        ax.set_title(f"{last}: 90 % intervals (± sd over frames)" if "validation_set" in out else
                     f"{last}: 90 % intervals (fit residuals: no validation set)")
        ax.legend(fontsize=8, ncol=4, loc="upper center")
    fig.suptitle(f"calibration set: {out['calibration_set']['path'].rsplit('/', 1)[-1]}; held-out "
                 f"{out['test_set']['render_mode']} at {out['test_spp']} spp", fontsize=10)
    fig.tight_layout()
    return atomic_write_png_figure(fig, path, dpi=100)
