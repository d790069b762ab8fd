"""What each JAX transformation of the simulator costs (issue 13), in one run:

- a scalar loss Σy² of the Table 1 drive (T samples): forward pass, ``jax.grad`` with
  respect to (log a, log k, c) and with respect to every drive sample, ``jax.jacfwd`` of
  y over all ten parameters, ``jax.hessian`` of the loss; the same through plain JAX AD of
  the time loop (no custom rule) for comparison;
- first-call compile times, each measured in a fresh process (no persistent cache):
  forward, grad, hessian, and a cold Levenberg–Marquardt solve (trace + compile + solve);
- population evaluation at P = 120 and 1000, a user's ``jax.vmap`` and the GA's (in
  blocks of 64 members from P = 256 on), on one device and split over two host devices,
  against the Numba loop of `reference_loop.py` (one core and ``prange`` over both
  cores), and the single trajectory against Numba.

    python benchmarks/bench_transforms.py [--spp 200] [--repeats 30]

Times are medians of repeated calls after compilation; the functions of one table are
timed in interleaved rounds (in each, every function called twice and the second call
timed), so that the machine's speed drifting during the run does not bias their ratios.
Run on a quiet machine; compare ratios within one run only.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def median_ms(fn, repeats):
    fn()
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return float(np.median(times)) * 1e3


def interleaved_ms(fns, repeats):
    """Median ms per call of each of ``fns`` ({name: thunk}), timed in interleaved rounds
    so that a drift in machine speed during the run biases no ratio between them. In
    each round every function is called twice and the second call timed: the caches
    hold its own data, as when it is called repeatedly, not the previous function's."""
    for fn in fns.values():
        fn()
    times = {name: [] for name in fns}
    for _ in range(repeats):
        for name, fn in fns.items():
            fn()
            t0 = time.perf_counter()
            fn()
            times[name].append(time.perf_counter() - t0)
    return {name: float(np.median(v)) * 1e3 for name, v in times.items()}


def setup(spp):
    import jax.numpy as jnp

    import jaxhyst as jh
    from jaxhyst.model import magnetization as mag
    from jaxhyst.model.simulate import simulate_unchecked

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=spp)
    p0 = jh.TABLE1_TRUE

    def with_akc(z):
        return p0.replace(a=jnp.exp(z[0]), k=jnp.exp(z[1]), c=z[2])

    def loss(z):
        return jnp.sum(simulate_unchecked(with_akc(z), jh.ACTUATOR1, drive).y ** 2) * 1e12

    def loss_H(H):
        d = jh.Drive(drive.t, H, run_in=drive.run_in, uniform=True)
        return jnp.sum(simulate_unchecked(p0, jh.ACTUATOR1, d).y ** 2) * 1e12

    def y_of(x):
        return simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive).y

    z0 = jnp.array([np.log(7012.0), np.log(3283.0), 0.18])
    return dict(jh=jh, mag=mag, drive=drive, loss=loss, loss_H=loss_H, y_of=y_of, z0=z0,
                x0=p0.to_array())


def compile_child(what, spp):
    """Print the first-call time of one transformation (run in a fresh process)."""
    import jax

    s = setup(spp)
    t0 = time.perf_counter()
    if what == "forward":
        jax.jit(s["loss"])(s["z0"]).block_until_ready()
    elif what == "grad":
        jax.jit(jax.grad(s["loss"]))(s["z0"]).block_until_ready()
    elif what == "jacfwd":
        jax.jit(jax.jacfwd(s["y_of"]))(s["x0"]).block_until_ready()
    elif what == "hessian":
        jax.jit(jax.hessian(s["loss"]))(s["z0"]).block_until_ready()
    elif what == "lm_solve":
        jh = s["jh"]
        problem = jh.synthetic_problem(jh.TABLE1_TRUE, s["drive"], jh.ACTUATOR1,
                                       jh.TABLE1_BOUNDS)
        res = jh.solve(problem, np.full(10, 0.5), solver="lm", report=False)
        assert res.cost < 1e-10, res.cost
    first = time.perf_counter() - t0
    print(json.dumps({"what": what, "first_call_s": first}))


def compile_times(spp):
    out = {}
    env = dict(os.environ, JAXHYST_CACHE_DIR="off")
    for what in ("forward", "grad", "jacfwd", "hessian", "lm_solve"):
        r = subprocess.run([sys.executable, __file__, "--compile-child", what, "--spp",
                            str(spp)], env=env, capture_output=True, text=True, check=True)
        out[what] = json.loads(r.stdout.strip().splitlines()[-1])["first_call_s"]
    return out


