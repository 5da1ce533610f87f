"""The per-frame image steps of the pipeline and the checks of its inputs.

:func:`check_frames` validates a frame or stack for a camera;
:func:`subtract_baseline`, :func:`denoise` and :func:`apply_threshold` are
steps 1-3 of :mod:`optitact.pipeline.frame_pipeline`; :func:`readings_from_moments` turns a
region's sums into :class:`~optitact.pipeline.readings.Readings`;
:func:`estimate_noise` measures a camera's temporal noise from a no-load
stack; :func:`noise_from_stack` maps it pixel by pixel and
:func:`noise_from_one_frame` maps the noise of a single no-load frame;
:func:`threshold_sigmas` turns an estimated noise into a threshold with the
false-alarm rate of ``k`` sigmas. :class:`optitact.pipeline.frame_pipeline.Pipeline` runs them (its
``"reference"`` method in turn, its ``"fast"`` method folded into per-pixel
weights).

Convention
----------
Images are ``(row, col)`` with the origin at the top-left pixel centre; grey
levels are the frame's own units (DN for camera frames).
"""

from __future__ import annotations

import math
import warnings

import numpy as np

from optitact._validate import check_type
from optitact.optics.camera import Camera
from optitact.errors import InputError, KindError, OptitactWarning, ShapeError
from optitact.pipeline.readings import Readings

__all__ = ["FILTERS", "G_MIN", "MAX_GREY", "add_clipped_tail", "apply_threshold", "check_frames",
           "clipped_tail", "denoise", "estimate_noise", "filter_radius", "gaussian_kernel", "impulse_hits",
           "impulses", "maximum_noise", "noise_from_one_frame", "noise_from_stack", "noise_from_variance",
           "pooled_variance", "readings_from_moments", "saturation_level", "stack_mean", "subtract_baseline",
           "temporal_variance", "threshold_sigmas"]

FILTERS = ("none", "gaussian", "median")
#: moments) and the squares in the noise estimates then stay far inside float64's range.
MAX_GREY = 1e100
#: Smallest G (grey level x mm^2) that can read as contact: below it the sums are made of
#: subnormal numbers, whose rounding would make the centroid meaningless.
G_MIN = 1e-250
#: Fewest interior pixels from which :func:`noise_from_one_frame` estimates a frame's noise.
MIN_NOISE_PIXELS = 1000
#: Grey-level bins of :func:`noise_from_one_frame` (at most; each holds >= MIN_NOISE_PIXELS / 4).
NOISE_BINS = 16
#: Per-pixel noise of a stack baseline (``Pipeline(stack_noise=...)``): :func:`noise_from_stack`'s
#: pooled variance, or the earlier :func:`maximum_noise`.
STACK_NOISE = ("pooled", "maximum")
#: Width (px, Gaussian sigma) over which :func:`noise_from_stack` pools the per-pixel variances.
NOISE_POOL_SIGMA = 1.5
#: Fraction of pixels of uniform Gaussian noise that :func:`noise_from_stack` finds noisier than
#: their neighbourhood (and gives their own noise).
OUTLIER_RATE = 1e-3


# ---------------------------------------------------------------------------- input checks
def check_frames(frames, camera: Camera, name: str = "frames") -> tuple[np.ndarray, bool]:
    """Validate a frame ``(H, W)`` or stack ``(T, H, W)`` for a camera.

    Returns
    -------
    stack : (T, H, W) ndarray
        The input as a stack (a view where possible; never modified).
        float16 frames come back as float32 and extended-precision floats
        as float64 (both exact for the accepted range).
    single : bool
        True when a single 2-D frame came in.

    Raises
    ------
    TypeError
        For a non-numeric, bool, complex or object dtype, or nested
        sequences that do not form an array.
    ShapeError
        If the array is not 2-D or 3-D or its image size is not the camera's
        ``(height, width)``.
    InputError
        For an empty stack, a NaN or infinite pixel, a float pixel beyond
        ``MAX_GREY`` in magnitude, or a negative value in an integer frame.
    """
    check_type(camera, Camera, "camera")
    try:
        arr = np.asarray(frames)
    except (ValueError, TypeError) as exc:  # ragged nested sequences
        raise KindError(f"{name} must be an array of grey levels (H, W) or (T, H, W); "
                        f"could not make one ({exc})") from None
    if arr.dtype.kind not in "uif":
        raise KindError(f"{name} must have an unsigned/signed integer or float dtype "
                        f"(uint8, uint16, float32, float64), got {arr.dtype}")
    if arr.ndim not in (2, 3):
        raise ShapeError(f"{name} must be a frame (H, W) or a stack (T, H, W), got shape {arr.shape}")
    if arr.shape[-2:] != camera.shape:
        raise ShapeError(f"{name} must be {camera.shape[0]}x{camera.shape[1]} (H, W) for this camera, "
                         f"got {arr.shape[-2]}x{arr.shape[-1]}")
    single = arr.ndim == 2
    stack = arr[None] if single else arr
    if stack.shape[0] == 0:
        raise InputError(f"{name} is an empty stack (0 frames)")
    if arr.dtype.kind == "f":
        if not _within_max_grey(stack):
            ok = np.isfinite(stack)
            if not ok.all():
                t, r, c = (int(i) for i in np.argwhere(~ok)[0])
                raise InputError(f"{name} must be finite, got {stack[t, r, c]} at frame {t}, "
                                 f"pixel (row {r}, col {c})")
            t, r, c = (int(i) for i in np.argwhere(np.abs(stack) > MAX_GREY)[0])
            raise InputError(f"{name} must hold grey levels of magnitude at most {MAX_GREY:g}, got "
                             f"{stack[t, r, c]} at frame {t}, pixel (row {r}, col {c})")
        if arr.dtype.itemsize < 4:
            stack = stack.astype(np.float32)
        elif arr.dtype.itemsize > 8:
            stack = stack.astype(np.float64)
    elif arr.dtype.kind == "i" and stack.size and stack.min() < 0:
        t, r, c = (int(i) for i in np.argwhere(stack < 0)[0])
        raise InputError(f"{name} must be non-negative grey levels, got {stack[t, r, c]} at "
                         f"frame {t}, pixel (row {r}, col {c})")
    return stack, single


