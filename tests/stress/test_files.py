"""Calibration files: valid, truncated, garbage, pickles, deep nesting, huge numbers, any edited value."""

from __future__ import annotations

import json
import pickle
import re

import numpy as np
import pytest
from hypothesis import strategies as st
from optitact.calib.document import CalibrationMismatchError
from optitact.calib.fit import Calibration

from optitact.errors import InputError, OptitactWarning
from optitact.optics.camera import FisheyeCamera
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.readings import Readings

from .helpers import LONE, SMALL, Touch, coupled_set
from .strategies import counted, rng_of, seeds, stress

_W = {"broken": 5, "edited": 7}
SHARE = {k: v / sum(_W.values()) for k, v in _W.items()}


@pytest.fixture(scope="module")
def cal_doc():
    f, r = coupled_set(np.random.default_rng(5), 40)
    cal = Calibration.fit(r, f, sensor=LONE, camera=SMALL, pipeline_options={"noise_sigma": 0.5})
    return cal, cal.to_dict()


def _paths(d, path=()):
    yield path
    if isinstance(d, dict):
        for k, v in d.items():
            yield from _paths(v, path + (k,))
    elif isinstance(d, list):
        for i, v in enumerate(d):
            yield from _paths(v, path + (i,))


def _get(d, path):
    for k in path:
        d = d[k]
    return d


def _floats(doc):
    return [p for p in _paths(doc) if p and isinstance(_get(doc, p), float)]


@stress("calibration_file", SHARE["broken"], seed=seeds,
        kind=st.sampled_from(["valid"] * 2 + ["truncated"] * 6 + ["garbage"] * 2 + ["pickle", "deep_nesting",
                             "huge_number", "nan_literal"] + ["wrong_version"] * 2 + ["wrong_schema"] * 2
                             + ["missing_key"] * 4 + ["wrong_sensor"] * 2 + ["edited_sensor"] * 2))
