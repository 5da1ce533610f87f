"""Registration says when its answer is not to be trusted, and refuses inputs it cannot use (issue 31).

Frames are the stand-ins of ``registration/test_pose.py`` (Gaussian spots drawn at the model's projections of
the cone patch centres, 2 grey levels of noise, uint8), except the gains' frames, which are two-stage
renders. The command-line tests run the installed ``optitact`` in a fresh folder and cache (the ``user``
fixture); the frames are written there as .png / .npy first.
"""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
from test_pose import NOMINAL, PRESSES, SENSOR, H, W, _spot, frames, pose_error, standin

from optitact.errors import InputError, KindError
from optitact.optics.camera_models import PinholeCamera
from optitact.optics.contact import contact_patches
from optitact.optics.camera import pixel_from_dome
from optitact.optics.sensor import DomeSensor
from optitact.registration.pose import RegistrationWarning, register

PM = r"(-?[\d.]+) \+- ([\d.]+)"


def checkerboard(true):
    """The nominal camera with the stand-in's intrinsics (a checkerboard calibration's)."""
    return replace(NOMINAL, fx=true.fx, fy=true.fy, cx=true.cx, cy=true.cy, dist=true.dist)


def write(user, noload, pressed, camera=None) -> list[str]:
    """noload.png, pressed_i.png (and cam.yml, a cv2.fisheye.calibrate file) in the user's folder."""
    import cv2

    cv2.imwrite(str(user.path("noload.png")), noload)
    names = []
    for i, f in enumerate(pressed):
        names.append(f"pressed_{i}.png")
        cv2.imwrite(str(user.path(names[-1])), f)
    if camera is not None:
        fs = cv2.FileStorage(str(user.path("cam.yml")), cv2.FILE_STORAGE_WRITE)
        fs.write("image_width", W)
        fs.write("image_height", H)
        fs.write("camera_matrix", camera.K)
        fs.write("distortion_coefficients", camera.D.reshape(1, 4))
        fs.write("distortion_model", "fisheye")
        fs.release()
    return names


def warning_lines(stderr: str) -> list[str]:
    return [line for line in stderr.splitlines() if line.startswith("optitact: warning: ")]


def report_value(stderr: str, pattern: str) -> tuple[float, ...]:
    m = re.search(pattern, stderr)
    assert m, (pattern, stderr)
    return tuple(float(g) for g in m.groups())


# ----------------------------------------------------------------------------- --fit-dome
def test_fit_dome_keeps_the_designed_radius_and_says_the_frames_cannot_pin_it():
    """Frames of the designed dome: without a prior the radius wandered to 10.8 +- 8.2 mm (the camera to
    z = -2.5 +- 2.3 mm); with the 1 % prior it stays at 20 mm, the pose stays right, and a caution says
    the frames add nothing to the radius."""
    true = standin(0)
    noload, pressed = frames(true, 0)
    with pytest.warns(RegistrationWarning, match=r"--fit-dome: the frames cannot pin the dome's outer radius "
                                                 r"down .* drop --fit-dome") as caught:
        reg = register(noload, pressed, camera=checkerboard(true), fit_dome=True)
    assert len(caught) == 1 and reg.cautions == (str(caught[0].message),)
    assert reg.sensor.outer_radius == pytest.approx(20.0, abs=0.05)
    assert 0.15 <= reg.std_errors["outer_radius_mm"] <= 0.2  # the prior's 0.2 mm, hardly narrowed
    dpos, dang = pose_error(reg.camera, true)
    assert dpos <= 0.05 and dang <= 0.1 and reg.std_errors["z_mm"] <= 0.1, (dpos, dang, reg.std_errors)
    assert json.loads(json.dumps(reg.to_dict()))["registration"]["cautions"] == list(reg.cautions)


