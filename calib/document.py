"""Calibration documents: the JSON a :class:`~optitact.calib.fit.Calibration` is saved as, read and validated.

:func:`read_document` reads a calibration file (bounded in size, never
executing anything, refusing NaN and infinity), :func:`from_document` checks
every field of the document and builds the calibration, refusing parameters
a fit never gives and a fingerprint that does not match the sensor, camera
and pipeline it names.

Schema versions (``schema_version``):

1. ``elements.u0`` (the zero-shear centroid) optional: written only when a
   fit found one, and absent from every file written before it existed.
2. ``elements.u0`` required: an array, or ``null`` when the calibration has
   none. A version-2 document without it is refused; a version-1 document
   still loads as version 1 (without ``u0``, its coupled shear curves read
   ``u0 = 0``, with an :class:`~optitact.errors.OptitactWarning` saying so).
3. ``elements.shape`` required: each element's own shape
   (:attr:`Calibration.shape <optitact.calib.fit.Calibration.shape>`, ``(E, 3)``),
   or ``null``. Earlier versions have none (their curves as they are); a
   reader of version 2 refuses a version-3 file rather than ignore the shapes.
"""

from __future__ import annotations

import json
import os
import warnings
from pathlib import Path

import numpy as np

from optitact._validate import check_keys, check_type, json_numbers
from optitact.optics.camera import Camera, camera_from_dict
from optitact.optics.ccd import IntensityScale
from optitact.errors import InputError, OptitactWarning
from optitact.io.files import json_fingerprint
from optitact.optics.sensor import DomeSensor

from optitact.calib.curves import FZ_FLOOR, G_TERMS, MODELS, g_design

__all__ = ["SCHEMA", "SCHEMA_VERSION", "READ_VERSIONS", "MAX_FILE_BYTES", "PIPELINE_KEYS",
           "STACK_NOISE_UNNAMED", "CalibrationMismatchError", "fingerprint", "from_document", "plain_options",
           "read_document", "resolved_options"]

SCHEMA = "optitact.calibration"
#: The schema version written (see the module docstring for what each version holds).
SCHEMA_VERSION = 3
#: The schema versions read.
READ_VERSIONS = (1, 2, 3)
#: Largest calibration file read (bytes); a calibration of 41 elements is ~20 kB.
MAX_FILE_BYTES = 5_000_000
#: Pipeline options a calibration file may hold.
PIPELINE_KEYS = ("method", "filter", "filter_size", "noise_sigma", "k", "min_pixels", "saturation",
                 "radius", "grid_mm", "tail", "stack_noise")
#: The ``stack_noise`` rule of calibrations and calibration sets that do not name one: they were made
#: before the option existed, with the 3 x 3 maximum of a stack baseline's noise (``"maximum"``).
#: Newly fitted calibrations and new sets name theirs.
STACK_NOISE_UNNAMED = "maximum"


def fingerprint(sensor: DomeSensor, camera: Camera, pipeline_options: dict,
                intensity: IntensityScale | None = None) -> str:
    """Short hash of the sensor, camera, pipeline options and intensity scale a calibration belongs to.

    The default scale (8-bit, exposure 1, gain 1) is left out of the hash, so
    that calibrations written before the scale was recorded keep their
    fingerprint.
    """
    check_type(sensor, DomeSensor, "sensor")
    check_type(camera, Camera, "camera")
    doc = {"sensor": sensor.to_dict(), "camera": camera.to_dict(), "pipeline": plain_options(pipeline_options)}
    if intensity is not None and check_type(intensity, IntensityScale, "intensity") != IntensityScale():
        doc["intensity"] = intensity.to_dict()
    return json_fingerprint(doc, 16)


def plain_options(options: dict) -> dict:
    """Pipeline options as a calibration stores them: sorted, without None and without ``baseline``.

    None means "the pipeline's default", so leaving it out keeps the
    fingerprint of options given with and without it the same; the baseline
    is a frame, not an option of the curves.

    Parameters
    ----------
    options : dict
        Keyword options of :class:`~optitact.pipeline.frame_pipeline.Pipeline`.

    Returns
    -------
    dict
    """
    return {k: v for k, v in sorted(options.items()) if v is not None and k != "baseline"}


def resolved_options(sensor: DomeSensor, camera: Camera, options: dict) -> dict:
    """Pipeline options (:func:`plain_options`) with the region geometry made explicit.

    The default region radius and dewarp cell size are derived from the
    sensor and camera; storing the values used keeps a calibration valid
    even if a later version derives other defaults.

    Parameters
    ----------
    sensor : DomeSensor
    camera : Camera
    options : dict
        Keyword options of :class:`~optitact.pipeline.frame_pipeline.Pipeline`.

    Returns
    -------
    dict
        ``plain_options(options)`` with ``radius`` and ``grid_mm`` as the
        pipeline built from them uses.

    Raises
    ------
    InputError, TypeError
        Options that build no pipeline for ``sensor`` and ``camera``.
    """
    from optitact.pipeline.frame_pipeline import Pipeline

    plain = plain_options(options)
    pipe = Pipeline(sensor, camera, **plain)
    return plain | {"radius": pipe.grids.radius, "grid_mm": pipe.grids.grid_mm}


