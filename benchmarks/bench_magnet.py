"""MagNet core loss (issue 31): does a B-driven Jiles–Atherton model predict the loss of a
condition it was not fitted to? For each material of the shared MagNet slice, leave one
measured period out, fit the others' loss per cycle (∮H dB = loss/f, J/m³) and predict the
one left out; the relative error of the predicted loss, median and 95th percentile.

    python benchmarks/bench_magnet.py [FILE] [--samples 256] [--starts 6] [--materials N87]

Models (all physical; the slice holds the loss near 450 kW/m³, so a constant would score
well without meaning anything — the fitted parameters are printed for that reason):

- static: the B-driven static JA (classic form), one parameter set per material;
- rate-dependent: the same plus eddy-current and excess loss coefficients (shared);
- smooth in f, T: the rate-dependent model with k ∝ f^s·exp(q·(T − T_ref)/10 K) and
  a ∝ exp(q_a·(T − T_ref)/10 K) (`jaxhyst.ConditionModel`, slopes in `SLOPES`), the
  rest shared; one LM solve from the rate-dependent fit of the same fold with slopes 0
  (run the rate-dependent model first; otherwise multi-start from the box).

Each period is resampled to ``--samples`` points (periodic linear interpolation of the
measured B) and run in for one period. Fits: multi-start LM (``--starts`` starts in the
box below), structural parameters fixed (a B–H model).
"""

from __future__ import annotations

import argparse
import csv
import os
import sys
import time
import warnings
from collections import defaultdict

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
DATA = os.path.join(HERE, "..", "..", "shared", "data", "MagNet_iso_loss_B_cycles.csv")

#: The box of a power ferrite (SI): Ms 0.13–1.3 T/μ0, a and k 0.5–500 A/m.
BOX = {"Ms": (1e5, 1e6), "a": (0.5, 500.0), "k": (0.5, 500.0), "alpha": (-1e-3, 1e-3),
       "c": (0.0, 1.0)}
#: Loss coefficients' box: k_e·(dB/dt)² and k_x·|dB/dt|^1.5 at dB/dt ~ 1e5 T/s.
LOSS_BOX = {"eddy": (0.0, 1e-4), "excess": (0.0, 0.1)}
SMOOTH = {"k": ("log_f", "T"), "a": ("T",)}
#: Their slopes' box: k ∝ f^s with |s| ≤ 2; a factor e^(±1) per 10 K at most.
SLOPES = {"k:log_f": (-2.0, 2.0), "k:T": (-1.0, 1.0), "a:T": (-1.0, 1.0)}


def read_cycles(path):
    rows = defaultdict(list)
    meta = {}
    with open(path) as fh:
        for r in csv.DictReader(fh):
            i = int(r["cycle"])
            rows[i].append((float(r["t_s"]), float(r["B_T"])))
            meta[i] = (r["material"], float(r["frequency_Hz"]), float(r["temperature_C"]),
                       float(r["loss_W_per_m3"]))
    out = []
    for i in sorted(rows):
        t, B = np.array(rows[i]).T
        out.append({"cycle": i, "material": meta[i][0], "f": meta[i][1], "T": meta[i][2],
                    "loss": meta[i][3], "t": t, "B": B})
    return out


