"""Closed-form patch coverage: which camera pixels see a contact patch through the dome, and how much.

Each camera pixel's ray (any camera model of :mod:`optitact.optics.camera`: its
:meth:`~optitact.optics.camera.Camera.ray_from_pixel` from its
:attr:`~optitact.optics.camera.Camera.position`) is refracted into the acrylic at the
inner surface (Snell), weighted by the Fresnel transmittance back out, and hit on
the flat polygon of a contact patch
(:func:`~optitact.render.scene.patch_polygons`); pixels at a polygon's edge
are sub-sampled with stratified rays. Both stages of the two-stage light
transport use it (:mod:`optitact.render.twostage`): stage 1 to turn rendered
pixels into patch radiance, stage 2 to composite the patches as emitters.

Convention
----------
Global ``(x, y, z)`` mm as in :mod:`optitact.optics.sensor`; pixels ``(row, col)``
with the origin at the top-left pixel centre, as in :mod:`optitact.optics.camera`.
"""

from __future__ import annotations

import math

import numpy as np

from optitact._validate import integer
from optitact.optics.camera import Camera
from optitact.optics.contact import Contacts
from optitact.optics.sensor import DomeSensor

from optitact.render.scene import RenderSettings, patch_polygons

__all__ = ["patch_coverage", "MIN_SAMPLES_ACROSS"]

#: Fewest stage-2 sub-pixel rays across a patch's diameter (small patches are sampled finer).
MIN_SAMPLES_ACROSS = 32


def _sample_rays(sensor: DomeSensor, camera: Camera, rows: np.ndarray, cols: np.ndarray):
    """Refracted rays inside the acrylic for image positions: (origin Q, direction, transmittance).

    Any camera model: the pixel's ray ``C + t d`` (``C`` the camera's
    :attr:`~optitact.optics.camera.Camera.position`, ``d`` its
    :meth:`~optitact.optics.camera.Camera.ray_from_pixel`, both in the dome frame)
    meets the inner sphere at ``t = -b + sqrt(b^2 - |C|^2 + r^2)``,
    ``b = C . d`` (``C`` lies inside it). Pixels no ray maps to give NaN rows.
    """
    d = camera.ray_from_pixel(np.stack([rows, cols], axis=-1))
    c = camera.position
    r_in = sensor.inner_radius
    b = d @ c
    with np.errstate(invalid="ignore"):
        t = -b + np.sqrt(b * b - float(c @ c) + r_in * r_in)
        q = t[:, None] * d + c
        nrm = q / r_in
        cos_i = np.sum(d * nrm, axis=1)
        n = float(sensor.refractive_index)
        eta = 1.0 / n
        cos_t = np.sqrt(1.0 - eta * eta * (1.0 - cos_i * cos_i))
        dt = eta * d + (cos_t - eta * cos_i)[:, None] * nrm
        rs = (cos_i - n * cos_t) / (cos_i + n * cos_t)
        rp = (n * cos_i - cos_t) / (n * cos_i + cos_t)
    # Fresnel transmittance (unpolarised; the same both ways) and the n^2 radiance scaling
    # on leaving the acrylic.
    trans = (1.0 - 0.5 * (rs * rs + rp * rp)) / (n * n)
    return q, dt, trans


