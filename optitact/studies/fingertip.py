"""Fingertip study on the simulated non-coplanar 25-unit fingertip.

The resistance law and the ranges that follow from the published formula,
the first-order dynamics (:func:`step_response`), decoupling accuracy of the
published plane resultants versus a calibrated matrix
(:func:`decoupling_study`), the repeatability error of repeated loadings
(:func:`repeated_loadings`), object recognition and hardness cues with a
five-finger hand (:mod:`optitact.studies.fingertip_objects`).
``optitact.studies.run("fingertip")`` runs it all.
"""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np

from optitact._validate import finite, integer, positive, real_array, seed_value
from optitact.errors import InputError
from optitact.taxels.sources import Indenter, Scenario
from optitact.taxels.decoupling import (DecouplingMatrix, axis_ranges, decouple, detection_ranges,
                                        repeatability_error)
from optitact.taxels.fingertip25 import UNIT_PLANE, Fingertip25, force_from_resistance, resistance_law
from optitact.studies._protocol import Study, study_seeds
from optitact.studies.fingertip_objects import (OBJECTS, fingertip_source, hardness_cues, object_dataset,
                                                recognise_objects)

__all__ = ["REPEAT_LEVELS_N", "decoupling_study", "repeated_loadings", "step_response", "run", "draw", "STUDY"]

_POINT = Indenter("point")                 # scenarios built here: the source uses the resultant only
#: Unit force levels (N) of the repeated loadings: a staircase up to just under the top of the range.
REPEAT_LEVELS_N = (1.0, 2.0, 3.0, 4.0, 4.8)


def _plateau(source: Fingertip25, forces: np.ndarray, *, n_hold: int, n_avg: int, rng) -> np.ndarray:
    """Hold each force (n, 3) n_hold samples in one run; mean decoded unit forces of the last n_avg samples."""
    n = forces.shape[0]
    t = np.arange(n * n_hold) / source.config.rate_hz
    f = source.unit_forces(np.repeat(forces, n_hold, axis=0))
    r = source.transduce(f, t, seed=rng)
    dec = force_from_resistance(r, config=source.config).reshape(n, n_hold, 5, 5)
    return dec[:, -n_avg:].mean(axis=1)


def _errors(est: np.ndarray, true: np.ndarray) -> dict:
    e = est - true
    rms = np.sqrt(np.mean(e ** 2, axis=0))
    return {"rms_n": rms.tolist(), "max_abs_n": np.abs(e).max(axis=0).tolist(),
            "bias_n": e.mean(axis=0).tolist(), "rms_total_n": float(np.sqrt(np.mean(np.sum(e ** 2, axis=1))))}


