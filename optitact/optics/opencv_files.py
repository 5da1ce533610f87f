"""Reading OpenCV's calibration output into a camera model of :mod:`optitact.optics.camera_models`.

:func:`read_opencv_calibration` reads a ``cv2.FileStorage`` YAML/XML file (or
the same keys in plain YAML, ROS ``camera_info`` style) and
:func:`camera_from_opencv` takes OpenCV's ``K`` and ``D`` arrays; both return a
:class:`optitact.optics.camera_models.PinholeCamera` or
:class:`optitact.optics.camera_models.OpenCVFisheyeCamera`, and both are importable
from :mod:`optitact.optics.camera_models` too. OpenCV (``cv2``) is imported only
when a file is read.

Convention
----------
``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels with ``cx`` along
columns, as OpenCV writes it; the cameras index pixels ``(row, col)`` = OpenCV's
``(v, u)``. The pose (``rvec``, ``tvec``, mm) is OpenCV's, in the dome frame
(see :mod:`optitact.optics.camera_models`).
"""

from __future__ import annotations

import math
import os

import numpy as np

from optitact._validate import integer
from optitact.optics.camera import CAMERA_MODELS, Camera
from optitact.errors import InputError

__all__ = ["camera_from_opencv", "read_opencv_calibration"]

_MODEL_NAMES = {"pinhole": "pinhole", "plumb_bob": "pinhole", "radtan": "pinhole",
                "rational_polynomial": "pinhole", "fisheye": "opencv_fisheye",
                "opencv_fisheye": "opencv_fisheye", "equidistant": "opencv_fisheye",
                "kannala_brandt": "opencv_fisheye"}


def camera_from_opencv(K, D, width: int, height: int, *, model: str = "pinhole", rvec=(0.0, 0.0, 0.0),  # noqa: N803
                       tvec=(0.0, 0.0, 5.0)) -> Camera:
    """A camera from OpenCV's camera matrix ``K`` and distortion ``D``.

    Parameters
    ----------
    K : (3, 3) array_like
        ``[[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` (pixels); a skew entry is refused.
    D : array_like
        Distortion coefficients: 4, 5, 8 or 12 for ``model="pinhole"``
        (``cv2.calibrateCamera``), 4 for ``model="fisheye"``
        (``cv2.fisheye.calibrate``).
    width, height : int
        Image size the calibration was made at (pixels).
    model : {"pinhole", "fisheye"}
        Also accepted: ``"opencv_fisheye"``, ``"equidistant"``,
        ``"kannala_brandt"``, ``"plumb_bob"``, ``"radtan"``,
        ``"rational_polynomial"``.
    rvec, tvec : optional
        The camera's pose in the dome (see
        :class:`optitact.optics.camera_models.PinholeCamera`); default on the axis at
        z = -5 mm looking up it.

    Returns
    -------
    PinholeCamera or OpenCVFisheyeCamera

    Raises
    ------
    InputError
        For a K that is not a camera matrix, a non-finite value, an unknown
        model or a distortion it cannot read.
    """
    if not isinstance(model, str) or model.lower() not in _MODEL_NAMES:
        raise InputError(f"model must be one of {sorted(_MODEL_NAMES)}, got {model!r}")
    try:
        k = np.asarray(K, dtype=np.float64)
    except (TypeError, ValueError):
        raise InputError(f"K must be a 3x3 camera matrix of numbers, got {K!r}") from None
    if k.shape != (3, 3):
        raise InputError(f"K must be a 3x3 camera matrix, got shape {k.shape}")
    if not np.isfinite(k).all():
        raise InputError(f"K must be finite, got {k.tolist()}")
    if not (k[1, 0] == 0 and k[2, 0] == 0 and k[2, 1] == 0 and abs(k[2, 2] - 1) <= 1e-12 and k[0, 0] > 0
            and k[1, 1] > 0):
        raise InputError(f"K is not a camera matrix [[fx, 0, cx], [0, fy, cy], [0, 0, 1]] with fx, fy > 0, "
                         f"got {k.tolist()}")
    if abs(k[0, 1]) > 1e-12 * k[0, 0]:
        raise InputError(f"K has a skew entry K[0, 1] = {k[0, 1]!r}; only zero skew is supported")
    try:
        d = np.asarray(D if D is not None else [], dtype=np.float64).ravel()
    except (TypeError, ValueError):
        raise InputError(f"D must be distortion coefficients (numbers), got {D!r}") from None
    from optitact.optics.camera_models import OpenCVFisheyeCamera

    cls = CAMERA_MODELS[_MODEL_NAMES[model.lower()]]
    if cls is OpenCVFisheyeCamera and d.size != 4:
        raise InputError(f"D of the fisheye model must have 4 coefficients (k1..k4), got {d.size}")
    return cls(width, height, fx=k[0, 0], fy=k[1, 1], cx=k[0, 2], cy=k[1, 2], dist=d, rvec=rvec, tvec=tvec)


