"""What a fit predicts for loops, shared by ``identify`` (its leave-one-out folds and
figures), ``predict`` and the refits: the problem over the loops themselves, the model's
prediction of each loop and its error."""

from __future__ import annotations

import math

from .problems import loop_conditions
from .spec import CLIError, loop_drive, loop_field, read_data, signal_column


def records_of(problem):
    """The problem over the loops themselves: a condition model's records problem, else
    the problem."""
    import jaxhyst as jh

    return problem.records if isinstance(problem, jh.ConditionProblem) else problem


def joint_view(problem, params):
    """(the joint problem over the loops, its per-loop parameters) of a joint or
    condition-model problem at ``params``."""
    records = records_of(problem)
    return records, (params if records is problem else problem.per_record(params))


def error_summary(predicted, data, unit: str | None = None) -> dict:
    """{rms, max_abs, data_scale} of predicted − data (the data's unit, ``unit`` where
    given: then also in the row)."""
    import numpy as np

    e = np.asarray(predicted) - np.asarray(data)
    row = {"rms": float(np.sqrt(np.mean(e**2))), "max_abs": float(np.max(np.abs(e))),
           "data_scale": float(np.max(np.abs(data)))}
    return row if unit is None else {**row, "unit": unit}


def predict_loops(spec, fitted, params, loops, conditions=None, source=None) -> list:
    """The model's prediction and the data of each loop of ``loops`` (`jaxhyst.io.Loop`,
    of the fitted data or new ones), from a fit of ``fitted`` (the problem built from
    ``spec``) at ``params``: [(predicted, data or None)] in the fitted output's unit. A
    condition model is evaluated at each loop's conditions (``conditions``:
    {"frequency": …, "temperature": …} overriding the file's); shared joint parameters
    are used as they are; a single-loop fit's parameters likewise. The model is the
    fit's: its form, loss coefficients and the form's own parameters; a fit that kept the
    nearest-condition baseline (``spec["predict_by"]``) predicts a loop by the set of the
    fitted loop nearest to its conditions (`nearest_of`). ``source``: the
    file the loops come from (for the messages; the fitted data file by default). Each
    loop is simulated padded to the longest of ``loops`` — or to ``spec``'s common shape
    (``pad_to``: a leave-one-out) — so that loops of any length share one program. A
    B-driven fit (``--driven-by B``) predicts each loop's field H (A/m) from its B(t)
    (columns t and B; its peak B the amplitude of a condition law), compared with the
    loop's H where the file has it."""
    import jax
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.actuator import MAGNETIZATION_ONLY
    from jaxhyst.identify.joint import common_shape, pad_drive
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.model.paths import split_parameters

    from .models import equal_sets

    records = records_of(fitted)
    if isinstance(records, jh.FluxProblem):  # (each loop's B(t) drives it; H predicted)
        drives, actuator = [flux_drive(spec, lp, source) for lp in loops], None
    else:
        kind = output_kind(records.output if records.output != "mixed" else
                           records.outputs[0])
        actuator, name = records.actuator, signal_column(kind.name)
        drives = [loop_drive(spec, lp, name or "B", actuator, source) for lp in loops]
        if kind.magnetic_only:  # (a material: simulate checks its M, not a placeholder y)
            actuator = jh.Actuator(**{**actuator.to_dict(), "name": MAGNETIZATION_ONLY})
    pad_to = spec.get("pad_to") or (common_shape(drives) if len(drives) > 1 else None)
    nearest = nearest_of(spec)
    if nearest is not None:  # (each loop's nearest fitted loop, once for all)
        try:  # (a condition the fitted loops differ in, which the loops lack: one line)
            by = nearest.nearest(loop_conditions({**spec, "data": source or spec["data"]},
                                                 loops, actuator, conditions))
        except ValueError as err:
            raise CLIError(f"{source or spec['data']}: {err} (a column, or --frequency and "
                           "--temperature)") from None
    out = []
    for k, (lp, drive) in enumerate(zip(loops, drives, strict=True)):
        if isinstance(fitted, jh.ConditionProblem):
            try:
                at = loop_conditions({**spec, "data": source or spec["data"]}, [lp],
                                     actuator, conditions)
                tree = fitted.at(params, at)
            except ValueError as err:
                raise CLIError(f"{source or spec['data']}: {err} (a column, or --frequency "
                               "and --temperature)") from None
            tree = jax.tree.map(lambda x: np.asarray(x)[0], tree)
            _physical_at(tree, lp, at, actuator is None)
        elif nearest is not None:  # (the nearest fitted loop's set)
            tree = jax.tree.map(lambda x, i=int(by[k]): np.asarray(x)[i], params)
        elif np.ndim(split_parameters(params)[0].Ms) == 1:
            tree = equal_sets(params)
            if tree is None:
                raise CLIError("the fit has parameters per loop (--per-loop): it cannot "
                               "predict another loop; fit with shared parameters or --vary.")
        else:
            tree = params
        p, losses, form = split_parameters(tree)
        form = records.variant if form is None else form
        run = drive if pad_to is None else pad_drive(drive, pad_to)
        observed = slice(run.run_in, run.run_in + drive.n_observed)
        if actuator is None:  # (driven by B: the field H)
            sim = jh.simulate_flux(p, run, form, records.substeps, losses)
            predicted, data = np.asarray(sim.H)[observed], lp.H
        else:
            sim = jh.simulate(p, actuator, run, form, records.substeps, losses)
            predicted, data = np.asarray(kind.of(sim))[observed], lp.signals.get(name)
        out.append((predicted, None if data is None else np.asarray(data)))
    return out


