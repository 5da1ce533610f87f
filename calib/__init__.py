"""Calibration: synthetic calibration sets, fitted curves f (shear) and g (normal), presses and error models.

Modules: :mod:`~optitact.calib.sets` (synthetic sets, resumable Zarr stores) and
:mod:`~optitact.calib.patterns` (their load patterns); :mod:`~optitact.calib.curves`
and :mod:`~optitact.calib.fit` (:class:`~optitact.calib.fit.Calibration`: fitted,
saved as JSON, applied to readings); :mod:`~optitact.calib.document` (the JSON
schema); :mod:`~optitact.calib.shipped` (the shipped calibration);
:mod:`~optitact.calib.gauge`, :mod:`~optitact.calib.press_fit`
and :mod:`~optitact.calib.held_out` (a real
sensor's gauge presses: fitted, refined, tested); :mod:`~optitact.calib.element_shapes`
(each element's own curves, shrunk toward a start); :mod:`~optitact.calib.wrench` and
:mod:`~optitact.calib.wrench_fit` (a force/torque sensor's totals); :mod:`~optitact.calib.error_model`,
:mod:`~optitact.calib.propagation` and :mod:`~optitact.calib.crosstalk` (standard
errors of forces); :mod:`~optitact.calib.plots`.

Each public name lives in one module (import it from there); the modules load on first use.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=[
    "crosstalk", "curves", "document", "element_shapes", "error_model", "fit", "gauge", "held_out", "patterns",
    "plots", "press_fit", "propagation", "sets", "shipped", "store", "wrench", "wrench_fit"])
