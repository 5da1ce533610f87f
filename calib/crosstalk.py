"""Cross-talk between elements: the joint inversion of all elements' normal forces in a frame.

Light one contact patch takes out of the waveguide does not reach the others,
and light it scatters feeds its neighbours, so an element's integrated grey
value depends on what the other elements carry. To first order the effect is
multiplicative and linear in the other patches' contact area, which the
contact model makes proportional to their normal load (Sneddon: ``A = 2 P
tan(alpha) / E*``):

    ln G_e = ln G_iso,e(F_e, u_e) - sum_{j != e} W_ej Fz_j

``G_iso`` is what the element would read alone, the per-element curves of a
:class:`~optitact.calib.fit.Calibration` map it to force, and ``W`` has the
structure of the light transport: ``W_ej = K[r(e), r(j)] + K_near[r(e)]
exp(-d_ej / NEAR_MM)``, a coupling per pair of rings (the guided light from
the rim passes ring by ring) and a near-field term that falls with the
geodesic distance ``d_ej`` between the elements (light scattered to the
neighbours), ``R (R + 1)`` coefficients for ``R`` rings.

Fitting (:func:`fit_crosstalk`) alternates two linear least-squares steps on
a calibration set (known forces in every frame): the per-element curves on
``G exp(W Fz)``, then the coefficients on ``ln G_iso - ln G`` with ``G_iso``
the fitted curves inverted at the known force. The set must vary what the
neighbours carry (the ``blend`` design of :mod:`optitact.calib.patterns`;
with independent random loads on every element the neighbours' sum barely
varies, and the coupling is not identifiable).

Applying (:meth:`CrossTalk.solve`): from the per-element estimate ``Fz0``,
fixed-point steps ``Fz <- g(G exp(W Fz), u)`` (a contraction: the coupling
is a few per cent of the signal per newton) until no force moves by more
than ``TOLERANCE_N`` (at most ``ITERATIONS``).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from optitact.errors import InputError
from optitact.optics.sensor import DomeSensor

__all__ = ["CrossTalk", "fit_crosstalk", "NEAR_MM", "ITERATIONS"]

#: Length scale (mm, geodesic) of the near-field coupling between neighbouring elements.
NEAR_MM = 6.0
#: Most fixed-point steps of the joint inversion per frame, and the step (N) at which it stops.
ITERATIONS = 30
TOLERANCE_N = 1e-10
#: Alternations of the fit (curves, coupling) before the joint Gauss-Newton refinement.
FIT_ROUNDS = 3


@dataclass(frozen=True, eq=False)
class CrossTalk:
    """The coupling ``W`` (E, E) of the joint inversion (see the module docstring).

    Attributes
    ----------
    coefficients : (R, R + 1) ndarray
        ``K[r, s]`` (1/N): the change of ``-ln G`` of an element of ring
        ``r`` per newton on another element of ring ``s``; last column: the
        near-field coefficient ``K_near[r]`` per newton at zero distance.
    near_mm : float
        Length scale of the near-field term (mm).
    """

    coefficients: np.ndarray
    near_mm: float = NEAR_MM
    _cache: dict = field(default_factory=dict, repr=False, compare=False)

    def matrix(self, sensor: DomeSensor) -> np.ndarray:
        """``W`` (E, E) for ``sensor``'s elements (zero diagonal)."""
        if self._cache.get("sensor") is not sensor:  # the last sensor's matrix (every frame asks again)
            ring = sensor.element_ring
            n_rings = len(sensor.ring_counts)
            k = np.asarray(self.coefficients, dtype=np.float64)
            if k.shape != (n_rings, n_rings + 1):
                raise InputError(f"cross-talk coefficients must have shape {(n_rings, n_rings + 1)} for a "
                                 f"sensor of {n_rings} rings, got {k.shape}")
            w = k[ring][:, ring] + k[ring, n_rings][:, None] * np.exp(-_geodesic(sensor) / self.near_mm)
            np.fill_diagonal(w, 0.0)
            self._cache.update(sensor=sensor, matrix=w)
        return self._cache["matrix"]

    def to_dict(self) -> dict:
        """JSON-friendly parameters."""
        return {"coefficients": np.asarray(self.coefficients).tolist(), "near_mm": float(self.near_mm)}

    @classmethod
    def from_dict(cls, d) -> CrossTalk:
        """From :meth:`to_dict` output; InputError on a malformed one."""
        if not isinstance(d, dict) or "coefficients" not in d:
            raise InputError(f"cross-talk must be an object with 'coefficients', got {d!r:.80}")
        try:
            k = np.asarray(d["coefficients"], dtype=np.float64)
            near = float(d.get("near_mm", NEAR_MM))
        except (TypeError, ValueError) as exc:
            raise InputError(f"cross-talk coefficients must be numbers ({exc})") from None
        if k.ndim != 2 or k.shape[1] != k.shape[0] + 1 or not np.isfinite(k).all():
            raise InputError(f"cross-talk coefficients must be a finite (R, R + 1) array, got shape {k.shape}")
        if not (np.isfinite(near) and near > 0):
            raise InputError(f"cross-talk near_mm must be a positive length, got {near}")
        return cls(k, near)

    def solve(self, sensor: DomeSensor, G: np.ndarray, contact: np.ndarray, normal, *,
              iterations: int = ITERATIONS) -> np.ndarray:
        """Joint inversion: the isolated grey values ``G_iso = G exp(W Fz)`` of all elements together.

        Parameters
        ----------
        sensor : DomeSensor
        G : (E,) or (T, E) ndarray
            Measured integrated grey values.
        contact : bool array of the shape of ``G``
            Elements in contact (the others carry no load).
        normal : callable
            ``normal(G) -> Fz`` (the shape of ``G``): the per-element normal
            curves (the shear follows from the result once).

        Returns
        -------
        ndarray
            ``G_iso``, at which the per-element curves give every force.
        """
        w = self.matrix(sensor)
        fz = np.where(contact, normal(G), 0.0)
        g_iso = G
        for _ in range(iterations):
            g_iso = G * np.exp(fz @ w.T)
            new = np.where(contact, normal(g_iso), 0.0)
            step = float(np.max(np.abs(new - fz), initial=0.0))
            fz = new
            if step <= TOLERANCE_N:
                break
        return G * np.exp(fz @ w.T)


