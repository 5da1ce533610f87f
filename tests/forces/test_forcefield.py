"""Tests for optitact.forces.ForceField: derived quantities, table, CSV, plot and errors."""

from __future__ import annotations

import math
import re
import subprocess
import sys

import numpy as np
import pytest
from optitact.forces import ForceField

from optitact.errors import InputError, ShapeError
from optitact.optics.camera import FisheyeCamera
from optitact.optics.force_frames import global_from_local, local_from_global
from optitact.optics.sensor import DomeSensor

N = 41
R = 20.0
COLUMNS = ["element", "fx", "fy", "fz", "fx_global", "fy_global", "fz_global", "contact", "clamped",
           "saturated"]


@pytest.fixture(scope="module")
def sensor():
    return DomeSensor.default()


@pytest.fixture(scope="module")
def camera():
    return FisheyeCamera()


def _unit(polar_deg, azimuth_deg):
    th, ph = math.radians(polar_deg), math.radians(azimuth_deg)
    return np.array([math.sin(th) * math.cos(ph), math.sin(th) * math.sin(ph), math.cos(th)])


def _loaded(seed=0):
    rng = np.random.default_rng(seed)
    f = np.zeros((N, 3))
    f[:, 2] = rng.uniform(-0.5, 1.5, N)
    f[:, :2] = rng.normal(0.0, 0.1, (N, 2))
    return f


# ----------------------------------------------------------------------------- construction
def test_stored_read_only_copies(sensor):
    f = _loaded().astype(np.float32)
    before = f.copy()
    ff = ForceField(sensor, f)
    assert ff.local.dtype == np.float64 and ff.local.shape == (N, 3)
    assert not np.shares_memory(ff.local, f)
    np.testing.assert_array_equal(f, before)
    for arr in (ff.local, ff.contact, ff.clamped, ff.saturated, ff.global_forces):
        assert not arr.flags.writeable
    for name in ("contact", "clamped", "saturated"):
        assert getattr(ff, name).dtype == np.bool_ and getattr(ff, name).shape == (N,)
    with pytest.raises(ValueError, match="read-only"):
        ff.local[0, 0] = 1.0
    with pytest.raises(AttributeError):
        ff.local = np.zeros((N, 3))


def test_default_flags(sensor):
    f = _loaded()
    ff = ForceField(sensor, f)
    np.testing.assert_array_equal(ff.contact, f[:, 2] > 0)
    assert not ff.clamped.any() and not ff.saturated.any()
    zero = ForceField(sensor, np.zeros((N, 3)))
    assert not zero.contact.any()  # Fz = 0 is not contact


def test_explicit_flags(sensor):
    contact = np.zeros(N, bool)
    contact[[1, 2]] = True
    clamped = np.zeros(N, bool)
    clamped[5] = True
    ff = ForceField(sensor, _loaded(), contact=contact, clamped=clamped, saturated=clamped)
    np.testing.assert_array_equal(ff.contact, contact)
    np.testing.assert_array_equal(ff.clamped, clamped)
    np.testing.assert_array_equal(ff.saturated, clamped)
    assert not np.shares_memory(ff.contact, contact)


def test_keyword_only_flags(sensor):
    with pytest.raises(TypeError):
        ForceField(sensor, np.zeros((N, 3)), np.zeros(N, bool))


# ----------------------------------------------------------------------------- derived quantities
def test_global_local_consistency(sensor):
    f = _loaded(1)
    ff = ForceField(sensor, f)
    np.testing.assert_allclose(ff.global_forces, global_from_local(sensor, f), rtol=0, atol=1e-15)
    np.testing.assert_allclose(local_from_global(sensor, ff.global_forces), f, rtol=0, atol=1e-12)
    # Element 1 (polar 22.5 deg, azimuth 0) by hand: x = (cos t, 0, -sin t), y = (0, 1, 0), z = n.
    t = math.radians(22.5)
    fx, fy, fz = f[1]
    expected = (fx * np.array([math.cos(t), 0.0, -math.sin(t)]) + fy * np.array([0.0, 1.0, 0.0])
                - fz * _unit(22.5, 0.0))
    np.testing.assert_allclose(ff.global_forces[1], expected, rtol=0, atol=1e-12)


