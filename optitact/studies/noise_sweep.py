"""The noise study: G and centroid spread against the Cramér–Rao bound, and contact flicker.

A Gaussian spot of known energy and centre is drawn on the nominal camera,
exposed many times through the CCD model (shot noise, read noise, rounding,
clipping) at eight signal levels, and read back by the pipeline; the spread
of G and u is compared with the Cramér–Rao bound computed from each pixel's
exact grey-value distribution (:func:`noise_sweep`). :func:`flicker_check`
compares the contact flag's rate and flip rate at the noise floor with the
noise model's prediction.

``optitact.studies.run("noise")`` runs both (``quick``: 100 frames per level,
``full``: 400); :mod:`optitact.studies.bench_stability` adds the generated
stress cases for ``optitact bench stability``.
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass

import numpy as np

from optitact.optics.camera import FisheyeCamera
from optitact.optics.ccd import CCD
from optitact.errors import InputError
from optitact.pipeline.fastpath import CHUNK_FRAMES
from optitact.pipeline.frame_pipeline import Pipeline
from optitact.optics.sensor import DomeSensor
from optitact.studies._protocol import Study

__all__ = ["compact_level", "compact_levels", "FLICKER_TARGETS", "NOMINAL_LOAD_N", "NOMINAL_WIDTH_MM",
           "STUDY", "SWEEP_FACTORS", "flicker_check", "noise_sweep", "nominal_energy", "run"]

#: Signal levels of the noise sweep, as multiples of the nominal spot's energy.
SWEEP_FACTORS = (1 / 32, 1 / 16, 1 / 8, 1 / 4, 1 / 2, 1.0, 2.0, 4.0)
#: The nominal spot: rms width (mm) and normal load (N) whose energy it carries.
NOMINAL_WIDTH_MM = 0.5
NOMINAL_LOAD_N = 0.5
#: Where the sweep's spot sits: element and centre (element-local mm).
SWEEP_ELEMENT = 0
SWEEP_CENTRE = (0.2, -0.1)
#: Contact rates at which the flicker check is made.
FLICKER_TARGETS = (0.2, 0.5, 0.8)
#: Monte Carlo frames per level (and per flicker check) of the quick and full sizes.
FRAMES = {"quick": 100, "full": 400}


# ============================================================================ the noise sweep
def _quantised_pmf(lam: float, ccd: CCD) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distribution of one pixel's DN for a mean charge ``lam`` (electrons), exactly as the CCD model draws it.

    Returns ``(d, P, dP)``: the DN values, their probabilities and the
    derivative of the probabilities with respect to ``lam`` (Poisson shot
    noise, full-well clip, Gaussian read noise, rounding and the ADC clip).
    """
    from scipy.special import ndtr
    from scipy.stats import poisson

    g, o, sr, top, fw = ccd.dn_per_electron, ccd.dark_offset, ccd.read_noise, 2**ccd.bits - 1, ccd.full_well
    sd = math.sqrt(lam) + 1.0
    k = np.arange(max(0, int(lam - 10 * sd - 5)), int(lam + 10 * sd + 7), dtype=np.float64)
    pk = poisson.pmf(k, lam)
    lo = max(0, int(math.floor(g * (min(k[0], fw) - 9 * sr - 1) + o)) - 1)
    hi = min(top, int(math.ceil(g * (min(k[-1] + 1, fw) + 9 * sr + 1) + o)) + 1)
    d = np.arange(lo, hi + 1, dtype=np.float64)

    def q(kv):  # P(DN == d | k electrons)
        kv = np.minimum(kv, fw)[:, None]
        up = np.where(d[None] >= top, np.inf, (d[None] + 0.5 - o) / g - kv)
        dn = np.where(d[None] <= 0, -np.inf, (d[None] - 0.5 - o) / g - kv)
        if sr > 0:
            return ndtr(up / sr) - ndtr(dn / sr)
        return ((dn < 0) & (up >= 0)).astype(np.float64)

    qk = q(k)
    return d, pk @ qk, pk @ (q(k + 1.0) - qk)


