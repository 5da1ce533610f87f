"""The indenter contact model: shapes, poses, Hertz and Winkler truths, force control, friction, the CLI.

The truths are independent of the module: Hertz's sphere on an elastic half-space
(``F = 4/3 E* sqrt(R) d^1.5``, ``a = sqrt(R d)``, ``p = p0 sqrt(1 - r^2/a^2)``), penetrations
computed here in closed form, :func:`optitact.finger.scene.feeler_forces` (the finger's penalty
model) and signed distances differentiated here by finite differences.
"""

from __future__ import annotations

import importlib.util
import math
import os
import subprocess
import sys
import time

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.finger import scene
from optitact.forces.indenter import (SDF, SPEC_GRAMMAR, ContactModel, Cylinder, Edge, Flat, Indentation, Pose,
                                      Sphere, parse_spec, press, press_points)
from optitact.optics.force_frames import global_from_local
from optitact.optics.sensor import DomeSensor

SENSOR = DomeSensor.default()
E, NU = 1.0, 0.49
E_STAR = E / (1.0 - NU**2)


def grid(spacing: float, half: float) -> tuple[np.ndarray, np.ndarray]:
    """Tips on a square grid in the plane z = 0 and their normals (+z)."""
    x = np.arange(-half, half + spacing / 2, spacing)
    tips = np.stack(np.meshgrid(x, x, [0.0]), -1).reshape(-1, 3)
    return tips, np.tile([0.0, 0.0, 1.0], (len(tips), 1))


# --------------------------------------------------------------------------------------------- shapes
RNG = np.random.default_rng(7)
SHAPES = [Sphere(4.0), Flat(3.0), Cylinder(2.5, 12.0), Edge(10.0, 0.6), Edge(8.0, 0.3, angle=100.0)]


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.spec)
def test_closed_form_normals_are_the_gradient_of_the_signed_distance(shape):
    """Normals agree with central differences of signed_distance, are unit, and the distance is 1-Lipschitz."""
    q = RNG.uniform(-6, 6, (400, 3)) + [0.0, 0.0, 2.0]
    d = shape.signed_distance(q)
    h = 1e-6
    grad = np.stack([(shape.signed_distance(q + h * e) - shape.signed_distance(q - h * e)) / (2 * h)
                     for e in np.eye(3)], axis=1)
    smooth = np.abs(np.linalg.norm(grad, axis=1) - 1.0) < 1e-4  # away from the kinks (edges, axes)
    assert smooth.mean() > 0.9
    np.testing.assert_allclose(shape.normal(q)[smooth], grad[smooth], atol=1e-5)
    np.testing.assert_allclose(np.linalg.norm(shape.normal(q), axis=1), 1.0, atol=1e-12)
    if not isinstance(shape, Flat):  # the punch's inside is the depth below its face, not a distance
        i, j = RNG.integers(0, len(q), (2, 2000))
        assert np.all(np.abs(d[i] - d[j]) <= np.linalg.norm(q[i] - q[j], axis=1) + 1e-12)


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.spec)
def test_every_shape_touches_the_origin_from_above(shape):
    """The indenter frame's convention: the lowest point at the origin, the solid on the +z side."""
    assert abs(shape.signed_distance([[0.0, 0.0, 0.0]])[0]) < 1e-12
    np.testing.assert_allclose(shape.normal([[0.0, 0.0, -1.0]]), [[0.0, 0.0, -1.0]], atol=1e-12)
    assert shape.signed_distance([[0.0, 0.0, 0.1]])[0] < 0


def test_shapes_have_the_distances_of_their_geometry():
    assert Sphere(5.0).signed_distance([[3.0, 0.0, 5.0]])[0] == pytest.approx(-2.0)
    assert Flat(3.0).signed_distance([[6.0, 0.0, -4.0]])[0] == pytest.approx(5.0)   # from the rim
    assert Cylinder(2.0, 10.0).signed_distance([[0.0, 3.0, 2.0]])[0] == pytest.approx(1.0)
    assert Cylinder(2.0, 10.0).signed_distance([[5.5, 0.0, 2.0]])[0] == pytest.approx(0.5)  # beyond an end
    e = Edge(10.0, 0.5, angle=90.0)
    # a flank: the line through the tip circle's tangent points, 45 deg from vertical
    p = np.array([[0.0, 3.0, 0.5]])  # beside the circle's centre, well outside the flank
    flank_dist = (3.0 * math.cos(math.pi / 4) - 0.0 * math.sin(math.pi / 4)) - 0.5
    assert e.signed_distance(p)[0] == pytest.approx(flank_dist)


