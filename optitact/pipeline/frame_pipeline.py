"""The frame pipeline: camera frames to per-element readings (G, u, contact, saturated).

Steps, each a public function (the ``"reference"`` method runs them in turn):

1. :func:`subtract_baseline` -- subtract the no-load frame, clip at zero;
2. :func:`denoise` -- none, Gaussian or median filter;
3. :func:`apply_threshold` -- zero every pixel at or below ``k`` sigma of the noise;
4. :func:`split_regions` (once) and :func:`dewarp` -- resample the image onto
   a fine grid of geodesic tangent coordinates around every element, with
   the closed-form camera model; the grid cells carry their area on the
   dome and their region (Voronoi cell of the element, cut at a radius);
5. :func:`integrate` -- integrated grey value G and grey-value centroid per
   region; :func:`readings_from_moments` turns them into :class:`Readings`
   (no contact -> G = 0, u = 0). G sums the lit values; the centroid weighs
   each lit value by its height above the threshold, ``value - threshold``,
   so that a pixel's weight grows from 0 as it crosses the threshold instead
   of jumping (see :class:`Pipeline`, *Notes*).

The ``"fast"`` method (default) computes the same sums with the linear
stages folded into per-pixel weights: the bilinear dewarp weights times the
cells' areas and coordinates, summed per (element, pixel). A frame then costs
one comparison pass over the frame to find the lit pixels and a few weighted
sums over those. The pipeline hands these sums to a
:class:`~optitact.pipeline.fastpath.FastPath` that it makes and keeps
(:attr:`Pipeline.fast_path`).

Convention
----------
Images are ``(row, col)`` with the origin at the top-left pixel centre; grey
levels are the frame's own units (DN for camera frames). Region grids use
element-local tangent coordinates ``(x, y)`` in mm, geodesic normal
coordinates around the element centre (``sensor.dome_point(e, (x, y))`` is
the dome point of grid coordinate ``(x, y)``).
"""

from __future__ import annotations

import copy
import math

import numpy as np

from optitact.pipeline import kernel as _kernel
from optitact.pipeline.fastpath import FastPath, thread_count
from optitact.pipeline.fastpath import cores as _cores
from optitact.pipeline.baseline import baseline_noise, impulse_floor, take_baseline
from optitact._validate import integer, positive
from optitact.optics.camera import Camera
from optitact.optics.ccd import check_bit_depth, dn_ratio
from optitact.errors import InputError, ShapeError
from optitact.pipeline.readings import Readings
from optitact.pipeline.regions import (deferred_grids, dewarp, fold_regions, integrate)
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.imageops import (FILTERS, STACK_NOISE, add_clipped_tail, apply_threshold, check_frames,
                                        denoise, estimate_noise, filter_radius, gaussian_kernel,
                                        readings_from_moments, saturation_level, stack_mean,
                                        subtract_baseline, threshold_sigmas)

__all__ = ["METHODS", "Pipeline"]

METHODS = ("fast", "reference")
#: What G does with the energy the threshold clips from the spots' tails (``Pipeline(tail=...)``).
TAILS = ("none", "gaussian")
#: Options of :class:`Pipeline` that change how it runs, not its readings (:meth:`Pipeline.replace`).
RUN_OPTIONS = frozenset({"kernel", "threads"})


