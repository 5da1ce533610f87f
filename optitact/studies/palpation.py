"""Palpation with thread8 arrays on gripper jaws: the published study reproduced.

Ten objects (rigid block ... soft ball, :data:`~optitact.taxels.grasp.OBJECTS`)
are grasped ten times each with a random pose (:func:`palpation_dataset`);
per frame the mean μ and standard deviation σ of each jaw's 64 taxels form
time series; DTW distances, each normalised by its largest pairwise
distance, for μ, σ or both and the left, right or both jaws
(:func:`palpation_distances`); k-NN (k = 1, 3, 5) with stratified 10-fold
cross validation (:func:`optitact.taxels.dtw.classify`). :func:`run` is the
study, :func:`draw` its figure, ``STUDY`` its registry entry
(``optitact.studies.run("palpation", seed=0, size="quick")``).
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass

import numpy as np

from optitact._validate import integer, seed_value
from optitact.errors import InputError
from optitact.taxels.dtw import classify, dtw_matrix
from optitact.taxels.grasp import OBJECTS, GraspProtocol, PalpationObject, default_jaws, grasp, mu_sigma
from optitact.taxels.thread8 import Thread8
from optitact.studies._protocol import Study, study_seeds

__all__ = ["FEATURES", "SENSORS", "PalpationDataset", "palpation_dataset", "palpation_distances", "PUBLISHED",
           "run", "draw", "STUDY"]

#: Feature sets of the distance metrics: μ alone, σ alone, both (2-D DTW).
FEATURES = ("mu", "sigma", "mu+sigma")
#: Objects of the quick study (indices into OBJECTS): the rigid cylinder and the plastic bottle, the pair the
#: full study confuses most (both stiff, similar contact strip), and two distinct ones (clay roll, soft ball).
QUICK_OBJECTS = (1, 4, 6, 9)
#: Jaws of the distance metrics: left, right, both (sum of the normalised per-jaw distances).
SENSORS = ("left", "right", "both")


@dataclass(frozen=True, eq=False)
class PalpationDataset:
    """Grasps of several objects: frames of both jaws per grasp, labels and poses.

    Attributes
    ----------
    names : tuple of str
        Object names; label ``i`` is ``names[i]``.
    labels : (n,) int
    left, right : tuple of (T_i, rows, cols) uint8 arrays
        Frames of each grasp (lengths differ between grasps).
    contact_frame, x_mm, y_mm, angle_rad : (n,) arrays
        Per grasp, see :class:`Grasp`.
    """

    names: tuple[str, ...]
    labels: np.ndarray
    left: tuple[np.ndarray, ...]
    right: tuple[np.ndarray, ...]
    contact_frame: np.ndarray
    x_mm: np.ndarray
    y_mm: np.ndarray
    angle_rad: np.ndarray

    def __len__(self) -> int:
        return int(self.labels.size)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Table-shaped summary, one row per grasp (frames excluded)."""
        return {"grasp": np.arange(len(self)), "label": self.labels,
                "object": np.array([self.names[i] for i in self.labels]),
                "n_frames": np.array([f.shape[0] for f in self.left]), "contact_frame": self.contact_frame,
                "x_mm": self.x_mm, "y_mm": self.y_mm, "angle_rad": self.angle_rad}

    def features(self, sensor: str) -> list[np.ndarray]:
        """Per grasp the (T_i, 2) series of frame mean μ and standard deviation σ, DN, of ``sensor``."""
        if sensor not in ("left", "right"):
            raise InputError(f"sensor must be 'left' or 'right', got {sensor!r}")
        return [mu_sigma(f) for f in getattr(self, sensor)]


