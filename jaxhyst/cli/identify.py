"""``jaxhyst identify``: identify parameters from a data file."""

from __future__ import annotations

import os
from pathlib import Path

from jaxhyst._files import writes_in_place
from jaxhyst.names import DEFAULT_SUBSTEPS, MAGNETIC_OUTPUT_NAMES

from .candidates import (
    AMPLITUDE_CANDIDATE,
    CANDIDATES,
    RATE_CANDIDATES,
    candidate_spec,
    candidates,
    check_comparison,
    loss_names,
    rate_note,
    spans_frequencies,
)
from .fitting import check_hybrid_options, decimated_first, fit_by_options, widen_derived_box
from .flux_fit import check_flux_options, flux_figure
from .heldout import held_out_text, leave_one_out
from .nearest import NEAREST, nearest_fit
from .options import (
    COUNT,
    EXIT_HELP,
    HYBRID,
    LOCAL,
    POSITIVE_INT,
    UNITS_HELP,
    VARIANTS,
    Parser,
)
from .predictions import expected_error, fitted_range, joint_view, model_to_save, records_of
from .problems import DEFAULT_CELLS, build_problem, resolve_bounds
from .spec import (
    CLIError,
    actuator_arg,
    bounds_arg,
    check_flux_loops,
    check_outputs,
    file_sha256,
    fixed_arg,
    note,
    parameters_arg,
    per_loop_arg,
    print_result,
    read_data,
    warn,
)


