"""A six-axis force/torque sensor's totals: its CSV, its pose, and the map from element forces to them.

A lab presses objects anywhere on the dome while a six-axis force/torque
(F/T) sensor under the dome's mount records the total wrench. This module
reads those wrenches (:func:`read_wrench`), places the F/T sensor relative to
the dome (:class:`SensorPose`), maps element-local forces to the wrench the
F/T sensor sees (:func:`wrench_matrix`, :func:`element_wrench`), and checks
that a set of loaded frames can pin down every element
(:func:`check_identifiable`). A fit of per-element curves to the totals
builds on these.

Convention
----------
The wrench ``(fx, fy, fz, tx, ty, tz)`` is the one **the object exerts on the
dome** (what an F/T sensor under the mount measures once tared at no load),
**in the F/T sensor's own frame**, with the torque **about the F/T sensor's
origin**. Forces are in N and torques in N m (not the N mm of the rest of
optitact: F/T sensors and their software use N m; :func:`wrench_matrix`
converts the dome's mm).

The F/T sensor's pose (:class:`SensorPose`) is a rotation ``R`` taking
vectors from the F/T frame to the dome's sensor frame
(:mod:`optitact.optics.sensor`: origin at the centre of the dome's base
circle, ``z`` up through the apex) and the F/T origin ``p`` in mm in the
dome frame: a point ``X_ft`` in the F/T frame is ``R X_ft + p`` in the dome
frame.

Element forces act at the tip of each element's columnar feeler, ``(R_o +
h) n_i`` in the dome frame (``R_o`` the dome's outer radius, ``h`` the
sensor's :attr:`~optitact.optics.sensor.DomeSensor.lever_arm`, ``n_i`` the
element's outward normal); see :func:`contact_points`.

The wrench CSV
--------------
One row per frame, columns found by name (any order, any case, ``,`` ``;``
or tab as :func:`optitact.io.tables.sniff_delimiter` tells them; other
columns are ignored)::

    frame,fx,fy,fz,tx,ty,tz

``frame`` names the frame as the force gauge's CSV does
(:mod:`optitact.calib.gauge`): its source as ``optitact process`` names it in
its ``source`` column (``press_001.png``, or ``clip.avi#12`` for frame 12 of
a video or ``.npy`` stack) or a 0-based index into all the frames in the
order they are read. A frame with no row has no known wrench and is not used
(unlike the gauge, where it is a no-load sample); a frame listed twice is an
error.

Units. A force column's unit is written in brackets after its name as in the
gauge's CSV (``Fz (mN)``, one of :data:`optitact.io.tables.FORCE_UNITS`, any
case; none: N). A torque column's unit is one of :data:`TORQUE_UNITS` in any
case (``Tx (N·mm)``; none: N m), the force and the length joined by ``·``,
``*``, ``.``, ``-``, a space or nothing (``N·m``, ``N*m``, ``N.m``, ``N-m``,
``Nm``); the imperial ones may also be written length first (``in·lbf``).
Any other unit is refused by name: a mass times a length (``kg·cm``,
``lb·in``: write ``kgf·cm``, ``lbf·in``), a force in a torque column or a
torque in a force column, and a unit glued to the name (``tz_Nmm``: write
``Tz (N·mm)``). Two columns of one name are refused as ambiguous.

Checks. Every number must be finite. A force beyond
:data:`MAX_WRENCH_FORCE_N` (200 N in all) is refused as a likely unit
mistake, naming the line and frame. So is a torque that would put the force
further from the F/T origin than :data:`MAX_LEVER_FACTOR` times the dome's
size plus the F/T sensor's offset (``|t| / |f|`` beyond ``10 (R_o + h +
|p|)``; torques in N mm read as N m are 1000 times too large); forces below
:data:`LEVER_FORCE_FLOOR_N` are taken as that floor for this check, so that
the noise of a tared no-load frame passes. A file where every frame's force
is zero is refused (nothing to fit).

Encoding and lines as the gauge's CSV: UTF-8 (with or without a byte-order
mark), UTF-16 with a byte-order mark, else Windows-1252 (or Latin-1); lines
of at most :data:`optitact.calib.gauge.MAX_LINE_CHARS` characters; blank lines
and lines starting with ``#`` are ignored.
"""

from __future__ import annotations

import json
import math
import os
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from optitact._validate import check_keys, check_type, integer, json_numbers, real_array
from optitact.calib.gauge import MAX_LINE_CHARS, frame_of
from optitact.errors import InputError, ShapeError
from optitact.io.tables import FORCE_UNITS, MASS_UNITS, column_key, force_unit, text_rows
from optitact.optics.camera import rotation_from_rvec
from optitact.optics.sensor import DomeSensor

__all__ = ["LEVER_FORCE_FLOOR_N", "MAX_LEVER_FACTOR", "MAX_POSE_DISTANCE_MM", "MAX_WRENCH_FORCE_N",
           "SensorPose", "TORQUE_UNITS", "UnidentifiableError", "Wrenches", "check_identifiable",
           "contact_points", "element_wrench", "read_wrench", "torque_unit", "wrench_matrix"]

#: The largest total force (N) an F/T sensor's row may give: beyond it, a unit left out of the header.
MAX_WRENCH_FORCE_N = 200.0
#: How far from the F/T origin a torque may put the force: this many times (outer radius + lever arm +
#: the F/T origin's distance from the dome's centre); beyond it, torques in N mm read as N m.
MAX_LEVER_FACTOR = 10.0
#: Forces (N) below this count as this much in the lever-arm check (the noise of a tared no-load frame).
LEVER_FORCE_FLOOR_N = 0.05
#: The farthest (mm) an F/T sensor's origin may be from the dome's centre (further: metres or µm for mm).
MAX_POSE_DISTANCE_MM = 1000.0

