"""The project's numerical solvers, behind one small interface (the only module that imports jaxopt).

jaxopt is no longer developed upstream; callers use these functions only, so another library (e.g. optimistix)
can replace it here without touching them. All functions are pure, jit-able and vmap-able.

* :func:`least_squares` — ``argmin_x ½‖r(x)‖²`` by Levenberg–Marquardt (Madsen & Nielsen, alg. 6.18):
  ``(JᵀJ + μI) Δ = −Jᵀr`` with the damping μ adapted by the gain ratio (jaxopt's ``LevenbergMarquardt``).
* :func:`bisection` — a root of a scalar function bracketed by ``[lo, hi]``, usable under ``jit`` (no bracket
  check; the caller guarantees ``f(lo)`` and ``f(hi)`` differ in sign, or gets the nearest end);
  :func:`bisection_with_value` also returns ``f`` there (the annealing β rules of :mod:`jaxmocap.filters.annealing`).
* :func:`minimize` — ``argmin_x f(x)`` by L-BFGS.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import NamedTuple

import jax
import jax.numpy as jnp

# jaxopt is imported by the functions that use it: its package imports SciPy's optimize (about 0.8 s), which a run
# whose programs are all read back from disk (jaxmocap.stored_programs) never needs


class SolveInfo(NamedTuple):
    """Diagnostics of an iterative solve: iterations used, final objective value and gradient/error norm."""

    iterations: jnp.ndarray
    value: jnp.ndarray
    error: jnp.ndarray


def least_squares(
    residual_fn: Callable[..., jnp.ndarray],
    init: jnp.ndarray,
    *args,
    jac_fn: Callable[..., jnp.ndarray] | None = None,
    maxiter: int = 50,
    tol: float = 1e-6,
    damping: float = 1e-6,
) -> tuple[jnp.ndarray, SolveInfo]:
    """Minimise ``½ Σ r_i(x)²`` from ``init (n,)`` by Levenberg–Marquardt.

    Args:
      residual_fn: ``r(x, *args) -> (m,)``, smooth.
      init: starting point ``(n,)``.
      *args: extra (traced) arguments of ``residual_fn``.
      jac_fn: ``J(x, *args) -> (m, n)``, the Jacobian of ``residual_fn``; by default ``jax.jacfwd`` of it.
      maxiter: number of iterations; tol: an iterate with ``‖Jᵀr‖₂ ≤ tol`` is kept from then on;
      damping: initial ``μ / max diag(JᵀJ)``.

    A step whose iterate, cost or gradient norm is not finite is not taken: the solver stops at the last finite
    iterate (an exact fit can reach a zero residual, where the gain ratio of Levenberg–Marquardt is 0/0).

    Returns:
      ``(x, SolveInfo)``; ``iterations`` counts the steps taken before the tolerance was met. The Jacobian is
      materialised and the normal equations solved by Cholesky (right for small dense problems such as pose
      fitting). The iterations run as a fixed-length ``fori_loop`` of jaxopt's LM ``update`` (frozen once
      converged) rather than a ``while_loop``: the same iterates, a smaller program to compile (about 40 %
      less for a vmapped pose fit) and no data-dependent trip count under ``vmap``.
    """
    import jaxopt

    solver = jaxopt.LevenbergMarquardt(
        residual_fn,
        maxiter=maxiter,
        tol=tol,
        damping_parameter=damping,
        materialize_jac=True,
        jac_fun=jac_fn,
        solver="cholesky",
        implicit_diff=False,
        jit=True,
    )
    if jac_fn is not None:
        # jaxopt 0.8.5 only wires ``jac_fun`` when ``materialize_jac=False``; give the materialising path it too.
        solver._jac_fun = jac_fn
    init = jnp.asarray(init)
    state = jax.tree.map(jnp.asarray, solver.init_state(init, *args))

    def step(_, carry):
        x, st = carry
        x_new, st_new = solver.update(x, st, *args)
        # converged, or a step that left the finite numbers (an exact fit's 0/0 gain ratio, a damping grown past
        # the float range): the last finite iterate is kept
        bad = ~(jnp.all(jnp.isfinite(x_new)) & jnp.isfinite(st_new.value) & jnp.isfinite(st_new.error))
        done = (st.error <= tol) | bad
        keep = lambda old, new: jnp.where(done, old, new).astype(old.dtype)
        return jax.tree.map(keep, (x, st), (x_new, st_new))

    x, state = jax.lax.fori_loop(0, maxiter, step, (init, state))
    return x, SolveInfo(state.iter_num, state.value, state.error)


def bisection(
    fn: Callable[..., jnp.ndarray], lo, hi, *args, maxiter: int = 60, tol: float = 1e-6
) -> jnp.ndarray:
    """A root of the scalar ``fn(x, *args)`` in ``[lo, hi]`` by bisection (jit-able: no bracket check).

    ``lo`` and ``hi`` may be traced. Stops after ``maxiter`` halvings or when ``|fn| ≤ tol``.
    """
    return bisection_with_value(fn, lo, hi, *args, maxiter=maxiter, tol=tol)[0]


def bisection_with_value(
    fn: Callable[..., jnp.ndarray], lo, hi, *args, maxiter: int = 60, tol: float = 1e-6
) -> tuple[jnp.ndarray, jnp.ndarray]:
    """:func:`bisection` that also returns ``fn`` at the root: ``(x, fn(x, *args))`` at the last midpoint, from
    which the caller tells a met tolerance from an exhausted ``maxiter`` or a bracket without a sign change."""
    import jaxopt

    solver = jaxopt.Bisection(fn, lower=lo, upper=hi, maxiter=maxiter, tol=tol, check_bracket=False, jit=True)
    params, state = solver.run(None, *args)
    return params, state.value


def minimize(
    fn: Callable[..., jnp.ndarray], init: jnp.ndarray, *args, maxiter: int = 200, tol: float = 1e-6
) -> tuple[jnp.ndarray, SolveInfo]:
    """Minimise a smooth scalar ``fn(x, *args)`` from ``init`` by L-BFGS (zoom line search)."""
    import jaxopt

    solver = jaxopt.LBFGS(fn, maxiter=maxiter, tol=tol, implicit_diff=False, jit=True)
    x, state = solver.run(init, *args)
    return x, SolveInfo(state.iter_num, state.value, state.error)