def identify_parser():
    """A ``jaxhyst`` parser that knows only this command (``jaxhyst.batch`` reads each
    manifest row's options with it, as the command line would)."""
    parser = Parser(prog="jaxhyst")
    add_parser(parser.add_subparsers(dest="command", required=True))
    return parser


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "identify", help="identify parameters from a measured loop",
        description="Identify the free parameters from a data file (CSV/TSV; columns t, H "
        "or I, and the observed signal y, strain, lambda, M or B; a 'loop' column separates "
        "loops; units in the header as 'y [um]' or 'y_um'). " + UNITS_HELP,
        epilog=EXIT_HELP)  # fmt: skip
    parser.add_argument("data", help="data file")
    parser.add_argument("--output", choices=("y", "strain", "lambda", "M", "B"),
                        help="observed column (needed when the file has several)")
    parser.add_argument("--loop", type=COUNT, help="which loop of a multi-loop file")
    parser.add_argument("--driven-by", choices=("H", "B"), default="H",
                        help="H (default): the file's field drives the model and its "
                        "signal is fitted; B: its flux density B(t) drives the model (the "
                        "B-driven model of a material: columns t, H and B) and the field H "
                        "is fitted")
    parser.add_argument("--joint", action="store_true", help="fit all loops of the file as one "
                        "problem (parameters shared unless listed in --per-loop)")
    parser.add_argument("--per-loop", help="with --joint: parameters free per loop, e.g. "
                        "'a,k,c'")
    parser.add_argument("--vary", help="with --joint: parameters as smooth functions of the "
                        "loops' conditions, e.g. 'k:log_f+T,c:log_amplitude' (features: "
                        "log_f from a frequency column, T from a temperature column, "
                        "log_amplitude from the loop's peak field); the others shared")
    parser.add_argument("--vary-degree", type=POSITIVE_INT, choices=(1, 2),
                        help="with --vary: 1 (linear in each feature) or 2 (quadratic)")
    parser.add_argument("--leave-one-out", action="store_true",
                        help="with --joint: also fit every loop but one and predict the one "
                        "left out, for each loop; reports each held-out error beside the "
                        "nearest measured loop's own fit, and with several forms keeps the "
                        "one that predicts best (that baseline too: then each loop's own "
                        "fit, a new loop predicted by the nearest's)")
    parser.add_argument("--variant", help="model form: " + ", ".join(VARIANTS) + " (energy: "
                        "the paper's Jiles–Atherton form, the default; play and preisach: "
                        "forms of pinning cells with return-point memory, their own "
                        "parameter 'spread'); with --leave-one-out a comma-separated list "
                        "to compare (default there: " + ",".join(CANDIDATES) + ", and "
                        + AMPLITUDE_CANDIDATE + " on three loops or more of different "
                        "amplitudes; on loops at several frequencies, with times: "
                        + ",".join(RATE_CANDIDATES) + "); a form may carry loss "
                        "coefficients of its own, e.g. play+relax or play+eddy+excess (the "
                        "mechanisms compared by held-out error), and a condition law of its "
                        "own after '@', e.g. play@spread:log_amplitude")
    parser.add_argument("--cells", type=POSITIVE_INT, default=DEFAULT_CELLS,
                        help="pinning cells of the forms play and preisach")
    parser.add_argument("--losses", help="loss coefficients to identify with the "
                        "rate-dependent model, from 'eddy', 'excess', 'lag' (the "
                        "hysteresis field's relaxation time) and 'relax' (the "
                        "magnetization's, an after-effect), e.g. 'eddy,excess' (the file "
                        "needs times; their box is derived from the data's rates unless "
                        "--bounds names it)")
    parser.add_argument("--columns", help="column names for a file without a header (or "
                        "instead of its header), e.g. 't,H,y [um]'; '-' skips a column")
    parser.add_argument("--actuator", default="actuator1",
                        help="actuator1, actuator2 or a JSON file {Ar, lr, n, Hb}")
    parser.add_argument("--bounds", help="search box: table1, or a JSON file {name: [lower, "
                        "upper]} (SI) naming only the parameters it changes. Default: for M or "
                        "B data a box derived from the loops (field and magnetization "
                        "amplitudes, coercive field; printed), else the paper's Table 1 box")
    parser.add_argument("--fix", action="append", help="hold parameters fixed: 'Ms=7.65e5' or "
                        "'Ms,lambda_s' with --params; repeatable")
    parser.add_argument("--params", help="known values for --fix without a value")
    parser.add_argument("--method", default="auto", choices=("auto",) + HYBRID + LOCAL,
                        help="a hybrid GA (paper §3.4) or a local solver (multi-start); auto: "
                        "GATR1 for y/strain/lambda data, lm for M or B loops")
    parser.add_argument("--start", help="local solvers: start from the parameters of an "
                        "earlier result JSON (identify --out)")
    parser.add_argument("--starts", type=POSITIVE_INT, default=8,
                        help="local solvers: random starts, solved in one vmapped batch (1: "
                        "one start at the centre of the box)")
    parser.add_argument("--max-steps", type=POSITIVE_INT,
                        help="local solver iterations (hybrids: T3)")
    parser.add_argument("--generations", type=POSITIVE_INT, help="hybrids: generations in "
                        "all, T1 + T2 (paper 300: 5 binary-coded, then 295 real-coded)")
    parser.add_argument("--population", type=POSITIVE_INT,
                        help="hybrids: BCGA population q1 (paper 120; q2 = q1/4)")
    parser.add_argument("--seed", type=COUNT, default=0,
                        help="random seed (integer >= 0): GA, random starts")
    parser.add_argument("--checkpoint", help="hybrids: checkpoint file (.npz), written "
                        "atomically every --checkpoint-every generations and on Ctrl-C")
    parser.add_argument("--checkpoint-every", type=POSITIVE_INT, default=10,
                        help="hybrids: generations between checkpoints")
    parser.add_argument("--resume", action="store_true", help="continue from --checkpoint")
    parser.add_argument("--run-in-periods", type=COUNT, default=1,
                        help="copies of the record simulated before it (transient)")
    parser.add_argument("--substeps", type=POSITIVE_INT, default=DEFAULT_SUBSTEPS,
                        help="RK4 substeps per sample (a warning says when the record is too "
                        "coarse for it)")
    parser.add_argument("--progress", type=COUNT, default=10,
                        help="progress on stderr: a line every N generations of a hybrid, every "
                        "2 s of a local solve (0: quiet)")
    parser.add_argument("--out", help="write the result (JSON, names and units) here")
    parser.add_argument("--intervals", choices=("profile", "linear"), default="profile",
                        help="profile (default): each 95 %% interval checked along its "
                        "profile likelihood and moved where the quadratic approximation "
                        "fails (about one more fit); linear: the linearised intervals only "
                        "(faster)")
    parser.add_argument("--save-model", metavar="FILE",
                        help="write the identified model (parameters, form, actuator, "
                        "substeps) here, for jaxhyst.load_model")
    parser.add_argument("--png", help="measured vs fitted loop with the error (and, for "
                        "hybrids, <name>_history.png)")
    parser.add_argument("--json", action="store_true", help="print the result as JSON")
    parser.set_defaults(func=run)


