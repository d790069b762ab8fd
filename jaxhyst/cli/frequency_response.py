"""``jaxhyst frequency-response``: the structural response ε/λ (eq 13)."""

from __future__ import annotations

from .options import POSITIVE, POSITIVE_INT, UNITS_HELP
from .spec import CLIError, actuator_arg, check_outputs, parameters_arg, print_result


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser("frequency-response", help="structural response ε/λ (eq 13)",
                            description="Magnitude and phase lag of G(jω) = (Ar·E/lr)/(Mz(jω)² + "
                            "Cz·jω + Kz). " + UNITS_HELP)
    parser.add_argument("--params", default="table1", help="table1, table3:<Hz> or a JSON file")
    parser.add_argument("--actuator", default="actuator1",
                        help="actuator1, actuator2 or a JSON file {Ar, lr, n, Hb}")
    parser.add_argument("--frequencies", help="comma-separated, Hz")
    parser.add_argument("--fmin", type=POSITIVE, default=1.0, help="lowest frequency, Hz")
    parser.add_argument("--fmax", type=POSITIVE, default=1e4, help="highest frequency, Hz")
    parser.add_argument("--points", type=POSITIVE_INT, default=25,
                        help="log-spaced frequencies between --fmin and --fmax")
    parser.add_argument("--png", help="magnitude and phase figure (Fig 8)")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object on stdout")
    parser.set_defaults(func=run)


def run(args) -> int:
    import numpy as np

    import jaxhyst as jh

    check_outputs(args)

    params = parameters_arg(args.params)
    actuator = actuator_arg(args.actuator)
    if args.frequencies:
        try:
            f = np.array([float(x) for x in args.frequencies.split(",")])
        except ValueError:
            raise CLIError("--frequencies must be comma-separated numbers (Hz).") from None
    else:
        if not (0 < args.fmin < args.fmax):
            raise CLIError("need 0 < --fmin < --fmax (Hz).")
        f = np.geomspace(args.fmin, args.fmax, args.points)
    if np.any(~np.isfinite(f)) or np.any(f <= 0):
        raise CLIError("frequencies must be finite and > 0 Hz.")
    G = np.asarray(jh.frequency_response(params, actuator, f))
    rows = [{"frequency_Hz": float(fi), "magnitude": float(abs(g)),
             "phase_lag_deg": float(-np.degrees(np.angle(g)))} for fi, g in zip(f, G, strict=True)]
    if args.png:
        from jaxhyst.plots import plot_frequency_response

        lo, hi = (f.min() / 2, f.max() * 2) if args.frequencies else (f.min(), f.max())
        dense = np.geomspace(lo, hi, 400)
        plot_frequency_response(dense, np.asarray(jh.frequency_response(params, actuator,
                                                                        dense)),
                                args.png, title=f"{actuator.name}, eq 13",
                                marks=(f, G) if args.frequencies else None)
    wn = float(np.sqrt(params.Kz / params.Mz) / (2 * np.pi))
    text = [f"natural frequency fn = {wn:.1f} Hz, ε/λ at 0 Hz = "
            f"{actuator.Ar * params.E / actuator.lr / params.Kz:.4g}",
            f"{'f (Hz)':>12} {'|ε/λ|':>12} {'lag (°)':>10}"]
    text += [f"{r['frequency_Hz']:>12.5g} {r['magnitude']:>12.5g} {r['phase_lag_deg']:>10.3f}"
             for r in rows]
    print_result(args, {"natural_frequency_Hz": wn, "response": rows}, "\n".join(text))
    return 0
