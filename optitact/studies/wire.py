"""Wire study on the simulated 5×5 optoelectronic pad: normalisation, wire shape, diameter classifiers.

The study of the wire-handling paper reproduced on :class:`~optitact.taxels.opto5.Opto5`:
a calibration closure builds the per-taxel normalisation
(:class:`~optitact.taxels.wire.NormalisationLUT`); simulated grasps of wires
of six diameters plus a no-wire class (:func:`wire_dataset`) train the 2-D
lookup table, an SVM with a second-order polynomial kernel
(:func:`svm_classifier`) and a small neural network (:func:`mlp_classifier`)
(:func:`classify_wires`); :func:`shape_comparison` shows that normalisation
matters for the wire's shape. ``optitact.studies.run("wire")`` runs it all.
"""

from __future__ import annotations

import sys
import warnings
from dataclasses import asdict, dataclass

import numpy as np

from optitact._optional import require
from optitact._validate import finite, integer, positive, real_array, seed_value
from optitact.errors import InputError
from optitact.taxels.sources import Indenter
from optitact.taxels.opto5 import FINGER_DISTANCE_MAX, Opto5, Opto5Config, grasp_scenario
from optitact.taxels.wire import (LookupTableClassifier, NormalisationLUT, calibration_closure, hold_response,
                                  main_direction, wire_shape)
from optitact.studies._protocol import Study, study_seeds

__all__ = ["WIRE_DIAMETERS_MM", "svm_classifier", "mlp_classifier", "WireDataset", "wire_dataset",
           "classify_wires", "shape_comparison", "run", "draw", "STUDY"]

#: Wire diameters of the diameter study, mm (the no-wire class is diameter 0).
WIRE_DIAMETERS_MM = (1.5, 2.0, 2.5, 3.0, 3.5, 4.0)


def svm_classifier(*, C: float = 10.0):
    """Scaled SVM, second-order polynomial kernel ``(γ x·x' + 1)²``, one-vs-one (scikit-learn pipeline)."""
    make_pipeline = require("sklearn.pipeline", purpose="the wire study").make_pipeline
    StandardScaler = require("sklearn.preprocessing", purpose="the wire study").StandardScaler
    SVC = require("sklearn.svm", purpose="the wire study").SVC

    return make_pipeline(StandardScaler(), SVC(kernel="poly", degree=2, coef0=1.0, C=positive(C, "C"),
                                               decision_function_shape="ovo"))


def mlp_classifier(*, hidden: tuple[int, ...] = (64, 32), seed: int | None = None, max_iter: int = 2000):
    """Scaled small multi-layer perceptron (scikit-learn ``MLPClassifier``, Adam, ReLU)."""
    MLPClassifier = require("sklearn.neural_network", purpose="the wire study").MLPClassifier
    make_pipeline = require("sklearn.pipeline", purpose="the wire study").make_pipeline
    StandardScaler = require("sklearn.preprocessing", purpose="the wire study").StandardScaler

    hidden = tuple(integer(h, "hidden", minimum=1) for h in hidden)
    return make_pipeline(StandardScaler(), MLPClassifier(hidden_layer_sizes=hidden, alpha=1e-3,
                                                         max_iter=integer(max_iter, "max_iter", minimum=1),
                                                         random_state=seed_value(seed)))


