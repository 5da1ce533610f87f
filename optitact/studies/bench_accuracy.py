"""Benchmark: force errors of both calibration models on a held-out synthetic set.

Not library code: ``optitact bench accuracy`` runs it.
"""

from __future__ import annotations

import sys

import numpy as np

from optitact._validate import integer
from optitact.errors import InputError
from optitact.camera import FisheyeCamera

__all__ = ["bench_accuracy"]


def bench_accuracy(*, frames: int = 100, test_frames: int = 30, spp: int = 64,
                   test_spp: int | None = None, size: tuple[int, int] = (640, 480),
                   calibration_set=None, test_set=None, seed: int = 0,
                   variant: str | None = None, plot=None, contact_min_n: float = 0.01,
                   render_mode: str = "two_stage", test_render_mode: str = "pixels") -> dict:
    """Force errors of both calibration models on a held-out synthetic set.

    Parameters
    ----------
    frames, test_frames : int
        Frames of the calibration and the held-out set (41 samples each).
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
        :func:`optitact.calib.generate`); by default the calibration comes
        from the two-stage light transport and is tested on path-traced frames.

    Returns
    -------
    dict
        ``{"models": {"ohka": {...}, "coupled": {...}}, ...}`` with, per model,
        ``fx_rmse_n``, ``fy_rmse_n``, ``fz_rmse_n``, the same as % of full
        scale (``fz_max`` for Fz, ``shear_max`` for Fx and Fy),
        ``max_abs_error_n``, ``contact_flag_error_rate`` and
        ``clamped_rate``, over every element sample of the held-out set.
    """
    from optitact._cache import cache_dir
    from optitact.calib import MODELS, CalibrationSet, fit, generate
    from optitact.calib.plots import plot_errors

    width, height = size
    camera = FisheyeCamera(width=integer(width, "width", minimum=2),
                           height=integer(height, "height", minimum=2))
    sets = cache_dir() / "sets"

    def get(given, n, s, tag, n_spp, mode):
        if given is not None:
            return CalibrationSet(given)
        path = sets / f"{tag}-{width}x{height}-f{n}-spp{n_spp}-seed{s}-{mode}.zarr"
        print(f"optitact: bench accuracy: {tag} set {path}", file=sys.stderr)
        if path.exists():
            cached = CalibrationSet(path)
            if cached.complete:  # made earlier (possibly by an older version): use as is
                return cached
        return generate(path, frames=n, camera=camera, spp=n_spp, seed=s, variant=variant, render_mode=mode)

    test_spp = spp if test_spp is None else integer(test_spp, "test_spp", minimum=1)
    cs = get(calibration_set, frames, seed, "calibration", spp, render_mode)
    ts = get(test_set, test_frames, seed + 1000, "test", test_spp, test_render_mode)
    if ts.attrs["seed"] == cs.attrs["seed"]:
        raise InputError("the held-out set must have another seed than the calibration set")
    truth = ts.forces()
    readings = ts.readings()
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
    for model in MODELS:
        cal = fit(cs, model=model)
        est, clamped = cal.forces(readings)
        estimates[model] = est
        err = est - truth
        rmse = np.sqrt(np.mean(err**2, axis=(0, 1)))
        should = truth[..., 2] >= contact_min_n
        out["models"][model] = {
            "fx_rmse_n": round(float(rmse[0]), 5), "fy_rmse_n": round(float(rmse[1]), 5),
            "fz_rmse_n": round(float(rmse[2]), 5),
            "fx_rmse_pct_fs": round(float(100 * rmse[0] / fs[0]), 3),
            "fy_rmse_pct_fs": round(float(100 * rmse[1] / fs[1]), 3),
            "fz_rmse_pct_fs": round(float(100 * rmse[2] / fs[2]), 3),
            "max_abs_error_n": round(float(np.abs(err).max()), 5),
            "contact_flag_error_rate": round(float(np.mean(readings.contact != should)), 5),
            "clamped_rate": round(float(np.mean(clamped)), 5),
        }
    if plot is not None:
        plot_errors(truth, estimates, plot)
        out["plot"] = str(plot)
    return out
