"""Palpating grasps: a parallel gripper with a :class:`~optitact.taxels.thread8.Thread8` on each jaw.

An object catalogue (:data:`OBJECTS`, rigid block ... soft ball), a gripper
protocol (:class:`GraspProtocol`: close until contact, squeeze five 1 mm
steps, release five steps), one simulated grasp (:func:`grasp`) and the
per-frame features of its frames, mean μ and standard deviation σ of the
taxels (:func:`frame_features`, :func:`mu_sigma`).

Convention: see :mod:`optitact.taxels.thread8`. The right jaw faces the left
one, so an object at ``x`` on the left patch sits at ``-x`` on the right
patch.

Examples
--------
>>> [o.name for o in OBJECTS][:2]
['rigid block', 'rigid cylinder']
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from optitact._validate import integer, positive, real_array, seed_value
from optitact.errors import InputError
from optitact.taxels.sources import Indenter, Layout, Scenario
from optitact.taxels.base import fraction
from optitact.taxels.thread8 import SUPPORTED_SHAPES, Thread8, Thread8Config

__all__ = ["PalpationObject", "OBJECTS", "GraspProtocol", "Grasp", "grasp", "default_jaws", "MOUNT_SPREAD",
           "frame_features", "mu_sigma", "MOUNT_TILT", "JAW_EFFECTS"]


@dataclass(frozen=True)
class PalpationObject:
    """An object of the palpation study.

    Parameters
    ----------
    name : str
    indenter : Indenter
        Its shape on the patch (``sphere``, ``cylinder``, ``box`` or ``flat``), size,
        ``stiffness_n_per_mm`` and ``plasticity``.
    width_mm : float
        Its extent between the jaws, mm (where the jaws touch it).
    """

    name: str
    indenter: Indenter
    width_mm: float

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"object name must be a non-empty string, got {self.name!r}")
        if not isinstance(self.indenter, Indenter):
            raise TypeError(f"indenter must be an Indenter, got {type(self.indenter).__name__}")
        if self.indenter.shape not in SUPPORTED_SHAPES:
            raise InputError(f"object indenter shape must be one of {SUPPORTED_SHAPES}, "
                             f"got {self.indenter.shape!r}")
        positive(self.width_mm, "width_mm")

    def as_dict(self) -> dict:
        """JSON-serialisable description (``inf`` stiffness as ``None``: rigid)."""
        ind = self.indenter
        return {"name": self.name, "shape": ind.shape, "size_mm": ind.size_mm,
                "length_mm": None if math.isinf(ind.length_mm) else ind.length_mm,
                "stiffness_n_per_mm": None if math.isinf(ind.stiffness_n_per_mm) else ind.stiffness_n_per_mm,
                "plasticity": ind.plasticity, "width_mm": self.width_mm}


def _obj(name, shape, size, width, *, k=math.inf, plasticity=0.0, length=math.inf):
    return PalpationObject(name, Indenter(shape, size_mm=size, length_mm=length, stiffness_n_per_mm=k,
                                          plasticity=plasticity), width)


#: The ten objects, from a rigid block to a soft ball: shape, size (mm), contact stiffness
#: (N/mm with a plate the size of the patch; rigid = inf), plasticity (0 elastic ... 1 plastic), width (mm).
OBJECTS: tuple[PalpationObject, ...] = (
    _obj("rigid block", "box", 15.0, 40.0),
    _obj("rigid cylinder", "cylinder", 10.0, 20.0),
    _obj("hard ball", "sphere", 25.0, 50.0),
    _obj("wooden bar", "box", 5.0, 30.0, k=100.0, length=60.0),
    _obj("plastic bottle", "cylinder", 30.0, 60.0, k=15.0, plasticity=0.1),
    _obj("tennis ball", "sphere", 33.0, 66.0, k=12.0),
    _obj("clay roll", "cylinder", 15.0, 30.0, k=8.0, plasticity=0.8),
    _obj("paper cup", "cylinder", 35.0, 70.0, k=6.0, plasticity=0.5),
    _obj("foam block", "box", 15.0, 50.0, k=4.0, plasticity=0.05),
    _obj("soft ball", "sphere", 35.0, 70.0, k=2.0),
)


@dataclass(frozen=True)
class GraspProtocol:
    """How the parallel gripper palpates an object (both jaws move symmetrically).

    The gripper starts ``clearance_mm`` (drawn per grasp) wider than the object
    and closes at ``close_speed_mm_s`` until a taxel on either jaw reads
    ``contact_dn`` above its free reading (noise-free) or the object is squeezed
    by ``max_precontact`` of its width; it then closes ``n_steps`` steps of
    ``step_mm`` at ``step_speed_mm_s``, holding ``hold_s`` after each, and opens
    the same steps back to the contact position.

    *Variability of a real gripper* (each drawn per grasp from its seed; set
    to 0 with :meth:`ideal`):

    - ``latency_s``: the controller reacts to the contact reading after a
      delay uniform in this range (at least one frame period, 10 ms: the
      frame must be read and the decision sent; up to 50 ms: a servo command
      over a serial bus plus deceleration), during which the jaws keep closing
      at ``close_speed_mm_s``: the squeeze starts from a pre-compression that
      differs from grasp to grasp (contact onset).
    - ``step_error_mm``: 1-sigma error of every commanded gap (each squeeze and
      release step's target, independently): the position repeatability of a
      small servo-driven parallel gripper (about ±0.1 mm). The gripper is
      position controlled, so this is the grasp-force spread: the force
      follows from the gap through the object's and the pads' stiffness.
    - ``offset_mm`` and ``angle_range_rad``: the object's pose on the patch,
      placed by hand between the open jaws: centre uniform in ±``offset_mm``
      (x and y), axis angle uniform in [0, ``angle_range_rad``) (π: any
      direction; 0: always along x).
    - ``tilt_spread_rad``: 1-sigma of the object's tilt out of the patch plane,
      about each in-plane axis (``Scenario.extra`` ``tilt_x_rad`` /
      ``tilt_y_rad`` of :class:`~optitact.taxels.thread8.Thread8`; mirrored in x on
      the right jaw): an object held by hand between the jaws is square to
      them only by eye. Default 0: a loosely held object between parallel
      jaws is turned flat by the contact moment as they close, so little
      tilt is left once the squeeze starts (with the tilt kept, 1° lowers
      the μ rates of the full study by 5–10 points, 3° by 15–25).
    """

    close_speed_mm_s: float = 10.0               # mm/s, closing speed before contact (gap)
    clearance_mm: tuple[float, float] = (2.0, 6.0)  # mm, range of the initial gap minus the object width
    contact_dn: float = 10.0                     # DN, contact detection level above the free reading
    max_precontact: float = 0.4                  # fraction of the width squeezed before giving up detection
    step_mm: float = 1.0                         # mm, gap change per squeeze/release step
    n_steps: int = 5                             # squeeze steps (as many release steps)
    step_speed_mm_s: float = 10.0                # mm/s, gap speed during a step
    hold_s: float = 0.4                          # s, hold after each step
    offset_mm: float = 2.5                       # mm, object centre uniform in ±offset on the patch (x and y)
    latency_s: tuple[float, float] = (0.01, 0.05)  # s, range of the reaction time after contact detection
    step_error_mm: float = 0.1                   # mm, 1-sigma error of each commanded gap (repeatability)
    angle_range_rad: float = math.pi             # rad, object axis angle uniform in [0, angle_range_rad)
    tilt_spread_rad: float = 0.0                 # rad, 1-sigma of the object's out-of-plane tilt (each axis)

    def __post_init__(self) -> None:
        for name in ("close_speed_mm_s", "contact_dn", "step_mm", "step_speed_mm_s"):
            positive(getattr(self, name), name)
        for name in ("hold_s", "offset_mm", "step_error_mm", "angle_range_rad", "tilt_spread_rad"):
            positive(getattr(self, name), name, allow_zero=True)
        integer(self.n_steps, "n_steps", minimum=1)
        fraction(self.max_precontact, "max_precontact")
        arr = real_array(self.clearance_mm, "clearance_mm")
        if arr.shape != (2,) or not np.all(np.isfinite(arr)) or not 0 < arr[0] <= arr[1]:
            raise InputError(f"clearance_mm must be (low, high) with 0 < low <= high, "
                             f"got {self.clearance_mm!r}")
        object.__setattr__(self, "clearance_mm", (float(arr[0]), float(arr[1])))
        lat = real_array(self.latency_s, "latency_s")
        if lat.shape != (2,) or not np.all(np.isfinite(lat)) or not 0 <= lat[0] <= lat[1]:
            raise InputError(f"latency_s must be (low, high) with 0 <= low <= high, got {self.latency_s!r}")
        object.__setattr__(self, "latency_s", (float(lat[0]), float(lat[1])))

    @classmethod
    def ideal(cls, **changes) -> GraspProtocol:
        """The protocol of an ideal gripper: no reaction latency, exact steps (``changes`` override fields).

        Examples
        --------
        >>> p = GraspProtocol.ideal()
        >>> p.latency_s, p.step_error_mm, p.tilt_spread_rad
        ((0.0, 0.0), 0.0, 0.0)
        """
        return cls(**{"latency_s": (0.0, 0.0), "step_error_mm": 0.0, "tilt_spread_rad": 0.0, **changes})

    def step_profile(self, rate_hz: float, errors_mm=None) -> np.ndarray:
        """Gap reduction (mm) after contact for the squeeze and release phases, one value per frame.

        Parameters
        ----------
        rate_hz : float
            Frame rate.
        errors_mm : (2 n_steps,) array, optional
            Error of each step's target gap reduction (squeeze steps, then
            release steps; the last release returns to the contact position plus
            its error); the gap moves linearly from one target to the next.
            None: exact steps.
        """
        n_move = max(1, int(round(self.step_mm / self.step_speed_mm_s * rate_hz)))
        n_hold = int(round(self.hold_s * rate_hz))
        frac = np.concatenate([np.arange(1, n_move + 1) / n_move, np.ones(n_hold)])
        step = frac * self.step_mm
        if errors_mm is None:
            up = [i * self.step_mm + step for i in range(self.n_steps)]
            down = [(self.n_steps - i) * self.step_mm - step for i in range(self.n_steps)]
            return np.concatenate(up + down)
        err = real_array(errors_mm, "errors_mm")
        if err.shape != (2 * self.n_steps,):
            raise InputError(f"errors_mm must have shape ({2 * self.n_steps},), got {err.shape}")
        n = self.n_steps
        targets = np.r_[np.arange(1, n + 1), np.arange(n - 1, -1, -1)] * self.step_mm + err
        starts = np.r_[0.0, targets[:-1]]
        return np.concatenate([a + frac * (b - a) for a, b in zip(starts, targets, strict=True)])


@dataclass(frozen=True, eq=False)
class Grasp:
    """One simulated grasp: frames of both jaws and the gripper trajectory.

    Attributes
    ----------
    left, right : (T, rows, cols) uint8
        Frames of the left and right jaw, DN.
    t_s : (T,) float
        Sample times, s.
    depth_mm : (T,) float
        Approach of the object into each jaw since first touch (half the gap reduction), mm.
    contact_frame : int
        Frame at which the gripper detected contact; the squeeze steps start
        after the reaction latency (at once with :meth:`GraspProtocol.ideal`).
    x_mm, y_mm, angle_rad : float
        The object's pose on the left patch (mirrored in x on the right one).
    """

    left: np.ndarray
    right: np.ndarray
    t_s: np.ndarray
    depth_mm: np.ndarray
    contact_frame: int
    x_mm: float
    y_mm: float
    angle_rad: float


#: mm and rad, 1-sigma placement of a hand-glued patch on its jaw (by eye: about 1 mm and 3 degrees).
MOUNT_SPREAD = (1.0, math.radians(3.0))
#: rad, tilt of the (left, right) patch on its jaw: a wedge of glue under a hand-placed patch. The published
#: study attributes the left jaw's lower rates to imperfect placement: the left patch sits on a 1 mm wedge
#: across its 20 mm (about 3 degrees), the right one on 0.35 mm (1 degree, placed with care).
MOUNT_TILT = (math.radians(3.0), math.radians(1.0))
#: Effects of a hand-made sensor on a gripper jaw (:class:`~optitact.taxels.thread8.Thread8Config` fields;
#: their physical basis and sources are in its docstring): stitch-tension threshold spread, the silicone
#: pad's two-term Prony relaxation, sensitivity drift between grasps, the scan's crosstalk (open rows).
#: The drift is 0.05, the low end of the 5-20 % that piezoresistive composites are reported to drift: the
#: palpation paper describes its own sensor as "consistent over time with little relaxation".
JAW_EFFECTS = {"threshold_spread": 0.2, "pad_relax_fraction": (0.10, 0.10), "pad_relax_tau_s": (0.5, 20.0),
               "drift_gain_spread": 0.05, "floating_rows": True}


def default_jaws(sensors=None) -> tuple[Thread8, Thread8]:
    """The (left, right) jaws: ``sensors`` checked, or two hand-made arrays for None.

    The default arrays have ``unit_seed`` 0 and 1 and are glued on their jaws
    with the placement spread :data:`MOUNT_SPREAD` (``mount_spread_mm``,
    ``mount_spread_rad``) and the tilts :data:`MOUNT_TILT`; their per-taxel
    and whole-sensor sensitivities and thresholds differ, their rubber pads
    relax and their sensitivity drifts between grasps (:data:`JAW_EFFECTS`,
    :class:`~optitact.taxels.thread8.Thread8Config`).
    """
    if sensors is None:
        mm, rad = MOUNT_SPREAD
        return tuple(Thread8(Thread8Config(unit_seed=i, mount_spread_mm=mm, mount_spread_rad=rad,
                                           mount_tilt_rad=tilt, **JAW_EFFECTS))
                     for i, tilt in zip((0, 1), MOUNT_TILT, strict=True))
    if (not isinstance(sensors, (tuple, list)) or len(sensors) != 2
            or not all(isinstance(s, Thread8) for s in sensors)):
        raise TypeError(f"sensors must be a pair (left, right) of Thread8, got {sensors!r}")
    if sensors[0].layout.rate_hz != sensors[1].layout.rate_hz:
        raise InputError(f"both jaws must sample at the same rate, got {sensors[0].layout.rate_hz} and "
                         f"{sensors[1].layout.rate_hz} Hz")
    return sensors[0], sensors[1]


def grasp(obj: PalpationObject, *, seed: int | None = None, protocol: GraspProtocol | None = None,
          sensors: tuple[Thread8, Thread8] | None = None) -> Grasp:
    """Simulate one palpation grasp of ``obj`` with a random pose.

    Parameters
    ----------
    obj : PalpationObject
        For example one of :data:`OBJECTS`.
    seed : int, optional
        Seeds the pose (offset on the patch, axis angle, initial clearance), the
        gripper's latency and step errors, and both jaws' noise.
    protocol : GraspProtocol, optional
        Gripper motion; ``GraspProtocol()`` by default.
    sensors : (Thread8, Thread8), optional
        Left and right jaw; by default two arrays with ``unit_seed`` 0 and 1.

    Returns
    -------
    Grasp

    Notes
    -----
    The gap closes at constant speed from ``width + clearance``; the depth of
    the object in each jaw is half the gap reduction beyond the object's
    width. Contact is detected on the noise-free response of both jaws
    (loading branch; the level is far below the creep pressure); the
    squeeze/release steps (:meth:`GraspProtocol.step_profile`) follow from
    there. All phases are sampled at the sensors' frame rate.

    Examples
    --------
    >>> g = grasp(OBJECTS[0], seed=1)
    >>> g.left.shape[1:], g.left.dtype.name, g.left.shape == g.right.shape
    ((8, 8), 'uint8', True)
    """
    if not isinstance(obj, PalpationObject):
        raise TypeError(f"obj must be a PalpationObject, got {type(obj).__name__}")
    protocol = GraspProtocol() if protocol is None else protocol
    if not isinstance(protocol, GraspProtocol):
        raise TypeError(f"protocol must be a GraspProtocol, got {type(protocol).__name__}")
    left, right = default_jaws(sensors)
    seed = seed_value(seed)
    ss = np.random.SeedSequence(seed)
    s_pose, s_left, s_right, s_drift, s_tilt = ss.spawn(5)   # the first three as before drift and tilt
    rng = np.random.default_rng(s_pose)
    x, y = rng.uniform(-protocol.offset_mm, protocol.offset_mm, size=2) if protocol.offset_mm else (0.0, 0.0)
    angle = float(rng.uniform(0.0, protocol.angle_range_rad))
    clearance = float(rng.uniform(*protocol.clearance_mm))
    # gripper variability, drawn after the pose (an ideal protocol leaves the pose draws unchanged)
    latency = float(rng.uniform(*protocol.latency_s)) if protocol.latency_s[1] > 0 else 0.0
    errors = (protocol.step_error_mm * rng.standard_normal(2 * protocol.n_steps)
              if protocol.step_error_mm > 0 else None)
    # this grasp's sensitivity drift of each jaw, its own stream (independent of the protocol's draws)
    rng_drift = np.random.default_rng(s_drift)
    gains = (left.drift_gain(rng_drift), right.drift_gain(rng_drift))
    tx, ty = (protocol.tilt_spread_rad * np.random.default_rng(s_tilt).standard_normal(2)
              if protocol.tilt_spread_rad > 0 else (0.0, 0.0))
    tilts = ({"tilt_x_rad": float(tx), "tilt_y_rad": float(ty)},
             {"tilt_x_rad": float(-tx), "tilt_y_rad": float(ty)})
    rate = left.layout.rate_hz
    ind = obj.indenter
    poses = ((left, x, angle), (right, -x, math.pi - angle))

    # closing ramp until contact is detected (or the squeeze limit is reached)
    per_frame = protocol.close_speed_mm_s / rate
    n_close = int(math.ceil((clearance + protocol.max_precontact * obj.width_mm) / per_frame)) + 1
    ramp = np.clip(np.arange(n_close) * per_frame - clearance, 0.0, None) / 2.0
    k_contact = n_close - 1
    for start in range(0, n_close, 32):       # in chunks: most objects are detected early in the ramp
        part = slice(start, min(start + 32, n_close))
        t_part = np.arange(part.start, part.stop) / rate
        detected = np.zeros(t_part.size, dtype=bool)
        for (src, px, pa), gain, tilt in zip(poses, gains, tilts, strict=True):
            sc = Scenario(ind, t_part, x_mm=px, y_mm=y, angle_rad=pa, depth_mm=ramp[part], extra=tilt)
            dn = src.counts(src.voltage(src.contact(sc)["taxel_kpa"], t_part, gain=gain))
            free = src.counts(src.voltage(np.zeros((1, *src.layout.shape))))[0]
            detected |= (dn - free).reshape(t_part.size, -1).max(axis=1) >= protocol.contact_dn
        if detected.any():
            k_contact = start + int(np.argmax(detected))
            break
    # the jaws keep closing for the reaction latency, then step from where they stopped
    n_lat = int(math.ceil(latency * rate - 1e-9))
    d_stop = ramp[k_contact] + protocol.close_speed_mm_s * latency / 2.0
    coast = np.minimum(ramp[k_contact] + np.arange(1, n_lat + 1) * per_frame / 2.0, d_stop)
    start = ramp[k_contact] if n_lat == 0 else d_stop
    squeeze = np.maximum(start + protocol.step_profile(rate, errors) / 2.0, 0.0)
    depth = np.concatenate([ramp[:k_contact + 1], coast, squeeze])
    t = np.arange(depth.size) / rate
    out = []
    for (src, px, pa), s_noise, gain, tilt in zip(poses, (s_left, s_right), gains, tilts, strict=True):
        sc = Scenario(ind, t, x_mm=px, y_mm=y, angle_rad=pa, depth_mm=depth, extra=tilt)
        out.append(src.frames(sc, seed=int(s_noise.generate_state(1)[0]), gain=gain))
    return Grasp(out[0], out[1], t, depth, k_contact, float(x), float(y), angle)



@lru_cache(maxsize=1)
def _default_layout() -> Layout:
    return Thread8().layout


def mu_sigma(frames) -> np.ndarray:
    """(T, 2) series of the frame mean μ and standard deviation σ over all cells of (T, ...) ``frames``."""
    arr = np.asarray(frames)
    flat = np.asarray(arr, dtype=np.float64).reshape(arr.shape[0], -1)
    return np.stack([flat.mean(axis=1), flat.std(axis=1)], axis=1)


def frame_features(frames, *, layout: Layout | None = None) -> dict[str, np.ndarray]:
    r"""Per frame the mean μ and standard deviation σ of all taxels.

    Parameters
    ----------
    frames : (T, H, W) or (H, W) array
        Frames on ``layout`` (uint8, uint16, float32 or float64).
    layout : Layout, optional
        Default: the ``thread8`` layout (8×8). Only cells in ``layout.mask`` count.

    Returns
    -------
    dict
        Table-shaped, one row per frame: ``frame``, ``mu``, ``sigma`` (float64,
        the frames' units).

    Raises
    ------
    ShapeError
        When the frames do not have the layout's shape.
    TypeError, InputError
        For non-numeric or non-finite values.

    Notes
    -----
    :math:`\mu_t = \frac1N\sum_i v_{t,i}`, :math:`\sigma_t = \sqrt{\frac1N\sum_i (v_{t,i} - \mu_t)^2}`
    (population standard deviation) over the :math:`N` cells.

    Examples
    --------
    >>> import numpy as np
    >>> f = frame_features(np.arange(64).reshape(1, 8, 8))
    >>> float(f["mu"][0]), round(float(f["sigma"][0]), 4)
    (31.5, 18.473)
    """
    if layout is None:
        layout = _default_layout()
    if not isinstance(layout, Layout):
        raise TypeError(f"layout must be a Layout, got {type(layout).__name__}")
    arr = layout.check_frames(frames)
    cells = arr[:, layout.mask]
    return {"frame": np.arange(arr.shape[0]), "mu": cells.mean(axis=1), "sigma": cells.std(axis=1)}

