"""``jaxhyst compensate``: the drive input that makes the actuator follow a displacement
(`jaxhyst.control.compensate`), and with ``--measured`` the next input of iterative
learning on the real actuator (`jaxhyst.control.IterativeLearning`)."""

from __future__ import annotations

import sys

from jaxhyst._interrupt import stop_requested
from jaxhyst.names import DEFAULT_SUBSTEPS

from .learning import check_known_delay, learn
from .options import COUNT, FINITE, NON_NEGATIVE, POSITIVE, POSITIVE_INT, UNITS_HELP, VARIANTS
from .spec import (
    CLIError,
    actuator_arg,
    check_outputs,
    float_list,
    note,
    parameters_arg,
    print_result,
    variant_from_name,
    warn,
)

#: The fraction of the stroke a reference derived from the limits swings over.
DEFAULT_SWING = 0.3


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "compensate", help="the drive current that makes the actuator follow a displacement",
        description="Compensate hysteresis: the coil current (or, for an actuator driven by "
        "a field, the AC field) that makes the model follow a reference displacement — the "
        "inverse model, refined through the forward model within --current-limit and "
        "--slew-limit. The reference is a sinusoid, tones at harmonics of --frequency, or a "
        "CSV file (t, y or strain). With --measured (a run of the real actuator: t, I or H, "
        "y) it writes the next input of iterative learning instead. Writes t, input and the "
        "predicted displacement (--csv), a figure (--png) and a JSON summary (--out). "
        "Exit 3: part of the reference is beyond the actuator, or the refinement stopped "
        "short (the result is written and says where). " + UNITS_HELP)
    parser.add_argument("--params", help="table1 (default), table3:<Hz> or a JSON file (a "
                        "result JSON also works)")
    parser.add_argument("--model", help="a saved model (jaxhyst identify --save-model) "
                        "instead of --params/--actuator/--variant/--substeps")
    parser.add_argument("--actuator", help="actuator1 (default), actuator2 or a JSON file "
                        "{Ar, lr, n, Hb}")
    parser.add_argument("--variant", choices=VARIANTS,
                        help="model form (default energy: the paper's)")
    parser.add_argument("--substeps", type=POSITIVE_INT,
                        help=f"RK4 substeps per sample (default {DEFAULT_SUBSTEPS})")
    parser.add_argument("--reference", default="sine",
                        help="sine, tones, or a CSV file with t and y (or strain) columns")
    parser.add_argument("--frequency", type=POSITIVE,
                        help="Hz: of the sine, the tones' fundamental, or the period of a "
                        "reference file (default 100 for sine and tones; a file without it "
                        "is a record, unless --periodic)")
    parser.add_argument("--amplitude", type=POSITIVE, help="of the sine, m (or strain)")
    parser.add_argument("--tones", help="amplitudes of the tones at harmonics 1, 2, 3 … of "
                        "--frequency, comma-separated, m (or strain)")
    parser.add_argument("--phases", help="phases of the tones, comma-separated, rad")
    parser.add_argument("--mean", type=FINITE, help="mean displacement, m (or strain)")
    parser.add_argument("--samples-per-period", type=POSITIVE_INT, default=200,
                        help="samples per period of the sine and the tones")
    parser.add_argument("--periodic", action="store_true",
                        help="the reference file is one period")
    parser.add_argument("--strain", action="store_true",
                        help="the reference (amplitudes, mean, file) is strain, not metres")
    parser.add_argument("--columns", help="column names of a reference file without a "
                        "header (or instead of its header); '-' skips a column")
    parser.add_argument("--current-limit", help="L (|input| <= L) or LO,HI: A of coil "
                        "current, or A/m of AC field for an actuator without turns per metre")
    parser.add_argument("--slew-limit", type=POSITIVE,
                        help="largest |d input/dt|, A/s (or A/m per s)")
    parser.add_argument("--tolerance", type=NON_NEGATIVE, default=1e-6,
                        help="stop refining at this rms error / peak-to-peak (default 1e-6)")
    parser.add_argument("--max-steps", type=POSITIVE_INT, default=100,
                        help="Levenberg–Marquardt steps at most")
    parser.add_argument("--no-refine", action="store_true",
                        help="the inverse model alone")
    parser.add_argument("--measured", help="a run of the actuator (t, I or H, y at the "
                        "reference's samples; several periods are averaged): write the next "
                        "input of iterative learning")
    parser.add_argument("--state", help="with --measured: the learning state (JSON), read "
                        "if it exists and written after the step, so that learning carries "
                        "its trust region from run to run")
    parser.add_argument("--gain", type=POSITIVE, help="a factor in (0, 1] on every learning "
                        "step (default 1: the model's full step, held by the trust region) for "
                        "--measured or --plant")
    parser.add_argument("--plant", help="rehearse learning on a simulated actuator with these "
                        "parameters (table1, table3:<Hz> or a JSON file): --iterations runs")
    parser.add_argument("--iterations", type=POSITIVE_INT, default=10,
                        help="with --plant: learning iterations (default 10)")
    parser.add_argument("--noise", type=NON_NEGATIVE, help="with --plant: measurement noise σ "
                        "over the reference's peak-to-peak (e.g. 0.005)")
    parser.add_argument("--delay", type=COUNT, help="with --plant: acquisition delay, samples")
    parser.add_argument("--known-delay", type=COUNT, help="with --measured or --plant: the "
                        "acquisition's delay in samples where it is known (0: none), "
                        "corrected exactly, every other lag taken for the plant's phase "
                        "(default: a late record of a sample or more is corrected)")
    parser.add_argument("--mode", help="with --plant: an unmodelled structural mode "
                        "'FREQUENCY,DAMPING' (Hz, ratio), e.g. '2500,0.05'")
    parser.add_argument("--seed", type=COUNT, default=0, help="with --plant: of the noise")
    parser.add_argument("--csv", help="write t, input and predicted displacement here")
    parser.add_argument("--png", help="write a figure here (needs matplotlib)")
    parser.add_argument("--out", help="write a JSON summary here")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")
    parser.add_argument("--periods", type=POSITIVE_INT, default=1,
                        help="periods of a periodic input written to --csv (default 1)")
    parser.set_defaults(func=run)


