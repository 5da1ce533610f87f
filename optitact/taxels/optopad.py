"""5×5 optoelectronic taxel pad: wire shape and diameter (source ``"opto5"``).

Twenty-five photo-reflector taxels (an infrared LED and a phototransistor
each) sit under a silicone pad on a gripper finger: 3.55 mm pitch, 21×21 mm
sensing area, 12-bit ADC, 500 Hz. Pressing the pad moves its reflective
underside towards a taxel and raises the taxel's voltage. The reflective
surfaces are handmade, so every taxel has its own gain and its own non-linear
response shape; the fingers also flex, so a flat grasp does not load the pad
evenly. This module simulates the pad (:class:`Opto5`, registered as
``"opto5"``) and implements the processing chain of the wire-handling study:

1. offset removal (:func:`remove_offset`),
2. per-taxel linearising normalisation from a calibration closure
   (:class:`NormalisationLUT`),
3. wire shape from the normalised image (:func:`wire_shape`),
4. wire diameter from ``(finger distance, 25 normalised values)`` with a 2-D
   lookup table (:class:`LookupTableClassifier`), an SVM with a second-order
   polynomial kernel (:func:`svm_classifier`) and a small neural network
   (:func:`mlp_classifier`) (:func:`classify_wires`),
5. the whole study with figures: :func:`experiment`, :func:`plot_experiment`.

Convention: taxel indices are ``(row, col)``, ``(0, 0)`` top-left; the
layout frame has x along columns and y along rows (mm), origin at the pad
centre (:mod:`optitact.sources`). Row 0 lies towards the fingertip, row 4
towards the palm. Finger distance is the gripper's own 8-bit encoder value:
0 = fully open, 255 = fully closed (pads touching), larger = closed tighter.

Examples
--------
>>> import numpy as np
>>> from optitact.taxels.optopad import LookupTableClassifier
>>> lut = LookupTableClassifier.from_table(
...     [218], [1.5, 2.0, 2.5, 3.0, 3.5, 4.0],
...     [[0.9518, 2.2716, 3.0802, 3.5735, 6.2054, 7.9888]])
>>> float(lut.predict(218, 3.2))
2.5
"""

from __future__ import annotations

import dataclasses
import math
import sys
import time
import warnings
from dataclasses import dataclass
from functools import cached_property
from typing import NamedTuple

import numpy as np

from .._validate import finite, integer, positive, real_array, seed_value
from ..errors import InputError, ShapeError
from ..sources import Indenter, Layout, Scenario, moments, register_source

__all__ = [
    "Opto5Config", "Opto5", "FINGER_DISTANCE_MAX", "WIRE_DIAMETERS_MM", "remove_offset",
    "NormalisationLUT", "calibration_closure", "WireShape", "wire_centroids", "wire_shape",
    "LookupTableClassifier", "svm_classifier", "mlp_classifier", "WireDataset", "wire_dataset",
    "classify_wires", "shape_comparison", "experiment", "plot_experiment",
]

#: Largest finger-distance encoder value (fully closed).
FINGER_DISTANCE_MAX = 255
#: Wire diameters of the diameter study, mm (the no-wire class is diameter 0).
WIRE_DIAMETERS_MM = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0)
#: Indenter shapes :class:`Opto5` simulates.
SUPPORTED_SHAPES = ("wire", "cylinder", "sphere", "flat")


def _fraction(value, name: str, *, upper: float = 1.0) -> float:
    v = positive(value, name, allow_zero=True)
    if v >= upper:
        raise InputError(f"{name} must be in [0, {upper:g}), got {value!r}")
    return v


def _range_pair(value, name: str) -> tuple[float, float]:
    arr = real_array(value, name)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)) or arr[0] > arr[1]:
        raise InputError(f"{name} must be two finite numbers (low, high) with low <= high, got {value!r}")
    return float(arr[0]), float(arr[1])


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
        _fraction(self.hysteresis, "hysteresis", upper=0.5)
        _fraction(self.repeatability, "repeatability", upper=0.3)
        _fraction(self.flex, "flex")
        if self.pad_share > 1:
            raise InputError(f"pad_share must be in (0, 1], got {self.pad_share!r}")
        object.__setattr__(self, "shape_range", _range_pair(self.shape_range, "shape_range"))
        object.__setattr__(self, "offset_range_v", _range_pair(self.offset_range_v, "offset_range_v"))
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


class Opto5:
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

    def __init__(self, config: Opto5Config | None = None) -> None:
        if config is None:
            config = Opto5Config()
        if not isinstance(config, Opto5Config):
            raise TypeError(f"config must be an Opto5Config, got {type(config).__name__}")
        self.config = config
        shape = (config.rows, config.cols)
        rng = np.random.default_rng(config.unit_seed)
        self.gain = np.exp(config.gain_spread * rng.standard_normal(shape))
        self.shape_k = rng.uniform(*config.shape_range, size=shape)
        self.offset_v = rng.uniform(*config.offset_range_v, size=shape)
        for arr in (self.gain, self.shape_k, self.offset_v):
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
        p = _finger_distance(finger_distance)
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
    def _compression(self, shape: str, radius: float, length: float, x, y, ang, depth, kappa) -> np.ndarray:
        """Pad compression (n, n_grid) mm after finger flex, for n poses."""
        if shape == "flat":
            delta = np.broadcast_to(depth[:, None], (depth.size, self._gx.size))
        else:
            dx = self._gx[None, :] - x[:, None]
            dy = self._gy[None, :] - y[:, None]
            if shape == "sphere":
                r2 = dx * dx + dy * dy
                along = None
            else:
                c, s = np.cos(ang)[:, None], np.sin(ang)[:, None]
                along = dx * c + dy * s
                n = -dx * s + dy * c - 0.5 * kappa[:, None] * along * along
                r2 = n * n
            h = radius - np.sqrt(np.clip(radius * radius - r2, 0.0, None))
            delta = np.clip(depth[:, None] - h, 0.0, None)
            if along is not None and math.isfinite(length):
                delta = np.where(np.abs(along) <= length / 2, delta, 0.0)
        return delta * self._flex[None, :]

    def _pose(self, scenario: Scenario):
        if not isinstance(scenario, Scenario):
            raise TypeError(f"scenario must be a Scenario, got {type(scenario).__name__}")
        ind = scenario.indenter
        if ind.shape not in SUPPORTED_SHAPES:
            raise InputError(f"the opto5 source simulates indenters {SUPPORTED_SHAPES}, got {ind.shape!r}")
        extra = dict(scenario.extra)
        kappa = extra.pop("curvature_per_mm", 0.0)
        if extra:
            raise InputError(f"unknown Scenario.extra key(s) {sorted(extra)} for opto5; "
                             "valid: ['curvature_per_mm']")
        k = finite(real_array(kappa, "curvature_per_mm"), "curvature_per_mm")
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
        delta = self._compression(ind.shape, ind.size_mm, ind.length_mm, sc.x_mm[sl], sc.y_mm[sl],
                                  sc.angle_rad[sl], np.array([depth]), kappa[sl])
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
            delta = self._compression(ind.shape, ind.size_mm, ind.length_mm, scenario.x_mm[idx],
                                      scenario.y_mm[idx], scenario.angle_rad[idx], depth[idx], kappa[idx])
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
        seed = seed_value(seed)
        rng = np.random.default_rng(seed)
        c = self.config
        state = self.contact(scenario)
        dv = self.response_v(state["taxel_force_n"])
        dv = dv * (1.0 + c.repeatability * rng.standard_normal(self.layout.shape))
        v = self.offset_v + dv + c.noise_v * rng.standard_normal(dv.shape)
        top = 2 ** c.adc_bits - 1
        counts = np.clip(np.rint(v / c.v_ref * top), 0, top)
        return counts * self.lsb_v


