"""95 % intervals that account for the box: the Gauss–Newton (linearised) profile
likelihood with the active bounds as constraints (NumPy only).

At a fit, the cost near the optimum is the quadratic χ²(x) ≈ χ²_u + (x − x̃)ᵀA(x − x̃) in
the relative coordinates x = (θ − θ̂)/θ₀ of `jaxhyst.analysis.identifiability` (A = JᵀJ of
the whitened Jacobian, x̃ = −A⁺Jᵀe the unconstrained Gauss–Newton optimum). Where no bound
is active, x̃ = 0 and the 95 % profile interval of each parameter is the Wald interval
θ̂ ± 1.96·se. Where some parameters ended on their bound, holding them fixed would shrink
every correlated interval (they are constraints, not knowledge); leaving them free would
centre the others at an optimum outside the box. The profile of parameter i is instead

    P_i(v) = min { χ²(x) : x_i = v, the parameters at a bound on their side of it },

(each active set of the bound parameters tried: the minimum of the quadratic with some of
them held at their bound is a Schur complement of the covariance C = A⁺), and the
interval is {v in the box : P_i(v) − min P_i ≤ c(v)}. For a parameter at its bound this
is one-sided: from the bound to where the profile has risen by c.

The threshold c(v) is Feldman and Cousins' (Phys. Rev. D 57 (1998) 3873) for a Gaussian
estimate of a quantity that cannot pass a bound: the 95 % quantile of the likelihood
ratio when the true value is v, t = |v − bound|/se from the parameter's own box end —
2.71 at the bound, rising to 3.84 (χ²₁) a few standard errors away. With 3.84
everywhere, a one-sided interval would hold a true value near its bound whenever the fit
ends there, and cover it in ~97.5 % instead of 95 %. A parameter correlated (ρ) with one
at its bound shares that effect: its threshold is lowered by ρ² of the bound parameter's
(at the bound parameter's conditional optimum) — an approximation of the exact
two-parameter construction. Each interval says how it was made (`METHODS`).
"""

from __future__ import annotations

import itertools
import math

import numpy as np

from .wording import Z95

#: How each interval was made.
METHODS = {
    "wald": "Wald (linearised, no bound active)",
    "bound-aware": "linearised profile with the active bounds",
    "one-sided": "one-sided linearised profile from the bound",
    "near-bound": "linearised profile near the box end (no bound active)",
}
#: Most bound parameters whose active sets are enumerated (2^k sets per evaluation).
MAX_BOUND = 8
_GRID = 4001
#: Within this many standard errors of its own box end a parameter's interval is the
#: bounded construction (beyond it, the Wald interval).
NEAR_BOUND = 6.0


def _phi(x: float) -> float:
    """The standard normal distribution function at the number ``x``."""
    return 0.5 * (1.0 + math.erf(x / math.sqrt(2.0)))


def _coverage_at(t, c):
    """P(Δ ≤ c) for a true value t standard errors inside the bound (module docstring):
    Δ = z² where the estimate stays inside, t·(−2z − t) where it is censored at the bound
    (z < −t), z ~ N(0, 1)."""
    root = math.sqrt(c)
    inside = _phi(root) - _phi(max(-t, -root))
    if t <= 0:
        return float(inside + 0.5)
    censored = max(0.0, float(_phi(-t) - _phi(-(c / t + t) / 2.0)))
    return float(inside + censored)


def _critical(t: float, level: float = 0.95) -> float:
    lo, hi = 1.0, 3.9
    for _ in range(60):  # bisection: the coverage grows with c
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if _coverage_at(t, mid) < level else (lo, mid)
    return 0.5 * (lo + hi)


#: Feldman–Cousins critical values c(t) on a grid of t (standard errors from the bound).
_T = np.linspace(0.0, NEAR_BOUND, 121)
_C = np.array([_critical(float(t)) for t in _T])


def critical_value(t):
    """The 95 % likelihood-ratio threshold for a true value ``t`` standard errors from
    the bound (2.71 at it, 3.84 far from it)."""
    return np.interp(np.abs(t), _T, _C, right=Z95**2)


def _profile(v, i, x_tilde, C, bound_idx, bound_x, side):
    """P_i(v) − (quadratic's unconstrained minimum) for the values ``v`` (shape (G,)):
    the minimum over the feasible active sets of the bound parameters."""
    best = np.full(v.shape, np.inf)
    others = [b for b in bound_idx if b != i]
    for k in range(len(others) + 1):
        for held in itertools.combinations(others, k):
            F = [i, *held]
            S = C[np.ix_(F, F)]
            try:
                S_inv = np.linalg.inv(S)
            except np.linalg.LinAlgError:
                continue
            d = np.empty((v.shape[0], len(F)))
            d[:, 0] = v - x_tilde[i]
            for c, b in enumerate(held, start=1):
                d[:, c] = bound_x[b] - x_tilde[b]
            value = np.einsum("gi,ij,gj->g", d, S_inv, d)
            feasible = np.ones(v.shape, bool)
            free = [b for b in others if b not in held]
            if free:  # the free bound parameters must stay on their side
                x_free = x_tilde[free][None, :] + d @ (S_inv @ C[np.ix_(F, free)])
                for c, b in enumerate(free):
                    feasible &= side[b] * (x_free[:, c] - bound_x[b]) >= -1e-12
            best = np.where(feasible & (value < best), value, best)
    return best


