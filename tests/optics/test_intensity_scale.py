"""Frames' intensity scale, one-frame baselines and calibration files (issue 17).

Frames are drawn with the CCD model from a known radiance: a smooth
background that brightens towards the image's rim (where the outer ring of
elements lies) and Gaussian spots at three elements' centres. 16-bit frames
are the 8-bit ones times 257 (``65535 = 257 x 255``, how 8-bit images are
widened), so their readings must equal the 8-bit ones up to rounding.
"""

from __future__ import annotations

import json
import os
import warnings

import numpy as np
import pytest
from optitact.calib.fit import Calibration
from optitact.calib.shipped import DEFAULT_CALIBRATION, default_calibration

import optitact
from optitact.errors import InputError
from optitact.optics.ccd import CCD, IntensityScale, dn_ratio
from optitact.optics.camera import pixel_from_dome
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.imageops import noise_from_one_frame

SENSOR = optitact.optics.sensor.DomeSensor.default()
LOADED = (0, 5, 20)
SMALL = optitact.optics.camera.FisheyeCamera(width=160, height=120)


def _radiance(camera, loaded=LOADED, amplitude=0.3):
    """Background brightening towards the rim, plus a Gaussian spot (3 px) on each loaded element."""
    rows, cols = np.mgrid[0:camera.height, 0:camera.width].astype(np.float64)
    rr = np.hypot(rows - camera.height / 2, cols - camera.width / 2) / (camera.height / 2)
    img = 0.01 + 0.12 * np.minimum(rr, 1.3) ** 2
    px = pixel_from_dome(SENSOR.element_positions[list(loaded)], sensor=SENSOR, camera=camera)
    for r, c in px:
        img += amplitude * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2 * 3.0**2))
    return img


@pytest.fixture(scope="module")
def scene():
    """Default calibration, an 8-bit no-load frame, and an 8-bit loaded frame (CCD model)."""
    cal = default_calibration()
    ccd = CCD()
    noload = ccd.expose(_radiance(cal.camera, loaded=()), seed=1)
    frame = ccd.expose(_radiance(cal.camera), seed=2)
    return cal, noload, frame


@pytest.fixture(scope="module")
def readings8(scene):
    cal, noload, frame = scene
    return cal.pipeline(baseline=noload).process(frame)


# ---------------------------------------------------------------------------- 2. one-frame baseline
def test_one_frame_baseline_gives_no_phantom_contacts(readings8):
    """The default calibration with one no-load frame as baseline: exactly the loaded elements read contact."""
    assert np.flatnonzero(readings8.contact).tolist() == list(LOADED)


def _fireflies(frame, seed, n=600, height=(5, 12)):
    """``frame`` with ``n`` isolated bright pixels at random places (hot pixels, path-tracing fireflies)."""
    rng = np.random.default_rng(seed)
    out = frame.copy()
    rows = rng.integers(1, frame.shape[0] - 1, n)
    cols = rng.integers(1, frame.shape[1] - 1, n)
    out[rows, cols] = np.minimum(out[rows, cols] + rng.integers(*height, n), 255).astype(frame.dtype)
    return out


def test_isolated_bright_pixels_make_no_phantom_contacts(scene):
    """Rendered frames hold fireflies, real cameras hot pixels: each frame at other places. With one
    no-load frame as baseline only the loaded elements read contact, and with the same forces."""
    cal, noload, frame = scene
    pipe = cal.pipeline(baseline=_fireflies(noload, 10))
    plain = cal.pipeline(baseline=noload).process(frame)
    for seed in (11, 12, 13):
        r = pipe.process(_fireflies(frame, seed))
        assert np.flatnonzero(r.contact).tolist() == list(LOADED), seed
        np.testing.assert_allclose(cal.forces(r)[0][list(LOADED), 2], cal.forces(plain)[0][list(LOADED), 2],
                                   rtol=0.03)


