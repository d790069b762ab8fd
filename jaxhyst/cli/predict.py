"""``jaxhyst predict``: what a fitted model predicts for other loops or conditions, with
its error against their data when they have data."""

from __future__ import annotations

import os

from .options import COUNT, FINITE, POSITIVE
from .spec import CLIError, check_outputs, load_result, loop_field, print_result, warn


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "predict", help="predict other loops or conditions from an identify result",
        description="Predict the loops of a data file (default: the fitted data) from a "
        "result of 'jaxhyst identify --out': a condition model (--vary) is evaluated at "
        "each loop's frequency, temperature (the file's columns, or --frequency and "
        "--temperature) and peak field; shared parameters are used as fitted. Writes the "
        "prediction (and the error where the file has data).")
    parser.add_argument("result", help="result JSON from identify --out")
    parser.add_argument("data", nargs="?", help="data file of the loops to predict "
                        "(columns as for identify; default: the fitted data)")
    parser.add_argument("--loop", type=COUNT, action="append",
                        help="predict only this loop of the file (repeatable)")
    parser.add_argument("--frequency", type=POSITIVE, help="the loops' frequency, Hz "
                        "(replaces the file's frequency column)")
    parser.add_argument("--temperature", type=FINITE, help="the loops' temperature, °C "
                        "(replaces the file's temperature column)")
    parser.add_argument("--out", help="write the prediction here (CSV: loop, H, predicted, "
                        "data, error; SI units)")
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

    check_outputs(args)
    _, spec, fitted, params = load_result(args.result)
    source = args.data or spec["data"]
    loops = read_loops(source, spec.get("columns"))
    if args.loop:
        ids = [lp.index for lp in loops]
        missing = [i for i in args.loop if i not in ids]
        if missing:
            raise CLIError(f"--loop {missing}: {source} holds loops {ids}.")
        loops = [lp for lp in loops if lp.index in args.loop]
    overrides = {"frequency": args.frequency, "temperature": args.temperature}
    varies = fitted.form.features if isinstance(fitted, jh.ConditionProblem) else ()
    for name, feature in (("frequency", "log_f"), ("temperature", "T")):
        if overrides[name] is not None and feature not in varies:
            warn(args, f"--{name}: the fitted model does not vary with the {name} "
                 "(identify --vary); it has no effect on the prediction.")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", ConditionWarning)
        predictions = predict_loops(spec, fitted, params, loops, overrides)
    for w in caught:
        if issubclass(w.category, ConditionWarning):
            warn(args, str(w.message))
    rows, columns = [], {"loop": [], "H_A_per_m": [], "predicted": [], "data": [],
                         "error": []}
    for lp, (pred, data) in zip(loops, predictions, strict=True):
        H = np.asarray(loop_field(lp, records_of(fitted).actuator, source))
        row = {"loop": lp.index, "samples": int(pred.shape[0])}
        if data is not None:
            row.update(error_summary(pred, data))
        rows.append(row)
        columns["loop"].append(np.full(pred.shape, lp.index, dtype=float))
        columns["H_A_per_m"].append(H[-pred.shape[0]:])
        columns["predicted"].append(pred)
        nan = np.full(pred.shape, np.nan)
        columns["data"].append(nan if data is None else data)
        columns["error"].append(nan if data is None else pred - data)
    if args.out:
        write_columns_csv(args.out, {k: np.concatenate(v) for k, v in columns.items()})
    text = [f"prediction of {len(rows)} loop(s) of {os.path.basename(source)} from "
            f"{os.path.basename(args.result)}"]
    for r in rows:
        err = (f": rms error {r['rms']:.4g} (max {r['max_abs']:.4g}, "
               f"{100 * r['rms'] / r['data_scale']:.2g} % of max|data|)") if "rms" in r else \
            " (no data to compare)"
        text.append(f"  loop {r['loop']}{err}")
    if args.out:
        text.append(f"  wrote {args.out}")
    print_result(args, {"loops": rows, "out": args.out}, "\n".join(text))
    return 0

