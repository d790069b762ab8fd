"""Local solves of a problem: one start (`solve`) or a vmapped batch of starts
(`multistart`), each stepped from the host by the one driver (progress, interruption),
and the reading of a start (`start_z`)."""

from __future__ import annotations

import time

import jax
import jax.numpy as jnp
import numpy as np

from .._driver import KEYBOARD, drive
from .._interrupt import Interrupted
from ..params import is_concrete
from ..progress import NoProgressMeter, progress_meter
from ._stepped import SteppedSolve, best_start
from .problem import AbstractProblem, check_problem
from .result import RESULTS, IdentificationResult, member, outcome_name, params_of
from .solvers import make_solver, solver_name
from .space import z_from_u
from .summary import point_of, summarize, with_linearization


def stepped_solve(problem: AbstractProblem, solver, z0s, max_steps: int, meter,
                  label: str):
    """Solve from each start of ``z0s`` (K, n) in one vmapped batch through the driver,
    reporting to ``meter``: ((z, results, steps, cost, final step size, group residuals)
    batched over K as host values, how the loop ended: ``"done"``, ``"stopped"`` or
    ``"keyboard"``, the solver's linearizations at each z: `SteppedSolve.outputs`). A
    stopped solve's results are `RESULTS.interrupted`."""
    run = SteppedSolve(problem, solver, z0s, max_steps,
                       with_cost=not isinstance(meter, NoProgressMeter), finish_meanwhile=True)
    meter_state = meter.init(label, int(max_steps))
    try:
        carry, how, meter_state = drive(run.state, advance=run.advance, done=run.done,
                                        describe=run.describe, meter=meter,
                                        meter_state=meter_state)
    except BaseException:
        run.drop()
        raise
    out = run.outputs(carry)
    linear = run.linearizations
    overtaken = 0 if run.overtaken is None else int(np.sum(run.overtaken))
    if how != "done":
        stopped = RESULTS.where(jnp.asarray(True), RESULTS.interrupted, out[1])
        out = (out[0], jax.device_get(stopped), *out[2:])
    steps = np.asarray(out[2])
    costs = np.asarray(out[3])
    best = best_start(costs, run.overtaken)
    ended = "interrupted" if how != "done" else "done"
    text = (f"{ended} after {int(steps[best])} steps, cost {costs[best]:.4e}"
            if steps.size == 1 else
            f"{ended}: the best start after {int(steps[best])} steps, cost "
            f"{costs[best]:.4e} (the longest start {int(steps.max())} steps"
            + (f"; {overtaken} stopped there, unable to catch up)" if overtaken else ")"))
    meter.close(meter_state, text)
    return out, how, linear


def start_z(problem: AbstractProblem, start) -> jax.Array:
    """z0 from parameters of the problem's kind (projected into the box; a batch of them
    gives (K, n)) or from box coordinates u ∈ [0, 1]ⁿ (shape (n,) or (K, n)). For a
    space over a single array, an array is read as box coordinates."""
    space, start = problem.space, params_of(start)
    tree_kind = not jax.tree_util.treedef_is_leaf(space.treedef)
    if tree_kind and jax.tree.structure(start) == space.treedef:
        leaf, shape = jax.tree.leaves(start)[0], space.shapes[0]
        z = jax.vmap(space.z_from_params)(start) if jnp.ndim(leaf) > len(shape) else \
            space.z_from_params(start)
        bad = _first_nonfinite(space, z) if is_concrete(z) else None
        if bad is not None:
            raise ValueError(f"the start's {bad[1]} is not a finite number; give every free "
                             "parameter a value.")
        return z
    if isinstance(start, dict) and tree_kind and space.treedef.node_data()[0] is not dict:
        return _z_of_values(space, start)
    try:
        u = jnp.asarray(start, dtype=jnp.float64)
    except (TypeError, ValueError):
        raise TypeError(_start_kind_message(space, start)) from None
    if u.ndim not in (1, 2) or u.shape[-1] != space.n_free:
        raise ValueError(f"A start in box coordinates needs {space.n_free} entries (free "
                         f"parameters {space.names}); got shape {u.shape}.")
    u_np = np.asarray(u)
    if u_np.size == 0:
        raise ValueError(f"a batch of starts needs at least one start; got shape {u.shape}.")
    bad = _first_nonfinite(space, u_np)
    if bad is not None:
        raise ValueError(f"Box coordinates u of a start must be finite numbers in [0, 1]; "
                         f"got {bad[0]} for {bad[1]}.")
    if not np.all((u_np >= 0) & (u_np <= 1)):
        kind = (f"; to start from values of the parameters give {_kind(space)}"
                if tree_kind else "")
        raise ValueError(
            f"Box coordinates u of a start must lie in [0, 1] (an array start is read as "
            f"box coordinates, one per free parameter: {', '.join(space.names)}); got "
            f"values from {u_np.min():.6g} to {u_np.max():.6g}{kind}.")
    return _z_from_u_jit(u)


