"""Benchmark: ``optitact process`` on a whole video against decoding the video alone.

Not library code: ``optitact bench process`` runs it. The recording is made
once per size and codec and kept in the cache folder: two-stage renders of
the dome (a no-load stretch, then all 41 elements loaded, the load swelling
and easing) exposed by the CCD model with a new noise seed per frame. Each
repeat then runs, in turn, three fresh processes on it: ``optitact process``
(with the shipped calibration where the frames are its camera's, readings
alone elsewhere), the decode loop a user would write (``cv2.VideoCapture``
read and ``cvtColor`` to grey), and the same loop tuned as ``process`` runs
it (OpenCV's worker pool off, one OpenBLAS thread, grey video read as grey
and Motion JPEG as its luma plane): the floor of decoding here. CPU time is
the operating system's accounting of each finished child (user + system),
wall time a monotonic clock around it; the ratios are taken
repeat by repeat and their medians reported, so that a drift of the shared
machine's speed cuts both sides.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from optitact._validate import integer

__all__ = ["CODECS", "DECODE_LOOP", "bench_process", "recording"]

#: Codecs a recording can be written with: FOURCC -> file suffix.
CODECS = {"MJPG": ".avi", "FFV1": ".avi"}

#: The decode-only loop a user would write (``sys.argv[1]``: the video); ``TUNED`` runs it as
#: ``optitact process`` reads frames (OpenCV's worker pool off; OpenBLAS's set by the environment;
#: 8-bit grey video read as grey and Motion JPEG as its luma plane, without the BGR round trip).
DECODE_LOOP = """\
import sys, cv2
tuned = len(sys.argv) > 2
cap = cv2.VideoCapture(sys.argv[1])
if tuned:
    cv2.setNumThreads(1)
    fourcc = int(cap.get(cv2.CAP_PROP_FOURCC)).to_bytes(4, "little")
    pixels = int(cap.get(cv2.CAP_PROP_CODEC_PIXEL_FORMAT)).to_bytes(4, "little")
    if pixels == b"Y800" or (fourcc == b"MJPG" and pixels == b"I420"):
        cv2.utils.logging.setLogLevel(cv2.utils.logging.LOG_LEVEL_ERROR)
        cap.set(cv2.CAP_PROP_CONVERT_RGB, 0)
n = 0
while True:
    ok, frame = cap.read()
    if not ok:
        break
    if frame.ndim == 3:
        grey = cv2.cvtColor(frame, cv2.COLOR_BGR2GRAY)
    n += 1
