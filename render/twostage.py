"""Two-stage light transport: guided light to the patches once, then patches as emitters seen through the dome.

Stage 1 (expensive, once per designed sensor and render settings, for every
camera, cached on disk or shipped; :mod:`optitact.render.emission`): the light the rim injects reaches a
contact patch only after many total internal reflections, and barely depends
on a few small contacts elsewhere. Brute-force path tracing at high spp of
single patches on a grid of polar angle ``theta`` and patch radius ``a`` gives
each patch's emitted radiance ``L_e(theta, a)`` (per unit rim radiance): the
:class:`~optitact.render.emission.EmissionTable`.

Stage 2 (per frame, milliseconds, no Mitsuba; this module,
:func:`render_two_stage`): every touching cone's patch is an emitter of
radiance ``L_e(theta, a)``; each camera pixel that can see a patch is traced
in closed form (:mod:`optitact.render.coverage`) — the camera's ray (any
model: pinhole or fisheye, distorted, off axis and tilted),
refraction into the acrylic at the inner surface (Snell), Fresnel
transmittance back out, and the ray's hit on the patch's flat polygon — with
``n_sub x n_sub`` stratified sub-pixel rays. Pixels are composited over the
no-load frame: a covered fraction ``c`` of a pixel shows the patch instead of
what lay behind it.

Stage 1's names are imported from :mod:`optitact.render.emission` and the
coverage's from :mod:`optitact.render.coverage`, where they are defined.

Convention
----------
Global ``(x, y, z)`` mm as in :mod:`optitact.optics.sensor`; pixels ``(row, col)``
with the origin at the top-left pixel centre, as in :mod:`optitact.optics.camera`.
"""

from __future__ import annotations

import numpy as np

from optitact.optics.camera import Camera
from optitact.optics.contact import Contacts
from optitact.optics.sensor import DomeSensor

from optitact.render.coverage import patch_coverage
from optitact.render.emission import EmissionTable
from optitact.render.scene import RenderSettings

__all__ = ["render_two_stage"]


def render_two_stage(sensor: DomeSensor, contacts: Contacts, *, camera: Camera,
                     table: EmissionTable, background: np.ndarray, settings: RenderSettings,
                     n_sub: int = 8) -> np.ndarray:
    """Stage 2: the frame with every touching patch an emitter of radiance ``table(theta, a)``.

    ``background`` is the no-load radiance (H, W); a pixel with patch
    coverage ``c`` becomes ``(1 - c) * background + sum(L_e * transmitted)``.
    Deterministic: no Monte Carlo noise, only the ``n_sub**2`` stratified
    sub-pixel sampling of each pixel's area. Returns float32 (H, W).
    """
    cov = patch_coverage(sensor, camera, contacts, settings, n_sub=n_sub)
    out = np.asarray(background, dtype=np.float64).copy().reshape(-1)
    if cov["patch"].size == 0:
        return out.reshape(camera.shape).astype(np.float32)
    le = table.radiance_of(cov["theta"], cov["radius"], cov["element"]) * settings.rim_radiance
    if sensor.element_gain:  # as built: each element's own brightness
        le = le * sensor.gains[cov["element"]]
    n = out.size
    covered = np.bincount(cov["pixel"], weights=cov["coverage"], minlength=n)
    light = np.bincount(cov["pixel"], weights=le[cov["patch"]] * cov["transmitted"], minlength=n)
    out = out * (1.0 - np.minimum(covered, 1.0)) + light
    return out.reshape(camera.shape).astype(np.float32)

