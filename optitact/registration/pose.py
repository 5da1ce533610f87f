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
points are global ``(x, y, z)`` in mm (see :mod:`optitact.optics.sensor`); the
camera's pose is OpenCV's ``rvec``/``tvec`` (see :mod:`optitact.optics.camera_models`).

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
   radius, per-element tangent offsets, when asked; the last two each with a
   Gaussian prior around the given sensor: :data:`DOME_PRIOR_FRACTION` of the
   radius, :data:`OFFSET_PRIOR_MM`); then the clusters are associated again
   with the fitted camera and the fit repeated until the association is
   stable. Standard errors are ``sqrt(diag(C))``, ``C = (J_d^T J_d / s^2 +
   J_p^T J_p)^-1`` (``J_d`` the centroids' rows, ``J_p`` the priors' in
   prior standard deviations), with ``s^2 = sum r_d^2 / (m - n)`` at the
   solution (``m`` rows, priors included, ``n`` parameters); without priors,
   ``s^2 (J^T J)^-1``. A condition number of the column-scaled ``J^T J``
   above :data:`MAX_CONDITION` is a degenerate pose.
5. *Checks* (:class:`RegistrationWarning`, also kept in ``cautions``): a
   standard error beyond a physical scale (:data:`POSE_SE_MM`,
   :data:`POSE_SE_DEG`, :data:`FOCAL_SE_FRACTION`, :data:`CENTER_SE_PX`; the
   dome's radius when the frames add little to its prior); a reprojection RMS
   beyond :data:`RMS_NOISE_RATIO` times what the clusters' centroid noise
   explains (each centroid's noise from the difference image's: ``sigma
   sqrt(sum d_i^2 / 2) / E`` over its pixels); signs of a wrong camera model
   (the camera far from the given pose, spots near outer-ring elements
   outside every gate, an outer ring that fits much worse than the inner);
   gains whose spread is within their uncertainty, or uncertain gains.
"""

from __future__ import annotations

import json
import math
import os
import warnings
from dataclasses import dataclass, field, replace
from typing import TYPE_CHECKING

import numpy as np

from optitact._validate import check_type, integer, positive, real_array
from optitact.optics.camera import Camera, FisheyeCamera
from optitact.registration.clusters import associate, element_clusters, nearest_spacing, vote_shift
from optitact.errors import InputError, OptitactWarning, RegistrationError, ShapeError
from optitact.registration.gains import element_gains
from optitact.optics.sensor import DomeSensor
from optitact.registration.spots import grey_dtype, grey_image, spots_in_difference

if TYPE_CHECKING:
    from pathlib import Path

__all__ = ["DOME_PRIOR_FRACTION", "GATE", "MAX_CONDITION", "Registration", "RegistrationWarning", "register"]

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
#: Prior standard deviation of the dome's outer radius, as a fraction of the given sensor's (1 %: 0.2 mm on the
#: designed 20 mm, a moulded dome's tolerance). Centroids alone hardly tell the radius from the camera's
#: height (scaling both moves no ray but through the fixed shell thickness and cone sizes): without it
#: ``fit_dome`` wanders several-fold from the design on frames of the designed dome.
DOME_PRIOR_FRACTION = 0.01
#: Largest standard error of the camera centre's coordinates (mm) and of its rotation (deg) that passes
#: without a caution: a camera known no better puts the element regions (2.2 mm radius) off by a sizeable
#: part of their size; a well-pressed sensor pins it to about 0.05 mm and 0.1 deg.
POSE_SE_MM, POSE_SE_DEG = 1.0, 1.0
#: Largest standard error of the fitted focal lengths (fraction) and principal point (px) without a caution.
FOCAL_SE_FRACTION, CENTER_SE_PX = 0.02, 2.0
#: A reprojection RMS above this many times the clusters' centroid noise (and above :data:`RMS_FLOOR_PX`)
#: is a model that does not fit the spots: element offsets, or the camera model. The floor is what a
#: right model leaves on rendered stand-ins (0.06 px at 640x480, 0.11 px at 320x240: the spots' shapes,
#: not their noise); element offsets left unfitted give about 0.5 px, a wrong camera model 1 px or more.
RMS_NOISE_RATIO = 4.0
RMS_FLOOR_PX = 0.25
#: Signs of a wrong camera model: the camera this far from the given camera's position (mm) or rotated this
#: far from it (deg), by more than 3 standard errors; this many spot clusters near outer-ring elements
#: outside every gate or dropped; an outer ring's RMS this many times the inner's (and above 0.3 px).
MODEL_OFFSET_MM, MODEL_TILT_DEG, MODEL_OUTER_LOST, MODEL_RING_RATIO = 1.0, 3.0, 3, 3.0
#: Gains: a spread whose mean squared deviation from the median is at most this many squared standard
#: errors is noise; a median standard error above this fraction is uncertain.
GAIN_CHI2, GAIN_SE_FRACTION = 2.0, 0.05


class RegistrationWarning(OptitactWarning):
    """Registration worked, but some of its answer is not to be trusted; the message says what to change."""



def _opencv_camera(camera: Camera) -> Camera:
    """An OpenCV-model camera: the default equidistant camera becomes the equal OpenCV fisheye."""
    if isinstance(camera, FisheyeCamera):
        from optitact.optics.camera_models import OpenCVFisheyeCamera

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
    from optitact.optics.contact import contact_patches

    built = _as_built(sensor, offsets)
    forces = np.zeros((built.n_elements, 3))
    forces[:, 2] = 1.0
    return contact_patches(built, forces).centers[elements]


def _predict(sensor: DomeSensor, camera: Camera, elements: np.ndarray,
             offsets: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Predicted cluster centroids (n, 2) and ring RMS radii (n,) in pixels; NaN where a cone is not seen."""
    from optitact.optics.camera import pixel_from_dome

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
        self.dome_prior_mm = DOME_PRIOR_FRACTION * sensor.outer_radius
        self.n_prior = 2 * len(self.offset_elements) + bool(fit_dome)

    def build(self, x: np.ndarray):
        from optitact.optics.camera import rotation_from_rvec

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
            return np.full(2 * len(elements) + self.n_prior, 1e3)
        pred, _ = _predict(sensor, camera, elements)
        r = np.nan_to_num(measured - pred, nan=1e3).ravel()
        # priors, in units of prior_px per prior standard deviation (the loss's scale)
        if len(self.offset_elements):
            r = np.concatenate([r, self.prior_px * offsets[self.offset_elements].ravel() / OFFSET_PRIOR_MM])
        if self.fit_dome:
            dr = sensor.outer_radius - self.sensor0.outer_radius
            r = np.concatenate([r, [self.prior_px * dr / self.dome_prior_mm]])
        return r


def _fit(model: _Model, elements, measured, f_scale: float, x0=None):
    from scipy.optimize import least_squares

    return least_squares(model.residuals, model.x0 if x0 is None else x0, args=(elements, measured),
                         loss="soft_l1", f_scale=f_scale, x_scale="jac", method="trf", xtol=1e-12, ftol=1e-12,
                         gtol=1e-12, max_nfev=MAX_ITERATIONS)


def _check_conditioning(jac: np.ndarray, names: list[str], n_elements: int) -> None:
    """RegistrationError naming what the frames cannot pin down, unless the column-scaled ``J^T J`` is fine.

    Refused: a parameter the spots do not depend on, a condition number above :data:`MAX_CONDITION`.
    """
    norms = np.linalg.norm(jac, axis=0)
    if np.any(norms == 0):
        bad = [names[i] for i in np.flatnonzero(norms == 0)]
        raise RegistrationError(f"degenerate pose: the spots do not depend on {bad}; press more elements, "
                                f"spread over the rings and further from the apex (seen: {n_elements})")
    cond, worst = _least_determined(jac, names)
    if not cond <= MAX_CONDITION:
        raise RegistrationError(
            f"degenerate pose: the condition number of J^T J is {cond:.3g} (at most {MAX_CONDITION:.0e}): "
            f"the frames cannot tell {', '.join(worst)} apart; press more elements ({n_elements} seen), spread "
            f"over several rings and further from the apex, or fit fewer parameters")


def _least_determined(jac: np.ndarray, names: list[str]) -> tuple[float, list[str]]:
    """Condition number of the column-scaled ``J^T J`` and the three parameters it determines least."""
    norms = np.linalg.norm(jac, axis=0)
    js = jac / np.where(norms > 0, norms, 1.0)
    jtj = js.T @ js
    inflation = np.diag(np.linalg.pinv(jtj, hermitian=True))
    return float(np.linalg.cond(jtj)), [names[i] for i in np.argsort(-inflation)[:3]]


def _covariance(jac: np.ndarray, fun: np.ndarray, n_data: int, prior_px: float) -> np.ndarray:
    """Covariance of the parameters: centroid rows weighted by their residual variance, prior rows by the prior.

    The prior rows are the last ``len(fun) - n_data``, ``prior_px`` per prior standard deviation.
    """
    n = jac.shape[1]
    s2 = float(np.sum(fun[:n_data] ** 2)) / max(fun.size - n, 1)
    jd, jp = jac[:n_data], jac[n_data:] / prior_px
    info = jd.T @ jd / max(s2, 1e-300) + jp.T @ jp
    d = np.sqrt(np.diag(info))
    d = np.where(d > 0, d, 1.0)
    return np.linalg.pinv(info / np.outer(d, d), hermitian=True) / np.outer(d, d)


def _fit_observations(sensor, camera, clusters, obs_f, obs_c, obs_e, *, fit_intrinsics, fit_dome, fit_offsets,
                      f_scale) -> dict:
    """Fit the model to associated clusters; observations far beyond the robust spread are dropped once."""
    measured = np.array([clusters[f]["centroid"][c] for f, c in zip(obs_f, obs_c, strict=True)]).reshape(-1, 2)
    noise = np.array([clusters[f]["centroid_se"][c] for f, c in zip(obs_f, obs_c, strict=True)])
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
    return {"model": model, "res": res, "element": obs_e[keep], "frame": obs_f[keep], "keep": keep,
            "measured": measured, "noise": noise[keep]}


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
        with ``fit_gains`` ``gain_E`` (absolute, in the gain's units: the
        larger of the frames' noise through the pipeline's region sums and
        the spread of repeated presses; see :func:`optitact.registration.gains.element_gains`).
    unseen : tuple of int
        Elements the fit does not use: no frame showed them, or their clusters were rejected
        (:attr:`no_spot` are those with no spot at all; ``rejected`` says why the others were dropped).
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
    rejected : tuple of dict
        Spot clusters found but not used: ``frame``, ``row``, ``col`` (px), ``reason`` (``"compact"``: smaller
        than an element's ring, a reflection or a hot pixel; ``"gate"``: outside every element's gate;
        ``"outlier"``: associated, then dropped as an outlier of the fit), ``element`` (the element the fitted
        camera puts nearest, or None when none lies within an element spacing; for an outlier, its element),
        ``distance_px`` (from that element's predicted centre) and ``gate_px`` (its gate).
    centroid_noise_px : float
        RMS of the fitted clusters' centroid standard errors that the frames' noise explains (pixels, one
        axis, as ``rms_px``): the RMS a model that fits the spots reaches.
    cautions : tuple of str
        What the registration found not to be trusted (each also issued as a :class:`RegistrationWarning`).
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
    rejected: tuple = ()
    centroid_noise_px: float = math.nan
    cautions: tuple = ()

    @property
    def no_spot(self) -> tuple:
        """Unseen elements with no spot near them: ``unseen`` less those a gate or outlier rejection names."""
        found = {r["element"] for r in self.rejected if r["reason"] != "compact" and r["element"] is not None}
        return tuple(e for e in self.unseen if e not in found)

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
                                 "gain_force_n": self.gain_force_n, "gain_unfitted": list(self.gain_unfitted),
                                 "rejected": list(self.rejected),
                                 "centroid_noise_px": (self.centroid_noise_px
                                                       if math.isfinite(self.centroid_noise_px) else None),
                                 "cautions": list(self.cautions)}}

    def save(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_dict` as JSON (atomically); returns the path."""
        from optitact.io.files import atomic_write_text

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


def _bits(dtype: np.dtype) -> str:
    return f"{8 * dtype.itemsize}-bit ({dtype})"


def _check_depths(noload, pressed) -> None:
    """KindError for frames that are not grey levels; InputError for integer frames of different bit depths."""
    named = [("noload", grey_dtype(noload, "noload"))]
    if isinstance(pressed, np.ndarray):
        named.append(("pressed", grey_dtype(pressed, "pressed")))
    elif hasattr(pressed, "__len__"):
        named += [(f"pressed[{i}]", grey_dtype(f, f"pressed[{i}]")) for i, f in enumerate(pressed)]
    ints = [(n, d) for n, d in named if d is not None and d.kind in "ui"]
    other = [(n, d) for n, d in ints if d.itemsize != ints[0][1].itemsize]
    if other:
        (n1, d1), (n2, d2) = ints[0], other[0]
        raise InputError(f"{n1} is {_bits(d1)} but {n2} is {_bits(d2)}: the spots are the pressed frames' "
                         f"difference from the no-load frame, so all of them must come from one camera at one "
                         f"bit depth; record them again at one depth, or convert them to one (the 16-bit "
                         f"frames // 256 for 8-bit ones)")


def _rounded(frame: np.ndarray) -> float:
    """1.0 when every grey level of ``frame`` is an integer (a camera's frame, rounded), else 0.0."""
    return float(np.array_equal(frame, np.round(frame)))


def _rejections(clusters, compact, obs_f, obs_c, obs_e, keep, measured, pred, gate) -> list[dict]:
    """The clusters found but not used, each with the element the fitted camera puts nearest and why."""
    spacing = nearest_spacing(pred)
    out = []

    def add(frame, c, reason, element=None):
        d = np.linalg.norm(pred - c, axis=1)
        if element is None:
            element = int(np.nanargmin(d))
            if not d[element] <= spacing[element]:
                element = None
        e = int(np.nanargmin(d)) if element is None else element
        out.append({"frame": int(frame), "row": float(c[0]), "col": float(c[1]), "reason": reason,
                    "element": element, "distance_px": float(d[e]), "gate_px": float(gate[e])})

    for f, c in compact:
        add(f, c, "compact")
    for i, cl in enumerate(clusters):
        used = set(obs_c[obs_f == i].tolist())
        for j, c in enumerate(cl["centroid"]):
            if j not in used:
                add(i, c, "gate")
    for f, e, m in zip(obs_f[~keep], obs_e[~keep], measured[~keep], strict=True):
        add(f, m, "outlier", int(e))
    return sorted(out, key=lambda x: (x["frame"], x["row"], x["col"]))


def _pose_cautions(model, se, fit_sensor, sensor, *, fit_dome, fit_intrinsics) -> list[str]:
    """Cautions for parameters the frames cannot pin down (standard errors beyond a physical scale)."""
    loose = []
    axis = max(("x_mm", "y_mm", "z_mm"), key=se.get)
    if se[axis] > POSE_SE_MM:
        loose.append(f"the camera's {axis[0]} position (+- {se[axis]:.2g} mm; at most {POSE_SE_MM:g} mm)")
    rot = math.degrees(max(se["rvec_x"], se["rvec_y"], se["rvec_z"]))
    if rot > POSE_SE_DEG:
        loose.append(f"the camera's rotation (+- {rot:.2g} deg; at most {POSE_SE_DEG:g} deg)")
    if fit_intrinsics:
        cam = model.build(model.x0)[1]
        focal = max(se["fx"] / cam.fx, se["fy"] / cam.fy)
        if focal > FOCAL_SE_FRACTION:
            loose.append(f"the focal length (+- {100 * focal:.2g} %; at most {100 * FOCAL_SE_FRACTION:g} %)")
        centre = max(se["cx"], se["cy"])
        if centre > CENTER_SE_PX:
            loose.append(f"the principal point (+- {centre:.2g} px; at most {CENTER_SE_PX:g} px)")
    out = []
    if loose:
        drop = [flag for flag, on in (("--fit-intrinsics", fit_intrinsics), ("--fit-dome", fit_dome)) if on]
        out.append(f"the frames cannot pin down {', '.join(loose)}: press more elements, 5 to 8 per frame "
                   f"spread over all the rings and out towards the rim"
                   + (f", or fit fewer parameters (drop {' and '.join(drop)})" if drop else ""))
    if fit_dome:
        prior, sd = model.dome_prior_mm, se["outer_radius_mm"]
        if sd > prior / math.sqrt(2.0):  # the frames alone know the radius no better than its prior
            alone = prior * sd / math.sqrt(prior ** 2 - sd ** 2) if sd < prior else math.inf
            out.append(f"--fit-dome: the frames cannot pin the dome's outer radius down (alone they would give "
                       f"it +- {alone:.3g} mm: it trades off with the camera's height), so the fitted "
                       f"{fit_sensor.outer_radius:.3f} +- {sd:.3f} mm is the given {sensor.outer_radius:g} mm "
                       f"within its {100 * DOME_PRIOR_FRACTION:g} % tolerance (the prior) and says nothing "
                       f"about your dome; drop --fit-dome (the given radius is kept), or add presses of every "
                       f"ring, out to the rim")
    return out


def _model_cautions(camera, given, fit_camera, se, sensor, elements, r, noise, dropped, *,
                    fit_offsets) -> list[str]:
    """Cautions that the model does not fit the spots: the RMS beyond their noise, a wrong camera model."""
    from optitact.optics.camera import rotation_from_rvec

    rms, noise_px = float(np.sqrt(np.mean(r ** 2))), float(np.sqrt(np.mean(noise ** 2)))
    misfit = ""
    if rms > max(RMS_NOISE_RATIO * noise_px, RMS_FLOOR_PX):
        size = np.linalg.norm(r, axis=1)
        worst = ", ".join(f"{elements[i]} ({size[i]:.2f} px)" for i in np.argsort(-size)[:3])
        misfit = (f"the reprojection RMS {rms:.3f} px is {rms / max(noise_px, 1e-12):.0f}x what the spots' "
                  f"centroid noise explains ({noise_px:.3f} px; worst elements {worst})")

    rings = np.asarray(sensor.element_ring)
    signs = []
    d = fit_camera.position - camera.position
    lateral, se_lateral = math.hypot(d[0], d[1]), math.hypot(se["x_mm"], se["y_mm"])
    if abs(d[2]) > MODEL_OFFSET_MM and abs(d[2]) > 3.0 * se["z_mm"]:
        signs.append(f"the camera lands {abs(d[2]):.2f} mm {'below' if d[2] < 0 else 'above'} the given "
                     f"camera's height (z = {fit_camera.position[2]:.2f} mm, given "
                     f"{camera.position[2]:.2f} mm)")
    if lateral > MODEL_OFFSET_MM and lateral > 3.0 * se_lateral:
        signs.append(f"the camera lands {lateral:.2f} mm off the given camera's axis")
    rel = rotation_from_rvec(fit_camera.rvec) @ rotation_from_rvec(camera.rvec).T
    tilt = math.degrees(math.acos(float(np.clip((np.trace(rel) - 1.0) / 2.0, -1.0, 1.0))))
    if tilt > MODEL_TILT_DEG and tilt > 3.0 * math.degrees(max(se["rvec_x"], se["rvec_y"], se["rvec_z"])):
        signs.append(f"the camera is rotated {tilt:.1f} deg from the given camera")
    outer = int(rings.max())
    lost = [x["element"] for x in dropped
            if x["reason"] != "compact" and x["element"] is not None and rings[x["element"]] == outer]
    if len(lost) >= MODEL_OUTER_LOST:
        signs.append(f"{len(lost)} spot cluster(s) near outer-ring elements ({sorted(set(lost))}) fall outside "
                     f"every element's gate or off the fit")
    ring_of = rings[elements]
    per = {int(q): float(np.sqrt(np.mean(r[ring_of == q] ** 2))) for q in np.unique(ring_of)
           if np.sum(ring_of == q) >= 3}
    if len(per) >= 2:
        lo, hi = per[min(per)], per[max(per)]
        hi_noise = float(np.sqrt(np.mean(noise[ring_of == max(per)] ** 2)))
        if hi > MODEL_RING_RATIO * lo and hi > max(0.3, RMS_NOISE_RATIO * hi_noise):
            signs.append(f"the outer ring reprojects {hi / max(lo, 1e-12):.0f}x worse than the inner "
                         f"({hi:.2f} px vs {lo:.2f} px RMS)")
    if not signs:
        if not misfit:
            return []
        fix = ("each element's position may be off its design: add --fit-offsets (fit_offsets=True); if it "
               "stays, " if not fit_offsets else "")
        return [f"{misfit}: the model does not fit the spots; {fix}press harder (a dim cone that misses the "
                f"threshold pulls its element's centre), and check the camera model and its intrinsics "
                f"(--model, --camera-intrinsics)"]
    unseen_outer = int(np.sum(rings == outer)) - len(set(elements[ring_of == outer].tolist()))
    lead = f"{unseen_outer} outer-ring element(s) unseen and " if unseen_outer else ""
    if misfit:
        signs.append(misfit)
    return [f"{lead}{'; '.join(signs)}: is the camera model right? The camera given is a "
            f"{type(given).__name__}; a file from cv2.fisheye.calibrate (4 distortion coefficients) needs "
            f"--model fisheye (read_opencv_calibration(..., model='fisheye')), one from cv2.calibrateCamera "
            f"(5, 8, 12 or 14) --model pinhole; and the intrinsics must be this camera's at this frame size"]


def _gain_cautions(gains: dict, seen: list[int], size: tuple[int, int]) -> list[str]:
    """Cautions for gains the presses do not measure: a spread within their uncertainty, large uncertainty."""
    ok = np.array([e for e in seen if e not in gains["unfitted"]], dtype=np.int64)
    g, se = gains["gain"][ok], gains["se"][ok]
    good = np.isfinite(se) & (se > 0)
    if good.sum() < 3:
        return []
    g, se, ok = g[good], se[good], ok[good]
    rel = se / g
    mid = float(np.median(g))
    chi2 = float(np.mean(((g - mid) / se) ** 2))
    spread = 1.4826 * float(np.median(np.abs(g - mid))) / mid
    w, h = size
    fix = ("press harder or record larger frames, press each element more than once, or register without "
           "gains (--no-fit-gains)")
    if chi2 <= GAIN_CHI2:
        return [f"the element gains' spread ({100 * spread:.1f} % robust, {g.min():.2f} to {g.max():.2f}) is "
                f"no more than their standard errors explain (median {100 * np.median(rel):.1f} %): these "
                f"{w}x{h} frames do not measure the elements' gains; {fix}"]
    if np.median(rel) > GAIN_SE_FRACTION:
        worst = int(np.argmax(rel))
        return [f"the element gains are uncertain: median standard error {100 * np.median(rel):.1f} % "
                f"(largest {100 * rel[worst]:.1f} %, element {ok[worst]}) at {w}x{h}; {fix}"]
    return []


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
        :func:`optitact.optics.opencv_files.read_opencv_calibration`) and a starting pose. Default:
        the default equidistant camera of the frames' size. A
        :class:`FisheyeCamera` is fitted as the equal
        :class:`optitact.optics.camera_models.OpenCVFisheyeCamera`.
    sensor : DomeSensor, optional
        Default :meth:`DomeSensor.default`.
    fit_intrinsics : bool
        Also fit ``fx, fy, cx, cy`` (the distortion stays as given).
    fit_dome : bool
        Also fit the dome's outer radius (the shell thickness stays), with a
        Gaussian prior of :data:`DOME_PRIOR_FRACTION` of the given radius
        around it (the centroids alone hardly tell the radius from the
        camera's height); a caution says when the frames add little to it.
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
        :func:`optitact.calib.shipped.default_calibration`).
    k : float
        Spot threshold in robust noise sigmas (see :func:`detect_spots`).
    f_scale : float
        Soft-L1 loss scale (pixels): residuals beyond it count less.
    min_elements : int, optional
        Fewest distinct elements accepted; default ``(parameters + 4) / 2``
        rounded up (5 for the pose alone, 7 with the intrinsics). At least
        ``(parameters + 1) / 2`` rounded up (4 for the pose alone, 6 with the
        intrinsics): two coordinates per element, one to spare.

    Returns
    -------
    Registration

    Notes
    -----
    Gains: the pressed frames are read by a :class:`optitact.pipeline.frame_pipeline.Pipeline` of
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
    InputError
        Frames of different bit depths (a 16-bit no-load frame with 8-bit
        pressed ones), a ``min_elements`` below what the fit needs.
    KindError
        Frames that are not grey levels (bool, complex, object arrays).

    Warns
    -----
    RegistrationWarning
        For each part of the answer not to be trusted (see the module's
        *Checks*); the messages are also in ``cautions``.
    """
    sensor = DomeSensor.default() if sensor is None else check_type(sensor, DomeSensor, "sensor")
    _check_depths(noload, pressed)
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
    n_par = 6 + 4 * bool(fit_intrinsics) + bool(fit_dome)
    fewest = math.ceil((n_par + 1) / 2)
    if min_elements is None:
        need = max(4, math.ceil((n_par + 4) / 2))
    else:
        need = integer(min_elements, "min_elements")
        if need < fewest:
            raise InputError(f"min_elements must be an integer >= {fewest}: the fit's {n_par} parameters need "
                             f"two coordinates from each of at least {fewest} elements, one to spare; got "
                             f"{min_elements!r}")
    if fit_gains:
        from optitact.calib.fit import Calibration
        from optitact.calib.shipped import default_calibration

        calibration = default_calibration() if calibration is None else check_type(calibration, Calibration,
                                                                                    "calibration")
    given = camera
    camera = _opencv_camera(camera)

    # spots and clusters, per frame, seen with the nominal camera
    everything = np.arange(sensor.n_elements)
    pred0, ring0 = _predict(sensor, camera, everything)
    gate0 = GATE * nearest_spacing(pred0)
    diffs = [f - base for f in frames]
    spots = [spots_in_difference(d, k, 2) for d in diffs]
    # Grey levels rounded to integers carry a rounding noise of 1/12 grey level^2 that the robust sigma of
    # quantised, nearly dark frames (most differences exactly 0) does not see.
    rounding = [(_rounded(f) + _rounded(base)) / 12.0 for f in frames]
    clusters = [element_clusters(d, s, sensor, camera, sigma=math.sqrt(s.noise_sigma ** 2 + q))
                for d, s, q in zip(diffs, spots, rounding, strict=True)]
    rejected = [0] * len(frames)
    compact = []  # (frame, centroid) of clusters smaller than an element's ring
    for i, cl in enumerate(clusters):  # compact blobs are no element's ring
        if len(cl["rms"]) == 0:
            continue
        near = np.nanargmin(np.linalg.norm(cl["centroid"][:, None, :] - pred0[None], axis=-1), axis=1)
        ring = cl["rms"] >= MIN_RING_FRACTION * ring0[near]
        rejected[i] += int((~ring).sum())
        compact += [(i, c) for c in cl["centroid"][~ring]]
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
    all_f, all_c, all_e = (np.array(v, dtype=np.int64) for v in cur)
    model, res, elements, obs_f = fit["model"], fit["res"], fit["element"], fit["frame"]
    n_el = np.unique(elements).size
    if n_el < need:
        raise RegistrationError(f"too few elements: {n_el} distinct element(s) fit without outliers, and "
                                f"registration needs at least {need}; press more elements, spread over the "
                                f"rings")
    fit_sensor, fit_camera, offsets = model.build(res.x)
    _check_conditioning(res.jac, model.names, n_el)
    if not res.success:
        cond, worst = _least_determined(res.jac, model.names)
        raise RegistrationError(f"the fit did not converge ({res.message}): the frames hardly tell "
                                f"{', '.join(worst)} apart (condition number of J^T J {cond:.3g}); press more "
                                f"elements ({n_el} seen), spread over several rings and further from the apex, "
                                f"or fit fewer parameters")
    r = res.fun[:2 * len(elements)].reshape(-1, 2)
    cov = _covariance(res.jac, res.fun, 2 * len(elements), model.prior_px)
    std = np.sqrt(np.maximum(np.diag(cov), 0.0))
    seen = set(int(e) for e in elements)
    per_frame = []
    for i in range(len(frames)):
        mine = np.asarray(obs_f) == i
        per_frame.append({"elements": sorted(int(e) for e in elements[mine]), "rejected": int(rejected[i]),
                          "spots": int(len(spots[i].energy)), "noise_sigma": spots[i].noise_sigma})
    for i, cl in enumerate(clusters):  # clusters matched to no element
        per_frame[i]["rejected"] += int(len(cl["energy"]) - len(per_frame[i]["elements"]))
    std_errors = {name: float(v) for name, v in zip(model.names, std, strict=True)}
    rms = float(np.sqrt(np.mean(r ** 2)))
    noise_px = float(np.sqrt(np.mean(fit["noise"] ** 2)))
    dropped = _rejections(clusters, compact, all_f, all_c, all_e, fit["keep"], fit["measured"], pred, gate)
    cautions = _pose_cautions(model, std_errors, fit_sensor, sensor, fit_dome=bool(fit_dome),
                              fit_intrinsics=bool(fit_intrinsics))
    cautions += _model_cautions(camera, given, fit_camera, std_errors, sensor, elements, r, fit["noise"],
                                dropped, fit_offsets=bool(fit_offsets))
    gains = None
    if fit_gains:
        gains = element_gains(fit_sensor, fit_camera, base, frames, np.asarray(obs_f), elements,
                              press_force=press_force, calibration=calibration)
        fit_sensor = replace(fit_sensor, element_gain=tuple(gains["gain"]))
        std_errors |= {f"gain_{e}": float(gains["se"][e]) for e in sorted(seen)}
        cautions += _gain_cautions(gains, sorted(seen), (w, h))
    for text in cautions:
        warnings.warn(text, RegistrationWarning, stacklevel=2)
    return Registration(
        sensor=fit_sensor, camera=fit_camera, rms_px=rms, std_errors=std_errors,
        unseen=tuple(int(e) for e in everything if e not in seen), frames=tuple(per_frame),
        element=elements, frame=np.asarray(obs_f, dtype=np.int64), residuals_px=r, element_offsets=offsets,
        gain_force_n=None if gains is None else gains["force"],
        gain_unfitted=() if gains is None else gains["unfitted"], rejected=tuple(dropped),
        centroid_noise_px=noise_px, cautions=tuple(cautions))
