"""Optional dependencies: imported where used, with an error naming the extra to install.

The core (``pip install optitact``) needs NumPy, SciPy, OpenCV and tqdm only.
Everything else is an extra::

    render   Mitsuba 3, Dr.Jit, a libLLVM for the CPU JIT, Zarr (rendering, synthetic sets)
    sets     Zarr (reading and writing calibration sets)
    dask     Dask distributed (cluster scale-out of sets and batch processing)
    taxels   scikit-learn, dtaidistance (the taxel-sensor studies)
    plot     matplotlib (every PNG figure)
    fast     numba (the compiled per-frame kernel; NumPy otherwise, same readings)
    columnar pyarrow, pandas (Parquet tables for long recordings)
    record   mcap, mcap-ros2-support (MCAP recordings of live streams, and their replay)
    live     rerun-sdk and the record extra (the live view in Rerun)
    all      everything above
"""

from __future__ import annotations

import importlib
from types import ModuleType

from optitact.errors import MissingExtraError

__all__ = ["EXTRAS", "require"]

#: import name -> (extra, PyPI distribution); what :func:`require` knows how to name.
EXTRAS: dict[str, tuple[str, str]] = {
    "mitsuba": ("render", "mitsuba"),
    "drjit": ("render", "drjit"),
    "zarr": ("sets", "zarr"),
    "distributed": ("dask", "dask[distributed]"),
    "dask": ("dask", "dask[distributed]"),
    "sklearn": ("taxels", "scikit-learn"),
    "dtaidistance": ("taxels", "dtaidistance"),
    "matplotlib": ("plot", "matplotlib"),
    "numba": ("fast", "numba"),
    "pyarrow": ("columnar", "pyarrow"),
    "mcap": ("record", "mcap"),
    "mcap_ros2": ("record", "mcap-ros2-support"),
    "rerun": ("live", "rerun-sdk"),
}


def require(module: str, *, purpose: str | None = None) -> ModuleType:
    """Import ``module`` or raise :class:`MissingExtraError` naming the extra to install.

    Parameters
    ----------
    module : str
        Import name, e.g. ``"matplotlib.figure"``; its top-level package must be
        one of :data:`EXTRAS`.
    purpose : str, optional
        What needs it, for the message (e.g. ``"plots"``).

    Examples
    --------
    >>> np_linalg = require("numpy.linalg")  # a core dependency imports as usual
    >>> np_linalg.__name__
    'numpy.linalg'
    """
    try:
        return importlib.import_module(module)
    except ModuleNotFoundError as exc:
        top = module.split(".")[0]
        missing = (exc.name or "").split(".")[0]
        if top not in EXTRAS or missing != top:
            raise
        extra, dist = EXTRAS[top]
        what = f" for {purpose}" if purpose else ""
        raise MissingExtraError(
            f"{dist} is needed{what} but is not installed: pip install 'optitact[{extra}]'") from None
