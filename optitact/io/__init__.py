"""Files: atomic writes, frames in, tables out, partial outputs and the user cache.

Modules: :mod:`~optitact.io.files` (atomic JSON, PNG and NPY writes), :mod:`~optitact.io.partial`
(outputs named partial until complete), :mod:`~optitact.io.cache` (the user cache folder),
:mod:`~optitact.io.frames` (image files, folders, videos and cameras as frames) and
:mod:`~optitact.io.tables` (forces CSV in, readings and forces tables out).

Each public name lives in one module (import it from there); the modules load on first use.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=[
    "cache", "files", "frames", "partial", "tables"])