def refuse_amplitude_by_flux(amplitude, path: str) -> None:
    """`predict --amplitude` scales a loop's field: refused, in one line, for the fit or
    model at ``path`` driven by B (its loops are driven by their B(t))."""
    if amplitude is not None:
        raise CLIError(f"--amplitude scales a loop's field; {path} is a B-driven fit "
                       "(--driven-by B), whose loops are driven by their B(t): give a file "
                       "of the B(t) to predict.")


def flux_curves(curves) -> list:
    """A B-driven prediction's curves for `jaxhyst.plots.plot_predictions` as a B(H) loop
    ("flux_density"): from (label, B, predicted H, measured H or None) per loop, the
    predicted and the measured H each against B."""
    return [c for name, B, pred, data in curves for c in
            [(f"{name}: predicted", pred, B, None)] +
            ([(f"{name}: measured", data, B, None)] if data is not None else [])]


def flux_drive(spec, lp, source):
    """The `FluxDrive` of a loop's B(t) for a B-driven fit's prediction (run in as the fit
    was)."""
    import jaxhyst as jh

    from .spec import flux_of

    data = source or spec["data"]
    B = flux_of(lp, data)  # (its own line where a column is missing)
    try:
        return jh.flux_from_record(lp.t, B, run_in_periods=spec.get("run_in_periods") or 1)
    except ValueError as err:
        raise CLIError(f"{data}: loop {lp.index}: {err}") from None


class BeyondLaw(CLIError):
    """A condition law that gives, at a loop's conditions, parameters outside their
    physical range: that loop has no prediction (a leave-one-out row says so, with
    ``reason``; `predict` stops with this one line)."""

    def __init__(self, message: str, reason: str):
        super().__init__(message)
        self.reason = reason


