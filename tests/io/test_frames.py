"""Frame files (optitact.io.frames): lossy and truncated sources, bad .npy files, frame sizes."""

import re
import struct
import tracemalloc
import warnings
import zlib

import cv2
import numpy as np
import pytest

from optitact.cli import main
from optitact.errors import InputError, ShapeError
from optitact.io.frames import FramesWarning, count_frames, expand_sources, iter_frames
from optitact.optics.camera import MAX_FRAME_PIXELS, FisheyeCamera
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.regions import region_weights, split_regions

W, H = 64, 48
N_FRAMES = 40


def _frames(n=N_FRAMES):
    rng = np.random.default_rng(3)
    return [rng.integers(0, 60, (H, W), dtype=np.uint8) for _ in range(n)]


def _video(path, fourcc, frames):
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 10, (W, H), False)
    assert vw.isOpened()
    for f in frames:
        vw.write(f)
    vw.release()
    return path


def _read_quietly(path):
    """Frames of a file, failing on any warning."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return [f for _, f in iter_frames(expand_sources([path]))]


# ---------------------------------------------------------------------------- lossy sources
@pytest.mark.parametrize("fourcc, suffix, name", [("MJPG", ".avi", "Motion JPEG"), ("mp4v", ".mp4", "MPEG-4")])
def test_lossy_video_warns_once_per_file(tmp_path, fourcc, suffix, name):
    path = _video(tmp_path / f"clip{suffix}", fourcc, _frames(3))
    with pytest.warns(FramesWarning, match=rf"clip{suffix}: video codec .* is lossy \({name}\)") as rec:
        got = [f for _, f in iter_frames([path])]
    assert len(got) == 3 and len(rec) == 1
    assert len(_read_quietly(path)) == 3  # once per file: a second read is silent


def test_lossless_video_and_png_read_exactly_without_warning(tmp_path):
    frames = _frames(3)
    path = _video(tmp_path / "clip.avi", "FFV1", frames)
    got = _read_quietly(path)
    np.testing.assert_array_equal(np.stack(got), np.stack(frames))
    cv2.imwrite(str(tmp_path / "f.png"), frames[0])
    np.testing.assert_array_equal(_read_quietly(tmp_path / "f.png")[0], frames[0])


def test_lossy_images_warn(tmp_path):
    frame = _frames(1)[0]
    cv2.imwrite(str(tmp_path / "f.jpg"), frame)
    with pytest.warns(FramesWarning, match=r"f\.jpg: JPEG is a lossy format"):
        [(name, got)] = list(iter_frames([tmp_path / "f.jpg"]))
    assert name == "f.jpg" and got.shape == (H, W)
    cv2.imwrite(str(tmp_path / "lossy.webp"), frame, [cv2.IMWRITE_WEBP_QUALITY, 80])
    with pytest.warns(FramesWarning, match=r"lossy\.webp: lossy WebP is a lossy format"):
        list(iter_frames(expand_sources([tmp_path / "lossy.webp"])))
    cv2.imwrite(str(tmp_path / "exact.webp"), frame, [cv2.IMWRITE_WEBP_QUALITY, 101])  # lossless
    np.testing.assert_array_equal(_read_quietly(tmp_path / "exact.webp")[0], frame)


# ---------------------------------------------------------------------------- truncated videos
@pytest.mark.parametrize("fourcc", ["FFV1", "MJPG"])
@pytest.mark.parametrize("fraction", [0.5, 0.95])
def test_truncated_video_reports_frames_read_against_announced(tmp_path, fourcc, fraction):
    full = _video(tmp_path / "full.avi", fourcc, _frames())
    cut = tmp_path / "cut.avi"
    data = full.read_bytes()
    cut.write_bytes(data[:int(len(data) * fraction)])
    assert count_frames([cut]) == N_FRAMES  # the header still announces them all
    with warnings.catch_warnings(record=True) as rec:
        warnings.simplefilter("always")
        n_read = sum(1 for _ in iter_frames([cut]))
    assert 0 < n_read < N_FRAMES
    truncated = [str(w.message) for w in rec if "announces" in str(w.message)]
    assert truncated == [f"{cut}: read {n_read} of the {N_FRAMES} frames its header announces; the video "
                         f"is truncated or corrupt after frame {n_read - 1}"]
    assert all(issubclass(w.category, FramesWarning) for w in rec)


def test_whole_video_has_no_truncation_warning(tmp_path):
    assert len(_read_quietly(_video(tmp_path / "full.avi", "FFV1", _frames()))) == N_FRAMES


def test_process_cli_reports_a_truncated_video(tmp_path, capsys):
    full = _video(tmp_path / "full.avi", "FFV1", _frames())
    cut = tmp_path / "cut.avi"
    cut.write_bytes(full.read_bytes()[:len(full.read_bytes()) // 2])
    assert main(["process", str(cut), "--out", str(tmp_path / "r.csv")]) == 0
    # the command line prints the warning as one line of its own, no source line
    lines = [ln for ln in capsys.readouterr().err.splitlines() if "warning" in ln.lower()]
    assert len(lines) == 1
    assert re.fullmatch(r"optitact: warning: .*cut\.avi: read \d+ of the 40 frames its header announces; .*",
                        lines[0])


# ---------------------------------------------------------------------------- bad .npy files
@pytest.mark.parametrize("cut", [9, 20, 40, 60, 100, 127, 200])
def test_truncated_npy_is_named_as_such(tmp_path, cut):
    good = tmp_path / "good.npy"
    np.save(good, np.zeros((3, H, W), np.uint8))
    bad = tmp_path / "bad.npy"
    bad.write_bytes(good.read_bytes()[:cut])
    want = re.escape(f"{bad}: truncated or corrupt .npy file")
    with pytest.raises(InputError, match=want):
        list(iter_frames([bad]))
    with pytest.raises(InputError, match=want):
        count_frames([bad])


def test_npy_of_python_objects_is_refused(tmp_path):
    path = tmp_path / "obj.npy"
    np.save(path, np.array([{"a": 1}], dtype=object), allow_pickle=True)
    with pytest.raises(InputError, match="obj.npy: holds Python objects"):
        list(iter_frames([path]))


@pytest.mark.parametrize("shape", [(), (100,), (2, 3, H, W), (1, 2, 3, 4, 5)])
def test_npy_of_the_wrong_shape(tmp_path, shape, capsys):
    path = tmp_path / "x.npy"
    np.save(path, np.zeros(shape, np.uint8))
    want = re.escape(f"{path}: wrong shape: expected (H, W) or (T, H, W), got {shape}")
    with pytest.raises(ShapeError, match=want):
        list(iter_frames([path]))
    with pytest.raises(ShapeError, match=want):
        count_frames([path])
    assert main(["process", str(path), "--out", str(tmp_path / "r.csv")]) == 2
    assert "wrong shape" in capsys.readouterr().err


# ---------------------------------------------------------------------------- frame size
def test_too_small_frame_names_the_minimum(tmp_path, capsys):
    sensor = DomeSensor.default()
    with pytest.raises(InputError, match=r"frame too small: a 2x2 frame .* at least (\d+) pixels") as exc:
        Pipeline(sensor, FisheyeCamera(width=2, height=2))
    need = int(re.search(r"at least (\d+) pixels", str(exc.value)).group(1))
    # the minimum is exact: a camera of that shorter side builds its regions, one pixel less cannot
    assert split_regions(sensor, FisheyeCamera(width=need + 3, height=need)).mask.any(axis=(1, 2)).all()
    with pytest.raises(InputError, match=f"frame too small.*at least {need} pixels"):
        split_regions(sensor, FisheyeCamera(width=need + 3, height=need - 1))
    cv2.imwrite(str(tmp_path / "tiny.png"), np.zeros((2, 2), np.uint8))
    assert main(["process", str(tmp_path / "tiny.png"), "--out", str(tmp_path / "r.csv")]) == 2
    assert "frame too small" in capsys.readouterr().err


def _png_header_only(path, width, height):
    """A PNG whose header says width x height, with no pixels: reading them would fail."""
    ihdr = struct.pack(">IIBBBBB", width, height, 8, 0, 0, 0, 0)
    chunk = b"IHDR" + ihdr
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + struct.pack(">I", 13) + chunk
                     + struct.pack(">I", zlib.crc32(chunk)))
    return path


def test_huge_frame_is_refused_before_reading(tmp_path, monkeypatch, capsys):
    big = _png_header_only(tmp_path / "big.png", 8000, 8000)
    monkeypatch.setattr(cv2, "imread", lambda *a, **k: pytest.fail("the pixels were read"))
    with pytest.raises(InputError, match=r"big\.png: frame too large: 8000x8000 .* OPTITACT_MAX_FRAME_PIXELS"):
        list(iter_frames([big]))
    assert main(["process", str(big), "--out", str(tmp_path / "r.csv")]) == 2
    assert "frame too large" in capsys.readouterr().err
    with pytest.raises(InputError, match="camera: frame too large: 8000x8000"):
        FisheyeCamera(width=8000, height=8000)
    assert FisheyeCamera(width=4096, height=MAX_FRAME_PIXELS // 4096).shape == (4096, 4096)


def test_frame_size_limit_can_be_changed(tmp_path, monkeypatch):
    cv2.imwrite(str(tmp_path / "f.png"), _frames(1)[0])
    np.save(tmp_path / "s.npy", np.zeros((2, H, W), np.uint8))
    video = _video(tmp_path / "clip.avi", "FFV1", _frames(2))
    monkeypatch.setenv("OPTITACT_MAX_FRAME_PIXELS", str(W * H - 1))
    for path in (tmp_path / "f.png", tmp_path / "s.npy", video):
        with pytest.raises(InputError, match=f"frame too large: {W}x{H} = 3,072 pixels, more than the 3,071"):
            list(iter_frames([path]))
    monkeypatch.setenv("OPTITACT_MAX_FRAME_PIXELS", str(W * H))
    assert len(list(iter_frames([tmp_path / "f.png", tmp_path / "s.npy", video]))) == 5
    monkeypatch.setenv("OPTITACT_MAX_FRAME_PIXELS", "lots")
    with pytest.raises(InputError, match="OPTITACT_MAX_FRAME_PIXELS must be an integer"):
        FisheyeCamera()


def test_region_precompute_memory_stays_near_what_it_keeps():
    # A camera no other test uses (no cache hit). The set-up used to hold the dot products of
    # every grid cell with all 41 element normals at once: a peak of 13x what it keeps here.
    sensor, cam = DomeSensor.default(), FisheyeCamera(width=160, height=120, fov_deg=141.0)
    tracemalloc.start()
    try:
        grids = split_regions(sensor, cam)
        weights = region_weights(grids, cam.shape)
        kept, peak = tracemalloc.get_traced_memory()
    finally:
        tracemalloc.stop()
    held = sum(a.nbytes for a in (grids.pixels, grids.area, grids.mask, weights.pixel, weights.label,
                                  weights.weights))
    assert held <= kept and peak <= 2.0 * held


# ----------------------------------------------------------------------------- read_ahead
def test_read_ahead_gives_the_items_in_order_and_raises_where_they_fail():
    from optitact.io.frames import read_ahead

    assert list(read_ahead(iter(range(1000)), depth=3)) == list(range(1000))

    def failing():
        yield from range(5)
        raise InputError("frame 5 is corrupt")

    got = []
    with pytest.raises(InputError, match="frame 5 is corrupt"):
        for item in read_ahead(failing(), depth=2):
            got.append(item)
    assert got == [0, 1, 2, 3, 4]  # every item before the failure, then its error


def test_read_ahead_closed_early_stops_its_thread_and_closes_the_source():
    import threading

    from optitact.io.frames import read_ahead

    closed = threading.Event()

    def endless():
        try:
            k = 0
            while True:
                yield k
                k += 1
        finally:
            closed.set()

    ahead = read_ahead(endless(), depth=4)
    assert [next(ahead) for _ in range(10)] == list(range(10))
    ahead.close()
    assert closed.wait(5.0)  # the source's finally ran (a video is released)
    assert not any(t.name == "optitact-read-ahead" and t.is_alive() for t in threading.enumerate())
    with pytest.raises(InputError, match="depth"):
        next(read_ahead(iter([1]), depth=0))


def test_read_ahead_starts_at_once_and_closing_it_unread_closes_the_source():
    import threading

    from optitact.io.frames import read_ahead

    started, closed = threading.Event(), threading.Event()

    def items():
        try:
            started.set()
            yield from range(100)
        finally:
            closed.set()

    ahead = read_ahead(items(), depth=2)
    assert started.wait(5.0)  # decoding began before anything was asked of it
    ahead.close()  # never read: the thread stops and the source is closed all the same
    assert closed.wait(5.0)
    assert not any(t.name == "optitact-read-ahead" and t.is_alive() for t in threading.enumerate())
    assert list(ahead) == []  # a closed read-ahead gives nothing more
    with read_ahead(iter(range(5)), depth=2) as ahead:
        assert list(ahead) == [0, 1, 2, 3, 4]


def test_a_read_ahead_dropped_unclosed_stops_its_thread():
    import gc
    import threading

    from optitact.io.frames import read_ahead

    closed = threading.Event()

    def endless():
        try:
            yield from iter(int, 1)  # zeros, for ever
        finally:
            closed.set()

    ahead = read_ahead(endless(), depth=2)
    assert next(ahead) == 0
    del ahead
    gc.collect()
    assert closed.wait(5.0)  # the thread saw it was dropped, closed the source and ended


def test_read_ahead_depth_is_four_batches_within_the_byte_bound():
    from optitact.io.frames import READ_AHEAD_BYTES, read_ahead_depth

    assert read_ahead_depth((480, 640), 32) == min(128, READ_AHEAD_BYTES // (2 * 480 * 640))
    assert read_ahead_depth((60, 80), 3) == 12
    assert read_ahead_depth((20000, 20000), 32) == 2  # at least two frames, however large


def test_a_grey_video_is_read_as_grey_with_the_levels_of_a_colour_read(tmp_path):
    """An 8-bit grey FFV1 video is read without OpenCV's conversion to BGR: the same levels."""
    path = _video(tmp_path / "g.avi", "FFV1", _frames())
    cap = cv2.VideoCapture(str(path))
    assert int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT)).to_bytes(4, "little") == b"Y800"
    truth = []
    while True:  # the default read: BGR, then OpenCV's BGR-to-grey
        ok, img = cap.read()
        if not ok:
            break
        truth.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    got = _read_quietly(path)
    assert len(got) == len(truth) == N_FRAMES
    assert all(g.dtype == np.uint8 and g.shape == (H, W) for g in got)
    assert all(np.array_equal(g, t) for g, t in zip(got, truth, strict=True))
    assert all(np.array_equal(g, f) for g, f in zip(got, _frames(), strict=True))  # and FFV1 is lossless


