"""Synthetic calibration sets: a load design, rendered frames and their readings in a Zarr store.

A set is a Zarr group whose attributes hold everything that made it (sensor,
camera, CCD, render settings, spp, seed, design, pipeline options, library
version) and whose arrays hold, per frame, the true forces, the frame's seed,
the readings and a ``done`` flag (plus the frames with ``keep_frames``).
Every array is chunked one frame per chunk and Zarr writes chunks atomically
(temporary file, then rename); ``done[i]`` is written last, so a run killed
at any moment leaves only whole frames marked done, and running the same
command again renders the missing ones -- with their own seeds, so the set is
identical to an uninterrupted run. A store killed before its attributes were
written (no finished frame; only the store's own file names in the folder) is
rebuilt by the same command, an empty folder is a new store, and a folder
holding anything else is never deleted. Zarr's ``*.partial`` temporary files
left by a kill are removed on the next run. While :func:`generate` writes it
holds an OS lock on the store (``.optitact-lock`` inside it, naming the
holder): a second writer is refused at once. That housekeeping of the store
(its lock, a half-made store, stray partial files) is in
:mod:`optitact.calib.store`.
"""

from __future__ import annotations

import hashlib
import os
import sys
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from optitact._optional import require
from optitact._validate import integer, positive, seed_value
from optitact.optics.camera import FisheyeCamera, camera_from_dict
from optitact.optics.ccd import CCD
from optitact.errors import InputError
from optitact.io.files import json_fingerprint
from optitact.pipeline.readings import Readings
from optitact.optics.sensor import DomeSensor

from optitact.calib.store import open_store, remove_partials, store_lock
from optitact.calib.document import STACK_NOISE_UNNAMED
from optitact.calib.patterns import PATTERNS, design_forces

__all__ = ["SCHEMA", "Design", "CalibrationSet", "FrameMaker", "frame_seeds", "generate", "RENDER_MODES"]

#: How :func:`generate` renders its frames (see its ``render_mode``).
RENDER_MODES = ("two_stage", "pixels", "full")
#: :func:`store_lock` under the name it had here (a process that holds a store's lock imports it).
_store_lock = store_lock

SCHEMA = "optitact.calibration-set"
SCHEMA_VERSION = 1


@dataclass(frozen=True)
class Design:
    """The load design of a calibration set (N, and fractions of frames).

    Parameters
    ----------
    fz_max : float
        Largest normal force per element (N), default 1.0; normal forces are
        drawn in ``[0, fz_max]``.
    shear_max : float
        Largest shear magnitude per element (N), default 0.5.
    mu_max : float
        Largest shear-to-normal ratio, default 0.35 (the contact model's
        feeler tips over at about 0.37-0.40, beyond which the centroid no
        longer tells the shear).
    sweep_fraction : float
        Fraction of frames given to the pure-normal and pure-shear sweeps
        (half each), default 0.2; the rest is a scrambled Sobol design.
    pattern : str
        How loads are spread over the elements (:mod:`optitact.calib.patterns`):
        ``"independent"`` (default: every element its own random load, with
        the sweeps), ``"uniform"``, ``"single"``, ``"clustered"``,
        ``"checkerboard"``, ``"shear"``, or ``"blend"`` (all of them in turn).
    """

    fz_max: float = 1.0
    shear_max: float = 0.5
    mu_max: float = 0.35
    sweep_fraction: float = 0.2
    pattern: str = "independent"

    def __post_init__(self) -> None:
        for name in ("fz_max", "shear_max", "mu_max"):
            object.__setattr__(self, name, positive(getattr(self, name), name))
        frac = positive(self.sweep_fraction, "sweep_fraction", allow_zero=True)
        if frac > 1:
            raise InputError(f"sweep_fraction must be in [0, 1], got {frac}")
        object.__setattr__(self, "sweep_fraction", frac)
        if self.pattern not in PATTERNS:
            raise InputError(f"pattern must be one of {PATTERNS}, got {self.pattern!r}")

    def to_dict(self) -> dict:
        """JSON-friendly parameters (``pattern`` only when not the classic ``"independent"``)."""
        out = {"fz_max": self.fz_max, "shear_max": self.shear_max, "mu_max": self.mu_max,
               "sweep_fraction": self.sweep_fraction}
        if self.pattern != "independent":
            out["pattern"] = self.pattern
        return out


def frame_seeds(seed: int, n_frames: int) -> np.ndarray:
    """Per-frame seeds (uint32) of the renders and the camera noise."""
    return np.random.SeedSequence([seed, 2]).generate_state(n_frames).astype(np.uint32)