def _conflicts(args) -> None:
    """Options that do not go together are refused, not resolved silently."""
    builder = args.reference in ("sine", "tones")
    given = [o for o in ("params", "actuator", "variant", "substeps")
             if getattr(args, o) is not None]
    if args.model and given:
        raise CLIError(f"--model holds the parameters, actuator, form and substeps; leave "
                       f"out --{', --'.join(given)}.")
    for o, default in (("params", "table1"), ("actuator", "actuator1"), ("variant", "energy"),
                       ("substeps", DEFAULT_SUBSTEPS)):
        if getattr(args, o) is None:
            setattr(args, o, default)
    if args.reference == "sine" and (args.tones or args.phases):
        raise CLIError("--tones and --phases go with --reference tones, not sine.")
    if args.reference == "tones" and (args.amplitude is not None or not args.tones):
        raise CLIError("--reference tones needs --tones A1,A2,… (m) and no --amplitude.")
    if not builder and (args.amplitude is not None or args.tones or args.phases
                        or args.mean is not None):
        raise CLIError(f"--reference {args.reference} is a file: --amplitude, --tones, "
                       "--phases and --mean build a sine or tones instead.")
    if args.periodic and builder:
        raise CLIError("--periodic applies to a reference file (a sine or tones is periodic).")
    if args.periodic and args.frequency is not None:
        raise CLIError("--periodic (the file is one period) and --frequency (the file holds "
                       "periods of 1/f) exclude each other; give one.")
    if args.no_refine and (args.measured or args.plant):
        raise CLIError("--no-refine (the inverse model alone) and learning (--measured, "
                       "--plant) exclude each other.")
    if args.measured and args.plant:
        raise CLIError("--measured learns from a real run, --plant rehearses on a simulated "
                       "one: give one of them.")
    if args.gain is not None and not (args.measured or args.plant):
        raise CLIError(f"--gain {args.gain:g} applies to learning (--measured or --plant).")
    if args.gain is not None and args.gain > 1:
        raise CLIError(f"--gain {args.gain:g}: the learning gain must lie in (0, 1].")
    if args.known_delay is not None and not (args.measured or args.plant):
        raise CLIError(f"--known-delay {args.known_delay} applies to learning (--measured or "
                       "--plant).")
    if args.reference in ("sine", "tones"):  # (a file's period: once it is read)
        check_known_delay(args.known_delay, args.samples_per_period)
    if args.state and not args.measured:
        raise CLIError("--state carries learning between runs of --measured; give --measured.")
    rehearsal = [o for o in ("noise", "delay", "mode") if getattr(args, o) is not None]
    if rehearsal and not args.plant:
        raise CLIError(f"--{rehearsal[0]} describes the simulated plant: give --plant.")