# ---------------------------------------------------------------------------- the pipeline
class Pipeline:
    r"""Frames to readings for one sensor and camera; precomputes once, then processes fast.

    Parameters
    ----------
    sensor : DomeSensor
    camera : Camera
        Any camera model (:class:`optitact.optics.camera.FisheyeCamera`, the default, or those of
        :mod:`optitact.optics.camera_models`).
    method : {"fast", "reference"}
        ``"fast"`` (default): the folded per-pixel weights; ``"reference"``:
        the steps one after another on the whole frame. They compute the
        same sums and agree to floating-point rounding.
    baseline : (H, W) or (T, H, W) array_like, optional
        No-load frame, or a stack of them: the mean is subtracted, its
        per-pixel noise (from two frames on, the stack's temporal noise;
        from one frame, its spatial fluctuations) raises the threshold
        where the background is noisier than ``noise_sigma`` (see
        ``threshold_map``), and its isolated bright pixels raise the
        noise floor of G. None subtracts nothing (for frames that are
        already background-free). See :meth:`with_baseline`.
    filter : {"none", "gaussian", "median"}
        Denoising before the threshold, default ``"none"``.
    filter_size : float
        Gaussian sigma in pixels (default 1.0) or the median window (odd
        integer, default 3 when ``filter="median"``).
    noise_sigma : float
        Noise of ``frame - baseline`` per pixel, in grey levels, default 0.5
        (an 8-bit camera whose noise is mostly quantisation); use
        :func:`estimate_noise` or :meth:`from_noload` for your camera, and 0
        for noiseless frames.
    k : float
        Threshold in noise sigmas, default 3: pixels at or below
        ``k * sigma_f`` (``sigma_f``: ``noise_sigma`` after the filter, i.e.
        times the Gaussian kernel's L2 norm) count as dark. Where a stack
        baseline's measured noise is higher, the threshold is as many of its
        sigmas as let through what ``k`` true sigmas would
        (:func:`~optitact.pipeline.imageops.threshold_sigmas`: 3.29 for ``k = 3`` from
        two frames, 3.05 from six).
    min_pixels : float
        Contact needs ``G`` above the region's noise floor: what
        ``min_pixels + n_false + 3 sqrt(n_false)`` independent samples just at
        the threshold would give, with ``n_false = n Q(k)`` the number of
        the region's ``n`` samples that Gaussian noise alone puts above the
        threshold on average (``Q``: the normal tail); default 3. A sample
        is a pixel, or after a Gaussian filter its correlation area
        ``1 / sum(k**2)**2 = 4 pi sigma^2`` pixels.
    saturation : float, optional
        Grey level at which a pixel is saturated; default the integer dtype's
        maximum (255, 65535), none for float frames.
    radius, grid_mm : float, optional
        Region radius and dewarp cell size (mm); see :func:`split_regions`.
        The regions' folded weights (:func:`~optitact.pipeline.regions.fold_regions`)
        are cached in the user cache folder, so a pipeline for a sensor and
        camera seen before starts in milliseconds; the grids themselves
        (:attr:`grids`) are built only if the reference method needs them.
    bits : int, optional
        Bit depth of the frames' grey levels (1 to 16), e.g. 12 for 12-bit
        data in ``uint16`` frames. When given, integer frames (and the
        baseline) must fit it: a dtype too small for it, or a value above
        ``2**bits - 1``, is an error. Default: ``readings_bits``, else not
        checked.
    readings_bits : int, optional
        Bit depth whose grey levels the readings' G, ``noise_sigma`` and
        ``saturation`` are in (a calibration's, see
        :meth:`optitact.calib.fit.Calibration.pipeline`). Frames of ``bits`` are
        mapped onto it exactly, by the ratio of the full scales (see
        :func:`optitact.optics.ccd.dn_ratio`: 16-bit frames of an 8-bit scale are
        read as ``frame / 257``), or refused. Without ``bits``, integer
        frames must be of the dtype that holds ``readings_bits`` (``uint8``
        up to 8 bits, ``uint16`` above): ``uint16`` frames for an 8-bit
        scale may hold 12- or 16-bit data and are refused until ``bits``
        says which.
    kernel : {"auto", "numba", "numpy"}
        What computes the fast method's sums: ``"numba"``, one compiled pass
        over the region pixels (the ``fast`` extra: ``pip install
        'optitact[fast]'``; compiled on first use and cached in the user
        cache folder), or ``"numpy"``, gathers and ``np.bincount``. Both
        give the same readings bit for bit. ``"auto"`` (default) takes numba
        when it is installed; :attr:`kernel` says which runs. Frames with a
        filter always take NumPy.
    threads : int, optional
        Threads a ``(T, H, W)`` stack is split across, in blocks of
        consecutive frames (about four a thread) that each thread takes as it
        finishes the last, so a core slowed by other work holds up no more
        than its block (the compiled kernel releases the GIL; the threads are
        kept between calls); the readings are the same as one thread's, in
        frame order. Default: every core this process may use, with at least
        ``MIN_FRAMES_PER_THREAD`` (8) frames each, so single frames and short
        stacks stay on the calling thread. ``threads=1``: never split.
    tail : {"none", "gaussian"}
        ``"gaussian"`` adds back to G the energy the threshold clipped from
        the spots' tails (:func:`~optitact.pipeline.imageops.clipped_tail`: exact for
        Gaussian spots, from G and the lit pixels' summed threshold); default
        ``"none"``. A calibration fitted with it must be applied with it.
    stack_noise : {"pooled", "maximum"}
        The per-pixel noise of a baseline of two or more frames:
        ``"pooled"`` (default), each pixel's temporal variance pooled over
        its neighbours, the threshold :func:`~optitact.pipeline.imageops.threshold_sigmas`
        times it (:func:`~optitact.pipeline.imageops.noise_from_stack`); ``"maximum"``,
        the earlier map, the largest variance of each 3 x 3 neighbourhood,
        ``k`` times it (:func:`~optitact.pipeline.imageops.maximum_noise`): higher, and
        what the calibrations fitted on readings made before the pooled map
        expect (the shipped one among them). The contact floor allows for
        the baseline's isolated bright pixels with either.

    Raises
    ------
    MissingExtraError
        ``kernel="numba"`` without numba installed.
    TypeError, InputError, ShapeError
        For a wrong kind or value of an option or of the baseline (see
        :func:`check_frames`); also when ``k * noise_sigma`` or the noise
        floor would overflow float64, and when the frames' ``bits`` cannot
        be mapped exactly onto ``readings_bits``.

    Notes
    -----
    With ``v`` a pixel's value after the baseline and the filter and ``t``
    its threshold, a region reads

    .. math::

        G = \sum_{v > t} a\,v, \qquad
        u = \frac{\sum_{v > t} a\,(x, y)\,(v - t)}{\sum_{v > t} a\,(v - t)}

    (``a``, ``x``, ``y``: the pixel's folded area and coordinates). The
    centroid's weights ``v - t`` rise continuously from 0 at the threshold:
    with the plain weights ``v``, a faint pixel flickering across the
    threshold moves the centroid by a jump of ``t`` times its lever arm,
    which dominated the centroid's noise for faint, wide spots (integer
    frames make the jump larger: the smallest lit value of an 8-bit frame at
    a 1.5 DN threshold is 2 DN). For a Gaussian spot of rms width 0.5 mm
    with the energy of a 0.5 N load, on the default camera and CCD, this
    raises the centroid's efficiency against the Cramer-Rao bound from about
    0.67 to 0.92 (the noise sweep study, ``optitact.studies.noise_sweep``); on rendered
    frames, whose spots are compact and bright, the centroid's noise is
    unchanged and the calibrated shear error the same or slightly lower.
    Symmetric spots keep their centroid; noiseless frames (``t = 0``) read
    the plain centroid.

    Examples
    --------
    >>> import numpy as np
    >>> from optitact.optics.camera import FisheyeCamera
    >>> from optitact.optics.sensor import DomeSensor
    >>> s, cam = DomeSensor.default(), FisheyeCamera(width=160, height=120)
    >>> pipe = Pipeline(s, cam)
    >>> r = pipe.process(np.zeros(cam.shape, np.uint8))
    >>> r.G.shape, bool(r.contact.any())
    ((41,), False)
    """

    def __init__(self, sensor: DomeSensor, camera: Camera, *, method: str = "fast",
                 baseline=None, filter: str = "none", filter_size: float | None = None,
                 noise_sigma: float = 0.5, k: float = 3.0, min_pixels: float = 3.0,
                 saturation: float | None = None, radius: float | None = None,
                 grid_mm: float | None = None, bits: int | None = None,
                 readings_bits: int | None = None, kernel: str = "auto",
                 threads: int | None = None, tail: str = "none", stack_noise: str = "pooled") -> None:
        if not isinstance(sensor, DomeSensor):
            raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
        if not isinstance(camera, Camera):
            raise TypeError(f"camera must be a FisheyeCamera, got {type(camera).__name__} (or another camera "
                            f"model of optitact.optics.camera: PinholeCamera, OpenCVFisheyeCamera)")
        if method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {method!r}")
        if filter not in FILTERS:
            raise InputError(f"filter must be one of {FILTERS}, got {filter!r}")
        if filter_size is None:
            filter_size = 3 if filter == "median" else 1.0
        if filter == "median":
            filter_size = integer(filter_size, "filter_size", minimum=1)
            if filter_size % 2 == 0:
                raise InputError(f"filter_size of a median must be odd, got {filter_size}")
        else:
            filter_size = positive(filter_size, "filter_size")
        _check_filter_fits(filter, filter_size, camera)
        if tail not in TAILS:
            raise InputError(f"tail must be one of {TAILS}, got {tail!r}")
        if stack_noise not in STACK_NOISE:
            raise InputError(f"stack_noise must be one of {STACK_NOISE}, got {stack_noise!r}")
        #: The noise map of a stack baseline (see ``stack_noise``).
        self.stack_noise = stack_noise
        #: How G treats the energy the threshold clips from the spots' tails (see ``tail``).
        self.tail = tail
        self._run_with(kernel, threads)
        self.sensor, self.camera, self.method = sensor, camera, method
        self.filter, self.filter_size = filter, filter_size
        self.noise_sigma = positive(noise_sigma, "noise_sigma", allow_zero=True)
        self.k = positive(k, "k", allow_zero=True)
        self.min_pixels = positive(min_pixels, "min_pixels", allow_zero=True)
        self.saturation = None if saturation is None else positive(saturation, "saturation")
        self.bits = None if bits is None else check_bit_depth(bits, "bits")
        self.readings_bits = None if readings_bits is None else check_bit_depth(readings_bits, "readings_bits")
        #: Grey levels of the frames per grey level of the readings (1 unless ``bits`` and
        #: ``readings_bits`` differ): thresholds and the noise floor are in the frames' levels,
        #: the readings' G is divided by it.
        self.dn_ratio = 1.0 if self.bits is None or self.readings_bits is None \
            else dn_ratio(self.bits, self.readings_bits)
        self._frame_saturation = None if self.saturation is None else self.saturation * self.dn_ratio
        # A separable Gaussian k (x) k scales white noise by its L2 norm, sum(k**2), and
        # correlates it over 1 / sum(k**2)**2 pixels (4 pi sigma^2).
        gain = float(np.sum(gaussian_kernel(filter_size) ** 2)) if filter == "gaussian" else 1.0
        #: Grey level (of ``frame - baseline``, after the filter) at or below which a pixel is
        #: dark: ``k * noise_sigma`` (times the filter's noise gain); see ``threshold_map``.
        self.threshold = self.k * self.noise_sigma * self.dn_ratio * gain
        if not math.isfinite(self.threshold):
            raise InputError(f"k * noise_sigma must be finite, got k={self.k!r}, "
                             f"noise_sigma={self.noise_sigma!r}")
        self._baseline_input = baseline
        #: dtype of the baseline as given (frames of another integer dtype are refused).
        self.baseline_dtype = None
        self._one_frame = False
        self._impulses = None
        self._noise_dof = math.inf
        self._baseline_frames = 0
        self.baseline, self.noise_map = (None, None) if baseline is None \
            else self._check_baseline(baseline)
        #: Per-pixel threshold (H, W) when there is a baseline whose noise could be measured:
        #: ``max(threshold, threshold_sigmas(k, dof) * noise_map * gain)``, ``dof`` the degrees of
        #: freedom of the noise map (infinite for one frame's; see
        #: :func:`~optitact.pipeline.imageops.noise_from_stack`); None otherwise.
        if self.noise_map is None:
            self.threshold_map = None
        else:
            sigmas = threshold_sigmas(self.k, self._noise_dof)
            with np.errstate(over="ignore"):
                self.threshold_map = np.maximum(self.threshold, sigmas * self.noise_map * gain)
            if not np.isfinite(self.threshold_map).all():
                raise InputError(f"k * the baseline's noise must be finite, got k={self.k!r} and a "
                                 f"noise of up to {self.noise_map.max():g} grey levels")
            if self._one_frame and not np.any(self.threshold_map > self.threshold):
                self.threshold_map = None  # the estimate raises no pixel: one threshold everywhere
        self._geometry = dict(radius=radius, grid_mm=grid_mm)  # as given: replace() hits the cache
        #: Per-(element, pixel) weights of the regions (:func:`~optitact.pipeline.regions.region_weights`),
        #: cached on disk by :func:`~optitact.pipeline.regions.fold_regions`.
        self.region_weights = fold_regions(sensor, camera, radius=radius, grid_mm=grid_mm)
        #: The region grids (:func:`~optitact.pipeline.regions.split_regions`); their arrays are built on
        #: first use (the reference method), never by the fast method.
        self.grids = deferred_grids(sensor, camera, self.region_weights.radius, self.region_weights.grid_mm)
        #: Per-region noise floor of G (grey level x mm^2).
        # Gaussian noise alone lights n Q(k) of a region's n independent samples on average (at
        # most: threshold_sigmas keeps a measured noise map's rate at Q(k)): the floor adds that
        # count and 3 of its (Poisson) standard deviations. Isolated bright pixels (fireflies,
        # flickering hot pixels) come on top, at other places in every frame, for a baseline of
        # any number of frames (impulse_floor).
        n_false = self.region_weights.n_pixels * gain**2 * 0.5 * math.erfc(self.k / math.sqrt(2.0))
        samples = self.min_pixels + n_false + 3.0 * np.sqrt(n_false)
        fold = self.region_weights
        impulse_g = (np.zeros(len(fold.n_pixels)) if self._impulses is None or not self._impulses[0].any()
                     else impulse_floor(self._impulses, fold, frames=self._baseline_frames))
        #: Threshold (grey levels) of each entry of :attr:`region_weights`.
        if self.threshold_map is None:
            self.entry_threshold = np.full(len(fold.pixel), self.threshold)
        else:
            self.entry_threshold = self.threshold_map.reshape(-1)[fold.pixel]
        region_thr = np.bincount(fold.label, self.entry_threshold, minlength=len(fold.n_pixels))
        region_thr = np.divide(region_thr, fold.n_pixels, out=np.zeros(len(fold.n_pixels)),
                               where=fold.n_pixels > 0)
        with np.errstate(over="ignore"):
            self.floor = samples / gain**2 * region_thr * fold.pixel_area + impulse_g
        if not np.isfinite(self.floor).all():
            raise InputError(f"the noise floor of G overflows float64 for min_pixels={self.min_pixels!r}, "
                             f"k={self.k!r}, noise_sigma={self.noise_sigma!r} and this baseline")
        #: Baseline value (grey levels) of each entry of :attr:`region_weights`.
        self.entry_baseline = (np.zeros(len(self.region_weights.pixel)) if self.baseline is None
                              else self.baseline.reshape(-1)[self.region_weights.pixel])
        #: The fast method (:class:`~optitact.pipeline.fastpath.FastPath`): made from the folded
        #: weights, the entries' baselines and thresholds and the floor above; it keeps the per-dtype
        #: precompute (lit levels, the compiled kernel's arguments).
        self.fast_path = FastPath(fold, n_elements=self.grids.n_elements, frame_shape=camera.shape,
                                  entry_baseline=self.entry_baseline, entry_threshold=self.entry_threshold,
                                  floor=self.floor, saturation=self._frame_saturation, tail=self.tail,
                                  filter=self.filter, filter_size=self.filter_size, baseline=self.baseline)

    # ------------------------------------------------------------------ set-up
    def _run_with(self, kernel: str, threads: int | None) -> None:
        """Set how the pipeline runs (``kernel`` and ``threads``: they change no reading)."""
        if kernel not in _kernel.KERNELS:
            raise InputError(f"kernel must be one of {_kernel.KERNELS}, got {kernel!r}")
        #: The ``kernel`` option as given (``"auto"``, ``"numba"`` or ``"numpy"``); :attr:`kernel` is
        #: the one that runs.
        self.requested_kernel = kernel
        #: The fast method's kernel that runs: ``"numba"`` (compiled, the ``fast`` extra) or
        #: ``"numpy"`` (the fallback; also what runs after a filter).
        self.kernel = _kernel.resolve(kernel)
        #: The ``threads`` option as given (None: every core, see :meth:`threads_for`).
        self.requested_threads = threads
        #: Most threads a (T, H, W) batch is split across (default: the cores this process may use).
        self.threads = _cores() if threads is None else integer(threads, "threads", minimum=1)

    def _check_baseline(self, baseline) -> tuple[np.ndarray, np.ndarray | None]:
        """The baseline's mean and its per-pixel noise (grey levels of ``frame - baseline``).

        From two frames on, the noise map is the stack's temporal noise of a
        new frame minus the mean, pooled over a few pixels
        (:func:`~optitact.pipeline.imageops.noise_from_stack`); its degrees of freedom
        set how many of its sigmas the threshold is
        (:func:`threshold_sigmas`), so that a stack of any length lets
        through the false-alarm rate of ``k`` sigmas. One frame holds no
        temporal noise: :func:`noise_from_one_frame` estimates it from the
        frame's spatial fluctuations, as a function of its grey level (None,
        with a warning, when it cannot tell). Either way the baseline's
        isolated bright pixels that come and go are kept for the noise floor
        (:func:`~optitact.pipeline.baseline.baseline_noise`).
        """
        stack, _ = check_frames(baseline, self.camera, "baseline")
        self.check_scale(stack, "baseline")
        self.baseline_dtype = stack.dtype
        frames = stack.astype(np.float64)
        b = stack_mean(frames)
        b.flags.writeable = False
        self._one_frame = len(frames) < 2
        self._baseline_frames = len(frames)
        # a stack's variance needs float64 (its impulses are the same to the bit); one integer frame
        # takes the exact integer arithmetic, faster
        measured = baseline_noise(stack if self._one_frame else frames, stack_noise=self.stack_noise,
                                  stacklevel=5)
        self._noise_dof = measured.dof
        #: (rate, height) of its isolated bright pixels (see :func:`~optitact.pipeline.baseline.impulse_floor`).
        self._impulses = (measured.rate, measured.height)
        noise = measured.noise
        if noise is not None:
            noise.flags.writeable = False
        return b, noise

    def options(self) -> dict:
        """The keyword options this pipeline was made with (the region geometry as given), baseline aside.

        ``Pipeline(sensor, camera, baseline=..., **pipe.options())`` makes the same pipeline;
        :meth:`replace` and a calibration's stored pipeline options start from it.
        """
        return dict(method=self.method, filter=self.filter, filter_size=self.filter_size,
                    noise_sigma=self.noise_sigma, k=self.k, min_pixels=self.min_pixels,
                    saturation=self.saturation, bits=self.bits, readings_bits=self.readings_bits,
                    kernel=self.requested_kernel, threads=self.requested_threads, tail=self.tail,
                    stack_noise=self.stack_noise, **self._geometry)

    def check_scale(self, stack: np.ndarray, name: str = "frames") -> None:
        """Refuse integer frames that are not of the pipeline's bit depth or of the baseline's dtype.

        Float frames are taken to be in the frames' grey levels as they are.
        :meth:`process` checks its frames so; a function that reads frames
        with the pipeline's thresholds without processing them calls it.

        Parameters
        ----------
        stack : (T, H, W) ndarray
            The frames (as :func:`check_frames` returns them).
        name : str
            What they are called in the error message.

        Raises
        ------
        InputError
            Integer frames of another dtype than the baseline, or not of the
            pipeline's bit depth (see ``bits`` and ``readings_bits``), or
            with a value above its full scale.
        """
        if stack.dtype.kind not in "ui":
            return
        if self.baseline_dtype is not None and self.baseline_dtype.kind in "ui" \
                and stack.dtype != self.baseline_dtype:
            raise InputError(f"{name}: dtype {stack.dtype}, but the baseline's is {self.baseline_dtype}: a "
                             f"baseline and frames of different bit depths cannot be subtracted; "
                             f"record them at one depth")
        depth = self.bits if self.bits is not None else self.readings_bits
        if depth is None:
            return
        top = 2**depth - 1
        if self.bits is None:  # implied by the readings' scale: the dtype must be the one that holds it
            natural = np.dtype(np.uint8 if depth <= 8 else np.uint16)
            if stack.dtype.itemsize != natural.itemsize:
                raise InputError(
                    f"{name}: dtype {stack.dtype} (up to {8 * stack.dtype.itemsize}-bit grey levels), but "
                    f"this pipeline reads {depth}-bit frames (full scale {top}), e.g. a calibration's "
                    f"scale; state the frames' bit depth (bits=..., --bits N: 16 for 16-bit data, 12 "
                    f"for 12-bit data in 16-bit files) so that they are mapped exactly or refused")
        elif np.iinfo(stack.dtype).max < top:
            raise InputError(f"{name}: dtype {stack.dtype} cannot hold the stated {depth}-bit grey "
                             f"levels (full scale {top})")
        if np.iinfo(stack.dtype).max > top and stack.size and stack.max() > top:
            t, r, c = (int(i) for i in np.argwhere(stack > top)[0])
            raise InputError(f"{name}: {stack[t, r, c]} at frame {t}, pixel (row {r}, col {c}) is "
                             f"above the full scale {top} of {depth}-bit grey levels; state the "
                             f"frames' real bit depth")

    def replace(self, **changes) -> Pipeline:
        """A pipeline with some options changed (the geometry is shared when unchanged).

        A new ``filter`` without a ``filter_size`` takes that filter's default size.
        Changing only :data:`RUN_OPTIONS` (how it runs, not what it reads) copies the
        pipeline as it is: no baseline statistics or thresholds are made again.
        """
        if changes and changes.keys() <= RUN_OPTIONS:  # the same readings: nothing to make again
            out = copy.copy(self)
            out.fast_path = self.fast_path.copy()  # its caches its own
            out._run_with(changes.get("kernel", self.requested_kernel),
                          changes.get("threads", self.requested_threads))
            return out
        opts = self.options() | {"baseline": self._baseline_input} | changes
        if "filter" in changes and "filter_size" not in changes:
            opts["filter_size"] = None
        out = Pipeline(self.sensor, self.camera, **opts)
        if out.region_weights is self.region_weights:
            out.grids = self.grids  # the same geometry: built at most once
        return out

    @property
    def baseline_frames(self) -> int:
        """Frames averaged into the baseline's mean (0 without one): its noise is a frame's over their root."""
        return self._baseline_frames

    def with_baseline(self, frames) -> Pipeline:
        """The same pipeline with ``frames`` (a frame or the mean of a stack) as no-load baseline."""
        return self.replace(baseline=frames)

    def with_baseline_mean(self, mean) -> Pipeline:
        """The same pipeline subtracting another no-load mean; its noise map, thresholds and floor kept.

        For a baseline that drifts slowly (the rim light, the black level, a
        sub-pixel camera creep; :class:`optitact.pipeline.drift.DriftTracker`):
        only the mean that is subtracted changes, so the swap costs one small
        copy (no noise statistics made again) and frames keep the original
        baseline's dtype check. :meth:`replace` and :meth:`with_baseline`
        start again from the baseline as first given.

        Parameters
        ----------
        mean : (H, W) array_like
            The no-load mean in the frames' grey levels, finite.

        Returns
        -------
        Pipeline

        Raises
        ------
        InputError
            This pipeline has no baseline, or ``mean`` is not finite.
        ShapeError
            ``mean`` is not of the camera's ``(H, W)``.
        """
        if self.baseline is None:
            raise InputError("this pipeline has no baseline whose mean could be replaced; give one "
                             "(with_baseline) first")
        b = np.array(mean, dtype=np.float64)
        if b.shape != self.camera.shape:
            raise ShapeError(f"mean must have the camera's shape {self.camera.shape}, got {b.shape}")
        if not np.isfinite(b).all():
            raise InputError("mean must be finite")
        b.flags.writeable = False
        out = copy.copy(self)
        out.baseline = b
        out.entry_baseline = b.reshape(-1)[self.region_weights.pixel]
        out.fast_path = FastPath(self.region_weights, n_elements=self.grids.n_elements,
                                 frame_shape=self.camera.shape, entry_baseline=out.entry_baseline,
                                 entry_threshold=self.entry_threshold, floor=self.floor,
                                 saturation=self._frame_saturation, tail=self.tail, filter=self.filter,
                                 filter_size=self.filter_size, baseline=b)
        return out

    @classmethod
    def from_noload(cls, sensor: DomeSensor, camera: Camera, frames, **options) -> Pipeline:
        """A pipeline whose baseline and noise come from a no-load stack ``(T, H, W)``, T >= 2.

        The baseline is the stack's mean; ``noise_sigma`` is
        ``estimate_noise(frames) * sqrt(1 + 1/T)``, the noise of a frame minus
        that mean.
        """
        stack, _ = check_frames(frames, camera, "frames")
        sigma = estimate_noise(stack) * math.sqrt(1.0 + 1.0 / stack.shape[0])
        if options.get("bits") is not None and options.get("readings_bits") is not None:
            # noise_sigma is in the readings' grey levels
            sigma /= dn_ratio(options["bits"], options["readings_bits"])
        return cls(sensor, camera, baseline=stack, noise_sigma=sigma, **options)

    # ------------------------------------------------------------------ processing
    def process(self, frames) -> Readings:
        """Readings of a frame ``(H, W)`` or of every frame of a stack ``(T, H, W)``.

        Raises
        ------
        TypeError, ShapeError, InputError
            See :func:`check_frames`; also (InputError) integer frames of
            another dtype than the baseline, or not of the pipeline's bit
            depth (see ``bits`` and ``readings_bits``).
        """
        stack, single = check_frames(frames, self.camera)
        self.check_scale(stack, "frames")
        out = self._process(stack, single)
        if self.dn_ratio != 1.0:
            out = Readings(out.G / self.dn_ratio, out.u, out.contact, out.saturated)
        return out

    def _process(self, stack: np.ndarray, single: bool) -> Readings:
        if self.method == "reference":
            out = Readings.stack([self._reference(f) for f in stack])
        elif self.kernel == "numba" and self.filter == "none":
            return self.fast_path.process_compiled(stack, single, 1 if single else self.threads_for(len(stack)))
        elif single:
            return self.fast_path.process_numpy(stack, single=True)
        else:
            return self.fast_path.process_numpy_chunks(stack, self.threads_for(len(stack)))
        return out[0] if single else out

    def threads_for(self, n_frames: int) -> int:
        """Threads a stack of ``n_frames`` frames is split across (see ``threads``)."""
        return thread_count(self.requested_threads, self.threads, n_frames)

    def lit_levels(self, dtype) -> np.ndarray:
        """The grey level above which a frame of ``dtype`` lights each entry of :attr:`region_weights`.

        For integer frames an entry is lit exactly when ``frame > level``
        (``frame - baseline > threshold`` in float64, as the reference tests
        it); for float frames ``frame > level`` picks the candidates, and that
        test decides among them. See :meth:`.FastPath.levels`.

        Parameters
        ----------
        dtype : numpy.dtype
            The frames' dtype.

        Returns
        -------
        (n_entries,) ndarray of ``dtype``
            Kept per dtype: not to be written to.
        """
        return self.fast_path.levels(np.dtype(dtype)).level

    def stream(self, frames, *, baseline_frames: int = 0):
        """Yield readings frame by frame from an iterable of frames.

        Parameters
        ----------
        frames : iterable of (H, W) arrays
        baseline_frames : int
            When > 0, the mean of the first ``baseline_frames`` frames becomes
            the no-load baseline; readings are yielded for every frame,
            those first ones included.
        """
        baseline, head, rest = take_baseline(frames, baseline_frames)
        pipe = self
        if baseline is not None:
            pipe = self.with_baseline(baseline)
            yield from pipe.process(baseline)
        for frame in rest:
            yield pipe.process(frame)

    # ------------------------------------------------------------------ the two methods
    def _reference(self, frame: np.ndarray) -> Readings:
        img = subtract_baseline(frame, self.baseline, clip=self.filter == "none")
        img = denoise(img, method=self.filter, size=self.filter_size)
        thr = self.threshold if self.threshold_map is None else self.threshold_map
        img = apply_threshold(img, thr)
        g, _ = integrate(dewarp(img, self.grids), self.grids)
        # the centroid weighs each lit value by its height above the threshold
        w, m = integrate(dewarp(np.where(img > thr, img - thr, 0.0), self.grids), self.grids)
        level = saturation_level(frame.dtype, self._frame_saturation)
        hot = dewarp((frame >= level).astype(np.float64), self.grids)
        out = readings_from_moments(g, m, (hot > 0).any(axis=(1, 2)), self.floor, weight=w)
        return add_clipped_tail(out, w) if self.tail == "gaussian" else out


def _check_filter_fits(method: str, size: float, camera: Camera) -> None:
    """InputError when the filter's window (3 sigma each side of a gaussian) is wider than the frames."""
    if method == "none":
        return
    side = min(camera.shape)
    # a sigma wider than the frame is refused before its kernel is made
    window = size if method == "median" or size > side else 2 * filter_radius(method, size) + 1
    if window > side:
        raise InputError(f"filter_size={size:g}: the {method} filter reads {window:g} px across, wider than "
                         f"the {camera.width}x{camera.height} frames' shorter side ({side} px); about 1 px "
                         f"(gaussian sigma) or 3 px (median window) smooths pixel noise")
