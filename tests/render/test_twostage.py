"""Fast rendering: only loaded elements get geometry, and the two-stage light transport.

The two-stage frame is compared with brute-force path tracing on a tiny scene:
same spots (pixels), pipeline readings within a stated error.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from optitact.render import render
from optitact.render.pathtrace import spot_pixels
from optitact.render.background import noload_radiance
from optitact.render.coverage import patch_coverage
from optitact.render.emission import EmissionTable, band_weights, emission_table
from optitact.render.scene import RenderSettings, patch_mesh, patch_polygons
from optitact.render.twostage import render_two_stage

import optitact
from optitact.optics.contact import Contacts, contact_patches

pytestmark = pytest.mark.render

SENSOR = optitact.optics.sensor.DomeSensor.default()
SETTINGS = RenderSettings()
CAM = optitact.optics.camera.FisheyeCamera(width=160, height=120)
LOAD = np.zeros((41, 3))
LOAD[[0, 5, 20], 2] = (0.9, 0.7, 0.8)
LOAD[0, 0] = 0.15
LOADED = [0, 5, 20]
#: A coarse stage-1 table for the tiny camera: enough to test the method, seconds to measure.
TINY_TABLE = dict(thetas_deg=tuple(range(0, 78, 4)), radii_mm=(0.15, 0.3, 0.5), spp=512)


def test_unloaded_elements_get_no_geometry():
    forces = np.zeros((41, 3))
    assert patch_mesh(contact_patches(SENSOR, forces), radius=20, inset=0.02, segments=24) is None
    for loaded in ([0], [0, 7, 30], list(range(41))):
        forces = np.zeros((41, 3))
        forces[loaded, 2] = 0.5
        v, f, _ = patch_mesh(contact_patches(SENSOR, forces), radius=20, inset=0.02, segments=24)
        assert len(f) == 24 * 8 * len(loaded)  # 8 cones x 24 triangles per loaded element only
        assert len(v) == 25 * 8 * len(loaded)


def test_polygons_have_the_contact_area_and_sit_at_the_patch():
    forces = np.zeros((41, 3))
    forces[[0, 12], 2] = (0.6, 0.9)
    c = contact_patches(SENSOR, forces)
    mid, normal, u, w, circ, radii = patch_polygons(c, radius=20.0, inset=0.02, segments=24)
    k = 24
    area = 0.5 * k * circ**2 * math.sin(2 * math.pi / k)
    np.testing.assert_allclose(area, np.pi * radii**2, rtol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(mid, axis=1), 19.98, atol=1e-12)
    np.testing.assert_allclose(np.sum(u * normal, axis=1), 0, atol=1e-12)
    np.testing.assert_allclose(np.cross(u, w), normal, atol=1e-12)


def _footprint_mm2(cam, rows, cols):
    """Dome area (mm^2) one pixel covers, from the closed-form camera (independent of the tracer)."""
    p = cam.unproject(np.stack([rows, cols], -1).astype(float), SENSOR)
    pr = cam.unproject(np.stack([rows + 0.5, cols], -1).astype(float), SENSOR)
    pc = cam.unproject(np.stack([rows, cols + 0.5], -1).astype(float), SENSOR)
    return 4 * np.linalg.norm(np.cross(pr - p, pc - p), axis=-1)


@pytest.mark.parametrize("polar", [0.0, 25.0, 50.0, 70.0])
def test_coverage_integrates_to_the_patch_area(polar):
    """Sum over pixels of coverage x pixel footprint on the dome = pi a^2 (analytic)."""
    _check_coverage_area(optitact.optics.camera.FisheyeCamera(), polar)


def _check_coverage_area(cam, polar):
    """Sum over pixels of coverage x pixel footprint = pi a^2 (1 %); the spot's centroid at the projection."""
    th, ph = math.radians(polar), math.radians(33.0)
    point = 20.0 * np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])
    for a in (0.12, 0.4):
        one = np.ones((1, 1))
        c = Contacts(centers=point.reshape(1, 1, 3), radii=a * one, loads=0 * one, saturated=one < 0,
                     tipped=np.zeros(1, bool), slide=np.zeros((1, 2)))
        cov = patch_coverage(SENSOR, cam, c, SETTINGS, n_sub=16)
        rows, cols = np.divmod(cov["pixel"], cam.width)
        area = np.sum(cov["coverage"] * _footprint_mm2(cam, rows, cols))
        assert area == pytest.approx(np.pi * a * a, rel=0.01)
        # the spot is where the closed-form camera projects the patch centre
        weight = cov["coverage"] / cov["coverage"].sum()
        centre = np.array([np.sum(weight * rows), np.sum(weight * cols)])
        np.testing.assert_allclose(centre, cam.project(point, SENSOR), atol=0.15)


