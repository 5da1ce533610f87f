import doctest
import json
import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.sources import Indenter, Layout, Scenario, TactileSource, make_source
from optitact.taxels import tracing
from optitact.taxels.tracing import (FINGER_PAD_MASK, Piezo16, Piezo16Config, WidthClassifier,
                                     combined_distribution, diameter_resolution, features, pair_separation,
                                     radial_line, trace, tracing_dataset, unit_voltage)

PITCH = 2.2
FULL_MASK = ("#" * 16,) * 16


def scenario(indenter, depth, *, n=1, **pose):
    return Scenario(indenter, np.arange(n) / 1000.0, depth_mm=depth, **pose)


@pytest.fixture(scope="module")
def src():
    return Piezo16()


@pytest.fixture(scope="module")
def ideal():
    """No readout noise, no gain spread: outputs follow the law exactly."""
    return Piezo16(Piezo16Config(noise_v=0.0, unit_gain_spread=0.0))


@pytest.fixture(scope="module")
def result():
    return tracing.experiment(seed=0, full=False, progress=False)


def test_docstring_examples():
    assert doctest.testmod(tracing, optionflags=doctest.ELLIPSIS).failed == 0


# ---- the response law ----------------------------------------------------------------------------------
def test_law_published_values():
    assert unit_voltage(1.0, 1.0) == pytest.approx(3.06, rel=0, abs=1e-12)
    assert unit_voltage(0.25, 1.0) == pytest.approx(0.4725, rel=0, abs=1e-12)   # "0.47 V for 25 %"
    # 50 % area: silent below q = 0.39 / (3.45 * 0.5) = 0.2261 mm ("about 0.23 mm")
    q = np.array([0.0, 0.1, 0.2, 0.226, 0.227, 0.25])
    v = unit_voltage(0.5, q)
    assert np.all(v[:4] == 0.0) and np.all(v[4:] > 0)
    np.testing.assert_allclose(v[4:], 3.45 * 0.5 * q[4:] - 0.39, rtol=0, atol=1e-12)
    assert unit_voltage(0.0, 5.0) == 0.0


def test_law_vectorised_broadcast():
    p = np.linspace(0, 1, 5)[:, None]
    q = np.linspace(0, 1.5, 7)[None, :]
    v = unit_voltage(p, q)
    assert v.shape == (5, 7) and v.dtype == np.float64
    np.testing.assert_allclose(v, np.maximum(0.0, 3.45 * p * q - 0.39), rtol=0, atol=1e-12)
    assert unit_voltage(1.0, 1.0, gain_v_per_mm=1.0, offset_v=0.0) == 1.0


@pytest.mark.parametrize("p,q,exc,match", [
    (1.1, 0.5, InputError, "p .pressed area fraction. must be in"),
    (-0.1, 0.5, InputError, "p .pressed area fraction"),
    (0.5, -0.1, InputError, "q .compression. must be >= 0"),
    (np.nan, 0.5, InputError, "p must be finite"),
    (0.5, np.inf, InputError, "q must be finite"),
    ([0.5, 0.5], [0.1, 0.2, 0.3], ShapeError, "must broadcast"),
    ("a", 0.5, TypeError, "p must be a real numeric array"),
])
def test_law_bad_input(p, q, exc, match):
    with pytest.raises(exc, match=match):
        unit_voltage(p, q)


# ---- the source ----------------------------------------------------------------------------------------
def test_registered_source_and_layout():
    s = make_source("piezo16")
    assert isinstance(s, TactileSource) and isinstance(s, Piezo16) and s.name == "piezo16"
    lay = s.layout
    assert lay.shape == (16, 16) and lay.units == "V" and lay.rate_hz == 1000.0
    np.testing.assert_allclose(lay.pitch_mm, (PITCH, PITCH), rtol=0, atol=1e-12)
    assert lay.n_cells == 204
    m = lay.mask
    assert np.array_equal(m, m[:, ::-1])                        # left-right symmetric pad
    assert m[8:12].all() and not m[0, 0] and not m[15, 15]       # full middle rows, rounded corners
    assert m[0].sum() < m[15].sum()                              # rounder at the fingertip than at the base
    assert make_source("piezo16", noise_v=0.0).config.noise_v == 0.0
    with pytest.raises(ValueError, match="unknown config field"):
        make_source("piezo16", colour=1)