print(n)
"""

#: Frames at no load that start a recording (process takes the first as its baseline).
NOLOAD_FRAMES = 5


def recording(width: int, height: int, codec: str, *, frames: int, seed: int) -> Path:
    """The benchmark's video of ``frames`` frames, made once and kept in the cache folder.

    The file is written to a temporary name and renamed when complete: an
    interrupted run leaves no half video behind and the next one makes it again.
    """
    import cv2

    from optitact.io.cache import cache_dir
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.ccd import CCD
    from optitact.io.files import atomic_write
    from optitact.render import render
    from optitact.optics.sensor import DomeSensor
    from optitact.studies.bench_render import render_cases

    if codec not in CODECS:
        raise ValueError(f"codec must be one of {sorted(CODECS)}, got {codec!r}")
    name = f"process-{width}x{height}-{codec}-f{frames}-seed{seed}{CODECS[codec]}"
    path = cache_dir() / "bench-videos" / name
    if path.exists():
        return path
    sensor = DomeSensor.default()
    camera = FisheyeCamera(width=width, height=height)
    noload = render(sensor, np.zeros((sensor.n_elements, 3)), camera=camera, transport="two_stage")
    loaded = render(sensor, render_cases(sensor, seed=seed)["41"], camera=camera, transport="two_stage")
    ccd = CCD()

    def write(tmp: Path) -> None:
        out = cv2.VideoWriter(str(tmp), cv2.VideoWriter_fourcc(*codec), 200, (width, height), isColor=False)
        if not out.isOpened():
            raise RuntimeError(f"OpenCV cannot write {codec} video here")
        try:
            for k in range(frames):
                load = 0.0 if k < NOLOAD_FRAMES else 0.3 + 0.7 * np.sin(k / 30.0) ** 2
                out.write(ccd.expose(noload + (loaded - noload) * load, seed=seed + k))
        finally:
            out.release()

    return atomic_write(path, write)


def _run(cmd: list[str], env: dict) -> tuple[float, float]:
    """Wall and CPU seconds (user + system, the OS's accounting of the child) of one run of ``cmd``.

    The child's stderr goes to a file, not a pipe: a full pipe would block a child that prints
    more than the pipe holds while this process waits for it to exit.
    """
    with tempfile.TemporaryFile() as err:
        t = time.perf_counter()
        proc = subprocess.Popen(cmd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        _, status, usage = os.wait4(proc.pid, 0)
        wall = time.perf_counter() - t
        proc.returncode = os.waitstatus_to_exitcode(status)
        if proc.returncode != 0:
            err.seek(0)
            text = err.read().decode(errors="replace").strip()
            raise RuntimeError(f"{' '.join(cmd)} failed ({proc.returncode}): {text[-2000:]}")
    return wall, usage.ru_utime + usage.ru_stime


def _median_row(times: dict, names: tuple) -> dict:
    out = {}
    for name in names:
        wall, cpu = np.median(np.asarray(times[name]), axis=0)
        out[f"{name}_wall_s"], out[f"{name}_cpu_s"] = round(float(wall), 3), round(float(cpu), 3)
    for base in names[1:]:
        for i, kind in enumerate(("wall", "cpu")):
            ratios = [a[i] / b[i] for a, b in zip(times[names[0]], times[base], strict=True)]
            out[f"{kind}_vs_{base}"] = round(float(np.median(ratios)), 3)
    return out


def bench_process(sizes=((640, 480), (1280, 960)), *, codecs=("MJPG",), frames: int = 500, repeats: int = 5,
                  seed: int = 0) -> dict:
    """Time ``optitact process`` on a video against decoding it alone, side by side in each repeat.

    Parameters
    ----------
    sizes : sequence of (width, height)
    codecs : sequence of str
        FOURCCs of :data:`CODECS`.
    frames : int
        Frames per recording (default 500).
    repeats : int
        Timed runs of each command; medians are reported (one untimed warm-up run each first).
    seed : int
        Of the load and the frames' noise.

    Returns
    -------
    dict
        ``rows``: per size and codec, ``process_*``, ``decode_*`` (the user's loop) and
        ``decode_tuned_*`` (the loop as ``process`` reads) medians of wall and CPU seconds,
        and the medians of the per-repeat ratios ``wall_vs_decode``, ``cpu_vs_decode``,
        ``wall_vs_decode_tuned``, ``cpu_vs_decode_tuned``; whether the run had a calibration,
        the rows the table got; and the machine's cores.
    """
    from tqdm import tqdm

    from optitact import cli
    from optitact.calib.shipped import default_calibration
    from optitact.optics.camera import FisheyeCamera
    from optitact.pipeline.fastpath import cores as _cores

    frames = integer(frames, "frames", minimum=NOLOAD_FRAMES + 1)
    repeats = integer(repeats, "repeats", minimum=1)
    shipped = default_calibration().camera
    # the children as a user's shell runs them: bytecode cached (a session may turn caching off),
    # without the OpenBLAS setting this command line made for itself
    env = {k: v for k, v in os.environ.items() if k != "PYTHONDONTWRITEBYTECODE"}
    if cli.BLAS_THREADS_SET:
        env.pop("OPENBLAS_NUM_THREADS", None)
    tuned_env = env | {"OPENBLAS_NUM_THREADS": "1"}
    rows = {}
    names = ("process", "decode", "decode_tuned")
    with tempfile.TemporaryDirectory() as tmp:
        loop = Path(tmp) / "decode.py"
        loop.write_text(DECODE_LOOP)
        jobs = [(w, h, c) for w, h in sizes for c in codecs]
        for w, h, codec in tqdm(jobs, desc="bench process", unit="video", file=sys.stderr):
            video = recording(w, h, codec, frames=frames, seed=seed)
            calibrated = FisheyeCamera(width=w, height=h) == shipped
            out = Path(tmp) / "readings.csv"
            cmds = {"process": [sys.executable, "-m", "optitact", "process", str(video), "--out", str(out)]
                    + (["--calibration", "default"] if calibrated else []),
                    "decode": [sys.executable, str(loop), str(video)],
                    "decode_tuned": [sys.executable, str(loop), str(video), "tuned"]}
            envs = {"process": env, "decode": env, "decode_tuned": tuned_env}
            times = {name: [] for name in names}
            for name in names:
                _run(cmds[name], envs[name])  # warm-up: bytecode written, files in the page cache
            for _ in range(repeats):
                for name in names:
                    times[name].append(_run(cmds[name], envs[name]))
            with out.open() as fh:
                n_rows = sum(1 for _ in fh) - 1
            rows[f"{w}x{h}-{codec}"] = {"frames": frames, "calibration": "default" if calibrated else None,
                                        "table_rows": n_rows, **_median_row(times, names)}
    return {"frames": frames, "repeats": repeats, "cores": _cores(), "rows": rows}
