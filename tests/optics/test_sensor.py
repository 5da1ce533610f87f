"""Tests for the dome geometry in optitact.optics.sensor."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

R = 20.0


@pytest.fixture(scope="module")
def sensor():
    return DomeSensor.default()


def _spherical(polar_deg, azimuth_deg, radius=1.0):
    th, ph = math.radians(polar_deg), math.radians(azimuth_deg)
    return radius * np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph),
                              math.cos(th)])


# --------------------------------------------------------------------------- #
# Layout of the default 41-element sensor
# --------------------------------------------------------------------------- #
def test_default_equals_constructor(sensor):
    assert sensor == DomeSensor()
    assert sensor.ring_counts == (1, 8, 16, 16)
    assert sensor.ring_polar_deg == (0.0, 22.5, 45.0, 67.5)


def test_element_count_and_rings(sensor):
    assert sensor.n_elements == 41
    expected = np.array([0] * 1 + [1] * 8 + [2] * 16 + [3] * 16)
    np.testing.assert_array_equal(sensor.element_ring, expected)
    for name in ("element_ring", "element_polar", "element_azimuth"):
        assert getattr(sensor, name).shape == (41,)
    assert sensor.element_positions.shape == (41, 3)
    assert sensor.element_frames.shape == (41, 3, 3)


def test_apex_element(sensor):
    np.testing.assert_allclose(sensor.element_positions[0], [0.0, 0.0, R], rtol=0, atol=1e-12)
    np.testing.assert_allclose(sensor.element_frames[0], np.eye(3), rtol=0, atol=1e-12)


@pytest.mark.parametrize(
    ("element", "polar_deg", "azimuth_deg"),
    [
        (1, 22.5, 0.0),     # first of ring 1, on +x
        (2, 22.5, 45.0),
        (3, 22.5, 90.0),    # counter-clockwise: +y
        (5, 22.5, 180.0),
        (8, 22.5, 315.0),   # last of ring 1
        (9, 45.0, 0.0),     # first of ring 2
        (13, 45.0, 90.0),
        (24, 45.0, 337.5),
        (25, 67.5, 0.0),    # first of ring 3
        (29, 67.5, 90.0),
        (33, 67.5, 180.0),
        (40, 67.5, 337.5),
    ],
)
def test_element_order_and_position(sensor, element, polar_deg, azimuth_deg):
    np.testing.assert_allclose(sensor.element_positions[element],
                               _spherical(polar_deg, azimuth_deg, R), rtol=0, atol=1e-12)
    assert sensor.element_polar[element] == pytest.approx(math.radians(polar_deg), abs=1e-15)
    assert sensor.element_azimuth[element] == pytest.approx(math.radians(azimuth_deg), abs=1e-14)


def test_explicit_coordinates_of_ring_one(sensor):
    s, c = math.sin(math.radians(22.5)), math.cos(math.radians(22.5))
    np.testing.assert_allclose(sensor.element_positions[1], [R * s, 0.0, R * c], rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(sensor.element_positions[3], [0.0, R * s, R * c], rtol=0,
                               atol=1e-12)


def test_rings_are_counter_clockwise_seen_from_above(sensor):
    pos = sensor.element_positions
    for ring in range(1, 4):
        idx = np.flatnonzero(sensor.element_ring == ring)
        a, b = pos[idx], pos[np.roll(idx, -1)]
        # z-component of a x b > 0 for consecutive elements: counter-clockwise about +z.
        cross_z = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
        assert np.all(cross_z > 0)


def test_positions_on_outer_surface(sensor):
    np.testing.assert_allclose(np.linalg.norm(sensor.element_positions, axis=1), R, rtol=0,
                               atol=1e-12)
    assert np.all(sensor.element_positions[:, 2] > 0)


# --------------------------------------------------------------------------- #
# Element-local frames
# --------------------------------------------------------------------------- #
def test_frames_orthonormal_and_right_handed(sensor):
    fr = sensor.element_frames
    gram = np.einsum("nij,nkj->nik", fr, fr)
    np.testing.assert_allclose(gram, np.broadcast_to(np.eye(3), gram.shape), rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(fr), 1.0, rtol=0, atol=1e-12)
    # y = z x x
    np.testing.assert_allclose(fr[:, 1], np.cross(fr[:, 2], fr[:, 0]), rtol=0, atol=1e-12)


def test_z_axis_is_outward_unit_normal(sensor):
    normals = sensor.element_positions / R
    np.testing.assert_allclose(sensor.element_frames[:, 2], normals, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(sensor.element_frames[:, 2], axis=1), 1.0,
                               rtol=0, atol=1e-12)


def test_x_axis_is_projected_global_x(sensor):
    # Independent construction: x ~ (1 - n_x^2, -n_x n_y, -n_x n_z), normalised.
    n = sensor.element_positions / R
    raw = np.stack([1.0 - n[:, 0] ** 2, -n[:, 0] * n[:, 1], -n[:, 0] * n[:, 2]], axis=1)
    expected = raw / np.linalg.norm(raw, axis=1, keepdims=True)
    x = sensor.element_frames[:, 0]
    np.testing.assert_allclose(x, expected, rtol=0, atol=1e-12)
    # Characterisation: tangent, in span(e_x, n), pointing along +x.
    ex = np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(np.einsum("ni,ni->n", x, n), 0.0, rtol=0, atol=1e-12)
    spans = np.linalg.det(np.stack([x, np.broadcast_to(ex, x.shape), n], axis=1))
    np.testing.assert_allclose(spans, 0.0, rtol=0, atol=1e-12)
    assert np.all(x @ ex > 0)


def test_frame_of_element_on_y_axis(sensor):
    # Element 3 (azimuth 90 deg): normal in the y-z plane, so x stays global x.
    th = math.radians(22.5)
    fr = sensor.element_frames[3]
    np.testing.assert_allclose(fr[0], [1.0, 0.0, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fr[2], [0.0, math.sin(th), math.cos(th)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fr[1], [0.0, math.cos(th), -math.sin(th)], rtol=0, atol=1e-12)


def test_frame_of_element_on_x_axis(sensor):
    th = math.radians(22.5)
    fr = sensor.element_frames[1]
    np.testing.assert_allclose(fr[0], [math.cos(th), 0.0, -math.sin(th)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(fr[1], [0.0, 1.0, 0.0], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- #
# Cones and derived properties
# --------------------------------------------------------------------------- #
def test_cone_offsets(sensor):
    off = sensor.cone_offsets
    assert off.shape == (8, 2)
    np.testing.assert_allclose(np.hypot(off[:, 0], off[:, 1]), 1.25, rtol=0, atol=1e-12)
    np.testing.assert_allclose(off[0], [1.25, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(off[2], [0.0, 1.25], rtol=0, atol=1e-12)
    angles = np.mod(np.arctan2(off[:, 1], off[:, 0]), 2 * np.pi)
    np.testing.assert_allclose(angles, np.arange(8) * np.pi / 4, rtol=0, atol=1e-12)


@pytest.mark.parametrize("n_cones", [3, 5, 12])
def test_cone_offsets_custom_count(n_cones):
    s = DomeSensor(n_cones=n_cones, cone_base_radius=0.1)
    off = s.cone_offsets
    assert off.shape == (n_cones, 2)
    np.testing.assert_allclose(np.linalg.norm(off, axis=1), s.cone_circle_radius, rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(off.sum(axis=0), 0.0, rtol=0, atol=1e-12)


def test_derived_properties_default(sensor):
    assert sensor.inner_radius == 17.0
    e_star = 1.0 / (1.0 - 0.49**2)
    assert sensor.effective_modulus == pytest.approx(e_star, rel=0, abs=1e-14)
    assert sensor.shear_modulus == pytest.approx(1.0 / (2 * 1.49), rel=0, abs=1e-14)
    assert sensor.cone_half_angle == pytest.approx(math.pi / 4, rel=0, abs=1e-15)
    # Sneddon: pi r^2 = 2 P tan(alpha) / E*, tan(45 deg) = 1.
    assert sensor.max_cone_load == pytest.approx(math.pi * 0.45**2 * e_star / 2.0, rel=0,
                                                 abs=1e-14)


@pytest.mark.parametrize(
    ("youngs", "nu", "apex", "base"),
    [(2.0, 0.3, 60.0, 0.3), (0.5, 0.0, 120.0, 0.2), (3.0, 0.45, 30.0, 0.4)],
)
def test_derived_properties_custom(youngs, nu, apex, base):
    s = DomeSensor(youngs_modulus=youngs, poisson_ratio=nu, cone_apex_deg=apex,
                   cone_base_radius=base, outer_radius=15.0, shell_thickness=2.5)
    assert s.inner_radius == pytest.approx(12.5, rel=0, abs=1e-14)
    e_star = youngs / (1.0 - nu**2)
    assert s.effective_modulus == pytest.approx(e_star, rel=1e-14, abs=0)
    alpha = math.radians(apex / 2)
    p_max = s.max_cone_load
    # The load that makes Sneddon's contact area equal the cone's base area.
    assert 2.0 * p_max * math.tan(alpha) / e_star == pytest.approx(math.pi * base**2,
                                                                   rel=1e-13, abs=0)


# --------------------------------------------------------------------------- #
# dome_point: exponential map
# --------------------------------------------------------------------------- #
def test_dome_point_zero_offset_is_element_centre(sensor):
    pts = sensor.dome_point(np.arange(41), np.zeros((41, 2)))
    np.testing.assert_allclose(pts, sensor.element_positions, rtol=0, atol=1e-12)


def test_dome_point_geodesic_distance(sensor):
    rng = np.random.default_rng(11)
    element = rng.integers(0, 41, size=500)
    offset = rng.uniform(-6.0, 6.0, size=(500, 2))
    pts = sensor.dome_point(element, offset)
    assert pts.shape == (500, 3)
    np.testing.assert_allclose(np.linalg.norm(pts, axis=1), R, rtol=0, atol=1e-12)
    n = sensor.element_frames[element, 2]
    u = pts / R
    # Well-conditioned angle between the normal and the point.
    angle = np.arctan2(np.linalg.norm(np.cross(n, u), axis=1), np.einsum("ni,ni->n", n, u))
    np.testing.assert_allclose(R * angle, np.linalg.norm(offset, axis=1), rtol=0, atol=1e-11)
    # The point lies in the direction of the tangent offset.
    fr = sensor.element_frames[element]
    tangent = offset[:, :1] * fr[:, 0] + offset[:, 1:] * fr[:, 1]
    along = np.einsum("ni,ni->n", u, tangent)
    assert np.all(along >= 0)
    across = np.einsum("ni,ni->n", np.cross(n, tangent), u)
    np.testing.assert_allclose(across, 0.0, rtol=0, atol=1e-12)


def test_dome_point_small_offset_matches_tangent_plane(sensor):
    off = np.array([1e-4, -2e-4])
    p = sensor.dome_point(5, off)
    fr = sensor.element_frames[5]
    np.testing.assert_allclose(p, sensor.element_positions[5] + off[0] * fr[0] + off[1] * fr[1],
                               rtol=0, atol=1e-8)


def test_dome_point_apex_along_x():
    s = DomeSensor()
    p = s.dome_point(0, [R * math.pi / 4, 0.0])
    np.testing.assert_allclose(p, _spherical(45.0, 0.0, R), rtol=0, atol=1e-12)
    p = s.dome_point(0, [0.0, R * math.pi / 6])
    np.testing.assert_allclose(p, _spherical(30.0, 90.0, R), rtol=0, atol=1e-12)


def test_dome_point_broadcasts(sensor):
    element = np.broadcast_to(np.arange(41)[:, None], (41, 8))
    offsets = np.broadcast_to(sensor.cone_offsets, (41, 8, 2))
    pts = sensor.dome_point(element, offsets)
    assert pts.shape == (41, 8, 3)
    for i in (0, 7, 30):
        np.testing.assert_allclose(pts[i], sensor.dome_point(np.full(8, i), sensor.cone_offsets),
                                   rtol=0, atol=0)


def test_dome_point_does_not_mutate(sensor):
    element = np.array([1, 2, 3])
    offset = np.array([[0.1, 0.2], [0.0, 0.0], [-1.0, 0.5]])
    e0, o0 = element.copy(), offset.copy()
    sensor.dome_point(element, offset)
    np.testing.assert_array_equal(element, e0)
    np.testing.assert_array_equal(offset, o0)


# --------------------------------------------------------------------------- #
# Custom rings
# --------------------------------------------------------------------------- #
def test_custom_rings_without_apex():
    s = DomeSensor(ring_counts=(6, 12), ring_polar_deg=(30.0, 60.0))
    assert s.n_elements == 18
    np.testing.assert_array_equal(s.element_ring, [0] * 6 + [1] * 12)
    np.testing.assert_allclose(s.element_positions[0], _spherical(30.0, 0.0, R), rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(s.element_positions[1], _spherical(30.0, 60.0, R), rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(s.element_positions[6], _spherical(60.0, 0.0, R), rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(s.element_positions[9], _spherical(60.0, 90.0, R), rtol=0,
                               atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(s.element_frames), 1.0, rtol=0, atol=1e-12)


def test_custom_rings_lists_become_tuples():
    s = DomeSensor(ring_counts=[1, 4], ring_polar_deg=[0, 40])
    assert s.ring_counts == (1, 4)
    assert s.ring_polar_deg == (0, 40)
    assert s.n_elements == 5
    hash(s)
    np.testing.assert_allclose(s.element_positions[2], _spherical(40.0, 90.0, R), rtol=0,
                               atol=1e-12)


def test_single_apex_element():
    s = DomeSensor(ring_counts=(1,), ring_polar_deg=(0.0,), outer_radius=10.0,
                   shell_thickness=1.0)
    assert s.n_elements == 1
    np.testing.assert_allclose(s.element_positions, [[0.0, 0.0, 10.0]], rtol=0, atol=1e-12)


# --------------------------------------------------------------------------- #
# Serialisation and immutability
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    "kwargs",
    [{}, {"ring_counts": (6, 12), "ring_polar_deg": (30.0, 60.0), "preload": 0.05},
     {"outer_radius": 25.0, "shell_thickness": 4.0, "n_cones": 6, "cone_base_radius": 0.5,
      "poisson_ratio": 0.0}],
)
def test_json_round_trip(kwargs):
    s = DomeSensor(**kwargs)
    text = json.dumps(s.to_dict())
    back = DomeSensor.from_dict(json.loads(text))
    assert back == s
    assert hash(back) == hash(s)
    np.testing.assert_array_equal(back.element_positions, s.element_positions)


def test_to_dict_contents(sensor):
    d = sensor.to_dict()
    as_built = {"element_offsets", "element_gain"}  # only written when set
    assert set(d) == {f.name for f in dataclasses.fields(DomeSensor)} - as_built
    assert d["ring_counts"] == [1, 8, 16, 16]
    assert d["ring_polar_deg"] == [0.0, 22.5, 45.0, 67.5]
    assert d["outer_radius"] == 20.0


def test_from_dict_partial_uses_defaults():
    s = DomeSensor.from_dict({"preload": 0.1, "ring_counts": [1, 8], "ring_polar_deg": [0, 30]})
    assert s == DomeSensor(preload=0.1, ring_counts=(1, 8), ring_polar_deg=(0, 30))


def test_to_dict_json_friendly_with_numpy_inputs():
    s = DomeSensor(ring_counts=np.array([1, 8, 16, 16]), n_cones=np.int64(8),
                   outer_radius=np.float32(20.0))
    json.dumps(s.to_dict())


def test_frozen(sensor):
    with pytest.raises(dataclasses.FrozenInstanceError):
        sensor.outer_radius = 30.0  # type: ignore[misc]


@pytest.mark.parametrize(
    "name", ["element_positions", "element_frames", "element_polar", "element_azimuth",
             "element_ring", "cone_offsets"],
)
def test_cached_arrays_read_only(sensor, name):
    arr = getattr(sensor, name)
    with pytest.raises(ValueError, match="read-only"):
        arr[0] = 0


# --------------------------------------------------------------------------- #
# Validation
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"outer_radius": "20"}, r"outer_radius must be a real number, got str"),
        ({"youngs_modulus": True}, r"youngs_modulus must be a real number, got bool"),
        ({"preload": None}, r"preload must be a real number, got NoneType"),
        ({"poisson_ratio": 0.3j}, r"poisson_ratio must be a real number, got complex"),
        ({"n_cones": 8.0}, r"n_cones must be an integer, got float"),
        ({"n_cones": True}, r"n_cones must be an integer, got bool"),
        ({"ring_counts": (1, 8.0), "ring_polar_deg": (0, 20)},
         r"ring_counts\[1\] must be an integer, got float"),
        ({"ring_counts": (1, 8), "ring_polar_deg": (0, "20")},
         r"ring_polar_deg\[1\] must be a real number, got str"),
    ],
)
def test_wrong_kind_is_type_error(kwargs, match):
    with pytest.raises(TypeError, match=match):
        DomeSensor(**kwargs)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"outer_radius": 0.0}, r"outer_radius must be finite and > 0, got 0.0"),
        ({"outer_radius": -1.0}, r"outer_radius must be finite and > 0"),
        ({"lever_arm": float("nan")}, r"lever_arm must be finite and > 0, got nan"),
        ({"cone_circle_radius": float("inf")}, r"cone_circle_radius must be finite and > 0"),
        ({"preload": -0.1}, r"preload must be finite and >= 0, got -0.1"),
        ({"poisson_ratio": 0.5}, r"poisson_ratio must be in \[0, 0.5\), got 0.5"),
        ({"poisson_ratio": 0.7}, r"poisson_ratio must be in \[0, 0.5\), got 0.7"),
        ({"poisson_ratio": -0.1}, r"poisson_ratio must be finite and >= 0"),
        ({"shell_thickness": 20.0}, r"shell_thickness must be < outer_radius \(20.0 mm\)"),
        ({"shell_thickness": 25.0}, r"shell_thickness must be < outer_radius"),
        ({"refractive_index": 1.0}, r"refractive_index must be > 1, got 1.0"),
        ({"refractive_index": 0.8}, r"refractive_index must be > 1"),
        ({"cone_apex_deg": 180.0}, r"cone_apex_deg must be in \(0, 180\), got 180.0"),
        ({"n_cones": 2}, r"n_cones must be >= 3, got 2"),
        ({"ring_counts": (), "ring_polar_deg": ()}, r"must be non-empty and of equal length"),
        ({"ring_counts": (1, 8), "ring_polar_deg": (0.0,)},
         r"must be non-empty and of equal length, got 2 and 1"),
        ({"ring_counts": (1, 0), "ring_polar_deg": (0.0, 30.0)},
         r"ring_counts\[1\] must be >= 1, got 0"),
        ({"ring_counts": (2, 8), "ring_polar_deg": (0.0, 30.0)},
         r"a ring at polar angle 0 must hold 1 element, got 2"),
        ({"ring_counts": (1, 8), "ring_polar_deg": (0.0, 90.0)},
         r"ring_polar_deg\[1\] must be in \[0, 90\), got 90.0"),
        ({"ring_counts": (1, 8), "ring_polar_deg": (0.0, 120.0)},
         r"ring_polar_deg\[1\] must be in \[0, 90\)"),
        ({"ring_counts": (8,), "ring_polar_deg": (-10.0,)},
         r"ring_polar_deg\[0\] must be finite and >= 0"),
        ({"ring_counts": (1, 8, 8), "ring_polar_deg": (0.0, 45.0, 30.0)},
         r"ring_polar_deg must be strictly increasing"),
        ({"ring_counts": (1, 8, 8), "ring_polar_deg": (0.0, 30.0, 30.0)},
         r"ring_polar_deg must be strictly increasing"),
        ({"cone_base_radius": 0.5}, r"cone_base_radius 0.5 mm makes neighbouring cones overlap"),
        ({"n_cones": 16}, r"makes neighbouring cones overlap .*16 cones"),
    ],
)
def test_bad_value_is_value_error(kwargs, match):
    with pytest.raises(InputError, match=match) as info:
        DomeSensor(**kwargs)
    assert isinstance(info.value, ValueError)


def test_touching_cones_allowed():
    pitch = 2 * 1.25 * math.sin(math.pi / 8)
    s = DomeSensor(cone_base_radius=pitch / 2)
    assert s.cone_base_radius == pitch / 2


def test_from_dict_unknown_keys():
    d = DomeSensor().to_dict()
    d["colour"] = "red"
    d["aperture"] = 2
    with pytest.raises(InputError, match=r"sensor parameters: unknown parameter\(s\) \['aperture', 'colour'\]"):
        DomeSensor.from_dict(d)
    with pytest.raises(ValueError, match=r"valid: \[.*'outer_radius'"):
        DomeSensor.from_dict({"radius": 20})


@pytest.mark.parametrize("bad", [[("outer_radius", 20.0)], "outer_radius", None])
def test_from_dict_not_a_dict(bad):
    with pytest.raises(TypeError, match=r"sensor parameters must be a dict"):
        DomeSensor.from_dict(bad)


def test_from_dict_validates_values():
    with pytest.raises(InputError, match=r"poisson_ratio must be in"):
        DomeSensor.from_dict({"poisson_ratio": 0.5})


# ----------------------------------------------------------------------------- as built
def test_element_offsets_move_centres_by_the_exponential_map(sensor):
    rng = np.random.default_rng(3)
    off = rng.normal(0.0, 0.15, (sensor.n_elements, 2))
    built = DomeSensor(element_offsets=off)
    # the design frames' logarithmic map of the displaced centres gives the offsets back
    back = sensor.tangent_offset(np.arange(sensor.n_elements), built.element_positions)
    np.testing.assert_allclose(back, off, atol=1e-12)
    # geodesic distance = offset length
    cosang = np.sum(built.element_positions * sensor.element_positions, axis=1) / sensor.outer_radius ** 2
    np.testing.assert_allclose(sensor.outer_radius * np.arccos(np.clip(cosang, -1, 1)),
                               np.linalg.norm(off, axis=1), atol=1e-6)
    f = built.element_frames  # still orthonormal, z the outward normal at the new centre
    np.testing.assert_allclose(np.einsum("nij,nkj->nik", f, f), np.broadcast_to(np.eye(3), f.shape), atol=1e-12)
    np.testing.assert_allclose(f[:, 2] * sensor.outer_radius, built.element_positions, atol=1e-12)
    z = f[:, 2]
    np.testing.assert_allclose(np.cos(built.element_polar), z[:, 2], atol=1e-12)
    assert built.as_designed == sensor


def test_as_built_fields_round_trip_and_stay_out_of_designed_dicts(sensor):
    rng = np.random.default_rng(4)
    built = DomeSensor(element_offsets=rng.normal(0, 0.1, (41, 2)), element_gain=rng.uniform(0.8, 1.2, 41))
    d = built.to_dict()
    assert len(d["element_offsets"]) == 41 and len(d["element_gain"]) == 41
    assert DomeSensor.from_dict(json.loads(json.dumps(d))) == built
    assert "element_gain" not in sensor.to_dict()
    np.testing.assert_array_equal(sensor.gains, np.ones(41))
    np.testing.assert_allclose(built.gains, built.element_gain)


@pytest.mark.parametrize("kw, match", [
    ({"element_gain": [1.0] * 40}, "shape"),
    ({"element_gain": [0.0] * 41}, "1/16"),
    ({"element_gain": [float("nan")] * 41}, "finite"),
    ({"element_offsets": [[0.0, 0.0]] * 41 + [[0, 0]]}, "shape"),
    ({"element_offsets": [[3.0, 0.0]] * 41}, "column_diameter"),
])
def test_bad_as_built_fields_are_refused(kw, match):
    with pytest.raises(ValueError, match=match):
        DomeSensor(**kw)


def test_as_built_field_of_the_wrong_type_is_a_type_error():
    with pytest.raises(TypeError, match="element_gain"):
        DomeSensor(element_gain=1.5)
