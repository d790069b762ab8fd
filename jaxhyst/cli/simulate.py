"""``jaxhyst simulate``: simulate an actuator and write its loop (CSV, PNG)."""

from __future__ import annotations

from jaxhyst.names import DEFAULT_SUBSTEPS

from .options import COUNT, FINITE, NON_NEGATIVE, POSITIVE, POSITIVE_INT, UNITS_HELP, VARIANTS
from .spec import (
    CLIError,
    actuator_arg,
    check_outputs,
    loop_field,
    parameters_arg,
    print_result,
    variant_from_name,
)


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "simulate", help="simulate an actuator and write its loop (CSV, PNG)",
        description="Simulate an actuator. The drive is a current I = offset + amplitude·"
        "sin(2πft) (A) by default, a field with --field-amplitude (A/m), or a measured "
        "record with --drive FILE (columns t and H or I). Starts demagnetized, ramps to the "
        "drive, discards one run-in period. " + UNITS_HELP)  # fmt: skip
    parser.add_argument("--preset", choices=("table1",), default="table1",
                        help="parameters when --params is not given")
    parser.add_argument("--params", help="table1, table3:<Hz> or a JSON file {name: value} "
                        "(a result JSON also works)")
    parser.add_argument("--actuator",
                        help="actuator1 (default), actuator2 or a JSON file {Ar, lr, n, Hb}")
    parser.add_argument("--model", help="a saved model (identify --save-model) instead of "
                        "--params/--actuator/--variant/--eddy/--excess/--lag/--relax; a "
                        "condition law (identify --vary) is evaluated at --frequency, "
                        "--temperature and the drive's amplitude")
    parser.add_argument("--temperature", type=FINITE, help="with --model: the temperature, "
                        "°C, of a law that varies with it")
    parser.add_argument("--frequency", type=POSITIVE, help="drive frequency, Hz (default 100)")
    parser.add_argument("--amplitude", type=FINITE, help="current amplitude, A (default 0.77)")
    parser.add_argument("--offset", type=FINITE, help="current offset (bias), A (default 1.53)")
    parser.add_argument("--field-amplitude", type=FINITE, help="field amplitude, A/m (instead "
                        "of a current)")
    parser.add_argument("--field-offset", type=FINITE, help="field offset, A/m (default 0)")
    parser.add_argument("--flux-amplitude", type=POSITIVE, help="drive the material by its "
                        "flux density B = amplitude·sin(2πft), T (the B-driven model: H(t) "
                        "and the loss per volume; no actuator)")
    parser.add_argument("--eddy", type=NON_NEGATIVE, help="eddy-current loss coefficient, "
                        "A/m per T/s (the rate-dependent model; default 0)")
    parser.add_argument("--excess", type=NON_NEGATIVE, help="excess loss coefficient, A/m "
                        "per √(T/s) (the rate-dependent model; default 0)")
    parser.add_argument("--lag", type=NON_NEGATIVE, help="relaxation time of the hysteresis "
                        "field, s: H_lag = lag·dH_hyst/dt (the rate-dependent model; "
                        "default 0)")
    parser.add_argument("--relax", type=NON_NEGATIVE, help="relaxation time of the "
                        "magnetization, s: relax·dM/dt = M_static − M, an after-effect "
                        "(the H-driven rate-dependent model; default 0)")
    parser.add_argument("--drive", help="CSV/TSV with t and H (or I) columns")
    parser.add_argument("--columns", help="column names for a file without a header (or "
                        "instead of its header); '-' skips a column")
    parser.add_argument("--run-in-periods", type=COUNT, help="with --drive: copies of the "
                        "record simulated before it, for a periodic drive to settle "
                        "(default 1)")
    parser.add_argument("--noise", type=NON_NEGATIVE, help="a simulated sensor: Gaussian "
                        "noise on the written y, σ over its peak-to-peak (e.g. 0.005)")
    parser.add_argument("--delay", type=COUNT, help="a simulated sensor: y written this many "
                        "samples late (an acquisition delay)")
    parser.add_argument("--seed", type=COUNT, help="of --noise (default 0)")
    parser.add_argument("--periods", type=POSITIVE, help="observed periods (default 1)")
    parser.add_argument("--samples-per-period", type=POSITIVE_INT,
                        help="samples per drive period (default 200)")
    parser.add_argument("--substeps", type=POSITIVE_INT,
                        help=f"RK4 substeps per sample (default {DEFAULT_SUBSTEPS}, or "
                        "the --model's)")
    parser.add_argument("--variant", choices=VARIANTS,
                        help="Jiles–Atherton form (default energy: the paper's)")
    parser.add_argument("--cells", type=POSITIVE_INT,
                        help="pinning cells of the forms play and preisach (default 16)")
    parser.add_argument("--csv", help="write the signals here (SI units in the header)")
    parser.add_argument("--png", help="write a figure here (needs matplotlib)")
    parser.add_argument("--json", action="store_true", help="print a JSON summary")
    parser.set_defaults(func=run)