def patch_coverage(sensor: DomeSensor, camera: Camera, contacts: Contacts,
                   settings: RenderSettings, *, n_sub: int = 8):
    """Which pixels see which patch, and how much of each pixel it covers.

    Parameters
    ----------
    sensor, camera, contacts, settings
        The patches are those :func:`~optitact.render.scene.patch_mesh` builds.
    n_sub : int
        Stratified sub-pixel rays per pixel side (``n_sub**2`` per pixel).

    Returns
    -------
    dict
        Equal-length arrays, one row per (patch, pixel) pair with non-zero
        coverage: ``patch`` (index into the touching cones, row-major over
        ``(element, cone)``), ``pixel`` (flat ``row * width + col``),
        ``coverage`` (fraction of the pixel's area on the patch) and
        ``transmitted`` (coverage times the Fresnel transmittance ``/ n^2`` of
        the pixel's central ray: the pixel's radiance per unit patch radiance); plus ``theta`` and
        ``radius`` per patch.
    """
    n_sub = integer(n_sub, "n_sub", minimum=1)
    poly = patch_polygons(contacts, radius=sensor.outer_radius, inset=settings.patch_inset,
                          segments=settings.patch_segments)
    empty = {"patch": np.zeros(0, np.int64), "pixel": np.zeros(0, np.int64),
             "coverage": np.zeros(0), "transmitted": np.zeros(0)}
    if poly is None:
        return {**empty, "theta": np.zeros(0), "radius": np.zeros(0), "element": np.zeros(0, np.int64)}
    mid, normal, u, w, circ, radii = poly
    m = len(mid)
    k = settings.patch_segments
    # Pixel bounding boxes: the polygon's rim projected through the closed-form camera (rim points
    # the camera does not see are left out).
    ang = 2.0 * np.pi * np.arange(k) / k
    rim = (mid[:, None, :] + circ[:, None, None]
           * (np.cos(ang)[None, :, None] * u[:, None, :] + np.sin(ang)[None, :, None] * w[:, None, :]))
    rim = rim / np.linalg.norm(rim, axis=-1, keepdims=True) * sensor.outer_radius
    px = camera.project(rim.reshape(-1, 3), sensor, outside="nan").reshape(m, k, 2)
    seen = np.isfinite(px).all(axis=-1).any(axis=1)  # patches wholly hidden get an empty box
    with np.errstate(invalid="ignore"):
        lo = np.where(seen[:, None], np.floor(np.nanmin(np.where(seen[:, None, None], px, 0.0), axis=1) - 1.0),
                      0).astype(np.int64)
        hi = np.where(seen[:, None], np.ceil(np.nanmax(np.where(seen[:, None, None], px, 0.0), axis=1) + 1.0),
                      -1).astype(np.int64)
    lo = np.maximum(lo, 0)
    hi = np.minimum(hi, [camera.height - 1, camera.width - 1])
    sizes = np.maximum(hi - lo + 1, 0)
    counts = sizes[:, 0] * sizes[:, 1]
    patch = np.repeat(np.arange(m), counts)
    start = np.repeat(np.cumsum(counts) - counts, counts)
    local = np.arange(patch.size) - start
    row = lo[patch, 0] + local // sizes[patch, 1]
    col = lo[patch, 1] + local % sizes[patch, 1]
    plane = sensor.outer_radius - settings.patch_inset
    step = 2.0 * np.pi / k
    apothem = circ * math.cos(step / 2)

    cos_psi = np.cos((np.arange(k) + 0.5) * step)
    sin_psi = np.sin((np.arange(k) + 0.5) * step)

    def local(rs, cs, ps):
        """Each ray's hit on its patch's plane in the polygon's (u, w) axes (mm; NaN: no hit), and T."""
        q, dt, trans = _sample_rays(sensor, camera, rs, cs)
        nn = normal[ps]
        denom = np.sum(nn * dt, axis=1)
        dist = (plane - np.sum(nn * q, axis=1)) / np.where(denom > 0, denom, 1.0)
        hit = q + dist[:, None] * dt - mid[ps]
        ok = (denom > 0) & (dist > 0)
        return (np.where(ok, np.sum(hit * u[ps], axis=1), np.nan),
                np.where(ok, np.sum(hit * w[ps], axis=1), np.nan), trans)

    def edge_distance(lu, lw, ps):
        """Signed distance (mm) from the polygon's edge, < 0 inside (exact inside test)."""
        j = np.floor(np.mod(np.arctan2(lw, lu), 2.0 * np.pi) / step).astype(np.int64) % k
        sd = lu * cos_psi[j] + lw * sin_psi[j] - apothem[ps]
        return np.where(np.isnan(sd), np.inf, sd)

    # One ray per pixel centre (and one a pixel to the right and below, for the local affine map
    # pixel -> patch plane). Pixels farther from the polygon's edge than the longer side of their
    # own footprint on the plane (which bounds the distance from the centre to any corner; 10 %
    # margin for the polygon's corners) are wholly in or out; the rest are sub-sampled with
    # n_sub x n_sub stratified points through the affine map (its error over one pixel is second
    # order, for distorted, off-axis, tilted models as for the default fisheye; see
    # tests/render/test_twostage.py).
    rf, cf = row.astype(float), col.astype(float)
    lu, lw, trans = local(np.concatenate([rf, rf, rf + 1.0]), np.concatenate([cf, cf + 1.0, cf]),
                          np.tile(patch, 3))
    n_pairs = patch.size
    lu, lw = lu.reshape(3, n_pairs), lw.reshape(3, n_pairs)
    trans = np.where(np.isfinite(trans[:n_pairs]), trans[:n_pairs], 0.0)
    du_c, dw_c = lu[1] - lu[0], lw[1] - lw[0]
    du_r, dw_r = lu[2] - lu[0], lw[2] - lw[0]
    footprint = np.maximum(np.hypot(du_c, dw_c), np.hypot(du_r, dw_r))
    sd = edge_distance(lu[0], lw[0], patch)
    clear = ~(np.abs(sd) <= 1.1 * footprint)  # NaN footprints (rays missing the plane) count as clear
    cov = np.where(clear & (sd < 0), 1.0, 0.0)
    edge = np.flatnonzero(~clear)
    # Patches a few pixels wide or less get finer sub-sampling: at least MIN_SAMPLES_ACROSS rays
    # across their diameter (capped at 64 per pixel side).
    across = 2.0 * circ[patch] / np.where(footprint > 0, footprint, np.inf)
    n_pair = np.clip(np.ceil(MIN_SAMPLES_ACROSS / np.maximum(across, 1e-9)), n_sub, 64).astype(np.int64)
    n_pair = np.where(np.isfinite(across), n_pair, n_sub)
    for n in np.unique(n_pair[edge]):
        sel = edge[n_pair[edge] == n]
        # Stratified sub-pixel offsets; pixel (r, c) covers [r - 0.5, r + 0.5] x [c - 0.5, c + 0.5].
        off = (np.arange(n) + 0.5) / n - 0.5
        oy, ox = (g.ravel() for g in np.meshgrid(off, off, indexing="ij"))
        su = lu[0, sel, None] + ox[None, :] * du_c[sel, None] + oy[None, :] * du_r[sel, None]
        sw = lw[0, sel, None] + ox[None, :] * dw_c[sel, None] + oy[None, :] * dw_r[sel, None]
        cov[sel] = (edge_distance(su, sw, patch[sel, None]) <= 0).mean(axis=1)
    tr = cov * trans
    keep = cov > 0
    theta = np.arctan2(np.hypot(mid[:, 0], mid[:, 1]), mid[:, 2])
    return {"patch": patch[keep], "pixel": row[keep] * camera.width + col[keep],
            "coverage": cov[keep], "transmitted": tr[keep], "theta": theta, "radius": radii,
            "element": np.nonzero(contacts.radii > 0)[0]}