def test_coverage_converges_with_sub_sampling():
    forces = np.zeros((41, 3))
    forces[:, 2] = 0.5
    forces[:, 0] = 0.1
    c = contact_patches(SENSOR, forces)
    cam = optitact.optics.camera.FisheyeCamera()
    fine = patch_coverage(SENSOR, cam, c, SETTINGS, n_sub=24)
    per_fine = np.bincount(fine["patch"], weights=fine["transmitted"])
    coarse = patch_coverage(SENSOR, cam, c, SETTINGS, n_sub=8)
    per_coarse = np.bincount(coarse["patch"], weights=coarse["transmitted"], minlength=per_fine.size)
    np.testing.assert_allclose(per_coarse, per_fine, rtol=0.01)
    assert abs(per_coarse.sum() / per_fine.sum() - 1) < 1e-3
    assert np.all((coarse["coverage"] > 0) & (coarse["coverage"] <= 1))


def test_band_weights_are_a_partition_of_unity():
    bands = np.radians([5.0, 20.0, 35.0])
    th = np.radians([0.0, 5.0, 12.5, 20.0, 30.0, 50.0])
    w = band_weights(th, bands)
    np.testing.assert_allclose(w.sum(axis=1), 1.0)
    np.testing.assert_allclose(w[2], [0.5, 0.5, 0.0])
    np.testing.assert_allclose(w[[0, -1]], [[1, 0, 0], [0, 0, 1]])


@pytest.fixture(scope="module")
def tiny_table():
    return emission_table(SENSOR, CAM, **TINY_TABLE)


def test_table_is_cached_and_round_trips(tiny_table):
    again = emission_table(SENSOR, CAM, **TINY_TABLE)
    np.testing.assert_array_equal(again.radiance, tiny_table.radiance)
    back = EmissionTable.from_dict(tiny_table.to_dict())
    np.testing.assert_array_equal(back(tiny_table.theta, 0.3), tiny_table(tiny_table.theta, 0.3))
    assert np.all(tiny_table.radiance > 0) and np.all(np.isfinite(tiny_table.coupling))
    with pytest.raises(ValueError, match="version"):
        EmissionTable.from_dict({**tiny_table.to_dict(), "version": 0})
    with pytest.raises(ValueError, match="shapes"):
        EmissionTable.from_dict({**tiny_table.to_dict(), "radiance": [[1.0]]})


def test_two_stage_matches_brute_force_on_a_tiny_scene(tiny_table):
    """Same spots, and pipeline readings of the loaded elements within the stated error:
    G within 8 % and u within 0.05 mm of a 2048-spp path-traced frame. The tiny scene has a
    coarse table (4 deg steps across the sharp fall of the guided light near 42 deg, 512 spp,
    0.5 mm pixels); at 640x480 with the default table `optitact bench render` measures < 1 % in G."""
    from optitact.pipeline.frame_pipeline import Pipeline

    bg = noload_radiance(SENSOR, CAM)
    contacts = contact_patches(SENSOR, LOAD)
    fast = render_two_stage(SENSOR, contacts, camera=CAM, table=tiny_table, background=bg, settings=SETTINGS)
    mask = spot_pixels(SENSOR, CAM, LOAD)
    brute = render(SENSOR, LOAD, camera=CAM, spp=2048, seed=3, pixels=mask, background=bg)
    # nothing changes outside the loaded elements' regions (no seams, no stray light)
    np.testing.assert_array_equal(fast[~mask], bg[~mask])
    # same spots: the lit pixels coincide
    lit_fast = fast - bg > 0.05 * (fast - bg).max()
    lit_brute = brute - bg > 0.05 * (fast - bg).max()
    assert (lit_fast & lit_brute).sum() >= 0.8 * max(lit_fast.sum(), lit_brute.sum())
    pipe = Pipeline(SENSOR, CAM, baseline=bg, noise_sigma=0.0)
    rf, rb = pipe.process(fast), pipe.process(brute)
    assert rf.contact[LOADED].all() and not rf.contact[np.setdiff1d(np.arange(41), LOADED)].any()
    np.testing.assert_allclose(rf.G[LOADED], rb.G[LOADED], rtol=0.08)
    np.testing.assert_allclose(rf.u[LOADED], rb.u[LOADED], atol=0.05)


