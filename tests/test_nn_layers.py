"""Layers and combinators of jaxocean.nn: declared shapes, gradients, reference values."""

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from jax import lax
from jax.test_util import check_grads

from jaxocean.nn import backbones, discriminators
from jaxocean.nn import layers as nl

LAYERS = {
    "dense": (nl.Dense(5), (2, 7)),
    "conv3": (nl.Conv(4, 3), (2, 9, 7, 3)),
    "conv_stride2_odd": (nl.Conv(4, 3, 2), (2, 9, 7, 3)),
    "conv4_stride2": (nl.Conv(2, 4, 2), (1, 8, 8, 3)),
    "conv_transpose": (nl.ConvTranspose(3, 2), (2, 5, 4, 6)),
    "upsample": (nl.Upsample(3), (1, 4, 5, 2)),
    "avgpool": (nl.AvgPool(2), (2, 8, 6, 3)),
    "groupnorm": (nl.GroupNorm(2), (2, 5, 5, 4)),
    "dropout": (nl.Dropout(0.5), (2, 6)),
    "relu": (nl.Relu, (3, 4)),
    "serial": (nl.serial(nl.Conv(4), nl.GroupNorm(2), nl.Relu, nl.Conv(2, 1)), (2, 6, 6, 3)),
    "residual": (nl.residual(nl.Conv(3), nl.Relu), (2, 6, 6, 3)),
    "residual_projection": (nl.residual(nl.Conv(5), shortcut=nl.Conv(5, 1)), (2, 6, 6, 3)),
    "concat": (nl.serial(nl.fan_out(2), nl.parallel(nl.Conv(2), nl.Identity), nl.fan_in_concat()), (2, 6, 6, 3)),
    "resnet": (backbones.ResNet(8, 2, downsample=1), (2, 8, 8, 3)),
    "unet": (backbones.UNet((4, 8, 8)), (2, 8, 12, 3)),
    "patch_disc": (discriminators.PatchDiscriminator(4, 2), (2, 8, 8, 3)),
}


@pytest.mark.parametrize("name", [pytest.param(n, marks=pytest.mark.slow) if n == "unet" else n  # unet: 14 s
                                  for n in sorted(LAYERS)])
def test_declared_shape_is_the_applied_shape(name, key):
    layer, shape = LAYERS[name]
    out_shape, params = layer.init(key, shape)
    x = jax.ShapeDtypeStruct(shape, jnp.float32)
    # the applied shape by abstract evaluation: apply traced, nothing compiled
    y = jax.eval_shape(lambda p, x: layer.apply(p, x, key=jax.random.fold_in(key, 2), train=True), params, x)
    assert y.shape == tuple(out_shape)
    # an unknown batch size (-1) declares the same per-example shape
    out_unknown, _ = layer.init(key, (-1,) + shape[1:])
    assert tuple(out_unknown[1:]) == tuple(out_shape[1:])


def test_conv_matches_lax_reference(key):
    layer = nl.Conv(5, 3, 2)
    _, p = layer.init(key, (2, 9, 8, 3))
    x = jax.random.normal(key, (2, 9, 8, 3))
    ref = lax.conv_general_dilated(x, p["w"], (2, 2), "SAME",
                                   dimension_numbers=("NHWC", "HWIO", "NHWC")) + p["b"]
    np.testing.assert_allclose(layer.apply(p, x), ref, rtol=1e-6, atol=1e-6)
    # SAME with stride 2 on 9 rows: output 5 rows, the centre tap of output 0 is input row 0
    assert layer.apply(p, x).shape == (2, 5, 4, 5)


def test_conv_transpose_is_the_transpose_of_the_strided_conv(key):
    """<ConvT(x), y> == <x, ConvT^T(y)> where ConvT^T is the kernel-2 stride-2 conv."""
    layer = nl.ConvTranspose(3, 2)
    _, p = layer.init(key, (1, 4, 4, 2))
    p = dict(p, b=jnp.zeros_like(p["b"]))
    x = jax.random.normal(key, (1, 4, 4, 2))
    y = jax.random.normal(jax.random.fold_in(key, 1), (1, 8, 8, 3))
    lhs = jnp.sum(layer.apply(p, x) * y)
    _, vjp = jax.vjp(lambda x: layer.apply(p, x), x)
    rhs = jnp.sum(x * vjp(y)[0])
    np.testing.assert_allclose(lhs, rhs, rtol=1e-5)
    # the block of output pixel (2i + a, 2j + b) is x[i, j] @ w[:, (a, b) slot]
    w = p["w"].reshape(2, 2, 2, 3)
    np.testing.assert_allclose(layer.apply(p, x)[0, 3, 4], x[0, 1, 2] @ w[:, 1, 0], rtol=1e-5)


def test_groupnorm_normalises_each_group(key):
    layer = nl.GroupNorm(2)
    _, p = layer.init(key, (3, 4, 4, 6))
    x = 5.0 + 3.0 * jax.random.normal(key, (3, 4, 4, 6))
    y = layer.apply(p, x).reshape(3, 16, 2, 3)
    np.testing.assert_allclose(y.mean((1, 3)), 0.0, atol=1e-5)
    np.testing.assert_allclose(y.var((1, 3)), 1.0, atol=1e-3)
    # no batch statistics: an image's output does not depend on its batch mates
    np.testing.assert_allclose(layer.apply(p, x)[:1], layer.apply(p, x[:1]), rtol=1e-6)
    # then each channel's own scale and shift
    scale, shift = jnp.linspace(0.5, 2.0, 6), jnp.linspace(-1.0, 1.0, 6)
    np.testing.assert_allclose(layer.apply({"scale": scale, "shift": shift}, x),
                               y.reshape(3, 4, 4, 6) * scale + shift, rtol=1e-5, atol=1e-5)


