"""Load-pattern families: each draws what its name says, within the design's bounds, from its seed."""

from __future__ import annotations

import numpy as np
import pytest
from optitact.calib.patterns import FAMILIES, PATTERNS, design_forces, pattern_forces
from optitact.calib.sets import Design

from optitact.optics.sensor import DomeSensor

SENSOR = DomeSensor.default()
DESIGN = Design()


@pytest.mark.parametrize("pattern", PATTERNS)
def test_every_family_stays_within_the_design_and_repeats_with_its_seed(pattern):
    f = pattern_forces(pattern, 40, SENSOR, DESIGN, seed=5)
    assert f.shape == (40, 41, 3) and np.isfinite(f).all()
    fz, shear = f[..., 2], np.linalg.norm(f[..., :2], axis=-1)
    assert fz.min() >= 0 and fz.max() <= DESIGN.fz_max + 1e-12
    assert shear.max() <= DESIGN.shear_max + 1e-12
    assert np.all(shear <= DESIGN.mu_max * fz + 1e-12)  # no shear without its normal load
    assert (fz > 0).any(axis=1).all()  # every frame loads something
    np.testing.assert_array_equal(f, pattern_forces(pattern, 40, SENSOR, DESIGN, seed=5))
    assert not np.array_equal(f, pattern_forces(pattern, 40, SENSOR, DESIGN, seed=6)) or pattern == "uniform"


def test_each_family_is_what_it_says():
    uni = pattern_forces("uniform", 9, SENSOR, DESIGN, 1)
    assert np.all(uni[..., 2] == uni[:, :1, 2]) and not uni[..., :2].any()
    np.testing.assert_allclose(np.sort(uni[:, 0, 2]), np.arange(1, 10) / 9)
    single = pattern_forces("single", 82, SENSOR, DESIGN, 1)
    assert np.all((single[..., 2] > 0).sum(axis=1) == 1)
    assert np.all(np.bincount(np.nonzero(single[..., 2])[1], minlength=41) == 2)  # elements in turn
    board = pattern_forces("checkerboard", 4, SENSOR, DESIGN, 1)
    ring = SENSOR.element_ring
    for t in range(4):
        on = np.flatnonzero(board[t, :, 2] > 0)
        for r in range(1, 4):  # no two loaded neighbours round a ring
            idx = np.flatnonzero(ring == r)
            mask = np.isin(idx, on)
            assert not np.any(mask & np.roll(mask, 1))
    shear = pattern_forces("shear", 16, SENSOR, DESIGN, 1)
    assert np.all(shear[..., 2] == DESIGN.fz_max / 2)
    # the drag direction of each frame is one of 8, the same for every element not at the apex
    dirs = {round(float(np.degrees(np.arctan2(shear[t, 0, 1], shear[t, 0, 0])))) % 360 for t in range(16)}
    assert dirs == {0, 45, 90, 135, 180, 225, 270, 315}
    clustered = pattern_forces("clustered", 12, SENSOR, DESIGN, 1)
    normals = SENSOR.element_frames[:, 2]
    geodesic = SENSOR.outer_radius * np.arccos(np.clip(normals @ normals.T, -1, 1))
    for t in range(12):  # one neighbourhood, falling from its peak: every loaded element but the
        fz = clustered[t, :, 2]  # strongest has a stronger loaded neighbour within 9 mm
        loaded = np.flatnonzero(fz > 0)
        assert 0 < loaded.size < 41
        for e in loaded[loaded != np.argmax(fz)]:
            stronger = loaded[fz[loaded] > fz[e]]
            assert geodesic[e, stronger].min() < 9.0


def test_blend_holds_every_family_and_design_dispatches():
    blend = pattern_forces("blend", len(FAMILIES) * 4, SENSOR, DESIGN, 3)
    counts = (blend[..., 2] > 0).sum(axis=1)
    assert 1 in counts and 41 in counts
    np.testing.assert_array_equal(design_forces(12, 41, Design(pattern="blend"), 2),
                                  pattern_forces("blend", 12, SENSOR, DESIGN, 2))
    np.testing.assert_array_equal(design_forces(8, 41, Design(pattern="clustered"), 2),
                                  pattern_forces("clustered", 8, SENSOR, DESIGN, 2))
    np.testing.assert_array_equal(design_forces(8, 41, DESIGN, 2), pattern_forces("independent", 8, SENSOR,
                                                                                     DESIGN, 2))


def test_design_names_its_pattern_only_when_not_the_classic_one():
    assert "pattern" not in Design().to_dict()
    assert Design(pattern="single").to_dict()["pattern"] == "single"
    with pytest.raises(ValueError, match="pattern must be one of"):
        Design(pattern="diagonal")
    with pytest.raises(ValueError, match="pattern must be one of"):
        pattern_forces("diagonal", 3, SENSOR, DESIGN, 0)
    with pytest.raises(ValueError, match="n_elements"):
        design_forces(3, 8, Design(pattern="uniform"), 0)


def test_the_command_line_offers_every_pattern():
    from optitact.cli._args import pattern_choices

    assert pattern_choices() == PATTERNS
