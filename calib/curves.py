"""The curve models of a calibration, and the least-squares fit of one element's curves.

Models
------
``"ohka"`` -- the sensor's published form, per element ``i``::

    Fz = g_i(G),   Fx = f_i(ux),   Fy = f_i(uy)

``"coupled"`` -- the shear curve depends on the normal load, and the normal
curve on where the light comes from::

    Fz = g_i(G) + s (p_i . u / u_scale),   (Fx, Fy) = (ux, uy) * Fz / (a_i + b_i sqrt(Fz))

with ``s = G / G_scale``. The second term is the brightness gradient across
the element: the dome is lit from its rim, so a cone nearer the rim gives a
brighter spot for the same load, and a tilted feeler (which moves load, and
the centroid, towards one side) changes G at equal Fz -- by up to +-10 % on
the 45-degree ring of the default sensor.

Why the coupled form: the columnar feeler is rigid, so moment balance on the
cones gives ``sum_k P_k r_k = h F_t`` (``h`` the lever arm), and a cone's
contact area, hence its grey value, is proportional to its load (Sneddon,
``A = 2 P tan(alpha) / E*``); the grey-value centroid of the tilted feeler
is therefore ``sum P_k r_k / sum P_k = h F_t / F_z``. The patches also slide
by ``F_t / sum k_k`` with Mindlin stiffness ``k = 8 G* a`` and ``a ~ sqrt(P)``,
i.e. by about ``c F_t / sqrt(F_z)``. Together ``u = F_t (h / F_z + c /
sqrt(F_z))``, which inverts to the form above with ``a ~ h`` and ``b ~ c``.
A curve ``f(u)`` alone cannot represent this: the same shift means twice the
shear at twice the normal load.

Both models use ``g_i(G) = c0 + c1 s + c2 s^2 + c3 s^3`` (``s = G / G_scale``)
with all ``c >= 0``, so g increases with G; ``f_i(u) = d1 t + d3 t^3``
(``t = u / u_scale``), ``d >= 0``, odd and increasing; ``a, b >= 0``. Fits are
bounded linear or non-linear least squares (SciPy) on scaled inputs.
Outside the fitted range readings are flagged: a shift beyond the largest
fitted one is clamped to it, and above the largest fitted G the normal curve
goes on along its tangent up to :data:`EXTRAPOLATE` further, then holds
(:func:`normal_force`).

:class:`~optitact.calib.fit.Calibration` evaluates these curves; :func:`fit_element`
fits them to one element's samples (``Calibration.fit`` runs it per element).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from optitact.errors import InputError

__all__ = ["EXTRAPOLATE", "MODELS", "MIN_RELATIVE_SPREAD", "FZ_FLOOR", "ElementCurves", "fit_element",
           "grey_for_force", "normal_force", "zero_shear_centroid"]

MODELS = ("ohka", "coupled")
#: Smallest relative spread (``ptp / max |x|``) of G, u and Fz a fit accepts; a narrower range
#: leaves the cubic g(G) and the shear curve ill-conditioned.
MIN_RELATIVE_SPREAD = 1e-6
#: Coefficients of the cubic g(G).
G_TERMS = 4


def g_design(s: np.ndarray) -> np.ndarray:
    """The cubic's terms ``(1, s, s^2, s^3)`` along a new last axis."""
    return np.stack([np.ones_like(s), s, s**2, s**3], axis=-1)


#: Above an element's fitted range (``G > g_max``) its normal curve goes on along its tangent at
#: ``g_max`` up to this fraction beyond it, and holds there (the reading is flagged ``clamped``).
#: A loaded element whose neighbours are not (a single touch) reads brighter than any calibration
#: frame that loaded it as hard with as much shear; such readings lie just above the range, where
#: the tangent follows the curve better than a flat hold (figures in docs/results/accuracy.md).
EXTRAPOLATE = 0.25


