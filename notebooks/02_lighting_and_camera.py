# ---
# jupyter:
#   jupytext:
#     formats: ipynb,py:percent
#     text_representation:
#       extension: .py
#       format_name: percent
#   kernelspec:
#     display_name: Python 3
#     language: python
#     name: python3
# ---

# %% [markdown]
# # 2. Fitting the lighting and the camera
#
# Given an image **and its geometry** (normal and roughness per pixel), `fit.lighting`
# recovers the sun direction and the sun, sky and sea colours; `fit.camera` recovers the
# camera's height and pitch from an image of known waves. Both report `success` only when
# the answer explains the image. Sizes shrink when `JAXOCEAN_SMALL=1`.

# %%
import os
import time

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt

from jaxocean import camera, fit, plots, render, shading, spectrum

small = os.environ.get("JAXOCEAN_SMALL") == "1"
res = (32, 32) if small else (96, 96)

sea = spectrum.Spectrum(hs=1.0, tp=6.0, gamma=3.3, theta_mean=0.0, s_max=10.0)
waves = spectrum.sample_waves(jax.random.key(1), sea, 16 if small else 64).waves
cam = camera.make_camera(height=10.0, pitch=0.35, fov=0.8, resolution=res)
truth = shading.make_lighting(sun_azimuth=0.15, sun_elevation=0.3, sun_color=(20.0, 18.0, 15.0))
geo = render.geometry(waves, cam, 0.0, plan=None)
image = render.render(waves, cam, truth, 0.0, plan=None)

# %% [markdown]
# ## Lighting from a random start
# The image is linear in the three colours, so they are solved in closed form inside the
# residual and the solver searches only the two sun angles (starts from the glints and a
# sky grid). The speed–accuracy chart below runs each solver of the registry from the same
# random start: time (compilation included) against the sun's angular error.

# %%
init = fit.random_lighting(jax.random.key(7))
solvers = ("lm", "dogleg") if not small else ("lm",)  # each solver compiles once: the small run keeps one
rows = []
for name in solvers:
    t0 = time.perf_counter()
    result = fit.lighting(image, geo, cam, init=init, solver=name, throw=False)
    wall = time.perf_counter() - t0
    error = float(fit.lighting_error(result.lighting, truth)["sun_angle_deg"])
    rows.append((name, wall, error, bool(result.success)))
    print(f"{name:13s} {wall:6.1f} s  sun off by {error:.2e} deg  steps {int(result.steps):3d}  "
          f"success {bool(result.success)}")
best = fit.lighting(image, geo, cam, init=init, throw=False)  # the "lm" fit again: compiled already
assert bool(best.success) and float(fit.lighting_error(best.lighting, truth)["sun_angle_deg"]) < 0.01

# %% [markdown]
# Without sun glitter in the image the sun direction is not determined, and the fit says so
# instead of reporting a false success (the colours it can determine are still returned).

# %%
behind = truth._replace(sun_azimuth=jnp.asarray(3.0))  # the sun behind the camera
dark = fit.lighting(render.render(waves, cam, behind, 0.0, plan=None), geo, cam, init=init, throw=False)
print(bool(dark.success), fit.lighting_fit.failure_message(dark))
assert not bool(dark.success) and not bool(dark.determined["sun_direction"])

# %% [markdown]
# ## Camera
# Height and pitch from an image of known waves and lighting, starting 3% high and
# 0.005 rad off in pitch; the full size runs coarse to fine over the hierarchy (footprint
# scaled 4, 2, 1), the small one at the finest level only.

# %%
start = camera.make_camera(height=10.3, pitch=0.355, fov=0.8, resolution=res)
t0 = time.perf_counter()
cam_fit = fit.camera(image, waves, 0.0, start, lighting=truth, throw=False,
                     search=(3, 3) if small else (7, 5), levels=(1.0,) if small else (4.0, 2.0, 1.0), plan=None)
print(f"height {float(cam_fit.camera.height):.4f} m (true 10), pitch {float(cam_fit.camera.pitch):.5f} rad "
      f"(true 0.35), success {bool(cam_fit.success)}, {time.perf_counter() - t0:.1f} s")

# %%
fig, axes = plt.subplots(1, 3, figsize=(13, 3.5))
for name, wall, error, ok in rows:
    axes[0].loglog(wall, max(error, 1e-12), "o" if ok else "x", label=name)
axes[0].set_xlabel("wall time incl. compilation [s]")
axes[0].set_ylabel("sun error [deg]")
axes[0].set_title("speed-accuracy, one random start")
axes[0].legend()
model = render.render(waves, cam, best.lighting, 0.0, plan=None)
for ax, picture, title in zip(axes[1:], [plots.display(image), plots.display(model)], ["observed", "re-rendered with the fit"]):
    ax.imshow(picture)
    ax.set_title(title)
    ax.axis("off")