@dataclass
class _SpotModel:
    """A Gaussian spot drawn in a window of the image, its pixel weights in the pipeline, and its noise."""

    sensor: DomeSensor
    camera: FisheyeCamera
    ccd: CCD
    pipe: Pipeline
    element: int
    window: tuple[int, int, int, int]   # r0, r1, c0, c1
    xy: np.ndarray                      # (h, w, 2) tangent offsets of the window's pixels
    entries: np.ndarray                 # flat window index of each of the element's fold entries
    weights: np.ndarray                 # (3, n) fold weights (area, area x, area y) of those entries
    base: np.ndarray                    # (n,) baseline of those entries
    thr: np.ndarray                     # (n,) threshold of those entries

    @classmethod
    def build(cls, sensor, camera, ccd, element, *, margin_mm=4.0):
        pipe = Pipeline(sensor, camera, baseline=np.full(camera.shape, ccd.dark_offset))
        fold = pipe.region_weights
        sel = fold.label == element
        pix = fold.pixel[sel]
        rows, cols = np.divmod(pix, camera.width)
        cen = camera.project(sensor.element_positions[element], sensor)
        half = int(math.ceil(margin_mm / (pipe.grids.grid_mm * 2.5))) + 2
        r0 = int(max(0, min(rows.min(), cen[0] - half)))
        r1 = int(min(camera.height, max(rows.max() + 1, cen[0] + half + 1)))
        c0 = int(max(0, min(cols.min(), cen[1] - half)))
        c1 = int(min(camera.width, max(cols.max() + 1, cen[1] + half + 1)))
        rr, cc = np.mgrid[r0:r1, c0:c1]
        pts = camera.unproject(np.stack([rr, cc], -1).astype(np.float64), sensor, outside="nan")
        xy = sensor.tangent_offset(np.full(rr.shape, element), pts)
        entries = (rows - r0) * (c1 - c0) + (cols - c0)
        return cls(sensor, camera, ccd, pipe, element, (r0, r1, c0, c1), xy, entries,
                   fold.weights[:, sel], pipe.entry_baseline[sel], pipe.entry_threshold[sel])

    def radiance(self, energy: float, s: float, c) -> np.ndarray:
        """Window radiance of a spot of ``energy`` (DN mm^2 on the dome), rms width ``s`` (mm), centre ``c``."""
        d2 = np.sum((self.xy - np.asarray(c)) ** 2, axis=-1)
        peak_dn = energy / (2 * math.pi * s * s)
        scale = peak_dn / (self.ccd.dn_per_electron * self.ccd.exposure)
        return np.where(np.isfinite(d2), scale * np.exp(-np.nan_to_num(d2, nan=1e9) / (2 * s * s)), 0.0)

    def frames(self, rad: np.ndarray, n: int, seed: int):
        """Yield stacks of full frames (chunks of CHUNK_FRAMES) with the spot exposed in the window."""
        r0, r1, c0, c1 = self.window
        rng = np.random.default_rng(seed)
        dtype = np.uint8 if self.ccd.bits == 8 else np.uint16
        for i in range(0, n, CHUNK_FRAMES):
            t = min(CHUNK_FRAMES, n - i)
            st = np.full((t,) + self.camera.shape, round(self.ccd.dark_offset), dtype)
            st[:, r0:r1, c0:c1] = self.ccd.expose(np.broadcast_to(rad, (t,) + rad.shape),
                                                  seed=int(rng.integers(2**63)))
            yield st


