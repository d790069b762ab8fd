"""A single measured loop of 2 000 points fitted from scratch with the default command
(issue 15), against SciPy differential_evolution + least_squares on the same model and
loss, in the same run.

    python benchmarks/bench_measured.py [--repeats 3] [--out benchmarks/bench_measured_output.md]

Loops (B in T against H in A/m, no time column, each written to a CSV):

- ``ferrite-digitized``: a ferrite-like JA loop (Ms 3.2e5 A/m, a 14, k 11 A/m, c 0.6)
  resampled like a digitized curve: 2 000 points starting a third of the way round, noise
  of 0.1 % of the range on H (reversals within the branches) and 0.3 % on B;
- ``MnZn-2-resampled``: the largest measured MnZn loop (../shared/data, 129 points)
  interpolated to 2 000 points along its sample index (a digitizer's density), measured
  values otherwise unchanged.

jaxhyst: ``jaxhyst identify loop.csv --out r.json`` in a fresh process, timed wall clock
from start to exit: once with an empty compilation cache (cold: compilation included)
and then ``--repeats`` times with the cache it filled (warm). SciPy: the problem jaxhyst
builds from the same file (same model, default bounds, loss), its cost compiled once
(compile time counted), DE (popsize 15, vectorized over the population, tol 0.01,
polish off) then least_squares (trf, jacobian by forward mode) from DE's best. The best
loss any method reached is the minimum over these and a reference run (16 other LM
starts, up to 300 steps); "within 1 %" means cost ≤ 1.01 × that.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

sys.path.insert(0, os.path.dirname(__file__))
sys.path.insert(0, os.path.join(os.path.dirname(__file__), "..", "tests"))

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data",
                    "MnZn_ferrite_BH.csv")


def loops(d):
    from test_measured import _digitized

    from jaxhyst.io import read_loops

    out = {}
    H, B = _digitized(seed=3, n=2000)
    out["ferrite-digitized"] = (H, B)
    if os.path.exists(DATA):
        lp = read_loops(DATA)[2]
        s = np.linspace(0, lp.n_samples - 1, 2000)
        idx = np.arange(lp.n_samples)
        out["MnZn-2-resampled"] = (np.interp(s, idx, lp.H), np.interp(s, idx, lp.signals["B"]))
    paths = {}
    for name, (H, B) in out.items():
        paths[name] = os.path.join(d, f"{name}.csv")
        np.savetxt(paths[name], np.c_[H, B], delimiter=",", header="H [A/m],B [T]",
                   comments="")
    return paths


def run_cli(csv, out, cache):
    env = {**os.environ, "JAXHYST_CACHE_DIR": cache}
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "jaxhyst.cli", "identify", csv, "--out", out,
                        "--progress", "0"], env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode not in (0, 4):
        raise RuntimeError(p.stderr[-2000:])
    with open(out) as fh:
        res = json.load(fh)
    return wall, res["cost"], p.returncode


def scipy_fit(problem, seed):
    import jax
    import jax.numpy as jnp
    from scipy.optimize import differential_evolution, least_squares

    import jaxhyst as jh

    n = problem.space.n_free
    t0 = time.perf_counter()
    cost_batch = jax.jit(jax.vmap(lambda u: problem.cost_u(u)))
    fun = jax.jit(lambda z: problem.residuals(z))
    jac = jax.jit(jax.jacfwd(lambda z: problem.residuals(z)))
    cost_batch(jnp.full((15 * n, n), 0.5)).block_until_ready()
    fun(jnp.zeros(n)).block_until_ready()
    jac(jnp.zeros(n)).block_until_ready()
    compiled = time.perf_counter() - t0
    de = differential_evolution(
        lambda U: np.nan_to_num(np.asarray(cost_batch(jnp.asarray(U.T))), nan=1e300),
        [(0.0, 1.0)] * n, popsize=15, seed=seed, polish=False, tol=0.01, vectorized=True,
        updating="deferred")
    z0 = np.asarray(jh.identify.z_from_u(jnp.asarray(de.x)))
    ls = least_squares(lambda z: np.asarray(fun(z)), z0, jac=lambda z: np.asarray(jac(z)),
                       method="trf")
    wall = time.perf_counter() - t0
    return wall, compiled, float(np.sum(ls.fun ** 2)), int(de.nfev)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--out", help="write the table (markdown) here too")
    args = ap.parse_args()
    from bench_simulate import machine

    import jaxhyst as jh
    from jaxhyst.cli import build_problem  # the CLI's own problem builder

    lines = [f"machine: {machine()}", f"date: {time.strftime('%Y-%m-%d')}", ""]
    d = tempfile.mkdtemp(prefix="bench-measured-")
    paths = loops(d)
    lines += ["| loop | method | wall (s) | cost | / best | within 1 % |",
              "|---|---|---|---|---|---|"]
    for name, csv in paths.items():
        rows = []
        cache = os.path.join(d, f"cache-{name}")
        cold = run_cli(csv, os.path.join(d, "cold.json"), cache)
        warm = [run_cli(csv, os.path.join(d, f"warm{i}.json"), cache)
                for i in range(args.repeats)]
        rows.append(("jaxhyst identify (cold cache)", cold[0], cold[1]))
        rows.append((f"jaxhyst identify (warm cache, median of {args.repeats})",
                     float(np.median([w[0] for w in warm])),
                     float(np.median([w[1] for w in warm]))))
        with open(os.path.join(d, "cold.json")) as fh:
            spec = json.load(fh)["problem"]
        spec["data"] = csv
        problem = build_problem(spec)
        sc = [scipy_fit(problem, seed) for seed in range(args.repeats)]
        for i, (wall, comp, cost, nfev) in enumerate(sc):
            rows.append((f"SciPy DE + least_squares (seed {i}, {nfev} evaluations, "
                         f"compile {comp:.1f} s)", wall, cost))
        starts = np.random.default_rng(7).uniform(0, 1, (16, problem.space.n_free))
        ref = jh.identify.multistart(problem, starts, solver="lm", max_steps=300)
        rows.append(("reference: 16 other LM starts, 300 steps", ref.wall_time, ref.cost))
        best = min(r[2] for r in rows)
        for label, wall, cost in rows:
            lines.append(f"| {name} | {label} | {wall:.1f} | {cost:.6e} | {cost / best:.4f} | "
                         f"{'yes' if cost <= 1.01 * best else 'NO'} |")
        print("\n".join(lines[-len(rows):]), flush=True)
    text = "\n".join(lines)
    print("\n" + text)
    if args.out:
        with open(args.out, "w") as fh:
            fh.write(text + "\n")


if __name__ == "__main__":
    main()
