"""optitact: optical three-axis tactile sensing.

Sensor models, the closed-form camera models, the contact model and the CCD model are
importable at once; the Mitsuba renderer lives in :mod:`optitact.render` and
is imported only when used (``import optitact`` never imports mitsuba).
"""

from __future__ import annotations

import importlib

from .camera import Camera, FisheyeCamera, camera_from_dict
from .camera_models import OpenCVFisheyeCamera, PinholeCamera, read_opencv_calibration
from .ccd import CCD, IntensityScale
from .contact import Contacts, cone_loads, contact_patches
from .dome_optics import dome_from_pixel, pixel_from_dome
from .errors import InputError, OptitactError, OptitactWarning, RenderError, ShapeError
from .pipeline import Pipeline
from .readings import Readings
from .register import register  # the function (scipy.optimize is imported when it runs)
from .sensor import DomeSensor

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
    "cone_loads",
    "camera_from_dict",
    "contact_patches",
    "dome_from_pixel",
    "pixel_from_dome",
    "read_opencv_calibration",
    "register",
]

_SUBPACKAGES = ("render", "calib", "forces", "live")


def __getattr__(name: str):
    if name in _SUBPACKAGES:
        return importlib.import_module(f"{__name__}.{name}")
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")