def _pixel_stats(model: _SpotModel, lam: np.ndarray):
    """Per-pixel Fisher information about the mean charge, and the moments of the pipeline's terms.

    For every window pixel: ``J`` (Fisher information of its DN about its
    mean charge). For every fold entry: the mean and the derivative (w.r.t.
    the pixel's mean charge) of the lit value ``v 1[v > t]`` (G's term) and
    of ``(v - t) 1[v > t]`` (the centroid's weight), with ``v = DN - baseline``.
    """
    flat = lam.reshape(-1)
    cache: dict = {}
    J = np.zeros(flat.size)
    for i, lam_i in enumerate(flat):
        key = round(float(lam_i), 9)
        if key not in cache:
            d, P, dP = _quantised_pmf(float(lam_i), model.ccd)
            ok = P > 1e-300
            cache[key] = (d, P, dP, float(np.sum(dP[ok] ** 2 / P[ok])))
        J[i] = cache[key][3]
    n = len(model.entries)
    eg, dg, ew, dw = (np.zeros(n) for _ in range(4))
    for j, p in enumerate(model.entries):
        d, P, dP, _ = cache[round(float(flat[p]), 9)]
        v = d - model.base[j]
        lit = v > model.thr[j]
        term_g = np.where(lit, v, 0.0)
        term_w = np.where(lit, v - model.thr[j], 0.0)
        eg[j], dg[j] = term_g @ P, term_g @ dP
        ew[j], dw[j] = term_w @ P, term_w @ dP
    return J.reshape(lam.shape), eg, dg, ew, dw


def _sweep_level(model: _SpotModel, energy: float, s: float, c, n_frames: int, seed: int) -> dict:
    ccd = model.ccd
    rad = model.radiance(energy, s, c)
    lam = rad * ccd.exposure                                    # mean electrons per pixel
    n_e = float(lam.sum())
    J, eg, dg, ew, dw = _pixel_stats(model, lam)
    # Fisher information about (energy, s, cx, cy) from every pixel of the window
    xy = np.nan_to_num(model.xy)
    dx, dy = xy[..., 0] - c[0], xy[..., 1] - c[1]
    r2 = dx * dx + dy * dy
    grads = np.stack([lam / energy, lam * (r2 / s**3 - 2.0 / s), lam * dx / s**2, lam * dy / s**2])
    fisher = np.einsum("aij,bij,ij->ab", grads, grads, J)
    crb = np.linalg.inv(fisher)
    # gradients of the estimators' means over all four parameters, from the exact per-pixel
    # distributions (the centroid's as a ratio of means): the bound of a biased estimator
    # with nuisance parameters is grad' I^-1 grad
    g_e = grads.reshape(4, -1)[:, model.entries]                 # d lam / d theta, per entry
    area, wx, wy = model.weights
    grad_G = (area * dg) @ g_e.T
    W, Mx, My = area @ ew, wx @ ew, wy @ ew
    dW = (area * dw) @ g_e.T
    grad_u = [((wmom * dw) @ g_e.T * W - mom * dW) / W**2 for wmom, mom in ((wx, Mx), (wy, My))]
    bound_G = float(grad_G @ crb @ grad_G)
    bound_u = [float(gu @ crb @ gu) for gu in grad_u]
    # Monte Carlo through the CCD model and the pipeline
    G, u, contact, G_tail = [], [], [], []
    tail_pipe = model.pipe.replace(tail="gaussian")  # the same frames, the clipped tails added back
    for st in model.frames(rad, n_frames, seed):
        r = model.pipe.process(st)
        G.append(r.G[:, model.element])
        u.append(r.u[:, model.element])
        contact.append(r.contact[:, model.element])
        G_tail.append(tail_pipe.process(st).G[:, model.element])
    G, u, contact, G_tail = (np.concatenate(G), np.concatenate(u), np.concatenate(contact),
                             np.concatenate(G_tail))
    rate = float(contact.mean())
    g_true = energy
    n_eff = 4 * math.pi * s * s / float(model.pipe.region_weights.pixel_area[model.element])
    out = {"signal_factor": None, "energy_dn_mm2": energy, "electrons": n_e,
           "snr": n_e / math.sqrt(n_e + n_eff * (ccd.read_noise**2 + 1.0 / (12.0 * ccd.dn_per_electron**2))),
           "contact_rate": rate}
    Gc, uc = G[contact], u[contact]
    if len(Gc) >= 10:
        var_g = float(np.var(Gc, ddof=1))
        out["G"] = {"true": g_true, "mean": float(Gc.mean()), "mean_model": float(area @ eg),
                    "bias_rel": float(Gc.mean() / g_true - 1.0),
                    "bias_rel_tail": float(G_tail[contact].mean() / g_true - 1.0),
                    "std_rel": math.sqrt(var_g) / g_true,
                    "crb_rel": math.sqrt(crb[0, 0]) / g_true, "slope": float(grad_G[0]),
                    "bound_rel": math.sqrt(bound_G) / g_true,
                    "efficiency": bound_G / var_g if rate >= 0.99 and var_g > 0 else None}
        var_u = np.var(uc, axis=0, ddof=1)
        eff = [b / v for b, v in zip(bound_u, var_u, strict=True)] \
            if rate >= 0.99 and np.all(var_u > 0) else None
        bias = uc.mean(axis=0) - np.asarray(c)
        out["u"] = {"bias_mm": [float(b) for b in bias], "std_mm": [float(math.sqrt(v)) for v in var_u],
                    "crb_mm": [math.sqrt(crb[2, 2]), math.sqrt(crb[3, 3])],
                    "bound_mm": [math.sqrt(b) for b in bound_u], "simple_bound_mm": s / math.sqrt(n_e),
                    "slope": [float(grad_u[0][2]), float(grad_u[1][3])],
                    "efficiency": float(np.mean(eff)) if eff is not None else None}
    return out