def test_broken_calibration_files_load_right_or_fail_clearly(cal_doc, tmp_path_factory, seed, kind):
    rng = rng_of(seed)
    cal, doc = cal_doc
    doc = json.loads(json.dumps(doc))
    text = json.dumps(doc)
    tmp = tmp_path_factory.mktemp("cal")
    path = tmp / "c.json"

    def load(**kw):
        return Calibration.load(path, **kw)

    if kind == "valid":
        path.write_text(text)
        back = load(sensor=LONE, camera=SMALL)
        _loaded_is_sane(back, doc)
        assert back.fingerprint == cal.fingerprint
    elif kind == "truncated":
        path.write_text(text[:int(rng.integers(0, len(text) - 1))])
        with pytest.raises(InputError, match="not a JSON calibration"):
            load()
    elif kind == "garbage":
        path.write_bytes(rng.integers(0, 256, int(rng.integers(1, 4000)), dtype=np.uint8).tobytes())
        with pytest.raises(InputError):
            load()
    elif kind == "pickle":
        marker = tmp / "executed"
        path.write_bytes(pickle.dumps(Touch(str(marker))) if rng.random() < 0.5 else
                         b"__import__('pathlib').Path(%r).touch()" % str(marker).encode())
        with pytest.raises(InputError, match="not a JSON calibration"):
            load()
        assert not marker.exists(), "loading a calibration executed code from the file"
    elif kind == "deep_nesting":
        depth = int(rng.integers(10_000, 200_000))
        deep = "[" * depth + "]" * depth if rng.random() < 0.5 else '{"a":' * depth + "1" + "}" * depth
        path.write_text(deep)
        with pytest.raises(InputError):
            load()
    elif kind == "huge_number":  # beyond float64 (>= 310 digits) or Python's int parsing (> 4300)
        p = _floats(doc)[int(rng.integers(len(_floats(doc))))]
        _get(doc, p[:-1])[p[-1]] = "__BIG__"
        path.write_text(json.dumps(doc).replace('"__BIG__"', "9" * int(rng.integers(310, 6000))))
        with pytest.raises(InputError):
            load()
    elif kind == "nan_literal":
        p = _floats(doc)[int(rng.integers(len(_floats(doc))))]
        _get(doc, p[:-1])[p[-1]] = float(rng.choice([np.nan, np.inf, -np.inf]))
        path.write_text(json.dumps(doc))
        with pytest.raises(InputError, match="not a JSON calibration"):
            load()
    elif kind == "wrong_version":
        doc["schema_version"] = [0, 4, -1, "2", None, True, 1.5, [2]][int(rng.integers(8))]
        path.write_text(json.dumps(doc))
        with pytest.raises(InputError, match="schema version"):
            load()
    elif kind == "wrong_schema":
        which = int(rng.integers(3))
        if which == 0:
            doc["schema"] = ["other", None, 1, ""][int(rng.integers(4))]
        path.write_text(json.dumps(doc if which == 0 else [doc] if which == 1 else "calibration"))
        with pytest.raises(InputError, match="not an optitact calibration" if which == 0 else "JSON object"):
            load()
    elif kind == "missing_key":
        top = ("model", "sensor", "camera", "pipeline", "elements", "fingerprint", "schema")
        keys = [p for p in _paths(doc) if len(p) in (1, 2) and p[0] in top]
        p = keys[int(rng.integers(len(keys)))]
        del _get(doc, p[:-1])[p[-1]]
        path.write_text(json.dumps(doc))
        try:
            back = load()
        except (InputError, CalibrationMismatchError) as exc:  # the current version: every field it needs
            assert str(exc).startswith(f"{path}: "), f"the error does not name the file: {exc}"
            if p[0] == "elements" or p in (("model",), ("fingerprint",), ("elements",)):
                assert repr(p[-1]) in str(exc), f"the error does not name the missing {p[-1]!r}: {exc}"
        else:  # a sensor or camera key equal to its default may go: the result must be the same
            assert len(p) == 2 and p[0] in ("sensor", "camera") and back.sensor == cal.sensor \
                and back.camera == cal.camera, f"a calibration without {p} loaded as another calibration"
    elif kind == "wrong_sensor":
        path.write_text(text)
        if rng.random() < 0.5:
            other = DomeSensor(ring_counts=(1,), ring_polar_deg=(0.0,), outer_radius=float(rng.uniform(15, 19)))
            with pytest.raises(CalibrationMismatchError, match="another sensor"):
                load(sensor=other)
        else:
            other = FisheyeCamera(width=int(rng.integers(40, 300)), height=int(rng.integers(30, 200)))
            if other != SMALL:
                with pytest.raises(CalibrationMismatchError, match="camera"):
                    load(camera=other)
    else:  # edited_sensor
        key = str(rng.choice(["outer_radius", "lever_arm", "cone_circle_radius"]))
        doc["sensor"][key] = float(doc["sensor"][key]) * float(rng.uniform(1.01, 1.2))
        path.write_text(json.dumps(doc))
        with pytest.raises((CalibrationMismatchError, InputError)):
            load()


