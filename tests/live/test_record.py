"""MCAP recordings of live streams and their replay (``process --camera ... --record``, ``process RUN.mcap``).

The recording is read back with the ``mcap`` reader and the ROS 2 decoder of ``mcap-ros2-support``
(not optitact's own reader), and its frames are compared with what ``cv2.VideoCapture`` decodes from
the video: an independent truth for every frame, force and stamp.
"""

from __future__ import annotations

import csv
import json

import cv2
import numpy as np
import pytest
from test_process import CAM, SENSOR, spot_frame

from optitact.cli import main

mcap_reader = pytest.importorskip("mcap.reader")
ros2_decoder = pytest.importorskip("mcap_ros2.decoder")

#: Spot brightness of the clip's frames: no load first (the baseline), then loads that come and go.
AMPS = (0, 60, 120, 200, 150, 90, 0, 170)


def write_clip(path, amps=AMPS, fourcc="FFV1"):
    vw = cv2.VideoWriter(str(path), cv2.VideoWriter_fourcc(*fourcc), 30, (CAM.width, CAM.height), False)
    for a in amps:
        vw.write(spot_frame(a))
    vw.release()
    return path


def video_frames(path):
    cap = cv2.VideoCapture(str(path))
    out = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        out.append(img)
    cap.release()
    return out


def small_cal_file(path):
    """The shipped calibration's curves for the 160x120 test camera, saved to ``path``."""
    from optitact.calib.document import fingerprint
    from optitact.calib.fit import Calibration
    from optitact.calib.shipped import DEFAULT_CALIBRATION

    shipped = json.loads(DEFAULT_CALIBRATION.read_text())
    shipped.update(camera=CAM.to_dict(), pipeline={}, fingerprint=fingerprint(SENSOR, CAM, {}))
    return Calibration.from_dict(shipped).save(path)


def read_rows(path):
    with open(path, newline="") as fh:
        return list(csv.DictReader(fh))


def messages(path, topic):
    """Decoded ROS 2 messages of ``topic``: (mcap message, decoded), with the mcap reader."""
    with open(path, "rb") as f:
        reader = mcap_reader.make_reader(f, decoder_factories=[ros2_decoder.DecoderFactory()])
        return [(m, d) for _s, _c, m, d in reader.iter_decoded_messages(topics=[topic], log_time_order=True)]


def forces_of(rows, n):
    return np.array([[float(r[k]) for k in ("fx", "fy", "fz")] for r in rows]).reshape(n, 41, 3)


