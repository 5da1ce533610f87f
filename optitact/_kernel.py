"""The fused per-frame kernel of the fast pipeline, compiled with numba (the ``fast`` extra).

One pass over a frame's region entries (sorted by pixel, so the frame is
read in memory order) gathers each entry's grey value, compares it with the
entry's lit level, and adds the lit ones' weighted values to their
element's sums: G, the centroid's weight and its first moments. The sums
run in entry order, as ``np.bincount`` adds them in
:func:`optitact._fastpath.fast_numpy` (the NumPy path), so both give the same
readings bit for bit.

numba is imported on first use only, never by ``import optitact``; the
compiled functions are cached in the user cache folder
(:func:`optitact._cache.cache_dir`, ``numba`` under it), never next to the
source.
"""

from __future__ import annotations

import importlib
import importlib.util
import threading

from ._optional import require

__all__ = ["KERNELS", "available", "lit_sums", "loaded", "resolve"]

#: Kernel names accepted by :class:`optitact.Pipeline` (``kernel=``).
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


def _lit_sums(flat, t0, t1, pixel, label, level, base, thr, area, wx, wy, watch, sat, exact,
              floor, g_min, g_out, w_out, u_out, sat_out, contact_out):  # pragma: no cover - compiled by numba
    """Frames ``t0 .. t1 - 1`` of ``flat`` (T, H*W): per-element readings into rows of the outputs.

    ``exact``: float frames, where ``frame > level`` only selects candidates
    and ``frame - base > thr`` (float64) decides, as the reference tests it.
    Each frame's sums then become readings as
    :func:`optitact.steps.readings_from_moments` makes them (the same float64
    operations): contact where ``G > floor`` and ``G > g_min``, else G = 0;
    ``u = M / weight`` where in contact with a positive weight, else 0.
    """
    n = pixel.shape[0]
    for t in range(t0, t1):
        frame = flat[t]
        g, w, hot, u, contact = g_out[t], w_out[t], sat_out[t], u_out[t], contact_out[t]
        mx, my = u[:, 0], u[:, 1]
        for i in range(n):
            raw = frame[pixel[i]]
            if raw > level[i]:  # lit (for float frames: a candidate)
                x = float(raw)
                if x >= sat:
                    hot[label[i]] = True
                v = x - base[i]
                if exact and not v > thr[i]:
                    continue
                above = max(v - thr[i], 0.0)
                e = label[i]
                g[e] += area[i] * v
                w[e] += area[i] * above
                mx[e] += wx[i] * above
                my[e] += wy[i] * above
        for j in range(watch.shape[0]):
            if float(frame[pixel[watch[j]]]) >= sat:
                hot[label[watch[j]]] = True
        for e in range(g.shape[0]):
            in_contact = g[e] > floor[e] and g[e] > g_min
            contact[e] = in_contact
            if not in_contact:
                g[e] = 0.0
            if in_contact and w[e] > 0.0:
                mx[e] = mx[e] / w[e]
                my[e] = my[e] / w[e]
            else:
                mx[e] = 0.0
                my[e] = 0.0


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

            from ._cache import cache_dir

            given = config.CACHE_DIR
            if not given:  # the cache locator is chosen when the function is decorated
                config.CACHE_DIR = str(cache_dir() / "numba")
            try:
                _compiled["lit_sums"] = numba.njit(nogil=True, cache=True)(_lit_sums)
            finally:
                config.CACHE_DIR = given
        return _compiled["lit_sums"]


def lit_sums(flat, t0, t1, args, sat, exact, out) -> None:
    """Readings of frames ``t0 .. t1 - 1`` by the compiled kernel (releases the GIL).

    Parameters
    ----------
    flat : (T, H*W) ndarray
        Frames, C-contiguous, of one dtype (uint8, uint16, other integers, float32, float64).
    t0, t1 : int
        The frames to sum (rows of the outputs they fill).
    args : tuple
        ``(pixel, label, level, base, thr, area, wx, wy, watch)``: the region
        entries, their lit level (frame dtype), baseline and threshold, the
        folded weights, and the entries to watch for saturation; then
        ``floor`` ((E,) noise floor of G) and ``g_min`` (G_MIN).
    sat : float
        Saturation level (``inf``: none).
    exact : bool
        Float frames: the reference's float64 test decides among the candidates.
    out : tuple of ndarrays
        ``(G, weight, u, saturated, contact)``, (T, E) but ``u`` (T, E, 2),
        zeroed; rows ``t0 .. t1 - 1`` are filled: G, u, saturated and
        contact are the readings (``weight`` is the centroid's weight sum).
    """
    *entries, floor, g_min = args
    _compile()(flat, t0, t1, *entries, float(sat), bool(exact), floor, float(g_min), *out)
