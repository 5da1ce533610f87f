"""Element regions on the dome: the dewarp grids and the per-pixel weights they fold into.

:func:`split_regions` (once per sensor and camera) lays a fine grid of
geodesic tangent coordinates around every element, cut to the element's
Voronoi cell within a radius; :func:`dewarp` resamples an image onto those
grids and :func:`integrate` sums them (steps 4-5 of
:mod:`optitact.pipeline`). :func:`region_weights` folds the bilinear dewarp
weights, cell areas and coordinates into per-(element, pixel) weights, the
fast pipeline's sums; :meth:`RegionWeights.region_pixels` names the pixels
an element's region reads (what the renderer needs to render only those).

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
from functools import lru_cache

import numpy as np

from ._validate import check_type, positive
from .camera import Camera
from .errors import InputError
from .sensor import DomeSensor

__all__ = ["OVERSAMPLE", "REGION_MARGIN_MM", "RegionGrids", "RegionWeights", "default_region_radius", "dewarp",
           "integrate", "region_weights", "split_regions"]

#: Margin (mm) added to the farthest reach of a cone's patch for the default region radius.
REGION_MARGIN_MM = 0.5
#: Grid cells per smallest pixel footprint in the default dewarp grid.
OVERSAMPLE = 2.5


@dataclass(frozen=True, eq=False)
class RegionGrids:
    """The 41 element regions as fine grids on the dome, with their pixel maps.

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

    coords: np.ndarray
    grid_mm: float
    radius: float
    pixels: np.ndarray
    area: np.ndarray
    mask: np.ndarray

    @property
    def n_elements(self) -> int:
        """Number of regions."""
        return self.mask.shape[0]


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


@lru_cache(maxsize=8)
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
    """
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
    grid_mm = positive(grid_mm, "grid_mm")
    if grid_mm > radius:
        raise InputError(f"grid_mm must be at most the region radius {radius:g} mm, got {grid_mm!r}")
    half = math.ceil(radius / grid_mm)
    if 2 * half + 1 > 2001:
        raise InputError(f"grid_mm={grid_mm} is too fine for radius={radius} "
                         f"({2 * half + 1} cells per side; at most 2001)")
    coords = (np.arange(2 * half + 1) - half) * grid_mm
    gx, gy = np.meshgrid(coords, coords)  # x along columns, y along rows
    offsets = np.stack([gx, gy], axis=-1)
    rho = np.hypot(gx, gy)
    n_el = sensor.n_elements
    r_out = sensor.outer_radius
    normals = sensor.element_frames[:, 2, :]
    mask = np.zeros((n_el,) + rho.shape, bool)
    within = np.flatnonzero(rho <= radius)
    pixels = np.full(mask.shape + (2,), -10.0)
    # One element at a time, over the cells within the radius: the temporaries stay a few times
    # one element's grid (all elements' products at once took 3 GB at 2560 x 1920).
    for e in range(n_el):
        pts = sensor.dome_point(np.full(len(within), e), offsets.reshape(-1, 2)[within])  # (m, 3)
        nearest = np.argmax(np.einsum("ik,fk->if", pts, normals), axis=-1)
        keep = (nearest == e) & camera.visible(pts, sensor)
        mask[e].reshape(-1)[within[keep]] = True
        if keep.any():
            pixels[e].reshape(-1, 2)[within[keep]] = camera.project(pts[keep], sensor)
    h, w = camera.shape
    inside = ((pixels[..., 0] >= 0) & (pixels[..., 0] <= h - 1)
              & (pixels[..., 1] >= 0) & (pixels[..., 1] <= w - 1))
    mask &= inside
    pixels[~mask] = -10.0
    x = rho / r_out
    area = grid_mm**2 * np.where(x > 0, np.sin(x) / np.where(x > 0, x, 1.0), 1.0)
    area = np.where(mask, area[None], 0.0)
    for arr in (coords, pixels, area, mask):
        arr.flags.writeable = False
    return RegionGrids(coords, float(grid_mm), float(radius), pixels, area, mask)


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
    pipeline's are :attr:`optitact.Pipeline.region_weights`.

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
    """

    pixel: np.ndarray
    label: np.ndarray
    weights: np.ndarray
    pixel_area: np.ndarray
    n_pixels: np.ndarray

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


def _element_weights(grids: RegionGrids, e: int, h: int, w: int) -> tuple[np.ndarray, np.ndarray]:
    """Element ``e``'s part of :func:`region_weights`: sorted keys ``pixel * E + e`` and (3, n) weights.

    Contributions to one pixel are summed in the order (corner, cell), the
    same as when all elements are folded at once.
    """
    i_idx, j_idx = np.nonzero(grids.mask[e])
    rc = grids.pixels[e, i_idx, j_idx]
    a = grids.area[e, i_idx, j_idx]
    x, y = grids.coords[j_idx], grids.coords[i_idx]
    r0 = np.minimum(np.floor(rc[:, 0]).astype(np.int64), h - 2)
    c0 = np.minimum(np.floor(rc[:, 1]).astype(np.int64), w - 2)
    fr, fc = rc[:, 0] - r0, rc[:, 1] - c0
    pix, bw = [], []
    for dr, dc, wt in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                       (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        keep = wt > 0
        pix.append((r0[keep] + dr) * w + c0[keep] + dc)
        bw.append(np.stack([wt * a, wt * a * x, wt * a * y])[:, keep])
    pix, bw = np.concatenate(pix), np.concatenate(bw, axis=1)
    keys, inverse = np.unique(pix * grids.n_elements + e, return_inverse=True)
    return keys, np.stack([np.bincount(inverse, bw[k], minlength=len(keys)) for k in range(3)])


@lru_cache(maxsize=8)
def region_weights(grids: RegionGrids, shape: tuple[int, int]) -> RegionWeights:
    """Fold bilinear dewarp weights, cell areas and cell coordinates into per-pixel weights.

    ``W_e(p) = sum over cells c of region e of B(c, p) * area(c) * (1, x_c, y_c)``,
    with ``B(c, p)`` the bilinear weight of pixel ``p`` at cell ``c``'s pixel
    position, so that ``sum_c dewarp(I)(c) area(c) (1, x, y) = sum_p W_e(p) I(p)``.
    Cached per (grids, shape).

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
    parts = [_element_weights(grids, e, h, w) for e in range(n_el)]  # one element at a time
    keys = np.concatenate([k for k, _ in parts])
    order = np.argsort(keys, kind="stable")
    keys = keys[order]
    weights = np.concatenate([wt for _, wt in parts], axis=1)[:, order]
    pixel, label = np.divmod(keys, n_el)
    n_pix = np.bincount(label, minlength=n_el)
    region_area = np.bincount(label, weights[0], minlength=n_el)
    pixel_area = np.divide(region_area, n_pix, out=np.zeros(n_el), where=n_pix > 0)
    pixel, label = pixel.astype(np.intp), label.astype(np.intp)
    for arr in (pixel, label, weights, pixel_area, n_pix):
        arr.flags.writeable = False
    return RegionWeights(pixel, label, weights, pixel_area, n_pix)
