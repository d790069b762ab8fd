"""Sharding over CPU host devices: what the loops axis and the replicate axis buy.

    python benchmarks/bench_sharding.py [--devices 2]

Splits the CPU into ``--devices`` XLA host devices (the flag is set before jax starts)
and times, each sharded and unsharded in the same process:

- a joint LM solve (30 steps) of two synthetic Actuator2 loops (800 and 1250 Hz, Table 3
  columns, the problem of tests/test_joint.py without noise) with
  ``JointProblem(shard_loops=True/False)``;
- 16 replicate LM fits (Table 1 actuator, 100 Hz, 0.1 % noise, a k α̃ c free) by
  `fit_replicates(shard=True/False)`.

Times are medians of 3 runs after a first (compiling) run; results compared.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

HERE = os.path.dirname(os.path.abspath(__file__))


def _median_time(fn, repeats=3):
    fn()  # compile
    ts = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        ts.append(time.perf_counter() - t)
    ts.sort()
    return ts[len(ts) // 2], out


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--devices", type=int, default=2)
    args = ap.parse_args()
    os.environ["XLA_FLAGS"] = (os.environ.get("XLA_FLAGS", "") +
                               f" --xla_force_host_platform_device_count={args.devices}")
    sys.path.insert(0, os.path.join(HERE, "..", "tests"))
    import jax
    import numpy as np
    from test_joint import FREQS, PER_LOOP, _bounds, _truth

    import jaxhyst as jh
    from jaxhyst.analysis import fit_replicates

    print(f"{jax.device_count()} host devices on {os.cpu_count()} cores")
    truth = _truth()
    act = jh.ACTUATOR2
    drives = [jh.sinusoidal_field(f, 8e3, act.Hb, samples_per_period=60) for f in FREQS]
    data = [np.asarray(d.observed(jh.simulate(
        jh.Parameters.from_array(truth.to_array()[i]), act, d).y))
        for i, d in enumerate(drives)]
    space = jh.JointSpace(_bounds(truth), len(FREQS), per_loop=PER_LOOP,
                          fixed={"Ms": np.asarray(truth.Ms), "Mz": float(truth.Mz[0])})
    start = jh.Parameters.from_array(np.asarray(truth.to_array()) * 1.1)
    solved = {}
    for shard in (True, False):
        problem = jh.JointProblem(data, drives, act, space, shard_loops=shard)
        t, res = _median_time(lambda p=problem: jh.solve(p, start, solver="lm",
                                                          max_steps=30, report=False))
        solved[shard] = res
        print(f"joint LM, 2 loops, shard_loops={shard}: {t:.2f} s, cost {res.cost:.3e}")
    a, b = (np.asarray(solved[s].params.to_array()) for s in (True, False))
    print(f"  parameters, sharded vs not: max rel diff {np.max(np.abs(a / b - 1)):.1e}")

    p = jh.TABLE1_TRUE
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=50)
    problem = jh.synthetic_problem(p, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS,
                                   fixed=["Ms", "lambda_s", "E", "Kz", "Mz", "Cz"])
    y = np.asarray(problem.data)
    reps = y + 1e-3 * np.max(np.abs(y)) * np.random.default_rng(0).standard_normal((16, y.size))
    fits = {}
    for shard in (True, False):
        t, f = _median_time(lambda s=shard: fit_replicates(
            problem, reps, p, solver="lm", max_steps=100, batch_size=16, shard=s))
        fits[shard] = f
        print(f"16 replicate LM fits, shard={shard}: {t:.2f} s, outcomes "
              f"{sorted(set(f['results']))}, steps {f['steps'].min()}–{f['steps'].max()}")
    v = {s: fits[s]["values"] for s in fits}
    se = fits[False]["std_errors"]
    print(f"  values, sharded vs not: max rel diff {np.max(np.abs(v[True] / v[False] - 1)):.1e}"
          f" = {np.max(np.abs(v[True] - v[False]) / se):.1e} standard errors")


if __name__ == "__main__":
    main()
