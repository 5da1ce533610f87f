"""The robotic finger: DH kinematics, RMRC, the contact model, the chain and the three experiments."""

from __future__ import annotations

import dataclasses
import doctest
import json

import numpy as np
import pytest

import optitact
import optitact.finger as fg
from optitact.calib import CalibrationMismatchError, fit, generate
from optitact.errors import InputError, ShapeError
from optitact.finger import (
    Box,
    ChainEstimate,
    ChainSimulator,
    Cylinder,
    Finger,
    SingularityError,
    Table,
    UnreachableError,
    feeler_forces,
)

SENSOR = optitact.DomeSensor.default()
TINY = optitact.FisheyeCamera(width=120, height=90)


def test_docstring_examples():
    assert doctest.testmod(fg, optionflags=doctest.ELLIPSIS).failed == 0


# ---------------------------------------------------------------------------- kinematics
FINGERS = [Finger(), Finger(phi1_deg=10.0, phi2_deg=-15.0, d=(12.0, 3.0, -2.0), a=(5.0, 90.0, 70.0),
                                alpha_deg=(80.0, 5.0, -3.0), theta_offset_deg=(3.0, -10.0, 20.0),
                                base=(1.0, 2.0, 3.0), tool=15.0)]


@pytest.mark.parametrize("finger", FINGERS)
def test_jacobian_matches_finite_differences(finger):
    rng = np.random.default_rng(0)
    h = 1e-6
    for _ in range(10):
        th, z = rng.uniform(-2.5, 2.5, 3), rng.uniform(-20, 20)
        num = np.stack([(finger.forward(th + h * e, z=z) - finger.forward(th - h * e, z=z)) / (2 * h)
                        for e in np.eye(3)], axis=1)
        np.testing.assert_allclose(finger.jacobian(th, z=z), num, rtol=0, atol=1e-6)


def test_forward_frames_and_sensor_pose():
    f = Finger()
    np.testing.assert_allclose(f.forward([0, 0, 0]), [200, 0, 0], atol=1e-12)
    np.testing.assert_allclose(f.forward([np.pi / 2, 0, 0], z=7.0), [0, 200, 7], atol=1e-12)
    np.testing.assert_allclose(f.forward([0, np.pi / 2, 0]), [0, 0, 200], atol=1e-12)
    th = np.array([0.3, 0.5, -1.2])
    rot, origin = f.sensor_pose(th, z=4.0)
    np.testing.assert_allclose(rot.T @ rot, np.eye(3), atol=1e-12)
    assert np.linalg.det(rot) == pytest.approx(1.0)
    np.testing.assert_allclose(origin + f.tool * rot[:, 2], f.forward(th, z=4.0), atol=1e-12)
    rot_down, _ = f.sensor_pose(fg.POSE_DOWN)
    np.testing.assert_allclose(rot_down[:, 2], [0, 0, -1], atol=1e-12)  # the apex points down
    # z-stage and base tilt: a pure translation / rotation of the whole finger
    tilted = Finger(phi1_deg=20.0)
    c, s = np.cos(np.radians(20)), np.sin(np.radians(20))
    np.testing.assert_allclose(tilted.forward(th), np.array([[1, 0, 0], [0, c, -s], [0, s, c]]) @ f.forward(th),
                               atol=1e-9)


@pytest.mark.parametrize("finger", FINGERS)
def test_rmrc_converges(finger):
    rng = np.random.default_rng(1)
    for _ in range(8):
        goal = rng.uniform([-0.8, 0.2, -1.6], [0.8, 0.9, -0.4])
        target = finger.forward(goal, z=5.0)
        start = goal + rng.uniform(-0.3, 0.3, 3)
        r = finger.rmrc(target, start, z=5.0, tol=1e-4)
        assert r.error < 1e-4 and r.iterations < 20 and r.condition < 1e3
        np.testing.assert_allclose(finger.forward(r.theta, z=5.0), target, atol=1e-4)
        np.testing.assert_allclose(r.path[-1], r.position)
    # plain Newton (no step limit) converges quadratically near the solution
    r = Finger().rmrc(Finger().forward([0.1, 0.4, -1.0]), [0.12, 0.38, -1.05], max_step=None, tol=1e-9)
    assert r.iterations <= 5