def palpation_dataset(*, n_per_object: int = 10, seed: int | None = 0,
                      objects: tuple[PalpationObject, ...] | None = None,
                      protocol: GraspProtocol | None = None, sensors: tuple[Thread8, Thread8] | None = None,
                      progress: bool = False) -> PalpationDataset:
    """Simulate ``n_per_object`` grasps of each object, each with its own random pose and noise.

    Parameters
    ----------
    n_per_object : int
        Grasps per object (>= 1).
    seed : int, optional
        Seeds every grasp (grasp ``i`` gets the ``i``-th child of ``SeedSequence(seed)``).
    objects : sequence of PalpationObject, optional
        Default :data:`OBJECTS`.
    protocol, sensors
        See :func:`grasp`.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    PalpationDataset
        Grasps ordered object by object.
    """
    from tqdm import tqdm

    n_per_object = integer(n_per_object, "n_per_object", minimum=1)
    seed = seed_value(seed)
    objects = OBJECTS if objects is None else tuple(objects)
    if not objects or not all(isinstance(o, PalpationObject) for o in objects):
        raise TypeError("objects must be a non-empty sequence of PalpationObject")
    names = tuple(o.name for o in objects)
    if len(set(names)) != len(names):
        raise InputError(f"object names must be unique, got {list(names)}")
    sensors = default_jaws(sensors)
    labels = np.repeat(np.arange(len(objects)), n_per_object)
    grasps = [grasp(objects[lab], seed=s, protocol=protocol, sensors=sensors)
              for lab, s in zip(tqdm(labels, desc="thread8 grasps", file=sys.stderr, disable=not progress),
                                study_seeds(seed, labels.size), strict=True)]
    return PalpationDataset(
        names=names, labels=labels, left=tuple(g.left for g in grasps), right=tuple(g.right for g in grasps),
        contact_frame=np.array([g.contact_frame for g in grasps]), x_mm=np.array([g.x_mm for g in grasps]),
        y_mm=np.array([g.y_mm for g in grasps]), angle_rad=np.array([g.angle_rad for g in grasps]))



def _normalised(d: np.ndarray) -> np.ndarray:
    top = d.max()
    return d / top if top > 0 else d.copy()


def palpation_distances(dataset: PalpationDataset, *, window: int | None = None, progress: bool = False,
                        features: tuple[str, ...] = FEATURES) -> dict[str, np.ndarray]:
    """The nine DTW distance metrics of the study, each normalised by its largest pairwise distance.

    Parameters
    ----------
    dataset : PalpationDataset
    window : int, optional
        See :func:`dtw_distance`.
    progress : bool
        tqdm progress bar on stderr.
    features : tuple of str
        Which of :data:`FEATURES` to compute (default all).

    Returns
    -------
    dict
        ``"{feature}/{sensor}"`` → (n, n) matrix with values in [0, 1], for
        ``feature`` in ``features`` and ``sensor`` in :data:`SENSORS`.

    Notes
    -----
    ``mu`` and ``sigma`` use 1-D DTW on one feature; ``mu+sigma`` uses DTW on
    the 2-D series (μ, σ) with the squared Euclidean distance per sample pair.
    A jaw's matrix is divided by its largest entry; ``both`` jaws is the sum of
    the two normalised matrices, divided by its own largest entry. The
    normalisation uses every grasp of the dataset (as in the published study),
    before any cross-validation split.
    """
    from tqdm import tqdm

    if not isinstance(dataset, PalpationDataset):
        raise TypeError(f"dataset must be a PalpationDataset, got {type(dataset).__name__}")
    features = tuple(features)
    if not features or any(f not in FEATURES for f in features):
        raise InputError(f"features must be a non-empty subset of {FEATURES}, got {features!r}")
    feats = {s: dataset.features(s) for s in ("left", "right")}
    columns = {"mu": 0, "sigma": 1, "mu+sigma": slice(0, 2)}
    out = {}
    bar = tqdm(total=len(features) * 2, desc="thread8 DTW", file=sys.stderr, disable=not progress)
    for feature in features:
        per = {}
        for sensor in ("left", "right"):
            per[sensor] = _normalised(dtw_matrix([f[:, columns[feature]] for f in feats[sensor]],
                                                 window=window))
            out[f"{feature}/{sensor}"] = per[sensor]
            bar.update()
        out[f"{feature}/both"] = _normalised(per["left"] + per["right"])
    bar.close()
    return {f"{f}/{s}": out[f"{f}/{s}"] for f in FEATURES if f in features for s in SENSORS}


#: The modelled effects of the set-up and how :func:`without` switches each off (field → value), on the
#: jaws' :class:`~optitact.taxels.thread8.Thread8Config` (``sensor``) or the :class:`GraspProtocol`.
EFFECTS = {
    "sensor spread": {"sensor": {"sensitivity_spread": 0.0, "sensor_gain_spread": 0.0,
                                 "threshold_spread": 0.0}},
    "mounting": {"sensor": {"mount_spread_mm": 0.0, "mount_spread_rad": 0.0, "mount_tilt_rad": 0.0}},
    "object pose": {"protocol": {"offset_mm": 0.0, "angle_range_rad": 0.0}},
    "grasp force": {"protocol": {"step_error_mm": 0.0}},
    "contact onset": {"protocol": {"latency_s": (0.0, 0.0)}},
    "film hysteresis+creep": {"sensor": {"hysteresis": 0.0, "creep_fraction": 0.0}},
    "pad relaxation": {"sensor": {"pad_relax_fraction": (), "pad_relax_tau_s": ()}},
    "drift": {"sensor": {"drift_gain_spread": 0.0}},
    "crosstalk": {"sensor": {"floating_rows": False}},
}
#: Grasps per object and folds of each ablation variant in a full run (half the study's grasps: ten
#: variants in about three minutes on two cores).
ABLATION_SIZE = (5, 5)
#: Feature sets of the ablation (those the paper reports).
ABLATION_FEATURES = ("mu", "mu+sigma")


