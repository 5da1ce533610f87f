"""Non-coplanar 25-unit piezoresistive fingertip: 3-D force and object recognition (source ``"fingertip25"``).

Twenty-five piezoresistive units (Ø 2.5 mm) sit on the faceted surface of a
robotic fingertip: a flat pad (the *normal plane*, plane 1) and tilted planes
around it. Each unit's resistance falls from about 38.5 kΩ at 0.2 N to about
1.2 kΩ at 5 N; the detection range is 0.2–5 N, the resolution 0.2 N, and the
response follows a load with 80 ms and an unload with 160 ms. Because the
planes face different directions, the units decouple a 3-D force. This module
simulates the fingertip (:class:`Fingertip25`, registered as
``"fingertip25"``) and implements the study that goes with it:

1. the resistance law :func:`resistance_from_force` / :func:`force_from_resistance`;
2. the published decoupling by plane resultants (:func:`plane_resultants`,
   :func:`decouple`, :func:`detection_ranges`) and a calibrated linear
   decoupling for comparison (:class:`DecouplingMatrix`);
3. the repeatability error :func:`repeatability_error`;
4. object recognition with a five-finger hand carrying 125 units
   (:data:`OBJECTS`, :func:`grasp`, :func:`object_dataset`,
   :func:`recognise_objects`) and hardness cues (:func:`hardness_cues`);
5. the whole study with a figure: :func:`experiment`, :func:`plot_experiment`.

Convention: the fingertip frame has z along the pad's outward normal, y along
the finger towards its tip and x across the finger (x, y, z right-handed), in
mm, origin at the pad centre. A force :math:`F = (F_x, F_y, F_z)` is the
contact force the fingertip applies to an object, in that frame: pressing
with the pad is :math:`F_z > 0`, pushing with the tip end :math:`F_y > 0`,
with the +x side :math:`F_x > 0`. Units are read out on a 5×5 grid indexed
``(row, col)``, ``(0, 0)`` top-left; row 0 is the tip end, row 4 towards the
finger's base, col 0 the −x side (:data:`UNIT_PLANE`). The grid is a readout
order that follows the surface roughly; the true 3-D unit centres and
normals are ``layout.positions_mm`` and ``layout.normals``.

Examples
--------
>>> from optitact.taxels.fingertip import detection_ranges
>>> r = detection_ranges()
>>> [round(float(v), 2) for v in (r["low_n"][1], r["high_n"][1])]      # plane 2: 4 F_s cos 77.25 deg
[0.18, 4.41]
"""

from __future__ import annotations

import dataclasses
import math
import numbers
import sys
import time
import warnings
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .._validate import finite, integer, positive, real_array, seed_value
from ..errors import InputError, ShapeError
from ..sources import Indenter, Layout, Scenario, register_source

__all__ = [
    "Fingertip25Config", "Fingertip25", "UNIT_PLANE", "UNIT_SIDE", "PLANE_AXIS", "PUBLISHED_PLANE_UNITS",
    "resistance_law", "resistance_from_force", "force_from_resistance", "plane_resultants", "decouple",
    "detection_ranges", "axis_ranges", "DecouplingMatrix", "decoupling_study", "repeatability_error",
    "repeated_loadings", "step_response", "GraspObject", "OBJECTS", "FINGERS", "grasp", "ObjectDataset",
    "object_dataset", "hidden_units", "recognise_objects", "hardness_cues", "experiment", "plot_experiment",
]

#: Plane (1 ... 5) of each unit on the 5×5 readout grid; row 0 is the tip end, col 0 the −x side.
UNIT_PLANE = np.array([[4, 5, 5, 5, 4],
                       [3, 1, 1, 1, 3],
                       [3, 1, 1, 1, 3],
                       [2, 2, 1, 2, 2],
                       [2, 2, 1, 2, 2]])
#: Side of each unit along its plane's axis: −1 for the mirrored planes 2 and 3 on the −x side, else +1.
UNIT_SIDE = np.array([[1, 1, 1, 1, 1],
                      [-1, 1, 1, 1, 1],
                      [-1, 1, 1, 1, 1],
                      [-1, -1, 1, 1, 1],
                      [-1, -1, 1, 1, 1]])
#: Axis each plane measures (planes 1 ... 5).
PLANE_AXIS = ("z", "x", "x", "y", "y")
#: Units per plane in the published plane resultants (one side; planes 2 and 3 are mirrored on −x).
PUBLISHED_PLANE_UNITS = (8, 4, 2, 2, 3)
_AXIS_INDEX = {"x": 0, "y": 1, "z": 2}
_POINT = Indenter("point")                 # scenarios built here: the source uses the resultant only
for _plane, _n in enumerate(PUBLISHED_PLANE_UNITS, start=1):
    if int(np.sum((UNIT_PLANE == _plane) & (UNIT_SIDE > 0))) != _n:  # pragma: no cover - module invariant
        raise RuntimeError(f"unit map disagrees with the published count of plane {_plane}")
UNIT_PLANE.setflags(write=False)
UNIT_SIDE.setflags(write=False)


def _fraction(value, name: str, *, upper: float = 1.0, closed: bool = False) -> float:
    v = positive(value, name, allow_zero=True)
    if v > upper or (v == upper and not closed):
        raise InputError(f"{name} must be in [0, {upper:g}{']' if closed else ')'}, got {value!r}")
    return v


@dataclass(frozen=True)
class Fingertip25Config:
    """The non-coplanar 25-unit piezoresistive fingertip.

    Every field states its unit. The unit map (which unit lies on which
    plane) is :data:`UNIT_PLANE` / :data:`UNIT_SIDE`; ``plane_units`` must
    match it and is kept here so that a config states the whole design.
    """

    unit_diameter_mm: float = 2.5         # mm, diameter of a sensing unit
    pitch_mm: float = 3.0                 # mm, centre spacing of neighbouring units along the surface
    plane_angles_deg: tuple[float, ...] = (0.0, 77.25, 62.09, 46.47, 9.03)  # deg, unit normal to measured axis
    plane_units: tuple[int, ...] = PUBLISHED_PLANE_UNITS   # units per plane (one side), planes 1 ... 5
    force_low_n: float = 0.2              # N, detection threshold: low end of the range
    force_high_n: float = 5.0             # N, high end of the range (the reading saturates there)
    r_low_kohm: float = 38.5              # kOhm, resistance at force_low_n
    r_high_kohm: float = 1.2              # kOhm, resistance at force_high_n
    r_open_kohm: float = 1000.0           # kOhm, reading of a unit below the threshold (open contact)
    resolution_n: float = 0.2             # N, readings are quantised to this force step
    tau_load_s: float = 0.080             # s, first-order time constant while the force rises
    tau_unload_s: float = 0.160           # s, first-order time constant while the force falls
    rate_hz: float = 100.0                # samples / s of the readout
    noise_n: float = 0.05                 # N, 1-sigma white noise on each unit's equivalent force
    repeatability: float = 0.007          # 1, 1-sigma scatter of each unit's gain from one loading to the next
    crosstalk: float = 0.05               # 1, sensitivity of a unit to off-axis force along its normal
    unit_stiffness_n_per_mm: float = 20.0  # N/mm, normal stiffness of one unit and its skin (grasp contact)

    def __post_init__(self) -> None:
        for name in ("unit_diameter_mm", "pitch_mm", "force_low_n", "force_high_n", "r_low_kohm", "r_high_kohm",
                     "r_open_kohm", "resolution_n", "tau_load_s", "tau_unload_s", "rate_hz",
                     "unit_stiffness_n_per_mm"):
            positive(getattr(self, name), name)
        positive(self.noise_n, "noise_n", allow_zero=True)
        _fraction(self.repeatability, "repeatability", upper=0.3)
        _fraction(self.crosstalk, "crosstalk", closed=True)
        if self.pitch_mm < self.unit_diameter_mm:
            raise InputError(f"pitch_mm must be >= unit_diameter_mm = {self.unit_diameter_mm:g} (units may not "
                             f"overlap), got {self.pitch_mm!r}")
        ang = real_array(self.plane_angles_deg, "plane_angles_deg")
        if ang.shape != (5,) or not np.all(np.isfinite(ang)):
            raise ShapeError(f"plane_angles_deg must be 5 finite angles (planes 1 ... 5), "
                             f"got {self.plane_angles_deg!r}")
        if ang[0] != 0 or np.any(ang[1:] <= 0) or np.any(ang >= 90):
            raise InputError("plane_angles_deg must be 0 for plane 1 (the normal plane) and in (0, 90) deg for "
                             f"planes 2 ... 5, got {self.plane_angles_deg!r}")
        object.__setattr__(self, "plane_angles_deg", tuple(float(a) for a in ang))
        units = tuple(self.plane_units)
        if any(isinstance(n, bool) or not isinstance(n, numbers.Integral) for n in units):
            raise TypeError(f"plane_units must be integers, got {self.plane_units!r}")
        if units != PUBLISHED_PLANE_UNITS:
            raise InputError(f"plane_units must be {PUBLISHED_PLANE_UNITS} (the modelled unit map, "
                             f"UNIT_PLANE), got {self.plane_units!r}")
        object.__setattr__(self, "plane_units", tuple(int(n) for n in units))
        if self.force_low_n >= self.force_high_n:
            raise InputError(f"force_low_n must be < force_high_n = {self.force_high_n:g}, "
                             f"got {self.force_low_n!r}")
        if not self.r_open_kohm > self.r_low_kohm > self.r_high_kohm:
            raise InputError("resistances must satisfy r_open_kohm > r_low_kohm > r_high_kohm (resistance "
                             f"falls with force), got {self.r_open_kohm!r}, {self.r_low_kohm!r}, "
                             f"{self.r_high_kohm!r}")
        if self.resolution_n > self.force_low_n:
            raise InputError(f"resolution_n must be <= force_low_n = {self.force_low_n:g}, "
                             f"got {self.resolution_n!r}")


