"""Renderer tests: tiny renders and crop windows only (seconds in all).

Renders are compared statistically or against the closed-form camera, never
bit-exact across machines; the JIT variant is whichever works here.
"""

from __future__ import annotations

import subprocess
import sys

import numpy as np
import pytest
from optitact.render import render, render_contacts
from optitact.render.pathtrace import pass_seeds
from optitact.render.backend import PREFERRED_VARIANTS, active_variant, find_libllvm, select_variant
from optitact.render.scene import RenderSettings

import optitact
from optitact.optics.contact import Contacts

pytestmark = pytest.mark.render

SENSOR = optitact.optics.sensor.DomeSensor.default()
CAMERA = optitact.optics.camera.FisheyeCamera()
TINY = optitact.optics.camera.FisheyeCamera(width=64, height=48)


def single_patch(point, radius) -> Contacts:
    one = np.ones((1, 1))
    return Contacts(centers=np.asarray(point, float).reshape(1, 1, 3), radii=radius * one,
                    loads=0 * one, saturated=one < 0, tipped=np.zeros(1, bool),
                    slide=np.zeros((1, 2)))


def dome_point(polar_deg, azimuth_deg, r=20.0):
    th, ph = np.radians(polar_deg), np.radians(azimuth_deg)
    return r * np.array([np.sin(th) * np.cos(ph), np.sin(th) * np.sin(ph), np.cos(th)])


def window(center_rc, half):
    r0, c0 = int(round(center_rc[0])) - half, int(round(center_rc[1])) - half
    return (r0, c0, 2 * half + 1, 2 * half + 1)


def centroid(img, crop):
    w = np.clip(img, 0, None)
    w = np.where(w >= 0.2 * w.max(), w, 0.0)
    rr, cc = np.mgrid[0:img.shape[0], 0:img.shape[1]]
    return np.array([(w * rr).sum() / w.sum() + crop[0], (w * cc).sum() / w.sum() + crop[1]])


def patch_spot(camera, point):
    """The intensity centroid (row, col) of a 0.25 mm patch at a dome point (256 spp, over the empty
    frame), and ``pixel_from_dome`` of the point."""
    px = optitact.optics.camera.pixel_from_dome(point, sensor=SENSOR, camera=camera)
    crop = window(px, 10)
    spot = render_contacts(SENSOR, single_patch(point, 0.25), camera=camera, spp=256, seed=7,
                           crop=crop).astype(np.float64)
    empty = render_contacts(SENSOR, single_patch(point, 0.0), camera=camera, spp=256, seed=8,
                            crop=crop).astype(np.float64)
    return centroid(spot - empty, crop), px


def test_variant_is_the_fastest_that_works():
    mi, variant = select_variant()
    assert variant in PREFERRED_VARIANTS
    assert variant == mi.variant()
    info = active_variant()
    assert info["variant"] == variant
    path = find_libllvm()
    if path is not None:  # a library this machine has must be one Dr.Jit accepts
        import re

        major = int(re.search(r"(?:LLVM-|LLVM\.so\.|llvm-)(\d+)", path).group(1))
        assert major >= 19


def test_unknown_variant_is_a_value_error():
    with pytest.raises(ValueError, match="variant must be a Mitsuba variant name"):
        render(SENSOR, np.zeros((41, 3)), camera=TINY, spp=1, variant="nope")
    # well formed but not built into this Mitsuba: refused once Mitsuba says what it has
    with pytest.raises(ValueError, match="unknown Mitsuba variant 'cuda_mono_polarized_double'; available"):
        render(SENSOR, np.zeros((41, 3)), camera=TINY, spp=1, variant="cuda_mono_polarized_double")


