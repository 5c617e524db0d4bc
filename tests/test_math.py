"""The numerical helpers of jaxocean._math: fast float32 sincos, inv_sqrt, and the
component split and materialisation whose derivative rules shape what XLA compiles."""

import jax
import jax.numpy as jnp
import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from jax.test_util import check_grads

import pytest

from jaxocean._math import components, inv_sqrt, materialize, materialize_cotangent, sincos


def test_float32_sincos_is_within_a_few_ulp_of_the_exact_values():
    # every phase the renderer and the fits produce: |x| up to 1e4 rad
    x = jnp.linspace(-1e4, 1e4, 400_001, dtype=jnp.float32)
    s, c = sincos(x)
    exact = np.asarray(x, np.float64)
    assert s.dtype == c.dtype == jnp.float32
    assert np.max(np.abs(np.asarray(s) - np.sin(exact))) < 2e-7
    assert np.max(np.abs(np.asarray(c) - np.cos(exact))) < 2e-7
    # quadrant boundaries and exact points
    q = jnp.asarray([0.0, np.pi / 2, np.pi, -np.pi / 2, 3 * np.pi / 4, -np.pi / 4], jnp.float32)
    s, c = sincos(q)
    np.testing.assert_allclose(s, np.sin(np.asarray(q, np.float64)), atol=1e-7)
    np.testing.assert_allclose(c, np.cos(np.asarray(q, np.float64)), atol=1e-7)


@given(st.floats(-3000.0, 3000.0))
def test_float32_sincos_matches_numpy_and_stays_on_the_unit_circle(x):
    s, c = sincos(jnp.float32(x))
    x64 = float(np.float32(x))
    assert abs(float(s) - np.sin(x64)) < 2e-7 and abs(float(c) - np.cos(x64)) < 2e-7
    assert abs(float(s) ** 2 + float(c) ** 2 - 1.0) < 5e-7


def test_sincos_float64_is_the_library_function_and_gradients_are_exact(x64):
    x = jnp.linspace(-50.0, 50.0, 101)
    s, c = sincos(x)
    np.testing.assert_array_equal(s, jnp.sin(x))
    np.testing.assert_array_equal(c, jnp.cos(x))
    check_grads(lambda x: sincos(x)[0] * 2.0 + sincos(x)[1] ** 2, (x,), order=2, modes=("fwd", "rev"))


def test_float32_sincos_derivative_is_cos_and_minus_sin():
    x = jnp.linspace(-20.0, 20.0, 41, dtype=jnp.float32)
    ds = jax.vmap(jax.grad(lambda x: sincos(x)[0]))(x)
    dc = jax.vmap(jax.grad(lambda x: sincos(x)[1]))(x)
    s, c = sincos(x)
    np.testing.assert_array_equal(ds, c)
    np.testing.assert_array_equal(dc, -s)


def test_sincos_propagates_non_finite_inputs():
    s, c = sincos(jnp.asarray([jnp.inf, jnp.nan], jnp.float32))
    assert np.all(np.isnan(s)) and np.all(np.isnan(c))


def test_inv_sqrt_value_and_gradient(x64):
    x = jnp.geomspace(1e-8, 1e8, 33)
    np.testing.assert_allclose(inv_sqrt(x), 1.0 / np.sqrt(np.asarray(x)), rtol=1e-15)
    check_grads(inv_sqrt, (jnp.linspace(0.1, 10.0, 7),), order=2, modes=("fwd", "rev"))
    x32 = jnp.geomspace(1e-6, 1e6, 33, dtype=jnp.float32)
    np.testing.assert_allclose(inv_sqrt(x32), 1.0 / np.sqrt(np.asarray(x32, np.float64)), rtol=3e-7)


def test_components_values_and_derivatives_equal_plain_slicing(x64):
    x = jnp.asarray(np.random.default_rng(0).normal(size=(4, 5, 3)))
    probe = jnp.asarray(np.random.default_rng(1).normal(size=(3, 4, 5)))

    def loss(split):
        # a nonlinear function of every component, so each cotangent is a different array
        return lambda v: sum(jnp.sum(jnp.sin(c * (i + 1)) * probe[i]) for i, c in enumerate(split(v)))

    plain = loss(lambda v: tuple(v[..., i] for i in range(3)))
    fast = loss(components)
    for got, want in zip(components(x), (x[..., 0], x[..., 1], x[..., 2])):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(jax.grad(fast)(x), jax.grad(plain)(x), rtol=1e-14)
    tangent = jnp.ones_like(x)
    np.testing.assert_allclose(jax.jvp(fast, (x,), (tangent,))[1], jax.jvp(plain, (x,), (tangent,))[1], rtol=1e-14)
    check_grads(fast, (x,), order=2, modes=("fwd", "rev"))


def test_materialize_is_the_identity_with_identity_derivatives(x64):
    a, b = jnp.arange(6.0).reshape(2, 3), -jnp.arange(6.0).reshape(2, 3) ** 2
    for got, want in zip(materialize(a, b), (a, b)):
        np.testing.assert_array_equal(got, want)
    np.testing.assert_allclose(jax.grad(lambda a: jnp.sum(jnp.sin(materialize(a, b)[0])))(a), jnp.cos(a), rtol=1e-14)
    with pytest.raises(ValueError, match="at least two arrays"):
        materialize(a)
    v = jnp.asarray(np.random.default_rng(2).normal(size=(4, 5, 3)))
    assert materialize_cotangent(v) is v
    for mode in (jax.grad, jax.jacfwd):
        np.testing.assert_allclose(mode(lambda v: jnp.sum(jnp.sin(materialize_cotangent(v))))(v), jnp.cos(v),
                                   rtol=1e-14)


def test_safe_normalize_maps_zero_to_the_fallback_and_nan_to_nan_traced_as_eagerly():
    from jaxocean._math import safe_normalize

    x = jnp.asarray([[3.0, 0.0, 4.0], [0.0, 0.0, 0.0], [jnp.nan, 0.0, 1.0]])
    for f in (safe_normalize, jax.jit(safe_normalize)):
        y = np.asarray(f(x))
        np.testing.assert_allclose(y[0], [0.6, 0.0, 0.8], rtol=1e-6)
        np.testing.assert_array_equal(y[1], [0.0, 0.0, 1.0])  # a zero vector: the fallback
        assert np.isnan(y[2]).all()  # a NaN is no zero vector: never a plausible +z
    g = jax.grad(lambda v: safe_normalize(v)[..., 2].sum())(jnp.zeros(3))
    assert np.isfinite(np.asarray(g)).all()


def test_shade_under_jit_returns_nan_where_a_normal_is_nan():
    # eagerly shade refuses NaN normals; traced it cannot look, and must not paint the pixel
    # as a flat sea
    from jaxocean import camera as cam
    from jaxocean import render, shading

    camera = cam.make_camera(height=10.0, pitch=0.8, fov=0.8, resolution=(8, 8))
    normal = jnp.zeros((8, 8, 3)).at[..., 2].set(1.0).at[6, 4].set(jnp.nan)
    image = np.asarray(jax.jit(render.shade)(normal, jnp.full((8, 8), 0.01), camera, shading.make_lighting()))
    assert np.isnan(image[6, 4]).all()
    assert np.isfinite(np.delete(image.reshape(64, 3), 6 * 8 + 4, axis=0)).all()