@dataclass(frozen=True, eq=False)
class WireDataset:
    """Simulated wire grasps: one observation per grasp.

    Attributes
    ----------
    finger_distance : (n,) int array
        Encoder value of the grasp.
    diameter_mm : (n,) array
        Class label: wire diameter, 0 for no wire.
    angle_rad, offset_mm : (n,) arrays
        Wire direction and signed distance of its axis from the pad centre.
    dv : (n, 5, 5) array
        Offset-removed hold response, V.
    values : (n, 5, 5) array
        Normalised Δṽ.
    """

    finger_distance: np.ndarray
    diameter_mm: np.ndarray
    angle_rad: np.ndarray
    offset_mm: np.ndarray
    dv: np.ndarray
    values: np.ndarray

    def __len__(self) -> int:
        return int(self.finger_distance.size)

    def features(self) -> np.ndarray:
        """Observations (n, 26): finger distance, then the 25 normalised values (row-major)."""
        return np.column_stack([self.finger_distance, self.values.reshape(len(self), -1)])

    def as_dict(self) -> dict[str, np.ndarray]:
        """Table-shaped: ``grasp``, scalars per grasp, ``sum`` and one column ``v_r_c`` per taxel."""
        out = {"grasp": np.arange(len(self)), "finger_distance": self.finger_distance,
               "diameter_mm": self.diameter_mm, "angle_rad": self.angle_rad, "offset_mm": self.offset_mm,
               "sum": self.values.reshape(len(self), -1).sum(axis=1)}
        for r, c in np.ndindex(self.values.shape[1:]):
            out[f"v_{r}_{c}"] = self.values[:, r, c]
        return out


def wire_dataset(*, n_per_class: int, seed: int | None = None, source: Opto5 | None = None,
                 lut: NormalisationLUT | None = None, diameters_mm=WIRE_DIAMETERS_MM,
                 finger_range: tuple[int, int] = (214, 255), max_offset_mm: float = 7.0,
                 n_base: int = 50, n_ramp: int = 10, n_hold: int = 10, progress: bool = False) -> WireDataset:
    """Simulated grasps of wires of each diameter plus a no-wire class.

    Each grasp: ``n_base`` unloaded samples, the gripper closing to a random
    finger distance over ``n_ramp`` samples, ``n_hold`` samples held; the
    observation is the mean offset-removed hold response, normalised.

    Parameters
    ----------
    n_per_class : int
        Grasps per class (each diameter and no wire).
    seed : int, optional
        Seeds everything random (poses, finger distances, sensor noise).
    source : Opto5, optional
        The sensor; ``Opto5()`` by default.
    lut : NormalisationLUT, optional
        Normalisation; by default built from :func:`calibration_closure` of ``source``.
    diameters_mm : sequence of float
        Wire diameters, mm.
    finger_range : (int, int)
        Inclusive range of the random finger distances (encoder values); the
        default starts just past contact with the thinnest wire.
    max_offset_mm : float
        Wire axis offset from the pad centre is uniform in ±this, mm; angle uniform in [0, π).
    n_base, n_ramp, n_hold : int
        Samples per grasp phase.
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    WireDataset
    """
    from tqdm import tqdm

    n_per_class = integer(n_per_class, "n_per_class", minimum=2)
    source = Opto5() if source is None else source
    if not isinstance(source, Opto5):
        raise TypeError(f"source must be an Opto5, got {type(source).__name__}")
    diam = finite(real_array(diameters_mm, "diameters_mm"), "diameters_mm")
    if diam.ndim != 1 or diam.size < 1 or np.any(diam <= 0):
        raise InputError(f"diameters_mm must be a non-empty 1-D array of positive diameters, "
                         f"got {diameters_mm!r}")
    lo, hi = (integer(v, "finger_range") for v in finger_range)
    if not 0 <= lo <= hi <= FINGER_DISTANCE_MAX:
        raise InputError(f"finger_range must satisfy 0 <= low <= high <= 255, got {finger_range!r}")
    max_off = positive(max_offset_mm, "max_offset_mm", allow_zero=True)
    n_base, n_ramp, n_hold = (integer(v, k, minimum=1) for v, k in
                              ((n_base, "n_base"), (n_ramp, "n_ramp"), (n_hold, "n_hold")))
    ss = np.random.SeedSequence(seed_value(seed))
    lut_seq, pose_seq, noise_seq = ss.spawn(3)
    if lut is None:
        dv_c, stim = calibration_closure(source, seed=int(lut_seq.generate_state(1)[0]))
        lut = NormalisationLUT.from_closure(dv_c, stim)
    if not isinstance(lut, NormalisationLUT):
        raise TypeError(f"lut must be a NormalisationLUT, got {type(lut).__name__}")
    labels = np.repeat(np.concatenate([[0.0], diam]), n_per_class)
    n = labels.size
    rng = np.random.default_rng(pose_seq)
    p = rng.integers(lo, hi, endpoint=True, size=n)
    ang = rng.uniform(0.0, np.pi, size=n)
    off = rng.uniform(-max_off, max_off, size=n)
    seeds = noise_seq.generate_state(n)
    dv = np.empty((n, *source.layout.shape))
    for i in tqdm(range(n), desc="opto5 grasps", file=sys.stderr, disable=not progress):
        d = labels[i]
        depth = float(source.depth_from_finger_distance(p[i], d)) if d > 0 else 0.0
        ind = Indenter("wire", d / 2) if d > 0 else Indenter("flat")
        sc = grasp_scenario(source, ind, depth, n_base=n_base, n_ramp=n_ramp, n_hold=n_hold,
                             x_mm=-off[i] * np.sin(ang[i]), y_mm=off[i] * np.cos(ang[i]), angle_rad=ang[i])
        dv[i] = hold_response(source, sc, n_base=n_base, n_hold=n_hold, seed=int(seeds[i]))
    return WireDataset(p, labels, ang, off, dv, lut.apply(dv))