def _finger_distance(value, name: str = "finger_distance") -> np.ndarray:
    p = finite(real_array(value, name), name)
    if p.size and (p.min() < 0 or p.max() > FINGER_DISTANCE_MAX):
        raise InputError(f"{name} must be in [0, {FINGER_DISTANCE_MAX}] (0 open, 255 closed), "
                         f"got range [{p.min():g}, {p.max():g}]")
    return p


def _float_out(arr: np.ndarray, like) -> np.ndarray:
    return arr.astype(np.float32) if np.asarray(like).dtype == np.float32 else arr


# ---- offset and normalisation ----------------------------------------------------------------------
def remove_offset(v, *, n: int = 50) -> np.ndarray:
    """Per-taxel offset removal: Δv = v − mean of the first ``n`` samples.

    Parameters
    ----------
    v : (T, ...) array
        Samples in time order (e.g. (T, 5, 5) volts); the first ``n`` are unloaded.
    n : int
        Number of leading samples that define the offset.

    Returns
    -------
    ndarray
        Δv, same shape; float64 (float32 if ``v`` is float32).

    Raises
    ------
    ShapeError
        If ``v`` has fewer than ``n`` samples along its first axis.

    Examples
    --------
    >>> import numpy as np
    >>> remove_offset(np.array([[1.0], [1.0], [1.5]]), n=2).ravel().tolist()
    [0.0, 0.0, 0.5]
    """
    n = integer(n, "n", minimum=1)
    arr = finite(real_array(v, "v"), "v")
    if arr.ndim < 1 or arr.shape[0] < n:
        raise ShapeError(f"v must have at least n={n} samples along axis 0, got shape {arr.shape}")
    return _float_out(arr - arr[:n].mean(axis=0), v)