def test_two_stage_through_render_is_deterministic_and_validated(tiny_table):
    a = render(SENSOR, LOAD, camera=CAM, transport="two_stage", table=tiny_table)
    b = render(SENSOR, LOAD, camera=CAM, transport="two_stage", table=tiny_table, seed=99, spp=1)
    np.testing.assert_array_equal(a, b)  # no Monte Carlo: the seed and spp do not matter
    crop = render(SENSOR, LOAD, camera=CAM, transport="two_stage", table=tiny_table, crop=(10, 20, 30, 40))
    np.testing.assert_array_equal(crop, a[10:40, 20:60])
    with pytest.raises(ValueError, match="transport must be one of"):
        render(SENSOR, LOAD, camera=CAM, transport="fast")
    with pytest.raises(ValueError, match="pixels= is"):
        render(SENSOR, LOAD, camera=CAM, transport="two_stage", table=tiny_table,
               pixels=np.ones(CAM.shape, bool))
    with pytest.raises(ValueError, match="n_sub must be >= 1"):
        render(SENSOR, LOAD, camera=CAM, transport="two_stage", table=tiny_table, n_sub=0)
    with pytest.raises(TypeError, match="table must be an EmissionTable"):
        render(SENSOR, LOAD, camera=CAM, transport="two_stage", table={})


def test_calibration_set_from_two_stage_frames(tiny_table, tmp_path):
    """generate(render_mode="two_stage") renders no Monte Carlo noise into the loaded frames: the
    same set twice is identical, and its readings follow the path-traced pixels mode's."""
    from optitact.calib.sets import generate

    kw = dict(frames=3, camera=CAM, spp=64, seed=4, progress=False)
    a = generate(tmp_path / "a.zarr", render_mode="two_stage", table=tiny_table, **kw)
    b = generate(tmp_path / "b.zarr", render_mode="two_stage", table=tiny_table, **kw)
    assert a.attrs["render_mode"] == "two_stage" and a.complete
    np.testing.assert_array_equal(a.array("G"), b.array("G"))
    p = generate(tmp_path / "p.zarr", render_mode="pixels", **(kw | {"spp": 512}))
    ga, gp = a.array("G"), p.array("G")
    both = (ga > 0) & (gp > 0)
    assert both.sum() > 0.8 * (gp > 0).sum()
    ratio = np.median(ga[both] / gp[both])
    assert abs(ratio - 1) < 0.06, ratio
    with pytest.raises(ValueError, match="table is for render_mode='two_stage'"):
        generate(tmp_path / "c.zarr", render_mode="pixels", table=tiny_table, **kw)


def test_adaptive_sampling_reaches_its_target():
    """target_error: passes until each loaded element's summed radiance has that relative
    standard error; a looser target stops earlier, and the result is within ~3 targets of a
    converged render."""
    bg = noload_radiance(SENSOR, CAM)
    mask = spot_pixels(SENSOR, CAM, LOAD)
    ref = render(SENSOR, LOAD, camera=CAM, spp=4096, seed=1, pixels=mask, background=bg)
    from optitact.pipeline.regions import region_weights, split_regions

    weights = region_weights(split_regions(SENSOR, CAM), CAM.shape)

    def sums(img):
        d = (img - bg).reshape(-1)
        return np.array([d[weights.region_pixels([e])[0]].sum() for e in LOADED])

    used = {}
    for target in (0.05, 0.01):
        out = render(SENSOR, LOAD, camera=CAM, spp=16, seed=2, pixels=mask, background=bg,
                     target_error=target, max_spp=4096, full_output=True)
        img, used[target] = out.radiance, out.spp
        np.testing.assert_allclose(sums(img), sums(ref), rtol=3 * target + 0.01)
    assert used[0.05] < used[0.01] <= 4096
    assert used[0.05] >= 64  # at least 4 passes to estimate the spread
    with pytest.raises(ValueError, match="target_error must be finite and > 0"):
        render(SENSOR, LOAD, camera=CAM, target_error=0)
    with pytest.raises(ValueError, match="target_error is for transport='path'"):
        render(SENSOR, LOAD, camera=CAM, target_error=0.01, transport="two_stage")