def _within_max_grey(arr: np.ndarray) -> bool:
    """True when a non-empty float array is finite and within ``MAX_GREY`` in magnitude."""
    bound = np.asarray(MAX_GREY, dtype=np.result_type(arr.dtype, np.float64))
    return bool(arr.min() >= -bound and arr.max() <= bound)  # NaN fails both


def stack_mean(frames: np.ndarray) -> np.ndarray:
    """Mean over the first axis of a float64 array, to float64 rounding for any length.

    Pairwise sums (error growing as log T, where numpy's reduction over the
    first axis grows as T), then one correction pass: the pairwise mean of
    the residuals, which are small, is added back.

    Parameters
    ----------
    frames : (T, ...) float64 ndarray
        A stack, ``T >= 1``.

    Returns
    -------
    (...) float64 ndarray
        The mean frame (a new array).

    Examples
    --------
    >>> stack_mean(np.array([[1.0, 2.0], [3.0, 6.0]]))
    array([2., 4.])
    """
    t_n = frames.shape[0]
    mean = _pairwise_sum0(frames) / t_n
    return mean + _pairwise_sum0(frames - mean) / t_n


def _pairwise_sum0(a: np.ndarray) -> np.ndarray:
    """Sum over the first axis by pairwise halving (a new array)."""
    while a.shape[0] > 1:
        half = a.shape[0] // 2
        total = a[:half] + a[half:2 * half]
        if a.shape[0] % 2:
            total[0] += a[-1]
        a = total
    return np.array(a[0])


def _var0(frames: np.ndarray) -> np.ndarray:
    """Sample variance (ddof = 1) over the first axis, with :func:`stack_mean`'s accuracy."""
    dev = frames - stack_mean(frames)
    return _pairwise_sum0(dev * dev) / (frames.shape[0] - 1)


def saturation_level(dtype: np.dtype, saturation: float | None) -> float:
    """Grey level at and above which a pixel of a ``dtype`` frame is saturated.

    Parameters
    ----------
    dtype : numpy.dtype
        The frames' dtype.
    saturation : float or None
        The level stated (in the frames' grey levels); None: the integer
        dtype's maximum (255, 65535), or none (``inf``) for float frames.

    Returns
    -------
    float

    Examples
    --------
    >>> saturation_level(np.dtype(np.uint8), None), saturation_level(np.dtype(np.float32), None)
    (255.0, inf)
    """
    if saturation is not None:
        return saturation
    if dtype.kind in "ui":
        return float(np.iinfo(dtype).max)
    return math.inf


# ---------------------------------------------------------------------------- steps
def subtract_baseline(frame, baseline=None, *, clip: bool = True) -> np.ndarray:
    """Step 1: ``frame - baseline`` in float64, clipped at 0 (a new array).

    Parameters
    ----------
    frame : (H, W) array_like
    baseline : (H, W) array_like or None
        The no-load frame (for example the mean of the first frames of a
        stream); None subtracts nothing.
    clip : bool
        Clip at zero (default). The pipeline keeps the sign when a filter
        follows, so that the filter averages zero-mean noise; its threshold
        (>= 0) then does the clipping.
    """
    img = np.asarray(frame, dtype=np.float64)
    if baseline is not None:
        b = np.asarray(baseline, dtype=np.float64)
        if b.shape != img.shape:
            raise ShapeError(f"baseline must have the frame's shape {img.shape}, got {b.shape}")
        img = img - b
    return np.maximum(img, 0.0) if clip else np.array(img)