@dataclass(frozen=True, eq=False)
class NormalisationLUT:
    """Per-taxel lookup tables Δv → normalised Δṽ that linearise and equalise the taxels.

    Build with :meth:`from_closure`. ``dv_knots[i]`` (strictly increasing, V)
    and ``value_knots[i]`` (normalised stimulus) are taxel ``i``'s table, taxels
    in row-major order; :meth:`apply` interpolates linearly and clamps outside
    the table.
    """

    shape: tuple[int, int]
    dv_knots: tuple[np.ndarray, ...]
    value_knots: tuple[np.ndarray, ...]

    @classmethod
    def from_closure(cls, dv_closure, stimulus, *, tol: float = 0.1) -> NormalisationLUT:
        r"""Tables from a calibration closure in which every taxel gets the same stimulus.

        Parameters
        ----------
        dv_closure : (T, H, W) array
            Offset-removed taxel responses during the closure (fingers closed
            slowly to the maximum on a flat object), V.
        stimulus : (T,) array
            The common stimulus at each sample, >= 0, 0 = unloaded (e.g. the
            crest depth in mm or the finger distance beyond contact). The
            normalised value of a sample is ``stimulus / stimulus.max()``.
        tol : float
            Largest accepted RMS deviation from a monotone response, as a
            fraction of the taxel's response range.

        Returns
        -------
        NormalisationLUT

        Raises
        ------
        ShapeError
            For mismatched shapes or fewer than 3 samples.
        InputError
            If the stimulus is negative or never positive, or a taxel does not
            respond (flat fitted response) or does not respond monotonically;
            the message names the taxel.

        Notes
        -----
        Each taxel's Δv is regressed on the normalised stimulus
        :math:`u = s / \max s` by isotonic (monotone non-decreasing)
        regression, which removes noise without assuming a shape. The table is
        the fitted Δv levels with, for each level, the mean :math:`u` of the
        samples on it; so the table inverts the taxel's own response and equally
        stimulated taxels map to the same :math:`u`.
        """
        from sklearn.isotonic import IsotonicRegression

        dv = finite(real_array(dv_closure, "dv_closure"), "dv_closure")
        if dv.ndim != 3 or dv.shape[0] < 3:
            raise ShapeError(f"dv_closure must have shape (T, H, W) with T >= 3, got {dv.shape}")
        s = finite(real_array(stimulus, "stimulus"), "stimulus")
        if s.shape != (dv.shape[0],):
            raise ShapeError(f"stimulus must have shape ({dv.shape[0]},) like dv_closure's T, got {s.shape}")
        if s.min() < 0 or s.max() <= 0:
            raise InputError(f"stimulus must be >= 0 with a positive maximum, got range [{s.min()}, {s.max()}]")
        tol = positive(tol, "tol")
        u = s / s.max()
        xs, ys = [], []
        for (r, c) in np.ndindex(dv.shape[1:]):
            y = dv[:, r, c]
            fit = IsotonicRegression(increasing=True).fit_transform(u, y)
            span = float(fit.max() - fit.min())
            rms = float(np.sqrt(np.mean((y - fit) ** 2)))
            if span <= 0:
                raise InputError(f"taxel ({r}, {c}) does not respond to the closure: its fitted increasing "
                                 f"response spans 0 V; expected Δv that grows with the stimulus")
            if rms > tol * span:
                raise InputError(f"taxel ({r}, {c}) responds non-monotonically to the closure: RMS deviation "
                                 f"{rms:.3g} V from a monotone fit exceeds tol={tol} x its range {span:.3g} V")
            levels, inverse = np.unique(fit, return_inverse=True)
            mean_u = np.bincount(inverse, weights=u) / np.bincount(inverse)
            xs.append(levels)
            ys.append(mean_u)
        for arr in (*xs, *ys):
            arr.setflags(write=False)
        return cls(shape=dv.shape[1:], dv_knots=tuple(xs), value_knots=tuple(ys))

    def apply(self, dv) -> np.ndarray:
        """Normalised values Δṽ for offset-removed responses ``dv`` of shape (..., H, W).

        Values below or above a taxel's table clamp to its first or last value.

        Raises
        ------
        ShapeError
            If the trailing dimensions are not the table's (H, W).
        """
        arr = finite(real_array(dv, "dv"), "dv")
        if arr.ndim < 2 or arr.shape[-2:] != tuple(self.shape):
            raise ShapeError(f"dv must have shape (..., {self.shape[0]}, {self.shape[1]}), got {arr.shape}")
        out = np.empty(arr.shape)
        for i, (r, c) in enumerate(np.ndindex(*self.shape)):
            out[..., r, c] = np.interp(arr[..., r, c], self.dv_knots[i], self.value_knots[i])
        return _float_out(out, dv)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Per-taxel summary, one row per taxel.

        Columns: ``taxel``, ``row``, ``col``, ``n_knots``, ``dv_min``, ``dv_max``, ``value_max``.
        """
        rows, cols = np.divmod(np.arange(len(self.dv_knots)), self.shape[1])
        return {"taxel": np.arange(len(self.dv_knots)), "row": rows, "col": cols,
                "n_knots": np.array([k.size for k in self.dv_knots]),
                "dv_min": np.array([k[0] for k in self.dv_knots]),
                "dv_max": np.array([k[-1] for k in self.dv_knots]),
                "value_max": np.array([k[-1] for k in self.value_knots])}


def _grasp_scenario(source: Opto5, indenter: Indenter, depth: float, *, n_base: int, n_ramp: int, n_hold: int,
                    x_mm: float = 0.0, y_mm: float = 0.0, angle_rad: float = 0.0,
                    curvature_per_mm: float = 0.0) -> Scenario:
    t = np.arange(n_base + n_ramp + n_hold) / source.config.rate_hz
    d = np.concatenate([np.zeros(n_base), np.linspace(0.0, depth, n_ramp + 1)[1:], np.full(n_hold, depth)])
    extra = {"curvature_per_mm": curvature_per_mm} if curvature_per_mm else {}
    return Scenario(indenter, t_s=t, x_mm=x_mm, y_mm=y_mm, angle_rad=angle_rad, depth_mm=d, extra=extra)


def _hold_dv(source: Opto5, scenario: Scenario, *, n_base: int, n_hold: int, seed) -> np.ndarray:
    dv = remove_offset(source.frames(scenario, seed=seed), n=n_base)
    return dv[-n_hold:].mean(axis=0)


def calibration_closure(source: Opto5, *, plate_mm: float = 4.0, n_samples: int = 400, n_base: int = 50,
                        seed: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Simulated calibration closure: the fingers close slowly to 255 on a flat plate.

    Parameters
    ----------
    source : Opto5
    plate_mm : float
        Plate thickness, mm; the closure compresses the pad up to
        ``depth_from_finger_distance(255, plate_mm)``.
    n_samples : int
        Samples of the closing ramp (after ``n_base`` unloaded samples).
    n_base : int
        Unloaded samples that define the offset.
    seed : int, optional

    Returns
    -------
    dv : (n_base + n_samples, 5, 5) ndarray
        Offset-removed responses, V.
    stimulus : (n_base + n_samples,) ndarray
        Crest depth (mm) at each sample: the common stimulus for
        :meth:`NormalisationLUT.from_closure`.
    """
    if not isinstance(source, Opto5):
        raise TypeError(f"source must be an Opto5, got {type(source).__name__}")
    plate = positive(plate_mm, "plate_mm")
    n_samples = integer(n_samples, "n_samples", minimum=3)
    n_base = integer(n_base, "n_base", minimum=1)
    p_contact = max(0.0, source.finger_distance_at_contact(plate))
    p = np.concatenate([np.zeros(n_base), np.linspace(p_contact, FINGER_DISTANCE_MAX, n_samples)])
    depth = source.depth_from_finger_distance(p, plate)
    t = np.arange(p.size) / source.config.rate_hz
    sc = Scenario(Indenter("flat"), t_s=t, depth_mm=depth)
    return remove_offset(source.frames(sc, seed=seed), n=n_base), depth


# ---- wire shape --------------------------------------------------------------------------------------
class WireShape(NamedTuple):
    """Quadratic wire centre line, mm.

    ``y = a x² + b x + c`` for a horizontal wire, ``x = a y² + b y + c`` for a vertical one.
    """

    a: float
    b: float
    c: float
    direction: str


_DIRECTIONS = ("horizontal", "vertical")


def _image(values, name: str = "values") -> np.ndarray:
    v = finite(real_array(values, name), name)
    if v.ndim != 2 or min(v.shape) < 3:
        raise ShapeError(f"{name} must be one 2-D taxel image with at least 3 rows and columns, "
                         f"got shape {v.shape}")
    return v


