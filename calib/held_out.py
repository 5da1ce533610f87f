"""The held-out report of a calibration on measured presses, and its error against presses per element.

:func:`press_report` scores a calibration on presses of known forces
(errors per axis and ring, the worst elements, the unloaded samples);
:func:`evaluate_calibration` does so from frames and their gauge CSV;
:func:`press_curve` measures how the held-out error falls with the number of
presses per element, fitted from scratch and refined.
"""

from __future__ import annotations

import os
import warnings
from collections.abc import Sequence

import numpy as np

from optitact._validate import check_type, integer
from optitact.errors import InputError, OptitactWarning
from optitact.pipeline.readings import Readings
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.uncertainty import coverage, error_ratio

from optitact.calib.fit import Calibration
from optitact.calib.gauge import check_presses, measure_presses
from optitact.calib.press_fit import fit_presses, starting_calibration

__all__ = ["evaluate_calibration", "press_curve", "press_report"]


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
        ``clamped_rate`` of the pressed samples; ``coverage_90`` per axis:
        the fraction of pressed samples whose true force lies inside the
        calibration's 90 % interval (its model error, as ``process
        --stderr`` gives it; near 0.9 when the error bars are honest, and
        :meth:`Calibration.validated` measures them from presses like these);
        ``error_ratio`` per axis: the errors in those standard errors, root
        mean square (1 when they are right:
        :func:`optitact.pipeline.uncertainty.error_ratio`).
    """
    check_type(calibration, Calibration, "calibration")
    worst = integer(worst, "worst", minimum=0)
    f, pressed = check_presses(readings, forces, pressed)
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
    se = calibration.stderr(readings, forces=est)
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
        "coverage_90": dict(zip(axes, coverage(est, f, se, where=pressed).tolist(), strict=True)),
        "error_ratio": dict(zip(axes, error_ratio(est, f, se, where=pressed).tolist(), strict=True)),
    }


def evaluate_calibration(frames: Sequence[str | os.PathLike], forces: str | os.PathLike, *,
                         calibration, baseline=None, baseline_frames: int = 1, progress: bool = False) -> dict:
    """Held-out report (:func:`press_report`) of a calibration on frames and their gauge CSV.

    ``calibration`` is a :class:`Calibration`, ``"default"`` or a file; the
    frames are read with its pipeline (see :func:`measure_presses`).
    """
    cal = starting_calibration(calibration)
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
    from optitact.calib.document import plain_options

    f = np.asarray(forces, dtype=np.float64)
    pressed = np.any(f != 0, axis=-1) if pressed is None else np.asarray(pressed, dtype=bool)
    pool = pressed & readings.contact & ~readings.saturated
    have = pool.sum(axis=0)
    rng = np.random.default_rng(seed)
    start = starting_calibration(start)
    out: dict = {"ns": [int(n) for n in ns], "scratch": [], "refined": [],
                 "pool_presses_per_element_min": int(have.min())}
    options = plain_options(pipeline_options or {})
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
