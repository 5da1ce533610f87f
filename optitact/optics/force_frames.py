"""Forces in the element-local frames and in the sensor's global frame, and a frame's totals.

Convention
----------
Element-local forces ``(Fx, Fy, Fz)``: ``z`` the outward normal of element
``i`` (:attr:`DomeSensor.element_frames <optitact.optics.sensor.DomeSensor.element_frames>`),
``Fz`` positive when the element is pressed onto the dome, so the global force
the object exerts on the element is ``Fx x_i + Fy y_i - Fz z_i``. Global
forces are in the sensor frame of :mod:`optitact.optics.sensor`. Units: N.
"""

from __future__ import annotations

import numpy as np

from optitact.optics.contact import check_forces
from optitact.optics.sensor import DomeSensor

__all__ = ["frame_totals", "global_from_local", "local_from_global"]

_SIGN = np.array([1.0, 1.0, -1.0])


def global_from_local(sensor: DomeSensor, forces) -> np.ndarray:
    """Convert element-local forces (N, 3) to global force vectors on the elements (N, 3).

    Notes
    -----
    ``F_global_i = frames_i^T (Fx, Fy, -Fz)``: the compressive normal ``Fz``
    points into the dome, against the outward normal.

    Examples
    --------
    >>> import numpy as np
    >>> s = DomeSensor.default()
    >>> f = np.zeros((41, 3)); f[0] = (0.1, 0.0, 1.0)
    >>> global_from_local(s, f)[0]
    array([ 0.1,  0. , -1. ])
    """
    f = check_forces(forces, sensor)
    return np.einsum("nij,ni->nj", sensor.element_frames, f * _SIGN)


def local_from_global(sensor: DomeSensor, forces_global) -> np.ndarray:
    """Inverse of :func:`global_from_local`."""
    f = check_forces(forces_global, sensor, "forces_global")
    return np.einsum("nij,nj->ni", sensor.element_frames, f) * _SIGN


def frame_totals(sensor: DomeSensor, local, contact) -> dict[str, np.ndarray]:
    """Per-frame totals of a stack of force fields: :class:`~optitact.forces.ForceField`'s quantities.

    Parameters
    ----------
    sensor : DomeSensor
    local : (T, N, 3) array_like
        Element-local forces (N) of ``T`` frames.
    contact : (T, N) bool array_like
        Elements in contact.

    Returns
    -------
    dict of str to ndarray
        ``global`` (T, N, 3) global forces on the elements (N);
        ``resultant`` (T, 3) their sum over contact elements (N);
        ``total_normal`` (T,) the sum of ``Fz`` over contact elements (N);
        ``centre_of_pressure`` (T, 3) in mm, NaN where :attr:`~optitact.forces.ForceField.centre_of_pressure`
        is None; ``n_contact`` (T,) int. Frame ``t`` equals
        ``ForceField(sensor, local[t], contact=contact[t])``'s (to rounding).
    """
    f = np.asarray(local, dtype=np.float64)
    c = np.asarray(contact, dtype=bool)
    g = np.einsum("nij,tni->tnj", sensor.element_frames, f * _SIGN)
    cm = c[..., None]
    w = np.where(c, np.maximum(f[..., 2], 0.0), 0.0)
    total = w.sum(axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        p = (w @ sensor.element_positions) / total[:, None]
        norm = np.linalg.norm(p, axis=1)
        cop = sensor.outer_radius * p / norm[:, None]
    cop[~((total > 0) & (norm > 0))] = np.nan
    return {"global": g, "resultant": np.where(cm, g, 0.0).sum(axis=1),
            "total_normal": np.where(c, f[..., 2], 0.0).sum(axis=1), "centre_of_pressure": cop,
            "n_contact": c.sum(axis=1)}
