"""Contour tracing with the dome on the finger: a cylinder and a box on a table.

Seek the table, lift, and trace an object's contour with the published rules
(approach until an element reads 0.3 N, retreat along the estimated normal,
advance along the tangent, square search when lost), every force *estimated*
(:class:`optitact.finger.chain.ChainSimulator`). :func:`contour_tracing` traces,
:func:`joint_error_study` adds the finger's own (unmeasured) joint errors to
read the published deviations, :func:`draw` and :func:`draw_joint_error`
draw results. Part of the ``finger`` study (:mod:`optitact.studies.finger`).
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time

import numpy as np

from optitact._validate import integer, positive
from optitact.errors import InputError
from optitact.finger.kinematics import POSE_TRACE, Finger, SingularityError, UnreachableError
from optitact.finger.scene import Box, Cylinder, Table, feeler_forces, feeler_tips, world_from_local
from optitact.finger.chain import ChainSimulator
from optitact.studies._finger_common import chain_for, need, study_seed
from optitact.studies._protocol import jsonable

__all__ = ["contour_tracing", "joint_error_study", "draw", "draw_joint_error", "PUBLISHED_DEVIATION_MM"]


def _rot_ccw(v: np.ndarray) -> np.ndarray:
    return np.array([-v[1], v[0]])


def _unit(v: np.ndarray) -> np.ndarray:
    n = float(np.linalg.norm(v))
    return v / n if n > 0 else v


class _Probe:
    """The finger, the objects and the chain in closed loop: one frame per call, counted."""

    def __init__(self, chain: ChainSimulator, finger: Finger, objects, *, stiffness: float,
                 feeler_height: float, first_index: int, max_frames: int, joint_error: float = 0.0,
                 rng: np.random.Generator | None = None) -> None:
        self.chain, self.finger, self.objects = chain, dataclasses.replace(finger, tool=0.0), objects
        self.k, self.h = stiffness, feeler_height
        self.index, self.frames, self.max_frames = first_index, 0, max_frames
        self.theta = POSE_TRACE.copy()
        self.actual = self.theta
        self.joint_error, self.rng = joint_error, rng

    def move(self, centre: np.ndarray, z: float) -> None:
        self.theta = self.finger.rmrc(centre, self.theta, z=z, max_step=5.0).theta
        self.z = z
        self.actual = self.theta
        if self.joint_error > 0:  # where the joints really are (backlash, encoder error): not known
            self.actual = self.theta + self.rng.normal(0.0, self.joint_error, 3)

    def sense(self) -> dict:
        sensor = self.chain.sensor
        rot_a, origin_a = self.finger.sensor_pose(self.actual, z=self.z)
        local, _ = feeler_forces(sensor, rot_a, origin_a, self.objects, stiffness=self.k,
                                 feeler_height=self.h)
        est = self.chain.estimate(local, first_index=self.index)
        self.index += 1
        self.frames += 1
        # The controller's view: the commanded pose.
        rot, origin = self.finger.sensor_pose(self.theta, z=self.z)
        tips = feeler_tips(sensor, rot, origin, feeler_height=self.h)
        world = world_from_local(sensor, est.forces, rot[None])[0]
        return {"est": est.forces[0], "world": world, "tips": tips, "rot": rot, "origin": origin,
                "truth": local, "clamped": est.clamped[0]}

    @property
    def exhausted(self) -> bool:
        return self.frames >= self.max_frames


def _start_point(obj, contact_y: float, r_tip: float, gap: float) -> tuple[float, float]:
    """Where the experimenter puts the dome centre (x, y) before the approach along +x.

    From there the first contact is at ``y = contact_y``, and every feeler starts ``gap`` mm clear.
    """
    xs = np.linspace(0.0, 400.0, 4001)

    def first_contact(yc: float):
        d, n = obj.signed_distance(np.stack([xs, np.full_like(xs, yc)], axis=1))
        hit = np.flatnonzero(d <= r_tip)
        if not len(hit):
            return None
        i = hit[0]
        return xs[i], yc - r_tip * n[i, 1], np.flatnonzero((d >= r_tip + gap) & (xs < xs[i]))

    lo, hi = contact_y - 2.0 * r_tip, contact_y + 2.0 * r_tip
    for _ in range(50):  # bisection on the centre's y: the contact's y grows with it
        mid = 0.5 * (lo + hi)
        fc = first_contact(mid)
        if fc is None:
            lo, hi = (mid, hi) if mid < contact_y else (lo, mid)
            continue
        lo, hi = (mid, hi) if fc[1] < contact_y else (lo, mid)
    fc = first_contact(0.5 * (lo + hi))
    if fc is None or not len(fc[2]):
        raise InputError(f"no approach along +x reaches the object at y = {contact_y} mm")
    return float(xs[fc[2][-1]]), 0.5 * (lo + hi)


def _trace_one(obj, chain: ChainSimulator, finger: Finger, *, start_y: float, end_y: float, step: float,
               approach_step: float, retreat: float, contact_threshold: float, table_threshold: float,
               lift: float, stiffness: float, feeler_height: float, max_frames: int, corner_margin: float,
               first_index: int, joint_error_deg: float = 0.0, rng=None, gap: float = 4.0) -> dict:
    from optitact.forces.contact_events import ContactDetector

    sensor = chain.sensor
    r_tip = sensor.outer_radius + feeler_height
    table = Table(0.0)
    probe = _Probe(chain, finger, (table, obj), stiffness=stiffness, feeler_height=feeler_height,
                   first_index=first_index, max_frames=max_frames, joint_error=math.radians(joint_error_deg),
                   rng=rng)
    tool0 = dataclasses.replace(finger, tool=0.0)
    c_nominal = tool0.forward(POSE_TRACE)
    centre = np.array([*_start_point(obj, start_y, r_tip, gap), 0.0])
    # ---- seek the table: lower the z-stage until an element feels 0.2 N
    z_stage = r_tip + 6.0 - c_nominal[2]
    centre[2] = c_nominal[2] + z_stage
    probe.move(centre, z_stage)
    det = ContactDetector(table_threshold)
    table_est = None
    while not probe.exhausted:
        s = probe.sense()
        state = det.update(s["est"][:, 2])
        if state.any():
            e = int(np.argmax(np.where(state, s["est"][:, 2], -np.inf)))
            table_est = float(s["tips"][e, 2] + s["est"][e, 2] / stiffness)
            break
        z_stage -= 1.0
        probe.move(np.array([centre[0], centre[1], c_nominal[2] + z_stage]), z_stage)
    if table_est is None:
        return {"failure": "the table was not found", "frames": probe.frames}
    # ---- lift: the lowest feeler tip `lift` mm above the estimated table
    lowest = float(s["tips"][:, 2].min())
    z_stage += (table_est - lowest) + lift
    c_z = c_nominal[2] + z_stage
    table_frames = probe.frames
    # ---- trace: advance/retreat rules with square search
    det = ContactDetector(contact_threshold)
    n_in, d = np.array([1.0, 0.0]), np.array([0.0, 1.0])
    c = centre[:2].copy()
    path, contacts, normals, forces = [c.copy()], [], [], []
    travel, turns, n_turns, lost = 0.0, 0, 0, False
    failure, table_touches = None, 0
    while not probe.exhausted:
        try:
            probe.move(np.array([c[0], c[1], c_z]), z_stage)
        except (UnreachableError, SingularityError) as exc:
            failure, lost = f"stopped: {exc}", True
            break
        s = probe.sense()
        state = det.update(s["est"][:, 2])
        total = s["world"][state].sum(axis=0)
        if state.any() and total[2] > math.hypot(total[0], total[1]):
            # Pushed up more than sideways: the table (a finger that sagged), not the object's wall.
            table_touches += 1
            state[:] = False
        if state.any():
            fz = np.where(state, s["est"][:, 2], -np.inf)
            e = int(np.argmax(fz))
            nhat = _unit(total)
            point = s["tips"][e] + (s["est"][e, 2] / stiffness) * nhat
            contacts.append(point[:2])
            forces.append(float(np.linalg.norm(total)))
            n2 = _unit(total[:2])
            if np.linalg.norm(n2) > 0:
                n_in = -n2
                d = _rot_ccw(n_in)
            normals.append(-n_in)
            travel, turns = 0.0, 0
            if point[1] >= end_y:
                break
            c = c - n_in * retreat + d * step
        else:
            if not contacts and travel >= gap + 4.0 * (retreat + step):
                failure, lost = "the object was not found on the first approach", True
                break
            if contacts and travel >= retreat + step:  # the first approach goes on until it touches
                turns += 1
                n_turns += 1
                if turns > 4:
                    lost = True
                    break
                n_in, d = -d, n_in
                travel = 0.0
            c = c + n_in * approach_step
            travel += approach_step
        path.append(c.copy())
    pts = np.array(contacts).reshape(-1, 2)
    dev = np.abs(obj.signed_distance(pts)[0]) if len(pts) else np.zeros(0)
    corners = obj.corners
    if len(corners) and len(pts):
        near = np.min(np.linalg.norm(pts[:, None, :] - corners[None], axis=2), axis=1) < corner_margin
    else:
        near = np.zeros(len(pts), bool)
    keep = dev[~near]
    return {"contacts": pts, "path": np.array(path), "normals": np.array(normals).reshape(-1, 2),
            "contact_force_n": forces, "deviation_mm": dev, "near_corner": near,
            "max_deviation_mm": float(dev.max()) if len(dev) else None,
            "mean_deviation_mm": float(dev.mean()) if len(dev) else None,
            "max_deviation_except_corners_mm": float(keep.max()) if len(keep) else None,
            "n_contacts": int(len(pts)), "square_search_turns": n_turns, "lost": lost, "failure": failure,
            "table_touches": table_touches,
            "reached_end": bool(len(pts) and pts[-1, 1] >= end_y),
            "frames": probe.frames, "table": {"true_z": 0.0, "estimated_z": table_est, "frames": table_frames},
            "trace_height_mm": float(c_z), "outline": obj.outline(), "corners": corners}


def contour_tracing(*, chain: ChainSimulator | None = None, objects=("cylinder", "box"),
                    finger: Finger | None = None, span: float = 18.0, step: float = 5.0,
                    approach_step: float = 1.0, retreat: float = 2.0, contact_threshold: float = 0.3,
                    table_threshold: float = 0.2, lift: float = 5.0, stiffness: float = 0.5,
                    feeler_height: float = 1.0, max_frames: int = 120, corner_margin: float = 5.0,
                    joint_error_deg: float = 0.0, seed: int = 0, progress: bool = True) -> dict:
    r"""Trace the contour of a cylinder and a box on a table with the dome, from estimated forces.

    Parameters
    ----------
    chain : ChainSimulator, optional
        Default ``ChainSimulator(seed=seed)``.
    objects : sequence
        ``"cylinder"`` (radius 30 mm), ``"box"`` (40 x 40 mm, a corner
        facing the finger) or :class:`~optitact.finger.scene.Cylinder` /
        :class:`~optitact.finger.scene.Box` instances
        (placed in front of the finger, near x = 200 mm).
    finger : Finger, optional
        Default ``Finger()``, in ``POSE_TRACE`` (sensor axis 45 deg down).
    span : float
        The trace runs from ``y = -span`` to ``y = +span`` (mm), default 18.
    step : float
        Advance along the contour after each contact (mm), published 5.
    approach_step, retreat : float
        Approach increment towards the object and retreat after a contact
        (mm), default 1 and 2.
    contact_threshold, table_threshold : float
        Per-element normal force thresholds (N), published 0.3 and 0.2
        (with hysteresis, :class:`optitact.forces.contact_events.ContactDetector`).
    lift : float
        Clearance of the lowest feeler above the table while tracing (mm),
        published 5.
    stiffness, feeler_height : float
        Of :func:`optitact.finger.scene.feeler_forces`.
    max_frames : int
        Frame budget per object (default 120).
    corner_margin : float
        Contacts nearer than this to a box corner (mm) are left out of
        ``max_deviation_except_corners_mm``.
    joint_error_deg : float
        Standard deviation (deg) of an unmeasured joint-angle error drawn
        at each move (backlash, encoder and gear errors of a real finger):
        the contact happens at the actual pose, the controller computes
        with the commanded one. Default 0: an ideal finger, so the
        deviations measure the sensing alone.
    seed : int
    progress : bool

    Returns
    -------
    dict
        JSON-ready: one entry per object under ``objects`` with its
        ``contacts`` (estimated contact points, mm), ``path`` (dome-centre
        path), ``deviation_mm`` per contact, ``max_deviation_mm``,
        ``max_deviation_except_corners_mm``, ``table`` (true and estimated
        height), ``frames``, ``square_search_turns``; ``settings``,
        ``seconds``.

    Notes
    -----
    1. *Seek the table*: the dome, tilted 45 deg down, is lowered by the
       z-stage in 1 mm steps until an element's estimated normal force
       reaches 0.2 N; the table height is that element's feeler tip plus
       its estimated indentation ``F_z / k``.
    2. *Lift* so that the lowest feeler clears the table by ``lift``.
    3. *Trace* in that horizontal plane, moving the dome centre with RMRC:
       approach the object in ``approach_step`` increments along the
       inward direction until an element reads 0.3 N (the first approach,
       from 4 mm clear, goes on until it touches, up to 4 mm plus four
       square-search sides); then record the
       contact point (the loaded feeler's tip, moved out by its estimated
       indentation along the estimated force), take the estimated force's
       horizontal direction as the surface normal, *retreat* ``retreat`` mm
       along it and *advance* ``step`` mm along the tangent. When the
       approach runs ``retreat + step`` mm without contact (the surface
       turned away, at a corner), *square search*: turn the search
       direction by 90 deg towards the object and approach again (at most
       4 turns). A contact whose estimated force pushes up more than
       sideways is the table (only a finger with joint errors sags that far):
       it is counted (``table_touches``), not recorded, and the approach
       goes on.

    The published deviations (about 3.6 mm on a cylinder, 2.7 mm on a box
    away from the corners) are of the real finger, whose positioning errors
    dominate them; with an ideal finger (``joint_error_deg=0``) the contact
    points here are off only by the estimated indentation's error (the
    feeler tip's position is known from the kinematics), a few hundredths
    of a millimetre; ``joint_error_deg`` adds the finger's own errors.
    """
    from tqdm import tqdm

    seed = study_seed(seed)
    chain = chain_for(chain, seed)
    finger = Finger() if finger is None else finger
    span = positive(span, "span")
    opts = dict(step=positive(step, "step"), approach_step=positive(approach_step, "approach_step"),
                retreat=positive(retreat, "retreat"),
                contact_threshold=positive(contact_threshold, "contact_threshold"),
                table_threshold=positive(table_threshold, "table_threshold"), lift=positive(lift, "lift"),
                stiffness=positive(stiffness, "stiffness"),
                feeler_height=positive(feeler_height, "feeler_height", allow_zero=True),
                max_frames=integer(max_frames, "max_frames", minimum=1),
                corner_margin=positive(corner_margin, "corner_margin", allow_zero=True),
                joint_error_deg=positive(joint_error_deg, "joint_error_deg", allow_zero=True))
    t0 = time.perf_counter()
    r_tip = chain.sensor.outer_radius + opts["feeler_height"]
    front = float(dataclasses.replace(finger, tool=0.0).forward(POSE_TRACE)[0] + r_tip) - 12.0
    out = {}
    index = 0
    items = list(objects)
    for k, item in enumerate(tqdm(items, desc="contour tracing", unit="object", file=sys.stderr,
                                  disable=not progress)):
        if item == "cylinder":
            obj, name = Cylinder(center=(front + 30.0, 0.0), radius=30.0), "cylinder"
        elif item == "box":
            half_diag = 40.0 / math.sqrt(2.0)
            obj, name = Box(center=(front + half_diag, 0.0), size=(40.0, 40.0), angle_deg=45.0), "box"
        elif isinstance(item, (Cylinder, Box)):
            obj, name = item, f"{type(item).__name__.lower()}{k}"
        else:
            raise InputError(f"objects must hold 'cylinder', 'box', Cylinder or Box, got {item!r}")
        res = _trace_one(obj, chain, finger, start_y=-span, end_y=span, first_index=index,
                         rng=np.random.default_rng([seed, 31, k]), **opts)
        index += 100_000
        res["object"] = {"kind": type(obj).__name__.lower(), **dataclasses.asdict(obj)}
        out[name] = res
    return jsonable({"objects": out, "settings": {**opts, "span_mm": span, "finger": finger.to_dict(),
                                                   "chain": chain.describe(), "seed": seed},
                      "seconds": time.perf_counter() - t0})


#: Published largest deviations of traced contours (mm): the cylinder, and the box away from its corners.
PUBLISHED_DEVIATION_MM = {"cylinder": 3.6, "box": 2.7}


def joint_error_study(*, chain: ChainSimulator | None = None, joint_errors_deg=(0.0, 0.25, 0.5, 1.0),
                      repeats: int = 3, objects=("cylinder", "box"), baseline: dict | None = None,
                      seed: int = 0, progress: bool = True, **trace_options) -> dict:
    """Contour-tracing deviations against the finger's own (unmeasured) joint errors.

    With an ideal finger the traced contour is off only by the sensing error (hundredths of a
    millimetre); the published deviations (about 3.6 mm on the cylinder, 2.7 mm on the box away
    from its corners) are dominated by the real finger's positioning. This traces each object
    ``repeats`` times at each joint-angle error level (:func:`contour_tracing`'s
    ``joint_error_deg``, different seeds) and reports the largest deviation per trace, so the
    published figures can be read as an equivalent joint error.

    Parameters
    ----------
    chain : ChainSimulator, optional
    joint_errors_deg : sequence of float
        Standard deviations of the joint-angle error (deg), default 0, 0.25, 0.5, 1.
    repeats : int
        Traces per level and object (default 3; an ideal finger is traced once).
    objects : sequence
        As for :func:`contour_tracing`.
    baseline : dict, optional
        A :func:`contour_tracing` result of the ideal finger with this seed, reused for level 0.
    seed : int
    progress : bool
    **trace_options
        Passed to :func:`contour_tracing` (``span``, ``max_frames``, ...).

    Returns
    -------
    dict
        JSON-ready: ``joint_error_deg``, and per object ``max_deviation_mm`` (the cylinder's
        largest deviation, the box's away from its corners) as a list per level (one value per
        repeat), their ``median`` and ``mean``, the ``published_mm`` figure, and ``seconds``.
    """
    seed = study_seed(seed)
    chain = chain_for(chain, seed)
    levels = [positive(v, f"joint_errors_deg[{i}]", allow_zero=True) for i, v in enumerate(joint_errors_deg)]
    repeats = integer(repeats, "repeats", minimum=1)
    t0 = time.perf_counter()
    names = [o if isinstance(o, str) else f"{type(o).__name__.lower()}{k}" for k, o in enumerate(objects)]
    per = {n: [] for n in names}
    for level in levels:
        runs = {n: [] for n in names}
        for r in range(1 if level == 0 else repeats):
            if level == 0 and baseline is not None and r == 0:
                res = baseline
            else:
                res = contour_tracing(chain=chain, objects=objects, joint_error_deg=level,
                                      seed=seed + 1000 * r, progress=progress, **trace_options)
            for n in names:  # without corners this is the plain largest deviation
                runs[n].append(res["objects"].get(n, {}).get("max_deviation_except_corners_mm"))
        for n in names:
            per[n].append(runs[n])
    out = {"joint_error_deg": levels, "repeats": repeats, "objects": {}}
    for n in names:
        vals = per[n]
        rows = [[v for v in row if v is not None] for row in vals]
        out["objects"][n] = {"max_deviation_mm": vals,
                             "median": [float(np.median(r)) if r else None for r in rows],
                             "mean": [float(np.mean(r)) if r else None for r in rows],
                             "published_mm": PUBLISHED_DEVIATION_MM.get(n)}
    out["seconds"] = time.perf_counter() - t0
    return jsonable(out)



def draw_joint_error(ax, study: dict) -> None:
    """Fill the axes ``ax`` from a :func:`joint_error_study` result: largest deviation per joint error."""
    levels = np.asarray(need(study, "joint_error_deg"), float)
    for k, (name, o) in enumerate(need(study, "objects").items()):
        color = f"C{k}"
        for lv, row in zip(levels, o["max_deviation_mm"], strict=True):
            vals = [v for v in row if v is not None]
            ax.plot([lv] * len(vals), vals, "o", color=color, alpha=0.5, ms=4)
        label = f"{name} (except corners)" if name == "box" else name
        ax.plot(levels, np.array(o["median"], dtype=float), "-", color=color, label=f"{label}, median")
        if o.get("published_mm") is not None:
            ax.axhline(o["published_mm"], color=color, ls=":", lw=1)
            ax.text(levels.max(), o["published_mm"], f" published {name} {o['published_mm']:g} mm", color=color,
                    fontsize=6, va="bottom", ha="right")
    ax.set_xlabel("joint-angle error of the finger, sd (deg)")
    ax.set_ylabel("largest deviation (mm)")
    ax.set_title("traced contour vs the finger's own errors", fontsize=8)
    ax.legend(fontsize=6, loc="upper left")


def draw(fig, result: dict, study: dict | None = None) -> None:
    """Fill ``fig`` from a :func:`contour_tracing` result: true contours, path, contact points.

    With ``study`` (a :func:`joint_error_study` result) a last panel shows it.
    """
    objs = need(result, "objects")
    axes = np.atleast_1d(fig.subplots(1, max(len(objs), 1) + (study is not None)))
    if study is not None:
        draw_joint_error(axes[-1], study)
        axes = axes[:-1]
    for ax, (name, r) in zip(axes, objs.items(), strict=False):
        if "outline" not in r:
            ax.set_title(f"{name}: {r.get('failure')}", fontsize=8)
            continue
        out = np.asarray(r["outline"])
        ax.plot(out[:, 0], out[:, 1], "k-", lw=1.5, label="true contour")
        path = np.asarray(r["path"])
        ax.plot(path[:, 0], path[:, 1], ".-", color="0.6", lw=0.8, ms=3, label="dome centre")
        pts = np.asarray(r["contacts"]).reshape(-1, 2)
        if len(pts):
            sc = ax.scatter(pts[:, 0], pts[:, 1], c=r["deviation_mm"], cmap="viridis", s=25, zorder=3,
                            label="contacts")
            fig.colorbar(sc, ax=ax, label="deviation (mm)", shrink=0.8)
        ax.set_aspect("equal")
        lo = np.vstack([pts, path]).min(axis=0) - 10 if len(pts) else path.min(axis=0) - 10
        hi = np.vstack([pts, path]).max(axis=0) + 10 if len(pts) else path.max(axis=0) + 10
        ax.set_xlim(lo[0], max(hi[0], out[:, 0].min() + 20))
        ax.set_ylim(lo[1], hi[1])
        md, mc = r["max_deviation_mm"], r["max_deviation_except_corners_mm"]
        text = f"max dev {md:.2f} mm" if md is not None else "no contact"
        if len(r.get("corners", [])) and mc is not None:
            text += f", except corners {mc:.2f} mm"
        ax.set_title(f"{name}: {text}", fontsize=8)
        ax.set_xlabel("x (mm)")
        ax.set_ylabel("y (mm)")
        ax.legend(fontsize=6, loc="lower left")