def nominal_energy(sensor: DomeSensor | None = None, load_n: float = NOMINAL_LOAD_N,
                   element: int = SWEEP_ELEMENT) -> float:
    """G (grey level x mm^2) that the shipped calibration gives a pure normal ``load_n`` on ``element``.

    The energy of a typical spot on the default camera and CCD: the inverse
    of the calibration's g(G) with u = 0, by bisection.
    """
    from optitact.calib.shipped import default_calibration

    cal = default_calibration()
    if sensor is not None and sensor != cal.sensor:
        raise InputError("nominal_energy uses the shipped calibration of the default sensor")
    lo, hi = 0.0, float(cal.g_max[element]) * 4.0
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        s = mid / cal.g_scale[element]
        fz = float(cal.g[element] @ np.array([1.0, s, s * s, s**3]))
        lo, hi = (mid, hi) if fz < load_n else (lo, mid)
    return 0.5 * (lo + hi)


def noise_sweep(*, n_frames: int = 400, seed: int = 0, factors=SWEEP_FACTORS,
                width_mm: float = NOMINAL_WIDTH_MM, camera: FisheyeCamera | None = None,
                ccd: CCD | None = None, progress: bool = False) -> dict:
    """Bias, spread and efficiency of G and u against signal-to-noise, for a Gaussian spot.

    Parameters
    ----------
    n_frames : int
        Monte Carlo frames per signal level.
    seed : int
        Seed of the CCD noise.
    factors : sequence of float
        Signal levels as multiples of the nominal energy (the G of a 0.5 N
        normal load, :func:`nominal_energy`).
    width_mm : float
        The spot's rms width along each axis (mm), default 0.5: it keeps 99.7 %
        of its energy within 1.7 mm, the reach of an element's cone patches.
    camera, ccd : optional
        Default: the package's nominal ``FisheyeCamera()`` (640 x 480) and ``CCD()`` (8 bits).
    progress : bool
        A progress bar on stderr.

    Returns
    -------
    dict
        ``levels``: one entry per factor with ``snr``, ``electrons``,
        ``contact_rate``, ``G`` (``bias_rel``, ``std_rel``, ``crb_rel``,
        ``efficiency``) and ``u`` (``bias_mm``, ``std_mm``, ``crb_mm``,
        ``simple_bound_mm``, ``efficiency``); ``nominal``: the level at
        factor 1 with ``u_efficiency`` and ``G_efficiency``; ``spot``: the
        spot's settings.

    Notes
    -----
    The spot ``A exp(-|xy - c|^2 / 2 s^2)`` is drawn at the pixel centres
    (``xy``: the element-local geodesic coordinates of the dome point each
    pixel sees, through the closed-form camera), its energy ``A 2 pi s^2``
    in DN mm^2 turned into mean electrons ``lambda_p`` with the CCD's gain
    and exposure. Each pixel's DN has the exact distribution of the CCD model
    (Poisson shot noise, full-well clip, Gaussian read noise, rounding, ADC
    clip), computed by summing over electron counts; its Fisher information
    about ``lambda_p`` is ``J_p = sum_d (dP/dlambda)^2 / P``. The bound is
    the inverse of ``I_ab = sum_p J_p (d lambda_p / d theta_a)(d lambda_p /
    d theta_b)`` over ``theta = (energy, s, c_x, c_y)`` (the width is a
    nuisance parameter), over every pixel of a window around the element --
    the information outside the region included. ``simple_bound_mm`` is
    ``s / sqrt(N)``, the photon limit.

    The pipeline's estimators are biased (the threshold drops the spot's
    rim), so the bound applies as ``var >= k^2 CRB`` with ``k = dE[estimate]
    / d theta``, computed from the same exact per-pixel distributions (the
    centroid's as a ratio of means); ``efficiency = k^2 CRB / var`` over the
    frames in contact, reported where at least 99 % of them are. ``snr`` is
    ``N / sqrt(N + n_eff sigma_e^2)`` with ``N`` the spot's electrons,
    ``n_eff = 4 pi s^2 / pixel area`` and ``sigma_e^2`` read noise plus
    quantisation noise in electrons^2.
    """
    camera = FisheyeCamera() if camera is None else camera
    ccd = CCD() if ccd is None else ccd
    sensor = DomeSensor.default()
    model = _SpotModel.build(sensor, camera, ccd, SWEEP_ELEMENT)
    e0 = nominal_energy(sensor)
    levels = []
    it = list(enumerate(factors))
    if progress:
        from tqdm import tqdm

        it = tqdm(it, desc="noise sweep", unit="level", file=sys.stderr)
    for i, f in it:
        lv = _sweep_level(model, e0 * f, width_mm, SWEEP_CENTRE, n_frames, seed + 7919 * i)
        lv["signal_factor"] = f
        levels.append(lv)
    nominal = next(lv for lv in levels if lv["signal_factor"] == 1.0) if 1.0 in factors else None
    if nominal is not None:
        nominal = dict(nominal, u_efficiency=nominal.get("u", {}).get("efficiency"),
                       G_efficiency=nominal.get("G", {}).get("efficiency"))
    return {"levels": levels, "nominal": nominal,
            "spot": {"element": SWEEP_ELEMENT, "centre_mm": list(SWEEP_CENTRE), "width_mm": width_mm,
                     "nominal_energy_dn_mm2": e0, "nominal_load_n": NOMINAL_LOAD_N,
                     "camera": camera.to_dict(), "ccd": ccd.to_dict(), "frames_per_level": n_frames,
                     "pipeline": {"noise_sigma": model.pipe.noise_sigma, "k": model.pipe.k,
                                  "threshold": model.pipe.threshold}}}


