"""Benchmark: a stand-in for a real sensor, registered and calibrated from presses, against its own floor.

Not library code: ``optitact bench realism`` runs it.

The stand-in is the default sensor as a workshop would build it, drawn from a
seed and not told to the code under test (:func:`draw_standin`):

* camera: an OpenCV fisheye (Kannala-Brandt k1..k4 of a fibrescope) 0.1-0.5 mm
  off the dome axis, up to 0.2 mm off its nominal height and 0.5-2 deg tilted,
  focal length +-3 %, principal point +-8 px;
* dome: outer radius +-1 %, shell thickness +-5 %;
* elements: positions off by up to 0.2 mm, brightness +-15 %;
* rim light: a low-order azimuthal non-uniformity ``1 + s (a1 cos(phi - p1) +
  a2 cos 2(phi - p2))`` (a1 up to 10 %, a2 up to 5 %), felt fully at the rim
  (``s = theta / 90 deg``) and not at the apex, where light arrives from every
  side. It multiplies the light reaching each element (folded into the
  element's gain) and the dark no-load background's rim glow.

Physics the package does not model (:data:`EFFECTS`, each switchable, all on by
default, drawn from the stand-in's seed):

* ``stiffness``: each element's rubber a little stiffer or softer than the
  design: it deforms under a force ``F`` as the design does under ``s F``,
  ``s`` uniform in [0.9, 1.1] per element;
* ``nonlinearity``: and slightly nonlinear, as the design under ``F
  (Fz / 0.5 N)^g``, ``g`` uniform in [-0.05, 0.05] per element (together:
  the frame is rendered for ``s (Fz / 0.5 N)^g F``);
* ``blur``: a lens blur, Gaussian of 0.6 px standard deviation;
* ``vignetting``: the lens's fall-off, ``1 - 0.15 (r / r_edge)^2`` with ``r``
  the distance from the image centre and ``r_edge`` half the shorter side
  (0.85 at the image edge, held beyond);
* ``prnu``: 1 % pixel response non-uniformity (a fixed gain per pixel,
  normal around 1).

The optical ones act on the radiance reaching the sensor (no-load glow
included), before the CCD's noise.

Frames are rendered with the two-stage light transport through the
stand-in's own camera and geometry and exposed with the nominal CCD model.
The user's knowledge of the camera is what ``cv2.fisheye.calibrate`` on a
checkerboard gives: the true intrinsics with calibration errors (focal length
0.1 %, principal point 0.3 px, distortion coefficients 2 % of their size) and
no pose. Then, per stand-in:

1. ``nominal``: the default sensor and camera with the shipped calibration
   (what a user gets today);
2. ``registered``: :func:`optitact.registration.pose` on a no-load frame and six frames
   pressing every element once at one gauge setting (pose, element offsets and
   gains at that force, ``--press-force``), with the shipped calibration
   transferred to the result (its error model widened for the transfer);
3. ``presses``: the registered pipeline and a calibration fitted from ``N``
   single-element gauge presses per element (half normal, half inclined; the
   gauge reads 1 % of reading noise), refined from the transferred shipped
   calibration and from scratch;
4. ``matched``: the floor: the stand-in's own synthetic calibration (its true
   sensor and camera, a 200-frame ``blend`` design rendered the same way,
   fitted as the shipped one is: the joint model when it has one).

Each is scored on the same held-out frames (independent loads on every
element, ``calib.patterns.design_forces`` with seeds no other step uses) with
:func:`optitact.calib.held_out.press_report` (RMSE in % of full scale).
"""

from __future__ import annotations

import functools
import math
import sys
import warnings
from dataclasses import dataclass

import numpy as np

from optitact._validate import integer
from optitact.optics.camera import Camera, FisheyeCamera
from optitact.optics.camera_models import OpenCVFisheyeCamera, pose_from_position
from optitact.errors import InputError, OptitactWarning
from optitact.optics.sensor import DomeSensor

__all__ = ["EFFECTS", "StandIn", "draw_standin", "bench_realism", "REGISTRATION_PRESSES"]

#: The physics of a real sensor the package does not model, switchable in the stand-ins (module docstring).
EFFECTS = ("stiffness", "nonlinearity", "blur", "vignetting", "prnu")
#: Per-element stiffness and nonlinearity of the stand-ins: ``s`` in [1 - a, 1 + a], ``g`` in [-b, b].
STIFFNESS_SPREAD, NONLINEARITY_SPREAD = 0.10, 0.05
#: The force at which the nonlinearity ``(Fz / F_REF)^g`` is 1 (N).
NONLINEARITY_REF_N = 0.5
#: Lens blur (Gaussian sigma, px), vignetting at the image edge, pixel response non-uniformity (sigma).
BLUR_PX, VIGNETTING_EDGE, PRNU = 0.6, 0.85, 0.01

#: Elements pressed in each registration frame: all 41 once, spread over the rings (7 per frame).
REGISTRATION_PRESSES = ((0, 2, 5, 11, 14, 27, 33), (1, 4, 7, 9, 17, 21, 30, 37), (3, 6, 13, 19, 25, 29, 40),
                        (8, 10, 15, 23, 26, 34, 38), (12, 16, 20, 24, 28, 31, 35), (18, 22, 32, 36, 39))
