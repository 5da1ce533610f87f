"""Per-element relative brightness from presses of equal force (registration's gains).

Real elements differ in brightness (rubber, cone tips, the rim light that
reaches them). Pressed at one gauge setting, each element's integrated grey
value G (read through a :class:`~optitact.pipeline.frame_pipeline.Pipeline` of the registered sensor
and camera, dewarped onto the dome, so camera-independent to first order)
over what a reference calibration's curves give at that force is its gain
relative to the reference sensor; without a known force, the one that makes
the median gain 1. :func:`optitact.registration.pose` calls :func:`element_gains` with
``fit_gains=True``.
"""

from __future__ import annotations

import math

import numpy as np

from optitact.errors import GainsError, InputError

__all__ = ["element_gains", "reference_curve", "reference_g"]


def reference_curve(calibration, n_grid: int = 4097) -> tuple[np.ndarray, np.ndarray]:
    """Each element's reference ``Fz(G)`` (a pure normal press, ``u = 0``) on a grid of G: (grid, (n, E))."""
    from optitact.pipeline.readings import Readings

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

    Returns ``gain`` (N,), ``se`` (N,) (NaN where unknown), ``presses`` (N,) (the presses each gain is the
    median of), ``force`` (the press force, given or the one that makes the median gain 1), ``unfitted``
    (seen elements whose presses could not be read against the reference: no contact, saturated, outside
    its range).

    Notes
    -----
    A gain's standard error is the larger of two estimates over its ``n`` presses, each ``gain * s /
    sqrt(n)``: with ``s`` the relative noise of one press's G that the frames' dark noise gives through
    the pipeline's region sums (:func:`optitact.pipeline.uncertainty.reading_errors` with the pipeline's own
    noise, no shot noise: the fewer pixels an element's light covers, the larger it is), and, where some
    element was pressed more than once, with ``s`` the spread of repeated presses (of log G, pooled over
    the elements), which includes the shot noise and the presses' own variation.
    """
    from optitact.pipeline.frame_pipeline import Pipeline
    from optitact.pipeline.uncertainty import PixelNoise, reading_errors

    n = sensor.n_elements
    if len(calibration.g) != n:
        raise InputError(f"calibration: the reference calibration has {len(calibration.g)} elements, the "
                         f"sensor {n}; give a calibration of a sensor with the same element layout")
    pipe = Pipeline(sensor, camera, baseline=base, readings_bits=calibration.intensity.bits,
                    **calibration.reading_options)
    stack = np.stack(frames)
    readings = pipe.process(stack)
    g_meas = readings.G[obs_f, obs_e]
    ok = readings.contact[obs_f, obs_e] & ~readings.saturated[obs_f, obs_e] & (g_meas > 0)
    rel_noise = np.full(len(obs_e), np.nan)
    if pipe.filter == "none":  # a filtered image's pixel noise is correlated: not modelled
        g_se = reading_errors(pipe, stack, PixelNoise(0.0), readings=readings).G_se[obs_f, obs_e]
        rel_noise = np.where(ok, g_se / np.where(g_meas > 0, g_meas, 1.0), np.nan)
    grid, fz = reference_curve(calibration)
    ref_gain = calibration.sensor.gains

    def gains_at(force, noise=False):
        g_ref = reference_g(grid, fz, force)[obs_e]
        ratio = np.where(ok & np.isfinite(g_ref), g_meas / np.where(g_ref > 0, g_ref, np.nan), np.nan)
        per, rel = {}, {}
        for e in np.unique(obs_e):
            mine = obs_e == e
            good = np.isfinite(ratio[mine])
            if good.any():
                per[int(e)] = ratio[mine][good] * ref_gain[e]
                rel[int(e)] = rel_noise[mine][good]
        return (per, rel) if noise else per

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
    per, rel = gains_at(force, noise=True)
    if not per:
        raise GainsError(
            f"no element's gain could be measured: the pressed elements show no contact in the pipeline or "
            f"their G lies outside the reference calibration's range at {force:.3g} N; press harder or "
            f"lighter, give press_force (--press-force), or register without fit_gains")
    if press_force is None:  # exact normalisation: the median over the seen elements is 1
        med = float(np.median([np.median(v) for v in per.values()]))
        per = {e: v / med for e, v in per.items()}
    gain, se, presses = sensor.gains.copy(), np.full(n, np.nan), np.zeros(n, np.int64)
    logs = [np.log(v) - np.mean(np.log(v)) for v in per.values() if v.size > 1]
    dof = sum(v.size - 1 for v in per.values() if v.size > 1)
    s_rel = math.sqrt(sum(float(np.sum(d ** 2)) for d in logs) / dof) if dof else math.nan
    for e, v in per.items():
        gain[e] = float(np.median(v))
        s_noise = math.sqrt(float(np.mean(rel[e] ** 2))) if np.isfinite(rel[e]).all() else math.nan
        s = np.nanmax([s_rel, s_noise]) if np.isfinite([s_rel, s_noise]).any() else math.nan
        se[e] = gain[e] * s / math.sqrt(v.size)
        presses[e] = v.size
    gain = np.clip(gain, 1.0 / 16.0, 16.0)
    unfitted = tuple(int(e) for e in np.unique(obs_e) if int(e) not in per)
    return {"gain": gain, "se": se, "presses": presses, "force": force, "unfitted": unfitted}
