"""Numerical stability and bad input: generated stress cases and a Monte Carlo noise sweep.

:func:`run_stability` is ``optitact bench stability``: it generates stress
cases for every stage (frames into the pipeline, readings at their edges,
calibration fits and files, accumulation over long streams and big batches,
the CCD model, the contact model and the renderer's input checks), runs each
with warnings turned into errors, and sweeps the noise of a spot of known
energy and centre through the CCD model and the pipeline, comparing the
spread of G and u with the Cramer-Rao bound.

A case passes when its stage gives the right answer -- checked against an
independent truth (an analytic spot integrated over the region's cells, the
``"reference"`` method, ``math.fsum``, a power-of-two rescaling that must be
exact, ...) -- or raises a documented error: a ``ValueError`` or
``TypeError`` (the package's ``InputError``, ``ShapeError``,
``CalibrationMismatchError`` subclass them) whose message names what was
expected. Anything else fails: NaN or a wrong number, an ``IndexError``,
``ZeroDivisionError``, ``OverflowError`` or a ``RuntimeWarning`` from deep in
NumPy, or a renderer check that imports Mitsuba before refusing its input.

Examples
--------
>>> import tempfile
>>> from optitact.stability import generate_cases, run_case
>>> with tempfile.TemporaryDirectory() as tmp:
...     cases = generate_cases(40, seed=1, tmp=tmp, long_rows=100)
...     failed = [case.name for case in cases if run_case(case) is not None]
>>> len(cases), failed
(40, [])

``run_stability()`` runs 10,000 cases and the sweep in about a minute on
two CPU cores and returns the ``optitact bench stability --json`` object.
"""

from __future__ import annotations

import io
import json
import math
import pickle
import sys
import tempfile
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from .camera import FisheyeCamera
from .ccd import CCD
from .contact import MAX_FORCE_N, check_forces, contact_patches
from .errors import InputError, ShapeError
from .pipeline import CHUNK_FRAMES, G_MIN, MAX_GREY, Pipeline, estimate_noise, readings_from_moments
from .readings import Readings
from .sensor import DomeSensor

__all__ = ["CATEGORIES", "Case", "CaseFailure", "flicker_check", "generate_cases", "noise_sweep",
           "run_case", "run_stability"]

#: Case categories and their share of the generated cases.
CATEGORIES = {
    "frames": 0.40,
    "readings": 0.14,
    "calibration_fit": 0.07,
    "calibration_file": 0.12,
    "accumulation": 0.05,
    "ccd": 0.09,
    "contact_render": 0.13,
}
#: Signal levels of the noise sweep, as multiples of the nominal spot's energy.
SWEEP_FACTORS = (1 / 32, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0)
#: The nominal spot: rms width (mm) and normal load (N) whose energy it carries.
NOMINAL_WIDTH_MM = 0.5
NOMINAL_LOAD_N = 0.5
#: Where the sweep's spot sits: element and centre (element-local mm).
SWEEP_ELEMENT = 0
SWEEP_CENTRE = (0.2, -0.1)


class CaseFailure(AssertionError):
    """A stress case's stage gave a wrong answer or an undocumented error."""


@dataclass(frozen=True)
class Case:
    """One generated stress case: a name, its category and a check that raises on failure."""

    name: str
    category: str
    check: Callable[[], None]


def run_case(case: Case) -> str | None:
    """Run one case with warnings as errors; None when it passes, else why it failed."""
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        try:
            case.check()
        except CaseFailure as exc:
            return str(exc)[:500]
        except Exception as exc:  # noqa: BLE001 - any other error is the finding
            return f"unexpected {type(exc).__name__}: {str(exc)[:400]}"
    return None


# ============================================================================ helpers
def _fail(msg: str) -> None:
    raise CaseFailure(msg)


def _expect_error(fn: Callable[[], object], types: tuple[type, ...], *words: str) -> None:
    """``fn()`` must raise one of ``types`` (ValueError/TypeError kinds) naming all ``words``."""
    try:
        fn()
    except types as exc:
        if not isinstance(exc, ValueError | TypeError):
            _fail(f"{type(exc).__name__} is not a ValueError/TypeError: {exc}")
        msg = str(exc)
        missing = [w for w in words if w.lower() not in msg.lower()]
        if missing:
            _fail(f"{type(exc).__name__} message does not name {missing}: {msg[:300]}")
        return
    except CaseFailure:
        raise
    except Exception as exc:  # noqa: BLE001
        _fail(f"expected {'/'.join(t.__name__ for t in types)}, got {type(exc).__name__}: {str(exc)[:300]}")
    _fail(f"expected {'/'.join(t.__name__ for t in types)} naming {list(words)}, but no error")


def _close(a, b, *, rtol: float = 0.0, atol: float = 0.0, what: str = "") -> None:
    a, b = np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64)
    if a.shape != b.shape:
        _fail(f"{what}: shape {a.shape} != {b.shape}")
    if not np.isfinite(a).all():
        _fail(f"{what}: non-finite value {a[~np.isfinite(a)][:3]}")
    err = np.abs(a - b)
    bound = atol + rtol * np.abs(b)
    if not np.all(err <= bound):
        i = np.unravel_index(np.argmax(err - bound), err.shape)
        _fail(f"{what}: {a[i]!r} vs {b[i]!r} at {tuple(int(k) for k in i)} (err {err[i]:.3g} > {bound[i]:.3g})")


def _same_readings(a: Readings, b: Readings, *, g_rtol: float = 0.0, u_atol: float = 0.0,
                   what: str = "readings") -> None:
    if not np.array_equal(a.contact, b.contact):
        _fail(f"{what}: contact flags differ at {np.argwhere(a.contact != b.contact)[:3].tolist()}")
    if not np.array_equal(a.saturated, b.saturated):
        _fail(f"{what}: saturated flags differ at {np.argwhere(a.saturated != b.saturated)[:3].tolist()}")
    _close(a.G, b.G, rtol=g_rtol, what=f"{what} G")
    _close(a.u, b.u, atol=u_atol, what=f"{what} u")


def _sane(r: Readings, pipe: Pipeline, what: str = "readings") -> None:
    """Invariants every reading must meet: finite, G >= 0, |u| inside the region, flags consistent."""
    if not (np.isfinite(r.G).all() and np.isfinite(r.u).all()):
        _fail(f"{what}: non-finite G or u")
    if np.any(r.G < 0):
        _fail(f"{what}: negative G {r.G.min()}")
    if np.any(r.G[~r.contact] != 0) or np.any(r.u[~r.contact] != 0):
        _fail(f"{what}: a region out of contact reads G or u != 0")
    if np.any(r.contact & ~(r.G > np.maximum(pipe.floor, G_MIN))):
        _fail(f"{what}: contact with G at or below the noise floor")
    radius = np.hypot(r.u[..., 0], r.u[..., 1])
    if np.any(radius > pipe.grids.radius * (1 + 1e-9)):
        _fail(f"{what}: centroid {radius.max()} mm outside the region (radius {pipe.grids.radius})")
    if r.G.dtype != np.float64 or r.contact.dtype != bool:
        _fail(f"{what}: dtypes {r.G.dtype}, {r.contact.dtype}")


class _Guard:
    """Make ``import mitsuba`` / ``import drjit`` fail while active (restoring them after)."""

    names = ("mitsuba", "drjit")

    def __enter__(self):
        self.saved = {k: sys.modules.get(k, _Guard) for k in self.names}
        for k in self.names:
            sys.modules[k] = None  # import raises ImportError
        return self

    def __exit__(self, *exc):
        for k, v in self.saved.items():
            if v is _Guard:
                sys.modules.pop(k, None)
            else:
                sys.modules[k] = v


# ============================================================================ shared context
class _Context:
    """Sensors, cameras, pipelines and truths shared by the cases (built once per run)."""

    def __init__(self, camera: FisheyeCamera | None, tmp: Path) -> None:
        self.sensor = DomeSensor.default()
        self.camera = FisheyeCamera(width=160, height=120) if camera is None else camera
        if not isinstance(self.camera, FisheyeCamera):
            raise TypeError(f"camera must be a FisheyeCamera, got {type(self.camera).__name__}")
        self.tmp = tmp
        self.n_el = self.sensor.n_elements
        self.pipe = Pipeline(self.sensor, self.camera)
        self.pipe0 = self.pipe.replace(noise_sigma=0.0)
        self._pipes: dict = {}
        g = self.pipe.grids
        self.area = g.area.sum(axis=(1, 2))
        gx, gy = np.meshgrid(g.coords, g.coords)
        self.cell_x, self.cell_y = gx, gy
        self.centroid = np.stack([(g.area * gx).sum(axis=(1, 2)), (g.area * gy).sum(axis=(1, 2))], -1) \
            / self.area[:, None]
        rr, cc = np.mgrid[0:self.camera.height, 0:self.camera.width]
        px = np.stack([rr, cc], axis=-1).astype(np.float64)
        self.dome = self.camera.unproject(px, self.sensor, outside="nan")
        self._offsets: dict = {}
        self.region_pixels: dict = {}
        self.lone = DomeSensor(ring_counts=(1,), ring_polar_deg=(0.0,))
        # pixel footprint (mm per pixel, largest direction) at each element's centre
        px = self.camera.project(self.sensor.element_positions, self.sensor)
        jac = []
        for step in ([0.5, 0.0], [0.0, 0.5]):
            a = self.sensor.tangent_offset(np.arange(self.n_el), self.camera.unproject(px - step, self.sensor))
            b = self.sensor.tangent_offset(np.arange(self.n_el), self.camera.unproject(px + step, self.sensor))
            jac.append(b - a)
        self.footprint = np.linalg.svd(np.stack(jac, axis=-1), compute_uv=False)[:, 0]
        self._cal = None

    def pipeline(self, **options) -> Pipeline:
        key = tuple(sorted((k, v) for k, v in options.items() if k != "baseline"))
        if options.get("baseline") is not None:
            return self.pipe.replace(**options)
        if key not in self._pipes:
            self._pipes[key] = self.pipe.replace(**options)
        return self._pipes[key]

    def offsets(self, e: int) -> np.ndarray:
        """(H, W, 2) element-local tangent offsets (mm) of every pixel's dome point (NaN off the dome)."""
        if e not in self._offsets:
            self._offsets[e] = self.sensor.tangent_offset(np.full(self.camera.shape, e), self.dome)
        return self._offsets[e]

    def spot(self, e: int, c, s: float, a: float) -> np.ndarray:
        """Float64 frame of a Gaussian spot ``a exp(-|xy - c|^2 / 2 s^2)`` around element ``e``, cut at 6 s."""
        xy = self.offsets(e)
        d2 = np.sum((xy - np.asarray(c, np.float64)) ** 2, axis=-1)
        img = np.zeros(self.camera.shape)
        near = np.isfinite(d2) & (d2 <= (6.0 * s) ** 2)
        img[near] = a * np.exp(-d2[near] / (2.0 * s * s))
        return img

    def spot_truth(self, e: int, c, s: float, a: float, pipe: Pipeline) -> tuple[float, np.ndarray]:
        """G and first moments of the spot integrated over region ``e``'s cells (no camera involved)."""
        g = pipe.grids
        m = g.mask[e]
        x, y = self.cell_x[m], self.cell_y[m]
        val = a * np.exp(-((x - c[0]) ** 2 + (y - c[1]) ** 2) / (2.0 * s * s))
        val = np.where((x - c[0]) ** 2 + (y - c[1]) ** 2 <= (6.0 * s) ** 2, val, 0.0)
        w = val * g.area[e][m]
        return float(w.sum()), np.array([(w * x).sum(), (w * y).sum()])

    @property
    def calibration(self):
        """A coupled calibration of the one-element sensor, fitted on exact analytic readings."""
        if self._cal is None:
            from optitact.calib import Calibration

            forces, r = _analytic_set(np.random.default_rng(12345), 60, gain=120.0, h=3.0, c=0.2)
            self._cal = Calibration.fit(r, forces, sensor=self.lone, camera=self.camera, model="coupled",
                                        pipeline_options={"noise_sigma": 0.5})
            self._cal_doc = self._cal.to_dict()
        return self._cal