@pytest.mark.parametrize("kwargs,exc,match", [
    ({"mask": FINGER_PAD_MASK[:15]}, ShapeError, "mask must be 16 strings of 16 characters"),
    ({"mask": ("#" * 15,) * 16}, ShapeError, "mask must be 16 strings"),
    ({"mask": ("x" * 16,) * 16}, InputError, "mask characters must be"),
    ({"mask": ("." * 16,) * 16}, InputError, "at least one unit"),
    ({"mask": "#" * 256}, TypeError, "mask must be a tuple of row strings"),
    ({"grid_mm": 0.3}, InputError, "electrode_mm / grid_mm must be an integer"),
    ({"noise_v": -0.1}, InputError, "noise_v must be finite and >= 0"),
    ({"elastomer_mm": 0.0}, InputError, "elastomer_mm must be finite and > 0"),
    ({"unit_seed": 1.5}, TypeError, "unit_seed must be an integer"),
    ({"grid": (16,)}, TypeError, "grid must be a pair"),
])
def test_config_validation(kwargs, exc, match):
    with pytest.raises(exc, match=match):
        Piezo16Config(**kwargs)


def test_unit_gains_deterministic():
    a, b = Piezo16(Piezo16Config(unit_seed=3)), Piezo16(Piezo16Config(unit_seed=3))
    assert np.array_equal(a.unit_gain, b.unit_gain)
    assert not np.array_equal(a.unit_gain, Piezo16(Piezo16Config(unit_seed=4)).unit_gain)
    g = a.unit_gain[a.layout.mask]
    assert np.all(a.unit_gain[~a.layout.mask] == 0) and 0.1 > abs(np.log(g).std() - 0.1)


@pytest.mark.parametrize("depth", [0.3, 0.7, 1.2])
def test_flat_press_follows_law_exactly(ideal, depth):
    # a flat plate compresses every electrode fully by the pressing depth (the kernel conserves it)
    sc = scenario(Indenter("flat"), depth)
    state = ideal.compression(sc)
    mask = ideal.layout.mask
    np.testing.assert_allclose(state["pressed_fraction"][0][mask], 1.0, rtol=0, atol=0)
    np.testing.assert_allclose(state["compression_mm"][0][mask], depth, rtol=0, atol=1e-12)
    f = ideal.frames(sc)
    assert f.shape == (1, 16, 16) and f.dtype == np.float64
    np.testing.assert_allclose(f[0][mask], 3.45 * depth - 0.39, rtol=0, atol=1e-12)
    assert np.all(f[0][~mask] == 0)


def test_small_compression_in_dead_zone():
    # 0.1 mm everywhere: 3.45 * 0.1 - 0.39 = -0.045 V, 9 noise sigmas below 0 -> exactly 0 despite the noise
    s = Piezo16(Piezo16Config(unit_gain_spread=0.0))
    assert np.all(s.frames(scenario(Indenter("flat"), 0.1, n=5), seed=1) == 0.0)
    assert np.all(s.frames(scenario(Indenter("flat"), 0.0), seed=1) == 0.0)
    # 0.2 mm: 0.3 V above zero; the noise shows
    v = s.frames(scenario(Indenter("flat"), 0.2, n=5), seed=1)[:, s.layout.mask]
    assert abs(v.mean() - (0.69 - 0.39)) < 0.001 and 0.004 < v.std() < 0.006


def _line_kernel(h, cutoff, x):
    """Line integral along y of the Boussinesq kernel 3h^3 / (2 pi (r^2 + h^2)^2.5), cut at r = cutoff h."""
    a2 = x * x + h * h
    ymax = np.sqrt(np.clip((cutoff * h) ** 2 - x * x, 0.0, None))
    prim = ymax * (2 * ymax ** 2 + 3 * a2) / (3 * a2 ** 2 * (a2 + ymax ** 2) ** 1.5)
    return 2 * prim