class CalibrationMismatchError(InputError):
    """A calibration was made for another sensor, camera or pipeline."""


def read_document(path: str | os.PathLike):
    """The JSON value in a calibration file at ``path`` (not yet validated: see :func:`from_document`).

    Raises
    ------
    FileNotFoundError
        Nothing at ``path``.
    InputError
        ``path`` is a folder or not a regular file (a FIFO, a device),
        oversized (over ``MAX_FILE_BYTES``), or not JSON of finite numbers.
    """
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"calibration file not found: {path}")
    if path.is_dir():
        raise InputError(f"{path} is a folder, expected a calibration JSON file")
    if not path.is_file():
        raise InputError(f"{path} is not a regular file (a FIFO, socket or device?), expected a "
                         f"calibration JSON file")
    size = path.stat().st_size
    if size > MAX_FILE_BYTES:
        raise InputError(f"{path}: {size} bytes is too large for a calibration "
                         f"(at most {MAX_FILE_BYTES})")
    with path.open("rb") as fh:
        data = fh.read(MAX_FILE_BYTES + 1)  # the file may have grown since stat()
    if len(data) > MAX_FILE_BYTES:
        raise InputError(f"{path} is too large for a calibration (more than {MAX_FILE_BYTES} bytes)")
    try:
        d = json.loads(data.decode("utf-8"), parse_constant=_refuse_constant)
    except (UnicodeDecodeError, ValueError, RecursionError) as exc:
        # JSONDecodeError and numbers too long to convert are ValueErrors; absurd nesting
        # exhausts the parser's recursion
        raise InputError(f"{path} is not a JSON calibration ({type(exc).__name__}: "
                         f"{str(exc)[:200]})") from None
    return d


