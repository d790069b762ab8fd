"""The paper's hybrid genetic algorithms (§3.4) as a solver in Optimistix's shape.

A hybrid is the hybrid-coded GA (BCGA for T1 generations, then FCGA) composed with a
local solver (an Optimistix solver object, or a name), the way Optimistix composes a
descent with a search — GATR1 and GALM1 differ in one field:

| method  | local solver | placement                                              |
|---------|--------------|--------------------------------------------------------|
| GATR1   | ``tra``      | ``inside``: every FCGA generation, from the best       |
| GALM1   | ``lma``      | ``inside``                                             |
| GATR2   | ``tra``      | ``after``: T3 iterations from the FCGA's best          |
| GALM2   | ``lma``      | ``after``                                              |
| GA      | none         | —                                                      |

`HybridGA` holds its settings as fields: those that shape the compiled programs
(population sizes, bits, elites, local steps, carry-over, sharding) are static; the
numbers a generation only reads (T1, T2, pc, pm, β, c1) and the step limits of the final
solves (T3, check_steps) are arrays, so that new values compile nothing. Its methods are
``init`` (the first `GAState`), ``step`` (one generation, state → (state, record): the
population's costs in one vmapped batch, sharded over devices with no communication when
there are several; the ``inside`` local search by the programs of a stepped solve, which
the ``after`` placement's solve shares; selection and reproduction — each program shared
by every hybrid of equal settings), ``terminate`` and ``postprocess`` (the ``after``
placement's solve and the convergence check, stepped by the one driver).
`jaxhyst.identify.run.run_hybrid` drives it.

Choices (documented in docs/identification.md):
- BCGA → FCGA: the q2 fittest of the last BCGA generation are the FCGA's first parents.
- Inside the FCGA the local search runs ``local_steps`` steps (default 5) from the best
  individual after each evaluation; its result replaces that individual (so it passes
  on as an elite). With ``carry_over`` the LMA damping / TRA radius it ended with is
  where the next one starts; a best individual where the last local search already
  converged is not searched again.
- Fitness F = 1/√(c1 + E) (eq 35); non-finite costs get F = 0 and are counted.
- **Convergence check**: every run ends with a Levenberg–Marquardt solve (``lm``, up to
  ``check_steps``, default 100) from its best point. Its outcome is the run's outcome: a
  run whose best point is not at an optimum the check can reach says
  ``max_steps_reached``. Where the check lowered the cost, the result is the lower point
  and ``extra["convergence_check"]`` says by how much. LM rather than the hybrid's own
  solver: the paper's TRA rejects every step at an optimum with non-zero residuals (its
  ratio test then compares round-off) and would never report convergence there.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._driver import DONE, STOPPED, drive
from .._interrupt import stop_requested
from ..names import HYBRID_NAMES
from ..sharding import map_sharded, shardable, vmap_blocked
from ._stepped import SteppedSolve, evaluate_at
from .ga import GAState, bcga_offspring, decode, fcga_offspring
from .problem import AbstractProblem
from .result import RESULTS, member, outcome_name
from .solvers import initial_step_size, make_solver, solver_name, with_initial_step_size
from .space import u_from_z, z_from_u

#: Settings that shape the compiled generation programs (static fields).
STRUCTURE = ("q1", "q2", "bits", "elites", "local_steps", "carry_over", "shard")
#: Settings a generation only reads, or the host loop uses (array fields).
NUMBERS = ("T1", "T2", "T3", "check_steps", "pc", "pm", "beta", "c1")


def _int(value, name: str) -> int:
    if isinstance(value, bool) or not float(value).is_integer():
        raise ValueError(f"HybridGA.{name} must be an integer; got {value!r}.")
    return int(value)


class HybridGA(eqx.Module):
    """A GA plus a local solver, with the paper's settings (§4) as fields.

    **Arguments:**
    - ``local_solver``: an Optimistix least-squares solver or minimiser, a name of
      `jaxhyst.identify.SOLVERS`, or ``None`` (the plain GA).
    - ``placement``: ``inside`` (GATR1/GALM1) or ``after`` (GATR2/GALM2).
    - ``name``: the label of its progress lines and results.
    - ``q1``, ``q2``: BCGA and FCGA population sizes; ``bits`` per parameter (BCGA);
      ``elites`` kept unchanged per generation.
    - ``T1``, ``T2``: BCGA and FCGA generations; ``T3``: local iterations of the
      ``after`` placement; ``local_steps``: local steps per FCGA generation (``inside``).
    - ``pc``, ``pm``: crossover and mutation probabilities; ``beta``: non-uniform
      mutation exponent; ``c1``: of the fitness F = 1/√(c1 + E).
    - ``carry_over``: the local search's damping / radius carries over between
      generations; ``check_steps``: steps of the final convergence check (0 skips it);
      ``shard``: split each generation's population over all devices when it divides
      evenly (results are the same either way).
    """

    local_solver: object
    placement: str = eqx.field(static=True)
    name: str = eqx.field(static=True)
    q1: int = eqx.field(static=True)
    q2: int = eqx.field(static=True)
    bits: int = eqx.field(static=True)
    elites: int = eqx.field(static=True)
    local_steps: int = eqx.field(static=True)
    carry_over: bool = eqx.field(static=True)
    shard: bool = eqx.field(static=True)
    T1: np.ndarray
    T2: np.ndarray
    T3: np.ndarray
    check_steps: np.ndarray
    pc: np.ndarray
    pm: np.ndarray
    beta: np.ndarray
    c1: np.ndarray

    def __init__(self, local_solver=None, placement: str = "inside", name: str = "", *,
                 q1=120, q2=30, bits=16, elites=2, local_steps=5, carry_over=True,
                 shard=True, T1=5, T2=295, T3=350, check_steps=100, pc=0.8, pm=0.05,
                 beta=5.0, c1=1e-30):
        if placement not in ("inside", "after"):
            raise ValueError(f"placement must be 'inside' or 'after'; got {placement!r}.")
        self.local_solver = None if local_solver is None else make_solver(local_solver)
        self.placement = placement
        self.name = name or ("GA" if local_solver is None else
                             f"GA+{solver_name(local_solver)} ({placement})")
        counts = {n: _int(v, n) for n, v in (("q1", q1), ("q2", q2), ("bits", bits),
                                             ("elites", elites), ("local_steps", local_steps),
                                             ("T1", T1), ("T2", T2), ("T3", T3),
                                             ("check_steps", check_steps))}
        if not (counts["q1"] >= counts["q2"] >= counts["elites"] + 2 and counts["elites"] >= 0):
            raise ValueError(f"HybridGA needs q1 >= q2 >= elites + 2 and elites >= 0; got "
                             f"q1={q1}, q2={q2}, elites={elites}.")
        if counts["T1"] < 1 or min(counts["T2"], counts["T3"], counts["local_steps"],
                                   counts["check_steps"]) < 0:
            raise ValueError("HybridGA needs T1 >= 1 and T2, T3, local_steps, check_steps "
                             ">= 0.")
        if not 2 <= counts["bits"] <= 30:
            raise ValueError(f"HybridGA.bits must be in 2 … 30; got {bits}.")
        if not (0 <= pc <= 1 and 0 <= pm <= 1):
            raise ValueError(f"HybridGA: pc and pm are probabilities in [0, 1]; got pc={pc}, "
                             f"pm={pm}.")
        if not (np.isfinite(beta) and beta > 0 and np.isfinite(c1) and c1 > 0):
            raise ValueError("HybridGA: beta and c1 must be finite and > 0.")
        self.q1, self.q2, self.bits = counts["q1"], counts["q2"], counts["bits"]
        self.elites, self.local_steps = counts["elites"], counts["local_steps"]
        self.carry_over, self.shard = bool(carry_over), bool(shard)
        for n in ("T1", "T2", "T3", "check_steps"):
            setattr(self, n, np.asarray(counts[n], np.int64))
        for n, v in (("pc", pc), ("pm", pm), ("beta", beta), ("c1", c1)):
            setattr(self, n, np.asarray(float(v), np.float64))

    # -- settings -------------------------------------------------------------------------
    def settings(self) -> dict:
        """Every setting as a Python number, by name."""
        out = {n: getattr(self, n) for n in STRUCTURE}
        out.update({n: getattr(self, n).item() for n in NUMBERS})
        return out

    def replace(self, **settings) -> HybridGA:
        """A copy with some settings changed (``method.replace(T2=50)``)."""
        unknown = sorted(set(settings) - set(STRUCTURE) - set(NUMBERS))
        if unknown:
            raise ValueError(f"Unknown HybridGA settings {unknown}; the settings are "
                             f"{sorted(STRUCTURE + NUMBERS)}.")
        return HybridGA(self.local_solver, self.placement, self.name,
                        **{**self.settings(), **settings})

    @property
    def generations(self) -> int:
        return int(self.T1) + int(self.T2)

    # -- the solver's interface --------------------------------------------------------------
    def init(self, problem: AbstractProblem, seed: int) -> GAState:
        """The state before the first generation; everything random derives from
        ``jax.random.PRNGKey(seed)``."""
        n = problem.space.n_free
        key, k0 = jax.random.split(jax.random.PRNGKey(seed))
        genes = jax.random.bernoulli(k0, 0.5, (self.q1, n, self.bits)).astype(jnp.uint8)
        step = initial_step_size(self.local_solver) if self.local_solver is not None else 1.0
        # dtypes as the generations return them (none weakly typed): otherwise the second
        # generation would compile its program again
        i64, f64 = jnp.zeros((), jnp.int64), jnp.float64
        return GAState(key=key, genes=genes, U=jnp.zeros((self.q2, n), f64), generation=i64,
                       best_u=jnp.full((n,), 0.5, f64), best_cost=jnp.asarray(jnp.inf, f64),
                       evaluations=i64, failures=i64, local_steps=i64,
                       step_size=jnp.asarray(float(step), f64),
                       last_local_u=jnp.zeros((n,), f64), has_last_local=jnp.asarray(False))

    def step(self, problem: AbstractProblem, state: GAState) -> tuple[GAState, dict]:
        """One generation (BCGA while i ≤ T1, then FCGA): (new state, record). An FCGA
        generation is three programs — the population's costs, the ``inside`` local
        search (the programs of a stepped solve of one start, which the ``after``
        placement's solve shares), selection and reproduction — each shared by every
        hybrid that runs it."""
        seen = self._as_generation_sees_it()
        if int(state.generation) < int(self.T1):
            return _bcga_generation(problem, seen, state)
        costs, bad = _fcga_costs(problem, state.U, self.shard)
        return _fcga_generation(problem, seen, state, costs, bad,
                                self._local_search(problem, state, costs))

    def _as_generation_sees_it(self) -> HybridGA:
        """Itself without what a generation's programs do not use (the name, the local
        search, its placement), so that every hybrid of equal settings shares them."""
        return HybridGA(None, "inside", "GA", **{**self.settings(), "local_steps": 0})

    def _local_search(self, problem: AbstractProblem, state: GAState, costs) -> tuple:
        """The ``inside`` search (``local_steps`` steps) from the generation's best, unless
        the last one converged there (skipped: cost the best's): (ran, skipped, z, result,
        steps, cost, final step size), host values (z 0, NaN where none ran)."""
        if self.local_solver is None or self.placement != "inside" or not self.local_steps:
            return _as_local(False, False, np.zeros(np.shape(state.U)[1]), RESULTS.successful,
                             0, np.nan, np.nan)
        costs, U = np.asarray(costs), np.asarray(state.U)
        best = int(np.argmin(costs))
        if bool(state.has_last_local) and np.array_equal(U[best], np.asarray(state.last_local_u)):
            return _as_local(False, True, np.zeros(U.shape[1]), RESULTS.successful, 0,
                             costs[best], np.nan)
        z0 = np.asarray(_z_from_u(U[best]))
        solver = with_initial_step_size(self.local_solver, state.step_size)
        run = SteppedSolve(problem, solver, z0[None], self.local_steps, with_cost=True)
        run.chunk = self.local_steps
        z, results, steps, cost, final, _ = run.outputs(run.advance(run.state))
        return _as_local(True, False, z[0], member(results, 0), steps[0], cost[0], final[0])

    def terminate(self, state: GAState) -> bool:
        """Whether every generation is done."""
        return int(state.generation) >= self.generations

    def postprocess(self, problem: AbstractProblem, state: GAState, meter):
        """The ``after`` placement's solve (``T3`` steps) and the convergence check
        (``check_steps`` LM steps) from the best point, each stepped by the driver.
        Returns (z, outcome, {"after", "convergence_check", "local_steps"}, how) with how
        the driver's (``"stopped"`` also for a stop requested between the two)."""
        z = best_z(state)
        best_cost = float(state.best_cost)
        info = {"after": None, "convergence_check": None, "local_steps": 0}
        outcome = None
        if self.local_solver is not None and self.placement == "after" and int(self.T3):
            solver = with_initial_step_size(self.local_solver, initial_step_size(
                self.local_solver))
            found, how = _final_solve(problem, solver, z, int(self.T3), meter,
                                      f"{self.name} local")
            info["local_steps"] = found["steps"]
            info["after"] = {"result": found["result"], "steps": found["steps"],
                             "cost_before": best_cost, "cost_after": found["cost"]}
            if np.isfinite(found["cost"]) and found["cost"] <= best_cost:
                z = found["z"]
            if how != DONE:
                return z, RESULTS.interrupted, info, how
            outcome = found["outcome"]
        if not int(self.check_steps):  # no convergence test: the run only reached its limit
            return z, outcome or RESULTS.nonlinear_max_steps_reached, info, DONE
        if stop_requested():  # stopped before the check began
            return z, RESULTS.interrupted, info, STOPPED
        before = float(evaluate_at(problem, z)[0])  # (the program a stepped solve has)
        found, how = _final_solve(problem, make_solver("lm"), z, int(self.check_steps), meter,
                                  f"{self.name} check")
        info["convergence_check"] = {"result": found["result"], "steps": found["steps"],
                                     "cost_before": before, "cost_after": found["cost"]}
        if np.isfinite(found["cost"]) and found["cost"] < before:
            z = found["z"]
        return z, (found["outcome"] if how == DONE else RESULTS.interrupted), info, how