def test_single_apex_normal(sensor):
    f = np.zeros((N, 3))
    f[0, 2] = 1.0
    ff = ForceField(sensor, f)
    np.testing.assert_allclose(ff.resultant, [0.0, 0.0, -1.0], rtol=0, atol=1e-15)
    assert ff.total_normal == pytest.approx(1.0, rel=0, abs=1e-15)
    assert ff.n_contact == 1
    np.testing.assert_allclose(ff.moment, 0.0, rtol=0, atol=1e-12)


def test_moment_of_pure_normal_loads_is_zero(sensor):
    rng = np.random.default_rng(2)
    f = np.zeros((N, 3))
    f[:, 2] = rng.uniform(0.1, 2.0, N)
    ff = ForceField(sensor, f)
    assert ff.n_contact == N
    np.testing.assert_allclose(ff.moment, 0.0, rtol=0, atol=1e-12)
    # ... while the resultant is not zero: sum of -Fz n_i, by hand.
    normals = np.array([_unit(p, a) for p, a in zip(np.degrees(sensor.element_polar),
                                                    np.degrees(sensor.element_azimuth), strict=True)])
    np.testing.assert_allclose(ff.resultant, -(f[:, 2:3] * normals).sum(axis=0), rtol=0, atol=1e-12)


def test_moment_of_apex_shear(sensor):
    # Fx = 0.1 N at the apex (with Fz = 1 N, so the element is in contact): the normal part
    # passes through the centre and r x F = (0, 0, 20) x (0.1, 0, 0) = (0, 2, 0) N mm.
    f = np.zeros((N, 3))
    f[0] = (0.1, 0.0, 1.0)
    ff = ForceField(sensor, f)
    r, shear = np.array([0.0, 0.0, R]), np.array([0.1, 0.0, 0.0])
    by_hand = np.array([r[1] * shear[2] - r[2] * shear[1], r[2] * shear[0] - r[0] * shear[2],
                        r[0] * shear[1] - r[1] * shear[0]])
    np.testing.assert_allclose(by_hand, [0.0, 2.0, 0.0], rtol=0, atol=1e-15)
    np.testing.assert_allclose(ff.moment, by_hand, rtol=0, atol=1e-12)
    # Pure shear with the contact flag given explicitly gives the same moment.
    g = np.zeros((N, 3))
    g[0, 0] = 0.1
    contact = np.zeros(N, bool)
    contact[0] = True
    np.testing.assert_allclose(ForceField(sensor, g, contact=contact).moment, by_hand, rtol=0,
                               atol=1e-12)


def test_non_contact_excluded(sensor):
    t = math.radians(22.5)
    f = np.zeros((N, 3))
    f[0] = (0.2, -0.1, 1.0)     # in contact
    f[1] = (0.3, 0.0, 0.5)      # in contact (polar 22.5, azimuth 0)
    f[2] = (0.5, 0.5, -0.4)     # Fz < 0: not in contact by default
    f[3] = (1.0, 1.0, 0.0)      # Fz = 0: not in contact
    ff = ForceField(sensor, f)
    apex = np.array([0.2, -0.1, -1.0])
    elem1 = 0.3 * np.array([math.cos(t), 0.0, -math.sin(t)]) - 0.5 * _unit(22.5, 0.0)
    np.testing.assert_allclose(ff.resultant, apex + elem1, rtol=0, atol=1e-12)
    assert ff.total_normal == pytest.approx(1.5, rel=0, abs=1e-15)
    np.testing.assert_allclose(ff.moment, np.cross([0, 0, R], apex) + np.cross(R * _unit(22.5, 0), elem1),
                               rtol=0, atol=1e-12)
    # An explicit contact mask leaves out element 1 although Fz > 0.
    contact = np.zeros(N, bool)
    contact[0] = True
    only_apex = ForceField(sensor, f, contact=contact)
    np.testing.assert_allclose(only_apex.resultant, apex, rtol=0, atol=1e-15)
    assert only_apex.total_normal == pytest.approx(1.0, rel=0, abs=1e-15)


@pytest.mark.parametrize("element", [0, 1, 13, 27, 40])
def test_centre_of_pressure_single_element(sensor, element):
    f = np.zeros((N, 3))
    f[element] = (0.3, -0.2, 0.7)
    cop = ForceField(sensor, f).centre_of_pressure
    polar, azimuth = np.degrees(sensor.element_polar[element]), np.degrees(sensor.element_azimuth[element])
    np.testing.assert_allclose(cop, R * _unit(polar, azimuth), rtol=0, atol=1e-12)