def _main_direction(v: np.ndarray, pitch: float) -> str:
    lay = Layout(shape=v.shape, pitch_mm=pitch, units="1", rate_hz=1.0)
    m = moments(v, lay)
    if m["total"][0] <= 0:
        raise InputError("values have no positive cell: no wire to find")
    return "horizontal" if m["sxx"][0] >= m["syy"][0] else "vertical"


def wire_centroids(values, *, direction: str = "horizontal", pitch_mm: float = 3.55) -> dict[str, np.ndarray]:
    """Per-column weighted centroids of the rows around a wire (rows and columns swap for vertical wires).

    Parameters
    ----------
    values : (H, W) array
        One (normalised) taxel image; negative values count as 0.
    direction : {"horizontal", "vertical"}
        Main direction of the wire.
    pitch_mm : float
        Taxel pitch, mm.

    Returns
    -------
    dict
        Table-shaped, one row per column along the wire: ``column``,
        ``x_mm`` (position along the wire), ``i_max`` (row of the column's
        maximum, -1 if the column has no positive value), ``y_mm`` (weighted
        centroid across the wire; NaN where ``valid`` is False), ``weight``
        (sum of the kept values), ``valid``, ``row_lo``/``row_hi`` (the kept
        rows, the same in every row).

    Notes
    -----
    Rows kept: ``max(min(i_max) - 1, 0)`` to ``min(max(i_max) + 1, H - 1)``,
    the extremes over the columns with a positive value. Positions follow the
    layout convention (x along columns, y along rows, origin at the centre).
    """
    v = np.clip(_image(values), 0.0, None)
    if direction not in _DIRECTIONS:
        raise InputError(f"direction must be one of {_DIRECTIONS}, got {direction!r}")
    pitch = positive(pitch_mm, "pitch_mm")
    if direction == "vertical":
        v = v.T
    h, w = v.shape
    valid = v.max(axis=0) > 0
    if not valid.any():
        raise InputError("values have no positive cell: no wire to find")
    i_max = np.where(valid, np.argmax(v, axis=0), -1)
    lo = max(int(i_max[valid].min()) - 1, 0)
    hi = min(int(i_max[valid].max()) + 1, h - 1)
    pos_y = (np.arange(h) - (h - 1) / 2) * pitch
    band = v[lo:hi + 1]
    weight = band.sum(axis=0)
    valid = weight > 0
    y = np.full(w, np.nan)
    y[valid] = (pos_y[lo:hi + 1] @ band)[valid] / weight[valid]
    return {"column": np.arange(w), "x_mm": (np.arange(w) - (w - 1) / 2) * pitch, "i_max": i_max,
            "y_mm": y, "weight": weight, "valid": valid, "row_lo": np.full(w, lo), "row_hi": np.full(w, hi)}


def wire_shape(values, *, direction: str | None = None, pitch_mm: float = 3.55) -> WireShape:
    r"""Wire centre line from one taxel image: a least-squares quadratic through the column centroids.

    Parameters
    ----------
    values : (H, W) array
        One normalised taxel image Δṽ (raw Δv works too, worse).
    direction : {"horizontal", "vertical"}, optional
        Main direction of the wire; by default the axis with the larger
        second moment of the (non-negative) values.
    pitch_mm : float
        Taxel pitch, mm.

    Returns
    -------
    WireShape
        ``(a, b, c, direction)``: ``y = a x² + b x + c`` for a horizontal wire,
        ``x = a y² + b y + c`` for a vertical one (layout frame, mm).

    Raises
    ------
    InputError
        If no cell is positive or fewer than 3 columns carry weight.

    Notes
    -----
    Per column :math:`j` the row of the maximum :math:`i_j`; rows
    :math:`\min i - 1 \ldots \max i + 1` (clipped to the pad) are kept and
    the centroid :math:`y_j = \sum_i y_i v_{ij} / \sum_i v_{ij}` over them;
    then :math:`(a, b, c) = \arg\min \sum_j (a x_j^2 + b x_j + c - y_j)^2`
    (:func:`wire_centroids`).

    Examples
    --------
    >>> import numpy as np
    >>> img = np.zeros((5, 5)); img[1] = 1.0          # a straight wire along row 1
    >>> a, b, c, direction = wire_shape(img)
    >>> direction, round(a, 9) + 0.0, round(b, 9) + 0.0, round(c, 9)   # + 0.0: no signed zeros
    ('horizontal', 0.0, 0.0, -3.55)
    """
    v = _image(values)
    pitch = positive(pitch_mm, "pitch_mm")
    if direction is None:
        direction = _main_direction(v, pitch)
    cent = wire_centroids(v, direction=direction, pitch_mm=pitch)
    ok = cent["valid"]
    if ok.sum() < 3:
        raise InputError(f"a quadratic needs at least 3 columns with positive values along the wire, "
                         f"got {ok.sum()}")
    x, y = cent["x_mm"][ok], cent["y_mm"][ok]
    coef, *_ = np.linalg.lstsq(np.stack([x * x, x, np.ones_like(x)], axis=1), y, rcond=None)
    return WireShape(float(coef[0]), float(coef[1]), float(coef[2]), direction)


