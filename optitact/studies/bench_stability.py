"""Benchmark: ``optitact bench stability``, the generated stress cases and the full noise study.

The stress cases of ``tests/stress`` (a source checkout) run under pytest in
a subprocess, scaled to the requested number of generated examples and
counted per category; the full noise study
(:mod:`optitact.studies.noise_sweep`) adds its Cramér–Rao comparison and
contact-flicker checks. Not library code.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from optitact.errors import InputError
from optitact.studies.noise_sweep import compact_level, compact_levels, run

__all__ = ["STRESS_TESTS", "bench_stability"]


#: Where the stress cases live: ``tests/stress`` of the source checkout this package runs from.
STRESS_TESTS = Path(__file__).resolve().parents[2] / "tests" / "stress"


def _stress_cases(cases: int, seed: int, progress: bool) -> dict:
    """Run pytest on ``tests/stress`` scaled to ``cases`` examples; the counts its conftest writes."""
    import importlib.util

    missing = [m for m in ("pytest", "hypothesis") if importlib.util.find_spec(m) is None]
    if not (STRESS_TESTS / "conftest.py").is_file() or missing:
        why = (f"needs {' and '.join(missing)} (pip install 'optitact[test]')" if missing and
               (STRESS_TESTS / "conftest.py").is_file() else
               f"need a source checkout: {STRESS_TESTS} is not there (the package was installed without it)")
        return {"stress_cases": f"the stress cases {why}", "categories": {}, "failures": {}}
    with tempfile.TemporaryDirectory(prefix="optitact-stress-") as tmp:
        counts = Path(tmp) / "counts.json"
        env = dict(os.environ, OPTITACT_STRESS_CASES=str(cases), OPTITACT_STRESS_SEED=str(seed),
                   OPTITACT_STRESS_COUNTS=str(counts))
        cmd = [sys.executable, "-m", "pytest", str(STRESS_TESTS), "-q", "-p", "no:cacheprovider",
               "-o", "addopts=", "-W", "error", "--tb=line"]
        proc = subprocess.run(cmd, cwd=STRESS_TESTS.parents[1], env=env, text=True,
                              stdout=sys.stderr if progress else subprocess.PIPE, stderr=subprocess.STDOUT)
        if not counts.is_file():
            tail = (proc.stdout or "")[-2000:]
            raise RuntimeError(f"pytest on {STRESS_TESTS} wrote no counts (exit {proc.returncode}): {tail}")
        out = json.loads(counts.read_text())
    out["pytest_exit_code"] = proc.returncode
    return out


def _budget(stress: dict) -> dict:
    """The generated tests' examples: requested, executed, left unspent, and the tests that ran short."""
    tests = stress.get("tests", {})
    return {"requested": stress.get("requested", 0),
            "executed": sum(t["executed"] for t in tests.values()),
            "unspent": stress.get("unspent", 0),
            "ran_short": {name: {"allotted": t["allotted"], "executed": t["executed"]}
                          for name, t in sorted(tests.items()) if t["executed"] < t["allotted"]}}


def bench_stability(*, cases: int = 10_000, seed: int = 0, progress: bool = True) -> dict:
    """``optitact bench stability``: the generated stress cases and the full noise study.

    Parameters
    ----------
    cases : int
        Generated stress cases in all, shared among the categories of
        ``tests/stress`` by their weights (pytest runs them in a subprocess
        with ``OPTITACT_STRESS_CASES=cases``). Examples a test leaves unused
        (its strategies hold fewer distinct values, it filters examples out,
        or it fails and stops) pass on to the next test, so that the
        generated tests execute ``cases`` examples in all.
    seed : int
        Seed of the case generator (Hypothesis) and of the sweep's noise.
    progress : bool
        Progress (pytest's and the sweep's) on stderr.

    Returns
    -------
    dict
        ``cases`` (executed examples in all), ``failures`` (failing tests),
        ``failure_reasons`` (test -> why, at most 50), ``categories``
        (per category: ``generated``, ``passed``, ``failed``, and the same as
        ``cases``/``failures``), ``noise_sweep`` (per signal level: SNR, and
        bias, std and efficiency of G and u), ``nominal`` (the level at the
        nominal energy, with ``u_efficiency``), ``spot``, ``flicker`` (the
        contact flag at the noise floor; each check counts as a readings
        case), ``budget`` (``requested`` and ``executed`` examples of the
        generated tests, ``unspent``: allotted examples no test used, and
        ``ran_short``: the tests that executed fewer than they were allotted,
        with both figures), ``seconds``, ``seed`` and ``camera`` (of the
        stress cases).
        Without a source checkout ``stress_cases`` says why there are none.
    """
    if isinstance(cases, bool) or not isinstance(cases, int) or cases < 0:
        raise InputError(f"cases must be a non-negative integer, got {cases!r}")
    t0 = time.perf_counter()
    stress = _stress_cases(cases, seed, progress) if cases else {"categories": {}, "failures": {}}
    t_cases = time.perf_counter() - t0
    per_cat = {cat: dict(c, cases=c["generated"], failures=c["failed"])
               for cat, c in stress["categories"].items()}
    failures = dict(stress["failures"])
    sw = run(seed, full=True, progress=progress)
    readings = per_cat.setdefault("readings", {"generated": 0, "passed": 0, "failed": 0})
    for fl in sw["flicker"]:
        readings["generated"] += 1
        if fl["ok"]:
            readings["passed"] += 1
        else:
            readings["failed"] += 1
            failures[f"readings/contact_flicker/p{fl['target_rate']}"] = \
                f"contact flicker beyond the noise model's prediction: {fl}"
    readings.update(cases=readings["generated"], failures=readings["failed"])
    result = {"cases": sum(c["generated"] for c in per_cat.values()), "failures": sorted(failures),
              "failure_reasons": {k: v[:500] for k, v in sorted(failures.items())[:50]}, "categories": per_cat,
              "noise_sweep": compact_levels(sw["levels"]),
              "nominal": compact_level(sw["nominal"]) | {"u_efficiency": sw["nominal"]["u_efficiency"],
                                                          "G_efficiency": sw["nominal"]["G_efficiency"]},
              "spot": sw["spot"], "flicker": sw["flicker"], "budget": _budget(stress),
              "seconds": {"cases": round(t_cases, 2), "total": round(time.perf_counter() - t0, 2)},
              "seed": seed, "camera": stress.get("camera")}
    for key in ("stress_cases", "pytest_exit_code"):
        if key in stress:
            result[key] = stress[key]
    return result
