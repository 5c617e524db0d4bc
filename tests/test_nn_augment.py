"""Display augmentation of geometry-network inputs (jaxocean.nn.augment)."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxocean import radiometry
from jaxocean.io import dataset
from jaxocean.nn import augment as aug
from jaxocean.nn import geometry_train as gt

KINDS = ("srgb", "gamma", "bruneton", "linear")
# the largest radiance each response returns for a display value of 1 (radiometry docstring)
UPPER = {"srgb": 1.0, "gamma": 1.0, "linear": 1.0, "bruneton": 6.94}
_augment = jax.jit(aug.augment, static_argnums=2)


def _radiance(key, shape=(2, 24, 20, 3), high=0.6):
    """Sea-like radiance, log-uniform in [0.01, high]."""
    return jnp.exp(jax.random.uniform(key, shape, minval=np.log(0.01), maxval=np.log(high)))


@pytest.mark.parametrize("kind", KINDS)
def test_roundtrip_without_noise_or_quantisation_is_the_exposed_radiance(kind):
    linear = _radiance(jax.random.key(0))
    resp = radiometry.Response(kind)
    same = aug.display_roundtrip(jax.random.key(1), linear, resp, 1.0, 0.0, bits=None)
    np.testing.assert_allclose(same, linear, rtol=2e-5, atol=1e-7)
    # an exposure scale stays in the result: radiance relative to the unknown exposure
    scaled = aug.display_roundtrip(jax.random.key(1), linear, resp, 1.5, 0.0, bits=None)
    np.testing.assert_allclose(scaled, 1.5 * linear, rtol=2e-5, atol=1e-7)


@pytest.mark.parametrize("kind", KINDS)
def test_roundtrip_quantises_and_clips_like_a_display_file(kind):
    resp = radiometry.Response(kind)
    linear = _radiance(jax.random.key(2)).at[0, 0, 0].set(50.0)  # one saturated pixel
    out = aug.display_roundtrip(jax.random.key(3), linear, resp, 1.0, 0.0, bits=8)
    codes = np.asarray(radiometry.to_display(out, resp))[1:] * 255  # (bruneton caps the top code below 1)
    np.testing.assert_allclose(codes, np.round(codes), atol=2e-3)  # on the 8-bit codes
    assert np.max(np.abs(out - linear)[1:]) > 0  # and not the identity
    np.testing.assert_allclose(out[0, 0, 0], UPPER[kind], rtol=2e-3)  # saturated: the lower bound
    assert out.shape == linear.shape and out.dtype == jnp.float32


def test_noise_has_the_requested_standard_deviation_in_display_units():
    resp = radiometry.Response("srgb")
    linear = jnp.full((64, 64, 3), 0.1)
    out = aug.display_roundtrip(jax.random.key(4), linear, resp, 1.0, 0.02, bits=None)
    diff = np.asarray(radiometry.to_display(out, resp) - radiometry.to_display(linear, resp))
    assert np.std(diff) == pytest.approx(0.02, rel=0.05)
    assert abs(np.mean(diff)) < 0.002


def test_draw_covers_the_configured_ranges():
    config = aug.DisplayAugment()
    p = jax.vmap(lambda k: aug.draw(k, config))(jax.random.split(jax.random.key(5), 4000))
    assert np.all((p.exposure >= 0.5 * (1 - 1e-6)) & (p.exposure <= 2.0 * (1 + 1e-6)))
    assert np.all((p.noise >= 0) & (p.noise <= 0.03))
    assert set(np.asarray(p.response).tolist()) == {0, 1, 2}
    assert np.mean(p.clean) == pytest.approx(0.2, abs=0.03)
    # log-uniform exposure: the median is the geometric mean of the range
    assert np.median(p.exposure) == pytest.approx(1.0, rel=0.05)


def test_augment_is_deterministic_per_key_and_the_same_under_jit():
    config = aug.DisplayAugment(clean_fraction=0.0)
    linear = _radiance(jax.random.key(6), (2, 12, 10, 3))
    a = _augment(jax.random.key(7), linear, config)
    np.testing.assert_array_equal(a, _augment(jax.random.key(7), linear, config))
    np.testing.assert_array_equal(a, aug.augment(jax.random.key(7), linear, config))
    assert not np.array_equal(a, _augment(jax.random.key(8), linear, config))
    batch = jnp.stack([_augment(k, linear, config) for k in jax.random.split(jax.random.key(9), 6)])
    assert batch.shape == (6,) + linear.shape
    assert np.all(np.isfinite(batch)) and np.all(batch >= 0) and np.all(batch <= UPPER["bruneton"])


def test_a_sample_shares_one_exposure_and_clean_samples_pass_unchanged():
    linear = _radiance(jax.random.key(10), high=0.3)
    noiseless = aug.DisplayAugment(noise=(0.0, 0.0), bits=None, clean_fraction=0.0)
    for i in range(4):
        out = _augment(jax.random.key(i), linear, noiseless)
        ratio = np.asarray(out / linear)
        np.testing.assert_allclose(ratio, ratio.flat[0], rtol=1e-4)  # every frame, pixel, channel
    clean = _augment(jax.random.key(0), linear, aug.DisplayAugment(clean_fraction=1.0))
    np.testing.assert_array_equal(clean, linear)


def test_bad_settings_are_refused():
    with pytest.raises(ValueError, match="responses"):
        aug.DisplayAugment(responses=("srgb", "log")).validate()
    with pytest.raises(ValueError, match="exposure"):
        aug.DisplayAugment(exposure=(0.0, 1.0)).validate()
    with pytest.raises(ValueError, match="noise"):
        aug.DisplayAugment(noise=(0.02, 0.01)).validate()


@pytest.mark.slow  # simulates a dataset and compiles the batch preparation: 36 s at load 9
def test_training_batches_see_the_round_trip_and_keep_the_true_image(tmp_path):
    assert gt.CONFIGS["cpu"].augment is not None and gt.CONFIGS["cpu"].to_json()["augment"]["bits"] == 8
    dataset.simulate(tmp_path, 12, 1, (16, 16), seed=3, progress=False)
    data = dataset.Dataset(tmp_path)
    b = gt._batch_dict(next(data.batches(jax.random.key(0), "train", 2)))
    plain = gt._prepare(b, jax.random.key(1), "rgb", 16)
    seen = gt._prepare(b, jax.random.key(1), "rgb", 16, aug.DisplayAugment(clean_fraction=0.0))
    np.testing.assert_array_equal(seen["image"], plain["image"])
    np.testing.assert_array_equal(seen["mask"], plain["mask"])
    assert not np.allclose(seen["feats"][..., :3], plain["feats"][..., :3], atol=1e-3)
    np.testing.assert_array_equal(seen["feats"][..., 3:], plain["feats"][..., 3:])  # camera channels


def test_config_is_static_under_jit():
    # its docstring calls it static: jit(augment) failed on the response names as array leaves
    config = aug.DisplayAugment(clean_fraction=0.0)
    assert jax.tree.leaves(config) == [] and hash(config) == hash(aug.DisplayAugment(clean_fraction=0.0))
    x = jnp.full((4, 4, 3), 0.3, jnp.float32)
    key = jax.random.key(1)
    np.testing.assert_array_equal(jax.jit(aug.augment)(key, x, config), aug.augment(key, x, config))