def gaussian_kernel(size: float) -> np.ndarray:
    """The 1-D kernel of the ``"gaussian"`` filter (:func:`denoise`): sigma ``size`` px, 3 sigma each side.

    Parameters
    ----------
    size : float
        The Gaussian's sigma in pixels, > 0.

    Returns
    -------
    (2 r + 1,) float64 ndarray
        The normalised kernel, ``r = max(1, ceil(3 size))``; the filter
        applies it along rows and columns.

    Examples
    --------
    >>> k = gaussian_kernel(1.0)
    >>> len(k), round(float(k.sum()), 12)
    (7, 1.0)
    """
    import cv2

    radius = max(1, math.ceil(3.0 * size))
    return cv2.getGaussianKernel(2 * radius + 1, size, cv2.CV_64F).ravel()


def filter_radius(method: str, size: float) -> int:
    """Pixels on each side that a filter reads (0 for ``"none"``)."""
    if method == "gaussian":
        return (len(gaussian_kernel(size)) - 1) // 2
    if method == "median":
        return int(size) // 2
    return 0


def denoise(image, *, method: str = "none", size: float = 1.0) -> np.ndarray:
    """Step 2: denoise a float image (a new array).

    Parameters
    ----------
    image : (H, W) array_like
    method : {"none", "gaussian", "median"}
        ``"gaussian"``: separable Gaussian of standard deviation ``size``
        pixels, truncated at ``ceil(3 size)``; ``"median"``: median over a
        ``size x size`` window (odd integer ``size``). Borders reflect
        (``cv2.BORDER_REFLECT_101`` / ``mode="mirror"``).
    size : float
        The filter's size (see ``method``).
    """
    img = np.array(image, dtype=np.float64)
    if method == "none":
        return img
    if method == "gaussian":
        import cv2

        k = gaussian_kernel(size)
        return cv2.sepFilter2D(img, cv2.CV_64F, k, k, borderType=cv2.BORDER_REFLECT_101)
    if method == "median":
        from scipy.ndimage import median_filter

        return median_filter(img, size=int(size), mode="mirror")
    raise InputError(f"filter must be one of {FILTERS}, got {method!r}")


def apply_threshold(image, threshold: float) -> np.ndarray:
    """Step 3: keep pixels above ``threshold``, zero the rest (a new float64 array)."""
    img = np.asarray(image, dtype=np.float64)
    return np.where(img > threshold, img, 0.0)


def readings_from_moments(G, M, saturated, floor, *, weight=None) -> Readings:
    """Turn integrated values and moments into readings.

    Parameters
    ----------
    G : (E,) or (T, E) array_like
        Integrated grey value of each region.
    M : (E, 2) or (T, E, 2) array_like
        First moments of the centroid's weights (see ``weight``).
    saturated : bool array_like, shape of ``G``
    floor : (E,) array_like
        Noise floor of G per region.
    weight : array_like, shape of ``G``, optional
        Sum of the centroid's weights, ``u = M / weight``; default ``G``
        (the plain grey-value centroid). The pipeline weighs each lit value by
        its height above the threshold (see :class:`Pipeline`).

    Notes
    -----
    A region is in contact when ``G > floor`` and ``G > G_MIN`` (1e-250:
    smaller sums are built of subnormal numbers); then ``u = M / weight``.
    Regions not in contact read ``G = 0``, ``u = (0, 0)`` (never NaN).
    """
    g = np.asarray(G, dtype=np.float64)
    m = np.asarray(M, dtype=np.float64)
    w = g if weight is None else np.asarray(weight, dtype=np.float64)
    contact = (g > floor) & (g > G_MIN)
    g = np.where(contact, g, 0.0)
    u = np.divide(m, w[..., None], out=np.zeros(m.shape), where=(contact & (w > 0))[..., None])
    return Readings(g, u, contact, np.asarray(saturated, dtype=bool))


