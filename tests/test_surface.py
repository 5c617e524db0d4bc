import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from jax.test_util import check_grads

from jaxocean import hierarchy, surface
from jaxocean.errors import InvalidValueError
from jaxocean.waves import GRAVITY, Waves, make_waves


def random_waves(seed, n, dtype=np.float32, max_steepness=0.3):
    rng = np.random.default_rng(seed)
    omega = rng.uniform(0.8, 4.0, n)
    k = omega**2 / GRAVITY
    amplitude = rng.uniform(0.0, max_steepness / n, n) / k * 3
    return make_waves(amplitude.astype(dtype), omega.astype(dtype), rng.uniform(-np.pi, np.pi, n).astype(dtype),
                      rng.uniform(0, 2 * np.pi, n).astype(dtype))


def numpy_trochoid(waves, x, y, t):
    """Straight transcription of paper eq. 1 (float64, a loop over waves)."""
    h, om, th, ph = (np.asarray(a, np.float64) for a in waves)
    px, py, pz = np.array(x, np.float64), np.array(y, np.float64), np.zeros(np.shape(x))
    for i in range(len(h)):
        k = om[i] ** 2 / GRAVITY
        psi = om[i] * t - k * (np.cos(th[i]) * x + np.sin(th[i]) * y) + ph[i]
        px = px + h[i] * np.cos(th[i]) * np.sin(psi)
        py = py + h[i] * np.sin(th[i]) * np.sin(psi)
        pz = pz + h[i] * np.cos(psi)
    return np.stack([px, py, pz], -1)


def grid_xy(x, y):
    xx, yy = jnp.meshgrid(x, y)
    return jnp.stack([xx, yy], -1)


def test_displacement_matches_numpy_transcription_of_eq1():
    waves = random_waves(0, 12)
    rng = np.random.default_rng(1)
    xy = rng.uniform(-20, 20, (50, 2)).astype(np.float32)
    for t in (0.0, 1.7, 12.0):
        p = np.asarray(surface.surface_point(waves, xy, t))
        ref = numpy_trochoid(waves, xy[:, 0], xy[:, 1], t)
        np.testing.assert_allclose(p, ref, atol=2e-5)


def test_normals_are_unit_and_match_finite_difference_of_eq1(x64):
    waves = random_waves(2, 8, np.float64, max_steepness=0.6)
    rng = np.random.default_rng(3)
    xy = rng.uniform(-10, 10, (40, 2))
    t, eps = 0.9, 1e-5
    n = np.asarray(surface.normal(waves, xy, t))
    np.testing.assert_allclose(np.linalg.norm(n, axis=-1), 1.0, atol=1e-12)
    dpx = (numpy_trochoid(waves, xy[:, 0] + eps, xy[:, 1], t) - numpy_trochoid(waves, xy[:, 0] - eps, xy[:, 1], t)) / (2 * eps)
    dpy = (numpy_trochoid(waves, xy[:, 0], xy[:, 1] + eps, t) - numpy_trochoid(waves, xy[:, 0], xy[:, 1] - eps, t)) / (2 * eps)
    ref = np.cross(dpx, dpy)
    ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
    np.testing.assert_allclose(n, ref, atol=1e-8)


def test_flat_sea():
    waves = make_waves(np.zeros(3), [1.0, 2.0, 3.0], [0.0, 1.0, 2.0])
    xy = jnp.array([[0.0, 0.0], [3.0, -2.0]])
    np.testing.assert_array_equal(surface.displacement(waves, xy, 1.0), np.zeros((2, 3)))
    np.testing.assert_array_equal(surface.normal(waves, xy, 1.0), [[0, 0, 1], [0, 0, 1]])
    np.testing.assert_array_equal(surface.slope_variance(waves), (0.0, 0.0))


def test_single_wave_normal_is_the_trochoid_slope():
    # theta = 0: the profile is x = X + h sin(psi), z = h cos(psi), psi = w t - k X + phi;
    # dz/dx = k h sin(psi) / (1 - k h cos(psi)), so n ~ (-k h sin psi, 0, 1 - k h cos psi)
    kh = 0.8
    omega = 2.0
    k = omega**2 / GRAVITY
    waves = make_waves([kh / k], [omega], [0.0], [0.3])
    X = jnp.linspace(-5, 5, 41)
    xy = jnp.stack([X, jnp.zeros_like(X)], -1)
    n = np.asarray(surface.normal(waves, xy, 0.4))
    psi = omega * 0.4 - k * np.asarray(X) + 0.3
    ref = np.stack([-kh * np.sin(psi), np.zeros_like(psi), 1 - kh * np.cos(psi)], -1)
    ref /= np.linalg.norm(ref, axis=-1, keepdims=True)
    np.testing.assert_allclose(n, ref, atol=2e-6)


