import doctest
import json

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.sources import Indenter, Scenario, TactileSource, make_source
from optitact.taxels import optopad
from optitact.taxels.optopad import (LookupTableClassifier, NormalisationLUT, Opto5, Opto5Config,
                                     calibration_closure, classify_wires, remove_offset, wire_centroids,
                                     wire_dataset, wire_shape)

PUBLISHED_ROW = [0.9518, 2.2716, 3.0802, 3.5735, 6.2054, 7.9888]
DIAMETERS = [1.5, 2.0, 2.5, 3.0, 3.5, 4.0]


def grasp(src, indenter, depth, *, seed=0, **pose):
    sc = optopad._grasp_scenario(src, indenter, depth, n_base=50, n_ramp=10, n_hold=10, **pose)
    return remove_offset(src.frames(sc, seed=seed), n=50)[-10:].mean(axis=0)


@pytest.fixture(scope="module")
def clean():
    """A noise-free sensor (ADC quantisation only) and its normalisation."""
    src = Opto5(Opto5Config(noise_v=0.0, repeatability=0.0))
    dv, stim = calibration_closure(src, seed=0)
    return src, NormalisationLUT.from_closure(dv, stim), stim.max()


@pytest.fixture(scope="module")
def result():
    return optopad.experiment(seed=0, full=False, progress=False)


def test_docstring_examples():
    assert doctest.testmod(optopad, optionflags=doctest.ELLIPSIS).failed == 0


# ---- source --------------------------------------------------------------------------------------------
def test_registered_source_and_layout():
    src = make_source("opto5")
    assert isinstance(src, TactileSource) and src.name == "opto5"
    lay = src.layout
    assert lay.shape == (5, 5) and lay.pitch_mm == (3.55, 3.55) and lay.units == "V" and lay.rate_hz == 500
    assert make_source("opto5", unit_seed=3).config.unit_seed == 3
    with pytest.raises(ValueError, match="unknown config field"):
        make_source("opto5", colour=1)


@pytest.mark.parametrize("field, value, match", [
    ("pitch_mm", 0.0, "pitch_mm must be finite and > 0"),
    ("hysteresis", 0.6, r"hysteresis must be in \[0, 0.5\)"),
    ("flex", 1.0, r"flex must be in \[0, 1\)"),
    ("shape_range", (2.0, 1.0), "low <= high"),
    ("offset_range_v", (0.1, 5.0), "v_ref"),
    ("pad_mm", 10.0, "must cover the taxel grid"),
])
def test_config_validation(field, value, match):
    with pytest.raises(InputError, match=match):
        Opto5Config(**{field: value})
    with pytest.raises(TypeError, match="adc_bits must be an integer"):
        Opto5Config(adc_bits=12.0)


def test_sensor_instance_fixed_by_unit_seed_and_frames_by_seed():
    a, b, c = Opto5(Opto5Config(unit_seed=1)), Opto5(Opto5Config(unit_seed=1)), Opto5(Opto5Config(unit_seed=2))
    np.testing.assert_array_equal(a.gain, b.gain)
    assert not np.allclose(a.gain, c.gain)
    sc = Scenario(Indenter("wire", 1.0), t_s=np.arange(5) / 500, depth_mm=[0, 0.2, 0.5, 0.5, 0.1],
                  angle_rad=0.3)
    f1, f2, f3 = a.frames(sc, seed=4), a.frames(sc, seed=4), a.frames(sc, seed=5)
    assert f1.shape == (5, 5, 5)
    np.testing.assert_array_equal(f1, f2)
    assert not np.array_equal(f1, f3)
    np.testing.assert_allclose(f1 / a.lsb_v, np.rint(f1 / a.lsb_v), rtol=0, atol=1e-9)   # on the 12-bit grid