def test_tiny_render_smoke():
    forces = np.zeros((41, 3))
    forces[0, 2] = 1.0
    img = render(SENSOR, forces, camera=TINY, spp=8, seed=1)
    assert img.shape == (48, 64) and img.dtype == np.float32
    assert np.all(np.isfinite(img)) and img.min() >= 0
    # The apex element's spots surround the image centre (23.5, 31.5), within ~3 px.
    rr, cc = np.mgrid[0:48, 0:64]
    near = np.hypot(rr - 23.5, cc - 31.5) < 4
    assert img[near].sum() > 0.5 * img[np.hypot(rr - 23.5, cc - 31.5) < 12].sum() > 0


@pytest.mark.parametrize("polar,azimuth", [(0, 0), (30, 40), (50, 200), (65, 300)])
def test_render_agrees_with_closed_form_projection(polar, azimuth):
    """A small patch's intensity centroid is within 0.25 px of project() of its centre."""
    c, px = patch_spot(CAMERA, dome_point(polar, azimuth))
    np.testing.assert_allclose(c, px, rtol=0, atol=0.25)


def test_no_load_gives_no_spot_and_load_gives_more_light():
    crop = window(CAMERA.project(SENSOR.element_positions[0], SENSOR), 14)
    totals = []
    for fz in (0.0, 0.2, 0.8):
        f = np.zeros((41, 3))
        f[0, 2] = fz
        totals.append(render(SENSOR, f, camera=CAMERA, spp=64, seed=3, crop=crop).sum())
    # Background only (no contact): a tiny glow. Spot light grows with load (area ~ load).
    assert totals[0] < 0.05 * totals[1]
    ratio = (totals[2] - totals[0]) / (totals[1] - totals[0])
    assert 2.5 < ratio < 5.5  # Sneddon: area ratio 4 for a 4x load


def test_shear_moves_the_spot_centroid_along_the_shear():
    crop = window(CAMERA.project(SENSOR.element_positions[0], SENSOR), 14)
    cents = []
    for fx in (-0.25, 0.25):
        f = np.zeros((41, 3))
        f[0] = (fx, 0.0, 0.8)
        img = render(SENSOR, f, camera=CAMERA, spp=64, seed=5, crop=crop).astype(np.float64)
        rr, cc = np.mgrid[0:img.shape[0], 0:img.shape[1]]
        cents.append(np.array([(img * rr).sum(), (img * cc).sum()]) / img.sum())
    # Apex: local x = global x = image columns.
    assert cents[1][1] - cents[0][1] > 0.5
    assert abs(cents[1][0] - cents[0][0]) < 0.3


def test_same_seed_same_frame_jit():
    f = np.zeros((41, 3))
    f[0, 2] = 0.6
    a = render(SENSOR, f, camera=TINY, spp=20, seed=11)
    b = render(SENSOR, f, camera=TINY, spp=20, seed=11)
    c = render(SENSOR, f, camera=TINY, spp=20, seed=12)
    np.testing.assert_allclose(a, b, rtol=1e-5, atol=1e-6)
    assert not np.allclose(a, c)


def test_same_seed_bit_identical_on_scalar():
    f = np.zeros((41, 3))
    f[0, 2] = 0.6
    crop = (20, 28, 8, 8)
    kw = dict(camera=TINY, spp=4, seed=2, variant="scalar_rgb", crop=crop)
    a = render(SENSOR, f, **kw)
    b = render(SENSOR, f, **kw)
    assert np.array_equal(a, b)
    assert a.sum() > 0


def test_pass_seeds_are_deterministic_and_distinct():
    assert pass_seeds(3, 4) == pass_seeds(3, 4)
    assert len(set(pass_seeds(3, 16))) == 16
    assert pass_seeds(3, 2) != pass_seeds(4, 2)


