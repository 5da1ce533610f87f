"""The contact model on any forces, and the renderer's input checks (made before Mitsuba is imported)."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from optitact.errors import InputError, ShapeError
from optitact.optics.camera import FisheyeCamera
from optitact.optics.contact import MAX_FORCE_N, check_forces, contact_patches

from .helpers import N_EL, SENSOR, no_mitsuba
from .strategies import counted, rng_of, seeds, stress


def _valid_forces(seed):
    """Valid forces from subnormal to MAX_FORCE_N, pressing, pulling and zero."""
    rng = rng_of(seed)
    mag = 10 ** rng.uniform(-320, math.log10(MAX_FORCE_N), (N_EL, 3))
    return mag * rng.choice([-1.0, 1.0, 0.0], (N_EL, 3), p=[0.3, 0.6, 0.1])


any_forces = st.one_of(
    hnp.arrays(np.float64, (N_EL, 3), elements=st.floats(allow_nan=True, allow_infinity=True, width=64)),
    seeds.map(_valid_forces))


@stress("contact_render", 1 / 3, forces=any_forces)
def test_contact_model_on_any_forces(forces):
    try:
        c = contact_patches(SENSOR, forces)
    except InputError as exc:
        assert not np.isfinite(forces).all() or np.abs(forces).max() > MAX_FORCE_N
        assert "finite" in str(exc) or "at most 1e+06 N" in str(exc)
        return
    for name in ("centers", "radii", "loads", "slide"):
        assert np.isfinite(getattr(c, name)).all()
    assert np.all(c.radii >= 0) and np.all(c.radii <= SENSOR.cone_base_radius * (1 + 1e-12))
    assert np.all(c.loads >= 0)
    fz = np.maximum(forces[:, 2] + SENSOR.preload, 0.0)
    np.testing.assert_allclose(c.loads.sum(axis=1), fz, rtol=1e-9, atol=1e-300)
    pull = forces[:, 2] + SENSOR.preload <= 0
    assert np.all(c.radii[pull] == 0) and not np.any(c.tipped[pull]), "pulling elements must have no contact"
    assert np.all(np.hypot(c.slide[:, 0], c.slide[:, 1]) <= np.pi * SENSOR.outer_radius * (1 + 1e-12))


@counted("contact_render")
def test_shear_on_a_vanishing_normal_load_tips_without_overflow():
    f = np.zeros((N_EL, 3))
    f[0] = (1e6, 0.0, 1e-300)
    f[1] = (1e6, 1e6, 5e-324)
    f[2] = (0.1, 0.0, 1.0)
    f[3] = (1e-320, 0.0, 5e-324)  # all subnormal: the direction of a tipped feeler must not overflow
    c = contact_patches(SENSOR, f)
    assert c.tipped[[0, 1, 3]].all() and not c.tipped[2]
    np.testing.assert_allclose(np.hypot(c.slide[:2, 0], c.slide[:2, 1]), np.pi * SENSOR.outer_radius)
    assert np.isfinite(c.centers).all()


def _bad_forces(rng):
    """Bad forces, the error types they raise and a pattern their message matches."""
    kind = int(rng.integers(8))
    f = np.zeros((N_EL, 3))
    if kind == 0:
        f[int(rng.integers(N_EL)), int(rng.integers(3))] = rng.choice([np.nan, np.inf, -np.inf])
        return f, InputError, "finite"
    if kind == 1:
        big = float(rng.choice([-1, 1]) * 10 ** rng.uniform(6.01, 308))
        f[int(rng.integers(N_EL)), int(rng.integers(3))] = big
        return f, InputError, "at most.*N"
    if kind == 2:
        shape = [(N_EL,), (N_EL, 2), (N_EL - 1, 3), (3, N_EL), (1, N_EL, 3), ()][int(rng.integers(6))]
        return np.zeros(shape), ShapeError, rf"must have shape.*\({N_EL}, 3\)"
    if kind == 3:
        return np.zeros((N_EL, 3), [bool, complex, object][int(rng.integers(3))]), TypeError, "real"
    if kind == 4:
        return [[0.0, 0.0, 1.0]] * (N_EL - 1) + [[0.0, 1.0]], (TypeError, ValueError), "forces"
    if kind == 5:
        return "forces.csv", TypeError, "real"
    if kind == 6:
        return None, TypeError, "real"
    return np.full((N_EL, 3), np.nan), InputError, "finite"


@stress("contact_render", 1 / 3, seed=seeds)
def test_bad_forces_are_refused_by_name(seed):
    f, exc, match = _bad_forces(rng_of(seed))
    with pytest.raises(exc, match=match):
        check_forces(f, SENSOR)
    with pytest.raises(exc, match=match):
        contact_patches(SENSOR, f)


@counted("contact_render")
@pytest.mark.parametrize("forces,exc,match", [
    (np.full((N_EL, 3), 2e6), InputError, r"forces must be at most 1e\+06 N in magnitude \(check the units\), "
                                          r"got 2000000.0 at index \(0, 0\)"),
    ([[0.0, 0.0, 1.0]] * 40 + [[0.0, 1.0]], TypeError, "forces must be a real numeric array; could not make"),
    (np.zeros((N_EL, 3), bool), TypeError, "forces must be a real numeric array, got dtype bool"),
])
def test_bad_forces(forces, exc, match):
    with pytest.raises(exc, match=match):
        check_forces(forces, SENSOR)


CAM = FisheyeCamera(width=32, height=24)
RENDER_BAD = {  # option -> [(value, error types, pattern of the message)]
    "spp": [(0, InputError, "spp.*>= 1"), (-3, InputError, "spp.*>= 1"), (1.5, TypeError, "spp.*integer"),
            (True, TypeError, "spp.*integer"), ("4", TypeError, "spp.*integer"), (None, TypeError, "spp")],
    "seed": [(-1, InputError, "seed"), (1.5, TypeError, "seed"), (None, InputError, "seed"),
             ("0", TypeError, "seed")],
    "camera": [(object(), TypeError, "camera.*FisheyeCamera"), ("cam", TypeError, "camera")],
    "settings": [({"spp": 4}, TypeError, "settings.*RenderSettings")],
    "transport": [("bidir", InputError, "transport"), ("", InputError, "transport")],
    "crop": [((0, 0, 0, 5), InputError, "crop"), ((0, 0, 99, 5), InputError, "crop"),
             ((-1, 0, 2, 2), InputError, "crop"), ((0, 0, 2), InputError, "crop"),
             ((0.5, 0, 2, 2), TypeError, "crop"), (5, (TypeError, InputError), "crop")],
    "pixels": [(np.ones(CAM.shape, np.uint8), TypeError, "pixels.*bool"),
               (np.ones((3, 3), bool), InputError, "pixels.*shape")],
    "background": [(np.full(CAM.shape, np.nan), InputError, "background.*finite"),
                   (np.zeros((3, 3)), InputError, "background.*shape"),
                   (np.zeros(CAM.shape, complex), TypeError, "background"),
                   (np.full(CAM.shape, -1.0), InputError, "background"),
                   (np.full(CAM.shape, 1e300), InputError, "background")],
    "target_error": [(0.0, InputError, "target_error"), (-0.1, InputError, "target_error"),
                     (np.nan, InputError, "target_error")],
    "max_spp": [(16, InputError, "max_spp")],
    "variant": [("no_such_variant", InputError, "variant"), (7, TypeError, "variant")],
    "n_sub": [(0, InputError, "n_sub"), (2.5, TypeError, "n_sub")],
    "table": [("table.npz", TypeError, "table.*EmissionTable")],
    "two_stage_pixels": [(True, InputError, "pixels")],
}


def _render(forces, **kwargs):
    from optitact.render import render

    with no_mitsuba():
        render(SENSOR, forces, **kwargs)


@stress("contact_render", 1 / 3, seed=seeds, option=st.sampled_from(["forces"] + sorted(RENDER_BAD)))
def test_renderer_refuses_bad_input_before_mitsuba(seed, option):
    """Bad renderer inputs: a clear error before Mitsuba (or Dr.Jit) is imported."""
    rng = rng_of(seed)
    forces = np.zeros((N_EL, 3))
    forces[0, 2] = 0.5
    kw: dict = {"camera": CAM, "spp": 1}
    if option == "forces":
        forces, exc, match = _bad_forces(rng)
    else:
        value, exc, match = RENDER_BAD[option][int(rng.integers(len(RENDER_BAD[option])))]
        if option == "background":
            kw["pixels"] = np.ones(CAM.shape, bool)
        elif option == "max_spp":
            kw.update(target_error=0.01, spp=64)
        elif option in ("n_sub", "table", "two_stage_pixels"):
            kw["transport"] = "two_stage"
            if option == "two_stage_pixels":
                option, value = "pixels", np.ones(CAM.shape, bool)
        kw[option] = value
    with pytest.raises(exc, match=match):
        _render(forces, **kw)


RENDER_CASES = [
    (dict(spp=0), InputError, "spp must be >= 1, got 0"),
    (dict(spp=2.5), TypeError, "spp must be an integer, got float"),
    (dict(seed=-1), InputError, "seed must be >= 0"),
    (dict(forces=np.full((N_EL, 3), np.nan)), InputError, "forces must be finite"),
    (dict(forces=np.full((N_EL, 3), -1e9)), InputError, r"at most 1e\+06 N"),
    (dict(forces=np.zeros((N_EL, 2))), ShapeError, r"forces must have shape \(41, 3\)"),
    (dict(transport="bidir"), InputError, "transport must be one of"),
    (dict(crop=(0, 0, 0, 4)), InputError, "crop window"),
    (dict(pixels=np.ones((3, 3), bool)), InputError, "pixels must have the camera's shape"),
    (dict(pixels=True, background=np.full((24, 32), np.nan)), InputError, "background must be finite"),
    (dict(target_error=-1.0), InputError, "target_error must be finite and > 0"),
    (dict(transport="two_stage", n_sub=0), InputError, "n_sub must be >= 1"),
    (dict(camera="cam"), TypeError, "camera must be a FisheyeCamera"),
    # defects the stress cases found; render/ now checks them before Mitsuba is imported
    (dict(variant="no_such_variant"), InputError, "variant"),
    (dict(crop=5), (TypeError, InputError), "crop"),
    (dict(pixels=True, background=-np.ones((24, 32))), InputError, "background"),
    (dict(pixels=True, background=np.full((24, 32), 1e300)), InputError, "background"),
]


@counted("contact_render")
@pytest.mark.parametrize("kwargs,exc,match", RENDER_CASES)
def test_renderer_input_errors(kwargs, exc, match):
    kw = dict(camera=CAM, spp=1) | kwargs
    forces = kw.pop("forces", np.zeros((N_EL, 3)))
    if kw.get("pixels") is True:
        kw["pixels"] = np.ones(CAM.shape, bool)
    with pytest.raises(exc, match=match):
        _render(forces, **kw)
