"""Active tracing of pipes with the piezo16 finger pad: the published study reproduced.

The finger presses a pipe 0.7 mm and traces across its axis in ``N`` steps
(``N`` = 1, 2, 4, 8) of ``W/N`` (``W`` = 2 mm); the combined distribution of
the pipe-radial grid line gives the width and the mean neighbour difference
(:mod:`optitact.taxels.combined`), and a width classifier tells the
diameters (⌀10–40 mm) apart. :func:`tracing_dataset` simulates random
traces; :func:`run` is the study, :func:`draw` its figure, ``STUDY`` its
registry entry (``optitact.studies.run("tracing", seed=0, size="quick")``).
"""

from __future__ import annotations

import dataclasses
import math
import sys

import numpy as np

from optitact._validate import finite, integer, positive, real_array, seed_value
from optitact.errors import InputError
from optitact.taxels.sources import Indenter, Scenario, TactileSource
from optitact.taxels.combined import (WidthClassifier, combined_distribution, diameter_resolution, features,
                                      finger_errors, pair_separation, tracing_direction)
from optitact.taxels.piezo16 import Piezo16, Piezo16Config
from optitact.studies._protocol import Study, study_seeds

__all__ = ["N_STEPS", "DIAMETERS_MM", "PUBLISHED", "FINGER", "EFFECTS", "study_pad", "tracing_dataset",
           "ablation", "run", "draw", "STUDY"]

#: Steps N of the published table.
N_STEPS = (1, 2, 4, 8)
#: Pipe diameters of the published table, mm.
DIAMETERS_MM = (10.0, 15.0, 20.0, 25.0, 30.0, 35.0, 40.0)

#: The tracing finger's repeatability, mm, 1-sigma per step (:func:`~optitact.taxels.combined.finger_errors`):
#: the finger re-presses at every step, so its pressing depth and its position along the stroke scatter
#: independently from step to step. 0.02 mm is the pose repeatability of a small precision arm or
#: positioning stage (ISO 9283 figures of such arms are ±0.02 mm); the paper gives the set depth (0.7 mm)
#: and step (W/N), not their scatter, so this is an assumption, stated as such.
FINGER = {"depth_spread_mm": 0.02, "step_jitter_mm": 0.02}


def study_pad(**overrides) -> Piezo16Config:
    r"""The study's pad: the default :class:`Piezo16Config` with the pad's published layers spreading the load.

    * ``spread_depth_mm = elastomer_mm + rubber_mm`` (2.5 mm): the electrodes
      lie under *both* continuous sheets (2 mm elastomer + 0.5 mm conductive
      rubber, the paper's description), so the Boussinesq stress reaches
      them at that depth (Shimojo 1997: the cover's filter width is set by
      the depth of the sensing plane), not at 2 mm;
    * ``rubber_leak_mm = rubber_mm`` (0.5 mm): the conductive rubber is one
      continuous sheet over all electrodes, so an electrode's current also
      flows sideways through it; for an isotropic sheet of thickness
      :math:`t` between electrode planes the lateral decay length
      :math:`\lambda = \sqrt{\rho t / (\rho / t)} = t`;
    * per-unit gain spread (``unit_gain_spread`` 0.1 in ln gain) and readout
      noise (``noise_v`` 5 mV) as in the default pad.

    Parameters
    ----------
    **overrides
        Config fields to change (the ablation switches effects off this way).
    """
    base = Piezo16Config()
    fields = {"spread_depth_mm": base.elastomer_mm + base.rubber_mm, "rubber_leak_mm": base.rubber_mm}
    fields.update(overrides)
    return dataclasses.replace(base, **fields)