def _method(args, problem) -> str:
    """--method auto: GATR1 (the paper) for actuator outputs, multi-start LM for M/B."""
    if args.method != "auto":
        return args.method
    return "lm" if problem.output in (*MAGNETIC_OUTPUT_NAMES, "field") else "GATR1"


def _read_start(args):
    """The parameters of an earlier result (--start), or None."""
    import jaxhyst as jh
    from jaxhyst.io import read_json

    from .problems import model_parameters_from_json

    if not args.start:
        return None  # (a form's own parameters in the file: not used, see _start_params)
    return model_parameters_from_json(read_json(args.start), jh.EnergyBasedJA(),
                                      f"parameters in --start {args.start}")


def check_options(args) -> dict:
    """Every check of the options that needs no data (one line per problem): the spec of
    the fit without its data's parts. Also what ``identify-many`` runs on each item of
    a manifest before any work."""
    check_outputs(args)
    if args.joint and args.loop is not None:
        raise CLIError(f"--joint fits every loop of the file together and --loop "
                       f"{args.loop} picks one; give one of them.")
    known = parameters_arg(args.params) if args.params else None
    actuator = actuator_arg(args.actuator)
    spec = {"data": os.path.abspath(args.data), "columns": args.columns, "loop": args.loop,
            "output": args.output, "actuator": actuator.to_dict(),
            "fixed": fixed_arg(args.fix, known),
            "run_in_periods": args.run_in_periods, "substeps": args.substeps,
            "variant": None, "cells": args.cells, "losses": loss_names(args.losses),
            "joint": args.joint, "per_loop": per_loop_arg(args.per_loop),
            "vary": args.vary, "vary_degree": args.vary_degree or 1, "driven_by": args.driven_by}
    check_flux_options(args)
    if args.driven_by == "B":  # (the B(H) loop the box is derived from)
        spec["output"] = "B"
    if args.vary_degree is not None and not args.vary:
        raise CLIError(f"--vary-degree {args.vary_degree} shapes the laws of --vary; give "
                       "--vary (e.g. 'k:log_f').")
    for flag, value in (("--per-loop", spec["per_loop"]), ("--vary", args.vary),
                        ("--leave-one-out", args.leave_one_out)):
        if value and not args.joint:
            raise CLIError(f"{flag} needs --joint (several loops fitted together).")
    if args.leave_one_out and spec["per_loop"]:
        raise CLIError("--leave-one-out predicts a loop from the others: its parameters must "
                       "be shared or given by --vary, not --per-loop.")
    check_hybrid_options(args)
    candidates(args)
    return spec


