import doctest
import json
import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.sources import Indenter, Scenario, TactileSource, make_source
from optitact.taxels import palpation
from optitact.taxels.palpation import (OBJECTS, GraspProtocol, PalpationObject, Thread8, Thread8Config,
                                       classify, cv_folds, dtw_distance, dtw_matrix, frame_features, grasp,
                                       knn_cv, palpation_dataset, palpation_distances)

KP = 100.0  # kPa/mm, default pad: 0.5 MPa / 5 mm


def dtw_reference(a, b):
    """Direct O(nm) dynamic programme: sqrt of the least summed squared distance along a warping path."""
    a = np.asarray(a, dtype=float).reshape(len(a), -1)
    b = np.asarray(b, dtype=float).reshape(len(b), -1)
    n, m = len(a), len(b)
    c = np.full((n + 1, m + 1), np.inf)
    c[0, 0] = 0.0
    for i in range(1, n + 1):
        for j in range(1, m + 1):
            cost = float(np.sum((a[i - 1] - b[j - 1]) ** 2))
            c[i, j] = cost + min(c[i - 1, j], c[i, j - 1], c[i - 1, j - 1])
    return math.sqrt(c[n, m])


def scenario(indenter, depth, *, rate=100.0, **pose):
    depth = np.asarray(depth, dtype=float)
    return Scenario(indenter, np.arange(depth.size) / rate, depth_mm=depth, **pose)


@pytest.fixture(scope="module")
def src():
    return Thread8()


@pytest.fixture(scope="module")
def result():
    return palpation.experiment(seed=0, full=False, progress=False)


def test_docstring_examples():
    assert doctest.testmod(palpation, optionflags=doctest.ELLIPSIS).failed == 0


# ---- source --------------------------------------------------------------------------------------------
def test_registered_source_and_layout():
    s = make_source("thread8")
    assert isinstance(s, TactileSource) and isinstance(s, Thread8) and s.name == "thread8"
    lay = s.layout
    assert lay.shape == (8, 8) and lay.pitch_mm == (2.5, 2.5) and lay.units == "DN" and lay.rate_hz == 100.0
    assert s.pad_area_mm2 == 400.0 and s.full_scale == 255
    assert make_source("thread8", unit_seed=4).config.unit_seed == 4
    with pytest.raises(ValueError, match="unknown config field"):
        make_source("thread8", colour=1)
    with pytest.raises(TypeError, match="Thread8Config"):
        Thread8(object())


@pytest.mark.parametrize("field, value, exc, match", [
    ("pitch_mm", 0.0, InputError, "pitch_mm must be finite and > 0"),
    ("r_pressed_ohm", 2e6, InputError, "r_pressed_ohm must be < r_free_ohm"),
    ("hysteresis", 0.5, InputError, r"hysteresis must be in \[0, 0.5\)"),
    ("creep_fraction", 1.0, InputError, r"creep_fraction must be in \[0, 1\)"),
    ("grid_mm", 0.3, InputError, "pitch_mm / grid_mm must be a positive integer"),
    ("adc_bits", 8.0, TypeError, "adc_bits must be an integer"),
    ("adc_bits", 20, InputError, "adc_bits must be <= 16"),
    ("noise_v", -0.1, InputError, "noise_v must be finite and >= 0"),
])
def test_config_validation(field, value, exc, match):
    with pytest.raises(exc, match=match):
        Thread8Config(**{field: value})


def test_resistance_law(src):
    c = src.config
    p = np.linspace(0.0, 2000.0, 4001)
    r = src.resistance_ohm(p)
    assert np.all(np.diff(r) < 0)                                                     # falls monotonically
    np.testing.assert_allclose(src.resistance_ohm(0.0), c.r_free_ohm, rtol=1e-3, atol=0)
    np.testing.assert_allclose(src.resistance_ohm(c.threshold_kpa - 5 * c.transition_kpa), c.r_free_ohm,
                               rtol=0.05, atol=0)
    assert 100e3 < float(src.resistance_ohm(c.threshold_kpa)) < 1e6                   # smooth onset
    np.testing.assert_allclose(src.resistance_ohm(1e9), c.r_pressed_ohm, rtol=1e-3, atol=0)
    # well above threshold: R - R_pressed = 1 / (1/(R_free - R_pressed) + e/rho), e = p - threshold
    e = 130.0
    want = c.r_pressed_ohm + 1.0 / (1.0 / (c.r_free_ohm - c.r_pressed_ohm) + e / c.r_coeff_ohm_kpa)
    np.testing.assert_allclose(src.resistance_ohm(c.threshold_kpa + e), want, rtol=1e-9, atol=0)
    with pytest.raises(InputError, match="pressure_kpa must be >= 0"):
        src.resistance_ohm(-1.0)