def decoupling_study(source: Fingertip25 | None = None, *, n_train: int = 100, n_test: int = 100,
                     seed: int | None = None, fraction: float = 0.75, hold_s: float = 1.0) -> dict:
    r"""Decoupling accuracy on random 3-D forces: the published formula versus a calibrated matrix.

    Each force is held for ``hold_s`` in one continuous run (so the dynamics
    of the previous force settle); the reading is the mean decoded unit force
    over the last 30 % of the hold.

    Parameters
    ----------
    source : Fingertip25, optional
    n_train, n_test : int
        Loads used to fit :class:`DecouplingMatrix`, and loads both methods are tested on.
    seed : int, optional
    fraction : float
        Forces are uniform in ``fraction`` of the sensed domain:
        :math:`F_x \in \pm x_{high}`, :math:`F_y \in [0, y_{high}]`,
        :math:`F_z \in [z_{low}, z_{high}]` scaled by ``fraction``
        (:func:`axis_ranges`), so few units saturate.
    hold_s : float
        Hold time per force, s.

    Returns
    -------
    dict
        JSON-serialisable: ``n_train``, ``n_test``, ``domain_n``, and for
        ``published`` and ``calibrated``: ``rms_n``, ``max_abs_n``, ``bias_n``
        (per axis x, y, z) and ``rms_total_n``; ``sample``: up to 100 test
        forces with both estimates.
    """
    source = fingertip_source(source)
    n_train = integer(n_train, "n_train", minimum=26)
    n_test = integer(n_test, "n_test", minimum=1)
    fraction = positive(fraction, "fraction")
    if fraction > 1:
        raise InputError(f"fraction must be in (0, 1], got {fraction!r}")
    hold = positive(hold_s, "hold_s")
    rng = np.random.default_rng(seed_value(seed))
    ax = axis_ranges(config=source.config)
    lo = np.array([-ax["x"][1], 0.0, ax["z"][0]]) * np.array([fraction, 1.0, 1.0])
    hi = np.array([ax["x"][1], ax["y"][1], ax["z"][1]]) * fraction
    forces = rng.uniform(lo, hi, size=(n_train + n_test, 3))
    n_hold = max(3, int(round(hold * source.config.rate_hz)))
    n_avg = max(1, int(round(0.3 * n_hold)))
    readings = _plateau(source, forces, n_hold=n_hold, n_avg=n_avg, rng=rng)
    matrix = DecouplingMatrix.fit(readings[:n_train], forces[:n_train])
    true, meas = forces[n_train:], readings[n_train:]
    pub, cal = decouple(meas, config=source.config), matrix.apply(meas)
    k = min(100, n_test)
    return {"n_train": n_train, "n_test": n_test, "domain_n": {"low": lo.tolist(), "high": hi.tolist()},
            "published": _errors(pub, true), "calibrated": _errors(cal, true),
            "sample": {"true": true[:k].tolist(), "published": pub[:k].tolist(),
                       "calibrated": cal[:k].tolist()}}


def repeated_loadings(source: Fingertip25 | None = None, *, levels_n=REPEAT_LEVELS_N, n_cycles: int = 10,
                      seed: int | None = None, hold_s: float = 1.0) -> np.ndarray:
    """Readings of the 8 pad units under repeated staircase loadings with a normal force.

    Each cycle is one loading (its own gain draw): the pad force steps up
    through ``8 * levels_n`` (each pad unit gets ``levels_n``), each held
    ``hold_s``; the reading is the mean decoded force over the last 30 % of
    the hold.

    Returns
    -------
    ndarray
        (n_cycles, len(levels_n), 8), N.
    """
    source = fingertip_source(source)
    lv = finite(real_array(levels_n, "levels_n"), "levels_n")
    if lv.ndim != 1 or lv.size < 1 or lv.min() <= 0:
        raise InputError(f"levels_n must be a non-empty 1-D array of forces > 0, got {levels_n!r}")
    n_cycles = integer(n_cycles, "n_cycles", minimum=2)
    hold = positive(hold_s, "hold_s")
    n_hold = max(3, int(round(hold * source.config.rate_hz)))
    n_avg = max(1, int(round(0.3 * n_hold)))
    forces = np.column_stack([np.zeros((lv.size, 2)), 8.0 * lv])
    ss = np.random.SeedSequence(seed_value(seed))
    pad = UNIT_PLANE == 1
    out = np.empty((n_cycles, lv.size, 8))
    for i, child in enumerate(ss.spawn(n_cycles)):
        read = _plateau(source, forces, n_hold=n_hold, n_avg=n_avg, rng=np.random.default_rng(child))
        out[i] = read[:, pad]
    return out


