"""The fast method's two kernels (pipeline.kernel): numba and the NumPy fallback give the same readings.

Truth is the NumPy path (``np.bincount`` over gathered entries, itself checked against the
reference steps in test_frame_pipeline.py): the compiled pass must match it bit for bit (array_equal)
on random integer frames with spots, on the pipeline tests' analytic frames, for every frame dtype;
threaded batches must equal serial ones. Without numba, ``"auto"`` falls back and ``"numba"``
names the extra to install.
"""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest
import test_frame_pipeline as test_pipeline

import optitact
from optitact.errors import InputError, OptitactWarning
from optitact.pipeline import kernel as _kernel
from optitact.pipeline.fastpath import CHUNK_FRAMES
from optitact.pipeline.frame_pipeline import Pipeline

SENSOR = optitact.optics.sensor.DomeSensor.default()
SMALL = optitact.optics.camera.FisheyeCamera(width=160, height=120)
DTYPES = [np.uint8, np.uint16, np.float32, np.float64]
FIELDS = ("G", "u", "contact", "saturated")
noisy_scene = test_pipeline.noisy_scene  # the pipeline tests' fixture, shared

needs_numba = pytest.mark.skipif(not _kernel.available(), reason="numba (the fast extra) is not installed")


def assert_identical(a, b):
    for name in FIELDS:
        np.testing.assert_array_equal(getattr(a, name), getattr(b, name), err_msg=name)


