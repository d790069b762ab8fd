"""The paper's two gradient algorithms as Optimistix compositions (SPEC §2).

- **LMA** (eqs 24–27): ``DampedNewtonDescent`` (d = −(JᵀJ + h·I)⁻¹Jᵀe, with h = 1/step
  size) driven by `MultiplicativeDamping`: accept a step iff E decreases, then h ← h/10;
  otherwise reject it and h ← 10·h; h1 = 0.01.
- **TRA** (eqs 28–32, Branch–Coleman–Li 1999; Byrd–Schnabel–Shultz 1988): the
  `TwoDimensionalSubspaceDescent` minimises the Gauss–Newton model q(d) = E + gᵀd + ½dᵀBd,
  B = JᵀJ, over ‖d‖₂ ≤ Δ restricted to span{g, n}, n the Gauss–Newton direction, driven
  by `PaperTrustRegion` (Optimistix's trust-region update with the paper's constants and
  a settable initial radius): reject when
  ρ < 0.1 (and so when E increases), Δ ← Δ/2 there, Δ kept for 0.1 ≤ ρ ≤ 0.75, Δ ← 2Δ
  for ρ > 0.75. Δ1 = 1 in the solver's coordinates z (about a third of the box).

Choice: the Newton direction is the minimum-norm Gauss–Newton step −J⁺e from an SVD of J
(exact for our ≤ 10 parameters) instead of the paper's preconditioned CG; B = JᵀJ is
positive semi-definite, so the "negative curvature" branch of the paper never arises with
the Gauss–Newton model, and where B is singular the pseudo-inverse gives the minimum-norm
direction.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx
from optimistix._search import AbstractDescent, AbstractSearch, FunctionInfo
from optimistix._solution import RESULTS
from optimistix._solver.levenberg_marquardt import DampedNewtonDescent
from optimistix._solver.trust_region import (
    ClassicalTrustRegion,
    _AbstractTrustRegion,
    _TrustRegionState,
)

_default_verbose = optx.LevenbergMarquardt(1e-8, 1e-8).verbose


class _DampingState(eqx.Module):
    step_size: jax.Array


class MultiplicativeDamping(AbstractSearch):
    """The paper's LMA rule for the damping h = 1/step_size: accept iff the cost
    decreases; h ← h/10 after an accepted step, h ← 10·h after a rejected one."""

    initial_damping: jax.Array = eqx.field(default_factory=lambda: jnp.array(0.01))
    factor: float = 10.0

    def init(self, y, f_info_struct):
        del y, f_info_struct
        return _DampingState(step_size=1.0 / jnp.asarray(self.initial_damping, dtype=float))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        del y, y_eval
        decreased = f_eval_info.as_min() < f_info.as_min()
        accept = first_step | decreased
        multiplier = jnp.where(first_step, 1.0, jnp.where(decreased, self.factor, 1 / self.factor))
        step_size = state.step_size * multiplier
        return step_size, accept, RESULTS.successful, _DampingState(step_size=step_size)


class PaperTrustRegion(_AbstractTrustRegion):
    """The paper's radius rule (reject for ρ < 0.1 and halve; keep for ρ ≤ 0.75; double
    above) with the Gauss–Newton predicted reduction of ``optx.ClassicalTrustRegion``, and
    a settable initial radius (so a hybrid can carry the radius across generations)."""

    high_cutoff: float = 0.75
    low_cutoff: float = 0.1
    high_constant: float = 2.0
    low_constant: float = 0.5
    initial_radius: jax.Array = eqx.field(default_factory=lambda: jnp.array(1.0))

    def init(self, y, f_info_struct):
        del y, f_info_struct
        return _TrustRegionState(step_size=jnp.asarray(self.initial_radius, dtype=float))

    def predict_reduction(self, y_diff, f_info):
        return ClassicalTrustRegion.predict_reduction(self, y_diff, f_info)


class _SubspaceState(eqx.Module):
    grad: jax.Array
    basis: jax.Array  # (n, 2), orthonormal columns (second may be zero)
    g2: jax.Array  # (2,)  projected gradient
    B2: jax.Array  # (2, 2) projected Gauss–Newton matrix
    result: RESULTS


def _solve_2d_trust_region(g2, B2, radius, iterations: int = 60):
    """argmin_s g2·s + ½ sᵀB2 s subject to ‖s‖ ≤ radius, for a 2×2 symmetric B2 ⪰ 0 (or
    indefinite): eigen-decomposition, then bisection on the secular equation in λ."""
    mu, Q = jnp.linalg.eigh(B2)
    gh = Q.T @ g2
    tiny = 1e-14 * (jnp.abs(mu).max() + 1e-300)

    def step_for(lam):
        return -gh / jnp.maximum(mu + lam, tiny)

    lam_min = jnp.maximum(0.0, -mu[0]) + tiny
    inside = (mu[0] > tiny) & (jnp.linalg.norm(step_for(0.0)) <= radius)
    # bracket λ: ‖s(λ)‖ ≤ ‖g‖/λ, so λ_hi = λ_min + ‖g‖/radius suffices
    lam_hi = lam_min + jnp.linalg.norm(gh) / radius

    def bisect(_, bracket):
        lo, hi = bracket
        mid = 0.5 * (lo + hi)
        too_long = jnp.linalg.norm(step_for(mid)) > radius
        return jnp.where(too_long, mid, lo), jnp.where(too_long, hi, mid)

    _, lam = jax.lax.fori_loop(0, iterations, bisect, (lam_min, lam_hi))
    s = jnp.where(inside, step_for(0.0), step_for(lam))
    return Q @ s


class TwoDimensionalSubspaceDescent(AbstractDescent):
    """Trust-region step restricted to span{gradient, Gauss–Newton direction}; the
    step size handed over by the search is the radius Δ (in the solver's coordinates)."""

    linear_solver: lx.AbstractLinearSolver = lx.SVD()

    def init(self, y, f_info_struct):
        n = y.shape[0]
        return _SubspaceState(
            grad=jnp.zeros(n), basis=jnp.zeros((n, 2)), g2=jnp.zeros(2),
            B2=jnp.zeros((2, 2)), result=RESULTS.successful,
        )  # fmt: skip

    def query(self, y, f_info, state):
        del y, state
        if not isinstance(f_info, FunctionInfo.ResidualJac):
            raise ValueError("TwoDimensionalSubspaceDescent needs a least-squares solver.")
        J = f_info.jac.as_matrix()
        r = f_info.residual
        grad = J.T @ r
        sol = lx.linear_solve(f_info.jac, -r, self.linear_solver, throw=False)
        newton = sol.value
        g_norm = jnp.linalg.norm(grad)
        e1 = grad / jnp.where(g_norm > 0, g_norm, 1.0)
        w = newton - (e1 @ newton) * e1
        w_norm = jnp.linalg.norm(w)
        independent = w_norm > 1e-10 * (jnp.linalg.norm(newton) + 1e-300)
        e2 = jnp.where(independent, w / jnp.where(independent, w_norm, 1.0), 0.0)
        basis = jnp.stack([e1, e2], axis=1)
        JV = J @ basis
        return _SubspaceState(
            grad=grad, basis=basis, g2=basis.T @ grad, B2=JV.T @ JV,
            result=RESULTS.promote(sol.result),
        )  # fmt: skip

    def step(self, step_size, state):
        s = _solve_2d_trust_region(state.g2, state.B2, step_size)
        return state.basis @ s, state.result


class PaperLMA(optx.AbstractGaussNewton):
    """The paper's Levenberg–Marquardt algorithm (eqs 24–27): h1 = 0.01, ×/÷ 10."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: DampedNewtonDescent = DampedNewtonDescent(linear_solver=lx.SVD())
    search: MultiplicativeDamping = MultiplicativeDamping()
    verbose: Callable = _default_verbose


class PaperTRA(optx.AbstractGaussNewton):
    """The paper's trust-region algorithm (eqs 28–32) on a 2-D subspace."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: TwoDimensionalSubspaceDescent = TwoDimensionalSubspaceDescent()
    search: PaperTrustRegion = PaperTrustRegion()
    verbose: Callable = _default_verbose


def with_initial_step_size(solver, step_size):
    """``solver`` starting from a given damping (LMA: h = 1/step_size) or radius (TRA: Δ =
    step_size); other solvers are returned unchanged (their searches restart at 1)."""
    step_size = jnp.asarray(step_size, dtype=float)
    if isinstance(solver, PaperLMA):
        return eqx.tree_at(lambda s: s.search.initial_damping, solver, 1.0 / step_size)
    if isinstance(solver, PaperTRA):
        return eqx.tree_at(lambda s: s.search.initial_radius, solver, step_size)
    return solver