def test_finger_distance_mapping():
    src = Opto5()
    np.testing.assert_allclose(src.gap_mm([0, 255]), [8.0, 0.0], rtol=0, atol=1e-12)
    np.testing.assert_allclose(src.depth_from_finger_distance(218, 2.5), 0.5 * (2.5 - 8.0 * 37 / 255),
                               rtol=0, atol=1e-12)
    assert src.depth_from_finger_distance(100, 2.5) == 0          # gap 4.9 mm: not touching
    assert src.finger_distance_at_contact(2.5) == pytest.approx(255 * (1 - 2.5 / 8))
    with pytest.raises(InputError, match=r"finger_distance must be in \[0, 255\]"):
        src.gap_mm(256)
    with pytest.raises(InputError, match="thickness_mm must be >= 0"):
        src.depth_from_finger_distance(200, -1.0)


def test_force_scenario_solves_the_depth():
    src = Opto5()
    t = np.arange(3) / 500
    depth = Scenario(Indenter("wire", 1.25), t_s=t, depth_mm=[0.0, 0.4, 1.1], y_mm=1.0, angle_rad=0.2)
    state = src.contact(depth)
    assert state["force_n"][0] == 0 and np.all(np.diff(state["force_n"]) > 0)
    force = Scenario(Indenter("wire", 1.25), t_s=t, force_n=state["force_n"], y_mm=1.0, angle_rad=0.2)
    np.testing.assert_allclose(src.contact(force)["depth_mm"], [0.0, 0.4, 1.1], rtol=1e-7, atol=1e-9)
    # flat: total force = E/t * mean compression * area, with compression falling linearly to the tip
    flat = src.contact(Scenario(Indenter("flat"), t_s=[0.0], depth_mm=1.0))
    c = src.config
    expected = c.pad_modulus_mpa / c.pad_thickness_mm * 1.0 * (1 - c.flex / 2) * c.pad_mm ** 2
    np.testing.assert_allclose(flat["force_n"], [expected], rtol=1e-9)


def test_hysteresis_band_and_repeatability():
    src = Opto5(Opto5Config(noise_v=0.0))
    up = np.linspace(0, 4, 41)
    f = np.concatenate([up, up[::-1][1:]])[:, None, None] * np.ones((1, 5, 5))
    dv = src.response_v(f)
    loading, unloading = dv[:41], dv[40:][::-1]
    peak = dv[40]
    gap = unloading - loading
    assert np.all(gap >= -1e-15) and np.all(gap <= 0.05 * peak + 1e-15)
    np.testing.assert_allclose(gap[20], 0.05 * peak, rtol=1e-12)      # widest at half the peak force
    np.testing.assert_allclose(dv[-1], 0.0, atol=1e-15)                 # back to the offset when unloaded
    # repeatability: per-trial gain scatter ~3 % (1 sigma) of each taxel's response
    hold = np.stack([grasp(src, Indenter("flat"), 1.5, seed=s) for s in range(30)])
    rel = hold.std(axis=0, ddof=1) / hold.mean(axis=0)
    assert 0.025 < np.sqrt(np.mean(rel ** 2)) < 0.036


def test_source_errors():
    src = Opto5()
    t = np.arange(2) / 500
    with pytest.raises(InputError, match="simulates indenters"):
        src.frames(Scenario(Indenter("point"), t_s=t, depth_mm=0.1))
    with pytest.raises(InputError, match="unknown Scenario.extra key"):
        src.frames(Scenario(Indenter("wire"), t_s=t, depth_mm=0.1, extra={"twist": 1}))
    with pytest.raises(ShapeError, match="curvature_per_mm"):
        src.frames(Scenario(Indenter("wire"), t_s=t, depth_mm=0.1, extra={"curvature_per_mm": [0.1, 0.2, 0.3]}))
    with pytest.raises(TypeError, match="scenario must be a Scenario"):
        src.frames("wire")
    with pytest.raises(TypeError, match="Opto5Config"):
        Opto5({"pitch_mm": 3.55})


