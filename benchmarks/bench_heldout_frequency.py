"""Held-out frequency (issue 31): synthetic Actuator2 strain made from the paper's Table 3
parameter sets (one column per frequency, H = Hb + 8·sin(2πft) kA/m), fit four
frequencies, predict the fifth, for each frequency in turn.

    python benchmarks/bench_heldout_frequency.py [--samples 100] [--max-steps 200]

Predictions of the held-out strain, rms error in % of its max|ε|:

- nearest: the parameters of the nearest fitted frequency used as they are — the
  per-frequency fit at its best (noise-free data: its own column of Table 3, exactly);
- smooth in f: λs, a, k, α̃ and c as linear functions of ln f (power laws for λs, a, k),
  Ms, E, Kz, Mz, Cz shared (`jaxhyst.ConditionModel`), fitted jointly to the four
  frequencies by LM from the least-squares line through the four per-frequency fits
  (their columns) in the features — the workflow from per-frequency fits to one model;
- rate-dependent: one parameter set plus the eddy-current and excess loss coefficients
  (`jaxhyst.Losses`, the H-driven rate-dependent model), fitted jointly by LM from the
  four columns' mean — the physics that Table 3's drift stands in for.
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
SMOOTH = ("lambda_s", "a", "k", "alpha", "c")
LOSS_BOX = {"eddy": (0.0, 1.0), "excess": (0.0, 100.0)}


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--samples", type=int, default=100)
    ap.add_argument("--max-steps", type=int, default=200)
    args = ap.parse_args()
    sys.path.insert(0, HERE)
    import jax.numpy as jnp
    from bench_simulate import machine

    import jaxhyst as jh
    from jaxhyst.cli.studies import TABLE3_FIELD_AMPLITUDE

    warnings.simplefilter("ignore")
    act = jh.ACTUATOR2
    freqs = sorted(jh.TABLE3)
    drives = {f: jh.sinusoidal_field(f, TABLE3_FIELD_AMPLITUDE, act.Hb,
                                     samples_per_period=args.samples) for f in freqs}
    data = {f: np.asarray(drives[f].observed(jh.simulate(jh.TABLE3[f], act, drives[f]).strain))
            for f in freqs}
    cols = np.array([np.asarray(jh.TABLE3[f].to_array()) for f in freqs])
    lo, hi = np.min(cols, axis=0), np.max(cols, axis=0)
    lo, hi = np.minimum(lo * 0.5, lo * 2), np.maximum(hi * 2, hi * 0.5)
    c_i = jh.NAMES.index("c")
    lo[c_i], hi[c_i] = 0.0, 1.0
    bounds = jh.Bounds(jh.Parameters.from_array(lo), jh.Parameters.from_array(hi))

    def rms(p, f, losses=None):
        sim = jh.simulate(p, act, drives[f], losses=losses)
        e = np.asarray(drives[f].observed(sim.strain)) - data[f]
        return 100 * float(np.sqrt(np.mean(e**2))) / float(np.max(np.abs(data[f])))

    print(f"machine: {machine()}; {args.samples} samples per period, noise-free strain\n")
    print("| held out | nearest (its column) | smooth in f | rate-dependent | smooth: fit "
          "rms (µε), time | rate-dep.: fit rms (µε), time |")
    print("|---|---|---|---|---|---|")
    for held in freqs:
        fitted = [f for f in freqs if f != held]
        nearest = min(fitted, key=lambda f: abs(np.log(f / held)))
        e_near = rms(jh.TABLE3[nearest], held)
        mean = {n: float(np.mean([float(getattr(jh.TABLE3[f], n)) for f in fitted]))
                for n in jh.NAMES}

        # smooth in ln f
        t0 = time.perf_counter()
        records = jh.JointProblem([data[f] for f in fitted], [drives[f] for f in fitted], act,
                                  jh.per_record_space(bounds, len(fitted)), output="strain")
        cm = jh.ConditionModel({n: ("log_f",) for n in SMOOTH})
        space = jh.condition_space(bounds, cm)
        problem = jh.ConditionProblem(records, jh.Conditions(frequency=fitted), cm, space)
        start = regression_start(jh, problem, [jh.TABLE3[f] for f in fitted])
        r = jh.solve(problem, start, solver="lm", max_steps=args.max_steps, report=False)
        p = problem.at(r.params, jh.Conditions(frequency=[held]))
        p = jh.Parameters.from_array(np.asarray(p.to_array())[0])
        e_smooth, t_smooth, fit_smooth = rms(p, held), time.perf_counter() - t0, r.rms_error

        # rate-dependent, one parameter set
        t0 = time.perf_counter()

        def residuals(params, d):
            p, losses = params
            return {f"{f} Hz": drives[f].observed(
                jh.simulate_unchecked(p, act, drives[f], losses=losses).strain) - d[i]
                for i, f in enumerate(fitted)}

        rspace = jh.ParameterSpace.with_losses(bounds, LOSS_BOX)
        rproblem = jh.ResidualProblem(
            residuals, rspace, [jnp.asarray(data[f]) for f in fitted],
            groups={f"{f} Hz": {"scale": float(np.max(np.abs(data[f]))), "unit": "1"}
                    for f in fitted})
        r2 = jh.solve(rproblem, (jh.Parameters(**mean), jh.Losses(0.01, 1.0)), solver="lm",
                      max_steps=args.max_steps, report=False)
        p2, losses = r2.params
        e_rate, t_rate = rms(p2, held, losses), time.perf_counter() - t0
        print(f"| {held} Hz | {e_near:.2f} % ({nearest} Hz) | {e_smooth:.2f} % | "
              f"{e_rate:.2f} % | {1e6 * fit_smooth:.3g}, {t_smooth:.0f} s | "
              f"{1e6 * r2.rms_error:.3g}, {t_rate:.0f} s |", flush=True)


def regression_start(jh, problem, per_record):
    """Coefficients of ``problem``'s condition model from per-record parameter sets: for
    each varying parameter the least-squares line of its value (its log for a power law)
    against the records' features; shared parameters their mean."""
    from jaxhyst.identify.conditions import ADDITIVE

    X = np.asarray(problem.features)
    A = np.column_stack([np.ones(X.shape[0]), X])
    start = {}
    for n in jh.NAMES:
        v = np.array([float(getattr(p, n)) for p in per_record])
        feats = problem.form.varies.get(n)
        if not feats:
            start[n] = float(np.mean(v))
            continue
        y = v if n in ADDITIVE else np.log(np.abs(v))
        cols = [0] + [1 + problem.form.features.index(f) for f in feats]
        coef = np.linalg.lstsq(A[:, cols], y, rcond=None)[0]
        start[n] = float(coef[0]) if n in ADDITIVE else float(np.sign(v[0]) * np.exp(coef[0]))
        for f, s in zip(feats, coef[1:], strict=True):
            start[f"{n}:{f}"] = float(np.clip(s, -2.9, 2.9))
    return start


if __name__ == "__main__":
    main()