@counted("calibration_file")
@pytest.mark.parametrize("model", ["coupled", "ohka"])
def test_calibration_files_of_schema_version_1_load_as_version_1(cal_doc, tmp_path, model):
    """Version 1 held u0 only when a fit found one (and files before it none): such files load, and a
    coupled one without u0 says that its shear curves go without; version 2 needs u0, null or not."""
    cal, doc = cal_doc
    assert doc["schema_version"] == 3 and doc["model"] == "coupled" and cal.u0 is not None
    path = tmp_path / "c.json"
    old = json.loads(json.dumps(doc)) | {"schema_version": 1}
    path.write_text(json.dumps(old))
    back = Calibration.load(path)  # version 1 with u0: the same calibration, no warning
    np.testing.assert_array_equal(back.u0, cal.u0)
    del old["elements"]["u0"]
    old["model"] = model
    path.write_text(json.dumps(old))
    if model == "coupled":
        with pytest.warns(OptitactWarning, match=rf"^{re.escape(str(path))}: schema version 1 without "
                                                 rf"elements\.u0 .* u0 = 0"):
            back = Calibration.load(path)
    else:  # ohka's shear curves have no u0: nothing goes missing
        back = Calibration.load(path)
    assert back.u0 is None and back.fingerprint == cal.fingerprint
    new = json.loads(json.dumps(doc))
    new["elements"]["u0"] = None
    path.write_text(json.dumps(new))
    assert Calibration.load(path).u0 is None
    del new["elements"]["u0"]
    path.write_text(json.dumps(new))
    with pytest.raises(InputError, match=rf"^{re.escape(str(path))}: calibration elements are missing 'u0' "
                                         rf".* schema version 3 requires"):
        Calibration.load(path)
    new["elements"]["u0"] = None  # version 3 needs the elements' shapes too, null or not
    del new["elements"]["shape"]
    path.write_text(json.dumps(new))
    with pytest.raises(InputError, match=r"missing 'shape' .* schema version 3 requires"):
        Calibration.load(path)
    new["elements"]["shape"] = np.tile([0.05, -0.02, 0.01], (len(cal.g), 1)).tolist()
    path.write_text(json.dumps(new))
    shaped = Calibration.load(path)
    np.testing.assert_array_equal(shaped.shape[-1], [0.05, -0.02, 0.01])
    assert Calibration.from_dict(shaped.to_dict()).shape.tolist() == new["elements"]["shape"]
    new["elements"]["shape"][-1] = [0.9, 0.0, 0.0]  # a factor of 2.5: not the element the curves describe
    path.write_text(json.dumps(new))
    with pytest.raises(InputError, match=r"shape must be finite, each value within \+-0.5"):
        Calibration.load(path)
    old["elements"]["u0"] = None  # version 1 never wrote null
    path.write_text(json.dumps(old))
    with pytest.raises(InputError, match=r"elements\['u0'\] must hold numbers"):
        Calibration.load(path)


@counted("calibration_file")
def test_oversized_calibration_files_are_refused(cal_doc, tmp_path):
    from optitact.calib.document import MAX_FILE_BYTES

    text = json.dumps(cal_doc[1])
    path = tmp_path / "c.json"
    path.write_text(text + " " * (MAX_FILE_BYTES + 1 - len(text)))
    with pytest.raises(InputError, match="too large"):
        Calibration.load(path)


_JSON_VALUES = (None, True, False, 0, -1, 1e308, -1e-308, 3.5, "", "x", [], [1, 2], {}, {"a": 1}, [[0.0] * 4],
                10**400, "NaN")
json_leaves = st.none() | st.booleans() | st.integers(-10**400, 10**400) | st.floats() | st.text(max_size=5)
json_values = st.sampled_from(_JSON_VALUES) | st.recursive(
    json_leaves,
    lambda kids: st.lists(kids, max_size=4) | st.dictionaries(st.text(max_size=4), kids, max_size=3),
    max_leaves=8)


def _loaded_is_sane(back, doc) -> None:
    """A calibration that loaded gives finite forces and holds the document's numbers."""
    for name in ("g", "g_scale", "f", "u_scale", "g_max", "u_max", "gu"):
        np.testing.assert_array_equal(getattr(back, name), np.array(doc["elements"][name], dtype=np.float64))
    rng = np.random.default_rng(0)
    G = np.concatenate([[0.0], [0.5, 1.0, 2.0], np.minimum(back.g_max, 1e300) * rng.uniform(0, 2, 6)])[:, None]
    G[1:4] *= min(float(back.g_max[0]), 1e300)
    u = rng.normal(0.0, 1.0, (10, 1, 2)) * np.minimum(back.u_max, 1e300)[:, None]
    u[:4] = np.array([[0.2, -0.4]]) * min(float(back.u_max[0]), 1e300)
    est, _ = back.forces(Readings(G, u, G > 0, np.zeros_like(G, bool)))
    assert np.isfinite(est).all() and np.all(est[..., 2] >= 0)


