"""Friction scanning with the dome on the finger: the friction coefficient of flat specimens.

The apex element presses on a specimen and the finger slides it along a
straight stroke; the friction coefficient comes from the *estimated* forces
(:class:`optitact.finger.chain.ChainSimulator`) over the steady part of the slide
(:func:`optitact.forces.friction.friction_coefficient`). :func:`surface_scanning` runs
it, :func:`draw` draws a result. Part of the ``finger`` study
(:mod:`optitact.studies.finger`).
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from optitact._validate import positive, real_number
from optitact.errors import InputError
from optitact.finger.kinematics import POSE_SCAN, Finger
from optitact.finger.chain import ChainSimulator
from optitact.finger.scene import local_from_world, sliding_friction, world_from_local
from optitact.studies._finger_common import ar1, chain_for, need, rounded, study_seed
from optitact.studies._protocol import jsonable

__all__ = ["surface_scanning", "draw"]


def _smoothstep(x):
    x = np.clip(x, 0.0, 1.0)
    return x * x * (3.0 - 2.0 * x)



def _scan_profile(mu_k: float, speed: float, fn0: float, rate: float, slide_time: float,
                  rng: np.random.Generator) -> dict:
    """Simulated normal and friction force of one scan (force-controlled press, stick, slide, stop, lift)."""
    approach, dwell, stop, unload = 0.4, 0.2, 0.3, 0.25
    static_ratio, k_t, relax, wave, lam = 1.12, 0.5, 0.1, 0.03, 3.0
    n = int(round((approach + dwell + slide_time + stop + unload) * rate)) + 1
    t = np.arange(n) / rate
    t_s = approach + dwell
    t_e = t_s + slide_time
    t_u = t_e + stop
    x = speed * np.clip(t - t_s, 0.0, slide_time)
    press = _smoothstep(t / approach) * (1.0 - _smoothstep((t - t_u) / unload))
    fn = fn0 * press * (1.0 + wave * np.sin(2 * np.pi * x / lam + rng.uniform(0, 2 * np.pi))
                        + ar1(rng, n, 0.01, 0.5))
    fluct = ar1(rng, n, 0.02, 0.6)
    ft = np.zeros(n)
    t_on = None
    for i in range(n):
        if t_s < t[i] <= t_e:
            if t_on is None:
                stick = k_t * x[i]
                if stick < static_ratio * mu_k * fn[i]:
                    ft[i] = stick
                    continue
                t_on = t[i]
            ft[i] = mu_k * fn[i] * (1.0 + (static_ratio - 1.0) * math.exp(-(t[i] - t_on) / relax) + fluct[i])
        elif t[i] > t_e:
            last = ft[np.searchsorted(t, t_e, side="right") - 1]
            ft[i] = last * (0.5 + 0.5 * math.exp(-(t[i] - t_e) / relax)) * press[i] / max(press.max(), 1e-12)
    return {"t": t, "fn": fn, "ft": ft, "x": x, "t_slide": (t_s, t_e), "t_slip": t_on}


def surface_scanning(*, chain: ChainSimulator | None = None, frictions=(0.39, 0.40, 0.53),
                     speeds=(1.4, 6.2, 25.0), normal_force: float = 0.1, frame_rate: float = 20.0,
                     slide_time: float = 2.5, speed_coefficient: float = 0.01, tolerance: float = 0.02,
                     lean_deg: float = 9.0, finger: Finger | None = None, seed: int = 0,
                     progress: bool = True) -> dict:
    r"""Friction coefficients of flat specimens scanned by the apex element, from estimated forces.

    Parameters
    ----------
    chain : ChainSimulator, optional
        Default ``ChainSimulator(seed=seed)`` (shipped calibration, 640x480,
        32 spp).
    frictions : sequence of float
        Kinetic friction coefficients of the specimens at 6.2 mm/s
        (published: 0.39, 0.40, 0.53).
    speeds : sequence of float
        Sliding speeds (mm/s), published 1.4, 6.2 and 25.
    normal_force : float
        Pressing force of the apex element (N), published 0.1.
    frame_rate : float
        Camera frames per second, default 20.
    slide_time : float
        Duration of the sliding stroke (s), default 2.5.
    speed_coefficient : float
        ``c`` of :func:`optitact.finger.scene.sliding_friction` (default 0.01).
    tolerance : float
        The accepted ``|mu_est - mu_sim|``, published 0.02.
    lean_deg : float
        Lean of the sensor axis from straight down towards the sliding
        direction (deg), default 9, held along the stroke with the z-stage
        (:meth:`optitact.finger.kinematics.Finger.rmrc_lean`); see *Notes*. 0 presses the apex straight
        down.
    finger : Finger, optional
        Default ``Finger()``; the stroke is a straight radial line of the apex
        (world +x) from ``POSE_SCAN``, followed by RMRC frame by frame.
    seed : int
    progress : bool
        tqdm bars on stderr.

    Returns
    -------
    dict
        JSON-ready: ``runs`` (one per friction and speed: ``mu_simulated``
        (the model's kinetic coefficient at that speed), ``mu_estimated``,
        ``mu_std``, ``error``, ``within_tolerance``, ``steady_s``,
        ``mu_truth_steady`` (the same steady-part analysis on the simulated
        forces), ``clamped_fraction`` and ``tipped_fraction`` over the steady
        part, ``local_ratio_steady`` (the element-local ``|F_t| / F_z`` the
        sensor saw), the lean's range, the z-stage travel, and the
        ``series`` ``t, fn, ft, mu`` estimated and true), ``summary``,
        ``settings``, ``seconds``.

    Notes
    -----
    Force model of one run: the z-stage presses the apex element to
    ``normal_force`` (smooth ramp, 0.4 s), dwells 0.2 s, then the finger
    slides at ``v``: the friction force first grows elastically
    (0.5 N/mm) up to the static level ``1.12 mu_k F_n``, then relaxes to the
    kinetic level ``mu_k(v) F_n`` (time constant 0.1 s) with 2 % stick-slip
    fluctuations; the normal force carries 3 % waviness (3 mm wavelength)
    and 1 % noise. After the stroke the finger stops (the shear relaxes to
    half) and lifts. The world forces are turned into element-local ones
    with the sensor orientation from the finger's kinematics, rendered and
    read back; the estimated forces are turned back into world normal and
    tangential components with the same orientation, and
    :func:`optitact.forces.friction.friction_coefficient` finds the steady part.

    Why the lean: the element's columnar feeler tips over when
    ``h |F_t| > r F_z`` (lever arm ``h`` = 3 mm, cone circle ``r`` = 1.25 mm:
    at ``|F_t| / F_z`` of about 0.37-0.40, :func:`optitact.optics.contact.cone_loads`);
    beyond that the centroid stops following the shear, so an element whose
    axis is along the specimen's normal cannot measure ``mu`` = 0.53 at any
    normal force. With the sensor axis leaning by ``beta`` towards the
    sliding direction, the contact force (leaning back by the friction angle
    ``phi = atan mu``) meets the element at ``phi - beta``: the element sees
    ``|F_t| / F_z = tan(phi - beta)`` -- 0.35 for the steady 0.537 (0.53 at
    25 mm/s) with ``beta`` = 9 deg, 0.22 for 0.39 -- and ``-tan(beta)``
    while pressing without sliding. 9 deg keeps the apex feeler the lowest
    one (the nearest ring-1 feeler stays 0.32 mm above the specimen, more
    than the apex's indentation). A three-joint finger cannot hold an
    orientation while it moves (the lean would drift by about 0.55 deg/mm
    along a radial stroke); the z-stage as a fourth axis holds it
    (:meth:`optitact.finger.kinematics.Finger.rmrc_lean`). The world ``mu`` is recovered exactly by
    rotating the estimated forces back, so the lean changes what the element
    sees, not what is measured.
    """
    from tqdm import tqdm

    from optitact.forces.friction import friction_coefficient

    seed = study_seed(seed)
    chain = chain_for(chain, seed)
    finger = Finger() if finger is None else finger
    fn0 = positive(normal_force, "normal_force")
    rate = positive(frame_rate, "frame_rate")
    slide_time = positive(slide_time, "slide_time")
    tol = positive(tolerance, "tolerance")
    frictions = [positive(m, f"frictions[{i}]") for i, m in enumerate(frictions)]
    speeds = [positive(v, f"speeds[{i}]") for i, v in enumerate(speeds)]
    lean = real_number(lean_deg, "lean_deg")
    if not 0.0 <= lean < 45.0:
        raise InputError(f"lean_deg must be in [0, 45) degrees, got {lean!r}")
    sensor = chain.sensor
    t0 = time.perf_counter()
    guess = POSE_SCAN + np.radians([0.0, 0.0, lean - 9.0])  # second link at 50 deg, third at the lean
    start = finger.rmrc_lean(finger.forward(guess), lean, guess)
    theta_c, z_c, apex0 = start.theta, start.z, start.position
    runs = []
    paths = {}  # the stroke depends on the speed only: one RMRC path per speed
    cases = [(m, v) for m in frictions for v in speeds]
    index = 0
    for k, (mu, v) in enumerate(tqdm(cases, desc="surface scanning", unit="run", file=sys.stderr,
                                     disable=not progress)):
        rng = np.random.default_rng([seed, 11, k])
        mu_k = sliding_friction(mu, v, coefficient=speed_coefficient)
        prof = _scan_profile(mu_k, v, fn0, rate, slide_time, rng)
        n = len(prof["t"])
        if v not in paths:
            targets = apex0 + np.outer(prof["x"] - v * slide_time / 2.0, [1.0, 0.0, 0.0])
            paths[v] = finger.follow(targets, theta_c, z0=z_c, lean_deg=lean)
        rots, stage = paths[v]
        world = np.zeros((n, sensor.n_elements, 3))
        world[:, 0, 0] = -prof["ft"]  # friction opposes the apex's motion (+x)
        world[:, 0, 2] = prof["fn"]
        local = local_from_world(sensor, world, rots)
        est = chain.estimate(local, first_index=index, progress=progress, desc=f"mu {mu:g}, {v:g} mm/s")
        index += n
        west = world_from_local(sensor, est.forces, rots)[:, 0]
        fn_e, ft_e = west[:, 2], np.hypot(west[:, 0], west[:, 1])
        leans = np.degrees(np.arcsin(np.clip(rots[:, 0, 2], -1.0, 1.0)))
        run = {"friction": mu, "speed_mm_s": v, "mu_simulated": mu_k, "frames": n,
               "lean_deg": [float(leans.min()), float(leans.max())],
               "stage_travel_mm": float(np.ptp(stage))}
        try:
            fe = friction_coefficient(ft_e, fn_e, t=prof["t"])
            run.update(mu_estimated=fe.mean, mu_std=fe.std, mu_sem=fe.sem, error=fe.mean - mu_k,
                       within_tolerance=bool(abs(fe.mean - mu_k) <= tol), steady_s=[fe.t_start, fe.t_stop],
                       steady_samples=fe.n, clamped_fraction=float(est.clamped[fe.steady, 0].mean()),
                       tipped_fraction=float(est.tipped[fe.steady, 0].mean()),
                       local_ratio_steady=float(np.median(
                           np.hypot(local[fe.steady, 0, 0], local[fe.steady, 0, 1]) / local[fe.steady, 0, 2])))
            mu_series = fe.mu
        except InputError as exc:
            run.update(mu_estimated=None, error=None, within_tolerance=False, failure=str(exc))
            mu_series = np.where(fn_e > 0.2 * fn0, ft_e / np.where(fn_e > 0, fn_e, 1.0), 0.0)
        try:
            run["mu_truth_steady"] = friction_coefficient(prof["ft"], prof["fn"], t=prof["t"]).mean
        except InputError:
            run["mu_truth_steady"] = None
        run["series"] = {"t": rounded(prof["t"], 4), "fn_true": rounded(prof["fn"]),
                         "ft_true": rounded(prof["ft"]), "fn": rounded(fn_e), "ft": rounded(ft_e),
                         "mu": rounded(mu_series)}
        runs.append(run)
    ok = [r for r in runs if r["error"] is not None]
    summary = {"n_runs": len(runs), "n_within_tolerance": sum(r["within_tolerance"] for r in runs),
               "max_abs_error": max((abs(r["error"]) for r in ok), default=None),
               "max_abs_error_by_friction": {f"{m:g}": max((abs(r["error"]) for r in ok if r["friction"] == m),
                                                           default=None) for m in frictions}}
    return jsonable({"runs": runs, "summary": summary,
                      "settings": {"normal_force_n": fn0, "frame_rate_hz": rate, "slide_time_s": slide_time,
                                   "speed_coefficient": speed_coefficient, "tolerance": tol,
                                   "finger": finger.to_dict(), "chain": chain.describe(), "seed": seed},
                      "seconds": time.perf_counter() - t0})


def draw(fig, result: dict) -> None:
    """Fill ``fig`` from a :func:`surface_scanning` result: forces and μ over time per run, μ against speed."""
    runs = need(result, "runs")
    frictions = sorted({r["friction"] for r in runs})
    speeds = sorted({r["speed_mm_s"] for r in runs})
    axes = fig.subplots(len(frictions) + 1, len(speeds), squeeze=False)
    for r in runs:
        ax = axes[frictions.index(r["friction"]), speeds.index(r["speed_mm_s"])]
        s = r["series"]
        t = np.asarray(s["t"])
        ax.plot(t, s["fn_true"], color="0.6", lw=1, label="F_n true")
        ax.plot(t, s["fn"], color="tab:blue", lw=1.2, label="F_n est.")
        ax.plot(t, s["ft_true"], color="0.6", lw=1, ls="--", label="|F_t| true")
        ax.plot(t, s["ft"], color="tab:orange", lw=1.2, label="|F_t| est.")
        ax.set_xlabel("t (s)", fontsize=7)
        ax.set_ylabel("force (N)", fontsize=7)
        ax.tick_params(labelsize=6)
        ax2 = ax.twinx()
        ax2.plot(t, s["mu"], color="tab:green", lw=1, label="μ est.")
        ax2.axhline(r["mu_simulated"], color="tab:green", ls=":", lw=1)
        ax2.set_ylim(0.0, max(0.8, r["mu_simulated"] * 1.5))
        ax2.tick_params(labelsize=6, colors="tab:green")
        if r.get("steady_s"):
            ax.axvspan(*r["steady_s"], color="tab:green", alpha=0.1)
        est = "failed" if r["mu_estimated"] is None else f"{r['mu_estimated']:.3f}±{r['mu_std']:.3f}"
        ax.set_title(f"μ={r['friction']:g}, {r['speed_mm_s']:g} mm/s: sim {r['mu_simulated']:.3f}, est {est}",
                     fontsize=7)
    axes[0, 0].legend(fontsize=5, loc="upper left")
    for ax in axes[-1, 1:]:
        ax.remove()
    ax = axes[-1, 0]
    gs = ax.get_subplotspec().get_gridspec()
    ax.remove()
    ax = fig.add_subplot(gs[-1, :])
    for m in frictions:
        rs = [r for r in runs if r["friction"] == m and r["mu_estimated"] is not None]
        ax.errorbar([r["speed_mm_s"] for r in rs], [r["mu_estimated"] for r in rs],
                    yerr=[r["mu_std"] for r in rs], marker="o", capsize=3, label=f"est., μ={m:g}")
        rs = [r for r in runs if r["friction"] == m]
        ax.plot([r["speed_mm_s"] for r in rs], [r["mu_simulated"] for r in rs], "kx:", lw=1, ms=6)
    ax.set_xscale("log")
    ax.set_xticks(speeds, [f"{v:g}" for v in speeds])
    ax.minorticks_off()
    ax.set_xlim(min(speeds) / 1.5, max(speeds) * 1.5)
    ax.set_xlabel("speed (mm/s)")
    ax.set_ylabel("μ")
    ax.set_title("estimated (markers, ±1 sd) vs simulated (crosses) friction coefficient", fontsize=8)
    ax.legend(fontsize=6)
