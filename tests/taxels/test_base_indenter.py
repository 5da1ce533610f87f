"""The shared taxel base (config, seeds, scenario checks, constructor) and the one indenter geometry."""

import math
import subprocess
import sys
from dataclasses import dataclass

import numpy as np
import pytest

from optitact.errors import InputError
from optitact.taxels import base
from optitact.taxels.base import TaxelSource, check_config, check_scenario, fraction, range_pair
from optitact.taxels.indenter import overlap, surface_height
from optitact.taxels.sources import Indenter, Scenario


def test_fraction_and_range_pair():
    assert fraction(0.0, "f") == 0.0 and fraction(1.0, "f", closed=True) == 1.0
    with pytest.raises(InputError, match=r"f must be in \[0, 0.5\), got 0.5"):
        fraction(0.5, "f", upper=0.5)
    with pytest.raises(InputError, match=r"f must be in \[0, 1\], got 1.5"):
        fraction(1.5, "f", closed=True)
    with pytest.raises(InputError, match="f must be finite and >= 0"):
        fraction(-0.1, "f")
    assert range_pair((1, 2), "r") == (1.0, 2.0)
    with pytest.raises(InputError, match="low <= high"):
        range_pair((2, 1), "r")


@dataclass(frozen=True)
class _Cfg:
    unit_seed: int = 0


class _Src(TaxelSource):
    name, config_type, shapes = "toy-taxels", _Cfg, ("sphere", "flat")
    extra = {"tilt": 0.0}
    drive = "depth"

    def _setup(self, config):
        self.gain = base.unit_gains(np.random.default_rng(config.unit_seed), (2, 3), 0.1)


def test_constructor_and_scenario_checks():
    s = _Src()
    assert s.config == _Cfg() and s.gain.shape == (2, 3) and not s.gain.flags.writeable
    np.testing.assert_array_equal(_Src(_Cfg(4)).gain, _Src(_Cfg(4)).gain)
    with pytest.raises(TypeError, match="config must be a _Cfg, got int"):
        _Src(3)
    with pytest.raises(TypeError, match="config must be an Opto"):
        check_config(1, type("OptoCfg", (), {}))
    sc = Scenario(Indenter("sphere", 2.0), [0.0], depth_mm=0.1, extra={"tilt": 0.3})
    ind, extra = s.check_scenario(sc)
    assert ind.shape == "sphere" and extra == {"tilt": 0.3}
    assert s.check_scenario(Scenario(Indenter("flat"), [0.0], depth_mm=0.1))[1] == {"tilt": 0.0}
    with pytest.raises(TypeError, match="scenario must be a Scenario"):
        s.check_scenario("x")
    with pytest.raises(InputError, match=r"the toy-taxels source simulates indenters \('sphere', 'flat'\)"):
        s.check_scenario(Scenario(Indenter("box"), [0.0], depth_mm=0.1))
    with pytest.raises(InputError, match=r"unknown Scenario.extra key\(s\) \['colour'\] for toy-taxels; "
                                         r"valid: \['tilt'\]"):
        s.check_scenario(Scenario(Indenter("flat"), [0.0], depth_mm=0.1, extra={"colour": 1}))
    with pytest.raises(InputError, match="needs depth_mm"):
        s.check_scenario(Scenario(Indenter("flat"), [0.0], force_n=1.0))
    with pytest.raises(InputError, match="needs a force-driven scenario"):
        check_scenario(Scenario(Indenter("flat"), [0.0], depth_mm=1.0), "f", ("flat",), drive="force")


def _direct_height(shape, r, along, size, length):
    """Per point, straight from the definitions (loops, math module)."""
    if math.isfinite(length) and shape in ("cylinder", "wire", "box") and abs(along) > length / 2:
        return math.inf
    if shape == "flat":
        return 0.0
    if shape == "box":
        return 0.0 if r <= size else math.inf
    return size - math.sqrt(size * size - r * r) if r < size else math.inf


@pytest.mark.parametrize("shape", ["sphere", "cylinder", "wire", "box", "flat"])
@pytest.mark.parametrize("length", [math.inf, 6.0])
def test_surface_height_matches_definitions(shape, length):
    ind = Indenter(shape, size_mm=3.0, length_mm=length)
    rng = np.random.default_rng(0)
    px, py = rng.uniform(-6, 6, size=(2, 50))
    x0, y0, ang = np.array([0.5, -1.0]), np.array([0.0, 2.0]), np.array([0.3, 2.0])
    h = surface_height(ind, px, py, x0, y0, ang)
    assert h.shape == (2, 50)
    for k in range(2):
        dx, dy = px - x0[k], py - y0[k]
        c, s = math.cos(ang[k]), math.sin(ang[k])
        for i in range(50):
            along = dx[i] * c + dy[i] * s
            r = math.hypot(dx[i], dy[i]) if shape == "sphere" else abs(dy[i] * c - dx[i] * s)
            want = _direct_height(shape, r, along, 3.0, length)
            assert (h[k, i] == want == math.inf) or abs(h[k, i] - want) < 1e-12
    # scalar pose: the points' shape; grids broadcast
    g = surface_height(ind, np.arange(4.0)[None, :], np.arange(3.0)[:, None], 0.5, 0.0, 0.3)
    assert g.shape == (3, 4)
    np.testing.assert_array_equal(g[0], surface_height(ind, np.arange(4.0), 0.0, 0.5, 0.0, 0.3))


def test_bent_wire_and_overlap():
    ind = Indenter("wire", size_mm=1.0)
    kappa = 0.1
    s = np.linspace(-5, 5, 11)
    on_axis = surface_height(ind, s, 0.5 * kappa * s * s, 0.0, 0.0, 0.0, curvature_per_mm=kappa)
    np.testing.assert_allclose(on_axis, 0.0, rtol=0, atol=1e-12)
    assert np.all(np.isinf(surface_height(ind, s, 0.5 * kappa * s * s + 1.5, 0.0, 0.0, 0.0,
                                          curvature_per_mm=kappa)))
    np.testing.assert_array_equal(overlap(0.5, [0.0, 0.2, np.inf]), [0.5, 0.3, 0.0])
    with pytest.raises(InputError, match="to have a surface"):
        surface_height(Indenter("point"), 0.0, 0.0, 0.0, 0.0)
    with pytest.raises(TypeError, match="indenter must be an Indenter"):
        surface_height("sphere", 0.0, 0.0, 0.0, 0.0)


def test_taxels_import_no_optional_dependency_and_no_study():
    code = ("import sys, optitact.taxels, optitact.taxels.sources as s\n"
            "s.make_source('piezo16'), s.make_source('thread8')\n"
            "import optitact.taxels.combined, optitact.taxels.grasp, optitact.taxels.dtw\n"
            "heavy = ('sklearn', 'dtaidistance', 'matplotlib')\n"
            "print(sorted(m for m in sys.modules\n"
            "             if m.split('.')[0] in heavy or m.startswith('optitact.studies')))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"