_LBF_IN = FORCE_UNITS["lbf"] * 0.0254
#: The units a torque column may name in brackets (any case, any separator), in N m per unit.
TORQUE_UNITS = {"N·m": 1.0, "mN·m": 1e-3, "N·cm": 1e-2, "N·mm": 1e-3, "gf·cm": FORCE_UNITS["gf"] * 1e-2,
                "kgf·cm": FORCE_UNITS["kgf"] * 1e-2, "kgf·m": FORCE_UNITS["kgf"], "lbf·in": _LBF_IN,
                "lbf·ft": FORCE_UNITS["lbf"] * 0.3048, "ozf·in": _LBF_IN / 16}
_IMPERIAL = ("lbf·in", "lbf·ft", "ozf·in")  # also written length first: in·lbf, ft·lbf, in·ozf
_SEPARATORS = re.compile(r"[\s·⋅∙*.\-×]+")
_BRACKETS = re.compile(r"[\(\[]\s*([^\)\]]*?)\s*[\)\]]\s*$")
_LENGTHS = ("m", "cm", "mm", "in", "ft")

_COLUMNS = ("frame", "fx", "fy", "fz", "tx", "ty", "tz")
_FORCES = ("fx", "fy", "fz")
_TORQUES = ("tx", "ty", "tz")
_CONTACT = ("tip", "surface")


def _spellings() -> dict[str, str]:
    """Every accepted torque spelling, separators dropped and lower case, to its :data:`TORQUE_UNITS` key."""
    out = {}
    for unit in TORQUE_UNITS:
        force, length = unit.split("·")
        out[(force + length).lower()] = unit
        if unit in _IMPERIAL:
            out[(length + force).lower()] = unit
    return out


_SPELLINGS = _spellings()


def _mass_torques() -> dict[str, str]:
    """Mass-times-length spellings (``kgcm``, ``inlb``) to the torque unit meant."""
    out = {}
    for mass, force in MASS_UNITS.items():
        for length in _LENGTHS:
            unit = f"{force}·{length}"
            if unit in TORQUE_UNITS:
                out[mass + length] = unit
                out[length + mass] = unit
    return out


_MASS_TORQUES = _mass_torques()


def _torque_key(unit: str) -> str:
    return _SEPARATORS.sub("", unit).lower()


def torque_unit(cell: str) -> float:
    """N m per unit of a torque column's header cell: ``"Tz (N·mm)"`` -> 0.001; no unit: 1.

    Parameters
    ----------
    cell : str
        The header cell, its unit in brackets after the name.

    Returns
    -------
    float
        The factor taking the column's values to N m.

    Raises
    ------
    InputError
        A unit that is not one of :data:`TORQUE_UNITS` (any case; the force
        and the length joined by ``·``, ``*``, ``.``, ``-``, a space or
        nothing), named with the accepted ones: a force (``N``), a mass times
        a length (``kg·cm``: the message says ``kgf·cm``), ``MN·m``
        (meganewton metres: write ``mN·m``), anything else.

    Examples
    --------
    >>> torque_unit("Tz (N·mm)"), torque_unit("tx [Nm]"), torque_unit("TY"), torque_unit("tx (N-m)")
    (0.001, 1.0, 1.0, 1.0)
    >>> round(torque_unit("Tz (lbf*in)"), 6), round(torque_unit("Tz (in-lbf)"), 6)
    (0.112985, 0.112985)
    """
    m = _BRACKETS.search(cell)
    if m is None:
        return 1.0
    unit = m.group(1)
    key = _torque_key(unit)
    accepted = ", ".join(TORQUE_UNITS)
    if key.startswith("mn") and key[2:] in _LENGTHS and unit.lstrip().startswith("MN"):
        raise InputError(f"unit {unit!r} is meganewton metres; write mN·m for millinewton metres (accepted: "
                         f"{accepted})")
    if key in _SPELLINGS:
        return TORQUE_UNITS[_SPELLINGS[key]]
    hint = ""
    if key in _MASS_TORQUES:
        hint = (f"; {unit!r} is a mass times a length: if the F/T sensor reads {_MASS_TORQUES[key]} (a force "
                f"times a length), write {_MASS_TORQUES[key]}")
    else:
        try:
            force_unit(f"t ({unit})")
        except InputError:
            pass
        else:
            hint = f"; {unit!r} is a force unit, and tx, ty, tz are torques (a force times a length)"
    raise InputError(f"unknown torque unit {unit!r}; the accepted units are {accepted} (any case, the force "
                     f"and the length joined by '·', '*', '.', '-', a space or nothing: 'Tz (N·mm)', "
                     f"'Tz (Nmm)'){hint}")


# ---------------------------------------------------------------------------- the F/T sensor's pose
def _frozen(a: np.ndarray) -> np.ndarray:
    a = np.array(a, dtype=np.float64)
    a.setflags(write=False)
    return a