#: The gauge setting of the registration presses (N, straight down).
REGISTRATION_FORCE_N = 0.6
#: Frames averaged into each pipeline's no-load baseline.
BASELINE_FRAMES = 4
#: Frames of the stand-in's own synthetic calibration (the matched floor).
MATCHED_FRAMES = 200


@dataclass(frozen=True)
class StandIn:
    """A stand-in sensor: the truth (as built) and what its user is told.

    Attributes
    ----------
    sensor : DomeSensor
        As built: dome radius and shell, ``element_offsets``, ``element_gain``
        (brightness times rim light).
    camera : OpenCVFisheyeCamera
        The true camera, pose included.
    intrinsics : OpenCVFisheyeCamera
        The user's checkerboard calibration: the true intrinsics with small
        errors, on the dome axis at the nominal height (no pose known).
    rim : tuple of float
        ``(a1, p1, a2, p2)`` of the rim light's non-uniformity.
    brightness : (N,) ndarray
        The elements' own brightness (without the rim light).
    """

    sensor: DomeSensor
    camera: OpenCVFisheyeCamera
    intrinsics: OpenCVFisheyeCamera
    rim: tuple
    brightness: np.ndarray
    stiffness: np.ndarray | None = None
    nonlinearity: np.ndarray | None = None
    effects: tuple = ()
    seed: int = 0

    def effective_forces(self, forces) -> np.ndarray:
        """The forces the design's rubber would need to deform as this stand-in's does under ``forces``.

        ``s (Fz / 0.5 N)^g F`` per element with the ``stiffness`` and
        ``nonlinearity`` effects on; ``forces`` as they are otherwise.
        """
        f = np.asarray(forces, dtype=np.float64)
        k = np.ones(f.shape[:-1])
        if "stiffness" in self.effects:
            k = k * self.stiffness
        if "nonlinearity" in self.effects:
            fz = np.maximum(f[..., 2], 1e-9)
            k = k * (fz / NONLINEARITY_REF_N) ** self.nonlinearity
        return f * k[..., None]

    def optics(self, radiance: np.ndarray) -> np.ndarray:
        """The radiance the pixels receive: lens blur, vignetting and pixel non-uniformity (those on)."""
        img = np.asarray(radiance, dtype=np.float32)
        if "blur" in self.effects:
            import cv2

            img = cv2.GaussianBlur(img, (0, 0), BLUR_PX, borderType=cv2.BORDER_REFLECT)
        h, w = img.shape[:2]
        gain = _pixel_gain(self.seed, h, w, "vignetting" in self.effects, "prnu" in self.effects)
        return img if gain is None else img * gain

    def rim_factor(self, polar, azimuth) -> np.ndarray:
        """The rim light's relative strength at dome points ``(polar, azimuth)`` (rad)."""
        return _rim_factor(self.rim, polar, azimuth)


@functools.lru_cache(maxsize=4)
def _pixel_gain(seed: int, h: int, w: int, vignetting: bool, prnu: bool) -> np.ndarray | None:
    """Each pixel's response: the vignetting's fall-off times the pixel non-uniformity (None: neither)."""
    if not (vignetting or prnu):
        return None
    gain = np.ones((h, w))
    if vignetting:
        rows, cols = np.mgrid[:h, :w]
        r = np.hypot(rows - (h - 1) / 2, cols - (w - 1) / 2) / (min(w, h) / 2)
        gain *= 1.0 - (1.0 - VIGNETTING_EDGE) * np.minimum(r, 1.0) ** 2
    if prnu:
        gain *= 1.0 + PRNU * np.random.default_rng([seed, 23]).standard_normal((h, w))
    out = gain.astype(np.float32)
    out.flags.writeable = False
    return out


def _rim_factor(rim, polar, azimuth) -> np.ndarray:
    """The rim light ``1 + s (a1 cos(phi - p1) + a2 cos 2(phi - p2))``, ``s = polar / 90 deg``."""
    a1, p1, a2, p2 = rim
    s = np.clip(np.asarray(polar) / (np.pi / 2), 0.0, 1.0)
    return 1.0 + s * (a1 * np.cos(azimuth - p1) + a2 * np.cos(2.0 * (azimuth - p2)))


