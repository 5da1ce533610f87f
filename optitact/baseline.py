"""The no-load baseline of a stream: splitting it off, and the contact floor its impulses need.

:func:`take_baseline` takes the first frames of a stream as its no-load
baseline (``optitact process``, :meth:`optitact.Pipeline.stream`, live
capture). :func:`baseline_noise` measures a baseline's noise: the Gaussian
noise of each pixel, and the isolated bright pixels (hot pixels, path-tracing
fireflies) that another frame holds at other places; :func:`impulse_floor`
is the part of each element's contact floor that allows for those
(:class:`optitact.Pipeline`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from ._validate import integer
from .errors import InputError
from .steps import (
    IMPULSE_SIGMAS,
    impulse_hits,
    impulses,
    noise_from_one_frame,
    noise_from_variance,
    pooled_variance,
    temporal_variance,
)

__all__ = ["IMPULSE_FALSE_CONTACT", "BaselineNoise", "baseline_noise", "impulse_floor", "take_baseline"]

#: Probability that isolated bright pixels (:func:`~optitact.steps.impulses`) alone lift one
#: region of one frame above its noise floor.
IMPULSE_FALSE_CONTACT = 1e-5


def take_baseline(items, n: int, *, frame=None) -> tuple[np.ndarray | None, list, Iterator]:
    """Split the first ``n`` items of a stream off as its no-load baseline.

    Parameters
    ----------
    items : iterable
        Frames, or items holding one (see ``frame``).
    n : int
        Frames the baseline averages (>= 0; 0 takes none).
    frame : callable, optional
        The frame of an item (default: the item itself), e.g.
        ``lambda item: item[1]`` for ``(source, frame)`` pairs.

    Returns
    -------
    baseline : (n, H, W) ndarray or None
        The first ``n`` frames stacked (for :meth:`Pipeline.with_baseline`);
        None when ``n == 0`` or the stream is empty.
    head : list
        The first ``n`` items (to process with the new baseline).
    rest : iterator
        The items after them.

    Raises
    ------
    InputError
        When the stream ends after 1 to ``n - 1`` items.
    """
    n = integer(n, "baseline_frames", minimum=0)
    rest = iter(items)
    head = list(itertools.islice(rest, n))
    if not head:
        return None, head, rest
    if len(head) < n:
        raise InputError(f"the stream ended after {len(head)} frames, before the {n} baseline frames")
    get = (lambda item: item) if frame is None else frame
    return np.stack([np.asarray(get(item)) for item in head]), head, rest


@dataclass(frozen=True)
class BaselineNoise:
    """The noise of ``frame - baseline`` for a no-load baseline (:func:`baseline_noise`).

    Attributes
    ----------
    noise : (H, W) float64 ndarray or None
        Gaussian noise per pixel (grey levels, rms); None when one frame is
        too small to tell (a warning said so).
    dof : float
        Degrees of freedom of ``noise``'s estimate (``math.inf`` for one
        frame's, estimated from thousands of pixels): the threshold is
        :func:`~optitact.steps.threshold_sigmas` (k, dof) times it.
    rate, height : (H, W) float64 ndarrays
        The isolated bright pixels another frame may hold where ``noise``
        does not allow for them: per pixel, the fraction of the baseline's
        frames in which it is one, and its mean height over them (see
        :func:`~optitact.steps.impulses`); :func:`impulse_floor` turns them
        into each region's share of the contact floor.
    """

    noise: np.ndarray | None
    dof: float
    rate: np.ndarray
    height: np.ndarray


def baseline_noise(stack: np.ndarray, *, stacklevel: int = 2) -> BaselineNoise:
    r"""The noise map and the isolated bright pixels of a no-load baseline of any number of frames.

    Parameters
    ----------
    stack : (T, H, W) ndarray
        The baseline (validated; ``T = 1`` for one frame).
    stacklevel : int
        Of :func:`~optitact.steps.noise_from_one_frame`'s warning.

    Notes
    -----
    Path-traced frames hold fireflies, real frames flickering hot pixels and
    cosmic rays, each frame at other places: another frame minus the
    baseline holds about as many, where the baseline's noise map saw none.
    A variance cannot stand for them (they are heavy-tailed), so the noise
    map models the Gaussian part and the impulses are counted apart, for
    one frame and for a stack alike.

    One frame: the noise from its spatial fluctuations
    (:func:`~optitact.steps.noise_from_one_frame`) and every impulse
    (:func:`~optitact.steps.impulses`): one frame cannot tell a fixed hot
    pixel from a passing one.

    A stack of ``T >= 2``: the impulses of each frame
    (:func:`~optitact.steps.impulse_hits`) that stand above the local
    Gaussian noise, not just the frame's typical noise (their height above
    ``IMPULSE_SIGMAS`` times the residual's :math:`\sqrt{3/2}\,\sigma`, with
    :math:`\sigma` pooled over the neighbours that hold no impulse: a
    region of the frame much noisier than the rest is noise, not impulses).
    A pixel that is one in every frame is fixed (a hot pixel): the mean
    baseline subtracts it, and its own variance, if large, sets its noise.
    The others' rate is their fraction of the ``T`` frames, a per-frame
    rate measured ``T`` times over; a pixel that fires often but not in
    every frame is counted with its rate, an upper bound of how often it
    lights a new frame above a baseline that holds some of its fires. The
    noise map (:func:`~optitact.steps.noise_from_stack`) pools the
    variance over the pixels without impulses.
    """
    if len(stack) < 2:
        rate, height = impulses(stack)  # integer frames: exact integer arithmetic, the same values
        return BaselineNoise(noise_from_one_frame(stack[0], stacklevel=stacklevel + 1), math.inf, rate, height)
    t_n = len(stack)
    var = temporal_variance(stack)
    hits = []  # each frame's impulses as (flat index, height): a few per thousand pixels
    for f in stack:
        hit, height = impulse_hits(f)
        where = np.flatnonzero(hit)
        hits.append((where, height.reshape(-1)[where]))
    found = np.zeros(var.size, bool)
    for where, _ in hits:
        found[where] = True
    sigma = np.sqrt(pooled_variance(var, exclude=found.reshape(var.shape))[0]).reshape(-1)
    bar = IMPULSE_SIGMAS * math.sqrt(1.5) * sigma
    count, total = np.zeros(var.size), np.zeros(var.size)
    for where, height in hits:
        real = height > bar[where]
        count[where[real]] += 1.0  # one impulse per pixel and frame: no repeated indices
        total[where[real]] += height[real]
    count, total = count.reshape(var.shape), total.reshape(var.shape)
    moving = (count > 0) & (count < t_n)
    noise, dof = noise_from_variance(var, t_n, exclude=count > 0)
    return BaselineNoise(noise, dof, np.where(moving, count / t_n, 0.0), np.where(moving, total / t_n, 0.0))


def impulse_floor(impulses: tuple[np.ndarray, np.ndarray] | None, fold) -> np.ndarray:
    """Per region, the G that another frame's impulses may add (0 without impulses).

    ``impulses`` is ``(rate, height)`` of the baseline's impulses
    (:class:`BaselineNoise`); ``fold`` the pipeline's
    :class:`~optitact.regions.RegionWeights`.

    A frame holds about as many isolated bright pixels as the no-load
    frames (:func:`~optitact.steps.impulses`), at other places: a
    region expecting ``c`` of them (their density, smoothed over a
    twentieth of the frame, summed over the region) sees at most the
    Poisson count that
    is exceeded with probability :data:`IMPULSE_FALSE_CONTACT` (in a
    region of one frame), each up to the 90th percentile of the
    impulses' heights, times the region's pixel area. For a one-frame
    baseline this is conservative where an impulse is a fixed hot pixel
    (the baseline subtracts it): one frame cannot tell the two apart. A
    stack's noise map does not stand for them: it is raised only where its
    own frames happened to hold one, and a few impulses of 5 grey levels
    in an element's region of an otherwise dark frame outweigh the
    Gaussian part of the floor.
    """
    n_regions = len(fold.n_pixels)
    if impulses is None or not impulses[0].any():
        return np.zeros(n_regions)
    rate, height = impulses
    hits = rate > 0
    # Their density, pooled over a neighbourhood of several regions: a region's own few impulses
    # would be a noisy count (its expectation, not its draw, bounds the next frame's).
    density = _smooth(rate, max(rate.shape) / 20.0)
    key = np.sort(fold.label.astype(np.int64) * rate.size + fold.pixel)
    key = key[np.concatenate(([True], key[1:] != key[:-1]))]  # each region pixel once (np.unique's result)
    label, pixel = np.divmod(key, rate.size)
    count = np.bincount(label, density.reshape(-1)[pixel], minlength=n_regions)
    tall = float(_quantile(height[hits] / rate[hits], 0.9))  # one impulse's height, 90th percentile
    k = np.arange(0, 64 + int(10 * count.max()) + 1)
    cdf = poisson_cdf(k, count)  # Poisson CDF of each region's impulse count
    most = np.argmax(cdf >= 1.0 - IMPULSE_FALSE_CONTACT, axis=1)
    return np.where(count > 0, most, 0) * tall * fold.pixel_area


def _quantile(values: np.ndarray, q: float) -> float:
    """``np.quantile(values, q)`` (its default, linear method) to the bit, for values without NaN.

    NumPy's own checks import ``numpy.ma`` (a hundredth of a second of a command's start-up).
    """
    x = np.asarray(values, dtype=np.float64).reshape(-1)
    h = (x.size - 1) * q
    i = int(np.floor(h))
    j = min(i + 1, x.size - 1)
    part = np.partition(x, (i, j))
    a, b, t = part[i], part[j], h - i
    return float(b - (b - a) * (1 - t) if t >= 0.5 else a + (b - a) * t)


def _smooth(image: np.ndarray, sigma: float) -> np.ndarray:
    """A Gaussian blur of width ``sigma`` (px) computed on a copy shrunk to about 4 pixels per sigma.

    Box-averaging by ``f`` pixels, blurring by ``sigma / f`` and interpolating
    back widens the kernel by about 0.5 % (variances ``f^2 / 12`` and
    ``f^2 / 6`` beside ``sigma^2``), at ``1 / f^2`` of the work of the full-size
    blur (0.44 s of a 1280x960 baseline's set-up otherwise).
    """
    import cv2

    h, w = image.shape
    f = max(1, int(sigma // 4))
    if f == 1:
        return cv2.GaussianBlur(image, (0, 0), sigma, borderType=cv2.BORDER_REFLECT_101)
    small = cv2.resize(image, (-(-w // f), -(-h // f)), interpolation=cv2.INTER_AREA)
    small = cv2.GaussianBlur(small, (0, 0), sigma / f, borderType=cv2.BORDER_REFLECT_101)
    return cv2.resize(small, (w, h), interpolation=cv2.INTER_LINEAR)


def poisson_cdf(k: np.ndarray, mean: np.ndarray) -> np.ndarray:
    """``P(N <= k)`` (len(mean), len(k)) of Poisson counts of each ``mean``, for ``k = 0, 1, ..., K``.

    The cumulative sum of the probabilities, each from its logarithm (``-m + k ln m - ln k!``):
    what ``scipy.special.pdtr`` gives (to 1e-15 here), without importing SciPy's special functions
    (a fifth of a second of a command's start-up).
    """
    k = np.asarray(k, dtype=np.float64)
    m = np.asarray(mean, dtype=np.float64)[:, None]
    log_fact = np.concatenate([[0.0], np.cumsum(np.log(np.arange(1.0, k.size)))])
    log_m = np.log(np.where(m > 0, m, 1.0))
    log_p = np.where(m > 0, -m + k[None, :] * log_m - log_fact[None, :],
                     np.where(k[None, :] == 0, 0.0, -np.inf))  # a mean of 0: N = 0 surely
    return np.minimum(np.cumsum(np.exp(log_p), axis=1), 1.0)