def test_cli_fit_dome_prints_every_parameter_with_its_standard_error(user):
    true = standin(0)
    names = write(user, *frames(true, 0), camera=true)
    r = user.run("register", "noload.png", *names, "--camera-intrinsics", "cam.yml", "--model", "fisheye",
                 "--fit-dome", "--out", "setup.json")
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "setup.json"
    x, y, z = (report_value(r.stderr, rf"{a} {PM}") for a in ("x", "y", "z"))
    assert z[0] == pytest.approx(true.position[2], abs=0.05) and z[1] <= 0.1, z
    assert abs(x[0] - true.position[0]) <= 0.05 and abs(y[0] - true.position[1]) <= 0.05
    assert re.search(rf"rotation vector \(deg\): x {PM}, y {PM}, z {PM}", r.stderr), r.stderr
    radius, se = report_value(r.stderr, rf"dome outer radius: {PM} mm")
    assert radius == pytest.approx(20.0, abs=0.05) and 0.15 <= se <= 0.2
    warned = warning_lines(r.stderr)
    assert len(warned) == 1 and "cannot pin the dome's outer radius down" in warned[0], r.stderr
    assert r.stderr.rstrip().splitlines()[-1] == warned[0]  # after the report it qualifies
    doc = json.loads(user.path("setup.json").read_text())
    assert doc["sensor"]["outer_radius"] == pytest.approx(20.0, abs=0.05)
    assert doc["registration"]["std_errors"]["outer_radius_mm"] == pytest.approx(se, abs=1e-3)
    assert len(doc["registration"]["cautions"]) == 1


# ----------------------------------------------------------------------------- RMS beyond the spots' noise
def test_centroid_noise_explains_a_model_that_fits():
    for seed in range(3):
        true = standin(seed)
        reg = register(*frames(true, seed), camera=checkerboard(true))
        assert 0.6 <= reg.rms_px / reg.centroid_noise_px <= 1.5, (reg.rms_px, reg.centroid_noise_px)
        assert reg.cautions == ()


def test_cli_rms_beyond_the_spots_noise_suggests_fit_offsets(user):
    """A sensor built with element offsets (0.12 mm rms): the pose alone leaves 0.47 px RMS against the
    spots' 0.04 px of noise, and says so, suggesting --fit-offsets; with it, 0.11 px and no caution."""
    true = standin(4)
    built = DomeSensor(element_offsets=np.random.default_rng(9).normal(0.0, 0.12, (41, 2)))
    names = write(user, *frames(true, 4, sensor=built), camera=true)
    args = ("register", "noload.png", *names, "--camera-intrinsics", "cam.yml", "--model", "fisheye",
            "--no-fit-gains")
    r = user.run(*args, "--out", "plain.json")
    assert r.returncode == 0, r.stderr
    rms, noise = report_value(r.stderr, r"reprojection RMS ([\d.]+) px \(the spots' centroid noise explains "
                                        r"([\d.]+) px\)")
    assert rms >= 5 * noise and noise <= 0.08, (rms, noise)
    warned = warning_lines(r.stderr)
    assert len(warned) == 1 and "the reprojection RMS" in warned[0] and "add --fit-offsets" in warned[0]
    r = user.run(*args, "--fit-offsets", "--out", "offsets.json")
    assert r.returncode == 0, r.stderr
    assert warning_lines(r.stderr) == [], r.stderr
    assert json.loads(user.path("offsets.json").read_text())["registration"]["rms_px"] <= 0.15
    assert re.search(r"element offsets \(mm, x, y \+- larger SE\): 0: [-+][\d.]+, [-+][\d.]+ \+- [\d.]+",
                     r.stderr), r.stderr


# ----------------------------------------------------------------------------- rejected vs no spot
def test_cli_lists_spots_found_but_rejected_apart_from_elements_with_no_spot(user):
    """Frame 0 has a reflection between two ring-2 elements; in frame 1 element 9's cones are drawn 3 px
    off its ring (associated, then an outlier of the fit). Element 9 was found and rejected, not unseen."""
    true = standin(1)
    mid = pixel_from_dome(SENSOR.outer_radius * np.array([np.sin(np.pi / 4) * np.cos(np.pi / 16),
                                                          np.sin(np.pi / 4) * np.sin(np.pi / 16),
                                                          np.cos(np.pi / 4)]), sensor=SENSOR, camera=true)
    noload, pressed = frames(true, 1, extra=(0, tuple(mid)), drop=(1, 9))
    forces = np.zeros((41, 3))
    forces[:, 2] = 1.0
    moved = np.zeros((H, W))
    for r, c in pixel_from_dome(contact_patches(SENSOR, forces).centers[9], sensor=SENSOR, camera=true):
        _spot(moved, r + 3.0, c)
    pressed[1] = np.clip(pressed[1] + np.round(moved), 0, 255).astype(np.uint8)

    reg = register(noload, pressed, camera=checkerboard(true))
    reasons = {(x["frame"], x["reason"], x["element"]) for x in reg.rejected}
    assert (1, "outlier", 9) in reasons and any(f == 0 and why == "compact" for f, why, _ in reasons)
    assert 9 in reg.unseen and 9 not in reg.no_spot
    assert set(reg.no_spot) == set(range(41)) - set(sum(PRESSES, []))

    names = write(user, noload, pressed, camera=true)
    r = user.run("register", "noload.png", *names, "--camera-intrinsics", "cam.yml", "--model", "fisheye",
                 "--no-fit-gains", "--out", "setup.json")
    assert r.returncode == 0, r.stderr
    no_spot = re.search(r"(\d+) element\(s\) with no spot: \[([\d, ]+)\]", r.stderr)
    assert no_spot and 9 not in {int(e) for e in no_spot.group(2).split(",")}, r.stderr
    assert re.search(r"found but rejected \(\d+\): .*element 9 \(frame 1, at .*an outlier of the fit\)",
                     r.stderr), r.stderr
    assert re.search(r"a spot near element \d+ \(frame 0, .*too compact for an element's ring", r.stderr)
    rejected = json.loads(user.path("setup.json").read_text())["registration"]["rejected"]
    assert {"frame": 1, "reason": "outlier", "element": 9}.items() <= next(
        x for x in rejected if x["reason"] == "outlier").items()


