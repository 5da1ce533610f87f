"""Calibration from measured presses: frames and a force gauge's readings per frame and element.

A real sensor is calibrated by pressing its elements with a force gauge and
recording a frame per press. This module gathers the three steps, each in a
module of its own:

* :mod:`optitact.calib.gauge` -- the gauge's CSV (:func:`read_presses`, its
  columns in that module's docstring) and the frames read with the normal
  pipeline (:func:`measure_presses`, giving :class:`Presses`);
* :mod:`optitact.calib.press_fit` -- :func:`fit_from_frames` and
  :func:`fit_presses` fit a :class:`~optitact.calib.Calibration`, from scratch
  (``MIN_PRESSES_SCRATCH`` presses per element) or by refining a starting
  calibration (the shipped synthetic one, ``start="default"``;
  ``MIN_PRESSES_REFINE``), keeping per element each group of parameters only
  where it beats the start on held-out presses;
* :mod:`optitact.calib.held_out` -- :func:`evaluate_calibration` and
  :func:`press_report` give the held-out report; :func:`press_curve`
  measures how the held-out error falls with the number of presses per
  element, from scratch and refined.
"""

from __future__ import annotations

from .gauge import Presses, measure_presses, read_presses
from .held_out import evaluate_calibration, press_curve, press_report
from .press_fit import MIN_PRESSES_REFINE, MIN_PRESSES_SCRATCH, fit_from_frames, fit_presses

__all__ = ["MIN_PRESSES_REFINE", "MIN_PRESSES_SCRATCH", "Presses", "evaluate_calibration", "fit_from_frames",
           "fit_presses", "measure_presses", "press_curve", "press_report", "read_presses"]