def _config(config) -> Fingertip25Config:
    if config is None:
        return Fingertip25Config()
    if not isinstance(config, Fingertip25Config):
        raise TypeError(f"config must be a Fingertip25Config, got {type(config).__name__}")
    return config


# ---- resistance law -----------------------------------------------------------------------------------
def resistance_law(config: Fingertip25Config | None = None) -> tuple[float, float]:
    r"""Coefficients ``(a, b)`` of the power law :math:`R = a F^{-b}` through the two published points.

    Returns
    -------
    a : float
        kΩ·N^b.
    b : float
        Exponent, > 0.

    Notes
    -----
    Through :math:`(F_1, R_1) = (0.2\,\mathrm{N}, 38.5\,\mathrm{k\Omega})` and
    :math:`(F_2, R_2) = (5\,\mathrm{N}, 1.2\,\mathrm{k\Omega})`:
    :math:`b = \ln(R_1/R_2) / \ln(F_2/F_1)`, :math:`a = R_1 F_1^{b}`
    (b ≈ 1.0775, a ≈ 6.80 kΩ·N^b for the defaults). A power law is a
    straight line in log–log axes, the usual shape of piezoresistive
    composites over a decade or two of force.

    Examples
    --------
    >>> a, b = resistance_law()
    >>> round(a, 3), round(b, 4)
    (6.797, 1.0775)
    """
    c = _config(config)
    b = math.log(c.r_low_kohm / c.r_high_kohm) / math.log(c.force_high_n / c.force_low_n)
    return c.r_low_kohm * c.force_low_n ** b, b


def resistance_from_force(force_n, *, config: Fingertip25Config | None = None) -> np.ndarray:
    """Resistance (kΩ) of a unit under normal force ``force_n`` (N, > 0), by :func:`resistance_law`.

    The law is evaluated as is (no threshold, saturation or quantisation:
    those belong to :meth:`Fingertip25.transduce`).

    Raises
    ------
    InputError
        For forces that are not finite or not > 0.
    """
    f = finite(real_array(force_n, "force_n"), "force_n")
    if f.size and f.min() <= 0:
        raise InputError(f"force_n must be > 0 (the law diverges at 0), got minimum {f.min()}")
    a, b = resistance_law(config)
    return a * f ** -b


def force_from_resistance(resistance_kohm, *, config: Fingertip25Config | None = None) -> np.ndarray:
    """Equivalent normal force (N) of a unit reading ``resistance_kohm``; inverts :func:`resistance_from_force`.

    Readings at or above ``config.r_open_kohm`` (an open, unloaded unit) give 0 N.

    Raises
    ------
    InputError
        For resistances that are not finite or not > 0.

    Examples
    --------
    >>> round(float(force_from_resistance(1.2)), 9), float(force_from_resistance(1000.0))
    (5.0, 0.0)
    """
    c = _config(config)
    r = finite(real_array(resistance_kohm, "resistance_kohm"), "resistance_kohm")
    if r.size and r.min() <= 0:
        raise InputError(f"resistance_kohm must be > 0, got minimum {r.min()}")
    a, b = resistance_law(c)
    return np.where(r >= c.r_open_kohm, 0.0, (a / np.minimum(r, c.r_open_kohm)) ** (1.0 / b))


# ---- geometry -------------------------------------------------------------------------------------------
def _unit_geometry(config: Fingertip25Config) -> tuple[np.ndarray, np.ndarray]:
    """Unit centres and outward normals (5, 5, 3) on the faceted fingertip."""
    p = config.pitch_mm
    theta = np.deg2rad(config.plane_angles_deg)
    tilt = np.where(np.arange(5) == 0, 0.0, np.pi / 2 - theta)           # tilt of each plane from the pad
    normals = np.zeros((5, 5, 3))
    pos = np.zeros((5, 5, 3))
    for r, c in np.ndindex(5, 5):
        k = UNIT_PLANE[r, c] - 1
        t = tilt[k]
        if PLANE_AXIS[k] == "z":
            normals[r, c] = (0.0, 0.0, 1.0)
        elif PLANE_AXIS[k] == "x":
            normals[r, c] = (UNIT_SIDE[r, c] * np.sin(t), 0.0, np.cos(t))
        else:
            normals[r, c] = (0.0, np.sin(t), np.cos(t))
    # rows 1-4: walk outwards from the centre column across the facets of the row (tilt about y)
    for r in range(1, 5):
        pos[r, 2] = (0.0, (2.5 - r) * p, 0.0)
        for step in (1, -1):
            x = z = 0.0
            prev = tilt[UNIT_PLANE[r, 2] - 1]
            for c in range(2 + step, 2 + 3 * step, step):
                t = tilt[UNIT_PLANE[r, c] - 1]
                x += step * p / 2 * (np.cos(prev) + np.cos(t))
                z -= p / 2 * (np.sin(prev) + np.sin(t))
                pos[r, c] = (x, (2.5 - r) * p, z)
                prev = t
    # row 0: the tip end, beyond row 1 along +y (tilt about x); plane 5 lies beyond a full plane-4 facet
    t4, t5 = tilt[3], tilt[4]
    for c in range(5):
        x, y, z = pos[1, c]
        y += p / 2
        if UNIT_PLANE[0, c] == 4:
            y, z = y + p / 2 * np.cos(t4), z - p / 2 * np.sin(t4)
        else:
            y, z = y + p * np.cos(t4) + p / 2 * np.cos(t5), z - p * np.sin(t4) - p / 2 * np.sin(t5)
        pos[0, c] = (x, y, z)
    return pos, normals


def _axis_gain(config: Fingertip25Config) -> np.ndarray:
    """G per unit: sum of cos(theta) over the units that share its axis and side (5, 5)."""
    cos_plane = np.cos(np.deg2rad(config.plane_angles_deg))
    cos_unit = cos_plane[UNIT_PLANE - 1]
    axis = np.array([_AXIS_INDEX[PLANE_AXIS[k - 1]] for k in UNIT_PLANE.ravel()]).reshape(5, 5)
    gain = np.zeros((5, 5))
    for a in range(3):
        for s in (-1, 1):
            sel = (axis == a) & (UNIT_SIDE == s)
            gain[sel] = cos_unit[sel].sum()
    return gain


def _check_grid(values, name: str) -> np.ndarray:
    arr = finite(real_array(values, name), name)
    if arr.ndim < 2 or arr.shape[-2:] != (5, 5):
        raise ShapeError(f"{name} must have shape (..., 5, 5) (the unit grid), got {arr.shape}")
    return arr


def _float_out(arr: np.ndarray, like) -> np.ndarray:
    return arr.astype(np.float32) if np.asarray(like).dtype == np.float32 else arr