@dataclass(frozen=True, eq=False)
class SensorPose:
    """Where the six-axis F/T sensor is relative to the dome.

    A point ``X_ft`` in the F/T sensor's frame is ``rotation @ X_ft +
    position`` in the dome's sensor frame (:mod:`optitact.optics.sensor`:
    origin at the centre of the dome's base circle, ``z`` up through the
    apex; mm). The columns of ``rotation`` are the F/T sensor's axes in the
    dome frame.

    Parameters
    ----------
    rotation : (3, 3) array_like
        The rotation from the F/T frame to the dome frame (orthonormal,
        determinant +1); default the identity (axes aligned).
    position : (3,) array_like
        The F/T sensor's origin in the dome frame (mm); default the centre of
        the dome's base circle.

    Raises
    ------
    ShapeError
        ``rotation`` not (3, 3) or ``position`` not (3,).
    InputError
        A value that is not finite, a rotation that is not orthonormal
        (``|R^T R - I|`` beyond 1e-6) or is a reflection, a position further
        than :data:`MAX_POSE_DISTANCE_MM` from the dome's centre. That the
        origin is not inside the dome is checked against a sensor
        (:meth:`check`).

    Notes
    -----
    The rotation vector of :meth:`from_rotation_vector`, :meth:`from_string`
    and the JSON files is an axis times an angle in degrees, rotating the
    dome's axes onto the F/T sensor's: an F/T sensor under the dome with its
    ``z`` pointing down is ``0,0,-30,180,0,0`` (30 mm below the base centre,
    turned half a turn about ``x``).

    Examples
    --------
    >>> p = SensorPose.from_string("0, 0, -30, 180, 0, 0")
    >>> p.position.tolist(), (np.round(p.rotation, 12) + 0.0).tolist()
    ([0.0, 0.0, -30.0], [[1.0, 0.0, 0.0], [0.0, -1.0, 0.0], [0.0, 0.0, -1.0]])
    """

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    position: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        rot = real_array(self.rotation, "rotation")
        pos = real_array(self.position, "position")
        if rot.shape != (3, 3):
            raise ShapeError(f"rotation must be a (3, 3) matrix (F/T frame to dome frame), got shape "
                             f"{rot.shape}")
        if pos.shape != (3,):
            raise ShapeError(f"position must be (x, y, z) in mm, got shape {pos.shape}")
        if not np.isfinite(rot).all():
            raise InputError(f"rotation must be finite, got {rot.tolist()}")
        if not np.isfinite(pos).all():
            raise InputError(f"position must be finite (x, y, z in mm), got {pos.tolist()}")
        err = float(np.abs(rot.T @ rot - np.eye(3)).max())
        if err > 1e-6:
            raise InputError(f"rotation must be orthonormal (R^T R = I; a rotation matrix from the F/T frame "
                             f"to the dome frame), but R^T R differs from I by {err:.3g}: {rot.tolist()}")
        if np.linalg.det(rot) < 0:
            raise InputError(f"rotation must be a rotation (determinant +1), got a reflection (determinant "
                             f"-1): {rot.tolist()}; is one axis of the F/T frame flipped?")
        dist = float(np.linalg.norm(pos))
        if dist > MAX_POSE_DISTANCE_MM:
            raise InputError(f"the F/T sensor's origin at {_mm(pos)} is {dist:.6g} mm from the dome's centre, "
                             f"more than the {MAX_POSE_DISTANCE_MM:g} mm an F/T sensor under the dome's mount "
                             f"can be; the position is in mm (not m or µm)")
        object.__setattr__(self, "rotation", _frozen(rot))
        object.__setattr__(self, "position", _frozen(pos))

    def __repr__(self) -> str:
        return (f"SensorPose(position_mm={self.position.tolist()}, "
                f"rotation_deg={np.round(self.rotation_deg, 12).tolist()})")

    @property
    def rotation_deg(self) -> np.ndarray:
        """The rotation as a rotation vector (axis times angle, degrees), shape (3,)."""
        from scipy.spatial.transform import Rotation

        return Rotation.from_matrix(self.rotation).as_rotvec(degrees=True)

    @classmethod
    def from_rotation_vector(cls, position_mm, rotation_deg=(0.0, 0.0, 0.0)) -> SensorPose:
        """A pose from the F/T origin (mm) and a rotation vector (axis times angle, degrees).

        Parameters
        ----------
        position_mm : (3,) array_like
            The F/T sensor's origin in the dome frame (mm).
        rotation_deg : (3,) array_like
            The rotation from the F/T frame to the dome frame as an axis
            times an angle in degrees (the Rodrigues vector in degrees).

        Returns
        -------
        SensorPose
        """
        rv = real_array(rotation_deg, "rotation_deg")
        if rv.shape != (3,):
            raise ShapeError(f"rotation_deg must be (rx, ry, rz) in degrees, got shape {rv.shape}")
        if not np.isfinite(rv).all():
            raise InputError(f"rotation_deg must be finite, got {rv.tolist()}")
        return cls(rotation=rotation_from_rvec(np.deg2rad(rv)), position=position_mm)

    @classmethod
    def from_string(cls, text: str, *, sensor: DomeSensor | None = None) -> SensorPose:
        """A pose from ``"x,y,z"`` or ``"x,y,z,rx,ry,rz"`` (mm, then a rotation vector in degrees).

        What ``--ft-pose`` takes on the command line.

        Parameters
        ----------
        text : str
            Three or six numbers separated by commas (blanks around them are
            fine): the F/T origin in the dome frame (mm) and, optionally, the
            rotation from the F/T frame to the dome frame (axis times angle,
            degrees; default none).
        sensor : DomeSensor, optional
            When given, the pose is checked against it (:meth:`check`).

        Returns
        -------
        SensorPose

        Raises
        ------
        InputError
            Not three or six numbers, a cell that is not a finite number (the
            message names it and what was expected), a pose inside the dome.
        """
        check_type(text, str, "pose")
        expected = ("expected 'x,y,z' (the F/T sensor's origin in the dome frame, mm) or 'x,y,z,rx,ry,rz' "
                    "(then its rotation vector, degrees), e.g. '0,0,-30' or '0,0,-30,180,0,0'")
        cells = [c.strip() for c in text.split(",")]
        if len(cells) not in (3, 6):
            raise InputError(f"F/T sensor pose {text!r}: {expected}; got {len(cells)} value"
                             f"{'s' if len(cells) != 1 else ''}")
        values = []
        for k, cell in enumerate(cells, start=1):
            name = ("x", "y", "z", "rx", "ry", "rz")[k - 1]
            try:
                v = float(cell)
            except ValueError:
                raise InputError(f"F/T sensor pose {text!r}: {name} (value {k}) is {cell!r}, not a number; "
                                 f"{expected}") from None
            if not math.isfinite(v):
                raise InputError(f"F/T sensor pose {text!r}: {name} (value {k}) is {cell!r}, not finite; "
                                 f"{expected}")
            values.append(v)
        pose = cls.from_rotation_vector(values[:3], values[3:] or (0.0, 0.0, 0.0))
        return pose if sensor is None else pose.check(sensor)

    @classmethod
    def from_dict(cls, d, *, what: str = "F/T sensor pose", sensor: DomeSensor | None = None) -> SensorPose:
        """A pose from ``{"position_mm": [x, y, z], "rotation_deg": [rx, ry, rz]}`` or OpenCV's rvec and tvec.

        Parameters
        ----------
        d : dict
            Either ``position_mm`` (the F/T origin in the dome frame, mm) and
            optionally ``rotation_deg`` (the rotation from the F/T frame to
            the dome frame, axis times angle in degrees; default none), as
            :meth:`to_dict` writes; or OpenCV's ``rvec`` (radians) and
            ``tvec`` (mm) of the dome in the F/T frame, as ``cv2`` writes a
            camera's pose: ``X_ft = Rodrigues(rvec) X_dome + tvec``, so the
            rotation is ``Rodrigues(rvec)^T`` and the position
            ``-Rodrigues(rvec)^T tvec``.
        what : str
            What ``d`` is, for messages (a file's path).
        sensor : DomeSensor, optional
            When given, the pose is checked against it (:meth:`check`).

        Returns
        -------
        SensorPose

        Raises
        ------
        InputError
            Keys of neither form, or of both; values that are not three
            finite numbers; a pose inside the dome.
        """
        if not isinstance(d, dict):
            raise InputError(f"{what}: expected a JSON object {{\"position_mm\": [x, y, z], \"rotation_deg\": "
                             f"[rx, ry, rz]}} or {{\"rvec\": [...], \"tvec\": [...]}}, got {type(d).__name__}")
        ours, cv = {"position_mm", "rotation_deg"}, {"rvec", "tvec"}
        if set(d) & ours and set(d) & cv:
            raise InputError(f"{what}: keys {sorted(d)} mix the two forms; give position_mm (and rotation_deg) "
                             f"or OpenCV's rvec and tvec, not both")
        if set(d) & cv:
            d = check_keys(d, cv, what, required=("rvec", "tvec"))
            rvec = _three(d["rvec"], f"{what}: rvec (radians)")
            tvec = _three(d["tvec"], f"{what}: tvec (mm)")
            r = rotation_from_rvec(rvec)
            pose = cls(rotation=r.T, position=-r.T @ tvec)
        else:
            d = check_keys(d, ours, what, required=("position_mm",))
            position = _three(d["position_mm"], f"{what}: position_mm")
            rotation = _three(d.get("rotation_deg", [0.0, 0.0, 0.0]), f"{what}: rotation_deg")
            pose = cls.from_rotation_vector(position, rotation)
        return pose if sensor is None else pose.check(sensor)

    @classmethod
    def from_json(cls, path: str | os.PathLike, *, sensor: DomeSensor | None = None) -> SensorPose:
        """A pose from a JSON file holding one object as :meth:`from_dict` reads it.

        Parameters
        ----------
        path : path-like
            The JSON file.
        sensor : DomeSensor, optional
            When given, the pose is checked against it (:meth:`check`).

        Returns
        -------
        SensorPose

        Raises
        ------
        FileNotFoundError
            No file at ``path``.
        InputError
            Not JSON (the message gives the line), or see :meth:`from_dict`.
        """
        path = Path(path)
        if not path.is_file():
            raise FileNotFoundError(f"F/T sensor pose file not found: {path}")
        try:
            d = json.loads(path.read_text(encoding="utf-8-sig"))
        except UnicodeDecodeError as exc:
            raise InputError(f"{path}: not UTF-8 text ({exc.reason} at byte {exc.start}); expected a JSON "
                             f"file with the F/T sensor's pose") from None
        except json.JSONDecodeError as exc:
            raise InputError(f"{path}, line {exc.lineno}, column {exc.colno}: not JSON ({exc.msg}); expected "
                             f"{{\"position_mm\": [x, y, z], \"rotation_deg\": [rx, ry, rz]}}") from None
        return cls.from_dict(d, what=str(path), sensor=sensor)

    @classmethod
    def parse(cls, value: str | os.PathLike, *, sensor: DomeSensor | None = None) -> SensorPose:
        """A pose from what ``--ft-pose`` takes: a JSON file's path or a ``"x,y,z[,rx,ry,rz]"`` string.

        Parameters
        ----------
        value : str or path-like
            A path ending in ``.json`` or naming an existing file is read by
            :meth:`from_json`; anything else by :meth:`from_string`.
        sensor : DomeSensor, optional
            When given, the pose is checked against it (:meth:`check`).

        Returns
        -------
        SensorPose
        """
        if isinstance(value, os.PathLike) or str(value).lower().endswith(".json") or Path(str(value)).is_file():
            return cls.from_json(value, sensor=sensor)
        return cls.from_string(value, sensor=sensor)

    def to_dict(self) -> dict:
        """``{"position_mm": [x, y, z], "rotation_deg": [rx, ry, rz]}``, as :meth:`from_dict` reads it."""
        return {"position_mm": self.position.tolist(), "rotation_deg": self.rotation_deg.tolist()}

    def check(self, sensor: DomeSensor) -> SensorPose:
        """Refuse an F/T origin inside the dome (``|p| < R_o`` and ``z > 0``); return the pose.

        Parameters
        ----------
        sensor : DomeSensor

        Returns
        -------
        SensorPose
            ``self``.

        Raises
        ------
        InputError
            The origin lies inside the dome, where the camera and the light
            are; the message names the position and what a plausible pose
            looks like.
        """
        check_type(sensor, DomeSensor, "sensor")
        p = self.position
        r = float(np.linalg.norm(p))
        if r < sensor.outer_radius and p[2] > 0:
            flip = (f"; if you measured the dome's position in the F/T sensor's frame, the F/T sensor's "
                    f"origin in the dome frame is its negative ({_mm(-p)} for axes aligned)")
            raise InputError(f"the F/T sensor's origin at {_mm(p)} lies inside the dome (|p| = {r:.6g} mm < "
                             f"the outer radius {sensor.outer_radius:g} mm, z > 0), where the camera and the "
                             f"light are; an F/T sensor under the dome's mount lies below the dome's base "
                             f"plane z = 0, e.g. '0,0,-30' (30 mm below the base centre, axes aligned){flip}")
        return self