def _first_nonfinite(space, z):
    """(the value, "name" or "name of start k") of the first non-finite entry of starts
    ``z`` (shape (n,) or (K, n), one column per free parameter), or None."""
    z = np.asarray(z)
    if np.all(np.isfinite(z)):
        return None
    at = np.argwhere(~np.isfinite(z))[0]
    return z[tuple(at)], space.names[at[-1]] + (f" of start {at[0]}" if z.ndim == 2 else "")


def _z_of_values(space, values: dict) -> jax.Array:
    """z0 from ``{name: SI value}`` giving every free parameter of a space over a
    Modules' pytree (fixed ones may be named: their fixed values are kept), projected
    into the box."""
    unknown = sorted(set(values) - set(space.flat_names) - set(space.names))
    missing = [n for n in space.names if n not in values]
    if unknown or missing:
        raise ValueError(f"a start {{name: value}} gives every free parameter ("
                         f"{', '.join(space.names)}) in SI units; "
                         + (f"unknown: {unknown}" if unknown else f"missing: {missing}") + ".")
    try:
        x = np.array([float(values[n]) for n in space.names])
    except (TypeError, ValueError):
        raise ValueError("a start {name: value} holds numbers (SI units).") from None
    return _z_from_u_jit(space.u_from_free(x))


def _kind(space) -> str:
    """The parameters of a space over a pytree (not a single array) in words, for
    messages about a start."""
    node, keys = space.treedef.node_data()
    if node is dict:
        return "a dict with the keys " + ", ".join(map(repr, keys))
    return f"a {node.__name__} (like the problem's bounds)"


def _start_kind_message(space, start) -> str:
    """Why ``start`` is neither this problem's parameters nor box coordinates."""
    coordinates = (f"box coordinates u in [0, 1] (one per free parameter, "
                   f"{', '.join(space.names)})")
    if jax.tree_util.treedef_is_leaf(space.treedef):  # (a space over a single array)
        return f"start must be {coordinates}; got {type(start).__name__}."
    node, keys = space.treedef.node_data()
    if isinstance(start, dict) and node is dict:
        missing, unknown = sorted(set(keys) - set(start)), sorted(set(start) - set(keys))
        return (f"start must be {_kind(space)} (or box coordinates u in [0, 1]); it has "
                f"the keys {sorted(start)}: missing {missing}, unknown {unknown}.")
    return f"start must be {_kind(space)} or {coordinates}; got {type(start).__name__}."


_z_from_u_jit = jax.jit(z_from_u)



def finished(result: IdentificationResult, how: str) -> IdentificationResult:
    """The result, or `Interrupted` carrying it after a KeyboardInterrupt."""
    if how == KEYBOARD:
        raise Interrupted(result)
    return result