class Fingertip25:
    r"""Simulated non-coplanar 25-unit piezoresistive fingertip (source ``"fingertip25"``).

    Parameters
    ----------
    config : Fingertip25Config, optional
        Defaults to ``Fingertip25Config()``.

    Notes
    -----
    *Geometry.* Plane 1 (8 units) is the pad, normal +z. Planes 2 (4 units)
    and 3 (2 units) are tilted about y towards +x and are mirrored on the −x
    side (planes 2′, 3′); planes 4 (2 units) and 5 (3 units) are tilted about
    x at the tip end, towards +y. Plane :math:`k` measures axis :math:`a_k`
    (:data:`PLANE_AXIS`) and its unit normals make the published angle
    :math:`\theta_k` with that axis (0°, 77.25°, 62.09°, 46.47°, 9.03°), i.e.
    they are tilted :math:`90° - \theta_k` from the pad. That gives
    8 + 2·(4 + 2) + 2 + 3 = 25 units (see :func:`decouple` for why).

    *Mechanics* (:meth:`unit_forces`). The design assumption of the
    published decoupling: each axis component of :math:`F` is carried by the
    units of the planes on its side, each pressed along its own normal, with
    one common unit force :math:`F_s = (s F_a)^+ / G_{a,s}`,
    :math:`G_{a,s} = \sum_{i \in (a, s)} \cos\theta_i` (so the units'
    projections on the axis add up to :math:`F_a`). The fingertip cannot pull
    and has no units facing −y: :math:`F_z < 0` and :math:`F_y < 0` give no
    response. Besides, each unit feels the off-axis force along its normal
    with relative sensitivity :math:`c` (``crosstalk``):
    :math:`f_i = [(s_i F_{a_i})^+ + c\,(F\cdot n_i - F_{a_i} n_{i,a_i})^+] / G_i`.

    *Transduction* (:meth:`transduce`), per unit and sample: a per-loading
    gain :math:`1 + \rho z` (``repeatability``); first-order dynamics
    :math:`y_n = y_{n-1} + (1 - e^{-\Delta t/\tau})(x_n - y_{n-1})` with
    :math:`\tau` = ``tau_load_s`` while :math:`x_n > y_{n-1}` and
    ``tau_unload_s`` otherwise (the state starts settled at the first
    sample); white noise (``noise_n``); below ``force_low_n`` the unit is
    open (``r_open_kohm``); else the force is quantised to ``resolution_n``
    (at least ``force_low_n``), saturates at ``force_high_n`` and
    :math:`R = a F^{-b}` (:func:`resistance_law`).
    Frames are resistances in kΩ (``layout.units == "kOhm"``).

    ``Scenario.force_n`` is :math:`|F|`; ``Scenario.extra["direction"]`` (a
    3-vector or (T, 3), normalised here; default +z) its direction in the
    fingertip frame. Depth-driven scenarios are refused; the indenter's shape,
    pose and stiffness are not used (the fingertip senses the resultant).
    Grasps of objects use a contact model instead (:func:`grasp`).
    """

    name = "fingertip25"

    def __init__(self, config: Fingertip25Config | None = None) -> None:
        self.config = _config(config)
        pos, normals = _unit_geometry(self.config)
        self._normals = normals
        self._positions = pos
        self._gain = _axis_gain(self.config)
        self._axis = np.array([_AXIS_INDEX[PLANE_AXIS[k - 1]] for k in UNIT_PLANE.ravel()]).reshape(5, 5)

    @cached_property
    def layout(self) -> Layout:
        """5×5 readout grid, ``pitch_mm`` along the surface, 3-D unit centres and normals, kΩ, ``rate_hz``."""
        c = self.config
        return Layout(shape=(5, 5), pitch_mm=(c.pitch_mm, c.pitch_mm), units="kOhm", rate_hz=c.rate_hz,
                      positions_mm=self._positions, normals=self._normals)

    def unit_table(self) -> dict[str, np.ndarray]:
        """Geometry and role of every unit, one row per unit (row-major order).

        Columns: ``unit``, ``row``, ``col``, ``plane``, ``axis``, ``side``,
        ``angle_deg``, ``x_mm``, ``y_mm``, ``z_mm``, ``nx``, ``ny``, ``nz``.
        """
        plane = UNIT_PLANE.ravel()
        rows, cols = np.divmod(np.arange(25), 5)
        p, n = self._positions.reshape(-1, 3), self._normals.reshape(-1, 3)
        return {"unit": np.arange(25), "row": rows, "col": cols, "plane": plane.copy(),
                "axis": np.array([PLANE_AXIS[k - 1] for k in plane]), "side": UNIT_SIDE.ravel().copy(),
                "angle_deg": np.asarray(self.config.plane_angles_deg)[plane - 1],
                "x_mm": p[:, 0], "y_mm": p[:, 1], "z_mm": p[:, 2], "nx": n[:, 0], "ny": n[:, 1], "nz": n[:, 2]}

    def unit_forces(self, force_xyz) -> np.ndarray:
        """Noise-free unit normal forces (..., 5, 5), N, for contact forces ``force_xyz`` (..., 3), N.

        See the class Notes for the model; forces beyond the range are not clipped here.
        """
        f = finite(real_array(force_xyz, "force_xyz"), "force_xyz")
        if f.ndim < 1 or f.shape[-1] != 3:
            raise ShapeError(f"force_xyz must have shape (..., 3) (Fx, Fy, Fz), got {f.shape}")
        f = f[..., None, None, :]
        idx = np.broadcast_to(self._axis[..., None], (*f.shape[:-3], 5, 5, 1))
        own = np.take_along_axis(np.broadcast_to(f, idx.shape[:-1] + (3,)), idx, axis=-1)[..., 0]
        along = np.sum(f * self._normals, axis=-1)
        n_axis = np.take_along_axis(self._normals, self._axis[..., None], axis=-1)[..., 0]
        off = along - own * n_axis
        c = self.config.crosstalk
        return (np.clip(UNIT_SIDE * own, 0.0, None) + c * np.clip(off, 0.0, None)) / self._gain

    def transduce(self, unit_force_n, t_s, *, seed: int | None = None) -> np.ndarray:
        """Resistances (T, 5, 5), kΩ, of the units under normal forces ``unit_force_n`` at times ``t_s``.

        Parameters
        ----------
        unit_force_n : (T, 5, 5) array
            Normal force on each unit, N, >= 0, in time order.
        t_s : (T,) array
            Sample times, s, strictly increasing.
        seed : int, optional
            Seeds this loading's gain scatter and the noise.

        Raises
        ------
        ShapeError, InputError
            For mismatched shapes, negative forces or times that do not increase.
        """
        f = _check_grid(unit_force_n, "unit_force_n")
        if f.ndim != 3:
            raise ShapeError(f"unit_force_n must have shape (T, 5, 5), got {f.shape}")
        t = _times(t_s, f.shape[0])
        return self._transduce(f, t, np.random.default_rng(seed_value(seed)))

    def _transduce(self, f: np.ndarray, t: np.ndarray, rng: np.random.Generator) -> np.ndarray:
        """Transduction of (T, ...) unit forces; trailing dimensions are independent units."""
        if f.size and f.min() < 0:
            raise InputError(f"unit forces must be >= 0, got minimum {f.min()}")
        c = self.config
        x = f * (1.0 + c.repeatability * rng.standard_normal(f.shape[1:]))
        y = np.empty_like(x)
        y[0] = x[0]
        if t.size > 1:
            dt = np.diff(t)
            a_load, a_unload = -np.expm1(-dt / c.tau_load_s), -np.expm1(-dt / c.tau_unload_s)
            for n in range(1, t.size):
                prev = y[n - 1]
                y[n] = prev + np.where(x[n] > prev, a_load[n - 1], a_unload[n - 1]) * (x[n] - prev)
        if c.noise_n:
            y = y + c.noise_n * rng.standard_normal(y.shape)
        on = y >= c.force_low_n
        q = np.clip(np.rint(y / c.resolution_n) * c.resolution_n, c.force_low_n, c.force_high_n)
        a, b = resistance_law(c)
        return np.where(on, a * np.where(on, q, 1.0) ** -b, c.r_open_kohm)

    def force_vectors(self, scenario: Scenario) -> np.ndarray:
        """Contact force (T, 3), N, of a scenario: ``force_n`` times the unit ``extra["direction"]``."""
        if not isinstance(scenario, Scenario):
            raise TypeError(f"scenario must be a Scenario, got {type(scenario).__name__}")
        if scenario.force_n is None:
            raise InputError("the fingertip25 source needs a force-driven scenario (force_n), got depth_mm")
        extra = dict(scenario.extra)
        direction = extra.pop("direction", (0.0, 0.0, 1.0))
        if extra:
            raise InputError(f"unknown Scenario.extra key(s) {sorted(extra)} for fingertip25; "
                             "valid: ['direction']")
        d = finite(real_array(direction, "direction"), "direction")
        n = scenario.n_frames
        if d.shape == (3,):
            d = np.broadcast_to(d, (n, 3))
        if d.shape != (n, 3):
            raise ShapeError(f"direction must have shape (3,) or ({n}, 3), got {d.shape}")
        norm = np.linalg.norm(d, axis=1)
        if np.any(norm == 0):
            raise InputError(f"direction must be non-zero, got a zero vector at sample {int(np.argmin(norm))}")
        return np.asarray(scenario.force_n)[:, None] * d / norm[:, None]

    def frames(self, scenario: Scenario, *, seed: int | None = None) -> np.ndarray:
        """Unit resistances (T, 5, 5), kΩ, for a force-driven ``scenario`` (see the class Notes).

        Raises
        ------
        InputError
            For a depth-driven scenario, unknown ``extra`` keys or a zero direction.
        """
        rng = np.random.default_rng(seed_value(seed))
        return self._transduce(self.unit_forces(self.force_vectors(scenario)), scenario.t_s, rng)


def _times(t_s, n: int) -> np.ndarray:
    t = finite(real_array(t_s, "t_s"), "t_s")
    if t.shape != (n,):
        raise ShapeError(f"t_s must have shape ({n},) like the samples, got {t.shape}")
    if n > 1 and np.any(np.diff(t) <= 0):
        raise InputError("t_s must be strictly increasing")
    return t


# ---- decoupling ---------------------------------------------------------------------------------------
_UNITS = ("N", "kOhm")


def _unit_values(values, units: str, config) -> np.ndarray:
    if units not in _UNITS:
        raise InputError(f"units must be one of {_UNITS}, got {units!r}")
    arr = _check_grid(values, "values")
    if units == "kOhm":
        return force_from_resistance(arr, config=config)
    if arr.size and arr.min() < 0:
        raise InputError(f"unit forces must be >= 0, got minimum {arr.min()}")
    return arr


