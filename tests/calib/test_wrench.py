"""A six-axis F/T sensor's totals: the wrench CSV, the F/T sensor's pose, the element-to-wrench map, and
whether loaded frames can pin down every element.

Truths are independent of the package where they can be: the element directions and unit factors from
their definitions, the torques from the ``r x F`` rule written out here, the forces' sum from
:func:`optitact.optics.force_frames.frame_totals`.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from optitact.calib.wrench import (
    SensorPose,
    UnidentifiableError,
    check_identifiable,
    contact_points,
    element_wrench,
    read_wrench,
    torque_unit,
    wrench_matrix,
)
from scipy.spatial.transform import Rotation

from optitact.errors import InputError, ShapeError
from optitact.optics.force_frames import frame_totals, global_from_local
from optitact.optics.sensor import DomeSensor

SENSOR = DomeSensor.default()  # outer radius 20 mm, lever arm 3 mm, rings (1, 8, 16, 16) at 0, 22.5, 45, 67.5°
N_EL = SENSOR.n_elements
R_O, H = 20.0, 3.0
SOURCES = ["noload.png", "press_001.png", "press_002.png", "clip.avi#12"]

# N per unit and N m per unit, from the definitions: standard gravity 9.80665 m/s², 1 lb = 0.45359237 kg,
# 1 oz = 1/16 lb, 1 in = 25.4 mm, 1 ft = 12 in
G0, LBF = 9.80665, 0.45359237 * 9.80665
N_PER = {"N": 1.0, "mN": 1e-3, "kN": 1e3, "gf": G0 * 1e-3, "kgf": G0, "lbf": LBF, "ozf": LBF / 16}
NM_PER = {"N·m": 1.0, "N*m": 1.0, "Nm": 1.0, "N.m": 1.0, "N-m": 1.0, "N m": 1.0, "nm": 1.0, "N⋅m": 1.0,
          "mN·m": 1e-3, "mNm": 1e-3, "N·mm": 1e-3, "Nmm": 1e-3, "N*mm": 1e-3, "N·cm": 1e-2,
          "kgf·cm": G0 * 1e-2, "KGFCM": G0 * 1e-2, "gf·cm": G0 * 1e-5, "kgf·m": G0,
          "lbf·in": LBF * 0.0254, "in-lbf": LBF * 0.0254, "in·lbf": LBF * 0.0254,
          "lbf·ft": LBF * 0.3048, "ft·lbf": LBF * 0.3048, "ozf·in": LBF / 16 * 0.0254,
          "in·ozf": LBF / 16 * 0.0254}

# frames 1, 2, 3 of SOURCES: (fx, fy, fz) N, (tx, ty, tz) N m; a press of about 1 N some 50 mm from the origin
WRENCH = {1: [0.05, -0.02, -0.9, 0.011, -0.03, 0.0004],
          2: [0.0, 0.0, -1.5, 0.0, 0.0, 0.0],
          3: [-0.3, 0.2, -2.0, -0.05, -0.06, 0.002]}


def wrench_text(force_unit=None, torque_unit=None, sep=",", rows=None, order=None):
    """WRENCH as a CSV, forces in ``force_unit`` and torques in ``torque_unit`` (None: no unit), 17 digits."""
    names = ["Fx", "Fy", "Fz", "Tx", "Ty", "Tz"]
    heads = [f"{n} ({force_unit})" if force_unit else n for n in names[:3]] + \
            [f"{n} ({torque_unit})" if torque_unit else n for n in names[3:]]
    scale = [N_PER[force_unit or "N"]] * 3 + [NM_PER[torque_unit or "N·m"]] * 6
    order = order or list(range(7))
    cols = ["frame", *heads]
    lines = [sep.join(cols[j] for j in order)]
    for t, w in (rows or WRENCH).items():
        name = SOURCES[t] if isinstance(t, int) else t
        cells = [name, *(f"{v / s:.17g}" for v, s in zip(w, scale, strict=False))]
        lines.append(sep.join(cells[j] for j in order))
    return "\n".join(lines) + "\n"


def write(tmp_path, text, name="wrench.csv", encoding="utf-8"):
    p = tmp_path / name
    p.write_bytes(text.encode(encoding))
    return p


def expected():
    return np.array([WRENCH[t] for t in sorted(WRENCH)])


# ---------------------------------------------------------------------------- the map: truths by hand
def unit_normal(polar_deg, azimuth_rad):
    th = math.radians(polar_deg)
    return np.array([math.sin(th) * math.cos(azimuth_rad), math.sin(th) * math.sin(azimuth_rad), math.cos(th)])


@pytest.mark.parametrize("at", ["tip", "surface"])
def test_a_pure_normal_force_on_one_element_by_hand(at):
    """Element 5 (ring 1 at 22.5°, 5th of 8: azimuth 180°) pressed with 2 N: the force is -2 n, through the
    dome's centre, so about an F/T origin at p the torque is (c - p) x F = -p x F whatever the point c on n."""
    n = unit_normal(22.5, math.pi)
    p = np.array([10.0, -5.0, -30.0])
    f = np.zeros((N_EL, 3))
    f[5, 2] = 2.0
    w = element_wrench(SENSOR, SensorPose(position=p), f, at=at)
    force = -2.0 * n
    # (-p) x F written out, mm N -> N m
    torque = 1e-3 * np.array([-(p[1] * force[2] - p[2] * force[1]), -(p[2] * force[0] - p[0] * force[2]),
                              -(p[0] * force[1] - p[1] * force[0])])
    th = math.radians(22.5)
    np.testing.assert_allclose(w[:3], [2 * math.sin(th), 0.0, -2 * math.cos(th)], rtol=0, atol=1e-12)
    np.testing.assert_allclose(w[3:], torque, rtol=0, atol=1e-14)
    # the numbers: F = (0.765367, 0, -1.847759) N; (-10, 5, 30) mm x F
    # = (-9.238795, 30 * 0.765367 - 10 * 1.847759, -5 * 0.765367) = (-9.238795, 4.483415, -3.826834) mN m
    np.testing.assert_allclose(w, [0.7653668647, 0.0, -1.8477590650, -0.0092387953, 0.0044834153,
                                   -0.0038268343], rtol=0, atol=1e-9)


