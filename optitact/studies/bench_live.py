"""Benchmark: latency and dropped frames of a live stream, with and without the viewer and the recorder.

Not library code: ``optitact bench live`` runs it. A lossless video of
analytic contact spots (Gaussian spots of growing and moving loads drawn on
the dome through the camera model, over a dim, noisy background) is played
by :class:`PacedCapture` at a frame rate: a reader thread decodes each frame
and hands it over at its scheduled time, as a camera's driver does, and the
stream takes frames with the ``"newest"`` policy of a device, so a consumer
that falls behind drops frames (counted) rather than queueing stale ones.
Each configuration runs the same loop as ``optitact process --camera``
(:func:`optitact.live.stream.stream` with the shipped calibration and drift
tracking, :class:`~optitact.live.stream.LiveWriter` writing the rows), with
the Rerun view (:mod:`optitact.live.viewer`, logging to an ``.rrd`` file)
and/or the MCAP recorder (:mod:`optitact.live.record`, lossless frames), side
by side in one run.

Latency is measured from the moment the capture handed over a frame (its
timestamp) to the moment its forces were ready (capture to forces), and to
the moment the viewer's SDK took its log calls (capture to viewer: the
frame, arrows and series are then queued in Rerun's own sender thread; the
time the viewer itself takes to draw is not observable from here).
"""

from __future__ import annotations

import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from optitact._validate import integer, positive

__all__ = ["CONFIGS", "PacedCapture", "bench_live", "spot_clip"]

#: The configurations each rate runs: (name, with the viewer, with the recorder).
CONFIGS = (("forces", False, False), ("forces + viewer", True, False), ("forces + recorder", False, True),
           ("forces + viewer + recorder", True, True))


def spot_clip(path, calibration, *, n_frames: int = 120, seed: int = 0) -> Path:
    """Write a lossless (FFV1) video of ``n_frames`` frames of analytic spots for ``calibration``'s camera.

    Three elements are loaded at a time with loads that rise and fall over
    the clip; the background is a dim vignetted level with 0.5 grey-level
    noise, 8-bit. The first frame is unloaded (the stream's baseline).
    """
    import cv2

    rng = np.random.default_rng(seed)
    sensor, cam = calibration.sensor, calibration.camera
    rows, cols = np.mgrid[0:cam.height, 0:cam.width]
    pts = cam.unproject(np.stack([rows, cols], -1).astype(float), sensor, outside="nan")
    inside = np.isfinite(pts).all(-1)
    r = np.hypot(rows - cam.height / 2, cols - cam.width / 2) / (0.5 * min(cam.shape))
    background = 6.0 + 4.0 * np.exp(-r**2)
    loaded = rng.choice(sensor.n_elements, size=(n_frames, 3))
    offsets = {e: sensor.tangent_offset(np.full(cam.shape, e), pts) for e in np.unique(loaded)}
    vw = cv2.VideoWriter(os.fspath(path), cv2.VideoWriter_fourcc(*"FFV1"), 30, (cam.width, cam.height), False)
    try:
        for k in range(n_frames):
            img = background + rng.normal(0.0, 0.5, cam.shape)
            if k:
                amp = 60.0 + 140.0 * np.sin(np.pi * k / n_frames) ** 2
                for j, e in enumerate(loaded[k]):
                    c = np.array([0.3 * np.cos(k / 7 + j), 0.3 * np.sin(k / 5 + j)])
                    d2 = ((np.nan_to_num(offsets[e]) - c) ** 2).sum(-1)
                    img += np.where(inside, amp * np.exp(-0.5 * d2 / 0.35**2), 0.0)
            vw.write(np.clip(np.rint(img), 0, 255).astype(np.uint8))
    finally:
        vw.release()
    return Path(path)


class PacedCapture:
    """A video played at ``fps``: ``read()`` returns each frame at its scheduled time (looping the file).

    Decoding happens in ``read()`` (on the stream's reader thread, as a
    camera driver's work would), then it sleeps until the frame is due. A
    frame whose decoding ran past its time is handed over at once.
    """

    def __init__(self, path, fps: float, *, frames: int) -> None:
        import cv2

        self.path, self.fps, self.total = os.fspath(path), float(fps), int(frames)
        self.cap = cv2.VideoCapture(self.path)
        self.k = 0
        self.t0: float | None = None
        self.late = 0  # frames decoded after their scheduled time

    def read(self):
        """``(ok, image)`` at the frame's time."""
        import cv2

        if self.k >= self.total:
            return False, None
        ok, img = self.cap.read()
        if not ok:  # loop
            self.cap.release()
            self.cap = cv2.VideoCapture(self.path)
            ok, img = self.cap.read()
        if self.t0 is None:
            self.t0 = time.perf_counter()
        due = self.t0 + self.k / self.fps
        wait = due - time.perf_counter()
        if wait > 0:
            time.sleep(wait)
        else:
            self.late += 1
        self.k += 1
        return ok, img

    def release(self) -> None:
        """Close the video."""
        self.cap.release()


