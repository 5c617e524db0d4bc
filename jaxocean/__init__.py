"""jaxocean: dynamic ocean inverse modeling with differentiable rendering, in JAX.

The forward chain spectrum -> waves -> trochoid surface -> per-pixel shader is made of
pure, jittable, differentiable functions over registered pytrees; the inverse steps
(fitting, learning) run through it. Modules, one concept each:

``spectrum``   PM / JONSWAP spectra, directional spreading, moments, wave sampling
``waves``      Waves pytree, dispersion, steepness, validation
``hierarchy``  Nyquist filter: per-wave displacement / normal / roughness weights
``surface``    trochoid displacement, analytic normals, slope variance, grid fast paths
``camera``     Camera pytree, pixel rays, sea-plane intersection, pixel footprint
``shading``    Lighting pytree, Bruneton ocean BRDF, Fresnel, sky, tone maps
``render``     geometry(), shade(), render(): the composed per-pixel renderer
``errors``     the two-tier error policy
``compile_cache``  XLA's persistent compilation cache (``compile_cache.enable()``)
"""

from jaxocean import camera, compile_cache, errors, hierarchy, render, shading, spectrum, surface, waves
from jaxocean.camera import Camera, make_camera, make_orthographic
from jaxocean.errors import InvalidValueError
from jaxocean.hierarchy import WaveWeights
from jaxocean.render import Geometry, RenderPlan
from jaxocean.shading import Lighting, make_lighting, tonemap
from jaxocean.spectrum import Spectrum, sample_waves
from jaxocean.surface import GridSurface, on_grid
from jaxocean.waves import GRAVITY, Waves, make_waves

__version__ = "0.1.0"

__all__ = [
    "camera", "compile_cache", "errors", "hierarchy", "render", "shading", "spectrum", "surface", "waves",
    "Camera", "make_camera", "make_orthographic",
    "InvalidValueError",
    "WaveWeights",
    "Geometry", "RenderPlan",
    "Lighting", "make_lighting", "tonemap",
    "Spectrum", "sample_waves",
    "GridSurface", "on_grid",
    "GRAVITY", "Waves", "make_waves",
    "__version__",
]