@pytest.mark.parametrize("shape", SHAPES, ids=lambda s: s.spec)
def test_spec_round_trips(shape):
    assert parse_spec(shape.spec) == (shape, 0.0)


def test_parse_spec_reads_spin_and_refuses_bad_text():
    assert parse_spec("Sphere: radius = 5 , spin=30") == (Sphere(5.0), 30.0)
    for bad, why in [("sphere", "needs radius"), ("ball:radius=5", "unknown shape"),
                     ("sphere:radius=-1", "must be finite and > 0"), ("sphere:r=5", "not 'r'"),
                     ("sphere:radius=five", "not a number"), ("cylinder:radius=1", "needs length"),
                     ("sphere:radius=1,radius=2", "given twice"),
                     ("edge:length=1,tip_radius=1,angle=200", "(0, 180)"),
                     ("sphere:radius=nan", "finite"), ("sphere:radius", "not key=value"), (":x", "not NAME")]:
        with pytest.raises(InputError, match="expected sphere:radius=R") as e:
            parse_spec(bad)
        assert why in str(e.value), (bad, str(e.value))


# ------------------------------------------------------------------------------------------------ pose
def test_pose_touching_puts_the_tip_on_the_feeler_tips_sphere():
    for polar, az, spin in [(0, 0, 0), (30, 40, 0), (67.5, 200, 35), (89, 0, 10)]:
        pose = Pose.touching(SENSOR, polar, az, spin_deg=spin)
        th, ph = math.radians(polar), math.radians(az)
        u = np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
        np.testing.assert_allclose(pose.position, 21.0 * u, atol=1e-12)
        np.testing.assert_allclose(pose.press_direction, -u, atol=1e-12)
        np.testing.assert_allclose(pose.rotation.T @ pose.rotation, np.eye(3), atol=1e-12)
        assert np.linalg.det(pose.rotation) == pytest.approx(1.0)
        assert abs(pose.rotation[:, 0] @ [0.0, 1.0, 0.0] * 0 + pose.rotation[:, 0] @ u) < 1e-12
    # zero spin: the x axis is the global x projected (the element frames' convention), spin turns it
    p0, p1 = Pose.touching(SENSOR, 30, 40), Pose.touching(SENSOR, 30, 40, spin_deg=90)
    x = np.array([1.0, 0.0, 0.0]) - p0.rotation[0, 2] * p0.rotation[:, 2]
    np.testing.assert_allclose(p0.rotation[:, 0], x / np.linalg.norm(x), atol=1e-12)
    np.testing.assert_allclose(p1.rotation[:, 0], p0.rotation[:, 1], atol=1e-12)


def test_pose_touching_at_an_element_touches_that_element_first():
    i = 12
    pose = Pose.touching(SENSOR, math.degrees(SENSOR.element_polar[i]), math.degrees(SENSOR.element_azimuth[i]))
    assert press(SENSOR, Sphere(3.0), pose, depth=-1e-9).n_contact == 0
    ind = press(SENSOR, Sphere(3.0), pose, depth=1e-3)
    assert np.flatnonzero(ind.contact).tolist() == [i]
    assert ind.normal[i] == pytest.approx(2e-3, rel=1e-9)  # the default 2 N/mm
    np.testing.assert_allclose(ind.forces[i], [0.0, 0.0, 2e-3], atol=1e-15)


def test_pose_rotation_vector_and_matrix_agree():
    from scipy.spatial.transform import Rotation

    v = np.array([0.3, -0.5, 0.9])
    a = Pose([1.0, 2.0, 3.0], v)
    np.testing.assert_allclose(a.rotation, Rotation.from_rotvec(v).as_matrix(), atol=1e-12)
    b = Pose([1.0, 2.0, 3.0], Rotation.from_rotvec(v).as_matrix())
    np.testing.assert_allclose(b.rotation, a.rotation, atol=1e-12)
    np.testing.assert_allclose(a.to_local([a.position + a.rotation @ [0.1, 0.2, 0.3]])[0], [0.1, 0.2, 0.3],
                               atol=1e-12)
    np.testing.assert_allclose(a.moved(2.0).position, a.position + 2.0 * a.press_direction)