@pytest.mark.parametrize("at, arm_mm", [("tip", R_O + H + 30.0), ("surface", R_O + 30.0)])
def test_a_shear_on_the_apex_by_hand(at, arm_mm):
    """1 N of local Fx on the apex element is +x, applied 30 mm + (20 mm, + 3 mm at the feeler's tip) above
    an F/T origin at (0, 0, -30): torque (0, arm, 0) N mm = (0, arm / 1000, 0) N m; and seen from an F/T
    sensor turned half a turn about x (its z down) the force is (1, 0, 0) and the torque (0, -arm, 0)."""
    f = np.zeros((N_EL, 3))
    f[0, 0] = 1.0
    w = element_wrench(SENSOR, SensorPose.from_string("0,0,-30"), f, at=at)
    np.testing.assert_allclose(w, [1.0, 0, 0, 0, arm_mm * 1e-3, 0], rtol=0, atol=1e-14)
    w = element_wrench(SENSOR, SensorPose.from_string("0,0,-30,180,0,0"), f, at=at)
    np.testing.assert_allclose(w, [1.0, 0, 0, 0, -arm_mm * 1e-3, 0], rtol=0, atol=1e-14)
    f = np.zeros((N_EL, 3))
    f[0, 2] = 1.0  # pressing the apex: down in the dome frame, up in the upside-down F/T frame
    w = element_wrench(SENSOR, SensorPose.from_string("0,0,-30,180,0,0"), f, at=at)
    np.testing.assert_allclose(w, [0, 0, 1.0, 0, 0, 0], rtol=0, atol=1e-14)


def test_contact_points_are_on_the_normal_at_the_surface_or_the_feeler_tip():
    n = unit_normal(45.0, 2 * math.pi * 3 / 16)  # element 12: ring 2, 4th of 16
    np.testing.assert_allclose(contact_points(SENSOR, "surface")[12], R_O * n, rtol=0, atol=1e-12)
    np.testing.assert_allclose(contact_points(SENSOR)[12], (R_O + H) * n, rtol=0, atol=1e-12)
    with pytest.raises(InputError, match=r"at must be one of tip, surface, got 'cone'"):
        contact_points(SENSOR, "cone")


def random_pose(rng, z=-40.0):
    rot = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    return SensorPose(rotation=rot, position=rng.uniform(-15, 15, 3) + [0, 0, z])


def random_forces(rng, t=4):
    f = rng.normal(scale=0.2, size=(t, N_EL, 3))
    f[..., 2] = rng.uniform(0, 1.5, (t, N_EL))
    return f


def test_the_force_part_is_frame_totals_resultant_rotated_into_the_ft_frame():
    rng = np.random.default_rng(1)
    f = random_forces(rng)
    contact = rng.random((4, N_EL)) < 0.6
    f[~contact] = 0.0
    pose = random_pose(rng)
    w = element_wrench(SENSOR, pose, f)
    resultant = frame_totals(SENSOR, f, contact)["resultant"]
    np.testing.assert_allclose(w[:, :3], resultant @ pose.rotation, rtol=0, atol=1e-12)  # R^T F, row-wise
    np.testing.assert_allclose(pose.rotation @ w[0, :3], resultant[0], rtol=0, atol=1e-12)


def test_the_torque_is_the_sum_of_r_cross_f_element_by_element():
    rng = np.random.default_rng(2)
    f = random_forces(rng, t=1)[0]
    pose = random_pose(rng)
    g = global_from_local(SENSOR, f)
    total = np.zeros(3)
    for e in range(N_EL):
        c = (R_O + H) * SENSOR.element_frames[e, 2]
        total += np.cross(c - pose.position, g[e])
    w = element_wrench(SENSOR, pose, f)
    np.testing.assert_allclose(pose.rotation @ w[3:] * 1e3, total, rtol=1e-12, atol=1e-12)


