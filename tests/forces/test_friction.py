"""Friction coefficient, slip detection and contact hysteresis on synthetic streams with known truth."""

from __future__ import annotations

import numpy as np
import pytest
from optitact.forces.contact_events import ContactDetector, detect_contact
from optitact.forces.friction import friction_coefficient
from optitact.forces.slip import SlipDetector, detect_slip

from optitact.errors import InputError, ShapeError


# ---------------------------------------------------------------------------- friction
def sliding_stream(mu=0.4, fn0=0.1, rate=20.0, seed=0, noise=0.002):
    """Press (0.5 s), dwell (0.3 s), stick ramp to a 15 % static peak, slide 3 s, stop, lift."""
    rng = np.random.default_rng(seed)
    t = np.arange(0, 5.0, 1 / rate)
    fn = fn0 * np.clip(t / 0.5, 0, 1) * np.where(t > 4.6, np.clip((5.0 - t) / 0.3, 0, 1), 1)
    ft = np.zeros_like(t)
    stick = (t > 0.8) & (t <= 0.95)
    ft[stick] = 1.15 * mu * fn0 * (t[stick] - 0.8) / 0.15
    slide = (t > 0.95) & (t <= 4.0)
    ft[slide] = mu * fn0 * (1 + 0.15 * np.exp(-(t[slide] - 0.95) / 0.1))
    ft[t > 4.0] = 0.5 * mu * fn0 * fn[t > 4.0] / fn0
    return t, ft + rng.normal(0, noise, t.size) * (fn > 0), fn + rng.normal(0, noise, t.size) * (fn > 0)


@pytest.mark.parametrize("mu", [0.2, 0.39, 0.53])
def test_friction_coefficient_recovers_known_mu(mu):
    t, ft, fn = sliding_stream(mu)
    est = friction_coefficient(ft, fn, t=t)
    assert est.mean == pytest.approx(mu, abs=0.006)
    assert est.std < 0.05 and est.n >= 30
    # the steady part lies inside the sliding stroke, after the static peak has decayed
    assert 1.0 <= est.t_start and est.t_stop <= 4.0
    assert est.mu.shape == t.shape and not est.mu.flags.writeable
    assert est.as_dict()["n"] == est.n and est.steady == slice(est.start, est.stop)


def test_friction_vector_shear_and_no_mutation():
    t, ft, fn = sliding_stream(0.3, seed=1)
    ang = np.linspace(0, 1, t.size)
    vec = np.stack([ft * np.cos(ang), ft * np.sin(ang)], axis=1)
    keep = vec.copy(), fn.copy()
    a = friction_coefficient(vec, fn, t=t)
    b = friction_coefficient(ft, fn, t=t)
    assert a.mean == pytest.approx(b.mean, rel=0, abs=1e-12)
    np.testing.assert_array_equal(vec, keep[0])
    np.testing.assert_array_equal(fn, keep[1])


def test_friction_errors():
    t, ft, fn = sliding_stream()
    with pytest.raises(ShapeError, match="fn must have shape"):
        friction_coefficient(ft, fn[:-1])
    with pytest.raises(ShapeError, match="t must have shape"):
        friction_coefficient(ft, fn, t=t[:-1])
    with pytest.raises(InputError, match="strictly increasing"):
        friction_coefficient(ft, fn, t=t[::-1])
    with pytest.raises(InputError, match="finite"):
        friction_coefficient(np.r_[ft[:-1], np.nan], fn)
    with pytest.raises(TypeError, match="real numeric"):
        friction_coefficient(ft > 0, fn)
    with pytest.raises(InputError, match="contact samples"):
        friction_coefficient(np.zeros(10), np.zeros(10))
    with pytest.raises(InputError, match="min_level"):
        friction_coefficient(ft, fn, min_level=2.0)
    with pytest.raises(InputError, match="no steady sliding part"):
        friction_coefficient(np.linspace(0, 1, 40), np.ones(40), min_samples=30)  # a ramp, no plateau


# ---------------------------------------------------------------------------- slip
def slip_stream(onsets, *, rate=20.0, duration=30.0, level=0.15, noise=0.005, seed=0):
    rng = np.random.default_rng(seed)
    t = np.arange(0, duration, 1 / rate)
    shear = np.full(t.size, level)
    for t0 in onsets:  # drop by half (tau 0.05 s), hold 0.3 s, recover (tau 0.15 s)
        on = (t >= t0) & (t < t0 + 0.3)
        after = t >= t0 + 0.3
        shear[on] -= 0.5 * level * (1 - np.exp(-(t[on] - t0) / 0.05))
        shear[after] -= 0.5 * level * (1 - np.exp(-0.3 / 0.05)) * np.exp(-(t[after] - t0 - 0.3) / 0.15)
    return t, shear + rng.normal(0, noise, t.size)


