"""Object recognition with a five-finger hand of :class:`~optitact.taxels.fingertip25.Fingertip25` fingertips.

Nine objects (rigid and soft) as data (:data:`OBJECTS`), a contact model of
one fingertip pressed on an object's curved, compliant surface
(:func:`grasp`: 125 features per grasp), simulated grasp sets
(:func:`object_dataset`), a back-propagation network on them
(:func:`recognise_objects`) and the hardness cue (:func:`hardness_cues`):
part of ``optitact.studies.run("fingertip")``.
"""

from __future__ import annotations

import math
import numbers
import sys
import warnings
from dataclasses import dataclass

import numpy as np

from optitact._optional import require
from optitact._validate import finite, integer, positive, real_array, seed_value
from optitact.errors import InputError, ShapeError
from optitact.taxels.fingertip25 import Fingertip25, force_from_resistance

__all__ = ["fingertip_source", "GraspObject", "OBJECTS", "FINGERS", "RIGID_STIFFNESS_N_PER_MM", "grasp",
           "ObjectDataset", "object_dataset", "hidden_units", "recognise_objects", "hardness_cues"]

#: The hand's fingers, in feature order (25 units each).
FINGERS = ("thumb", "index", "middle", "ring", "little")
_SHAPES = ("sphere", "ellipsoid", "cylinder", "box")
#: Objects with a per-unit contact stiffness at least this (N/mm) count as rigid.
RIGID_STIFFNESS_N_PER_MM = 100.0


@dataclass(frozen=True)
class GraspObject:
    """An object of the recognition study, as data.

    ``fingers`` counts the fingers in contact in a typical grasp, thumb
    included (the thumb opposes the others); ``grasp_force_n`` is the typical
    total grip force (thumb + fingers), lower for fragile objects.
    """

    name: str
    shape: str                  # "sphere", "ellipsoid", "cylinder" or "box"
    size_mm: float              # mm, diameter (sphere, cylinder), short axis (ellipsoid), side (box)
    length_mm: float            # mm, long axis (ellipsoid), length (cylinder), other side (box)
    stiffness_n_per_mm: float   # N/mm, contact stiffness the object offers one unit (inf: rigid)
    fragile: bool               # breaks or dents under a firm grasp
    grasp_force_n: float        # N, typical total grip force
    fingers: int                # fingers in contact, thumb included (2 ... 5)

    def __post_init__(self) -> None:
        if not isinstance(self.name, str) or not self.name:
            raise TypeError(f"name must be a non-empty string, got {self.name!r}")
        if self.shape not in _SHAPES:
            raise InputError(f"shape must be one of {_SHAPES}, got {self.shape!r}")
        for name in ("size_mm", "length_mm", "grasp_force_n"):
            positive(getattr(self, name), name)
        k = self.stiffness_n_per_mm
        if isinstance(k, bool) or not isinstance(k, numbers.Real) or math.isnan(k) or k <= 0:
            raise InputError(f"stiffness_n_per_mm must be a number > 0 (inf: rigid), got {k!r}")
        f = integer(self.fingers, "fingers", minimum=2)
        if f > len(FINGERS):
            raise InputError(f"fingers must be in [2, {len(FINGERS)}], got {f}")

    @property
    def rigid(self) -> bool:
        """True when ``stiffness_n_per_mm >= RIGID_STIFFNESS_N_PER_MM``."""
        return self.stiffness_n_per_mm >= RIGID_STIFFNESS_N_PER_MM


