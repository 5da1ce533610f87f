"""Distributed piezoresistive finger pad: active tracing of pipes (source ``"piezo16"``).

Square unit electrodes (2 mm, 0.2 mm gaps: 2.2 mm pitch) on a 16×16
row/column grid, 204 of them present in a finger-pad shape, lie under 0.5 mm
of pressure-sensitive conductive rubber and a 2 mm elastomer sheet. The
elastomer spreads an indentation; every unit reads

    v = max(0, 3.45·p·q − 0.39) V

(``p``: pressed fraction of the electrode's area, ``q``: mean compression of
its pressed part, mm), so small compressions fall in a dead zone. All 204
units are sampled in 1 ms. This module simulates the pad (:class:`Piezo16`,
registered as ``"piezo16"``) and the active-tracing study that tells pipe
diameters apart:

1. the finger presses a pipe 0.7 mm and traces across its axis in ``N``
   steps of ``W/N`` (``W`` = 2 mm) (:func:`trace`);
2. the outputs of the pipe-radial grid line with the highest output are
   interleaved into one combined distribution,
   ``(e₁(0..N−1), e₂(0..N−1), …)`` (:func:`combined_distribution`): ``N``
   times finer sampling than the electrode pitch;
3. features: its width (number of non-zero elements) and the mean absolute
   difference between neighbours (:func:`features`);
4. the diameter (⌀10–40 mm) from the width with thresholds learned on
   training traces (:class:`WidthClassifier`), and the diameter resolution
   (:func:`pair_separation`, :func:`diameter_resolution`);
5. the whole study and its figure: :func:`experiment`, :func:`plot_experiment`.

Convention: unit indices are ``(row, col)``, ``(0, 0)`` top-left; the layout
frame has x along columns and y along rows (mm), origin at the grid centre
(:mod:`optitact.sources`), seen from the touched object. Row 0 is the
fingertip end of the pad.

Examples
--------
>>> from optitact.sources import make_source
>>> src = make_source("piezo16")
>>> src.layout.shape, src.layout.n_cells, src.layout.pitch_mm, src.layout.units, src.layout.rate_hz
((16, 16), 204, (2.2, 2.2), 'V', 1000.0)
>>> round(float(unit_voltage(1.0, 1.0)), 2), round(float(unit_voltage(0.25, 1.0)), 4)
(3.06, 0.4725)
>>> frames = trace(src, 20.0, 4, seed=0)
>>> frames.shape
(4, 16, 16)
>>> width, mad = features(combined_distribution(frames, 4))
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
from ..sources import Indenter, Layout, Scenario, TactileSource
from .base import TaxelSource, noise_rng, unit_gains
from .indenter import overlap, surface_height

__all__ = [
    "Piezo16Config", "Piezo16", "SUPPORTED_SHAPES", "FINGER_PAD_MASK", "unit_voltage", "trace",
    "radial_line", "combined_distribution", "features", "WidthClassifier", "pair_separation",
    "diameter_resolution", "tracing_dataset", "experiment", "plot_experiment",
]

#: Indenter shapes :class:`Piezo16` simulates.
SUPPORTED_SHAPES = ("cylinder", "sphere", "flat")

#: The default finger-pad mask, one string per grid row (``#``: unit present, ``.``: none), row 0 at
#: the fingertip: a rounded tip (rows 0-7), full rows 8-11, a slightly rounded base; 204 units.
FINGER_PAD_MASK: tuple[str, ...] = tuple(
    "." * k + "#" * (16 - 2 * k) + "." * k for k in (5, 4, 3, 2, 2, 1, 1, 1, 0, 0, 0, 0, 1, 1, 2, 3)
)


def unit_voltage(p, q, *, gain_v_per_mm: float = 3.45, offset_v: float = 0.39) -> np.ndarray:
    r"""The unit's response law: ``v = max(0, gain·p·q − offset)``, V (vectorised).

    Parameters
    ----------
    p : float or array
        Pressed fraction of the electrode's area, 0…1.
    q : float or array
        Mean compression of the pressed part, mm (>= 0); broadcast with ``p``.
    gain_v_per_mm : float
        V per mm of area-weighted compression (3.45 in the published law).
    offset_v : float
        V, the law's offset (0.39): the dead zone is ``p·q < offset / gain``.

    Returns
    -------
    ndarray
        Unit output, V (float64, the broadcast shape of ``p`` and ``q``).

    Raises
    ------
    TypeError
        For non-numeric input.
    InputError
        For NaN/inf, ``p`` outside [0, 1] or ``q < 0``.
    ShapeError
        If ``p`` and ``q`` do not broadcast.

    Notes
    -----
    Since :math:`p\,q` is the electrode-mean compression (the unpressed part
    contributes 0), an electrode stays silent until its mean compression
    reaches :math:`0.39 / 3.45 = 0.113` mm; at half area that takes
    :math:`q > 0.226` mm.

    Examples
    --------
    >>> unit_voltage([1.0, 0.25, 0.5], [1.0, 1.0, 0.2]).round(4).tolist()
    [3.06, 0.4725, 0.0]
    """
    pa = finite(real_array(p, "p"), "p")
    qa = finite(real_array(q, "q"), "q")
    gain = positive(gain_v_per_mm, "gain_v_per_mm")
    off = positive(offset_v, "offset_v", allow_zero=True)
    if pa.size and (pa.min() < 0 or pa.max() > 1):
        raise InputError(f"p (pressed area fraction) must be in [0, 1], got range [{pa.min()}, {pa.max()}]")
    if qa.size and qa.min() < 0:
        raise InputError(f"q (compression) must be >= 0 mm, got minimum {qa.min()}")
    try:
        pa, qa = np.broadcast_arrays(pa, qa)
    except ValueError as exc:
        raise ShapeError(f"p {pa.shape} and q {qa.shape} must broadcast") from exc
    return np.maximum(gain * pa * qa - off, 0.0)


def _ratio(a: float, b: float, name: str) -> int:
    r = a / b
    n = round(r)
    if abs(r - n) > 1e-9:
        raise InputError(f"{name} must be an integer, got {r:g}")
    return int(n)


def _mask_rows(mask, grid: tuple[int, int]) -> tuple[str, ...]:
    if isinstance(mask, str) or not isinstance(mask, (tuple, list)):
        raise TypeError(f"mask must be a tuple of row strings ('#' present, '.' absent), got "
                        f"{type(mask).__name__}")
    rows = tuple(mask)
    if len(rows) != grid[0] or any(not isinstance(r, str) or len(r) != grid[1] for r in rows):
        lengths = [len(r) if isinstance(r, str) else None for r in rows]
        raise ShapeError(f"mask must be {grid[0]} strings of {grid[1]} characters (grid {grid}), got "
                         f"{len(rows)} rows of lengths {lengths}")
    bad = sorted({ch for r in rows for ch in r} - {"#", "."})
    if bad:
        raise InputError(f"mask characters must be '#' (present) or '.' (absent), got {bad}")
    if not any("#" in r for r in rows):
        raise InputError("mask must contain at least one unit ('#'), got none")
    return rows


# ==== the sensor ========================================================================================
@dataclass(frozen=True)
class Piezo16Config:
    """The distributed piezoresistive finger pad.

    Every field states its unit. Per-unit gains are drawn once from
    ``unit_seed`` (one config describes one physical pad); readout noise is
    drawn from the ``seed`` of each :meth:`Piezo16.frames` call.
    """

    grid: tuple[int, int] = (16, 16)       # units along y (rows) and x (columns)
    mask: tuple[str, ...] = FINGER_PAD_MASK  # rows of '#' (unit present) / '.' (none); 204 units
    electrode_mm: float = 2.0              # mm, side of a square unit electrode
    gap_mm: float = 0.2                    # mm, gap between neighbouring electrodes (pitch = side + gap)
    elastomer_mm: float = 2.0              # mm, elastomer sheet over the rubber (spreads the indentation)
    rubber_mm: float = 0.5                 # mm, pressure-sensitive conductive rubber over the electrodes
    gain_v_per_mm: float = 3.45            # V/mm, law v = gain·p·q − offset
    offset_v: float = 0.39                 # V, law offset (dead zone below p·q = offset / gain)
    v_max: float = 5.0                     # V, output saturation (readout supply rail)
    unit_gain_spread: float = 0.1          # 1-sigma of ln(gain) across units (rubber nonuniformity, unit_seed)
    unit_seed: int = 0                     # seed of this pad's per-unit gains
    noise_v: float = 0.005                 # V, 1-sigma readout noise, added before the law's clipping
    sample_period_s: float = 0.001         # s, one scan of all units
    grid_mm: float = 0.1                   # mm, sub-electrode integration grid (divides side and gap)
    spread_cutoff: float = 4.0             # spreading kernel truncated at this many elastomer thicknesses

    def __post_init__(self) -> None:
        if not isinstance(self.grid, (tuple, list)) or len(self.grid) != 2:
            raise TypeError(f"grid must be a pair of integers (rows, cols), got {self.grid!r}")
        grid = (integer(self.grid[0], "grid[0]", minimum=1), integer(self.grid[1], "grid[1]", minimum=1))
        object.__setattr__(self, "grid", grid)
        object.__setattr__(self, "mask", _mask_rows(self.mask, grid))
        integer(self.unit_seed, "unit_seed", minimum=0)
        for name in ("electrode_mm", "elastomer_mm", "rubber_mm", "gain_v_per_mm", "v_max",
                     "sample_period_s", "grid_mm", "spread_cutoff"):
            positive(getattr(self, name), name)
        for name in ("gap_mm", "offset_v", "unit_gain_spread", "noise_v"):
            positive(getattr(self, name), name, allow_zero=True)
        _ratio(self.electrode_mm, self.grid_mm, "electrode_mm / grid_mm")
        _ratio(self.gap_mm, self.grid_mm, "gap_mm / grid_mm")

    @property
    def pitch_mm(self) -> float:
        """Electrode centre spacing, mm (side + gap)."""
        return self.electrode_mm + self.gap_mm

    @property
    def mask_array(self) -> np.ndarray:
        """The mask as a (rows, cols) bool array."""
        return np.array([[ch == "#" for ch in row] for row in self.mask], dtype=bool)


@lru_cache(maxsize=8)
def _kernel(h: float, g: float, cutoff: float) -> np.ndarray:
    """Boussinesq spreading kernel at depth ``h`` on a ``g`` grid, truncated at ``cutoff·h``, sum 1."""
    m = int(math.ceil(cutoff * h / g))
    r = np.arange(-m, m + 1) * g
    r2 = r[:, None] ** 2 + r[None, :] ** 2
    k = np.where(r2 <= (cutoff * h) ** 2, 1.0 / (r2 + h * h) ** 2.5, 0.0)
    k /= k.sum()
    k.setflags(write=False)
    return k


class Piezo16(TaxelSource):
    r"""Simulated distributed piezoresistive finger pad (source ``"piezo16"``).

    Parameters
    ----------
    config : Piezo16Config, optional
        The pad; defaults to ``Piezo16Config()``.

    Notes
    -----
    *Indentation.* A rigid indenter with its surface :math:`s(x, y)` above
    its crest (sphere / cylinder of radius :math:`R`:
    :math:`s = R - \sqrt{R^2 - r^2}` with :math:`r` the distance from the
    centre / axis, :math:`\infty` beyond :math:`R` or beyond a finite
    cylinder's length; flat: 0) pressed ``depth_mm`` :math:`d` into the pad
    indents its surface by :math:`u = \max(0, d - s)`.

    *Spreading.* The elastomer acts as a mechanical low-pass filter
    (Shimojo, IEEE Trans. Robot. Autom. 13(1), 1997, "Mechanical filtering
    effect of elastic cover for tactile sensor"): the surface load reaches
    the rubber at depth :math:`h` (``elastomer_mm``) convolved with the
    Boussinesq kernel of a point load on an elastic half-space,

    .. math:: K_h(r) = \frac{3 h^3}{2\pi (r^2 + h^2)^{5/2}},\qquad \int K_h\,dA = 1,

    whose half width at half maximum is :math:`0.57 h` (across a long pipe
    its line integral is Flamant's :math:`2h^3/(\pi(x^2 + h^2)^2)`, half width
    :math:`0.64 h`). With a
    local (Winkler) surface load proportional to :math:`u`, the rubber's
    compression field is :math:`w = K_h * u` (mm; the kernel conserves the
    indented volume, and a flat press gives :math:`w = d` everywhere). The
    kernel is truncated at ``spread_cutoff``·h and renormalised; the
    elastomer sheet extends beyond the electrode grid by that radius.

    *Units.* On a ``grid_mm`` sub-grid over each electrode (the gaps do not
    count), :math:`p` is the fraction of the electrode's area where
    :math:`w > 0` and :math:`q` the mean of :math:`w` there, so
    :math:`p q` is the electrode-mean compression. Unit :math:`i` reads
    :math:`v_i = \mathrm{clip}(g_i\,3.45\,p q - 0.39 + n, 0, v_{max})` with
    a per-unit gain :math:`g_i = e^{\sigma z_i}` (``unit_gain_spread``
    :math:`\sigma`, ``unit_seed``: the rubber's nonuniformity) and Gaussian
    readout noise :math:`n` (``noise_v``) added *before* the clipping, so
    units in the dead zone read exactly 0. :math:`g_i = 1` and no noise give
    :func:`unit_voltage`. Cells outside the mask read 0. All units are
    sampled at once every ``sample_period_s``; the pad is flat (its
    curvature is not modelled) and the indenter rigid.
    """

    name = "piezo16"
    config_type = Piezo16Config
    shapes = SUPPORTED_SHAPES
    drive = "depth"
    drive_note = "; force_n is not modelled (the law is written in compression, not force)"

    def __init__(self, config: Piezo16Config | None = None) -> None:
        super().__init__(config)

    def _setup(self, c: Piezo16Config) -> None:
        gain = unit_gains(np.random.default_rng(c.unit_seed), c.grid, c.unit_gain_spread) * c.mask_array
        gain.setflags(write=False)
        self.unit_gain = gain
        g = c.grid_mm
        self._n_e = _ratio(c.electrode_mm, g, "electrode_mm / grid_mm")
        self._sub = self._n_e + _ratio(c.gap_mm, g, "gap_mm / grid_mm")
        self._kernel = _kernel(c.elastomer_mm, g, c.spread_cutoff)
        self._margin = (self._kernel.shape[0] - 1) // 2
        rows, cols = c.grid
        pitch = c.pitch_mm

        def axis(n: int) -> np.ndarray:
            # sub-cell centres: electrode k spans [x_k - e/2, x_k + e/2], its gap follows it
            start = -(n - 1) / 2 * pitch - c.electrode_mm / 2 - self._margin * g
            return start + (np.arange(n * self._sub + 2 * self._margin) + 0.5) * g

        self._x = axis(cols)
        self._y = axis(rows)

    @cached_property
    def layout(self) -> Layout:
        """16×16 grid, 2.2 mm pitch, finger-pad mask (204 units), volts, 1 kHz."""
        c = self.config
        return Layout(shape=c.grid, pitch_mm=(c.pitch_mm, c.pitch_mm), units="V",
                      rate_hz=1.0 / c.sample_period_s, mask=c.mask_array)

    def _check(self, scenario: Scenario) -> Indenter:
        ind, _ = self.check_scenario(scenario)
        if not math.isinf(ind.stiffness_n_per_mm):
            raise InputError(f"the piezo16 source simulates rigid indenters (stiffness_n_per_mm = inf), got "
                             f"{ind.stiffness_n_per_mm!r}")
        limit = self.config.elastomer_mm + self.config.rubber_mm
        if np.max(scenario.depth_mm) >= limit:
            raise InputError(f"depth_mm must be < the pad thickness {limit:g} mm (elastomer + rubber), got "
                             f"maximum {np.max(scenario.depth_mm)}")
        return ind

    def _indentation(self, ind: Indenter, x0: float, y0: float, ang: float, depth: float) -> np.ndarray:
        """Surface indentation u (mm) on the padded sub-grid for one pose."""
        if depth <= 0:
            return np.zeros((self._y.size, self._x.size))
        return overlap(depth, surface_height(ind, self._x[None, :], self._y[:, None], x0, y0, ang))

    def compression(self, scenario: Scenario) -> dict[str, np.ndarray]:
        """Pressed area fraction and compression of every electrode, noise-free.

        Parameters
        ----------
        scenario : Scenario
            Indenter ``cylinder`` (a pipe: ``size_mm`` its radius, ``angle_rad``
            its axis direction, ``length_mm`` its length), ``sphere``
            (``size_mm`` its radius) or ``flat``, rigid; pose ``x_mm``,
            ``y_mm``; ``depth_mm`` the pressing depth (< elastomer + rubber).

        Returns
        -------
        dict
            Table-shaped, one row per sample: ``frame``, ``depth_mm``,
            ``pressed_fraction`` ((T, rows, cols) :math:`p`), ``compression_mm``
            ((T, rows, cols) :math:`q`, 0 where :math:`p = 0`) and
            ``mean_compression_mm`` ((T, rows, cols) :math:`p q`). Cells outside
            the mask hold 0.

        Raises
        ------
        TypeError
            If ``scenario`` is not a Scenario.
        InputError
            For an unsupported or soft indenter, ``force_n`` instead of
            ``depth_mm``, ``extra`` keys, or a depth beyond the pad's thickness.
        """
        from scipy.signal import fftconvolve

        ind = self._check(scenario)
        c = self.config
        rows, cols = c.grid
        n_t = scenario.n_frames
        sub, n_e = self._sub, self._n_e
        p = np.zeros((n_t, rows, cols))
        pq = np.zeros((n_t, rows, cols))
        depth = np.asarray(scenario.depth_mm, dtype=float)
        keys = [(float(x), float(y), float(a), float(d))
                for x, y, a, d in zip(scenario.x_mm, scenario.y_mm, scenario.angle_rad, depth, strict=True)]
        todo = list(dict.fromkeys(keys))   # each distinct pose once
        cache: dict[tuple, tuple[np.ndarray, np.ndarray]] = {}
        for start in range(0, len(todo), 8):
            chunk = todo[start:start + 8]
            u = np.stack([self._indentation(ind, *k) for k in chunk])
            if ind.shape == "flat":   # the normalised kernel leaves a uniform field unchanged
                m = self._margin
                w = u[:, m:u.shape[1] - m, m:u.shape[2] - m]
            else:
                w = np.clip(fftconvolve(u, self._kernel[None], mode="valid", axes=(1, 2)), 0.0, None)
                w[w < 1e-12] = 0.0   # FFT round-off where nothing is pressed
            e = w.reshape(len(chunk), rows, sub, cols, sub)[:, :, :n_e, :, :n_e]
            frac = (e > 0).mean(axis=(2, 4))
            mean = e.mean(axis=(2, 4))
            for j, k in enumerate(chunk):
                cache[k] = (frac[j], mean[j])
        for i, key in enumerate(keys):
            p[i], pq[i] = cache[key]
        mask = c.mask_array
        p *= mask
        pq *= mask
        q = np.divide(pq, p, out=np.zeros_like(pq), where=p > 0)
        return {"frame": np.arange(n_t), "depth_mm": depth.copy(), "pressed_fraction": p, "compression_mm": q,
                "mean_compression_mm": pq}

    def frames(self, scenario: Scenario, *, seed: int | None = None) -> np.ndarray:
        """Unit outputs (T, rows, cols), V (float64), for ``scenario``.

        Parameters
        ----------
        scenario : Scenario
            See :meth:`compression`.
        seed : int, optional
            Seed of the readout noise; the same seed gives the same frames.

        Raises
        ------
        TypeError
            If ``scenario`` is not a Scenario.
        InputError
            See :meth:`compression`.
        """
        rng = noise_rng(seed)
        c = self.config
        state = self.compression(scenario)
        v = c.gain_v_per_mm * self.unit_gain * state["mean_compression_mm"] - c.offset_v
        if c.noise_v > 0:
            v = v + c.noise_v * rng.standard_normal(v.shape)
        return np.clip(v, 0.0, c.v_max) * c.mask_array


# ==== active tracing ====================================================================================
def _n_steps(n_steps) -> int:
    return integer(n_steps, "n_steps", minimum=1)


def _number(value, name: str) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.floating, np.integer)):
        raise TypeError(f"{name} must be a real number, got {type(value).__name__}")
    if not math.isfinite(value):
        raise InputError(f"{name} must be a finite number, got {value!r}")
    return float(value)


def _motion(angle_rad: float) -> np.ndarray:
    """Tracing direction across a pipe with axis ``angle_rad``: the unit normal, main component > 0."""
    n = np.array([-math.sin(angle_rad), math.cos(angle_rad)])
    main = int(np.argmax(np.abs(n) + np.array([1e-12, 0.0])))   # x wins a 45° tie
    return n if n[main] > 0 else -n


def trace(source: TactileSource, diameter_mm: float, n_steps: int, *, depth_mm: float = 0.7,
          offset_mm: float = 0.0, angle_rad: float = 0.0, stroke_mm: float = 2.0, samples_per_step: int = 1,
          seed: int | None = None) -> np.ndarray:
    r"""Frames of one active trace across a pipe: ``n_steps`` steps of ``stroke_mm / n_steps``.

    Parameters
    ----------
    source : TactileSource
        The pad (:class:`Piezo16`; any source that simulates ``cylinder`` works).
    diameter_mm : float
        Pipe diameter, mm (a rigid ``cylinder`` of radius ``diameter_mm / 2``, longer than the pad).
    n_steps : int
        Number of steps N (>= 1).
    depth_mm : float
        Pressing depth, mm.
    offset_mm : float
        Position of the pipe's axis at the first step, along the tracing
        direction from the grid centre, mm.
    angle_rad : float
        Direction of the pipe's axis, from +x towards +y (layout frame).
    stroke_mm : float
        Tracing distance W covered by the N steps, mm (step ``W/N``).
    samples_per_step : int
        Frames recorded while the finger rests at each step.
    seed : int, optional
        Seed of the readout noise.

    Returns
    -------
    ndarray
        (N·samples_per_step, rows, cols) frames in step order.

    Notes
    -----
    The finger moves along the pipe's normal :math:`\hat n` whose larger
    component is positive (``angle_rad = 0``: axis along x, tracing along +y,
    across grid rows; ``angle_rad = π/2``: tracing along +x). At step
    :math:`j` the finger has moved :math:`j W/N`, so the pipe's axis sits at
    :math:`(o - j W/N)\,\hat n` on the pad (:math:`o` = ``offset_mm``), and
    electrode :math:`i` of a radial grid line samples the pipe at
    :math:`x_i + j W/N` in the pipe's frame. Frame times are
    ``arange(T) · sample_period``.
    """
    if not isinstance(source, TactileSource):
        raise TypeError(f"source must be a TactileSource, got {type(source).__name__}")
    n = _n_steps(n_steps)
    k = integer(samples_per_step, "samples_per_step", minimum=1)
    radius = positive(diameter_mm, "diameter_mm") / 2
    depth = positive(depth_mm, "depth_mm", allow_zero=True)
    stroke = positive(stroke_mm, "stroke_mm", allow_zero=True)
    offset, angle = _number(offset_mm, "offset_mm"), _number(angle_rad, "angle_rad")
    seed = seed_value(seed)
    normal = _motion(angle)
    pos = np.repeat(offset - np.arange(n) * stroke / n, k)
    scenario = Scenario(Indenter("cylinder", size_mm=radius), np.arange(n * k) / source.layout.rate_hz,
                        x_mm=pos * normal[0], y_mm=pos * normal[1], angle_rad=angle,
                        depth_mm=depth)
    return source.frames(scenario, seed=seed)


@lru_cache(maxsize=1)
def _default_layout() -> Layout:
    return Piezo16().layout


def _step_frames(frames, n_steps, layout: Layout | None) -> tuple[np.ndarray, Layout]:
    if layout is None:
        layout = _default_layout()
    if not isinstance(layout, Layout):
        raise TypeError(f"layout must be a Layout, got {type(layout).__name__}")
    n = _n_steps(n_steps)
    arr = layout.check_frames(frames)
    if arr.shape[0] % n:
        raise ShapeError(f"the number of frames must be a multiple of n_steps = {n} (samples per step), "
                         f"got {arr.shape[0]} frames")
    k = arr.shape[0] // n
    steps = arr.reshape(n, k, *layout.shape).mean(axis=1)
    return np.where(layout.mask, steps, 0.0), layout


def _line(steps: np.ndarray, layout: Layout, radial_axis: str | None) -> tuple[str, int]:
    if radial_axis is None:
        from ..sources import moments

        m = moments(steps.sum(axis=0), layout)
        radial_axis = "x" if m["sxx"][0] <= m["syy"][0] else "y"
    if radial_axis not in ("x", "y"):
        raise InputError(f"radial_axis must be 'x', 'y' or None (auto), got {radial_axis!r}")
    total = steps.sum(axis=0)
    line = total.sum(axis=1) if radial_axis == "x" else total.sum(axis=0)
    return radial_axis, int(np.argmax(line))


def radial_line(frames, *, layout: Layout | None = None, radial_axis: str | None = None) -> tuple[str, int]:
    """The pipe-radial grid line with the highest output: ``(axis, index)``.

    Parameters
    ----------
    frames : (T, rows, cols) or (rows, cols) array
        A trace (see :func:`combined_distribution`).
    layout : Layout, optional
        The frames' layout (default: the default :class:`Piezo16`'s).
    radial_axis : {"x", "y"}, optional
        ``"x"``: the radial line is a grid row (pipe along y); ``"y"``: a grid
        column (pipe along x). Default: the axis along which the summed output's
        second moment is smaller (across the pipe's stripe).

    Returns
    -------
    (str, int)
        The axis and the index of the row (``"x"``) or column (``"y"``) with
        the largest summed output over all frames (the first on ties).
    """
    steps, lay = _step_frames(frames, 1, layout)
    return _line(steps, lay, radial_axis)


def combined_distribution(frames, n_steps: int, *, layout: Layout | None = None,
                          radial_axis: str | None = None) -> np.ndarray:
    r"""Interleave a trace's radial-line outputs into one N-times finer distribution.

    Parameters
    ----------
    frames : (T, rows, cols) or (rows, cols) array
        The trace in step order; ``T = N·k`` frames: ``k`` consecutive samples
        per step, averaged.
    n_steps : int
        Steps N of the trace.
    layout : Layout, optional
        The frames' layout (default: the default :class:`Piezo16`'s); cells
        outside its mask count as 0.
    radial_axis : {"x", "y"}, optional
        See :func:`radial_line`.

    Returns
    -------
    ndarray
        (N·L,) float64, L the line's length: ``combined[i·N + j] = e_i(j)``,
        the output of element ``i`` of the selected line at step ``j``
        (``frames[j, row, i]`` for ``"x"``, ``frames[j, i, col]`` for ``"y"``).

    Raises
    ------
    TypeError
        For non-numeric frames, a non-integer ``n_steps`` or a wrong ``layout``.
    ShapeError
        If the frames do not fit the layout or their number is not a multiple of ``n_steps``.
    InputError
        For NaN/inf frames, ``n_steps < 1`` or a bad ``radial_axis``.

    Notes
    -----
    The trace moves the finger along +i (see :func:`trace`), so element
    :math:`i` at step :math:`j` sampled the pipe at :math:`x_i + jW/N`: the
    order :math:`(e_1(0..N-1), e_2(0..N-1), \ldots)` is the order along the
    pipe's radius (exactly uniform when W equals the pitch).

    Examples
    --------
    >>> import numpy as np
    >>> from optitact.sources import Layout
    >>> lay = Layout(shape=(2, 3), pitch_mm=(2.2, 2.2), units="V", rate_hz=1000.0)
    >>> f = np.zeros((2, 2, 3))
    >>> f[0, 1] = [1, 2, 3]
    >>> f[1, 1] = [10, 20, 30]
    >>> combined_distribution(f, 2, layout=lay, radial_axis="x").tolist()
    [1.0, 10.0, 2.0, 20.0, 3.0, 30.0]
    """
    steps, lay = _step_frames(frames, n_steps, layout)
    axis, idx = _line(steps, lay, radial_axis)
    line = steps[:, idx, :] if axis == "x" else steps[:, :, idx]
    return np.ascontiguousarray(line.T).ravel()


def features(combined) -> tuple[int, float]:
    """Width and mean neighbour difference of a combined distribution.

    Parameters
    ----------
    combined : (n,) array
        A combined distribution (:func:`combined_distribution`).

    Returns
    -------
    width : int
        Number of non-zero elements.
    mean_abs_diff : float
        Mean of :math:`|c_{k+1} - c_k|` over the neighbouring pairs inside the
        distribution's span (first to last non-zero element); 0.0 when the
        width is 0 or 1 (no pair).

    Raises
    ------
    TypeError
        For non-numeric input.
    ShapeError
        If ``combined`` is not a non-empty 1-D array.
    InputError
        For NaN or infinite values.

    Examples
    --------
    >>> features([0, 0, 1.0, 3.0, 2.0, 0, 0])
    (3, 1.5)
    """
    c = finite(real_array(combined, "combined"), "combined")
    if c.ndim != 1 or c.size == 0:
        raise ShapeError(f"combined must be a non-empty 1-D array, got shape {c.shape}")
    nz = np.flatnonzero(c)
    if nz.size < 2:
        return int(nz.size), 0.0
    span = c[nz[0]:nz[-1] + 1]
    return int(nz.size), float(np.abs(np.diff(span)).mean())


def _labelled(widths, diameters) -> tuple[np.ndarray, np.ndarray]:
    w = finite(real_array(widths, "widths"), "widths")
    d = finite(real_array(diameters, "diameters"), "diameters")
    if w.ndim != 1 or d.shape != w.shape or w.size == 0:
        raise ShapeError(f"widths and diameters must be non-empty 1-D arrays of one length, got {w.shape} "
                         f"and {d.shape}")
    return w, d


@dataclass(frozen=True, eq=False)
class WidthClassifier:
    r"""Diameter from the width of a combined distribution: thresholds between class mean widths.

    Parameters
    ----------
    diameters : (K,) array
        The classes, ordered by their mean width (ties: by diameter).
    mean_widths : (K,) array
        Mean training width of each class (non-decreasing).
    thresholds : (K−1,) array
        Midpoints between consecutive mean widths.

    Notes
    -----
    A width :math:`w` gets class :math:`k` = the number of thresholds
    :math:`\le w` (a width on a threshold goes to the wider class).

    Examples
    --------
    >>> clf = WidthClassifier.fit([3, 3, 5, 5, 9], [10, 10, 20, 20, 30])
    >>> clf.thresholds.tolist(), clf.predict([3.9, 4.0, 6.9, 7.1]).tolist()
    ([4.0, 7.0], [10.0, 20.0, 20.0, 30.0])
    """

    diameters: np.ndarray
    mean_widths: np.ndarray
    thresholds: np.ndarray

    def __post_init__(self) -> None:
        d = finite(real_array(self.diameters, "diameters"), "diameters")
        m = finite(real_array(self.mean_widths, "mean_widths"), "mean_widths")
        t = finite(real_array(self.thresholds, "thresholds"), "thresholds")
        if d.ndim != 1 or d.size < 2 or np.unique(d).size != d.size:
            raise InputError(f"diameters must hold at least 2 distinct classes, got {d.tolist()}")
        if m.shape != d.shape or t.shape != (d.size - 1,):
            raise ShapeError(f"mean_widths must have shape {d.shape} and thresholds ({d.size - 1},), got "
                             f"{m.shape} and {t.shape}")
        if np.any(np.diff(m) < 0) or np.any(np.diff(t) < 0):
            raise InputError("mean_widths and thresholds must be non-decreasing")
        for name, arr in (("diameters", d), ("mean_widths", m), ("thresholds", t)):
            arr = arr.copy()
            arr.setflags(write=False)
            object.__setattr__(self, name, arr)

    @classmethod
    def fit(cls, widths, diameters) -> WidthClassifier:
        """Learn the thresholds from training traces.

        Parameters
        ----------
        widths : (n,) array
            Widths of the training traces' combined distributions.
        diameters : (n,) array
            Their pipe diameters (the classes), mm.

        Raises
        ------
        ShapeError
            For arrays of different lengths or not 1-D.
        InputError
            For NaN/inf or fewer than two classes.
        """
        w, d = _labelled(widths, diameters)
        classes, idx = np.unique(d, return_inverse=True)
        if classes.size < 2:
            raise InputError(f"training needs at least two diameters, got {classes.tolist()}")
        means = np.bincount(idx, weights=w) / np.bincount(idx)
        order = np.lexsort((classes, means))
        m = means[order]
        return cls(classes[order], m, (m[1:] + m[:-1]) / 2)

    def predict(self, widths) -> np.ndarray:
        """Diameter (mm) of each width."""
        w = finite(real_array(widths, "widths"), "widths")
        return self.diameters[np.searchsorted(self.thresholds, w, side="right")]

    def score(self, widths, diameters) -> float:
        """Fraction of traces whose diameter is predicted exactly."""
        w, d = _labelled(widths, diameters)
        return float(np.mean(self.predict(w) == d))

    def as_dict(self) -> dict[str, list]:
        """Table-shaped: one row per class: ``diameter_mm``, ``mean_width``, ``upper_threshold`` (None last)."""
        return {"diameter_mm": self.diameters.tolist(), "mean_width": self.mean_widths.tolist(),
                "upper_threshold": [*self.thresholds.tolist(), None]}


def pair_separation(classifier: WidthClassifier, widths, diameters) -> dict[str, np.ndarray]:
    r"""How well the width tells every pair of diameters apart on test traces.

    Parameters
    ----------
    classifier : WidthClassifier
        Fitted on training traces (its class mean widths).
    widths, diameters : (n,) arrays
        Test traces.

    Returns
    -------
    dict
        Table-shaped, one row per pair of classes (smaller diameter first):
        ``d_small``, ``d_large``, ``delta_mm``, ``accuracy`` (balanced
        accuracy of the pair's threshold on the test traces of the two).

    Notes
    -----
    For a pair (a, b) the threshold is the midpoint of their training mean
    widths; a test trace is right when it falls on its class's side (the
    side of the class with the larger mean width is :math:`w \ge t`). The
    accuracy is the mean of the two classes' right fractions; a pair with
    equal mean widths, or with no test trace of either class, scores 0.5.
    """
    if not isinstance(classifier, WidthClassifier):
        raise TypeError(f"classifier must be a WidthClassifier, got {type(classifier).__name__}")
    w, d = _labelled(widths, diameters)
    mean = dict(zip(classifier.diameters.tolist(), classifier.mean_widths.tolist(), strict=True))
    classes = sorted(mean)
    rows: dict[str, list] = {"d_small": [], "d_large": [], "delta_mm": [], "accuracy": []}
    for i, a in enumerate(classes):
        for b in classes[i + 1:]:
            wa, wb = w[d == a], w[d == b]
            if mean[a] == mean[b] or wa.size == 0 or wb.size == 0:
                acc = 0.5
            else:
                t = (mean[a] + mean[b]) / 2
                hi_a = mean[a] > mean[b]
                ra = np.mean((wa >= t) == hi_a)
                rb = np.mean((wb >= t) != hi_a)
                acc = float((ra + rb) / 2)
            rows["d_small"].append(a)
            rows["d_large"].append(b)
            rows["delta_mm"].append(b - a)
            rows["accuracy"].append(acc)
    return {k: np.asarray(v, dtype=float) for k, v in rows.items()}


def diameter_resolution(classifier: WidthClassifier, widths, diameters, *, reliability: float = 0.95) -> float:
    r"""Smallest diameter difference that the width separates reliably across the whole range.

    Parameters
    ----------
    classifier : WidthClassifier
        Fitted on training traces.
    widths, diameters : (n,) arrays
        Test traces.
    reliability : float
        Balanced accuracy a pair must reach (0.5 < reliability <= 1).

    Returns
    -------
    float
        The smallest :math:`\Delta` among the pairs' differences such that every
        pair of classes at least :math:`\Delta` apart reaches ``reliability``
        in :func:`pair_separation`, mm; ``inf`` when not even the two extreme
        classes do.

    Examples
    --------
    >>> clf = WidthClassifier.fit([3, 3, 4, 4, 5, 5], [10, 10, 20, 20, 30, 30])
    >>> diameter_resolution(clf, [3, 3, 3, 4, 5, 5], [10, 10, 20, 20, 30, 30])
    20.0
    """
    r = positive(reliability, "reliability")
    if not 0.5 < r <= 1:
        raise InputError(f"reliability must be in (0.5, 1], got {reliability!r}")
    table = pair_separation(classifier, widths, diameters)
    best = math.inf
    for delta in sorted(set(table["delta_mm"].tolist()), reverse=True):
        if np.all(table["accuracy"][table["delta_mm"] >= delta] >= r - 1e-12):
            best = delta
        else:
            break
    return float(best)


# ==== the study =========================================================================================
#: Steps N of the published table.
N_STEPS = (1, 2, 4, 8)
#: Pipe diameters of the published table, mm.
DIAMETERS_MM = (10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)


def tracing_dataset(source: TactileSource, diameters_mm, n_steps: int, n_traces: int, *,
                    seed: int | None = None, depth_mm: float = 0.7, stroke_mm: float = 2.0,
                    angle_rad: float = math.pi / 2, progress: bool = False) -> dict[str, np.ndarray]:
    """Features of random traces: ``n_traces`` offsets uniform in [0, W) per diameter.

    Parameters
    ----------
    source : TactileSource
        The pad (:class:`Piezo16`, or any source that simulates ``cylinder``).
    diameters_mm : sequence of float
        Pipe diameters, mm.
    n_steps : int
        Steps N per trace.
    n_traces : int
        Traces per diameter.
    seed : int, optional
        Seeds the offsets and the noise.
    depth_mm, stroke_mm, angle_rad
        See :func:`trace` (default: pipe along y, radial lines are grid rows).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    dict
        Table-shaped, one row per trace: ``diameter_mm``, ``offset_mm``,
        ``width``, ``mean_abs_diff``, and ``combined`` ((n, N·cols) the
        combined distributions).
    """
    from tqdm import tqdm

    if not isinstance(source, TactileSource):
        raise TypeError(f"source must be a TactileSource, got {type(source).__name__}")
    diam = finite(real_array(diameters_mm, "diameters_mm"), "diameters_mm").ravel()
    if diam.size == 0 or diam.min() <= 0:
        raise InputError(f"diameters_mm must be a non-empty list of diameters > 0, got {diam.tolist()}")
    n = _n_steps(n_steps)
    n_tr = integer(n_traces, "n_traces", minimum=1)
    stroke = positive(stroke_mm, "stroke_mm")
    depth = positive(depth_mm, "depth_mm", allow_zero=True)
    angle = _number(angle_rad, "angle_rad")
    rng = np.random.default_rng(seed_value(seed))
    normal = _motion(angle)
    axis = "x" if abs(normal[0]) >= abs(normal[1]) else "y"
    rows: dict[str, list] = {k: [] for k in ("diameter_mm", "offset_mm", "width", "mean_abs_diff", "combined")}
    for d in tqdm(diam.tolist(), desc=f"piezo16 traces N={n}", file=sys.stderr, disable=not progress):
        offsets = rng.uniform(0.0, stroke, n_tr)
        pos = (offsets[:, None] - np.arange(n)[None, :] * stroke / n).ravel()
        sc = Scenario(Indenter("cylinder", size_mm=d / 2), np.arange(pos.size) / source.layout.rate_hz,
                      x_mm=pos * normal[0], y_mm=pos * normal[1], angle_rad=angle, depth_mm=depth)
        frames = source.frames(sc, seed=int(rng.integers(2 ** 31))).reshape(n_tr, n, *source.layout.shape)
        for t in range(n_tr):
            comb = combined_distribution(frames[t], n, layout=source.layout, radial_axis=axis)
            w, mad = features(comb)
            rows["diameter_mm"].append(d)
            rows["offset_mm"].append(float(offsets[t]))
            rows["width"].append(w)
            rows["mean_abs_diff"].append(mad)
            rows["combined"].append(comb)
    out = {k: np.asarray(v, dtype=float) for k, v in rows.items()}
    out["width"] = out["width"].astype(int)
    return out


def _jsonable(value):
    if isinstance(value, float) and not math.isfinite(value):
        return None
    if isinstance(value, tuple):
        return [_jsonable(v) for v in value]
    return value


def experiment(*, seed: int = 0, full: bool = False, progress: bool = True) -> dict:
    """The active-tracing study on simulated traces: width and neighbour difference, N × diameter.

    Parameters
    ----------
    seed : int
        Seeds the offsets and the readout noise (the pad is the default one).
    full : bool
        Full size (7 diameters, N = 1, 2, 4, 8, 20 training + 20 test traces
        each) or small (⌀10, 25, 40 mm, 3 + 3 traces: a few seconds).
    progress : bool
        tqdm progress bars on stderr.

    Returns
    -------
    dict
        JSON-serialisable: ``seed``, ``full``, ``config``, ``protocol``
        (depth, stroke W, angle, trace counts, reliability), ``table``
        (one row per (N, diameter): ``n_steps``, ``diameter_mm``,
        ``width_mean``, ``width_std``, ``width_min``, ``width_max``,
        ``mad_mean``, ``mad_std``, ``n_traces``; over training and test traces),
        ``classification`` (one row per N: ``n_steps``, ``accuracy`` (test),
        ``resolution_mm`` (None: not resolved), ``classifier``
        (:meth:`WidthClassifier.as_dict`), ``pairs`` (:func:`pair_separation`)),
        ``examples`` (one combined distribution per N and diameter, with its
        sample positions in mm) and ``seconds``.

    Notes
    -----
    Each trace has its own contact offset, uniform in [0, W). The classifier
    of each N is fitted on the training traces, and its accuracy and the
    resolution (:func:`diameter_resolution`, reliability 0.95) are measured
    on the test traces.
    """
    seed = seed_value(seed)
    if seed is None:
        raise InputError("experiment needs an integer seed, got None")
    t0 = time.perf_counter()
    diameters = DIAMETERS_MM if full else (10.0, 25.0, 40.0)
    n_train, n_test = (20, 20) if full else (3, 3)
    depth, stroke, angle, reliability = 0.7, 2.0, math.pi / 2, 0.95
    source = Piezo16()
    pitch = source.config.pitch_mm
    seeds = np.random.SeedSequence(seed).spawn(len(N_STEPS))
    keys = ("n_steps", "diameter_mm", "width_mean", "width_std", "width_min", "width_max", "mad_mean",
            "mad_std", "n_traces")
    table: dict[str, list] = {k: [] for k in keys}
    cls_rows: dict[str, list] = {k: [] for k in ("n_steps", "accuracy", "resolution_mm", "classifier", "pairs")}
    examples: dict[str, list] = {"n_steps": [], "diameter_mm": [], "position_mm": [], "combined": []}
    for n, ss in zip(N_STEPS, seeds, strict=True):
        data = tracing_dataset(source, diameters, n, n_train + n_test, seed=int(ss.generate_state(1)[0]),
                               depth_mm=depth, stroke_mm=stroke, angle_rad=angle, progress=progress)
        is_train = np.tile(np.arange(n_train + n_test) < n_train, len(diameters))
        for d in diameters:
            sel = data["diameter_mm"] == d
            w, mad = data["width"][sel], data["mean_abs_diff"][sel]
            for k, v in zip(keys, (n, d, w.mean(), w.std(ddof=1), w.min(), w.max(), mad.mean(), mad.std(ddof=1),
                                   int(sel.sum())), strict=True):
                table[k].append(int(v) if k in ("n_steps", "width_min", "width_max", "n_traces") else float(v))
            first = int(np.flatnonzero(sel)[0])
            comb = data["combined"][first]
            i = np.arange(comb.size)
            cols = source.layout.shape[1]
            pos = ((i // n) - (cols - 1) / 2) * pitch + (i % n) * stroke / n - data["offset_mm"][first]
            examples["n_steps"].append(n)
            examples["diameter_mm"].append(d)
            examples["position_mm"].append(pos.tolist())
            examples["combined"].append(comb.tolist())
        clf = WidthClassifier.fit(data["width"][is_train], data["diameter_mm"][is_train])
        test_w, test_d = data["width"][~is_train], data["diameter_mm"][~is_train]
        pairs = pair_separation(clf, test_w, test_d)
        cls_rows["n_steps"].append(n)
        cls_rows["accuracy"].append(clf.score(test_w, test_d))
        cls_rows["resolution_mm"].append(_jsonable(diameter_resolution(clf, test_w, test_d,
                                                                       reliability=reliability)))
        cls_rows["classifier"].append(clf.as_dict())
        cls_rows["pairs"].append({k: v.tolist() for k, v in pairs.items()})
    return {
        "seed": seed, "full": bool(full),
        "config": {k: _jsonable(v) for k, v in dataclasses.asdict(source.config).items()},
        "protocol": {"depth_mm": depth, "stroke_mm": stroke, "angle_rad": angle, "n_steps": list(N_STEPS),
                     "diameters_mm": list(diameters), "n_train": n_train, "n_test": n_test,
                     "reliability": reliability, "chance": 1.0 / len(diameters)},
        "table": table, "classification": cls_rows, "examples": examples,
        "seconds": time.perf_counter() - t0,
    }


def plot_experiment(result: dict, path) -> None:
    """Save a PNG of :func:`experiment`'s result: width and neighbour difference per N, examples, resolution.

    Parameters
    ----------
    result : dict
        As returned by :func:`experiment` (or read back from its JSON).
    path : str or path-like
        Output PNG file.
    """
    from matplotlib.figure import Figure

    try:
        table, cls, ex = result["table"], result["classification"], result["examples"]
        ns = sorted(set(table["n_steps"]))
        d_all = np.asarray(table["diameter_mm"], dtype=float)
        n_all = np.asarray(table["n_steps"])
    except (KeyError, TypeError) as exc:
        raise InputError(f"result must be a dict returned by experiment(), missing {exc}") from exc
    fig = Figure(figsize=(14, 9), layout="constrained")
    grid = fig.add_gridspec(2, 3)
    for col, (key, err, label) in enumerate((("width_mean", "width_std", "width (non-zero elements)"),
                                             ("mad_mean", "mad_std", "mean |neighbour difference|, V"))):
        ax = fig.add_subplot(grid[0, col])
        for j, n in enumerate(ns):
            sel = n_all == n
            ax.errorbar(d_all[sel], np.asarray(table[key])[sel], yerr=np.asarray(table[err])[sel], marker="o",
                        capsize=2, color=f"C{j}", label=f"N = {n}")
        ax.set_xlabel("pipe diameter, mm")
        ax.set_ylabel(label)
        ax.set_title(label.split(" (")[0].split(",")[0] + " of the combined distribution")
        ax.legend(fontsize=8)
    ax = fig.add_subplot(grid[0, 2])
    res = [np.nan if r is None else r for r in cls["resolution_mm"]]
    pos = np.arange(len(cls["n_steps"]))
    ax.bar(pos - 0.2, res, 0.4, color="C0", label="resolution, mm")
    ax.set_xticks(pos, [f"N = {n}" for n in cls["n_steps"]])
    ax.set_ylabel("diameter resolution, mm")
    ax2 = ax.twinx()
    ax2.bar(pos + 0.2, 100 * np.asarray(cls["accuracy"]), 0.4, color="C1", label="accuracy, %")
    ax2.set_ylabel("test accuracy, %")
    ax2.set_ylim(0, 105)
    ax.set_title("width classifier (bars: resolution | accuracy)")
    e_n = np.asarray(ex["n_steps"])
    e_d = np.asarray(ex["diameter_mm"], dtype=float)
    shown = sorted(set(e_d.tolist()))
    shown = [shown[0], shown[len(shown) // 2], shown[-1]]
    for col, d in enumerate(shown):
        ax = fig.add_subplot(grid[1, col])
        for j, n in enumerate(ns):
            i = int(np.flatnonzero((e_n == n) & (e_d == d))[0])
            ax.step(ex["position_mm"][i], ex["combined"][i], where="mid", color=f"C{j}", lw=1.2,
                    label=f"N = {n}")
        ax.set_xlim(-12, 12)
        ax.set_xlabel("position across the pipe, mm")
        ax.set_ylabel("unit output, V")
        ax.set_title(f"combined distribution, ⌀{d:g} mm")
        ax.legend(fontsize=8)
    fig.suptitle(f"piezo16 active tracing (seed {result.get('seed')}, full={result.get('full')})")
    fig.savefig(path, dpi=110)


Piezo16.register()
