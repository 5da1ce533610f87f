"""The ``finger`` study: the dome sensor on a 3-DOF finger, friction scanning, slip and contour tracing.

The three published experiments of the sensor's inventors, run through the
simulated chain (:class:`optitact.finger.chain.ChainSimulator`: every force is
estimated from rendered frames, never read from the simulation):

* :func:`optitact.studies.finger_scanning.surface_scanning` -- friction
  coefficients of flat specimens;
* :func:`optitact.studies.finger_slip.slip_experiment` -- slip detection
  while dragging a block around a rectangle;
* :func:`optitact.studies.finger_contour.contour_tracing` and
  :func:`~optitact.studies.finger_contour.joint_error_study` -- tracing a
  cylinder and a box on a table.

``optitact.studies.run("finger", seed=0, size="quick")`` runs all three
(:func:`experiment`), ``optitact.studies.save_plot("finger", result, path)``
draws them in one figure (:func:`draw`).
"""

from __future__ import annotations

import time

from optitact._validate import integer, positive
from optitact.errors import InputError
from optitact.finger.chain import ChainSimulator
from optitact.studies import finger_contour, finger_scanning, finger_slip
from optitact.studies._finger_common import chain_for, need, study_seed
from optitact.studies._protocol import Study

__all__ = ["STUDY", "experiment", "extended_calibration", "draw"]