def derivative_table(spp, repeats):
    import jax
    import jax.numpy as jnp

    s = setup(spp)
    mag, jh = s["mag"], s["jh"]
    from jaxhyst.model import paths, timeloop

    f = jax.jit(s["loss"])
    g = jax.jit(jax.grad(s["loss"]))
    gH = jax.jit(jax.grad(s["loss_H"]))
    J = jax.jit(jax.jacfwd(s["y_of"]))
    Hs = jax.jit(jax.hessian(s["loss"]))
    z0, x0, H0 = s["z0"], s["x0"], s["drive"].H
    ours = {
        "forward": lambda: f(z0).block_until_ready(),
        "grad (a, k, c)": lambda: g(z0).block_until_ready(),
        "grad (every drive sample)": lambda: gH(H0).block_until_ready(),
        "jacfwd of y (10 parameters)": lambda: J(x0).block_until_ready(),
        "hessian (a, k, c)": lambda: Hs(z0).block_until_ready(),
    }
    for fn in ours.values():  # compile with the derivative rule in place
        fn()
    # plain JAX AD of the same time loop, without the custom rule
    # (the time loop without its rule, where simulate and magnetization_path call it)
    mag.run_path = paths.run_path = timeloop.run_path_plain
    try:
        s2 = setup(spp)
        f2 = jax.jit(s2["loss"])
        g2 = jax.jit(jax.grad(s2["loss"]))
        gH2 = jax.jit(jax.grad(s2["loss_H"]))
        J2 = jax.jit(jax.jacfwd(s2["y_of"]))
        plain = {
            "forward": lambda: f2(z0).block_until_ready(),
            "grad (a, k, c)": lambda: g2(z0).block_until_ready(),
            "grad (every drive sample)": lambda: gH2(H0).block_until_ready(),
            "jacfwd of y (10 parameters)": lambda: J2(x0).block_until_ready(),
        }
        for fn in plain.values():  # compile while the plain loop is in place
            fn()
        agree = float(jnp.max(jnp.abs(g(z0) - g2(z0))) / jnp.max(jnp.abs(g2(z0))))
    finally:
        mag.run_path = paths.run_path = timeloop.run_path
    timed = interleaved_ms({**{("ours", k): v for k, v in ours.items()},
                            **{("plain", k): v for k, v in plain.items()}}, repeats)
    rows = {k: timed["ours", k] for k in ours}
    plain_rows = {k: timed["plain", k] for k in plain}
    return (rows, plain_rows, agree, s["drive"].n_samples, jh.cpu_loop_kernels(),
            ours["forward"])


