# %% [markdown]
# # Calibration: a synthetic set, both models, held-out frames
#
# Generate a small synthetic calibration set (every frame loads all 41 elements with
# independent forces), fit the published model (`ohka`: Fz = g(G), Fx = f(ux)) and the
# contact-model-based `coupled` model, look at g(G) and the shear curves with their
# residuals, and apply both to held-out frames. Small sizes so that it runs in a minute;
# `optitact bench accuracy` does the full-size study.

# %%
import tempfile
from pathlib import Path

import numpy as np
from IPython.display import Image
from optitact.calib.fit import fit
from optitact.calib.plots import plot_errors, plot_fit
from optitact.calib.sets import generate

import optitact

work = Path(tempfile.mkdtemp())
camera = optitact.optics.camera.FisheyeCamera(width=240, height=180)
common = dict(camera=camera, spp=32, render_mode="pixels", progress=False)
train = generate(work / "train.zarr", frames=48, seed=0, **common)
test = generate(work / "test.zarr", frames=12, seed=100, **common)
len(train), len(test)

# %%
models = {name: fit(train, model=name) for name in ("ohka", "coupled")}
plot_fit(models["coupled"], train.readings(), train.forces(), work / "fit.png")
Image(filename=str(work / "fit.png"))

# %% [markdown]
# Held-out frames: estimated against true forces, both models side by side.

# %%
truth = test.forces()
estimates = {name: cal.forces(test.readings())[0] for name, cal in models.items()}
plot_errors(truth, estimates, work / "errors.png")
for name, est in estimates.items():
    loaded = truth[..., 2] > 0.05
    rms = np.sqrt(np.mean((est[loaded] - truth[loaded]) ** 2, axis=0))
    print(f"{name:8s} rms error (N)  Fx {rms[0]:.3f}  Fy {rms[1]:.3f}  Fz {rms[2]:.3f}")
Image(filename=str(work / "errors.png"))
