"""Sample loads: element forces for demos and tests."""

from __future__ import annotations

import numpy as np

from optitact._validate import check_type, positive
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["indenter_load", "random_load"]


def indenter_load(sensor: DomeSensor, *, polar_deg: float = 30.0, azimuth_deg: float = 40.0,
                  peak: float = 0.8, width: float = 5.0, shear_ratio: float = 0.2,
                  shear_azimuth_deg: float = 0.0, cutoff: float = 0.02) -> np.ndarray:
    """Element-local forces of a rounded indenter pressed and dragged on the dome.

    Parameters
    ----------
    sensor : DomeSensor
    polar_deg, azimuth_deg : float
        Where the indenter's centre touches the dome (deg).
    peak : float
        Normal force on an element right under the centre (N), default 0.8.
    width : float
        Gaussian width of the normal-force distribution along the surface (mm).
    shear_ratio : float
        Shear as a fraction of each element's normal force (a friction-limited
        drag), default 0.2.
    shear_azimuth_deg : float
        Drag direction: the global direction ``(cos a, sin a, 0)``, projected
        onto each element's tangent plane (deg).
    cutoff : float
        Elements with less normal force than this (N) are left unloaded.

    Returns
    -------
    (N, 3) ndarray
        Element-local ``(Fx, Fy, Fz)`` in N.

    Notes
    -----
    ``Fz_i = peak exp(-d_i^2 / (2 width^2))`` with ``d_i`` the geodesic
    distance from the indenter centre to element ``i``; the shear is
    ``shear_ratio Fz_i`` along the projected drag direction.
    """
    check_type(sensor, DomeSensor, "sensor")
    peak = positive(peak, "peak", allow_zero=True)
    width = positive(width, "width")
    shear_ratio = positive(shear_ratio, "shear_ratio", allow_zero=True)
    cutoff = positive(cutoff, "cutoff", allow_zero=True)
    if not 0.0 <= polar_deg < 90.0:
        raise InputError(f"polar_deg must be in [0, 90), got {polar_deg}")
    th, ph = np.radians(polar_deg), np.radians(azimuth_deg)
    centre = np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])
    normals = sensor.element_frames[:, 2, :]
    dist = sensor.outer_radius * np.arccos(np.clip(normals @ centre, -1.0, 1.0))
    fz = peak * np.exp(-0.5 * (dist / width) ** 2)
    fz[fz < cutoff] = 0.0
    a = np.radians(shear_azimuth_deg)
    drag = np.array([np.cos(a), np.sin(a), 0.0])
    t = np.einsum("nij,j->ni", sensor.element_frames[:, :2, :], drag)  # local x, y components
    norm = np.linalg.norm(t, axis=1, keepdims=True)
    t = np.divide(t, norm, out=np.zeros_like(t), where=norm > 1e-12)
    t[np.abs(t) < 1e-12] = 0.0  # exact zeros where the drag has no component
    forces = np.zeros((sensor.n_elements, 3))
    forces[:, :2] = shear_ratio * fz[:, None] * t
    forces[:, 2] = fz
    return forces


def random_load(sensor: DomeSensor, *, fz_range: tuple[float, float] = (0.1, 1.0),
                shear_ratio: float = 0.3, loaded: float = 1.0, seed: int | None = 0) -> np.ndarray:
    """Independent random forces on the elements (element-local, N).

    Parameters
    ----------
    sensor : DomeSensor
    fz_range : (float, float)
        Normal force of a loaded element, uniform in ``[lo, hi]`` (N).
    shear_ratio : float
        Shear magnitude uniform in ``[0, shear_ratio * Fz]`` in a uniform
        random direction.
    loaded : float
        Fraction of elements loaded (each independently), default all.
    seed : int or None
        Seed of ``np.random.default_rng``.

    Returns
    -------
    (N, 3) ndarray
        ``(Fx, Fy, Fz)`` per element; unloaded elements are zero.
    """
    from optitact._validate import seed_value

    check_type(sensor, DomeSensor, "sensor")

    lo, hi = (positive(v, "fz_range[]", allow_zero=True) for v in fz_range)
    if not lo <= hi:
        raise InputError(f"fz_range must be (lo, hi) with lo <= hi, got {fz_range!r}")
    shear_ratio = positive(shear_ratio, "shear_ratio", allow_zero=True)
    loaded = positive(loaded, "loaded", allow_zero=True)
    if loaded > 1:
        raise InputError(f"loaded must be a fraction in [0, 1], got {loaded}")
    rng = np.random.default_rng(seed_value(seed))
    n = sensor.n_elements
    fz = rng.uniform(lo, hi, n)
    mag = rng.uniform(0.0, shear_ratio, n) * fz
    ang = rng.uniform(0.0, 2 * np.pi, n)
    on = rng.random(n) < loaded
    forces = np.stack([mag * np.cos(ang), mag * np.sin(ang), fz], axis=1)
    forces[~on] = 0.0
    return forces
