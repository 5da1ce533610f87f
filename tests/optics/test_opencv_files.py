"""Camera files as researchers have them (OpenCV, ROS, Kalibr) and camera dicts in any process.

The truth is the camera written: each file is made from a known ``OpenCVFisheyeCamera`` or
``PinholeCamera`` (with OpenCV's own ``FileStorage`` where OpenCV writes the file), and must read
back as exactly that camera. The registry tests run a new interpreter that imports nothing but
what a user's script would, so no earlier import can register a model for it.
"""

from __future__ import annotations

import json
import textwrap

import pytest
from test_camera_models import write_calibration  # tests/ is on sys.path

from optitact.errors import InputError
from optitact.optics.camera_models import OpenCVFisheyeCamera, PinholeCamera
from optitact.optics.opencv_files import read_opencv_calibration

FISHEYE = OpenCVFisheyeCamera(640, 480, fx=205.3, fy=205.1, cx=321.4, cy=238.2,
                              dist=(0.012, -0.004, 0.0011, -0.0003))
PINHOLE = PinholeCamera(640, 480, fx=410.0, fy=409.0, cx=318.0, cy=242.5,
                        dist=(-0.21, 0.05, 0.001, -0.0007, -0.004))


def _storage(path, k, d, **kw):
    """A file as OpenCV's calibration sample writes it (cv2.FileStorage; ``test_camera_models``)."""
    write_calibration(path, k, d, **kw)
    return path


def _ros(path, cam, model):
    """A ROS camera_info YAML (camera_calibration's ost.yaml)."""
    k = cam.K.ravel().tolist()
    path.write_text(textwrap.dedent(f"""\
        image_width: {cam.width}
        image_height: {cam.height}
        camera_name: dome_cam
        camera_matrix:
          rows: 3
          cols: 3
          data: {k}
        distortion_model: {model}
        distortion_coefficients:
          rows: 1
          cols: {len(cam.dist)}
          data: {list(cam.dist)}
        rectification_matrix:
          rows: 3
          cols: 3
          data: [1, 0, 0, 0, 1, 0, 0, 0, 1]
        """))
    return path


def _kalibr(path, cams: dict):
    """A Kalibr camchain: camN -> camera_model, intrinsics [fu, fv, pu, pv], distortion, resolution."""
    lines = []
    for name, (cam, dmodel) in cams.items():
        lines += [f"{name}:", "  camera_model: pinhole",
                  f"  distortion_coeffs: {list(cam.dist)}", f"  distortion_model: {dmodel}",
                  f"  intrinsics: {[cam.fx, cam.fy, cam.cx, cam.cy]}",
                  f"  resolution: [{cam.width}, {cam.height}]", f"  rostopic: /{name}/image_raw"]
    path.write_text("\n".join(lines) + "\n")
    return path


# ---------------------------------------------------------------------------- which model a file is
def test_fisheye_calibrate_output_without_a_model_key_is_a_fisheye(tmp_path):
    """cv2.fisheye.calibrate gives K and 4 coefficients; saved the usual way there is no model key."""
    path = _storage(tmp_path / "cam.yml", FISHEYE.K, FISHEYE.D)
    assert read_opencv_calibration(path) == FISHEYE
    assert isinstance(read_opencv_calibration(path, model="pinhole"), PinholeCamera)
    assert read_opencv_calibration(_storage(tmp_path / "pin.yml", PINHOLE.K, PINHOLE.D)) == PINHOLE


def test_a_coefficient_count_that_says_no_model_is_refused(tmp_path):
    path = _storage(tmp_path / "cam.yml", PINHOLE.K, [0.1, 0.01, 0.0])
    with pytest.raises(InputError, match="3 distortion coefficients and no model.*--model pinhole"):
        read_opencv_calibration(path)


@pytest.mark.parametrize("cam, model", [(FISHEYE, "equidistant"), (PINHOLE, "plumb_bob")])
def test_ros_camera_info(tmp_path, cam, model):
    assert read_opencv_calibration(_ros(tmp_path / "ost.yaml", cam, model)) == cam


def test_kalibr_camchain(tmp_path):
    radtan = PinholeCamera(640, 480, fx=400.0, fy=401.0, cx=320.5, cy=240.5, dist=(-0.2, 0.04, 0.001, 0.002))
    one = _kalibr(tmp_path / "camchain.yaml", {"cam0": (FISHEYE, "equidistant")})
    assert read_opencv_calibration(one) == FISHEYE
    two = _kalibr(tmp_path / "two.yaml", {"cam0": (FISHEYE, "equidistant"), "cam1": (radtan, "radtan")})
    with pytest.raises(InputError, match=r"cameras \['cam0', 'cam1'\]; say which.*two.yaml#cam0"):
        read_opencv_calibration(two)
    assert read_opencv_calibration(f"{two}#cam1") == radtan
    assert read_opencv_calibration(two, camera="cam0") == FISHEYE
    with pytest.raises(InputError, match="no camera 'cam7'"):
        read_opencv_calibration(f"{two}#cam7")
    omni = tmp_path / "omni.yaml"
    omni.write_text(one.read_text().replace("camera_model: pinhole", "camera_model: omni"))
    with pytest.raises(InputError, match="camera model 'omni' is not one optitact reads"):
        read_opencv_calibration(omni)


@pytest.mark.parametrize("cut", [30, 120, 200])
def test_a_half_written_file_is_a_clear_error(tmp_path, cut):
    whole = _storage(tmp_path / "whole.yml", FISHEYE.K, FISHEYE.D).read_text()
    half = tmp_path / "half.yml"
    half.write_text(whole[:len(whole) - cut])
    with pytest.raises(InputError, match="half.yml"):
        read_opencv_calibration(half)


def test_image_size_must_be_whole_pixels(tmp_path):
    text = _ros(tmp_path / "a.yaml", FISHEYE, "equidistant").read_text()
    bad = tmp_path / "b.yaml"
    bad.write_text(text.replace("image_width: 640", "image_width: 640.7"))
    with pytest.raises(InputError, match="image width must be a whole number of pixels.*640.7"):
        read_opencv_calibration(bad)


# ---------------------------------------------------------------------------- any process finds every model
@pytest.mark.parametrize("cam", [FISHEYE, PINHOLE], ids=["opencv_fisheye", "pinhole"])
def test_a_camera_dict_reads_in_a_fresh_interpreter(user, cam):
    """A user's script: read a setup's camera with nothing imported but optitact itself."""
    (user.folder / "cam.json").write_text(json.dumps(cam.to_dict()))
    r = user.python("import json, optitact\n"
                    "cam = optitact.optics.camera.camera_from_dict(json.load(open('cam.json')))\n"
                    "print(type(cam).__name__, cam.fx)")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == [type(cam).__name__, repr(cam.fx)]


def test_setup_files_load_in_python(user):
    setup = {"sensor": {}, "camera": FISHEYE.to_dict()}
    (user.folder / "setup.json").write_text(json.dumps(setup))
    r = user.python("import optitact\n"
                    "s = optitact.registration.setup.read_setup('setup.json')\n"
                    "print(s.sensor.n_elements, s.camera.model)")
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["41", "opencv_fisheye"]
