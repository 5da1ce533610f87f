"""The frame pipeline: camera frames to per-element readings, with their errors.

Modules: :mod:`~optitact.pipeline.readings` (the per-element result), :mod:`~optitact.pipeline.imageops`
(baseline subtraction, denoising, thresholds, noise estimates), :mod:`~optitact.pipeline.baseline`
(no-load baselines from stacks), :mod:`~optitact.pipeline.regions` (element regions and weights),
:mod:`~optitact.pipeline.kernel` (the compiled per-frame kernel), :mod:`~optitact.pipeline.fastpath`
(the folded one-pass path), :mod:`~optitact.pipeline.frame_pipeline` (:class:`Pipeline`),
:mod:`~optitact.pipeline.uncertainty` (readings' standard errors), :mod:`~optitact.pipeline.batch`
(files and videos through a pipeline) and :mod:`~optitact.pipeline.drift` (slow drift of light, black
level and camera position tracked over long runs).

Each public name lives in one module (import it from there); the modules load on first use.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=[
    "baseline", "batch", "fastpath", "frame_pipeline", "imageops", "kernel", "readings", "regions",
    "uncertainty", "drift"])