def solve(problem: AbstractProblem, start, solver="lm", max_steps: int = 200,
          rtol: float = 1e-10, atol: float = 1e-12,
          progress=False) -> IdentificationResult:
    """Run one local solver from ``start``: `Parameters` (SI; the problem's fixed values
    are kept), a dict {name: SI value}, an earlier fit (an `IdentificationResult`: its
    parameters), or box coordinates u, float64 of shape (n,) in [0, 1]
    (n = ``problem.space.n_free``).

    ``solver``: a name of `jaxhyst.identify.SOLVERS` (with termination tolerances
    ``rtol``/``atol``) or any Optimistix least-squares solver or minimiser object.
    ``max_steps`` bounds the iterations (the paper's T3 for ``lma``/``tra``); a solve
    that reaches it reports the outcome ``max_steps_reached``, never success.
    ``progress``: a progress meter (`jaxhyst.progress`), or True for a line every 2 s on
    stderr. A stop request returns the point reached (outcome ``interrupted``); Ctrl-C
    raises `jaxhyst.Interrupted` carrying that result."""
    check_problem(problem)
    z0 = start_z(problem, start)
    if z0.ndim != 1:
        raise ValueError("solve takes one start; use multistart for a batch of starts.")
    solver_obj = make_solver(solver, rtol, atol)
    t0 = time.perf_counter()
    (z, results, steps, cost, _, residuals), how, linear = stepped_solve(
        problem, solver_obj, np.asarray(z0)[None], max_steps,
        progress_meter(progress, every=0), solver_name(solver))
    result = summarize(problem, z[0], steps[0], member(results, 0), solver_name(solver),
                       time.perf_counter() - t0,
                       evaluated=(cost[0], [r[0] for r in residuals]))
    result = with_linearization(result, problem, z[0],
                                None if linear is None else [a[0] for a in linear])
    return finished(result, how)


def multistart(problem: AbstractProblem, starts, solver="lm", max_steps: int = 200,
               rtol: float = 1e-10, atol: float = 1e-12,
               progress=False) -> IdentificationResult:
    """Solve from K starts in one vmapped batch; returns the best, with the per-start
    table (final cost, outcome, steps, free values) in ``extra["starts"]``.

    ``starts``: box coordinates of shape (K, n_free), or a batch of parameters. The batch
    runs until a start has converged below the others and none of them can catch up at
    its pace (those end ``overtaken``), or until its slowest member stops, so
    ``max_steps`` matters. The outcome is the best start's. ``progress`` and
    interruption as for `solve`."""
    if isinstance(starts, (int, np.integer)) and not isinstance(starts, bool):
        n, k = problem.space.n_free, (starts if starts >= 1 else 8)
        raise ValueError(
            f"multistart takes the starts themselves, not their number ({starts}): e.g. "
            f"{k} starts spread over the box as box coordinates, jax.random.uniform("
            f"jax.random.PRNGKey(0), ({k}, {n})), or a batch of parameters.")
    check_problem(problem)
    z0s = start_z(problem, starts)
    if z0s.ndim != 2:
        raise ValueError("multistart needs a batch of starts, shape (K, n_free).")
    solver_obj = make_solver(solver, rtol, atol)
    t0 = time.perf_counter()
    label = f"{solver_name(solver)} x{z0s.shape[0]}"
    (zs, results, steps, costs, _, residuals), how, linear = stepped_solve(
        problem, solver_obj, z0s, max_steps, progress_meter(progress, every=0), label)
    costs = np.asarray(costs)
    names = np.atleast_1d(outcome_name(results))
    best = best_start(costs, names == "overtaken")
    space = problem.space
    values = np.asarray(point_of(space, zs)[0])  # (K, n), one compiled call
    table = [
        {"cost": float(costs[i]), "result": str(names[i]), "steps": int(steps[i]),
         "params": dict(zip(space.names, values[i].tolist(), strict=True))}
        for i in range(len(costs))
    ]  # fmt: skip
    result = summarize(problem, zs[best], steps[best], member(results, best),
                       f"{solver_name(solver)} x{len(costs)}", time.perf_counter() - t0,
                       extra={"starts": table, "best_index": best},
                       evaluated=(costs[best], [r[best] for r in residuals]))
    result = with_linearization(result, problem, zs[best],
                                None if linear is None else [a[best] for a in linear])
    return finished(result, how)