def flicker_check(*, target_rate: float = 0.5, n_frames: int = 400, seed: int = 0, width_mm: float = 0.4,
                  camera: FisheyeCamera | None = None, ccd: CCD | None = None) -> dict:
    """Contact flag at the noise floor: its rate and flip rate against the noise model's prediction.

    A spot is scaled until the noise model gives contact with probability
    ``target_rate``; ``n_frames`` frames of the same spot through the CCD
    model and the pipeline then give the measured contact and flip rates.
    The prediction samples every pixel's DN from its exact distribution
    (:func:`_quantised_pmf`, not the CCD's sampler) and applies the contact
    rule (``G > floor``) to the sums; consecutive frames are independent, so
    the predicted flip rate is ``2 p (1 - p)``.

    Returns
    -------
    dict
        ``predicted_rate``, ``measured_rate``, ``predicted_flip_rate``,
        ``measured_flip_rate``, their tolerances, ``deterministic`` (the same
        frame always reads the same flag) and ``ok``.
    """
    camera = FisheyeCamera() if camera is None else camera
    ccd = CCD() if ccd is None else ccd
    sensor = DomeSensor.default()
    model = _SpotModel.build(sensor, camera, ccd, SWEEP_ELEMENT)
    rng = np.random.default_rng(seed)
    floor = float(model.pipe.floor[SWEEP_ELEMENT])
    area = model.weights[0]
    cache: dict = {}

    def sampler(energy):
        lam = (model.radiance(energy, width_mm, SWEEP_CENTRE) * ccd.exposure).reshape(-1)[model.entries]
        cdfs = []
        for lv in lam:
            key = round(float(lv), 9)
            if key not in cache:
                d, P, _ = _quantised_pmf(float(lv), ccd)
                cache[key] = (d, np.cumsum(P) / P.sum())
            cdfs.append(cache[key])
        return cdfs

    def model_rate(energy, n):
        cdfs = sampler(energy)
        G = np.zeros(n)
        for j, (d, cdf) in enumerate(cdfs):
            dn = d[np.minimum(np.searchsorted(cdf, rng.random(n)), len(d) - 1)]
            v = dn - model.base[j]
            G += area[j] * np.where(v > model.thr[j], v, 0.0)
        return float(np.mean(G > floor))

    lo, hi = 0.0, 2.0
    e_unit = floor * 10.0
    for _ in range(14):  # bisection on the spot's energy for the target contact rate
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if model_rate(e_unit * mid, 600) < target_rate else (lo, mid)
    energy = e_unit * 0.5 * (lo + hi)
    p = model_rate(energy, 20000)
    rad = model.radiance(energy, width_mm, SWEEP_CENTRE)
    contact = []
    deterministic = True
    for st in model.frames(rad, n_frames, int(rng.integers(2**63))):
        r = model.pipe.process(st)
        contact.append(r.contact[:, SWEEP_ELEMENT])
        again = model.pipe.process(st[:4])
        deterministic &= bool(np.array_equal(again.contact[:, SWEEP_ELEMENT], r.contact[:4, SWEEP_ELEMENT]))
    contact = np.concatenate(contact)
    measured = float(contact.mean())
    flips = float(np.mean(contact[1:] != contact[:-1]))
    pred_flip = 2 * p * (1 - p)
    tol_rate = 4 * math.sqrt(max(p * (1 - p), 1e-4) / n_frames) + 0.01
    tol_flip = 4 * math.sqrt(max(pred_flip * (1 - pred_flip), 1e-4) * 2 / (n_frames - 1)) + 0.01
    ok = deterministic and abs(measured - p) <= tol_rate and flips <= pred_flip + tol_flip
    return {"energy_dn_mm2": energy, "floor_dn_mm2": floor, "predicted_rate": p, "measured_rate": measured,
            "rate_tolerance": tol_rate, "predicted_flip_rate": pred_flip, "measured_flip_rate": flips,
            "flip_tolerance": tol_flip, "frames": n_frames, "deterministic": deterministic, "ok": bool(ok)}


