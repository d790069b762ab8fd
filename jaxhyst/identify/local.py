"""Local solves of a problem, one start or a vmapped batch of starts.

Every solver works in the unconstrained coordinates z of the problem's space (bounds by
construction). Least-squares solvers see the residual vector with its Jacobian from
``jax.jacfwd`` (handed over whole through a custom JVP, `jacobian_linearized`);
minimisers (``bfgs``, any ``optx.AbstractMinimiser``) see the cost and its reverse-mode
gradient. Never finite differences.
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .problem import AbstractProblem
from .result import IdentificationResult, Outcome
from .solvers import BoxTermination, final_step_size, make_solver, solver_name
from .space import u_from_z, z_from_u

#: Result codes of `run_local` (int arrays, so that they vmap).
CODES = (Outcome.successful, Outcome.max_steps_reached, Outcome.failed)


def jacobian_linearized(fn):
    """``fn`` (a residual vector of a few parameters) with a custom JVP that forms the
    whole Jacobian by one forward-mode pass (`jax.jacfwd`, primal computed once) and
    returns J·t.

    Optimistix linearizes the residuals once per step and then applies the linear map
    to a basis (to materialise J for its QR) and its transpose (for Jᵀr). Linearizing
    the simulation itself would store its intermediates and replay the tangent for
    each use; with this rule the stored linearization is just the matrix J, so each step
    costs one jacfwd. Values and derivatives are unchanged (the rule is the exact
    derivative); it differentiates again (jacfwd inside) if needed.
    """

    @jax.custom_jvp
    def f(z, args=None):
        return fn(z, args)

    @f.defjvp
    def f_jvp(primals, tangents):
        z, args = primals
        t, _ = tangents

        def both(z):
            r = fn(z, args)
            return r, r

        J, r = jax.jacfwd(both, has_aux=True)(z)
        return r, J @ t

    return f


def _code(result) -> jax.Array:
    """Our code (index into `CODES`) of an Optimistix RESULTS value, by public comparisons."""
    max_steps = ((result == optx.RESULTS.max_steps_reached)
                 | (result == optx.RESULTS.nonlinear_max_steps_reached))
    return jnp.where(result == optx.RESULTS.successful, 0,
                     jnp.where(max_steps, 1, 2)).astype(jnp.int32)


def run_local(problem: AbstractProblem, solver, z0, max_steps: int):
    """One solve from z0; returns arrays only (z, code, steps, cost, final step size) so
    that it vmaps (Optimistix issue #63: a whole Solution does not). ``solver`` is an
    Optimistix solver object (`make_solver`)."""
    if isinstance(solver, optx.AbstractMinimiser):
        sol = optx.minimise(problem.cost, solver, z0, max_steps=max_steps, throw=False)
    else:
        wrapped = BoxTermination(solver) if isinstance(solver, optx.AbstractGaussNewton) \
            else solver
        sol = optx.least_squares(jacobian_linearized(problem.residuals), wrapped, z0,
                                 max_steps=max_steps, throw=False, options={"jac": "fwd"})
    z = sol.value
    cost = problem.cost(z)
    return z, _code(sol.result), sol.stats["num_steps"], cost, final_step_size(sol.state)


_run_jit = eqx.filter_jit(run_local)


@eqx.filter_jit
def _run_many(problem, solver, z0s, max_steps):
    return jax.vmap(lambda z0: run_local(problem, solver, z0, max_steps))(z0s)


def start_z(problem: AbstractProblem, start) -> jax.Array:
    """z0 from parameters of the problem's kind (projected into the box; a batch of them
    gives (K, n)) or from box coordinates u ∈ [0, 1]ⁿ (shape (n,) or (K, n)). For a
    space over a single array, an array is read as box coordinates."""
    space = problem.space
    if (space.treedef.num_leaves > 1 and jax.tree.structure(start) == space.treedef):
        leaf, shape = jax.tree.leaves(start)[0], space.shapes[0]
        if jnp.ndim(leaf) > len(shape):
            return jax.vmap(space.z_from_params)(start)
        return space.z_from_params(start)
    try:
        u = jnp.asarray(start, dtype=jnp.float64)
    except TypeError:
        raise TypeError(f"start must be box coordinates u or parameters of this problem's "
                        f"kind; got {type(start).__name__}.") from None
    if u.ndim not in (1, 2) or u.shape[-1] != space.n_free:
        raise ValueError(f"A start in box coordinates needs {space.n_free} entries (free "
                         f"parameters {space.names}); got shape {u.shape}.")
    if not bool(jnp.all((u >= 0) & (u <= 1))):
        raise ValueError("Box coordinates u of a start must lie in [0, 1].")
    return z_from_u(u)


def _stats(groups, residuals):
    """Per-group rms and max |e|, and the overall ones when all groups share a unit."""
    out = {}
    for g, e in zip(groups, residuals, strict=True):
        e = np.asarray(e, dtype=float).ravel()
        out[g.name] = {"rms": float(np.sqrt(np.mean(e**2))), "max_abs": float(np.max(np.abs(e))),
                       "unit": g.unit,
                       "sigma": None if g.sigma is None else float(g.sigma), "size": g.size}
    units = {g.unit for g in groups}
    if len(units) != 1:
        return out, None, None, None
    e = np.concatenate([np.asarray(r, dtype=float).ravel() for r in residuals])
    return out, float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e))), float(np.sum(e**2))


@eqx.filter_jit
def _evaluate_at(problem, z):
    """(cost, group residuals) at z, compiled (an eager vmapped scan runs op by op)."""
    params = problem.space.params_from_z(z)
    return problem.cost(z), problem.group_residuals(params)


def summarize(problem: AbstractProblem, z, steps, outcome, solver: str, wall: float,
              extra: dict | None = None) -> IdentificationResult:
    """An `IdentificationResult` at the solver coordinate ``z`` (without report)."""
    cost, residuals = _evaluate_at(problem, jnp.asarray(z))
    cost = float(cost)
    outcome = Outcome(outcome)
    if not np.isfinite(cost) and outcome is not Outcome.interrupted:
        outcome = Outcome.nonfinite
    groups, rms, max_abs, sse = _stats(problem.groups, residuals)
    space = problem.space
    values = np.asarray(space.free_from_u(u_from_z(jnp.asarray(z))), dtype=float)
    return IdentificationResult(
        params=space.params_from_z(jnp.asarray(z)), free=space.names,
        values=tuple(float(v) for v in values), cost=cost, outcome=outcome, steps=int(steps),
        solver=solver, wall_time=wall, groups=groups, rms_error=rms, max_abs_error=max_abs,
        sse=sse, output=getattr(problem, "output", ""), extra=extra or {},
    )  # fmt: skip


def solve(problem: AbstractProblem, start, solver="lm", max_steps: int = 200,
          rtol: float = 1e-10, atol: float = 1e-12) -> IdentificationResult:
    """Run one local solver from ``start`` (parameters, or box coordinates u).

    ``solver``: a name of `jaxhyst.identify.SOLVERS` (with termination tolerances
    ``rtol``/``atol``) or any Optimistix least-squares solver or minimiser object.
    ``max_steps`` bounds the iterations (the paper's T3 for ``lma``/``tra``); a solve
    that reaches it reports the outcome ``max_steps_reached``, never success."""
    z0 = start_z(problem, start)
    solver_obj = make_solver(solver, rtol, atol)
    t0 = time.perf_counter()
    z, code, steps, _, _ = _run_jit(problem, solver_obj, z0, max_steps)
    z.block_until_ready()
    wall = time.perf_counter() - t0
    return summarize(problem, z, steps, CODES[int(code)], solver_name(solver), wall)


def multistart(problem: AbstractProblem, starts, solver="lm", max_steps: int = 200,
               rtol: float = 1e-10, atol: float = 1e-12) -> IdentificationResult:
    """Solve from K starts in one vmapped batch; returns the best, with the per-start
    table (final cost, outcome, steps, free values) in ``extra["starts"]``.

    ``starts``: box coordinates of shape (K, n_free), or a batch of parameters. The batch
    runs until its slowest member stops, so ``max_steps`` matters. The outcome is the
    best start's."""
    z0s = start_z(problem, starts)
    if z0s.ndim != 2:
        raise ValueError("multistart needs a batch of starts, shape (K, n_free).")
    solver_obj = make_solver(solver, rtol, atol)
    t0 = time.perf_counter()
    zs, codes, steps, costs, _ = _run_many(problem, solver_obj, z0s, max_steps)
    costs = np.asarray(costs)
    wall = time.perf_counter() - t0
    ranked = np.where(np.isfinite(costs), costs, np.inf)
    best = int(np.argmin(ranked))
    space = problem.space
    table = [
        {"cost": float(costs[i]), "result": CODES[int(codes[i])].value, "steps": int(steps[i]),
         "params": dict(zip(space.names, np.asarray(space.free_from_u(u_from_z(zs[i]))).tolist(),
                            strict=True))}
        for i in range(len(costs))
    ]  # fmt: skip
    return summarize(problem, zs[best], steps[best], CODES[int(codes[best])],
                     f"{solver_name(solver)} x{len(costs)}", wall,
                     extra={"starts": table, "best_index": best})
