"""Grasps with a thread8 array on each gripper jaw, and the per-frame features."""


import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.grasp import OBJECTS, GraspProtocol, PalpationObject, frame_features, grasp
from optitact.taxels.sources import Indenter
from optitact.taxels.thread8 import Thread8


def test_grasp_protocol_and_seed():
    proto = GraspProtocol.ideal()
    g = grasp(OBJECTS[1], seed=3, protocol=GraspProtocol.ideal())
    steps = proto.step_profile(100.0)
    n_move, n_hold = 10, 40
    assert steps.size == 2 * proto.n_steps * (n_move + n_hold)
    assert g.left.shape == g.right.shape == (g.contact_frame + 1 + steps.size, 8, 8)
    d_c = g.depth_mm[g.contact_frame]
    np.testing.assert_allclose(g.depth_mm.max(), d_c + proto.n_steps * proto.step_mm / 2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g.depth_mm[-1], d_c, rtol=0, atol=1e-12)
    assert g.left[g.contact_frame].max() >= 10 and g.left[: max(g.contact_frame - 5, 1)].max() < 10
    same = grasp(OBJECTS[1], seed=3, protocol=GraspProtocol.ideal())
    np.testing.assert_array_equal(g.left, same.left)
    np.testing.assert_array_equal(g.right, same.right)
    other = grasp(OBJECTS[1], seed=4, protocol=GraspProtocol.ideal())
    assert (other.x_mm, other.left.shape) != (g.x_mm, g.left.shape) or not np.array_equal(other.left, g.left)
    with pytest.raises(TypeError, match="PalpationObject"):
        grasp(OBJECTS[0].indenter, seed=0)
    with pytest.raises(TypeError, match="pair"):
        grasp(OBJECTS[0], seed=0, sensors=(Thread8(),))
    with pytest.raises(InputError, match="clearance_mm"):
        GraspProtocol(clearance_mm=(3.0, 1.0))
    with pytest.raises(InputError, match="object indenter shape"):
        PalpationObject("wire", Indenter("wire"), 5.0)


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.float32, np.float64])
def test_frame_features(dtype):
    rng = np.random.default_rng(0)
    frames = rng.integers(0, 255, size=(5, 8, 8)).astype(dtype)
    f = frame_features(frames)
    flat = frames.astype(np.float64).reshape(5, 64)
    np.testing.assert_allclose(f["mu"], flat.mean(axis=1), rtol=1e-12, atol=0)
    np.testing.assert_allclose(f["sigma"], flat.std(axis=1), rtol=1e-12, atol=0)
    assert f["mu"].dtype == np.float64 and list(f["frame"]) == list(range(5))


@pytest.mark.parametrize("bad, exc, match", [
    (np.zeros((3, 5, 5)), ShapeError, r"frames must have shape \(8, 8\)"),
    (np.zeros((3, 8, 8, 1)), ShapeError, "frames must have shape"),
    (np.full((2, 8, 8), np.nan), InputError, "frames must be finite"),
    (np.zeros((2, 8, 8), dtype=bool), TypeError, "real numeric array"),
])
def test_frame_features_bad_input(bad, exc, match):
    with pytest.raises(exc, match=match):
        frame_features(bad)