def test_rotating_the_sea_rotates_the_normal():
    waves = random_waves(4, 5)
    rot = 0.7
    turned = waves._replace(theta=waves.theta + rot)
    c, s = np.cos(rot), np.sin(rot)
    xy = np.random.default_rng(0).uniform(-5, 5, (20, 2)).astype(np.float32)
    xy_rot = xy @ np.array([[c, s], [-s, c]], np.float32)
    n = np.asarray(surface.normal(waves, xy, 0.5))
    n_rot = np.asarray(surface.normal(turned, xy_rot, 0.5))
    np.testing.assert_allclose(n_rot[:, 0], c * n[:, 0] - s * n[:, 1], atol=1e-5)
    np.testing.assert_allclose(n_rot[:, 2], n[:, 2], atol=1e-5)


def test_slope_variance_reference_and_small_slope_limit():
    waves = make_waves([0.01, 0.02], [2.0, 3.0], [0.0, np.pi / 2])
    sx2, sy2 = surface.slope_variance(waves)
    k = np.array([4.0, 9.0]) / GRAVITY
    kh = k * np.array([0.01, 0.02])
    np.testing.assert_allclose(sx2, 1 - np.sqrt(1 - kh[0] ** 2), rtol=1e-5)
    np.testing.assert_allclose(sy2, 1 - np.sqrt(1 - kh[1] ** 2), rtol=1e-5)
    # gentle waves: 1 - sqrt(1 - (kh)^2) ~ (kh)^2 / 2, the linear-theory slope variance
    np.testing.assert_allclose(sx2, kh[0] ** 2 / 2, rtol=1e-3)
    # weights send waves to roughness one by one
    sx2_w, sy2_w = surface.slope_variance(waves, jnp.array([[1.0, 0.0], [0.0, 1.0]]))
    np.testing.assert_allclose(sx2_w, [sx2, 0.0], rtol=1e-6, atol=1e-12)
    np.testing.assert_allclose(sy2_w, [0.0, sy2], rtol=1e-6, atol=1e-12)


@pytest.mark.parametrize("dtype, atol", [(np.float32, 1e-5), (np.float64, 1e-10)])
def test_on_grid_equals_per_point_path(dtype, atol):
    with jax.enable_x64(dtype == np.float64):
        waves = random_waves(5, 20, dtype)
        x = jnp.linspace(-6, 6, 24, dtype=dtype)
        y = jnp.linspace(-4, 5, 18, dtype=dtype)
        times = jnp.array([0.0, 0.37, 2.0], dtype=dtype)
        # footprint 5 m sends the shortest waves (lambda >= 3.85 m) to roughness, grid cell 8 m
        # thins the displacement further
        weights = hierarchy.weights(waves, jnp.asarray(5.0, dtype), grid_cell=jnp.asarray(8.0, dtype))
        for w in (None, weights):
            grid = surface.on_grid(waves, x, y, times, w)
            assert grid.displacement.shape == (3, 18, 24, 3) and grid.normal.shape == (3, 18, 24, 3)
            assert grid.roughness.shape == (3, 18, 24)
            for ti, t in enumerate(times):
                np.testing.assert_allclose(grid.displacement[ti], surface.displacement(waves, grid_xy(x, y), t, w),
                                           atol=atol)
                np.testing.assert_allclose(grid.normal[ti], surface.normal(waves, grid_xy(x, y), t, w), atol=atol)
        sx2, sy2 = surface.slope_variance(waves, weights)
        np.testing.assert_allclose(grid.roughness[1, 2, 3], sx2 + sy2, rtol=1e-5)
        assert float(sx2 + sy2) > 0  # some waves really went to roughness


