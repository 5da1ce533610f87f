"""A setup file: a sensor as built and its camera, as ``optitact register`` writes them.

A setup is the JSON document ``{"sensor": ..., "camera": ..., "registration": ...}``
(:meth:`optitact.registration.pose.Registration.save`, or the ``forces.json`` of
``optitact demo``). :func:`read_setup` reads one into a :class:`Setup`, whatever the
process imported before: every camera model the package ships is found by name
(:func:`optitact.optics.camera.camera_model`). Every command that takes ``--setup``
(``process``, ``demo``, ``render``, ``calibrate generate|fit|test``) reads it so.

Examples
--------
>>> import optitact
>>> setup = optitact.registration.setup.read_setup("setup.json")            # doctest: +SKIP
>>> from optitact.pipeline.frame_pipeline import Pipeline
>>> pipe = Pipeline(setup.sensor, setup.camera, baseline=noload)  # doctest: +SKIP
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

from optitact.optics.camera import Camera, camera_from_dict
from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["Setup", "read_setup"]


@dataclass(frozen=True)
class Setup:
    """A sensor and its camera, with what registration measured (if a registration wrote it).

    Attributes
    ----------
    sensor : DomeSensor
        The sensor as built (element offsets and gains where registered).
    camera : Camera
        Its camera, any model (:class:`optitact.optics.camera.FisheyeCamera`,
        :class:`~optitact.optics.camera_models.PinholeCamera`,
        :class:`~optitact.optics.camera_models.OpenCVFisheyeCamera`).
    registration : dict
        The file's ``registration`` block (RMS, standard errors, unseen elements, ...);
        empty for a setup that was not registered.
    """

    sensor: DomeSensor
    camera: Camera
    registration: dict = field(default_factory=dict, compare=False)

    @classmethod
    def from_dict(cls, doc: Mapping, *, source: str = "setup") -> Setup:
        """A setup from its JSON document; InputError naming ``source`` for a bad one."""
        if not isinstance(doc, Mapping) or "sensor" not in doc or "camera" not in doc:
            got = sorted(doc) if isinstance(doc, Mapping) else type(doc).__name__
            raise InputError(f"{source}: expected a JSON object with 'sensor' and 'camera' (as optitact "
                             f"register writes), got {got}")
        reg = doc.get("registration") or {}
        if not isinstance(reg, Mapping):
            raise InputError(f"{source}: 'registration' must be a JSON object, got {type(reg).__name__}")
        try:
            return cls(DomeSensor.from_dict(doc["sensor"]), camera_from_dict(doc["camera"]), dict(reg))
        except (TypeError, ValueError) as exc:
            raise InputError(f"{source}: {exc}") from None

    def to_dict(self) -> dict:
        """The JSON document (``registration`` only where there is one)."""
        doc = {"sensor": self.sensor.to_dict(), "camera": self.camera.to_dict()}
        if self.registration:
            doc["registration"] = self.registration
        return doc

    def save(self, path: str | os.PathLike) -> Path:
        """Write :meth:`to_dict` as JSON, atomically; returns the path."""
        from optitact.io.files import atomic_write_text

        return atomic_write_text(path, json.dumps(self.to_dict(), indent=2) + "\n")


def read_setup(path: str | os.PathLike) -> Setup:
    """Read a setup file (``optitact register --out``, ``optitact demo``'s ``forces.json``).

    Raises
    ------
    InputError
        For a missing or malformed file, or a sensor or camera it cannot read,
        naming the file.
    """
    from optitact.io.files import read_json_object

    doc = read_json_object(path, ("sensor", "camera"), what="setup", writer="optitact register")
    return Setup.from_dict(doc, source=str(path))
