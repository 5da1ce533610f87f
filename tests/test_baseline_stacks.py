"""Baselines of several no-load frames: a threshold and a contact floor that follow the stack's noise.

A stack of ``T`` no-load frames measures each pixel's temporal noise with ``T - 1`` degrees of
freedom, and the frames' isolated bright pixels (path-tracing fireflies, flickering hot pixels)
where they happened to be. The floor must hold its false-contact rate for any ``T``: the
threshold is Student's t quantile of the pooled noise (``steps.threshold_sigmas``), and the
impulses another frame holds elsewhere are counted apart (``baseline.baseline_noise``). Ground
truth here is synthetic noise of known law; the rendered and outside-in tests take the README's
path-traced case.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import optitact
from optitact.baseline import baseline_noise
from optitact.ccd import CCD
from optitact.pipeline import Pipeline
from optitact.steps import impulses, noise_from_stack, threshold_sigmas

SENSOR = optitact.DomeSensor.default()
SMALL = optitact.FisheyeCamera(width=160, height=120)
H, W = SMALL.shape
N_EL = SENSOR.n_elements
#: Normal upper tail at 3 sigmas: the per-pixel false-alarm rate of the default k = 3.
Q3 = 0.5 * math.erfc(3.0 / math.sqrt(2.0))
#: The floor's target: fewer false contacts than this per element and frame.
TARGET = 1e-4
LOADED = [0, 5, 20]


def _frames(kind: str, n: int, rng: np.random.Generator) -> np.ndarray:
    """``n`` no-load frames of known noise at the small camera's size.

    ``"gauss"``: float frames, white Gaussian noise of 2 grey levels. ``"ccd"``: 8-bit frames of a
    smooth glow through the CCD model (photon, read and rounding noise), with isolated bright
    pixels at random places in 0.3 % of each frame's pixels (5-12 grey levels, as the fireflies
    of a 64-spp render) and two fixed hot pixels.
    """
    if kind == "gauss":
        return 30.0 + rng.normal(0.0, 2.0, (n, H, W))
    rows, cols = np.mgrid[0:H, 0:W]
    glow = (0.4 * np.exp(-((cols - 80.0) ** 2 + (rows - 60.0) ** 2) / (2 * 40.0**2))).astype(np.float32)
    ccd = CCD()
    out = np.stack([ccd.expose(glow, seed=int(rng.integers(1 << 30))) for _ in range(n)]).astype(np.int32)
    m = int(0.003 * H * W)
    for t in range(n):
        r, c = rng.integers(1, H - 1, m), rng.integers(1, W - 1, m)
        out[t, r, c] += rng.integers(5, 13, m)
    out[:, 30, 40], out[:, 90, 120] = 200, 180
    return np.clip(out, 0, 255).astype(np.uint8)


def _spots(amplitude: float) -> np.ndarray:
    """Gaussian spots (1.2 px) of peak ``amplitude`` at the loaded elements' centres."""
    rows, cols = np.mgrid[0:H, 0:W]
    out = np.zeros((H, W))
    for e in LOADED:
        r, c = SMALL.project(SENSOR.element_positions[e], SENSOR)
        out += amplitude * np.exp(-((rows - r) ** 2 + (cols - c) ** 2) / (2 * 1.2**2))
    return out


# ---------------------------------------------------------------------------- the threshold
def test_threshold_sigmas_is_students_t_quantile():
    from scipy import stats

    for k in (0.5, 1.0, 3.0, 5.0):
        for dof in (1.0, 28.3, 141.0):
            want = stats.t.isf(0.5 * math.erfc(k / math.sqrt(2.0)), dof)
            assert threshold_sigmas(k, dof) == pytest.approx(want, rel=1e-9, abs=0)
    assert threshold_sigmas(3.0, math.inf) == 3.0 and threshold_sigmas(0.0, 28.3) == 0.0
    assert threshold_sigmas(3.0, 1e9) == pytest.approx(3.0, rel=1e-6)
    assert math.isfinite(threshold_sigmas(40.0, 28.3)) and threshold_sigmas(40.0, 1e12) >= 40.0


