"""Identification with the identifiability report attached: `solve`, `multistart` and
`run_hybrid` of `jaxhyst.identify`, each followed by `jaxhyst.analysis.identifiability`
at the result (with the solver's last Jacobian where it left one, else one jacfwd of the
model). This module sits above both packages, so that `identify` never imports
`analysis`."""

from __future__ import annotations

import dataclasses
import functools

from . import identify
from ._background import awaited, meanwhile, when_settled
from .analysis.identifiability import compile_report, identifiability
from .analysis.profile_intervals import REFITS, compile_refits
from .identify.result import stopped_short
from .identify.signal import sampling_error
from .identify.summary import point_of


def attach_report(result, problem, report: bool | str = True):
    """``result`` with its identifiability report (or the reason it is missing) and the
    model's error at the data's sampling (`jaxhyst.identify.signal.sampling_error`;
    ``result.warnings`` says so where it exceeds the documented accuracy). ``report``:
    True (the linear intervals, unchecked: no re-fits),
    ``"profile"`` (intervals checked along the profile likelihood and moved where the
    quadratic fails: `jaxhyst.analysis.profile_intervals`; a few batches of constrained
    re-fits) or False.

    Where a profile re-fit ends below the cost of a fit that says it converged (it
    stopped short of the minimum, or in a local one: ``report.lower_cost``), the fit
    continues from that re-fit — one Levenberg–Marquardt solve of every free parameter —
    and, where that lowers the cost, the result is the continued fit
    (``extra["convergence_check"]`` says from where and by how much; its steps and time
    are added) with the report made again at it. Once: a second lower cost is reported,
    not chased. A fit that ended otherwise (its step limit, a stop request) keeps its
    outcome and its limit; its report says NOT THE MINIMUM."""
    if result.result == "nonfinite":
        return result
    result = _with_sampling_error(result, problem)
    if not report:
        return result
    try:
        rep = identifiability(problem, result.params, profile=report == "profile",
                              linearization=result.linearization)
        if rep.lower_cost and result.success:
            result, rep = _continued(result, problem, rep)
        return result.with_report(rep)
    except (ValueError, FloatingPointError) as err:
        return result.with_report(None, error=str(err))


def _with_sampling_error(result, problem):
    """``result`` with the model's error at the data's sampling where it exceeds the
    documented accuracy (its warning is then among the result's warnings)."""
    error = sampling_error(problem, result.params)
    if error is None:
        return result
    return dataclasses.replace(result, sampling_error=error, substeps=int(problem.substeps))


def _continued(result, problem, rep):
    """(result, report) continued from the report's lower-cost re-fit where that lowers
    the cost (`attach_report`); else the two unchanged."""
    import numpy as np

    low = rep.lower_cost
    space = problem.space
    u = np.clip(np.asarray(space.u_from_free(np.asarray(low["values"], float))), 0.0, 1.0)
    more = identify.solve(problem, u)
    if not stopped_short(result.cost, more.cost):
        return result, rep
    check = {"cost_before": float(result.cost), "cost_after": float(more.cost),
             "steps": int(more.steps), "by": "the profile check",
             "from": f"{low['held']} = {low['value']:.6g}"}
    merged = _with_sampling_error(dataclasses.replace(
        more, solver=result.solver, steps=int(result.steps) + int(more.steps),
        wall_time=float(result.wall_time) + float(more.wall_time),
        extra={**result.extra, "convergence_check": check,
               "earlier_convergence_check": result.extra.get("convergence_check")}), problem)
    return merged, identifiability(problem, merged.params, profile=True,
                                   linearization=merged.linearization)


#: Problem structure (`_structure`) → the report programs this process has compiled for
#: it ("sampling": the model's error at the data's sampling; "jacobian": the report's).
_COMPILED: dict = {}


def _structure(problem):
    """What the report's compiled programs depend on: the problem's tree structure, its
    arrays' shapes and dtypes, its other leaves; None where that is not hashable."""
    import jax

    leaves, treedef = jax.tree_util.tree_flatten(problem)
    key = (treedef, tuple((tuple(x.shape), str(x.dtype)) if hasattr(x, "shape") else x
                          for x in leaves))
    try:
        hash(key)
    except TypeError:
        return None
    return key


def _compile_report_meanwhile(problem, report, linearized: bool = False):
    """Compile the programs every report runs (the model's error at the data's sampling,
    the whitened Jacobian: they depend on the problem's shapes, not on the fit) in a
    background thread (`jaxhyst._background`), at the box's centre, so that they compile
    while the fit's own programs compile and run instead of after them — once per problem
    structure in a process (they are evaluated there, which a second fit need not pay).
    ``linearized``: the fit's solver leaves its Jacobian at the end
    (`IdentificationResult.linearization`), which the report uses: its own is not
    compiled."""
    import numpy as np

    key = _structure(problem)
    # (the model's error at the sampling is computed with or without a report)
    needed = {"sampling"} if linearized or not report else {"sampling", "jacobian"}
    done = _COMPILED.get(key, set()) if key is not None else set()
    if needed <= done:  # (compiled already: nothing to gain)
        return None

    def work():
        # (the box's centre, u = 0.5 at z = 0, by the program every fit's summary runs:
        # not op by op, which compiles a dozen tiny programs on this thread's path)
        values, centre = point_of(problem.space, np.zeros(problem.space.n_free))
        if "sampling" not in done:
            sampling_error(problem, centre)
        if "jacobian" in needed - done:
            compile_report(problem, values)
        if key is not None:
            _COMPILED[key] = done | needed
        # (not the profile check's re-fits: they run only where the fit is not exact,
        # which is known once the fit's cost has settled — `refits_meanwhile`;
        # compiled for nothing, they slow the fit)

    return meanwhile(work)