# ---- offset and normalisation ---------------------------------------------------------------------------
@pytest.mark.parametrize("dtype", [np.float32, np.float64, np.uint16])
def test_remove_offset(dtype):
    v = np.zeros((60, 5, 5), dtype=dtype)
    v[:] = np.arange(25, dtype=dtype).reshape(5, 5)
    v[55:] += 3
    dv = remove_offset(v)
    assert dv.dtype == (np.float32 if dtype == np.float32 else np.float64)
    np.testing.assert_allclose(dv[:55], 0.0, atol=0)
    np.testing.assert_allclose(dv[55:], 3.0, atol=0)
    with pytest.raises(ShapeError, match="at least n=50 samples"):
        remove_offset(v[:10])


def test_lut_inverts_known_responses_exactly():
    # 25 taxels with their own gain and shape, all stimulated by u = 0 ... 1
    u = np.linspace(0, 1, 2001)
    rng = np.random.default_rng(0)
    g, k = rng.uniform(0.5, 2, 25), rng.uniform(-0.5, 2, 25)
    resp = g * -np.expm1(-np.outer(u, k)) / k
    lut = NormalisationLUT.from_closure(resp.reshape(-1, 5, 5), 3.0 * u)    # stimulus units cancel
    test_u = np.array([0.0, 0.1, 0.37, 0.8, 1.0])
    out = lut.apply((g * -np.expm1(-np.outer(test_u, k)) / k).reshape(-1, 5, 5))
    np.testing.assert_allclose(out, test_u[:, None, None] * np.ones((1, 5, 5)), rtol=0, atol=1e-6)
    # outside the table: clamp
    np.testing.assert_allclose(lut.apply(np.full((5, 5), 100.0)), 1.0, rtol=0, atol=0)
    np.testing.assert_allclose(lut.apply(np.full((5, 5), -1.0)), 0.0, rtol=0, atol=0)
    assert lut.apply(np.zeros((2, 3, 5, 5), np.float32)).dtype == np.float32
    assert set(lut.as_dict()) >= {"taxel", "row", "col", "n_knots"}


def test_lut_makes_equally_stimulated_taxels_equal(clean):
    src, lut, d_max = clean
    for depth in (0.3, 1.0, 1.6):
        raw = grasp(src, Indenter("flat"), depth)
        out = lut.apply(raw)
        assert raw.std() / raw.mean() > 0.3                       # raw: gains, shapes and flex differ
        np.testing.assert_allclose(out, depth / d_max, rtol=0, atol=0.04)
    # deeper than the closure: every taxel clamps to the top of its table (~1)
    top = np.reshape([v[-1] for v in lut.value_knots], (5, 5))
    np.testing.assert_array_equal(lut.apply(grasp(src, Indenter("flat"), 2.5)), top)
    assert np.all(top > 0.95)
    # with noise and 3 % repeatability the normalised spread stays small
    noisy = Opto5()
    dv, stim = calibration_closure(noisy, seed=1)
    norm = NormalisationLUT.from_closure(dv, stim).apply(grasp(noisy, Indenter("flat"), 1.0, seed=2))
    assert norm.std() / norm.mean() < 0.1
    assert abs(norm.mean() - 1.0 / stim.max()) < 0.03


def test_lut_errors():
    u = np.linspace(0, 1, 50)
    good = np.outer(u, np.ones(25)).reshape(-1, 5, 5)
    dead = good.copy()
    dead[:, 1, 2] = 0.0
    with pytest.raises(InputError, match=r"taxel \(1, 2\) does not respond"):
        NormalisationLUT.from_closure(dead, u)
    bump = good.copy()
    bump[:, 3, 4] = np.sin(np.pi * u)
    with pytest.raises(InputError, match=r"taxel \(3, 4\) responds non-monotonically"):
        NormalisationLUT.from_closure(bump, u)
    with pytest.raises(ShapeError, match=r"stimulus must have shape \(50,\)"):
        NormalisationLUT.from_closure(good, u[:-1])
    with pytest.raises(InputError, match="stimulus must be >= 0"):
        NormalisationLUT.from_closure(good, u - 0.5)
    with pytest.raises(ShapeError, match=r"dv_closure must have shape \(T, H, W\)"):
        NormalisationLUT.from_closure(good[:, 0], u)
    with pytest.raises(ShapeError, match=r"dv must have shape \(\.\.\., 5, 5\)"):
        NormalisationLUT.from_closure(good, u).apply(np.zeros((4, 4)))


