"""Live capture: a camera or stream processed frame by frame.

Modules: :mod:`~optitact.live.stream` (a ``cv2.VideoCapture`` source through a pipeline, with forces),
:mod:`~optitact.live.record` (MCAP recordings of a stream and their replay) and
:mod:`~optitact.live.viewer` (the live view in Rerun).

Each public name lives in one module (import it from there); the modules load on first use.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=[
    "record", "stream", "viewer"])
