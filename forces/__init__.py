"""Force fields on the dome: frame changes now; slip, friction and decoupling build on them.

Convention
----------
Element-local forces ``(Fx, Fy, Fz)``: ``z`` the outward normal, ``Fz`` positive
when the element is pressed onto the dome (so the global force the object
exerts on the element is ``Fx x_i + Fy y_i - Fz z_i``). Global forces are in
the sensor frame of :mod:`optitact.sensor`. Units: N.
"""

from __future__ import annotations

import numpy as np

from optitact.contact import check_forces
from optitact.sensor import DomeSensor

__all__ = ["global_from_local", "local_from_global"]

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