def test_the_matrix_is_the_map_element_wrench_applies():
    rng = np.random.default_rng(3)
    f = random_forces(rng, t=5)
    pose = random_pose(rng)
    m = wrench_matrix(SENSOR, pose)
    assert m.shape == (N_EL, 3, 6)
    np.testing.assert_allclose(f.reshape(5, -1) @ m.reshape(-1, 6), element_wrench(SENSOR, pose, f),
                               rtol=1e-12, atol=1e-14)
    # row j of m[e]: the wrench of 1 N along element e's local axis j
    unit = np.zeros((N_EL, 3))
    unit[7, 1] = 1.0
    np.testing.assert_allclose(m[7, 1], element_wrench(SENSOR, pose, unit), rtol=0, atol=1e-15)
    np.testing.assert_allclose(element_wrench(SENSOR, pose, f[2]), element_wrench(SENSOR, pose, f)[2],
                               rtol=0, atol=0)


def test_moving_the_ft_sensor_moves_the_wrench_by_the_r_cross_f_rule():
    """The wrench about pose A's origin, in A's frame, taken to the dome frame, moved to B's origin
    (t_B = t_A + (p_A - p_B) x F) and into B's frame is the wrench computed for pose B."""
    rng = np.random.default_rng(4)
    f = random_forces(rng, t=3)
    a, b = random_pose(rng, z=-30.0), random_pose(rng, z=-80.0)
    wa, wb = element_wrench(SENSOR, a, f), element_wrench(SENSOR, b, f)
    force = wa[:, :3] @ a.rotation.T  # rows: R_A F_A, in the dome frame
    torque = wa[:, 3:] @ a.rotation.T + np.cross((a.position - b.position) * 1e-3, force)
    np.testing.assert_allclose(force @ b.rotation, wb[:, :3], rtol=0, atol=1e-12)
    np.testing.assert_allclose(torque @ b.rotation, wb[:, 3:], rtol=0, atol=1e-13)
    # and back: B's wrench moved to A is A's
    back = wb[:, 3:] @ b.rotation.T + np.cross((b.position - a.position) * 1e-3, force)
    np.testing.assert_allclose(back @ a.rotation, wa[:, 3:], rtol=0, atol=1e-13)


def test_element_wrench_refuses_bad_forces():
    pose = SensorPose.from_string("0,0,-30")
    with pytest.raises(ShapeError, match=r"forces must have shape \(41, 3\) or \(T, 41, 3\).*got \(40, 3\)"):
        element_wrench(SENSOR, pose, np.zeros((40, 3)))
    f = np.zeros((N_EL, 3))
    f[3, 1] = np.nan
    with pytest.raises(InputError, match=r"forces must be finite, got nan at index \(3, 1\)"):
        element_wrench(SENSOR, pose, f)


# ---------------------------------------------------------------------------- the pose
def test_pose_strings_json_and_opencv_agree():
    rv = np.array([10.0, -20.0, 170.0])
    pos = np.array([3.0, -4.0, -35.0])
    p = SensorPose.from_string(",".join(map(str, [*pos, *rv])))
    rot = Rotation.from_rotvec(rv, degrees=True).as_matrix()
    np.testing.assert_allclose(p.rotation, rot, rtol=0, atol=1e-14)
    np.testing.assert_allclose(p.position, pos, rtol=0, atol=0)
    np.testing.assert_allclose(p.rotation_deg, rv, rtol=0, atol=1e-10)
    q = SensorPose.from_dict(p.to_dict())
    np.testing.assert_allclose(q.rotation, p.rotation, rtol=0, atol=1e-14)
    # OpenCV: the dome in the F/T frame, X_ft = Rcv X_dome + t: Rcv = R^T, t = -R^T p
    cv = {"rvec": Rotation.from_matrix(rot.T).as_rotvec().tolist(), "tvec": (-rot.T @ pos).tolist()}
    c = SensorPose.from_dict(cv)
    np.testing.assert_allclose(c.rotation, rot, rtol=0, atol=1e-12)
    np.testing.assert_allclose(c.position, pos, rtol=0, atol=1e-12)


def test_pose_files_and_parse(tmp_path):
    path = tmp_path / "ft_pose.json"
    path.write_text(json.dumps({"position_mm": [0, 0, -30], "rotation_deg": [180, 0, 0]}))
    p = SensorPose.parse(str(path), sensor=SENSOR)
    np.testing.assert_allclose(p.rotation, np.diag([1.0, -1.0, -1.0]), rtol=0, atol=1e-15)
    assert SensorPose.parse(path).position.tolist() == [0.0, 0.0, -30.0]
    assert SensorPose.parse(" 1, 2 ,-30 ").position.tolist() == [1.0, 2.0, -30.0]
    np.testing.assert_array_equal(SensorPose.parse("1,2,-30").rotation, np.eye(3))
    path.write_text(json.dumps({"position_mm": [0, 0, -30]}))
    np.testing.assert_array_equal(SensorPose.from_json(path).rotation, np.eye(3))


