"""Drift tracking (optitact.pipeline.drift) against injected truths.

Frames are the drift benchmark's (``optitact.studies.bench_drift``): a synthetic rim ring and
Gaussian contact spots on the default sensor seen by a 320 x 240 camera, blurred by a 0.7 px lens
PSF (which the camera's shift moves exactly), read noise 0.5 DN with shot noise, 8 bits. Each test
injects a known drift (gain, black level, shift, a local change of light) and checks what the
tracker makes of it.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from optitact.errors import InputError, ShapeError
from optitact.optics.camera import FisheyeCamera
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.drift import DriftState, DriftTracker
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.studies.bench_drift import DARK_DN, _expose, _noload_light, _Spots, drift_hour

SENSOR = DomeSensor.default()
CAM = FisheyeCamera(width=320, height=240)
N_EL = SENSOR.n_elements


@pytest.fixture(scope="module")
def scene():
    """The no-load light, a pipeline with a 32-frame no-load baseline, and the spots."""
    light, _ = _noload_light(SENSOR, CAM, "synthetic")
    rng = np.random.default_rng(7)
    stack = np.stack([_expose(light, 1.0, DARK_DN, (0.0, 0.0), rng.standard_normal(CAM.shape))
                      for _ in range(32)])
    pipe = Pipeline.from_noload(SENSOR, CAM, stack)
    return light, pipe, _Spots(pipe, SENSOR)


def _frame(light, rng, gain=1.0, dark=DARK_DN, shift=(0.0, 0.0)):
    return _expose(light, gain, dark, shift, rng.standard_normal(CAM.shape))


def _region_mask(pipe, e):
    mask = np.zeros(CAM.shape[0] * CAM.shape[1])
    fold = pipe.region_weights
    mask[fold.pixel[fold.label == e]] = 1.0
    return mask.reshape(CAM.shape)


# ---------------------------------------------------------------------------- the global model
@pytest.mark.parametrize("gain, dark, shift", [(0.95, 5.5, (0.4, -0.25)), (1.08, 3.0, (-0.15, 0.3)),
                                               (0.98, 6.0, (0.05, 0.1)), (1.0, DARK_DN, (0.0, 0.0))])
def test_known_gain_offset_and_shift_are_recovered(scene, gain, dark, shift):
    """40 frames of a fixed drift: the tracker's model within 1 % (gain), 0.05 DN (offset = dark - gain * 4 DN,
    the baseline's dark level being 4 DN) and 0.03 px (shift) of the injected one."""
    light, pipe, _ = scene
    tracker = DriftTracker(pipe, fps=1.0, smooth=10.0, gain_tolerance=0.0, offset_tolerance=0.0,
                           shift_tolerance=0.0, significance=0.0)  # the model as estimated, applied
    rng = np.random.default_rng(11)
    for _ in range(40):
        state = tracker.process(_frame(light, rng, gain, dark, shift))[1]
    assert state.tracking and not state.flag, state.reason
    assert abs(state.gain - gain) < 0.01
    assert abs(state.offset - (dark - gain * DARK_DN)) < 0.05
    assert math.hypot(state.shift_x - shift[0], state.shift_y - shift[1]) < 0.03
    assert 0.5 < state.peak and 0.7 < state.residual < 1.5


def test_no_drift_costs_nothing_and_changes_no_reading(scene):
    """Without drift (presses coming and going), every reading is the plain pipeline's, bit for bit."""
    light, pipe, spots = scene
    tracker = DriftTracker(pipe, fps=2.0)
    rng = np.random.default_rng(3)
    for i in range(80):
        forces = np.zeros((N_EL, 3))
        if 20 <= i < 50:
            forces[5] = (0.05, -0.02, 0.6)
        frame = _expose(light + spots.image(forces), 1.0, DARK_DN, (0.0, 0.0), rng.standard_normal(CAM.shape))
        got, state = tracker.process(frame)
        plain = pipe.process(frame)
        for name in ("G", "u", "contact", "saturated"):
            assert np.array_equal(getattr(got, name), getattr(plain, name)), (i, name)
        assert not state.corrected and not state.flag
        assert tracker.current_pipeline is pipe
    assert tracker.corrections == 0 and state.gain == 1.0 and state.shift_x == state.shift_y == 0.0


