"""8×8 piezoresistive thread-electrode array: palpation classification (source ``"thread8"``).

Sixty-four taxels at 2.5 mm pitch sit on a 20×20 mm piezoresistive patch
whose rows and columns are conductive threads; the electronics scan row by
row and read every crossing through a voltage divider with an 8-bit ADC at
100 frames/s. Pressing the patch lowers the crossing's resistance from
megaohms (free) to about 0.5 kΩ, so the divider voltage rises. This module
simulates the array (:class:`Thread8`, registered as ``"thread8"``) and the
palpation study that recognises grasped objects by their stiffness,
elasticity/plasticity and size:

1. an object catalogue (:data:`OBJECTS`, rigid block ... soft ball) and a
   gripper protocol (:class:`GraspProtocol`: close until contact, squeeze
   five 1 mm steps, release five steps) with one array on each jaw
   (:func:`grasp`, :func:`palpation_dataset`);
2. per frame the mean μ and standard deviation σ of the 64 taxels
   (:func:`frame_features`) → one time series per grasp and jaw;
3. dynamic time warping distances with the C core of ``dtaidistance``
   (:func:`dtw_distance`, :func:`dtw_matrix`), each metric normalised by its
   largest pairwise distance, for μ, σ or both and the left, right or both
   jaws (:func:`palpation_distances`);
4. k-NN (k = 1, 3, 5) on the precomputed distances, stratified 10-fold cross
   validation with equal class shares per fold, mean recognition rate and a
   95 % t-interval over the folds (:func:`cv_folds`, :func:`knn_cv`,
   :func:`classify`);
5. the whole study and its figure: :func:`experiment`, :func:`plot_experiment`.

Convention: taxel indices are ``(row, col)``, ``(0, 0)`` top-left; the layout
frame has x along columns and y along rows (mm), origin at the patch centre
(:mod:`optitact.sources`), seen from the grasped object. The right jaw faces
the left one, so an object at ``x`` on the left patch sits at ``-x`` on the
right patch.

Examples
--------
>>> from optitact.sources import make_source
>>> src = make_source("thread8")
>>> src.layout.shape, src.layout.units, src.layout.rate_hz
((8, 8), 'DN', 100.0)
>>> [o.name for o in OBJECTS][:2]
['rigid block', 'rigid cylinder']
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from .._validate import finite, integer, positive, real_array, seed_value
from ..errors import InputError, ShapeError
from ..sources import Indenter, Layout, Scenario
from .base import TaxelSource, fraction, noise_rng, unit_gains
from .indenter import surface_height

__all__ = [
    "Thread8Config", "Thread8", "SUPPORTED_SHAPES", "PalpationObject", "OBJECTS", "GraspProtocol",
    "Grasp", "grasp", "PalpationDataset", "palpation_dataset", "frame_features", "dtw_distance",
    "dtw_matrix", "FEATURES", "SENSORS", "palpation_distances", "cv_folds", "knn_cv", "classify",
    "experiment", "plot_experiment",
]

#: Indenter shapes :class:`Thread8` simulates.
SUPPORTED_SHAPES = ("sphere", "cylinder", "box", "flat")
#: Feature sets of the distance metrics: μ alone, σ alone, both (2-D DTW).
FEATURES = ("mu", "sigma", "mu+sigma")
#: Jaws of the distance metrics: left, right, both (sum of the normalised per-jaw distances).
SENSORS = ("left", "right", "both")


# ==== the sensor ========================================================================================
@dataclass(frozen=True)
class Thread8Config:
    """The 8×8 piezoresistive thread-electrode array on a gripper jaw.

    Every field states its unit. Per-taxel sensitivities are drawn once from
    ``unit_seed``, so one config describes one physical sensor; noise is drawn
    from the ``seed`` of each :meth:`Thread8.frames` call. The patch side is
    ``rows * pitch_mm`` (20 mm by default).
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
        for name in ("sensitivity_spread", "noise_v"):
            positive(getattr(self, name), name, allow_zero=True)
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
    bits) DN (``layout.units == "DN"``). The row/column scan is treated as
    simultaneous within a frame; crosstalk between threads is not modelled.
    """

    name = "thread8"
    config_type = Thread8Config
    shapes = SUPPORTED_SHAPES

    def __init__(self, config: Thread8Config | None = None) -> None:
        super().__init__(config)

    def _setup(self, c: Thread8Config) -> None:
        rng = np.random.default_rng(c.unit_seed)
        self.sensitivity = unit_gains(rng, (c.rows, c.cols), c.sensitivity_spread)
        self._sub = int(round(c.pitch_mm / c.grid_mm))
        ny, nx = c.rows * self._sub, c.cols * self._sub
        gy = (np.arange(ny) - (ny - 1) / 2) * c.grid_mm
        gx = (np.arange(nx) - (nx - 1) / 2) * c.grid_mm
        yy, xx = np.meshgrid(gy, gx, indexing="ij")
        self._gx, self._gy = xx.ravel(), yy.ravel()
        iy, ix = np.meshgrid(np.arange(ny) // self._sub, np.arange(nx) // self._sub, indexing="ij")
        self._gy_cell, self._gx_cell = iy.ravel(), ix.ravel()
        self._cell_area = c.grid_mm ** 2

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
    def _heights(self, ind: Indenter, x, y, ang) -> np.ndarray:
        """Object surface above its crest on the grid, (n, N) mm (inf where it cannot touch)."""
        return surface_height(ind, self._gx, self._gy, x, y, ang)

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
        return self.check_scenario(scenario)[0]

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
            h = self._heights(ind, sx[:1], sy[:1], sa[:1])[0]
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
                h = self._heights(ind, sx[idx], sy[idx], sa[idx])
                u = np.clip(depth[idx, None] - h, 0.0, None)
                umax = np.maximum(prev[None, :], np.maximum.accumulate(u, axis=0))
                store(idx, self._pressure(u, umax, k, r))
                prev = umax[-1]
        else:
            from scipy.optimize import brentq

            depth = np.zeros(n_t)
            for i, f in enumerate(scenario.force_n):
                h = self._heights(ind, sx[i:i + 1], sy[i:i + 1], sa[i:i + 1])[0]

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
        return {"frame": np.arange(n_t), "depth_mm": depth, "force_n": force, "peak_kpa": peak,
                "taxel_kpa": taxel}

    # ---- response --------------------------------------------------------------------------------
    def resistance_ohm(self, pressure_kpa, *, sensitivity=1.0) -> np.ndarray:
        """Static crossing resistance (Ω) at effective pressure ``pressure_kpa`` (no hysteresis or creep).

        Parameters
        ----------
        pressure_kpa : float or array
            Effective pressure, kPa (>= 0).
        sensitivity : float or array
            Per-taxel sensitivity factor :math:`s_i` (1 = nominal); broadcast with ``pressure_kpa``.

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
        excess = w * np.logaddexp(0.0, (p - c.threshold_kpa) / w)
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

    def voltage(self, taxel_kpa, t_s=None) -> np.ndarray:
        """Noise-free divider voltage (T, rows, cols), V, for taxel pressures in time order.

        See :meth:`effective_kpa` for the parameters and the class Notes for the model.
        """
        r_s = self.resistance_ohm(self.effective_kpa(taxel_kpa, t_s), sensitivity=self.sensitivity)
        c = self.config
        return c.v_plus * c.r_divider_ohm / (r_s + c.r_divider_ohm)

    def counts(self, v) -> np.ndarray:
        """Noise-free ADC reading (float DN, not rounded) of voltages ``v``."""
        return np.asarray(v, dtype=float) / self.config.v_plus * self.full_scale

    def frames(self, scenario: Scenario, *, seed: int | None = None) -> np.ndarray:
        """ADC counts (T, rows, cols), uint8 DN (uint16 for ``adc_bits`` > 8), for ``scenario``.

        Parameters
        ----------
        scenario : Scenario
            See :meth:`contact`.
        seed : int, optional
            Seed of the noise; the same seed gives the same frames.

        Raises
        ------
        TypeError
            If ``scenario`` is not a Scenario.
        InputError
            For an unsupported indenter, ``extra`` keys or an unreachable force.
        """
        rng = noise_rng(seed)
        state = self.contact(scenario)
        v = self.voltage(state["taxel_kpa"], scenario.t_s)
        v = v + self.config.noise_v * rng.standard_normal(v.shape)
        dtype = np.uint8 if self.config.adc_bits <= 8 else np.uint16
        return np.clip(np.rint(self.counts(v)), 0, self.full_scale).astype(dtype)


