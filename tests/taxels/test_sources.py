import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.taxels.sources import (
    Indenter,
    Layout,
    Scenario,
    TactileSource,
    make_source,
    moments,
    source_config,
    source_names,
)


def test_registry_lists_dome_and_refuses_unknown_names():
    assert "dome41" in source_names()
    with pytest.raises(ValueError, match="unknown tactile source 'nope'; valid names: .*dome41"):
        make_source("nope")
    with pytest.raises(ValueError, match="unknown config field"):
        source_config("dome41", colour=3)


def test_dome_source_satisfies_protocol():
    src = make_source("dome41", width=64, height=48)
    assert isinstance(src, TactileSource)
    lay = src.layout
    assert lay.shape == (48, 64) and lay.units == "DN" and 0 < lay.n_cells < 48 * 64


def test_layout_validation():
    with pytest.raises(ValueError, match="pitch_mm"):
        Layout(shape=(4, 4), pitch_mm=0, units="V", rate_hz=10)
    with pytest.raises(ShapeError, match="mask must have shape"):
        Layout(shape=(4, 4), pitch_mm=1, units="V", rate_hz=10, mask=np.ones((3, 4), bool))
    with pytest.raises(TypeError, match="bool"):
        Layout(shape=(4, 4), pitch_mm=1, units="V", rate_hz=10, mask=np.ones((4, 4)))
    lay = Layout(shape=(4, 4), pitch_mm=1, units="V", rate_hz=10)
    with pytest.raises(ShapeError, match=r"\(4, 4\)"):
        lay.check_frames(np.zeros((5, 4)))
    with pytest.raises(InputError, match="finite"):
        lay.check_frames(np.full((4, 4), np.nan))


def test_scenario_validation():
    ind = Indenter("sphere", 2.0)
    with pytest.raises(InputError, match="exactly one"):
        Scenario(ind, t_s=[0, 1])
    with pytest.raises(InputError, match="increasing"):
        Scenario(ind, t_s=[0, 0], depth_mm=1)
    with pytest.raises(ShapeError, match="like t_s"):
        Scenario(ind, t_s=[0, 1], depth_mm=[1, 2, 3])
    with pytest.raises(InputError, match="shape must be one of"):
        Indenter("cone")
    sc = Scenario(ind, t_s=[0, 1, 2], depth_mm=0.5, x_mm=[0, 1, 2])
    assert sc.n_frames == 3 and sc.depth_mm.tolist() == [0.5] * 3


def test_moments_of_analytic_image():
    lay = Layout(shape=(5, 7), pitch_mm=(2.0, 1.0), units="V", rate_hz=10)
    img = np.zeros((5, 7))
    img[1, 5] = 3.0          # x = (5 - 3) * 1 = 2, y = (1 - 2) * 2 = -2
    img[3, 1] = 1.0          # x = -2, y = 2
    m = moments(np.stack([img, np.zeros_like(img)]), lay)
    np.testing.assert_allclose([m["total"][0], m["x_mm"][0], m["y_mm"][0]], [4.0, 1.0, -1.0], atol=1e-12)
    # second moments: weights 3/4 and 1/4 at distance (1, -1) and (-3, 3)
    np.testing.assert_allclose([m["sxx"][0], m["syy"][0], m["sxy"][0]], [3.0, 3.0, -3.0], atol=1e-12)
    assert m["total"][1] == 0 and m["x_mm"][1] == 0 and m["n_active"].tolist() == [2, 0]