#: The paper's hybrids and the plain GA, by name (`jaxhyst.names.HYBRID_NAMES`).
HYBRIDS = {
    "GATR1": HybridGA("tra", "inside", "GATR1"),
    "GALM1": HybridGA("lma", "inside", "GALM1"),
    "GATR2": HybridGA("tra", "after", "GATR2"),
    "GALM2": HybridGA("lma", "after", "GALM2"),
    "GA": HybridGA(None, "after", "GA"),
}
assert tuple(HYBRIDS) == HYBRID_NAMES


_z_from_u = jax.jit(z_from_u)


def best_z(state: GAState) -> np.ndarray:
    """The solver coordinates z of the best point of ``state``."""
    return np.asarray(_z_from_u(state.best_u))


def _final_solve(problem, solver, z0, max_steps: int, meter, label: str):
    """One stepped solve from z0 (its step limit is data: a new T3 or check_steps
    compiles nothing): ({z, outcome, result, steps, cost}, how)."""
    run = SteppedSolve(problem, solver, np.asarray(z0)[None], max_steps, with_cost=True)
    meter_state = meter.init(label, max_steps)
    carry, how, meter_state = drive(run.state, advance=run.advance, done=run.done,
                                    describe=run.describe, meter=meter,
                                    meter_state=meter_state)
    z, results, steps, cost, _, _ = run.outputs(carry)
    outcome = member(results, 0) if how == DONE else RESULTS.interrupted
    found = {"z": np.asarray(z[0]), "outcome": outcome, "result": outcome_name(outcome),
             "steps": int(steps[0]), "cost": float(cost[0])}
    meter.close(meter_state, f"{'done after' if how == DONE else 'interrupted at'} "
                f"{found['steps']} steps, cost {found['cost']:.4e}")
    return found, how