def test_a_video_read_ahead_is_the_video(tmp_path):
    from optitact.io.frames import read_ahead

    path = _video(tmp_path / "v.avi", "FFV1", _frames())
    direct = list(iter_frames([path]))
    ahead = list(read_ahead(iter_frames([path]), depth=2))
    assert [n for n, _ in ahead] == [n for n, _ in direct]
    assert all(np.array_equal(a, b) for (_, a), (_, b) in zip(ahead, direct, strict=True))


def _bgr_read(path):
    """A video as a user reads it: OpenCV's BGR frames, then its BGR-to-grey conversion."""
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        out.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    return out


def _colour_mjpg(path, saturated):
    rng = np.random.default_rng(5)
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*"MJPG"), 10, (W, H), True)
    for _ in range(8):
        img = rng.integers(0, 256, (H, W, 3), dtype=np.uint8)
        vw.write(img if saturated else cv2.GaussianBlur(img, (5, 5), 2))
    vw.release()
    return path


def test_a_grey_mjpg_video_is_read_as_its_luma_plane_with_the_levels_of_a_colour_read(tmp_path):
    """JPEG's full-range luma is the grey image: read without the BGR round trip, the same levels."""
    from optitact.io.frames import _luma_reader

    path = _video(tmp_path / "m.avi", "MJPG", _frames())
    cap = cv2.VideoCapture(str(path))
    used, first, luma = _luma_reader(path, cap, cv2)
    try:
        assert luma and used.get(cv2.CAP_PROP_CONVERT_RGB) == 0  # the luma plane is what is read
    finally:
        used.release()
    truth = _bgr_read(path)
    assert np.array_equal(first, truth[0])
    with pytest.warns(FramesWarning, match="lossy"):
        got = [f for _, f in iter_frames([path])]
    assert len(got) == len(truth) == N_FRAMES
    assert all(g.dtype == np.uint8 and g.shape == (H, W) for g in got)
    assert all(np.array_equal(g, t) for g, t in zip(got, truth, strict=True))


