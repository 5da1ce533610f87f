"""Non-coplanar 25-unit piezoresistive fingertip (source ``"fingertip25"``): geometry, mechanics, resistance.

Twenty-five piezoresistive units (Ø 2.5 mm) sit on the faceted surface of a
robotic fingertip: a flat pad (the *normal plane*, plane 1) and tilted planes
around it. Each unit's resistance falls from about 38.5 kΩ at 0.2 N to about
1.2 kΩ at 5 N; the detection range is 0.2–5 N, the resolution 0.2 N, and the
response follows a load with 80 ms and an unload with 160 ms. Because the
planes face different directions, the units decouple a 3-D force. This module
simulates the fingertip (:class:`Fingertip25`, registered as
``"fingertip25"``) with its resistance law (:func:`resistance_law`,
:func:`resistance_from_force`, :func:`force_from_resistance`); the published
decoupling and the repeatability error are :mod:`optitact.taxels.decoupling`,
the study (dynamics, decoupling accuracy, repeatability, object recognition)
``optitact.studies.run("fingertip")``.

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
"""

from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from optitact._validate import finite, positive, real_array
from optitact.errors import InputError, ShapeError
from optitact.taxels.sources import INDENTER_SHAPES, Layout, Scenario
from optitact.taxels.base import TaxelSource, check_config, fraction, noise_rng

__all__ = [
    "Fingertip25Config", "Fingertip25", "UNIT_PLANE", "UNIT_SIDE", "PLANE_AXIS", "PUBLISHED_PLANE_UNITS",
    "resistance_law", "resistance_from_force", "force_from_resistance", "check_unit_grid",
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
for _plane, _n in enumerate(PUBLISHED_PLANE_UNITS, start=1):
    if int(np.sum((UNIT_PLANE == _plane) & (UNIT_SIDE > 0))) != _n:  # pragma: no cover - module invariant
        raise RuntimeError(f"unit map disagrees with the published count of plane {_plane}")
UNIT_PLANE.setflags(write=False)
UNIT_SIDE.setflags(write=False)


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
        fraction(self.repeatability, "repeatability", upper=0.3)
        fraction(self.crosstalk, "crosstalk", closed=True)
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
    c = check_config(config, Fingertip25Config)
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
    c = check_config(config, Fingertip25Config)
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


def check_unit_grid(values, name: str) -> np.ndarray:
    """``values`` as a finite float array of shape (..., 5, 5) (the unit grid); a ShapeError names ``name``."""
    arr = finite(real_array(values, name), name)
    if arr.ndim < 2 or arr.shape[-2:] != (5, 5):
        raise ShapeError(f"{name} must have shape (..., 5, 5) (the unit grid), got {arr.shape}")
    return arr


class Fingertip25(TaxelSource):
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
    8 + 2·(4 + 2) + 2 + 3 = 25 units (see :func:`~optitact.taxels.decoupling.decouple` for why).

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
    Grasps of objects use a contact model instead
    (:func:`optitact.studies.fingertip_objects.grasp`).
    """

    name = "fingertip25"
    config_type = Fingertip25Config
    shapes = INDENTER_SHAPES                # any: the fingertip senses the resultant only
    extra = {"direction": (0.0, 0.0, 1.0)}
    drive = "force"

    def _setup(self, config: Fingertip25Config) -> None:
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

    def transduce(self, unit_force_n, t_s, *, seed: int | np.random.Generator | None = None) -> np.ndarray:
        """Resistances (T, ..., 5, 5), kΩ, of the units under normal forces ``unit_force_n`` at times ``t_s``.

        Parameters
        ----------
        unit_force_n : (T, 5, 5) or (T, ..., 5, 5) array
            Normal force on each unit, N, >= 0, in time order; extra middle
            dimensions are independent fingertips (e.g. the fingers of a hand).
        t_s : (T,) array
            Sample times, s, strictly increasing.
        seed : int or numpy.random.Generator, optional
            Seeds this loading's gain scatter and the noise; a Generator is
            drawn from (and so advanced), for callers that share one stream.

        Raises
        ------
        ShapeError, InputError
            For mismatched shapes, negative forces or times that do not increase.
        """
        f = check_unit_grid(unit_force_n, "unit_force_n")
        if f.ndim < 3:
            raise ShapeError(f"unit_force_n must have shape (T, 5, 5) (or (T, ..., 5, 5) for several "
                             f"fingertips), got {f.shape}")
        t = _times(t_s, f.shape[0])
        rng = seed if isinstance(seed, np.random.Generator) else noise_rng(seed)
        return self._transduce(f, t, rng)

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
        _, extra = self.check_scenario(scenario)
        d = finite(real_array(extra["direction"], "direction"), "direction")
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
        rng = noise_rng(seed)
        return self._transduce(self.unit_forces(self.force_vectors(scenario)), scenario.t_s, rng)


def _times(t_s, n: int) -> np.ndarray:
    t = finite(real_array(t_s, "t_s"), "t_s")
    if t.shape != (n,):
        raise ShapeError(f"t_s must have shape ({n},) like the samples, got {t.shape}")
    if n > 1 and np.any(np.diff(t) <= 0):
        raise InputError("t_s must be strictly increasing")
    return t


Fingertip25.register()
