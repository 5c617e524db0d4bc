"""One registry of solvers, used by every fit: a name -> a runner with one signature.

Protocol
--------
A fit states its problem as a residual function and a starting vector::

    residual_fn(y, args) -> r          # y: (n,) parameters, r: (m,) residuals, same dtype
    out = solve(name, residual_fn, y0, args, max_steps=..., rtol=..., atol=...)

and gets back a :class:`SolverOutput` of arrays only (so ``jax.vmap`` maps a fit over many
images): the final ``params``, ``loss = 0.5 * sum(r**2)`` there, the number of ``steps``, a
``success`` flag and, with ``history=True``, the loss after every step. The objective of the
minimisers is the same ``0.5 * sum(r**2)``, so every solver sees the same problem.

=================  ==========  =========================================================
name               library     method
=================  ==========  =========================================================
``lm``             optimistix  ``LevenbergMarquardt`` (trust-region Gauss-Newton)
``gauss_newton``   optimistix  ``GaussNewton`` (full steps, no globalisation)
``dogleg``         optimistix  ``Dogleg`` (trust region, Cauchy point / Gauss-Newton)
``bfgs``           optimistix  ``BFGS`` on ``0.5 |r|^2`` (line search)
``lbfgsb``         jaxopt      ``LBFGSB``: box constraints ``lower <= y <= upper``
``scipy``          jaxopt      ``ScipyMinimize`` (SciPy on the host; not traceable)
``adam``           optax       ``adam(learning_rate)`` for exactly ``max_steps`` steps
=================  ==========  =========================================================

Conventions:

* ``rtol`` / ``atol`` are optimistix's Cauchy tolerances (on the step in ``y`` and the
  change of the residual, in the solver's ``norm``; the default here is the RMS norm, so
  tolerances do not depend on the number of pixels). jaxopt's ``tol`` is a gradient norm
  instead: it is set to ``atol`` (override with ``options={"tol": ...}``). SciPy gets
  ``tol=rtol``.
* Adam has no convergence test. It runs ``max_steps`` steps and reports success when the
  loss has stalled: changed by less than ``rtol`` (relative) over the last tenth of the
  steps. Its learning rate is ``options["learning_rate"]`` (default 0.05).
* ``success`` is False when the solver ran out of steps, diverged, or ended on a non-finite
  loss. Nothing here raises on failure: the fits decide (see ``throw`` there).
* ``history``: ``(max_steps + 1,)``, entry ``k`` the loss after ``k`` steps (entry 0 at
  ``y0``), padded with the final loss once the solver has stopped. For the optimistix
  solvers it is recorded by a step loop that mirrors ``optimistix``'s own (same ``init`` /
  ``step`` / ``terminate``); that loop is not differentiable, so ask for a history only in
  scripted runs. ``scipy`` records it on the host through SciPy's callback.
* Differentiation: the optimistix runners go through ``optimistix.least_squares`` with its
  implicit adjoint, ``lbfgsb`` through jaxopt's implicit differentiation; ``adam``
  differentiates through its unrolled steps. ``scipy`` is a host call.
* ``traceable``: every solver but ``scipy`` runs under ``jit`` and ``vmap``.

Every runner is deterministic; none takes a random key.
"""

from __future__ import annotations

import functools
from typing import Any, Callable, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
import optimistix as optx
from jax.custom_derivatives import SymbolicZero

from jaxocean.errors import is_concrete

__all__ = [
    "FitError",
    "SolverOutput",
    "SolverSpec",
    "SOLVERS",
    "SOLVER_NAMES",
    "get_solver",
    "solve",
    "loss_of",
    "dense_jacobian",
    "value_and_jacobian",
]


class FitError(RuntimeError):
    """A fit that did not converge, raised by an eager fit called with ``throw=True``.

    ``result`` holds the (failed) fit result, so that a caller can still inspect it.
    """

    def __init__(self, message: str, result=None):
        super().__init__(message)
        self.result = result


