"""Fitting a calibration to a six-axis force/torque sensor's totals, alone or with gauge presses.

A lab presses objects anywhere on the dome while an F/T sensor under its
mount records the total wrench (:mod:`optitact.calib.wrench`: the CSV, the
sensor's pose, the map from element forces to the wrench). Each element's
curves are fitted so that the element forces, summed as a wrench about the
F/T sensor's origin, match the measured totals: every element's own shape on
top of a starting calibration (the shipped synthetic one, transferred to a
registered sensor), shrunk toward it, the strength cross-validated over
frames (:mod:`optitact.calib.element_shapes`). Gauge presses, where there are
some, are fitted with the frames.

The frames must be able to tell the elements apart: an element never loaded,
or always loaded with the same neighbours, is refused by name
(:func:`~optitact.calib.wrench.check_identifiable`) unless gauge presses pin
it down. The calibration's error model comes from the held-out frames (the
start's, scaled to what the frames' totals show; with 20 presses or more,
from the held-out presses themselves).
"""

from __future__ import annotations

import os
from collections.abc import Sequence

import numpy as np

from optitact._validate import integer
from optitact.errors import InputError, ShapeError
from optitact.pipeline.readings import Readings
from optitact.optics.sensor import DomeSensor

from optitact.calib.fit import Calibration
from optitact.calib.gauge import check_presses, read_presses
from optitact.calib.press_fit import GAUGE_NOISE, MIN_PRESSES_REFINE, fit_element_shapes, starting_calibration
from optitact.calib.wrench import SensorPose, Wrenches, check_identifiable, read_wrench, wrench_matrix

__all__ = ["FT_NOISE", "FT_FLOOR", "MIN_WRENCH_FRAMES", "fit_wrench_frames", "fit_wrenches"]

#: Frames (with a wrench) that must load each element the presses do not pin down: with fewer, the
#: element's curves would rest on the prior alone, which is the start's and needs no frames.
MIN_WRENCH_FRAMES = 2
#: The F/T sensor's noise: a fraction of the wrench it reads (0.5 %, a typical six-axis sensor's accuracy).
FT_NOISE = 0.005
#: Its noise floor: (N, N m) per force and torque component (a small six-axis sensor's resolution).
FT_FLOOR = (0.002, 2e-5)


def _ft_noise(wrench: np.ndarray, relative: float) -> np.ndarray:
    """Standard error of each component (T, 6): ``relative`` of the force (torque) magnitude, with the floor."""
    force = np.linalg.norm(wrench[:, :3], axis=1, keepdims=True)
    torque = np.linalg.norm(wrench[:, 3:], axis=1, keepdims=True)
    return np.concatenate([np.sqrt((relative * force) ** 2 + FT_FLOOR[0] ** 2).repeat(3, axis=1),
                           np.sqrt((relative * torque) ** 2 + FT_FLOOR[1] ** 2).repeat(3, axis=1)], axis=1)


