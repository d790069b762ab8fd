"""Local identifiability of the free parameters of a problem at a parameter point.

Coordinates: relative changes of the free parameters, x_r = d log|θ_r| (θ = θ0·(1 + x)),
so a null direction reads directly as a power law: the output is unchanged when θ_r is
multiplied by s^{v_r}. For a parameter at exactly 0 the box width is used as its scale.

- Jacobian J = ∂y/∂x from ``jax.jacfwd`` (output units), singular values and condition
  number.
- Null directions: right singular vectors with σ/σ₁ below ``null_tol`` (structural
  non-identifiability gives ~1e-15). The null space is put in reduced row-echelon form,
  which makes each direction sparse and names it (``Ms^+1 · alpha^-1``: the output is
  unchanged under Ms → s·Ms, alpha → alpha/s). Found from J, never hard-coded. The
  columns are ordered by `PREFER_FIX` first, so the echelon pivots — the parameters to fix
  — are the ones a user is most likely to know (datasheet Ms and λs, the weighed mass).
- Identifiable combinations: for every non-pivot parameter f touched by a null direction,
  the power product θ_f · Π θ_pivot^(−B[row, f]) is invariant along all null directions
  (B the echelon basis); its value, standard error and interval are reported.
- Residual groups: each of the problem's groups is whitened by its noise level σ_g —
  the one it declares, or, where it declares none, σ̂_g² = RSS_g/(N_g − n·N_g/N) from
  the fit (its share of the degrees of freedom) — and priors by their sd. The report
  lists σ per group.
- Gauss–Newton covariance of x: (JwᵀJw)⁺ of the whitened Jacobian on the identifiable
  subspace; standard errors and 95 % intervals (normal quantile 1.96) for parameters
  with no component along a null direction; the others are reported as "not
  identifiable" rather than with a huge or NaN interval. An identifiable parameter whose
  relative standard error exceeds ``max_rel_se`` (default 0.5) is "poorly determined"
  (practical non-identifiability: it depends on the noise level).
- Parameters at a bound (within `BOUND_TOL` of the box width): active constraints of
  the fit. They are left out of the analysis (never reported as null directions, no
  interval: the optimum is constrained there) and listed in ``at_bound``. An interior
  value whose interval reaches beyond a bound is marked "near" it.
- Only finite combinations with moderate exponents (|p| ≤ 10) are listed.
"""

from __future__ import annotations

import re
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..identify.result import bound_status
from ..params import NAMES, UNITS

Z95 = 1.959963984540054

#: Order in which parameters are preferred as the ones to fix (pivots of the null basis):
#: material constants from datasheets first, then the measurable mass, then the rest.
PREFER_FIX = ("Ms", "lambda_s", "Mz", "E", "Kz", "Cz", "alpha", "c", "a", "k")

#: Combinations with a larger exponent are not listed (not a meaningful invariant).
MAX_EXPONENT = 10.0


def _base_name(name: str) -> str:
    return re.sub(r"\[.*\]$", "", name)


def _preference(names) -> list[int]:
    rank = {n: i for i, n in enumerate(PREFER_FIX)}
    return sorted(range(len(names)), key=lambda i: (rank.get(_base_name(names[i]), 99), i))


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


def _clean(v, tol=1e-6):
    v = np.where(np.abs(v) < tol, 0.0, v)
    return np.round(v, 3) + 0.0


def _power_text(exponents: dict) -> str:
    def term(n, p):
        return n if p == 1 else f"{n}^{p:g}"

    num = [term(n, p) for n, p in exponents.items() if p > 0]
    den = [term(n, -p) for n, p in exponents.items() if p < 0]
    text = "·".join(num) if num else "1"
    if den:
        text += "/" + ("·".join(den) if len(den) == 1 else "(" + "·".join(den) + ")")
    return text


def _transform_text(exponents: dict) -> str:
    def move(n, p):
        if p == 1:
            return f"{n} → s·{n}"
        if p == -1:
            return f"{n} → {n}/s"
        return f"{n} → s^{p:g}·{n}"

    return ("the output is unchanged under "
            + ", ".join(move(n, p) for n, p in exponents.items()) + " for any s > 0")


