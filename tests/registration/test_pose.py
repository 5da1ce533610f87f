"""Registration (issue 18): spots -> elements -> the camera's pose (and intrinsics), on stand-in sensors.

A stand-in is the default sensor seen by an OpenCV fisheye camera the package
is not told about: 0.1-0.5 mm off the axis, 0.5-2 deg tilted, focal length
+-3 %, principal point +-8 px, Kannala-Brandt k1..k4. Its frames are drawn
analytically: a Gaussian spot (sigma 1 px, 100 grey levels) at the projection
(:func:`pixel_from_dome`, through the dome) of every cone patch centre of a
pressed element, on a 20-level background with 2 grey levels of noise, cast
to uint8. The truth is the stand-in's camera.
"""

from __future__ import annotations

import csv
import json
from dataclasses import replace

import numpy as np
import pytest

import optitact
from optitact.errors import RegistrationError, ShapeError
from optitact.optics.camera import camera_from_dict, rotation_from_rvec
from optitact.optics.camera_models import OpenCVFisheyeCamera, pose_from_position
from optitact.optics.contact import contact_patches
from optitact.optics.camera import pixel_from_dome
from optitact.optics.sensor import DomeSensor
from optitact.registration.pose import Registration, RegistrationWarning, register
from optitact.registration.spots import detect_spots

SENSOR = DomeSensor.default()
W, H = 320, 240
F0 = (min(W, H) / 2) / np.deg2rad(70)  # the default equidistant camera's focal length (px/rad)
NOMINAL = OpenCVFisheyeCamera(W, H, fx=F0, fy=F0, cx=(W - 1) / 2, cy=(H - 1) / 2, dist=(0, 0, 0, 0),
                              tvec=(0, 0, 5))
#: Elements pressed per frame: 22 of the 41, every ring.
PRESSES = ([0, 2, 5, 11, 14, 27, 33], [1, 4, 7, 9, 17, 21, 30, 37], [3, 6, 13, 19, 25, 29, 40])
N_STANDINS = 10


def standin(seed: int) -> OpenCVFisheyeCamera:
    """A stand-in sensor's true camera."""
    rng = np.random.default_rng(seed)
    off, a = rng.uniform(0.1, 0.5), rng.uniform(0, 2 * np.pi)
    tilt, b = np.deg2rad(rng.uniform(0.5, 2.0)), rng.uniform(0, 2 * np.pi)
    rvec = (tilt * np.cos(b), tilt * np.sin(b), rng.uniform(-0.01, 0.01))
    fx = F0 * (1 + rng.uniform(-0.03, 0.03))
    dist = (rng.uniform(-0.05, 0.05), rng.uniform(-0.02, 0.02), rng.uniform(-0.005, 0.005),
            rng.uniform(-0.002, 0.002))
    return OpenCVFisheyeCamera(W, H, fx=fx, fy=fx * (1 + rng.uniform(-0.003, 0.003)),
                               cx=(W - 1) / 2 + rng.uniform(-8, 8), cy=(H - 1) / 2 + rng.uniform(-8, 8),
                               dist=dist,
                               **pose_from_position((off * np.cos(a), off * np.sin(a), -5.0), rvec))


def _spot(img: np.ndarray, r: float, c: float, amp: float = 100.0, sigma: float = 1.0) -> None:
    r0, c0 = int(round(r)), int(round(c))
    rr, cc = np.mgrid[max(r0 - 6, 0):min(r0 + 7, H), max(c0 - 6, 0):min(c0 + 7, W)]
    img[rr, cc] += amp * np.exp(-((rr - r) ** 2 + (cc - c) ** 2) / (2 * sigma * sigma))