@pytest.mark.parametrize("n_cols", [23, 16, 1])
def test_on_rows_equals_per_point_path_with_per_row_weights(n_cols):
    waves = random_waves(3, 30)
    rng = np.random.default_rng(0)
    rows = 7
    origin = rng.uniform(-5, 5, (rows, 2)).astype(np.float32)
    step = rng.uniform(-0.3, 0.3, (rows, 2)).astype(np.float32)
    weights = hierarchy.weights(waves, jnp.asarray(rng.uniform(1, 6, rows), jnp.float32))
    got = surface.on_rows(waves, origin, step, n_cols, 0.7, weights)
    xy = origin[:, None, :] + np.arange(n_cols)[None, :, None] * step[:, None, :]
    per_pixel = jax.tree.map(lambda a: jnp.broadcast_to(a[:, None, :], (rows, n_cols, a.shape[-1])), weights)
    assert got.normal.shape == (rows, n_cols, 3)
    np.testing.assert_allclose(got.displacement, surface.displacement(waves, xy, 0.7, per_pixel), atol=1e-5)
    np.testing.assert_allclose(got.normal, surface.normal(waves, xy, 0.7, per_pixel), atol=1e-5)
    normal_only = surface.on_rows(waves, origin, step, n_cols, 0.7, weights, with_displacement=False)
    assert normal_only.displacement is None
    np.testing.assert_allclose(normal_only.normal, got.normal, atol=1e-6)
    sx2, sy2 = surface.slope_variance(waves, per_pixel)
    np.testing.assert_allclose(got.slope_variance[..., 0], sx2, rtol=1e-5)
    np.testing.assert_allclose(got.slope_variance[..., 1], sy2, rtol=1e-5)
    assert float(jnp.max(sx2 + sy2)) > 0  # the footprints really split the sea
    with pytest.raises(ValueError, match=r"origin and step must both be \(R, 2\)"):
        surface.on_rows(waves, origin, step[:3], n_cols, 0.0)


@pytest.mark.slow  # on_grid and normal compiled vmapped and per sea
def test_vmap_over_batches_of_seas():
    batch = jax.tree.map(lambda *a: jnp.stack(a), *[random_waves(s, 6) for s in range(3)])
    x = jnp.linspace(0, 5, 8)
    y = jnp.linspace(0, 4, 6)
    grids = jax.vmap(lambda w: surface.on_grid(w, x, y, jnp.array([0.0, 1.0])))(batch)
    assert grids.normal.shape == (3, 2, 6, 8, 3)
    for b in range(3):
        one = surface.on_grid(jax.tree.map(lambda a: a[b], batch), x, y, jnp.array([0.0, 1.0]))
        np.testing.assert_allclose(grids.normal[b], one.normal, atol=1e-6)
    pts = jax.vmap(lambda w: surface.normal(w, grid_xy(x, y), 1.0))(batch)
    np.testing.assert_allclose(pts, grids.normal[:, 1], atol=1e-5)


def test_structural_errors_name_the_problem():
    waves = random_waves(0, 4)
    with pytest.raises(ValueError, match="trailing axis of size 2"):
        surface.normal(waves, jnp.zeros((5, 3)), 0.0)
    batch = jax.tree.map(lambda a: jnp.stack([a, a]), waves)
    with pytest.raises(ValueError, match="use jax.vmap"):
        surface.displacement(batch, jnp.zeros((5, 2)), 0.0)
    with pytest.raises(ValueError, match=r"on_grid \(per-wave\) needs \w+ weights of shape \(4,\)"):
        surface.on_grid(waves, jnp.zeros(3), jnp.zeros(3), jnp.zeros(1), jnp.ones((3, 4)))
    with pytest.raises(InvalidValueError, match="omega must be > 0"):
        surface.normal(waves._replace(omega=-waves.omega), jnp.zeros((1, 2)), 0.0)


def test_an_array_time_or_wrong_weights_are_refused_not_broadcast_against_the_waves():
    # four waves, four points, four times: omega * t used to pair each time with a wave and
    # return a (4, 3) array of meaningless values
    waves = random_waves(0, 4)
    xy = jnp.zeros((4, 2))
    for fn in (surface.normal, surface.displacement, surface.surface_point):
        with pytest.raises(ValueError, match="t must be one time"):
            fn(waves, xy, jnp.arange(4.0))
    with pytest.raises(ValueError, match="t must be one time"):
        surface.on_rows(waves, jnp.zeros((2, 2)), jnp.ones((2, 2)), 3, jnp.zeros(4))
    with pytest.raises(ValueError, match="normal weights must be per wave"):
        surface.normal(waves, xy, 0.0, jnp.ones(3))
    with pytest.raises(ValueError, match="n_cols must be a positive int"):
        surface.on_rows(waves, jnp.zeros((2, 2)), jnp.ones((2, 2)), 0, 0.0)


