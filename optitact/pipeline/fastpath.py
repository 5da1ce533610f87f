"""The fast method's per-frame sums: the compiled kernel (numba) and its NumPy twin.

:class:`FastPath` is the fast method of a :class:`~optitact.pipeline.frame_pipeline.Pipeline`,
which makes one from what the sums need (the folded region weights, each entry's baseline and
threshold, each region's noise floor) and keeps it: it holds the per-dtype precompute (lit
levels, the compiled kernel's arguments) and computes readings two ways.
:meth:`FastPath.process_compiled` runs :func:`optitact.pipeline.kernel.lit_sums` over frames
split across threads; :meth:`FastPath.process_numpy` gathers the region pixels and sums the lit
ones with ``np.bincount``; both add the same terms in the same order, so their readings are
identical bit for bit. :meth:`FastPath.filtered_lit` is the lit entries after a denoising
filter (NumPy only). :func:`run_blocks` and :func:`thread_count` share a stack out across
threads.
"""

from __future__ import annotations

import copy
import math
import os
import threading
from typing import NamedTuple

import numpy as np

from optitact.pipeline import kernel as _kernel
from optitact.pipeline.readings import Readings
from optitact.pipeline.imageops import (G_MIN, add_clipped_tail, denoise, filter_radius,
                                        readings_from_moments, saturation_level, subtract_baseline)
from optitact.pipeline.regions import RegionWeights

__all__ = ["BLOCKS_PER_THREAD", "CHUNK_ENTRIES", "CHUNK_FRAMES", "MIN_FRAMES_PER_THREAD", "FastPath",
           "LitLevels", "cores", "run_blocks", "thread_count"]

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
        from concurrent.futures import ThreadPoolExecutor  # imported here: one thread never pays for it

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


class LitLevels(NamedTuple):
    """When the region entries of frames of one dtype are lit (:meth:`FastPath.levels`)."""

    #: (n_entries,) of the frames' dtype: an entry is lit where ``frame > level`` (for float
    #: frames, a candidate: ``frame - baseline > threshold`` in float64 decides).
    level: np.ndarray
    #: Entries whose level reaches the saturation level: watched for saturation separately.
    watched: np.ndarray
    #: The saturation level of the frames (``inf``: none).
    saturation: float