def without(effect: str | None, sensors: tuple[Thread8, Thread8] | None = None,
            protocol: GraspProtocol | None = None) -> tuple[tuple[Thread8, Thread8], GraspProtocol]:
    """The jaws and the protocol with ``effect`` (a key of :data:`EFFECTS`; None: none) switched off.

    Examples
    --------
    >>> (left, _), proto = without("grasp force")
    >>> proto.step_error_mm, left.config.drift_gain_spread > 0
    (0.0, True)
    """
    sensors = default_jaws(sensors)
    protocol = GraspProtocol() if protocol is None else protocol
    if effect is None:
        return sensors, protocol
    if effect not in EFFECTS:
        raise InputError(f"effect must be one of {list(EFFECTS)}, got {effect!r}")
    change = EFFECTS[effect]
    if "sensor" in change:
        sensors = tuple(Thread8(dataclasses.replace(s.config, **change["sensor"])) for s in sensors)
    if "protocol" in change:
        protocol = dataclasses.replace(protocol, **change["protocol"])
    return sensors, protocol


def recognition_rates(*, objects: tuple[PalpationObject, ...], n_per_object: int, n_folds: int, seed: int,
                      sensors: tuple[Thread8, Thread8] | None = None, protocol: GraspProtocol | None = None,
                      features: tuple[str, ...] = ABLATION_FEATURES, ks=(1, 3, 5),
                      progress: bool = False) -> dict[str, list[float]]:
    """Mean k-NN recognition rate per metric and k of one simulated data set: ``{metric: [rate per k]}``.

    ``seed`` seeds the grasps and the folds as in :func:`run`; the metrics are
    ``"{feature}/{sensor}"`` for ``features`` and :data:`SENSORS`.
    """
    s_data, s_cv = study_seeds(seed, 2)
    data = palpation_dataset(n_per_object=n_per_object, seed=s_data, objects=objects, protocol=protocol,
                             sensors=sensors, progress=progress)
    table = classify(palpation_distances(data, features=features), data.labels, ks=tuple(ks),
                     n_folds=n_folds, seed=s_cv % 2 ** 31)
    out: dict[str, list[float]] = {}
    for metric, rate in zip(table["metric"], table["mean"], strict=True):
        out.setdefault(metric, []).append(float(rate))
    return out


def palpation_ablation(*, objects: tuple[PalpationObject, ...] | None = None, n_per_object: int = 5,
                       n_folds: int = 5, seed: int = 0, effects=None,
                       progress: bool = False) -> dict[str, dict[str, list[float]]]:
    """Recognition with every effect on (``"all on"``) and with each of ``effects`` switched off in turn.

    Parameters
    ----------
    objects : sequence of PalpationObject, optional
        Default all :data:`~optitact.taxels.grasp.OBJECTS`.
    n_per_object, n_folds, seed
        Size of each data set and its cross validation; every variant uses the
        same seed (the same poses and noise draws where the variant draws them).
    effects : sequence of str, optional
        Keys of :data:`EFFECTS` (default all).
    progress : bool
        tqdm progress bars on stderr.

    Returns
    -------
    dict
        ``{"all on" or "no <effect>": {"{feature}/{sensor}": [rate at k = 1, 3, 5]}}`` for the
        :data:`ABLATION_FEATURES`.
    """
    objects = OBJECTS if objects is None else tuple(objects)
    effects = tuple(EFFECTS) if effects is None else tuple(effects)
    out = {}
    for effect in (None, *effects):
        sensors, protocol = without(effect)
        out["all on" if effect is None else f"no {effect}"] = recognition_rates(
            objects=objects, n_per_object=n_per_object, n_folds=n_folds, seed=seed, sensors=sensors,
            protocol=protocol, progress=progress)
    return out



