"""The identifiability report: what `jaxhyst.analysis.identifiability` found, in numbers
and in words (null directions as power laws, identifiable combinations with their
intervals, the parameters to fix)."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .nullspace import analyse
from .wording import Z95


def _power_text(exponents: dict) -> str:
    def term(n, p):
        return n if p == 1 else f"{n}^{p:g}"

    num = [term(n, p) for n, p in exponents.items() if p > 0]
    den = [term(n, -p) for n, p in exponents.items() if p < 0]
    text = "·".join(num) if num else "1"
    if den:
        text += "/" + ("·".join(den) if len(den) == 1 else "(" + "·".join(den) + ")")
    return text


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
    ``None`` for parameters that are not identifiable; ``interval_methods`` says how each
    interval was made (`jaxhyst.analysis.intervals.METHODS`: Wald where no bound is
    active, else the linearised profile with the active bounds — one-sided for a
    parameter at its bound); intervals stay inside the box; ``combinations`` lists the
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
    interval_methods: dict | None = None  # {name: key of intervals.METHODS or None}
    linearity: dict = field(default_factory=dict)  # {name or combination: (lo, hi) ratios}
    misspecified: str | None = None  # what the residual tests found (misspecification)
    unbounded: dict = field(default_factory=dict)  # {name: "below"/"above"}: the box ends
    #: {name: {"side": "below"/"above", "between": (θ under c, θ over c or the end
    #: extrapolated), "bracketed": bool}}: ends the profile search did not settle (the
    #: interval holds the bracket's interpolation, or the extrapolation)
    unsettled: dict = field(default_factory=dict)
    #: {"held", "value", "delta_chi2", "values"}: a profile re-fit (``held`` at ``value``)
    #: that ended ``delta_chi2`` below the fit's cost — the fit is not the minimum;
    #: ``values`` are that re-fit's free values (SI). Empty where none did.
    lower_cost: dict = field(default_factory=dict)

    @property
    def identifiable(self) -> tuple[str, ...]:
        return tuple(n for n in self.names if self.std_errors[n] is not None)

    @property
    def rank(self) -> int:
        """Rank of the Jacobian of the free parameters."""
        return len(self.names) - len(self.null_directions)

    def relative_std_errors(self) -> dict:
        """Standard error / |value| (or / box width for a parameter at 0); None if not
        identifiable."""
        out = {}
        for i, n in enumerate(self.names):
            se = self.std_errors[n]
            out[n] = None if se is None else se / abs(self.scale[i])
        return out

    def linear_miss(self) -> dict:
        """``{name: p}``: how often the linear 95 % interval of each checked quantity
        would miss the truth by its own profile likelihood — at each linear end (a
        quantity of one sign: on ln|θ|, `profile_intervals`) the profile's Δχ² is r
        times the threshold (`linearity`), the signed root there 1.96·√r, and
        p = Σ_ends (1 − Φ(1.96·√r)) (0.05 where the quadratic holds at both ends; an
        end the profile does not reach counts 0.5)."""
        from math import erfc, sqrt

        def tail(r):
            return 0.5 if not r > 0 else 0.5 * erfc(Z95 * sqrt(r) / sqrt(2.0))

        return {k: tail(a) + tail(b) for k, (a, b) in self.linearity.items()}

    def nonlinear(self, miss: float = 0.10) -> tuple[str, ...]:
        """Quantities whose linear 95 % interval is materially wrong by their own
        profile: it would miss the truth more often than ``miss`` (twice the 5 % it
        states; `linear_miss`). A profile merely asymmetric — one end too near, the other
        too far, the coverage about right — is not flagged. Their reported intervals are
        the profile's wherever an end moved, flagged or not."""
        return tuple(k for k, p in self.linear_miss().items() if p > miss)

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
        s_log = float(np.sqrt(max(p @ self.cov_log @ p, 0.0)))  # of ln|Π θ^p|
        se = abs(value) * s_log
        # on the log scale: a product keeps its sign (a product of positive parameters
        # stays positive, α̃·Ms keeps α̃'s sign)
        ends = sorted((value * np.exp(-Z95 * s_log), value * np.exp(Z95 * s_log)))
        return {"exponents": dict(exponents), "text": text, "value": value,
                "identifiable": True, "std_error": se, "interval": tuple(ends)}

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
            sub = analyse([self.names[i] for i in keep], self.values[keep],
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
            "nonlinear": list(self.nonlinear()),
            "linear_miss": self.linear_miss(),
            "linearity": {k: list(v) for k, v in self.linearity.items()},
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
            "sigma": self.sigma, "dof": self.dof, "misspecified": self.misspecified,
            "unbounded": dict(self.unbounded),
            "unsettled": {n: {**u, "between": [float(v) for v in u["between"]]}
                          for n, u in self.unsettled.items()},
            "lower_cost": dict(self.lower_cost),
            "group_sigma": {k: {"sigma": v[0], "estimated": v[1]}
                            for k, v in self.group_sigma.items()},
            "parameters": {n: {"value": float(v), "unit": u, "std_error": f(self.std_errors[n]),
                               "interval": None if self.intervals[n] is None
                               else [float(x) for x in self.intervals[n]],
                               "interval_method": (self.interval_methods or {}).get(n)}
                           for n, v, u in zip(self.names, self.values, self.units, strict=True)},
            "correlation": [[None if not np.isfinite(c) else float(c) for c in row]
                            for row in self.correlation],
        }  # fmt: skip

    def __str__(self) -> str:
        sig = ", ".join(f"{k} {v[0]:.3g}" + (f" ({v[1]})" if isinstance(v[1], str) else
                                              " (est.)" if v[1] else "")
                        for k, v in self.group_sigma.items())
        at = self.at_bound or {}
        held = (f" ({len(at)} at a bound: intervals from the profile with that constraint)"
                if at else "")
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
            if se is None or self.intervals.get(n) is None:
                lines.append(f"  {n:<9}= {v:.6g} {u}  not identifiable from these data")
                continue
            lo, hi = self.intervals[n]
            if n in at:
                lines.append(f"  {n:<9}= {v:.6g} {u}  AT ITS {at[n][0].upper()} BOUND "
                             f"(95 %, one-sided: {lo:.6g} … {hi:.6g}; widen the bound if a "
                             "value beyond it is physical)")
                continue
            tag = "  poorly determined" if n in poor else ""
            if self.bounds is not None and (lo <= self.bounds[0][i] or hi >= self.bounds[1][i]):
                tag += "  (the box ends the interval)"
            method = (self.interval_methods or {}).get(n)
            if method == "bound-aware":
                tag += "  (profile with the active bounds)"
            elif method == "profile":
                tag += "  (from the profile likelihood)"
            lines.append(f"  {n:<9}= {v:.6g} ± {se:.2g} {u}  (95 %: {lo:.6g} … {hi:.6g})"
                         f"{tag}")
        for c in self.combinations:
            lo, hi = c["interval"]
            lines.append(f"  {c['text']} = {c['value']:.6g} ± {c['std_error']:.2g}  "
                         f"(95 %: {lo:.6g} … {hi:.6g})  identifiable combination")
        miss = self.linear_miss()
        for k in self.nonlinear():
            a, b = self.linearity[k]
            lines.append(f"  NOT LINEAR: {k}'s linear interval would miss the truth "
                         f"{100 * miss[k]:.0f} % of the time, not 5 % (its profile rises "
                         f"{a:.2g} and {b:.2g} times the threshold at its ends): the "
                         "interval above is the profile's")
        for k, side in self.unbounded.items():
            lines.append(f"  {k}: the data do not bound it {side} inside the box (its "
                         "interval ends at the box's)")
        for k, u in self.unsettled.items():
            end = "lower" if u["side"] == "below" else "upper"
            if u.get("bracketed", True):
                a, b = sorted(u["between"])
                lines.append(f"  {k}: its {end} end was not settled by the profile search "
                             f"(a steep profile, or too few batches): the crossing lies "
                             f"between {a:.6g} and {b:.6g}")
            else:
                lines.append(f"  {k}: its {end} end was not settled by the profile search: "
                             f"the profile stays below the threshold as far as "
                             f"{u['between'][0]:.6g}; the end given, {u['between'][1]:.6g}, "
                             "is extrapolated")
        if self.lower_cost:
            low = self.lower_cost
            lines.append(f"  NOT THE MINIMUM: with {low['held']} held at {low['value']:.6g} "
                         f"the other parameters re-fitted reach a cost lower by Δχ² = "
                         f"{low['delta_chi2']:.3g}: the fit stopped short of the minimum or "
                         "in a local one, and the intervals above describe that point; fit "
                         "again (identify with more --starts; --start RESULT.json where it "
                         "stopped at its step limit)")
        if self.misspecified:
            lines.append(f"  MISSPECIFIED: {self.misspecified}")
        return "\n".join(lines)