# ---- diameter classifiers ----------------------------------------------------------------------------
@dataclass(frozen=True, eq=False)
class LookupTableClassifier:
    r"""2-D lookup table: mean summed Δṽ per finger distance and diameter; predicts the nearest.

    Parameters
    ----------
    finger_distance : (P,) array
        Table rows, strictly increasing encoder values.
    classes : (K,) array
        Class labels (diameters in mm; 0 = no wire).
    table : (P, K) array
        Mean summed normalised value for each finger distance and class.

    Notes
    -----
    For an observation :math:`(p, S)` the expected sums :math:`\bar S_k(p)`
    are the table row at :math:`p` (linear interpolation between rows, the
    end rows beyond them); the prediction is :math:`\arg\min_k |S - \bar S_k(p)|`.
    """

    finger_distance: np.ndarray
    classes: np.ndarray
    table: np.ndarray

    def __post_init__(self) -> None:
        p = _finger_distance(self.finger_distance)
        k = finite(real_array(self.classes, "classes"), "classes")
        t = finite(real_array(self.table, "table"), "table")
        if p.ndim != 1 or p.size < 1 or np.any(np.diff(p) <= 0):
            raise InputError(f"finger_distance must be a non-empty strictly increasing 1-D array, got {p!r}")
        if k.ndim != 1 or k.size < 2 or np.unique(k).size != k.size:
            raise InputError(f"classes must be at least 2 distinct labels, got {k!r}")
        if t.shape != (p.size, k.size):
            raise ShapeError(f"table must have shape (len(finger_distance), len(classes)) = "
                             f"{(p.size, k.size)}, got {t.shape}")
        for name, arr in (("finger_distance", p), ("classes", k), ("table", t)):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def from_table(cls, finger_distance, classes, table) -> LookupTableClassifier:
        """A classifier from a published-style table (rows: finger distances, columns: classes)."""
        return cls(finger_distance, classes, table)

    @classmethod
    def fit(cls, finger_distance, total, labels) -> LookupTableClassifier:
        """Table of mean ``total`` per (integer) finger distance and label.

        Cells without samples are interpolated linearly along finger distance
        from the same class's filled cells (the nearest filled cell beyond them).

        Parameters
        ----------
        finger_distance : (n,) array
            Encoder values, rounded to integers for the table rows.
        total : (n,) array
            Summed normalised values of each observation.
        labels : (n,) array
            Class labels.
        """
        p = np.rint(_finger_distance(finger_distance))
        s = finite(real_array(total, "total"), "total")
        y = finite(real_array(labels, "labels"), "labels")
        if p.ndim != 1 or s.shape != p.shape or y.shape != p.shape:
            raise ShapeError(f"finger_distance, total and labels must be 1-D of one length, got "
                             f"{p.shape}, {s.shape}, {y.shape}")
        rows, ri = np.unique(p, return_inverse=True)
        classes, ci = np.unique(y, return_inverse=True)
        total_sum = np.zeros((rows.size, classes.size))
        count = np.zeros_like(total_sum)
        np.add.at(total_sum, (ri, ci), s)
        np.add.at(count, (ri, ci), 1.0)
        table = np.empty_like(total_sum)
        for k in range(classes.size):
            has = count[:, k] > 0
            table[:, k] = np.interp(rows, rows[has], total_sum[has, k] / count[has, k])
        return cls(rows, classes, table)

    def expected(self, finger_distance) -> np.ndarray:
        """Expected sums (..., K) at ``finger_distance`` (rows interpolated)."""
        p = _finger_distance(finger_distance)
        cols = [np.interp(p, self.finger_distance, self.table[:, k]) for k in range(self.classes.size)]
        return np.stack(cols, axis=-1)

    def predict(self, finger_distance, total) -> np.ndarray:
        """Class whose expected sum at ``finger_distance`` is nearest to ``total`` (arrays broadcast)."""
        p = _finger_distance(finger_distance)
        s = finite(real_array(total, "total"), "total")
        try:
            p, s = np.broadcast_arrays(p, s)
        except ValueError as exc:
            raise ShapeError(f"finger_distance {p.shape} and total {s.shape} must broadcast") from exc
        return self.classes[np.argmin(np.abs(self.expected(p) - s[..., None]), axis=-1)]

    def as_dict(self) -> dict[str, np.ndarray]:
        """Long table: one row per (finger distance, class): ``finger_distance``, ``label``, ``mean_total``."""
        p, k = np.meshgrid(self.finger_distance, self.classes, indexing="ij")
        return {"finger_distance": p.ravel(), "label": k.ravel(), "mean_total": self.table.ravel()}


def svm_classifier(*, C: float = 10.0):
    """Scaled SVM, second-order polynomial kernel ``(γ x·x' + 1)²``, one-vs-one (scikit-learn pipeline)."""
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler
    from sklearn.svm import SVC

    return make_pipeline(StandardScaler(), SVC(kernel="poly", degree=2, coef0=1.0, C=positive(C, "C"),
                                               decision_function_shape="ovo"))


def mlp_classifier(*, hidden: tuple[int, ...] = (64, 32), seed: int | None = None, max_iter: int = 2000):
    """Scaled small multi-layer perceptron (scikit-learn ``MLPClassifier``, Adam, ReLU)."""
    from sklearn.neural_network import MLPClassifier
    from sklearn.pipeline import make_pipeline
    from sklearn.preprocessing import StandardScaler

    hidden = tuple(integer(h, "hidden", minimum=1) for h in hidden)
    return make_pipeline(StandardScaler(), MLPClassifier(hidden_layer_sizes=hidden, alpha=1e-3,
                                                         max_iter=integer(max_iter, "max_iter", minimum=1),
                                                         random_state=seed_value(seed)))


@dataclass(frozen=True, eq=False)
class WireDataset:
    """Simulated wire grasps: one observation per grasp.

    Attributes
    ----------
    finger_distance : (n,) int array
        Encoder value of the grasp.
    diameter_mm : (n,) array
        Class label: wire diameter, 0 for no wire.
    angle_rad, offset_mm : (n,) arrays
        Wire direction and signed distance of its axis from the pad centre.
    dv : (n, 5, 5) array
        Offset-removed hold response, V.
    values : (n, 5, 5) array
        Normalised Δṽ.
    """

    finger_distance: np.ndarray
    diameter_mm: np.ndarray
    angle_rad: np.ndarray
    offset_mm: np.ndarray
    dv: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return int(self.finger_distance.size)

    def features(self) -> np.ndarray:
        """Observations (n, 26): finger distance, then the 25 normalised values (row-major)."""
        return np.column_stack([self.finger_distance, self.values.reshape(len(self), -1)])

    def as_dict(self) -> dict[str, np.ndarray]:
        """Table-shaped: ``grasp``, scalars per grasp, ``sum`` and one column ``v_r_c`` per taxel."""
        out = {"grasp": np.arange(len(self)), "finger_distance": self.finger_distance,
               "diameter_mm": self.diameter_mm, "angle_rad": self.angle_rad, "offset_mm": self.offset_mm,
               "sum": self.values.reshape(len(self), -1).sum(axis=1)}
        for r, c in np.ndindex(self.values.shape[1:]):
            out[f"v_{r}_{c}"] = self.values[:, r, c]
        return out