def frames(camera, seed: int, presses=PRESSES, extra=None, drop=None, sensor=SENSOR):
    """No-load frame and pressed frames (uint8); ``extra = (frame, (row, col))`` adds a reflection,
    ``drop = (frame, element)`` leaves a pressed element out."""
    rng = np.random.default_rng(seed + 1000)
    forces = np.zeros((sensor.n_elements, 3))
    forces[:, 2] = 1.0
    px = pixel_from_dome(contact_patches(sensor, forces).centers, sensor=sensor, camera=camera)

    def noisy(img):
        return np.clip(np.round(img + rng.normal(0.0, 2.0, img.shape)), 0, 255).astype(np.uint8)

    out = []
    for i, els in enumerate(presses):
        img = np.full((H, W), 20.0)
        for e in els:
            if drop != (i, e):
                for r, c in px[e]:
                    _spot(img, r, c)
        if extra is not None and extra[0] == i:
            _spot(img, *extra[1], amp=150.0, sigma=1.5)
        out.append(noisy(img))
    return noisy(np.full((H, W), 20.0)), out


def pose_error(fit, true) -> tuple[float, float]:
    """Camera centre error (mm) and rotation error (deg)."""
    rel = rotation_from_rvec(fit.rvec) @ rotation_from_rvec(true.rvec).T
    angle = np.degrees(np.arccos(np.clip((np.trace(rel) - 1) / 2, -1, 1)))
    return float(np.linalg.norm(fit.position - true.position)), float(angle)


@pytest.fixture(scope="module")
def standins():
    """(true camera, no-load frame, pressed frames) of the stand-ins."""
    out = []
    for seed in range(N_STANDINS):
        cam = standin(seed)
        out.append((cam, *frames(cam, seed)))
    return out


# ----------------------------------------------------------------------------- spots
@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_detect_spots_finds_analytic_spots(dtype):
    rng = np.random.default_rng(3)
    truth = np.array([[30.3, 40.7], [80.55, 120.2], [150.0, 60.45]])
    img = np.full((H, W), 20.0)
    for r, c in truth:
        _spot(img, r, c)
    base = np.clip(np.round(np.full((H, W), 20.0) + rng.normal(0, 2, (H, W))), 0, 255).astype(dtype)
    frame = np.clip(np.round(img + rng.normal(0, 2, (H, W))), 0, 255).astype(dtype)
    spots = detect_spots(frame, base)
    order = np.argsort(spots.centroid[:, 0])
    np.testing.assert_allclose(spots.centroid[order], truth, rtol=0, atol=0.1)
    total = 2 * np.pi * 100.0  # a spot's energy; the pixels above 5 sigma (r < 2 px) hold 86 % of it
    assert np.all((0.8 * total < spots.energy) & (spots.energy < total)), spots.energy
    assert 2.0 < spots.noise_sigma < 3.6  # the difference of two frames of 2 grey levels of noise: 2.83
    assert detect_spots(base, base).centroid.shape == (0, 2)


def test_quantised_dark_frames_find_only_the_spots():
    """Dark uint8 frames where nearly every difference is exactly 0 (the robust sigma collapses): a
    threshold below the noise's own negative tail would take the +-1 grey-level flicker for spots."""
    rng = np.random.default_rng(8)

    def dark():
        return np.clip(np.round(4.0 + rng.normal(0, 0.3, (H, W))), 0, 255)

    base = np.mean([dark() for _ in range(4)], axis=0)
    img = dark()
    truth = np.array([[50.2, 60.6], [120.4, 200.3]])
    spotted = np.zeros((H, W))
    for r, c in truth:
        _spot(spotted, r, c, amp=40.0)
    frame = np.clip(img + np.round(spotted), 0, 255).astype(np.uint8)
    spots = detect_spots(frame, base)
    assert len(spots.energy) == 2, len(spots.energy)
    np.testing.assert_allclose(spots.centroid[np.argsort(spots.centroid[:, 0])], truth, atol=0.15)


