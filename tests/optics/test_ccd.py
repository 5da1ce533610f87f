"""Tests for the camera/CCD model in optitact.optics.ccd."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.optics.ccd import CCD

FIELD = (400, 500)
N_PIX = FIELD[0] * FIELD[1]
N_SE = 5.0  # agreement required, in standard errors


# --------------------------------------------------------------------------- #
# Statistics of the noise model
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize("bits", [12, 16])
@pytest.mark.parametrize("level", [0.04, 0.16, 0.4, 0.64])
def test_mean_and_variance_match_model(bits, level):
    ccd = CCD(bits=bits)
    # Stay clear of saturation so the closed forms apply.
    assert level * ccd.exposure + 6 * np.sqrt(level * ccd.exposure) < ccd.full_well
    radiance = np.full(FIELD, level)
    frame = ccd.expose(radiance, seed=1234 + bits).astype(np.float64)

    mu = ccd.mean_dn(radiance)
    var = ccd.variance_dn(radiance)
    assert mu.shape == FIELD and var.shape == FIELD
    assert np.all(mu == mu[0, 0]) and np.all(var == var[0, 0])
    mu, var = mu[0, 0], var[0, 0]

    se_mean = np.sqrt(var / N_PIX)
    se_var = var * np.sqrt(2.0 / (N_PIX - 1))
    assert abs(frame.mean() - mu) < N_SE * se_mean
    assert abs(frame.var(ddof=1) - var) < N_SE * se_var


@pytest.mark.parametrize("bits", [12, 16])
def test_zero_radiance_gives_offset_and_read_noise(bits):
    # An offset far above the read-noise spread, so nothing clips at 0 DN.
    ccd = CCD(bits=bits, dark_offset=400.0)
    sigma = ccd.dn_per_electron * ccd.read_noise
    assert ccd.dark_offset > 8 * sigma
    frame = ccd.expose(np.zeros(FIELD), seed=7).astype(np.float64)

    var = sigma**2 + 1.0 / 12.0
    np.testing.assert_allclose(ccd.mean_dn(np.zeros((2, 2))), 400.0, rtol=0, atol=0)
    np.testing.assert_allclose(ccd.variance_dn(np.zeros((2, 2))), var, rtol=1e-12, atol=0)
    assert abs(frame.mean() - ccd.dark_offset) < N_SE * np.sqrt(var / N_PIX)
    assert abs(frame.var(ddof=1) - var) < N_SE * var * np.sqrt(2.0 / (N_PIX - 1))


def test_zero_radiance_without_read_noise_is_exactly_offset():
    ccd = CCD(bits=12, read_noise=0.0, dark_offset=17.0)
    frame = ccd.expose(np.zeros((8, 9)), seed=0)
    assert np.all(frame == 17)


def test_read_noise_below_zero_dn_clips_at_zero():
    ccd = CCD(bits=12, dark_offset=0.0, read_noise=50.0)
    frame = ccd.expose(np.zeros(FIELD), seed=3)
    assert frame.min() == 0
    # Half the read noise is negative and reads 0 (plus the rounding band).
    frac_zero = np.mean(frame == 0)
    assert 0.45 < frac_zero < 0.60


@pytest.mark.parametrize("bits", [8, 10, 12, 16])
@pytest.mark.parametrize("level_over_sat", [3.0, 1e6, 1e300])
def test_far_above_saturation_reads_top_code_with_headroom(bits, level_over_sat):
    # Gain with the full well 10 read-noise sigmas above the top of the ADC.
    base = CCD(bits=bits)
    sigma_e = base.read_noise
    gain = (2**bits - 1 - base.dark_offset) / (base.full_well - 10 * sigma_e)
    ccd = CCD(bits=bits, gain=gain)
    radiance = np.full((50, 60), level_over_sat * ccd.radiance_at_saturation)
    frame = ccd.expose(radiance, seed=11)
    assert np.all(frame == 2**bits - 1)


@pytest.mark.parametrize("bits", [12, 16])
def test_saturation_with_default_gain(bits):
    # Default gain maps the full well onto the top code, so a saturated pixel
    # reads the top code minus the negative half of the read noise.
    ccd = CCD(bits=bits)
    top = 2**bits - 1
    radiance = np.full((200, 200), 5.0 * ccd.radiance_at_saturation)
    frame = ccd.expose(radiance, seed=5).astype(np.int64)
    sigma = ccd.dn_per_electron * ccd.read_noise
    assert frame.max() == top
    assert np.median(frame) == top
    assert frame.min() >= top - np.ceil(6 * sigma)
    np.testing.assert_allclose(ccd.mean_dn(radiance), top, rtol=0, atol=1e-9)
    np.testing.assert_allclose(ccd.variance_dn(radiance), sigma**2 + 1.0 / 12.0, rtol=1e-12, atol=0)


def test_derived_quantities():
    ccd = CCD(exposure=2000.0, full_well=10000.0, dark_offset=5.0, bits=10)
    assert ccd.radiance_at_saturation == 5.0
    assert ccd.dn_per_electron == pytest.approx((1023 - 5) / 10000.0, rel=1e-15)
    assert CCD(gain=0.25).dn_per_electron == 0.25
    # The full well lands on the top code with the default gain.
    assert ccd.mean_dn(np.full((1, 1), ccd.radiance_at_saturation))[0, 0] == pytest.approx(
        1023.0, abs=1e-9
    )


def test_mean_dn_independent_formula():
    ccd = CCD(exposure=1000.0, full_well=10000.0, dark_offset=5.0, gain=0.01, bits=12)
    radiance = np.array([[0.0, 2.0, 9.99], [10.0, 11.0, 1e300]])
    expected = np.array([[5.0, 25.0, 104.9], [105.0, 105.0, 105.0]])
    np.testing.assert_allclose(ccd.mean_dn(radiance), expected, rtol=0, atol=1e-9)
    var = ccd.variance_dn(radiance)
    expected_var = 1e-4 * (np.array([[0.0, 2000.0, 9990.0], [0.0, 0.0, 0.0]]) + 100.0) + 1 / 12
    np.testing.assert_allclose(var, expected_var, rtol=1e-12, atol=0)


# --------------------------------------------------------------------------- #
# Determinism, dtypes, shapes, inputs
# --------------------------------------------------------------------------- #
def test_same_seed_identical_different_seed_differs():
    ccd = CCD(bits=12)
    radiance = np.linspace(0.0, 6.0, 40 * 30).reshape(40, 30)
    a = ccd.expose(radiance, seed=42)
    b = ccd.expose(radiance, seed=42)
    c = ccd.expose(radiance, seed=43)
    np.testing.assert_array_equal(a, b)
    assert not np.array_equal(a, c)


@pytest.mark.parametrize(
    ("bits", "dtype"), [(8, np.uint8), (10, np.uint16), (12, np.uint16), (16, np.uint16)]
)
@pytest.mark.parametrize("shape", [(6, 7), (3, 6, 7)])
def test_output_dtype_and_shape(bits, dtype, shape):
    frame = CCD(bits=bits).expose(np.full(shape, 1.0), seed=0)
    assert frame.dtype == dtype
    assert frame.shape == shape
    assert CCD(bits=bits).mean_dn(np.ones(shape)).dtype == np.float64
    assert CCD(bits=bits).variance_dn(np.ones(shape)).shape == shape


def test_stack_frames_are_independent_draws():
    ccd = CCD(bits=16)
    stack = ccd.expose(np.full((4, 50, 50), 0.3), seed=9)
    assert not np.array_equal(stack[0], stack[1])
    # Each slice is a draw from the same per-pixel distribution.
    mu = ccd.mean_dn(np.full((1, 1), 0.3))[0, 0]
    var = ccd.variance_dn(np.full((1, 1), 0.3))[0, 0]
    n = stack[0].size
    for frame in stack.astype(np.float64):
        assert abs(frame.mean() - mu) < N_SE * np.sqrt(var / n)


def test_input_not_mutated_and_read_only_input_works():
    rng = np.random.default_rng(0)
    radiance = rng.uniform(0.0, 8.0, size=(30, 40))
    before = radiance.copy()
    radiance.setflags(write=False)
    ccd = CCD(bits=12)
    frame = ccd.expose(radiance, seed=1)
    ccd.mean_dn(radiance)
    ccd.variance_dn(radiance)
    np.testing.assert_array_equal(radiance, before)
    assert frame.shape == radiance.shape
    assert not np.shares_memory(frame, radiance)


def test_float32_and_float64_give_the_same_frame():
    # Multiples of 1/8 are exactly representable in float32.
    values = (np.arange(2 * 20 * 25) % 64) / 8.0
    r64 = values.reshape(2, 20, 25)
    r32 = r64.astype(np.float32)
    ccd = CCD(bits=16)
    np.testing.assert_array_equal(ccd.expose(r32, seed=5), ccd.expose(r64, seed=5))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16, np.int32, np.int64])
def test_integer_radiance_accepted(dtype):
    ccd = CCD(bits=12)
    r_int = np.full((10, 12), 2, dtype=dtype)
    np.testing.assert_array_equal(
        ccd.expose(r_int, seed=2), ccd.expose(r_int.astype(np.float64), seed=2)
    )


def test_nested_list_and_empty_input():
    ccd = CCD()
    assert ccd.expose([[0.0, 1.0], [2.0, 3.0]], seed=0).shape == (2, 2)
    assert ccd.expose(np.zeros((0, 5)), seed=0).shape == (0, 5)


# --------------------------------------------------------------------------- #
# Serialisation and frozen config
# --------------------------------------------------------------------------- #
def test_to_dict_round_trip_through_json():
    for ccd in (CCD(), CCD(bits=12, gain=0.3, read_noise=0.0, dark_offset=100)):
        d = json.loads(json.dumps(ccd.to_dict()))
        assert CCD.from_dict(d) == ccd
    assert CCD().to_dict() == {
        "exposure": 25000.0,
        "full_well": 20000.0,
        "read_noise": 10.0,
        "dark_offset": 4.0,
        "bits": 8,
        "gain": None,
    }


def test_numpy_scalars_are_stored_as_python_numbers():
    ccd = CCD(exposure=np.float32(1000.0), bits=np.int64(12), dark_offset=np.int16(3))
    assert type(ccd.exposure) is float and type(ccd.bits) is int
    assert type(ccd.dark_offset) is float
    json.dumps(ccd.to_dict())


def test_from_dict_partial_uses_defaults():
    assert CCD.from_dict({"bits": 10}) == CCD(bits=10)


def test_from_dict_unknown_key():
    with pytest.raises(ValueError, match=r"CCD fields\): unknown field\(s\) \['gamma'\]; valid: .*exposure"):
        CCD.from_dict({"gamma": 2.2})


def test_from_dict_not_a_mapping():
    with pytest.raises(TypeError, match=r"d \(CCD fields\) must be a dict, got list"):
        CCD.from_dict([("bits", 8)])


def test_config_is_frozen():
    with pytest.raises(dataclasses.FrozenInstanceError):
        CCD().bits = 12  # type: ignore[misc]


# --------------------------------------------------------------------------- #
# Validation errors
# --------------------------------------------------------------------------- #
@pytest.mark.parametrize(
    ("name", "bad"),
    [
        (name, bad)
        for name in ["exposure", "full_well", "read_noise", "dark_offset", "gain"]
        for bad in [True, "1.0", None, [1.0]]
        if not (name == "gain" and bad is None)  # gain=None is the default gain
    ],
)
def test_field_wrong_kind(name, bad):
    with pytest.raises(TypeError, match=f"{name} must be a real number, got"):
        CCD(**{name: bad})


@pytest.mark.parametrize("name", ["exposure", "full_well", "gain"])
@pytest.mark.parametrize("bad", [0.0, -1.0, np.nan, np.inf])
def test_field_not_positive_or_not_finite(name, bad):
    with pytest.raises(InputError, match=rf"{name} must be finite and > 0, got"):
        CCD(**{name: bad})


@pytest.mark.parametrize("name", ["read_noise", "dark_offset"])
@pytest.mark.parametrize("bad", [-0.5, np.nan, np.inf])
def test_field_negative_or_not_finite(name, bad):
    with pytest.raises(InputError, match=rf"{name} must be finite and >= 0, got"):
        CCD(**{name: bad})


@pytest.mark.parametrize("bad", [True, 8.0, "8", None])
def test_bits_wrong_kind(bad):
    with pytest.raises(TypeError, match="bits must be an integer, got"):
        CCD(bits=bad)


@pytest.mark.parametrize("bad", [0, 9, 14, 32])
def test_bits_not_allowed(bad):
    with pytest.raises(InputError, match=rf"bits must be one of \(8, 10, 12, 16\), got {bad}"):
        CCD(bits=bad)


@pytest.mark.parametrize(("bits", "top"), [(8, 255), (10, 1023), (12, 4095), (16, 65535)])
def test_dark_offset_above_adc_range(bits, top):
    CCD(bits=bits, dark_offset=top)  # the top code itself is allowed
    with pytest.raises(InputError, match=rf"dark_offset must be in \[0, {top}\] DN.*got"):
        CCD(bits=bits, dark_offset=top + 0.5)


METHODS = ["expose", "mean_dn", "variance_dn"]


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize(
    ("value", "dtype_name"),
    [
        (np.ones((3, 3), dtype=bool), "bool"),
        (np.ones((3, 3), dtype=complex), "complex128"),
        (np.ones((3, 3), dtype=object), "object"),
        (np.full((3, 3), "a"), "<U1"),
    ],
)
def test_radiance_wrong_dtype(method, value, dtype_name):
    with pytest.raises(
        TypeError,
        match=rf"radiance must be a real numeric array, got dtype "
        rf"{dtype_name}",
    ):
        getattr(CCD(), method)(value)


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("shape", [(), (5,), (2, 3, 4, 5)])
def test_radiance_wrong_ndim(method, shape):
    with pytest.raises(ShapeError, match=r"radiance must have shape \(H, W\) or \(T, H, W\), got"):
        getattr(CCD(), method)(np.ones(shape))


@pytest.mark.parametrize("method", METHODS)
@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf])
def test_radiance_not_finite(method, bad):
    radiance = np.ones((3, 4))
    radiance[1, 2] = bad
    with pytest.raises(InputError, match=r"radiance must be finite, got .* at index \(1, 2\)"):
        getattr(CCD(), method)(radiance)


@pytest.mark.parametrize("method", METHODS)
def test_radiance_negative_names_minimum(method):
    radiance = np.ones((2, 3, 4))
    radiance[0, 1, 2] = -0.25
    radiance[1, 0, 0] = -0.5
    with pytest.raises(
        InputError,
        match=r"radiance must be >= 0, got minimum -0\.5 at index "
        r"\(1, 0, 0\)",
    ):
        getattr(CCD(), method)(radiance)


def test_negative_zero_radiance_is_allowed():
    frame = CCD(read_noise=0.0).expose(np.full((2, 2), -0.0), seed=0)
    assert np.all(frame == 4)


@pytest.mark.parametrize(
    ("seed", "exc", "match"),
    [
        (-1, InputError, "seed must be >= 0, got -1"),
        (1.5, TypeError, "seed must be an integer, got float"),
        ("0", TypeError, "seed must be an integer, got str"),
        (True, TypeError, "seed must be an integer, got bool"),
    ],
)
def test_bad_seed(seed, exc, match):
    with pytest.raises(exc, match=match):
        CCD().expose(np.ones((2, 2)), seed=seed)
