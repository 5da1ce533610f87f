"""The simulated chain of the dome sensor: element forces -> render -> CCD -> pipeline -> calibration.

:class:`ChainSimulator` turns element-local forces into *estimated* forces,
frame by frame, through the real chain (contact model, Mitsuba render of only
the loaded elements' pixels over a cached no-load baseline, CCD exposure, the
frame pipeline and a calibration); :class:`ChainEstimate` holds what it
returns. The finger studies (:mod:`optitact.studies.finger`) use it so that
every force they analyse is estimated, never read from the simulated truth.
"""

from __future__ import annotations

import sys
import time
from dataclasses import dataclass, field

import numpy as np

from optitact._validate import integer, real_array, seed_value
from optitact.optics.camera import FisheyeCamera
from optitact.optics.ccd import CCD
from optitact.errors import InputError, ShapeError
from optitact.optics.sensor import DomeSensor

__all__ = ["ChainSimulator", "ChainEstimate"]


@dataclass(frozen=True)
class ChainEstimate:
    """Estimated element forces of a sequence of frames (see :meth:`ChainSimulator.estimate`).

    Attributes
    ----------
    forces : (T, N, 3) ndarray
        Estimated element-local forces (N); 0 where there is no contact.
    clamped : (T, N) ndarray of bool
        The reading was outside the calibration's fitted range (clamped).
    contact : (T, N) ndarray of bool
        The pipeline found the element in contact.
    truth : (T, N, 3) ndarray
        The forces the frames were rendered from.
    tipped : (T, N) ndarray of bool
        The contact model tipped the feeler (shear beyond what the cones
        balance; see :func:`optitact.optics.contact.cone_loads`).
    readings : optitact.pipeline.readings.Readings
        Stack readings, e.g. for another calibration.
    seconds : float
        Wall time of the chain.
    """

    forces: np.ndarray
    clamped: np.ndarray
    contact: np.ndarray
    truth: np.ndarray
    tipped: np.ndarray
    readings: object = field(repr=False)
    seconds: float = 0.0

    def __len__(self) -> int:
        return len(self.forces)


