"""Baselines of several no-load frames: a threshold and a contact floor that follow the stack's noise.

A stack of ``T`` no-load frames measures each pixel's temporal noise with ``T - 1`` degrees of
freedom, and the frames' isolated bright pixels (path-tracing fireflies, flickering hot pixels)
where they happened to be. The floor must hold its false-contact rate for any ``T``: the
threshold is Student's t quantile of the pooled noise (``steps.threshold_sigmas``), and the
impulses another frame holds elsewhere are counted apart (``baseline.baseline_noise``): each
region's allowance is a compound Poisson quantile of their heights times its pixels' areas
(``baseline.impulse_floor``), at the rate pooled over rings about the dome's axis
(``baseline.impulse_density``). Ground truth here is synthetic noise of known law, and exact
distributions; the rendered and outside-in tests take the README's path-traced case.
"""

from __future__ import annotations

import csv
import math

import numpy as np
import pytest

import optitact
from optitact.errors import InputError
from optitact.optics.ccd import CCD
from optitact.pipeline.baseline import (
    baseline_noise,
    compound_poisson_quantile,
    impulse_density,
    impulse_floor,
    poisson_cdf,
)
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.imageops import (
    impulses,
    maximum_noise,
    noise_from_stack,
    temporal_variance,
    threshold_sigmas,
)

SENSOR = optitact.optics.sensor.DomeSensor.default()
SMALL = optitact.optics.camera.FisheyeCamera(width=160, height=120)
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