def test_a_short_drifted_run_reads_as_if_there_were_none():
    """Four minutes at 2 fps drifting as the benchmark's hour does (rim light -3 %, black level +2 DN, 0.3 px
    creep), random presses: tracked, Fz RMSE within 1.2 x the no-drift run's and no false contact; with the
    baseline fixed, the black-level step alone makes false contacts everywhere."""
    r = drift_hour(minutes=4.0, fps=2.0, background="synthetic", drift_hours=1.0, seed=0, baseline_frames=64,
                   tracker_options={"smooth": 20.0})
    runs = r["runs"]
    assert runs["no_drift"]["loaded_element_frames"] > 100
    assert r["ratio_tracked_to_no_drift"] <= 1.2, r["ratio_tracked_to_no_drift"]
    assert runs["tracked"]["false_contacts"] == 0 and runs["no_drift"]["false_contacts"] == 0
    assert runs["tracked"]["missed_contacts"] == runs["no_drift"]["missed_contacts"]
    assert runs["fixed"]["fz_rmse_n"] > 10 * runs["tracked"]["fz_rmse_n"]
    assert runs["fixed"]["false_contacts"] > 1000
    assert r["bar"]["met"] and r["tracker"]["flagged_frames"] == 0
    final = r["tracker"]["final"]
    assert abs(final["gain"] - final["gain_true"]) < 0.01


# ---------------------------------------------------------------------------- per element
def test_a_slow_press_and_a_held_one_are_not_absorbed_and_a_local_light_change_is_followed(scene):
    """Element 0 is pressed up to 0.5 N over 3 minutes and held 5 minutes: its G stays the plain pipeline's
    (no drift here, so that is the truth) to 0.5 %, its offset at 0. Element 12's light rises by 0.6 DN over
    4 minutes (a local change): the tracker follows it within 0.15 DN and reads no contact there in the last
    minute, where the plain pipeline reads contact in most frames."""
    light, pipe, spots = scene
    pressed, lit_el = 0, 12
    local = _region_mask(pipe, lit_el)
    tracker = DriftTracker(pipe, fps=0.5)
    rng = np.random.default_rng(5)
    fps, seconds = 0.5, 480.0
    tracked_b, plain_b = [], []
    for i in range(int(seconds * fps)):
        t = i / fps
        forces = np.zeros((N_EL, 3))
        forces[pressed] = np.array([0.1, 0.0, 1.0]) * 0.5 * min(t / 180.0, 1.0)
        frame = _expose(light + spots.image(forces) + 0.6 * min(t / 240.0, 1.0) * local, 1.0, DARK_DN,
                        (0.0, 0.0), rng.standard_normal(CAM.shape))
        got, state = tracker.process(frame, t=t)
        plain = pipe.process(frame)
        if got.contact[pressed]:
            assert abs(got.G[pressed] / plain.G[pressed] - 1.0) < 0.005, (t, got.G[pressed], plain.G[pressed])
        if t >= seconds - 60.0:
            tracked_b.append(bool(got.contact[lit_el]))
            plain_b.append(bool(plain.contact[lit_el]))
    assert got.contact[pressed] and abs(state.element_offset[pressed]) < 0.02
    assert abs(state.element_offset[lit_el] - 0.6) < 0.15
    assert not any(tracked_b) and sum(plain_b) > 0.5 * len(plain_b)
    assert not state.flag


# ---------------------------------------------------------------------------- the flag
@pytest.mark.parametrize("case, words", [("gain", "rim light"), ("shift", "camera moved"),
                                         ("object", "background"), ("element", "element 12")])
