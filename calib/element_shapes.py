"""Each element's own curves: corrections to a calibration, shrunk toward it, fitted to presses or totals.

A synthetic (or transferred) calibration describes the elements as designed.
A real sensor's elements differ: one's rubber is a little stiffer, another's
more nonlinear, a third's zero-shear centroid sits off where the design puts
it. This module fits, per element ``e``, seven parameters ``theta_e``
(:data:`PARAMETERS`) on top of a starting calibration's curves::

    Fz_e = (Fz0_e + gradient_e . z_e) m_e,   m_e = exp(log_scale_e + exponent_e l),
    shear_e = (shear0_e - q_e shift_e) m_e exp(log_shear_e),   l = log(max(Fz0, FZ_FLOOR) / SHAPE_REF_N),

``F0`` the starting curves' forces, ``z = s u / u_scale`` the coupled normal
curve's brightness-gradient term (``s = G / g_scale``: an element whose light
falls across it otherwise than the synthetic one's reads another Fz under
shear) and ``q = Fz / (a + b sqrt(Fz))`` the coupled shear curve's slope (N per
mm of centroid; gradient and shifts are for the coupled model only). The scale and
exponent change the *shape* of the normal curve, not only its gain: an element whose rubber
deforms under ``F`` as the
design's under ``s F (Fz / F_ref)^g`` reads ``F0 = s F (Fz / F_ref)^g``, which
a scale ``-log s / (1 + g)`` and an exponent ``-g / (1 + g)`` undo exactly.

Shrinkage
---------
The presses seldom say everything: five presses of an element tell its
scale well and its exponent poorly. The fit is the maximum a posteriori
estimate under a hierarchical prior: each element's parameters scatter
around its ring's (``N(mu_ring, diag(PRIOR_WIDTH^2) / lambda)``) and each
ring's around the start's (``N(0, ...)``), so a ring whose elements all
differ alike is learned from all of them, and an element the presses say
little about keeps its ring's correction. The strength ``lambda`` is chosen
from :data:`STRENGTHS` by K-fold cross-validation over the presses (or
frames): the one whose held-out predictions are best. With few presses a
strong prior wins and the fit stays at the start (today's refinement, or
less); with many a weak one does and each element follows its presses.

Observations
------------
:class:`Observations` are linear in the elements' forces: a gauge press
observes one element's three forces, a force/torque sensor's frame the
wrench of all of them (:mod:`optitact.calib.wrench`). Both are fitted the
same way, together when both exist, each weighted by its standard error
(the measurement's noise and the start's model error).

The held-out predictions of the chosen strength measure the fit's own error:
:func:`fit_shapes` returns them for :class:`~optitact.calib.error_model.ErrorModel`.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np

from optitact._validate import integer
from optitact.errors import InputError

from optitact.calib.curves import FZ_FLOOR
from optitact.calib.fit import MAX_SHAPE, SHAPE_REF_N, Calibration

__all__ = ["FOLDS", "NORMAL", "NP", "PARAMETERS", "SHAPE_PARAMETERS", "PINNED", "PRIOR_WIDTH", "STRENGTHS",
           "Observations", "ShapeFit", "fit_shapes", "gradient_term", "press_observations", "prior_sigma",
           "shaped",
           "shear_elasticity", "shear_slope", "wrench_observations"]

#: The per-element parameters, in the order of :attr:`ShapeFit.theta`.
PARAMETERS = ("log_scale", "exponent", "log_shear", "gradient_x", "gradient_y", "shift_x", "shift_y")
#: Parameters per element.
NP = len(PARAMETERS)
#: The parameters kept in :attr:`Calibration.shape <optitact.calib.fit.Calibration.shape>`; the
#: brightness gradient is added to ``gu`` and the centroid shifts to ``u0`` (coupled model only).
SHAPE_PARAMETERS = 3
#: The prior's width of each parameter at strength 1: a real element's force scale (5 %), its
#: force-law exponent (0.05), its shear scale (5 %), its brightness gradient across the element
#: (0.02 N per unit of ``s u / u_scale``, about a quarter of the largest the synthetic curves fit) and
#: its zero-shear centroid (0.05 mm) off the start's; the cross-validated strengths scale them.
PRIOR_WIDTH = np.array([0.05, 0.05, 0.05, 0.02, 0.02, 0.05, 0.05])
#: The strengths of the prior the cross-validation chooses from (``lambda``, 1 = :data:`PRIOR_WIDTH`).
STRENGTHS = np.geomspace(0.01, 1000.0, 11)
#: The parameters of the normal curve (the rest are the shear's): each group's prior strength is chosen
#: on its own.
NORMAL = np.array([True, True, False, True, True, False, False])
#: Folds of the cross-validation (leave-one-out below this many units).
FOLDS = 5
#: Largest centroid shift (mm).
MAX_SHIFT_MM = 0.5
#: Largest change of an element's brightness gradient (N per unit of ``s u / u_scale``).
MAX_GRADIENT = 0.5
#: An element's parameter is "pinned down" when the fit's posterior standard deviation is below this
#: fraction of the prior's: the observations, not the prior, set it.
PINNED = 0.5


@dataclass(frozen=True)
class Observations:
    """Observations linear in the elements' forces, for :func:`fit_shapes`.

    Attributes
    ----------
    base : (n, 3) ndarray
        The start's curve forces of each *cell* (a frame's element), N,
        before any shape.
    slope : (n,) ndarray
        The start's shear per mm of centroid at each cell (0 for ohka).
    gradient : (n, 2) ndarray
        The brightness-gradient term ``s u / u_scale`` of each cell.
    elasticity : (n,) ndarray
        How the shear curve follows Fz at each cell: ``d log(shear) / d log(Fz)``
        (coupled ``(a + b sqrt(Fz) / 2) / (a + b sqrt(Fz))``; 0 for ohka).
    element : (n,) ndarray of int
        Each cell's element.
    mix : (m, 3 n) scipy.sparse matrix
        Observation ``k`` is ``mix[k] @ F.ravel()`` of the cells' forces.
    value, sigma : (m,) ndarray
        Measured values and the weights' standard errors (the floor of the start's model error and the
        measurement's noise).
    model_var : (m, 6) ndarray
        What an error model's parts give each observation's variance, per unit of each: the floor
        (``sum mix^2``) and the part relative to Fz (``sum mix^2 Fz^2``) of each element-local axis (Fx,
        Fy, Fz) of the cells it reads.
    noise_var : (m,) ndarray
        The measurement's own noise (variance).
    unit : (m,) ndarray of int
        The cross-validation unit of each observation (a press, a frame):
        a unit's observations are held out together.
    stratum : (units,) ndarray of int
        Per unit: units are dealt over the folds within their stratum (the
        pressed element; -1 for frames of many).
    """

    base: np.ndarray
    slope: np.ndarray
    gradient: np.ndarray
    elasticity: np.ndarray
    element: np.ndarray
    mix: object
    value: np.ndarray
    sigma: np.ndarray
    unit: np.ndarray
    stratum: np.ndarray
    model_var: np.ndarray
    noise_var: np.ndarray

    @property
    def n_units(self) -> int:
        """How many cross-validation units (presses, frames) the observations hold."""
        return len(self.stratum)

    @staticmethod
    def concatenate(parts) -> Observations:
        """One set of observations from several (cells, observations and units renumbered)."""
        from scipy.sparse import block_diag

        parts = [p for p in parts if p is not None]
        if len(parts) == 1:
            return parts[0]
        offsets = np.cumsum([0] + [p.n_units for p in parts])[:-1]
        return Observations(np.concatenate([p.base for p in parts]), np.concatenate([p.slope for p in parts]),
                            np.concatenate([p.gradient for p in parts]),
                            np.concatenate([p.elasticity for p in parts]),
                            np.concatenate([p.element for p in parts]),
                            block_diag([p.mix for p in parts], format="csr"),
                            np.concatenate([p.value for p in parts]), np.concatenate([p.sigma for p in parts]),
                            np.concatenate([p.unit + o for p, o in zip(parts, offsets, strict=True)]),
                            np.concatenate([p.stratum for p in parts]),
                            np.concatenate([p.model_var for p in parts]),
                            np.concatenate([p.noise_var for p in parts]))


@dataclass(frozen=True)
class ShapeFit:
    """What :func:`fit_shapes` found.

    Attributes
    ----------
    theta : (E, 7) ndarray
        Each element's parameters (:data:`PARAMETERS`), the start's shape included.
    strength : dict
        The prior's strengths the cross-validation chose: ``normal`` (force
        scale, exponent, brightness gradient) and ``shear`` (shear scale,
        centroid shifts).
    scores : dict
        Held-out weighted mean square per pair of strengths tried (``"normal,shear"``).
    held_out : (n, 3) ndarray
        Each cell's forces predicted by the fit without its fold, at the chosen strength.
    held_out_obs : (m,) ndarray
        Each observation's predicted value without its fold.
    pinned : (E, 7) bool ndarray
        Which parameters the observations pinned down (:data:`PINNED`).
    """

    theta: np.ndarray
    strength: dict
    scores: dict
    held_out: np.ndarray
    held_out_obs: np.ndarray
    pinned: np.ndarray


def _cell_forces(obs: Observations, theta: np.ndarray):
    """Forces of every cell under ``theta`` (n, 3), with what the Jacobian needs.

    A change of the normal curve (the gradient) moves the coupled shear curve with it, by ``kappa dFz /
    Fz`` (``kappa`` its logarithmic slope in Fz, :attr:`Observations.elasticity`).
    """
    th = theta[obs.element]
    f0 = obs.base
    ell = np.log(np.maximum(f0[:, 2], FZ_FLOOR) / SHAPE_REF_N)
    m = np.exp(th[:, 0] + th[:, 1] * ell)
    ms = m * np.exp(th[:, 2])
    dfz = np.sum(obs.gradient * th[:, 3:5], axis=1)
    ratio = 1.0 + obs.elasticity * dfz / np.maximum(f0[:, 2], FZ_FLOOR)
    raw = f0[:, :2] - obs.slope[:, None] * th[:, 5:7]
    shear = raw * (ratio * ms)[:, None]
    fz = (f0[:, 2] + dfz) * m
    return np.concatenate([shear, fz[:, None]], axis=1), ell, (m, ms, ratio, raw, f0)


def _cell_jacobian(obs: Observations, f: np.ndarray, ell: np.ndarray, parts, n_el: int, n_par: int):
    """d(cell forces, raveled)/d(theta, raveled) as a sparse (3 n, NP E) matrix (first ``n_par`` parameters)."""
    from scipy.sparse import coo_matrix

    m, ms, ratio, raw, f0 = parts
    n = len(f)
    rows3 = 3 * np.arange(n)
    col = NP * obs.element
    r, c, v = [], [], []
    for ax in range(3):  # log_scale and exponent: every axis
        r += [rows3 + ax] * 2
        c += [col, col + 1]
        v += [f[:, ax], f[:, ax] * ell]
    for ax in range(2):  # log_shear: the shear
        r.append(rows3 + ax)
        c.append(col + 2)
        v.append(f[:, ax])
    if n_par > SHAPE_PARAMETERS:  # the brightness gradient: Fz (and the shear with it); the shifts: the shear
        lever = obs.elasticity / np.maximum(f0[:, 2], FZ_FLOOR) * ms
        for k in range(2):
            r += [rows3 + 2, rows3, rows3 + 1, rows3 + k]
            c += [col + 3 + k, col + 3 + k, col + 3 + k, col + 5 + k]
            v += [obs.gradient[:, k] * m, raw[:, 0] * lever * obs.gradient[:, k],
                  raw[:, 1] * lever * obs.gradient[:, k], -obs.slope * ms * ratio]
    jac = coo_matrix((np.concatenate(v), (np.concatenate(r), np.concatenate(c))), shape=(3 * n, NP * n_el))
    return jac.tocsr()


def _solve(obs: Observations, rows: np.ndarray, ring: np.ndarray, theta0: np.ndarray, strength: float,
           n_par: int, x0=None):
    """MAP parameters (E, NP) from the observations ``rows``, by Gauss-Newton on the sparse normal equations.

    Unknowns: the free parameters of every element and the rings' means. Returns the parameters, the
    unknowns (to warm-start the next solve), the normal matrix at the solution (for the posterior) and
    the indices of the free parameters.
    """
    from scipy.linalg import cho_factor, cho_solve
    from scipy.sparse import csr_matrix, hstack, vstack, diags

    n_el, n_ring = len(ring), int(ring.max()) + 1
    free = np.zeros((n_el, NP), bool)
    free[:, :n_par] = True
    free_th = np.flatnonzero(free.ravel())
    free_mu = np.flatnonzero(np.tile(np.arange(NP) < n_par, n_ring))
    n_th, n_mu = free_th.size, free_mu.size
    mix = obs.mix[rows]
    w = 1.0 / obs.sigma[rows]
    value = obs.value[rows]
    lam = np.broadcast_to(np.asarray(strength, dtype=np.float64), (NP,))
    tau = (np.tile(PRIOR_WIDTH / np.sqrt(lam), n_el))[free_th]
    tau_r = np.tile(PRIOR_WIDTH / np.sqrt(lam), n_ring)[free_mu]
    ring_of = (NP * ring[:, None] + np.arange(NP)).ravel()[free_th]  # each parameter's ring mean
    mu_col = np.searchsorted(free_mu, ring_of)
    # the prior's residuals are linear: P x - P x0, with x = (theta_free, mu)
    prior = vstack([hstack([diags(1.0 / tau), csr_matrix((-1.0 / tau, (np.arange(n_th), mu_col)),
                                                          shape=(n_th, n_mu))]),
                    hstack([csr_matrix((n_mu, n_th)), diags(1.0 / tau_r)])]).tocsr()
    centre = np.concatenate([theta0.ravel()[free_th], np.zeros(n_mu)])
    ptp = (prior.T @ prior).toarray()
    lim = np.array([0.95 * MAX_SHAPE] * SHAPE_PARAMETERS + [MAX_GRADIENT] * 2 + [MAX_SHIFT_MM] * 2)
    hi = np.concatenate([np.tile(lim, n_el)[free_th], np.full(n_mu, np.inf)])

    def theta_of(x):
        th = theta0.ravel().copy()
        th[free_th] = x[:n_th]
        return th.reshape(n_el, NP)

    def state(x):
        f, ell, parts = _cell_forces(obs, theta_of(x))
        r = (mix @ f.ravel() - value) * w
        d = prior @ (x - centre)
        return f, ell, parts, r, float(r @ r + d @ d)

    x = np.clip(centre if x0 is None else x0, -hi, hi)
    f, ell, parts, r, cost = state(x)
    for _ in range(30):
        jd = (diags(w) @ mix @ _cell_jacobian(obs, f, ell, parts, n_el, n_par))[:, free_th]
        a = ptp.copy()
        a[:n_th, :n_th] += (jd.T @ jd).toarray()
        g = np.concatenate([jd.T @ r, np.zeros(n_mu)]) + ptp @ (x - centre)
        step = -cho_solve(cho_factor(a), g)
        for _ in range(20):  # halve a step that does not lower the cost
            x_new = np.clip(x + step, -hi, hi)
            f_n, ell_n, parts_n, r_n, cost_n = state(x_new)
            if cost_n <= cost:
                break
            step = step / 2
        else:
            break
        done = cost - cost_n <= 1e-10 * max(cost, 1e-300)
        x, f, ell, parts, r, cost = x_new, f_n, ell_n, parts_n, r_n, cost_n
        if done or np.max(np.abs(step)) < 1e-9:
            break
    jd = (diags(w) @ mix @ _cell_jacobian(obs, f, ell, parts, n_el, n_par))[:, free_th]
    a = ptp.copy()
    a[:n_th, :n_th] += (jd.T @ jd).toarray()
    return theta_of(x), x, a, free_th


def _folds(obs: Observations, seed) -> np.ndarray:
    """Each unit's fold: within each stratum dealt round-robin over a seeded permutation."""
    rng = np.random.default_rng(seed)
    fold = np.zeros(obs.n_units, np.int64)
    for s in np.unique(obs.stratum):
        idx = rng.permutation(np.flatnonzero(obs.stratum == s))
        fold[idx] = np.arange(idx.size) % FOLDS
    return fold


