"""Error propagation through a calibration: the Jacobian of its forces, its model error, standard errors.

:class:`~optitact.calib.fit.Calibration` exposes these as methods
(:meth:`~optitact.calib.fit.Calibration.jacobian`,
:meth:`~optitact.calib.fit.Calibration.model_error`,
:meth:`~optitact.calib.fit.Calibration.stderr`); the readings' own covariance
comes from :func:`optitact.pipeline.uncertainty.reading_errors`.
"""

from __future__ import annotations

import numpy as np

from optitact.errors import ShapeError
from optitact.pipeline.readings import Readings

from optitact.calib.curves import G_TERMS

__all__ = ["jacobian", "model_error", "stderr"]


def jacobian(cal, readings: Readings) -> np.ndarray:
    r"""Derivatives of the estimated forces with respect to every element's reading.

    Returns
    -------
    (E, 3, E, 3) or (T, E, 3, E, 3) ndarray
        ``J[..., e, a, j, b] = d F[e, a] / d x[j, b]`` with ``F = (Fx, Fy,
        Fz)`` (N) and ``x = (G, ux, uy)`` (the readings' units); zero in
        the rows of elements without contact.

    Notes
    -----
    Each element's own block is a central difference of the curves
    (steps ``1e-4 g_scale`` in G, ``1e-4 u_scale`` in u). With a
    cross-talk model the forces solve ``Fz = g(G_iso, u)``, ``G_iso = G
    exp(W Fz)`` (:mod:`optitact.calib.crosstalk`); differentiating that
    fixed point (the implicit-function theorem) gives, with ``a_e = G_iso,e
    dg_e/dG_iso`` and ``b_e = dg_e/du``,

    .. math::

        dFz = (I - \mathrm{diag}(a) W_c)^{-1} (\mathrm{diag}(a / G)\,dG + \mathrm{diag}(b)\,du),

    ``W_c`` the coupling to the elements in contact, and the shear
    follows through ``G_iso``. It is exact to first order at the
    converged fixed point.
    """
    local, g_point = _local_jacobian(cal, readings)
    lead, n_el = local.shape[:-3], local.shape[-3]
    contact = np.asarray(readings.contact, bool)
    eye = np.eye(n_el)
    if cal.crosstalk is None:
        out = np.einsum("...eab,ej->...eajb", local, eye)
    else:
        w = cal.crosstalk.matrix(cal.sensor) * contact[..., None, :]
        G = np.where(contact, readings.G, 1.0)
        a = local[..., 2, 0] * g_point                                  # (..., E)
        m = np.linalg.inv(eye - a[..., :, None] * w)                   # (..., E, E)
        r = np.concatenate([(a / G)[..., None], local[..., 2, 1:]], axis=-1)   # (..., E, 3)
        dfz = m[..., :, :, None] * r[..., None, :, :]                  # (..., E, E, 3)
        own = np.zeros(lead + (n_el, n_el, 3))
        own[..., np.arange(n_el), np.arange(n_el), 0] = 1.0 / G
        dgiso = g_point[..., :, None, None] * (own + np.einsum("...ek,...kjb->...ejb", w, dfz))
        out = np.empty(lead + (n_el, 3, n_el, 3))
        out[..., :2, :, :] = local[..., :2, 0, None, None] * dgiso[..., :, None, :, :]
        out[..., :2, :, 1:] += np.einsum("...eab,ej->...eajb", local[..., :2, 1:], eye)
        out[..., 2, :, :] = dfz
    return np.where(contact[..., None, None, None], out, 0.0)


def _local_jacobian(cal, readings: Readings) -> tuple[np.ndarray, np.ndarray]:
    """Each element's own curves differentiated at its reading: (..., E, 3, 3), and the G used."""
    cal.check_readings(readings)
    G, u = np.asarray(readings.G, np.float64), np.asarray(readings.u, np.float64)
    if cal.crosstalk is not None:
        G = cal.crosstalk.solve(cal.sensor, G, readings.contact, cal.normal_curve(u))
    out = np.empty(G.shape + (3, 3))
    # steps that never vanish beside G (an element with almost no calibration samples has a tiny scale)
    h_g, h_u = np.maximum(1e-4 * cal.g_scale, 1e-7 * np.abs(G)), 1e-4 * cal.u_scale
    curves = cal.per_element_forces
    out[..., 0] = (curves(G + h_g, u)[0] - curves(np.maximum(G - h_g, 0.0), u)[0]) \
        / (G + h_g - np.maximum(G - h_g, 0.0))[..., None]
    for k in (0, 1):
        step = np.zeros(u.shape)
        step[..., k] = h_u
        out[..., k + 1] = (curves(G, u + step)[0] - curves(G, u - step)[0]) / (2.0 * h_u)[..., None]
    return out, G


