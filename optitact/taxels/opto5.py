"""5×5 optoelectronic taxel pad (source ``"opto5"``): the sensor model and its grasp scenarios.

Twenty-five photo-reflector taxels (an infrared LED and a phototransistor
each) sit under a silicone pad on a gripper finger: 3.55 mm pitch, 21×21 mm
sensing area, 12-bit ADC, 500 Hz. Pressing the pad moves its reflective
underside towards a taxel and raises the taxel's voltage. The reflective
surfaces are handmade, so every taxel has its own gain and its own non-linear
response shape; the fingers also flex, so a flat grasp does not load the pad
evenly. This module simulates the pad (:class:`Opto5`, registered as
``"opto5"``); the processing chain of the wire-handling study (offset removal,
normalisation, wire shape, lookup-table diameter) is :mod:`optitact.taxels.wire`,
the study itself ``optitact.studies.run("wire")``.

Convention: taxel indices are ``(row, col)``, ``(0, 0)`` top-left; the
layout frame has x along columns and y along rows (mm), origin at the pad
centre (:mod:`optitact.taxels.sources`). Row 0 lies towards the fingertip, row 4
towards the palm. Finger distance is the gripper's own 8-bit encoder value:
0 = fully open, 255 = fully closed (pads touching), larger = closed tighter.

Examples
--------
>>> src = Opto5()
>>> float(src.gap_mm(255)), src.layout.shape
(0.0, (5, 5))
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from optitact._validate import finite, integer, positive, real_array
from optitact.errors import InputError, ShapeError
from optitact.taxels.sources import Indenter, Layout, Scenario
from optitact.taxels.base import TaxelSource, fraction, noise_rng, range_pair, unit_gains
from optitact.taxels.indenter import overlap, surface_height

__all__ = ["Opto5Config", "Opto5", "FINGER_DISTANCE_MAX", "SUPPORTED_SHAPES", "check_finger_distance",
           "grasp_scenario"]

#: Largest finger-distance encoder value (fully closed).
FINGER_DISTANCE_MAX = 255
#: Indenter shapes :class:`Opto5` simulates.
SUPPORTED_SHAPES = ("wire", "cylinder", "sphere", "flat")


@dataclass(frozen=True)
class Opto5Config:
    """The 5×5 optoelectronic taxel pad.

    Every field states its unit. Per-taxel gains, response shapes and dark
    offsets are drawn once from ``unit_seed``, so one config describes one
    physical sensor instance; noise and trial-to-trial scatter are drawn from
    the ``seed`` of each :meth:`Opto5.frames` call.
    """

    rows: int = 5                         # taxels along y (row 0 at the fingertip)
    cols: int = 5                         # taxels along x
    pitch_mm: float = 3.55                # mm, taxel centre spacing along rows and columns
    pad_mm: float = 21.0                  # mm, side of the square sensing area
    adc_bits: int = 12                    # bits of the ADC
    v_ref: float = 3.3                    # V, ADC full scale
    rate_hz: float = 500.0                # samples / s
    sensitivity_v_per_n: float = 0.018    # V/N, small-load slope of a unit-gain taxel (force on its cell)
    hysteresis: float = 0.05              # fraction of the peak response: widest unloading/loading gap
    repeatability: float = 0.03           # fraction, 1-sigma per-trial scatter of each taxel's gain
    gain_spread: float = 0.4              # 1-sigma of ln(gain) across taxels (unit_seed)
    shape_range: tuple[float, float] = (-0.5, 2.0)   # 1, range of the per-taxel shape k (unit_seed)
    offset_range_v: tuple[float, float] = (0.4, 1.2)  # V, range of the per-taxel dark offsets (unit_seed)
    unit_seed: int = 0                    # seed of this sensor instance's gains, shapes and offsets
    force_ref_n: float = 4.0              # N, cell force at which the response shape is evaluated (u = 1)
    pad_modulus_mpa: float = 0.5          # MPa = N/mm², silicone modulus (Winkler foundation)
    pad_thickness_mm: float = 3.0         # mm, silicone thickness
    spot_sigma_mm: float = 1.3            # mm, 1-sigma of the Gaussian pad footprint each taxel sees
    flex: float = 0.2                     # fraction of compression lost at the fingertip edge (finger flex)
    noise_v: float = 0.001                # V, 1-sigma white noise of every sample
    gap_open_mm: float = 8.0              # mm, pad-to-pad gap at finger distance 0 (0 mm at 255)
    pad_share: float = 0.5                # fraction of the squeeze taken by this pad (the rest: opposite pad)
    grid_mm: float = 0.25                 # mm, contact integration grid

    def __post_init__(self) -> None:
        integer(self.rows, "rows", minimum=3)
        integer(self.cols, "cols", minimum=3)
        integer(self.adc_bits, "adc_bits", minimum=1)
        integer(self.unit_seed, "unit_seed", minimum=0)
        for name in ("pitch_mm", "pad_mm", "v_ref", "rate_hz", "sensitivity_v_per_n", "force_ref_n",
                     "pad_modulus_mpa", "pad_thickness_mm", "spot_sigma_mm", "gap_open_mm", "grid_mm",
                     "pad_share"):
            positive(getattr(self, name), name)
        for name in ("hysteresis", "repeatability", "gain_spread", "noise_v"):
            positive(getattr(self, name), name, allow_zero=True)
        fraction(self.hysteresis, "hysteresis", upper=0.5)
        fraction(self.repeatability, "repeatability", upper=0.3)
        fraction(self.flex, "flex")
        if self.pad_share > 1:
            raise InputError(f"pad_share must be in (0, 1], got {self.pad_share!r}")
        object.__setattr__(self, "shape_range", range_pair(self.shape_range, "shape_range"))
        object.__setattr__(self, "offset_range_v", range_pair(self.offset_range_v, "offset_range_v"))
        if self.offset_range_v[0] < 0 or self.offset_range_v[1] >= self.v_ref:
            raise InputError(f"offset_range_v must lie in [0, v_ref={self.v_ref}), got {self.offset_range_v}")
        span = (max(self.rows, self.cols) - 1) * self.pitch_mm
        if self.pad_mm < span:
            raise InputError(f"pad_mm must cover the taxel grid (>= {span:g} mm), got {self.pad_mm!r}")
        if self.grid_mm > self.pitch_mm / 4:
            raise InputError(f"grid_mm must be <= pitch_mm / 4 = {self.pitch_mm / 4:g}, got {self.grid_mm!r}")


def _response_shape(u: np.ndarray, k: np.ndarray) -> np.ndarray:
    """phi_k(u) = (1 - exp(-k u)) / k, phi_0(u) = u: slope 1 at 0, saturating (k > 0) or expansive (k < 0)."""
    small = np.abs(k) < 1e-9
    ks = np.where(small, 1.0, k)
    return np.where(small, u, -np.expm1(-ks * u) / ks)


class Opto5(TaxelSource):
    r"""Simulated 5×5 optoelectronic taxel pad (source ``"opto5"``).

    Parameters
    ----------
    config : Opto5Config, optional
        The sensor instance; defaults to ``Opto5Config()``.

    Notes
    -----
    Contact: the pad is a Winkler foundation. An indenter pressed to depth
    :math:`D` (the compression at its crest) compresses the pad by
    :math:`\delta(x, y) = \max(0, D - h(x, y))`, where :math:`h` is the
    indenter's surface height above its crest (a wire of radius :math:`R` at
    distance :math:`r` from its axis: :math:`h = R - \sqrt{R^2 - r^2}`,
    :math:`h = R` beyond; a flat: :math:`h = 0`). The finger flexes, so the
    compression falls linearly towards the fingertip:
    :math:`\delta' = \delta\,(1 - f\,\hat y)`, :math:`\hat y = 1/2 - y/L`
    (0 at the palm edge, 1 at the fingertip edge, :math:`f` = ``flex``).
    Pressure is :math:`E\,\delta'/t`; the total normal force is its integral
    over the pad, which is how ``force_n`` scenarios are solved for :math:`D`.

    Taxels: taxel :math:`i` sees the Gaussian-weighted mean compression
    :math:`\bar\delta_i` under its spot (``spot_sigma_mm``), i.e. a cell
    force :math:`F_i = (E p^2 / t)\,\bar\delta_i`. Its voltage change is
    :math:`\Delta v_i = g_i\,s\,F_{ref}\,\phi_{k_i}(F_i/F_{ref})` with
    :math:`\phi_k(u) = (1 - e^{-k u})/k` (slope 1 at 0), gain :math:`g_i` and
    shape :math:`k_i` from ``unit_seed``. Hysteresis: while unloading from a
    peak :math:`F_p` the output is raised by
    :math:`h\,\Delta v(F_p)\,4q(1-q)`, :math:`q = F/F_p`. Each call draws
    a per-taxel gain factor :math:`1 + \rho z` (repeatability :math:`\rho`)
    and white noise; the sum with the dark offset is quantised by the ADC.
    Frames are in volts on the ADC's LSB grid (``layout.units == "V"``).

    Finger distance :math:`p` (0 open ... 255 closed) maps to the pad-to-pad
    gap :math:`g(p) = g_0 (1 - p/255)`; an object of thickness :math:`d` (a
    wire's diameter) is squeezed by :math:`\max(0, d - g)`, of which this pad
    takes the share ``pad_share`` as its crest depth :math:`D`
    (:meth:`depth_from_finger_distance`).

    Indenter ``stiffness_n_per_mm`` and ``plasticity`` are not modelled (rigid
    objects). ``Scenario.extra["curvature_per_mm"]`` (float or (T,)) bends a
    wire's axis: in the wire's own frame (s along ``angle_rad``, n to its left)
    the axis is :math:`n = \kappa s^2 / 2` through ``(x_mm, y_mm)``.
    """

    name = "opto5"
    config_type = Opto5Config
    shapes = SUPPORTED_SHAPES
    extra = {"curvature_per_mm": 0.0}

    def _setup(self, config: Opto5Config) -> None:
        shape = (config.rows, config.cols)
        rng = np.random.default_rng(config.unit_seed)
        self.gain = unit_gains(rng, shape, config.gain_spread)
        self.shape_k = rng.uniform(*config.shape_range, size=shape)
        self.offset_v = rng.uniform(*config.offset_range_v, size=shape)
        for arr in (self.shape_k, self.offset_v):
            arr.setflags(write=False)
        n = int(round(config.pad_mm / config.grid_mm))
        g = (np.arange(n) - (n - 1) / 2) * (config.pad_mm / n)
        self._n_grid = n
        gy, gx = np.meshgrid(g, g, indexing="ij")
        self._gx, self._gy = gx.ravel(), gy.ravel()
        self._cell_area = (config.pad_mm / n) ** 2
        self._flex = 1.0 - config.flex * (0.5 - self._gy / config.pad_mm)
        # Gaussian spots are separable: weights along y per row and along x per column, each summing to 1.
        x, y = self.layout.cell_xy()
        spots = []
        for centres in (y[:, 0], x[0]):
            w = np.exp(-(g[None, :] - centres[:, None]) ** 2 / (2 * config.spot_sigma_mm ** 2))
            spots.append(w / w.sum(axis=1, keepdims=True))
        self._spot_y, self._spot_x = spots                       # (rows, n), (cols, n)
        self._k_cell = config.pad_modulus_mpa * config.pitch_mm ** 2 / config.pad_thickness_mm  # N/mm
        self._k_area = config.pad_modulus_mpa / config.pad_thickness_mm                      # N/mm³

    @cached_property
    def layout(self) -> Layout:
        """5×5 grid, 3.55 mm pitch, values in volts, 500 Hz."""
        c = self.config
        return Layout(shape=(c.rows, c.cols), pitch_mm=(c.pitch_mm, c.pitch_mm), units="V", rate_hz=c.rate_hz)

    @property
    def lsb_v(self) -> float:
        """One ADC step, V."""
        return self.config.v_ref / (2 ** self.config.adc_bits - 1)

    # ---- finger distance -------------------------------------------------------------------------
    def gap_mm(self, finger_distance) -> np.ndarray:
        """Pad-to-pad gap (mm) at finger distance ``finger_distance`` (0 open ... 255 closed).

        Raises
        ------
        InputError
            For values outside [0, 255] or not finite.
        """
        p = check_finger_distance(finger_distance)
        return self.config.gap_open_mm * (1.0 - p / FINGER_DISTANCE_MAX)

    def depth_from_finger_distance(self, finger_distance, thickness_mm) -> np.ndarray:
        """Crest depth (mm) this pad is compressed by when the gripper closes to ``finger_distance``.

        Parameters
        ----------
        finger_distance : float or array
            Encoder value, 0 (open) ... 255 (closed).
        thickness_mm : float or array
            Thickness of the grasped object (a wire's diameter), mm; 0 for nothing.

        Returns
        -------
        ndarray
            ``pad_share * max(0, thickness_mm - gap_mm(finger_distance))``.
        """
        d = finite(real_array(thickness_mm, "thickness_mm"), "thickness_mm")
        if np.any(d < 0):
            raise InputError(f"thickness_mm must be >= 0, got minimum {d.min()}")
        return self.config.pad_share * np.clip(d - self.gap_mm(finger_distance), 0.0, None)

    def finger_distance_at_contact(self, thickness_mm: float) -> float:
        """Finger distance at which an object of ``thickness_mm`` starts to be squeezed (may be < 0)."""
        d = positive(thickness_mm, "thickness_mm", allow_zero=True)
        return FINGER_DISTANCE_MAX * (1.0 - d / self.config.gap_open_mm)

    # ---- contact ---------------------------------------------------------------------------------
    def _compression(self, ind: Indenter, x, y, ang, depth, kappa) -> np.ndarray:
        """Pad compression (n, n_grid) mm after finger flex, for n poses (:mod:`optitact.taxels.indenter`)."""
        h = surface_height(ind, self._gx, self._gy, x, y, ang, curvature_per_mm=kappa)
        return overlap(depth[:, None], h) * self._flex[None, :]

    def _pose(self, scenario: Scenario) -> tuple[Indenter, np.ndarray]:
        ind, extra = self.check_scenario(scenario)
        k = finite(real_array(extra["curvature_per_mm"], "curvature_per_mm"), "curvature_per_mm")
        if k.ndim == 0:
            k = np.full(scenario.n_frames, float(k))
        if k.shape != (scenario.n_frames,):
            raise ShapeError(f"curvature_per_mm must be a scalar or have shape ({scenario.n_frames},), "
                             f"got {k.shape}")
        return ind, k

    def _depths(self, scenario: Scenario, ind: Indenter, kappa: np.ndarray) -> np.ndarray:
        if scenario.depth_mm is not None:
            return np.asarray(scenario.depth_mm, dtype=float)
        from scipy.optimize import brentq

        depth = np.zeros(scenario.n_frames)
        for i, f in enumerate(scenario.force_n):
            if f == 0:
                continue

            def excess(d, i=i, f=f):
                return self._total_force(ind, scenario, i, d, kappa) - f

            hi = 1.0
            while excess(hi) < 0:
                hi *= 2.0
                if hi > 1e4:
                    raise InputError(f"force_n[{i}] = {f} N cannot be reached by this indenter on the pad")
            depth[i] = brentq(excess, 0.0, hi, xtol=1e-9, rtol=1e-10)
        return depth

    def _total_force(self, ind: Indenter, sc: Scenario, i: int, depth: float, kappa: np.ndarray) -> float:
        sl = slice(i, i + 1)
        delta = self._compression(ind, sc.x_mm[sl], sc.y_mm[sl], sc.angle_rad[sl], np.array([depth]), kappa[sl])
        return float(delta.sum() * self._cell_area * self._k_area)

    def contact(self, scenario: Scenario) -> dict[str, np.ndarray]:
        """Noise-free contact state per sample.

        Returns
        -------
        dict
            Table-shaped, one row per sample: ``frame``, ``depth_mm`` (crest
            depth), ``force_n`` (total normal force), ``taxel_force_n``
            ((T, 5, 5) cell forces, N).
        """
        ind, kappa = self._pose(scenario)
        depth = self._depths(scenario, ind, kappa)
        t = scenario.n_frames
        cells = np.zeros((t, self._spot_y.shape[0] * self._spot_x.shape[0]))
        total = np.zeros(t)
        active = np.flatnonzero(depth > 0)
        for start in range(0, active.size, 128):
            idx = active[start:start + 128]
            delta = self._compression(ind, scenario.x_mm[idx], scenario.y_mm[idx], scenario.angle_rad[idx],
                                      depth[idx], kappa[idx])
            grid = delta.reshape(idx.size, self._n_grid, self._n_grid)
            # einsum in two separable steps (no BLAS threads: these products are small)
            along_x = np.einsum("nij,cj->nic", grid, self._spot_x)
            cells[idx] = self._k_cell * np.einsum("nic,ri->nrc", along_x, self._spot_y).reshape(idx.size, -1)
            total[idx] = delta.sum(axis=1) * self._cell_area * self._k_area
        return {"frame": np.arange(t), "depth_mm": depth, "force_n": total,
                "taxel_force_n": cells.reshape(t, *self.layout.shape)}

    def response_v(self, taxel_force_n) -> np.ndarray:
        """Noise-free voltage change Δv (T, 5, 5) of this sensor for cell forces (T, 5, 5) N, with hysteresis.

        Samples are taken in time order (hysteresis follows each taxel's running peak force).
        """
        f = self.layout.check_frames(taxel_force_n, "taxel_force_n")
        if np.any(f < 0):
            raise InputError(f"taxel_force_n must be >= 0, got minimum {f.min()}")
        c = self.config
        scale = self.gain * c.sensitivity_v_per_n * c.force_ref_n

        def dv(force):
            return scale * _response_shape(force / c.force_ref_n, self.shape_k)

        peak = np.maximum.accumulate(f, axis=0)
        q = np.divide(f, peak, out=np.ones_like(f), where=peak > 0)
        return dv(f) + c.hysteresis * dv(peak) * 4.0 * q * (1.0 - q)

    def frames(self, scenario: Scenario, *, seed: int | None = None) -> np.ndarray:
        """Taxel voltages (T, 5, 5), V, on the ADC's LSB grid, for ``scenario``.

        Parameters
        ----------
        scenario : Scenario
            Indenter ``wire``/``cylinder`` (``size_mm`` = radius), ``sphere`` or ``flat``;
            ``depth_mm`` (crest compression before finger flex) or ``force_n`` (total normal force).
        seed : int, optional
            Seed of this trial's noise and gain scatter; the same seed gives the same frames.

        Raises
        ------
        InputError
            For an unsupported indenter, unknown ``extra`` keys or an unreachable force.
        """
        rng = noise_rng(seed)
        c = self.config
        state = self.contact(scenario)
        dv = self.response_v(state["taxel_force_n"])
        dv = dv * (1.0 + c.repeatability * rng.standard_normal(self.layout.shape))
        v = self.offset_v + dv + c.noise_v * rng.standard_normal(dv.shape)
        top = 2 ** c.adc_bits - 1
        counts = np.clip(np.rint(v / c.v_ref * top), 0, top)
        return counts * self.lsb_v


def check_finger_distance(value, name: str = "finger_distance") -> np.ndarray:
    """``value`` as a float array of gripper encoder values, checked to lie in [0, 255] (0 open, 255 closed).

    Raises
    ------
    InputError
        For values outside [0, 255] or not finite.
    """
    p = finite(real_array(value, name), name)
    if p.size and (p.min() < 0 or p.max() > FINGER_DISTANCE_MAX):
        raise InputError(f"{name} must be in [0, {FINGER_DISTANCE_MAX}] (0 open, 255 closed), "
                         f"got range [{p.min():g}, {p.max():g}]")
    return p


def grasp_scenario(source: Opto5, indenter: Indenter, depth: float, *, n_base: int, n_ramp: int, n_hold: int,
                   x_mm: float = 0.0, y_mm: float = 0.0, angle_rad: float = 0.0,
                   curvature_per_mm: float = 0.0) -> Scenario:
    """A grasp: ``n_base`` unloaded samples, a ramp to crest ``depth`` (mm) over ``n_ramp``, ``n_hold`` held.

    The wire (or other indenter) pose is fixed; ``curvature_per_mm`` bends a
    wire's axis (``Scenario.extra``, see :class:`Opto5`). Samples are
    ``1 / rate_hz`` apart.
    """
    t = np.arange(n_base + n_ramp + n_hold) / source.config.rate_hz
    d = np.concatenate([np.zeros(n_base), np.linspace(0.0, depth, n_ramp + 1)[1:], np.full(n_hold, depth)])
    extra = {"curvature_per_mm": curvature_per_mm} if curvature_per_mm else {}
    return Scenario(indenter, t_s=t, x_mm=x_mm, y_mm=y_mm, angle_rad=angle_rad, depth_mm=d, extra=extra)


Opto5.register()