def test_bench_render_uses_the_table_it_is_given(tiny_table, monkeypatch):
    """bench_render(table=...) once reset its argument and built the default 4096-spp table (minutes)."""
    from optitact.studies import bench_render as br

    def no_table(*args, **kwargs):
        raise AssertionError("bench_render built a table although one was given")

    import optitact.render.emission as em

    monkeypatch.setattr(em, "emission_table", no_table)
    out = br.bench_render((1,), modes=("two_stage",), n_subs=(2,), reference_spp=8, width=CAM.width,
                          height=CAM.height, cases=("1-heavy",), table=tiny_table, progress=False)
    assert [r["mode"] for r in out["rows"]] == ["two_stage"]
    assert out["rows"][0]["g_rel_error"] >= 0
    assert out["headline"]["best_mode"] in ("two_stage", None)  # a mode alone, at or off the target


def test_element_gain_scales_each_elements_spots(tiny_table):
    """As built: an element's gain multiplies its patches' radiance, exactly in two-stage
    (deterministic) and within Monte Carlo noise in path tracing (it scales the rubber's reflectance)."""
    gains = np.ones(41)
    gains[[5, 20]] = (1.2, 0.7)
    built = optitact.optics.sensor.DomeSensor(element_gain=gains)
    bg = np.zeros(CAM.shape, np.float32)
    contacts = contact_patches(SENSOR, LOAD)
    plain = render_two_stage(SENSOR, contacts, camera=CAM, table=tiny_table, background=bg, settings=SETTINGS)
    lit = render_two_stage(built, contacts, camera=CAM, table=tiny_table, background=bg, settings=SETTINGS)
    near = CAM.project(SENSOR.element_positions[LOADED], SENSOR)
    rows, cols = np.mgrid[:CAM.height, :CAM.width]
    mask = spot_pixels(SENSOR, CAM, LOAD)
    for e, (r, c) in zip(LOADED, near, strict=True):
        disc = np.hypot(rows - r, cols - c) < 12
        assert lit[disc].sum() / plain[disc].sum() == pytest.approx(gains[e], rel=1e-6)
        if e == 20:
            path_plain = render(SENSOR, LOAD, camera=CAM, spp=512, seed=1, pixels=mask, background=bg)
            path_lit = render(built, LOAD, camera=CAM, spp=512, seed=1, pixels=mask, background=bg)
            assert path_lit[disc].sum() / path_plain[disc].sum() == pytest.approx(gains[e], rel=0.02)
    with pytest.raises(ValueError, match="exceed 1"):
        render(optitact.optics.sensor.DomeSensor(element_gain=np.full(41, 1.5)), LOAD, camera=CAM, spp=1)


# ---------------------------------------------------------------- any camera model

def _old_fisheye_sample_rays(sensor, camera, rows, cols):
    """The closed-form equidistant rays of the coverage before it took every model (the reference)."""
    cy, cx = camera.center
    dr, dc = rows - cy, cols - cx
    alpha = np.hypot(dr, dc) / camera.focal_px
    phi = np.arctan2(dr, dc)
    sa = np.sin(alpha)
    d = np.stack([sa * np.cos(phi), sa * np.sin(phi), np.cos(alpha)], axis=-1)
    zc = camera.z
    r_in = sensor.inner_radius
    cd = zc * d[:, 2]
    t = -cd + np.sqrt(cd * cd - zc * zc + r_in * r_in)
    q = t[:, None] * d
    q[:, 2] += zc
    nrm = q / r_in
    cos_i = np.sum(d * nrm, axis=1)
    n = float(sensor.refractive_index)
    eta = 1.0 / n
    cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
    dt = eta * d + (cos_t - eta * cos_i)[:, None] * nrm
    rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
    rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    return q, dt, (1.0 - 0.5 * (rs * rs + rp * rp)) / (n * n)


