"""Registration: fit the camera's pose (and optionally its intrinsics and the dome) to spots in real frames.

A user's sensor is not the design: the camera sits a fraction of a millimetre
off the axis, tilted by a degree or two, and its intrinsics may be known only
roughly. :func:`register` takes a no-load frame and a few frames in which
elements are pressed (one or several at a time, straight down), finds the
bright spots in them, works out which element each group of spots belongs to
and fits the camera to them by robust least squares. It does not need the
pipeline or a calibration: registration comes first.

Convention
----------
Pixels are ``(row, col)``, origin at the centre of the top-left pixel; dome
points are global ``(x, y, z)`` in mm (see :mod:`optitact.sensor`); the
camera's pose is OpenCV's ``rvec``/``tvec`` (see :mod:`optitact.camera_models`).

Notes
-----
Steps (each checked, each refusal naming what to add):

1. *Spots*: ``frame - noload``, thresholded at ``k`` times a robust noise
   estimate (1.4826 x the median absolute deviation), and never below the
   mirror image of the difference's own negative tail (quantised dark frames,
   where the robust estimate collapses), connected components
   (``cv2.connectedComponentsWithStats``, 8-connected).
2. *Clusters*: a pressed element shows a ring of up to ``n_cones`` cone spots
   (merged into one blob when the image is small); spots whose dome points
   (seen with the nominal camera) lie within a cone-circle diameter are linked
   into one cluster. The *model's* centroid is the mean of the projected cone
   patch centres of a pure normal press (:func:`contact_patches` through
   :func:`pixel_from_dome`, refraction included); the measured one is the
   plain mean of the cone spots' centroids when every cone is a spot of its
   own (whatever their brightness: the rim light makes the outer cones
   brighter), else the intensity-weighted centroid of the cluster's pixels
   (grown by two pixels), which equal spots make the same point. A cluster
   much more compact than an element's ring (a reflection) is dropped.
3. *Association*: the common image shift between clusters and the nominal
   camera's predicted element centroids is voted for (every cluster-element
   pair proposes one; the one most clusters agree with wins, the smallest on
   a tie; a different shift with as many votes is an ambiguity), then a
   Hungarian assignment per frame (``linear_sum_assignment``) with a gate of
   :data:`GATE` times the local element spacing; clusters outside every gate
   are rejected as extra reflections.
4. *Fit*: ``scipy.optimize.least_squares`` (``loss="soft_l1"``, ``f_scale``
   in pixels) of the measured minus the predicted cluster centroids over the
   camera's rotation and centre (and ``fx, fy, cx, cy``, the dome's outer
   radius, per-element tangent offsets with a prior, when asked); then the
   clusters are associated again with the fitted camera and the fit repeated
   until the association is stable. Standard errors are
   ``sqrt(diag(s^2 (J^T J)^-1))`` with ``s^2 = sum r^2 / (m - n)`` at the
   solution; a condition number of the column-scaled ``J^T J`` above
   :data:`MAX_CONDITION` is a degenerate pose.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from ._validate import check_type, positive, real_array
from .camera import Camera, FisheyeCamera
from .clusters import associate, element_clusters, nearest_spacing, vote_shift
from .errors import GainsError, InputError, RegistrationError, ShapeError
from .gains import element_gains
from .sensor import DomeSensor
from .spots import Spots, detect_spots, grey_image, spots_in_difference

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["GATE", "MAX_CONDITION", "GainsError", "Registration", "RegistrationError", "Spots", "detect_spots",
           "register"]

#: Association gate: a cluster may match an element within this fraction of the element's distance to its
#: nearest neighbour (pixels, predicted with the camera of the moment).
GATE = 0.35
#: Largest condition number of the column-scaled ``J^T J`` accepted at the solution.
MAX_CONDITION = 1e10
#: A cluster whose intensity-weighted RMS radius is below this fraction of the element ring's predicted one
#: is not an element (a reflection or a hot pixel).
MIN_RING_FRACTION = 0.6
#: Most iterations of the least-squares fit (each costs a Jacobian by finite differences).
MAX_ITERATIONS = 60
#: Prior standard deviation of the per-element position offsets (mm), when they are fitted.
OFFSET_PRIOR_MM = 0.2




def _opencv_camera(camera: Camera) -> Camera:
    """An OpenCV-model camera: the default equidistant camera becomes the equal OpenCV fisheye."""
    if isinstance(camera, FisheyeCamera):
        from .camera_models import OpenCVFisheyeCamera

        cy, cx = camera.center
        return OpenCVFisheyeCamera(camera.width, camera.height, fx=camera.focal_px, fy=camera.focal_px, cx=cx,
                                   cy=cy, dist=(0.0, 0.0, 0.0, 0.0), tvec=(0.0, 0.0, -camera.z))
    if not hasattr(camera, "fx"):
        raise InputError(f"camera: registration fits OpenCV-style cameras (fx, fy, cx, cy, rvec, tvec), got a "
                         f"{type(camera).__name__}")
    return camera


def _with(camera: Camera, **changes) -> Camera:
    """``dataclasses.replace`` that keeps the distortion's cached range (it depends only on ``dist``)."""
    new = replace(camera, **changes)
    for name in ("max_radius", "max_angle"):
        if name in camera.__dict__ and "dist" not in changes:
            new.__dict__[name] = camera.__dict__[name]
    return new


