"""Population evaluation speed: jaxhyst (jit + vmap, 1 device and sharded over 2 host
devices) against the same model as a plain Python/NumPy loop and as a Numba loop
(serial and parallel over individuals), same substeps, same machine, same run.

    python benchmarks/bench_simulate.py            # everything (a few minutes)
    python benchmarks/bench_simulate.py --quick    # P ≤ 120, 200 samples/period

Reports ns per (individual × sample): median of repeated runs after compilation.
"""

from __future__ import annotations

import argparse
import os
import platform
import subprocess
import sys
import time

import numpy as np


def machine() -> str:
    cpu = platform.processor()
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                if line.startswith("model name"):
                    cpu = line.split(":", 1)[1].strip()
                    break
    except OSError:
        pass
    import jax

    return (f"{cpu}, {os.cpu_count()} cores, Python {platform.python_version()}, "
            f"jax {jax.__version__}, {time.strftime('%Y-%m-%d')}")


def median_time(fn, repeats=5):
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times))


def population(P, seed=0):
    import jax

    import jaxhyst as jh

    lo, hi = jh.TABLE1_BOUNDS.lower.to_array(), jh.TABLE1_BOUNDS.upper.to_array()
    return np.asarray(lo + (hi - lo) * jax.random.uniform(jax.random.PRNGKey(seed), (P, 10)))


def bench_jax(P_list, spp_list, sharded):
    import jax
    import jax.numpy as jnp
    from jax.sharding import Mesh, NamedSharding, PartitionSpec

    import jaxhyst as jh
    from jaxhyst.model.simulate import simulate_unchecked

    rows = []
    for spp in spp_list:
        drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=spp)
        T = drive.n_samples

        def one(x, drive=drive):
            return simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive).y

        batched = jax.jit(jax.vmap(one))
        for P in P_list:
            X = jnp.asarray(population(P))
            if sharded:
                n = len(jax.devices())
                if P % n:
                    continue
                mesh = Mesh(np.array(jax.devices()), ("pop",))
                X = jax.device_put(X, NamedSharding(mesh, PartitionSpec("pop")))
            t0 = time.perf_counter()
            batched(X).block_until_ready()
            first = time.perf_counter() - t0
            t = median_time(lambda X=X: batched(X).block_until_ready())
            rows.append(dict(impl="jax vmap" + (" sharded x2" if sharded else ""), spp=spp,
                             P=P, T=T, seconds=t, ns=t / (P * T) * 1e9, compile=first - t))
        if not sharded:
            x0 = jnp.asarray(population(1)[0])
            single = jax.jit(one)
            t1 = median_time(lambda: single(x0).block_until_ready(), 20)
            jac = jax.jit(jax.jacfwd(one))
            tj = median_time(lambda: jac(x0).block_until_ready(), 10)
            rows.append(dict(impl="jax single", spp=spp, P=1, T=T, seconds=t1,
                             ns=t1 / T * 1e9, compile=float("nan"), jac_ratio=tj / t1))
    return rows


def bench_loops(P_list, spp_list, numpy_individuals=2):
    from reference_loop import numba_module, simulate_loop, structural_matrices

    import jaxhyst as jh

    compiled = numba_module()
    fast, fast_population = compiled.simulate_loop, compiled.simulate_population

    rows = []
    for spp in spp_list:
        drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=spp)
        H = np.asarray(drive.H)
        T = len(H)
        h = float(drive.dt) / 2
        Ar = float(jh.ACTUATOR1.Ar)
        for P in P_list:
            X = population(P)
            mats = [structural_matrices(x[7], x[8], x[9], h) for x in X]
            Phis = np.stack([m[0] for m in mats])
            Gs = np.stack([m[1] for m in mats])
            Y = np.zeros((P, T))
            t0 = time.perf_counter()
            fast_population(X, Ar, H, h, 2, Phis, Gs, Y)
            first = time.perf_counter() - t0

            def serial():
                for j in range(P):
                    fast(X[j], Ar, H, h, 2, Phis[j], Gs[j], Y[j])

            t_par = median_time(lambda: fast_population(X, Ar, H, h, 2, Phis,
                                                        Gs, Y))
            t_ser = median_time(serial)
            rows.append(dict(impl="numba loop, all cores", spp=spp, P=P, T=T, seconds=t_par,
                             ns=t_par / (P * T) * 1e9, compile=first - t_par))
            rows.append(dict(impl="numba loop, 1 core", spp=spp, P=P, T=T, seconds=t_ser,
                             ns=t_ser / (P * T) * 1e9, compile=float("nan")))
            # plain Python/NumPy: time a few individuals and extrapolate (said in the table)
            k = min(P, numpy_individuals)
            t0 = time.perf_counter()
            for j in range(k):
                simulate_loop(X[j], Ar, H, h, 2, Phis[j], Gs[j], Y[j])
            t_np = (time.perf_counter() - t0) / k * P
            rows.append(dict(impl=f"numpy loop (extrapolated from {k})", spp=spp, P=P, T=T,
                             seconds=t_np, ns=t_np / (P * T) * 1e9, compile=float("nan")))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--quick", action="store_true")
    ap.add_argument("--sharded-child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    P_list = [1, 30, 120] if args.quick else [1, 30, 120, 1000]
    spp_list = [200] if args.quick else [200, 1000]
    sys.path.insert(0, os.path.dirname(__file__))
    if args.sharded_child:
        import json

        print(json.dumps(bench_jax([P for P in P_list if P % 2 == 0], spp_list, True)))
        return
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    child = subprocess.run([sys.executable, __file__, "--sharded-child"]
                           + (["--quick"] if args.quick else []),
                           env=env, capture_output=True, text=True, check=True)
    import json

    rows = json.loads(child.stdout.strip().splitlines()[-1])
    rows += bench_jax(P_list, spp_list, False)
    rows += bench_loops(P_list, spp_list)
    print(f"machine: {machine()}\n")
    print("| implementation | samples/period | P | T | ns per indiv.·sample | wall (ms) | "
          "compile (s) |")
    print("|---|---|---|---|---|---|---|")
    for r in sorted(rows, key=lambda r: (r["spp"], r["P"], r["ns"])):
        comp = "" if np.isnan(r["compile"]) else f"{r['compile']:.1f}"
        print(f"| {r['impl']} | {r['spp']} | {r['P']} | {r['T']} | {r['ns']:.0f} | "
              f"{r['seconds'] * 1e3:.2f} | {comp} |")
    for r in rows:
        if "jac_ratio" in r:
            print(f"\njacfwd (10 parameters) / one simulation at {r['spp']} samples/period: "
                  f"{r['jac_ratio']:.2f}x  (single simulation {r['seconds'] * 1e3:.2f} ms)")


if __name__ == "__main__":
    main()