def test_rmrc_singular_and_unreachable():
    f = Finger()
    target = f.forward([0.0, 0.3, -1.0])
    with pytest.raises(SingularityError, match="condition number"):
        f.rmrc(target, [0.0, 0.3, 0.0])  # stretched arm: J has rank 2
    r = f.rmrc(target, [0.0, 0.3, 0.0], damping=1.0)  # damped least squares gets out
    assert r.error < 1e-3
    with pytest.raises(SingularityError, match="near-singular"):
        f.rmrc([0.0, 0.0, 100.0], [0.1, 0.3, -1.0])  # on the yaw axis: theta1 undetermined
    with pytest.raises(UnreachableError, match="reaches 0.000 to 200.000 mm"):
        f.rmrc([300.0, 0.0, 0.0], [0.0, 0.3, -1.0])
    with pytest.raises(UnreachableError, match="did not reach"):
        f.rmrc(target, [0.5, 0.6, -1.5], max_iter=1, max_step=1.0)
    assert issubclass(SingularityError, ValueError) and issubclass(UnreachableError, ValueError)
    with pytest.raises(ShapeError, match="theta0"):
        f.rmrc(target, [0.0, 0.3])
    with pytest.raises(InputError, match="tol"):
        f.rmrc(target, [0.0, 0.3, -1.0], tol=0)
    with pytest.raises(TypeError, match="a must be a sequence of 3"):
        Finger(a=(1.0, 2.0))
    with pytest.raises(InputError, match="finite"):
        Finger(phi1_deg=float("nan"))


@pytest.mark.parametrize("finger", FINGERS)
def test_stage_jacobian_matches_finite_differences(finger):
    rng = np.random.default_rng(2)
    h = 1e-6
    d = np.array([0.6, 0.8, 0.0])

    def task(q):
        return np.append(finger.forward(q[:3], z=q[3]), finger.sensor_pose(q[:3], z=q[3])[0][:, 2] @ d)

    for _ in range(10):
        q = np.append(rng.uniform(-2.5, 2.5, 3), rng.uniform(-20, 20))
        num = np.stack([(task(q + h * e) - task(q - h * e)) / (2 * h) for e in np.eye(4)], axis=1)
        np.testing.assert_allclose(finger.jacobian_stage(q[:3], z=q[3], direction=d), num, rtol=0, atol=1e-6)


def test_rmrc_lean_holds_the_lean_along_a_stroke():
    f = Finger()
    start = f.rmrc_lean(f.forward(fg.POSE_SCAN), 9.0, fg.POSE_SCAN)
    assert np.degrees(f.lean(start.theta, z=start.z)) == pytest.approx(9.0, abs=1e-5)
    th, z = start.theta, start.z
    plain = []
    for dx in np.linspace(-31.25, 31.25, 9):
        target = start.position + [dx, 0.0, 0.0]
        r = f.rmrc_lean(target, 9.0, th, z0=z, tol=1e-6)
        th, z = r.theta, r.z
        np.testing.assert_allclose(f.forward(th, z=z), target, rtol=0, atol=1e-6)
        assert np.degrees(f.lean(th, z=z)) == pytest.approx(9.0, abs=1e-6)
        plain.append(np.degrees(f.lean(f.rmrc(target, fg.POSE_SCAN, z=start.z).theta, z=start.z)))
    assert np.ptp(plain) > 20  # three joints alone let the lean drift by ~0.55 deg/mm
    with pytest.raises(SingularityError, match="z-stage Jacobian"):
        f.rmrc_lean(start.position + [10.0, 0, 0], 9.0, [0.0, 0.0, np.radians(-81.0)])  # link 2 horizontal
    with pytest.raises(InputError, match="lean_deg"):
        f.rmrc_lean(start.position, 90.0, fg.POSE_SCAN)
    with pytest.raises(InputError, match="non-zero"):
        f.rmrc_lean(start.position, 9.0, fg.POSE_SCAN, direction=(0, 0, 0))
    with pytest.raises(UnreachableError, match="z-stage did not reach"):
        f.rmrc_lean(start.position + [30.0, 0, 0], 9.0, fg.POSE_SCAN, max_iter=1, max_step=1.0)


# ---------------------------------------------------------------------------- contact geometry
def test_feeler_forces_table_and_walls():
    f = Finger()
    rot, origin = f.sensor_pose(fg.POSE_DOWN)
    apex_tip = origin + (SENSOR.outer_radius + 1.0) * rot[:, 2]
    local, tips = feeler_forces(SENSOR, rot, origin, [Table(apex_tip[2] + 0.4)], stiffness=0.5)
    np.testing.assert_allclose(tips[0], apex_tip)
    np.testing.assert_allclose(local[0], [0, 0, 0.2], atol=1e-12)  # pressed straight on: 0.5 N/mm x 0.4 mm
    assert np.all(local[1:] == 0)
    cyl = Cylinder(center=(0.0, 0.0), radius=10.0)
    d, n = cyl.signed_distance([[13.0, 0.0], [0.0, -4.0]])
    np.testing.assert_allclose(d, [3.0, -6.0])
    np.testing.assert_allclose(n, [[1, 0], [0, -1]])
    box = Box(center=(0.0, 0.0), size=(4.0, 2.0), angle_deg=90.0)
    d, n = box.signed_distance([[0.0, 3.0], [2.0, 3.0], [0.0, 0.5]])
    np.testing.assert_allclose(d, [1.0, np.hypot(1.0, 1.0), -1.0], atol=1e-12)  # x in [-1, 1], y in [-2, 2]
    np.testing.assert_allclose(n[0], [0, 1], atol=1e-12)
    assert box.corners.shape == (4, 2) and len(box.outline()) == 5


