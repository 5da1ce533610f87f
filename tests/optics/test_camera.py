"""Tests for the closed-form fisheye camera in optitact.optics.camera."""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.optics.camera import FisheyeCamera, dome_from_pixel, pixel_from_dome, radial_map
from optitact.optics.sensor import DomeSensor

CAMERAS = [
    FisheyeCamera(),
    FisheyeCamera(width=320, height=240, fov_deg=180.0, z=-2.0),
    FisheyeCamera(width=200, height=300, fov_deg=120.0, z=-12.0),
    FisheyeCamera(width=256, height=256, fov_deg=220.0, z=3.0),
]


@pytest.fixture(scope="module")
def sensor():
    return DomeSensor.default()


def _theta_max(sensor, camera):
    return camera.max_polar_angle(sensor)


def _random_dome_points(sensor, theta_max, n, seed):
    rng = np.random.default_rng(seed)
    # Uniform on the visible cap, plus the apex and the visible limit.
    theta = np.arccos(rng.uniform(math.cos(theta_max), 1.0, n))
    theta[:2] = (0.0, theta_max)
    phi = rng.uniform(-math.pi, math.pi, n)
    r = sensor.outer_radius
    return np.stack([r * np.sin(theta) * np.cos(phi), r * np.sin(theta) * np.sin(phi),
                     r * np.cos(theta)], axis=-1)


# --------------------------------------------------------------------------- #
# Round trips
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"z{c.z}")
def test_dome_pixel_dome_round_trip(sensor, camera):
    pts = _random_dome_points(sensor, _theta_max(sensor, camera), 5000, seed=1)
    px = pixel_from_dome(pts, sensor=sensor, camera=camera)
    assert px.shape == (5000, 2)
    back = dome_from_pixel(px, sensor=sensor, camera=camera)
    np.testing.assert_allclose(back, pts, rtol=0, atol=1e-6)


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"z{c.z}")
def test_pixel_dome_pixel_round_trip_over_mask(sensor, camera):
    mask = camera.dome_mask(sensor)
    assert mask.shape == (camera.height, camera.width) and mask.dtype == bool
    assert mask.any()
    rc = np.argwhere(mask).astype(np.float64)
    pts = dome_from_pixel(rc, sensor=sensor, camera=camera)
    assert np.all(np.isfinite(pts))
    np.testing.assert_allclose(np.linalg.norm(pts, axis=-1), sensor.outer_radius, rtol=0,
                               atol=1e-9)
    assert np.all(pts[:, 2] >= -1e-9)
    back = pixel_from_dome(pts, sensor=sensor, camera=camera)
    np.testing.assert_allclose(back, rc, rtol=0, atol=1e-6)


def test_methods_match_functions(sensor):
    cam = FisheyeCamera()
    pts = _random_dome_points(sensor, _theta_max(sensor, cam), 50, seed=2)
    np.testing.assert_array_equal(cam.project(pts, sensor),
                                  pixel_from_dome(pts, sensor=sensor, camera=cam))
    px = cam.project(pts, sensor)
    np.testing.assert_array_equal(cam.unproject(px, sensor),
                                  dome_from_pixel(px, sensor=sensor, camera=cam))


def test_element_positions_round_trip(sensor):
    cam = FisheyeCamera()
    px = cam.project(sensor.element_positions, sensor)
    assert px.shape == (41, 2)
    np.testing.assert_allclose(cam.unproject(px, sensor), sensor.element_positions, rtol=0,
                               atol=1e-9)


def test_broadcast_shapes(sensor):
    cam = FisheyeCamera()
    pts = _random_dome_points(sensor, 1.0, 24, seed=3).reshape(2, 3, 4, 3)
    px = cam.project(pts, sensor)
    assert px.shape == (2, 3, 4, 2)
    assert cam.unproject(px, sensor).shape == (2, 3, 4, 3)
    single = cam.project(pts[0, 0, 0], sensor)
    assert single.shape == (2,)
    np.testing.assert_array_equal(single, px[0, 0, 0])


