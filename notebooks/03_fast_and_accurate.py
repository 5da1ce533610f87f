# %% [markdown]
# # Fast and accurate: what each skip buys, and the time-versus-error front
#
# A path-traced frame of the dome is expensive: light reaches a spot only after many total
# internal reflections. optitact skips what a scene does not need — geometry for unloaded
# elements, pixels that cannot show a spot, samples beyond a target error — and its
# two-stage light transport measures the guided light at the patches once, then traces
# the patches as emitters in closed form. Every mode is measured against converged path
# tracing. (A small camera here; `optitact bench render` runs the full 640 x 480 study.)

# %%
import tempfile
import time
from pathlib import Path

import numpy as np
from IPython.display import Image
from optitact.render.pathtrace import spot_pixels
from optitact.render.emission import emission_table
from optitact.render.scene import patch_mesh

import optitact
from optitact.optics.contact import contact_patches
from optitact.studies.bench_render import bench_render, render_cases

sensor = optitact.optics.sensor.DomeSensor.default()
camera = optitact.optics.camera.FisheyeCamera(width=160, height=120)
cases = render_cases(sensor)

# %% [markdown]
# **Only loaded elements get geometry, only their pixels are rendered.**

# %%
for name, f in cases.items():
    mesh = patch_mesh(contact_patches(sensor, f), radius=sensor.outer_radius, inset=0.02, segments=24)
    pixels = spot_pixels(sensor, camera, f)
    print(f"{name:8s} loaded elements {int((f[:, 2] > 0).sum()):2d}   patch triangles "
          f"{0 if mesh is None else len(mesh[1]):5d}   pixels rendered {pixels.mean():6.1%} of the frame")

# %% [markdown]
# **Two-stage light transport.** Stage 1 (once, cached): path-trace probe patches to
# measure the radiance a patch emits at each polar angle and radius, and how other patches
# dim or feed it. A coarse table here (4-degree steps, 512 samples per pixel: about half a
# minute, or none when the cache has it); the default one has 2-degree steps and 4096 samples
# per pixel.

# %%
t0 = time.perf_counter()
table = emission_table(sensor, camera, thetas_deg=tuple(range(0, 78, 4)), radii_mm=(0.15, 0.3, 0.5), spp=512)
print(f"stage 1: {time.perf_counter() - t0:.0f} s (cached on disk for later runs)")
print("isolated-patch radiance along the dome (radius 0.3 mm):",
      np.round(table(table.theta, 0.3), 2))

# %% [markdown]
# **Time against error.** Each mode at several settings on five loaded elements, against a
# converged (512-spp) reference. Without a calibration for this small camera the error is
# the relative error of G.

# %%
work = Path(tempfile.mkdtemp())
result = bench_render((16, 64), modes=("brute", "pixels", "adaptive", "two_stage"), targets=(0.05,),
                      n_subs=(8,), reference_spp=512, width=camera.width, height=camera.height,
                      cases=("5-heavy",), table=table, plot=work / "pareto.png", progress=False)
for row in result["rows"]:
    print(f"{row['case']:8s} {row['mode']:9s} {str(row['setting']):6s} {row['seconds']:8.3f} s   "
          f"G error {row['g_rel_error']:.4f}   u error {row['u_error_mm']:.4f} mm")
print(result["headline"])
Image(filename=str(work / "pareto.png"))
