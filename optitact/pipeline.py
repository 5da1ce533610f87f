"""The frame pipeline: camera frames to per-element readings (G, u, contact, saturated).

Steps, each a public function (the ``"reference"`` method runs them in turn):

1. :func:`subtract_baseline` -- subtract the no-load frame, clip at zero;
2. :func:`denoise` -- none, Gaussian or median filter;
3. :func:`apply_threshold` -- zero every pixel at or below ``k`` sigma of the noise;
4. :func:`split_regions` (once) and :func:`dewarp` -- resample the image onto
   a fine grid of geodesic tangent coordinates around every element, with
   the closed-form camera model; the grid cells carry their area on the
   dome and their region (Voronoi cell of the element, cut at a radius);
5. :func:`integrate` -- integrated grey value G and grey-value centroid per
   region; :func:`readings_from_moments` turns them into :class:`Readings`
   (no contact -> G = 0, u = 0). G sums the lit values; the centroid weighs
   each lit value by its height above the threshold, ``value - threshold``,
   so that a pixel's weight grows from 0 as it crosses the threshold instead
   of jumping (see :class:`Pipeline`, *Notes*).

The ``"fast"`` method (default) computes the same sums with the linear
stages folded into per-pixel weights: the bilinear dewarp weights times the
cells' areas and coordinates, summed per (element, pixel). A frame then costs
one comparison pass over the frame to find the lit pixels and a few weighted
sums over those.

Convention
----------
Images are ``(row, col)`` with the origin at the top-left pixel centre; grey
levels are the frame's own units (DN for camera frames). Region grids use
element-local tangent coordinates ``(x, y)`` in mm, geodesic normal
coordinates around the element centre (``sensor.dome_point(e, (x, y))`` is
the dome point of grid coordinate ``(x, y)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from ._validate import integer, positive
from .camera import FisheyeCamera, _radial_map
from .errors import InputError, ShapeError
from .readings import Readings
from .sensor import DomeSensor

__all__ = [
    "Pipeline",
    "RegionGrids",
    "apply_threshold",
    "check_frames",
    "default_region_radius",
    "denoise",
    "dewarp",
    "estimate_noise",
    "integrate",
    "readings_from_moments",
    "split_regions",
    "subtract_baseline",
]

FILTERS = ("none", "gaussian", "median")
METHODS = ("fast", "reference")
#: Margin (mm) added to the farthest reach of a cone's patch for the default region radius.
REGION_MARGIN_MM = 0.5
#: Grid cells per smallest pixel footprint in the default dewarp grid.
OVERSAMPLE = 2.5
#: Frames processed together by the fast method (bounds its temporary memory).
CHUNK_FRAMES = 64
#: Largest grey-level magnitude a frame or baseline may hold: sums over a region (G, its
#: moments) and the squares in the noise estimates then stay far inside float64's range.
MAX_GREY = 1e100
#: Smallest G (grey level x mm^2) that can read as contact: below it the sums are made of
#: subnormal numbers, whose rounding would make the centroid meaningless.
G_MIN = 1e-250


# ---------------------------------------------------------------------------- input checks
def check_frames(frames, camera: FisheyeCamera, name: str = "frames") -> tuple[np.ndarray, bool]:
    """Validate a frame ``(H, W)`` or stack ``(T, H, W)`` for a camera.

    Returns
    -------
    stack : (T, H, W) ndarray
        The input as a stack (a view where possible; never modified).
        float16 frames come back as float32 and extended-precision floats
        as float64 (both exact for the accepted range).
    single : bool
        True when a single 2-D frame came in.

    Raises
    ------
    TypeError
        For a non-numeric, bool, complex or object dtype, or nested
        sequences that do not form an array.
    ShapeError
        If the array is not 2-D or 3-D or its image size is not the camera's
        ``(height, width)``.
    InputError
        For an empty stack, a NaN or infinite pixel, a float pixel beyond
        ``MAX_GREY`` in magnitude, or a negative value in an integer frame.
    """
    try:
        arr = np.asarray(frames)
    except (ValueError, TypeError) as exc:  # ragged nested sequences
        raise TypeError(f"{name} must be an array of grey levels (H, W) or (T, H, W); "
                        f"could not make one ({exc})") from None
    if arr.dtype.kind not in "uif":
        raise TypeError(f"{name} must have an unsigned/signed integer or float dtype "
                        f"(uint8, uint16, float32, float64), got {arr.dtype}")
    if arr.ndim not in (2, 3):
        raise ShapeError(f"{name} must be a frame (H, W) or a stack (T, H, W), got shape {arr.shape}")
    if arr.shape[-2:] != camera.shape:
        raise ShapeError(f"{name} must be {camera.shape[0]}x{camera.shape[1]} (H, W) for this camera, "
                         f"got {arr.shape[-2]}x{arr.shape[-1]}")
    single = arr.ndim == 2
    stack = arr[None] if single else arr
    if stack.shape[0] == 0:
        raise InputError(f"{name} is an empty stack (0 frames)")
    if arr.dtype.kind == "f":
        if not _within_max_grey(stack):
            ok = np.isfinite(stack)
            if not ok.all():
                t, r, c = (int(i) for i in np.argwhere(~ok)[0])
                raise InputError(f"{name} must be finite, got {stack[t, r, c]} at frame {t}, "
                                 f"pixel (row {r}, col {c})")
            t, r, c = (int(i) for i in np.argwhere(np.abs(stack) > MAX_GREY)[0])
            raise InputError(f"{name} must hold grey levels of magnitude at most {MAX_GREY:g}, got "
                             f"{stack[t, r, c]} at frame {t}, pixel (row {r}, col {c})")
        if arr.dtype.itemsize < 4:
            stack = stack.astype(np.float32)
        elif arr.dtype.itemsize > 8:
            stack = stack.astype(np.float64)
    elif arr.dtype.kind == "i" and stack.size and stack.min() < 0:
        t, r, c = (int(i) for i in np.argwhere(stack < 0)[0])
        raise InputError(f"{name} must be non-negative grey levels, got {stack[t, r, c]} at "
                         f"frame {t}, pixel (row {r}, col {c})")
    return stack, single


def _within_max_grey(arr: np.ndarray) -> bool:
    """True when a non-empty float array is finite and within ``MAX_GREY`` in magnitude."""
    bound = np.asarray(MAX_GREY, dtype=np.result_type(arr.dtype, np.float64))
    return bool(arr.min() >= -bound and arr.max() <= bound)  # NaN fails both


def _mean0(frames: np.ndarray) -> np.ndarray:
    """Mean over the first axis of a float64 array, to float64 rounding for any length.

    Pairwise sums (error growing as log T, where numpy's reduction over the
    first axis grows as T), then one correction pass: the pairwise mean of
    the residuals, which are small, is added back.
    """
    t_n = frames.shape[0]
    mean = _pairwise_sum0(frames) / t_n
    return mean + _pairwise_sum0(frames - mean) / t_n


def _pairwise_sum0(a: np.ndarray) -> np.ndarray:
    """Sum over the first axis by pairwise halving (a new array)."""
    while a.shape[0] > 1:
        half = a.shape[0] // 2
        total = a[:half] + a[half:2 * half]
        if a.shape[0] % 2:
            total[0] += a[-1]
        a = total
    return np.array(a[0])


def _var0(frames: np.ndarray) -> np.ndarray:
    """Sample variance (ddof = 1) over the first axis, with :func:`_mean0`'s accuracy."""
    dev = frames - _mean0(frames)
    return _pairwise_sum0(dev * dev) / (frames.shape[0] - 1)


