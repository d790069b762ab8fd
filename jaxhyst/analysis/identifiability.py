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

import jax
import jax.numpy as jnp
import numpy as np

from .._traces import kept_jit
from ..identify.problem import content_digest
from ..identify.result import bound_status, params_of
from ..identify.summary import free_values_of
from ..params import NAMES
from .intervals import bound_aware_intervals, box_in_x, x_side
from .misspecification import misspecification
from .nullspace import MAX_EXPONENT, PREFER_FIX, analyse
from .profile_intervals import refine_intervals
from .report import IdentifiabilityReport
from .wording import unit_of

#: float64 resolution: the smallest noise level estimated for a group (relative to its
#: scale), so that data an exact fit reproduces bit for bit do not give σ = 0.
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

    def raw(dx):
        r = problem.group_residuals(space.params_from_free(x0 + dx * scale))
        flat = jnp.concatenate([jnp.ravel(g) for g in r])
        return flat, flat

    J, e = jax.jacfwd(raw, has_aux=True)(jnp.zeros_like(x0))
    return whiten(problem, J, e, x0, scale)


def whiten(problem, J, e, x0, scale):
    """`whitened_log_jacobian` from the Jacobian J (N, n) of the groups' residuals e (N,)
    (their units, concatenated) with respect to dx at x = x0 + dx·scale. Traceable."""
    groups = problem.groups
    space = problem.space
    n = x0.shape[0]
    sizes = np.array([g.size for g in groups])
    N = int(sizes.sum())
    bounds = np.concatenate([[0], np.cumsum(sizes)])
    counts = [g.count for g in groups]  # (observed: padded rows are 0 in J and e)
    n_obs = sum(counts)
    sig = []
    for k, g in enumerate(groups):
        if g.sigma is not None:
            sig.append(jnp.asarray(g.sigma, dtype=e.dtype))
        else:
            dof = jnp.maximum(counts[k] - n * counts[k] / n_obs, 1.0)
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


_log_jacobian = kept_jit(whitened_log_jacobian)
_whiten = kept_jit(whiten)


def _whitened(problem, values, scale, linearization):
    """(Jw, ew, σ) of `whitened_log_jacobian` at the free ``values``: from a fit's own
    ``linearization`` (`IdentificationResult.linearization`) where it was made of this
    problem at these values — no simulation, nothing compiled beyond the whitening —
    else by jacfwd."""
    if linearization is not None:
        at, J, e, digest = linearization
        # (the same problem — its shapes with it — at the same values)
        if np.array_equal(at, values) and digest == content_digest(problem):
            return _whiten(problem, jnp.asarray(np.asarray(J) * scale[None, :]),
                           jnp.asarray(e), jnp.asarray(values), jnp.asarray(scale))
    return _log_jacobian(problem, jnp.asarray(values), jnp.asarray(scale))


def compile_report(problem, values) -> None:
    """Compile the report's whitened Jacobian for ``problem`` (its program depends on the
    problem's structure and shapes only) by evaluating it once at the free ``values``
    (SI, shape (n_free,)) — for a background thread while the fit runs (`jaxhyst.fit`)."""
    x0 = np.asarray(values, dtype=float)
    _log_jacobian(problem, jnp.asarray(x0), jnp.asarray(np.ones_like(x0)))


