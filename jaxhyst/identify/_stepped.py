"""Optimistix's iteration, stepped: the one mirror of its loop in jaxhyst.

A solve is ``init``, then ``advance`` (up to n of the solver's steps, a compiled
``while_loop``), then ``finish`` (the solver's ``postprocess`` and the end point's cost)
— exactly the loop of ``optx.least_squares``/``optx.minimise`` (`optimistix._iterate`:
the termination test sees the previous iterate, a non-finite iterate ends the solve, the
static part of the state is the initial one, a solve that did not terminate by itself
reports ``nonlinear_max_steps_reached``); a test checks both give the same iterates. It
is used two ways:

- **traced whole** (`solve_traced`): one solve inside a compiled program — replicate
  fits vmapped over data sets, the profile's re-fits;
- **stepped from the host** (`SteppedSolve`): a vmapped batch of starts advanced a chunk
  of steps per dispatch by the one driver (`jaxhyst._driver`), which reports
  progress and honours interruption between chunks. Nothing in the compiled programs
  calls back into Python, so they go into the persistent compilation cache.

Outcomes are `RESULTS` values throughout.
"""

from __future__ import annotations

import contextlib
import time

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._background import meanwhile
from .._background import settled as _settled
from .._traces import kept_jit
from ..model.simulate import plain_vmap
from ._objective import objective
from .problem import AbstractProblem
from .result import RESULTS
from .solvers import accepted_jacobian, accepted_residuals, final_step_size

_TAGS = frozenset()
#: A batch's best cost has settled where a chunk of steps changed it by less than this
#: fraction of itself.
SETTLED = 1e-4


def _terminate(solver, fn, y, options, state):
    term, result = solver.terminate(fn, y, None, options, state, _TAGS)
    finite = jnp.all(jnp.isfinite(y))
    return term, optx.RESULTS.where(finite, result, optx.RESULTS.nonfinite)


def init(problem: AbstractProblem, solver, z0):
    """The solve's carry (y, steps, dynamic state, terminate, result) at z0, and the
    static part of the solver state."""
    solver, fn, options = objective(problem, solver)
    f_struct, aux_struct = jax.eval_shape(fn, z0, None)
    state = solver.init(fn, z0, None, options, f_struct, aux_struct, _TAGS)
    term, result = _terminate(solver, fn, z0, options, state)
    dynamic, static = eqx.partition(state, eqx.is_array)
    return (z0, jnp.array(0), dynamic, term, result), static


def running(carry, max_steps):
    """Whether a solve with ``carry`` goes on (not terminated, no failure, under
    ``max_steps``)."""
    _, steps, _, term, result = carry
    return (~term) & (result == optx.RESULTS.successful) & (steps < max_steps)


def advance(problem: AbstractProblem, solver, static, carry, n, max_steps):
    """Up to ``n`` more steps of the solve (fewer where it stops)."""
    solver, fn, options = objective(problem, solver)

    def cond(c):
        return running(c[:5], max_steps) & (c[5] < n)

    def body(c):
        y, steps, dynamic, _, _, i = c
        state = eqx.combine(static, dynamic)
        new_y, new_state, _ = solver.step(fn, y, None, options, state, _TAGS)
        term, result = _terminate(solver, fn, y, options, new_state)
        return (new_y, steps + 1, eqx.filter(new_state, eqx.is_array), term, result, i + 1)

    y, steps, dynamic, term, result, _ = jax.lax.while_loop(cond, body, (*carry, 0))
    return y, steps, dynamic, term, result


