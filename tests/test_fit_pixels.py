"""fit.pixels: the per-pixel inversion explains each pixel's colour (not necessarily its slope)."""

import jax
import numpy as np
import pytest

from jaxocean import render, shading
from jaxocean.errors import InvalidValueError
from jaxocean.fit import pixels
from jaxocean.io import dataset


@pytest.mark.slow  # a per-pixel inversion of a whole frame
def test_inversion_reproduces_the_pixels_it_calls_explained():
    scene = dataset.sample_scene(jax.random.key(7), dataset.SceneRanges(), (16, 20), 1)
    images, geo = dataset.render_scene(scene)
    fit = pixels.invert(images[0], scene.camera, scene.lighting)
    mask = np.asarray(geo.mask[0], bool)
    np.testing.assert_array_equal(np.asarray(fit.mask), mask)
    explained = np.asarray(fit.explained)
    assert explained[mask].mean() > 0.8
    again = render.shade(fit.normal, None, scene.camera, scene.lighting, slope_variance=fit.slope_variance)
    rel = np.abs(np.asarray(again) - np.asarray(images[0])) / np.asarray(images[0])
    assert np.max(rel[explained]) < 5e-3  # tolerance 1e-3 on log1p(I / median) per channel
    # a pixel is explained only where its residual is under the tolerance
    assert np.all(np.asarray(fit.residual)[explained] <= 1e-3)
    np.testing.assert_allclose(np.linalg.norm(np.asarray(fit.normal), axis=-1), 1.0, atol=1e-5)
    assert np.all(np.asarray(fit.slope_variance) >= shading.MIN_SLOPE_VARIANCE_AXIS * (1 - 1e-6))


def test_bad_image_shape_is_named():
    scene = dataset.sample_scene(jax.random.key(7), dataset.SceneRanges(), (16, 20), 1)
    with pytest.raises(ValueError, match=r"\(16, 20, 3\)"):
        pixels.invert(np.ones((20, 16, 3)), scene.camera, scene.lighting)
    with pytest.raises(ValueError, match="iterations"):
        pixels.invert(np.ones((16, 20, 3)), scene.camera, scene.lighting, iterations=0)


def test_nan_sea_pixels_are_named_not_returned_as_nan_residuals():
    scene = dataset.sample_scene(jax.random.key(7), dataset.SceneRanges(), (8, 10), 1)
    image = np.full((8, 10, 3), 0.1)
    sea = np.argwhere(np.asarray(render.geometry(scene.waves, scene.camera, 0.0).mask))[0]
    image[sea[0], sea[1], 1] = np.nan
    with pytest.raises(InvalidValueError, match="NaN/inf sea pixel"):
        pixels.invert(image, scene.camera, scene.lighting, iterations=1)
