"""``jaxhyst predict MODEL.eqx DATA``: a saved model (``identify --save-model``) predicts
the loops of a data file, each driven by its own field — a condition law evaluated at
each loop's frequency and temperature (the file's columns, or ``--frequency`` and
``--temperature``) and peak field — with its error against the loop's signal; a model
fitted driven by B, each loop by its B(t) (peak B the amplitude), its H predicted."""

from __future__ import annotations

from .spec import (
    CLIError,
    check_outputs,
    loop_drive,
    loop_field,
    print_result,
    read_data,
    select_loops,
    signal_column,
    signal_columns,
)


def run_model(args) -> int:
    """``predict`` with a model file (see the module docstring)."""
    import os

    import numpy as np

    import jaxhyst as jh
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS, write_columns_csv
    from jaxhyst.saved import read_header

    from .models import model_at, read_model
    from .predictions import (
        at_frequency,
        error_summary,
        expect,
        flux_curves,
        flux_drive,
        nearest_loop,
        outside,
        prediction_line,
        refuse_amplitude_by_flux,
        scaled_loop,
    )
    from .spec import flux_of

    check_outputs(args)
    if not args.data:
        raise CLIError(f"{args.result} is a saved model: give the data file whose loops it "
                       "predicts (predict MODEL.eqx DATA).")
    saved = read_model(args.result)
    meta = read_header(args.result).get("meta", {})
    problem = meta.get("problem")  # (the spec it was fitted with)
    by_flux = meta.get("output") == "field" or (problem or {}).get("driven_by") == "B"
    if by_flux:
        refuse_amplitude_by_flux(args.amplitude, args.result)
    fitted_column = (problem or {}).get("output") or signal_column(meta.get("output"))
    law = saved.law.features if saved.law is not None else ()
    rate = saved.losses is not None  # (rate dependent: the frequency runs the loop)
    for name, feature in (("frequency", "log_f"), ("temperature", "T")):
        if vars(args)[name] is not None and feature not in law and not (
                rate and name == "frequency"):
            raise CLIError(f"--{name}: the model in {args.result} does not vary with the "
                           f"{name}; it would have no effect.")
    loops = select_loops(read_data(args.data, None, drive=not by_flux), args.loop, args.data)
    measured = {lp.index: lp.conditions.get("frequency") for lp in loops}
    if rate and args.frequency is not None:  # (the same waveforms, faster or slower)
        loops = [at_frequency(lp, args.frequency, args.data, by_flux) for lp in loops]
    spec = {"data": args.data, "run_in_periods": 1}
    fitted, expected = _fitted_conditions(args.result, meta, saved.actuator)
    if by_flux:  # (its amplitude the peak flux density; a model saved before that was
        # recorded in teslas has no fitted range to compare with)
        spec = {**spec, "driven_by": "B",
                "run_in_periods": (problem or {}).get("run_in_periods") or 1}
        fitted = fitted if meta.get("amplitude_unit") == "T" else None
    overrides = {"frequency": args.frequency, "temperature": args.temperature}
    x_column = "B_T" if by_flux else "H_A_per_m"  # (driven by B: H predicted, from B)
    rows, curves = [], []
    columns = {k: [] for k in ("loop", x_column, "predicted", "data", "error")}
    for lp in loops:
        if by_flux:  # (its B(t) drives the model; H predicted, compared with its H)
            kind = None
            data = None if lp.H is None else np.asarray(lp.H, dtype=np.float64)
            H = np.asarray(flux_of(lp, args.data), dtype=np.float64)  # (the driving B)
        else:
            out, compared = _observed(spec, lp, fitted_column, args.result)
            kind = output_kind(SIGNAL_OUTPUTS[out])
            data = np.asarray(lp.signals[out], dtype=np.float64) if compared else None
            if args.amplitude is not None:  # (its field scaled: nothing measured to compare)
                lp, data = scaled_loop(lp, args.amplitude, saved.actuator, args.data), None
            H = np.asarray(loop_field(lp, saved.actuator, args.data), dtype=np.float64)
        f = args.frequency if args.frequency is not None else lp.conditions.get("frequency")
        T = args.temperature if args.temperature is not None else \
            lp.conditions.get("temperature")
        model = model_at(args, saved, args.result,
                         frequency=f if "log_f" in law else None,
                         temperature=T if "T" in law else None,
                         amplitude=float(np.max(np.abs(H))),
                         **({"amplitude_option": "its peak B", "amplitude_unit": "T"}
                            if by_flux else {}))
        if by_flux:
            drive = flux_drive(spec, lp, args.data)
            pred = np.asarray(model.simulate_flux(drive).H)[drive.run_in:]
        else:
            sim = model.simulate(loop_drive(spec, lp, out, model.actuator))
            pred = np.asarray(kind.of(sim))[sim.run_in:]
        row = {"loop": lp.index, "output": "field" if by_flux else kind.name,
               "samples": int(pred.shape[0]),
               "extrapolation": None}
        if data is not None:
            row.update(error_summary(pred, data, "A/m" if by_flux else kind.unit))
        elif args.amplitude is not None:
            row["not_compared"] = f"its field scaled to the peak {args.amplitude:g} A/m"
        elif rate and args.frequency is not None and data is None:
            row["not_compared"] = (f"measured at frequency {measured[lp.index]:g} Hz, "
                                   f"predicted at {args.frequency:g} Hz")
        if fitted is not None:
            row["extrapolation"], far = outside(spec, lp, saved.actuator, fitted, overrides)
            expect(row, far, expected)
        if isinstance(saved.law, jh.NearestCondition):  # (which fitted loop's set)
            row["by_fitted_loop"] = nearest_loop(problem, saved.law, jh.Conditions(
                frequency=None if f is None else (f,), amplitude=(float(np.max(np.abs(H))),),
                temperature=None if T is None else (T,)))
        rows.append(row)
        curves.append((f"loop {lp.index}", H, pred, data))
        nan = np.full(pred.shape, np.nan)
        for k, v in (("loop", np.full(pred.shape, lp.index, float)), (x_column, H),
                     ("predicted", pred), ("data", nan if data is None else data),
                     ("error", nan if data is None else pred - data)):
            columns[k].append(v)
    if args.png:
        from jaxhyst.plots import plot_predictions

        plot_predictions(flux_curves(curves) if by_flux else curves,
                         "flux_density" if by_flux else rows[0]["output"], args.png,
                         title=f"predicted by {os.path.basename(args.result)}")
    if args.out:
        write_columns_csv(args.out, {k: np.concatenate(v) for k, v in columns.items()})
    text = [f"prediction of {len(rows)} loop(s) of {os.path.basename(args.data)} from the "
            f"saved model {os.path.basename(args.result)}"]
    text += [prediction_line(r) for r in rows]
    text += [f"  wrote {f}" for f in (args.out, args.png) if f]
    print_result(args, {"loops": rows, "out": args.out, "png": args.png}, "\n".join(text))
    return 0


