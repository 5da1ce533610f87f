"""The force gauge's CSV as researchers write it: units in the header, impossible forces, two columns of
one name, other encodings, absurd lines.

In-process tests read the CSV with :func:`optitact.calib.gauge.read_presses`; outside-in tests run the installed
``optitact calibrate fit`` on a few frames of a stand-in sensor (two-stage renders, 10 % brighter than the
model) with the same presses written in different units, and on broken gauge files.
"""

from __future__ import annotations

import re
import warnings

import numpy as np
import pytest
from optitact.calib.fit import Calibration
from optitact.calib.gauge import read_presses

import optitact
from optitact.errors import InputError, OptitactWarning, ShapeError

SENSOR = optitact.optics.sensor.DomeSensor.default()
N_EL = SENSOR.n_elements
SOURCES = ["noload.png", "press_001.png", "press_002.png"]

# N per unit, from the definitions (not from the package): the standard gravity 9.80665 m/s²,
# 1 lb = 0.45359237 kg, 1 oz = 1/16 lb
N_PER = {"N": 1.0, "mN": 1e-3, "kN": 1e3, "gf": 9.80665e-3, "kgf": 9.80665, "lbf": 0.45359237 * 9.80665,
         "ozf": 0.45359237 * 9.80665 / 16}

PRESSES = np.array([[0.05, -0.02, 0.5], [0.0, 0.0, 0.25], [-0.1, 0.03, 0.8]])  # N: (frame 1, el 3), ...
AT = [(1, 3), (1, 7), (2, 3)]


def gauge_text(unit: str | None, header: str = "{axis} ({unit})", sep: str = ",") -> str:
    """The presses of PRESSES with the force columns in ``unit`` (None: no unit), 17 digits."""
    scale = N_PER[unit or "N"]
    cols = [header.format(axis=a, unit=unit) if unit else a for a in ("Fx", "Fy", "Fz")]
    rows = [sep.join(["frame", "element", *cols])]
    for (t, e), f in zip(AT, PRESSES, strict=True):
        rows.append(sep.join([SOURCES[t], str(e), *(f"{v / scale:.17g}" for v in f)]))
    return "\n".join(rows) + "\n"


def write(tmp_path, text, name="gauge.csv", encoding="utf-8"):
    p = tmp_path / name
    p.write_bytes(text.encode(encoding))
    return p


def expected_forces():
    f = np.zeros((len(SOURCES), N_EL, 3))
    for (t, e), v in zip(AT, PRESSES, strict=True):
        f[t, e] = v
    return f


# ---------------------------------------------------------------------------- units
@pytest.mark.parametrize("unit, header", [
    ("N", "{axis} ({unit})"), ("mN", "{axis} ({unit})"), ("mN", "{axis} [{unit}]"), ("kN", "{axis} ({unit})"),
    ("gf", "{axis} ({unit})"), ("kgf", "{axis}  [ {unit} ]"), ("lbf", "{axis} ({unit})"),
    ("ozf", "{axis} ({unit})"),
])
def test_force_units_convert_to_newtons(tmp_path, unit, header):
    f, pressed = read_presses(write(tmp_path, gauge_text(unit, header)), SOURCES, SENSOR)
    np.testing.assert_allclose(f, expected_forces(), rtol=1e-12, atol=0)
    assert pressed.sum() == 3


def test_units_any_case_and_per_column(tmp_path):
    text = "frame,element,FX (mn),fy (n),FZ (KGF)\npress_001.png,3,50,-0.02,0.1\n"
    f, _ = read_presses(write(tmp_path, text), SOURCES, SENSOR)
    np.testing.assert_allclose(f[1, 3], [0.05, -0.02, 0.980665], rtol=1e-12, atol=0)


@pytest.mark.parametrize("header, err, match", [
    ("Fz (psi)", InputError,
     r"column 5 \('Fz \(psi\)'\): unknown force unit 'psi'; the accepted units are N, mN, kN, gf, kgf, "
     r"lbf, ozf"),
    ("Fz (g)", InputError, r"unknown force unit 'g'.*'g' is a mass: if the gauge reads gf .*, write gf"),
    ("Fz (lb)", InputError, r"unknown force unit 'lb'.*write lbf"),
    ("Fz (MN)", InputError, r"'MN' is meganewton; write mN"),
    ("Fz ()", InputError, r"unknown force unit ''"),
    ("fz_mN", ShapeError, r"no column fz .*write 'fz_mN' as 'Fz \(unit\)'"),
])
def test_other_units_are_refused_by_name(tmp_path, header, err, match):
    text = f"frame,element,fx,fy,{header}\npress_001.png,3,0,0,500\n"
    with pytest.raises(err, match=match):
        read_presses(write(tmp_path, text), SOURCES, SENSOR)


