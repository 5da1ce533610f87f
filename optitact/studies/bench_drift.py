"""Benchmark: a simulated hour of drift, read with a fixed baseline and with drift tracking.

Not library code: ``optitact bench drift`` runs it (:func:`drift_hour`).

The sensor runs for an hour on a robot while its no-load image drifts
(the scenario of the drift-tracking issue):

* the rim light dims by 3 % over the hour (linearly);
* the camera's black level steps up by 2 DN a third of the way in (at 20
  minutes of an hour);
* the camera creeps 0.3 px against the dome over the hour (linearly, at
  30 deg to the image rows);

while random contacts load the elements 30 % of the time: one or two random
elements per press, a normal force up to about 1 N with a shear of up to 25
% of it, ramped up and down over about a second; one press in the middle of
the run is held for 5 minutes (a quarter of a shorter run). Frames carry
camera noise (0.5 DN read noise and the CCD model's shot noise) and are
quantised to 8 bits.

Frames are cheap, consistent with a calibration: the no-load light is the
converged path-traced no-load frame of the default sensor for the camera
(:func:`optitact.render.background.noload_radiance`, cached; a synthetic rim
ring where the render extra is not installed), exposed with the CCD model's
conversion (DN per radiance unit); a contact adds a Gaussian spot on the dome
(drawn on the element's region pixels through the pipeline's own region
coordinates) whose integrated grey value is what the shipped calibration's
normal curve gives for the force and whose centroid is what its shear curve
gives for the shear. The whole image is blurred by a lens PSF (Gaussian, 0.7
px) and moved by the camera's shift (the PSF sampled at the shifted pixel
centres: exact for any sub-pixel shift). A calibration is then fitted
(:meth:`optitact.calib.fit.Calibration.fit`, coupled model) on 150 frames of
these spots without drift, so the no-drift run's force error is the noise's
and the fit's, small and honest.

Three runs read the same frames (the same seed, contacts and noise draws):
``no_drift`` (no drift, fixed baseline), ``fixed`` (drift, fixed baseline:
no tracking) and ``tracked`` (drift, :class:`optitact.pipeline.drift.DriftTracker`);
``no_drift_tracked`` reads the no-drift frames through a tracker too (its
readings should be the plain pipeline's, bit for bit).
"""

from __future__ import annotations

import math
import sys
import time

import numpy as np

from optitact._validate import integer, positive
from optitact.errors import InputError

__all__ = ["CONTACT_DUTY", "DRIFT", "drift_hour"]

#: The drift over an hour: rim light (relative), black-level step (DN) and when (fraction of the run),
#: camera creep (px) and its direction (deg from the image rows, towards increasing rows).
DRIFT = {"gain": -0.03, "black_step_dn": 2.0, "black_step_at": 1.0 / 3.0, "shift_px": 0.3,
         "shift_deg": 30.0}
#: Fraction of the time with at least one element pressed.
CONTACT_DUTY = 0.30
#: Camera: dark level (DN), read noise (DN), DN per photo-electron (shot noise), lens PSF sigma (px).
DARK_DN, READ_NOISE_DN, DN_PER_ELECTRON, PSF_PX = 4.0, 0.5, 251.0 / 20000.0, 0.7
#: DN per radiance unit of the no-load render (the CCD model's exposure times its conversion gain).
DN_PER_RADIANCE = 25000.0 * DN_PER_ELECTRON
#: Frames of the no-load baseline stack (default); frames of the calibration set.
BASELINE_FRAMES, CALIBRATION_FRAMES = 64, 150
#: Loads (N) above which an element read without contact counts as a missed contact.
MISSED_N = 0.05
#: Force full scale the errors are given in % of (N).
FULL_SCALE_N = 1.0


