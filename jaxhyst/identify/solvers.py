"""Local solvers: the named ones, the paper's LMA and TRA as Optimistix compositions, and
the small amount of Optimistix solver state jaxhyst reads.

| name          | what                                                           |
|---------------|----------------------------------------------------------------|
| ``lm``        | ``optx.LevenbergMarquardt`` (QR), damping relaxed at ρ > 0.75    |
| ``indirect_lm`` | ``optx.IndirectLevenbergMarquardt``                          |
| ``dogleg``    | ``optx.Dogleg`` with an SVD linear solve (JᵀJ can be singular)  |
| ``lma``       | the paper's LMA (`PaperLMA`, eqs 24–27)                        |
| ``tra``       | the paper's 2-D subspace trust region (`PaperTRA`, eqs 28–32)  |
| ``bfgs``      | ``optx.BFGS`` on the cost (a minimiser, not least squares)       |

Any Optimistix least-squares solver or minimiser object may be passed instead of a name.

**Optimistix state read here** (public classes, private state layout; the tested range
of optimistix is pinned in ``pyproject.toml`` and `tests/test_identify.py` checks each
read): the Gauss–Newton family's state fields ``first_step``, ``num_accepted_steps``,
``f_info`` (its residual at the accepted point, for the cost at the end of a solve),
``terminate`` (by `BoxTermination`), and ``search_state.step_size`` of a finished LMA or
TRA solve (the damping or radius a hybrid carries to its next local search). Every read
is in this module, chosen by the solver's type.
"""

from __future__ import annotations

from collections.abc import Callable

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import optimistix as optx

from ..names import SOLVER_NAMES
from .space import u_from_z

_DEFAULT_VERBOSE = optx.LevenbergMarquardt(1e-8, 1e-8).verbose


# -- the paper's LMA (eqs 24–27) ----------------------------------------------------------------

class _StepSizeState(eqx.Module):
    step_size: jax.Array


class MultiplicativeDamping(optx.AbstractSearch):
    """The paper's LMA rule for the damping h = 1/step_size: accept iff the cost
    decreases; h ← h/10 after an accepted step, h ← 10·h after a rejected one; the
    first damping is ``initial_damping`` (h1 = 0.01 in the paper)."""

    initial_damping: jax.Array = eqx.field(default_factory=lambda: jnp.array(0.01),
                                           converter=jnp.asarray)
    factor: float = 10.0

    def init(self, y, f_info_struct):
        del y, f_info_struct
        return _StepSizeState(step_size=1.0 / jnp.asarray(self.initial_damping, dtype=float))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        del y, y_eval
        decreased = f_eval_info.as_min() < f_info.as_min()
        accept = first_step | decreased
        multiplier = jnp.where(first_step, 1.0, jnp.where(decreased, self.factor, 1 / self.factor))
        step_size = state.step_size * multiplier
        return step_size, accept, optx.RESULTS.successful, _StepSizeState(step_size)


# -- the paper's TRA (eqs 28–32) ----------------------------------------------------------------

class PaperTrustRegion(optx.AbstractSearch):
    """The paper's radius rule with the Gauss–Newton predicted reduction: reject for
    ρ < 0.1 (or an increase) and halve Δ; keep Δ for 0.1 ≤ ρ ≤ 0.75; double it above.
    The first radius is ``initial_radius`` (Δ1 = 1 in z, about a third of the box)."""

    initial_radius: jax.Array = eqx.field(default_factory=lambda: jnp.array(1.0),
                                          converter=jnp.asarray)
    high_cutoff: float = 0.75
    low_cutoff: float = 0.1

    def init(self, y, f_info_struct):
        del y, f_info_struct
        return _StepSizeState(step_size=jnp.asarray(self.initial_radius, dtype=float))

    def step(self, first_step, y, y_eval, f_info, f_eval_info, state):
        if not isinstance(f_info, optx.FunctionInfo.ResidualJac):
            raise ValueError("PaperTrustRegion needs a least-squares solver.")
        y_diff = y_eval - y
        r = f_info.residual
        Jd = f_info.jac.mv(y_diff)
        predicted = 0.5 * (jnp.sum((Jd + r) ** 2) - jnp.sum(r**2))  # < 0 for descent
        actual = f_eval_info.as_min() - f_info.as_min()
        accept = first_step | (actual <= self.low_cutoff * predicted)
        good = ~first_step & (predicted < 0) & (actual < self.high_cutoff * predicted)
        multiplier = jnp.where(accept, jnp.where(good, 2.0, 1.0), 0.5)
        step_size = state.step_size * multiplier
        return step_size, accept, optx.RESULTS.successful, _StepSizeState(step_size)


