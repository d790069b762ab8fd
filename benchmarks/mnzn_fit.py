"""Measured B(H) loops of a MnZn ferrite (../shared/data/MnZn_ferrite_BH.csv, three
amplitudes): joint and separate fits, the published parameters under the same model, and
the time to fit the three loops jointly against SciPy differential_evolution +
least_squares on the same model, loss and evaluation budget.

    python benchmarks/mnzn_fit.py [--variant classic|venkataraman|energy|pop] [--png DIR]

Model: the classic (Szewczyk "dMan/dHe") JA form by default — the form of the toolbox
whose fit the data README quotes. Loss: Σ over loops of the mean squared error in B
relative to that loop's max|B| (each loop counts equally), as `JointProblem` defines it.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

from jaxhyst.cli import VARIANTS, variant_from_name

sys.path.insert(0, os.path.dirname(__file__))

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data",
                    "MnZn_ferrite_BH.csv")
BOUNDS = {"Ms": (1e5, 5e5), "lambda_s": (0.0, 1e-3), "a": (0.5, 100.0), "k": (0.5, 100.0),
          "alpha": (0.0, 1e-3), "c": (0.0, 1.0), "E": (1e10, 5e10), "Kz": (1e7, 5e7),
          "Mz": (0.1, 1.0), "Cz": (0.0, 1e4)}
PUBLISHED = {"Ms": 2.607e5, "a": 5.75, "k": 4.14, "c": 1.0, "alpha": 6.4e-8}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--variant", default="classic", choices=VARIANTS)
    ap.add_argument("--png", help="directory for the figures")
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--part", choices=("all", "fits", "speed"), default="all",
                    help="only the fit tables, or only the speed comparison")
    args = ap.parse_args()
    if not os.path.exists(DATA):
        sys.exit(f"{DATA} not found (the shared data folder is not here).")

    import jax
    import jax.numpy as jnp
    from bench_simulate import machine
    from scipy.optimize import differential_evolution, least_squares

    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR, STRUCTURAL
    from jaxhyst.io import read_loops

    variant = variant_from_name(args.variant)
    bounds = jh.Bounds.from_dict(BOUNDS)
    fixed = {n: 0.5 * sum(BOUNDS[n]) for n in STRUCTURAL}
    loops = read_loops(DATA)
    drives = [jh.drive_from_record(None, lp.H) for lp in loops]
    Bs = [lp.signals["B"] for lp in loops]
    print(f"machine: {machine()}\nmodel: {type(variant).__name__}, 4 RK4 substeps per "
          f"sample; loops of {[lp.n_samples for lp in loops]} samples, max|B| "
          f"{[round(float(np.max(np.abs(b))), 4) for b in Bs]} T\n")

    def joint(per_loop=()):
        space = jh.JointSpace(bounds, 3, per_loop=per_loop, fixed=fixed)
        return jh.JointProblem(Bs, drives, NO_ACTUATOR, space, output="flux_density",
                               variant=variant, substeps=4)

    def rms_per_loop(problem, params):
        pred = np.asarray(problem.predict_loops(params))
        return [float(np.sqrt(np.mean((pred[i, :len(b)] - b) ** 2))) for i, b in
                enumerate(Bs)]

    pj = joint()
    if args.part in ("all", "fits"):
        joint_res, sep = fits(args, jh, jnp, np, pj, joint, rms_per_loop, fixed, bounds,
                              variant, loops, Bs)
    if args.part in ("all", "speed"):
        speed(args, jh, jax, jnp, pj, differential_evolution, least_squares)
    if args.png and args.part in ("all", "fits"):
        figure(args, jh, np, pj, joint_res, sep, loops, Bs, bounds, variant, fixed)


def fits(args, jh, jnp, np, pj, joint, rms_per_loop, fixed, bounds, variant, loops, Bs):
    rows = []
    # 1. published parameters, same model
    pub = jh.Parameters.from_dict({**fixed, **PUBLISHED})
    pub_b = jh.Parameters.from_array(jnp.broadcast_to(pub.to_array(), (3, 10)))
    rows.append(("published (README), same model", rms_per_loop(pj, pub_b), None, None))

    # 2. joint, all shared: multi-start LM (16 starts, one vmapped batch)
    U = np.random.default_rng(0).uniform(0, 1, (16, pj.space.n_free))
    t0 = time.perf_counter()
    jh.multistart(pj, U, solver="lm", max_steps=150, report=False)
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    res = jh.multistart(pj, U, solver="lm", max_steps=150)
    wall = time.perf_counter() - t0
    rows.append(("joint, all shared (LM ×16)", rms_per_loop(pj, res.params), res, wall))
    joint_res = res
    print(res, "\n")

    # 3. joint with a, k, c per loop (Ms, α̃ shared)
    pl = joint(per_loop=("a", "k", "c"))
    U = np.random.default_rng(0).uniform(0, 1, (16, pl.space.n_free))
    jh.multistart(pl, U, solver="lm", max_steps=150, report=False)
    t0 = time.perf_counter()
    res = jh.multistart(pl, U, solver="lm", max_steps=150)
    rows.append(("joint, a k c per loop (LM ×16)", rms_per_loop(pl, res.params), res,
                 time.perf_counter() - t0))

    # 4. each loop separately
    sep = []
    for b, lp in zip(Bs, loops, strict=True):
        prob = jh.loop_problem(lp.H, b, bounds, variant=variant, substeps=4, fixed=fixed)
        U = np.random.default_rng(0).uniform(0, 1, (16, prob.space.n_free))
        jh.multistart(prob, U, solver="lm", max_steps=150, report=False)
        t0 = time.perf_counter()
        r = jh.multistart(prob, U, solver="lm", max_steps=150)
        sep.append((r, time.perf_counter() - t0))
    rows.append(("separately, one loop at a time", [r.rms_error for r, _ in sep], None,
                 sum(w for _, w in sep)))

    print("| fit | rms B loop 0 (mT) | loop 1 | loop 2 | wall (s, after compile) |")
    print("|---|---|---|---|---|")
    for label, rms, _, wall in rows:
        w = "" if wall is None else f"{wall:.2f}"
        print(f"| {label} | " + " | ".join(f"{1e3 * r:.2f}" for r in rms) + f" | {w} |")
    print()
    for r, _ in sep:
        print({n: round(float(getattr(r.params, n)), 8) for n in ("Ms", "a", "k", "alpha",
                                                                   "c")})
    print(f"\ncompile (first multistart of the joint problem): {compile_s:.1f} s\n",
          flush=True)
    return joint_res, sep


def speed(args, jh, jax, jnp, pj, differential_evolution, least_squares):
    # 5. speed: jaxhyst hybrid vs SciPy DE + least_squares, same model, loss, budget
    settings = dict(q1=60, q2=20, T1=5, T2=45, T3=60, local_steps=4)
    budget = settings.T1 * settings.q1 + settings.T2 * settings.q2
    methods = ("GATR2", "GALM2")
    for m in methods:
        jh.run_hybrid(pj, m, seed=99, settings=settings, report=False)  # compile
    cost_batch = jax.jit(jax.vmap(pj.cost_u))
    fun = jax.jit(lambda z: pj.residuals(z))
    jac = jax.jit(jax.jacfwd(lambda z: pj.residuals(z)))
    n = pj.space.n_free
    cost_batch(jnp.zeros((15 * n, n)))
    fun(jnp.zeros(n))
    jac(jnp.zeros(n))
    print(f"speed: {budget} population evaluations + ≤ {settings.T3} local iterations "
          f"each; seeds {args.seeds}")
    print("| method | seed | normalised cost | rms B (mT) | wall (s) |")
    print("|---|---|---|---|---|")
    for seed in args.seeds:
        for m in methods:
            t0 = time.perf_counter()
            r = jh.run_hybrid(pj, m, seed=seed, settings=settings, report=False)
            w = time.perf_counter() - t0
            print(f"| jaxhyst {m} (vmapped GA + {m[2:4]}) | {seed} | {r.cost:.4e} | "
                  f"{1e3 * r.rms_error:.3f} | {w:.2f} |", flush=True)
        popsize = 15
        maxiter = max(1, budget // (popsize * n) - 1)
        t0 = time.perf_counter()
        de = differential_evolution(
            lambda Ut: np.nan_to_num(np.asarray(cost_batch(jnp.asarray(Ut.T))), nan=1e300),
            [(0.0, 1.0)] * n, popsize=popsize, maxiter=maxiter, seed=seed, polish=False,
            tol=0, vectorized=True, updating="deferred")
        z0 = np.asarray(jh.identify.z_from_u(jnp.asarray(de.x)))
        ls = least_squares(lambda z: np.asarray(fun(z)), z0, jac=lambda z: np.asarray(jac(z)),
                           method="trf", max_nfev=settings.T3, xtol=1e-15, ftol=1e-15,
                           gtol=1e-15)
        w = time.perf_counter() - t0
        c = float(np.sum(ls.fun ** 2))
        rms = float(np.sqrt(np.mean((np.asarray(pj.predict(pj.space.params_from_z(
            jnp.asarray(ls.x)))) - pj.data) ** 2)))
        print(f"| SciPy DE (vectorised, jaxhyst model) + least_squares(trf, jacfwd) | "
              f"{seed} | {c:.4e} | {1e3 * rms:.3f} | {w:.2f} |", flush=True)
        t0 = time.perf_counter()
        cost_one = jax.jit(lambda u: pj.cost_u(u))
        cost_one(jnp.zeros(n))
        de = differential_evolution(lambda u: float(cost_one(jnp.asarray(u))),
                                    [(0.0, 1.0)] * n, popsize=popsize, maxiter=maxiter,
                                    seed=seed, polish=False, tol=0)
        z0 = np.asarray(jh.identify.z_from_u(jnp.asarray(de.x)))
        ls = least_squares(lambda z: np.asarray(fun(z)), z0, method="trf",
                           max_nfev=settings.T3 * (n + 1), xtol=1e-15, ftol=1e-15,
                           gtol=1e-15)
        w = time.perf_counter() - t0
        print(f"| SciPy DE (one call per individual) + least_squares(trf, 2-point FD) | "
              f"{seed} | {float(np.sum(ls.fun ** 2)):.4e} | | {w:.2f} |", flush=True)



def figure(args, jh, np, pj, joint_res, sep, loops, Bs, bounds, variant, fixed):
    from jaxhyst.plots import _pyplot

    plt = _pyplot()
    os.makedirs(args.png, exist_ok=True)
    pred = np.asarray(pj.predict_loops(joint_res.params))
    fig, axes = plt.subplots(2, 3, figsize=(14, 7), height_ratios=[2, 1],
                             constrained_layout=True)
    for i, (lp, b) in enumerate(zip(loops, Bs, strict=True)):
        ax, ax2 = axes[0, i], axes[1, i]
        ax.plot(lp.H, b * 1e3, ".", ms=3, color="0.35", label="measured")
        ax.plot(lp.H, pred[i, :len(b)] * 1e3, "-", color="C3", label="joint fit")
        r_sep = sep[i][0]
        p_sep = np.asarray(jh.loop_problem(lp.H, b, bounds, variant=variant, substeps=4,
                                           fixed=fixed).predict(r_sep.params))
        ax.plot(lp.H, p_sep * 1e3, "--", color="C0", lw=1, label="fitted alone")
        ax.set(xlabel="H (A/m)", ylabel="B (mT)", title=f"loop {i}")
        ax.grid(alpha=0.3)
        ax2.plot((pred[i, :len(b)] - b) * 1e3, color="C3", label="joint")
        ax2.plot((p_sep - b) * 1e3, "--", color="C0", label="alone")
        ax2.set(xlabel="sample", ylabel="model − measured (mT)")
        ax2.grid(alpha=0.3)
    axes[0, 0].legend()
    axes[1, 0].legend()
    fig.suptitle(f"MnZn ferrite, {type(variant).__name__}: joint fit (all parameters "
                 "shared) and separate fits")
    fig.savefig(os.path.join(args.png, f"mnzn_{args.variant}.png"), dpi=110)
    plt.close(fig)


if __name__ == "__main__":
    main()
