"""Local least-squares solvers on a `Problem`, single or vmapped multi-start.

Every solver runs in the unconstrained coordinates z of the problem (bounds by
construction, see `problem`), with Jacobians from ``jax.jacfwd`` (Optimistix's
``options={"jac": "fwd"}``), never finite differences.

| name          | what                                                          |
|---------------|---------------------------------------------------------------|
| ``lm``        | ``optx.LevenbergMarquardt`` (QR), damping relaxed at ρ > 0.75   |
| ``indirect_lm`` | ``optx.IndirectLevenbergMarquardt``                         |
| ``dogleg``    | ``optx.Dogleg`` with an SVD linear solve (JᵀJ can be singular) |
| ``lma``       | the paper's LMA (`PaperLMA`)                                  |
| ``tra``       | the paper's 2-D subspace trust region (`PaperTRA`)            |
"""

from __future__ import annotations

import time

import equinox as eqx
import jax
import jax.numpy as jnp
import lineax as lx
import numpy as np
import optimistix as optx
from optimistix._misc import cauchy_termination

from .paper_solvers import PaperLMA, PaperTRA
from .problem import Problem, u_from_z, z_from_u
from .result import IdentificationResult

SOLVERS = ("lm", "indirect_lm", "dogleg", "lma", "tra")


def make_solver(name: str, rtol: float = 1e-10, atol: float = 1e-12):
    """An Optimistix least-squares solver by name (see module table). ``rtol``/``atol``
    are Optimistix's Cauchy termination tolerances on the step (in z, or in box
    coordinates u: `BoxTermination`) and on the residuals."""
    if name == "lm":
        # Optimistix's LM shrinks its damping λ = 1/step size only when the step did
        # better than 0.99 of its predicted reduction (Gould et al.'s constants). Our
        # normalised residuals give JᵀJ entries of 1e-3–0.2 against λ = 1 at the start,
        # and the piecewise-smooth hysteresis model rarely reaches ρ > 0.99, so λ stayed
        # large and LM crept like gradient descent. Relaxing at ρ > 0.75 (the textbook
        # threshold, also the paper's TRA) cut the median steps from 16 random starts
        # 140 → 42 (MnZn joint loops), 62 → 47 and 112 → 87 (Table 1, 10 and 7 free) with
        # as many or more starts reaching the optimum (docs/identification.md).
        lm = optx.LevenbergMarquardt(rtol=rtol, atol=atol)
        return eqx.tree_at(lambda s: s.search, lm, optx.ClassicalTrustRegion(high_cutoff=0.75))
    if name == "indirect_lm":
        return optx.IndirectLevenbergMarquardt(rtol=rtol, atol=atol)
    if name == "dogleg":
        return optx.Dogleg(rtol=rtol, atol=atol, linear_solver=lx.SVD())
    if name == "lma":
        return PaperLMA(rtol=rtol, atol=atol)
    if name == "tra":
        return PaperTRA(rtol=rtol, atol=atol)
    raise ValueError(f"Unknown solver {name!r}; choose one of {list(SOLVERS)}.")


def jacobian_linearized(fn):
    """``fn`` (a residual vector of a few parameters) with a custom JVP that forms the
    whole Jacobian by one forward-mode pass (`jax.jacfwd`, primal computed once) and
    returns J·t.

    Optimistix linearizes the residuals once per step and then applies the linear map
    to a basis (to materialise J for its QR) and its transpose (for Jᵀr). Linearizing
    the simulation's scan itself stores every intermediate of the time loop and replays
    the tangent scan for each use; with this rule the stored linearization is just the
    matrix J, so each step costs one jacfwd. Measured on the joint MnZn problem (3 loops,
    5 parameters): an LM step 54 ms → 11.5 ms. Values and derivatives are unchanged (the
    rule is the exact derivative); it differentiates again (jacfwd inside) if needed.
    """

    @jax.custom_jvp
    def f(z, args=None):
        return fn(z, args)

    @f.defjvp
    def f_jvp(primals, tangents):
        z, args = primals
        t, _ = tangents

        def both(z):
            r = fn(z, args)
            return r, r

        J, r = jax.jacfwd(both, has_aux=True)(z)
        return r, J @ t

    return f