def run(args) -> int:
    import jaxhyst as jh
    from jaxhyst._interrupt import stop_requested
    from jaxhyst.io import bounds_to_json, json_safe, write_json

    spec = check_options(args)
    given = bounds_arg(args.bounds)
    start = _read_start(args)
    size = os.path.getsize(spec["data"]) if os.path.isfile(spec["data"]) else 0
    if size > 5e6 and args.progress:  # (a few seconds: say so before)
        note("identify", f"reading {args.data} ({size / 1e6:.0f} MB) …")
    by_flux = spec.get("driven_by") == "B"  # (B(t) drives; H is the data)
    loops = read_data(spec["data"], spec["columns"], said=(times := []),  # (noted below)
                      drive=not by_flux)
    if by_flux:
        check_flux_loops(loops, spec["data"])
    if size > 5e6 and args.progress:
        note("identify", f"read {sum(lp.n_samples for lp in loops)} samples in "
                         f"{len(loops)} loop{'s' if len(loops) > 1 else ''}")
    forms = candidates(args, loops)
    if args.variant is None and args.leave_one_out and args.progress and \
            tuple(forms) == RATE_CANDIDATES:
        lo, hi = spans_frequencies(loops)
        note("identify", f"the loops were measured at {lo:.4g}–{hi:.4g} Hz: the candidates "
                         f"compared are {', '.join(forms)} (two static forms, two rate "
                         "mechanisms; --variant names others). The rate-dependent ones take "
                         "minutes on 2 cores")
    if args.leave_one_out:  # (before the first candidate's own law joins --vary's)
        check_comparison(spec, loops, forms)
    spec.update(candidate_spec(args, forms[0]))
    bounds, extra, where = resolve_bounds(spec, given, loops)
    spec["bounds"] = bounds_to_json(bounds)
    spec["extra_bounds"] = {n: list(v) for n, v in extra.items()}
    problem = build_problem(spec, loops)  # (its warnings: one line each, see main)
    method = _method(args, problem)
    if args.start and method in HYBRID:  # (only with --method auto) a start means a local solve
        method = "lm"
    if method not in HYBRID and (args.checkpoint or args.resume):
        raise CLIError(f"--checkpoint/--resume apply to the hybrid GAs; --method {method} is a "
                       "local solve (not checkpointed: rerun it).")
    rate = rate_note(spec, loops, forms) if args.progress and spec.get("joint") else None
    for text in filter(None, [*times, rate] if args.progress else ()):  # (input checked)
        note("identify", text)
    held = curves = result = None
    folds = ()
    if args.leave_one_out:  # (first: with several forms, it chooses the one to fit)
        held = leave_one_out(args, spec, given, loops, method, forms)
        curves, folds, own = held.pop("_curves"), held.pop("_folds"), held.pop("_own", ())
        if held["partial"]:
            return _interrupted(args, spec, held)
        if held["kept"] == NEAREST:  # (each loop's own fit: polished together, no search)
            spec, problem, result = nearest_fit(args, spec, given, loops, held, own)
            where = None
        elif held["kept"] != forms[0]:
            spec.update(candidate_spec(args, held["kept"]))
            bounds, extra, where = resolve_bounds(spec, given, loops)
            spec["bounds"] = bounds_to_json(bounds)
            spec["extra_bounds"] = {n: list(v) for n, v in extra.items()}
            problem = build_problem(spec, loops)
    if where and args.progress:  # (after every check of the input: errors stay one line)
        note("identify", where)
    thinned = None if result else decimated_first(args, spec, loops, problem, method)
    # (the kept form's folds among the final fit's starts: near its optimum too)
    seeds = [problem.space.params_from_free(x) for names, x in folds
             if names == tuple(problem.space.names)]
    result = result or thinned or fit_by_options(args, problem, method, start, seeds=seeds)
    if where and where.startswith("bounds derived"):  # (after a thinned fit: its polish's
        result, problem = widen_derived_box(  # single LM solve, not a batch on all samples)
            args, spec, given, loops, problem, result, method, batch=thinned is None)
    if stop_requested() and result.result != "interrupted":  # Ctrl-C during a local solve
        result = result.with_outcome("interrupted")
    d = result.to_dict()
    d["problem"] = {**spec, "data": _portable_path(spec["data"], args.out)}
    d["data_sha256"] = file_sha256(spec["data"])  # (report and predict check it)
    if isinstance(result.params, dict):  # a condition model: every coefficient
        d["coefficients"] = {n: float(v) for n, v in result.params.items()}
    if "history" in result.extra:
        d["history"] = result.extra["history"]
    if held is not None:
        d["leave_one_out"] = held
    figures = _identify_figure(args, problem, result, has_t=loops[0].t is not None) \
        if args.png else []
    if args.png and curves and not writes_in_place(args.png):
        from .predictions import held_out_figure
        held_png = str(Path(args.png).with_name(Path(args.png).stem + "_heldout"
                                                + Path(args.png).suffix))
        records = records_of(problem)
        held_out_figure(curves, held["kept"], spec, getattr(records, "actuator", None),
                        records.output if records.output != "mixed" else records.outputs[0],
                        held_png)
        figures.append(held_png)
    if args.out:
        write_json(args.out, d)
    if args.save_model:
        model, records = model_to_save(spec, problem, result), records_of(problem)
        jh.save_model(args.save_model, model, data=spec["data"],
                      data_sha256=file_sha256(spec["data"]), outcome=result.result,
                      rms_error=result.rms_error, output=result.output,
                      identifiability=json_safe(d.get("identifiability")),
                      fitted_conditions=fitted_range(spec, getattr(records, "actuator", None),
                                                     strict=False),
                      amplitude_unit="T" if spec.get("driven_by") == "B" else "A/m",
                      expected_error=expected_error(d),
                      problem={**spec, "data": _portable_path(spec["data"], args.save_model)})
    wrote = [f for f in (args.out, args.save_model, *figures) if f]
    text = str(result) + (held_out_text(held) if held else "") + \
        "".join(f"\n  wrote {f}" for f in wrote)
    print_result(args, d, text)
    for w in result.warnings:
        warn(args, w)
    status = _exit_status(result)
    if status == 0 and held is not None and held["stopped_short"]:
        warn(args, "a fit of the leave-one-out stopped short: " + "; ".join(held[
            "stopped_short"]) + " (a fold's held-out error, or the own fit a ratio divides "
             f"by, is not final; --max-steps N allows a fit more steps than "
             f"{args.max_steps or 200})")
        return 3
    return status


