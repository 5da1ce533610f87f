"""The shipped calibration of the default sensor, camera and pipeline (small JSON in the package).

It was fitted to a synthetic set of ``DomeSensor.default()`` seen by
``FisheyeCamera()`` (640x480); the README and the docs' calibration guide give
the command that regenerates it. A registered real sensor starts from it
(``calibrate fit --start default``) or transfers it (``--setup``).
"""

from __future__ import annotations

from pathlib import Path

from optitact.calib.fit import Calibration

__all__ = ["DEFAULT_CALIBRATION", "default_calibration"]

#: The shipped calibration of ``DomeSensor.default()`` and ``FisheyeCamera()``.
DEFAULT_CALIBRATION = Path(__file__).with_name("data") / "dome41.json"


def default_calibration() -> Calibration:
    """Load the shipped calibration (:data:`DEFAULT_CALIBRATION`)."""
    return Calibration.load(DEFAULT_CALIBRATION)
