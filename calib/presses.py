"""Calibration from measured presses: frames and a force gauge's readings per frame and element.

A real sensor is calibrated by pressing its elements with a force gauge and
recording a frame per press. :func:`fit_from_frames` reads those frames with
the normal pipeline (:func:`optitact.batch.process_files`), reads the gauge's
CSV (:func:`read_presses`) and fits a :class:`~optitact.calib.Calibration`
(:func:`fit_presses`), either from scratch or by refining a starting
calibration (the shipped synthetic one, ``start="default"``).
:func:`evaluate_calibration` and :func:`press_report` give the held-out
report; :func:`press_curve` measures how the held-out error falls with the
number of presses per element, from scratch and refined.

The gauge CSV
-------------
One row per frame and pressed element, columns found by name (any order, any
case, units in brackets such as ``Fz (N)``, a byte-order mark, ``,`` ``;`` or
tab as :func:`optitact.io.csv_rows` reads them)::

    frame,element,fx,fy,fz[,frame_of_reference]

``frame`` is the frame's source as ``optitact process`` names it in its
``source`` column (``press_001.png``, or ``clip.avi#12`` for frame 12 of a
video or ``.npy`` stack) or a 0-based index into all the frames in the order
they are read (baseline frames included). ``element`` is the element index.
``fx, fy, fz`` are in N, element-local (``z`` the outward normal, ``fz > 0``
pressing) unless ``frame_of_reference`` reads ``global`` (the sensor frame:
converted with :func:`optitact.forces.local_from_global`). The elements of a
listed frame that have no row are unloaded, and so is every element of a
frame that is not listed: those no-load samples are used where the pipeline
sees contact anyway (a zero-force sample for the fit, and in the report's
``unloaded`` errors); a no-load frame also serves as the baseline
(``baseline_frames``). A *press* is one row: one frame of one element under a
known force; the usual protocol presses one element at a time, normal then
inclined, and frames pressing several elements at once (mixed loads) work
the same way.

Refinement
----------
From scratch every element needs at least ``MIN_PRESSES_SCRATCH`` presses
(the cubic ``g(G)``, its brightness gradient and the shear curve of
:meth:`Calibration.fit <optitact.calib.Calibration.fit>`). Starting from a
calibration, each element with at least ``MIN_PRESSES_REFINE`` presses gets
two factors fitted by least squares over its presses: a gain ``k`` on G
(``g_scale`` and ``g_max`` times ``k``: ``Fz = g_start(G / k, u)``; real
elements differ in brightness) and a scale ``c`` on the shear curve (``F_t =
c f_start``; fitted where a press has shear, else 1). Elements with fewer
presses keep the starting curves (a warning names them). The fitted range
grows to the largest G and shift seen in the presses.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from optitact._validate import check_type, integer
from optitact.ccd import IntensityScale
from optitact.errors import InputError, OptitactWarning, ShapeError
from optitact.io import column_key, csv_numbers, csv_rows
from optitact.readings import Readings
from optitact.sensor import DomeSensor

from .fit import MODELS, PIPELINE_KEYS, Calibration

__all__ = ["MIN_PRESSES_REFINE", "MIN_PRESSES_SCRATCH", "Presses", "evaluate_calibration", "fit_from_frames",
           "fit_presses", "measure_presses", "press_curve", "press_report", "read_presses"]

#: Presses per element a fit from scratch needs (``Calibration.fit``'s usable-sample minimum).
MIN_PRESSES_SCRATCH = 8
#: Presses per element a refinement of a starting calibration needs (else the element keeps its curves).
MIN_PRESSES_REFINE = 2
_REFERENCES = ("local", "global")
_COLUMNS = ("frame", "element", "fx", "fy", "fz")


@dataclass(frozen=True, eq=False)
class Presses:
    """Frames read by the pipeline, with the gauge's forces (what :func:`measure_presses` returns).

    Attributes
    ----------
    sources : list of str
        Each frame's source (as ``optitact process`` names it).
    readings : Readings
        ``(T, E)`` readings of the frames.
    forces : (T, E, 3) ndarray
        Element-local forces (N); 0 for elements without a row.
    pressed : (T, E) bool ndarray
        The gauge CSV has a row for this frame and element.
    """

    sources: list
    readings: Readings
    forces: np.ndarray
    pressed: np.ndarray


# ---------------------------------------------------------------------------- the gauge CSV
def _frame_index(cell: str, sources: Sequence[str], by_name: dict, path, lineno: int, col: int) -> int:
    """The frame a ``frame`` cell names: a source name or a 0-based index."""
    if cell in by_name:
        hits = by_name[cell]
        if len(hits) > 1:
            raise InputError(f"{path}, line {lineno}, column {col}: frame {cell!r} names {len(hits)} frames "
                             f"(frames {', '.join(map(str, hits[:5]))}: files of the same name in different "
                             f"folders); name the frame by its 0-based index instead")
        return hits[0]
    try:
        k = float(cell)
    except ValueError:
        k = math.nan
    if k.is_integer() and 0 <= k < len(sources):
        return int(k)
    shown = ", ".join(repr(s) for s in sources[:3]) + (", ..." if len(sources) > 3 else "")
    raise InputError(f"{path}, line {lineno}, column {col}: frame {cell!r} is not one of the {len(sources)} "
                     f"frames: name it as the 'source' column of optitact process does ({shown}) or by its "
                     f"0-based index 0..{len(sources) - 1}")


def read_presses(path: str | os.PathLike, sources: Sequence[str], sensor: DomeSensor) -> tuple[np.ndarray,
                                                                                               np.ndarray]:
    r"""Read a force gauge's CSV: element-local forces per frame and element.

    Parameters
    ----------
    path : path-like
        The CSV (see the module docstring for its columns).
    sources : sequence of str
        The frames' sources in order (:attr:`optitact.batch.ProcessedFrames.sources`).
    sensor : DomeSensor

    Returns
    -------
    forces : (T, E, 3) float64 ndarray
        Element-local forces (N); 0 where there is no row.
    pressed : (T, E) bool ndarray
        Where there is a row.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ShapeError
        No header naming ``frame, element, fx, fy, fz``, a row of the wrong width, no rows.
    InputError
        A frame or element that does not exist, a force that is not a finite
        number (NaN), a frame listed twice for one element, an unknown
        ``frame_of_reference`` (each message gives the line).

    Examples
    --------
    >>> import pathlib, tempfile
    >>> from optitact import DomeSensor
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "gauge.csv"
    >>> _ = p.write_text("Frame;Element;Fx (N);Fy (N);Fz (N)\npress_1.png;3;0.1;0;0.5\n1;0;0;0;0.2\n")
    >>> f, pressed = read_presses(p, ["noload.png", "press_1.png"], DomeSensor.default())
    >>> f.shape, f[1, 3].tolist(), f[1, 0].tolist(), int(pressed.sum())
    ((2, 41, 3), [0.1, 0.0, 0.5], [0.0, 0.0, 0.2], 2)
    """
    from optitact.forces import local_from_global

    check_type(sensor, DomeSensor, "sensor")
    sources = [str(s) for s in sources]
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"force gauge file not found: {path}")
    rows = csv_rows(path)
    if not rows:
        raise ShapeError(f"{path}: empty; expected a header {', '.join(_COLUMNS)} and one row per frame and "
                         f"pressed element")
    header_line, first = rows[0]
    header = [column_key(c) for c in first]
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        raise ShapeError(f"{path}, line {header_line}: no column {', '.join(missing)} in the header {first}; "
                         f"expected the columns {', '.join(_COLUMNS)} (any order, units like 'Fz (N)'), "
                         f"optionally frame_of_reference (local or global)")
    col = {k: header.index(k) for k in (*_COLUMNS, "frame_of_reference") if k in header}
    n_t, n_el = len(sources), sensor.n_elements
    by_name: dict[str, list[int]] = {}
    for i, s in enumerate(sources):
        by_name.setdefault(s, []).append(i)
    forces = np.zeros((n_t, n_el, 3))
    pressed = np.zeros((n_t, n_el), bool)
    is_global = np.zeros((n_t, n_el), bool)
    line_of: dict[tuple[int, int], int] = {}
    if len(rows) < 2:
        raise ShapeError(f"{path}: a header and no presses; expected one row per frame and pressed element")
    for lineno, cells in rows[1:]:
        if len(cells) != len(header):
            raise ShapeError(f"{path}, line {lineno}: expected {len(header)} columns, got {len(cells)}")
        t = _frame_index(cells[col["frame"]], sources, by_name, path, lineno, col["frame"] + 1)
        cell = cells[col["element"]]
        try:
            e = float(cell)
        except ValueError:
            e = math.nan
        if not (e.is_integer() and 0 <= e < n_el):
            raise InputError(f"{path}, line {lineno}, column {col['element'] + 1}: element {cell!r} does not "
                             f"exist (the sensor's elements are 0..{n_el - 1})")
        e = int(e)
        if (t, e) in line_of:
            raise InputError(f"{path}, line {lineno}: frame {sources[t]!r} is listed twice for element {e} "
                             f"(also on line {line_of[t, e]}); one row per frame and element")
        line_of[t, e] = lineno
        forces[t, e] = [csv_numbers([cells[col[k]]], path, lineno, first_column=col[k] + 1)[0]
                        for k in ("fx", "fy", "fz")]
        pressed[t, e] = True
        if "frame_of_reference" in col:
            ref = cells[col["frame_of_reference"]].strip().lower() or "local"
            if ref not in _REFERENCES:
                raise InputError(f"{path}, line {lineno}, column {col['frame_of_reference'] + 1}: "
                                 f"frame_of_reference must be local or global, got "
                                 f"{cells[col['frame_of_reference']]!r}")
            is_global[t, e] = ref == "global"
    for t in np.flatnonzero(is_global.any(axis=1)):
        local = local_from_global(sensor, forces[t])
        forces[t, is_global[t]] = local[is_global[t]]
    return forces, pressed


# ---------------------------------------------------------------------------- frames -> presses
def measure_presses(frames: Sequence[str | os.PathLike], forces: str | os.PathLike, *, pipeline,
                    baseline=None, baseline_frames: int = 1, progress: bool = False) -> Presses:
    """Read frames with ``pipeline`` and the gauge CSV ``forces`` that goes with them.

    Parameters
    ----------
    frames : sequence of path-like
        Image files, folders, ``.npy`` stacks or videos
        (:func:`optitact.frames.expand_sources`), read in order.
    forces : path-like
        The gauge CSV (see the module docstring).
    pipeline : Pipeline
    baseline : array_like, optional
        No-load frame(s); else the mean of the first ``baseline_frames``
        frames (which must not be listed in the CSV), as in
        :func:`optitact.batch.process_files`.
    baseline_frames : int
    progress : bool

    Raises
    ------
    InputError
        The CSV names a baseline frame as pressed; see also :func:`read_presses`
        and :func:`~optitact.batch.process_files`.
    """
    from optitact.batch import process_files

    done = process_files(frames, pipeline=pipeline, baseline=baseline, baseline_frames=baseline_frames,
                         progress=progress)
    f, pressed = read_presses(forces, done.sources, pipeline.sensor)
    n_base = 0 if baseline is not None or pipeline.baseline is not None else int(baseline_frames)
    hit = np.flatnonzero(pressed[:n_base].any(axis=1))
    if hit.size:
        raise InputError(f"{forces}: frame {done.sources[hit[0]]!r} is the no-load baseline (the first "
                         f"{n_base} frame(s), baseline_frames / --baseline-frames) but the gauge lists it "
                         f"pressed; record no-load frames first, or give the baseline as a file "
                         f"(--baseline)")
    return Presses(sources=list(done.sources), readings=done.readings, forces=f, pressed=pressed)


def _check_presses(readings: Readings, forces, pressed) -> tuple[np.ndarray, np.ndarray]:
    """Forces ``(T, E, 3)`` and the pressed mask ``(T, E)`` checked against stack readings."""
    if not isinstance(readings, Readings) or not readings.is_stack:
        raise TypeError("readings must be stack Readings (T, E) from Pipeline.process(stack)")
    f = np.asarray(forces, dtype=np.float64)
    shape = readings.G.shape
    if f.shape != (*shape, 3):
        raise ShapeError(f"forces must have shape {(*shape, 3)} to match the readings, got {f.shape}")
    if not np.isfinite(f).all():
        raise InputError("forces must be finite (a NaN or infinite gauge reading)")
    pressed = np.any(f != 0, axis=-1) if pressed is None else np.asarray(pressed, dtype=bool)
    if pressed.shape != shape:
        raise ShapeError(f"pressed must have shape {shape}, got {pressed.shape}")
    return f, pressed


def _start(start) -> Calibration | None:
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
    start = _start(start)
    if pipeline is None:
        pipeline = start.pipeline() if start is not None else _default_pipeline(frames)
    p = measure_presses(frames, forces, pipeline=pipeline, baseline=baseline, baseline_frames=baseline_frames,
                        progress=progress)
    return _fit_measured(p, pipeline, model=model, start=start, forces=forces)


def _fit_measured(p: Presses, pipeline, *, model, start, forces) -> Calibration:
    """:func:`fit_presses` on measured presses, with the pipeline's sensor, camera, options and scale."""
    options = {k: v for k, v in pipeline._options().items() if k in PIPELINE_KEYS and k != "method"}
    bits = pipeline.readings_bits or pipeline.bits or 8
    return fit_presses(p.readings, p.forces, pressed=p.pressed, sensor=pipeline.sensor, camera=pipeline.camera,
                       pipeline_options=options, model=model, start=start,
                       intensity=start.intensity if start is not None else IntensityScale(bits=bits),
                       provenance={"frames": len(p.sources), "forces": str(forces),
                                   "presses": int(p.pressed.sum())})


