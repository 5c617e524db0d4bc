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
# # jaxocean quickstart
#
# The forward chain **spectrum → waves → trochoid surface → per-pixel shader**, and a
# gradient through all of it. Sizes shrink when `JAXOCEAN_SMALL=1` (CI runs this notebook).

# %%
import os

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt

from jaxocean import camera, plots, render, shading, spectrum

small = os.environ.get("JAXOCEAN_SMALL") == "1"
res = (48, 64) if small else (160, 240)
n_waves = 16 if small else 120

# %% [markdown]
# A JONSWAP sea (Hs = 1.2 m, Tp = 5.5 s), sampled into wave trains `{h, ω, θ, φ}`:

# %%
sea = spectrum.Spectrum(hs=1.2, tp=5.5, gamma=3.3, theta_mean=0.4, s_max=10.0)
sample = spectrum.sample_waves(jax.random.key(0), sea, n_waves)
waves = sample.waves
m = spectrum.moments(sea)
print(f"Hs from the spectrum: {float(m.hs):.3f} m; sum of h^2/2 = {float(jnp.sum(waves.amplitude**2) / 2):.4f} "
      f"m^2 vs band m0 = {float(sample.band_m0):.4f} m^2")

# %% [markdown]
# A camera 12 m above the sea looking 20° down, and the sun in front of it:

# %%
cam = camera.make_camera(height=12.0, pitch=0.35, fov=0.8, resolution=res)
light = shading.make_lighting(sun_azimuth=0.1, sun_elevation=0.35)
geo = render.geometry(waves, cam, 0.0)
image = render.shade(geo.normal, geo.roughness, cam, light, slope_variance=geo.slope_variance)

fig, axes = plt.subplots(1, 3, figsize=(12, 3))
for ax, picture, title in zip(axes, [plots.display(image), plots.normal_to_rgb(geo.normal, geo.mask),
                                     plots.roughness_to_rgb(geo.roughness, geo.mask)],
                              ["image", "normal", "roughness"]):
    ax.imshow(picture)
    ax.set_title(title)
    ax.axis("off")

# %% [markdown]
# Everything is differentiable: the gradient of the mean image brightness with respect to
# the sun elevation and to every wave amplitude.

# %%
def brightness(elevation, amplitude):
    lit = light._replace(sun_elevation=elevation)
    return jnp.mean(render.render(waves._replace(amplitude=amplitude), cam, lit, 0.0, plan=None))

d_elevation, d_amplitude = jax.grad(brightness, argnums=(0, 1))(light.sun_elevation, waves.amplitude)
print(f"d brightness / d sun elevation = {float(d_elevation):.4f} per rad")
assert jnp.isfinite(d_elevation) and bool(jnp.all(jnp.isfinite(d_amplitude)))
assert image.shape == res + (3,) and bool(jnp.all(image >= 0))