def _observed(spec, loop, fitted, model_path: str) -> tuple[str, bool]:
    """(the signal column the model predicts for ``loop``, whether the loop has it to
    compare with): the column the model was fitted to (``fitted``, e.g. ``"B"``) where
    the loop has it or has no signal at all, else the loop's one signal column."""
    from jaxhyst.io import SIGNAL_OUTPUTS

    signals = signal_columns(loop)
    if fitted in SIGNAL_OUTPUTS and (fitted in signals or not signals):
        return fitted, fitted in signals
    if len(signals) == 1:
        return signals[0], True
    if not signals:  # (a model saved from Python does not say what it was fitted to)
        raise CLIError(f"{spec['data']} has no signal column and {model_path} does not say "
                       "which signal it predicts: add a column of it (B, M, y …) to the file.")
    raise CLIError(f"{spec['data']} has signal columns {signals} and the model in "
                   f"{model_path} was fitted to {fitted or 'none of them'}: keep the one "
                   "column to compare with in the file.")


def _fitted_conditions(path: str, meta: dict, actuator):
    """(the fitted loops' conditions {name: [lowest, highest]} or None, the error the
    leave-one-out folds lead one to expect or None) from the header's ``meta`` of the
    model file at ``path``: as ``identify --save-model`` records them, or, for a file
    saved before it did, the conditions of the data file it names, where that is still
    there and unchanged."""
    from .models import fitted_data
    from .predictions import fitted_range

    if "fitted_conditions" in meta:
        return meta["fitted_conditions"], meta.get("expected_error")
    spec, missing = fitted_data(path, meta)
    if missing:
        return None, None
    return fitted_range(spec, actuator, strict=False), None
