"""The pipeline's precompute cached on disk (fold_regions, cached_arrays).

Truths: the weights folded from the grids themselves (``region_weights(split_regions(...))``,
an independent route through the (E, n, n) grids), compared byte for byte; a cache file
that is truncated, bit-flipped, foreign or garbage is rebuilt (the fold runs again) and
never trusted.
"""

from __future__ import annotations

import pickle

import numpy as np
import pytest

import optitact
from optitact.pipeline import regions
from optitact.pipeline.regions import fold_regions, region_weights, split_regions

SENSOR = optitact.optics.sensor.DomeSensor.default()
CAM = optitact.optics.camera.FisheyeCamera(width=160, height=120)
FIELDS = ("pixel", "label", "weights", "pixel_area", "n_pixels")


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """A fresh, empty cache folder; the in-memory copies forgotten; counts the folds."""
    monkeypatch.setenv("OPTITACT_CACHE_DIR", str(tmp_path))
    monkeypatch.delenv("OPTITACT_PRECOMPUTE_CACHE", raising=False)
    regions.forget_folded_weights()
    calls = []
    fold = regions._fold

    def counted(*args):
        calls.append(args)
        return fold(*args)

    monkeypatch.setattr(regions, "_fold", counted)
    yield tmp_path / "precompute", calls
    regions.forget_folded_weights()


@pytest.fixture(scope="module")
def truth():
    return region_weights(split_regions(SENSOR, CAM), CAM.shape)


def _same(a, b):
    for name in FIELDS:
        x, y = getattr(a, name), getattr(b, name)
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name
    assert (a.radius, a.grid_mm) == (b.radius, b.grid_mm)


def _from_disk():
    regions.forget_folded_weights()
    return fold_regions(SENSOR, CAM)


def test_cold_cached_and_grid_folds_are_identical(cache, truth):
    folder, calls = cache
    _same(fold_regions(SENSOR, CAM, cache=False), truth)
    assert not folder.exists()  # cache=False writes nothing
    cold = fold_regions(SENSOR, CAM)
    assert len(calls) == 2 and len(list(folder.glob("*.npz"))) == 1
    assert fold_regions(SENSOR, CAM) is cold  # in memory
    warm = _from_disk()
    assert len(calls) == 2  # read from the file, not folded again
    _same(cold, truth)
    _same(warm, truth)
    assert not warm.pixel.flags.writeable and not warm.weights.flags.writeable
    grids = split_regions(SENSOR, CAM)
    assert (truth.radius, truth.grid_mm) == (grids.radius, grids.grid_mm)


def test_the_key_holds_camera_and_options(cache):
    folder, calls = cache
    fold_regions(SENSOR, CAM)
    fold_regions(SENSOR, optitact.optics.camera.FisheyeCamera(width=160, height=120, fov_deg=190.0))
    wide = fold_regions(SENSOR, CAM, radius=3.0)
    assert len(calls) == 3 and len(list(folder.glob("*.npz"))) == 3
    assert wide.radius == 3.0
    _same(wide, region_weights(split_regions(SENSOR, CAM, radius=3.0), CAM.shape))


