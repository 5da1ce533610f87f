"""One frame's forces on the dome as a :class:`ForceField`; slip, friction and contact events in the modules.

Modules: :mod:`~optitact.forces.slip`, :mod:`~optitact.forces.friction`, :mod:`~optitact.forces.contact_events`,
:mod:`~optitact.forces.indenter` (objects pressed into the dome: their forces on the elements)
(and the frame changes in :mod:`optitact.optics.force_frames`).

Convention
----------
Element-local forces ``(Fx, Fy, Fz)``: ``z`` the outward normal, ``Fz`` positive
when the element is pressed onto the dome (so the global force the object
exerts on the element is ``Fx x_i + Fy y_i - Fz z_i``). Global forces are in
the sensor frame of :mod:`optitact.optics.sensor`. Units: N.
"""

from __future__ import annotations

import csv
import math
import os
from dataclasses import KW_ONLY, dataclass
from functools import cached_property
from pathlib import Path

import numpy as np

from optitact._validate import finite, positive, real_array
from optitact.optics.camera import Camera
from optitact.optics.contact import check_forces
from optitact.errors import InputError, ShapeError
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.uncertainty import Z90
from optitact.optics.force_frames import global_from_local

__all__ = ["ForceField"]

# ----------------------------------------------------------------------------- force field
_CSV_COLUMNS = ("element", "fx", "fy", "fz", "fx_global", "fy_global", "fz_global",
                "contact", "clamped", "saturated")
_FLAG_NAMES = ("contact", "clamped", "saturated")
#: Columns of the standard errors, written after the others when a field has them.
_SE_COLUMNS = ("fx_se", "fy_se", "fz_se")


def _freeze(arr: np.ndarray) -> np.ndarray:
    arr.setflags(write=False)
    return arr


def _flag_array(value, name: str, n: int) -> np.ndarray:
    """Validate a per-element flag: a bool array of shape (n,); returns a read-only copy."""
    arr = np.asarray(value)
    if arr.dtype != np.bool_:
        raise TypeError(f"{name} must be a bool array of shape ({n},) (one flag per element), "
                        f"got dtype {arr.dtype}")
    if arr.shape != (n,):
        raise ShapeError(f"{name} must have shape ({n},) (one flag per element), got {arr.shape}")
    return _freeze(arr.copy())