# ------------------------------------------------------------------------------------------- Hertz
@pytest.fixture(scope="module")
def hertz():
    """A rigid sphere (R = 10 mm) 0.1 mm into a 0.1 mm grid of rigid feelers on coupled rubber."""
    spacing, radius, depth = 0.1, 10.0, 0.1
    tips, up = grid(spacing, 2.0)
    model = ContactModel(stiffness=math.inf, coupling=True, youngs_modulus=E, poisson_ratio=NU)
    ind = press_points(tips, up, spacing**2, Sphere(radius), Pose([0.0, 0.0, 0.0]), depth=depth, model=model)
    return ind, tips, spacing, radius, depth, model


def test_hertz_force_contact_radius_and_pressure(hertz):
    """Boussinesq coupling on a dense flat array reproduces Hertz's sphere (measured: 0.4 %, 1 %)."""
    ind, tips, spacing, radius, depth, _ = hertz
    f_hertz = 4.0 / 3.0 * E_STAR * math.sqrt(radius) * depth**1.5
    assert abs(ind.normal_force / f_hertz - 1.0) < 0.02, (ind.normal_force, f_hertz)
    a = math.sqrt(radius * depth)
    r = np.hypot(tips[:, 0], tips[:, 1])
    assert abs(r[ind.contact].max() - a) <= spacing          # the contact edge within one grid step
    assert r[~ind.contact].min() >= a - spacing
    p0 = 2.0 * E_STAR * a / (math.pi * radius)               # Hertz's peak pressure, independent of F
    pressure = ind.normal / spacing**2
    inner = r < 0.9 * a
    profile = p0 * np.sqrt(1.0 - (r[inner] / a) ** 2)
    rms = np.sqrt(np.mean((pressure[inner] - profile) ** 2)) / p0
    assert rms < 0.03, rms
    # frictionless: the forces point along the sphere's normals, and the resultant is vertical
    np.testing.assert_allclose(ind.resultant[:2], 0.0, atol=1e-12)


def test_hertz_force_control_and_the_three_halves_power(hertz):
    ind, tips, spacing, radius, depth, model = hertz
    up = np.tile([0.0, 0.0, 1.0], (len(tips), 1))
    deeper = press_points(tips, up, spacing**2, Sphere(radius), Pose([0.0, 0.0, 0.0]), depth=1.5 * depth,
                          model=model)
    assert deeper.normal_force / ind.normal_force == pytest.approx(1.5**1.5, rel=0.02)
    # force control on a coarser grid (a quicker solve): the depth for Hertz's force, and the force back
    coarse, up = grid(0.2, 2.0)
    f_hertz = 4.0 / 3.0 * E_STAR * math.sqrt(radius) * depth**1.5
    back = press_points(coarse, up, 0.04, Sphere(radius), Pose([0.0, 0.0, 0.0]), force=f_hertz, model=model)
    assert abs(back.normal_force / f_hertz - 1.0) < 1e-6
    assert back.depth == pytest.approx(depth, rel=0.05)


def test_coupled_solution_satisfies_the_complementarity_conditions():
    """Independently of the solver: rebuild the compliance matrix from Boussinesq's formula and check."""
    spacing, radius = 0.25, 6.0
    tips, up = grid(spacing, 2.5)
    model = ContactModel(stiffness=2.0, coupling=True, youngs_modulus=E, poisson_ratio=NU)
    pose = Pose([0.1, -0.05, 0.0])
    ind = press_points(tips, up, spacing**2, Sphere(radius), pose, depth=0.3, model=model)
    centre = pose.position + [0.0, 0.0, radius - 0.3]
    v = tips - centre
    gap = np.linalg.norm(v, axis=1) - radius
    n = v / np.linalg.norm(v, axis=1)[:, None]
    r = np.linalg.norm(tips[:, None] - tips[None], axis=-1)
    c = (1 - NU**2) / (math.pi * E)
    with np.errstate(divide="ignore"):
        w = np.where(r > 0, c / r, 2 * c / math.sqrt(spacing**2 / math.pi))
    cos = -n[:, 2]
    a = np.eye(len(tips)) / 2.0 + cos[:, None] * cos[None, :] * w
    p = ind.normal
    assert np.all(p >= 0)
    after = gap + a @ p
    assert after.min() > -1e-10
    assert np.abs(p * after).max() < 1e-10
    assert ind.n_contact > 20 and np.all(gap[ind.contact] < 0)