# ----------------------------------------------------------------------------- the camera model
def test_cli_says_when_the_camera_model_looks_wrong(user):
    """Fisheye frames registered as a pinhole (a cv2.fisheye.calibrate file read with the wrong model):
    the camera lands 2.8 mm low, the outer ring's spots fall outside the gates; the caution names --model."""
    true = standin(0)
    noload, pressed = frames(true, 0)
    with pytest.warns(RegistrationWarning) as caught:  # also: the rotation is loose (+- 1.7 deg)
        api = register(noload, pressed, camera=PinholeCamera(W, H, fx=true.fx, fy=true.fy, cx=true.cx,
                                                             cy=true.cy, dist=tuple(true.dist)))
    assert sum("is the camera model right?" in str(w.message) for w in caught) == 1
    assert api.camera.position[2] < true.position[2] - 2.0
    names = write(user, noload, pressed, camera=true)
    r = user.run("register", "noload.png", *names, "--camera-intrinsics", "cam.yml", "--model", "pinhole",
                 "--no-fit-gains", "--out", "setup.json")
    assert r.returncode == 0, r.stderr
    wrong = [w for w in warning_lines(r.stderr) if "is the camera model right?" in w]
    assert len(wrong) == 1, r.stderr
    assert re.search(r"16 outer-ring element\(s\) unseen and the camera lands 2\.\d\d mm below the given "
                     r"camera's height", wrong[0]), wrong[0]
    assert "outside every element's gate" in wrong[0] and "needs --model fisheye" in wrong[0]
    assert "found but rejected" in r.stderr


# ----------------------------------------------------------------------------- gains
@pytest.mark.render
def test_cli_low_resolution_gains_come_with_their_uncertainty_and_a_caution(user):
    """64x48 two-stage frames of the designed sensor (every gain 1), each element pressed once at 0.2 N:
    the gains spread 0.85-1.21, each +- about 7 % from the frames' noise through the few pixels an
    element's light covers, and the command says the spread is no more than that."""
    from optitact.render import render
    from optitact.render.emission import shipped_table

    import optitact
    from optitact.optics.ccd import CCD

    cam = optitact.optics.camera.FisheyeCamera(width=64, height=48)
    table, ccd = shipped_table(SENSOR), CCD()
    presses = (*PRESSES, (8, 10, 12, 15, 16, 18, 20), (22, 24, 26, 28, 31, 32, 34), (35, 36, 38, 39, 23))

    def frame(load, seed):
        return ccd.expose(render(SENSOR, load, camera=cam, transport="two_stage", table=table), seed=seed)

    np.save(user.path("noload.npy"), np.stack([frame(np.zeros((41, 3)), 100 + i) for i in range(2)]))
    for i, els in enumerate(presses):
        load = np.zeros((41, 3))
        load[list(els), 2] = 0.2
        np.save(user.path(f"pressed_{i}.npy"), frame(load, i))
    r = user.run("register", "noload.npy", *(f"pressed_{i}.npy" for i in range(len(presses))), "--out",
                 "setup.json")
    assert r.returncode == 0, r.stderr
    each = re.search(r"each \(\+- standard error\): (.*)", r.stderr)
    assert each, r.stderr
    gains = {int(e): (float(g), float(s)) for e, g, s in re.findall(r"(\d+): ([\d.]+) \+- ([\d.]+)",
                                                                      each.group(1))}
    assert len(gains) >= 35
    g, se = np.array(list(gains.values())).T
    assert 0.03 <= np.median(se) <= 0.15, np.median(se)
    assert np.std(g) <= 2.0 * np.median(se)  # the spread (true gains all 1) is what the uncertainty explains
    warned = [w for w in warning_lines(r.stderr) if "element gains' spread" in w]
    assert len(warned) == 1 and "64x48 frames do not measure the elements' gains" in warned[0], r.stderr
    doc = json.loads(user.path("setup.json").read_text())
    assert doc["registration"]["std_errors"]["gain_0"] == pytest.approx(gains[0][1], abs=1e-3)


