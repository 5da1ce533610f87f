"""Batch processing: frame files (images, folders, ``.npy`` stacks, videos) to a readings table.

:func:`process_files` reads every frame of the sources in order, turns them
into readings with a :class:`~optitact.pipeline.frame_pipeline.Pipeline` (and into forces with a
calibration), and returns the table or writes it as CSV
(:class:`~optitact.io.tables.ReadingsWriter`), or as Parquet for a name ending in
``.parquet``. ``optitact process`` is this function
behind a command line; it runs here, or on a Dask cluster with one task per
file (the same table either way).

Examples
--------
>>> import numpy as np, optitact
>>> from optitact.pipeline.batch import process_files
>>> cam = optitact.optics.camera.FisheyeCamera(width=80, height=60)
>>> pipe = optitact.pipeline.frame_pipeline.Pipeline(optitact.optics.sensor.DomeSensor.default(), cam)
>>> import tempfile, pathlib
>>> folder = pathlib.Path(tempfile.mkdtemp())
>>> np.save(folder / "rec.npy", np.zeros((3, 60, 80), np.uint8))
>>> table = process_files([folder / "rec.npy"], pipeline=pipe)
>>> table.n_frames, table.readings.G.shape
(3, (3, 41))
"""

from __future__ import annotations

import itertools
import os
import sys
import time
from collections.abc import Iterable, Sequence
from contextlib import closing, contextmanager, nullcontext
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from optitact.pipeline import kernel as _kernel
from optitact._validate import integer
from optitact.errors import InputError, OptitactError
from optitact.io.frames import (ReadAhead, count_frames, expand_sources, iter_frames, read_ahead,
                                read_ahead_depth)
from optitact.io.tables import ReadingsWriter, refuse_overwriting_inputs, table_files
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.baseline import take_baseline
from optitact.pipeline.readings import Readings
from optitact.pipeline.imageops import check_frames

__all__ = ["SHORT_RUN_PIXELS", "ProcessedFrames", "process_files"]

#: A run of fewer frames x pixels than this takes the NumPy kernel when the compiled one is not
#: loaded yet (``kernel="auto"``): loading numba and its cached kernel (numba imports SciPy's
#: BLAS) costs more CPU than the compiled kernel saves over NumPy on a run this short, even with
#: every element loaded (figures: docs/results/pipeline.md). The readings are the same bit for bit.
SHORT_RUN_PIXELS = 1e9

#: While :func:`process_files` decodes ahead, the interpreter's switch interval is at most this (s).
#: The decoding thread needs the GIL back after every frame OpenCV decodes; at the default (5 ms)
#: it waits for it while this thread runs Python, and decodes slower than alone (figures:
#: docs/results/pipeline.md).
SWITCH_INTERVAL = 2e-4


#: :func:`process_files`' progress bar appears once the run has taken this long (s). Until then
#: tqdm is not even imported: its import (its version from ``importlib.metadata``) would hold up
#: the thread that reads the frames for a noticeable part of a short run.
PROGRESS_DELAY = 0.5


class _Progress:
    """tqdm's progress bar on stderr, made (and tqdm imported) once the work has taken ``delay`` seconds.

    Counts what :meth:`update` is given from the start, so the bar, once shown, tells the
    frames done and the rate since the run began, as one made at the start would.
    """

    def __init__(self, total: int, *, desc: str, unit: str = "frame", disable: bool = False,
                 delay: float = PROGRESS_DELAY) -> None:
        self._options = {"total": total, "desc": desc, "unit": unit, "file": sys.stderr}
        self._off, self._delay = disable, delay
        self._t0 = time.perf_counter()
        self.n = 0
        self._bar = None

    def update(self, n: int) -> None:
        self.n += n
        if self._bar is not None:
            self._bar.update(n)
        elif not self._off and time.perf_counter() - self._t0 >= self._delay:
            from tqdm import tqdm

            bar = tqdm(**self._options)
            # backdate the bar (made just now, start_t its clock's now) to when the work began
            bar.start_t = bar.last_print_t = bar.start_t - (time.perf_counter() - self._t0)
            bar.update(self.n)
            self._bar = bar

    def close(self) -> None:
        if self._bar is not None:
            self._bar.close()

    def __enter__(self) -> _Progress:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


