"""Per-element relative brightness from presses of equal force (registration's gains).

Real elements differ in brightness (rubber, cone tips, the rim light that
reaches them). Pressed at one gauge setting, each element's integrated grey
value G (read through a :class:`~optitact.Pipeline` of the registered sensor
and camera, dewarped onto the dome, so camera-independent to first order)
over what a reference calibration's curves give at that force is its gain
relative to the reference sensor; without a known force, the one that makes
the median gain 1. :func:`optitact.register` calls :func:`element_gains` with
``fit_gains=True``.
"""

from __future__ import annotations

import math

import numpy as np

from .errors import GainsError, InputError

__all__ = ["element_gains", "reference_curve", "reference_g"]


def reference_curve(calibration, n_grid: int = 4097) -> tuple[np.ndarray, np.ndarray]:
    """Each element's reference ``Fz(G)`` (a pure normal press, ``u = 0``) on a grid of G: (grid, (n, E))."""
    from .readings import Readings

    frac = np.linspace(0.0, 1.0, n_grid)[:, None]
    grid = frac * calibration.g_max[None, :]
    readings = Readings(grid, np.zeros(grid.shape + (2,)), np.ones(grid.shape, bool),
                        np.zeros(grid.shape, bool))
    fz = calibration.forces(readings)[0][..., 2]
    return grid, np.maximum.accumulate(fz, axis=0) + frac * 1e-9  # strictly increasing, for np.interp


def reference_g(grid: np.ndarray, fz: np.ndarray, force: float) -> np.ndarray:
    """The reference G (E,) the curves map to ``force``; NaN where ``force`` is beyond an element's range."""
    out = np.full(grid.shape[1], np.nan)
    for e in range(grid.shape[1]):
        if fz[0, e] <= force <= fz[-1, e]:
            out[e] = np.interp(force, fz[:, e], grid[:, e])
    return out


def element_gains(sensor, camera, base, frames, obs_f, obs_e, *, press_force, calibration) -> dict:
    """Per-element gains from equal presses: measured G over the reference calibration's G at the press force.

    Returns ``gain`` (N,), ``se`` (N,) (NaN where unknown), ``force`` (the press force, given or the one that
    makes the median gain 1), ``unfitted`` (seen elements whose presses could not be read against the
    reference: no contact, saturated, outside its range).
    """
    from .pipeline import Pipeline

    n = sensor.n_elements
    if len(calibration.g) != n:
        raise InputError(f"calibration: the reference calibration has {len(calibration.g)} elements, the "
                         f"sensor {n}; give a calibration of a sensor with the same element layout")
    options = {k: v for k, v in calibration.pipeline_options.items() if k != "method"}
    pipe = Pipeline(sensor, camera, baseline=base, readings_bits=calibration.intensity.bits, **options)
    readings = pipe.process(np.stack(frames))
    g_meas = readings.G[obs_f, obs_e]
    ok = readings.contact[obs_f, obs_e] & ~readings.saturated[obs_f, obs_e] & (g_meas > 0)
    grid, fz = reference_curve(calibration)
    ref_gain = calibration.sensor.gains

    def gains_at(force):
        g_ref = reference_g(grid, fz, force)[obs_e]
        ratio = np.where(ok & np.isfinite(g_ref), g_meas / np.where(g_ref > 0, g_ref, np.nan), np.nan)
        per = {}
        for e in np.unique(obs_e):
            r = ratio[obs_e == e]
            r = r[np.isfinite(r)]
            if r.size:
                per[int(e)] = r * ref_gain[e]
        return per

    if press_force is None:  # the force at which the median element's gain is 1
        top = float(np.min(fz[-1, np.unique(obs_e)]))
        lo, hi = 1e-6 * top, top
        for _ in range(60):
            mid = math.sqrt(lo * hi)
            per = gains_at(mid)
            med = np.median([np.median(v) for v in per.values()]) if per else np.nan
            if not np.isfinite(med):
                break
            lo, hi = (mid, hi) if med > 1.0 else (lo, mid)
        force = math.sqrt(lo * hi)
    else:
        force = float(press_force)
    per = gains_at(force)
    if not per:
        raise GainsError(
            f"no element's gain could be measured: the pressed elements show no contact in the pipeline or "
            f"their G lies outside the reference calibration's range at {force:.3g} N; press harder or "
            f"lighter, give press_force (--press-force), or register without fit_gains")
    if press_force is None:  # exact normalisation: the median over the seen elements is 1
        med = float(np.median([np.median(v) for v in per.values()]))
        per = {e: v / med for e, v in per.items()}
    gain, se = sensor.gains.copy(), np.full(n, np.nan)
    logs = [np.log(v) - np.mean(np.log(v)) for v in per.values() if v.size > 1]
    dof = sum(v.size - 1 for v in per.values() if v.size > 1)
    s_rel = math.sqrt(sum(float(np.sum(d ** 2)) for d in logs) / dof) if dof else math.nan
    for e, v in per.items():
        gain[e] = float(np.median(v))
        se[e] = gain[e] * s_rel / math.sqrt(v.size)
    gain = np.clip(gain, 1.0 / 16.0, 16.0)
    unfitted = tuple(int(e) for e in np.unique(obs_e) if int(e) not in per)
    return {"gain": gain, "se": se, "force": force, "unfitted": unfitted}
