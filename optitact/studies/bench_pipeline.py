"""Benchmark: per-frame cost of the fast and reference pipelines against one pass over the frame.

Not library code: ``optitact bench pipeline`` runs it. Every method is timed
side by side in each repeat of one run (CPU time and wall time, medians over
repeats), because the machine is shared and noisy; the one-pass floor
``np.count_nonzero(frame > t)`` is measured on the same frames in the same
repeats. Frames are two-stage renders (the contact patches as emitters, over
a dark background) exposed by the CCD model: realistic spot sizes at any
frame size in milliseconds, no path tracing.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from optitact._validate import integer
from optitact.optics.camera import FisheyeCamera
from optitact.optics.sensor import DomeSensor

__all__ = ["LOAD_CASES", "WARM_PASSES", "bench_pipeline"]

#: Untimed passes over the frames before each frame-by-frame timing. After the long stacks have
#: flushed the caches, one pass over 16 frames leaves the fast path at 1.2-2x its steady cost at
#: 640x480 with 41 elements loaded (measured on a 2-core VM); five bring it back.
WARM_PASSES = 5

#: Elements loaded -> the load case of :func:`optitact.studies.bench_render.render_cases`.
LOAD_CASES = {1: "1-heavy", 5: "5-heavy", 41: "41"}


def _clock(into: dict, name: str, fn, *args) -> None:
    """Append ``fn(*args)``'s wall and CPU seconds to ``into[name]``."""
    w, c = time.perf_counter(), time.process_time()
    fn(*args)
    into.setdefault(name, []).append((time.perf_counter() - w, time.process_time() - c))


def _each(pipe, frames) -> None:
    for f in frames:
        pipe.process(f)


def _floor(frames, thr) -> None:
    for f in frames:
        np.count_nonzero(f > thr)


def _start_up(sensor, camera, baseline, frame, *, repeats: int, startup: bool = True) -> tuple:
    """Pipeline construction without and with the precompute cache, a one-frame baseline, a fresh process (s).

    Medians over ``repeats`` (one cold construction above 1 Mpixel: seconds
    each); the in-memory copies are forgotten before each construction, so
    "cached" is a load from the cache folder. The start-up is None when not
    ``startup``.
    """
    import os
    import subprocess
    import tempfile

    from optitact.pipeline import regions
    from optitact.pipeline.frame_pipeline import Pipeline

    def build(cache: bool) -> float:
        regions.forget_folded_weights()
        old = os.environ.get("OPTITACT_PRECOMPUTE_CACHE")
        os.environ["OPTITACT_PRECOMPUTE_CACHE"] = "1" if cache else "0"
        try:
            t = time.perf_counter()
            Pipeline(sensor, camera)  # the sensor and camera's precompute (no baseline: see below)
            return time.perf_counter() - t
        finally:
            if old is None:
                del os.environ["OPTITACT_PRECOMPUTE_CACHE"]
            else:
                os.environ["OPTITACT_PRECOMPUTE_CACHE"] = old

    def with_baseline() -> float:
        pipe = Pipeline(sensor, camera)
        t = time.perf_counter()
        pipe.with_baseline(baseline)  # one frame: its noise, impulses and their floor per region
        return time.perf_counter() - t

    cold = [build(False) for _ in range(repeats if camera.width * camera.height <= 2**20 else 1)]
    build(True)  # the file is there
    cached = [build(True) for _ in range(repeats)]
    base = float(np.median([with_baseline() for _ in range(repeats)]))
    if not startup:
        return float(np.median(cold)), float(np.median(cached)), base, None
    runs = []
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
            runs.append(time.perf_counter() - t)
    return float(np.median(cold)), float(np.median(cached)), base, float(np.median(runs))


def _per_frame(times: list, n: int) -> tuple[float, float]:
    """Median wall and CPU microseconds per frame over repeats of ``n`` frames."""
    wall, cpu = np.median(np.asarray(times), axis=0)
    return float(wall / n * 1e6), float(cpu / n * 1e6)


