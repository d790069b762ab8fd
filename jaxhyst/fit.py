"""Identification with the identifiability report attached: `solve`, `multistart` and
`run_hybrid` of `jaxhyst.identify`, each followed by `jaxhyst.analysis.identifiability`
at the result (one jacfwd of the model). This module sits above both packages, so that
`identify` never imports `analysis`."""

from __future__ import annotations

import dataclasses
import functools

from . import identify
from .analysis.identifiability import identifiability
from .identify.signal import sampling_error


def attach_report(result, problem, report: bool | str = True):
    """``result`` with its identifiability report (or the reason it is missing) and the
    model's error at the data's sampling (`jaxhyst.identify.signal.sampling_error`;
    ``result.warnings`` says so where it exceeds the documented accuracy). ``report``:
    True (the linear intervals, unchecked: no re-fits),
    ``"profile"`` (intervals checked along the profile likelihood and moved where the
    quadratic fails: `jaxhyst.analysis.profile_intervals`; a few batches of constrained
    re-fits) or False."""
    if result.result == "nonfinite":
        return result
    error = sampling_error(problem, result.params)
    if error is not None:  # (its warning is among the result's warnings)
        result = dataclasses.replace(result, sampling_error=error,
                                     substeps=int(problem.substeps))
    if not report:
        return result
    try:
        return result.with_report(identifiability(problem, result.params,
                                                  profile=report == "profile"))
    except (ValueError, FloatingPointError) as err:
        return result.with_report(None, error=str(err))


def _with_report(fn):
    @functools.wraps(fn)
    def wrapped(problem, *args, report: bool = True, **kwargs):
        return attach_report(fn(problem, *args, **kwargs), problem, report)

    wrapped.__doc__ = (fn.__doc__ or "") + (
        "\n\n    ``report`` (keyword, default True): attach the identifiability report "
        "(``\"profile\"``: with intervals checked along the profile likelihood).")
    return wrapped


solve = _with_report(identify.solve)
multistart = _with_report(identify.multistart)
run_hybrid = _with_report(identify.run_hybrid)