def draw_standin(seed: int, size: tuple[int, int] = (640, 480), effects=EFFECTS) -> StandIn:
    """The stand-in sensor of ``seed`` (see the module docstring for the tolerances).

    ``effects``: which of :data:`EFFECTS` it has (all by default); the rest of
    the draw does not depend on them, so a seed is the same sensor with any.
    """
    effects = tuple(effects)
    bad = [e for e in effects if e not in EFFECTS]
    if bad:
        raise InputError(f"unknown stand-in effect(s) {bad}; valid: {', '.join(EFFECTS)}")
    rng = np.random.default_rng([int(seed), 18])
    w, h = size
    nominal = DomeSensor.default()
    n = nominal.n_elements
    r_off = 0.2 * np.sqrt(rng.uniform(0, 1, n))  # uniform over a 0.2 mm disc
    a_off = rng.uniform(0, 2 * np.pi, n)
    offsets = np.stack([r_off * np.cos(a_off), r_off * np.sin(a_off)], axis=1)
    brightness = rng.uniform(0.85, 1.15, n)
    rim = (rng.uniform(0, 0.10), rng.uniform(0, 2 * np.pi), rng.uniform(0, 0.05), rng.uniform(0, np.pi))
    shaped = DomeSensor(outer_radius=nominal.outer_radius * (1 + rng.uniform(-0.01, 0.01)),
                        shell_thickness=nominal.shell_thickness * (1 + rng.uniform(-0.05, 0.05)),
                        element_offsets=offsets)
    gains = brightness * _rim_factor(rim, shaped.element_polar, shaped.element_azimuth)
    sensor = DomeSensor(outer_radius=shaped.outer_radius, shell_thickness=shaped.shell_thickness,
                        element_offsets=offsets, element_gain=gains)
    f0 = (min(w, h) / 2) / math.radians(70.0)  # the default equidistant camera's focal length (px/rad)
    fx = f0 * (1 + rng.uniform(-0.03, 0.03))
    fy = fx * (1 + rng.uniform(-0.003, 0.003))
    cx, cy = (w - 1) / 2 + rng.uniform(-8, 8), (h - 1) / 2 + rng.uniform(-8, 8)
    dist = (rng.uniform(-0.05, 0.05), rng.uniform(-0.02, 0.02), rng.uniform(-0.005, 0.005),
            rng.uniform(-0.002, 0.002))
    off, a = rng.uniform(0.1, 0.5), rng.uniform(0, 2 * np.pi)
    tilt, b = math.radians(rng.uniform(0.5, 2.0)), rng.uniform(0, 2 * np.pi)
    rvec = (tilt * math.cos(b), tilt * math.sin(b), rng.uniform(-0.01, 0.01))
    z = FisheyeCamera(width=w, height=h).z
    dz = rng.uniform(-0.2, 0.2)
    camera = OpenCVFisheyeCamera(w, h, fx=fx, fy=fy, cx=cx, cy=cy, dist=dist,
                                 **pose_from_position((off * math.cos(a), off * math.sin(a), z + dz), rvec))
    # what cv2.fisheye.calibrate on a checkerboard tells the user: small errors, no pose
    intrinsics = OpenCVFisheyeCamera(w, h, fx=fx * (1 + rng.normal(0, 0.001)),
                                     fy=fy * (1 + rng.normal(0, 0.001)),
                                     cx=cx + rng.normal(0, 0.3), cy=cy + rng.normal(0, 0.3),
                                     dist=tuple(float(d * (1 + rng.normal(0, 0.02))) for d in dist),
                                     **pose_from_position((0.0, 0.0, z)))
    rubber = np.random.default_rng([int(seed), 21])  # drawn apart: the geometry above is the same either way
    stiffness = 1.0 + rubber.uniform(-STIFFNESS_SPREAD, STIFFNESS_SPREAD, n)
    nonlinearity = rubber.uniform(-NONLINEARITY_SPREAD, NONLINEARITY_SPREAD, n)
    return StandIn(sensor, camera, intrinsics, tuple(float(v) for v in rim), brightness, stiffness,
                   nonlinearity, effects, int(seed))


# ----------------------------------------------------------------------------- rendering the stand-in
class _Frames:
    """Renders and exposes frames of one stand-in (two-stage, its own camera and geometry)."""

    def __init__(self, standin: StandIn, *, variant=None):
        from optitact.optics.ccd import CCD
        from optitact.render.background import noload_radiance
        from optitact.render.emission import shipped_table

        self.standin = standin
        designed = DomeSensor.default()
        # The guided light reaching a patch is the designed dome's (the table is measured once for it; the
        # stand-in's +-1 % radius and +-5 % shell change it far less than its +-15 % element gains).
        self.table = shipped_table(designed, FisheyeCamera(width=standin.camera.width,
                                                           height=standin.camera.height))
        bg = noload_radiance(designed, standin.camera, variant=variant)
        rows, cols = np.mgrid[:standin.camera.height, :standin.camera.width]
        # the no-load frame is dark but for the rim glow: the rim light's non-uniformity scales it by the
        # azimuth round the image of the dome axis
        axis = standin.camera.project(np.array([[0.0, 0.0, standin.sensor.outer_radius]]), standin.sensor)[0]
        phi = np.arctan2(rows - axis[0], cols - axis[1])  # dome x along columns, y along rows
        self.background = (bg * standin.rim_factor(np.pi / 2, phi)).astype(np.float32)
        self.ccd = CCD()

    def radiance(self, forces: np.ndarray) -> np.ndarray:
        from optitact.render import render

        radiance = render(self.standin.sensor, self.standin.effective_forces(forces),
                          camera=self.standin.camera, transport="two_stage", table=self.table,
                          background=self.background)
        return self.standin.optics(radiance)

    def frame(self, forces: np.ndarray, seed: int) -> np.ndarray:
        return self.ccd.expose(self.radiance(forces), seed=seed)

    def baseline(self, seed: int) -> np.ndarray:
        empty = self.radiance(np.zeros((self.standin.sensor.n_elements, 3)))
        return np.stack([self.ccd.expose(empty, seed=s) for s in
                         np.random.SeedSequence([seed, 7]).generate_state(BASELINE_FRAMES)])