def population_table(spp, repeats, sharded):
    """ns per individual·sample of a user's ``jax.vmap`` of the simulation and of the
    GA's population evaluation (`jaxhyst.sharding.vmap_blocked`: blocks of 64 members on
    the CPU from P = 256 on), timed interleaved; each device runs its own share when
    ``sharded`` (`map_sharded`)."""
    import jax

    from jaxhyst.sharding import batch_sharding, map_sharded, place, vmap_blocked

    s = setup(spp)
    jh = s["jh"]
    lo, hi = jh.TABLE1_BOUNDS.lower.to_array(), jh.TABLE1_BOUNDS.upper.to_array()
    rows = {}
    for P in (120, 1000):
        X = lo + (hi - lo) * jax.random.uniform(jax.random.PRNGKey(0), (P, 10))
        if sharded:  # already on the devices, as the GA's population is (no copy per call)
            X = place(X, batch_sharding(P))
        per_device = P // jax.device_count() if sharded else P
        # each device runs its own share, no communication in the time loop
        plain = jax.jit(map_sharded(jax.vmap(s["y_of"]), P, sharded))
        blocked = jax.jit(map_sharded(vmap_blocked(s["y_of"], per_device), P, sharded))
        t = interleaved_ms({"vmap": lambda X=X: plain(X).block_until_ready(),
                            "blocked": lambda X=X: blocked(X).block_until_ready()},
                           max(5, repeats // 3))
        rows[P] = {k: v / (P * s["drive"].n_samples) * 1e6 for k, v in t.items()}
    return rows


def numba_table(spp, repeats, jax_forward):
    sys.path.insert(0, HERE)
    from reference_loop import numba_module, structural_matrices

    import jaxhyst as jh

    mod = numba_module()
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=spp)
    H, T = np.asarray(drive.H), drive.n_samples
    h, Ar = float(drive.dt) / 2, float(jh.ACTUATOR1.Ar)
    th = np.asarray(jh.TABLE1_TRUE.to_array())
    Phi, G = structural_matrices(th[7], th[8], th[9], h)
    y = np.zeros(T)
    single = interleaved_ms({"jax": jax_forward,
                             "numba": lambda: mod.simulate_loop(th, Ar, H, h, 2, Phi, G, y)},
                            repeats * 2)
    rng = np.random.default_rng(0)
    lo = np.asarray(jh.TABLE1_BOUNDS.lower.to_array())
    hi = np.asarray(jh.TABLE1_BOUNDS.upper.to_array())
    rows = {}
    for P in (120, 1000):
        X = lo + (hi - lo) * rng.uniform(size=(P, 10))
        mats = [structural_matrices(x[7], x[8], x[9], h) for x in X]
        Phis, Gs = np.stack([m[0] for m in mats]), np.stack([m[1] for m in mats])
        Y = np.zeros((P, T))
        par = median_ms(lambda: mod.simulate_population(X, Ar, H, h, 2, Phis, Gs, Y),
                        max(5, repeats // 3))

        def serial(X=X, Phis=Phis, Gs=Gs, Y=Y):
            for j in range(len(X)):
                mod.simulate_loop(X[j], Ar, H, h, 2, Phis[j], Gs[j], Y[j])

        ser = median_ms(serial, max(5, repeats // 3))
        rows[P] = (par / (P * T) * 1e6, ser / (P * T) * 1e6)
    return single, rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--spp", type=int, default=200, help="samples per period (200: T = 451)")
    ap.add_argument("--repeats", type=int, default=30)
    ap.add_argument("--compile-child", help=argparse.SUPPRESS)
    ap.add_argument("--sharded-child", action="store_true", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.compile_child:
        compile_child(args.compile_child, args.spp)
        return
    if args.sharded_child:
        print(json.dumps(population_table(args.spp, args.repeats, True)))
        return
    sys.path.insert(0, HERE)
    from bench_simulate import machine

    print(f"machine: {machine()}\n", flush=True)
    rows, plain_rows, agree, T, loops, forward = derivative_table(args.spp, args.repeats)
    fwd = rows["forward"]
    print(f"Table 1 drive, T = {T} samples, 2 RK4 substeps; XLA:CPU loop kernels: {loops}\n")
    print("| transformation | jaxhyst (ms) | × forward | plain AD of the scan (ms) | × forward |")
    print("|---|---|---|---|---|")
    for k, v in rows.items():
        pv = plain_rows.get(k)
        ps = f"{pv:.3f} | {pv / plain_rows['forward']:.1f}" if pv else "– | –"
        print(f"| {k} | {v:.3f} | {v / fwd:.1f} | {ps} |")
    print(f"\ngrad agrees with plain AD to {agree:.1e} (relative)\n", flush=True)
    single, numba_rows = numba_table(args.spp, args.repeats, forward)
    print(f"single trajectory (interleaved): jaxhyst forward {single['jax']:.3f} ms, Numba "
          f"{single['numba']:.3f} ms ({single['jax'] / single['numba']:.1f}×)\n", flush=True)
    one = population_table(args.spp, args.repeats, False)
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    child = subprocess.run([sys.executable, __file__, "--sharded-child", "--spp",
                            str(args.spp), "--repeats", str(args.repeats)], env=env,
                           capture_output=True, text=True, check=True)
    two = {int(k): v for k, v in json.loads(child.stdout.strip().splitlines()[-1]).items()}
    print("| P | jax vmap, 1 device | in blocks (GA), 1 device | jax vmap, 2 host devices | "
          "in blocks (GA), 2 host devices | Numba prange, 2 cores | Numba, 1 core | "
          "best jax vs Numba 2 cores |")
    print("|---|---|---|---|---|---|---|---|")
    for P in (120, 1000):
        best = min(*one[P].values(), *two[P].values())
        print(f"| {P} | {one[P]['vmap']:.0f} | {one[P]['blocked']:.0f} | "
              f"{two[P]['vmap']:.0f} | {two[P]['blocked']:.0f} | {numba_rows[P][0]:.0f} | "
              f"{numba_rows[P][1]:.0f} | {numba_rows[P][0] / best:.1f}× |")
    print("(ns per individual·sample)\n", flush=True)
    comp = compile_times(args.spp)
    print("| first call, fresh process, no cache | seconds |")
    print("|---|---|")
    for k, v in comp.items():
        print(f"| {k} | {v:.1f} |")


if __name__ == "__main__":
    main()