def _default_pipeline(frames):
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
        ``MIN_PRESSES_REFINE`` presses keep its curves.
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
    f, pressed = _check_presses(readings, forces, pressed)
    usable = readings.contact & ~readings.saturated
    n_press = np.sum(pressed & usable, axis=0)
    start = _start(start)
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
    return _refine(start, readings, f, usable, n_press, sensor=sensor, camera=camera, intensity=intensity,
                   provenance=prov)


def _refined(start: Calibration, logk, logc, g_top, u_top, **fields) -> Calibration:
    k, c = np.exp(logk), np.exp(logc)
    f = start.f / c[:, None] if start.model == "coupled" else start.f * c[:, None]
    return replace(start, g_scale=start.g_scale * k, g_max=np.maximum(start.g_max * k, g_top),
                   u_max=np.maximum(start.u_max, u_top), f=f, **fields)


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
    n_k = k_ids.size
    logk, logc = np.zeros(n_el), np.zeros(n_el)
    if n_k:
        def unpack(x):
            lk, lc = np.zeros(n_el), np.zeros(n_el)
            lk[k_ids], lc[c_ids] = x[:n_k], x[n_k:]
            return lk, lc

        def resid(x):
            est, _ = _refined(start, *unpack(x), g_top, u_top).forces(readings)
            return (est[t_idx, e_idx] - truth).ravel()

        col_k = np.full(n_el, -1)
        col_k[k_ids] = np.arange(n_k)
        col_c = np.full(n_el, -1)
        col_c[c_ids] = n_k + np.arange(c_ids.size)
        rows = np.arange(3 * t_idx.size)
        el = np.repeat(e_idx, 3)
        rr = np.r_[rows, rows[col_c[el] >= 0]]
        cc = np.r_[col_k[el], col_c[el][col_c[el] >= 0]]
        sparsity = coo_matrix((np.ones(rr.size), (rr, cc)), shape=(rows.size, n_k + c_ids.size))
        sol = least_squares(resid, np.zeros(n_k + c_ids.size), jac_sparsity=sparsity, method="trf",
                            bounds=(np.log(0.2), np.log(5.0)), x_scale=0.1)
        logk, logc = unpack(sol.x)
    kept = np.flatnonzero(~fit_el)
    if kept.size:
        warnings.warn(f"{_elements(kept, n_press)} presses: fewer than the {MIN_PRESSES_REFINE} a refinement "
                      f"needs, so these keep the starting calibration's curves", OptitactWarning, stacklevel=3)
    cal = _refined(start, logk, logc, g_top, u_top, sensor=sensor, camera=camera)
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
                         "shear_scale": np.exp(logc).round(6).tolist()}
    return replace(cal, residuals=res, provenance=prov,
                   intensity=start.intensity if intensity is None else intensity)


