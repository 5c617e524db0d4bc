"""Every use of jaxopt in jaxocean, behind one module (jaxopt is unmaintained upstream).

Protocol: two runners over a scalar objective ``loss_fn(y, args)`` of a parameter vector
``y (n,)``, each returning ``(params, loss, steps, success, history)`` as
:class:`jaxocean.fit.solvers.SolverOutput` expects:

* :func:`lbfgsb` -- ``jaxopt.LBFGSB`` with box bounds ``lower <= y <= upper``; jittable and
  vmappable. ``tol`` is jaxopt's stopping test on the projected-gradient norm (in float32 a
  very small ``tol`` is never met: scale it to the objective).
* :func:`scipy_minimize` -- ``jaxopt.ScipyMinimize`` (``scipy.optimize.minimize`` on the
  host, ``method="BFGS"`` by default): an independent cross-check, neither jittable nor
  vmappable; calling it with traced values raises ``ValueError``.

Importing jaxopt emits a ``DeprecationWarning``; it is silenced here, at the one import.
"""

from __future__ import annotations

import functools
import warnings

import jax
import jax.numpy as jnp
import numpy as np

from jaxocean.errors import is_concrete

with warnings.catch_warnings():
    warnings.simplefilter("ignore", DeprecationWarning)
    import jaxopt

__all__ = ["lbfgsb", "scipy_minimize"]


def lbfgsb(loss_fn, y0, args, lower, upper, *, max_steps: int, tol, history: bool = False, **options):
    """Box-constrained L-BFGS-B from ``y0`` (clipped into the box first)."""
    solver = jaxopt.LBFGSB(fun=loss_fn, maxiter=max_steps, tol=tol, **options)
    bounds = (lower, upper)
    y0 = jnp.clip(y0, lower, upper)
    if not history:
        params, state = solver.run(y0, bounds, args)
        loss = loss_fn(params, args)
        success = (state.error <= tol) & jnp.isfinite(loss) & jnp.all(jnp.isfinite(params))
        return params, loss, jnp.asarray(state.iter_num, jnp.int32), success, None

    state0 = solver.init_state(y0, bounds, args)
    loss0 = loss_fn(y0, args)
    hist0 = jnp.full((max_steps + 1,), loss0)

    def cond(carry):
        _, state, k, _ = carry
        return (state.error > tol) & (k < max_steps)

    def body(carry):
        y, state, k, hist = carry
        y, state = solver.update(y, state, bounds, args)
        hist = jnp.where(jnp.arange(max_steps + 1) > k, state.value, hist)
        return y, state, k + 1, hist

    params, state, steps, hist = jax.lax.while_loop(cond, body, (y0, state0, jnp.asarray(0, jnp.int32), hist0))
    loss = loss_fn(params, args)
    hist = hist.at[-1].set(loss)
    success = (state.error <= tol) & jnp.isfinite(loss) & jnp.all(jnp.isfinite(params))
    return params, loss, steps, success, hist


@functools.lru_cache(maxsize=64)
def _jitted(loss_fn):
    return jax.jit(loss_fn)


@functools.lru_cache(maxsize=64)
def _scipy_solver(loss_fn, method, max_steps, tol, options):
    return jaxopt.ScipyMinimize(fun=loss_fn, method=method, maxiter=max_steps, tol=tol, **dict(options))


def scipy_minimize(loss_fn, y0, args, *, max_steps: int, tol, history: bool = False, method: str = "BFGS",
                   **options):
    """``scipy.optimize.minimize(method=method)`` through jaxopt, on the host."""
    if not is_concrete(y0, args):
        raise ValueError("the 'scipy' solver runs SciPy on the host: it cannot be used under jit or vmap "
                         "(pick a traceable solver such as 'lm' or 'lbfgsb')")
    y0 = jnp.asarray(y0)
    losses = []
    if history:
        losses.append(float(loss_fn(y0, args)))
    jitted_loss = _jitted(loss_fn)

    def callback(y):
        losses.append(float(jitted_loss(y, args)))

    if history:
        solver = jaxopt.ScipyMinimize(fun=loss_fn, method=method, maxiter=max_steps, tol=tol, callback=callback,
                                      **options)
    else:  # one solver object per problem: jaxopt jits its objective once per object
        solver = _scipy_solver(loss_fn, method, max_steps, float(tol), tuple(sorted(options.items())))
    params, info = solver.run(y0, args)
    params = jnp.asarray(params, y0.dtype)
    loss = jitted_loss(params, args)
    steps = jnp.asarray(int(info.iter_num), jnp.int32)
    success = jnp.asarray(bool(info.success) and bool(np.isfinite(float(loss))))
    hist = None
    if history:
        padded = np.full(max_steps + 1, float(loss))
        padded[: min(len(losses), max_steps + 1)] = losses[: max_steps + 1]
        hist = jnp.asarray(padded, y0.dtype)
    return params, loss, steps, success, hist
