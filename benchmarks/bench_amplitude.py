"""Amplitude (issue 31): can one parameter set describe loops of several amplitudes of
one material? Leave-one-loop-out on a multi-amplitude B(H) file: fit the other loops
jointly, predict the loop left out, and divide its rms error by that loop's own fit's.

    python benchmarks/bench_amplitude.py [FILE] [--variants classic,energy,venkataraman,pop]
                                         [--starts 8]

FILE defaults to ../shared/data/MnZn_ferrite_BH.csv (columns loop, H, B). For each form:
shared parameters (one set for every loop), and the amplitude form of
`jaxhyst.identify.conditions` (k, a and c power laws / linear in ln of the loop's peak
field). Fits: multi-start LM from the data-derived box (`loop_bounds`), 4 substeps,
structural parameters fixed.
"""

from __future__ import annotations

import argparse
import os

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "MnZn_ferrite_BH.csv")

#: The amplitude forms tried: name → {parameter: features}.
FORMS = {
    "shared": {},
    "amplitude (k, a, c)": {"k": ("log_amplitude",), "a": ("log_amplitude",),
                            "c": ("log_amplitude",)},
    "amplitude (k, c)": {"k": ("log_amplitude",), "c": ("log_amplitude",)},
    "amplitude (k)": {"k": ("log_amplitude",)},
    "amplitude (a, k)": {"a": ("log_amplitude",), "k": ("log_amplitude",)},
}


def fit(jh, problem, n, starts, seed=0):
    X = np.random.default_rng(seed).uniform(0.05, 0.95, (starts, n))
    return jh.multistart(problem, X, max_steps=300, report=False)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("data", nargs="?", default=DATA)
    ap.add_argument("--variants", default="classic,energy")
    ap.add_argument("--starts", type=int, default=8)
    ap.add_argument("--substeps", type=int, default=4)
    ap.add_argument("--forms", default=";".join(FORMS),
                    help="semicolon-separated names of FORMS to run")
    args = ap.parse_args()
    import warnings

    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR, STRUCTURAL
    from jaxhyst.identify.measured import loop_bounds, monotone_branches
    from jaxhyst.io import read_loops

    warnings.simplefilter("ignore")
    loops = read_loops(args.data)
    Hs = [np.asarray(lp.H) for lp in loops]
    Bs = [np.asarray(lp.signals["B"]) for lp in loops]
    L = len(loops)
    drives = [jh.drive_from_record(None, monotone_branches(H)) for H in Hs]
    bounds = loop_bounds(Hs, Bs, "flux_density")
    fixed = {n: 0.5 * (float(getattr(bounds.lower, n)) + float(getattr(bounds.upper, n)))
             for n in STRUCTURAL}
    amplitude = [float(np.max(np.abs(H))) for H in Hs]
    print(f"{os.path.basename(args.data)}: {L} loops, peak fields "
          f"{', '.join(f'{a:.3g}' for a in amplitude)} A/m\n")
    print("| form | variant | loop left out | own fit rms (mT) | held-out rms (mT) | ratio |")
    print("|---|---|---|---|---|---|")
    for vname in args.variants.split(","):
        from jaxhyst.cli.spec import variant_from_name

        variant = variant_from_name(vname)
        own = []
        for i in range(L):
            space = jh.ParameterSpace(bounds, fixed)
            p = jh.Problem(Bs[i], drives[i], NO_ACTUATOR, space, output="flux_density",
                           variant=variant, substeps=args.substeps)
            own.append(fit(jh, p, space.n_free, args.starts).rms_error)
        for form in (f.strip() for f in args.forms.split(";")):
            varying = FORMS[form]
            model = jh.ConditionModel(varying)
            for held in range(L):
                idx = [j for j in range(L) if j != held]
                records = jh.JointProblem([Bs[j] for j in idx], [drives[j] for j in idx],
                                          NO_ACTUATOR, jh.per_record_space(bounds, len(idx)),
                                          output="flux_density", variant=variant,
                                          substeps=args.substeps)
                cond = jh.Conditions(amplitude=[amplitude[j] for j in idx])
                space = jh.condition_space(bounds, model, fixed=fixed)
                problem = jh.ConditionProblem(records, cond, model, space)
                r = fit(jh, problem, space.n_free, args.starts)
                p = problem.parameters_at(r.params, problem.condition_model.feature_values(
                    jh.Conditions(amplitude=[amplitude[held]])))
                p = jh.Parameters.from_array(np.asarray(p.to_array())[0])
                sim = jh.simulate(p, NO_ACTUATOR, drives[held], variant,
                                  substeps=args.substeps)
                B = 4e-7 * np.pi * (np.asarray(sim.observed("H")) + np.asarray(
                    sim.observed("M")))
                rms = float(np.sqrt(np.mean((B - Bs[held]) ** 2)))
                print(f"| {form} | {vname} | {held} | {1e3 * own[held]:.2f} | "
                      f"{1e3 * rms:.2f} | {rms / own[held]:.1f} |", flush=True)


if __name__ == "__main__":
    main()
