"""Taxel-array tactile sensors as lower-dimension image sources.

Each sensor is its model and transduction law on one shared base
(:mod:`optitact.taxels.base`: config, seeds and scenario checks; one indenter
geometry in :mod:`optitact.taxels.indenter`), plus reusable analyses; the
published studies live in ``optitact.studies``. Importing this package
imports no optional dependency (scikit-learn, dtaidistance and matplotlib are
imported by the functions that need them).

Importing this package registers every taxel sensor type with
:func:`optitact.taxels.sources.register_source`:

- ``"piezo16"``: distributed piezoresistive finger pad (16x16 grid, 204 units) (:mod:`optitact.taxels.piezo16`);
  active tracing with it in :mod:`optitact.taxels.combined`;
- ``"thread8"``: 8x8 piezoresistive thread-electrode array (:mod:`optitact.taxels.thread8`); grasps with
  one on each gripper jaw in :mod:`optitact.taxels.grasp`, DTW and k-NN in :mod:`optitact.taxels.dtw`;
- ``"opto5"``: 5x5 optoelectronic taxel pad (:mod:`optitact.taxels.opto5`); offset removal, normalisation,
  wire shape and diameter in :mod:`optitact.taxels.wire`;
- ``"fingertip25"``: non-coplanar 25-unit piezoresistive fingertip (:mod:`optitact.taxels.fingertip25`);
  3-D force by plane decoupling in :mod:`optitact.taxels.decoupling`.
"""

from __future__ import annotations

import importlib

_MODULES = ("piezo16", "thread8", "opto5", "fingertip25")

for _name in _MODULES:
    importlib.import_module(f"{__name__}.{_name}")
