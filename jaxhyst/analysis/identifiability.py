"""Local identifiability of the free parameters of a `Problem` at a parameter point.

Coordinates: relative changes of the free parameters, d log|θ_r| (so a null direction
reads directly as a power law: y is unchanged when θ_r is multiplied by s^{v_r}). For a
parameter at exactly 0 the box width is used as its scale instead.

- Jacobian J = ∂y/∂log|θ| from ``jax.jacfwd`` (output units), its singular values and
  condition number.
- Null directions: right singular vectors with σ/σ₁ below ``null_tol`` (structural
  non-identifiability gives ~1e-15). The null space is returned in reduced row-echelon
  form, which makes each direction sparse and names it: e.g. Ms^+1 · alpha^-1 means the
  output is unchanged under Ms → s·Ms, alpha → alpha/s. Found from J, never hard-coded.
- Suggestion: the pivot parameters of that echelon form; fixing them removes every null
  direction (their columns of the null basis form an identity block).
- Gauss–Newton covariance σ²·(JᵀJ)⁺ on the identifiable subspace, σ² = Σe²/(N − rank);
  standard errors and 95 % intervals (normal quantile 1.96) for parameters that have no
  component along a null direction; the others are reported as not identifiable rather
  than with a huge or NaN interval.
"""

from __future__ import annotations

from dataclasses import dataclass

import jax
import jax.numpy as jnp
import numpy as np

from ..identify.problem import Problem
from ..params import NAMES, Parameters

Z95 = 1.959963984540054


@dataclass
class IdentifiabilityReport:
    """Result of `identifiability`; all arrays NumPy, names in the order of ``names``."""

    names: tuple[str, ...]
    values: np.ndarray
    singular_values: np.ndarray  # relative, σ/σ₁, descending
    condition_number: float  # σ₁/σ_min over the identifiable subspace
    null_directions: list[dict]  # {"exponents": {name: p}, "text": str}
    suggest_fix: tuple[str, ...]
    sigma: float  # residual standard deviation, output unit
    std_errors: dict  # name -> float, or None if not identifiable
    intervals: dict  # name -> (low, high), or None
    correlation: np.ndarray  # on identifiable parameters (NaN rows for the others)

    @property
    def identifiable(self) -> tuple[str, ...]:
        return tuple(n for n in self.names if self.std_errors[n] is not None)

    def __str__(self) -> str:
        lines = [f"Identifiability of {len(self.names)} free parameters: "
                 f"rank {len(self.names) - len(self.null_directions)}, condition number "
                 f"{self.condition_number:.3g}"]
        sv = ", ".join(f"{s:.2e}" for s in self.singular_values)
        lines.append(f"  singular values / σ1: {sv}")
        for d in self.null_directions:
            lines.append(f"  NOT identifiable: {d['text']}")
        if self.suggest_fix:
            lines.append(f"  fix {', '.join(self.suggest_fix)} (or report the invariant "
                         "combinations) to make the rest identifiable")
        for n, v in zip(self.names, self.values, strict=True):
            se = self.std_errors[n]
            if se is None:
                lines.append(f"  {n:<9}= {v:.6g}  not identifiable from these data")
            else:
                lo, hi = self.intervals[n]
                lines.append(f"  {n:<9}= {v:.6g} ± {se:.2g}  (95 %: {lo:.6g} … {hi:.6g})")
        return "\n".join(lines)


def _rref(A, tol=1e-9):
    """Reduced row-echelon form of A (k × n) and its pivot columns."""
    A = np.array(A, dtype=float)
    pivots, row = [], 0
    for col in range(A.shape[1]):
        if row >= A.shape[0]:
            break
        p = row + int(np.argmax(np.abs(A[row:, col])))
        if abs(A[p, col]) < tol:
            continue
        A[[row, p]] = A[[p, row]]
        A[row] /= A[row, col]
        for r in range(A.shape[0]):
            if r != row:
                A[r] -= A[r, col] * A[row]
        pivots.append(col)
        row += 1
    return A, pivots


def _power_law_text(exponents: dict) -> str:
    terms = " · ".join(f"{n}^{p:+.3g}" for n, p in exponents.items())
    return f"the output is unchanged along {terms} (θ → θ·s^p for each listed θ)"


def identifiability(problem: Problem, params: Parameters, null_tol: float = 1e-8
                    ) -> IdentifiabilityReport:
    """Identifiability report of ``problem``'s free parameters at ``params`` (see module
    docstring). ``null_tol``: σ/σ₁ below which a direction counts as structurally null."""
    space = problem.space
    free = list(space.free)
    names = space.names
    theta = np.asarray(params.to_array())
    values = theta[free]
    width = np.asarray(space.upper - space.lower)
    # θ = θ0·(1 + x): x is d log|θ| (sign kept for negative θ such as α̃)
    scale = np.where(values != 0, values, np.where(width > 0, width, 1.0))

    def output(x):  # x: relative change of each free parameter
        full = jnp.asarray(theta).at[jnp.array(free)].set(jnp.asarray(values) + x * scale)
        return problem.predict(Parameters.from_array(full))

    J = np.asarray(jax.jacfwd(output)(jnp.zeros(len(free))))
    e = np.asarray(problem.predict(params) - problem.data)
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    rel = s / s[0] if s[0] > 0 else s
    null = rel < null_tol
    rank = int(np.sum(~null))
    null_dirs, fix = [], ()
    if np.any(null):
        basis, pivots = _rref(Vt[null])
        fix = tuple(names[p] for p in pivots)
        for row in basis:
            row = np.where(np.abs(row) < 1e-6, 0.0, row)
            # express as exponents, largest magnitude 1
            row = row / np.max(np.abs(row))
            exps = {names[i]: float(np.round(row[i], 3)) for i in np.flatnonzero(row)}
            null_dirs.append({"exponents": exps, "text": _power_law_text(exps)})
    dof = max(len(e) - rank, 1)
    sigma = float(np.sqrt(np.sum(e**2) / dof))
    # pseudo-inverse of JᵀJ on the identifiable subspace
    inv = (Vt[~null].T / s[~null] ** 2) @ Vt[~null]
    cov_rel = sigma**2 * inv  # covariance of relative changes
    in_null = np.zeros(len(free), bool)
    if np.any(null):
        in_null = np.max(np.abs(Vt[null]), axis=0) > 1e-6
    se, ci = {}, {}
    for i, n in enumerate(names):
        if in_null[i]:
            se[n] = ci[n] = None
        else:
            se[n] = float(np.sqrt(max(cov_rel[i, i], 0.0)) * abs(scale[i]))
            ci[n] = (float(values[i] - Z95 * se[n]), float(values[i] + Z95 * se[n]))
    d = np.sqrt(np.clip(np.diag(cov_rel), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov_rel / np.outer(d, d)
    corr[in_null, :] = np.nan
    corr[:, in_null] = np.nan
    cond = float(s[0] / s[~null][-1]) if rank else float("inf")
    return IdentifiabilityReport(
        names=names, values=values, singular_values=rel, condition_number=cond,
        null_directions=null_dirs, suggest_fix=fix, sigma=sigma, std_errors=se,
        intervals=ci, correlation=corr,
    )  # fmt: skip


__all__ = ["IdentifiabilityReport", "identifiability", "NAMES"]
