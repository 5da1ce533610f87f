"""Load-pattern families: how forces are spread over the elements in a frame.

A calibration fitted on independent random loads is tested where a robot
actually loads the sensor: one object pressing a cluster of elements, a flat
plate loading all of them alike, a single element touched, sliding with shear
in one direction. Each family here draws element-local forces ``(T, E, 3)``
(N) for a :class:`~optitact.calib.sets.Design` (its ``fz_max``,
``shear_max`` and ``mu_max`` bound every load), seeded;
:func:`design_forces` draws a calibration set's forces from its design's
pattern:

``independent``
    Every element its own random load (a scrambled Sobol design over normal
    force, shear magnitude and direction), with the pure-normal and
    pure-shear sweeps of ``sweep_fraction`` of the frames: the classic design.
``uniform``
    All elements the same normal force, no shear; levels evenly over
    ``(0, fz_max]`` (a flat plate).
``single``
    One element loaded per frame, the others free; elements in turn, random
    normal force and shear.
``clustered``
    A rounded indenter (:func:`optitact.optics.loads.indenter_load`) pressed at a
    random point, width 2-8 mm, peak up to ``fz_max``, dragged with up to
    ``mu_max`` of shear in a random direction: a neighbourhood loaded
    together, strongest at its centre.
``checkerboard``
    Alternate elements loaded (by ring and position in the ring, so that
    every loaded element has free neighbours), the two colourings in turn,
    random normal force and shear.
``shear``
    Every element at ``fz_max / 2`` with shear along one of 8 directions
    (global, projected onto each element's tangent plane), magnitude evenly
    up to the design's limit: sliding.
``blend``
    Frames of every family above in turn (a calibration design that has seen
    every pattern).
"""

from __future__ import annotations

import math

import numpy as np

from optitact._validate import integer
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["PATTERNS", "FAMILIES", "design_forces", "pattern_forces"]

#: The load-pattern families of held-out tests (``blend`` mixes them for a calibration design).
FAMILIES = ("independent", "uniform", "single", "clustered", "checkerboard", "shear")
#: Every pattern a :class:`~optitact.calib.sets.Design` can name.
PATTERNS = (*FAMILIES, "blend")


def _shear(rng, fz: np.ndarray, design) -> np.ndarray:
    """Random shear (..., 2) within ``min(mu_max Fz, shear_max)``, uniform over the disc."""
    mag = np.minimum(design.mu_max * fz, design.shear_max) * np.sqrt(rng.uniform(0, 1, fz.shape))
    ang = rng.uniform(0, 2 * np.pi, fz.shape)
    return np.stack([mag * np.cos(ang), mag * np.sin(ang)], axis=-1)


def _tangent(sensor: DomeSensor, direction: np.ndarray) -> np.ndarray:
    """A global direction projected onto each element's tangent plane, unit length (E, 2); 0 where none."""
    t = np.einsum("nij,j->ni", sensor.element_frames[:, :2, :], direction)
    norm = np.linalg.norm(t, axis=1, keepdims=True)
    return np.divide(t, norm, out=np.zeros_like(t), where=norm > 1e-12)


def _colouring(sensor: DomeSensor) -> np.ndarray:
    """0/1 per element: alternating round each ring, the rings' phases alternating too."""
    ring = sensor.element_ring
    pos = np.concatenate([np.arange(n) for n in sensor.ring_counts])
    return (pos + ring) % 2


def design_forces(n_frames: int, n_elements: int, design, seed: int,
                  sensor: DomeSensor | None = None) -> np.ndarray:
    """Element-local forces ``(n_frames, n_elements, 3)`` (N) of a calibration set of ``design``.

    ``design`` is a :class:`~optitact.calib.sets.Design`. One of another
    ``pattern`` than ``"independent"`` is drawn by :func:`pattern_forces` on
    ``sensor`` (default the default sensor).

    Notes
    -----
    The ``"independent"`` design:

    * Sobol frames: a scrambled Sobol sequence (seeded) of
      ``(u1, u2, u3)`` per element sample gives ``Fz = fz_max u1``, shear
      magnitude ``min(mu_max Fz, shear_max) sqrt(u2)`` (uniform over the
      allowed disc) and direction ``2 pi u3``.
    * Normal sweep frames: ``Fz`` on an even grid over ``(0, fz_max]``,
      shuffled over elements, no shear.
    * Shear sweep frames: ``Fz = fz_max / 2``, shear along +-x or +-y with
      magnitudes on an even grid up to the limit.
    """
    if design.pattern != "independent":
        sensor = DomeSensor.default() if sensor is None else sensor
        if sensor.n_elements != n_elements:
            raise InputError(f"n_elements ({n_elements}) is not the sensor's ({sensor.n_elements})")
        return pattern_forces(design.pattern, n_frames, sensor, design, seed)
    return _independent(integer(n_frames, "frames", minimum=1), n_elements, design, seed)


