"""Identification results: immutable, with an outcome that never calls a stopped-short
or non-finite fit a success."""

from __future__ import annotations

import dataclasses
import enum
from dataclasses import dataclass, field
from types import MappingProxyType

import numpy as np

from ..params import NAMES, UNITS


class Outcome(str, enum.Enum):
    """How an identification ended.

    - ``successful``: the solver's convergence test passed and the cost is finite;
    - ``max_steps_reached``: it stopped at its step limit without converging (the fit
      stopped short: more steps, or another start, may do better);
    - ``nonfinite``: the cost is NaN or inf (the model diverged or the data hold such);
    - ``failed``: the solver reported another failure (a singular linear solve …);
    - ``interrupted``: the run was stopped (Ctrl-C, SIGTERM, ``stop_after``) and returns
      the best point so far.
    """

    successful = "successful"
    max_steps_reached = "max_steps_reached"
    nonfinite = "nonfinite"
    failed = "failed"
    interrupted = "interrupted"


def _frozen(d):
    return MappingProxyType(dict(d or {}))


@dataclass(frozen=True)
class IdentificationResult:
    """What an identification returns (plain Python/NumPy values, SI units; immutable —
    `with_report` and `dataclasses.replace` make modified copies).

    - ``params``: the identified parameters (the problem's pytree: `Parameters`, per loop
      for a joint problem; fixed entries at their given values).
    - ``free``: names of the free entries; ``values``: their SI values (the order of
      ``free``).
    - ``cost``: the problem's own objective Σr² at ``params`` (see `AbstractProblem`).
    - ``outcome``: an `Outcome`; ``steps``: solver iterations (GA: generations).
    - ``groups``: per residual group, ``{"rms", "max_abs", "unit", "sigma", "size"}`` of
      model − data in the group's unit.
    - ``rms_error``, ``max_abs_error``: over all residual groups when they share a unit
      (else None); ``sse``: Σ(model − data)² then (the paper's E for a `Problem`).
    - ``solver``, ``wall_time`` (s), ``output``, ``extra`` (per-method details, read-only:
      a multi-start table, a GA history, the convergence check).
    - ``report``: the `IdentifiabilityReport` at ``params`` (attached by `jaxhyst.solve`
      etc.), or None; ``report_error`` says why it is missing.
    """

    params: object
    free: tuple[str, ...]
    values: tuple[float, ...]
    cost: float
    outcome: Outcome
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

    def __post_init__(self):
        object.__setattr__(self, "outcome", Outcome(self.outcome))
        object.__setattr__(self, "extra", _frozen(self.extra))
        object.__setattr__(self, "groups", _frozen(self.groups))

    @property
    def result(self) -> str:
        """The outcome's name (``"successful"``, ``"max_steps_reached"`` …)."""
        return self.outcome.value

    @property
    def success(self) -> bool:
        """True only for a converged fit with a finite cost."""
        return self.outcome is Outcome.successful and bool(np.isfinite(self.cost))

    @property
    def objective(self) -> float | None:
        """The paper's E = Σ(y − ỹ)² (alias of ``sse``)."""
        return self.sse

    @property
    def n_loops(self) -> int | None:
        """Number of loops of a joint identification (parameters with leaves (L,))."""
        ms = getattr(self.params, "Ms", None)
        return None if ms is None or np.ndim(ms) == 0 else int(np.shape(ms)[0])

    def with_report(self, report=None, error: str | None = None) -> IdentificationResult:
        """A copy with the identifiability report (or the reason it is missing)."""
        return dataclasses.replace(self, report=report, report_error=error)

    def with_outcome(self, outcome: Outcome, **extra) -> IdentificationResult:
        """A copy with another outcome (and extra details merged in)."""
        return dataclasses.replace(self, outcome=Outcome(outcome),
                                   extra={**self.extra, **extra})

    # -- presentation -----------------------------------------------------------------------
    def _is_parameters(self) -> bool:
        return all(hasattr(self.params, n) for n in NAMES)

    def _value(self, n):
        v = np.asarray(getattr(self.params, n), dtype=float)
        return float(v) if v.ndim == 0 else v.tolist()

    def _is_free(self, n) -> bool:
        return n in self.free or any(f.startswith(n + "[") for f in self.free)

    def to_dict(self) -> dict:
        if self._is_parameters():
            params = {n: {"value": self._value(n), "unit": UNITS[n], "free": self._is_free(n)}
                      for n in NAMES}
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
        if check and check["cost_after"] < check["cost_before"] * (1 - 1e-6):
            lines.append(f"  the search stopped short of the optimum: the convergence check "
                         f"lowered the cost from {check['cost_before']:.4e} to "
                         f"{check['cost_after']:.4e} in {check['steps']} LM steps")
        if len(self.groups) > 1:
            for name, g in self.groups.items():
                lines.append(f"    {name}: rms {g['rms']:.3e} {g['unit']}, "
                             f"max {g['max_abs']:.3e} {g['unit']}")
        if self._is_parameters():
            for n in NAMES:
                mark = "" if self._is_free(n) else "  (fixed)"
                v = self._value(n)
                if isinstance(v, list):
                    shared = n in self.free or not self._is_free(n)
                    text = f"{v[0]:>13.6g}" if shared else "  ".join(f"{x:.6g}" for x in v)
                    mark = mark or ("  (shared)" if shared else "  (per loop)")
                else:
                    text = f"{v:>13.6g}"
                lines.append(f"  {n:<9}= {text} {UNITS[n]}{mark}")
        else:
            for n, v in zip(self.free, self.values, strict=True):
                lines.append(f"  {n:<9}= {v:>13.6g}")
        if self.report is not None:
            lines.append(str(self.report))
        elif self.report_error:
            lines.append(f"Identifiability: not available ({self.report_error})")
        return "\n".join(lines)