def _physical_at(tree, loop, at, by_flux: bool = False) -> None:
    """Raise `BeyondLaw` where the parameters ``tree`` a condition law gives at ``loop``'s
    conditions ``at`` (`jaxhyst.Conditions` of that one loop; ``by_flux``: its amplitude
    a peak flux density) are not physical — a parameter, a loss coefficient or the form's
    own (e.g. the spread beyond [0, 10])."""
    from jaxhyst.model.paths import unphysical

    reason = unphysical(tree)
    if reason is None:
        return
    shown = [f"{name} {values[0]:.4g} {unit}" for name, values, unit in
             (("peak flux density", at.amplitude, "T") if by_flux else
              ("peak field", at.amplitude, "A/m"), ("frequency", at.frequency, "Hz"),
              ("temperature", at.temperature, "°C")) if values is not None]
    raise BeyondLaw(f"loop {loop.index} ({', '.join(shown)}): the fitted condition law "
                    f"does not reach it — there it gives {reason}; no prediction (predict "
                    "loops nearer the fitted conditions)",
                    f"the law gives {reason} there")


def model_to_save(spec, problem, result):
    """The `jaxhyst.Model` of a fit (``identify --save-model``): a material's (magnetic
    outputs only) without an actuator; the nearest-condition model with its loops'
    conditions (`nearest_of`)."""
    import equinox as eqx

    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR
    from jaxhyst.names import MAGNETIC_OUTPUT_NAMES

    from .models import one_set

    model = problem.model(result.params)
    records = records_of(problem)
    if all(o in MAGNETIC_OUTPUT_NAMES
           for o in getattr(records, "outputs", None) or (records.output,)):
        model = eqx.tree_at(lambda m: m.actuator, model, NO_ACTUATOR)  # (a material)
    nearest = nearest_of(spec)
    if nearest is not None:
        return jh.Model(model.params, model.actuator, model.variant, model.substeps,
                        model.losses, nearest)
    return one_set(model)  # (every parameter shared: the one material's set)


def nearest_loop(spec, nearest, conditions) -> int:
    """The file index of the fitted loop whose set a nearest-condition model (``nearest``,
    fitted as ``spec`` says: `nearest_of`) uses at ``conditions`` (one record)."""
    i = int(nearest.nearest(conditions)[0])
    rows = (spec or {}).get("nearest_conditions") or []
    return int(rows[i].get("loop", i)) if i < len(rows) else i


def nearest_of(spec):
    """The `jaxhyst.NearestCondition` of a fit that kept the nearest-condition baseline
    (``identify --joint --leave-one-out``: ``spec["predict_by"]`` "nearest", the fitted
    loops' conditions in ``spec["nearest_conditions"]``), else None."""
    import jaxhyst as jh

    if spec.get("predict_by") != "nearest":
        return None
    rows = spec["nearest_conditions"]
    columns = {name: [r.get(name) for r in rows] for name in ("frequency", "temperature",
                                                              "amplitude")}
    return jh.NearestCondition(jh.Conditions(**{
        name: None if any(v is None for v in values) else values
        for name, values in columns.items()}),
        {"log_amplitude": "T" if spec.get("driven_by") == "B" else "A/m"})


def beyond(value: float, lo: float, hi: float, name: str) -> float:
    """How far the condition ``name`` at ``value`` lies beyond [lo, hi]: a factor for the
    amplitude and the frequency (1 inside), kelvin for the temperature (0 inside)."""
    if name == "temperature":
        return max(lo - value, value - hi, 0.0)
    return max(lo / value, value / hi, 1.0)


def expected_error(saved) -> dict | None:
    """The error a prediction may be expected to have, from a result's (``saved``: the
    result JSON as a dict) leave-one-out folds of the kept form: the largest held-out rms
    relative to the loop's size among the interpolated folds (a loop inside the others'
    conditions) and among all folds (an extrapolation), and how far the folds
    extrapolated (``reach``: {condition: `beyond`}; None for a result written before the
    folds recorded it); None without folds."""
    held = saved.get("leave_one_out")
    if not isinstance(held, dict) or not held.get("kept"):
        return None
    rows = held["forms"][held["kept"]]["rows"]
    if not rows:
        return None
    rel = [r["rms"] / r["data_scale"] if r.get("rms") is not None else math.inf
           for r in rows]  # (None: a fold whose law gave no material there, inf saved)
    inside = [x for x, r in zip(rel, rows, strict=True) if not r.get("outside")]
    reach: dict | None = {} if all("beyond" in r for r in rows) else None
    for r in rows if reach is not None else ():
        for name, far in r["beyond"].items():
            reach[name] = max(reach.get(name, far), far)
    return {"interpolated": max(inside) if inside else max(rel), "extrapolated": max(rel),
            "reach": reach}