#: Each modelled effect and how the ablation switches it off: ``("pad", overrides)`` on the
#: :func:`study_pad` config, or ``("finger", overrides)`` on :data:`FINGER`.
EFFECTS = {
    "spreading through the rubber": ("pad", {"spread_depth_mm": None}),   # Boussinesq at 2 mm only
    "rubber lateral leak": ("pad", {"rubber_leak_mm": 0.0}),
    "unit gain spread": ("pad", {"unit_gain_spread": 0.0}),
    "readout noise": ("pad", {"noise_v": 0.0}),
    "pressing-depth spread": ("finger", {"depth_spread_mm": 0.0}),
    "step position jitter": ("finger", {"step_jitter_mm": 0.0}),
}


def tracing_dataset(source: TactileSource, diameters_mm, n_steps: int, n_traces: int, *,
                    seed: int | None = None, depth_mm: float = 0.7, stroke_mm: float = 2.0,
                    angle_rad: float = math.pi / 2, progress: bool = False, depth_spread_mm: float = 0.0,
                    step_jitter_mm: float = 0.0) -> dict[str, np.ndarray]:
    """Features of random traces: ``n_traces`` offsets uniform in [0, W) per diameter.

    Parameters
    ----------
    source : TactileSource
        The pad (:class:`Piezo16`, or any source that simulates ``cylinder``).
    diameters_mm : sequence of float
        Pipe diameters, mm.
    n_steps : int
        Steps N per trace.
    n_traces : int
        Traces per diameter.
    seed : int, optional
        Seeds the offsets and the noise.
    depth_mm, stroke_mm, angle_rad
        See :func:`trace` (default: pipe along y, radial lines are grid rows).
    progress : bool
        tqdm progress bar on stderr.
    depth_spread_mm, step_jitter_mm : float
        The finger's repeatability per step, mm
        (:func:`~optitact.taxels.combined.finger_errors`; 0: exact; drawn
        after each diameter's offsets).

    Returns
    -------
    dict
        Table-shaped, one row per trace: ``diameter_mm``, ``offset_mm``,
        ``width``, ``mean_abs_diff``, and ``combined`` ((n, N·cols) the
        combined distributions).
    """
    from tqdm import tqdm

    if not isinstance(source, TactileSource):
        raise TypeError(f"source must be a TactileSource, got {type(source).__name__}")
    diam = finite(real_array(diameters_mm, "diameters_mm"), "diameters_mm").ravel()
    if diam.size == 0 or diam.min() <= 0:
        raise InputError(f"diameters_mm must be a non-empty list of diameters > 0, got {diam.tolist()}")
    n = integer(n_steps, "n_steps", minimum=1)
    n_tr = integer(n_traces, "n_traces", minimum=1)
    stroke = positive(stroke_mm, "stroke_mm")
    depth = positive(depth_mm, "depth_mm", allow_zero=True)
    angle = float(finite(real_array(angle_rad, "angle_rad"), "angle_rad"))
    rng = np.random.default_rng(seed_value(seed))
    normal = tracing_direction(angle)
    axis = "x" if abs(normal[0]) >= abs(normal[1]) else "y"
    rows: dict[str, list] = {k: [] for k in ("diameter_mm", "offset_mm", "width", "mean_abs_diff", "combined")}
    for d in tqdm(diam.tolist(), desc=f"piezo16 traces N={n}", file=sys.stderr, disable=not progress):
        offsets = rng.uniform(0.0, stroke, n_tr)
        dz, dx = finger_errors(rng, (n_tr, n), depth_spread_mm=depth_spread_mm, step_jitter_mm=step_jitter_mm)
        pos = (offsets[:, None] - np.arange(n)[None, :] * stroke / n + dx).ravel()
        sc = Scenario(Indenter("cylinder", size_mm=d / 2), np.arange(pos.size) / source.layout.rate_hz,
                      x_mm=pos * normal[0], y_mm=pos * normal[1], angle_rad=angle,
                      depth_mm=np.clip(depth + dz, 0.0, None).ravel())
        frames = source.frames(sc, seed=int(rng.integers(2 ** 31))).reshape(n_tr, n, *source.layout.shape)
        for t in range(n_tr):
            comb = combined_distribution(frames[t], n, layout=source.layout, radial_axis=axis)
            w, mad = features(comb)
            rows["diameter_mm"].append(d)
            rows["offset_mm"].append(float(offsets[t]))
            rows["width"].append(w)
            rows["mean_abs_diff"].append(mad)
            rows["combined"].append(comb)
    out = {k: np.asarray(v, dtype=float) for k, v in rows.items()}
    out["width"] = out["width"].astype(int)
    return out