def _interrupted(args, spec, held) -> int:
    """A leave-one-out stopped by Ctrl-C/SIGTERM: the folds that finished, marked
    PARTIAL, written where --out says; exit 130."""
    from jaxhyst.io import write_json

    d = {"outcome": "interrupted", "problem": {**spec, "data": _portable_path(
        spec["data"], args.out)}, "leave_one_out": held}
    if args.out:
        write_json(args.out, d)
    print_result(args, d, "leave-one-out interrupted: no final fit" + held_out_text(held)
                 + (f"\n  wrote {args.out} (PARTIAL)" if args.out else ""))
    return 130


def _portable_path(path: str, out: str | None) -> str:
    """``path`` relative to the directory of the result file ``out`` (so that a result
    moved together with its data still finds them); absolute when on another drive."""
    base = os.path.dirname(os.path.abspath(out)) if out else os.getcwd()
    try:
        return os.path.relpath(path, base)
    except ValueError:
        return path


def _identify_figure(args, problem, result, has_t: bool) -> list[str]:
    """Draw the fit into ``args.png`` (and a hybrid's history beside it): files written."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.identify.summary import fitted_output
    from jaxhyst.plots import plot_fit, plot_history

    flags = (" — at bound: " + ", ".join(result.at_bound)) if result.at_bound else ""
    if isinstance(records_of(problem), jh.FluxProblem):
        flux_figure(problem, result.params, args.png,
                    f"{result.solver}: B-driven, measured and fitted H{flags}")
        return [args.png]
    if args.joint:
        problem, params = joint_view(problem, result.params)
        pred = np.asarray(problem.predict_loops(params))
        mask = np.asarray(problem.mask)
        H = np.asarray(problem.drive.H)[:, problem.drive.run_in:]
        plot_fit([H[i][mask[i]] for i in range(problem.n_loops)],
                 [np.asarray(problem.padded)[i][mask[i]] for i in range(problem.n_loops)],
                 [pred[i][mask[i]] for i in range(problem.n_loops)], problem.output, args.png,
                 title=f"{result.solver}: {problem.n_loops} loops fitted jointly{flags}")
        return [args.png]
    pred = fitted_output(result, problem)  # (from the fit's residuals: no compile)
    plot_fit(problem.drive.observed(problem.drive.H), problem.data, pred, problem.output,
             args.png, t=problem.drive.observed(problem.drive.t) if has_t else None,
             title=f"{result.solver}: measured and fitted ({os.path.basename(args.data)})"
             + flags)
    # (the history beside the figure; not beside a device or FIFO: /dev/null_history.png)
    if result.extra.get("history") and not writes_in_place(args.png):
        hist_png = str(Path(args.png).with_name(Path(args.png).stem + "_history.png"))
        plot_history(result.extra["history"], problem.space.names, problem.space.lower,
                     problem.space.upper, hist_png, title=result.solver + flags)
        return [args.png, hist_png]
    return [args.png]


def _exit_status(result) -> int:
    """0 for a converged fit (a parameter at its physical limit included: the result
    says so), 130 for an interrupted run, 3 for one that stopped short, failed (max
    steps, non-finite cost, solver failure) or ended far from its data, 4 for a converged
    fit with a parameter at a bound of its box that is not a physical limit."""
    if result.result == "interrupted":
        return 130
    if not result.success or result.far_from_data:
        return 3
    from jaxhyst.params import at_physical_limit

    box = [n for n, (_, bound) in result.at_bound.items()
           if not at_physical_limit(n, bound)]  # (a physical limit is the model's, fine)
    return 4 if box else 0