# ---------------------------------------------------------------- gradients (x64)

def _grad_case():
    waves = random_waves(7, 4, np.float64, max_steepness=0.5)
    xy = jnp.array([[0.3, -1.2], [2.5, 0.7], [-3.1, 4.0]])
    return waves, xy


def test_displacement_and_normal_gradients_match_finite_differences(x64):
    waves, xy = _grad_case()
    footprint = jnp.array([0.5, 2.0, 6.0])  # a wave straddles the filter at some points
    for fn in (surface.displacement, surface.normal):
        def f(amp, omega, theta, phase, xy, t):
            w = Waves(amp, omega, theta, phase)
            return fn(w, xy, t), fn(w, xy, t, hierarchy.weights(w, footprint))
        check_grads(jax.jit(f), (*waves, xy, jnp.array(1.3)), order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-5, rtol=1e-5)


def test_slope_variance_gradients_match_finite_differences(x64):
    waves, _ = _grad_case()

    def f(amp, omega, theta, footprint):
        w = Waves(amp, omega, theta, jnp.zeros_like(amp))
        return surface.slope_variance(w, hierarchy.weights(w, footprint))

    check_grads(jax.jit(f), (waves.amplitude, waves.omega, waves.theta, jnp.array([3.0, 8.0])), order=1,
                modes=("fwd", "rev"), eps=1e-6, atol=1e-6, rtol=1e-5)


def test_on_grid_gradients_match_finite_differences(x64):
    waves, _ = _grad_case()

    def f(amp, omega, theta, phase, x, t):
        w = Waves(amp, omega, theta, phase)
        # footprint 1 m / grid cell 1.6 m put some of these waves (lambda 1.5 .. 19 m) on the filter ramp
        weights = hierarchy.weights(w, jnp.asarray(1.0), grid_cell=jnp.asarray(1.6))
        g = surface.on_grid(w, x, jnp.linspace(0, 2, 3), t, weights)
        return g.displacement, g.normal

    # both modes: on_grid's core has a custom (linear, transposable) tangent rule
    check_grads(jax.jit(f), (*waves, jnp.linspace(0, 3, 4), jnp.array([0.0, 0.5])), order=1, modes=("fwd", "rev"),
                eps=1e-6, atol=1e-5, rtol=1e-5)


def _on_grid_losses():
    """A scalar loss of on_grid's displacement and normal, by the fast path and by plain autodiff
    of the straightforward product, with hierarchy weights on their ramp; and its arguments."""
    waves = random_waves(11, 9, np.float64, max_steepness=0.6)
    x, y, times = jnp.linspace(-6, 7, 11), jnp.linspace(-4, 5, 6), jnp.array([0.0, 0.37, 2.0])
    probe_d, probe_n = np.random.default_rng(12).normal(size=(2, 3, 6, 11, 3))

    def loss(fn):
        def f(amp, omega, theta, phase, x, y, times):
            w = Waves(amp, omega, theta, phase)
            weights = hierarchy.weights(w, jnp.asarray(3.5), grid_cell=jnp.asarray(4.0))
            d, n = fn(w, x, y, times, weights)
            return jnp.sum(jnp.sin(d) * probe_d) + jnp.sum(n * probe_n) + jnp.sum(n[..., :2] ** 2)
        return f

    weights = hierarchy.weights(waves, jnp.asarray(3.5), grid_cell=jnp.asarray(4.0))
    for w in (weights.normal, weights.displacement):  # the filter acts, and its ramp is differentiated
        assert np.any((w > 0) & (w < 1))
    fast = loss(lambda *a: tuple(surface.on_grid(*a)[:2]))
    return fast, loss(surface._on_grid_reference), (*waves, x, y, times)


def _close(got, want):
    np.testing.assert_allclose(got, want, rtol=1e-10, atol=1e-10 * float(jnp.max(jnp.abs(want))))


