"""A calibration's own error, measured on independent data (validation frames or gauge presses).

The curves' fit residuals say how well the curves follow the samples they
were fitted on; they say nothing of what those samples leave out (another
renderer, another batch of frames, the sensor drifting since). An honest
error bar needs the error measured where the calibration is used: on
independent readings of known forces. :class:`ErrorModel` is that error,
per axis, as a floor plus parts that grow with the load,

    sigma_axis(Fz, Ft) = sqrt(floor_axis^2 + (relative_axis Fz)^2 + (shear_axis Ft)^2
                              + (shear2_axis Ft^2)^2),

``Ft`` the magnitude of the element's estimated shear (parts chosen by the
likelihood of held-out validation frames: see :meth:`ErrorModel.fit`; the
last, second order in the shear, for Fz only: :data:`QUADRATIC_SHEAR`),
times a scale per ring of elements and axis (the camera sees the rings at
different angles, and the curves fit the outer ones worse),

fitted by maximum likelihood to the residuals beside the noise the readings
carried (their propagated standard errors), so that noise is not counted
twice. :func:`validate` (:meth:`optitact.calib.fit.Calibration.validated`) fits one;
:meth:`~optitact.calib.fit.Calibration.stderr` then adds it instead of the fit
residuals.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from optitact._validate import json_numbers
from optitact.errors import InputError, ShapeError

__all__ = ["MIN_GROUP_SAMPLES", "MIN_SAMPLES", "QUADRATIC_SHEAR", "ErrorModel", "validate"]

#: Fewest loaded element samples an error model is fitted from.
MIN_SAMPLES = 20

_AXES = ("fx", "fy", "fz")

#: Axes (Fx, Fy, Fz) whose error model has the part of second order in the shear, ``shear2 Ft^2``.
#: The coupled curves give Fz a term linear in the centroid shift, so what they leave of G's
#: dependence on the shear is of second order: without this part the linear one widens the intervals
#: of every sheared element to cover the few most sheared. Fx and Fy are the curves f(u) themselves,
#: whose error grows with the shear they read: for them it would take the linear part's place on the
#: most sheared elements and leave the intervals of little-sheared ones too narrow, so they have none.
#: The held-out figures that chose this: docs/results/accuracy.md.
QUADRATIC_SHEAR = (False, False, True)

#: A group of elements (a ring) with fewer loaded samples than this gets no scale of its own: the
#: largest group's.
MIN_GROUP_SAMPLES = 20
#: Bounds of a group's scale of the model error: ``exp(-3)`` to ``exp(3)``.
_LOG_SCALE_BOUND = 3.0


@dataclass(frozen=True, eq=False)
class ErrorModel:
    """Per-axis model error ``sqrt(floor^2 + (relative Fz)^2 + (shear Ft)^2 + (shear2 Ft^2)^2)`` (N).

    Parameters
    ----------
    floor_n : (3,) array_like
        The part that does not grow with the load, per axis (Fx, Fy, Fz), N.
    relative : (3,) array_like
        The part proportional to the element's normal force, per axis
        (N per N of Fz).
    samples : int
        Loaded element samples it was fitted on.
    source : str
        Where those samples came from (kept in the calibration's file).
    shear : (3,) array_like
        The part proportional to the magnitude of the element's estimated
        shear force ``Ft = hypot(Fx, Fy)``, per axis (N per N of Ft); default 0
        (a model fitted without it, or read from a file that has none).
    shear2 : (3,) array_like
        The part proportional to ``Ft^2``, per axis (N per N^2); default 0
        (:data:`QUADRATIC_SHEAR`: fitted for Fz only).
    element_scale : (E, 3) array_like, optional
        What each element's model error is times, per axis (> 0; fitted per
        ring of elements, their loaded samples' mean square 1); default
        None: 1 everywhere (a model fitted without the elements, or read
        from a file that has none). :meth:`at` applies it; :meth:`sigma`
        is the error before it.

    Examples
    --------
    >>> m = ErrorModel([0.001, 0.001, 0.003], [0.005, 0.005, 0.01], samples=100)
    >>> m.sigma(np.array([0.0, 1.0])).round(4).tolist()
    [[0.001, 0.001, 0.003], [0.0051, 0.0051, 0.0104]]
    >>> ErrorModel([0.001] * 3, [0.0] * 3, 100, shear=[0.01, 0.01, 0.0]).sigma(0.5, 0.2).round(4).tolist()
    [0.0022, 0.0022, 0.001]
    """

    floor_n: np.ndarray
    relative: np.ndarray
    samples: int
    source: str = ""
    shear: np.ndarray = (0.0, 0.0, 0.0)
    shear2: np.ndarray = (0.0, 0.0, 0.0)
    element_scale: np.ndarray | None = None

    def __post_init__(self) -> None:
        for name in ("floor_n", "relative", "shear", "shear2"):
            a = np.array(getattr(self, name), dtype=np.float64)
            if a.shape != (3,):
                raise ShapeError(f"{name} must have shape (3,) (Fx, Fy, Fz), got {a.shape}")
            if not (np.isfinite(a).all() and (a >= 0).all()):
                raise InputError(f"{name} must be finite and >= 0, got {a.tolist()}")
            a.flags.writeable = False
            object.__setattr__(self, name, a)
        if isinstance(self.samples, bool) or not isinstance(self.samples, (int, np.integer)) \
                or self.samples < 1:
            raise InputError(f"samples must be an integer >= 1, got {self.samples!r}")
        object.__setattr__(self, "samples", int(self.samples))
        if not isinstance(self.source, str):
            raise TypeError(f"source must be a string, got {type(self.source).__name__}")
        if self.element_scale is not None:
            a = np.array(self.element_scale, dtype=np.float64)
            if a.ndim != 2 or a.shape[1] != 3 or len(a) == 0:
                raise ShapeError(f"element_scale must have shape (E, 3) (Fx, Fy, Fz per element), got "
                                 f"{a.shape}")
            if not (np.isfinite(a).all() and (a > 0).all()):
                raise InputError("element_scale must be finite and > 0")
            a.flags.writeable = False
            object.__setattr__(self, "element_scale", a)

    def sigma(self, fz, ft=0.0) -> np.ndarray:
        """The model error (..., 3) N of elements of estimated normal force ``fz`` and shear ``ft`` (N)."""
        fz = np.maximum(np.asarray(fz, dtype=np.float64), 0.0)[..., None]
        ft = np.abs(np.asarray(ft, dtype=np.float64))[..., None]
        return np.sqrt(self.floor_n**2 + (self.relative * fz) ** 2 + (self.shear * ft) ** 2
                       + (self.shear2 * ft**2) ** 2)

    def at(self, forces) -> np.ndarray:
        """The model error (..., E, 3) N of estimated element-local forces ``forces`` (..., E, 3) N.

        With :attr:`element_scale`, the second-last axis is the elements'
        (ShapeError if it is not E long); without it any (..., 3) is taken.
        """
        f = np.asarray(forces, dtype=np.float64)
        out = self.sigma(f[..., 2], np.hypot(f[..., 0], f[..., 1]))
        if self.element_scale is None:
            return out
        if f.ndim < 2 or f.shape[-2] != len(self.element_scale):
            raise ShapeError(f"forces must have shape (..., {len(self.element_scale)}, 3) for an error model "
                             f"with a scale per element, got {f.shape}")
        return out * self.element_scale

    @classmethod
    def fit(cls, residuals, noise_se, fz, ft=None, *, element=None, element_group=None,
            source: str = "") -> ErrorModel:
        """Maximum-likelihood floor, relative and shear parts from residuals beside the readings' own noise.

        Parameters
        ----------
        residuals : (n, 3) array_like
            Estimated minus true force per loaded element sample, N.
        noise_se : (n, 3) array_like
            The standard errors the readings' noise alone gives those
            estimates (:meth:`~optitact.calib.fit.Calibration.stderr` without the
            model error), N; zeros to let the model take the noise too.
        fz : (n,) array_like
            The estimated normal forces, N (what :meth:`sigma` is given in use).
        ft : (n,) array_like, optional
            The estimated shear magnitudes ``hypot(Fx, Fy)``, N; without them
            the model has no shear parts.
        element : (n,) array_like of int, optional
            Each sample's element, with ``element_group``: the model error
            then has a scale per group and axis (:attr:`element_scale`).
        element_group : (E,) array_like of int, optional
            Each element's group (the sensor's rings: ``element_ring``).
            A group with fewer than :data:`MIN_GROUP_SAMPLES` samples gets
            the largest group's scale.
        source : str

        Returns
        -------
        ErrorModel

        Raises
        ------
        ShapeError
            Shapes other than (n, 3), (n, 3), (n,) (and (n,) for ``ft`` and
            ``element``), or an element outside ``element_group``.
        InputError
            Fewer than :data:`MIN_SAMPLES` samples, values that are not
            finite, or only one of ``element`` and ``element_group``.

        Notes
        -----
        Per axis, each residual is taken as ``N(0, s_i^2 + k_g^2 (a^2 + b^2
        fz_i^2 + c^2 ft_i^2 + d^2 ft_i^4))`` with ``s_i`` its noise standard
        error, ``g`` its element's group (``k = 1`` without groups) and ``d``
        for the axes of :data:`QUADRATIC_SHEAR` only, else 0; ``(a, b, c, d)
        >= 0`` and the groups' ``log k`` (in +-3; the largest group's 0)
        minimise the negative log-likelihood (L-BFGS-B over the squares, on
        residuals scaled to unit RMS); the scales are then normalised to a
        mean square of 1 over the samples. Starting from the residuals'
        variance split evenly and every ``k`` 1, the fit is deterministic.

        Every part is there because the held-out likelihood chose it (five-fold
        cross-validation by frames of the accuracy bench's validation frames;
        the figures are in docs/results/accuracy.md). The scale is per ring,
        not per element: a sensor's own presses give few samples per element.
        """
        from scipy.optimize import minimize

        res, se, f = (np.asarray(x, dtype=np.float64) for x in (residuals, noise_se, fz))
        n = len(res)
        t = np.zeros(n) if ft is None else np.asarray(ft, dtype=np.float64)
        if res.ndim != 2 or res.shape[1] != 3 or se.shape != res.shape or f.shape != (n,) or t.shape != (n,):
            raise ShapeError(f"residuals and noise_se must be (n, 3) and fz and ft (n,), got {res.shape}, "
                             f"{se.shape}, {f.shape} and {t.shape}")
        if n < MIN_SAMPLES:
            raise InputError(f"an error model needs at least {MIN_SAMPLES} loaded element samples, got {n}")
        if not all(np.isfinite(x).all() for x in (res, se, f, t)):
            raise InputError("residuals, noise_se, fz and ft must be finite")
        groups, element_group = _groups(element, element_group, n)
        n_groups = int(groups.max()) + 1
        counts = np.bincount(groups, minlength=n_groups)
        ref = int(np.argmax(counts))
        own = [g for g in range(n_groups) if g != ref and counts[g] >= MIN_GROUP_SAMPLES]  # their own scale
        # the parts' variances are linear in these: 1, fz^2, ft^2, ft^4
        features = np.stack([np.ones(n), np.maximum(f, 0.0) ** 2, t**2, t**4], axis=1)
        parts = np.zeros((3, 4))  # axis x (floor, relative, shear, shear2)
        scales = np.ones((n_groups, 3))
        for ax in range(3):
            scale = float(np.sqrt(np.mean(res[:, ax] ** 2)))
            if scale == 0.0:
                continue
            used = [0, 1] + ([] if ft is None else [2, 3] if QUADRATIC_SHEAR[ax] else [2])
            e2, s2, x2 = (res[:, ax] / scale) ** 2, (se[:, ax] / scale) ** 2, features[:, used]
            mean = x2.mean(axis=0)
            mean[mean == 0.0] = 1.0
            k = len(used)

            def nll(p, e2=e2, s2=s2, x2=x2, k=k):  # p: the parts' variances (their gradient is not 0 at 0),
                log_k = np.zeros(n_groups)           # then the groups' log scales
                log_k[own] = p[k:]
                m, k2 = x2 @ p[:k], np.exp(2.0 * log_k)[groups]
                v = np.maximum(s2 + k2 * m, 1e-12)  # residuals are scaled to unit RMS
                dv = 0.5 * (1.0 / v - e2 / v**2)
                d_log = np.bincount(groups, 2.0 * dv * k2 * m, minlength=n_groups)[own]
                return 0.5 * float(np.sum(np.log(v) + e2 / v)), np.concatenate([(dv * k2) @ x2, d_log])

            start = np.concatenate([1.0 / k / mean, np.zeros(len(own))])  # each part an equal share
            bounds = [(0.0, None)] * k + [(-_LOG_SCALE_BOUND, _LOG_SCALE_BOUND)] * len(own)
            best = minimize(nll, start, jac=True, method="L-BFGS-B", bounds=bounds)
            k_ax = np.ones(n_groups)
            k_ax[own] = np.exp(best.x[k:])
            norm = np.sqrt(np.mean(k_ax[groups] ** 2))  # the samples' mean square scale: 1
            scales[:, ax] = k_ax / norm
            parts[ax, used] = np.sqrt(best.x[:k]) * scale * norm
        element_scale = None if element_group is None else scales[element_group]
        return cls(parts[:, 0], parts[:, 1], n, source, shear=parts[:, 2], shear2=parts[:, 3],
                   element_scale=element_scale)

    def to_dict(self) -> dict:
        """JSON-ready: the parts per axis, ``samples``, ``source`` and any ``element_scale``.

        The parts are ``floor_n``, ``relative``, ``shear`` and ``shear2``;
        ``element_scale`` is per axis a list over the elements.
        """
        out = {"floor_n": dict(zip(_AXES, self.floor_n.tolist(), strict=True)),
               "relative": dict(zip(_AXES, self.relative.tolist(), strict=True)),
               "shear": dict(zip(_AXES, self.shear.tolist(), strict=True)),
               "shear2": dict(zip(_AXES, self.shear2.tolist(), strict=True)),
               "samples": self.samples, "source": self.source}
        if self.element_scale is not None:
            out["element_scale"] = dict(zip(_AXES, self.element_scale.T.tolist(), strict=True))
        return out

    @classmethod
    def from_dict(cls, d) -> ErrorModel:
        """Build from :meth:`to_dict` output; InputError for a malformed one."""
        if not isinstance(d, dict) or not all(k in d for k in ("floor_n", "relative", "samples")):
            raise InputError("calibration 'error_model' must be an object with floor_n, relative and samples")

        def part(name):  # files written before a part was added have none
            return (0.0, 0.0, 0.0) if d.get(name) is None else \
                json_numbers([d[name][a] for a in _AXES], f"calibration error_model[{name!r}]")

        try:
            scale = d.get("element_scale")  # files written before the scales have none
            if scale is not None:
                scale = np.stack([json_numbers(scale[a], f"calibration error_model['element_scale'][{a!r}]")
                                  for a in _AXES], axis=1)
            return cls(json_numbers([d["floor_n"][a] for a in _AXES], "calibration error_model['floor_n']"),
                       json_numbers([d["relative"][a] for a in _AXES], "calibration error_model['relative']"),
                       d["samples"], d.get("source", ""), shear=part("shear"), shear2=part("shear2"),
                       element_scale=scale)
        except (KeyError, TypeError, ValueError) as exc:
            raise InputError(f"calibration 'error_model' is malformed: {exc!r}") from None


def _groups(element, element_group, n: int) -> tuple[np.ndarray, np.ndarray | None]:
    """Each sample's group (n,) (all 0 without groups) and the elements' groups (E,) (or None), checked."""
    if (element is None) != (element_group is None):
        raise InputError("give both element and element_group (or neither)")
    if element is None:
        return np.zeros(n, np.intp), None
    el, grp = np.asarray(element), np.asarray(element_group)
    if el.shape != (n,) or grp.ndim != 1 or el.dtype.kind not in "iu" or grp.dtype.kind not in "iu":
        raise ShapeError(f"element must be (n,) = ({n},) integers and element_group (E,) integers, got "
                         f"{el.shape} {el.dtype} and {grp.shape} {grp.dtype}")
    if el.size and (el.min() < 0 or el.max() >= len(grp)) or (grp.size and grp.min() < 0):
        raise ShapeError(f"element must index element_group's {len(grp)} elements and groups be >= 0")
    _, grp = np.unique(grp, return_inverse=True)  # groups numbered 0 .. G-1
    return grp[el].astype(np.intp), grp.astype(np.intp)


def validate(cal, readings, forces, errors=None, *, source: str = ""):
    """``cal`` (a :class:`~optitact.calib.fit.Calibration`) with its error measured on independent readings.

    The curves stay as they are; the residuals of ``cal.forces`` on
    readings the fit never saw (validation frames, or gauge presses of the
    sensor in use) give an :class:`ErrorModel` (a floor plus parts growing
    with Fz and with the shear, per axis, times a scale per ring of
    elements), fitted beside the readings' own noise, which
    :meth:`~optitact.calib.fit.Calibration.stderr` then adds instead of the fit
    residuals. In-sample residuals miss what the calibration samples leave
    out, so without this the error bars are too narrow wherever the
    calibration is used on other frames.

    Parameters
    ----------
    cal : Calibration
    readings : Readings
        Stack readings (T, E) of the validation frames.
    forces : (T, E, 3) array_like
        Their true element-local forces, N; samples with ``Fz > 0`` count.
    errors : ReadingErrors, optional
        The readings' covariance (:func:`optitact.pipeline.uncertainty.reading_errors`),
        propagated and set beside the residuals: pass it when the
        calibration will be used with ``errors`` too (otherwise the model
        error takes the frames' noise as well).
    source : str
        Where the validation data came from (kept in the file).

    Returns
    -------
    Calibration

    Raises
    ------
    ShapeError
        ``forces`` is not (T, E, 3) for stack readings of E elements.
    InputError
        Fewer than :data:`MIN_SAMPLES` loaded samples.
    """
    from optitact.calib import propagation

    cal.check_readings(readings)
    truth = np.asarray(forces, dtype=np.float64)
    if not readings.is_stack or truth.shape != np.shape(readings.G) + (3,):
        raise ShapeError(f"forces must have shape (T, E, 3) = {np.shape(readings.G) + (3,)} for stack "
                         f"readings, got {truth.shape}")
    est = cal.forces(readings)[0]
    noise = (propagation.stderr(cal, readings, errors, with_model_error=False) if errors is not None
             else np.zeros_like(est))
    loaded = truth[..., 2] > 0
    model = ErrorModel.fit((est - truth)[loaded], noise[loaded], est[..., 2][loaded],
                           np.hypot(est[..., 0], est[..., 1])[loaded], element=np.nonzero(loaded)[-1],
                           element_group=cal.sensor.element_ring,
                           source=source or f"{len(truth)} validation frames")
    return replace(cal, error_model=model)