class SolverOutput(NamedTuple):
    """What every solver returns (arrays only; ``history`` is None unless asked for).

    * ``params``  ``(n,)`` final parameters.
    * ``loss``    ``()`` ``0.5 * sum(residual**2)`` at ``params``.
    * ``steps``   ``()`` int32 solver steps taken.
    * ``success`` ``()`` bool: converged to the tolerances with a finite loss.
    * ``history`` ``(max_steps + 1,)`` loss after each step, or None.
    """

    params: jax.Array
    loss: jax.Array
    steps: jax.Array
    success: jax.Array
    history: Any = None


class SolverSpec(NamedTuple):
    """A registry entry: how to run one solver and what it supports."""

    name: str
    library: str
    kind: str  # "least_squares" (uses the residual vector) or "minimise" (uses 0.5 |r|^2)
    bounded: bool  # honours lower / upper
    traceable: bool  # runs under jit / vmap
    description: str
    run: Callable


def loss_of(residual_fn, y, args):
    """``0.5 * sum(residual_fn(y, args) ** 2)``: the objective every solver minimises."""
    r = residual_fn(y, args)
    return 0.5 * jnp.sum(r * r)


def dense_jacobian(residual_fn):
    """``residual_fn`` with a JVP that materialises the Jacobian ``(m, n)`` once per point.

    For a residual of few parameters (``n`` small) and many outputs (pixels), the solvers
    evaluate Jacobian-vector and vector-Jacobian products many times per step (trust-region
    ratios, normal equations, the implicit adjoint). With this wrapper a linearisation costs
    ``n`` forward-mode passes, after which every product is a small matrix product: the
    compiled program holds one copy of the forward-mode Jacobian instead of a JVP *and* a
    transposed (reverse-mode) copy of the whole pixel pipeline, which cuts compile time
    several-fold and speeds up each step. Derivatives with respect to ``args`` (e.g. the
    image, for implicit differentiation of a fit) fall back to an ordinary JVP.
    """

    @jax.custom_jvp
    def wrapped(y, args):
        return residual_fn(y, args)

    def jvp(primals, tangents):
        y, args = primals
        y_dot, args_dot = tangents
        r, jac = value_and_jacobian(residual_fn, y, args)
        if isinstance(y_dot, SymbolicZero):
            out = jnp.zeros_like(r)
        else:
            out = jac @ y_dot
        arg_leaves = jax.tree_util.tree_leaves(args_dot, is_leaf=lambda x: isinstance(x, SymbolicZero))
        if not all(isinstance(t, SymbolicZero) for t in arg_leaves):
            args_dot = jax.tree.map(lambda t, a: jnp.zeros_like(a) if isinstance(t, SymbolicZero) else t,
                                    args_dot, args, is_leaf=lambda x: isinstance(x, SymbolicZero))
            out = out + jax.jvp(lambda a: residual_fn(y, a), (args,), (args_dot,))[1]
        return r, out

    wrapped.defjvp(jvp, symbolic_zeros=True)
    return wrapped


# Forward-mode Jacobian columns are computed in vmapped blocks of at most this many basis
# vectors. Work-around for an XLA:CPU miscompilation (jax/jaxlib 0.10.2): in float32, a
# jitted vmap of 9 or more JVPs through this library's pixel pipelines is fused into one
# YNNPACK kernel ("__ynn_fusion") that returns wrong tangents -- columns that must be zero
# come out O(1) (reproduced on a 20-line function: a normalised half vector, a dot and a
# power, 4096 pixels; 8 columns or fewer, float64, or
# XLA_FLAGS=--xla_cpu_experimental_ynn_fusion_type= are all correct). It broke every float32
# fit with more than 8 parameters (the lighting fit's display-space refinement and "plain"
# structure: 11; camera fits have at most 5). Blocks of 8 compile to the correct kernels.
_JACOBIAN_BLOCK = 8


