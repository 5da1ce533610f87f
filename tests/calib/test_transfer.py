"""A calibration transferred to a registered sensor and camera (issue 18: per-element gains).

Truths: a transferred calibration reads a gain-scaled G to exactly the force the
original reads the unscaled G to; its fingerprint is :func:`fingerprint` of the
new sensor, camera and options; refinement from ``start="default"`` for a sensor
with gains starts at those gains (presses made from them need no further gain).
"""

from __future__ import annotations

import json
import re
from dataclasses import replace

import numpy as np
import pytest
from optitact.calib.document import CalibrationMismatchError, fingerprint
from optitact.calib.press_fit import fit_presses
from optitact.calib.shipped import default_calibration

import optitact
from optitact.cli import main
from optitact.optics.camera_models import OpenCVFisheyeCamera
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.readings import Readings
from optitact.registration.gains import reference_curve, reference_g

W, H = 64, 48
F0 = (min(W, H) / 2) / np.deg2rad(70)
CAM = OpenCVFisheyeCamera(W, H, fx=F0, fy=F0, cx=(W - 1) / 2 + 0.7, cy=(H - 1) / 2 - 0.4, dist=(0.01, 0, 0, 0),
                          tvec=(0.1, -0.05, 5.0))
GAINS = np.random.default_rng(4).uniform(0.8, 1.25, 41)
BUILT = optitact.optics.sensor.DomeSensor(element_gain=GAINS,
                            element_offsets=np.random.default_rng(5).normal(0.0, 0.1, (41, 2)))


@pytest.fixture(scope="module")
def shipped():
    return default_calibration()


@pytest.fixture(scope="module")
def moved(shipped):
    return shipped.transferred(BUILT, CAM)


def _readings(G, u):
    return Readings(G, u, G > 0, np.zeros(G.shape, bool))


def test_transferred_reads_gain_scaled_G_to_the_same_force(shipped, moved):
    rng = np.random.default_rng(0)
    G = rng.uniform(0.0, 1.0, (20, 41)) * shipped.g_max
    u = rng.normal(0.0, 0.05, (20, 41, 2))
    alone, moved_alone = replace(shipped, crosstalk=None), replace(moved, crosstalk=None)
    want, clamp0 = alone.forces(_readings(G, u))
    got, clamp1 = moved_alone.forces(_readings(G * GAINS, u))
    np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(clamp1, clamp0)
    # the joint inversion's coupling keeps its coefficients; its near field follows the as-built element
    # distances (offsets of ~0.1 mm move the forces by less than 0.1 mN here)
    assert moved.crosstalk is shipped.crosstalk
    want, _ = shipped.forces(_readings(G, u))
    got, _ = moved.forces(_readings(G * GAINS, u))
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-4)


def test_transferred_fingerprint_and_provenance(shipped, moved, tmp_path):
    assert moved.sensor == BUILT and moved.camera == CAM
    assert moved.fingerprint == fingerprint(BUILT, CAM, moved.pipeline_options, moved.intensity)
    assert moved.fingerprint != shipped.fingerprint
    assert moved.provenance["transferred_from"] == shipped.fingerprint
    assert moved.pipeline_options == shipped.pipeline_options  # mm on the dome: they carry over as they are
    back = optitact.calib.fit.Calibration.load(moved.save(tmp_path / "moved.json"))
    assert back.fingerprint == moved.fingerprint
    np.testing.assert_array_equal(back.g_scale, moved.g_scale)
    # back to the designed sensor and the shipped camera: the shipped curves again
    again = moved.transferred(shipped.sensor, shipped.camera)
    np.testing.assert_allclose(again.g_scale, shipped.g_scale, rtol=1e-12)
    assert again.fingerprint == shipped.fingerprint