def _readings(frames: _Frames, pipelines: dict, forces: np.ndarray, seed: int, desc: str, progress: bool):
    """Render every frame of ``forces`` (T, E, 3) once and read it with every pipeline: {name: Readings}."""
    from tqdm import tqdm

    from optitact.pipeline.readings import Readings

    seeds = np.random.SeedSequence([seed, 11]).generate_state(len(forces))
    out = {k: [] for k in pipelines}
    for f, s in tqdm(zip(forces, seeds, strict=True), total=len(forces), desc=desc, unit="frame",
                     file=sys.stderr, disable=not progress, leave=False):
        img = frames.frame(f, int(s))
        for k, p in pipelines.items():
            out[k].append(p.process(img))
    return {k: Readings(np.stack([r.G for r in v]), np.stack([r.u for r in v]),
                        np.stack([r.contact for r in v]), np.stack([r.saturated for r in v]))
            for k, v in out.items()}


def _press_forces(n: int, n_el: int, seed: int) -> np.ndarray:
    """The gauge protocol: ``n`` single-element presses per element, half normal, half inclined (T, E, 3)."""
    rng = np.random.default_rng([seed, 5])
    f = np.zeros((n * n_el, n_el, 3))
    t = 0
    for e in range(n_el):
        for j in range(n):
            fz = rng.uniform(0.05, 1.0)  # the range the held-out loads span (the design's)
            mu = 0.0 if j % 2 == 0 else rng.uniform(0.1, 0.35)
            phi = rng.uniform(0, 2 * np.pi)
            f[t, e] = (mu * fz * math.cos(phi), mu * fz * math.sin(phi), fz)
            t += 1
    return f[rng.permutation(len(f))]


#: The F/T sensor of the wrench protocol: 30 mm below the dome's base, turned 15 deg about z and
#: slightly off the axis (a mount as built).
FT_POSE = {"position_mm": [1.0, -2.0, -30.0], "rotation_deg": [0.0, 0.0, 15.0]}
#: Largest element force (N) a wrench-protocol press may give, and the largest ratio of an element's shear
#: to its normal force (the calibrated range: the design's loads, :class:`optitact.calib.sets.Design`).
WRENCH_MAX_ELEMENT_N, WRENCH_MAX_SHEAR_RATIO = 1.0, 0.35


def _wrench_loads(n: int, sensor: DomeSensor, seed: int) -> np.ndarray:
    """The wrench protocol: ``n`` presses of random objects at random poses (T, E, 3) element-local forces.

    An object (sphere of 3-15 mm radius, flat punch of 2-6 mm, rounded edge of 0.5-2 mm tip, lying
    cylinder of 3-10 mm) is pressed near an element (3 mm rms off it along the dome, the elements taken
    in a random order, round after round: a lab moving the object over the whole dome), turned at
    random about its axis, to a total force of 0.2-2.5 N (less where an element would
    carry more than :data:`WRENCH_MAX_ELEMENT_N`), then slid by up to 0.3 mm (friction 0.5) for shear
    (:func:`optitact.forces.indenter.press`). A press that shears an element beyond
    :data:`WRENCH_MAX_SHEAR_RATIO` of its normal force (an object pressing a feeler from the side) is
    outside what a calibration covers, and another is drawn.
    """
    from optitact.forces.indenter import Cylinder, Edge, Flat, Pose, Sphere, press

    rng = np.random.default_rng([seed, 29])
    out = np.zeros((n, sensor.n_elements, 3))
    order = {}
    t = 0
    while t < n:
        kind = rng.integers(4)
        shape = (Sphere(rng.uniform(3, 15)), Flat(rng.uniform(2, 6)),
                 Edge(length=rng.uniform(10, 20), tip_radius=rng.uniform(0.5, 2.0)),
                 Cylinder(rng.uniform(3, 10), 30.0))[kind]
        if t % sensor.n_elements == 0 and t not in order:
            order[t] = rng.permutation(sensor.n_elements)  # the next round over the dome
        e = order[t - t % sensor.n_elements][t % sensor.n_elements]
        # near element e: its point on the dome, moved by 3 mm (rms, along the surface) in a random direction
        polar = math.degrees(sensor.element_polar[e]) + math.degrees(rng.normal(0, 3.0) / sensor.outer_radius)
        azimuth = math.degrees(sensor.element_azimuth[e]) + math.degrees(
            rng.normal(0, 3.0) / (sensor.outer_radius * max(math.sin(sensor.element_polar[e]), 0.2)))
        pose = Pose.touching(sensor, float(np.clip(abs(polar), 0.0, 80.0)), azimuth,
                             spin_deg=rng.uniform(0, 360))
        slide = rng.uniform(0, 0.3) * np.array([math.cos(a := rng.uniform(0, 2 * np.pi)), math.sin(a)])
        total = rng.uniform(0.2, 2.5)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", OptitactWarning)
                f = press(sensor, shape, pose, force=total, slide=slide, friction=0.5).forces
                top = float(f[:, 2].max())
                if top > WRENCH_MAX_ELEMENT_N:
                    f = press(sensor, shape, pose, force=total * 0.95 * WRENCH_MAX_ELEMENT_N / top, slide=slide,
                              friction=0.5).forces
        except InputError:  # too deep for this object at this force: draw another
            continue
        f = np.where(f[:, 2:3] > 1e-4, f, 0.0)  # elements the object does not press
        if not f[:, 2].any() or np.any(np.hypot(f[:, 0], f[:, 1]) > WRENCH_MAX_SHEAR_RATIO * f[:, 2]):
            continue  # nothing pressed, or an element sheared beyond the calibrated range: another object
        out[t] = f
        t += 1
    return out