@contextmanager
def _switch_interval(seconds: float | None):
    """The interpreter's thread switch interval at most ``seconds`` within the block (None: unchanged)."""
    old = sys.getswitchinterval()
    if seconds is None or seconds >= old:
        yield
        return
    sys.setswitchinterval(seconds)
    try:
        yield
    finally:
        sys.setswitchinterval(old)


@dataclass(frozen=True, eq=False)
class ProcessedFrames:
    """What :func:`process_files` returns.

    Attributes
    ----------
    n_frames : int
        Frames processed.
    sources : list of str
        The source of each frame (file, or ``file[k]`` for a frame of a stack
        or video), as in the CSV's ``source`` column.
    readings : Readings or None
        ``(n_frames, E)`` readings; None when the table was written to ``out``.
    forces : (n_frames, E, 3) ndarray or None
        Element-local forces (N) with a calibration, when not written to ``out``.
    clamped : (n_frames, E) bool ndarray or None
        Readings outside the calibration's fitted range (likewise; see
        :meth:`optitact.calib.fit.Calibration.forces`).
    last_frame : (H, W) ndarray
        The last frame (e.g. to plot its force field).
    last_readings : Readings
        Its readings ``(E,)``.
    seconds : float
        Wall time, reading the files included.
    global_forces : (n_frames, E, 3) ndarray or None
        With a calibration, when not written to ``out``: the forces on the
        elements in the sensor frame (N), as
        :attr:`optitact.forces.ForceField.global_forces`.
    resultant : (n_frames, 3) ndarray or None
        Likewise: per frame, the sum of the global forces over contact
        elements (N).
    total_normal : (n_frames,) ndarray or None
        Likewise: per frame, the sum of Fz over contact elements (N).
    centre_of_pressure : (n_frames, 3) ndarray or None
        Likewise: per frame, the centre of pressure on the outer surface (mm;
        NaN where no element carries a normal force).
    stderr : (n_frames, E, 3) ndarray or None
        With ``noise``: the standard errors of the element-local forces (N,
        :meth:`optitact.calib.fit.Calibration.stderr`).
    """

    n_frames: int
    sources: list
    readings: Readings | None
    forces: np.ndarray | None
    clamped: np.ndarray | None
    last_frame: np.ndarray
    last_readings: Readings
    seconds: float
    global_forces: np.ndarray | None = None
    stderr: np.ndarray | None = None
    resultant: np.ndarray | None = None
    total_normal: np.ndarray | None = None
    centre_of_pressure: np.ndarray | None = None


class _Table:
    """The in-memory counterpart of :class:`~optitact.io.tables.ReadingsWriter` (same ``write``)."""

    def __init__(self, *, forces: bool, sensor=None) -> None:
        self.with_forces, self.sensor, self.frames = forces, sensor, 0
        self.parts: list = []

    def write(self, readings, sources, forces=None, clamped=None, stderr=None) -> None:
        self.parts.append((readings, forces, clamped, stderr))
        self.frames += len(sources)

    def __enter__(self) -> _Table:
        return self

    def __exit__(self, *exc) -> None:
        pass

    def result(self) -> dict:
        """The fields of :class:`ProcessedFrames` that hold the table."""
        r = Readings.stack([p[0] for p in self.parts])
        if not self.with_forces:
            return {"readings": r, "forces": None, "clamped": None}
        from optitact.optics.force_frames import frame_totals

        forces = np.concatenate([p[1] for p in self.parts])
        tot = frame_totals(self.sensor, forces, r.contact)
        se = np.concatenate([p[3] for p in self.parts]) if self.parts[0][3] is not None else None
        return {"readings": r, "forces": forces, "clamped": np.concatenate([p[2] for p in self.parts]),
                "stderr": se,
                "global_forces": tot["global"], "resultant": tot["resultant"],
                "total_normal": tot["total_normal"], "centre_of_pressure": tot["centre_of_pressure"]}


def frame_label(name: str) -> str:
    """A frame's source as the messages name it: ``"rec.npy#50"`` -> ``"rec.npy, frame 50"``.

    Frames of a stack or video are counted from 0 within their file.
    """
    file, sep, k = name.rpartition("#")
    return f"{file}, frame {k}" if sep and k.isdigit() else name


