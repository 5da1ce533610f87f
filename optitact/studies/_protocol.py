"""One protocol for every study: seeds, size, progress, timing, JSON, figures, cache, registry."""

from __future__ import annotations

import dataclasses
import hashlib
import importlib
import importlib.util
import json
import math
import numbers
import time
from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

import numpy as np

from optitact._validate import seed_value
from optitact.errors import InputError


#: Study sizes: ``quick`` runs in seconds (tests, notebooks), ``full`` is the published protocol.
SIZES = ("quick", "full")

#: name -> module defining ``STUDY``; imported only when that study is asked for.
_REGISTRY: dict[str, str] = {
    "tracing": "optitact.studies.tracing",
    "palpation": "optitact.studies.palpation",
    "wire": "optitact.studies.wire",
    "fingertip": "optitact.studies.fingertip",
    "finger": "optitact.studies.finger",
    "noise": "optitact.studies.noise_sweep",
}


@dataclasses.dataclass(frozen=True)
class Study:
    """A reproduced experiment.

    Parameters
    ----------
    name : str
        Registry name (``optitact experiment NAME``).
    summary : str
        One line: the sensor and what the study measures.
    run : callable
        ``run(seed: int, *, full: bool, progress: bool) -> dict``: the study's
        own figures and series (anything :func:`jsonable` converts).
    draw : callable, optional
        ``draw(fig, result) -> None``: fills a ``matplotlib.figure.Figure``
        from a result of :func:`optitact.studies.run` (or its JSON read back).
    published : dict
        The published paper's figures, reported next to the study's own
        (``result["published"]``), with their source in ``"reference"``.
    figsize : tuple
        Figure size in inches.
    key_figures : callable, optional
        ``key_figures(result) -> [(label, ours, published), ...]``: the few
        figures a reader compares first, each beside the published one (None
        where the paper gives none). Without it :func:`key_figures` pairs
        every entry of ``published`` with the result's entry at the same key.
    """

    name: str
    summary: str
    run: Callable[..., dict]
    draw: Callable[[Any, dict], None] | None = None
    published: Mapping[str, Any] = dataclasses.field(default_factory=dict)
    figsize: tuple[float, float] = (14.0, 9.0)
    key_figures: Callable[[dict], list[tuple[str, Any, Any]]] | None = None


def names() -> list[str]:
    """Names of the registered studies."""
    return sorted(_REGISTRY)


def get(name: str) -> Study:
    """The :class:`Study` registered as ``name`` (its module is imported now)."""
    if not isinstance(name, str):
        raise TypeError(f"study name must be a str, got {type(name).__name__}")
    if name not in _REGISTRY:
        raise InputError(f"unknown study {name!r}; valid: {', '.join(names())}")
    study = importlib.import_module(_REGISTRY[name]).STUDY
    if not isinstance(study, Study) or study.name != name:  # pragma: no cover - a registry mistake
        raise RuntimeError(f"{_REGISTRY[name]}.STUDY is not the Study {name!r}")
    return study


def study_seeds(seed: int, n: int) -> list[int]:
    """``n`` independent integer seeds spawned from ``seed`` (NumPy ``SeedSequence``)."""
    return [int(s.generate_state(1)[0]) for s in np.random.SeedSequence(seed).spawn(n)]


def jsonable(obj):
    """``obj`` as plain JSON values, the one JSON conversion of the studies.

    NumPy scalars and arrays become Python values, tuples lists, dataclasses
    dicts, non-finite floats None, paths str.

    Examples
    --------
    >>> jsonable({"a": np.arange(3), "b": (1.5, float("nan")), "c": np.float32(2)})
    {'a': [0, 1, 2], 'b': [1.5, None], 'c': 2.0}
    """
    if obj is None or isinstance(obj, (bool, str)):
        return obj
    if isinstance(obj, np.bool_):
        return bool(obj)
    if isinstance(obj, numbers.Integral):
        return int(obj)
    if isinstance(obj, numbers.Real):
        v = float(obj)
        return v if math.isfinite(v) else None
    if isinstance(obj, np.ndarray):
        return jsonable(obj.tolist())
    if isinstance(obj, Mapping):
        return {str(k): jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple, set, frozenset)):
        return [jsonable(v) for v in obj]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return jsonable(dataclasses.asdict(obj))
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"cannot convert {type(obj).__name__} to JSON")


def _source_token() -> str:
    """A hash of the installed package's source: cached results die with any code change."""
    root = Path(__file__).resolve().parents[1]
    h = hashlib.sha256()
    for p in sorted(root.rglob("*.py")):
        h.update(p.relative_to(root).as_posix().encode())
        h.update(p.read_bytes())
    for sub in ("render", "calib", "forces"):
        mod = importlib.util.find_spec(f"optitact.{sub}")
        if mod is not None and mod.submodule_search_locations:
            for loc in mod.submodule_search_locations:
                for p in sorted(Path(loc).rglob("*.py")):
                    h.update(p.read_bytes())
    return h.hexdigest()[:16]