def test_pipe_compression_matches_line_spreading(ideal):
    # independent truth: the pipe's 1-D indentation profile convolved with the analytic line kernel
    radius, depth, x0, h, cut = 10.0, 0.7, 0.37, 2.0, 4.0
    sc = scenario(Indenter("cylinder", size_mm=radius), depth, x_mm=x0, angle_rad=math.pi / 2)
    state = ideal.compression(sc)
    pq = state["mean_compression_mm"][0]
    mask = ideal.layout.mask
    for r in range(16):                         # a long pipe along y: every row reads the same
        np.testing.assert_allclose(pq[r][mask[r]], pq[9][mask[r]], rtol=0, atol=1e-9)
    g = 0.005
    xs = np.arange(-40, 40 + g / 2, g)
    surface = radius - np.sqrt(np.clip(radius ** 2 - (xs - x0) ** 2, 0, None))
    u = np.where(np.abs(xs - x0) < radius, np.clip(depth - surface, 0, None), 0.0)
    kx = np.arange(-cut * h, cut * h + g / 2, g)
    k = _line_kernel(h, cut, kx)
    w = np.convolve(u, k / k.sum(), mode="same")
    centres = (np.arange(16) - 7.5) * PITCH
    expected = np.array([w[np.abs(xs - c) <= 1.0].mean() for c in centres])
    np.testing.assert_allclose(pq[9], expected, rtol=0, atol=1.5e-3)   # untruncated Flamant differs by 3e-3
    # the elastomer spreads: electrodes wholly outside the rigid contact (half width sqrt(2 R d) = 3.74 mm)
    # are compressed, and the peak is lower than the pressing depth
    assert pq[9].max() < depth - 0.05
    assert np.any((np.abs(centres - x0) - 1.0 > math.sqrt(2 * radius * depth)) & (pq[9] > 0.03))
    # p·q is the electrode-mean compression, and p is a fraction
    p, q = state["pressed_fraction"][0], state["compression_mm"][0]
    assert np.all((p >= 0) & (p <= 1))
    np.testing.assert_allclose(p * q, pq, rtol=0, atol=1e-12)


def test_sphere_position_convention(ideal):
    # a sphere over cell (row 9, col 12): x along columns, y along rows, origin at the grid centre
    x, y = (12 - 7.5) * PITCH, (9 - 7.5) * PITCH
    f = ideal.frames(scenario(Indenter("sphere", size_mm=5.0), 0.8, x_mm=x, y_mm=y))[0]
    assert np.unravel_index(np.argmax(f), f.shape) == (9, 12)
    np.testing.assert_allclose(f[9, 11], f[9, 13], rtol=0, atol=1e-9)
    np.testing.assert_allclose(f[8, 12], f[10, 12], rtol=0, atol=1e-9)


@pytest.mark.parametrize("sc,match", [
    (scenario(Indenter("box"), 0.5), "simulates indenters"),
    (Scenario(Indenter("flat"), np.arange(2) / 1e3, force_n=1.0), "needs depth_mm"),
    (scenario(Indenter("sphere", size_mm=5.0), 2.5), "depth_mm must be < the pad thickness 2.5"),
    (scenario(Indenter("sphere", size_mm=5.0, stiffness_n_per_mm=10.0), 0.5), "rigid indenters"),
    (Scenario(Indenter("flat"), [0.0], depth_mm=0.5, extra={"colour": 1}), "unknown Scenario.extra"),
])
def test_frames_bad_scenario(src, sc, match):
    with pytest.raises(InputError, match=match):
        src.frames(sc)


def test_frames_not_a_scenario(src):
    with pytest.raises(TypeError, match="scenario must be a Scenario"):
        src.frames("pipe")


# ---- tracing ---------------------------------------------------------------------------------------------
def test_trace_deterministic_by_seed(src):
    a = trace(src, 20.0, 4, seed=7, offset_mm=0.5)
    assert a.shape == (4, 16, 16)
    assert np.array_equal(a, trace(src, 20.0, 4, seed=7, offset_mm=0.5))
    assert not np.array_equal(a, trace(src, 20.0, 4, seed=8, offset_mm=0.5))


def test_trace_positions(ideal):
    # step j puts the pipe's axis at (offset - j W/N) along the tracing direction (+x for an axis along y)
    n, off = 4, 0.3
    got = trace(ideal, 16.0, n, offset_mm=off, angle_rad=math.pi / 2, samples_per_step=2)
    pos = off - np.arange(n) * 2.0 / n
    sc = Scenario(Indenter("cylinder", size_mm=8.0), np.arange(n) / 1e3, x_mm=pos, angle_rad=math.pi / 2,
                  depth_mm=0.7)
    want = ideal.frames(sc)
    np.testing.assert_allclose(got[0::2], want, rtol=0, atol=1e-12)
    np.testing.assert_allclose(got[1::2], want, rtol=0, atol=1e-12)