@pytest.mark.parametrize("text, match", [
    ("0,0", r"pose '0,0': expected 'x,y,z' .*or 'x,y,z,rx,ry,rz' .*; got 2 values"),
    ("0,0,-30,90", r"expected 'x,y,z' .*got 4 values"),
    ("", r"pose '': expected 'x,y,z'.*got 1 value$"),
    ("0;0;-30", r"got 1 value"),
    ("0,0,-30mm", r"z \(value 3\) is '-30mm', not a number; expected 'x,y,z'"),
    ("0,nan,-30", r"y \(value 2\) is 'nan', not finite"),
    ("0,0,-30,0,0,inf", r"rz \(value 6\) is 'inf', not finite"),
])
def test_bad_pose_strings_say_what_was_expected(text, match):
    with pytest.raises(InputError, match=match):
        SensorPose.from_string(text)


def test_a_pose_inside_the_dome_is_refused(tmp_path):
    with pytest.raises(InputError, match=r"F/T sensor's origin at \(0, 0, 5\) mm lies inside the dome "
                                         r"\(\|p\| = 5 mm < the outer radius 20 mm, z > 0\).*camera and the "
                                         r"light.*below the dome's base plane.*'0,0,-30'.*\(-0, -0, -5\) mm"):
        SensorPose.from_string("0,0,5", sensor=SENSOR)
    inside = SensorPose.from_string("3,4,10")  # |p| = 11.2 mm
    with pytest.raises(InputError, match=r"\(3, 4, 10\) mm lies inside the dome"):
        wrench_matrix(SENSOR, inside)
    with pytest.raises(InputError, match=r"lies inside the dome"):
        read_wrench(write(tmp_path, wrench_text()), SOURCES, pose=inside)
    # on or below the base plane, or beyond the dome: outside
    for text in ("0,0,0", "5,0,-1", "0,0,25", "30,0,5"):
        SensorPose.from_string(text, sensor=SENSOR)


@pytest.mark.parametrize("kwargs, err, match", [
    ({"rotation": [[1, 0.1, 0], [0, 1, 0], [0, 0, 1]]}, InputError,
     r"rotation must be orthonormal.*differs from I by 0.1"),
    ({"rotation": np.diag([1.0, 1.0, -1.0])}, InputError, r"got a reflection \(determinant -1\)"),
    ({"rotation": np.eye(2)}, ShapeError, r"rotation must be a \(3, 3\) matrix"),
    ({"position": [0, np.nan, -30]}, InputError, r"position must be finite \(x, y, z in mm\), got \[0.0, nan"),
    ({"position": [0, 0, -30, 1]}, ShapeError, r"position must be \(x, y, z\) in mm"),
    ({"position": [0, 0, -5000]}, InputError, r"5000 mm from the dome's centre, more than the 1000 mm.*in mm"),
    ({"rotation": [[np.inf, 0, 0], [0, 1, 0], [0, 0, 1]]}, InputError, r"rotation must be finite"),
])
def test_bad_poses_are_refused(kwargs, err, match):
    with pytest.raises(err, match=match):
        SensorPose(**kwargs)


@pytest.mark.parametrize("content, match", [
    ('{"position_mm": [0, 0, -30], "rvec": [0, 0, 0]}', r"mix the two forms"),
    ('{"position_mm": [0, 0, -30], "rotation": [0, 0, 0]}', r"unknown key\(s\) \['rotation'\]"),
    ('{"rotation_deg": [0, 0, 0]}', r"missing key\(s\) \['position_mm'\]"),
    ('{"rvec": [0, 0], "tvec": [0, 0, 30]}', r"rvec \(radians\) must be three numbers"),
    ('{"position_mm": ["0", 0, -30]}', r"position_mm must hold numbers, got '0'"),
    ('{"position_mm": [0, 0, -30],}', r"ft.json, line 1, column 29: not JSON"),
    ('[0, 0, -30]', r"expected a JSON object"),
    ('{"position_mm": [0, 0, 1e999]}', r"position_mm must be finite"),
])
def test_bad_pose_files_are_refused(tmp_path, content, match):
    path = tmp_path / "ft.json"
    path.write_text(content)
    with pytest.raises(InputError, match=match):
        SensorPose.from_json(path)


# ---------------------------------------------------------------------------- the wrench CSV
@pytest.mark.parametrize("funit", [None, "N", "mN", "gf", "kgf", "lbf", "ozf"])
@pytest.mark.parametrize("tunit", [None, *NM_PER])
def test_units_convert_to_newtons_and_newton_metres(tmp_path, funit, tunit):
    w = read_wrench(write(tmp_path, wrench_text(funit, tunit)), SOURCES)
    assert w.frames.tolist() == [1, 2, 3] and w.lines.tolist() == [2, 3, 4]
    np.testing.assert_allclose(w.wrench, expected(), rtol=1e-12, atol=0)
    np.testing.assert_array_equal(w.force, w.wrench[:, :3])
    np.testing.assert_array_equal(w.torque, w.wrench[:, 3:])