def test_two_columns_of_one_name_are_ambiguous(tmp_path):
    text = "frame,element,fx,fy,fz,Fz (N)\npress_001.png,3,0,0,500,0.5\n"
    with pytest.raises(InputError,
                       match=r"line 1: columns 5 \('fz'\) and 6 \('Fz \(N\)'\) both name fz.*ambiguous"):
        read_presses(write(tmp_path, text), SOURCES, SENSOR)
    text = "Frame,element,fx,fy,fz,frame\npress_001.png,3,0,0,0.5,press_002.png\n"
    with pytest.raises(InputError, match=r"columns 1 \('Frame'\) and 6 \('frame'\) both name frame"):
        read_presses(write(tmp_path, text), SOURCES, SENSOR)


# ---------------------------------------------------------------------------- impossible forces
@pytest.mark.parametrize("row, match", [
    ("press_002.png,5,0,0,-0.3", r"line 3: frame 'press_002.png', element 5: Fz = -0.3 N is a pull"),
    ("press_002.png,5,1e6,0,0.3",
     r"line 3: frame 'press_002.png', element 5: Fx = 1e\+06 N is beyond the 100 N"),
    ("press_002.png,5,0,0,1e300", r"line 3: .*element 5: Fz = 1e\+300 N is beyond the 100 N.*'Fz \(mN\)'"),
    ("press_002.png,5,0.1,0,0", r"line 3: .*element 5: a shear of \(0.1, 0\) N with Fz = 0"),
    ("press_002.png,5,0,0,1e400", r"line 3, column 5: '1e400' is not finite"),
    ("press_002.png,5,0,0,inf", r"line 3, column 5: 'inf' is not finite"),
])
def test_impossible_forces_are_refused(tmp_path, row, match):
    text = f"frame,element,fx,fy,fz\npress_001.png,3,0,0,0.5\n{row}\n"
    with pytest.raises(InputError, match=match):
        read_presses(write(tmp_path, text), SOURCES, SENSOR)


def test_a_global_pull_is_refused_in_the_elements_frame(tmp_path):
    normal = SENSOR.element_frames[9][2]  # outward: a global force along it pulls the element
    g = 0.4 * normal
    text = ("frame,element,fx,fy,fz,frame_of_reference\n"
            f"press_001.png,9,{g[0]:.17g},{g[1]:.17g},{g[2]:.17g},global\n")
    with pytest.raises(InputError, match=r"line 2: frame 'press_001.png', element 9: Fz = -0.4 N is a pull.*"
                                         r"converted from global"):
        read_presses(write(tmp_path, text), SOURCES, SENSOR)


def test_zero_fz_on_every_row_is_refused(tmp_path):
    text = "frame,element,fx,fy,fz\npress_001.png,3,0,0,0\npress_002.png,4,0,0,0.0\n"
    with pytest.raises(InputError, match=r"gauge.csv: Fz is 0 on every row: no press to fit or test"):
        read_presses(write(tmp_path, text), SOURCES, SENSOR)
    # one zero-force row among presses is a no-load sample, read as it is
    text = "frame,element,fx,fy,fz\npress_001.png,3,0,0,0\npress_002.png,4,0,0,0.2\n"
    f, pressed = read_presses(write(tmp_path, text), SOURCES, SENSOR)
    assert pressed[1, 3] and not f[1, 3].any() and f[2, 4, 2] == 0.2


def test_fit_presses_refuses_impossible_arrays():
    from optitact.calib.press_fit import fit_presses
    from optitact.calib.shipped import default_calibration

    from optitact.pipeline.readings import Readings

    G = np.full((2, N_EL), 1e4)
    r = Readings(G, np.zeros((2, N_EL, 2)), np.ones((2, N_EL), bool), np.zeros((2, N_EL), bool))
    f = np.zeros((2, N_EL, 3))
    f[..., 2] = 0.3
    cam = default_calibration().camera
    for (t, e, axis), v, match in [
            ((1, 4, 2), -0.2, r"forces\[1, 4\] \(frame 1, element 4\): Fz = -0.2 N is a pull"),
            ((0, 2, 0), 1e6, r"forces\[0, 2\].*Fx = 1e\+06 N is beyond the 100 N")]:
        bad = f.copy()
        bad[t, e, axis] = v
        with pytest.raises(InputError, match=match):
            fit_presses(r, bad, sensor=SENSOR, camera=cam, start="default")
    with pytest.raises(InputError, match=r"no press with Fz > 0: nothing to fit from"):
        fit_presses(r, np.zeros_like(f), pressed=np.ones((2, N_EL), bool), sensor=SENSOR, camera=cam,
                    start="default")