@pytest.mark.slow  # float64 autodiff of both products, both modes
def test_on_grid_custom_derivatives_equal_autodiff_of_the_plain_product(x64):
    """on_grid's hand-written tangent rule (forward mode, and transposed, reverse mode) equals
    plain autodiff of the straightforward product to 1e-10, wrt waves, grid and times."""
    fast, plain, args = _on_grid_losses()
    np.testing.assert_allclose(jax.jit(fast)(*args), jax.jit(plain)(*args), rtol=1e-12)
    argnums = tuple(range(len(args)))
    for g_fast, g_plain in zip(jax.jit(jax.grad(fast, argnums))(*args), jax.jit(jax.grad(plain, argnums))(*args)):
        _close(g_fast, g_plain)
    rng = np.random.default_rng(13)
    tangents = tuple(jnp.asarray(rng.normal(size=np.shape(a))) for a in args)
    _close(*(jax.jit(lambda a, t, f=f: jax.jvp(f, a, t)[1])(args, tangents) for f in (fast, plain)))
    check_grads(jax.jit(fast), args, order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-5, rtol=1e-5)


@pytest.mark.slow  # compiles two forward-over-reverse programs (~10 s)
def test_on_grid_second_derivatives_equal_autodiff_of_the_plain_product(x64):
    """Forward over reverse differentiates the tangent rule itself (Hessian-vector products)."""
    fast, plain, args = _on_grid_losses()
    rng = np.random.default_rng(14)
    tangents = tuple(jnp.asarray(rng.normal(size=np.shape(a))) for a in args)

    def hvp(f):
        grad = jax.grad(f, tuple(range(len(args))))
        return jax.jit(lambda a, t: jax.jvp(lambda *z: grad(*z), a, t)[1])

    for h_fast, h_plain in zip(hvp(fast)(args, tangents), hvp(plain)(args, tangents)):
        _close(h_fast, h_plain)


@pytest.mark.parametrize("with_displacement", [pytest.param(True, marks=pytest.mark.slow), False])  # True: 14 s
def test_on_rows_custom_derivatives_equal_autodiff_of_the_plain_product(x64, with_displacement):
    """on_rows' hand-written tangent rule (forward mode, and transposed, reverse mode) equals
    plain autodiff of the same tables and product to 1e-10, wrt waves, row origins and steps,
    time and the per-row footprints (hierarchy weights on their ramp); a ragged last block;
    also for the normal-only product (five channels, what the renderer uses)."""
    waves = random_waves(21, 9, np.float64, max_steepness=0.6)
    rng = np.random.default_rng(22)
    rows, n_cols, block = 5, 13, 4
    origin, step = rng.uniform(-5, 5, (rows, 2)), rng.uniform(-0.4, 0.4, (rows, 2))
    footprint = rng.uniform(1.5, 4.0, rows)
    probe_d, probe_n = rng.normal(size=(2, rows, n_cols, 3))

    def loss(fn):
        def f(amp, omega, theta, phase, origin, step, t, footprint):
            w = Waves(amp, omega, theta, phase)
            weights = hierarchy.weights(w, footprint, grid_cell=footprint * 1.3)
            d, n = fn(w, origin, step, n_cols, t, weights, block=block)
            normal_terms = jnp.sum(n * probe_n) + jnp.sum(n[..., :2] ** 2)
            return normal_terms + (jnp.sum(jnp.sin(d) * probe_d) if with_displacement else 0.0)
        return f

    weights = hierarchy.weights(waves, jnp.asarray(footprint), grid_cell=jnp.asarray(footprint * 1.3))
    for w in (weights.normal, weights.displacement):  # the filter acts, and its ramp is differentiated
        assert np.any((w > 0) & (w < 1))
    fast = loss(lambda *a, **k: tuple(surface.on_rows(*a, **k, with_displacement=with_displacement)[:2]))
    plain = loss(surface._on_rows_reference)
    args = (*waves, jnp.asarray(origin), jnp.asarray(step), jnp.asarray(0.37), jnp.asarray(footprint))
    np.testing.assert_allclose(jax.jit(fast)(*args), jax.jit(plain)(*args), rtol=1e-12)
    argnums = tuple(range(len(args)))
    for g_fast, g_plain in zip(jax.jit(jax.grad(fast, argnums))(*args), jax.jit(jax.grad(plain, argnums))(*args)):
        _close(g_fast, g_plain)
    tangents = tuple(jnp.asarray(rng.normal(size=np.shape(a))) for a in args)
    _close(*(jax.jit(lambda a, t, f=f: jax.jvp(f, a, t)[1])(args, tangents) for f in (fast, plain)))
    check_grads(jax.jit(fast), args, order=1, modes=("fwd", "rev"), eps=1e-6, atol=1e-5, rtol=1e-5)


