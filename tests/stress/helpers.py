"""Shared truths of the stress cases: analytic spots, exact readings, invariants every reading meets.

A case passes when its stage gives the right answer -- checked against an
independent truth (an analytic spot integrated over the region's cells, the
``"reference"`` method, ``math.fsum``, a power-of-two rescaling that must be
exact, ...) -- or raises a documented ``ValueError``/``TypeError`` subclass
whose message names what was expected. Warnings are errors (pyproject).
"""

from __future__ import annotations

import contextlib
import math
import sys
from pathlib import Path

import numpy as np

from optitact.optics.camera import FisheyeCamera
from optitact.optics.sensor import DomeSensor
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.pipeline.imageops import G_MIN
from optitact.pipeline.readings import Readings

SENSOR = DomeSensor.default()
#: The camera of the stress cases: small, so that thousands of frames run in a minute.
SMALL = FisheyeCamera(width=160, height=120)
#: A one-element sensor (calibration fits and files).
LONE = DomeSensor(ring_counts=(1,), ring_polar_deg=(0.0,))
H, W = SMALL.shape
N_EL = SENSOR.n_elements

INT_DTYPES = (np.uint8, np.uint16, np.int16, np.int32, np.int64, np.uint64)
FLOAT_DTYPES = (np.float16, np.float32, np.float64, np.longdouble)


class Context:
    """Pipelines, dome offsets and region truths of the small camera, built once per session."""

    def __init__(self, tmp: Path) -> None:
        self.sensor, self.camera, self.tmp, self.n_el = SENSOR, SMALL, tmp, N_EL
        self.pipe = Pipeline(SENSOR, SMALL)
        self._pipes: dict = {}
        g = self.pipe.grids
        self.area = g.area.sum(axis=(1, 2))
        self.cell_x, self.cell_y = np.meshgrid(g.coords, g.coords)
        self.centroid = np.stack([(g.area * self.cell_x).sum(axis=(1, 2)),
                                  (g.area * self.cell_y).sum(axis=(1, 2))], -1) / self.area[:, None]
        px = np.stack(np.mgrid[0:H, 0:W], axis=-1).astype(np.float64)
        self.dome = SMALL.unproject(px, SENSOR, outside="nan")
        self._offsets: dict = {}
        self._region_pixels: dict = {}
        # pixel footprint (mm per pixel, largest direction) at each element's centre
        px = SMALL.project(SENSOR.element_positions, SENSOR)
        jac = []
        for step in ([0.5, 0.0], [0.0, 0.5]):
            a = SENSOR.tangent_offset(np.arange(N_EL), SMALL.unproject(px - step, SENSOR))
            b = SENSOR.tangent_offset(np.arange(N_EL), SMALL.unproject(px + step, SENSOR))
            jac.append(b - a)
        self.footprint = np.linalg.svd(np.stack(jac, axis=-1), compute_uv=False)[:, 0]

    def pipeline(self, **options) -> Pipeline:
        """``pipe.replace(**options)``, cached unless a baseline is given."""
        if options.get("baseline") is not None:
            return self.pipe.replace(**options)
        key = tuple(sorted(options.items()))
        if key not in self._pipes:
            self._pipes[key] = self.pipe.replace(**options)
        return self._pipes[key]

    def offsets(self, e: int) -> np.ndarray:
        """(H, W, 2) element-local tangent offsets (mm) of every pixel's dome point (NaN off the dome)."""
        if e not in self._offsets:
            self._offsets[e] = SENSOR.tangent_offset(np.full(SMALL.shape, e), self.dome)
        return self._offsets[e]

    def spot(self, e: int, c, s: float, a: float) -> np.ndarray:
        """Float64 frame of a Gaussian spot ``a exp(-|xy - c|^2 / 2 s^2)`` around element ``e``, cut at 6 s."""
        d2 = np.sum((self.offsets(e) - np.asarray(c, np.float64)) ** 2, axis=-1)
        img = np.zeros(SMALL.shape)
        near = np.isfinite(d2) & (d2 <= (6.0 * s) ** 2)
        img[near] = a * np.exp(-d2[near] / (2.0 * s * s))
        return img

    def spot_truth(self, e: int, c, s: float, a: float, pipe: Pipeline) -> tuple[float, np.ndarray]:
        """G and first moments of the spot integrated over region ``e``'s cells (no camera involved)."""
        g = pipe.grids
        m = g.mask[e]
        x, y = self.cell_x[m], self.cell_y[m]
        d2 = (x - c[0]) ** 2 + (y - c[1]) ** 2
        val = np.where(d2 <= (6.0 * s) ** 2, a * np.exp(-d2 / (2.0 * s * s)), 0.0)
        w = val * g.area[e][m]
        return float(w.sum()), np.array([(w * x).sum(), (w * y).sum()])

    def region_pixels(self, e: int) -> np.ndarray:
        """Flat pixels whose values the bilinear dewarp of region ``e`` reads (from the public grids)."""
        if e not in self._region_pixels:
            g = self.pipe.grids
            rc = g.pixels[e][g.mask[e]]
            out: set = set()
            for rows in (np.floor(rc[:, 0]), np.ceil(rc[:, 0])):
                for cols in (np.floor(rc[:, 1]), np.ceil(rc[:, 1])):
                    out.update((rows.astype(int) * W + cols.astype(int)).tolist())
            self._region_pixels[e] = np.array(sorted(out))
        return self._region_pixels[e]

    def random_frame(self, rng, dtype) -> np.ndarray:
        """Up to five random spots on a random level with Gaussian noise, in ``dtype``."""
        img = np.zeros(SMALL.shape)
        for e in rng.choice(N_EL, size=int(rng.integers(0, 6)), replace=False):
            img += self.spot(int(e), rng.uniform(-0.8, 0.8, 2), float(rng.uniform(0.35, 0.7)),
                             float(rng.uniform(2, 150)))
        img += rng.uniform(0, 20) + rng.normal(0.0, rng.uniform(0, 2), img.shape)
        return as_dtype(np.maximum(img, 0.0), dtype)


