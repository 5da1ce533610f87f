"""OpenCV's camera models in the dome: against cv2's own projection, exact inverses, files, the pipeline."""

from __future__ import annotations

import math

import cv2
import numpy as np
import pytest

import optitact
from optitact.errors import InputError
from optitact.optics.camera import Camera, FisheyeCamera, camera_from_dict, rotation_from_rvec
from optitact.optics.camera_models import OpenCVFisheyeCamera, PinholeCamera, pose_from_position
from optitact.optics.opencv_files import camera_from_opencv, read_opencv_calibration

SENSOR = optitact.optics.sensor.DomeSensor.default()
R_OUT = SENSOR.outer_radius


def random_pinhole(rng, n_dist=5, *, width=640, height=480, pose=True):
    dist = np.zeros(n_dist)
    dist[:2] = rng.uniform([-0.15, -0.03], [0.05, 0.05])
    dist[2:4] = rng.uniform(-2e-3, 2e-3, 2)
    if n_dist >= 5:
        dist[4] = rng.uniform(-0.01, 0.01)
    if n_dist >= 8:
        dist[5:8] = rng.uniform(-0.02, 0.02, 3)
    if n_dist >= 12:
        dist[8:12] = rng.uniform(-1e-3, 1e-3, 4)
    return random_camera(PinholeCamera, rng, dist, (260, 340), width, height, pose)


def random_fisheye(rng, *, width=640, height=480, pose=True):
    dist = rng.uniform([-0.05, -0.02, -0.005, -0.001], [0.05, 0.02, 0.005, 0.001])
    return random_camera(OpenCVFisheyeCamera, rng, dist, (190, 230), width, height, pose)


def random_camera(cls, rng, dist, f_range, width, height, pose):
    """Random focal (within 3 % between axes), principal point (+-8 px) and pose (0.5 mm, ~2 deg)."""
    rvec, tvec = (0.0, 0.0, 0.0), (0.0, 0.0, 5.0)
    if pose:
        p = pose_from_position(rng.uniform([-0.5, -0.5, -5.5], [0.5, 0.5, -4.5]), rng.normal(0, 0.03, 3))
        rvec, tvec = p["rvec"], p["tvec"]
    f = rng.uniform(*f_range)
    return cls(width, height, fx=f, fy=f * rng.uniform(0.97, 1.03), cx=(width - 1) / 2 + rng.uniform(-8, 8),
               cy=(height - 1) / 2 + rng.uniform(-8, 8), dist=dist, rvec=rvec, tvec=tvec)


def cv2_pixels(cam, points):
    """OpenCV's own projection of dome-frame points, as (row, col)."""
    pts = np.ascontiguousarray(points, np.float64).reshape(-1, 1, 3)
    rvec, tvec = np.array(cam.rvec), np.array(cam.tvec)
    if isinstance(cam, OpenCVFisheyeCamera):
        uv, _ = cv2.fisheye.projectPoints(pts, rvec, tvec, cam.K, cam.D)
    else:
        uv, _ = cv2.projectPoints(pts, rvec, tvec, cam.K, cam.D)
    return uv.reshape(-1, 2)[:, ::-1]