def test_scan_lean_keeps_the_apex_feeler_alone_on_the_specimen():
    f = Finger()
    r = f.rmrc_lean(f.forward(fg.POSE_SCAN), 9.0, fg.POSE_SCAN)
    rot, origin = f.sensor_pose(r.theta, z=r.z)
    tips = origin + ((SENSOR.outer_radius + 1.0) * SENSOR.element_frames[:, 2, :]) @ rot.T
    height = np.sort(tips[:, 2] - tips[0, 2])
    assert np.argmin(tips[:, 2]) == 0 and height[1] > 0.3  # next feeler 0.32 mm up: > 0.2 mm indentation
    local, _ = feeler_forces(SENSOR, rot, origin, [Table(tips[0, 2] + 0.2)], stiffness=0.5)
    assert np.flatnonzero(local[:, 2] > 0).tolist() == [0]
    # a frictionless press reaches the element 9 deg off its axis
    np.testing.assert_allclose(np.degrees(np.arctan2(np.hypot(*local[0, :2]), local[0, 2])), 9.0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(local[0]), 0.1, atol=1e-12)


def test_sliding_friction_mild_speed_dependence():
    assert fg.sliding_friction(0.4, 6.2) == pytest.approx(0.4)
    lo, hi = fg.sliding_friction(0.4, 1.4), fg.sliding_friction(0.4, 25.0)
    assert 0.39 < lo < 0.4 < hi < 0.41


# ---------------------------------------------------------------------------- a perfect sensor
class PerfectChain(ChainSimulator):
    """The chain's interface with the simulated forces plus 2 mN noise: tests the experiments' logic."""

    def __init__(self, noise=0.002):
        self.sensor, self.camera, self.noise = SENSOR, optitact.FisheyeCamera(), noise

    def describe(self):
        return {"perfect": True}

    def estimate(self, forces, *, first_index=0, progress=False, desc=""):
        arr = np.asarray(forces, float)
        arr = arr[None] if arr.ndim == 2 else arr
        rng = np.random.default_rng(first_index)
        loaded = arr[..., 2:3] > 0
        est = np.where(loaded, arr + rng.normal(0, self.noise, arr.shape), 0.0)
        flags = np.zeros(arr.shape[:2], bool)
        return ChainEstimate(forces=est, clamped=flags, contact=loaded[..., 0], truth=arr, tipped=flags,
                             readings=None)


@pytest.mark.parametrize("lean", [9.0, 0.0])
def test_surface_scanning_logic_recovers_mu(lean):
    res = fg.surface_scanning(chain=PerfectChain(), speeds=(1.4, 25.0), lean_deg=lean, progress=False)
    assert len(res["runs"]) == 6
    for r in res["runs"]:
        assert abs(r["error"]) < 0.02, r
        assert r["within_tolerance"] and r["steady_s"][0] >= 0.6
        assert r["lean_deg"] == pytest.approx([lean, lean], abs=1e-6)
        # the element sees the contact force at (friction angle - lean) from its axis
        expected = np.tan(np.arctan(r["mu_truth_steady"]) - np.radians(lean))
        assert r["local_ratio_steady"] == pytest.approx(expected, abs=0.01)
    assert res["runs"][0]["mu_simulated"] < 0.39 < res["runs"][1]["mu_simulated"]  # speed dependence
    assert res["runs"][1]["stage_travel_mm"] > 20 * (lean > 0)  # the stage holds the lean on 62.5 mm
    json.dumps(res, allow_nan=False)


def test_slip_experiment_logic():
    res = fg.slip_experiment(chain=PerfectChain(), progress=False)
    sc = res["scores"]
    assert len(res["onsets_s"]) == 6 and sc["recall"] == 1.0 and sc["precision"] == 1.0
    assert 0 <= sc["max_delay_s"] <= 0.3
    assert res["scores_truth"]["recall"] == 1.0
    json.dumps(res, allow_nan=False)