# ----------------------------------------------------------------------------- the frames
def _noload_light(sensor, camera, background: str) -> tuple[np.ndarray, str]:
    """The no-load light above the dark level (DN, before the lens PSF), and what it is."""
    if background in ("auto", "rendered"):
        try:
            from optitact.render.background import noload_radiance

            rad = noload_radiance(sensor, camera)
            return np.asarray(rad, np.float64) * DN_PER_RADIANCE, "rendered"
        except ImportError:
            if background == "rendered":
                raise
    # synthetic: the rim light seen as a thin ring at the edge of the dome's view (4 DN per pixel of its
    # length, about the light of the rendered one) and a faint one inside it (1.5 DN), splatted
    # bilinearly from a dense circle of dome points
    theta = camera.max_polar_angle(sensor) - 1e-3
    out = np.zeros(camera.shape)
    h, w = camera.shape
    for polar, level in ((theta, 4.0), (0.9 * theta, 1.5)):
        n = int(20 * 2 * np.pi * max(h, w))
        phi = np.linspace(0.0, 2.0 * np.pi, n, endpoint=False)
        r = sensor.outer_radius
        pts = np.stack([r * math.sin(polar) * np.cos(phi), r * math.sin(polar) * np.sin(phi),
                        np.full(n, r * math.cos(polar))], axis=-1)
        px = camera.project(pts, sensor, outside="nan")
        px = px[np.isfinite(px).all(axis=1)]
        step = np.hypot(*np.diff(px, axis=0).T).mean() if len(px) > 1 else 0.0
        r0, c0 = np.floor(px).astype(int).T
        fr, fc = px[:, 0] - r0, px[:, 1] - c0
        for dr, dc, wgt in ((0, 0, (1 - fr) * (1 - fc)), (0, 1, (1 - fr) * fc), (1, 0, fr * (1 - fc)),
                            (1, 1, fr * fc)):
            rr, cc = r0 + dr, c0 + dc
            ok = (rr >= 0) & (rr < h) & (cc >= 0) & (cc < w)
            np.add.at(out, (rr[ok], cc[ok]), level * step * wgt[ok])
    return out, "synthetic"


def _psf(shift: float, radius: int = 4) -> np.ndarray:
    """The lens PSF along one axis sampled at pixel offsets moved by ``shift`` px, as a correlation kernel."""
    x = np.arange(-radius, radius + 1) - shift
    k = np.exp(-0.5 * (x / PSF_PX) ** 2)
    return (k / k.sum())[::-1].copy()


def _expose(light: np.ndarray, gain: float, dark: float, shift: tuple[float, float],
            z: np.ndarray) -> np.ndarray:
    """An 8-bit frame: the light times ``gain``, blurred and moved by ``shift`` (x, y px), dark and noise added.

    ``z`` holds the noise's standard normal draws (the same draws give the three runs the same noise).
    """
    import cv2

    seen = cv2.sepFilter2D(light, cv2.CV_64F, _psf(shift[0]), _psf(shift[1]), borderType=cv2.BORDER_CONSTANT)
    seen *= gain
    sigma = np.sqrt(READ_NOISE_DN**2 + DN_PER_ELECTRON * np.maximum(seen, 0.0))
    return np.clip(np.rint(dark + seen + sigma * z), 0, 255).astype(np.uint8)


