"""The paper's hybrid genetic algorithms (§3.4): a GA state, a pure jitted generation
step, and one thin driver.

A hybrid is the hybrid-coded GA (BCGA for T1 generations, then FCGA) composed with a
local solver (an Optimistix solver object, or a name), the way Optimistix composes a
descent with a search:

| method  | local solver | placement                                              |
|---------|--------------|--------------------------------------------------------|
| GATR1   | ``tra``      | ``inside``: every FCGA generation, from the best       |
| GALM1   | ``lma``      | ``inside``                                             |
| GATR2   | ``tra``      | ``after``: T3 iterations from the FCGA's best          |
| GALM2   | ``lma``      | ``after``                                              |
| GA      | none         | —                                                      |

``HybridGA(optx.LevenbergMarquardt(1e-10, 1e-12), "inside")`` plugs any solver in.

**State and step.** `GAState` holds everything a generation changes (key, BCGA genes,
FCGA population, best so far, counters, the local search's carried damping/radius).
`bcga_generation` and `fcga_generation` are pure functions state → (state, record),
each compiled once and dispatched once per generation: population evaluation (one
vmapped batch, sharded over devices with no communication when there are several),
the local search, selection and reproduction all run inside. The driver `run_hybrid`
only reports progress, records the history, checkpoints (the serialized state) and
handles interruption.

Choices (documented in docs/identification.md):
- BCGA → FCGA: the q2 fittest of the last BCGA generation are the FCGA's first parents.
- Inside the FCGA the local search runs ``local_steps`` steps (default 5) from the best
  individual after each evaluation; its result replaces that individual (so it passes
  on as an elite). With ``carry_over`` the LMA damping / TRA radius it ended with is
  where the next one starts (a restart at h1 = 0.01 made GALM1 stall at cost ~2e-9);
  a best individual where the last local search already converged is not searched again.
- Fitness F = 1/√(c1 + E) (eq 35); non-finite costs get F = 0 and are counted.
- **Convergence check**: every run ends with a Levenberg–Marquardt solve (``lm``, up to
  ``check_steps``, default 100) from its best point. Its outcome is the run's outcome: a
  run whose best point is not at an optimum the check can reach says
  ``max_steps_reached``. Where the check lowered the cost, the result is the lower point
  and ``extra["convergence_check"]`` says by how much (the result's text says that the
  GA stopped short). LM rather than the hybrid's own solver, because the paper's TRA
  rejects every step at an optimum with non-zero residuals (its ratio test then
  compares round-off) and would never report convergence there.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import sys
import time
import zipfile
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._files import write_bytes
from .._interrupt import interruptible
from ..names import HYBRID_NAMES
from ..sharding import map_sharded, shardable, vmap_blocked
from .ga import bcga_offspring, decode, fcga_offspring
from .local import CODES, run_local, stepped_solve, summarize
from .problem import AbstractProblem
from .result import IdentificationResult, Outcome
from .solvers import initial_step_size, make_solver, solver_name, with_initial_step_size
from .space import u_from_z, z_from_u

CHECKPOINT_VERSION = 2


class CheckpointError(ValueError):
    """A checkpoint file cannot be used (one-line message naming the file and the fix)."""


@dataclass(frozen=True)
class GASettings:
    """The paper's GA settings (§4): population sizes q1 (BCGA) and q2 (FCGA), crossover
    and mutation probabilities, bits per parameter, generations T1 (BCGA) and T2 (FCGA),
    local iterations T3 (``after`` placement), non-uniform mutation β, elites, local
    steps per FCGA generation (``inside`` placement), whether the local search's damping
    / radius carries over (``carry_over``), c1 of the fitness, and the steps of the final
    convergence check (``check_steps``; 0 skips it)."""

    q1: int = 120
    q2: int = 30
    pc: float = 0.8
    pm: float = 0.05
    bits: int = 16
    T1: int = 5
    T2: int = 295
    T3: int = 350
    beta: float = 5.0
    elites: int = 2
    local_steps: int = 5
    carry_over: bool = True
    c1: float = 1e-30
    check_steps: int = 100
    shard: bool = True

    def __post_init__(self):
        ints = ("q1", "q2", "bits", "T1", "T2", "T3", "elites", "local_steps", "check_steps")
        for name in ints:
            v = getattr(self, name)
            if isinstance(v, bool) or not isinstance(v, (int, np.integer)):
                raise ValueError(f"GASettings.{name} must be an integer; got {v!r}.")
        if self.q1 < self.q2 or self.q2 < self.elites + 2 or self.elites < 0:
            raise ValueError(f"GASettings need q1 >= q2 >= elites + 2 and elites >= 0; got "
                             f"q1={self.q1}, q2={self.q2}, elites={self.elites}.")
        if not (0 <= self.pc <= 1 and 0 <= self.pm <= 1):
            raise ValueError(f"GASettings: pc and pm are probabilities in [0, 1]; got "
                             f"pc={self.pc}, pm={self.pm}.")
        if self.T1 < 1 or self.T2 < 0 or self.T3 < 0 or self.local_steps < 0 \
                or self.check_steps < 0:
            raise ValueError("GASettings need T1 >= 1 and T2, T3, local_steps, check_steps "
                             ">= 0.")
        if not 2 <= self.bits <= 30:
            raise ValueError(f"GASettings.bits must be in 2 … 30; got {self.bits}.")
        if not (np.isfinite(self.beta) and self.beta > 0 and np.isfinite(self.c1)
                and self.c1 > 0):
            raise ValueError("GASettings: beta and c1 must be finite and > 0.")

    @property
    def generations(self) -> int:
        return self.T1 + self.T2


class HybridGA(eqx.Module):
    """A GA plus a local solver: ``local_solver`` is an Optimistix least-squares solver or
    minimiser, a name of `jaxhyst.identify.SOLVERS`, or ``None`` (the plain GA);
    ``placement`` is ``inside`` (GATR1/GALM1) or ``after`` (GATR2/GALM2)."""

    local_solver: object = None
    placement: str = eqx.field(static=True, default="inside")
    name: str = eqx.field(static=True, default="")

    def __init__(self, local_solver=None, placement: str = "inside", name: str = ""):
        if placement not in ("inside", "after"):
            raise ValueError(f"placement must be 'inside' or 'after'; got {placement!r}.")
        self.local_solver = None if local_solver is None else make_solver(local_solver)
        self.placement = placement
        self.name = name or ("GA" if local_solver is None else
                             f"GA+{solver_name(local_solver)} ({placement})")


#: The paper's hybrids and the plain GA, by name (`jaxhyst.names.HYBRID_NAMES`).
HYBRIDS = {
    "GATR1": HybridGA("tra", "inside", "GATR1"),
    "GALM1": HybridGA("lma", "inside", "GALM1"),
    "GATR2": HybridGA("tra", "after", "GATR2"),
    "GALM2": HybridGA("lma", "after", "GALM2"),
    "GA": HybridGA(None, "after", "GA"),
}
assert tuple(HYBRIDS) == HYBRID_NAMES


class GAState(eqx.Module):
    """Everything a generation changes; a checkpoint is this state serialized."""

    key: jax.Array  # PRNG key (uint32, (2,))
    genes: jax.Array  # BCGA population, (q1, n, bits) uint8
    U: jax.Array  # FCGA population in box coordinates, (q2, n)
    generation: jax.Array  # generations completed
    best_u: jax.Array  # (n,)
    best_cost: jax.Array
    evaluations: jax.Array
    failures: jax.Array
    local_steps: jax.Array
    step_size: jax.Array  # the local search's damping (1/h) or radius, carried over
    last_local_u: jax.Array  # (n,) where the last local search converged
    has_last_local: jax.Array  # bool


def initial_state(n: int, settings: GASettings, seed: int, step_size: float) -> GAState:
    key, k0 = jax.random.split(jax.random.PRNGKey(seed))
    genes = jax.random.bernoulli(k0, 0.5, (settings.q1, n, settings.bits)).astype(jnp.uint8)
    # dtypes as the generations return them (none weakly typed): otherwise the second
    # generation would compile its program again
    i64, f64 = jnp.zeros((), jnp.int64), jnp.float64
    return GAState(key=key, genes=genes, U=jnp.zeros((settings.q2, n), f64), generation=i64,
                   best_u=jnp.full((n,), 0.5, f64), best_cost=jnp.asarray(jnp.inf, f64),
                   evaluations=i64, failures=i64, local_steps=i64,
                   step_size=jnp.asarray(float(step_size), f64),
                   last_local_u=jnp.zeros((n,), f64), has_last_local=jnp.asarray(False))


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


class _Knobs(eqx.Module):
    """The settings a generation reads as numbers, traced: a new T1, T2, pc, pm, β or c1
    runs the compiled generation programs again instead of compiling new ones."""

    T1: jax.Array
    T: jax.Array  # T1 + T2
    pc: jax.Array
    pm: jax.Array
    beta: jax.Array
    c1: jax.Array


def _split_settings(settings: GASettings):
    """(the settings that shape a generation's program, static; `_Knobs`, traced). The
    static part has the traced fields (and T3, check_steps, unused by a generation) set
    to fixed values, so that it hashes the same for every value of them."""
    s = settings
    knobs = _Knobs(T1=jnp.asarray(s.T1, jnp.int64), T=jnp.asarray(s.generations, jnp.int64),
                   pc=jnp.asarray(s.pc, float), pm=jnp.asarray(s.pm, float),
                   beta=jnp.asarray(s.beta, float), c1=jnp.asarray(s.c1, float))
    static = dataclasses.replace(s, T1=1, T2=0, T3=0, check_steps=0, pc=0.0, pm=0.0,
                                 beta=1.0, c1=1.0)
    return static, knobs


def _no_local(cost):
    nan = jnp.asarray(jnp.nan)
    return {"local_ran": jnp.asarray(False), "local_skipped": jnp.asarray(False),
            "local_code": jnp.asarray(-1, jnp.int32), "local_steps": jnp.asarray(0, jnp.int64),
            "local_cost_before": cost, "local_cost_after": nan}


def _update_best(state, population, costs):
    best = jnp.argmin(costs)
    better = costs[best] < state.best_cost
    return (jnp.where(better, population[best], state.best_u),
            jnp.where(better, costs[best], state.best_cost))


def bcga_generation(problem: AbstractProblem, method: HybridGA, settings: GASettings,
                    state: GAState):
    """One BCGA generation (i ≤ T1): evaluate the binary population, keep the best,
    reproduce; at i = T1 hand the q2 fittest to the FCGA. Returns (state, record).
    Compiled once per problem, method and population shape (T1, T2, pc, pm, β and c1
    are traced)."""
    return _bcga_generation(problem, method, *_split_settings(settings), state)


@eqx.filter_jit
def _bcga_generation(problem, method, s: GASettings, knobs: _Knobs, state: GAState):
    i = state.generation + 1
    population = decode(state.genes)
    costs = _evaluate(problem, population, s.shard)
    bad = ~jnp.isfinite(costs)
    costs = jnp.where(bad, jnp.inf, costs)
    fitness = problem.fitness_from_cost(costs, knobs.c1)
    best_u, best_cost = _update_best(state, population, costs)
    key, k = jax.random.split(state.key)
    T = knobs.T

    def next_bcga(_):
        genes = bcga_offspring(k, state.genes, fitness, knobs.pc, knobs.pm, elites=s.elites)
        return genes, state.U

    def handover(_):
        top = jnp.argsort(costs, stable=True)[: s.q2]
        U = population[top]
        U = jax.lax.cond(i < T, lambda U: fcga_offspring(k, U, fitness[top], i, T, knobs.pc,
                                                         knobs.pm, knobs.beta, elites=s.elites),
                         lambda U: U, U)
        return state.genes, U

    genes, U = jax.lax.cond(i < knobs.T1, next_bcga, handover, None)
    new = eqx.tree_at(
        lambda st: (st.key, st.genes, st.U, st.generation, st.best_u, st.best_cost,
                    st.evaluations, st.failures),
        state, (key, genes, U, i, best_u, best_cost,
                state.evaluations + population.shape[0], state.failures + jnp.sum(bad)))
    return new, _record(new, costs, fitness, _no_local(jnp.min(costs)))


def fcga_generation(problem: AbstractProblem, method: HybridGA, settings: GASettings,
                    state: GAState):
    """One FCGA generation (i > T1): evaluate, run the local search from the best
    (``inside`` placement), keep the best, reproduce. Returns (state, record). Compiled
    once per problem, method and population shape, as `bcga_generation`."""
    return _fcga_generation(problem, method, *_split_settings(settings), state)


@eqx.filter_jit
def _fcga_generation(problem, method, s: GASettings, knobs: _Knobs, state: GAState):
    i = state.generation + 1
    T = knobs.T
    population = state.U
    costs = _evaluate(problem, population, s.shard)
    bad = ~jnp.isfinite(costs)
    costs = jnp.where(bad, jnp.inf, costs)
    best = jnp.argmin(costs)
    local = _no_local(costs[best])
    step_size, last_u, has_last = state.step_size, state.last_local_u, state.has_last_local
    local_steps = state.local_steps
    if method.local_solver is not None and method.placement == "inside" and s.local_steps:
        unchanged = has_last & jnp.all(population[best] == last_u)

        def search(_):
            solver = with_initial_step_size(method.local_solver, step_size)
            z, code, steps, cost, final = run_local(problem, solver, z_from_u(population[best]),
                                                    s.local_steps)
            return z, code, steps.astype(jnp.int64), cost, jnp.asarray(final, float)

        def skip(_):
            return (z_from_u(population[best]), jnp.asarray(0, jnp.int32),
                    jnp.asarray(0, jnp.int64), costs[best], jnp.asarray(step_size, float))

        z, code, steps, cost, final = jax.lax.cond(unchanged, skip, search, None)
        improved = jnp.isfinite(cost) & (cost <= costs[best]) & ~unchanged
        population = jnp.where(improved, population.at[best].set(u_from_z(z)), population)
        costs = jnp.where(improved, costs.at[best].set(cost), costs)
        if s.carry_over:
            step_size = jnp.where(~unchanged & jnp.isfinite(final) & (final > 0), final,
                                  step_size)
        converged = code == 0
        last_u = jnp.where(unchanged, last_u, population[best])
        has_last = jnp.where(unchanged, has_last, converged)
        local_steps = local_steps + steps
        local = {"local_ran": ~unchanged, "local_skipped": unchanged, "local_code": code,
                 "local_steps": steps, "local_cost_before": local["local_cost_before"],
                 "local_cost_after": cost}
    fitness = problem.fitness_from_cost(costs, knobs.c1)
    best_u, best_cost = _update_best(state, population, costs)
    key, k = jax.random.split(state.key)
    U = jax.lax.cond(i < T, lambda U: fcga_offspring(k, U, fitness, i, T, knobs.pc, knobs.pm,
                                                     knobs.beta, elites=s.elites),
                     lambda U: U, population)
    new = eqx.tree_at(
        lambda st: (st.key, st.U, st.generation, st.best_u, st.best_cost, st.evaluations,
                    st.failures, st.local_steps, st.step_size, st.last_local_u,
                    st.has_last_local),
        state, (key, U, i, best_u, best_cost, state.evaluations + population.shape[0],
                state.failures + jnp.sum(bad), local_steps, step_size, last_u, has_last))
    return new, _record(new, costs, fitness, local)


def _final_solve(problem, solver, z0, max_steps: int, progress: int, label: str):
    """The ``after`` placement's solve or the convergence check, from z0, on the stepped
    driver: its step limit is data (a new T3 or check_steps compiles nothing), it reports
    progress with the run's, and an interruption returns the point reached. Returns
    (z, code, steps, cost, interrupted) as Python values (z an array)."""
    (z, code, steps, cost, _, _), stopped = stepped_solve(
        problem, solver, np.asarray(z0)[None], max_steps, bool(progress), label)
    return z[0], int(code[0]), int(steps[0]), float(cost[0]), stopped


# -- checkpoints -----------------------------------------------------------------------------

def fingerprint(problem: AbstractProblem, method: HybridGA, settings: GASettings,
                seed: int) -> str:
    """A hash of everything a run's result depends on."""
    h = hashlib.sha256()
    for leaf in jax.tree.leaves(problem.observations):
        h.update(np.asarray(leaf, dtype=np.float64).tobytes())
    h.update(np.asarray(problem.space.lower).tobytes() + np.asarray(problem.space.upper).tobytes())
    h.update(np.asarray(problem.space.base).tobytes())
    h.update(repr((solver_name(method.local_solver) if method.local_solver is not None
                   else None, method.placement, dataclasses.astuple(settings), int(seed),
                   problem.space.names, [g.name for g in problem.groups])).encode())
    return h.hexdigest()[:16]


def save_checkpoint(path, state: GAState, history: list, meta: dict) -> None:
    """Write the state, history and meta data (`jaxhyst._files`: atomically for a
    regular file)."""
    arrays = {f.name: np.asarray(getattr(state, f.name)) for f in dataclasses.fields(state)}
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(json.dumps({**meta, "history": history,
                                            "version": CHECKPOINT_VERSION})), **arrays)
    write_bytes(path, buf.getvalue())