def test_columns_any_order_case_and_delimiter_frames_by_index(tmp_path):
    order = [3, 6, 0, 1, 5, 2, 4]
    for sep in (";", "\t"):
        text = wrench_text("mN", "N·mm", sep=sep, order=order).replace("Fx", "FX").replace("frame", "Frame")
        w = read_wrench(write(tmp_path, text), SOURCES)
        np.testing.assert_allclose(w.wrench, expected(), rtol=1e-12, atol=0)
    rows = {"3": WRENCH[3], "press_001.png": WRENCH[1]}  # by index and by name; frame 2 not listed
    text = "time,status," + wrench_text(rows=rows).replace("\n", "\n0.1,ok,")[:-len("0.1,ok,")]
    w = read_wrench(write(tmp_path, text), SOURCES)
    assert w.frames.tolist() == [1, 3] and w.lines.tolist() == [3, 2]
    np.testing.assert_allclose(w.wrench, [WRENCH[1], WRENCH[3]], rtol=1e-15, atol=0)


@pytest.mark.parametrize("encoding", ["utf-8-sig", "utf-16", "cp1252"])
def test_encodings_people_save_in(tmp_path, encoding):
    text = "# F/T-Messung für Sensor B, Drehmoment in N·mm\n" + wrench_text("N", "N·mm", sep=";")
    w = read_wrench(write(tmp_path, text, encoding=encoding), SOURCES)
    np.testing.assert_allclose(w.wrench, expected(), rtol=1e-12, atol=0)


def test_torque_unit_function():
    assert torque_unit("Tz (N·mm)") == 1e-3 and torque_unit("tz") == 1.0
    assert torque_unit("Tz [ozf·in]") == pytest.approx(LBF / 16 * 0.0254, rel=1e-12)


@pytest.mark.parametrize("header, err, match", [
    ("Tz (psi)", InputError, r"column 7 \('Tz \(psi\)'\): unknown torque unit 'psi'; the accepted units are "
                             r"N·m, mN·m, N·cm, N·mm, gf·cm, kgf·cm, kgf·m, lbf·in, lbf·ft, ozf·in"),
    ("Tz (kg·cm)", InputError, r"unknown torque unit 'kg·cm'.*a mass times a length.*write kgf·cm"),
    ("Tz (lb-in)", InputError, r"unknown torque unit 'lb-in'.*write lbf·in"),
    ("Tz (ft lb)", InputError, r"write lbf·ft"),
    ("Tz (N)", InputError, r"unknown torque unit 'N'.*'N' is a force unit, and tx, ty, tz are torques"),
    ("Tz (MN·m)", InputError, r"'MN·m' is meganewton metres; write mN·m"),
    ("Tz ()", InputError, r"unknown torque unit ''"),
    ("tz_Nmm", ShapeError, r"no column tz .*write 'tz_Nmm' as 'Tz \(unit\)'"),
])
def test_other_torque_units_are_refused_by_name(tmp_path, header, err, match):
    text = f"frame,fx,fy,fz,tx,ty,{header}\npress_001.png,0,0,-1,0,0.01,0\n"
    with pytest.raises(err, match=match):
        read_wrench(write(tmp_path, text), SOURCES)


@pytest.mark.parametrize("header, err, match", [
    ("Fz (N·m)", InputError, r"column 4 \('Fz \(N·m\)'\): unknown force unit 'N·m'.*'N·m' is a torque unit, "
                             r"and fx, fy, fz are forces"),
    ("Fz (g)", InputError, r"unknown force unit 'g'.*write gf"),
    ("Fz (MN)", InputError, r"'MN' is meganewton"),
    ("fz_mN", ShapeError, r"no column fz .*write 'fz_mN' as 'Fz \(unit\)'"),
])
def test_other_force_units_are_refused_by_name(tmp_path, header, err, match):
    text = f"frame,fx,fy,{header},tx,ty,tz\npress_001.png,0,0,-1,0,0.01,0\n"
    with pytest.raises(err, match=match):
        read_wrench(write(tmp_path, text), SOURCES)


@pytest.mark.parametrize("text, err, match", [
    ("frame,fx,fy,fz,mx,my,mz\n1,0,0,-1,0,0,0\n", ShapeError,
     r"line 1: no column tx, ty, tz in the header.*name the torque \(moment\) columns tx, ty, tz "
     r"\(found 'mx'\)"),
    ("frame,fx,fy,fz,tx,ty,tz,Fz (N)\n1,0,0,-1,0,0,0,-1\n", InputError,
     r"line 1: columns 4 \('fz'\) and 8 \('Fz \(N\)'\) both name fz.*ambiguous"),
    ("frame,fx,fy,fz,tx,ty,tz\n1,0,0,-1,0,0,0\n2,0,0,-1,0,0,0\n3,0,0,-1,0,0\n", ShapeError,
     r"line 4: expected 7 columns \(frame, fx, fy, fz, tx, ty, tz\), got 6"),
    ("", ShapeError, r"wrench.csv: empty; expected a header frame, fx, fy, fz, tx, ty, tz"),
    ("# only a comment\nframe,fx,fy,fz,tx,ty,tz\n", ShapeError, r"a header and no wrenches"),
])
def test_bad_headers_and_rows(tmp_path, text, err, match):
    with pytest.raises(err, match=match):
        read_wrench(write(tmp_path, text), SOURCES)


