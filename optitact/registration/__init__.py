"""Registering a real sensor: spots in its frames, the camera pose, element gains.

Modules: :mod:`~optitact.registration.spots` (bright spots in a frame), :mod:`~optitact.registration.clusters`
(spots grouped by element), :mod:`~optitact.registration.gains` (per-element brightness gains),
:mod:`~optitact.registration.pose` (the pose fit, :func:`~optitact.registration.pose.register`) and
:mod:`~optitact.registration.setup` (the ``setup.json`` it writes).

Each public name lives in one module (import it from there); the modules load on first use.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=[
    "clusters", "gains", "pose", "setup", "spots"])