def test_uneven_cone_brightness_does_not_move_the_pose(standins):
    """The rim light makes an element's cones nearer the rim brighter (up to +-30 % here). Where the
    cones are spots of their own (here at 640x480) the element's centre is the plain mean of their
    centroids, as the model predicts it: the pose is as good as with even cones (the energy-weighted
    centroid of the element's light moved it by 0.1 mm here)."""
    small, _, _ = standins[0]
    true = replace(small, width=2 * W, height=2 * H, fx=2 * small.fx, fy=2 * small.fy, cx=2 * small.cx + 0.5,
                   cy=2 * small.cy + 0.5)
    rng = np.random.default_rng(5)
    forces = np.zeros((SENSOR.n_elements, 3))
    forces[:, 2] = 1.0
    centres = contact_patches(SENSOR, forces).centers
    px = pixel_from_dome(centres, sensor=SENSOR, camera=true)
    polar = np.arccos(centres[..., 2] / np.linalg.norm(centres, axis=-1))  # brighter towards the rim
    amp = 100.0 * (1 + 0.3 * np.tanh(8 * (polar - SENSOR.element_polar[:, None])))
    rows, cols = np.mgrid[0:2 * H, 0:2 * W]

    def noisy(img):
        return np.clip(np.round(img + rng.normal(0.0, 2.0, img.shape)), 0, 255).astype(np.uint8)

    pressed = []
    for els in PRESSES:
        img = np.full((2 * H, 2 * W), 20.0)
        for e in els:
            for (r, c), a in zip(px[e], amp[e], strict=True):
                win = (np.abs(rows - r) < 7) & (np.abs(cols - c) < 7)
                img[win] += a * np.exp(-((rows[win] - r) ** 2 + (cols[win] - c) ** 2) / 2.0)
        pressed.append(noisy(img))
    start = replace(true, **pose_from_position((0.0, 0.0, -5.0)))
    reg = register(noisy(np.full((2 * H, 2 * W), 20.0)), pressed, camera=start)
    dpos, dang = pose_error(reg.camera, true)
    assert dpos <= 0.02 and dang <= 0.05 and reg.rms_px <= 0.1, (dpos, dang, reg.rms_px)


# ----------------------------------------------------------------------------- pose
def test_register_recovers_the_pose_of_every_standin(standins):
    """Intrinsics known (OpenCV's checkerboard calibration), the pose nominal: <= 0.05 mm, 0.1 deg, 0.1 px."""
    worst = np.zeros(3)
    for true, noload, pressed in standins:
        start = replace(NOMINAL, fx=true.fx, fy=true.fy, cx=true.cx, cy=true.cy, dist=true.dist)
        reg = register(noload, pressed, camera=start)
        assert isinstance(reg, Registration)
        dpos, dang = pose_error(reg.camera, true)
        worst = np.maximum(worst, [dpos, dang, reg.rms_px])
        assert sorted(reg.unseen) == sorted(set(range(41)) - set(sum(PRESSES, [])))
        assert [f["elements"] for f in reg.frames] == [sorted(p) for p in PRESSES]
        # the reported standard errors describe the actual errors
        assert np.linalg.norm(reg.camera.position - true.position) <= 5 * np.linalg.norm(
            [reg.std_errors[k] for k in ("x_mm", "y_mm", "z_mm")])
    assert worst[0] <= 0.05 and worst[1] <= 0.1 and worst[2] <= 0.1, worst


def test_register_fits_the_intrinsics(standins):
    """From nominal intrinsics (distortion known): fx, cx, cy, camera height within 4 standard errors."""
    for true, noload, pressed in standins[:4]:
        reg = register(noload, pressed, camera=replace(NOMINAL, dist=true.dist), fit_intrinsics=True)
        assert reg.rms_px <= 0.1
        se = reg.std_errors
        for name, fitted, truth in (("fx", reg.camera.fx, true.fx), ("fy", reg.camera.fy, true.fy),
                                    ("cx", reg.camera.cx, true.cx), ("cy", reg.camera.cy, true.cy),
                                    ("z_mm", reg.camera.position[2], true.position[2])):
            assert abs(fitted - truth) <= 4 * se[name] + 1e-3, (name, fitted, truth, se[name])
        assert abs(reg.camera.fx / true.fx - 1) < 0.03
        assert np.hypot(reg.camera.cx - true.cx, reg.camera.cy - true.cy) < 4.0