# -- one generation ---------------------------------------------------------------------------

def _evaluate(problem, U, shard: bool = True):
    """Costs of a population (vmapped, in blocks on the CPU when large: `vmap_blocked`;
    over all devices, no communication, when ``shard`` and the population divides
    evenly)."""
    P = U.shape[0]
    split = shard and shardable(P)
    per_device = P // jax.device_count() if split else P
    return map_sharded(vmap_blocked(problem.cost_u, per_device), P, split)(U)


def _record(state, costs, fitness, local):
    finite = jnp.isfinite(costs)
    mean = jnp.sum(jnp.where(finite, fitness, 0.0)) / jnp.maximum(jnp.sum(finite), 1)
    return {"best_cost": state.best_cost, "best_fitness": jnp.max(fitness),
            "mean_fitness": mean, "best_u": state.best_u,
            "evaluations": state.evaluations, "failures": state.failures, **local}


def _no_local(cost):
    return {"local_ran": jnp.asarray(False), "local_skipped": jnp.asarray(False),
            "local_result": RESULTS.successful, "local_steps": jnp.asarray(0, jnp.int64),
            "local_cost_before": cost, "local_cost_after": jnp.asarray(jnp.nan)}


def _update_best(state, population, costs):
    best = jnp.argmin(costs)
    better = costs[best] < state.best_cost
    return (jnp.where(better, population[best], state.best_u),
            jnp.where(better, costs[best], state.best_cost))