@pytest.mark.parametrize("row, match", [
    ("press_002.png,0,nan,-1,0,0,0",
     r"line 3, column 3 \('fy'\): expected a finite number \(fy in N\), got 'nan' \(not finite\)"),
    ("press_002.png,0,0,-1,0,0,-inf",
     r"line 3, column 7 \('tz'\): expected a finite number \(tz in N m\), got '-inf' \(not finite\)"),
    ("press_002.png,0,0,-1,0,1e400,0",
     r"column 6 \('ty'\): expected a finite number .*got '1e400' \(not finite\)"),
    ("press_002.png,0,0,n/a,0,0,0", r"column 4 \('fz'\): expected a finite number \(fz in N\), got 'n/a' "
                                    r"\(not a number\)"),
    ("press_002.png,0,0,,0,0,0", r"column 4 \('fz'\): expected a finite number \(fz in N\), got ''"),
])
def test_numbers_that_are_not_finite_are_refused(tmp_path, row, match):
    text = f"frame,fx,fy,fz,tx,ty,tz\npress_001.png,0,0,-1,0,0,0\n{row}\n"
    with pytest.raises(InputError, match=match):
        read_wrench(write(tmp_path, text), SOURCES)


def test_a_decimal_comma_is_named(tmp_path):
    text = "frame;fx;fy;fz;tx;ty;tz\npress_001.png;0;0;-1,5;0;0;0\n"
    with pytest.raises(InputError, match=r"column 4 \('fz'\): .*got '-1,5' \(not a number\); a decimal comma"):
        read_wrench(write(tmp_path, text), SOURCES)


def test_unknown_frames_are_all_named(tmp_path):
    text = ("frame,fx,fy,fz,tx,ty,tz\npress_001.png,0,0,-1,0,0,0\npress_009.png,0,0,-1,0,0,0\n"
            "4,0,0,-1,0,0,0\n-1,0,0,-1,0,0,0\n")
    with pytest.raises(InputError, match=r"wrench.csv: 3 frames not among the 4 frames: 'press_009.png' "
                                         r"\(line 3\), '4' \(line 4\), '-1' \(line 5\); name each frame as the "
                                         r"'source' column of optitact process does \('noload.png', "
                                         r"'press_001.png', 'press_002.png', \.\.\.\) or by its 0-based index "
                                         r"0..3"):
        read_wrench(write(tmp_path, text), SOURCES)


def test_a_frame_listed_twice_is_refused(tmp_path):
    text = "frame,fx,fy,fz,tx,ty,tz\npress_001.png,0,0,-1,0,0,0\n1,0,0,-2,0,0,0\n"
    with pytest.raises(InputError, match=r"line 3: frame 'press_001.png' \(frame 1\) is listed twice \(also on "
                                         r"line 2\); one row per frame"):
        read_wrench(write(tmp_path, text), SOURCES)


def test_a_name_shared_by_two_frames_must_be_given_by_index(tmp_path):
    sources = ["a/press.png", "press.png", "press.png"]
    text = "frame,fx,fy,fz,tx,ty,tz\npress.png,0,0,-1,0,0,0\n"
    with pytest.raises(InputError, match=r"frame 'press.png' names 2 frames \(frames 1, 2.*0-based index "
                                         r"instead"):
        read_wrench(write(tmp_path, text), sources)
    w = read_wrench(write(tmp_path, text.replace("press.png", "2")), sources)
    assert w.frames.tolist() == [2]


def test_a_force_beyond_200_n_is_a_unit_mistake(tmp_path):
    text = "frame,fx,fy,fz,tx,ty,tz\npress_001.png,0,0,-1,0,0,0\npress_002.png,30,0,-500,0,0.01,0\n"
    with pytest.raises(InputError, match=r"line 3: frame 'press_002.png': a force of 500.89\d* N is beyond the "
                                         r"200 N.*name it in the header \(e.g. 'Fz \(mN\)'\)"):
        read_wrench(write(tmp_path, text), SOURCES)
    text = text.replace("fx,fy,fz", "fx (mN),fy (mN),fz (mN)")
    w = read_wrench(write(tmp_path, text), SOURCES)
    np.testing.assert_allclose(w.force[1], [0.03, 0, -0.5], rtol=1e-15)