# --------------------------------------------------------------------------- #
# Image geometry
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"z{c.z}")
def test_apex_projects_to_centre(sensor, camera):
    px = pixel_from_dome([0.0, 0.0, sensor.outer_radius], sensor=sensor, camera=camera)
    h, w = camera.height, camera.width
    assert camera.center == ((h - 1) / 2, (w - 1) / 2)
    np.testing.assert_allclose(px, [(h - 1) / 2, (w - 1) / 2], rtol=0, atol=1e-9)
    back = dome_from_pixel(camera.center, sensor=sensor, camera=camera)
    np.testing.assert_allclose(back, [0.0, 0.0, sensor.outer_radius], rtol=0, atol=1e-12)


def test_azimuth_preserved(sensor):
    cam = FisheyeCamera()
    cy, cx = cam.center
    r = sensor.outer_radius
    th = math.radians(40.0)
    on_x = cam.project([r * math.sin(th), 0.0, r * math.cos(th)], sensor)
    on_y = cam.project([0.0, r * math.sin(th), r * math.cos(th)], sensor)
    on_mx = cam.project([-r * math.sin(th), 0.0, r * math.cos(th)], sensor)
    assert on_x[0] == pytest.approx(cy, abs=1e-9) and on_x[1] > cx + 10
    assert on_y[1] == pytest.approx(cx, abs=1e-9) and on_y[0] > cy + 10
    assert on_mx[0] == pytest.approx(cy, abs=1e-9) and on_mx[1] < cx - 10
    # Same polar angle -> same image radius.
    radii = [math.hypot(p[0] - cy, p[1] - cx) for p in (on_x, on_y, on_mx)]
    np.testing.assert_allclose(radii, radii[0], rtol=0, atol=1e-9)


def test_azimuth_of_random_points(sensor):
    cam = FisheyeCamera()
    pts = _random_dome_points(sensor, _theta_max(sensor, cam), 300, seed=4)[2:]
    px = cam.project(pts, sensor)
    cy, cx = cam.center
    img_az = np.arctan2(px[:, 0] - cy, px[:, 1] - cx)
    dome_az = np.arctan2(pts[:, 1], pts[:, 0])
    diff = np.angle(np.exp(1j * (img_az - dome_az)))
    np.testing.assert_allclose(diff, 0.0, rtol=0, atol=1e-9)


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"z{c.z}")
def test_ray_from_pixel_is_equidistant(camera):
    rng = np.random.default_rng(5)
    px = rng.uniform(0, [camera.height - 1, camera.width - 1], (400, 2))
    d = camera.ray_from_pixel(px)
    assert d.shape == (400, 3)
    np.testing.assert_allclose(np.linalg.norm(d, axis=-1), 1.0, rtol=0, atol=1e-12)
    cy, cx = camera.center
    radius = np.hypot(px[:, 0] - cy, px[:, 1] - cx)
    angle = np.arctan2(np.hypot(d[:, 0], d[:, 1]), d[:, 2])
    np.testing.assert_allclose(angle, radius / camera.focal_px, rtol=0, atol=1e-12)
    # Columns grow with +x, rows with +y.
    np.testing.assert_allclose(np.arctan2(d[:, 1], d[:, 0]),
                               np.arctan2(px[:, 0] - cy, px[:, 1] - cx), rtol=0, atol=1e-12)


def test_focal_length():
    cam = FisheyeCamera(width=640, height=480, fov_deg=140.0)
    assert cam.focal_px == pytest.approx(240.0 / math.radians(70.0), rel=1e-15)
    # The image circle of the field of view touches the shorter sides.
    d = cam.ray_from_pixel([cam.center[0] + 240.0, cam.center[1]])
    assert math.degrees(math.acos(d[2])) == pytest.approx(70.0, abs=1e-12)
    tall = FisheyeCamera(width=300, height=500, fov_deg=90.0)
    assert tall.focal_px == pytest.approx(150.0 / math.radians(45.0), rel=1e-15)
    assert tall.shape == (500, 300)


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"z{c.z}")
def test_ray_pixel_round_trip(camera):
    rng = np.random.default_rng(6)
    px = rng.uniform(0, [camera.height - 1, camera.width - 1], (500, 2))
    np.testing.assert_allclose(camera.pixel_from_ray(camera.ray_from_pixel(px)), px, rtol=0,
                               atol=1e-9)
    # Non-unit directions give the same pixels.
    d = camera.ray_from_pixel(px) * rng.uniform(0.1, 10.0, (500, 1))
    np.testing.assert_allclose(camera.pixel_from_ray(d), px, rtol=0, atol=1e-9)