def test_default_equidistant_camera_is_fitted_as_opencv_fisheye():
    true = replace(NOMINAL, **pose_from_position((0.3, -0.2, -5.0), (0.02, -0.01, 0.0)))
    noload, pressed = frames(true, 7)
    reg = optitact.registration.pose.register(noload, pressed)  # the default camera of the frames' size
    assert isinstance(reg.camera, OpenCVFisheyeCamera)
    dpos, dang = pose_error(reg.camera, true)
    assert dpos <= 0.05 and dang <= 0.1 and reg.rms_px <= 0.1


def test_reflection_and_missing_element_still_register(standins):
    true, _, _ = standins[1]
    # a bright reflection half-way between two elements of ring 2, in frame 0; element 9 missing from frame 1
    mid = pixel_from_dome(SENSOR.outer_radius * np.array([np.sin(np.pi / 4) * np.cos(np.pi / 16),
                                                          np.sin(np.pi / 4) * np.sin(np.pi / 16),
                                                          np.cos(np.pi / 4)]), sensor=SENSOR, camera=true)
    noload, pressed = frames(true, 1, extra=(0, tuple(mid)), drop=(1, 9))
    start = replace(NOMINAL, fx=true.fx, fy=true.fy, cx=true.cx, cy=true.cy, dist=true.dist)
    reg = register(noload, pressed, camera=start)
    dpos, dang = pose_error(reg.camera, true)
    assert dpos <= 0.05 and dang <= 0.1 and reg.rms_px <= 0.1
    assert reg.frames[0]["elements"] == sorted(PRESSES[0]) and reg.frames[0]["rejected"] == 1
    assert 9 not in reg.frames[1]["elements"] and 9 in reg.unseen


# ----------------------------------------------------------------------------- refusals
def test_too_few_elements_are_refused(standins):
    true, _, _ = standins[0]
    noload, pressed = frames(true, 0, presses=([2, 11],))
    with pytest.raises(RegistrationError, match=r"too few spots: .* 2 element-shaped cluster\(s\).* at least 5 "
                                                r"elements; press more elements"):
        register(noload, pressed, camera=NOMINAL)
    with pytest.raises(RegistrationError, match="at least 7 elements"):
        register(noload, pressed, camera=NOMINAL, fit_intrinsics=True)


def test_a_ring_alone_cannot_tell_focal_length_from_height(standins):
    true, _, _ = standins[0]
    noload, pressed = frames(true, 0, presses=([1, 2, 3, 4, 5, 6, 7, 8],))
    # the dome's prior pins its radius; focal length and height stay apart only by a condition number of 5e8
    with pytest.raises(RegistrationError, match=r"(degenerate pose|not converge).* tell .*(fx.*z_mm|z_mm.*fx)"):
        register(noload, pressed, camera=replace(NOMINAL, dist=true.dist), fit_intrinsics=True, fit_dome=True)


def test_bad_frames_are_refused(standins):
    _, noload, pressed = standins[0]
    with pytest.raises(ShapeError, match="the camera .* is for 640x480"):
        register(noload, pressed, camera=replace(NOMINAL, width=640, height=480))
    with pytest.raises(ShapeError, match=r"pressed\[1\] must have the no-load frame's shape"):
        register(noload, [pressed[0], pressed[1][:-1]], camera=NOMINAL)
    with pytest.raises(RegistrationError, match="no pressed frames"):
        register(noload, [], camera=NOMINAL)
    with pytest.raises(TypeError, match="fit_intrinsics must be True or False"):
        register(noload, pressed, camera=NOMINAL, fit_intrinsics="yes")