def _check_shape(name: str, frame: np.ndarray, shape: tuple[int, int]) -> None:
    if frame.shape != shape:
        raise InputError(f"{frame_label(name)}: expected a {shape[0]}x{shape[1]} frame for this camera, "
                         f"got {frame.shape}")


def _name_the_frame(pipe: Pipeline, names: Sequence[str], frames) -> None:
    """Raise the error of the first frame that the pipeline refuses, naming its file and index there.

    Called when a batch failed: the batch's own message counts frames within
    the batch. Returns (and the caller re-raises its error) when no single
    frame is at fault.
    """
    for name, frame in zip(names, frames, strict=True):
        try:
            check_frames(frame, pipe.camera, "the frame")
        except (OptitactError, TypeError, ValueError) as exc:
            msg = str(exc).replace(" at frame 0, pixel", " at pixel")
            raise type(exc)(f"{frame_label(name)}: {msg}") from None


def _batches(pairs: Iterable, shape: tuple[int, int], batch: int, *, reuse: bool = False):
    """``(names, stack)`` of up to ``batch`` frames at a time from ``(name, frame)`` pairs.

    With ``reuse``, every stack of frames of one dtype is the same buffer, overwritten by the
    next batch: a batch of large frames is not mapped and faulted in afresh each time (39 MB
    of 1280x960 frames at 32 a batch, a sixth of a second per 500 frames).
    """
    held: list = []
    buffer = None

    def stacked():
        nonlocal buffer
        frames = [f for _, f in held]
        dtype = frames[0].dtype
        if not reuse or any(f.dtype != dtype for f in frames):
            return np.stack(frames)
        if buffer is None or buffer.dtype != dtype:
            buffer = np.empty((batch, *shape), dtype)
        return np.stack(frames, out=buffer[:len(frames)])

    for name, frame in pairs:
        _check_shape(name, frame, shape)
        held.append((name, frame))
        if len(held) >= batch:
            yield [n for n, _ in held], stacked()
            held = []
    if held:
        yield [n for n, _ in held], stacked()


def _read(pipe: Pipeline, cal, names: list, stack: np.ndarray, noise=None) -> tuple:
    """``(names, readings, forces, clamped, last frame, stderr)`` of one batch.

    Forces are None without ``cal``, stderr None without ``noise``.
    """
    try:
        r = pipe.process(stack)
    except (OptitactError, TypeError, ValueError):
        _name_the_frame(pipe, names, stack)
        raise
    forces, clamped = cal.forces(r) if cal is not None else (None, None)
    se = None
    if noise is not None:
        from optitact.pipeline.uncertainty import reading_errors

        se = cal.stderr(r, None if noise == "model" else reading_errors(pipe, stack, noise, r), forces=forces)
    return names, r, forces, clamped, stack[-1], se


def _read_file(pipe: Pipeline, cal, path, batch: int, noise=None) -> list:
    """Every batch of one file: a task of :func:`process_files` on a cluster."""
    return [_read(pipe, cal, names, stack, noise)
            for names, stack in _batches(iter_frames([path]), pipe.camera.shape, batch)]


