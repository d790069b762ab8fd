"""Prediction of loops the model never saw (issue 41): leave one loop out with the forms
compared by the command line, on measured loops and on synthetic loop families made by
a model *other* than the ones fitted.

    python benchmarks/bench_heldout_forms.py [--files mnzn,amplitude,frequency,relaxation]
                                             [--forms classic,energy,play,preisach]
                                             [--out benchmarks/bench_heldout_forms_output.md]
                                             [--losses eddy,excess]

Every number comes from the user's command, ``jaxhyst identify FILE --joint
--leave-one-out --variant FORMS --out R.json`` (each fold's box from its training loops,
widened where a fit ends on it; each loop also fitted alone), read back from R.json:
per form and held-out loop the rms error, its ratio to the loop's own fit (same form),
the nearest measured loop's fit predicting it (the skeptic's baseline), and whether the
loop lies inside the others' conditions (interpolated) or not (extrapolated).

The files:
- ``mnzn``: ../shared/data/MnZn_ferrite_BH.csv (three measured B(H) loops);
- ``amplitude``: four B(H) loops of 25–200 A/m made by a Preisach model with a
  *bimodal* distribution of pinning fields (two log-normal populations: no form here
  has it) and 0.2 % noise;
- ``frequency``: four B(H) loops at 50–400 Hz and one field amplitude, made by the
  play model with eddy-current and excess losses and 0.2 % noise, fitted with
  ``--losses eddy,excess`` (the rate-dependent model of every form): the *same* model
  as the play form fitted, so it checks the machinery, not a prediction;
- ``relaxation``: four B(H) loops at 50–400 Hz of one field amplitude made by a
  mechanism no form has: the Preisach model's rate-independent magnetisation relaxed
  through a first-order lag (magnetic after-effect, τ·dM/dt = M_static − M, τ = 0.15 ms,
  the periodic state solved exactly by Fourier series) and 0.2 % noise, fitted with
  ``--losses eddy,excess`` (run with ``--forms classic,play``: the Preisach form made
  the loops' static part).

Candidates may carry loss terms of their own (``--forms play+eddy+excess,play+relax
--losses ""``): one command then compares the mechanisms on the frequency families.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
MNZN = os.path.join(HERE, "..", "..", "shared", "data", "MnZn_ferrite_BH.csv")
MU0 = 4e-7 * np.pi


def _write(path, rows, columns):
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(columns) + "\n")
        for r in rows:
            fh.write(",".join(f"{v:.10g}" for v in r) + "\n")


def amplitude_family(path, seed=0):
    """Four loops (25, 50, 100, 200 A/m) of a Preisach model whose pinning fields form
    two log-normal populations (half at 12 A/m, half at 60 A/m, each of spread 0.4),
    with a reversible part of its own width: B(H) sampled 160 times per loop."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR

    p = jh.Parameters(Ms=3.8e5, lambda_s=0.0, a=25.0, k=12.0, alpha=5e-5, c=0.35, E=1.0,
                      Kz=1.0, Mz=1.0, Cz=0.0)
    rng = np.random.default_rng(seed)
    rows = []
    for i, Hm in enumerate((25.0, 50.0, 100.0, 200.0)):
        drive = jh.sinusoidal_field(1.0, Hm, 0.0, samples_per_period=160)
        # two populations: the same form at two median pinning fields, averaged
        Ms = []
        for k in (12.0, 60.0):
            form = jh.PreisachJA(spread=0.4, a_rev=40.0, cells=24)
            sim = jh.simulate(p.replace(k=k), NO_ACTUATOR, drive, form, substeps=1)
            Ms.append(np.asarray(drive.observed(sim.M)))
        H = np.asarray(drive.observed(drive.H))
        B = MU0 * (H + 0.5 * (Ms[0] + Ms[1]))
        B = B + 0.002 * np.max(np.abs(B)) * rng.standard_normal(B.shape)
        rows += [(i, h, b) for h, b in zip(H, B, strict=True)]
    _write(path, rows, ["loop", "H_A_per_m", "B_T"])


#: The material of the frequency families (a soft ferrite-like loop).
FAMILY_PARAMS = dict(Ms=3.8e5, lambda_s=0.0, a=30.0, k=25.0, alpha=3e-5, c=0.4, E=1.0,
                     Kz=1.0, Mz=1.0, Cz=0.0)


def _frequency_loops(path, seed, flux_density):
    """Four loops at 50, 100, 200 and 400 Hz of one field amplitude (120 A/m), 200
    samples per period, B from ``flux_density(params, drive, f)`` (the observed period)
    plus 0.2 % noise: t, H, B with a frequency column."""
    import jaxhyst as jh

    p = jh.Parameters(**FAMILY_PARAMS)
    rng = np.random.default_rng(seed)
    rows = []
    for i, f in enumerate((50.0, 100.0, 200.0, 400.0)):
        drive = jh.sinusoidal_field(f, 120.0, 0.0, samples_per_period=200)
        B = flux_density(p, drive, f)
        B = B + 0.002 * np.max(np.abs(B)) * rng.standard_normal(B.shape)
        t = np.asarray(drive.observed(drive.t))
        H = np.asarray(drive.observed(drive.H))
        rows += [(i, f, tt - t[0], h, b) for tt, h, b in zip(t, H, B, strict=True)]
    _write(path, rows, ["loop", "frequency", "t_s", "H_A_per_m", "B_T"])


