"""``jaxhyst predict``: what a fitted model predicts for other loops or conditions, with
its error against their data when they have data."""

from __future__ import annotations

import os

from .models import is_model_file
from .options import COUNT, FINITE, POSITIVE
from .problems import load_result, loop_conditions
from .spec import (
    CLIError,
    check_outputs,
    loop_field,
    print_result,
    read_data,
    select_loops,
    warn,
)


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "predict", help="predict other loops or conditions from an identify result",
        description="Predict the loops of a data file (default: the fitted data) from a "
        "result of 'jaxhyst identify --out': a condition model (--vary) is evaluated at "
        "each loop's frequency, temperature (the file's columns, or --frequency and "
        "--temperature) and peak field; shared parameters are used as fitted. A fit driven "
        "by B (--driven-by B) predicts each loop's H from its B(t) (peak B the amplitude). "
        "Writes the prediction (and the error where the file has data).")
    parser.add_argument("result", help="result JSON from identify --out, or a saved model "
                        "(.eqx, identify --save-model: then give the data file)")
    parser.add_argument("data", nargs="?", help="data file of the loops to predict "
                        "(columns as for identify; default: the fitted data)")
    parser.add_argument("--loop", type=COUNT, action="append",
                        help="predict only this loop of the file (repeatable)")
    parser.add_argument("--frequency", type=POSITIVE, help="the loops' frequency, Hz "
                        "(replaces the file's frequency column; a rate-dependent model runs "
                        "each loop's waveform at it, its times scaled)")
    parser.add_argument("--temperature", type=FINITE, help="the loops' temperature, °C "
                        "(replaces the file's temperature column)")
    parser.add_argument("--amplitude", type=POSITIVE, help="the loops' peak field, A/m: "
                        "each loop's field scaled to it (the loop's shape kept); the file's "
                        "data, measured at its own amplitude, are then not compared")
    parser.add_argument("--out", help="write the prediction here (CSV: loop, H, predicted, "
                        "data, error; SI units; B in place of H for a B-driven fit)")
    parser.add_argument("--png", help="draw the predicted loops (with the data they are "
                        "compared with) here: .png, .pdf or .svg")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object on stdout")
    parser.set_defaults(func=run)


def run(args) -> int:
    import warnings

    import numpy as np

    import jaxhyst as jh
    from jaxhyst.drive import MAX_FIELD
    from jaxhyst.identify.conditions import ConditionWarning
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import write_columns_csv

    from .predictions import (
        at_frequency,
        error_summary,
        expect,
        expected_error,
        fitted_range,
        flux_curves,
        nearest_loop,
        nearest_of,
        outside,
        predict_loops,
        prediction_line,
        records_of,
        refuse_amplitude_by_flux,
        scaled_loop,
    )

    if args.amplitude is not None and args.amplitude >= MAX_FIELD:
        raise CLIError(f"--amplitude {args.amplitude:g}: a peak field of {MAX_FIELD:g} A/m or "
                       "more is no laboratory field; give the peak field in A/m.")
    if is_model_file(args.result):  # a saved model (identify --save-model)
        from .predict_model import run_model

        return run_model(args)
    check_outputs(args)
    saved, spec, fitted, params = load_result(args.result)
    records = records_of(fitted)
    by_flux = isinstance(records, jh.FluxProblem)  # (H predicted from B(t))
    # (what is plotted and compared: B-driven, the field; else the fitted signal's kind)
    kind = "flux_density" if by_flux else records.output if records.output != "mixed" \
        else records.outputs[0]
    if by_flux:
        refuse_amplitude_by_flux(args.amplitude, args.result)
    source = args.data or spec["data"]
    loops = select_loops(read_data(source, spec.get("columns"), drive=not by_flux), args.loop,
                         source)
    overrides = {"frequency": args.frequency, "temperature": args.temperature}
    nearest = nearest_of(spec)  # (a fit that kept the nearest-condition baseline)
    varies = fitted.form.features if isinstance(fitted, jh.ConditionProblem) else \
        nearest.features if nearest is not None else ()
    rate = bool(spec.get("losses"))  # (a rate-dependent model: the frequency runs the loop)
    for name, feature in (("frequency", "log_f"), ("temperature", "T"),
                          ("amplitude", "log_amplitude")):
        if vars(args)[name] is not None and feature not in varies and not (
                rate and name == "frequency"):
            warn(args, f"--{name}: the fitted model does not vary with the {name} "
                 "(identify --vary); only the loop's field changes." if name == "amplitude"
                 else f"--{name}: the fitted model does not vary with the {name} "
                 "(identify --vary); it has no effect on the prediction.")
    actuator = getattr(records, "actuator", None)  # (None: driven by B)
    elsewhere = _elsewhere(loops, overrides, args.amplitude)
    if args.amplitude is not None:
        loops = [scaled_loop(lp, args.amplitude, actuator, source) for lp in loops]
    if rate and args.frequency is not None:
        loops = [at_frequency(lp, args.frequency, source, by_flux) for lp in loops]
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConditionWarning)
        predictions = predict_loops(spec, fitted, params, loops, overrides, source)
    for w in caught:
        if issubclass(w.category, ConditionWarning):
            warn(args, str(w.message))
    x_column = "B_T" if by_flux else "H_A_per_m"  # (driven by B: H predicted, from B)
    unit = "A/m" if by_flux else output_kind(kind).unit
    rows, curves = [], []
    columns = {k: [] for k in ("loop", x_column, "predicted", "data", "error")}
    for lp, (pred, data) in zip(loops, predictions, strict=True):
        H = np.asarray(lp.signals["B"] if by_flux else loop_field(lp, actuator, source))
        row = {"loop": lp.index, "samples": int(pred.shape[0])}
        if elsewhere.get(lp.index):
            row["not_compared"] = elsewhere[lp.index]
            data = None
        if data is not None:
            row.update(error_summary(pred, data, unit))
        curves.append((f"loop {lp.index}", H[-pred.shape[0]:], pred, data))
        rows.append(row)
        columns["loop"].append(np.full(pred.shape, lp.index, dtype=float))
        columns[x_column].append(H[-pred.shape[0]:])
        columns["predicted"].append(pred)
        nan = np.full(pred.shape, np.nan)
        columns["data"].append(nan if data is None else data)
        columns["error"].append(nan if data is None else pred - data)
    expected = expected_error(saved)
    fitted_conditions = fitted_range(spec, actuator)
    for lp, row in zip(loops, rows, strict=True):
        row["extrapolation"], far = outside({**spec, "data": source}, lp,
                                            actuator, fitted_conditions,
                                            overrides)
        expect(row, far, expected)
        if nearest is not None:  # (which fitted loop's set predicted it)
            row["by_fitted_loop"] = nearest_loop(spec, nearest, loop_conditions(
                {**spec, "data": source}, [lp], actuator, overrides))
    if args.png:
        from jaxhyst.plots import plot_predictions

        plot_predictions(flux_curves(curves) if by_flux else curves, kind, args.png,
                         title=f"predicted by {os.path.basename(args.result)}")
    if args.out:
        write_columns_csv(args.out, {k: np.concatenate(v) for k, v in columns.items()})
    text = [f"prediction of {len(rows)} loop(s) of {os.path.basename(source)} from "
            f"{os.path.basename(args.result)}"]
    text += [prediction_line(r) for r in rows]
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
