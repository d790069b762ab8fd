"""The paper's hybrid genetic algorithms (§3.4) and the one driver that runs them.

A hybrid is the hybrid-coded GA (BCGA for T1 generations, then FCGA) composed with a
local solver, the way Optimistix composes a descent with a search:

| method  | local solver | placement                                              |
|---------|--------------|--------------------------------------------------------|
| GATR1   | ``tra``      | ``inside``: every FCGA generation, from the best       |
| GALM1   | ``lma``      | ``inside``                                             |
| GATR2   | ``tra``      | ``after``: T3 iterations from the FCGA's best          |
| GALM2   | ``lma``      | ``after``                                              |

Any solver of `jaxhyst.identify.SOLVERS` can be plugged in (``HybridGA("lm", "inside")``),
and ``HybridGA(None, "after")`` is the plain GA.

Choices (documented in docs/identification.md):
- BCGA → FCGA: the q2 fittest of the last BCGA generation are the FCGA's first parents.
- Inside the FCGA, the local search runs ``local_steps`` Optimistix steps (default 5) from
  the best individual after each evaluation; its result replaces that individual, so it
  passes on as an elite. By default (``carry_over=True``) the LMA damping / TRA radius it
  ended with is where the next generation's local search starts: with a restart at
  h1 = 0.01 the LMA spends its few steps re-growing h and GALM1 stalls (measured: cost
  ~2e-9 after 300 generations, against < 1e-20 with carry-over). The carried value is
  part of the checkpoint, so resume stays exact.
- Fitness F = 1/√(c1 + E) (eq 35) with E in SI units; non-finite simulations get F = 0.

The driver is a thin Python loop around jitted pieces (population evaluation in one vmapped
batch, reproduction, local solve): it reports progress, records a history per generation,
checkpoints atomically every N generations, resumes to the identical result, and on Ctrl-C
returns the best individual so far.
"""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import sys
import time
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..sharding import batch_sharding, place
from .ga import bcga_offspring, decode, fcga_offspring
from .local import SOLVERS, _result_name, _run_jit, make_solver, summarize
from .paper_solvers import with_initial_step_size
from .problem import Problem, u_from_z, z_from_u
from .result import IdentificationResult


@dataclass(frozen=True)
class GASettings:
    """The paper's GA settings (§4): population sizes q1 (BCGA) and q2 (FCGA), crossover
    and mutation probabilities, bits per parameter, generations T1 (BCGA) and T2 (FCGA),
    local iterations T3 (``after`` placement), non-uniform mutation β, elites, local
    steps per FCGA generation (``inside`` placement), whether the LMA damping / TRA radius
    carries over from one generation's local search to the next (``carry_over``), and c1
    of the fitness."""

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

    def __post_init__(self):
        if self.q1 < self.q2 or self.q2 < self.elites + 2:
            raise ValueError("Need q1 >= q2 >= elites + 2 (population sizes).")
        if not (0 <= self.pc <= 1 and 0 <= self.pm <= 1):
            raise ValueError("pc and pm are probabilities in [0, 1].")
        if self.T1 < 1 or self.T2 < 0 or self.T3 < 0 or self.bits < 2:
            raise ValueError("Need T1 >= 1, T2 >= 0, T3 >= 0 and bits >= 2.")


class HybridGA(eqx.Module):
    """A GA plus a local solver. ``placement``: ``inside`` (GATR1/GALM1) or ``after``
    (GATR2/GALM2)."""

    local_solver: str | None = eqx.field(static=True)
    placement: str = eqx.field(static=True, default="inside")
    name: str = eqx.field(static=True, default="")

    def __check_init__(self):
        if self.local_solver is not None and self.local_solver not in SOLVERS:
            raise ValueError(f"Unknown local solver {self.local_solver!r}; use one of {SOLVERS}.")
        if self.placement not in ("inside", "after"):
            raise ValueError("placement must be 'inside' or 'after'.")