def finish(problem: AbstractProblem, solver, static, carry):
    """(y, result, steps, cost, final step size, group residuals, known, linearization)
    at the end of a solve. A Gauss–Newton state holds the residual vector at its
    accepted point, so no simulation is run here for those; before the first accepted
    step the state holds placeholder zeros (``known`` False) and the caller evaluates
    the end point. ``linearization``: (∂r/∂z (R, n), r (R,)) at y from that state (None
    for other solvers; meaningful where ``known``)."""
    run, fn, options = objective(problem, solver)
    y, steps, dynamic, term, result = carry
    state = eqx.combine(static, dynamic)
    result = optx.RESULTS.where((result == optx.RESULTS.successful) & ~term,
                                optx.RESULTS.nonlinear_max_steps_reached, result)
    y, _, _ = run.postprocess(fn, y, None, None, options, state, _TAGS, result)
    held = accepted_residuals(run, state)
    if held is None:
        cost, residuals = problem.cost(y), problem.group_residuals(problem.space.params_from_z(y))
        residuals, known = tuple(jnp.ravel(e) for e in residuals), jnp.array(True)
        linearization = None
    else:
        r, accepted = held
        cost, residuals, known = jnp.sum(r**2), problem.groups_from_residuals(r), accepted > 0
        linearization = (accepted_jacobian(run, state), r)
    return (y, RESULTS.promote(result), steps, cost, final_step_size(run, state), residuals,
            known, linearization)


def solve_traced(problem: AbstractProblem, solver, z0, max_steps):
    """One whole solve from z0 inside a trace: (z, result, steps, cost, final step size),
    arrays only, so that it vmaps."""
    carry, static = init(problem, solver, z0)
    carry = advance(problem, solver, static, carry, max_steps, max_steps)
    y, result, steps, cost, step_size, _, known, _ = finish(problem, solver, static, carry)
    cost = jnp.where(known, cost, problem.cost(y))  # (a cond of it does not vmap)
    return y, result, steps, cost, step_size


# -- batches stepped from the host ---------------------------------------------------------

def _ended(carry, max_steps):
    """(running, converged: stopped by the solver's own test) per start."""
    _, _, _, term, result = carry
    return running(carry, max_steps), term & (result == optx.RESULTS.successful)


@jax.jit
@jax.vmap
def _mark_overtaken(mask, result):
    return RESULTS.where(mask, RESULTS.overtaken, result)


_ended_jit = jax.jit(_ended)  # (op by op, each operation would compile on its own)


def _static(problem, solver, carry):
    """The static part of the solver state of a batch's solves (what `init` returns
    beside the carry: the same for every start), made inside the trace from the first
    start's point, so that a batch program's arguments are arrays and structure only
    (its trace can be kept: `jaxhyst._traces`)."""
    return init(problem, solver, carry[0][0])[1]


def _per_start(f, batch):
    """``jax.vmap(f)(batch)`` over a batch's starts (its leading axis) — or, for a batch
    of one start, ``f`` of that start with the axis put back: traced without the batching
    interpreter and run by the model's single-trajectory code (a solve's step traces in
    under half the time; `benchmarks/RESULTS.md`, issue 45)."""
    if jax.tree.leaves(batch)[0].shape[0] != 1:
        return jax.vmap(f)(batch)
    return jax.tree.map(lambda x: jnp.asarray(x)[None], f(jax.tree.map(lambda x: x[0], batch)))


@kept_jit
def _init_batch(problem, solver, z0s):
    return _per_start(lambda z: init(problem, solver, z)[0], z0s)


@kept_jit
def _advance_batch(problem, solver, carry, n, max_steps, with_cost):
    run, _, _ = objective(problem, solver)
    static = _static(problem, solver, carry)

    def one(c):
        c = advance(problem, solver, static, c, n, max_steps)
        if not with_cost:
            return c, None
        # the cost for progress lines, in this program (a separate one would compile
        # again): a Gauss–Newton state holds the residuals at its point (before its first
        # accepted step, +inf: no cost known), so no simulation is added for those
        held = accepted_residuals(run, eqx.combine(static, c[2]))
        if held is None:
            return c, problem.cost(c[0])
        r, accepted = held
        return c, jnp.where(accepted > 0, jnp.sum(r**2), jnp.inf)

    return _per_start(one, carry)


@kept_jit
def _finish_batch(problem, solver, carry):
    static = _static(problem, solver, carry)
    return _per_start(lambda c: finish(problem, solver, static, c), carry)


