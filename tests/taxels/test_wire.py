"""The wire chain: offset removal, normalisation tables, wire shape, the 2-D lookup table."""


import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.opto5 import Opto5, grasp_scenario
from optitact.taxels.sources import Indenter
from optitact.taxels.wire import (
    LookupTableClassifier,
    NormalisationLUT,
    calibration_closure,
    hold_response,
    remove_offset,
    wire_centroids,
    wire_shape,
)

PUBLISHED_ROW = [0.9518, 2.2716, 3.0802, 3.5735, 6.2054, 7.9888]
DIAMETERS = [1.5, 2.0, 2.5, 3.0, 3.5, 4.0]


def grasp(src, indenter, depth, *, seed=0, **pose):
    sc = grasp_scenario(src, indenter, depth, n_base=50, n_ramp=10, n_hold=10, **pose)
    return hold_response(src, sc, n_base=50, n_hold=10, seed=seed)


@pytest.fixture
def clean(opto5_clean):
    """A noise-free sensor (ADC quantisation only) and its normalisation (session fixture)."""
    return opto5_clean


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
