"""The studies layer: published experiments reproduced, benchmarks and the noise sweep.

Nothing in the library core imports this package; a study uses the library the
way a user would. Every study follows one protocol (:class:`Study`): it runs
with a seed, a size (``"quick"`` or ``"full"``) and a progress flag and returns
a JSON-ready dict; it draws a figure from such a result; seeds, timing, the
JSON conversion, the published figures and an on-disk cache of results are
handled here, once.

    >>> from optitact import studies
    >>> "tracing" in studies.names()
    True

``optitact experiment NAME`` and the notebooks go through :func:`run` and
:func:`save_plot`.
"""

from __future__ import annotations

from ._protocol import (
    SIZES,
    Study,
    get,
    jsonable,
    key_figures,
    names,
    run,
    save_plot,
    study_seeds,
)

__all__ = ["SIZES", "Study", "get", "jsonable", "key_figures", "names", "run", "save_plot", "study_seeds"]