def _frame_dtype(ccd: CCD) -> str:
    return "u1" if ccd.bits == 8 else "u2"


def _set_attrs(*, sensor, camera, ccd, design, spp, seed, n_frames, keep_frames, settings,
               pipeline_options, baseline_frames, render_mode) -> dict:
    from optitact import __version__

    return {"schema": SCHEMA, "schema_version": SCHEMA_VERSION, "library_version": __version__,
            "frames": n_frames, "seed": seed, "spp": spp, "keep_frames": keep_frames,
            "baseline_frames": baseline_frames, "render_mode": render_mode,
            "sensor": sensor.to_dict(), "camera": camera.to_dict(), "ccd": ccd.to_dict(),
            "design": design.to_dict(), "render_settings": settings,
            "pipeline": pipeline_options}


class CalibrationSet:
    """A calibration set on disk (read side).

    Attributes
    ----------
    path : Path
    attrs : dict
        What made the set (see the module docstring).
    sensor, camera, ccd
        The set's models.
    """

    def __init__(self, path: str | os.PathLike) -> None:
        zarr = require("zarr", purpose="calibration sets")

        self.path = Path(path)
        if not self.path.exists():
            raise FileNotFoundError(f"calibration set not found: {self.path}")
        try:
            self._group = zarr.open_group(str(self.path), mode="r")
        except Exception as exc:  # zarr raises several kinds for a non-store
            raise InputError(f"{self.path} is not a Zarr calibration set ({exc})") from None
        self.attrs = dict(self._group.attrs)
        if self.attrs.get("schema") != SCHEMA:
            raise InputError(f"{self.path} is not an optitact calibration set "
                             f"(schema {self.attrs.get('schema')!r})")
        if self.attrs.get("schema_version") != SCHEMA_VERSION:
            raise InputError(f"{self.path}: calibration-set schema version "
                             f"{self.attrs.get('schema_version')!r}; this optitact reads {SCHEMA_VERSION}")
        missing = [k for k in ("frames", "seed", "spp", "sensor", "camera", "ccd", "design")
                   if k not in self.attrs]
        if missing:
            raise InputError(f"{self.path} is an incomplete calibration set (missing "
                             f"{', '.join(missing)}); run its generate command again")
        self.sensor = DomeSensor.from_dict(self.attrs["sensor"])
        self.camera = camera_from_dict(self.attrs["camera"])
        self.ccd = CCD.from_dict(self.attrs["ccd"])

    def __len__(self) -> int:
        return int(self.attrs["frames"])

    @property
    def done(self) -> np.ndarray:
        """(frames,) bool: frames rendered and read."""
        return np.asarray(self._group["done"][:], dtype=bool)

    @property
    def complete(self) -> bool:
        """All frames are done."""
        return bool(self.done.all())

    def has_array(self, name: str) -> bool:
        """Whether the set holds the array ``name`` (:meth:`array`; ``frames`` only with ``keep_frames``)."""
        return name in self._group

    def array(self, name: str) -> np.ndarray:
        """A whole array of the set.

        Names: ``forces``, ``seeds``, ``G``, ``u``, ``contact``, ``saturated``,
        ``done``, ``baseline`` (the no-load frames), ``baseline_radiance``
        (their renders) and (with ``keep_frames``) ``frames``.
        """
        if name not in self._group:
            raise KeyError(f"{self.path} has no array {name!r}")
        return np.asarray(self._group[name][:])

    def readings(self) -> Readings:
        """Readings of the done frames, ``(T_done, E)``."""
        d = self.done
        return Readings(self.array("G")[d], self.array("u")[d], self.array("contact")[d],
                        self.array("saturated")[d])

    def forces(self) -> np.ndarray:
        """True element-local forces of the done frames, ``(T_done, E, 3)``."""
        return self.array("forces")[self.done]