#: Defaults of the sinusoidal drive's options (None in the parser, so that an option
#: given where it does not apply is refused instead of ignored).
SINE_DEFAULTS = {"frequency": 100.0, "amplitude": 0.77, "offset": 1.53, "field_offset": 0.0,
                 "periods": 1.0, "samples_per_period": 200}
#: The largest drive the command simulates at once (samples; ~0.5 GB of signals).
MAX_SAMPLES = 5_000_000


def _check_drive_options(args) -> None:
    """Options that do not go together are refused, not resolved silently; defaults are
    filled in; the drive's size is checked before anything is allocated."""
    sine = [o for o in ("frequency", "amplitude", "offset", "field_amplitude",
                        "field_offset", "periods", "samples_per_period")
            if getattr(args, o) is not None
            and not (o == "frequency" and args.model)]  # (a saved law's condition)
    flag = lambda o: "--" + o.replace("_", "-")  # noqa: E731
    if args.drive and sine:
        raise CLIError(f"--drive reads the drive from {args.drive}; "
                       f"{', '.join(flag(o) for o in sine)} build a sinusoid instead: give one.")
    if args.run_in_periods is not None and not args.drive:
        raise CLIError("--run-in-periods applies to a --drive record (a sinusoid runs in "
                       "one period).")
    if args.seed is not None and args.noise is None:
        raise CLIError("--seed goes with --noise.")
    if args.flux_amplitude is not None:
        other = [o for o in ("amplitude", "offset", "field_amplitude", "field_offset",
                             "noise", "delay") if getattr(args, o) is not None] + \
            (["drive"] if args.drive else [])
        if other:
            raise CLIError(f"--flux-amplitude drives the material by B; {flag(other[0])} "
                           "belongs to a current or field drive of the actuator: give one.")
    if args.field_amplitude is not None:
        current = [o for o in ("amplitude", "offset") if getattr(args, o) is not None]
        if current:
            raise CLIError(f"--field-amplitude drives with a field; {flag(current[0])} is of "
                           "a current drive: give one kind.")
    elif args.field_offset is not None:
        raise CLIError("--field-offset goes with --field-amplitude (a field drive).")
    for o, v in SINE_DEFAULTS.items():
        if getattr(args, o) is None:
            setattr(args, o, v)
    samples = (args.periods + 1.25) * args.samples_per_period
    if not args.drive and samples > MAX_SAMPLES:
        raise CLIError(f"--periods {args.periods:g} × --samples-per-period "
                       f"{args.samples_per_period} is {samples:.3g} samples (about "
                       f"{samples * 100 / 1e9:.2g} GB of signals); at most {MAX_SAMPLES:.0e}.")


def _drive_from_args(args, actuator, loop):
    """The drive and its description: the --drive record ``loop`` (else None), or a
    sinusoid of the options."""
    import jaxhyst as jh

    if loop is not None:
        periods = 1 if args.run_in_periods is None else args.run_in_periods
        return (jh.drive_from_record(loop.t, loop_field(loop, actuator, args.drive),
                                     run_in_periods=periods), f"drive from {args.drive}")
    if args.field_amplitude is not None:
        d = jh.sinusoidal_field(args.frequency, args.field_amplitude, args.field_offset,
                                periods=args.periods,
                                samples_per_period=args.samples_per_period)
        return d, (f"H = {args.field_offset:g} + {args.field_amplitude:g} "
                   f"sin(2π·{args.frequency:g} t) A/m")
    if actuator.n is None:
        raise CLIError(f"{actuator.name} is driven by its field (it has no turns per metre "
                       "to carry a current): give --field-amplitude (and --field-offset), "
                       "A/m, instead of a current.")
    d = jh.sinusoidal_current(args.frequency, args.amplitude, args.offset, actuator,
                              periods=args.periods, samples_per_period=args.samples_per_period)
    return d, f"I = {args.amplitude:.2f} sin(2π·{args.frequency:g} t) + {args.offset:.2f} A"


def _current(sim, actuator):
    """The coil current I = (H − Hb)/n (A) of the observed samples, or None for an
    actuator without turns per metre."""
    import numpy as np

    if actuator.n is None:
        return None
    return (np.asarray(sim.observed("H")) - float(actuator.Hb)) / float(actuator.n)