# ----------------------------------------------------------------------------------------- Winkler
def test_winkler_sphere_is_k_times_the_penetration_of_every_tip():
    tips, up = grid(0.5, 5.0)
    k, radius, depth = 0.7, 6.0, 0.3
    pose = Pose([0.3, -0.2, 0.0])
    ind = press_points(tips, up, 0.25, Sphere(radius), pose, depth=depth,
                       model=ContactModel(stiffness=k))
    centre = np.array([0.3, -0.2, radius - depth])
    v = tips - centre
    pen = np.maximum(radius - np.linalg.norm(v, axis=1), 0.0)
    n = v / np.linalg.norm(v, axis=1)[:, None]
    np.testing.assert_allclose(ind.global_forces, (k * pen)[:, None] * n, rtol=0, atol=1e-14)
    assert ind.normal_force == pytest.approx(float(k * pen @ -n[:, 2]), rel=1e-13)
    np.testing.assert_array_equal(ind.contact, pen > 0)
    # element-local: z = +z here, so Fz is the downward push and (Fx, Fy) the horizontal one
    np.testing.assert_allclose(ind.forces, ind.global_forces * [1.0, 1.0, -1.0], atol=1e-15)


def test_winkler_sphere_on_the_dome_matches_a_direct_computation():
    pose = Pose.touching(SENSOR, 22.5, 0.0)
    radius, depth = 15.0, 2.5
    ind = press(SENSOR, Sphere(radius), pose, depth=depth, model=ContactModel(stiffness=0.5, skin=False))
    tips = 21.0 * SENSOR.element_frames[:, 2, :]
    centre = pose.position - (depth - radius) * pose.rotation[:, 2]
    v = tips - centre
    pen = np.maximum(radius - np.linalg.norm(v, axis=1), 0.0)
    g = (0.5 * pen)[:, None] * v / np.linalg.norm(v, axis=1)[:, None]
    np.testing.assert_allclose(global_from_local(SENSOR, ind.forces), g, atol=1e-13)
    assert ind.n_contact == np.count_nonzero(pen) >= 3
    assert ind.slipping.sum() == 0 and ind.on_skin.sum() == 0


@pytest.mark.parametrize("polar, azimuth", [(0.0, 0.0), (30.0, 40.0), (50.0, 200.0)])
@pytest.mark.parametrize("skin, depth", [(False, 2.0), (True, 0.9)])
def test_a_large_flat_on_the_dome_is_feeler_forces_against_a_table(polar, azimuth, skin, depth):
    """Where the models overlap (the feeler tips; with the skin: a plate that cannot reach it, 0.9 mm < h)."""
    pose = Pose.touching(SENSOR, polar, azimuth, spin_deg=25.0)
    ind = press(SENSOR, Flat(100.0), pose, depth=depth, model=ContactModel(stiffness=0.5, skin=skin))
    # the table's world: the dome's pressing direction is world -z, the plane at world z = 0
    rot = np.diag([1.0, -1.0, -1.0]) @ pose.rotation.T
    origin = np.array([0.0, 0.0, 21.0 - depth])
    want, tips = scene.feeler_forces(SENSOR, rot, origin, [scene.Table(0.0)])
    np.testing.assert_allclose(ind.forces, want, rtol=0, atol=1e-13)
    assert ind.n_contact == np.count_nonzero(want[:, 2]) > 0
    assert not ind.on_skin.any()
    np.testing.assert_allclose(ind.points, tips[ind.contact] @ rot - rot.T @ origin, atol=1e-12)


def test_a_lying_cylinder_on_the_dome_is_feeler_forces_against_a_standing_one():
    radius, length, depth = 4.0, 60.0, 1.5
    pose = Pose.touching(SENSOR, 45.0, 22.5, spin_deg=90.0)
    ind = press(SENSOR, Cylinder(radius, length), pose, depth=depth, model=ContactModel(skin=False))
    # scene world = the indenter frame with its x axis along world z: the cylinder stands on the table
    perm = np.array([[0.0, 0.0, 1.0], [0.0, 1.0, 0.0], [-1.0, 0.0, 0.0]])
    rot = perm @ pose.rotation.T
    origin = -rot @ pose.moved(depth).position + [0.0, 0.0, length / 2]
    want, _ = scene.feeler_forces(SENSOR, rot, origin, [scene.Cylinder((radius, 0.0), radius, length)],
                                  stiffness=2.0)
    np.testing.assert_allclose(ind.forces, want, rtol=0, atol=1e-13)
    assert ind.n_contact >= 2


# -------------------------------------------------------------------------------------- force control
@pytest.mark.parametrize("shape, polar, azimuth", [(Sphere(5.0), 30.0, 40.0), (Flat(4.0), 10.0, 0.0),
                                                  (Edge(20.0, 2.0), 45.0, 90.0),
                                                  (Cylinder(3.0, 15.0), 20.0, 300.0)])