def _slerp_midpoint(a, b):
    """Great-circle midpoint of two points on the sphere of radius R, by the slerp formula."""
    ua, ub = a / R, b / R
    omega = math.acos(float(np.clip(ua @ ub, -1.0, 1.0)))
    return R * (math.sin(omega / 2) * (ua + ub) / math.sin(omega))


@pytest.mark.parametrize(("i", "j"), [(1, 2), (9, 17), (25, 26), (27, 40)])
def test_centre_of_pressure_two_equal_loads(sensor, i, j):
    f = np.zeros((N, 3))
    f[[i, j], 2] = 0.8
    cop = ForceField(sensor, f).centre_of_pressure
    a = R * _unit(np.degrees(sensor.element_polar[i]), np.degrees(sensor.element_azimuth[i]))
    b = R * _unit(np.degrees(sensor.element_polar[j]), np.degrees(sensor.element_azimuth[j]))
    np.testing.assert_allclose(cop, _slerp_midpoint(a, b), rtol=0, atol=1e-12)
    assert np.linalg.norm(cop) == pytest.approx(R, rel=0, abs=1e-12)


def test_centre_of_pressure_opposite_elements_is_apex(sensor):
    f = np.zeros((N, 3))
    f[[1, 5], 2] = 1.0  # ring 1 at azimuth 0 and 180 deg
    np.testing.assert_allclose(ForceField(sensor, f).centre_of_pressure, [0.0, 0.0, R], rtol=0,
                               atol=1e-12)


def test_centre_of_pressure_weighted_by_fz(sensor):
    f = np.zeros((N, 3))
    f[1, 2], f[2, 2] = 3.0, 1.0
    a, b = sensor.element_positions[1], sensor.element_positions[2]
    p = (3.0 * a + 1.0 * b) / 4.0
    np.testing.assert_allclose(ForceField(sensor, f).centre_of_pressure, R * p / np.linalg.norm(p),
                               rtol=0, atol=1e-12)


def test_no_contact(sensor):
    f = np.zeros((N, 3))
    f[:, 2] = -0.1
    f[:, 0] = 0.2
    ff = ForceField(sensor, f)
    assert ff.centre_of_pressure is None
    assert ff.n_contact == 0 and ff.total_normal == 0.0
    np.testing.assert_array_equal(ff.resultant, 0.0)
    np.testing.assert_array_equal(ff.moment, 0.0)
    assert ff.resultant.shape == (3,) and ff.moment.shape == (3,)


# ----------------------------------------------------------------------------- table and CSV
def test_as_dict_table(sensor):
    clamped = np.zeros(N, bool)
    clamped[4] = True
    ff = ForceField(sensor, _loaded(3), clamped=clamped)
    d = ff.as_dict()
    assert list(d) == COLUMNS
    assert all(len(v) == N and v.ndim == 1 for v in d.values())
    np.testing.assert_array_equal(d["element"], np.arange(N))
    np.testing.assert_array_equal(np.stack([d["fx"], d["fy"], d["fz"]], axis=1), ff.local)
    np.testing.assert_array_equal(np.stack([d["fx_global"], d["fy_global"], d["fz_global"]], axis=1),
                                  ff.global_forces)
    np.testing.assert_array_equal(d["clamped"], clamped)
    d["fx"][0] = 99.0  # copies: the force field is unchanged
    assert ff.local[0, 0] != 99.0


def test_as_dict_is_table_shaped(sensor):
    d = ForceField(sensor, _loaded(4)).as_dict()
    assert list(d) == list(COLUMNS)
    assert {np.asarray(v).shape for v in d.values()} == {(N,)}


