"""Fitting a calibration to measured presses, from scratch or by refining a starting calibration.

:func:`fit_from_frames` reads frames of presses and the gauge's CSV
(:func:`~optitact.calib.gauge.measure_presses`) and fits a
:class:`~optitact.calib.fit.Calibration` to them with :func:`fit_presses`, either
from scratch or by refining a starting calibration (the shipped synthetic
one, ``start="default"``).

Refinement
----------
From scratch every element needs at least ``MIN_PRESSES_SCRATCH`` presses
(the cubic ``g(G)``, its brightness gradient and the shear curve of
:meth:`Calibration.fit <optitact.calib.fit.Calibration.fit>`). Starting from a
calibration, each element with at least ``MIN_PRESSES_REFINE`` presses may
change in three groups of parameters (:data:`GROUPS`), fitted by least
squares over its presses:

* ``gain``: a gain ``k`` on G (``g_scale`` and ``g_max`` times ``k``: ``Fz =
  g_start(G / k, u)``; real elements differ in brightness);
* ``shear_scale``: a scale ``c`` on the shear curve (``F_t = c f_start``);
* ``centroid_shift`` (coupled model): a shift of its zero-shear centroid
  (``u0``; the element's own brightness gradient across its cones, up to
  ``MAX_CENTROID_SHIFT_MM``).

A group is kept for an element only where it beats what the element has
without it on presses the fit did not see. Each element's presses are split
into :data:`REFINE_FOLDS` folds (one press per fold below that: leave one
out; seeded, the sheared presses spread over the folds first); the groups
are tried in the order above, each fitted on all folds but one and scored on
the one left out, in turn, and kept where it beats what the element had
(the start's curves, then the groups kept before) beyond chance: its
held-out squared error (Fx, Fy and Fz, N²) falls, and its held-out error
vectors shorten, relative to their length, by more than :data:`EVIDENCE`
standard errors of that mean (a paired test over the element's presses, its
sheared ones for the shear scale; a group that only fits the noise rarely
passes it, and with few presses a real but small change may not either). A
group needs
:data:`MIN_PRESSES_TO_TELL` presses of the element (sheared ones for the
shear scale) to be tried at all; an element with some but fewer keeps the
start's values for it, and a warning names it. The kept groups are then
fitted on all the presses. The provenance records what was kept
(``kept_groups``, ``too_few_to_tell``, ``untested_groups``) and the
held-out figures (``held_out``: RMSE per axis of the start and of the
refinement over the same held-out presses; the selection saw them too, so
the refined figure is slightly optimistic, while a fresh ``calibrate test``
is not). Elements with fewer than ``MIN_PRESSES_REFINE`` presses keep the
starting curves (a warning names them). A refined element's fitted range
grows to the largest G and shift seen in its presses. A start made for
another sensor or camera is transferred to the presses' first
(:meth:`Calibration.transferred <optitact.calib.fit.Calibration.transferred>`),
so a registered sensor's element gains start the refinement.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence
from dataclasses import replace

import numpy as np

from optitact._validate import integer
from optitact.optics.ccd import IntensityScale
from optitact.errors import InputError, OptitactWarning, ShapeError
from optitact.pipeline.readings import Readings
from optitact.optics.sensor import DomeSensor

from optitact.calib.curves import MODELS
from optitact.calib.document import PIPELINE_KEYS
from optitact.calib.fit import Calibration
from optitact.calib.gauge import Presses, check_presses, measure_presses

__all__ = ["EVIDENCE", "GAUGE_NOISE", "GROUPS", "METHODS", "MIN_FLOOR_N", "fit_element_shapes",
           "MIN_PRESSES_REFINE",
           "MIN_PRESSES_SCRATCH", "MIN_PRESSES_TO_TELL",
           "REFINE_FOLDS", "fit_from_frames", "fit_presses", "error_model_of_totals", "untransferred"]

#: How a start is refined (:func:`fit_presses`): each element's own shape, or the earlier groups.
METHODS = ("shapes", "groups")
#: The gauge's noise, a fraction of the force it reads.
GAUGE_NOISE = 0.01
#: The smallest floor (N) of an error model fitted to held-out presses.
MIN_FLOOR_N = 1e-4
#: Presses per element a fit from scratch needs (``Calibration.fit``'s usable-sample minimum).
MIN_PRESSES_SCRATCH = 8
#: Presses per element a refinement of a starting calibration needs (else the element keeps its curves).
MIN_PRESSES_REFINE = 2
#: Largest shift (mm) of an element's zero-shear centroid a refinement accepts.
MAX_CENTROID_SHIFT_MM = 0.5
#: The range a refinement's gain and shear scale may take.
BOUNDS = (0.2, 5.0)
#: The groups of parameters a refinement may change per element, in the order they are tried.
GROUPS = ("gain", "shear_scale", "centroid_shift")
#: Presses an element needs before a group is tried (sheared presses for the shear scale).
MIN_PRESSES_TO_TELL = {"gain": MIN_PRESSES_REFINE, "shear_scale": 2, "centroid_shift": 3}
#: Folds of the held-out test of a refinement (leave-one-out for an element with fewer presses).
REFINE_FOLDS = 5
#: Standard errors by which a group must shorten an element's held-out errors (relative) to be kept, per
#: group. A gain moves every press of the element along its normal curve, and a real one (a brightness
#: the registration did not catch) shows in every press; a shear scale or centroid shift shows only in
#: the sheared part of few presses, where chance improvements are common enough that at 1 standard
#: error they would often be kept on a start that is already right.
EVIDENCE = {"gain": 1.0, "shear_scale": 2.0, "centroid_shift": 2.0}
_GROUP_NAMES = {"gain": "gain", "shear_scale": "shear scale", "centroid_shift": "centroid shift"}
_COUNTED = {"gain": "presses", "shear_scale": "sheared presses", "centroid_shift": "presses"}


def starting_calibration(start) -> Calibration | None:
    """The calibration ``start`` names: None, a :class:`Calibration`, ``"default"`` or a calibration file."""
    if start is None or isinstance(start, Calibration):
        return start
    if isinstance(start, str) and start == "default":
        from optitact.calib.shipped import default_calibration

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


def fit_measured(p: Presses, pipeline, *, model, start, forces, method: str = "shapes") -> Calibration:
    """:func:`fit_presses` on measured presses, with the pipeline's sensor, camera, options and scale."""
    options = {k: v for k, v in pipeline.options().items() if k in PIPELINE_KEYS and k != "method"}
    bits = pipeline.readings_bits or pipeline.bits or 8
    return fit_presses(p.readings, p.forces, pressed=p.pressed, sensor=pipeline.sensor, camera=pipeline.camera,
                       pipeline_options=options, model=model, start=start, method=method,
                       intensity=start.intensity if start is not None else IntensityScale(bits=bits),
                       provenance={"frames": len(p.sources), "forces": str(forces),
                                   "presses": int(p.pressed.sum())})


