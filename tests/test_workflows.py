"""The README's workflows as a researcher types them: each command a new ``optitact`` process.

Every test here works in a fresh folder with a fresh ``OPTITACT_CACHE_DIR`` (the ``user``
fixture, ``tests/outside_in.py``); the test process imports nothing of optitact before the
commands run. The inputs a researcher would bring from the bench (camera calibration files,
frames of presses, the gauge's CSV, a recording) are made by a script run in its own interpreter,
from a stand-in sensor the commands are not told about: the default sensor as a workshop would
build it (:func:`optitact.studies.bench_realism.draw_standin`: element offsets and gains, dome
radius and shell, an OpenCV fisheye camera off axis and tilted), rendered two-stage through its
own camera. The truth the outputs are held to is that stand-in: its camera pose, and the forces
its frames were rendered with.
"""

from __future__ import annotations

import csv
import json
import math
import textwrap

import numpy as np
import pytest

pytestmark = pytest.mark.render

#: The researcher's bench, as a script: a stand-in sensor's frames, camera files and gauge CSVs.
BENCH = textwrap.dedent('''
    import json, sys
    import cv2
    import numpy as np
    from optitact.optics.sensor import DomeSensor
    from optitact.optics.camera_models import PinholeCamera
    from optitact.calib.patterns import design_forces
    from optitact.calib.sets import Design
    from optitact.optics.camera_models import pose_from_position
    from optitact.optics.ccd import CCD
    from optitact.render import render
    from optitact.render.emission import shipped_table
    from optitact.studies.bench_realism import REGISTRATION_FORCE_N, REGISTRATION_PRESSES, draw_standin

    KIND, W, H = sys.argv[1], 320, 240
    s = draw_standin(4, size=(W, H))
    sensor, camera, told = s.sensor, s.camera, s.intrinsics
    if KIND == "pinhole":  # a wide-angle pinhole lens instead of the fisheye, off axis and tilted
        camera = PinholeCamera(W, H, fx=72.0, fy=72.3, cx=161.2, cy=118.4,
                               dist=(-0.02, 0.004, 3e-4, -2e-4, 0.0),
                               **pose_from_position((0.25, -0.15, -5.1), (0.012, -0.009, 0.004)))
        told = PinholeCamera(W, H, fx=camera.fx, fy=camera.fy, cx=camera.cx, cy=camera.cy, dist=camera.dist)
    table = shipped_table(DomeSensor.default())   # the guided light at the patches: any camera
    ccd, dark = CCD(), np.zeros((H, W), np.float32)
    n = sensor.n_elements

    def frame(forces, seed):
        return ccd.expose(render(sensor, forces, camera=camera, transport="two_stage", table=table,
                                 background=dark), seed=seed)

    # the camera's calibration, as each tool writes it
    K, D = told.K, np.asarray(told.D, float)
    fs = cv2.FileStorage("cam.yml", cv2.FILE_STORAGE_WRITE)   # cv2.fisheye.calibrate / calibrateCamera output
    fs.write("image_width", W); fs.write("image_height", H)
    fs.write("camera_matrix", K); fs.write("distortion_coefficients", D.reshape(-1, 1))
    fs.release()
    ros_model = "equidistant" if KIND != "pinhole" else "plumb_bob"
    open("ost.yaml", "w").write(
        f"image_width: {W}\\nimage_height: {H}\\ncamera_name: dome\\n"
        f"camera_matrix:\\n  rows: 3\\n  cols: 3\\n  data: {K.ravel().tolist()}\\n"
        f"distortion_model: {ros_model}\\n"
        f"distortion_coefficients:\\n  rows: 1\\n  cols: {D.size}\\n  data: {D.tolist()}\\n")
    open("camchain.yaml", "w").write(
        f"cam0:\\n  camera_model: pinhole\\n  distortion_coeffs: {D.tolist()}\\n"
        f"  distortion_model: {'equidistant' if KIND != 'pinhole' else 'radtan'}\\n"
        f"  intrinsics: {[told.fx, told.fy, told.cx, told.cy]}\\n  resolution: [{W}, {H}]\\n"
        f"  rostopic: /dome/image_raw\\n")

    # registration: a no-load frame and frames of equal presses straight down, all 41 elements
    cv2.imwrite("noload.png", frame(np.zeros((n, 3)), 1))
    for k, els in enumerate(REGISTRATION_PRESSES):
        f = np.zeros((n, 3)); f[list(els), 2] = REGISTRATION_FORCE_N
        cv2.imwrite(f"reg_{k}.png", frame(f, 10 + k))
    truth = {"position": camera.position.tolist(), "rotation": camera.rotation.tolist()}
    if sys.argv[2:] != ["presses"]:
        json.dump(truth, open("truth.json", "w"))
        sys.exit()

    # gauge presses (every element in every frame), held-out presses, and a recording
    import pathlib
    forces = design_forces(15, n, Design(fz_max=0.9), seed=5)
    forces[:, :, 2] = np.maximum(forces[:, :, 2], 0.15)
    for folder in ("presses", "held"):  # the first frame of each unloaded: the baseline
        pathlib.Path(folder).mkdir()
    cv2.imwrite("presses/press_000.png", frame(np.zeros((n, 3)), 20))
    cv2.imwrite("held/press_000.png", frame(np.zeros((n, 3)), 21))
    rows = {"presses": ["frame,element,Fx (mN),Fy (mN),Fz (mN)"], "held": ["frame,element,fx,fy,fz"]}
    for t, f in enumerate(forces[:11]):
        folder = "presses" if t < 8 else "held"
        name = f"press_{t + 1:03d}.png"
        cv2.imwrite(f"{folder}/{name}", frame(f, 30 + t))
        scale = 1000.0 if folder == "presses" else 1.0  # the gauge in mN, the held-out sheet in N
        rows[folder] += [f"{name},{e},{scale * f[e, 0]:.9g},{scale * f[e, 1]:.9g},{scale * f[e, 2]:.9g}"
                         for e in range(n)]
    open("gauge.csv", "w").write("\\n".join(rows["presses"]) + "\\n")
    open("held.csv", "w").write("\\n".join(rows["held"]) + "\\n")
    vw = cv2.VideoWriter("clip.avi", cv2.VideoWriter_fourcc(*"FFV1"), 30, (W, H), False)
    vw.write(frame(np.zeros((n, 3)), 50))
    for t, f in enumerate(forces[11:]):
        vw.write(frame(f, 51 + t))
    vw.release()
    truth["clip_forces"] = forces[11:].tolist()
    json.dump(truth, open("truth.json", "w"))
''')