def wire_dataset(*, n_per_class: int, seed: int | None = None, source: Opto5 | None = None,
                 lut: NormalisationLUT | None = None, diameters_mm=WIRE_DIAMETERS_MM,
                 finger_range: tuple[int, int] = (214, 255), max_offset_mm: float = 7.0,
                 n_base: int = 50, n_ramp: int = 10, n_hold: int = 10, progress: bool = False) -> WireDataset:
    """Simulated grasps of wires of each diameter plus a no-wire class.

    Each grasp: ``n_base`` unloaded samples, the gripper closing to a random
    finger distance over ``n_ramp`` samples, ``n_hold`` samples held; the
    observation is the mean offset-removed hold response, normalised.

    Parameters
    ----------
    n_per_class : int
        Grasps per class (each diameter and no wire).
    seed : int, optional
        Seeds everything random (poses, finger distances, sensor noise).
    source : Opto5, optional
        The sensor; ``Opto5()`` by default.
    lut : NormalisationLUT, optional
        Normalisation; by default built from :func:`calibration_closure` of ``source``.
    diameters_mm : sequence of float
        Wire diameters, mm.
    finger_range : (int, int)
        Inclusive range of the random finger distances (encoder values); the
        default starts just past contact with the thinnest wire.
    max_offset_mm : float
        Wire axis offset from the pad centre is uniform in ±this, mm; angle uniform in [0, π).
    n_base, n_ramp, n_hold : int
        Samples per grasp phase.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    WireDataset
    """
    from tqdm import tqdm

    n_per_class = integer(n_per_class, "n_per_class", minimum=2)
    source = Opto5() if source is None else source
    if not isinstance(source, Opto5):
        raise TypeError(f"source must be an Opto5, got {type(source).__name__}")
    diam = finite(real_array(diameters_mm, "diameters_mm"), "diameters_mm")
    if diam.ndim != 1 or diam.size < 1 or np.any(diam <= 0):
        raise InputError(f"diameters_mm must be a non-empty 1-D array of positive diameters, "
                         f"got {diameters_mm!r}")
    lo, hi = (integer(v, "finger_range") for v in finger_range)
    if not 0 <= lo <= hi <= FINGER_DISTANCE_MAX:
        raise InputError(f"finger_range must satisfy 0 <= low <= high <= 255, got {finger_range!r}")
    max_off = positive(max_offset_mm, "max_offset_mm", allow_zero=True)
    n_base, n_ramp, n_hold = (integer(v, k, minimum=1) for v, k in
                              ((n_base, "n_base"), (n_ramp, "n_ramp"), (n_hold, "n_hold")))
    ss = np.random.SeedSequence(seed_value(seed))
    lut_seq, pose_seq, noise_seq = ss.spawn(3)
    if lut is None:
        dv_c, stim = calibration_closure(source, seed=int(lut_seq.generate_state(1)[0]))
        lut = NormalisationLUT.from_closure(dv_c, stim)
    if not isinstance(lut, NormalisationLUT):
        raise TypeError(f"lut must be a NormalisationLUT, got {type(lut).__name__}")
    labels = np.repeat(np.concatenate([[0.0], diam]), n_per_class)
    n = labels.size
    rng = np.random.default_rng(pose_seq)
    p = rng.integers(lo, hi, endpoint=True, size=n)
    ang = rng.uniform(0.0, np.pi, size=n)
    off = rng.uniform(-max_off, max_off, size=n)
    seeds = noise_seq.generate_state(n)
    dv = np.empty((n, *source.layout.shape))
    for i in tqdm(range(n), desc="opto5 grasps", file=sys.stderr, disable=not progress):
        d = labels[i]
        depth = float(source.depth_from_finger_distance(p[i], d)) if d > 0 else 0.0
        ind = Indenter("wire", d / 2) if d > 0 else Indenter("flat")
        sc = _grasp_scenario(source, ind, depth, n_base=n_base, n_ramp=n_ramp, n_hold=n_hold,
                             x_mm=-off[i] * np.sin(ang[i]), y_mm=off[i] * np.cos(ang[i]), angle_rad=ang[i])
        dv[i] = _hold_dv(source, sc, n_base=n_base, n_hold=n_hold, seed=int(seeds[i]))
    return WireDataset(p, labels, ang, off, dv, lut.apply(dv))


def classify_wires(dataset: WireDataset, *, seed: int | None = 0, test_size: float = 0.2) -> dict:
    """Train and test the three diameter classifiers on one stratified split.

    Parameters
    ----------
    dataset : WireDataset
    seed : int, optional
        Seeds the split and the network's initialisation.
    test_size : float
        Test fraction (stratified by class).

    Returns
    -------
    dict
        JSON-serialisable: ``classes_mm``, ``n_train``, ``n_test``, ``chance``, and for
        ``lookup_table``, ``svm`` and ``mlp``: ``accuracy`` and ``confusion``
        (rows: true class, columns: predicted, in ``classes_mm`` order); the
        network also reports ``converged`` and ``n_iter``.
    """
    from sklearn.exceptions import ConvergenceWarning
    from sklearn.metrics import confusion_matrix
    from sklearn.model_selection import train_test_split

    if not isinstance(dataset, WireDataset):
        raise TypeError(f"dataset must be a WireDataset, got {type(dataset).__name__}")
    seed = seed_value(seed)
    if not 0 < test_size < 1:
        raise InputError(f"test_size must be in (0, 1), got {test_size!r}")
    X, y = dataset.features(), dataset.diameter_mm
    classes = np.unique(y)
    label = np.searchsorted(classes, y)          # integer class index for scikit-learn
    tr, te = train_test_split(np.arange(len(y)), test_size=test_size, stratify=label, random_state=seed)

    def report(pred):
        cm = confusion_matrix(label[te], np.searchsorted(classes, pred), labels=np.arange(classes.size))
        return {"accuracy": float(np.mean(pred == y[te])), "confusion": cm.tolist()}

    table = LookupTableClassifier.fit(X[tr, 0], X[tr, 1:].sum(axis=1), y[tr])
    out = {"classes_mm": classes.tolist(), "n_train": int(tr.size), "n_test": int(te.size),
           "chance": 1.0 / classes.size,
           "lookup_table": report(table.predict(X[te, 0], X[te, 1:].sum(axis=1)))}
    svm = svm_classifier().fit(X[tr], label[tr])
    out["svm"] = report(classes[svm.predict(X[te])])
    mlp = mlp_classifier(seed=seed)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        mlp.fit(X[tr], label[tr])
    out["mlp"] = report(classes[mlp.predict(X[te])])
    out["mlp"]["converged"] = not any(issubclass(w.category, ConvergenceWarning) for w in caught)
    out["mlp"]["n_iter"] = int(mlp[-1].n_iter_)
    return out