def load_checkpoint(path, template: GAState) -> tuple[GAState, list, dict]:
    """Read a checkpoint written by `save_checkpoint`, checking every array against
    ``template`` (never unpickling). Raises `CheckpointError` with one line."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise CheckpointError(f"checkpoint {path} does not exist; run without resume to "
                              "start a new run.")
    if os.path.isdir(path):
        raise CheckpointError(f"checkpoint {path} is a directory; give a file.")
    try:
        with np.load(path, allow_pickle=False) as z:
            files = set(z.files)
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in files if k != "meta"}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile,
            json.JSONDecodeError) as err:
        raise CheckpointError(f"checkpoint {path} is not a readable jaxhyst checkpoint "
                              f"({type(err).__name__}: {' '.join(str(err).split())[:120]}); "
                              "delete it or run without resume.") from None
    if not isinstance(meta, dict) or meta.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"checkpoint {path} was written by another jaxhyst version; "
                              "delete it or run without resume.")
    values = {}
    for f in dataclasses.fields(template):
        ref = np.asarray(getattr(template, f.name))
        a = arrays.get(f.name)
        if a is None or a.shape != ref.shape or a.dtype != ref.dtype:
            raise CheckpointError(f"checkpoint {path} does not match this run (entry "
                                  f"{f.name!r}); delete it or run without resume.")
        values[f.name] = jnp.asarray(a)
    history = meta.pop("history", [])
    if not isinstance(history, list):
        raise CheckpointError(f"checkpoint {path} has a malformed history.")
    return GAState(**values), history, meta


# -- the driver --------------------------------------------------------------------------

def _history_entry(i, phase, rec, names, lower, upper, elapsed):
    r = {k: np.asarray(v) for k, v in rec.items()}
    best_u = r["best_u"].astype(float)
    entry = {"generation": int(i), "phase": phase, "best_fitness": float(r["best_fitness"]),
             "mean_fitness": float(r["mean_fitness"]), "best_cost": float(r["best_cost"]),
             "best_u": best_u.tolist(),
             "best_values": (lower + (upper - lower) * best_u).tolist(),
             "evaluations": int(r["evaluations"]), "failures": int(r["failures"]),
             "elapsed": elapsed, "local": None}
    if bool(r["local_ran"]) or bool(r["local_skipped"]):
        entry["local"] = {
            "result": "skipped (best unchanged)" if bool(r["local_skipped"])
            else CODES[int(r["local_code"])].value,
            "steps": int(r["local_steps"]), "cost_before": float(r["local_cost_before"]),
            "cost_after": float(r["local_cost_after"])}
    return entry


def run_hybrid(problem: AbstractProblem, method: str | HybridGA = "GATR1", seed: int = 0,
               settings: GASettings | None = None, *, progress: bool | int = False,
               checkpoint: str | os.PathLike | None = None, checkpoint_every: int = 10,
               resume: bool = False, stop_after: int | None = None,
               shard: bool | None = None) -> IdentificationResult:
    """Identify ``problem`` with a hybrid GA.

    **Arguments:**
    - ``method``: ``GATR1``, ``GALM1``, ``GATR2``, ``GALM2``, ``GA`` or a `HybridGA`.
    - ``seed``: everything random derives from ``jax.random.PRNGKey(seed)``; the same seed
      on the same machine gives the identical result (also across a resume).
    - ``settings``: `GASettings` (paper defaults).
    - ``progress``: print a line to stderr every ``progress`` generations (True = 10),
      what is being compiled before the first generation, and the final local solve's
      and the convergence check's steps every 2 s.
    - ``checkpoint``: path of an ``.npz`` written atomically every ``checkpoint_every``
      generations and on interruption; ``resume=True`` continues from it (it must exist
      and belong to the same problem, method, settings and seed).
    - ``stop_after``: stop after this many generations, as if interrupted.
    - ``shard``: overrides ``settings.shard`` (split each generation's population over
      all devices when it divides evenly; results are the same either way).

    The first Ctrl-C (or SIGTERM) stops at the end of the current generation (in the
    ``after`` placement's solve or the convergence check: after the current chunk of
    steps) and returns the best so far (outcome ``interrupted``); a second one stops at
    once.

    **Returns:** an `IdentificationResult` whose ``extra`` holds ``history`` (one dict
    per generation), ``evaluations``, ``failures``, ``local_steps``, ``after`` (the
    ``after`` placement's solve) and ``convergence_check``.
    """
    if isinstance(method, str):
        if method not in HYBRIDS:
            raise ValueError(f"Unknown method {method!r}; choose one of {list(HYBRIDS)}.")
        method = HYBRIDS[method]
    if not isinstance(method, HybridGA):
        raise TypeError(f"method must be a name or a HybridGA; got {type(method).__name__}.")
    s = settings or GASettings()
    if shard is not None:
        s = dataclasses.replace(s, shard=bool(shard))
    label = method.name
    every = 10 if progress is True else int(progress or 0)
    n = problem.space.n_free
    names = problem.space.names
    lower, upper = np.asarray(problem.space.lower), np.asarray(problem.space.upper)
    start_step = initial_step_size(method.local_solver) if method.local_solver is not None \
        else 1.0
    template = initial_state(n, s, seed, start_step)
    fp = fingerprint(problem, method, s, seed)
    if resume:
        if checkpoint is None:
            raise ValueError("resume=True needs a checkpoint path.")
        state, history, meta = load_checkpoint(checkpoint, template)
        if meta.get("fingerprint") != fp:
            raise CheckpointError(f"checkpoint {checkpoint} belongs to another run (problem, "
                                  "method, settings or seed differ); delete it or run "
                                  "without resume.")
        elapsed0 = float(meta.get("elapsed", 0.0))
    else:
        state, history, elapsed0 = template, [], 0.0
    T = s.generations

    def save(state, history):
        if checkpoint is not None:
            save_checkpoint(checkpoint, state, history,
                            {"fingerprint": fp, "elapsed": elapsed0 + time.perf_counter() - t0})

    def say(text):
        print(f"[{label}] {text}", file=sys.stderr, flush=True)

    def stopped_in(where):  # an interruption: the state reached goes to the checkpoint
        save(state, history)
        if every:
            say(f"interrupted {where}; returning the best so far"
                + (f" (checkpoint {checkpoint})" if checkpoint else ""))

    t0 = time.perf_counter()
    interrupted = False
    with interruptible() as stop:
        if every and int(state.generation) < T:
            say("compiling the generation step (the first call takes a while) …")
        while int(state.generation) < T:
            i = int(state.generation) + 1
            phase = "BCGA" if i <= s.T1 else "FCGA"
            step = bcga_generation if i <= s.T1 else fcga_generation
            state, rec = step(problem, method, s, state)
            history.append(_history_entry(i, phase, rec, names, lower, upper,
                                          elapsed0 + time.perf_counter() - t0))
            h = history[-1]
            if every and (i % every == 0 or i == T or i == 1):
                say(f"generation {i}/{T} {phase}: best cost {h['best_cost']:.3e}, "
                    f"{h['evaluations']} evaluations, {h['elapsed']:.1f} s")
            if checkpoint is not None and checkpoint_every and i % checkpoint_every == 0:
                save(state, history)
            if stop() or (stop_after is not None and len(history) >= stop_after and i < T):
                interrupted = True
                break
        if interrupted:
            stopped_in(f"after generation {int(state.generation)}")
        best_u = state.best_u
        z_best = z_from_u(best_u)
        local_steps = int(state.local_steps)
        after_info = check_info = None
        outcome = Outcome.interrupted if interrupted else Outcome.successful
        if not interrupted and method.local_solver is not None and \
                method.placement == "after" and s.T3 > 0:
            if every:
                say(f"local search ({solver_name(method.local_solver)}, up to {s.T3} steps) …")
            solver = with_initial_step_size(method.local_solver, start_step)
            z, code, lsteps, cost, stopped = _final_solve(problem, solver, z_best, s.T3,
                                                          every, f"{label} local")
            local_steps += lsteps
            after_info = {"result": (Outcome.interrupted if stopped else CODES[code]).value,
                          "steps": lsteps, "cost_before": float(state.best_cost),
                          "cost_after": cost}
            if np.isfinite(cost) and cost <= float(state.best_cost):
                z_best = z
            if stopped:  # the GA itself is complete: a resume starts at this solve
                interrupted, outcome = True, Outcome.interrupted
                stopped_in("in the local search")
        if not interrupted and s.check_steps and not stop():
            checker = make_solver("lm")
            if every:
                say(f"convergence check ({solver_name(checker)}, up to {s.check_steps} "
                    "steps) …")
            before = float(_cost_at(problem, z_best))
            z, code, csteps, cost, stopped = _final_solve(problem, checker, z_best,
                                                          s.check_steps, every, f"{label} check")
            outcome = Outcome.interrupted if stopped else CODES[code]
            check_info = {"result": outcome.value, "steps": csteps,
                          "cost_before": before, "cost_after": cost}
            if np.isfinite(cost) and cost < before:
                z_best = z
            if stopped:
                stopped_in("in the convergence check")
        elif not interrupted and s.check_steps:  # stopped before the check began
            interrupted, outcome = True, Outcome.interrupted
            stopped_in("before the convergence check")
        elif not interrupted:  # no convergence test: the run only reached its limit
            outcome = (Outcome(after_info["result"]) if after_info is not None
                       else Outcome.max_steps_reached)
    wall = elapsed0 + time.perf_counter() - t0
    result = summarize(problem, z_best, len(history), outcome, label, wall,
                       extra={"history": history, "evaluations": int(state.evaluations),
                              "failures": int(state.failures), "local_steps": local_steps,
                              "after": after_info, "convergence_check": check_info,
                              "seed": seed})
    if every and not interrupted:
        say(f"done: {result.result}, cost {result.cost:.3e}, {wall:.1f} s")
    return result


@eqx.filter_jit
def _cost_at(problem, z):
    return problem.cost(z)
