"""Benchmark: render time side by side with the error it leaves, per mode and setting.

Not library code: ``optitact bench render`` runs it. Every figure is a median
over repeats taken in one run, because the machine is shared and noisy.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from optitact._validate import integer
from optitact.optics.camera import FisheyeCamera
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["bench_render", "render_cases", "RENDER_MODES"]

#: First samples per pixel of the adaptive mode (it then adds passes of 16 until its target).
SPP_MIN_ADAPTIVE = 64


def render_cases(sensor: DomeSensor, seed: int = 11) -> dict[str, np.ndarray]:
    """The fixed load cases of the render benchmark: 1, 5 and 41 loaded elements, light and heavy."""
    from optitact.optics.loads import random_load

    five = [0, 1, 3, 9, 25]
    cases = {}
    for name, fz, shear in (("1-light", 0.3, 0.05), ("1-heavy", 0.9, 0.2)):
        f = np.zeros((sensor.n_elements, 3))
        f[0] = (shear, 0.0, fz)
        cases[name] = f
    for name, fz, shear in (("5-light", 0.3, 0.05), ("5-heavy", 0.9, 0.2)):
        f = np.zeros((sensor.n_elements, 3))
        f[five, 2] = fz
        f[five, 0] = shear
        cases[name] = f
    cases["41"] = random_load(sensor, seed=seed)
    return cases


def _render_readings(images: dict, sensor, camera, noload, ccd, cal):
    """Readings (and forces) of noise-free camera frames made from radiance images."""
    from optitact.pipeline.frame_pipeline import Pipeline

    options = dict(cal.pipeline_options) if cal is not None else {}
    pipe = Pipeline(sensor, camera, baseline=ccd.mean_dn(noload), **options)
    out = {}
    for key, img in images.items():
        r = pipe.process(ccd.mean_dn(img))
        out[key] = (r, None if cal is None else cal.forces(r)[0])
    return out


#: Render modes of :func:`bench_render`, and what their "setting" is.
RENDER_MODES = {"brute": "spp", "pixels": "spp", "adaptive": "target relative error per element",
                "two_stage": "sub-pixel rays per side"}


def bench_render(spps=(16, 64, 256), *, modes=("brute", "pixels", "adaptive", "two_stage"),
                 targets=(0.02, 0.01, 0.005), n_subs=(4, 8), reference_spp: int = 4096,
                 width: int = 640, height: int = 480, repeats: int = 1, cases=None,
                 target_pct_fs: float = 0.5, variant: str | None = None, seed: int = 0,
                 plot=None, progress: bool = True, table=None) -> dict:
    """Render time against the error it leaves, per mode and setting, on fixed load cases.

    Parameters
    ----------
    spps : sequence of int
        Samples per pixel measured for ``"brute"`` and ``"pixels"``.
    modes : sequence of str
        ``"brute"``: path-traced full frames (the reference method);
        ``"pixels"``: path-traced, only the loaded elements' pixels
        (:func:`optitact.render.pathtrace.spot_pixels`) over the cached no-load frame;
        ``"adaptive"``: as ``"pixels"``, with passes until every loaded
        element's summed radiance reaches a target relative standard error;
        ``"two_stage"``: the two-stage light transport
        (:mod:`optitact.render.twostage`), no Monte Carlo noise.
    targets : sequence of float
        Target relative errors measured for ``"adaptive"``.
    n_subs : sequence of int
        Sub-pixel rays per side measured for ``"two_stage"``.
    reference_spp : int
        Samples per pixel of the converged reference of each case (spot
        pixels only, the same estimator per pixel; cached on disk).
    width, height : int
    repeats : int
        Renders per row; times are medians, errors are RMS over repeats.
    cases : sequence of str, optional
        Names from :func:`render_cases` (default all).
    target_pct_fs : float
        Force error (% of full scale) at which ``speedup_at_equal_error`` and
        ``calibration_frame_s`` are stated.
    variant : str, optional
    seed : int
    plot : path-like, optional
        Error against time (log-log), one curve per mode, for the 41-element
        case (or the last case).
    progress : bool
        Show a progress bar on stderr.
    table : EmissionTable, optional
        The two-stage table (default: the cached one for this camera,
        measured on first use).

    Returns
    -------
    dict
        ``rows`` (case, mode, setting, seconds, G relative error, u error
        (mm), force error (% FS) through the shipped calibration where it
        applies to this camera),
        ``pareto`` per case, ``one_time_s`` (the cached no-load frame and the
        two-stage table, which every later frame reuses) and ``headline``:
        ``seconds_at_target`` per mode for the 41-element case,
        ``speedup_at_equal_error`` (brute ÷ best mode) and
        ``calibration_frame_s`` (the best mode's seconds).

    Notes
    -----
    Errors are those of the render alone: radiance is turned into
    noise-free DN (:meth:`CCD.mean_dn`), read with a pipeline whose
    baseline is the converged no-load frame, and compared with the
    reference's readings on the loaded elements. Path-traced modes whose
    largest setting misses the target are extrapolated with error ~
    1/sqrt(spp) and time ~ spp; the two-stage mode has no noise to average
    away, so it reaches the target only if one of its rows does.
    """
    from tqdm import tqdm

    from optitact.render.cache import cached_render
    from optitact.calib.shipped import default_calibration
    from optitact.optics.ccd import CCD
    from optitact.render.backend import active_variant
    from optitact.render import render
    from optitact.render.pathtrace import spot_pixels
    from optitact.render.emission import emission_table
    from optitact.render.background import noload_radiance

    spps = tuple(integer(v, "spps[]", minimum=1) for v in spps)
    n_subs = tuple(integer(v, "n_subs[]", minimum=1) for v in n_subs)
    targets = tuple(float(t) for t in targets)
    if any(not 0 < t < 1 for t in targets):
        raise InputError(f"targets must lie in (0, 1), got {targets}")
    repeats = integer(repeats, "repeats", minimum=1)
    reference_spp = integer(reference_spp, "reference_spp", minimum=1)
    for m in modes:
        if m not in RENDER_MODES:
            raise InputError(f"modes must be among {sorted(RENDER_MODES)}, got {m!r}")
    sensor = DomeSensor.default()
    camera = FisheyeCamera(width=integer(width, "width", minimum=2),
                           height=integer(height, "height", minimum=2))
    all_cases = render_cases(sensor)
    names = list(all_cases) if cases is None else list(cases)
    for n in names:
        if n not in all_cases:
            raise InputError(f"unknown case {n!r}; valid: {sorted(all_cases)}")
    ccd = CCD()
    cal = default_calibration()
    if cal.camera != camera:
        cal = None
    render(sensor, np.zeros((sensor.n_elements, 3)), camera=camera, spp=1, variant=variant)
    one_time = {}
    t0 = time.perf_counter()
    noload = noload_radiance(sensor, camera, variant=variant)
    one_time["noload_s"] = round(time.perf_counter() - t0, 2)
    if "two_stage" in modes:
        t0 = time.perf_counter()
        if table is None:
            measuring = camera if isinstance(camera, FisheyeCamera) else None
            table = emission_table(sensor, measuring, variant=variant, progress=progress)
        one_time["two_stage_table_s"] = round(time.perf_counter() - t0, 2)
        one_time["two_stage_table_build_s"] = table.meta.get("seconds")
    settings = {"brute": spps, "pixels": spps, "adaptive": targets, "two_stage": n_subs}
    fs = np.array([0.5, 0.5, 1.0])
    rows = []
    jobs = [(c, m, v, k) for c in names for m in modes for v in settings[m] for k in range(repeats)]
    bar = tqdm(total=len(jobs) + len(names), desc="bench render", unit="render", file=sys.stderr,
               disable=not progress)
    for case in names:
        f = all_cases[case]
        loaded = f[:, 2] > 0
        mask = spot_pixels(sensor, camera, f)
        ref = cached_render(sensor, f, camera=camera, spp=reference_spp, seed=seed + 5,
                            variant=variant, spot_pixels_only=True)
        ref = np.where(mask, ref, noload)
        bar.update(1)
        for mode in modes:
            for value in settings[mode]:
                times, images = [], {}
                for k in range(repeats):
                    kw = dict(camera=camera, seed=seed + 100 + k, variant=variant)
                    if mode == "brute":
                        kw.update(spp=value)
                    elif mode == "pixels":
                        kw.update(spp=value, pixels=mask, background=noload)
                    elif mode == "adaptive":
                        kw.update(spp=min(SPP_MIN_ADAPTIVE, reference_spp), pixels=mask, background=noload,
                                  target_error=value, max_spp=reference_spp)
                    else:
                        kw.update(transport="two_stage", n_sub=value, table=table, background=noload)
                    t0 = time.perf_counter()
                    images[k] = render(sensor, f, **kw)
                    times.append(time.perf_counter() - t0)
                    bar.update(1)
                images["ref"] = ref
                read = _render_readings(images, sensor, camera, noload, ccd, cal)
                r_ref, f_ref = read.pop("ref")
                seen = loaded & r_ref.contact  # loaded elements the reference sees
                if not seen.any():
                    raise InputError(f"case {case}: the reference shows no loaded element at "
                                     f"{camera.width}x{camera.height}; use a larger image")
                g_err, u_err, f_err = [], [], []
                for r, est in read.values():
                    g_err.append((r.G[seen] - r_ref.G[seen]) / r_ref.G[seen])
                    u_err.append(np.linalg.norm(r.u[seen] - r_ref.u[seen], axis=-1))
                    if est is not None:
                        f_err.append((est[loaded] - f_ref[loaded]) / fs)
                row = {"case": case, "mode": mode, "setting": value,
                       "seconds": round(float(np.median(times)), 4),
                       "g_rel_error": round(float(np.sqrt(np.mean(np.square(g_err)))), 5),
                       "u_error_mm": round(float(np.sqrt(np.mean(np.square(u_err)))), 5)}
                if f_err:
                    per_axis = np.sqrt(np.mean(np.square(f_err), axis=(0, 1)))
                    row["force_error_pct_fs"] = round(float(100 * per_axis.max()), 4)
                rows.append(row)
    bar.close()
    err_key = "force_error_pct_fs" if cal is not None else "g_rel_error"
    target = target_pct_fs if cal is not None else target_pct_fs / 100
    pareto = {}
    for case in names:
        best = np.inf
        front = []
        for row in sorted((r for r in rows if r["case"] == case), key=lambda r: r["seconds"]):
            if row[err_key] < best:
                best = row[err_key]
                front.append(f"{row['mode']}@{row['setting']}")
        pareto[case] = front

    def time_at_target(case, mode):
        mine = [r for r in rows if r["case"] == case and r["mode"] == mode]
        ok = [r["seconds"] for r in mine if r[err_key] <= target]
        if ok:
            return min(ok)
        if mode == "two_stage":
            return None
        # Monte Carlo modes: error ~ 1/sqrt(time) from the most accurate row.
        top = min(mine, key=lambda r: r[err_key])
        return top["seconds"] * (top[err_key] / target) ** 2

    head_case = "41" if "41" in names else names[-1]
    t_modes = {m: time_at_target(head_case, m) for m in modes}
    reached = {m: t for m, t in t_modes.items() if t is not None}
    best_mode = min(reached, key=reached.get) if reached else None  # None: no mode reached the target
    headline = {"case": head_case, "error_measure": err_key, "target": target,
                "seconds_at_target": {m: None if t is None else round(t, 4) for m, t in t_modes.items()},
                "best_mode": best_mode,
                "calibration_frame_s": None if best_mode is None else round(reached[best_mode], 4)}
    if "brute" in reached:
        headline["speedup_at_equal_error"] = round(reached["brute"] / reached[best_mode], 1)
    result = {"variant": active_variant()["variant"], "size": f"{camera.width}x{camera.height}",
              "reference_spp": reference_spp, "repeats": repeats, "settings": RENDER_MODES,
              "one_time_s": one_time, "rows": rows, "pareto": pareto, "headline": headline,
              "calibration": "shipped (default)" if cal is not None else None}
    if plot is not None:
        from optitact._optional import require
        from optitact.io.files import atomic_write_png_figure

        fig = require("matplotlib.figure", purpose="plots").Figure(figsize=(6, 4.5), layout="constrained")
        ax = fig.subplots()
        for mode in modes:
            pts = sorted((r["seconds"], r[err_key]) for r in rows
                         if r["case"] == head_case and r["mode"] == mode)
            ax.loglog(*zip(*pts, strict=True), "o-", label=mode)
        ax.axhline(target, color="k", lw=0.8, ls="--", label="target")
        ax.set(xlabel="seconds per frame", ylabel=err_key.replace("_", " "),
               title=f"render time vs error, case {head_case}, {camera.width}x{camera.height}")
        ax.legend()
        atomic_write_png_figure(fig, plot, dpi=100)
        result["plot"] = str(plot)
    return result