def test_impulses_are_found_and_spots_are_not():
    """steps.impulses: single bright pixels over a noisy background are impulses, a 3-px spot is not."""
    from optitact.pipeline.imageops import impulses

    rng = np.random.default_rng(0)
    f = rng.normal(20.0, 1.0, (1, 60, 80))
    f[0, 10, 10] += 12.0
    f[0, 40, 70] += 9.0
    rows, cols = np.mgrid[0:60, 0:80]
    f[0] += 40.0 * np.exp(-((rows - 30) ** 2 + (cols - 30) ** 2) / (2 * 3.0**2))
    rate, height = impulses(f)
    assert sorted(map(tuple, np.argwhere(rate > 0))) == [(10, 10), (40, 70)]
    assert 10.0 < height[10, 10] < 14.0 and 7.0 < height[40, 70] < 11.0


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int8, np.int16])
def test_integer_frames_give_the_float_paths_values_to_the_bit(dtype):
    """impulses and noise_from_one_frame on integer frames (exact integer sums, histogram medians,
    a looked-up noise per level) give what the float64 arithmetic gives on the same frames."""
    from optitact.pipeline.imageops import impulses

    info = np.iinfo(dtype)
    rng = np.random.default_rng(int(info.bits))
    for trial in range(24):
        h, w = rng.integers(30, 70, 2)
        scale = [1.0, 3.0, 20.0, info.max / 4][trial % 4]
        ramp = np.linspace(0.0, rng.uniform(0, info.max / 3), w)
        f = np.clip(rng.normal(rng.uniform(0, info.max / 2), scale, (h, w)) + ramp, info.min, info.max)
        f = f.astype(dtype)
        f[rng.integers(1, h - 1), rng.integers(1, w - 1)] = info.max  # an impulse
        if trial % 6 == 5:
            f[:] = f[0, 0]  # flat: every residual 0
        stack = np.stack([f, np.roll(f, 3, axis=1)])
        for got, want in zip(impulses(stack), impulses(stack.astype(np.float64)), strict=True):
            assert np.array_equal(got, want)
        got, want = noise_from_one_frame(f), noise_from_one_frame(f.astype(np.float64))
        assert got.dtype == want.dtype and np.array_equal(got, want)


def test_one_frame_noise_estimate_matches_the_ccd_model():
    """noise_from_one_frame against the CCD's own noise of frame - baseline (photon + read + rounding)."""
    ccd = CCD()
    rad = _radiance(SMALL, loaded=())
    noise = noise_from_one_frame(ccd.expose(rad, seed=3))
    truth = np.sqrt(2.0 * ccd.variance_dn(rad))
    inner = np.s_[10:-10, 10:-10]
    assert abs(np.median(noise[inner] / truth[inner]) - 1.0) < 0.1


def test_one_frame_baseline_too_small_warns():
    cam = optitact.optics.camera.FisheyeCamera(width=30, height=20)
    with pytest.warns(UserWarning, match="too small to estimate its noise"):
        pipe = Pipeline(SENSOR, cam, baseline=np.full(cam.shape, 10, np.uint8))
    assert pipe.noise_map is None


# ---------------------------------------------------------------------------- 1. intensity scale
def test_16_bit_frames_of_8_bit_ones_read_the_same_forces(scene, readings8):
    cal, noload, frame = scene
    r16 = cal.pipeline(baseline=noload.astype(np.uint16) * 257, bits=16).process(frame.astype(np.uint16) * 257)
    np.testing.assert_array_equal(r16.contact, readings8.contact)
    np.testing.assert_allclose(r16.G, readings8.G, rtol=1e-12, atol=0)
    np.testing.assert_allclose(r16.u, readings8.u, rtol=0, atol=1e-12)
    f8, _ = cal.forces(readings8)
    f16, _ = cal.forces(r16)
    np.testing.assert_allclose(f16, f8, rtol=1e-9, atol=1e-12)