# ----------------------------------------------------------------------------- the command line
def test_cli_writes_a_setup_that_process_reads(standins, tmp_path, capsys):
    import cv2

    from optitact.cli import main

    true, noload, pressed = standins[2]
    cv2.imwrite(str(tmp_path / "noload.png"), noload)
    names = []
    for i, f in enumerate(pressed):
        names.append(str(tmp_path / f"pressed_{i}.png"))
        cv2.imwrite(names[-1], f)
    fs = cv2.FileStorage(str(tmp_path / "cam.yml"), cv2.FILE_STORAGE_WRITE)
    fs.write("image_width", W)
    fs.write("image_height", H)
    fs.write("camera_matrix", true.K)
    fs.write("distortion_coefficients", true.D.reshape(1, 4))
    fs.write("distortion_model", "fisheye")
    fs.release()
    setup = tmp_path / "setup.json"
    assert main(["register", str(tmp_path / "noload.png"), *names, "--camera-intrinsics",
                 str(tmp_path / "cam.yml"), "--out", str(setup)]) == 0
    assert capsys.readouterr().out.strip() == str(setup)
    doc = json.loads(setup.read_text())
    assert set(doc) == {"sensor", "camera", "registration"}
    assert doc["registration"]["rms_px"] <= 0.1 and len(doc["registration"]["frames"]) == 3
    cam = optitact.optics.camera.camera_from_dict(doc["camera"])
    dpos, dang = pose_error(cam, true)
    assert dpos <= 0.05 and dang <= 0.1

    out = tmp_path / "readings.csv"
    assert main(["process", *names, "--baseline", str(tmp_path / "noload.png"), "--setup", str(setup),
                 "--out", str(out)]) == 0
    with out.open() as fh:
        rows = list(csv.DictReader(fh))
    for i, els in enumerate(PRESSES):
        mine = [r for r in rows if int(r["frame"]) == i] if "frame" in rows[0] else rows[41 * i:41 * (i + 1)]
        contact = {int(r["element"]) for r in mine if r["contact"] in ("1", "True", "true")}
        assert contact == set(els)
        # a pure normal press: the grey-value centroid lands on the element's centre
        u = np.array([[float(r["ux"]), float(r["uy"])] for r in mine if int(r["element"]) in els])
        assert np.abs(u).max() <= 0.05, u


def test_cli_refuses_pinhole_without_intrinsics(standins, tmp_path, capsys):
    import cv2

    from optitact.cli import main

    _, noload, pressed = standins[0]
    cv2.imwrite(str(tmp_path / "n.png"), noload)
    cv2.imwrite(str(tmp_path / "p.png"), pressed[0])
    assert main(["register", str(tmp_path / "n.png"), str(tmp_path / "p.png"), "--model", "pinhole",
                 "--out", str(tmp_path / "s.json")]) == 2
    assert "--model pinhole needs --camera-intrinsics" in capsys.readouterr().err


def test_element_offsets_fit_with_their_prior(standins):
    """Per-element offsets (prior 0.2 mm) on a sensor built to the design: they stay near 0, the pose holds."""
    true, noload, pressed = standins[3]
    start = replace(NOMINAL, fx=true.fx, fy=true.fy, cx=true.cx, cy=true.cy, dist=true.dist)
    reg = register(noload, pressed, camera=start, fit_offsets=True)
    dpos, dang = pose_error(reg.camera, true)
    assert dpos <= 0.05 and dang <= 0.1 and reg.rms_px <= 0.1
    assert np.abs(reg.element_offsets).max() <= 0.05
    assert "offset_2_x_mm" in reg.std_errors and "offset_2_x_mm" not in {f"offset_{e}_x_mm" for e in reg.unseen}
    assert json.loads(json.dumps(reg.to_dict()))["registration"]["element_offsets_mm"]