def normal_force(g: np.ndarray, g_scale: np.ndarray, g_max: np.ndarray, G: np.ndarray,
                 q: np.ndarray) -> np.ndarray:
    """Fz (..., E) of the elements' normal curves at ``G`` (..., E): ``g(s) + q s``, ``s = G / g_scale``.

    ``g`` (E, 4): the cubic's coefficients; ``q`` (..., E): the coupled
    model's centroid term (``gu . u / u_scale``, 0 for ohka). Up to
    ``g_max`` the curve itself; above it its tangent there, up to
    :data:`EXTRAPOLATE` beyond ``g_max``, then held. At least 0.
    """
    s = np.minimum(G, g_max) / g_scale
    fz = ((g[:, 3] * s + g[:, 2]) * s + g[:, 1] + q) * s + g[:, 0]
    s_max = g_max / g_scale
    over = (np.minimum(G, g_max * (1.0 + EXTRAPOLATE)) - g_max) / g_scale
    slope = g[:, 1] + (2.0 * g[:, 2] + 3.0 * g[:, 3] * s_max) * s_max + q
    return np.maximum(fz + np.maximum(over, 0.0) * np.maximum(slope, 0.0), 0.0)


def f_ohka(t: np.ndarray, d: np.ndarray) -> np.ndarray:
    """The ohka shear curve ``d1 t + d3 t^3``."""
    return d[0] * t + d[1] * t**3


#: Normal force (N) below which the zero-shear centroid ``u0(Fz)`` stops growing (its 1/sqrt(Fz) term).
FZ_FLOOR = 0.02


def zero_shear_centroid(u0: np.ndarray, fz: np.ndarray) -> np.ndarray:
    """Where the centroid sits without shear: ``u0[..., 0, :] + u0[..., 1, :] / sqrt(max(Fz, FZ_FLOOR))``.

    The rim light makes the cones nearer the rim brighter, so the grey-value centroid of an unsheared
    element sits off its centre, towards the rim, by a fraction of the cone circle that shrinks as the
    spots grow with the load (measured on the 45 deg ring: -0.10 mm at 0.03 N, -0.07 mm at 0.8 N).
    """
    return u0[..., 0, :] + u0[..., 1, :] / np.sqrt(np.maximum(fz, FZ_FLOOR))[..., None]


def shear_coupled(u: np.ndarray, fz: np.ndarray, p: np.ndarray, u0: np.ndarray | None = None) -> np.ndarray:
    """The coupled shear ``(u - u0(Fz)) Fz / (a + b sqrt(Fz))`` of ``p = (a, b)``."""
    if u0 is not None:
        u = u - zero_shear_centroid(u0, fz)
    return u * (fz / (p[0] + p[1] * np.sqrt(fz)))[..., None]


def check_spread(x: np.ndarray, what: str) -> None:
    """InputError unless ``x`` spans a range wider than ``MIN_RELATIVE_SPREAD`` of its magnitude."""
    spread, scale = float(np.ptp(x)), float(np.max(np.abs(x)))
    if not spread > MIN_RELATIVE_SPREAD * scale:
        raise InputError(f"{what} spans {spread:.3g} around a magnitude of {scale:.3g} (relative "
                         f"{spread / scale if scale else 0.0:.3g}); a fit needs a relative spread "
                         f"above {MIN_RELATIVE_SPREAD:g} (an ill-conditioned range)")


@dataclass(frozen=True)
class ElementCurves:
    """The fitted curves of one element (one row of each :class:`~optitact.calib.fit.Calibration` array).

    Attributes
    ----------
    g : (4,) ndarray
        Normal-force coefficients on ``s = G / g_scale``.
    gu : (2,) ndarray
        The brightness gradient (coupled; zero for ohka).
    f : (2,) ndarray
        Shear coefficients ``(d1, d3)`` (ohka) or ``(a, b)`` (coupled).
    u0 : (2, 2) ndarray
        Coupled: the centroid at zero shear, ``u0(Fz) = u0[0] + u0[1] / sqrt(max(Fz, FZ_FLOOR))``
        (mm; zero for ohka).
    g_scale, u_scale, g_max, u_max : float
        Scales and fitted ranges (the largest G and ``|u|``).
    rms_fx, rms_fy, rms_fz : float
        RMS fit residuals (N).
    n : int
        Samples fitted.
    """

    g: np.ndarray
    gu: np.ndarray
    f: np.ndarray
    u0: np.ndarray
    g_scale: float
    u_scale: float
    g_max: float
    u_max: float
    rms_fx: float
    rms_fy: float
    rms_fz: float
    n: int