def test_torques_in_n_mm_read_as_n_m_are_refused(tmp_path):
    """2 N pressed 53 mm from the F/T origin with a 1 N shear: 53 N mm of torque, which read as N m puts
    the force 23.7 m away: beyond 10 x (20 + 3) mm = 0.23 m. Written with its unit it reads fine."""
    text = "frame,fx,fy,fz,tx,ty,tz\npress_001.png,1,0,-2,0,53,0\n"
    with pytest.raises(InputError, match=r"line 2: frame 'press_001.png': a torque of 53 N m with a force of "
                                         r"2.236\d* N puts the force 23.7\d* m from the F/T sensor's origin, "
                                         r"more than 10 times the dome's size plus the F/T offset \(0.23 m\).*"
                                         r"'Tz \(N·mm\)'"):
        read_wrench(write(tmp_path, text), SOURCES)
    text = text.replace("tx,ty,tz", "tx (N·mm),ty (N·mm),tz (N·mm)")
    np.testing.assert_allclose(read_wrench(write(tmp_path, text), SOURCES).torque, [[0, 0.053, 0]], rtol=1e-15)


def test_the_lever_arm_bound_grows_with_the_pose_and_spares_no_load_noise(tmp_path):
    # 2 N m with 1 N: 2 m away, beyond 0.23 m, within 10 x (20 + 3 + 300) mm = 3.23 m of an F/T sensor
    # 300 mm below
    text = "frame,fx,fy,fz,tx,ty,tz\npress_001.png,0,0,-1,2,0,0\n"
    with pytest.raises(InputError, match=r"puts the force 2 m from"):
        read_wrench(write(tmp_path, text), SOURCES)
    w = read_wrench(write(tmp_path, text), SOURCES, pose=SensorPose.from_string("0,0,-300"))
    assert w.torque.tolist() == [[2.0, 0.0, 0.0]]
    # a tared no-load frame's noise: no force and 1 mN m passes (the force counts as 0.05 N: 11.5 mN m allowed)
    text = "frame,fx,fy,fz,tx,ty,tz\nnoload.png,0,0,0,0.001,0,0\npress_001.png,0,0,-1,0,0,0.01\n"
    w = read_wrench(write(tmp_path, text), SOURCES)
    assert w.frames.tolist() == [0, 1]
    with pytest.raises(InputError, match=r"line 2: frame 'noload.png': a torque of 0.02 N m with a force of "
                                         r"0 N"):
        read_wrench(write(tmp_path, text.replace("0.001", "0.02")), SOURCES)


def test_a_file_of_zero_forces_is_refused(tmp_path):
    text = "frame,fx,fy,fz,tx,ty,tz\nnoload.png,0,0,0,0,0,0\npress_001.png,0,0,0.0,0.001,0,0\n"
    with pytest.raises(InputError, match=r"wrench.csv: the force is 0 in every frame: no wrench to fit from"):
        read_wrench(write(tmp_path, text), SOURCES)