def run(name: str, *, seed: int = 0, size: str = "quick", progress: bool = False, cache: bool = True) -> dict:
    """Run the study ``name`` and return its JSON-ready result.

    Parameters
    ----------
    name : str
        A registered study (:func:`names`).
    seed : int
        Seeds every random draw of the study; the same seed gives the same result.
    size : {"quick", "full"}
        ``quick`` (seconds to a minute) or the published protocol (minutes).
    progress : bool
        Progress bars on stderr.
    cache : bool
        Reuse a result cached in the user cache folder for the same study,
        seed, size and package source (any code change invalidates it), and
        cache a new one.

    Returns
    -------
    dict
        The study's own keys, plus ``study``, ``seed``, ``size``, ``full``,
        ``published`` (the paper's figures) and ``seconds`` (wall time of the
        run that made it).
    """
    study = get(name)
    seed = seed_value(seed)
    if seed is None:
        raise InputError("a study needs an integer seed, got None")
    if size not in SIZES:
        raise InputError(f"size must be one of {SIZES}, got {size!r}")
    path = None
    if cache:
        from optitact.io.cache import cache_dir

        path = cache_dir() / "studies" / f"{name}-{size}-{seed}-{_source_token()}.json"
        if path.is_file():
            try:
                return json.loads(path.read_text())
            except (OSError, ValueError):
                pass  # a damaged cache entry is recomputed
    t0 = time.perf_counter()
    body = study.run(seed, full=size == "full", progress=progress)
    if not isinstance(body, Mapping):  # pragma: no cover - a study's own mistake
        raise RuntimeError(f"study {name!r} returned {type(body).__name__}, not a dict")
    result = jsonable({**body, "study": name, "seed": seed, "size": size, "full": size == "full",
                       "published": dict(study.published), "seconds": time.perf_counter() - t0})
    if path is not None:
        from optitact.io.files import atomic_write_text

        atomic_write_text(path, json.dumps(result))
    return result


def save_plot(name: str, result: Mapping, path) -> Path:
    """Draw the study's figure from ``result`` and save it as a PNG at ``path`` (atomically).

    Needs the ``plot`` extra (matplotlib). A result that lacks what the figure
    needs is an :class:`~optitact.errors.InputError`.
    """
    from optitact._optional import require

    study = get(name)
    if study.draw is None:
        raise InputError(f"study {name!r} has no figure")
    if not isinstance(result, Mapping):
        raise TypeError(f"result must be a dict returned by studies.run, got {type(result).__name__}")
    figure = require("matplotlib.figure", purpose="plots")
    fig = figure.Figure(figsize=study.figsize, layout="constrained")
    try:
        study.draw(fig, result)
    except (KeyError, IndexError, TypeError) as exc:
        raise InputError(f"result is not a complete {name!r} study result "
                         f"({type(exc).__name__}: {exc})") from exc
    from optitact.io.files import atomic_write_png_figure

    return atomic_write_png_figure(fig, path)


#: Entries of ``published`` that describe rather than measure (not paired with the result).
_DESCRIPTIVE = ("reference", "note")


def paired_figures(published: Mapping, ours, prefix: str = "") -> list[tuple[str, Any, Any]]:
    """Rows ``(key path, result's value there or None, published value)`` for every leaf of ``published``."""
    rows = []
    for key, pub in published.items():
        if key in _DESCRIPTIVE:
            continue
        mine = ours.get(key) if isinstance(ours, Mapping) else None
        if isinstance(pub, Mapping):
            rows += paired_figures(pub, mine, f"{prefix}{key}/")
        else:
            rows.append((f"{prefix}{key}", mine, pub))
    return rows


def key_figures(name: str, result: Mapping) -> list[tuple[str, Any, Any]]:
    """The study's key figures beside the published ones: ``[(label, ours, published), ...]``.

    Uses the study's own :attr:`Study.key_figures` if it has one, else pairs
    every entry of ``result["published"]`` with the result's entry at the same
    key path (``ours`` is None where the result has no such entry). Values
    are as in the result (JSON values); ``published`` is None where the paper
    gives no figure.

    Examples
    --------
    Palpation's hook pairs them as the generic pairing does (:func:`paired_figures`), adding the
    ablation's rows to a full run's:

    >>> rows = key_figures("palpation", {"n_folds": 5, "recognition": {"mu/left": [0.8, 0.95]},
    ...                                  "published": {"reference": "a paper", "n_folds": 10,
    ...                                                "recognition": {"mu/left": [0.707, 0.781],
    ...                                                                "mu/right": [0.84, 0.86]}}})
    >>> for row in rows:
    ...     print(row)
    ('n_folds', 5, 10)
    ('recognition/mu/left', [0.8, 0.95], [0.707, 0.781])
    ('recognition/mu/right', None, [0.84, 0.86])
    """
    study = get(name)
    if not isinstance(result, Mapping):
        raise TypeError(f"result must be a dict returned by studies.run, got {type(result).__name__}")
    if study.key_figures is not None:
        try:
            return [(str(label), ours, pub) for label, ours, pub in study.key_figures(result)]
        except (KeyError, IndexError, TypeError) as exc:
            raise InputError(f"result is not a complete {name!r} study result "
                             f"({type(exc).__name__}: {exc})") from exc
    return paired_figures(result.get("published") or {}, result)