def plane_resultants(values, *, units: str = "N",
                     config: Fingertip25Config | None = None) -> dict[str, np.ndarray]:
    r"""Published plane resultants :math:`F_1 ... F_5` of unit readings.

    Parameters
    ----------
    values : (..., 5, 5) array
        Unit normal forces (N) or resistances (kΩ, converted by :func:`force_from_resistance`).
    units : {"N", "kOhm"}
    config : Fingertip25Config, optional
        Plane angles and resistance law; defaults to ``Fingertip25Config()``.

    Returns
    -------
    dict
        ``F1`` ... ``F5``, each of shape ``values.shape[:-2]``, N, along the
        plane's axis (:data:`PLANE_AXIS`); float32 if ``values`` is.

    Raises
    ------
    ShapeError
        If the trailing dimensions are not (5, 5).
    InputError
        For an unknown ``units``, non-finite values, negative forces or resistances <= 0.

    Notes
    -----
    :math:`F_k = \cos\theta_k \sum_{i \in k} s_i f_i`, :math:`s_i = \pm 1`
    the unit's side (:data:`UNIT_SIDE`). With one common reading
    :math:`F_s` on the + side this is the published
    :math:`F_1 = 8 F_s`, :math:`F_2 = 4 F_s \cos 77.25°`,
    :math:`F_3 = 2 F_s \cos 62.09°`, :math:`F_4 = 2 F_s \cos 46.47°`,
    :math:`F_5 = 3 F_s \cos 9.03°`.
    """
    c = _config(config)
    f = _unit_values(values, units, c)
    cos_plane = np.cos(np.deg2rad(c.plane_angles_deg))
    return {f"F{k}": _float_out(cos_plane[k - 1] * np.sum(np.where(UNIT_PLANE == k, UNIT_SIDE * f, 0.0),
                                                           axis=(-2, -1)), values)
            for k in range(1, 6)}


def decouple(values, *, units: str = "N", config: Fingertip25Config | None = None) -> np.ndarray:
    r"""3-D contact force ``(Fx, Fy, Fz)`` (..., 3), N, from unit readings by the published plane resultants.

    Parameters
    ----------
    values : (..., 5, 5) array
        Unit normal forces (N) or resistance frames (kΩ).
    units : {"N", "kOhm"}
    config : Fingertip25Config, optional

    Returns
    -------
    ndarray
        (..., 3): :math:`F_x = F_2 + F_3`, :math:`F_y = F_4 + F_5`,
        :math:`F_z = F_1` (:func:`plane_resultants`); float32 if ``values`` is.

    Notes
    -----
    Reading of the published design. The plane resultants name the axis
    each plane measures and count 8 + 4 + 2 + 2 + 3 = 19 units; the
    fingertip has 25. Here plane 1 is the pad (z), planes 2 and 3 face +x
    and are mirrored on −x (the 2·(4 + 2) = 12 units that make 19 + 6 = 25,
    and the only way to sense both signs of :math:`F_x`; mirroring also
    cancels the pad-normal force the side units feel), planes 4 and 5 wrap
    the tip end (+y). A unit at angle :math:`\theta_k` to its axis pressed
    with :math:`F_s` contributes :math:`F_s \cos\theta_k` along it, which is
    the published formula. Negative :math:`F_z` (pulling) and :math:`F_y`
    (no units face −y) cannot be sensed. Crosstalk (the off-axis force a
    tilted unit feels) biases the result; :class:`DecouplingMatrix` removes
    the linear part of it by calibration.

    Examples
    --------
    >>> import numpy as np
    >>> src = Fingertip25(Fingertip25Config(crosstalk=0.0))
    >>> np.round(decouple(src.unit_forces([1.0, 2.0, 5.0])), 6).tolist()
    [1.0, 2.0, 5.0]
    """
    r = plane_resultants(values, units=units, config=config)
    return np.stack([r["F2"] + r["F3"], r["F4"] + r["F5"], r["F1"]], axis=-1)


def detection_ranges(*, config: Fingertip25Config | None = None) -> dict[str, np.ndarray]:
    r"""Range of each plane resultant, computed from the unit range and the published formula.

    Returns
    -------
    dict
        One row per plane: ``plane``, ``axis``, ``n_units``, ``angle_deg``,
        ``factor`` (:math:`n_k \cos\theta_k`), ``low_n``, ``high_n``
        (:math:`[F_{low}, F_{high}] \cdot n_k \cos\theta_k`; e.g. plane 2:
        0.1765–4.413 N, published as 0.17–4.41 N).
    """
    c = _config(config)
    n = np.asarray(c.plane_units, dtype=float)
    ang = np.asarray(c.plane_angles_deg)
    factor = n * np.cos(np.deg2rad(ang))
    return {"plane": np.arange(1, 6), "axis": np.array(PLANE_AXIS), "n_units": n.astype(int), "angle_deg": ang,
            "factor": factor, "low_n": c.force_low_n * factor, "high_n": c.force_high_n * factor}


def axis_ranges(*, config: Fingertip25Config | None = None) -> dict[str, tuple[float, float]]:
    """Range of |F| along each axis (one side): all units of the axis at the unit range low and high ends.

    Returns
    -------
    dict
        ``{"x": (low, high), "y": ..., "z": ...}`` in N; the x range holds for
        either sign, y and z only for positive values.
    """
    c = _config(config)
    r = detection_ranges(config=c)
    out = {}
    for axis in ("x", "y", "z"):
        sel = r["axis"] == axis
        out[axis] = (float(r["low_n"][sel].sum()), float(r["high_n"][sel].sum()))
    return out


@dataclass(frozen=True, eq=False)
class DecouplingMatrix:
    r"""Calibrated linear decoupling :math:`\hat F = M f + b` from the 25 unit forces.

    Build with :meth:`fit`; ``matrix`` is (3, 25) (row-major units), ``offset`` (3,), N.
    """

    matrix: np.ndarray
    offset: np.ndarray

    def __post_init__(self) -> None:
        m = finite(real_array(self.matrix, "matrix"), "matrix")
        b = finite(real_array(self.offset, "offset"), "offset")
        if m.shape != (3, 25) or b.shape != (3,):
            raise ShapeError(f"matrix must have shape (3, 25) and offset (3,), got {m.shape} and {b.shape}")
        for name, arr in (("matrix", m), ("offset", b)):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def fit(cls, unit_force_n, force_xyz) -> DecouplingMatrix:
        """Least-squares fit on known loads.

        Parameters
        ----------
        unit_force_n : (n, 5, 5) array
            Measured unit forces, N (e.g. decoded plateau readings).
        force_xyz : (n, 3) array
            The applied forces, N.

        Raises
        ------
        ShapeError
            For mismatched shapes or fewer than 26 loads.
        InputError
            If the loads do not determine the fit (rank-deficient readings).
        """
        f = _check_grid(unit_force_n, "unit_force_n")
        y = finite(real_array(force_xyz, "force_xyz"), "force_xyz")
        if f.ndim != 3 or y.shape != (f.shape[0], 3):
            raise ShapeError(f"unit_force_n must be (n, 5, 5) and force_xyz (n, 3) with one n, "
                             f"got {f.shape} and {y.shape}")
        if f.shape[0] < 26:
            raise ShapeError(f"a decoupling fit needs at least 26 loads, got {f.shape[0]}")
        X = np.column_stack([f.reshape(f.shape[0], -1), np.ones(f.shape[0])])
        coef, _, rank, _ = np.linalg.lstsq(X, y, rcond=None)
        if rank < 4:
            raise InputError(f"the loads do not determine a decoupling (rank {rank} of 26)")
        return cls(coef[:25].T, coef[25])

    def apply(self, unit_force_n) -> np.ndarray:
        """Forces (..., 3), N, from unit forces (..., 5, 5), N."""
        f = _check_grid(unit_force_n, "unit_force_n")
        return f.reshape(*f.shape[:-2], 25) @ self.matrix.T + self.offset


def _plateau(source: Fingertip25, forces: np.ndarray, *, n_hold: int, n_avg: int, rng) -> np.ndarray:
    """Hold each force (n, 3) n_hold samples in one run; mean decoded unit forces of the last n_avg samples."""
    n = forces.shape[0]
    t = np.arange(n * n_hold) / source.config.rate_hz
    f = source.unit_forces(np.repeat(forces, n_hold, axis=0))
    r = source._transduce(f, t, rng)
    dec = force_from_resistance(r, config=source.config).reshape(n, n_hold, 5, 5)
    return dec[:, -n_avg:].mean(axis=1)


def _errors(est: np.ndarray, true: np.ndarray) -> dict:
    e = est - true
    rms = np.sqrt(np.mean(e ** 2, axis=0))
    return {"rms_n": rms.tolist(), "max_abs_n": np.abs(e).max(axis=0).tolist(),
            "bias_n": e.mean(axis=0).tolist(), "rms_total_n": float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))}