def test_trace_direction_follows_axis():
    # on a full square pad, a pipe along x traced along +y is the transpose of a pipe along y traced along +x
    s = Piezo16(Piezo16Config(mask=FULL_MASK, noise_v=0.0, unit_gain_spread=0.0))
    a = trace(s, 20.0, 2, offset_mm=0.4, angle_rad=0.0)
    b = trace(s, 20.0, 2, offset_mm=0.4, angle_rad=math.pi / 2)
    np.testing.assert_allclose(a, b.transpose(0, 2, 1), rtol=0, atol=1e-9)
    assert radial_line(a, layout=s.layout)[0] == "y" and radial_line(b, layout=s.layout)[0] == "x"


@pytest.mark.parametrize("kwargs,exc,match", [
    ({"n_steps": 0}, InputError, "n_steps must be >= 1"),
    ({"n_steps": 2.0}, TypeError, "n_steps must be an integer"),
    ({"diameter_mm": -1.0}, InputError, "diameter_mm must be finite and > 0"),
    ({"offset_mm": math.nan}, InputError, "offset_mm must be a finite number"),
    ({"angle_rad": "x"}, TypeError, "angle_rad must be a real number"),
    ({"samples_per_step": 0}, InputError, "samples_per_step must be >= 1"),
    ({"seed": -1}, InputError, "seed must be >= 0"),
])
def test_trace_bad_input(src, kwargs, exc, match):
    args = {"diameter_mm": 20.0, "n_steps": 2, **kwargs}
    with pytest.raises(exc, match=match):
        trace(src, args.pop("diameter_mm"), args.pop("n_steps"), **args)


# ---- the combined distribution ---------------------------------------------------------------------------
def coded_frames(n, *, row=9, col=None):
    f = np.zeros((n, 16, 16))
    for j in range(n):
        if col is None:
            f[j, row, :] = 100 * j + np.arange(16) + 1
        else:
            f[j, :, col] = 100 * j + np.arange(16) + 1
    return f


@pytest.mark.parametrize("n", [1, 2, 3, 8])
def test_interleaving_order(n):
    f = coded_frames(n)
    f[:, 10, :] = 0.5                           # a weaker row: not chosen
    before = f.copy()
    comb = combined_distribution(f, n, radial_axis="x")
    assert comb.shape == (16 * n,)
    for i in range(16):
        for j in range(n):
            assert comb[i * n + j] == f[j, 9, i]
    assert np.array_equal(f, before)            # input untouched
    assert comb[:2 * n].tolist() == [100 * j + 1 for j in range(n)] + [100 * j + 2 for j in range(n)]


def test_interleaving_along_columns_and_auto_axis():
    n = 4
    f = coded_frames(n, col=6)
    comb = combined_distribution(f, n, radial_axis="y")
    want = np.array([f[j, i, 6] for i in range(16) for j in range(n)])
    assert np.array_equal(comb, want)
    # a pipe stripe along y (radial along x): auto picks rows, and the row with the highest output
    stripe = np.zeros((n, 16, 16))
    stripe[:, :, 6:9] = 1.0
    stripe[:, 11, 6:9] = 1.5
    assert radial_line(stripe) == ("x", 11)
    assert radial_line(stripe.transpose(0, 2, 1)) == ("y", 11)


def test_samples_per_step_are_averaged_and_mask_ignored():
    n, k = 2, 3
    base = coded_frames(n)
    f = np.repeat(base, k, axis=0)
    f[0::k] += 0.3
    f[1::k] -= 0.3
    f[:, 0, 0] = 1e6                            # outside the finger-pad mask: ignored
    np.testing.assert_allclose(combined_distribution(f, n), combined_distribution(base, n), rtol=0, atol=1e-12)


@pytest.mark.parametrize("frames,n,exc,match", [
    (np.zeros((2, 16, 15)), 2, ShapeError, r"frames must have shape \(16, 16\)"),
    (np.zeros((2, 12, 12)), 2, ShapeError, r"frames must have shape"),
    (np.full((2, 16, 16), np.nan), 2, InputError, "frames must be finite"),
    (np.zeros((7, 16, 16)), 2, ShapeError, "number of frames must be a multiple of n_steps = 2"),
    (np.zeros((4, 16, 16)), 3, ShapeError, "multiple of n_steps = 3 .samples per step., got 4 frames"),
    (np.zeros((4, 16, 16)), 0, InputError, "n_steps must be >= 1"),
    (np.zeros((4, 16, 16)), 2.0, TypeError, "n_steps must be an integer"),
    (np.zeros((4, 16, 16), dtype=complex), 2, TypeError, "real numeric array"),
])
def test_combined_bad_input(frames, n, exc, match):
    with pytest.raises(exc, match=match):
        combined_distribution(frames, n)