def test_csv_round_trip(sensor, tmp_path):
    rng = np.random.default_rng(5)
    f = _loaded(5)
    f[7] = (1.0 / 3.0, -2e-17, 123456.789)
    flags = {name: rng.random(N) < 0.3 for name in ("contact", "clamped", "saturated")}
    ff = ForceField(sensor, f, **flags)
    path = ff.to_csv(tmp_path / "ff.csv")
    lines = path.read_text().splitlines()
    assert lines[0] == ",".join(COLUMNS) and len(lines) == N + 1
    assert set(lines[1].split(",")[-3:]) <= {"0", "1"}
    back = ForceField.from_csv(path, sensor)
    np.testing.assert_array_equal(back.local, ff.local)  # repr floats: exact
    for name in ("contact", "clamped", "saturated"):
        np.testing.assert_array_equal(getattr(back, name), flags[name])


def test_csv_errors(sensor, tmp_path):
    ff = ForceField(sensor, _loaded(6))
    path = ff.to_csv(tmp_path / "ff.csv")
    lines = path.read_text().splitlines()
    with pytest.raises(FileNotFoundError, match="not found"):
        ForceField.from_csv(tmp_path / "missing.csv", sensor)
    with pytest.raises(InputError, match=r"line 15, column 1: element '13' does not exist"):
        ForceField.from_csv(path, DomeSensor(ring_counts=(1, 12), ring_polar_deg=(0.0, 40.0)))
    bad = tmp_path / "bad.csv"
    cells = lines[3].split(",")
    bad.write_text("\n".join([*lines[:3], ",".join([*cells[:7], "2", *cells[8:]]), *lines[4:]]))
    with pytest.raises(InputError, match="line 4, column 8 .contact.: expected 0 or 1"):
        ForceField.from_csv(bad, sensor)
    bad.write_text("\n".join([*lines[:3], ",".join([cells[0], "nan", *cells[2:]]), *lines[4:]]))
    with pytest.raises(InputError, match="line 4, column 2: 'nan' is not finite"):
        ForceField.from_csv(bad, sensor)
    bad.write_text("\n".join([*lines[:3], ",".join([cells[0], "1.0", *cells[2:]]), *lines[4:]]))
    with pytest.raises(InputError, match="global forces of element 2 disagree"):
        ForceField.from_csv(bad, sensor)
    bad.write_text("\n".join(["fx,fy,fz", *lines[1:]]))
    with pytest.raises(ShapeError, match="line 2: expected 3 columns, got 10"):
        ForceField.from_csv(bad, sensor)
    bad.write_text("\n".join(lines[1:]))  # no header: the columns cannot be named
    with pytest.raises(ShapeError, match=r"line 1: no header row; expected one naming the columns fx, fy, fz"):
        ForceField.from_csv(bad, sensor)
    bad.write_text("\n".join([*lines, lines[3]]))
    with pytest.raises(InputError, match=r"line 43: element 2 appears twice \(also on line 4\)"):
        ForceField.from_csv(bad, sensor)


def _as_people_write(ff, *, bom=False, delimiter=",", units=False, order=(0, 1, 2), sparse=False):
    """``ff``'s local forces as a person (or Excel) writes them: any column order, units, ``;``, a BOM."""
    names = [("Fx (N)", "Fy (N)", "Fz (N)")[i] if units else ("fx", "fy", "fz")[i] for i in order]
    rows = [delimiter.join(["Element", *names])]
    for i in range(ff.n_elements):
        if sparse and not ff.local[i].any():
            continue
        rows.append(delimiter.join([str(i), *(repr(float(ff.local[i, j])) for j in order)]))
    return ("\ufeff" if bom else "") + "\r\n".join(rows) + "\r\n"


@pytest.mark.parametrize("style", [
    {"bom": True}, {"units": True}, {"order": (2, 1, 0)}, {"sparse": True}, {"delimiter": ";"},
    {"delimiter": "\t", "units": True, "order": (1, 2, 0)},
    {"bom": True, "delimiter": ";", "units": True, "order": (2, 0, 1), "sparse": True},
])
def test_forces_files_as_people_write_them(sensor, tmp_path, style):
    """Excel's BOM, units in headers, other column orders, sparse rows, ';' or tab: read by column name."""
    from optitact.io.tables import read_forces_csv

    f = np.zeros((N, 3))
    f[[0, 5, 20]] = [(0.1, -0.05, 0.6), (0.0, 0.02, 0.4), (-1.0 / 3.0, 0.0, 0.3)]
    ff = ForceField(sensor, f)
    path = tmp_path / "people.csv"
    path.write_bytes(_as_people_write(ff, **style).encode("utf-8"))
    np.testing.assert_array_equal(read_forces_csv(path, N), f)  # repr floats: exact
    back = ForceField.from_csv(path, sensor)
    np.testing.assert_array_equal(back.local, f)
    np.testing.assert_array_equal(back.contact, f[:, 2] > 0)  # no contact column: the default


