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
    parser.add_argument("--actuator", default="actuator1",
                        help="actuator1, actuator2 or a JSON file {Ar, lr, n, Hb}")
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
    parser.add_argument("--drive", help="CSV/TSV with t and H (or I) columns")
    parser.add_argument("--columns", help="column names for a file without a header")
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
    parser.add_argument("--substeps", type=POSITIVE_INT, default=DEFAULT_SUBSTEPS,
                        help="RK4 substeps per sample")
    parser.add_argument("--variant", choices=VARIANTS, default="energy",
                        help="Jiles–Atherton form (energy: the paper's)")
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
            if getattr(args, o) is not None]
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


def _drive_from_args(args, actuator):
    import jaxhyst as jh
    from jaxhyst.io import read_loops

    if args.drive:
        loop = read_loops(args.drive, args.columns)[0]
        periods = 1 if args.run_in_periods is None else args.run_in_periods
        return (jh.drive_from_record(loop.t, loop_field(loop, actuator, args.drive),
                                     run_in_periods=periods), f"drive from {args.drive}")
    if args.field_amplitude is not None:
        d = jh.sinusoidal_field(args.frequency, args.field_amplitude, args.field_offset,
                                periods=args.periods,
                                samples_per_period=args.samples_per_period)
        return d, (f"H = {args.field_offset:g} + {args.field_amplitude:g} "
                   f"sin(2π·{args.frequency:g} t) A/m")
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

    if args.eddy is None and args.excess is None:
        return None
    return jh.Losses(eddy=args.eddy or 0.0, excess=args.excess or 0.0)


def _run_flux(args, params) -> int:
    """The B-driven model: H(t) for B(t) = amplitude·sin(2πft), and the loss per volume."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.io import write_columns_csv

    drive = jh.sinusoidal_flux(args.frequency, args.flux_amplitude, periods=args.periods,
                               samples_per_period=args.samples_per_period)
    sim = jh.simulate_flux(params, drive, variant_from_name(args.variant),
                           substeps=args.substeps, losses=_losses(args))
    H = np.asarray(sim.observed("H"))
    loss = float(sim.loss_density(args.frequency, max(1, int(round(args.periods)))))
    what = f"B = {args.flux_amplitude:g} sin(2π·{args.frequency:g} t) T"
    summary = {"params": args.params or args.preset, "drive": what,
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
    from jaxhyst.io import write_simulation_csv

    check_outputs(args)
    _check_drive_options(args)
    params = parameters_arg(args.params or args.preset)
    if args.flux_amplitude is not None:
        return _run_flux(args, params)
    actuator = actuator_arg(args.actuator)
    drive, what = _drive_from_args(args, actuator)
    sim = jh.simulate(params, actuator, drive, variant=variant_from_name(args.variant),
                      substeps=args.substeps, losses=_losses(args))
    y = sim.observed("y")
    summary = {
        "params": args.params or args.preset, "actuator": actuator.name, "drive": what,
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