def _as_built(sensor: DomeSensor, offsets: np.ndarray | None) -> DomeSensor:
    """``sensor`` with ``offsets`` (N, 2) mm added to its element offsets (both in the design frame)."""
    if offsets is None or not np.any(offsets):
        return sensor
    total = np.asarray(offsets, dtype=np.float64)
    if sensor.element_offsets:
        total = total + np.asarray(sensor.element_offsets)
    return replace(sensor, element_offsets=tuple(map(tuple, total)))


def _cone_points(sensor: DomeSensor, elements: np.ndarray, offsets: np.ndarray | None = None) -> np.ndarray:
    """(n, K, 3) cone patch centres of a pure normal press on ``elements``.

    ``offsets`` (N, 2) mm, one per element of the sensor, are added to the
    sensor's own element offsets (design frame): the cones are those of the
    as-built sensor :func:`_as_built` gives, exactly.
    """
    from .contact import contact_patches

    built = _as_built(sensor, offsets)
    forces = np.zeros((built.n_elements, 3))
    forces[:, 2] = 1.0
    return contact_patches(built, forces).centers[elements]


def _predict(sensor: DomeSensor, camera: Camera, elements: np.ndarray,
             offsets: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Predicted cluster centroids (n, 2) and ring RMS radii (n,) in pixels; NaN where a cone is not seen."""
    from .dome_optics import pixel_from_dome

    px = pixel_from_dome(_cone_points(sensor, elements, offsets), sensor=sensor, camera=camera, outside="nan")
    cen = px.mean(axis=1)
    rms = np.sqrt(np.mean(np.sum((px - cen[:, None, :]) ** 2, axis=-1), axis=1))
    return cen, rms


# ----------------------------------------------------------------------------- the fit
class _Model:
    """Parameter vector <-> (sensor, camera, offsets) and the residuals of observed cluster centroids."""

    def __init__(self, sensor, camera, *, fit_intrinsics, fit_dome, fit_offsets, elements, prior_px):
        self.sensor0, self.camera0 = sensor, camera
        self.names = ["rvec_x", "rvec_y", "rvec_z", "x_mm", "y_mm", "z_mm"]
        x0 = list(camera.rvec) + list(camera.position)
        if fit_intrinsics:
            self.names += ["fx", "fy", "cx", "cy"]
            x0 += [camera.fx, camera.fy, camera.cx, camera.cy]
        if fit_dome:
            self.names += ["outer_radius_mm"]
            x0 += [sensor.outer_radius]
        self.offset_elements = np.unique(elements) if fit_offsets else np.zeros(0, int)
        for e in self.offset_elements:
            self.names += [f"offset_{e}_x_mm", f"offset_{e}_y_mm"]
        x0 += [0.0] * (2 * len(self.offset_elements))
        self.x0 = np.array(x0)
        self.fit_intrinsics, self.fit_dome = fit_intrinsics, fit_dome
        self.prior_px = prior_px

    def build(self, x: np.ndarray):
        from .camera import rotation_from_rvec

        rvec = x[:3]
        tvec = -(rotation_from_rvec(rvec) @ x[3:6])
        i = 6
        kw = {"rvec": tuple(rvec), "tvec": tuple(tvec)}
        if self.fit_intrinsics:
            kw.update(fx=x[6], fy=x[7], cx=x[8], cy=x[9])
            i = 10
        sensor = self.sensor0
        if self.fit_dome:
            sensor = replace(sensor, outer_radius=float(x[i]))
            i += 1
        offsets = np.zeros((sensor.n_elements, 2))
        offsets[self.offset_elements] = x[i:].reshape(-1, 2)
        return _as_built(sensor, offsets), _with(self.camera0, **kw), offsets

    def residuals(self, x: np.ndarray, elements: np.ndarray, measured: np.ndarray) -> np.ndarray:
        try:
            sensor, camera, offsets = self.build(x)
        except InputError:  # a step beyond what a sensor can be (an offset longer than the column)
            sensor = None
        if sensor is None or not np.linalg.norm(camera.position) < sensor.inner_radius:
            return np.full(2 * len(elements) + 2 * len(self.offset_elements), 1e3)
        pred, _ = _predict(sensor, camera, elements)
        r = np.nan_to_num(measured - pred, nan=1e3).ravel()
        if len(self.offset_elements):
            r = np.concatenate([r, self.prior_px * offsets[self.offset_elements].ravel() / OFFSET_PRIOR_MM])
        return r


def _fit(model: _Model, elements, measured, f_scale: float, x0=None):
    from scipy.optimize import least_squares

    return least_squares(model.residuals, model.x0 if x0 is None else x0, args=(elements, measured),
                         loss="soft_l1", f_scale=f_scale, x_scale="jac", method="trf", xtol=1e-12, ftol=1e-12,
                         gtol=1e-12, max_nfev=MAX_ITERATIONS)


def _check_conditioning(jac: np.ndarray, names: list[str], n_elements: int) -> np.ndarray:
    """``(J^T J)^-1`` of the column-scaled J, or RegistrationError naming the parameters it cannot pin down."""
    norms = np.linalg.norm(jac, axis=0)
    if np.any(norms == 0):
        bad = [names[i] for i in np.flatnonzero(norms == 0)]
        raise RegistrationError(f"degenerate pose: the spots do not depend on {bad}; press more elements, "
                                f"spread over the rings and further from the apex (seen: {n_elements})")
    js = jac / norms
    jtj = js.T @ js
    cond = float(np.linalg.cond(jtj))
    if not cond <= MAX_CONDITION:
        inflation = np.diag(np.linalg.pinv(jtj))
        worst = [names[i] for i in np.argsort(-inflation)[:3]]
        raise RegistrationError(
            f"degenerate pose: the condition number of J^T J is {cond:.3g} (at most {MAX_CONDITION:.0e}): "
            f"the frames cannot tell {', '.join(worst)} apart; press more elements ({n_elements} seen), spread "
            f"over several rings and further from the apex, or fit fewer parameters")
    return np.linalg.inv(jtj) / np.outer(norms, norms)


def _fit_observations(sensor, camera, clusters, obs_f, obs_c, obs_e, *, fit_intrinsics, fit_dome, fit_offsets,
                      f_scale) -> dict:
    """Fit the model to associated clusters; observations far beyond the robust spread are dropped once."""
    measured = np.array([clusters[f]["centroid"][c] for f, c in zip(obs_f, obs_c, strict=True)]).reshape(-1, 2)
    keep = np.ones(len(obs_e), bool)
    for _ in range(2):
        model = _Model(sensor, camera, fit_intrinsics=fit_intrinsics, fit_dome=fit_dome,
                       fit_offsets=fit_offsets, elements=obs_e[keep], prior_px=f_scale)
        res = _fit(model, obs_e[keep], measured[keep], f_scale)
        rn = np.linalg.norm(res.fun[:2 * int(keep.sum())].reshape(-1, 2), axis=1)
        bad = rn > max(5.0 * 1.4826 * float(np.median(rn)), 2.0 * f_scale)
        if not bad.any():
            break
        keep[np.flatnonzero(keep)[bad]] = False
    return {"model": model, "res": res, "element": obs_e[keep], "frame": obs_f[keep]}


# ----------------------------------------------------------------------------- the result
@dataclass(frozen=True)
class Registration:
    """A sensor and camera fitted to spots in real frames, with how well they fit.

    Attributes
    ----------
    sensor : DomeSensor
        The sensor as built: its ``outer_radius`` fitted with ``fit_dome``,
        its ``element_offsets`` (the given sensor's plus the fitted ones, in
        the design frame) with ``fit_offsets``, its ``element_gain`` with
        ``fit_gains``. Every map built from it (pipeline, render) uses them.
    camera : Camera
        The fitted camera (an OpenCV model; :meth:`Camera.to_dict` for files).
    rms_px : float
        Reprojection RMS of the cluster centroids (pixels, both axes pooled: ``sqrt(mean(dr^2 + dc^2) / 2)``).
    std_errors : dict
        Standard error of every fitted parameter: ``rvec_x..z`` (rad), the
        camera centre ``x_mm, y_mm, z_mm`` (dome frame), ``fx, fy, cx, cy``
        (pixels), ``outer_radius_mm``, ``offset_E_x_mm`` / ``_y_mm``, and
        with ``fit_gains`` ``gain_E`` (relative; NaN for an element pressed
        once when no element was pressed twice: the spread of repeated
        presses, pooled over the elements, is the measure).
    unseen : tuple of int
        Elements no frame showed (or whose clusters were rejected).
    frames : tuple of dict
        Per pressed frame: ``elements`` found, ``rejected`` clusters (outside every gate, not ring-shaped or
        outliers of the fit), ``spots`` detected, ``noise_sigma``.
    element : (n,) ndarray of int
        The element of each observation (one per frame and element seen).
    frame : (n,) ndarray of int
        The frame index of each observation.
    residuals_px : (n, 2) ndarray
        Measured minus predicted cluster centroid ``(row, col)`` (pixels).
    element_offsets : (N, 2) ndarray
        The fitted change of the elements' tangent offsets (mm, in the design
        position's element-local x, y); zeros unless ``fit_offsets``. The
        sensor's ``element_offsets`` are the given sensor's plus these.
    gain_force_n : float or None
        With ``fit_gains``: the press force (N) the gains refer to, ``press_force`` when given, else the
        force at which the reference calibration gives the median gain 1.
    gain_unfitted : tuple of int
        Seen elements whose gain could not be measured (no contact in the pipeline, saturated, or beyond
        the reference calibration's range); they keep the given sensor's gain, as the unseen ones do.
    """

    sensor: DomeSensor
    camera: Camera
    rms_px: float
    std_errors: dict
    unseen: tuple
    frames: tuple
    element: np.ndarray = field(repr=False)
    frame: np.ndarray = field(repr=False)
    residuals_px: np.ndarray = field(repr=False)
    element_offsets: np.ndarray = field(repr=False)
    gain_force_n: float | None = None
    gain_unfitted: tuple = ()

    def as_dict(self) -> dict:
        """Per-observation table: ``frame, element, residual_row_px, residual_col_px``."""
        return {"frame": self.frame, "element": self.element, "residual_row_px": self.residuals_px[:, 0],
                "residual_col_px": self.residuals_px[:, 1]}

    def to_dict(self) -> dict:
        """The setup document ``{"sensor", "camera", "registration"}`` for ``optitact process --setup``."""
        return {"sensor": self.sensor.to_dict(), "camera": self.camera.to_dict(),
                "registration": {"rms_px": self.rms_px,
                                 "std_errors": {k: (v if math.isfinite(v) else None)
                                                for k, v in self.std_errors.items()},
                                 "unseen": list(self.unseen), "frames": list(self.frames),
                                 "element_offsets_mm": {
                                     str(e): self.element_offsets[e].tolist()
                                     for e in np.flatnonzero(self.element_offsets.any(axis=1))},
                                 "gain_force_n": self.gain_force_n, "gain_unfitted": list(self.gain_unfitted)}}

    def save(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_dict` as JSON (atomically); returns the path."""
        from .io import atomic_write_text

        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")


def _frames(pressed, noload_shape) -> list[np.ndarray]:
    if isinstance(pressed, np.ndarray) and pressed.ndim == 3:
        pressed = list(pressed)
    if isinstance(pressed, np.ndarray) or not hasattr(pressed, "__len__"):
        raise ShapeError(f"pressed must be a sequence of frames (or a (T, H, W) stack), got "
                         f"{getattr(pressed, 'shape', type(pressed).__name__)}")
    frames = [grey_image(f, f"pressed[{i}]") for i, f in enumerate(pressed)]
    if not frames:
        raise RegistrationError("no pressed frames: give at least one frame in which elements are pressed")
    for i, f in enumerate(frames):
        if f.shape != noload_shape:
            raise ShapeError(f"pressed[{i}] must have the no-load frame's shape {noload_shape}, got {f.shape}")
    return frames


def register(noload, pressed, *, camera: Camera | None = None, sensor: DomeSensor | None = None,
             fit_intrinsics: bool = False, fit_dome: bool = False, fit_offsets: bool = False,
             fit_gains: bool = False, press_force: float | None = None, calibration=None, k: float = 5.0,
             f_scale: float = 0.5, min_elements: int | None = None) -> Registration:
    """Fit the camera's pose (and optionally its intrinsics and the dome) to spots of pressed elements.

    Parameters
    ----------
    noload : (H, W) array_like
        A frame of the unloaded sensor (its preload spots, if any, are
        subtracted); a (T, H, W) stack is averaged.
    pressed : sequence of (H, W) array_like, or (T, H, W)
        Frames in which elements are pressed straight down (several per frame
        is best: 5 to 8 spread over the rings).
    camera : Camera, optional
        The nominal camera: its intrinsics and distortion (e.g. from
        :func:`optitact.read_opencv_calibration`) and a starting pose. Default:
        the default equidistant camera of the frames' size. A
        :class:`FisheyeCamera` is fitted as the equal
        :class:`optitact.OpenCVFisheyeCamera`.
    sensor : DomeSensor, optional
        Default :meth:`DomeSensor.default`.
    fit_intrinsics : bool
        Also fit ``fx, fy, cx, cy`` (the distortion stays as given).
    fit_dome : bool
        Also fit the dome's outer radius (the shell thickness stays).
    fit_offsets : bool
        Also fit a tangent position offset per element seen, with a Gaussian
        prior of :data:`OFFSET_PRIOR_MM` (the manufacturing tolerance). The
        fitted sensor carries them as its ``element_offsets`` (the given
        sensor's plus the fitted ones, in the design frame).
    fit_gains : bool
        Also estimate each seen element's relative gain (brightness) from the
        pressed frames, which must then be presses of (about) equal force:
        one gauge setting, or one weight, for every press. The fitted sensor
        carries them as its ``element_gain``; see Notes.
    press_force : float, optional
        The force (N) of every press, when known: the gains are then
        absolute (relative to the reference calibration's sensor) instead of
        normalised to a median of 1.
    calibration : Calibration, optional
        The reference the gains are measured against: a calibration of the
        designed sensor (default: the shipped one,
        :func:`optitact.calib.default_calibration`).
    k : float
        Spot threshold in robust noise sigmas (see :func:`detect_spots`).
    f_scale : float
        Soft-L1 loss scale (pixels): residuals beyond it count less.
    min_elements : int, optional
        Fewest distinct elements accepted; default ``(parameters + 4) / 2``
        rounded up (5 for the pose alone, 7 with the intrinsics).

    Returns
    -------
    Registration

    Notes
    -----
    Gains: the pressed frames are read by a :class:`optitact.Pipeline` of
    the fitted sensor and camera (baseline: the no-load frame; the reference
    calibration's pipeline options). Each seen element's gain is its
    integrated grey value G (dewarped onto the dome, grey level x mm^2, so
    camera-independent to first order) over the G that the reference
    calibration's curve ``Fz = g(G, u = 0)`` gives at the press force, times
    the reference sensor's own gain; an element pressed several times takes
    the median. Without ``press_force`` the force is the one at which the
    median gain over the seen elements is 1, and the gains are normalised to
    that median exactly. Unseen elements keep the given sensor's gain (1 for
    a designed sensor) and are named in ``unseen``; seen ones that cannot be
    read in ``gain_unfitted``.

    Raises
    ------
    RegistrationError
        When the frames cannot pin the model down: too few spots or elements
        (naming how many it found and needs), an ambiguous association, a
        degenerate pose, a fit that does not converge.
    ShapeError
        For frames that are not (H, W) images of one shape, or of another
        size than the camera's.
    """
    sensor = DomeSensor.default() if sensor is None else check_type(sensor, DomeSensor, "sensor")
    base = real_array(noload, "noload")
    if base.ndim == 3:
        base = base.mean(axis=0)
    base = grey_image(base, "noload")
    frames = _frames(pressed, base.shape)
    h, w = base.shape
    camera = FisheyeCamera(width=w, height=h) if camera is None else check_type(camera, Camera, "camera")
    if camera.shape != (h, w):
        raise ShapeError(f"the frames are {w}x{h} but the camera (intrinsics) is for {camera.width}x"
                         f"{camera.height} frames; give intrinsics calibrated at the frames' size")
    for name, v in (("fit_intrinsics", fit_intrinsics), ("fit_dome", fit_dome), ("fit_offsets", fit_offsets),
                    ("fit_gains", fit_gains)):
        if not isinstance(v, (bool, np.bool_)):
            raise TypeError(f"{name} must be True or False, got {type(v).__name__}")
    k, f_scale = positive(k, "k"), positive(f_scale, "f_scale")
    if press_force is not None:
        if not fit_gains:
            raise InputError("press_force is the force of the presses the gains are measured from; it needs "
                             "fit_gains=True")
        press_force = positive(press_force, "press_force")
    if fit_gains:
        from .calib import Calibration, default_calibration

        calibration = default_calibration() if calibration is None else check_type(calibration, Calibration,
                                                                                    "calibration")
    camera = _opencv_camera(camera)
    n_par = 6 + 4 * bool(fit_intrinsics) + bool(fit_dome)
    need = max(4, math.ceil((n_par + 4) / 2)) if min_elements is None else int(min_elements)

    # spots and clusters, per frame, seen with the nominal camera
    everything = np.arange(sensor.n_elements)
    pred0, ring0 = _predict(sensor, camera, everything)
    gate0 = GATE * nearest_spacing(pred0)
    diffs = [f - base for f in frames]
    spots = [spots_in_difference(d, k, 2) for d in diffs]
    clusters = [element_clusters(d, s, sensor, camera) for d, s in zip(diffs, spots, strict=True)]
    rejected = [0] * len(frames)
    for i, cl in enumerate(clusters):  # compact blobs are no element's ring
        if len(cl["rms"]) == 0:
            continue
        near = np.nanargmin(np.linalg.norm(cl["centroid"][:, None, :] - pred0[None], axis=-1), axis=1)
        ring = cl["rms"] >= MIN_RING_FRACTION * ring0[near]
        rejected[i] += int((~ring).sum())
        clusters[i] = {key: v[ring] for key, v in cl.items()}
    n_clusters = sum(len(c["energy"]) for c in clusters)
    if n_clusters < need:
        raise RegistrationError(
            f"too few spots: {sum(len(s.energy) for s in spots)} spots in {len(frames)} pressed frame(s) form "
            f"{n_clusters} element-shaped cluster(s), and registration needs at least {need} elements; press "
            f"more elements (5 to 8 per frame, spread over the rings and further from the apex), harder, or "
            f"lower k ({k:g})")

    # association: one common shift, then per frame the Hungarian assignment within the gates
    search = 0.15 * min(h, w)
    shift = vote_shift([c["centroid"] for c in clusters], pred0, gate0, search)
    pred, gate, cur, fit = pred0, gate0, None, None
    for _round in range(4):
        obs_f, obs_c, obs_e = [], [], []
        for i, cl in enumerate(clusters):
            ci, ei = associate(cl["centroid"], pred, gate, shift)
            obs_f += [i] * len(ci)
            obs_c += list(ci)
            obs_e += list(ei)
        n_el = np.unique(obs_e).size
        if n_el < need:
            raise RegistrationError(
                f"too few elements: {n_el} distinct element(s) could be matched in {len(frames)} pressed "
                f"frame(s) ({n_clusters} cluster(s) found), and registration needs at least {need}; press more "
                f"elements, spread over the rings and further from the apex")
        key = (tuple(obs_f), tuple(obs_c), tuple(obs_e))
        if key == cur:
            break
        cur = key
        fit = _fit_observations(sensor, camera, clusters, np.array(obs_f), np.array(obs_c), np.array(obs_e),
                                fit_intrinsics=bool(fit_intrinsics), fit_dome=bool(fit_dome),
                                fit_offsets=bool(fit_offsets), f_scale=f_scale)
        fs, fc, _ = fit["model"].build(fit["res"].x)
        pred, _ = _predict(fs, fc, everything)
        gate, shift = GATE * nearest_spacing(pred), np.zeros(2)
    model, res, elements, obs_f = fit["model"], fit["res"], fit["element"], fit["frame"]
    n_el = np.unique(elements).size
    if n_el < need:
        raise RegistrationError(f"too few elements: {n_el} distinct element(s) fit without outliers, and "
                                f"registration needs at least {need}; press more elements, spread over the "
                                f"rings")
    fit_sensor, fit_camera, offsets = model.build(res.x)
    m, n = res.fun.size, res.x.size
    cov = _check_conditioning(res.jac, model.names, n_el)
    if not res.success:
        raise RegistrationError(f"the fit did not converge ({res.message}); press more elements, spread over "
                                f"the rings and further from the apex")
    r = res.fun[:2 * len(elements)].reshape(-1, 2)
    dof = max(m - n, 1)
    s2 = float(np.sum(res.fun ** 2)) / dof
    std = np.sqrt(np.maximum(np.diag(cov) * s2, 0.0))
    seen = set(int(e) for e in elements)
    per_frame = []
    for i in range(len(frames)):
        mine = np.asarray(obs_f) == i
        per_frame.append({"elements": sorted(int(e) for e in elements[mine]), "rejected": int(rejected[i]),
                          "spots": int(len(spots[i].energy)), "noise_sigma": spots[i].noise_sigma})
    for i, cl in enumerate(clusters):  # clusters matched to no element
        per_frame[i]["rejected"] += int(len(cl["energy"]) - len(per_frame[i]["elements"]))
    std_errors = {name: float(v) for name, v in zip(model.names, std, strict=True)}
    gains = None
    if fit_gains:
        gains = element_gains(fit_sensor, fit_camera, base, frames, np.asarray(obs_f), elements,
                               press_force=press_force, calibration=calibration)
        fit_sensor = replace(fit_sensor, element_gain=tuple(gains["gain"]))
        std_errors |= {f"gain_{e}": float(gains["se"][e]) for e in sorted(seen)}
    return Registration(
        sensor=fit_sensor, camera=fit_camera, rms_px=float(np.sqrt(np.mean(r ** 2))), std_errors=std_errors,
        unseen=tuple(int(e) for e in everything if e not in seen), frames=tuple(per_frame),
        element=elements, frame=np.asarray(obs_f, dtype=np.int64), residuals_px=r, element_offsets=offsets,
        gain_force_n=None if gains is None else gains["force"],
        gain_unfitted=() if gains is None else gains["unfitted"])