def test_pixel_from_ray_axis():
    cam = FisheyeCamera()
    np.testing.assert_allclose(cam.pixel_from_ray([0.0, 0.0, 2.0]), cam.center, rtol=0, atol=0)
    a = math.radians(30.0)
    px = cam.pixel_from_ray([math.sin(a), 0.0, math.cos(a)])
    np.testing.assert_allclose(px, [cam.center[0], cam.center[1] + cam.focal_px * a], rtol=0,
                               atol=1e-12)


# --------------------------------------------------------------------------- #
# Refraction: an independent direct 3-D trace
# --------------------------------------------------------------------------- #
def _sphere_exit(origin, direction, radius):
    """Far intersection of ``origin + t direction`` (unit) with a sphere about the origin."""
    b = origin @ direction
    c = origin @ origin - radius**2
    return origin + (-b + math.sqrt(b * b - c)) * direction


def _trace(sensor, camera, pixel):
    cy, cx = camera.center
    dr, dc = pixel[0] - cy, pixel[1] - cx
    alpha = math.hypot(dr, dc) / camera.focal_px
    phi = math.atan2(dr, dc)
    d = np.array([math.sin(alpha) * math.cos(phi), math.sin(alpha) * math.sin(phi),
                  math.cos(alpha)])
    cam = np.array([0.0, 0.0, camera.z])
    q = _sphere_exit(cam, d, sensor.inner_radius)
    normal = q / sensor.inner_radius
    # Split into normal and tangential parts; Snell acts on the tangential part.
    d_tan = d - (d @ normal) * normal
    sin_i = np.linalg.norm(d_tan)
    n2 = sensor.refractive_index
    sin_t = sin_i / n2
    t_dir = math.sqrt(1.0 - sin_t**2) * normal
    if sin_i > 0:
        t_dir = t_dir + sin_t * d_tan / sin_i
    # Checks of the refraction itself.
    assert np.linalg.norm(t_dir) == pytest.approx(1.0, abs=1e-14)
    assert np.linalg.norm(np.cross(d, normal)) == pytest.approx(
        n2 * np.linalg.norm(np.cross(t_dir, normal)), abs=1e-13)        # n1 sin i = n2 sin t
    assert np.cross(d, normal) @ t_dir == pytest.approx(0.0, abs=1e-13)  # coplanar
    assert t_dir @ normal > 0 and d @ normal > 0                         # both go outward
    return _sphere_exit(q, t_dir, sensor.outer_radius)


@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"z{c.z}")
def test_refraction_against_direct_trace(sensor, camera):
    mask = camera.dome_mask(sensor)
    rc = np.argwhere(mask)
    rng = np.random.default_rng(7)
    picks = rc[rng.choice(len(rc), 25, replace=False)].astype(np.float64)
    picks = np.vstack([picks, [camera.center], picks[:3] + 0.37])
    lib = dome_from_pixel(picks, sensor=sensor, camera=camera)
    direct = np.array([_trace(sensor, camera, p) for p in picks])
    np.testing.assert_allclose(lib, direct, rtol=0, atol=1e-9)


@pytest.mark.parametrize("z", [-5.0, 2.0])
def test_refractive_index_near_one_is_straight_line(z):
    s = DomeSensor(refractive_index=1.0 + 1e-12)
    cam = FisheyeCamera(z=z)
    rc = np.argwhere(cam.dome_mask(s))[::97].astype(np.float64)
    pts = dome_from_pixel(rc, sensor=s, camera=cam)
    origin = np.array([0.0, 0.0, z])
    d = cam.ray_from_pixel(rc)
    straight = np.array([_sphere_exit(origin, di, s.outer_radius) for di in d])
    np.testing.assert_allclose(pts, straight, rtol=0, atol=1e-8)