class BoxTermination(optx.AbstractLeastSquaresSolver):
    """A Gauss–Newton-family solver whose Cauchy test may also pass in box coordinates.

    The solvers iterate in z with u = (1 + sin z)/2. When the optimum lies on a bound
    (u = 0 or 1, e.g. c = 1 on the MnZn loops) z approaches ±π/2 only linearly — the
    residuals are quadratic in z there, so each Gauss–Newton step halves the distance —
    and Optimistix's test on the z step (|Δz| < atol + rtol·|z|) needs ~30 more steps
    after u has converged to round-off. This wrapper stops an *accepted* step also when
    the same test passes with u in place of z (and the usual test on the residuals
    passes). Interior optima are unaffected (Table 1: the same median steps); on the
    joint MnZn loops the median steps of 16 starts fell 42 → 32 (`lm`) and 200 → 55
    (`lma`). Relies on the state of `optx.AbstractGaussNewton` (all our solvers).
    """

    inner: optx.AbstractLeastSquaresSolver

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

    def step(self, fn, y, args, options, state, tags):
        y_new, new_state, aux = self.inner.step(fn, y, args, options, state, tags)
        accepted = (new_state.num_accepted_steps > state.num_accepted_steps) & ~state.first_step
        u_new = u_from_z(y_new)
        residual = new_state.f_info.residual
        in_box = cauchy_termination(self.rtol, self.atol, self.norm, u_new,
                                    u_new - u_from_z(y), residual,
                                    residual - state.f_info.residual)
        terminate = new_state.terminate | (accepted & in_box)
        return y_new, eqx.tree_at(lambda s: s.terminate, new_state, terminate), aux

    def terminate(self, fn, y, args, options, state, tags):
        return self.inner.terminate(fn, y, args, options, state, tags)

    def postprocess(self, fn, y, aux, args, options, state, tags, result):
        return self.inner.postprocess(fn, y, aux, args, options, state, tags, result)


def _run(problem: Problem, solver, z0, max_steps: int):
    """One solve; returns only arrays (value, result, steps, cost) so that it vmaps
    (Optimistix issue #63: a whole Solution does not)."""
    sol = optx.least_squares(
        jacobian_linearized(problem.residuals), BoxTermination(solver), z0,
        max_steps=max_steps, throw=False, options={"jac": "fwd"},
    )  # fmt: skip
    z = sol.value
    cost = jnp.sum(problem.residuals(z) ** 2)
    return z, sol.result._value, sol.stats["num_steps"], cost, sol.state.search_state.step_size


_run_jit = eqx.filter_jit(_run)


@eqx.filter_jit
def _run_many(problem, solver, z0s, max_steps):
    return jax.vmap(lambda z0: _run(problem, solver, z0, max_steps))(z0s)


_RESULT_NAMES = {
    int(item._value): name for name, item in optx.RESULTS._name_to_item.items()
}


def _result_name(code) -> str:
    """Optimistix's RESULTS name (e.g. ``successful``, ``max_steps_reached``)."""
    return _RESULT_NAMES.get(int(code), f"code {int(code)}")


def _start_z(problem: Problem, start) -> jax.Array:
    """z0 from a `Parameters` (projected into the box) or u ∈ [0, 1]ⁿ array."""
    if hasattr(start, "to_array"):
        return problem.space.z_from_params(start)
    u = jnp.asarray(start, dtype=jnp.float64)
    if u.shape[-1] != problem.space.n_free:
        raise ValueError(
            f"A start in box coordinates needs {problem.space.n_free} entries (free "
            f"parameters {problem.space.names}); got shape {u.shape}."
        )
    if not bool(jnp.all((u >= 0) & (u <= 1))):
        raise ValueError("Box coordinates u of a start must lie in [0, 1].")
    return z_from_u(u)