def classify_wires(dataset: WireDataset, *, seed: int | None = 0, test_size: float = 0.2) -> dict:
    """Train and test the three diameter classifiers on one stratified split.

    Parameters
    ----------
    dataset : WireDataset
    seed : int, optional
        Seeds the split and the network's initialisation.
    test_size : float
        Test fraction (stratified by class).

    Returns
    -------
    dict
        JSON-serialisable: ``classes_mm``, ``n_train``, ``n_test``, ``chance``, and for
        ``lookup_table``, ``svm`` and ``mlp``: ``accuracy`` and ``confusion``
        (rows: true class, columns: predicted, in ``classes_mm`` order); the
        network also reports ``converged`` and ``n_iter``.
    """
    ConvergenceWarning = require("sklearn.exceptions", purpose="the wire study").ConvergenceWarning
    confusion_matrix = require("sklearn.metrics", purpose="the wire study").confusion_matrix
    train_test_split = require("sklearn.model_selection", purpose="the wire study").train_test_split

    if not isinstance(dataset, WireDataset):
        raise TypeError(f"dataset must be a WireDataset, got {type(dataset).__name__}")
    seed = seed_value(seed)
    if not 0 < test_size < 1:
        raise InputError(f"test_size must be in (0, 1), got {test_size!r}")
    X, y = dataset.features(), dataset.diameter_mm
    classes = np.unique(y)
    label = np.searchsorted(classes, y)          # integer class index for scikit-learn
    tr, te = train_test_split(np.arange(len(y)), test_size=test_size, stratify=label, random_state=seed)

    def report(pred):
        cm = confusion_matrix(label[te], np.searchsorted(classes, pred), labels=np.arange(classes.size))
        return {"accuracy": float(np.mean(pred == y[te])), "confusion": cm.tolist()}

    table = LookupTableClassifier.fit(X[tr, 0], X[tr, 1:].sum(axis=1), y[tr])
    out = {"classes_mm": classes.tolist(), "n_train": int(tr.size), "n_test": int(te.size),
           "chance": 1.0 / classes.size,
           "lookup_table": report(table.predict(X[te, 0], X[te, 1:].sum(axis=1)))}
    svm = svm_classifier().fit(X[tr], label[tr])
    out["svm"] = report(classes[svm.predict(X[te])])
    mlp = mlp_classifier(seed=seed)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConvergenceWarning)
        mlp.fit(X[tr], label[tr])
    out["mlp"] = report(classes[mlp.predict(X[te])])
    out["mlp"]["converged"] = not any(issubclass(w.category, ConvergenceWarning) for w in caught)
    out["mlp"]["n_iter"] = int(mlp[-1].n_iter_)
    return out


