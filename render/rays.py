"""Rays of any camera model at pixel corners, for the ray-table sensor plugin of :mod:`optitact.render.scene`.

Convention
----------
Pixel ``(row, col)`` covers ``[row - 0.5, row + 0.5) x [col - 0.5, col +
0.5)`` (the package's convention, :mod:`optitact.optics.camera`); rays are unit
vectors in the dome frame (global ``(x, y, z)``, mm, :mod:`optitact.optics.sensor`).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from optitact.optics.camera import Camera

__all__ = ["corner_rays", "interpolate_rays"]


def _finite_rays(rays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Float32 rays with the missing (NaN) ones zeroed, and which are present."""
    ok = np.isfinite(rays).all(axis=-1)
    return np.where(ok[..., None], rays, 0.0).astype(np.float32), ok


@lru_cache(maxsize=4)
def _window_corner_rays(camera: Camera, r0: int, c0: int, h: int, w: int):
    rows = r0 - 0.5 + np.arange(h + 1, dtype=np.float64)
    cols = c0 - 0.5 + np.arange(w + 1, dtype=np.float64)
    grid = np.stack(np.meshgrid(rows, cols, indexing="ij"), axis=-1)
    rays, ok = _finite_rays(camera.ray_from_pixel(grid))
    valid = ok[:-1, :-1] & ok[:-1, 1:] & ok[1:, :-1] & ok[1:, 1:]
    rays.flags.writeable = False
    valid.flags.writeable = False
    return rays, valid


def corner_rays(camera: Camera, crop: tuple[int, int, int, int] | None = None,
                pixels: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Dome-frame unit rays of the pixel corners, and which pixels have all four, for the ray-table plugin.

    Pixel ``(row, col)`` covers ``[row - 0.5, row + 0.5) x [col - 0.5, col +
    0.5)`` (the package's convention, :mod:`optitact.optics.camera`); its corners'
    rays come from :meth:`Camera.ray_from_pixel`. Inside a pixel the plugin
    interpolates them bilinearly and normalises; a pixel with a corner no ray
    maps to (NaN, e.g. beyond a pinhole's field) is marked invalid: its
    samples miss with weight 0.

    Parameters
    ----------
    camera : Camera
    crop : (row0, col0, height, width), optional
        The window to cover (default the whole image).
    pixels : (n,) int array, optional
        Flat pixel indices (``row * width + col``) instead of a window.

    Returns
    -------
    rays : float32 ndarray
        ``(h + 1, w + 1, 3)`` for a window (cached per camera and window),
        ``(n, 2, 2, 3)`` (each pixel's corners, rows then columns) for
        ``pixels``; missing rays are 0.
    valid : bool ndarray
        ``(h, w)`` or ``(n,)``: pixels whose four corners have rays.
    """
    if pixels is None:
        r0, c0, h, w = (0, 0, camera.height, camera.width) if crop is None else crop
        return _window_corner_rays(camera, int(r0), int(c0), int(h), int(w))
    rows, cols = np.divmod(np.asarray(pixels, dtype=np.int64), camera.width)
    # corner (i, j) of a pixel lies at (row + i - 0.5, col + j - 0.5): flat index in the (H+1) x (W+1) grid
    ids = ((rows[:, None, None] + np.arange(2)[None, :, None]) * (camera.width + 1)
           + cols[:, None, None] + np.arange(2)[None, None, :])
    unique, inverse = np.unique(ids, return_inverse=True)
    cr, cc = np.divmod(unique, camera.width + 1)
    rays, ok = _finite_rays(camera.ray_from_pixel(np.stack([cr - 0.5, cc - 0.5], axis=-1)))
    return rays[inverse.reshape(ids.shape)], ok[inverse.reshape(ids.shape)].all(axis=(1, 2))


def interpolate_rays(rays: np.ndarray, positions: np.ndarray, origin=(0.0, 0.0)) -> np.ndarray:
    """NumPy reference of the ray-table plugin: rays at sub-pixel positions from a window's corner rays.

    Parameters
    ----------
    rays : (h + 1, w + 1, 3) array
        Corner rays of a window (:func:`corner_rays`).
    positions : (..., 2) array
        Image positions ``(row, col)`` inside the window.
    origin : (row0, col0)
        The window's first pixel.

    Returns
    -------
    (..., 3) float64 ndarray
        Bilinear interpolation between the 4 corners of each position's pixel, normalised.
    """
    q = np.asarray(positions, dtype=np.float64) - np.asarray(origin, dtype=np.float64) + 0.5
    h, w = rays.shape[0] - 1, rays.shape[1] - 1
    i = np.clip(np.floor(q[..., 0]), 0, h - 1).astype(np.int64)
    j = np.clip(np.floor(q[..., 1]), 0, w - 1).astype(np.int64)
    v, u = (q[..., 0] - i)[..., None], (q[..., 1] - j)[..., None]
    t = rays.astype(np.float64)
    d = (t[i, j] * (1 - u) + t[i, j + 1] * u) * (1 - v) + (t[i + 1, j] * (1 - u) + t[i + 1, j + 1] * u) * v
    return d / np.linalg.norm(d, axis=-1, keepdims=True)