@pytest.mark.parametrize("kwargs,exc,match", [
    (dict(forces=np.full((41, 3), np.nan)), ValueError, "forces must be finite"),
    (dict(forces=np.zeros((40, 3))), ValueError, r"forces must have shape \(41, 3\)"),
    (dict(forces=np.zeros((41, 3), complex)), TypeError, "real numeric array"),
    (dict(spp=0), ValueError, "spp must be >= 1"),
    (dict(spp=2.5), TypeError, "spp must be an integer"),
    (dict(seed=-1), ValueError, "seed must be >= 0"),
    (dict(crop=(0, 0, 100, 10)), ValueError, "crop window"),
    (dict(crop=(0, 0, 5)), ValueError, "crop must be"),
    (dict(camera="cam"), TypeError, "camera must be a FisheyeCamera"),
    (dict(settings={}), TypeError, "settings must be a RenderSettings"),
])
def test_bad_input_is_refused_before_mitsuba(kwargs, exc, match):
    args = dict(forces=np.zeros((41, 3)), camera=TINY, spp=1, seed=0)
    args.update(kwargs)
    forces = args.pop("forces")
    with pytest.raises(exc, match=match):
        render(SENSOR, forces, **args)


def test_errors_do_not_import_mitsuba_and_import_is_lazy():
    code = (
        "import sys, numpy as np, optitact\n"
        "from optitact.render import render\n"
        "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules\n"
        "s = optitact.optics.sensor.DomeSensor.default()\n"
        "for kw in ({'spp': 0}, {'spp': 1, 'seed': -2}):\n"
        "    try:\n"
        "        render(s, np.zeros((41, 3)), **kw)\n"
        "    except ValueError:\n"
        "        pass\n"
        "    else:\n"
        "        raise SystemExit('no error')\n"
        "assert 'mitsuba' not in sys.modules and 'drjit' not in sys.modules\n"
    )
    subprocess.run([sys.executable, "-c", code], check=True)


@pytest.mark.parametrize("kwargs,match", [
    (dict(max_depth=2), "max_depth must be >= 3"),
    (dict(rubber_reflectance=1.5), "rubber_reflectance must be <= 1"),
    (dict(rim_radiance=0.0), "rim_radiance must be finite and > 0"),
])
def test_render_settings_validation(kwargs, match):
    with pytest.raises(ValueError, match=match):
        RenderSettings(**kwargs)


# ---------------------------------------------------------------------------- only the spot pixels
PIX_CAM = optitact.optics.camera.FisheyeCamera(width=160, height=120)
PIX_LOAD = np.zeros((41, 3))
PIX_LOAD[[0, 5, 20], 2] = (0.8, 0.5, 0.6)
PIX_LOAD[0, 0] = 0.1


@pytest.fixture(scope="module")
def noload_bg():
    return render(SENSOR, np.zeros((41, 3)), camera=PIX_CAM, spp=128, seed=7)


def test_spot_pixels_are_the_loaded_regions():
    from optitact.render.pathtrace import spot_pixels

    from optitact.pipeline.frame_pipeline import Pipeline

    mask = spot_pixels(SENSOR, PIX_CAM, PIX_LOAD)
    weights = Pipeline(SENSOR, PIX_CAM).region_weights
    want = np.zeros(PIX_CAM.shape, bool).reshape(-1)
    want[weights.pixel[np.isin(weights.label, [0, 5, 20])]] = True
    np.testing.assert_array_equal(mask.reshape(-1), want)
    assert mask.sum() < 0.1 * mask.size
    assert spot_pixels(SENSOR, PIX_CAM, PIX_LOAD, margin=2).sum() > mask.sum()
    assert not spot_pixels(SENSOR, PIX_CAM, np.zeros((41, 3))).any()