def _one_load(sensor, camera, forces, baseline, pipes, *, n_frames, repeats, n_reference, seed, label):
    """The figures of one size and load case (see :func:`bench_pipeline`)."""
    from tqdm import tqdm

    from optitact.pipeline.fastpath import run_blocks
    from optitact.optics.ccd import CCD
    from optitact.render import render

    fast, numpy_pipe, one_thread, all_threads, ref = pipes
    radiance = render(sensor, forces, camera=camera, transport="two_stage",
                      background=np.zeros(camera.shape))
    ccd = CCD()
    frames = np.stack([ccd.expose(radiance, seed=seed + 100 + k) for k in range(n_frames)])
    # a long stack: >= 64 frames and >= 2**25 pixels (so that a thread's share is milliseconds of work)
    n_min = max(64, -(-2**25 // frames[0].size))
    long = np.concatenate([frames] * max(1, -(-n_min // n_frames)))
    n_long, n_threads = len(long), all_threads.threads_for(len(long))
    thr = int(np.ceil(fast.threshold + baseline.mean()))

    def floor_threads():  # shared out as the pipeline shares out its stack
        run_blocks(lambda a, b: _floor(long[a:b], thr), n_long, n_threads)

    for p in (fast, numpy_pipe, one_thread, all_threads):
        p.process(frames[:2])  # warm caches (level maps, the compiled kernel)
    floor_threads()
    t: dict = {}
    for _ in tqdm(range(repeats), desc=label, unit="repeat", file=sys.stderr):
        # frame by frame as on a stream, where only the new frame is cold and the pipeline's tables stay in
        # cache: WARM_PASSES untimed passes first (the long stacks below flush the caches), the first of
        # the fast path's timed as "fast_after_flush"
        for name, fn, args in (("fast", _each, (fast, frames)), ("numpy", _each, (numpy_pipe, frames)),
                               ("floor", _floor, (frames, thr))):
            if name == "fast":
                _clock(t, "fast_after_flush", fn, *args)
            for _ in range(WARM_PASSES - (name == "fast")):
                fn(*args)
            _clock(t, name, fn, *args)
        # the long stack, each way after an untimed run of the same (the tables and the threads warm)
        for name, fn, args in (("batch_1thread", one_thread.process, (long,)),
                               ("batch_threads", all_threads.process, (long,)),
                               ("floor_1thread", _floor, (long, thr)), ("floor_threads", floor_threads, ())):
            fn(*args)
            _clock(t, name, fn, *args)
    sub = frames[:n_reference]
    _clock(t, "reference", _each, ref, sub)  # slow: one timing
    us = {k: _per_frame(v, n_frames if k in ("fast", "fast_after_flush", "numpy", "floor") else
                        len(sub) if k == "reference" else n_long) for k, v in t.items()}
    rf, rr, rn = fast.process(sub), ref.process(sub), numpy_pipe.process(sub)
    both = rr.contact & rf.contact
    g_rel = np.abs(rf.G - rr.G)[both] / rr.G[both]
    lit = [int(np.count_nonzero(f.astype(np.float64) - baseline > fast.threshold)) for f in sub]
    row = {f"{k}_us": round(v[0], 1) for k, v in us.items()}
    row |= {f"{k}_cpu_us": round(v[1], 1) for k, v in us.items()}
    cpu = {k: v[1] for k, v in us.items()}
    wall = {k: v[0] for k, v in us.items()}
    return row | {
        "fast_over_floor": round(cpu["fast"] / cpu["floor"], 2),
        "fast_after_flush_over_floor": round(cpu["fast_after_flush"] / cpu["floor"], 2),
        "numpy_over_floor": round(cpu["numpy"] / cpu["floor"], 2),
        "batch_over_floor": round(cpu["batch_1thread"] / cpu["floor_1thread"], 2),
        "speedup": round(cpu["reference"] / cpu["fast"], 1),
        "threads": n_threads,
        "threads_speedup": round(wall["batch_1thread"] / wall["batch_threads"], 2),
        "floor_threads_speedup": round(wall["floor_1thread"] / wall["floor_threads"], 2),
        "max_G_rel_diff": float(g_rel.max()) if g_rel.size else 0.0,
        "max_u_diff_mm": float(np.abs(rf.u - rr.u).max()),
        "flags_identical": bool(np.array_equal(rf.contact, rr.contact)
                                and np.array_equal(rf.saturated, rr.saturated)),
        "kernels_identical": bool(all(np.array_equal(getattr(rf, k), getattr(rn, k))
                                      for k in ("G", "u", "contact", "saturated"))),
        "elements_in_contact": int(rf.contact[0].sum()),
        "lit_pixels": int(np.median(lit)),
    }, frames[0]


def bench_pipeline(sizes=((320, 240), (640, 480), (1280, 960), (1920, 1440)), *, loads=(1, 5, 41),
                   n_frames: int = 16, repeats: int = 5, n_reference: int = 1, seed: int = 0,
                   startup: bool = True) -> dict:
    """Per-frame cost of the fast, batch and reference pipelines and of one pass over the frame.

    Frame by frame, each method is timed in its steady state on a stream:
    one untimed pass over the frames first, then the timed one (the long
    stacks of the batch timings flush every cache in between).

    Parameters
    ----------
    sizes : sequence of (width, height)
        Camera sizes to measure (default 320x240, 640x480, 1280x960, 1920x1440).
    loads : sequence of int
        Elements loaded, keys of :data:`LOAD_CASES` (default 1, 5 and 41).
    n_frames : int
        Distinct frames per size and load: one two-stage render (dark
        background) exposed with ``n_frames`` CCD noise seeds (uint8). The
        baseline is the dark background exposed.
    repeats : int
        Timing repeats; figures are medians over repeats, each repeat timing
        every method side by side.
    n_reference : int
        Frames the reference processes, timed once (it is slow).
    seed : int
        Seed of the noise.
    startup : bool
        Also time a fresh ``optitact process`` on one frame per size.

    Returns
    -------
    dict
        ``cores``, ``threads``, ``kernel`` (what the fast path ran:
        ``"numba"`` or ``"numpy"``), versions, ``table`` (fast / floor, CPU
        time, per size and load: the README's table) and per size ``WxH``:
        ``precompute_cold_s`` (the pipeline's construction for the sensor and
        camera without the precompute cache, median of up to three),
        ``precompute_cached_s`` (from the cache on disk, nothing in memory),
        ``one_frame_baseline_s`` (what a one-frame baseline adds: its noise,
        impulses and their floor per region), ``startup_to_first_frame_s``
        (wall time of a fresh ``python -m optitact.cli process`` on one frame with a
        baseline frame, interpreter start to table written), and per load
        ``loads[n]``: microseconds per frame, wall (``*_us``) and CPU
        (``*_cpu_us``), of ``fast`` (frame by frame, one thread), ``numpy``
        (the NumPy fallback, frame by frame), ``fast_after_flush`` (the fast
        path's first pass over the frames after the long stacks have flushed
        the caches; the others are timed after :data:`WARM_PASSES` untimed
        passes, as on a stream), ``floor`` (``np.count_nonzero(frame
        > t)`` frame by frame), ``batch_1thread`` and ``batch_threads`` (one
        call on a stack of at least 64 frames and 2**25 pixels (437 frames
        of 320x240), one thread and every core),
        ``floor_1thread`` and ``floor_threads`` (the floor over the same
        stack, one thread and split across as many threads: the bound on
        the threads' speed-up), ``reference``; the ratios ``fast_over_floor``, ``fast_after_flush_over_floor``,
        ``numpy_over_floor``, ``batch_over_floor`` (CPU time),
        ``threads_speedup`` and ``floor_threads_speedup`` (wall time, one
        thread over ``threads``), ``speedup`` (reference / fast); the
        exactness figures ``max_G_rel_diff`` and ``max_u_diff_mm`` (fast vs
        reference, elements in contact), ``flags_identical``,
        ``kernels_identical`` (NumPy fallback vs fast, bit for bit); and
        ``elements_in_contact``, ``lit_pixels`` (median per frame).
    """
    import os
    import platform

    from optitact.optics.ccd import CCD
    from optitact.pipeline.fastpath import cores as _cores
    from optitact.pipeline.frame_pipeline import Pipeline
    from optitact.studies.bench_render import render_cases

    n_frames = integer(n_frames, "n_frames", minimum=1)
    repeats = integer(repeats, "repeats", minimum=1)
    n_reference = integer(n_reference, "n_reference", minimum=1)
    sensor = DomeSensor.default()
    cases = render_cases(sensor)
    for n in loads:
        if n not in LOAD_CASES:
            from optitact.errors import InputError

            raise InputError(f"loads: expected elements loaded among {sorted(LOAD_CASES)}, got {n!r}")
    result: dict = {"cores": os.cpu_count(), "threads": _cores(),
                    "python": platform.python_version(), "numpy": np.__version__,
                    "frames": f"{n_frames} uint8 frames per size and load: a two-stage render of the "
                              f"load case over a dark background, exposed with CCD noise (seeds "
                              f"{seed + 100}..); baseline: the dark background exposed",
                    "floor": "np.count_nonzero(frame > threshold), one pass over the frame",
                    "warm_passes": WARM_PASSES,
                    "table": {}}
    for width, height in sizes:
        camera = FisheyeCamera(width=integer(width, "width", minimum=2),
                               height=integer(height, "height", minimum=2))
        key = f"{width}x{height}"
        baseline = CCD().expose(np.zeros(camera.shape), seed=seed + 99)
        fast = Pipeline(sensor, camera, baseline=baseline, threads=1)
        result["kernel"] = fast.kernel
        pipes = (fast, fast.replace(kernel="numpy"), fast, fast.replace(threads=None),
                 fast.replace(method="reference"))
        row: dict = {"loads": {}}
        for n in loads:
            row["loads"][str(n)], frame = _one_load(sensor, camera, cases[LOAD_CASES[n]], baseline, pipes,
                                             n_frames=n_frames, repeats=repeats, n_reference=n_reference,
                                             seed=seed, label=f"bench pipeline {key}, {n} loaded")
        print(f"optitact: bench pipeline {key}: precompute and start-up", file=sys.stderr)
        cold, cached, base, start = _start_up(sensor, camera, baseline, frame, repeats=min(repeats, 3),
                                              startup=startup)
        row |= {"precompute_cold_s": round(cold, 3), "precompute_cached_s": round(cached, 4),
                "one_frame_baseline_s": round(base, 4),
                "startup_to_first_frame_s": None if start is None else round(start, 3)}
        result[key] = row
        result["table"][key] = {n: r["fast_over_floor"] for n, r in row["loads"].items()}
    return result
