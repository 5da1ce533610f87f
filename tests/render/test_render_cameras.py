"""Rendering with any camera model: the ray-table sensor plugin (tiny renders and crop windows only).

The independent truths: the closed-form projection through the dome
(:func:`optitact.optics.camera.pixel_from_dome`, itself checked against OpenCV's
``projectPoints``), the exact rays of :meth:`Camera.ray_from_pixel`, and the
closed-form equidistant plugin for a model that equals it.
"""

from __future__ import annotations

import numpy as np
import pytest
from optitact.render import render
from optitact.render.pathtrace import spot_pixels
from optitact.render.rays import corner_rays, interpolate_rays
from test_render import PIX_LOAD, dome_point, patch_spot, single_patch

import optitact
from optitact.optics.camera_models import OpenCVFisheyeCamera, PinholeCamera, pose_from_position

pytestmark = pytest.mark.render

SENSOR = optitact.optics.sensor.DomeSensor.default()
#: A board camera: pinhole with radial-tangential distortion, 0.22 mm off axis and 1 deg tilted.
PINHOLE = PinholeCamera(640, 480, fx=300.0, fy=302.0, cx=322.0, cy=236.0,
                        dist=(-0.12, 0.02, 0.001, -0.0008, 0.0),
                        **pose_from_position((0.2, -0.1, -5.0), (0.01, -0.015, 0.0)))
#: A fibrescope: Kannala-Brandt fisheye, 0.36 mm off axis and 1.9 deg tilted.
TILTED = OpenCVFisheyeCamera(640, 480, fx=185.0, fy=186.0, cx=323.0, cy=237.0,
                             dist=(0.03, -0.01, 0.002, -0.0005),
                             **pose_from_position((0.3, -0.2, -5.0), (0.02, -0.025, 0.01)))


def quarter(cam):
    """The same camera at a quarter of the resolution (160 x 120)."""
    kw = cam.to_dict()
    del kw["model"]
    kw.update(width=160, height=120, fx=cam.fx / 4, fy=cam.fy / 4, cx=(cam.cx + 0.5) / 4 - 0.5,
              cy=(cam.cy + 0.5) / 4 - 0.5)
    return type(cam)(**kw)


@pytest.mark.parametrize("cam", [optitact.optics.camera.FisheyeCamera(width=160, height=120), quarter(PINHOLE),
                                 quarter(TILTED)], ids=["default", "pinhole", "tilted"])
def test_corner_ray_interpolation_is_far_below_the_agreement_tolerance(cam):
    """Bilinear rays between the float32 corner rays re-project within 0.01 px of the sample (0.25 px allowed).

    Measured at 640 x 480 (200,000 positions on the dome): 6e-4 px (default
    fisheye), 9e-4 px (pinhole), 5e-4 px (tilted fisheye); at this quarter
    resolution the error is about 4 times larger.
    """
    rays, valid = corner_rays(cam)
    assert rays.shape == (121, 161, 3) and rays.dtype == np.float32
    on_dome = cam.dome_mask(SENSOR)
    assert valid[on_dome].all()  # (the tilted fisheye's distortion folds at 119 deg, in the image corners)
    rng = np.random.default_rng(1)
    pos = rng.uniform(-0.5, 0.5, (4, on_dome.sum(), 2)) + np.argwhere(on_dome)
    pos = pos.reshape(-1, 2)
    exact = cam.ray_from_pixel(pos)
    d = interpolate_rays(rays, pos)
    assert np.all(np.degrees(np.arccos(np.clip((d * exact).sum(-1), -1, 1))) < 0.01)
    err = np.hypot(*(cam.pixel_from_ray(d) - pos).T)
    assert err.max() < 0.01, err.max()
    # the corners themselves are the camera's own rays
    np.testing.assert_allclose(rays[10, 20], cam.ray_from_pixel([9.5, 19.5]), rtol=0, atol=1e-7)


def test_corner_rays_of_listed_pixels_are_the_windows_corners():
    cam = quarter(TILTED)
    full, full_valid = corner_rays(cam)
    crop, crop_valid = corner_rays(cam, crop=(30, 40, 5, 7))
    np.testing.assert_array_equal(crop, full[30:36, 40:48])
    np.testing.assert_array_equal(crop_valid, full_valid[30:35, 40:47])
    pixels = np.array([60 * 160 + 80, 60 * 160 + 81, 30 * 160 + 40, 0, 160 * 120 - 1])  # last 2: past the fold
    rays, valid = corner_rays(cam, pixels=pixels)
    assert rays.shape == (5, 2, 2, 3) and valid.tolist() == [True, True, True, False, False]
    for k, (r, c) in enumerate(zip(*np.divmod(pixels, 160), strict=True)):
        np.testing.assert_array_equal(rays[k], full[r:r + 2, c:c + 2])