class _Spots:
    """Gaussian spots on the dome for element forces, consistent with the shipped calibration's curves."""

    def __init__(self, pipe, sensor) -> None:
        from optitact.calib.shipped import default_calibration

        self.cal = default_calibration()
        fold = pipe.region_weights
        area, wx, wy = fold.weights
        ok = area > 0
        self.pixel, self.label = fold.pixel[ok], fold.label[ok]
        self.x, self.y = wx[ok] / area[ok], wy[ok] / area[ok]
        self.by_element = [np.flatnonzero(self.label == e) for e in range(sensor.n_elements)]
        self.shape = pipe.camera.shape
        self.n_el = sensor.n_elements

    def targets(self, forces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The G (grey level x mm^2) and centroid (mm) the curves give for forces ``(..., E, 3)``."""
        from optitact.calib.curves import grey_for_force

        cal = self.cal
        fz = np.maximum(forces[..., 2], 1e-6)
        a, b = cal.f[:, 0], cal.f[:, 1]
        u = forces[..., :2] * ((a + b * np.sqrt(fz)) / fz)[..., None]
        G = grey_for_force(cal, fz, u)
        G = np.where(forces[..., 2] > 0, G, 0.0)
        return np.nan_to_num(G), np.where(forces[..., 2:3] > 0, u, 0.0)

    def image(self, forces: np.ndarray) -> np.ndarray:
        """The spots' light (DN above dark, before the PSF) for element forces ``(E, 3)``."""
        out = np.zeros(self.shape[0] * self.shape[1])
        loaded = np.flatnonzero(forces[:, 2] > 0)
        if not len(loaded):
            return out.reshape(self.shape)
        G, u = self.targets(_pad(forces, loaded))
        for e in loaded:
            idx = self.by_element[e]
            sig = 0.35 * math.sqrt(1.0 + float(forces[e, 2]))  # the spot widens with the load (mm)
            amp = G[e] / (2.0 * math.pi * sig**2)
            r2 = (self.x[idx] - u[e, 0]) ** 2 + (self.y[idx] - u[e, 1]) ** 2
            out[self.pixel[idx]] += amp * np.exp(-0.5 * r2 / sig**2)
        return out.reshape(self.shape)


def _pad(forces: np.ndarray, loaded: np.ndarray) -> np.ndarray:
    """The forces with only ``loaded`` kept (the curves are per element: the others read nothing)."""
    out = np.zeros_like(forces)
    out[loaded] = forces[loaded]
    return out


# ----------------------------------------------------------------------------- the scenario
def _schedule(n: int, fps: float, n_el: int, rng) -> tuple[np.ndarray, dict]:
    """Element forces ``(n, E, 3)`` of the random contacts, and the held press's element and frames."""
    duration = n / fps
    forces = np.zeros((n, n_el, 3))
    busy_until = np.full(n_el, -1.0)
    t_frames = np.arange(n) / fps
    hold = min(300.0, 0.25 * duration)
    h_el = int(rng.integers(n_el))
    h_start = 0.55 * duration
    events = [(h_start, [h_el], 0.6, np.array([0.05, -0.03]), 1.0, hold, 1.0)]
    busy_until[h_el] = h_start + hold + 2.0
    mean_press = 1.0 + 11.5 + 1.0
    mean_gap = mean_press * (1.0 - CONTACT_DUTY) / CONTACT_DUTY
    t = float(rng.exponential(mean_gap / 2))
    while t < duration:
        up, down = rng.uniform(0.5, 1.5, 2)
        held = rng.uniform(3.0, 20.0)
        k = 1 if rng.random() < 0.7 else 2
        free = [e for e in range(n_el) if busy_until[e] < t and not (e == h_el and t < busy_until[h_el])]
        if len(free) >= k:
            els = [int(e) for e in rng.choice(free, k, replace=False)]
            fz = float(rng.uniform(0.1, 1.0))
            ang = rng.uniform(0.0, 2.0 * np.pi)
            ratio = 0.25 * math.sqrt(rng.random())
            shear = fz * ratio * np.array([math.cos(ang), math.sin(ang)])
            events.append((t, els, fz, shear, up, held, down))
            busy_until[els] = t + up + held + down + 1.0
        t += up + held + down + float(rng.exponential(mean_gap))
    for t0, els, fz, shear, up, held, down in events:
        env = np.clip(np.minimum((t_frames - t0) / up, (t0 + up + held + down - t_frames) / down), 0.0, 1.0)
        env = np.where(env > 0, env, 0.0)
        for e in els:
            forces[:, e, 2] += env * fz
            forces[:, e, :2] += env[:, None] * shear
    held_frames = np.flatnonzero((t_frames >= h_start + 1.0) & (t_frames <= h_start + 1.0 + hold))
    return forces, {"element": h_el, "frames": held_frames, "seconds": hold, "force_n": 0.6}


def _drift(t: np.ndarray, duration: float, hours: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Gain, dark level (DN) and shift (x, y px) at times ``t`` of a run of ``duration`` s.

    The run drifts as ``hours`` of the scenario do (its hourly drift times ``hours``, spread evenly
    over the run); the black-level step comes at its fraction of the run.
    """
    frac = t / duration * hours
    gain = 1.0 + DRIFT["gain"] * frac
    dark = DARK_DN + DRIFT["black_step_dn"] * (t >= DRIFT["black_step_at"] * duration)
    ang = math.radians(DRIFT["shift_deg"])
    s = DRIFT["shift_px"] * frac
    return gain, dark, np.stack([s * math.cos(ang), s * math.sin(ang)], axis=-1)


# ----------------------------------------------------------------------------- the scores
def _scores(est: np.ndarray, contact: np.ndarray, truth: np.ndarray, bins: np.ndarray) -> dict:
    """Force errors over loaded elements, false and missed contacts, in all and per time bin."""
    loaded = truth[..., 2] > 0
    err = est - truth
    false = contact & ~loaded
    missed = ~contact & (truth[..., 2] >= MISSED_N)

    def rmse(sel, axis):
        return float(np.sqrt(np.mean(err[..., axis][sel] ** 2))) if sel.any() else float("nan")

    out = {"fz_rmse_n": rmse(loaded, 2), "fx_rmse_n": rmse(loaded, 0), "fy_rmse_n": rmse(loaded, 1)}
    out.update({f"{k[:2]}_rmse_pct_fs": 100.0 * v / FULL_SCALE_N for k, v in list(out.items())})
    out["loaded_element_frames"] = int(loaded.sum())
    out["false_contacts"] = int(false.sum())
    out["frames_with_false_contact"] = int(false.any(axis=1).sum())
    out["missed_contacts"] = int(missed.sum())
    per = []
    for b in range(int(bins.max()) + 1):
        sel = bins == b
        lb = loaded & sel[:, None]
        per.append({"fz_rmse_n": rmse(lb, 2), "false_contacts": int(false[sel].sum()),
                    "missed_contacts": int(missed[sel].sum())})
    out["bins"] = per
    return out


# ----------------------------------------------------------------------------- the run
def drift_hour(*, minutes: float = 60.0, fps: float = 1.0, width: int = 320, height: int = 240, seed: int = 0,
               progress: bool = False, plot=None, background: str = "auto", bin_minutes: float = 5.0,
               min_pixels: float = 6.0, drift_hours: float | None = None,
               tracker_options: dict | None = None, baseline_frames: int = BASELINE_FRAMES) -> dict:
    """``optitact bench drift``: an hour of drift read with a fixed baseline and with drift tracking.

    Parameters
    ----------
    minutes : float
        Length of the run (default 60). The drift goes on at its hourly rates
        (a shorter run drifts less); the black-level step comes a third of the
        way in and the held press lasts 5 minutes or a quarter of the run.
    fps : float
        Frames per second (default 1: 3600 frames an hour, each read three ways).
    width, height : int
        The camera's frames (default 320 x 240, ``FisheyeCamera``).
    seed : int
        Seed of the contacts and the noise (``numpy.random.default_rng``).
    progress : bool
        A progress bar on stderr.
    plot : path, optional
        Write a PNG of the Fz error and the contact flags over time for the
        three runs, and of the tracked drift against the truth.
    background : {"auto", "rendered", "synthetic"}
        The no-load light: the path-traced no-load frame (the render extra;
        cached after the first run, about 10 s at 320 x 240), or a synthetic
        rim ring; ``"auto"``: rendered when it can be.
    bin_minutes : float
        Width of the time bins of the error over time (default 5).
    drift_hours : float, optional
        Spread this many hours of the scenario's drift over the run (a short
        test run that drifts as much as an hour); default the run's own length
        (the drift at its real rates).
    tracker_options : dict, optional
        Keyword options of the :class:`~optitact.pipeline.drift.DriftTracker`
        (e.g. a shorter ``smooth`` for drift compressed into a short run).
    baseline_frames : int
        Frames of the no-load stack the baseline is the mean of (default 64,
        about a second at 60 fps): its noise is what the tracker cannot tell
        from drift; the rim's light in it, which the gain is measured against,
        is known to about 0.4 % rms from 16 frames at 320 x 240 and 0.2 % from
        64, and a gain error of that size is an Fz error of that size.
    min_pixels : float
        The pipeline's contact floor (:class:`~optitact.pipeline.frame_pipeline.Pipeline`),
        default 6: with the default 3, the noise of these frames alone (0.5 DN
        read noise, shot noise, 8 bits) makes about one false contact per
        10 000 element-frames, which would hide whether drift makes any.

    Returns
    -------
    dict
        JSON-ready: ``runs`` (``no_drift``, ``fixed``, ``tracked``: Fz, Fx, Fy
        RMSE over loaded elements in N and % of 1 N full scale, false and
        missed contacts, and per bin), ``ratio_tracked_to_no_drift`` (Fz RMSE),
        ``bar`` (the issue's: the ratio at most 1.2 with no false contact
        from the drift, i.e. none that the no-drift run, whose noise alone
        makes a rare one, does not have on the same frame; and whether it is
        met), ``prevented`` (the fixed baseline's error and
        false contacts that tracking removes), ``held_press`` (its Fz error
        at the end of the hold, per run), ``tracker`` (the tracked drift
        against the truth per bin, flags, per-frame costs), ``no_drift_tracked``
        (whether a tracker on the no-drift frames changed any reading),
        ``calibration`` (its fit residuals), ``scenario`` and ``seconds``.
    """
    from tqdm import tqdm

    from optitact.calib.fit import Calibration
    from optitact.optics.camera import FisheyeCamera
    from optitact.optics.sensor import DomeSensor
    from optitact.pipeline.drift import DriftTracker
    from optitact.pipeline.frame_pipeline import Pipeline

    minutes = positive(minutes, "minutes")
    fps = positive(fps, "fps")
    width, height = integer(width, "width", minimum=64), integer(height, "height", minimum=48)
    seed = integer(seed, "seed", minimum=0)
    baseline_frames = integer(baseline_frames, "baseline_frames", minimum=2)
    bin_minutes = positive(bin_minutes, "bin_minutes")
    if background not in ("auto", "rendered", "synthetic"):
        raise InputError(f"background must be 'auto', 'rendered' or 'synthetic', got {background!r}")
    t_start = time.perf_counter()
    sensor, camera = DomeSensor.default(), FisheyeCamera(width=width, height=height)
    n_el = sensor.n_elements
    n = max(int(round(minutes * 60.0 * fps)), 2)
    duration = n / fps
    rng = np.random.default_rng(seed)
    light, kind = _noload_light(sensor, camera, background)
    # the no-load baseline: a stack at the start (no drift yet)
    shape = camera.shape
    base_rng = np.random.default_rng([seed, 1])
    stack = np.stack([_expose(light, 1.0, DARK_DN, (0.0, 0.0), base_rng.standard_normal(shape))
                      for _ in range(baseline_frames)])
    pipe = Pipeline.from_noload(sensor, camera, stack, min_pixels=min_pixels)
    spots = _Spots(pipe, sensor)
    # a calibration fitted on these spots without drift
    cal_rng = np.random.default_rng([seed, 2])
    cal_forces = np.zeros((CALIBRATION_FRAMES, n_el, 3))
    cal_forces[..., 2] = cal_rng.uniform(0.03, 1.1, (CALIBRATION_FRAMES, n_el))
    ang = cal_rng.uniform(0, 2 * np.pi, (CALIBRATION_FRAMES, n_el))
    ratio = 0.3 * np.sqrt(cal_rng.random((CALIBRATION_FRAMES, n_el)))
    cal_forces[..., 0] = cal_forces[..., 2] * ratio * np.cos(ang)
    cal_forces[..., 1] = cal_forces[..., 2] * ratio * np.sin(ang)
    cal_frames = np.stack([_expose(light + spots.image(f), 1.0, DARK_DN, (0.0, 0.0),
                                   cal_rng.standard_normal(shape)) for f in cal_forces])
    cal = Calibration.fit(pipe.process(cal_frames), cal_forces, sensor=sensor, camera=camera,
                          pipeline_options=pipe.options(), model="coupled",
                          provenance={"source": "bench drift: synthetic spots", "seed": seed})
    t_setup = time.perf_counter() - t_start
    # the scenario
    forces, held = _schedule(n, fps, n_el, rng)
    t = np.arange(n) / fps
    hours = duration / 3600.0 if drift_hours is None else positive(drift_hours, "drift_hours")
    gain, dark, shift = _drift(t, duration, hours)
    bin_s = bin_minutes * 60.0
    bins = np.minimum((t // bin_s).astype(int), max(int(math.ceil(duration / bin_s)) - 1, 0))
    options = {"fps": fps, **(tracker_options or {})}
    tracker = DriftTracker(pipe, **options)
    quiet = DriftTracker(pipe, **options)
    names = ("no_drift", "fixed", "tracked")
    est = {k: np.zeros((n, n_el, 3)) for k in names}
    contact = {k: np.zeros((n, n_el), bool) for k in names}
    states = []
    cost = {"pipeline": np.zeros(n), "tracker": np.zeros(n)}
    identical = True
    noise_rng = np.random.default_rng([seed, 3])
    for i in tqdm(range(n), desc="drift hour", unit="frame", file=sys.stderr, disable=not progress,
                  leave=False):
        z = noise_rng.standard_normal(shape)
        lit = light + spots.image(forces[i])
        clean = _expose(lit, 1.0, DARK_DN, (0.0, 0.0), z)
        drifted = _expose(lit, float(gain[i]), float(dark[i]), tuple(shift[i]), z)
        r_a = pipe.process(clean)
        c0 = time.perf_counter()
        r_b = pipe.process(drifted)
        c1 = time.perf_counter()
        r_c, state = tracker.process(drifted, t=float(t[i]))
        c2 = time.perf_counter()
        cost["pipeline"][i], cost["tracker"][i] = c1 - c0, c2 - c1
        r_q, _ = quiet.process(clean, t=float(t[i]))
        identical &= (np.array_equal(r_q.G, r_a.G) and np.array_equal(r_q.u, r_a.u)
                      and np.array_equal(r_q.contact, r_a.contact))
        for k, r in zip(names, (r_a, r_b, r_c), strict=True):
            f, _ = cal.forces(r)
            est[k][i], contact[k][i] = f, r.contact
        states.append(state)
    runs = {k: _scores(est[k], contact[k], forces, bins) for k in names}
    a, b, c = (runs[k] for k in names)
    loaded = forces[..., 2] > 0
    # false contacts of the tracked run that the no-drift run does not have (same frames, same noise)
    drift_false = int((contact["tracked"] & ~loaded & ~contact["no_drift"]).sum())
    ratio_c = c["fz_rmse_n"] / a["fz_rmse_n"] if a["fz_rmse_n"] > 0 else float("nan")
    hf = held["frames"]
    he = held["element"]
    held_out = {k: {"fz_error_end_n": float(est[k][hf[-1], he, 2] - forces[hf[-1], he, 2]) if len(hf) else None,
                    "fz_rmse_n": float(np.sqrt(np.mean((est[k][hf, he, 2] - forces[hf, he, 2]) ** 2)))
                    if len(hf) else None} for k in names}
    g_est = np.array([s.gain for s in states])
    o_est = np.array([s.offset for s in states])
    sx_est = np.array([s.shift_x for s in states])
    sy_est = np.array([s.shift_y for s in states])
    flags = np.array([s.flag for s in states])
    true_offset = dark - gain * DARK_DN
    per_bin = []
    for bi in range(int(bins.max()) + 1):
        last = np.flatnonzero(bins == bi)[-1]
        per_bin.append({"minute": float(t[last] / 60.0), "gain": float(g_est[last]),
                        "gain_true": float(gain[last]),
                        "offset": float(o_est[last]), "offset_true": float(true_offset[last]),
                        "shift_x": float(sx_est[last]), "shift_y": float(sy_est[last]),
                        "shift_x_true": float(shift[last, 0]), "shift_y_true": float(shift[last, 1])})
    estimated = np.array([s.estimated for s in states])
    ms = {k: v * 1e3 for k, v in cost.items()}
    result = {
        "runs": runs,
        "ratio_tracked_to_no_drift": float(ratio_c),
        "ratio_fx_fy": {ax: (c[f"{ax}_rmse_n"] / a[f"{ax}_rmse_n"]) for ax in ("fx", "fy")},
        "bar": {"ratio_at_most": 1.2, "drift_false_contacts_at_most": 0, "drift_false_contacts": drift_false,
                "met": bool(ratio_c <= 1.2 and drift_false == 0)},
        "prevented": {"fz_rmse_n": b["fz_rmse_n"] - c["fz_rmse_n"],
                      "fz_rmse_ratio_fixed_to_tracked": b["fz_rmse_n"] / c["fz_rmse_n"],
                      "false_contacts": b["false_contacts"] - c["false_contacts"],
                      "missed_contacts": b["missed_contacts"] - c["missed_contacts"]},
        "held_press": {"element": he, "seconds": held["seconds"], "force_n": held["force_n"], **held_out},
        "tracker": {"bins": per_bin, "flagged_frames": int(flags.sum()),
                    "reasons": sorted({s.reason for s in states if s.flag}),
                    "corrected_frames": int(sum(s.corrected for s in states)),
                    "corrections": tracker.corrections,
                    "final": {"gain": float(g_est[-1]), "gain_true": float(gain[-1]),
                              "offset": float(o_est[-1]), "offset_true": float(true_offset[-1]),
                              "shift_x": float(sx_est[-1]), "shift_y": float(sy_est[-1]),
                              "shift_true": [float(shift[-1, 0]), float(shift[-1, 1])]},
                    "ms_per_frame": {"pipeline_median": float(np.median(ms["pipeline"])),
                                     "tracker_median": float(np.median(ms["tracker"])),
                                     "tracker_p99": float(np.percentile(ms["tracker"], 99)),
                                     "tracker_max": float(ms["tracker"].max()),
                                     "tracker_estimating_median": float(np.median(ms["tracker"][estimated]))
                                     if estimated.any() else None,
                                     "estimates": int(estimated.sum())},
                    "camera": f"{width}x{height}"},
        "no_drift_tracked": {"identical_to_plain": bool(identical),
                             "corrected_frames": int(quiet.state.corrected)},
        "calibration": {"fz_residual_n": float(np.median(cal.residuals["fz"])),
                        "fx_residual_n": float(np.median(cal.residuals["fx"])),
                        "frames": CALIBRATION_FRAMES},
        "scenario": {"minutes": float(duration / 60.0), "fps": fps, "frames": n, "seed": seed,
                     "width": width, "height": height, "background": kind, "drift_per_hour": dict(DRIFT),
                     "drift_hours": hours, "tracker_options": dict(tracker_options or {}),
                     "black_step_minute": float(DRIFT["black_step_at"] * duration / 60.0),
                     "contact_time_fraction": float((forces[..., 2] > 0).any(axis=1).mean()),
                     "read_noise_dn": READ_NOISE_DN, "baseline_frames": baseline_frames,
                     "min_pixels": min_pixels,
                     "bin_minutes": bin_minutes},
        "seconds": {"setup": round(t_setup, 2), "total": round(time.perf_counter() - t_start, 2)},
    }
    if plot is not None:
        result["plot"] = str(_plot(result, t, est, contact, forces, (g_est, o_est, sx_est, sy_est),
                                   (gain, true_offset, shift), plot))
    return result


# ----------------------------------------------------------------------------- the figure
def _plot(result: dict, t, est, contact, truth, tracked, true, path):
    """Fz error and false contacts over time for the three runs, and the tracked drift against the truth."""
    from optitact._optional import require
    from optitact.io.files import atomic_write_png_figure

    require("matplotlib", purpose="the drift plot")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    minute = t / 60.0
    step = max(1, int(round(60.0 / max(t[1] - t[0], 1e-9))))  # one point a minute
    edges = np.arange(0, len(t) + step, step)
    starts = minute[np.minimum(edges[:-1], len(t) - 1)]
    loaded = truth[..., 2] > 0
    colours = {"no_drift": "tab:green", "fixed": "tab:red", "tracked": "tab:blue"}
    labels = {"no_drift": "no drift, fixed baseline", "fixed": "drift, fixed baseline",
              "tracked": "drift, tracked"}
    scen = result["scenario"]
    held = result["held_press"]
    h0 = minute[np.flatnonzero(truth[:, held["element"], 2] >= 0.99 * held["force_n"])]
    fig, axes = plt.subplots(3, 1, figsize=(10, 9.5), sharex=True)
    for a in axes:
        a.axvline(scen["black_step_minute"], color="0.5", ls="--", lw=0.8)
        if len(h0):
            a.axvspan(h0[0], h0[-1], color="0.85", zorder=0)
    ax = axes[0]
    for k, col in colours.items():
        pts, xs = [], []
        for x0, a, b in zip(starts, edges[:-1], edges[1:], strict=False):
            sel = loaded[a:b]
            if sel.any():
                e = (est[k][a:b, :, 2] - truth[a:b, :, 2])[sel]
                pts.append(1000.0 * math.sqrt(float(np.mean(e**2))))
                xs.append(x0 + 0.5 * step * (t[1] - t[0]) / 60.0)
        ax.plot(xs, pts, "-", color=col, lw=1.2, label=f"{labels[k]} "
                f"(RMSE {1000 * result['runs'][k]['fz_rmse_n']:.1f} mN)")
    ax.set_ylabel("Fz RMSE over loaded elements\n(mN, per minute)")
    ax.set_yscale("log")
    ax.legend(fontsize=8, loc="upper left")
    gain_pct = 100 * DRIFT["gain"] * scen["drift_hours"]
    creep = DRIFT["shift_px"] * scen["drift_hours"]
    title = (f"simulated {scen['minutes']:.0f} min: rim light {gain_pct:+.1f} %, black level "
             f"+{DRIFT['black_step_dn']:g} DN at {scen['black_step_minute']:.0f} min (dashed), creep "
             f"{creep:.2f} px; tracked / no drift = {result['ratio_tracked_to_no_drift']:.2f}; "
             f"grey: the press held {held['seconds'] / 60:.0f} min")
    ax.set_title(title, fontsize=9)
    bx = axes[1]
    for k, col in colours.items():
        false = (contact[k] & ~loaded).sum(axis=1)
        per = [int(false[a:b].sum()) for a, b in zip(edges[:-1], edges[1:], strict=False)]
        bx.step(starts, per, where="post", color=col, lw=1.2,
                label=f"{labels[k]} ({result['runs'][k]['false_contacts']} in all)")
    bx.set_ylabel("false contacts\n(element-frames per minute)")
    bx.set_yscale("symlog", linthresh=1)
    bx.set_ylim(-0.2, None)
    bx.legend(fontsize=8, loc="upper left")
    cx = axes[2]
    g, o, sx, sy = tracked
    tg, to, ts = true
    cx.plot(minute, 100 * (g - 1), color="tab:orange", lw=1.2, label="gain - 1 (%), tracked")
    cx.plot(minute, 100 * (tg - 1), color="tab:orange", lw=1, ls=":", label="gain - 1 (%), true")
    cx.plot(minute, o, color="tab:purple", lw=1.2, label="offset (DN), tracked")
    cx.plot(minute, to, color="tab:purple", lw=1, ls=":", label="offset (DN), true")
    cx.plot(minute, 10 * np.hypot(sx, sy), color="tab:brown", lw=1.2, label="shift x 10 (px), tracked")
    cx.plot(minute, 10 * np.hypot(ts[:, 0], ts[:, 1]), color="tab:brown", lw=1, ls=":",
            label="shift x 10 (px), true")
    cx.set_ylabel("drift model")
    cx.set_xlabel("minutes")
    cx.legend(fontsize=8, ncol=3, loc="lower left")
    for a in axes:
        a.grid(alpha=0.3)
    fig.tight_layout()
    out = atomic_write_png_figure(fig, path)
    plt.close(fig)
    return out