def test_flat_contact_and_divider_analytic(src):
    c = src.config
    depth = np.array([0.0, 0.2, 0.5, 1.0])
    st = src.contact(scenario(Indenter("flat"), depth))
    np.testing.assert_allclose(st["taxel_kpa"], (KP * depth)[:, None, None] * np.ones((1, 8, 8)),
                               rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(st["force_n"], KP * depth * 400.0 * 1e-3, rtol=1e-12, atol=1e-12)
    # loading, below creep: V = V+ R / (R_s(p) + R) with the per-taxel sensitivities
    v = src.voltage(st["taxel_kpa"])
    r_s = src.resistance_ohm(st["taxel_kpa"], sensitivity=src.sensitivity)
    np.testing.assert_allclose(v, c.v_plus * c.r_divider_ohm / (r_s + c.r_divider_ohm), rtol=1e-12, atol=0)
    # soft object in series with the pad: kappa = 1 / (1/kp + 1/ko), ko = k / A_pad
    soft = src.contact(scenario(Indenter("flat", stiffness_n_per_mm=4.0), depth))
    kappa = 1.0 / (1.0 / KP + 400.0 / 4e3)
    np.testing.assert_allclose(soft["taxel_kpa"][:, 3, 3], kappa * depth, rtol=1e-12, atol=1e-12)


def test_sphere_force_matches_winkler_cap_volume(src):
    radius, d = 10.0, 1.0
    st = src.contact(scenario(Indenter("sphere", size_mm=radius), [d]))
    cap = math.pi * d * d * (3 * radius - d) / 3                                      # mm³
    np.testing.assert_allclose(st["force_n"][0], KP * cap * 1e-3, rtol=0.01, atol=0)
    np.testing.assert_allclose(st["peak_kpa"][0], KP * d, rtol=0.01, atol=0)
    tax = st["taxel_kpa"][0]
    np.testing.assert_allclose(tax, tax[::-1, ::-1], rtol=0, atol=1e-9)             # centred: symmetric
    assert tax[0, 0] == 0.0 and tax[3, 3] > 0


@pytest.mark.parametrize("obj", [o for o in OBJECTS if o.indenter.shape != "flat"], ids=lambda o: o.name)
def test_moving_pose_path_matches_static_path(src, obj):
    depth = np.r_[np.linspace(0, 3, 40), np.linspace(3, 0.5, 40)]
    a = src.contact(scenario(obj.indenter, depth, x_mm=1.0, y_mm=-0.7, angle_rad=0.4))
    b = src.contact(scenario(obj.indenter, depth, x_mm=np.r_[1.0 + 1e-12, np.ones(79)], y_mm=-0.7,
                             angle_rad=0.4))
    np.testing.assert_allclose(a["taxel_kpa"], b["taxel_kpa"], rtol=0, atol=1e-9)


def test_plastic_object_unloads_faster(src):
    k, phi, dmax = 4.0, 0.5, 3.0
    depth = np.r_[np.linspace(0, dmax, 31), np.linspace(dmax, 0, 31)[1:]]
    elastic = src.contact(scenario(Indenter("flat", stiffness_n_per_mm=k), depth))["taxel_kpa"][:, 4, 4]
    plastic = src.contact(scenario(Indenter("flat", stiffness_n_per_mm=k, plasticity=phi),
                                   depth))["taxel_kpa"][:, 4, 4]
    kappa = 1.0 / (1.0 / KP + 400.0 / (1e3 * k))
    set_ = phi * kappa / (1e3 * k / 400.0) * dmax                                      # residual set, mm
    unload = kappa * dmax * np.clip((depth - set_) / (dmax - set_), 0, 1)
    want = np.r_[kappa * depth[:31], unload[31:]]
    np.testing.assert_allclose(plastic, want, rtol=0, atol=1e-9)
    np.testing.assert_allclose(elastic, kappa * depth, rtol=0, atol=1e-9)
    assert plastic[-1] == 0 and np.all(plastic[31:] <= elastic[31:] + 1e-12)


def test_force_mode_round_trip(src):
    ind = Indenter("sphere", size_mm=15.0, stiffness_n_per_mm=8.0, plasticity=0.6)
    depth = np.r_[np.linspace(0, 2, 8), np.linspace(2, 0.8, 6)]
    st = src.contact(scenario(ind, depth, x_mm=0.5))
    sc = Scenario(ind, np.arange(depth.size) / 100.0, x_mm=0.5, force_n=st["force_n"])
    back = src.contact(sc)
    loaded = st["force_n"] > 0
    np.testing.assert_allclose(back["depth_mm"][loaded], depth[loaded], rtol=1e-7, atol=0)
    np.testing.assert_allclose(back["taxel_kpa"], st["taxel_kpa"], rtol=0, atol=1e-6)


def test_hysteresis_and_creep_analytic(src):
    c = src.config
    p = np.r_[np.linspace(0, 100, 11), np.linspace(100, 0, 11)[1:]]
    eff = src.effective_kpa(p[:, None, None] * np.ones((1, 8, 8)))[:, 0, 0]
    np.testing.assert_allclose(eff[:11], p[:11], rtol=0, atol=1e-12)                # loading branch
    np.testing.assert_allclose(eff[15], 50 + c.hysteresis * 100, rtol=0, atol=1e-9)  # q = 0.5: widest gap
    # hold at 400 kPa: first-order drift to p (1 + f (1 - p_c / p)) with tau
    hold = np.full((200, 8, 8), 400.0)
    eff = src.effective_kpa(hold)[:, 0, 0]
    c_inf = c.creep_fraction * (1 - c.creep_kpa / 400.0)
    n = int(round(c.creep_tau_s * c.rate_hz))
    np.testing.assert_allclose(eff[n - 1], 400 * (1 + c_inf * (1 - math.exp(-1))), rtol=1e-12, atol=0)
    assert np.all(np.diff(eff) > 0) and eff[-1] < 400 * (1 + c_inf)
    below = src.effective_kpa(np.full((50, 8, 8), 150.0))
    np.testing.assert_allclose(below, 150.0, rtol=0, atol=1e-12)                    # no creep below p_c


def test_frames_dtype_baseline_and_seed(src):
    sc = scenario(OBJECTS[1].indenter, np.r_[np.zeros(100), np.linspace(0, 2, 50)], x_mm=0.3)
    a = src.frames(sc, seed=5)
    assert a.dtype == np.uint8 and a.shape == (150, 8, 8)
    np.testing.assert_array_equal(a, src.frames(sc, seed=5))
    assert not np.array_equal(a, src.frames(sc, seed=6))
    free = 255 * 10e3 / (1e6 + 10e3)                                                   # R / (R_free + R)
    assert abs(a[:100].mean() - free) < 0.1
    assert a[-1].max() > 150


@pytest.mark.parametrize("bad, exc, match", [
    (lambda: Scenario(Indenter("wire"), [0.0], depth_mm=0.0), InputError, "simulates indenters"),
    (lambda: Scenario(Indenter("flat"), [0.0], depth_mm=0.0, extra={"spin": 1}), InputError, "extra"),
    (lambda: "scenario", TypeError, "scenario must be a Scenario"),
    (lambda: Scenario(Indenter("sphere", size_mm=1.0), [0.0], x_mm=50.0, force_n=1.0), InputError,
     "cannot be reached"),
])
def test_frames_bad_input(src, bad, exc, match):
    with pytest.raises(exc, match=match):
        src.frames(bad(), seed=0)


# ---- grasps ----------------------------------------------------------------------------------------------
def test_grasp_protocol_and_seed():
    proto = GraspProtocol()
    g = grasp(OBJECTS[1], seed=3)
    steps = proto.step_profile(100.0)
    n_move, n_hold = 10, 40
    assert steps.size == 2 * proto.n_steps * (n_move + n_hold)
    assert g.left.shape == g.right.shape == (g.contact_frame + 1 + steps.size, 8, 8)
    d_c = g.depth_mm[g.contact_frame]
    np.testing.assert_allclose(g.depth_mm.max(), d_c + proto.n_steps * proto.step_mm / 2, rtol=0, atol=1e-12)
    np.testing.assert_allclose(g.depth_mm[-1], d_c, rtol=0, atol=1e-12)
    assert g.left[g.contact_frame].max() >= 10 and g.left[: max(g.contact_frame - 5, 1)].max() < 10
    same = grasp(OBJECTS[1], seed=3)
    np.testing.assert_array_equal(g.left, same.left)
    np.testing.assert_array_equal(g.right, same.right)
    other = grasp(OBJECTS[1], seed=4)
    assert (other.x_mm, other.left.shape) != (g.x_mm, g.left.shape) or not np.array_equal(other.left, g.left)
    with pytest.raises(TypeError, match="PalpationObject"):
        grasp(OBJECTS[0].indenter, seed=0)
    with pytest.raises(TypeError, match="pair"):
        grasp(OBJECTS[0], seed=0, sensors=(Thread8(),))
    with pytest.raises(InputError, match="clearance_mm"):
        GraspProtocol(clearance_mm=(3.0, 1.0))
    with pytest.raises(InputError, match="object indenter shape"):
        PalpationObject("wire", Indenter("wire"), 5.0)


def test_dataset_seed_and_table():
    objs = (OBJECTS[0], OBJECTS[3])
    a = palpation_dataset(n_per_object=2, seed=1, objects=objs)
    b = palpation_dataset(n_per_object=2, seed=1, objects=objs)
    assert len(a) == 4 and a.names == ("rigid block", "wooden bar")
    np.testing.assert_array_equal(a.labels, [0, 0, 1, 1])
    for fa, fb in zip(a.left + a.right, b.left + b.right, strict=True):
        np.testing.assert_array_equal(fa, fb)
    table = a.as_dict()
    assert len({len(v) for v in table.values()}) == 1 and list(table["object"][:1]) == ["rigid block"]
    f = a.features("left")[0]
    ff = frame_features(a.left[0])
    np.testing.assert_allclose(f, np.stack([ff["mu"], ff["sigma"]], axis=1), rtol=0, atol=1e-12)
    with pytest.raises(InputError, match="unique"):
        palpation_dataset(n_per_object=1, objects=(OBJECTS[0], OBJECTS[0]))


# ---- features and DTW ---------------------------------------------------------------------------------
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


def test_dtw_matches_dynamic_programming_reference():
    rng = np.random.default_rng(7)
    for d in (1, 2):
        series = [rng.normal(size=(n, d)).squeeze(axis=1) if d == 1 else rng.normal(size=(n, d))
                  for n in (5, 9, 12, 7, 1)]
        mat = dtw_matrix(series)
        ref = np.array([[dtw_reference(a, b) for b in series] for a in series])
        np.testing.assert_allclose(mat, ref, rtol=1e-10, atol=1e-12)
        np.testing.assert_allclose(dtw_distance(series[1], series[2]), ref[1, 2], rtol=1e-10, atol=0)
    # warping absorbs repeated samples; unequal values add up in quadrature
    assert dtw_distance([0, 1, 1, 1, 2], [0, 1, 2]) == 0.0
    np.testing.assert_allclose(dtw_distance(np.zeros((2, 2)), np.full((3, 2), 1.0)), math.sqrt(6), rtol=1e-12)


@pytest.mark.parametrize("bad, exc, match", [
    ([[0.0, np.nan], [1.0]], InputError, "must be finite"),
    ([np.zeros(3), np.zeros((3, 2))], ShapeError, "same d"),
    ([np.zeros((2, 2, 2)), np.zeros(2)], ShapeError, "non-empty"),
    ([np.zeros(3)], InputError, "at least two"),
    ("abc", TypeError, "sequence"),
])
def test_dtw_bad_input(bad, exc, match):
    with pytest.raises(exc, match=match):
        dtw_matrix(bad)


# ---- cross validation and k-NN -----------------------------------------------------------------------
def test_cv_folds_disjoint_stratified_and_seeded():
    labels = np.repeat(np.arange(4), 10)
    folds = cv_folds(labels, n_folds=10, seed=3)
    tests = [te for _, te in folds]
    assert len(folds) == 10
    np.testing.assert_array_equal(np.sort(np.concatenate(tests)), np.arange(40))   # disjoint, cover all
    for tr, te in folds:
        assert np.intersect1d(tr, te).size == 0 and tr.size + te.size == 40
        np.testing.assert_array_equal(np.bincount(labels[te], minlength=4), [1, 1, 1, 1])  # equal shares
    again = cv_folds(labels, n_folds=10, seed=3)
    assert all(np.array_equal(a[1], b[1]) for a, b in zip(folds, again, strict=True))
    other = cv_folds(labels, n_folds=10, seed=4)
    assert not all(np.array_equal(a[1], b[1]) for a, b in zip(folds, other, strict=True))
    with pytest.raises(InputError, match="at least n_folds = 10 samples"):
        cv_folds(np.repeat([0, 1], 5), n_folds=10)
    with pytest.raises(TypeError, match="integer array"):
        cv_folds(np.array([0.0, 1.0]))


def test_knn_cv_rates_and_t_interval():
    from scipy.stats import t as student_t

    rng = np.random.default_rng(1)
    labels = np.repeat(np.arange(3), 10)
    x = labels + rng.normal(scale=0.45, size=labels.size)
    d = np.abs(x[:, None] - x[None, :])
    res = knn_cv(d, labels, ks=(1, 3, 5), n_folds=10, seed=0)
    assert list(res["k"]) == [1, 3, 5] and res["fold_rates"].shape == (3, 10)
    r = res["fold_rates"][0]
    half = student_t.ppf(0.975, 9) * r.std(ddof=1) / math.sqrt(10)
    np.testing.assert_allclose(res["mean"][0], r.mean(), rtol=0, atol=1e-15)
    np.testing.assert_allclose([res["ci_low"][0], res["ci_high"][0]],
                               [max(0, r.mean() - half), min(1, r.mean() + half)], rtol=0, atol=1e-12)
    assert np.all(res["mean"] > 0.6)
    # 1-NN by hand on the first fold
    tr, te = cv_folds(labels, n_folds=10, seed=0)[0]
    pred = labels[tr][np.argmin(d[np.ix_(te, tr)], axis=1)]
    np.testing.assert_allclose(r[0], np.mean(pred == labels[te]), rtol=0, atol=1e-15)
    with pytest.raises(ShapeError, match="square"):
        knn_cv(np.zeros((3, 4)), [0, 1, 2])
    with pytest.raises(InputError, match="symmetric"):
        knn_cv(np.triu(np.ones((20, 20))), np.repeat([0, 1], 10), n_folds=2)
    with pytest.raises(ShapeError, match=r"labels must have shape \(30,\)"):
        knn_cv(d, labels[:-1])
    with pytest.raises(InputError, match="smallest training fold"):
        knn_cv(d, labels, ks=(28,), n_folds=10)


# ---- the study -----------------------------------------------------------------------------------------
def test_experiment_table_far_above_chance(result, tmp_path):
    back = json.loads(json.dumps(result))
    table = back["table"]
    assert len(table["metric"]) == 9 * 3 and len({len(v) for v in table.values()}) == 1
    assert set(table["metric"]) == {f"{f}/{s}" for f in palpation.FEATURES for s in palpation.SENSORS}
    assert back["chance"] == 0.25 and back["n_folds"] == 5
    mean = np.array(table["mean"])
    assert np.all(np.array(table["ci_low"]) <= mean + 1e-12)
    assert np.all(mean <= np.array(table["ci_high"]) + 1e-12)
    assert mean.mean() >= 0.85 and mean.min() >= 0.6                                  # chance: 0.25
    best = [v for m, k, v in zip(table["metric"], table["k"], mean, strict=True)
            if (m, k) == ("mu+sigma/both", 1)]
    assert len(best) == 1 and best[0] >= 0.9
    path = tmp_path / "palpation.png"
    palpation.plot_experiment(back, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="experiment"):
        palpation.plot_experiment({"table": {}}, path)


def test_distances_normalised_and_classify_shape():
    data = palpation_dataset(n_per_object=2, seed=2, objects=(OBJECTS[1], OBJECTS[3]))
    dist = palpation_distances(data)
    assert list(dist) == [f"{f}/{s}" for f in palpation.FEATURES for s in palpation.SENSORS]
    for d in dist.values():
        assert d.shape == (4, 4) and np.isclose(d.max(), 1.0) and np.all(np.diag(d) == 0)
        np.testing.assert_allclose(d, d.T, rtol=0, atol=0)
    mu = [f[:, 0] for f in data.features("left")]
    raw = dtw_matrix(mu)
    np.testing.assert_allclose(dist["mu/left"], raw / raw.max(), rtol=1e-12, atol=0)
    table = classify({"mu/left": dist["mu/left"]}, data.labels, ks=(1,), n_folds=2, seed=0)
    assert table["metric"] == ["mu/left"] and table["k"] == [1] and len(table["fold_rates"][0]) == 2
