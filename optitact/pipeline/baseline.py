"""The no-load baseline of a stream: splitting it off, and the contact floor its impulses need.

:func:`take_baseline` takes the first frames of a stream as its no-load
baseline (``optitact process``, :meth:`optitact.pipeline.frame_pipeline.Pipeline.stream`, live
capture). :func:`baseline_noise` measures a baseline's noise: the Gaussian
noise of each pixel, and the isolated bright pixels (hot pixels, path-tracing
fireflies) that another frame holds at other places; :func:`impulse_floor`
is the part of each element's contact floor that allows for those
(:class:`optitact.pipeline.frame_pipeline.Pipeline`): a quantile of their summed heights
(:func:`compound_poisson_quantile`) at their rate in each region
(:func:`impulse_density`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Iterator
from dataclasses import dataclass

import numpy as np

from optitact._validate import integer
from optitact.errors import InputError
from optitact.pipeline.imageops import (IMPULSE_SIGMAS, impulse_hits, impulses, maximum_noise,
                                        noise_from_one_frame, noise_from_variance, pooled_variance,
                                        temporal_variance)

__all__ = ["IMPULSE_FALSE_CONTACT", "BaselineNoise", "baseline_noise", "compound_poisson_quantile",
           "impulse_density", "impulse_floor", "take_baseline"]

#: Probability that isolated bright pixels (:func:`~optitact.pipeline.imageops.impulses`) alone lift one
#: region of one frame above its noise floor.
IMPULSE_FALSE_CONTACT = 1e-5
#: :func:`impulse_density`: the least half-width of its rings (of the frame's larger side), the least
#: fraction of the frame's pixels each ring holds, the radius of its discs (of the larger side), and
#: the probability below which a disc's count, under the rings' rates, marks a cluster.
RING_WIDTH = 1.0 / 40.0
RING_PIXELS = 0.1
DISC_RADIUS = 1.0 / 20.0
CLUSTER_ALPHA = 1e-3


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
        :func:`~optitact.pipeline.imageops.threshold_sigmas` (k, dof) times it.
    rate, height : (H, W) float64 ndarrays
        The isolated bright pixels another frame may hold where ``noise``
        does not allow for them: per pixel, the fraction of the baseline's
        frames in which it is one, and its mean height over them (see
        :func:`~optitact.pipeline.imageops.impulses`); :func:`impulse_floor` turns them
        into each region's share of the contact floor.
    """

    noise: np.ndarray | None
    dof: float
    rate: np.ndarray
    height: np.ndarray