@dataclass(frozen=True, eq=False)
class FrameMaker:
    """Everything one calibration frame needs, as one picklable callable (a task on a cluster).

    ``maker(forces, seed)`` renders the frame (``render_mode``), exposes it
    and reads it with the set's pipeline; returns ``G``, ``u``, ``contact``,
    ``saturated`` and, with ``keep_frames``, ``frame``. The pipeline is built
    once per process.
    """

    sensor: DomeSensor
    camera: FisheyeCamera
    ccd: CCD
    pipeline_options: dict
    baseline: np.ndarray
    background: np.ndarray
    render_mode: str
    spp: int
    variant: str | None
    table: object
    keep_frames: bool

    def pipeline(self):
        """The set's pipeline, built on first use in this process."""
        pipe = self.__dict__.get("_pipe")
        if pipe is None:
            from optitact.pipeline.frame_pipeline import Pipeline

            options = {"stack_noise": STACK_NOISE_UNNAMED} | self.pipeline_options  # older sets name none
            pipe = Pipeline(self.sensor, self.camera, baseline=self.baseline, **options)
            self.__dict__["_pipe"] = pipe
        return pipe

    def __getstate__(self):
        return {k: v for k, v in self.__dict__.items() if k != "_pipe"}

    def __setstate__(self, state):
        self.__dict__.update(state)

    def __call__(self, forces, seed: int) -> dict:
        """Render, expose and read one frame of element-local ``forces`` with ``seed``."""
        from optitact.render import render
        from optitact.render.pathtrace import spot_pixels

        f = np.asarray(forces, dtype=np.float64)
        if self.render_mode == "two_stage":
            radiance = render(self.sensor, f, camera=self.camera, transport="two_stage", table=self.table,
                              background=self.background)
        elif self.render_mode == "pixels":
            radiance = render(self.sensor, f, camera=self.camera, spp=self.spp, seed=seed,
                              variant=self.variant, pixels=spot_pixels(self.sensor, self.camera, f),
                              background=self.background)
        else:
            radiance = render(self.sensor, f, camera=self.camera, spp=self.spp, seed=seed,
                              variant=self.variant)
        frame = self.ccd.expose(radiance, seed=seed)
        r = self.pipeline().process(frame)
        out = {"G": r.G, "u": r.u, "contact": r.contact, "saturated": r.saturated}
        if self.keep_frames:
            out["frame"] = frame
        return out


def _make_frame(maker: FrameMaker, forces, seed: int) -> dict:
    return maker(forces, seed)


def _distributed(scheduler, maker: FrameMaker, todo, forces, seeds, token: str):
    """Run frames on a Dask cluster; yield ``(index, readings)`` as they finish."""
    from optitact.dask_client import dask_client

    as_completed = require("distributed", purpose="calibration sets on a cluster").as_completed
    with dask_client(scheduler, purpose="calibration sets on a cluster") as client:
        [remote] = client.scatter([maker], broadcast=True, hash=False)
        tag = hashlib.sha256(token.encode()).hexdigest()[:12]
        futures = {client.submit(_make_frame, remote, forces[i], int(seeds[i]), key=f"optitact-frame-{tag}-{i}",
                                 retries=3, pure=False): int(i) for i in todo}
        for fut in as_completed(futures):
            yield futures[fut], fut.result()