def decoupling_study(source: Fingertip25 | None = None, *, n_train: int = 100, n_test: int = 100,
                     seed: int | None = None, fraction: float = 0.75, hold_s: float = 1.0) -> dict:
    r"""Decoupling accuracy on random 3-D forces: the published formula versus a calibrated matrix.

    Each force is held for ``hold_s`` in one continuous run (so the dynamics
    of the previous force settle); the reading is the mean decoded unit force
    over the last 30 % of the hold.

    Parameters
    ----------
    source : Fingertip25, optional
    n_train, n_test : int
        Loads used to fit :class:`DecouplingMatrix`, and loads both methods are tested on.
    seed : int, optional
    fraction : float
        Forces are uniform in ``fraction`` of the sensed domain:
        :math:`F_x \in \pm x_{high}`, :math:`F_y \in [0, y_{high}]`,
        :math:`F_z \in [z_{low}, z_{high}]` scaled by ``fraction``
        (:func:`axis_ranges`), so few units saturate.
    hold_s : float
        Hold time per force, s.

    Returns
    -------
    dict
        JSON-serialisable: ``n_train``, ``n_test``, ``domain_n``, and for
        ``published`` and ``calibrated``: ``rms_n``, ``max_abs_n``, ``bias_n``
        (per axis x, y, z) and ``rms_total_n``; ``sample``: up to 100 test
        forces with both estimates.
    """
    source = _source(source)
    n_train = integer(n_train, "n_train", minimum=26)
    n_test = integer(n_test, "n_test", minimum=1)
    fraction = positive(fraction, "fraction")
    if fraction > 1:
        raise InputError(f"fraction must be in (0, 1], got {fraction!r}")
    hold = positive(hold_s, "hold_s")
    rng = np.random.default_rng(seed_value(seed))
    ax = axis_ranges(config=source.config)
    lo = np.array([-ax["x"][1], 0.0, ax["z"][0]]) * np.array([fraction, 1.0, 1.0])
    hi = np.array([ax["x"][1], ax["y"][1], ax["z"][1]]) * fraction
    forces = rng.uniform(lo, hi, size=(n_train + n_test, 3))
    n_hold = max(3, int(round(hold * source.config.rate_hz)))
    n_avg = max(1, int(round(0.3 * n_hold)))
    readings = _plateau(source, forces, n_hold=n_hold, n_avg=n_avg, rng=rng)
    matrix = DecouplingMatrix.fit(readings[:n_train], forces[:n_train])
    true, meas = forces[n_train:], readings[n_train:]
    pub, cal = decouple(meas, config=source.config), matrix.apply(meas)
    k = min(100, n_test)
    return {"n_train": n_train, "n_test": n_test, "domain_n": {"low": lo.tolist(), "high": hi.tolist()},
            "published": _errors(pub, true), "calibrated": _errors(cal, true),
            "sample": {"true": true[:k].tolist(), "published": pub[:k].tolist(),
                       "calibrated": cal[:k].tolist()}}


# ---- repeatability and dynamics -----------------------------------------------------------------------
#: Unit force levels (N) of the repeated loadings: a staircase up to just under the top of the range.
REPEAT_LEVELS_N = (1.0, 2.0, 3.0, 4.0, 4.8)


def repeatability_error(samples, full_scale: float, *, z: float = 3.0) -> float:
    r"""Repeatability error :math:`\delta_R = Z s / Y_{FS} \times 100\,\%`.

    Parameters
    ----------
    samples : (n,) or (n, m) array
        Outputs of ``n >= 2`` repeated loadings (rows) at ``m`` load points (columns).
    full_scale : float
        Full-scale output :math:`Y_{FS}`, same unit as ``samples``.
    z : float
        Coverage factor: 3 for 99.73 % of a normal distribution.

    Returns
    -------
    float
        :math:`\delta_R` in percent, with :math:`s` the largest sample
        standard deviation (ddof = 1) over the load points.

    Raises
    ------
    ShapeError
        For fewer than 2 repetitions or more than 2 dimensions.

    Examples
    --------
    >>> repeatability_error([[1.0, 5.0], [2.0, 5.0], [3.0, 5.0]], 100.0)
    3.0
    """
    s = finite(real_array(samples, "samples"), "samples")
    if s.ndim == 1:
        s = s[:, None]
    if s.ndim != 2 or s.shape[0] < 2 or s.shape[1] < 1:
        raise ShapeError(f"samples must have shape (n, ) or (n, m) with n >= 2 repetitions, got {s.shape}")
    fs = positive(full_scale, "full_scale")
    z = positive(z, "z")
    return float(100.0 * z * s.std(axis=0, ddof=1).max() / fs)


def repeated_loadings(source: Fingertip25 | None = None, *, levels_n=REPEAT_LEVELS_N, n_cycles: int = 10,
                      seed: int | None = None, hold_s: float = 1.0) -> np.ndarray:
    """Readings of the 8 pad units under repeated staircase loadings with a normal force.

    Each cycle is one loading (its own gain draw): the pad force steps up
    through ``8 * levels_n`` (each pad unit gets ``levels_n``), each held
    ``hold_s``; the reading is the mean decoded force over the last 30 % of
    the hold.

    Returns
    -------
    ndarray
        (n_cycles, len(levels_n), 8), N.
    """
    source = _source(source)
    lv = finite(real_array(levels_n, "levels_n"), "levels_n")
    if lv.ndim != 1 or lv.size < 1 or lv.min() <= 0:
        raise InputError(f"levels_n must be a non-empty 1-D array of forces > 0, got {levels_n!r}")
    n_cycles = integer(n_cycles, "n_cycles", minimum=2)
    hold = positive(hold_s, "hold_s")
    n_hold = max(3, int(round(hold * source.config.rate_hz)))
    n_avg = max(1, int(round(0.3 * n_hold)))
    forces = np.column_stack([np.zeros((lv.size, 2)), 8.0 * lv])
    ss = np.random.SeedSequence(seed_value(seed))
    pad = UNIT_PLANE == 1
    out = np.empty((n_cycles, lv.size, 8))
    for i, child in enumerate(ss.spawn(n_cycles)):
        read = _plateau(source, forces, n_hold=n_hold, n_avg=n_avg, rng=np.random.default_rng(child))
        out[i] = read[:, pad]
    return out


def step_response(source: Fingertip25 | None = None, *, unit_force_n: float = 4.0,
                  rate_hz: float = 1000.0) -> dict:
    """Loading and unloading step of the pad (noise and gain scatter off): measured response times.

    The pad units step from 0 to ``unit_force_n`` and back; times are from
    the step to the first sample whose decoded reading (mean of the 8 pad
    units) has covered 63.2 % or 90 % of the change. Quantisation to
    ``resolution_n`` shifts them slightly from ``tau`` and ``tau·ln 10``.

    Returns
    -------
    dict
        JSON-serialisable: ``t63_load_ms``, ``t90_load_ms``, ``t63_unload_ms``,
        ``t90_unload_ms``, and the trace ``t_s``, ``force_n`` (every 10th sample).
    """
    source = _source(source)
    level = positive(unit_force_n, "unit_force_n")
    rate = positive(rate_hz, "rate_hz")
    quiet = Fingertip25(dataclasses.replace(source.config, noise_n=0.0, repeatability=0.0))
    n = int(round(0.8 * rate))
    t = np.arange(3 * n) / rate
    fz = np.concatenate([np.zeros(n), np.full(n, 8.0 * level), np.zeros(n)])
    sc = Scenario(_POINT, t_s=t, force_n=fz)
    dec = force_from_resistance(quiet.frames(sc, seed=0), config=quiet.config)[:, UNIT_PLANE == 1].mean(axis=1)
    top = dec[2 * n - 1]

    def crossing(start, frac, rising):
        seg = dec[start:]
        hit = seg >= frac * top - 1e-6 if rising else seg <= (1 - frac) * top + 1e-6
        return float(1000.0 * (np.argmax(hit)) / rate) if hit.any() else float("nan")

    return {"t63_load_ms": crossing(n, 1 - math.exp(-1), True), "t90_load_ms": crossing(n, 0.9, True),
            "t63_unload_ms": crossing(2 * n, 1 - math.exp(-1), False),
            "t90_unload_ms": crossing(2 * n, 0.9, False),
            "t_s": t[::10].tolist(), "force_n": dec[::10].tolist()}


# ---- object recognition ---------------------------------------------------------------------------------
#: The hand's fingers, in feature order (25 units each).
FINGERS = ("thumb", "index", "middle", "ring", "little")
_SHAPES = ("sphere", "ellipsoid", "cylinder", "box")
#: Objects with a per-unit contact stiffness at least this (N/mm) count as rigid.
RIGID_STIFFNESS_N_PER_MM = 100.0


@dataclass(frozen=True)
class GraspObject:
    """An object of the recognition study, as data.

    ``fingers`` counts the fingers in contact in a typical grasp, thumb
    included (the thumb opposes the others); ``grasp_force_n`` is the typical
    total grip force (thumb + fingers), lower for fragile objects.
    """

    name: str
    shape: str                  # "sphere", "ellipsoid", "cylinder" or "box"
    size_mm: float              # mm, diameter (sphere, cylinder), short axis (ellipsoid), side (box)
    length_mm: float            # mm, long axis (ellipsoid), length (cylinder), other side (box)
    stiffness_n_per_mm: float   # N/mm, contact stiffness the object offers one unit (inf: rigid)
    fragile: bool               # breaks or dents under a firm grasp
    grasp_force_n: float        # N, typical total grip force
    fingers: int                # fingers in contact, thumb included (2 ... 5)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"name must be a non-empty string, got {self.name!r}")
        if self.shape not in _SHAPES:
            raise InputError(f"shape must be one of {_SHAPES}, got {self.shape!r}")
        for name in ("size_mm", "length_mm", "grasp_force_n"):
            positive(getattr(self, name), name)
        k = self.stiffness_n_per_mm
        if isinstance(k, bool) or not isinstance(k, numbers.Real) or math.isnan(k) or k <= 0:
            raise InputError(f"stiffness_n_per_mm must be a number > 0 (inf: rigid), got {k!r}")
        f = integer(self.fingers, "fingers", minimum=2)
        if f > len(FINGERS):
            raise InputError(f"fingers must be in [2, {len(FINGERS)}], got {f}")

    @property
    def rigid(self) -> bool:
        """True when ``stiffness_n_per_mm >= RIGID_STIFFNESS_N_PER_MM``."""
        return self.stiffness_n_per_mm >= RIGID_STIFFNESS_N_PER_MM


