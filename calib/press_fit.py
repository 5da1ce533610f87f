"""Fitting a calibration to measured presses, from scratch or by refining a starting calibration.

:func:`fit_from_frames` reads frames of presses and the gauge's CSV
(:func:`~optitact.calib.gauge.measure_presses`) and fits a
:class:`~optitact.calib.Calibration` to them with :func:`fit_presses`, either
from scratch or by refining a starting calibration (the shipped synthetic
one, ``start="default"``).

Refinement
----------
From scratch every element needs at least ``MIN_PRESSES_SCRATCH`` presses
(the cubic ``g(G)``, its brightness gradient and the shear curve of
:meth:`Calibration.fit <optitact.calib.Calibration.fit>`). Starting from a
calibration, each element with at least ``MIN_PRESSES_REFINE`` presses gets
fitted by least squares over its presses: a gain ``k`` on G (``g_scale`` and
``g_max`` times ``k``: ``Fz = g_start(G / k, u)``; real elements differ in
brightness), a scale ``c`` on the shear curve (``F_t = c f_start``; fitted
where a press has shear, else 1) and, for the coupled model, a shift of its
zero-shear centroid (``u0``; the element's own brightness gradient across
its cones, up to ``MAX_CENTROID_SHIFT_MM``). Elements with fewer
presses keep the starting curves (a warning names them). The fitted range
grows to the largest G and shift seen in the presses. A start made for
another sensor or camera is transferred to the presses' first
(:meth:`Calibration.transferred <optitact.calib.Calibration.transferred>`),
so a registered sensor's element gains start the refinement.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from optitact.ccd import IntensityScale
from optitact.errors import InputError, OptitactWarning, ShapeError
from optitact.readings import Readings
from optitact.sensor import DomeSensor

from .curves import MODELS
from .document import PIPELINE_KEYS
from .fit import Calibration
from .gauge import Presses, check_presses, measure_presses

__all__ = ["MIN_PRESSES_REFINE", "MIN_PRESSES_SCRATCH", "fit_from_frames", "fit_presses"]

#: Presses per element a fit from scratch needs (``Calibration.fit``'s usable-sample minimum).
MIN_PRESSES_SCRATCH = 8
#: Presses per element a refinement of a starting calibration needs (else the element keeps its curves).
MIN_PRESSES_REFINE = 2
#: Largest shift (mm) of an element's zero-shear centroid a refinement accepts.
MAX_CENTROID_SHIFT_MM = 0.5


def starting_calibration(start) -> Calibration | None:
    """The calibration ``start`` names: None, a :class:`Calibration`, ``"default"`` or a calibration file."""
    if start is None or isinstance(start, Calibration):
        return start
    if isinstance(start, str) and start == "default":
        from . import default_calibration

        return default_calibration()
    if isinstance(start, (str, os.PathLike)):
        return Calibration.load(start)
    raise TypeError(f"start must be None, 'default', a Calibration or a calibration file, got "
                    f"{type(start).__name__}")


def fit_from_frames(frames: Sequence[str | os.PathLike], forces: str | os.PathLike, *, pipeline=None,
                    model: str | None = None, start=None, baseline=None, baseline_frames: int = 1,
                    progress: bool = False) -> Calibration:
    """Fit a calibration to frames of measured presses and the gauge's CSV.

    Parameters
    ----------
    frames : sequence of path-like
        The frames (see :func:`measure_presses`).
    forces : path-like
        The gauge CSV (see the module docstring).
    pipeline : Pipeline, optional
        Reads the frames; default ``start.pipeline()`` with a start, else a
        pipeline of ``DomeSensor.default()`` and a ``FisheyeCamera`` of the
        frames' size.
    model : {"coupled", "ohka"}, optional
        From scratch (default "coupled"); a refinement keeps the start's.
    start : None, "default", Calibration or path-like
        Refine this calibration (see :func:`fit_presses`).
    baseline, baseline_frames, progress
        As in :func:`measure_presses`.

    Returns
    -------
    Calibration
        With the sensor, camera and pipeline options of ``pipeline``.
    """
    start = starting_calibration(start)
    if pipeline is None:
        pipeline = start.pipeline() if start is not None else default_pipeline(frames)
    p = measure_presses(frames, forces, pipeline=pipeline, baseline=baseline, baseline_frames=baseline_frames,
                        progress=progress)
    return fit_measured(p, pipeline, model=model, start=start, forces=forces)


def fit_measured(p: Presses, pipeline, *, model, start, forces) -> Calibration:
    """:func:`fit_presses` on measured presses, with the pipeline's sensor, camera, options and scale."""
    options = {k: v for k, v in pipeline._options().items() if k in PIPELINE_KEYS and k != "method"}
    bits = pipeline.readings_bits or pipeline.bits or 8
    return fit_presses(p.readings, p.forces, pressed=p.pressed, sensor=pipeline.sensor, camera=pipeline.camera,
                       pipeline_options=options, model=model, start=start,
                       intensity=start.intensity if start is not None else IntensityScale(bits=bits),
                       provenance={"frames": len(p.sources), "forces": str(forces),
                                   "presses": int(p.pressed.sum())})