def test_uint16_frames_need_their_bits_stated(scene):
    cal, noload, frame = scene
    with pytest.raises(InputError, match=r"baseline: dtype uint16.*8-bit frames \(full scale 255\).*bit depth"):
        cal.pipeline(baseline=noload.astype(np.uint16) * 257)
    with pytest.raises(InputError, match=r"frames: dtype uint16.*8-bit frames \(full scale 255\).*bit depth"):
        cal.pipeline().process(frame.astype(np.uint16) * 257)


def test_12_bit_frames_for_an_8_bit_calibration_are_refused(scene):
    cal, _, _ = scene
    frame12 = CCD(bits=12).expose(_radiance(cal.camera), seed=4)
    with pytest.raises(InputError, match=r"12-bit frames \(full scale 4095\).*8-bit scale \(full scale 255\)"):
        cal.pipeline(bits=12)
    with pytest.raises(InputError, match="state the frames' bit depth"):
        cal.pipeline().process(frame12)


def test_values_above_the_stated_depth_are_refused():
    pipe = Pipeline(SENSOR, SMALL, bits=12)
    frame = np.zeros(SMALL.shape, np.uint16)
    frame[7, 9] = 5000
    with pytest.raises(InputError, match=r"5000 at frame 0, pixel \(row 7, col 9\) is above the full scale 4095"
                       ):
        pipe.process(frame)
    with pytest.raises(InputError, match="uint8 cannot hold the stated 12-bit"):
        pipe.process(np.zeros(SMALL.shape, np.uint8))


@pytest.mark.parametrize("base_dtype,frame_dtype", [(np.uint8, np.uint16), (np.uint16, np.uint8)])
def test_baseline_and_frames_of_different_depth_are_an_error(base_dtype, frame_dtype):
    pipe = Pipeline(SENSOR, SMALL, baseline=np.full(SMALL.shape, 4, base_dtype))
    with pytest.raises(InputError, match="baseline and frames of different bit depths"):
        pipe.process(np.full(SMALL.shape, 4, frame_dtype))
    with pytest.raises(InputError, match="baseline and frames of different bit depths"):
        pipe.with_baseline(np.full(SMALL.shape, 4, base_dtype)).process(np.full(SMALL.shape, 4, frame_dtype))


def test_dn_ratio_exact_pairs_only():
    assert dn_ratio(16, 8) == 257.0 and dn_ratio(8, 16) == 1 / 257 and dn_ratio(10, 10) == 1.0
    with pytest.raises(InputError, match=r"10-bit frames \(full scale 1023\).*8-bit scale \(full scale 255\)"):
        dn_ratio(10, 8)


def test_calibration_records_its_scale(tmp_path, scene):
    cal, _, _ = scene
    assert cal.intensity == IntensityScale() and cal.fingerprint == "ab5d3097d27267af"
    d = json.loads(DEFAULT_CALIBRATION.read_text())
    assert IntensityScale.from_dict(d.get("intensity", {})) == IntensityScale()  # 8-bit (the default)
    cal12 = Calibration(**{**cal.__dict__, "intensity": IntensityScale(bits=12, exposure=2.5)})
    assert cal12.fingerprint != cal.fingerprint
    back = Calibration.load(cal12.save(tmp_path / "c12.json"))
    assert back.intensity == IntensityScale(bits=12, exposure=2.5) and back.fingerprint == cal12.fingerprint
    # 12-bit data in uint16 frames: the calibration's own depth, accepted without stating it
    frame12 = CCD(bits=12).expose(_radiance(cal.camera), seed=4)
    assert back.pipeline(baseline=frame12).process(frame12).G.shape == (41,)
    with pytest.raises(InputError, match="uint8.*12-bit frames"):
        back.pipeline().process(np.zeros(cal.camera.shape, np.uint8))
    with pytest.raises(InputError, match=r"exposure 1 is not the calibration's \(12-bit"):
        back.pipeline(exposure=1.0)
    # an edited scale breaks the fingerprint
    d12 = json.loads((tmp_path / "c12.json").read_text())
    d12["intensity"]["bits"] = 8
    with pytest.raises(InputError, match="fingerprint"):
        Calibration.from_dict(d12)


