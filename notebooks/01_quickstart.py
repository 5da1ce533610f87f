# %% [markdown]
# # Quickstart: a loaded dome, its frame, its forces
#
# Render the optical three-axis tactile sensor under a load, expose the camera frame,
# read it with the frame pipeline and turn the readings into forces with the shipped
# calibration; then overlay the estimated force field on the frame.

# %%
import tempfile
from pathlib import Path

import numpy as np
from IPython.display import Image
from matplotlib.figure import Figure
from optitact.calib.shipped import default_calibration
from optitact.render import render
from optitact.render.pathtrace import spot_pixels

import optitact

sensor = optitact.optics.sensor.DomeSensor.default()
camera = optitact.optics.camera.FisheyeCamera()        # 640 x 480 fisheye under the dome
ccd = optitact.optics.ccd.CCD()
cal = default_calibration()              # fitted on synthetic frames of this sensor and camera

# %% [markdown]
# A load: the apex element and a few on the first two rings, with some shear.

# %%
forces = np.zeros((41, 3))
forces[[0, 3, 7, 12, 20], 2] = (0.8, 0.5, 0.3, 0.6, 0.4)
forces[[0, 12], 0] = (0.15, -0.1)
forces[7, 1] = 0.08

# %% [markdown]
# The no-load frames make the pipeline's baseline; the loaded frame renders only the pixels
# the pipeline reads for the loaded elements (path tracing, 32 samples per pixel).

# %%
noload = [render(sensor, np.zeros((41, 3)), camera=camera, spp=32, seed=s) for s in (1, 2)]
baseline = np.stack([ccd.expose(img, seed=s) for s, img in enumerate(noload)])
background = np.mean(noload, axis=0)
radiance = render(sensor, forces, camera=camera, spp=32, seed=3,
                  pixels=spot_pixels(sensor, camera, forces), background=background)
frame = ccd.expose(radiance, seed=3)
frame.shape, frame.dtype

# %%
pipe = cal.pipeline(baseline=baseline)
readings = pipe.process(frame)
estimated, clamped = cal.forces(readings)
for e in (0, 3, 7, 12, 20):
    print(f"element {e:2d}: true {forces[e].round(2)}  estimated {estimated[e].round(2)}  G={readings.G[e]:.1f}")

# %% [markdown]
# The force field over the frame: shear as arrows, normal force as colour.

# %%
field = cal.apply(readings)
fig = Figure(figsize=(7, 5.5), layout="constrained")
ax = fig.subplots()
field.plot(frame, camera, ax=ax)
ax.set_title("estimated forces")
out = Path(tempfile.mkdtemp()) / "forces.png"
fig.savefig(out, dpi=90)
Image(filename=str(out))

# %%
err = np.abs(estimated[forces[:, 2] > 0] - forces[forces[:, 2] > 0])
print("largest error (N) in Fx, Fy, Fz:", err.max(axis=0).round(3))