_K_KEYS = ("camera_matrix", "K", "cameraMatrix", "intrinsic_matrix", "intrinsics")
_D_KEYS = ("distortion_coefficients", "dist_coeffs", "D", "distCoeffs", "distortion", "dist")


def _node_array(node, key: str, path: str) -> np.ndarray:
    """A FileStorage node as an array: an ``!!opencv-matrix``, a sequence, or ROS's ``{rows, cols, data}``."""
    if node.isMap() and not node.getNode("dt").empty():
        return np.asarray(node.mat(), dtype=np.float64)
    if node.isMap() and not node.getNode("data").empty():
        node = node.getNode("data")
    if node.isSeq():
        vals = [node.at(i) for i in range(node.size())]
        if not all(v.isReal() or v.isInt() for v in vals):
            raise InputError(f"{path}: '{key}' must hold numbers")
        return np.array([v.real() for v in vals], dtype=np.float64)
    if node.isReal() or node.isInt():
        return np.array([node.real()])
    raise InputError(f"{path}: '{key}' is not a matrix or a list of numbers")


#: Kalibr's ``camera_model`` values this package reads: the projection (Kalibr's ``pinhole``
#: with a ``distortion_model`` of ``radtan``, ``equidistant`` or ``none``). Kalibr's omnidirectional,
#: double-sphere and extended unified models are refused by name.
_KALIBR_PROJECTIONS = ("pinhole",)

#: What a distortion vector of each length is when a file does not say its model: OpenCV's
#: fisheye calibration (``cv2.fisheye.calibrate``) writes 4 coefficients, ``cv2.calibrateCamera``
#: 5, 8, 12 or 14.
_MODEL_BY_COEFFICIENTS = {4: "fisheye", 5: "pinhole", 8: "pinhole", 12: "pinhole"}


def _split_entry(path: str) -> tuple[str, str | None]:
    """``camchain.yaml#cam1`` -> (``camchain.yaml``, ``cam1``); a path that exists as given is kept whole."""
    if os.path.exists(path) or "#" not in path:
        return path, None
    file, _, entry = path.rpartition("#")
    return file, entry or None


def _open_storage(path: str):
    """A ``cv2.FileStorage`` open for reading, or an InputError naming the file."""
    import cv2

    try:
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
        ok = fs.isOpened()
    except (cv2.error, SystemError) as exc:  # OpenCV 5 raises SystemError on a malformed file
        cause = exc.__cause__ if isinstance(exc, SystemError) and exc.__cause__ is not None else exc
        raise InputError(f"{path}: not a readable OpenCV FileStorage YAML/XML file (is it complete? "
                         f"{str(cause).strip()[-160:]})") from None
    if not ok:
        raise InputError(f"{path}: not an OpenCV FileStorage YAML/XML file")
    return fs