def step_response(source: Fingertip25 | None = None, *, unit_force_n: float = 4.0,
                  rate_hz: float = 1000.0) -> dict:
    """Loading and unloading step of the pad (noise and gain scatter off): measured response times.

    The pad units step from 0 to ``unit_force_n`` and back; times are from
    the step to the first sample whose decoded reading (mean of the 8 pad
    units) has covered 63.2 % or 90 % of the change. Quantisation to
    ``resolution_n`` shifts them slightly from ``tau`` and ``tau·ln 10``.

    Returns
    -------
    dict
        JSON-serialisable: ``t63_load_ms``, ``t90_load_ms``, ``t63_unload_ms``,
        ``t90_unload_ms``, and the trace ``t_s``, ``force_n`` (every 10th sample).
    """
    source = fingertip_source(source)
    level = positive(unit_force_n, "unit_force_n")
    rate = positive(rate_hz, "rate_hz")
    quiet = Fingertip25(dataclasses.replace(source.config, noise_n=0.0, repeatability=0.0))
    n = int(round(0.8 * rate))
    t = np.arange(3 * n) / rate
    fz = np.concatenate([np.zeros(n), np.full(n, 8.0 * level), np.zeros(n)])
    sc = Scenario(_POINT, t_s=t, force_n=fz)
    dec = force_from_resistance(quiet.frames(sc, seed=0), config=quiet.config)[:, UNIT_PLANE == 1].mean(axis=1)
    top = dec[2 * n - 1]

    def crossing(start, frac, rising):
        seg = dec[start:]
        hit = seg >= frac * top - 1e-6 if rising else seg <= (1 - frac) * top + 1e-6
        return float(1000.0 * (np.argmax(hit)) / rate) if hit.any() else float("nan")

    return {"t63_load_ms": crossing(n, 1 - math.exp(-1), True), "t90_load_ms": crossing(n, 0.9, True),
            "t63_unload_ms": crossing(2 * n, 1 - math.exp(-1), False),
            "t90_unload_ms": crossing(2 * n, 0.9, False),
            "t_s": t[::10].tolist(), "force_n": dec[::10].tolist()}


def run(seed: int, *, full: bool, progress: bool) -> dict:
    r"""The fingertip study: law, ranges, dynamics, decoupling, repeatability, recognition, hardness cues.

    Parameters
    ----------
    seed : int
        Seeds everything.
    full : bool
        Full size (300 + 300 decoupling loads, 20 loading cycles, 100 grasps per
        object, 8 force levels × 5 grasps) or quick (60 + 40, 5, 30, 3 × 1: a few seconds).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    dict
        ``config``, ``law`` (``a_kohm``, ``b``), ``ranges``
        (:func:`~optitact.taxels.decoupling.detection_ranges`),
        ``axis_ranges_n``, ``response`` (:func:`step_response`), ``decoupling``
        (:func:`decoupling_study`), ``repeatability`` (per pad unit and the
        mean and max :math:`\delta_R`, %, full scale ``force_high_n``),
        ``recognition`` (:func:`~optitact.studies.fingertip_objects.recognise_objects`)
        and ``hardness`` (:func:`~optitact.studies.fingertip_objects.hardness_cues`).
    """
    from tqdm import tqdm

    if full:
        n_train, n_test, n_cycles, n_obj, levels, n_grasps = 300, 300, 20, 100, np.linspace(2, 30, 8), 5
    else:
        n_train, n_test, n_cycles, n_obj, levels, n_grasps = 60, 40, 5, 30, np.array([2.0, 8.0, 20.0]), 1
    source = Fingertip25()
    c = source.config
    s_dec, s_rep, s_obj, s_cls, s_hard = study_seeds(seed, 5)
    steps = tqdm(total=5, desc="fingertip25 study", file=sys.stderr, disable=not progress)
    a, b = resistance_law(c)
    response = step_response(source)
    steps.update()
    decoupling = decoupling_study(source, n_train=n_train, n_test=n_test, seed=s_dec)
    steps.update()
    reads = repeated_loadings(source, n_cycles=n_cycles, seed=s_rep)
    per_unit = [repeatability_error(reads[:, :, u], c.force_high_n) for u in range(reads.shape[2])]
    repeat = {"levels_n": list(REPEAT_LEVELS_N), "n_cycles": n_cycles, "full_scale_n": c.force_high_n, "z": 3.0,
              "per_unit_pct": per_unit, "mean_pct": float(np.mean(per_unit)),
              "max_pct": float(np.max(per_unit))}
    steps.update()
    data = object_dataset(n_per_object=n_obj, seed=s_obj, source=source, progress=False)
    recognition = recognise_objects(data, seed=s_cls % 2 ** 31)
    recognition["n_per_object"] = n_obj
    recognition["rigid"] = [o.rigid for o in OBJECTS]
    steps.update()
    hardness = hardness_cues(forces_n=levels, n_grasps=n_grasps, seed=s_hard, source=source)
    steps.update()
    steps.close()
    return {"config": dataclasses.asdict(c), "law": {"a_kohm": a, "b": b},
            "ranges": detection_ranges(config=c), "axis_ranges_n": axis_ranges(config=c),
            "response": response, "decoupling": decoupling, "repeatability": repeat,
            "recognition": recognition, "hardness": hardness}


