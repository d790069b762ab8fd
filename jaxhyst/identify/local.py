"""Local solves of a problem, one start or a vmapped batch of starts.

Every solver works in the unconstrained coordinates z of the problem's space (bounds by
construction). Least-squares solvers see the residual vector with its Jacobian from
``jax.jacfwd`` (handed over whole through a custom JVP, `jacobian_linearized`);
minimisers (``bfgs``, any ``optx.AbstractMinimiser``) see the cost and its reverse-mode
gradient. Never finite differences.
"""

from __future__ import annotations

import sys
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .problem import AbstractProblem
from .result import IdentificationResult, Outcome, bound_status
from .solvers import BoxTermination, accepted_residuals, final_step_size, make_solver, solver_name
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

    The Jacobian is formed by one jitted function of (fn, z, args), so a program that
    linearizes ``fn`` more than once (Optimistix's ``init`` for the shapes, then
    ``step``) traces it once, provided ``fn`` is the same pytree each time (a bound
    method of an equinox Module, as ``problem.residuals``, is one: its arrays are
    arguments, the rest is compared by equality).
    """

    @jax.custom_jvp
    def f(z, args=None):
        return fn(z, args)

    @f.defjvp
    def f_jvp(primals, tangents):
        z, args = primals
        t, _ = tangents
        J, r = _jacobian_and_value(fn, z, args)
        return r, J @ t

    return f


@eqx.filter_jit
def _jacobian_and_value(fn, z, args):
    """(∂fn/∂z, fn(z, args)) by one forward-mode pass."""

    def both(z):
        r = fn(z, args)
        return r, r

    return jax.jacfwd(both, has_aux=True)(z)


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


# -- the same solve, stepped from Python ----------------------------------------------------
#
# `solve` and `multistart` drive the solver's public interface (init / step / terminate /
# postprocess of an Optimistix solver) from Python, a chunk of steps per dispatch, exactly
# as `optx.least_squares`/`optx.minimise` loop over them (`optimistix._iterate`: the
# termination test sees the previous iterate, a non-finite iterate ends the solve, the
# static part of the state is the initial one). Between chunks the driver reports the
# cost and honours an interruption; nothing in the compiled programs calls back into
# Python, so they go into the persistent compilation cache. `run_local` stays the
# traceable whole solve (hybrids, replicate fits); tests check both give the same.

_TAGS = frozenset()


def _objective(problem, solver):
    """(solver as run, fn(y, args) -> (out, aux), options) as Optimistix sets them up."""
    if isinstance(solver, optx.AbstractMinimiser):
        return solver, (lambda y, args: (problem.cost(y, args), None)), {}
    wrapped = BoxTermination(solver) if isinstance(solver, optx.AbstractGaussNewton) \
        else solver
    res = jacobian_linearized(problem.residuals)
    return wrapped, (lambda y, args: (res(y, args), None)), {"jac": "fwd"}


def _terminate(solver, fn, y, options, state):
    term, result = solver.terminate(fn, y, None, options, state, _TAGS)
    finite = jnp.all(jnp.isfinite(y))
    return term, optx.RESULTS.where(finite, result, optx.RESULTS.nonfinite)


def _init_one(problem, solver, z0):
    solver, fn, options = _objective(problem, solver)
    f_struct, aux_struct = jax.eval_shape(fn, z0, None)
    state = solver.init(fn, z0, None, options, f_struct, aux_struct, _TAGS)
    term, result = _terminate(solver, fn, z0, options, state)
    dynamic, static = eqx.partition(state, eqx.is_array)
    return (z0, jnp.array(0), dynamic, term, result), static


def _running(carry, max_steps):
    """Whether a solve with ``carry`` = (y, steps, state, terminate, result) goes on."""
    _, steps, _, term, result = carry
    return (~term) & (result == optx.RESULTS.successful) & (steps < max_steps)


def _advance_one(problem, solver, static, carry, n, max_steps, with_cost):
    solver, fn, options = _objective(problem, solver)

    def cond(c):
        return _running(c[:5], max_steps) & (c[5] < n)

    def body(c):
        y, steps, dynamic, _, _, i = c
        state = eqx.combine(static, dynamic)
        new_y, new_state, _ = solver.step(fn, y, None, options, state, _TAGS)
        term, result = _terminate(solver, fn, y, options, new_state)
        return (new_y, steps + 1, eqx.filter(new_state, eqx.is_array), term, result, i + 1)

    y, steps, dynamic, term, result, _ = jax.lax.while_loop(cond, body, (*carry, 0))
    # the cost for progress lines, in this program (a separate one would compile again)
    cost = problem.cost(y) if with_cost else None
    return (y, steps, dynamic, term, result), cost


def _finish_one(problem, solver, static, carry):
    solver, fn, options = _objective(problem, solver)
    y, steps, dynamic, term, result = carry
    state = eqx.combine(static, dynamic)
    result = optx.RESULTS.where((result == optx.RESULTS.successful) & ~term,
                                optx.RESULTS.nonlinear_max_steps_reached, result)
    y, _, _ = solver.postprocess(fn, y, None, None, options, state, _TAGS, result)
    # cost and group residuals at the end for `summarize`: a Gauss–Newton state holds the
    # residual vector at its accepted point (no simulation in this program, which would
    # compile it once more); other solvers evaluate the problem here
    r = accepted_residuals(state)
    if r is None:
        cost, residuals = _evaluation(problem, y)
        residuals, known = tuple(jnp.ravel(e) for e in residuals), jnp.array(True)
    else:
        # (before the first accepted step the state holds placeholder zeros:
        # `stepped_solve` evaluates those end points itself)
        known = state.num_accepted_steps > 0
        cost, residuals = jnp.sum(r**2), problem.groups_from_residuals(r)
    return y, _code(result), steps, cost, final_step_size(state), residuals, known


_running_jit = jax.jit(_running)  # (op by op, each operation would compile on its own)


@eqx.filter_jit
def _init_jit(problem, solver, z0s):
    return eqx.filter_vmap(lambda z: _init_one(problem, solver, z),
                           out_axes=eqx.if_array(0))(z0s)


@eqx.filter_jit
def _advance_jit(problem, solver, static, carry, n, max_steps, with_cost):
    return jax.vmap(lambda c: _advance_one(problem, solver, static, c, n, max_steps,
                                           with_cost))(carry)


@eqx.filter_jit
def _finish_jit(problem, solver, static, carry):
    return jax.vmap(lambda c: _finish_one(problem, solver, static, c))(carry)


def _say(label, text, live=False):
    """A progress line on stderr; on a terminal ``live`` lines overwrite each other."""
    stream = sys.stderr
    tty = bool(getattr(stream, "isatty", lambda: False)())
    print(f"{chr(13) + chr(27) + '[K' if tty else ''}[{label}] {text}",
          end="" if live and tty else "\n", file=stream, flush=True)


def stepped_solve(problem: AbstractProblem, solver, z0s, max_steps: int,
                  progress: float | bool = False, label: str = "local"):
    """Solve from each start of ``z0s`` (K, n) in one vmapped batch, stepped from Python;
    returns (z, code, steps, cost, final step size, group residuals flattened) batched
    over K, as NumPy arrays, and whether it was interrupted. ``progress``: seconds
    between progress lines on stderr (True = 2 s; a live line on a terminal). Ctrl-C/SIGTERM
    (`jaxhyst._interrupt`) stops after the current chunk of steps with the points
    reached."""
    from .._interrupt import interruptible

    every = 2.0 if progress is True else float(progress or 0)
    t0 = time.perf_counter()
    if every:
        _say(label, "compiling the solver (cached on disk by the command line) …")
    carry, static = _init_jit(problem, solver, z0s)
    interrupted, chunk, last = False, 1, t0
    with interruptible() as stop:
        # (host scalars: jnp.asarray of one compiles a program of its own on first use)
        while np.any(np.asarray(_running_jit(carry, np.int64(max_steps)))):
            c0 = time.perf_counter()
            carry, costs = _advance_jit(problem, solver, static, carry, np.int64(chunk),
                                        np.int64(max_steps), bool(every))  # no recompile
            jax.block_until_ready(carry)
            now = time.perf_counter()
            if now - c0 < 0.25:  # keep each dispatch near a quarter second
                chunk = min(chunk * 2, 64)
            if every and (now - last >= every or last == t0):
                costs = np.asarray(costs)
                best = np.min(np.where(np.isfinite(costs), costs, np.inf))
                _say(label, f"step {int(np.max(carry[1]))}/{max_steps}: best cost "
                     f"{best:.4e}, {now - t0:.1f} s", live=last != t0)
                last = now
            if stop():
                interrupted = True
                break
    # on the host at once (indexing device arrays compiles a small program per shape)
    *out, known = jax.device_get(_finish_jit(problem, solver, static, carry))
    missing = np.flatnonzero(~np.asarray(known))  # solves that accepted no step
    if missing.size:
        out[3], out[5] = np.array(out[3]), [np.array(r) for r in out[5]]  # (writable)
        for k in missing:
            cost, residuals = _evaluate_at(problem, out[0][k])
            out[3][k] = float(cost)
            for r, e in zip(out[5], residuals, strict=True):
                r[k] = np.ravel(e)
    out = tuple(out)
    if every:
        steps = int(np.max(np.asarray(out[2])))
        _say(label, f"{'interrupted at' if interrupted else 'done after'} {steps} steps, "
             f"best cost {np.nanmin(np.asarray(out[3])):.4e}, "
             f"{time.perf_counter() - t0:.1f} s")
    return out, interrupted


def start_z(problem: AbstractProblem, start) -> jax.Array:
    """z0 from parameters of the problem's kind (projected into the box; a batch of them
    gives (K, n)) or from box coordinates u ∈ [0, 1]ⁿ (shape (n,) or (K, n)). For a
    space over a single array, an array is read as box coordinates."""
    space = problem.space
    tree_kind = not jax.tree_util.treedef_is_leaf(space.treedef)
    if tree_kind and jax.tree.structure(start) == space.treedef:
        leaf, shape = jax.tree.leaves(start)[0], space.shapes[0]
        if jnp.ndim(leaf) > len(shape):
            return jax.vmap(space.z_from_params)(start)
        return space.z_from_params(start)
    try:
        u = jnp.asarray(start, dtype=jnp.float64)
    except (TypeError, ValueError):
        raise TypeError(_start_kind_message(space, start)) from None
    if u.ndim not in (1, 2) or u.shape[-1] != space.n_free:
        raise ValueError(f"A start in box coordinates needs {space.n_free} entries (free "
                         f"parameters {space.names}); got shape {u.shape}.")
    u_np = np.asarray(u)
    if not np.all((u_np >= 0) & (u_np <= 1)):
        kind = (f"; to start from values of the parameters give {_kind(space)}"
                if tree_kind else "")
        raise ValueError(
            f"Box coordinates u of a start must lie in [0, 1] (an array start is read as "
            f"box coordinates, one per free parameter: {', '.join(space.names)}); got "
            f"values from {np.nanmin(u_np):.6g} to {np.nanmax(u_np):.6g}{kind}.")
    return _z_from_u_jit(u)


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


def _evaluation(problem, z):
    """(cost, group residuals) at the solver coordinate z."""
    return problem.cost(z), problem.group_residuals(problem.space.params_from_z(z))


# compiled: an eager vmapped scan runs op by op
_evaluate_at = eqx.filter_jit(_evaluation)


@eqx.filter_jit
def _point(space, z):
    """(free values in SI, parameter pytree) at the solver coordinate z."""
    return space.free_from_u(u_from_z(z)), space.params_from_z(z)


def summarize(problem: AbstractProblem, z, steps, outcome, solver: str, wall: float,
              extra: dict | None = None, evaluated=None) -> IdentificationResult:
    """An `IdentificationResult` at the solver coordinate ``z`` (without report).
    ``evaluated``: (cost, group residuals) at ``z`` when the caller has them already."""
    cost, residuals = evaluated if evaluated is not None else _evaluate_at(
        problem, np.asarray(z))
    cost = float(cost)
    outcome = Outcome(outcome)
    if not np.isfinite(cost) and outcome is not Outcome.interrupted:
        outcome = Outcome.nonfinite
    groups, rms, max_abs, sse = _stats(problem.groups, residuals)
    scales = _data_scales(problem)
    if scales is not None:  # the built-in problems: max|data| of each group
        for g, sc in zip(groups.values(), scales, strict=True):
            g["data_scale"] = sc
    space = problem.space
    values, params = _point(space, np.asarray(z))  # (jnp.asarray would compile a copy)
    values = np.asarray(values, dtype=float)
    lower, upper = np.asarray(space.lower), np.asarray(space.upper)
    at_bound = {space.names[i]: (side, float(lower[i] if side == "lower" else upper[i]))
                for i, side in bound_status(values, lower, upper).items()}
    return IdentificationResult(
        params=params, free=space.names,
        values=tuple(float(v) for v in values), cost=cost, outcome=outcome, steps=int(steps),
        solver=solver, wall_time=wall, groups=groups, rms_error=rms, max_abs_error=max_abs,
        sse=sse, output=getattr(problem, "output", ""), extra=extra or {},
        at_bound=at_bound,
    )  # fmt: skip


def _data_scales(problem) -> list[float] | None:
    """max|data| of each residual group of the built-in problems (None for others)."""
    if hasattr(problem, "scales"):
        return [float(s) for s in problem.scales]
    if hasattr(problem, "scale") and len(problem.groups) == 1:
        return [float(problem.scale)]
    return None


def solve(problem: AbstractProblem, start, solver="lm", max_steps: int = 200,
          rtol: float = 1e-10, atol: float = 1e-12,
          progress: bool = False) -> IdentificationResult:
    """Run one local solver from ``start`` (parameters, or box coordinates u).

    ``solver``: a name of `jaxhyst.identify.SOLVERS` (with termination tolerances
    ``rtol``/``atol``) or any Optimistix least-squares solver or minimiser object.
    ``max_steps`` bounds the iterations (the paper's T3 for ``lma``/``tra``); a solve
    that reaches it reports the outcome ``max_steps_reached``, never success.
    ``progress``: say on stderr what is compiling, then the step and cost every
    ``progress`` seconds (True: 2). Ctrl-C/SIGTERM stops after the current chunk of
    steps and returns the point reached (outcome ``interrupted``)."""
    z0 = start_z(problem, start)
    if z0.ndim != 1:
        raise ValueError("solve takes one start; use multistart for a batch of starts.")
    solver_obj = make_solver(solver, rtol, atol)
    t0 = time.perf_counter()
    (z, code, steps, cost, _, residuals), interrupted = stepped_solve(
        problem, solver_obj, np.asarray(z0)[None], max_steps, progress,
        solver_name(solver))
    wall = time.perf_counter() - t0
    outcome = Outcome.interrupted if interrupted else CODES[int(code[0])]
    return summarize(problem, z[0], steps[0], outcome, solver_name(solver), wall,
                     evaluated=(cost[0], [r[0] for r in residuals]))


def multistart(problem: AbstractProblem, starts, solver="lm", max_steps: int = 200,
               rtol: float = 1e-10, atol: float = 1e-12,
               progress: bool = False) -> IdentificationResult:
    """Solve from K starts in one vmapped batch; returns the best, with the per-start
    table (final cost, outcome, steps, free values) in ``extra["starts"]``.

    ``starts``: box coordinates of shape (K, n_free), or a batch of parameters. The batch
    runs until its slowest member stops, so ``max_steps`` matters. The outcome is the
    best start's. ``progress`` as for `solve`."""
    if isinstance(starts, (int, np.integer)) and not isinstance(starts, bool):
        n = problem.space.n_free
        raise ValueError(
            f"multistart takes the starts themselves, not their number: e.g. {starts} "
            f"starts spread over the box as box coordinates, jax.random.uniform("
            f"jax.random.PRNGKey(0), ({starts}, {n})), or a batch of parameters.")
    z0s = start_z(problem, starts)
    if z0s.ndim != 2:
        raise ValueError("multistart needs a batch of starts, shape (K, n_free).")
    solver_obj = make_solver(solver, rtol, atol)
    t0 = time.perf_counter()
    label = f"{solver_name(solver)} x{z0s.shape[0]}"
    (zs, codes, steps, costs, _, residuals), interrupted = stepped_solve(
        problem, solver_obj, z0s, max_steps, progress, label)
    costs = np.asarray(costs)
    wall = time.perf_counter() - t0
    ranked = np.where(np.isfinite(costs), costs, np.inf)
    best = int(np.argmin(ranked))
    space = problem.space
    values = np.asarray(_point(space, zs)[0])  # (K, n), one compiled call
    table = [
        {"cost": float(costs[i]), "result": CODES[int(codes[i])].value, "steps": int(steps[i]),
         "params": dict(zip(space.names, values[i].tolist(), strict=True))}
        for i in range(len(costs))
    ]  # fmt: skip
    outcome = Outcome.interrupted if interrupted else CODES[int(codes[best])]
    return summarize(problem, zs[best], steps[best], outcome,
                     f"{solver_name(solver)} x{len(costs)}", wall,
                     extra={"starts": table, "best_index": best},
                     evaluated=(costs[best], [r[best] for r in residuals]))
