"""Fitting applications: optimistix / jaxopt / optax solvers through the forward models.

* :mod:`jaxocean.fit.solvers`  one registry of solvers (name -> runner) used by every fit
* :mod:`jaxocean.fit.lighting` sun direction and sun / sky / sea colours from an image and
  its geometry (variable projection: colours in closed form, two sun angles searched)
* :mod:`jaxocean.fit.camera`   camera height, pitch (and field of view) from an image and
  its waves, alone or jointly with the lighting
* :mod:`jaxocean.fit.reedit`   re-render fitted scenes under a new camera or light; style
  transfer
* :mod:`jaxocean.fit.heights`  surface heights from a normal map (perspective normal
  integration: each pixel's hit on the surface, up to the window's mean level)
* :mod:`jaxocean.fit.waves`    component waves from a geometry sequence (spectral start,
  greedy detection with order selection, structured Levenberg-Marquardt)
* :mod:`jaxocean.fit.photometric` waves, lighting and exposure refined jointly against the
  image sequence through the renderer (robust IRLS loss, outlier mask)
* :mod:`jaxocean.fit.spectrum` sea state (Hs, Tp, gamma, direction, spreading) behind fitted
  waves and the roughness; the spectrum correction of unresolved amplitudes
* :mod:`jaxocean.fit.pixels`   each sea pixel's slope and roughness from its colour alone, with
  the camera and lighting known (``fit.pixels.invert``; a baseline)

The functions ``fit.waves``, ``fit.spectrum``, ``fit.camera``, ``fit.lighting``,
``fit.photometric`` and ``fit.heights`` shadow their modules' names on this package; the
modules are re-exported as ``waves_fit``, ``spectrum_fit``, ``camera_fit``, ``lighting_fit``,
``photometric_fit`` and ``heights_fit`` (and the module of ``fit.reedit`` as ``reedit_module``).

Usage::

    from jaxocean import fit
    result = fit.lighting(image, geometry, camera)          # LightingFit
    images = fit.reedit(waves, camera, result.lighting, times, camera_height=5.0)
    waves = fit.waves(normals, roughness, camera, times).waves   # WaveFit
    sea = fit.spectrum(waves, camera=camera, roughness=roughness) # SpectrumFit
"""

from jaxocean.fit import camera as camera_fit
from jaxocean.fit import heights as heights_fit
from jaxocean.fit import lighting as lighting_fit
from jaxocean.fit import photometric as photometric_fit
from jaxocean.fit import pixels as pixels_fit
from jaxocean.fit import reedit as reedit_module
from jaxocean.fit import solvers
from jaxocean.fit import spectrum as spectrum_fit
from jaxocean.fit import waves as waves_fit
from jaxocean.fit.camera import CAMERA_FIELDS, CameraFit, camera
from jaxocean.fit.lighting import (
    COLOR_FIELDS,
    COLOR_RANGES,
    FIT_FIELDS,
    STRUCTURES,
    LightingFit,
    fit_to_dict,
    lighting,
    lighting_error,
    lighting_from_dict,
    lighting_to_dict,
    nnls_small,
    pq_to_direction,
    pq_to_sun,
    random_lighting,
    sun_to_pq,
    tonemap_weights,
)
from jaxocean.fit.heights import HeightMap, heights
from jaxocean.fit.photometric import PhotometricFit, photometric
from jaxocean.fit.reedit import StyleTransfer, edit_camera, edit_lighting, reedit, reedit_scene, style_transfer
from jaxocean.fit.spectrum import SeaState, SpectrumFit, correct_amplitudes, sea_state, spectrum, tail_waves
from jaxocean.fit.waves import (
    NoWaveFound,
    OrderSelection,
    SpectralEstimate,
    WaveFit,
    WaveMatch,
    match,
    refine,
    resolvable,
    separable,
    spectral_estimate,
    spectral_init,
    waves,
)
from jaxocean.fit.solvers import SOLVER_NAMES, SOLVERS, FitError, SolverOutput, get_solver, solve

__all__ = [
    # modules
    "solvers",
    "lighting_fit",
    "camera_fit",
    "photometric_fit",
    "pixels_fit",
    "pixels",
    "reedit_module",
    "waves_fit",
    "spectrum_fit",
    "heights_fit",
    # solvers
    "SOLVERS",
    "SOLVER_NAMES",
    "SolverOutput",
    "FitError",
    "get_solver",
    "solve",
    # lighting
    "FIT_FIELDS",
    "COLOR_FIELDS",
    "STRUCTURES",
    "COLOR_RANGES",
    "LightingFit",
    "lighting",
    "random_lighting",
    "tonemap_weights",
    "lighting_error",
    "sun_to_pq",
    "pq_to_sun",
    "pq_to_direction",
    "nnls_small",
    "fit_to_dict",
    "lighting_from_dict",
    "lighting_to_dict",
    # camera
    "CAMERA_FIELDS",
    "CameraFit",
    "camera",
    # photometric refinement
    "PhotometricFit",
    "photometric",
    # re-editing
    "StyleTransfer",
    "edit_camera",
    "edit_lighting",
    "reedit",
    "reedit_scene",
    "style_transfer",
    # heights
    "HeightMap",
    "heights",
    # waves
    "WaveFit",
    "NoWaveFound",
    "OrderSelection",
    "SpectralEstimate",
    "WaveMatch",
    "waves",
    "refine",
    "match",
    "resolvable",
    "separable",
    "spectral_estimate",
    "spectral_init",
    # spectrum
    "SpectrumFit",
    "SeaState",
    "spectrum",
    "sea_state",
    "correct_amplitudes",
    "tail_waves",
]