def test_slip_detected_at_known_onsets():
    onsets = [3.03, 9.51, 15.0, 22.27]
    t, shear = slip_stream(onsets)
    res = detect_slip(t, shear)
    det = res.onsets
    assert len(det) == len(onsets)
    delay = det - np.array(onsets)
    assert np.all(delay >= 0) and np.all(delay <= 0.25)
    assert all(e.sign == -1 and e.peak_rate < -0.06 for e in res.events)
    assert res.slipping.sum() > 0 and res.derivative.shape == t.shape
    assert set(res.as_dict()) == {"onset", "end", "onset_index", "end_index", "peak_rate", "sign"}


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_no_false_alarms_on_noise(seed):
    # 5 mN white noise at 20 Hz for 5 minutes: the 0.5 s slope has 0.011 N/s noise, the band 0.06
    t, shear = slip_stream([], duration=300.0, noise=0.005, seed=seed)
    assert detect_slip(t, shear).events == []


def test_online_equals_offline_and_gate():
    t, shear = slip_stream([4.0, 12.0], seed=3)
    gate = ~((t > 11.5) & (t < 13.0))  # the second slip happens while detection is off
    off = detect_slip(t, shear, active=gate)
    det = SlipDetector()
    states = [det.update(ti, si, active=bool(g)) for ti, si, g in zip(t, shear, gate, strict=True)]
    det.finish()
    assert [e.as_dict() for e in det.events] == [e.as_dict() for e in off.events]
    np.testing.assert_array_equal(states, off.slipping)
    assert len(off.events) == 1 and off.events[0].onset == pytest.approx(4.0, abs=0.2)
    assert not off.ready[np.flatnonzero(~gate)].any()


def test_slope_is_least_squares_and_vector_shear():
    rng = np.random.default_rng(0)
    t = np.cumsum(rng.uniform(0.03, 0.07, 50))  # non-uniform sampling
    res = detect_slip(t, 0.2 + 0.03 * t, threshold=0.06)
    np.testing.assert_allclose(res.derivative[res.ready], 0.03, rtol=0, atol=1e-12)
    assert res.events == []
    vec = np.stack([0.12 * np.ones(50), 0.16 * np.ones(50)], axis=1)  # |F_t| = 0.2, any direction
    det = SlipDetector()
    for ti, v in zip(t, vec, strict=True):
        det.update(ti, v)
    assert det.derivative == pytest.approx(0.0, abs=1e-12)


def test_slip_direction_filter_and_errors():
    t, shear = slip_stream([5.0])
    rise = detect_slip(t, shear, direction="rise").events  # only the recovery, after the drop
    assert len(rise) == 1 and rise[0].sign == 1 and rise[0].onset > 5.3
    drop = detect_slip(t, shear, direction="drop").events
    assert len(drop) == 1 and drop[0].sign == -1 and drop[0].onset == pytest.approx(5.0, abs=0.25)
    with pytest.raises(InputError, match="direction"):
        SlipDetector(direction="up")
    det = SlipDetector()
    det.update(1.0, 0.1)
    with pytest.raises(InputError, match="increase"):
        det.update(1.0, 0.1)
    with pytest.raises(TypeError, match="t must be a real number"):
        det.update("2", 0.1)
    with pytest.raises(TypeError, match="bool"):
        detect_slip(t, shear, active=np.ones(t.size))
    with pytest.raises(ShapeError, match="active"):
        detect_slip(t, shear, active=np.ones(3, bool))
    with pytest.raises(InputError, match="threshold"):
        SlipDetector(threshold=0)


# ---------------------------------------------------------------------------- contact
def test_contact_hysteresis_stops_chatter():
    rng = np.random.default_rng(0)
    fn = 0.3 + rng.normal(0, 0.015, 400)  # hovering at the published contour threshold
    fn[:50] = 0.0
    chatter = detect_contact(fn, on=0.3, off=0.3)
    steady = detect_contact(fn, on=0.3)  # off = 0.225: 5 sigma below
    assert np.count_nonzero(np.diff(chatter.astype(int))) > 50
    assert np.count_nonzero(np.diff(steady.astype(int))) == 1
    assert not steady[:50].any() and steady[-1]


def test_contact_per_element_events_and_confirm():
    det = ContactDetector(0.2, confirm=2)
    samples = [[0.0, 0.25], [0.21, 0.25], [0.22, 0.1], [0.22, 0.1], [0.1, 0.0], [0.1, 0.0]]
    states = [det.update(s) for s in samples]
    assert [s.tolist() for s in states] == [[False, False], [False, True], [True, True], [True, False],
                                            [True, False], [False, False]]
    assert det.events == [(1, 1, "on"), (2, 0, "on"), (3, 1, "off"), (5, 0, "off")]
    online = np.array(states)
    np.testing.assert_array_equal(detect_contact(np.array(samples), on=0.2, confirm=2), online)
    with pytest.raises(ShapeError, match="keep its shape"):
        det.update([0.1, 0.1, 0.1])
    with pytest.raises(InputError, match="off must be <= on"):
        ContactDetector(0.2, off=0.3)
    with pytest.raises(InputError, match="finite"):
        ContactDetector(0.2).update(np.nan)
