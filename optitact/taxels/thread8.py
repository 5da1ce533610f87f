"""8×8 piezoresistive thread-electrode array (source ``"thread8"``): contact, film response, ADC.

Sixty-four taxels at 2.5 mm pitch sit on a 20×20 mm piezoresistive patch
whose rows and columns are conductive threads; the electronics scan row by
row and read every crossing through a voltage divider with an 8-bit ADC at
100 frames/s. Pressing the patch lowers the crossing's resistance from
megaohms (free) to about 0.5 kΩ, so the divider voltage rises.
:class:`Thread8` simulates the array (registered as ``"thread8"``); grasps
with one array on each gripper jaw are in :mod:`optitact.taxels.grasp`, the
palpation study in ``optitact.studies.palpation``.

Convention: taxel indices are ``(row, col)``, ``(0, 0)`` top-left; the layout
frame has x along columns and y along rows (mm), origin at the patch centre
(:mod:`optitact.taxels.sources`), seen from the grasped object.

Examples
--------
>>> from optitact.taxels.sources import make_source
>>> src = make_source("thread8")
>>> src.layout.shape, src.layout.units, src.layout.rate_hz
((8, 8), 'DN', 100.0)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from optitact._validate import finite, integer, positive, real_array
from optitact.errors import InputError, ShapeError
from optitact.taxels.sources import Indenter, Layout, Scenario
from optitact.taxels.base import TaxelSource, fraction, noise_rng, unit_gains
from optitact.taxels.indenter import surface_height

__all__ = ["Thread8Config", "Thread8", "SUPPORTED_SHAPES", "prony_relax", "matrix_scan_voltage"]

#: Indenter shapes :class:`Thread8` simulates.
SUPPORTED_SHAPES = ("sphere", "cylinder", "box", "flat")

@dataclass(frozen=True)
class Thread8Config:
    r"""The 8×8 piezoresistive thread-electrode array on a gripper jaw.

    Every field states its unit. Per-taxel sensitivities, the whole sensor's
    sensitivity factor and its mounting offset/rotation are drawn once from
    ``unit_seed``, so one config describes one physical sensor; noise is drawn
    from the ``seed`` of each :meth:`Thread8.frames` call. The patch side is
    ``rows * pitch_mm`` (20 mm by default).

    *Sensor-to-sensor variability.* The arrays are hand-made (conductive
    threads sewn over a piezoresistive film), so the film's thickness and the
    threads' contact pressure differ from sensor to sensor: the whole sensor's
    sensitivity is scaled by :math:`e^{\sigma_s z}` (``sensor_gain_spread``
    :math:`\sigma_s` = 0.2, i.e. about ±20 %, the sheet-to-sheet spread of
    commercial piezoresistive films such as Velostat is of that order).
    ``mount_spread_mm`` / ``mount_spread_rad`` describe how precisely the patch
    was glued on its jaw (0: exactly centred and aligned, the default for a
    sensor on its own; :func:`optitact.taxels.grasp.default_jaws` uses 1 mm
    and 3°: placement by eye). Set all three to 0 for an ideal sensor.

    *Effects of a sensor on a gripper jaw* (all off by default, so a bare
    sensor is unchanged; :func:`optitact.taxels.grasp.default_jaws` switches
    them on with the values below):

    - ``threshold_spread``: 1-sigma of ln(onset threshold) across taxels
      (``unit_seed``). Each crossing of two sewn threads is pre-loaded by the
      threads' tension, which differs from stitch to stitch, so each taxel
      starts conducting at its own pressure: the per-taxel *offset* of a
      hand-made sensor (jaws: 0.2, the ±20 % spread of hand-sewn stitches'
      tension, of the order of the sensitivity spread of hand-made
      piezoresistive fabric sensors).
    - ``mount_tilt_rad``: the patch glued at a tilt about its y axis: the
      glue/pad under it is a wedge, so one edge sits ``pitch * cols * tan(tilt)``
      further from the object than the other (sign: positive recesses +x).
      The recessed side touches later and less: the sensor *sees less of the
      object*, and what it sees depends on where the object sits. A hand-glued
      patch on a 5 mm pad: 0.3–1 mm across 20 mm, i.e. 1°–3°.
    - ``pad_relax_fraction`` / ``pad_relax_tau_s``: the silicone pad is
      viscoelastic; its relaxation modulus is the Prony series
      :math:`E(t) = E_0 [1 - \sum_i g_i (1 - e^{-t/\tau_i})]` (a generalised
      standard linear solid). Soft silicone rubbers relax by 10–30 % within
      10–100 s with a fast (0.1–1 s) and a slow (10–100 s) branch (the
      range of published stress-relaxation tests of Ecoflex, Dragon Skin
      and Sylgard 184 elastomers): jaws use :math:`g = (0.10, 0.10)`,
      :math:`\tau = (0.5, 20)` s. Empty: elastic pad. Applied to the
      pressures of a ``depth_mm`` scenario, scaled by the pad's share of the
      series compliance (a soft object relaxes the pad's pressure less).
    - ``drift_gain_spread``: 1-sigma of ln(sensitivity) drift between recordings
      (grasps). Piezoresistive composites drift with temperature, humidity and
      their load history (incomplete recovery after the previous grasp): their
      sensitivity changes between otherwise equal loadings (published
      characterisations of Velostat/Linqstat films report drift and
      repeatability errors of 5–20 %). Jaws: 0.05, the low end of that range,
      because the palpation paper describes its piezoresistive-rubber sensor
      as "consistent over time with little relaxation". Drawn per
      :meth:`Thread8.frames` call (or given as its ``gain``).
    - ``floating_rows``: the scan drives one row at V₊ and reads each column
      through its divider resistor while the other rows are left open (a
      passive row/column matrix without diodes or grounded rows). Current
      then also flows through parallel paths (driven row → pressed crossing →
      other column → pressed crossing → open row → pressed crossing → read
      column), so unloaded crossings inside a loaded region's rows and columns
      read as loaded ("ghosting", crosstalk of resistive matrices; D'Alessio,
      Sens. Actuators A 72, 1999, analyses it). Solved exactly with
      Kirchhoff's laws (:func:`matrix_scan_voltage`). False: every crossing
      read in isolation, the classic divider.
    """

    rows: int = 8                          # taxels along y
    cols: int = 8                          # taxels along x
    pitch_mm: float = 2.5                  # mm, taxel centre spacing (thread spacing)
    v_plus: float = 5.0                    # V, divider supply and ADC reference (ratiometric)
    r_divider_ohm: float = 10e3            # Ω, divider resistor R in V = V₊·R/(R_sensor + R)
    r_free_ohm: float = 1e6                # Ω, crossing resistance without load
    r_pressed_ohm: float = 500.0           # Ω, crossing resistance at full load (limit)
    r_coeff_ohm_kpa: float = 4.5e5         # Ω·kPa, R_sensor - r_pressed ≈ r_coeff / (p - threshold)
    threshold_kpa: float = 30.0            # kPa, pressure below which the film stays open
    transition_kpa: float = 3.0            # kPa, width of the smooth onset around the threshold
    creep_kpa: float = 200.0               # kPa, pressure above which the response creeps
    creep_tau_s: float = 0.5               # s, time constant of creep and its recovery
    creep_fraction: float = 0.15           # 1, steady-state relative rise of effective pressure (p → ∞)
    hysteresis: float = 0.08               # fraction of the peak pressure: widest unloading/loading gap
    sensitivity_spread: float = 0.1        # 1-sigma of ln(sensitivity) across taxels (unit_seed)
    sensor_gain_spread: float = 0.2        # 1-sigma of ln(whole-sensor sensitivity), hand-made (unit_seed)
    mount_spread_mm: float = 0.0           # mm, 1-sigma of the patch's offset on its jaw, x and y (unit_seed)
    mount_spread_rad: float = 0.0          # rad, 1-sigma of the patch's rotation on its jaw (unit_seed)
    threshold_spread: float = 0.0          # 1-sigma of ln(per-taxel onset threshold), stitches (unit_seed)
    mount_tilt_rad: float = 0.0            # rad, tilt of the patch about its y axis on the jaw (wedge of glue)
    pad_relax_fraction: tuple[float, ...] = ()  # 1, Prony weights g_i of the pad's relaxation modulus
    pad_relax_tau_s: tuple[float, ...] = ()     # s, Prony relaxation times tau_i (as many as the weights)
    drift_gain_spread: float = 0.0         # 1-sigma of ln(sensitivity) drift between recordings (grasps)
    floating_rows: bool = False            # unselected rows float during the scan: crosstalk (ghosting)
    unit_seed: int = 0                     # seed of this sensor's per-taxel sensitivities
    adc_bits: int = 8                      # bits of the ADC
    rate_hz: float = 100.0                 # frames / s
    noise_v: float = 0.01                  # V, 1-sigma white noise of every sample before the ADC
    pad_modulus_mpa: float = 0.5           # MPa = N/mm², modulus of the jaw's rubber pad (Winkler layer)
    pad_thickness_mm: float = 5.0          # mm, thickness of the jaw's rubber pad
    grid_mm: float = 0.25                  # mm, contact integration grid (pitch_mm / grid_mm an integer)

    def __post_init__(self) -> None:
        integer(self.rows, "rows", minimum=1)
        integer(self.cols, "cols", minimum=1)
        integer(self.adc_bits, "adc_bits", minimum=1)
        integer(self.unit_seed, "unit_seed", minimum=0)
        if self.adc_bits > 16:
            raise InputError(f"adc_bits must be <= 16 (frames are uint8/uint16), got {self.adc_bits}")
        for name in ("pitch_mm", "v_plus", "r_divider_ohm", "r_free_ohm", "r_pressed_ohm", "r_coeff_ohm_kpa",
                     "threshold_kpa", "transition_kpa", "creep_kpa", "creep_tau_s", "rate_hz",
                     "pad_modulus_mpa", "pad_thickness_mm", "grid_mm"):
            positive(getattr(self, name), name)
        for name in ("sensitivity_spread", "sensor_gain_spread", "mount_spread_mm", "mount_spread_rad",
                     "noise_v", "threshold_spread", "drift_gain_spread"):
            positive(getattr(self, name), name, allow_zero=True)
        finite(real_array(self.mount_tilt_rad, "mount_tilt_rad"), "mount_tilt_rad")
        if not abs(self.mount_tilt_rad) < 0.5:
            raise InputError(f"mount_tilt_rad must be within ±0.5 rad, got {self.mount_tilt_rad!r}")
        g = real_array(self.pad_relax_fraction, "pad_relax_fraction").ravel()
        tau = real_array(self.pad_relax_tau_s, "pad_relax_tau_s").ravel()
        if g.shape != tau.shape:
            raise InputError(f"pad_relax_fraction and pad_relax_tau_s must have the same length, got "
                             f"{g.size} and {tau.size}")
        if not (np.all(np.isfinite(g)) and np.all(g >= 0) and g.sum() < 1):
            raise InputError(f"pad_relax_fraction must be >= 0 with a sum < 1, got {self.pad_relax_fraction!r}")
        if not (np.all(np.isfinite(tau)) and np.all(tau > 0)):
            raise InputError(f"pad_relax_tau_s must be > 0, got {self.pad_relax_tau_s!r}")
        object.__setattr__(self, "pad_relax_fraction", tuple(float(v) for v in g))
        object.__setattr__(self, "pad_relax_tau_s", tuple(float(v) for v in tau))
        fraction(self.creep_fraction, "creep_fraction")
        fraction(self.hysteresis, "hysteresis", upper=0.5)
        if self.r_pressed_ohm >= self.r_free_ohm:
            raise InputError(f"r_pressed_ohm must be < r_free_ohm = {self.r_free_ohm:g}, "
                             f"got {self.r_pressed_ohm!r}")
        ratio = self.pitch_mm / self.grid_mm
        if abs(ratio - round(ratio)) > 1e-9 or round(ratio) < 1:
            raise InputError(f"pitch_mm / grid_mm must be a positive integer, got {self.pitch_mm!r} / "
                             f"{self.grid_mm!r} = {ratio:g}")

    @property
    def pad_kpa_per_mm(self) -> float:
        """Areal stiffness of the rubber pad, kPa per mm of compression (E / t)."""
        return 1e3 * self.pad_modulus_mpa / self.pad_thickness_mm


def matrix_scan_voltage(conductance_s, v_plus: float, r_divider_ohm: float) -> np.ndarray:
    r"""Column voltages of a passive row/column resistive matrix scanned row by row with open unselected rows.

    Parameters
    ----------
    conductance_s : (..., rows, cols) array
        Conductance of every crossing, S (> 0).
    v_plus : float
        Voltage of the driven row, V.
    r_divider_ohm : float
        Each column's resistor to ground, Ω.

    Returns
    -------
    ndarray
        (..., rows, cols): the voltage of column ``j`` while row ``i`` is driven.

    Notes
    -----
    Unknowns: the column voltages :math:`w_c` and the open rows' voltages
    :math:`u_r`. Kirchhoff's current law at column :math:`c`:
    :math:`\sum_r G_{rc}(u_r - w_c) = w_c / R`; at an open row :math:`r`:
    :math:`\sum_c G_{rc}(w_c - u_r) = 0`; the driven row :math:`u_i = V_+`.
    With one crossing conducting the reading is the divider :math:`V_+ R G/(1 + R G)`.

    Examples
    --------
    >>> g = np.full((2, 2), 1e-9); g[0, 0] = 1e-3
    >>> round(float(matrix_scan_voltage(g, 5.0, 1e4)[0, 0]), 4)                       # 5 * 10 / 11
    4.5455
    """
    g = np.asarray(conductance_s, dtype=float)
    nr, nc = g.shape[-2:]
    lead = g.shape[:-2]
    g = g.reshape(-1, nr, nc)
    n = nr + nc
    a = np.zeros((g.shape[0], n, n))
    ri, ci = np.arange(nr), nr + np.arange(nc)
    a[:, ri, ri] = g.sum(axis=2)
    a[:, ci, ci] = g.sum(axis=1) + 1.0 / r_divider_ohm
    a[:, :nr, nr:] = -g
    a[:, nr:, :nr] = -np.swapaxes(g, 1, 2)
    out = np.empty_like(g)
    for i in range(nr):                                 # the driven row's equation becomes u_i = V+
        ai = a.copy()
        ai[:, i, :] = 0.0
        ai[:, i, i] = 1.0
        b = np.zeros((g.shape[0], n))
        b[:, i] = v_plus
        out[:, i, :] = np.linalg.solve(ai, b[..., None])[:, nr:, 0]
    return out.reshape(*lead, nr, nc)


def prony_relax(p_elastic, t_s, fractions, taus_s) -> np.ndarray:
    r"""Pressure of a linear viscoelastic layer (Prony series) driven by its elastic pressure history.

    Parameters
    ----------
    p_elastic : (T, ...) array
        The pressure an elastic layer of the instantaneous modulus would carry, in time order.
    t_s : (T,) array
        Sample times, s (increasing).
    fractions, taus_s : sequences of float
        Prony weights :math:`g_i` (sum < 1) and relaxation times :math:`\tau_i`, s.

    Returns
    -------
    ndarray
        :math:`p(t) = \int_0^t [1 - \sum_i g_i (1 - e^{-(t-s)/\tau_i})]\,\dot p_e(s)\,ds`
        (the Boltzmann superposition integral of the relaxation function), same shape.

    Notes
    -----
    With :math:`h_i = \int e^{-(t-s)/\tau_i} \dot p_e\,ds`, :math:`p = (1 - \sum g_i) p_e + \sum g_i h_i`.
    The update is exact for a history linear between samples:
    :math:`h_i \leftarrow a h_i + \Delta p_e \frac{\tau_i}{\Delta t}(1 - a)`, :math:`a = e^{-\Delta t/\tau_i}`.
    The history starts at rest (:math:`p_e = 0` before the first sample, reached as a step).
    No clipping: the caller clips where the layer cannot pull.

    Examples
    --------
    >>> t = np.arange(0, 3.0, 0.01)
    >>> p = prony_relax(np.minimum(t / 0.1, 1.0), t, (0.2,), (1.0,))
    >>> round(float(p[-1]), 3)                                    # relaxing towards 1 - 0.2
    0.811
    """
    p = np.asarray(p_elastic, dtype=float)
    t = np.asarray(t_s, dtype=float)
    out = (1.0 - float(sum(fractions))) * p
    if p.shape[0] == 0 or not len(fractions):
        return p.copy() if not len(fractions) else out
    dt = np.diff(t)
    dp = np.diff(p, axis=0)
    for g, tau in zip(fractions, taus_s, strict=True):
        a = np.exp(-dt / tau)
        b = np.where(dt > 0, tau / np.where(dt > 0, dt, 1.0) * -np.expm1(-dt / tau), 1.0)
        h = p[0].copy()
        acc = np.empty_like(p)
        acc[0] = h
        for i in range(dt.size):
            h = a[i] * h + b[i] * dp[i]
            acc[i + 1] = h
        out = out + g * acc
    return out


class Thread8(TaxelSource):
    r"""Simulated 8×8 piezoresistive thread-electrode array (source ``"thread8"``).

    Parameters
    ----------
    config : Thread8Config, optional
        The sensor instance; defaults to ``Thread8Config()``.

    Notes
    -----
    *Contact.* The patch lies on a rubber pad (Winkler layer, areal stiffness
    :math:`\kappa_p = E/t`) and the object's surface is a second Winkler
    layer in series, :math:`\kappa_o = k / A_{pad}`, where :math:`k` is the
    indenter's ``stiffness_n_per_mm`` measured with a plate the size of the
    patch (:math:`A_{pad}`; rigid: :math:`\kappa_o = \infty`). With the object's
    undeformed surface :math:`h(x, y)` above its crest (sphere / cylinder of
    radius :math:`R`: :math:`h = R - \sqrt{R^2 - r^2}`, :math:`\infty` beyond
    :math:`R` or beyond the length; box: 0 on its face of :math:`2a \times L`,
    :math:`\infty` off it; flat: 0) and the depth :math:`d` (``depth_mm``: how far
    the crest has moved into pad + object since first touch), the overlap
    is :math:`u = \max(0, d - h)` and, on first loading, the pressure is
    :math:`p = \kappa u`, :math:`\kappa = (1/\kappa_p + 1/\kappa_o)^{-1}`.
    Object compliance and size therefore set the contact area and pressure:
    a soft object needs a large depth for a given pressure and flattens over
    a wide area; a small rigid one concentrates the load.

    *Plasticity.* A plastic object keeps part of its deformation: at each
    point the object's set after unloading is :math:`r\,u_{max}`, with
    :math:`r = \phi\,\kappa/\kappa_o` (plasticity :math:`\phi` times the
    object's share of the compression) and :math:`u_{max}` the largest overlap
    so far. Below :math:`u_{max}` the pressure follows the elastic unloading
    line :math:`p = \kappa u_{max}\,\mathrm{clip}((u - r u_{max}) / ((1 - r) u_{max}), 0, 1)`,
    so on release it drops faster and reaches 0 before the object is free.

    *Taxels.* Each taxel reads the mean pressure :math:`p_i` over its
    ``pitch × pitch`` cell. Hysteresis: while unloading from its running peak
    :math:`P_i` the film behaves as if pressed by
    :math:`p_i + \eta P_i\,4q(1 - q)`, :math:`q = p_i/P_i` (``hysteresis``
    :math:`\eta`). Creep: above :math:`p_c` (``creep_kpa``) the effective
    pressure drifts up as :math:`p(1 + c)` with
    :math:`\dot c = (c_\infty - c)/\tau`, :math:`c_\infty = f_c \max(0, 1 - p_c/p)`
    (first order, also recovering with :math:`\tau` when unloaded).

    *Resistance.* With the smooth excess over the threshold
    :math:`e = w \ln(1 + e^{(p - p_{th})/w})` (``transition_kpa`` :math:`w`):

    .. math:: R_s = R_{pr} + \left(\frac{1}{R_{free} - R_{pr}} + \frac{s_i e}{\rho}\right)^{-1},

    i.e. :math:`R_{free}` (≈ 1 MΩ) below the threshold, a conductance that
    grows linearly with the excess pressure above it (:math:`\rho` =
    ``r_coeff_ohm_kpa``, per-taxel sensitivity :math:`s_i` from ``unit_seed``)
    and the limit :math:`R_{pr}` (≈ 0.5 kΩ). The divider gives
    :math:`V = V_+ R/(R_s + R)`; white noise is added and the ADC (reference
    :math:`V_+`) quantises to ``adc_bits``. Frames are uint8 (uint16 above 8
    bits) DN (``layout.units == "DN"``). The per-taxel sensitivities
    :math:`s_i` include the whole sensor's factor ``sensor_gain``; object
    poses are given in the jaw frame and moved into the patch frame by the
    mounting offset ``mount_offset_mm`` and rotation ``mount_angle_rad``
    (see :class:`Thread8Config`). The row/column scan is treated as
    simultaneous within a frame; crosstalk through the open rows of the scan
    is modelled with ``floating_rows`` (:func:`matrix_scan_voltage`), the pad's
    viscoelastic relaxation with ``pad_relax_fraction`` (:func:`prony_relax`).
    """

    name = "thread8"
    config_type = Thread8Config
    shapes = SUPPORTED_SHAPES
    #: ``Scenario.extra``: the object's surface tilted towards +x / +y of the jaw frame (rad, out of the
    #: patch plane): a hand-placed object is not exactly square to the jaw
    #: (:class:`~optitact.taxels.grasp.GraspProtocol` ``tilt_spread_rad``)
    extra = {"tilt_x_rad": 0.0, "tilt_y_rad": 0.0}

    def __init__(self, config: Thread8Config | None = None) -> None:
        super().__init__(config)

    def _setup(self, c: Thread8Config) -> None:
        rng = np.random.default_rng(c.unit_seed)
        gains = unit_gains(rng, (c.rows, c.cols), c.sensitivity_spread)
        # drawn after the per-taxel gains (those stay as before); spread 0 gives exactly 1 / 0
        z_sensor, zx, zy, za = rng.standard_normal(4)
        #: whole-sensor sensitivity factor (hand-made sensor), 1
        self.sensor_gain = float(np.exp(c.sensor_gain_spread * z_sensor))
        self.sensitivity = gains * self.sensor_gain if self.sensor_gain != 1.0 else gains
        self.sensitivity.setflags(write=False)
        #: the patch centre's offset on its jaw (x, y), mm, and its in-plane rotation, rad
        self.mount_offset_mm = (float(c.mount_spread_mm * zx), float(c.mount_spread_mm * zy))
        self.mount_angle_rad = float(c.mount_spread_rad * za)
        # drawn after everything above (unchanged by these fields); spread 0 gives exactly 1
        z_thr = rng.standard_normal((c.rows, c.cols))
        #: per-taxel onset threshold, kPa (stitch tension of a hand-sewn crossing)
        self.threshold_kpa = c.threshold_kpa * np.exp(c.threshold_spread * z_thr)
        self.threshold_kpa.setflags(write=False)
        half = c.cols * c.pitch_mm / 2.0
        tilt = math.tan(c.mount_tilt_rad)
        self._sub = int(round(c.pitch_mm / c.grid_mm))
        ny, nx = c.rows * self._sub, c.cols * self._sub
        gy = (np.arange(ny) - (ny - 1) / 2) * c.grid_mm
        gx = (np.arange(nx) - (nx - 1) / 2) * c.grid_mm
        yy, xx = np.meshgrid(gy, gx, indexing="ij")
        self._gx, self._gy = xx.ravel(), yy.ravel()
        iy, ix = np.meshgrid(np.arange(ny) // self._sub, np.arange(nx) // self._sub, indexing="ij")
        self._gy_cell, self._gx_cell = iy.ravel(), ix.ravel()
        self._cell_area = c.grid_mm ** 2
        #: recess of each grid point below the jaw's contact plane, mm (tilted mounting; >= 0)
        self._recess = self._gx * tilt + half * abs(tilt) if tilt else None

    @cached_property
    def layout(self) -> Layout:
        """8×8 grid, 2.5 mm pitch, values in ADC counts (DN), 100 Hz."""
        c = self.config
        return Layout(shape=(c.rows, c.cols), pitch_mm=(c.pitch_mm, c.pitch_mm), units="DN",
                      rate_hz=c.rate_hz)

    @property
    def pad_area_mm2(self) -> float:
        """Area of the patch, mm²."""
        c = self.config
        return c.rows * c.cols * c.pitch_mm ** 2

    @property
    def full_scale(self) -> int:
        """Largest ADC count."""
        return 2 ** self.config.adc_bits - 1

    # ---- contact ---------------------------------------------------------------------------------
    def _heights(self, ind: Indenter, x, y, ang, tilt=(0.0, 0.0)) -> np.ndarray:
        r"""Object surface above its crest on the grid, (n, N) mm (inf where it cannot touch).

        The pose (jaw frame) is moved into the patch frame: minus the mounting
        offset, rotated by minus the mounting angle; a tilted patch adds its
        recess :math:`x \tan\beta + (W/2)|\tan\beta|` (``mount_tilt_rad``
        :math:`\beta`, patch width :math:`W`) to the gap. A tilted object
        (``tilt`` = (tilt_x, tilt_y), jaw frame) adds the plane
        :math:`\tan t_x (x - x_0) + \tan t_y (y - y_0)` through its crest, shifted
        so that its nearest point on the patch is at 0 (first touch at depth 0).
        """
        tx, ty = math.tan(float(tilt[0])), math.tan(float(tilt[1]))
        ox, oy = self.mount_offset_mm
        th = self.mount_angle_rad
        if ox or oy or th:
            dx, dy = np.asarray(x, dtype=float) - ox, np.asarray(y, dtype=float) - oy
            cs, sn = math.cos(th), math.sin(th)
            x, y, ang = cs * dx + sn * dy, -sn * dx + cs * dy, np.asarray(ang, dtype=float) - th
        h = surface_height(ind, self._gx, self._gy, x, y, ang)
        if tx or ty:
            cs, sn = math.cos(th), math.sin(th)                # the jaw-frame gradient in the patch frame
            gx, gy = cs * tx + sn * ty, -sn * tx + cs * ty
            xs = np.atleast_1d(np.asarray(x, dtype=float))[:, None]
            ys = np.atleast_1d(np.asarray(y, dtype=float))[:, None]
            plane = gx * (self._gx[None, :] - xs) + gy * (self._gy[None, :] - ys)
            h2 = np.atleast_2d(h)
            low = np.min(np.where(np.isfinite(h2), h2 + plane, np.inf), axis=1, keepdims=True)
            low = np.where(np.isfinite(low), np.minimum(low, 0.0), 0.0)
            h = (h2 + plane - low).reshape(h.shape)
        return h if self._recess is None else h + self._recess

    def _stiffness(self, ind: Indenter) -> tuple[float, float]:
        """Series areal stiffness (kPa/mm) and the plastic set fraction r."""
        kp = self.config.pad_kpa_per_mm
        if math.isinf(ind.stiffness_n_per_mm):
            return kp, 0.0
        ko = 1e3 * ind.stiffness_n_per_mm / self.pad_area_mm2
        k = 1.0 / (1.0 / kp + 1.0 / ko)
        return k, ind.plasticity * k / ko

    @staticmethod
    def _pressure(u: np.ndarray, umax: np.ndarray, k: float, r: float) -> np.ndarray:
        """Pressure (kPa) at overlap ``u`` after the largest overlap ``umax`` (>= u)."""
        if r == 0.0:
            return k * u
        safe = np.where(umax > 0, umax, 1.0)
        return k * umax * np.clip((u - r * umax) / ((1.0 - r) * safe), 0.0, 1.0)

    def _check(self, scenario: Scenario) -> Indenter:
        ind, ex = self.check_scenario(scenario)
        self._tilt = (float(ex["tilt_x_rad"]), float(ex["tilt_y_rad"]))
        return ind

    def contact(self, scenario: Scenario) -> dict[str, np.ndarray]:
        """Noise-free contact state per sample.

        Parameters
        ----------
        scenario : Scenario
            Indenter ``sphere``/``cylinder`` (``size_mm`` = radius), ``box``
            (``size_mm`` = half width of its face, ``length_mm`` its length) or
            ``flat``, with ``stiffness_n_per_mm`` and ``plasticity``; pose
            ``x_mm``, ``y_mm``, ``angle_rad`` (axis of a cylinder/box); either
            ``depth_mm`` (the object's crest approach into pad + object since
            first touch) or ``force_n`` (total normal force on this patch).

        Returns
        -------
        dict
            Table-shaped, one row per sample: ``frame``, ``depth_mm``,
            ``force_n`` (total normal force on the patch), ``peak_kpa`` (largest
            pressure on the patch) and ``taxel_kpa`` ((T, rows, cols) mean
            pressure over each taxel cell, kPa).

        Raises
        ------
        TypeError
            If ``scenario`` is not a Scenario.
        InputError
            For an unsupported indenter, ``extra`` keys, or a force that cannot be reached.
        """
        ind = self._check(scenario)
        k, r = self._stiffness(ind)
        c = self.config
        n_t, n_g = scenario.n_frames, self._gx.size
        taxel = np.zeros((n_t, c.rows, c.cols))
        force = np.zeros(n_t)
        peak = np.zeros(n_t)
        sx, sy, sa = scenario.x_mm, scenario.y_mm, scenario.angle_rad
        sub = self._sub

        def store(idx, p):
            grid = p.reshape(idx.size, c.rows, sub, c.cols, sub)
            taxel[idx] = grid.mean(axis=(2, 4))
            force[idx] = p.sum(axis=1) * self._cell_area * 1e-3
            peak[idx] = p.max(axis=1)

        prev = np.zeros(n_g)
        static = all(np.all(a == a[0]) for a in (sx, sy, sa))
        if scenario.depth_mm is not None and static:
            # one pose: u_max = clip(running max depth - h); only points that are ever touched matter
            depth = np.asarray(scenario.depth_mm, dtype=float)
            h = self._heights(ind, sx[:1], sy[:1], sa[:1], self._tilt)[0]
            hit = np.flatnonzero(h < depth.max())
            if hit.size:
                u = np.clip(depth[:, None] - h[hit], 0.0, None)
                umax = np.clip(np.maximum.accumulate(depth)[:, None] - h[hit], 0.0, None)
                p = self._pressure(u, umax, k, r)
                cell = self._gy_cell[hit] * c.cols + self._gx_cell[hit]      # hit is sorted, cells are not
                order = np.argsort(cell, kind="stable")
                cells, starts = np.unique(cell[order], return_index=True)
                sums = np.zeros((n_t, c.rows * c.cols))
                sums[:, cells] = np.add.reduceat(p[:, order], starts, axis=1)
                taxel[:] = (sums / sub ** 2).reshape(n_t, c.rows, c.cols)
                force[:] = p.sum(axis=1) * self._cell_area * 1e-3
                peak[:] = p.max(axis=1)
        elif scenario.depth_mm is not None:
            depth = np.asarray(scenario.depth_mm, dtype=float)
            for start in range(0, n_t, 128):
                idx = np.arange(start, min(start + 128, n_t))
                h = self._heights(ind, sx[idx], sy[idx], sa[idx], self._tilt)
                u = np.clip(depth[idx, None] - h, 0.0, None)
                umax = np.maximum(prev[None, :], np.maximum.accumulate(u, axis=0))
                store(idx, self._pressure(u, umax, k, r))
                prev = umax[-1]
        else:
            from scipy.optimize import brentq

            depth = np.zeros(n_t)
            for i, f in enumerate(scenario.force_n):
                h = self._heights(ind, sx[i:i + 1], sy[i:i + 1], sa[i:i + 1], self._tilt)[0]

                def excess(d, h=h, f=f, prev=prev):
                    u = np.clip(d - h, 0.0, None)
                    return self._pressure(u, np.maximum(prev, u), k, r).sum() * self._cell_area * 1e-3 - f

                if f > 0:
                    hi = 0.1
                    while excess(hi) < 0:
                        hi *= 2.0
                        if hi > 1e4:
                            raise InputError(f"force_n[{i}] = {f} N cannot be reached by this indenter "
                                             "on the patch")
                    depth[i] = brentq(excess, 0.0, hi, xtol=1e-10, rtol=1e-12)
                u = np.clip(depth[i] - h, 0.0, None)
                umax = np.maximum(prev, u)
                store(np.array([i]), self._pressure(u, umax, k, r)[None, :])
                prev = umax
        if scenario.depth_mm is not None and c.pad_relax_fraction:
            share = k / c.pad_kpa_per_mm               # the pad's share of the series compliance (rigid: 1)
            g = tuple(share * gi for gi in c.pad_relax_fraction)
            t = np.asarray(scenario.t_s, dtype=float)
            taxel = np.clip(prony_relax(taxel, t, g, c.pad_relax_tau_s), 0.0, None)
            force = np.clip(prony_relax(force, t, g, c.pad_relax_tau_s), 0.0, None)
            peak = np.clip(prony_relax(peak, t, g, c.pad_relax_tau_s), 0.0, None)
        return {"frame": np.arange(n_t), "depth_mm": depth, "force_n": force, "peak_kpa": peak,
                "taxel_kpa": taxel}

    # ---- response --------------------------------------------------------------------------------
    def resistance_ohm(self, pressure_kpa, *, sensitivity=1.0, threshold_kpa=None) -> np.ndarray:
        """Static crossing resistance (Ω) at effective pressure ``pressure_kpa`` (no hysteresis or creep).

        Parameters
        ----------
        pressure_kpa : float or array
            Effective pressure, kPa (>= 0).
        sensitivity : float or array
            Per-taxel sensitivity factor :math:`s_i` (1 = nominal); broadcast with ``pressure_kpa``.
        threshold_kpa : float or array, optional
            Onset threshold(s), kPa; default the config's ``threshold_kpa``.

        Examples
        --------
        >>> src = Thread8()
        >>> float(src.resistance_ohm(0.0)) > 0.99e6, round(float(src.resistance_ohm(1e6)))
        (True, 500)
        """
        p = finite(real_array(pressure_kpa, "pressure_kpa"), "pressure_kpa")
        if p.size and p.min() < 0:
            raise InputError(f"pressure_kpa must be >= 0, got minimum {p.min()}")
        c = self.config
        w = c.transition_kpa
        thr = c.threshold_kpa if threshold_kpa is None else np.asarray(threshold_kpa, dtype=float)
        excess = w * np.logaddexp(0.0, (p - thr) / w)
        g = 1.0 / (c.r_free_ohm - c.r_pressed_ohm) + np.asarray(sensitivity) * excess / c.r_coeff_ohm_kpa
        return c.r_pressed_ohm + 1.0 / g

    def effective_kpa(self, taxel_kpa, t_s=None) -> np.ndarray:
        """Pressure the film responds to (T, rows, cols), kPa: taxel pressure with hysteresis and creep.

        Parameters
        ----------
        taxel_kpa : (T, rows, cols) array
            Mean pressure per taxel, kPa, in time order.
        t_s : (T,) array, optional
            Sample times, s; by default ``arange(T) / rate_hz``.
        """
        p = self.layout.check_frames(taxel_kpa, "taxel_kpa")
        if np.any(p < 0):
            raise InputError(f"taxel_kpa must be >= 0, got minimum {p.min()}")
        c = self.config
        n = p.shape[0]
        if t_s is None:
            t_s = np.arange(n) / c.rate_hz
        t = finite(real_array(t_s, "t_s"), "t_s")
        if t.shape != (n,):
            raise ShapeError(f"t_s must have shape ({n},) like taxel_kpa, got {t.shape}")
        peak = np.maximum.accumulate(p, axis=0)
        q = np.divide(p, peak, out=np.ones_like(p), where=peak > 0)
        ph = p + c.hysteresis * peak * 4.0 * q * (1.0 - q)
        ratio = np.divide(c.creep_kpa, ph, out=np.full_like(ph, np.inf), where=ph > 0)
        c_inf = c.creep_fraction * np.clip(1.0 - ratio, 0.0, None)
        dt = np.diff(t, prepend=t[0] - 1.0 / c.rate_hz)
        alpha = -np.expm1(-dt / c.creep_tau_s)
        creep = np.zeros_like(ph)
        state = np.zeros(ph.shape[1:])
        for i in range(n):
            state = state + alpha[i] * (c_inf[i] - state)
            creep[i] = state
        return ph * (1.0 + creep)

    def voltage(self, taxel_kpa, t_s=None, *, gain: float = 1.0) -> np.ndarray:
        """Noise-free divider voltage (T, rows, cols), V, for taxel pressures in time order.

        See :meth:`effective_kpa` for the parameters and the class Notes for the model;
        ``gain`` scales every taxel's sensitivity (this recording's drift, :meth:`drift_gain`).
        """
        sens = self.sensitivity if gain == 1.0 else self.sensitivity * float(gain)
        thr = self.threshold_kpa if self.config.threshold_spread else None
        r_s = self.resistance_ohm(self.effective_kpa(taxel_kpa, t_s), sensitivity=sens, threshold_kpa=thr)
        c = self.config
        if c.floating_rows:
            return matrix_scan_voltage(1.0 / r_s, c.v_plus, c.r_divider_ohm)
        return c.v_plus * c.r_divider_ohm / (r_s + c.r_divider_ohm)

    def counts(self, v) -> np.ndarray:
        """Noise-free ADC reading (float DN, not rounded) of voltages ``v``."""
        return np.asarray(v, dtype=float) / self.config.v_plus * self.full_scale

    def drift_gain(self, rng: np.random.Generator) -> float:
        r"""A recording's sensitivity drift factor :math:`e^{\sigma_d z}` (``drift_gain_spread``).

        Exactly 1 (and nothing drawn) when the spread is 0.
        """
        s = self.config.drift_gain_spread
        return float(np.exp(s * rng.standard_normal())) if s else 1.0

    def frames(self, scenario: Scenario, *, seed: int | None = None, gain: float | None = None) -> np.ndarray:
        """ADC counts (T, rows, cols), uint8 DN (uint16 for ``adc_bits`` > 8), for ``scenario``.

        Parameters
        ----------
        scenario : Scenario
            See :meth:`contact`.
        seed : int, optional
            Seed of the noise (and of the drift gain); the same seed gives the same frames.
        gain : float, optional
            This recording's sensitivity drift factor; None: drawn from the
            seed's generator before the noise (:meth:`drift_gain`; 1 without drift).

        Raises
        ------
        TypeError
            If ``scenario`` is not a Scenario.
        InputError
            For an unsupported indenter, ``extra`` keys or an unreachable force.
        """
        rng = noise_rng(seed)
        state = self.contact(scenario)
        if gain is None:
            gain = self.drift_gain(rng)
        v = self.voltage(state["taxel_kpa"], scenario.t_s, gain=gain)
        v = v + self.config.noise_v * rng.standard_normal(v.shape)
        dtype = np.uint8 if self.config.adc_bits <= 8 else np.uint16
        return np.clip(np.rint(self.counts(v)), 0, self.full_scale).astype(dtype)


Thread8.register()
