"""The paper's studies, as functions the CLI, tests and benchmarks share.

- `table1_study`: the simulation study (Table 1, §4);
- `table3_study`: Actuator2 from 10 to 2000 Hz (Table 3, Figs 7 and 8, §5.2);
- `table2_study`: the quasi-static Actuator1 (Table 2, §5.1).

The paper's experiments (Tables 2 and 3) identify measured loops we do not have; we
reproduce them on synthetic strain with stated noise, simulated at the paper's identified
values, so that the identification can be checked against a known truth.

Table 1: noise-free displacement data of the Table 1 actuator (Actuator1, I = 0.77·sin(200πt) +
1.53 A, Table 1 truth), all ten parameters free in the Table 1 box, identified by the four
hybrids. Because three directions of the ten are not identifiable from displacement
(docs/theory.md), the table reports, next to the raw parameters (the paper's layout), the
error of the seven identifiable combinations, which is what the data can recover.
"""

from __future__ import annotations

import contextlib
import time
import warnings

import jax
import numpy as np

from jaxhyst._interrupt import stop_requested
from jaxhyst.actuator import ACTUATOR1, ACTUATOR2
from jaxhyst.drive import sinusoidal_current, sinusoidal_field
from jaxhyst.identify import (
    ParameterSpace,
    Problem,
    SamplingWarning,
    hybrid_method,
    run_hybrid,
    synthetic_problem,
)
from jaxhyst.params import NAMES, TABLE1_BOUNDS, TABLE1_TRUE, TABLE3, Bounds, Parameters
from jaxhyst.progress import NoProgressMeter, TextProgressMeter

METHODS = ("GATR1", "GALM1", "GATR2", "GALM2")

#: ``--quick``: a smaller GA on a coarser record (a minute or so, mostly compiling); the
#: paper's settings otherwise.
QUICK = {"q1": 60, "q2": 20, "T1": 3, "T2": 40, "T3": 20, "local_steps": 4}