def _mm(p) -> str:
    return "(" + ", ".join(f"{float(v):.6g}" for v in p) + ") mm"


def _three(value, what: str) -> np.ndarray:
    a = json_numbers(value, what)
    if a.shape != (3,):
        raise InputError(f"{what} must be three numbers, got {value!r}")
    return a


# ---------------------------------------------------------------------------- element forces -> wrench
def contact_points(sensor: DomeSensor, at: str = "tip") -> np.ndarray:
    """Where each element's force acts, in the dome frame (mm), shape (E, 3).

    Parameters
    ----------
    sensor : DomeSensor
    at : {"tip", "surface"}
        ``"tip"`` (default): the tip of the element's columnar feeler, ``(R_o
        + lever_arm) n_i``, where the object touches the element and so where
        the external force enters the sensor (the cones pass it on to the
        dome as the same force plus the moment ``lever_arm x shear``, which
        together are that force at the tip). ``"surface"``: the element's
        centre on the outer dome surface, ``R_o n_i``
        (:attr:`~optitact.optics.sensor.DomeSensor.element_positions`, where
        the cones touch the dome).

    Returns
    -------
    (E, 3) ndarray

    Notes
    -----
    The normal force acts along ``n_i``, through the dome's centre, so the
    two points give the same wrench for it; they differ by ``lever_arm`` times
    the shear in torque (3 mN m per N of shear for the default sensor: 15 %
    of the shear's torque about the dome's centre).
    """
    check_type(sensor, DomeSensor, "sensor")
    if at not in _CONTACT:
        raise InputError(f"at must be one of {', '.join(_CONTACT)}, got {at!r}")
    radius = sensor.outer_radius + (sensor.lever_arm if at == "tip" else 0.0)
    return radius * sensor.element_frames[:, 2, :]