def test_record_outside_in_frames_forces_stamps_wrench_and_replay(user):
    """process --camera clip.avi --record s.mcap, then the recording read back and replayed, as typed."""
    clip = write_clip(user.path("clip.avi"))
    small_cal_file(user.path("cal.json"))
    r = user.run("process", "--camera", "clip.avi", "--calibration", "cal.json", "--record", "s.mcap",
                 "--out", "live.csv")
    assert r.returncode == 0, r.stderr
    assert "recorded 8 frames (lossless frames) to s.mcap" in r.stderr
    assert not user.path("s.partial.mcap").exists()
    n = len(AMPS)
    truth = video_frames(clip)
    assert len(truth) == n

    # every frame present and bit-identical to the video's (a grey video decodes as BGR of equal channels)
    images = messages(user.path("s.mcap"), "/optitact/camera/image")
    assert len(images) == n
    for (_, img), want in zip(images, truth, strict=True):
        assert img.encoding == "mono8" and (img.height, img.width) == (CAM.height, CAM.width)
        got = np.frombuffer(bytes(img.data), np.uint8).reshape(img.height, img.step)[:, :img.width]
        for c in range(3):
            np.testing.assert_array_equal(got, want[:, :, c])

    # the forces equal process's CSV to the last digit; the stamps are the CSV's capture times
    rows = read_rows(user.path("live.csv"))
    per_frame = read_rows(user.path("live.per_frame.csv"))
    elements = messages(user.path("s.mcap"), "/optitact/elements")
    assert [d.frame for _, d in elements] == list(range(n))
    got = np.array([np.stack([d.fx, d.fy, d.fz], -1) for _, d in elements])
    np.testing.assert_array_equal(got, forces_of(rows, n))
    np.testing.assert_array_equal(np.array([d.g for _, d in elements]),
                                  np.array([float(r["G"]) for r in rows]).reshape(n, 41))
    np.testing.assert_array_equal(np.array([d.contact for _, d in elements]),
                                  np.array([r["contact"] == "1" for r in rows]).reshape(n, 41))
    se = np.array([np.stack([d.fx_stderr, d.fy_stderr, d.fz_stderr], -1) for _, d in elements])
    assert np.isfinite(se).all() and (se > 0).all()
    stamps = np.array([m.log_time for m, _ in elements])
    assert (np.diff(stamps) > 0).all()
    header = np.array([d.header.stamp.sec * 10**9 + d.header.stamp.nanosec for _, d in elements])
    np.testing.assert_array_equal(header, stamps)
    assert [m.log_time for m, _ in images] == stamps.tolist()
    # the CSV's time_s is the same capture moment: its differences are the stamps' (to the microsecond)
    time_s = np.array([float(per_frame[k]["time_s"]) for k in range(n)])
    np.testing.assert_allclose(np.diff(stamps) / 1e9, np.diff(time_s), atol=2e-6)

    # the resultant as geometry_msgs/msg/WrenchStamped, decoded with its ROS 2 definition
    wrenches = messages(user.path("s.mcap"), "/optitact/wrench")
    assert len(wrenches) == n
    schema_names = set()
    with open(user.path("s.mcap"), "rb") as f:
        summary = mcap_reader.make_reader(f).get_summary()
        schema_names = {s.name for s in summary.schemas.values()}
        encodings = {c.topic: c.message_encoding for c in summary.channels.values()}
    assert "geometry_msgs/msg/WrenchStamped" in schema_names and encodings["/optitact/wrench"] == "cdr"
    for (_, w), row in zip(wrenches, per_frame, strict=True):
        assert [w.wrench.force.x, w.wrench.force.y, w.wrench.force.z] == [
            float(row[f"resultant_{a}"]) for a in "xyz"]
    assert any(abs(w.wrench.force.z) > 0.05 for _, w in wrenches)

    # Rerun's own MCAP importer reads the recording too (images, wrenches, the custom messages)
    rerun_chunk = pytest.importorskip("rerun.chunk")
    entities = {c.entity_path for c in rerun_chunk.McapReader(user.path("s.mcap")).stream()}
    assert {"/optitact/camera/image", "/optitact/elements", "/optitact/wrench"} <= entities

    # replay with the same calibration: the same forces, to a Parquet table
    r = user.run("process", "s.mcap", "--calibration", "cal.json", "--out", "replay.parquet")
    assert r.returncode == 0, r.stderr
    import pandas as pd

    replay = pd.read_parquet(user.path("replay.parquet"))
    np.testing.assert_array_equal(replay[["fx", "fy", "fz"]].to_numpy().reshape(n, 41, 3), forces_of(rows, n))
    assert replay["source"].iloc[0] == "s.mcap#0"
    # the recorded capture times, not the replay's: the live stream's own, to the bit
    np.testing.assert_array_equal(replay["time_s"].to_numpy()[::41], time_s)
    live_drift = np.array([[float(r[k]) for k in ("drift_gain", "drift_offset")] for r in per_frame])
    np.testing.assert_array_equal(replay.groupby("frame")[["drift_gain", "drift_offset"]].first().to_numpy(),
                                  live_drift)


def test_lossy_and_no_frames(tmp_path, capsys):
    clip = write_clip(tmp_path / "clip.avi")
    cal = small_cal_file(tmp_path / "cal.json")
    for mode in ("lossy", "none"):
        out = tmp_path / f"{mode}.mcap"
        assert main(["process", "--camera", str(clip), "--calibration", str(cal), "--record", str(out),
                     "--frames", mode, "--out", str(tmp_path / f"{mode}.csv")]) == 0
    err = capsys.readouterr().err
    assert "--frames lossy: JPEG changes G and the centroids" in err
    jpeg = messages(tmp_path / "lossy.mcap", "/optitact/camera/compressed")
    assert len(jpeg) == len(AMPS) and all(d.format == "jpeg" for _, d in jpeg)
    assert not messages(tmp_path / "none.mcap", "/optitact/camera/image")
    assert len(messages(tmp_path / "none.mcap", "/optitact/elements")) == len(AMPS)
    refused(capsys, ["process", str(tmp_path / "none.mcap"), "--out", str(tmp_path / "r.csv")],
            "holds no frames")
    # a lossy recording replays, with forces that differ a little from the live ones
    assert main(["process", str(tmp_path / "lossy.mcap"), "--calibration", str(cal),
                 "--out", str(tmp_path / "lossy_replay.csv")]) == 0
    a = forces_of(read_rows(tmp_path / "lossy.csv"), len(AMPS))
    b = forces_of(read_rows(tmp_path / "lossy_replay.csv"), len(AMPS))
    assert np.abs(a - b).max() < 0.2


def refused(capsys, argv, message):
    assert main(argv) == 2
    err = capsys.readouterr().err
    assert message in err, err
    assert "Traceback" not in err