def estimate_noise(frames) -> float:
    """Temporal noise (grey levels, rms) of a no-load stack ``(T, H, W)``, ``T >= 2``.

    The square root of the mean over pixels of the per-pixel sample variance.
    """
    try:
        arr = np.asarray(frames)
    except (ValueError, TypeError) as exc:
        raise KindError(f"frames must be a real numeric stack (T, H, W); could not make one ({exc})") from None
    if arr.ndim != 3 or arr.shape[0] < 2:
        raise ShapeError(f"estimate_noise needs a stack (T, H, W) with T >= 2, got {arr.shape}")
    if arr.dtype.kind not in "uif":
        raise KindError(f"frames must be a real numeric stack, got dtype {arr.dtype}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise InputError("frames must be finite")
    if arr.size and arr.dtype.kind == "f" and not _within_max_grey(arr):
        raise InputError(f"frames must hold grey levels of magnitude at most {MAX_GREY:g}, got "
                         f"{np.abs(arr).max()}")
    var = _var0(arr.astype(np.float64))
    return float(np.sqrt(var.mean())) if var.size else 0.0


def temporal_variance(frames) -> np.ndarray:
    """Per-pixel sample variance (ddof 1) of a stack ``(T, H, W)``, ``T >= 2``, in float64.

    Pairwise sums over the frames (:func:`estimate_noise`'s accuracy for any ``T``).
    """
    return _var0(np.asarray(frames, dtype=np.float64))


def _pool_kernel() -> np.ndarray:
    import cv2

    radius = max(1, math.ceil(3.0 * NOISE_POOL_SIGMA))
    return cv2.getGaussianKernel(2 * radius + 1, NOISE_POOL_SIGMA, cv2.CV_64F).ravel()


def pooled_variance(variance, *, exclude=None) -> tuple[np.ndarray, float]:
    r"""Per-pixel variances averaged over a Gaussian neighbourhood, leaving some pixels out.

    Parameters
    ----------
    variance : (H, W) array_like
        Per-pixel sample variances (:func:`temporal_variance`).
    exclude : (H, W) bool array_like, optional
        Pixels whose variance does not stand for their neighbours' (the
        isolated bright pixels of :func:`impulse_hits`): each pixel's pool
        is the weighted mean over the others (all of them where a whole
        neighbourhood is excluded).

    Returns
    -------
    pooled : (H, W) float64 ndarray
    samples : float
        Independent pixels a pool is worth, :math:`1 / \sum_i w_i^2` for the
        Gaussian weights :math:`w_i` of ``NOISE_POOL_SIGMA`` (1.5) pixels:
        :math:`4 \pi \sigma^2 \approx 28.3`.
    """
    import cv2

    w = _pool_kernel()
    var = np.asarray(variance, dtype=np.float64)
    blur = lambda a: cv2.sepFilter2D(a, cv2.CV_64F, w, w, borderType=cv2.BORDER_REFLECT_101)  # noqa: E731
    pooled = blur(var)
    if exclude is not None and np.any(exclude):
        keep = ~np.asarray(exclude, dtype=bool)
        weight = blur(keep.astype(np.float64))
        kept = blur(np.where(keep, var, 0.0))
        ok = weight > 1e-3
        pooled = np.where(ok, kept / np.where(ok, weight, 1.0), pooled)
    return np.maximum(pooled, 0.0), 1.0 / float(np.sum(w * w)) ** 2


def noise_from_stack(frames, *, exclude=None) -> tuple[np.ndarray, float]:
    r"""Per-pixel noise (grey levels, rms) of ``frame - mean(frames)`` for a no-load stack, and its dof.

    Parameters
    ----------
    frames : (T, H, W) array_like
        No-load frames, ``T >= 2`` (validated by the caller).
    exclude : (H, W) bool array_like, optional
        Pixels left out of their neighbours' noise (see
        :func:`pooled_variance`): the baseline's isolated bright pixels,
        which the noise floor counts apart
        (:func:`optitact.pipeline.baseline.baseline_noise`).

    Returns
    -------
    noise : (H, W) float64 ndarray
        The noise of a new frame minus the stack's mean, at every pixel.
    dof : float
        Degrees of freedom of the variance it is estimated from (see *Notes*):
        :func:`threshold_sigmas` turns ``k`` into the threshold that keeps the
        false-alarm rate of ``k`` sigmas despite the estimate's own error.

    Notes
    -----
    The sample variances :math:`s^2` of the pixels (ddof 1: :math:`T - 1`
    degrees of freedom each; two frames give one, too few for a pixel on its
    own) are pooled with a Gaussian of ``NOISE_POOL_SIGMA`` (1.5) pixels,
    :math:`v = \sum_i w_i s_i^2`. Where the noise is locally uniform and
    white, ``v`` is a scaled chi-square with :math:`\nu = (T - 1) / \sum_i w_i^2`
    degrees of freedom (Satterthwaite; :math:`28.3 (T - 1)` here). A new
    frame minus the mean of ``T`` frames has the variance
    :math:`\sigma^2 (1 + 1/T)`, so the noise is :math:`\sqrt{v (1 + 1/T)}`,
    taken at the largest value in each 3 x 3 neighbourhood: a pixel on the
    noisy side of a step in the noise (the edge of a bright feature) is then
    not judged by its quieter neighbours. On uniform noise this maximum keeps
    a threshold of :func:`threshold_sigmas` (k, dof) noises below the rate
    of ``k`` sigmas (0.4 of it from 2 frames, 0.8 from 20), at 3.5, 3.2 and
    3.1 true sigmas from 2, 4 and 6 frames for ``k = 3``.

    A pixel noisier than its neighbourhood (a flickering hot pixel) would be
    lost in the pool: where its own variance exceeds the pool by more than
    uniform noise allows in a fraction ``OUTLIER_RATE`` (1e-3) of pixels
    (the F distribution with :math:`T - 1` and :math:`\nu` degrees of
    freedom), its own :math:`\sqrt{s^2 (1 + 1/T)}` is taken when larger.

    Examples
    --------
    >>> import numpy as np
    >>> stack = np.random.default_rng(0).normal(50.0, 2.0, (4, 120, 160))
    >>> noise, dof = noise_from_stack(stack)
    >>> round(dof, 1), round(float(np.median(noise) / (2.0 * np.sqrt(1.25))), 1)  # 2 sqrt(1 + 1/4)
    (84.8, 1.0)
    """
    x = np.asarray(frames)
    return noise_from_variance(temporal_variance(x), x.shape[0], exclude=exclude)


def noise_from_variance(variance, n_frames: int, *, exclude=None) -> tuple[np.ndarray, float]:
    """:func:`noise_from_stack` from the stack's :func:`temporal_variance` and its number of frames."""
    from scipy.ndimage import maximum_filter  # a fifth of a second to import: stacks only
    from scipy.special import fdtri

    var = np.asarray(variance, dtype=np.float64)
    pooled, samples = pooled_variance(var, exclude=exclude)
    dof = (n_frames - 1) * samples
    scale = 1.0 + 1.0 / n_frames
    noise = maximum_filter(np.sqrt(pooled * scale), size=3, mode="nearest")
    outlier = var > float(fdtri(n_frames - 1, dof, 1.0 - OUTLIER_RATE)) * pooled
    return np.where(outlier, np.maximum(noise, np.sqrt(var * scale)), noise), dof


def maximum_noise(variance, n_frames: int) -> np.ndarray:
    r"""The earlier per-pixel noise of a stack baseline, which calibrations fitted before the pooled one expect.

    Parameters
    ----------
    variance : (H, W) array_like
        The stack's :func:`temporal_variance`.
    n_frames : int
        Frames of the stack (>= 2).

    Returns
    -------
    (H, W) float64 ndarray
        :math:`\sqrt{v (1 + 1/T)}`, ``v`` the largest variance in each 3 x 3
        neighbourhood blurred by a Gaussian of 1 pixel; the threshold is
        ``k`` times it (``Pipeline(stack_noise="maximum")``).

    Notes
    -----
    Conservative where the frames are few (``k = 3`` lets Gaussian noise
    through as rarely as 5.5 true sigmas from 2 frames, 4.6 from 4): the
    maximum of nine variances of :math:`T - 1` degrees of freedom lies well
    above their mean. Its isolated bright pixels raise the threshold of
    their neighbours too. G and the centroid read through it differ from
    :func:`noise_from_stack`'s where the background is noisy (the
    path-traced rim of a synthetic frame: 0.3 % in G, more in the centroid),
    and a calibration applies only with the map its readings were made
    with.
    """
    import cv2
    from scipy.ndimage import maximum_filter  # a fifth of a second to import: stacks only

    var = maximum_filter(np.asarray(variance, dtype=np.float64), size=3, mode="nearest")
    var = cv2.GaussianBlur(var, (0, 0), 1.0, borderType=cv2.BORDER_REFLECT_101)
    return np.sqrt(np.maximum(var, 0.0) * (1.0 + 1.0 / n_frames))


def threshold_sigmas(k: float, dof: float) -> float:
    r"""Multiple of an estimated noise that Gaussian noise exceeds as rarely as it exceeds ``k`` true sigmas.

    Parameters
    ----------
    k : float
        The threshold in true sigmas (>= 0).
    dof : float
        Degrees of freedom of the noise's estimate (``math.inf``: known).

    Returns
    -------
    float
        Student's t quantile :math:`t_\nu^{-1}(1 - Q(k))` (``Q``: the normal
        upper tail), never below ``k``.

    Notes
    -----
    A value of Gaussian noise divided by an independent estimate of its
    sigma with :math:`\nu` degrees of freedom is Student-t distributed;
    a threshold at ``k`` estimated sigmas would let through more than
    :math:`Q(k)` of the noise (from one frame pair, :math:`\nu = 1`: 20 %
    of pixels above 3 estimated sigmas, not 0.13 %). The quantile restores
    the rate for any number of frames. Tails beyond ``1e-300`` (``k`` above
    about 37) are taken at ``1e-300``.

    Examples
    --------
    >>> round(threshold_sigmas(3.0, 28.3), 2), threshold_sigmas(3.0, float("inf"))
    (3.29, 3.0)
    """
    if k == 0.0 or math.isinf(dof):
        return k
    from scipy.special import stdtrit  # loaded with scipy.ndimage (noise_from_stack): no extra start-up

    tail = max(0.5 * math.erfc(k / math.sqrt(2.0)), 1e-300)
    return max(k, -float(stdtrit(dof, tail)))


def _median(a: np.ndarray) -> np.float64:
    """``np.median`` of a non-empty array without NaN, to the bit (whose NaN check imports ``numpy.ma``)."""
    a = a.reshape(-1)
    k = a.size // 2
    if a.size % 2:
        return np.partition(a, k)[k]
    p = np.partition(a, (k - 1, k))
    return (p[k - 1] + p[k]) / 2.0


def _small_integers(a: np.ndarray) -> bool:
    """Integers of at most 16 bits: the one-frame statistics below take exact integer paths for them."""
    return a.dtype.kind in "ui" and a.dtype.itemsize <= 2


def noise_from_one_frame(frame, *, stacklevel: int = 2) -> np.ndarray | None:
    r"""Per-pixel noise (grey levels, rms) of ``frame - baseline`` for a one-frame no-load baseline.

    One frame holds no temporal noise; this measures its spatial
    fluctuations instead, as a function of the grey level (photon noise
    grows with it), assuming the no-load image is smooth on the scale of a
    pixel and its noise white.

    Parameters
    ----------
    frame : (H, W) array_like
        The no-load frame (validated by the caller).
    stacklevel : int
        Of the warning, for callers that wrap this.

    Returns
    -------
    (H, W) float64 ndarray or None
        The noise of a frame minus this baseline at every pixel; None, with
        a warning, when the frame has fewer than ``MIN_NOISE_PIXELS``
        interior pixels to tell it from.

    Notes
    -----
    The residual of each interior pixel from the mean of its left and right
    neighbours, :math:`r = x - (x_l + x_r) / 2`, has variance
    :math:`\tfrac32 \sigma^2` for white noise of variance :math:`\sigma^2`
    (a smooth image cancels to second order). Its level ``m`` is the mean of
    the six pixels above and below (rows the residual does not use, so that
    sorting by ``m`` does not select the noise). Pixels are sorted by ``m``
    into up to ``NOISE_BINS`` bins of equal counts; in each, the variance of
    ``r`` is the mean square of the residuals within ``max(4 s, 2 q)`` of
    their median (``s`` = 1.4826 times their median absolute deviation,
    ``q`` the smallest non-zero deviation: edges and texture are left out,
    and quantised frames keep their one-level steps whatever their scale,
    so that frames times a constant give the noise times that constant).
    Interpolated linearly in
    ``m`` (clamped at the ends), :math:`\sigma^2(m) = \tfrac23 \mathrm{var}(r)`,
    and a frame minus the baseline holds the noise of both:
    :math:`\sqrt{2 \sigma^2(m)}`.

    Examples
    --------
    >>> import numpy as np
    >>> frame = np.random.default_rng(0).normal(50.0, 2.0, (120, 160))
    >>> noise = noise_from_one_frame(frame)
    >>> bool(abs(noise.mean() / (2.0 * np.sqrt(2.0)) - 1.0) < 0.05)
    True
    """
    x = np.asarray(frame)
    integer = _small_integers(x)
    if not integer:
        x = x.astype(np.float64, copy=False)
    h, w = x.shape
    if (h - 2) * (w - 2) < MIN_NOISE_PIXELS:
        warnings.warn(f"a one-frame baseline of {h}x{w} pixels is too small to estimate its noise from "
                      f"(fewer than {MIN_NOISE_PIXELS} interior pixels): the threshold is noise_sigma "
                      f"alone; average several no-load frames (a baseline stack) to measure the noise",
                      OptitactWarning, stacklevel=stacklevel)
        return None
    if integer:  # the same values from exact integer sums; the sort is a radix sort of 16-bit keys
        g = x.astype(np.int16 if x.dtype.itemsize == 1 else np.int32)
        r = ((g[1:-1, 1:-1] * 2 - g[1:-1, :-2] - g[1:-1, 2:]) / 2.0).ravel()
        s6 = g[:-2, :-2] + g[:-2, 1:-1] + g[:-2, 2:] + g[2:, :-2] + g[2:, 1:-1] + g[2:, 2:]
        m_in = (s6 / 6.0).ravel()
        order = np.argsort(s6.reshape(-1), kind="stable")  # s / 6.0 keeps the order of s, ties and all
    else:
        r = (x[1:-1, 1:-1] - 0.5 * (x[1:-1, :-2] + x[1:-1, 2:])).ravel()
        m_in = (x[:-2, :-2] + x[:-2, 1:-1] + x[:-2, 2:] + x[2:, :-2] + x[2:, 1:-1] + x[2:, 2:]) / 6.0
        m_in = m_in.ravel()
        order = np.argsort(m_in, kind="stable")
    n_bins = max(1, min(NOISE_BINS, len(order) * 4 // MIN_NOISE_PIXELS))
    centres, variances = [], []
    for chunk in np.array_split(order, n_bins):
        res = r[chunk]
        med = _median(res)
        dev = np.abs(res - med)
        step = dev[dev > 0]
        keep = dev <= max(4.0 * 1.4826 * float(_median(dev)), 2.0 * step.min() if step.size else 0.0)
        centres.append(float(_median(m_in[chunk])))
        variances.append(float(np.mean((res[keep] - med) ** 2)))
    centres, variances = np.array(centres), np.array(variances)
    # equal centres (a frame with many pixels at one level): the larger variance, conservatively
    xp, inv = np.unique(centres, return_inverse=True)
    fp = np.zeros(len(xp))
    np.maximum.at(fp, inv, variances)
    if integer:  # the noise of each level sum once, looked up (elementwise: padding commutes)
        lo = int(s6.min())
        var = np.interp(np.arange(lo, int(s6.max()) + 1) / 6.0, xp, fp) * (2.0 / 3.0)
        return np.pad(np.sqrt(2.0 * var)[s6 - lo], 1, mode="edge")
    level = np.pad(m_in.reshape(h - 2, w - 2), 1, mode="edge")
    var = np.interp(level, xp, fp) * (2.0 / 3.0)
    return np.sqrt(2.0 * var)


#: A pixel is an impulse when it stands this many residual sigmas above both pairs of neighbours.
IMPULSE_SIGMAS = 6.0


def impulses(frames) -> tuple[np.ndarray, np.ndarray]:
    r"""Mean height (grey levels) of the isolated bright pixels of no-load frames: hot pixels, fireflies.

    Gaussian noise models the many small fluctuations of a no-load frame;
    some frames also hold rare isolated bright pixels (a hot or flickering
    pixel, a cosmic ray, the Monte Carlo outliers of a path-traced frame).
    Another frame holds as many at other places, and a region's sum then
    reads them as light: the noise floor of G must include them.

    Parameters
    ----------
    frames : (T, H, W) array_like
        No-load frames (validated by the caller).

    Returns
    -------
    rate, height : (H, W) float64 ndarrays
        Per pixel, the fraction of the frames in which it is an impulse,
        and the mean over the frames of its height above its neighbours
        (0 in a frame where it is not an impulse).

    Notes
    -----
    A pixel is an impulse where both its horizontal and its vertical
    second-difference residuals, :math:`x - (x_l + x_r)/2` and
    :math:`x - (x_u + x_d)/2`, exceed :data:`IMPULSE_SIGMAS` times their
    robust spread (1.4826 x the median absolute deviation of all residuals,
    at least half a grey level) : a spot of light spreads over several
    pixels, an impulse stands alone. Its height is the smaller residual.

    Examples
    --------
    >>> import numpy as np
    >>> f = np.full((1, 40, 40), 4.0)
    >>> f[0, 10, 20] = 14.0
    >>> rate, height = impulses(f)
    >>> float(rate[10, 20]), float(height[10, 20]), int((rate > 0).sum())
    (1.0, 10.0, 1)
    """
    x = np.asarray(frames)
    if not _small_integers(x):
        x = x.astype(np.float64, copy=False)
    rate, out = np.zeros(x.shape[1:]), np.zeros(x.shape[1:])
    for f in x:
        hit, height = impulse_hits(f)
        rate += hit
        out += height  # 0.0 where not a hit: the same sums
    return rate / len(x), out / len(x)


def impulse_hits(frame) -> tuple[np.ndarray, np.ndarray]:
    """The impulses of one frame (see :func:`impulses`): where they are, and their heights.

    Returns
    -------
    hit : (H, W) bool ndarray
    height : (H, W) float64 ndarray
        The smaller of the two residuals where ``hit``, 0 elsewhere.
    """
    f = np.asarray(frame)
    if not _small_integers(f):
        f = f.astype(np.float64, copy=False)
    hit, height = np.zeros(f.shape, bool), np.zeros(f.shape)
    if f.shape[0] < 3 or f.shape[1] < 3:
        return hit, height
    if f.dtype.kind == "f":
        c = f[1:-1, 1:-1]
        rh = c - 0.5 * (f[1:-1, :-2] + f[1:-1, 2:])
        rv = c - 0.5 * (f[:-2, 1:-1] + f[2:, 1:-1])
        r = np.minimum(rh, rv)
        spread = max(1.4826 * float(_median(np.abs(rh - _median(rh)))), 0.5)
        inner = r > IMPULSE_SIGMAS * spread
        tall = r[inner]
    else:
        inner, tall = _integer_impulses(f)
    hit[1:-1, 1:-1] = inner
    height[1:-1, 1:-1][inner] = tall
    return hit, height


def _integer_impulses(f: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`impulses`' hits and heights in one frame of 8- or 16-bit integers, in integer arithmetic.

    Twice the residuals are integers (``2 x - x_l - x_r``), so every step is
    exact and halving at the end gives the float path's values to the bit:
    medians scale by powers of 2 exactly, and ``r > s`` is ``2 r > 2 s``.
    Medians come from histograms; a quarter of the memory of float64 on
    8-bit frames.
    """
    work = np.int16 if f.dtype.itemsize == 1 else np.int32
    g = f.astype(work)
    c2 = g[1:-1, 1:-1] * work(2)
    rh2 = c2 - g[1:-1, :-2] - g[1:-1, 2:]
    r2 = np.minimum(rh2, c2 - g[:-2, 1:-1] - g[2:, 1:-1])
    med2 = _integer_median(rh2)  # 2 x the median residual: an integer or a half
    q = 1 if med2 == int(med2) else 2  # so that q x 2 x the deviations are integers
    dev = np.abs(rh2 - work(med2)) if q == 1 else np.abs(rh2.astype(np.int32) * 2 - int(2 * med2))
    spread = max(1.4826 * (_integer_median(dev) / (2.0 * q)), 0.5)
    hit = r2 > 2.0 * (IMPULSE_SIGMAS * spread)
    return hit, r2[hit] / 2.0


def _integer_median(a: np.ndarray) -> float:
    """``_median`` of a non-empty integer array, to the bit, from its histogram."""
    a = a.reshape(-1)
    lo = int(a.min())
    cum = np.cumsum(np.bincount((a - lo) if lo else a))
    k = a.size // 2
    upper = lo + int(np.searchsorted(cum, k, side="right"))  # the k-th smallest (from 0)
    if a.size % 2:
        return float(upper)
    return (float(lo + int(np.searchsorted(cum, k - 1, side="right"))) + float(upper)) / 2.0


def clipped_tail(G, W) -> np.ndarray:
    """The energy the threshold clipped from the tails of Gaussian spots, from their lit sums.

    Parameters
    ----------
    G : array_like
        Lit sums ``sum a v`` (grey level x mm^2) of regions in contact.
    W : array_like
        The centroid's weights ``sum a (v - t)`` over the same lit pixels, so
        ``T = G - W = sum a t`` is the lit area times the threshold.

    Returns
    -------
    ndarray
        ``T / L`` (0 where ``T <= 0`` or ``G <= T``), with ``L = ln(A / t)``
        solving ``(e^L - 1) / L = G / T``.

    Notes
    -----
    For a 2-D Gaussian spot of peak ``A`` and width ``s`` thresholded at
    ``t < A``, the lit disc has area ``2 pi s^2 L``, holds ``G = 2 pi s^2
    (A - t)``, and the energy outside it is exactly ``2 pi s^2 t = T / L``.
    Several equal spots (an element's cones) give the same ratio. Spots with
    other tails (a disc blurred by the pixel footprint) get an approximate
    correction; the noise sweep measures how well it serves.

    Examples
    --------
    >>> import math
    >>> A, t, s = 50.0, 5.0, 1.0                       # peak, threshold, width
    >>> L = math.log(A / t)
    >>> G, T = 2 * math.pi * s * s * (A - t), 2 * math.pi * s * s * t * L
    >>> round(float(clipped_tail(G, G - T)), 6) == round(2 * math.pi * s * s * t, 6)
    True
    """
    g = np.asarray(G, dtype=np.float64)
    t = g - np.asarray(W, dtype=np.float64)
    ok = (t > 0) & (g > t)
    q = np.where(ok, g / np.where(ok, t, 1.0), 2.0)
    lo, hi = np.full(q.shape, 1e-12), np.full(q.shape, 60.0)
    for _ in range(80):  # (e^L - 1) / L rises from 1 (L -> 0): bisection on L
        mid = 0.5 * (lo + hi)
        below = np.expm1(mid) / mid < q
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return np.where(ok, t / (0.5 * (lo + hi)), 0.0)


def add_clipped_tail(readings: Readings, W) -> Readings:
    """``readings`` with :func:`clipped_tail` added to G where in contact (u and the flags unchanged)."""
    extra = clipped_tail(readings.G, W)
    return Readings(np.where(readings.contact, readings.G + extra, readings.G), readings.u, readings.contact,
                    readings.saturated)