# ---- normalisation matters ---------------------------------------------------------------------------
def _true_curve(x_cols: np.ndarray, x0: float, y0: float, ang: float, kappa: float) -> np.ndarray:
    s = np.linspace(-40.0, 40.0, 8001)
    px = x0 + s * np.cos(ang) - 0.5 * kappa * s * s * np.sin(ang)
    py = y0 + s * np.sin(ang) + 0.5 * kappa * s * s * np.cos(ang)
    order = np.argsort(px)
    return np.interp(x_cols, px[order], py[order])


def shape_comparison(source: Opto5, lut: NormalisationLUT, *, n_trials: int = 20, seed: int | None = None,
                     diameter_mm: float = 3.0, finger_distance: int = 235) -> dict:
    """Shape estimation from raw Δv versus normalised Δṽ: a flat grasp and wires near the pad's edge.

    Parameters
    ----------
    source : Opto5
    lut : NormalisationLUT
    n_trials : int
        Edge-wire grasps: roughly horizontal (±10°), slightly curved
        (``|κ| <= 0.01`` /mm), axis 4.5–6.5 mm from the centre towards either edge.
    seed : int, optional
    diameter_mm : float
        Wire diameter of the edge trials, mm.
    finger_distance : int
        Encoder value of the edge grasps.

    Returns
    -------
    dict
        JSON-serialisable. ``flat``: raw and normalised hold images of a flat
        grasp at half the closure depth and their spread across taxels
        (``*_cv``: std/mean; ``*_max_over_min``). ``edge_wire``: per-trial RMS
        error (mm) over the columns of the fitted centre line, from raw and
        from normalised values and from the noise-free cell forces of equal
        linear taxels (``ideal``: the floor of the centroid method itself),
        with the main direction given as horizontal; their means; how often the
        automatic main direction is right; one example (images, fits, truth).
    """
    if not isinstance(source, Opto5) or not isinstance(lut, NormalisationLUT):
        raise TypeError("source must be an Opto5 and lut a NormalisationLUT, got "
                        f"{type(source).__name__} and {type(lut).__name__}")
    n_trials = integer(n_trials, "n_trials", minimum=1)
    ss = np.random.SeedSequence(seed_value(seed))
    rng = np.random.default_rng(ss.spawn(1)[0])
    n_base, n_ramp, n_hold = 50, 10, 10
    depth_flat = 0.5 * float(source.depth_from_finger_distance(FINGER_DISTANCE_MAX, 4.0))
    sc = grasp_scenario(source, Indenter("flat"), depth_flat, n_base=n_base, n_ramp=n_ramp, n_hold=n_hold)
    raw = hold_response(source, sc, n_base=n_base, n_hold=n_hold, seed=int(rng.integers(2 ** 32)))
    norm = lut.apply(raw)

    def spread(img):
        return float(img.std() / img.mean()), float(img.max() / img.min())

    flat = {"depth_mm": depth_flat, "raw": raw.tolist(), "normalised": norm.tolist()}
    flat["raw_cv"], flat["raw_max_over_min"] = spread(raw)
    flat["normalised_cv"], flat["normalised_max_over_min"] = spread(norm)

    x_cols = source.layout.cell_xy()[0][0]
    depth = float(source.depth_from_finger_distance(finger_distance, diameter_mm))
    err = {"raw": [], "normalised": [], "ideal": []}
    auto_ok = {"raw": 0, "normalised": 0}
    example = None
    for _ in range(n_trials):
        ang = rng.uniform(-np.pi / 18, np.pi / 18)
        y0 = rng.choice([-1.0, 1.0]) * rng.uniform(4.5, 6.5)
        kappa = rng.uniform(-0.01, 0.01)
        sc = grasp_scenario(source, Indenter("wire", diameter_mm / 2), depth, n_base=n_base, n_ramp=n_ramp,
                             n_hold=n_hold, y_mm=y0, angle_rad=ang, curvature_per_mm=kappa)
        raw_w = hold_response(source, sc, n_base=n_base, n_hold=n_hold, seed=int(rng.integers(2 ** 32)))
        truth = _true_curve(x_cols, 0.0, y0, ang, kappa)
        ideal = source.contact(sc)["taxel_force_n"][-n_hold:].mean(axis=0)   # equal linear taxels, no noise
        fits = {}
        for key, img in (("raw", raw_w), ("normalised", lut.apply(raw_w)), ("ideal", ideal)):
            fit = wire_shape(img, direction="horizontal", pitch_mm=source.config.pitch_mm)
            est = fit.a * x_cols ** 2 + fit.b * x_cols + fit.c
            err[key].append(float(np.sqrt(np.mean((est - truth) ** 2))))
            if key in auto_ok:
                auto_ok[key] += main_direction(img, source.config.pitch_mm) == "horizontal"
            fits[key] = (img, fit)
        if example is None:
            example = {"y0_mm": y0, "angle_rad": ang, "curvature_per_mm": kappa, "x_mm": x_cols.tolist(),
                       "truth_y_mm": truth.tolist(),
                       **{f"{k}_image": v[0].tolist() for k, v in fits.items()},
                       **{f"{k}_fit": list(v[1][:3]) for k, v in fits.items()}}
    edge = {"diameter_mm": diameter_mm, "finger_distance": finger_distance, "n_trials": n_trials,
            "raw_rms_mm": err["raw"], "normalised_rms_mm": err["normalised"],
            "raw_mean_rms_mm": float(np.mean(err["raw"])),
            "normalised_mean_rms_mm": float(np.mean(err["normalised"])),
            "ideal_rms_mm": err["ideal"], "ideal_mean_rms_mm": float(np.mean(err["ideal"])),
            "raw_auto_direction_ok": auto_ok["raw"] / n_trials,
            "normalised_auto_direction_ok": auto_ok["normalised"] / n_trials, "example": example}
    return {"flat": flat, "edge_wire": edge}


