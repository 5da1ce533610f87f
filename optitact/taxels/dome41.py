"""The dome sensor as a :class:`~optitact.taxels.sources.TactileSource` (registered as ``"dome41"``).

Its frames are camera frames; a scenario's indenter load is shared among the
elements it covers and rendered with Mitsuba (imported only when frames are
made).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from optitact._validate import integer, positive, seed_value
from optitact.optics.camera import FisheyeCamera
from optitact.optics.ccd import CCD
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor
from optitact.taxels.sources import Layout, Scenario, register_source

__all__ = ["DomeSourceConfig", "DomeSource", "element_forces"]


@dataclass(frozen=True)
class DomeSourceConfig:
    """The dome sensor seen by its camera.

    Units: ``width``/``height`` pixels; ``spp`` samples per pixel; ``bits`` of
    the CCD's digital numbers; ``rate_hz`` camera frames per second.
    """

    width: int = 640          # px
    height: int = 480         # px
    spp: int = 64             # samples per pixel of each rendered frame
    bits: int = 8             # CCD output bits (8 -> uint8, else uint16)
    rate_hz: float = 30.0     # frames / s

    def __post_init__(self) -> None:
        integer(self.width, "width", minimum=8)
        integer(self.height, "height", minimum=8)
        integer(self.spp, "spp", minimum=1)
        integer(self.bits, "bits", minimum=8)
        positive(self.rate_hz, "rate_hz")


def element_forces(sensor: DomeSensor, scenario: Scenario, index: int) -> np.ndarray:
    """Element-local forces (41, 3) N at sample ``index`` of ``scenario``.

    The indenter's normal force is shared among the elements whose apex
    position, projected onto the base plane, lies within the indenter's
    ``size_mm`` of its centre ``(x_mm, y_mm)`` (global frame), weighted by a
    Hertz-like ``(1 - d²/a²)^{3/2}`` profile; a ``point`` indenter (or one
    covering no element) loads the nearest element. Only ``force_n``
    scenarios are simulated.
    """
    if scenario.force_n is None:
        raise InputError("the dome source simulates force-controlled scenarios: give force_n, not depth_mm")
    xy = sensor.element_positions[:, :2]
    centre = np.array([scenario.x_mm[index], scenario.y_mm[index]])
    d2 = np.sum((xy - centre) ** 2, axis=1)
    a = scenario.indenter.size_mm
    w = np.clip(1.0 - d2 / (a * a), 0.0, None) ** 1.5
    if scenario.indenter.shape == "point" or not np.any(w > 0):
        w = np.zeros(len(xy))
        w[int(np.argmin(d2))] = 1.0
    forces = np.zeros((sensor.n_elements, 3))
    forces[:, 2] = scenario.force_n[index] * w / w.sum()
    return forces


class DomeSource:
    """Camera frames of the dome sensor for contact scenarios."""

    name = "dome41"

    def __init__(self, config: DomeSourceConfig) -> None:
        self.config = config
        self.sensor = DomeSensor.default()
        self.camera = FisheyeCamera(width=config.width, height=config.height)
        self.ccd = CCD(bits=config.bits)

    @cached_property
    def layout(self) -> Layout:
        """Pixels of the camera; only those that see the dome exist; pitch = footprint at the apex."""
        mask = self.camera.dome_mask(self.sensor)
        apex = self.sensor.element_positions[0]
        px = self.camera.project(apex[None], self.sensor)[0]
        step = self.camera.unproject(np.array([px, px + (0.0, 1.0)]), self.sensor)
        pitch = float(np.linalg.norm(step[1] - step[0]))
        return Layout(shape=self.camera.shape, pitch_mm=(pitch, pitch), units="DN",
                      rate_hz=self.config.rate_hz, mask=mask)

    def frames(self, scenario: Scenario, *, seed: int | None = None) -> np.ndarray:
        """Rendered and exposed camera frames (T, H, W) for ``scenario``."""
        from optitact.render import render

        seed = seed_value(seed) or 0
        seeds = np.random.SeedSequence(seed).generate_state(scenario.n_frames)
        out = []
        for i in range(scenario.n_frames):
            radiance = render(self.sensor, element_forces(self.sensor, scenario, i), camera=self.camera,
                              spp=self.config.spp, seed=int(seeds[i]))
            out.append(self.ccd.expose(radiance, seed=int(seeds[i])))
        return np.stack(out)


register_source("dome41", DomeSourceConfig, DomeSource)
