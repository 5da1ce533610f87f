"""Active tracing with the piezo16 pad: traces, combined distribution, features, width classifier."""

import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.combined import (
    WidthClassifier,
    combined_distribution,
    diameter_resolution,
    features,
    pair_separation,
    radial_line,
    trace,
)
from optitact.taxels.piezo16 import Piezo16, Piezo16Config
from optitact.taxels.sources import Indenter, Layout, Scenario

PITCH = 2.2
FULL_MASK = ("#" * 16,) * 16


@pytest.fixture
def src(piezo16_source):
    return piezo16_source


@pytest.fixture
def ideal(piezo16_ideal):
    return piezo16_ideal


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


# ---- the modelled effects, each against an independent truth ------------------------------------------------
def test_boussinesq_kernel_conserves_load_and_matches_closed_form():
    from optitact.taxels.piezo16 import boussinesq_kernel

    h, g = 2.5, 0.1
    k = boussinesq_kernel(h, g, 4.0)
    assert k.sum() == pytest.approx(1.0, abs=1e-12)                       # carries the whole load
    m = (k.shape[0] - 1) // 2
    # closed form 3 h^3 / (2 pi (r^2 + h^2)^2.5) per unit area; the truncated part of the load is
    # 1 - (1 + cutoff^2)^-1.5 (exact integral), so the nodes carry the closed form divided by what is kept
    kept = 1 - (1 + 16.0) ** -1.5
    for r_idx in (0, 10, 25):
        r = r_idx * g
        want = 3 * h ** 3 / (2 * math.pi * (r * r + h * h) ** 2.5) * g * g / kept
        assert k[m, m + r_idx] == pytest.approx(want, rel=2e-3)
    # half width at half maximum 0.57 h (sqrt(2^(2/5) - 1) h = 0.566 h)
    half = np.flatnonzero(k[m, m:] >= k[m, m] / 2)[-1] * g
    assert half == pytest.approx(math.sqrt(2 ** 0.4 - 1) * h, abs=g)


def test_leak_kernel_is_the_sheet_greens_function():
    from scipy.special import k0

    from optitact.taxels.piezo16 import leak_kernel

    lam, g = 0.5, 0.1
    k = leak_kernel(lam, g)
    assert k.sum() == pytest.approx(1.0, abs=1e-12)
    m = (k.shape[0] - 1) // 2
    # K0(r / lam) / (2 pi lam^2) per unit area (its integral is 1): the nodes follow it away from the centre
    for r_idx in (3, 5, 10):
        want = k0(r_idx * g / lam) / (2 * math.pi * lam ** 2) * g * g
        assert k[m, m + r_idx] == pytest.approx(want, rel=0.02)
    assert np.allclose(k, k.T) and np.allclose(k, k[::-1])


def test_spreading_fields_default_to_todays_pad():
    base = Piezo16(Piezo16Config(noise_v=0.0, unit_gain_spread=0.0))
    same = Piezo16(Piezo16Config(noise_v=0.0, unit_gain_spread=0.0, spread_depth_mm=2.0, rubber_leak_mm=0.0))
    assert Piezo16Config().depth_of_spreading_mm == 2.0
    sc = Scenario(Indenter("cylinder", size_mm=6.0), np.arange(3) / 1e3, x_mm=[0.0, 0.3, 0.9],
                  angle_rad=math.pi / 2, depth_mm=0.7)
    np.testing.assert_array_equal(base.frames(sc), same.frames(sc))
    with pytest.raises(InputError, match="spread_depth_mm must be finite and > 0"):
        Piezo16Config(spread_depth_mm=0.0)
    with pytest.raises(InputError, match="rubber_leak_mm"):
        Piezo16Config(rubber_leak_mm=-0.1)


def test_spreading_conserves_volume_and_widens():
    # a long pipe across a full pad: the compression summed over the electrodes (x pitch^2) ~ the indented
    # volume per electrode area; deeper spreading and the rubber's leak keep it but widen the profile
    kw = {"mask": FULL_MASK, "noise_v": 0.0, "unit_gain_spread": 0.0}
    sc = Scenario(Indenter("cylinder", size_mm=10.0), np.zeros(1), angle_rad=math.pi / 2, depth_mm=0.7)
    profiles = []
    for extra in ({}, {"spread_depth_mm": 2.5}, {"spread_depth_mm": 2.5, "rubber_leak_mm": 0.5}):
        st = Piezo16(Piezo16Config(**kw, **extra)).compression(sc)
        profiles.append(st["mean_compression_mm"][0, 8])
    a = math.sqrt(2 * 10.0 * 0.7 - 0.49)
    area = 2 * (0.7 * a - a ** 3 / (3 * 2 * 10.0))                          # indented cross-section, mm^2
    for prof in profiles:
        # electrodes cover 2.0 of every 2.2 mm: the summed line samples area / pitch (within the gap's share)
        assert prof.sum() * PITCH == pytest.approx(area, rel=0.05)
    peaks = [p.max() for p in profiles]
    assert peaks[0] > peaks[1] > peaks[2]


def test_finger_errors_statistics():
    from optitact.taxels.combined import finger_errors

    dz, dx = finger_errors(np.random.default_rng(3), (400, 50), depth_spread_mm=0.02, step_jitter_mm=0.05)
    assert dz.shape == dx.shape == (400, 50)
    assert abs(dz.mean()) < 4 * 0.02 / math.sqrt(dz.size) and abs(dx.mean()) < 4 * 0.05 / math.sqrt(dx.size)
    assert dz.std() == pytest.approx(0.02, rel=0.03) and dx.std() == pytest.approx(0.05, rel=0.03)
    assert abs(np.corrcoef(dz.ravel(), dx.ravel())[0, 1]) < 0.03          # independent
    z0, x0 = finger_errors(np.random.default_rng(3), 4)
    assert not z0.any() and not x0.any()
    with pytest.raises(InputError, match="depth_spread_mm"):
        finger_errors(np.random.default_rng(0), 2, depth_spread_mm=-1.0)
    with pytest.raises(TypeError, match="rng must be a numpy Generator"):
        finger_errors(0, 2)


def test_trace_with_finger_errors(ideal):
    # a seed's readout noise is unchanged by the finger's errors; zero errors give the exact trace
    exact = trace(ideal, 20.0, 4, seed=5)
    np.testing.assert_array_equal(exact, trace(ideal, 20.0, 4, seed=5, depth_spread_mm=0.0, step_jitter_mm=0.0))
    shaky = trace(ideal, 20.0, 4, seed=5, depth_spread_mm=0.05)
    assert not np.array_equal(exact, shaky)
    np.testing.assert_array_equal(shaky, trace(ideal, 20.0, 4, seed=5, depth_spread_mm=0.05))
    # deeper press, more output: the depth error of each step moves its whole frame one way
    rng = np.random.default_rng((5, 1))
    dz = 0.05 * rng.standard_normal(4)
    diff = (shaky - exact).sum(axis=(1, 2))
    assert np.all(np.sign(diff) == np.sign(dz))


def test_unit_gain_spread_has_configured_std():
    src = Piezo16(Piezo16Config(mask=FULL_MASK, unit_gain_spread=0.15, unit_seed=4))
    lg = np.log(src.unit_gain)
    assert lg.std(ddof=1) == pytest.approx(0.15, rel=0.15)              # 256 units: ~4.4 % standard error
    assert abs(lg.mean()) < 4 * 0.15 / 16