def wrench_matrix(sensor: DomeSensor, pose: SensorPose, *, at: str = "tip") -> np.ndarray:
    """The linear map from element-local forces to the wrench the F/T sensor sees, shape (E, 3, 6).

    Parameters
    ----------
    sensor : DomeSensor
    pose : SensorPose
        The F/T sensor's pose; refused inside the dome (:meth:`SensorPose.check`).
    at : {"tip", "surface"}
        Where each element's force acts (:func:`contact_points`).

    Returns
    -------
    (E, 3, 6) ndarray
        ``f_local[e] @ M[e]`` is element ``e``'s contribution to the wrench
        ``(fx, fy, fz, tx, ty, tz)`` (N and N m) in the F/T frame about its
        origin, for element-local ``f_local[e] = (Fx, Fy, Fz)`` in N; row
        ``j`` of ``M[e]`` is the wrench of 1 N along local axis ``j``. The
        wrench of forces ``(T, E, 3)`` is ``np.einsum("tej,ejk->tk", forces,
        M)`` (:func:`element_wrench`), or with the flat ``(3 E, 6)`` matrix,
        ``forces.reshape(T, -1) @ M.reshape(-1, 6)``.

    Notes
    -----
    Element ``e``'s global force is ``g_e = A_e f_e`` with ``A_e =
    frames_e^T diag(1, 1, -1)``
    (:func:`~optitact.optics.force_frames.global_from_local`), acting at
    ``c_e`` (:func:`contact_points`). About the F/T origin ``p`` and in the
    F/T frame (``R`` the pose's rotation) it contributes the force ``R^T
    g_e`` and the torque ``R^T ((c_e - p) x g_e) / 1000`` (mm N to N m).

    Examples
    --------
    >>> s = DomeSensor.default()
    >>> M = wrench_matrix(s, SensorPose.from_string("0,0,-30"))
    >>> M.shape, M[0, 2].round(6).tolist()  # 1 N pressing the apex element: down, on the axis
    ((41, 3, 6), [0.0, 0.0, -1.0, 0.0, 0.0, 0.0])
    """
    check_type(sensor, DomeSensor, "sensor")
    check_type(pose, SensorPose, "pose")
    pose.check(sensor)
    a = np.transpose(sensor.element_frames, (0, 2, 1)) * np.array([1.0, 1.0, -1.0])  # (E, 3, 3): to global
    r = (contact_points(sensor, at) - pose.position) * 1e-3  # m
    skew = np.zeros((len(r), 3, 3))
    skew[:, 0, 1], skew[:, 0, 2], skew[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    skew[:, 1, 0], skew[:, 2, 0], skew[:, 2, 1] = r[:, 2], -r[:, 1], r[:, 0]
    rt = pose.rotation.T
    force = np.einsum("ij,ejk->eik", rt, a)  # (E, 3 wrench rows, 3 local axes)
    torque = np.einsum("ij,ejk,ekl->eil", rt, skew, a)
    return np.ascontiguousarray(np.concatenate([force, torque], axis=1).transpose(0, 2, 1))


def element_wrench(sensor: DomeSensor, pose: SensorPose, forces, *, at: str = "tip") -> np.ndarray:
    """The wrench element-local forces exert, as the F/T sensor sees it.

    Parameters
    ----------
    sensor : DomeSensor
    pose : SensorPose
    forces : (E, 3) or (T, E, 3) array_like
        Element-local forces (N), one frame or ``T``.
    at : {"tip", "surface"}
        Where each element's force acts (:func:`contact_points`).

    Returns
    -------
    (6,) or (T, 6) ndarray
        ``(fx, fy, fz, tx, ty, tz)`` in N and N m, in the F/T frame about its
        origin (:func:`wrench_matrix`).

    Raises
    ------
    ShapeError
        ``forces`` not ``(E, 3)`` or ``(T, E, 3)``.
    InputError
        A force that is not finite.
    """
    m = wrench_matrix(sensor, pose, at=at)
    f = real_array(forces, "forces")
    n_el = sensor.n_elements
    if f.shape[-2:] != (n_el, 3) or f.ndim not in (2, 3):
        raise ShapeError(f"forces must have shape ({n_el}, 3) or (T, {n_el}, 3) (element-local Fx, Fy, Fz in "
                         f"N), got {f.shape}")
    if not np.isfinite(f).all():
        bad = tuple(int(i) for i in np.argwhere(~np.isfinite(f))[0])
        raise InputError(f"forces must be finite, got {f[bad]} at index {bad}")
    return np.einsum("...ej,ejk->...k", f, m)


# ---------------------------------------------------------------------------- the wrench CSV
@dataclass(frozen=True, eq=False)
class Wrenches:
    """The F/T sensor's wrenches of the frames its CSV lists (what :func:`read_wrench` returns).

    Attributes
    ----------
    frames : (n,) int ndarray
        The frames' 0-based indices into the sources, ascending.
    wrench : (n, 6) float64 ndarray
        ``(fx, fy, fz, tx, ty, tz)`` in N and N m: the wrench the object
        exerts on the dome, in the F/T frame about its origin.
    lines : (n,) int ndarray
        The CSV line of each frame's row.
    path : pathlib.Path
        The CSV.
    """

    frames: np.ndarray
    wrench: np.ndarray
    lines: np.ndarray
    path: Path

    @property
    def force(self) -> np.ndarray:
        """``(n, 3)`` forces (N)."""
        return self.wrench[:, :3]

    @property
    def torque(self) -> np.ndarray:
        """``(n, 3)`` torques (N m)."""
        return self.wrench[:, 3:]


def _glued_unit(key: str) -> str | None:
    """``'tz_nmm'`` -> ``'tz'``, ``'fz_mn'`` -> ``'fz'`` (a column's unit glued to its name), else None."""
    m = re.fullmatch(r"([ft][xyz])[\s_/-]+(.+)", key)
    if m is None:
        return None
    unit = _torque_key(m.group(2))
    forces = {u.lower() for u in FORCE_UNITS} | set(MASS_UNITS)
    return m.group(1) if unit in forces or unit in _SPELLINGS or unit in _MASS_TORQUES else None


def _column_unit(cell: str, name: str, path, lineno: int, col: int) -> float:
    """The factor of a force (to N) or torque (to N m) column's header cell, or an error naming it."""
    try:
        if name in _TORQUES:
            return torque_unit(cell)
        try:
            return force_unit(cell)
        except InputError as exc:
            unit = _BRACKETS.search(cell).group(1)
            if _torque_key(unit) in _SPELLINGS:
                raise InputError(f"{exc}; {unit!r} is a torque unit, and fx, fy, fz are forces") from None
            raise
    except InputError as exc:
        raise InputError(f"{path}, line {lineno}, column {col} ({cell!r}): {exc}") from None


def _number(cell: str, what: str, path, lineno: int, col: int, header: str) -> float:
    """A cell as a finite number, or an error naming the line, column, what was expected and what came."""
    try:
        v = float(cell)
    except ValueError:
        v = None
    if v is None or not math.isfinite(v):
        hint = "; a decimal comma? write a point" if re.fullmatch(r"[-+]?\d+,\d+", cell) else ""
        got = "not a number" if v is None else "not finite"
        raise InputError(f"{path}, line {lineno}, column {col} ({header!r}): expected a finite number "
                         f"({what}), got {cell!r} ({got}){hint}")
    return v


def read_wrench(path: str | os.PathLike, sources: Sequence[str], *, pose: SensorPose | None = None,
                sensor: DomeSensor | None = None) -> Wrenches:
    r"""Read a six-axis F/T sensor's CSV: the wrench of each frame it lists.

    Parameters
    ----------
    path : path-like
        The CSV (see the module docstring for its columns, units and encodings).
    sources : sequence of str
        The frames' sources in order (:attr:`optitact.pipeline.batch.ProcessedFrames.sources`).
    pose : SensorPose, optional
        The F/T sensor's pose: checked against the sensor, and its distance
        from the dome's centre widens the lever-arm check. Default: the F/T
        origin at the dome's base centre.
    sensor : DomeSensor, optional
        Default :meth:`DomeSensor.default() <optitact.optics.sensor.DomeSensor.default>`.

    Returns
    -------
    Wrenches
        The listed frames in ascending order, their wrenches in N and N m.

    Raises
    ------
    FileNotFoundError
        No file at ``path``.
    ShapeError
        No header naming ``frame, fx, fy, fz, tx, ty, tz``, a row of the
        wrong width, no rows.
    InputError
        Frames that do not exist (all of them named, with their lines), a
        frame listed twice, a number that is not finite, an unknown unit, two
        columns of one name, a force beyond :data:`MAX_WRENCH_FORCE_N`, a
        torque beyond the lever-arm check, no frame with a non-zero force, a
        file that is not UTF-8 or UTF-16 text, a line longer than
        :data:`~optitact.calib.gauge.MAX_LINE_CHARS`, a pose inside the dome.

    Examples
    --------
    >>> import pathlib, tempfile
    >>> p = pathlib.Path(tempfile.mkdtemp()) / "wrench.csv"
    >>> _ = p.write_text("Frame;Fx (mN);Fy (mN);Fz (mN);Tx (N·mm);Ty (N·mm);Tz (N·mm)\n"
    ...                  "press_1.png;0;0;-500;0;0;0\n2;100;0;-800;0;8;0\n", encoding="utf-8")
    >>> w = read_wrench(p, ["noload.png", "press_1.png", "press_2.png"])
    >>> w.frames.tolist(), w.wrench[1].tolist()
    ([1, 2], [0.1, 0.0, -0.8, 0.0, 0.008, 0.0])
    """
    sensor = DomeSensor.default() if sensor is None else check_type(sensor, DomeSensor, "sensor")
    pose = SensorPose() if pose is None else check_type(pose, SensorPose, "pose")
    pose.check(sensor)
    sources = [str(s) for s in sources]
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"F/T sensor wrench file not found: {path}")
    rows = text_rows(path, what="wrench CSV", max_chars=MAX_LINE_CHARS, columns=_COLUMNS,
                     holds="a frame and six numbers")
    if not rows:
        raise ShapeError(f"{path}: empty; expected a header {', '.join(_COLUMNS)} and one row per frame")
    header_line, first = rows[0]
    header = [column_key(c) for c in first]
    missing = [c for c in _COLUMNS if c not in header]
    if missing:
        glued = [(c, _glued_unit(k)) for c, k in zip(first, header, strict=True) if _glued_unit(k) in missing]
        hint = "".join(f"; write {c!r} as '{name.capitalize()} (unit)', the unit in brackets"
                       for c, name in glued[:1])
        moments = [c for c, k in zip(first, header, strict=True) if k in ("mx", "my", "mz")]
        if moments and not glued:
            hint = f"; name the torque (moment) columns tx, ty, tz (found {moments[0]!r})"
        raise ShapeError(f"{path}, line {header_line}: no column {', '.join(missing)} in the header {first}; "
                         f"expected the columns {', '.join(_COLUMNS)} (any order, units like 'Fz (N)', "
                         f"'Tz (N·m)'){hint}")
    col = {}
    for k in _COLUMNS:
        at = [j for j, h in enumerate(header) if h == k]
        if len(at) > 1:
            raise InputError(f"{path}, line {header_line}: columns {at[0] + 1} ({first[at[0]]!r}) and "
                             f"{at[1] + 1} ({first[at[1]]!r}) both name {k}: which to use is ambiguous; "
                             f"keep one")
        col[k] = at[0]
    unit = {k: _column_unit(first[col[k]], k, path, header_line, col[k] + 1) for k in (*_FORCES, *_TORQUES)}
    label = {}
    for k in (*_FORCES, *_TORQUES):
        m = _BRACKETS.search(first[col[k]])
        label[k] = m.group(1) if m is not None else ("N" if k in _FORCES else "N m")
    if len(rows) < 2:
        raise ShapeError(f"{path}: a header and no wrenches; expected one row per frame")
    by_name: dict[str, list[int]] = {}
    for i, s in enumerate(sources):
        by_name.setdefault(s, []).append(i)
    size_mm = sensor.outer_radius + sensor.lever_arm + float(np.linalg.norm(pose.position))
    max_lever_m = MAX_LEVER_FACTOR * size_mm * 1e-3
    line_of: dict[int, int] = {}
    unknown: list[tuple[str, int]] = []
    out: list[tuple[int, int, list[float]]] = []
    for lineno, cells in rows[1:]:
        if len(cells) != len(header):
            raise ShapeError(f"{path}, line {lineno}: expected {len(header)} columns ({', '.join(first)}), got "
                             f"{len(cells)}")
        t = frame_of(cells[col["frame"]], sources, by_name, path, lineno, col["frame"] + 1)
        if t is None:
            unknown.append((cells[col["frame"]], lineno))
            continue
        if t in line_of:
            raise InputError(f"{path}, line {lineno}: frame {sources[t]!r} (frame {t}) is listed twice (also "
                             f"on line {line_of[t]}); one row per frame")
        line_of[t] = lineno
        w = [_number(cells[col[k]], f"{k} in {label[k]}", path, lineno, col[k] + 1, first[col[k]]) * unit[k]
             for k in (*_FORCES, *_TORQUES)]
        f, tq = float(np.linalg.norm(w[:3])), float(np.linalg.norm(w[3:]))
        if f > MAX_WRENCH_FORCE_N:
            raise InputError(f"{path}, line {lineno}: frame {sources[t]!r}: a force of {f:.6g} N is beyond the "
                             f"{MAX_WRENCH_FORCE_N:g} N an object pressing a tactile dome can give; if the F/T "
                             f"sensor writes another unit, name it in the header (e.g. 'Fz (mN)')")
        if tq > max_lever_m * max(f, LEVER_FORCE_FLOOR_N):
            raise InputError(
                f"{path}, line {lineno}: frame {sources[t]!r}: a torque of {tq:.6g} N m with a force of "
                f"{f:.6g} N puts the force {tq / max(f, 1e-300):.6g} m from the F/T sensor's origin, more "
                f"than {MAX_LEVER_FACTOR:g} times the dome's size plus the F/T offset ({max_lever_m:.6g} m); "
                f"torques are read in N m: if the F/T sensor writes N mm, name it in the header "
                f"('Tz (N·mm)')")
        out.append((t, lineno, w))
    if unknown:
        shown = ", ".join(f"{c!r} (line {n})" for c, n in unknown[:5]) + (
            f" and {len(unknown) - 5} more" if len(unknown) > 5 else "")
        names = ", ".join(repr(s) for s in sources[:3]) + (", ..." if len(sources) > 3 else "")
        raise InputError(f"{path}: {len(unknown)} frame{'s' if len(unknown) != 1 else ''} not among the "
                         f"{len(sources)} frames: {shown}; name each frame as the 'source' column of optitact "
                         f"process does ({names}) or by its 0-based index 0..{len(sources) - 1}")
    out.sort()
    wrench = np.array([w for _, _, w in out], dtype=np.float64).reshape(-1, 6)
    if not np.any(wrench[:, :3] != 0):
        raise InputError(f"{path}: the force is 0 in every frame: no wrench to fit from; give each frame's "
                         f"force (in N, or name the unit in the header: 'Fz (mN)')")
    return Wrenches(frames=np.array([t for t, _, _ in out], dtype=np.int64), wrench=wrench,
                    lines=np.array([n for _, n, _ in out], dtype=np.int64), path=path)


