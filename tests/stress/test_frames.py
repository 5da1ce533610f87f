"""Frames into the pipeline: blank, constant, saturated, hot, scaled, noisy, malformed, and random ones."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import strategies as st

from optitact.errors import InputError, ShapeError
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.imageops import G_MIN, MAX_GREY, estimate_noise

from .helpers import FLOAT_DTYPES, INT_DTYPES, N_EL, SENSOR, SMALL, H, W, as_dtype, assert_same, assert_sane
from .strategies import counted, rng_of, seeds, stress

# shares of the frames category (they add up to 1)
_W = {"blank": 1, "constant": 2, "noise": 1, "saturated": 2, "hot_pixel": 2, "scaling": 2, "float32": 2,
      "bad": 5.6, "one_frame_stack": 1, "views": 1, "max_uint16": 1, "random": 4, "any_frame": 3}
SHARE = {k: v / sum(_W.values()) for k, v in _W.items()}

filters = st.sampled_from(["none", "gaussian", "median"])
methods = st.sampled_from(["fast", "reference"])
options = st.fixed_dictionaries({}, optional={"filter": st.sampled_from(["gaussian", "median"]),
                                              "method": st.just("reference")})


@stress("frames", SHARE["blank"], dtype=st.sampled_from(INT_DTYPES + FLOAT_DTYPES), opts=options,
        sigma=st.sampled_from([0.0, 0.5, 2.0]), t=st.integers(1, 3), single=st.booleans())
def test_blank_frames_read_nothing(ctx, dtype, opts, sigma, t, single):
    pipe = ctx.pipeline(**opts, noise_sigma=sigma)
    frames = np.zeros((t,) + SMALL.shape, dtype)
    r = pipe.process(frames[0] if single else frames)
    assert_sane(r, pipe)
    assert not (r.contact.any() or r.saturated.any() or np.any(r.G) or np.any(r.u))


@stress("frames", SHARE["constant"],
        dtype=st.sampled_from((np.uint8, np.uint16, np.float32, np.float64, np.int32)),
        level=st.sampled_from([1, 3, 17, 200, 254]), exp=st.floats(-3, 4),
        sigma=st.sampled_from([0.0, 0.5, 1.0]), method=methods)
def test_constant_frame_reads_the_region_area_and_centroid(ctx, dtype, level, exp, sigma, method):
    c = float(level) if np.dtype(dtype).kind in "ui" else 10.0**exp
    pipe = ctx.pipeline(noise_sigma=sigma, method=method)
    r = pipe.process(np.full(SMALL.shape, c, dtype))
    assert_sane(r, pipe)
    c = float(np.asarray(c, dtype))
    expect_g = np.where((c > pipe.threshold) & (c * ctx.area > pipe.floor), c * ctx.area, 0.0)
    np.testing.assert_allclose(r.G, expect_g, rtol=1e-9, atol=0, err_msg="G = c x region area")
    np.testing.assert_allclose(r.u, np.where((expect_g > 0)[:, None], ctx.centroid, 0.0), rtol=0, atol=1e-9,
                               err_msg="u = the region's own centroid")
    cap = 2 * np.pi * SENSOR.outer_radius**2 * (1 - math.cos(pipe.grids.radius / SENSOR.outer_radius))
    # the region is the cells within the radius: a staircase disc, within a cell of the circle
    np.testing.assert_allclose(ctx.area, np.full(N_EL, cap), rtol=pipe.grids.grid_mm / pipe.grids.radius)


@stress("frames", SHARE["noise"], seed=seeds, filt=filters)
def test_noise_only_frames_rarely_read_contact(ctx, seed, filt):
    rng = rng_of(seed)
    sigma, level = float(rng.uniform(0.6, 3.0)), float(rng.uniform(5, 60))

    def draw(t):
        return np.clip(np.rint(level + rng.normal(0.0, sigma, (t,) + SMALL.shape)), 0, 255).astype(np.uint8)

    pipe = Pipeline.from_noload(SENSOR, SMALL, draw(6), filter=filt)
    r = pipe.process(draw(8))
    assert_sane(r, pipe)
    assert r.contact.mean() <= 0.05, f"noise-only frames read contact in {r.contact.mean():.1%} of the regions"


@stress("frames", SHARE["saturated"], seed=seeds, dtype=st.sampled_from((np.uint8, np.uint16)), opts=options,
        whole=st.booleans())
def test_saturated_frames_and_regions(ctx, seed, dtype, opts, whole):
    rng = rng_of(seed)
    top = np.iinfo(dtype).max
    if whole:
        pipe = ctx.pipeline(**opts)
        full = np.full(SMALL.shape, top, dtype)
        r = pipe.process(full)
        assert_sane(r, pipe)
        assert r.saturated.all() and r.contact.all()
        if pipe.filter == "none":
            np.testing.assert_allclose(r.G, top * ctx.area, rtol=1e-9)
        rb = pipe.replace(baseline=full).process(full)  # nothing above a saturated baseline, still saturated
        assert not rb.contact.any() and rb.saturated.all()
        return
    e = int(rng.integers(N_EL))
    frame = np.zeros(SMALL.shape, dtype)
    frame.reshape(-1)[ctx.region_pixels(e)] = top
    pipe = ctx.pipeline(method=opts.get("method", "fast"))
    r = pipe.process(frame)
    assert_sane(r, pipe)
    np.testing.assert_array_equal(r.saturated, np.arange(N_EL) == e)
    np.testing.assert_array_equal(r.contact, np.arange(N_EL) == e)
    np.testing.assert_allclose(r.G[e], top * ctx.area[e], rtol=1e-9)


@stress("frames", SHARE["hot_pixel"], seed=seeds, dtype=st.sampled_from((np.uint8, np.uint16)),
        filt=st.sampled_from(["none", "none", "gaussian", "median"]), inside=st.integers(0, 4))
def test_a_hot_pixel_saturates_the_regions_it_feeds(ctx, seed, dtype, filt, inside):
    rng = rng_of(seed)
    e = int(rng.integers(N_EL))
    p = int(rng.choice(ctx.region_pixels(e))) if inside else int(rng.integers(H * W))
    frame = np.zeros(SMALL.shape, dtype)
    frame.reshape(-1)[p] = np.iinfo(dtype).max
    fast = ctx.pipeline(filter=filt)
    r = fast.process(frame)
    assert_sane(r, fast)
    feeds = np.array([np.isin(p, ctx.region_pixels(f)) for f in range(N_EL)])
    np.testing.assert_array_equal(r.saturated, feeds, err_msg=f"hot pixel {divmod(p, W)}")
    assert_same(r, fast.replace(method="reference").process(frame), g_rtol=1e-9, u_atol=1e-9)
    assert not (filt == "median" and r.contact.any()), "a 3x3 median must remove a single hot pixel"


@stress("frames", SHARE["scaling"], k=st.integers(-1100, 330), e=st.integers(0, N_EL - 1), seed=seeds,
        method=methods)
def test_power_of_two_scaling_is_exact(ctx, k, e, seed, method):
    """Noiseless pipeline: frame x 2^k gives G x 2^k bit for bit and the same u, from 1e-270 to 1e99."""
    rng = rng_of(seed)
    img = ctx.spot(e, rng.uniform(-0.6, 0.6, 2), float(rng.uniform(0.45, 0.7)), 1.0)
    p0 = ctx.pipeline(noise_sigma=0.0, method=method)
    base = p0.process(img)
    assert_sane(base, p0)
    assert base.contact[e], "a noiseless spot must read contact"
    scaled = np.ldexp(img, k)  # exact unless it underflows
    if np.abs(scaled).max() > MAX_GREY:
        with pytest.raises(InputError, match=r"magnitude at most 1e\+100"):
            p0.process(scaled)
        return
    r = p0.process(scaled)
    assert_sane(r, p0)
    lit = scaled[scaled > 0]
    if lit.size and lit.min() > 1e-290:  # no subnormal pixel or product: exact
        want = np.ldexp(base.G, k)
        keep = want > G_MIN
        np.testing.assert_array_equal(r.G, np.where(keep, want, 0.0))
        np.testing.assert_array_equal(r.u, np.where(keep[:, None], base.u, 0.0))
    elif r.contact[e]:
        np.testing.assert_allclose(r.u[e], base.u[e], rtol=0, atol=1e-6)


@counted("frames")
@pytest.mark.parametrize("c", [1e-30, 1e30])
def test_tiny_and_huge_float_frames(ctx, c):
    img = ctx.spot(12, (0.3, -0.2), 0.6, 1.0)
    p0 = ctx.pipeline(noise_sigma=0.0)
    a, b = p0.process(img), p0.process(img * c)
    np.testing.assert_allclose(b.G, a.G * c, rtol=1e-12, atol=0)
    np.testing.assert_allclose(b.u, a.u, rtol=0, atol=1e-12)
    assert b.contact[12] and a.contact.sum() == b.contact.sum()


@stress("frames", SHARE["float32"], seed=seeds, opts=options)
def test_float32_and_float64_frames_agree(ctx, seed, opts):
    rng = rng_of(seed)
    e = int(rng.integers(N_EL))
    img = ctx.spot(e, rng.uniform(-0.5, 0.5, 2), float(rng.uniform(0.4, 0.7)), float(rng.uniform(20, 200)))
    img += rng.normal(0.0, 0.5, img.shape) + 10.0
    pipe = ctx.pipeline(**opts).replace(baseline=np.full(SMALL.shape, 10.0))
    f32 = img.astype(np.float32)
    r32 = pipe.process(f32)
    assert_sane(r32, pipe)
    assert_same(r32, pipe.process(f32.astype(np.float64)), g_rtol=1e-12, u_atol=1e-12)
    # against the float64 original: within float32 precision, unless a pixel sits within it of the threshold
    near = np.abs((img - 10.0) - pipe.threshold) < 1e-5 * np.maximum(np.abs(img), 1.0)
    if not near.any() and pipe.filter != "median":
        assert_same(r32, pipe.process(img), g_rtol=1e-5, u_atol=2e-5)


@counted("frames")
def test_float32_and_float64_of_the_same_frame(ctx):
    """Same values in float32 and float64: identical readings, even for values at the threshold itself."""
    rng = np.random.default_rng(3)
    img = ctx.spot(5, (0.1, 0.2), 0.6, 80.0) + rng.normal(0.0, 0.5, SMALL.shape) + 10.0
    f32 = img.astype(np.float32)
    p = ctx.pipe.replace(baseline=np.full(SMALL.shape, 10.0))
    # put pixels exactly at, just above and just below the level a float32 rounding would move
    level = np.float32(10.0 + p.threshold)
    f32[60, 70:73] = [level, np.nextafter(level, np.float32(np.inf)), np.nextafter(level, np.float32(0))]
    a, b = p.process(f32), p.process(f32.astype(np.float64))
    assert_same(a, b, g_rtol=1e-15, u_atol=1e-15)
    assert_same(p.replace(method="reference").process(f32), a, g_rtol=1e-12, u_atol=1e-12)
    assert_same(a, p.process(img), g_rtol=1e-5, u_atol=2e-5)  # the float64 original: float32 precision


BAD_SHAPES = [(W,), (H, W + 1), (H - 1, W), (W, H), (1, 1, H, W), (2, H, W, 1), (), (H * W,), (0, W), (H, 0)]
BAD_DTYPES = [bool, complex, object, "U1", "M8[s]", "m8[s]"]


@stress("frames", SHARE["bad"], seed=seeds, opts=options,
        kind=st.sampled_from(["non_finite"] * 5 + ["too_large"] * 5 + ["wrong_shape"] * 5 + ["wrong_dtype"] * 5
                             + ["negative_int"] * 5 + ["ragged", "ragged", "empty_stack", "empty_stack"]))
def test_bad_frames_are_refused_by_name(ctx, seed, opts, kind):
    rng = rng_of(seed)
    pipe = ctx.pipeline(**opts)
    row, col = int(rng.integers(H)), int(rng.integers(W))
    if kind == "non_finite":
        t = int(rng.integers(1, 4))
        stack = np.zeros((t,) + SMALL.shape, rng.choice([np.float16, np.float32, np.float64]))
        f = int(rng.integers(t))
        stack[f, row, col] = rng.choice([np.nan, np.inf, -np.inf])
        frames = stack if rng.random() < 0.6 else stack[f]
        where = f"frame {f if frames.ndim == 3 else 0}, pixel (row {row}, col {col})"
        with pytest.raises(InputError, match=r"finite.*" + re.escape(where)):
            pipe.process(frames)
        if rng.random() < 0.3:  # as a baseline
            with pytest.raises(InputError, match="baseline must be finite"):
                pipe.replace(baseline=stack)
    elif kind == "too_large":
        frame = np.zeros(SMALL.shape)
        frame[row, col] = float(10 ** rng.uniform(100.5, 308)) * float(rng.choice([-1, 1]))
        with pytest.raises(InputError, match=r"magnitude at most 1e\+100"):
            pipe.process(frame)
        with pytest.raises(InputError, match="magnitude at most"):
            estimate_noise(np.stack([frame, frame * 0.5]))
    elif kind == "wrong_shape":
        shape = BAD_SHAPES[int(rng.integers(len(BAD_SHAPES)))]
        arr = np.zeros(shape, rng.choice([np.uint8, np.float64]))
        match = "for this camera" if len(shape) in (2, 3) else r"\(H, W\)"
        with pytest.raises(ShapeError, match=match) as info:
            pipe.process(arr)
        assert len(shape) in (2, 3) or str(shape) in str(info.value)
    elif kind == "wrong_dtype":
        arr = np.zeros((H, W), BAD_DTYPES[int(rng.integers(len(BAD_DTYPES)))])
        with pytest.raises(TypeError, match="dtype") as info:
            pipe.process(arr)
        assert str(arr.dtype) in str(info.value)
    elif kind == "negative_int":
        stack = np.zeros((2,) + SMALL.shape, rng.choice([np.int8, np.int16, np.int32, np.int64]))
        stack[1, row, col] = -int(rng.integers(1, 100))
        with pytest.raises(InputError, match=rf"non-negative.*frame 1, pixel \(row {row}, col {col}\)"):
            pipe.process(stack)
    elif kind == "ragged":
        rows = [[0.0] * W for _ in range(H)]
        rows[row] = [0.0] * int(rng.integers(1, W))
        with pytest.raises((TypeError, ValueError), match="frames"):
            pipe.process(rows)
    else:
        with pytest.raises(InputError, match="empty stack"):
            pipe.process(np.zeros((0,) + SMALL.shape, rng.choice([np.uint8, np.float32])))


@counted("frames")
@pytest.mark.parametrize("frames,exc,match", [
    (np.full((H, W), 1e101), InputError,
     r"magnitude at most 1e\+100, got 1e\+101 at frame 0, pixel \(row 0, col 0\)"),
    (np.full((2, H, W), -1e200), InputError, r"magnitude at most 1e\+100"),
    ([[0.0] * W] * (H - 1) + [[0.0] * 3], TypeError, "frames must be an array of grey levels"),
    (np.zeros((H, W), "m8[s]"), TypeError, "dtype .*timedelta64"),
])
def test_frame_errors(ctx, frames, exc, match):
    with pytest.raises(exc, match=match):
        ctx.pipe.process(frames)


@stress("frames", SHARE["one_frame_stack"], seed=seeds, dtype=st.sampled_from([np.uint8, np.uint16, np.float32,
                                                                                 np.float64]), opts=options)
def test_one_frame_stack_reads_as_the_frame(ctx, seed, dtype, opts):
    frame = ctx.random_frame(rng_of(seed), dtype)
    pipe = ctx.pipeline(**opts)
    one, stack = pipe.process(frame), pipe.process(frame[None])
    assert not one.is_stack and stack.is_stack and len(stack) == 1
    assert_same(stack[0], one)


@stress("frames", SHARE["views"], seed=seeds,
        dtype=st.sampled_from([np.uint8, np.uint16, np.float32, np.float64]), opts=options)
def test_views_read_as_the_frame_and_are_not_modified(ctx, seed, dtype, opts):
    frame = ctx.random_frame(rng_of(seed), dtype)
    pipe = ctx.pipeline(**opts)
    expected = pipe.process(frame)
    big = np.zeros((frame.shape[0], 2 * frame.shape[1]), frame.dtype)
    big[:, ::2] = frame
    ro = frame.copy()
    ro.flags.writeable = False
    before = frame.copy()
    for view in (big[:, ::2], np.asfortranarray(frame), ro, frame[::-1, ::-1].copy()[::-1, ::-1]):
        assert_same(pipe.process(view), expected)
    np.testing.assert_array_equal(frame, before)


@stress("frames", SHARE["max_uint16"], seed=seeds, opts=options)
def test_max_range_uint16_fast_equals_reference(ctx, seed, opts):
    rng = rng_of(seed)
    img = rng.integers(0, 65536, SMALL.shape).astype(np.uint16)
    img[img < 60000] = 0
    img.reshape(-1)[int(rng.integers(img.size))] = 65535
    base = rng.integers(0, 40, SMALL.shape).astype(np.uint16)
    pipe = ctx.pipeline(**opts, noise_sigma=float(rng.uniform(0, 3))).replace(baseline=base)
    r = pipe.process(img)
    assert_sane(r, pipe)
    other = pipe.replace(method="reference" if pipe.method == "fast" else "fast")
    assert_same(r, other.process(img), g_rtol=1e-9, u_atol=1e-9)


@stress("frames", SHARE["random"], seed=seeds,
        dtype=st.sampled_from([np.uint8, np.uint16, np.float32, np.float64, np.int32, np.float16]),
        t=st.integers(1, 3), filt=st.sampled_from(["none", "none", "gaussian", "median"]),
        sigma=st.one_of(st.sampled_from([0.0, 0.5]), st.floats(0.1, 3)),
        k=st.one_of(st.just(3.0), st.floats(0, 5)), baseline=st.integers(0, 2))
def test_random_frames_fast_equals_reference(ctx, seed, dtype, t, filt, sigma, k, baseline):
    """Random frames, dtypes and options: fast == reference (independent implementations), invariants hold."""
    rng = rng_of(seed)
    stack = np.stack([ctx.random_frame(rng, dtype) for _ in range(t)])
    opts = {"filter": filt, "noise_sigma": sigma, "k": k}
    if baseline == 1:
        opts["baseline"] = as_dtype(np.full(SMALL.shape, 5.0), dtype)
    elif baseline == 2:
        opts["baseline"] = np.stack([as_dtype(5.0 + rng.normal(0, 1, SMALL.shape), dtype) for _ in range(3)])
    fast = ctx.pipeline(**opts)
    before = stack.copy()
    r = fast.process(stack)
    assert_sane(r, fast)
    np.testing.assert_array_equal(stack, before)
    ref = fast.replace(method="reference").process(stack)
    assert_same(r, ref, g_rtol=1e-9, u_atol=1e-9 * max(float(np.abs(r.G).max()), 1.0))


FRAME_DTYPES = [np.uint8, np.uint16, np.int16, np.int64, np.uint64, np.float16, np.float32, np.float64,
                np.longdouble]


@stress("frames", SHARE["any_frame"], dtype=st.sampled_from(FRAME_DTYPES), seed=seeds,
        scale=st.sampled_from([0.0, 1e-30, 1e-3, 1.0, 255.0, 65535.0, 1e30]), n_spots=st.integers(0, 4),
        t_n=st.integers(1, 3), filt=filters, sigma=st.sampled_from([0.0, 0.5, 2.0]),
        special=st.sampled_from([None, "nan", "inf", "neg", "huge", "hot"]))
def test_any_frame_gives_readings_or_a_documented_error(ctx, dtype, seed, scale, n_spots, t_n, filt, sigma,
                                                        special):
    rng = rng_of(seed)
    img = np.zeros((t_n, H, W))
    for e in rng.choice(N_EL, n_spots, replace=False):
        img += ctx.spot(int(e), rng.uniform(-1, 1, 2), rng.uniform(0.4, 0.8), rng.uniform(0.1, 1.0))
    img = img * scale
    info = np.finfo(dtype) if np.dtype(dtype).kind == "f" else np.iinfo(dtype)
    frames = np.clip(img, 0, min(float(info.max), 2.0**53)).astype(dtype)
    t, r, c = int(rng.integers(t_n)), int(rng.integers(H)), int(rng.integers(W))
    p = ctx.pipeline(filter=filt, noise_sigma=sigma)
    kind = np.dtype(dtype).kind
    if special == "hot" or (special in ("nan", "inf", "huge") and kind != "f") \
            or (special == "neg" and kind != "i"):
        frames[t, r, c] = info.max if kind in "ui" else 1e4
    elif special is not None:
        bad = {"nan": np.nan, "inf": np.inf, "neg": -1, "huge": min(float(info.max), 1e300)}
        frames[t, r, c] = bad[special]
    before = frames.copy()
    try:
        res = p.process(frames)
    except InputError as exc:
        where = f"frame {t}, pixel (row {r}, col {c})"
        assert (special == "nan" and "finite" in str(exc) and where in str(exc)) \
            or (special == "inf" and "finite" in str(exc)) \
            or (special == "huge" and ("magnitude at most" in str(exc) or "finite" in str(exc))) \
            or (special == "neg" and "non-negative" in str(exc) and where in str(exc)), str(exc)
        return
    ref = p.replace(method="reference").process(frames)
    np.testing.assert_array_equal(frames, before)
    assert special not in ("nan", "inf") or kind != "f"
    assert_sane(res, p)
    assert_same(res, ref, g_rtol=1e-9, u_atol=1e-9 * max(1.0, float(np.abs(res.G).max())))


@counted("frames")
def test_narrow_and_extended_floats_are_accepted(ctx):
    img = ctx.spot(3, (0.0, 0.3), 0.6, 100.0)
    pipe = ctx.pipe
    want = pipe.process(img.astype(np.float32))
    assert_same(pipe.process(img.astype(np.float16).astype(np.float32)), pipe.process(img.astype(np.float16)))
    assert_same(pipe.process(img.astype(np.longdouble)), pipe.process(img), g_rtol=1e-15, u_atol=1e-15)
    assert want.contact[3]


@counted("frames")
def test_float32_frames_with_a_baseline_beyond_float32(ctx):
    """A float64 baseline above float32's range: nothing is lit (no overflow warning on the level)."""
    r = ctx.pipe.replace(baseline=np.full(SMALL.shape, 1e39)).process(np.full(SMALL.shape, 3e38, np.float32))
    assert not r.contact.any()


@counted("frames")
@pytest.mark.parametrize("kwargs,match", [
    (dict(k=1e300, noise_sigma=1e10), r"k \* noise_sigma must be finite"),
    (dict(min_pixels=1e308, k=30.0, noise_sigma=1e10), "noise floor of G overflows"),
    (dict(radius=1e308), "radius must be at most half a great circle of the dome, 62.83.* mm, got 1e\\+308"),
    (dict(radius=2.0, grid_mm=1e308), "grid_mm must be at most the region radius 2 mm, got 1e\\+308"),
])
def test_pipeline_options_that_overflow(kwargs, match):
    with pytest.raises(InputError, match=match):
        Pipeline(SENSOR, SMALL, **kwargs)