#: The nine objects of the recognition study (rigid and soft).
OBJECTS = (
    GraspObject("sponge", "box", 60.0, 90.0, 0.5, False, 8.0, 5),
    GraspObject("foam ball", "sphere", 60.0, 60.0, 0.8, False, 8.0, 4),
    GraspObject("paper cup", "cylinder", 75.0, 90.0, 1.5, True, 6.0, 5),
    GraspObject("plastic bottle", "cylinder", 65.0, 200.0, 3.0, False, 10.0, 5),
    GraspObject("tennis ball", "sphere", 67.0, 67.0, 6.0, False, 12.0, 4),
    GraspObject("ping-pong ball", "sphere", 40.0, 40.0, 15.0, True, 4.0, 3),
    GraspObject("egg", "ellipsoid", 44.0, 57.0, 300.0, True, 6.0, 3),
    GraspObject("wooden block", "box", 50.0, 50.0, math.inf, False, 12.0, 4),
    GraspObject("steel cylinder", "cylinder", 30.0, 120.0, math.inf, False, 20.0, 5),
)


def _curvature(obj: GraspObject, psi: float) -> np.ndarray:
    """Curvature tensor (2, 2), 1/mm, of the object's surface at the contact, principal axes rotated by psi."""
    if obj.shape == "sphere":
        k1 = k2 = 2.0 / obj.size_mm
    elif obj.shape == "ellipsoid":                 # at the equator of a prolate spheroid, long axis along y
        a, c = obj.size_mm / 2, obj.length_mm / 2
        k1, k2 = 1.0 / a, a / (c * c)
    elif obj.shape == "cylinder":                  # axis across the fingers (x): curved along y
        k1, k2 = 0.0, 2.0 / obj.size_mm
    else:
        k1 = k2 = 0.0
    rot = np.array([[math.cos(psi), -math.sin(psi)], [math.sin(psi), math.cos(psi)]])
    return rot @ np.diag([k1, k2]) @ rot.T