def generate(path: str | os.PathLike, *, frames: int = 200, sensor: DomeSensor | None = None,
             camera: FisheyeCamera | None = None, ccd: CCD | None = None, spp: int = 64,
             seed: int = 0, design: Design | None = None, keep_frames: bool = False,
             variant: str | None = None, pipeline_options: dict | None = None,
             baseline_frames: int = 4, render_mode: str = "two_stage", table=None,
             table_spp: int | None = None, scheduler=None, progress: bool = True) -> CalibrationSet:
    """Create or finish a synthetic calibration set (resumable).

    Parameters
    ----------
    path : path-like
        The Zarr store (a folder). If it exists it must have been started by
        the same call (same parameters); its missing frames are then made.
    frames : int
        Frames in the set; each loads all elements, so it gives E samples.
    sensor, camera, ccd : optional
        Defaults: ``DomeSensor.default()``, ``FisheyeCamera()``, ``CCD()``.
    spp : int
        Samples per pixel of each render.
    seed : int
        Seed of the design, the no-load baseline and every frame.
    design : Design, optional
        Load ranges and the share of sweeps.
    keep_frames : bool
        Also store the camera frames.
    variant : str, optional
        Mitsuba variant (not part of the set's identity).
    pipeline_options : dict, optional
        Options of :class:`optitact.pipeline.frame_pipeline.Pipeline` that read the frames.
    baseline_frames : int
        No-load frames rendered for the baseline (default 4): their mean is
        subtracted and their per-pixel noise sets the threshold (the faint
        guided light of the background carries Monte Carlo noise of its own).
    render_mode : {"two_stage", "pixels", "full"}
        ``"two_stage"`` (default): the two-stage light transport
        (:mod:`optitact.render.twostage`; ``spp`` then applies to the no-load
        baseline frames only), a few hundredths of a second per frame with no
        Monte Carlo noise; ``"pixels"``: path-traced, only the pixels the
        pipeline reads for the loaded elements
        (:func:`optitact.render.pathtrace.spot_pixels`), composited over the mean
        no-load radiance; ``"full"``: path-traced whole frames. ``optitact
        bench render`` measures each against converged path tracing.
    table : EmissionTable, optional
        ``"two_stage"`` only: the stage-1 table. Default: the one shipped with
        the package for the default sensor and camera (nothing to measure),
        else the cached one for this sensor and camera, measured on first use
        at ``table_spp`` (a one-time step of many minutes, announced on stderr
        with an estimate; see :func:`optitact.render.emission.emission_table`).
    table_spp : int, optional
        Samples per pixel of that measurement (default: the shipped table's,
        else ``TABLE_SPP`` = 4096); fewer is faster and noisier.
    scheduler : str or distributed.Client, optional
        Run the frames on a Dask distributed cluster: a scheduler address
        (``"tcp://host:8786"``) or a ``Client``. Each frame is one task that
        carries its own seed, so the set is identical to a local one; a task
        whose worker dies is retried elsewhere, and only this process writes
        the store (readings, then the frame's ``done`` flag), so killed
        workers lose or duplicate nothing. Without it the frames run here,
        one after another.
    progress : bool
        Show a progress bar (frames/s, ETA) on stderr.

    Returns
    -------
    CalibrationSet

    Raises
    ------
    InputError
        If ``path`` holds a set made with other parameters.
    """
    zarr = require("zarr", purpose="calibration sets")

    from optitact.pipeline.frame_pipeline import Pipeline
    from optitact.render.scene import RenderSettings

    frames = integer(frames, "frames", minimum=1)
    spp = integer(spp, "spp", minimum=1)
    baseline_frames = integer(baseline_frames, "baseline_frames", minimum=1)
    if render_mode not in RENDER_MODES:
        raise InputError(f"render_mode must be one of {RENDER_MODES}, got {render_mode!r}")
    if table is not None and render_mode != "two_stage":
        raise InputError("table is for render_mode='two_stage'")
    if table_spp is not None and (table is not None or render_mode != "two_stage"):
        raise InputError("table_spp is for render_mode='two_stage' without a table")
    if scheduler is not None and not isinstance(scheduler, str) and \
            type(scheduler).__name__ != "Client":
        raise TypeError(f"scheduler must be an address string or a distributed.Client, got "
                        f"{type(scheduler).__name__}")
    seed = seed_value(seed)
    if seed is None:
        raise InputError("a calibration set needs an integer seed (it is how frames resume)")
    sensor = sensor or DomeSensor.default()
    camera = camera or FisheyeCamera()
    ccd = ccd or CCD()
    design = design or Design()
    options = dict(pipeline_options or {})
    check = Pipeline(sensor, camera, **options)  # validate the options before any work
    # the region geometry as used, so the readings stay interpretable if defaults change
    options |= {"radius": check.grids.radius, "grid_mm": check.grids.grid_mm, "stack_noise": check.stack_noise}
    attrs = _set_attrs(sensor=sensor, camera=camera, ccd=ccd, design=design, spp=spp, seed=seed,
                       n_frames=frames, keep_frames=bool(keep_frames),
                       settings=asdict(RenderSettings()), pipeline_options=options,
                       baseline_frames=baseline_frames, render_mode=render_mode)
    if render_mode == "two_stage":
        from optitact.render.emission import emission_table, shipped_table

        # The table belongs to the patches, not the camera: the shipped one serves every camera; else it
        # is measured through this camera if it is an on-axis fisheye (small ones measure fast), else the
        # default camera.
        if table is None and table_spp is None:
            table = shipped_table(sensor)
        if table is None:
            measuring = camera if isinstance(camera, FisheyeCamera) else None
            table = emission_table(sensor, measuring, variant=variant, spp=table_spp, progress=progress)
        attrs["two_stage_table"] = json_fingerprint(table.to_dict()["radiance"], 16)
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{path} exists and is a file, not a calibration set (a Zarr store is a folder)")
    with store_lock(path):
        return _fill(path, zarr=zarr, attrs=attrs, check=check, frames=frames, sensor=sensor, camera=camera,
                     ccd=ccd, design=design, seed=seed, spp=spp, keep_frames=keep_frames,
                     baseline_frames=baseline_frames, variant=variant, options=options,
                     render_mode=render_mode, table=table, scheduler=scheduler, progress=progress)