def test_combined_other_layout_and_bad_axis():
    lay = Layout(shape=(2, 3), pitch_mm=(2.0, 2.0), units="V", rate_hz=100.0)
    f = np.arange(12, dtype=float).reshape(2, 2, 3)
    assert combined_distribution(f, 2, layout=lay, radial_axis="x").tolist() == [3, 9, 4, 10, 5, 11]
    with pytest.raises(InputError, match="radial_axis must be 'x', 'y' or None"):
        combined_distribution(f, 2, layout=lay, radial_axis="z")
    with pytest.raises(TypeError, match="layout must be a Layout"):
        combined_distribution(f, 2, layout="piezo16")


# ---- features ----------------------------------------------------------------------------------------------
@pytest.mark.parametrize("comb,width,mad", [
    ([0, 0, 1.0, 3.0, 2.0, 0, 0], 3, 1.5),          # |3-1|, |2-3|
    ([0, 1.0, 0, 2.0, 0], 2, 1.5),                  # span [1, 0, 2]: a dip inside counts
    ([1.0, 2.0, 3.0, 4.0], 4, 1.0),
    ([0.0, 0.0, 0.0], 0, 0.0),
    ([0.0, 5.0, 0.0], 1, 0.0),
    ([0.5, 0.0, 0.0, 0.0, 0.25], 2, 0.1875),        # (0.5 + 0.25) / 4
])
def test_features_hand_made(comb, width, mad):
    w, m = features(comb)
    assert isinstance(w, int) and isinstance(m, float)
    assert w == width
    assert m == pytest.approx(mad, rel=0, abs=1e-12)


def test_features_of_a_triangle_sampled_finer():
    # a triangle of height 1 sampled N times finer: width N-fold, neighbour difference 1/N-fold
    x = np.linspace(-3, 3, 7)
    coarse = features(np.clip(1 - np.abs(x) / 3, 0, None))
    fine = features(np.clip(1 - np.abs(np.linspace(-3, 3, 25)) / 3, 0, None))
    assert (coarse[0], fine[0]) == (5, 23)
    assert coarse[1] == pytest.approx(1 / 3, abs=1e-12) and fine[1] == pytest.approx(1 / 12, abs=1e-12)


@pytest.mark.parametrize("comb,exc,match", [
    (np.zeros((2, 3)), ShapeError, "non-empty 1-D"),
    ([], ShapeError, "non-empty 1-D"),
    ([0.0, np.nan], InputError, "combined must be finite"),
    (["a"], TypeError, "real numeric array"),
])
def test_features_bad_input(comb, exc, match):
    with pytest.raises(exc, match=match):
        features(comb)


# ---- classifier and resolution -----------------------------------------------------------------------------
def test_width_classifier_thresholds():
    w = np.array([9, 3, 3, 5, 5, 4, 6])
    d = np.array([30, 10, 10, 20, 20, 10, 20])
    before = w.copy()
    clf = WidthClassifier.fit(w, d)
    assert np.array_equal(w, before)
    np.testing.assert_allclose(clf.mean_widths, [10 / 3, 16 / 3, 9], rtol=0, atol=1e-12)
    np.testing.assert_allclose(clf.thresholds, [13 / 3, 43 / 6], rtol=0, atol=1e-12)
    assert clf.predict([0, 13 / 3, 4.3, 7.0, 7.2, 50]).tolist() == [10, 20, 10, 20, 30, 30]
    assert clf.score(w, d) == 1.0 and clf.score([4.5, 3, 8], [10, 10, 30]) == pytest.approx(2 / 3)
    assert clf.as_dict()["upper_threshold"][-1] is None
    # classes are ordered by mean width, not by diameter
    swapped = WidthClassifier.fit([8, 8, 2, 2], [10, 10, 40, 40])
    assert swapped.diameters.tolist() == [40, 10] and swapped.predict([1, 9]).tolist() == [40, 10]