class _SubspaceState(eqx.Module):
    basis: jax.Array  # (n, 2), orthonormal columns (second may be zero)
    g2: jax.Array  # (2,)  projected gradient
    B2: jax.Array  # (2, 2) projected Gauss–Newton matrix
    result: optx.RESULTS


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


class TwoDimensionalSubspaceDescent(optx.AbstractDescent):
    """Trust-region step restricted to span{gradient, Gauss–Newton direction}; the step
    size handed over by the search is the radius Δ (in the solver's coordinates). The
    Newton direction is the minimum-norm −J⁺r from an SVD (exact for ≤ 10 parameters;
    the paper uses preconditioned CG); with the Gauss–Newton model B = JᵀJ ⪰ 0 the
    paper's negative-curvature branch never arises."""

    linear_solver: lx.AbstractLinearSolver = lx.SVD()

    def init(self, y, f_info_struct):
        n = y.shape[0]
        return _SubspaceState(basis=jnp.zeros((n, 2)), g2=jnp.zeros(2),
                              B2=jnp.zeros((2, 2)), result=optx.RESULTS.successful)

    def query(self, y, f_info, state):
        del y, state
        if not isinstance(f_info, optx.FunctionInfo.ResidualJac):
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
        return _SubspaceState(basis=basis, g2=basis.T @ grad, B2=JV.T @ JV,
                              result=optx.RESULTS.promote(sol.result))

    def step(self, step_size, state):
        s = _solve_2d_trust_region(state.g2, state.B2, step_size)
        return state.basis @ s, state.result


class PaperLMA(optx.AbstractGaussNewton):
    """The paper's Levenberg–Marquardt algorithm (eqs 24–27): h1 = 0.01, ×/÷ 10."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: optx.DampedNewtonDescent = optx.DampedNewtonDescent(linear_solver=lx.SVD())
    search: MultiplicativeDamping = MultiplicativeDamping()
    verbose: Callable = _DEFAULT_VERBOSE


class PaperTRA(optx.AbstractGaussNewton):
    """The paper's trust-region algorithm (eqs 28–32) on a 2-D subspace."""

    rtol: float
    atol: float
    norm: Callable = optx.max_norm
    descent: TwoDimensionalSubspaceDescent = TwoDimensionalSubspaceDescent()
    search: PaperTrustRegion = PaperTrustRegion()
    verbose: Callable = _DEFAULT_VERBOSE


def _relaxed_lm(rtol, atol):
    # Optimistix's LM shrinks its damping λ = 1/step size only when a step did better than
    # 0.99 of its predicted reduction (Gould et al.'s constants). Normalised residuals give
    # JᵀJ entries of 1e-3–0.2 against λ = 1 at the start, and the piecewise-smooth
    # hysteresis model rarely reaches ρ > 0.99, so λ stayed large and LM crept like
    # gradient descent. Relaxing at ρ > 0.75 cuts the steps several-fold (measured in
    # benchmarks/RESULTS.md and docs/identification.md).
    lm = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
    return eqx.tree_at(lambda s: s.search, lm, optx.ClassicalTrustRegion(high_cutoff=0.75))


#: Solver name → factory(rtol, atol). The names are `jaxhyst.names.SOLVER_NAMES`.
SOLVERS = {
    "lm": _relaxed_lm,
    "indirect_lm": lambda rtol, atol: optx.IndirectLevenbergMarquardt(rtol=rtol, atol=atol),
    "dogleg": lambda rtol, atol: optx.Dogleg(rtol=rtol, atol=atol, linear_solver=lx.SVD()),
    "lma": lambda rtol, atol: PaperLMA(rtol=rtol, atol=atol),
    "tra": lambda rtol, atol: PaperTRA(rtol=rtol, atol=atol),
    "bfgs": lambda rtol, atol: optx.BFGS(rtol=rtol, atol=atol),
}
assert tuple(SOLVERS) == SOLVER_NAMES