def _analytic_set(rng, n: int, *, gain: float, h: float, c: float, n_el: int = 1,
                  f_scale: float = 1.0):
    """Exact readings of an ideal coupled sensor: G = gain Fz, u = F_t (h / Fz + c / sqrt(Fz))."""
    fz = rng.uniform(0.05, 1.0, (n, n_el)) * f_scale
    mag = rng.uniform(0.0, 0.35, (n, n_el)) * fz
    ang = rng.uniform(0.0, 2 * np.pi, (n, n_el))
    forces = np.stack([mag * np.cos(ang), mag * np.sin(ang), fz], axis=-1)
    u = forces[..., :2] * (h / fz + c * math.sqrt(f_scale) / np.sqrt(fz))[..., None]
    return forces, Readings(gain * fz, u, np.ones((n, n_el), bool), np.zeros((n, n_el), bool))


# ============================================================================ frames
_INT_DTYPES = (np.uint8, np.uint16, np.int16, np.int32, np.int64, np.uint64)
_FLOAT_DTYPES = (np.float16, np.float32, np.float64, np.longdouble)


def _as_dtype(img: np.ndarray, dtype) -> np.ndarray:
    dtype = np.dtype(dtype)
    if dtype.kind in "ui":
        top = np.iinfo(dtype).max
        return np.clip(np.rint(img), 0, min(top, 2.0**53)).astype(dtype)
    if dtype == np.float16:
        return np.clip(img, -60000, 60000).astype(dtype)
    return img.astype(dtype)


def _frame_cases(ctx: _Context, rng: np.random.Generator, n: int) -> list[Case]:
    kinds = [("blank", 1), ("constant", 2), ("noise", 1), ("saturated_whole", 1), ("saturated_element", 1),
             ("hot_pixel", 2), ("scaling", 2), ("float32_vs_float64", 2), ("non_finite", 1),
             ("too_large", 1), ("wrong_shape", 1), ("wrong_dtype", 1), ("negative_int", 1), ("ragged", 0.3),
             ("empty_stack", 0.3), ("one_frame_stack", 1), ("views", 1), ("max_uint16", 1), ("random", 4)]
    names, w = zip(*kinds, strict=True)
    picks = rng.choice(len(names), size=n, p=np.array(w) / sum(w))
    cases = []
    for i, k in enumerate(picks):
        sub = np.random.default_rng(rng.integers(2**63))
        cases.append(Case(f"frames/{names[k]}/{i}", "frames", _bind(_FRAME_CHECKS[names[k]], ctx, sub)))
    return cases


def _bind(fn, *args):
    return lambda: fn(*args)


def _random_options(rng) -> dict:
    opts = {}
    if rng.random() < 0.3:
        opts["filter"] = str(rng.choice(["gaussian", "median"]))
    if rng.random() < 0.3:
        opts["method"] = "reference"
    return opts


def _check_blank(ctx: _Context, rng) -> None:
    dtype = rng.choice(_INT_DTYPES + _FLOAT_DTYPES)
    pipe = ctx.pipeline(**_random_options(rng), noise_sigma=float(rng.choice([0.0, 0.5, 2.0])))
    frames = np.zeros((int(rng.integers(1, 4)),) + ctx.camera.shape, dtype)
    r = pipe.process(frames if rng.random() < 0.5 else frames[0])
    _sane(r, pipe)
    if r.contact.any() or r.saturated.any() or np.any(r.G) or np.any(r.u):
        _fail("a blank frame reads contact, saturation or a non-zero G/u")


def _check_constant(ctx: _Context, rng) -> None:
    dtype = np.dtype(rng.choice((np.uint8, np.uint16, np.float32, np.float64, np.int32)))
    c = float(rng.choice([1, 3, 17, 200, 254])) if dtype.kind in "ui" else float(10 ** rng.uniform(-3, 4))
    sigma = float(rng.choice([0.0, 0.5, 1.0]))
    pipe = ctx.pipeline(noise_sigma=sigma, method=str(rng.choice(["fast", "reference"])))
    r = pipe.process(np.full(ctx.camera.shape, c, dtype))
    _sane(r, pipe)
    c = float(np.asarray(c, dtype))
    lit = c > pipe.threshold
    expect_g = np.where(lit & (c * ctx.area > pipe.floor), c * ctx.area, 0.0)
    _close(r.G, expect_g, rtol=1e-9, what="G of a constant frame (c x region area)")
    _close(r.u, np.where((expect_g > 0)[:, None], ctx.centroid, 0.0), atol=1e-9,
           what="u of a constant frame (the region's own centroid)")
    cap = 2 * np.pi * ctx.sensor.outer_radius**2 * (1 - math.cos(pipe.grids.radius / ctx.sensor.outer_radius))
    # the region is the cells within the radius: a staircase disc, within a cell of the circle
    _close(ctx.area, np.full(ctx.n_el, cap), rtol=pipe.grids.grid_mm / pipe.grids.radius,
           what="region area vs the geodesic disc")


def _check_noise(ctx: _Context, rng) -> None:
    sigma = float(rng.uniform(0.6, 3.0))
    level = float(rng.uniform(5, 60))
    shape = ctx.camera.shape

    def draw(t):
        return np.clip(np.rint(level + rng.normal(0.0, sigma, (t,) + shape)), 0, 255).astype(np.uint8)

    filt = str(rng.choice(["none", "gaussian", "median"]))
    pipe = Pipeline.from_noload(ctx.sensor, ctx.camera, draw(6), filter=filt)
    r = pipe.process(draw(8))
    _sane(r, pipe)
    if r.contact.mean() > 0.05:
        _fail(f"noise-only frames read contact in {r.contact.mean():.1%} of the regions (> 5 %)")


def _check_saturated_whole(ctx: _Context, rng) -> None:
    dtype = np.dtype(rng.choice((np.uint8, np.uint16)))
    top = np.iinfo(dtype).max
    pipe = ctx.pipeline(**_random_options(rng))
    r = pipe.process(np.full(ctx.camera.shape, top, dtype))
    _sane(r, pipe)
    if not (r.saturated.all() and r.contact.all()):
        _fail("a frame at the dtype's maximum must read every region saturated and in contact")
    if pipe.filter == "none":
        _close(r.G, top * ctx.area, rtol=1e-9, what="G of a saturated frame")
    # A saturated baseline: nothing above it, but the regions are still saturated.
    full = np.full(ctx.camera.shape, top, dtype)
    rb = pipe.replace(baseline=full).process(full)
    if rb.contact.any() or not rb.saturated.all():
        _fail("frame == saturated baseline must read no contact but saturated regions")


def _region_pixels(ctx: _Context, e: int) -> np.ndarray:
    """Flat pixels whose values the bilinear dewarp of region ``e`` reads (from the grids, not the fold)."""
    if e not in ctx.region_pixels:
        g = ctx.pipe.grids
        rc = g.pixels[e][g.mask[e]]
        w = ctx.camera.width
        out: set = set()
        for rows in (np.floor(rc[:, 0]), np.ceil(rc[:, 0])):
            for cols in (np.floor(rc[:, 1]), np.ceil(rc[:, 1])):
                out.update((rows.astype(int) * w + cols.astype(int)).tolist())
        ctx.region_pixels[e] = np.array(sorted(out))
    return ctx.region_pixels[e]


def _check_saturated_element(ctx: _Context, rng) -> None:
    e = int(rng.integers(ctx.n_el))
    dtype = np.dtype(rng.choice((np.uint8, np.uint16)))
    top = np.iinfo(dtype).max
    frame = np.zeros(ctx.camera.shape, dtype)
    frame.reshape(-1)[_region_pixels(ctx, e)] = top
    pipe = ctx.pipeline(method=str(rng.choice(["fast", "reference"])))
    r = pipe.process(frame)
    _sane(r, pipe)
    want = np.zeros(ctx.n_el, bool)
    want[e] = True
    if not (np.array_equal(r.saturated, want) and np.array_equal(r.contact, want)):
        _fail(f"saturating region {e}: saturated {np.flatnonzero(r.saturated)}, "
              f"contact {np.flatnonzero(r.contact)}")
    _close(r.G[e], top * ctx.area[e], rtol=1e-9, what="G of a saturated region")


def _check_hot_pixel(ctx: _Context, rng) -> None:
    e = int(rng.integers(ctx.n_el))
    pix = _region_pixels(ctx, e)
    p = int(rng.choice(pix)) if rng.random() < 0.8 else int(rng.integers(ctx.camera.height * ctx.camera.width))
    dtype = np.dtype(rng.choice((np.uint8, np.uint16)))
    frame = np.zeros(ctx.camera.shape, dtype)
    frame.reshape(-1)[p] = np.iinfo(dtype).max
    filt = str(rng.choice(["none", "none", "gaussian", "median"]))
    fast = ctx.pipeline(filter=filt)
    r = fast.process(frame)
    _sane(r, fast)
    feeds = np.array([np.isin(p, _region_pixels(ctx, f)) for f in range(ctx.n_el)])
    if not np.array_equal(r.saturated, feeds):
        _fail(f"hot pixel {divmod(p, ctx.camera.width)}: saturated {np.flatnonzero(r.saturated)}, "
              f"expected {np.flatnonzero(feeds)}")
    ref = fast.replace(method="reference").process(frame)
    _same_readings(r, ref, g_rtol=1e-9, u_atol=1e-9, what="fast vs reference")
    if filt == "median" and r.contact.any():
        _fail("a 3x3 median must remove a single hot pixel")


def _check_scaling(ctx: _Context, rng) -> None:
    """Noiseless pipeline: scaling a float frame by 2^k scales G exactly and keeps u bit for bit."""
    e = int(rng.integers(ctx.n_el))
    img = ctx.spot(e, rng.uniform(-0.6, 0.6, 2), float(rng.uniform(0.4, 0.7)), 1.0)
    pipe = ctx.pipeline(noise_sigma=0.0, method=str(rng.choice(["fast", "reference"])))
    base = pipe.process(img)
    _sane(base, pipe)
    if not base.contact[e]:
        _fail("a noiseless spot must read contact")
    k = int(rng.integers(-1100, 330))
    scale = 2.0**k if -1022 <= k <= 1023 else None
    scaled = np.ldexp(img, k)  # exact unless it underflows or overflows
    if not np.isfinite(scaled).all() or np.abs(scaled).max() > MAX_GREY:
        _expect_error(lambda: pipe.process(scaled), (InputError,), "finite" if not np.isfinite(scaled).all()
                      else "magnitude")
        return
    r = pipe.process(scaled)
    _sane(r, pipe)
    exact = scale is not None and np.array_equal(np.ldexp(scaled, -k), img)
    if exact and base.G[e] * scale > 1e-240:
        _close(r.G, base.G * scale, rtol=0, what=f"G of the frame x 2^{k}")
        _close(r.u, base.u, atol=0, what=f"u of the frame x 2^{k}")
    elif r.contact[e] and np.hypot(*(r.u[e] - base.u[e])) > 1e-6:
        _fail(f"x 2^{k} (subnormal pixels): u moved by {np.hypot(*(r.u[e] - base.u[e]))} mm")
    for c in (1e-30, 1e30):  # the tiny and huge values
        rc = pipe.process(img * c)
        _close(rc.G, base.G * c, rtol=1e-12, what=f"G of the frame x {c:g}")
        _close(rc.u, base.u, atol=1e-12, what=f"u of the frame x {c:g}")


def _check_float32_vs_float64(ctx: _Context, rng) -> None:
    e = int(rng.integers(ctx.n_el))
    img = ctx.spot(e, rng.uniform(-0.5, 0.5, 2), float(rng.uniform(0.4, 0.7)), float(rng.uniform(20, 200)))
    img += rng.normal(0.0, 0.5, img.shape) + 10.0
    pipe = ctx.pipeline(**_random_options(rng)).replace(baseline=np.full(ctx.camera.shape, 10.0))
    f32 = img.astype(np.float32)
    r32 = pipe.process(f32)
    _sane(r32, pipe)
    _same_readings(r32, pipe.process(f32.astype(np.float64)), g_rtol=1e-12, u_atol=1e-12,
                   what="float32 vs the same values in float64")
    # against the float64 original: within float32 precision, unless a pixel sits within it of the threshold
    near = np.abs((img - 10.0) - pipe.threshold) < 1e-5 * np.maximum(np.abs(img), 1.0)
    if not near.any() and pipe.filter != "median":
        r64 = pipe.process(img)
        _same_readings(r32, r64, g_rtol=1e-5, u_atol=2e-5, what="float32 vs float64 original")