def _camera_node(fs, path: str, entry: str | None):
    """The map holding the camera: the root, or a Kalibr camchain's ``camN`` (``entry`` picks one)."""
    root = fs.root()
    keys = list(root.keys()) if root.isMap() else []
    cams = [k for k in keys if fs.getNode(k).isMap() and "intrinsics" in fs.getNode(k).keys()]
    if entry is not None:
        if entry not in keys or not fs.getNode(entry).isMap():
            raise InputError(f"{path}: no camera {entry!r} in the file; found keys {keys}")
        return fs.getNode(entry), f"{path}#{entry}"
    if cams and not any(k in keys for k in _K_KEYS):
        if len(cams) > 1:
            raise InputError(f"{path}: a Kalibr camchain with cameras {cams}; say which: "
                             f"'{path}#{cams[0]}' (--camera-intrinsics) or read_opencv_calibration(..., "
                             f"camera={cams[0]!r})")
        return fs.getNode(cams[0]), f"{path}#{cams[0]}"
    return root, path


def _integer_size(value: float, name: str, path: str) -> int:
    if not math.isfinite(value) or value != int(value) or value < 2:
        raise InputError(f"{path}: image {name} must be a whole number of pixels (>= 2), got {value!r}")
    return int(value)


def read_opencv_calibration(path, *, model: str | None = None, width: int | None = None,
                            height: int | None = None, camera: str | None = None, rvec=(0.0, 0.0, 0.0),
                            tvec=(0.0, 0.0, 5.0)) -> Camera:
    """Read a camera calibration file (OpenCV FileStorage YAML/XML, ROS ``camera_info``, Kalibr).

    Parameters
    ----------
    path : str or os.PathLike
        A file written by ``cv2.FileStorage`` (OpenCV's calibration sample:
        ``camera_matrix``, ``distortion_coefficients``, ``image_width``,
        ``image_height``), the same keys in plain YAML (ROS ``camera_info``
        style ``{rows, cols, data}`` matrices and ``distortion_model``), or a
        Kalibr camchain (``cam0: {camera_model, intrinsics: [fu, fv, pu, pv],
        distortion_model, distortion_coeffs, resolution}``; ``FILE#cam1`` or
        ``camera="cam1"`` picks another camera of the chain). Also accepted:
        ``K``/``cameraMatrix``, ``D``/``dist_coeffs``/``distCoeffs``,
        ``image_size``/``imageSize`` as ``[width, height]``.
    model : {"pinhole", "fisheye"}, optional
        Override the model. Otherwise the file's own word (``fisheye_model: 1``,
        or a ``distortion_model``/``camera_model``/``model`` such as ``plumb_bob``,
        ``radtan``, ``fisheye``, ``equidistant``), else the number of distortion
        coefficients decides: 4 is ``cv2.fisheye.calibrate``'s Kannala-Brandt
        model, 5, 8 or 12 are ``cv2.calibrateCamera``'s pinhole model. Other
        counts without a model word are refused (pass ``model``).
    width, height : int, optional
        Image size, where the file has none (or to check it).
    camera : str, optional
        Which camera of a Kalibr camchain (default: its only one).
    rvec, tvec : optional
        The camera's pose in the dome (see :class:`optitact.optics.camera_models.PinholeCamera`).

    Returns
    -------
    PinholeCamera or OpenCVFisheyeCamera

    Raises
    ------
    InputError
        For a missing, unreadable or half-written file, missing keys (listing
        those found and those expected), a camchain with several cameras and
        none chosen, a model it cannot read (14 coefficients: the tilted model;
        Kalibr's omni/ds/eucm), a coefficient count that does not say the model,
        non-finite values, a non-integer image size, a K that is not a camera
        matrix, or a width/height that disagrees with the file.
    """
    import cv2

    path, entry = _split_entry(os.fspath(path))
    if camera is not None:
        entry = camera
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such calibration file")
    fs = _open_storage(path)
    try:
        try:
            node, where = _camera_node(fs, path, entry)
            keys = list(node.keys())

            def find(names):
                for name in names:
                    if name in keys:
                        return name
                return None

            kk, dk = find(_K_KEYS), find(_D_KEYS + ("distortion_coeffs",))
            if kk is None or dk is None:
                raise InputError(f"{where}: expected a camera matrix (one of {list(_K_KEYS)}) and distortion "
                                 f"coefficients (one of {list(_D_KEYS)}), found keys {keys}")
            k = _node_array(node.getNode(kk), kk, where)
            d = _node_array(node.getNode(dk), dk, where)
            if k.size == 4 and kk == "intrinsics":  # Kalibr's [fu, fv, pu, pv]
                k = np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1]])
            if k.size != 9:
                raise InputError(f"{where}: '{kk}' must be a 3x3 camera matrix, got {k.size} values")
            k = k.reshape(3, 3)
            size = {}
            for name in ("image_width", "image_height", "width", "height"):
                if name in keys:
                    size[name.split("_")[-1]] = node.getNode(name).real()
            sk = find(("image_size", "imageSize", "resolution"))
            if sk is not None:
                wh = _node_array(node.getNode(sk), sk, where)
                if wh.size == 2:
                    size.setdefault("width", wh[0])
                    size.setdefault("height", wh[1])
            said = None
            if "fisheye_model" in keys:
                said = "fisheye" if node.getNode("fisheye_model").real() else "pinhole"
            projection = node.getNode("camera_model").string() if "camera_model" in keys else None
            mk = find(("distortion_model", "model"))
            if mk is not None and node.getNode(mk).isString():
                said = node.getNode(mk).string()
        except (cv2.error, SystemError) as exc:
            raise InputError(f"{path}: could not read the calibration ({str(exc).strip()[-160:]})") from None
    finally:
        fs.release()
    if projection is not None and projection.lower() not in _KALIBR_PROJECTIONS + tuple(_MODEL_NAMES):
        raise InputError(f"{where}: camera model {projection!r} is not one optitact reads (Kalibr's "
                         f"'pinhole' projection with radtan or equidistant distortion, or OpenCV's models)")
    if said is None and projection is not None and projection.lower() in _MODEL_NAMES:
        said = projection
    if said is not None and said.lower() == "none":  # Kalibr: an undistorted pinhole
        said, d = "pinhole", np.zeros(0)
    for name, given in (("width", width), ("height", height)):
        if name in size:
            size[name] = _integer_size(size[name], name, where)
        if given is not None:
            given = integer(given, name, minimum=2)
            if name in size and size[name] != given:
                raise InputError(f"{where}: the file's image {name} is {size[name]}, not the {given} given")
            size[name] = given
        if name not in size:
            raise InputError(f"{where}: no image {name} in the file (image_width/image_height, image_size or "
                             f"resolution); pass {name}=")
    if not np.isfinite(d).all():
        raise InputError(f"{where}: distortion coefficients must be finite, got {d.tolist()}")
    if d.size == 14:
        raise InputError(f"{where}: 14 distortion coefficients are OpenCV's tilted-sensor model (tauX, tauY), "
                         f"which optitact cannot read; recalibrate without CALIB_TILTED_MODEL (4, 5, 8 or 12 "
                         f"coefficients)")
    if model is None:
        if said is not None and said.lower() not in _MODEL_NAMES:
            raise InputError(f"{where}: distortion model {said!r} is not one optitact reads; valid: "
                             f"{sorted(_MODEL_NAMES)}")
        model = said or _MODEL_BY_COEFFICIENTS.get(d.size)
        if model is None:
            raise InputError(f"{where}: {d.size} distortion coefficients and no model in the file: say which "
                             f"model it is (--model pinhole|fisheye, or model=): cv2.fisheye.calibrate writes "
                             f"4, cv2.calibrateCamera 5, 8 or 12")
    try:
        return camera_from_opencv(k, d, size["width"], size["height"], model=model, rvec=rvec, tvec=tvec)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