# ---------------------------------------------------------------------------- encodings and lines
@pytest.mark.parametrize("encoding", ["utf-8", "utf-8-sig", "utf-16", "utf-16-be-bom", "cp1252", "latin-1"])
def test_encodings_people_save_in(tmp_path, encoding):
    """Excel's "CSV UTF-8" (BOM), "Unicode text" (UTF-16 with BOM, tab-separated) and "CSV" on Western
    Windows (cp1252) all read the same presses; a comment holds non-ASCII letters."""
    text = "# Kraftmessung für Sensor B — µ ≈ 0.3\n".replace("≈", "=") + gauge_text("mN", sep="\t")
    if encoding == "utf-16-be-bom":
        data = b"\xfe\xff" + text.encode("utf-16-be")
    elif encoding in ("cp1252", "latin-1"):
        data = text.replace("—", "-").encode(encoding)
    else:
        data = text.encode(encoding)
    p = tmp_path / "gauge.csv"
    p.write_bytes(data)
    f, _ = read_presses(p, SOURCES, SENSOR)
    np.testing.assert_allclose(f, expected_forces(), rtol=1e-12, atol=0)


@pytest.mark.parametrize("data, match", [
    (gauge_text("N").encode("utf-16-le"), r"gauge.csv: holds NUL characters: UTF-16 without a byte-order mark"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xff\xfe",
     r"gauge.csv: not a text file in UTF-8 or UTF-16.*'CSV UTF-8'"),
    (b"\xff\xfe" + b"\x00\xd8" + b"a\x00", r"gauge.csv: not a text file in UTF-8 or UTF-16 \(utf-16 fails"),
])
def test_files_that_are_not_text_are_refused(tmp_path, data, match):
    p = tmp_path / "gauge.csv"
    p.write_bytes(data)
    with pytest.raises(InputError, match=match):
        read_presses(p, SOURCES, SENSOR)


@pytest.mark.parametrize("line", ["press_002.png,4,0,0," + "1" * 140_000, '"' + "x" * 140_000 + '",4,0,0,1'])
def test_a_line_over_128_kib_is_refused(tmp_path, line):
    text = f"frame,element,fx,fy,fz\npress_001.png,3,0,0,0.5\n{line}\n"
    with pytest.raises(InputError, match=r"gauge.csv, line 3: 140\d\d\d characters long, more than the 131072"):
        read_presses(write(tmp_path, text), SOURCES, SENSOR)


# ---------------------------------------------------------------------------- outside in
@pytest.fixture(scope="module")
def presses(tmp_path_factory):
    """Frames of a stand-in 10 % brighter than the model: a no-load frame and 5 mixed-load frames (every
    element pressed), rendered two-stage with the shipped emission table; and their forces (N)."""
    from optitact.calib.patterns import design_forces
    from optitact.calib.sets import Design
    from optitact.calib.shipped import default_calibration
    from optitact.render import render

    from optitact.io.files import write_png
    from optitact.optics.ccd import CCD

    folder = tmp_path_factory.mktemp("gauge-presses")
    frames = folder / "frames"
    frames.mkdir()
    cam = default_calibration().camera
    ccd = CCD()
    bg = np.zeros(cam.shape, np.float32)
    forces = design_forces(5, N_EL, Design(fz_max=0.9), seed=11)
    forces[:, :, 2] = np.maximum(forces[:, :, 2], 0.15)
    write_png(frames / "press_000.png", ccd.expose(bg, seed=0))
    for t, f in enumerate(forces):
        radiance = render(SENSOR, f, camera=cam, transport="two_stage", background=bg)
        write_png(frames / f"press_{t + 1:03d}.png", ccd.expose(1.1 * radiance, seed=1 + t))
    return frames, forces


def presses_csv(forces, unit: str, encoding: str = "utf-8") -> bytes:
    scale = N_PER[unit]
    rows = [f"frame,element,Fx ({unit}),Fy ({unit}),Fz ({unit})"]
    rows += [f"press_{t + 1:03d}.png,{e}," + ",".join(f"{v / scale:.17g}" for v in forces[t, e])
             for t in range(len(forces)) for e in range(N_EL)]
    return ("\n".join(rows) + "\n").encode(encoding)