def run(seed: int, *, full: bool, progress: bool) -> dict:
    """The palpation study on simulated grasps: DTW distances, k-NN, cross validation.

    Parameters
    ----------
    seed : int
        Seeds the grasps and the fold shuffle.
    full : bool
        Full size (all ten :data:`~optitact.taxels.grasp.OBJECTS` × 10 grasps,
        10 folds) or quick (the 4 :data:`QUICK_OBJECTS` × 5 grasps, 5 folds: a few seconds).
    progress : bool
        tqdm progress bars on stderr.

    Returns
    -------
    dict
        ``config`` (left jaw), ``protocol``, ``objects`` (catalogue rows
        used), ``n_per_object``, ``n_folds``, ``ks``, ``table``
        (:func:`~optitact.taxels.dtw.classify`), ``grasps``
        (:meth:`PalpationDataset.as_dict`), ``recognition`` (per metric the
        [lowest, highest] mean rate over the ks, as ``PUBLISHED["recognition"]``),
        ``jaws`` (each jaw's drawn sensor gain and mounting), ``examples`` (μ and σ series of the
        first grasp of every object, left jaw), ``rate_hz``, ``chance``, and with ``full``
        ``ablation`` (:func:`palpation_ablation` on all objects at :data:`ABLATION_SIZE`, same seed;
        None in a quick run, which stays as fast as before) and ``ablation_size``.
    """
    if full:
        objects, n_per, n_folds = OBJECTS, 10, 10
    else:
        objects, n_per, n_folds = tuple(OBJECTS[i] for i in QUICK_OBJECTS), 5, 5
    ks = (1, 3, 5)
    protocol = GraspProtocol()
    sensors = default_jaws(None)
    s_data, s_cv = study_seeds(seed, 2)
    data = palpation_dataset(n_per_object=n_per, seed=s_data, objects=objects, protocol=protocol,
                             sensors=sensors, progress=progress)
    distances = palpation_distances(data, progress=progress)
    table = classify(distances, data.labels, ks=ks, n_folds=n_folds, seed=s_cv % 2 ** 31)
    recognition = {}
    for metric, rate in zip(table["metric"], table["mean"], strict=True):
        lo, hi = recognition.get(metric, (np.inf, -np.inf))
        recognition[metric] = (min(lo, float(rate)), max(hi, float(rate)))
    feats = data.features("left")
    first = [int(np.flatnonzero(data.labels == i)[0]) for i in range(len(objects))]
    ablation = (palpation_ablation(objects=objects, n_per_object=ABLATION_SIZE[0], n_folds=ABLATION_SIZE[1],
                                   seed=seed, progress=progress) if full else None)
    return {
        "ablation": ablation, "ablation_size": {"n_per_object": ABLATION_SIZE[0], "n_folds": ABLATION_SIZE[1]}
        if full else None,
        "config": dataclasses.asdict(sensors[0].config), "protocol": dataclasses.asdict(protocol),
        "objects": [o.as_dict() for o in objects], "n_per_object": n_per, "n_folds": n_folds, "ks": list(ks),
        "chance": 1.0 / len(objects), "rate_hz": sensors[0].layout.rate_hz, "table": table,
        "recognition": {m: list(v) for m, v in recognition.items()},
        "jaws": [{"sensor_gain": s.sensor_gain, "mount_offset_mm": list(s.mount_offset_mm),
                  "mount_angle_rad": s.mount_angle_rad, "mount_tilt_rad": s.config.mount_tilt_rad}
                 for s in sensors],
        "grasps": data.as_dict(),
        "examples": {"object": [objects[i].name for i in range(len(objects))],
                     "mu": [feats[j][:, 0].tolist() for j in first],
                     "sigma": [feats[j][:, 1].tolist() for j in first],
                     "contact_frame": [int(data.contact_frame[j]) for j in first]},
    }