@eqx.filter_jit
def _bcga_generation(problem, method: HybridGA, state: GAState):
    """One BCGA generation (i ≤ T1): evaluate the binary population, keep the best,
    reproduce; at i = T1 hand the q2 fittest to the FCGA."""
    i = state.generation + 1
    T = method.T1 + method.T2
    population = decode(state.genes)
    costs = _evaluate(problem, population, method.shard)
    bad = ~jnp.isfinite(costs)
    costs = jnp.where(bad, jnp.inf, costs)
    fitness = problem.fitness_from_cost(costs, method.c1)
    best_u, best_cost = _update_best(state, population, costs)
    key, k = jax.random.split(state.key)

    def next_bcga(_):
        genes = bcga_offspring(k, state.genes, fitness, method.pc, method.pm,
                               elites=method.elites)
        return genes, state.U

    def handover(_):
        top = jnp.argsort(costs, stable=True)[: method.q2]
        U = population[top]
        U = jax.lax.cond(i < T, lambda U: fcga_offspring(k, U, fitness[top], i, T, method.pc,
                                                         method.pm, method.beta,
                                                         elites=method.elites),
                         lambda U: U, U)
        return state.genes, U

    genes, U = jax.lax.cond(i < method.T1, next_bcga, handover, None)
    new = eqx.tree_at(
        lambda st: (st.key, st.genes, st.U, st.generation, st.best_u, st.best_cost,
                    st.evaluations, st.failures),
        state, (key, genes, U, i, best_u, best_cost,
                state.evaluations + population.shape[0], state.failures + jnp.sum(bad)))
    return new, _record(new, costs, fitness, _no_local(jnp.min(costs)))