@pytest.mark.parametrize("text, match", [
    ("fx|fy|fz\n0|0|1\n", r"no column fx, fy, fz in the header \['fx\|fy\|fz'\]"),
    ("element,fx,fy,fz\n3,0,0,1\n3,0,0,2\n", r"line 3: element 3 appears twice \(also on line 2\)"),
    ("element,fx,fy,fz\n41,0,0,1\n", r"element '41' does not exist"),
    ("element,fx,fy,fz\n1.5,0,0,1\n", r"element '1.5' does not exist"),
    ("element,fx,fx,fz\n1,0,0,1\n", r"the column 'fx' appears twice"),
    ("Fx [N];Fy [N];Force\n0;0;1\n", r"no column fz in the header.*delimiter ';' \(semicolon\)"),
])
def test_forces_files_that_cannot_be_read_say_why(sensor, tmp_path, text, match):
    from optitact.io.tables import read_forces_csv

    path = tmp_path / "f.csv"
    path.write_text(text)
    with pytest.raises(ValueError, match=match):
        read_forces_csv(path, N)
    with pytest.raises(ValueError, match=match):
        ForceField.from_csv(path, sensor)


# ----------------------------------------------------------------------------- plot
def _frame(camera, dtype=np.uint16):
    rng = np.random.default_rng(8)
    return rng.integers(0, 4000, camera.shape).astype(dtype)


def _plot_forces():
    f = np.zeros((N, 3))
    f[[0, 3, 12, 25], 2] = (1.0, 0.5, 0.2, 1.4)
    f[[0, 3, 12, 25], :2] = ((0.1, 0.0), (0.0, -0.2), (0.05, 0.05), (3.0, 0.0))  # 25: cut at the edge
    f[20] = (0.4, 0.4, -0.3)  # shear but no contact: no arrow
    return f