def test_a_set_for_a_registered_sensor_uses_its_camera(tmp_path, monkeypatch):
    """calibrate generate --setup: the set is made for the setup's camera, two-stage like any other
    (the emission table belongs to the patches, not the camera)."""
    import json

    import optitact.calib.sets as calib

    from optitact.optics.camera_models import PinholeCamera

    cam = PinholeCamera(width=64, height=48, fx=30.0, fy=30.0, cx=31.5, cy=23.5, tvec=(0.1, 0.0, 5.0))
    setup = tmp_path / "setup.json"
    setup.write_text(json.dumps({"sensor": DomeSensor.default().to_dict(), "camera": cam.to_dict()}))
    seen = {}

    def fake_generate(path, **kw):
        seen.update(kw)
        raise optitact.errors.InputError("stop here")   # the command's wiring is what is tested

    monkeypatch.setattr(calib, "generate", fake_generate)
    from optitact.cli import main

    assert main(["calibrate", "generate", "--frames", "2", "--out", str(tmp_path / "s.zarr"),
                 "--setup", str(setup)]) == 2
    assert seen["camera"] == cam and seen["render_mode"] == "two_stage"
    assert seen["sensor"] == optitact.optics.sensor.DomeSensor.default()


# ----------------------------------------------------------------------------- as built: offsets and gains
def test_cone_points_with_offsets_are_the_as_built_sensors_cones():
    from optitact.registration.pose import _cone_points

    rng = np.random.default_rng(2)
    first, more = rng.normal(0, 0.15, (41, 2)), rng.normal(0, 0.15, (41, 2))
    built = DomeSensor(element_offsets=first)
    both = DomeSensor(element_offsets=first + more)
    forces = np.zeros((41, 3))
    forces[:, 2] = 1.0
    els = np.arange(41)
    np.testing.assert_allclose(_cone_points(built, els, more), contact_patches(both, forces).centers,
                               rtol=0, atol=1e-12)
    np.testing.assert_array_equal(_cone_points(SENSOR, els, None), contact_patches(SENSOR, forces).centers)


def test_fitted_offsets_make_a_sensor_that_reprojects_its_cones_where_they_are(standins):
    """A stand-in built with element offsets (0.12 mm rms, each element seen once): the setup's sensor (the
    fitted offsets, design frame) seen by the fitted camera puts every seen element's cone ring where the
    fit predicts it (the measured centroid minus the residual). One view per element pins its offset only
    together with the prior, so the offsets are recovered to half their size (and the pose to ~0.2 mm)."""
    true, _, _ = standins[4]
    truth = DomeSensor(element_offsets=np.random.default_rng(9).normal(0.0, 0.12, (41, 2)))
    noload, pressed = frames(true, 4, sensor=truth)
    start = replace(NOMINAL, fx=true.fx, fy=true.fy, cx=true.cx, cy=true.cy, dist=true.dist)
    with pytest.warns(RegistrationWarning, match="add --fit-offsets"):  # 0.47 px, the spots' noise 0.04 px
        plain = register(noload, pressed, camera=start)
    reg = register(noload, pressed, camera=start, fit_offsets=True)
    assert reg.rms_px <= 0.15 and plain.rms_px > 3 * reg.rms_px  # offsets explain what the pose alone cannot
    setup = json.loads(json.dumps(reg.to_dict()))
    sensor = DomeSensor.from_dict(setup["sensor"])
    np.testing.assert_allclose(np.asarray(sensor.element_offsets), reg.element_offsets, rtol=0, atol=1e-12)
    forces = np.zeros((41, 3))
    forces[:, 2] = 1.0

    def rings(s, cam):
        cones = contact_patches(s, forces).centers[reg.element]
        return pixel_from_dome(cones, sensor=s, camera=cam).mean(axis=1)

    # measured centroid (the true ring, to the spots' noise) = the setup's prediction + the fit's residual
    err = np.linalg.norm(rings(sensor, camera_from_dict(setup["camera"])) + reg.residuals_px
                         - rings(truth, true), axis=1)
    assert err.max() <= 0.2 and np.sqrt(np.mean(err ** 2)) <= 0.08, err
    seen = np.unique(reg.element)
    fitted, real = np.asarray(sensor.element_offsets)[seen], np.asarray(truth.element_offsets)[seen]
    rms = np.sqrt(np.mean(np.sum((fitted - real) ** 2, axis=1)))
    assert rms <= 0.5 * np.sqrt(np.mean(np.sum(real ** 2, axis=1))), rms