@eqx.filter_jit
def evaluate_at(problem, z):
    """(cost, group residuals) at the solver coordinate z."""
    return problem.cost(z), problem.group_residuals(problem.space.params_from_z(z))


#: Starts whose cost is within this fraction of the best converged start's are at its
#: minimum (`SteppedSolve` stops them).
SAME_MINIMUM = 1e-6
#: The steps over which a start's pace (its fall of cost) is measured.
PACE_STEPS = 10


def best_start(costs, overtaken=None) -> int:
    """The index of the lowest finite cost (0 if none is finite); between equal costs
    a start not ``overtaken`` (mask, or None) — the one that converged."""
    costs = np.asarray(costs)
    ranked = np.where(np.isfinite(costs), costs, np.inf)
    left = np.zeros(costs.shape, bool) if overtaken is None else np.asarray(overtaken)
    return int(np.lexsort((left, ranked))[0])


def left_behind(steps, costs, history, best_cost, max_steps):
    """Which running starts cannot catch up with a converged start of cost
    ``best_cost``: those at its minimum (within `SAME_MINIMUM`) and those whose fall of
    cost over their last `PACE_STEPS` steps or more, kept up for every step left to them,
    would not reach it. ``steps``, ``costs``: (K,) now; ``history``: earlier (steps,
    costs) pairs, oldest first. A start with fewer steps behind it is not judged."""
    gap = costs - best_cost * (1.0 + SAME_MINIMUM)
    behind = ~np.isfinite(costs) | (gap <= 0)
    for k in np.flatnonzero(~behind):
        then = [(s[k], c[k]) for s, c in history if s[k] <= steps[k] - PACE_STEPS]
        if then:
            s0, c0 = then[-1]
            pace = max(c0 - costs[k], 0.0) / (steps[k] - s0)  # (cost per step)
            behind[k] = pace * (max_steps - steps[k]) < gap[k]
    return behind


