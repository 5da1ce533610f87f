"""What every taxel source shares: config checks, seeds, scenario checks and the constructor.

A taxel sensor is a frozen config dataclass (units in its field comments)
plus a source class built on :class:`TaxelSource`, which states the
sensor's ``name``, ``config_type``, the indenter ``shapes`` it simulates,
the ``Scenario.extra`` keys it reads and whether it is driven by depth or
force. The base checks the config once in its constructor and a scenario
once in :meth:`TaxelSource.check_scenario`; :meth:`TaxelSource.register`
registers the class with :func:`optitact.taxels.sources.register_source`.

Examples
--------
>>> from dataclasses import dataclass
>>> @dataclass(frozen=True)
... class ToyConfig:
...     unit_seed: int = 0
>>> class Toy(TaxelSource):
...     name, config_type, shapes = "toy", ToyConfig, ("sphere",)
>>> Toy().config
ToyConfig(unit_seed=0)
>>> Toy(3)
Traceback (most recent call last):
...
TypeError: config must be a ToyConfig, got int
"""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from optitact._validate import positive, real_array, seed_value
from optitact.errors import InputError
from optitact.taxels.sources import Indenter, Scenario, register_source

__all__ = ["fraction", "range_pair", "check_config", "unit_gains", "noise_rng", "check_scenario",
           "freeze_fields", "TaxelSource"]


def fraction(value, name: str, *, upper: float = 1.0, closed: bool = False) -> float:
    """``value`` as a float in ``[0, upper)`` (``[0, upper]`` when ``closed``).

    Raises
    ------
    TypeError
        For a non-number.
    InputError
        Outside the interval (the message names ``name``).

    Examples
    --------
    >>> fraction(0.25, "hysteresis", upper=0.5)
    0.25
    >>> fraction(1.0, "crosstalk")
    Traceback (most recent call last):
    ...
    optitact.errors.InputError: crosstalk must be in [0, 1), got 1.0
    """
    v = positive(value, name, allow_zero=True)
    if v > upper or (v == upper and not closed):
        raise InputError(f"{name} must be in [0, {upper:g}{']' if closed else ')'}, got {value!r}")
    return v


def range_pair(value, name: str) -> tuple[float, float]:
    """``value`` as two finite floats ``(low, high)`` with ``low <= high``.

    Examples
    --------
    >>> range_pair([0.4, 1.2], "offset_range_v")
    (0.4, 1.2)
    """
    arr = real_array(value, name)
    if arr.shape != (2,) or not np.all(np.isfinite(arr)) or arr[0] > arr[1]:
        raise InputError(f"{name} must be two finite numbers (low, high) with low <= high, got {value!r}")
    return float(arr[0]), float(arr[1])


def _article(word: str) -> str:
    return "an" if word[:1] in "AEIOU" else "a"


def check_config(config, config_type: type):
    """``config_type()`` for None, ``config`` if it is a ``config_type``; TypeError otherwise."""
    if config is None:
        return config_type()
    if not isinstance(config, config_type):
        name = config_type.__name__
        raise TypeError(f"config must be {_article(name)} {name}, got {type(config).__name__}")
    return config


def unit_gains(rng: np.random.Generator, shape, spread: float) -> np.ndarray:
    r"""Per-unit gains :math:`e^{\sigma z}`, :math:`z \sim N(0, 1)` (read-only), drawn from ``rng``.

    One config describes one physical sensor: sources draw these once from
    ``np.random.default_rng(config.unit_seed)``.
    """
    gain = np.exp(spread * rng.standard_normal(shape))
    gain.setflags(write=False)
    return gain


def noise_rng(seed) -> np.random.Generator:
    """The generator of one ``frames(..., seed=seed)`` call (``seed`` checked; None: fresh entropy)."""
    return np.random.default_rng(seed_value(seed))