def _run(clip, calibration, fps: float, seconds: float, *, viewer: bool, recorder: bool, folder: Path,
         label: str) -> dict:
    """One configuration at one rate: the process --camera loop; latencies (ms) and drops."""
    from optitact.live.stream import LiveWriter, stream
    from optitact.pipeline.drift import DriftTracker

    n = int(round(fps * seconds))
    cap = PacedCapture(clip, fps, frames=n)
    forces_ms, viewer_ms = [], []
    view = rec = None
    out = LiveWriter(folder / f"{label}.csv", calibration=calibration, drift=True)
    cpu0 = time.process_time()
    try:
        if recorder:
            from optitact.live.record import Recorder

            rec = Recorder(folder / f"{label}.mcap", source="bench", calibration=calibration)
        if viewer:
            from optitact.live.viewer import open_view

            view = open_view(os.fspath(folder / f"{label}.rrd"), sensor=calibration.sensor,
                             camera=calibration.camera, calibration=calibration)
        last, start_drops = None, None
        frames = stream(cap, calibration=calibration, policy="newest", track=DriftTracker)
        for lf in frames:
            got = time.perf_counter()  # the forces were ready just before the generator gave them
            out.write(lf)
            if rec is not None:
                rec.write(lf)
            if view is not None:
                view.log(lf, latency_s=lf.latency)
                viewer_ms.append((lf.latency + time.perf_counter() - got) * 1e3)
            if not lf.baseline:
                forces_ms.append(lf.latency * 1e3)
                if start_drops is None:  # frames dropped while the baseline and the tracker were set up
                    start_drops = lf.dropped
            last = lf
        dropped = last.dropped if last is not None else 0
        processed = len(forces_ms) + 1
    finally:
        out.close()
        if rec is not None:
            rec.close()
        if view is not None:
            view.close()
    cpu = time.process_time() - cpu0
    f = np.asarray(forces_ms)
    v = np.asarray(viewer_ms)
    return {"fps": fps, "config": label.split("@")[0].replace("_", " "), "frames": n, "processed": processed,
            "dropped": int(dropped), "dropped_at_start": int(start_drops or 0),
            "dropped_after_start": int(dropped - (start_drops or 0)), "late_capture_frames": cap.late,
            "forces_ms_median": float(np.median(f)), "forces_ms_p99": float(np.percentile(f, 99)),
            "viewer_ms_median": float(np.median(v)) if v.size else None,
            "viewer_ms_p99": float(np.percentile(v, 99)) if v.size else None,
            "cpu_ms_per_frame": cpu / max(processed, 1) * 1e3}


def bench_live(*, rates=(30, 60, 120), seconds: float = 10.0, configs=None, seed: int = 0,
               plot: str | os.PathLike | None = None) -> dict:
    """Capture-to-forces and capture-to-viewer latency and dropped frames at each rate and configuration.

    Parameters
    ----------
    rates : sequence of float
        Frame rates the video is played at (frames/s).
    seconds : float
        Length of each run (frames = rate x seconds).
    configs : sequence of str, optional
        Names from :data:`CONFIGS` (default all).
    seed : int
        The clip's seed.
    plot : path-like, optional
        Save the latencies as a PNG.

    Returns
    -------
    dict
        ``rows`` (one per rate and configuration: median and 99th percentile latencies in ms, frames
        processed and dropped (in all, while the first frame's baseline and drift tracker are set up,
        and after that), CPU ms per frame), ``floor_ms`` (the pipeline and calibration alone on
        the same frames, median), the camera size and the machine's cores.
    """
    from tqdm import tqdm

    from optitact.calib.shipped import default_calibration

    seconds = positive(seconds, "seconds")
    integer(seed, "seed")
    names = [c[0] for c in CONFIGS]
    configs = names if configs is None else list(configs)
    for c in configs:
        if c not in names:
            raise ValueError(f"configs must be among {names}, got {c!r}")
    cal = default_calibration()
    cam = cal.camera
    with tempfile.TemporaryDirectory(prefix="optitact-bench-live-") as tmp:
        folder = Path(tmp)
        clip = spot_clip(folder / "clip.avi", cal, seed=seed)
        floor = _floor(clip, cal)
        rows = []
        runs = [(fps, c) for fps in rates for c in CONFIGS if c[0] in configs]
        for fps, (name, viewer, recorder) in tqdm(runs, desc="bench live", unit="run", file=sys.stderr):
            label = f"{name.replace(' ', '_').replace('+', 'and')}@{fps:g}"
            row = _run(clip, cal, float(fps), seconds, viewer=viewer, recorder=recorder, folder=folder,
                       label=label)
            row["config"] = name
            rows.append(row)
            for suffix in (".csv", ".per_frame.csv", ".mcap", ".rrd"):
                p = folder / f"{label}{suffix}"
                if p.exists():
                    row.setdefault("bytes_per_frame", {})[suffix] = p.stat().st_size / max(row["processed"], 1)
                    p.unlink()
    out = {"camera": f"{cam.width}x{cam.height}", "seconds": seconds, "cores": os.cpu_count(),
           "floor_ms": floor, "rows": rows}
    if plot is not None:
        _plot(out, plot)
        out["plot"] = os.fspath(plot)
    return out