@pytest.mark.slow  # hypothesis examples, each compiled
@given(
    kh=st.lists(st.floats(0.0, 1.0), min_size=3, max_size=3),
    omega=st.lists(st.floats(0.3, 8.0), min_size=3, max_size=3),
    theta=st.lists(st.floats(-np.pi, np.pi), min_size=3, max_size=3),
    t=st.floats(0.0, 100.0),
    footprint=st.floats(0.01, 50.0),
)
def test_values_and_gradients_finite_over_valid_domain(kh, omega, theta, t, footprint):
    omega = np.asarray(omega, np.float32)
    amp = np.asarray(kh, np.float32) / (omega**2 / GRAVITY)
    # include the point where the steepest wave has psi = 0 (a cusp when k h = 1)
    k0 = omega[0] ** 2 / GRAVITY
    x_cusp = omega[0] * t / k0 / np.cos(theta[0]) if abs(np.cos(theta[0])) > 0.1 else 0.0
    xy = jnp.array([[x_cusp, 0.0], [1.0, 2.0], [0.0, 0.0]], jnp.float32)

    def loss(amp, omega, theta, xy, t):
        w = Waves(amp, omega, theta, jnp.zeros_like(amp))
        ws = hierarchy.weights(w, jnp.full(xy.shape[:1], footprint, jnp.float32))
        n = surface.normal(w, xy, t, ws)
        d = surface.displacement(w, xy, t, ws)
        sx2, sy2 = surface.slope_variance(w, ws)
        return jnp.sum(n) + jnp.sum(d) + jnp.sum(sx2 + sy2)

    args = (jnp.asarray(amp), jnp.asarray(omega), jnp.asarray(theta, jnp.float32), xy, jnp.float32(t))
    val, grads = jax.value_and_grad(loss, argnums=(0, 1, 2, 3, 4))(*args)
    assert np.isfinite(val)
    for g in grads:
        assert np.all(np.isfinite(g))


def _wave_pair(kh, theta2=0.0):
    """Two waves of k h = ``kh`` each, the second turned by ``theta2``, crests aligned at X = 0, t = 0."""
    omega = np.array([1.0, 1.3])
    k = omega**2 / GRAVITY
    return make_waves(kh / k, omega, np.array([0.0, theta2]), np.array([0.0, 0.0]), dtype=np.float64)


def test_fold_determinant_matches_finite_differences_of_surface_points(x64):
    waves = random_waves(4, 7, np.float64, max_steepness=0.3)
    xy = np.random.default_rng(5).uniform(-30, 30, (16, 2))
    t, eps = 1.7, 1e-5

    def horizontal(p):
        return np.asarray(surface.surface_point(waves, p, t))[..., :2]

    dx = (horizontal(xy + [eps, 0]) - horizontal(xy - [eps, 0])) / (2 * eps)
    dy = (horizontal(xy + [0, eps]) - horizontal(xy - [0, eps])) / (2 * eps)
    expected = dx[:, 0] * dy[:, 1] - dx[:, 1] * dy[:, 0]
    np.testing.assert_allclose(surface.fold_determinant(waves, xy, t), expected, atol=1e-8)
    assert float(jnp.min(surface.fold_determinant(make_waves([0.0], [1.0], [0.0]), xy, t))) == 1.0  # flat


def test_fold_determinant_detects_a_folding_wave_pair(x64):
    # each wave is within k h <= 1, but aligned crests sum to 1.4 > 1: the surface folds there
    xy = np.stack(np.meshgrid(np.linspace(-20, 20, 81), np.linspace(-20, 20, 81)), -1)
    folding = surface.fold_determinant(_wave_pair(0.7, 0.3), xy, 0.0)
    assert float(jnp.min(folding)) < 0
    assert float(surface.fold_determinant(_wave_pair(0.7, 0.3), np.zeros(2), 0.0)) < 0  # at the aligned crests
    gentle = surface.fold_determinant(_wave_pair(0.3, 0.3), xy, 0.0)
    assert float(jnp.min(gentle)) > 0.3  # 1 - sum k h = 0.4 is the worst case