@pytest.mark.parametrize("coupling", [False, True])
def test_force_control_reaches_the_force(shape, polar, azimuth, coupling):
    pose = Pose.touching(SENSOR, polar, azimuth, spin_deg=15.0)
    model = ContactModel.of(SENSOR, coupling=coupling)
    for target in (0.05, 0.8, 2.0):
        ind = press(SENSOR, shape, pose, force=target, model=model)
        assert abs(ind.normal_force / target - 1.0) < 1e-6, (target, ind.normal_force)
        again = press(SENSOR, shape, pose, depth=ind.depth, model=model)
        np.testing.assert_array_equal(again.forces, ind.forces)
        assert ind.n_contact >= 1
        assert ind.forces[:, 2].min() >= -1e-3 * ind.forces[:, 2].max()  # elements are pressed, not pulled
    depths = np.linspace(0.0, ind.depth, 31)
    forces = [press(SENSOR, shape, pose, depth=d, model=model).normal_force for d in depths]
    assert np.all(np.diff(forces) >= -1e-12)  # non-decreasing up to 2 N


def test_coupling_softens_and_spreads_the_load():
    pose = Pose.touching(SENSOR, 22.5, 0.0)
    off = press(SENSOR, Sphere(10.0), pose, depth=2.0, model=ContactModel.of(SENSOR))
    on = press(SENSOR, Sphere(10.0), pose, depth=2.0, model=ContactModel.of(SENSOR, coupling=True))
    assert on.normal_force < off.normal_force
    assert on.n_contact == off.n_contact


def test_the_skin_catches_a_small_sphere_between_the_feelers():
    """A 5 mm ball between elements sinks past the tips; the skin carries it to the elements around."""
    pose = Pose.touching(SENSOR, 30.0, 40.0)
    tips_only = ContactModel(skin=False)
    with pytest.raises(InputError, match="sinks past the feelers"):
        press(SENSOR, Sphere(5.0), pose, force=2.5, model=tips_only)
    ind = press(SENSOR, Sphere(5.0), pose, force=2.5)
    assert ind.on_skin.any() and ind.n_contact >= 3
    # every load reaches the elements: the element forces sum to the contact points' forces
    np.testing.assert_allclose(ind.resultant, ind.point_forces.sum(axis=0), atol=1e-12)
    assert float(ind.resultant @ pose.press_direction) == pytest.approx(2.5, rel=1e-9)
    # the finer the skin's sampling, the same forces (within a few per cent)
    fine = press(SENSOR, Sphere(5.0), pose, depth=ind.depth, model=ContactModel(skin_spacing=0.25))
    assert np.abs(fine.forces - ind.forces).max() < 0.03 * np.abs(ind.forces).max()


def test_press_is_fast():
    pose = Pose.touching(SENSOR, 30.0, 40.0)
    press(SENSOR, Sphere(5.0), pose, depth=0.5)
    t = time.perf_counter()
    for _ in range(50):
        press(SENSOR, Sphere(12.0), pose, depth=1.0)
    per_call = (time.perf_counter() - t) / 50
    assert per_call < 0.05, per_call  # about 1 ms on an idle core


# -------------------------------------------------------------------------------------------- friction
def test_friction_sticks_below_the_coulomb_limit_and_slips_beyond():
    pose = Pose.touching(SENSOR, 0.0, 0.0)
    model = ContactModel.of(SENSOR)
    kt, mu = model.tangential, 0.5
    assert kt == pytest.approx(2.0 * 2 * (1 - 0.49) / (2 - 0.49))  # Mindlin's share of k = 2 N/mm
    p = 2.0 * 0.5  # apex alone, 0.5 mm in
    threshold = mu * p / kt
    stick = press(SENSOR, Flat(100.0), pose, depth=0.5, slide=(0.5 * threshold, 0.0), friction=mu)
    np.testing.assert_allclose(stick.forces[0], [kt * 0.5 * threshold, 0.0, p], atol=1e-14)
    assert stick.n_contact == 1 and not stick.slipping.any()
    slip = press(SENSOR, Flat(100.0), pose, depth=0.5, slide=(0.0, 10 * threshold), friction=mu)
    np.testing.assert_allclose(slip.forces[0], [0.0, mu * p, p], atol=1e-14)
    assert slip.slipping.tolist() == [True] + [False] * 40
    frictionless = press(SENSOR, Flat(100.0), pose, depth=0.5, slide=(1.0, 0.0), friction=0.0)
    np.testing.assert_allclose(frictionless.forces[0], [0.0, 0.0, p], atol=1e-15)


