"""Spot clusters: a frame's spots linked into element candidates, and their association to elements.

:func:`element_clusters` links the spots of a pressed element (its cones'
bright patches, or one merged blob in a small image) into one candidate
with a centroid, energy and radius; :func:`vote_shift` finds the image
shift most candidates agree with, and :func:`associate` pairs a frame's
candidates with the predicted elements inside their gates (Hungarian
assignment). :func:`optitact.registration.pose.register` runs them in turn.

Convention
----------
Pixels are ``(row, col)``, origin at the centre of the top-left pixel.
"""

from __future__ import annotations

import math

import numpy as np

from optitact.optics.camera import Camera
from optitact.errors import RegistrationError
from optitact.optics.sensor import DomeSensor
from optitact.registration.spots import Spots

__all__ = ["associate", "element_clusters", "nearest_spacing", "vote_shift"]


def nearest_spacing(cen: np.ndarray) -> np.ndarray:
    """Each predicted element's pixel distance to its nearest predicted neighbour (inf where alone)."""
    d = np.linalg.norm(cen[:, None, :] - cen[None, :, :], axis=-1)
    np.fill_diagonal(d, np.inf)
    d[~np.isfinite(d)] = np.inf
    return d.min(axis=1)


def element_clusters(diff: np.ndarray, spots: Spots, sensor: DomeSensor, camera: Camera, *,
                     sigma: float | None = None) -> dict:
    """Spots linked into element candidates on the dome (nominal camera); their centroids, energies, radii.

    Returns a dict of equal-length arrays: ``centroid`` (n, 2) px, ``energy``, ``rms`` (ring radius, px),
    ``n_spots`` and ``centroid_se`` (px): the standard error of one centroid coordinate that the difference
    image's noise (``sigma`` per pixel, independent; default ``spots.noise_sigma``) gives, ``sigma *
    sqrt(sum(d_i^2) / 2) / E`` over the pixels that weigh into it (``d_i`` their distance from the
    centroid, ``E`` their summed value); for the plain mean of ``K`` cone spots, the root-sum-square of the
    spots' own over ``K``.
    """
    import cv2
    from scipy.sparse.csgraph import connected_components

    from optitact.optics.camera import dome_from_pixel

    m = len(spots.energy)
    pts = (dome_from_pixel(spots.centroid, sensor=sensor, camera=camera, outside="nan") if m
           else np.zeros((0, 3)))
    ok = np.isfinite(pts[:, 0]) & (spots.energy > 0)
    link = 2.0 * sensor.cone_circle_radius
    d = np.linalg.norm(pts[:, None, :] - pts[None, :, :], axis=-1)
    adj = (d <= link) & ok[:, None] & ok[None, :]
    _, comp = connected_components(adj, directed=False) if m else (0, np.zeros(0, int))
    groups = [np.flatnonzero((comp == c) & ok) for c in np.unique(comp[ok])] if m else []
    kernel = cv2.getStructuringElement(cv2.MORPH_ELLIPSE, (5, 5))
    h, w = diff.shape
    out = {"centroid": [], "energy": [], "rms": [], "n_spots": [], "centroid_se": []}
    sigma = float(spots.noise_sigma if sigma is None else sigma)
    for g in groups:
        mask = np.isin(spots.labels, g + 1)
        rr, cc = np.nonzero(mask)
        r0, r1, c0, c1 = max(rr.min() - 3, 0), min(rr.max() + 4, h), max(cc.min() - 3, 0), min(cc.max() + 4, w)
        sub = cv2.dilate(mask[r0:r1, c0:c1].astype(np.uint8), kernel).astype(bool)
        wts = np.where(sub, diff[r0:r1, c0:c1], 0.0)
        e = wts.sum()
        if not e > 0:
            continue
        gr, gc = np.mgrid[r0:r1, c0:c1]
        cen = np.array([(wts * gr).sum(), (wts * gc).sum()]) / e
        wp = np.maximum(wts, 0.0)
        d2 = (gr - cen[0]) ** 2 + (gc - cen[1]) ** 2
        rms = math.sqrt(d2[sub] @ wp[sub] / max(wp.sum(), 1e-300))
        se = sigma * math.sqrt(float(np.sum(d2[sub])) / 2.0) / e
        if g.size == sensor.n_cones:
            # Every cone a spot of its own: the plain mean of the spots' centroids is what the model
            # predicts (the mean of the cones' images, as registration predicts them), whatever the
            # cones' brightness (the rim light makes those nearer the rim brighter, which pulls the
            # energy-weighted centroid of a ring merged at low resolution outwards, by up to half a pixel).
            cen = spots.centroid[g].mean(axis=0)
            lab = spots.labels[r0:r1, c0:c1]
            se = sigma * math.sqrt(sum(_spot_se(spots, int(i), lab, (r0, c0)) ** 2 for i in g)) / g.size
        out["centroid"].append(cen)
        out["energy"].append(e)
        out["rms"].append(rms)
        out["n_spots"].append(g.size)
        out["centroid_se"].append(se)
    return {"centroid": np.array(out["centroid"]).reshape(-1, 2), "energy": np.array(out["energy"]),
            "rms": np.array(out["rms"]), "n_spots": np.array(out["n_spots"], dtype=np.int64),
            "centroid_se": np.array(out["centroid_se"])}