# ---------------------------------------------------------------------------- identifiability
class UnidentifiableError(InputError):
    """The loaded frames cannot pin down every element's scale; the message says which frames to add.

    Attributes
    ----------
    counts : (E,) int ndarray
        Frames in which each element is loaded.
    groups : list of tuple of int
        Elements that cannot be told apart (loaded together, or in
        dependent patterns), smallest groups first.
    """

    def __init__(self, message: str, counts: np.ndarray | None = None, groups: Sequence[tuple[int, ...]] = ()):
        super().__init__(message)
        self.counts = counts
        self.groups = list(groups)


def _names(elements) -> str:
    e = [str(int(i)) for i in elements]
    return e[0] if len(e) == 1 else ", ".join(e[:-1]) + " and " + e[-1]


def _circuits(m: np.ndarray) -> list[np.ndarray]:
    """Minimal dependent column sets of ``m`` (the fundamental circuits of its reduced row echelon form)."""
    a = m.astype(np.float64).copy()
    n, k = a.shape
    pivots, row = [], 0
    for j in range(k):
        if row >= n:
            break
        p = row + int(np.argmax(np.abs(a[row:, j])))
        if abs(a[p, j]) < 1e-9:
            continue
        a[[row, p]] = a[[p, row]]
        a[row] /= a[row, j]
        others = np.arange(n) != row
        a[others] -= a[others, j, None] * a[row]
        pivots.append(j)
        row += 1
    out = []
    for j in range(k):
        if j in pivots:
            continue
        v = np.zeros(k)
        v[j] = 1.0
        for r, pj in enumerate(pivots):
            v[pj] = -a[r, j]
        v[np.abs(v) < 1e-9] = 0.0
        out.append(v)
    return out


