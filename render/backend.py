"""Find a working Mitsuba variant: cuda_ad_rgb > llvm_ad_rgb > scalar_rgb.

Dr.Jit's CPU backend loads libLLVM at its first import. It accepts LLVM 19 or
newer here (14 is refused, 15/16 crash on ``fminimum``), so before mitsuba is
imported we point ``DRJIT_LIBLLVM_PATH`` at a suitable library: the one the
``karellen-llvm-core`` wheel installs into the environment
(``<prefix>/lib/libLLVM.so.23.1``), else Debian's ``libllvm19`` or newer.
A user-set ``DRJIT_LIBLLVM_PATH`` is always respected.
"""

from __future__ import annotations

import glob
import os
import re
import site
import sys

import numpy as np

from optitact.errors import InputError, RenderError

__all__ = ["PREFERRED_VARIANTS", "find_libllvm", "select_variant", "active_variant"]

PREFERRED_VARIANTS = ("cuda_ad_rgb", "llvm_ad_rgb", "scalar_rgb")
MIN_LLVM_MAJOR = 19

_state: dict = {"variant": None, "auto": None, "verified": set(), "llvm_path": None,
                "message": None}


def _llvm_major(path: str) -> int | None:
    name = os.path.basename(path)
    m = re.match(r"libLLVM(?:-(\d+)|\.so\.(\d+))", name)
    if m:
        return int(m.group(1) or m.group(2))
    m = re.search(r"llvm-(\d+)", path)
    return int(m.group(1)) if m else None


def find_libllvm() -> str | None:
    """Return the path of a libLLVM (major >= 19) for Dr.Jit, or None.

    Looks in the Python environment's ``lib`` folders (where the
    ``karellen-llvm-core`` wheel puts it), then in Debian's LLVM folders.
    """
    prefixes = dict.fromkeys([sys.prefix, sys.exec_prefix, sys.base_prefix, site.getuserbase()])
    patterns = []
    for prefix in prefixes:
        patterns += [os.path.join(prefix, "lib", "libLLVM.so.*"),
                     os.path.join(prefix, "lib", "libLLVM-*.so*")]
    patterns += ["/usr/lib/llvm-*/lib/libLLVM.so.*", "/usr/lib/llvm-*/lib/libLLVM-*.so*",
                 "/usr/lib/*-linux-gnu/libLLVM-*.so*", "/usr/lib/*-linux-gnu/libLLVM.so.*"]
    found = []
    for pattern in patterns:
        for path in sorted(glob.glob(pattern)):
            major = _llvm_major(path)
            if major is not None and major >= MIN_LLVM_MAJOR and os.path.isfile(path):
                found.append((major, path))
        if found:  # prefer the environment's own library over system ones
            break
    if not found:
        return None
    return max(found)[1]


def _configure_llvm() -> None:
    """Set DRJIT_LIBLLVM_PATH before the first drjit import, unless the user did."""
    if os.environ.get("DRJIT_LIBLLVM_PATH"):
        _state["llvm_path"] = os.environ["DRJIT_LIBLLVM_PATH"]
        return
    if "drjit" in sys.modules:
        return  # too late: Dr.Jit already picked its library
    path = find_libllvm()
    if path:
        os.environ["DRJIT_LIBLLVM_PATH"] = path
        _state["llvm_path"] = path


def _works(mi, dr, variant: str) -> str | None:
    """Return None if ``variant`` runs a tiny kernel, else the reason it does not."""
    if variant.startswith("cuda") and not dr.has_backend(dr.JitBackend.CUDA):
        return "no CUDA device"
    if variant.startswith("llvm") and not dr.has_backend(dr.JitBackend.LLVM):
        return "Dr.Jit found no usable libLLVM (needs LLVM >= 19)"
    try:
        mi.set_variant(variant)
        if variant.startswith("scalar"):
            return None
        x = dr.arange(mi.Float, 4) * 2.0
        dr.eval(x)
        if abs(float(np.asarray(x).sum()) - 12.0) > 1e-6:  # pragma: no cover - defensive
            return "a test kernel returned a wrong result"
    except Exception as exc:  # noqa: BLE001 - any backend failure means "does not work"
        return f"{type(exc).__name__}: {exc}"
    return None


def select_variant(requested: str | None = None):
    """Activate and return ``(mitsuba module, variant name)``.

    Parameters
    ----------
    requested : str, optional
        A Mitsuba variant name; None picks the fastest that works here in the
        order cuda_ad_rgb > llvm_ad_rgb > scalar_rgb.

    Raises
    ------
    InputError
        If ``requested`` is not a variant this Mitsuba build has.
    RenderError
        If ``requested`` (or every variant) cannot run here.
    """
    _configure_llvm()
    from optitact._optional import require

    dr = require("drjit", purpose="rendering")
    mi = require("mitsuba", purpose="rendering")

    available = mi.variants()
    if requested is not None:
        if not isinstance(requested, str):
            raise TypeError(f"variant must be a str, got {type(requested).__name__}")
        if requested not in available:
            raise InputError(f"unknown Mitsuba variant {requested!r}; available: {available}")
        if requested not in _state["verified"]:
            reason = _works(mi, dr, requested)
            if reason:
                raise RenderError(f"Mitsuba variant {requested!r} cannot run here: {reason}")
            _state["verified"].add(requested)
        mi.set_variant(requested)
        _state["variant"] = requested
        return mi, requested
    if _state["auto"] is not None:
        mi.set_variant(_state["auto"])
        _state["variant"] = _state["auto"]
        return mi, _state["auto"]
    reasons = []
    for variant in PREFERRED_VARIANTS:
        if variant not in available:
            continue
        reason = _works(mi, dr, variant)
        if reason is None:
            _state.update(variant=variant, auto=variant)
            _state["verified"].add(variant)
            if reasons:
                msg = ("optitact: rendering on " + variant + " (" + "; ".join(reasons) + ")")
                if variant == "scalar_rgb":
                    msg += (". scalar_rgb is slow: install karellen-llvm-core or Debian's "
                            "libllvm19, or set DRJIT_LIBLLVM_PATH to a libLLVM >= 19")
                _state["message"] = msg
            return mi, variant
        reasons.append(f"{variant}: {reason}")
    raise RenderError("no Mitsuba variant works here: " + "; ".join(reasons))


def active_variant() -> dict:
    """Describe the variant in use: name, libLLVM path, and why faster ones were skipped."""
    return {"variant": _state["variant"], "libllvm": _state["llvm_path"],
            "note": _state["message"]}