def make_solver(solver, rtol: float = 1e-10, atol: float = 1e-12):
    """An Optimistix solver from a name of `SOLVERS` (any case; with Cauchy termination
    tolerances ``rtol``/``atol``), or ``solver`` itself if it already is an Optimistix
    least-squares solver or minimiser."""
    if isinstance(solver, str):
        key = solver.strip().lower()  # ("LM" is lm)
        if key not in SOLVERS:
            raise ValueError(f"Unknown solver {solver!r}; choose one of {list(SOLVERS)} or "
                             "pass an Optimistix least-squares solver or minimiser.")
        return SOLVERS[key](rtol, atol)
    if isinstance(solver, (optx.AbstractLeastSquaresSolver, optx.AbstractMinimiser)):
        return solver
    raise TypeError(f"solver must be a name ({list(SOLVERS)}) or an Optimistix "
                    f"least-squares solver or minimiser; got {type(solver).__name__}.")


def solver_name(solver) -> str:
    """A short label for a solver (its name, or its class name)."""
    return solver if isinstance(solver, str) else type(solver).__name__


def _carried_search(solver):
    """The search of a solver whose step size a hybrid carries between local searches
    (`MultiplicativeDamping` of the LMA, `PaperTrustRegion` of the TRA), or None."""
    if isinstance(solver, optx.AbstractGaussNewton) and isinstance(
            solver.search, (MultiplicativeDamping, PaperTrustRegion)):
        return solver.search
    return None


def with_initial_step_size(solver, step_size):
    """``solver`` starting from a given damping (LMA: h = 1/step_size) or radius (TRA:
    Δ = step_size); other solvers are returned unchanged (their searches restart at 1)."""
    step_size = jnp.asarray(step_size, dtype=float)
    search = _carried_search(solver)
    if isinstance(search, MultiplicativeDamping):
        return eqx.tree_at(lambda s: s.search.initial_damping, solver, 1.0 / step_size)
    if isinstance(search, PaperTrustRegion):
        return eqx.tree_at(lambda s: s.search.initial_radius, solver, step_size)
    return solver


def initial_step_size(solver) -> float:
    """The step size a solver's search starts from (LMA: 1/h1 = 100; TRA: Δ1; else 1)."""
    search = _carried_search(solver)
    if isinstance(search, MultiplicativeDamping):
        return float(1.0 / search.initial_damping)
    if isinstance(search, PaperTrustRegion):
        return float(search.initial_radius)
    return 1.0


def _cauchy_small(rtol, atol, norm, y, y_diff, f, f_diff):
    """|Δy| < atol + rtol·|y| and |Δf| < atol + rtol·|f| in ``norm``: Optimistix's Cauchy
    termination test."""
    y_ok = norm(jnp.abs(y_diff) / (atol + rtol * jnp.abs(y))) < 1
    f_ok = norm(jnp.abs(f_diff) / (atol + rtol * jnp.abs(f))) < 1
    return y_ok & f_ok


class AbstractTerminationWrapper(optx.AbstractLeastSquaresSolver):
    """A Gauss–Newton-family solver (``inner``) with one more way to stop: a final
    subclass implements ``step`` (the inner step, then its own test setting the state's
    ``terminate``); everything else is the inner solver's."""

    inner: eqx.AbstractVar[optx.AbstractLeastSquaresSolver]

    @property
    def rtol(self):
        return self.inner.rtol

    @property
    def atol(self):
        return self.inner.atol

    @property
    def norm(self):
        return self.inner.norm

    def init(self, fn, y, args, options, f_struct, aux_struct, tags):
        return self.inner.init(fn, y, args, options, f_struct, aux_struct, tags)

    def terminate(self, fn, y, args, options, state, tags):
        return self.inner.terminate(fn, y, args, options, state, tags)

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return self.inner.postprocess(fn, y, aux, args, options, state, tags, result)