def _signed_power(values, p) -> float:
    """Π θ_i^p_i, with the sign of negative θ_i kept for odd integer p_i."""
    mag = float(np.prod(np.abs(values) ** p))
    sign = 1.0
    for v, e in zip(values, p, strict=True):
        if v < 0 and e != 0 and float(e).is_integer() and int(e) % 2:
            sign = -sign
    return sign * mag


@dataclass
class IdentifiabilityReport:
    """Result of `identifiability`; NumPy arrays, entries in the order of ``names``.

    ``singular_values`` are relative (σ/σ₁, descending); ``std_errors``/``intervals`` are
    ``None`` for parameters that are not identifiable; ``combinations`` lists the
    identifiable power-product combinations of the non-identifiable parameters with their
    value, standard error and 95 % interval; ``group_sigma`` the noise level of each
    residual group (declared or estimated; ``sigma`` is the first group's), in its unit;
    ``cov_log`` the covariance of d log|θ|; ``jacobian``/``residuals`` are whitened."""

    names: tuple[str, ...]
    values: np.ndarray
    units: tuple[str, ...]
    singular_values: np.ndarray
    condition_number: float
    null_directions: list[dict]
    suggest_fix: tuple[str, ...]
    combinations: list[dict]
    sigma: float
    dof: int
    group_sigma: dict
    std_errors: dict
    intervals: dict
    correlation: np.ndarray
    cov_log: np.ndarray
    null_space: np.ndarray  # orthonormal rows spanning the null directions (x coordinates)
    jacobian: np.ndarray  # ∂y/∂x, (N, n), output unit
    residuals: np.ndarray  # model − data, output unit
    scale: np.ndarray  # θ0 used for x (|θ| or the box width)
    max_rel_se: float = 0.5
    at_bound: dict | None = None  # {name: ("lower" | "upper", bound value)}
    bounds: tuple | None = None  # (lower, upper) of the free values, SI

    @property
    def identifiable(self) -> tuple[str, ...]:
        return tuple(n for n in self.names if self.std_errors[n] is not None)

    @property
    def rank(self) -> int:
        """Rank of the Jacobian of the parameters not at a bound."""
        return len(self.names) - len(self.at_bound or {}) - len(self.null_directions)

    def relative_std_errors(self) -> dict:
        """Standard error / |value| (or / box width for a parameter at 0); None if not
        identifiable."""
        out = {}
        for i, n in enumerate(self.names):
            se = self.std_errors[n]
            out[n] = None if se is None else se / abs(self.scale[i])
        return out

    def poorly_determined(self, max_rel_se: float | None = None) -> tuple[str, ...]:
        """Identifiable parameters whose relative standard error exceeds ``max_rel_se``."""
        t = self.max_rel_se if max_rel_se is None else max_rel_se
        return tuple(n for n, r in self.relative_std_errors().items() if r is not None and r > t)

    def combination(self, exponents: dict) -> dict:
        """Value, standard error and 95 % interval of Π θ^p for ``exponents`` {name: p}
        (e.g. ``{"alpha": 1, "Ms": 1}`` for α·Ms); ``identifiable`` False (and no error)
        when the product changes along a null direction or involves a parameter at a
        bound (then listed in ``at_bound``)."""
        unknown = [n for n in exponents if n not in self.names]
        if unknown:
            raise ValueError(f"{unknown} are not free parameters of this report "
                             f"({list(self.names)}); combine free parameters only.")
        p = np.array([float(exponents.get(n, 0.0)) for n in self.names])
        value = _signed_power(self.values, p)
        text = _power_text({n: exponents[n] for n in self.names if exponents.get(n, 0)})
        held = sorted(n for n in (self.at_bound or {}) if exponents.get(n, 0))
        if held:  # a bound holds part of it: no interval from the unconstrained analysis
            return {"exponents": dict(exponents), "text": text, "value": value,
                    "identifiable": False, "std_error": None, "interval": None,
                    "at_bound": held}
        ok = self.null_space.size == 0 or (
            np.linalg.norm(self.null_space @ p) <= 1e-6 * max(np.linalg.norm(p), 1e-300))
        if not ok:
            return {"exponents": dict(exponents), "text": text, "value": value,
                    "identifiable": False, "std_error": None, "interval": None}
        se = abs(value) * float(np.sqrt(max(p @ self.cov_log @ p, 0.0)))
        return {"exponents": dict(exponents), "text": text, "value": value,
                "identifiable": True, "std_error": se,
                "interval": (value - Z95 * se, value + Z95 * se)}

    def suggest_fixed(self, max_rel_se: float | None = None) -> tuple[str, ...]:
        """Parameters to fix so that the rest are identifiable and determined to
        ``max_rel_se``: the structural pivots (`suggest_fix`), then, greedily, the worst
        poorly determined parameter until none is left (re-analysing the remaining
        columns of the same Jacobian each time)."""
        t = self.max_rel_se if max_rel_se is None else max_rel_se
        fixed = list(self.suggest_fix)
        held = set(self.at_bound or {})  # active constraints: held already
        while True:
            keep = [i for i, n in enumerate(self.names) if n not in fixed and n not in held]
            if not keep:
                return tuple(fixed)
            sub = _analyse([self.names[i] for i in keep], self.values[keep],
                           self.scale[keep], self.jacobian[:, keep], self.residuals, 1e-8)
            if sub["null_directions"]:  # cannot happen after fixing the pivots
                fixed += list(sub["suggest_fix"])
                continue
            rel = {n: sub["std_errors"][n] / abs(self.scale[keep][j])
                   for j, n in enumerate(sub["names"])}
            worst = max(rel, key=rel.get)
            if rel[worst] <= t:
                return tuple(fixed)
            fixed.append(worst)

    def to_dict(self) -> dict:
        """JSON-ready summary (no Jacobian)."""
        def f(x):
            return None if x is None else float(x)

        return {
            "names": list(self.names), "rank": self.rank,
            "singular_values": [float(s) for s in self.singular_values],
            "at_bound": {n: {"bound": b, "value": float(v)}
                         for n, (b, v) in (self.at_bound or {}).items()},
            "condition_number": float(self.condition_number),
            "null_directions": self.null_directions, "suggest_fix": list(self.suggest_fix),
            "poorly_determined": list(self.poorly_determined()),
            "combinations": [{**c, "interval": None if c["interval"] is None
                              else [float(c["interval"][0]), float(c["interval"][1])]}
                             for c in self.combinations],
            "sigma": self.sigma, "dof": self.dof,
            "group_sigma": {k: {"sigma": v[0], "estimated": v[1]}
                            for k, v in self.group_sigma.items()},
            "parameters": {n: {"value": float(v), "unit": u, "std_error": f(self.std_errors[n]),
                               "interval": None if self.intervals[n] is None
                               else [float(x) for x in self.intervals[n]]}
                           for n, v, u in zip(self.names, self.values, self.units, strict=True)},
            "correlation": [[None if not np.isfinite(c) else float(c) for c in row]
                            for row in self.correlation],
        }  # fmt: skip

    def __str__(self) -> str:
        sig = ", ".join(f"{k} {v[0]:.3g}{' (est.)' if v[1] else ''}"
                        for k, v in self.group_sigma.items())
        at = self.at_bound or {}
        held = f" ({len(at)} at a bound, left out)" if at else ""
        lines = [f"Identifiability of {len(self.names)} free parameters{held}: rank "
                 f"{self.rank}, condition number {self.condition_number:.3g}; noise σ: {sig}"]
        lines.append("  singular values / σ1: "
                     + ", ".join(f"{s:.2e}" for s in self.singular_values))
        for d in self.null_directions:
            lines.append(f"  NOT identifiable: {d['text']}")
        if self.suggest_fix:
            lines.append(f"  fix {', '.join(self.suggest_fix)} (or report the combinations "
                         "below) to make the rest identifiable")
        poor = self.poorly_determined()
        for i, n in enumerate(self.names):
            v, u = self.values[i], self.units[i]
            se = self.std_errors[n]
            if n in at:
                lines.append(f"  {n:<9}= {v:.6g} {u}  AT ITS {at[n][0].upper()} BOUND: an "
                             "active constraint, no interval (widen the bound if a value "
                             "beyond it is physical)")
            elif se is None:
                lines.append(f"  {n:<9}= {v:.6g} {u}  not identifiable from these data")
            else:
                lo, hi = self.intervals[n]
                tag = "  poorly determined" if n in poor else ""
                if self.bounds is not None and lo < self.bounds[0][i]:
                    tag += "  (near its lower bound: the interval reaches beyond it)"
                if self.bounds is not None and hi > self.bounds[1][i]:
                    tag += "  (near its upper bound: the interval reaches beyond it)"
                lines.append(f"  {n:<9}= {v:.6g} ± {se:.2g} {u}  (95 %: {lo:.6g} … {hi:.6g})"
                             f"{tag}")
        for c in self.combinations:
            lo, hi = c["interval"]
            lines.append(f"  {c['text']} = {c['value']:.6g} ± {c['std_error']:.2g}  "
                         f"(95 %: {lo:.6g} … {hi:.6g})  identifiable combination")
        return "\n".join(lines)


