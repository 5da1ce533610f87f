"""Element regions on the dome: the dewarp grids and the per-pixel weights they fold into.

:func:`split_regions` (once per sensor and camera) lays a fine grid of
geodesic tangent coordinates around every element, cut to the element's
Voronoi cell within a radius; :func:`dewarp` resamples an image onto those
grids and :func:`integrate` sums them (steps 4-5 of
:mod:`optitact.pipeline.frame_pipeline`). :func:`region_weights` folds the bilinear dewarp
weights, cell areas and coordinates into per-(element, pixel) weights, the
fast pipeline's sums; :func:`fold_regions` makes the same weights without
the grids and keeps them in the user cache folder (the pipeline's
precompute, loaded in milliseconds); :meth:`RegionWeights.region_pixels`
names the pixels an element's region reads (what the renderer needs to
render only those).

Convention
----------
Images are ``(row, col)`` with the origin at the top-left pixel centre.
Region grids use element-local tangent coordinates ``(x, y)`` in mm,
geodesic normal coordinates around the element centre
(``sensor.dome_point(e, (x, y))`` is the dome point of grid coordinate
``(x, y)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache, partial

import numpy as np

from optitact._validate import check_type, positive
from optitact.optics.camera import Camera
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["OVERSAMPLE", "REGION_MARGIN_MM", "RegionGrids", "RegionWeights", "default_region_radius",
           "deferred_grids", "dewarp", "fold_regions", "forget_folded_weights", "integrate", "region_weights",
           "split_regions"]

#: Margin (mm) added to the farthest reach of a cone's patch for the default region radius.
REGION_MARGIN_MM = 0.5
#: Grid cells per smallest pixel footprint in the default dewarp grid.
OVERSAMPLE = 2.5


class RegionGrids:
    """The 41 element regions as fine grids on the dome, with their pixel maps.

    Made by :func:`split_regions`; a pipeline's (:attr:`optitact.pipeline.frame_pipeline.Pipeline.grids`)
    builds its arrays on first use (the fast method never needs them), so
    ``grids.radius``, ``grids.grid_mm``, ``grids.coords`` and ``grids.n_elements``
    cost nothing.

    Attributes
    ----------
    coords : (n,) ndarray
        Cell-centre coordinates (mm) along each tangent axis; the same for x
        and y, centred on the element centre.
    grid_mm : float
        Cell size (mm).
    radius : float
        Region radius (mm, geodesic).
    pixels : (E, n, n, 2) ndarray
        Pixel position ``(row, col)`` where each cell's dome point appears;
        -10 for cells outside the region.
    area : (E, n, n) ndarray
        Each cell's area on the dome (mm^2), 0 outside the region.
    mask : (E, n, n) bool ndarray
        Cells of the region: within ``radius`` of the element centre, nearer
        to it than to any other element centre, visible through the dome and
        inside the image.
    """

    def __init__(self, coords: np.ndarray, grid_mm: float, radius: float, pixels: np.ndarray | None,
                 area: np.ndarray | None, mask: np.ndarray | None, *, n_elements: int | None = None,
                 build=None) -> None:
        self._coords, self._grid_mm, self._radius = coords, grid_mm, radius
        self._arrays = None if build is not None else (pixels, area, mask)
        self._n = mask.shape[0] if n_elements is None else int(n_elements)
        self._build = build

    def _get(self, i: int) -> np.ndarray:
        if self._arrays is None:  # deferred: built once, on first use
            self._arrays = self._build()
            self._build = None
        return self._arrays[i]

    coords = property(lambda self: self._coords, doc="Cell-centre coordinates (mm) along each tangent axis.")
    grid_mm = property(lambda self: self._grid_mm, doc="Cell size (mm).")
    radius = property(lambda self: self._radius, doc="Region radius (mm, geodesic).")
    pixels = property(lambda self: self._get(0), doc="(E, n, n, 2) pixel position of each cell.")
    area = property(lambda self: self._get(1), doc="(E, n, n) area of each cell on the dome (mm^2).")
    mask = property(lambda self: self._get(2), doc="(E, n, n) cells of each region.")

    @property
    def n_elements(self) -> int:
        """Number of regions."""
        return self._n

    def __repr__(self) -> str:
        state = "built" if self._arrays is not None else "deferred"
        return (f"RegionGrids(n_elements={self._n}, cells={len(self._coords)}x{len(self._coords)}, "
                f"grid_mm={self._grid_mm!r}, radius={self._radius!r}, {state})")


def default_region_radius(sensor: DomeSensor) -> float:
    """Farthest reach of a patch plus a margin, capped at half the closest element spacing (mm).

    ``min(cone_circle_radius + cone_base_radius + REGION_MARGIN_MM, d_min / 2)``
    where ``d_min`` is the smallest geodesic distance between element centres.
    """
    reach = sensor.cone_circle_radius + sensor.cone_base_radius + REGION_MARGIN_MM
    n = sensor.element_frames[:, 2, :]
    if len(n) < 2:
        return reach
    cos = np.clip(n @ n.T, -1.0, 1.0)
    np.fill_diagonal(cos, -1.0)
    d_min = sensor.outer_radius * float(np.arccos(cos.max()))
    return min(reach, 0.5 * d_min)


def _smallest_footprint(sensor: DomeSensor, camera: Camera, radius: float) -> float:
    """Smallest dome length (mm) one pixel spans, over points in the regions."""
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    ring = np.concatenate([[[0.0, 0.0]], radius * np.stack([np.cos(ang), np.sin(ang)], 1)])
    e = np.repeat(np.arange(sensor.n_elements), len(ring))
    pts = sensor.dome_point(e, np.tile(ring, (sensor.n_elements, 1)))
    pts = pts[camera.visible(pts, sensor)]
    px = camera.project(pts, sensor)
    h = 1e-3
    d0 = camera.unproject(px, sensor, outside="nan")
    jr = (camera.unproject(px + [h, 0], sensor, outside="nan") - d0) / h
    jc = (camera.unproject(px + [0, h], sensor, outside="nan") - d0) / h
    s = np.linalg.svd(np.stack([jr, jc], axis=-1), compute_uv=False)  # (n, 2)
    s = s[np.isfinite(s).all(axis=1)]
    if s.size == 0:
        raise InputError("no element region is visible to this camera")
    return float(s[:, 1].min())


def _resolve_geometry(sensor: DomeSensor, camera: Camera, radius: float | None,
                      grid_mm: float | None) -> tuple[float, float]:
    """The region radius and cell size (mm) :func:`split_regions` uses, defaults filled in and checked."""
    check_type(sensor, DomeSensor, "sensor")
    check_type(camera, Camera, "camera")
    radius = default_region_radius(sensor) if radius is None else positive(radius, "radius")
    if radius > math.pi * sensor.outer_radius:
        raise InputError(f"radius must be at most half a great circle of the dome, "
                         f"{math.pi * sensor.outer_radius:g} mm, got {radius!r}")
    if grid_mm is None:
        grid_mm = _smallest_footprint(sensor, camera, radius) / OVERSAMPLE
        if grid_mm > radius:  # a pixel spans more than the region: the footprint scales as 1 / side
            side = min(camera.shape)
            fov = f" (fov {camera.fov_deg:g} deg)" if hasattr(camera, "fov_deg") else ""
            raise InputError(
                f"frame too small: a {camera.width}x{camera.height} frame cannot resolve the element "
                f"regions; this sensor and camera{fov} need at least "
                f"{math.ceil(side * grid_mm / radius)} pixels on the shorter side")
        derived = True
    else:
        derived = False
    grid_mm = positive(grid_mm, "grid_mm")
    if grid_mm > radius:
        raise InputError(f"grid_mm must be at most the region radius {radius:g} mm, got {grid_mm!r}")
    half = math.ceil(radius / grid_mm)
    if 2 * half + 1 > 2001 and derived:  # nobody chose grid_mm: say what about the camera makes it so fine
        dist = getattr(camera, "dist", None)
        raise InputError(
            f"this camera's model maps part of the dome onto so many pixels that one pixel spans only "
            f"{grid_mm * OVERSAMPLE:.3g} mm of it: the element regions' grid ({OVERSAMPLE:g} cells per pixel, "
            f"{grid_mm:.3g} mm) would need {2 * half + 1} cells per side (at most 2001). A distortion model "
            f"that stretches the image this much is usually wrong: check the camera's "
            f"{type(camera).__name__} distortion{f' {tuple(dist)}' if dist is not None else ''} (a fisheye "
            f"file's k1..k4 read as a pinhole's, or coefficients from a calibration at another frame size: "
            f"register --model, --camera-intrinsics); if it is right, give a coarser grid_mm (Pipeline's "
            f"option)")
    if 2 * half + 1 > 2001:
        raise InputError(f"grid_mm={grid_mm} is too fine for radius={radius} "
                         f"({2 * half + 1} cells per side; at most 2001)")
    return float(radius), float(grid_mm)


def _coords(radius: float, grid_mm: float) -> np.ndarray:
    """Cell-centre coordinates (mm) along each tangent axis of a region grid."""
    half = math.ceil(radius / grid_mm)
    return (np.arange(2 * half + 1) - half) * grid_mm


def _region_cells(sensor: DomeSensor, camera: Camera, radius: float, grid_mm: float):
    """The region cells, one element at a time: the cell layout, then ``(e, cells, rc)`` per element.

    Yields first ``(coords, area)`` (the grid's cell coordinates and the
    ``(n, n)`` cell areas on the sphere), then for every element ``e`` the
    flat indices ``cells`` (increasing) of its region's cells in the
    ``(n, n)`` grid and their pixel positions ``rc`` ``(m, 2)``. One element
    at a time, over the cells within the radius: the temporaries stay a few
    times one element's grid (all elements' products at once took 3 GB at
    2560 x 1920). Only elements within twice the radius of ``e`` can be
    nearer to one of its cells than ``e`` itself; the others are not tested.
    """
    coords = _coords(radius, grid_mm)
    gx, gy = np.meshgrid(coords, coords)  # x along columns, y along rows
    offsets = np.stack([gx, gy], axis=-1).reshape(-1, 2)
    rho = np.hypot(gx, gy)
    x = rho / sensor.outer_radius
    yield coords, grid_mm**2 * np.where(x > 0, np.sin(x) / np.where(x > 0, x, 1.0), 1.0)
    within = np.flatnonzero(rho <= radius)
    offsets = offsets[within]
    normals = sensor.element_frames[:, 2, :]
    apart = sensor.outer_radius * np.arccos(np.clip(normals @ normals.T, -1.0, 1.0))  # (E, E) geodesic
    h, w = camera.shape
    for e in range(sensor.n_elements):
        rivals = np.flatnonzero(apart[e] <= 2.0 * radius * (1.0 + 1e-6) + 1e-6)  # e is one of them
        pts = sensor.dome_point(np.intp(e), offsets)  # (m, 3)
        nearest = rivals[np.argmax(np.einsum("ik,fk->if", pts, normals[rivals]), axis=-1)]
        keep = np.flatnonzero(nearest == e)
        keep = keep[camera.visible(pts[keep], sensor)]
        rc = camera.project(pts[keep], sensor) if len(keep) else np.zeros((0, 2))
        inside = (rc[:, 0] >= 0) & (rc[:, 0] <= h - 1) & (rc[:, 1] >= 0) & (rc[:, 1] <= w - 1)
        yield e, within[keep[inside]], rc[inside]


@lru_cache(maxsize=2)
def split_regions(sensor: DomeSensor, camera: Camera, *, radius: float | None = None,
                  grid_mm: float | None = None) -> RegionGrids:
    """Step 4a (once per sensor and camera): the element regions as dome grids.

    Parameters
    ----------
    sensor : DomeSensor
    camera : Camera
        Any camera model; cells it does not see (:meth:`Camera.visible`) are
        left out.
    radius : float, optional
        Region radius (mm, geodesic); default :func:`default_region_radius`;
        at most half a great circle (``pi * outer_radius``).
        Cells nearer to another element's centre belong to that element
        (Voronoi), so regions never overlap.
    grid_mm : float, optional
        Cell size (mm); default the smallest pixel footprint in the regions
        divided by ``OVERSAMPLE`` (2.5), so the bilinear dewarp never skips a
        pixel; at most ``radius``.

    Returns
    -------
    RegionGrids

    Raises
    ------
    TypeError, InputError
        ``radius`` or ``grid_mm`` not a positive number, beyond the bounds
        above, or so fine that a region would need more than 2001 cells
        per side.

    Notes
    -----
    Cell ``(i, j)`` of element ``e`` is the dome point
    ``sensor.dome_point(e, (coords[j], coords[i]))`` (x along columns, y
    along rows of the grid); its area on the sphere is
    ``grid_mm^2 sin(rho/R) / (rho/R)`` with ``rho`` its geodesic distance from
    the centre (the area element of geodesic normal coordinates).

    Cached in memory for the last two (sensor, camera, radius, grid_mm): at
    1920x1440 a set of grids holds about 130 MB. The fast pipeline never
    builds them; it folds the same cells straight into
    :func:`fold_regions`'s per-pixel weights.
    """
    radius, grid_mm = _resolve_geometry(sensor, camera, radius, grid_mm)
    cells = _region_cells(sensor, camera, radius, grid_mm)
    coords, cell_area = next(cells)
    n = len(coords)
    mask = np.zeros((sensor.n_elements, n, n), bool)
    pixels = np.full(mask.shape + (2,), -10.0)
    for e, idx, rc in cells:
        mask[e].reshape(-1)[idx] = True
        pixels[e].reshape(-1, 2)[idx] = rc
    area = np.where(mask, cell_area[None], 0.0)
    for arr in (coords, pixels, area, mask):
        arr.flags.writeable = False
    return RegionGrids(coords, grid_mm, radius, pixels, area, mask)


def dewarp(image, grids: RegionGrids) -> np.ndarray:
    """Step 4b: resample an image onto every region's dome grid, ``(E, n, n)`` float64.

    Bilinear interpolation (``scipy.ndimage.map_coordinates``, order 1, exact
    weights) at each cell's pixel position; cells outside a region read 0.
    """
    from scipy.ndimage import map_coordinates

    img = np.asarray(image, dtype=np.float64)
    n = len(grids.coords)
    out = np.zeros((grids.n_elements, n, n))
    for e in range(grids.n_elements):
        cells = grids.mask[e]
        rc = grids.pixels[e][cells]
        out[e][cells] = map_coordinates(img, rc.T, order=1, mode="constant", cval=0.0,
                                        prefilter=False)
    return out


def integrate(patches, grids: RegionGrids) -> tuple[np.ndarray, np.ndarray]:
    """Step 5: integrated grey value and first moments of every region.

    Parameters
    ----------
    patches : (E, n, n) array_like
        Dewarped grey values (:func:`dewarp`).
    grids : RegionGrids

    Returns
    -------
    G : (E,) ndarray
        ``sum(value * area)`` over the region's cells (grey level x mm^2).
    M : (E, 2) ndarray
        ``sum(value * area * (x, y))``: the first moments; the centroid is
        ``M / G``.
    """
    p = np.asarray(patches, dtype=np.float64)
    wa = p * grids.area
    g = wa.sum(axis=(1, 2))
    mx = (wa.sum(axis=1) * grids.coords).sum(axis=1)
    my = (wa.sum(axis=2) * grids.coords).sum(axis=1)
    return g, np.stack([mx, my], axis=-1)


@dataclass(frozen=True, eq=False)
class RegionWeights:
    """Per-(element, pixel) weights: the dewarp, areas and coordinates folded together.

    Entries are sorted by pixel (so a frame is read in memory order), then
    element; a pixel feeding two regions (only possible where regions
    touch) has one entry for each. Made by :func:`region_weights`; a
    pipeline's are :attr:`optitact.pipeline.frame_pipeline.Pipeline.region_weights`.

    Attributes
    ----------
    pixel : (n_entries,) intp ndarray
        Flat pixel index of the entry (``row * W + col``).
    label : (n_entries,) intp ndarray
        Element of the entry.
    weights : (3, n_entries) ndarray
        Dome area (mm^2) the pixel gives its region, and area times the
        element-local ``x`` and ``y`` (mm^3).
    pixel_area : (E,) ndarray
        Mean dome area (mm^2) per footprint pixel of each region.
    n_pixels : (E,) ndarray
        Footprint pixels of each region.
    radius, grid_mm : float
        Region radius and dewarp cell size (mm) of the grids they were
        folded from (:func:`split_regions`).
    """

    pixel: np.ndarray
    label: np.ndarray
    weights: np.ndarray
    pixel_area: np.ndarray
    n_pixels: np.ndarray
    radius: float = math.nan
    grid_mm: float = math.nan

    def region_pixels(self, elements=None) -> tuple[np.ndarray, np.ndarray]:
        """The pixels the regions of ``elements`` read, and the element of each.

        Parameters
        ----------
        elements : array_like of int or bool mask, optional
            Element indices (or an ``(E,)`` bool mask); default all.

        Returns
        -------
        pixel, label : (n,) intp ndarrays
            Flat pixel indices (``row * W + col``, sorted) and their element;
            a pixel on the border of two regions appears once for each.
        """
        if elements is None:
            return self.pixel, self.label
        sel = np.asarray(elements)
        if sel.dtype == bool:
            sel = np.flatnonzero(sel)
        keep = np.isin(self.label, sel)
        return self.pixel[keep], self.label[keep]


def _fold_element(e: int, cells: np.ndarray, rc: np.ndarray, area: np.ndarray, coords: np.ndarray,
                  n_el: int, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Element ``e``'s part of :func:`region_weights`: sorted keys ``pixel * E + e`` and (3, n) weights.

    ``cells`` are the flat indices (increasing) of the region's cells in the
    ``(n, n)`` grid, ``rc`` their pixel positions and ``area`` their areas.
    Contributions to one pixel are summed in the order (corner, cell), the
    same as when all elements are folded at once; the sums run over a dense
    index of the region's bounding box of pixels (no sort).
    """
    i_idx, j_idx = np.divmod(cells, len(coords))
    x, y = coords[j_idx], coords[i_idx]
    r0 = np.minimum(np.floor(rc[:, 0]).astype(np.int64), h - 2)
    c0 = np.minimum(np.floor(rc[:, 1]).astype(np.int64), w - 2)
    fr, fc = rc[:, 0] - r0, rc[:, 1] - c0
    pix, bw = [], []
    for dr, dc, wt in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                       (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        keep = wt > 0
        pix.append((r0[keep] + dr) * w + c0[keep] + dc)
        bw.append(np.stack([wt * area, wt * area * x, wt * area * y])[:, keep])
    pix, bw = np.concatenate(pix), np.concatenate(bw, axis=1)
    if not len(pix):
        return np.zeros(0, np.int64), np.zeros((3, 0))
    rows, cols = np.divmod(pix, w)
    top, left = rows.min(), cols.min()
    width = cols.max() - left + 1
    local = (rows - top) * width + (cols - left)  # increasing with the pixel index
    size = int(local.max()) + 1
    used = np.flatnonzero(np.bincount(local, minlength=size))
    keys = ((used // width + top) * w + used % width + left) * n_el + e
    return keys, np.stack([np.bincount(local, bw[k], minlength=size)[used] for k in range(3)])


def _assemble(parts: list, n_el: int, radius: float, grid_mm: float) -> RegionWeights:
    """The elements' folded parts as one :class:`RegionWeights`, entries sorted by pixel then element."""
    keys = np.concatenate([k for k, _ in parts])
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    weights = np.concatenate([wt for _, wt in parts], axis=1)[:, order]
    pixel, label = np.divmod(keys, n_el)
    n_pix = np.bincount(label, minlength=n_el)
    region_area = np.bincount(label, weights[0], minlength=n_el)
    pixel_area = np.divide(region_area, n_pix, out=np.zeros(n_el), where=n_pix > 0)
    return _weights(pixel.astype(np.intp), label.astype(np.intp), weights, pixel_area, n_pix, radius, grid_mm)


def _weights(pixel, label, weights, pixel_area, n_pixels, radius, grid_mm) -> RegionWeights:
    for arr in (pixel, label, weights, pixel_area, n_pixels):
        arr.flags.writeable = False
    return RegionWeights(pixel, label, weights, pixel_area, n_pixels, float(radius), float(grid_mm))


@lru_cache(maxsize=2)
def region_weights(grids: RegionGrids, shape: tuple[int, int]) -> RegionWeights:
    """Fold bilinear dewarp weights, cell areas and cell coordinates into per-pixel weights.

    ``W_e(p) = sum over cells c of region e of B(c, p) * area(c) * (1, x_c, y_c)``,
    with ``B(c, p)`` the bilinear weight of pixel ``p`` at cell ``c``'s pixel
    position, so that ``sum_c dewarp(I)(c) area(c) (1, x, y) = sum_p W_e(p) I(p)``.
    Cached per (grids, shape). :func:`fold_regions` gives the same weights
    without building the grids, cached on disk.

    Parameters
    ----------
    grids : RegionGrids
        From :func:`split_regions`.
    shape : (int, int)
        The image's ``(H, W)`` (the camera's ``shape``).

    Returns
    -------
    RegionWeights
    """
    h, w = shape
    n_el = grids.n_elements
    parts = []
    for e in range(n_el):  # one element at a time
        cells = np.flatnonzero(grids.mask[e])
        parts.append(_fold_element(e, cells, grids.pixels[e].reshape(-1, 2)[cells],
                                   grids.area[e].reshape(-1)[cells], grids.coords, n_el, h, w))
    return _assemble(parts, n_el, grids.radius, grids.grid_mm)


def _fold(sensor: DomeSensor, camera: Camera, radius: float, grid_mm: float) -> RegionWeights:
    """:func:`region_weights` of :func:`split_regions`, folded element by element without the grids."""
    h, w = camera.shape
    n_el = sensor.n_elements
    cells = _region_cells(sensor, camera, radius, grid_mm)
    coords, cell_area = next(cells)
    flat_area = cell_area.reshape(-1)
    parts = [_fold_element(e, idx, rc, flat_area[idx], coords, n_el, h, w) for e, idx, rc in cells]
    return _assemble(parts, n_el, radius, grid_mm)


def _check_folded(arrays: dict, n_el: int, n_px: int) -> None:
    """ValueError unless ``arrays`` make a consistent RegionWeights of ``n_el`` regions, ``n_px`` pixels."""
    pixel, label, weights = arrays["pixel"], arrays["label"], arrays["weights"]
    pixel_area, n_pixels, geometry = arrays["pixel_area"], arrays["n_pixels"], arrays["geometry"]
    n = len(pixel)
    if not (pixel.dtype == label.dtype == np.intp and pixel.shape == label.shape == (n,)
            and weights.dtype == pixel_area.dtype == geometry.dtype == np.float64
            and weights.shape == (3, n) and pixel_area.shape == n_pixels.shape == (n_el,)
            and n_pixels.dtype.kind == "i" and geometry.shape == (2,)):
        raise ValueError("folded region weights: wrong dtypes or shapes")
    if n and not (0 <= pixel[0] and pixel[-1] < n_px and 0 <= label.min() and label.max() < n_el):
        raise ValueError("folded region weights: index out of range")
    keys = pixel * n_el + label
    if np.any(keys[1:] <= keys[:-1]) or not np.array_equal(np.bincount(label, minlength=n_el), n_pixels):
        raise ValueError("folded region weights: entries not sorted or not counted")
    if not (np.isfinite(weights).all() and np.isfinite(pixel_area).all() and np.all(geometry > 0)):
        raise ValueError("folded region weights: not finite")


@lru_cache(maxsize=4)
def _fold_cached(sensor: DomeSensor, camera: Camera, radius, grid_mm) -> RegionWeights:
    from optitact.io.cache import cached_arrays

    def build() -> dict:
        r, g = _resolve_geometry(sensor, camera, radius, grid_mm)
        w = _fold(sensor, camera, r, g)
        return dict(pixel=w.pixel, label=w.label, weights=w.weights, pixel_area=w.pixel_area,
                    n_pixels=w.n_pixels, geometry=np.array([r, g]))

    key = {"what": "region_weights", "sensor": sensor.to_dict(), "camera": camera.to_dict(),
           "radius": radius, "grid_mm": grid_mm}
    a = cached_arrays("precompute", key, build,
                      lambda arrays: _check_folded(arrays, sensor.n_elements, camera.height * camera.width))
    r, g = (float(v) for v in a["geometry"])
    return _weights(a["pixel"], a["label"], a["weights"], a["pixel_area"], a["n_pixels"], r, g)


def fold_regions(sensor: DomeSensor, camera: Camera, *, radius: float | None = None,
                 grid_mm: float | None = None, cache: bool = True) -> RegionWeights:
    """The fast pipeline's precompute: :func:`region_weights` of :func:`split_regions`, cached on disk.

    The same weights, bit for bit, folded element by element without
    building the ``(E, n, n)`` grids, and kept in the user cache folder
    (``precompute/`` in :func:`optitact.io.cache.cache_dir`) keyed by the
    sensor, the camera, ``radius``, ``grid_mm`` and the package's and
    NumPy's versions: a second process loads them in milliseconds instead
    of folding again (about 0.5 s at 640x480, 2 s at 1280x960). The last
    few are also kept in memory.

    Parameters
    ----------
    sensor : DomeSensor
    camera : Camera
    radius, grid_mm : float, optional
        As for :func:`split_regions`.
    cache : bool
        False: fold now, neither reading nor writing any cache. The
        environment variable ``OPTITACT_PRECOMPUTE_CACHE=0`` turns the disk
        cache off everywhere.

    Returns
    -------
    RegionWeights
        With the geometry's ``radius`` and ``grid_mm`` (defaults filled in).

    Raises
    ------
    TypeError, InputError
        As :func:`split_regions`.
    """
    check_type(sensor, DomeSensor, "sensor")
    check_type(camera, Camera, "camera")
    if not cache:
        return _fold(sensor, camera, *_resolve_geometry(sensor, camera, radius, grid_mm))
    return _fold_cached(sensor, camera, radius, grid_mm)


def forget_folded_weights() -> None:
    """Forget the folded weights :func:`fold_regions` keeps in memory (not the files of the cache folder).

    The next :func:`fold_regions` of a sensor and camera loads them from the
    cache folder, or folds them again when that is off: what a new process
    would do (the precompute benchmark times both).
    """
    _fold_cached.cache_clear()


def deferred_grids(sensor: DomeSensor, camera: Camera, radius: float, grid_mm: float) -> RegionGrids:
    """:func:`split_regions` of the resolved geometry, its arrays built on first use.

    ``radius`` and ``grid_mm`` are the resolved values (those of a
    :class:`RegionWeights`); the coordinates, radius, cell size and number
    of regions are there at once.
    """
    build = partial(_grid_arrays, sensor, camera, radius, grid_mm)
    return RegionGrids(_coords(radius, grid_mm), float(grid_mm), float(radius), None, None, None,
                       n_elements=sensor.n_elements, build=build)


def _grid_arrays(sensor: DomeSensor, camera: Camera, radius: float, grid_mm: float) -> tuple:
    """``(pixels, area, mask)`` of :func:`split_regions` (a module function: deferred grids pickle)."""
    g = split_regions(sensor, camera, radius=radius, grid_mm=grid_mm)
    return g.pixels, g.area, g.mask