@pytest.mark.parametrize("t_n", [2, 4, 6])
def test_stack_threshold_lets_through_the_rate_of_k_sigmas(t_n):
    """On uniform Gaussian noise, new frames minus the stack's mean exceed the threshold at most as
    often as 3 true sigmas would (0.13 % of pixels), and not far less often: from 2 frames the
    threshold is near 3.5 true sigmas (the 3 x 3 maximum of the old noise map made it 5.5)."""
    rng = np.random.default_rng(t_n)
    sigma, shape = 2.0, (200, 200)
    base = rng.normal(0.0, sigma, (t_n,) + shape)
    noise, dof = noise_from_stack(base)
    assert dof == pytest.approx(28.27 * (t_n - 1), rel=1e-3)
    thr = threshold_sigmas(3.0, dof) * noise
    fresh = rng.normal(0.0, sigma, (10,) + shape)
    rate = float(np.mean((fresh - base.mean(axis=0)) > thr))
    assert 0.15 * Q3 < rate < 1.0 * Q3, rate / Q3
    true_sigma = sigma * math.sqrt(1.0 + 1.0 / t_n)
    assert 3.0 < np.median(thr) / true_sigma < 3.7


def test_the_noisy_side_of_a_noise_step_is_not_judged_by_its_quiet_neighbours():
    rng = np.random.default_rng(1)
    sigma = np.where(np.arange(120) < 60, 4.0, 1.0)[None, None, :]
    base = rng.normal(0.0, 1.0, (2, 100, 120)) * sigma
    noise, dof = noise_from_stack(base)
    fresh = rng.normal(0.0, 1.0, (60, 100, 120)) * sigma
    per_column = np.mean((fresh - base.mean(axis=0)) > threshold_sigmas(3.0, dof) * noise, axis=(0, 1))
    assert per_column[50:70].max() < 3.0 * Q3


def test_a_flickering_pixel_keeps_its_own_noise():
    """One pixel 20x noisier than the rest would vanish in the pooled variance: it keeps its own."""
    rng = np.random.default_rng(2)
    base = rng.normal(0.0, 1.0, (4, 60, 80))
    base[:, 30, 40] = [0.0, 40.0, -30.0, 10.0]
    noise, _ = noise_from_stack(base)
    own = math.sqrt(np.var(base[:, 30, 40], ddof=1) * 1.25)
    assert noise[30, 40] == pytest.approx(own, rel=1e-12)
    assert np.median(noise) < 1.5


# ---------------------------------------------------------------------------- the impulses
def test_a_stack_counts_the_impulses_that_come_and_go_and_not_the_fixed_ones():
    base = np.full((4, 60, 80), 10.0)
    base[:, 20, 30] = 60.0  # a hot pixel in every frame: the mean subtracts it
    base[1, 40, 50] = 20.0  # a firefly in one frame of four
    noise = baseline_noise(base)
    assert noise.rate[20, 30] == 0.0 and noise.rate[40, 50] == 0.25 and noise.height[40, 50] == 2.5
    assert np.count_nonzero(noise.rate) == 1 and noise.dof == pytest.approx(3 * 28.27, rel=1e-3)
    one = baseline_noise(base[:1])  # one frame cannot tell the hot pixel from a passing one
    assert one.rate[20, 30] == 1.0 and math.isinf(one.dof)


def test_a_noisy_region_of_a_stack_is_noise_not_impulses():
    """Gaussian noise 5x the frame's typical noise crosses the frame-wide impulse test often; a
    stack judges each against its own neighbourhood's noise."""
    rng = np.random.default_rng(3)
    sigma = np.ones((120, 160))
    sigma[:, :40] = 5.0
    base = 50.0 + rng.normal(0.0, 1.0, (4, 120, 160)) * sigma
    assert impulses(base)[0][:, :40].mean() > 1e-3  # the frame-wide test alone
    assert baseline_noise(base).rate.max() == 0.0


# ---------------------------------------------------------------------------- readings
@pytest.mark.parametrize("kind", ["gauss", "ccd"])
@pytest.mark.parametrize("t_n", [2, 4, 6])
def test_stacks_of_no_load_frames_make_no_false_contacts(kind, t_n):
    """3 stacks x 250 fresh no-load frames x 41 elements: at the target of 1e-4 false contacts per
    element and frame, 3.1 on average; 12 or more would happen with probability 2e-5 (Poisson).
    Before the impulses were counted for stacks, the ``ccd`` frames read 1.5e-3 to 5.7e-3."""
    rng = np.random.default_rng(10 * t_n + (kind == "ccd"))
    false = total = 0
    for _ in range(3):
        pipe = Pipeline(SENSOR, SMALL, baseline=_frames(kind, t_n, rng))
        r = pipe.process(_frames(kind, 250, rng))
        false, total = false + int(r.contact.sum()), total + r.contact.size
    assert total * TARGET == pytest.approx(3.075)
    assert false < 12, f"{false} false contacts in {total} element-frames"


