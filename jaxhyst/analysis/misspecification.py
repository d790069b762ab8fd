"""Is the model able to explain the data? Tests of the residuals at a fit, named in the
identifiability report, with the intervals widened where they fail.

- **Declared noise** (every residual group has its σ): the cost is a χ² with N − n
  degrees of freedom if the model is right; a cost beyond its 0.1 % upper quantile (the
  normal approximation √(2χ²) − √(2ν − 1) > 3.09) is a lack of fit.
- **Estimated noise**: the residuals of a right model are noise, uncorrelated from
  sample to sample; a lag-1 autocorrelation r₁ along each group's samples beyond
  3.29/√N (two-sided 0.1 %) means they carry structure the model does not (a wrong law, a
  missing loss, a shape it cannot draw).

Where a test fails the report says so, and the intervals are widened: by the variance
inflation (1 + r₁)/(1 − r₁) of an AR(1) sequence of that correlation for correlated
residuals (the effective number of independent samples is smaller), by χ²/ν for a lack of
fit with declared noise (the noise the data show, not the one declared).
"""

from __future__ import annotations

import math

import numpy as np

#: Two-sided 0.1 % quantile of a standard normal (the tests' level).
Z_TEST = 3.2905267314918945
#: Its one-sided counterpart (the χ² test is one-sided).
Z_ONE = 3.090232306167813


def lag1(r: np.ndarray) -> float:
    """The lag-1 autocorrelation of the sequence r (0 for fewer than 3 samples)."""
    r = np.asarray(r, float) - np.mean(r)
    denom = float(np.dot(r, r))
    if r.shape[0] < 3 or not denom > 0:
        return 0.0
    return float(np.dot(r[:-1], r[1:]) / denom)


def misspecification(problem, e: np.ndarray, n_free: int) -> tuple[str | None, float]:
    """(what the residual tests found, or None; the factor by which the covariance is
    widened, ≥ 1) for the whitened residuals ``e`` of ``problem`` (its groups' rows in
    order, priors after them) at a fit with ``n_free`` free parameters."""
    groups = problem.groups
    sizes = [g.size for g in groups]
    data = np.asarray(e[:sum(sizes)], float)
    if all(g.sigma is not None for g in groups):
        chi2 = float(np.sum(data**2))  # (padded rows are 0)
        nu = max(sum(int(g.count) for g in groups) - n_free, 1)
        z = math.sqrt(2.0 * chi2) - math.sqrt(2.0 * nu - 1.0)
        if z > Z_ONE:
            return (f"lack of fit: χ² = {chi2:.4g} for {nu} degrees of freedom "
                    f"({chi2 / nu:.3g} per degree; P < 0.001): the residuals exceed the "
                    "declared noise, so the model does not explain the data; intervals "
                    f"widened ×{math.sqrt(chi2 / nu):.3g}"), chi2 / nu
        return None, 1.0
    ends = np.cumsum([0, *sizes])
    r1s, weights = [], []
    for k, g in enumerate(groups):
        if g.count < 20:
            continue
        r1s.append(lag1(g.observed(data[ends[k]:ends[k + 1]])))
        weights.append(int(g.count))
    if not r1s:
        return None, 1.0
    r1 = float(np.average(r1s, weights=weights))
    N = sum(weights)
    if r1 <= Z_TEST / math.sqrt(N):
        return None, 1.0
    r1 = min(r1, 0.999)
    factor = (1.0 + r1) / (1.0 - r1)
    return (f"structured residuals: lag-1 autocorrelation {r1:.2f} along the samples "
            f"(noise would give |r₁| < {Z_TEST / math.sqrt(N):.2g}): the model does not "
            f"explain the data (a wrong law, a missing effect); intervals widened "
            f"×{math.sqrt(factor):.3g} for the correlation"), factor