def default_pipeline(frames):
    """A pipeline of ``DomeSensor.default()`` and a ``FisheyeCamera`` of the first frame's size."""
    from optitact.camera import FisheyeCamera
    from optitact.frames import expand_sources, iter_frames
    from optitact.pipeline import Pipeline

    first = next(iter_frames(expand_sources(frames)[:1]), None)
    if first is None:
        raise InputError("the frames hold no frame")
    h, w = first[1].shape[:2]
    return Pipeline(DomeSensor.default(), FisheyeCamera(width=w, height=h))


# ---------------------------------------------------------------------------- fitting
def _elements(ids, counts) -> str:
    return ", ".join(f"element {e} ({counts[e]})" for e in ids[:12]) + (
        f" and {len(ids) - 12} more" if len(ids) > 12 else "")


def fit_presses(readings: Readings, forces, *, pressed=None, sensor: DomeSensor, camera,
                pipeline_options: dict | None = None, model: str | None = None, start=None,
                intensity: IntensityScale | None = None, provenance: dict | None = None) -> Calibration:
    """Fit a calibration to readings of measured presses, from scratch or refining ``start``.

    Parameters
    ----------
    readings : Readings
        ``(T, E)`` readings of the frames.
    forces : (T, E, 3) array_like
        Element-local forces (N), 0 where unloaded.
    pressed : (T, E) bool array_like, optional
        Which frame and element the gauge pressed (default: a non-zero
        force). A press counts where the pipeline sees contact and no
        saturation.
    sensor, camera, pipeline_options
        What the readings came from (stored in the calibration).
    model : {"coupled", "ohka"}, optional
        From scratch (default "coupled"). A refinement keeps the start's
        model; naming another is an error.
    start : None, "default", Calibration or path-like
        None: fit every element from scratch (:meth:`Calibration.fit`), which
        needs ``MIN_PRESSES_SCRATCH`` presses per element. Otherwise refine
        this calibration's curves per element (a gain on G and a scale on the
        shear curve; see the module docstring); elements with fewer than
        ``MIN_PRESSES_REFINE`` presses keep its curves. A start made for
        another sensor or camera (e.g. the shipped one, for a registered
        sensor) is first transferred to ``sensor`` and ``camera``
        (:meth:`Calibration.transferred`: its gains relative to the start's
        sensor folded into the G scales), so the refinement starts close.
    intensity : IntensityScale, optional
        Of the frames (default: the start's, else 8-bit).
    provenance : dict, optional
        Stored, with what the fit adds (presses per element, refined and kept elements).

    Raises
    ------
    InputError
        From scratch, elements with too few presses (the message names them,
        with their counts and what they need, and suggests ``start``); a
        start of another model or number of elements; see also
        :meth:`Calibration.fit`.
    ShapeError
        ``forces`` or ``pressed`` do not match the readings.

    Warns
    -----
    OptitactWarning
        Refining: elements with too few presses keep the start's curves.
    """
    f, pressed = check_presses(readings, forces, pressed)
    usable = readings.contact & ~readings.saturated
    n_press = np.sum(pressed & usable, axis=0)
    start = starting_calibration(start)
    prov = dict(provenance or {}) | {"presses_per_element": n_press.tolist()}
    if start is None:
        model = "coupled" if model is None else model
        if model not in MODELS:
            raise InputError(f"model must be one of {MODELS}, got {model!r}")
        few = np.flatnonzero(n_press < MIN_PRESSES_SCRATCH)
        if few.size:
            raise InputError(
                f"too few presses to fit from scratch: {_elements(few, n_press)} presses in contact; each "
                f"element needs at least {MIN_PRESSES_SCRATCH} (normal and inclined); press them more, or "
                f"refine a starting calibration that supplies them (start='default', --start default)")
        return Calibration.fit(readings, f, sensor=sensor, camera=camera, pipeline_options=pipeline_options,
                               model=model, provenance=prov | {"fit": "scratch"}, intensity=intensity)
    if model is not None and model != start.model:
        raise InputError(f"model {model!r}: a refinement keeps the starting calibration's model "
                         f"({start.model!r}); drop the model or start from a {model} calibration")
    if len(start.g) != readings.n_elements:
        raise ShapeError(f"the starting calibration has {len(start.g)} elements, the readings "
                         f"{readings.n_elements}")
    if start.sensor != sensor or start.camera != camera:  # e.g. the shipped one, for a registered sensor
        start = start.transferred(sensor, camera)
    return _refine(start, readings, f, usable, n_press, sensor=sensor, camera=camera, intensity=intensity,
                   provenance=prov)


def _refined(start: Calibration, logk, logc, du, g_top, u_top, **fields) -> Calibration:
    k, c = np.exp(logk), np.exp(logc)
    f = start.f / c[:, None] if start.model == "coupled" else start.f * c[:, None]
    u0 = start.u0
    if start.model == "coupled" and np.any(du):
        u0 = np.zeros((len(k), 2, 2)) if u0 is None else np.array(u0, dtype=np.float64)
        u0[:, 0, :] += du
    return replace(start, g_scale=start.g_scale * k, g_max=np.maximum(start.g_max * k, g_top),
                   u_max=np.maximum(start.u_max, u_top), f=f, u0=u0, **fields)