def _sensed(args, y):
    """y as a simulated sensor writes it (--delay, --noise), or None for y itself."""
    import numpy as np

    if not args.noise and not args.delay:
        return None
    if args.delay:
        if args.delay >= y.shape[0]:
            raise CLIError(f"--delay {args.delay}: the record has {y.shape[0]} samples.")
        y = np.concatenate([np.full(args.delay, y[0]), y[:-args.delay]])
    if args.noise:
        rng = np.random.default_rng(args.seed or 0)
        y = y + args.noise * float(np.ptp(y)) * rng.standard_normal(y.shape)
    return y


def _losses(args):
    """The loss coefficients given (`jaxhyst.Losses`), or None for the static model."""
    import jaxhyst as jh

    if all(getattr(args, n) is None for n in ("eddy", "excess", "lag", "relax")):
        return None
    return jh.Losses(eddy=args.eddy or 0.0, excess=args.excess or 0.0, lag=args.lag or 0.0,
                     relax=args.relax or 0.0)


def _model(args, record):
    """(params, actuator or None, form, substeps, losses) of the run: from --model (its law
    at the run's conditions: the --drive ``record``'s peak field for an amplitude) or from
    the options."""
    from jaxhyst.model.play import AbstractPlayForm

    if not args.model:
        if args.temperature is not None:
            raise CLIError("--temperature goes with --model (a saved condition law).")
        form = variant_from_name(args.variant or "energy", args.cells)
        if args.cells is not None and not isinstance(form, AbstractPlayForm):
            raise CLIError(f"--cells applies to the forms of pinning cells (--variant play "
                           f"or preisach); --variant {args.variant or 'energy'} has none.")
        return (parameters_arg(args.params or args.preset), None, form,
                args.substeps or DEFAULT_SUBSTEPS, _losses(args))
    given = [o for o in ("params", "actuator", "variant", "cells", "eddy", "excess",
                         "lag", "relax") if getattr(args, o) is not None]
    if given:
        raise CLIError(f"--model holds the parameters, actuator, form and losses; "
                       f"leave out --{', --'.join(given)}.")
    from .models import model_at, read_model

    model = read_model(args.model)
    if args.drive and args.given_frequency is not None and (
            model.law is None or "log_f" not in model.law.features):
        raise CLIError(f"--frequency with --drive gives the frequency of a saved law; the "
                       f"model in {args.model} does not vary with it (the record sets the "
                       "drive's timing): leave it out.")
    flux = args.flux_amplitude is not None
    amplitude = args.flux_amplitude if flux else args.field_amplitude
    if amplitude is None and args.drive and model.law is not None:  # (the record's peak)
        import numpy as np

        H = loop_field(record, model.actuator, args.drive)
        amplitude = float(np.max(np.abs(H)))
    model = model_at(args, model, args.model, frequency=args.given_frequency,
                     temperature=args.temperature,
                     amplitude=None if amplitude is None else abs(amplitude),
                     amplitude_option="--flux-amplitude" if flux else "--field-amplitude",
                     amplitude_unit="T" if flux else "A/m")
    material = model.actuator.n is None and str(model.actuator.name).startswith("none")
    if material and not flux and args.field_amplitude is None and not args.drive:
        raise CLIError(f"--model {args.model} is a material's model (no coil): drive it by a "
                       "field (--field-amplitude, or --drive with an H column) or by B "
                       "(--flux-amplitude).")
    return (model.params, model.actuator, model.variant,
            args.substeps or model.substeps, model.losses)