def _floor(clip, cal) -> dict:
    """The pipeline (with drift tracking) and the calibration alone on the clip's frames: ms per frame."""
    import cv2

    from optitact.pipeline.drift import DriftTracker

    cap = cv2.VideoCapture(os.fspath(clip))
    frames = []
    while True:
        ok, img = cap.read()
        if not ok:
            break
        frames.append(cv2.cvtColor(img, cv2.COLOR_BGR2GRAY))
    cap.release()
    pipe = cal.pipeline().with_baseline(frames[0])
    tracker = DriftTracker(pipe)
    for f in frames[:10]:
        cal.apply(pipe.process(f))
        tracker.process(f)
    plain, tracked = [], []
    for f in frames[1:]:
        t = time.perf_counter()
        cal.apply(pipe.process(f))
        plain.append(time.perf_counter() - t)
        t = time.perf_counter()
        cal.apply(tracker.process(f)[0])
        tracked.append(time.perf_counter() - t)
    return {"pipeline_and_forces_ms": float(np.median(plain) * 1e3),
            "with_drift_tracking_ms": float(np.median(tracked) * 1e3), "frames": len(plain)}


def _plot(out: dict, path) -> None:
    from optitact._optional import require

    require("matplotlib", purpose="bench live --plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    rows = out["rows"]
    rates = sorted({r["fps"] for r in rows})
    names = [c[0] for c in CONFIGS if any(r["config"] == c[0] for r in rows)]
    fig, axes = plt.subplots(1, 3, figsize=(15, 4.4))
    width = 0.8 / max(len(names), 1)
    for j, name in enumerate(names):
        xs = np.arange(len(rates)) + (j - (len(names) - 1) / 2) * width
        med = [next((r["forces_ms_median"] for r in rows if r["fps"] == f and r["config"] == name), np.nan)
               for f in rates]
        p99 = [next((r["forces_ms_p99"] for r in rows if r["fps"] == f and r["config"] == name), np.nan)
               for f in rates]
        axes[0].bar(xs, med, width, label=name)
        axes[0].errorbar(xs, med, yerr=[np.zeros(len(med)), np.subtract(p99, med)], fmt="none", ecolor="k",
                         capsize=2, lw=0.8)
        def pct(key, f, name=name):
            return next((100 * r[key] / r["frames"] for r in rows if r["fps"] == f and r["config"] == name),
                        np.nan)

        start = [pct("dropped_at_start", f) for f in rates]
        after = [pct("dropped_after_start", f) for f in rates]
        bars = axes[1].bar(xs, start, width, label=name)
        axes[1].bar(xs, after, width, bottom=start, color=bars.patches[0].get_facecolor(), hatch="//",
                    edgecolor="k", lw=0.5)
        view = [next((r["viewer_ms_median"] for r in rows if r["fps"] == f and r["config"] == name), None)
                for f in rates]
        if all(v is not None for v in view):
            p99 = [next(r["viewer_ms_p99"] for r in rows if r["fps"] == f and r["config"] == name)
                   for f in rates]
            axes[2].bar(xs, view, width, label=name, color=bars.patches[0].get_facecolor())
            axes[2].errorbar(xs, view, yerr=[np.zeros(len(view)), np.subtract(p99, view)], fmt="none",
                             ecolor="k", capsize=2, lw=0.8)
    for ax, title, unit in ((axes[0], "capture to forces (median, bar to p99)", "ms"),
                            (axes[1], "dropped frames (solid: while the baseline is set up;\n"
                                      "hatched: after it)", "% of frames"),
                            (axes[2], "capture to viewer SDK (median, bar to p99)", "ms")):
        ax.set_xticks(np.arange(len(rates)), [f"{f:g} fps" for f in rates])
        ax.set_title(title)
        ax.set_ylabel(unit)
    axes[0].axhline(out["floor_ms"]["with_drift_tracking_ms"], color="0.4", ls="--", lw=0.8,
                    label="pipeline + forces alone")
    axes[0].legend(fontsize=7)
    fig.suptitle(f"optitact bench live: {out['camera']} frames, {out['seconds']:g} s per run, "
                 f"{out['cores']} cores")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)

