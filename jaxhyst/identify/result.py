"""Identification results: immutable, with an outcome that never calls a stopped-short
or non-finite fit a success.

Outcomes are one type everywhere, `RESULTS`: Optimistix's results enumeration (which
the solvers return inside compiled code, batched under ``vmap``) extended with
``interrupted``. On the host a result also has a short name (`outcome_name`), the one
written to result files.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass, field
from types import MappingProxyType

import jax
import numpy as np
import optimistix as optx

from ..model.accuracy import sampling_message
from ..model.paths import PARAMETER_UNITS, model_values, parameter_unit
from ..params import STRUCTURAL, Parameters, at_physical_limit
from .outputs import MAGNETIC_OUTPUTS


class RESULTS(optx.RESULTS):  # pyright: ignore
    interrupted = ("The run was stopped (Ctrl-C, SIGTERM or stop_after) and returns the "
                   "best point so far.")
    overtaken = ("Another start of the batch converged to a lower cost, which this one "
                 "could not reach at its pace: it was stopped there.")


#: Short names of outcomes (`outcome_name`), as result files write them:
#: ``successful`` — the solver's convergence test passed and the cost is finite;
#: ``max_steps_reached`` — it stopped at its step limit without converging (more steps,
#: or another start, may do better); ``nonfinite`` — the cost is NaN or inf (the model
#: diverged or the data hold such); ``failed`` — another failure (a singular linear
#: solve …); ``interrupted`` — stopped early, the best point so far; ``overtaken`` — a
#: start of a batch stopped because another converged lower than it could reach.
OUTCOME_NAMES = ("successful", "max_steps_reached", "nonfinite", "failed", "interrupted",
                 "overtaken")

#: `RESULTS` entries by short name (the others are ``failed``).
_BY_NAME = {
    "successful": ("successful",),
    "max_steps_reached": ("nonlinear_max_steps_reached", "max_steps_reached"),
    "nonfinite": ("nonfinite", "nonfinite_input"),
    "interrupted": ("interrupted",),
    "overtaken": ("overtaken",),
}


def outcome_name(result) -> str | np.ndarray:
    """The short name (`OUTCOME_NAMES`) of a `RESULTS` value (host value; an array of
    names for a batch of them)."""
    names = np.full(np.shape(jax.tree.leaves(result)[0]), "failed", dtype=object)
    for short, entries in _BY_NAME.items():
        for entry in entries:
            names[np.asarray(result == getattr(RESULTS, entry))] = short
    return str(names) if names.ndim == 0 else names


def as_result(outcome) -> RESULTS:
    """A `RESULTS` value from itself or from a short name (`OUTCOME_NAMES`)."""
    if isinstance(outcome, RESULTS):
        return outcome
    if isinstance(outcome, str) and outcome in OUTCOME_NAMES:
        return getattr(RESULTS, _BY_NAME.get(outcome, ("nonlinear_divergence",))[0])
    raise ValueError(f"outcome must be a jaxhyst.RESULTS value or one of {OUTCOME_NAMES}; "
                     f"got {outcome!r}.")


def member(result, k: int) -> RESULTS:
    """Member ``k`` of a batch of `RESULTS` values (host values)."""
    return jax.tree.map(lambda v: np.asarray(v)[k], result)


def _frozen(d):
    return MappingProxyType(dict(d or {}))


#: A free value within this fraction of its box width from a bound is "at the bound" (an
#: active constraint: the solvers stop at 1e-10 of the box on a bound optimum, so a value
#: further inside is an interior optimum near the bound).
BOUND_TOL = 1e-6
#: A residual group whose rms error exceeds this fraction of max|data| is "far from its
#: data"; a loop whose relative error is `OUTLIER_RATIO` times the others' median (and
#: above `OUTLIER_FLOOR`) is "far above the others".
FAR_FROM_DATA = 0.2
OUTLIER_RATIO = 5.0
OUTLIER_FLOOR = 0.05


#: A cost (the normalised Σr², ~ (rms/size)²) below which a fit is exact to round-off:
#: moving it further is round-off, not a better optimum.
ROUND_OFF_COST = 1e-24


def stopped_short(cost_before: float, cost_after: float) -> bool:
    """Whether a convergence check that moved the cost from ``cost_before`` to
    ``cost_after`` found a better optimum: a decrease of more than 1e-6 of the cost and
    more than round-off (`ROUND_OFF_COST`)."""
    return cost_before - cost_after > max(1e-6 * cost_before, ROUND_OFF_COST)


def bound_status(values, lower, upper, tol: float = BOUND_TOL) -> dict:
    """``{index: "lower" | "upper"}`` of the values within ``tol`` of their box width
    from a bound (boxes of zero width excluded)."""
    values, lower, upper = (np.asarray(x, dtype=float) for x in (values, lower, upper))
    width = upper - lower
    out = {}
    for i in range(values.shape[0]):
        if not width[i] > 0:
            continue
        u = (values[i] - lower[i]) / width[i]
        if u <= tol:
            out[i] = "lower"
        elif u >= 1.0 - tol:
            out[i] = "upper"
    return out


@dataclass(frozen=True)
class IdentificationResult:
    """What an identification returns (plain Python/NumPy values, SI units; immutable —
    `with_report` and `dataclasses.replace` make modified copies).

    - ``params``: the identified parameters (the problem's pytree: `Parameters`, per loop
      for a joint problem; fixed entries at their given values).
    - ``free``: names of the free entries; ``values``: their SI values (the order of
      ``free``).
    - ``cost``: the problem's own objective Σr² at ``params`` (see `AbstractProblem`).
    - ``outcome``: a `RESULTS` value (``result`` is its short name, `OUTCOME_NAMES`);
      ``steps``: solver iterations (GA: generations).
    - ``groups``: per residual group, ``{"rms", "max_abs", "unit", "sigma", "size"}`` of
      model − data in the group's unit.
    - ``rms_error``, ``max_abs_error``: over all residual groups when they share a unit
      (else None); ``sse``: Σ(model − data)² then (the paper's E for a `Problem`).
    - ``solver``, ``wall_time`` (s), ``output``, ``extra`` (per-method details, read-only:
      a multi-start table, a GA history, the convergence check).
    - ``report``: the `IdentifiabilityReport` at ``params`` (attached by `jaxhyst.solve`
      etc.), or None; ``report_error`` says why it is missing.
    - ``at_bound``: ``{name: ("lower" | "upper", bound)}`` of the free values that ended
      within 1e-6 of the box width from a bound (a constrained optimum);
    - ``sampling_error``: the model's error at the data's sampling with its RK4
      ``substeps``, relative to the output's size, at ``params`` (estimated where the
      drive is coarse, else None);
      ``far_from_data`` and ``warnings`` (properties) say what else needs attention.
    - ``linearization``: (free values (n,), J (N, n), e (N,), digest): the residual
      groups' residuals (model − data in their units, concatenated) at those values and
      their Jacobian with respect to them (SI), as a Gauss–Newton-family solver's last
      linearization left them, and the fitted problem's `content_digest`; or None. The
      report of that problem at those values uses it instead of differentiating the
      model again. Not saved.
    """

    params: object
    free: tuple[str, ...]
    values: tuple[float, ...]
    cost: float
    outcome: RESULTS
    steps: int
    solver: str
    wall_time: float
    groups: MappingProxyType = field(default_factory=lambda: _frozen({}))
    rms_error: float | None = None
    max_abs_error: float | None = None
    sse: float | None = None
    output: str = ""
    extra: MappingProxyType = field(default_factory=lambda: _frozen({}))
    report: object = None
    report_error: str | None = None
    at_bound: MappingProxyType = field(default_factory=lambda: _frozen({}))
    sampling_error: float | None = None
    substeps: int | None = None
    linearization: object = field(default=None, repr=False, compare=False)

    def __post_init__(self):
        object.__setattr__(self, "outcome", as_result(self.outcome))
        object.__setattr__(self, "at_bound", _frozen(self.at_bound))
        object.__setattr__(self, "extra", _frozen(self.extra))
        object.__setattr__(self, "groups", _frozen(self.groups))

    @property
    def result(self) -> str:
        """The outcome's short name (``"successful"``, ``"max_steps_reached"`` …:
        `OUTCOME_NAMES`)."""
        return outcome_name(self.outcome)

    @property
    def success(self) -> bool:
        """True only for a converged fit with a finite cost."""
        return self.result == "successful" and bool(np.isfinite(self.cost))

    @property
    def far_from_data(self) -> tuple[str, ...]:
        """Residual groups (loops) the fit is far from: rms error above `FAR_FROM_DATA`
        of max|data|, or `OUTLIER_RATIO` times the other loops' median relative error
        (above `OUTLIER_FLOOR`). Only for groups whose data size is known."""
        rel = {k: g["rms"] / g["data_scale"] for k, g in self.groups.items()
               if g.get("data_scale")}
        out = []
        for k, r in rel.items():
            others = [v for j, v in rel.items() if j != k]
            if not np.isfinite(r) or r > FAR_FROM_DATA or (
                    others and r > OUTLIER_FLOOR and r > OUTLIER_RATIO * np.median(others)):
                out.append(k)
        return tuple(out)

    @property
    def warnings(self) -> tuple[str, ...]:
        """What a user must know before trusting the fit, one line each: a stopped-short
        or failed outcome, loops far from their data, parameters at a bound."""
        out = []
        if self.result == "max_steps_reached":
            out.append("the fit stopped at its step limit before converging: allow more "
                       "steps, or start again from this result")
        elif self.result in ("nonfinite", "failed"):
            out.append(f"the fit failed ({self.result}): the cost is not a valid optimum")
        coarse = None if self.sampling_error is None else sampling_message(
            self.sampling_error, self.substeps or 0, "the model's output")
        if coarse is not None:
            out.append(coarse.rstrip("."))
        for k in self.far_from_data:
            g = self.groups[k]
            out.append(f"{k}: rms error {g['rms']:.3g} {g['unit']} is "
                       f"{100 * g['rms'] / g['data_scale']:.0f} % of max|data| "
                       f"({g['data_scale']:.3g} {g['unit']}): the fit is far from these data")
        for n, (side, bound) in self.at_bound.items():
            if at_physical_limit(n, bound):
                out.append(f"{n} ended at its physical limit {n} = {bound:g}: the data want "
                           "a value the model does not allow (another JA form, --variant, "
                           "may describe them better)")
            else:
                out.append(f"{n} ended at its {side} bound {bound:g}: the optimum is "
                           "constrained there; widen the bound if a value beyond it is "
                           "physical")
        return tuple(out)

    @property
    def objective(self) -> float | None:
        """The paper's E = Σ(y − ỹ)² (alias of ``sse``)."""
        return self.sse

    @property
    def n_loops(self) -> int | None:
        """Number of loops of a joint identification (parameters with leaves (L,))."""
        if not self._is_parameters():
            return None
        Ms = model_values(self.params)["Ms"]
        return None if np.ndim(Ms) == 0 else int(np.shape(Ms)[0])

    def with_report(self, report=None, error: str | None = None) -> IdentificationResult:
        """A copy with the identifiability report (or the reason it is missing)."""
        return dataclasses.replace(self, report=report, report_error=error)

    def with_outcome(self, outcome, **extra) -> IdentificationResult:
        """A copy with another outcome (a `RESULTS` value or a short name; extra details
        merged in)."""
        return dataclasses.replace(self, outcome=as_result(outcome),
                                   extra={**self.extra, **extra})

    # -- presentation -----------------------------------------------------------------------
    def _is_parameters(self) -> bool:
        """Whether the parameters are a model's (`Parameters`, alone or with `Losses`
        and a form's own: `jaxhyst.model.paths.split_parameters`)."""
        first = self.params[0] if isinstance(self.params, tuple) and self.params else \
            self.params
        return isinstance(first, Parameters)

    def _names(self) -> list[str]:
        return list(model_values(self.params))

    def _value(self, n):
        v = np.asarray(model_values(self.params)[n], dtype=float)
        return float(v) if v.ndim == 0 else v.tolist()

    def _is_free(self, n) -> bool:
        return n in self.free or any(f.startswith(n + "[") for f in self.free)

    def _unused(self) -> set[str]:
        """The fixed structural parameters of a fit of M or B, which cannot affect it
        (the placeholder structure of a material's model): not printed, and marked
        ``"unused": true`` in `to_dict`."""
        if self.output not in MAGNETIC_OUTPUTS:
            return set()
        return {n for n in self._names() if n in STRUCTURAL and not self._is_free(n)}

    def to_dict(self) -> dict:
        if self._is_parameters():
            params = {n: {"value": self._value(n), "unit": PARAMETER_UNITS.get(n, ""),
                          "free": self._is_free(n)} for n in self._names()}
            for n in self._unused():  # (kept: the file rebuilds the whole model)
                params[n]["unused"] = True
        else:
            params = {n: {"value": v, "free": True}
                      for n, v in zip(self.free, self.values, strict=True)}
        return {
            "params": params, "cost": self.cost, "outcome": self.result,
            "success": self.success, "steps": self.steps, "solver": self.solver,
            "wall_time_s": self.wall_time, "output": self.output,
            "rms_error": self.rms_error, "max_abs_error": self.max_abs_error,
            "sse": self.sse, "groups": {k: dict(v) for k, v in self.groups.items()},
            "identifiability": None if self.report is None else self.report.to_dict(),
            "identifiability_error": self.report_error,
            "at_bound": {n: {"bound": side, "value": b}
                         for n, (side, b) in self.at_bound.items()},
            "far_from_data": list(self.far_from_data),
            "warnings": list(self.warnings),
            "convergence_check": None if not self.extra.get("convergence_check") else
            dict(self.extra["convergence_check"]),
        }  # fmt: skip

    def __str__(self) -> str:
        lines = [
            f"Identification by {self.solver}: {self.result} after {self.steps} steps "
            f"in {self.wall_time:.2f} s",
            f"  cost {self.cost:.3e}" + (
                f", rms |e| = {self.rms_error:.3e}, max |e| = {self.max_abs_error:.3e} "
                f"({self.output})" if self.rms_error is not None else ""),
        ]
        check = self.extra.get("convergence_check")
        if check and stopped_short(check["cost_before"], check["cost_after"]):
            by = check.get("by", "the convergence check")
            where = f" (from its re-fit with {check['from']} held)" if "from" in check else ""
            lines.append(f"  the search stopped short of the optimum: {by}{where} "
                         f"lowered the cost from {check['cost_before']:.4e} to "
                         f"{check['cost_after']:.4e} in {check['steps']} LM steps")
        if len(self.groups) > 1:
            for name, g in self.groups.items():
                lines.append(f"    {name}: rms {g['rms']:.3e} {g['unit']}, "
                             f"max {g['max_abs']:.3e} {g['unit']}")
        if self._is_parameters():
            unused = self._unused()
            for n in self._names():
                if n in unused:
                    continue  # cannot affect M or B: not printed
                mark = "" if self._is_free(n) else "  (fixed)"
                if n in self.at_bound:
                    mark += f"  AT {self.at_bound[n][0].upper()} BOUND"
                v = self._value(n)
                if isinstance(v, list):
                    shared = n in self.free or not self._is_free(n)
                    text = f"{v[0]:>13.6g}" if shared else "  ".join(f"{x:.6g}" for x in v)
                    mark = mark or ("  (shared)" if shared else "  (per loop)")
                else:
                    text = f"{v:>13.6g}"
                lines.append(f"  {n:<9}= {text} {PARAMETER_UNITS.get(n, '')}{mark}")
        else:
            for n, v in zip(self.free, self.values, strict=True):
                lines.append(f"  {n:<9}= {v:>13.6g} {parameter_unit(n)}".rstrip())
        if self.report is not None:
            lines.append(str(self.report))
        elif self.report_error:
            lines.append(f"Identifiability: not available ({self.report_error})")
        lines += [f"  WARNING: {w}" for w in self.warnings]
        return "\n".join(lines)


def params_of(params):
    """``params`` — or, given a fit (an `IdentificationResult`), its parameters: the
    solvers' starts and the analyses take either."""
    return params.params if isinstance(params, IdentificationResult) else params