def draw(fig, result: dict) -> None:
    """Law, ranges, step, decoupling, confusion matrix, hardness cues and repeatability."""
    law, ranges, resp = result["law"], result["ranges"], result["response"]
    dec, rec, hard, cfg = result["decoupling"], result["recognition"], result["hardness"], result["config"]
    ax = fig.subplots(2, 4)
    f = np.geomspace(0.1, 8.0, 200)
    a_ax = ax[0, 0]
    a_ax.loglog(f, law["a_kohm"] * f ** -law["b"], "k-", label=f"R = {law['a_kohm']:.2f} F^-{law['b']:.3f}")
    a_ax.loglog([cfg["force_low_n"], cfg["force_high_n"]], [cfg["r_low_kohm"], cfg["r_high_kohm"]], "ro",
                label="published points")
    a_ax.axvspan(cfg["force_low_n"], cfg["force_high_n"], color="0.9")
    a_ax.set_xlabel("unit force, N")
    a_ax.set_ylabel("resistance, kΩ")
    a_ax.set_title("resistance law")
    a_ax.legend(fontsize=7)
    b_ax = ax[0, 1]
    planes = [f"F{p} ({x})" for p, x in zip(ranges["plane"], ranges["axis"], strict=True)]
    lo, hi = np.asarray(ranges["low_n"]), np.asarray(ranges["high_n"])
    b_ax.barh(planes, hi - lo, left=lo, color="tab:blue")
    for i, (l_, h_) in enumerate(zip(lo, hi, strict=True)):
        b_ax.text(h_, i, f" {l_:.2f}–{h_:.2f} N", va="center", fontsize=7)
    b_ax.set_xscale("log")
    b_ax.set_xlabel("plane resultant range, N")
    b_ax.set_title("detection ranges (computed)")
    c_ax = ax[0, 2]
    c_ax.plot(resp["t_s"], resp["force_n"], "k-")
    c_ax.set_xlabel("t, s")
    c_ax.set_ylabel("decoded pad-unit force, N")
    c_ax.set_title(f"step: t63 {resp['t63_load_ms']:.0f} ms up, {resp['t63_unload_ms']:.0f} ms down")
    d_ax = ax[0, 3]
    true = np.asarray(dec["sample"]["true"])
    for key, marker in (("published", "o"), ("calibrated", "x")):
        est = np.asarray(dec["sample"][key])
        for k, colour in enumerate(("tab:red", "tab:green", "tab:blue")):
            d_ax.plot(true[:, k], est[:, k], marker, ms=3, color=colour, alpha=0.6,
                      label=f"{'xyz'[k]} {key}")
    lim = [float(min(true.min(), 0)), float(true.max())]
    d_ax.plot(lim, lim, "k--", lw=1)
    d_ax.set_xlabel("applied force, N")
    d_ax.set_ylabel("decoupled force, N")
    d_ax.set_title("decoupling: RMS " + ", ".join(f"{k} {dec[k]['rms_total_n']:.2f} N"
                                                 for k in ("published", "calibrated")), fontsize=9)
    d_ax.legend(fontsize=6, ncol=2)
    e_ax = ax[1, 0]
    cm = np.asarray(rec["confusion"])
    e_ax.imshow(cm, cmap="Blues")
    for (i, j), v in np.ndenumerate(cm):
        if v:
            e_ax.text(j, i, str(v), ha="center", va="center", fontsize=7,
                      color="white" if v > cm.max() / 2 else "black")
    names = rec["objects"]
    e_ax.set_xticks(range(len(names)), names, rotation=60, ha="right", fontsize=7)
    e_ax.set_yticks(range(len(names)), names, fontsize=7)
    e_ax.set_title(f"recognition: {100 * rec['accuracy']:.1f} % (chance {100 * rec['chance']:.0f} %)")
    g_ax = ax[1, 1]
    forces = hard["forces_n"]
    for name, v in hard["objects"].items():
        g_ax.plot(forces, v["n_responding"], "-" if v["rigid"] else "--", marker=".", label=name)
    g_ax.set_xlabel("grip force, N")
    g_ax.set_ylabel("responding units (of 125)")
    g_ax.set_title("hardness cue per object (solid: rigid)")
    g_ax.legend(fontsize=6)
    h_ax = ax[1, 2]
    h_ax.plot(forces, hard["rigid_mean"], "k-o", label=f"rigid ({hard['rigid_slope_per_n']:.2f} /N)")
    h_ax.plot(forces, hard["elastic_mean"], "m--o", label=f"elastic ({hard['elastic_slope_per_n']:.2f} /N)")
    h_ax.set_xlabel("grip force, N")
    h_ax.set_ylabel("responding units")
    h_ax.set_title("rigid vs elastic")
    h_ax.legend(fontsize=7)
    r_ax = ax[1, 3]
    rep = result.get("repeatability", {})
    per = rep.get("per_unit_pct", [])
    r_ax.bar(range(len(per)), per, color="tab:orange")
    r_ax.set_xlabel("pad unit")
    r_ax.set_ylabel("δ_R, %")
    r_ax.set_title(f"repeatability (Z = 3): mean {rep.get('mean_pct', float('nan')):.2f} %")
    fig.suptitle(f"fingertip25 study (seed {result.get('seed')}, full={result.get('full')})")