# ----------------------------------------------------------------------------- inputs
@pytest.mark.parametrize("value", [0, -3, 3])
def test_min_elements_below_what_the_fit_needs_is_refused(value):
    noload, pressed = frames(NOMINAL, 0)
    with pytest.raises(InputError, match=rf"min_elements must be an integer >= 4: the fit's 6 parameters "
                                         rf"need .* got {value}"):
        register(noload, pressed, camera=NOMINAL, min_elements=value)


@pytest.mark.parametrize("value", [2.7, "x", True])
def test_min_elements_of_the_wrong_kind_is_refused(value):
    noload, pressed = frames(NOMINAL, 0)
    with pytest.raises(TypeError, match="min_elements must be an integer"):
        register(noload, pressed, camera=NOMINAL, min_elements=value)


def test_min_elements_at_the_minimum_is_accepted():
    noload, pressed = frames(NOMINAL, 0)
    reg = register(noload, pressed, camera=NOMINAL, min_elements=np.int64(4))
    assert reg.rms_px <= 0.1
    with pytest.raises(InputError, match=r">= 6: the fit's 10 parameters"):
        register(noload, pressed, camera=NOMINAL, fit_intrinsics=True, min_elements=5)


def test_cli_refuses_frames_of_different_bit_depths_naming_both(user):
    noload, pressed = frames(NOMINAL, 0)
    with pytest.raises(InputError, match=r"noload is 16-bit \(uint16\) but pressed\[0\] is 8-bit \(uint8\)"):
        register(noload.astype(np.uint16) * 256, pressed, camera=NOMINAL)
    names = write(user, noload, pressed)
    np.save(user.path("noload16.npy"), noload.astype(np.uint16) * 256)
    r = user.run("register", "noload16.npy", *names, "--out", "setup.json")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert r.stderr.startswith("optitact: error: noload is 16-bit (uint16) but pressed[0] is 8-bit (uint8)")
    assert not user.path("setup.json").exists()


def test_cli_refuses_a_bool_noload_as_the_api_does(user):
    noload, pressed = frames(NOMINAL, 0)
    mask = noload > 20
    message = "noload must hold grey levels (an integer or float image), got dtype bool"
    with pytest.raises(KindError, match=re.escape(message)):
        register(mask, pressed, camera=NOMINAL)
    names = write(user, noload, pressed)
    np.save(user.path("mask.npy"), mask)
    r = user.run("register", "mask.npy", *names, "--out", "setup.json")
    assert r.returncode == 2 and r.stderr == f"optitact: error: {message}\n", r.stderr


def test_cli_too_fine_a_region_grid_names_the_camera_not_an_option(user):
    """A setup whose pinhole distortion (k1 = 2) stretches the image: the automatic region grid would be
    too fine; the message says the camera's distortion is why, not 'grid_mm=0.00187 is too fine'."""
    cam = PinholeCamera(W, H, fx=60.0, fy=60.0, cx=159.5, cy=119.5, dist=(2.0, 0.0, 0.0, 0.0, 0.0))
    user.path("setup.json").write_text(json.dumps({"sensor": SENSOR.to_dict(), "camera": cam.to_dict()}))
    np.save(user.path("frame.npy"), np.full((H, W), 20, np.uint8))
    r = user.run("process", "frame.npy", "--baseline", "frame.npy", "--setup", "setup.json", "--out", "r.csv")
    assert r.returncode == 2 and r.stderr.count("\n") == 1, r.stderr
    assert "grid_mm=" not in r.stderr
    assert re.search(r"one pixel spans only 0\.00\d+ mm .* check the camera's PinholeCamera distortion "
                     r"\(2\.0, 0\.0, 0\.0, 0\.0, 0\.0\)", r.stderr), r.stderr
