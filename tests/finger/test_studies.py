"""The finger studies: surface scanning, slip, contour tracing, the joint-error study and their figures."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest

import optitact
from optitact import studies
from optitact.errors import InputError
from optitact.finger.chain import ChainEstimate, ChainSimulator
from optitact.finger.kinematics import Finger
from optitact.io.files import atomic_write_png_figure
from optitact.studies import finger as finger_study
from optitact.studies import finger_contour, finger_scanning, finger_slip
from optitact.studies.finger_contour import _trace_one as trace_one
from optitact.studies.finger_contour import contour_tracing, joint_error_study
from optitact.studies.finger_scanning import surface_scanning
from optitact.studies.finger_slip import slip_experiment

SENSOR = optitact.optics.sensor.DomeSensor.default()


def _png(draw, result, path, figsize=(12, 8)):
    from matplotlib.figure import Figure

    fig = Figure(figsize=figsize, layout="constrained")
    draw(fig, result)
    atomic_write_png_figure(fig, path)
    return fig


# ---------------------------------------------------------------------------- a perfect sensor
class PerfectChain(ChainSimulator):
    """The chain's interface with the simulated forces plus 2 mN noise: tests the experiments' logic."""

    def __init__(self, noise=0.002):
        self.sensor, self.camera, self.noise = SENSOR, optitact.optics.camera.FisheyeCamera(), noise

    def describe(self):
        return {"perfect": True}

    def estimate(self, forces, *, first_index=0, progress=False, desc=""):
        arr = np.asarray(forces, float)
        arr = arr[None] if arr.ndim == 2 else arr
        rng = np.random.default_rng(first_index)
        loaded = arr[..., 2:3] > 0
        est = np.where(loaded, arr + rng.normal(0, self.noise, arr.shape), 0.0)
        flags = np.zeros(arr.shape[:2], bool)
        return ChainEstimate(forces=est, clamped=flags, contact=loaded[..., 0], truth=arr, tipped=flags,
                             readings=None)


@pytest.mark.parametrize("lean", [9.0, 0.0])
def test_surface_scanning_logic_recovers_mu(lean):
    res = surface_scanning(chain=PerfectChain(), speeds=(1.4, 25.0), lean_deg=lean, progress=False)
    assert len(res["runs"]) == 6
    for r in res["runs"]:
        assert abs(r["error"]) < 0.02, r
        assert r["within_tolerance"] and r["steady_s"][0] >= 0.6
        assert r["lean_deg"] == pytest.approx([lean, lean], abs=1e-6)
        # the element sees the contact force at (friction angle - lean) from its axis
        expected = np.tan(np.arctan(r["mu_truth_steady"]) - np.radians(lean))
        assert r["local_ratio_steady"] == pytest.approx(expected, abs=0.01)
    assert res["runs"][0]["mu_simulated"] < 0.39 < res["runs"][1]["mu_simulated"]  # speed dependence
    assert res["runs"][1]["stage_travel_mm"] > 20 * (lean > 0)  # the stage holds the lean on 62.5 mm
    json.dumps(res, allow_nan=False)


def test_slip_experiment_logic():
    res = slip_experiment(chain=PerfectChain(), progress=False)
    sc = res["scores"]
    assert len(res["onsets_s"]) == 6 and sc["recall"] == 1.0 and sc["precision"] == 1.0
    assert 0 <= sc["max_delay_s"] <= 0.3
    assert res["scores_truth"]["recall"] == 1.0
    json.dumps(res, allow_nan=False)


def test_contour_tracing_logic():
    res = contour_tracing(chain=PerfectChain(), progress=False)
    cyl, box = res["objects"]["cylinder"], res["objects"]["box"]
    for r in (cyl, box):
        assert r["reached_end"] and not r["lost"] and r["n_contacts"] >= 8
        assert abs(r["table"]["estimated_z"]) < 0.1
        assert abs(r["trace_height_mm"] - (SENSOR.outer_radius + 1.0 + 5.0)) < 0.6
    assert cyl["max_deviation_mm"] < 0.3 and box["max_deviation_except_corners_mm"] < 0.3
    assert box["max_deviation_mm"] >= box["max_deviation_except_corners_mm"]
    shaky = contour_tracing(chain=PerfectChain(), objects=("cylinder",), joint_error_deg=1.0, progress=False)
    assert shaky["objects"]["cylinder"]["max_deviation_mm"] > 0.5  # the finger's own errors show
    json.dumps(res, allow_nan=False)


def test_first_approach_goes_on_until_it_touches(monkeypatch):
    # starting 8 mm clear is more than one square-search side (retreat 2 + step 5 mm)
    opts = dict(step=5.0, approach_step=1.0, retreat=2.0, contact_threshold=0.3, table_threshold=0.2, lift=5.0,
                stiffness=0.5, feeler_height=1.0, max_frames=80, corner_margin=5.0)
    box = optitact.finger.scene.Box(center=(188.0, 0.0), size=(40.0, 40.0), angle_deg=45.0)
    r = trace_one(box, PerfectChain(), Finger(), start_y=-8.0, end_y=8.0, first_index=0, gap=8.0, **opts)
    assert not r["lost"] and r["reached_end"] and r["n_contacts"] >= 4
    start = finger_contour._start_point
    monkeypatch.setattr(finger_contour, "_start_point",
                        lambda *a: (start(*a)[0] - 60.0, start(*a)[1]))  # 68 mm clear
    far = trace_one(box, PerfectChain(), Finger(), start_y=-8.0, end_y=8.0, first_index=0, gap=8.0, **opts)
    assert far["lost"] and far["failure"] == "the object was not found on the first approach"
    assert far["n_contacts"] == 0 and np.ptp(np.asarray(far["path"])[:, 1]) == 0  # straight in, no turns


def test_table_touch_is_not_a_contour_point():
    # seed 4: one move sags the finger with joint errors until the table pushes up (a known case)
    r = contour_tracing(chain=PerfectChain(), objects=("cylinder",), joint_error_deg=1.0, seed=4,
                        progress=False)["objects"]["cylinder"]
    assert r["table_touches"] >= 1 and r["reached_end"]
    assert r["max_deviation_mm"] < 6.0  # a table point recorded as the wall would be ~20 mm off
    assert np.all(np.abs(np.asarray(r["contacts"])[:, 0] - 170.0) < 30.0)


def test_joint_error_study_separates_sensing_from_positioning():
    base = contour_tracing(chain=PerfectChain(), objects=("cylinder", "box"), span=8.0, progress=False)
    st = joint_error_study(chain=PerfectChain(), joint_errors_deg=(0.0, 1.0), repeats=2, span=8.0,
                           baseline=base, progress=False)
    assert st["joint_error_deg"] == [0.0, 1.0]
    for name in ("cylinder", "box"):
        o = st["objects"][name]
        assert len(o["max_deviation_mm"][0]) == 1 and len(o["max_deviation_mm"][1]) == 2
        assert o["max_deviation_mm"][0][0] < 0.3 < min(o["max_deviation_mm"][1])  # 1 deg at ~200 mm reach
        assert o["published_mm"] == finger_contour.PUBLISHED_DEVIATION_MM[name]
    assert st["objects"]["box"]["max_deviation_mm"][0][0] == base["objects"]["box"][
        "max_deviation_except_corners_mm"]
    json.dumps(st, allow_nan=False)
    with pytest.raises(InputError, match="repeats"):
        joint_error_study(chain=PerfectChain(), repeats=0)


def test_plots(tmp_path):
    chain = PerfectChain()
    trace = contour_tracing(chain=chain, objects=("box",), span=5.0, progress=False)
    result = {"surface_scanning": surface_scanning(chain=chain, frictions=(0.4,), speeds=(6.2,),
                                                   slide_time=1.0, progress=False),
              "slip": slip_experiment(chain=chain, rectangle=(16.0, 10.0), n_slips=2, progress=False),
              "contour_tracing": trace,
              "joint_error_study": joint_error_study(chain=chain, joint_errors_deg=(0.0, 0.5), repeats=1,
                                                     objects=("box",), span=5.0, baseline=trace,
                                                     progress=False),
              "seed": 0, "full": False}
    studies.save_plot("finger", result, tmp_path / "all.png")
    _png(finger_scanning.draw, result["surface_scanning"], tmp_path / "scan.png")
    _png(finger_slip.draw, result["slip"], tmp_path / "slip.png")
    fig = _png(finger_contour.draw, result["contour_tracing"], tmp_path / "contour.png")
    assert fig.axes
    _png(lambda f, r: finger_contour.draw_joint_error(f.subplots(), r), result["joint_error_study"],
         tmp_path / "joints.png")
    for name in ("all", "scan", "slip", "contour", "joints"):
        assert (tmp_path / f"{name}.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with pytest.raises(InputError, match="missing"):
        studies.save_plot("finger", {"slip": {}}, tmp_path / "bad.png")



@pytest.mark.render
def test_experiments_run_through_the_real_chain(tiny_chain, tmp_path):
    result = {
        "surface_scanning": surface_scanning(chain=tiny_chain, frictions=(0.3,), speeds=(6.2,),
                                             slide_time=0.5, frame_rate=8.0, progress=False),
        "slip": slip_experiment(chain=tiny_chain, rectangle=(6.0, 4.0), speed=6.0, n_slips=1,
                                frame_rate=5.0, progress=False),
        "contour_tracing": contour_tracing(chain=tiny_chain, objects=("cylinder",), span=3.0, max_frames=12,
                                           progress=False),
        "seed": 0, "full": False}
    run = result["surface_scanning"]["runs"][0]
    assert run["frames"] == len(run["series"]["t"]) and "mu_truth_steady" in run
    assert result["slip"]["frames"] == len(result["slip"]["series"]["t"])
    assert result["contour_tracing"]["objects"]["cylinder"]["frames"] <= 12
    json.dumps(result, allow_nan=False)
    studies.save_plot("finger", result, tmp_path / "finger.png")
    assert (tmp_path / "finger.png").stat().st_size > 10_000


def test_experiment_argument_checks():
    with pytest.raises(InputError, match="not both"):
        finger_study.experiment(chain=PerfectChain(), calibration="extended")
    with pytest.raises(TypeError, match="ChainSimulator"):
        surface_scanning(chain="default")
    with pytest.raises(InputError, match="seed"):
        slip_experiment(chain=PerfectChain(), seed=None)
    with pytest.raises(InputError, match="objects"):
        contour_tracing(chain=PerfectChain(), objects=("sphere",))
    assert dataclasses.is_dataclass(Finger())


# ---------------------------------------------------------------------------- the quick study, real chain
@pytest.mark.render
def test_quick_study_through_the_registry(quick_result, tmp_path):
    r = quick_result
    assert r["study"] == "finger" and r["size"] == "quick" and r["seed"] == 0 and r["full"] is False
    assert set(r) >= {"surface_scanning", "slip", "contour_tracing", "published", "seconds"}
    assert "joint_error_study" not in r
    pub = r["published"]
    assert pub["reference"] and pub["contour_tracing"]["max_deviation_mm"] == {"cylinder": 3.6, "box": 2.7}
    assert pub["slip"]["band_n_s"] == 0.06 and pub["surface_scanning"]["frictions"] == [0.39, 0.40, 0.53]
    runs = r["surface_scanning"]["runs"]
    assert [run["friction"] for run in runs] == [0.39, 0.40, 0.53]
    assert all(run["speed_mm_s"] == 6.2 and run["frames"] == len(run["series"]["t"]) for run in runs)
    assert r["slip"]["frames"] == len(r["slip"]["series"]["t"]) and len(r["slip"]["onsets_s"]) == 4
    assert r["contour_tracing"]["objects"]["cylinder"]["frames"] <= 60
    json.dumps(r, allow_nan=False)
    assert studies.run("finger", seed=0, size="quick") == r  # cached
    studies.save_plot("finger", r, tmp_path / "finger.png")
    assert (tmp_path / "finger.png").stat().st_size > 10_000


def test_key_figures_summarise_the_quick_study(quick_result):
    rows = {label: (ours, pub) for label, ours, pub in studies.key_figures("finger", quick_result)}
    summary = quick_result["surface_scanning"]["summary"]
    assert rows["friction runs within tolerance"] == (
        f"{summary['n_within_tolerance']} of {summary['n_runs']}", "+-0.02")
    assert rows["slip: precision / recall"][0] == [quick_result["slip"]["scores"]["precision"],
                                                   quick_result["slip"]["scores"]["recall"]]
    cyl = quick_result["contour_tracing"]["objects"]["cylinder"]["max_deviation_except_corners_mm"]
    assert rows["contour cylinder: max deviation, ideal finger (mm)"] == (cyl, 3.6)
    assert not any("joint error" in label for label in rows)   # the quick size has no joint-error study
