"""Accumulation over long streams and big batches: exact sums, means and noise estimates, stream == batch."""

from __future__ import annotations

import csv
import math

import numpy as np
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from optitact.io.tables import ReadingsWriter
from optitact.optics.camera import FisheyeCamera
from optitact.pipeline.fastpath import CHUNK_FRAMES
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.imageops import estimate_noise
from optitact.pipeline.readings import Readings

from .helpers import N_EL, SENSOR, SMALL, assert_same
from .strategies import counted, rng_of, seeds, stress

_W = {"fsum": 3, "batch": 2, "baseline_mean": 2, "noise_estimate": 2, "stream": 1}
SHARE = {k: v / sum(_W.values()) for k, v in _W.items()}
#: A tiny camera for the baseline means (what they check does not depend on the frame size).
TINY = FisheyeCamera(width=40, height=30)


@stress("accumulation", SHARE["fsum"], seed=seeds)
def test_g_is_the_exactly_rounded_sum_of_its_terms(ctx, seed):
    """G per region against math.fsum of the same terms: within float64 summation rounding."""
    rng = rng_of(seed)
    img = np.zeros(SMALL.shape) + 10 ** rng.uniform(-3, 2, SMALL.shape)
    hot = rng.random(SMALL.shape) < 0.01
    img[hot] = 10 ** rng.uniform(6, 14, hot.sum())
    pipe = ctx.pipeline(noise_sigma=0.0)
    r = pipe.process(img)
    fold = pipe.region_weights  # the per-pixel weights of the fast method
    terms = fold.weights[0] * img.reshape(-1)[fold.pixel]
    eps = np.finfo(np.float64).eps
    for e in range(N_EL):
        t = terms[fold.label == e].tolist()
        exact = math.fsum(t)
        assert abs(r.G[e] - exact) <= len(t) * eps * math.fsum(abs(x) for x in t), f"G[{e}] vs fsum"


@stress("accumulation", SHARE["batch"], seed=seeds, t=st.integers(1, 3 * CHUNK_FRAMES + 1),
        filt=st.sampled_from(["none", "none", "gaussian"]))