def random_frames(dtype, n=3, seed=0, shape=SMALL.shape):
    """Integer-valued frames: a noisy background, bright square spots, a few saturated pixels."""
    rng = np.random.default_rng(seed)
    top = 255 if dtype == np.uint8 else 4095
    base = rng.integers(2, 12, shape)
    frames = base[None] + rng.integers(0, 4, (n,) + shape)
    for t in range(n):
        for _ in range(12):
            r, c = rng.integers(0, shape[0] - 6), rng.integers(0, shape[1] - 6)
            frames[t, r:r + 5, c:c + 5] += rng.integers(20, top // 2)
        frames[t].reshape(-1)[rng.integers(0, frames[t].size, 30)] = top
    frames = np.clip(frames, 0, top)
    return frames.astype(dtype), base.astype(dtype)


@pytest.fixture(scope="module")
def pipes():
    """Per dtype: (numpy pipeline, numba pipeline), with a one-frame baseline of that dtype."""
    out = {}
    for dtype in DTYPES:
        _, base = random_frames(dtype)
        sat = None if dtype == np.uint8 else 4095.0
        p = Pipeline(SENSOR, SMALL, baseline=np.stack([base, base]), noise_sigma=1.0, saturation=sat,
                     kernel="numpy")
        out[dtype] = (p, p.replace(kernel="numba") if _kernel.available() else None)
    return out


@needs_numba
@pytest.mark.parametrize("dtype", DTYPES)
def test_numba_equals_numpy_on_random_frames(pipes, dtype):
    frames, _ = random_frames(dtype, n=3, seed=1)
    if np.dtype(dtype).kind == "f":
        frames = frames + np.asarray(0.25, dtype)  # off the integers: the float test decides
    p_np, p_nb = pipes[dtype]
    assert (p_np.kernel, p_nb.kernel) == ("numpy", "numba")
    a, b = p_np.process(frames), p_nb.process(frames)
    assert_identical(a, b)
    assert a.contact.any() and a.saturated.any()  # the frames exercise every branch
    for t, f in enumerate(frames):  # single frames: the same readings as the rows of the stack
        assert_identical(p_np.process(f), p_nb.process(f))
        assert_identical(p_nb.process(f), b[t])


@needs_numba
@pytest.mark.parametrize("base,thr", [(0.7, 0.3), (1.4, 0.6), (1.7, 0.3), (10.0, 2.0), (10.0, 0.0)])
@pytest.mark.parametrize("dtype", DTYPES)
def test_numba_equals_numpy_at_the_threshold(base, thr, dtype):
    """Frames exactly one rounding step from ``baseline + threshold`` light the same entries."""
    n = np.floor(base + thr) + np.arange(-1, 3)[:, None, None]
    frames = np.broadcast_to(np.maximum(n, 0), (4,) + SMALL.shape).astype(dtype)
    p = Pipeline(SENSOR, SMALL, baseline=np.full(SMALL.shape, base), k=1.0, noise_sigma=thr, min_pixels=0.0,
                 kernel="numpy")
    a, b = p.process(frames), p.replace(kernel="numba").process(frames)
    assert_identical(a, b)
    np.testing.assert_array_equal(a.contact.any(axis=1), (n[:, 0, 0] - base) > thr)


@needs_numba
def test_numba_equals_numpy_on_the_pipeline_tests_frames(noisy_scene):
    """The pipeline tests' analytic spot frames (41 spots, structured background, noise), uint8 and float64."""
    frame, base = noisy_scene
    for dtype in (np.uint8, np.float64):
        cast = lambda a, d=dtype: np.asarray(a, d)  # noqa: E731
        p = Pipeline(SENSOR, test_pipeline.CAM, baseline=cast(base), noise_sigma=1.0, kernel="numpy")
        q = p.replace(kernel="numba")
        a, b = p.process(cast(frame)), q.process(cast(frame))
        assert_identical(a, b)
        assert a.contact.sum() == 41
        # and the reference still agrees with the compiled path to rounding
        r = p.replace(method="reference").process(cast(frame))
        np.testing.assert_allclose(b.G, r.G, rtol=1e-9, atol=0)
        np.testing.assert_allclose(b.u, r.u, rtol=0, atol=1e-9)


@pytest.mark.parametrize("n_pixels", [64, 100, 1000])
def test_chunks_cover_every_entry_once(n_pixels):
    """Every entry sits in exactly one slot chain at its own pixel; empty slots never light."""
    rng = np.random.default_rng(n_pixels)
    pixel = np.sort(rng.integers(0, n_pixels, 3 * n_pixels // 4))  # repeats: pixels shared by regions
    level = rng.integers(0, 200, n_pixels).astype(np.uint8)[pixel]  # a pixel's level (its baseline + threshold)
    chunk_start, slot_entry, slot_level, next_same_pixel = _kernel.chunks(pixel, level, n_pixels)
    assert np.all(chunk_start >= 0) and np.all(chunk_start + _kernel.CHUNK <= n_pixels)
    seen = []
    for slot in np.flatnonzero(slot_entry >= 0):
        k, j = divmod(slot, _kernel.CHUNK)
        i = slot_entry[slot]
        while True:  # the kernel's walk over a shared pixel's entries
            assert pixel[i] == chunk_start[k] + j
            seen.append(i)
            if not next_same_pixel[i]:
                break
            i += 1
        assert slot_level[slot] == level[slot_entry[slot]]
    assert sorted(seen) == list(range(len(pixel)))  # each entry once
    assert np.all(slot_level[slot_entry < 0] == 255)  # nothing is greater than the dtype's top
    with pytest.raises(ValueError, match="share its lit level"):
        _kernel.chunks(np.array([3, 3]), np.array([1, 2], np.uint8), n_pixels)


@needs_numba
@pytest.mark.parametrize("dtype", DTYPES)
def test_numba_equals_numpy_where_regions_touch_and_on_tiny_frames(dtype):
    """Wide regions share pixels (two entries per pixel); on the smallest frames the last chunk is clamped."""
    for camera, radius in ((SMALL, 3.5), (optitact.optics.camera.FisheyeCamera(width=12, height=9), None)):
        frames, base = random_frames(dtype, n=4, seed=3, shape=(max(camera.height, 12), camera.width))
        frames, base = frames[:, :camera.height], base[:camera.height]
        with warnings.catch_warnings():  # a 12x9 one-frame baseline is too small to measure noise: said
            warnings.simplefilter("ignore", OptitactWarning)
            fast = Pipeline(SENSOR, camera, baseline=base, kernel="numba", threads=1, radius=radius)
            slow = fast.replace(kernel="numpy")
        if radius is not None:
            pix = fast.region_weights.pixel
            assert np.any(pix[1:] == pix[:-1])  # the case under test
        assert_identical(fast.process(frames), slow.process(frames))


@needs_numba
@pytest.mark.parametrize("kernel", ["numba", "numpy"])
def test_threaded_batch_equals_serial(pipes, kernel):
    frames, _ = random_frames(np.uint8, n=2 * CHUNK_FRAMES + 5, seed=2)
    p = pipes[np.uint8][0].replace(kernel=kernel, threads=1)
    serial = p.process(frames)
    for threads in (2, 3, 7):
        assert_identical(p.replace(threads=threads).process(frames), serial)
    assert_identical(serial[[0, 70, -1]], p.process(frames[[0, 70, -1]]))  # in frame order


def test_default_threads_split_long_stacks_only(pipes):
    """threads=None: every core, at least MIN_FRAMES_PER_THREAD frames each; readings as one thread's."""
    from optitact.pipeline.fastpath import MIN_FRAMES_PER_THREAD, thread_count

    assert thread_count(None, 4, 1) == 1 and thread_count(None, 4, 2 * MIN_FRAMES_PER_THREAD - 1) == 1
    assert thread_count(None, 4, 2 * MIN_FRAMES_PER_THREAD) == 2 and thread_count(None, 4, 1000) == 4
    assert thread_count(3, 16, 2) == 2 and thread_count(1, 16, 1000) == 1
    p = pipes[np.uint8][0].replace(kernel="auto", threads=None)
    frames, _ = random_frames(np.uint8, n=4 * MIN_FRAMES_PER_THREAD + 3, seed=5)
    assert_identical(p.process(frames), p.replace(threads=1).process(frames))


def test_run_blocks_covers_every_item_once_in_order():
    """Blocks cover 0 .. n - 1 once, results in block order, whichever thread took a block."""
    from optitact.pipeline.fastpath import BLOCKS_PER_THREAD, run_blocks

    for n, threads in ((1, 2), (5, 1), (7, 3), (1000, 2), (2 * BLOCKS_PER_THREAD + 1, 2)):
        parts = run_blocks(lambda a, b: list(range(a, b)), n, threads)
        assert [i for p in parts for i in p] == list(range(n))
        assert len(parts) <= threads * BLOCKS_PER_THREAD or threads == 1
    seen = set()

    def slow_first(a, b):  # the block of 0 holds its thread up: the others take the rest
        seen.add(threading.get_ident())
        if a == 0:
            time.sleep(0.2)
        return b - a

    assert sum(run_blocks(slow_first, 64, 2)) == 64 and len(seen) == 2


def test_run_blocks_errors_reach_the_caller():
    from optitact.pipeline.fastpath import run_blocks

    done = []

    def fail_at_5(a, b):
        if a <= 5 < b:
            raise ZeroDivisionError("block with 5")
        time.sleep(0.001)
        done.append(a)
        return a

    with pytest.raises(ZeroDivisionError, match="block with 5"):
        run_blocks(fail_at_5, 10_000, 2)  # 8 blocks; the first one fails at once
    assert len(done) <= 3  # the first error stopped the handing out of blocks

    def all_fail(a, b):  # the pool worker's block fails at once, the caller's later: the worker's error wins
        if threading.current_thread() is threading.main_thread():
            time.sleep(0.05)
            raise ValueError("the caller's")
        raise ValueError("the worker's")

    with pytest.raises(ValueError, match="the worker's"):
        run_blocks(all_fail, 64, 2)


def test_kernel_and_threads_options(pipes):
    p = pipes[np.uint8][0]
    assert p.kernel == "numpy" and p.replace(kernel="auto").kernel == ("numba" if _kernel.available()
                                                                         else "numpy")
    assert p.threads >= 1 and p.replace(threads=3).threads == 3
    assert p.replace(threads=2).replace(k=2.0).threads == 2  # replace keeps the options
    with pytest.raises(InputError, match=r"kernel must be one of .*'numba'.*got 'cuda'"):
        p.replace(kernel="cuda")
    with pytest.raises(InputError, match="threads"):
        p.replace(threads=0)


BLOCK = textwrap.dedent("""
    import importlib.abc, sys, json
    class _Missing(importlib.abc.MetaPathFinder):
        def find_spec(self, name, path=None, target=None):
            if name.split(".")[0] == "numba":
                raise ModuleNotFoundError(f"No module named {name!r}", name=name)
            return None
    sys.meta_path.insert(0, _Missing())
    import numpy as np, optitact
    s = optitact.optics.sensor.DomeSensor.default()
    cam = optitact.optics.camera.FisheyeCamera(width=160, height=120)
    p = optitact.pipeline.frame_pipeline.Pipeline(s, cam)
    frame = np.zeros(cam.shape, np.uint8)
    frame[50:60, 70:90] = 200
    out = {"auto": p.kernel, "G": p.process(frame).G.tolist(), "numba_imported": "numba" in sys.modules}
    try:
        optitact.pipeline.frame_pipeline.Pipeline(s, cam, kernel="numba")
    except Exception as exc:
        out["error"] = [type(exc).__name__, str(exc), isinstance(exc, ImportError)]
    print(json.dumps(out))
""")


def test_without_numba_auto_falls_back_and_numba_names_the_extra(tmp_path):
    r = subprocess.run([sys.executable, "-c", BLOCK], capture_output=True, text=True, cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    out = json.loads(r.stdout)
    assert out["auto"] == "numpy" and not out["numba_imported"]
    name, message, is_import_error = out["error"]
    assert name == "MissingExtraError" and is_import_error
    assert "numba" in message and "pip install 'optitact[fast]'" in message
    frame = np.zeros(SMALL.shape, np.uint8)
    frame[50:60, 70:90] = 200
    np.testing.assert_array_equal(out["G"], Pipeline(SENSOR, SMALL).process(frame).G)  # same readings


@needs_numba
def test_compiled_kernel_caches_in_the_user_cache_folder():
    from optitact.io.cache import cache_dir

    Pipeline(SENSOR, SMALL, kernel="numba").process(np.zeros(SMALL.shape, np.uint8))
    assert any((cache_dir() / "numba").rglob("*.nbi"))
    assert not any(Path(optitact.__file__).parent.rglob("*.nbi"))  # never next to the source