def _independent(n_frames: int, n_elements: int, design, seed: int) -> np.ndarray:
    """The ``independent`` design's forces (see :func:`design_forces`)."""
    from scipy.stats import qmc

    rng = np.random.default_rng([seed, 1])
    n_sweep = int(round(design.sweep_fraction * n_frames))
    n_normal = n_sweep // 2
    n_shear = n_sweep - n_normal
    n_sobol = n_frames - n_sweep
    out = np.zeros((n_frames, n_elements, 3))
    if n_sobol:
        sob = qmc.Sobol(3, scramble=True, seed=np.random.default_rng([seed, 0]))
        m = math.ceil(math.log2(max(n_sobol * n_elements, 2)))
        u = sob.random_base2(m)[: n_sobol * n_elements].reshape(n_sobol, n_elements, 3)
        fz = design.fz_max * u[..., 0]
        mag = np.minimum(design.mu_max * fz, design.shear_max) * np.sqrt(u[..., 1])
        ang = 2 * np.pi * u[..., 2]
        out[:n_sobol] = np.stack([mag * np.cos(ang), mag * np.sin(ang), fz], axis=-1)
    if n_normal:
        levels = design.fz_max * np.arange(1, n_normal * n_elements + 1) / (n_normal * n_elements)
        fz = rng.permutation(levels).reshape(n_normal, n_elements)
        out[n_sobol:n_sobol + n_normal, :, 2] = fz
    if n_shear:
        fz = design.fz_max / 2
        limit = min(design.mu_max * fz, design.shear_max)
        k = n_shear * n_elements
        mags = limit * np.arange(1, k + 1) / k
        dirs = np.array([[1, 0], [-1, 0], [0, 1], [0, -1]])[np.arange(k) % 4]
        order = rng.permutation(k)
        shear = (mags[:, None] * dirs)[order].reshape(n_shear, n_elements, 2)
        out[n_sobol + n_normal:, :, :2] = shear
        out[n_sobol + n_normal:, :, 2] = fz
    return out


def pattern_forces(pattern: str, n_frames: int, sensor: DomeSensor, design, seed: int) -> np.ndarray:
    """Element-local forces ``(n_frames, E, 3)`` (N) of a load-pattern family (see the module docstring).

    ``independent`` is :func:`design_forces`'s classic design; the others
    are drawn from ``np.random.default_rng([seed, 2, k])`` with ``k`` the
    family's index, so each family's frames depend only on the seed.
    """
    from optitact.optics.loads import indenter_load

    if pattern not in PATTERNS:
        raise InputError(f"pattern must be one of {PATTERNS}, got {pattern!r}")
    n_frames = integer(n_frames, "frames", minimum=1)
    n_el = sensor.n_elements
    if pattern == "independent":
        return _independent(n_frames, n_el, design, seed)
    if pattern == "blend":
        parts = np.array_split(np.arange(n_frames), len(FAMILIES))
        out = np.zeros((n_frames, n_el, 3))
        for fam, idx in zip(FAMILIES, parts, strict=True):
            if idx.size:
                out[idx] = pattern_forces(fam, idx.size, sensor, design, seed)
        return out
    rng = np.random.default_rng([seed, 2, PATTERNS.index(pattern)])
    out = np.zeros((n_frames, n_el, 3))
    if pattern == "uniform":
        levels = design.fz_max * (np.arange(n_frames) + 1) / n_frames
        out[:, :, 2] = rng.permutation(levels)[:, None]
    elif pattern == "single":
        elements = rng.permutation(np.resize(np.arange(n_el), n_frames))
        fz = design.fz_max * rng.uniform(0.05, 1.0, n_frames)
        t = np.arange(n_frames)
        out[t, elements, 2] = fz
        out[t, elements, :2] = _shear(rng, fz, design)
    elif pattern == "clustered":
        for t in range(n_frames):
            polar = math.degrees(math.acos(rng.uniform(math.cos(math.radians(75.0)), 1.0)))
            out[t] = indenter_load(sensor, polar_deg=polar, azimuth_deg=rng.uniform(0, 360),
                                   peak=design.fz_max * rng.uniform(0.3, 1.0), width=rng.uniform(2.0, 8.0),
                                   shear_ratio=design.mu_max * rng.uniform(0, 1),
                                   shear_azimuth_deg=rng.uniform(0, 360))
        mag = np.linalg.norm(out[..., :2], axis=-1)
        cap = np.where(mag > design.shear_max, design.shear_max / np.maximum(mag, 1e-300), 1.0)
        out[..., :2] *= cap[..., None]
    elif pattern == "checkerboard":
        colour = _colouring(sensor)
        for t in range(n_frames):
            on = colour == (t % 2)
            fz = design.fz_max * rng.uniform(0.05, 1.0, n_el)
            out[t, on, 2] = fz[on]
            out[t, on, :2] = _shear(rng, fz, design)[on]
    elif pattern == "shear":
        fz = design.fz_max / 2
        limit = min(design.mu_max * fz, design.shear_max)
        for t in range(n_frames):
            a = 2 * np.pi * (t % 8) / 8
            mag = limit * ((t // 8) + 1) / (-(-n_frames // 8))
            out[t, :, :2] = mag * _tangent(sensor, np.array([math.cos(a), math.sin(a), 0.0]))
            out[t, :, 2] = fz
        out = out[rng.permutation(n_frames)]
    return out
