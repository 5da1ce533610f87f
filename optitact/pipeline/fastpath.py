"""The fast method's per-frame sums: the compiled kernel (numba) and its NumPy twin.

Functions of a :class:`~optitact.pipeline.frame_pipeline.Pipeline` (its folded region
weights, levels, thresholds and floor): :func:`fast_compiled` runs
:func:`optitact.pipeline.kernel.lit_sums` over frames split across threads,
:func:`fast_numpy` gathers the region pixels and sums the lit ones with
``np.bincount``; both add the same terms in the same order, so their
readings are identical bit for bit. :func:`filtered_lit` is the lit entries
after a denoising filter (NumPy only).
"""

from __future__ import annotations

import os
import threading

import numpy as np

from optitact.pipeline import kernel as _kernel
from optitact.pipeline.readings import Readings
from optitact.pipeline.imageops import (G_MIN, _saturation_level, add_clipped_tail, denoise, filter_radius,
                                        readings_from_moments, subtract_baseline)

__all__ = ["BLOCKS_PER_THREAD", "CHUNK_ENTRIES", "CHUNK_FRAMES", "MIN_FRAMES_PER_THREAD", "cores",
           "fast_compiled", "fast_numpy", "fast_numpy_chunks", "filtered_lit", "kernel_args", "run_blocks",
           "thread_count"]

#: With ``threads=None`` a stack is split so that each thread gets at least this many frames.
MIN_FRAMES_PER_THREAD = 8
#: Most frames the fast method's NumPy kernel processes together (bounds its temporary memory).
CHUNK_FRAMES = 64
#: Region entries (frames x entries per frame) the NumPy kernel processes together: its
#: temporaries stay a few MB, which the allocator reuses; larger ones are mapped afresh on
#: every call, and the page faults of touching them cost more than the NumPy calls saved.
CHUNK_ENTRIES = 2**18

_pools: dict = {}  # workers -> ThreadPoolExecutor
_pools_lock = threading.Lock()


def cores() -> int:
    """CPU cores this process may run on."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not on Linux
        return os.cpu_count() or 1


def thread_count(requested: int | None, cores: int, n_frames: int) -> int:
    """Threads sharing a stack of ``n_frames``: ``requested``, or (None) every core with enough frames."""
    if requested is None:
        requested = min(cores, n_frames // MIN_FRAMES_PER_THREAD)
    return max(1, min(requested, n_frames))


def _pool(n: int):
    """A thread pool of ``n`` workers kept for the process's life (no thread start per call)."""
    pool = _pools.get(n)
    if pool is None:
        from concurrent.futures import ThreadPoolExecutor  # 6 ms to import: not for one thread

        with _pools_lock:
            pool = _pools.setdefault(n, ThreadPoolExecutor(n, thread_name_prefix="optitact-frames"))
    return pool


#: :func:`run_blocks` cuts a stack into about this many blocks per thread.
BLOCKS_PER_THREAD = 4