def _analyse(names, values, scale, J, e, null_tol) -> dict:
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
            row = _clean(row / np.max(np.abs(row)))
            exps = {names[i]: float(row[i]) for i in np.flatnonzero(row)}
            null_dirs.append({"exponents": exps, "text": _transform_text(exps)})
        touched = np.flatnonzero(np.any(np.abs(basis) > 1e-6, axis=0))
        for f in touched:
            if f in pivots:
                continue
            p = np.zeros(n)
            p[f] = 1.0
            for r, piv in enumerate(pivots):
                p[piv] = -basis[r, f]
            p = _clean(p)
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


#: Relative resolution of float64 data: the floor of an estimated noise level.
_RESOLUTION = float(np.finfo(np.float64).eps)


def whitened_log_jacobian(problem, x0, scale):
    """(Jw, ew, σ) at the free values ``x0``: the Jacobian of every residual with respect
    to dx at dx = 0 for x = x0 + dx·scale (relative coordinates when scale = x0), and
    the residuals, each group divided by its noise level σ_g (declared, or estimated as
    √(RSS_g/(N_g − n·N_g/N)), but not below 2.2e-16 times the group's scale), priors by
    their sd; σ: the σ_g used, shape (groups,). One forward pass (the residuals ride
    along as jacfwd's aux). Traceable: used jitted here and inside the vmapped replicate
    fits."""
    space = problem.space
    groups = problem.groups
    n = x0.shape[0]

    def raw(dx):
        r = problem.group_residuals(space.params_from_free(x0 + dx * scale))
        flat = jnp.concatenate([jnp.ravel(g) for g in r])
        return flat, flat

    J, e = jax.jacfwd(raw, has_aux=True)(jnp.zeros_like(x0))
    sizes = np.array([g.size for g in groups])
    N = int(sizes.sum())
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    sig = []
    for k, g in enumerate(groups):
        if g.sigma is not None:
            sig.append(jnp.asarray(g.sigma, dtype=e.dtype))
        else:
            dof = max(g.size - n * g.size / N, 1.0)
            rss = jnp.sum(e[bounds[k]:bounds[k + 1]] ** 2)
            # no estimate below the data's float64 resolution: data an exact fit
            # reproduces bit for bit (simulated, noise-free) would give σ = 0
            sig.append(jnp.maximum(jnp.sqrt(rss / dof), _RESOLUTION * jnp.abs(g.scale)))
    sigma = jnp.stack(sig)
    per_row = jnp.repeat(sigma, sizes, total_repeat_length=N)
    per_row = jnp.where(per_row > 0, per_row, 1.0)
    Jw, ew = J / per_row[:, None], e / per_row
    if problem.priors:
        idx = np.array([space.names.index(p.name) for p in problem.priors])
        sd = np.array([p.sd for p in problem.priors])
        mean = np.array([p.mean for p in problem.priors])
        Jp = jnp.zeros((len(idx), n), e.dtype).at[np.arange(len(idx)), idx].set(
            scale[idx] / sd)
        Jw = jnp.concatenate([Jw, Jp])
        ew = jnp.concatenate([ew, (x0[idx] - mean) / sd])
    return Jw, ew, sigma