def test_far_beyond_the_limit_every_element_slides_at_mu_times_its_normal_force():
    pose = Pose.touching(SENSOR, 0.0, 0.0, spin_deg=30.0)
    mu = 0.4
    ind = press(SENSOR, Flat(100.0), pose, depth=2.0, slide=(5.0, 2.0), friction=mu)
    assert ind.n_contact == 9 and ind.slipping.sum() == 9
    g = ind.global_forces[ind.contact]
    normal = -g[:, 2]  # the plate's normal is -z: normal and tangential parts split along z
    np.testing.assert_allclose(normal, ind.normal[ind.contact], rtol=1e-12)
    np.testing.assert_allclose(np.hypot(g[:, 0], g[:, 1]), mu * normal, rtol=1e-12)
    slide = 5.0 * pose.rotation[:, 0] + 2.0 * pose.rotation[:, 1]  # (dx, dy) in the indenter's own axes
    np.testing.assert_allclose(g[:, :2] / np.hypot(g[:, 0], g[:, 1])[:, None],
                               np.tile(slide[:2] / np.linalg.norm(slide[:2]), (9, 1)), atol=1e-12)
    same = press(SENSOR, Flat(100.0), pose, depth=2.0, slide=slide, friction=mu)  # a 3-vector, sensor frame
    np.testing.assert_allclose(same.forces, ind.forces, atol=1e-14)


def test_a_slide_in_stick_on_a_flat_array_is_k_t_times_the_slide():
    tips, up = grid(0.5, 3.0)
    model = ContactModel(stiffness=0.8, tangential_stiffness=0.3)
    ind = press_points(tips, up, 0.25, Flat(2.0), Pose([0.0, 0.0, 0.0]), depth=0.2, slide=(0.01, -0.02),
                       model=model)
    t = ind.global_forces[ind.contact]
    np.testing.assert_allclose(t[:, :2], np.tile([0.3 * 0.01, -0.3 * 0.02], (ind.n_contact, 1)), atol=1e-15)
    np.testing.assert_allclose(-t[:, 2], 0.8 * 0.2)
    assert not ind.slipping.any()


# ------------------------------------------------------------------------------------------------- SDF
def test_a_user_sdf_of_a_sphere_gives_the_spheres_forces():
    radius = 6.0
    ball = SDF(lambda q: np.linalg.norm(q - (0.0, 0.0, radius), axis=1) - radius)
    for pose, kw in [(Pose.touching(SENSOR, 30.0, 40.0), {"force": 0.8, "slide": (0.2, 0.1)}),
                     (Pose.touching(SENSOR, 10.0, 100.0), {"depth": 1.7})]:
        want = press(SENSOR, Sphere(radius), pose, **kw)
        got = press(SENSOR, ball, pose, **kw)
        np.testing.assert_allclose(got.forces, want.forces, rtol=0, atol=1e-8)
        assert got.depth == pytest.approx(want.depth, abs=1e-8)
    q = RNG.uniform(-3, 3, (50, 3))
    np.testing.assert_allclose(ball.normal(q), Sphere(radius).normal(q), atol=1e-8)


def test_sdf_errors_name_what_came():
    with pytest.raises(TypeError, match="SDF function must be callable"):
        SDF(5.0)
    with pytest.raises(ShapeError, match=r"one signed distance per point, shape \(3,\)"):
        SDF(lambda q: q).signed_distance(np.zeros((3, 3)))
    with pytest.raises(ShapeError, match="one signed distance per point"):
        SDF(lambda q: 1.0).signed_distance(np.zeros((3, 3)))
    with pytest.raises(TypeError, match="real numbers"):
        SDF(lambda q: np.array(["a"] * len(q))).signed_distance(np.zeros((2, 3)))
    with pytest.raises(InputError, match="must be finite"):
        SDF(lambda q: np.full(len(q), np.nan)).signed_distance(np.zeros((2, 3)))
    with pytest.raises(InputError, match="gradient is zero"):
        SDF(lambda q: np.zeros(len(q))).normal(np.zeros((2, 3)))
    with pytest.raises(ShapeError, match=r"one signed distance per point"):
        press(SENSOR, SDF(lambda q: q[:, :2]), Pose.touching(SENSOR, 0, 0), depth=1.0)