def _free_dict(problem, z) -> dict:
    """{free name: SI value} at solver coordinate z."""
    sp = problem.space
    x = np.asarray(sp.lower + (sp.upper - sp.lower) * u_from_z(z))
    return {n: float(v) for n, v in zip(sp.names, x, strict=True)}


@eqx.filter_jit
def predict_jit(problem, params) -> jax.Array:
    """``problem.predict(params)`` compiled (cached per problem structure). Called eagerly,
    the vmapped scan of a joint problem runs op by op: 1.3 s of a 4.3 s MnZn hybrid."""
    return problem.predict(params)


def summarize(problem: Problem, z, steps, code, solver_name: str, wall: float,
              extra: dict | None = None, report: bool = True) -> IdentificationResult:
    """Build an `IdentificationResult` at the solver coordinate ``z``, with the
    identifiability report at that point when ``report`` (one jacfwd of the model)."""
    params = problem.space.params_from_z(z)
    e = np.asarray(predict_jit(problem, params) - problem.data)
    w = np.asarray(problem.sample_scale)
    cost = float(np.sum((e / w) ** 2) / e.shape[0])  # Σr², as in residuals
    result = IdentificationResult(
        params=params, free=problem.space.names, cost=cost, objective=float(np.sum(e**2)),
        rms_error=float(np.sqrt(np.mean(e**2))), max_abs_error=float(np.max(np.abs(e))),
        steps=int(steps), result=_result_name(code), solver=solver_name, wall_time=wall,
        output=problem.output, extra=extra or {},
    )  # fmt: skip
    if report:
        from ..analysis.identifiability import identifiability  # (analysis imports identify)

        try:
            result.report = identifiability(problem, params)
        except ValueError as err:
            result.report_error = str(err)
    return result


def solve(problem: Problem, start, solver: str = "lm", max_steps: int = 200,
          rtol: float = 1e-10, atol: float = 1e-12, report: bool = True
          ) -> IdentificationResult:
    """Run one local solver from ``start`` (`Parameters` or box coordinates u).

    ``max_steps`` bounds the iterations (the paper's T3 for ``lma``/``tra``); ``report``
    attaches the identifiability report at the solution."""
    z0 = _start_z(problem, start)
    t0 = time.perf_counter()
    z, code, steps, _, _ = _run_jit(problem, make_solver(solver, rtol, atol), z0, max_steps)
    z.block_until_ready()
    wall = time.perf_counter() - t0
    return summarize(problem, z, steps, code, solver, wall, report=report)


def multistart(problem: Problem, starts, solver: str = "lm", max_steps: int = 200,
               rtol: float = 1e-10, atol: float = 1e-12, report: bool = True
               ) -> IdentificationResult:
    """Solve from K starts in one vmapped batch; returns the best, with the per-start
    table (final cost, result, steps, parameters) in ``extra["starts"]``.

    ``starts``: box coordinates of shape (K, n_free), or a batched `Parameters`.
    The batch runs until its slowest member stops, so ``max_steps`` matters."""
    z0s = _start_z(problem, starts)
    if z0s.ndim != 2:
        raise ValueError("multistart needs a batch of starts, shape (K, n_free).")
    t0 = time.perf_counter()
    zs, codes, steps, costs, _ = _run_many(problem, make_solver(solver, rtol, atol), z0s, max_steps)
    costs = np.asarray(costs)
    wall = time.perf_counter() - t0
    ranked = np.where(np.isfinite(costs), costs, np.inf)
    best = int(np.argmin(ranked))
    table = [
        {"cost": float(costs[i]), "result": _result_name(codes[i]), "steps": int(steps[i]),
         "params": _free_dict(problem, zs[i])}
        for i in range(len(costs))
    ]  # fmt: skip
    return summarize(problem, zs[best], steps[best], codes[best], f"{solver} x{len(costs)}",
                     wall, extra={"starts": table, "best_index": best}, report=report)