def _model(args):
    import jaxhyst as jh

    if args.model:
        from .models import model_at, read_model

        model = read_model(args.model)
        other = [f for f in (model.law.features if model.law is not None else ())
                 if f != "log_f"]
        if other:
            what = ("picks the nearest of its fitted loops by" if isinstance(
                model.law, jh.NearestCondition) else "its condition law varies with")
            raise CLIError(f"--model {args.model}: {what} {', '.join(other)}; compensate "
                           "evaluates a law of the frequency only: save model.at(…) from "
                           "Python (jaxhyst.save_model) first.")
        model = model_at(args, model, args.model, frequency=args.frequency)
        if model.actuator.magnetization_only:
            raise CLIError(f"--model {args.model}: a model of a material alone (fitted to M or "
                           "B loops) has no actuator to compensate; fit displacement data, or "
                           "give --params and --actuator.")
        return model
    return jh.Model(parameters_arg(args.params), actuator_arg(args.actuator),
                    variant_from_name(args.variant), args.substeps)


def _limit(args):
    if args.current_limit is None:
        return None
    values = float_list(args.current_limit, "--current-limit")
    if len(values) > 2:
        raise CLIError(f"--current-limit {args.current_limit!r}: give L or LO,HI.")
    return values[0] if len(values) == 1 else tuple(values)


def _reference(args, model, limit):
    from jaxhyst.control import multitone_reference, reference_from_record
    from jaxhyst.control.limits import InputLimits
    from jaxhyst.control.reach import reach
    from jaxhyst.control.tracking import input_gain

    lr = float(model.actuator.lr)
    to_m = lr if args.strain else 1.0
    if args.reference in ("sine", "tones"):
        f = args.frequency or 100.0
        amplitudes = ([args.amplitude] if args.reference == "sine" and args.amplitude
                      else float_list(args.tones, "--tones") if args.tones else None)
        mean = args.mean
        if amplitudes is None or mean is None:
            if limit is None:
                raise CLIError("give the reference (--amplitude and --mean, m), or "
                               "--current-limit to derive one from the stroke it allows.")
            gain, unit = input_gain(model)
            lo, hi = reach(model, InputLimits.of(limit, unit=unit), gain).y
            mean = 0.5 * (lo + hi) / to_m if mean is None else mean
            if amplitudes is None:
                amplitudes = [DEFAULT_SWING * (hi - lo) / to_m]
            note("compensate", f"reference derived from the stroke {lo * 1e6:.4g}–"
                               f"{hi * 1e6:.4g} µm that the limit allows: mean "
                               f"{mean * to_m * 1e6:.4g} µm, amplitude "
                               f"{amplitudes[0] * to_m * 1e6:.4g} µm")
        phases = float_list(args.phases, "--phases") if args.phases else None
        if phases is not None and len(phases) != len(amplitudes):
            raise CLIError(f"--phases: give one per tone ({len(amplitudes)}).")
        ref = multitone_reference(f, [a * to_m for a in amplitudes], mean * to_m,
                                  phases=phases, samples_per_period=args.samples_per_period)
        what = (f"{f:g} Hz sine" if len(amplitudes) == 1 else
                f"{len(amplitudes)} tones at harmonics of {f:g} Hz")
        return ref, what
    from jaxhyst.io import read_loops

    loops = read_loops(args.reference, args.columns, drive=False)
    if len(loops) != 1:
        raise CLIError(f"{args.reference} holds {len(loops)} loops; give one reference.")
    loop = loops[0]
    if loop.t is None:
        raise CLIError(f"{args.reference} has no time column t (s); a reference needs times.")
    kind = "strain" if args.strain else "y"
    if kind not in loop.signals:
        other = "strain" if kind == "y" else "y"
        hint = (f" (it has {other}: {'add' if other == 'strain' else 'drop'} --strain)"
                if other in loop.signals else "")
        raise CLIError(f"{args.reference} has no {kind} column{hint}.")
    values = loop.signals[kind]
    ref = (reference_from_record(loop.t, strain=values, actuator=model.actuator,
                                 periodic=args.periodic, frequency=args.frequency)
           if args.strain else
           reference_from_record(loop.t, values, periodic=args.periodic,
                                 frequency=args.frequency))
    return ref, f"{args.reference} ({'one period' if ref.periodic else 'a record'})"