def _spot_se(spots: Spots, i: int, labels: np.ndarray, origin: tuple[int, int]) -> float:
    """Spot ``i``'s centroid standard error (px, one coordinate) per unit of pixel noise.

    ``labels`` is a window of ``spots.labels`` whose top-left pixel is ``origin``.
    """
    rr, cc = np.nonzero(labels == i + 1)
    d2 = (rr + origin[0] - spots.centroid[i, 0]) ** 2 + (cc + origin[1] - spots.centroid[i, 1]) ** 2
    return math.sqrt(float(np.sum(d2)) / 2.0) / max(float(spots.energy[i]), 1e-300)


def vote_shift(clusters: list[np.ndarray], pred: np.ndarray, gate: np.ndarray, search: float) -> np.ndarray:
    """The image shift (measured - predicted) most clusters agree with; RegistrationError on a tie."""
    allc = np.concatenate(clusters) if clusters else np.zeros((0, 2))
    good = np.isfinite(pred[:, 0])
    p, g = pred[good], gate[good]
    cand = (allc[:, None, :] - p[None, :, :]).reshape(-1, 2)
    cand = np.concatenate([np.zeros((1, 2)), cand[np.linalg.norm(cand, axis=-1) <= search]])

    def score(s):
        d = np.linalg.norm((allc - s)[:, None, :] - p[None, :, :], axis=-1)
        j = d.argmin(axis=1)
        hit = d[np.arange(len(allc)), j] <= g[j]
        return int(hit.sum()), hit, j

    counts = np.array([score(s)[0] for s in cand])
    order = np.lexsort((np.linalg.norm(cand, axis=-1), -counts))
    best = cand[order[0]]
    n, hit, j = score(best)
    if n == 0:
        return np.zeros(2)
    for o in order[1:]:
        if counts[o] < n:
            break
        if np.linalg.norm(cand[o] - best) > 2.0 * np.median(g):
            raise RegistrationError(
                f"ambiguous association: shifting the predicted elements by {np.round(best, 1).tolist()} px or "
                f"by {np.round(cand[o], 1).tolist()} px explains the same {n} spot clusters; press more "
                f"elements, spread over several rings and further from the apex, or give a camera closer to "
                f"the real one")
    return np.median(allc[hit] - p[j[hit]], axis=0)


def associate(cl: np.ndarray, pred: np.ndarray, gate: np.ndarray,
               shift: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Hungarian assignment of one frame's clusters to elements within the gates: (cluster, element) pairs."""
    from scipy.optimize import linear_sum_assignment

    if len(cl) == 0:
        return np.zeros(0, int), np.zeros(0, int)
    d = np.linalg.norm((cl - shift)[:, None, :] - pred[None, :, :], axis=-1)
    inside = np.isfinite(d) & (d <= gate[None, :])
    cost = np.where(inside, d, 1e9)
    ri, ci = linear_sum_assignment(cost)
    keep = inside[ri, ci]
    return ri[keep], ci[keep]
