r"""3-D force from the fingertip's non-coplanar units: plane resultants, ranges, calibrated decoupling.

The published decoupling of :class:`~optitact.taxels.fingertip25.Fingertip25`
sums each plane's unit readings along the axis it measures
(:func:`plane_resultants`, :func:`decouple`); the ranges follow from the unit
range and the formula (:func:`detection_ranges`, :func:`axis_ranges`). A
calibrated linear decoupling (:class:`DecouplingMatrix`) removes the linear
crosstalk the formula leaves. :func:`repeatability_error` is the usual
:math:`\delta_R = Z s / Y_{FS}` of repeated loadings.

Convention: the fingertip frame and the 5×5 unit grid of
:mod:`optitact.taxels.fingertip25`.

Examples
--------
>>> r = detection_ranges()
>>> [round(float(v), 2) for v in (r["low_n"][1], r["high_n"][1])]      # plane 2: 4 F_s cos 77.25 deg
[0.18, 4.41]
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from optitact._validate import finite, float_like, positive, real_array
from optitact.errors import InputError, ShapeError
from optitact.taxels.base import check_config, freeze_fields
from optitact.taxels.fingertip25 import (PLANE_AXIS, UNIT_PLANE, UNIT_SIDE, Fingertip25Config, check_unit_grid,
                                         force_from_resistance)

__all__ = ["plane_resultants", "decouple", "detection_ranges", "axis_ranges", "DecouplingMatrix",
           "repeatability_error"]


_UNITS = ("N", "kOhm")


def _unit_values(values, units: str, config) -> np.ndarray:
    if units not in _UNITS:
        raise InputError(f"units must be one of {_UNITS}, got {units!r}")
    arr = check_unit_grid(values, "values")
    if units == "kOhm":
        return force_from_resistance(arr, config=config)
    if arr.size and arr.min() < 0:
        raise InputError(f"unit forces must be >= 0, got minimum {arr.min()}")
    return arr


def plane_resultants(values, *, units: str = "N",
                     config: Fingertip25Config | None = None) -> dict[str, np.ndarray]:
    r"""Published plane resultants :math:`F_1` to :math:`F_5` of unit readings.

    Parameters
    ----------
    values : (..., 5, 5) array
        Unit normal forces (N) or resistances (kΩ, converted by
        :func:`~optitact.taxels.fingertip25.force_from_resistance`).
    units : {"N", "kOhm"}
    config : Fingertip25Config, optional
        Plane angles and resistance law; defaults to ``Fingertip25Config()``.

    Returns
    -------
    dict
        ``F1`` ... ``F5``, each of shape ``values.shape[:-2]``, N, along the
        plane's axis (:data:`~optitact.taxels.fingertip25.PLANE_AXIS`); float32 if ``values`` is.

    Raises
    ------
    ShapeError
        If the trailing dimensions are not (5, 5).
    InputError
        For an unknown ``units``, non-finite values, negative forces or resistances <= 0.

    Notes
    -----
    :math:`F_k = \cos\theta_k \sum_{i \in k} s_i f_i`, :math:`s_i = \pm 1`
    the unit's side (:data:`~optitact.taxels.fingertip25.UNIT_SIDE`). With one common reading
    :math:`F_s` on the + side this is the published
    :math:`F_1 = 8 F_s`, :math:`F_2 = 4 F_s \cos 77.25°`,
    :math:`F_3 = 2 F_s \cos 62.09°`, :math:`F_4 = 2 F_s \cos 46.47°`,
    :math:`F_5 = 3 F_s \cos 9.03°`.
    """
    c = check_config(config, Fingertip25Config)
    f = _unit_values(values, units, c)
    cos_plane = np.cos(np.deg2rad(c.plane_angles_deg))
    return {f"F{k}": float_like(cos_plane[k - 1] * np.sum(np.where(UNIT_PLANE == k, UNIT_SIDE * f, 0.0),
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
    >>> from optitact.taxels.fingertip25 import Fingertip25, Fingertip25Config
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
    c = check_config(config, Fingertip25Config)
    n = np.asarray(c.plane_units, dtype=float)
    ang = np.asarray(c.plane_angles_deg)
    factor = n * np.cos(np.deg2rad(ang))
    return {"plane": np.arange(1, 6), "axis": np.array(PLANE_AXIS), "n_units": n.astype(int), "angle_deg": ang,
            "factor": factor, "low_n": c.force_low_n * factor, "high_n": c.force_high_n * factor}


def axis_ranges(*, config: Fingertip25Config | None = None) -> dict[str, tuple[float, float]]:
    """Range of the force magnitude along each axis (one side): all units of the axis at the range's ends.

    Returns
    -------
    dict
        ``{"x": (low, high), "y": ..., "z": ...}`` in N; the x range holds for
        either sign, y and z only for positive values.
    """
    c = check_config(config, Fingertip25Config)
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
        freeze_fields(self, matrix=m, offset=b)

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
        f = check_unit_grid(unit_force_n, "unit_force_n")
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
        f = check_unit_grid(unit_force_n, "unit_force_n")
        return f.reshape(*f.shape[:-2], 25) @ self.matrix.T + self.offset


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

