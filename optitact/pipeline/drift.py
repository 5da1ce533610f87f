"""Slow drift of the no-load image tracked over long runs, and readings corrected for it.

A pipeline subtracts a fixed no-load baseline ``B0``. Over an hour a real
sensor's no-load image moves away from it: the rim light (LEDs) dims or
brightens with temperature, the camera's black level steps, the camera mount
creeps a fraction of a pixel against the dome, and the light reaching one
element can change locally. Read against ``B0`` each of these reads as force.
:class:`DriftTracker` follows them frame by frame and corrects the readings:

* the global model of a frame, ``I(p) = gain * B0(p - shift) + offset +
  spots``, is estimated every ``every`` seconds from pixels away from the
  element regions only (a press changes only its element's region): the
  dark level from the dark background, the gain as the ratio of the lit
  rim's summed light now and in ``B0`` (a sum over the whole rim keeps its
  light whatever interpolation does to a sharp rim, and the baseline's
  noise enters it without bias), the sub-pixel shift by phase correlation
  (OpenCV's ``cv2.phaseCorrelate`` on a 160 x 120 copy: the coarse step and
  the match quality) refined by Gauss-Newton on the rim's gradient (Lanczos
  samples); the estimates are smoothed over ``smooth`` seconds, steps taken
  at once;
* per element, while it holds no spot (no pixel far above its level) and
  has not read a press for ``holdoff`` seconds, a slow residual offset of its
  region (a local change of light), followed with a long time constant and a
  rate limit;
* the correction swaps the predicted no-load image
  ``B' = dark + gain (B0(p - shift) - dark0) + element offsets`` in for the
  baseline mean (:meth:`~optitact.pipeline.frame_pipeline.Pipeline.with_baseline_mean`:
  noise map and thresholds kept, integer frames stay integer), divides G by
  the gain (the spots are lit by the same rim light) and takes the shift's
  image in mm off the centroids of the elements in contact. Until the model
  can be told from no drift, frames go through the plain pipeline
  (bit-identical readings, no cost).

Changes beyond what tracking can follow raise :attr:`DriftState.flag` with a
:attr:`DriftState.reason`; the model then holds its last accepted
parameters until the frames agree with a model within the limits again. See
``docs/models/drift.md`` for the model, its parameters and the simulated
hour that measures it (``optitact bench drift``).

Convention
----------
Images are ``(row, col)`` with the origin at the top-left pixel centre; grey
levels are the frames' own (DN of the frames, before a ``bits`` mapping); the
shift is ``(shift_x, shift_y)`` = (columns, rows) in pixels, the motion of the
image content (a dome point seen at pixel ``p`` in the baseline is seen at
``p + shift`` now).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import cv2
import numpy as np

from optitact._validate import check_type, positive
from optitact.errors import InputError, ShapeError
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.imageops import check_frames, saturation_level
from optitact.pipeline.readings import Readings

__all__ = ["DriftState", "DriftTracker"]

#: Pixels at the frame's border left out of the fits (warps read beyond them).
BORDER_PX = 3
#: Gaussian sigma (px) of the smoothed baseline that picks the lit rim, and the margin (px) it is widened by.
SMOOTH_PX, RIM_MARGIN = 2.0, 1
#: At most this many pixels of the lit rim and of the dark background go into a fit.
MAX_FIT_PIXELS = 16384
#: Pixels (at most) of each element's region its residual offset is read from, and the steps that find it.
ELEMENT_PIXELS, ELEMENT_STEPS = 256, 6
#: A region with more than SPOT_PIXELS of its read pixels SPOT_SIGMAS noise sigmas above its level holds a spot.
SPOT_SIGMAS, SPOT_PIXELS = 4.0, 3
#: Pixels (at most) of the dark background and the lit rim the per-frame step check reads.
SENTINEL_PIXELS = 1024
#: Seed of the noise that sets the expected phase-correlation peak (deterministic).
PEAK_SEED = 20240611
#: Changes of the dark level (grey levels), the gain and the shift (px) corrected on the frame that shows them;
#: smaller ones (a slow drift's next step) on the next frame.
STEP_DARK, STEP_GAIN, STEP_SHIFT = 0.25, 0.01, 0.1
#: The coarse phase correlation (about 0.3 px rms on 160 x 120) restarts the fit when this far (px) from it.
COARSE_JUMP_PX = 1.0
#: Most Gauss-Newton steps of the shift, and the step (px) after which they stop (about one estimate's noise).
SHIFT_ITERATIONS, SHIFT_CONVERGED = 4, 0.02
#: Largest fraction of the dark background off the model by more than 6 sigmas (hot pixels, fireflies).
MAX_OUTLIERS = 0.01
#: Largest single-estimate standard error of the gain (relative) and the shift (px) that is tracked.
GAIN_OBSERVABLE, SHIFT_OBSERVABLE = 0.05, 0.2


@dataclass(frozen=True, eq=False)
class DriftState:
    """The tracker's model after a frame (:meth:`DriftTracker.process`).

    The frame is modelled as ``gain * B0(p - shift) + offset`` plus the
    spots, ``B0`` the pipeline's no-load baseline; these are the parameters
    the frame's readings were corrected with.

    Attributes
    ----------
    gain : float
        Brightness of the no-load light relative to the baseline's (the rim
        light); G is divided by it.
    offset : float
        Grey levels added to every pixel (``dark - gain * dark0``: a black
        level change, and the gain's share of the dark level).
    shift_x, shift_y : float
        Motion of the image against the dome, pixels (columns, rows).
    tracking : bool
        The tracker follows the drift: its last estimate was accepted. False
        while the flag is up (the model holds) and before the first estimate.
    flag : bool
        The change exceeds what tracking can follow (:attr:`reason`): take a
        new baseline with the sensor unloaded.
    reason : str
        Why the flag is up ("" when it is not).
    corrected : bool
        This frame's readings were corrected (the model is not the identity).
    estimated : bool
        The drift was estimated on this frame.
    time : float
        The frame's time, seconds (given, or frame index / ``fps``).
    frame : int
        Frames processed before this one.
    dark : float
        The dark level of the background now (grey levels).
    peak : float
        Phase-correlation peak of the last estimate relative to the one a
        noisy copy of the baseline gives (about 1 when the rim matches; NaN
        when the shift is not tracked).
    residual : float
        RMS residual of the last global fit in noise sigmas (about 1 when the
        model explains the background).
    element_offset : (E,) ndarray
        Each element's residual offset, grey levels (read-only).
    """

    gain: float = 1.0
    offset: float = 0.0
    shift_x: float = 0.0
    shift_y: float = 0.0
    tracking: bool = False
    flag: bool = False
    reason: str = ""
    corrected: bool = False
    estimated: bool = False
    time: float = 0.0
    frame: int = 0
    dark: float = float("nan")
    peak: float = float("nan")
    residual: float = float("nan")
    element_offset: np.ndarray = field(default_factory=lambda: np.zeros(0))

    def as_dict(self) -> dict:
        """The state as JSON-ready Python values."""
        out = {k: getattr(self, k) for k in ("gain", "offset", "shift_x", "shift_y", "tracking", "flag",
                                             "reason", "corrected", "estimated", "time", "frame", "dark",
                                             "peak", "residual")}
        out = {k: (v if isinstance(v, (str, bool)) else (int(v) if k == "frame" else float(v)))
               for k, v in out.items()}
        out["element_offset"] = [float(v) for v in self.element_offset]
        return out


class _Smoothed:
    """One tracked parameter: exponential smoothing that takes a significant step at once.

    A step is an estimate beyond ``jump`` standard errors of the smoothed value; with ``confirm``,
    two such estimates in a row on the same side (then their mean is taken).
    """

    def __init__(self, value: float, confirm: bool = False) -> None:
        self.value, self.confirm, self._pending = value, confirm, None

    def update(self, estimate: float, se: float, alpha: float, jump: float) -> None:
        if abs(estimate - self.value) > jump * se:
            side = estimate > self.value
            if not self.confirm:
                self.value, self._pending = estimate, None
                return
            if self._pending is not None and self._pending[0] == side:
                self.value, self._pending = 0.5 * (estimate + self._pending[1]), None
                return
            self._pending = (side, estimate)
        else:
            self._pending = None
        self.value += alpha * (estimate - self.value)


class DriftTracker:
    """Track slow drift of a pipeline's no-load image and correct each frame's readings for it.

    Parameters
    ----------
    pipeline : Pipeline
        With a no-load baseline (the reference ``B0``); its options stay as they are.
    fps : float
        Frame rate used for the frames' times when :meth:`process` is given none (default 60).
    every : float
        Seconds between drift estimates (default 1; 0: every frame). A per-frame
        check of the dark level and of the rim brightness (about 10 us) brings
        the next estimate forward when they step.
    smooth : float
        Time constant (s) of the smoothing of the global parameters (default
        60): drift is slow, and the estimate of one frame is noisy (the gain
        of a faint rim to about 1 %). A change larger than ``jump`` of one
        estimate's standard errors is taken at once (a black-level step).
    jump : float
        See ``smooth`` (default 6).
    element_tau : float
        Time constant (s) of each element's residual offset (default 120): with
        about 256 of its pixels read per estimate, its noise is then a few
        thousandths of a grey level.
    element_rate : float
        Most an element's residual offset changes, grey levels per minute
        (default 0.2): a press ramped over minutes or held long is not
        absorbed (it is not followed at all while the element reads contact).
    holdoff : float
        Seconds after an element last read contact before its offset is
        followed again (default 10).
    gain_tolerance, offset_tolerance, shift_tolerance, element_tolerance : float
        Changes of the gain (relative, default 0.002), the dark level (grey
        levels, default 0.03), the shift (px, default 0.01) and an element's
        offset (grey levels, default 0.03) below which the correction is not
        redone. The model leaves no drift only when a parameter is beyond its
        tolerance and beyond ``significance`` of its standard error at no
        drift (the baseline's own noise and the smoothed estimate's: what
        cannot be told from noise is not corrected, so that with no drift the
        readings are the plain pipeline's); from then on every parameter beyond its tolerance is
        applied, until it is back within it.
    max_gain : float
        Flag a gain beyond ``1 +- max_gain`` (default 0.2).
    max_shift : float
        Flag a shift beyond this many pixels (default 2).
    min_peak : float
        Flag a phase-correlation peak below this fraction of the one a noisy
        copy of the baseline gives (default 0.3): the rim no longer looks like
        the baseline's.
    max_residual : float
        Flag a global fit whose RMS residual is beyond this many noise sigmas
        (default 4): something besides the drift model changed outside the
        elements (a light leak, an object in view).
    max_element_offset : float
        Flag an element whose residual offset reaches this many grey levels
        (default: half the pipeline's threshold); it is held there.
    margin : int
        Pixels (default 3) by which the element regions are widened before the
        background is taken from the rest.
    significance : float
        See the tolerances (default 4: over an hour of smoothed estimates, 3 would be crossed by noise now
        and then).

    Attributes
    ----------
    pipeline : Pipeline
        The pipeline as given (its baseline is the reference ``B0``).
    tracks_gain, tracks_shift : bool
        Whether the baseline has a lit rim (outside the element regions)
        bright enough for the gain, and structure enough for the shift
        (otherwise the dark level and the elements' offsets only).
    corrections : int
        How many times the correction was redone (a new predicted baseline
        swapped in).

    Raises
    ------
    TypeError
        ``pipeline`` is not a :class:`Pipeline`.
    InputError
        The pipeline has no baseline, or an option is out of range.

    Notes
    -----
    Cost: a frame that is not estimated costs the pipeline's own processing,
    plus the step check; one that is estimated costs a phase correlation, a
    few Gauss-Newton steps on the lit rim and the per-element residuals
    (a few ms at 640 x 480). Redoing the correction (when the model moved
    beyond a tolerance) costs a warp of the baseline and the pipeline's
    per-dtype precompute, a few ms.

    Examples
    --------
    >>> import numpy as np
    >>> from optitact.optics.camera import FisheyeCamera
    >>> from optitact.optics.sensor import DomeSensor
    >>> cam = FisheyeCamera(width=160, height=120)
    >>> noload = np.full(cam.shape, 4, np.uint8)
    >>> tracker = DriftTracker(Pipeline(DomeSensor.default(), cam, baseline=noload))
    >>> readings, state = tracker.process(noload)
    >>> state.gain, state.flag, state.corrected
    (1.0, False, False)
    """

    def __init__(self, pipeline: Pipeline, *, fps: float = 60.0, every: float = 1.0, smooth: float = 60.0,
                 jump: float = 6.0, element_tau: float = 120.0, element_rate: float = 0.2,
                 holdoff: float = 10.0, gain_tolerance: float = 0.002, offset_tolerance: float = 0.03,
                 shift_tolerance: float = 0.01, element_tolerance: float = 0.03, max_gain: float = 0.2,
                 max_shift: float = 2.0, min_peak: float = 0.3, max_residual: float = 4.0,
                 max_element_offset: float | None = None, margin: int = 3, significance: float = 4.0) -> None:
        check_type(pipeline, Pipeline, "pipeline")
        if pipeline.baseline is None:
            raise InputError("drift tracking needs a pipeline with a no-load baseline (with_baseline)")
        self.pipeline = pipeline
        self.fps = positive(fps, "fps")
        self.every = positive(every, "every", allow_zero=True)
        self.smooth = positive(smooth, "smooth", allow_zero=True)
        self.jump = positive(jump, "jump")
        self.element_tau = positive(element_tau, "element_tau")
        self.element_rate = positive(element_rate, "element_rate", allow_zero=True)
        self.holdoff = positive(holdoff, "holdoff", allow_zero=True)
        self.gain_tolerance = positive(gain_tolerance, "gain_tolerance", allow_zero=True)
        self.offset_tolerance = positive(offset_tolerance, "offset_tolerance", allow_zero=True)
        self.shift_tolerance = positive(shift_tolerance, "shift_tolerance", allow_zero=True)
        self.element_tolerance = positive(element_tolerance, "element_tolerance", allow_zero=True)
        self.max_gain = positive(max_gain, "max_gain")
        self.max_shift = positive(max_shift, "max_shift")
        self.min_peak = positive(min_peak, "min_peak", allow_zero=True)
        self.max_residual = positive(max_residual, "max_residual")
        self.significance = positive(significance, "significance", allow_zero=True)
        if isinstance(margin, bool) or not isinstance(margin, (int, np.integer)) or margin < 0:
            raise InputError(f"margin must be a non-negative integer (px), got {margin!r}")
        self.margin = int(margin)
        thr = (float(np.median(pipeline.entry_threshold)) if len(pipeline.entry_threshold)
               else pipeline.threshold)
        self.max_element_offset = (0.5 * thr if max_element_offset is None
                                   else positive(max_element_offset, "max_element_offset"))
        self._prepare()
        self._g = _Smoothed(1.0, confirm=True)
        self._dark = _Smoothed(self._dark0)
        self._sx, self._sy = _Smoothed(0.0, confirm=True), _Smoothed(0.0, confirm=True)
        self._engaged = {"gain": False, "dark": False, "shift": False}
        self._ema_se = {"gain": 0.0, "dark": 0.0, "shift": 0.0}
        n_el = self._n_el
        self._element = np.zeros(n_el)
        self._last_contact = np.full(n_el, -math.inf)
        self._light_only = np.zeros(n_el, bool)  # in contact by a change of light (not a spot)
        self._applied = (1.0, self._dark0, 0.0, 0.0, np.zeros(n_el))
        self._pipe = pipeline
        self._pending = None  # a model to put in use at the next frame
        self.corrections = 0
        self._frames = 0
        self._t_last = None
        self._t_est = None
        self._flag, self._reason, self._tracking = False, "", False
        self._peak, self._residual, self._outliers = math.nan, math.nan, 0.0
        self._state = DriftState(dark=self._dark0, element_offset=self._frozen(self._element))

    # ------------------------------------------------------------------ set-up
    def _prepare(self) -> None:
        """The pixel sets, weights and references the estimates read (once)."""
        pipe = self.pipeline
        b0 = np.asarray(pipe.baseline, dtype=np.float64)
        h, w = b0.shape
        fold = pipe.region_weights
        self._n_el = int(pipe.grids.n_elements)
        region = np.zeros(h * w, np.uint8)
        region[fold.pixel] = 1
        region = region.reshape(h, w)
        if self.margin:
            k = 2 * self.margin + 1
            region = cv2.dilate(region, np.ones((k, k), np.uint8))
        back = region == 0
        back[:BORDER_PX] = back[-BORDER_PX:] = False
        back[:, :BORDER_PX] = back[:, -BORDER_PX:] = False
        sat_in = None if pipe.saturation is None else pipe.saturation * pipe.dn_ratio
        dtype = pipe.baseline_dtype if pipe.baseline_dtype is not None else np.dtype(np.float64)
        level = saturation_level(dtype, sat_in)
        if math.isfinite(level):
            back &= b0 < 0.8 * level  # room for the light to brighten without saturating
        # noise of a frame and of the baseline's mean (frame grey levels)
        sigma = pipe.noise_sigma * pipe.dn_ratio
        if pipe.noise_map is not None and back.any():
            sigma = max(sigma, float(np.median(pipe.noise_map[back])))
        n_base = max(pipe.baseline_frames, 1)
        if n_base > 1:
            sigma /= math.sqrt(1.0 + 1.0 / n_base)  # the map is the noise of a frame minus the mean
        spread = float(np.percentile(b0, 99.9) - np.percentile(b0, 50.0)) if b0.size else 0.0
        sigma = max(sigma, 1e-3 * spread, 1e-12)
        self._sigma = sigma
        self._sigma_ref = sigma / math.sqrt(n_base)
        self._shape = (h, w)
        dark0 = float(np.median(b0[back])) if back.any() else float(np.median(b0))
        # the lit rim: where the baseline smoothed over SMOOTH_PX is 6 of its noise sigmas above the dark
        # (one frame's: the smoothing passes 1 / (2 sqrt(pi) SMOOTH_PX) of it), widened by RIM_MARGIN px.
        # Its edge runs through dark pixels, chosen by the smoothed light of others: a pixel's own noise
        # hardly decides whether it is in (it would bias the rim's sum, and so the gain, upward).
        lit_img = cv2.GaussianBlur((b0 - dark0).astype(np.float32), (0, 0), SMOOTH_PX)
        lit_dn = 6.0 * sigma / (2.0 * math.sqrt(math.pi) * SMOOTH_PX)
        core = back & (lit_img > lit_dn)
        k = 2 * RIM_MARGIN + 1
        bright = cv2.dilate(core.astype(np.uint8), np.ones((k, k), np.uint8)).astype(bool) & back
        dark = back & ~cv2.dilate(bright.astype(np.uint8), np.ones((3, 3), np.uint8)).astype(bool)
        dark &= np.abs(b0 - dark0) <= 6.0 * sigma + 0.5  # no hot pixels of the baseline
        dr, dc = _spread(np.nonzero(dark), MAX_FIT_PIXELS)
        br, bc = _spread(np.nonzero(bright), MAX_FIT_PIXELS)
        self._dark_px = (dr, dc)
        self._dark0 = float(b0[dr, dc].mean()) if len(dr) else dark0
        self._b0c = (b0 - self._dark0).astype(np.float32)  # the baseline above its dark level
        self._bright_px = (br.astype(np.float32), bc.astype(np.float32), br, bc)
        self._gx = (0.5 * cv2.Sobel(self._b0c, cv2.CV_32F, 1, 0, ksize=1)).astype(np.float32)
        self._gy = (0.5 * cv2.Sobel(self._b0c, cv2.CV_32F, 0, 1, ksize=1)).astype(np.float32)
        self._b0_grad = np.ascontiguousarray(np.dstack([self._b0c, self._gx, self._gy]))  # one sampling
        # what one estimate can see: the gain needs lit rim, the shift its gradient too
        bb = self._b0c[br, bc].astype(np.float64)
        denom = float(bb.sum())
        self._se_gain1 = math.inf if denom <= 0 else sigma * math.sqrt(len(bb)) / denom
        self.tracks_gain = len(br) >= 50 and self._se_gain1 <= GAIN_OBSERVABLE
        gx, gy = self._gx[br, bc].astype(np.float64), self._gy[br, bc].astype(np.float64)
        normal = np.array([[gx @ gx, gx @ gy], [gx @ gy, gy @ gy]])
        lo = float(np.linalg.eigvalsh(normal)[0]) if len(br) else 0.0
        self._se_shift1 = math.inf if lo <= 0 else sigma / math.sqrt(lo)
        self.tracks_shift = self.tracks_gain and self._se_shift1 <= SHIFT_OBSERVABLE
        # the baseline's own noise sets what can be told from no drift
        self._ref_se = {"gain": self._se_gain1 * self._sigma_ref / sigma if self.tracks_gain else 0.0,
                        "shift": self._se_shift1 * self._sigma_ref / sigma if self.tracks_shift else 0.0,
                        "dark": self._sigma_ref / math.sqrt(max(len(dr), 1))}
        # the per-frame step check: a few dark and lit pixels
        self._sent_dark = _spread((dr, dc), SENTINEL_PIXELS)
        sbr, sbc = _spread((br, bc), SENTINEL_PIXELS)
        self._sent_bright = (sbr, sbc)
        self._sent_b = float(self._b0c[sbr, sbc].astype(np.float64).sum())
        self._se_sent_gain = math.inf if self._sent_b <= 0 else sigma * math.sqrt(len(sbr)) / self._sent_b
        # phase correlation of the background (regions blanked), downsampled on large frames
        self._pc_scale = max(1, min(h, w) // 120)  # about 160 x 120: a coarse step and the match quality
        self._pc_mask = back.astype(np.float32)
        self._pc_ref = self._pc_image(self._b0c)
        self._peak0 = 1.0
        if self.tracks_shift:
            noise = np.random.default_rng(PEAK_SEED).normal(0.0, sigma, (h, w)).astype(np.float32)
            _, self._peak0 = cv2.phaseCorrelate(self._pc_ref, self._pc_image(self._b0c + noise))
            self._peak0 = max(float(self._peak0), 1e-12)
        # the element regions: up to ELEMENT_PIXELS of each, evenly spread, for its residual offset
        pick = np.concatenate([_evenly(np.flatnonzero(fold.label == e), ELEMENT_PIXELS)
                               for e in range(self._n_el)] or [np.zeros(0, np.intp)]).astype(np.intp)
        self._entry_pick = pick
        self._entry_px = fold.pixel[pick]
        self._entry_el = fold.label[pick]
        self._entry_n = np.bincount(self._entry_el, minlength=self._n_el).astype(np.float64)
        self._entry_all = fold.pixel  # where the element offsets go in the predicted baseline
        self._entry_all_el = fold.label
        self._jacobian = _region_jacobians(fold, w, self._n_el)

    def _pc_image(self, img: np.ndarray) -> np.ndarray:
        """The image phase correlation reads: above the dark level, element regions blanked, downsampled."""
        x = np.asarray(img, np.float32) * self._pc_mask
        if self._pc_scale > 1:
            h, w = x.shape
            x = cv2.resize(x, (w // self._pc_scale, h // self._pc_scale), interpolation=cv2.INTER_AREA)
        return x.astype(np.float64)

    @staticmethod
    def _frozen(a: np.ndarray) -> np.ndarray:
        out = np.array(a, dtype=np.float64)
        out.flags.writeable = False
        return out

    # ------------------------------------------------------------------ public
    @property
    def state(self) -> DriftState:
        """The state after the last frame (:class:`DriftState`)."""
        return self._state

    @property
    def current_pipeline(self) -> Pipeline:
        """The pipeline the last frame was read with (the given one while the model is the identity)."""
        return self._pipe

    def process(self, frame, t: float | None = None) -> tuple[Readings, DriftState]:
        """Readings of one frame corrected for the drift, and the tracker's state.

        Parameters
        ----------
        frame : (H, W) array_like
            One frame, in capture order (integer or float, as the pipeline takes them).
        t : float, optional
            Its capture time in seconds (non-decreasing); default frame index / ``fps``.

        Returns
        -------
        readings : Readings
            As the pipeline's, corrected: G divided by the gain, the centroids
            of the elements in contact less the image of the shift.
        state : DriftState

        Raises
        ------
        ShapeError
            Not one ``(H, W)`` frame of the pipeline's camera.
        InputError
            A time earlier than the last frame's, or what the pipeline refuses.
        """
        arr = np.asarray(frame)
        if arr.ndim != 2:
            raise ShapeError(f"the drift tracker takes one frame (H, W) at a time, got shape {arr.shape}")
        if arr.shape != self._shape:
            raise ShapeError(f"frame must be {self._shape[0]}x{self._shape[1]} (H, W) for this pipeline, "
                             f"got {arr.shape[0]}x{arr.shape[1]}")
        t = self._frames / self.fps if t is None else float(t)
        if not math.isfinite(t) or (self._t_last is not None and t < self._t_last):
            raise InputError(f"frame times must be finite and non-decreasing, got {t!r} after {self._t_last!r}")
        if arr.dtype.kind not in "uif":
            return self._pipe.process(arr), self._state  # the pipeline's own error
        due = self._t_est is None or t - self._t_est >= self.every
        if due or arr.dtype.kind == "f":  # what the estimates read is what the pipeline would take
            stack, _ = check_frames(arr, self.pipeline.camera, "frame")
            self.pipeline.check_scale(stack, "frame")
        if self._pending is not None:
            self._swap(self._pending)
        due = due or self._stepped(arr)
        dt = 0.0 if self._t_est is None else t - self._t_est
        img = None
        if due:
            img = arr.astype(np.float32)
            self._estimate(img, dt)
            self._apply()
        readings = self._read(arr)
        if not due:  # (an estimate tells a spot from a change of light itself, below)
            self._last_contact[np.asarray(readings.contact) & ~self._light_only] = t
        if due:
            self._follow_elements(img, readings, dt, t)
            self._t_est = t
        self._t_last = t
        g, dark, sx, sy, elem = self._applied
        self._state = DriftState(gain=float(g), offset=float(dark - g * self._dark0), shift_x=float(sx),
                                 shift_y=float(sy), tracking=self._tracking, flag=self._flag,
                                 reason=self._reason, corrected=self._pipe is not self.pipeline,
                                 estimated=due, time=t, frame=self._frames, dark=float(self._dark.value),
                                 peak=self._peak, residual=self._residual,
                                 element_offset=self._frozen(elem))
        self._frames += 1
        return readings, self._state

    # ------------------------------------------------------------------ per frame
    def _stepped(self, arr: np.ndarray) -> bool:
        """Whether the dark level or the rim light stepped since the last estimate (a few pixels read)."""
        dr, dc = self._sent_dark
        if not len(dr):
            return False
        d = float(arr[dr, dc].mean(dtype=np.float64))
        if abs(d - self._dark.value) > max(0.25, 6.0 * self._sigma / math.sqrt(len(dr))):
            return True
        if self.tracks_gain and self._sent_b > 0:
            br, bc = self._sent_bright
            g = float((arr[br, bc].astype(np.float64) - d).sum()) / self._sent_b
            if abs(g - self._g.value) > max(0.03, 6.0 * self._se_sent_gain):
                return True
        return False

    def _read(self, arr: np.ndarray) -> Readings:
        """The frame read by the pipeline in use, G and centroids corrected for the applied model."""
        r = self._pipe.process(arr)
        if self._pipe is self.pipeline:
            return r
        g, _, sx, sy, _ = self._applied
        G = r.G / g if g != 1.0 else r.G
        u = r.u
        if sx != 0.0 or sy != 0.0:
            u = np.array(r.u, dtype=np.float64)
            move = self._jacobian @ np.array([sx, sy])  # (E, 2) mm
            u[r.contact] -= move[r.contact]
        return Readings(G, u, r.contact, r.saturated)

    # ------------------------------------------------------------------ the global estimate
    def _estimate(self, img: np.ndarray, dt: float) -> None:
        """Estimate dark level, gain and shift on ``img`` (float32); accept them or raise the flag."""
        dr, dc = self._dark_px
        reasons = []
        if len(dr):
            vals = img[dr, dc].astype(np.float64)
            window = 6.0 * self._sigma + 0.5  # hot pixels and fireflies out
            keep = np.abs(vals - self._dark.value) <= window
            if keep.sum() < 0.9 * len(vals):  # the level stepped: centre on the median instead
                keep = np.abs(vals - float(np.median(vals))) <= window
            self._outliers = 1.0 - float(keep.mean())
            vals = vals[keep] if keep.any() else vals
            dark = float(vals.mean())
            dark_res = vals - dark
            se_dark = max(float(vals.std()) / math.sqrt(len(vals)), 1e-12)
        else:
            dark, dark_res, se_dark = self._dark.value, np.zeros(0), 1e-12
        g, sx, sy, se_g, se_s = self._g.value, self._sx.value, self._sy.value, 0.0, 0.0
        res_b = np.zeros(0)
        self._peak = math.nan
        if self.tracks_gain:
            start = (self._sx.value, self._sy.value)
            if self.tracks_shift:
                (px, py), peak = cv2.phaseCorrelate(self._pc_ref, self._pc_image(img - np.float32(dark)))
                px, py = px * self._pc_scale, py * self._pc_scale
                self._peak = float(peak) / self._peak0
                if math.hypot(px - start[0], py - start[1]) > COARSE_JUMP_PX:
                    start = (px, py)
            g, sx, sy, se_g, se_s, res_b = self._fit_rim(img, dark, start)
        sig = self._sigma
        res_all = np.concatenate([dark_res, res_b])
        if len(res_all):
            sq = np.sort(res_all**2)
            sq = sq[:max(1, int(math.ceil(0.99 * len(sq))))]  # a few impulses do not count
            self._residual = float(math.sqrt(sq.mean()) / sig)
        # the limits
        if self.tracks_gain and abs(g - 1.0) > self.max_gain:
            reasons.append(f"the rim light changed by {100 * (g - 1):+.1f} % (beyond "
                           f"+-{100 * self.max_gain:g} %)")
        if self.tracks_shift and math.hypot(sx, sy) > self.max_shift:
            reasons.append(f"the camera moved {math.hypot(sx, sy):.2f} px against the dome (beyond "
                           f"{self.max_shift:g} px)")
        if self.tracks_shift and self._peak < self.min_peak:
            reasons.append(f"the rim no longer matches the baseline's (phase-correlation peak {self._peak:.2f} "
                           f"of the expected, below {self.min_peak:g})")
        if self._outliers > MAX_OUTLIERS:
            reasons.append(f"the background outside the elements changed ({100 * self._outliers:.1f} % of its "
                           f"pixels off the drifted baseline: a light or an object in view?)")
        if self._residual > self.max_residual:
            reasons.append(f"the background outside the elements differs from the drifted baseline "
                           f"(residual {self._residual:.1f} sigma, beyond {self.max_residual:g})")
        if dark < 3.0 * sig and self._dark0 >= 3.0 * sig:
            reasons.append(f"the black level fell to {dark:.2f} grey levels: the frames clip at 0")
        if reasons:
            self._flag, self._reason, self._tracking = True, "; ".join(reasons), False
            return
        alpha = 1.0 if self.smooth == 0 else 1.0 - math.exp(-max(dt, 0.0) / self.smooth)
        # the smoothed values' own noise: one estimate's, times sqrt(a / (2 - a)) at the usual pace
        pace = 1.0 if self.smooth == 0 or dt <= 0 else 1.0 - math.exp(-dt / self.smooth)
        shrink = math.sqrt(pace / (2.0 - pace))
        self._ema_se = {"dark": se_dark * shrink, "gain": se_g * shrink if self.tracks_gain else 0.0,
                        "shift": se_s * shrink if self.tracks_shift else 0.0}
        self._dark.update(dark, se_dark, alpha, self.jump)
        if self.tracks_gain:
            self._g.update(g, se_g, alpha, self.jump)
        if self.tracks_shift:
            self._sx.update(sx, se_s, alpha, self.jump)
            self._sy.update(sy, se_s, alpha, self.jump)
        self._flag, self._reason, self._tracking = False, "", True

    def _fit_rim(self, img: np.ndarray, dark: float, start: tuple[float, float]):
        """Gain (ratio of sums over the lit rim) and shift (Gauss-Newton), with their standard errors.

        The gain is ``sum(I - dark) / sum(B0(p - shift) - dark0)`` over the lit rim and its margin: a
        sum over the whole feature keeps its light whatever the interpolation does to a thin, sharp rim
        (weighted sums do not, by a percent at half a pixel), and the baseline's noise enters it only as
        a sum (no bias). Pixels more than 8 sigmas (of the residual) off the model are left out. From a
        start near the answer (the last estimate), one Gauss-Newton step is usually all it takes.
        """
        rf, cf, ri, ci = self._bright_px
        y = img[ri, ci].astype(np.float64) - dark
        sx, sy = start
        g, cov, e, keep, b = 1.0, None, np.zeros(0), np.ones(len(y), bool), np.zeros(len(y))
        for _ in range(SHIFT_ITERATIONS if self.tracks_shift else 1):
            r, c = rf - np.float32(sy), cf - np.float32(sx)
            bg = _sample(self._b0_grad, r, c) if self.tracks_shift else _sample(self._b0c, r, c)[:, None]
            b = bg[:, 0]
            sb = float(b.sum())
            if sb <= 0:
                return g, sx, sy, math.inf, math.inf, np.zeros(0)
            g = float(y.sum()) / sb
            e = y - g * b
            near = np.abs(e) <= 8.0 * self._sigma
            scale = max(float(np.sqrt(np.mean(e[near] ** 2))) if near.any() else 0.0, self._sigma)
            keep = np.abs(e) <= 8.0 * scale  # impulses, a stray light out
            if not keep.all():
                sb = float(b[keep].sum())
                if sb <= 0:
                    return g, sx, sy, math.inf, math.inf, np.zeros(0)
                g = float(y[keep].sum()) / sb
                e = y - g * b
            if not self.tracks_shift:
                break
            ax, ay, ek = -g * bg[keep, 1], -g * bg[keep, 2], e[keep]
            normal = np.array([[ax @ ax, ax @ ay], [ax @ ay, ay @ ay]])
            try:
                step = np.linalg.solve(normal, np.array([ax @ ek, ay @ ek]))
                cov = np.linalg.inv(normal)
            except np.linalg.LinAlgError:
                break
            sx, sy = sx + float(step[0]), sy + float(step[1])
            if math.hypot(*step) < SHIFT_CONVERGED:
                break  # the gain and the residual at the last shift: a step this small moves neither
        ek = e[keep]
        scale = max(float(np.sqrt(np.mean(ek**2))) if len(ek) else 0.0, 1e-12)
        sb = float(b[keep].sum())
        se_g = math.inf if sb <= 0 else scale * math.sqrt(float(keep.sum())) / sb
        se_s = (math.inf if cov is None
                else scale * math.sqrt(max(float(np.linalg.eigvalsh(cov)[-1]), 0.0)))
        return g, sx, sy, se_g, se_s, ek

    # ------------------------------------------------------------------ the correction
    def _target(self):
        """The smoothed model, each parameter held at no drift until it can be told from it.

        The model leaves no drift when a parameter is beyond its tolerance and beyond ``significance``
        of its standard error at no drift (the baseline's own noise and the smoothed estimate's, in
        quadrature); then every parameter beyond its
        tolerance is applied (a correction is made anyway), each until it is back within its tolerance.
        """
        g, dark, sx, sy = self._g.value, self._dark.value, self._sx.value, self._sy.value
        ref, k = self._ref_se, self.significance
        dev = {"gain": (abs(g - 1.0), self.gain_tolerance),
               "dark": (abs(dark - self._dark0), self.offset_tolerance),
               "shift": (math.hypot(sx, sy), self.shift_tolerance)}
        for name, (d, tol) in dev.items():
            if self._engaged[name]:
                self._engaged[name] = d > tol
            else:
                self._engaged[name] = d > max(tol, k * math.hypot(ref[name], self._ema_se[name]))
        if any(self._engaged.values()):  # a correction is made anyway: each parameter beyond its tolerance
            for name, (d, tol) in dev.items():
                self._engaged[name] = self._engaged[name] or d > tol
        if not self._engaged["gain"]:
            g = 1.0
        if not self._engaged["dark"]:
            dark = self._dark0
        if not self._engaged["shift"]:
            sx = sy = 0.0
        elem = np.where(np.abs(self._element) <= self.element_tolerance, 0.0, self._element)
        return g, dark, sx, sy, elem

    def _apply(self) -> None:
        """Redo the correction when the model moved beyond a tolerance from the applied one."""
        g, dark, sx, sy, elem = self._target()
        ag, adark, asx, asy, aelem = self._applied
        identity = g == 1.0 and dark == self._dark0 and sx == 0.0 and sy == 0.0 and not elem.any()
        if identity:
            self._applied, self._pipe, self._pending = (1.0, self._dark0, 0.0, 0.0, elem), self.pipeline, None
            return
        moved = (abs(g - ag) > self.gain_tolerance or abs(dark - adark) > self.offset_tolerance
                 or math.hypot(sx - asx, sy - asy) > self.shift_tolerance
                 or bool(np.any(np.abs(elem - aelem) > self.element_tolerance))
                 or (g == 1.0) != (ag == 1.0) or (sx == sy == 0.0) != (asx == asy == 0.0)
                 or self._pipe is self.pipeline)
        if not moved:
            return
        target = (g, dark, sx, sy, elem)
        step = (abs(dark - adark) > STEP_DARK or abs(g - ag) > STEP_GAIN
                or math.hypot(sx - asx, sy - asy) > STEP_SHIFT or self._pipe is self.pipeline)
        if step:  # this frame already: a black-level step read with the old baseline is contact everywhere
            self._swap(target)
        else:  # a slow drift's next step: the next frame, so that no frame pays for an estimate and a swap
            self._pending = target

    def _swap(self, target: tuple) -> None:
        """Put the pipeline for the model ``target`` (gain, dark, shift x, shift y, element offsets) in use."""
        self._pending = None
        self._applied = target
        self._pipe = self.pipeline.with_baseline_mean(self._predicted(*target))
        self.corrections += 1

    def _predicted(self, g: float, dark: float, sx: float, sy: float, elem: np.ndarray) -> np.ndarray:
        """The no-load image the model predicts now: ``dark + g (B0(p - shift) - dark0)`` + element offsets."""
        b = self._b0c
        if sx != 0.0 or sy != 0.0:
            h, w = self._shape
            m = np.float64([[1.0, 0.0, sx], [0.0, 1.0, sy]])
            # bicubic: the element regions are the dark part of the baseline, where it is as good as
            # Lanczos (the estimates sample the sharp rim with Lanczos) and a third of the cost
            b = cv2.warpAffine(b, m, (w, h), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REPLICATE)
        out = dark + g * b.astype(np.float64)
        if elem.any():
            flat = out.reshape(-1)
            np.add.at(flat, self._entry_all, elem[self._entry_all_el])
        return out

    # ------------------------------------------------------------------ per element
    def _follow_elements(self, img: np.ndarray, readings: Readings, dt: float, t: float) -> None:
        """Follow each quiet element's residual offset (slowly, rate-limited); flag one at its limit."""
        if dt <= 0 or self._flag or self._n_el == 0:
            return
        # the residual against the model now: the applied baseline at the entries, moved by what the
        # smoothed model differs from the applied one (the shift's part is within its tolerance)
        ag, adark, _, _, aelem = self._applied
        g, dark = self._target()[:2]
        lab = self._entry_el
        b0c = self._b0c.reshape(-1)[self._entry_px].astype(np.float64)
        res = (img.reshape(-1)[self._entry_px].astype(np.float64) - self._pipe.entry_baseline[self._entry_pick]
               - (dark - adark) - (g - ag) * b0c - (self._element - aelem)[lab])
        sig, n_el = self._sigma, self._n_el
        # each region's change of light: a mean over the pixels within 2.5 sigma of it, found from 0
        # in a few steps (a spot's pixels, far above, stay out; so does the noise's tail, symmetrically)
        mean = np.zeros(n_el)
        n_in = self._entry_n
        for _ in range(ELEMENT_STEPS):
            near = np.abs(res - mean[lab]) <= 2.5 * sig
            n_in = np.bincount(lab, near, minlength=n_el)
            mean = np.divide(np.bincount(lab, np.where(near, res, 0.0), minlength=n_el), n_in,
                             out=np.zeros(n_el), where=n_in > 0)
        # a spot: pixels far above that level (noise puts about 1 in 30 000 there; a firefly or two pass)
        high = np.bincount(lab, res > mean[lab] + SPOT_SIGMAS * sig, minlength=n_el)
        uniform = high <= SPOT_PIXELS
        contact = np.asarray(readings.contact)
        self._light_only = contact & uniform
        self._last_contact[contact & ~uniform] = t
        quiet = uniform & (t - self._last_contact >= self.holdoff) & (n_in >= 0.5 * self._entry_n)
        alpha = 1.0 - math.exp(-dt / self.element_tau)
        limit = self.element_rate / 60.0 * dt
        step = np.clip(alpha * mean, -limit, limit)
        self._element = np.where(quiet, self._element + step, self._element)
        cap = self.max_element_offset
        at_cap = np.abs(self._element) >= cap
        self._element = np.clip(self._element, -cap, cap)
        if at_cap.any():
            worst = int(np.argmax(np.abs(self._element)))
            self._flag, self._tracking = True, True
            self._reason = (f"the light of element {worst} changed by {self._element[worst]:+.2f} grey levels "
                            f"({int(at_cap.sum())} element(s) at the {cap:.2f} limit)")


# ---------------------------------------------------------------------------- helpers
def _evenly(a: np.ndarray, most: int) -> np.ndarray:
    """At most ``most`` items of ``a``, evenly spread over it (deterministic)."""
    if len(a) <= most:
        return a
    return a[np.linspace(0, len(a) - 1, most).round().astype(np.intp)]


def _spread(idx: tuple[np.ndarray, np.ndarray], most: int) -> tuple[np.ndarray, np.ndarray]:
    """At most ``most`` of the pixels ``(rows, cols)``, evenly spread over them (deterministic)."""
    r, c = idx
    return _evenly(r, most), _evenly(c, most)


def _sample(img: np.ndarray, rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
    """Lanczos (8 x 8) samples of a float32 image ``(H, W)`` or ``(H, W, C)`` at ``(rows, cols)``, float64.

    Lanczos, not bicubic: on a sharp rim (a lens blur of 0.7 px) bicubic samples shift it by up to
    15 % of a sub-pixel shift, Lanczos by about 1 %.
    """
    n = len(rows)
    chans = img.shape[2:] if img.ndim == 3 else ()
    if n == 0:
        return np.zeros((0, *chans))
    width = 4096
    m = -(-n // width) * width  # OpenCV's maps are at most 32767 wide: fold them into rows
    r = np.zeros(m, np.float32)
    c = np.zeros(m, np.float32)
    r[:n], c[:n] = rows, cols
    out = cv2.remap(img, c.reshape(-1, width), r.reshape(-1, width), cv2.INTER_LANCZOS4,
                    borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(m, *chans)[:n].astype(np.float64)


def _region_jacobians(fold, width: int, n_el: int) -> np.ndarray:
    """Per element, mm of its tangent coordinates per pixel of image motion, ``(E, 2, 2)``.

    ``out[e] @ (dx, dy)`` is the move (mm, element-local x and y) of a spot on element ``e`` whose
    image moves ``(dx, dy)`` px (columns, rows): a least-squares fit of the region's cell coordinates
    on its pixels, weighted by their area.
    """
    area, wx, wy = fold.weights
    rows, cols = np.divmod(fold.pixel, width)
    out = np.zeros((n_el, 2, 2))
    ok = area > 0
    for e in range(n_el):
        sel = ok & (fold.label == e)
        if sel.sum() < 3:
            continue
        a = area[sel]
        design = np.column_stack([np.ones(sel.sum()), cols[sel], rows[sel]]) * np.sqrt(a)[:, None]
        target = np.column_stack([wx[sel] / a, wy[sel] / a]) * np.sqrt(a)[:, None]
        coef, *_ = np.linalg.lstsq(design, target, rcond=None)
        out[e] = coef[1:].T  # [[dx/dcol, dx/drow], [dy/dcol, dy/drow]]
    return out