# ----------------------------------------------------------------------------------------- bad inputs
@pytest.mark.parametrize("make, error, match", [
    (lambda: Sphere(-1.0), InputError, "Sphere radius .* must be finite and > 0, got -1.0"),
    (lambda: Sphere(float("nan")), InputError, "Sphere radius"),
    (lambda: Sphere("5"), TypeError, "Sphere radius .* must be a real number, got str"),
    (lambda: Flat(0.0), InputError, "Flat radius"),
    (lambda: Cylinder(1.0, -2.0), InputError, "Cylinder length"),
    (lambda: Edge(1.0, 0.0), InputError, "Edge tip_radius"),
    (lambda: Edge(1.0, 0.5, angle=180.0), InputError, r"Edge angle \(deg\) must be in \(0, 180\)"),
    (lambda: Pose([np.nan, 0.0, 0.0]), InputError, "Pose position must be finite"),
    (lambda: Pose([0.0, 0.0]), ShapeError, r"Pose position must have shape \(3,\)"),
    (lambda: Pose([0.0, 0.0, 0.0], np.ones((3, 3))), InputError, "rotation matrix"),
    (lambda: Pose([0.0, 0.0, 0.0], np.diag([1.0, 1.0, -1.0])), InputError, "determinant"),
    (lambda: Pose([0.0, 0.0, 0.0], [0.0, np.inf, 0.0]), InputError, "Pose rotation must be finite"),
    (lambda: Pose([0.0, 0.0, 0.0], np.eye(2)), ShapeError, "rotation matrix or a"),
    (lambda: Pose.touching(SENSOR, 95.0, 0.0), InputError, r"polar_deg must be in \[0, 90\)"),
    (lambda: Pose.touching(SENSOR, np.nan, 0.0), InputError, "polar_deg must be finite"),
    (lambda: ContactModel(stiffness=-1.0), InputError, "stiffness"),
    (lambda: ContactModel(stiffness=math.inf), InputError, "needs coupling=True"),
    (lambda: ContactModel(poisson_ratio=0.5), InputError, r"\[0, 0.5\)"),
    (lambda: ContactModel(coupling=1), TypeError, "coupling must be a bool"),
    (lambda: ContactModel(skin_spacing=0.001), InputError, "skin_spacing"),
])
def test_bad_parameters_are_clear_errors(make, error, match):
    with pytest.raises(error, match=match):
        make()


@pytest.mark.parametrize("kw, error, match", [
    ({"depth": 1.0, "force": 0.5}, InputError, "exactly one of depth .* got both"),
    ({}, InputError, "exactly one of depth .* got neither"),
    ({"depth": np.nan}, InputError, "depth .* must be finite"),
    ({"force": -0.5}, InputError, "force .* must be finite and > 0"),
    ({"depth": 1.0, "friction": -0.1}, InputError, "friction must be finite and >= 0"),
    ({"depth": 1.0, "slide": (1.0, 2.0, 3.0, 4.0)}, ShapeError, "slide must be"),
    ({"depth": 1.0, "slide": (1.0, np.nan)}, InputError, "slide must be finite"),
    ({"depth": 1.0, "model": "soft"}, TypeError, "model must be a ContactModel"),
])
def test_bad_press_arguments_are_clear_errors(kw, error, match):
    with pytest.raises(error, match=match):
        press(SENSOR, Sphere(5.0), Pose.touching(SENSOR, 0.0, 0.0), **kw)


def test_bad_press_objects_and_unreachable_forces():
    pose = Pose.touching(SENSOR, 0.0, 0.0)
    with pytest.raises(TypeError, match="indenter must be a Shape"):
        press(SENSOR, "sphere", pose, depth=1.0)
    with pytest.raises(TypeError, match="pose must be a Pose"):
        press(SENSOR, Sphere(5.0), np.zeros(3), depth=1.0)
    with pytest.raises(TypeError, match="sensor must be a DomeSensor"):
        press(None, Sphere(5.0), pose, depth=1.0)
    away = Pose([0.0, 0.0, 40.0], np.diag([1.0, -1.0, -1.0]))  # above the dome, pressing away from it
    with pytest.raises(InputError, match="touches nothing"):
        press(SENSOR, Sphere(5.0), away, force=1.0)
    tips, up = grid(1.0, 2.0)
    with pytest.raises(ShapeError, match="normals must have the shape of tips"):
        press_points(tips, up[:3], 1.0, Sphere(1.0), Pose([0.0, 0.0, 0.0]), depth=0.1)
    with pytest.raises(InputError, match="areas must be > 0"):
        press_points(tips, up, 0.0, Sphere(1.0), Pose([0.0, 0.0, 0.0]), depth=0.1)
    with pytest.raises(InputError, match="non-zero"):
        press_points(tips, 0 * up, 1.0, Sphere(1.0), Pose([0.0, 0.0, 0.0]), depth=0.1)


