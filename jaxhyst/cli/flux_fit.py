"""``identify --driven-by B``: a material's B-driven fit from the command line — the
file's B(t) drives the model (`jaxhyst.FluxProblem`) and the fitted output is its field
H(t), for one loop, several with shared parameters (``--joint``), with a condition law
(``--joint --vary``: the amplitude is then each loop's peak flux density, T) or free per
loop (``--per-loop``), and compared by leave-one-out (``--joint --leave-one-out``: each
held-out loop's H predicted from its B(t)). Its problem is built by
`jaxhyst.cli.problems.flux_problem`; here: its option checks and its figure."""

from __future__ import annotations

from .spec import CLIError


def check_flux_options(args) -> None:
    """What a B-driven fit does not do, refused in one line before any work."""
    if args.driven_by != "B":
        return
    if args.output not in (None, "B"):
        raise CLIError(f"--driven-by B fits the field H from B(t); --output {args.output} "
                       "is of an H-driven fit: leave it out.")


def flux_figure(problem, params, path: str, title: str) -> None:
    """The measured and fitted H against the driving B of every loop."""
    import numpy as np

    from jaxhyst.plots import plot_predictions

    from .predictions import joint_view

    records, per = joint_view(problem, params)
    H_model = np.asarray(records.predict(per))
    B = np.asarray(records.drive.B)[:, records.drive.run_in:]
    curves = []
    lengths = np.asarray(records.valid).sum(axis=1)  # (each record's observed samples)
    for i, n in enumerate(lengths):
        which = f"record {i}: " if records.n_records > 1 else ""
        curves.append((f"{which}measured", np.asarray(records.data)[i, :n], B[i, :n], None))
        curves.append((f"{which}model", H_model[i, :n], B[i, :n], None))
    plot_predictions(curves, "flux_density", path, title=title)