def _check_non_finite(ctx: _Context, rng) -> None:
    dtype = rng.choice([np.float16, np.float32, np.float64])
    t = int(rng.integers(1, 4))
    st = np.zeros((t,) + ctx.camera.shape, dtype)
    f = int(rng.integers(t))
    row, col = int(rng.integers(ctx.camera.height)), int(rng.integers(ctx.camera.width))
    st[f, row, col] = rng.choice([np.nan, np.inf, -np.inf])
    pipe = ctx.pipeline(**_random_options(rng))
    frames = st if rng.random() < 0.6 else st[f]
    where = f"frame {f if frames.ndim == 3 else 0}, pixel (row {row}, col {col})"
    _expect_error(lambda: pipe.process(frames), (InputError,), "finite", where)
    if rng.random() < 0.3:  # as a baseline
        _expect_error(lambda: pipe.replace(baseline=st), (InputError,), "baseline must be finite")


def _check_too_large(ctx: _Context, rng) -> None:
    v = float(10 ** rng.uniform(100.5, 308)) * float(rng.choice([-1, 1]))
    st = np.zeros(ctx.camera.shape)
    st[int(rng.integers(ctx.camera.height)), int(rng.integers(ctx.camera.width))] = v
    pipe = ctx.pipeline(**_random_options(rng))
    _expect_error(lambda: pipe.process(st), (InputError,), "magnitude at most", "1e+100")
    _expect_error(lambda: estimate_noise(np.stack([st, st * 0.5])), (InputError,), "magnitude at most")


def _check_wrong_shape(ctx: _Context, rng) -> None:
    h, w = ctx.camera.shape
    shapes = [(w,), (h, w + 1), (h - 1, w), (w, h), (1, 1, h, w), (2, h, w, 1), (), (h * w,), (0, w), (h, 0)]
    shape = shapes[int(rng.integers(len(shapes)))]
    arr = np.zeros(shape, rng.choice([np.uint8, np.float64]))
    words = ("for this camera",) if len(shape) in (2, 3) else ("(H, W)", str(shape))
    _expect_error(lambda: ctx.pipe.process(arr), (ShapeError,), *words)


def _check_wrong_dtype(ctx: _Context, rng) -> None:
    h, w = ctx.camera.shape
    kind = int(rng.integers(6))
    arr = [np.zeros((h, w), bool), np.zeros((h, w), complex), np.zeros((h, w), object),
           np.full((h, w), "a"), np.zeros((h, w), "M8[s]"), np.zeros((h, w), "m8[s]")][kind]
    _expect_error(lambda: ctx.pipeline(**_random_options(rng)).process(arr), (TypeError,), "dtype",
                  str(arr.dtype))


def _check_negative_int(ctx: _Context, rng) -> None:
    dtype = rng.choice([np.int8, np.int16, np.int32, np.int64])
    st = np.zeros((2,) + ctx.camera.shape, dtype)
    row, col = int(rng.integers(ctx.camera.height)), int(rng.integers(ctx.camera.width))
    st[1, row, col] = -int(rng.integers(1, 100))
    _expect_error(lambda: ctx.pipe.process(st), (InputError,), "non-negative",
                  f"frame 1, pixel (row {row}, col {col})")


def _check_ragged(ctx: _Context, rng) -> None:
    rows = [[0.0] * ctx.camera.width for _ in range(ctx.camera.height)]
    rows[int(rng.integers(ctx.camera.height))] = [0.0] * int(rng.integers(1, ctx.camera.width))
    _expect_error(lambda: ctx.pipe.process(rows), (TypeError, ValueError), "frames")


def _check_empty_stack(ctx: _Context, rng) -> None:
    dtype = rng.choice([np.uint8, np.float32])
    pipe = ctx.pipeline(**_random_options(rng))
    _expect_error(lambda: pipe.process(np.zeros((0,) + ctx.camera.shape, dtype)), (InputError,), "empty stack")


def _random_frame(ctx: _Context, rng, dtype) -> np.ndarray:
    img = np.zeros(ctx.camera.shape)
    for e in rng.choice(ctx.n_el, size=int(rng.integers(0, 6)), replace=False):
        img += ctx.spot(int(e), rng.uniform(-0.8, 0.8, 2), float(rng.uniform(0.35, 0.7)),
                        float(rng.uniform(2, 150)))
    img += rng.uniform(0, 20) + rng.normal(0.0, rng.uniform(0, 2), img.shape)
    return _as_dtype(np.maximum(img, 0.0), dtype)


def _check_one_frame_stack(ctx: _Context, rng) -> None:
    dtype = rng.choice([np.uint8, np.uint16, np.float32, np.float64])
    frame = _random_frame(ctx, rng, dtype)
    pipe = ctx.pipeline(**_random_options(rng))
    one, st = pipe.process(frame), pipe.process(frame[None])
    if one.is_stack or not st.is_stack or len(st) != 1:
        _fail("a frame must give single readings and a 1-frame stack stack readings of length 1")
    _same_readings(st[0], one, what="(1, H, W) vs (H, W)")


def _check_views(ctx: _Context, rng) -> None:
    dtype = rng.choice([np.uint8, np.uint16, np.float32, np.float64])
    frame = _random_frame(ctx, rng, dtype)
    pipe = ctx.pipeline(**_random_options(rng))
    expected = pipe.process(frame)
    big = np.zeros((frame.shape[0], 2 * frame.shape[1]), frame.dtype)
    big[:, ::2] = frame
    ro = frame.copy()
    ro.flags.writeable = False
    before = frame.copy()
    views = {"strided": big[:, ::2], "fortran": np.asfortranarray(frame), "read-only": ro,
             "reversed": frame[::-1, ::-1].copy()[::-1, ::-1]}
    for name, v in views.items():
        _same_readings(pipe.process(v), expected, what=f"{name} view")
    if not np.array_equal(frame, before):
        _fail("the pipeline modified its input")


def _check_max_uint16(ctx: _Context, rng) -> None:
    img = rng.integers(0, 65536, ctx.camera.shape).astype(np.uint16)
    img[img < 60000] = 0
    img.reshape(-1)[int(rng.integers(img.size))] = 65535
    base = rng.integers(0, 40, ctx.camera.shape).astype(np.uint16)
    pipe = ctx.pipeline(**_random_options(rng), noise_sigma=float(rng.uniform(0, 3))).replace(baseline=base)
    r = pipe.process(img)
    _sane(r, pipe)
    ref = pipe.replace(method="reference" if pipe.method == "fast" else "fast").process(img)
    _same_readings(r, ref, g_rtol=1e-9, u_atol=1e-9, what="fast vs reference on max-range uint16")


def _check_random(ctx: _Context, rng) -> None:
    """Random frames, dtypes and options: fast == reference (independent implementations), invariants hold."""
    dtype = rng.choice([np.uint8, np.uint16, np.float32, np.float64, np.int32, np.float16])
    t = int(rng.integers(1, 4))
    st = np.stack([_random_frame(ctx, rng, dtype) for _ in range(t)])
    opts = _random_options(rng)
    opts.pop("method", None)
    opts["noise_sigma"] = float(rng.choice([0.0, 0.5, rng.uniform(0.1, 3)]))
    opts["k"] = float(rng.choice([3.0, rng.uniform(0, 5)]))
    bkind = int(rng.integers(3))
    if bkind == 1:
        opts["baseline"] = _as_dtype(np.full(ctx.camera.shape, 5.0), dtype)
    elif bkind == 2:
        opts["baseline"] = np.stack([_as_dtype(5.0 + rng.normal(0, 1, ctx.camera.shape), dtype)
                                     for _ in range(3)])
    fast = ctx.pipeline(**opts)
    before = st.copy()
    r = fast.process(st)
    _sane(r, fast)
    if not np.array_equal(st, before):
        _fail("the pipeline modified its input")
    ref = fast.replace(method="reference").process(st)
    scale = max(float(np.abs(r.G).max()), 1.0)
    _same_readings(r, ref, g_rtol=1e-9, u_atol=1e-9 * scale, what="fast vs reference")


_FRAME_CHECKS = {
    "blank": _check_blank, "constant": _check_constant, "noise": _check_noise,
    "saturated_whole": _check_saturated_whole, "saturated_element": _check_saturated_element,
    "hot_pixel": _check_hot_pixel, "scaling": _check_scaling, "float32_vs_float64": _check_float32_vs_float64,
    "non_finite": _check_non_finite, "too_large": _check_too_large, "wrong_shape": _check_wrong_shape,
    "wrong_dtype": _check_wrong_dtype, "negative_int": _check_negative_int, "ragged": _check_ragged,
    "empty_stack": _check_empty_stack, "one_frame_stack": _check_one_frame_stack, "views": _check_views,
    "max_uint16": _check_max_uint16, "random": _check_random,
}


# ============================================================================ readings at the edge
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


def _readings_cases(ctx: _Context, rng: np.random.Generator, n: int) -> list[Case]:
    kinds = [("spot", 4), ("spot_on_border", 3), ("vanishing", 2), ("moments", 2), ("near_threshold", 2)]
    names, w = zip(*kinds, strict=True)
    picks = rng.choice(len(names), size=n, p=np.array(w) / sum(w))
    checks = {"spot": _check_spot, "spot_on_border": _check_spot_on_border, "vanishing": _check_vanishing,
              "moments": _check_moments, "near_threshold": _check_near_threshold}
    return [Case(f"readings/{names[k]}/{i}", "readings", _bind(checks[names[k]], ctx,
                                                               np.random.default_rng(rng.integers(2**63))))
            for i, k in enumerate(picks)]


def _spot_vs_truth(ctx: _Context, e: int, c, s: float, a: float, pipe: Pipeline) -> Readings:
    r = pipe.process(ctx.spot(e, c, s, a))
    _sane(r, pipe)
    g_true, m_true = ctx.spot_truth(e, c, s, a, pipe)
    tol = spot_tolerance(a * 2 * np.pi * s * s, s, float(ctx.footprint[e]))
    _close(r.G[e], g_true, atol=tol, what=f"G of a spot at {np.round(c, 3)} (s={s:.2f})")
    # first moments: the same bound times the farthest lever arm in the region
    _close(r.u[e] * r.G[e], m_true, atol=tol * pipe.grids.radius,
           what=f"first moments of a spot at {np.round(c, 3)} (s={s:.2f})")
    return r


def _check_spot(ctx: _Context, rng) -> None:
    e = int(rng.integers(ctx.n_el))
    s = float(rng.uniform(0.45, 0.7))
    c = rng.uniform(-0.7, 0.7, 2)
    _spot_vs_truth(ctx, e, c, s, float(10 ** rng.uniform(0, 3)), ctx.pipeline(noise_sigma=0.0))


def _check_spot_on_border(ctx: _Context, rng) -> None:
    """A spot centred near the region's edge (radius +- 2 s): G and moments follow the cut region."""
    e = int(rng.integers(ctx.n_el))
    s = float(rng.uniform(0.45, 0.7))
    pipe = ctx.pipeline(noise_sigma=0.0)
    rho = pipe.grids.radius + rng.uniform(-2, 2) * s
    phi = rng.uniform(0, 2 * np.pi)
    _spot_vs_truth(ctx, e, rho * np.array([math.cos(phi), math.sin(phi)]), s, 100.0, pipe)


def _check_vanishing(ctx: _Context, rng) -> None:
    """G -> 0: the centroid stays put (no division blow-up) until G_MIN, then no contact, never NaN."""
    e = int(rng.integers(ctx.n_el))
    img = ctx.spot(e, rng.uniform(-0.5, 0.5, 2), float(rng.uniform(0.45, 0.7)), 1.0)
    pipe = ctx.pipeline(noise_sigma=0.0)
    ref = pipe.process(img)
    for k in sorted(rng.integers(0, 1070, 6)):
        r = pipe.process(np.ldexp(img, -int(k)))
        _sane(r, pipe)
        g = ref.G[e] * 2.0**-int(k)
        if g > 1e-240:
            if not r.contact[e]:
                _fail(f"G = {g:.3g} must read contact on a noiseless pipeline")
            _close(r.u[e], ref.u[e], atol=1e-12, what=f"u at G = {g:.3g}")
        elif g < G_MIN * 1e-3 and r.contact[e]:
            _fail(f"G = {r.G[e]:.3g} (subnormal sums) reads contact")


