"""The ``jaxhyst`` command. All quantities are SI: fields in A/m, currents in A,
displacements in m, times in s, frequencies in Hz."""

from __future__ import annotations

import argparse
import json
import sys

PRESETS = ("table1",)


def _simulate(args) -> int:
    import jaxhyst as jh
    from jaxhyst.io import write_simulation_csv

    if args.preset == "table1":
        params, actuator = jh.TABLE1_TRUE, jh.ACTUATOR1
        drive = jh.sinusoidal_current(
            args.frequency, args.amplitude, args.offset, actuator,
            periods=args.periods, samples_per_period=args.samples_per_period,
        )  # fmt: skip
        title = (
            f"Table 1 actuator, I = {args.amplitude:.2f} sin(2π·{args.frequency:g} t)"
            f" + {args.offset:.2f} A"
        )
    sim = jh.simulate(params, actuator, drive, substeps=args.substeps)
    y = sim.observed("y")
    summary = {
        "preset": args.preset,
        "samples_observed": int(y.shape[0]),
        "y_min_m": float(y.min()),
        "y_max_m": float(y.max()),
        "M_over_Ms_min": float(sim.observed("M").min() / params.Ms),
        "M_over_Ms_max": float(sim.observed("M").max() / params.Ms),
    }
    if args.csv:
        write_simulation_csv(args.csv, sim)
        summary["csv"] = args.csv
    if args.png:
        from jaxhyst.plots import plot_simulation

        plot_simulation(sim, args.png, title=title)
        summary["png"] = args.png
    if args.json:
        print(json.dumps(summary))
    else:
        print(f"simulated {summary['samples_observed']} observed samples ({args.preset})")
        print(f"  y in [{summary['y_min_m'] * 1e6:.3f}, {summary['y_max_m'] * 1e6:.3f}] μm, "
              f"M/Ms in [{summary['M_over_Ms_min']:.3f}, {summary['M_over_Ms_max']:.3f}]")
        for key in ("csv", "png"):
            if key in summary:
                print(f"  wrote {summary[key]}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="jaxhyst",
        description="Jiles–Atherton hysteresis of magnetostrictive actuators (SI units "
        "throughout: A/m, A, m, s, Hz).",
    )
    sub = parser.add_subparsers(dest="command", required=True)
    sim = sub.add_parser(
        "simulate",
        help="simulate an actuator and write its loop (CSV, PNG)",
        description="Simulate a preset actuator driven by I = offset + amplitude·sin(2πft) "
        "(amperes). Starts demagnetized, ramps to the drive, discards one run-in period.",
    )
    sim.add_argument("--preset", choices=PRESETS, default="table1",
                     help="parameters + actuator: the paper's Table 1 study (Actuator1)")
    sim.add_argument("--frequency", type=float, default=100.0, help="drive frequency, Hz")
    sim.add_argument("--amplitude", type=float, default=0.77, help="current amplitude, A")
    sim.add_argument("--offset", type=float, default=1.53, help="current offset (bias), A")
    sim.add_argument("--periods", type=float, default=1.0, help="observed periods")
    sim.add_argument("--samples-per-period", type=int, default=200)
    sim.add_argument("--substeps", type=int, default=2, help="RK4 substeps per sample")
    sim.add_argument("--csv", help="write the signals here (SI units in the header)")
    sim.add_argument("--png", help="write a figure here (needs matplotlib)")
    sim.add_argument("--json", action="store_true", help="print a JSON summary")
    sim.set_defaults(func=_simulate)
    return parser


def main(argv=None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return args.func(args)
    except (ValueError, TypeError, ImportError, OSError) as err:
        print(f"jaxhyst {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