def baseline_noise(stack: np.ndarray, *, stack_noise: str = "pooled", stacklevel: int = 2) -> BaselineNoise:
    r"""The noise map and the isolated bright pixels of a no-load baseline of any number of frames.

    Parameters
    ----------
    stack : (T, H, W) ndarray
        The baseline (validated; ``T = 1`` for one frame).
    stack_noise : {"pooled", "maximum"}
        The noise map of ``T >= 2`` frames: :func:`~optitact.pipeline.imageops.noise_from_stack`
        (default), or the earlier :func:`~optitact.pipeline.imageops.maximum_noise`
        (``dof`` then infinite: ``k`` of its sigmas). The impulses are
        counted either way.
    stacklevel : int
        Of :func:`~optitact.pipeline.imageops.noise_from_one_frame`'s warning.

    Notes
    -----
    Path-traced frames hold fireflies, real frames flickering hot pixels and
    cosmic rays, each frame at other places: another frame minus the
    baseline holds about as many, where the baseline's noise map saw none.
    A variance cannot stand for them (they are heavy-tailed), so the noise
    map models the Gaussian part and the impulses are counted apart, for
    one frame and for a stack alike.

    One frame: the noise from its spatial fluctuations
    (:func:`~optitact.pipeline.imageops.noise_from_one_frame`) and every impulse
    (:func:`~optitact.pipeline.imageops.impulses`): one frame cannot tell a fixed hot
    pixel from a passing one.

    A stack of ``T >= 2``: the impulses of each frame
    (:func:`~optitact.pipeline.imageops.impulse_hits`) that stand above the local
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
    noise map (:func:`~optitact.pipeline.imageops.noise_from_stack`) pools the
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
    if stack_noise == "maximum":
        noise, dof = maximum_noise(var, t_n), math.inf
    else:
        noise, dof = noise_from_variance(var, t_n, exclude=count > 0)
    return BaselineNoise(noise, dof, np.where(moving, count / t_n, 0.0), np.where(moving, total / t_n, 0.0))


def impulse_floor(impulses: tuple[np.ndarray, np.ndarray] | None, fold, *, frames: int) -> np.ndarray:
    r"""Per region, the G that another frame's impulses may add (0 without impulses).

    Parameters
    ----------
    impulses : (rate, height) of (H, W) ndarrays, or None
        The baseline's isolated bright pixels (:class:`BaselineNoise`).
    fold : RegionWeights
        The pipeline's :class:`~optitact.pipeline.regions.RegionWeights`.
    frames : int
        Frames of the baseline (``rate`` is a count of them over ``frames``).

    Returns
    -------
    (E,) float64 ndarray
        The sum of impulse heights times pixel areas that a region of one
        frame exceeds with probability :data:`IMPULSE_FALSE_CONTACT` (grey
        level x mm^2).

    Notes
    -----
    A frame holds about as many isolated bright pixels as the no-load
    frames (:func:`~optitact.pipeline.imageops.impulses`), at other places. A region
    of expected count :math:`\lambda` (:func:`impulse_density` summed over
    its pixels) receives a Poisson number of them, each adding
    :math:`a h` to G: :math:`a` the dome area of the pixel it lands on
    (drawn in proportion to the density over the region's pixels: a pixel
    at the region's centre gives up to 1.6 times the mean area), :math:`h`
    a height drawn from the baseline's impulses (each impulsive pixel's
    mean height, in proportion to its rate). The allowance is the
    :math:`1 - \epsilon` quantile of that compound Poisson sum,
    :math:`\epsilon` = :data:`IMPULSE_FALSE_CONTACT`
    (:func:`compound_poisson_quantile`); a region whose :math:`\lambda` is
    below :math:`\epsilon` gets none. On path-traced frames of 16 spp the
    sum's tail follows this law (its :math:`1 - 10^{-3}` quantile, measured
    over 1,900 frames, lies within the model's).

    One frame cannot tell a fixed hot pixel (the baseline subtracts it)
    from a passing one: its impulses' heights count up to their 90th
    percentile, so that a few hot pixels far taller than the rest do not
    set the floor. A stack's noise map does not stand for its impulses: it
    is raised only where its own frames happened to hold one, and a few
    impulses in an element's region of an otherwise dark frame outweigh
    the Gaussian part of the floor.
    """
    n_regions = len(fold.n_pixels)
    if impulses is None or not impulses[0].any():
        return np.zeros(n_regions)
    rate, height = impulses
    density = impulse_density(rate, fold, frames=frames).reshape(-1)
    # each (region, pixel) once, with its dome area summed (np.unique's result, without its import)
    key = fold.label.astype(np.int64) * rate.size + fold.pixel
    order = np.argsort(key, kind="stable")
    key = key[order]
    first = np.concatenate(([True], key[1:] != key[:-1]))
    area = np.add.reduceat(np.asarray(fold.weights[0], dtype=np.float64)[order], np.flatnonzero(first))
    label, pixel = np.divmod(key[first], rate.size)
    lam = np.bincount(label, density[pixel], minlength=n_regions)
    hits = rate > 0
    tall, share = height[hits] / rate[hits], rate[hits] / rate[hits].sum()
    if frames < 2:
        tall = np.minimum(tall, _quantile(tall, 0.9))
    out = np.zeros(n_regions)
    for e in np.flatnonzero(lam > IMPULSE_FALSE_CONTACT):
        mine = label == e
        out[e] = compound_poisson_quantile(lam[e], area[mine], density[pixel[mine]], tall, share,
                                           1.0 - IMPULSE_FALSE_CONTACT)
    return out


def impulse_density(rate: np.ndarray, fold, *, frames: int) -> np.ndarray:
    """Expected impulses per pixel of a new frame (H, W), pooled from a baseline's ``rate`` map.

    Parameters
    ----------
    rate : (H, W) ndarray
        Per pixel, the fraction of the baseline's frames in which it holds
        an impulse (:class:`BaselineNoise`).
    fold : RegionWeights
        Where the regions are: their dome-area-weighted pixel mean is the
        image of the dome's axis.
    frames : int
        Frames of the baseline.

    Notes
    -----
    A few frames place few impulses: the rate is pooled over rings of the
    image centred on the dome's axis, each ring the pixels within
    ``RING_WIDTH`` (a fortieth of the frame's larger side) of a distance
    from the axis, widened until it holds ``RING_PIXELS`` (a tenth) of the
    frame. The no-load dome is symmetric about its axis, and so are its
    path-traced fireflies, which crowd into a band near the rim that the
    frame's edges cut (a pooling over image discs gives the regions beside
    a cut a fraction of their rate); a camera's hot pixels and cosmic rays
    fall anywhere, and a ring estimates their uniform rate from more
    pixels than a disc of the same reach. A ring stops at its edge: an
    impulse farther from the axis gives a region no allowance, where a
    smoothing kernel's tails would give every region near one a whole
    impulse.

    Where impulses cluster off the symmetry (a patch of flickering
    pixels), the mean over a disc of radius ``DISC_RADIUS`` (a twentieth
    of the larger side) is taken instead, if its count over the
    ``frames`` is one that the rings' rates at its pixels give with
    probability below ``CLUSTER_ALPHA`` (1e-3).
    """
    import cv2

    rate = np.asarray(rate, dtype=np.float64)
    h, w = rate.shape
    side = max(h, w)
    a = np.asarray(fold.weights[0], dtype=np.float64)
    row, col = np.divmod(np.asarray(fold.pixel), w)
    centre = (np.sum(a * row) / np.sum(a), np.sum(a * col) / np.sum(a))
    rows, cols = np.ogrid[0:h, 0:w]
    ring = np.floor(np.hypot(rows - centre[0], cols - centre[1])).astype(np.intp)
    n = int(ring.max()) + 1
    count = np.concatenate(([0.0], np.cumsum(np.bincount(ring.reshape(-1), rate.reshape(-1), minlength=n))))
    pixels = np.concatenate(([0.0], np.cumsum(np.bincount(ring.reshape(-1), minlength=n).astype(np.float64))))
    radius = np.arange(n)
    half = np.full(n, -1)
    for width in range(max(1, math.ceil(RING_WIDTH * side)), n + 1):
        lo, hi = np.maximum(radius - width, 0), np.minimum(radius + width, n - 1) + 1
        half = np.where((half < 0) & ((pixels[hi] - pixels[lo] >= RING_PIXELS * h * w) | (width == n)),
                        width, half)
        if (half >= 0).all():
            break
    lo, hi = np.maximum(radius - half, 0), np.minimum(radius + half, n - 1) + 1
    radial = ((count[hi] - count[lo]) / np.maximum(pixels[hi] - pixels[lo], 1.0))[ring]
    reach = DISC_RADIUS * side
    r = math.ceil(reach)
    y, x = np.mgrid[-r:r + 1, -r:r + 1]
    disc = (x * x + y * y <= reach * reach).astype(np.float64)
    found = cv2.filter2D(rate, cv2.CV_64F, disc, borderType=cv2.BORDER_CONSTANT) * frames  # impulses seen
    inside = cv2.filter2D(np.ones_like(rate), cv2.CV_64F, disc, borderType=cv2.BORDER_CONSTANT)
    expected = cv2.filter2D(radial, cv2.CV_64F, disc, borderType=cv2.BORDER_CONSTANT) * frames  # each ring's
    found, inside, expected = found.reshape(-1), inside.reshape(-1), expected.reshape(-1)
    out = radial.reshape(-1).copy()
    maybe = np.flatnonzero(found > expected + 0.5)  # few: test only those
    if maybe.size:
        seen = np.maximum(np.rint(found[maybe]).astype(np.intp), 1)
        below = poisson_cdf(np.arange(int(seen.max())), expected[maybe])[np.arange(maybe.size), seen - 1]
        cluster = maybe[1.0 - below < CLUSTER_ALPHA]  # P(N >= seen) under the ring's rate
        out[cluster] = found[cluster] / (inside[cluster] * frames)
    return out.reshape(h, w)


def compound_poisson_quantile(lam: float, area, area_weight, height, height_weight, q: float) -> float:
    r"""The ``q`` quantile of a sum of ``Poisson(lam)`` products ``a * h``, ``a`` and ``h`` drawn independently.

    ``a`` from the values ``area`` with probabilities in proportion to
    ``area_weight``, ``h`` from ``height`` in proportion to
    ``height_weight``. Values are rounded up onto a grid of a 256th of the
    largest product (each of ``a`` and ``h`` first onto 128 levels of its
    largest), so the result is an upper bound within one grid step per
    term; the sum's distribution is the inverse FFT of its characteristic
    function :math:`\exp(\lambda(\phi - 1))` over a range that holds all
    but 1e-12 of the Poisson count.

    Examples
    --------
    >>> compound_poisson_quantile(0.5, [1.0], [1.0], [2.0], [1.0], 0.99)  # 3 jumps of 2: P(N <= 3) = 0.998
    6.0
    """
    area, height = np.asarray(area, dtype=np.float64), np.asarray(height, dtype=np.float64)
    pa, ph = np.asarray(area_weight, dtype=np.float64), np.asarray(height_weight, dtype=np.float64)
    if pa.sum() <= 0:
        pa = np.ones_like(area)
    levels = 128
    a_top, h_top = float(area.max()), float(height.max())
    if lam <= 0 or a_top <= 0 or h_top <= 0 or math.exp(-lam) >= q:
        return 0.0
    a_pmf = np.bincount(np.ceil(area / a_top * levels).astype(np.intp), pa, minlength=levels + 1)
    h_pmf = np.bincount(np.ceil(height / h_top * levels).astype(np.intp), ph, minlength=levels + 1)
    a_pmf, h_pmf = a_pmf / a_pmf.sum(), h_pmf / h_pmf.sum()
    steps = 256  # grid steps per largest product
    dx = a_top * h_top / steps
    grid = np.arange(levels + 1, dtype=np.float64) / levels
    cell = np.ceil(np.outer(grid, grid) * steps - 1e-9).astype(np.intp)  # (a level, h level) -> grid step
    k = np.arange(0, 64 + int(10 * lam) + 1)
    most = int(np.argmax(poisson_cdf(k, np.array([lam]))[0] >= 1.0 - 1e-12)) + 1
    size = 1 << math.ceil(math.log2(steps * most + 1))
    one = np.bincount(cell.reshape(-1), np.outer(a_pmf, h_pmf).reshape(-1), minlength=size)[:size]
    pmf = np.fft.irfft(np.exp(lam * (np.fft.rfft(one) - 1.0)), size)
    cdf = np.cumsum(np.maximum(pmf, 0.0))
    return float(np.argmax(cdf >= q * cdf[-1]) * dx)


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