# ---- wire shape ----------------------------------------------------------------------------------------
def curve_image(a, b, c, pitch=3.55):
    """Two-row images whose column centroids lie exactly on y = a x² + b x + c."""
    pos = (np.arange(5) - 2) * pitch
    img = np.zeros((5, 5))
    for j, x in enumerate(pos):
        y = a * x * x + b * x + c
        k = min(int(np.floor((y - pos[0]) / pitch)), 3)
        w = (pos[k + 1] - y) / pitch
        img[k, j], img[k + 1, j] = w, 1 - w
    return img


@pytest.mark.parametrize("coef", [(0.04, 0.25, -1.0), (-0.03, 0.1, -4.0), (0.0, 0.0, 6.0)])
def test_wire_shape_recovers_a_known_curve_exactly(coef):
    img = curve_image(*coef)
    cent = wire_centroids(img)
    lo, hi = cent["row_lo"][0], cent["row_hi"][0]
    spurious = next(r for r in range(5) if r < lo or r > hi)       # a bright cell outside the kept rows
    img[spurious, 2] = 0.45
    assert np.argmax(img[:, 2]) != spurious
    shape = wire_shape(img)
    assert shape.direction == "horizontal"
    np.testing.assert_allclose(shape[:3], coef, rtol=0, atol=1e-12)
    # the row selection matters: the centroid over all rows is pulled by the spurious cell
    pos = (np.arange(5) - 2) * 3.55
    assert abs(pos @ img[:, 2] / img[:, 2].sum() - cent["y_mm"][2]) > 0.1
    # a vertical wire swaps the axes: x = a y² + b y + c
    vertical = wire_shape(img.T)
    assert vertical.direction == "vertical"
    np.testing.assert_allclose(vertical[:3], coef, rtol=0, atol=1e-12)


def test_row_band_is_clipped_to_the_pad():
    img = curve_image(0.0, 0.05, -6.0)          # along the top edge: every column's maximum in row 0
    cent = wire_centroids(img)
    assert np.all(cent["i_max"] == 0) and cent["row_lo"][0] == 0 and cent["row_hi"][0] == 1
    np.testing.assert_allclose(wire_shape(img)[:3], (0.0, 0.05, -6.0), rtol=0, atol=1e-12)


def test_wire_shape_of_simulated_wires(clean):
    src, lut, _ = clean
    depth = float(src.depth_from_finger_distance(230, 3.0))
    h = wire_shape(lut.apply(grasp(src, Indenter("wire", 1.5), depth, y_mm=-1.2)))
    assert h.direction == "horizontal" and abs(h.a) < 0.01 and abs(h.b) < 0.05 and abs(h.c + 1.2) < 0.35
    v = wire_shape(lut.apply(grasp(src, Indenter("wire", 1.5), depth, x_mm=0.7, angle_rad=np.pi / 2)))
    assert v.direction == "vertical" and abs(v.a) < 0.01 and abs(v.b) < 0.05 and abs(v.c - 0.7) < 0.35


def test_wire_shape_errors():
    with pytest.raises(InputError, match="no positive cell"):
        wire_shape(np.zeros((5, 5)))
    with pytest.raises(ShapeError, match="2-D taxel image"):
        wire_shape(np.ones(25))
    with pytest.raises(InputError, match="direction must be one of"):
        wire_shape(np.ones((5, 5)), direction="diagonal")
    img = np.zeros((5, 5))
    img[2, :2] = 1.0
    with pytest.raises(InputError, match="at least 3 columns"):
        wire_shape(img, direction="horizontal")
    with pytest.raises(TypeError, match="real numeric"):
        wire_shape(np.full((5, 5), "a"))