def draw(fig, result: dict) -> None:
    """μ and σ series per object and the recognition table (k-NN rate per metric and k, 95 % CI).

    Where the result carries the published rates (``result["published"]["recognition"]``), each
    metric's published range over k is drawn over its bars (two black lines) in a grey band of that
    range ± 5 points.

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Filled in place (``optitact.studies.save_plot("palpation", result, path)`` makes and saves it).
    result : dict
        As returned by ``optitact.studies.run("palpation", ...)`` (or read back from its JSON).
    """
    from matplotlib.patches import Rectangle

    ex, table, rate = result["examples"], result["table"], float(result["rate_hz"])
    names, mus, sigmas = ex["object"], ex["mu"], ex["sigma"]
    metrics = list(dict.fromkeys(table["metric"]))
    ks = sorted(set(table["k"]))
    grid = fig.add_gridspec(2, 2)
    colours = [f"C{i}" for i in range(10)]
    for col, (series, label) in enumerate(((mus, "frame mean μ, DN"), (sigmas, "frame std σ, DN"))):
        ax = fig.add_subplot(grid[0, col])
        for i, (name, s) in enumerate(zip(names, series, strict=True)):
            s = np.asarray(s)
            ax.plot(np.arange(s.size) / rate, s, color=colours[i % 10], lw=1.2, label=name)
        ax.set_xlabel("time, s")
        ax.set_ylabel(label)
        ax.set_title(f"{label.split(',')[0]} (left jaw, first grasp of each object)")
        if col == 0:
            ax.legend(fontsize=7, ncol=2)
    ax = fig.add_subplot(grid[1, :])
    width = 0.8 / len(ks)
    pos = np.arange(len(metrics))
    for j, k in enumerate(ks):
        rows = [next(i for i, (m, kk) in enumerate(zip(table["metric"], table["k"], strict=True))
                     if m == metric and kk == k) for metric in metrics]
        mean = np.array([table["mean"][i] for i in rows])
        lo = mean - np.array([table["ci_low"][i] for i in rows])
        hi = np.array([table["ci_high"][i] for i in rows]) - mean
        ax.bar(pos + (j - (len(ks) - 1) / 2) * width, 100 * mean, width, yerr=100 * np.vstack([lo, hi]),
               capsize=2, label=f"k = {k}", color=f"C{j}")
    if "chance" in result:
        ax.axhline(100 * result["chance"], color="grey", ls="--", lw=1, label="chance")
    published = (result.get("published") or {}).get("recognition", {})
    shown = [m for m in metrics if m in published]
    for metric in shown:   # the published range over k, and that range +- 5 points
        i, first = metrics.index(metric), metric == shown[0]
        lo, hi = (100 * float(v) for v in published[metric])
        ax.add_patch(Rectangle((i - 0.45, lo - 5), 0.9, hi - lo + 10, color="k", alpha=0.08, lw=0,
                               label="published ± 5 points" if first else None))
        ax.hlines([lo, hi], i - 0.45, i + 0.45, color="k", lw=1.5, label="published range" if first else None)
    ax.set_xticks(pos, metrics, rotation=20, fontsize=8)
    ax.set_ylim(0, 105)
    ax.set_ylabel("recognition rate, % (mean, 95 % CI over folds)")
    ax.set_title("k-NN on normalised DTW distances, stratified cross validation")
    ax.legend(fontsize=8, loc="lower right")
    fig.suptitle(f"thread8 palpation study (seed {result.get('seed')}, full={result.get('full')}, "
                 f"{result.get('n_per_object')} grasps per object)")


Thread8.register()


#: The published recognition rates (10 objects × 10 grasps, DTW, 1/3/5-NN, 10-fold cross validation):
#: ranges over k, per feature set and jaw, fractions.
PUBLISHED = {
    "reference": "Palpation with 8x8 piezoresistive thread-electrode arrays on a parallel gripper's jaws: "
                 "10 objects x 10 grasps, DTW on the frame mean and standard deviation, 1/3/5-NN, "
                 "stratified 10-fold cross validation",
    "ks": [1, 3, 5],
    "n_folds": 10,
    "recognition": {
        "mu/left": [0.707, 0.781], "mu/right": [0.840, 0.860], "mu/both": [0.840, 0.916],
        "mu+sigma/left": [0.781, 0.886], "mu+sigma/right": [0.850, 0.880], "mu+sigma/both": [0.900, 0.920],
    },
    "note": "left and right differ because the real sensors were placed imperfectly and hand-made; rigid "
            "objects were confused with each other",
}

def key_figures(result: dict) -> list[tuple[str, object, object]]:
    """The published rates beside ours, then (full runs) one ablation row per variant.

    An ablation row holds the mean rate over k = 1, 3, 5 of ``mu`` and ``mu+sigma`` for the left, right
    and both jaws (in that order; the paper has no ablation).
    """
    from optitact.studies._protocol import paired_figures

    rows = paired_figures(result.get("published") or {}, result)
    for variant, rates in (result.get("ablation") or {}).items():
        vals = [round(float(np.mean(rates[f"{f}/{s}"])), 3) for f in ABLATION_FEATURES for s in SENSORS]
        rows.append((f"ablation {variant}: mu L/R/B, mu+sigma L/R/B", vals, None))
    return rows


STUDY = Study(name="palpation", summary="thread8 arrays on gripper jaws: object recognition by DTW k-NN on the "
              "frame mean and standard deviation", run=run, draw=draw, published=PUBLISHED, figsize=(15.0, 9.0),
              key_figures=key_figures)