def _check_moments(ctx: _Context, rng) -> None:
    """readings_from_moments on sums from zero through subnormal to huge: contact rule exact, never NaN."""
    shape = (int(rng.integers(1, 4)), 5)
    pool = np.array([0.0, -0.0, 5e-324, 1e-310, G_MIN, 1e-240, 1e-200, 1.0, 1e150, 1e300, -1.0, 3.0])
    G = rng.choice(pool, shape)
    frac = rng.choice([1.0, 0.5, 1e-10, 0.0], shape) if rng.random() < 0.5 else None
    W = None if frac is None else G * frac
    u0 = rng.uniform(-2, 2, shape + (2,))
    M = (G if W is None else W)[..., None] * u0
    floor = rng.choice([0.0, 0.5, 1e-300], 5)
    r = readings_from_moments(G, M, np.zeros(shape, bool), floor, weight=W)
    if not (np.isfinite(r.G).all() and np.isfinite(r.u).all()):
        _fail("readings_from_moments gave NaN/inf")
    want = (G > floor) & (G > G_MIN)
    if not np.array_equal(r.contact, want):
        _fail("contact must be G > floor and G > G_MIN")
    w = G if W is None else W
    good = want & (w > 1e-290)
    _close(r.u[good], u0[good], rtol=1e-12, what="u = M / weight")
    if np.any(r.u[~want] != 0) or np.any(r.G[~want] != 0):
        _fail("no contact must read G = 0, u = 0")


def _check_near_threshold(ctx: _Context, rng) -> None:
    """Spots whose peak sits near the threshold, with noise: G is 0 or above the floor, u inside the region."""
    e = int(rng.integers(ctx.n_el))
    pipe = ctx.pipeline(noise_sigma=float(rng.uniform(0.3, 2.0)), filter=str(rng.choice(["none", "gaussian"])))
    img = ctx.spot(e, rng.uniform(-1.5, 1.5, 2), float(rng.uniform(0.3, 0.8)),
                   pipe.threshold * rng.uniform(0.5, 3))
    st = img + rng.normal(0.0, pipe.noise_sigma, (4,) + img.shape)
    dtype = rng.choice([np.float64, np.float32])
    r = pipe.process(st.astype(dtype))
    _sane(r, pipe)
    _same_readings(r, pipe.replace(method="reference").process(st.astype(dtype)), g_rtol=1e-9,
                   u_atol=1e-9, what="fast vs reference near the threshold")


# ============================================================================ calibration fits
def _fit_cases(ctx: _Context, rng: np.random.Generator, n: int) -> list[Case]:
    kinds = [("valid", 3), ("duplicates", 1), ("constant", 1), ("too_few", 1), ("ill_conditioned", 1),
             ("no_shear", 0.5), ("non_finite", 1), ("bad_types", 0.5), ("clamp", 2)]
    names, w = zip(*kinds, strict=True)
    picks = rng.choice(len(names), size=n, p=np.array(w) / sum(w))
    return [Case(f"calibration_fit/{names[k]}/{i}", "calibration_fit",
                 _bind(_check_fit, ctx, np.random.default_rng(rng.integers(2**63)), names[k]))
            for i, k in enumerate(picks)]


def _check_fit(ctx: _Context, rng, kind: str) -> None:
    from optitact.calib import Calibration

    n = int(rng.integers(10, 80))
    f_scale = float(10 ** rng.uniform(-3, 3)) if kind == "valid" else 1.0
    forces, r = _analytic_set(rng, n, gain=float(10 ** rng.uniform(-5, 5)), h=float(rng.uniform(1, 5)),
                              c=float(rng.uniform(0, 0.5)), f_scale=f_scale)
    model = str(rng.choice(["coupled", "ohka"]))
    kw = dict(sensor=ctx.lone, camera=ctx.camera, model=model)

    def fit(readings, f):
        return Calibration.fit(readings, f, **kw)

    def with_(G=None, u=None):
        return Readings(r.G if G is None else G, r.u if u is None else u, r.contact, r.saturated)

    if kind == "valid":
        cal = fit(r, forces)
        est, clamped = cal.forces(r)
        if not np.isfinite(est).all() or clamped.any():
            _fail("fitted on exact data: non-finite forces or clamped readings inside the range")
        if model == "coupled":
            _close(est, forces, atol=1e-4 * float(np.abs(forces).max()),
                   what=f"coupled fit on exact coupled data (forces x {f_scale:.3g})")
        else:
            _close(est[..., 2], forces[..., 2], atol=1e-4 * float(forces[..., 2].max()), what="ohka Fz")
    elif kind == "duplicates":
        k = int(rng.integers(1, 4))
        idx = rng.integers(0, k, n)
        f2, r2 = forces[idx], r[idx]
        _expect_error(lambda: fit(r2, f2), (InputError,), "element 0", "do not vary" if k == 1 else "distinct")
    elif kind == "constant":
        which = int(rng.integers(3))
        if which == 0:
            _expect_error(lambda: fit(with_(G=np.full_like(r.G, 7.0)), forces), (InputError,), "do not vary")
        elif which == 1:
            _expect_error(lambda: fit(with_(u=np.zeros_like(r.u) + 0.3), forces), (InputError,), "do not vary")
        else:
            f2 = forces.copy()
            f2[..., 2] = 0.5
            _expect_error(lambda: fit(r, f2), (InputError,), "normal forces", "spans")
    elif kind == "too_few":
        m = int(rng.integers(0, 8))
        _expect_error(lambda: fit(r[:m], forces[:m]), (InputError,), f"{m} usable samples", "at least 8")
    elif kind == "ill_conditioned":
        eps = float(10 ** rng.uniform(-13, -7))
        if rng.random() < 0.5:
            g = 1000.0 * (1.0 + eps * rng.random(r.G.shape))
            _expect_error(lambda: fit(with_(G=g), forces), (InputError,), "ill-conditioned")
        else:
            u = 5.0 + eps * 5.0 * rng.random(r.u.shape)
            _expect_error(lambda: fit(with_(u=u), forces), (InputError,), "ill-conditioned")
    elif kind == "no_shear":
        f2 = forces.copy()
        f2[..., :2] = 0.0
        _expect_error(lambda: fit(r, f2), (InputError,), "shear")
    elif kind == "non_finite":
        bad = float(rng.choice([np.nan, np.inf, -np.inf]))
        which = int(rng.integers(3))
        if which == 0:
            f2 = forces.copy()
            f2[int(rng.integers(n)), 0, int(rng.integers(3))] = bad
            _expect_error(lambda: fit(r, f2), (InputError,), "finite")
        elif which == 1:
            g = r.G.copy()
            g[int(rng.integers(n)), 0] = bad
            _expect_error(lambda: fit(with_(G=g), forces), (InputError,), "finite")
        else:
            u = r.u.copy()
            u[0, 0, int(rng.integers(2))] = bad
            _expect_error(lambda: ctx.calibration.forces(with_(u=u)[0]), (InputError,), "finite")
    elif kind == "bad_types":
        which = int(rng.integers(3))
        if which == 0:
            _expect_error(lambda: fit(r, forces.astype(complex)), (TypeError,), "forces", "complex")
        elif which == 1:
            _expect_error(lambda: fit(r[0], forces[0]), (TypeError,), "stack Readings")
        else:
            _expect_error(lambda: fit(r, forces[:-1]), (ShapeError,), "forces must have shape")
    elif kind == "clamp":
        cal = ctx.calibration
        t = int(rng.integers(1, 5))
        k_g, k_u = 10 ** rng.uniform(-0.5, 6, (t, 1)), 10 ** rng.uniform(-0.5, 6, (t, 1))
        ang = rng.uniform(0, 2 * np.pi, (t, 1))
        G = cal.g_max * k_g
        u = np.stack([np.cos(ang), np.sin(ang)], -1) * (cal.u_max * k_u)[..., None]
        rr = Readings(G, u, np.ones((t, 1), bool), np.zeros((t, 1), bool))
        est, clamped = cal.forces(rr)
        if not np.isfinite(est).all():
            _fail("forces of readings beyond the fitted range are not finite")
        beyond = (k_g > 1) | (k_u > 1)
        if not np.array_equal(clamped, beyond):
            _fail(f"clamped flags {clamped.ravel()} != beyond-range {beyond.ravel()}")
        at = Readings(np.minimum(G, cal.g_max), u * np.minimum(1.0, 1.0 / k_u)[..., None], rr.contact,
                      rr.saturated)
        _close(est, cal.forces(at)[0], rtol=1e-9, atol=1e-12,
               what="clamped forces vs forces at the range's edge")


# ============================================================================ calibration files
def _file_cases(ctx: _Context, rng: np.random.Generator, n: int) -> list[Case]:
    kinds = [("valid", 1), ("truncated", 3), ("garbage", 1), ("pickle", 0.5), ("deep_nesting", 0.3),
             ("huge_number", 0.5), ("nan_literal", 0.5), ("wrong_version", 1), ("wrong_schema", 1),
             ("missing_key", 2), ("mutated", 6), ("wrong_sensor", 1), ("edited_sensor", 1), ("oversized", 0.1)]
    names, w = zip(*kinds, strict=True)
    picks = rng.choice(len(names), size=n, p=np.array(w) / sum(w))
    return [Case(f"calibration_file/{names[k]}/{i}", "calibration_file",
                 _bind(_check_file, ctx, np.random.default_rng(rng.integers(2**63)), names[k], i))
            for i, k in enumerate(picks)]


_JSON_VALUES = (None, True, False, 0, -1, 1e308, -1e-308, 3.5, "", "x", [], [1, 2], {}, {"a": 1}, [[0.0] * 4],
                10**400, "NaN")


def _leaves(d, path=()):
    if isinstance(d, dict):
        yield path, d
        for k, v in d.items():
            yield from _leaves(v, path + (k,))
    elif isinstance(d, list):
        yield path, d
        for i, v in enumerate(d):
            yield from _leaves(v, path + (i,))
    else:
        yield path, d


def _set_path(d, path, value):
    for k in path[:-1]:
        d = d[k]
    d[path[-1]] = value


def _loaded_is_sane(cal, doc) -> None:
    """A calibration that loaded must give finite forces and hold the document's numbers."""
    for name in ("g", "g_scale", "f", "u_scale", "g_max", "u_max", "gu"):
        _close(getattr(cal, name), np.array(doc["elements"][name], dtype=np.float64), rtol=0,
               what=f"loaded elements[{name!r}]")
    rng = np.random.default_rng(0)
    G = np.concatenate([[0.0], np.minimum(cal.g_max, 1e300) * rng.uniform(0, 2, 6)])[:, None]
    u = rng.normal(0.0, 1.0, (7, 1, 2)) * np.minimum(cal.u_max, 1e300)[:, None]
    est, _ = cal.forces(Readings(G, u, G > 0, np.zeros_like(G, bool)))
    if not np.isfinite(est).all() or np.any(est[..., 2] < 0):
        _fail("a calibration that loads gives non-finite or negative normal forces")