@pytest.fixture(scope="module")
def gain_frames():
    """Two-stage frames (160x120 default camera, the shipped emission table: it serves every camera) of a
    sensor with known gains and of the designed one, the 22 elements of PRESSES pressed at 0.6 N each."""
    from optitact.render import render
    from optitact.render.emission import shipped_table

    from optitact.optics.ccd import CCD

    cam = optitact.optics.camera.FisheyeCamera(width=160, height=120)
    table = shipped_table(SENSOR)
    gains = np.random.default_rng(5).uniform(0.85, 1.15, 41)
    ccd = CCD()
    out = {"gains": gains}
    for name, sensor in (("built", DomeSensor(element_gain=gains)), ("designed", SENSOR)):
        def frame(load, seed, sensor=sensor):
            return ccd.expose(render(sensor, load, camera=cam, transport="two_stage", table=table), seed=seed)

        noload = np.mean([frame(np.zeros((41, 3)), 100 + i) for i in range(4)], axis=0)
        pressed = []
        for rep in range(2 if name == "built" else 1):  # the built sensor's elements pressed twice each
            for i, els in enumerate(PRESSES):
                load = np.zeros((41, 3))
                load[els, 2] = 0.6
                pressed.append(frame(load, 10 * rep + i))
        out[name] = (noload, pressed)
    return out


@pytest.mark.render
def test_register_recovers_element_gains(gain_frames):
    """Relative gains of a sensor built with known gains (0.85-1.15), each element pressed twice at 0.6 N.

    Measured against the shipped (640x480) calibration, the tiny camera's own per-ring bias (G read at
    160x120 is up to 12 % off the shipped curves' G, ring 2 high) adds to the gains; the same registration
    of the designed sensor's frames measures that bias, and the built sensor's gains over it are the true
    gains within 4 % (rms 2 %)."""
    gains = gain_frames["gains"]
    reg = register(*gain_frames["built"], fit_gains=True)
    ref = register(*gain_frames["designed"], fit_gains=True)
    seen = np.array(sorted(set(sum(PRESSES, []))))
    assert reg.gain_unfitted == () and sorted(reg.unseen) == sorted(set(range(41)) - set(seen))
    est = np.asarray(reg.sensor.element_gain)
    assert np.median(est[seen]) == pytest.approx(1.0, abs=1e-12)  # normalised: the force is not given
    np.testing.assert_array_equal(est[list(reg.unseen)], 1.0)
    assert 0.3 < reg.gain_force_n < 1.0
    rel = est[seen] / np.asarray(ref.sensor.element_gain)[seen]
    rel /= np.median(rel)
    truth = gains[seen] / np.median(gains[seen])
    err = rel / truth - 1.0
    assert np.abs(err).max() <= 0.04 and np.sqrt(np.mean(err ** 2)) <= 0.02, err
    # a known press force: absolute gains, the same up to the normalisation
    absolute = register(gain_frames["built"][0], gain_frames["built"][1][:3], fit_gains=True, press_force=0.6)
    assert absolute.gain_force_n == 0.6
    ratio = np.asarray(absolute.sensor.element_gain)[seen] / est[seen]
    np.testing.assert_allclose(ratio, np.median(ratio), rtol=0.05)
    # each pressed twice: a standard error from the pooled spread of the repeats (CCD noise only)
    assert all(0 < reg.std_errors[f"gain_{e}"] < 0.02 for e in seen)
    assert 0 < ref.std_errors["gain_2"] < 0.02  # pressed once: the frames' noise through the region sums
    with pytest.raises(optitact.errors.InputError, match="press_force .* needs fit_gains=True"):
        register(*gain_frames["built"], press_force=0.6)