def _geodesic(sensor: DomeSensor) -> np.ndarray:
    n = sensor.element_frames[:, 2, :]
    return sensor.outer_radius * np.arccos(np.clip(n @ n.T, -1.0, 1.0))


def _design(sensor: DomeSensor, fz: np.ndarray, near_mm: float) -> np.ndarray:
    """Columns (T, E, R + 1): each element's neighbours' normal load per ring, and the near-field sum."""
    ring = sensor.element_ring
    n_rings = len(sensor.ring_counts)
    onehot = np.eye(n_rings)[ring]  # (E, R)
    per_ring = fz @ onehot  # (T, R): load per ring
    own = fz[..., None] * onehot[None]  # (T, E, R): the element's own load in its ring
    near = np.exp(-_geodesic(sensor) / near_mm)
    np.fill_diagonal(near, 0.0)
    return np.concatenate([per_ring[:, None, :] - own, (fz @ near.T)[..., None]], axis=-1)


def fit_crosstalk(readings, forces: np.ndarray, sensor: DomeSensor, fit_curves, invert,
                  *, near_mm: float = NEAR_MM, rounds: int = FIT_ROUNDS):
    """Fit the coupling and the per-element curves together (see the module docstring).

    Parameters
    ----------
    readings : Readings
        Stack readings of a calibration set.
    forces : (T, E, 3) ndarray
        The known element-local forces.
    sensor : DomeSensor
    fit_curves : callable
        ``fit_curves(G) -> calibration`` fits the per-element curves to the
        readings with ``G`` in place of theirs.
    invert : callable
        ``invert(calibration, fz, u) -> G``: the grey value the curves give
        force ``fz`` at shift ``u`` (where defined; NaN elsewhere).

    Returns
    -------
    (CrossTalk, calibration, info)
        ``info``: ``rms_log_before`` / ``rms_log_after``, the RMS of
        ``ln G_iso - ln G`` before and after the coupling is removed.
    """
    fz = forces[..., 2]
    ok = readings.contact & ~readings.saturated & (readings.G > 0) & (fz > 0)
    if ok.sum() < 10 * (len(sensor.ring_counts) + 1) * len(sensor.ring_counts):
        raise InputError("too few loaded samples to fit the cross-talk between elements")
    x = _design(sensor, fz, near_mm)  # (T, E, R + 1)
    ring = sensor.element_ring
    n_rings = len(sensor.ring_counts)
    k = np.zeros((n_rings, n_rings + 1))
    ct = CrossTalk(k, near_mm)
    cal = fit_curves(readings.G)
    info = {}
    for i in range(rounds):
        g_iso = invert(cal, fz, readings.u)
        y = np.log(np.where(ok, g_iso, 1.0)) - np.log(np.where(ok, readings.G, 1.0))
        good = ok & np.isfinite(y)
        if i == 0:
            info["rms_log_before"] = float(np.sqrt(np.mean(y[good] ** 2)))
        for r in range(n_rings):
            m = good & (ring == r)[None, :]
            a, b = x[m], y[m]
            # a little ridge: rings whose neighbours' loads hardly vary keep small coefficients
            reg = 1e-6 * len(b) * np.eye(n_rings + 1)
            k[r] = np.linalg.solve(a.T @ a + reg, a.T @ b)
        ct = CrossTalk(k.copy(), near_mm)
        corrected = readings.G * np.exp(fz @ ct.matrix(sensor).T)
        cal = fit_curves(np.where(readings.contact, corrected, readings.G))
    # The alternation converges slowly where the neighbours' loads follow the element's own (a flat
    # plate, an indenter): finish with Gauss-Newton on every normal curve and the coupling at once.
    k, ok_fit = _refine(cal, ct, readings, forces, sensor)
    ct = CrossTalk(k, near_mm)
    cal = fit_curves(np.where(readings.contact, readings.G * np.exp(fz @ ct.matrix(sensor).T), readings.G))
    g_iso = invert(cal, fz, readings.u)
    y = np.log(np.where(ok, g_iso, 1.0)) - np.log(np.where(ok, readings.G, 1.0))
    good = ok & np.isfinite(y)
    fitted = np.einsum("tek,ek->te", x, k[ring])
    info["rms_log_after"] = float(np.sqrt(np.mean((y[good] - fitted[good]) ** 2)))
    info["refinement_converged"] = bool(ok_fit)
    return ct, cal, info