def test_fisheye_coverage_is_unchanged_by_the_general_rays(monkeypatch):
    """One ray path for every model: the FisheyeCamera's coverage equals the old closed form's to 1e-12."""
    import optitact.render.coverage as cv

    forces = np.zeros((41, 3))
    forces[[0, 3, 11, 26, 40], 2] = (0.4, 0.9, 0.6, 1.2, 0.8)
    forces[[3, 26], 1] = 0.2
    c = contact_patches(SENSOR, forces)
    for cam in (optitact.optics.camera.FisheyeCamera(), CAM):
        new = patch_coverage(SENSOR, cam, c, SETTINGS)
        with monkeypatch.context() as m:
            m.setattr(cv, "_sample_rays", _old_fisheye_sample_rays)
            old = patch_coverage(SENSOR, cam, c, SETTINGS)
        for key in ("patch", "pixel", "element"):
            np.testing.assert_array_equal(new[key], old[key])
        for key in ("coverage", "transmitted", "theta", "radius"):
            np.testing.assert_allclose(new[key], old[key], rtol=0, atol=1e-12)
        assert new["pixel"].size > 100


def _models():
    from test_render_cameras import PINHOLE, TILTED, quarter

    return {"pinhole": PINHOLE, "tilted": TILTED, "pinhole_q": quarter(PINHOLE), "tilted_q": quarter(TILTED)}


@pytest.mark.parametrize("model", ["pinhole", "tilted"])
@pytest.mark.parametrize("polar", [0.0, 25.0, 50.0])
def test_coverage_integrates_to_the_patch_area_for_other_models(model, polar):
    """A distorted, off-axis, tilted camera: coverage x pixel footprint on the dome (from the closed-form
    unprojection) sums to pi a^2 within 1 %, and the spot's centroid is the projected centre (0.15 px).

    The affine map over one pixel (centre and the neighbours' rays) holds as well as for the default
    fisheye: its error at the pixel's corners, measured on 3000 dome pixels of each 640 x 480 camera,
    is at most 0.31 % (pinhole) and 0.51 % (tilted fisheye) of the pixel's footprint (0.48 % default)."""
    _check_coverage_area(_models()[model], polar)


def test_table_key_ignores_the_rendering_camera_and_the_as_built_fields(tiny_table):
    from optitact.render.emission import _shipped_key, _table_key, shipped_table

    built = optitact.optics.sensor.DomeSensor(element_gain=np.linspace(0.9, 1.1, 41),
                                element_offsets=np.full((41, 2), 0.1))
    grid = ((0.0, 10.0), (5.0,))
    assert _shipped_key(built, CAM, SETTINGS, grid, (0.3,)) == _shipped_key(SENSOR, CAM, SETTINGS, grid, (0.3,))
    assert (_table_key(built, CAM, SETTINGS, grid, (0.3,), 64, 0, "v")
            == _table_key(SENSOR, CAM, SETTINGS, grid, (0.3,), 64, 0, "v"))
    # the measuring camera is part of the key; the default sensor's shipped table serves the as-built one
    assert _shipped_key(SENSOR, CAM, SETTINGS, grid, (0.3,)) != _shipped_key(
        SENSOR, optitact.optics.camera.FisheyeCamera(), SETTINGS, grid, (0.3,))
    assert shipped_table(built) is not None
    # the tiny table, asked for again for the as-built sensor, comes from the cache (no measurement)
    again = emission_table(built, CAM, **TINY_TABLE)
    np.testing.assert_array_equal(again.radiance, tiny_table.radiance)


@pytest.fixture(scope="module")
def nominal_bg():
    return noload_radiance(SENSOR, CAM)