def _bench(user, kind: str, *what: str) -> dict:
    """Run the bench script: registration frames and camera files (``"presses"``: gauge frames too)."""
    user.path("bench.py").write_text(BENCH)
    r = user.python(f"import sys; sys.argv = ['bench.py', {kind!r}, *{what!r}]; exec(open('bench.py').read())")
    assert r.returncode == 0, r.stderr
    return json.loads(user.path("truth.json").read_text())


def _pose_error(setup: dict, truth: dict) -> tuple[float, float]:
    """Camera position (mm) and orientation (deg) error of a setup file's camera against the truth."""
    from optitact.optics.camera import camera_from_dict  # after the commands ran: only to read their output

    cam = camera_from_dict(setup["camera"])
    dp = float(np.linalg.norm(cam.position - np.array(truth["position"])))
    rel = cam.rotation @ np.array(truth["rotation"]).T
    angle = math.degrees(math.acos(np.clip((np.trace(rel) - 1) / 2, -1, 1)))
    return dp, angle


def _table(path) -> list[dict]:
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


def _ok(r):
    assert r.returncode == 0, f"exit {r.returncode}\n{r.stderr}"
    return r


def test_own_sensor_workflow_from_an_opencv_fisheye_file(user):
    """The README's own-sensor block as typed (``reg_*.png`` expanded as a shell does; the recording
    for ``--camera 0``): register (cv2.fisheye.calibrate's YAML, no model key) -> process --setup ->
    calibrate fit --setup --start default (gauge in mN) -> calibrate test (shipped, transferred; then
    the fit) -> process --camera: every step a new process, each reading the previous one's file."""
    truth = _bench(user, "fisheye", "presses")
    regs = sorted(p.name for p in user.folder.glob("reg_*.png"))
    reg = _ok(user.run("register", "noload.png", *regs, "--camera-intrinsics", "cam.yml", "--fit-offsets",
                       "--out", "setup.json"))
    setup = json.loads(user.path("setup.json").read_text())
    assert setup["camera"]["model"] == "opencv_fisheye"
    dp, angle = _pose_error(setup, truth)
    assert dp < 0.3 and angle < 0.6, reg.stderr  # README: <= 0.15 mm and 0.37 deg at 640x480
    assert "0 element(s) with no spot" in reg.stderr and "warning" not in reg.stderr, reg.stderr
    # the same intrinsics as ROS and Kalibr write them register the same camera
    for intrinsics in ("ost.yaml", "camchain.yaml"):
        _ok(user.run("register", "noload.png", *regs, "--camera-intrinsics", intrinsics, "--fit-offsets",
                     "--out", f"setup_{intrinsics}.json"))
        other = json.loads(user.path(f"setup_{intrinsics}.json").read_text())
        assert other["camera"] == setup["camera"] and other["sensor"] == setup["sensor"], intrinsics

    _ok(user.run("process", "presses/", "--setup", "setup.json", "--calibration", "default", "--out",
                 "forces.csv"))
    forces = _table(user.path("forces.csv"))
    assert len(forces) == 9 * 41
    assert all(row["contact"] == ("0" if row["source"] == "press_000.png" else "1") for row in forces)

    fit = _ok(user.run("calibrate", "fit", "--frames", "presses/", "--forces", "gauge.csv", "--setup",
                       "setup.json", "--start", "default", "--out", "mysensor.json"))
    assert "held-out" in fit.stderr
    reports = {}
    for name, args in (("transferred", ["--calibration", "default", "--setup", "setup.json"]),
                       ("refined", ["--calibration", "mysensor.json", "--plot", "errors.png"])):
        r = _ok(user.run("calibrate", "test", "--frames", "held/", "--forces", "held.csv", *args, "--json"))
        reports[name] = json.loads(r.stdout)
    assert reports["transferred"]["presses"] == 3 * 41 and user.path("errors.png").stat().st_size > 0
    # the guide's figures (pytest -s)
    print(fit.stderr, {k: (v["rmse_pct_fs"], v["coverage_90"]) for k, v in reports.items()})
    for k in ("fx", "fy", "fz"):
        # README (640x480): 1.2-1.8 % FS transferred, 0.5-1.4 % FS refined from 5 presses
        assert reports["transferred"]["rmse_pct_fs"][k] < 4.0, reports["transferred"]
        assert reports["refined"]["rmse_pct_fs"][k] < 1.05 * reports["transferred"]["rmse_pct_fs"][k], reports

    live = _ok(user.run("process", "--camera", "clip.avi", "--calibration", "mysensor.json", "--out",
                        "live.csv"))
    rows = _table(user.path("live.csv"))
    assert {"time_s", "wall_time", "fz"} <= set(rows[0]), live.stderr
    clip = np.array(truth["clip_forces"])  # (4, 41, 3): frames 1..4 of the clip
    fz = np.zeros(clip.shape[:2])
    for row in rows:
        if int(row["frame"]) >= 1:
            fz[int(row["frame"]) - 1, int(row["element"])] = float(row["fz"])
    rmse = float(np.sqrt(np.mean((fz - clip[..., 2]) ** 2)))
    assert rmse < 0.04 * clip[..., 2].max(), rmse  # within 4 % of full scale, as calibrate test says