def run_blocks(fn, n: int, n_threads: int) -> list:
    """``[fn(a, b) for blocks (a, b) covering range(n)]`` on ``n_threads`` threads taking blocks as they go.

    The items are cut into about :data:`BLOCKS_PER_THREAD` blocks per thread,
    and each thread (the caller and ``n_threads - 1`` pool workers) takes the
    next block when it has finished one: a core slowed by other work
    (another process, a busy laptop) does fewer blocks instead of holding
    up the whole stack, as an even split in ``n_threads`` parts would.
    Results come in block order. The first error stops the handing out of
    blocks and reaches the caller (whichever thread met it) once every
    thread has stopped.
    """
    if n_threads <= 1 or n <= 1:
        return [fn(0, n)]
    size = -(-n // (n_threads * BLOCKS_PER_THREAD))
    starts = range(0, n, size)
    todo = iter(starts)
    lock = threading.Lock()
    results: dict = {}
    failed: list = []

    def work() -> None:
        while not failed:
            with lock:
                a = next(todo, None)
            if a is None:
                return
            try:
                results[a] = fn(a, min(a + size, n))
            except BaseException as exc:
                failed.append(exc)
                raise

    futures = [_pool(n_threads - 1).submit(work) for _ in range(n_threads - 1)]
    try:
        work()
    except BaseException as exc:  # in failed already, unless it came between blocks (an interrupt)
        if not any(exc is f for f in failed):
            failed.insert(0, exc)
    finally:
        for f in futures:
            f.exception()  # waits
    if failed:
        raise failed[0]  # the first error, whichever thread met it
    return [results[a] for a in starts]


def kernel_args(pipe, dtype: np.dtype) -> tuple:
    """Arguments of the compiled kernel for ``dtype`` frames (:func:`optitact.pipeline.kernel.lit_sums`)."""
    key = ("kernel", dtype.str)
    if key not in pipe._levels:
        level, watch, sat = pipe._level(dtype)
        fold = pipe.region_weights
        n_pixels = max(int(np.prod(pipe.camera.shape)), _kernel.CHUNK)  # smaller frames are padded
        cpix, centry, clevel, more = _kernel.chunks(fold.pixel, np.ascontiguousarray(level), n_pixels)
        fent = np.column_stack([pipe.entry_baseline, pipe.entry_threshold, *fold.weights]).astype(np.float64)
        watched = np.column_stack([fold.pixel[watch], fold.label[watch]]).astype(np.intp).reshape(-1, 2)
        params = np.array([sat, G_MIN, 0.0 if dtype.kind != "f" else 1.0])
        floor = np.ascontiguousarray(pipe.floor, np.float64)
        # the smallest index types: the lit pixels' look-ups stay in cache
        label = fold.label.astype(np.uint8 if pipe.grids.n_elements <= 255 else np.int32)
        pipe._levels[key] = (label, more, fent, watched, cpix, centry, clevel, params, floor)
    return pipe._levels[key]


def fast_compiled(pipe, stack: np.ndarray, single: bool) -> Readings:
    """The fast method's sums by the compiled kernel (numba), frames split across threads.

    The same sums in the same order as :func:`fast_numpy`: bit-identical readings.
    """
    t_n, n_el = stack.shape[0], pipe.grids.n_elements
    flat = stack.reshape(t_n, -1)
    if flat.shape[1] < _kernel.CHUNK:  # a tiny frame: pad it to one chunk (never lit: no entry there)
        flat = np.pad(flat, ((0, 0), (0, _kernel.CHUNK - flat.shape[1])))
    elif not flat.flags.c_contiguous:
        flat = np.ascontiguousarray(flat)
    args = kernel_args(pipe, stack.dtype)
    sums = np.zeros((2, t_n, n_el))
    flags = np.zeros((2, t_n, n_el), bool)
    u = np.zeros((t_n, n_el, 2))
    out = (sums, u, flags)
    run_blocks(lambda a, b: _kernel.lit_sums(flat, a, b, args, out), t_n,
               pipe.threads_for(t_n) if t_n > 1 else 1)
    out = (Readings(sums[0, 0], u[0], flags[1, 0], flags[0, 0]) if single
           else Readings(sums[0], u, flags[1], flags[0]))
    if pipe.tail == "gaussian":
        out = add_clipped_tail(out, sums[1, 0] if single else sums[1])
    return out


def fast_numpy(pipe, stack: np.ndarray, single: bool = False) -> Readings:
    """The folded sums over the lit entries of a stack (readings ``(T, E)``, or ``(E,)`` if single).

    Only the pixels of the regions are read (in memory order); the lit
    ones (above the level) are weighted and summed per element, so dark
    pixels cost one comparison each.
    """
    t_n = stack.shape[0]
    fold = pipe.region_weights
    n_ent, n_el = len(fold.pixel), pipe.grids.n_elements
    level, watch, sat = pipe._level(stack.dtype)
    flat = stack.reshape(t_n, -1)
    if pipe.filter == "none":
        # (T, n_entries) grey values of the region pixels
        g = flat[0][fold.pixel][None] if t_n == 1 else np.take(flat, fold.pixel, axis=1)
        idx = np.flatnonzero(g > level)
        e = idx if t_n == 1 else idx % n_ent
        raw = g.reshape(-1)[idx]
        v = raw - np.take(pipe.entry_baseline, e)
        hot = idx[raw >= sat]
        if stack.dtype.kind == "f":  # candidates: the reference's test decides
            keep = v > np.take(pipe.entry_threshold, e)
            idx, e, v = idx[keep], e[keep], v[keep]
        above = np.maximum(v - np.take(pipe.entry_threshold, e), 0.0)
        if watch.size:
            wt, wi = np.nonzero(g[:, watch] >= sat)
            hot = np.concatenate([hot, wt * n_ent + watch[wi]])
    else:
        idx, v, hot = filtered_lit(pipe, flat)
        e = idx % n_ent
        above = np.maximum(v - np.take(pipe.entry_threshold, e), 0.0)
    key = fold.label[e]
    if t_n > 1:
        key = key + (idx // n_ent) * n_el
    size = t_n * n_el
    area, wx, wy = fold.weights
    g_sum = np.bincount(key, area[e] * v, minlength=size).reshape(t_n, n_el)
    w_sum = np.bincount(key, area[e] * above, minlength=size).reshape(t_n, n_el)
    m = np.empty((t_n, n_el, 2))
    m[..., 0] = np.bincount(key, wx[e] * above, minlength=size).reshape(t_n, n_el)
    m[..., 1] = np.bincount(key, wy[e] * above, minlength=size).reshape(t_n, n_el)
    saturated = np.zeros((t_n, n_el), bool)
    if hot.size:
        saturated.reshape(-1)[fold.label[hot % n_ent] + (hot // n_ent) * n_el] = True
    if single:
        out, w_sum = readings_from_moments(g_sum[0], m[0], saturated[0], pipe.floor, weight=w_sum[0]), w_sum[0]
    else:
        out = readings_from_moments(g_sum, m, saturated, pipe.floor, weight=w_sum)
    return add_clipped_tail(out, w_sum) if pipe.tail == "gaussian" else out


def fast_numpy_chunks(pipe, stack: np.ndarray) -> Readings:
    """:func:`fast_numpy` of a (T, H, W) stack in chunks shared out across the pipeline's threads.

    A chunk holds at most :data:`CHUNK_ENTRIES` region entries and
    :data:`CHUNK_FRAMES` frames; the readings come in frame order.
    """
    step = min(max(CHUNK_ENTRIES // max(len(pipe.region_weights.pixel), 1), 1), CHUNK_FRAMES)
    chunks = [stack[i:i + step] for i in range(0, len(stack), step)]
    parts = [r for part in run_blocks(lambda a, b: [fast_numpy(pipe, c) for c in chunks[a:b]],
                                      len(chunks), min(pipe.threads_for(len(stack)), len(chunks)))
             for r in part]
    return parts[0] if len(parts) == 1 else Readings.stack(parts)


def filtered_lit(pipe, flat: np.ndarray):
    """Lit entries after the filter, computed on the crop that holds the regions plus the filter's reach."""
    h, w = pipe.camera.shape
    fold = pipe.region_weights
    n_ent = len(fold.pixel)
    rows, cols = np.divmod(fold.pixel, w)
    pad = filter_radius(pipe.filter, pipe.filter_size)
    r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, h)
    c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, w)
    local = (rows - r0) * (c1 - c0) + cols - c0
    base = None if pipe.baseline is None else pipe.baseline[r0:r1, c0:c1]
    sat = _saturation_level(flat.dtype, pipe._frame_saturation)
    idx, v, hot = [], [], []
    for i, frame in enumerate(flat):
        crop = frame.reshape(h, w)[r0:r1, c0:c1]
        img = denoise(subtract_baseline(crop, base, clip=False), method=pipe.filter,
                      size=pipe.filter_size)
        vals = np.take(img, local)
        lit = np.flatnonzero(vals > pipe.entry_threshold)
        idx.append(i * n_ent + lit)
        v.append(vals[lit])
        hot.append(i * n_ent + np.flatnonzero(np.take(crop, local) >= sat))
    return np.concatenate(idx), np.concatenate(v), np.concatenate(hot)