def test_transfer_refuses_another_layout_or_options(shipped):
    with pytest.raises(CalibrationMismatchError, match=r"ring_counts \(1, 8, 16, 16\), the new one \(1, 8, 16\)"):  # noqa: E501
        shipped.transferred(DomeSensor(ring_counts=(1, 8, 16), ring_polar_deg=(0, 25, 50)), CAM)
    with pytest.raises(CalibrationMismatchError, match="n_cones 8, the new one 6"):
        shipped.transferred(optitact.optics.sensor.DomeSensor(n_cones=6), CAM)
    bad = replace(shipped, pipeline_options={"radius": 50.0, "grid_mm": 0.037})
    with pytest.raises(CalibrationMismatchError, match="pipeline options .* do not carry over .*too fine"):
        bad.transferred(BUILT, CAM)
    with pytest.raises(TypeError, match="camera"):
        shipped.transferred(BUILT, "camera")


def test_refinement_from_default_starts_at_the_sensors_gains(shipped, moved):
    """Presses made by the transferred curves (G = gain x the shipped G): the refinement from
    ``start="default"`` finds nothing to change (its fitted gains on top of the transfer are 1)."""
    grid, fz = reference_curve(shipped)
    forces = np.zeros((6, 41, 3))
    G = np.zeros((6, 41))
    for t, f in enumerate(np.linspace(0.2, 0.7, 6)):
        forces[t, :, 2] = f
        G[t] = reference_g(grid, fz, f) * GAINS
    readings = _readings(G, np.zeros((6, 41, 2)))
    for method in ("groups", "shapes"):
        cal = fit_presses(readings, forces, sensor=BUILT, camera=CAM, start="default", method=method)
        if method == "groups":
            np.testing.assert_allclose(cal.provenance["gain"], 1.0, rtol=0, atol=2e-3)
        else:  # every element's force scale and exponent stay the transferred curves'
            np.testing.assert_allclose(cal.provenance["theta"]["log_scale"], 0.0, rtol=0, atol=2e-3)
            np.testing.assert_allclose(cal.provenance["theta"]["exponent"], 0.0, rtol=0, atol=5e-3)
        assert cal.provenance["start"] == moved.fingerprint
        assert cal.provenance["start_provenance"]["transferred_from"] == shipped.fingerprint
        est, _ = cal.forces(readings)
        np.testing.assert_allclose(est[..., 2], forces[..., 2], rtol=0, atol=2e-3)


# ----------------------------------------------------------------------------- optitact process --setup
@pytest.fixture()
def setup_files(tmp_path):
    setup = tmp_path / "setup.json"
    setup.write_text(json.dumps({"sensor": BUILT.to_dict(), "camera": CAM.to_dict()}))
    frames = tmp_path / "frames.npy"
    np.save(frames, np.full((3, H, W), 10, np.uint8))
    return setup, frames


def test_process_transfers_the_shipped_calibration_to_a_setup(setup_files, tmp_path, capsys):
    setup, frames = setup_files
    out = tmp_path / "f.csv"
    assert main(["process", str(frames), "--setup", str(setup), "--calibration", "default", "--out",
                 str(out)]) == 0
    err = capsys.readouterr().err
    assert err.count("the shipped calibration is transferred to the setup's sensor and camera") == 1
    assert out.exists()


def test_process_refuses_a_calibration_file_of_another_sensor(setup_files, shipped, tmp_path, capsys):
    setup, frames = setup_files
    mine = shipped.save(tmp_path / "mine.json")
    assert main(["process", str(frames), "--setup", str(setup), "--calibration", str(mine), "--out",
                 str(tmp_path / "f.csv")]) == 2
    assert "was made for another sensor" in capsys.readouterr().err


@pytest.mark.parametrize("text, match", [
    ("{", "setup.json: not a setup JSON file"),
    ('{"sensor": {}}', r"setup.json: expected a JSON object with 'sensor' and 'camera' .*got \['sensor'\]"),
    ('{"sensor": {"radius": 3}, "camera": {}}', "setup.json: .*radius"),
    ('{"sensor": {"element_gain": [1, 2]}, "camera": {}}', r"setup.json: element_gain must have shape \(41,\)"),
])
def test_a_bad_setup_file_is_named(setup_files, text, match, tmp_path, capsys):
    setup, frames = setup_files
    setup.write_text(text)
    assert main(["process", str(frames), "--setup", str(setup), "--out", str(tmp_path / "f.csv")]) == 2
    assert re.search(match, capsys.readouterr().err)
