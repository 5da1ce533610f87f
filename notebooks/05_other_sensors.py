# %% [markdown]
# # Other tactile sensors: taxel arrays as small images
#
# Besides the dome, optitact simulates four taxel arrays as *sources* of small images with
# one interface (`optitact.taxels.sources`): a 16 x 16 piezoresistive finger pad (`piezo16`),
# 8 x 8 thread-electrode arrays on a gripper's jaws (`thread8`), a 5 x 5 optoelectronic pad
# (`opto5`) and a non-coplanar 25-unit fingertip (`fingertip25`). Each comes with the
# analysis its inventors used: active tracing of pipes, palpation classification, wire
# shape and diameter, and 3-D force decoupling. Small runs here; `optitact experiment NAME
# --full` runs the published sizes.

# %%
import tempfile
from pathlib import Path

import matplotlib.pyplot as plt
import numpy as np
from IPython.display import Image, display

from optitact import studies
from optitact.taxels.sources import Indenter, Scenario, make_source, moments

work = Path(tempfile.mkdtemp())

# %% [markdown]
# **Frames as images.** The same kind of scenario — an indenter pressed over time — gives
# each source's frames; `moments` reads them like the dome's spots (total, centroid).

# %%
t = np.linspace(0.0, 1.0, 11)
setups = {
    "piezo16": Scenario(Indenter("cylinder", size_mm=3.0), t_s=t, angle_rad=0.5, depth_mm=np.linspace(0, 1.0, 11)),
    "thread8": Scenario(Indenter("sphere", size_mm=5.0), t_s=t, x_mm=2.0, force_n=np.linspace(0, 2.0, 11)),
    "opto5": Scenario(Indenter("wire", size_mm=1.0), t_s=t, angle_rad=0.3, depth_mm=np.linspace(0, 1.0, 11)),
    "fingertip25": Scenario(Indenter("sphere", size_mm=10.0), t_s=t, force_n=np.linspace(0, 2.0, 11)),
}
fig, axes = plt.subplots(1, 4, figsize=(14, 3.4), layout="constrained")
for ax, (name, scenario) in zip(axes, setups.items(), strict=True):
    source = make_source(name)
    frames = source.frames(scenario, seed=0)
    m = moments(frames, source.layout)
    change = np.abs(frames[-1].astype(float) - frames[0])  # raw values carry per-taxel offsets
    im = ax.imshow(change, cmap="magma")
    fig.colorbar(im, ax=ax, shrink=0.8)
    ax.set_title(f"{name}: {frames.shape[1]}x{frames.shape[2]} {frames.dtype}, |loaded - unloaded|", fontsize=9)
    print(f"{name:12s} frames {frames.shape}  total of the last frame {float(m['total'][-1]):9.3f}")
plt.show()

# %% [markdown]
# **Active tracing (piezo16).** The pad strokes across pipes of several diameters; the
# interleaved combined distribution of the steps gives a width feature that separates
# the diameters.

# %%
res = studies.run("tracing", seed=0, size="quick")
cls = res["classification"]
print("pipe diameters (mm):", cls["classifier"][0]["diameter_mm"])
for n, acc, resol in zip(cls["n_steps"], cls["accuracy"], cls["resolution_mm"], strict=True):
    print(f"{n:2d} tracing steps: diameter classification accuracy {acc:.0%}, "
          f"smallest difference told apart reliably {'-' if resol is None else f'{resol:g}'} mm")
studies.save_plot("tracing", res, work / "tracing.png")
display(Image(filename=str(work / "tracing.png")))

# %% [markdown]
# **Palpation (thread8).** A gripper squeezes objects; dynamic time warping between the
# frames' feature series and a k-nearest-neighbour vote recognise them (cross-validated).

# %%
res = studies.run("palpation", seed=0, size="quick")
tab = res["table"]
print(f"{len(res['objects'])} objects, {res['n_per_object']} grasps each, chance {res['chance']:.0%}")
for i in range(len(tab["metric"])):
    if tab["k"][i] == 1:
        print(f"  {tab['metric'][i]:14s} k=1: recognition rate {tab['mean'][i]:.0%} "
              f"[{tab['ci_low'][i]:.0%}, {tab['ci_high'][i]:.0%}]")
studies.save_plot("palpation", res, work / "palpation.png")
display(Image(filename=str(work / "palpation.png")))

# %% [markdown]
# **Wire shape and diameter (opto5).** Per-taxel normalisation, the wire's centre line,
# and its diameter by lookup table, SVM and MLP.

# %%
res = studies.run("wire", seed=0, size="quick")
for name in ("lookup_table", "svm", "mlp"):
    print(f"{name:12s} accuracy {res['classification'][name]['accuracy']:.1%}")
studies.save_plot("wire", res, work / "wire.png")
display(Image(filename=str(work / "wire.png")))

# %% [markdown]
# **3-D decoupling (fingertip25).** Five planes of units at different angles; forces come
# back from the units' readings by the published plane formula and by a calibrated matrix.

# %%
res = studies.run("fingertip", seed=0, size="quick")
dec = res["decoupling"]
for name in ("published", "calibrated"):
    print(f"{name:10s} decoupling: RMS error x/y/z", np.round(dec[name]["rms_n"], 3), "N")
print(f"object recognition: {res['recognition']['accuracy']:.1%} (chance {res['recognition']['chance']:.1%})")
studies.save_plot("fingertip", res, work / "fingertip.png")
display(Image(filename=str(work / "fingertip.png")))
