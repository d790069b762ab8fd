"""`run_hybrid`: a `HybridGA` driven generation by generation by the one driver, with its
history, checkpoints and final solves."""

from __future__ import annotations

import os
import time

import numpy as np

from .._driver import DONE, drive
from ..progress import progress_meter
from .checkpoint import CheckpointError, fingerprint, load_checkpoint, save_checkpoint
from .hybrid import HYBRIDS, GAState, HybridGA, best_z
from .local import finished
from .problem import AbstractProblem, check_problem
from .result import RESULTS, IdentificationResult, outcome_name
from .summary import summarize


def hybrid_method(method: str | HybridGA, settings: dict | None = None) -> HybridGA:
    """The `HybridGA` for a name of `HYBRIDS` (or a `HybridGA`), with ``settings``
    ({name: value}) changed."""
    if isinstance(method, str):
        if method not in HYBRIDS:
            raise ValueError(f"Unknown method {method!r}; choose one of {list(HYBRIDS)}.")
        method = HYBRIDS[method]
    if not isinstance(method, HybridGA):
        raise TypeError(f"method must be a name or a HybridGA; got {type(method).__name__}.")
    return method.replace(**settings) if settings else method


class _History:
    """A run's bookkeeping on the host: one dict per generation, the checkpoint, the
    elapsed time (carried across a resume)."""

    def __init__(self, problem, method: HybridGA, seed: int, checkpoint, resume: bool):
        self.problem, self.method, self.checkpoint = problem, method, checkpoint
        self.fingerprint = fingerprint(problem, method, seed)
        self.state, self.entries, self.elapsed0 = method.init(problem, seed), [], 0.0
        if resume:
            if checkpoint is None:
                raise ValueError("resume=True needs a checkpoint path.")
            self.state, self.entries, meta = load_checkpoint(checkpoint, self.state)
            if meta.get("fingerprint") != self.fingerprint:
                raise CheckpointError(f"checkpoint {checkpoint} belongs to another run "
                                      "(problem, method, settings or seed differ); delete it "
                                      "or run without resume.")
            self.elapsed0 = float(meta.get("elapsed", 0.0))
        self.t0 = time.perf_counter()

    def elapsed(self) -> float:
        return self.elapsed0 + time.perf_counter() - self.t0

    def advance(self, state: GAState) -> GAState:
        phase = "BCGA" if int(state.generation) < int(self.method.T1) else "FCGA"
        state, record = self.method.step(self.problem, state)
        self.entries.append(_entry(int(state.generation), phase, record, self.problem.space,
                                   self.elapsed()))
        return state

    def describe(self, state: GAState) -> tuple[int, str]:
        h = self.entries[-1]
        return h["generation"], (f"generation {h['generation']}/{self.method.generations} "
                                 f"{h['phase']}: best cost {h['best_cost']:.3e}, "
                                 f"{h['evaluations']} evaluations")

    def save(self, state: GAState) -> None:
        save_checkpoint(self.checkpoint, state, self.entries,
                        {"fingerprint": self.fingerprint, "elapsed": self.elapsed()})


def _entry(i, phase, record, space, elapsed) -> dict:
    r = {k: np.asarray(v) for k, v in record.items() if k != "local_result"}
    best_u = r["best_u"].astype(float)
    lower, upper = np.asarray(space.lower), np.asarray(space.upper)
    entry = {"generation": i, "phase": phase, "best_fitness": float(r["best_fitness"]),
             "mean_fitness": float(r["mean_fitness"]), "best_cost": float(r["best_cost"]),
             "best_u": best_u.tolist(), "best_values": (lower + (upper - lower) * best_u).tolist(),
             "evaluations": int(r["evaluations"]), "failures": int(r["failures"]),
             "elapsed": elapsed, "local": None}
    if bool(r["local_ran"]) or bool(r["local_skipped"]):
        entry["local"] = {
            "result": "skipped (best unchanged)" if bool(r["local_skipped"])
            else outcome_name(record["local_result"]),
            "steps": int(r["local_steps"]), "cost_before": float(r["local_cost_before"]),
            "cost_after": float(r["local_cost_after"])}
    return entry


def _where(info: dict) -> str:
    """Where the final solves of a run were interrupted, in words."""
    if info["convergence_check"] is not None:
        return "in the convergence check"
    if info["after"] is not None and info["after"]["result"] == "interrupted":
        return "in the local search"
    return "before the convergence check"


def run_hybrid(problem: AbstractProblem, method: str | HybridGA = "GATR1", seed: int = 0,
               settings: dict | None = None, *, progress=False,
               checkpoint: str | os.PathLike | None = None, checkpoint_every: int = 10,
               resume: bool = False, stop_after: int | None = None) -> IdentificationResult:
    """Identify ``problem`` with a hybrid GA.

    **Arguments:**
    - ``method``: ``GATR1``, ``GALM1``, ``GATR2``, ``GALM2``, ``GA`` or a `HybridGA`;
      ``settings``: {name: value} of its settings to change (``{"T2": 50}``).
    - ``seed``: everything random derives from ``jax.random.PRNGKey(seed)``; the same seed
      on the same machine gives the identical result (also across a resume).
    - ``progress``: a meter (`jaxhyst.progress`), True (a line on stderr every 10
      generations) or n (every n generations); silent by default.
    - ``checkpoint``: path of an ``.npz`` written every ``checkpoint_every`` generations
      and on interruption; ``resume=True`` continues from it (it must exist and belong to
      the same problem, method, settings and seed).
    - ``stop_after``: stop once this many generations are complete, as if interrupted.

    A stop request (the command line's Ctrl-C) returns the best point so far (outcome
    ``interrupted``); Ctrl-C in Python raises `jaxhyst.Interrupted` carrying it. Either
    way the checkpoint is written.

    **Returns:** an `IdentificationResult` whose ``extra`` holds ``history`` (one dict
    per generation), ``evaluations``, ``failures``, ``local_steps``, ``after`` (the
    ``after`` placement's solve), ``convergence_check`` and ``seed``.
    """
    method = hybrid_method(method, settings)
    meter = progress_meter(progress, every=10)
    check_problem(problem)
    run = _History(problem, method, seed, checkpoint, resume)
    meter_state = meter.init(method.name, method.generations)
    state, how, meter_state = drive(
        run.state, advance=run.advance, done=method.terminate, describe=run.describe,
        meter=meter, meter_state=meter_state, save=run.save if checkpoint else None,
        save_every=checkpoint_every, stop_after=stop_after)
    if how == DONE:
        z, outcome, info, how = method.postprocess(problem, state, meter)
        if how != DONE and checkpoint:  # the GA is complete: a resume starts the solves
            run.save(state)
        where = _where(info)
    else:
        z, outcome, where = best_z(state), RESULTS.interrupted, \
            f"after generation {int(state.generation)}"
        info = {"after": None, "convergence_check": None, "local_steps": 0}
    result = summarize(problem, z, len(run.entries), outcome, method.name, run.elapsed(),
                       extra={"history": run.entries, "evaluations": int(state.evaluations),
                              "failures": int(state.failures),
                              "local_steps": int(state.local_steps) + info["local_steps"],
                              "after": info["after"],
                              "convergence_check": info["convergence_check"], "seed": seed})
    saved = f" (checkpoint {checkpoint})" if checkpoint else ""
    meter.close(meter_state, f"done: {result.result}, cost {result.cost:.3e}" if how == DONE
                else f"interrupted {where}; returning the best so far{saved}")
    return finished(result, how)