def fit_element(G: np.ndarray, u: np.ndarray, fe: np.ndarray, *, model: str, lever_arm: float,
                e: int) -> ElementCurves:
    """Fit element ``e``'s curves to its usable samples (in contact, not saturated).

    Parameters
    ----------
    G : (N,) ndarray
        Grey values.
    u : (N, 2) ndarray
        Centroid shifts (mm).
    fe : (N, 3) float64 ndarray
        Element-local forces (N).
    model : {"ohka", "coupled"}
    lever_arm : float
        The sensor's lever arm (mm): the coupled fit's scale when its linear
        start is degenerate.
    e : int
        The element's index (for the messages).

    Raises
    ------
    InputError
        Fewer than 8 samples, fewer than 4 distinct G values, no spread (or
        an ill-conditioned one) in G, u or Fz, or no shear at all.
    """
    from scipy.optimize import least_squares, lsq_linear

    if len(G) < 8:
        raise InputError(f"element {e}: {len(G)} usable samples (in contact, not "
                         f"saturated); a fit needs at least 8")
    if np.ptp(G) <= 0 or np.ptp(u) <= 0:
        raise InputError(f"element {e}: the readings do not vary (constant G or u); "
                         f"the loads must span a range")
    n_distinct = len(np.unique(G))
    if n_distinct < G_TERMS:
        raise InputError(f"element {e}: {n_distinct} distinct G values (duplicate points); "
                         f"the cubic g(G) needs at least {G_TERMS}")
    check_spread(G, f"element {e}: G")
    check_spread(u, f"element {e}: u")
    check_spread(fe[:, 2], f"element {e}: the normal forces Fz")
    if not np.any(fe[:, :2]):
        raise InputError(f"element {e}: no sample has shear (Fx = Fy = 0 throughout); the "
                         f"shear curve needs loads with shear")
    g_scale = np.float64(G.max())
    s = G / g_scale
    g_max = np.float64(G.max())
    radius = np.hypot(u[:, 0], u[:, 1])
    u_max = np.float64(radius.max())
    u_scale = u_max
    design = g_design(s)
    if model == "coupled":  # + the brightness gradient across the element
        design = np.concatenate([design, s[:, None] * u / u_scale], axis=1)
    lo = np.r_[np.zeros(G_TERMS), np.full(design.shape[1] - G_TERMS, -np.inf)]
    sol = lsq_linear(design, fe[:, 2], bounds=(lo, np.inf), method="bvls")
    # BVLS can return a bound-active coefficient a rounding error below 0 (-5.6e-17 seen).
    g = np.maximum(sol.x[:G_TERMS], 0.0)
    gu = sol.x[G_TERMS:] if model == "coupled" else np.zeros(2)
    fz_hat = np.maximum(design @ np.r_[g, sol.x[G_TERMS:]], 0.0)
    if model == "ohka":
        tt = (u / u_scale).reshape(-1)
        a = np.stack([tt, tt**3], axis=-1)
        f = np.maximum(lsq_linear(a, fe[:, :2].reshape(-1), bounds=(0.0, np.inf), method="bvls").x, 0.0)
        shear = f_ohka(u / u_scale, f)
        u0 = np.zeros((2, 2))
    else:
        fzp = np.maximum(fz_hat, 1e-9)
        ft = fe[:, :2]
        # The zero-shear centroid u0(Fz) = p + q / sqrt(Fz): the intercept of u against the shear, at
        # several normal loads (fitted from 12 samples on; fewer keep it 0).
        with_u0 = len(G) >= 12 and np.ptp(fe[:, 2]) > 0

        def unpack(x):
            return x[:2], (x[2:].reshape(2, 2) if with_u0 else np.zeros((2, 2)))

        def resid(x, u=u, fzp=fzp, target=ft):
            p, off = unpack(x)
            return (shear_coupled(u, fzp, p, off) - target).reshape(-1)

        # Start from the linear problem u = F_t (a + b sqrt(Fz)) / Fz + u0(Fz) (exact on exact data,
        # with the true Fz), then minimise the shear residuals themselves (with the fitted Fz).
        fz_true = np.maximum(fe[:, 2], 1e-9)
        inv = 1.0 / np.sqrt(np.maximum(fz_true, FZ_FLOOR))
        cols = [ft / fz_true[:, None], ft / np.sqrt(fz_true)[:, None]]
        if with_u0:
            one = np.ones(len(G))
            cols += [np.stack([one, 0 * one], 1), np.stack([0 * one, one], 1),
                     np.stack([inv, 0 * inv], 1), np.stack([0 * inv, inv], 1)]
        lin = np.stack([c.reshape(-1) for c in cols], axis=-1)
        n_x = lin.shape[1]
        lower = np.r_[1e-6, 0.0, np.full(n_x - 2, -np.inf)]
        x0 = lsq_linear(lin, u.reshape(-1), bounds=(lower, np.inf), method="bvls").x
        if with_u0:  # rows of u0: (p_x, p_y), (q_x, q_y)
            x0 = np.r_[x0[:2], x0[2], x0[3], x0[4], x0[5]]
        h0 = max(lever_arm, 1e-3)
        scale = [max(x0[0], 1e-6), max(x0[1], 1e-3 * x0[0], 1e-6)] if x0[0] > 1e-6 else [h0, h0]
        scale += [max(u_scale, 1e-9) * 0.1] * (n_x - 2)
        sol2 = least_squares(resid, x0=x0, bounds=(lower, np.inf), x_scale=scale,
                             ftol=1e-12, xtol=1e-12, gtol=1e-12)
        f, u0 = unpack(sol2.x)
        shear = shear_coupled(u, fzp, f, u0)
    rms_fz = math.sqrt(np.mean((fz_hat - fe[:, 2]) ** 2))
    rms_fx = math.sqrt(np.mean((shear[:, 0] - fe[:, 0]) ** 2))
    rms_fy = math.sqrt(np.mean((shear[:, 1] - fe[:, 1]) ** 2))
    return ElementCurves(g=g, gu=gu, f=f, u0=u0, g_scale=g_scale, u_scale=u_scale, g_max=g_max, u_max=u_max,
                         rms_fx=rms_fx, rms_fy=rms_fy, rms_fz=rms_fz, n=len(G))


def grey_for_force(cal, fz: np.ndarray, u: np.ndarray) -> np.ndarray:
    """The G (T, E) at which a calibration ``cal``'s normal curve of each element gives ``fz`` at shift ``u``.

    NaN where no G in ``[0, 2 g_max]`` does (bisection: the curve rises with G on the fitted range).
    """
    radius = np.hypot(u[..., 0], u[..., 1])
    scale = np.divide(np.broadcast_to(cal.u_max, radius.shape), radius, out=np.ones_like(radius),
                      where=radius > cal.u_max)
    t = u * scale[..., None] / cal.u_scale[:, None]
    q = np.sum(t * cal.gu, axis=-1)

    def curve(s):
        return np.einsum("...ek,ek->...e", g_design(s), cal.g) + s * q

    hi_s = np.broadcast_to(2.0 * cal.g_max / cal.g_scale, fz.shape).copy()
    lo, hi = np.zeros_like(hi_s), hi_s
    bracketed = (curve(lo) <= fz) & (curve(hi) >= fz)
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        below = curve(mid) < fz
        lo, hi = np.where(below, mid, lo), np.where(below, hi, mid)
    return np.where(bracketed, 0.5 * (lo + hi) * cal.g_scale, np.nan)
