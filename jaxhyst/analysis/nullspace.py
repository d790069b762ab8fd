"""The linear analysis of a whitened Jacobian in log coordinates (NumPy only): singular
values, null directions in reduced row-echelon form (which names the parameters to fix),
the Gauss–Newton covariance, standard errors and intervals (see
`jaxhyst.analysis.identifiability` for the method)."""

from __future__ import annotations

import numpy as np

from .wording import Z95, base_name, clean, transform_text

#: Order in which parameters are preferred as the ones to fix (pivots of the null basis):
#: material constants from datasheets first, then the measurable mass, then the rest.
PREFER_FIX = ("Ms", "lambda_s", "Mz", "E", "Kz", "Cz", "alpha", "c", "a", "k")

#: Combinations with a larger exponent are not listed (not a meaningful invariant).
MAX_EXPONENT = 10.0


def _preference(names) -> list[int]:
    rank = {n: i for i, n in enumerate(PREFER_FIX)}
    return sorted(range(len(names)), key=lambda i: (rank.get(base_name(names[i]), 99), i))


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


def analyse(names, values, scale, J, e, null_tol) -> dict:
    """The NumPy part of the analysis on the whitened Jacobian ``J`` and residuals ``e``
    (so that sub-problems can be re-analysed): covariance (JᵀJ)⁺."""
    names = list(names)
    n = len(names)
    U, s, Vt = np.linalg.svd(J, full_matrices=False)
    rel = s / s[0] if s.size and s[0] > 0 else np.zeros_like(s)
    null = rel < null_tol
    rank = int(np.sum(~null))
    null_dirs, fix, combos = [], (), []
    if np.any(null):
        order = _preference(names)
        basis_p, piv_p = _rref(Vt[null][:, order])
        basis = np.zeros_like(basis_p)
        basis[:, order] = basis_p
        pivots = [order[c] for c in piv_p]
        fix = tuple(names[p] for p in pivots)
        for row in basis:
            row = clean(row / np.max(np.abs(row)))
            exps = {names[i]: float(row[i]) for i in np.flatnonzero(row)}
            null_dirs.append({"exponents": exps, "text": transform_text(exps)})
        touched = np.flatnonzero(np.any(np.abs(basis) > 1e-6, axis=0))
        for f in touched:
            if f in pivots:
                continue
            p = np.zeros(n)
            p[f] = 1.0
            for r, piv in enumerate(pivots):
                p[piv] = -basis[r, f]
            p = clean(p)
            combos.append({names[i]: float(p[i]) for i in np.flatnonzero(p)})
    dof = max(J.shape[0] - rank, 1)
    sigma = float(np.sqrt(np.sum(e**2) / dof))  # ≈ 1 for well-whitened residuals
    cov = (Vt[~null].T / s[~null] ** 2) @ Vt[~null]  # (JᵀJ)⁺ on the identifiable subspace
    in_null = np.max(np.abs(Vt[null]), axis=0) > 1e-6 if np.any(null) else np.zeros(n, bool)
    se, ci = {}, {}
    for i, name in enumerate(names):
        if in_null[i]:
            se[name] = ci[name] = None
        else:
            se[name] = float(np.sqrt(max(cov[i, i], 0.0)) * abs(scale[i]))
            ci[name] = (float(values[i] - Z95 * se[name]), float(values[i] + Z95 * se[name]))
    d = np.sqrt(np.clip(np.diag(cov), 0, None))
    with np.errstate(invalid="ignore", divide="ignore"):
        corr = cov / np.outer(d, d)
    corr[in_null, :] = np.nan
    corr[:, in_null] = np.nan
    cond = float(s[0] / s[~null][-1]) if rank else float("inf")
    return dict(names=tuple(names), singular_values=rel, condition_number=cond,
                null_directions=null_dirs, suggest_fix=fix, combos=combos, sigma=sigma,
                dof=dof, std_errors=se, intervals=ci, correlation=corr, cov_log=cov,
                null_space=Vt[null])

