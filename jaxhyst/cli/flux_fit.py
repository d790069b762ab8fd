"""``identify --driven-by B``: a material's B-driven fit from the command line — the
file's B(t) drives the model (`jaxhyst.FluxProblem`) and the fitted output is its field
H(t), for one loop, several with shared parameters (``--joint``) or with a condition law
(``--joint --vary``: the amplitude is then each loop's peak flux density, T)."""

from __future__ import annotations

from .spec import CLIError


def check_flux_options(args) -> None:
    """What a B-driven fit does not do, refused in one line before any work."""
    if args.driven_by != "B":
        return
    for flag, value in (("--leave-one-out", args.leave_one_out),
                        ("--per-loop", args.per_loop)):
        if value:
            raise CLIError(f"{flag} applies to H-driven fits; a B-driven fit (--driven-by "
                           "B) shares its parameters or varies them with --vary.")
    if args.output not in (None, "B"):
        raise CLIError(f"--driven-by B fits the field H from B(t); --output {args.output} "
                       "is of an H-driven fit: leave it out.")


def flux_problem(spec: dict, loops, bounds, fixed: dict, form, substeps: int):
    """The `FluxProblem` (or its `ConditionProblem`) of the spec's loops: each loop's B(t)
    (it needs t, B and H columns, every loop the same number of samples) drives the model,
    its H is the data."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.identify.joint import fix_structural

    from .problems import loop_conditions, model_space, parse_vary

    data = spec["data"]
    for lp in loops:
        missing = [q for q, v in (("t", lp.t), ("H", lp.H), ("B", lp.signals.get("B")))
                   if v is None]
        if missing:
            raise CLIError(f"--driven-by B: loop {lp.index} of {data} has no "
                           f"{', '.join(missing)} column; B(t) drives the model and H is "
                           "fitted (columns t, H and B).")
    lengths = sorted({lp.n_samples for lp in loops})
    if len(lengths) > 1:
        raise CLIError(f"--driven-by B: the loops of {data} have {lengths} samples; a "
                       "B-driven joint fit needs one length (resample them).")
    fixed = fix_structural(bounds, fixed)
    run_in = spec.get("run_in_periods") or 1
    try:
        drives = [jh.flux_from_record(lp.t, lp.signals["B"], run_in_periods=run_in)
                  for lp in loops]
    except ValueError as err:
        raise CLIError(f"--driven-by B: {data}: {err}") from None
    H = np.stack([np.asarray(lp.H, dtype=np.float64) for lp in loops])
    vary = parse_vary(spec.get("vary"))
    losses_box = {n: tuple(v) for n, v in (spec.get("extra_bounds") or {}).items()
                  if n in (spec.get("losses") or [])} or None
    if not vary:
        return jh.FluxProblem(H, drives, model_space(spec, bounds, fixed), output="field",
                              variant=form, substeps=substeps)
    own_form = form if isinstance(form, jh.AbstractPlayForm) else None
    records = jh.FluxProblem(H, drives, jh.per_record_space(bounds, len(loops), losses_box,
                                                            own_form),
                             output="field", variant=form, substeps=substeps)
    actuator = jh.Actuator(**spec["actuator"])
    c = loop_conditions(spec, loops, actuator)
    peak_B = [float(np.max(np.abs(lp.signals["B"]))) for lp in loops]
    conditions = jh.Conditions(frequency=c.frequency, temperature=c.temperature,
                               amplitude=peak_B)
    law = jh.ConditionModel(vary, int(spec.get("vary_degree", 1)))
    try:
        space = jh.condition_space(bounds, law, fixed=fixed, losses=losses_box,
                                   form=own_form)
        return jh.ConditionProblem(records, conditions, law, space)
    except ValueError as err:
        raise CLIError(f"--vary: {err}") from None


def flux_figure(problem, params, path: str, title: str) -> None:
    """The measured and fitted H against the driving B of every loop."""
    import numpy as np

    from jaxhyst.plots import plot_predictions

    from .predictions import joint_view

    records, per = joint_view(problem, params)
    H_model = np.asarray(records.predict(per))
    B = np.asarray(records.drive.B)[:, records.drive.run_in:]
    curves = []
    for i in range(records.n_records):
        which = f"record {i}: " if records.n_records > 1 else ""
        curves.append((f"{which}measured", np.asarray(records.data)[i], B[i], None))
        curves.append((f"{which}model", H_model[i], B[i], None))
    plot_predictions(curves, "flux_density", path, title=title)
