"""``jaxhyst reproduce``: the paper's studies (`jaxhyst.cli.studies`)."""

from __future__ import annotations

from pathlib import Path

from .options import COUNT, HYBRID
from .spec import CLIError, check_outputs, print_result


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser("reproduce", help="reproduce a study of the paper",
                            description="Reproduce a study of the paper: table1, the simulation "
                            "study with the four hybrids (GATR1, GALM1, GATR2, GALM2); table3, "
                            "Actuator2 at 10-2000 Hz identified by GATR1 from noisy synthetic "
                            "strain (Figs 7, 8 with --png); table2, the quasi-static Actuator1 "
                            "identified three times by GATR1. Progress on stderr.")
    parser.add_argument("study", choices=("table1", "table2", "table3"),
                        help="which study: table1, table2 or table3")
    parser.add_argument("--quick", action="store_true", help="small GA, coarse record (a few "
                        "minutes on 2 cores, mostly compiling)")
    parser.add_argument("--seeds", type=COUNT, nargs="+", default=[0],
                        help="GA seeds (integers >= 0), one run per method and seed")
    parser.add_argument("--methods", help="comma-separated subset of the hybrids")
    parser.add_argument("--out", help="directory for <study>.md, <study>.json (and figures)")
    parser.add_argument("--png", action="store_true", help="with --out: figures (table1: GA "
                        "histories; table3: Figs 7 and 8)")
    parser.add_argument("--json", action="store_true",
                        help="print the result as one JSON object on stdout")
    parser.set_defaults(func=run)


def run(args) -> int:
    from jaxhyst.io import atomic_write_text, write_json

    check_outputs(args, directory="out")
    out = Path(args.out) if args.out else None
    if args.study != "table1":
        return _reproduce_experiment(args, out)
    from .studies import METHODS, table1_study

    methods = args.methods.split(",") if args.methods else list(METHODS)
    bad = [m for m in methods if m not in HYBRID]
    if bad:
        raise CLIError(f"--methods {bad}: choose from {list(HYBRID)}.")
    study = table1_study(quick=args.quick, methods=methods, seeds=tuple(args.seeds),
                         progress=not args.json)
    problem = study.pop("problem")
    if out:
        out.mkdir(parents=True, exist_ok=True)
        if args.png:  # figures first: a failure leaves no partial set of files
            from jaxhyst.plots import plot_history

            for r in study["runs"]:
                plot_history(r["history"], problem.space.names, problem.space.lower,
                             problem.space.upper, out / f"{r['method']}_s{r['seed']}.png",
                             title=f"{r['method']}, seed {r['seed']}"
                             + (" (PARTIAL: interrupted)" if study["partial"] else ""))
        write_json(out / "table1.json", study)
        atomic_write_text(out / "table1.md", study["markdown"] + "\n")
    summary = {k: v for k, v in study.items() if k != "runs"}
    summary["runs"] = [{k: v for k, v in r.items() if k != "history"} for r in study["runs"]]
    text = study["markdown"] + (f"\n\nwrote {out}/table1.md, table1.json" if out else "")
    print_result(args, summary, text)
    return 130 if study["partial"] else 0


def _reproduce_experiment(args, out) -> int:
    """``reproduce table3`` / ``table2``: GATR1 on noisy synthetic strain of the paper's
    experiments (`jaxhyst.cli.studies`)."""
    import numpy as np

    from jaxhyst.io import atomic_write_text, write_json

    from .studies import table2_study, table3_study

    if args.methods:
        raise CLIError(f"--methods: {args.study} is identified by GATR1 only (as in the "
                       "paper); leave --methods out.")
    if args.study == "table3":
        study = table3_study(quick=args.quick, seed=args.seeds[0], progress=not args.json)
    else:
        seeds = tuple(args.seeds) if len(args.seeds) > 1 else (0, 1, 2)
        study = table2_study(quick=args.quick, seeds=seeds, progress=not args.json)
    name = args.study
    figures = []
    if out:
        out.mkdir(parents=True, exist_ok=True)
    if out and args.png:
        from jaxhyst.plots import plot_frequency_response, plot_table3_loops

        if name == "table3":
            import jaxhyst as jh

            from .studies import TABLE3_FREQUENCIES

            plot_table3_loops(study["loops"], out / "fig7_loops.png",
                              title="Actuator2, Hb = 16 kA/m, H_AC = 8 kA/m (Table 3 values)"
                              + (" (PARTIAL: interrupted)" if study["partial"] else ""))
            p = jh.TABLE3[1000]
            dense = np.logspace(0, 4, 300)
            fm = np.array(TABLE3_FREQUENCIES, dtype=float)
            plot_frequency_response(
                dense, np.asarray(jh.frequency_response(p, jh.ACTUATOR2, dense)),
                out / "fig8_frequency_response.png",
                title="ε/λ of Actuator2 (Table 3, 1000 Hz column), drive frequencies marked",
                marks=(fm, np.asarray(jh.frequency_response(p, jh.ACTUATOR2, fm))))
            figures = ["fig7_loops.png", "fig8_frequency_response.png"]
    if out:
        write_json(out / f"{name}.json", study)
        atomic_write_text(out / f"{name}.md", study["markdown"] + "\n")
    summary = {k: v for k, v in study.items() if k != "loops"}
    wrote = ", ".join([f"{name}.md", f"{name}.json", *figures])
    text = (f"{name}: GATR1 on synthetic strain with noise σ = {study['noise']:g}·max|ε| "
            f"(✗: the truth outside the 95 % interval)\n\n" + study["markdown"]
            + (f"\n\nwrote {out}/: {wrote}" if out else ""))
    print_result(args, summary, text)
    return 130 if study["partial"] else 0