@pytest.mark.parametrize(("z", "sign"), [(-5.0, 1), (5.0, -1)])
def test_refraction_bends_towards_normal(sensor, z, sign):
    # Entering denser acrylic bends rays towards the inner-surface normal. A camera below the
    # dome's centre sees the inner surface tilted outwards of its rays, so off-axis points are
    # seen at a larger polar angle than along a straight line; above the centre, smaller.
    cam = FisheyeCamera(z=z)
    rc = np.array([[cam.center[0], cam.center[1] + k] for k in (40.0, 120.0, 200.0)])
    bent = dome_from_pixel(rc, sensor=sensor, camera=cam)
    origin = np.array([0.0, 0.0, cam.z])
    straight = np.array([_sphere_exit(origin, d, sensor.outer_radius)
                         for d in cam.ray_from_pixel(rc)])

    def polar(p):
        return np.arctan2(np.hypot(p[:, 0], p[:, 1]), p[:, 2])

    assert np.all(sign * (polar(bent) - polar(straight)) > 1e-3)


# --------------------------------------------------------------------------- #
# Radial map and mask
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("camera", CAMERAS, ids=lambda c: f"z{c.z}")
def test_radial_map_monotone(sensor, camera):
    rmap = radial_map(sensor, camera.z)
    alpha = np.linspace(0.0, rmap.alpha_max, 2001)
    theta, ok = rmap.theta(alpha)
    assert ok.all()
    assert np.all(np.diff(theta) > 0)
    assert theta[0] == pytest.approx(0.0, abs=1e-15)
    assert theta[-1] == pytest.approx(rmap.theta_max, abs=1e-12)
    assert rmap.theta_max <= math.pi / 2
    # Through the public functions: image radius grows with the dome polar angle.
    t = np.linspace(0.0, rmap.theta_max, 200)
    r = sensor.outer_radius
    pts = np.stack([r * np.sin(t), np.zeros_like(t), r * np.cos(t)], axis=-1)
    col = pixel_from_dome(pts, sensor=sensor, camera=camera)[:, 1]
    assert np.all(np.diff(col) > 0)


def test_default_visible_limit(sensor):
    # Documented: about 88.3 deg for the default sensor and camera.
    assert math.degrees(_theta_max(sensor, FisheyeCamera())) == pytest.approx(88.35, abs=0.05)


def test_dome_mask_matches_ray_angle(sensor):
    cam = FisheyeCamera()
    mask = cam.dome_mask(sensor)
    rows, cols = np.mgrid[0:cam.height, 0:cam.width]
    cy, cx = cam.center
    alpha = np.hypot(rows - cy, cols - cx) / cam.focal_px
    np.testing.assert_array_equal(mask, alpha <= radial_map(sensor, cam.z).alpha_max)
    assert mask[int(cy), int(cx)]
    assert not mask[0, 0] and not mask[-1, -1]


def test_outside_pixels(sensor):
    cam = FisheyeCamera()
    mask = cam.dome_mask(sensor)
    assert (~mask).any()
    rows, cols = np.mgrid[0:cam.height, 0:cam.width]
    grid = np.stack([rows, cols], axis=-1)
    with pytest.raises(InputError, match=r"pixels must see the dome \(ray angle <= 73.6"):
        dome_from_pixel(grid, sensor=sensor, camera=cam)
    with pytest.raises(InputError, match=r"pixels must see the dome"):
        cam.unproject([0.0, 0.0], sensor)
    pts = dome_from_pixel(grid, sensor=sensor, camera=cam, outside="nan")
    assert pts.shape == (cam.height, cam.width, 3)
    nan_rows = np.isnan(pts)
    np.testing.assert_array_equal(nan_rows.any(axis=-1), ~mask)
    np.testing.assert_array_equal(nan_rows.all(axis=-1), ~mask)
    np.testing.assert_array_equal(pts[mask], dome_from_pixel(grid[mask], sensor=sensor,
                                                             camera=cam))


def test_outside_nan_single_pixel(sensor):
    cam = FisheyeCamera()
    assert np.isnan(cam.unproject([0.0, 0.0], sensor, outside="nan")).all()
    assert np.isfinite(cam.unproject(cam.center, sensor, outside="nan")).all()


def test_inputs_not_mutated(sensor):
    cam = FisheyeCamera()
    pts = _random_dome_points(sensor, 1.2, 20, seed=9)
    px = np.vstack([cam.project(pts, sensor), [[0.0, 0.0]]])
    p0, x0 = pts.copy(), px.copy()
    cam.project(pts, sensor)
    cam.unproject(px, sensor, outside="nan")
    cam.ray_from_pixel(px)
    np.testing.assert_array_equal(pts, p0)
    np.testing.assert_array_equal(px, x0)


