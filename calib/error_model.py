"""A calibration's own error, measured on independent data (validation frames or gauge presses).

The curves' fit residuals say how well the curves follow the samples they
were fitted on; they say nothing of what those samples leave out (another
renderer, another batch of frames, the sensor drifting since). An honest
error bar needs the error measured where the calibration is used: on
independent readings of known forces. :class:`ErrorModel` is that error,
per axis, as a floor plus a part that grows with the load,

    sigma_axis(Fz) = sqrt(floor_axis^2 + (relative_axis Fz)^2),

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

__all__ = ["MIN_SAMPLES", "ErrorModel", "validate"]

#: Fewest loaded element samples an error model is fitted from.
MIN_SAMPLES = 20

_AXES = ("fx", "fy", "fz")


@dataclass(frozen=True, eq=False)
class ErrorModel:
    """Per-axis model error ``sqrt(floor^2 + (relative Fz)^2)`` (N), measured on independent data.

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

    Examples
    --------
    >>> m = ErrorModel([0.001, 0.001, 0.003], [0.005, 0.005, 0.01], samples=100)
    >>> m.sigma(np.array([0.0, 1.0])).round(4).tolist()
    [[0.001, 0.001, 0.003], [0.0051, 0.0051, 0.0104]]
    """

    floor_n: np.ndarray
    relative: np.ndarray
    samples: int
    source: str = ""

    def __post_init__(self) -> None:
        for name in ("floor_n", "relative"):
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

    def sigma(self, fz) -> np.ndarray:
        """The model error (..., 3) N for elements whose estimated normal force is ``fz`` (...,) N."""
        fz = np.maximum(np.asarray(fz, dtype=np.float64), 0.0)[..., None]
        return np.sqrt(self.floor_n**2 + (self.relative * fz) ** 2)

    @classmethod
    def fit(cls, residuals, noise_se, fz, *, source: str = "") -> ErrorModel:
        """Maximum-likelihood floor and relative part from residuals beside the readings' own noise.

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
        source : str

        Returns
        -------
        ErrorModel

        Raises
        ------
        ShapeError
            Shapes other than (n, 3), (n, 3), (n,).
        InputError
            Fewer than :data:`MIN_SAMPLES` samples, or values that are not finite.

        Notes
        -----
        Per axis, each residual is taken as ``N(0, s_i^2 + a^2 + b^2 fz_i^2)``
        with ``s_i`` its noise standard error, and ``(a, b) >= 0`` minimise
        the negative log-likelihood (L-BFGS-B, on residuals scaled to unit
        RMS). Starting from the residuals' RMS split evenly, the fit is
        deterministic.
        """
        from scipy.optimize import minimize

        res, se, f = (np.asarray(x, dtype=np.float64) for x in (residuals, noise_se, fz))
        n = len(res)
        if res.ndim != 2 or res.shape[1] != 3 or se.shape != res.shape or f.shape != (n,):
            raise ShapeError(f"residuals and noise_se must be (n, 3) and fz (n,), got {res.shape}, "
                             f"{se.shape} and {f.shape}")
        if n < MIN_SAMPLES:
            raise InputError(f"an error model needs at least {MIN_SAMPLES} loaded element samples, got {n}")
        if not (np.isfinite(res).all() and np.isfinite(se).all() and np.isfinite(f).all()):
            raise InputError("residuals, noise_se and fz must be finite")
        f = np.maximum(f, 0.0)
        floor, rel = np.zeros(3), np.zeros(3)
        for ax in range(3):
            scale = float(np.sqrt(np.mean(res[:, ax] ** 2)))
            if scale == 0.0:
                continue
            e2, s2, f2 = (res[:, ax] / scale) ** 2, (se[:, ax] / scale) ** 2, f**2
            f_rms = float(np.sqrt(np.mean(f2))) or 1.0

            def nll(p, e2=e2, s2=s2, f2=f2):
                v = np.maximum(s2 + p[0] ** 2 + p[1] ** 2 * f2, 1e-12)  # residuals are scaled to unit RMS
                dv = 0.5 * (1.0 / v - e2 / v**2)
                return 0.5 * float(np.sum(np.log(v) + e2 / v)), \
                    np.array([2.0 * p[0] * dv.sum(), 2.0 * p[1] * (dv * f2).sum()])

            start = np.array([np.sqrt(0.5), np.sqrt(0.5) / f_rms])
            best = minimize(nll, start, jac=True, method="L-BFGS-B", bounds=[(0.0, None)] * 2)
            floor[ax], rel[ax] = best.x * scale
        return cls(floor, rel, n, source)

    def to_dict(self) -> dict:
        """JSON-ready: ``floor_n`` and ``relative`` per axis, ``samples``, ``source``."""
        return {"floor_n": dict(zip(_AXES, self.floor_n.tolist(), strict=True)),
                "relative": dict(zip(_AXES, self.relative.tolist(), strict=True)),
                "samples": self.samples, "source": self.source}

    @classmethod
    def from_dict(cls, d) -> ErrorModel:
        """Build from :meth:`to_dict` output; InputError for a malformed one."""
        if not isinstance(d, dict) or not all(k in d for k in ("floor_n", "relative", "samples")):
            raise InputError("calibration 'error_model' must be an object with floor_n, relative and samples")
        from .document import numbers

        try:
            return cls(numbers([d["floor_n"][a] for a in _AXES], "calibration error_model['floor_n']"),
                       numbers([d["relative"][a] for a in _AXES], "calibration error_model['relative']"),
                       d["samples"], d.get("source", ""))
        except (KeyError, TypeError) as exc:
            raise InputError(f"calibration 'error_model' is malformed: {exc!r}") from None


def validate(cal, readings, forces, errors=None, *, source: str = ""):
    """``cal`` (a :class:`~optitact.calib.Calibration`) with its error measured on independent readings.

    The curves stay as they are; the residuals of ``cal.forces`` on
    readings the fit never saw (validation frames, or gauge presses of the
    sensor in use) give an :class:`ErrorModel` (a floor plus a part growing
    with Fz, per axis), fitted beside the readings' own noise, which
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
                           source=source or f"{len(truth)} validation frames")
    return replace(cal, error_model=model)