def _round(x, n=4):
    if x is None:
        return None
    if isinstance(x, list | tuple):
        return [_round(v, n) for v in x]
    return float(f"{x:.{n}g}")


def compact_level(lv: dict) -> dict:
    """One noise level of :func:`run`'s result, reduced to the figures ``bench stability`` reports (rounded)."""
    out = {"signal_factor": lv["signal_factor"], "snr": _round(lv["snr"]), "electrons": _round(lv["electrons"]),
           "contact_rate": _round(lv["contact_rate"])}
    if "G" in lv:
        out["G"] = {k: _round(lv["G"][k]) for k in ("true", "bias_rel", "bias_rel_tail", "std_rel", "crb_rel",
                                                    "efficiency")}
        out["u"] = {k: _round(lv["u"][k])
                    for k in ("bias_mm", "std_mm", "crb_mm", "simple_bound_mm", "efficiency")}
    return out


def compact_levels(levels: list[dict]) -> list[dict]:
    """:func:`compact_level` of each level."""
    return [compact_level(lv) for lv in levels]


# ============================================================================ the study
def run(seed: int, *, full: bool, progress: bool) -> dict:
    """The sweep over :data:`SWEEP_FACTORS` and the flicker checks at :data:`FLICKER_TARGETS`.

    Returns ``levels``, ``nominal`` and ``spot`` of :func:`noise_sweep` and
    ``flicker``: one :func:`flicker_check` per target rate (seeds ``seed +
    101 i``), with its ``target_rate``.
    """
    n_frames = FRAMES["full" if full else "quick"]
    out = noise_sweep(n_frames=n_frames, seed=seed, progress=progress)
    out["flicker"] = [dict(flicker_check(target_rate=t, n_frames=n_frames, seed=seed + 101 * i), target_rate=t)
                      for i, t in enumerate(FLICKER_TARGETS)]
    return out