def _solve_depth(c: np.ndarray, w: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Depth d per row with sum_i w_i (d - c_i)^+ = target (rows of c (n, m), weights w (m,) > 0)."""
    order = np.argsort(c, axis=1)
    cs = np.take_along_axis(c, order, axis=1)
    ws = np.take_along_axis(np.broadcast_to(w, c.shape), order, axis=1)
    W, S = np.cumsum(ws, axis=1), np.cumsum(ws * cs, axis=1)
    f_at = np.zeros_like(cs)
    f_at[:, 1:] = W[:, :-1] * cs[:, 1:] - S[:, :-1]
    j = np.sum(f_at <= target[:, None], axis=1) - 1
    rows = np.arange(c.shape[0])
    return (target + S[rows, j]) / W[rows, j]


def _finger_unit_forces(source: Fingertip25, obj: GraspObject, finger_force: np.ndarray, pose: np.ndarray
                        ) -> np.ndarray:
    """Unit normal forces (n, 25) of one fingertip for finger forces (n,) and one contact pose.

    pose = (x0, y0, gx, gy, psi): contact point (mm), surface slope, curvature orientation (rad).
    """
    pos = source.layout.positions_mm.reshape(25, 3)
    nz = source.layout.normals.reshape(25, 3)[:, 2]
    x0, y0, gx, gy, psi = pose
    d = pos[:, :2] - (x0, y0)
    q = 0.5 * np.einsum("ni,ij,nj->n", d, _curvature(obj, psi), d) - d @ (gx, gy)
    c = q - pos[:, 2]                       # depth at which each unit starts to touch
    k_eff = 1.0 / (1.0 / source.config.unit_stiffness_n_per_mm + 1.0 / obj.stiffness_n_per_mm)
    depth = _solve_depth(np.broadcast_to(c, (finger_force.size, 25)), k_eff * nz * nz, finger_force)
    return k_eff * nz * np.clip(depth[:, None] - c, 0.0, None)


def _object(obj) -> GraspObject:
    if isinstance(obj, str):
        for o in OBJECTS:
            if o.name == obj:
                return o
        raise InputError(f"unknown object {obj!r}; valid names: {', '.join(o.name for o in OBJECTS)}")
    if not isinstance(obj, GraspObject):
        raise TypeError(f"obj must be a GraspObject or the name of one of OBJECTS, got {type(obj).__name__}")
    return obj


def grasp(obj, *, seed: int | None = None, force_n: float | None = None, source: Fingertip25 | None = None,
          jitter: float = 1.0, ramp_s: float = 0.4, hold_s: float = 0.6) -> np.ndarray:
    r"""Simulated grasp of ``obj`` by a five-finger hand with one fingertip on each finger: 125 features.

    Parameters
    ----------
    obj : GraspObject or str
        An object, or the name of one of :data:`OBJECTS`.
    seed : int, optional
        Seeds the grasp's variation and the sensor noise.
    force_n : float, optional
        Total grip force, N; by default ``obj.grasp_force_n`` × U(1 − 0.15 j, 1 + 0.15 j).
    source : Fingertip25, optional
        The fingertip of every finger (same config).
    jitter : float
        Scale j of the grasp-to-grasp variation (0: every grasp of an object alike but for sensor noise).
    ramp_s, hold_s : float
        The grip force rises linearly over ``ramp_s`` and is held ``hold_s``.

    Returns
    -------
    ndarray
        (125,): mean decoded unit force (N) over the last third of the hold,
        finger-major (:data:`FINGERS`), each finger's 25 units row-major.

    Notes
    -----
    The thumb carries half the grip force, the other fingers in contact
    share the rest (weights :math:`1 + 0.2 j z`); with probability
    :math:`0.1 j` the outermost finger misses. Each contact has a random
    offset on the fingertip (σ = 1 mm · j), a surface slope (σ = 0.04 j)
    and, for curved objects, an orientation jitter (σ = 10° · j; an egg lies
    either way). Contact: the object's surface above its lowest point is
    :math:`q(d) = \tfrac12 d^\top K d - g\cdot d` (curvature tensor
    :math:`K` from shape and size, :math:`d` the offset from the contact
    point in the fingertip's x, y, :math:`g` the slope); pressed in by
    :math:`\delta`, unit :math:`i` at height :math:`z_i` overlaps by
    :math:`o_i = (\delta - q_i + z_i)^+` and carries
    :math:`f_i = k\,o_i\,n_{z,i}` with :math:`k` the unit's and the
    object's stiffness in series; :math:`\delta` solves
    :math:`\sum_i f_i n_{z,i} = F_{finger}` exactly (piecewise linear). Soft
    objects need a large :math:`\delta` and so wrap onto the tilted planes;
    rigid ones load a few units hard. The unit forces go through
    :meth:`Fingertip25.transduce` (dynamics, noise, threshold, quantisation)
    and are decoded with :func:`force_from_resistance`.
    """
    obj = _object(obj)
    source = fingertip_source(source)
    j = positive(jitter, "jitter", allow_zero=True)
    if force_n is not None:
        force_n = positive(force_n, "force_n", allow_zero=True)
    ramp, hold = positive(ramp_s, "ramp_s"), positive(hold_s, "hold_s")
    return _grasp(obj, np.random.default_rng(seed_value(seed)), force_n, source, j, ramp, hold)[0]


def _grasp(obj: GraspObject, rng: np.random.Generator, force_n: float | None, source: Fingertip25, j: float,
           ramp: float, hold: float) -> tuple[np.ndarray, float]:
    spread = rng.uniform(1.0 - 0.15 * j, 1.0 + 0.15 * j)
    total = obj.grasp_force_n * spread if force_n is None else force_n
    n_fing = obj.fingers - (1 if obj.fingers > 2 and rng.random() < 0.1 * j else 0)
    w = np.clip(1.0 + 0.2 * j * rng.standard_normal(n_fing - 1), 0.3, None)
    share = np.zeros(len(FINGERS))
    share[0] = 0.5
    share[1:n_fing] = 0.5 * w / w.sum()
    rate = source.config.rate_hz
    n_ramp, n_hold = max(1, int(round(ramp * rate))), max(3, int(round(hold * rate)))
    t = np.arange(n_ramp + n_hold) / rate
    profile = np.minimum(np.arange(n_ramp + n_hold) / n_ramp, 1.0)
    forces = np.zeros((t.size, len(FINGERS), 25))
    for k in range(n_fing):
        flip = math.pi / 2 if obj.shape == "ellipsoid" and rng.random() < 0.5 else 0.0
        x0, y0 = rng.normal(0.0, 1.0 * j, size=2)
        gx, gy = rng.normal(0.0, 0.04 * j, size=2)
        psi = flip + rng.normal(0.0, math.radians(10.0) * j)
        forces[:, k] = _finger_unit_forces(source, obj, total * share[k] * profile, (x0, y0, gx, gy, psi))
    r = source.transduce(forces.reshape(t.size, len(FINGERS), 5, 5), t, seed=rng)
    dec = force_from_resistance(r, config=source.config)
    return dec[-max(1, n_hold // 3):].mean(axis=0).reshape(-1), float(total)


def fingertip_source(source) -> Fingertip25:
    """``source``, or ``Fingertip25()`` for None."""
    if source is None:
        return Fingertip25()
    if not isinstance(source, Fingertip25):
        raise TypeError(f"source must be a Fingertip25, got {type(source).__name__}")
    return source


@dataclass(frozen=True, eq=False)
class ObjectDataset:
    """Simulated grasps, one row per grasp.

    Attributes
    ----------
    features : (n, 125) array
        :func:`grasp` features, N.
    label : (n,) int array
        Index into ``names``.
    names : tuple of str
        Object names.
    force_n : (n,) array
        Total grip force of each grasp, N.
    """

    features: np.ndarray
    label: np.ndarray
    names: tuple[str, ...]
    force_n: np.ndarray

    def __post_init__(self) -> None:
        x = finite(real_array(self.features, "features"), "features")
        y = np.asarray(self.label)
        if x.ndim != 2 or y.shape != (x.shape[0],) or np.shape(self.force_n) != y.shape:
            raise ShapeError(f"features must be (n, m), label and force_n (n,), got {x.shape}, {y.shape}, "
                             f"{np.shape(self.force_n)}")
        if y.dtype.kind not in "iu" or (y.size and (y.min() < 0 or y.max() >= len(self.names))):
            raise InputError(f"label must be integers indexing names (0 ... {len(self.names) - 1})")

    def __len__(self) -> int:
        return int(self.label.size)

    def as_dict(self) -> dict[str, np.ndarray]:
        """Table-shaped: ``grasp``, ``label``, ``object``, ``force_n``, ``n_responding``, a column per unit.

        ``n_responding`` counts units whose feature is at least 0.1 N (half the default threshold).
        """
        out = {"grasp": np.arange(len(self)), "label": self.label, "object": np.array(self.names)[self.label],
               "force_n": self.force_n, "n_responding": np.sum(self.features > 0.1, axis=1)}
        for j, finger in enumerate(FINGERS):
            for u in range(25):
                out[f"{finger}_{u}"] = self.features[:, 25 * j + u]
        return out


def object_dataset(*, n_per_object: int, seed: int | None = None, objects=OBJECTS,
                   source: Fingertip25 | None = None, jitter: float = 1.0,
                   progress: bool = False) -> ObjectDataset:
    """Simulated grasps of each object (:func:`grasp`).

    Parameters
    ----------
    n_per_object : int
        Grasps per object.
    seed : int, optional
    objects : sequence of GraspObject
        The classes; :data:`OBJECTS` by default.
    source : Fingertip25, optional
    jitter : float
        Scale of the grasp-to-grasp variation (:func:`grasp`).
    progress : bool
        tqdm progress bar on stderr.

    Returns
    -------
    ObjectDataset
    """
    from tqdm import tqdm

    n = integer(n_per_object, "n_per_object", minimum=2)
    objs = tuple(_object(o) for o in objects)
    if len(objs) < 2 or len({o.name for o in objs}) != len(objs):
        raise InputError(f"objects must be at least 2 objects with distinct names, "
                         f"got {[o.name for o in objs]}")
    source = fingertip_source(source)
    j = positive(jitter, "jitter", allow_zero=True)
    seeds = np.random.SeedSequence(seed_value(seed)).generate_state(n * len(objs))
    label = np.repeat(np.arange(len(objs)), n)
    x = np.empty((label.size, 125))
    force = np.empty(label.size)
    for i in tqdm(range(label.size), desc="fingertip25 grasps", file=sys.stderr, disable=not progress):
        x[i], force[i] = _grasp(objs[label[i]], np.random.default_rng(int(seeds[i])), None, source, j, 0.4, 0.6)
    return ObjectDataset(x, label, tuple(o.name for o in objs), force)


def hidden_units(n_inputs: int, n_outputs: int, *, a: float = 1.0) -> int:
    r"""Empirical hidden-layer size :math:`h = \sqrt{m + n} + a`, rounded; ``a`` is usually in [1, 10].

    Examples
    --------
    >>> hidden_units(125, 9)          # sqrt(134) + 1 = 12.58
    13
    """
    m = integer(n_inputs, "n_inputs", minimum=1)
    n = integer(n_outputs, "n_outputs", minimum=1)
    return int(round(math.sqrt(m + n) + positive(a, "a", allow_zero=True)))


def recognise_objects(dataset: ObjectDataset, *, seed: int | None = 0, test_size: float = 0.3,
                      hidden: int | None = None, solver: str = "lbfgs", alpha: float = 0.1,
                      max_iter: int = 2000) -> dict:
    """Back-propagation network on min–max normalised grasp features: stratified split, accuracy, confusion.

    Parameters
    ----------
    dataset : ObjectDataset
    seed : int, optional
        Seeds the split and the network's initial weights.
    test_size : float
        Test fraction (0.3: the 70/30 split).
    hidden : int, optional
        Hidden tanh units; by default :func:`hidden_units` (13 for 125 inputs and 9 classes).
    solver : {"lbfgs", "adam", "sgd"}
        scikit-learn's optimiser of the back-propagated gradient.
    alpha : float
        L2 weight decay; some is needed with 125 inputs and a few hundred grasps
        (0.1 generalises best on the simulated sets, 1e-4 overfits).
    max_iter : int

    Returns
    -------
    dict
        JSON-serialisable: ``objects``, ``n_train``, ``n_test``, ``hidden``,
        ``chance``, ``accuracy``, ``train_accuracy``, ``confusion`` (rows: true,
        columns: predicted, in ``objects`` order), ``converged``, ``n_iter``.

    Notes
    -----
    Min–max normalisation to [0, 1] is fitted on the training grasps
    (``MinMaxScaler(clip=True)``: test values outside the training range are
    clipped); the network is ``MLPClassifier(hidden_layer_sizes=(h,),
    activation="tanh")`` with a softmax output of one unit per object.
    """
    purpose = "object recognition"
    ConvergenceWarning = require("sklearn.exceptions", purpose=purpose).ConvergenceWarning
    confusion_matrix = require("sklearn.metrics", purpose=purpose).confusion_matrix
    train_test_split = require("sklearn.model_selection", purpose=purpose).train_test_split
    MLPClassifier = require("sklearn.neural_network", purpose=purpose).MLPClassifier
    make_pipeline = require("sklearn.pipeline", purpose=purpose).make_pipeline
    MinMaxScaler = require("sklearn.preprocessing", purpose=purpose).MinMaxScaler
    from threadpoolctl import threadpool_limits       # a scikit-learn dependency

    if not isinstance(dataset, ObjectDataset):
        raise TypeError(f"dataset must be an ObjectDataset, got {type(dataset).__name__}")
    seed = seed_value(seed)
    if isinstance(test_size, bool) or not isinstance(test_size, numbers.Real) or not 0 < test_size < 1:
        raise InputError(f"test_size must be in (0, 1), got {test_size!r}")
    solvers = ("lbfgs", "adam", "sgd")
    if solver not in solvers:
        raise InputError(f"solver must be one of {solvers}, got {solver!r}")
    k = len(dataset.names)
    h = hidden_units(dataset.features.shape[1], k) if hidden is None else integer(hidden, "hidden", minimum=1)
    idx = np.arange(len(dataset))
    tr, te = train_test_split(idx, test_size=test_size, stratify=dataset.label, random_state=seed)
    model = make_pipeline(MinMaxScaler(clip=True),
                          MLPClassifier(hidden_layer_sizes=(h,), activation="tanh", solver=solver,
                                        alpha=positive(alpha, "alpha", allow_zero=True),
                                        max_iter=integer(max_iter, "max_iter", minimum=1), random_state=seed))
    # one BLAS/OpenMP thread: the products are tiny, and threads contending for busy cores cost 30x here
    with warnings.catch_warnings(record=True) as caught, threadpool_limits(limits=1):
        warnings.simplefilter("always", ConvergenceWarning)
        model.fit(dataset.features[tr], dataset.label[tr])
    pred = model.predict(dataset.features[te])
    cm = confusion_matrix(dataset.label[te], pred, labels=np.arange(k))
    return {"objects": list(dataset.names), "n_train": int(tr.size), "n_test": int(te.size), "hidden": h,
            "alpha": float(alpha), "solver": solver,
            "chance": 1.0 / k, "accuracy": float(np.mean(pred == dataset.label[te])),
            "train_accuracy": float(model.score(dataset.features[tr], dataset.label[tr])),
            "confusion": cm.tolist(),
            "converged": not any(issubclass(w.category, ConvergenceWarning) for w in caught),
            "n_iter": int(model[-1].n_iter_)}


def hardness_cues(*, forces_n=(2.0, 5.0, 10.0, 20.0), n_grasps: int = 3, seed: int | None = None,
                  objects=OBJECTS, source: Fingertip25 | None = None) -> dict:
    """How many units respond as the grip force rises, for each object and for rigid versus elastic ones.

    A unit responds when its :func:`grasp` feature is at least half the
    detection threshold (most of its plateau samples are on).

    Returns
    -------
    dict
        JSON-serialisable: ``forces_n``; ``objects``: per object name its
        ``rigid`` flag and ``n_responding`` (mean over ``n_grasps`` per force);
        ``rigid_mean`` and ``elastic_mean`` (mean over the group's objects) and
        each group's least-squares ``*_slope_per_n`` (units per N).
    """
    f = finite(real_array(forces_n, "forces_n"), "forces_n")
    if f.ndim != 1 or f.size < 2 or f.min() < 0:
        raise InputError(f"forces_n must be a 1-D array of at least 2 forces >= 0, got {forces_n!r}")
    n_grasps = integer(n_grasps, "n_grasps", minimum=1)
    objs = tuple(_object(o) for o in objects)
    source = fingertip_source(source)
    seeds = np.random.SeedSequence(seed_value(seed)).generate_state(len(objs) * f.size * n_grasps)
    on = 0.5 * source.config.force_low_n
    out = {"forces_n": f.tolist(), "objects": {}}
    counts = np.empty((len(objs), f.size))
    it = iter(seeds)
    for i, o in enumerate(objs):
        for j, force in enumerate(f):
            feats = [grasp(o, seed=int(next(it)), force_n=float(force), source=source) for _ in range(n_grasps)]
            counts[i, j] = np.mean([np.sum(x >= on) for x in feats])
        out["objects"][o.name] = {"rigid": o.rigid, "n_responding": counts[i].tolist()}
    for key, sel in (("rigid", [o.rigid for o in objs]), ("elastic", [not o.rigid for o in objs])):
        sel = np.asarray(sel)
        mean = counts[sel].mean(axis=0) if sel.any() else np.full(f.size, np.nan)
        out[f"{key}_mean"] = mean.tolist()
        out[f"{key}_slope_per_n"] = float(np.polyfit(f, mean, 1)[0]) if sel.any() else float("nan")
    return out


