"""Stage 1 of the two-stage light transport: the emission table of contact patches.

The light the rim injects reaches a contact patch only after many total
internal reflections, and barely depends on a few small contacts elsewhere.
Brute-force path tracing at high spp of single patches on a grid of polar
angle ``theta`` and patch radius ``a`` gives each patch's emitted radiance
``L_e(theta, a)`` (per unit rim radiance), and probes with blocker patches
and lit neighbours give how patches dim or feed each other: the
:class:`EmissionTable`. The emitted radiance belongs to the patch (Lambertian
rubber), not to the camera that sees it: the table serves every camera model.
It is measured once per designed sensor and render settings, through a
*measuring camera* (an on-axis :class:`~optitact.optics.camera.FisheyeCamera`,
default ``FisheyeCamera()``; :func:`emission_table`, announced on stderr,
cached on disk) or taken from the tables shipped with the package
(:func:`shipped_table`, ``render/data/``), against the converged no-load frame
(:func:`noload_radiance`). Stage 2 (:mod:`optitact.render.twostage`) renders
frames from it through any camera.

Convention
----------
Global ``(x, y, z)`` mm as in :mod:`optitact.optics.sensor`; pixels ``(row, col)``
with the origin at the top-left pixel centre, as in :mod:`optitact.optics.camera`.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass

import numpy as np

from optitact._validate import check_keys, check_type, integer
from optitact.optics.camera import FisheyeCamera
from optitact.optics.contact import Contacts
from optitact.errors import InputError, RenderError
from optitact.io.files import atomic_write_text, json_fingerprint
from optitact.optics.sensor import DomeSensor

from optitact.render.background import NOLOAD_SPP, measuring_camera, noload_radiance
from optitact.render.coverage import patch_coverage
from optitact.render.scene import RenderSettings

__all__ = ["EmissionTable", "emission_table", "shipped_table", "band_weights", "TABLE_THETA_DEG",
           "TABLE_RADII_MM", "TABLE_SPP"]

#: Polar angles (deg) of the stage-1 table: every cone of the default sensor lies within 3-72 deg.
TABLE_THETA_DEG = tuple(float(t) for t in np.arange(0.0, 76.1, 2.0))
#: Patch radii (mm) of the stage-1 table (interpolated in log radius; cones touch with 0.001-0.42 mm).
TABLE_RADII_MM = (0.03, 0.08, 0.16, 0.3, 0.5)
#: Polar angles (deg) of the band centres of the patch-coupling model.
BAND_THETA_DEG = (5.0, 20.0, 35.0, 50.0, 65.0)
#: Blocker patches used to measure the coupling: radius (mm), spacing round a band (mm), most per band.
BLOCKER_RADIUS_MM, BLOCKER_SPACING_MM, BLOCKER_MAX = 0.45, 2.5, 40
#: Polar angles (deg) of the probe elements (8 lit cones each) that measure the near-field coupling.
CLUSTER_THETA_DEG = (0.0, 10.0, 20.0, 30.0, 40.0, 50.0, 60.0, 70.0)
#: Cone patch radius (mm) of the probe elements.
CLUSTER_RADIUS_MM = 0.3
#: Probes nearer than this (deg) to a band's blockers are near field and not used for its coupling.
NEAR_FIELD_DEG = 10.0
#: Probe patches per stage-1 render (the grid's angles are shared out over several renders).
PROBES_PER_RENDER = 13
#: Version of the table format and of how it is measured (part of the cache key).
TABLE_VERSION = 5
#: Samples per pixel of a stage-1 table measured here when none is shipped for the sensor and settings.
TABLE_SPP = 4096
#: Stage-1 tables shipped with the package (``render/data/``): the default sensor and camera's.
SHIPPED_TABLES = ("emission_default.json",)
#: Seconds per stage-1 render on 2 busy CPU cores (llvm_ad_rgb, 640x480): ``a + b * spp``; and the
#: converged no-load frame's. A first guess only: the estimate is measured again after the first render.
_PRIOR_S_PER_RENDER, _PRIOR_S_PER_SPP, _PRIOR_NOLOAD_S = 8.0, 0.003, 250.0
#: Keys of a table's dict (:meth:`EmissionTable.to_dict`); all but the last are required.
_TABLE_KEYS = ("version", "theta", "radius", "radiance", "stderr", "bands", "coupling", "local", "meta")


@dataclass(frozen=True, eq=False)
class EmissionTable:
    """Emitted radiance of contact patches per unit rim radiance: isolated, and how patches dim each other.

    Parameters
    ----------
    theta : (m,) float
        Polar angles of the grid (rad), increasing.
    radius : (k,) float
        Patch radii of the grid (mm), increasing.
    radiance : (m, k) float
        ``L_0``: radiance inside the acrylic of an isolated patch, per unit
        ``rim_radiance``.
    stderr : (m, k) float
        Monte Carlo standard error of ``radiance``.
    bands : (nb,) float
        Polar angles (rad) of the band centres of the coupling model.
    coupling : (m, nb) float
        ``C``: change of ``ln L_e`` at polar angle ``theta`` per mm² of
        patches of *other elements* in band ``b`` (far field: shadowing and
        scattered light from across the dome).
    local : (m,) float
        ``C_loc``: change of ``ln L_e`` per mm² of the other cones' patches of
        the *same element* (near field: light the neighbouring cones scatter).
    meta : dict
        What the table was measured for (designed sensor, measuring camera, settings, spp, seed,
        variant).

    Notes
    -----
    A patch ``i`` among others emits
    ``L_i = L_0(theta_i, a_i) * exp(sum_b C(theta_i, b) * A_b + C_loc(theta_i) * A_loc)``,
    where ``A_b`` is the area of other elements' patches assigned to band
    ``b`` by hat-function weights in polar angle and ``A_loc`` that of the
    other patches of patch ``i``'s own element: the guided light a patch
    receives is dimmed by the patches it passes (shadowing) and fed by the
    light they scatter, and to first order both are linear in their area.
    """

    theta: np.ndarray
    radius: np.ndarray
    radiance: np.ndarray
    stderr: np.ndarray
    bands: np.ndarray
    coupling: np.ndarray
    local: np.ndarray
    meta: dict

    def __call__(self, theta, radius) -> np.ndarray:
        """``L_0`` of isolated patches at polar angles ``theta`` (rad) and radii ``radius`` (mm).

        Bilinear in ``(theta, log radius)``; clamped to the grid's edges.
        """
        th = np.clip(np.asarray(theta, float), self.theta[0], self.theta[-1])
        lr = np.clip(np.log(np.maximum(np.asarray(radius, float), 1e-12)),
                     math.log(self.radius[0]), math.log(self.radius[-1]))
        lgrid = np.log(self.radius)
        i = np.clip(np.searchsorted(self.theta, th) - 1, 0, len(self.theta) - 2)
        j = np.clip(np.searchsorted(lgrid, lr) - 1, 0, len(lgrid) - 2)
        ti = (th - self.theta[i]) / (self.theta[i + 1] - self.theta[i])
        tj = (lr - lgrid[j]) / (lgrid[j + 1] - lgrid[j])
        r = self.radiance
        return ((1 - ti) * (1 - tj) * r[i, j] + ti * (1 - tj) * r[i + 1, j]
                + (1 - ti) * tj * r[i, j + 1] + ti * tj * r[i + 1, j + 1])

    def coupling_at(self, theta) -> np.ndarray:
        """``C`` (..., nb) at polar angles ``theta`` (rad), linear in ``theta``."""
        th = np.asarray(theta, float)
        return np.stack([np.interp(th, self.theta, self.coupling[:, b]) for b in range(len(self.bands))],
                        axis=-1)

    def radiance_of(self, theta, radius, element) -> np.ndarray:
        """``L_e`` of every patch of one frame, each dimmed or fed by all the others (see Notes).

        ``theta`` (rad), ``radius`` (mm) and ``element`` (int) per patch.
        """
        theta = np.asarray(theta, float)
        element = np.asarray(element)
        area = np.pi * np.asarray(radius, float) ** 2
        _, inv = np.unique(element, return_inverse=True)
        per_element = np.bincount(inv, weights=area)
        same = per_element[inv] - area
        w = band_weights(theta, self.bands) * area[:, None]
        element_bands = np.zeros((per_element.size, len(self.bands)))
        np.add.at(element_bands, inv, w)
        far = w.sum(axis=0)[None, :] - element_bands[inv]
        exponent = (np.sum(self.coupling_at(theta) * far, axis=1)
                    + np.interp(theta, self.theta, self.local) * same)
        return self(theta, radius) * np.exp(exponent)

    def to_dict(self) -> dict:
        """JSON-friendly dict (see :meth:`from_dict`)."""
        return {"version": TABLE_VERSION, "theta": self.theta.tolist(), "radius": self.radius.tolist(),
                "radiance": self.radiance.tolist(), "stderr": self.stderr.tolist(),
                "bands": self.bands.tolist(), "coupling": self.coupling.tolist(), "local": self.local.tolist(),
                "meta": self.meta}

    @classmethod
    def from_dict(cls, d: dict) -> EmissionTable:
        """Rebuild a table from :meth:`to_dict` output; a wrong version or shape is an InputError."""
        if not isinstance(d, dict) or d.get("version") != TABLE_VERSION:
            raise InputError(f"emission table must be a dict of version {TABLE_VERSION}, "
                             f"got version {d.get('version') if isinstance(d, dict) else type(d).__name__}")
        check_keys(d, _TABLE_KEYS, "emission table", required=_TABLE_KEYS[:-1])
        theta, radius = np.asarray(d["theta"], float), np.asarray(d["radius"], float)
        rad, err = np.asarray(d["radiance"], float), np.asarray(d["stderr"], float)
        bands, coupling = np.asarray(d["bands"], float), np.asarray(d["coupling"], float)
        local = np.asarray(d["local"], float)
        if (rad.shape != (theta.size, radius.size) or err.shape != rad.shape
                or coupling.shape != (theta.size, bands.size) or local.shape != theta.shape):
            raise InputError(f"emission table arrays must have shapes {(theta.size, radius.size)} and "
                             f"{(theta.size, bands.size)}, got {rad.shape}, {err.shape}, {coupling.shape}")
        return cls(theta, radius, rad, err, bands, coupling, local, dict(d.get("meta", {})))


def _table_key(sensor, camera, settings, thetas, radii, spp, seed, variant) -> str:
    """Cache key of a measured table: the designed sensor, the measuring camera, settings, grid, sampling."""
    return json_fingerprint({"sensor": sensor.as_designed.to_dict(), "camera": camera.to_dict(),
                             "settings": settings.to_dict(), "theta_deg": list(thetas), "radii": list(radii),
                             "spp": spp, "seed": seed, "variant": variant, "version": TABLE_VERSION}, 24)


def _shipped_key(sensor, camera, settings, thetas, radii) -> str:
    """What a table depends on besides its sampling (spp, seed, variant): the lookup key of shipped tables.

    The designed sensor (as-built offsets and gains are applied at render time), the measuring
    camera, the render settings and the grid; never the camera a frame is rendered through.
    """
    return json_fingerprint({"sensor": sensor.as_designed.to_dict(), "camera": camera.to_dict(),
                             "settings": settings.to_dict(), "theta_deg": list(thetas), "radii": list(radii),
                             "version": TABLE_VERSION}, 24)


def shipped_table(sensor: DomeSensor, camera: FisheyeCamera | None = None, *,
                  settings: RenderSettings | None = None,
                  thetas_deg=TABLE_THETA_DEG, radii_mm=TABLE_RADII_MM, bands_deg=BAND_THETA_DEG,
                  spp: int | None = None, seed: int = 0) -> EmissionTable | None:
    """The stage-1 table shipped with the package for this sensor, settings and grid, or None.

    Shipped tables (``render/data/``) are measured as :func:`emission_table`
    measures them, once, by the developers; one matches when everything the
    table depends on is the same (the designed sensor: as-built offsets and
    gains do not count; the measuring camera ``camera``, default
    ``FisheyeCamera()``; render settings, grid, table version: the
    fingerprint in its ``meta["key"]``) and, if given, ``spp`` and ``seed``
    are those it was measured with. The Mitsuba variant it was measured on is
    not part of the match (the physics is the same). The table serves every
    camera a frame is rendered through.
    """
    from pathlib import Path

    camera = measuring_camera(camera)
    settings = RenderSettings() if settings is None else settings
    thetas = tuple(float(t) for t in thetas_deg)
    bands = tuple(float(b) for b in bands_deg)
    key = _shipped_key(sensor, camera, settings, (thetas, bands), tuple(float(r) for r in radii_mm))
    for name in SHIPPED_TABLES:
        path = Path(__file__).parent / "data" / name
        if not path.is_file():
            continue
        d = json.loads(path.read_text(encoding="utf-8"))
        meta = d.get("meta", {})
        if meta.get("key") == key and meta.get("seed") == seed and spp in (None, meta.get("spp")):
            return EmissionTable.from_dict(d)
    return None


def _minutes(seconds: float) -> str:
    return f"{seconds:.0f} s" if seconds < 90 else f"{seconds / 60:.0f} min"


def _ring_points(sensor: DomeSensor, theta_deg, phi) -> np.ndarray:
    th = np.radians(np.asarray(theta_deg, float))
    return sensor.outer_radius * np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)],
                                          axis=-1)


def _contacts(centers: np.ndarray, radii: np.ndarray, per_element: int = 1) -> Contacts:
    """Patches as Contacts, ``per_element`` consecutive patches forming one element."""
    m = len(radii) // per_element
    k = per_element
    return Contacts(centers=centers.reshape(m, k, 3), radii=np.asarray(radii, float).reshape(m, k),
                    loads=np.zeros((m, k)), saturated=np.zeros((m, k), bool), tipped=np.zeros(m, bool),
                    slide=np.zeros((m, 2)))


def _clusters(sensor: DomeSensor, thetas_deg, phi) -> np.ndarray:
    """Cone centres (n * K, 3) of elements whose centres sit at ``thetas_deg``, ``phi``."""
    th = np.radians(np.asarray(thetas_deg, float))
    n = np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)], axis=-1)
    ex = np.cross([0.0, 0.0, 1.0], n)
    ex = np.where(np.linalg.norm(ex, axis=1, keepdims=True) > 1e-9, ex, [[0.0, 1.0, 0.0]])
    ex /= np.linalg.norm(ex, axis=1, keepdims=True)
    ey = np.cross(n, ex)
    off = sensor.cone_offsets
    d = np.linalg.norm(off, axis=1)[None, :, None] / sensor.outer_radius
    t = (off[None, :, 0:1] * ex[:, None, :] + off[None, :, 1:2] * ey[:, None, :])
    t /= np.linalg.norm(t, axis=-1, keepdims=True)
    return (sensor.outer_radius * (np.cos(d) * n[:, None, :] + np.sin(d) * t)).reshape(-1, 3)


def _blockers(sensor: DomeSensor, band_deg: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Blocker patches spread round the band at ``band_deg``: centres, radii, azimuths."""
    circumference = 2.0 * math.pi * sensor.outer_radius * math.sin(math.radians(band_deg))
    n = int(np.clip(circumference // BLOCKER_SPACING_MM, 4, BLOCKER_MAX))
    phi = 2.0 * np.pi * np.arange(n) / n
    return _ring_points(sensor, np.full(n, band_deg), phi), np.full(n, BLOCKER_RADIUS_MM), phi


def _probe_azimuths(thetas_deg, blockers: list[tuple[float, np.ndarray]]) -> np.ndarray:
    """Golden-angle spread azimuths; a probe near a blocker band moves to the middle of a gap."""
    phi = np.radians(17.0) + 2.0 * np.pi * np.arange(len(thetas_deg)) * 0.381966
    for band, bphi in blockers:
        n = len(bphi)
        for i, t in enumerate(thetas_deg):
            if abs(t - band) < 8.0:
                gaps = 2.0 * np.pi * (np.arange(n) + 0.5) / n
                diff = np.angle(np.exp(1j * (gaps - phi[i])))
                phi[i] = gaps[np.argmin(np.abs(diff))]
    return phi


def band_weights(theta, bands) -> np.ndarray:
    """Hat-function weights (..., nb) of polar angles ``theta`` (rad) on the band centres (rad)."""
    theta = np.clip(np.asarray(theta, float), bands[0], bands[-1])
    w = np.zeros((*theta.shape, len(bands)))
    j = np.clip(np.searchsorted(bands, theta) - 1, 0, len(bands) - 2)
    t = (theta - bands[j]) / (bands[j + 1] - bands[j])
    np.put_along_axis(w, j[..., None], (1 - t)[..., None], axis=-1)
    np.put_along_axis(w, (j + 1)[..., None], t[..., None], axis=-1)
    return w


def _measure(sensor, camera, settings, probes_c, probes_r, extra_c, extra_r, *, spp, seed, variant,
             background, n_sub=16, n_passes=8, per_element=1):
    """Path-trace probe patches (plus other patches) and return each probe's ``L_e`` and its stderr."""
    import cv2

    from optitact.render.pathtrace import pass_seeds, path_trace

    n = len(probes_r)
    contacts = _contacts(np.concatenate([probes_c, extra_c]), np.concatenate([probes_r, extra_r]),
                         per_element)
    cov = patch_coverage(sensor, camera, contacts, settings, n_sub=n_sub)
    bg = np.asarray(background, np.float64).reshape(-1)
    # Each probe's window: its covered pixels grown by 2 pixels (the spot's glow), each pixel going
    # to the patch whose projected centre is nearest (neighbouring cones share no pixel, and pixels
    # nearest a non-probe patch count for none).
    from scipy.spatial import cKDTree

    grown = np.zeros(bg.size, np.uint8)
    grown[cov["pixel"][cov["patch"] < n]] = 1
    grown = cv2.dilate(grown.reshape(camera.shape), np.ones((5, 5), np.uint8)).reshape(-1) > 0
    pix = np.flatnonzero(grown)
    centres = contacts.centers.reshape(-1, 3)[contacts.radii.reshape(-1) > 0]
    centres = centres / np.linalg.norm(centres, axis=1, keepdims=True) * sensor.outer_radius
    _, nearest = cKDTree(camera.project(centres, sensor)).query(np.stack(np.divmod(pix, camera.width), -1))
    window = np.zeros(bg.size, np.int32)
    window[pix] = np.where(nearest < n, nearest + 1, 0)
    mask = (window > 0).reshape(camera.shape)
    sums = []
    for s in pass_seeds(seed, n_passes):
        img, _ = path_trace(sensor, contacts, camera=camera, spp=max(spp // n_passes, 1), seed=int(s),
                            variant=variant, settings=settings, pixels=mask, background=background)
        diff = np.asarray(img, np.float64).reshape(-1) - bg
        sums.append(np.bincount(window, weights=diff, minlength=n + 1)[1:])
    mine = cov["patch"] < n
    occluded = np.bincount(cov["patch"][mine], weights=(cov["coverage"] * bg[cov["pixel"]])[mine], minlength=n)
    trans = np.bincount(cov["patch"][mine], weights=cov["transmitted"][mine], minlength=n)
    per_pass = (np.array(sums) + occluded) / trans / settings.rim_radiance
    return per_pass.mean(axis=0), per_pass.std(axis=0, ddof=1) / math.sqrt(n_passes)


def emission_table(sensor: DomeSensor, camera: FisheyeCamera | None = None, *,
                   settings: RenderSettings | None = None,
                   thetas_deg=TABLE_THETA_DEG, radii_mm=TABLE_RADII_MM, bands_deg=BAND_THETA_DEG,
                   spp: int | None = None, seed: int = 0, variant: str | None = None,
                   progress: bool = False, cache: bool = True) -> EmissionTable:
    """Stage 1: measure ``L_0(theta, a)`` and the coupling ``C(theta, b)`` by path tracing (cached).

    Probe patches at the grid's polar angles (spread in azimuth, at most
    ``PROBES_PER_RENDER`` per render) are path-traced at ``spp``, rendering
    only the pixels around them over the converged no-load frame
    (:func:`noload_radiance`). Per probe, with ``S`` the rendered radiance
    minus the no-load radiance summed over its pixels, ``c`` the covered
    fractions and ``t`` the transmitted weights of :func:`patch_coverage`:
    ``L = (S + sum(c * background)) / sum(t)``; standard errors come from the
    spread of 8 passes.

    - ``radiance``: probes of each radius, alone.
    - ``coupling``: probes of the largest radius rendered again with blocker
      patches round one band at a time; ``C = ln(L_blocked / L_alone) / A_blockers``,
      smoothed in ``theta`` by a weighted cubic per band.
    - ``radiance`` is then corrected for the other probes of its own render
      with that coupling, so it holds isolated patches.
    - ``local``: probe elements (all 8 cones lit, radius ``CLUSTER_RADIUS_MM``)
      at ``CLUSTER_THETA_DEG``; ``C_loc = ln(L_cone / L_expected) / A_neighbours``,
      a weighted quadratic in ``theta``.

    The emitted radiance belongs to the patch, not to a camera: the table
    serves every camera model a frame is rendered through. ``camera`` is only
    the camera it is *measured* through: an on-axis
    :class:`~optitact.optics.camera.FisheyeCamera`, default ``FisheyeCamera()``
    (tests measure coarse tables through tiny ones). It is measured on the
    designed sensor (``sensor.as_designed``): as-built element offsets and
    gains are applied at render time and do not change the table.

    The table is cached in the user cache folder (``emission/``), keyed by
    everything it depends on. The default sensor and camera's table ships
    with the package (:func:`shipped_table`): with ``spp=None`` (the
    default) or its own spp it is used and nothing is rendered. Otherwise
    ``spp=None`` measures at ``TABLE_SPP``; fewer samples measure faster (not
    proportionally: each render has a fixed cost) and noisier (the errors
    measured at 256 to 1024 spp are in the documentation's rendering
    results, ``docs/results/render.md``). With ``progress`` a message
    on stderr says, before this one-time step, what it is, where it is cached
    and how long it should take (re-estimated after the first render), and a
    bar shows its progress.
    """
    from optitact.io.cache import cache_dir

    from optitact.render.backend import select_variant
    from optitact.render.pathtrace import SPP_PER_PASS

    check_type(sensor, DomeSensor, "sensor")
    camera = measuring_camera(camera)
    sensor = sensor.as_designed
    settings = RenderSettings() if settings is None else settings
    if spp is not None:
        spp = integer(spp, "spp", minimum=2 * SPP_PER_PASS)
    shipped = shipped_table(sensor, camera, settings=settings, thetas_deg=thetas_deg, radii_mm=radii_mm,
                            bands_deg=bands_deg, spp=spp, seed=seed)
    if shipped is not None:
        return shipped
    spp = TABLE_SPP if spp is None else spp
    used = select_variant(variant)[1]
    thetas = tuple(float(t) for t in thetas_deg)
    radii = tuple(float(r) for r in radii_mm)
    bands = tuple(float(b) for b in bands_deg)
    for name, v in (("thetas_deg", thetas), ("radii_mm", radii), ("bands_deg", bands)):
        if len(v) < 2 or np.any(np.diff(v) <= 0) or v[0] < 0:
            raise InputError(f"{name} must hold >= 2 increasing non-negative values, got {v}")
    name = _table_key(sensor, camera, settings, (thetas, bands), radii, spp, seed, used)
    path = cache_dir() / "emission" / f"{name}.json"
    if cache and path.is_file():
        return EmissionTable.from_dict(json.loads(path.read_text()))
    start = time.perf_counter()
    n_groups = -(-len(thetas) // PROBES_PER_RENDER)
    n_renders = (len(radii) + len(bands)) * n_groups + 2  # the jobs below
    if progress:
        guess = n_renders * (_PRIOR_S_PER_RENDER + _PRIOR_S_PER_SPP * spp)
        print(f"optitact: one-time step: measuring the two-stage emission table for this sensor and render "
              f"settings, through a {camera.width}x{camera.height} fisheye; any camera renders with it "
              f"({n_renders} path-traced renders at {spp} spp, after a converged "
              f"{NOLOAD_SPP}-spp no-load frame unless that is cached); it is cached in "
              f"{path if cache else '(nowhere: cache=False)'} and never measured again. Estimate: "
              f"{_minutes(guess)} for the renders (+ up to {_minutes(_PRIOR_NOLOAD_S)} for the no-load frame) "
              f"on 2 CPU cores at 640x480 ({used}); measured again after the first render. Fewer samples "
              f"(--table-spp) are faster and noisier.", file=sys.stderr, flush=True)
    background = noload_radiance(sensor, camera, settings=settings, variant=used)
    blockers = [_blockers(sensor, b) for b in bands]
    phi = _probe_azimuths(thetas, [(b, blk[2]) for b, blk in zip(bands, blockers, strict=True)])
    groups = [np.arange(g, len(thetas), n_groups) for g in range(n_groups)]
    centres = _ring_points(sensor, thetas, phi)
    mid = len(radii) - 1  # coupling probes: the largest radius (the least noisy)
    jobs = [("alone", j, g) for j in range(len(radii)) for g in range(n_groups)]
    jobs += [("blocked", b, g) for b in range(len(bands)) for g in range(n_groups)]
    cluster_groups = [CLUSTER_THETA_DEG[0::2], CLUSTER_THETA_DEG[1::2]]
    jobs += [("cluster", 0, g) for g in range(len(cluster_groups))]
    if progress:
        from tqdm import tqdm

        jobs = tqdm(jobs, desc="emission table", unit="render", file=sys.stderr)
    rad = np.zeros((len(thetas), len(radii)))
    err = np.zeros_like(rad)
    blocked = np.zeros((len(thetas), len(bands)))
    none = (np.zeros((0, 3)), np.zeros(0))
    cluster_theta, cluster_value, cluster_err = [], [], []
    k_cones = sensor.n_cones
    first = time.perf_counter()
    for k, (kind, j, g) in enumerate(jobs):
        if k == 1 and progress:
            took = time.perf_counter() - first
            jobs.write(f"optitact: emission table: the first render took {took:.1f} s: about "
                       f"{_minutes(took * (n_renders - 1))} for the other {n_renders - 1} (the bar's "
                       f"estimate follows)", file=sys.stderr)
        if kind == "cluster":
            ct = np.asarray(cluster_groups[g], float)
            cphi = np.radians(40.0) + np.pi / 2 * np.arange(ct.size)
            cones = _clusters(sensor, ct, cphi)
            val, se = _measure(sensor, camera, settings, cones, np.full(len(cones), CLUSTER_RADIUS_MM), *none,
                               spp=spp, seed=seed + 7919 * k, variant=used, background=background,
                               per_element=k_cones)
            cluster_theta.append(np.arctan2(np.hypot(cones[:, 0], cones[:, 1]), cones[:, 2]))
            cluster_value.append(val)
            cluster_err.append(se)
            continue
        idx = groups[g]
        a = radii[j] if kind == "alone" else radii[mid]
        extra = none if kind == "alone" else blockers[j][:2]
        val, se = _measure(sensor, camera, settings, centres[idx], np.full(idx.size, a), *extra, spp=spp,
                           seed=seed + 7919 * k, variant=used, background=background)
        if kind == "alone":
            rad[idx, j], err[idx, j] = val, se
        else:
            blocked[idx, j] = val
    if np.any(rad <= 0) or np.any(blocked <= 0):
        raise RenderError(f"stage-1 measurement too noisy at spp={spp} for this camera (a probe read "
                          f"<= 0); raise spp or the smallest radius")
    th = np.radians(np.array(thetas))
    bands_rad = np.radians(np.array(bands))
    blocker_area = np.array([np.pi * np.sum(blk[1] ** 2) for blk in blockers])
    coupling = np.log(blocked / rad[:, [mid]]) / blocker_area[None, :]
    # The far-field coupling is smooth in theta; a weighted cubic per band keeps the trend, not the
    # noise. Probes within NEAR_FIELD_DEG of a band sit close to its blockers (near field, which
    # the same-element term models): they are left out of that band's fit.
    rel = np.hypot(err[:, mid] / rad[:, mid], err[:, mid] / rad[:, mid])
    for b, band in enumerate(bands):
        far = np.abs(np.array(thetas) - band) >= NEAR_FIELD_DEG
        fit = np.polynomial.Polynomial.fit(th[far], coupling[far, b], deg=3, w=blocker_area[b] / rel[far])
        coupling[:, b] = fit(th)
    # Each probe was measured beside the other probes of its render: undo their (first-order) effect.
    for g in groups:
        w = band_weights(th[g], bands_rad)
        c = np.stack([np.interp(th[g], th, coupling[:, b]) for b in range(len(bands))], axis=-1)
        for j, a in enumerate(radii):
            others = (w.sum(axis=0)[None, :] - w) * np.pi * a * a
            rad[g, j] *= np.exp(-np.sum(c * others, axis=1))
    # Near field: each cone of a probe element beside its 7 lit neighbours, against the isolated
    # radiance (and the far-field effect of the other probe elements of its render).
    ct, cv, ce = (np.concatenate(x) for x in (cluster_theta, cluster_value, cluster_err))
    partial = EmissionTable(th, np.array(radii), rad, err, bands_rad, coupling, np.zeros_like(th), {})
    expected = np.concatenate([
        partial.radiance_of(t, np.full(t.size, CLUSTER_RADIUS_MM), np.arange(t.size) // k_cones)
        for t in cluster_theta])
    same_area = (k_cones - 1) * np.pi * CLUSTER_RADIUS_MM**2
    ok = (cv > 0) & (cv > 2 * ce)  # cones whose measurement stands clear of its noise
    if ok.sum() < 3:
        raise RenderError(f"stage-1 near-field measurement too noisy at spp={spp} for this camera; "
                          f"raise spp")
    local_samples = np.log(cv[ok] / expected[ok]) / same_area
    fit = np.polynomial.Polynomial.fit(ct[ok], local_samples, deg=2, w=cv[ok] / np.maximum(ce[ok], 1e-12))
    local = fit(th)
    meta = {"sensor": sensor.to_dict(), "camera": camera.to_dict(), "settings": settings.to_dict(),
            "spp": spp, "seed": seed, "variant": used, "seconds": round(time.perf_counter() - start, 2)}
    table = EmissionTable(th, np.array(radii), rad, err, bands_rad, coupling, local, meta)
    if cache:
        atomic_write_text(path, json.dumps(table.to_dict()))
    return table