def test_contour_tracing_logic():
    res = fg.contour_tracing(chain=PerfectChain(), progress=False)
    cyl, box = res["objects"]["cylinder"], res["objects"]["box"]
    for r in (cyl, box):
        assert r["reached_end"] and not r["lost"] and r["n_contacts"] >= 8
        assert abs(r["table"]["estimated_z"]) < 0.1
        assert abs(r["trace_height_mm"] - (SENSOR.outer_radius + 1.0 + 5.0)) < 0.6
    assert cyl["max_deviation_mm"] < 0.3 and box["max_deviation_except_corners_mm"] < 0.3
    assert box["max_deviation_mm"] >= box["max_deviation_except_corners_mm"]
    shaky = fg.contour_tracing(chain=PerfectChain(), objects=("cylinder",), joint_error_deg=1.0, progress=False)
    assert shaky["objects"]["cylinder"]["max_deviation_mm"] > 0.5  # the finger's own errors show
    json.dumps(res, allow_nan=False)


def test_first_approach_goes_on_until_it_touches(monkeypatch):
    # starting 8 mm clear is more than one square-search side (retreat 2 + step 5 mm)
    opts = dict(step=5.0, approach_step=1.0, retreat=2.0, contact_threshold=0.3, table_threshold=0.2, lift=5.0,
                stiffness=0.5, feeler_height=1.0, max_frames=80, corner_margin=5.0)
    box = fg.Box(center=(188.0, 0.0), size=(40.0, 40.0), angle_deg=45.0)
    r = fg._trace_one(box, PerfectChain(), Finger(), start_y=-8.0, end_y=8.0, first_index=0, gap=8.0, **opts)
    assert not r["lost"] and r["reached_end"] and r["n_contacts"] >= 4
    start = fg._start_point
    monkeypatch.setattr(fg, "_start_point", lambda *a: (start(*a)[0] - 60.0, start(*a)[1]))  # 68 mm clear
    far = fg._trace_one(box, PerfectChain(), Finger(), start_y=-8.0, end_y=8.0, first_index=0, gap=8.0, **opts)
    assert far["lost"] and far["failure"] == "the object was not found on the first approach"
    assert far["n_contacts"] == 0 and np.ptp(np.asarray(far["path"])[:, 1]) == 0  # straight in, no turns


def test_table_touch_is_not_a_contour_point():
    # seed 4: one move sags the finger with joint errors until the table pushes up (a known case)
    r = fg.contour_tracing(chain=PerfectChain(), objects=("cylinder",), joint_error_deg=1.0, seed=4,
                           progress=False)["objects"]["cylinder"]
    assert r["table_touches"] >= 1 and r["reached_end"]
    assert r["max_deviation_mm"] < 6.0  # a table point recorded as the wall would be ~20 mm off
    assert np.all(np.abs(np.asarray(r["contacts"])[:, 0] - 170.0) < 30.0)


def test_joint_error_study_separates_sensing_from_positioning():
    base = fg.contour_tracing(chain=PerfectChain(), objects=("cylinder", "box"), span=8.0, progress=False)
    st = fg.joint_error_study(chain=PerfectChain(), joint_errors_deg=(0.0, 1.0), repeats=2, span=8.0,
                              baseline=base, progress=False)
    assert st["joint_error_deg"] == [0.0, 1.0]
    for name in ("cylinder", "box"):
        o = st["objects"][name]
        assert len(o["max_deviation_mm"][0]) == 1 and len(o["max_deviation_mm"][1]) == 2
        assert o["max_deviation_mm"][0][0] < 0.3 < min(o["max_deviation_mm"][1])  # 1 deg at ~200 mm reach
        assert o["published_mm"] == fg.PUBLISHED_DEVIATION_MM[name]
    assert st["objects"]["box"]["max_deviation_mm"][0][0] == base["objects"]["box"][
        "max_deviation_except_corners_mm"]
    json.dumps(st, allow_nan=False)
    with pytest.raises(InputError, match="repeats"):
        fg.joint_error_study(chain=PerfectChain(), repeats=0)