def _wrench_calibrations(readings, loads, counts, reg, start, standin: StandIn, seed: int) -> list:
    """Calibrations from the first ``n`` wrench-protocol frames (each of ``counts``): refined from ``start``.

    The F/T sensor reads the true wrench with 0.5 % of reading noise (and its floor). A fit the frames
    cannot support (an element never loaded) is ``{"refused": message}``.
    """
    from optitact.calib.wrench import SensorPose, Wrenches, element_wrench
    from optitact.calib.wrench_fit import FT_FLOOR, FT_NOISE, fit_wrenches
    from optitact.pipeline.readings import Readings

    pose = SensorPose.from_dict(FT_POSE)
    true = element_wrench(standin.sensor, pose, loads)
    rng = np.random.default_rng([seed, 31])
    force = np.linalg.norm(true[:, :3], axis=1, keepdims=True)
    torque = np.linalg.norm(true[:, 3:], axis=1, keepdims=True)
    sd = np.concatenate([np.sqrt((FT_NOISE * force) ** 2 + FT_FLOOR[0] ** 2).repeat(3, 1),
                         np.sqrt((FT_NOISE * torque) ** 2 + FT_FLOOR[1] ** 2).repeat(3, 1)], axis=1)
    measured = true + sd * rng.standard_normal(true.shape)
    out = []
    for n in counts:
        sub = Readings(readings.G[:n], readings.u[:n], readings.contact[:n], readings.saturated[:n])
        w = Wrenches(np.arange(n), measured[:n], np.arange(2, n + 2), "ft.csv")
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", OptitactWarning)
                out.append(fit_wrenches(sub, w, pose, sensor=reg.sensor, camera=reg.camera, start=start,
                                        seed=seed))
        except InputError as exc:
            out.append({"refused": str(exc)})
    return out


def _pose_error(fit: Camera, true: Camera) -> tuple[float, float]:
    rel = fit.rotation @ true.rotation.T
    angle = math.degrees(math.acos(float(np.clip((np.trace(rel) - 1) / 2, -1, 1))))
    return float(np.linalg.norm(fit.position - true.position)), angle


def _registration_errors(reg, standin: StandIn) -> dict:
    """Registration against the hidden truth."""
    mm, deg = _pose_error(reg.camera, standin.camera)
    n = standin.sensor.n_elements
    def offsets(sensor):
        return np.asarray(sensor.element_offsets) if sensor.element_offsets else np.zeros((n, 2))

    true_off, fit_off = offsets(standin.sensor), offsets(reg.sensor)
    seen = np.setdiff1d(np.arange(standin.sensor.n_elements), reg.unseen)
    out = {"pose_mm": mm, "pose_deg": deg, "rms_px": reg.rms_px,
           "focal_pct": 100.0 * abs(reg.camera.fx / standin.camera.fx - 1.0),
           "offsets_rms_mm": float(np.sqrt(np.mean(np.sum((fit_off - true_off)[seen] ** 2, axis=1)))),
           "offsets_true_rms_mm": float(np.sqrt(np.mean(np.sum(true_off ** 2, axis=1)))),
           "dome_radius_pct": 100.0 * abs(reg.sensor.outer_radius / standin.sensor.outer_radius - 1.0),
           "unseen": [int(e) for e in reg.unseen]}
    if reg.sensor.element_gain:
        g_fit, g_true = reg.sensor.gains[seen], standin.sensor.gains[seen]
        rel = (g_fit / np.median(g_fit)) / (g_true / np.median(g_true))
        out["gains_rms_pct"] = float(100.0 * np.sqrt(np.mean((rel - 1.0) ** 2)))
    return out


def _press_calibrations(readings, gauge, n: int, reg, start, options: dict, seed: int) -> dict:
    """Calibrations from ``n`` presses per element (drawn, seeded): refined from ``start`` and from scratch.

    A fit that is refused (from scratch below its minimum presses) is ``{"refused": message}``.
    """
    from optitact.calib.press_fit import fit_presses
    from optitact.pipeline.readings import Readings

    pressed = np.any(gauge != 0, axis=-1) & readings.contact & ~readings.saturated
    rng = np.random.default_rng([seed, n, 19])
    chosen = np.zeros_like(pressed)
    for e in range(readings.n_elements):
        pool = np.flatnonzero(pressed[:, e])
        chosen[rng.choice(pool, min(n, pool.size), replace=False), e] = True
    sub = Readings(readings.G, readings.u, chosen, readings.saturated)
    forces = np.where(chosen[..., None], gauge, 0.0)
    out = {}
    kinds = (("refined", start, "shapes"), ("groups", start, "groups"), ("scratch", None, None))
    for kind, st, method in kinds:
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", OptitactWarning)
                out[kind] = fit_presses(sub, forces, pressed=chosen, sensor=reg.sensor, camera=reg.camera,
                                        pipeline_options=options, start=st,
                                        **({} if method is None else {"method": method}))
        except InputError as exc:
            out[kind] = {"refused": str(exc)}
    return out