def fit_shapes(start: Calibration, obs: Observations, *, seed: int = 0, strengths=None) -> ShapeFit:
    """Each element's shape on top of ``start``, shrunk toward it, the strengths cross-validated.

    K-fold over the observations' units (:data:`FOLDS`, seeded): first one strength for every
    parameter, from ``strengths``; then the normal curve's (:data:`NORMAL`) and the shear's in turn,
    each the best of ``strengths`` with the other held.

    Parameters
    ----------
    start : Calibration
        The curves (their shape, if any, is the prior's centre).
    obs : Observations
        Presses, force/torque frames, or both (:meth:`Observations.concatenate`).
    seed : int
        Of the folds.
    strengths : sequence of float, optional
        The prior's strengths to choose from (default :data:`STRENGTHS`).

    Returns
    -------
    ShapeFit

    Raises
    ------
    InputError
        Fewer than two cross-validation units.
    """
    from threadpoolctl import threadpool_limits

    with threadpool_limits(limits=1):  # hundreds of small dense solves: one BLAS thread is fastest
        return _fit_shapes(start, obs, integer(seed, "seed", minimum=0), strengths)


def _fit_shapes(start: Calibration, obs: Observations, seed: int, strengths) -> ShapeFit:
    grid = STRENGTHS if strengths is None else np.asarray(strengths, dtype=np.float64)
    if obs.n_units < 2:
        raise InputError(f"an element shape fit needs at least 2 presses or frames, got {obs.n_units}")
    n_el = len(start.g)
    ring = np.asarray(start.sensor.element_ring)
    n_par = NP if start.model == "coupled" else SHAPE_PARAMETERS
    theta0 = np.zeros((n_el, NP))
    if start.shape is not None:
        theta0[:, :SHAPE_PARAMETERS] = start.shape
    unit_fold = _folds(obs, seed)
    fold = unit_fold[obs.unit]
    n_fold = int(fold.max()) + 1
    cell_unit = np.zeros(len(obs.base), np.int64)  # each cell's unit (the first observation that reads it)
    coo = obs.mix.tocoo()
    cell_unit[coo.col // 3] = obs.unit[coo.row]
    cell_fold = unit_fold[cell_unit]
    scores, preds = {}, {}

    def score(lam: np.ndarray) -> float:
        key = tuple(float(v) for v in lam[[0, 2]])
        if key in scores:
            return scores[key]
        pred_obs = np.zeros(len(obs.value))
        pred_cell = np.zeros_like(obs.base)
        for k in range(n_fold):
            train = np.flatnonzero(fold != k)
            th, _, _, _ = _solve(obs, train, ring, theta0, lam, n_par)
            f, _, _ = _cell_forces(obs, th)
            test = fold == k
            pred_obs[test] = obs.mix[np.flatnonzero(test)] @ f.ravel()
            pred_cell[cell_fold == k] = f[cell_fold == k]
        scores[key] = float(np.mean(((pred_obs - obs.value) / obs.sigma) ** 2))
        preds[key] = (pred_obs, pred_cell)
        return scores[key]

    # one strength for all, then the normal curve's and the shear's in turn (coordinate search on the grid)
    best = min((np.full(NP, lam) for lam in grid), key=score)
    for group in (NORMAL, ~NORMAL):
        best = min((np.where(group, lam, best) for lam in grid), key=score)
    key = tuple(float(v) for v in best[[0, 2]])
    theta, _, normal, free_th = _solve(obs, np.arange(len(obs.value)), ring, theta0, best, n_par)
    # posterior standard deviations of the elements' parameters (Gauss-Newton), against the prior's
    try:
        cov = np.linalg.pinv(normal)
        post = np.full(NP * n_el, np.inf)
        post[free_th] = np.sqrt(np.maximum(np.diag(cov)[:free_th.size], 0.0))
    except np.linalg.LinAlgError:  # pragma: no cover - pinv of a finite matrix converges
        post = np.full(NP * n_el, np.inf)
    prior_sd = np.tile(PRIOR_WIDTH / np.sqrt(best), n_el)
    pinned = (post < PINNED * prior_sd).reshape(n_el, NP)
    pinned[:, n_par:] = False
    return ShapeFit(theta, {"normal": key[0], "shear": key[1]},
                    {f"{a:g},{b:g}": v for (a, b), v in scores.items()}, preds[key][1], preds[key][0], pinned)


def shaped(start: Calibration, theta: np.ndarray, **fields) -> Calibration:
    """``start`` with the elements' parameters ``theta`` (E, NP): the shape; the gradient added to ``gu``.

    The centroid shifts go to ``u0``; other fields (e.g. ``sensor``) are replaced by ``fields``.
    """
    theta = np.asarray(theta, dtype=np.float64)
    shape = theta[:, :SHAPE_PARAMETERS]
    u0, gu = start.u0, start.gu
    if start.model == "coupled" and np.any(theta[:, 5:7]):
        u0 = np.zeros((len(theta), 2, 2)) if u0 is None else np.array(u0, dtype=np.float64)
        u0[:, 0, :] += theta[:, 5:7]
    if start.model == "coupled" and np.any(theta[:, 3:5]):
        gu = np.asarray(gu, dtype=np.float64) + theta[:, 3:5]
    return replace(start, shape=shape if np.any(shape) else None, u0=u0, gu=gu, **fields)


def prior_sigma(cal: Calibration, est, *, floor_only: bool = False) -> np.ndarray:
    """The calibration's expected error (..., E, 3) N at its estimates ``est`` (..., E, 3).

    Its :class:`~optitact.calib.error_model.ErrorModel` where it has one, else its fit residuals
    (:meth:`Calibration.model_error <optitact.calib.fit.Calibration.model_error>`). ``floor_only``:
    the error model's part that does not grow with the load (what weighs the observations: the parts
    that grow with it are what a shape fit removes, and weighing by them would fit relative errors,
    not the forces).
    """
    est = np.asarray(est, dtype=np.float64)
    if cal.error_model is not None:
        if floor_only:
            return cal.error_model.at(np.zeros_like(est))
    return np.broadcast_to(cal.model_error(), est.shape).copy()


def press_observations(start: Calibration, readings, forces, t_idx, e_idx, noise) -> Observations:
    """Gauge presses as :class:`Observations`: each press observes its element's three forces.

    Parameters
    ----------
    start : Calibration
        Its curves (without their shape) give the cells' base forces, its
        error model (:func:`prior_sigma`) their expected error.
    readings : Readings
        ``(T, E)`` readings of the frames.
    forces : (T, E, 3) ndarray
        The gauge's element-local forces.
    t_idx, e_idx : (n,) ndarray of int
        The presses (frame and element).
    noise : (n, 3) ndarray
        The gauge's noise per press and axis (N).
    """
    from scipy.sparse import identity

    base_cal = replace(start, shape=None)
    full = base_cal.forces(readings)[0]
    est = full[t_idx, e_idx]
    floor = prior_sigma(start, full, floor_only=True)[t_idx, e_idx] ** 2
    n = len(t_idx)
    by_axis = np.zeros((3 * n, 6))
    axis = np.tile(np.arange(3), n)
    by_axis[np.arange(3 * n), axis] = 1.0
    by_axis[np.arange(3 * n), 3 + axis] = np.repeat(est[:, 2], 3) ** 2
    sigma = np.sqrt(floor + np.asarray(noise, dtype=np.float64) ** 2 + 1e-12)
    return Observations(est, shear_slope(start, est[:, 2], e_idx), gradient_term(start, readings, t_idx, e_idx),
                        shear_elasticity(start, est[:, 2], e_idx), np.asarray(e_idx),
                        identity(3 * n, format="csr"), np.asarray(forces)[t_idx, e_idx].ravel(),
                        sigma.ravel(), np.repeat(np.arange(n), 3), np.asarray(e_idx), by_axis,
                        (np.asarray(noise, dtype=np.float64) ** 2).ravel())


def shear_slope(cal: Calibration, fz, e_idx) -> np.ndarray:
    """The coupled shear curve's slope ``Fz / (a + b sqrt(Fz))`` (N/mm) of elements ``e_idx`` (0: ohka)."""
    fz = np.maximum(np.asarray(fz, dtype=np.float64), 0.0)
    if cal.model != "coupled":
        return np.zeros_like(fz)
    return fz / (cal.f[e_idx, 0] + cal.f[e_idx, 1] * np.sqrt(fz))


def wrench_observations(start: Calibration, readings, wrench, matrix, noise) -> Observations:
    """A force/torque sensor's frames as :class:`Observations`: each observes the wrench of all its elements.

    Parameters
    ----------
    start : Calibration
    readings : Readings
        ``(T, E)`` readings of the frames that have a measured wrench.
    wrench : (T, 6) ndarray
        The measured wrenches (N and N m, the F/T sensor's frame and origin).
    matrix : (E, 3, 6) ndarray
        Element-local forces to the wrench (:func:`optitact.calib.wrench.wrench_matrix`):
        ``W_t = sum_e F_te @ matrix[e]``.
    noise : (T, 6) ndarray
        The F/T sensor's noise per component. The standard errors add the
        start's expected error of every loaded element, carried into the
        wrench.
    """
    from scipy.sparse import coo_matrix

    base_cal = replace(start, shape=None)
    est = base_cal.forces(readings)[0]
    t_idx, e_idx = np.nonzero(readings.contact)
    n = len(t_idx)
    mat = np.asarray(matrix, dtype=np.float64)
    rows = (6 * t_idx[:, None, None] + np.arange(6)[None, None, :]).repeat(3, axis=1)  # (n, 3, 6)
    cols = (3 * np.arange(n)[:, None, None] + np.arange(3)[None, :, None]).repeat(6, axis=2)
    mix = coo_matrix((mat[e_idx].ravel(), (rows.ravel(), cols.ravel())), shape=(6 * len(wrench), 3 * n)).tocsr()
    base = est[t_idx, e_idx]
    sq = mix.multiply(mix)
    fz2 = np.repeat(base_fz2 := est[t_idx, e_idx, 2] ** 2, 3).reshape(-1, 3)
    axis_of = [np.where(np.arange(3) == a, 1.0, 0.0)[None, :] for a in range(3)]
    model = np.stack([sq @ np.repeat(x, n, axis=0).ravel() for x in axis_of]
                     + [sq @ (x * fz2).ravel() for x in axis_of], axis=1)
    del base_fz2
    floor = sq @ (prior_sigma(start, est, floor_only=True)[t_idx, e_idx] ** 2).ravel()
    sigma = np.sqrt(floor + np.asarray(noise, dtype=np.float64).ravel() ** 2 + 1e-12)
    return Observations(base, shear_slope(start, base[:, 2], e_idx),
                        gradient_term(start, readings, t_idx, e_idx),
                        shear_elasticity(start, base[:, 2], e_idx), e_idx, mix,
                        np.asarray(wrench, dtype=np.float64).ravel(), sigma,
                        np.repeat(np.arange(len(wrench)), 6), np.full(len(wrench), -1), model,
                        np.asarray(noise, dtype=np.float64).ravel() ** 2)


def gradient_term(cal: Calibration, readings, t_idx, e_idx) -> np.ndarray:
    """The coupled normal curve's brightness-gradient term ``s u / u_scale`` (n, 2) of the samples (0: ohka)."""
    n = len(t_idx)
    if cal.model != "coupled":
        return np.zeros((n, 2))
    u = cal.clamped_shift(readings.u)[0][t_idx, e_idx]
    s = readings.G[t_idx, e_idx] / cal.g_scale[e_idx]
    return s[:, None] * u / cal.u_scale[e_idx, None]


def shear_elasticity(cal: Calibration, fz, e_idx) -> np.ndarray:
    """``d log(shear) / d log(Fz)`` of the coupled shear curve (0 for ohka).

    ``(a + b sqrt(Fz) / 2) / (a + b sqrt(Fz))`` of elements ``e_idx`` at ``fz``.
    """
    fz = np.maximum(np.asarray(fz, dtype=np.float64), 0.0)
    if cal.model != "coupled":
        return np.zeros_like(fz)
    a, b = cal.f[e_idx, 0], cal.f[e_idx, 1] * np.sqrt(fz)
    return (a + b / 2) / (a + b)

