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
# # 1. The forward model
#
# **spectrum → waves → surface → image**, the Nyquist hierarchy that splits the waves
# between the per-pixel normal and the sub-pixel roughness, and gradients through all of it.
# Conventions (units, axes, phase sign) are in `docs/design.md`. Sizes shrink when
# `JAXOCEAN_SMALL=1` (`make test` runs this notebook that way).

# %%
import os

import jax
import jax.numpy as jnp
import matplotlib.pyplot as plt
import numpy as np

from jaxocean import camera, hierarchy, plots, render, shading, spectrum, surface

small = os.environ.get("JAXOCEAN_SMALL") == "1"
res = (40, 56) if small else (160, 240)
n_waves = 24 if small else 120

# %% [markdown]
# ## Spectrum → waves
# A JONSWAP sea (Hs = 1.2 m, Tp = 5.5 s) sampled into `n_waves` trains `{h, ω, θ, φ}`. The
# sampled amplitudes carry the band's energy: Σ h²/2 = m₀ of the band.

# %%
sea = spectrum.Spectrum(hs=1.2, tp=5.5, gamma=3.3, theta_mean=0.4, s_max=10.0)
sample = spectrum.sample_waves(jax.random.key(0), sea, n_waves)
waves = sample.waves
energy = float(jnp.sum(waves.amplitude**2) / 2)
print(f"Hs of the spectrum {float(spectrum.moments(sea).hs):.3f} m; sum h^2/2 = {energy:.4f} m^2, "
      f"band m0 = {float(sample.band_m0):.4f} m^2")
assert abs(energy - float(sample.band_m0)) < 1e-4 * float(sample.band_m0)

# %% [markdown]
# ## Waves → surface → geometry
# The camera looks 20° down from 12 m. Each pixel's footprint on the sea grows with distance;
# Bruneton's filter gives each wave a weight in the normal, smoothstep(1, 1.5, λ / footprint),
# and the rest of it in the roughness.

# %%
cam = camera.make_camera(height=12.0, pitch=0.35, fov=0.8, resolution=res)
geo = render.geometry(waves, cam, 0.0, plan=None)
footprint = float(jnp.median(geo.footprint[geo.mask]))
w = hierarchy.weights(waves, jnp.asarray(footprint))
print(f"median footprint {footprint:.3f} m: {int(jnp.sum(w.normal > 0.5))} of {n_waves} waves in the normal, "
      f"the rest in the roughness")

# %% [markdown]
# ## Geometry → image
# The ocean BRDF (sun glitter, reflected sky, refracted sea colour) shades each pixel.

# %%
light = shading.make_lighting(sun_azimuth=0.1, sun_elevation=0.35)
image = render.render(waves, cam, light, 0.0, plan=None)
assert image.shape == res + (3,) and bool(jnp.all(jnp.isfinite(image)))

# %% [markdown]
# ## Gradients
# The image is differentiable with respect to every wave, camera and lighting parameter.
# Here d(mean brightness)/d(sun elevation) by `jax.grad`, checked against a central
# difference.

# %%
@jax.jit
def brightness(elevation):
    return jnp.mean(render.render(waves, cam, light._replace(sun_elevation=elevation), 0.0, plan=None))


e0 = light.sun_elevation
grad = float(jax.jit(jax.grad(brightness))(e0))
step = 1e-2
central = float((brightness(e0 + step) - brightness(e0 - step)) / (2 * step))
print(f"grad {grad:.5f}, central difference {central:.5f} per rad")
assert abs(grad - central) < 0.05 * abs(central) + 1e-6

# %%
fig, axes = plt.subplots(1, 4, figsize=(15, 3))
lam = np.asarray(2 * np.pi / (waves.omega**2 / 9.81))
axes[0].semilogx(lam, np.asarray(w.normal), "o", label="normal")
axes[0].semilogx(lam, np.asarray(w.roughness), "x", label="roughness")
axes[0].set_xlabel("wavelength [m]")
axes[0].set_title("hierarchy weights at the median footprint")
axes[0].legend()
for ax, picture, title in zip(axes[1:], [plots.display(image), plots.normal_to_rgb(geo.normal, geo.mask),
                                         plots.roughness_to_rgb(geo.roughness, geo.mask)],
                              ["image", "normal", "roughness"]):
    ax.imshow(picture)
    ax.set_title(title)
    ax.axis("off")
