"""The paper's simulation study (Table 1): I = 0.77·sin(200πt) + 1.53 A, Table 1 truth and
ranges, Actuator1 constants, noise-free displacement data at 200 samples per period
(¼-period ramp from H = 0 and one run-in period, then one observed period).

Runs GATR1, GALM1, GATR2, GALM2 with the paper's settings over several seeds, plus two
peers on the same problem: vmapped multi-start LM alone (16 starts) and SciPy
differential_evolution (population evaluated in one vmapped batch, same evaluation
budget as the GA) polished by least_squares(trf) with the jacfwd Jacobian.

    python benchmarks/paper_table1.py                 # paper settings, seeds 0 1 2
    python benchmarks/paper_table1.py --quick         # T2 = 45, T3 = 100, one seed
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--methods", default="GATR1,GALM1,GATR2,GALM2")
    args = ap.parse_args()

    import jax
    import jax.numpy as jnp
    from bench_simulate import machine
    from helpers import identifiable_combinations
    from scipy.optimize import differential_evolution, least_squares

    import jaxhyst as jh
    from jaxhyst.params import NAMES

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=200)
    problem = jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS)
    settings = dict(T2=45, T3=100) if args.quick else {}
    seeds = args.seeds[:1] if args.quick else args.seeds
    truth = jh.TABLE1_TRUE.to_dict()
    truth_c = identifiable_combinations(truth)
    print(f"machine: {machine()}\nsettings: {settings}\n")

    runs = []
    for method in args.methods.split(","):
        for seed in seeds:
            t0 = time.perf_counter()
            res = jh.run_hybrid(problem, method, seed=seed, settings=settings)
            wall = time.perf_counter() - t0
            runs.append((f"{method} s{seed}", res, wall, res.extra["evaluations"],
                         res.extra["local_steps"]))
            print(f"{method} seed {seed}: cost {res.cost:.3e} in {wall:.1f} s "
                  f"(recorded {res.wall_time:.1f} s)", file=sys.stderr, flush=True)

    # peer 1: vmapped multi-start LM
    U = np.random.default_rng(0).uniform(0, 1, (16, 10))
    jh.multistart(problem, U, solver="lm", max_steps=200)  # compile
    t0 = time.perf_counter()
    res = jh.multistart(problem, U, solver="lm", max_steps=200)
    runs.append(("LM x16 (vmapped)", res, time.perf_counter() - t0, 0,
                 sum(s["steps"] for s in res.extra["starts"])))

    # peer 2: SciPy DE (vectorised: one vmapped batch per generation) + trf polish
    cost_batch = jax.jit(jax.vmap(lambda u: problem.cost_u(u)))
    fun = jax.jit(lambda z: problem.residuals(z))
    jac = jax.jit(jax.jacfwd(lambda z: problem.residuals(z)))
    budget = settings.T1 * settings.q1 + settings.T2 * settings.q2
    popsize = 15
    maxiter = max(1, budget // (popsize * 10) - 1)
    counter = {"n": 0}

    def batch_cost(Ut):  # DE passes shape (n, S)
        counter["n"] += Ut.shape[1]
        c = np.asarray(cost_batch(jnp.asarray(Ut.T)))
        return np.where(np.isfinite(c), c, 1e300)

    for seed in seeds:
        counter["n"] = 0
        t0 = time.perf_counter()
        de = differential_evolution(batch_cost, [(0.0, 1.0)] * 10, popsize=popsize,
                                    maxiter=maxiter, seed=seed, polish=False, tol=0,
                                    vectorized=True, updating="deferred")
        z0 = np.asarray(jh.identify.z_from_u(jnp.asarray(de.x)))
        ls = least_squares(lambda z: np.asarray(fun(z)), z0, jac=lambda z: np.asarray(jac(z)),
                           method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                           max_nfev=settings.T3)
        wall = time.perf_counter() - t0
        res = jh.identify.local.summarize(
            problem, jnp.asarray(ls.x), ls.nfev,
            "successful" if ls.status > 0 else "max_steps_reached", "DE+trf", wall)
        runs.append((f"DE+trf s{seed}", res, wall, counter["n"], ls.nfev))

    # -- the table in the paper's layout ------------------------------------------------------
    header = "| θ | true | " + " | ".join(name for name, *_ in runs) + " |"
    print(header)
    print("|" + "---|" * (len(runs) + 2))
    for n in NAMES:
        vals = " | ".join(f"{float(getattr(r.params, n)):.5g}" for _, r, *_ in runs)
        print(f"| {n} | {truth[n]:.5g} | {vals} |")

    def max_rel(r):
        return max(abs(float(getattr(r.params, n)) / truth[n] - 1) for n in NAMES)

    def comb_err(r):
        c = identifiable_combinations(r.params.to_dict())
        return max(abs(c[k] / truth_c[k] - 1) for k in c)

    rows = [
        ("max rel. error (10 params)", lambda r, *_: f"{100 * max_rel(r):.3g} %"),
        ("max rel. error (7 identifiable combinations)", lambda r, *_: f"{comb_err(r):.1e}"),
        ("max abs e (μm)", lambda r, *_: f"{r.max_abs_error * 1e6:.2e}"),
        ("normalised cost", lambda r, *_: f"{r.cost:.1e}"),
        ("Fmax (F = 1/sqrt(1e-30 + E), E in m²)",
         lambda r, *_: f"{float(problem.fitness_from_cost(r.cost)):.3g}"),
        ("population evaluations", lambda r, w, ev, ls: f"{ev}"),
        ("local steps / nfev", lambda r, w, ev, ls: f"{ls}"),
        ("wall time (s)", lambda r, w, ev, ls: f"{w:.1f}"),
    ]
    for label, fmt in rows:
        print(f"| {label} | | " + " | ".join(fmt(r, w, ev, ls) for _, r, w, ev, ls in runs)
              + " |")


if __name__ == "__main__":
    main()