@pytest.mark.parametrize("w,d,exc,match", [
    ([3, 4], [10, 10], InputError, "at least two diameters"),
    ([3, 4, 5], [10, 20], ShapeError, "one length"),
    ([3, np.nan], [10, 20], InputError, "widths must be finite"),
    ([], [], ShapeError, "non-empty"),
])
def test_width_classifier_bad_input(w, d, exc, match):
    with pytest.raises(exc, match=match):
        WidthClassifier.fit(w, d)


def test_pair_separation_and_resolution():
    d = np.repeat([10, 20, 30, 40], 4)
    clean = np.repeat([3, 4, 5, 6], 4)
    clf = WidthClassifier.fit(clean, d)
    assert diameter_resolution(clf, clean, d) == 10.0
    # half the 30 mm traces look like 20 mm ones: that adjacent pair fails, pairs 20 mm apart all pass
    noisy = clean.copy()
    noisy[8:10] = 4
    table = pair_separation(clf, noisy, d)
    assert len(table["d_small"]) == 6
    acc = {(a, b): c for a, b, c in zip(table["d_small"], table["d_large"], table["accuracy"], strict=True)}
    assert acc[(20, 30)] == 0.75 and acc[(10, 20)] == 1.0 and acc[(10, 30)] == 1.0 and acc[(30, 40)] == 1.0
    assert diameter_resolution(clf, noisy, d) == 20.0
    assert diameter_resolution(clf, noisy, d, reliability=0.75) == 10.0
    same = np.full(16, 4)
    assert diameter_resolution(WidthClassifier.fit(np.r_[same[:15], 5], d), same, d) == math.inf
    with pytest.raises(InputError, match="reliability must be in"):
        diameter_resolution(clf, clean, d, reliability=0.5)
    with pytest.raises(TypeError, match="classifier must be a WidthClassifier"):
        pair_separation("clf", clean, d)


def test_tracing_dataset_deterministic(src):
    a = tracing_dataset(src, [20.0], 2, 2, seed=1)
    b = tracing_dataset(src, [20.0], 2, 2, seed=1)
    assert set(a) == {"diameter_mm", "offset_mm", "width", "mean_abs_diff", "combined"}
    assert a["combined"].shape == (2, 32) and np.all((a["offset_mm"] >= 0) & (a["offset_mm"] < 2.0))
    for k in a:
        assert np.array_equal(a[k], b[k])
    assert not np.array_equal(a["offset_mm"], tracing_dataset(src, [20.0], 2, 2, seed=2)["offset_mm"])


# ---- the study ---------------------------------------------------------------------------------------------
def test_experiment_table_behaviour(result):
    back = json.loads(json.dumps(result))
    assert back["table"] == result["table"]
    t = {k: np.asarray(v) for k, v in result["table"].items() if k != "n_traces"}
    diam = result["protocol"]["diameters_mm"]
    assert len(t["n_steps"]) == 4 * len(diam)

    def cell(key, n, d):
        return float(t[key][(t["n_steps"] == n) & (t["diameter_mm"] == d)][0])

    for d in diam:
        w1 = cell("width_mean", 1, d)
        for n in (2, 4, 8):
            assert 0.7 * n * w1 <= cell("width_mean", n, d) <= 1.3 * n * w1     # about N-fold
        mads = [cell("mad_mean", n, d) for n in (1, 2, 4, 8)]
        assert all(b < a for a, b in zip(mads, mads[1:], strict=False))           # falls with N
    w8 = [cell("width_mean", 8, d) for d in diam]
    assert all(b > a for a, b in zip(w8, w8[1:], strict=False))                  # grows with diameter at N=8
    assert cell("mad_mean", 8, diam[-1]) < cell("mad_mean", 8, diam[0])         # falls with diameter
    cls = result["classification"]
    assert cls["n_steps"] == [1, 2, 4, 8]
    assert all(0 <= a <= 1 for a in cls["accuracy"])
    res = [math.inf if r is None else r for r in cls["resolution_mm"]]
    assert res[-1] <= res[0]


def test_plot_experiment(result, tmp_path):
    path = tmp_path / "tracing.png"
    tracing.plot_experiment(result, path)
    assert path.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="result must be a dict returned by experiment"):
        tracing.plot_experiment({}, tmp_path / "x.png")