def default_pipeline(frames):
    """A pipeline of ``DomeSensor.default()`` and a ``FisheyeCamera`` of the first frame's size."""
    from optitact.optics.camera import FisheyeCamera
    from optitact.io.frames import expand_sources, iter_frames
    from optitact.pipeline.frame_pipeline import Pipeline

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
                intensity: IntensityScale | None = None, provenance: dict | None = None,
                seed: int = 0, method: str = "shapes", gauge_noise: float = GAUGE_NOISE,
                extra=None) -> Calibration:
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
        this calibration's curves per element (a gain on G, a scale on the
        shear curve and a shift of the zero-shear centroid, each kept only
        where it beats the start on held-out presses; see the module
        docstring); elements with fewer than ``MIN_PRESSES_REFINE`` presses
        keep its curves. A start made for
        another sensor or camera (e.g. the shipped one, for a registered
        sensor) is first transferred to ``sensor`` and ``camera``
        (:meth:`Calibration.transferred`: its gains relative to the start's
        sensor folded into the G scales), so the refinement starts close.
    intensity : IntensityScale, optional
        Of the frames (default: the start's, else 8-bit).
    provenance : dict, optional
        Stored, with what the fit adds (presses per element; refining: the
        elements refined and kept, the parameters, the groups kept per
        element and the held-out figures, see the module docstring).
    seed : int
        Of the refinement's folds (the same presses and seed give the same calibration).
    method : {"shapes", "groups"}
        How a start is refined. ``"shapes"`` (default): every element's own
        curve shape, shrunk toward the start by a hierarchical prior whose
        strength the presses' cross-validation chooses
        (:mod:`optitact.calib.element_shapes`); the held-out predictions give
        the calibration its :class:`~optitact.calib.error_model.ErrorModel`,
        so ``process --stderr`` is honest with no validation step.
        ``"groups"``: the earlier refinement (a gain, a shear scale and a
        centroid shift per element, each kept where it beats the start; see
        the module docstring).
    gauge_noise : float
        The gauge's noise, a fraction of the force it reads (default 1 %):
        weighs the presses against each other and against force/torque frames.
    extra : Observations, optional
        ``"shapes"`` only: more observations fitted with the presses (e.g.
        force/torque frames, :func:`optitact.calib.element_shapes.wrench_observations`).

    Raises
    ------
    InputError
        From scratch, elements with too few presses (the message names them,
        with their counts and what they need, and suggests ``start``); a
        start of another model or number of elements; see also
        :meth:`Calibration.fit`; no press with Fz > 0; a force a press cannot
        have (:func:`~optitact.calib.gauge.check_presses`).
    ShapeError
        ``forces`` or ``pressed`` do not match the readings.

    Warns
    -----
    OptitactWarning
        Refining: elements with too few presses keep the start's curves;
        elements with too few presses to tell whether a group helps keep the
        start's values for it; a gain or shear scale at the bounds of
        :data:`BOUNDS` (the gauge's units are the usual cause).
    """
    f, pressed = check_presses(readings, forces, pressed)
    if not np.any(f[pressed][:, 2] > 0):
        raise InputError("no press with Fz > 0: nothing to fit from (every pressed sample has Fz = 0, or "
                         "none is pressed)")
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
    if method not in METHODS:
        raise InputError(f"method must be one of {METHODS}, got {method!r}")
    if method == "shapes":
        return fit_element_shapes(start, readings, f, usable, n_press, sensor=sensor, camera=camera,
                                  intensity=intensity, provenance=prov, seed=integer(seed, "seed", minimum=0),
                                  gauge_noise=gauge_noise, extra=extra)
    return _refine(start, readings, f, usable, n_press, sensor=sensor, camera=camera, intensity=intensity,
                   provenance=prov, seed=integer(seed, "seed", minimum=0))


def _refined(start: Calibration, logk, logc, du, g_top, u_top, **fields) -> Calibration:
    k, c = np.exp(logk), np.exp(logc)
    f = start.f / c[:, None] if start.model == "coupled" else start.f * c[:, None]
    u0 = start.u0
    if start.model == "coupled" and np.any(du):
        u0 = np.zeros((len(k), 2, 2)) if u0 is None else np.array(u0, dtype=np.float64)
        u0[:, 0, :] += du
    return replace(start, g_scale=start.g_scale * k, g_max=np.maximum(start.g_max * k, g_top),
                   u_max=np.maximum(start.u_max, u_top), f=f, u0=u0, **fields)


def _calibration(start: Calibration, active: dict, logs, g_top, u_top, **fields) -> Calibration:
    """The start with fitted parameters ``logs``; the range grows to the readings of refined elements only."""
    refined = active["gain"] | active["shear_scale"] | active["centroid_shift"]
    return _refined(start, *logs, np.where(refined, g_top, 0.0), np.where(refined, u_top, 0.0), **fields)


def _isolated(cal: Calibration, readings: Readings) -> Readings:
    """``readings`` with each element's G as it would read alone (``cal``'s cross-talk undone).

    A refinement fits its per-element parameters to these with the cross-talk held still (the
    neighbours' loads are those ``cal`` reads), which spares the joint inversion in every step.
    """
    if cal.crosstalk is None:
        return readings
    fz = cal.forces(readings)[0][..., 2]
    G = readings.G * np.exp(fz @ cal.crosstalk.matrix(cal.sensor).T)
    return Readings(G, readings.u, readings.contact, readings.saturated)


def _packed(readings: Readings, t_idx, e_idx) -> tuple[Readings, np.ndarray]:
    """The samples ``t_idx, e_idx`` as few rows of readings: each element's samples down its column.

    Without cross-talk every element is read on its own, so a calibration's forces on these rows are
    its forces on the samples (at ``rows, e_idx``) for a fraction of the work. Returns the readings and
    each sample's row.
    """
    order = np.argsort(e_idx, kind="stable")
    starts = np.searchsorted(e_idx[order], e_idx[order])
    rows = np.empty_like(e_idx)
    rows[order] = np.arange(e_idx.size) - starts
    shape = (int(rows.max(initial=-1)) + 1, readings.n_elements)
    G, u, contact = np.zeros(shape), np.zeros((*shape, 2)), np.zeros(shape, bool)
    G[rows, e_idx], u[rows, e_idx] = readings.G[t_idx, e_idx], readings.u[t_idx, e_idx]
    contact[rows, e_idx] = True
    return Readings(G, u, contact, np.zeros(shape, bool)), rows


def _fit_groups(start: Calibration, readings: Readings, t_idx, e_idx, truth, active: dict, g_top, u_top):
    """Least squares of the ``active`` groups' parameters (per element) to the samples ``t_idx, e_idx``.

    ``start`` has no cross-talk and ``readings`` are :func:`_isolated`. Returns ``(log gain, log shear
    scale, centroid shift)`` per element, 0 where a group is not active.
    """
    from scipy.optimize import least_squares
    from scipy.sparse import coo_matrix

    n_el = readings.n_elements
    logk, logc, du = np.zeros(n_el), np.zeros(n_el), np.zeros((n_el, 2))
    k_ids, c_ids, d_ids = (np.flatnonzero(active[g]) for g in GROUPS)
    n_k, n_c, n_d = k_ids.size, c_ids.size, 2 * d_ids.size
    n_x = n_k + n_c + n_d
    if n_x == 0 or t_idx.size == 0:
        return logk, logc, du
    packed, rows_of = _packed(readings, t_idx, e_idx)

    def unpack(x):
        lk, lc, d = np.zeros(n_el), np.zeros(n_el), np.zeros((n_el, 2))
        lk[k_ids], lc[c_ids] = x[:n_k], x[n_k:n_k + n_c]
        d[d_ids] = x[n_k + n_c:].reshape(-1, 2)
        return lk, lc, d

    def resid(x):
        est, _ = _calibration(start, active, unpack(x), g_top, u_top).forces(packed)
        return (est[rows_of, e_idx] - truth).ravel()

    col_k = np.full(n_el, -1)
    col_k[k_ids] = np.arange(n_k)
    col_c = np.full(n_el, -1)
    col_c[c_ids] = n_k + np.arange(n_c)
    col_d = np.full(n_el, -1)
    col_d[d_ids] = n_k + n_c + 2 * np.arange(d_ids.size)
    rows = np.arange(3 * t_idx.size)
    el = np.repeat(e_idx, 3)
    # a gain moves all three axes, a scale the shear, a shift Fx and Fy (and Fz through the brightness
    # gradient): every row of its element
    rr = np.r_[rows[col_k[el] >= 0], rows[col_c[el] >= 0], np.repeat(rows[col_d[el] >= 0], 2)]
    dcols = col_d[el][col_d[el] >= 0]
    cc = np.r_[col_k[el][col_k[el] >= 0], col_c[el][col_c[el] >= 0], np.stack([dcols, dcols + 1], 1).ravel()]
    sparsity = coo_matrix((np.ones(rr.size), (rr, cc)), shape=(rows.size, n_x))
    lo = np.r_[np.full(n_k + n_c, np.log(BOUNDS[0])), np.full(n_d, -MAX_CENTROID_SHIFT_MM)]
    hi = np.r_[np.full(n_k + n_c, np.log(BOUNDS[1])), np.full(n_d, MAX_CENTROID_SHIFT_MM)]
    sol = least_squares(resid, np.zeros(n_x), jac_sparsity=sparsity, method="trf", bounds=(lo, hi),
                        x_scale=np.r_[np.full(n_k + n_c, 0.1), np.full(n_d, 0.01)])
    return unpack(sol.x)


def _folds(e_idx, sheared, n_el: int, seed) -> np.ndarray:
    """Each sample's fold: per element ``REFINE_FOLDS`` folds (one per sample below that), seeded.

    The element's sheared samples are dealt over the folds first, so that each fold's training keeps some.
    """
    rng = np.random.default_rng(seed)
    fold = np.zeros(e_idx.size, np.int64)
    for e in range(n_el):
        idx = rng.permutation(np.flatnonzero(e_idx == e))
        idx = idx[np.argsort(~sheared[idx], kind="stable")]
        fold[idx] = np.arange(idx.size) % max(1, min(REFINE_FOLDS, idx.size))
    return fold


def _held_out(start, readings, iso, t_idx, e_idx, truth, fold, active, g_top, u_top) -> np.ndarray:
    """Every sample's forces fitted without its fold (``active`` groups), ``(n, 3)``."""
    pred = np.zeros_like(truth)
    free = replace(start, crosstalk=None)
    for k in range(int(fold.max()) + 1):
        train, test = fold != k, fold == k
        logs = _fit_groups(free, iso, t_idx[train], e_idx[train], truth[train], active, g_top, u_top)
        cal = _calibration(start, active, logs, g_top, u_top)
        pred[test] = cal.forces(readings)[0][t_idx[test], e_idx[test]]
    return pred


def _beats(before, after, e_idx, tested, n_el: int, evidence: float) -> np.ndarray:
    """Per element: whether the held-out errors ``after`` (n, 3) beat ``before`` beyond chance.

    Yes where the element's squared error falls over all its samples and, over its ``tested``
    samples, the relative shortening of the error vector, ``(|before| - |after|) / max(|before|,
    |after|)`` (in [-1, 1], whatever the size of the press), is above 0 by more than
    ``evidence`` standard errors of its mean (:data:`EVIDENCE` of the group).
    """
    drop = np.bincount(e_idx, weights=np.sum(before**2, axis=1) - np.sum(after**2, axis=1), minlength=n_el)
    lb, la = np.linalg.norm(before, axis=1), np.linalg.norm(after, axis=1)
    top = np.maximum(lb, la)
    rel = np.divide(lb - la, top, out=np.zeros_like(top), where=top > 0)
    e, rel = e_idx[tested], rel[tested]
    n_samples = np.bincount(e, minlength=n_el)
    n = np.maximum(n_samples, 1)
    mean = np.bincount(e, weights=rel, minlength=n_el) / n
    var = np.bincount(e, weights=(rel - mean[e]) ** 2, minlength=n_el) / np.maximum(n - 1, 1)
    return (n_samples >= 2) & (drop > 0) & (mean > evidence * np.sqrt(var / n))


def _rmse(err) -> dict:
    return dict(zip(("fx", "fy", "fz"), np.sqrt(np.mean(err**2, axis=0)).round(9).tolist(), strict=True))


def _refine(start, readings, f, usable, n_press, *, sensor, camera, intensity, provenance, seed) -> Calibration:
    n_el = readings.n_elements
    fit_el = n_press >= MIN_PRESSES_REFINE
    t_idx, e_idx = np.nonzero(usable & fit_el)
    truth = f[t_idx, e_idx]
    sheared = np.any(truth[:, :2] != 0, axis=1)
    n_sheared = np.bincount(e_idx[sheared], minlength=n_el)
    g_top = np.max(np.where(usable, readings.G, 0.0), axis=0)
    u_top = np.max(np.where(usable, np.hypot(*np.moveaxis(readings.u, -1, 0)), 0.0), axis=0)
    groups = GROUPS if start.model == "coupled" else GROUPS[:2]
    counts = {"gain": n_press, "shear_scale": n_sheared, "centroid_shift": n_press}
    active = {g: np.zeros(n_el, bool) for g in GROUPS}
    too_few, untested = {}, {}
    best = start.forces(readings)[0][t_idx, e_idx]
    iso = _isolated(start, readings)
    start_err = best - truth
    if t_idx.size:
        fold = _folds(e_idx, sheared, n_el, seed)
        for g in groups:
            tell = fit_el & (counts[g] >= MIN_PRESSES_TO_TELL[g])
            untested[g] = np.flatnonzero(fit_el & ~tell).tolist()
            too_few[g] = np.flatnonzero(fit_el & ~tell & (counts[g] > 0)).tolist()
            if not tell.any():
                continue
            trial = active | {g: tell}
            pred = _held_out(start, readings, iso, t_idx, e_idx, truth, fold, trial, g_top, u_top)
            # a shear scale is seen in sheared presses only: they alone tell whether it helps
            tested = sheared if g == "shear_scale" else np.ones(e_idx.size, bool)
            keep = tell & _beats(best - truth, pred - truth, e_idx, tested, n_el, EVIDENCE[g])
            active[g] = keep
            best[keep[e_idx]] = pred[keep[e_idx]]
    free = replace(start, crosstalk=None)
    logk, logc, du = _fit_groups(free, iso, t_idx, e_idx, truth, active, g_top, u_top)
    cal = _calibration(start, active, (logk, logc, du), g_top, u_top, sensor=sensor, camera=camera)
    if start.crosstalk is not None:  # once more, with the neighbours' loads the refinement reads
        iso = _isolated(cal, readings)
        logk, logc, du = _fit_groups(free, iso, t_idx, e_idx, truth, active, g_top, u_top)
        cal = _calibration(start, active, (logk, logc, du), g_top, u_top, sensor=sensor, camera=camera)
    _warn_refinement(fit_el, n_press, too_few, active, logk, logc, counts)
    est, _ = cal.forces(readings)
    res = {k: np.array(start.residuals.get(k, np.zeros(n_el)), dtype=float).copy() for k in ("fx", "fy", "fz")}
    res["n"] = np.array(start.residuals.get("n", np.zeros(n_el)), dtype=int).copy()
    for e in np.flatnonzero(fit_el):
        m = usable[:, e]
        err = est[m, e] - f[m, e]
        res["fx"][e], res["fy"][e], res["fz"][e] = np.sqrt(np.mean(err**2, axis=0))
        res["n"][e] = int(m.sum())
    held_out = {"samples": int(t_idx.size), "elements": int(np.unique(e_idx).size),
                "folds": f"{REFINE_FOLDS}-fold over each element's presses, leave-one-out below {REFINE_FOLDS}",
                "seed": seed, "rmse_n": {"start": _rmse(start_err), "refined": _rmse(best - truth)}}
    prov = provenance | {"fit": "refined", "start": start.fingerprint, "start_provenance": start.provenance,
                         "refined_elements": np.flatnonzero(fit_el).tolist(),
                         "kept_elements": np.flatnonzero(~fit_el).tolist(),
                         "gain": np.exp(logk).round(6).tolist(),
                         "shear_scale": np.exp(logc).round(6).tolist(),
                         "centroid_shift_mm": du.round(6).tolist(),
                         "kept_groups": {g: np.flatnonzero(active[g]).tolist() for g in groups},
                         "too_few_to_tell": {g: too_few.get(g, []) for g in groups},
                         "untested_groups": {g: untested.get(g, []) for g in groups},
                         "held_out": held_out}
    return replace(cal, residuals=res, provenance=prov,
                   intensity=start.intensity if intensity is None else intensity)


def _warn_refinement(fit_el, n_press, too_few, active, logk, logc, counts) -> None:
    """Warn of elements the refinement could not refine, or could not tell, or that hit its bounds."""
    kept = np.flatnonzero(~fit_el)
    if kept.size:
        warnings.warn(f"{_elements(kept, n_press)} presses: fewer than the {MIN_PRESSES_REFINE} a refinement "
                      f"needs, so these keep the starting calibration's curves", OptitactWarning, stacklevel=4)
    parts = [f"{_GROUP_NAMES[g]} ({MIN_PRESSES_TO_TELL[g]} {_COUNTED[g]} needed): "
             f"{_elements(np.asarray(ids), counts[g])}" for g, ids in too_few.items() if ids]
    if parts:
        warnings.warn("too few presses to tell whether refining helps, so these keep the starting "
                      "calibration's values: " + "; ".join(parts), OptitactWarning, stacklevel=4)
    for g, logs in (("gain", logk), ("shear_scale", logc)):
        at = np.flatnonzero(active[g] & (np.abs(np.abs(logs) - np.log(BOUNDS[1])) < 1e-6))
        if at.size:
            warnings.warn(f"the {_GROUP_NAMES[g]} of {_elements(at, np.exp(logs).round(3))} is at the bound "
                          f"the refinement allows ({BOUNDS[0]:g} to {BOUNDS[1]:g}): the gauge's forces are far "
                          f"from what the start reads; check the gauge's units (the header, e.g. 'Fz (mN)'), "
                          f"element numbers and frame_of_reference", OptitactWarning, stacklevel=4)


def fit_element_shapes(start: Calibration, readings: Readings, f, usable, n_press, *, sensor, camera, intensity,
                       provenance, seed, gauge_noise=GAUGE_NOISE, extra=None) -> Calibration:
    """The ``"shapes"`` refinement of :func:`fit_presses` (see there), with its cross-validated error model."""
    from optitact.calib.element_shapes import (PARAMETERS, Observations, fit_shapes, press_observations,
                                               shaped)
    from optitact.calib.error_model import MIN_SAMPLES, ErrorModel

    n_el = readings.n_elements
    t_idx, e_idx = np.nonzero(usable)
    truth = f[t_idx, e_idx]
    est0 = replace(start, shape=None).forces(readings)[0]
    noise = float(gauge_noise) * np.abs(truth)  # each component read to gauge_noise of itself
    obs = press_observations(start, readings, f, t_idx, e_idx, noise)
    fit = fit_shapes(start, Observations.concatenate([obs, extra]), seed=seed)
    cal = shaped(start, fit.theta, sensor=sensor, camera=camera)
    held = fit.held_out[:len(t_idx)]
    res_cells = held - truth
    if len(t_idx) >= MIN_SAMPLES:  # the presses' own held-out errors
        # beside the gauge's own noise: the error bars are of the true force, not of the gauge's reading
        error_model = ErrorModel.fit(res_cells, noise, held[:, 2],
                                     np.hypot(held[:, 0], held[:, 1]), element=e_idx,
                                     element_group=sensor.element_ring,
                                     source=f"{len(t_idx)} presses, held out ({FOLDS_NOTE})")
        # few presses can put all of their scatter down to the gauge: an error bar is never 0
        error_model = replace(error_model, floor_n=np.maximum(error_model.floor_n, MIN_FLOOR_N))
    elif extra is not None and start.error_model is not None:  # the curves' own, scaled to the totals
        rows = slice(len(obs.value), None)
        own = untransferred(start.error_model, start.provenance.get("transfer_tolerance", 0.0))
        error_model = error_model_of_totals(own, fit.held_out_obs[rows] - extra.value, extra.model_var,
                                            extra.noise_var,
                                            source=f"{extra.n_units} force/torque frames, held out "
                                                   f"({FOLDS_NOTE})")
    else:
        error_model = None
    est, _ = cal.forces(readings)
    res = {k: np.zeros(n_el) for k in ("fx", "fy", "fz")}
    res["n"] = np.zeros(n_el, int)
    for e in range(n_el):
        m = usable[:, e]
        if m.any():
            err = est[m, e] - f[m, e]
            res["fx"][e], res["fy"][e], res["fz"][e] = np.sqrt(np.mean(err**2, axis=0))
            res["n"][e] = int(m.sum())
    pinned = {p: np.flatnonzero(fit.pinned[:, i]).tolist() for i, p in enumerate(PARAMETERS)
              if i < (len(PARAMETERS) if start.model == "coupled" else 3)}
    prov = provenance | {"fit": "shapes", "start": start.fingerprint, "start_provenance": start.provenance,
                         "strength": fit.strength, "cv_scores": fit.scores, "pinned": pinned,
                         "normal_curve_pinned": np.flatnonzero(fit.pinned[:, 0] & fit.pinned[:, 1]).tolist(),
                         "theta": {p: fit.theta[:, i].round(6).tolist() for i, p in enumerate(PARAMETERS)},
                         "held_out": {"samples": int(len(t_idx)), "folds": FOLDS_NOTE, "seed": seed,
                                      **({"rmse_n": {"start": _rmse(est0[t_idx, e_idx] - truth),
                                                     "refined": _rmse(res_cells)}} if len(t_idx) else {})}}
    if extra is not None:  # the totals: RMS of the force and torque components, start and held out
        rows = slice(len(obs.value), None)
        start_pred = extra.mix @ extra.base.ravel()

        def rms(pred):
            r = (pred - extra.value).reshape(-1, 6)
            return {"force_n": float(np.sqrt(np.mean(r[:, :3] ** 2))),
                    "torque_nm": float(np.sqrt(np.mean(r[:, 3:] ** 2)))}

        prov["held_out"]["wrench_rms"] = {"frames": int(extra.n_units), "start": rms(start_pred),
                                          "refined": rms(fit.held_out_obs[rows])}
    return replace(cal, residuals=res, provenance=prov, error_model=error_model,
                   intensity=start.intensity if intensity is None else intensity)


FOLDS_NOTE = "5-fold over each element's presses (and over force/torque frames), seeded"


def error_model_of_totals(model, residuals, design, noise_var, *, source: str):
    """``model`` (an :class:`~optitact.calib.error_model.ErrorModel`) scaled to held-out residuals of totals.

    ``residuals`` (m,) of observations that sum several elements' forces (a force/torque sensor's
    components); ``design`` (m, 6) their variance per unit of each part of an error model (the floor and
    the part relative to Fz, of Fx, Fy and Fz: :attr:`Observations.model_var
    <optitact.calib.element_shapes.Observations.model_var>`); ``noise_var`` (m,) the sensor's own. The
    residuals cannot tell the elements' axes apart well (Fz dominates every total), so the model's
    shape is kept and one factor ``k`` (within ``[0.1, 10]``) solves ``mean(r^2 / (k^2 v + noise_var)) =
    1``, ``v`` what ``model`` gives each observation.
    """
    from scipy.optimize import brentq

    r2 = np.asarray(residuals, dtype=np.float64) ** 2
    v = np.asarray(design, dtype=np.float64) @ np.concatenate([model.floor_n**2, model.relative**2])
    nv = np.maximum(np.asarray(noise_var, dtype=np.float64), 1e-18)

    def excess(log_k):
        return float(np.mean(r2 / (np.exp(2 * log_k) * v + nv))) - 1.0

    lo, hi = np.log(0.1), np.log(10.0)
    k = np.exp(lo if excess(lo) <= 0 else hi if excess(hi) >= 0 else brentq(excess, lo, hi, xtol=1e-6))
    return replace(model, floor_n=model.floor_n * k, relative=model.relative * k, shear=model.shear * k,
                   shear2=model.shear2 * k, samples=max(int(len(r2)), 1), source=source)


def untransferred(model, tolerance: float):
    """``model`` without what a transfer added for another sensor's elements (``tolerance`` relative).

    :meth:`Calibration.transferred <optitact.calib.fit.Calibration.transferred>` adds it; a fit to
    that sensor removes it.
    """
    if not tolerance:
        return model
    tol = np.array([0.0, 0.0, tolerance])
    return replace(model, relative=np.sqrt(np.maximum(model.relative**2 - tol**2, 0.0)),
                   shear=np.sqrt(np.maximum(model.shear**2 - (tolerance - tol) ** 2, 0.0)))
