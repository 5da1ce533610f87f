"""Distributed piezoresistive finger pad (source ``"piezo16"``): the sensor and its response law.

Square unit electrodes (2 mm, 0.2 mm gaps: 2.2 mm pitch) on a 16×16
row/column grid, 204 of them present in a finger-pad shape, lie under 0.5 mm
of pressure-sensitive conductive rubber and a 2 mm elastomer sheet. The
elastomer spreads an indentation; every unit reads

    v = max(0, 3.45·p·q − 0.39) V

(``p``: pressed fraction of the electrode's area, ``q``: mean compression of
its pressed part, mm), so small compressions fall in a dead zone
(:func:`unit_voltage`). All 204 units are sampled in 1 ms. :class:`Piezo16`
simulates the pad (registered as ``"piezo16"``); active tracing of pipes
with it is in :mod:`optitact.taxels.combined`, the published study in
``optitact.studies.tracing``.

Convention: unit indices are ``(row, col)``, ``(0, 0)`` top-left; the layout
frame has x along columns and y along rows (mm), origin at the grid centre
(:mod:`optitact.taxels.sources`), seen from the touched object. Row 0 is the
fingertip end of the pad.

Examples
--------
>>> from optitact.taxels.sources import make_source
>>> src = make_source("piezo16")
>>> src.layout.shape, src.layout.n_cells, src.layout.pitch_mm, src.layout.units, src.layout.rate_hz
((16, 16), 204, (2.2, 2.2), 'V', 1000.0)
>>> round(float(unit_voltage(1.0, 1.0)), 2), round(float(unit_voltage(0.25, 1.0)), 4)
(3.06, 0.4725)
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property, lru_cache

import numpy as np

from optitact._validate import finite, integer, positive, real_array
from optitact.errors import InputError, ShapeError
from optitact.taxels.sources import Indenter, Layout, Scenario
from optitact.taxels.base import TaxelSource, noise_rng, unit_gains
from optitact.taxels.indenter import overlap, surface_height

__all__ = ["Piezo16Config", "Piezo16", "SUPPORTED_SHAPES", "FINGER_PAD_MASK", "unit_voltage",
           "boussinesq_kernel", "leak_kernel"]

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
    spread_cutoff: float = 4.0             # spreading kernel truncated at this many spreading depths
    spread_depth_mm: float | None = None   # mm, depth of the Boussinesq spreading; None: elastomer_mm
    rubber_leak_mm: float = 0.0            # mm, decay length of lateral spreading in the rubber sheet; 0: off

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
        for name in ("gap_mm", "offset_v", "unit_gain_spread", "noise_v", "rubber_leak_mm"):
            positive(getattr(self, name), name, allow_zero=True)
        if self.spread_depth_mm is not None:
            positive(self.spread_depth_mm, "spread_depth_mm")
        _ratio(self.electrode_mm, self.grid_mm, "electrode_mm / grid_mm")
        _ratio(self.gap_mm, self.grid_mm, "gap_mm / grid_mm")

    @property
    def pitch_mm(self) -> float:
        """Electrode centre spacing, mm (side + gap)."""
        return self.electrode_mm + self.gap_mm

    @property
    def depth_of_spreading_mm(self) -> float:
        """Depth h of the Boussinesq spreading kernel, mm (``spread_depth_mm``, or ``elastomer_mm``)."""
        return self.elastomer_mm if self.spread_depth_mm is None else float(self.spread_depth_mm)

    @property
    def mask_array(self) -> np.ndarray:
        """The mask as a (rows, cols) bool array."""
        return np.array([[ch == "#" for ch in row] for row in self.mask], dtype=bool)


def boussinesq_kernel(h: float, g: float, cutoff: float) -> np.ndarray:
    r"""Boussinesq spreading kernel at depth ``h`` on a ``g`` grid, truncated at ``cutoff·h``, sum 1.

    Samples :math:`K_h(r) = 3 h^3 / (2\pi (r^2 + h^2)^{5/2})` (the vertical
    stress at depth :math:`h` under a unit point load on an elastic
    half-space) at the grid's nodes and renormalises the truncated kernel.
    Read-only (cached).
    """
    return _kernel(float(h), float(g), float(cutoff), 0.0)


def leak_kernel(lam: float, g: float) -> np.ndarray:
    r"""Lateral-spreading kernel of the conductive rubber, :math:`\propto K_0(r/\lambda)`, ``g`` grid, sum 1.

    :math:`K_0` (modified Bessel function) is the Green's function of a thin
    resistive sheet on a conductive (leaky) base: a current injected at a
    point spreads as :math:`K_0(r/\lambda)/(2\pi\lambda^2)`, whose area
    integral is 1. The singular centre node takes the kernel's mean over its
    cell; truncated at :math:`8\lambda`. Read-only (cached).
    """
    return _leak(float(lam), float(g))


@lru_cache(maxsize=8)
def _leak(lam: float, g: float) -> np.ndarray:
    from scipy.special import k0

    m = int(math.ceil(8 * lam / g))
    r = np.arange(-m, m + 1) * g
    rr = np.hypot(r[:, None], r[None, :])
    k = np.where(rr <= 8 * lam, k0(np.maximum(rr, 1e-300) / lam), 0.0)
    # centre cell: mean of K0(r/lam) over a disc of the cell's area, 2 lam^2 (1 - (a/lam) K1(a/lam)) / a^2
    from scipy.special import k1

    a = g / math.sqrt(math.pi)
    k[m, m] = 2 * lam ** 2 * (1 - (a / lam) * k1(a / lam)) / a ** 2
    k /= k.sum()
    k.setflags(write=False)
    return k


@lru_cache(maxsize=8)
def _kernel(h: float, g: float, cutoff: float, leak: float) -> np.ndarray:
    """Boussinesq kernel at depth ``h`` (truncated at ``cutoff·h``), convolved with the rubber's leak; sum 1."""
    m = int(math.ceil(cutoff * h / g))
    r = np.arange(-m, m + 1) * g
    r2 = r[:, None] ** 2 + r[None, :] ** 2
    k = np.where(r2 <= (cutoff * h) ** 2, 1.0 / (r2 + h * h) ** 2.5, 0.0)
    k /= k.sum()
    if leak > 0:
        from scipy.signal import fftconvolve

        k = np.clip(fftconvolve(k, _leak(leak, g)), 0.0, None)
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
        self._kernel = _kernel(c.depth_of_spreading_mm, g, c.spread_cutoff, float(c.rubber_leak_mm))
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


Piezo16.register()
