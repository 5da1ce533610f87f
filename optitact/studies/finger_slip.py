"""Slip detection with the dome on the finger: dragging a block around a rectangle.

The apex element presses on a block and the finger drags it around a
rectangle; slip episodes are injected at known times and detected from the
*estimated* shear (:class:`optitact.finger.chain.ChainSimulator`) with
:func:`optitact.forces.slip.detect_slip` (the published ±0.06 N/s band).
:func:`slip_experiment` runs it, :func:`draw` draws a result. Part of the
``finger`` study (:mod:`optitact.studies.finger`).
"""

from __future__ import annotations

import math
import time

import numpy as np

from optitact._validate import integer, positive
from optitact.finger.kinematics import POSE_DOWN, Finger
from optitact.finger.chain import ChainSimulator
from optitact.finger.scene import local_from_world, world_from_local
from optitact.studies._finger_common import ar1, chain_for, need, rounded, study_seed
from optitact.studies._protocol import jsonable

__all__ = ["slip_experiment", "draw"]


def _rectangle_motion(width: float, height: float, speed: float, rate: float, *, t_acc: float = 0.5,
                      pause: float = 0.5, settle: float = 0.5, laps: int = 1) -> dict:
    """Positions, velocities and the detection gate of a trapezoidal-velocity walk around a rectangle."""
    corners = np.array([[0.0, 0.0], [width, 0.0], [width, height], [0.0, height]])
    seg_t, seg_p, seg_v, seg_gate, side_of = [], [], [], [], []
    t_cursor = 0.0
    dt = 1.0 / rate
    for lap in range(laps):
        for s in range(4):
            a, b = corners[s], corners[(s + 1) % 4]
            length = float(np.linalg.norm(b - a))
            u = (b - a) / length
            acc = speed / t_acc
            t_cruise = max(length / speed - t_acc, 0.0)
            dur = 2 * t_acc + t_cruise
            tt = np.arange(math.ceil((dur + pause) * rate)) * dt
            s_pos = np.where(tt < t_acc, 0.5 * acc * tt**2,
                             np.where(tt < t_acc + t_cruise, 0.5 * speed * t_acc + speed * (tt - t_acc),
                                      length - 0.5 * acc * np.clip(dur - tt, 0.0, None) ** 2))
            vel = np.where(tt < t_acc, acc * tt, np.where(tt < t_acc + t_cruise, speed,
                                                           np.clip(acc * (dur - tt), 0.0, None)))
            s_pos = np.where(tt >= dur, length, s_pos)
            gate = (tt >= t_acc + settle) & (tt < t_acc + t_cruise)
            seg_t.append(t_cursor + tt)
            seg_p.append(a + np.outer(s_pos, u))
            seg_v.append(np.outer(vel, u))
            seg_gate.append(gate)
            side_of.append(np.full(len(tt), 4 * lap + s))
            t_cursor += len(tt) * dt
    return {"t": np.concatenate(seg_t), "xy": np.concatenate(seg_p), "v": np.concatenate(seg_v),
            "gate": np.concatenate(seg_gate), "side": np.concatenate(side_of)}