@pytest.mark.parametrize("dtype", [np.float32, np.int32, np.int64])
def test_pixel_dtypes(sensor, dtype):
    cam = FisheyeCamera()
    px = np.array([[240, 320], [200, 300]], dtype=dtype)
    out = cam.unproject(px, sensor)
    assert out.dtype == np.float64
    np.testing.assert_allclose(out, cam.unproject(px.astype(np.float64), sensor), rtol=0,
                               atol=0)


# --------------------------------------------------------------------------- #
# Camera parameters
# --------------------------------------------------------------------------- #
def test_camera_defaults_and_dict_round_trip():
    cam = FisheyeCamera()
    assert (cam.width, cam.height, cam.fov_deg, cam.z) == (640, 480, 140.0, -5.0)
    other = FisheyeCamera(width=100, height=80, fov_deg=150.0, z=-3.0)
    assert FisheyeCamera.from_dict(json.loads(json.dumps(other.to_dict()))) == other
    with pytest.raises(dataclasses.FrozenInstanceError):
        cam.z = 0.0  # type: ignore[misc]


def test_camera_from_dict_unknown_key():
    with pytest.raises(InputError, match=r"camera parameters: unknown parameter\(s\) \['focal'\]"):
        FisheyeCamera.from_dict({"focal": 3.0})