def test_cli_process_bits_option(tmp_path, scene):
    from optitact.cli import main

    cal, noload, frame = scene
    np.save(tmp_path / "frames.npy", np.stack([noload, frame]).astype(np.uint16) * 257)
    out = tmp_path / "out.csv"
    assert main(["process", str(tmp_path / "frames.npy"), "--calibration", "default", "--out", str(out)]) == 2
    assert main(["process", str(tmp_path / "frames.npy"), "--calibration", "default", "--bits", "16",
                 "--out", str(out)]) == 0
    rows = [line.split(",") for line in out.read_text().splitlines()]
    head = rows[0]
    last = [r for r in rows[1:] if r[head.index("frame")] == "1"]
    contact = [int(r[head.index("element")]) for r in last if r[head.index("contact")] in ("1", "True")]
    assert contact == list(LOADED)


# ---------------------------------------------------------------------------- 3-6. calibration files
def _default_dict():
    return json.loads(DEFAULT_CALIBRATION.read_text())


def test_infinite_residual_is_refused_at_load(tmp_path):
    text = DEFAULT_CALIBRATION.read_text()
    d = _default_dict()
    first = d["residuals_n"]["fz"][0]
    path = tmp_path / "inf.json"
    path.write_text(text.replace(repr(first), "1e309", 1))
    with pytest.raises(InputError, match=r"residuals_n\['fz'\] must be finite"):
        Calibration.load(path)


def test_save_never_writes_non_json(tmp_path):
    cal = default_calibration()
    bad = Calibration(**{**cal.__dict__, "residuals": {**cal.residuals, "fz": np.full(41, np.inf)}})
    with pytest.raises(InputError, match="not finite"):
        bad.save(tmp_path / "bad.json")
    assert not (tmp_path / "bad.json").exists()


@pytest.mark.parametrize("value", ["0.99", True, None])
@pytest.mark.parametrize("where", ["elements", "residuals_n"])
def test_non_numbers_are_refused_naming_the_key(value, where):
    d = _default_dict()
    if where == "elements":
        d["elements"]["g"][3][1] = value
        match = r"elements\['g'\] must hold numbers, got"
    else:
        d["residuals_n"]["fx"][2] = value
        match = r"residuals_n\['fx'\] must hold numbers, got"
    with pytest.raises(InputError, match=match):
        Calibration.from_dict(d)


def test_calibration_prints_a_short_summary():
    text = str(default_calibration())
    assert len(text) < 400 and "\n" not in text
    for part in ("coupled", "41 elements", "640x480", "8-bit", "ab5d3097d27267af", "fz"):
        assert part in text
    assert repr(default_calibration()) == text


def test_huge_sensor_radius_is_a_clear_error():
    d = _default_dict()
    d["sensor"]["outer_radius"] = 1e308
    with pytest.raises(InputError, match=r"outer_radius must be a length from 1e-06 to 10000 mm, got 1e\+308"):
        Calibration.from_dict(d)


def test_folder_or_fifo_is_named_for_what_it_is(tmp_path):
    folder = tmp_path / "x.json"
    folder.mkdir()
    with pytest.raises(InputError, match="is a folder, expected a calibration JSON file"):
        Calibration.load(folder)
    if hasattr(os, "mkfifo"):
        fifo = tmp_path / "fifo.json"
        os.mkfifo(fifo)
        with pytest.raises(InputError, match="is not a regular file"):
            Calibration.load(fifo)
    with pytest.raises(FileNotFoundError, match="not found"):
        Calibration.load(tmp_path / "missing.json")


def test_no_warning_for_a_full_size_one_frame_baseline(scene):
    cal, noload, _ = scene
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        cal.pipeline(baseline=noload)