def process_files(sources: Sequence[str | os.PathLike], *, pipeline: Pipeline | None = None,
                  calibration=None, baseline=None, baseline_frames: int = 1,
                  out: str | os.PathLike | None = None, batch: int = 32, scheduler=None,
                  progress: bool = False, noise=None, frames: ReadAhead | None = None) -> ProcessedFrames:
    """Readings (and forces) of every frame in image files, folders, ``.npy`` stacks or videos.

    Parameters
    ----------
    sources : sequence of path-like
        Files and folders (a folder is its sorted frame files), read in order;
        see :func:`optitact.io.frames.expand_sources`.
    pipeline : Pipeline, optional
        Turns frames into readings; default ``calibration.pipeline()``.
    calibration : Calibration, optional
        Also estimate forces: the element-local ``fx, fy, fz``, the global
        ``fx_global, fy_global, fz_global`` and ``clamped`` of every element,
        and per frame the resultant, total normal force and centre of
        pressure (see :class:`~optitact.io.tables.ReadingsWriter`).
    baseline : (H, W) or (T, H, W) array_like, optional
        No-load frame(s) to use as the pipeline's baseline.
    baseline_frames : int
        When neither ``baseline`` nor the pipeline holds a baseline, the mean
        of the first ``baseline_frames`` frames becomes it (default 1: the
        recording starts unloaded; 0 subtracts nothing). Those frames are
        processed too. At least one frame must follow them: input that would
        be all baseline has nothing to measure and is an error.
    out : path-like, optional
        Write the table as CSV here instead of keeping it in memory (with a
        calibration also ``NAME.per_frame.csv`` beside it, one row per frame);
        a name ending in ``.parquet`` writes Parquet tables instead (the
        ``columnar`` extra: the same columns, written in row groups as frames
        come, read by ``pandas.read_parquet``).
        The files appear when the run is complete (a temporary file is
        renamed), so an existing ``out`` is never replaced by a partial table;
        if the run fails, the rows of the frames done so far are kept as
        ``NAME.partial.csv``, ending on a whole frame, and the error says so;
        a second run writing the same ``out`` meanwhile is refused, and a
        complete run removes the hidden partial files that killed runs of
        ``out`` left (see :class:`~optitact.io.tables.ReadingsWriter`).
    batch : int
        Frames processed together (default 32); the results do not depend on it.
        Here (without a scheduler) a background thread decodes the next frames
        (:func:`~optitact.io.frames.read_ahead`) while a batch is processed, and a
        pipeline made without ``threads`` splits its batches across one core fewer.
    scheduler : str or distributed.Client, optional
        Process on a Dask cluster, one task per file (needs the ``dask``
        extra); the table is the same as a local run's.
    progress : bool
        Show a progress bar on stderr (once the run has taken :data:`PROGRESS_DELAY` seconds).
    noise : PixelNoise or "model", optional
        With a calibration: also the standard error of every force
        (:meth:`optitact.calib.fit.Calibration.stderr`), written as ``fx_se,
        fy_se, fz_se`` after the force columns: a
        :class:`~optitact.pipeline.uncertainty.PixelNoise` propagates each frame's
        shot and read noise and adds the calibration's model error;
        ``"model"`` gives the model error alone.
    frames : ReadAhead, optional
        The frames of ``sources``, already being decoded: a
        :func:`~optitact.io.frames.read_ahead` of
        :func:`~optitact.io.frames.iter_frames` that the caller started before
        building the pipeline (``optitact process`` does), so that decoding
        overlaps the set-up. Read instead of opening ``sources`` again (which
        still name the files and count the frames), and closed when the run
        ends, however it ends.
        Default: read ``sources`` here.

    Returns
    -------
    ProcessedFrames

    Raises
    ------
    FileNotFoundError, InputError, ShapeError, KindError
        A missing or unreadable source, no frames, a frame of the wrong size
        or kind or with NaN (the message names its file, and its index within
        the file counted from 0 for a stack or video: ``rec.npy, frame 50``),
        fewer frames than ``baseline_frames`` or none after them, ``out``
        naming a folder, ``out`` (or its per-frame or partial table) being
        one of the input files, another run writing ``out`` (the message
        names its process id).
    TypeError
        Neither a pipeline nor a calibration, or objects of the wrong kind.
    """
    with closing(frames) if frames is not None else nullcontext():  # closed however the run ends
        if frames is not None and scheduler is not None:
            raise InputError("frames are decoded here: a run with a scheduler reads its files on the cluster")
        return _process_files(sources, pipeline, calibration, baseline, baseline_frames, out, batch, scheduler,
                              progress, noise, frames)