def test_plots(tmp_path):
    chain = PerfectChain()
    trace = fg.contour_tracing(chain=chain, objects=("box",), span=5.0, progress=False)
    result = {"surface_scanning": fg.surface_scanning(chain=chain, frictions=(0.4,), speeds=(6.2,),
                                                      slide_time=1.0, progress=False),
              "slip": fg.slip_experiment(chain=chain, rectangle=(16.0, 10.0), n_slips=2, progress=False),
              "contour_tracing": trace,
              "joint_error_study": fg.joint_error_study(chain=chain, joint_errors_deg=(0.0, 0.5), repeats=1,
                                                        objects=("box",), span=5.0, baseline=trace,
                                                        progress=False),
              "seed": 0, "full": False}
    fg.plot_experiment(result, tmp_path / "all.png")
    fg.plot_surface_scanning(result["surface_scanning"], tmp_path / "scan.png")
    fg.plot_slip(result["slip"], tmp_path / "slip.png")
    fig = fg.plot_contour(result["contour_tracing"], tmp_path / "contour.png")
    assert fig.axes
    fg.plot_joint_error_study(result["joint_error_study"], tmp_path / "joints.png")
    for name in ("all", "scan", "slip", "contour", "joints"):
        assert (tmp_path / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="missing"):
        fg.plot_experiment({"slip": {}}, tmp_path / "bad.png")


# ---------------------------------------------------------------------------- the real chain, tiny
@pytest.fixture(scope="module")
def tiny_chain(tmp_path_factory):
    """A 120x90 camera calibrated on 20 frames at 8 spp (a few seconds; noisy, for smoke tests only)."""
    cset = generate(tmp_path_factory.mktemp("finger") / "c.zarr", frames=20, camera=TINY, spp=8, seed=0,
                    render_mode="pixels", baseline_frames=2, progress=False)
    return ChainSimulator(fit(cset), spp=4, seed=3, baseline_frames=2, baseline_spp=8)


@pytest.mark.render
def test_chain_estimates_through_the_real_chain(tiny_chain):
    f = np.zeros((3, 41, 3))
    f[1, 0] = (0.1, 0.0, 0.8)
    f[2, 0] = (0.0, 0.1, 0.8)
    a = tiny_chain.estimate(f, first_index=5)
    b = tiny_chain.estimate(f, first_index=5)
    assert a.forces.shape == (3, 41, 3) and a.clamped.shape == a.contact.shape == (3, 41)
    np.testing.assert_array_equal(a.forces, b.forces)  # same seeds, same frames
    assert not a.contact[0].any() and a.contact[1:, 0].all()
    assert a.forces[1, 0, 2] > 0.3 and a.forces[1, 0, 0] > a.forces[2, 0, 0]  # coarse on a 120x90 camera
    np.testing.assert_array_equal(a.truth, f)
    assert len(a) == 3 and len(a.readings) == 3
    json.dumps(tiny_chain.describe())


def test_chain_checks(tiny_chain):
    with pytest.raises(CalibrationMismatchError):
        ChainSimulator(tiny_chain.calibration, camera=optitact.FisheyeCamera())
    with pytest.raises(InputError, match="must not set"):
        ChainSimulator(tiny_chain.calibration, render_options={"spp": 3})
    with pytest.raises(TypeError, match="Calibration"):
        ChainSimulator("shipped")
    with pytest.raises(ShapeError, match="forces"):
        tiny_chain.estimate(np.zeros((41, 2)))


@pytest.mark.render
def test_experiments_run_through_the_real_chain(tiny_chain, tmp_path):
    result = {
        "surface_scanning": fg.surface_scanning(chain=tiny_chain, frictions=(0.3,), speeds=(6.2,),
                                                slide_time=0.5, frame_rate=8.0, progress=False),
        "slip": fg.slip_experiment(chain=tiny_chain, rectangle=(6.0, 4.0), speed=6.0, n_slips=1,
                                   frame_rate=5.0, progress=False),
        "contour_tracing": fg.contour_tracing(chain=tiny_chain, objects=("cylinder",), span=3.0, max_frames=12,
                                              progress=False),
        "seed": 0, "full": False}
    run = result["surface_scanning"]["runs"][0]
    assert run["frames"] == len(run["series"]["t"]) and "mu_truth_steady" in run
    assert result["slip"]["frames"] == len(result["slip"]["series"]["t"])
    assert result["contour_tracing"]["objects"]["cylinder"]["frames"] <= 12
    json.dumps(result, allow_nan=False)
    fg.plot_experiment(result, tmp_path / "finger.png")
    assert (tmp_path / "finger.png").stat().st_size > 10_000


def test_experiment_argument_checks():
    with pytest.raises(InputError, match="not both"):
        fg.experiment(chain=PerfectChain(), calibration="extended")
    with pytest.raises(TypeError, match="ChainSimulator"):
        fg.surface_scanning(chain="default")
    with pytest.raises(InputError, match="seed"):
        fg.slip_experiment(chain=PerfectChain(), seed=None)
    with pytest.raises(InputError, match="objects"):
        fg.contour_tracing(chain=PerfectChain(), objects=("sphere",))
    assert dataclasses.is_dataclass(Finger())