_log_jacobian = eqx.filter_jit(whitened_log_jacobian)


def identifiability(problem, params, null_tol: float = 1e-8, max_rel_se: float = 0.5
                    ) -> IdentifiabilityReport:
    """Identifiability report of ``problem``'s free parameters at ``params`` (see the module
    docstring).

    **Arguments:**
    - ``problem``: any problem of the identification protocol
      (`jaxhyst.identify.AbstractProblem`).
    - ``params``: the parameter point, usually the fitted one.
    - ``null_tol``: σ/σ₁ below which a direction counts as structurally null.
    - ``max_rel_se``: relative standard error above which an identifiable parameter is
      flagged as poorly determined.
    """
    space = problem.space
    names = tuple(space.names)
    values = np.asarray(space.free_values(params), dtype=float)
    width = np.asarray(space.upper - space.lower)
    # signed θ0, so that x = dθ/θ0 = d log|θ| also for negative θ (α̃)
    scale = np.where(values != 0, values, np.where(width > 0, width, 1.0))
    J, e, sigma = (np.asarray(a) for a in _log_jacobian(problem, jnp.asarray(values),
                                                         jnp.asarray(scale)))
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(e))):
        raise ValueError("The model output or its Jacobian is not finite at these parameters; "
                         "the identifiability analysis needs a point where the model runs.")
    lower, upper = np.asarray(space.lower), np.asarray(space.upper)
    status = bound_status(values, lower, upper)
    at_bound = {names[i]: (b, float(lower[i] if b == "lower" else upper[i]))
                for i, b in status.items()}
    keep = [i for i in range(len(names)) if i not in status]
    if not keep:
        raise ValueError(f"every free parameter ({', '.join(names)}) is at a bound; the fit "
                         "is constrained everywhere: widen the bounds.")
    a = _expand(_analyse([names[i] for i in keep], values[keep], scale[keep], J[:, keep], e,
                         null_tol), names, keep)
    group_sigma = {g.name: (float(s), g.sigma is None)
                   for g, s in zip(problem.groups, sigma, strict=True)}
    combos = []
    units = tuple(_unit(n) for n in names)
    rep = IdentifiabilityReport(
        names=names, values=values, units=units, singular_values=a["singular_values"],
        condition_number=a["condition_number"], null_directions=a["null_directions"],
        suggest_fix=a["suggest_fix"], combinations=combos,
        sigma=float(sigma[0]), dof=a["dof"], group_sigma=group_sigma,
        std_errors=a["std_errors"], intervals=a["intervals"], correlation=a["correlation"],
        cov_log=a["cov_log"], null_space=a["null_space"], jacobian=J, residuals=e,
        scale=scale, max_rel_se=max_rel_se, at_bound=at_bound, bounds=(lower, upper),
    )  # fmt: skip
    for c in a["combos"]:
        if max(abs(p) for p in c.values()) > MAX_EXPONENT:
            continue
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            combo = rep.combination(c)
        if np.isfinite(combo["value"]) and combo["std_error"] is not None and \
                np.isfinite(combo["std_error"]):
            combos.append(combo)
    return rep


def _expand(a: dict, names, keep) -> dict:
    """The analysis of the columns ``keep`` written back to all ``names`` (the others —
    parameters at a bound — with no error, zero covariance, NaN correlation)."""
    n, k = len(names), np.asarray(keep)
    if len(keep) == n:
        return a
    cov = np.zeros((n, n))
    cov[np.ix_(k, k)] = a["cov_log"]
    corr = np.full((n, n), np.nan)
    corr[np.ix_(k, k)] = a["correlation"]
    null = np.zeros((a["null_space"].shape[0], n))
    null[:, k] = a["null_space"]
    se = {nm: a["std_errors"].get(nm) for nm in names}
    ci = {nm: a["intervals"].get(nm) for nm in names}
    return {**a, "names": tuple(names), "cov_log": cov, "correlation": corr,
            "null_space": null, "std_errors": se, "intervals": ci}


def _unit(name: str) -> str:
    return UNITS.get(_base_name(name), "")


__all__ = ["IdentifiabilityReport", "identifiability", "PREFER_FIX", "NAMES"]