#: The nine objects of the recognition study (rigid and soft).
OBJECTS = (
    GraspObject("sponge", "box", 60.0, 90.0, 0.5, False, 8.0, 5),
    GraspObject("foam ball", "sphere", 60.0, 60.0, 0.8, False, 8.0, 4),
    GraspObject("paper cup", "cylinder", 75.0, 90.0, 1.5, True, 6.0, 5),
    GraspObject("plastic bottle", "cylinder", 65.0, 200.0, 3.0, False, 10.0, 5),
    GraspObject("tennis ball", "sphere", 67.0, 67.0, 6.0, False, 12.0, 4),
    GraspObject("ping-pong ball", "sphere", 40.0, 40.0, 15.0, True, 4.0, 3),
    GraspObject("egg", "ellipsoid", 44.0, 57.0, 300.0, True, 6.0, 3),
    GraspObject("wooden block", "box", 50.0, 50.0, math.inf, False, 12.0, 4),
    GraspObject("steel cylinder", "cylinder", 30.0, 120.0, math.inf, False, 20.0, 5),
)


def _curvature(obj: GraspObject, psi: float) -> np.ndarray:
    """Curvature tensor (2, 2), 1/mm, of the object's surface at the contact, principal axes rotated by psi."""
    if obj.shape == "sphere":
        k1 = k2 = 2.0 / obj.size_mm
    elif obj.shape == "ellipsoid":                 # at the equator of a prolate spheroid, long axis along y
        a, c = obj.size_mm / 2, obj.length_mm / 2
        k1, k2 = 1.0 / a, a / (c * c)
    elif obj.shape == "cylinder":                  # axis across the fingers (x): curved along y
        k1, k2 = 0.0, 2.0 / obj.size_mm
    else:
        k1 = k2 = 0.0
    rot = np.array([[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]])
    return rot @ np.diag([k1, k2]) @ rot.T


