"""Benchmarks: run time side by side with the error it buys.

Every figure is a median over repeats taken in one run, because the machine
is shared and noisy.
"""

from __future__ import annotations

import sys
import time

import numpy as np

from ._validate import integer
from .camera import FisheyeCamera
from .loads import indenter_load
from .sensor import DomeSensor

__all__ = ["bench_render"]


def bench_render(spps=(16, 64, 256), *, repeats: int = 3, width: int = 640, height: int = 480,
                 variant: str | None = None, seed: int = 0) -> dict:
    """Time full-frame renders of the demo load and measure their Monte Carlo noise.

    Parameters
    ----------
    spps : sequence of int
        Samples per pixel to measure.
    repeats : int
        Renders per spp (>= 2), each with its own seed; times are reported as
        median and all runs.
    width, height : int
        Image size.
    variant : str, optional
        Mitsuba variant (default: the fastest that works).
    seed : int
        Base seed; repeat ``k`` uses ``seed + k``.

    Returns
    -------
    dict
        ``variant``, ``size`` and per spp: ``median_s``, ``runs_s``,
        ``spot_pixel_rel_noise`` (RMS per-pixel difference between repeats,
        divided by sqrt(2) and by the mean radiance, over pixels that belong to
        spots) and ``spot_sum_rel_spread`` (relative standard deviation of the
        total spot radiance over repeats: the noise of an integrated grey value).

    Notes
    -----
    A warm-up render (1 spp) compiles the kernels and selects the variant
    first, so the times are those of a warm process. Spot pixels are those
    where the mean over repeats exceeds 10 % of its 99.9th percentile.
    """
    from tqdm import tqdm

    from .render import active_variant, render

    repeats = integer(repeats, "repeats", minimum=2)
    spps = tuple(integer(spp, "spps[]", minimum=1) for spp in spps)
    sensor = DomeSensor.default()
    camera = FisheyeCamera(width=width, height=height)
    forces = indenter_load(sensor)
    render(sensor, forces, camera=camera, spp=1, seed=seed, variant=variant)
    result = {"variant": active_variant()["variant"], "size": f"{width}x{height}",
              "load": "indenter_load (demo)", "repeats": repeats, "spp": {}}
    jobs = [(spp, k) for spp in spps for k in range(repeats)]
    images: dict[int, list] = {spp: [] for spp in spps}
    times: dict[int, list] = {spp: [] for spp in spps}
    for spp, k in tqdm(jobs, desc="bench render", unit="frame", file=sys.stderr):
        t0 = time.perf_counter()
        img = render(sensor, forces, camera=camera, spp=spp, seed=seed + k, variant=variant)
        times[spp].append(time.perf_counter() - t0)
        images[spp].append(img.astype(np.float64))
    for spp in spps:
        stack = np.stack(images[spp])
        mean = stack.mean(axis=0)
        spot = mean > 0.1 * np.percentile(mean, 99.9)
        diff = (stack[0] - stack[1])[spot] / np.sqrt(2.0)
        sums = stack[:, spot].sum(axis=1)
        result["spp"][str(spp)] = {
            "median_s": round(float(np.median(times[spp])), 3),
            "runs_s": [round(t, 3) for t in times[spp]],
            "spot_pixel_rel_noise": round(float(np.sqrt(np.mean(diff**2)) / mean[spot].mean()), 4),
            "spot_sum_rel_spread": round(float(sums.std(ddof=1) / sums.mean()), 5),
        }
    return result