@contextlib.contextmanager
def _same_model_data():
    """The studies' data are simulated by the model that fits them, at the same sampling
    and substeps: the simulator's own error against the exact equations (up to ~1e-4 of
    the signal at the quick studies' 40 samples per period) is common to data and fits
    and does not bias the study, so its `SamplingWarning` is not shown there."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", SamplingWarning)
        yield


def _partial(study: dict, planned: int) -> dict:
    """``study`` marked ``partial`` (and its markdown headed so) when a stop was requested
    (the command line's Ctrl-C or SIGTERM): the last run is the best point at the stop,
    and the runs after it were not made."""
    interrupted = stop_requested() or any(r.get("outcome") == "interrupted"
                                          for r in study["runs"])
    study["partial"] = bool(interrupted)
    study["planned_runs"] = planned
    if interrupted:
        study["markdown"] = (f"**PARTIAL: interrupted** — {len(study['runs'])} of {planned} "
                             "runs, the last stopped early (its best point so far).\n\n"
                             + study["markdown"])
    return study


def _meter(progress: bool, label: str, total: int):
    """The study's own meter (a line per run) and its state."""
    meter = TextProgressMeter(every=1, interval=0.0) if progress else NoProgressMeter()
    return meter, meter.init(label, total)


def combination_errors(params, truth=TABLE1_TRUE) -> float:
    """Largest relative error of the seven identifiable combinations (α̃·Ms, a, k, c,
    λs·E/Mz, Kz/Mz, Cz/Mz: the basis the identifiability report names)."""
    p, q = params.to_dict(), truth.to_dict()

    def combos(d):
        return [d["alpha"] * d["Ms"], d["a"], d["k"], d["c"], d["lambda_s"] * d["E"] / d["Mz"],
                d["Kz"] / d["Mz"], d["Cz"] / d["Mz"]]

    return max(abs(a / b - 1) for a, b in zip(combos(p), combos(q), strict=True))


def table1_study(quick: bool = False, methods=METHODS, seeds=(0,), progress: bool = False,
                 settings: dict | None = None) -> dict:
    """Run the study; returns ``{"settings", "runs": [...], "markdown"}`` where each run has
    the method, seed, identified parameters, cost, combination error, wall time and GA
    history (for the figures)."""
    spp = 50 if quick else 200
    settings = settings or (QUICK if quick else {})
    drive = sinusoidal_current(100.0, 0.77, 1.53, ACTUATOR1, samples_per_period=spp)
    with _same_model_data():
        problem = synthetic_problem(TABLE1_TRUE, drive, ACTUATOR1, TABLE1_BOUNDS)
    runs = []
    meter, state = _meter(progress, "table1", len(methods) * len(seeds))
    for method in methods:
        for seed in seeds:
            t0 = time.perf_counter()
            res = run_hybrid(problem, method, seed=seed, settings=settings,
                             progress=10 if progress else False)
            wall = time.perf_counter() - t0
            runs.append({"method": method, "seed": seed, "params": res.params.to_dict(),
                         "cost": res.cost, "max_abs_error_m": res.max_abs_error,
                         "combination_error": combination_errors(res.params),
                         "wall_time_s": wall, "evaluations": res.extra["evaluations"],
                         "local_steps": res.extra["local_steps"],
                         "history": res.extra["history"]})
            runs[-1]["outcome"] = res.result
            state = meter.step(state, len(runs), f"{method} seed {seed}: cost {res.cost:.3e}, "
                               f"combinations {runs[-1]['combination_error']:.1e}, "
                               f"{wall:.1f} s")
            if stop_requested():
                break
        if stop_requested():
            break
    planned = len(methods) * len(seeds)
    meter.close(state, f"{len(runs)} runs" + ("" if not stop_requested() else
                                              f" of {planned}: interrupted"))
    truth = TABLE1_TRUE.to_dict()
    head = "| θ | true | " + " | ".join(f"{r['method']} s{r['seed']}" for r in runs) + " |"
    lines = [head, "|" + "---|" * (len(runs) + 2)]
    for n in NAMES:
        lines.append(f"| {n} | {truth[n]:.5g} | "
                     + " | ".join(f"{r['params'][n]:.5g}" for r in runs) + " |")
    for label, key, fmt in (("normalised cost", "cost", "{:.1e}"),
                            ("max rel. error, 7 identifiable combinations",
                             "combination_error", "{:.1e}"),
                            ("max abs error (m)", "max_abs_error_m", "{:.2e}"),
                            ("wall time (s)", "wall_time_s", "{:.1f}")):
        lines.append(f"| {label} | | " + " | ".join(fmt.format(r[key]) for r in runs) + " |")
    return _partial({"settings": hybrid_method("GATR1", settings).settings(),
                     "samples_per_period": spp, "runs": runs,
                     "markdown": "\n".join(lines), "problem": problem}, planned)


# -- the experiments (Tables 2 and 3) ---------------------------------------------------------

#: The seven combinations strain data determine (the null directions of docs/theory.md
#: leave α̃·Ms, λs·E/Mz, Kz/Mz, Cz/Mz and a, k, c): label → exponents.
COMBINATIONS = {
    "alpha*Ms": {"alpha": 1, "Ms": 1}, "a": {"a": 1}, "k": {"k": 1}, "c": {"c": 1},
    "lambda_s*E/Mz": {"lambda_s": 1, "E": 1, "Mz": -1}, "Kz/Mz": {"Kz": 1, "Mz": -1},
    "Cz/Mz": {"Cz": 1, "Mz": -1},
}

TABLE3_FREQUENCIES = (10, 800, 1000, 1250, 2000)
#: Table 3's drive: H = Hb + 8·sin(2πft) kA/m on Actuator2 (Hb = 16 kA/m).
TABLE3_FIELD_AMPLITUDE = 8e3

#: Table 2 (§5.1): the quasi-static Actuator1 values GATR1 identified. The paper gives no
#: Mz, Cz there (a 2 Hz drive barely depends on them); Table 1's are used to simulate.
TABLE2_TRUE = Parameters(Ms=7.60e5, lambda_s=1.10e-3, a=1925.0, k=7545.0, alpha=-0.0157,
                         c=0.1003, E=2.6e10, Kz=4.9e7, Mz=0.55, Cz=4300.0)
#: Table 2's drive: I = 1.2·sin(4πt) A, Hb = 0 (the paper's current is not stated; 1.2 A
#: gives ±58 kA/m, a major loop of Terfenol-D).
TABLE2_CURRENT = (2.0, 1.2, 0.0)  # frequency (Hz), amplitude (A), offset (A)

#: Relative noise of the synthetic strain: σ = NOISE · max|ε|.
NOISE = 1e-3

#: ``--quick`` for the experiments: a small GA on 40 samples per period.
QUICK_EXPERIMENT = {"q1": 40, "q2": 12, "T1": 2, "T2": 15, "T3": 20, "local_steps": 4,
                    "check_steps": 200}


def box_around(truth: Parameters, rel: float = 0.5) -> Bounds:
    """The search box truth·(1 ± rel) for every parameter (c kept in [0, 1]); the paper's
    Table 1 box is of this kind (±50 %)."""
    x = np.asarray(truth.to_array(), dtype=float)
    lo, hi = np.minimum(x * (1 - rel), x * (1 + rel)), np.maximum(x * (1 - rel), x * (1 + rel))
    i = NAMES.index("c")
    hi[i] = min(hi[i], 1.0)
    return Bounds(Parameters.from_array(lo), Parameters.from_array(hi))


def noisy_strain_problem(truth: Parameters, actuator, drive, noise: float, key) -> Problem:
    """Strain simulated at ``truth`` plus white noise σ = noise·max|ε| (declared, so the
    cost is a χ² and the report's intervals use it); all ten parameters free in
    `box_around` the truth."""
    with _same_model_data():
        clean = synthetic_problem(truth, drive, actuator, TABLE1_BOUNDS, output="strain")
    sigma = noise * float(clean.scale)
    data = np.asarray(clean.data) + sigma * np.asarray(
        jax.random.normal(key, clean.data.shape))
    return Problem(data, drive, actuator, ParameterSpace(box_around(truth)),
                   output="strain", sigma=sigma)


def combination_check(report, truth: Parameters) -> dict:
    """For each of `COMBINATIONS`: identified value, standard error, 95 % interval, the
    truth and whether the interval holds it (None when not identifiable)."""
    q = truth.to_dict()
    out = {}
    for label, exps in COMBINATIONS.items():
        c = report.combination(exps)
        true = float(np.prod([np.sign(q[n]) ** p * abs(q[n]) ** p for n, p in exps.items()]))
        lo, hi = c["interval"] if c["interval"] is not None else (None, None)
        out[label] = {"value": c["value"], "std_error": c["std_error"], "interval": c["interval"],
                      "truth": true, "identifiable": c["identifiable"],
                      "covers": None if lo is None else bool(lo <= true <= hi)}
    return out


def _experiment(label, truth, actuator, drive, noise, seed, settings, progress):
    from jaxhyst.fit import run_hybrid as run_with_report

    problem = noisy_strain_problem(truth, actuator, drive, noise, jax.random.PRNGKey(seed))
    res = run_with_report(problem, "GATR1", seed=seed, settings=settings,
                          progress=10 if progress else False)
    row = {"label": label, "seed": seed, "params": res.params.to_dict(), "cost": res.cost,
           "outcome": res.result, "wall_time_s": res.wall_time, "n_data": problem.data.size,
           "sigma": float(problem.sigma), "rms_error": res.rms_error,
           "combinations": combination_check(res.report, truth) if res.report else None,
           "poorly_determined": res.report.poorly_determined() if res.report else None}
    return row, problem


def _row_line(row) -> str:
    return (f"{row['label']}: GATR1 seed {row['seed']}: χ² {row['cost']:.1f} for "
            f"{row['n_data']} samples, {row['outcome']}, {row['wall_time_s']:.1f} s")


def _experiment_markdown(rows) -> str:
    head = "| combination | " + " | ".join(
        f"{r['label']}: truth | identified ± 1.96·SE" for r in rows) + " |"
    lines = [head, "|---|" + "---|---|" * len(rows)]
    for label in COMBINATIONS:
        cells = []
        for r in rows:
            c = r["combinations"][label]
            if c["identifiable"]:
                ci = (c["interval"][1] - c["interval"][0]) / 2
                mark = "" if c["covers"] else " ✗"
                cells.append(f"{c['truth']:.5g} | {c['value']:.5g} ± {ci:.2g}{mark}")
            else:
                cells.append(f"{c['truth']:.5g} | not identifiable")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines.append("| outcome | " + " | ".join(f" | {r['outcome']}" for r in rows) + " |")
    lines.append("| χ² / samples | " + " | ".join(
        f" | {r['cost']:.0f} / {r['n_data']}" for r in rows) + " |")
    lines.append("| not determined (rel. SE > 50 %) | " + " | ".join(
        f" | {', '.join(undetermined(r)) or '—'}" for r in rows) + " |")
    return "\n".join(lines)


def undetermined(row, max_rel_se: float = 0.5) -> list[str]:
    """The combinations of a run that its data do not determine: not identifiable, or a
    relative standard error above ``max_rel_se``."""
    out = []
    for label, c in row["combinations"].items():
        if not c["identifiable"] or c["std_error"] > max_rel_se * abs(c["value"]):
            out.append(label)
    return out


def table3_study(quick: bool = False, frequencies=TABLE3_FREQUENCIES, seed: int = 0,
                 noise: float = NOISE, progress: bool = False,
                 settings: dict | None = None) -> dict:
    """Table 3 (§5.2): Actuator2 under Hb = 16 kA/m and H_AC = 8·sin(2πft) kA/m at each
    frequency, simulated at that column of Table 3, strain plus noise σ = noise·max|ε|,
    identified by GATR1 with all ten parameters free in a ±50 % box. Returns the runs
    (identified parameters, χ², the seven identifiable combinations with their 95 %
    intervals next to the truth), the markdown table, and the loops and frequency
    response of Figs 7 and 8. Every frequency's problem has the same structure, so the
    GA compiles once."""
    spp = 40 if quick else 200
    settings = settings or (QUICK_EXPERIMENT if quick else {})
    rows, loops = [], {}
    meter, state = _meter(progress, "table3", len(frequencies))
    for f in frequencies:
        if f not in TABLE3:
            raise ValueError(f"Table 3 has frequencies {sorted(TABLE3)} Hz; got {f}.")
        drive = sinusoidal_field(f, TABLE3_FIELD_AMPLITUDE, ACTUATOR2.Hb,
                                 samples_per_period=spp)
        row, problem = _experiment(f"{f} Hz", TABLE3[f], ACTUATOR2, drive, noise, seed,
                                   settings, progress)
        row["frequency_hz"] = f
        rows.append(row)
        state = meter.step(state, len(rows), _row_line(row))

        from jaxhyst.model.simulate import simulate

        with _same_model_data():
            sim = simulate(TABLE3[f], ACTUATOR2, drive)
        loops[f] = {k: np.asarray(sim.observed(k)).tolist() for k in ("H", "lam", "strain")}
        loops[f]["data_strain"] = np.asarray(problem.data).tolist()
        if stop_requested():
            break
    meter.close(state, f"{len(rows)} frequencies" + (": interrupted" if stop_requested()
                                                       else ""))
    return _partial({"settings": hybrid_method("GATR1", settings).settings(),
                     "samples_per_period": spp, "noise": noise, "runs": rows, "loops": loops,
                     "markdown": _experiment_markdown(rows)}, len(frequencies))


def table2_study(quick: bool = False, seeds=(0, 1, 2), noise: float = NOISE,
                 progress: bool = False, settings: dict | None = None) -> dict:
    """Table 2 (§5.1): the quasi-static Actuator1 (Hb = 0, 2 Hz, `TABLE2_CURRENT`),
    strain simulated at `TABLE2_TRUE` plus noise, identified by GATR1 three times (one
    noise realisation and GA seed per run, as the paper's repeated runs). Shows what the
    runs agree on (the identifiable combinations) and that Mz and Cz are not determined at
    2 Hz (their combinations' intervals span orders of magnitude). Along those directions
    the cost is flat to the noise, so the final convergence check typically ends at its
    step limit (outcome ``max_steps_reached``) with χ² already at the noise level."""
    spp = 40 if quick else 200
    settings = settings or (QUICK_EXPERIMENT if quick else {})
    meter, state = _meter(progress, "table2", len(seeds))
    f, amp, offset = TABLE2_CURRENT
    drive = sinusoidal_current(f, amp, offset, ACTUATOR1, samples_per_period=spp)
    rows = []
    for seed in seeds:
        row, _ = _experiment(f"run {seed}", TABLE2_TRUE, ACTUATOR1, drive, noise, seed,
                             settings, progress)
        rows.append(row)
        state = meter.step(state, len(rows), _row_line(row))
        if stop_requested():
            break
    meter.close(state, f"{len(rows)} runs" + (": interrupted" if stop_requested() else ""))
    spread = {}
    for n in NAMES:
        v = np.array([r["params"][n] for r in rows])
        spread[n] = float(np.ptp(v) / abs(np.mean(v)))
    return _partial({"settings": hybrid_method("GATR1", settings).settings(),
                     "samples_per_period": spp, "noise": noise, "runs": rows,
                     "relative_spread": spread, "markdown": _experiment_markdown(rows)},
                    len(seeds))