def test_dropout_train_and_eval(key):
    layer = nl.Dropout(0.25)
    x = jnp.ones((1000,))
    np.testing.assert_array_equal(layer.apply((), x), x)
    y = layer.apply((), x, key=key, train=True)
    assert 0.65 < float(jnp.mean(y > 0)) < 0.85
    np.testing.assert_allclose(y[y > 0], 1 / 0.75, rtol=1e-6)
    with pytest.raises(ValueError, match="PRNG key"):
        layer.apply((), x, train=True)


def test_bad_shapes_are_named(key):
    with pytest.raises(ValueError, match="rank-4"):
        nl.Conv(3).init(key, (2, 5, 3))
    with pytest.raises(ValueError, match="divisible"):
        nl.GroupNorm(4).init(key, (1, 4, 4, 6))
    with pytest.raises(ValueError, match="divisible"):
        nl.AvgPool(2).init(key, (1, 5, 4, 3))
    with pytest.raises(ValueError, match="equal shapes"):
        nl.fan_in_sum().init(key, ((1, 4), (1, 5)))


@pytest.mark.parametrize("make", [lambda: nl.Upsample(0), lambda: nl.AvgPool(-1), lambda: nl.ConvTranspose(3, 0),
                                  lambda: nl.GroupNorm(-2), lambda: nl.GroupNorm(0), lambda: nl.Dense(0),
                                  lambda: nl.Conv(-3), lambda: nl.Conv(3, 2.5), lambda: nl.Conv(3, 3, True)])
def test_bad_layer_sizes_are_named(make, key):
    # were accepted: AvgPool(-1) declared (1, -4, -4, 1), Upsample(0) and Dense(0) empty
    # outputs, GroupNorm(-2) passed its divisibility check, Conv(3, 2.5) a compiler error
    with pytest.raises(ValueError, match="must be an int >= 1"):
        make()


def test_groupnorm_names_channels_that_its_groups_do_not_divide_at_apply(key):
    layer = nl.GroupNorm(4)
    _, params = layer.init(key, (1, 4, 4, 8))
    with pytest.raises(ValueError, match="divisible by 4; got 6"):
        layer.apply({k: v[:6] for k, v in params.items()}, jnp.ones((1, 4, 4, 6)))


def test_odd_sizes_are_refused_at_init_and_apply(key):
    # the ResNet's stride-2 conv and transposed conv turned 7 x 9 into 8 x 10 without a word
    # traced only (jax.eval_shape): nothing compiled
    with pytest.raises(ValueError, match=r"ResNet\(downsample=1\) needs H and W divisible by 2; got \(7, 9\)"):
        jax.eval_shape(lambda k: backbones.ResNet(4, 1).init(k, (1, 7, 9, 3))[1], key)
    for net in (backbones.ResNet(4, 1), backbones.UNet((4, 8))):
        params = jax.eval_shape(lambda k: net.init(k, (-1, 8, 8, 3))[1], key)
        # the params do not fix the size: an odd input after an even init (a reshape error before)
        with pytest.raises(ValueError, match="divisible by 2"):
            jax.eval_shape(net.apply, params, jax.ShapeDtypeStruct((1, 7, 8, 3), jnp.float32))
        assert jax.eval_shape(net.apply, params, jax.ShapeDtypeStruct((1, 6, 10, 3), jnp.float32)).shape == \
            (1, 6, 10, 4)
    # a parallel layer given more inputs than it has layers dropped the rest
    par = nl.parallel(nl.Identity, nl.Identity)
    _, params = par.init(key, ((1, 2), (1, 2)))
    with pytest.raises(ValueError, match="parallel of 2 layers got 3 inputs"):
        par.apply(params, (jnp.ones((1, 2)),) * 3)


@pytest.mark.parametrize("name", ["dense", "conv_stride2_odd", "conv_transpose", "groupnorm", "residual"])
def test_gradients_match_finite_differences(name, x64, key):
    layer, shape = LAYERS[name]
    _, params = layer.init(key, shape)
    params = jax.tree.map(lambda a: jnp.asarray(a, jnp.float64), params)
    x = jax.random.normal(jax.random.fold_in(key, 3), shape, jnp.float64)
    check_grads(lambda p, x: layer.apply(p, x), (params, x), order=1, modes=("rev",), eps=1e-4, atol=1e-4,
                rtol=1e-4)


def test_a_tiny_net_overfits_one_batch(key):
    net = nl.serial(backbones.UNet((8, 8)), nl.Conv(2, 1))
    _, params = net.init(key, (4, 8, 8, 3))
    x = jax.random.normal(key, (4, 8, 8, 3))
    y = jnp.stack([jnp.sin(x[..., 0] * 2) * x[..., 1], x[..., 2] ** 2], -1)
    opt = optax.adam(1e-2)
    state = opt.init(params)

    @jax.jit
    def step(params, state):
        loss, g = jax.value_and_grad(lambda p: jnp.mean((net.apply(p, x) - y) ** 2))(params)
        u, state = opt.update(g, state)
        return optax.apply_updates(params, u), state, loss

    first = None
    for _ in range(300):
        params, state, loss = step(params, state)
        first = first if first is not None else float(loss)
    assert float(loss) < first / 100
