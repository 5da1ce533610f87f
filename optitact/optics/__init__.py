"""The sensor and its optics: geometry, cameras, contact, the CCD.

Modules: :mod:`~optitact.optics.sensor` (the dome and its elements), :mod:`~optitact.optics.force_frames`
(element-local and global forces), :mod:`~optitact.optics.camera` (the camera interface, the
equidistant fisheye and the rays through the acrylic dome),
:mod:`~optitact.optics.camera_models` (OpenCV's pinhole and fisheye models),
:mod:`~optitact.optics.opencv_files` (OpenCV, ROS and Kalibr camera files),
:mod:`~optitact.optics.contact` (forces to contact patches), :mod:`~optitact.optics.ccd`
(radiance to digital numbers) and :mod:`~optitact.optics.loads` (sample loads).

Each public name lives in one module (import it from there); the modules load on first use.
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=[
    "camera", "camera_models", "ccd", "contact", "force_frames", "loads", "opencv_files", "sensor"])