class FastPath:
    """The fast method of a :class:`~optitact.pipeline.frame_pipeline.Pipeline`: sums over the lit entries.

    The pipeline makes one from its folded region weights, thresholds and
    floor and keeps it; what depends on the frames' dtype (the lit levels,
    the compiled kernel's arguments) is made on first use and kept. The
    kernel and the threads are chosen per call, so a pipeline that only
    changes how it runs shares everything but the caches (:meth:`copy`).

    Parameters
    ----------
    weights : RegionWeights
        The pipeline's folded region weights
        (:func:`~optitact.pipeline.regions.fold_regions`), entries sorted by pixel.
    n_elements : int
        Number of elements (regions) E.
    frame_shape : (int, int)
        The frames' ``(H, W)``.
    entry_baseline, entry_threshold : (n_entries,) float64 ndarray
        Baseline and threshold (the frames' grey levels) of each entry.
    floor : (E,) float64 ndarray
        Each region's noise floor of G: contact needs G above it.
    saturation : float, optional
        Saturation level in the frames' grey levels; default the integer
        dtype's maximum, none for float frames (:func:`~optitact.pipeline.imageops.saturation_level`).
    tail : {"none", "gaussian"}
        Whether G gets back the energy the threshold clipped from the spots' tails.
    filter : {"none", "gaussian", "median"}
        The denoising filter; with one, only the NumPy sums run.
    filter_size : float
        The filter's size (see :func:`~optitact.pipeline.imageops.denoise`).
    baseline : (H, W) float64 ndarray, optional
        The no-load frame the filter's input is taken from (None: nothing subtracted).
    """

    def __init__(self, weights: RegionWeights, *, n_elements: int, frame_shape: tuple[int, int],
                 entry_baseline: np.ndarray, entry_threshold: np.ndarray, floor: np.ndarray,
                 saturation: float | None = None, tail: str = "none", filter: str = "none",
                 filter_size: float = 1.0, baseline: np.ndarray | None = None) -> None:
        self.weights, self.n_elements, self.frame_shape = weights, int(n_elements), tuple(frame_shape)
        self.entry_baseline, self.entry_threshold, self.floor = entry_baseline, entry_threshold, floor
        self.saturation, self.tail = saturation, tail
        self.filter, self.filter_size, self.baseline = filter, filter_size, baseline
        self._levels: dict = {}  # dtype.str -> LitLevels
        self._kernel_args: dict = {}  # dtype.str -> the compiled kernel's arguments

    def copy(self) -> FastPath:
        """The same fast path with caches of its own (the arrays shared: they are never written)."""
        out = copy.copy(self)
        out._levels, out._kernel_args = dict(self._levels), dict(self._kernel_args)
        return out

    # ------------------------------------------------------------------ per-dtype precompute
    def levels(self, dtype: np.dtype) -> LitLevels:
        """Lit level per region entry for frames of ``dtype``, and the entries to watch for saturation.

        For integer frames an entry is lit exactly when ``frame > level``,
        ``level`` the largest grey level ``n`` with ``n - baseline <=
        threshold`` in float64, as the reference tests it. For float frames
        ``level`` lies a few ulps below ``baseline + threshold``: ``frame >
        level`` picks the candidates, and the reference's own test ``frame -
        baseline > threshold`` (float64) decides among them, so both methods
        light the same pixels even at the threshold itself. Entries whose
        level reaches the saturation level cannot show saturation by being
        lit; they are watched separately.
        """
        key = dtype.str
        if key not in self._levels:
            b, thr = self.entry_baseline, self.entry_threshold
            sat = saturation_level(dtype, self.saturation)
            if dtype.kind in "ui":
                top = np.iinfo(dtype).max
                # The largest n with n - b <= threshold in float64, as the reference
                # tests it: floor(b + threshold) can be one off after rounding.
                n = np.floor(b + thr)
                n += (n + 1.0) - b <= thr
                n -= n - b > thr
                level = np.clip(n, 0, top).astype(dtype)
            else:
                # safely below every x with x - b > thr: 4 ulps of the largest magnitude involved
                top = b + thr
                low = top - 4.0 * np.spacing(np.maximum(np.maximum(np.abs(b), np.abs(thr)), np.abs(top)))
                with np.errstate(over="ignore"):  # beyond float32: +inf, so never a candidate (right)
                    level = low.astype(dtype)
                down = level.astype(np.float64) > low
                level[down] = np.nextafter(level[down], -np.inf)
            if math.isinf(sat):
                watched = np.zeros(0, np.intp)
            else:
                watched = np.flatnonzero(b + thr >= sat - 1e-9 * max(1.0, sat))
            self._levels[key] = LitLevels(level, watched, sat)
        return self._levels[key]

    def kernel_args(self, dtype: np.dtype) -> tuple:
        """The compiled kernel's arguments for ``dtype`` frames (:func:`~optitact.pipeline.kernel.lit_sums`)."""
        key = dtype.str
        if key not in self._kernel_args:
            level, watched, sat = self.levels(dtype)
            fold = self.weights
            n_pixels = max(int(np.prod(self.frame_shape)), _kernel.CHUNK)  # smaller frames are padded
            chunk_start, slot_entry, slot_level, next_same_pixel = _kernel.chunks(
                fold.pixel, np.ascontiguousarray(level), n_pixels)
            entry_table = np.column_stack([self.entry_baseline, self.entry_threshold,
                                           *fold.weights]).astype(np.float64)
            watched_pairs = np.column_stack([fold.pixel[watched], fold.label[watched]]).astype(np.intp)
            watched_pairs = watched_pairs.reshape(-1, 2)
            settings = np.array([sat, G_MIN, 0.0 if dtype.kind != "f" else 1.0])
            floor = np.ascontiguousarray(self.floor, np.float64)
            # the smallest index types: the lit pixels' look-ups stay in cache
            entry_element = fold.label.astype(np.uint8 if self.n_elements <= 255 else np.int32)
            self._kernel_args[key] = (entry_element, next_same_pixel, entry_table, watched_pairs, chunk_start,
                                      slot_entry, slot_level, settings, floor)
        return self._kernel_args[key]

    # ------------------------------------------------------------------ the sums
    def process_compiled(self, stack: np.ndarray, single: bool, threads: int = 1) -> Readings:
        """Readings by the compiled kernel (numba), frames split across ``threads`` (a stack of more than one).

        The same sums in the same order as :meth:`process_numpy`: bit-identical readings.
        ``stack`` is ``(T, H, W)``; ``single``: return the readings of its one frame ``(E,)``.
        """
        t_n, n_el = stack.shape[0], self.n_elements
        flat = stack.reshape(t_n, -1)
        if flat.shape[1] < _kernel.CHUNK:  # a tiny frame: pad it to one chunk (never lit: no entry there)
            flat = np.pad(flat, ((0, 0), (0, _kernel.CHUNK - flat.shape[1])))
        elif not flat.flags.c_contiguous:
            flat = np.ascontiguousarray(flat)
        args = self.kernel_args(stack.dtype)
        sums = np.zeros((2, t_n, n_el))
        flags = np.zeros((2, t_n, n_el), bool)
        u = np.zeros((t_n, n_el, 2))
        out = (sums, u, flags)
        run_blocks(lambda a, b: _kernel.lit_sums(flat, a, b, args, out), t_n, threads if t_n > 1 else 1)
        out = (Readings(sums[0, 0], u[0], flags[1, 0], flags[0, 0]) if single
               else Readings(sums[0], u, flags[1], flags[0]))
        if self.tail == "gaussian":
            out = add_clipped_tail(out, sums[1, 0] if single else sums[1])
        return out

    def process_numpy(self, stack: np.ndarray, single: bool = False) -> Readings:
        """The folded sums over the lit entries of a stack (readings ``(T, E)``, or ``(E,)`` if single).

        Only the pixels of the regions are read (in memory order); the lit
        ones (above the level) are weighted and summed per element, so dark
        pixels cost one comparison each.
        """
        t_n = stack.shape[0]
        fold = self.weights
        n_ent, n_el = len(fold.pixel), self.n_elements
        level, watched, sat = self.levels(stack.dtype)
        flat = stack.reshape(t_n, -1)
        if self.filter == "none":
            # (T, n_entries) grey values of the region pixels
            g = flat[0][fold.pixel][None] if t_n == 1 else np.take(flat, fold.pixel, axis=1)
            idx = np.flatnonzero(g > level)
            e = idx if t_n == 1 else idx % n_ent
            raw = g.reshape(-1)[idx]
            v = raw - np.take(self.entry_baseline, e)
            hot = idx[raw >= sat]
            if stack.dtype.kind == "f":  # candidates: the reference's test decides
                keep = v > np.take(self.entry_threshold, e)
                idx, e, v = idx[keep], e[keep], v[keep]
            above = np.maximum(v - np.take(self.entry_threshold, e), 0.0)
            if watched.size:
                wt, wi = np.nonzero(g[:, watched] >= sat)
                hot = np.concatenate([hot, wt * n_ent + watched[wi]])
        else:
            idx, v, hot = self.filtered_lit(flat)
            e = idx % n_ent
            above = np.maximum(v - np.take(self.entry_threshold, e), 0.0)
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
            out = readings_from_moments(g_sum[0], m[0], saturated[0], self.floor, weight=w_sum[0])
            w_sum = w_sum[0]
        else:
            out = readings_from_moments(g_sum, m, saturated, self.floor, weight=w_sum)
        return add_clipped_tail(out, w_sum) if self.tail == "gaussian" else out

    def process_numpy_chunks(self, stack: np.ndarray, threads: int = 1) -> Readings:
        """:meth:`process_numpy` of a (T, H, W) stack in chunks shared out across ``threads``.

        A chunk holds at most :data:`CHUNK_ENTRIES` region entries and
        :data:`CHUNK_FRAMES` frames; the readings come in frame order.
        """
        step = min(max(CHUNK_ENTRIES // max(len(self.weights.pixel), 1), 1), CHUNK_FRAMES)
        chunks = [stack[i:i + step] for i in range(0, len(stack), step)]
        parts = [r for part in run_blocks(lambda a, b: [self.process_numpy(c) for c in chunks[a:b]],
                                          len(chunks), min(threads, len(chunks)))
                 for r in part]
        return parts[0] if len(parts) == 1 else Readings.stack(parts)

    def filtered_lit(self, flat: np.ndarray):
        """Lit entries after the filter, computed on the crop that holds the regions plus the filter's reach.

        ``flat`` is ``(T, H*W)``; returns the lit ``frame * n_entries + entry``
        indices, their filtered values and the saturated ones' indices.
        """
        h, w = self.frame_shape
        fold = self.weights
        n_ent = len(fold.pixel)
        rows, cols = np.divmod(fold.pixel, w)
        pad = filter_radius(self.filter, self.filter_size)
        r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, h)
        c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, w)
        local = (rows - r0) * (c1 - c0) + cols - c0
        base = None if self.baseline is None else self.baseline[r0:r1, c0:c1]
        sat = saturation_level(flat.dtype, self.saturation)
        idx, v, hot = [], [], []
        for i, frame in enumerate(flat):
            crop = frame.reshape(h, w)[r0:r1, c0:c1]
            img = denoise(subtract_baseline(crop, base, clip=False), method=self.filter,
                          size=self.filter_size)
            vals = np.take(img, local)
            lit = np.flatnonzero(vals > self.entry_threshold)
            idx.append(i * n_ent + lit)
            v.append(vals[lit])
            hot.append(i * n_ent + np.flatnonzero(np.take(crop, local) >= sat))
        return np.concatenate(idx), np.concatenate(v), np.concatenate(hot)