def test_register_a_pinhole_camera_from_opencv_and_kalibr_files_then_process(user):
    """cv2.calibrateCamera's YAML (5 coefficients, no model key) and a Kalibr camchain (pinhole-radtan)
    register a pinhole stand-in, and the setup reads in a new process with the shipped calibration."""
    from optitact.studies.bench_realism import REGISTRATION_FORCE_N, REGISTRATION_PRESSES

    truth = _bench(user, "pinhole")
    regs = sorted(p.name for p in user.folder.glob("reg_*.png"))
    for intrinsics in ("cam.yml", "camchain.yaml"):
        reg = _ok(user.run("register", "noload.png", *regs, "--camera-intrinsics", intrinsics, "--fit-offsets",
                           "--out", "setup.json"))
        setup = json.loads(user.path("setup.json").read_text())
        assert setup["camera"]["model"] == "pinhole", intrinsics
        dp, angle = _pose_error(setup, truth)
        assert dp < 0.3 and angle < 0.6, (intrinsics, reg.stderr)
    _ok(user.run("process", "reg_0.png", "--baseline", "noload.png", "--setup", "setup.json",
                 "--calibration", "default", "--out", "forces.csv"))
    fz = {int(r["element"]): float(r["fz"]) for r in _table(user.path("forces.csv"))}
    np.testing.assert_allclose([fz[e] for e in REGISTRATION_PRESSES[0]], REGISTRATION_FORCE_N, rtol=0.15)


def test_calibrate_generate_fit_process(user):
    """A synthetic set for the default sensor, its fit, and frames processed with it: three processes."""
    _ok(user.run("calibrate", "generate", "--frames", "10", "--out", "set.zarr", "--width", "160", "--height",
                 "120", "--keep-frames", "--seed", "3"))
    _ok(user.run("calibrate", "fit", "set.zarr", "--model", "ohka", "--out", "cal.json"))
    script = ("import numpy as np, zarr\n"
              "g = zarr.open_group('set.zarr', mode='r')\n"
              "np.save('noload.npy', np.asarray(g['baseline'][:]))\n"
              "np.save('frames.npy', np.asarray(g['frames'][:]))\n"
              "np.save('forces.npy', np.asarray(g['forces'][:]))\n")
    _ok(user.python(script))
    _ok(user.run("process", "frames.npy", "--baseline", "noload.npy", "--calibration", "cal.json",
                 "--out", "forces.csv"))
    truth = np.load(user.path("forces.npy"))
    est = np.zeros_like(truth)
    for row in _table(user.path("forces.csv")):
        est[int(row["frame"]), int(row["element"])] = [float(row[k]) for k in ("fx", "fy", "fz")]
    assert np.corrcoef(est[..., 2].ravel(), truth[..., 2].ravel())[0, 1] > 0.9


def test_demo_as_typed(user):
    """``optitact demo`` (small), then its frame processed with its own setup file, in new processes."""
    _ok(user.run("demo", "--spp", "4", "--width", "160", "--height", "120", "--out", "demo", cached=True))
    for name in ("frame.png", "overlay.png", "forces.json", "radiance.npy"):
        assert user.path(f"demo/{name}").is_file(), name
    _ok(user.run("process", "demo/frame.png", "--baseline", "demo/frame.png", "--setup", "demo/forces.json",
                 "--out", "r.csv"))
    assert len(_table(user.path("r.csv"))) == 41