# ==== objects and grasps ================================================================================
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

    def __post_init__(self) -> None:
        for name in ("close_speed_mm_s", "contact_dn", "step_mm", "step_speed_mm_s"):
            positive(getattr(self, name), name)
        for name in ("hold_s", "offset_mm"):
            positive(getattr(self, name), name, allow_zero=True)
        integer(self.n_steps, "n_steps", minimum=1)
        fraction(self.max_precontact, "max_precontact")
        arr = real_array(self.clearance_mm, "clearance_mm")
        if arr.shape != (2,) or not np.all(np.isfinite(arr)) or not 0 < arr[0] <= arr[1]:
            raise InputError(f"clearance_mm must be (low, high) with 0 < low <= high, "
                             f"got {self.clearance_mm!r}")
        object.__setattr__(self, "clearance_mm", (float(arr[0]), float(arr[1])))

    def step_profile(self, rate_hz: float) -> np.ndarray:
        """Gap reduction (mm) after contact for the squeeze and release phases, one value per frame."""
        n_move = max(1, int(round(self.step_mm / self.step_speed_mm_s * rate_hz)))
        n_hold = int(round(self.hold_s * rate_hz))
        step = np.concatenate([np.arange(1, n_move + 1) / n_move, np.ones(n_hold)]) * self.step_mm
        up = [i * self.step_mm + step for i in range(self.n_steps)]
        down = [(self.n_steps - i) * self.step_mm - step for i in range(self.n_steps)]
        return np.concatenate(up + down)


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
        Frame at which the gripper detected contact and started the squeeze steps.
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


