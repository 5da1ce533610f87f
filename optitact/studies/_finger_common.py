"""Helpers shared by the finger studies (scanning, slip, contour tracing): chain, seed, noise, figures."""

from __future__ import annotations

import math

import numpy as np

from optitact._validate import seed_value
from optitact.errors import InputError
from optitact.finger.chain import ChainSimulator

__all__: list[str] = []


def study_seed(seed) -> int:
    """A study's seed: a non-negative integer (None is refused: a study is reproducible)."""
    s = seed_value(seed)
    if s is None:
        raise InputError("seed must be a non-negative integer, got None")
    return s


def chain_for(chain, seed: int, spp: int = 32) -> ChainSimulator:
    """``chain``, or the default ``ChainSimulator(spp=spp, seed=seed)`` when it is None."""
    if chain is None:
        return ChainSimulator(spp=spp, seed=seed)
    if not isinstance(chain, ChainSimulator):
        raise TypeError(f"chain must be a ChainSimulator, got {type(chain).__name__}")
    return chain


def rounded(arr, digits: int = 5) -> list:
    """``arr`` rounded to ``digits`` decimals, as a list (the studies' stored series)."""
    return np.round(np.asarray(arr, float), digits).tolist()


def ar1(rng: np.random.Generator, n: int, sigma: float, corr: float) -> np.ndarray:
    """Stationary AR(1) noise of standard deviation ``sigma`` and lag-one correlation ``corr``."""
    out = np.empty(n)
    x = rng.normal(0.0, sigma)
    k = math.sqrt(1.0 - corr**2)
    for i in range(n):
        out[i] = x
        x = corr * x + k * rng.normal(0.0, sigma)
    return out


def need(result: dict, *keys):
    """``result[k1][k2]...``; a missing key is an InputError saying the result is not the right one."""
    try:
        for k in keys:
            result = result[k]
    except (KeyError, TypeError) as exc:
        raise InputError(f"result must come from the matching finger experiment; missing {exc}") from None
    return result