def fitted_range(spec, actuator, strict: bool = True) -> dict | None:
    """{condition: [lowest, highest]} of the fitted loops (amplitude: the peak field in
    A/m, the peak flux density in T for a B-driven fit; frequency in Hz and temperature in
    °C where every loop has them). Where the
    loops' conditions cannot be read (some loops without a frequency …), a `CLIError`,
    or None if not ``strict``. ``actuator`` None: a material's loops (a field column)."""
    from jaxhyst.identify.joint import NO_ACTUATOR
    actuator = NO_ACTUATOR if actuator is None else actuator
    loops = read_data(spec["data"], spec.get("columns"))
    if spec.get("loop") is not None and not spec.get("joint"):
        loops = [lp for lp in loops if lp.index == spec["loop"]] or loops
    try:
        c = loop_conditions(spec, loops, actuator)
    except CLIError:
        if strict:
            raise
        return None
    out = {"amplitude": [min(c.amplitude), max(c.amplitude)]}
    for name in ("frequency", "temperature"):
        values = getattr(c, name)
        if values is not None:
            out[name] = [min(values), max(values)]
    return out


def outside(spec, loop, actuator, fitted, overrides) -> tuple[str, dict]:
    """('' if ``loop`` lies within the ``fitted`` range (`fitted_range`, 1 % of slack),
    else which condition lies beyond it and how far; {condition: `beyond`} for those)."""
    c = loop_conditions(spec, [loop], actuator, overrides)
    units = {"amplitude": "T" if spec.get("driven_by") == "B" else "A/m", "frequency": "Hz",
             "temperature": "°C"}
    text, far = "", {}
    for name, (lo, hi) in fitted.items():
        values = getattr(c, name, None)
        if values is None:
            continue
        v = values[0]
        slack = 0.01 * max(abs(lo), abs(hi), 1e-300)
        if v < lo - slack or v > hi + slack:
            text = text or f"{name} ({v:.4g} {units[name]}; fitted {lo:.4g}–{hi:.4g})"
            far[name] = beyond(v, lo, hi, name)
    return text, far


def expect(row, far: dict, expected: dict | None) -> None:
    """Set a prediction's ``row["expected_relative_error"]`` from the folds' errors
    (`expected_error`) — where the loop lies no further beyond the fitted conditions
    (``far``, from `outside`) than some fold extrapolated; else ``row["beyond_folds"]``
    ({condition: [how far, how far the folds reached or None]}) and no number."""
    where = row.get("extrapolation")
    if expected is None or where is None:
        return
    reach = expected.get("reach")
    over = {} if not where or reach is None else {  # (a result written before `reach`)
        n: [f, reach.get(n)] for n, f in far.items()
        if n not in reach or f > (reach[n] + 1e-9 if n == "temperature"
                                  else reach[n] * (1 + 1e-9))}
    if over:
        row["beyond_folds"] = over
    else:
        row["expected_relative_error"] = expected["extrapolated" if where else
                                                  "interpolated"]


def prediction_line(row) -> str:
    """A prediction's line for the terminal: the loop, its error against the file's data
    (or why there is none) and `where_text`."""
    unit = f" {row['unit']}" if row.get("unit") not in (None, "1") else ""
    err = (f": rms error {row['rms']:.4g}{unit} (max {row['max_abs']:.4g}{unit}, "
           f"{100 * row['rms'] / row['data_scale']:.2g} % of max|data|)") if "rms" in row \
        else (f" (not compared with the file's data: {row['not_compared']})"
              if "not_compared" in row else " (no data to compare)")
    by = (f" (by fitted loop {row['by_fitted_loop']}'s parameters: the nearest)"
          if "by_fitted_loop" in row else "")
    return f"  loop {row['loop']}{by}{err}{where_text(row)}"


