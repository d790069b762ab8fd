"""One short run on a GPU (the device check of a session that is lent one):

    PYTHONPATH=. python benchmarks/gpu_check.py [--budget 240]

1. Population evaluation, ns per individual·sample of ``jax.jit(jax.vmap(simulate))``
   and of `jaxhyst.simulate_batch` (what the GA calls) for P = 1 000 … 100 000 on the
   Table 1 drive (T = 451, 2 substeps), median of repeated runs after compilation —
   with the time loop's branches as on the CPU, then branch-free (the accelerator's
   default, `jaxhyst.model.interval.on_accelerator`), in the same run.
2. `jaxhyst.compensate` of one 100 Hz period (200 samples, Actuator2, Table 3's 10 Hz
   column): first call and median of three, with its errors (compare the CPU's).

Stops starting new measurements once ``--budget`` seconds have passed.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--budget", type=float, default=240.0)
    args = ap.parse_args()
    start = time.perf_counter()
    sys.path.insert(0, HERE)
    import jax
    import jax.numpy as jnp
    from bench_simulate import median_time, population

    import jaxhyst as jh
    from jaxhyst.model.simulate import simulate_unchecked

    print(f"jax {jax.__version__}, devices {jax.devices()}", flush=True)
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=200)
    T = drive.n_samples

    def one(x):
        return simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive).y

    from jaxhyst.model import interval, timeloop

    print("\n| time loop | P | jit(vmap) ns/indiv·sample | simulate_batch ns/indiv·sample "
          "| first call (s) |\n|---|---|---|---|---|", flush=True)
    for free in (False, None):  # the CPU's branching loop, then the accelerator's own
        interval.FORCE_BRANCH_FREE = free
        jax.clear_caches()
        timeloop.clear_traces()
        batched = jax.jit(jax.vmap(one))
        label = "branching" if free is False else "branch-free"
        for P in (1_000, 10_000, 100_000):
            if time.perf_counter() - start > args.budget:
                print(f"(budget reached before P = {P})")
                break
            X = jnp.asarray(population(P))
            t0 = time.perf_counter()
            batched(X).block_until_ready()
            first = time.perf_counter() - t0
            t_vmap = median_time(lambda X=X, b=batched: b(X).block_until_ready(), 5)
            params = jh.Parameters.from_array(X)
            jh.simulate_batch(params, jh.ACTUATOR1, drive).y.block_until_ready()
            t_batch = median_time(lambda p=params: jh.simulate_batch(
                p, jh.ACTUATOR1, drive).y.block_until_ready(), 5)
            print(f"| {label} | {P} | {t_vmap / (P * T) * 1e9:.2f} | "
                  f"{t_batch / (P * T) * 1e9:.2f} | {first:.1f} |", flush=True)

    if time.perf_counter() - start > args.budget:
        return
    from jaxhyst.control import compensate, sinusoidal_reference

    model = jh.Model(jh.TABLE3[10], jh.ACTUATOR2)
    ref = sinusoidal_reference(100.0, 11.3e-6, 37.5e-6)
    t0 = time.perf_counter()
    res = compensate(model, ref, current_limit=12e3)
    first = time.perf_counter() - t0
    times = []
    for _ in range(3):
        t0 = time.perf_counter()
        res = compensate(model, ref, current_limit=12e3)
        times.append(time.perf_counter() - t0)
    print(f"\ncompensate, one 100 Hz period: first call {first:.1f} s, then "
          f"{np.median(times):.3f} s; errors uncompensated {res.uncompensated_error:.4g}, "
          f"inverse {res.inverse_error:.4g}, refined {res.error:.4g}, {res.steps} steps, "
          f"run-in {res.run_in_periods} periods", flush=True)
    print(f"total {time.perf_counter() - start:.0f} s")


if __name__ == "__main__":
    main()