def test_the_result_is_frozen_and_its_wrench_adds_up():
    ind = press(SENSOR, Sphere(5.0), Pose.touching(SENSOR, 30.0, 40.0), force=0.8, slide=(0.1, 0.0))
    assert isinstance(ind, Indentation)
    with pytest.raises(ValueError):
        ind.forces[0, 0] = 1.0
    np.testing.assert_allclose(global_from_local(SENSOR, ind.forces), ind.global_forces, atol=1e-15)
    assert ind.wrench.shape == (6,)
    np.testing.assert_allclose(ind.wrench[3:], np.cross(ind.points, ind.point_forces).sum(axis=0))
    assert "normal_force=0.8 N" in repr(ind)
    np.testing.assert_allclose(ind.pressed_pose.position,
                               ind.pose.position + ind.depth * ind.pose.press_direction)


# -------------------------------------------------------------------------------------------------- CLI
def test_the_cli_help_names_the_grammar():
    from optitact.cli import demo

    assert demo._INDENTER_GRAMMAR == SPEC_GRAMMAR


@pytest.fixture
def no_render(monkeypatch):
    import optitact.cli.demo as demo

    def refuse(*args, **kwargs):
        raise AssertionError("rendered despite a bad command line")

    monkeypatch.setattr(demo, "_render_frame", refuse)


@pytest.mark.parametrize("argv, match", [
    ([], "one of the arguments --forces --indenter is required"),
    (["--forces", "f.csv", "--indenter", "sphere:radius=5"], "not allowed with argument"),
    (["--indenter", "ball:r=5"], "expected sphere:radius=R"),
    (["--indenter", "sphere:radius=5", "--at", "30"], "expected POLAR,AZIMUTH"),
    (["--indenter", "sphere:radius=5", "--depth", "1", "--force", "1"], "not allowed with argument"),
    (["--indenter", "sphere:radius=5", "--depth", "1", "--slide", "1,2,3,4"], "expected DX,DY[,DZ]"),
    (["--indenter", "sphere:radius=5", "--depth", "1", "--forces-out", "f.txt"], "ending in .csv"),
])
def test_cli_argument_errors(no_render, capsys, tmp_path, argv, match):
    from optitact.cli import main

    with pytest.raises(SystemExit) as e:
        main(["render", "--out", str(tmp_path / "f.png"), *argv])
    assert e.value.code == 2
    assert match in capsys.readouterr().err


@pytest.mark.parametrize("argv, match", [
    (["--indenter", "sphere:radius=5"], "--indenter needs --depth MM"),
    (["--forces", "f.csv", "--depth", "1"], "--depth: only with --indenter"),
    (["--indenter", "sphere:radius=5", "--at", "95,0", "--depth", "1"], "polar_deg must be in [0, 90)"),
])
def test_cli_input_errors(no_render, capsys, tmp_path, argv, match):
    from optitact.cli import main

    assert main(["render", "--out", str(tmp_path / "f.png"), *argv]) == 2
    assert match in capsys.readouterr().err


@pytest.mark.render
def test_cli_renders_an_indenter_and_writes_its_forces(tmp_path):
    if importlib.util.find_spec("mitsuba") is None:
        pytest.skip("rendering needs the render extra (mitsuba)")
    import cv2

    from optitact.io.tables import read_forces_csv

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH",)}
    env["OPTITACT_CACHE_DIR"] = str(tmp_path / "cache")
    argv = [sys.executable, "-m", "optitact", "render", "--indenter", "sphere:radius=5,spin=10",
            "--at", "30,40", "--force", "0.8", "--slide", "0.1,0", "--friction", "0.4", "--width", "160",
            "--height", "120", "--spp", "4", "--out", "frame.png", "--forces-out", "forces.csv"]
    r = subprocess.run(argv, cwd=tmp_path, env=env, capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    frame = cv2.imread(str(tmp_path / "frame.png"), cv2.IMREAD_UNCHANGED)
    assert frame is not None and frame.shape == (120, 160)
    want = press(SENSOR, Sphere(5.0), Pose.touching(SENSOR, 30.0, 40.0, spin_deg=10.0), force=0.8,
                 slide=(0.1, 0.0), friction=0.4)
    got = read_forces_csv(tmp_path / "forces.csv", 41)
    np.testing.assert_allclose(got, want.forces, rtol=0, atol=1e-12)
    assert "pressing force 0.8 N" in r.stderr and f"{want.n_contact} of 41 elements in contact" in r.stderr
    assert all(f"element {i:2d}:" in r.stderr for i in np.flatnonzero(want.contact))