HYBRIDS = {
    "GATR1": HybridGA("tra", "inside", "GATR1"),
    "GALM1": HybridGA("lma", "inside", "GALM1"),
    "GATR2": HybridGA("tra", "after", "GATR2"),
    "GALM2": HybridGA("lma", "after", "GALM2"),
    "GA": HybridGA(None, "after", "GA"),
}


@eqx.filter_jit
def _evaluate(problem: Problem, U):
    return jax.vmap(problem.cost_u)(U)


_bcga_step = jax.jit(bcga_offspring, static_argnames="elites")
_fcga_step = jax.jit(fcga_offspring, static_argnames="elites")
# The per-generation bookkeeping, compiled: run op by op, θ(u) for the history, the
# fitness and the key split cost ~2 ms a generation (a 100-generation GA on Table 1, whose
# population evaluations take 6–13 ms each, went 1.03 → 0.81 s).
_fitness = eqx.filter_jit(lambda problem, costs, c1: problem.fitness_from_cost(costs, c1))
_theta = eqx.filter_jit(lambda space, u: space.theta_from_u(u))
_split = jax.jit(jax.random.split)
_decode = jax.jit(decode)


def _fingerprint(problem: Problem, method: HybridGA, settings: GASettings, seed: int) -> str:
    h = hashlib.sha256()
    h.update(np.asarray(problem.data).tobytes())
    h.update(np.asarray(problem.space.lower).tobytes() + np.asarray(problem.space.upper).tobytes())
    h.update(repr((method.local_solver, method.placement, dataclasses.astuple(settings), seed,
                   problem.space.free, problem.output)).encode())
    return h.hexdigest()[:16]


def _atomic_save(path, arrays: dict, meta: dict) -> None:
    path = os.fspath(path)
    os.makedirs(os.path.dirname(os.path.abspath(path)), exist_ok=True)
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(json.dumps(meta)), **arrays)
    tmp = f"{path}.tmp{os.getpid()}"
    with open(tmp, "wb") as fh:
        fh.write(buf.getvalue())
        fh.flush()
        os.fsync(fh.fileno())
    os.replace(tmp, path)


def _load(path):
    with np.load(path, allow_pickle=False) as z:
        meta = json.loads(str(z["meta"]))
        arrays = {k: z[k] for k in z.files if k != "meta"}
    return arrays, meta