def where_text(row) -> str:
    """The tail of a prediction's line: whether it extrapolates (``row["extrapolation"]``:
    '' within, a description beyond, None not known) and the error the folds lead one to
    expect (``row["expected_relative_error"]``, where there is one)."""
    where = row.get("extrapolation")
    text = ("; an extrapolation beyond the fitted loops' " + where if where else
            "; within the fitted loops' conditions" if where == "" else
            "; the fitted loops' conditions are not known (a model saved without them)")
    exp = row.get("expected_relative_error")
    if exp is not None and math.isfinite(exp):
        text += f"; expected from the leave-one-out folds: {100 * exp:.2g} % of max|data|"
    elif exp is not None:
        text += ("; no error to expect from the leave-one-out folds: a fold's law gave "
                 "no material at its held-out loop")
    for name, (far, reach) in (row.get("beyond_folds") or {}).items():
        how = "{:.3g} K" if name == "temperature" else "×{:.3g}"
        text += (f"; further beyond the fitted {name} ({how.format(far)}) than any "
                 "leave-one-out fold " + (f"reached ({how.format(reach)})" if reach is not None
                                          else "went") + ": no error to expect from them")
    return text


def scaled_loop(lp, amplitude, actuator, source):
    """The loop ``lp`` with its field scaled to the peak ``amplitude`` (A/m), no data."""
    import dataclasses

    import numpy as np

    H = np.asarray(loop_field(lp, actuator, source), dtype=np.float64)
    peak = float(np.max(np.abs(H)))
    if peak <= 0:
        raise CLIError(f"--amplitude: loop {lp.index} of {source} has no field to scale.")
    return dataclasses.replace(lp, H=H * (amplitude / peak), I=None, signals={})


def at_frequency(lp, frequency: float, source: str, by_flux: bool = False):
    """The loop ``lp`` run at ``frequency`` (Hz) by a rate-dependent model: the same
    waveform, its times scaled by the loop's own frequency over ``frequency``; nothing
    measured to compare (driven by B, its B(t) kept as the drive)."""
    import dataclasses

    import numpy as np

    own = lp.conditions.get("frequency")
    if own is not None and abs(own - frequency) <= 1e-9 * frequency:
        return lp
    if lp.t is None or own is None:
        raise CLIError(f"--frequency: the rate-dependent model runs loop {lp.index} of "
                       f"{source} at another frequency by scaling its times from its own; "
                       "give the file a 'frequency' column (Hz) and times (t, s).")
    return dataclasses.replace(
        lp, t=np.asarray(lp.t, dtype=np.float64) * (own / frequency),
        H=None if by_flux else lp.H, signals={"B": lp.signals["B"]} if by_flux else {},
        conditions={**lp.conditions, "frequency": float(frequency)})


def held_out_figure(curves, kept: str, spec, actuator, output: str, path: str) -> None:
    """Each held-out loop's prediction by the kept form (``curves``: [(loop, predicted,
    data)] from its folds) against its data, into ``path``."""
    import numpy as np

    from jaxhyst.plots import plot_predictions

    from .nearest import NEAREST
    from .spec import loop_field

    loops = []
    for lp, predicted, data in curves:
        x = lp.signals["B"] if spec.get("driven_by") == "B" else \
            loop_field(lp, actuator, spec["data"])  # (driven by B: B against H)
        loops.append((f"loop {lp.index} (held out)", np.asarray(x)[-predicted.shape[0]:],
                      predicted, data))
    if spec.get("driven_by") == "B":
        loops, output = flux_curves(loops), "flux_density"
    plot_predictions(loops, output, path, title=(
        "leave one loop out: each loop predicted by the nearest other loop's fit"
        if kept == NEAREST else f"leave one loop out: {kept}, each loop predicted from "
        "the others"))