@pytest.mark.parametrize(
    ("kwargs", "exc", "match"),
    [
        ({"width": 640.0}, TypeError, r"width must be an integer, got float"),
        ({"width": "640"}, TypeError, r"width must be an integer, got str"),
        ({"height": True}, TypeError, r"height must be an integer, got bool"),
        ({"fov_deg": "140"}, TypeError, r"fov_deg must be a real number, got str"),
        ({"fov_deg": None}, TypeError, r"fov_deg must be a real number, got NoneType"),
        ({"width": 1}, InputError, r"width must be >= 2, got 1"),
        ({"height": 0}, InputError, r"height must be >= 2, got 0"),
        ({"fov_deg": 0.0}, InputError, r"fov_deg must be finite and > 0"),
        ({"fov_deg": -10.0}, InputError, r"fov_deg must be finite and > 0"),
        ({"fov_deg": 360.0}, InputError, r"fov_deg must be in \(0, 360\), got 360.0"),
        ({"fov_deg": float("nan")}, InputError, r"fov_deg must be finite and > 0"),
        ({"z": float("nan")}, InputError, r"z must be finite \(mm\), got nan"),
        ({"z": float("inf")}, InputError, r"z must be finite \(mm\)"),
    ],
)
def test_camera_parameter_errors(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        FisheyeCamera(**kwargs)


@pytest.mark.parametrize("z", ["-5", None])
def test_camera_z_wrong_kind_is_type_error(z):
    with pytest.raises(TypeError, match=r"z must be"):
        FisheyeCamera(z=z)


@pytest.mark.parametrize("z", [np.float32(-5.0), np.int64(-5)])
def test_camera_z_numpy_scalar_accepted(z):
    assert FisheyeCamera(z=z).z == -5.0


@pytest.mark.parametrize("z", [17.0, -17.0, 25.0, -30.0])
def test_camera_outside_inner_sphere(sensor, z):
    cam = FisheyeCamera(z=z)
    match = r"camera z must lie inside the dome's inner sphere \(\|z\| < 17.0 mm\)"
    with pytest.raises(InputError, match=match):
        cam.dome_mask(sensor)
    with pytest.raises(InputError, match=match):
        cam.project([0.0, 0.0, sensor.outer_radius], sensor)
    with pytest.raises(InputError, match=match):
        cam.unproject(cam.center, sensor)


# --------------------------------------------------------------------------- #
# Errors of the transforms
# --------------------------------------------------------------------------- #
def test_points_off_surface(sensor):
    cam = FisheyeCamera()
    with pytest.raises(InputError, match=r"points must lie on the outer dome surface "
                                         r"\(radius 20.0 mm \+- 0.0001\), got a point at "
                                         r"radius 21"):
        cam.project([[0.0, 0.0, 20.0], [0.0, 0.0, 21.0]], sensor)
    with pytest.raises(InputError, match=r"outer dome surface"):
        cam.project([0.0, 0.0, 17.0], sensor)
    # Within the tolerance is accepted.
    px = cam.project([0.0, 0.0, 20.0 + 5e-5], sensor)
    np.testing.assert_allclose(px, cam.center, rtol=0, atol=1e-9)


def test_points_below_base(sensor):
    cam = FisheyeCamera()
    with pytest.raises(InputError, match=r"points must have z >= 0"):
        cam.project([0.0, 0.0, -20.0], sensor)


@pytest.mark.parametrize("polar_deg", [88.5, 89.9, 90.0])
def test_points_beyond_visible_limit(sensor, polar_deg):
    cam = FisheyeCamera()
    th = math.radians(polar_deg)
    p = 20.0 * np.array([math.sin(th), 0.0, math.cos(th)])
    with pytest.raises(InputError, match=r"points must be visible through the inner surface "
                                         r"\(polar angle <= 88.3\d\d deg"):
        cam.project(p, sensor)


@pytest.mark.parametrize(
    ("func", "arg", "match"),
    [
        ("project", np.zeros((4, 2)), r"points must have shape \(\.\.\., 3\), got \(4, 2\)"),
        ("project", np.zeros((3, 4)), r"points must have shape \(\.\.\., 3\)"),
        ("project", np.float64(20.0), r"points must have shape \(\.\.\., 3\), got \(\)"),
        ("unproject", np.zeros((4, 3)), r"pixels must have shape \(\.\.\., 2\) \(row, col\)"),
        ("unproject", np.zeros(5), r"pixels must have shape"),
        ("ray_from_pixel", np.zeros((2, 1)), r"pixels must have shape"),
        ("pixel_from_ray", np.zeros((2, 2)), r"directions must have shape \(\.\.\., 3\)"),
    ],
)
def test_wrong_last_dimension(sensor, func, arg, match):
    cam = FisheyeCamera()
    method = getattr(cam, func)
    call = (lambda: method(arg, sensor)) if func in ("project", "unproject") else \
        (lambda: method(arg))
    with pytest.raises(ShapeError, match=match) as info:
        call()
    assert isinstance(info.value, ValueError)


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_non_finite_inputs(sensor, bad):
    cam = FisheyeCamera()
    with pytest.raises(InputError, match=r"pixels must be finite, got (nan|inf) at index \(1, 0\)"):
        cam.unproject([[240.0, 320.0], [bad, 1.0]], sensor)
    with pytest.raises(InputError, match=r"pixels must be finite"):
        cam.unproject([[240.0, 320.0], [bad, 1.0]], sensor, outside="nan")
    with pytest.raises(InputError, match=r"pixels must be finite"):
        cam.ray_from_pixel([bad, 1.0])
    with pytest.raises(InputError, match=r"points must be finite"):
        cam.project([0.0, bad, 20.0], sensor)
    with pytest.raises(InputError, match=r"directions must be finite"):
        cam.pixel_from_ray([0.0, bad, 1.0])


@pytest.mark.parametrize("dtype", [bool, complex, object])
def test_wrong_dtype(sensor, dtype):
    cam = FisheyeCamera()
    with pytest.raises(TypeError, match=r"pixels must be a real numeric array"):
        cam.unproject(np.ones((3, 2), dtype=dtype), sensor)
    with pytest.raises(TypeError, match=r"points must be a real numeric array"):
        cam.project(np.ones((3, 3), dtype=dtype), sensor)


@pytest.mark.parametrize("outside", ["clip", "NaN", None, ""])
def test_bad_outside(sensor, outside):
    cam = FisheyeCamera()
    with pytest.raises(InputError, match=r"outside must be 'raise' or 'nan'"):
        cam.unproject(cam.center, sensor, outside=outside)


def test_keyword_only_arguments(sensor):
    cam = FisheyeCamera()
    with pytest.raises(TypeError):
        pixel_from_dome([0.0, 0.0, 20.0], sensor, cam)  # type: ignore[misc]
    with pytest.raises(TypeError):
        dome_from_pixel(cam.center, sensor, cam)  # type: ignore[misc]


def test_max_polar_angle_is_the_radial_maps_bound(sensor):
    cam = FisheyeCamera()
    assert cam.max_polar_angle(sensor) == radial_map(sensor, cam.z).theta_max
    assert cam.max_polar_angle(sensor) <= math.pi / 2