def fit_wrenches(readings: Readings, wrenches: Wrenches, pose: SensorPose, *, sensor: DomeSensor, camera,
                 start="default", forces=None, pressed=None, intensity=None, provenance: dict | None = None,
                 seed: int = 0, ft_noise: float = FT_NOISE, gauge_noise: float = GAUGE_NOISE) -> Calibration:
    """Fit each element's curves to an F/T sensor's totals (and any gauge presses), refining ``start``.

    Parameters
    ----------
    readings : Readings
        ``(T, E)`` readings of all the frames.
    wrenches : Wrenches
        The measured wrenches of some of them (:func:`~optitact.calib.wrench.read_wrench`).
    pose : SensorPose
        The F/T sensor's pose relative to the dome.
    sensor, camera
        What the readings came from (e.g. a registered sensor and camera).
    start : "default", Calibration or path-like
        The calibration refined (default: the shipped one, transferred to
        ``sensor`` and ``camera``).
    forces, pressed : optional
        Gauge presses among the frames (``(T, E, 3)`` element-local forces
        and the ``(T, E)`` pressed mask, as :func:`~optitact.calib.gauge.read_presses`
        gives them), fitted with the totals. A frame may not be both.
    intensity, provenance, seed
        As in :func:`~optitact.calib.press_fit.fit_presses`.
    ft_noise : float
        The F/T sensor's noise, a fraction of its reading (default :data:`FT_NOISE`).
    gauge_noise : float
        The gauge's, for the presses.

    Returns
    -------
    Calibration
        With each element's shape, the error model of the held-out frames,
        and in its provenance the frames, the F/T pose and which elements the
        observations pinned down.

    Raises
    ------
    UnidentifiableError
        Elements the frames (and presses) cannot pin down: named, with what to add.
    InputError
        No start (a wrench fit refines one), a frame both pressed by the gauge
        and in the wrench file, fewer than 2 frames with a wrench and contact.
    ShapeError
        Readings, forces or wrench frames that do not match.
    """
    start = starting_calibration(start)
    if start is None:
        raise InputError("a fit to force/torque totals refines a starting calibration (start='default', "
                         "--start default); it cannot fit curves from scratch")
    if not isinstance(readings, Readings) or not readings.is_stack:
        raise TypeError("readings must be stack Readings (T, E)")
    if not isinstance(wrenches, Wrenches):
        raise TypeError(f"wrenches must be Wrenches (from read_wrench), got {type(wrenches).__name__}")
    n_t, n_el = np.shape(readings.G)
    frames = np.asarray(wrenches.frames)
    if frames.size and (frames.min() < 0 or frames.max() >= n_t):
        raise ShapeError(f"the wrench file's frames run to {int(frames.max())}, the readings have {n_t} frames")
    if start.sensor != sensor or start.camera != camera:
        start = start.transferred(sensor, camera)
    if forces is None:
        f = np.zeros((n_t, n_el, 3))
        pressed = np.zeros((n_t, n_el), bool)
    else:
        f, pressed = check_presses(readings, forces, pressed)
    both = np.flatnonzero(pressed[frames].any(axis=1))
    if both.size:
        raise InputError(f"frame {int(frames[both[0]])} is both pressed by the gauge and listed with a wrench "
                         f"({both.size} such frame(s)); a frame is one or the other")
    usable = readings.contact & ~readings.saturated
    n_press = np.sum(pressed & usable, axis=0)
    seen = readings.contact[frames] & ~readings.saturated[frames]
    sub = Readings(readings.G[frames], readings.u[frames], seen, readings.saturated[frames])
    keep = sub.contact.any(axis=1)
    if keep.sum() < 2:
        raise InputError(f"{int(keep.sum())} of the {frames.size} frames with a wrench show contact; a fit "
                         f"needs at least 2 (and enough to load every element)")
    # elements the presses pin down need nothing from the totals
    free = np.flatnonzero(n_press < MIN_PRESSES_REFINE)
    counts = check_identifiable(sub.contact[keep], min_frames=MIN_WRENCH_FRAMES, elements=free)
    sub = Readings(sub.G[keep], sub.u[keep], sub.contact[keep], sub.saturated[keep])
    wrench = np.asarray(wrenches.wrench, dtype=np.float64)[keep]
    from optitact.calib.element_shapes import wrench_observations

    extra = wrench_observations(start, sub, wrench, wrench_matrix(sensor, pose),
                                _ft_noise(wrench, float(ft_noise)))
    prov = dict(provenance or {}) | {"presses_per_element": n_press.tolist(),
                                     "wrench_frames": int(keep.sum()),
                                     "wrench_frames_per_element": counts.tolist(),
                                     "ft_pose": pose.to_dict(), "ft_noise": float(ft_noise)}
    press_usable = usable & pressed.any(axis=1, keepdims=True)  # the press frames' samples (unpressed: 0 N)
    return fit_element_shapes(start, readings, f, press_usable, n_press, sensor=sensor, camera=camera,
                              intensity=intensity, provenance=prov, seed=integer(seed, "seed", minimum=0),
                              gauge_noise=gauge_noise, extra=extra)


def fit_wrench_frames(frames: Sequence[str | os.PathLike], wrench: str | os.PathLike, pose: SensorPose, *,
                      pipeline=None, start="default", forces: str | os.PathLike | None = None, baseline=None,
                      baseline_frames: int = 1, progress: bool = False) -> Calibration:
    """Read the frames and the F/T sensor's CSV (and a gauge CSV) and fit (:func:`fit_wrenches`).

    Parameters
    ----------
    frames : sequence of path-like
        Image files, folders, ``.npy`` stacks or videos, read in order.
    wrench : path-like
        The F/T sensor's CSV (:func:`~optitact.calib.wrench.read_wrench`).
    pose : SensorPose
    pipeline : Pipeline, optional
        Default ``start``'s pipeline.
    start : "default", Calibration or path-like
    forces : path-like, optional
        A gauge CSV of presses among the same frames.
    baseline, baseline_frames, progress
        As in :func:`optitact.calib.gauge.measure_presses`.
    """
    from optitact.pipeline.batch import process_files

    start = starting_calibration(start)
    if start is None:
        raise InputError("a fit to force/torque totals refines a starting calibration (--start default)")
    if pipeline is None:
        pipeline = start.pipeline()
    done = process_files(frames, pipeline=pipeline, baseline=baseline, baseline_frames=baseline_frames,
                         progress=progress)
    pose = pose.check(pipeline.sensor)
    w = read_wrench(wrench, done.sources, pose=pose, sensor=pipeline.sensor)
    n_base = 0 if baseline is not None or pipeline.baseline is not None else int(baseline_frames)
    if w.frames.size and w.frames.min() < n_base:
        raise InputError(f"{wrench}: frame {done.sources[int(w.frames.min())]!r} is the no-load baseline (the "
                         f"first {n_base} frame(s), --baseline-frames) but has a wrench row; record no-load "
                         f"frames first, or give the baseline as a file (--baseline)")
    f = pressed = None
    if forces is not None:
        f, pressed = read_presses(forces, done.sources, pipeline.sensor)
    return fit_wrenches(done.readings, w, pose, sensor=pipeline.sensor, camera=pipeline.camera, start=start,
                        forces=f, pressed=pressed, intensity=start.intensity,
                        provenance={"frames": len(done.sources), "wrench": str(wrench),
                                    **({} if forces is None else {"forces": str(forces)})})