def _jaws(sensors) -> tuple[Thread8, Thread8]:
    if sensors is None:
        return Thread8(Thread8Config(unit_seed=0)), Thread8(Thread8Config(unit_seed=1))
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
        Seeds the pose (offset on the patch, axis angle, initial clearance) and both jaws' noise.
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
    left, right = _jaws(sensors)
    seed = seed_value(seed)
    ss = np.random.SeedSequence(seed)
    s_pose, s_left, s_right = ss.spawn(3)
    rng = np.random.default_rng(s_pose)
    x, y = rng.uniform(-protocol.offset_mm, protocol.offset_mm, size=2) if protocol.offset_mm else (0.0, 0.0)
    angle = float(rng.uniform(0.0, math.pi))
    clearance = float(rng.uniform(*protocol.clearance_mm))
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
        for src, px, pa in poses:
            sc = Scenario(ind, t_part, x_mm=px, y_mm=y, angle_rad=pa, depth_mm=ramp[part])
            dn = src.counts(src.voltage(src.contact(sc)["taxel_kpa"], t_part))
            free = src.counts(src.voltage(np.zeros((1, *src.layout.shape))))[0]
            detected |= (dn - free).reshape(t_part.size, -1).max(axis=1) >= protocol.contact_dn
        if detected.any():
            k_contact = start + int(np.argmax(detected))
            break
    depth = np.concatenate([ramp[:k_contact + 1], ramp[k_contact] + protocol.step_profile(rate) / 2.0])
    t = np.arange(depth.size) / rate
    out = []
    for (src, px, pa), s_noise in zip(poses, (s_left, s_right), strict=True):
        sc = Scenario(ind, t, x_mm=px, y_mm=y, angle_rad=pa, depth_mm=depth)
        out.append(src.frames(sc, seed=int(s_noise.generate_state(1)[0])))
    return Grasp(out[0], out[1], t, depth, k_contact, float(x), float(y), angle)