def run(seed: int, *, full: bool, progress: bool) -> dict:
    """The wire study on the simulated pad: normalisation, diameter classifiers, shape comparison.

    Parameters
    ----------
    seed : int
        Seeds the whole study (the sensor instance is ``Opto5Config(unit_seed=seed)``).
    full : bool
        Full size (300 grasps per class, 1000-sample closure, 40 edge trials)
        or quick (100, 300, 8: a few seconds).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    dict
        ``config``, ``n_per_class``, ``n_closure_samples``, ``classification``
        (:func:`classify_wires`), ``normalisation`` (:func:`shape_comparison`)
        and ``lut`` (per-taxel table summary).
    """
    n_per_class, n_closure, n_trials = (300, 1000, 40) if full else (100, 300, 8)
    source = Opto5(Opto5Config(unit_seed=seed))
    s_lut, s_data, s_cls, s_shape = study_seeds(seed, 4)
    dv_c, stim = calibration_closure(source, n_samples=n_closure, seed=s_lut)
    lut = NormalisationLUT.from_closure(dv_c, stim)
    data = wire_dataset(n_per_class=n_per_class, seed=s_data, source=source, lut=lut, progress=progress)
    return {
        "config": asdict(source.config), "n_per_class": n_per_class, "n_closure_samples": n_closure,
        "classification": classify_wires(data, seed=s_cls % 2 ** 31),
        "normalisation": shape_comparison(source, lut, n_trials=n_trials, seed=s_shape),
        "lut": lut.as_dict(),
    }