def _saturation_level(dtype: np.dtype, saturation: float | None) -> float:
    if saturation is not None:
        return saturation
    if dtype.kind in "ui":
        return float(np.iinfo(dtype).max)
    return math.inf


# ---------------------------------------------------------------------------- steps
def subtract_baseline(frame, baseline=None, *, clip: bool = True) -> np.ndarray:
    """Step 1: ``frame - baseline`` in float64, clipped at 0 (a new array).

    Parameters
    ----------
    frame : (H, W) array_like
    baseline : (H, W) array_like or None
        The no-load frame (for example the mean of the first frames of a
        stream); None subtracts nothing.
    clip : bool
        Clip at zero (default). The pipeline keeps the sign when a filter
        follows, so that the filter averages zero-mean noise; its threshold
        (>= 0) then does the clipping.
    """
    img = np.asarray(frame, dtype=np.float64)
    if baseline is not None:
        b = np.asarray(baseline, dtype=np.float64)
        if b.shape != img.shape:
            raise ShapeError(f"baseline must have the frame's shape {img.shape}, got {b.shape}")
        img = img - b
    return np.maximum(img, 0.0) if clip else np.array(img)


def _gaussian_kernel(size: float) -> np.ndarray:
    import cv2

    radius = max(1, math.ceil(3.0 * size))
    return cv2.getGaussianKernel(2 * radius + 1, size, cv2.CV_64F).ravel()


def filter_radius(method: str, size: float) -> int:
    """Pixels on each side that a filter reads (0 for ``"none"``)."""
    if method == "gaussian":
        return (len(_gaussian_kernel(size)) - 1) // 2
    if method == "median":
        return int(size) // 2
    return 0