def _refine(start, readings, f, usable, n_press, *, sensor, camera, intensity, provenance) -> Calibration:
    from scipy.optimize import least_squares
    from scipy.sparse import coo_matrix

    n_el = readings.n_elements
    fit_el = n_press >= MIN_PRESSES_REFINE
    t_idx, e_idx = np.nonzero(usable & fit_el)
    truth = f[t_idx, e_idx]
    shear_el = np.zeros(n_el, bool)
    shear_el[e_idx[np.any(truth[:, :2] != 0, axis=1)]] = True
    g_top = np.where(fit_el, np.max(np.where(usable, readings.G, 0.0), axis=0), 0.0)
    u_top = np.where(fit_el, np.max(np.where(usable, np.hypot(*np.moveaxis(readings.u, -1, 0)), 0.0), axis=0),
                     0.0)
    k_ids, c_ids = np.flatnonzero(fit_el), np.flatnonzero(shear_el)
    # coupled: the zero-shear centroid moves with the element's own brightness gradient (its rim light),
    # so each element pressed at least MIN_PRESSES_REFINE times gets a constant shift of it too
    d_ids = k_ids if start.model == "coupled" else np.zeros(0, np.int64)
    n_k, n_c, n_d = k_ids.size, c_ids.size, 2 * d_ids.size
    logk, logc, du = np.zeros(n_el), np.zeros(n_el), np.zeros((n_el, 2))
    if n_k:
        def unpack(x):
            lk, lc, d = np.zeros(n_el), np.zeros(n_el), np.zeros((n_el, 2))
            lk[k_ids], lc[c_ids] = x[:n_k], x[n_k:n_k + n_c]
            d[d_ids] = x[n_k + n_c:].reshape(-1, 2)
            return lk, lc, d

        def resid(x):
            est, _ = _refined(start, *unpack(x), g_top, u_top).forces(readings)
            return (est[t_idx, e_idx] - truth).ravel()

        col_k = np.full(n_el, -1)
        col_k[k_ids] = np.arange(n_k)
        col_c = np.full(n_el, -1)
        col_c[c_ids] = n_k + np.arange(n_c)
        col_d = np.full(n_el, -1)
        col_d[d_ids] = n_k + n_c + 2 * np.arange(d_ids.size)
        rows = np.arange(3 * t_idx.size)
        el = np.repeat(e_idx, 3)
        # a shift moves Fx and Fy (and Fz through the brightness gradient): every row of its element
        rr = np.r_[rows, rows[col_c[el] >= 0], np.repeat(rows[col_d[el] >= 0], 2)]
        dcols = col_d[el][col_d[el] >= 0]
        cc = np.r_[col_k[el], col_c[el][col_c[el] >= 0], np.stack([dcols, dcols + 1], 1).ravel()]
        n_x = n_k + n_c + n_d
        sparsity = coo_matrix((np.ones(rr.size), (rr, cc)), shape=(rows.size, n_x))
        lo = np.r_[np.full(n_k + n_c, np.log(0.2)), np.full(n_d, -MAX_CENTROID_SHIFT_MM)]
        hi = np.r_[np.full(n_k + n_c, np.log(5.0)), np.full(n_d, MAX_CENTROID_SHIFT_MM)]
        sol = least_squares(resid, np.zeros(n_x), jac_sparsity=sparsity, method="trf", bounds=(lo, hi),
                            x_scale=np.r_[np.full(n_k + n_c, 0.1), np.full(n_d, 0.01)])
        logk, logc, du = unpack(sol.x)
    kept = np.flatnonzero(~fit_el)
    if kept.size:
        warnings.warn(f"{_elements(kept, n_press)} presses: fewer than the {MIN_PRESSES_REFINE} a refinement "
                      f"needs, so these keep the starting calibration's curves", OptitactWarning, stacklevel=3)
    cal = _refined(start, logk, logc, du, g_top, u_top, sensor=sensor, camera=camera)
    est, _ = cal.forces(readings)
    res = {k: np.array(start.residuals.get(k, np.zeros(n_el)), dtype=float).copy() for k in ("fx", "fy", "fz")}
    res["n"] = np.array(start.residuals.get("n", np.zeros(n_el)), dtype=int).copy()
    for e in k_ids:
        m = usable[:, e]
        err = est[m, e] - f[m, e]
        res["fx"][e], res["fy"][e], res["fz"][e] = np.sqrt(np.mean(err**2, axis=0))
        res["n"][e] = int(m.sum())
    prov = provenance | {"fit": "refined", "start": start.fingerprint,
                         "start_provenance": start.provenance, "refined_elements": k_ids.tolist(),
                         "kept_elements": kept.tolist(), "gain": np.exp(logk).round(6).tolist(),
                         "shear_scale": np.exp(logc).round(6).tolist(),
                         "centroid_shift_mm": du.round(6).tolist()}
    return replace(cal, residuals=res, provenance=prov,
                   intensity=start.intensity if intensity is None else intensity)