@pytest.mark.parametrize("damage", ["truncate", "flip", "garbage", "empty", "foreign"])
def test_a_damaged_file_is_rebuilt_never_trusted(cache, truth, damage):
    folder, calls = cache
    fold_regions(SENSOR, CAM)
    (path,) = folder.glob("*.npz")
    data = path.read_bytes()
    if damage == "truncate":
        path.write_bytes(data[: len(data) // 2])
    elif damage == "flip":  # inside the weights' bytes: only the ZIP checksum can tell
        i = data.index(truth.weights.tobytes(order="A")[:64]) + 1000
        path.write_bytes(data[:i] + bytes([data[i] ^ 0x10]) + data[i + 1:])
    elif damage == "garbage":
        path.write_bytes(b"not a zip file" * 100)
    elif damage == "empty":
        path.write_bytes(b"")
    else:  # a well-formed file of other weights under this key
        other = fold_regions(SENSOR, CAM, radius=3.0)
        (other_path,) = set(folder.glob("*.npz")) - {path}
        path.write_bytes(other_path.read_bytes())
        assert other.radius == 3.0
    n = len(calls)
    _same(_from_disk(), truth)
    assert len(calls) == n + 1  # rebuilt
    _same(_from_disk(), truth)
    assert len(calls) == n + 1  # and the file is whole again


def test_inconsistent_arrays_are_refused(truth):
    good = dict(pixel=truth.pixel, label=truth.label, weights=truth.weights, pixel_area=truth.pixel_area,
                n_pixels=truth.n_pixels, geometry=np.array([truth.radius, truth.grid_mm]))
    regions._check_folded(good, SENSOR.n_elements, CAM.height * CAM.width)
    bad = [dict(good, pixel=truth.pixel[::-1]), dict(good, label=truth.label[:-1]),
           dict(good, weights=np.where(truth.weights == truth.weights[0, 0], np.nan, truth.weights)),
           dict(good, n_pixels=truth.n_pixels + 1), dict(good, pixel=truth.pixel + CAM.width * CAM.height),
           dict(good, weights=truth.weights.astype(np.float32))]
    for arrays in bad:
        with pytest.raises(ValueError, match="folded region weights"):
            regions._check_folded(arrays, SENSOR.n_elements, CAM.height * CAM.width)


def test_cache_off_by_environment_and_unwritable_folder(cache, truth, monkeypatch, tmp_path):
    folder, calls = cache
    monkeypatch.setenv("OPTITACT_PRECOMPUTE_CACHE", "0")
    _same(_from_disk(), truth)
    assert not folder.exists()
    monkeypatch.delenv("OPTITACT_PRECOMPUTE_CACHE")
    blocker = tmp_path / "file"
    blocker.write_text("")
    monkeypatch.setenv("OPTITACT_CACHE_DIR", str(blocker / "below"))  # cannot be created
    _same(_from_disk(), truth)


def test_pipeline_readings_identical_cold_and_cached_and_grids_deferred(cache, monkeypatch):
    folder, calls = cache
    rng = np.random.default_rng(3)
    frames = rng.integers(0, 40, (3,) + CAM.shape).astype(np.uint8)
    monkeypatch.setenv("OPTITACT_PRECOMPUTE_CACHE", "0")
    regions.forget_folded_weights()
    cold = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, kernel="numpy").process(frames)
    monkeypatch.delenv("OPTITACT_PRECOMPUTE_CACHE")
    optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM)  # writes the file
    regions.forget_folded_weights()
    pipe = optitact.pipeline.frame_pipeline.Pipeline(SENSOR, CAM, kernel="numpy")  # reads it
    assert len(calls) == 2
    warm = pipe.process(frames)
    for name in ("G", "u", "contact", "saturated"):
        assert getattr(cold, name).tobytes() == getattr(warm, name).tobytes(), name
    assert warm.contact.any()
    assert pipe.grids._arrays is None  # the fast method never built the grids
    sent = pickle.loads(pickle.dumps(pipe))  # as a cluster ships it: the grids still deferred
    assert sent.grids._arrays is None and sent.process(frames).G.tobytes() == warm.G.tobytes()
    assert pipe.grids.n_elements == SENSOR.n_elements and pipe.grids.radius == pipe.region_weights.radius
    ref = pipe.replace(method="reference")
    assert ref.grids is pipe.grids
    r = ref.process(frames)
    np.testing.assert_allclose(r.G, warm.G, rtol=1e-12, atol=1e-12)
    np.testing.assert_array_equal(pipe.grids.mask, split_regions(SENSOR, CAM).mask)


def test_the_folder_keeps_the_most_recently_used_files(cache, monkeypatch):
    import os

    from optitact.io import cache as _cache

    folder, calls = cache
    monkeypatch.setattr(_cache, "CACHE_KEEP", 2)
    fold_regions(SENSOR, CAM)  # A
    (first,) = folder.glob("*.npz")
    fold_regions(SENSOR, CAM, radius=3.0)  # B
    os.utime(first, (1, 1))  # A long unused ...
    _from_disk()  # ... then read again: the most recent
    (second,) = set(folder.glob("*.npz")) - {first}
    os.utime(second, (2, 2))
    fold_regions(SENSOR, CAM, radius=2.5)  # C: B, the least recently used, goes
    left = set(folder.glob("*.npz"))
    assert len(left) == 2 and first in left and second not in left