# ---------------------------------------------------------------------------- held-out report
def press_report(calibration: Calibration, readings: Readings, forces, pressed=None, *,
                 worst: int = 5) -> dict:
    """Held-out errors of a calibration on presses of known forces.

    Parameters
    ----------
    calibration : Calibration
    readings : Readings
        ``(T, E)`` readings.
    forces : (T, E, 3) array_like
        The gauge's element-local forces (N).
    pressed : (T, E) bool array_like, optional
        The pressed samples (default: a non-zero force); the others are unloaded.
    worst : int
        How many of the worst elements to list.

    Returns
    -------
    dict
        JSON-ready: ``presses``; ``full_scale_n`` (``fx``/``fy``: the
        largest held-out shear component, ``fz``: the largest held-out Fz);
        over the pressed samples ``rmse_n``, ``rmse_pct_fs`` (None where the
        full scale is 0), ``bias_n`` (mean estimate - truth) and
        ``max_abs_error_n`` per axis; ``per_ring`` (``presses``, ``rmse_n``
        per axis); ``worst_elements`` (element, presses, RMS of the error
        vector in N, worst first); ``unloaded`` (``samples``, ``rmse_n`` per
        axis of the estimates where nothing was pressed, and
        ``contact_rate``, how often the pipeline saw contact there);
        ``clamped_rate`` of the pressed samples.
    """
    check_type(calibration, Calibration, "calibration")
    worst = integer(worst, "worst", minimum=0)
    f, pressed = _check_presses(readings, forces, pressed)
    if not pressed.any():
        raise InputError("no pressed sample to report on (the gauge CSV lists no press)")
    est, clamped = calibration.forces(readings)
    err = est - f
    axes = ("fx", "fy", "fz")
    truth = f[pressed]
    fs_shear = float(np.max(np.abs(truth[:, :2])))
    fs = {"fx": fs_shear, "fy": fs_shear, "fz": float(np.max(np.abs(truth[:, 2])))}
    ep = err[pressed]
    rmse = np.sqrt(np.mean(ep**2, axis=0))
    ring = calibration.sensor.element_ring
    e_of = np.nonzero(pressed)[1]
    per_ring = []
    for r in range(len(calibration.sensor.ring_counts)):
        m = ring[e_of] == r
        per_ring.append({"ring": r, "presses": int(m.sum()),
                         "rmse_n": dict(zip(axes, np.sqrt(np.mean(ep[m] ** 2, axis=0)).tolist(), strict=True))
                         if m.any() else None})
    norm2 = np.sum(ep**2, axis=1)
    counts = np.bincount(e_of, minlength=readings.n_elements)
    per_el = np.sqrt(np.bincount(e_of, weights=norm2, minlength=readings.n_elements) / np.maximum(counts, 1))
    order = [int(e) for e in np.argsort(-per_el, kind="stable") if counts[e]][:worst]
    free = ~pressed
    return {
        "presses": int(pressed.sum()), "elements_pressed": int(np.count_nonzero(counts)),
        "full_scale_n": fs,
        "rmse_n": dict(zip(axes, rmse.tolist(), strict=True)),
        "rmse_pct_fs": {k: (100.0 * float(v) / fs[k] if fs[k] > 0 else None)
                        for k, v in zip(axes, rmse, strict=True)},
        "bias_n": dict(zip(axes, ep.mean(axis=0).tolist(), strict=True)),
        "max_abs_error_n": dict(zip(axes, np.abs(ep).max(axis=0).tolist(), strict=True)),
        "per_ring": per_ring,
        "worst_elements": [{"element": e, "presses": int(counts[e]), "rms_error_n": float(per_el[e])}
                           for e in order],
        "unloaded": {"samples": int(free.sum()),
                     "rmse_n": dict(zip(axes, (np.sqrt(np.mean(err[free] ** 2, axis=0)) if free.any()
                                               else np.zeros(3)).tolist(), strict=True)),
                     "contact_rate": float(readings.contact[free].mean()) if free.any() else 0.0},
        "clamped_rate": float(clamped[pressed].mean()),
    }