@dataclass(frozen=True, eq=False, repr=False)
class ForceField:
    """Estimated forces on every element of the dome sensor in one frame.

    A small frozen container: the element-local forces and per-element flags,
    with the derived global forces, resultant, moment and centre of pressure,
    a table view (:meth:`as_dict`, :meth:`to_csv`) and a picture over the
    camera frame (:meth:`plot`).

    Parameters
    ----------
    sensor : DomeSensor
        The sensor the forces belong to (``N = sensor.n_elements``).
    local : (N, 3) array_like
        Element-local forces ``(Fx, Fy, Fz)`` (N); real and finite. Stored as
        a read-only float64 copy.
    contact : (N,) bool array, optional
        Elements in contact with the object; default ``local[:, 2] > 0``.
    clamped : (N,) bool array, optional
        The calibration clamped this element's reading to its fitted range;
        default all False.
    saturated : (N,) bool array, optional
        The element's image region saturated the camera; default all False.
    stderr : (N, 3) array_like, optional
        Standard errors of ``local`` (N), finite and >= 0, e.g. from
        :meth:`optitact.calib.fit.Calibration.stderr`; stored read-only. None:
        not known.

    Raises
    ------
    TypeError
        ``sensor`` is not a :class:`DomeSensor`, ``local`` is not a real
        numeric array (bool included), or a flag is not a bool array.
    ShapeError
        ``local`` or ``stderr`` is not (N, 3) or a flag is not (N,).
    InputError
        ``local`` holds NaN or infinity, ``stderr`` a negative or non-finite value.

    Convention
    ----------
    Element-local forces as in this module: ``z`` the outward surface normal,
    ``Fz`` positive when the element is pressed onto the dome. Global vectors
    and positions are ``(x, y, z)`` in the sensor frame of
    :mod:`optitact.optics.sensor` (origin at the dome centre, mm); forces in N,
    moments in N mm. The resultant, moment, total normal force and centre of
    pressure sum over contact elements only. Image positions in :meth:`plot`
    are ``(row, col)`` pixels, drawn at ``x = col``, ``y = row``.

    Notes
    -----
    With ``r_i`` the element centres on the outer surface (radius ``R``),
    ``F_i`` the global forces and ``C`` the contact set:

    - resultant ``F = sum_{i in C} F_i``;
    - moment about the dome centre ``M = sum_{i in C} r_i x F_i`` (a pure
      normal force points through the centre and adds nothing);
    - centre of pressure ``R p / |p|`` with
      ``p = sum_{i in C} w_i r_i / sum_{i in C} w_i``, ``w_i = max(Fz_i, 0)``:
      the Fz-weighted mean position projected radially onto the outer
      surface; ``None`` when no contact element carries a positive ``Fz``.

    Examples
    --------
    >>> s = DomeSensor.default()
    >>> f = np.zeros((41, 3)); f[0] = (0.1, 0.0, 1.0)
    >>> ff = ForceField(s, f)
    >>> ff.resultant
    array([ 0.1,  0. , -1. ])
    >>> ff.total_normal
    1.0
    >>> ff.centre_of_pressure
    array([ 0.,  0., 20.])
    """

    sensor: DomeSensor
    local: np.ndarray
    _: KW_ONLY
    contact: np.ndarray | None = None
    clamped: np.ndarray | None = None
    saturated: np.ndarray | None = None
    stderr: np.ndarray | None = None

    def __post_init__(self) -> None:
        if not isinstance(self.sensor, DomeSensor):
            raise TypeError(f"sensor must be a DomeSensor, got {type(self.sensor).__name__}")
        n = self.sensor.n_elements
        local = _freeze(np.array(check_forces(self.local, self.sensor, "local"), dtype=np.float64))
        object.__setattr__(self, "local", local)
        defaults = {"contact": local[:, 2] > 0, "clamped": np.zeros(n, bool),
                    "saturated": np.zeros(n, bool)}
        for name in _FLAG_NAMES:
            value = getattr(self, name)
            object.__setattr__(self, name, _flag_array(defaults[name] if value is None else value,
                                                       name, n))
        if self.stderr is not None:
            se = real_array(self.stderr, "stderr")
            if se.shape != (n, 3):
                raise ShapeError(f"stderr must have shape ({n}, 3) (one per element and axis), got {se.shape}")
            finite(se, "stderr")
            if np.any(se < 0):
                raise InputError(f"stderr must be >= 0, got {se.min()}")
            object.__setattr__(self, "stderr", _freeze(np.array(se, dtype=np.float64)))

    def __repr__(self) -> str:
        f = ", ".join(f"{v:.4g}" for v in self.resultant)
        return (f"ForceField(n_elements={self.n_elements}, n_contact={self.n_contact}, "
                f"resultant=({f}) N)")

    # ----------------------------------------------------------------- derived quantities
    @property
    def n_elements(self) -> int:
        """Number of elements ``N``."""
        return self.sensor.n_elements

    @property
    def n_contact(self) -> int:
        """Number of elements in contact."""
        return int(np.count_nonzero(self.contact))

    @cached_property
    def global_forces(self) -> np.ndarray:
        """Global force vectors on the elements (N), shape (N, 3), read-only; see :func:`global_from_local`."""
        return _freeze(global_from_local(self.sensor, self.local))

    @property
    def resultant(self) -> np.ndarray:
        """Sum of the global forces over contact elements (N), shape (3,)."""
        return self.global_forces[self.contact].sum(axis=0)

    @property
    def moment(self) -> np.ndarray:
        """Moment of the contact elements' global forces about the dome centre (N mm), shape (3,).

        ``sum_{i in contact} r_i x F_i`` with ``r_i`` = ``sensor.element_positions``.
        """
        r = self.sensor.element_positions[self.contact]
        return np.cross(r, self.global_forces[self.contact]).sum(axis=0)

    @property
    def total_normal(self) -> float:
        """Sum of ``Fz`` over contact elements (N)."""
        return float(self.local[self.contact, 2].sum())

    @property
    def centre_of_pressure(self) -> np.ndarray | None:
        """Fz-weighted mean contact position projected onto the outer surface (mm), shape (3,).

        ``None`` when no contact element carries a positive ``Fz`` (no
        contact); see the class *Notes*.
        """
        w = np.where(self.contact, np.maximum(self.local[:, 2], 0.0), 0.0)
        total = w.sum()
        if not total > 0:
            return None
        p = w @ self.sensor.element_positions / total
        norm = np.linalg.norm(p)
        if not norm > 0:  # positions have z > 0 on a dome, so only for pathological sensors
            return None
        return self.sensor.outer_radius * p / norm

    # ----------------------------------------------------------------- table
    def as_dict(self) -> dict[str, np.ndarray]:
        """Per-element table: equal-length arrays keyed by column name.

        Keys: ``element, fx, fy, fz`` (local, N), ``fx_global, fy_global,
        fz_global`` (N) and the flags ``contact, clamped, saturated`` (bool);
        then, when :attr:`stderr` is known, ``fx_se, fy_se, fz_se`` (N).
        ``pandas.DataFrame(ff.as_dict())`` gives one row per element. The
        arrays are new (writeable) copies.
        """
        g = self.global_forces
        return {
            "element": np.arange(self.n_elements),
            "fx": self.local[:, 0].copy(), "fy": self.local[:, 1].copy(),
            "fz": self.local[:, 2].copy(),
            "fx_global": g[:, 0].copy(), "fy_global": g[:, 1].copy(), "fz_global": g[:, 2].copy(),
            "contact": self.contact.copy(), "clamped": self.clamped.copy(),
            "saturated": self.saturated.copy(),
            **({} if self.stderr is None else {k: self.stderr[:, i].copy() for i, k in enumerate(_SE_COLUMNS)}),
        }

    def to_csv(self, path: str | os.PathLike) -> Path:
        """Write :meth:`as_dict` as CSV with a header row, atomically; returns the path.

        Floats are written with ``repr`` (shortest exact round trip), flags as
        0/1; the standard errors ``fx_se, fy_se, fz_se`` come last, when known.
        The rows go to a temporary file renamed to ``path`` when complete
        (:func:`optitact.io.files.atomic_write`): ``path`` is the old file or the
        whole new one, never half of it.
        """
        from optitact.io.files import atomic_write

        table = self.as_dict()

        se = () if self.stderr is None else _SE_COLUMNS

        def write(tmp: Path) -> None:
            with tmp.open("w", newline="") as fh:
                w = csv.writer(fh)
                w.writerow(_CSV_COLUMNS + se)
                for i in range(self.n_elements):
                    w.writerow([int(i), *(repr(float(table[k][i])) for k in _CSV_COLUMNS[1:7]),
                                *(int(table[k][i]) for k in _FLAG_NAMES),
                                *(repr(float(table[k][i])) for k in se)])

        return atomic_write(path, write)

    @classmethod
    def from_csv(cls, path: str | os.PathLike, sensor: DomeSensor) -> ForceField:
        """Read a force field from CSV: the files :meth:`to_csv` writes, and those people write.

        Columns are found by header name (:func:`optitact.io.tables.read_element_table`):
        ``fx, fy, fz`` (element-local, N) are needed, in any order, whatever
        their case and a unit in parentheses or brackets (``Fx (N)``);
        ``element``, the global columns ``fx_global, fy_global, fz_global``
        the 0/1 flags ``contact, clamped, saturated`` and the standard errors
        ``fx_se, fy_se, fz_se`` (all three or none) are read when
        present (a missing flag takes the :class:`ForceField` default), other
        columns are ignored. With an ``element`` column any subset of the
        elements may be listed, each at most once (the others are unloaded).
        The delimiter is ``,``, ``;`` or tab, a UTF-8 byte-order mark is fine,
        and blank lines and lines starting with ``#`` are ignored. Global
        columns, when present, are checked against the local ones for this
        ``sensor``.

        Raises
        ------
        FileNotFoundError
            If the file does not exist.
        ShapeError
            No header or a missing column, wrong number of columns or rows.
        InputError
            A cell that is not a finite number or a 0/1 flag (the message gives
            line and column), an element index that does not exist or appears
            twice, a delimiter that cannot be told, or global columns that
            disagree with the local forces for ``sensor``.
        """
        from optitact.io.tables import read_element_table

        if not isinstance(sensor, DomeSensor):
            raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
        cols = read_element_table(path, sensor.n_elements, _CSV_COLUMNS[1:4],
                                  optional=_CSV_COLUMNS[4:7] + _SE_COLUMNS,
                                  flags=_FLAG_NAMES, headerless=False, what="force field",
                                  force_units=_CSV_COLUMNS[1:7] + _SE_COLUMNS)
        local = np.stack([cols[k] for k in _CSV_COLUMNS[1:4]], axis=1)
        has_se = [k in cols for k in _SE_COLUMNS]
        if any(has_se) and not all(has_se):
            raise ShapeError(f"{path}: the standard-error columns {', '.join(_SE_COLUMNS)} come together; "
                             f"got only {', '.join(k for k in _SE_COLUMNS if k in cols)}")
        se = np.stack([cols[k] for k in _SE_COLUMNS], axis=1) if all(has_se) else None
        ff = cls(sensor, local, **{k: cols.get(k) for k in _FLAG_NAMES}, stderr=se)
        given = [k for k in _CSV_COLUMNS[4:7] if k in cols]
        if given:
            j = [_CSV_COLUMNS.index(k) - 4 for k in given]
            written = np.stack([cols[k] for k in given], axis=1)
            err = np.abs(ff.global_forces[:, j] - written)
            tol = 1e-9 * max(1.0, float(np.abs(local).max()), float(np.abs(written).max()))
            if np.any(err > tol):
                bad = int(np.argmax(err.max(axis=1)))
                raise InputError(
                    f"{path}: global forces of element {bad} disagree with its local forces for this "
                    f"sensor by {err.max():.3g} N (written for a different sensor?)"
                )
        return ff

    # ----------------------------------------------------------------- picture
    def plot(self, frame: np.ndarray, camera: Camera, *, ax=None,
             scale_mm_per_n: float = 10.0, title: str | None = None):
        """Draw the force field over a camera frame.

        Parameters
        ----------
        frame : (H, W) array_like
            Grey camera frame of ``camera.shape`` (any real dtype); shown in
            grey, stretched between its 0.5th and 99.9th percentiles for
            display only (the array is not changed).
        camera : Camera
            The camera that took the frame (element centres and arrows are
            projected with it).
        ax : matplotlib.axes.Axes, optional
            Axes to draw in; default a new :class:`matplotlib.figure.Figure`
            (no pyplot, so it works headless and leaves the backend alone).
        scale_mm_per_n : float
            Arrow length on the dome per newton of shear (mm/N), default 10.
        title : str, optional
            Axes title.

        Returns
        -------
        matplotlib.figure.Figure
            The figure holding the axes.

        Raises
        ------
        TypeError
            ``camera`` is not a :class:`~optitact.optics.camera.Camera` or ``frame`` is not a
            real numeric array.
        ShapeError
            ``frame`` is not ``camera.shape``.
        InputError
            ``frame`` holds NaN or infinity; ``scale_mm_per_n`` is not > 0.

        Notes
        -----
        Element centres are small grey dots. Each contact element with a
        non-zero shear ``(Fx, Fy)`` gets an arrow (a
        :class:`matplotlib.patches.FancyArrowPatch` in ``ax.patches``, gid
        ``"shear-<i>"``) from
        its centre to ``sensor.dome_point(i, (Fx, Fy) * scale_mm_per_n)``
        projected by ``camera.project``: the arrow follows the dome surface, so
        it shows the shear's direction on the dome as the camera sees it. An
        arrow that would leave the part of the dome the camera sees is cut at
        its edge. Contact elements are discs whose colour (colorbar
        "Fz (N)") and area grow with ``Fz``; clamped elements get a red ring,
        saturated elements an orange square. The resultant force is written
        in the lower-left corner. With :attr:`stderr` known, each contact
        element's 90 % interval is drawn: around the shear arrow's tip the
        ellipse ``(Fx, Fy) + 1.645 (sx cos t, sy sin t)`` mapped onto the
        dome as the arrow is (a :class:`matplotlib.patches.Polygon`, gid
        ``"shear-ci-<i>"``), and around the disc a dashed ring whose area is
        that of a disc of ``Fz + 1.645 sz``.

        Convention
        ----------
        Image positions are ``(row, col)`` with the origin at the top-left
        pixel centre; they are drawn at ``x = col``, ``y = row`` (row axis
        pointing down), so the picture matches the frame.
        """
        from optitact._optional import require

        Normalize = require("matplotlib.colors", purpose="plots").Normalize
        Figure = require("matplotlib.figure", purpose="plots").Figure
        Line2D = require("matplotlib.lines", purpose="plots").Line2D
        FancyArrowPatch = require("matplotlib.patches", purpose="plots").FancyArrowPatch
        Polygon = require("matplotlib.patches", purpose="plots").Polygon

        if not isinstance(camera, Camera):
            raise TypeError(f"camera must be a Camera (e.g. a FisheyeCamera), got {type(camera).__name__}")
        img = real_array(frame, "frame")
        if img.shape != camera.shape:
            raise ShapeError(f"frame must have shape (H, W) = {camera.shape} of the camera, "
                             f"got {img.shape}")
        finite(img, "frame")
        scale = positive(scale_mm_per_n, "scale_mm_per_n")

        if ax is None:
            fig = Figure(figsize=(8.0, max(3.0, 7.0 * camera.height / camera.width + 0.4)),
                         layout="constrained")
            ax = fig.add_subplot()
        else:
            fig = ax.figure
        lo, hi = (float(v) for v in np.percentile(img, [0.5, 99.9]))
        if not hi > lo:
            hi = lo + 1.0
        ax.imshow(img, cmap="gray", vmin=lo, vmax=hi, interpolation="nearest")

        s = self.sensor
        centres = camera.project(s.element_positions, s)  # (N, 2) row, col
        ax.scatter(centres[:, 1], centres[:, 0], s=6, c="0.65", linewidths=0, zorder=2)
        handles = [Line2D([], [], ls="", marker="o", ms=3, color="0.65", label="element centre")]

        idx = np.flatnonzero(self.contact)
        fz = self.local[idx, 2]
        fz_top = float(fz.max()) if idx.size else 0.0
        norm = Normalize(0.0, fz_top if fz_top > 0 else 1.0)
        size = 25.0 + 175.0 * np.clip(fz, 0.0, None) / norm.vmax
        sc = ax.scatter(centres[idx, 1], centres[idx, 0], s=size, c=fz, cmap="viridis", norm=norm,
                        edgecolors="white", linewidths=0.6, zorder=3)
        fig.colorbar(sc, ax=ax, label="Fz (N)", shrink=0.85)
        handles.append(Line2D([], [], ls="", marker="o", ms=7, mfc="tab:green", mec="white",
                              label="contact (size, colour: Fz)"))
        if self.stderr is not None and idx.size:
            upper = np.clip(fz + Z90 * self.stderr[idx, 2], 0.0, None)
            ax.scatter(centres[idx, 1], centres[idx, 0], s=25.0 + 175.0 * upper / norm.vmax, facecolors="none",
                       edgecolors="tab:pink", linewidths=0.9, linestyles="--", zorder=3)
            sxy = self.stderr[idx, :2] * Z90
            t = np.linspace(0.0, 2.0 * np.pi, 25)
            ring = np.stack([np.cos(t), np.sin(t)], axis=-1)                # (25, 2)
            for k, i in enumerate(idx):
                if not np.any(sxy[k] > 0):
                    continue
                pts = (self.local[i, :2] + ring * sxy[k]) * scale
                poly = self._visible_tips(camera, np.full(len(t), i), pts)
                ax.add_patch(Polygon(poly[:, ::-1], closed=True, facecolor="tab:cyan", alpha=0.25,
                                     edgecolor="tab:cyan", linewidth=0.6, zorder=4, gid=f"shear-ci-{i}"))
            handles.append(Line2D([], [], ls="", marker="o", ms=9, mfc="tab:cyan", alpha=0.4, mec="tab:cyan",
                                  label="90 % interval (shear: ellipse; Fz: dashed ring)"))

        shear = self.local[idx, :2]
        moving = np.hypot(shear[:, 0], shear[:, 1]) > 0
        if np.any(moving):
            tips = self._visible_tips(camera, idx[moving], shear[moving] * scale)
            for i, (r0, c0), (r1, c1) in zip(idx[moving], centres[idx[moving]], tips, strict=True):
                ax.add_patch(FancyArrowPatch((c0, r0), (c1, r1), arrowstyle="-|>", mutation_scale=9,
                                             color="tab:cyan", linewidth=1.3, shrinkA=0, shrinkB=0,
                                             zorder=4, gid=f"shear-{i}"))
        handles.append(Line2D([], [], color="tab:cyan", marker=">", ms=5,
                              label=f"shear ({scale:g} mm/N on the dome)"))

        for flag, marker, colour, label in ((self.clamped, "o", "red", "clamped"),
                                            (self.saturated, "s", "orange", "saturated")):
            if np.any(flag):
                ax.scatter(centres[flag, 1], centres[flag, 0], s=170, marker=marker,
                           facecolors="none", edgecolors=colour, linewidths=1.6, zorder=5)
                handles.append(Line2D([], [], ls="", marker=marker, ms=9, mfc="none", mec=colour,
                                      mew=1.6, label=label))
        ax.legend(handles=handles, loc="upper right", fontsize="x-small", framealpha=0.8)

        fx, fy, fz_r = self.resultant
        ax.text(0.01, 0.01,
                f"resultant (global) = ({fx:.3g}, {fy:.3g}, {fz_r:.3g}) N, "
                f"|F| = {math.hypot(fx, fy, fz_r):.3g} N\n"
                f"{self.n_contact} of {self.n_elements} elements in contact, "
                f"sum Fz = {self.total_normal:.3g} N",
                transform=ax.transAxes, ha="left", va="bottom", fontsize="x-small",
                bbox={"boxstyle": "round", "facecolor": "white", "alpha": 0.8})
        ax.set_xlim(-0.5, camera.width - 0.5)
        ax.set_ylim(camera.height - 0.5, -0.5)
        ax.set_xlabel("col (px)")
        ax.set_ylabel("row (px)")
        if title is not None:
            ax.set_title(title)
        return fig

    def _visible_tips(self, camera: Camera, idx: np.ndarray, offset: np.ndarray) -> np.ndarray:
        """Pixels of the arrow tips ``dome_point(idx, offset)``, cut where they leave the camera's view."""
        s = self.sensor
        theta_max = camera.max_polar_angle(s) - 1e-9

        def theta(frac):
            p = s.dome_point(idx, offset * frac[:, None])
            return np.arctan2(np.hypot(p[:, 0], p[:, 1]), p[:, 2])

        frac = np.ones(len(idx))
        out = theta(frac) > theta_max
        if np.any(out):  # bisect the visible fraction of the arrow
            lo, hi = np.zeros(len(idx)), np.ones(len(idx))
            for _ in range(40):
                mid = 0.5 * (lo + hi)
                ok = theta(mid) <= theta_max
                lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
            frac = np.where(out, lo, 1.0)
        return camera.project(s.dome_point(idx, offset * frac[:, None]), s)

    def save_plot(self, path: str | os.PathLike, frame: np.ndarray, camera: Camera,
                  **kwargs) -> Path:
        """Save :meth:`plot` as a PNG (100 dpi) and return the path; ``kwargs`` go to :meth:`plot`."""
        from optitact.io.files import atomic_write_png_figure

        return atomic_write_png_figure(self.plot(frame, camera, **kwargs), path, dpi=100)
