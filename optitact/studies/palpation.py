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


def palpation_distances(dataset: PalpationDataset, *, window: int | None = None,
                        progress: bool = False) -> dict[str, np.ndarray]:
    """The nine DTW distance metrics of the study, each normalised by its largest pairwise distance.

    Parameters
    ----------
    dataset : PalpationDataset
    window : int, optional
        See :func:`dtw_distance`.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    dict
        ``"{feature}/{sensor}"`` → (n, n) matrix with values in [0, 1], for
        ``feature`` in :data:`FEATURES` and ``sensor`` in :data:`SENSORS`.

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
    feats = {s: dataset.features(s) for s in ("left", "right")}
    columns = {"mu": 0, "sigma": 1, "mu+sigma": slice(0, 2)}
    out = {}
    bar = tqdm(total=len(FEATURES) * 2, desc="thread8 DTW", file=sys.stderr, disable=not progress)
    for feature in FEATURES:
        per = {}
        for sensor in ("left", "right"):
            per[sensor] = _normalised(dtw_matrix([f[:, columns[feature]] for f in feats[sensor]],
                                                 window=window))
            out[f"{feature}/{sensor}"] = per[sensor]
            bar.update()
        out[f"{feature}/both"] = _normalised(per["left"] + per["right"])
    bar.close()
    return {f"{f}/{s}": out[f"{f}/{s}"] for f in FEATURES for s in SENSORS}



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
        first grasp of every object, left jaw), ``rate_hz`` and ``chance``.
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
    return {
        "config": dataclasses.asdict(sensors[0].config), "protocol": dataclasses.asdict(protocol),
        "objects": [o.as_dict() for o in objects], "n_per_object": n_per, "n_folds": n_folds, "ks": list(ks),
        "chance": 1.0 / len(objects), "rate_hz": sensors[0].layout.rate_hz, "table": table,
        "recognition": {m: list(v) for m, v in recognition.items()},
        "jaws": [{"sensor_gain": s.sensor_gain, "mount_offset_mm": list(s.mount_offset_mm),
                  "mount_angle_rad": s.mount_angle_rad} for s in sensors],
        "grasps": data.as_dict(),
        "examples": {"object": [objects[i].name for i in range(len(objects))],
                     "mu": [feats[j][:, 0].tolist() for j in first],
                     "sigma": [feats[j][:, 1].tolist() for j in first],
                     "contact_frame": [int(data.contact_frame[j]) for j in first]},
    }


def draw(fig, result: dict) -> None:
    """μ and σ series per object and the recognition table (k-NN rate per metric and k, 95 % CI).

    Parameters
    ----------
    fig : matplotlib.figure.Figure
        Filled in place (``optitact.studies.save_plot("palpation", result, path)`` makes and saves it).
    result : dict
        As returned by ``optitact.studies.run("palpation", ...)`` (or read back from its JSON).
    """
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

STUDY = Study(name="palpation", summary="thread8 arrays on gripper jaws: object recognition by DTW k-NN on the "
              "frame mean and standard deviation", run=run, draw=draw, published=PUBLISHED, figsize=(15.0, 9.0))