# ---- normalisation matters ---------------------------------------------------------------------------
def _true_curve(x_cols: np.ndarray, x0: float, y0: float, ang: float, kappa: float) -> np.ndarray:
    s = np.linspace(-40.0, 40.0, 8001)
    px = x0 + s * np.cos(ang) - 0.5 * kappa * s * s * np.sin(ang)
    py = y0 + s * np.sin(ang) + 0.5 * kappa * s * s * np.cos(ang)
    order = np.argsort(px)
    return np.interp(x_cols, px[order], py[order])


def shape_comparison(source: Opto5, lut: NormalisationLUT, *, n_trials: int = 20, seed: int | None = None,
                     diameter_mm: float = 3.0, finger_distance: int = 235) -> dict:
    """Shape estimation from raw Δv versus normalised Δṽ: a flat grasp and wires near the pad's edge.

    Parameters
    ----------
    source : Opto5
    lut : NormalisationLUT
    n_trials : int
        Edge-wire grasps: roughly horizontal (±10°), slightly curved
        (|κ| <= 0.01 /mm), axis 4.5–6.5 mm from the centre towards either edge.
    seed : int, optional
    diameter_mm : float
        Wire diameter of the edge trials, mm.
    finger_distance : int
        Encoder value of the edge grasps.

    Returns
    -------
    dict
        JSON-serialisable. ``flat``: raw and normalised hold images of a flat
        grasp at half the closure depth and their spread across taxels
        (``*_cv``: std/mean; ``*_max_over_min``). ``edge_wire``: per-trial RMS
        error (mm) over the columns of the fitted centre line, from raw and
        from normalised values and from the noise-free cell forces of equal
        linear taxels (``ideal``: the floor of the centroid method itself),
        with the main direction given as horizontal; their means; how often the
        automatic main direction is right; one example (images, fits, truth).
    """
    if not isinstance(source, Opto5) or not isinstance(lut, NormalisationLUT):
        raise TypeError("source must be an Opto5 and lut a NormalisationLUT, got "
                        f"{type(source).__name__} and {type(lut).__name__}")
    n_trials = integer(n_trials, "n_trials", minimum=1)
    ss = np.random.SeedSequence(seed_value(seed))
    rng = np.random.default_rng(ss.spawn(1)[0])
    n_base, n_ramp, n_hold = 50, 10, 10
    depth_flat = 0.5 * float(source.depth_from_finger_distance(FINGER_DISTANCE_MAX, 4.0))
    sc = _grasp_scenario(source, Indenter("flat"), depth_flat, n_base=n_base, n_ramp=n_ramp, n_hold=n_hold)
    raw = _hold_dv(source, sc, n_base=n_base, n_hold=n_hold, seed=int(rng.integers(2 ** 32)))
    norm = lut.apply(raw)

    def spread(img):
        return float(img.std() / img.mean()), float(img.max() / img.min())

    flat = {"depth_mm": depth_flat, "raw": raw.tolist(), "normalised": norm.tolist()}
    flat["raw_cv"], flat["raw_max_over_min"] = spread(raw)
    flat["normalised_cv"], flat["normalised_max_over_min"] = spread(norm)

    x_cols = source.layout.cell_xy()[0][0]
    depth = float(source.depth_from_finger_distance(finger_distance, diameter_mm))
    err = {"raw": [], "normalised": [], "ideal": []}
    auto_ok = {"raw": 0, "normalised": 0}
    example = None
    for _ in range(n_trials):
        ang = rng.uniform(-np.pi / 18, np.pi / 18)
        y0 = rng.choice([-1.0, 1.0]) * rng.uniform(4.5, 6.5)
        kappa = rng.uniform(-0.01, 0.01)
        sc = _grasp_scenario(source, Indenter("wire", diameter_mm / 2), depth, n_base=n_base, n_ramp=n_ramp,
                             n_hold=n_hold, y_mm=y0, angle_rad=ang, curvature_per_mm=kappa)
        raw_w = _hold_dv(source, sc, n_base=n_base, n_hold=n_hold, seed=int(rng.integers(2 ** 32)))
        truth = _true_curve(x_cols, 0.0, y0, ang, kappa)
        ideal = source.contact(sc)["taxel_force_n"][-n_hold:].mean(axis=0)   # equal linear taxels, no noise
        fits = {}
        for key, img in (("raw", raw_w), ("normalised", lut.apply(raw_w)), ("ideal", ideal)):
            fit = wire_shape(img, direction="horizontal", pitch_mm=source.config.pitch_mm)
            est = fit.a * x_cols ** 2 + fit.b * x_cols + fit.c
            err[key].append(float(np.sqrt(np.mean((est - truth) ** 2))))
            if key in auto_ok:
                auto_ok[key] += _main_direction(img, source.config.pitch_mm) == "horizontal"
            fits[key] = (img, fit)
        if example is None:
            example = {"y0_mm": y0, "angle_rad": ang, "curvature_per_mm": kappa, "x_mm": x_cols.tolist(),
                       "truth_y_mm": truth.tolist(),
                       **{f"{k}_image": v[0].tolist() for k, v in fits.items()},
                       **{f"{k}_fit": list(v[1][:3]) for k, v in fits.items()}}
    edge = {"diameter_mm": diameter_mm, "finger_distance": finger_distance, "n_trials": n_trials,
            "raw_rms_mm": err["raw"], "normalised_rms_mm": err["normalised"],
            "raw_mean_rms_mm": float(np.mean(err["raw"])),
            "normalised_mean_rms_mm": float(np.mean(err["normalised"])),
            "ideal_rms_mm": err["ideal"], "ideal_mean_rms_mm": float(np.mean(err["ideal"])),
            "raw_auto_direction_ok": auto_ok["raw"] / n_trials,
            "normalised_auto_direction_ok": auto_ok["normalised"] / n_trials, "example": example}
    return {"flat": flat, "edge_wire": edge}


