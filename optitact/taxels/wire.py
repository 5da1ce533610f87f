"""The wire-handling chain of the 5×5 optoelectronic pad: offset, normalisation, wire shape, diameter table.

Sensor-independent analyses of small taxel images (they work on a real pad's
samples as well as on :class:`~optitact.taxels.opto5.Opto5` frames):

1. offset removal (:func:`remove_offset`),
2. per-taxel linearising normalisation from a calibration closure
   (:class:`NormalisationLUT`; :func:`calibration_closure` simulates one),
3. wire shape from the normalised image (:func:`wire_shape`),
4. wire diameter from ``(finger distance, summed normalised values)`` with a
   2-D lookup table (:class:`LookupTableClassifier`).

The learnt classifiers and the whole study are ``optitact.studies.run("wire")``.

Convention: taxel indices are ``(row, col)``, ``(0, 0)`` top-left; the
layout frame has x along columns and y along rows (mm), origin at the pad
centre (:mod:`optitact.taxels.sources`).

Examples
--------
>>> lut = LookupTableClassifier.from_table(
...     [218], [1.5, 2.0, 2.5, 3.0, 3.5, 4.0],
...     [[0.9518, 2.2716, 3.0802, 3.5735, 6.2054, 7.9888]])
>>> float(lut.predict(218, 3.2))
2.5
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from optitact._optional import require
from optitact._validate import finite, float_like, integer, positive, real_array
from optitact.errors import InputError, ShapeError
from optitact.taxels.sources import Indenter, Layout, Scenario, moments
from optitact.taxels.base import freeze_fields
from optitact.taxels.opto5 import FINGER_DISTANCE_MAX, Opto5, check_finger_distance

__all__ = [
    "remove_offset", "NormalisationLUT", "calibration_closure", "hold_response", "WireShape", "main_direction",
    "wire_centroids", "wire_shape", "LookupTableClassifier",
]


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
    return float_like(arr - arr[:n].mean(axis=0), v)


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
        IsotonicRegression = require("sklearn.isotonic", purpose="the normalisation tables").IsotonicRegression

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
        return float_like(out, dv)

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


def hold_response(source: Opto5, scenario: Scenario, *, n_base: int, n_hold: int, seed) -> np.ndarray:
    """Mean offset-removed response (H, W), V, of ``source.frames(scenario)``: its last ``n_hold`` samples."""
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


def main_direction(v: np.ndarray, pitch: float) -> str:
    """``"horizontal"`` or ``"vertical"``: the axis with the larger second moment of the image ``v``."""
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
        direction = main_direction(v, pitch)
    cent = wire_centroids(v, direction=direction, pitch_mm=pitch)
    ok = cent["valid"]
    if ok.sum() < 3:
        raise InputError(f"a quadratic needs at least 3 columns with positive values along the wire, "
                         f"got {ok.sum()}")
    x, y = cent["x_mm"][ok], cent["y_mm"][ok]
    coef, *_ = np.linalg.lstsq(np.stack([x * x, x, np.ones_like(x)], axis=1), y, rcond=None)
    return WireShape(float(coef[0]), float(coef[1]), float(coef[2]), direction)


# ---- diameter lookup table ----------------------------------------------------------------------------
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
        p = check_finger_distance(self.finger_distance)
        k = finite(real_array(self.classes, "classes"), "classes")
        t = finite(real_array(self.table, "table"), "table")
        if p.ndim != 1 or p.size < 1 or np.any(np.diff(p) <= 0):
            raise InputError(f"finger_distance must be a non-empty strictly increasing 1-D array, got {p!r}")
        if k.ndim != 1 or k.size < 2 or np.unique(k).size != k.size:
            raise InputError(f"classes must be at least 2 distinct labels, got {k!r}")
        if t.shape != (p.size, k.size):
            raise ShapeError(f"table must have shape (len(finger_distance), len(classes)) = "
                             f"{(p.size, k.size)}, got {t.shape}")
        freeze_fields(self, finger_distance=p, classes=k, table=t)

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
        p = np.rint(check_finger_distance(finger_distance))
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
        p = check_finger_distance(finger_distance)
        cols = [np.interp(p, self.finger_distance, self.table[:, k]) for k in range(self.classes.size)]
        return np.stack(cols, axis=-1)

    def predict(self, finger_distance, total) -> np.ndarray:
        """Class whose expected sum at ``finger_distance`` is nearest to ``total`` (arrays broadcast)."""
        p = check_finger_distance(finger_distance)
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
