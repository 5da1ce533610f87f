"""optitact: optical three-axis tactile sensing.

Sensor models, the closed-form camera models, the contact model and the CCD model are
importable at once; the Mitsuba renderer lives in :mod:`optitact.render` and
is imported only when used (``import optitact`` never imports mitsuba).
"""

from __future__ import annotations

import importlib
import sys
import types
from typing import TYPE_CHECKING

if TYPE_CHECKING:  # for type checkers and IDEs; at run time the names below load on first use
    from .camera import Camera, FisheyeCamera, camera_from_dict
    from .camera_models import OpenCVFisheyeCamera, PinholeCamera, read_opencv_calibration
    from .ccd import CCD, IntensityScale
    from .contact import Contacts, cone_loads, contact_patches
    from .dome_optics import dome_from_pixel, pixel_from_dome
    from .errors import InputError, OptitactError, OptitactWarning, RenderError, ShapeError
    from .pipeline import Pipeline
    from .readings import Readings
    from .register import register
    from .sensor import DomeSensor
    from .setup import Setup, read_setup

__version__ = "0.1.0"

__all__ = [
    "CCD",
    "Camera",
    "Contacts",
    "DomeSensor",
    "FisheyeCamera",
    "InputError",
    "IntensityScale",
    "OpenCVFisheyeCamera",
    "OptitactError",
    "OptitactWarning",
    "Pipeline",
    "PinholeCamera",
    "Readings",
    "RenderError",
    "ShapeError",
    "Setup",
    "cone_loads",
    "camera_from_dict",
    "contact_patches",
    "dome_from_pixel",
    "pixel_from_dome",
    "read_opencv_calibration",
    "read_setup",
    "register",
]

#: Where each name of ``__all__`` lives: ``import optitact`` imports nothing (not even NumPy),
#: a name's module is imported when the name is first used, so that the command line
#: starts without the modules its command does not need.
_HOMES = {
    "camera": ("Camera", "FisheyeCamera", "camera_from_dict"),
    "camera_models": ("OpenCVFisheyeCamera", "PinholeCamera", "read_opencv_calibration"),
    "ccd": ("CCD", "IntensityScale"),
    "contact": ("Contacts", "cone_loads", "contact_patches"),
    "dome_optics": ("dome_from_pixel", "pixel_from_dome"),
    "errors": ("InputError", "OptitactError", "OptitactWarning", "RenderError", "ShapeError"),
    "pipeline": ("Pipeline",),
    "readings": ("Readings",),
    "register": ("register",),  # the function (scipy.optimize is imported when it runs)
    "sensor": ("DomeSensor",),
    "setup": ("Setup", "read_setup"),
}
_HOME = {name: module for module, names in _HOMES.items() for name in names}


def __getattr__(name: str):
    home = _HOME.get(name)
    if home is not None:
        value = getattr(importlib.import_module(f"{__name__}.{home}"), name)
        globals()[name] = value  # the next look-up is a plain attribute
        return value
    if not name.startswith("_"):  # a submodule or subpackage: optitact.calib, optitact.render, ...
        try:
            return importlib.import_module(f"{__name__}.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"{__name__}.{name}":
                raise
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))


class _Package(types.ModuleType):
    """The package's module type: ``optitact.register`` stays the function when its submodule loads.

    Importing a submodule binds it as an attribute of the package; the
    submodule ``optitact.register`` would then hide the function ``register``
    (it stays in ``sys.modules``, where ``from optitact.register import ...``
    finds it).
    """

    def __setattr__(self, name: str, value) -> None:
        if name == "register" and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package