def _fill(path: Path, *, zarr, attrs, check, frames, sensor, camera, ccd, design, seed, spp, keep_frames,
          baseline_frames, variant, options, render_mode, table, scheduler, progress) -> CalibrationSet:
    """Open (rebuilding a half-created one) or create the store at ``path`` and render its missing frames."""
    from tqdm import tqdm

    from optitact.render import render

    n_el, (h, w) = sensor.n_elements, camera.shape
    group = open_store(path, zarr, schema=SCHEMA)
    if group is not None:
        old = dict(group.attrs)
        if isinstance(old.get("pipeline"), dict) and "radius" not in old["pipeline"]:
            # a set from before the geometry was stored: its defaults resolve as ours do
            old["pipeline"] = {**old["pipeline"], "radius": check.grids.radius,
                               "grid_mm": check.grids.grid_mm}
        old.setdefault("render_mode", "full")  # sets from before render modes rendered whole frames
        mismatch = sorted(k for k in attrs if k != "library_version" and old.get(k) != attrs[k])
        if mismatch:
            raise InputError(f"{path} holds a calibration set made with other settings "
                             f"({', '.join(mismatch)} differ); use another --out or the same "
                             f"settings to resume")
        remove_partials(path)
    else:
        group = zarr.open_group(str(path), mode="a")
        forces = design_forces(frames, n_el, design, seed, sensor)
        group.create_array("forces", data=forces, chunks=(1, n_el, 3))
        group.create_array("seeds", data=frame_seeds(seed, frames), chunks=(frames,))
        group.create_array("G", shape=(frames, n_el), dtype="f8", chunks=(1, n_el), fill_value=0.0)
        group.create_array("u", shape=(frames, n_el, 2), dtype="f8", chunks=(1, n_el, 2),
                           fill_value=0.0)
        group.create_array("contact", shape=(frames, n_el), dtype="bool", chunks=(1, n_el),
                           fill_value=False)
        group.create_array("saturated", shape=(frames, n_el), dtype="bool", chunks=(1, n_el),
                           fill_value=False)
        if keep_frames:
            group.create_array("frames", shape=(frames, h, w), dtype=_frame_dtype(ccd),
                               chunks=(1, h, w), fill_value=0)
        group.create_array("baseline", shape=(baseline_frames, h, w), dtype=_frame_dtype(ccd),
                           chunks=(1, h, w), fill_value=0)
        group.create_array("baseline_radiance", shape=(baseline_frames, h, w), dtype="f4",
                           chunks=(1, h, w), fill_value=0.0)
        group.create_array("baseline_done", shape=(baseline_frames,), dtype="bool", chunks=(1,),
                           fill_value=False)
        group.create_array("done", shape=(frames,), dtype="bool", chunks=(1,), fill_value=False)
        group.attrs.put(attrs)  # last, in one write: a store with attributes has all its arrays
    bseeds = np.random.SeedSequence([seed, 3]).generate_state(baseline_frames)
    todo_base = np.flatnonzero(~np.asarray(group["baseline_done"][:], dtype=bool))
    for k in tqdm(todo_base, desc="no-load baseline", unit="frame", file=sys.stderr,
                  disable=not progress or not len(todo_base)):
        empty = render(sensor, np.zeros((n_el, 3)), camera=camera, spp=spp, seed=int(bseeds[k]),
                       variant=variant)
        group["baseline_radiance"][k] = empty
        group["baseline"][k] = ccd.expose(empty, seed=int(bseeds[k]))
        group["baseline_done"][k] = True
    maker = FrameMaker(sensor=sensor, camera=camera, ccd=ccd, pipeline_options=options,
                       baseline=np.asarray(group["baseline"][:]),
                       background=np.asarray(group["baseline_radiance"][:], dtype=np.float64).mean(axis=0),
                       render_mode=render_mode, spp=spp, variant=variant, table=table,
                       keep_frames=bool(keep_frames))
    done = np.asarray(group["done"][:], dtype=bool)
    seeds = np.asarray(group["seeds"][:])
    forces = np.asarray(group["forces"][:])
    todo = np.flatnonzero(~done)

    def store(i: int, out: dict) -> None:
        # Only this process writes: a frame's readings, then its done flag last.
        for name in ("G", "u", "contact", "saturated"):
            group[name][i] = out[name]
        if keep_frames:
            group["frames"][i] = out["frame"]
        group["done"][i] = True

    with tqdm(total=frames, initial=frames - len(todo), unit="frame", desc=path.name,
              file=sys.stderr, disable=not progress) as bar:
        if scheduler is None:
            for i in todo:
                store(int(i), maker(forces[i], int(seeds[i])))
                bar.update(1)
        else:
            for i, out in _distributed(scheduler, maker, todo, forces, seeds, str(path)):
                store(i, out)
                bar.update(1)
    return CalibrationSet(path)