#: A settled cost above this is not an exact fit (σ̂ over the data's size 1e-7 or
#: more, where `identifiability` calls a fit exact at 1e-9): its report will re-fit.
NOT_EXACT = 1e-14


#: Data whose own noise (`_noisy`) is above this fraction of their range are never fitted
#: exactly: the profile check's re-fits will run.
NOISY = 1e-4


def _noisy(problem) -> bool:
    """Whether some observed series of ``problem`` (64 samples or more) carries noise
    above `NOISY` of its range, estimated from its 4th differences (robustly: their median
    absolute value over 0.6745·√70; a smooth signal's are far smaller). It decides only
    when the re-fit program starts compiling, never a result."""
    import jax
    import numpy as np

    try:
        leaves = jax.tree_util.tree_leaves(problem.observations)
    except Exception:  # noqa: BLE001  (a problem without data to look at: wait)
        return False
    for leaf in leaves:
        a = np.asarray(leaf, dtype=np.float64)
        for row in a.reshape(-1, a.shape[-1]) if a.ndim else ():
            span = float(np.ptp(row)) if row.size >= 64 else 0.0
            if span > 0 and np.median(np.abs(np.diff(row, 4))) / 5.64 > NOISY * span:
                return True
    return False


def refits_meanwhile(problem, cost, first=None, lowerings: int = 0):
    """Compile the profile check's re-fit program in a background thread (after
    ``first``, other background work, so that two compiles do not share the cores with
    the fit), once per problem structure in a process, where the fit's ``cost`` is above
    an exact fit's (`NOT_EXACT`: an exact fit's report re-fits nothing, so nothing is
    compiled for it); else None. A fit calls this once its best cost has settled,
    ``jaxhyst report`` with the result's cost, a fit of noisy data (`_noisy`) at its
    start. ``lowerings``: 0, start at once; n, once the caller has lowered its next n
    large programs. The caller that runs the check holds it `awaited` under ``REFITS``."""
    if not cost > NOT_EXACT:
        return None
    key = _structure(problem)
    done = _COMPILED.get(key, set()) if key is not None else set()
    if "refits" in done:
        return None

    def work():
        if first is not None:
            first.thread.join()
        compile_refits(problem)
        if key is not None:
            _COMPILED[key] = _COMPILED.get(key, set()) | {"refits"}

    if lowerings == 0:
        return meanwhile(work, wait=0.0)
    return meanwhile(work, lowerings=lowerings)


def _linearized(args, kwargs) -> bool:
    """Whether `solve` / `multistart` called with these arguments (after the problem)
    ends with its solver's Jacobian (a Gauss–Newton-family solver)."""
    import optimistix as optx

    from .identify.solvers import make_solver

    solver = kwargs.get("solver", args[1] if len(args) > 1 else "lm")
    try:
        made = make_solver(solver)
    except (ValueError, TypeError):  # (the fit itself says what is wrong)
        return False
    return isinstance(made, optx.AbstractGaussNewton)


def _with_report(fn, linearized=lambda args, kwargs: False):
    @functools.wraps(fn)
    def wrapped(problem, *args, report: bool = True, **kwargs):
        background = _compile_report_meanwhile(problem, report, linearized(args, kwargs))
        later = []  # (the profile's re-fits: at once for noisy data, else once the fit
        # shows it is not exact)
        if report == "profile" and _noisy(problem):  # (after the fit's step is lowered:
            # a solver's first two large programs, its start and its step)
            later.append(refits_meanwhile(problem, 1.0, background, lowerings=2))

        def settled(cost):
            if report == "profile" and not later:
                later.append(refits_meanwhile(problem, cost, background))
            elif later and later[0] is not None:  # (its lowerings may not come: programs
                later[0].start()                   # loaded from kept traces)

        try:
            with when_settled(settled):
                result = fn(problem, *args, **kwargs)
        except BaseException:  # (a compile not yet started is not waited for; the
            # report's first: the re-fits' work waits for it)
            for thread in [background, *later]:
                if thread is not None:
                    thread.drop()
            raise
        if background is not None:
            background.join()
        # (the re-fits compile beside the report's first part: the profile check waits
        # for them, `profile_intervals.REFITS`)
        with awaited(REFITS, later[0] if later else None):
            return attach_report(result, problem, report)

    wrapped.__doc__ = (fn.__doc__ or "") + (
        "\n\n    ``report`` (keyword, default True): attach the identifiability report "
        "(``\"profile\"``: with intervals checked along the profile likelihood). The "
        "report's programs compile in a background thread while the fit runs (the first "
        "time for a problem's structure; joined before this returns); the profile's "
        "re-fits there too: for noisy data once the fit's step is lowered, else once a "
        "multi-start fit's cost has settled above an exact fit's.")
    return wrapped


solve = _with_report(identify.solve, _linearized)
multistart = _with_report(identify.multistart, _linearized)
run_hybrid = _with_report(identify.run_hybrid)