@pytest.mark.parametrize("argv, message", [
    (["--record", "run.csv"], "the name must end in .mcap"),
    (["--record", "missing/run.mcap"], "the folder missing does not exist"),
    (["--view", "view.txt"], "view.txt"),
])
def test_record_and_view_refuse_bad_names(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    write_clip(tmp_path / "clip.avi")
    refused(capsys, ["process", "--camera", "clip.avi", "--out", "r.csv", *argv], message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clip.avi"]


def test_replay_refuses_what_is_not_a_recording(tmp_path, monkeypatch, capsys):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "bad.mcap").write_bytes(b"not an mcap file at all")
    refused(capsys, ["process", "bad.mcap", "--out", "r.csv"], "bad.mcap: not a readable MCAP file")
    refused(capsys, ["process", "gone.mcap", "--out", "r.csv"], "recording not found: gone.mcap")
    write_clip(tmp_path / "clip.avi")
    refused(capsys, ["process", "bad.mcap", "clip.avi", "--out", "r.csv"], "replayed alone")
    refused(capsys, ["process", "clip.avi", "--record", "x.mcap", "--out", "r.csv"],
            "options of a --camera stream or a replayed recording")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.mcap", "clip.avi"]


def test_sixteen_bit_and_colour_frames_are_stored_as_they_came(tmp_path):
    """The recorder stores mono16 and true colour as given, and the reader gives them back bit for bit."""
    from optitact.live.record import Recorder, read_recording
    from optitact.live.stream import stream
    from optitact.pipeline.frame_pipeline import Pipeline

    class Capture:
        def __init__(self, frames):
            self.frames = list(frames)

        def read(self):
            return (True, self.frames.pop(0)) if self.frames else (False, None)

        def release(self):
            pass

    rng = np.random.default_rng(0)
    grey16 = [(spot_frame(a, dtype=np.uint16).astype(np.uint16) * 200 + rng.integers(0, 50, CAM.shape)
               ).astype(np.uint16) for a in (0, 100, 180)]
    colour = [np.dstack([f, np.roll(f, 1, 0), f // 2]) for f in (spot_frame(a) for a in (0, 100, 180))]
    for name, frames in (("grey16", grey16), ("colour", colour)):
        path = tmp_path / f"{name}.mcap"
        with Recorder(path, source="test", sensor=SENSOR, camera=CAM) as rec:
            for lf in stream(Capture(frames), pipeline=Pipeline(SENSOR, CAM)):
                rec.write(lf)
        recording = read_recording(path)
        assert recording.n_frames == 3 and recording.frames == "lossless"
        assert recording.metadata["source"] == "test"
        for (_, _, _, got), want in zip(recording.images(), frames, strict=True):
            assert got.dtype == want.dtype
            np.testing.assert_array_equal(got, want)


def test_bench_live_runs_every_configuration_and_counts_every_frame(tmp_path, capsys):
    """A short bench live: each configuration's frames are all accounted for (processed + dropped)."""
    pytest.importorskip("rerun")
    plot = tmp_path / "live.png"
    assert main(["bench", "live", "--rates", "30", "--seconds", "0.5", "--configs", "forces",
                 "forces + viewer + recorder", "--plot", str(plot)]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["camera"] == "640x480" and [r["config"] for r in out["rows"]] == [
        "forces", "forces + viewer + recorder"]
    for row in out["rows"]:
        assert row["frames"] == 15 and row["processed"] + row["dropped"] == 15, row
        assert row["dropped"] == row["dropped_at_start"] + row["dropped_after_start"]
        assert 0 < row["forces_ms_median"] <= row["forces_ms_p99"]
        assert (row["viewer_ms_median"] is not None) == ("viewer" in row["config"])
        assert (".mcap" in row["bytes_per_frame"]) == ("recorder" in row["config"])
    assert plot.stat().st_size > 0


def test_drift_beyond_tracking_is_flagged_in_the_table_and_warned_once(tmp_path, monkeypatch, capsys):
    """The black level falls below zero mid-stream: a warning, once, and drift_flag 1 from that frame on."""
    monkeypatch.chdir(tmp_path)
    frames = [spot_frame(0)] * 3 + [spot_frame(120)] + [np.clip(spot_frame(120).astype(int) - 10, 0, 255)
                                                          .astype(np.uint8)] * 3
    vw = cv2.VideoWriter("clip.avi", cv2.VideoWriter_fourcc(*"FFV1"), 30, (CAM.width, CAM.height), False)
    for f in frames:
        vw.write(f)
    vw.release()
    assert main(["process", "--camera", "clip.avi", "--out", "r.csv"]) == 0
    err = capsys.readouterr().err
    assert err.count("warning: drift beyond what tracking follows at clip.avi#4") == 1, err
    assert "the black level fell" in err and "take a new baseline with the sensor unloaded" in err
    flags = [int(r["drift_flag"]) for r in read_rows(tmp_path / "r.csv")[::41]]
    assert flags == [0, 0, 0, 0, 1, 1, 1]
    assert main(["process", "--camera", "clip.avi", "--drift", "off", "--out", "off.csv"]) == 0
    assert "drift_flag" not in read_rows(tmp_path / "off.csv")[0]