def identifiability(problem, params, null_tol: float = 1e-8, max_rel_se: float = 0.5,
                    profile: bool = True, linearization=None) -> IdentifiabilityReport:
    """Identifiability report of ``problem``'s free parameters at ``params`` (see the module
    docstring).

    **Arguments:**
    - ``problem``: any problem of the identification protocol
      (`jaxhyst.identify.AbstractProblem`).
    - ``params``: the parameter point, usually the fitted one (its `Parameters`, or the
      `IdentificationResult` itself).
    - ``null_tol``: σ/σ₁ below which a direction counts as structurally null.
    - ``max_rel_se``: relative standard error above which an identifiable parameter is
      flagged as poorly determined.
    - ``profile``: check the linear intervals along the profile likelihood and move the
      ends where the quadratic approximation fails (`jaxhyst.analysis.profile_intervals`:
      a few vmapped batches of constrained re-fits; default). False: the linear
      intervals alone (the report a fit attaches by default: no re-fits).
    - ``linearization``: a fit's `IdentificationResult.linearization` at ``params``: its
      Jacobian is used instead of differentiating the model again (ignored where it was
      made of another problem or at other values).

    The residuals are tested for misspecification (`jaxhyst.analysis.misspecification`):
    where the model cannot explain the data the report says so and its intervals are
    widened.
    """
    space, params = problem.space, params_of(params)
    names = tuple(space.names)
    values = np.asarray(free_values_of(space, params), dtype=float)
    width = np.asarray(space.upper) - np.asarray(space.lower)
    # signed θ0, so that x = dθ/θ0 = d log|θ| also for negative θ (α̃)
    scale = np.where(np.abs(values) > 1e-9 * width, values, np.where(width > 0, width, 1.0))
    J, e, sigma = (np.asarray(a) for a in _whitened(problem, values, scale, linearization))
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(e))):
        raise ValueError("The model output or its Jacobian is not finite at these parameters; "
                         "the identifiability analysis needs a point where the model runs.")
    J, e, sigma, disagree = _declared_sigma_check(problem, J, e, np.asarray(sigma))
    # (an exact fit of noise-free data: its residuals are round-off, where no cost is
    # quadratic and no residual test means anything)
    exact = any(g.sigma is None and float(s) <= 1e-9 * float(np.abs(g.scale))
                for g, s in zip(problem.groups, sigma, strict=True))
    misspecified, inflation = (None, 1.0) if exact else misspecification(problem, e,
                                                                          len(names))
    J = J / np.sqrt(inflation)  # (the covariance, and every interval, widened)
    lower, upper = np.asarray(space.lower), np.asarray(space.upper)
    status = bound_status(values, lower, upper)
    at_bound = {names[i]: (b, float(lower[i] if b == "lower" else upper[i]))
                for i, b in status.items()}
    # every free parameter in the analysis (one at a bound is a constraint, not knowledge:
    # holding it fixed would shrink the intervals of everything correlated with it)
    a = analyse(list(names), values, scale, J, e, null_tol)
    # (J and e alike: the inflated χ² is χ²/inflation, whose unconstrained optimum, where
    # a bound is active, is the same point — J alone would move it √inflation times as far)
    a["intervals"], methods = _bound_aware(names, values, scale, lower, upper, status, J,
                                           e / np.sqrt(inflation), a["std_errors"])
    group_sigma = {g.name: (float(s), g.sigma is None)
                   for g, s in zip(problem.groups, sigma, strict=True)}
    group_sigma.update(disagree)
    combos = []
    units = tuple(unit_of(n) for n in names)
    rep = IdentifiabilityReport(
        names=names, values=values, units=units, singular_values=a["singular_values"],
        condition_number=a["condition_number"], null_directions=a["null_directions"],
        suggest_fix=a["suggest_fix"], combinations=combos,
        sigma=float(sigma[0]), dof=a["dof"], group_sigma=group_sigma,
        std_errors=a["std_errors"], intervals=a["intervals"], correlation=a["correlation"],
        cov_log=a["cov_log"], null_space=a["null_space"], jacobian=J, residuals=e,
        scale=scale, max_rel_se=max_rel_se, at_bound=at_bound, bounds=(lower, upper),
        interval_methods=methods, misspecified=misspecified,
    )  # fmt: skip
    for c in a["combos"]:
        if max(abs(p) for p in c.values()) > MAX_EXPONENT:
            continue
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
            combo = rep.combination(c)
        if np.isfinite(combo["value"]) and combo["std_error"] is not None and \
                np.isfinite(combo["std_error"]):
            combos.append(combo)
    if profile and not exact:
        rep.unbounded = refine_intervals(problem, params, rep, inflation=inflation)
    return rep


def _prior_chi2(problem, points) -> np.ndarray:
    if not problem.priors:
        return np.zeros(points.shape[0])
    idx = [problem.space.names.index(p.name) for p in problem.priors]
    mean = np.array([p.mean for p in problem.priors])
    sd = np.array([p.sd for p in problem.priors])
    return np.sum(((points[:, idx] - mean) / sd) ** 2, axis=1)


#: A declared σ whose whitened residuals' rms lies outside [1/SIGMA_RATIO, SIGMA_RATIO]
#: (in a group of at least `SIGMA_MIN_SIZE` residuals) does not describe the data.
SIGMA_RATIO, SIGMA_MIN_SIZE = 3.0, 20


def _declared_sigma_check(problem, J, e, sigma):
    """(J, e, σ, {group: (σ used, "declared σ disagrees")}) where a residual group's
    declared noise level disagrees with its residuals by more than `SIGMA_RATIO` (a σ set
    only to allow a prior, say): that group is whitened by the residuals' own rms
    instead, so that the intervals reflect the data; the report says so."""
    sizes = [g.size for g in problem.groups]
    ends = np.cumsum([0, *sizes])
    J, e, sigma = J.copy(), e.copy(), sigma.copy()
    out = {}
    for k, g in enumerate(problem.groups):
        if g.sigma is None or g.count < SIGMA_MIN_SIZE:
            continue
        rows = slice(ends[k], ends[k + 1])
        rms = float(np.sqrt(np.sum(e[rows] ** 2) / g.count))  # (padded rows are 0)
        if 1.0 / SIGMA_RATIO <= rms <= SIGMA_RATIO or not rms > 0:
            continue
        J[rows] /= rms
        e[rows] /= rms
        sigma[k] = sigma[k] * rms
        out[g.name] = (float(sigma[k]), f"declared {float(g.sigma):.3g} disagrees with the "
                                        f"residuals ({rms:.2g}×): estimated")
    return J, e, sigma, out


def _bound_aware(names, values, scale, lower, upper, status, J, e, std_errors):
    """({name: 95 % interval (SI) or None}, {name: how it was made}) by the linearised
    profile likelihood with the active bounds as constraints
    (`jaxhyst.analysis.intervals`)."""
    box = box_in_x(values, scale, lower, upper)
    sides = {i: x_side(b, scale[i]) for i, b in status.items()}
    identifiable = np.array([std_errors[n] is not None for n in names])
    lo, hi, how = bound_aware_intervals(J, e, box, sides, identifiable)
    intervals, methods = {}, {}
    for i, n in enumerate(names):
        if how[i] is None:
            intervals[n], methods[n] = None, None
            continue
        ends = sorted((float(values[i] + lo[i] * scale[i]),
                       float(values[i] + hi[i] * scale[i])))
        intervals[n], methods[n] = tuple(ends), how[i]
    return intervals, methods


__all__ = ["IdentifiabilityReport", "identifiability", "PREFER_FIX", "NAMES"]