#: What the fingertip paper reports, next to the study's own figures.
PUBLISHED = {
    "reference": ("non-coplanar 25-unit piezoresistive fingertip for 3-D force and object recognition "
                  "(the fingertip paper as specified in issue 8)"),
    "resistance_points": {"force_n": [0.2, 5.0], "resistance_kohm": [38.5, 1.2]},
    "detection_range_n": [0.2, 5.0], "resolution_n": 0.2,
    "response_ms": {"load": 80.0, "unload": 160.0},
    "plane_angles_deg": [0.0, 77.25, 62.09, 46.47, 9.03], "plane_units": [8, 4, 2, 2, 3],
    "plane_2_range_n": [0.17, 4.41],
    "repeatability_pct": 1.5,
    "recognition": "9 objects, 125 units, one hidden layer of 13 tanh units, 70/30 split",
}

def key_figures(result: dict) -> list[tuple]:
    """Ranges, response times, repeatability and recognition beside the paper's."""
    cfg, pub, ranges = result["config"], result["published"], result["ranges"]
    return [
        ("detection range (N)", [cfg["force_low_n"], cfg["force_high_n"]], pub["detection_range_n"]),
        ("resolution (N)", cfg["resolution_n"], pub["resolution_n"]),
        ("plane 2 range (N)", [ranges["low_n"][1], ranges["high_n"][1]], pub["plane_2_range_n"]),
        ("response 63 % load (ms)", result["response"]["t63_load_ms"], pub["response_ms"]["load"]),
        ("response 63 % unload (ms)", result["response"]["t63_unload_ms"], pub["response_ms"]["unload"]),
        ("repeatability mean (% FS)", result["repeatability"]["mean_pct"], pub["repeatability_pct"]),
        ("repeatability worst unit (% FS)", result["repeatability"]["max_pct"], pub["repeatability_pct"]),
        ("decoupling RMS (N), published law", result["decoupling"]["published"]["rms_total_n"], None),
        ("decoupling RMS (N), calibrated", result["decoupling"]["calibrated"]["rms_total_n"], None),
        ("recognition accuracy", result["recognition"]["accuracy"], pub["recognition"]),
    ]


STUDY = Study(name="fingertip", summary="non-coplanar 25-unit fingertip, 3-D force and object recognition",
              run=run, draw=draw, published=PUBLISHED, figsize=(17.0, 9.0), key_figures=key_figures)