class ChainSimulator:
    """Element forces -> estimated forces through the real chain, frame by frame.

    Parameters
    ----------
    calibration : optitact.calib.fit.Calibration, optional
        Default the shipped one (:func:`optitact.calib.shipped.default_calibration`);
        it fixes the sensor, camera and pipeline options.
    sensor, camera : optional
        Checked against the calibration's (a mismatch is a
        ``CalibrationMismatchError``).
    ccd : CCD, optional
        Camera noise model, default ``CCD()``.
    spp : int
        Samples per pixel of each frame's render, default 32.
    seed : int
        Seeds the no-load baseline and, with the frame index, every frame.
    baseline_frames : int
        No-load frames of the baseline (default 4), rendered once at
        ``baseline_spp`` (default 64) and cached on disk
        (:func:`optitact.render.cache.cached_render`; with seed 0 the same frames
        as ``optitact demo``).
    variant : str, optional
        Mitsuba variant.
    render_options : dict, optional
        Extra keywords for :func:`optitact.render.render` (e.g.
        ``{"transport": "two_stage"}``); with the default path tracing only
        the loaded elements' region pixels (:func:`optitact.render.pathtrace.spot_pixels`)
        are rendered, over the mean no-load radiance.

    Notes
    -----
    Frame ``i`` (an index the caller gives, so that closed-loop experiments
    stay reproducible) is rendered and exposed with the seed
    ``SeedSequence([seed, 7, i])``; a frame without loaded elements is the
    no-load radiance, exposed with fresh camera noise. The pipeline is
    ``calibration.pipeline(baseline=...)`` over the exposed no-load frames
    (their mean, and their per-pixel noise for the threshold); forces come
    from ``calibration.forces``.
    """

    def __init__(self, calibration=None, *, sensor: DomeSensor | None = None,
                 camera: FisheyeCamera | None = None, ccd: CCD | None = None, spp: int = 32, seed: int = 0,
                 baseline_frames: int = 4, baseline_spp: int = 64, variant: str | None = None,
                 render_options: dict | None = None) -> None:
        from optitact.calib.fit import Calibration
        from optitact.calib.shipped import default_calibration

        cal = default_calibration() if calibration is None else calibration
        if not isinstance(cal, Calibration):
            raise TypeError(f"calibration must be an optitact.calib.fit.Calibration, got {type(cal).__name__}")
        cal.check(sensor, camera)
        self.calibration = cal
        self.sensor, self.camera = cal.sensor, cal.camera
        self.ccd = CCD() if ccd is None else ccd
        if not isinstance(self.ccd, CCD):
            raise TypeError(f"ccd must be a CCD, got {type(self.ccd).__name__}")
        self.spp = integer(spp, "spp", minimum=1)
        seed = seed_value(seed)
        if seed is None:
            raise InputError("seed must be a non-negative integer, got None")
        self.seed = seed
        self.baseline_frames = integer(baseline_frames, "baseline_frames", minimum=1)
        self.baseline_spp = integer(baseline_spp, "baseline_spp", minimum=1)
        self.variant = variant
        if render_options is not None and not isinstance(render_options, dict):
            raise TypeError(f"render_options must be a dict, got {type(render_options).__name__}")
        self.render_options = dict(render_options or {})
        reserved = {"camera", "spp", "seed", "variant"} & set(self.render_options)
        if reserved:
            raise InputError(f"render_options must not set {sorted(reserved)} (ChainSimulator's own options)")
        self._pipe = None
        self._background = None

    def describe(self) -> dict:
        """The chain's settings, JSON-ready."""
        return {"camera": self.camera.to_dict(), "ccd": self.ccd.to_dict(), "spp": self.spp, "seed": self.seed,
                "baseline_frames": self.baseline_frames, "baseline_spp": self.baseline_spp,
                "render_options": {k: v for k, v in self.render_options.items()
                                   if isinstance(v, (str, int, float, bool))},
                "calibration": {"model": self.calibration.model,
                                "fingerprint": self.calibration.fingerprint,
                                "provenance": dict(self.calibration.provenance)}}

    def prepare(self) -> None:
        """Render (or load from the cache) the no-load baseline and build the pipeline; done on first use."""
        if self._pipe is not None:
            return
        from optitact.render.cache import cached_render

        zero = np.zeros((self.sensor.n_elements, 3))
        rads, frames = [], []
        for k in range(self.baseline_frames):
            s = self.seed + 1 + k
            rad = cached_render(self.sensor, zero, camera=self.camera, spp=self.baseline_spp, seed=s,
                                variant=self.variant)
            rads.append(rad)
            frames.append(self.ccd.expose(rad, seed=s))
        self._background = np.mean(rads, axis=0).astype(np.float32)
        self._pipe = self.calibration.pipeline(baseline=np.stack(frames))

    def frame_seed(self, index: int) -> int:
        """Render and camera seed of frame ``index``."""
        return int(np.random.SeedSequence([self.seed, 7, int(index)]).generate_state(1)[0])

    def _radiance(self, forces: np.ndarray, seed: int) -> np.ndarray:
        from optitact.render import render
        from optitact.render.pathtrace import spot_pixels

        opts = dict(self.render_options)
        if opts.get("transport", "path") == "path":
            if not np.any(forces[:, 2] > 0):
                return self._background
            opts.update(pixels=spot_pixels(self.sensor, self.camera, forces), background=self._background)
        return render(self.sensor, forces, camera=self.camera, spp=self.spp, seed=seed, variant=self.variant,
                      **opts)

    def estimate(self, forces, *, first_index: int = 0, progress: bool = False,
                 desc: str = "frames") -> ChainEstimate:
        """Estimated forces of a sequence of element-force frames.

        Parameters
        ----------
        forces : (N, 3) or (T, N, 3) array_like
            Element-local forces (N) of each frame.
        first_index : int
            Index of the first frame (seeds; see the class *Notes*).
        progress : bool
            tqdm bar on stderr.
        desc : str
            The bar's label.

        Returns
        -------
        ChainEstimate
            With a leading frame axis even for a single frame.
        """
        from optitact.optics.contact import check_forces, cone_loads
        from optitact.pipeline.readings import Readings

        arr = real_array(forces, "forces")
        if arr.ndim == 2:
            arr = arr[None]
        if arr.ndim != 3:
            raise ShapeError(f"forces must have shape (N, 3) or (T, N, 3), got {arr.shape}")
        for f in arr:
            check_forces(f, self.sensor)
        first_index = integer(first_index, "first_index", minimum=0)
        self.prepare()
        t0 = time.perf_counter()
        rows, tipped = [], np.zeros(arr.shape[:2], bool)
        from tqdm import tqdm

        for i in tqdm(range(len(arr)), desc=desc, unit="frame", file=sys.stderr, disable=not progress,
                      leave=False):
            s = self.frame_seed(first_index + i)
            frame = self.ccd.expose(self._radiance(arr[i], s), seed=s)
            rows.append(self._pipe.process(frame))
            tipped[i] = cone_loads(self.sensor, arr[i])[1]
        readings = Readings.stack(rows)
        est, clamped = self.calibration.forces(readings)
        return ChainEstimate(forces=est, clamped=clamped, contact=readings.contact.copy(), truth=arr.copy(),
                             tipped=tipped, readings=readings, seconds=time.perf_counter() - t0)