#: The full scales the errors are given in (N): the sensor's range of normal force and of shear.
FULL_SCALE_N = {"fx": 0.5, "fy": 0.5, "fz": 1.0}


def _report(cal, readings, forces) -> dict:
    from optitact.calib.held_out import press_report

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptitactWarning)
        rep = press_report(cal, readings, forces, np.any(forces != 0, axis=-1))
    return {"rmse_pct_fs": {a: 100.0 * rep["rmse_n"][a] / FULL_SCALE_N[a] for a in FULL_SCALE_N},
            "rmse_n": rep["rmse_n"], "bias_n": rep["bias_n"], "coverage_90": rep["coverage_90"],
            "error_model": "fitted" if cal.error_model is not None else "residuals"}


def bench_realism(*, sensors: int = 10, force_sensors: int = 2, ns=(2, 5, 10, 20), test_frames: int = 40,
                  size: tuple[int, int] = (640, 480), seed: int = 0, variant: str | None = None, plot=None,
                  matched_frames: int = MATCHED_FRAMES, progress: bool = True, effects=EFFECTS,
                  wrench_counts=(50, 100, 200, 400)) -> dict:
    """Registration and force errors on stand-ins for a real sensor (see the module docstring).

    Parameters
    ----------
    sensors : int
        Stand-ins registered (pose, focal length, offsets, gains against the
        hidden truth), seeds ``seed .. seed + sensors - 1``.
    force_sensors : int
        Of those, how many also get the force study (held-out frames, press
        calibrations, the matched floor): the first ones.
    ns : sequence of int
        Presses per element of the measured calibrations.
    test_frames : int
        Held-out frames per stand-in (every element loaded in each).
    size : (int, int)
        Frame width and height.
    seed : int
    variant : str, optional
        Mitsuba variant for the one-time no-load frame of the camera.
    plot : path-like, optional
        PNG: force errors against presses per element, and registration errors per stand-in.
    matched_frames : int
        Frames of each force stand-in's own synthetic calibration (the floor).
    progress : bool
    effects : sequence of str
        Which of :data:`EFFECTS` the stand-ins have (default all).
    wrench_counts : sequence of int
        Frames of the wrench protocol (:func:`_wrench_loads`, a six-axis
        F/T sensor's totals and no single-element presses) of the
        calibrations fitted to totals; empty: none.

    Returns
    -------
    dict
        ``registration`` (per stand-in and the worst over them), ``forces``
        (per force stand-in: ``nominal``, ``registered``, ``presses``
        (``ns``, ``refined``, ``scratch``), ``matched``; and ``summary``: the
        per-axis RMSE medians over the force stand-ins), ``setup``.
    """
    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import default_calibration
    from optitact.calib.patterns import design_forces, pattern_forces
    from optitact.calib.sets import Design
    from optitact.pipeline.frame_pipeline import Pipeline
    from optitact.errors import RegistrationError
    from optitact.registration.pose import register

    sensors = integer(sensors, "sensors", minimum=1)
    force_sensors = integer(force_sensors, "force_sensors", minimum=0)
    if force_sensors > sensors:
        raise InputError(f"force_sensors ({force_sensors}) must be at most sensors ({sensors})")
    ns = tuple(integer(n, "ns", minimum=1) for n in ns)
    wrench_counts = tuple(integer(n, "wrench_counts", minimum=2) for n in wrench_counts)
    test_frames = integer(test_frames, "test_frames", minimum=1)
    matched_frames = integer(matched_frames, "matched_frames", minimum=8)
    shipped = default_calibration()
    options = dict(shipped.pipeline_options)
    n_el = shipped.sensor.n_elements
    w, h = size
    reg_rows, force_rows = [], []
    for i in range(sensors):
        s_seed = seed + i
        standin = draw_standin(s_seed, size, effects)
        frames = _Frames(standin, variant=variant)
        base = frames.baseline(s_seed)
        press = np.zeros((len(REGISTRATION_PRESSES), n_el, 3))
        for k, els in enumerate(REGISTRATION_PRESSES):
            press[k, list(els), 2] = REGISTRATION_FORCE_N
        pressed = [frames.frame(f, int(s)) for f, s in
                   zip(press, np.random.SeedSequence([s_seed, 13]).generate_state(len(press)), strict=True)]
        row = {"seed": s_seed}
        try:
            reg = register(base.mean(axis=0), pressed, camera=standin.intrinsics, fit_offsets=True,
                           fit_gains=True, press_force=REGISTRATION_FORCE_N)
        except RegistrationError as exc:
            row["refused"] = str(exc)
            reg_rows.append(row)
            continue
        row.update(_registration_errors(reg, standin))
        try:  # for comparison: the intrinsics fitted from the frames too, instead of the checkerboard's
            alone = register(base.mean(axis=0), pressed, camera=standin.intrinsics, fit_offsets=True,
                             fit_intrinsics=True)
            row["fit_intrinsics"] = {k: v for k, v in _registration_errors(alone, standin).items()
                                     if k in ("pose_mm", "pose_deg", "rms_px", "focal_pct")}
        except RegistrationError as exc:
            row["fit_intrinsics"] = {"refused": str(exc)}
        reg_rows.append(row)
        if progress:
            print(f"optitact: bench realism: stand-in {s_seed}: pose {row['pose_mm']:.3f} mm / "
                  f"{row['pose_deg']:.3f} deg, {row['rms_px']:.3f} px RMS", file=sys.stderr)
        if i >= force_sensors:
            continue
        # --- forces: every pipeline reads the same frames
        designed_cam = FisheyeCamera(width=w, height=h)
        pipes = {"nominal": Pipeline(shipped.sensor, designed_cam, baseline=base, **options),
                 "registered": Pipeline(reg.sensor, reg.camera, baseline=base, **options),
                 "matched": Pipeline(standin.sensor, standin.camera, baseline=base, **options)}
        # held-out frames: every element loaded at once (independent loads), and gauge-style single presses
        tests = {"independent": design_forces(test_frames, n_el, Design(), seed=10_000 + s_seed),
                 "single": pattern_forces("single", test_frames * 4, shipped.sensor, Design(),
                                          seed=10_000 + s_seed)}
        test = {fam: _readings(frames, pipes, f, 20_000 + s_seed + 500 * k, f"held-out ({fam})", progress)
                for k, (fam, f) in enumerate(tests.items())}
        transferred = shipped.transferred(reg.sensor, reg.camera)
        out = {"seed": s_seed,
               "nominal": {fam: _report(shipped, test[fam]["nominal"], f) for fam, f in tests.items()},
               "registered": {fam: _report(transferred, test[fam]["registered"], f)
                              for fam, f in tests.items()}}
        press_f = _press_forces(max(ns), n_el, 30_000 + s_seed)
        gauge = press_f * (1 + 0.01 * np.random.default_rng([s_seed, 17]).normal(size=press_f.shape))
        pr = _readings(frames, {"registered": pipes["registered"]}, press_f, 40_000 + s_seed, "presses",
                       progress)["registered"]
        out["presses"] = {"ns": list(ns), "refined": [], "groups": [], "scratch": []}
        for n in ns:
            for kind, cal in _press_calibrations(pr, gauge, n, reg, transferred, options, s_seed).items():
                out["presses"][kind].append(cal if isinstance(cal, dict) else
                                            {fam: _report(cal, test[fam]["registered"], f)
                                             for fam, f in tests.items()})
        if wrench_counts:
            loads = _wrench_loads(max(wrench_counts), standin.sensor, 70_000 + s_seed)
            wr = _readings(frames, {"registered": pipes["registered"]}, loads, 80_000 + s_seed, "wrench frames",
                           progress)["registered"]
            out["wrench"] = {"counts": list(wrench_counts), "refined": [
                cal if isinstance(cal, dict) else {fam: _report(cal, test[fam]["registered"], f)
                                                   for fam, f in tests.items()}
                for cal in _wrench_calibrations(wr, loads, wrench_counts, reg, transferred, standin, s_seed)]}
        cal_f = design_forces(matched_frames, n_el, Design(pattern="blend"), seed=50_000 + s_seed,
                              sensor=standin.sensor)
        own = _readings(frames, {"matched": pipes["matched"]}, cal_f, 60_000 + s_seed, "matched set",
                        progress)["matched"]
        matched = Calibration.fit(own, cal_f, sensor=standin.sensor, camera=standin.camera,
                                  pipeline_options=options, model=shipped.model,
                                  joint=shipped.crosstalk is not None)
        out["matched"] = {fam: _report(matched, test[fam]["matched"], f) for fam, f in tests.items()}
        force_rows.append(out)
    result = {"setup": {"sensors": sensors, "force_sensors": force_sensors, "size": [w, h], "seed": seed,
                        "test_frames": test_frames, "ns": list(ns),
                        "registration_force_n": REGISTRATION_FORCE_N,
                        "matched_frames": matched_frames, "gauge_noise": "1 % of reading",
                        "render": "two_stage, stand-in's own camera and geometry, nominal CCD",
                        "effects": list(effects), "full_scale_n": FULL_SCALE_N,
                        "wrench_counts": list(wrench_counts), "ft_pose": FT_POSE,
                        "ft_noise": "0.5 % of reading"},
              "registration": {"per_sensor": reg_rows, "worst": _worst(reg_rows)},
              "forces": {"per_sensor": force_rows, "summary": _summary(force_rows, ns, wrench_counts)}}
    if plot is not None:
        result["plot"] = str(_plot(result, plot))
    return result