def _run_flux(args, params, variant, substeps, losses) -> int:
    """The B-driven model: H(t) for B(t) = amplitude·sin(2πft), and the loss per volume."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.io import write_columns_csv

    drive = jh.sinusoidal_flux(args.frequency, args.flux_amplitude, periods=args.periods,
                               samples_per_period=args.samples_per_period)
    sim = jh.simulate_flux(params, drive, variant, substeps=substeps, losses=losses)
    H = np.asarray(sim.observed("H"))
    loss = float(sim.loss_density(args.frequency, max(1, int(round(args.periods)))))
    what = f"B = {args.flux_amplitude:g} sin(2π·{args.frequency:g} t) T"
    summary = {"params": args.model or args.params or args.preset, "drive": what,
               "samples_observed": int(H.shape[0]), "H_min_A_per_m": float(H.min()),
               "H_max_A_per_m": float(H.max()), "loss_W_per_m3": loss}
    if args.png:
        from jaxhyst.plots import plot_predictions

        plot_predictions([(what, H, np.asarray(sim.observed("B")), None)], "flux_density",
                         args.png, title=f"B-driven: {what}")
        summary["png"] = args.png
    if args.csv:
        write_columns_csv(args.csv, {n: np.asarray(sim.observed(q)) for n, q in (
            ("t_s", "t"), ("B_T", "B"), ("H_A_per_m", "H"), ("M_A_per_m", "M"))})
        summary["csv"] = args.csv
    text = [f"simulated {H.shape[0]} observed samples ({what})",
            f"  H in [{H.min():.4g}, {H.max():.4g}] A/m, loss {loss:.4g} W/m³ (f·∮H dB)"]
    text += [f"  wrote {summary[k]}" for k in ("csv", "png") if k in summary]
    print_result(args, summary, "\n".join(text))
    return 0


def run(args) -> int:
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.io import read_loops, write_simulation_csv

    check_outputs(args)
    args.given_frequency = args.frequency  # (before the defaults: a law needs it given)
    _check_drive_options(args)
    record = read_loops(args.drive, args.columns)[0] if args.drive else None
    params, actuator, variant, substeps, losses = _model(args, record)
    if args.flux_amplitude is not None:
        return _run_flux(args, params, variant, substeps, losses)
    actuator = actuator or actuator_arg(args.actuator or "actuator1")
    drive, what = _drive_from_args(args, actuator, record)
    sim = jh.simulate(params, actuator, drive, variant=variant, substeps=substeps,
                      losses=losses)
    if str(actuator.name).startswith("none"):
        return _material_result(args, sim, params, what)
    y = sim.observed("y")
    summary = {
        "params": args.model or args.params or args.preset, "actuator": actuator.name,
        "drive": what,
        "samples_observed": int(y.shape[0]), "y_min_m": float(y.min()),
        "y_max_m": float(y.max()), "M_over_Ms_min": float(sim.observed("M").min() / params.Ms),
        "M_over_Ms_max": float(sim.observed("M").max() / params.Ms),
    }  # fmt: skip
    if args.png:  # the figure first: if it fails, no CSV is left behind without it
        from jaxhyst.plots import plot_simulation

        plot_simulation(sim, args.png, title=f"{actuator.name}, {what}")
        summary["png"] = args.png
    if args.csv:
        write_simulation_csv(args.csv, sim, current=_current(sim, actuator),
                             y=_sensed(args, np.asarray(sim.observed("y"))))
        summary["csv"] = args.csv
    text = [f"simulated {summary['samples_observed']} observed samples ({actuator.name}, {what})",
            f"  y in [{summary['y_min_m'] * 1e6:.3f}, {summary['y_max_m'] * 1e6:.3f}] μm, "
            f"M/Ms in [{summary['M_over_Ms_min']:.3f}, {summary['M_over_Ms_max']:.3f}]"]
    text += [f"  wrote {summary[k]}" for k in ("csv", "png") if k in summary]
    print_result(args, summary, "\n".join(text))
    return 0


def _material_result(args, sim, params, what) -> int:
    """A material's model (no actuator) driven by a field: its B(H) loop."""
    import numpy as np

    from jaxhyst.identify.outputs import FluxDensity
    from jaxhyst.io import write_columns_csv

    H = np.asarray(sim.observed("H"))
    B = np.asarray(FluxDensity().of(sim))[sim.run_in:]
    summary = {"params": args.model, "drive": what, "samples_observed": int(H.shape[0]),
               "B_min_T": float(B.min()), "B_max_T": float(B.max()),
               "M_over_Ms_max": float(np.max(np.abs(sim.observed("M"))) / params.Ms)}
    if args.png:
        from jaxhyst.plots import plot_predictions

        plot_predictions([(what, H, B, None)], "flux_density", args.png,
                         title=f"{args.model}: {what}")
        summary["png"] = args.png
    if args.csv:
        write_columns_csv(args.csv, {n: np.asarray(sim.observed(q)) for n, q in (
            ("t_s", "t"), ("H_A_per_m", "H"), ("M_A_per_m", "M"))} | {"B_T": B})
        summary["csv"] = args.csv
    text = [f"simulated {H.shape[0]} observed samples of the material ({what})",
            f"  B in [{B.min():.4g}, {B.max():.4g}] T, max |M|/Ms "
            f"{summary['M_over_Ms_max']:.3f}"]
    text += [f"  wrote {summary[k]}" for k in ("csv", "png") if k in summary]
    print_result(args, summary, "\n".join(text))
    return 0