def test_a_change_beyond_what_tracking_follows_raises_the_flag(scene, case, words):
    """The rim light down 30 %, the camera 3 px away, a bright object in view beside the dome, one element's
    light up 2 DN: the flag rises with a reason; a global one holds the model as it was."""
    light, pipe, _ = scene
    tracker = DriftTracker(pipe, fps=1.0)
    rng = np.random.default_rng(9)
    for _ in range(5):
        tracker.process(_frame(light, rng))
    assert not tracker.state.flag and tracker.state.reason == ""
    extra = np.zeros(CAM.shape)
    gain, shift = 1.0, (0.0, 0.0)
    if case == "gain":
        gain = 0.7
    elif case == "shift":
        shift = (3.0, -1.0)
    elif case == "object":
        extra[5:60, 5:60] = 20.0  # a corner of the frame, outside the dome's view
    else:
        extra = 2.0 * _region_mask(pipe, 12)
    states = [tracker.process(_expose(light + extra, gain, DARK_DN, shift, rng.standard_normal(CAM.shape)))[1]
              for _ in range(8 if case != "element" else 600)]
    flagged = [s for s in states if s.flag]
    assert flagged, [s.reason for s in states[-3:]]
    assert words in flagged[-1].reason
    if case != "element":
        assert not flagged[-1].tracking and flagged[-1].gain == 1.0 and flagged[-1].shift_x == 0.0


# ---------------------------------------------------------------------------- integer frames, the API
def test_sixteen_bit_frames_are_tracked(scene):
    """16-bit frames read on an 8-bit scale (bits=16, readings_bits=8: frame / 257): the dtype checks hold,
    and a black-level step (+2 DN of 8 bits) is followed at once, with no false contact."""
    light, _, _ = scene
    rng = np.random.default_rng(13)

    def frame16(dark):
        f = _expose(light, 1.0, dark, (0.0, 0.0), rng.standard_normal(CAM.shape)).astype(np.float64)
        return np.rint(257.0 * f + rng.uniform(-128.0, 128.0, CAM.shape)).clip(0, 65535).astype(np.uint16)

    pipe = Pipeline.from_noload(SENSOR, CAM, np.stack([frame16(DARK_DN) for _ in range(16)]), bits=16,
                                readings_bits=8)
    tracker = DriftTracker(pipe, fps=1.0)
    for i in range(6):
        got, state = tracker.process(frame16(DARK_DN + (2.0 if i >= 3 else 0.0)))
        assert not got.contact.any(), i
    assert state.corrected and abs(state.offset - 2.0 * 257.0) < 0.1 * 257.0
    with pytest.raises(InputError, match="uint8"):
        tracker.process(np.full(CAM.shape, 5, np.uint8))


def test_the_api_refuses_what_it_cannot_track(scene):
    light, pipe, _ = scene
    with pytest.raises(InputError, match="baseline"):
        DriftTracker(Pipeline(SENSOR, CAM))
    with pytest.raises(TypeError):
        DriftTracker("not a pipeline")
    tracker = DriftTracker(pipe)
    frame = _frame(light, np.random.default_rng(0))
    with pytest.raises(ShapeError, match="one frame"):
        tracker.process(np.stack([frame, frame]))
    tracker.process(frame, t=10.0)
    with pytest.raises(InputError, match="non-decreasing"):
        tracker.process(frame, t=9.0)
    state = tracker.state
    assert isinstance(state, DriftState) and state.estimated and state.time == 10.0
    d = state.as_dict()
    assert set(d) >= {"gain", "offset", "shift_x", "shift_y", "flag", "reason"}
    assert len(d["element_offset"]) == N_EL


def test_with_baseline_mean_keeps_the_noise_and_swaps_the_mean(scene):
    _, pipe, _ = scene
    same = pipe.with_baseline_mean(pipe.baseline)
    frame = np.clip(np.rint(pipe.baseline + 6.0 * _region_mask(pipe, 3)), 0, 255).astype(np.uint8)
    for name in ("G", "u", "contact"):
        assert np.array_equal(getattr(same.process(frame), name), getattr(pipe.process(frame), name))
    assert same.threshold_map is pipe.threshold_map and same.floor is pipe.floor
    raised = pipe.with_baseline_mean(pipe.baseline + 6.0 * _region_mask(pipe, 3))
    assert not raised.process(frame).contact[3] and pipe.process(frame).contact[3]
    assert pipe.baseline_frames == 32
    with pytest.raises(ShapeError):
        pipe.with_baseline_mean(np.zeros((10, 10)))
    with pytest.raises(InputError, match="finite"):
        pipe.with_baseline_mean(np.full(CAM.shape, np.nan))