def _refine(cal, ct: CrossTalk, readings, forces: np.ndarray, sensor: DomeSensor):
    """The coupling ``K`` by least squares in force, every element's normal curve profiled out.

    ``Fz = g(s') + s' (gu . t)`` with ``s' = G exp(W Fz_true) / g_scale`` is linear in each element's
    curve (``g``, ``gu``): for a trial ``K`` those are solved exactly (variable projection), and ``K``
    (its identifiable entries: a ring's coupling to loads that never vary, such as the apex's to its own
    ring, and a near field that repeats the rings' loads, stay 0) follows by Gauss-Newton on what is left.
    """
    from scipy.optimize import least_squares

    fz = forces[..., 2]
    ok = readings.contact & ~readings.saturated & (readings.G > 0) & (fz > 0)
    t_idx, e_idx = np.nonzero(ok)
    x = _design(sensor, fz, ct.near_mm)[t_idx, e_idx]  # (n, R + 1)
    ring = sensor.element_ring[e_idx]
    n_rings = len(sensor.ring_counts)
    g0 = readings.G[t_idx, e_idx] / cal.g_scale[e_idx]
    tt = (cal.clamped_shift(readings.u)[0] / cal.u_scale[:, None])[t_idx, e_idx]  # (n, 2)
    target = fz[t_idx, e_idx]
    coupled = bool(np.any(cal.gu))
    free = np.zeros((n_rings, n_rings + 1), bool)
    for r in range(n_rings):
        m = ring == r
        if not m.any():
            continue
        free[r] = np.ptp(x[m], axis=0) > 0
        if np.linalg.matrix_rank(x[m][:, free[r]]) < free[r].sum():
            free[r, -1] = False  # the near field is the rings' loads again (the apex: every ring equidistant)
    order = np.argsort(e_idx, kind="stable")
    bounds = np.searchsorted(e_idx[order], np.arange(sensor.n_elements + 1))

    def fun(p):
        k = np.zeros((n_rings, n_rings + 1))
        k[free] = p
        s = g0 * np.exp(np.sum(x * k[ring], axis=1))
        cols = [np.ones_like(s), s, s**2, s**3] + ([s * tt[:, 0], s * tt[:, 1]] if coupled else [])
        a = np.stack(cols, axis=1)
        res = np.empty_like(s)
        for e in range(sensor.n_elements):
            idx = order[bounds[e]:bounds[e + 1]]
            if idx.size:
                coef, *_ = np.linalg.lstsq(a[idx], target[idx], rcond=None)
                res[idx] = a[idx] @ coef - target[idx]
        return res

    sol = least_squares(fun, ct.coefficients[free], method="lm", xtol=1e-14, ftol=1e-14)
    k = np.zeros((n_rings, n_rings + 1))
    k[free] = sol.x
    return k, sol.status > 0