@stress("calibration_file", SHARE["edited"], which=st.integers(0, 10**6), value=json_values)
def test_any_edit_of_a_calibration_file_loads_right_or_fails_clearly(cal_doc, tmp_path_factory, which, value):
    _, doc = cal_doc
    doc = json.loads(json.dumps(doc))
    paths = [p for p in _paths(doc) if p]
    path = paths[which % len(paths)]
    _get(doc, path[:-1])[path[-1]] = value
    try:
        text = json.dumps(doc)
    except ValueError:  # an integer beyond Python's digit limit cannot even be written
        return
    f = tmp_path_factory.mktemp("cal") / "c.json"
    f.write_text(text)
    try:
        back = Calibration.load(f)
    except (InputError, CalibrationMismatchError) as exc:
        assert isinstance(exc, ValueError) and len(str(exc)) > 10
        return
    _loaded_is_sane(back, doc)


@counted("calibration_file")
@pytest.mark.parametrize("text,match", [
    ("[" * 100_000 + "]" * 100_000, "RecursionError"),
    ('{"schema": ' + "9" * 5000 + "}", "not a JSON calibration"),
    ('{"schema": NaN}', "NaN is not valid JSON"),
    ("\x80\x81 not utf-8", "not a JSON calibration"),
])
def test_unreadable_calibration_files(tmp_path, text, match):
    f = tmp_path / "c.json"
    f.write_bytes(text.encode("latin-1") if "\x80" in text else text.encode())
    with pytest.raises(InputError, match=match):
        Calibration.load(f)


@counted("calibration_file")
def test_calibration_files_never_execute_anything(tmp_path):
    marker = tmp_path / "executed"
    f = tmp_path / "c.json"
    for payload in (pickle.dumps(Touch(str(marker))), b"__import__('os').mkdir(%r)" % str(marker).encode()):
        f.write_bytes(payload)
        with pytest.raises(InputError, match="not a JSON calibration"):
            Calibration.load(f)
    assert not marker.exists()


@counted("calibration_file")
@pytest.mark.parametrize("edit,exc,match", [
    (lambda d: d.update(schema_version=True), InputError, "schema version True"),
    (lambda d: d["pipeline"].update(baseline=[0]), InputError, r"unknown option\(s\) \['baseline'\]"),
    (lambda d: d.update(provenance="x"), InputError, "'provenance' must be an object, got str"),
    (lambda d: d.update(residuals_n={"fz": ["a"]}), InputError, r"residuals_n\['fz'\] must hold numbers"),
    (lambda d: d["residuals_n"].update(n=[1e308]), InputError, r"residuals_n\['n'\] must hold sample counts"),
    (lambda d: d["elements"]["g"][0].__setitem__(1, -1.0), InputError, "g coefficients must be >= 0"),
    (lambda d: d["elements"]["f"][0].__setitem__(0, 0.0), InputError, "a > 0 and b >= 0"),
    (lambda d: d["elements"].update(u_max=[-1.0]), InputError, "g_max and u_max must be > 0"),
    (lambda d: d["elements"].update(g_scale=[1e-300]), InputError, "overflow float64 within their fitted"),
    (lambda d: d["elements"]["u0"][0][1].__setitem__(0, 1e308), InputError, "zero-shear centroid u0 out of"),
    (lambda d: d["elements"].update(g_max=[10**400]), InputError,
         r"elements\['g_max'\] must be a regular array of numbers within float64"),
    (lambda d: d["sensor"].update(outer_radius=10**400), InputError, "'sensor' is not a valid sensor"),
    (lambda d: d["intensity"].update(gain=10**400), InputError,
         r"not a valid intensity scale: gain must be finite and > 0, got a number beyond float64"),
    (lambda d: d["sensor"].update(ring_counts=5), InputError, "'sensor' is not a valid sensor"),
    (lambda d: d["camera"].update(width="wide"), InputError, "'camera' is not a valid camera"),
    (lambda d: d["pipeline"].update(noise_sigma=10**400), InputError, "'pipeline' options are not valid"),
    (lambda d: d["sensor"].update(lever_arm=3.5), CalibrationMismatchError, "does not match"),
])
def test_bad_calibration_documents(cal_doc, tmp_path, edit, exc, match):
    doc = json.loads(json.dumps(cal_doc[1]))
    edit(doc)
    f = tmp_path / "c.json"
    f.write_text(json.dumps(doc))
    with pytest.raises(exc, match=match):
        Calibration.load(f)