def value_and_jacobian(fn, y, args):
    """``(fn(y, args), J)`` with the dense forward-mode Jacobian ``J (m, n)`` of ``fn`` with
    respect to ``y (n,)``, its columns computed in vmapped blocks of ``_JACOBIAN_BLOCK`` (see
    above). ``fn(y, args) -> (m,)``. What :func:`dense_jacobian` linearises with; for the
    fits that need a Jacobian themselves (column scaling, ``J^T J`` uncertainties)."""
    n = y.shape[0]
    basis = jnp.eye(n, dtype=y.dtype)
    blocks = []
    for lo in range(0, n, _JACOBIAN_BLOCK):
        r, cols = jax.vmap(lambda v: jax.jvp(lambda z: fn(z, args), (y,), (v,)), out_axes=(None, -1))(
            basis[lo:lo + _JACOBIAN_BLOCK])
        blocks.append(cols)
    return r, blocks[0] if len(blocks) == 1 else jnp.concatenate(blocks, axis=-1)


def _finite(x):
    return jnp.all(jnp.isfinite(x))


# --------------------------------------------------------------------------- optimistix


def _optx_solver(name: str, rtol, atol, options):
    norm = options.get("norm", optx.rms_norm)
    if name == "lm":
        return optx.LevenbergMarquardt(rtol=rtol, atol=atol, norm=norm)
    if name == "gauss_newton":
        return optx.GaussNewton(rtol=rtol, atol=atol, norm=norm)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol, norm=norm)
    if name == "bfgs":
        return optx.BFGS(rtol=rtol, atol=atol, norm=norm)
    raise AssertionError(name)


def _optx_runner(name: str, kind: str):
    def run(residual_fn, y0, args, *, max_steps, rtol, atol, lower=None, upper=None, history=False, options=None):
        del lower, upper  # unbounded: the fits parameterise their constraints away
        options = dict(options or {})
        unknown = sorted(set(options) - {"norm"})
        if unknown:  # optimistix takes no other option: a typo would be ignored
            raise ValueError(f"solver {name!r} takes the option 'norm' only; got {unknown}")
        solver = _optx_solver(name, rtol, atol, options)
        # optimistix starts its trust region / step size at jnp.array(1.0): float64 under
        # jax_enable_x64, which a float32 problem's linear solve refuses ("structures do not
        # match"); traced in the parameters' precision, a float32 fit runs as without x64
        with jax.enable_x64(y0.dtype == jnp.float64):
            if history:
                return _optx_with_history(solver, kind, residual_fn, y0, args, max_steps)
            sol = optx.least_squares(residual_fn, solver, y0, args, max_steps=max_steps, throw=False)
        loss = _final_loss(sol, kind, residual_fn, args)
        success = (sol.result == optx.RESULTS.successful) & jnp.isfinite(loss) & _finite(sol.value)
        steps = jnp.asarray(sol.stats["num_steps"], jnp.int32)
        return SolverOutput(sol.value, loss, steps, success, None)

    return run


def _final_loss(sol, kind, residual_fn, args):
    """The loss at ``sol.value`` from the solver's own state where it holds it (no extra
    evaluation of the residual: one copy fewer of the whole pixel pipeline when compiled)."""
    f_info = getattr(sol.state, "f_info", None)
    if kind == "least_squares" and hasattr(f_info, "residual"):
        r = f_info.residual
        return 0.5 * jnp.sum(r * r)
    if kind == "minimise" and hasattr(f_info, "f"):
        return jnp.asarray(f_info.f)
    return loss_of(residual_fn, sol.value, args)