def denoise(image, *, method: str = "none", size: float = 1.0) -> np.ndarray:
    """Step 2: denoise a float image (a new array).

    Parameters
    ----------
    image : (H, W) array_like
    method : {"none", "gaussian", "median"}
        ``"gaussian"``: separable Gaussian of standard deviation ``size``
        pixels, truncated at ``ceil(3 size)``; ``"median"``: median over a
        ``size x size`` window (odd integer ``size``). Borders reflect
        (``cv2.BORDER_REFLECT_101`` / ``mode="mirror"``).
    size : float
        The filter's size (see ``method``).
    """
    img = np.array(image, dtype=np.float64)
    if method == "none":
        return img
    if method == "gaussian":
        import cv2

        k = _gaussian_kernel(size)
        return cv2.sepFilter2D(img, cv2.CV_64F, k, k, borderType=cv2.BORDER_REFLECT_101)
    if method == "median":
        from scipy.ndimage import median_filter

        return median_filter(img, size=int(size), mode="mirror")
    raise InputError(f"filter must be one of {FILTERS}, got {method!r}")


def apply_threshold(image, threshold: float) -> np.ndarray:
    """Step 3: keep pixels above ``threshold``, zero the rest (a new float64 array)."""
    img = np.asarray(image, dtype=np.float64)
    return np.where(img > threshold, img, 0.0)


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