# ---- diameter classification ---------------------------------------------------------------------------
def test_published_lookup_table_example():
    lut = LookupTableClassifier.from_table([218], DIAMETERS, [PUBLISHED_ROW])
    assert lut.predict(218, 3.2) == 2.5
    np.testing.assert_array_equal(lut.predict([218, 218, 218], [0.5, 5.0, 9.0]), [1.5, 3.5, 4.0])
    with pytest.raises(InputError, match=r"finger_distance must be in \[0, 255\]"):
        lut.predict(300, 3.2)
    with pytest.raises(ShapeError, match=r"table must have shape .* = \(1, 6\)"):
        LookupTableClassifier.from_table([218], DIAMETERS, [PUBLISHED_ROW[:5]])
    with pytest.raises(InputError, match="strictly increasing"):
        LookupTableClassifier.from_table([218, 210], DIAMETERS, [PUBLISHED_ROW, PUBLISHED_ROW])


def test_lookup_table_fit_means_and_fills_gaps():
    p = np.array([200, 200, 200, 210, 220, 220])
    total = np.array([1.0, 3.0, 10.0, 12.0, 2.0, 14.0])
    labels = np.array([1.5, 1.5, 3.0, 3.0, 1.5, 3.0])
    lut = LookupTableClassifier.fit(p, total, labels)
    np.testing.assert_array_equal(lut.finger_distance, [200, 210, 220])
    # class 1.5 has no sample at 210: filled linearly between 2.0 (200) and 2.0 (220)
    np.testing.assert_allclose(lut.table, [[2.0, 10.0], [2.0, 12.0], [2.0, 14.0]], rtol=0, atol=1e-12)
    np.testing.assert_array_equal(lut.predict([205, 205], [5.0, 8.0]), [1.5, 3.0])


def test_dataset_and_classifiers_are_deterministic_by_seed():
    a = wire_dataset(n_per_class=10, seed=3)
    b = wire_dataset(n_per_class=10, seed=3)
    np.testing.assert_array_equal(a.features(), b.features())
    assert a.features().shape == (70, 26) and sorted(set(a.diameter_mm)) == [0.0, *DIAMETERS]
    assert not np.array_equal(a.features(), wire_dataset(n_per_class=10, seed=4).features())
    assert classify_wires(a, seed=1) == classify_wires(b, seed=1)
    with pytest.raises(InputError, match="finger_range"):
        wire_dataset(n_per_class=2, finger_range=(200, 300))
    with pytest.raises(InputError, match="n_per_class must be >= 2"):
        wire_dataset(n_per_class=1)


def test_experiment_classifiers_beat_chance(result):
    cls = result["classification"]
    assert cls["classes_mm"] == [0.0, *DIAMETERS] and cls["chance"] == pytest.approx(1 / 7)
    for key in ("lookup_table", "svm", "mlp"):
        assert cls[key]["accuracy"] > 4 * cls["chance"]              # > 0.57
        cm = np.asarray(cls[key]["confusion"])
        assert cm.shape == (7, 7) and cm.sum() == cls["n_test"] == 140
        assert cls[key]["accuracy"] == pytest.approx(np.trace(cm) / cm.sum())
    assert cls["svm"]["accuracy"] > 0.85 and cls["mlp"]["accuracy"] > 0.85
    json.dumps(result)


def test_experiment_normalisation_matters(result, tmp_path):
    flat = result["normalisation"]["flat"]
    assert flat["raw_cv"] > 0.3 and flat["normalised_cv"] < 0.1
    edge = result["normalisation"]["edge_wire"]
    assert edge["normalised_mean_rms_mm"] < edge["raw_mean_rms_mm"]
    assert edge["ideal_mean_rms_mm"] < 0.3
    path = tmp_path / "opto5.png"
    optopad.plot_experiment(result, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="returned by experiment"):
        optopad.plot_experiment({}, path)