def test_plot_artists(sensor, camera):
    from matplotlib.figure import Figure
    from matplotlib.patches import FancyArrowPatch

    clamped = np.zeros(N, bool)
    clamped[3] = True
    saturated = np.zeros(N, bool)
    saturated[[0, 20]] = True
    ff = ForceField(sensor, _plot_forces(), clamped=clamped, saturated=saturated)
    frame = _frame(camera)
    before = frame.copy()
    fig = ff.plot(frame, camera, title="frame 0")
    np.testing.assert_array_equal(frame, before)
    assert isinstance(fig, Figure)
    ax = fig.axes[0]
    assert len(ax.images) == 1
    arrows = [p for p in ax.patches if isinstance(p, FancyArrowPatch)]
    assert len(arrows) == ff.n_contact == 4
    assert [a.get_gid() for a in arrows] == ["shear-0", "shear-3", "shear-12", "shear-25"]
    assert [a.get_ylabel() for a in fig.axes[1:]] == ["Fz (N)"]
    assert ax.get_title() == "frame 0"
    assert "clamped" in [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("resultant" in t.get_text() for t in ax.texts)
    # Arrow tails sit on the projected element centres (x = col, y = row).
    centres = camera.project(sensor.element_positions, sensor)
    tails = np.array([a._posA_posB[0] for a in arrows])
    np.testing.assert_allclose(tails, centres[[0, 3, 12, 25]][:, ::-1], rtol=0, atol=1e-9)
    # The apex arrow's tip is the projected dome point 0.1 N * 10 mm/N along +x.
    tip = camera.project(sensor.dome_point(np.array([0]), np.array([[1.0, 0.0]])), sensor)[0]
    np.testing.assert_allclose(arrows[0]._posA_posB[1], tip[::-1], rtol=0, atol=1e-9)
    # Element 25 (azimuth 0): its 30 mm arrow runs down the dome past what the camera sees (88.3 deg
    # polar); it is cut at that edge, on its great circle.
    edge = camera.unproject(np.array(arrows[3]._posA_posB[1])[::-1], sensor)
    assert 88.0 < math.degrees(math.acos(edge[2] / R)) < 88.4
    off = sensor.tangent_offset(25, edge)
    assert 0.0 < off[0] < 30.0 and off[1] == pytest.approx(0.0, abs=1e-9)


def test_plot_into_given_axes(sensor, camera):
    from matplotlib.figure import Figure

    fig = Figure()
    ax = fig.add_subplot()
    out = ForceField(sensor, np.zeros((N, 3))).plot(_frame(camera, np.float32), camera, ax=ax)
    assert out is fig and len(ax.images) == 1 and len(ax.patches) == 0


def test_save_plot_png(sensor, camera, tmp_path):
    import cv2

    frame = _frame(camera, np.uint8)
    before = frame.copy()
    path = ForceField(sensor, _plot_forces()).save_plot(tmp_path / "ff.png", frame, camera)
    np.testing.assert_array_equal(frame, before)
    img = cv2.imread(str(path))
    assert img is not None and img.ndim == 3
    assert 400 <= img.shape[0] <= 1000 and 600 <= img.shape[1] <= 1200
    assert img.std() > 10  # not a blank picture


def test_plot_errors(sensor, camera):
    ff = ForceField(sensor, _plot_forces())
    with pytest.raises(ShapeError, match=r"frame must have shape \(H, W\) = \(480, 640\).*got \(480, 641\)"):
        ff.plot(np.zeros((480, 641)), camera)
    with pytest.raises(ShapeError, match=r"got \(2, 480, 640\)"):
        ff.plot(np.zeros((2, 480, 640)), camera)
    with pytest.raises(TypeError, match="frame must be a real numeric array"):
        ff.plot(np.zeros(camera.shape, bool), camera)
    bad = np.zeros(camera.shape)
    bad[3, 4] = np.nan
    with pytest.raises(InputError, match="frame must be finite"):
        ff.plot(bad, camera)
    with pytest.raises(TypeError, match="camera must be a Camera"):
        ff.plot(np.zeros(camera.shape), "camera")
    with pytest.raises(InputError, match="scale_mm_per_n"):
        ff.plot(np.zeros(camera.shape), camera, scale_mm_per_n=0.0)


def test_import_is_light():
    code = ("import sys, optitact.forces; "
            "print(sorted(m for m in ('matplotlib', 'mitsuba', 'drjit') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert r.stdout.strip() == "[]"


# ----------------------------------------------------------------------------- errors
@pytest.mark.parametrize("shape", [(N, 2), (N + 1, 3), (3,), (2, N, 3)])
def test_wrong_shape_local(sensor, shape):
    with pytest.raises(ShapeError, match=r"local must have shape \(41, 3\).*got " + re.escape(str(shape))):
        ForceField(sensor, np.zeros(shape))


def test_nan_local(sensor):
    f = np.zeros((N, 3))
    f[5, 1] = np.nan
    with pytest.raises(InputError, match=r"local must be finite, got nan at index \(5, 1\)"):
        ForceField(sensor, f)
    f[5, 1] = np.inf
    with pytest.raises(ValueError, match="finite"):
        ForceField(sensor, f)


@pytest.mark.parametrize("dtype", [bool, complex, object, str])
def test_non_numeric_local(sensor, dtype):
    with pytest.raises(TypeError, match="local must be a real numeric array"):
        ForceField(sensor, np.zeros((N, 3), dtype=dtype))


@pytest.mark.parametrize("name", ["contact", "clamped", "saturated"])
def test_flag_errors(sensor, name):
    with pytest.raises(ShapeError, match=rf"{name} must have shape \(41,\).*got \(40,\)"):
        ForceField(sensor, np.zeros((N, 3)), **{name: np.zeros(N - 1, bool)})
    with pytest.raises(TypeError, match=rf"{name} must be a bool array.*got dtype int64"):
        ForceField(sensor, np.zeros((N, 3)), **{name: np.zeros(N, np.int64)})


def test_sensor_type(sensor):
    with pytest.raises(TypeError, match="sensor must be a DomeSensor, got dict"):
        ForceField({}, np.zeros((N, 3)))


def test_repr(sensor):
    f = np.zeros((N, 3))
    f[0, 2] = 1.0
    assert repr(ForceField(sensor, f)) == "ForceField(n_elements=41, n_contact=1, resultant=(0, 0, -1) N)"