def _smallest_footprint(sensor: DomeSensor, camera: FisheyeCamera, radius: float) -> float:
    """Smallest dome length (mm) one pixel spans, over points in the regions."""
    ang = np.linspace(0, 2 * np.pi, 8, endpoint=False)
    ring = np.concatenate([[[0.0, 0.0]], radius * np.stack([np.cos(ang), np.sin(ang)], 1)])
    e = np.repeat(np.arange(sensor.n_elements), len(ring))
    pts = sensor.dome_point(e, np.tile(ring, (sensor.n_elements, 1)))
    theta = np.arccos(np.clip(pts[:, 2] / sensor.outer_radius, -1, 1))
    pts = pts[theta <= _radial_map(sensor, camera.z).theta_max]
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
def split_regions(sensor: DomeSensor, camera: FisheyeCamera, *, radius: float | None = None,
                  grid_mm: float | None = None) -> RegionGrids:
    """Step 4a (once per sensor and camera): the element regions as dome grids.

    Parameters
    ----------
    sensor : DomeSensor
    camera : FisheyeCamera
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
    radius = default_region_radius(sensor) if radius is None else positive(radius, "radius")
    if radius > math.pi * sensor.outer_radius:
        raise InputError(f"radius must be at most half a great circle of the dome, "
                         f"{math.pi * sensor.outer_radius:g} mm, got {radius!r}")
    if grid_mm is None:
        grid_mm = _smallest_footprint(sensor, camera, radius) / OVERSAMPLE
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
    pts = sensor.dome_point(np.arange(n_el)[:, None, None], offsets[None])  # (E, n, n, 3)
    normals = sensor.element_frames[:, 2, :]
    nearest = np.argmax(np.einsum("eijk,fk->eijf", pts, normals), axis=-1)
    theta = np.arccos(np.clip(pts[..., 2] / r_out, -1.0, 1.0))
    mask = ((rho <= radius)[None] & (nearest == np.arange(n_el)[:, None, None])
            & (theta <= _radial_map(sensor, camera.z).theta_max))
    pixels = np.full(mask.shape + (2,), -10.0)
    pixels[mask] = camera.project(pts[mask], sensor)
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


def readings_from_moments(G, M, saturated, floor, *, weight=None) -> Readings:
    """Turn integrated values and moments into readings.

    Parameters
    ----------
    G : (E,) or (T, E) array_like
        Integrated grey value of each region.
    M : (E, 2) or (T, E, 2) array_like
        First moments of the centroid's weights (see ``weight``).
    saturated : bool array_like, shape of ``G``
    floor : (E,) array_like
        Noise floor of G per region.
    weight : array_like, shape of ``G``, optional
        Sum of the centroid's weights, ``u = M / weight``; default ``G``
        (the plain grey-value centroid). The pipeline weighs each lit value by
        its height above the threshold (see :class:`Pipeline`).

    Notes
    -----
    A region is in contact when ``G > floor`` and ``G > G_MIN`` (1e-250:
    smaller sums are built of subnormal numbers); then ``u = M / weight``.
    Regions not in contact read ``G = 0``, ``u = (0, 0)`` (never NaN).
    """
    g = np.asarray(G, dtype=np.float64)
    m = np.asarray(M, dtype=np.float64)
    w = g if weight is None else np.asarray(weight, dtype=np.float64)
    contact = (g > floor) & (g > G_MIN)
    g = np.where(contact, g, 0.0)
    u = np.divide(m, w[..., None], out=np.zeros(m.shape), where=(contact & (w > 0))[..., None])
    return Readings(g, u, contact, np.asarray(saturated, dtype=bool))


def estimate_noise(frames) -> float:
    """Temporal noise (grey levels, rms) of a no-load stack ``(T, H, W)``, ``T >= 2``.

    The square root of the mean over pixels of the per-pixel sample variance.
    """
    try:
        arr = np.asarray(frames)
    except (ValueError, TypeError) as exc:
        raise TypeError(f"frames must be a real numeric stack (T, H, W); could not make one ({exc})") from None
    if arr.ndim != 3 or arr.shape[0] < 2:
        raise ShapeError(f"estimate_noise needs a stack (T, H, W) with T >= 2, got {arr.shape}")
    if arr.dtype.kind not in "uif":
        raise TypeError(f"frames must be a real numeric stack, got dtype {arr.dtype}")
    if arr.dtype.kind == "f" and not np.isfinite(arr).all():
        raise InputError("frames must be finite")
    if arr.size and arr.dtype.kind == "f" and not _within_max_grey(arr):
        raise InputError(f"frames must hold grey levels of magnitude at most {MAX_GREY:g}, got "
                         f"{np.abs(arr).max()}")
    var = _var0(arr.astype(np.float64))
    return float(np.sqrt(var.mean())) if var.size else 0.0


# ---------------------------------------------------------------------------- the fold
@dataclass(frozen=True, eq=False)
class _Fold:
    """Per-(element, pixel) weights: the dewarp, areas and coordinates folded together.

    Entries are sorted by pixel (so a frame is read in memory order), then
    element; a pixel feeding two regions (only possible where regions
    touch) has one entry for each.
    """

    pixel: np.ndarray      # (n_entries,) flat pixel index (row * W + col)
    label: np.ndarray      # (n_entries,) element of the entry
    weights: np.ndarray    # (3, n_entries): dome area (mm^2) the pixel gives its region,
                           # area * x and area * y (mm^3)
    pixel_area: np.ndarray  # (E,) mean dome area (mm^2) per footprint pixel of each region
    n_pixels: np.ndarray   # (E,) footprint pixels of each region


@lru_cache(maxsize=8)
def _fold(grids: RegionGrids, shape: tuple[int, int]) -> _Fold:
    """Fold bilinear dewarp weights, cell areas and cell coordinates into per-pixel weights.

    ``W_e(p) = sum over cells c of region e of B(c, p) * area(c) * (1, x_c, y_c)``,
    with ``B(c, p)`` the bilinear weight of pixel ``p`` at cell ``c``'s pixel
    position, so that ``sum_c dewarp(I)(c) area(c) (1, x, y) = sum_p W_e(p) I(p)``.
    """
    h, w = shape
    e_idx, i_idx, j_idx = np.nonzero(grids.mask)
    rc = grids.pixels[e_idx, i_idx, j_idx]
    a = grids.area[e_idx, i_idx, j_idx]
    x, y = grids.coords[j_idx], grids.coords[i_idx]
    r0 = np.minimum(np.floor(rc[:, 0]).astype(np.int64), h - 2)
    c0 = np.minimum(np.floor(rc[:, 1]).astype(np.int64), w - 2)
    fr, fc = rc[:, 0] - r0, rc[:, 1] - c0
    pix, ele, bw = [], [], []
    for dr, dc, wt in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc),
                       (1, 0, fr * (1 - fc)), (1, 1, fr * fc)):
        keep = wt > 0
        pix.append((r0[keep] + dr) * w + c0[keep] + dc)
        ele.append(e_idx[keep])
        bw.append(np.stack([wt * a, wt * a * x, wt * a * y])[:, keep])
    pix, ele, bw = np.concatenate(pix), np.concatenate(ele), np.concatenate(bw, axis=1)
    n_el = grids.n_elements
    keys, inverse = np.unique(pix * n_el + ele, return_inverse=True)
    weights = np.stack([np.bincount(inverse, bw[k], minlength=len(keys)) for k in range(3)])
    pixel, label = np.divmod(keys, n_el)
    n_pix = np.bincount(label, minlength=n_el)
    region_area = np.bincount(label, weights[0], minlength=n_el)
    pixel_area = np.divide(region_area, n_pix, out=np.zeros(n_el), where=n_pix > 0)
    pixel, label = pixel.astype(np.intp), label.astype(np.intp)
    for arr in (pixel, label, weights, pixel_area, n_pix):
        arr.flags.writeable = False
    return _Fold(pixel, label, weights, pixel_area, n_pix)


# ---------------------------------------------------------------------------- the pipeline
class Pipeline:
    r"""Frames to readings for one sensor and camera; precomputes once, then processes fast.

    Parameters
    ----------
    sensor : DomeSensor
    camera : FisheyeCamera
    method : {"fast", "reference"}
        ``"fast"`` (default): the folded per-pixel weights; ``"reference"``:
        the steps one after another on the whole frame. They compute the
        same sums and agree to floating-point rounding.
    baseline : (H, W) or (T, H, W) array_like, optional
        No-load frame, or a stack of them: the mean is subtracted, and from
        two frames on their per-pixel temporal noise raises the threshold
        where the background is noisier than ``noise_sigma`` (see
        ``threshold_map``). None subtracts nothing (for frames that are
        already background-free). See :meth:`with_baseline`.
    filter : {"none", "gaussian", "median"}
        Denoising before the threshold, default ``"none"``.
    filter_size : float
        Gaussian sigma in pixels (default 1.0) or the median window (odd
        integer, default 3 when ``filter="median"``).
    noise_sigma : float
        Noise of ``frame - baseline`` per pixel, in grey levels, default 0.5
        (an 8-bit camera whose noise is mostly quantisation); use
        :func:`estimate_noise` or :meth:`from_noload` for your camera, and 0
        for noiseless frames.
    k : float
        Threshold in noise sigmas, default 3: pixels at or below
        ``k * sigma_f`` (``sigma_f``: ``noise_sigma`` after the filter, i.e.
        times the Gaussian kernel's L2 norm) count as dark.
    min_pixels : float
        Contact needs ``G`` above the region's noise floor: what
        ``min_pixels + n_false + 3 sqrt(n_false)`` independent samples just at
        the threshold would give, with ``n_false = n Q(k)`` the number of
        the region's ``n`` samples that Gaussian noise alone puts above the
        threshold on average (``Q``: the normal tail); default 3. A sample
        is a pixel, or after a Gaussian filter its correlation area
        ``1 / sum(k**2)**2 = 4 pi sigma^2`` pixels.
    saturation : float, optional
        Grey level at which a pixel is saturated; default the integer dtype's
        maximum (255, 65535), none for float frames.
    radius, grid_mm : float, optional
        Region radius and dewarp cell size (mm); see :func:`split_regions`.

    Raises
    ------
    TypeError, InputError, ShapeError
        For a wrong kind or value of an option or of the baseline (see
        :func:`check_frames`); also when ``k * noise_sigma`` or the noise
        floor would overflow float64.

    Notes
    -----
    With ``v`` a pixel's value after the baseline and the filter and ``t``
    its threshold, a region reads

    .. math::

        G = \sum_{v > t} a\,v, \qquad
        u = \frac{\sum_{v > t} a\,(x, y)\,(v - t)}{\sum_{v > t} a\,(v - t)}

    (``a``, ``x``, ``y``: the pixel's folded area and coordinates). The
    centroid's weights ``v - t`` rise continuously from 0 at the threshold:
    with the plain weights ``v``, a faint pixel flickering across the
    threshold moves the centroid by a jump of ``t`` times its lever arm,
    which dominated the centroid's noise for faint, wide spots (integer
    frames make the jump larger: the smallest lit value of an 8-bit frame at
    a 1.5 DN threshold is 2 DN). For a Gaussian spot of rms width 0.5 mm
    with the energy of a 0.5 N load, on the default camera and CCD, this
    raises the centroid's efficiency against the Cramer-Rao bound from about
    0.67 to 0.92 (:func:`optitact.stability.noise_sweep`); on rendered
    frames, whose spots are compact and bright, the centroid's noise is
    unchanged and the calibrated shear error the same or slightly lower.
    Symmetric spots keep their centroid; noiseless frames (``t = 0``) read
    the plain centroid.

    Examples
    --------
    >>> import numpy as np, optitact
    >>> s, cam = optitact.DomeSensor.default(), optitact.FisheyeCamera(width=160, height=120)
    >>> pipe = optitact.Pipeline(s, cam)
    >>> r = pipe.process(np.zeros(cam.shape, np.uint8))
    >>> r.G.shape, bool(r.contact.any())
    ((41,), False)
    """

    def __init__(self, sensor: DomeSensor, camera: FisheyeCamera, *, method: str = "fast",
                 baseline=None, filter: str = "none", filter_size: float | None = None,
                 noise_sigma: float = 0.5, k: float = 3.0, min_pixels: float = 3.0,
                 saturation: float | None = None, radius: float | None = None,
                 grid_mm: float | None = None) -> None:
        if not isinstance(sensor, DomeSensor):
            raise TypeError(f"sensor must be a DomeSensor, got {type(sensor).__name__}")
        if not isinstance(camera, FisheyeCamera):
            raise TypeError(f"camera must be a FisheyeCamera, got {type(camera).__name__}")
        if method not in METHODS:
            raise InputError(f"method must be one of {METHODS}, got {method!r}")
        if filter not in FILTERS:
            raise InputError(f"filter must be one of {FILTERS}, got {filter!r}")
        if filter_size is None:
            filter_size = 3 if filter == "median" else 1.0
        if filter == "median":
            filter_size = integer(filter_size, "filter_size", minimum=1)
            if filter_size % 2 == 0:
                raise InputError(f"filter_size of a median must be odd, got {filter_size}")
        else:
            filter_size = positive(filter_size, "filter_size")
        self.sensor, self.camera, self.method = sensor, camera, method
        self.filter, self.filter_size = filter, filter_size
        self.noise_sigma = positive(noise_sigma, "noise_sigma", allow_zero=True)
        self.k = positive(k, "k", allow_zero=True)
        self.min_pixels = positive(min_pixels, "min_pixels", allow_zero=True)
        self.saturation = None if saturation is None else positive(saturation, "saturation")
        # A separable Gaussian k (x) k scales white noise by its L2 norm, sum(k**2), and
        # correlates it over 1 / sum(k**2)**2 pixels (4 pi sigma^2).
        gain = float(np.sum(_gaussian_kernel(filter_size) ** 2)) if filter == "gaussian" else 1.0
        #: Grey level (of ``frame - baseline``, after the filter) at or below which a pixel is
        #: dark: ``k * noise_sigma`` (times the filter's noise gain); see ``threshold_map``.
        self.threshold = self.k * self.noise_sigma * gain
        if not math.isfinite(self.threshold):
            raise InputError(f"k * noise_sigma must be finite, got k={self.k!r}, "
                             f"noise_sigma={self.noise_sigma!r}")
        self._baseline_input = baseline
        self.baseline, self.noise_map = (None, None) if baseline is None \
            else self._check_baseline(baseline)
        #: Per-pixel threshold (H, W) when the baseline is a stack: ``max(threshold, k *
        #: noise_map * gain)``; None otherwise.
        if self.noise_map is None:
            self.threshold_map = None
        else:
            with np.errstate(over="ignore"):
                self.threshold_map = np.maximum(self.threshold, self.k * self.noise_map * gain)
            if not np.isfinite(self.threshold_map).all():
                raise InputError(f"k * the baseline's noise must be finite, got k={self.k!r} and a "
                                 f"noise of up to {self.noise_map.max():g} grey levels")
        self._geometry = dict(radius=radius, grid_mm=grid_mm)  # as given: replace() hits the cache
        self.grids = split_regions(sensor, camera, radius=radius, grid_mm=grid_mm)
        self._fold = _fold(self.grids, camera.shape)
        #: Per-region noise floor of G (grey level x mm^2).
        # Noise alone lights n Q(k) of a region's n independent samples on average:
        # the floor adds that count and 3 of its (Poisson) standard deviations.
        n_false = self._fold.n_pixels * gain**2 * 0.5 * math.erfc(self.k / math.sqrt(2.0))
        samples = self.min_pixels + n_false + 3.0 * np.sqrt(n_false)
        fold = self._fold
        if self.threshold_map is None:
            self._thr_entries = np.full(len(fold.pixel), self.threshold)
        else:
            self._thr_entries = self.threshold_map.reshape(-1)[fold.pixel]
        region_thr = np.bincount(fold.label, self._thr_entries, minlength=len(fold.n_pixels))
        region_thr = np.divide(region_thr, fold.n_pixels, out=np.zeros(len(fold.n_pixels)),
                               where=fold.n_pixels > 0)
        with np.errstate(over="ignore"):
            self.floor = samples / gain**2 * region_thr * fold.pixel_area
        if not np.isfinite(self.floor).all():
            raise InputError(f"the noise floor of G overflows float64 for min_pixels={self.min_pixels!r}, "
                             f"k={self.k!r}, noise_sigma={self.noise_sigma!r} and this baseline")
        self._levels: dict = {}
        self._base_entries = (np.zeros(len(self._fold.pixel)) if self.baseline is None
                              else self.baseline.reshape(-1)[self._fold.pixel])

    # ------------------------------------------------------------------ set-up
    def _check_baseline(self, baseline) -> tuple[np.ndarray, np.ndarray | None]:
        """The baseline's mean and, for a stack of two or more frames, its per-pixel noise.

        The noise map is the temporal standard deviation of the no-load frames,
        made conservative where it is estimated from few frames (the variance is
        taken as the largest in each 3 x 3 neighbourhood, then smoothed with a
        Gaussian of 1 pixel), times ``sqrt(1 + 1/T)`` for the noise of the mean.
        """
        import cv2
        from scipy.ndimage import maximum_filter

        stack, _ = check_frames(baseline, self.camera, "baseline")
        frames = stack.astype(np.float64)
        b = _mean0(frames)
        b.flags.writeable = False
        if len(frames) < 2:
            return b, None
        var = maximum_filter(_var0(frames), size=3, mode="nearest")
        var = cv2.GaussianBlur(var, (0, 0), 1.0, borderType=cv2.BORDER_REFLECT_101)
        noise = np.sqrt(np.maximum(var, 0.0) * (1.0 + 1.0 / len(frames)))
        noise.flags.writeable = False
        return b, noise

    def _options(self) -> dict:
        return dict(method=self.method, filter=self.filter, filter_size=self.filter_size,
                    noise_sigma=self.noise_sigma, k=self.k, min_pixels=self.min_pixels,
                    saturation=self.saturation, **self._geometry)

    def replace(self, **changes) -> Pipeline:
        """A pipeline with some options changed (the geometry is shared when unchanged).

        A new ``filter`` without a ``filter_size`` takes that filter's default size.
        """
        opts = self._options() | {"baseline": self._baseline_input} | changes
        if "filter" in changes and "filter_size" not in changes:
            opts["filter_size"] = None
        return Pipeline(self.sensor, self.camera, **opts)

    def with_baseline(self, frames) -> Pipeline:
        """The same pipeline with ``frames`` (a frame or the mean of a stack) as no-load baseline."""
        return self.replace(baseline=frames)

    @classmethod
    def from_noload(cls, sensor: DomeSensor, camera: FisheyeCamera, frames, **options) -> Pipeline:
        """A pipeline whose baseline and noise come from a no-load stack ``(T, H, W)``, T >= 2.

        The baseline is the stack's mean; ``noise_sigma`` is
        ``estimate_noise(frames) * sqrt(1 + 1/T)``, the noise of a frame minus
        that mean.
        """
        stack, _ = check_frames(frames, camera, "frames")
        sigma = estimate_noise(stack) * math.sqrt(1.0 + 1.0 / stack.shape[0])
        return cls(sensor, camera, baseline=stack, noise_sigma=sigma, **options)

    # ------------------------------------------------------------------ processing
    def process(self, frames) -> Readings:
        """Readings of a frame ``(H, W)`` or of every frame of a stack ``(T, H, W)``.

        Raises
        ------
        TypeError, ShapeError, InputError
            See :func:`check_frames`.
        """
        stack, single = check_frames(frames, self.camera)
        if self.method == "reference":
            out = Readings.stack([self._reference(f) for f in stack])
        elif single:
            return self._fast(stack, single=True)
        else:
            parts = [self._fast(stack[i:i + CHUNK_FRAMES])
                     for i in range(0, len(stack), CHUNK_FRAMES)]
            out = parts[0] if len(parts) == 1 else Readings.stack(parts)
        return out[0] if single else out

    def stream(self, frames, *, baseline_frames: int = 0):
        """Yield readings frame by frame from an iterable of frames.

        Parameters
        ----------
        frames : iterable of (H, W) arrays
        baseline_frames : int
            When > 0, the mean of the first ``baseline_frames`` frames becomes
            the no-load baseline; readings are yielded for every frame,
            those first ones included.
        """
        baseline_frames = integer(baseline_frames, "baseline_frames", minimum=0)
        pipe, held = self, []
        for frame in frames:
            if len(held) < baseline_frames:
                held.append(np.array(frame))
                if len(held) == baseline_frames:
                    pipe = self.with_baseline(np.stack(held))
                    yield from pipe.process(np.stack(held))
                continue
            yield pipe.process(frame)
        if 0 < len(held) < baseline_frames:
            raise InputError(f"the stream ended after {len(held)} frames, before the "
                             f"{baseline_frames} baseline frames")

    # ------------------------------------------------------------------ the two methods
    def _reference(self, frame: np.ndarray) -> Readings:
        img = subtract_baseline(frame, self.baseline, clip=self.filter == "none")
        img = denoise(img, method=self.filter, size=self.filter_size)
        thr = self.threshold if self.threshold_map is None else self.threshold_map
        img = apply_threshold(img, thr)
        g, _ = integrate(dewarp(img, self.grids), self.grids)
        # the centroid weighs each lit value by its height above the threshold
        w, m = integrate(dewarp(np.where(img > thr, img - thr, 0.0), self.grids), self.grids)
        level = _saturation_level(frame.dtype, self.saturation)
        hot = dewarp((frame >= level).astype(np.float64), self.grids)
        return readings_from_moments(g, m, (hot > 0).any(axis=(1, 2)), self.floor, weight=w)

    def _level(self, dtype: np.dtype):
        """Lit level per region entry for frames of ``dtype``, and the entries to watch for saturation.

        For integer frames an entry is lit exactly when ``frame > level``,
        ``level`` the largest grey level ``n`` with ``n - baseline <=
        threshold`` in float64, as the reference tests it. For float frames
        ``level`` lies a few ulps below ``baseline + threshold``: ``frame >
        level`` picks the candidates, and the reference's own test ``frame -
        baseline > threshold`` (float64) decides among them, so both methods
        light the same pixels even at the threshold itself. Entries whose
        level reaches the saturation level cannot show saturation by being
        lit; they are watched separately.
        """
        key = dtype.str
        if key not in self._levels:
            b, thr = self._base_entries, self._thr_entries
            sat = _saturation_level(dtype, self.saturation)
            if dtype.kind in "ui":
                top = np.iinfo(dtype).max
                # The largest n with n - b <= threshold in float64, as the reference
                # tests it: floor(b + threshold) can be one off after rounding.
                n = np.floor(b + thr)
                n += (n + 1.0) - b <= thr
                n -= n - b > thr
                level = np.clip(n, 0, top).astype(dtype)
            else:
                # safely below every x with x - b > thr: 4 ulps of the largest magnitude involved
                top = b + thr
                low = top - 4.0 * np.spacing(np.maximum(np.maximum(np.abs(b), np.abs(thr)), np.abs(top)))
                with np.errstate(over="ignore"):  # beyond float32: +inf, so never a candidate (right)
                    level = low.astype(dtype)
                down = level.astype(np.float64) > low
                level[down] = np.nextafter(level[down], -np.inf)
            if math.isinf(sat):
                watch = np.zeros(0, np.intp)
            else:
                watch = np.flatnonzero(b + thr >= sat - 1e-9 * max(1.0, sat))
            self._levels[key] = (level, watch, sat)
        return self._levels[key]

    def _fast(self, stack: np.ndarray, single: bool = False) -> Readings:
        """The folded sums over the lit entries of a stack (readings ``(T, E)``, or ``(E,)`` if single).

        Only the pixels of the regions are read (in memory order); the lit
        ones (above the level) are weighted and summed per element, so dark
        pixels cost one comparison each.
        """
        t_n = stack.shape[0]
        fold = self._fold
        n_ent, n_el = len(fold.pixel), self.grids.n_elements
        level, watch, sat = self._level(stack.dtype)
        flat = stack.reshape(t_n, -1)
        if self.filter == "none":
            # (T, n_entries) grey values of the region pixels
            g = flat[0][fold.pixel][None] if t_n == 1 else np.take(flat, fold.pixel, axis=1)
            idx = np.flatnonzero(g > level)
            e = idx if t_n == 1 else idx % n_ent
            raw = g.reshape(-1)[idx]
            v = raw - np.take(self._base_entries, e)
            hot = idx[raw >= sat]
            if stack.dtype.kind == "f":  # candidates: the reference's test decides
                keep = v > np.take(self._thr_entries, e)
                idx, e, v = idx[keep], e[keep], v[keep]
            above = np.maximum(v - np.take(self._thr_entries, e), 0.0)
            if watch.size:
                wt, wi = np.nonzero(g[:, watch] >= sat)
                hot = np.concatenate([hot, wt * n_ent + watch[wi]])
        else:
            idx, v, hot = self._filtered_lit(flat)
            e = idx % n_ent
            above = np.maximum(v - np.take(self._thr_entries, e), 0.0)
        key = fold.label[e]
        if t_n > 1:
            key = key + (idx // n_ent) * n_el
        size = t_n * n_el
        area, wx, wy = fold.weights
        g_sum = np.bincount(key, area[e] * v, minlength=size).reshape(t_n, n_el)
        w_sum = np.bincount(key, area[e] * above, minlength=size).reshape(t_n, n_el)
        m = np.empty((t_n, n_el, 2))
        m[..., 0] = np.bincount(key, wx[e] * above, minlength=size).reshape(t_n, n_el)
        m[..., 1] = np.bincount(key, wy[e] * above, minlength=size).reshape(t_n, n_el)
        saturated = np.zeros((t_n, n_el), bool)
        if hot.size:
            saturated.reshape(-1)[fold.label[hot % n_ent] + (hot // n_ent) * n_el] = True
        if single:
            return readings_from_moments(g_sum[0], m[0], saturated[0], self.floor, weight=w_sum[0])
        return readings_from_moments(g_sum, m, saturated, self.floor, weight=w_sum)

    def _filtered_lit(self, flat: np.ndarray):
        """Lit entries after the filter, computed on the crop that holds the regions plus the filter's reach."""
        h, w = self.camera.shape
        fold = self._fold
        n_ent = len(fold.pixel)
        rows, cols = np.divmod(fold.pixel, w)
        pad = filter_radius(self.filter, self.filter_size)
        r0, r1 = max(rows.min() - pad, 0), min(rows.max() + pad + 1, h)
        c0, c1 = max(cols.min() - pad, 0), min(cols.max() + pad + 1, w)
        local = (rows - r0) * (c1 - c0) + cols - c0
        base = None if self.baseline is None else self.baseline[r0:r1, c0:c1]
        sat = _saturation_level(flat.dtype, self.saturation)
        idx, v, hot = [], [], []
        for i, frame in enumerate(flat):
            crop = frame.reshape(h, w)[r0:r1, c0:c1]
            img = denoise(subtract_baseline(crop, base, clip=False), method=self.filter,
                          size=self.filter_size)
            vals = np.take(img, local)
            lit = np.flatnonzero(vals > self._thr_entries)
            idx.append(i * n_ent + lit)
            v.append(vals[lit])
            hot.append(i * n_ent + np.flatnonzero(np.take(crop, local) >= sat))
        return np.concatenate(idx), np.concatenate(v), np.concatenate(hot)