class BoxTermination(AbstractTerminationWrapper):
    """A Gauss–Newton-family solver whose Cauchy test may also pass in box coordinates.

    The solvers iterate in z with u = (1 + sin z)/2. When the optimum lies on a bound
    (u = 0 or 1, e.g. c = 1 on the MnZn loops) z approaches ±π/2 only linearly — the
    residuals are quadratic in z there, so each Gauss–Newton step halves the distance —
    and the test on the z step (|Δz| < atol + rtol·|z|) needs ~30 more steps after u has
    converged to round-off. This wrapper stops an *accepted* step also when the same test
    passes with u in place of z (and the usual test on the residuals passes). Interior
    optima are unaffected (the steps saved are in benchmarks/RESULTS.md). Reads the
    Gauss–Newton state (module docstring).
    """

    inner: optx.AbstractLeastSquaresSolver

    def step(self, fn, y, args, options, state, tags):
        y_new, new_state, aux = self.inner.step(fn, y, args, options, state, tags)
        accepted = (new_state.num_accepted_steps > state.num_accepted_steps) & ~state.first_step
        u_new = u_from_z(y_new)
        residual = new_state.f_info.residual
        in_box = _cauchy_small(self.rtol, self.atol, self.norm, u_new, u_new - u_from_z(y),
                               residual, residual - state.f_info.residual)
        terminate = new_state.terminate | (accepted & in_box)
        return y_new, eqx.tree_at(lambda s: s.terminate, new_state, terminate), aux


class TargetTermination(AbstractTerminationWrapper):
    """A Gauss–Newton-family solver that also stops once an accepted point's cost Σr²
    is at most ``target``: a solve that only has to be as accurate as its model (a
    compensating input refined to the model's own accuracy) need not run on to
    round-off. Reads the Gauss–Newton state (module docstring). ``target = 0`` leaves
    the inner solver's termination alone. ``budget`` (an integer array, or None): stop
    after that many steps as ``max_steps`` would (``nonlinear_max_steps_reached``), a
    count that is data — one program for every budget up to the solve's ``max_steps``."""

    inner: optx.AbstractLeastSquaresSolver
    target: float
    budget: object = None

    def step(self, fn, y, args, options, state, tags):
        y_new, new_state, aux = self.inner.step(fn, y, args, options, state, tags)
        accepted = (new_state.num_accepted_steps > state.num_accepted_steps) & ~state.first_step
        reached = jnp.sum(new_state.f_info.residual ** 2) <= self.target
        terminate = new_state.terminate | (accepted & reached)
        new_state = eqx.tree_at(lambda s: s.terminate, new_state, terminate)
        if self.budget is not None:  # (the loop ends on a result other than successful)
            spent = (new_state.num_steps >= self.budget) & ~terminate & \
                (new_state.result == optx.RESULTS.successful)
            new_state = eqx.tree_at(lambda s: s.result, new_state, optx.RESULTS.where(
                spent, optx.RESULTS.nonlinear_max_steps_reached, new_state.result))
        return y_new, new_state, aux


def _inner(solver):
    """The solver a `BoxTermination` wraps (its state is that solver's), else itself."""
    return solver.inner if isinstance(solver, AbstractTerminationWrapper) else solver


def accepted_residuals(solver, state):
    """(residual vector at the accepted point, accepted steps) of the state of a solve by
    ``solver`` (as run) of the Gauss–Newton family — the point its ``step`` returns;
    placeholder zeros while no step is accepted — or None for another kind of solver."""
    if not isinstance(_inner(solver), optx.AbstractGaussNewton):
        return None
    return state.f_info.residual, state.num_accepted_steps


def accepted_jacobian(solver, state):
    """The Jacobian ∂r/∂z, shape (R, n), at the accepted point of the state of a solve by
    ``solver`` (as run) of the Gauss–Newton family — the matrix its last linearization
    holds (`jaxhyst.identify._objective.jacobian_linearized`), applied to a basis: no
    simulation — or None for another kind of solver."""
    if not isinstance(_inner(solver), optx.AbstractGaussNewton):
        return None
    return state.f_info.jac.as_matrix()


def final_step_size(solver, state):
    """The damping (1/h) or radius a finished solve by ``solver`` (as run) ended with,
    for the solvers a hybrid carries it for (`with_initial_step_size`); NaN otherwise."""
    if _carried_search(_inner(solver)) is None:
        return jnp.nan
    return state.search_state.step_size
