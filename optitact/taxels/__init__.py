"""Taxel-array tactile sensors as lower-dimension image sources.

Importing this package registers every taxel sensor type with
:func:`optitact.sources.register_source`:

- ``"piezo16"``: distributed piezoresistive finger pad (16x16 grid, 204 units), active tracing
  (:mod:`optitact.taxels.tracing`);
- ``"thread8"``: 8x8 piezoresistive thread-electrode array, palpation (:mod:`optitact.taxels.palpation`);
- ``"opto5"``: 5x5 optoelectronic taxel pad, wire shape and diameter (:mod:`optitact.taxels.optopad`);
- ``"fingertip25"``: non-coplanar 25-unit piezoresistive fingertip, 3-D force
  (:mod:`optitact.taxels.fingertip`).
"""

from __future__ import annotations

import importlib

_MODULES = ("tracing", "palpation", "opto5", "fingertip25")

for _name in _MODULES:
    try:
        importlib.import_module(f"{__name__}.{_name}")
    except ModuleNotFoundError as _exc:  # pragma: no cover - while a module is being written
        if _exc.name != f"{__name__}.{_name}":
            raise
