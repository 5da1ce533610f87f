"""The finger's scene: objects, the feelers' penalty contact, world/local forces, sliding friction."""

from __future__ import annotations

import numpy as np
import pytest

import optitact
from optitact.finger.kinematics import POSE_DOWN, POSE_SCAN
from optitact.finger.scene import local_from_world, sliding_friction, world_from_local
from optitact.errors import ShapeError
from optitact.finger.kinematics import Finger
from optitact.finger.scene import Box, Cylinder, Table, feeler_forces

SENSOR = optitact.optics.sensor.DomeSensor.default()


# ---------------------------------------------------------------------------- contact geometry
def test_feeler_forces_table_and_walls():
    f = Finger()
    rot, origin = f.sensor_pose(POSE_DOWN)
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
    r = f.rmrc_lean(f.forward(POSE_SCAN), 9.0, POSE_SCAN)
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
    assert sliding_friction(0.4, 6.2) == pytest.approx(0.4)
    lo, hi = sliding_friction(0.4, 1.4), sliding_friction(0.4, 25.0)
    assert 0.39 < lo < 0.4 < hi < 0.41


def test_world_and_local_forces_round_trip():
    rng = np.random.default_rng(5)
    f = Finger()
    rots = np.stack([f.sensor_pose(th)[0] for th in rng.uniform(-1.0, 1.0, (4, 3))])
    local = rng.normal(0.0, 0.3, (4, SENSOR.n_elements, 3))
    world = world_from_local(SENSOR, local, rots)
    # direct: F_world = R frames_i^T (Fx, Fy, -Fz)
    direct = np.einsum("tij,nkj,tnk->tni", rots, SENSOR.element_frames, local * [1.0, 1.0, -1.0])
    np.testing.assert_allclose(world, direct, rtol=0, atol=1e-12)
    np.testing.assert_allclose(local_from_world(SENSOR, world, rots), local, rtol=0, atol=1e-12)
    with pytest.raises(ShapeError, match="rotations"):
        world_from_local(SENSOR, local, rots[:2])
    with pytest.raises(ShapeError, match="forces"):
        world_from_local(SENSOR, local[0], rots)