def draw(fig, result) -> None:
    """Centroid spread against the bound, the efficiencies of u and G, and G's bias, over SNR."""
    levels = [lv for lv in result["levels"] if "u" in lv]
    snr = [lv["snr"] for lv in levels]
    ax1, ax2, ax3 = fig.subplots(1, 3)
    if all("bias_rel_tail" in lv["G"] for lv in levels):
        ax3.semilogx(snr, [100 * lv["G"]["bias_rel"] for lv in levels], "o-", label="G, threshold only")
        ax3.semilogx(snr, [100 * lv["G"]["bias_rel_tail"] for lv in levels], "s-",
                     label="G, clipped tails added (tail='gaussian')")
        ax3.axhline(0.0, color="k", lw=0.8)
        ax3.set_xlabel("signal-to-noise ratio of the spot")
        ax3.set_ylabel("bias of G (% of the spot's energy)")
        ax3.legend(fontsize=8)
    else:
        ax3.set_axis_off()
    ax1.loglog(snr, [1e3 * np.mean(lv["u"]["std_mm"]) for lv in levels], "o-", label="u: measured std")
    ax1.loglog(snr, [1e3 * np.mean(lv["u"]["crb_mm"]) for lv in levels], "k--", label="u: Cramér–Rao bound")
    ax1.loglog(snr, [1e3 * lv["u"]["simple_bound_mm"] for lv in levels], ":", color="0.5", label="u: s/√N")
    ax1.set_xlabel("signal-to-noise ratio of the spot")
    ax1.set_ylabel("centroid error (µm)")
    ax1.legend()
    nan = float("nan")
    ax2.semilogx(snr, [nan if lv["u"]["efficiency"] is None else lv["u"]["efficiency"] for lv in levels], "o-",
                 label="u efficiency")
    ax2.semilogx(snr, [nan if lv["G"]["efficiency"] is None else lv["G"]["efficiency"] for lv in levels], "s-",
                 label="G efficiency")
    ax2.axhline(1.0, color="k", lw=0.8)
    ax2.set_ylim(0, 1.2)
    ax2.set_xlabel("signal-to-noise ratio of the spot")
    ax2.set_ylabel("efficiency (bound / variance)")
    ax2.legend()


def key_figures(result: dict) -> list[tuple]:
    """Efficiencies at the nominal noise beside the target, and the flicker checks."""
    nominal = result["nominal"]
    rows = [("centroid efficiency at nominal noise", nominal["u_efficiency"],
             f">= {result['published']['u_efficiency_min']}"),
            ("G efficiency at nominal noise", nominal["G_efficiency"], None),
            ("nominal SNR of the spot", nominal["snr"], None)]
    for f in result["flicker"]:
        rows.append((f"contact rate at {f['energy_dn_mm2']:.3g} DN mm2", f["measured_rate"],
                     f"predicted {f['predicted_rate']:.3g}"))
    return rows


STUDY = Study(
    key_figures=key_figures,
    name="noise",
    summary="Dome sensor: spread of G and of the centroid against the Cramér–Rao bound, and contact flicker",
    run=run,
    draw=draw,
    published={"reference": "issue 6 target (no published paper figure): centroid efficiency >= 0.7 "
                            "against the Cramér–Rao bound at the nominal noise",
               "u_efficiency_min": 0.7},
    figsize=(16.0, 4.0),
)