def experiment(*, seed: int = 0, full: bool = False, progress: bool = True) -> dict:
    """The wire study on the simulated pad: normalisation, diameter classifiers, shape comparison.

    Parameters
    ----------
    seed : int
        Seeds the whole study (the sensor instance is ``Opto5Config(unit_seed=seed)``).
    full : bool
        Full size (300 grasps per class, 1000-sample closure, 40 edge trials)
        or small (100, 300, 8: a few seconds).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    dict
        JSON-serialisable: ``seed``, ``full``, ``config``, ``n_per_class``,
        ``classification`` (:func:`classify_wires`), ``normalisation``
        (:func:`shape_comparison`), ``lut`` (per-taxel table summary) and ``seconds``.
    """
    seed = seed_value(seed)
    if seed is None:
        raise InputError("experiment needs an integer seed, got None")
    t0 = time.perf_counter()
    n_per_class, n_closure, n_trials = (300, 1000, 40) if full else (100, 300, 8)
    source = Opto5(Opto5Config(unit_seed=seed))
    ss = np.random.SeedSequence(seed)
    s_lut, s_data, s_cls, s_shape = (int(s.generate_state(1)[0]) for s in ss.spawn(4))
    dv_c, stim = calibration_closure(source, n_samples=n_closure, seed=s_lut)
    lut = NormalisationLUT.from_closure(dv_c, stim)
    data = wire_dataset(n_per_class=n_per_class, seed=s_data, source=source, lut=lut, progress=progress)
    result = {
        "seed": seed, "full": bool(full), "config": dataclasses.asdict(source.config),
        "n_per_class": n_per_class, "n_closure_samples": n_closure,
        "classification": classify_wires(data, seed=s_cls % 2 ** 31),
        "normalisation": shape_comparison(source, lut, n_trials=n_trials, seed=s_shape),
        "lut": {k: v.tolist() for k, v in lut.as_dict().items()},
    }
    result["config"] = {k: list(v) if isinstance(v, tuple) else v for k, v in result["config"].items()}
    result["seconds"] = time.perf_counter() - t0
    return result


def plot_experiment(result: dict, path) -> None:
    """Save a PNG of :func:`experiment`'s result: confusion matrices and the raw-vs-normalised comparison."""
    from matplotlib.figure import Figure

    try:
        cls, norm = result["classification"], result["normalisation"]
        classes = cls["classes_mm"]
    except (KeyError, TypeError) as exc:
        raise InputError(f"result must be a dict returned by experiment(), missing {exc}") from exc
    fig = Figure(figsize=(16, 8.5), layout="constrained")
    axes = fig.subplots(2, 4)
    ticks = ["none" if c == 0 else f"{c:g}" for c in classes]
    titles = {"lookup_table": "2-D lookup table", "svm": "SVM (poly 2)", "mlp": "neural network"}
    for ax, (key, title) in zip(axes[0, :3], titles.items(), strict=True):
        cm = np.asarray(cls[key]["confusion"])
        ax.imshow(cm, cmap="Blues")
        for (i, j), v in np.ndenumerate(cm):
            if v:
                ax.text(j, i, str(v), ha="center", va="center", fontsize=7,
                        color="white" if v > cm.max() / 2 else "black")
        ax.set_xticks(range(len(classes)), ticks, fontsize=7)
        ax.set_yticks(range(len(classes)), ticks, fontsize=7)
        ax.set_xlabel("predicted diameter, mm")
        ax.set_ylabel("true diameter, mm")
        ax.set_title(f"{title}: {100 * cls[key]['accuracy']:.1f} %")
    ax = axes[0, 3]
    edge = norm["edge_wire"]
    ax.boxplot([edge["raw_rms_mm"], edge["normalised_rms_mm"]])
    ax.set_xticks([1, 2], ["raw Δv", "normalised Δṽ"])
    ax.set_ylabel("centre-line RMS error, mm")
    ax.set_title("wire near the edge")
    flat = norm["flat"]
    for ax, key in ((axes[1, 0], "raw"), (axes[1, 1], "normalised")):
        img = np.asarray(flat[key])
        im = ax.imshow(img / img.mean(), cmap="coolwarm", vmin=0.0, vmax=2.0)
        fig.colorbar(im, ax=ax, shrink=0.8, label="value / pad mean")
        ax.set_title(f"flat grasp, {'raw Δv' if key == 'raw' else 'normalised Δṽ'}: CV {flat[key + '_cv']:.2f}")
    ex = edge["example"]
    x = np.asarray(ex["x_mm"])
    xs = np.linspace(x.min(), x.max(), 100)
    pitch = float(x[1] - x[0])
    for ax, key in ((axes[1, 2], "raw"), (axes[1, 3], "normalised")):
        img = np.asarray(ex[f"{key}_image"])
        half = pitch * (img.shape[0] / 2)
        ax.imshow(img, cmap="viridis", extent=(-half, half, half, -half))
        ax.plot(x, ex["truth_y_mm"], "w-", lw=2, label="true")
        a, b, c = ex[f"{key}_fit"]
        ax.plot(xs, a * xs ** 2 + b * xs + c, "r--", lw=2, label="fit")
        ax.set_xlabel("x, mm")
        ax.set_ylabel("y, mm")
        ax.set_title(f"edge wire, {key}")
        ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"opto5 wire study (seed {result.get('seed')}, full={result.get('full')})")
    fig.savefig(path, dpi=110)


register_source("opto5", Opto5Config, Opto5)