def _worst(rows: list) -> dict:
    ok = [r for r in rows if "refused" not in r]
    keys = ("pose_mm", "pose_deg", "rms_px", "focal_pct", "offsets_rms_mm", "gains_rms_pct", "dome_radius_pct")
    out = {k: max(r[k] for r in ok) for k in keys if ok and all(k in r for r in ok)}
    out["refused"] = [r["seed"] for r in rows if "refused" in r]
    alone = [r["fit_intrinsics"] for r in ok if "refused" not in r.get("fit_intrinsics", {"refused": 1})]
    keys = ("pose_mm", "pose_deg", "rms_px", "focal_pct")
    out["fit_intrinsics"] = {k: max(r[k] for r in alone) for k in keys} if alone else None
    return out


def _summary(rows: list, ns, wrench_counts=()) -> dict:
    """Per held-out family: per-axis RMSE (% FS), median over the force stand-ins, per row of the study."""
    if not rows:
        return {}
    axes = ("fx", "fy", "fz")

    def med(reports):
        good = [r for r in reports if "refused" not in r]
        return {a: float(np.median([r["rmse_pct_fs"][a] for r in good])) for a in axes} if good else None

    def cov(reports):
        good = [r for r in reports if "refused" not in r and r.get("coverage_90")]
        return {a: float(np.median([r["coverage_90"][a] for r in good])) for a in axes} if good else None

    out = {}
    for fam in rows[0]["matched"]:
        one = {"nominal": med([r["nominal"][fam] for r in rows]),
               "registered": med([r["registered"][fam] for r in rows]),
               "matched": med([r["matched"][fam] for r in rows])}
        for kind in ("refined", "groups", "scratch"):
            one[kind] = {str(n): med([r["presses"][kind][j].get(fam, r["presses"][kind][j]) for r in rows])
                         for j, n in enumerate(ns)}
        if wrench_counts:
            one["wrench"] = {str(n): med([r["wrench"]["refined"][j].get(fam, r["wrench"]["refined"][j])
                                          for r in rows]) for j, n in enumerate(wrench_counts)}
        one["coverage_90"] = {"registered": cov([r["registered"][fam] for r in rows]),
                              "refined": {str(n): cov([r["presses"]["refined"][j].get(fam, {}) for r in rows])
                                          for j, n in enumerate(ns)},
                              **({"wrench": {str(n): cov([r["wrench"]["refined"][j].get(fam, {}) for r in rows])
                                             for j, n in enumerate(wrench_counts)}} if wrench_counts else {})}
        floor = one["matched"]
        one["refined_over_matched"] = {str(n): ({a: v[a] / floor[a] for a in axes} if v else None)
                                       for n, v in one["refined"].items()}
        out[fam] = one
    return out