def _solve_depth(c: np.ndarray, w: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Depth d per row with sum_i w_i (d - c_i)^+ = target (rows of c (n, m), weights w (m,) > 0)."""
    order = np.argsort(c, axis=1)
    cs = np.take_along_axis(c, order, axis=1)
    ws = np.take_along_axis(np.broadcast_to(w, c.shape), order, axis=1)
    W, S = np.cumsum(ws, axis=1), np.cumsum(ws * cs, axis=1)
    f_at = np.zeros_like(cs)
    f_at[:, 1:] = W[:, :-1] * cs[:, 1:] - S[:, :-1]
    j = np.sum(f_at <= target[:, None], axis=1) - 1
    rows = np.arange(c.shape[0])
    return (target + S[rows, j]) / W[rows, j]


def _finger_unit_forces(source: Fingertip25, obj: GraspObject, finger_force: np.ndarray, pose: np.ndarray
                        ) -> np.ndarray:
    """Unit normal forces (n, 25) of one fingertip for finger forces (n,) and one contact pose.

    pose = (x0, y0, gx, gy, psi): contact point (mm), surface slope, curvature orientation (rad).
    """
    pos = source._positions.reshape(25, 3)
    nz = source._normals.reshape(25, 3)[:, 2]
    x0, y0, gx, gy, psi = pose
    d = pos[:, :2] - (x0, y0)
    q = 0.5 * np.einsum("ni,ij,nj->n", d, _curvature(obj, psi), d) - d @ (gx, gy)
    c = q - pos[:, 2]                       # depth at which each unit starts to touch
    k_eff = 1.0 / (1.0 / source.config.unit_stiffness_n_per_mm + 1.0 / obj.stiffness_n_per_mm)
    depth = _solve_depth(np.broadcast_to(c, (finger_force.size, 25)), k_eff * nz * nz, finger_force)
    return k_eff * nz * np.clip(depth[:, None] - c, 0.0, None)


def _object(obj) -> GraspObject:
    if isinstance(obj, str):
        for o in OBJECTS:
            if o.name == obj:
                return o
        raise InputError(f"unknown object {obj!r}; valid names: {', '.join(o.name for o in OBJECTS)}")
    if not isinstance(obj, GraspObject):
        raise TypeError(f"obj must be a GraspObject or the name of one of OBJECTS, got {type(obj).__name__}")
    return obj


def grasp(obj, *, seed: int | None = None, force_n: float | None = None, source: Fingertip25 | None = None,
          jitter: float = 1.0, ramp_s: float = 0.4, hold_s: float = 0.6) -> np.ndarray:
    r"""Simulated grasp of ``obj`` by a five-finger hand with one fingertip on each finger: 125 features.

    Parameters
    ----------
    obj : GraspObject or str
        An object, or the name of one of :data:`OBJECTS`.
    seed : int, optional
        Seeds the grasp's variation and the sensor noise.
    force_n : float, optional
        Total grip force, N; by default ``obj.grasp_force_n`` × U(1 − 0.15 j, 1 + 0.15 j).
    source : Fingertip25, optional
        The fingertip of every finger (same config).
    jitter : float
        Scale j of the grasp-to-grasp variation (0: every grasp of an object alike but for sensor noise).
    ramp_s, hold_s : float
        The grip force rises linearly over ``ramp_s`` and is held ``hold_s``.

    Returns
    -------
    ndarray
        (125,): mean decoded unit force (N) over the last third of the hold,
        finger-major (:data:`FINGERS`), each finger's 25 units row-major.

    Notes
    -----
    The thumb carries half the grip force, the other fingers in contact
    share the rest (weights :math:`1 + 0.2 j z`); with probability
    :math:`0.1 j` the outermost finger misses. Each contact has a random
    offset on the fingertip (σ = 1 mm · j), a surface slope (σ = 0.04 j)
    and, for curved objects, an orientation jitter (σ = 10° · j; an egg lies
    either way). Contact: the object's surface above its lowest point is
    :math:`q(d) = \tfrac12 d^\top K d - g\cdot d` (curvature tensor
    :math:`K` from shape and size, :math:`d` the offset from the contact
    point in the fingertip's x, y, :math:`g` the slope); pressed in by
    :math:`\delta`, unit :math:`i` at height :math:`z_i` overlaps by
    :math:`o_i = (\delta - q_i + z_i)^+` and carries
    :math:`f_i = k\,o_i\,n_{z,i}` with :math:`k` the unit's and the
    object's stiffness in series; :math:`\delta` solves
    :math:`\sum_i f_i n_{z,i} = F_{finger}` exactly (piecewise linear). Soft
    objects need a large :math:`\delta` and so wrap onto the tilted planes;
    rigid ones load a few units hard. The unit forces go through
    :meth:`Fingertip25.transduce` (dynamics, noise, threshold, quantisation)
    and are decoded with :func:`force_from_resistance`.
    """
    obj = _object(obj)
    source = _source(source)
    j = positive(jitter, "jitter", allow_zero=True)
    if force_n is not None:
        force_n = positive(force_n, "force_n", allow_zero=True)
    ramp, hold = positive(ramp_s, "ramp_s"), positive(hold_s, "hold_s")
    return _grasp(obj, np.random.default_rng(seed_value(seed)), force_n, source, j, ramp, hold)[0]


def _grasp(obj: GraspObject, rng: np.random.Generator, force_n: float | None, source: Fingertip25, j: float,
           ramp: float, hold: float) -> tuple[np.ndarray, float]:
    spread = rng.uniform(1.0 - 0.15 * j, 1.0 + 0.15 * j)
    total = obj.grasp_force_n * spread if force_n is None else force_n
    n_fing = obj.fingers - (1 if obj.fingers > 2 and rng.random() < 0.1 * j else 0)
    w = np.clip(1.0 + 0.2 * j * rng.standard_normal(n_fing - 1), 0.3, None)
    share = np.zeros(len(FINGERS))
    share[0] = 0.5
    share[1:n_fing] = 0.5 * w / w.sum()
    rate = source.config.rate_hz
    n_ramp, n_hold = max(1, int(round(ramp * rate))), max(3, int(round(hold * rate)))
    t = np.arange(n_ramp + n_hold) / rate
    profile = np.minimum(np.arange(n_ramp + n_hold) / n_ramp, 1.0)
    forces = np.zeros((t.size, len(FINGERS), 25))
    for k in range(n_fing):
        flip = math.pi / 2 if obj.shape == "ellipsoid" and rng.random() < 0.5 else 0.0
        x0, y0 = rng.normal(0.0, 1.0 * j, size=2)
        gx, gy = rng.normal(0.0, 0.04 * j, size=2)
        psi = flip + rng.normal(0.0, math.radians(10.0) * j)
        forces[:, k] = _finger_unit_forces(source, obj, total * share[k] * profile, (x0, y0, gx, gy, psi))
    r = source._transduce(forces, t, rng)
    dec = force_from_resistance(r, config=source.config)
    return dec[-max(1, n_hold // 3):].mean(axis=0).reshape(-1), float(total)


def _source(source) -> Fingertip25:
    if source is None:
        return Fingertip25()
    if not isinstance(source, Fingertip25):
        raise TypeError(f"source must be a Fingertip25, got {type(source).__name__}")
    return source


@dataclass(frozen=True, eq=False)
class ObjectDataset:
    """Simulated grasps, one row per grasp.

    Attributes
    ----------
    features : (n, 125) array
        :func:`grasp` features, N.
    label : (n,) int array
        Index into ``names``.
    names : tuple of str
        Object names.
    force_n : (n,) array
        Total grip force of each grasp, N.
    """

    features: np.ndarray
    label: np.ndarray
    names: tuple[str, ...]
    force_n: np.ndarray

    def __post_init__(self) -> None:
        x = finite(real_array(self.features, "features"), "features")
        y = np.asarray(self.label)
        if x.ndim != 2 or y.shape != (x.shape[0],) or np.shape(self.force_n) != y.shape:
            raise ShapeError(f"features must be (n, m), label and force_n (n,), got {x.shape}, {y.shape}, "
                             f"{np.shape(self.force_n)}")
        if y.dtype.kind not in "iu" or (y.size and (y.min() < 0 or y.max() >= len(self.names))):
            raise InputError(f"label must be integers indexing names (0 ... {len(self.names) - 1})")

    def __len__(self) -> int:
        return int(self.label.size)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Table-shaped: ``grasp``, ``label``, ``object``, ``force_n``, ``n_responding``, a column per unit.

        ``n_responding`` counts units whose feature is at least 0.1 N (half the default threshold).
        """
        out = {"grasp": np.arange(len(self)), "label": self.label, "object": np.array(self.names)[self.label],
               "force_n": self.force_n, "n_responding": np.sum(self.features > 0.1, axis=1)}
        for j, finger in enumerate(FINGERS):
            for u in range(25):
                out[f"{finger}_{u}"] = self.features[:, 25 * j + u]
        return out


def object_dataset(*, n_per_object: int, seed: int | None = None, objects=OBJECTS,
                   source: Fingertip25 | None = None, jitter: float = 1.0,
                   progress: bool = False) -> ObjectDataset:
    """Simulated grasps of each object (:func:`grasp`).

    Parameters
    ----------
    n_per_object : int
        Grasps per object.
    seed : int, optional
    objects : sequence of GraspObject
        The classes; :data:`OBJECTS` by default.
    source : Fingertip25, optional
    jitter : float
        Scale of the grasp-to-grasp variation (:func:`grasp`).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    ObjectDataset
    """
    from tqdm import tqdm

    n = integer(n_per_object, "n_per_object", minimum=2)
    objs = tuple(_object(o) for o in objects)
    if len(objs) < 2 or len({o.name for o in objs}) != len(objs):
        raise InputError(f"objects must be at least 2 objects with distinct names, "
                         f"got {[o.name for o in objs]}")
    source = _source(source)
    j = positive(jitter, "jitter", allow_zero=True)
    seeds = np.random.SeedSequence(seed_value(seed)).generate_state(n * len(objs))
    label = np.repeat(np.arange(len(objs)), n)
    x = np.empty((label.size, 125))
    force = np.empty(label.size)
    for i in tqdm(range(label.size), desc="fingertip25 grasps", file=sys.stderr, disable=not progress):
        x[i], force[i] = _grasp(objs[label[i]], np.random.default_rng(int(seeds[i])), None, source, j, 0.4, 0.6)
    return ObjectDataset(x, label, tuple(o.name for o in objs), force)


def hidden_units(n_inputs: int, n_outputs: int, *, a: float = 1.0) -> int:
    r"""Empirical hidden-layer size :math:`h = \sqrt{m + n} + a`, rounded; ``a`` is usually in [1, 10].

    Examples
    --------
    >>> hidden_units(125, 9)          # sqrt(134) + 1 = 12.58
    13
    """
    m = integer(n_inputs, "n_inputs", minimum=1)
    n = integer(n_outputs, "n_outputs", minimum=1)
    return int(round(math.sqrt(m + n) + positive(a, "a", allow_zero=True)))


def recognise_objects(dataset: ObjectDataset, *, seed: int | None = 0, test_size: float = 0.3,
                      hidden: int | None = None, solver: str = "lbfgs", alpha: float = 0.1,
                      max_iter: int = 2000) -> dict:
    """Back-propagation network on min–max normalised grasp features: stratified split, accuracy, confusion.

    Parameters
    ----------
    dataset : ObjectDataset
    seed : int, optional
        Seeds the split and the network's initial weights.
    test_size : float
        Test fraction (0.3: the 70/30 split).
    hidden : int, optional
        Hidden tanh units; by default :func:`hidden_units` (13 for 125 inputs and 9 classes).
    solver : {"lbfgs", "adam", "sgd"}
        scikit-learn's optimiser of the back-propagated gradient.
    alpha : float
        L2 weight decay; some is needed with 125 inputs and a few hundred grasps
        (0.1 generalises best on the simulated sets, 1e-4 overfits).
    max_iter : int

    Returns
    -------
    dict
        JSON-serialisable: ``objects``, ``n_train``, ``n_test``, ``hidden``,
        ``chance``, ``accuracy``, ``train_accuracy``, ``confusion`` (rows: true,
        columns: predicted, in ``objects`` order), ``converged``, ``n_iter``.

    Notes
    -----
    Min–max normalisation to [0, 1] is fitted on the training grasps
    (``MinMaxScaler(clip=True)``: test values outside the training range are
    clipped); the network is ``MLPClassifier(hidden_layer_sizes=(h,),
    activation="tanh")`` with a softmax output of one unit per object.
    """
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.metrics import confusion_matrix
    from sklearn.model_selection import train_test_split
    from sklearn.neural_network import MLPClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import MinMaxScaler
    from threadpoolctl import threadpool_limits

    if not isinstance(dataset, ObjectDataset):
        raise TypeError(f"dataset must be an ObjectDataset, got {type(dataset).__name__}")
    seed = seed_value(seed)
    if isinstance(test_size, bool) or not isinstance(test_size, numbers.Real) or not 0 < test_size < 1:
        raise InputError(f"test_size must be in (0, 1), got {test_size!r}")
    solvers = ("lbfgs", "adam", "sgd")
    if solver not in solvers:
        raise InputError(f"solver must be one of {solvers}, got {solver!r}")
    k = len(dataset.names)
    h = hidden_units(dataset.features.shape[1], k) if hidden is None else integer(hidden, "hidden", minimum=1)
    idx = np.arange(len(dataset))
    tr, te = train_test_split(idx, test_size=test_size, stratify=dataset.label, random_state=seed)
    model = make_pipeline(MinMaxScaler(clip=True),
                          MLPClassifier(hidden_layer_sizes=(h,), activation="tanh", solver=solver,
                                        alpha=positive(alpha, "alpha", allow_zero=True),
                                        max_iter=integer(max_iter, "max_iter", minimum=1), random_state=seed))
    # one BLAS/OpenMP thread: the products are tiny, and threads contending for busy cores cost 30x here
    with warnings.catch_warnings(record=True) as caught, threadpool_limits(limits=1):
        warnings.simplefilter("always", ConvergenceWarning)
        model.fit(dataset.features[tr], dataset.label[tr])
    pred = model.predict(dataset.features[te])
    cm = confusion_matrix(dataset.label[te], pred, labels=np.arange(k))
    return {"objects": list(dataset.names), "n_train": int(tr.size), "n_test": int(te.size), "hidden": h,
            "alpha": float(alpha), "solver": solver,
            "chance": 1.0 / k, "accuracy": float(np.mean(pred == dataset.label[te])),
            "train_accuracy": float(model.score(dataset.features[tr], dataset.label[tr])),
            "confusion": cm.tolist(),
            "converged": not any(issubclass(w.category, ConvergenceWarning) for w in caught),
            "n_iter": int(model[-1].n_iter_)}


def hardness_cues(*, forces_n=(2.0, 5.0, 10.0, 20.0), n_grasps: int = 3, seed: int | None = None,
                  objects=OBJECTS, source: Fingertip25 | None = None) -> dict:
    """How many units respond as the grip force rises, for each object and for rigid versus elastic ones.

    A unit responds when its :func:`grasp` feature is at least half the
    detection threshold (most of its plateau samples are on).

    Returns
    -------
    dict
        JSON-serialisable: ``forces_n``; ``objects``: per object name its
        ``rigid`` flag and ``n_responding`` (mean over ``n_grasps`` per force);
        ``rigid_mean`` and ``elastic_mean`` (mean over the group's objects) and
        each group's least-squares ``*_slope_per_n`` (units per N).
    """
    f = finite(real_array(forces_n, "forces_n"), "forces_n")
    if f.ndim != 1 or f.size < 2 or f.min() < 0:
        raise InputError(f"forces_n must be a 1-D array of at least 2 forces >= 0, got {forces_n!r}")
    n_grasps = integer(n_grasps, "n_grasps", minimum=1)
    objs = tuple(_object(o) for o in objects)
    source = _source(source)
    seeds = np.random.SeedSequence(seed_value(seed)).generate_state(len(objs) * f.size * n_grasps)
    on = 0.5 * source.config.force_low_n
    out = {"forces_n": f.tolist(), "objects": {}}
    counts = np.empty((len(objs), f.size))
    it = iter(seeds)
    for i, o in enumerate(objs):
        for j, force in enumerate(f):
            feats = [grasp(o, seed=int(next(it)), force_n=float(force), source=source) for _ in range(n_grasps)]
            counts[i, j] = np.mean([np.sum(x >= on) for x in feats])
        out["objects"][o.name] = {"rigid": o.rigid, "n_responding": counts[i].tolist()}
    for key, sel in (("rigid", [o.rigid for o in objs]), ("elastic", [not o.rigid for o in objs])):
        sel = np.asarray(sel)
        mean = counts[sel].mean(axis=0) if sel.any() else np.full(f.size, np.nan)
        out[f"{key}_mean"] = mean.tolist()
        out[f"{key}_slope_per_n"] = float(np.polyfit(f, mean, 1)[0]) if sel.any() else float("nan")
    return out


# ---- the study ----------------------------------------------------------------------------------------------
def experiment(*, seed: int = 0, full: bool = False, progress: bool = True) -> dict:
    r"""The fingertip study: law, ranges, dynamics, decoupling, repeatability, recognition, hardness cues.

    Parameters
    ----------
    seed : int
        Seeds everything.
    full : bool
        Full size (300 + 300 decoupling loads, 20 loading cycles, 100 grasps per
        object, 8 force levels × 5 grasps) or small (60 + 40, 5, 30, 3 × 1: a few seconds).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    dict
        JSON-serialisable: ``seed``, ``full``, ``config``, ``law`` (``a_kohm``,
        ``b``), ``ranges`` (:func:`detection_ranges` as lists),
        ``axis_ranges_n``, ``response`` (:func:`step_response`), ``decoupling``
        (:func:`decoupling_study`), ``repeatability`` (per pad unit and the
        mean and max :math:`\delta_R`, %, full scale ``force_high_n``),
        ``recognition`` (:func:`recognise_objects`), ``hardness``
        (:func:`hardness_cues`) and ``seconds``.
    """
    from tqdm import tqdm

    seed = seed_value(seed)
    if seed is None:
        raise InputError("experiment needs an integer seed, got None")
    t0 = time.perf_counter()
    if full:
        n_train, n_test, n_cycles, n_obj, levels, n_grasps = 300, 300, 20, 100, np.linspace(2, 30, 8), 5
    else:
        n_train, n_test, n_cycles, n_obj, levels, n_grasps = 60, 40, 5, 30, np.array([2.0, 8.0, 20.0]), 1
    source = Fingertip25()
    c = source.config
    children = np.random.SeedSequence(seed).spawn(5)
    s_dec, s_rep, s_obj, s_cls, s_hard = (int(s.generate_state(1)[0]) for s in children)
    steps = tqdm(total=5, desc="fingertip25 study", file=sys.stderr, disable=not progress)
    a, b = resistance_law(c)
    ranges = {k: v.tolist() for k, v in detection_ranges(config=c).items()}
    response = step_response(source)
    steps.update()
    decoupling = decoupling_study(source, n_train=n_train, n_test=n_test, seed=s_dec)
    steps.update()
    reads = repeated_loadings(source, n_cycles=n_cycles, seed=s_rep)
    per_unit = [repeatability_error(reads[:, :, u], c.force_high_n) for u in range(reads.shape[2])]
    repeat = {"levels_n": list(REPEAT_LEVELS_N), "n_cycles": n_cycles, "full_scale_n": c.force_high_n, "z": 3.0,
              "per_unit_pct": per_unit, "mean_pct": float(np.mean(per_unit)),
              "max_pct": float(np.max(per_unit))}
    steps.update()
    data = object_dataset(n_per_object=n_obj, seed=s_obj, source=source, progress=False)
    recognition = recognise_objects(data, seed=s_cls % 2 ** 31)
    recognition["n_per_object"] = n_obj
    recognition["rigid"] = [o.rigid for o in OBJECTS]
    steps.update()
    hardness = hardness_cues(forces_n=levels, n_grasps=n_grasps, seed=s_hard, source=source)
    steps.update()
    steps.close()
    config = {k: list(v) if isinstance(v, tuple) else v for k, v in dataclasses.asdict(c).items()}
    return {"seed": seed, "full": bool(full), "config": config, "law": {"a_kohm": a, "b": b},
            "ranges": ranges, "axis_ranges_n": {k: list(v) for k, v in axis_ranges(config=c).items()},
            "response": response, "decoupling": decoupling, "repeatability": repeat,
            "recognition": recognition, "hardness": hardness, "seconds": time.perf_counter() - t0}


def plot_experiment(result: dict, path) -> None:
    """Save a PNG of :func:`experiment`'s result (law, ranges, step, decoupling, confusion, hardness cues)."""
    from matplotlib.figure import Figure

    try:
        law, ranges, resp = result["law"], result["ranges"], result["response"]
        dec, rec, hard, cfg = result["decoupling"], result["recognition"], result["hardness"], result["config"]
    except (KeyError, TypeError) as exc:
        raise InputError(f"result must be a dict returned by experiment(), missing {exc}") from exc
    fig = Figure(figsize=(17, 9), layout="constrained")
    ax = fig.subplots(2, 4)
    f = np.geomspace(0.1, 8.0, 200)
    a_ax = ax[0, 0]
    a_ax.loglog(f, law["a_kohm"] * f ** -law["b"], "k-", label=f"R = {law['a_kohm']:.2f} F^-{law['b']:.3f}")
    a_ax.loglog([cfg["force_low_n"], cfg["force_high_n"]], [cfg["r_low_kohm"], cfg["r_high_kohm"]], "ro",
                label="published points")
    a_ax.axvspan(cfg["force_low_n"], cfg["force_high_n"], color="0.9")
    a_ax.set_xlabel("unit force, N")
    a_ax.set_ylabel("resistance, kΩ")
    a_ax.set_title("resistance law")
    a_ax.legend(fontsize=7)
    b_ax = ax[0, 1]
    planes = [f"F{p} ({x})" for p, x in zip(ranges["plane"], ranges["axis"], strict=True)]
    lo, hi = np.asarray(ranges["low_n"]), np.asarray(ranges["high_n"])
    b_ax.barh(planes, hi - lo, left=lo, color="tab:blue")
    for i, (l_, h_) in enumerate(zip(lo, hi, strict=True)):
        b_ax.text(h_, i, f" {l_:.2f}–{h_:.2f} N", va="center", fontsize=7)
    b_ax.set_xscale("log")
    b_ax.set_xlabel("plane resultant range, N")
    b_ax.set_title("detection ranges (computed)")
    c_ax = ax[0, 2]
    c_ax.plot(resp["t_s"], resp["force_n"], "k-")
    c_ax.set_xlabel("t, s")
    c_ax.set_ylabel("decoded pad-unit force, N")
    c_ax.set_title(f"step: t63 {resp['t63_load_ms']:.0f} ms up, {resp['t63_unload_ms']:.0f} ms down")
    d_ax = ax[0, 3]
    true = np.asarray(dec["sample"]["true"])
    for key, marker in (("published", "o"), ("calibrated", "x")):
        est = np.asarray(dec["sample"][key])
        for k, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            d_ax.plot(true[:, k], est[:, k], marker, ms=3, color=colour, alpha=0.6,
                      label=f"{'xyz'[k]} {key}")
    lim = [float(min(true.min(), 0)), float(true.max())]
    d_ax.plot(lim, lim, "k--", lw=1)
    d_ax.set_xlabel("applied force, N")
    d_ax.set_ylabel("decoupled force, N")
    d_ax.set_title("decoupling: RMS " + ", ".join(f"{k} {dec[k]['rms_total_n']:.2f} N"
                                                 for k in ("published", "calibrated")), fontsize=9)
    d_ax.legend(fontsize=6, ncol=2)
    e_ax = ax[1, 0]
    cm = np.asarray(rec["confusion"])
    e_ax.imshow(cm, cmap="Blues")
    for (i, j), v in np.ndenumerate(cm):
        if v:
            e_ax.text(j, i, str(v), ha="center", va="center", fontsize=7,
                      color="white" if v > cm.max() / 2 else "black")
    names = rec["objects"]
    e_ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=7)
    e_ax.set_yticks(range(len(names)), names, fontsize=7)
    e_ax.set_title(f"recognition: {100 * rec['accuracy']:.1f} % (chance {100 * rec['chance']:.0f} %)")
    g_ax = ax[1, 1]
    forces = hard["forces_n"]
    for name, v in hard["objects"].items():
        g_ax.plot(forces, v["n_responding"], "-" if v["rigid"] else "--", marker=".", label=name)
    g_ax.set_xlabel("grip force, N")
    g_ax.set_ylabel("responding units (of 125)")
    g_ax.set_title("hardness cue per object (solid: rigid)")
    g_ax.legend(fontsize=6)
    h_ax = ax[1, 2]
    h_ax.plot(forces, hard["rigid_mean"], "k-o", label=f"rigid ({hard['rigid_slope_per_n']:.2f} /N)")
    h_ax.plot(forces, hard["elastic_mean"], "m--o", label=f"elastic ({hard['elastic_slope_per_n']:.2f} /N)")
    h_ax.set_xlabel("grip force, N")
    h_ax.set_ylabel("responding units")
    h_ax.set_title("rigid vs elastic")
    h_ax.legend(fontsize=7)
    r_ax = ax[1, 3]
    rep = result.get("repeatability", {})
    per = rep.get("per_unit_pct", [])
    r_ax.bar(range(len(per)), per, color="tab:orange")
    r_ax.set_xlabel("pad unit")
    r_ax.set_ylabel("δ_R, %")
    r_ax.set_title(f"repeatability (Z = 3): mean {rep.get('mean_pct', float('nan')):.2f} %")
    fig.suptitle(f"fingertip25 study (seed {result.get('seed')}, full={result.get('full')})")
    fig.savefig(path, dpi=100)


register_source("fingertip25", Fingertip25Config, Fingertip25)