def _optx_with_history(solver, kind, residual_fn, y0, args, max_steps):
    """optimistix's iteration (``init``, ``step``, ``terminate``) with the loss recorded.

    Mirrors ``optimistix._iterate._iterate``: the ``y`` a step returns is the last accepted
    iterate for the Gauss-Newton family, and the loss recorded is evaluated there.
    """
    import equinox as eqx  # optimistix's own dependency; only its partition helpers are used

    if kind == "least_squares":
        def fn(y, a):
            return residual_fn(y, a), None
    else:
        def fn(y, a):
            return loss_of(residual_fn, y, a), None
    y0 = jnp.asarray(y0)
    f_struct, aux_struct = jax.eval_shape(fn, y0, args)
    options, tags = {}, frozenset()
    state = solver.init(fn, y0, args, options, f_struct, aux_struct, tags)
    dynamic_state, static_state = eqx.partition(state, eqx.is_array)
    loss0 = loss_of(residual_fn, y0, args)
    hist0 = jnp.full((max_steps + 1,), loss0)
    done0, result0 = solver.terminate(fn, y0, args, options, state, tags)

    def cond(carry):
        _, _, k, done, result, _ = carry
        return (~done) & (result == optx.RESULTS.successful) & (k < max_steps)

    def body(carry):
        y, dyn, k, _, _, hist = carry
        st = eqx.combine(static_state, dyn)
        y_new, st_new, _ = solver.step(fn, y, args, options, st, tags)
        done, result = solver.terminate(fn, y, args, options, st_new, tags)  # as optimistix: the old y
        result = optx.RESULTS.where(_finite(y_new), result, optx.RESULTS.nonfinite)
        loss = loss_of(residual_fn, y_new, args)
        # pad: every entry after k+1 holds the latest loss until overwritten
        hist = jnp.where(jnp.arange(max_steps + 1) > k, loss, hist)
        dyn_new, _ = eqx.partition(st_new, eqx.is_array)
        return y_new, dyn_new, k + 1, done, result, hist

    carry = (y0, dynamic_state, jnp.asarray(0, jnp.int32), done0, result0, hist0)
    y, _, steps, done, result, hist = jax.lax.while_loop(cond, body, carry)
    loss = hist[-1]
    success = done & (result == optx.RESULTS.successful) & jnp.isfinite(loss) & _finite(y)
    return SolverOutput(y, loss, steps, success, hist)


# --------------------------------------------------------------------------- jaxopt


def _lbfgsb(residual_fn, y0, args, *, max_steps, rtol, atol, lower=None, upper=None, history=False,
            options=None):
    from jaxocean.fit import _jaxopt

    options = dict(options or {})
    tol = options.pop("tol", atol)
    y0 = jnp.asarray(y0)
    lower = jnp.full_like(y0, -jnp.inf) if lower is None else jnp.broadcast_to(jnp.asarray(lower, y0.dtype), y0.shape)
    upper = jnp.full_like(y0, jnp.inf) if upper is None else jnp.broadcast_to(jnp.asarray(upper, y0.dtype), y0.shape)
    return SolverOutput(*_jaxopt.lbfgsb(_objective(residual_fn), y0, args, lower, upper,
                                        max_steps=max_steps, tol=tol, history=history, **options))


def _scipy(residual_fn, y0, args, *, max_steps, rtol, atol, lower=None, upper=None, history=False, options=None):
    from jaxocean.fit import _jaxopt

    del atol, lower, upper
    options = dict(options or {})
    tol = options.pop("tol", rtol)
    return SolverOutput(*_jaxopt.scipy_minimize(_objective(residual_fn), y0, args,
                                                max_steps=max_steps, tol=tol, history=history, **options))


@functools.lru_cache(maxsize=64)
def _objective(residual_fn):
    """``0.5 |r|^2`` as one function object per residual function, so that host-side solvers
    (which jit their objective themselves) hit the compilation cache on repeated fits."""
    def objective(y, a):
        return loss_of(residual_fn, y, a)

    return objective


# --------------------------------------------------------------------------- optax


