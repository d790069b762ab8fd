"""``jaxhyst predict``: what a fitted model predicts for other loops or conditions, with
its error against their data when they have data."""

from __future__ import annotations

import os

from .models import is_model_file
from .options import COUNT, FINITE, POSITIVE
from .problems import load_result
from .spec import CLIError, check_outputs, loop_field, print_result, select_loops, warn


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "predict", help="predict other loops or conditions from an identify result",
        description="Predict the loops of a data file (default: the fitted data) from a "
        "result of 'jaxhyst identify --out': a condition model (--vary) is evaluated at "
        "each loop's frequency, temperature (the file's columns, or --frequency and "
        "--temperature) and peak field; shared parameters are used as fitted. Writes the "
        "prediction (and the error where the file has data).")
    parser.add_argument("result", help="result JSON from identify --out, or a saved model "
                        "(.eqx, identify --save-model: then give the data file)")
    parser.add_argument("data", nargs="?", help="data file of the loops to predict "
                        "(columns as for identify; default: the fitted data)")
    parser.add_argument("--loop", type=COUNT, action="append",
                        help="predict only this loop of the file (repeatable)")
    parser.add_argument("--frequency", type=POSITIVE, help="the loops' frequency, Hz "
                        "(replaces the file's frequency column)")
    parser.add_argument("--temperature", type=FINITE, help="the loops' temperature, °C "
                        "(replaces the file's temperature column)")
    parser.add_argument("--amplitude", type=POSITIVE, help="the loops' peak field, A/m: "
                        "each loop's field scaled to it (the loop's shape kept); the file's "
                        "data, measured at its own amplitude, are then not compared")
    parser.add_argument("--out", help="write the prediction here (CSV: loop, H, predicted, "
                        "data, error; SI units)")
    parser.add_argument("--png", help="draw the predicted loops (with the data they are "
                        "compared with) here: .png, .pdf or .svg")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object on stdout")
    parser.set_defaults(func=run)


def run(args) -> int:
    import warnings

    import numpy as np

    import jaxhyst as jh
    from jaxhyst.identify.conditions import ConditionWarning
    from jaxhyst.io import read_loops, write_columns_csv

    from .predictions import error_summary, predict_loops, records_of

    if is_model_file(args.result):  # a saved model (identify --save-model)
        from .predict_model import run_model

        return run_model(args)
    check_outputs(args)
    from jaxhyst.drive import MAX_FIELD

    if args.amplitude is not None and args.amplitude >= MAX_FIELD:
        raise CLIError(f"--amplitude {args.amplitude:g}: a peak field of {MAX_FIELD:g} A/m or "
                       "more is no laboratory field; give the peak field in A/m.")
    saved, spec, fitted, params = load_result(args.result)
    if isinstance(records_of(fitted), jh.FluxProblem):
        raise CLIError(f"{args.result} is a B-driven fit (--driven-by B): predict reads "
                       "H-driven fits; simulate its saved model (identify --save-model) with "
                       "'jaxhyst simulate --model FILE --flux-amplitude B --frequency F'.")
    source = args.data or spec["data"]
    loops = select_loops(read_loops(source, spec.get("columns")), args.loop, source)
    overrides = {"frequency": args.frequency, "temperature": args.temperature}
    varies = fitted.form.features if isinstance(fitted, jh.ConditionProblem) else ()
    for name, feature in (("frequency", "log_f"), ("temperature", "T"),
                          ("amplitude", "log_amplitude")):
        if vars(args)[name] is not None and feature not in varies:
            warn(args, f"--{name}: the fitted model does not vary with the {name} "
                 "(identify --vary); only the loop's field changes." if name == "amplitude"
                 else f"--{name}: the fitted model does not vary with the {name} "
                 "(identify --vary); it has no effect on the prediction.")
    actuator = records_of(fitted).actuator
    elsewhere = _elsewhere(loops, overrides, args.amplitude)
    if args.amplitude is not None:
        loops = [_scaled(lp, args.amplitude, actuator, source) for lp in loops]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConditionWarning)
        predictions = predict_loops(spec, fitted, params, loops, overrides, source)
    for w in caught:
        if issubclass(w.category, ConditionWarning):
            warn(args, str(w.message))
    rows, columns = [], {"loop": [], "H_A_per_m": [], "predicted": [], "data": [],
                         "error": []}
    curves = []
    for lp, (pred, data) in zip(loops, predictions, strict=True):
        H = np.asarray(loop_field(lp, actuator, source))
        row = {"loop": lp.index, "samples": int(pred.shape[0])}
        if elsewhere.get(lp.index):
            row["not_compared"] = elsewhere[lp.index]
            data = None
        if data is not None:
            row.update(error_summary(pred, data))
        curves.append((f"loop {lp.index}", H[-pred.shape[0]:], pred, data))
        rows.append(row)
        columns["loop"].append(np.full(pred.shape, lp.index, dtype=float))
        columns["H_A_per_m"].append(H[-pred.shape[0]:])
        columns["predicted"].append(pred)
        nan = np.full(pred.shape, np.nan)
        columns["data"].append(nan if data is None else data)
        columns["error"].append(nan if data is None else pred - data)
    expected = _expected_error(saved)
    fitted_range = _fitted_range(spec, records_of(fitted).actuator)
    for lp, row in zip(loops, rows, strict=True):
        row["extrapolation"] = _outside({**spec, "data": source}, lp,
                                        records_of(fitted).actuator, fitted_range, overrides)
        if expected is not None:
            row["expected_relative_error"] = expected["extrapolated" if row["extrapolation"]
                                                      else "interpolated"]
    if args.png:
        from jaxhyst.plots import plot_predictions

        records = records_of(fitted)
        plot_predictions(curves, records.output if records.output != "mixed"
                         else records.outputs[0], args.png,
                         title=f"predicted by {os.path.basename(args.result)}")
    if args.out:
        write_columns_csv(args.out, {k: np.concatenate(v) for k, v in columns.items()})
    text = [f"prediction of {len(rows)} loop(s) of {os.path.basename(source)} from "
            f"{os.path.basename(args.result)}"]
    for r in rows:
        err = (f": rms error {r['rms']:.4g} (max {r['max_abs']:.4g}, "
               f"{100 * r['rms'] / r['data_scale']:.2g} % of max|data|)") if "rms" in r else \
            (f" (not compared with the file's data: {r['not_compared']})"
             if "not_compared" in r else " (no data to compare)")
        where = ("; an extrapolation beyond the fitted loops' " + r["extrapolation"]
                 if r["extrapolation"] else "; within the fitted loops' conditions")
        exp = r.get("expected_relative_error")
        hint = (f"; expected from the leave-one-out folds: {100 * exp:.2g} % of max|data|"
                if exp is not None else "")
        text.append(f"  loop {r['loop']}{err}{where}{hint}")
    text += [f"  wrote {f}" for f in (args.out, args.png) if f]
    print_result(args, {"loops": rows, "out": args.out, "png": args.png}, "\n".join(text))
    return 0