def check_identifiable(loaded, *, min_frames: int = 3, elements=None) -> np.ndarray:
    """Check that frames loading these elements can pin down each element's scale from their totals.

    A fit to an F/T sensor's totals gives each element a free scale (its
    curves); the totals of a frame constrain only the elements loaded in
    it. This checks the loading pattern alone, as if every loaded element
    of a frame carried a like share: a design that separates elements by
    *which* are loaded, not by how a load happened to split between them
    (which the torques tell only weakly for neighbours a few mm apart).

    Parameters
    ----------
    loaded : (n_frames, E) bool array_like
        Which elements the pipeline saw in contact in each frame with a
        known wrench.
    min_frames : int
        The fewest frames that must load each element (default 3: a scale
        from one frame has no check on it, and curves have more than a scale).
    elements : sequence of int, optional
        The elements whose scales the fit frees (default all); the others
        are taken as known and need nothing.

    Returns
    -------
    (E,) int ndarray
        The frames loading each element (for all elements, checked or not).

    Raises
    ------
    UnidentifiableError
        Naming what to add: elements loaded in fewer than ``min_frames``
        frames ("press elements 3 and 17 at least 3 times each"); elements
        always loaded together (identical columns of ``loaded``: "elements 4
        and 5 were always loaded together, in all 37 frames where either
        was: press one without the other"); and, more generally, elements
        whose loading patterns are linearly dependent (the rank of
        ``loaded`` restricted to them falls short), the smallest such groups
        named.
    ShapeError
        ``loaded`` is not two-dimensional.
    TypeError
        ``loaded`` is not boolean (or 0/1).

    Examples
    --------
    >>> loaded = np.zeros((6, 4), bool)
    >>> loaded[[0, 1, 2], 0] = loaded[[0, 1, 2], 1] = True  # 0 and 1 always together
    >>> loaded[3:, 2] = loaded[3:, 3] = True; loaded[5, 3] = False
    >>> try:
    ...     check_identifiable(loaded, min_frames=1)
    ... except UnidentifiableError as exc:
    ...     print(exc.groups)
    [(0, 1)]
    """
    a = np.asarray(loaded)
    if a.dtype != bool:
        if a.dtype.kind not in "iuf" or not np.isin(a, (0, 1)).all():
            raise TypeError(f"loaded must be a boolean (n_frames, E) array (which elements each frame loads), "
                            f"got dtype {a.dtype}")
        a = a.astype(bool)
    if a.ndim != 2:
        raise ShapeError(f"loaded must have shape (n_frames, E), got {a.shape}")
    min_frames = integer(min_frames, "min_frames", minimum=1)
    n_t, n_el = a.shape
    counts = a.sum(axis=0).astype(np.int64)
    if elements is None:
        idx = np.arange(n_el)
    else:
        idx = np.unique(np.asarray(elements, dtype=np.int64).reshape(-1))
        if idx.size and (idx.min() < 0 or idx.max() >= n_el):
            raise InputError(f"elements must be among 0..{n_el - 1}, got {idx.tolist()}")
    problems: list[str] = []
    groups: list[tuple[int, ...]] = []
    few = [int(e) for e in idx if counts[e] < min_frames]
    if few:
        got = ", ".join(f"{e}: {counts[e]}" for e in few[:10]) + (", ..." if len(few) > 10 else "")
        them = "them" if len(few) > 1 else "it"
        problems.append(f"press element{'s' if len(few) > 1 else ''} {_names(few)} at least {min_frames} "
                        f"time{'s' if min_frames > 1 else ''} each (frames loading {them}: {got})")
    seen = [int(e) for e in idx if counts[e] > 0]
    by_column: dict[bytes, list[int]] = {}
    for e in seen:
        by_column.setdefault(a[:, e].tobytes(), []).append(e)
    reps = []
    for members in by_column.values():
        reps.append(members[0])
        if len(members) > 1:
            groups.append(tuple(members))
            n = int(counts[members[0]])
            two = len(members) == 2
            problems.append(f"elements {_names(members)} were always loaded together, in all {n} frame"
                            f"{'s' if n != 1 else ''} where {'either' if two else 'any'} was: press "
                            f"{'one without the other' if two else 'each without the others'} (together they "
                            f"are pinned down only as a sum)")
    reps.sort()
    if reps:
        m = np.unique(a[:, reps], axis=0).astype(np.float64)
        rank = int(np.linalg.matrix_rank(m))
        if rank < len(reps):
            circuits = sorted(_circuits(m), key=lambda v: (np.count_nonzero(v), tuple(np.flatnonzero(v))))
            for v in circuits[:3]:
                members = tuple(reps[j] for j in np.flatnonzero(v))
                groups.append(members)
                plus = [reps[j] for j in np.flatnonzero(v > 0)]
                minus = [reps[j] for j in np.flatnonzero(v < 0)]
                relation = ""
                if np.all(np.isin(v[v != 0], (-1.0, 1.0))):
                    relation = (f": every frame loads as many of elements {_names(plus)} as of elements "
                                f"{_names(minus)}")
                problems.append(f"elements {_names(members)} are loaded in dependent patterns{relation}, so a "
                                f"scale on one can be traded for the others; press them in other combinations "
                                f"(one of them alone)")
            if len(circuits) > 3:
                problems.append(f"{len(circuits) - 3} more such group{'s' if len(circuits) > 4 else ''} (the "
                                f"loading patterns have rank {rank} for {len(reps)} distinct elements)")
    if problems:
        groups.sort(key=lambda g: (len(g), g))
        raise UnidentifiableError(f"the {n_t} frames with a known wrench cannot pin down every element's "
                                  f"scale: " + "; ".join(problems), counts, groups)
    return counts
