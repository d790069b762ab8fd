"""Time to reach cost < 1e-20 on the Table 1 problem (200 samples/period, noise-free, all
ten parameters free) from 16 fixed random starts in the box: each jaxhyst solver run
start by start and as one vmapped multi-start batch, against SciPy least_squares(trf)
with the jaxhyst Jacobian (jacfwd) and with finite differences.

    python benchmarks/bench_solvers.py [--starts 16] [--max-steps 200]
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--starts", type=int, default=16)
    ap.add_argument("--max-steps", type=int, default=200)
    ap.add_argument("--solvers", default="lm,dogleg,lma,tra,indirect_lm")
    args = ap.parse_args()

    import jax
    import jax.numpy as jnp
    from bench_simulate import machine
    from scipy.optimize import least_squares

    import jaxhyst as jh
    from jaxhyst.identify import z_from_u

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1)
    problem = jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS)
    U = np.random.default_rng(2024).uniform(0.0, 1.0, (args.starts, 10))
    print(f"machine: {machine()}\nproblem: Table 1, {drive.n_samples} samples "
          f"({drive.n_observed} observed), {args.starts} starts, max_steps {args.max_steps}\n")
    print("| method | success (cost < 1e-20) | median time per start (s) | total (s) | "
          "compile (s) |")
    print("|---|---|---|---|---|")

    for name in args.solvers.split(","):
        t0 = time.perf_counter()
        jh.solve(problem, U[0], solver=name, max_steps=args.max_steps)
        first = time.perf_counter() - t0
        times, ok = [], 0
        for u in U:
            r = jh.solve(problem, u, solver=name, max_steps=args.max_steps)
            times.append(r.wall_time)
            ok += r.cost < 1e-20
        comp = first - times[0]
        print(f"| jaxhyst {name} (one start at a time) | {ok}/{len(U)} | "
              f"{np.median(times):.2f} | {np.sum(times):.1f} | {comp:.0f} |", flush=True)
        t0 = time.perf_counter()
        jh.multistart(problem, U, solver=name, max_steps=args.max_steps)
        first = time.perf_counter() - t0
        r = jh.multistart(problem, U, solver=name, max_steps=args.max_steps)
        ok = sum(s["cost"] < 1e-20 for s in r.extra["starts"])
        print(f"| jaxhyst {name} (vmapped batch of {len(U)}) | {ok}/{len(U)} | "
              f"{r.wall_time / len(U):.2f} | {r.wall_time:.1f} | {first - r.wall_time:.0f} |",
              flush=True)

    fun = jax.jit(lambda z: problem.residuals(z))
    jac = jax.jit(jax.jacfwd(lambda z: problem.residuals(z)))
    for label, use_jac in (("jacfwd Jacobian", True), ("finite differences", False)):
        times, ok = [], 0
        for u in U:
            z0 = np.asarray(z_from_u(jnp.asarray(u)))
            t0 = time.perf_counter()
            sol = least_squares(lambda z: np.asarray(fun(z)), z0,
                                jac=(lambda z: np.asarray(jac(z))) if use_jac else "2-point",
                                method="trf", xtol=1e-15, ftol=1e-15, gtol=1e-15,
                                max_nfev=2000 if use_jac else 4000)
            times.append(time.perf_counter() - t0)
            ok += 2 * sol.cost < 1e-20
        print(f"| SciPy trf, {label} | {ok}/{len(U)} | {np.median(times):.2f} | "
              f"{np.sum(times):.1f} | |", flush=True)


if __name__ == "__main__":
    main()