def _slip_onsets(t: np.ndarray, gate: np.ndarray, n: int, rng: np.random.Generator, *, margin: float = 0.8,
                 spacing: float = 2.0) -> np.ndarray:
    """``n`` onset times inside gated windows, ``margin`` from their ends and ``spacing`` apart.

    The onsets are shared among the windows in proportion to what each can hold, and drawn uniformly
    in equal sub-intervals of a window (stratified), so that the spacing holds.
    """
    idx = np.flatnonzero(gate)
    runs = np.split(idx, np.flatnonzero(np.diff(idx) > 1) + 1) if len(idx) else []
    spans = [(t[r[0]] + margin, t[r[-1]] - margin) for r in runs]
    spans = [(a, b) for a, b in spans if b >= a]
    cap = np.array([int((b - a) // spacing) + 1 for a, b in spans], int)
    take = np.zeros(len(spans), int)
    order = rng.permutation(len(spans))
    while take.sum() < min(n, cap.sum()):
        for i in order:
            if take[i] < cap[i] and take.sum() < n:
                take[i] += 1
    out = []
    for (a, b), m in zip(spans, take, strict=True):
        if m == 0:
            continue
        width = (b - a + spacing) / m
        for j in range(m):
            out.append(a + j * width + rng.uniform(0.0, max(width - spacing, 0.0)))
    return np.sort(np.array(out, float))


def _match_events(onsets: np.ndarray, detections: np.ndarray, max_delay: float) -> dict:
    """Greedy matching of detections to true onsets: detection within [onset - 1e-9, onset + max_delay]."""
    used = np.zeros(len(detections), bool)
    delays = []
    matched = []
    for t0 in onsets:
        cand = np.flatnonzero(~used & (detections >= t0 - 1e-9) & (detections <= t0 + max_delay))
        if len(cand):
            j = int(cand[np.argmin(detections[cand])])
            used[j] = True
            delays.append(float(detections[j] - t0))
            matched.append(j)
        else:
            matched.append(None)
    tp = len(delays)
    nd = len(detections)
    return {"true_positives": tp, "false_alarms": int(nd - tp), "missed": int(len(onsets) - tp),
            "precision": tp / nd if nd else None, "recall": tp / len(onsets) if len(onsets) else None,
            "delays_s": delays, "mean_delay_s": float(np.mean(delays)) if delays else None,
            "max_delay_s": float(np.max(delays)) if delays else None,
            "false_alarm_times_s": [float(d) for d in detections[~used]], "matched_detection": matched}


def slip_experiment(*, chain: ChainSimulator | None = None, rectangle=(30.0, 20.0), speed: float = 5.0,
                    laps: int = 1, normal_force: float = 0.6, block_mass: float = 0.02,
                    table_friction: float = 0.2, n_slips: int = 6, frame_rate: float = 10.0,
                    threshold: float = 0.06, window: float = 0.6, hold: float = 0.3, max_delay: float = 1.0,
                    finger: Finger | None = None, seed: int = 0, progress: bool = True) -> dict:
    r"""Slip detection while the finger drags a block around a rectangle, with injected slip episodes.

    Parameters
    ----------
    chain : ChainSimulator, optional
        Default ``ChainSimulator(seed=seed)``.
    rectangle : (float, float)
        Side lengths (mm) of the path, default 30 x 20.
    speed : float
        Cruising speed (mm/s), default 5; each side accelerates and
        decelerates over 0.5 s and the finger pauses 0.5 s at each corner.
    laps : int
        Times round the rectangle, default 1.
    normal_force : float
        The apex element presses on the block's top with this force (N),
        default 0.6.
    block_mass, table_friction : float
        Block mass (kg, default 0.02) and its friction on the table (0.2):
        the drag the finger's shear must supply is
        ``table_friction (m g + F_n)`` (0.16 N by default).
    n_slips : int
        Slip episodes injected (default 6), at random times in the
        constant-speed parts, at least 1 s from their ends and 2.5 s apart.
    frame_rate : float
        Frames per second, default 10.
    threshold, window, hold
        Of :class:`optitact.forces.slip.SlipDetector` (published band 0.06 N/s;
        window 0.6 s: 6 samples).
    max_delay : float
        A detection counts for an episode when it comes at most this long
        after its onset (s), default 1.
    finger : Finger, optional
    seed : int
    progress : bool

    Returns
    -------
    dict
        JSON-ready: ``onsets_s`` (true), ``events`` (detected, from the
        estimated forces), ``scores`` (precision, recall, delays, false
        alarms), ``scores_truth`` (the same detector on the simulated forces),
        the ``series`` (t, x, y, gate, shear true and estimated, derivative),
        ``settings``, ``seconds``.

    Notes
    -----
    The apex element (sensor axis down) presses on the block and drags it;
    the shear on the element opposes the motion, scaled down to zero as the
    finger stops at a corner (the block rests; the shear turns with the next
    side). A slip episode: the contact gives way, the shear falls by a
    fraction 0.4-0.7 of the drag (time constant 0.05 s) with 5 % chatter, stays
    there 0.2-0.5 s (the finger slides over the block) and recovers
    (0.15 s) when the grip returns. Shear texture noise 1 %, normal force
    noise 2 %. Detection runs only while the finger cruises (``gate``: from
    0.5 s after the acceleration to the start of the deceleration): when the
    robot itself changes the load, a derivative means nothing. The detector
    works on the magnitude of the estimated horizontal force, obtained
    through the finger's orientation.
    """
    from optitact.forces.slip import detect_slip

    seed = study_seed(seed)
    chain = chain_for(chain, seed)
    finger = Finger() if finger is None else finger
    w, h = (positive(v, f"rectangle[{i}]") for i, v in enumerate(rectangle))
    speed = positive(speed, "speed")
    laps = integer(laps, "laps", minimum=1)
    fn0 = positive(normal_force, "normal_force")
    n_slips = integer(n_slips, "n_slips", minimum=0)
    rate = positive(frame_rate, "frame_rate")
    sensor = chain.sensor
    t0 = time.perf_counter()
    rng = np.random.default_rng([seed, 21])
    mot = _rectangle_motion(w, h, speed, rate, laps=laps)
    t = mot["t"]
    n = len(t)
    drag = positive(table_friction, "table_friction") * (positive(block_mass, "block_mass") * 9.81 + fn0)
    vmag = np.hypot(mot["v"][:, 0], mot["v"][:, 1])
    scale = np.clip(vmag / (0.25 * speed), 0.0, 1.0)
    direction = np.zeros((n, 2))
    moving = vmag > 0
    direction[moving] = mot["v"][moving] / vmag[moving, None]
    # keep the last direction while paused (the shear relaxes along it)
    for i in range(1, n):
        if not moving[i]:
            direction[i] = direction[i - 1]
    mult = 1.0 + ar1(rng, n, 0.01, 0.5)
    onsets = _slip_onsets(t, mot["gate"], n_slips, rng)
    episodes = []
    for t_on in onsets:
        d = rng.uniform(0.4, 0.7)
        dur = rng.uniform(0.2, 0.5)
        chatter = ar1(rng, n, 0.05, 0.3)
        during = (t >= t_on) & (t < t_on + dur)
        after = t >= t_on + dur
        drop_end = d * (1.0 - math.exp(-dur / 0.05))
        g = np.ones(n)
        g[during] = 1.0 - d * (1.0 - np.exp(-(t[during] - t_on) / 0.05)) + chatter[during] * (1 - d)
        g[after] = 1.0 - drop_end * np.exp(-(t[after] - t_on - dur) / 0.15)
        mult *= g
        episodes.append({"onset_s": float(t_on), "drop_fraction": d, "duration_s": dur})
    shear = drag * scale * mult
    fn = fn0 * (1.0 + ar1(rng, n, 0.02, 0.5))
    apex0 = finger.forward(POSE_DOWN)
    targets = apex0 + np.concatenate([mot["xy"] - [w / 2, h / 2], np.zeros((n, 1))], axis=1)
    rots, _ = finger.follow(targets, POSE_DOWN)
    world = np.zeros((n, sensor.n_elements, 3))
    world[:, 0, :2] = -shear[:, None] * direction
    world[:, 0, 2] = fn
    est = chain.estimate(local_from_world(sensor, world, rots), progress=progress, desc="slip")
    west = world_from_local(sensor, est.forces, rots)[:, 0]
    shear_est = np.hypot(west[:, 0], west[:, 1])
    kw = dict(threshold=threshold, window=window, hold=hold)
    res = detect_slip(t, shear_est, active=mot["gate"], **kw)
    res_true = detect_slip(t, shear, active=mot["gate"], **kw)
    scores = _match_events(onsets, res.onsets, max_delay)
    scores_true = _match_events(onsets, res_true.onsets, max_delay)
    return jsonable({
        "onsets_s": onsets, "episodes": episodes, "events": [e.as_dict() for e in res.events],
        "events_truth": [e.as_dict() for e in res_true.events], "scores": scores, "scores_truth": scores_true,
        "drag_n": drag, "frames": n,
        "series": {"t": rounded(t, 4), "x": rounded(mot["xy"][:, 0], 3), "y": rounded(mot["xy"][:, 1], 3),
                   "gate": mot["gate"], "shear_true": rounded(shear), "shear": rounded(shear_est),
                   "fn": rounded(west[:, 2]), "derivative": rounded(res.derivative),
                   "derivative_true": rounded(res_true.derivative)},
        "settings": {"rectangle_mm": [w, h], "speed_mm_s": speed, "laps": laps, "normal_force_n": fn0,
                     "block_mass_kg": block_mass, "table_friction": table_friction, "n_slips": n_slips,
                     "frame_rate_hz": rate, "threshold_n_s": threshold, "window_s": window, "hold_s": hold,
                     "max_delay_s": max_delay, "chain": chain.describe(), "seed": seed},
        "seconds": time.perf_counter() - t0})




def draw(fig, result: dict) -> None:
    """Fill ``fig`` from a :func:`slip_experiment` result: shear, its derivative against the band, the path."""
    s = need(result, "series")
    t = np.asarray(s["t"])
    ax1, ax2, ax3 = fig.subplots(1, 3, gridspec_kw={"width_ratios": [3, 3, 1.3]})
    gate = np.asarray(s["gate"], bool)
    for ax in (ax1, ax2):
        ax.fill_between(t, 0, 1, where=~gate, transform=ax.get_xaxis_transform(), color="0.9", lw=0)
        for t0 in result["onsets_s"]:
            ax.axvline(t0, color="tab:red", lw=0.8, ls="--")
    ax1.plot(t, s["shear_true"], color="0.5", lw=1, label="true")
    ax1.plot(t, s["shear"], color="tab:orange", lw=1, label="estimated")
    ax1.set_xlabel("t (s)")
    ax1.set_ylabel("|F_t| (N)")
    ax1.legend(fontsize=6)
    ax1.set_title("shear; red: injected slip onsets, grey: detection off", fontsize=8)
    ax2.plot(t, s["derivative"], color="tab:blue", lw=1)
    th = result["settings"]["threshold_n_s"]
    ax2.axhspan(-th, th, color="tab:green", alpha=0.15)
    for e in result["events"]:
        ax2.plot(e["onset"], e["peak_rate"], "kv", ms=5)
    sc = result["scores"]
    delay = "n/a" if sc["mean_delay_s"] is None else f"{sc['mean_delay_s']:.2f} s"
    prec = "n/a" if sc["precision"] is None else f"{sc['precision']:.2f}"
    rec = "n/a" if sc["recall"] is None else f"{sc['recall']:.2f}"
    ax2.set_title(f"d|F_t|/dt, band ±{th:g} N/s; precision {prec}, recall {rec}, mean delay {delay}",
                  fontsize=8)
    ax2.set_xlabel("t (s)")
    ax2.set_ylabel("N/s")
    ax3.plot(s["x"], s["y"], color="0.3")
    ax3.set_aspect("equal")
    ax3.set_xlabel("x (mm)")
    ax3.set_ylabel("y (mm)")
    ax3.set_title("finger path", fontsize=8)
