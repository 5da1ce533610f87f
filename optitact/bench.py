"""Benchmarks: run time side by side with the error it buys.

Every figure is a median over repeats taken in one run, because the machine
is shared and noisy.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from ._validate import integer
from .camera import FisheyeCamera
from .loads import indenter_load
from .sensor import DomeSensor

__all__ = ["bench_render", "bench_pipeline", "bench_accuracy"]


def bench_render(spps=(16, 64, 256), *, repeats: int = 3, width: int = 640, height: int = 480,
                 variant: str | None = None, seed: int = 0) -> dict:
    """Time full-frame renders of the demo load and measure their Monte Carlo noise.

    Parameters
    ----------
    spps : sequence of int
        Samples per pixel to measure.
    repeats : int
        Renders per spp (>= 2), each with its own seed; times are reported as
        median and all runs.
    width, height : int
        Image size.
    variant : str, optional
        Mitsuba variant (default: the fastest that works).
    seed : int
        Base seed; repeat ``k`` uses ``seed + k``.

    Returns
    -------
    dict
        ``variant``, ``size`` and per spp: ``median_s``, ``runs_s``,
        ``spot_pixel_rel_noise`` (RMS per-pixel difference between repeats,
        divided by sqrt(2) and by the mean radiance, over pixels that belong to
        spots) and ``spot_sum_rel_spread`` (relative standard deviation of the
        total spot radiance over repeats: the noise of an integrated grey value).

    Notes
    -----
    A warm-up render (1 spp) compiles the kernels and selects the variant
    first, so the times are those of a warm process. Spot pixels are those
    where the mean over repeats exceeds 10 % of its 99.9th percentile.
    """
    from tqdm import tqdm

    from .render import active_variant, render

    repeats = integer(repeats, "repeats", minimum=2)
    spps = tuple(integer(spp, "spps[]", minimum=1) for spp in spps)
    sensor = DomeSensor.default()
    camera = FisheyeCamera(width=width, height=height)
    forces = indenter_load(sensor)
    render(sensor, forces, camera=camera, spp=1, seed=seed, variant=variant)
    result = {"variant": active_variant()["variant"], "size": f"{width}x{height}",
              "load": "indenter_load (demo)", "repeats": repeats, "spp": {}}
    jobs = [(spp, k) for spp in spps for k in range(repeats)]
    images: dict[int, list] = {spp: [] for spp in spps}
    times: dict[int, list] = {spp: [] for spp in spps}
    for spp, k in tqdm(jobs, desc="bench render", unit="frame", file=sys.stderr):
        t0 = time.perf_counter()
        img = render(sensor, forces, camera=camera, spp=spp, seed=seed + k, variant=variant)
        times[spp].append(time.perf_counter() - t0)
        images[spp].append(img.astype(np.float64))
    for spp in spps:
        stack = np.stack(images[spp])
        mean = stack.mean(axis=0)
        spot = mean > 0.1 * np.percentile(mean, 99.9)
        diff = (stack[0] - stack[1])[spot] / np.sqrt(2.0)
        sums = stack[:, spot].sum(axis=1)
        result["spp"][str(spp)] = {
            "median_s": round(float(np.median(times[spp])), 3),
            "runs_s": [round(t, 3) for t in times[spp]],
            "spot_pixel_rel_noise": round(float(np.sqrt(np.mean(diff**2)) / mean[spot].mean()), 4),
            "spot_sum_rel_spread": round(float(sums.std(ddof=1) / sums.mean()), 5),
        }
    return result


def _median_rate(n: int, seconds: list[float]) -> float:
    return float(n / np.median(seconds))


def bench_pipeline(sizes=((640, 480), (480, 480)), *, n_frames: int = 16, repeats: int = 5,
                   n_reference: int = 3, spp: int = 64, seed: int = 0,
                   variant: str | None = None) -> dict:
    """Frames per second of the fast and reference pipelines and of one pass over the frame.

    Parameters
    ----------
    sizes : sequence of (width, height)
        Camera sizes to measure.
    n_frames : int
        Distinct frames per size: one render of all 41 elements loaded
        (:func:`optitact.loads.random_load`) exposed with ``n_frames`` CCD
        noise seeds (uint8); the baseline is a no-load render, exposed.
        Renders are cached in the user cache folder.
    repeats : int
        Timing repeats; rates are medians over repeats, each repeat timing
        fast, batch, floor and reference side by side.
    n_reference : int
        Frames the reference processes per repeat (it is slow).
    spp : int
        Samples per pixel of the renders.
    seed : int
        Seed of the load, the renders and the noise.
    variant : str, optional
        Mitsuba variant for the renders.

    Returns
    -------
    dict
        ``cores``, ``threads`` and per size ``WxH``: ``fast_fps`` (frame by
        frame), ``batch_fps`` (one ``(T, H, W)`` call), ``reference_fps``,
        ``speedup`` (fast / reference), ``floor_fps`` (``np.count_nonzero(frame
        > t)``, one pass), ``floor_over_fast`` (how many times slower than the
        floor the fast path is), ``max_G_rel_diff`` and ``max_u_diff_mm``
        (fast vs reference over the reference's frames, elements in
        contact), ``flags_identical``, ``elements_in_contact``, ``lit_pixels``
        (median per frame), ``precompute_s``.
    """
    import os
    import platform

    from tqdm import tqdm

    from ._cache import cached_render
    from .ccd import CCD
    from .loads import random_load
    from .pipeline import Pipeline

    n_frames = integer(n_frames, "n_frames", minimum=1)
    repeats = integer(repeats, "repeats", minimum=1)
    n_reference = integer(n_reference, "n_reference", minimum=1)
    spp = integer(spp, "spp", minimum=1)
    sensor = DomeSensor.default()
    forces = random_load(sensor, seed=seed)
    ccd = CCD()
    result: dict = {"cores": os.cpu_count(), "threads": 1,
                    "python": platform.python_version(), "numpy": np.__version__,
                    "frames": f"{n_frames} uint8 frames per size: all 41 elements loaded "
                              f"(random_load seed {seed}), rendered at {spp} spp, CCD noise",
                    "floor": "np.count_nonzero(frame > threshold), one pass over the frame"}
    for width, height in sizes:
        camera = FisheyeCamera(width=integer(width, "width", minimum=2),
                               height=integer(height, "height", minimum=2))
        print(f"optitact: bench pipeline {width}x{height}: rendering (cached after the first run)",
              file=sys.stderr)
        loaded = cached_render(sensor, forces, camera=camera, spp=spp, seed=seed, variant=variant)
        empty = cached_render(sensor, np.zeros_like(forces), camera=camera, spp=spp,
                              seed=seed + 1, variant=variant)
        frames = np.stack([ccd.expose(loaded, seed=seed + 100 + k) for k in range(n_frames)])
        baseline = ccd.expose(empty, seed=seed + 99)
        t0 = time.perf_counter()
        fast = Pipeline(sensor, camera, baseline=baseline)
        precompute = time.perf_counter() - t0
        ref = fast.replace(method="reference")
        sub = frames[:n_reference]
        t_fast, t_batch, t_floor, t_ref = [], [], [], []
        thr = int(np.ceil(fast.threshold + baseline.mean()))
        fast.process(frames[0])  # warm caches (level maps)
        for _ in tqdm(range(repeats), desc=f"bench pipeline {width}x{height}", unit="repeat",
                      file=sys.stderr):
            t = time.perf_counter()
            for f in frames:
                fast.process(f)
            t_fast.append(time.perf_counter() - t)
            t = time.perf_counter()
            fast.process(frames)
            t_batch.append(time.perf_counter() - t)
            t = time.perf_counter()
            for f in frames:
                np.count_nonzero(f > thr)
            t_floor.append(time.perf_counter() - t)
            t = time.perf_counter()
            for f in sub:
                ref.process(f)
            t_ref.append(time.perf_counter() - t)
        rf, rr = fast.process(sub), ref.process(sub)
        both = rr.contact & rf.contact
        g_rel = np.abs(rf.G - rr.G)[both] / rr.G[both]
        lit = [int(np.count_nonzero(f.astype(np.float64) - baseline > fast.threshold))
               for f in sub]
        fast_fps = _median_rate(n_frames, t_fast)
        floor_fps = _median_rate(n_frames, t_floor)
        ref_fps = _median_rate(len(sub), t_ref)
        result[f"{width}x{height}"] = {
            "fast_fps": round(fast_fps, 1),
            "batch_fps": round(_median_rate(n_frames, t_batch), 1),
            "reference_fps": round(ref_fps, 2),
            "speedup": round(fast_fps / ref_fps, 1),
            "floor_fps": round(floor_fps, 1),
            "floor_over_fast": round(floor_fps / fast_fps, 2),
            "max_G_rel_diff": float(g_rel.max()) if g_rel.size else 0.0,
            "max_u_diff_mm": float(np.abs(rf.u - rr.u).max()),
            "flags_identical": bool(np.array_equal(rf.contact, rr.contact)
                                    and np.array_equal(rf.saturated, rr.saturated)),
            "elements_in_contact": int(rf.contact[0].sum()),
            "lit_pixels": int(np.median(lit)),
            "precompute_s": round(precompute, 3),
        }
    return result


def bench_accuracy(*, frames: int = 100, test_frames: int = 30, spp: int = 64,
                   test_spp: int | None = None, size: tuple[int, int] = (640, 480),
                   calibration_set=None, test_set=None, seed: int = 0,
                   variant: str | None = None, plot=None, contact_min_n: float = 0.01) -> dict:
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

    Returns
    -------
    dict
        ``{"models": {"ohka": {...}, "coupled": {...}}, ...}`` with, per model,
        ``fx_rmse_n``, ``fy_rmse_n``, ``fz_rmse_n``, the same as % of full
        scale (``fz_max`` for Fz, ``shear_max`` for Fx and Fy),
        ``max_abs_error_n``, ``contact_flag_error_rate`` and
        ``clamped_rate``, over every element sample of the held-out set.
    """
    from ._cache import cache_dir
    from .calib import MODELS, CalibrationSet, fit, generate
    from .calib.plots import plot_errors

    width, height = size
    camera = FisheyeCamera(width=integer(width, "width", minimum=2),
                           height=integer(height, "height", minimum=2))
    sets = cache_dir() / "sets"

    def get(given, n, s, tag, n_spp):
        if given is not None:
            return CalibrationSet(given)
        path = sets / f"{tag}-{width}x{height}-f{n}-spp{n_spp}-seed{s}.zarr"
        print(f"optitact: bench accuracy: {tag} set {path}", file=sys.stderr)
        return generate(path, frames=n, camera=camera, spp=n_spp, seed=s, variant=variant)

    test_spp = spp if test_spp is None else integer(test_spp, "test_spp", minimum=1)
    cs = get(calibration_set, frames, seed, "calibration", spp)
    ts = get(test_set, test_frames, seed + 1000, "test", test_spp)
    if ts.attrs["seed"] == cs.attrs["seed"]:
        raise ValueError("the held-out set must have another seed than the calibration set")
    truth = ts.forces()
    readings = ts.readings()
    design = cs.attrs["design"]
    fs = np.array([design["shear_max"], design["shear_max"], design["fz_max"]])
    out: dict = {"size": f"{camera.width}x{camera.height}", "spp": int(cs.attrs["spp"]),
                 "test_spp": int(ts.attrs["spp"]),
                 "calibration_set": {"path": str(cs.path), "frames": int(cs.done.sum()),
                                     "seed": cs.attrs["seed"]},
                 "test_set": {"path": str(ts.path), "frames": int(ts.done.sum()),
                              "seed": ts.attrs["seed"], "samples": int(truth[..., 0].size)},
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