def as_dtype(img: np.ndarray, dtype) -> np.ndarray:
    """``img`` rounded and clipped into ``dtype``'s range."""
    dtype = np.dtype(dtype)
    if dtype.kind in "ui":
        return np.clip(np.rint(img), 0, min(np.iinfo(dtype).max, 2.0**53)).astype(dtype)
    if dtype == np.float16:
        return np.clip(img, -60000, 60000).astype(dtype)
    return img.astype(dtype)


def spot_tolerance(energy: float, s: float, h: float) -> float:
    """Bound on the error of G of a Gaussian spot from sampling it at pixels and resampling bilinearly.

    Bilinear interpolation on a grid of spacing ``h`` errs by at most
    ``h^2 / 8 (|f_xx| + |f_yy|)``; for a Gaussian of rms width ``s`` the
    integral of ``|f_xx| + |f_yy|`` is ``2 E|z^2 - 1| energy / s^2`` (``E|z^2 - 1|
    = 0.968`` for a standard normal ``z``), so over any part of the spot
    ``|G error| <= 0.242 (h / s)^2 energy``. Where the whole spot lies in the
    region the errors cancel (the integral of the curvature is 0); at a
    region's edge they do not, which is what this bounds.
    """
    return 2 * 0.968 / 8 * (h / s) ** 2 * energy


def assert_sane(r: Readings, pipe: Pipeline) -> None:
    """Invariants every reading meets: finite, G >= 0, |u| inside the region, flags consistent."""
    assert np.isfinite(r.G).all() and np.isfinite(r.u).all(), "non-finite G or u"
    assert np.all(r.G >= 0), f"negative G {r.G.min()}"
    assert np.all(r.G[~r.contact] == 0) and np.all(r.u[~r.contact] == 0), "no contact but G or u != 0"
    assert not np.any(r.contact & ~(r.G > np.maximum(pipe.floor, G_MIN))), "contact at or below the floor"
    radius = np.hypot(r.u[..., 0], r.u[..., 1])
    assert np.all(radius <= pipe.grids.radius * (1 + 1e-9)), f"centroid {radius.max()} mm outside the region"
    assert r.G.dtype == np.float64 and r.contact.dtype == bool


def assert_same(a: Readings, b: Readings, *, g_rtol: float = 0.0, u_atol: float = 0.0) -> None:
    """Same flags; G within ``g_rtol`` (relative) and u within ``u_atol`` (mm)."""
    np.testing.assert_array_equal(a.contact, b.contact)
    np.testing.assert_array_equal(a.saturated, b.saturated)
    np.testing.assert_allclose(a.G, b.G, rtol=g_rtol, atol=0)
    np.testing.assert_allclose(a.u, b.u, rtol=0, atol=u_atol)


def coupled_set(rng, n: int, *, f_scale: float = 1.0, gain: float = 120.0, h: float = 3.0, c: float = 0.2):
    """Exact readings of an ideal coupled one-element sensor: G = gain Fz, u = F_t (h / Fz + c / sqrt(Fz))."""
    fz = rng.uniform(0.05, 1.0, (n, 1)) * f_scale
    mag = rng.uniform(0, 0.35, (n, 1)) * fz
    ang = rng.uniform(0, 2 * np.pi, (n, 1))
    f = np.stack([mag * np.cos(ang), mag * np.sin(ang), fz], -1)
    u = f[..., :2] * (h / fz + c / math.sqrt(f_scale) / np.sqrt(fz))[..., None]
    return f, Readings(gain * fz, u, np.ones((n, 1), bool), np.zeros((n, 1), bool))


@contextlib.contextmanager
def no_mitsuba():
    """``import mitsuba`` / ``import drjit`` fail inside (the modules are restored after)."""
    saved = {k: sys.modules.get(k, no_mitsuba) for k in ("mitsuba", "drjit")}
    sys.modules["mitsuba"] = sys.modules["drjit"] = None
    try:
        yield
    finally:
        for k, v in saved.items():
            if v is no_mitsuba:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


class Touch:
    """Unpickling this would create a file: the calibration loader must never unpickle."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (Path.touch, (Path(self.path),))