def from_document(cls, d, *, source: str | os.PathLike | None = None):
    """Build a calibration of class ``cls`` from its JSON document ``d``, validating every field.

    This is :meth:`Calibration.from_dict <optitact.calib.fit.Calibration.from_dict>`;
    its docstring lists what is refused, and with which error. ``source``
    (the file the document was read from) names it in warnings.
    """
    if not isinstance(d, dict):
        raise InputError(f"a calibration must be a JSON object, got {type(d).__name__}")
    if d.get("schema") != SCHEMA:
        raise InputError(f"not an optitact calibration (schema {d.get('schema')!r})")
    version = d.get("schema_version")
    if isinstance(version, bool) or not isinstance(version, int) or version not in READ_VERSIONS:
        raise InputError(f"calibration schema version {d.get('schema_version')!r} is not "
                         f"supported (this optitact reads {', '.join(map(str, READ_VERSIONS))})")
    for key in ("model", "sensor", "camera", "pipeline", "elements", "fingerprint"):
        if key not in d:
            raise InputError(f"calibration is missing {key!r}")
    model = d["model"]
    if not isinstance(model, str) or model not in MODELS:
        raise InputError(f"calibration model must be one of {MODELS}, got {model!r}")
    if not isinstance(d["fingerprint"], str):
        raise InputError(f"calibration 'fingerprint' must be a string, got {d['fingerprint']!r}")
    try:
        sensor = DomeSensor.from_dict(d["sensor"])
    except (TypeError, ValueError, ArithmeticError) as exc:
        raise InputError(f"calibration 'sensor' is not a valid sensor: {exc}") from None
    try:
        camera = camera_from_dict(d["camera"])
    except (TypeError, ValueError, ArithmeticError) as exc:
        raise InputError(f"calibration 'camera' is not a valid camera: {exc}") from None
    if not isinstance(d["pipeline"], dict):
        raise InputError("calibration 'pipeline' must be an object of Pipeline options")
    check_keys(d["pipeline"], PIPELINE_KEYS, "calibration 'pipeline'", noun="option")
    for key in ("residuals_n", "provenance"):
        if not isinstance(d.get(key, {}), dict):
            raise InputError(f"calibration {key!r} must be an object, got "
                             f"{type(d[key]).__name__}")
    residuals = {key: json_numbers(value, f"calibration residuals_n[{key!r}]")
                 for key, value in d.get("residuals_n", {}).items()}
    if "n" in residuals:  # sample counts: integers, as a fit makes them (and writes them back)
        count = residuals["n"]
        if np.any(count < 0) or np.any(count != np.round(count)) or np.any(count >= 2.0**63):
            raise InputError("calibration residuals_n['n'] must hold sample counts (integers >= 0, "
                             "below 2**63)")
        residuals["n"] = count.astype(np.int64)
    try:
        intensity = IntensityScale.from_dict(d.get("intensity", {}))
    except (TypeError, ValueError) as exc:
        raise InputError(f"calibration 'intensity' is not a valid intensity scale: {exc}") from None
    n = sensor.n_elements
    el = d["elements"]
    if not isinstance(el, dict):
        raise InputError("calibration 'elements' must be an object")

    def arr(name, shape):
        if name not in el:
            raise InputError(f"calibration elements are missing {name!r}")
        a = json_numbers(el[name], f"calibration elements[{name!r}]")
        if a.shape != shape:
            raise InputError(f"calibration elements[{name!r}] must have shape {shape}, "
                             f"got {a.shape}")
        a.flags.writeable = False
        return a

    if "u0" in el:
        u0 = None if el["u0"] is None and version >= 2 else arr("u0", (n, 2, 2))
    elif version >= 2:
        raise InputError(f"calibration elements are missing 'u0' (the zero-shear centroid, null when there "
                         f"is none), which schema version {version} requires")
    else:
        u0 = None
        if model == "coupled":
            warnings.warn(f"{'calibration' if source is None else source}: schema version 1 without "
                          f"elements.u0 (a file written before the zero-shear centroid was fitted); loaded "
                          f"as version 1, its shear curves taking u0 = 0. Fit the calibration again to get "
                          f"it", OptitactWarning, stacklevel=3)
    if version >= 3:
        if "shape" not in el:
            raise InputError(f"calibration elements are missing 'shape' (each element's own shape, null when "
                             f"there is none), which schema version {version} requires")
        shape = None if el["shape"] is None else arr("shape", (n, 3))
    else:
        shape = None
    cal = cls(model, sensor, camera, dict(d["pipeline"]), arr("g", (n, G_TERMS)),
              arr("g_scale", (n,)), arr("f", (n, 2)), arr("u_scale", (n,)),
              arr("g_max", (n,)), arr("u_max", (n,)), arr("gu", (n, 2)),
              residuals, dict(d.get("provenance", {})), intensity, _crosstalk(d.get("crosstalk"), sensor),
              u0, _error_model(d.get("error_model")), shape)
    if np.any(cal.g_scale <= 0) or np.any(cal.u_scale <= 0):
        raise InputError("calibration scales must be > 0")
    if np.any(cal.g_max <= 0) or np.any(cal.u_max <= 0):
        raise InputError("calibration ranges g_max and u_max must be > 0")
    if np.any(cal.g < 0):
        raise InputError("calibration g coefficients must be >= 0 (g increases with G)")
    if model == "coupled" and (np.any(cal.f[:, 0] <= 0) or np.any(cal.f[:, 1] < 0)):
        raise InputError("coupled calibration shear parameters must have a > 0 and b >= 0")
    if model == "ohka" and np.any(cal.f < 0):
        raise InputError("ohka calibration shear coefficients must be >= 0")
    with np.errstate(all="ignore"):  # the curves must stay finite over the fitted range
        s_top, t_top = cal.g_max / cal.g_scale, cal.u_max / cal.u_scale
        fz_top = g_design(s_top) @ np.ones(G_TERMS) * np.abs(cal.g).max(axis=1) \
            + s_top * t_top * np.abs(cal.gu).sum(axis=1)
        # the coupled curve reads u - u0(Fz), u0 largest at the Fz floor
        u0_top = 0.0 if cal.u0 is None else \
            np.abs(cal.u0[:, 0]).max(axis=1) + np.abs(cal.u0[:, 1]).max(axis=1) / np.sqrt(FZ_FLOOR)
        shear_top = ((cal.u_max + u0_top) * fz_top / cal.f[:, 0] if model == "coupled"
                     else cal.f[:, 0] * t_top + cal.f[:, 1] * t_top**3)
    if not (np.isfinite(fz_top).all() and np.isfinite(shear_top).all()):
        raise InputError("calibration curves overflow float64 within their fitted range (scales, "
                         "ranges, coefficients or the zero-shear centroid u0 out of proportion)")
    try:
        cal.pipeline()  # the pipeline options must be valid
    except (TypeError, ValueError, ArithmeticError) as exc:
        raise InputError(f"calibration 'pipeline' options are not valid: {exc}") from None
    if cal.fingerprint != d["fingerprint"]:
        raise CalibrationMismatchError(
            f"calibration fingerprint {d['fingerprint']!r} does not match its own sensor, "
            f"camera and pipeline ({cal.fingerprint}); the file was edited or is corrupt")
    return cal


def _error_model(value):
    """The document's measured error model (None when it has none)."""
    if value is None:
        return None
    from optitact.calib.error_model import ErrorModel

    try:
        return ErrorModel.from_dict(value)
    except (TypeError, ValueError) as exc:
        raise InputError(f"calibration 'error_model' is not valid: {exc}") from None


def _crosstalk(value, sensor: DomeSensor):
    """The document's cross-talk (None when it has none), checked against the sensor's rings."""
    if value is None:
        return None
    from optitact.calib.crosstalk import CrossTalk

    ct = CrossTalk.from_dict(value)
    ct.matrix(sensor)  # InputError unless one row per ring
    return ct


def _refuse_constant(name: str):
    raise ValueError(f"{name} is not valid JSON (calibration numbers must be finite)")
