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
# # 3. Fitting waves and forecasting
#
# From a sequence of **geometry** frames (normal and roughness per pixel; an input -- here
# rendered by the library itself), `fit.waves` recovers the component wave trains
# `{h, ω, θ, φ}`: frequencies and directions from the space-time spectrum of the slopes,
# amplitudes and phases by a linear solve, then a structured Levenberg–Marquardt, the number
# of waves chosen by BIC. The fitted waves are then advanced in time and re-rendered.
# Sizes shrink when `JAXOCEAN_SMALL=1`.

# %%
import os

import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from jaxocean import camera, fit, forecast, plots, render
from jaxocean.waves import make_waves

small = os.environ.get("JAXOCEAN_SMALL") == "1"
n = 32 if small else 64
n_frames = 6 if small else 8

# a swell of three long-crested trains, 2.9-6.0 m long, seen from 20 m looking steeply down
truth = make_waves(amplitude=[0.03, 0.02, 0.015], omega=[3.2, 3.9, 4.6], theta=[0.4, 1.1, -0.2],
                   phase=[0.5, 2.0, 4.0])
cam = camera.make_camera(height=20.0, pitch=1.2, fov=0.9, resolution=(n, n))
times = jnp.arange(n_frames) * 0.12
frames = [render.geometry(truth, cam, t, plan=None) for t in times]
normals = jnp.stack([g.normal for g in frames])
roughness = jnp.stack([g.roughness for g in frames])

# %%
result = fit.waves(normals, roughness, cam, times, max_waves=6)
m = fit.match(result.waves, truth)
print(f"{int(result.n_waves)} waves fitted, success {bool(result.success)}, "
      f"mean normal error {np.degrees(float(result.normal_error)):.2e} deg")
print("matched", m.true_index.tolist(), "missed", m.missed.tolist(), "spurious", m.spurious.tolist())
print("largest |errors|: h", float(np.max(np.abs(m.abs_error.amplitude))), "m, omega",
      float(np.max(np.abs(m.abs_error.omega))), "rad/s")
assert m.true_index.size == 3 and float(np.max(np.abs(m.abs_error.amplitude))) < 1e-3

# %% [markdown]
# ## What is and is not identifiable
# * A wave is found when the view separates it from its neighbours: its frequency and
#   direction differ by more than the window's resolution (about 2π / duration in ω and one
#   wavelength over the view's width in k). Waves closer than that trade amplitude between
#   them; the fit's `uncertainty` (1-σ per wave, from JᵀJ at the stated noise) says how much.
# * Waves shorter than a pixel reach the data only through the roughness: their total slope
#   variance is observed, not their individual parameters (`fit.spectrum` fits a spectral
#   tail to it).
# * Waves longer than the view or slower than the observed time barely change the frames.

# %%
print({name: np.asarray(u).round(6).tolist() for name, u in zip(result.waves._fields, result.uncertainty)})

# %% [markdown]
# ## Forecast
# The fitted waves, advanced by their own dispersion, against the truth at frames 0, 50, 100.

# %%
f_times = jnp.asarray(forecast.frame_times(times, [0, 50, 100]), normals.dtype)
true_geo = forecast.forecast(truth, f_times, cam).geometry
# the least-squares forecast: the fit's waves and long-wave band, each damped outside the
# fitted window by its frequency uncertainty (the stand-ins for what the window cannot separate fade)
model, sigma, window = fit.waves_fit.forecast_model(result, cam, times)
fit_geo = forecast.forecast(model, f_times, cam, window=window, frequency_sigma=sigma).geometry
err = np.degrees(np.asarray(forecast.geometry_error(fit_geo, true_geo).normal))
print("mean normal error per frame [deg]:", err.round(4).tolist())

fig, axes = plt.subplots(2, 3, figsize=(10, 6.5))
for i, frame in enumerate([0, 50, 100]):
    axes[0, i].imshow(plots.normal_to_rgb(true_geo.normal[i], true_geo.mask[i]))
    axes[0, i].set_title(f"true, frame {frame}")
    axes[1, i].imshow(plots.normal_to_rgb(fit_geo.normal[i], fit_geo.mask[i]))
    axes[1, i].set_title(f"forecast: {err[i]:.3f} deg")
for ax in axes.ravel():
    ax.axis("off")