def frequency_family(path, seed=1):
    """The frequency loops (`_frequency_loops`) made by the play model with losses
    (k_e = 0.02 A/m per T/s, k_x = 0.3)."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR

    def flux_density(p, drive, f):
        sim = jh.simulate(p, NO_ACTUATOR, drive, jh.PlayJA(spread=0.7, cells=16),
                          losses=jh.Losses(0.02, 0.3), substeps=1)
        return MU0 * np.asarray(drive.observed(sim.H_hyst + sim.M))

    _frequency_loops(path, seed, flux_density)


def relaxation_family(path, seed=2, tau=1.5e-4):
    """The frequency loops (`_frequency_loops`) of the Preisach model's periodic
    magnetisation M_s(t) filtered by τ·dM/dt = M_s − M (each harmonic n of the
    fundamental f divided by 1 + j·2πnf·τ), B = μ0·(H + M)."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR

    def flux_density(p, drive, f):
        sim = jh.simulate(p, NO_ACTUATOR, drive, jh.PreisachJA(spread=0.7, cells=16),
                          substeps=1)
        Ms = np.asarray(drive.observed(sim.M))[:-1]  # (one period, without its end)
        n = np.fft.rfftfreq(Ms.shape[0], d=1.0 / Ms.shape[0])
        M = np.fft.irfft(np.fft.rfft(Ms) / (1.0 + 2j * np.pi * n * f * tau), Ms.shape[0])
        return MU0 * (np.asarray(drive.observed(drive.H)) + np.append(M, M[0]))

    _frequency_loops(path, seed, flux_density)


def run_cli(path, forms, out, extra=()):
    cmd = [sys.executable, "-m", "jaxhyst.cli", "identify", path, "--joint", "--leave-one-out",
           *(() if forms == "default" else ("--variant", forms)), "--out", out,
           "--progress", "0", *(x for x in extra if x)]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, capture_output=True, text=True)
    seconds = time.perf_counter() - t0
    if proc.returncode not in (0, 3, 4):
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}: {proc.stderr[-2000:]}")
    with open(out, encoding="utf-8") as fh:
        return json.load(fh), seconds, proc.returncode


def table(name, result, seconds, status) -> list[str]:
    held = result["leave_one_out"]
    loops = [r["loop"] for r in next(iter(held["forms"].values()))["rows"]]
    lines = [f"### {name}: kept `{held['kept']}` (exit {status}, {seconds:.0f} s)", "",
             "| form | " + " | ".join(f"loop {i}" for i in loops) + " | score |",
             "|---|" + "---|" * (len(loops) + 1)]
    for form, t in held["forms"].items():
        cells = []
        for r in t["rows"]:
            where = "extrap." if r.get("outside") else "interp."
            flag = "" if r["outcome"] == "successful" else f" ({r['outcome']})"
            how = (f"loop {r['nearest_loop']}'s fit" if form == "nearest" else
                   f"{r.get('ratio', float('nan')):.2g}× own")
            cells.append(f"{r['rms']:.3g} = {how} ({where}){flag}")
        score = "—" if t["score"] is None else f"{t['score']:.3g}"
        name = f"nearest loop's own fit ({t['form']})" if form == "nearest" else form
        lines.append(f"| {name} | " + " | ".join(cells) + f" | {score} |")
    for s in held["stopped_short"]:
        lines.append(f"\nstopped short: {s}")
    return lines + [""]


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--files", default="mnzn,amplitude,frequency")
    ap.add_argument("--forms", default="classic,energy,play,preisach",
                    help="the candidates; 'default': none named (the command's own choice)")
    ap.add_argument("--out", default=os.path.join(HERE, "bench_heldout_forms_output.md"))
    ap.add_argument("--losses", default="eddy,excess",
                    help="the loss coefficients fitted on the frequency families")
    args = ap.parse_args()
    lines = [f"# bench_heldout_forms — {time.strftime('%Y-%m-%d')}, {os.uname().machine}, "
             f"{os.cpu_count()} cores", "",
             "rms error of B (T) of each held-out loop predicted from a fit of the others; "
             "× own: over the loop's own fit (same form); row `nearest`: the baseline, "
             "each loop predicted by the nearest other loop's own fit (of the form whose "
             "fits do that best; never a fit the held-out loop shaped), a candidate too.",
             ""]
    with tempfile.TemporaryDirectory() as tmp:
        for name in args.files.split(","):
            if name == "mnzn":
                if not os.path.exists(MNZN):
                    print("skipping mnzn: ../shared/data absent")
                    continue
                path, extra = MNZN, ()
            elif name == "amplitude":
                path, extra = os.path.join(tmp, "amplitude.csv"), ()
                amplitude_family(path)
            elif name == "relaxation":
                path = os.path.join(tmp, "relaxation.csv")
                extra = ("--losses", args.losses) if args.losses else ()
                relaxation_family(path)
            else:
                path = os.path.join(tmp, "frequency.csv")
                extra = ("--losses", args.losses) if args.losses else ()
                frequency_family(path)
            result, seconds, status = run_cli(path, args.forms,
                                              os.path.join(tmp, f"{name}.json"), extra)
            lines += table(name, result, seconds, status)
            print("\n".join(lines[-8:]), flush=True)
    with open(args.out, "w", encoding="utf-8") as fh:
        fh.write("\n".join(lines) + "\n")
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