def _check_file(ctx: _Context, rng, kind: str, i: int) -> None:
    from optitact.calib import Calibration, CalibrationMismatchError

    cal = ctx.calibration
    doc = json.loads(json.dumps(ctx._cal_doc))
    path = ctx.tmp / f"cal-{i % 16}.json"
    text = json.dumps(doc)

    def load(**kw):
        return Calibration.load(path, **kw)

    errors = (InputError,)
    if kind == "valid":
        path.write_text(text)
        back = load(sensor=ctx.lone, camera=ctx.camera)
        _loaded_is_sane(back, doc)
        if back.fingerprint != cal.fingerprint:
            _fail("a saved calibration reloads with another fingerprint")
    elif kind == "truncated":
        path.write_text(text[:int(rng.integers(0, len(text) - 1))])
        _expect_error(load, errors, "not a JSON calibration")
    elif kind == "garbage":
        path.write_bytes(rng.integers(0, 256, int(rng.integers(1, 4000)), dtype=np.uint8).tobytes())
        _expect_error(load, errors)
    elif kind == "pickle":
        marker = ctx.tmp / f"executed-{i}"
        path.write_bytes(pickle.dumps(_Touch(str(marker))) if rng.random() < 0.5 else
                         b"__import__('pathlib').Path(%r).touch()" % str(marker).encode())
        _expect_error(load, errors, "not a JSON calibration")
        if marker.exists():
            _fail("loading a calibration executed code from the file")
    elif kind == "deep_nesting":
        depth = int(rng.integers(10_000, 200_000))
        deep = "[" * depth + "]" * depth if rng.random() < 0.5 else '{"a":' * depth + "1" + "}" * depth
        path.write_text(deep)
        _expect_error(load, errors)
    elif kind == "huge_number":  # beyond float64 (>= 310 digits) or Python's int parsing (> 4300)
        leaves = [p for p, v in _leaves(doc) if isinstance(v, float)]
        _set_path(doc, leaves[int(rng.integers(len(leaves)))], "__BIG__")
        path.write_text(json.dumps(doc).replace('"__BIG__"', "9" * int(rng.integers(310, 6000))))
        _expect_error(load, errors)
    elif kind == "nan_literal":
        leaves = [p for p, v in _leaves(doc) if isinstance(v, float)]
        _set_path(doc, leaves[int(rng.integers(len(leaves)))], float(rng.choice([np.nan, np.inf, -np.inf])))
        path.write_text(json.dumps(doc))
        _expect_error(load, errors, "not a JSON calibration")
    elif kind == "wrong_version":
        doc["schema_version"] = [0, 2, "1", None, True, 1.5, [1]][int(rng.integers(7))]
        path.write_text(json.dumps(doc))
        _expect_error(load, errors, "schema version")
    elif kind == "wrong_schema":
        which = int(rng.integers(3))
        if which == 0:
            doc["schema"] = ["other", None, 1, ""][int(rng.integers(4))]
            path.write_text(json.dumps(doc))
            _expect_error(load, errors, "not an optitact calibration")
        else:
            path.write_text(json.dumps([doc] if which == 1 else "calibration"))
            _expect_error(load, errors, "JSON object")
    elif kind == "missing_key":
        top = ("model", "sensor", "camera", "pipeline", "elements", "fingerprint", "schema")
        keys = [p for p, _ in _leaves(doc) if len(p) in (1, 2) and p[0] in top]
        p = keys[int(rng.integers(len(keys)))]
        parent = doc
        for k in p[:-1]:
            parent = parent[k]
        del parent[p[-1]]
        path.write_text(json.dumps(doc))
        try:
            back = load()
        except (InputError, CalibrationMismatchError) as exc:
            if not str(exc):
                _fail("an error without a message")
        else:  # a sensor or camera key equal to its default may go: the result must be the same
            if len(p) != 2 or p[0] not in ("sensor", "camera") or back.sensor != cal.sensor \
                    or back.camera != cal.camera:
                _fail(f"a calibration without {p} loaded as another calibration")
    elif kind == "mutated":
        paths = [p for p, _ in _leaves(doc) if p]
        p = paths[int(rng.integers(len(paths)))]
        _set_path(doc, p, json.loads(json.dumps(_JSON_VALUES[int(rng.integers(len(_JSON_VALUES)))]))
                  if rng.random() < 0.7 else float(rng.normal() * 10 ** rng.uniform(-3, 3)))
        try:
            path.write_text(json.dumps(doc))
        except ValueError:  # an int too long for json.dumps' digit limit
            return
        try:
            back = load()
        except (InputError, CalibrationMismatchError) as exc:
            if not str(exc):
                _fail("an error without a message")
        else:
            _loaded_is_sane(back, doc)
    elif kind == "wrong_sensor":
        path.write_text(text)
        if rng.random() < 0.5:
            other = DomeSensor(ring_counts=(1,), ring_polar_deg=(0.0,), outer_radius=float(rng.uniform(15, 19)))
            _expect_error(lambda: load(sensor=other), (CalibrationMismatchError,), "another sensor")
        else:
            other = FisheyeCamera(width=int(rng.integers(40, 300)), height=int(rng.integers(30, 200)))
            if other == ctx.camera:
                return
            _expect_error(lambda: load(camera=other), (CalibrationMismatchError,), "camera")
    elif kind == "edited_sensor":
        key = str(rng.choice(["outer_radius", "lever_arm", "cone_circle_radius"]))
        doc["sensor"][key] = float(doc["sensor"][key]) * float(rng.uniform(1.01, 1.2))
        path.write_text(json.dumps(doc))
        _expect_error(load, (CalibrationMismatchError, InputError), "")
    elif kind == "oversized":
        from optitact.calib.fit import MAX_FILE_BYTES

        with path.open("w") as fh:
            fh.write(text + " " * (MAX_FILE_BYTES + 1 - len(text)))
        _expect_error(load, errors, "too large")


class _Touch:
    """Unpickling this would create a file: the calibration loader must never unpickle."""

    def __init__(self, path: str) -> None:
        self.path = path

    def __reduce__(self):
        return (Path.touch, (Path(self.path),))


# ============================================================================ accumulation
def _accumulation_cases(ctx: _Context, rng: np.random.Generator, n: int, *, long_rows: int) -> list[Case]:
    kinds = [("fsum", 3), ("batch", 2), ("baseline_mean", 2), ("noise_estimate", 2), ("stream", 1)]
    names, w = zip(*kinds, strict=True)
    picks = rng.choice(len(names), size=max(n - 1, 0), p=np.array(w) / sum(w))
    checks = {"fsum": _check_fsum, "batch": _check_batch, "baseline_mean": _check_baseline_mean,
              "noise_estimate": _check_noise_estimate, "stream": _check_stream}
    cases = [Case(f"accumulation/{names[k]}/{i}", "accumulation",
                  _bind(checks[names[k]], ctx, np.random.default_rng(rng.integers(2**63))))
             for i, k in enumerate(picks)]
    if n >= 1:
        sub = np.random.default_rng(rng.integers(2**63))
        cases.append(Case(f"accumulation/long_stream_csv/{long_rows}_rows", "accumulation",
                          _bind(_check_long_stream, ctx, sub, long_rows)))
    return cases


def _check_fsum(ctx: _Context, rng) -> None:
    """G per region against math.fsum of the same terms: within float64 summation rounding."""
    img = np.zeros(ctx.camera.shape) + 10 ** rng.uniform(-3, 2, ctx.camera.shape)
    hot = rng.random(ctx.camera.shape) < 0.01
    img[hot] = 10 ** rng.uniform(6, 14, hot.sum())
    pipe = ctx.pipeline(noise_sigma=0.0)
    r = pipe.process(img)
    fold = pipe._fold
    terms = fold.weights[0] * img.reshape(-1)[fold.pixel]
    eps = np.finfo(np.float64).eps
    for e in range(ctx.n_el):
        t = terms[fold.label == e].tolist()
        exact = math.fsum(t)
        bound = len(t) * eps * math.fsum(abs(x) for x in t)
        if abs(r.G[e] - exact) > bound:
            _fail(f"G[{e}] = {r.G[e]!r} vs fsum {exact!r}: off by {abs(r.G[e] - exact):.3g} > {bound:.3g}")