def _elsewhere(loops, overrides, amplitude) -> dict:
    """{loop index: why its data are not those of the prediction} for the loops whose
    file conditions the options replace with other values."""
    out = {}
    units = {"frequency": "Hz", "temperature": "°C"}
    for lp in loops:
        why = [f"measured at {name} {lp.conditions[name]:g} {units[name]}, predicted at "
               f"{value:g} {units[name]}" for name, value in overrides.items()
               if value is not None and lp.conditions.get(name) is not None
               and abs(lp.conditions[name] - value) > 1e-9 * max(1.0, abs(value))]
        if amplitude is not None:
            why.append(f"its field scaled to the peak {amplitude:g} A/m")
        if why:
            out[lp.index] = "; ".join(why)
    return out


def _scaled(lp, amplitude, actuator, source):
    """The loop ``lp`` with its field scaled to the peak ``amplitude`` (A/m), no data."""
    import dataclasses

    import numpy as np

    H = np.asarray(loop_field(lp, actuator, source), dtype=np.float64)
    peak = float(np.max(np.abs(H)))
    if peak <= 0:
        raise CLIError(f"--amplitude: loop {lp.index} of {source} has no field to scale.")
    return dataclasses.replace(lp, H=H * (amplitude / peak), I=None, signals={})


def _expected_error(saved) -> dict | None:
    """The error a prediction may be expected to have, from the result's leave-one-out
    folds of the kept form: the largest held-out rms relative to the loop's size among
    the interpolated folds (a loop inside the others' conditions) and among all folds
    (an extrapolation); None without folds."""
    held = saved.get("leave_one_out")
    if not isinstance(held, dict) or not held.get("kept"):
        return None
    rows = held["forms"][held["kept"]]["rows"]
    if not rows:
        return None
    rel = [r["rms"] / r["data_scale"] for r in rows]
    inside = [x for x, r in zip(rel, rows, strict=True) if not r.get("outside")]
    return {"interpolated": max(inside) if inside else max(rel), "extrapolated": max(rel)}


def _fitted_range(spec, actuator) -> dict:
    """The range of each condition (amplitude, frequency, temperature) of the fitted
    loops."""
    from jaxhyst.io import read_loops

    from .problems import loop_conditions

    loops = read_loops(spec["data"], spec.get("columns"))
    if spec.get("loop") is not None and not spec.get("joint"):
        loops = [lp for lp in loops if lp.index == spec["loop"]] or loops
    c = loop_conditions(spec, loops, actuator)
    out = {"amplitude": (min(c.amplitude), max(c.amplitude))}
    for name in ("frequency", "temperature"):
        values = getattr(c, name)
        if values is not None:
            out[name] = (min(values), max(values))
    return out


def _outside(spec, loop, actuator, fitted_range, overrides) -> str:
    """'' if ``loop`` lies within the fitted loops' conditions (1 % of slack), else
    which condition lies beyond them and how far."""
    from .problems import loop_conditions

    c = loop_conditions(spec, [loop], actuator, overrides)
    units = {"amplitude": "A/m", "frequency": "Hz", "temperature": "°C"}
    for name, (lo, hi) in fitted_range.items():
        values = getattr(c, name)
        if values is None:
            continue
        v = values[0]
        slack = 0.01 * max(abs(lo), abs(hi), 1e-300)
        if v < lo - slack or v > hi + slack:
            return f"{name} ({v:.4g} {units[name]}; fitted {lo:.4g}–{hi:.4g})"
    return ""
