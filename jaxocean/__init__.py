"""jaxocean: dynamic ocean inverse modeling with differentiable rendering, in JAX.

The forward chain spectrum -> waves -> trochoid surface -> per-pixel shader is made of
pure, jittable, differentiable functions over registered pytrees; the inverse steps
(fitting, learning) run through it. Modules, one concept each:

``waves``      Waves pytree, dispersion, steepness, validation
``hierarchy``  Nyquist filter: per-wave displacement / normal / roughness weights
``surface``    trochoid displacement, analytic normals, slope variance, grid fast path
``errors``     the two-tier error policy
"""

from jaxocean import errors, hierarchy, surface, waves
from jaxocean.errors import InvalidValueError
from jaxocean.hierarchy import WaveWeights
from jaxocean.surface import GridSurface, on_grid
from jaxocean.waves import GRAVITY, Waves, make_waves

__version__ = "0.1.0"

__all__ = [
    "errors",
    "hierarchy",
    "surface",
    "waves",
    "InvalidValueError",
    "WaveWeights",
    "GridSurface",
    "on_grid",
    "GRAVITY",
    "Waves",
    "make_waves",
    "__version__",
]