def _check_batch(ctx: _Context, rng) -> None:
    """A big batch (chunks of CHUNK_FRAMES) reads bit for bit as frame by frame."""
    t = int(rng.integers(1, 3 * CHUNK_FRAMES + 2))
    scenes = np.stack([_random_frame(ctx, rng, np.uint8) for _ in range(3)])
    st = scenes[rng.integers(0, 3, t)]
    pipe = ctx.pipeline(filter=str(rng.choice(["none", "none", "gaussian"])))
    rs = pipe.process(st)
    singles = {k: pipe.process(scenes[k]) for k in range(3)}
    for k in range(3):
        rows = np.flatnonzero((st == scenes[k]).all(axis=(1, 2)))
        for i in rows[:: max(1, len(rows) // 8)]:
            _same_readings(rs[int(i)], singles[k], what=f"frame {i} of a {t}-frame batch")


def _check_baseline_mean(ctx: _Context, rng) -> None:
    """The baseline mean of T float frames: within 2 ulp of math.fsum / T, for offsets up to 1e8."""
    t = int(rng.integers(2, 300))
    offset = float(10 ** rng.uniform(0, 8))
    st = offset + rng.normal(0.0, 1.0, (t,) + ctx.camera.shape)
    pipe = ctx.pipe.replace(baseline=st)
    idx = rng.integers(0, st[0].size, 40)
    flat = st.reshape(t, -1)
    for p in idx:
        exact = math.fsum(flat[:, p].tolist()) / t
        got = pipe.baseline.reshape(-1)[p]
        if abs(got - exact) > 2 * np.spacing(abs(exact)):
            _fail(f"baseline mean of {t} frames off by {abs(got - exact) / np.spacing(abs(exact)):.1f} ulp")


def _check_noise_estimate(ctx: _Context, rng) -> None:
    """estimate_noise over long stacks: the exact (fsum) value to 1e-12 relative."""
    t = int(rng.integers(2, 20000))
    offset = float(10 ** rng.uniform(0, 6))
    st = offset + rng.normal(0.0, 10 ** rng.uniform(-2, 1), (t, 3, 4))
    flat = st.reshape(t, -1)
    var = []
    for p in range(flat.shape[1]):
        col = flat[:, p].tolist()
        m = math.fsum(col) / t
        var.append(math.fsum((x - m) ** 2 for x in col) / (t - 1))
    exact = math.sqrt(math.fsum(var) / len(var))
    _close(estimate_noise(st), exact, rtol=1e-12, what=f"estimate_noise of {t} frames")


def _check_stream(ctx: _Context, rng) -> None:
    """Pipeline.stream frame by frame == the batch, with the first frames as baseline."""
    t = int(rng.integers(3, 40))
    nb = int(rng.integers(0, 3))
    frames = [_random_frame(ctx, rng, np.uint8) for _ in range(t)]
    out = list(ctx.pipe.stream(iter(frames), baseline_frames=nb))
    pipe = ctx.pipe if nb == 0 else ctx.pipe.with_baseline(np.stack(frames[:nb]))
    _same_readings(Readings.stack(out), pipe.process(np.stack(frames)), what="stream vs batch")


def _check_long_stream(ctx: _Context, rng, rows: int) -> None:
    """A long stream of readings through the CSV writer: every value, and the sums, exact."""
    import csv

    from .io import ReadingsWriter

    t = max(1, rows // ctx.n_el)
    G = np.where(rng.random((t, ctx.n_el)) < 0.7, 10 ** rng.uniform(-3, 5, (t, ctx.n_el)), 0.0)
    u = np.where((G > 0)[..., None], rng.normal(0, 0.5, (t, ctx.n_el, 2)), 0.0)
    r = Readings(G, u, G > 0, np.zeros_like(G, bool))
    path = ctx.tmp / "stream.csv"
    with ReadingsWriter(path) as w:
        for i in range(0, t, 4096):
            w.write(r[i:i + 4096], [f"f{k}" for k in range(i, min(t, i + 4096))])
    with path.open(newline="") as fh:
        rd = csv.reader(fh)
        next(rd)
        back = np.array([float(row[3]) for row in rd])
    if back.shape != (t * ctx.n_el,) or not np.array_equal(back, G.reshape(-1)):
        _fail("readings written to CSV do not read back bit for bit")
    if math.fsum(back.tolist()) != math.fsum(G.reshape(-1).tolist()):
        _fail("the sum of G over the CSV differs from the sum over the readings")


# ============================================================================ CCD
def _ccd_cases(ctx: _Context, rng: np.random.Generator, n: int) -> list[Case]:
    return [Case(f"ccd/{'params' if i % 3 == 0 else 'expose'}/{i}", "ccd",
                 _bind(_check_ccd_params if i % 3 == 0 else _check_ccd_expose,
                       np.random.default_rng(rng.integers(2**63))))
            for i in range(n)]


_CCD_FIELDS = ("exposure", "full_well", "read_noise", "dark_offset", "bits", "gain")


def _check_ccd_params(rng) -> None:
    field = _CCD_FIELDS[int(rng.integers(len(_CCD_FIELDS)))]
    bad = [np.nan, np.inf, -1.0, "3", True, None, 1e308, 5e-324, 0.0, 7, 1e19][int(rng.integers(11))]
    kw = {field: bad}
    try:
        ccd = CCD(**kw)
    except TypeError as exc:
        if field not in str(exc):
            _fail(f"CCD({field}={bad!r}): TypeError not naming the field: {exc}")
        return
    except InputError as exc:
        if field not in str(exc) and "gain" not in str(exc):
            _fail(f"CCD({field}={bad!r}): InputError not naming the field: {exc}")
        return
    # accepted: the model must work without overflow on a range of radiance
    rad = np.array([[0.0, 1e-3, 1.0, 1e3, 1e300]])
    for out in (ccd.expose(rad, seed=0), ccd.mean_dn(rad), ccd.variance_dn(rad)):
        if not np.isfinite(np.asarray(out, np.float64)).all():
            _fail(f"CCD({field}={bad!r}) gives non-finite output")


def _check_ccd_expose(rng) -> None:
    bits = int(rng.choice([8, 10, 12, 16]))
    ccd = CCD(exposure=float(10 ** rng.uniform(0, 6)), full_well=float(10 ** rng.uniform(2, 6)),
              read_noise=float(rng.uniform(0, 30)), bits=bits, dark_offset=float(rng.uniform(0, 50)))
    which = int(rng.integers(4))
    if which == 0:  # bad radiance
        bad = [np.full((3, 3), np.nan), -np.ones((3, 3)), np.zeros(4), np.zeros((3, 3), complex),
               np.zeros((2, 2, 2, 2)), [[1.0, 2.0], [3.0]]][int(rng.integers(6))]
        _expect_error(lambda: ccd.expose(bad, seed=0), (InputError, ShapeError, TypeError), "radiance")
        return
    lum = float(10 ** rng.uniform(-4, 1)) * ccd.radiance_at_saturation
    rad = np.full((48, 48), lum)
    before = rad.copy()
    frame = ccd.expose(rad, seed=int(rng.integers(2**31)))
    top = 2**bits - 1
    if frame.dtype != (np.uint8 if bits == 8 else np.uint16) or frame.shape != rad.shape:
        _fail(f"expose gave {frame.dtype} {frame.shape}")
    if frame.max() > top or not np.array_equal(rad, before):
        _fail("expose exceeded the ADC range or modified its input")
    mu, var = float(ccd.mean_dn(rad)[0, 0]), float(ccd.variance_dn(rad)[0, 0])
    sd = math.sqrt(var)
    if sd > 1.0 and mu - 6 * sd > 0 and mu + 6 * sd < top and lum * ccd.exposure < ccd.full_well - 6 * sd / \
            ccd.dn_per_electron:
        x = frame.astype(np.float64)
        n = x.size
        if abs(x.mean() - mu) > 6 * sd / math.sqrt(n) + 0.05:
            _fail(f"mean DN {x.mean():.4g} vs the model's {mu:.4g} (sd {sd:.3g})")
        if not 0.6 * var < x.var(ddof=1) < 1.5 * var:
            _fail(f"DN variance {x.var(ddof=1):.4g} vs the model's {var:.4g}")


# ============================================================================ contact and renderer inputs
def _contact_cases(ctx: _Context, rng: np.random.Generator, n: int) -> list[Case]:
    return [Case(f"contact_render/{('contact', 'bad_forces', 'render_input')[i % 3]}/{i}", "contact_render",
                 _bind((_check_contact, _check_bad_forces, _check_render_input)[i % 3], ctx,
                       np.random.default_rng(rng.integers(2**63))))
            for i in range(n)]


def _check_contact(ctx: _Context, rng) -> None:
    """Valid forces, from subnormal to MAX_FORCE_N and pulling: finite patches, balanced loads."""
    s = ctx.sensor
    mag = 10 ** rng.uniform(-320, math.log10(MAX_FORCE_N), (s.n_elements, 3))
    f = mag * rng.choice([-1.0, 1.0, 0.0], (s.n_elements, 3), p=[0.3, 0.6, 0.1])
    c = contact_patches(s, f)
    for name in ("centers", "radii", "loads", "slide"):
        if not np.isfinite(getattr(c, name)).all():
            _fail(f"contact {name} not finite for forces up to {np.abs(f).max():.3g} N")
    if np.any(c.radii < 0) or np.any(c.radii > s.cone_base_radius * (1 + 1e-12)) or np.any(c.loads < 0):
        _fail("negative loads or radii beyond the cone base")
    fz = np.maximum(f[:, 2] + s.preload, 0.0)
    _close(c.loads.sum(axis=1), fz, rtol=1e-9, atol=1e-300, what="sum of cone loads vs Fz")
    pull = f[:, 2] + s.preload <= 0
    if np.any(c.radii[pull] != 0) or np.any(c.tipped[pull]):
        _fail("pulling elements must have no contact")


def _bad_forces(rng, n_el: int):
    kind = int(rng.integers(8))
    f = np.zeros((n_el, 3))
    if kind == 0:
        f[int(rng.integers(n_el)), int(rng.integers(3))] = rng.choice([np.nan, np.inf, -np.inf])
        return f, (InputError,), ("finite",)
    if kind == 1:
        big = float(rng.choice([-1, 1]) * 10 ** rng.uniform(6.01, 308))
        f[int(rng.integers(n_el)), int(rng.integers(3))] = big
        return f, (InputError,), ("at most", "N")
    if kind == 2:
        shape = [(n_el,), (n_el, 2), (n_el - 1, 3), (3, n_el), (1, n_el, 3), ()][int(rng.integers(6))]
        return np.zeros(shape), (ShapeError,), ("must have shape", f"({n_el}, 3)")
    if kind == 3:
        return np.zeros((n_el, 3), [bool, complex, object][int(rng.integers(3))]), (TypeError,), ("real",)
    if kind == 4:
        return [[0.0, 0.0, 1.0]] * (n_el - 1) + [[0.0, 1.0]], (TypeError, ValueError), ("forces",)
    if kind == 5:
        return "forces.csv", (TypeError,), ("real",)
    if kind == 6:
        return None, (TypeError,), ("real",)
    return np.full((n_el, 3), np.nan), (InputError,), ("finite",)


def _check_bad_forces(ctx: _Context, rng) -> None:
    f, types, words = _bad_forces(rng, ctx.n_el)
    _expect_error(lambda: check_forces(f, ctx.sensor), types, *words)
    _expect_error(lambda: contact_patches(ctx.sensor, f), types, *words)


_RENDER_BAD = {  # option -> [(value, error types, words the message must name)]
    "spp": [(0, (InputError,), ("spp", ">= 1")), (-3, (InputError,), ("spp", ">= 1")),
            (1.5, (TypeError,), ("spp", "integer")), (True, (TypeError,), ("spp", "integer")),
            ("4", (TypeError,), ("spp", "integer")), (None, (TypeError,), ("spp",))],
    "seed": [(-1, (InputError,), ("seed",)), (1.5, (TypeError,), ("seed",)), (None, (InputError,), ("seed",)),
             ("0", (TypeError,), ("seed",))],
    "camera": [(object(), (TypeError,), ("camera", "FisheyeCamera")), ("cam", (TypeError,), ("camera",))],
    "settings": [({"spp": 4}, (TypeError,), ("settings", "RenderSettings"))],
    "transport": [("bidir", (InputError,), ("transport",)), ("", (InputError,), ("transport",))],
    "crop": [((0, 0, 0, 5), (InputError,), ("crop",)), ((0, 0, 99, 5), (InputError,), ("crop",)),
             ((-1, 0, 2, 2), (InputError,), ("crop",)), ((0, 0, 2), (InputError,), ("crop",)),
             ((0.5, 0, 2, 2), (TypeError,), ("crop",)), (5, (TypeError, InputError), ("crop",))],
    "pixels": [("uint8", (TypeError,), ("pixels", "bool")), ("3x3", (InputError,), ("pixels", "shape"))],
    "background": [(np.nan, (InputError,), ("background", "finite")),
                   ("3x3", (InputError,), ("background", "shape")),
                   ("complex", (TypeError,), ("background",)), (-1.0, (InputError,), ("background",)),
                   (1e300, (InputError,), ("background",))],
    "target_error": [(0.0, (InputError,), ("target_error",)), (-0.1, (InputError,), ("target_error",)),
                     (np.nan, (InputError,), ("target_error",))],
    "max_spp": [(16, (InputError,), ("max_spp",))],
    "variant": [("no_such_variant", (InputError,), ("variant",)), (7, (TypeError,), ("variant",))],
    "n_sub": [(0, (InputError,), ("n_sub",)), (2.5, (TypeError,), ("n_sub",))],
    "table": [("table.npz", (TypeError,), ("table", "EmissionTable"))],
    "two_stage_pixels": [(True, (InputError,), ("pixels",))],
}


def _check_render_input(ctx: _Context, rng) -> None:
    """Bad renderer inputs: a clear error before Mitsuba (or Dr.Jit) is imported."""
    from optitact.render import render

    cam = FisheyeCamera(width=32, height=24)
    forces = np.zeros((ctx.n_el, 3))
    forces[0, 2] = 0.5
    kw: dict = {"camera": cam, "spp": 1}
    option = str(rng.choice(["forces"] + sorted(_RENDER_BAD)))
    if option == "forces":
        forces, types, words = _bad_forces(rng, ctx.n_el)
    else:
        value, types, words = _RENDER_BAD[option][int(rng.integers(len(_RENDER_BAD[option])))]
        if option == "pixels":
            value = np.ones(cam.shape, np.uint8) if value == "uint8" else np.ones((3, 3), bool)
        elif option == "background":
            kw["pixels"] = np.ones(cam.shape, bool)
            value = {"3x3": np.zeros((3, 3)), "complex": np.zeros(cam.shape, complex)}.get(value) \
                if isinstance(value, str) else np.full(cam.shape, value)
        elif option == "max_spp":
            kw.update(target_error=0.01, spp=64)
        elif option in ("n_sub", "table", "two_stage_pixels"):
            kw["transport"] = "two_stage"
            if option == "two_stage_pixels":
                option, value = "pixels", np.ones(cam.shape, bool)
        kw[option] = value
    with _Guard():
        _expect_error(lambda: render(ctx.sensor, forces, **kw), types, *words)


# ============================================================================ the noise sweep
def _quantised_pmf(lam: float, ccd: CCD) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distribution of one pixel's DN for a mean charge ``lam`` (electrons), exactly as the CCD model draws it.

    Returns ``(d, P, dP)``: the DN values, their probabilities and the
    derivative of the probabilities with respect to ``lam`` (Poisson shot
    noise, full-well clip, Gaussian read noise, rounding and the ADC clip).
    """
    from scipy.special import ndtr
    from scipy.stats import poisson

    g, o, sr, top, fw = ccd.dn_per_electron, ccd.dark_offset, ccd.read_noise, 2**ccd.bits - 1, ccd.full_well
    sd = math.sqrt(lam) + 1.0
    k = np.arange(max(0, int(lam - 10 * sd - 5)), int(lam + 10 * sd + 7), dtype=np.float64)
    pk = poisson.pmf(k, lam)
    lo = max(0, int(math.floor(g * (min(k[0], fw) - 9 * sr - 1) + o)) - 1)
    hi = min(top, int(math.ceil(g * (min(k[-1] + 1, fw) + 9 * sr + 1) + o)) + 1)
    d = np.arange(lo, hi + 1, dtype=np.float64)

    def q(kv):  # P(DN == d | k electrons)
        kv = np.minimum(kv, fw)[:, None]
        up = np.where(d[None] >= top, np.inf, (d[None] + 0.5 - o) / g - kv)
        dn = np.where(d[None] <= 0, -np.inf, (d[None] - 0.5 - o) / g - kv)
        if sr > 0:
            return ndtr(up / sr) - ndtr(dn / sr)
        return ((dn < 0) & (up >= 0)).astype(np.float64)

    qk = q(k)
    return d, pk @ qk, pk @ (q(k + 1.0) - qk)


@dataclass
class _SpotModel:
    """A Gaussian spot drawn in a window of the image, its pixel weights in the pipeline, and its noise."""

    sensor: DomeSensor
    camera: FisheyeCamera
    ccd: CCD
    pipe: Pipeline
    element: int
    window: tuple[int, int, int, int]   # r0, r1, c0, c1
    xy: np.ndarray                      # (h, w, 2) tangent offsets of the window's pixels
    entries: np.ndarray                 # flat window index of each of the element's fold entries
    weights: np.ndarray                 # (3, n) fold weights (area, area x, area y) of those entries
    base: np.ndarray                    # (n,) baseline of those entries
    thr: np.ndarray                     # (n,) threshold of those entries

    @classmethod
    def build(cls, sensor, camera, ccd, element, *, margin_mm=4.0):
        pipe = Pipeline(sensor, camera, baseline=np.full(camera.shape, ccd.dark_offset))
        fold = pipe._fold
        sel = fold.label == element
        pix = fold.pixel[sel]
        rows, cols = np.divmod(pix, camera.width)
        cen = camera.project(sensor.element_positions[element], sensor)
        half = int(math.ceil(margin_mm / (pipe.grids.grid_mm * 2.5))) + 2
        r0 = int(max(0, min(rows.min(), cen[0] - half)))
        r1 = int(min(camera.height, max(rows.max() + 1, cen[0] + half + 1)))
        c0 = int(max(0, min(cols.min(), cen[1] - half)))
        c1 = int(min(camera.width, max(cols.max() + 1, cen[1] + half + 1)))
        rr, cc = np.mgrid[r0:r1, c0:c1]
        pts = camera.unproject(np.stack([rr, cc], -1).astype(np.float64), sensor, outside="nan")
        xy = sensor.tangent_offset(np.full(rr.shape, element), pts)
        entries = (rows - r0) * (c1 - c0) + (cols - c0)
        return cls(sensor, camera, ccd, pipe, element, (r0, r1, c0, c1), xy, entries,
                   fold.weights[:, sel], pipe._base_entries[sel], pipe._thr_entries[sel])

    def radiance(self, energy: float, s: float, c) -> np.ndarray:
        """Window radiance of a spot of ``energy`` (DN mm^2 on the dome), rms width ``s`` (mm), centre ``c``."""
        d2 = np.sum((self.xy - np.asarray(c)) ** 2, axis=-1)
        peak_dn = energy / (2 * math.pi * s * s)
        scale = peak_dn / (self.ccd.dn_per_electron * self.ccd.exposure)
        return np.where(np.isfinite(d2), scale * np.exp(-np.nan_to_num(d2, nan=1e9) / (2 * s * s)), 0.0)

    def frames(self, rad: np.ndarray, n: int, seed: int):
        """Yield stacks of full frames (chunks of CHUNK_FRAMES) with the spot exposed in the window."""
        r0, r1, c0, c1 = self.window
        rng = np.random.default_rng(seed)
        dtype = np.uint8 if self.ccd.bits == 8 else np.uint16
        for i in range(0, n, CHUNK_FRAMES):
            t = min(CHUNK_FRAMES, n - i)
            st = np.full((t,) + self.camera.shape, round(self.ccd.dark_offset), dtype)
            st[:, r0:r1, c0:c1] = self.ccd.expose(np.broadcast_to(rad, (t,) + rad.shape),
                                                  seed=int(rng.integers(2**63)))
            yield st


def _pixel_stats(model: _SpotModel, lam: np.ndarray):
    """Per-pixel Fisher information about the mean charge, and the moments of the pipeline's terms.

    For every window pixel: ``J`` (Fisher information of its DN about its
    mean charge). For every fold entry: the mean and the derivative (w.r.t.
    the pixel's mean charge) of the lit value ``v 1[v > t]`` (G's term) and
    of ``(v - t) 1[v > t]`` (the centroid's weight), with ``v = DN - baseline``.
    """
    flat = lam.reshape(-1)
    cache: dict = {}
    J = np.zeros(flat.size)
    for i, lam_i in enumerate(flat):
        key = round(float(lam_i), 9)
        if key not in cache:
            d, P, dP = _quantised_pmf(float(lam_i), model.ccd)
            ok = P > 1e-300
            cache[key] = (d, P, dP, float(np.sum(dP[ok] ** 2 / P[ok])))
        J[i] = cache[key][3]
    n = len(model.entries)
    eg, dg, ew, dw = (np.zeros(n) for _ in range(4))
    for j, p in enumerate(model.entries):
        d, P, dP, _ = cache[round(float(flat[p]), 9)]
        v = d - model.base[j]
        lit = v > model.thr[j]
        term_g = np.where(lit, v, 0.0)
        term_w = np.where(lit, v - model.thr[j], 0.0)
        eg[j], dg[j] = term_g @ P, term_g @ dP
        ew[j], dw[j] = term_w @ P, term_w @ dP
    return J.reshape(lam.shape), eg, dg, ew, dw


def _sweep_level(model: _SpotModel, energy: float, s: float, c, n_frames: int, seed: int) -> dict:
    ccd = model.ccd
    rad = model.radiance(energy, s, c)
    lam = rad * ccd.exposure                                    # mean electrons per pixel
    n_e = float(lam.sum())
    J, eg, dg, ew, dw = _pixel_stats(model, lam)
    # Fisher information about (energy, s, cx, cy) from every pixel of the window
    xy = np.nan_to_num(model.xy)
    dx, dy = xy[..., 0] - c[0], xy[..., 1] - c[1]
    r2 = dx * dx + dy * dy
    grads = np.stack([lam / energy, lam * (r2 / s**3 - 2.0 / s), lam * dx / s**2, lam * dy / s**2])
    fisher = np.einsum("aij,bij,ij->ab", grads, grads, J)
    crb = np.linalg.inv(fisher)
    # gradients of the estimators' means over all four parameters, from the exact per-pixel
    # distributions (the centroid's as a ratio of means): the bound of a biased estimator
    # with nuisance parameters is grad' I^-1 grad
    g_e = grads.reshape(4, -1)[:, model.entries]                 # d lam / d theta, per entry
    area, wx, wy = model.weights
    grad_G = (area * dg) @ g_e.T
    W, Mx, My = area @ ew, wx @ ew, wy @ ew
    dW = (area * dw) @ g_e.T
    grad_u = [((wmom * dw) @ g_e.T * W - mom * dW) / W**2 for wmom, mom in ((wx, Mx), (wy, My))]
    bound_G = float(grad_G @ crb @ grad_G)
    bound_u = [float(gu @ crb @ gu) for gu in grad_u]
    # Monte Carlo through the CCD model and the pipeline
    G, u, contact = [], [], []
    for st in model.frames(rad, n_frames, seed):
        r = model.pipe.process(st)
        G.append(r.G[:, model.element])
        u.append(r.u[:, model.element])
        contact.append(r.contact[:, model.element])
    G, u, contact = np.concatenate(G), np.concatenate(u), np.concatenate(contact)
    rate = float(contact.mean())
    g_true = energy
    n_eff = 4 * math.pi * s * s / float(model.pipe._fold.pixel_area[model.element])
    out = {"signal_factor": None, "energy_dn_mm2": energy, "electrons": n_e,
           "snr": n_e / math.sqrt(n_e + n_eff * (ccd.read_noise**2 + 1.0 / (12.0 * ccd.dn_per_electron**2))),
           "contact_rate": rate}
    Gc, uc = G[contact], u[contact]
    if len(Gc) >= 10:
        var_g = float(np.var(Gc, ddof=1))
        out["G"] = {"true": g_true, "mean": float(Gc.mean()), "mean_model": float(area @ eg),
                    "bias_rel": float(Gc.mean() / g_true - 1.0), "std_rel": math.sqrt(var_g) / g_true,
                    "crb_rel": math.sqrt(crb[0, 0]) / g_true, "slope": float(grad_G[0]),
                    "bound_rel": math.sqrt(bound_G) / g_true,
                    "efficiency": bound_G / var_g if rate >= 0.99 and var_g > 0 else None}
        var_u = np.var(uc, axis=0, ddof=1)
        eff = [b / v for b, v in zip(bound_u, var_u, strict=True)] \
            if rate >= 0.99 and np.all(var_u > 0) else None
        bias = uc.mean(axis=0) - np.asarray(c)
        out["u"] = {"bias_mm": [float(b) for b in bias], "std_mm": [float(math.sqrt(v)) for v in var_u],
                    "crb_mm": [math.sqrt(crb[2, 2]), math.sqrt(crb[3, 3])],
                    "bound_mm": [math.sqrt(b) for b in bound_u], "simple_bound_mm": s / math.sqrt(n_e),
                    "slope": [float(grad_u[0][2]), float(grad_u[1][3])],
                    "efficiency": float(np.mean(eff)) if eff is not None else None}
    return out


def nominal_energy(sensor: DomeSensor | None = None, load_n: float = NOMINAL_LOAD_N,
                   element: int = SWEEP_ELEMENT) -> float:
    """G (grey level x mm^2) that the shipped calibration gives a pure normal ``load_n`` on ``element``.

    The energy of a typical spot on the default camera and CCD: the inverse
    of the calibration's g(G) with u = 0, by bisection.
    """
    from optitact.calib import default_calibration

    cal = default_calibration()
    if sensor is not None and sensor != cal.sensor:
        raise InputError("nominal_energy uses the shipped calibration of the default sensor")
    lo, hi = 0.0, float(cal.g_max[element]) * 4.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        s = mid / cal.g_scale[element]
        fz = float(cal.g[element] @ np.array([1.0, s, s * s, s**3]))
        lo, hi = (mid, hi) if fz < load_n else (lo, mid)
    return 0.5 * (lo + hi)


def noise_sweep(*, n_frames: int = 400, seed: int = 0, factors=SWEEP_FACTORS,
                width_mm: float = NOMINAL_WIDTH_MM, camera: FisheyeCamera | None = None,
                ccd: CCD | None = None, progress: bool = False) -> dict:
    """Bias, spread and efficiency of G and u against signal-to-noise, for a Gaussian spot.

    Parameters
    ----------
    n_frames : int
        Monte Carlo frames per signal level.
    seed : int
        Seed of the CCD noise.
    factors : sequence of float
        Signal levels as multiples of the nominal energy (the G of a 0.5 N
        normal load, :func:`nominal_energy`).
    width_mm : float
        The spot's rms width along each axis (mm), default 0.5: it keeps 99.7 %
        of its energy within 1.7 mm, the reach of an element's cone patches.
    camera, ccd : optional
        Default: the package's nominal ``FisheyeCamera()`` (640 x 480) and ``CCD()`` (8 bits).
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    dict
        ``levels``: one entry per factor with ``snr``, ``electrons``,
        ``contact_rate``, ``G`` (``bias_rel``, ``std_rel``, ``crb_rel``,
        ``efficiency``) and ``u`` (``bias_mm``, ``std_mm``, ``crb_mm``,
        ``simple_bound_mm``, ``efficiency``); ``nominal``: the level at
        factor 1 with ``u_efficiency`` and ``G_efficiency``; ``spot``: the
        spot's settings.

    Notes
    -----
    The spot ``A exp(-|xy - c|^2 / 2 s^2)`` is drawn at the pixel centres
    (``xy``: the element-local geodesic coordinates of the dome point each
    pixel sees, through the closed-form camera), its energy ``A 2 pi s^2``
    in DN mm^2 turned into mean electrons ``lambda_p`` with the CCD's gain
    and exposure. Each pixel's DN has the exact distribution of the CCD model
    (Poisson shot noise, full-well clip, Gaussian read noise, rounding, ADC
    clip), computed by summing over electron counts; its Fisher information
    about ``lambda_p`` is ``J_p = sum_d (dP/dlambda)^2 / P``. The bound is
    the inverse of ``I_ab = sum_p J_p (d lambda_p / d theta_a)(d lambda_p /
    d theta_b)`` over ``theta = (energy, s, c_x, c_y)`` (the width is a
    nuisance parameter), over every pixel of a window around the element --
    the information outside the region included. ``simple_bound_mm`` is
    ``s / sqrt(N)``, the photon limit.

    The pipeline's estimators are biased (the threshold drops the spot's
    rim), so the bound applies as ``var >= k^2 CRB`` with ``k = dE[estimate]
    / d theta``, computed from the same exact per-pixel distributions (the
    centroid's as a ratio of means); ``efficiency = k^2 CRB / var`` over the
    frames in contact, reported where at least 99 % of them are. ``snr`` is
    ``N / sqrt(N + n_eff sigma_e^2)`` with ``N`` the spot's electrons,
    ``n_eff = 4 pi s^2 / pixel area`` and ``sigma_e^2`` read noise plus
    quantisation noise in electrons^2.
    """
    camera = FisheyeCamera() if camera is None else camera
    ccd = CCD() if ccd is None else ccd
    sensor = DomeSensor.default()
    model = _SpotModel.build(sensor, camera, ccd, SWEEP_ELEMENT)
    e0 = nominal_energy(sensor)
    levels = []
    it = list(enumerate(factors))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="noise sweep", unit="level", file=sys.stderr)
    for i, f in it:
        lv = _sweep_level(model, e0 * f, width_mm, SWEEP_CENTRE, n_frames, seed + 7919 * i)
        lv["signal_factor"] = f
        levels.append(lv)
    nominal = next(lv for lv in levels if lv["signal_factor"] == 1.0) if 1.0 in factors else None
    if nominal is not None:
        nominal = dict(nominal, u_efficiency=nominal.get("u", {}).get("efficiency"),
                       G_efficiency=nominal.get("G", {}).get("efficiency"))
    return {"levels": levels, "nominal": nominal,
            "spot": {"element": SWEEP_ELEMENT, "centre_mm": list(SWEEP_CENTRE), "width_mm": width_mm,
                     "nominal_energy_dn_mm2": e0, "nominal_load_n": NOMINAL_LOAD_N,
                     "camera": camera.to_dict(), "ccd": ccd.to_dict(), "frames_per_level": n_frames,
                     "pipeline": {"noise_sigma": model.pipe.noise_sigma, "k": model.pipe.k,
                                  "threshold": model.pipe.threshold}}}


def flicker_check(*, target_rate: float = 0.5, n_frames: int = 400, seed: int = 0, width_mm: float = 0.4,
                  camera: FisheyeCamera | None = None, ccd: CCD | None = None) -> dict:
    """Contact flag at the noise floor: its rate and flip rate against the noise model's prediction.

    A spot is scaled until the noise model gives contact with probability
    ``target_rate``; ``n_frames`` frames of the same spot through the CCD
    model and the pipeline then give the measured contact and flip rates.
    The prediction samples every pixel's DN from its exact distribution
    (:func:`_quantised_pmf`, not the CCD's sampler) and applies the contact
    rule (``G > floor``) to the sums; consecutive frames are independent, so
    the predicted flip rate is ``2 p (1 - p)``.

    Returns
    -------
    dict
        ``predicted_rate``, ``measured_rate``, ``predicted_flip_rate``,
        ``measured_flip_rate``, their tolerances, ``deterministic`` (the same
        frame always reads the same flag) and ``ok``.
    """
    camera = FisheyeCamera() if camera is None else camera
    ccd = CCD() if ccd is None else ccd
    sensor = DomeSensor.default()
    model = _SpotModel.build(sensor, camera, ccd, SWEEP_ELEMENT)
    rng = np.random.default_rng(seed)
    floor = float(model.pipe.floor[SWEEP_ELEMENT])
    area = model.weights[0]
    cache: dict = {}

    def sampler(energy):
        lam = (model.radiance(energy, width_mm, SWEEP_CENTRE) * ccd.exposure).reshape(-1)[model.entries]
        cdfs = []
        for lv in lam:
            key = round(float(lv), 9)
            if key not in cache:
                d, P, _ = _quantised_pmf(float(lv), ccd)
                cache[key] = (d, np.cumsum(P) / P.sum())
            cdfs.append(cache[key])
        return cdfs

    def model_rate(energy, n):
        cdfs = sampler(energy)
        G = np.zeros(n)
        for j, (d, cdf) in enumerate(cdfs):
            dn = d[np.minimum(np.searchsorted(cdf, rng.random(n)), len(d) - 1)]
            v = dn - model.base[j]
            G += area[j] * np.where(v > model.thr[j], v, 0.0)
        return float(np.mean(G > floor))

    lo, hi = 0.0, 2.0
    e_unit = floor * 10.0
    for _ in range(14):  # bisection on the spot's energy for the target contact rate
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if model_rate(e_unit * mid, 600) < target_rate else (lo, mid)
    energy = e_unit * 0.5 * (lo + hi)
    p = model_rate(energy, 20000)
    rad = model.radiance(energy, width_mm, SWEEP_CENTRE)
    contact = []
    deterministic = True
    for st in model.frames(rad, n_frames, int(rng.integers(2**63))):
        r = model.pipe.process(st)
        contact.append(r.contact[:, SWEEP_ELEMENT])
        again = model.pipe.process(st[:4])
        deterministic &= bool(np.array_equal(again.contact[:, SWEEP_ELEMENT], r.contact[:4, SWEEP_ELEMENT]))
    contact = np.concatenate(contact)
    measured = float(contact.mean())
    flips = float(np.mean(contact[1:] != contact[:-1]))
    pred_flip = 2 * p * (1 - p)
    tol_rate = 4 * math.sqrt(max(p * (1 - p), 1e-4) / n_frames) + 0.01
    tol_flip = 4 * math.sqrt(max(pred_flip * (1 - pred_flip), 1e-4) * 2 / (n_frames - 1)) + 0.01
    ok = deterministic and abs(measured - p) <= tol_rate and flips <= pred_flip + tol_flip
    return {"energy_dn_mm2": energy, "floor_dn_mm2": floor, "predicted_rate": p, "measured_rate": measured,
            "rate_tolerance": tol_rate, "predicted_flip_rate": pred_flip, "measured_flip_rate": flips,
            "flip_tolerance": tol_flip, "frames": n_frames, "deterministic": deterministic, "ok": bool(ok)}


# ============================================================================ the run
def generate_cases(n_cases: int, *, seed: int = 0, camera: FisheyeCamera | None = None,
                   tmp: Path | None = None, long_rows: int = 1_000_000,
                   _ctx: _Context | None = None) -> list[Case]:
    """The stress cases: ``n_cases`` in all, shared among :data:`CATEGORIES` by their weights.

    ``tmp`` is a folder for calibration files (it must outlive the cases);
    ``long_rows`` is the length (rows of readings) of the long-stream case.
    """
    if isinstance(n_cases, bool) or not isinstance(n_cases, int) or n_cases < 0:
        raise InputError(f"n_cases must be a non-negative integer, got {n_cases!r}")
    if _ctx is None:
        if tmp is None:
            raise InputError("generate_cases needs tmp, a folder for the calibration files")
        _ctx = _Context(camera, Path(tmp))
    rng = np.random.default_rng(seed)
    counts = {k: int(n_cases * w) for k, w in CATEGORIES.items()}
    counts["frames"] += n_cases - sum(counts.values())
    makers = {"frames": _frame_cases, "readings": _readings_cases, "calibration_fit": _fit_cases,
              "calibration_file": _file_cases, "ccd": _ccd_cases, "contact_render": _contact_cases}
    cases = []
    for cat, n in counts.items():
        if cat == "accumulation":
            cases += _accumulation_cases(_ctx, rng, n, long_rows=long_rows)
        else:
            cases += makers[cat](_ctx, rng, n)
    return cases


def run_stability(*, n_cases: int = 10_000, seed: int = 0, progress: bool = True,
                  camera: FisheyeCamera | None = None, sweep: bool = True, sweep_frames: int = 400,
                  long_rows: int = 1_000_000) -> dict:
    """Run the generated stress cases and the noise sweep; the ``optitact bench stability`` JSON object.

    Parameters
    ----------
    n_cases : int
        Number of generated stress cases (default 10,000).
    seed : int
        Seed of the case generator and of the sweep's noise.
    progress : bool
        Progress bars on stderr.
    camera : FisheyeCamera, optional
        Camera of the stress cases, default 160 x 120 (small, so that the
        cases run in minutes); the noise sweep always uses the nominal
        ``FisheyeCamera()`` and ``CCD()``.
    sweep : bool
        Run the noise sweep and the contact-flicker checks (default True).
    sweep_frames : int
        Monte Carlo frames per sweep level.
    long_rows : int
        Rows of readings (frames x elements) in the long-stream case.

    Returns
    -------
    dict
        ``cases`` (count), ``failures`` (names of failing cases, empty when
        none), ``failure_reasons`` (name -> why, for at most 50),
        ``categories`` (cases and failures per category), ``noise_sweep``
        (per signal level: SNR, and bias, std and efficiency of G and u),
        ``nominal`` (the same at the nominal level, with ``u_efficiency``),
        ``flicker`` (the contact flag at the noise floor, whose checks are
        counted as cases), ``seconds`` and ``seed``.
    """
    t0 = time.perf_counter()
    failures: dict[str, str] = {}
    per_cat: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="optitact-stability-") as tmp:
        ctx = _Context(camera, Path(tmp))
        cases = generate_cases(n_cases, seed=seed, long_rows=long_rows, _ctx=ctx)
        it = cases
        if progress:
            from tqdm import tqdm

            it = tqdm(cases, desc="stress cases", unit="case", file=sys.stderr)
        for case in it:
            why = run_case(case)
            stats = per_cat.setdefault(case.category, {"cases": 0, "failures": 0})
            stats["cases"] += 1
            if why is not None:
                failures[case.name] = why
                stats["failures"] += 1
    t_cases = time.perf_counter() - t0
    out: dict = {}
    flicker = []
    if sweep:
        sw = noise_sweep(n_frames=sweep_frames, seed=seed, progress=progress)
        for i, target in enumerate((0.2, 0.5, 0.8)):
            res: dict = {}

            def check(target=target, i=i, res=res):
                res.update(flicker_check(target_rate=target, n_frames=sweep_frames, seed=seed + 101 * i))
                if not res["ok"]:
                    _fail(f"contact flicker beyond the noise model's prediction: {res}")

            name = f"readings/contact_flicker/p{target}"
            why = run_case(Case(name, "readings", check))
            stats = per_cat.setdefault("readings", {"cases": 0, "failures": 0})
            stats["cases"] += 1
            if why is not None:
                failures[name] = why
                stats["failures"] += 1
            flicker.append(dict(res, target_rate=target))
        out["noise_sweep"] = _compact_levels(sw["levels"])
        out["nominal"] = _compact_level(sw["nominal"]) | {"u_efficiency": sw["nominal"]["u_efficiency"],
                                                          "G_efficiency": sw["nominal"]["G_efficiency"]}
        out["spot"] = sw["spot"]
        out["flicker"] = flicker
    n_total = sum(c["cases"] for c in per_cat.values())
    result = {"cases": n_total, "failures": sorted(failures),
              "failure_reasons": dict(list(sorted(failures.items()))[:50]), "categories": per_cat}
    result.update(out)
    result["seconds"] = {"cases": round(t_cases, 2), "total": round(time.perf_counter() - t0, 2)}
    result["seed"] = seed
    result["camera"] = ctx.camera.to_dict()
    return result


def _round(x, n=4):
    if x is None:
        return None
    if isinstance(x, list | tuple):
        return [_round(v, n) for v in x]
    return float(f"{x:.{n}g}")


def _compact_level(lv: dict) -> dict:
    out = {"signal_factor": lv["signal_factor"], "snr": _round(lv["snr"]), "electrons": _round(lv["electrons"]),
           "contact_rate": _round(lv["contact_rate"])}
    if "G" in lv:
        out["G"] = {k: _round(lv["G"][k]) for k in ("true", "bias_rel", "std_rel", "crb_rel", "efficiency")}
        out["u"] = {k: _round(lv["u"][k])
                    for k in ("bias_mm", "std_mm", "crb_mm", "simple_bound_mm", "efficiency")}
    return out


def _compact_levels(levels: list[dict]) -> list[dict]:
    return [_compact_level(lv) for lv in levels]


def main(argv=None) -> int:  # pragma: no cover - a convenience until the CLI wires it
    """Print the JSON object of :func:`run_stability` (``python -m optitact.stability [n_cases]``)."""
    argv = sys.argv[1:] if argv is None else argv
    n = int(argv[0]) if argv else 10_000
    buf = io.StringIO()
    json.dump(run_stability(n_cases=n), buf)
    print(buf.getvalue())
    return 0


if __name__ == "__main__":  # pragma: no cover
    raise SystemExit(main())