def _as_local(ran, skipped, z, result, steps, cost, final) -> tuple:
    """A local search's outcome in fixed dtypes (one program whether a search ran or not)."""
    return (np.asarray(ran, bool), np.asarray(skipped, bool), np.asarray(z, np.float64),
            jax.tree.map(lambda v: np.asarray(v, np.int32), result),
            np.asarray(steps, np.int64), np.asarray(cost, np.float64),
            np.asarray(final, np.float64))


@eqx.filter_jit
def _fcga_costs(problem, U, shard: bool):
    """The FCGA population's costs (non-finite → +inf) and which were not finite."""
    costs = _evaluate(problem, U, shard)
    bad = ~jnp.isfinite(costs)
    return jnp.where(bad, jnp.inf, costs), bad


@eqx.filter_jit
def _fcga_generation(problem, method: HybridGA, state: GAState, costs, bad, local):
    """One FCGA generation (i > T1) after its population's costs and local search
    (`HybridGA._local_search`): the searched point replaces the best individual where it
    is no worse; keep the best, reproduce."""
    i = state.generation + 1
    T = method.T1 + method.T2
    population = state.U
    best = jnp.argmin(costs)
    ran, skipped, z, result, steps, cost, final = local
    before = costs[best]
    improved = ran & jnp.isfinite(cost) & (cost <= costs[best])
    population = jnp.where(improved, population.at[best].set(u_from_z(z)), population)
    costs = jnp.where(improved, costs.at[best].set(cost), costs)
    step_size = state.step_size
    if method.carry_over:
        step_size = jnp.where(ran & jnp.isfinite(final) & (final > 0), final, step_size)
    last_u = jnp.where(ran, population[best], state.last_local_u)
    has_last = jnp.where(ran, result == RESULTS.successful, state.has_last_local)
    local = {"local_ran": ran, "local_skipped": skipped, "local_result": result,
             "local_steps": steps, "local_cost_before": before, "local_cost_after": cost}
    fitness = problem.fitness_from_cost(costs, method.c1)
    best_u, best_cost = _update_best(state, population, costs)
    key, k = jax.random.split(state.key)
    U = jax.lax.cond(i < T, lambda U: fcga_offspring(k, U, fitness, i, T, method.pc,
                                                     method.pm, method.beta,
                                                     elites=method.elites),
                     lambda U: U, population)
    new = eqx.tree_at(
        lambda st: (st.key, st.U, st.generation, st.best_u, st.best_cost, st.evaluations,
                    st.failures, st.local_steps, st.step_size, st.last_local_u,
                    st.has_last_local),
        state, (key, U, i, best_u, best_cost, state.evaluations + population.shape[0],
                state.failures + jnp.sum(bad), state.local_steps + steps, step_size,
                last_u, has_last))
    return new, _record(new, costs, fitness, local)
