"""Benchmark: frames/s of the fast and reference pipelines against one pass over the frame.

Not library code: ``optitact bench pipeline`` runs it. Medians over repeats
taken in one run, side by side, because the machine is shared and noisy.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from optitact._validate import integer
from optitact.camera import FisheyeCamera
from optitact.sensor import DomeSensor

__all__ = ["bench_pipeline"]


def _median_rate(n: int, seconds: list[float]) -> float:
    return float(n / np.median(seconds))


def _clock(into: list, fn, *args) -> None:
    t = time.perf_counter()
    fn(*args)
    into.append(time.perf_counter() - t)


def _each(pipe, frames) -> None:
    for f in frames:
        pipe.process(f)


def _start_up(sensor, camera, baseline, frame, *, repeats: int) -> tuple[float, float, float]:
    """Pipeline construction without and with the precompute cache, and a fresh process on one frame (s).

    Medians over ``repeats``; the in-memory copies are forgotten before
    each construction, so "cached" is a load from the cache folder.
    """
    import os
    import subprocess
    import tempfile

    from optitact import regions
    from optitact.pipeline import Pipeline

    def build(cache: bool) -> float:
        regions._fold_cached.cache_clear()
        old = os.environ.get("OPTITACT_PRECOMPUTE_CACHE")
        os.environ["OPTITACT_PRECOMPUTE_CACHE"] = "1" if cache else "0"
        try:
            t = time.perf_counter()
            Pipeline(sensor, camera, baseline=baseline)
            return time.perf_counter() - t
        finally:
            if old is None:
                del os.environ["OPTITACT_PRECOMPUTE_CACHE"]
            else:
                os.environ["OPTITACT_PRECOMPUTE_CACHE"] = old

    cold = [build(False) for _ in range(repeats)]
    build(True)  # the file is there
    cached = [build(True) for _ in range(repeats)]
    startup = []
    with tempfile.TemporaryDirectory() as tmp:
        np.save(os.path.join(tmp, "base.npy"), baseline)
        np.save(os.path.join(tmp, "frame.npy"), frame[None])
        cmd = [sys.executable, "-m", "optitact.cli", "process", os.path.join(tmp, "frame.npy"), "--baseline",
               os.path.join(tmp, "base.npy"), "--out", os.path.join(tmp, "r.csv")]
        if camera != FisheyeCamera(width=camera.width, height=camera.height):
            raise ValueError("the start-up bench runs the default camera of the frames' size")
        for _ in range(repeats):
            t = time.perf_counter()
            subprocess.run(cmd, check=True, capture_output=True)
            startup.append(time.perf_counter() - t)
    return float(np.median(cold)), float(np.median(cached)), float(np.median(startup))


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
        (median per frame), ``precompute_s`` (the pipeline's construction in
        this run), ``precompute_cold_s`` and ``precompute_cached_s`` (the
        construction without the precompute cache, and from the cache on
        disk, nothing in memory), ``startup_to_first_frame_s`` (wall time of
        a fresh ``python -m optitact.cli process`` on one frame with a
        baseline frame, interpreter start to table written, median of
        three); and side by side: ``kernel``
        (what ``fast`` ran: ``"numba"``, else ``"numpy"``), ``numpy_fps`` and
        ``floor_over_numpy`` (the NumPy fallback, frame by frame),
        ``kernels_identical`` (its readings equal the fast path's bit for
        bit), ``batch_1thread_fps`` and ``batch_threads_fps`` (a stack of at
        least 64 frames on one thread and on ``threads``, the cores this
        process may use) and ``threads_speedup`` (their ratio).
    """
    import os
    import platform

    from tqdm import tqdm

    from optitact._cache import cached_render
    from optitact.ccd import CCD
    from optitact.loads import random_load
    from optitact.pipeline import Pipeline, _cores

    n_frames = integer(n_frames, "n_frames", minimum=1)
    repeats = integer(repeats, "repeats", minimum=1)
    n_reference = integer(n_reference, "n_reference", minimum=1)
    spp = integer(spp, "spp", minimum=1)
    sensor = DomeSensor.default()
    forces = random_load(sensor, seed=seed)
    ccd = CCD()
    result: dict = {"cores": os.cpu_count(), "threads": _cores(),
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
        numpy_pipe = fast.replace(kernel="numpy")
        one_thread = fast.replace(threads=1)
        all_threads = fast.replace(threads=_cores())
        long = np.concatenate([frames] * max(1, -(-64 // n_frames)))  # a long stack: >= 64 frames
        sub = frames[:n_reference]
        t_fast, t_batch, t_floor, t_ref, t_numpy, t_b1, t_bn = [], [], [], [], [], [], []
        thr = int(np.ceil(fast.threshold + baseline.mean()))
        for p in (fast, numpy_pipe, one_thread, all_threads):
            p.process(frames[:2])  # warm caches (level maps, the compiled kernel)
        for _ in tqdm(range(repeats), desc=f"bench pipeline {width}x{height}", unit="repeat",
                      file=sys.stderr):
            _clock(t_fast, _each, fast, frames)
            _clock(t_numpy, _each, numpy_pipe, frames)
            _clock(t_batch, fast.process, frames)
            _clock(t_b1, one_thread.process, long)
            _clock(t_bn, all_threads.process, long)
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
        numpy_fps = _median_rate(n_frames, t_numpy)
        b1_fps, bn_fps = _median_rate(len(long), t_b1), _median_rate(len(long), t_bn)
        rn = numpy_pipe.process(sub)
        cold, cached, startup = _start_up(sensor, camera, baseline, frames[0], repeats=min(repeats, 3))
        result[f"{width}x{height}"] = {
            "kernel": fast.kernel,
            "fast_fps": round(fast_fps, 1),
            "numpy_fps": round(numpy_fps, 1),
            "floor_over_numpy": round(floor_fps / numpy_fps, 2),
            "kernels_identical": bool(all(np.array_equal(getattr(rf, k), getattr(rn, k))
                                          for k in ("G", "u", "contact", "saturated"))),
            "batch_1thread_fps": round(b1_fps, 1),
            "batch_threads_fps": round(bn_fps, 1),
            "threads_speedup": round(bn_fps / b1_fps, 2),
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
            "precompute_cold_s": round(cold, 3),
            "precompute_cached_s": round(cached, 4),
            "startup_to_first_frame_s": round(startup, 3),
        }
    return result
