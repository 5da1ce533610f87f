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

fitted by maximum likelihood to the residuals beside the noise the readings
carried (their propagated standard errors), so that noise is not counted
twice. :func:`validate` (:meth:`optitact.calib.Calibration.validated`) fits one;
:meth:`~optitact.calib.Calibration.stderr` then adds it instead of the fit
residuals.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from optitact.errors import InputError, ShapeError

__all__ = ["MIN_SAMPLES", "QUADRATIC_SHEAR", "ErrorModel", "validate"]

#: Fewest loaded element samples an error model is fitted from.
MIN_SAMPLES = 20

_AXES = ("fx", "fy", "fz")

#: Axes (Fx, Fy, Fz) whose error model has the part of second order in the shear, ``shear2 Ft^2``.
#: The coupled curves give Fz a term linear in the centroid shift, so what they leave of G's
#: dependence on the shear is of second order; Fx and Fy are the curves f(u) themselves, whose
#: error grows with the shear they read. On the accuracy bench's 60 path-traced validation frames
#: the Fz error beyond the noise was 0-5 mN below Ft = 0.25 N and 12-17 mN above it, where the
#: linear part alone set 8 mN at 0.2 N: it widened the intervals of every sheared element to
#: cover the few most sheared (the single, checkerboard and shear families' Fz intervals held
#: 0.94, 0.93 and 0.95 of the true forces); with the quadratic part the held-out families'
#: log-likelihood in Fz rose by 63 and those fractions fell to 0.93, 0.92 and 0.93. For Fx and Fy
#: it would move their shear part to the few most sheared elements and leave the clustered family
#: (little shear) at 0.875-0.88, so they have none.
QUADRATIC_SHEAR = (False, False, True)


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

    def sigma(self, fz, ft=0.0) -> np.ndarray:
        """The model error (..., 3) N of elements of estimated normal force ``fz`` and shear ``ft`` (N)."""
        fz = np.maximum(np.asarray(fz, dtype=np.float64), 0.0)[..., None]
        ft = np.abs(np.asarray(ft, dtype=np.float64))[..., None]
        return np.sqrt(self.floor_n**2 + (self.relative * fz) ** 2 + (self.shear * ft) ** 2
                       + (self.shear2 * ft**2) ** 2)

    def at(self, forces) -> np.ndarray:
        """The model error (..., 3) N of estimated element-local forces ``forces`` (..., 3) N."""
        f = np.asarray(forces, dtype=np.float64)
        return self.sigma(f[..., 2], np.hypot(f[..., 0], f[..., 1]))

    @classmethod
    def fit(cls, residuals, noise_se, fz, ft=None, *, source: str = "") -> ErrorModel:
        """Maximum-likelihood floor, relative and shear parts from residuals beside the readings' own noise.

        Parameters
        ----------
        residuals : (n, 3) array_like
            Estimated minus true force per loaded element sample, N.
        noise_se : (n, 3) array_like
            The standard errors the readings' noise alone gives those
            estimates (:meth:`~optitact.calib.Calibration.stderr` without the
            model error), N; zeros to let the model take the noise too.
        fz : (n,) array_like
            The estimated normal forces, N (what :meth:`sigma` is given in use).
        ft : (n,) array_like, optional
            The estimated shear magnitudes ``hypot(Fx, Fy)``, N; without them
            the model has no shear parts.
        source : str

        Returns
        -------
        ErrorModel

        Raises
        ------
        ShapeError
            Shapes other than (n, 3), (n, 3), (n,) (and (n,) for ``ft``).
        InputError
            Fewer than :data:`MIN_SAMPLES` samples, or values that are not finite.

        Notes
        -----
        Per axis, each residual is taken as ``N(0, s_i^2 + a^2 + b^2 fz_i^2 +
        c^2 ft_i^2 + d^2 ft_i^4)`` with ``s_i`` its noise standard error (``d``
        for the axes of :data:`QUADRATIC_SHEAR` only, else 0), and ``(a, b, c,
        d) >= 0`` minimise the negative log-likelihood (L-BFGS-B over the squares,
        on residuals scaled to unit RMS). Starting from the residuals'
        variance split evenly, the fit is deterministic.

        The shear part is there because the held-out likelihood chose it: on
        the accuracy bench's 60 path-traced validation frames (ten of each
        load family), five-fold cross-validation by frames gave a negative
        log-likelihood of -23,316 with it against -23,230 without (a part in
        each element's neighbours' load contrast or mean load changed it by
        under 2).
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
        # the parts' variances are linear in these: 1, fz^2, ft^2, ft^4
        features = np.stack([np.ones(n), np.maximum(f, 0.0) ** 2, t**2, t**4], axis=1)
        parts = np.zeros((3, 4))  # axis x (floor, relative, shear, shear2)
        for ax in range(3):
            scale = float(np.sqrt(np.mean(res[:, ax] ** 2)))
            if scale == 0.0:
                continue
            used = [0, 1] + ([] if ft is None else [2, 3] if QUADRATIC_SHEAR[ax] else [2])
            e2, s2, x2 = (res[:, ax] / scale) ** 2, (se[:, ax] / scale) ** 2, features[:, used]
            mean = x2.mean(axis=0)
            mean[mean == 0.0] = 1.0

            def nll(q, e2=e2, s2=s2, x2=x2):  # q: the parts' variances (their gradient is not 0 at q = 0)
                v = np.maximum(s2 + x2 @ q, 1e-12)  # residuals are scaled to unit RMS
                dv = 0.5 * (1.0 / v - e2 / v**2)
                return 0.5 * float(np.sum(np.log(v) + e2 / v)), dv @ x2

            start = 1.0 / len(used) / mean  # each part an equal share of the residuals' variance
            best = minimize(nll, start, jac=True, method="L-BFGS-B", bounds=[(0.0, None)] * len(used))
            parts[ax, used] = np.sqrt(best.x) * scale
        return cls(parts[:, 0], parts[:, 1], n, source, shear=parts[:, 2], shear2=parts[:, 3])

    def to_dict(self) -> dict:
        """JSON-ready: ``floor_n``, ``relative``, ``shear`` and ``shear2`` per axis, ``samples``, ``source``."""
        return {"floor_n": dict(zip(_AXES, self.floor_n.tolist(), strict=True)),
                "relative": dict(zip(_AXES, self.relative.tolist(), strict=True)),
                "shear": dict(zip(_AXES, self.shear.tolist(), strict=True)),
                "shear2": dict(zip(_AXES, self.shear2.tolist(), strict=True)),
                "samples": self.samples, "source": self.source}

    @classmethod
    def from_dict(cls, d) -> ErrorModel:
        """Build from :meth:`to_dict` output; InputError for a malformed one."""
        if not isinstance(d, dict) or not all(k in d for k in ("floor_n", "relative", "samples")):
            raise InputError("calibration 'error_model' must be an object with floor_n, relative and samples")
        from .document import numbers

        def part(name):  # files written before a part was added have none
            return (0.0, 0.0, 0.0) if d.get(name) is None else \
                numbers([d[name][a] for a in _AXES], f"calibration error_model[{name!r}]")

        try:
            return cls(numbers([d["floor_n"][a] for a in _AXES], "calibration error_model['floor_n']"),
                       numbers([d["relative"][a] for a in _AXES], "calibration error_model['relative']"),
                       d["samples"], d.get("source", ""), shear=part("shear"), shear2=part("shear2"))
        except (KeyError, TypeError) as exc:
            raise InputError(f"calibration 'error_model' is malformed: {exc!r}") from None


def validate(cal, readings, forces, errors=None, *, source: str = ""):
    """``cal`` (a :class:`~optitact.calib.Calibration`) with its error measured on independent readings.

    The curves stay as they are; the residuals of ``cal.forces`` on
    readings the fit never saw (validation frames, or gauge presses of the
    sensor in use) give an :class:`ErrorModel` (a floor plus parts growing
    with Fz and with the shear, per axis), fitted beside the readings' own noise, which
    :meth:`~optitact.calib.Calibration.stderr` then adds instead of the fit
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
        The readings' covariance (:func:`optitact.uncertainty.reading_errors`),
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
    from . import propagation

    cal._check(readings)
    truth = np.asarray(forces, dtype=np.float64)
    if not readings.is_stack or truth.shape != np.shape(readings.G) + (3,):
        raise ShapeError(f"forces must have shape (T, E, 3) = {np.shape(readings.G) + (3,)} for stack "
                         f"readings, got {truth.shape}")
    est = cal.forces(readings)[0]
    noise = (propagation.stderr(cal, readings, errors, with_model_error=False) if errors is not None
             else np.zeros_like(est))
    loaded = truth[..., 2] > 0
    model = ErrorModel.fit((est - truth)[loaded], noise[loaded], est[..., 2][loaded],
                           np.hypot(est[..., 0], est[..., 1])[loaded],
                           source=source or f"{len(truth)} validation frames")
    return replace(cal, error_model=model)