def model_error(cal) -> np.ndarray:
    """The calibration's own error per element and axis, (E, 3) N, from its fit residuals.

    The stored RMS fit residuals (``residuals["fx", "fy", "fz"]``) with
    the degrees of freedom the curves took: ``rms sqrt(n / (n - p))``,
    ``p`` = 6 parameters for Fz of the coupled model (4 for ohka), 1 per
    shear axis (two shared by Fx and Fy). They hold the calibration
    frames' own noise too, so adding them to the noise of a reading
    counts that noise twice (conservative; on the synthetic sets the
    noise is a small part, see :meth:`stderr`). Zero when no residuals
    are recorded.
    """
    res = cal.residuals
    if not all(k in res for k in ("fx", "fy", "fz", "n")):
        return np.zeros((len(cal.g), 3))
    n = np.asarray(res["n"], np.float64)
    p_z = G_TERMS + (2 if cal.model == "coupled" else 0)
    rms = np.stack([np.asarray(res[k], np.float64) for k in ("fx", "fy", "fz")], axis=-1)
    p = np.array([1.0, 1.0, p_z])
    dof = np.where(n[:, None] > p + 1, n[:, None] / np.maximum(n[:, None] - p, 1.0), 1.0)
    return rms * np.sqrt(dof)


def stderr(cal, readings: Readings, errors=None, *, with_model_error: bool = True, forces=None) -> np.ndarray:
    """Standard errors of ``cal.forces(readings)``, (E, 3) or (T, E, 3) N.

    Parameters
    ----------
    readings : Readings
    errors : ReadingErrors, optional
        The readings' covariance (:func:`optitact.pipeline.uncertainty.reading_errors`),
        propagated through :func:`jacobian`; None: the calibration's
        model error alone.
    with_model_error : bool
        Add the model error in quadrature (default): the calibration's
        measured :class:`~optitact.calib.error_model.ErrorModel` at each
        element's estimated forces (its Fz and shear) where it has one
        (:meth:`~optitact.calib.fit.Calibration.validated`), else :func:`model_error`.
    forces : ndarray, optional
        ``cal.forces(readings)[0]`` when already made (the measured error
        model is read at them; otherwise they are computed again).

    Returns
    -------
    ndarray
        ``sqrt(J C J^T + m^2)`` per element and axis, ``C`` the readings'
        covariance (independent between elements), ``m`` the model error.
        Elements without contact read 0 N and get the model error alone.

    Examples
    --------
    >>> from optitact.calib.shipped import default_calibration
    >>> cal = default_calibration()
    >>> se = cal.stderr(Readings.empty(41))
    >>> se.shape, bool((se > 0).all())
    ((41, 3), True)
    """
    shape = np.shape(readings.G) + (3,)
    var = np.zeros(shape)
    if errors is not None:
        cov = np.asarray(errors.cov, np.float64)
        if cov.shape != np.shape(readings.G) + (3, 3):
            raise ShapeError(f"errors.cov must have shape {np.shape(readings.G) + (3, 3)} to match the "
                             f"readings, got {cov.shape}")
        if cal.crosstalk is None:
            local = _local_jacobian(cal, readings)[0]
            var = np.einsum("...ab,...bc,...ac->...a", local, cov, local)
        else:
            jac = jacobian(cal, readings)
            var = np.einsum("...eajb,...jbc,...eajc->...ea", jac, cov, jac)
        var = np.where(np.asarray(readings.contact, bool)[..., None], var, 0.0)
    if with_model_error:
        if cal.error_model is not None:
            var = var + cal.error_model.at(cal.forces(readings)[0] if forces is None else forces) ** 2
        else:
            var = var + model_error(cal) ** 2
    return np.sqrt(var)
