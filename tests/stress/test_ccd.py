"""The CCD model: settings valid or refused by name, exposures within range and matching the model's moments."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import strategies as st

from optitact.errors import InputError, ShapeError
from optitact.optics.ccd import CCD, MAX_FULL_WELL

from .strategies import counted, rng_of, seeds, stress

finite_or_not = st.one_of(st.floats(allow_nan=True, allow_infinity=True), st.integers(-10, 10**20),
                          st.sampled_from([True, None, "3", 5e-324, 1e308, np.nan, np.inf, -1.0, 0.0, 7, 1e19]))


@stress("ccd", 1 / 3,
        field=st.sampled_from(["exposure", "full_well", "read_noise", "dark_offset", "bits", "gain"]),
        value=finite_or_not)
def test_ccd_settings_are_valid_or_refused_by_name(field, value):
    try:
        ccd = CCD(**{field: value})
    except (TypeError, InputError) as exc:
        assert field in str(exc) or "gain" in str(exc), str(exc)
        return
    rad = np.array([[0.0, 1e-3, 1.0, 1e3, 1e300]])
    out = [ccd.expose(rad, seed=0), ccd.mean_dn(rad), ccd.variance_dn(rad)]
    assert all(np.isfinite(np.asarray(o, np.float64)).all() for o in out)


BAD_RADIANCE = [np.full((3, 3), np.nan), -np.ones((3, 3)), np.zeros(4), np.zeros((3, 3), complex),
                np.zeros((2, 2, 2, 2)), [[1.0, 2.0], [3.0]]]


@stress("ccd", 2 / 3, seed=seeds, bits=st.sampled_from([8, 10, 12, 16]),
        bad=st.integers(-3, len(BAD_RADIANCE) - 1))
def test_exposures_stay_in_range_and_match_the_model(seed, bits, bad):
    rng = rng_of(seed)
    ccd = CCD(exposure=float(10 ** rng.uniform(0, 6)), full_well=float(10 ** rng.uniform(2, 6)),
              read_noise=float(rng.uniform(0, 30)), bits=bits, dark_offset=float(rng.uniform(0, 50)))
    if bad >= 0:
        with pytest.raises((InputError, ShapeError, TypeError), match="radiance"):
            ccd.expose(BAD_RADIANCE[bad], seed=0)
        return
    lum = float(10 ** rng.uniform(-4, 1)) * ccd.radiance_at_saturation
    rad = np.full((48, 48), lum)
    before = rad.copy()
    frame = ccd.expose(rad, seed=int(rng.integers(2**31)))
    top = 2**bits - 1
    assert frame.dtype == (np.uint8 if bits == 8 else np.uint16) and frame.shape == rad.shape
    assert frame.max() <= top
    np.testing.assert_array_equal(rad, before)
    mu, var = float(ccd.mean_dn(rad)[0, 0]), float(ccd.variance_dn(rad)[0, 0])
    sd = math.sqrt(var)
    if sd > 1.0 and mu - 6 * sd > 0 and mu + 6 * sd < top and \
            lum * ccd.exposure < ccd.full_well - 6 * sd / ccd.dn_per_electron:
        x = frame.astype(np.float64)
        assert abs(x.mean() - mu) <= 6 * sd / math.sqrt(x.size) + 0.05, f"mean DN {x.mean()} vs {mu}"
        assert 0.6 * var < x.var(ddof=1) < 1.5 * var, f"DN variance {x.var(ddof=1)} vs {var}"


@counted("ccd")
@pytest.mark.parametrize("kwargs,match", [
    (dict(full_well=1e19), r"full_well must be at most 1e\+18 electrons"),
    (dict(full_well=5e-324), "gain inf DN/electron .* overflows float64"),
    (dict(gain=1e200), "overflows float64"),
    (dict(read_noise=1e200), "read_noise=1e\\+200 overflows float64"),
])
def test_ccd_settings_that_overflow(kwargs, match):
    with pytest.raises(InputError, match=match):
        CCD(**kwargs)
    assert MAX_FULL_WELL == 1e18


@counted("ccd")
def test_ccd_ragged_radiance_is_a_type_error():
    with pytest.raises(TypeError, match="radiance must be a real numeric array; could not make one"):
        CCD().expose([[1.0, 2.0], [3.0]], seed=0)