def _rim_band(rng: np.random.Generator) -> np.ndarray:
    """Flat indices of the pixels that fire in :func:`_band_frames`: an eighth of the band 43-65 px
    from the dome's axis, where the fireflies of a path-traced no-load frame of this camera fall (the
    outer ring's regions and beyond; the frame's edges cut it at the top and bottom)."""
    r0, c0 = SMALL.project(SENSOR.element_positions[0], SENSOR)
    rows, cols = np.mgrid[0:H, 0:W]
    band = np.flatnonzero((np.abs(np.hypot(rows - r0, cols - c0) - 54.0) <= 11.0).reshape(-1))
    return rng.choice(band, size=len(band) // 8, replace=False)


def _band_frames(n: int, rng: np.random.Generator, hot: np.ndarray) -> np.ndarray:
    """``n`` dark 8-bit no-load frames through the CCD model whose ``hot`` pixels each fire in 5 % of
    frames, by 20 grey levels (40 one time in twenty): the fireflies of a 16-spp render recur at the
    same few hundred pixels of a band, as these do (44 a frame)."""
    ccd = CCD()
    out = np.stack([ccd.expose(np.zeros((H, W), np.float32), seed=int(rng.integers(1 << 30)))
                    for _ in range(n)]).astype(np.int32)
    fire = rng.random((n, hot.size)) < 0.05
    height = np.where(rng.random((n, hot.size)) < 0.05, 40, 20)
    for t in range(n):
        out[t].reshape(-1)[hot[fire[t]]] += height[t, fire[t]]
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


def test_stack_noise_maximum_is_the_earlier_map():
    """``stack_noise="maximum"``: the 3 x 3 maximum of the variances, blurred by a Gaussian of 1 px, times
    ``1 + 1/T``, and ``k`` of its sigmas (the map the shipped calibration's readings were made with),
    against a direct implementation; the impulses still raise the floor."""
    import cv2
    from scipy.ndimage import maximum_filter

    rng = np.random.default_rng(4)
    base = _frames("ccd", 4, rng)
    var = np.var(base.astype(np.float64), axis=0, ddof=1)
    want = np.sqrt(cv2.GaussianBlur(maximum_filter(var, size=3, mode="nearest"), (0, 0), 1.0,
                                    borderType=cv2.BORDER_REFLECT_101) * 1.25)
    np.testing.assert_allclose(maximum_noise(temporal_variance(base), 4), want, rtol=1e-12, atol=1e-12)
    pipe = Pipeline(SENSOR, SMALL, baseline=base, stack_noise="maximum")
    np.testing.assert_allclose(pipe.threshold_map, np.maximum(pipe.threshold, 3.0 * want), rtol=1e-12, atol=0)
    pooled = Pipeline(SENSOR, SMALL, baseline=base)
    assert np.median(pipe.threshold_map) > 1.2 * np.median(pooled.threshold_map)
    assert pipe.replace(k=3.0).stack_noise == "maximum" and pooled.stack_noise == "pooled"
    impulse_g = impulse_floor((baseline_noise(base).rate, baseline_noise(base).height), pipe.region_weights,
                              frames=4)
    assert impulse_g.min() > 0 and np.all(pipe.floor > impulse_g)
    one = Pipeline(SENSOR, SMALL, baseline=base[0], stack_noise="maximum")  # one frame: no stack map
    np.testing.assert_array_equal(one.floor, Pipeline(SENSOR, SMALL, baseline=base[0]).floor)
    with pytest.raises(InputError, match=r"stack_noise must be one of \('pooled', 'maximum'\), got 'max'"):
        Pipeline(SENSOR, SMALL, stack_noise="max")


# ---------------------------------------------------------------------------- the floor's impulses
@pytest.mark.parametrize("lam", [1e-6, 0.02, 0.3, 2.5, 12.0])
def test_compound_poisson_quantile_of_unit_jumps_is_poissons(lam):
    from scipy import stats

    for q in (0.9, 1 - 1e-5):
        got = compound_poisson_quantile(lam, [1.0], [1.0], [1.0], [1.0], q)
        assert got == stats.poisson.ppf(q, lam)


def test_compound_poisson_quantile_is_exact_on_its_grid():
    """Jumps ``a h`` of a in {0.5, 1} and h in {1, 2} (multiples of the grid step, a 256th of 2): the
    quantile is the exact one, from the distribution summed over the Poisson counts directly."""
    lam, a, pa = 0.7, np.array([0.5, 1.0]), np.array([3.0, 1.0])
    h, ph = np.array([1.0, 2.0]), np.array([0.9, 0.1])
    one = np.zeros(5)  # a jump's distribution on a grid of 0.5
    for ai, wa in zip(a, pa / pa.sum(), strict=True):
        for hi, wh in zip(h, ph / ph.sum(), strict=True):
            one[int(round(ai * hi / 0.5))] += wa * wh
    total, conv = np.zeros(400), np.zeros(400)
    conv[0] = 1.0
    weights = poisson_cdf(np.arange(60), np.array([lam]))[0]
    weights = np.diff(np.concatenate(([0.0], weights)))
    for n in range(60):
        total += weights[n] * conv
        conv = np.convolve(conv, one)[:400]
    cdf = np.cumsum(total)
    for q in (0.5, 0.99, 1 - 1e-5):
        want = 0.5 * int(np.argmax(cdf >= q))
        assert compound_poisson_quantile(lam, a, pa, h, ph, q) == pytest.approx(want, rel=0, abs=1e-12)


def test_impulse_density_of_uniform_impulses_is_their_rate():
    """Impulses in 5 % of the pixels of 4 frames, anywhere: each ring (>= a tenth of the frame, some
    380 impulses) reads their rate within a few per cent; a disc reads its own only where its count
    is improbable under the ring's (at 1e-3 a disc, a few of the frame's 19,200)."""
    rng = np.random.default_rng(5)
    fold = Pipeline(SENSOR, SMALL).region_weights
    rate = (rng.random((4, H, W)) < 0.05).mean(axis=0)
    density = impulse_density(rate, fold, frames=4) / rate.mean()
    assert abs(np.median(density) - 1) < 0.02 and density.min() > 0.85 and np.mean(density > 1.3) < 1e-3


def test_impulses_of_a_band_give_no_allowance_beyond_their_reach_and_a_cluster_its_own():
    """Rings stop at their edge: impulses in the rim band raise the outer ring's floor and no other
    region's (a smoothing kernel's tails gave each region within four of its widths a whole
    impulse); a cluster off the axial symmetry is pooled over its disc, not over its ring."""
    rng = np.random.default_rng(6)
    fold = Pipeline(SENSOR, SMALL).region_weights
    inner = sum(SENSOR.ring_counts[:-1])
    hot = _rim_band(rng)
    base = _band_frames(4, rng, hot)
    noise = baseline_noise(base)
    floor = impulse_floor((noise.rate, noise.height), fold, frames=4)
    assert np.all(floor[:inner] == 0.0) and np.all(floor[inner:] > 5.0)
    rate = np.zeros((H, W))
    r, c = SMALL.project(SENSOR.element_positions[5], SENSOR)
    rate[int(r) - 1:int(r) + 2, int(c) - 1:int(c) + 2] = 0.5  # nine flickering pixels, 18 fires in 4 frames
    density = impulse_density(rate, fold, frames=4)
    assert density[int(r), int(c)] > 10 * density[int(r), W - 1 - int(c)] > 0
    floor = impulse_floor((rate, 10.0 * rate), fold, frames=4)
    assert floor[5] == floor.max() > 5.0


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


@pytest.mark.parametrize("t_n", [1, 2, 4])
def test_a_band_of_recurring_fireflies_makes_no_false_contacts(t_n):
    """Fireflies recurring at the same pixels of a band the frame's edges cut (as a 16-spp render's
    do): 3 baselines x 300 frames x 41 elements, 3.7 false contacts at the target of 1e-4 on
    average, 12 or more with probability 1e-4. A floor of a whole frame's 90th-percentile impulse
    height at each region's Gaussian-smoothed impulse count read 7, 19 and 12 here (and 9e-4 per
    element-frame on path-traced 160x120 frames at 16 spp: its count fell short where the frame's
    edges cut the band, and it took no pixel's area above the mean)."""
    rng = np.random.default_rng(30 + t_n)
    false = total = 0
    for _ in range(3):
        hot = _rim_band(rng)
        base = _band_frames(t_n, rng, hot)
        pipe = Pipeline(SENSOR, SMALL, baseline=base if t_n > 1 else base[0])
        r = pipe.process(_band_frames(300, rng, hot))
        false, total = false + int(r.contact.sum()), total + r.contact.size
    assert total * TARGET == pytest.approx(3.69)
    assert false < 12, f"{false} false contacts in {total} element-frames"


def test_regions_the_fireflies_do_not_reach_keep_their_sensitivity():
    """With fireflies in the rim band only, spots of 3 grey levels at the apex, ring 1 and ring 2 read
    in every frame (the smoothed-count floor read the ring-1 and ring-2 ones in none)."""
    rng = np.random.default_rng(7)
    hot = _rim_band(rng)
    pipe = Pipeline(SENSOR, SMALL, baseline=_band_frames(4, rng, hot))
    frames = np.clip(np.rint(_band_frames(40, rng, hot) + _spots(3.0)), 0, 255).astype(np.uint8)
    r = pipe.process(frames)
    assert r.contact[:, LOADED].all()
    assert not np.delete(r.contact, LOADED, axis=1).any()


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

    cam = optitact.optics.camera.FisheyeCamera(width=200, height=150)
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