def dome_points(rng, n, max_polar_deg):
    theta = np.radians(rng.uniform(0, max_polar_deg, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    return R_OUT * np.stack([np.sin(theta) * np.cos(phi), np.sin(theta) * np.sin(phi), np.cos(theta)], -1)


CAMERAS = [random_pinhole(np.random.default_rng(i), n) for i, n in enumerate((4, 5, 8, 12, 5, 5))] + [
    random_fisheye(np.random.default_rng(10 + i)) for i in range(6)
]
IDS = [f"{c.model}-{len(c.dist)}-{i}" for i, c in enumerate(CAMERAS)]


# ---------------------------------------------------------------------------- independent truth: cv2
@pytest.mark.parametrize("cam", CAMERAS, ids=IDS)
def test_points_project_as_opencv(cam):
    """Straight projection (no dome) of random points in front: cv2's pixels to 1e-6 px."""
    rng = np.random.default_rng(1)
    cam_pts = np.concatenate(
        [rng.uniform(-1, 1, (300, 2)) * rng.uniform(0, 1.2, (300, 1)), np.ones((300, 1))], 1
    )
    cam_pts *= rng.uniform(1, 20, (300, 1))
    dome = (cam_pts - np.array(cam.tvec)) @ cam.rotation  # X_dome = R^T (X_cam - t)
    mine = cam.pixel_from_point(dome)
    ok = np.isfinite(mine).all(-1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(mine[ok], cv2_pixels(cam, dome)[ok], rtol=0, atol=1e-6)


@pytest.mark.parametrize("cam", CAMERAS, ids=IDS)
def test_dome_without_refraction_is_opencv(cam):
    """project(..., refraction=False) of dome points = cv2.projectPoints of those points (1e-6 px)."""
    pts = dome_points(np.random.default_rng(2), 400, 60.0)
    px = cam.project(pts, SENSOR, refraction=False, outside="nan")
    ok = np.isfinite(px).all(-1)
    assert ok.mean() > 0.9
    np.testing.assert_allclose(px[ok], cv2_pixels(cam, pts[ok]), rtol=0, atol=1e-6)
    back = cam.unproject(px[ok], SENSOR, refraction=False)
    np.testing.assert_allclose(back, pts[ok], rtol=0, atol=1e-9)


def test_default_fisheye_is_the_zero_distortion_opencv_fisheye():
    """OpenCV's fisheye with D = 0 on the axis is today's equidistant camera: same pixels through the dome."""
    fe = FisheyeCamera()
    cy, cx = fe.center
    kb = OpenCVFisheyeCamera(fe.width, fe.height, fx=fe.focal_px, fy=fe.focal_px, cx=cx, cy=cy)
    pts = dome_points(np.random.default_rng(3), 500, 88.0)
    np.testing.assert_allclose(kb.project(pts, SENSOR), fe.project(pts, SENSOR), rtol=0, atol=1e-9)
    assert abs(kb.max_polar_angle(SENSOR) - fe.max_polar_angle(SENSOR)) < 1e-9
    np.testing.assert_array_equal(kb.dome_mask(SENSOR), fe.dome_mask(SENSOR))


# ---------------------------------------------------------------------------- exact inverses
@pytest.mark.parametrize("cam", CAMERAS, ids=IDS)
def test_undistortion_inverts_the_forward_model(cam):
    """Pixels over the whole image: those the lens images (nearly all) go to a ray and back to 1e-9 px."""
    rng = np.random.default_rng(4)
    px = np.stack([rng.uniform(0, cam.height - 1, 2000), rng.uniform(0, cam.width - 1, 2000)], -1)
    rays = cam.ray_from_pixel(px)
    ok = np.isfinite(rays).all(-1)
    assert ok.mean() > 0.75
    np.testing.assert_allclose(cam.pixel_from_ray(rays[ok]), px[ok], rtol=0, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(rays[ok], axis=-1), 1.0, rtol=0, atol=1e-12)


def test_strong_distortion_inverts_beyond_opencvs_undistort():
    """A strong barrel lens: Newton inverts it to 1e-9 px where cv2.undistortPoints' fixed iterations do not."""
    cam = PinholeCamera(
        640, 480, fx=250.0, fy=250.0, cx=320.0, cy=240.0, dist=(-0.35, 0.12, 0.002, -0.001, -0.02)
    )
    r = 0.98 * cam.max_radius
    px = cam.pixel_from_ray(np.array([[r, 0, 1], [0, r, 1], [-0.7 * r, 0.7 * r, 1], [0.5 * r, -0.8 * r, 1]]))
    rays = cam.ray_from_pixel(px)
    np.testing.assert_allclose(cam.pixel_from_ray(rays), px, rtol=0, atol=1e-9)
    xy = cv2.undistortPoints(px[:, ::-1].reshape(-1, 1, 2), cam.K, cam.D).reshape(-1, 2)
    redo = cam.pixel_from_ray(np.concatenate([xy, np.ones((4, 1))], 1) @ cam.rotation)
    assert np.abs(redo - px).max() > 1e-6  # OpenCV's approximation is visibly off here


def test_pixels_beyond_the_lens_range_have_no_ray():
    cam = PinholeCamera(640, 480, fx=100.0, fy=100.0, cx=320.0, cy=240.0, dist=(-0.4, 0.0, 0.0, 0.0, 0.0))
    # g(r) = r (1 - 0.4 r^2) peaks at r = 0.913, g = 0.609: 60.9 px from the centre at f = 100
    assert cam.max_radius == pytest.approx(math.sqrt(1 / 1.2), abs=1e-12)
    rays = cam.ray_from_pixel([[240.0, 320.0 + 60.0], [240.0, 320.0 + 62.0]])
    assert np.isfinite(rays[0]).all() and np.isnan(rays[1]).all()
    assert np.isnan(cam.pixel_from_ray([[0.0, 0.0, -1.0]])).all()  # behind a pinhole


@pytest.mark.parametrize("cam", CAMERAS, ids=IDS)
def test_dome_round_trips_off_axis_and_tilted(cam):
    rng = np.random.default_rng(5)
    pts = dome_points(rng, 1000, 89.0)
    px = cam.project(pts, SENSOR, outside="nan")
    seen = np.isfinite(px).all(-1)
    np.testing.assert_array_equal(seen, cam.visible(pts, SENSOR))
    assert seen.mean() > 0.5
    np.testing.assert_allclose(cam.unproject(px[seen], SENSOR), pts[seen], rtol=0, atol=1e-9)
    pix = np.stack([rng.uniform(0, cam.height - 1, 3000), rng.uniform(0, cam.width - 1, 3000)], -1)
    dome = cam.unproject(pix, SENSOR, outside="nan")
    hit = np.isfinite(dome).all(-1)
    assert hit.mean() > 0.5
    np.testing.assert_allclose(cam.project(dome[hit], SENSOR), pix[hit], rtol=0, atol=1e-9)


def test_refraction_obeys_snell_off_axis():
    """The ray found for a dome point, traced forwards by hand, obeys Snell's law and reaches the point."""
    cam = CAMERAS[1]
    pts = dome_points(np.random.default_rng(6), 50, 70.0)
    px = cam.project(pts, SENSOR)
    d = cam.ray_from_pixel(px)
    c = cam.position
    r_in, n = SENSOR.inner_radius, SENSOR.refractive_index
    b = d @ c
    q = c + (-b + np.sqrt(b * b - c @ c + r_in**2))[:, None] * d
    t = pts - q
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    nh = q / r_in
    sin_i = np.linalg.norm(np.cross(nh, d), axis=-1)
    sin_t = np.linalg.norm(np.cross(nh, t), axis=-1)
    np.testing.assert_allclose(sin_i, n * sin_t, rtol=0, atol=1e-12)
    np.testing.assert_allclose(np.einsum("ij,ij->i", np.cross(d, t), nh), 0.0, atol=1e-12)  # coplanar


def test_max_polar_angle_is_seen_all_round():
    cam = CAMERAS[7]
    theta = cam.max_polar_angle(SENSOR)
    phi = np.linspace(0, 2 * np.pi, 1000)
    for th, expect in ((theta - 1e-6, True), (theta + 0.02, False)):
        pts = R_OUT * np.stack(
            [np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.full_like(phi, np.cos(th))], -1
        )
        assert cam.visible(pts, SENSOR).all() == expect


# ---------------------------------------------------------------------------- parameters and files
def test_pose_conventions():
    cam = PinholeCamera(64, 48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, **pose_from_position((0.3, -0.2, -4.0)))
    np.testing.assert_allclose(cam.position, [0.3, -0.2, -4.0], atol=1e-15)
    # default: looking up the axis, columns with +x and rows with +y, as FisheyeCamera
    up = PinholeCamera(64, 48, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
    r, c = up.pixel_from_point([[1.0, 0.0, 10.0], [0.0, 1.0, 10.0]]).T
    assert c[0] > 31.5 and r[0] == 23.5 and r[1] > 23.5 and c[1] == 31.5
    m = rotation_from_rvec((0.1, -0.2, 0.3))
    np.testing.assert_allclose(m, cv2.Rodrigues(np.array([0.1, -0.2, 0.3]))[0], rtol=0, atol=1e-15)
    assert PinholeCamera(64, 48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, rvec=m) == PinholeCamera(
        64, 48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, rvec=(0.1, -0.2, 0.3)
    ) or np.allclose(
        PinholeCamera(64, 48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, rvec=m).rvec, (0.1, -0.2, 0.3), atol=1e-14
    )


@pytest.mark.parametrize("cam", [CAMERAS[0], CAMERAS[6], FisheyeCamera(width=80, height=60)], ids=str)
def test_dict_round_trip(cam):
    d = cam.to_dict()
    assert camera_from_dict(d) == cam and type(cam).from_dict(d) == cam
    assert ("model" in d) != isinstance(cam, FisheyeCamera)  # the default's dict (and fingerprints) unchanged
    assert hash(camera_from_dict(d)) == hash(cam)


def test_dict_errors():
    assert camera_from_dict({"width": 80, "height": 60}) == FisheyeCamera(width=80, height=60)
    assert FisheyeCamera.from_dict({"model": "equidistant", "z": -4.0}) == FisheyeCamera(z=-4.0)
    with pytest.raises(
        InputError, match=r"unknown model 'orthographic'; valid: \['equidistant', 'opencv_fisheye'"
    ):
        camera_from_dict({"model": "orthographic"})
    with pytest.raises(InputError, match="model 'pinhole' is not a FisheyeCamera"):
        FisheyeCamera.from_dict(CAMERAS[0].to_dict())
    with pytest.raises(InputError, match=r"unknown parameter\(s\) \['k1'\]"):
        camera_from_dict({**CAMERAS[0].to_dict(), "k1": 0.1})
    with pytest.raises(TypeError, match="camera parameters must be a dict"):
        camera_from_dict([1, 2])


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        (dict(fx=0.0), "fx must be > 0"),
        (dict(cy=float("nan")), "cy must be finite"),
        (dict(dist=(0.1, 0.2, 0.3)), "dist .* must have 5 or 4 or 8 or 12 entries, got 3"),
        (dict(dist=np.zeros(14)), "14 coefficients are OpenCV's tilted-sensor model"),
        (dict(dist=(0.1, np.inf, 0, 0)), "dist .* must be finite"),
        (dict(rvec=np.diag([1.0, 1.0, -1.0])), "must be a rotation"),
        (dict(tvec=(0, 0)), "tvec .* must have 3 entries"),
    ],
)
def test_parameter_errors(kwargs, match):
    base = dict(width=64, height=48, fx=50.0, fy=50.0, cx=31.5, cy=23.5)
    with pytest.raises(InputError, match=match):
        PinholeCamera(**{**base, **kwargs})


def test_camera_outside_the_dome_is_refused():
    cam = PinholeCamera(64, 48, fx=50.0, fy=50.0, cx=31.5, cy=23.5, **pose_from_position((0.0, 0.0, -30.0)))
    with pytest.raises(InputError, match="must lie inside the dome's inner sphere"):
        cam.project([[0.0, 0.0, R_OUT]], SENSOR)


def write_calibration(path, k, d, *, width=640, height=480, extra=None):
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("calibration_time", "today")
    fs.write("image_width", width)
    fs.write("image_height", height)
    for key, value in (extra or {}).items():
        fs.write(key, value)
    fs.write("camera_matrix", np.asarray(k, float))
    fs.write("distortion_coefficients", np.asarray(d, float).reshape(-1, 1))
    fs.write("avg_reprojection_error", 0.2)
    fs.release()


@pytest.mark.parametrize("suffix", [".yml", ".xml"])
def test_read_opencv_calibration_sample_output(tmp_path, suffix):
    cam = CAMERAS[2]
    write_calibration(tmp_path / f"cam{suffix}", cam.K, cam.D)
    got = read_opencv_calibration(tmp_path / f"cam{suffix}", rvec=cam.rvec, tvec=cam.tvec)
    assert got == cam
    fe = CAMERAS[7]
    write_calibration(tmp_path / f"fe{suffix}", fe.K, fe.D, extra={"fisheye_model": 1})
    assert read_opencv_calibration(tmp_path / f"fe{suffix}", rvec=fe.rvec, tvec=fe.tvec) == fe
    # 4 coefficients without a model key: what cv2.fisheye.calibrate writes (cv2.calibrateCamera: 5, 8, 12)
    write_calibration(tmp_path / f"four{suffix}", fe.K, fe.D)
    assert read_opencv_calibration(tmp_path / f"four{suffix}", rvec=fe.rvec, tvec=fe.tvec) == fe
    assert isinstance(read_opencv_calibration(tmp_path / f"four{suffix}", model="pinhole"), PinholeCamera)


def test_read_plain_yaml_and_arrays(tmp_path):
    (tmp_path / "ros.yaml").write_text(
        "image_width: 320\nimage_height: 240\ndistortion_model: equidistant\n"
        "camera_matrix:\n  rows: 3\n  cols: 3\n  data: [150.0, 0.0, 160.0, 0.0, 151.0, 120.0, 0.0, 0.0, 1.0]\n"
        "distortion_coefficients:\n  rows: 1\n  cols: 4\n  data: [0.01, -0.002, 0.0, 0.0]\n"
    )
    cam = read_opencv_calibration(tmp_path / "ros.yaml")
    assert cam == OpenCVFisheyeCamera(
        320, 240, fx=150.0, fy=151.0, cx=160.0, cy=120.0, dist=(0.01, -0.002, 0, 0)
    )
    assert camera_from_opencv(cam.K, cam.D, 320, 240, model="fisheye") == cam


@pytest.mark.parametrize(
    ("k", "d", "extra", "match"),
    [
        (None, [0.1] * 5, {}, r"expected a camera matrix \(one of \['camera_matrix'"),
        (
            [[100, 0, 30], [0, 100, 20], [0, 0, 1]],
            [0.0] * 14,
            {},
            "14 distortion coefficients are OpenCV's tilted",
        ),
        (
            [[100, 0, 30], [0, 100, 20], [0, 0, 1]],
            [0.1, np.nan, 0, 0, 0],
            {},
            "distortion coefficients must be finite",
        ),
        ([[100, 0, 30], [0, 100, 20], [0, 0, 2]], [0.0] * 5, {}, "K is not a camera matrix"),
        ([[100, 3, 30], [0, 100, 20], [0, 0, 1]], [0.0] * 5, {}, "skew"),
        ([[100, 0, 30], [0, 100, 20], [0, 0, 1]], [0.0] * 5, {"fisheye_model": 1}, "fisheye model must have 4"),
        (
            [[100, 0, 30], [0, 100, 20], [0, 0, 1]],
            [0.0] * 5,
            {"distortion_model": "omnidir"},
            "'omnidir' is not one",
        ),
    ],
)
def test_read_opencv_calibration_errors(tmp_path, k, d, extra, match):
    path = tmp_path / "bad.yml"
    if k is None:
        fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
        fs.write("intrinsic", np.eye(3))
        fs.write("distortion_coefficients", np.zeros((5, 1)))
        fs.release()
    else:
        write_calibration(path, k, d, extra=extra)
    with pytest.raises(InputError, match=match):
        read_opencv_calibration(path)


def test_read_opencv_calibration_file_errors(tmp_path):
    with pytest.raises(InputError, match="no such calibration file"):
        read_opencv_calibration(tmp_path / "none.yml")
    path = tmp_path / "nosize.yml"
    fs = cv2.FileStorage(str(path), cv2.FILE_STORAGE_WRITE)
    fs.write("K", np.array([[100.0, 0, 30], [0, 100, 20], [0, 0, 1]]))
    fs.write("D", np.zeros((1, 5)))
    fs.release()
    with pytest.raises(InputError, match="no image width in the file"):
        read_opencv_calibration(path)
    assert read_opencv_calibration(path, width=64, height=48).shape == (48, 64)


# ---------------------------------------------------------------------------- downstream
def spot_frame(cam, spots):
    """Gaussian spots on the dome (element-local tangent coordinates), drawn through the camera's own model."""
    rr, cc = np.mgrid[0 : cam.height, 0 : cam.width]
    pts = cam.unproject(np.stack([rr, cc], -1).astype(float), SENSOR, outside="nan")
    img = np.zeros(cam.shape)
    for e, c, s, a in spots:
        xy = SENSOR.tangent_offset(np.full(cam.shape, e), pts)
        d2 = np.sum((xy - np.asarray(c, float)) ** 2, axis=-1)
        near = np.isfinite(d2) & (d2 <= (5.0 * s) ** 2)
        img[near] += a * np.exp(-d2[near] / (2 * s * s))
    return img


PIPE_CAMERAS = {
    "pinhole": PinholeCamera(
        200,
        150,
        fx=70.0,
        fy=71.0,
        cx=101.0,
        cy=73.0,
        dist=(-0.03, 0.004, 1e-3, -1e-3, 0.0),
        **pose_from_position((0.3, -0.2, -5.0), (0.015, -0.02, 0.1)),
    ),
    "tilted-fisheye": OpenCVFisheyeCamera(
        200,
        150,
        fx=62.0,
        fy=63.0,
        cx=98.0,
        cy=76.0,
        dist=(0.03, -0.01, 0.002, -0.0005),
        **pose_from_position((-0.4, 0.25, -5.2), (0.03, 0.01, -0.2)),
    ),
}


@pytest.mark.parametrize("name", list(PIPE_CAMERAS))
def test_pipeline_recovers_spots_with_any_camera(name):
    cam = PIPE_CAMERAS[name]
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, cam)
    spots = [(0, (0.2, -0.1), 0.35, 100.0), (4, (-0.25, 0.2), 0.35, 100.0), (15, (0.15, 0.2), 0.35, 100.0)]
    r = pipe.process(spot_frame(cam, spots))
    default = optitact.optics.camera.FisheyeCamera(width=200, height=150)
    ref = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, default).process(spot_frame(default, spots))
    assert sorted(np.flatnonzero(r.contact)) == [0, 4, 15]
    for e, c, s, a in spots:
        np.testing.assert_allclose(r.u[e], c, rtol=0, atol=0.01)
        # G: the pipeline's own deficit on such spots (~1.4 %) is the default camera's too (within 1 %)
        np.testing.assert_allclose(r.G[e], a * 2 * math.pi * s * s, rtol=0.025)
        np.testing.assert_allclose(r.G[e], ref.G[e], rtol=0.01)
        # the centroid's dome point, seen through the camera, lands on the true spot's pixel
        found = cam.project(SENSOR.dome_point(e, r.u[e]), SENSOR)
        truth = cam.project(SENSOR.dome_point(e, c), SENSOR)
        assert np.linalg.norm(found - truth) < 0.1
        np.testing.assert_allclose(cam.unproject(truth, SENSOR), SENSOR.dome_point(e, c), rtol=0, atol=1e-9)


def test_top_level_exports():
    assert issubclass(PinholeCamera, Camera) and issubclass(FisheyeCamera, Camera)
    assert optitact.optics.opencv_files.read_opencv_calibration is read_opencv_calibration


def test_a_calibration_for_another_camera_model_saves_and_loads(tmp_path):
    """A calibration keeps its camera's model through save/load; its fingerprint covers the camera."""
    import dataclasses

    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import default_calibration

    shipped = default_calibration()
    cam = PinholeCamera(width=640, height=480, fx=300.0, fy=302.0, cx=321.5, cy=238.0,
                        dist=(-0.05, 0.01, 1e-4, -2e-4), tvec=(0.1, -0.2, 5.0))
    cal = dataclasses.replace(shipped, camera=cam)
    path = tmp_path / "pinhole.json"
    cal.save(path)
    back = Calibration.load(path)
    assert isinstance(back.camera, PinholeCamera) and back.camera == cam
    assert back.fingerprint != shipped.fingerprint
    np.testing.assert_array_equal(back.g, shipped.g)