def extended_calibration(*, mu_max: float = 0.40, frames: int = 100, spp: int = 64, seed: int = 0,
                         progress: bool = False):
    """A calibration of the default sensor and camera whose shear range reaches ``mu_max`` (cached).

    The shipped calibration's design stops at ``|F_t| / F_z`` = 0.35 and
    clamps centroid shifts beyond its fitted range, which caps an estimated
    friction coefficient at about 0.38 (at 0.1 N). This generates a set
    like the shipped one (:func:`optitact.calib.sets.generate`, two-stage
    transport, ``Design(mu_max=mu_max)``), fits the coupled model and keeps
    the JSON in the cache folder; later calls load it (about 30 s the
    first time once the two-stage table is cached).
    """
    from optitact import calib

    from optitact.io.cache import cache_dir

    mu_max = positive(mu_max, "mu_max")
    frames = integer(frames, "frames", minimum=8)
    path = cache_dir() / "finger" / f"calibration_mu{mu_max:g}_f{frames}_spp{spp}_s{seed}.json"
    if path.is_file():
        return calib.Calibration.load(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    store = path.with_suffix(".zarr")
    cset = calib.generate(store, frames=frames, spp=spp, seed=seed, design=calib.Design(mu_max=mu_max),
                          progress=progress)
    cal = calib.fit(cset, model="coupled")
    cal.save(path)
    return cal


def experiment(*, seed: int = 0, full: bool = False, progress: bool = True,
               chain: ChainSimulator | None = None, calibration=None) -> dict:
    """The three finger experiments through the real chain: surface scanning, slip, contour tracing.

    :func:`optitact.studies.run` calls this with the default chain; call it
    directly for another chain or calibration.

    Parameters
    ----------
    seed : int
        Seeds everything (the chain's frames, the force models, the slip onsets).
    full : bool
        Published sizes (3 frictions x 3 speeds, 2.5 s strokes at 20 Hz; two laps with 12 slips;
        cylinder and box, and the joint-error study): about three minutes on 2 CPU cores at
        640x480, 32 spp. Otherwise a quick run
        (the three frictions at 6.2 mm/s with 1.2 s strokes at 10 Hz; one lap with 4 slips; the
        cylinder only, a shorter span), about 35 seconds.
    progress : bool
        tqdm bars on stderr.
    chain : ChainSimulator, optional
        Default ``ChainSimulator(calibration, seed=seed)`` (640x480, 32 spp).
    calibration : Calibration or "extended", optional
        For the default chain: the shipped calibration (None), one of yours,
        or ``"extended"`` (:func:`extended_calibration`: the shipped design
        widened to ``|F_t| / F_z`` <= 0.40, made and cached on first use).

    Returns
    -------
    dict
        JSON-ready: ``surface_scanning``, ``slip``, ``contour_tracing`` (see the three studies),
        with ``full`` also ``joint_error_study``; ``seed``, ``full``, ``seconds``.
    """
    seed = study_seed(seed)
    t0 = time.perf_counter()
    if chain is None:
        if isinstance(calibration, str):
            if calibration != "extended":
                raise InputError(f"calibration must be a Calibration, None or 'extended', got {calibration!r}")
            calibration = extended_calibration(progress=progress)
        chain = ChainSimulator(calibration, seed=seed)
    elif calibration is not None:
        raise InputError("give chain or calibration, not both (the chain has its calibration)")
    chain = chain_for(chain, seed)
    study = None
    if full:
        scan = finger_scanning.surface_scanning(chain=chain, seed=seed, progress=progress)
        slip = finger_slip.slip_experiment(chain=chain, laps=2, n_slips=12, seed=seed, progress=progress)
        trace = finger_contour.contour_tracing(chain=chain, seed=seed, progress=progress)
        study = finger_contour.joint_error_study(chain=chain, baseline=trace, seed=seed, progress=progress)
    else:
        scan = finger_scanning.surface_scanning(chain=chain, speeds=(6.2,), slide_time=1.2, frame_rate=10.0,
                                                seed=seed, progress=progress)
        slip = finger_slip.slip_experiment(chain=chain, rectangle=(24.0, 16.0), n_slips=4, seed=seed,
                                           progress=progress)
        trace = finger_contour.contour_tracing(chain=chain, objects=("cylinder",), span=8.0, max_frames=60,
                                               seed=seed, progress=progress)
    out = {"surface_scanning": scan, "slip": slip, "contour_tracing": trace, "seed": seed, "full": bool(full),
           "seconds": time.perf_counter() - t0}
    if study is not None:
        out["joint_error_study"] = study
    return out


def _run(seed: int, *, full: bool, progress: bool) -> dict:
    return experiment(seed=seed, full=full, progress=progress)


#: Rows of the surface-scanning panel: one per friction (3 in both sizes) and the μ-against-speed row.
_SCAN_ROWS = 4


def draw(fig, result: dict) -> None:
    """Fill ``fig`` from a ``finger`` result: scanning, slip and contour tracing (with the joint errors)."""
    scan = need(result, "surface_scanning")
    n_rows = len({r["friction"] for r in need(scan, "runs")}) + 1
    top, mid, bottom = fig.subfigures(3, 1, height_ratios=[2.4 * n_rows, 4, 5])
    finger_scanning.draw(top, scan)
    finger_slip.draw(mid, need(result, "slip"))
    finger_contour.draw(bottom, need(result, "contour_tracing"), result.get("joint_error_study"))
    fig.suptitle(f"robotic finger with the dome sensor (seed {result.get('seed')}, full={result.get('full')})")


def key_figures(result: dict) -> list[tuple]:
    """Friction against the tolerance, slip detection, contour deviations (ideal, and with joint error)."""
    scan, slip, trace = result["surface_scanning"], result["slip"], result["contour_tracing"]
    pub = result["published"]
    summary, scores = scan["summary"], slip["scores"]
    rows = [("friction runs within tolerance", f"{summary['n_within_tolerance']} of {summary['n_runs']}",
             f"+-{pub['surface_scanning']['tolerance']}"),
            ("friction: largest error", summary["max_abs_error"], None),
            ("slip: precision / recall", [scores["precision"], scores["recall"]], None),
            ("slip: mean delay (s)", scores["mean_delay_s"], None),
            ("slip: false alarms", scores["false_alarms"], None)]
    published = pub["contour_tracing"]["max_deviation_mm"]
    for name, obj in trace["objects"].items():
        rows.append((f"contour {name}: max deviation, ideal finger (mm)",
                     obj["max_deviation_except_corners_mm"], published.get(name)))
    study = result.get("joint_error_study")
    if study is not None:
        for name, obj in study["objects"].items():
            for err, med in zip(study["joint_error_deg"], obj["median"], strict=True):
                if err > 0:
                    rows.append((f"contour {name}: median max deviation, joint error {err:g} deg (mm)", med,
                                 published.get(name)))
    return rows


STUDY = Study(
    name="finger",
    summary="the dome sensor on a 3-DOF finger: friction scanning, slip detection, contour tracing",
    run=_run,
    draw=draw,
    published={
        "reference": "the optical three-axis tactile sensor's inventors (Ohka et al.) on their 3-DOF finger "
                     "with a z-stage: surface scanning, slip detection and contour tracing, as quoted in the "
                     "README, section 'The robotic finger'",
        "surface_scanning": {"frictions": [0.39, 0.40, 0.53], "speeds_mm_s": [1.4, 6.2, 25.0],
                             "normal_force_n": 0.1, "tolerance": 0.02},
        "slip": {"band_n_s": 0.06},
        "contour_tracing": {"max_deviation_mm": dict(finger_contour.PUBLISHED_DEVIATION_MM),
                            "contact_threshold_n": 0.3, "table_threshold_n": 0.2, "step_mm": 5.0,
                            "lift_mm": 5.0},
    },
    figsize=(15.0, 2.4 * _SCAN_ROWS + 4 + 5),
    key_figures=key_figures,
)
