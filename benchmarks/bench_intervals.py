"""Do the report's 95 % intervals hold where the model bends? (issue 43) Replicate fits of
the full Table 3 problem (Actuator2 strain, all ten parameters free in the box ±50 %
around the truth, 0.1 % white noise, σ declared), each with the profile-checked report.

    python benchmarks/bench_intervals.py [--replicates 100] [--frequencies 2000,800]
                                         [--out benchmarks/bench_intervals_output.md]

Per frequency: for every identifiable parameter and every combination of
`jaxhyst.cli.studies.COMBINATIONS`, the share of replicates whose interval holds the
truth, beside that of the plain Wald interval (± 1.96 standard errors) on the same fits;
how often the report called each interval NOT LINEAR (by its profile the linear
interval would miss more than 10 %) and the median of that implied miss; the median
time of the fit and of the profile check. Each replicate is
fitted by Levenberg–Marquardt from the truth (the question is the interval's, not the
search's).
"""

from __future__ import annotations

import argparse
import datetime
import os
import platform
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def run_case(frequency: float, replicates: int, noise: float):
    import jax

    import jaxhyst as jh
    from jaxhyst.analysis import identifiability
    from jaxhyst.cli.studies import (
        TABLE3_FIELD_AMPLITUDE,
        combination_check,
        noisy_strain_problem,
    )

    truth = jh.TABLE3[frequency]
    drive = jh.sinusoidal_field(frequency, TABLE3_FIELD_AMPLITUDE, jh.ACTUATOR2.Hb,
                                samples_per_period=200)
    q = truth.to_dict()
    cover, wald, flagged, seen, implied = {}, {}, {}, {}, {}
    t_fit, t_profile = [], []
    for r in range(replicates):
        problem = noisy_strain_problem(truth, jh.ACTUATOR2, drive, noise,
                                       jax.random.PRNGKey(1000 + r))
        t0 = time.perf_counter()
        fit = jh.solve(problem, truth, report=False)
        t1 = time.perf_counter()
        rep = identifiability(problem, fit.params, profile=True)
        t2 = time.perf_counter()
        if r:  # (the first pays the compilations)
            t_fit.append(t1 - t0)
            t_profile.append(t2 - t1)
        nonlinear, miss = set(rep.nonlinear()), rep.linear_miss()
        for name, ends in rep.intervals.items():
            if ends is None or not np.all(np.isfinite(ends)):  # (not determined)
                continue
            lo, hi = ends
            seen[name] = seen.get(name, 0) + 1
            cover[name] = cover.get(name, 0) + int(lo <= q[name] <= hi)
            se = rep.std_errors[name]
            v = rep.values[rep.names.index(name)]
            wald[name] = wald.get(name, 0) + int(abs(v - q[name]) <= 1.96 * se)
            flagged[name] = flagged.get(name, 0) + int(name in nonlinear)
            if name in miss:
                implied.setdefault(name, []).append(miss[name])
        for label, c in combination_check(rep, truth).items():
            if c["covers"] is None or label in rep.intervals:  # (a parameter: done above)
                continue
            seen[label] = seen.get(label, 0) + 1
            cover[label] = cover.get(label, 0) + int(c["covers"])
            wald[label] = wald.get(label, 0) + int(
                abs(c["value"] - c["truth"]) <= 1.96 * c["std_error"])
        print(f"{frequency:g} Hz replicate {r + 1}/{replicates}: fit {t1 - t0:.1f} s, "
              f"profile {t2 - t1:.1f} s, NOT LINEAR {sorted(nonlinear)}", flush=True)
    return {"seen": seen, "cover": cover, "wald": wald, "flagged": flagged,
            "implied": {n: float(np.median(v)) for n, v in implied.items()},
            "fit_s": float(np.median(t_fit)) if t_fit else float("nan"),
            "profile_s": float(np.median(t_profile)) if t_profile else float("nan")}


def table(frequency, res, replicates) -> list[str]:
    lines = [f"**{frequency:g} Hz**, {replicates} replicates: median fit "
             f"{res['fit_s']:.2f} s, profile check {res['profile_s']:.2f} s "
             f"({res['profile_s'] / res['fit_s']:.2g}× the fit)", "",
             "| quantity | report's interval covers | Wald covers | NOT LINEAR | linear "
             "interval's miss by its profile (median) |",
             "|---|---|---|---|---|"]
    for name, n in res["seen"].items():
        flag = (f"{res['flagged'][name]}/{n}" if name in res["flagged"] else "—")
        implied = res["implied"].get(name)
        lines.append(f"| {name} | {res['cover'][name]}/{n} | {res['wald'][name]}/{n} | "
                     f"{flag} | {'—' if implied is None else f'{100 * implied:.1f} %'} |")
    return lines + [""]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--replicates", type=int, default=100)
    ap.add_argument("--frequencies", default="2000,800")
    ap.add_argument("--noise", type=float, default=1e-3)
    ap.add_argument("--out", default=os.path.join(HERE, "bench_intervals_output.md"))
    args = ap.parse_args()
    import jaxhyst as jh

    jh.enable_compilation_cache()
    lines = [f"`python benchmarks/bench_intervals.py --replicates {args.replicates} "
             f"--frequencies {args.frequencies}` — {datetime.date.today()}, "
             f"{platform.machine()}, {os.cpu_count()} cores", ""]
    for f in (float(x) for x in args.frequencies.split(",")):
        lines += table(f, run_case(f, args.replicates, args.noise), args.replicates)
    text = "\n".join(lines)
    print(text)
    with open(args.out, "w", encoding="utf-8") as fh:
        fh.write(text + "\n")


if __name__ == "__main__":
    main()
