"""The fused per-frame kernel of the fast pipeline, compiled with numba (the ``fast`` extra).

One pass over the frame's region pixels in memory order, in chunks of
:data:`CHUNK` consecutive pixels: a dark chunk costs one fixed-length
comparison with its lit levels (which the compiler vectorises); in a lit
chunk the lit pixels' entries add their weighted values to their element's
sums (G, the centroid's weight and its first moments), so the work beyond
the one pass is proportional to the lit pixels. The sums run in entry
order, as ``np.bincount`` adds them in
:meth:`optitact.pipeline.fastpath.FastPath.process_numpy` (the NumPy path),
so both give the same readings bit for bit.

numba is imported on first use only, never by ``import optitact``; the
compiled functions are cached in the user cache folder
(:func:`optitact.io.cache.cache_dir`, ``numba`` under it), never next to the
source.
"""

from __future__ import annotations

import importlib
import importlib.util
import threading

import numpy as np

from optitact._optional import require

__all__ = ["CHUNK", "KERNELS", "available", "chunks", "lit_sums", "loaded", "resolve"]

#: Kernel names accepted by :class:`optitact.pipeline.frame_pipeline.Pipeline` (``kernel=``).
KERNELS = ("auto", "numba", "numpy")

_lock = threading.Lock()
_compiled: dict = {}


def _numba():
    """The numba module, or None when it is not installed."""
    try:
        return importlib.import_module("numba")
    except ImportError:
        return None


def loaded() -> bool:
    """Whether the compiled kernel is loaded in this process already (numba imported, no start-up cost)."""
    return "lit_sums" in _compiled


def available() -> bool:
    """Whether the compiled kernel can run: numba is installed (found, not imported yet)."""
    if "lit_sums" in _compiled:
        return True
    try:
        return importlib.util.find_spec("numba") is not None
    except (ImportError, ValueError):
        return False


def resolve(kernel: str) -> str:
    """The kernel that runs for a request: ``"numba"`` or ``"numpy"``.

    Parameters
    ----------
    kernel : {"auto", "numba", "numpy"}
        ``"auto"`` takes numba when it is installed, else NumPy.

    Raises
    ------
    MissingExtraError
        ``"numba"`` without numba installed (the ``fast`` extra).
    """
    if kernel == "numpy":
        return "numpy"
    if available():
        return "numba"
    if kernel == "numba":
        require("numba", purpose="kernel='numba' (the compiled per-frame kernel)")  # MissingExtraError
    return "numpy"


#: numba's count-trailing-zeros intrinsic, bound when the kernel is first compiled (numba is not
#: imported before), read by :func:`_lit_sums` as a global at compile time.
trailing_zeros = None

#: Region pixels are read in chunks of this many consecutive frame pixels (one SIMD-friendly test per chunk).
CHUNK = 64

#: Multiplying a word of eight 0/1 bytes by this puts byte ``i`` at bit ``56 + i`` (no carries).
_GATHER_BITS = 0x0102040810204080


