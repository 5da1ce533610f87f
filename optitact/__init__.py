"""optitact: optical three-axis tactile sensing.

The package is built in layers; a module imports only from its own layer or
the layers below it (``tests/test_layers.py`` holds the code to this):

1. :mod:`optitact.errors`, ``optitact._validate``, ``optitact._optional``,
   :mod:`optitact.dask_client`: the foundation (exceptions, argument checks,
   optional dependencies).
2. :mod:`optitact.optics`: the sensor, its cameras and OpenCV camera files,
   the dome's optics, contact mechanics, the CCD.
3. :mod:`optitact.io`: atomic writes, frames in, tables out, the cache.
4. :mod:`optitact.pipeline`: frames to readings (baselines, regions, the fast
   path, standard errors), and batches of files through it.
5. :mod:`optitact.render` (synthetic frames with Mitsuba) and
   :mod:`optitact.forces` (force fields, slip, friction).
6. :mod:`optitact.calib`: calibration sets, fitted curves, presses, error models.
7. :mod:`optitact.registration`: a real sensor's camera pose and gains.
8. :mod:`optitact.live`, :mod:`optitact.taxels`, :mod:`optitact.finger`:
   what runs the stages together (live streams, the taxel sensors as image
   sources, the robotic finger).
9. :mod:`optitact.cli` and :mod:`optitact.studies`: the command line and the
   published experiments and benchmarks; nothing imports them.

Every public name lives in exactly one module and is imported from there
(``from optitact.pipeline.frame_pipeline import Pipeline``). ``import
optitact`` imports nothing heavy: subpackages and modules load on first use,
and the Mitsuba renderer only when a frame is rendered.
"""

import lazy_loader as _lazy

__version__ = "0.1.0"

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=[
    "calib", "cli", "dask_client", "errors", "finger", "forces", "io", "live", "optics", "pipeline",
    "registration", "render", "studies", "taxels"])