@pytest.mark.parametrize("model", ["pinhole_q", "tilted_q"])
def test_two_stage_matches_brute_force_through_other_models(tiny_table, nominal_bg, model):
    """The tiny table measured once through CAM serves a distorted off-axis pinhole and a tilted
    Kannala-Brandt fisheye (160 x 120): same spots, and G within 8 % and u within 0.05 mm of a
    4096-spp path-traced frame (the tolerance of the fisheye test above; at 2048 spp the path-traced
    G of one element moves by 3.5 % between seeds, so the reference takes twice the samples)."""
    from optitact.pipeline.frame_pipeline import Pipeline

    cam = _models()[model]
    bg = noload_radiance(SENSOR, cam, nominal=CAM)  # resampled from CAM's no-load frame
    contacts = contact_patches(SENSOR, LOAD)
    fast = render(SENSOR, LOAD, camera=cam, transport="two_stage", table=tiny_table, background=bg)
    mask = spot_pixels(SENSOR, cam, LOAD)
    brute = render(SENSOR, LOAD, camera=cam, spp=4096, seed=3, pixels=mask, background=bg)
    np.testing.assert_array_equal(fast[~mask], bg[~mask])
    np.testing.assert_array_equal(
        fast, render_two_stage(SENSOR, contacts, camera=cam, table=tiny_table, background=bg,
                               settings=SETTINGS))
    lit_fast = fast - bg > 0.05 * (fast - bg).max()
    lit_brute = brute - bg > 0.05 * (fast - bg).max()
    assert (lit_fast & lit_brute).sum() >= 0.8 * max(lit_fast.sum(), lit_brute.sum())
    pipe = Pipeline(SENSOR, cam, baseline=bg, noise_sigma=0.0)
    rf, rb = pipe.process(fast), pipe.process(brute)
    assert rf.contact[LOADED].all() and not rf.contact[np.setdiff1d(np.arange(41), LOADED)].any()
    np.testing.assert_allclose(rf.G[LOADED], rb.G[LOADED], rtol=0.08)
    np.testing.assert_allclose(rf.u[LOADED], rb.u[LOADED], atol=0.05)


def test_resampled_background_matches_a_path_traced_one(nominal_bg):
    """The no-load frame of an 80 x 60 Kannala-Brandt camera 0.36 mm off axis and 1.9 deg tilted,
    resampled from CAM's (160 x 120) through the dome, against its own path-traced one (1024 spp).

    The path-traced frame is sparse Monte Carlo speckle (the no-load light is a rim ring and a faint
    inner ring), so the comparison is of what the two agree on beyond noise: the total radiance in
    and outside the dome within 20 % (measured 6 % and 10 %; the target's own Poisson noise is about
    11 %), the correlation of the frames smoothed by 1.5 px above 0.8, and the rings at the same place:
    the radiance-weighted mean distance from the image centre within 0.5 px."""
    from scipy.ndimage import gaussian_filter

    from optitact.optics.camera_models import OpenCVFisheyeCamera, pose_from_position

    cam = OpenCVFisheyeCamera(80, 60, fx=185.0 / 8, fy=186.0 / 8, cx=323.5 / 8 - 0.5, cy=237.5 / 8 - 0.5,
                              dist=(0.03, -0.01, 0.002, -0.0005),
                              **pose_from_position((0.3, -0.2, -5.0), (0.02, -0.025, 0.01)))
    resampled = noload_radiance(SENSOR, cam, nominal=CAM).astype(np.float64)
    traced = noload_radiance(SENSOR, cam, resample=False).astype(np.float64)
    assert resampled.shape == cam.shape and np.isfinite(resampled).all()
    dome = cam.dome_mask(SENSOR)
    for part in (dome, ~dome):
        assert resampled[part].sum() == pytest.approx(traced[part].sum(), rel=0.2)
    a, b = gaussian_filter(resampled, 1.5), gaussian_filter(traced, 1.5)
    assert np.corrcoef(a.ravel(), b.ravel())[0, 1] > 0.8
    rows, cols = np.mgrid[:cam.height, :cam.width]
    dist = np.hypot(rows - cam.cy, cols - cam.cx)
    for part in (dome, ~dome):
        ra = np.sum(dist[part] * resampled[part]) / resampled[part].sum()
        rb = np.sum(dist[part] * traced[part]) / traced[part].sum()
        assert abs(ra - rb) < 0.5
    # a FisheyeCamera and resample=False are path-traced exactly as before
    np.testing.assert_array_equal(noload_radiance(SENSOR, CAM, resample=True), nominal_bg)
