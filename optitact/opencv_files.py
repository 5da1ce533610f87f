"""Reading OpenCV's calibration output into a camera model of :mod:`optitact.camera_models`.

:func:`read_opencv_calibration` reads a ``cv2.FileStorage`` YAML/XML file (or
the same keys in plain YAML, ROS ``camera_info`` style) and
:func:`camera_from_opencv` takes OpenCV's ``K`` and ``D`` arrays; both return a
:class:`optitact.camera_models.PinholeCamera` or
:class:`optitact.camera_models.OpenCVFisheyeCamera`, and both are importable
from :mod:`optitact.camera_models` too. OpenCV (``cv2``) is imported only
when a file is read.

Convention
----------
``K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]`` in pixels with ``cx`` along
columns, as OpenCV writes it; the cameras index pixels ``(row, col)`` = OpenCV's
``(v, u)``. The pose (``rvec``, ``tvec``, mm) is OpenCV's, in the dome frame
(see :mod:`optitact.camera_models`).
"""

from __future__ import annotations

import math
import os

import numpy as np

from ._validate import integer
from .camera import CAMERA_MODELS, Camera
from .errors import InputError

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
        :class:`optitact.camera_models.PinholeCamera`); default on the axis at
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
    from .camera_models import OpenCVFisheyeCamera

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


def read_opencv_calibration(path, *, model: str | None = None, width: int | None = None,
                            height: int | None = None, rvec=(0.0, 0.0, 0.0), tvec=(0.0, 0.0, 5.0)) -> Camera:
    """Read OpenCV's calibration output (FileStorage YAML/XML or plain YAML) into a camera.

    Parameters
    ----------
    path : str or os.PathLike
        A file written by ``cv2.FileStorage`` (OpenCV's calibration sample:
        ``camera_matrix``, ``distortion_coefficients``, ``image_width``,
        ``image_height``), or the same keys in plain YAML (ROS
        ``camera_info`` style ``{rows, cols, data}`` matrices too). Also
        accepted: ``K``/``cameraMatrix``, ``D``/``dist_coeffs``/``distCoeffs``,
        ``image_size``/``imageSize`` as ``[width, height]``.
    model : {"pinhole", "fisheye"}, optional
        Override the model. Otherwise fisheye if the file says so
        (``fisheye_model: 1``, or ``distortion_model``/``model`` of
        ``fisheye``, ``equidistant`` or ``kannala_brandt``), else pinhole.
    width, height : int, optional
        Image size, where the file has none (or to check it).
    rvec, tvec : optional
        The camera's pose in the dome (see :class:`optitact.camera_models.PinholeCamera`).

    Returns
    -------
    PinholeCamera or OpenCVFisheyeCamera

    Raises
    ------
    InputError
        For a missing or unreadable file, missing keys (listing those found
        and those expected), a distortion model it cannot read (14
        coefficients: the tilted model), non-finite values, a K that is not a
        camera matrix, or a width/height that disagrees with the file.
    """
    import cv2

    path = os.fspath(path)
    if not os.path.isfile(path):
        raise InputError(f"{path}: no such calibration file")
    try:
        fs = cv2.FileStorage(path, cv2.FILE_STORAGE_READ)
        ok = fs.isOpened()
    except cv2.error as exc:
        raise InputError(f"{path}: not an OpenCV FileStorage YAML/XML file "
                         f"({str(exc).strip()[-120:]})") from None
    if not ok:
        raise InputError(f"{path}: not an OpenCV FileStorage YAML/XML file")
    try:
        root = fs.root()
        keys = list(root.keys()) if root.isMap() else []

        def find(names):
            for name in names:
                if name in keys:
                    return name
            return None

        kk, dk = find(_K_KEYS), find(_D_KEYS)
        if kk is None or dk is None:
            raise InputError(f"{path}: expected a camera matrix (one of {list(_K_KEYS)}) and distortion "
                             f"coefficients (one of {list(_D_KEYS)}), found keys {keys}")
        try:
            k = _node_array(fs.getNode(kk), kk, path)
            d = _node_array(fs.getNode(dk), dk, path)
        except cv2.error as exc:
            raise InputError(f"{path}: could not read '{kk}'/'{dk}' ({str(exc).strip()[-120:]})") from None
        if k.size == 4 and kk == "intrinsics":  # Kalibr's [fu, fv, pu, pv]
            k = np.array([[k[0], 0, k[2]], [0, k[1], k[3]], [0, 0, 1]])
        if k.size != 9:
            raise InputError(f"{path}: '{kk}' must be a 3x3 camera matrix, got {k.size} values")
        k = k.reshape(3, 3)
        size = {}
        for name in ("image_width", "image_height", "width", "height"):
            if name in keys:
                size[name.split("_")[-1]] = fs.getNode(name).real()
        sk = find(("image_size", "imageSize", "resolution"))
        if sk is not None:
            wh = _node_array(fs.getNode(sk), sk, path)
            if wh.size == 2:
                size.setdefault("width", wh[0])
                size.setdefault("height", wh[1])
        said = None
        if "fisheye_model" in keys:
            said = "fisheye" if fs.getNode("fisheye_model").real() else None
        mk = find(("distortion_model", "camera_model", "model"))
        if mk is not None and fs.getNode(mk).isString():
            said = fs.getNode(mk).string()
    finally:
        fs.release()
    for name, given in (("width", width), ("height", height)):
        if name in size and not math.isfinite(size[name]):
            raise InputError(f"{path}: image {name} must be finite, got {size[name]!r}")
        if given is not None:
            given = integer(given, name, minimum=2)
            if name in size and int(size[name]) != given:
                raise InputError(f"{path}: the file's image {name} is {int(size[name])}, not the {given} given")
            size[name] = given
        if name not in size:
            raise InputError(f"{path}: no image {name} in the file (image_width/image_height or image_size); "
                             f"pass {name}=")
    if not np.isfinite(d).all():
        raise InputError(f"{path}: distortion coefficients must be finite, got {d.tolist()}")
    if d.size == 14:
        raise InputError(f"{path}: 14 distortion coefficients are OpenCV's tilted-sensor model (tauX, tauY), "
                         f"which optitact cannot read; recalibrate without CALIB_TILTED_MODEL (4, 5, 8 or 12 "
                         f"coefficients)")
    if model is None:
        if said is not None and said.lower() not in _MODEL_NAMES:
            raise InputError(f"{path}: distortion model {said!r} is not one optitact reads; valid: "
                             f"{sorted(_MODEL_NAMES)}")
        model = said or "pinhole"
    try:
        return camera_from_opencv(k, d, int(size["width"]), int(size["height"]), model=model, rvec=rvec,
                                  tvec=tvec)
    except InputError as exc:
        raise InputError(f"{path}: {exc}") from None