def resample(t, B, n):
    """n uniform samples of one period (without its end point), periodic interpolation."""
    period = (t[-1] - t[0]) * len(t) / (len(t) - 1)
    tn = np.arange(n) * period / n
    return tn, np.interp(tn, t - t[0], B, period=period)


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("data", nargs="?", default=DATA)
    ap.add_argument("--samples", type=int, default=256)
    ap.add_argument("--starts", type=int, default=6)
    ap.add_argument("--max-steps", type=int, default=150)
    ap.add_argument("--materials", default=None, help="comma-separated (default: all)")
    ap.add_argument("--models", default="static,rate-dependent,smooth_in_f_T",
                    help="comma-separated of: static, rate-dependent, smooth_in_f_T")
    args = ap.parse_args()
    sys.path.insert(0, HERE)
    from bench_simulate import machine

    import jaxhyst as jh

    warnings.simplefilter("ignore")
    cycles = read_cycles(args.data)
    materials = sorted({c["material"] for c in cycles}) if not args.materials else \
        args.materials.split(",")
    mid = jh.Parameters(Ms=3e5, lambda_s=0.0, a=20.0, k=20.0, alpha=0.0, c=0.3, E=1.0, Kz=1.0,
                        Mz=1.0, Cz=0.0)
    lo = mid.replace(**{n: v[0] for n, v in BOX.items()})
    hi = mid.replace(**{n: v[1] for n, v in BOX.items()})
    bounds = jh.Bounds(lo, hi)
    structural = {n: float(getattr(mid, n)) for n in ("lambda_s", "E", "Kz", "Mz", "Cz")}
    print(f"machine: {machine()}; {args.samples} samples per period, {args.starts} LM starts, "
          "classic JA\n")

    def fit(problem):
        X = np.random.default_rng(0).uniform(0.05, 0.95, (args.starts, problem.space.n_free))
        return jh.multistart(problem, X, max_steps=args.max_steps, report=False)

    summary = []
    for mat in materials:
        recs = [c for c in cycles if c["material"] == mat]
        drives = [jh.flux_from_period(*resample(c["t"], c["B"], args.samples)) for c in recs]
        energy = np.array([c["loss"] / c["f"] for c in recs])  # J/m³ per cycle
        print(f"## {mat}: {len(recs)} periods, {min(c['f'] for c in recs) / 1e3:.0f}–"
              f"{max(c['f'] for c in recs) / 1e3:.0f} kHz, "
              f"{min(c['T'] for c in recs):.0f}–{max(c['T'] for c in recs):.0f} °C\n")
        warm = {}
        for model in args.models.split(","):
            t0 = time.perf_counter()
            errors, last = [], None
            for held in range(len(recs)):
                idx = [j for j in range(len(recs)) if j != held]
                fd = [drives[j] for j in idx]
                if model == "static":
                    space = jh.ParameterSpace(bounds, structural)
                    problem = jh.FluxProblem(energy[idx], fd, space, output="cycle_energy",
                                             variant=jh.ClassicJA())
                elif model == "rate-dependent":
                    space = jh.ParameterSpace.with_losses(bounds, LOSS_BOX, structural)
                    problem = jh.FluxProblem(energy[idx], fd, space, output="cycle_energy",
                                             variant=jh.ClassicJA())
                else:
                    records = jh.FluxProblem(energy[idx], fd,
                                             jh.per_record_space(bounds, len(idx), LOSS_BOX),
                                             output="cycle_energy", variant=jh.ClassicJA())
                    cm = jh.ConditionModel(SMOOTH)
                    space = jh.condition_space(bounds, cm, fixed=structural, losses=LOSS_BOX,
                                               slope_bounds=SLOPES)
                    cond = jh.Conditions(frequency=[recs[j]["f"] for j in idx],
                                         temperature=[recs[j]["T"] for j in idx])
                    problem = jh.ConditionProblem(records, cond, cm, space)
                if model == "smooth_in_f_T" and held in warm:  # from the shared fit, slopes 0
                    p_w, l_w = warm[held]
                    start = {**{n: float(getattr(p_w, n)) for n in jh.NAMES},
                             "eddy": float(l_w.eddy), "excess": float(l_w.excess),
                             **{c: 0.0 for c in cm.coefficient_names()}}
                    r = jh.solve(problem, start, solver="lm", max_steps=args.max_steps,
                                 report=False)
                else:
                    r = fit(problem)
                if model == "rate-dependent":
                    warm[held] = r.params
                if model == "smooth_in_f_T":
                    p = problem.at(r.params, jh.Conditions(frequency=[recs[held]["f"]],
                                                           temperature=[recs[held]["T"]]))
                else:
                    p = r.params
                one = jh.FluxProblem(energy[[held]], [drives[held]],
                                     problem.space if model != "smooth_in_f_T" else
                                     jh.per_record_space(bounds, 1, LOSS_BOX),
                                     output="cycle_energy", variant=jh.ClassicJA())
                rel = float(np.asarray(one.group_residuals(p)[0]).ravel()[0])
                errors.append(abs(rel))
                last = r
            e = 100 * np.array(errors)
            secs = time.perf_counter() - t0
            summary.append((mat, model, np.median(e), np.percentile(e, 95), secs))
            print(f"- {model}: held-out loss error median {np.median(e):.1f} %, 95th "
                  f"{np.percentile(e, 95):.1f} %, max {e.max():.1f} % ({secs:.0f} s); "
                  f"fit on the others' loss rms {100 * last.rms_error:.2f} % — last fold's "
                  "parameters: " + ", ".join(
                      f"{n} {float(v):.3g}" for n, v in _named(last.params).items()),
                  flush=True)
        print()
    print("| material | model | held-out loss error, median | 95th percentile | time (s) |")
    print("|---|---|---|---|---|")
    for mat, model, med, p95, secs in summary:
        print(f"| {mat} | {model} | {med:.1f} % | {p95:.1f} % | {secs:.0f} |")


def _named(params):
    """{name: value} of the fitted parameters worth printing (magnetic and loss)."""
    if isinstance(params, dict):
        return {n: v for n, v in params.items() if n not in ("lambda_s", "E", "Kz", "Mz",
                                                             "Cz")}
    p, losses = params if isinstance(params, tuple) else (params, None)
    out = {n: getattr(p, n) for n in ("Ms", "a", "k", "alpha", "c")}
    if losses is not None:
        out.update(eddy=losses.eddy, excess=losses.excess)
    return out


if __name__ == "__main__":
    main()
