"""One short run on a GPU (the device check of a session that is lent one):

    PYTHONPATH=. python benchmarks/gpu_check.py [--budget 240] [--parts classic,compensate,forms]

1. Population evaluation, ns per individual·sample of ``jax.jit(jax.vmap(simulate))``
   and of `jaxhyst.simulate_batch` (what the GA calls) for P = 1 000 … 100 000 on the
   Table 1 drive (T = 451, 2 substeps), median of repeated runs after compilation —
   with the time loop's branches as on the CPU, then branch-free (the accelerator's
   default, `jaxhyst.model.interval.on_accelerator`), in the same run.
2. `jaxhyst.compensate` of one 100 Hz period (200 samples, Actuator2, Table 3's 10 Hz
   column): first call and median of three, with its errors (compare the CPU's).

3. ``forms``: the pinning-cell forms (`jaxhyst.PlayJA`, `jaxhyst.PreisachJA`, 16 cells) on
   a 50 Hz B(H) drive (T = 451, one substep): a population of P parameter sets (a, k, c
   scaled by factors in [0.7, 1.3]) as ``jax.jit(jax.vmap(simulate))``, ns per
   individual·sample on the GPU and on the same machine's CPU (its own time loop) in the
   same run, and the largest difference of M between the two (relative to max |M|).
4. ``losses``: the rate-dependent model (`jaxhyst.Losses`: eddy-current and excess
   fields and the magnetic after-effect together) with the classic and the play form on
   the same drive at 400 Hz, the same population timing and GPU-vs-CPU difference.

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
    ap.add_argument("--parts", default="classic,compensate,forms")
    ap.add_argument("--sizes", default="1000,10000,100000",
                    help="population sizes of the forms and losses parts")
    args = ap.parse_args()
    parts = args.parts.split(",")
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

    if "classic" in parts:
        print("\n| time loop | P | jit(vmap) ns/indiv·sample | simulate_batch "
              "ns/indiv·sample | first call (s) |\n|---|---|---|---|---|", flush=True)
    for free in ((False, None) if "classic" in parts else ()):  # the CPU's loop, then the
        # accelerator's own
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

    sizes = tuple(int(v) for v in args.sizes.split(","))
    if "forms" in parts:
        forms(start, args.budget, sizes)
    if "losses" in parts:
        forms(start, args.budget, sizes, losses=True)
    if time.perf_counter() - start > args.budget or "compensate" not in parts:
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


def forms(start, budget, sizes=(1_000, 10_000, 100_000), losses=False):
    """Parts 3 and 4 (the module's docstring)."""
    import jax
    import jax.numpy as jnp
    from bench_simulate import median_time

    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR
    from jaxhyst.model import interval, timeloop
    from jaxhyst.model.simulate import simulate_unchecked

    drive = jh.sinusoidal_field(400.0 if losses else 50.0, 120.0, 0.0,
                                samples_per_period=200)
    T = drive.n_samples
    # (the after-effect's τ_M of ~1/10 of the period; field terms of a few % of the field)
    rate = jh.Losses(eddy=0.05, excess=0.05, relax=2e-4) if losses else None
    base = jh.Parameters(Ms=3.8e5, lambda_s=0.0, a=30.0, k=25.0, alpha=3e-5, c=0.4, E=1.0,
                         Kz=1.0, Mz=1.0, Cz=0.0)
    cpu = jax.devices("cpu")[0]
    print("\n| form | P | GPU ns/indiv·sample | CPU ns/indiv·sample | first call GPU / CPU (s) "
          "| max |ΔM| / max |M| |\n|---|---|---|---|---|---|", flush=True)
    shown = ((jh.ClassicJA(), jh.PlayJA(spread=0.7, cells=16)) if losses else
             (jh.PlayJA(spread=0.7, cells=16), jh.PreisachJA(spread=0.7, cells=16)))
    for form in shown:
        def one(x, form=form):
            p = base.replace(a=base.a * x[0], k=base.k * x[1], c=base.c * x[2])
            return simulate_unchecked(p, NO_ACTUATOR, drive, form, substeps=1,
                                      losses=rate).M

        for P in sizes:
            if time.perf_counter() - start > budget:
                print(f"(budget reached before {type(form).__name__}, P = {P})")
                return
            X = np.random.default_rng(0).uniform(0.7, 1.3, (P, 3))
            row = {}
            for where, free in (("gpu", None), ("cpu", False)):
                if where == "cpu" and P > 10_000:
                    row[where] = (float("nan"), float("nan"), None)
                    continue
                interval.FORCE_BRANCH_FREE = free
                timeloop.clear_traces()
                batched = jax.jit(jax.vmap(one))
                Xd = jax.device_put(jnp.asarray(X), cpu) if where == "cpu" else \
                    jnp.asarray(X)
                t0 = time.perf_counter()
                M = batched(Xd).block_until_ready()
                first = time.perf_counter() - t0
                t = median_time(lambda b=batched, Xd=Xd: b(Xd).block_until_ready(), 3)
                row[where] = (t / (P * T) * 1e9, first, np.asarray(M))
            interval.FORCE_BRANCH_FREE = None
            Mg, Mc = row["gpu"][2], row["cpu"][2]
            diff = "—" if Mc is None else \
                f"{np.max(np.abs(Mg - Mc)) / np.max(np.abs(Mc)):.1e}"
            label = type(form).__name__ + (" + losses" if losses else "")
            print(f"| {label} | {P} | {row['gpu'][0]:.2f} | {row['cpu'][0]:.2f} "
                  f"| {row['gpu'][1]:.1f} / {row['cpu'][1]:.1f} | {diff} |", flush=True)


if __name__ == "__main__":
    main()