def _plot(result: dict, path):
    from optitact._optional import require
    from optitact.io.files import atomic_write_png_figure

    require("matplotlib", purpose="the realism plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    summary = result["forces"]["summary"]
    fig, axes = plt.subplots(1, 1 + max(len(summary), 1), figsize=(6 * (1 + max(len(summary), 1)), 4.8))
    colours = {"fx": "tab:blue", "fy": "tab:orange", "fz": "tab:green"}
    n_force = len(result["forces"]["per_sensor"])
    for ax, (fam, summ) in zip(axes, summary.items(), strict=False):
        ns = [int(n) for n in summ["refined"]]
        for a, c in colours.items():
            for kind, style in (("refined", "-o"), ("groups", ":d"), ("scratch", "--s")):
                pts = [(n, v[a]) for n, v in zip(ns, summ[kind].values(), strict=True) if v]
                if pts:
                    ax.plot(*zip(*pts, strict=True), style, color=c, label=f"{a.upper()} presses ({kind})")
            wrench = summ.get("wrench", {})
            pts = [(int(n) / 41, v[a]) for n, v in wrench.items() if v]
            if pts:  # force/torque frames, at their number per element
                ax.plot(*zip(*pts, strict=True), "-.^", color=c, label=f"{a.upper()} F/T totals (frames / 41)")
            ax.axhline(summ["matched"][a], color=c, lw=1, ls=":", label=f"{a.upper()} matched floor")
            ax.scatter([ns[0] * 0.6], [summ["registered"][a]], marker="^", color=c)
            ax.scatter([ns[0] * 0.45], [summ["nominal"][a]], marker="x", color=c)
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.set_xticks([ns[0] * 0.45, ns[0] * 0.6, *ns])
        ax.set_xticklabels(["nominal", "registered", *map(str, ns)], rotation=30)
        ax.minorticks_off()
        ax.set_xlabel("presses per element (after registration); F/T frames / 41")
        ax.set_ylabel("held-out RMSE (% of full scale)")
        ax.set_title(f"held-out {fam} loads, median of {n_force} stand-in(s)")
        ax.legend(fontsize=7, ncol=2)
    if not summary:
        axes[0].set_axis_off()
    bx = axes[-1]
    rows = [r for r in result["registration"]["per_sensor"] if "refused" not in r]
    x = [r["seed"] for r in rows]
    bx.bar(np.arange(len(x)) - 0.2, [1000 * r["pose_mm"] for r in rows], 0.4, label="pose error (um)")
    bx.bar(np.arange(len(x)) + 0.2, [1000 * r["pose_deg"] for r in rows], 0.4, label="rotation error (mdeg)")
    bx.axhline(50, color="tab:blue", ls=":", lw=1, label="bar: 50 um")
    bx.axhline(100, color="tab:orange", ls=":", lw=1, label="bar: 100 mdeg")
    bx.set_xticks(np.arange(len(x)))
    bx.set_xticklabels([str(s) for s in x])
    bx.set_xlabel("stand-in (seed)")
    bx.set_ylabel("registration error")
    bx.set_title("registration against the hidden truth")
    bx.legend(fontsize=8)
    fig.tight_layout()
    out = atomic_write_png_figure(fig, path)
    plt.close(fig)
    return out
