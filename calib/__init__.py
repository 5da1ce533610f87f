"""Calibration: synthetic calibration sets and fitted curves f (shear) and g (normal).

``generate`` renders a set (resumable Zarr store), ``fit`` fits a
:class:`Calibration` to it (or ``Calibration.fit`` to your own measured
readings and forces), ``Calibration.save/load`` keep it as JSON, and
``Calibration.apply`` turns readings into :class:`optitact.forces.ForceField`.
``default_calibration()`` is the shipped calibration of the default sensor,
camera and pipeline. ``fit_from_frames`` fits one to frames of measured
presses and a force gauge's CSV (from scratch, or refining a starting
calibration), ``evaluate_calibration`` reports its held-out errors (see
:mod:`optitact.calib.presses`).
"""

from __future__ import annotations

from pathlib import Path

from .fit import MODELS, Calibration, CalibrationMismatchError, fingerprint, fit
from .presses import (Presses, evaluate_calibration, fit_from_frames, fit_presses, measure_presses,
                      press_curve, press_report, read_presses)
from .sets import CalibrationSet, Design, design_forces, generate

__all__ = ["MODELS", "Calibration", "CalibrationMismatchError", "CalibrationSet", "Design",
           "DEFAULT_CALIBRATION", "Presses", "default_calibration", "design_forces",
           "evaluate_calibration", "fingerprint", "fit", "fit_from_frames", "fit_presses", "generate",
           "measure_presses", "press_curve", "press_report", "read_presses"]

#: The shipped calibration of ``DomeSensor.default()`` and ``FisheyeCamera()``.
DEFAULT_CALIBRATION = Path(__file__).with_name("data") / "dome41.json"


def default_calibration() -> Calibration:
    """Load the shipped calibration (see the README for the command that regenerates it)."""
    return Calibration.load(DEFAULT_CALIBRATION)
