"""``jaxhyst report``: what the data of an identify result determine."""

from __future__ import annotations

import os

from .models import is_model_file, load_model_fit
from .options import POSITIVE, POSITIVE_INT
from .problems import load_result
from .spec import check_outputs, print_result


def add_parser(sub) -> None:
    """Register the command and its options on the subparsers ``sub``."""
    parser = sub.add_parser(
        "report", help="identifiability of an identify result",
        description="Singular values, null directions, standard errors, identifiable "
        "combinations and (optionally) profile likelihoods of a result written by "
        "'jaxhyst identify --out' or a model saved by 'identify --save-model'.")  # fmt: skip
    parser.add_argument("result", help="result JSON from identify --out, or a model file "
                        "from identify --save-model (its data file where it was fitted)")
    parser.add_argument("--profile", action="append", help="profile likelihood of this "
                        "parameter (repeatable)")
    parser.add_argument("--profile-points", type=POSITIVE_INT, default=21,
                        help="grid points of each profile")
    parser.add_argument("--max-rel-se", type=POSITIVE, default=0.5,
                        help="relative standard error above which a parameter is poorly "
                        "determined")
    parser.add_argument("--png", help="singular values and correlation matrix figure")
    parser.add_argument("--json", action="store_true",
                       help="print the result as one JSON object on stdout")
    parser.set_defaults(func=run)


def fix_line(rep) -> str:
    """The report's last line: the parameters to fix (`IdentifiabilityReport.suggest_fixed`)
    so that the rest are identifiable and determined, or that none need fixing."""
    fix, share = rep.suggest_fixed(), f"{100 * rep.max_rel_se:g} %"
    if fix:
        return f"  to make the rest identifiable and determined to {share}: fix " \
               f"{', '.join(fix)}"
    return f"  every free parameter is identifiable and determined to {share}: nothing to fix"


def run(args) -> int:
    from jaxhyst._background import awaited
    from jaxhyst.analysis import identifiability, profile_likelihood
    from jaxhyst.analysis.profile_intervals import REFITS
    from jaxhyst.fit import refits_meanwhile

    check_outputs(args)
    saved, _, problem, params = (load_model_fit if is_model_file(args.result)
                                 else load_result)(args.result)
    cost = saved.get("cost") if isinstance(saved, dict) else None
    # (the profile check's re-fits compile beside the Jacobian where the fit is not exact)
    refits = refits_meanwhile(problem, cost, lowerings=1) if isinstance(cost, (int, float)) \
        else None
    with awaited(REFITS, refits):
        rep = identifiability(problem, params, max_rel_se=args.max_rel_se)
    summary = {"identifiability": rep.to_dict(), "suggest_fixed": list(rep.suggest_fixed())}
    text = [str(rep), fix_line(rep)]
    profiles = []
    for name in args.profile or []:
        prof = profile_likelihood(problem, params, name, n=args.profile_points)
        profiles.append(prof.to_dict())
        text.append(str(prof))
    summary["profiles"] = profiles
    if args.png:
        from jaxhyst.plots import plot_identifiability

        plot_identifiability(rep, args.png, title=os.path.basename(args.result))
        text.append(f"  wrote {args.png}")
    print_result(args, summary, "\n".join(text))
    return 0
