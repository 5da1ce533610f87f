"""The finger's kinematics: DH forward map, Jacobians, RMRC with and without the z-stage, paths."""

from __future__ import annotations

import numpy as np
import pytest

from optitact.finger.kinematics import POSE_DOWN, POSE_SCAN
from optitact.errors import InputError, ShapeError
from optitact.finger.kinematics import Finger, SingularityError, UnreachableError

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
    rot_down, _ = f.sensor_pose(POSE_DOWN)
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
    start = f.rmrc_lean(f.forward(POSE_SCAN), 9.0, POSE_SCAN)
    assert np.degrees(f.lean(start.theta, z=start.z)) == pytest.approx(9.0, abs=1e-5)
    th, z = start.theta, start.z
    plain = []
    for dx in np.linspace(-31.25, 31.25, 9):
        target = start.position + [dx, 0.0, 0.0]
        r = f.rmrc_lean(target, 9.0, th, z0=z, tol=1e-6)
        th, z = r.theta, r.z
        np.testing.assert_allclose(f.forward(th, z=z), target, rtol=0, atol=1e-6)
        assert np.degrees(f.lean(th, z=z)) == pytest.approx(9.0, abs=1e-6)
        plain.append(np.degrees(f.lean(f.rmrc(target, POSE_SCAN, z=start.z).theta, z=start.z)))
    assert np.ptp(plain) > 20  # three joints alone let the lean drift by ~0.55 deg/mm
    with pytest.raises(SingularityError, match="z-stage Jacobian"):
        f.rmrc_lean(start.position + [10.0, 0, 0], 9.0, [0.0, 0.0, np.radians(-81.0)])  # link 2 horizontal
    with pytest.raises(InputError, match="lean_deg"):
        f.rmrc_lean(start.position, 90.0, POSE_SCAN)
    with pytest.raises(InputError, match="non-zero"):
        f.rmrc_lean(start.position, 9.0, POSE_SCAN, direction=(0, 0, 0))
    with pytest.raises(UnreachableError, match="z-stage did not reach"):
        f.rmrc_lean(start.position + [30.0, 0, 0], 9.0, POSE_SCAN, max_iter=1, max_step=1.0)


def test_follow_holds_the_lean_and_checks_targets():
    f = Finger()
    start = f.rmrc_lean(f.forward(POSE_SCAN), 9.0, POSE_SCAN)
    targets = start.position + np.outer(np.linspace(-10.0, 10.0, 5), [1.0, 0.0, 0.0])
    rots, stage = f.follow(targets, start.theta, z0=start.z, lean_deg=9.0)
    assert rots.shape == (5, 3, 3) and stage.shape == (5,)
    np.testing.assert_allclose(np.degrees(np.arcsin(rots[:, 0, 2])), 9.0, atol=1e-6)
    rots, stage = f.follow(targets[:2] - [0.0, 0.0, 5.0], POSE_SCAN, z0=start.z)  # three joints only
    assert np.all(stage == start.z)
    with pytest.raises(ShapeError, match="targets"):
        f.follow(targets[:, :2], POSE_SCAN)
    with pytest.raises(InputError, match="z0"):
        f.follow(targets, POSE_SCAN, z0=float("inf"))


def test_the_finger_package_imports_no_studies_and_no_matplotlib():
    import subprocess
    import sys

    code = ("import sys, optitact.finger; "
            "bad = [m for m in sys.modules if m.startswith(('optitact.studies', 'matplotlib'))]; "
            "assert not bad, bad")
    subprocess.run([sys.executable, "-c", code], check=True)