def _process_files(sources, pipeline, calibration, baseline, baseline_frames, out, batch, scheduler, progress,
                   noise, frames) -> ProcessedFrames:
    if pipeline is None and calibration is None:
        raise TypeError("process_files needs a pipeline or a calibration")
    pipe = calibration.pipeline() if pipeline is None else pipeline
    if not isinstance(pipe, Pipeline):
        raise TypeError(f"pipeline must be a Pipeline, got {type(pipe).__name__}")
    batch = integer(batch, "batch", minimum=1)
    n_base = integer(baseline_frames, "baseline_frames", minimum=0)
    if out is not None and Path(out).is_dir():
        raise InputError(f"out: {out} is a folder; expected the name of the CSV file to write "
                         f"(e.g. {Path(out) / 'readings.csv'})")
    files = expand_sources(sources)
    if out is not None:
        refuse_overwriting_inputs({f"out's {k}" if k != "table" else "out": v
                                   for k, v in table_files(out, forces=calibration is not None).items()}, files)
    t0 = time.perf_counter()
    if baseline is not None:
        pipe, n_base = pipe.with_baseline(baseline), 0
    elif pipe.baseline is not None:
        n_base = 0
    with_forces = calibration is not None
    if noise is not None:
        from optitact.pipeline.uncertainty import PixelNoise

        if not with_forces:
            raise InputError("noise gives the forces' standard errors: it needs a calibration")
        if not (isinstance(noise, PixelNoise) or (isinstance(noise, str) and noise == "model")):
            raise TypeError(f"noise must be a PixelNoise or 'model', got {type(noise).__name__}")
    sensor = calibration.sensor if with_forces else None
    sink = (ReadingsWriter(out, forces=with_forces, sensor=sensor, stderr=noise is not None) if out is not None
            else _Table(forces=with_forces, sensor=sensor))
    names: list[str] = []
    last = None
    n_frames = count_frames(files)
    if (pipe.kernel == "numba" and pipe.requested_kernel == "auto" and not _kernel.loaded()
            and n_frames * pipe.camera.shape[0] * pipe.camera.shape[1] < SHORT_RUN_PIXELS):
        pipe = pipe.replace(kernel="numpy")
    if scheduler is None:  # decode the next frames while these are processed
        if pipe.requested_threads is None and pipe.threads > 1:  # a core is the decoder's
            pipe = pipe.replace(threads=pipe.threads - 1)
        if frames is None:
            frames = read_ahead(iter_frames(files), depth=read_ahead_depth(pipe.camera.shape, batch))
    else:
        frames = iter_frames(files)
    with sink, closing(frames), _switch_interval(SWITCH_INTERVAL if scheduler is None else None), \
            _Progress(n_frames, desc="process", disable=not progress) as bar:
        base, head, pairs = take_baseline(frames, n_base, frame=lambda item: item[1])
        if base is not None:
            for name, frame in head:
                _check_shape(name, frame, pipe.camera.shape)
            try:
                pipe = pipe.with_baseline(base)
            except (OptitactError, TypeError, ValueError):
                _name_the_frame(pipe, [n for n, _ in head], [f for _, f in head])
                raise
            following = next(pairs, None)
            if following is None:
                raise InputError(
                    f"all {len(head)} frame(s) of the input would become the no-load baseline "
                    f"(baseline_frames={n_base}), so no frame is left to measure: pass a no-load "
                    f"frame as the baseline (--baseline), record more frames after the no-load ones, or "
                    f"set baseline_frames=0 (--baseline-frames 0) to subtract nothing")
            pairs = itertools.chain([following], pairs)
        for part in _results(pipe, calibration, files, head, pairs, batch, scheduler, noise):
            part_names, r, forces, clamped, _, se = part
            if calibration is None:
                sink.write(r, part_names)
            else:
                sink.write(r, part_names, forces, clamped, se)
            names += part_names
            last = part
            bar.update(len(part_names))
        if last is None:
            raise InputError("the frames hold no frame")
    table = sink.result() if out is None else {"readings": None, "forces": None, "clamped": None}
    last_frame = last[4].copy()  # out of the batch buffer (reused by every batch, and a batch long)
    return ProcessedFrames(n_frames=len(names), sources=names, last_frame=last_frame, last_readings=last[1][-1],
                           seconds=time.perf_counter() - t0, **table)


def _results(pipe, cal, files, head, rest, batch, scheduler, noise=None):
    """Batches ``(names, readings, forces, clamped, last, stderr)`` in frame order, here or on a cluster."""
    if scheduler is None:
        if head:
            yield _read(pipe, cal, [n for n, _ in head], np.stack([f for _, f in head]), noise)
        for names, stack in _batches(rest, pipe.camera.shape, batch, reuse=True):
            yield _read(pipe, cal, names, stack, noise)
        return
    from optitact.dask_client import dask_client

    with dask_client(scheduler, purpose="batch processing on a cluster") as client:
        [p] = client.scatter([pipe], broadcast=True, hash=False)
        futures = [client.submit(_read_file, p, cal, f, batch, noise, retries=3, pure=False) for f in files]
        for fut in futures:  # in file order: the table is the same as a local run's
            yield from fut.result()