def _figures(source, finger: dict, diameters, n_traces: int, seed: int, progress: bool = False) -> dict:
    """Table 1 (mean width) and Table 2 (mean neighbour difference), ``{str(N): {str(d): value}}``."""
    t1: dict[str, dict] = {}
    t2: dict[str, dict] = {}
    for n, s in zip(N_STEPS, study_seeds(seed, len(N_STEPS)), strict=True):
        data = tracing_dataset(source, diameters, n, n_traces, seed=s, progress=progress, **finger)
        sel = {d: data["diameter_mm"] == d for d in diameters}
        t1[str(n)] = {f"{d:g}": float(data["width"][m].mean()) for d, m in sel.items()}
        t2[str(n)] = {f"{d:g}": float(data["mean_abs_diff"][m].mean()) for d, m in sel.items()}
    return {"table1": t1, "table2": t2}


def ablation(seed: int, *, diameters=DIAMETERS_MM, n_traces: int = 5, progress: bool = False) -> dict:
    """Tables 1 and 2 with every effect on, and with each of :data:`EFFECTS` switched off in turn.

    Parameters
    ----------
    seed : int
        Seeds the offsets, the finger's errors and the noise; every variant
        uses the same seeds (common random numbers), so the differences are
        the effects'.
    diameters : sequence of float
        Pipe diameters, mm.
    n_traces : int
        Traces per N and diameter.
    progress : bool
        tqdm progress bars on stderr.

    Returns
    -------
    dict
        ``{variant: {"table1": {N: {d: mean width}}, "table2": {N: {d: mean neighbour difference, V}}}}``
        (string keys), variants ``"all on"`` and ``"no <effect>"`` for each effect.
    """
    seed = integer(seed, "seed", minimum=0)
    diam = tuple(float(d) for d in diameters)
    out = {"all on": _figures(Piezo16(study_pad()), dict(FINGER), diam, n_traces, seed, progress)}
    for name, (where, off) in EFFECTS.items():
        pad = study_pad(**off) if where == "pad" else study_pad()
        finger = {**FINGER, **off} if where == "finger" else dict(FINGER)
        out[f"no {name}"] = _figures(Piezo16(pad), finger, diam, n_traces, seed, progress)
    return out