def plugin_rays(cam, *, crop=None, pixels=None, n=20000):
    """Rays the loaded Mitsuba sensor samples at random positions, with those positions (row, col)."""
    from optitact.render.backend import select_variant
    from optitact.render.scene import PACKED_WIDTH, RenderSettings, build_scene

    mi, _ = select_variant()
    scene = build_scene(mi, SENSOR, cam, single_patch([0.0, 0.0, 20.0], 0.0),
                        RenderSettings(n_polar=4, n_azimuth=8), crop=crop, pixels=pixels)
    rng = np.random.default_rng(3)
    frac = rng.uniform(1e-3, 1 - 1e-3, (n, 2))  # clear of the edges, where float32 rounding picks a neighbour
    if pixels is None:
        r0, c0, h, w = crop
        cell = np.stack([rng.integers(0, h, n), rng.integers(0, w, n)], -1)
        pos = cell + frac + [r0 - 0.5, c0 - 0.5]
        sample = (cell + frac) / [h, w]
    else:
        k = rng.integers(0, len(pixels), n)
        wf, hf = min(len(pixels), PACKED_WIDTH), -(-len(pixels) // PACKED_WIDTH)
        sample = (np.stack(np.divmod(k, wf), -1) + frac) / [hf, wf]
        pos = np.stack(np.divmod(pixels[k], cam.width), -1) + frac - 0.5
    ray, weight = scene.sensors()[0].sample_ray(0.0, 0.5, mi.Point2f(sample[:, 1], sample[:, 0]),
                                                mi.Point2f(0.5, 0.5))
    return pos, np.array(ray.d, np.float64).T, np.array(ray.o).T, np.array(weight)[0]


@pytest.mark.parametrize("cam", [PINHOLE, TILTED], ids=["pinhole", "tilted"])
def test_sensor_plugin_samples_the_cameras_rays(cam):
    """The Mitsuba sensor's ray for a sample at (row, col) starts at the camera's position and re-projects
    (pixel_from_ray) within 0.002 px of (row, col), in a crop window and for packed pixels (measured at
    640 x 480 over the dome: 9e-4 px pinhole, 5e-4 px tilted fisheye)."""
    rows, cols = np.mgrid[100:380:7, 180:460:11]  # spread over the image centre (on the dome)
    for kw in (dict(crop=(200, 280, 40, 60)), dict(pixels=(rows * cam.width + cols).ravel())):
        pos, d, origin, weight = plugin_rays(cam, **kw)
        np.testing.assert_allclose(origin, np.broadcast_to(cam.position, origin.shape), rtol=0, atol=1e-5)
        assert np.all(weight == 1.0)
        err = np.hypot(*(cam.pixel_from_ray(d) - pos).T)
        assert err.max() < 0.002, (kw.keys(), err.max())


@pytest.mark.parametrize("cam,polar,azimuth", [
    (PINHOLE, 0, 0), (PINHOLE, 25, 60), (PINHOLE, 35, 210),
    (TILTED, 0, 0), (TILTED, 50, 200), (TILTED, 65, 300),
], ids=["pinhole-0", "pinhole-25", "pinhole-35", "tilted-0", "tilted-50", "tilted-65"])
def test_render_agrees_with_closed_form_projection(cam, polar, azimuth):
    """A small patch's intensity centroid is within 0.25 px of pixel_from_dome of its centre."""
    c, px = patch_spot(cam, dome_point(polar, azimuth))
    np.testing.assert_allclose(c, px, rtol=0, atol=0.25)


def test_table_plugin_reproduces_the_closed_form_fisheye():
    """OpenCV's fisheye, undistorted and on the axis, is FisheyeCamera: the same samples give the same frame."""
    cam = optitact.optics.camera.FisheyeCamera(width=64, height=48)
    same = OpenCVFisheyeCamera(64, 48, fx=cam.focal_px, fy=cam.focal_px, cx=31.5, cy=23.5)
    forces = np.zeros((SENSOR.n_elements, 3))
    forces[[0, 3, 12], 2] = [0.6, 0.4, 0.3]
    a = render(SENSOR, forces, camera=cam, spp=8, seed=5)
    b = render(SENSOR, forces, camera=same, spp=8, seed=5)
    assert a.sum() > 0
    assert (a != b).mean() < 0.01  # rays differ by ~1e-5 rad: a rare specular path flips
    spots = spot_pixels(SENSOR, cam, forces)
    np.testing.assert_allclose(b[spots].sum(), a[spots].sum(), rtol=2e-3)
    kw = dict(spp=2, seed=2, variant="scalar_rgb", crop=(20, 28, 8, 8))  # the scalar variant too
    sa, sb = (render(SENSOR, forces, camera=c, **kw) for c in (cam, same))
    assert sa.sum() > 0
    np.testing.assert_allclose(sb, sa, rtol=1e-4, atol=1e-6)


def test_pixels_past_the_cameras_field_miss():
    """A pinhole whose distortion folds inside the image: pixels with a corner without a ray read 0, not NaN."""
    cam = PinholeCamera(64, 48, fx=30.0, fy=30.0, cx=31.5, cy=23.5, dist=(-0.3, 0.0, 0.0, 0.0))
    rows, cols = np.mgrid[0:49, 0:65] - 0.5
    has_ray = np.isfinite(cam.ray_from_pixel(np.stack([rows, cols], -1))).all(-1)
    want = has_ray[:-1, :-1] & has_ray[:-1, 1:] & has_ray[1:, :-1] & has_ray[1:, 1:]
    _, valid = corner_rays(cam)
    np.testing.assert_array_equal(valid, want)
    assert 0.2 < valid.mean() < 0.8
    forces = np.zeros((SENSOR.n_elements, 3))
    forces[0, 2] = 0.8
    full = render(SENSOR, forces, camera=cam, spp=4, seed=3)
    packed = render(SENSOR, forces, camera=cam, spp=4, seed=3, pixels=np.ones(cam.shape, bool))
    for img in (full, packed):
        assert np.isfinite(img).all()
        assert np.all(img[~valid] == 0) and img[valid].sum() > 0


@pytest.fixture(scope="module")
def tilted_quarter_noload():
    return render(SENSOR, np.zeros((41, 3)), camera=quarter(TILTED), spp=64, seed=7)


def test_pixel_rendering_matches_full_frames_within_noise(tilted_quarter_noload):
    """Spot pixels rendered packed over a no-load background agree with full frames: per loaded element,
    the summed radiance over the no-load frame within 4 combined standard errors (3 seeds each)."""
    from optitact.render.pathtrace import loaded_region_pixels

    cam = quarter(TILTED)
    bg = tilted_quarter_noload
    mask = spot_pixels(SENSOR, cam, PIX_LOAD)
    pixel, label = loaded_region_pixels(SENSOR, cam, PIX_LOAD)
    assert np.unique(label).tolist() == [0, 5, 20]

    def sums(img):
        return np.bincount(label, img.reshape(-1)[pixel].astype(np.float64) - bg.reshape(-1)[pixel])[[0, 5, 20]]

    packed, full = [], []
    for k in range(3):
        img = render(SENSOR, PIX_LOAD, camera=cam, spp=64, seed=10 + k, pixels=mask, background=bg)
        np.testing.assert_array_equal(img[~mask], bg[~mask])
        packed.append(sums(img))
        full.append(sums(render(SENSOR, PIX_LOAD, camera=cam, spp=64, seed=20 + k)))
    packed, full = np.array(packed), np.array(full)
    assert np.all(full.mean(0) > 0.5)
    se = np.sqrt(packed.var(0, ddof=1) / 3 + full.var(0, ddof=1) / 3)
    assert np.all(np.abs(packed.mean(0) - full.mean(0)) < 4 * se + 0.02 * full.mean(0)), (packed, full)


def test_two_stage_takes_every_model_and_measures_tables_through_a_fisheye_only():
    """Two-stage renders through any model (the table belongs to the patches); a table is measured
    through an on-axis FisheyeCamera only, and the message says how to render through another."""
    from optitact.render.emission import EmissionTable, emission_table

    th = np.radians([0.0, 80.0])
    table = EmissionTable(th, np.array([0.1, 0.5]), np.full((2, 2), 2.0), np.zeros((2, 2)), th,
                          np.zeros((2, 2)), np.zeros(2), {})
    for cam in (quarter(PINHOLE), quarter(TILTED)):
        bg = np.zeros(cam.shape, np.float32)
        img = render(SENSOR, PIX_LOAD, camera=cam, transport="two_stage", table=table, background=bg)
        assert img.shape == cam.shape and np.isfinite(img).all() and img.max() > 0.1
        assert np.all(img[~spot_pixels(SENSOR, cam, PIX_LOAD)] == 0)
        with pytest.raises(TypeError, match=r"FisheyeCamera or None .*table=emission_table\(sensor\)"):
            emission_table(SENSOR, cam)