def evaluate_calibration(frames: Sequence[str | os.PathLike], forces: str | os.PathLike, *,
                         calibration, baseline=None, baseline_frames: int = 1, progress: bool = False) -> dict:
    """Held-out report (:func:`press_report`) of a calibration on frames and their gauge CSV.

    ``calibration`` is a :class:`Calibration`, ``"default"`` or a file; the
    frames are read with its pipeline (see :func:`measure_presses`).
    """
    cal = _start(calibration)
    if cal is None:
        raise TypeError("calibration is required")
    p = measure_presses(frames, forces, pipeline=cal.pipeline(), baseline=baseline,
                        baseline_frames=baseline_frames, progress=progress)
    return press_report(cal, p.readings, p.forces, p.pressed)


# ---------------------------------------------------------------------------- presses per element
def press_curve(readings: Readings, forces, test_readings: Readings, test_forces, *, sensor: DomeSensor,
                camera, start, pressed=None, test_pressed=None, pipeline_options: dict | None = None,
                ns: Sequence[int] = (5, 10, 20), model: str | None = None, seed: int = 0) -> dict:
    """Held-out error against presses per element, fitted from scratch and refined from ``start``.

    For each ``N`` in ``ns``, ``N`` presses per element are drawn (without
    replacement, seeded) from the pool (``readings``, ``forces``,
    ``pressed``), a calibration is fitted on them from scratch and by
    refining ``start``, and both are scored on the held-out presses with
    :func:`press_report`.

    Returns
    -------
    dict
        ``{"ns": [...], "scratch": [...], "refined": [...]}``, each entry the
        report's ``rmse_pct_fs`` and ``rmse_n``, or ``{"refused": message}``
        where the fit is refused (from scratch below ``MIN_PRESSES_SCRATCH``).
    """
    from .fit import _plain

    f = np.asarray(forces, dtype=np.float64)
    pressed = np.any(f != 0, axis=-1) if pressed is None else np.asarray(pressed, dtype=bool)
    pool = pressed & readings.contact & ~readings.saturated
    have = pool.sum(axis=0)
    rng = np.random.default_rng(seed)
    start = _start(start)
    out: dict = {"ns": [int(n) for n in ns], "scratch": [], "refined": [],
                 "pool_presses_per_element_min": int(have.min())}
    options = _plain(pipeline_options or {})
    for n in ns:
        n = integer(n, "ns", minimum=1)
        if n > have.min():
            raise InputError(f"ns: {n} presses per element, but element {int(np.argmin(have))} has only "
                             f"{int(have.min())} in the pool")
        chosen = np.zeros_like(pool)
        for e in range(readings.n_elements):
            chosen[rng.choice(np.flatnonzero(pool[:, e]), n, replace=False), e] = True
        sub = Readings(readings.G, readings.u, chosen, readings.saturated)
        for kind, st in (("scratch", None), ("refined", start)):
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", OptitactWarning)
                    cal = fit_presses(sub, np.where(chosen[..., None], f, 0.0), pressed=chosen, sensor=sensor,
                                      camera=camera, pipeline_options=options, model=model if st is None
                                      else None, start=st)
            except InputError as exc:
                out[kind].append({"refused": str(exc)})
                continue
            rep = press_report(cal, test_readings, test_forces, test_pressed)
            out[kind].append({"rmse_pct_fs": rep["rmse_pct_fs"], "rmse_n": rep["rmse_n"]})
    return out