def held_at_bounds(C, held) -> np.ndarray:
    """The covariance ``C`` (n × n) conditional on the parameters ``held`` (indices: those
    on a bound) staying where they are: C_AA − C_AB·C_BB⁺·C_BA on the others, zero rows and
    columns for the held ones. Its columns are the linearised profile paths with the
    active bounds as constraints — the paths the bound-aware intervals follow."""
    if not held:
        return C
    free = [i for i in range(C.shape[0]) if i not in held]
    A, B = np.ix_(free, free), np.ix_(held, held)
    AB = C[np.ix_(free, held)]
    out = np.zeros_like(C)
    out[A] = C[A] - AB @ np.linalg.pinv(C[B]) @ AB.T
    return out


def bound_aware_intervals(J, e, box_x, at_bound: dict[int, str], identifiable,
                          z: float = Z95):
    """95 % intervals in the relative coordinates x (see the module docstring).

    **Arguments:** ``J`` whitened Jacobian (N × n) and ``e`` whitened residuals (N,) at
    the fit (x = 0); ``box_x`` (n × 2): each parameter's box in x (ordered); ``at_bound``
    {index: "lower" | "upper"} in x's orientation; ``identifiable`` (n,) bool: False for
    parameters along a null direction (no interval).

    **Returns:** (lo (n,), hi (n,), methods (n,) keys of `METHODS` or None), NaN where no
    interval is given. Intervals are limited to the box."""
    n = J.shape[1]
    A = J.T @ J
    C = np.linalg.pinv(A, rcond=1e-12)
    bound_idx = sorted(at_bound)[:MAX_BOUND]
    x_tilde = -C @ (J.T @ e) if bound_idx else np.zeros(n)
    side = {b: (1.0 if at_bound[b] == "lower" else -1.0) for b in bound_idx}
    bound_x = {b: box_x[b, 0] if at_bound[b] == "lower" else box_x[b, 1] for b in bound_idx}
    lo, hi = np.full(n, np.nan), np.full(n, np.nan)
    methods = [None] * n
    for i in range(n):
        if not identifiable[i] or not C[i, i] > 0:
            continue
        se = np.sqrt(C[i, i])
        near = min(-box_x[i, 0], box_x[i, 1]) < NEAR_BOUND * se
        if not bound_idx and not near:
            lo[i], hi[i] = -z * se, z * se
            methods[i] = "wald"
            continue
        span = z * se * 6 + abs(x_tilde[i])
        a, b = max(box_x[i, 0], -span), min(box_x[i, 1], span)
        if i in side:  # only its own side of the bound
            a, b = (bound_x[i], b) if side[i] > 0 else (a, bound_x[i])
        v = np.linspace(a, b, _GRID)
        P = _profile(v, i, x_tilde, C, bound_idx, bound_x, side)
        if not np.any(np.isfinite(P)):
            continue
        t = np.minimum(v - box_x[i, 0], box_x[i, 1] - v) / se  # from its own box end
        threshold = critical_value(t)
        for b in bound_idx:  # a bound on a correlated parameter: its share (ρ²) of the
            if b == i:       # boundary effect, at that parameter's conditional optimum
                continue
            rho2 = C[i, b] ** 2 / (C[i, i] * C[b, b])
            sd = np.sqrt(max(C[b, b] * (1.0 - rho2), 1e-300))
            x_b = x_tilde[b] + C[i, b] / C[i, i] * (v - x_tilde[i])
            t_b = np.maximum(side[b] * (x_b - bound_x[b]), 0.0) / sd
            threshold = np.minimum(threshold,
                                   Z95**2 - rho2 * (Z95**2 - critical_value(t_b)))
        excess = P - np.min(P) - threshold * (z / Z95) ** 2
        k = np.flatnonzero(excess <= 0)
        lo[i], hi[i] = _crossing(v, excess, k[0], -1), _crossing(v, excess, k[-1], 1)
        methods[i] = ("one-sided" if i in side else
                      "bound-aware" if bound_idx else "near-bound")
    return lo, hi, methods


def _crossing(v, f, k, direction):
    """Where f (≤ 0 at index k) crosses 0 next to k in ``direction``, interpolated; the
    grid's end where it does not."""
    j = k + direction
    if j < 0 or j >= v.shape[0]:
        return float(v[k])
    t = f[k] / (f[k] - f[j]) if f[k] != f[j] else 0.0
    return float(v[k] + t * (v[j] - v[k]))


def box_in_x(values, scale, lower, upper) -> np.ndarray:
    """Each parameter's box in the relative coordinates x = (θ − θ̂)/θ₀ (θ₀ = ``scale``,
    signed), ordered: shape (n, 2)."""
    values, scale = np.asarray(values, float), np.asarray(scale, float)
    ends = np.stack([(np.asarray(lower, float) - values) / scale,
                     (np.asarray(upper, float) - values) / scale], axis=1)
    return np.sort(ends, axis=1)


def x_side(side: str, scale: float) -> str:
    """A bound's side ("lower"/"upper" in θ) in x's orientation (flipped for θ₀ < 0)."""
    if scale >= 0:
        return side
    return "upper" if side == "lower" else "lower"


def path_point(values, scale, logs, x) -> np.ndarray:
    """The parameters (SI) at the relative coordinates x = d ln|θ| of the report:
    θ·exp(x) for those of one sign by construction (``logs``), θ + x·θ₀ for the others."""
    return np.where(logs, values * np.exp(np.where(logs, x, 0.0)), values + x * scale)