def check_scenario(scenario, source: str, shapes: tuple[str, ...], *, extra: dict[str, Any] | None = None,
                   drive: str | None = None, why: str = "") -> tuple[Indenter, dict[str, Any]]:
    """Check that source ``source`` simulates ``scenario``; return its indenter and its ``extra`` values.

    Parameters
    ----------
    scenario : Scenario
    source : str
        The source's registered name (for messages).
    shapes : tuple of str
        Indenter shapes the source simulates.
    extra : dict, optional
        ``Scenario.extra`` keys the source reads, with their defaults; any
        other key is refused.
    drive : {"depth", "force"}, optional
        The scenario must give ``depth_mm`` (``"depth"``) or ``force_n``
        (``"force"``); None accepts both.
    why : str
        Appended to the message of a wrong drive (the reason).

    Returns
    -------
    (Indenter, dict)
        The indenter and every key of ``extra`` with the scenario's value or the default.

    Raises
    ------
    TypeError
        If ``scenario`` is not a Scenario.
    InputError
        For an indenter shape not in ``shapes``, an unknown ``extra`` key or the wrong drive.
    """
    if not isinstance(scenario, Scenario):
        raise TypeError(f"scenario must be a Scenario, got {type(scenario).__name__}")
    ind = scenario.indenter
    if ind.shape not in shapes:
        raise InputError(f"the {source} source simulates indenters {shapes}, got {ind.shape!r}")
    allowed = dict(extra or {})
    unknown = sorted(set(scenario.extra) - set(allowed))
    if unknown:
        raise InputError(f"unknown Scenario.extra key(s) {unknown} for {source}; valid: {sorted(allowed)}")
    if drive == "depth" and scenario.depth_mm is None:
        raise InputError(f"the {source} source needs depth_mm (pressing depth), got force_n{why}")
    if drive == "force" and scenario.force_n is None:
        raise InputError(f"the {source} source needs a force-driven scenario (force_n), got depth_mm{why}")
    if drive not in (None, "depth", "force"):
        raise InputError(f"drive must be 'depth', 'force' or None, got {drive!r}")
    return ind, {k: scenario.extra.get(k, v) for k, v in allowed.items()}


def freeze_fields(obj, **arrays: np.ndarray) -> None:
    """Set each array as a read-only copy on the frozen dataclass ``obj`` (in its ``__post_init__``)."""
    for name, arr in arrays.items():
        arr = np.array(arr, copy=True)
        arr.setflags(write=False)
        object.__setattr__(obj, name, arr)


class TaxelSource:
    """Base of the taxel sources: the constructor, the scenario check and registration.

    Subclasses set the class attributes and build their precomputed state in
    :meth:`_setup` (called by the constructor with the checked config).

    Attributes
    ----------
    name : str
        Registered source name.
    config_type : type
        The frozen config dataclass.
    shapes : tuple of str
        Indenter shapes the source simulates.
    extra : dict
        ``Scenario.extra`` keys the source reads, with defaults.
    drive : {"depth", "force"} or None
        Which of ``depth_mm`` / ``force_n`` the source needs (None: either).
    drive_note : str
        Why (appended to the error of a wrong drive).
    """

    name: ClassVar[str]
    config_type: ClassVar[type]
    shapes: ClassVar[tuple[str, ...]] = ()
    extra: ClassVar[dict[str, Any]] = {}
    drive: ClassVar[str | None] = None
    drive_note: ClassVar[str] = ""

    def __init__(self, config=None) -> None:
        self.config = check_config(config, self.config_type)
        self._setup(self.config)

    def _setup(self, config) -> None:
        """Precompute what depends only on the config (per-unit draws, grids); nothing by default."""

    def check_scenario(self, scenario) -> tuple[Indenter, dict[str, Any]]:
        """The scenario's indenter and ``extra`` values (:func:`check_scenario` with this source's rules)."""
        return check_scenario(scenario, self.name, self.shapes, extra=self.extra, drive=self.drive,
                              why=self.drive_note)

    @classmethod
    def register(cls) -> None:
        """Register this class under :attr:`name` (:func:`optitact.taxels.sources.register_source`)."""
        register_source(cls.name, cls.config_type, cls)