@pytest.mark.parametrize("data, match", [
    (wrench_text().encode("utf-16-le"), r"wrench.csv: holds NUL characters: UTF-16 without a byte-order mark"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe", r"wrench.csv: not a text file in UTF-8 or UTF-16"),
    (("frame,fx,fy,fz,tx,ty,tz\npress_001.png,0,0,-1,0,0," + "1" * 140_000 + "\n").encode(),
     r"wrench.csv, line 2: 140\d\d\d characters long, more than the 131072"),
])
def test_files_that_are_not_wrench_csvs_are_refused(tmp_path, data, match):
    p = tmp_path / "wrench.csv"
    p.write_bytes(data)
    with pytest.raises(InputError, match=match):
        read_wrench(p, SOURCES)


def test_a_missing_file():
    with pytest.raises(FileNotFoundError, match=r"F/T sensor wrench file not found: .*nowhere.csv"):
        read_wrench("nowhere.csv", SOURCES)


def test_wrenches_read_match_element_wrench_of_known_forces(tmp_path):
    """End to end: forces on a few elements, their wrench written by an F/T sensor upside down 35 mm below in
    N·mm and mN, read back as the wrench element_wrench gives."""
    rng = np.random.default_rng(5)
    f = np.zeros((len(SOURCES), N_EL, 3))
    for t, els in ((1, [0]), (2, [3, 4]), (3, [20, 21, 30])):
        f[t, els, 2] = rng.uniform(0.3, 1.5, len(els))
        f[t, els, :2] = rng.uniform(-0.2, 0.2, (len(els), 2))
    pose = SensorPose.from_string("2,-1,-35,180,0,0", sensor=SENSOR)
    truth = element_wrench(SENSOR, pose, f)
    rows = {t: truth[t] * [1e3, 1e3, 1e3, 1e3, 1e3, 1e3] for t in (1, 2, 3)}
    text = "frame,fx (mN),fy (mN),fz (mN),tx (N·mm),ty (N·mm),tz (N·mm)\n" + "".join(
        f"{SOURCES[t]},{','.join(f'{v:.17g}' for v in w)}\n" for t, w in rows.items())
    w = read_wrench(write(tmp_path, text), SOURCES, pose=pose, sensor=SENSOR)
    np.testing.assert_allclose(w.wrench, truth[1:], rtol=1e-12, atol=1e-15)


# ---------------------------------------------------------------------------- identifiability
def alone(elements, times=3, n_el=N_EL):
    """Frames loading each of ``elements`` alone, ``times`` each."""
    rows = []
    for e in elements:
        for _ in range(times):
            r = np.zeros(n_el, bool)
            r[e] = True
            rows.append(r)
    return np.array(rows).reshape(-1, n_el)


def test_never_loaded_elements_are_named():
    loaded = alone([e for e in range(N_EL) if e not in (3, 17)])
    with pytest.raises(UnidentifiableError, match=r"the 117 frames with a known wrench cannot pin down every "
                                                  r"element's scale: press elements 3 and 17 at least 3 times "
                                                  r"each \(frames loading them: 3: 0, 17: 0\)") as exc:
        check_identifiable(loaded)
    assert exc.value.counts[3] == exc.value.counts[17] == 0 and exc.value.counts[0] == 3
    assert isinstance(exc.value, InputError)
    # too few frames on one
    loaded = np.vstack([alone(range(N_EL), 2), alone([5])])
    with pytest.raises(UnidentifiableError, match=r"press elements 0, 1, 2, 3, 4, 6, .* at least 3 times each"):
        check_identifiable(loaded)
    assert check_identifiable(loaded, min_frames=2)[5] == 5
    # elements the fit does not free need nothing
    counts = check_identifiable(alone(range(10)), elements=range(10))
    assert counts.tolist() == [3] * 10 + [0] * (N_EL - 10)


def test_elements_always_loaded_together_are_named():
    loaded = alone([e for e in range(N_EL) if e not in (4, 5)])
    both = np.zeros((37, N_EL), bool)
    both[:, [4, 5]] = True
    both[::3, 6] = True  # with a neighbour now and then: 4 and 5 still never apart
    loaded = np.vstack([loaded, both])
    with pytest.raises(UnidentifiableError, match=r"elements 4 and 5 were always loaded together, in all 37 "
                                                  r"frames where either was: press one without the "
                                                  r"other") as exc:
        check_identifiable(loaded)
    assert exc.value.groups == [(4, 5)]
    assert "dependent" not in str(exc.value)  # the pair is not reported twice
    loaded[0, 4] = True  # one frame of 4 without 5 (and with 0)
    check_identifiable(loaded)


def test_a_rank_deficient_pattern_names_its_smallest_group():
    """Elements 10, 11, 12, 13 pressed in pairs {10, 11}, {12, 13}, {10, 12}, {11, 13}: no two columns alike,
    but 10 - 11 - 12 + 13 loads nothing in every frame, so scales (s + a, s - a, s - a, s + a) fit alike."""
    loaded = alone([e for e in range(N_EL) if e not in (10, 11, 12, 13)])
    pairs = []
    for pair in ([10, 11], [12, 13], [10, 12], [11, 13]):
        for _ in range(3):
            r = np.zeros(N_EL, bool)
            r[pair] = True
            pairs.append(r)
    loaded = np.vstack([loaded, pairs])
    assert not np.any(loaded[:, [10, 11, 12, 13]].astype(int) @ [1, -1, -1, 1])  # the test's own truth
    with pytest.raises(UnidentifiableError, match=r"elements 10, 11, 12 and 13 are loaded in dependent "
                                                  r"patterns: every frame loads as many of elements 10 and 13 "
                                                  r"as of elements 11 and 12.*press them in other "
                                                  r"combinations") as exc:
        check_identifiable(loaded)
    assert exc.value.groups == [(10, 11, 12, 13)]
    assert np.linalg.matrix_rank(loaded.astype(float)) == N_EL - 1
    check_identifiable(np.vstack([loaded, alone([11])]))  # 11 alone breaks it


def test_a_good_random_pattern_is_accepted():
    rng = np.random.default_rng(6)
    loaded = np.zeros((300, N_EL), bool)
    for row in loaded:
        row[rng.choice(N_EL, size=rng.integers(1, 5), replace=False)] = True
    counts = check_identifiable(loaded)
    np.testing.assert_array_equal(counts, loaded.sum(axis=0))
    assert counts.min() >= 3


def test_check_identifiable_refuses_bad_arrays():
    with pytest.raises(TypeError, match=r"loaded must be a boolean"):
        check_identifiable(np.full((3, N_EL), 0.5))
    with pytest.raises(ShapeError, match=r"loaded must have shape \(n_frames, E\), got \(41,\)"):
        check_identifiable(np.ones(N_EL, bool))
    with pytest.raises(InputError, match=r"elements must be among 0..40, got \[41\]"):
        check_identifiable(np.ones((3, N_EL), bool), elements=[41])
    assert check_identifiable(np.eye(4, dtype=int), min_frames=1).tolist() == [1, 1, 1, 1]