def _adam(residual_fn, y0, args, *, max_steps, rtol, atol, lower=None, upper=None, history=False, options=None):
    del atol
    options = dict(options or {})
    optimizer = optax.adam(options.pop("learning_rate", 0.05), **options)
    y0 = jnp.asarray(y0)
    value_and_grad = jax.value_and_grad(lambda y: loss_of(residual_fn, y, args))

    def project(y):
        if lower is not None:
            y = jnp.maximum(y, lower)
        if upper is not None:
            y = jnp.minimum(y, upper)
        return y

    def step(carry, _):
        y, opt_state = carry
        loss, grad = value_and_grad(y)
        updates, opt_state = optimizer.update(grad, opt_state, y)
        return (project(optax.apply_updates(y, updates)), opt_state), loss

    (y, _), losses = jax.lax.scan(step, (y0, optimizer.init(y0)), None, length=max_steps)
    loss = loss_of(residual_fn, y, args)
    hist = jnp.concatenate([losses, loss[None]])  # hist[k]: loss after k steps
    window = max(1, max_steps // 10)
    earlier = hist[-1 - window]
    stalled = jnp.abs(earlier - loss) <= rtol * jnp.maximum(jnp.abs(loss), jnp.finfo(loss.dtype).tiny)
    success = stalled & jnp.isfinite(loss) & _finite(y)
    return SolverOutput(y, loss, jnp.asarray(max_steps, jnp.int32), success, hist if history else None)


# --------------------------------------------------------------------------- registry


SOLVERS: dict[str, SolverSpec] = {
    "lm": SolverSpec("lm", "optimistix", "least_squares", False, True,
                     "Levenberg-Marquardt (optimistix)", _optx_runner("lm", "least_squares")),
    "gauss_newton": SolverSpec("gauss_newton", "optimistix", "least_squares", False, True,
                               "Gauss-Newton (optimistix)", _optx_runner("gauss_newton", "least_squares")),
    "dogleg": SolverSpec("dogleg", "optimistix", "least_squares", False, True,
                         "Dogleg trust region (optimistix)", _optx_runner("dogleg", "least_squares")),
    "bfgs": SolverSpec("bfgs", "optimistix", "minimise", False, True,
                       "BFGS on 0.5|r|^2 (optimistix)", _optx_runner("bfgs", "minimise")),
    "lbfgsb": SolverSpec("lbfgsb", "jaxopt", "minimise", True, True,
                         "box-constrained L-BFGS-B (jaxopt)", _lbfgsb),
    "scipy": SolverSpec("scipy", "jaxopt", "minimise", False, False,
                        "scipy.optimize.minimize via jaxopt.ScipyMinimize (host, cross-check)", _scipy),
    "adam": SolverSpec("adam", "optax", "minimise", False, True,
                       "optax Adam, fixed number of steps (the paper's baseline)", _adam),
}
SOLVER_NAMES = tuple(SOLVERS)


def get_solver(name: str) -> SolverSpec:
    """The registry entry of ``name``; an unknown name raises ``ValueError`` listing the known ones."""
    try:
        return SOLVERS[name]
    except (KeyError, TypeError):
        raise ValueError(f"unknown solver {name!r}; expected one of {SOLVER_NAMES}") from None


def solve(name: str, residual_fn, y0, args=None, *, max_steps: int, rtol, atol, lower=None, upper=None,
          history: bool = False, options: dict | None = None) -> SolverOutput:
    """Run solver ``name`` on ``min_y 0.5 |residual_fn(y, args)|^2`` from ``y0``.

    ``lower`` / ``upper`` (broadcastable to ``y0``) are honoured by bounded solvers
    (``lbfgsb``; ``adam`` projects onto them) and ignored by the others. See the module
    docstring for tolerances, success and history.
    """
    spec = get_solver(name)
    if not isinstance(max_steps, int) or max_steps < 1:
        raise ValueError(f"max_steps must be a positive int; got {max_steps!r}")
    if jnp.ndim(y0) != 1:
        raise ValueError(f"y0 must be a parameter vector (n,); got shape {jnp.shape(y0)}")
    for tol_name, tol in (("rtol", rtol), ("atol", atol)):
        if is_concrete(tol) and not (np.ndim(tol) == 0 and np.isfinite(tol) and float(tol) >= 0):
            raise ValueError(f"{tol_name} must be a finite number >= 0; got {tol!r}")
    return spec.run(residual_fn, jnp.asarray(y0), args, max_steps=max_steps, rtol=rtol, atol=atol, lower=lower,
                    upper=upper, history=history, options=options)