def test_a_colour_mjpg_video_reads_its_luma_within_the_round_trips_rounding(tmp_path):
    path = _colour_mjpg(tmp_path / "c.avi", saturated=False)
    truth = _bgr_read(path)
    with pytest.warns(FramesWarning, match="lossy"):
        got = [f for _, f in iter_frames([path])]
    assert len(got) == len(truth) == 8
    diff = [np.abs(g.astype(int) - t).max() for g, t in zip(got, truth, strict=True)]
    assert max(diff) <= 1  # the luma, up to the BGR round trip's rounding of it


def test_a_video_whose_luma_read_differs_is_read_through_bgr(tmp_path):
    """Saturated colours clip in the BGR round trip: the luma check fails and the read is OpenCV's BGR."""
    from optitact.io.frames import _luma_reader

    path = _colour_mjpg(tmp_path / "s.avi", saturated=True)
    cap = cv2.VideoCapture(str(path))
    used, first, luma = _luma_reader(path, cap, cv2)
    try:
        assert not luma and used.get(cv2.CAP_PROP_CONVERT_RGB) == 1 and first.ndim == 3
    finally:
        used.release()
    truth = _bgr_read(path)
    with pytest.warns(FramesWarning, match="lossy"):
        got = [f for _, f in iter_frames([path])]
    assert all(np.array_equal(g, t) for g, t in zip(got, truth, strict=True))


def test_opencvs_log_level_is_quiet_while_a_luma_video_is_read_and_restored_after(tmp_path):
    log = cv2.utils.logging
    path = _video(tmp_path / "m.avi", "MJPG", _frames(4))
    given = log.getLogLevel()
    log.setLogLevel(log.LOG_LEVEL_WARNING)  # as OpenCV starts, unless told otherwise
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", FramesWarning)
            frames = iter_frames([path])
            next(frames)
            assert log.getLogLevel() == log.LOG_LEVEL_ERROR
            frames.close()
        assert log.getLogLevel() == log.LOG_LEVEL_WARNING
    finally:
        log.setLogLevel(given)