def run(seed: int, *, full: bool, progress: bool) -> dict:
    """The active-tracing study on simulated traces: width and neighbour difference, N × diameter.

    Parameters
    ----------
    seed : int
        Seeds the offsets and the readout noise (the pad is the default one).
    full : bool
        Full size (7 diameters, N = 1, 2, 4, 8, 20 training + 20 test traces
        each, and the :func:`ablation` with 5 traces per N and diameter) or
        quick (⌀10, 25, 40 mm, 3 + 3 traces: a few seconds; no ablation).
    progress : bool
        tqdm progress bars on stderr.

    Returns
    -------
    dict
        ``config``, ``protocol`` (depth, stroke W, angle, trace counts,
        reliability), ``table`` (one row per (N, diameter): ``n_steps``,
        ``diameter_mm``, ``width_mean``, ``width_std``, ``width_min``,
        ``width_max``, ``mad_mean``, ``mad_std``, ``n_traces``; over training
        and test traces), ``classification`` (one row per N: ``n_steps``,
        ``accuracy`` (test), ``resolution_mm`` (None: not resolved),
        ``classifier`` (:meth:`WidthClassifier.as_dict`), ``pairs``
        (:func:`pair_separation`)), ``examples`` (one combined distribution per
        N and diameter, with its sample positions in mm) and ``mad_range_v``
        (per N the smallest and largest mean neighbour difference over the
        diameters, next to the published ``PUBLISHED["mad_range_v"]``),
        ``table1`` / ``table2`` (mean width / neighbour difference,
        ``{str(N): {str(d): value}}``) and ``ablation`` (:func:`ablation`;
        None when quick).

    Notes
    -----
    The pad is :func:`study_pad` and the finger errs by :data:`FINGER`.
    Each trace has its own contact offset, uniform in [0, W). The classifier
    of each N is fitted on the training traces, and its accuracy and the
    resolution (:func:`diameter_resolution`, reliability 0.95) are measured
    on the test traces.
    """
    diameters = DIAMETERS_MM if full else (10.0, 25.0, 40.0)
    n_train, n_test = (20, 20) if full else (3, 3)
    depth, stroke, angle, reliability = 0.7, 2.0, math.pi / 2, 0.95
    source = Piezo16(study_pad())
    pitch = source.config.pitch_mm
    keys = ("n_steps", "diameter_mm", "width_mean", "width_std", "width_min", "width_max", "mad_mean",
            "mad_std", "n_traces")
    table: dict[str, list] = {k: [] for k in keys}
    cls_rows: dict[str, list] = {k: [] for k in ("n_steps", "accuracy", "resolution_mm", "classifier", "pairs")}
    examples: dict[str, list] = {"n_steps": [], "diameter_mm": [], "position_mm": [], "combined": []}
    for n, s in zip(N_STEPS, study_seeds(seed, len(N_STEPS)), strict=True):
        data = tracing_dataset(source, diameters, n, n_train + n_test, seed=s, depth_mm=depth,
                               stroke_mm=stroke, angle_rad=angle, progress=progress, **FINGER)
        is_train = np.tile(np.arange(n_train + n_test) < n_train, len(diameters))
        for d in diameters:
            sel = data["diameter_mm"] == d
            w, mad = data["width"][sel], data["mean_abs_diff"][sel]
            for k, v in zip(keys, (n, d, w.mean(), w.std(ddof=1), w.min(), w.max(), mad.mean(), mad.std(ddof=1),
                                   int(sel.sum())), strict=True):
                table[k].append(int(v) if k in ("n_steps", "width_min", "width_max", "n_traces") else float(v))
            first = int(np.flatnonzero(sel)[0])
            comb = data["combined"][first]
            i = np.arange(comb.size)
            cols = source.layout.shape[1]
            pos = ((i // n) - (cols - 1) / 2) * pitch + (i % n) * stroke / n - data["offset_mm"][first]
            examples["n_steps"].append(n)
            examples["diameter_mm"].append(d)
            examples["position_mm"].append(pos.tolist())
            examples["combined"].append(comb.tolist())
        clf = WidthClassifier.fit(data["width"][is_train], data["diameter_mm"][is_train])
        test_w, test_d = data["width"][~is_train], data["diameter_mm"][~is_train]
        pairs = pair_separation(clf, test_w, test_d)
        cls_rows["n_steps"].append(n)
        cls_rows["accuracy"].append(clf.score(test_w, test_d))
        cls_rows["resolution_mm"].append(diameter_resolution(clf, test_w, test_d, reliability=reliability))
        cls_rows["classifier"].append(clf.as_dict())
        cls_rows["pairs"].append({k: v.tolist() for k, v in pairs.items()})
    n_all, mad_all = np.asarray(table["n_steps"]), np.asarray(table["mad_mean"])
    cells = list(zip(table["n_steps"], table["diameter_mm"], table["width_mean"], table["mad_mean"],
                     strict=True))
    tables = {f"table{i}": {str(n): {f"{d:g}": float(c[i + 1]) for c in cells if c[0] == n for d in (c[1],)}
                            for n in N_STEPS} for i in (1, 2)}
    return {
        "config": dataclasses.asdict(source.config), "finger": dict(FINGER), **tables,
        "ablation": ablation(seed, progress=progress) if full else None,
        "protocol": {"depth_mm": depth, "stroke_mm": stroke, "angle_rad": angle, "n_steps": list(N_STEPS),
                     "diameters_mm": list(diameters), "n_train": n_train, "n_test": n_test,
                     "reliability": reliability, "chance": 1.0 / len(diameters)},
        "table": table, "classification": cls_rows, "examples": examples,
        "mad_range_v": {str(n): [float(mad_all[n_all == n].min()), float(mad_all[n_all == n].max())]
                        for n in N_STEPS},
    }


def draw(fig, result: dict) -> None:
    """Width and neighbour difference per N, the classifier's resolution and accuracy, example distributions.

    Where the result carries the published figures (``result["published"]``), the ⌀10 mm widths are
    drawn as black crosses with ±30 % bars (left of ⌀10) and the published ranges of the mean
    neighbour difference as bands in their N's colour.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Filled in place (``optitact.studies.save_plot("tracing", result, path)`` makes and saves it).
    result : dict
        As returned by ``optitact.studies.run("tracing", ...)`` (or read back from its JSON).
    """
    table, cls, ex = result["table"], result["classification"], result["examples"]
    ns = sorted(set(table["n_steps"]))
    d_all = np.asarray(table["diameter_mm"], dtype=float)
    n_all = np.asarray(table["n_steps"])
    grid = fig.add_gridspec(2, 3)
    for col, (key, err, label) in enumerate((("width_mean", "width_std", "width (non-zero elements)"),
                                             ("mad_mean", "mad_std", "mean |neighbour difference|, V"))):
        ax = fig.add_subplot(grid[0, col])
        for j, n in enumerate(ns):
            sel = n_all == n
            ax.errorbar(d_all[sel], np.asarray(table[key])[sel], yerr=np.asarray(table[err])[sel], marker="o",
                        capsize=2, color=f"C{j}", label=f"N = {n}")
        pub = result.get("published") or {}
        widths = pub.get("width_d10", {})
        for j, n in enumerate(ns):   # the published figures where the paper gives them, ±30 % as error bars
            if key == "width_mean" and str(n) in widths:
                w = float(widths[str(n)])
                ax.errorbar([9.0], [w], yerr=[[0.3 * w], [0.3 * w]], marker="x", ms=8, color="k", capsize=4,
                            ls="none", label="published ⌀10 (±30 %)" if str(n) == next(iter(widths)) else None)
            if key == "mad_mean" and str(n) in pub.get("mad_range_v", {}):
                lo, hi = (float(v) for v in pub["mad_range_v"][str(n)])
                ax.axhspan(lo, hi, color=f"C{j}", alpha=0.2, lw=0, label=f"published, N = {n}")
        ax.set_xlabel("pipe diameter, mm")
        ax.set_ylabel(label)
        ax.set_title(label.split(" (")[0].split(",")[0] + " of the combined distribution")
        ax.set_ylim(0, 1.3 * ax.get_ylim()[1])   # room for the legend above the curves
        ax.legend(fontsize=7, ncol=2, loc="upper left")
    ax = fig.add_subplot(grid[0, 2])
    res = [np.nan if r is None else r for r in cls["resolution_mm"]]
    pos = np.arange(len(cls["n_steps"]))
    ax.bar(pos - 0.2, res, 0.4, color="C0", label="resolution, mm")
    ax.set_xticks(pos, [f"N = {n}" for n in cls["n_steps"]])
    ax.set_ylabel("diameter resolution, mm")
    ax2 = ax.twinx()
    ax2.bar(pos + 0.2, 100 * np.asarray(cls["accuracy"]), 0.4, color="C1", label="accuracy, %")
    ax2.set_ylabel("test accuracy, %")
    ax2.set_ylim(0, 105)
    ax.set_title("width classifier (bars: resolution | accuracy)")
    e_n = np.asarray(ex["n_steps"])
    e_d = np.asarray(ex["diameter_mm"], dtype=float)
    shown = sorted(set(e_d.tolist()))
    shown = [shown[0], shown[len(shown) // 2], shown[-1]]
    for col, d in enumerate(shown):
        ax = fig.add_subplot(grid[1, col])
        for j, n in enumerate(ns):
            i = int(np.flatnonzero((e_n == n) & (e_d == d))[0])
            ax.step(ex["position_mm"][i], ex["combined"][i], where="mid", color=f"C{j}", lw=1.2,
                    label=f"N = {n}")
        ax.set_xlim(-12, 12)
        ax.set_xlabel("position across the pipe, mm")
        ax.set_ylabel("unit output, V")
        ax.set_title(f"combined distribution, ⌀{d:g} mm")
        ax.legend(fontsize=8)
    fig.suptitle(f"piezo16 active tracing (seed {result.get('seed')}, full={result.get('full')})")


Piezo16.register()



#: The published figures (mean neighbour difference of the combined distribution, V, over the pipe
#: diameters ⌀10–40 mm, falling with N and with the diameter).
PUBLISHED = {
    "reference": "Active tracing with a distributed piezoresistive finger pad (16x16 grid, 204 units, "
                 "law v = 3.45 p q - 0.39 V), pipes of diameter 10-40 mm, N = 1, 2, 4, 8 steps over W = 2 mm",
    "n_steps": list(N_STEPS),
    "diameters_mm": list(DIAMETERS_MM),
    "mad_range_v": {"1": [0.41, 0.52], "8": [0.079, 0.103]},
    "width_d10": {"2": 9, "4": 17, "8": 34},
    "note": "the mean neighbour difference falls with N and with the diameter; the width of the combined "
            "distribution separates the diameters more finely as N grows (diameter resolution)",
}

def key_figures(result: dict) -> list[tuple]:
    """Mean neighbour difference per N beside the published ranges, and the diameter classification."""
    pub, proto, c = result["published"], result["protocol"], result["classification"]
    rows = [("diameters (mm)", proto["diameters_mm"], pub["diameters_mm"])]
    rows += [(f"neighbour difference range, N = {n} (V)", result["mad_range_v"].get(str(n)),
              pub["mad_range_v"].get(str(n))) for n in proto["n_steps"]]
    ours_w = result.get("table1", {})
    rows += [(f"width, ⌀10 mm, N = {n}", round(ours_w[n]["10"], 1) if "10" in ours_w.get(n, {}) else None, w)
             for n, w in pub.get("width_d10", {}).items()]
    rows += [(f"diameter accuracy, N = {n}", acc, None)
             for n, acc in zip(c["n_steps"], c["accuracy"], strict=True)]
    for name, tabs in (result.get("ablation") or {}).items():
        t1, t2 = tabs["table1"], tabs["table2"]
        rng = {n: [round(min(t2[n].values()), 3), round(max(t2[n].values()), 3)] for n in ("1", "8")}
        rows.append((f"ablation, {name}: diff. range N=1 | N=8 (V); width ⌀10 N=2/4/8",
                     f"{rng['1']} | {rng['8']}; " + "/".join(f"{t1[n]['10']:.1f}" for n in ("2", "4", "8"))
                     if "10" in t1["2"] else f"{rng['1']} | {rng['8']}", None))
    return rows


STUDY = Study(name="tracing", summary="piezo16 finger pad: active tracing of pipes, diameter from the width of "
              "the combined distribution", run=run, draw=draw, published=PUBLISHED, figsize=(14.0, 9.0),
              key_figures=key_figures)
