"""The paper's simulation study (Table 1), as a function the CLI and benchmarks share.

Noise-free displacement data of the Table 1 actuator (Actuator1, I = 0.77·sin(200πt) +
1.53 A, Table 1 truth), all ten parameters free in the Table 1 box, identified by the four
hybrids. Because three directions of the ten are not identifiable from displacement
(docs/theory.md), the table reports, next to the raw parameters (the paper's layout), the
error of the seven identifiable combinations, which is what the data can recover.
"""

from __future__ import annotations

import sys
import time

from .actuator import ACTUATOR1
from .drive import sinusoidal_current
from .identify.hybrid import GASettings, run_hybrid
from .identify.problem import synthetic_problem
from .params import NAMES, TABLE1_BOUNDS, TABLE1_TRUE

METHODS = ("GATR1", "GALM1", "GATR2", "GALM2")

#: ``--quick``: a smaller GA on a coarser record (about a minute on 2 cores, compilation
#: included); the paper's settings otherwise.
QUICK = GASettings(q1=60, q2=20, T1=3, T2=40, T3=20, local_steps=4)


def combination_errors(params, truth=TABLE1_TRUE) -> float:
    """Largest relative error of the seven identifiable combinations (α̃·Ms, a, k, c,
    λs·E/Mz, Kz/Mz, Cz/Mz: the basis the identifiability report names)."""
    p, q = params.to_dict(), truth.to_dict()

    def combos(d):
        return [d["alpha"] * d["Ms"], d["a"], d["k"], d["c"], d["lambda_s"] * d["E"] / d["Mz"],
                d["Kz"] / d["Mz"], d["Cz"] / d["Mz"]]

    return max(abs(a / b - 1) for a, b in zip(combos(p), combos(q), strict=True))


def table1_study(quick: bool = False, methods=METHODS, seeds=(0,), progress: bool = False,
                 settings: GASettings | None = None) -> dict:
    """Run the study; returns ``{"settings", "runs": [...], "markdown"}`` where each run has
    the method, seed, identified parameters, cost, combination error, wall time and GA
    history (for the figures)."""
    spp = 50 if quick else 200
    settings = settings or (QUICK if quick else GASettings())
    drive = sinusoidal_current(100.0, 0.77, 1.53, ACTUATOR1, samples_per_period=spp)
    problem = synthetic_problem(TABLE1_TRUE, drive, ACTUATOR1, TABLE1_BOUNDS)
    runs = []
    for method in methods:
        for seed in seeds:
            t0 = time.perf_counter()
            res = run_hybrid(problem, method, seed=seed, settings=settings,
                             progress=10 if progress else False, report=False)
            wall = time.perf_counter() - t0
            runs.append({"method": method, "seed": seed, "params": res.params.to_dict(),
                         "cost": res.cost, "max_abs_error_m": res.max_abs_error,
                         "combination_error": combination_errors(res.params),
                         "wall_time_s": wall, "evaluations": res.extra["evaluations"],
                         "local_steps": res.extra["local_steps"],
                         "history": res.extra["history"]})
            if progress:
                print(f"[table1] {method} seed {seed}: cost {res.cost:.3e}, combinations "
                      f"{runs[-1]['combination_error']:.1e}, {wall:.1f} s", file=sys.stderr,
                      flush=True)
    truth = TABLE1_TRUE.to_dict()
    head = "| θ | true | " + " | ".join(f"{r['method']} s{r['seed']}" for r in runs) + " |"
    lines = [head, "|" + "---|" * (len(runs) + 2)]
    for n in NAMES:
        lines.append(f"| {n} | {truth[n]:.5g} | "
                     + " | ".join(f"{r['params'][n]:.5g}" for r in runs) + " |")
    for label, key, fmt in (("normalised cost", "cost", "{:.1e}"),
                            ("max rel. error, 7 identifiable combinations",
                             "combination_error", "{:.1e}"),
                            ("max abs error (m)", "max_abs_error_m", "{:.2e}"),
                            ("wall time (s)", "wall_time_s", "{:.1f}")):
        lines.append(f"| {label} | | " + " | ".join(fmt.format(r[key]) for r in runs) + " |")
    return {"settings": settings.__dict__, "samples_per_period": spp, "runs": runs,
            "markdown": "\n".join(lines), "problem": problem}