def test_pixel_rendering_matches_full_frames_within_noise(noload_bg):
    """Readings of frames rendered only at the spot pixels (over a no-load background) agree with
    full-frame renders in the mean over seeds, within 4 combined standard errors."""
    from optitact.render.pathtrace import spot_pixels

    from optitact.pipeline.frame_pipeline import Pipeline

    mask = spot_pixels(SENSOR, PIX_CAM, PIX_LOAD)
    pipe = Pipeline(SENSOR, PIX_CAM, baseline=noload_bg, noise_sigma=0.0)
    loaded = [0, 5, 20]
    packed, full = [], []
    for k in range(3):
        img = render(SENSOR, PIX_LOAD, camera=PIX_CAM, spp=128, seed=10 + k, pixels=mask,
                     background=noload_bg)
        np.testing.assert_array_equal(img[~mask], noload_bg[~mask])  # no seams: untouched
        packed.append(pipe.process(img).G[loaded])
        full.append(pipe.process(render(SENSOR, PIX_LOAD, camera=PIX_CAM, spp=128,
                                        seed=20 + k)).G[loaded])
    packed, full = np.array(packed), np.array(full)
    se = np.sqrt(packed.var(0, ddof=1) / 3 + full.var(0, ddof=1) / 3)
    diff = np.abs(packed.mean(0) - full.mean(0))
    assert np.all(diff < 4 * se + 0.02 * full.mean(0)), (packed.mean(0), full.mean(0), se)
    assert np.all(packed.mean(0) > 0.05)


def test_pixel_rendering_inputs(noload_bg):
    from optitact.render.pathtrace import spot_pixels

    mask = spot_pixels(SENSOR, PIX_CAM, PIX_LOAD)
    empty = render(SENSOR, PIX_LOAD, camera=PIX_CAM, spp=1, pixels=np.zeros(PIX_CAM.shape, bool),
                   background=noload_bg)
    np.testing.assert_array_equal(empty, noload_bg)
    bare = render(SENSOR, PIX_LOAD, camera=PIX_CAM, spp=4, pixels=mask)
    assert np.all(bare[~mask] == 0) and bare[mask].max() > 0
    for kw, exc, match in [
        (dict(pixels=mask, crop=(0, 0, 10, 10)), ValueError, "crop or pixels"),
        (dict(pixels=mask.astype(int)), TypeError, "bool mask"),
        (dict(pixels=mask[:, :-1]), ValueError, "camera's shape"),
        (dict(background=noload_bg), ValueError, "only used with pixels"),
        (dict(pixels=mask, background=noload_bg[:-1]), ValueError, "background must have"),
        (dict(pixels=mask, background=np.full(PIX_CAM.shape, np.nan)), ValueError, "finite"),
    ]:
        with pytest.raises(exc, match=match):
            render(SENSOR, PIX_LOAD, camera=PIX_CAM, spp=1, **kw)


def test_full_output_returns_what_the_render_measured():
    """render() returns the radiance; full_output=True a RenderResult with the samples used (no dict filled)."""
    from optitact.render import RenderResult

    cam = optitact.optics.camera.FisheyeCamera(width=32, height=24)
    bg = np.full(cam.shape, 0.25, np.float32)
    none = np.zeros(cam.shape, bool)
    out = render(SENSOR, np.zeros((41, 3)), camera=cam, pixels=none, background=bg, full_output=True)
    assert isinstance(out, RenderResult) and out.spp == 0
    np.testing.assert_array_equal(out.radiance, bg)
    plain = render(SENSOR, np.zeros((41, 3)), camera=cam, pixels=none, background=bg)
    assert isinstance(plain, np.ndarray)


def test_instanced_shell_renders_the_same_scene(monkeypatch):
    """A light render (instanced shell) equals the flat scene's render up to intersection rounding."""
    import optitact.render.pathtrace as R

    forces = np.zeros((SENSOR.n_elements, 3))
    forces[[0, 3, 12], 2] = [0.6, 0.4, 0.3]
    forces[3, 0] = 0.1
    light = render(SENSOR, forces, camera=TINY, spp=8, seed=5)          # 3,072 pixels x 8: instanced
    assert TINY.width * TINY.height * 8 < R.INSTANCED_BELOW_SAMPLES
    monkeypatch.setattr(R, "INSTANCED_BELOW_SAMPLES", 0)                 # the same render, flat scene
    flat = render(SENSOR, forces, camera=TINY, spp=8, seed=5)
    assert flat.sum() > 0
    differ = flat != light
    assert differ.mean() < 0.01                                          # the same samples, same paths
    np.testing.assert_allclose(light.sum(), flat.sum(), rtol=2e-3)