def _lit_sums(flat, t0, t1, entry_element, next_same_pixel, entry_table, watched, chunk_start, slot_entry,
              slot_level, settings, floor, sums, u_out, flags):  # pragma: no cover - compiled by numba
    """Frames ``t0 .. t1 - 1`` of ``flat`` (T, H*W): per-element readings into rows of the outputs.

    The region entries are grouped in chunks of :data:`CHUNK` consecutive
    frame pixels (``chunk_start``: each chunk's first pixel; ``slot_level``:
    each slot's lit level, the dtype's largest value where no entry of the
    chunk is; ``slot_entry``: the entry in each slot, or -1). A dark chunk
    costs one fixed-length comparison (vectorised); in a lit one, the lit
    slots become a bit mask whose set bits are visited in order, so the lit
    entries are summed in entry order (running sums kept in registers while
    the element stays the same, from one lit chunk to the next: a spot's
    rows), as ``np.bincount`` sums them in
    :meth:`optitact.pipeline.fastpath.FastPath.process_numpy`.

    ``entry_element``: each entry's element. ``next_same_pixel``: whether the
    next entry reads the same pixel (regions that touch share pixels;
    ``slot_entry`` holds the first). ``entry_table`` (n, 5): each entry's
    baseline, threshold, area and the centroid weights x, y. ``watched``
    (m, 2): pixel and element of the entries watched for saturation.
    ``settings``: saturation level (``inf``: none), ``G_MIN``, and 1.0 for
    float frames, where ``frame > level`` only selects candidates and
    ``frame - base > thr`` (float64) decides, as the reference tests it.
    Each frame's sums then become readings as
    :func:`optitact.pipeline.imageops.readings_from_moments` makes them (the same float64
    operations): contact where ``G > floor`` and ``G > g_min``, else G = 0;
    ``u = M / weight`` where in contact with a positive weight, else 0.
    """
    sat, g_min, exact = settings[0], settings[1], settings[2] != 0.0
    n_chunks = chunk_start.shape[0]
    mask = np.zeros(CHUNK, np.uint8)
    words = mask.view(np.uint64)
    for t in range(t0, t1):
        frame = flat[t]
        g, w, hot, contact, u = sums[0, t], sums[1, t], flags[0, t], flags[1, t], u_out[t]
        e = -1  # the element whose running sums are in registers (kept across chunks: a spot's rows)
        g_run = w_run = mx_run = my_run = 0.0  # its G, centroid weight and first moments x, y
        for k in range(n_chunks):
            start = chunk_start[k]
            chunk_grey = frame[start:start + CHUNK]
            chunk_level = slot_level[k * CHUNK:(k + 1) * CHUNK]
            # this test is most of a dark frame's time and must vectorise; LLVM's vectoriser is fragile
            # here (a local's name once stopped it): time `optitact bench pipeline` after any edit
            any_lit = False
            for j in range(CHUNK):
                any_lit |= chunk_grey[j] > chunk_level[j]
            if not any_lit:
                continue
            # the mask only for lit chunks: writing it in the test above keeps that loop from vectorising
            for j in range(CHUNK):
                mask[j] = chunk_grey[j] > chunk_level[j]
            bits = np.uint64(0)
            for q in range(CHUNK // 8):
                bits |= ((words[q] * np.uint64(_GATHER_BITS)) >> np.uint64(56)) << np.uint64(8 * q)
            while bits:
                j = trailing_zeros(bits)
                bits &= bits - np.uint64(1)
                i = slot_entry[k * CHUNK + j]
                grey = float(chunk_grey[j])
                while True:  # every entry of this pixel (regions that touch can share one), in entry order
                    v = grey - entry_table[i, 0]
                    thr = entry_table[i, 1]
                    if not exact or v > thr:
                        if entry_element[i] != e:
                            if e >= 0:
                                g[e], w[e], u[e, 0], u[e, 1] = g_run, w_run, mx_run, my_run
                            e = entry_element[i]
                            g_run, w_run, mx_run, my_run = g[e], w[e], u[e, 0], u[e, 1]
                        if grey >= sat:
                            hot[e] = True
                        above = max(v - thr, 0.0)
                        g_run += entry_table[i, 2] * v
                        w_run += entry_table[i, 2] * above
                        mx_run += entry_table[i, 3] * above
                        my_run += entry_table[i, 4] * above
                    if not next_same_pixel[i]:
                        break
                    i += 1
        if e >= 0:
            g[e], w[e], u[e, 0], u[e, 1] = g_run, w_run, mx_run, my_run
        for j in range(watched.shape[0]):
            if float(frame[watched[j, 0]]) >= sat:
                hot[watched[j, 1]] = True
        for e in range(g.shape[0]):
            in_contact = g[e] > floor[e] and g[e] > g_min
            contact[e] = in_contact
            if not in_contact:
                g[e] = 0.0
            if in_contact and w[e] > 0.0:
                u[e, 0] = u[e, 0] / w[e]
                u[e, 1] = u[e, 1] / w[e]
            else:
                u[e, 0] = 0.0
                u[e, 1] = 0.0


def chunks(pixel: np.ndarray, level: np.ndarray, n_pixels: int) -> tuple:
    """The chunks of :func:`_lit_sums` for region entries sorted by ``pixel``.

    Greedy: a chunk starts at the first entry not yet covered (or at
    ``n_pixels - CHUNK`` near the frame's end) and takes the entries of the
    next :data:`CHUNK` pixels. Frames must hold at least ``CHUNK`` pixels
    (smaller ones are padded by the caller). Entries of one pixel (where
    regions touch) share its level, so the kernel tests a slot once.

    Returns
    -------
    chunk_start : (K,) intp
        First frame pixel of each chunk.
    slot_entry : (K * CHUNK,) int32 (intp beyond 2**31 entries)
        The (first) entry read at each slot of each chunk, or -1.
    slot_level : (K * CHUNK,) level.dtype
        The lit level of each slot: the entry's, or the dtype's largest
        value (``inf`` for floats) where no entry is, so that it never lights.
    next_same_pixel : (n,) bool
        Whether entry ``i + 1`` reads the same pixel as entry ``i``.
    """
    pixel = np.asarray(pixel, np.intp)
    same = pixel[1:] == pixel[:-1]
    if np.any(level[1:][same] != level[:-1][same]):  # baselines and thresholds are per pixel
        raise ValueError("chunks: entries of one pixel must share its lit level")
    starts, opens = [], []  # each chunk's first pixel, and the entry that opens it
    i, n = 0, len(pixel)
    while i < n:
        p0 = min(int(pixel[i]), n_pixels - CHUNK)
        starts.append(p0)
        opens.append(i)
        i = int(np.searchsorted(pixel, p0 + CHUNK, "left"))
    chunk_start = np.asarray(starts, np.intp)
    k = np.repeat(np.arange(len(chunk_start)), np.diff(np.append(opens, n)))
    slot = k * CHUNK + pixel - chunk_start[k]
    next_same_pixel = np.zeros(n, bool)
    next_same_pixel[:-1] = same
    first = np.ones(n, bool)  # the first entry of its pixel
    first[1:] = ~next_same_pixel[:-1]
    # int32 where it can: small, stays in cache
    slot_entry = np.full(len(chunk_start) * CHUNK, -1, np.int32 if n < 2**31 else np.intp)
    slot_entry[slot[first]] = np.flatnonzero(first)
    top = np.inf if level.dtype.kind == "f" else np.iinfo(level.dtype).max
    slot_level = np.full(len(chunk_start) * CHUNK, top, level.dtype)
    slot_level[slot] = level
    return chunk_start, slot_entry, slot_level, next_same_pixel


def _compile():
    """The jitted kernel (compiled per frame dtype on first call; cached on disk)."""
    fn = _compiled.get("lit_sums")
    if fn is not None:  # every frame after the first: no lock
        return fn
    with _lock:
        if "lit_sums" not in _compiled:
            numba = _numba()
            if numba is None:
                resolve("numba")  # raises MissingExtraError
            from numba.core import config

            from optitact.io.cache import cache_dir

            given = config.CACHE_DIR
            if not given:  # the cache locator is chosen when the function is decorated
                config.CACHE_DIR = str(cache_dir() / "numba")
            global trailing_zeros
            from numba.cpython.unsafe.numbers import trailing_zeros

            try:
                _compiled["lit_sums"] = numba.njit(nogil=True, cache=True)(_lit_sums)
            finally:
                config.CACHE_DIR = given
        return _compiled["lit_sums"]


def lit_sums(flat, t0, t1, args, out) -> None:
    """Readings of frames ``range(t0, t1)`` by the compiled kernel (releases the GIL).

    Parameters
    ----------
    flat : (T, H*W) ndarray
        Frames, C-contiguous, of one dtype (uint8, uint16, other integers,
        float32, float64), at least :data:`CHUNK` pixels each.
    t0, t1 : int
        The frames to sum (rows of the outputs they fill).
    args : tuple
        ``(entry_element, next_same_pixel, entry_table, watched, chunk_start,
        slot_entry, slot_level, settings, floor)``, as
        :meth:`optitact.pipeline.fastpath.FastPath.kernel_args` makes them
        (see :func:`_lit_sums` and :func:`chunks`; ``watched`` (m, 2): pixel
        and element of the entries watched for saturation).
    out : tuple of ndarrays
        ``(sums, u, flags)``: (2, T, E) G and the centroid's weight, (T, E,
        2) u, (2, T, E) bool saturated and contact; zeroed. Rows ``t0 .. t1 -
        1`` are filled with the readings.
    """
    _compile()(flat, t0, t1, *args, *out)