@pytest.fixture(scope="module")
def in_newtons(presses, tmp_path_factory):
    """The calibration refined from the shipped one on the presses written in N (in this process)."""
    from optitact.calib.press_fit import fit_from_frames

    frames, forces = presses
    gauge = tmp_path_factory.mktemp("gauge-n") / "gauge.csv"
    gauge.write_bytes(presses_csv(forces, "N"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", OptitactWarning)
        return fit_from_frames([frames], gauge, start="default")


@pytest.mark.parametrize("unit, encoding", [("mN", "utf-8"), ("kgf", "utf-16"), ("lbf", "cp1252")])
def test_cli_fit_reads_the_gauges_units(user, presses, in_newtons, unit, encoding):
    """`calibrate fit --start default` on the same presses written in mN, kgf (UTF-16, Excel's "Unicode
    text") or lbf gives the calibration fitted to them in N: every element's shape to 1e-6, and the
    stand-in's 10 % brightness corrected (its held-out Fz error a third of the start's or less)."""
    frames, forces = presses
    user.path("gauge.csv").write_bytes(presses_csv(forces, unit, encoding))
    r = user.run("calibrate", "fit", "--frames", frames, "--forces", "gauge.csv", "--start", "default",
                 "--out", "mine.json")
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    cal = Calibration.load(user.path("mine.json"))
    ref = in_newtons.provenance
    assert cal.provenance["fit"] == ref["fit"] == "shapes"
    for name, values in ref["theta"].items():
        np.testing.assert_allclose(cal.provenance["theta"][name], values, rtol=1e-6, atol=1e-9, err_msg=name)
    held_out = cal.provenance["held_out"]["rmse_n"]
    assert held_out["refined"]["fz"] < held_out["start"]["fz"] / 3, held_out


def changed(forces, t: int, e: int, value) -> np.ndarray:
    out = forces.copy()
    out[t, e] = value
    return out


BROKEN = {  # what the file holds, and the error (the rows of frame t, element e are on line 2 + 41 t + e)
    "utf-16 without BOM": (lambda f: presses_csv(f, "N", "utf-16-le"),
                           r"gauge.csv: holds NUL characters: UTF-16 without a byte-order mark"),
    "1e300": (lambda f: presses_csv(changed(f, 1, 4, (1e300, 0, 0.5)), "N"),
              r"gauge.csv, line 47: frame 'press_002.png', element 4: Fx = 1e\+300 N is beyond the 100 N"),
    "negative fz": (lambda f: presses_csv(changed(f, 2, 7, (0, 0, -0.4)), "N"),
                    r"gauge.csv, line 91: frame 'press_003.png', element 7: Fz = -0.4 N is a pull"),
    "zero fz": (lambda f: presses_csv(changed(f, slice(None), slice(None), 0.0), "N"), r"Fz is 0 on every row"),
    "two fz": (lambda f: b"frame,element,fx,fy,fz,Fz (N)\npress_001.png,0,0,0,0.5,0.5\n",
               r"columns 5 \('fz'\) and 6 \('Fz \(N\)'\) both name fz"),
    "unit": (lambda f: b"frame,element,fx,fy,Fz (psi)\npress_001.png,0,0,0,0.5\n", r"unknown force unit 'psi'"),
    "long line": (lambda f: b"frame,element,fx,fy,fz\npress_001.png,0,0,0," + b"5" * 140_000 + b"\n",
                  r"gauge.csv, line 2: 140020 characters long"),
}


@pytest.mark.parametrize("case", list(BROKEN))
def test_cli_refuses_broken_gauge_files_in_one_line(user, presses, case):
    """Each a one-line error naming the file and what is wrong, exit 2 (no traceback)."""
    make, match = BROKEN[case]
    frames, forces = presses
    user.path("gauge.csv").write_bytes(make(forces))
    r = user.run("calibrate", "fit", "--frames", frames, "--forces", "gauge.csv", "--start", "default",
                 "--out", "mine.json")
    assert r.returncode == 2, r.stderr
    errors = [ln for ln in r.stderr.splitlines() if ln.startswith("optitact: error:")]
    assert len(errors) == 1 and "Traceback" not in r.stderr, r.stderr
    assert "gauge.csv" in errors[0] and re.search(match, errors[0]), errors[0]
    assert not user.path("mine.json").exists()