def draw(fig, result: dict) -> None:
    """Confusion matrices of the three classifiers and the raw-versus-normalised comparison."""
    cls, norm = result["classification"], result["normalisation"]
    classes = cls["classes_mm"]
    axes = fig.subplots(2, 4)
    ticks = ["none" if c == 0 else f"{c:g}" for c in classes]
    titles = {"lookup_table": "2-D lookup table", "svm": "SVM (poly 2)", "mlp": "neural network"}
    for ax, (key, title) in zip(axes[0, :3], titles.items(), strict=True):
        cm = np.asarray(cls[key]["confusion"])
        ax.imshow(cm, cmap="Blues")
        for (i, j), v in np.ndenumerate(cm):
            if v:
                ax.text(j, i, str(v), ha="center", va="center", fontsize=7,
                        color="white" if v > cm.max() / 2 else "black")
        ax.set_xticks(range(len(classes)), ticks, fontsize=7)
        ax.set_yticks(range(len(classes)), ticks, fontsize=7)
        ax.set_xlabel("predicted diameter, mm")
        ax.set_ylabel("true diameter, mm")
        ax.set_title(f"{title}: {100 * cls[key]['accuracy']:.1f} %")
    ax = axes[0, 3]
    edge = norm["edge_wire"]
    ax.boxplot([edge["raw_rms_mm"], edge["normalised_rms_mm"]])
    ax.set_xticks([1, 2], ["raw Δv", "normalised Δṽ"])
    ax.set_ylabel("centre-line RMS error, mm")
    ax.set_title("wire near the edge")
    flat = norm["flat"]
    for ax, key in ((axes[1, 0], "raw"), (axes[1, 1], "normalised")):
        img = np.asarray(flat[key])
        im = ax.imshow(img / img.mean(), cmap="coolwarm", vmin=0.0, vmax=2.0)
        fig.colorbar(im, ax=ax, shrink=0.8, label="value / pad mean")
        ax.set_title(f"flat grasp, {'raw Δv' if key == 'raw' else 'normalised Δṽ'}: CV {flat[key + '_cv']:.2f}")
    ex = edge["example"]
    x = np.asarray(ex["x_mm"])
    xs = np.linspace(x.min(), x.max(), 100)
    pitch = float(x[1] - x[0])
    for ax, key in ((axes[1, 2], "raw"), (axes[1, 3], "normalised")):
        img = np.asarray(ex[f"{key}_image"])
        half = pitch * (img.shape[0] / 2)
        ax.imshow(img, cmap="viridis", extent=(-half, half, half, -half))
        ax.plot(x, ex["truth_y_mm"], "w-", lw=2, label="true")
        a, b, c = ex[f"{key}_fit"]
        ax.plot(xs, a * xs ** 2 + b * xs + c, "r--", lw=2, label="fit")
        ax.set_xlabel("x, mm")
        ax.set_ylabel("y, mm")
        ax.set_title(f"edge wire, {key}")
        ax.legend(fontsize=7, loc="lower right")
    fig.suptitle(f"opto5 wire study (seed {result.get('seed')}, full={result.get('full')})")


#: What the wire-handling paper reports, next to the study's own figures.
PUBLISHED = {
    "reference": ("5×5 optoelectronic taxel pad on a gripper finger, wire shape and diameter "
                  "(the wire-handling paper as specified in issue 8)"),
    "sensor": {"pitch_mm": 3.55, "pad_mm": 21.0, "adc_bits": 12, "rate_hz": 500.0,
               "sensitivity_v_per_n": 0.018, "hysteresis": 0.05, "repeatability": 0.03},
    "lookup_table_row_218": {"finger_distance": 218, "diameters_mm": list(WIRE_DIAMETERS_MM),
                             "mean_sum": [0.9518, 2.2716, 3.0802, 3.5735, 6.2054, 7.9888]},
    "lookup_table_example": {"finger_distance": 218, "sum": 3.2, "diameter_mm": 2.5},
    "classifiers": "SVM (2nd-order polynomial kernel) and the neural network near 100 %; the lookup "
                   "table clearly worse, confusing neighbouring diameters",
}

def key_figures(result: dict) -> list[tuple]:
    """Diameter accuracy per classifier beside the paper's verdict, and the pad's stated specification."""
    c, pub = result["classification"], result["published"]
    rows = [("accuracy/lookup table", c["lookup_table"]["accuracy"], "clearly worse than SVM and NN"),
            ("accuracy/SVM", c["svm"]["accuracy"], "near 1"),
            ("accuracy/neural network", c["mlp"]["accuracy"], "near 1"),
            ("accuracy/chance", c["chance"], None)]
    return rows + [(f"sensor/{k}", result["config"].get(k), v) for k, v in pub["sensor"].items()]


STUDY = Study(name="wire", summary="5x5 optoelectronic pad, wire shape and diameter", run=run, draw=draw,
              published=PUBLISHED, figsize=(16.0, 8.5), key_figures=key_figures)