@pytest.mark.parametrize("t_n", [2, 4, 6])
def test_weak_spots_read_with_stacks_of_any_length(t_n):
    """Spots of 13 grey levels on frames with fireflies read in (nearly) every frame with a stack
    baseline, and nothing else reads. Over 8 draws: 95-100 % of frames with 2, 4 or 6 frames (one
    frame: 81-100 %); the old noise map read 55-99 % with 2 frames, with false contacts."""
    rng = np.random.default_rng(20 + t_n)
    pipe = Pipeline(SENSOR, SMALL, baseline=_frames("ccd", t_n, rng))
    frames = np.clip(np.rint(_frames("ccd", 40, rng) + _spots(13.0)), 0, 255).astype(np.uint8)
    r = pipe.process(frames)
    assert r.contact[:, LOADED].mean() >= 0.95
    assert not np.delete(r.contact, LOADED, axis=1).any()


# ---------------------------------------------------------------------------- rendered frames
@pytest.fixture(scope="module")
def path_traced():
    """200x150 path-traced no-load frames at 16 spp (fireflies in every frame) and one of the
    README's load (apex 0.8 N, 0.1 N shear), exposed by the CCD model: 8-bit."""
    from optitact.render import render

    cam = optitact.FisheyeCamera(width=200, height=150)
    ccd = CCD()
    noload = np.stack([ccd.expose(render(SENSOR, np.zeros((N_EL, 3)), camera=cam, spp=16, seed=s), seed=s)
                       for s in range(2, 8)])
    forces = np.zeros((N_EL, 3))
    forces[0] = (0.1, 0.0, 0.8)
    loaded = ccd.expose(render(SENSOR, forces, camera=cam, spp=16, seed=1), seed=1)
    return cam, noload, loaded


@pytest.mark.render
@pytest.mark.parametrize("t_n", [1, 2, 4])
def test_path_traced_no_load_stacks_read_no_contact(path_traced, t_n):
    """Baselines of 1, 2 and 4 path-traced no-load frames: other no-load frames read no contact
    (a two-frame stack read 8 of 164 element-frames in contact with the old noise map), and the
    apex load reads on its element alone."""
    cam, noload, loaded = path_traced
    pipe = Pipeline(SENSOR, cam, baseline=noload[0] if t_n == 1 else noload[:t_n])
    assert not pipe.process(noload[4:]).contact.any()
    assert np.flatnonzero(pipe.process(loaded).contact).tolist() == [0]


# ---------------------------------------------------------------------------- from the outside
def _contacts(user, out: str) -> set[tuple[int, int]]:
    with open(user.path(out), newline="") as f:
        return {(int(r["frame"]), int(r["element"])) for r in csv.DictReader(f) if r["contact"] == "1"}


def test_process_with_a_two_frame_no_load_stack_reads_only_the_loaded_elements(user):
    """``optitact process frames.npy --baseline noload.npy --out r.csv`` with a 2-frame no-load
    stack, on 60 frames with fireflies (the old noise map read 5 unloaded elements in contact)."""
    rng = np.random.default_rng(5)
    np.save(user.path("noload.npy"), _frames("ccd", 2, rng))
    frames = np.clip(np.rint(_frames("ccd", 60, rng) + _spots(40.0)), 0, 255).astype(np.uint8)
    np.save(user.path("frames.npy"), frames)
    run = user.run("process", "frames.npy", "--baseline", "noload.npy", "--out", "r.csv")
    assert run.returncode == 0, run.stderr
    assert _contacts(user, "r.csv") == {(t, e) for t in range(60) for e in LOADED}


@pytest.mark.render
def test_process_with_a_two_frame_path_traced_stack_reads_only_the_load(user, path_traced):
    """The README's case from the command line: a .npy stack of 2 path-traced no-load frames, then 4
    other no-load frames and the apex load (the old noise map read 15 false contacts here)."""
    _, noload, loaded = path_traced
    np.save(user.path("noload.npy"), noload[:2])
    np.save(user.path("frames.npy"), np.concatenate([noload[2:], loaded[None]]))
    run = user.run("process", "frames.npy", "--baseline", "noload.npy", "--out", "r.csv")
    assert run.returncode == 0, run.stderr
    assert _contacts(user, "r.csv") == {(4, 0)}