class SteppedSolve:
    """A vmapped batch of solves from the starts ``z0s`` (K, n), advanced from the host a
    chunk of steps per dispatch (each dispatch kept near a quarter second): what the
    driver runs for `jaxhyst.identify.solve`, ``multistart`` and a hybrid's final
    solves (and, in one dispatch, a hybrid's local search inside a generation).
    ``state`` is the batch's carry; `advance`, `done` and `describe` are the driver's
    three questions; `outputs` ends the solves.

    A batch of several starts ends once a start has converged below every other's cost
    and none of the others can catch up (`left_behind`); those are reported
    ``overtaken`` (``self.overtaken``: their mask) instead of running to their own end —
    the slowest start no longer sets the time. ``finish_meanwhile``: the end's program
    compiles in a background thread while the first chunk's compiles (`jaxhyst._background`;
    for a solve that runs once, not a hybrid's search inside every generation); `drop`
    it where the solve is left on an error."""

    def __init__(self, problem: AbstractProblem, solver, z0s, max_steps: int,
                 with_cost: bool = False, finish_meanwhile: bool = False):
        self.problem, self.solver, self.max_steps = problem, solver, np.int64(max_steps)
        self.early = np.shape(z0s)[0] > 1
        self.with_cost = bool(with_cost) or self.early
        self.history, self.overtaken = [], None
        # a minimiser may vmap the function itself (Nelder–Mead): trace it plainly
        self.tracing = plain_vmap if isinstance(solver, optx.AbstractMinimiser) else \
            contextlib.nullcontext
        with self.tracing():
            self.state = _init_batch(problem, solver, np.asarray(z0s))
        self.chunk, self.costs, self.started = 1, None, time.perf_counter()
        self.best_before = None  # (the best cost at the last check: `_settling`)
        self.linearizations = None
        # (`_finish_batch` compiled meanwhile, where asked: `advance`; False once done)
        self.finishing = None if finish_meanwhile else False

    def done(self, carry) -> bool:
        # (host scalars: jnp.asarray of one compiles a program of its own on first use)
        run, converged = (np.asarray(v) for v in _ended_jit(carry, self.max_steps))
        if not np.any(run):
            return True
        if not self.early or self.costs is None:
            return False
        steps, costs = np.asarray(carry[1]), np.asarray(self.costs, dtype=np.float64)
        self.history.append((steps, costs))
        self._settling(costs)
        converged = converged & np.isfinite(costs)
        best = best_start(costs, ~converged)  # (a converged start first at equal cost)
        if not converged[best]:
            return False
        behind = left_behind(steps[run], costs[run], [(s[run], c[run]) for s, c in
                                                       self.history[:-1]],
                             costs[best], int(self.max_steps))
        if np.all(behind):
            self.overtaken = run
            return True
        return False

    def _settling(self, costs) -> None:
        """Say (`jaxhyst._background.settled`) once the batch's best cost has changed by
        less than `SETTLED` of itself over a chunk of steps: what waits for the fit's
        outcome may then start while the fit ends."""
        finite = costs[np.isfinite(costs)]
        if finite.size:
            now, before = float(np.min(finite)), self.best_before
            if before is not None and abs(before - now) <= SETTLED * now:
                _settled(now)
            self.best_before = now

    def advance(self, carry):
        if self.finishing is None and self.tracing is contextlib.nullcontext:
            # (the end's program, compiled in a background thread once this step's is
            # lowered, while XLA compiles that: its inputs have this carry's shapes)
            problem, solver = self.problem, self.solver
            self.finishing = meanwhile(lambda: _finish_batch(problem, solver, carry)) or False
        t0 = time.perf_counter()
        with self.tracing():
            carry, costs = _advance_batch(self.problem, self.solver, carry,
                                          np.int64(self.chunk), self.max_steps,
                                          self.with_cost)
        jax.block_until_ready(carry)
        if time.perf_counter() - t0 < 0.25:
            self.chunk = min(self.chunk * 2, 64)
        self.costs = costs
        return carry

    def drop(self) -> None:
        """Drop the end's background compile if it has not started (a solve left on an
        error; `outputs` joins it)."""
        if self.finishing:
            self.finishing.drop()
            self.finishing = False

    def describe(self, carry) -> tuple[int, str]:
        steps = int(np.max(np.asarray(carry[1])))
        text = f"step {steps}/{int(self.max_steps)}"
        if self.costs is not None:
            costs = np.asarray(self.costs)
            text += f": best cost {np.min(np.where(np.isfinite(costs), costs, np.inf)):.4e}"
        return steps, f"{text}, {time.perf_counter() - self.started:.1f} s"

    def outputs(self, carry):
        """(z, results, steps, cost, final step size, group residuals) of every solve, as
        host values (``results`` a batch of `RESULTS`). ``self.linearizations`` is then
        (∂r/∂z (K, R, n), r (K, R)) at each z, NaN for a solve that accepted no step, or
        None (a solver outside the Gauss–Newton family)."""
        if self.finishing:
            self.finishing.join()
            self.finishing = False
        # on the host at once (indexing device arrays compiles a small program per shape)
        with self.tracing():
            *out, known, linear = jax.device_get(_finish_batch(self.problem, self.solver,
                                                               carry))
        if linear is not None:
            lost = ~np.asarray(known)
            self.linearizations = tuple(np.where(lost.reshape((-1,) + (1,) * (a.ndim - 1)),
                                                 np.nan, a) for a in linear)
        if self.overtaken is not None:
            out[1] = jax.device_get(_mark_overtaken(jnp.asarray(self.overtaken), out[1]))
        missing = np.flatnonzero(~np.asarray(known))  # solves that accepted no step
        if missing.size:
            out[3], out[5] = np.array(out[3]), [np.array(r) for r in out[5]]  # (writable)
            for k in missing:
                cost, residuals = evaluate_at(self.problem, out[0][k])
                out[3][k] = float(cost)
                for r, e in zip(out[5], residuals, strict=True):
                    r[k] = np.ravel(e)
        return tuple(out)
