"""Identification results: named parameters with units, fit quality, solver outcome."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from ..params import NAMES, UNITS, Parameters


@dataclass
class IdentificationResult:
    """What an identification returns (all numbers plain Python/NumPy, SI units).

    - ``params``: identified `Parameters` (fixed ones at their given values).
    - ``free``: names of the parameters that were identified.
    - ``cost``: normalised cost Σr² (mean squared error over max|data|²).
    - ``objective``: the paper's E = Σ(y − ỹ)², in the output's unit squared.
    - ``rms_error``, ``max_abs_error``: residual RMS and max |e|, output's unit.
    - ``steps``: solver iterations; ``result``: solver outcome (Optimistix RESULTS name).
    - ``solver``, ``wall_time`` (s), ``output`` (observed quantity), ``extra`` (per-method
      details, e.g. the multi-start table or a GA history).
    - ``report``: the `IdentifiabilityReport` at the identified point (standard errors,
      95 % intervals, null directions, identifiable combinations), or ``None`` if it was
      not requested; ``report_error`` says why it is missing if it failed.
    """

    params: Parameters
    free: tuple[str, ...]
    cost: float
    objective: float
    rms_error: float
    max_abs_error: float
    steps: int
    result: str
    solver: str
    wall_time: float
    output: str = "displacement"
    extra: dict = field(default_factory=dict)
    report: object = None
    report_error: str | None = None

    @property
    def success(self) -> bool:
        return self.result in ("successful", "max_steps_reached") and np.isfinite(self.cost)

    @property
    def n_loops(self) -> int | None:
        """Number of loops of a joint identification (parameters with leaves (L,))."""
        return None if np.ndim(self.params.Ms) == 0 else int(np.shape(self.params.Ms)[0])

    def _value(self, n):
        v = np.asarray(getattr(self.params, n), dtype=float)
        return float(v) if v.ndim == 0 else v.tolist()

    def _is_free(self, n) -> bool:
        return n in self.free or any(f.startswith(n + "[") for f in self.free)

    def to_dict(self) -> dict:
        return {
            "params": {n: {"value": self._value(n), "unit": UNITS[n],
                           "free": self._is_free(n)} for n in NAMES},
            "cost": self.cost, "objective": self.objective, "rms_error": self.rms_error,
            "max_abs_error": self.max_abs_error, "steps": self.steps, "result": self.result,
            "solver": self.solver, "wall_time_s": self.wall_time, "output": self.output,
            "identifiability": None if self.report is None else self.report.to_dict(),
            "identifiability_error": self.report_error,
        }  # fmt: skip

    def __str__(self) -> str:
        lines = [
            f"Identification by {self.solver}: {self.result} after {self.steps} steps "
            f"in {self.wall_time:.2f} s",
            f"  cost {self.cost:.3e} (normalised), E = {self.objective:.3e}, "
            f"rms |e| = {self.rms_error:.3e}, max |e| = {self.max_abs_error:.3e} "
            f"({self.output})",
        ]
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
        if self.report is not None:
            lines.append(str(self.report))
        elif self.report_error:
            lines.append(f"Identifiability: not available ({self.report_error})")
        return "\n".join(lines)
