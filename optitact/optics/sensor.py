"""The optical three-axis tactile sensor: dome geometry and sensing elements.

Convention
----------
Physical coordinates are ``(x, y, z)`` in mm. The global frame has its origin
at the centre of the dome's base circle, ``z`` along the dome axis towards the
apex. Elements are numbered 0 = apex, then ring by ring outwards, each ring
counter-clockwise (seen from above) starting at +x. The element-local frame has
``z`` = outward surface normal, ``x`` = the global x axis projected onto the
tangent plane and normalised, ``y = z x x``.
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, field, fields
from functools import cached_property

import numpy as np

from optitact._validate import check_keys, integer, positive
from optitact.errors import InputError

__all__ = ["DomeSensor"]

#: The sensor's lengths (mm) and their accepted range: 1 nm to 10 m keeps every derived
#: quantity (areas, pitches, the camera's maps) finite in float64.
LENGTHS_MM = ("outer_radius", "shell_thickness", "column_diameter", "lever_arm", "cone_circle_radius",
              "cone_base_radius")
MIN_LENGTH_MM = 1e-6
MAX_LENGTH_MM = 1e4


def _frozen(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True)
class DomeSensor:
    """Geometry and materials of the hemispherical optical tactile sensor.

    All lengths in mm, forces in N, moduli in MPa (= N/mm^2), angles in degrees.
    Every length lies between ``MIN_LENGTH_MM`` (1e-6) and ``MAX_LENGTH_MM``
    (1e4); beyond them the derived geometry leaves float64.

    Parameters
    ----------
    outer_radius : float
        Radius of the acrylic dome's outer surface (mm), default 20.
    shell_thickness : float
        Thickness of the acrylic shell (mm), default 3; inner radius is
        ``outer_radius - shell_thickness``.
    refractive_index : float
        Refractive index of the acrylic, default 1.49.
    ring_counts : tuple of int
        Number of elements per ring, apex first, default ``(1, 8, 16, 16)``.
    ring_polar_deg : tuple of float
        Polar angle of each ring from the dome axis (deg), default
        ``(0, 22.5, 45, 67.5)``. A ring at 0 deg must hold exactly one element.
    column_diameter : float
        Diameter of the columnar feeler (mm), default 2.5.
    lever_arm : float
        Height of the columnar feeler's load point above the cone tips (mm),
        default 3; shear times lever arm is the moment the cones balance.
    n_cones : int
        Conical feelers per element, default 8, centres evenly on a circle.
    cone_circle_radius : float
        Radius of the circle through the cone centres (mm), default 1.25.
    cone_apex_deg : float
        Full apex angle of each conical feeler (deg), default 90.
    cone_base_radius : float
        Base radius of a conical feeler (mm), default 0.45: the largest
        contact radius, reached when the cone is fully flattened.
    youngs_modulus : float
        Rubber Young's modulus E (MPa), default 1.
    poisson_ratio : float
        Rubber Poisson ratio nu, default 0.49.
    preload : float
        Normal preload per element (N), default 0; keeps cone tips lightly
        touching as on the real sensor.
    element_offsets : tuple of (float, float), optional
        As built: each element's displacement from its design position (mm,
        geodesic, in the design position's element-local x, y), one pair per
        element, each at most ``column_diameter`` long; default ``()`` (every
        element where the design puts it). Registration fits them
        (:func:`optitact.registration.pose` with ``fit_offsets=True``); every map,
        region and render uses the displaced centres.
    element_gain : tuple of float, optional
        As built: each element's relative brightness (rubber, cone tips, the
        rim light reaching it), one positive factor per element, from 1/16 to
        16; default ``()`` (all 1). Renders scale the element's patch radiance
        by it; registration estimates it from equal presses.

    Examples
    --------
    >>> s = DomeSensor.default()
    >>> s.n_elements
    41
    >>> s.element_positions.shape
    (41, 3)
    """

    outer_radius: float = 20.0
    shell_thickness: float = 3.0
    refractive_index: float = 1.49
    ring_counts: tuple[int, ...] = (1, 8, 16, 16)
    ring_polar_deg: tuple[float, ...] = (0.0, 22.5, 45.0, 67.5)
    column_diameter: float = 2.5
    lever_arm: float = 3.0
    n_cones: int = 8
    cone_circle_radius: float = 1.25
    cone_apex_deg: float = 90.0
    cone_base_radius: float = 0.45
    youngs_modulus: float = 1.0
    poisson_ratio: float = 0.49
    preload: float = field(default=0.0)
    element_offsets: tuple[tuple[float, float], ...] = ()
    element_gain: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        # Store plain Python numbers, so that to_dict() is always JSON-ready.
        for name in ("outer_radius", "shell_thickness", "refractive_index", "column_diameter",
                     "lever_arm", "cone_circle_radius", "cone_apex_deg", "cone_base_radius",
                     "youngs_modulus"):
            object.__setattr__(self, name, positive(getattr(self, name), name))
        for name in LENGTHS_MM:  # the geometry's trigonometry and areas stay within float64
            value = getattr(self, name)
            if not MIN_LENGTH_MM <= value <= MAX_LENGTH_MM:
                raise InputError(f"{name} must be a length from {MIN_LENGTH_MM:g} to {MAX_LENGTH_MM:g} mm, "
                                 f"got {value!r}")
        object.__setattr__(self, "preload", positive(self.preload, "preload", allow_zero=True))
        object.__setattr__(self, "poisson_ratio",
                           positive(self.poisson_ratio, "poisson_ratio", allow_zero=True))
        if self.poisson_ratio >= 0.5:
            raise InputError(f"poisson_ratio must be in [0, 0.5), got {self.poisson_ratio}")
        if self.shell_thickness >= self.outer_radius:
            raise InputError(
                f"shell_thickness must be < outer_radius ({self.outer_radius} mm), "
                f"got {self.shell_thickness}"
            )
        if self.refractive_index <= 1.0:
            raise InputError(f"refractive_index must be > 1, got {self.refractive_index}")
        if self.cone_apex_deg >= 180.0:
            raise InputError(f"cone_apex_deg must be in (0, 180), got {self.cone_apex_deg}")
        object.__setattr__(self, "n_cones", integer(self.n_cones, "n_cones", minimum=3))
        counts = tuple(self.ring_counts)
        polars = tuple(self.ring_polar_deg)
        if len(counts) == 0 or len(counts) != len(polars):
            raise InputError(
                "ring_counts and ring_polar_deg must be non-empty and of equal length, "
                f"got {len(counts)} and {len(polars)}"
            )
        counts = tuple(integer(n, f"ring_counts[{i}]", minimum=1) for i, n in enumerate(counts))
        polars = tuple(positive(p, f"ring_polar_deg[{i}]", allow_zero=True)
                       for i, p in enumerate(polars))
        object.__setattr__(self, "ring_counts", counts)
        object.__setattr__(self, "ring_polar_deg", polars)
        for i, (n, pv) in enumerate(zip(counts, polars, strict=True)):
            if pv >= 90.0:
                raise InputError(f"ring_polar_deg[{i}] must be in [0, 90), got {pv}")
            if pv == 0.0 and n != 1:
                raise InputError(f"a ring at polar angle 0 must hold 1 element, got {n}")
        if list(polars) != sorted(polars) or len(set(polars)) != len(polars):
            raise InputError(f"ring_polar_deg must be strictly increasing, got {polars}")
        pitch = 2.0 * self.cone_circle_radius * math.sin(math.pi / self.n_cones)
        if 2.0 * self.cone_base_radius > pitch:
            raise InputError(
                f"cone_base_radius {self.cone_base_radius} mm makes neighbouring cones overlap "
                f"(at most {pitch / 2:.4g} mm for {self.n_cones} cones on a "
                f"{self.cone_circle_radius} mm circle)"
            )

        self._check_as_built()

    def _check_as_built(self) -> None:
        """Validate and normalise ``element_offsets`` and ``element_gain`` (plain tuples of floats)."""
        n = self.n_elements
        for name, width in (("element_offsets", 2), ("element_gain", 1)):
            value = getattr(self, name)
            if value is None or (hasattr(value, "__len__") and len(value) == 0):
                object.__setattr__(self, name, ())
                continue
            if isinstance(value, (str, bytes)) or not hasattr(value, "__len__"):
                raise TypeError(f"{name} must be a sequence (one entry per element) or (), got "
                                f"{type(value).__name__}")
            try:
                arr = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise TypeError(f"{name} must hold real numbers, got {value!r:.80}") from exc
            want = (n, 2) if width == 2 else (n,)
            if arr.shape != want:
                raise InputError(f"{name} must have shape {want} (one entry per element of the {n}), got "
                                 f"{arr.shape}")
            if not np.isfinite(arr).all():
                raise InputError(f"{name} must be finite, got {arr[~np.isfinite(arr)][:3].tolist()}")
            if width == 2:
                worst = float(np.linalg.norm(arr, axis=1).max())
                if worst > self.column_diameter:
                    raise InputError(f"element_offsets must be at most column_diameter "
                                     f"({self.column_diameter:g} mm) long (a manufacturing tolerance), got "
                                     f"{worst:.4g} mm")
                value = tuple((float(a), float(b)) for a, b in arr)
            else:
                if arr.min() < 1.0 / 16.0 or arr.max() > 16.0:
                    raise InputError(f"element_gain must lie from 1/16 to 16, got values in "
                                     f"[{arr.min():.4g}, {arr.max():.4g}]")
                value = tuple(float(a) for a in arr)
            object.__setattr__(self, name, value)

    @property
    def gains(self) -> np.ndarray:
        """Each element's relative brightness, shape (N,): :attr:`element_gain`, or ones."""
        if self.element_gain:
            return np.asarray(self.element_gain, dtype=np.float64)
        return np.ones(self.n_elements)

    @property
    def as_designed(self) -> DomeSensor:
        """The same sensor without its as-built offsets and gains."""
        from dataclasses import replace

        return replace(self, element_offsets=(), element_gain=())

    @classmethod
    def default(cls) -> DomeSensor:
        """Return the 41-element sensor with the published dimensions."""
        return cls()

    # ----------------------------------------------------------------- serialisation
    def to_dict(self) -> dict:
        """Return the parameters as a JSON-friendly dict."""
        d = asdict(self)
        d["ring_counts"] = list(self.ring_counts)
        d["ring_polar_deg"] = list(self.ring_polar_deg)
        # As-built fields only when set: a designed sensor's dict (and every fingerprint of it) is as before.
        for name in ("element_offsets", "element_gain"):
            if getattr(self, name):
                d[name] = [list(v) if isinstance(v, tuple) else v for v in getattr(self, name)]
            else:
                del d[name]
        return d

    @classmethod
    def from_dict(cls, d: dict) -> DomeSensor:
        """Build a sensor from :meth:`to_dict` output; unknown keys are a ValueError."""
        kw = check_keys(d, [f.name for f in fields(cls)], "sensor parameters", noun="parameter")
        for key in ("ring_counts", "ring_polar_deg"):
            if key in kw:
                kw[key] = tuple(kw[key])
        if "element_offsets" in kw and isinstance(kw["element_offsets"], list):
            kw["element_offsets"] = tuple(tuple(v) if isinstance(v, list) else v for v in kw["element_offsets"])
        if "element_gain" in kw and isinstance(kw["element_gain"], list):
            kw["element_gain"] = tuple(kw["element_gain"])
        return cls(**kw)

    # ----------------------------------------------------------------- derived geometry
    @property
    def inner_radius(self) -> float:
        """Radius of the dome's inner surface (mm)."""
        return self.outer_radius - self.shell_thickness

    @property
    def n_elements(self) -> int:
        """Number of sensing elements."""
        return int(sum(self.ring_counts))

    @property
    def effective_modulus(self) -> float:
        """Plane-strain modulus E* = E / (1 - nu^2) of rubber on rigid acrylic (MPa)."""
        return self.youngs_modulus / (1.0 - self.poisson_ratio**2)

    @property
    def shear_modulus(self) -> float:
        """Rubber shear modulus G = E / (2 (1 + nu)) (MPa)."""
        return self.youngs_modulus / (2.0 * (1.0 + self.poisson_ratio))

    @property
    def cone_half_angle(self) -> float:
        """Semi-apex angle alpha of a conical feeler (rad)."""
        return math.radians(self.cone_apex_deg) / 2.0

    @property
    def max_cone_load(self) -> float:
        """Load (N) at which one cone is fully flattened (contact radius = base radius).

        From Sneddon's cone, ``A = 2 P tan(alpha) / E*`` with ``A = pi r_base^2``.
        """
        area = math.pi * self.cone_base_radius**2
        return area * self.effective_modulus / (2.0 * math.tan(self.cone_half_angle))

    @cached_property
    def element_ring(self) -> np.ndarray:
        """Ring index of each element, shape (N,)."""
        return _frozen(np.repeat(np.arange(len(self.ring_counts)), self.ring_counts))

    @cached_property
    def _design_angles(self) -> tuple[np.ndarray, np.ndarray]:
        """Polar angle and azimuth (rad) of the design positions."""
        polar = np.deg2rad(np.repeat(np.asarray(self.ring_polar_deg, float), self.ring_counts))
        az = np.concatenate([2.0 * np.pi * np.arange(n) / n for n in self.ring_counts])
        return polar, az

    @cached_property
    def element_polar(self) -> np.ndarray:
        """Polar angle of each element centre from the dome axis (rad), shape (N,)."""
        z = self.element_frames[:, 2, :]
        return _frozen(np.arccos(np.clip(z[:, 2], -1.0, 1.0)) if self.element_offsets
                       else self._design_angles[0].copy())

    @cached_property
    def element_azimuth(self) -> np.ndarray:
        """Azimuth of each element centre, counter-clockwise from +x (rad), shape (N,)."""
        if not self.element_offsets:
            return _frozen(self._design_angles[1].copy())
        z = self.element_frames[:, 2, :]
        return _frozen(np.mod(np.arctan2(z[:, 1], z[:, 0]), 2.0 * np.pi))

    @cached_property
    def element_positions(self) -> np.ndarray:
        """Element centres on the outer dome surface, global mm, shape (N, 3)."""
        return _frozen(self.outer_radius * self.element_frames[:, 2, :].copy())

    @cached_property
    def element_frames(self) -> np.ndarray:
        """Element-local axes as rows, shape (N, 3, 3): ``frames[i] = [x_i, y_i, z_i]``.

        ``z`` is the outward normal, ``x`` the global x axis projected onto the
        tangent plane and normalised, ``y = z x x``. A vector ``v_local`` maps
        to global as ``frames[i].T @ v_local``.
        """
        th, ph = self._design_angles
        z = np.stack([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)], axis=-1)
        frames = self._frames_at(z)
        if self.element_offsets:  # as built: the frame at the displaced centre (exponential map)
            off = np.asarray(self.element_offsets)
            t = off[:, 0:1] * frames[:, 0, :] + off[:, 1:2] * frames[:, 1, :]
            s = np.linalg.norm(off, axis=1, keepdims=True)
            ang = s / self.outer_radius
            z = np.cos(ang) * z + np.sin(ang) * t / np.where(s > 0, s, 1.0)
            frames = self._frames_at(z / np.linalg.norm(z, axis=1, keepdims=True))
        return _frozen(frames)

    @staticmethod
    def _frames_at(z: np.ndarray) -> np.ndarray:
        """Element-local axes (N, 3, 3) for outward normals ``z``."""
        ex = np.array([1.0, 0.0, 0.0])
        x = ex - (z @ ex)[:, None] * z
        x /= np.linalg.norm(x, axis=-1, keepdims=True)
        y = np.cross(z, x)
        return np.stack([x, y, z], axis=1)

    @cached_property
    def cone_offsets(self) -> np.ndarray:
        """Cone centres in the element's tangent plane (local x, y; mm), shape (n_cones, 2).

        Cone ``k`` sits at angle ``2 pi k / n_cones`` counter-clockwise from local x.
        """
        psi = 2.0 * np.pi * np.arange(self.n_cones) / self.n_cones
        return _frozen(self.cone_circle_radius * np.stack([np.cos(psi), np.sin(psi)], axis=-1))

    def dome_point(self, element: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Map tangent-plane offsets around elements onto the outer dome surface.

        Parameters
        ----------
        element : (...) int array
            Element indices.
        offset : (..., 2) array
            Offsets in the element-local x/y tangent coordinates (mm), measured
            as geodesic arc length along the dome surface.

        Returns
        -------
        (..., 3) ndarray
            Global points on the outer surface (mm).

        Notes
        -----
        The exponential map of the sphere: for a tangent offset ``t`` of length
        ``s`` at the element normal ``n``, the point is
        ``R (cos(s/R) n + sin(s/R) t/s)``.
        """
        frames = self.element_frames[np.asarray(element)]
        off = np.asarray(offset, dtype=np.float64)
        t = off[..., 0:1] * frames[..., 0, :] + off[..., 1:2] * frames[..., 1, :]
        s = np.linalg.norm(off, axis=-1, keepdims=True)
        ang = s / self.outer_radius
        safe = np.where(s > 0, s, 1.0)
        direction = np.cos(ang) * frames[..., 2, :] + np.sin(ang) * t / safe
        return self.outer_radius * direction

    def tangent_offset(self, element: np.ndarray, points: np.ndarray) -> np.ndarray:
        """Inverse of :meth:`dome_point`: tangent offsets (mm) of dome points around elements.

        Parameters
        ----------
        element : (...) int array
            Element indices.
        points : (..., 3) array
            Global points on (or radially projected onto) the outer surface.

        Returns
        -------
        (..., 2) ndarray
            Element-local ``(x, y)`` geodesic normal coordinates (mm): the
            logarithmic map of the sphere at the element centre.

        Notes
        -----
        With ``p`` the unit direction of the point and ``n`` the element
        normal, ``a = atan2(|p - (p.n) n|, p.n)`` and the offset is
        ``R a (p - (p.n) n) / |p - (p.n) n|`` expressed in the element's
        tangent axes.
        """
        frames = self.element_frames[np.asarray(element)]
        p = np.asarray(points, dtype=np.float64)
        p = p / np.linalg.norm(p, axis=-1, keepdims=True)
        n = frames[..., 2, :]
        c = np.sum(p * n, axis=-1, keepdims=True)
        t = p - c * n
        s = np.linalg.norm(t, axis=-1, keepdims=True)
        ang = np.arctan2(s, c)
        scale = self.outer_radius * np.where(s > 0, ang / np.where(s > 0, s, 1.0), 1.0)
        t = t * scale
        return np.stack([np.sum(t * frames[..., 0, :], axis=-1),
                         np.sum(t * frames[..., 1, :], axis=-1)], axis=-1)