def test_a_big_batch_reads_as_frame_by_frame(ctx, seed, t, filt):
    """A big batch (chunks of CHUNK_FRAMES) reads bit for bit as frame by frame."""
    rng = rng_of(seed)
    scenes = np.stack([ctx.random_frame(rng, np.uint8) for _ in range(3)])
    stack = scenes[rng.integers(0, 3, t)]
    pipe = ctx.pipeline(filter=filt)
    rs = pipe.process(stack)
    for k in range(3):
        single = pipe.process(scenes[k])
        rows = np.flatnonzero((stack == scenes[k]).all(axis=(1, 2)))
        for i in rows[:: max(1, len(rows) // 8)]:
            assert_same(rs[int(i)], single)


@counted("accumulation")
def test_big_batches_read_bit_for_bit_as_frame_by_frame(ctx):
    rng = np.random.default_rng(4)
    scenes = np.stack([np.clip(ctx.spot(e, (0.2, 0.1), 0.6, 200.0) + rng.normal(5, 1, SMALL.shape), 0, 255)
                       for e in (0, 17, 33)]).astype(np.uint8)
    which = rng.integers(0, 3, 1000)
    rs = ctx.pipe.process(scenes[which])
    singles = [ctx.pipe.process(s) for s in scenes]
    for t in range(0, 1000, 37):
        assert_same(rs[t], singles[which[t]])


@stress("accumulation", SHARE["baseline_mean"], t_n=st.integers(2, 400), offset_exp=st.floats(0, 8), seed=seeds)
def test_baseline_mean_is_exact_to_rounding(t_n, offset_exp, seed):
    """The baseline mean of T float frames: within 2 ulp of math.fsum / T, for offsets up to 1e8, whatever T.

    Plus the rounding of the frames' deviations from the mean (one ulp of the largest): where
    they cancel to a mean much smaller than the frames (offset 1, noise 1), that rounding is
    many ulps of the mean, and only an exact sum would do better.
    """
    rng = rng_of(seed)
    stack = 10**offset_exp + rng.normal(0.0, 1.0, (t_n,) + TINY.shape)
    b = Pipeline(SENSOR, TINY, baseline=stack).baseline.reshape(-1)
    flat = stack.reshape(t_n, -1)
    for p in rng.integers(0, flat.shape[1], 40):
        exact = math.fsum(flat[:, p].tolist()) / t_n
        assert abs(b[p] - exact) <= 2 * np.spacing(abs(exact)) + np.spacing(np.abs(flat[:, p] - exact).max())


def _offset_stack(args):
    t, offset_exp, spread_exp, seed = args
    rng = rng_of(seed)
    return 10**offset_exp + rng.normal(0.0, 10**spread_exp, (t, 3, 4))


stacks = st.one_of(
    hnp.arrays(np.float64, st.tuples(st.integers(2, 3000), st.just(2), st.just(3)),
               elements=st.floats(-1e6, 1e6)),
    st.tuples(st.integers(2, 20000), st.floats(0, 6), st.floats(-2, 1), seeds).map(_offset_stack))


@stress("accumulation", SHARE["noise_estimate"], stack=stacks)
def test_estimate_noise_is_exact_to_rounding(stack):
    t_n = stack.shape[0]
    var = []
    for col in stack.reshape(t_n, -1).T.tolist():
        m = math.fsum(col) / t_n
        var.append(math.fsum((x - m) ** 2 for x in col) / (t_n - 1))
    exact = math.sqrt(math.fsum(var) / len(var))
    # exact to rounding: 1e-12 relative, plus the rounding of the mean itself (an ulp of the values),
    # which no float64 algorithm avoids when the spread is a few ulp of a large offset
    ulp = float(np.finfo(np.float64).eps * np.abs(stack).max())
    np.testing.assert_allclose(estimate_noise(stack), exact, rtol=1e-12, atol=max(4 * ulp, 1e-300))


@stress("accumulation", SHARE["stream"], seed=seeds, t=st.integers(3, 39), nb=st.integers(0, 2))
def test_stream_reads_as_the_batch(ctx, seed, t, nb):
    """Pipeline.stream frame by frame == the batch, with the first frames as baseline."""
    rng = rng_of(seed)
    frames = [ctx.random_frame(rng, np.uint8) for _ in range(t)]
    out = list(ctx.pipe.stream(iter(frames), baseline_frames=nb))
    pipe = ctx.pipe if nb == 0 else ctx.pipe.with_baseline(np.stack(frames[:nb]))
    assert_same(Readings.stack(out), pipe.process(np.stack(frames)))


@counted("accumulation")
def test_a_long_stream_of_readings_sums_exactly_through_the_csv(tmp_path):
    """10^6 readings would take seconds; 41 x 2000 rows show the same: every value reads back bit for bit."""
    rng = np.random.default_rng(0)
    G = 10 ** rng.uniform(-6, 6, (2000, N_EL))
    G[rng.random(G.shape) < 0.3] = 0.0
    u = np.where((G > 0)[..., None], rng.normal(0, 0.7, (2000, N_EL, 2)), 0.0)
    r = Readings(G, u, G > 0, np.zeros_like(G, bool))
    path = tmp_path / "r.csv"
    with ReadingsWriter(path) as w:
        for i in range(0, 2000, 512):  # in chunks, as a stream writes them
            w.write(r[i:i + 512], [f"f{k}" for k in range(i, min(2000, i + 512))])
    with path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    back = np.array([float(row["G"]) for row in rows])
    np.testing.assert_array_equal(back, G.reshape(-1))
    np.testing.assert_array_equal(np.array([float(row["uy"]) for row in rows]), u[..., 1].reshape(-1))
    assert math.fsum(back.tolist()) == math.fsum(G.reshape(-1).tolist())