@dataclass(frozen=True, eq=False)
class PalpationDataset:
    """Grasps of several objects: frames of both jaws per grasp, labels and poses.

    Attributes
    ----------
    names : tuple of str
        Object names; label ``i`` is ``names[i]``.
    labels : (n,) int
    left, right : tuple of (T_i, rows, cols) uint8 arrays
        Frames of each grasp (lengths differ between grasps).
    contact_frame, x_mm, y_mm, angle_rad : (n,) arrays
        Per grasp, see :class:`Grasp`.
    """

    names: tuple[str, ...]
    labels: np.ndarray
    left: tuple[np.ndarray, ...]
    right: tuple[np.ndarray, ...]
    contact_frame: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    angle_rad: np.ndarray

    def __len__(self) -> int:
        return int(self.labels.size)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Table-shaped summary, one row per grasp (frames excluded)."""
        return {"grasp": np.arange(len(self)), "label": self.labels,
                "object": np.array([self.names[i] for i in self.labels]),
                "n_frames": np.array([f.shape[0] for f in self.left]), "contact_frame": self.contact_frame,
                "x_mm": self.x_mm, "y_mm": self.y_mm, "angle_rad": self.angle_rad}

    def features(self, sensor: str) -> list[np.ndarray]:
        """Per grasp the (T_i, 2) series of frame mean μ and standard deviation σ, DN, of ``sensor``."""
        if sensor not in ("left", "right"):
            raise InputError(f"sensor must be 'left' or 'right', got {sensor!r}")
        return [_mu_sigma(f) for f in getattr(self, sensor)]


def palpation_dataset(*, n_per_object: int = 10, seed: int | None = 0,
                      objects: tuple[PalpationObject, ...] | None = None,
                      protocol: GraspProtocol | None = None, sensors: tuple[Thread8, Thread8] | None = None,
                      progress: bool = False) -> PalpationDataset:
    """Simulate ``n_per_object`` grasps of each object, each with its own random pose and noise.

    Parameters
    ----------
    n_per_object : int
        Grasps per object (>= 1).
    seed : int, optional
        Seeds every grasp (grasp ``i`` gets the ``i``-th child of ``SeedSequence(seed)``).
    objects : sequence of PalpationObject, optional
        Default :data:`OBJECTS`.
    protocol, sensors
        See :func:`grasp`.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    PalpationDataset
        Grasps ordered object by object.
    """
    from tqdm import tqdm

    n_per_object = integer(n_per_object, "n_per_object", minimum=1)
    seed = seed_value(seed)
    objects = OBJECTS if objects is None else tuple(objects)
    if not objects or not all(isinstance(o, PalpationObject) for o in objects):
        raise TypeError("objects must be a non-empty sequence of PalpationObject")
    names = tuple(o.name for o in objects)
    if len(set(names)) != len(names):
        raise InputError(f"object names must be unique, got {list(names)}")
    sensors = _jaws(sensors)
    labels = np.repeat(np.arange(len(objects)), n_per_object)
    children = np.random.SeedSequence(seed).spawn(labels.size)
    grasps = [grasp(objects[lab], seed=int(s.generate_state(1)[0]), protocol=protocol, sensors=sensors)
              for lab, s in zip(tqdm(labels, desc="thread8 grasps", file=sys.stderr, disable=not progress),
                                children, strict=True)]
    return PalpationDataset(
        names=names, labels=labels, left=tuple(g.left for g in grasps), right=tuple(g.right for g in grasps),
        contact_frame=np.array([g.contact_frame for g in grasps]), x_mm=np.array([g.x_mm for g in grasps]),
        y_mm=np.array([g.y_mm for g in grasps]), angle_rad=np.array([g.angle_rad for g in grasps]))


# ==== features and DTW ==================================================================================
@lru_cache(maxsize=1)
def _default_layout() -> Layout:
    return Thread8().layout


def _mu_sigma(arr: np.ndarray) -> np.ndarray:
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


def _series_list(series, name: str = "series") -> list[np.ndarray]:
    if isinstance(series, np.ndarray):
        series = list(series)
    if not isinstance(series, (list, tuple)):
        raise TypeError(f"{name} must be a sequence of 1-D or 2-D arrays, got {type(series).__name__}")
    out = []
    for i, s in enumerate(series):
        a = finite(real_array(s, f"{name}[{i}]"), f"{name}[{i}]")
        if a.ndim not in (1, 2) or a.shape[0] < 1 or (a.ndim == 2 and a.shape[1] < 1):
            raise ShapeError(f"{name}[{i}] must be a non-empty (T,) or (T, d) array, got shape {a.shape}")
        out.append(np.ascontiguousarray(a, dtype=np.float64))
    if len(out) >= 2:
        dims = {1 if a.ndim == 1 else a.shape[1] for a in out}
        kinds = {a.ndim for a in out}
        if len(dims) > 1 or len(kinds) > 1:
            raise ShapeError(f"{name} must all be (T,) or all (T, d) with the same d, got shapes "
                             f"{sorted({a.shape[1:] for a in out})}")
    return out


def _window(window) -> int | None:
    return None if window is None else integer(window, "window", minimum=1)


def dtw_distance(a, b, *, window: int | None = None) -> float:
    r"""Dynamic time warping distance between two series (``dtaidistance``, C core).

    Parameters
    ----------
    a, b : (T,) or (T, d) array
        Series of any lengths; 2-D for several features per sample (same ``d``).
    window : int, optional
        Sakoe–Chiba band half width in samples; None for unconstrained warping.

    Returns
    -------
    float

    Notes
    -----
    :math:`D(a, b) = \sqrt{\min_\pi \sum_{(i, j) \in \pi} \lVert a_i - b_j \rVert^2}`
    over monotone, continuous warping paths :math:`\pi` from :math:`(0, 0)`
    to :math:`(n-1, m-1)`, i.e. the square root of the dynamic programme
    :math:`C_{ij} = \lVert a_i - b_j\rVert^2 + \min(C_{i-1,j}, C_{i,j-1}, C_{i-1,j-1})`.

    Examples
    --------
    >>> dtw_distance([0.0, 1.0, 2.0], [0.0, 0.0, 1.0, 2.0])
    0.0
    >>> dtw_distance([0.0, 0.0], [3.0, 4.0])
    5.0
    """
    from dtaidistance import dtw, dtw_ndim

    sa, sb = _series_list([a, b], "series (a, b)")
    w = _window(window)
    if sa.ndim == 1:
        return float(dtw.distance_fast(sa, sb, window=w))
    return float(dtw_ndim.distance_fast(sa, sb, window=w))


def dtw_matrix(series, *, window: int | None = None) -> np.ndarray:
    """Symmetric matrix of DTW distances between all pairs of ``series`` (``dtaidistance``, C, OpenMP).

    Parameters
    ----------
    series : sequence of (T_i,) or (T_i, d) arrays
        At least two series; lengths may differ, ``d`` may not.
    window : int, optional
        See :func:`dtw_distance`.

    Returns
    -------
    (n, n) float64
        Zero diagonal; entry ``(i, j)`` equals ``dtw_distance(series[i], series[j])``.
    """
    from dtaidistance import dtw, dtw_ndim
    from scipy.spatial.distance import squareform

    s = _series_list(series)
    if len(s) < 2:
        raise InputError(f"series must hold at least two series, got {len(s)}")
    w = _window(window)
    if s[0].ndim == 1:
        cond = dtw.distance_matrix_fast(s, compact=True, window=w)
    else:
        cond = dtw_ndim.distance_matrix_fast(s, compact=True, window=w)
    return squareform(np.asarray(cond, dtype=np.float64), checks=False)


def _normalised(d: np.ndarray) -> np.ndarray:
    top = d.max()
    return d / top if top > 0 else d.copy()


def palpation_distances(dataset: PalpationDataset, *, window: int | None = None,
                        progress: bool = False) -> dict[str, np.ndarray]:
    """The nine DTW distance metrics of the study, each normalised by its largest pairwise distance.

    Parameters
    ----------
    dataset : PalpationDataset
    window : int, optional
        See :func:`dtw_distance`.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    dict
        ``"{feature}/{sensor}"`` → (n, n) matrix with values in [0, 1], for
        ``feature`` in :data:`FEATURES` and ``sensor`` in :data:`SENSORS`.

    Notes
    -----
    ``mu`` and ``sigma`` use 1-D DTW on one feature; ``mu+sigma`` uses DTW on
    the 2-D series (μ, σ) with the squared Euclidean distance per sample pair.
    A jaw's matrix is divided by its largest entry; ``both`` jaws is the sum of
    the two normalised matrices, divided by its own largest entry. The
    normalisation uses every grasp of the dataset (as in the published study),
    before any cross-validation split.
    """
    from tqdm import tqdm

    if not isinstance(dataset, PalpationDataset):
        raise TypeError(f"dataset must be a PalpationDataset, got {type(dataset).__name__}")
    feats = {s: dataset.features(s) for s in ("left", "right")}
    columns = {"mu": 0, "sigma": 1, "mu+sigma": slice(0, 2)}
    out = {}
    bar = tqdm(total=len(FEATURES) * 2, desc="thread8 DTW", file=sys.stderr, disable=not progress)
    for feature in FEATURES:
        per = {}
        for sensor in ("left", "right"):
            per[sensor] = _normalised(dtw_matrix([f[:, columns[feature]] for f in feats[sensor]],
                                                 window=window))
            out[f"{feature}/{sensor}"] = per[sensor]
            bar.update()
        out[f"{feature}/both"] = _normalised(per["left"] + per["right"])
    bar.close()
    return {f"{f}/{s}": out[f"{f}/{s}"] for f in FEATURES for s in SENSORS}


# ==== classification ====================================================================================
def _labels(labels, n: int | None = None) -> np.ndarray:
    arr = np.asarray(labels)
    if arr.dtype.kind not in "iu":
        raise TypeError(f"labels must be an integer array, got dtype {arr.dtype}")
    if arr.ndim != 1 or (n is not None and arr.size != n):
        want = f"({n},)" if n is not None else "(n,)"
        raise ShapeError(f"labels must have shape {want}, got {arr.shape}")
    return arr


def cv_folds(labels, *, n_folds: int = 10, seed: int | None = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    """Stratified ``n_folds``-fold split with equal class shares per fold (shuffled with ``seed``).

    Parameters
    ----------
    labels : (n,) int array
    n_folds : int
        Number of folds (>= 2); every class needs at least ``n_folds`` samples.
    seed : int, optional
        Seed of the shuffle.

    Returns
    -------
    list of (train_index, test_index)
        Test folds are disjoint and cover every sample once; each holds
        ``count(class) // n_folds`` or one more of every class.

    Raises
    ------
    InputError
        If a class has fewer than ``n_folds`` samples.
    """
    from sklearn.model_selection import StratifiedKFold

    y = _labels(labels)
    n_folds = integer(n_folds, "n_folds", minimum=2)
    seed = seed_value(seed)
    classes, counts = np.unique(y, return_counts=True)
    if classes.size < 2:
        raise InputError(f"labels must hold at least two classes, got {classes.size}")
    if counts.min() < n_folds:
        raise InputError(f"every class needs at least n_folds = {n_folds} samples, got "
                         f"{int(counts.min())} for class {int(classes[np.argmin(counts)])}")
    skf = StratifiedKFold(n_splits=n_folds, shuffle=True, random_state=seed)
    return [(tr, te) for tr, te in skf.split(np.zeros((y.size, 1)), y)]


def _t_interval(rates: np.ndarray, level: float = 0.95) -> tuple[float, float, float]:
    from scipy.stats import t as student_t

    m = float(rates.mean())
    if rates.size < 2:
        return m, m, m
    half = float(student_t.ppf(0.5 + level / 2, rates.size - 1) * rates.std(ddof=1) / math.sqrt(rates.size))
    return m, max(0.0, m - half), min(1.0, m + half)


def knn_cv(distance, labels, *, ks=(1, 3, 5), n_folds: int = 10, seed: int | None = 0) -> dict[str, np.ndarray]:
    r"""k-NN recognition rate on a precomputed distance matrix, stratified k-fold cross validation.

    Parameters
    ----------
    distance : (n, n) array
        Symmetric, finite, non-negative distances between all samples.
    labels : (n,) int array
    ks : sequence of int
        Neighbour counts.
    n_folds : int
        Folds of :func:`cv_folds`.
    seed : int, optional
        Seed of the fold shuffle.

    Returns
    -------
    dict
        Table-shaped, one row per k: ``k``, ``mean`` (mean recognition rate over
        the folds), ``ci_low``, ``ci_high`` (95 % interval), ``std`` (over folds)
        and ``fold_rates`` ((n_k, n_folds)).

    Notes
    -----
    Each test sample gets the majority label of its ``k`` nearest training
    samples (scikit-learn ``KNeighborsClassifier(metric="precomputed")``, uniform
    weights; a tie goes to the smallest label). The interval is
    :math:`\bar r \pm t_{0.975,\,F-1}\, s/\sqrt F` over the :math:`F` fold rates
    (Student t), clipped to [0, 1].

    Examples
    --------
    >>> import numpy as np
    >>> x = np.r_[np.zeros(4), np.ones(4)]
    >>> d = np.abs(x[:, None] - x[None, :])
    >>> knn_cv(d, np.repeat([0, 1], 4), ks=(1,), n_folds=2)["mean"]
    array([1.])
    """
    from sklearn.neighbors import KNeighborsClassifier

    d = finite(real_array(distance, "distance"), "distance")
    if d.ndim != 2 or d.shape[0] != d.shape[1]:
        raise ShapeError(f"distance must be a square (n, n) matrix, got shape {d.shape}")
    if np.any(d < 0):
        raise InputError(f"distance must be >= 0, got minimum {d.min()}")
    if not np.allclose(d, d.T, rtol=1e-9, atol=1e-12):
        raise InputError("distance must be symmetric")
    y = _labels(labels, d.shape[0])
    ks = [integer(k, "k", minimum=1) for k in np.atleast_1d(np.asarray(ks, dtype=object))]
    if not ks:
        raise InputError("ks must hold at least one k, got none")
    folds = cv_folds(y, n_folds=n_folds, seed=seed)
    min_train = min(tr.size for tr, _ in folds)
    if max(ks) > min_train:
        raise InputError(f"k must be <= the smallest training fold ({min_train} samples), got {max(ks)}")
    rates = np.empty((len(ks), len(folds)))
    for j, (tr, te) in enumerate(folds):
        for i, k in enumerate(ks):
            clf = KNeighborsClassifier(n_neighbors=k, metric="precomputed").fit(d[np.ix_(tr, tr)], y[tr])
            rates[i, j] = float(np.mean(clf.predict(d[np.ix_(te, tr)]) == y[te]))
    stats = np.array([_t_interval(r) for r in rates])
    return {"k": np.array(ks), "mean": stats[:, 0], "ci_low": stats[:, 1], "ci_high": stats[:, 2],
            "std": rates.std(axis=1, ddof=1), "fold_rates": rates}


def classify(distances: dict[str, np.ndarray], labels, *, ks=(1, 3, 5), n_folds: int = 10,
             seed: int | None = 0) -> dict[str, list]:
    """The study's table: :func:`knn_cv` for every metric of :func:`palpation_distances`.

    Parameters
    ----------
    distances : dict
        ``"{feature}/{sensor}"`` → (n, n) distance matrix.
    labels : (n,) int array
    ks, n_folds, seed
        See :func:`knn_cv`; every metric uses the same folds.

    Returns
    -------
    dict
        Table-shaped (lists, JSON-serialisable), one row per (metric, k):
        ``metric``, ``feature``, ``sensor``, ``k``, ``mean``, ``ci_low``,
        ``ci_high``, ``std``, ``fold_rates``.
    """
    if not isinstance(distances, dict) or not distances:
        raise TypeError("distances must be a non-empty dict of metric name -> (n, n) matrix")
    table: dict[str, list] = {key: [] for key in ("metric", "feature", "sensor", "k", "mean", "ci_low",
                                                  "ci_high", "std", "fold_rates")}
    for metric, d in distances.items():
        feature, _, sensor = str(metric).partition("/")
        res = knn_cv(d, labels, ks=ks, n_folds=n_folds, seed=seed)
        for i, k in enumerate(res["k"]):
            table["metric"].append(str(metric))
            table["feature"].append(feature)
            table["sensor"].append(sensor)
            table["k"].append(int(k))
            for key in ("mean", "ci_low", "ci_high", "std"):
                table[key].append(float(res[key][i]))
            table["fold_rates"].append([float(v) for v in res["fold_rates"][i]])
    return table


# ==== the study =========================================================================================
def _jsonable(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, tuple):
        return [_jsonable(v) for v in value]
    return value


def experiment(*, seed: int = 0, full: bool = False, progress: bool = True) -> dict:
    """The palpation study on simulated grasps: DTW distances, k-NN, cross validation.

    Parameters
    ----------
    seed : int
        Seeds the grasps and the fold shuffle.
    full : bool
        Full size (all ten :data:`OBJECTS` × 10 grasps, 10 folds) or small
        (4 objects × 5 grasps, 5 folds: a few seconds).
    progress : bool
        tqdm progress bars on stderr.

    Returns
    -------
    dict
        JSON-serialisable: ``seed``, ``full``, ``config`` (left jaw),
        ``protocol``, ``objects`` (catalogue rows used), ``n_per_object``,
        ``n_folds``, ``ks``, ``table`` (:func:`classify`), ``grasps``
        (:meth:`PalpationDataset.as_dict`), ``examples`` (μ and σ series of the
        first grasp of every object, left jaw), ``rate_hz``, ``chance`` and
        ``seconds``.
    """
    seed = seed_value(seed)
    if seed is None:
        raise InputError("experiment needs an integer seed, got None")
    t0 = time.perf_counter()
    if full:
        objects, n_per, n_folds = OBJECTS, 10, 10
    else:
        objects, n_per, n_folds = tuple(OBJECTS[i] for i in (0, 3, 6, 9)), 5, 5
    ks = (1, 3, 5)
    protocol = GraspProtocol()
    sensors = _jaws(None)
    s_data, s_cv = (int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(2))
    data = palpation_dataset(n_per_object=n_per, seed=s_data, objects=objects, protocol=protocol,
                             sensors=sensors, progress=progress)
    distances = palpation_distances(data, progress=progress)
    table = classify(distances, data.labels, ks=ks, n_folds=n_folds, seed=s_cv % 2 ** 31)
    feats = data.features("left")
    first = [int(np.flatnonzero(data.labels == i)[0]) for i in range(len(objects))]
    grasps = {k: v.tolist() for k, v in data.as_dict().items()}
    return {
        "seed": seed, "full": bool(full),
        "config": {k: _jsonable(v) for k, v in dataclasses.asdict(sensors[0].config).items()},
        "protocol": {k: _jsonable(v) for k, v in dataclasses.asdict(protocol).items()},
        "objects": [o.as_dict() for o in objects], "n_per_object": n_per, "n_folds": n_folds, "ks": list(ks),
        "chance": 1.0 / len(objects), "rate_hz": sensors[0].layout.rate_hz, "table": table, "grasps": grasps,
        "examples": {"object": [objects[i].name for i in range(len(objects))],
                     "mu": [feats[j][:, 0].tolist() for j in first],
                     "sigma": [feats[j][:, 1].tolist() for j in first],
                     "contact_frame": [int(data.contact_frame[j]) for j in first]},
        "seconds": time.perf_counter() - t0,
    }


def plot_experiment(result: dict, path) -> None:
    """Save a PNG of :func:`experiment`'s result: μ and σ series per object and the recognition table.

    Parameters
    ----------
    result : dict
        As returned by :func:`experiment` (or read back from its JSON).
    path : str or path-like
        Output PNG file.
    """
    from matplotlib.figure import Figure

    try:
        ex, table, rate = result["examples"], result["table"], float(result["rate_hz"])
        names, mus, sigmas = ex["object"], ex["mu"], ex["sigma"]
        metrics = list(dict.fromkeys(table["metric"]))
        ks = sorted(set(table["k"]))
    except (KeyError, TypeError) as exc:
        raise InputError(f"result must be a dict returned by experiment(), missing {exc}") from exc
    fig = Figure(figsize=(15, 9), layout="constrained")
    grid = fig.add_gridspec(2, 2)
    colours = [f"C{i}" for i in range(10)]
    for col, (series, label) in enumerate(((mus, "frame mean μ, DN"), (sigmas, "frame std σ, DN"))):
        ax = fig.add_subplot(grid[0, col])
        for i, (name, s) in enumerate(zip(names, series, strict=True)):
            s = np.asarray(s)
            ax.plot(np.arange(s.size) / rate, s, color=colours[i % 10], lw=1.2, label=name)
        ax.set_xlabel("time, s")
        ax.set_ylabel(label)
        ax.set_title(f"{label.split(',')[0]} (left jaw, first grasp of each object)")
        if col == 0:
            ax.legend(fontsize=7, ncol=2)
    ax = fig.add_subplot(grid[1, :])
    width = 0.8 / len(ks)
    pos = np.arange(len(metrics))
    for j, k in enumerate(ks):
        rows = [next(i for i, (m, kk) in enumerate(zip(table["metric"], table["k"], strict=True))
                     if m == metric and kk == k) for metric in metrics]
        mean = np.array([table["mean"][i] for i in rows])
        lo = mean - np.array([table["ci_low"][i] for i in rows])
        hi = np.array([table["ci_high"][i] for i in rows]) - mean
        ax.bar(pos + (j - (len(ks) - 1) / 2) * width, 100 * mean, width, yerr=100 * np.vstack([lo, hi]),
               capsize=2, label=f"k = {k}", color=f"C{j}")
    if "chance" in result:
        ax.axhline(100 * result["chance"], color="grey", ls="--", lw=1, label="chance")
    ax.set_xticks(pos, metrics, rotation=20, fontsize=8)
    ax.set_ylim(0, 105)
    ax.set_ylabel("recognition rate, % (mean, 95 % CI over folds)")
    ax.set_title("k-NN on normalised DTW distances, stratified cross validation")
    ax.legend(fontsize=8, loc="lower right")
    fig.suptitle(f"thread8 palpation study (seed {result.get('seed')}, full={result.get('full')}, "
                 f"{result.get('n_per_object')} grasps per object)")
    fig.savefig(path, dpi=110)


Thread8.register()