def run_hybrid(problem: Problem, method: str | HybridGA = "GATR1", seed: int = 0,
               settings: GASettings | None = None, *, progress: bool | int = False,
               checkpoint: str | os.PathLike | None = None, checkpoint_every: int = 10,
               resume: bool = False, stop_after: int | None = None, report: bool = True,
               shard: bool | None = None) -> IdentificationResult:
    """Identify ``problem`` with a hybrid GA.

    **Arguments:**
    - ``method``: ``GATR1``, ``GALM1``, ``GATR2``, ``GALM2``, ``GA`` or a `HybridGA`.
    - ``seed``: everything random derives from ``jax.random.PRNGKey(seed)``; the same seed
      on the same machine gives the identical result.
    - ``settings``: `GASettings` (paper defaults).
    - ``progress``: print a line to stderr every ``progress`` generations (True = 10).
    - ``checkpoint``: path of an ``.npz`` written atomically every ``checkpoint_every``
      generations and on interruption; ``resume=True`` continues from it (refused if it
      belongs to another problem, method, settings or seed).
    - ``stop_after``: stop after this many generations, as if interrupted (for tests and
      for splitting long runs).
    - ``report``: attach the identifiability report at the result (one jacfwd).
    - ``shard``: spread each population evaluation over all devices (`jaxhyst.sharding`);
      ``None`` (default) does so whenever there are several devices and the population
      size is divisible by their number.

    **Returns:** an `IdentificationResult` whose ``extra`` holds ``history`` (one dict per
    generation: best/mean fitness, best cost and parameters, cumulative evaluations and
    failed evaluations, local-search outcome, elapsed seconds), ``evaluations``,
    ``failures`` and ``local_steps``. ``result`` is ``successful`` or ``interrupted``.
    """
    if isinstance(method, str):
        if method not in HYBRIDS:
            raise ValueError(f"Unknown method {method!r}; choose one of {list(HYBRIDS)}.")
        method = HYBRIDS[method]
    s = settings or GASettings()
    every = 10 if progress is True else int(progress or 0)
    T = s.T1 + s.T2
    n = problem.space.n_free
    fingerprint = _fingerprint(problem, method, s, seed)
    local = make_solver(method.local_solver) if method.local_solver else None
    # initial damping 1/h1 = 100 (LMA) or radius Δ1 = 1 (TRA); carried over if requested
    initial_step_size = 100.0 if method.local_solver == "lma" else 1.0
    local_step_size = initial_step_size

    # -- state ------------------------------------------------------------------------------
    last_local_u = None  # where the last local solve converged (see the skip below)
    if resume and checkpoint is not None and os.path.exists(checkpoint):
        arrays, meta = _load(checkpoint)
        if meta["fingerprint"] != fingerprint:
            raise ValueError(
                f"Checkpoint {checkpoint} belongs to another run (problem, method, settings "
                "or seed differ); delete it or run without resume."
            )
        generation, history = meta["generation"], meta["history"]
        evaluations, failures, local_steps = (meta["evaluations"], meta["failures"],
                                              meta["local_steps"])
        key = jnp.asarray(arrays["key"], dtype=jnp.uint32)
        genes = jnp.asarray(arrays["genes"]) if "genes" in arrays else None
        U = jnp.asarray(arrays["U"]) if "U" in arrays else None
        elapsed0 = meta["elapsed"]
        local_step_size = meta.get("local_step_size", local_step_size)
        if "last_local_u" in arrays:
            last_local_u = np.asarray(arrays["last_local_u"])
    else:
        key, k0 = jax.random.split(jax.random.PRNGKey(seed))
        genes = jax.random.bernoulli(k0, 0.5, (s.q1, n, s.bits)).astype(jnp.uint8)
        U = None
        generation, history = 0, []
        evaluations = failures = local_steps = 0
        elapsed0 = 0.0

    def snapshot():
        """The state at a generation boundary: what a checkpoint holds. (An interrupt can
        land mid-generation; checkpointing only snapshots keeps resume exact.)"""
        return dict(key=key, genes=genes, U=U, generation=generation, n_history=len(history),
                    evaluations=evaluations, failures=failures, local_steps=local_steps,
                    local_step_size=local_step_size, last_local_u=last_local_u,
                    elapsed=elapsed0 + time.perf_counter() - t_start)

    def save(snap):
        if checkpoint is None:
            return
        arrays = {"key": np.asarray(snap["key"])}
        for name in ("genes", "U", "last_local_u"):
            if snap[name] is not None:
                arrays[name] = np.asarray(snap[name])
        meta = {k: snap[k] for k in ("generation", "evaluations", "failures", "local_steps",
                                      "local_step_size", "elapsed")}
        meta.update(fingerprint=fingerprint, history=history[: snap["n_history"]])
        _atomic_save(checkpoint, arrays, meta)

    t_start = time.perf_counter()
    committed = snapshot()
    interrupted = False
    best_u, best_cost = None, np.inf
    if history:
        best_cost = history[-1]["best_cost"]
        best_u = np.asarray(history[-1]["best_u"])
    try:
        while generation < T:
            i = generation + 1  # the paper's 1-based generation index
            population = _decode(genes) if i <= s.T1 else U
            costs = np.asarray(_evaluate(problem, place(population, batch_sharding(
                population.shape[0], shard))))
            evaluations += population.shape[0]
            bad = ~np.isfinite(costs)
            failures += int(bad.sum())
            costs = np.where(bad, np.inf, costs)
            best = int(np.argmin(costs))
            local_info = None
            # The best is still the point where the last local solve *converged*: a restart
            # from it would stop at once, so skip it. (A solve that stopped at
            # local_steps is continued, from where it stopped, in the next generation.)
            unchanged = last_local_u is not None and np.array_equal(
                np.asarray(population[best]), last_local_u)
            if unchanged:
                local_info = {"result": "skipped (best unchanged)", "steps": 0,
                              "cost_before": float(costs[best]), "cost_after": float(costs[best])}
            elif local is not None and method.placement == "inside" and i > s.T1:
                solver = with_initial_step_size(local, local_step_size)
                z, code, steps, cost, final_step = _run_jit(
                    problem, solver, z_from_u(population[best]), s.local_steps)
                steps, cost = int(steps), float(cost)
                if s.carry_over and np.isfinite(float(final_step)) and float(final_step) > 0:
                    local_step_size = float(final_step)
                local_steps += steps
                local_info = {"result": _result_name(code), "steps": steps,
                              "cost_before": float(costs[best]), "cost_after": cost}
                if np.isfinite(cost) and cost <= costs[best]:
                    population = population.at[best].set(u_from_z(z))
                    costs[best] = cost
                converged = local_info["result"] == "successful"
                last_local_u = np.asarray(population[best]) if converged else None
            fitness = np.asarray(_fitness(problem, jnp.asarray(costs), s.c1))
            if costs[best] < best_cost:
                best_cost, best_u = float(costs[best]), np.asarray(population[best])
            finite = fitness[np.isfinite(costs)]
            history.append({
                "generation": i, "phase": "BCGA" if i <= s.T1 else "FCGA",
                "best_fitness": float(fitness.max()),
                "mean_fitness": float(finite.mean()) if finite.size else 0.0,
                "best_cost": best_cost, "best_u": best_u.tolist(),
                "best_params": _theta(problem.space, jnp.asarray(best_u)).tolist(),
                "evaluations": evaluations, "failures": failures, "local": local_info,
                "elapsed": elapsed0 + time.perf_counter() - t_start,
            })  # fmt: skip
            key, k = _split(key)
            fit = jnp.asarray(fitness)
            if i < s.T1:
                genes = _bcga_step(k, genes, fit, s.pc, s.pm, elites=s.elites)
            elif i < T:
                if i == s.T1:  # hand over the q2 fittest to the FCGA
                    top = np.argsort(costs, kind="stable")[: s.q2]
                    population, fit = population[top], fit[top]
                    genes = None
                U = _fcga_step(k, population, fit, i, T, s.pc, s.pm, s.beta, elites=s.elites)
            generation = i
            committed = snapshot()
            if every and (i % every == 0 or i == T):
                print(f"[{method.name or 'hybrid'}] generation {i}/{T} {history[-1]['phase']}: "
                      f"best cost {best_cost:.3e}, best F {history[-1]['best_fitness']:.4g}, "
                      f"{evaluations} evaluations, {history[-1]['elapsed']:.1f} s",
                      file=sys.stderr, flush=True)
            if checkpoint is not None and checkpoint_every and i % checkpoint_every == 0:
                save(committed)
            if stop_after is not None and len(history) >= stop_after and generation < T:
                interrupted = True
                break
    except KeyboardInterrupt:
        interrupted = True
        print(f"[{method.name or 'hybrid'}] interrupted after generation {generation}; "
              "returning the best so far", file=sys.stderr, flush=True)
    if interrupted:
        save(committed)
        generation = committed["generation"]
        del history[committed["n_history"]:]

    z_best = z_from_u(jnp.asarray(best_u))
    steps, code = generation, 0
    after_info = None
    if not interrupted and local is not None and method.placement == "after" and s.T3 > 0:
        solver = with_initial_step_size(local, initial_step_size)
        z, code, lsteps, cost, _ = _run_jit(problem, solver, z_best, s.T3)
        local_steps += int(lsteps)
        after_info = {"result": _result_name(code), "steps": int(lsteps),
                      "cost_before": best_cost, "cost_after": float(cost)}
        if np.isfinite(float(cost)) and float(cost) <= best_cost:
            z_best = z
        code = 0
    wall = elapsed0 + time.perf_counter() - t_start
    result = summarize(problem, z_best, steps, code, method.name or repr(method), wall,
                       extra={"history": history, "evaluations": evaluations,
                              "failures": failures, "local_steps": local_steps,
                              "after": after_info, "seed": seed}, report=report)
    if interrupted:
        result.result = "interrupted"
    return result
