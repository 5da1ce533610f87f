"""Bright spots of a frame over its no-load frame: the measurements :mod:`optitact.registration.pose` fits.

:func:`detect_spots` subtracts the no-load frame, thresholds the difference at
``k`` times a robust noise estimate (1.4826 x the median absolute deviation)
and labels its connected components (``cv2.connectedComponentsWithStats``,
8-connected); each spot's centroid is intensity-weighted.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from optitact._validate import finite, positive, real_array
from optitact.errors import InputError, KindError, ShapeError

__all__ = ["Spots", "detect_spots", "grey_dtype", "grey_image", "spots_in_difference"]


@dataclass(frozen=True)
class Spots:
    """Bright spots of one frame over its no-load frame (connected components of ``frame - noload``).

    Attributes
    ----------
    centroid : (M, 2) ndarray
        Intensity-weighted centroids ``(row, col)`` of the spots (pixels).
    energy : (M,) ndarray
        Summed grey value over the no-load frame of each spot's pixels.
    n_pixels : (M,) ndarray of int
        Pixels above the threshold per spot.
    labels : (H, W) ndarray of int32
        Component labels: 0 background, ``i + 1`` spot ``i``.
    noise_sigma : float
        Robust noise estimate of ``frame - noload`` (grey levels).
    threshold : float
        The threshold used (grey levels over the no-load frame).
    """

    centroid: np.ndarray
    energy: np.ndarray
    n_pixels: np.ndarray
    labels: np.ndarray = field(repr=False)
    noise_sigma: float
    threshold: float

    def as_dict(self) -> dict:
        """Per-spot table: ``spot, row, col, energy, n_pixels``."""
        return {"spot": np.arange(len(self.energy)), "row": self.centroid[:, 0], "col": self.centroid[:, 1],
                "energy": self.energy, "n_pixels": self.n_pixels}


def grey_dtype(frame, name: str) -> np.dtype | None:
    """The dtype of an array ``frame`` (None for other array_likes); KindError naming ``name`` unless real.

    Grey levels are integers or floats: a bool, complex or object frame (a mask saved by mistake) is
    refused here, by the API and the command line alike.
    """
    dtype = getattr(frame, "dtype", None)
    if dtype is None:
        return None
    dtype = np.dtype(dtype)
    if dtype.kind not in "iuf":
        raise KindError(f"{name} must hold grey levels (an integer or float image), got dtype {dtype}")
    return dtype


def grey_image(frame, name: str) -> np.ndarray:
    """``frame`` as a finite float64 grey image (H, W); ShapeError/InputError naming ``name`` otherwise."""
    grey_dtype(frame, name)
    arr = real_array(frame, name)
    if arr.ndim != 2:
        raise ShapeError(f"{name} must be a grey image (H, W), got shape {arr.shape}")
    return finite(arr, name).astype(np.float64)


def _difference(frame, noload, name: str) -> np.ndarray:
    f, b = grey_image(frame, name), grey_image(noload, "noload")
    if f.shape != b.shape:
        raise ShapeError(f"{name} must have the no-load frame's shape {b.shape}, got {f.shape}")
    return f - b


#: Fraction of pixels whose mirrored negative deviation bounds the spot threshold from below.
MIRROR_TAIL = 1e-4


def _noise_sigma(diff: np.ndarray) -> float:
    """Robust noise sigma of ``diff``: 1.4826 x its median absolute deviation, at least 1e-3 grey levels.

    Where that is 0 (quantised, nearly noiseless frames): the RMS deviation of
    the 90 % of pixels nearest the median.
    """
    med = float(np.median(diff))
    dev = np.abs(diff - med)
    s = 1.4826 * float(np.median(dev))
    if s == 0.0:
        core = dev[dev <= np.percentile(dev, 90)]
        s = float(np.sqrt(np.mean(core ** 2))) if core.size else 0.0
    return max(s, 1e-3)


def spots_in_difference(diff: np.ndarray, k: float, min_pixels: int) -> Spots:
    """The spots of a difference image ``frame - noload`` (:func:`detect_spots` checks the inputs)."""
    import cv2

    sigma = _noise_sigma(diff)
    med = float(np.median(diff))
    # Spots only brighten: the negative tail is noise alone. A threshold below its mirror image (the
    # level only MIRROR_TAIL of the pixels fall below) would take noise for spots, as in quantised,
    # nearly dark frames where most differences are exactly 0 and the robust sigma collapses.
    mirror = -float(np.quantile(diff - med, min(MIRROR_TAIL, 1.0))) if diff.size else 0.0
    thr = max(k * sigma, mirror) + med
    n, labels, stats, _ = cv2.connectedComponentsWithStats((diff > thr).astype(np.uint8), connectivity=8,
                                                           ltype=cv2.CV_32S)
    keep = np.flatnonzero(stats[1:, cv2.CC_STAT_AREA] >= min_pixels) + 1
    remap = np.zeros(n, np.int32)
    remap[keep] = np.arange(1, keep.size + 1)
    labels = remap[labels]
    m = keep.size
    flat = labels.ravel()
    w = np.where(flat > 0, diff.ravel(), 0.0)
    rows, cols = np.divmod(np.arange(flat.size), diff.shape[1])
    energy = np.bincount(flat, weights=w, minlength=m + 1)[1:]
    cen = np.stack([np.bincount(flat, weights=w * rows, minlength=m + 1)[1:],
                    np.bincount(flat, weights=w * cols, minlength=m + 1)[1:]], axis=-1)
    cen = cen / np.maximum(energy, 1e-300)[:, None]
    return Spots(centroid=cen, energy=energy, n_pixels=stats[keep, cv2.CC_STAT_AREA].astype(np.int64),
                 labels=labels, noise_sigma=sigma, threshold=thr)


def detect_spots(frame, noload, *, k: float = 5.0, min_pixels: int = 2) -> Spots:
    """Find the bright spots of ``frame`` over its no-load frame.

    Parameters
    ----------
    frame, noload : (H, W) array_like
        Grey frames of the same shape (any real dtype; sums in float64).
    k : float
        Threshold in robust noise sigmas over the median difference, default 5.
    min_pixels : int
        Smallest spot kept (pixels above the threshold), default 2: single hot
        pixels are dropped.

    Returns
    -------
    Spots

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(0)
    >>> base = rng.normal(20.0, 2.0, (40, 40))
    >>> r, c = np.mgrid[0:40, 0:40]
    >>> frame = base + 100.0 * np.exp(-((r - 10.3) ** 2 + (c - 25.6) ** 2) / 2.0)
    >>> np.round(detect_spots(frame, base).centroid, 1).tolist()
    [[10.3, 25.6]]
    """
    k = positive(k, "k")
    if isinstance(min_pixels, bool) or not isinstance(min_pixels, (int, np.integer)) or min_pixels < 1:
        raise InputError(f"min_pixels must be an integer >= 1, got {min_pixels!r}")
    return spots_in_difference(_difference(frame, noload, "frame"), k, int(min_pixels))


# ----------------------------------------------------------------------------- the model's predictions
