r"""Standard errors of the readings: each element's G and u from the camera's noise model.

The pipeline reads an element as sums over its lit pixels (see
:class:`optitact.pipeline.frame_pipeline.Pipeline`, *Notes*): ``G = sum a v`` and ``u = M / W`` with
``M = sum a (x, y) (v - t)``, ``W = sum a (v - t)``. A pixel's value ``v``
(frame minus baseline) has the variance

.. math::

    \sigma_p^2 = \sigma_{r,p}^2 + c + g\,\max(v_p, 0)^e,

read (and baseline) noise, the variance ``c`` every lit pixel has beyond it
(:attr:`PixelNoise.lit_variance`: rounding, and noise not proportional to
the signal), plus shot noise (``e = 1``; :attr:`PixelNoise.exponent` for
noise that grows otherwise with the signal): ``g`` is the conversion gain in
grey levels per electron (:attr:`PixelNoise.dn_per_electron`; for the CCD
model ``CCD.dn_per_electron``, for a real camera stated or estimated with
:meth:`PixelNoise.estimate`), and ``sigma_r`` the pipeline's own noise
floor, the one its threshold is ``k`` times (``entry_threshold / k``: the
per-pixel ``noise_map`` of a multi-frame baseline, else ``noise_sigma``).
Pixels are independent, so to first order (the delta method)

.. math::

    \mathrm{var}\,G = \sum a^2 \sigma_p^2, \quad
    \mathrm{cov}(u_i, u_j) = \sum \frac{(a x_i - u_i a)(a x_j - u_j a)}{W^2}\sigma_p^2, \quad
    \mathrm{cov}(G, u_i) = \sum \frac{a (a x_i - u_i a)}{W} \sigma_p^2,

summed over the lit pixels of the element, with the measured ``v`` standing
for its mean. This is the same linearisation the noise sweep
(:mod:`optitact.studies.noise_sweep`) checks against the Cramér–Rao bound;
what it leaves out is the threshold itself: a pixel whose mean lies near the
threshold is lit in some frames and not in others, which adds to var G (a
jump of ``t`` per crossing) and biases G low (the clipped tails, which
``Pipeline(tail="gaussian")`` adds back). Both are small for the compact
spots of loaded elements.

Here rather than in :mod:`optitact.calib`: the errors belong to the frames
and the pipeline (a user without a calibration gets them too), and
:meth:`optitact.calib.fit.Calibration.stderr` propagates them to forces. The
per-frame path (:meth:`optitact.pipeline.frame_pipeline.Pipeline.process`) is untouched: this is a
separate NumPy pass over the lit pixels, run only when errors are asked for.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from optitact._validate import integer, positive
from optitact.errors import InputError, KindError, ShapeError
from optitact.pipeline.imageops import MAX_GREY, check_frames

__all__ = ["Z90", "MAX_DN_PER_ELECTRON", "PixelNoise", "ReadingErrors", "coverage", "coverage_spread",
           "error_ratio", "reading_errors", "saturated_pixels"]

#: Half-width of the two-sided 90 % interval of a normal error, in standard errors.
Z90 = 1.6448536269514722

#: Largest conversion gain :class:`PixelNoise` takes, grey levels per electron: one electron spanning
#: the whole range of a 16-bit frame. Cameras have about 0.01 to 10 (an EMCCD, with its multiplication
#: gain, a few hundred); a larger value is a mistake of units, and would overflow the variances.
MAX_DN_PER_ELECTRON = 65535.0


@dataclass(frozen=True)
class PixelNoise:
    """The camera's noise per pixel: conversion gain (shot noise), and optionally the read noise.

    Parameters
    ----------
    dn_per_electron : float
        Conversion gain ``g`` of the frames, grey levels per photo-electron
        (>= 0, at most :data:`MAX_DN_PER_ELECTRON`; 0: no shot noise). The CCD model's is
        ``CCD.dn_per_electron`` (:meth:`from_ccd`); for a real camera it is
        on its data sheet (as electrons per DN: take the inverse, scaled to
        the bit depth of the frames), or :meth:`estimate` measures it.
    read_sigma : float, optional
        Noise (grey levels of the frames, rms) of ``frame - baseline`` in
        the dark. Default: the pipeline's own (its threshold over ``k``),
        which is what a pipeline made by :meth:`optitact.pipeline.frame_pipeline.Pipeline.from_noload`
        measured.
    lit_variance : float
        Variance (grey levels squared) every lit pixel has beyond the read
        and shot noise: the intercept of the photon-transfer line
        (:meth:`estimate`). Rounding to grey levels adds about 1/12 to a
        lit pixel that a dark one, whose noise is well below a grey level,
        does not show; noise that grows less than linearly with the signal
        (a path tracer's Monte Carlo noise) puts more here. Default 0.
    exponent : float
        How the rest grows with the pixel's signal ``v``:
        ``dn_per_electron * v**exponent``. 1 (the default) is shot noise, a
        camera's; a path tracer's Monte Carlo noise grows more slowly
        (:meth:`estimate` with ``exponent="fit"`` measures it: 0.86 on the
        accuracy bench's 256-spp frames). In (0, 2].

    Examples
    --------
    >>> from optitact.optics.ccd import CCD
    >>> round(PixelNoise.from_ccd(CCD()).dn_per_electron, 5)
    0.01255
    """

    dn_per_electron: float
    read_sigma: float | None = None
    lit_variance: float = 0.0
    exponent: float = 1.0

    def __post_init__(self) -> None:
        # the bounds keep every variance of reading_errors finite (pixel values are at most MAX_GREY)
        object.__setattr__(self, "dn_per_electron", _at_most(
            self.dn_per_electron, "dn_per_electron", MAX_DN_PER_ELECTRON,
            "grey levels per electron (one electron spanning a 16-bit frame's range; cameras have about "
            "0.01 to 10)"))
        object.__setattr__(self, "lit_variance", _at_most(
            self.lit_variance, "lit_variance", MAX_GREY, "grey levels squared"))
        object.__setattr__(self, "exponent", _exponent(self.exponent))
        if self.read_sigma is not None:
            object.__setattr__(self, "read_sigma", _at_most(self.read_sigma, "read_sigma", MAX_GREY,
                                                            "grey levels"))

    def to_dict(self) -> dict:
        """JSON-ready: the four parameters (``read_sigma`` None: the pipeline's own)."""
        return {"dn_per_electron": self.dn_per_electron, "read_sigma": self.read_sigma,
                "lit_variance": self.lit_variance, "exponent": self.exponent}

    @classmethod
    def from_dict(cls, d) -> PixelNoise:
        """Build from :meth:`to_dict` output; InputError naming what is missing, unknown or out of range."""
        if not isinstance(d, dict):
            raise InputError(f"a pixel noise model must be a JSON object, got {type(d).__name__}")
        names = tuple(f.name for f in fields(cls))
        if "dn_per_electron" not in d or set(d) - set(names):
            raise InputError(f"a pixel noise model has dn_per_electron and optionally read_sigma, "
                             f"lit_variance and exponent, got {sorted(d)}")
        for name in names:
            value = d.get(name)
            if value is not None and (isinstance(value, bool) or not isinstance(value, (int, float))):
                raise InputError(f"pixel noise {name} must be a number, got {value!r}")
        return cls(**d)

    def save(self, path, *, measured: dict | None = None) -> Path:
        """Write the model as JSON (atomically), with ``measured``: where it came from (kept, not read).

        ``optitact calibrate noise`` writes one; ``optitact process --stderr
        --noise FILE`` and :meth:`load` read it.
        """
        from optitact.io.files import write_json

        path = Path(path)
        doc = {"pixel_noise": self.to_dict()} | ({} if measured is None else {"measured": measured})
        write_json(path, doc)
        return path

    @classmethod
    def load(cls, path) -> PixelNoise:
        """A model written by :meth:`save`; InputError naming the file if it is not one."""
        from optitact.io.files import read_json_object

        doc = read_json_object(path, ("pixel_noise",), what="noise", writer="optitact calibrate noise")
        try:
            return cls.from_dict(doc["pixel_noise"])
        except (TypeError, ValueError) as exc:
            raise InputError(f"{path}: {exc}") from None

    @classmethod
    def from_ccd(cls, ccd) -> PixelNoise:
        """The conversion gain of a :class:`optitact.optics.ccd.CCD` (read noise: the pipeline's)."""
        return cls(float(ccd.dn_per_electron))

    @classmethod
    def estimate(cls, noload, pressed, *, min_signal: float = 20.0, exponent: float | str = 1.0) -> PixelNoise:
        r"""Measure the conversion gain from a no-load stack and a stack under one constant load.

        Parameters
        ----------
        noload, pressed : (T, H, W) array_like
            Frames of the same camera settings, ``T >= 2`` each: unloaded,
            and pressed by a load that does not change between frames. Grey
            levels of one dtype (integer, e.g. ``uint8`` or ``uint16``, or
            float of any precision).
        min_signal : float
            Only pixels whose mean signal (pressed minus unloaded mean) is
            above this (grey levels) enter the fit (default 20: below a few
            grey levels of noise, rounding bends the photon-transfer line).
            Saturated pixels (:func:`saturated_pixels`) never do: a clipped
            pixel's variance says nothing of its noise.
        exponent : float or "fit"
            The power of the signal the excess variance grows with (default
            1: shot noise, a camera's), or ``"fit"`` to measure it too (noise
            that is not shot noise: a path tracer's).

        Returns
        -------
        PixelNoise
            ``dn_per_electron`` the slope ``g`` of the photon-transfer line
            ``var_pressed - var_noload = c + g (mean_pressed - mean_noload)``
            over the lit pixels (least squares), ``lit_variance`` its
            intercept ``c`` (at least 0: the rounding noise, which a dark
            pixel whose noise is well below one grey level does not show,
            and any noise that is not proportional to the signal), and
            ``read_sigma`` the no-load stack's rms temporal noise times
            ``sqrt(1 + 1/T)`` (the noise of a frame minus the stack's mean).
            With ``exponent="fit"``: ``c + g s^e`` with ``e`` in [0.3, 1.5]
            too, by weighted least squares (each pixel's excess weighted by
            the inverse square of its model variance, iterated: the spread of
            a sample variance grows with it), over a grid of ``e`` in steps
            of 0.01.

        Raises
        ------
        KindError
            A stack that is not of an integer or float dtype (bool, complex, object).
        ShapeError
            The stacks are not (T, H, W) with T >= 2, or of different frame shapes.
        InputError
            Stacks of different integer dtypes (bit depths), a float pixel that
            is not finite, fewer than 10 unsaturated pixels above ``min_signal``
            (the message says whether saturation left too few).

        Notes
        -----
        Shot noise has the variance of the electron count, so in grey levels
        ``var = g^2 N_e = g (mean signal)``; read noise and quantisation
        add (nearly) the same variance with and without load and go into
        the intercept.
        """
        raw = _photon_stacks(noload, pressed)
        saturated = saturated_pixels(*raw)
        a, b = (np.asarray(s, dtype=np.float64) for s in raw)
        signal = b.mean(axis=0) - a.mean(axis=0)
        excess = b.var(axis=0, ddof=1) - a.var(axis=0, ddof=1)
        above = signal > positive(min_signal, "min_signal", allow_zero=True)
        lit = above & ~saturated
        if np.count_nonzero(lit) < 10:
            n_above, n_lit = np.count_nonzero(above), np.count_nonzero(lit)
            if n_above > n_lit:
                top = _full_scale(raw[1].dtype)
                raise InputError(
                    f"pressed: {n_above - n_lit} of the {n_above} pixels with a mean signal above "
                    f"min_signal={min_signal:g} grey levels are saturated (at {top:g}, the {raw[1].dtype} "
                    f"maximum, in some frame), leaving {n_lit}: a clipped pixel carries no noise "
                    f"information; lower the exposure, gain or light, or press more lightly, so that "
                    f"at least 10 lit pixels stay below saturation")
            raise InputError(f"pressed: only {n_lit} pixels have a mean signal above "
                             f"min_signal={min_signal:g} grey levels; press harder or lower min_signal")
        read = math.sqrt(float(a.var(axis=0, ddof=1)[~saturated].mean()) * (1.0 + 1.0 / a.shape[0]))
        if isinstance(exponent, str):
            if exponent != "fit":
                raise InputError(f"exponent must be a number or 'fit', got {exponent!r}")
            intercept, slope, power = _transfer_curve(signal[lit], excess[lit])
            return cls(slope, read, intercept, power)
        power = _exponent(exponent)
        slope, intercept = (float(c) for c in np.polyfit(signal[lit] ** power, excess[lit], 1))
        return cls(max(slope, 0.0), read, max(intercept, 0.0), power)


def saturated_pixels(*stacks) -> np.ndarray:
    """Pixels at their integer dtype's maximum (255 for ``uint8``) in any frame of the stacks.

    Parameters
    ----------
    *stacks : (T, H, W) array_like
        Frames of one shape; float frames have no known full scale and are
        never saturated here.

    Returns
    -------
    (H, W) bool ndarray

    Examples
    --------
    >>> import numpy as np
    >>> s = np.zeros((2, 1, 3), np.uint8)
    >>> s[1, 0, 2] = 255
    >>> saturated_pixels(s).tolist()
    [[False, False, True]]
    """
    out = None
    for s in stacks:
        arr = np.asarray(s)
        hit = (arr == _full_scale(arr.dtype)).any(axis=0) if arr.dtype.kind in "ui" else \
            np.zeros(arr.shape[1:], bool)
        out = hit if out is None else out | hit
    if out is None:
        raise TypeError("saturated_pixels needs at least one stack")
    return out


def _full_scale(dtype: np.dtype) -> float:
    """The largest grey level of an integer dtype (inf for a float one)."""
    return float(np.iinfo(dtype).max) if dtype.kind in "ui" else math.inf


def _photon_stacks(noload, pressed) -> tuple[np.ndarray, np.ndarray]:
    """The two stacks of :meth:`PixelNoise.estimate`, checked: (T, H, W), T >= 2, one frame shape and dtype."""
    out = []
    for name, s in (("noload", noload), ("pressed", pressed)):
        try:
            arr = np.asarray(s)
        except (ValueError, TypeError) as exc:  # ragged nested sequences
            raise KindError(f"{name} must be a stack of grey levels (T, H, W); could not make one ({exc})") \
                from None
        if arr.dtype.kind not in "uif":
            raise KindError(f"{name} must hold grey levels of an integer or float dtype (uint8, uint16, "
                            f"float32, float64), got {arr.dtype}")
        if arr.ndim != 3 or arr.shape[0] < 2:
            raise ShapeError(f"{name} must be a stack (T, H, W) with T >= 2, got shape {arr.shape}")
        if arr.dtype.kind == "f" and not np.isfinite(arr).all():
            raise InputError(f"{name} must hold finite grey levels, got NaN or infinity")
        out.append(arr)
    a, b = out
    if a.shape[1:] != b.shape[1:]:
        raise ShapeError(f"noload and pressed frames must have the same shape, got {a.shape[1:]} and "
                         f"{b.shape[1:]}")
    if a.dtype != b.dtype and not (a.dtype.kind == b.dtype.kind == "f"):
        raise InputError(f"noload frames are {_depth(a.dtype)} and pressed frames {_depth(b.dtype)}: both "
                         f"stacks must come from one camera setting, at one bit depth")
    return a, b


def _depth(dtype: np.dtype) -> str:
    """``"uint8 (8-bit)"``, ``"float32"``: a dtype and, for integers, its bit depth."""
    return f"{dtype} ({8 * dtype.itemsize}-bit)" if dtype.kind in "ui" else str(dtype)


def _at_most(value, name: str, bound: float, unit: str) -> float:
    """``value`` checked finite, >= 0 and at most ``bound`` (``unit`` says what it is, for the message)."""
    v = positive(value, name, allow_zero=True)
    if v > bound:
        raise InputError(f"{name} must be at most {bound:g} {unit}, got {value!r}")
    return v


def _exponent(value) -> float:
    """A :attr:`PixelNoise.exponent`, validated: a number in (0, 2]."""
    e = positive(value, "exponent")
    if e > 2.0:
        raise InputError(f"exponent must be in (0, 2], got {value!r}")
    return e


def _transfer_curve(signal: np.ndarray, excess: np.ndarray, iterations: int = 4) -> tuple[float, float, float]:
    """``(c, g, e)`` of ``excess ~ c + g signal^e`` (c, g >= 0, e on a 0.01 grid in [0.3, 1.5]).

    Weighted least squares: a sample variance's spread is proportional to
    its expected value, so each pixel is weighted by the inverse square of
    the model's variance at its signal (from the previous iteration; the
    first from a straight line). For each ``e`` the weighted fit is linear in
    ``(c, g)``; the ``e`` with the least weighted squares wins.
    """
    slope, intercept = np.polyfit(signal, excess, 1)
    tiny = max(abs(float(np.mean(excess))), 1e-12) * 1e-3  # keeps the weights finite
    model = np.maximum(intercept + slope * signal, tiny)
    logs = np.log(signal)
    best = (0.0, 0.0, 1.0)
    for _ in range(iterations):
        w = 1.0 / model**2
        best_sse = np.inf
        for e in np.round(np.arange(0.3, 1.5001, 0.01), 2):
            x = np.exp(e * logs)
            sw, sx, sxx = w.sum(), (w * x).sum(), (w * x * x).sum()
            sy, sxy = (w * excess).sum(), (w * x * excess).sum()
            det = sw * sxx - sx * sx
            g = (sw * sxy - sx * sy) / det if det > 0 else 0.0
            c = (sy - g * sx) / sw
            if c < 0.0:  # the best fit with c = 0
                c, g = 0.0, sxy / sxx
            g = max(g, 0.0)
            sse = float((w * (excess - c - g * x) ** 2).sum())
            if sse < best_sse:
                best_sse, best = sse, (float(c), float(g), float(e))
        c, g, e = best
        model = np.maximum(c + g * signal**e, tiny)
    return best if best[1] > 0.0 else (best[0], 0.0, 1.0)  # no part grows with the signal: no exponent


@dataclass(frozen=True)
class ReadingErrors:
    """Covariance of each element's ``(G, ux, uy)`` reading, from :func:`reading_errors`.

    Attributes
    ----------
    cov : (E, 3, 3) or (T, E, 3, 3) ndarray
        Covariance of ``(G, ux, uy)`` (grey level x mm^2 and mm, as the
        readings); zero where there is no contact.
    """

    cov: np.ndarray

    @property
    def G_se(self) -> np.ndarray:
        """Standard error of G, (E,) or (T, E)."""
        return np.sqrt(self.cov[..., 0, 0])

    @property
    def u_se(self) -> np.ndarray:
        """Standard errors of ``(ux, uy)`` (mm), (E, 2) or (T, E, 2)."""
        return np.sqrt(np.stack([self.cov[..., 1, 1], self.cov[..., 2, 2]], axis=-1))


def reading_errors(pipeline, frames, noise: PixelNoise, readings=None) -> ReadingErrors:
    """Covariance of the readings of ``frames`` from the noise model (see the module docstring).

    Parameters
    ----------
    pipeline : Pipeline
        The pipeline that reads (or read) the frames (filter ``"none"``).
    frames : (H, W) or (T, H, W) array_like
    noise : PixelNoise
    readings : Readings, optional
        ``pipeline.process(frames)`` if already made (else it is computed).

    Returns
    -------
    ReadingErrors
        ``(E, 3, 3)`` for a frame, ``(T, E, 3, 3)`` for a stack.

    Raises
    ------
    InputError
        A pipeline with a denoising filter (its pixels' noise is correlated;
        not modelled).
    TypeError
        ``noise`` is not a :class:`PixelNoise`.
    """
    if not isinstance(noise, PixelNoise):
        raise TypeError(f"noise must be a PixelNoise, got {type(noise).__name__}")
    if pipeline.filter != "none":
        raise InputError(f"reading errors need a pipeline without a filter (its pixels' noise is "
                         f"independent), got filter={pipeline.filter!r}")
    stack, single = check_frames(frames, pipeline.camera)
    pipeline.check_scale(stack, "frames")
    if readings is None:
        readings = pipeline.process(stack)
    fold = pipeline.region_weights
    n_ent, n_el, t_n = len(fold.pixel), len(fold.n_pixels), stack.shape[0]
    level = pipeline.lit_levels(stack.dtype)
    g = np.take(stack.reshape(t_n, -1), fold.pixel, axis=1)
    idx = np.flatnonzero(g > level)
    e = idx % n_ent
    v = g.reshape(-1)[idx] - np.take(pipeline.entry_baseline, e)
    thr = np.take(pipeline.entry_threshold, e)
    if stack.dtype.kind == "f":
        keep = v > thr
        idx, e, v, thr = idx[keep], e[keep], v[keep], thr[keep]
    if noise.read_sigma is not None:
        read2 = noise.read_sigma ** 2
    elif pipeline.k > 0:
        read2 = (thr / pipeline.k) ** 2
    else:
        read2 = (pipeline.noise_sigma * pipeline.dn_ratio) ** 2
    shot = np.maximum(v, 0.0) if noise.exponent == 1.0 else np.maximum(v, 0.0) ** noise.exponent
    var = read2 + noise.lit_variance + noise.dn_per_electron * shot
    key = fold.label[e] + (idx // n_ent) * n_el
    size = t_n * n_el
    area, wx, wy = (w[e] for w in fold.weights)
    above = np.maximum(v - thr, 0.0)
    W = np.bincount(key, area * above, minlength=size)
    ux = np.bincount(key, wx * above, minlength=size) / np.where(W > 0, W, 1.0)
    uy = np.bincount(key, wy * above, minlength=size) / np.where(W > 0, W, 1.0)
    dG = area
    inv_w = 1.0 / np.where(W > 0, W, 1.0)[key]
    dux = (wx - ux[key] * area) * inv_w
    duy = (wy - uy[key] * area) * inv_w
    parts = (dG, dux, duy)
    cov = np.zeros((size, 3, 3))
    for i in range(3):
        for j in range(i, 3):
            c = np.bincount(key, parts[i] * parts[j] * var, minlength=size)
            cov[:, i, j] = cov[:, j, i] = c
    cov = cov.reshape(t_n, n_el, 3, 3)
    r = pipeline.dn_ratio
    cov[..., 0, :] /= r
    cov[..., :, 0] /= r
    contact = np.asarray(readings.contact).reshape(t_n, n_el)
    cov[~contact] = 0.0
    if not np.isfinite(cov).all():  # never an empty standard error for a contact
        raise InputError(f"the readings' variances overflow with this noise model ({noise}) on these "
                         f"frames' grey levels; check the noise model's units")
    return ReadingErrors(cov[0] if single else cov)


def coverage(estimates, truth, stderr, *, z: float = Z90, where=None) -> np.ndarray:
    """Fraction of true values inside the interval ``estimate +- z stderr``, per axis.

    Parameters
    ----------
    estimates, truth, stderr : (..., 3) array_like
        Estimated forces, true forces and the estimates' standard errors (N).
    z : float
        Half-width in standard errors (default :data:`Z90`: the 90 % interval).
    where : bool array_like of the leading shape, optional
        Samples to count (e.g. the loaded elements); default all.

    Returns
    -------
    (3,) ndarray
        Per axis; NaN when no sample is counted. For honest standard errors
        of normal errors it is close to 0.9 (binomial spread ``sqrt(0.09 / n)``).

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> se = np.full((20000, 3), 0.01)
    >>> est = rng.normal(0.0, se)
    >>> [round(float(c), 2) for c in coverage(est, np.zeros_like(est), se)]
    [0.9, 0.9, 0.9]
    """
    inside, mask = _inside(estimates, truth, stderr, z, where)
    n = int(mask.sum())
    return inside[mask].mean(axis=0) if n else np.full(3, np.nan)


def error_ratio(estimates, truth, stderr, *, where=None) -> np.ndarray:
    """The errors in standard errors, root mean square, per axis: ``sqrt(mean(((est - truth) / stderr)^2))``.

    1 when the standard errors are right, whatever the errors' distribution;
    above 1 they are too narrow, below too wide. :func:`coverage` of the 90 %
    interval depends on the tails as well: errors with heavier tails than a
    normal's put more of them inside 1.64 standard errors at the same ratio.

    Parameters
    ----------
    estimates, truth, stderr, where
        As for :func:`coverage`; the counted standard errors must be > 0.

    Returns
    -------
    (3,) ndarray
        Per axis; NaN when no sample is counted.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(1)
    >>> se = np.full((20000, 3), 0.01)
    >>> est = rng.normal(0.0, 2 * se)  # standard errors half the real ones
    >>> [round(float(r), 1) for r in error_ratio(est, np.zeros_like(est), se)]
    [2.0, 2.0, 2.0]
    """
    err, se, mask = _errors(estimates, truth, stderr, where)
    if not mask.any():
        return np.full(3, np.nan)
    err, se = err[mask], se[mask]
    if not np.all(se > 0):
        raise InputError("stderr must be > 0 for every counted sample")
    return np.sqrt(np.mean((err / se) ** 2, axis=0))


def _errors(estimates, truth, stderr, where, stack: bool = False) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(estimates - truth, stderr)`` (..., 3) and the samples counted (...), checked.

    ``stack``: the arrays must be (T, E, 3), frames by elements.
    """
    est, tru, se = (np.asarray(a, dtype=np.float64) for a in (estimates, truth, stderr))
    if not est.shape == tru.shape == se.shape or est.shape[-1:] != (3,) or (stack and est.ndim != 3):
        shape = "(T, E, 3)" if stack else "(..., 3)"
        raise ShapeError(f"estimates, truth and stderr must have the same shape {shape}, got {est.shape}, "
                         f"{tru.shape} and {se.shape}")
    mask = np.ones(est.shape[:-1], bool) if where is None else np.asarray(where, bool)
    if mask.shape != est.shape[:-1]:
        raise ShapeError(f"where must have shape {est.shape[:-1]}, got {mask.shape}")
    return est - tru, se, mask


def _inside(estimates, truth, stderr, z: float, where, stack: bool = False) -> tuple[np.ndarray, np.ndarray]:
    """Whether each true value is inside its interval (..., 3), and the samples counted (...).

    ``stack``: the arrays must be (T, E, 3), frames by elements.
    """
    err, se, mask = _errors(estimates, truth, stderr, where, stack)
    return np.abs(err) <= positive(z, "z") * se, mask


def coverage_spread(estimates, truth, stderr, *, z: float = Z90, where=None, resamples: int = 1000,
                    seed: int = 0) -> np.ndarray:
    """Standard deviation of :func:`coverage` over frames drawn again with replacement (a bootstrap).

    The elements of one frame share its load pattern and its errors, so
    they are not independent samples: the spread of the coverage is that of
    the frames. Resampling whole frames (the leading axis) gives it, where
    ``sqrt(0.09 / n)`` over all ``n`` elements would understate it. A
    coverage that misses 0.9 by more than about twice this spread misses it
    beyond the luck of the frames drawn.

    Parameters
    ----------
    estimates, truth, stderr : (T, E, 3) array_like
        Per frame and element, as for :func:`coverage`.
    z, where
        As for :func:`coverage` (``where``: (T, E)).
    resamples : int
        Bootstrap draws (default 1000).
    seed : int
        Of the draws: the same seed gives the same spread.

    Returns
    -------
    (3,) ndarray
        Per axis; NaN with fewer than two frames holding a counted sample.

    Examples
    --------
    >>> import numpy as np
    >>> rng = np.random.default_rng(2)
    >>> se = np.full((200, 41, 3), 0.01)
    >>> est = rng.normal(0.0, se)
    >>> sd = coverage_spread(est, np.zeros_like(est), se)
    >>> bool(np.all((sd > 0.001) & (sd < 0.004)))  # about sqrt(0.09 / 8200) = 0.0033
    True
    """
    inside, mask = _inside(estimates, truth, stderr, z, where, stack=True)
    resamples = integer(resamples, "resamples", minimum=2)
    hits = (inside & mask[..., None]).sum(axis=1).astype(np.float64)  # (T, 3) per frame
    counts = mask.sum(axis=1).astype(np.float64)  # (T,)
    keep = counts > 0
    hits, counts = hits[keep], counts[keep]
    if len(counts) < 2:
        return np.full(3, np.nan)
    draws = np.random.default_rng(seed).integers(0, len(counts), (resamples, len(counts)))
    return (hits[draws].sum(axis=1) / counts[draws].sum(axis=1)[:, None]).std(axis=0, ddof=1)
