"""The dome sensor on a 3-degree-of-freedom robotic finger: kinematics, the scene, the simulated chain.

The finger of the sensor's inventors: three revolute joints (a yaw joint and
two pitch joints) on a vertical z-stage, with the dome sensor at the
fingertip.

* :mod:`~optitact.finger.kinematics` -- :class:`Finger`: forward kinematics
  from Denavit-Hartenberg parameters, the Jacobian, resolved motion rate
  control (:meth:`Finger.rmrc`, :meth:`Finger.rmrc_lean` with the z-stage as
  a fourth axis, :meth:`Finger.follow` along a path).
* :mod:`~optitact.finger.scene` -- :class:`Table`, :class:`Cylinder`,
  :class:`Box`, :func:`feeler_forces` (a penalty contact model of the dome's
  feelers), :func:`world_from_local` / :func:`local_from_world`,
  :func:`sliding_friction`.
* :mod:`~optitact.finger.chain` -- :class:`ChainSimulator`: element forces ->
  estimated forces through the real chain (contact model -> render -> CCD ->
  pipeline -> calibration), frame by frame.

The published experiments (friction scanning, slip, contour tracing) are
studies, not library code: ``optitact.studies.run("finger", seed=0,
size="quick")``, and :mod:`optitact.studies.finger_scanning`,
:mod:`~optitact.studies.finger_slip`, :mod:`~optitact.studies.finger_contour`.

Examples
--------
>>> import numpy as np
>>> from optitact.finger.kinematics import Finger
>>> f = Finger()
>>> np.round(f.forward([0.0, 0.0, 0.0]), 6)          # stretched out along x
array([200.,   0.,   0.])
"""

import lazy_loader as _lazy

__getattr__, __dir__, __all__ = _lazy.attach(__name__, submodules=["chain", "kinematics", "scene"])