def run(args) -> int:
    import warnings

    import numpy as np

    from jaxhyst.control import compensate
    from jaxhyst.control.learning_state import state_to_dict
    from jaxhyst.control.tracking import evaluate
    from jaxhyst.io import write_columns_csv, write_json
    from jaxhyst.progress import TextProgressMeter

    check_outputs(args)
    _conflicts(args)
    model = _model(args)
    limit = _limit(args)
    reference, what = _reference(args, model, limit)
    options = dict(current_limit=limit, slew_limit=args.slew_limit, tolerance=args.tolerance,
                   max_steps=args.max_steps, progress=TextProgressMeter())
    state = None
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if args.measured or args.plant:
            learner, state = learn(args, model, reference, options)
            result = learner.compensation
            u = state.input
            y = evaluate(learner.residuals.tracking, u)  # (the model, as it learns)
        else:
            result = compensate(model, reference, refine=not args.no_refine, **options)
            u, y = result.input, result.displacement
    for w in caught:
        if not issubclass(w.category, UserWarning) or "beyond the actuator" not in str(
                w.message):
            warn(args, " ".join(str(w.message).split()))
    summary = {"model": args.model or f"{args.params}, {model.actuator.name}",
               "reference": what, **result.to_dict()}
    if state is not None:
        last = state.reports[-1]
        summary["learning"] = {"source": args.measured or f"plant {args.plant}",
                               "iterations": state.iteration,
                               "measured_errors": list(state.errors),
                               "predicted_error_of_next": last.predicted,
                               "stopped": state.stopped,
                               "reports": [vars(r) for r in state.reports]}
    wrote = []
    if args.state and state is not None:
        write_json(args.state, state_to_dict(state))
        wrote.append(args.state)
    if args.png:
        from jaxhyst.plots import plot_compensation

        plot_compensation(result, args.png, title=f"{model.actuator.name}: {what}")
        wrote.append(args.png)
    if args.csv:
        t = np.asarray(reference.t)
        periods = max(int(args.periods), 1) if reference.periodic else 1
        if periods > 1:
            t = t[0] + reference.dt * np.arange(periods * t.shape[0])
            u, y = np.tile(u, periods), np.tile(y, periods)
        columns = {"t [s]": t}
        if model.actuator.n is not None:
            columns["I [A]"] = u
        columns["H [A/m]"] = result.gain * u + result.bias
        columns["y [m]"] = y
        write_columns_csv(args.csv, columns)
        wrote.append(args.csv)
    if args.out:
        write_json(args.out, summary)
        wrote.append(args.out)
    summary["wrote"] = wrote
    if state is None:
        text = [result.summary()]
    else:
        text = [f"learning on {summary['learning']['source']}, {what}"]
        text += [f"  {r}" for r in state.reports]
        if state.stopped:
            text.append(f"  stopped: {state.stopped}")
        else:
            text.append(f"  the next input is written; the plant's error is predicted at "
                        f"{last.predicted:.3e} of the peak-to-peak")
    text += [f"  wrote {f}" for f in wrote]
    print_result(args, summary, "\n".join(text))
    if stop_requested() or result.outcome == "interrupted":  # (Ctrl-C/SIGTERM)
        print("  PARTIAL: interrupted; the input written is the best so far",
              file=sys.stderr)
        return 130
    if state is not None:  # 3: learning stalled, or its last step was undone
        bad = (state.stopped and not state.stopped.startswith("at the noise floor")) or \
            state.reports[-1].action == "undone"
        return 3 if bad else 0
    stopped_short = not args.no_refine and result.outcome != "successful"
    return 3 if (result.unreachable or stopped_short) else 0
