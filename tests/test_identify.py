"""Identification problem and local solvers (issue 3)."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import max_combination_error, table1_problem

import jaxhyst as jh
from jaxhyst.identify import SOLVERS, ParameterSpace, Problem, u_from_z

TRUTH = jh.TABLE1_TRUE.to_dict()


@pytest.fixture(scope="module")
def problem():
    return table1_problem()


def _starts(problem):
    """±10 % perturbation of the truth (alternating signs) and a random box point."""
    signs = np.where(np.arange(10) % 2 == 0, 1.1, 0.9)
    perturbed = jh.Parameters.from_array(jh.TABLE1_TRUE.to_array() * signs)
    u_pert = np.asarray(problem.space.u_from_params(perturbed))
    u_rand = np.random.default_rng(0).uniform(0.05, 0.95, 10)
    return np.stack([u_pert, u_rand])


# What each solver achieves from those starts (noise-free data).
# IndirectLevenbergMarquardt converges only linearly here: its root-find on the damping
# keeps steps short along the three exactly-null directions of JᵀJ, and it stalls at
# cost ~1e-9 (measured 6e-10 … 3e-9 after 300 steps); we assert that honest outcome,
# with fewer steps since it never stops early.
REACHES_ZERO = {"lm": True, "dogleg": True, "lma": True, "tra": True, "indirect_lm": False}
MAX_STEPS = {"indirect_lm": 80}


# (indirect_lm, which never stops early, took ~80 s cold and ran only with `-m slow`
# until the local solvers got their Jacobian through a custom JVP: now ~16 s.)
@pytest.mark.parametrize("solver", SOLVERS)
def test_solver_outcome_on_table1(problem, solver):
    res = jh.multistart(problem, _starts(problem), solver=solver,
                        max_steps=MAX_STEPS.get(solver, 200))
    for row in res.extra["starts"]:
        p = row["params"]
        assert jh.TABLE1_BOUNDS.contains(jh.Parameters.from_dict(p))  # bounds by construction
        if REACHES_ZERO[solver]:
            assert row["cost"] < 1e-20, row
            assert max_combination_error(p, TRUTH) <= 1e-8, row
        else:
            assert row["cost"] < 1e-6, row  # progress from cost ~1e-2, but no convergence
    costs = [r["cost"] for r in res.extra["starts"]]
    assert res.extra["best_index"] == int(np.argmin(costs))


def test_single_solve_and_result_object(problem):
    res = jh.solve(problem, _starts(problem)[0], solver="lm")
    assert res.cost < 1e-20 and res.result == "successful" and res.steps > 0
    assert res.max_abs_error < 1e-9 * problem.scale
    text = str(res)
    assert "lambda_s" in text and "N*s/m" in text and "successful" in text
    d = res.to_dict()
    assert d["params"]["Ms"]["unit"] == "A/m" and d["params"]["Ms"]["free"]
    # every result carries its identifiability report, printed and in the JSON
    assert res.report is not None and len(res.report.null_directions) == 3
    assert "NOT identifiable" in text and "identifiable combination" in text
    back = json.loads(json.dumps(d))
    assert back["identifiability"]["rank"] == 7
    assert back["identifiability"]["suggest_fix"] == ["Ms", "lambda_s", "Mz"]


def test_scipy_trf_reaches_the_same_optimum(problem):
    scipy_optimize = pytest.importorskip("scipy.optimize")
    res = jh.solve(problem, _starts(problem)[1], solver="lm")
    fun = jax.jit(lambda z: problem.residuals(z))
    jac = jax.jit(jax.jacfwd(lambda z: problem.residuals(z)))
    z0 = jh.identify.z_from_u(jnp.asarray(_starts(problem)[1]))
    sol = scipy_optimize.least_squares(
        lambda z: np.asarray(fun(jnp.asarray(z))), np.asarray(z0),
        jac=lambda z: np.asarray(jac(jnp.asarray(z))), method="trf",
        xtol=1e-15, ftol=1e-15, gtol=1e-15, max_nfev=400,
    )  # fmt: skip
    p_scipy = problem.space.params_from_z(jnp.asarray(sol.x)).to_dict()
    assert 2 * sol.cost < 1e-20
    assert max_combination_error(p_scipy, TRUTH) <= 1e-8
    assert max_combination_error(p_scipy, res.params.to_dict()) <= 1e-8


def test_sine_map_keeps_every_z_inside_the_box():
    z = jax.random.normal(jax.random.PRNGKey(0), (10000, 10)) * 1e3
    u = u_from_z(z)
    assert bool(jnp.all((u >= 0) & (u <= 1)))
    space = ParameterSpace(jh.TABLE1_BOUNDS)
    theta = np.asarray(space.theta_from_u(u))
    lo = np.asarray(jh.TABLE1_BOUNDS.lower.to_array())
    hi = np.asarray(jh.TABLE1_BOUNDS.upper.to_array())
    assert np.all(theta >= lo) and np.all(theta <= hi)


def test_fixed_parameters_stay_exactly_fixed():
    fixed = {"Ms": 7.65e5, "lambda_s": 1.005e-3, "Mz": 0.55}
    prob = table1_problem(fixed=list(fixed))
    assert prob.space.names == ("a", "k", "alpha", "c", "E", "Kz", "Cz")
    u0 = np.full(7, 0.3)
    res = jh.solve(prob, u0, solver="lm")
    for n, v in fixed.items():
        assert float(getattr(res.params, n)) == v
    # with those three fixed every remaining parameter is identifiable
    assert res.cost < 1e-20
    for n in prob.space.names:
        assert abs(float(getattr(res.params, n)) / TRUTH[n] - 1) < 1e-7, n


def test_bad_problems_are_refused(problem):
    drive, act = problem.drive, problem.actuator
    with pytest.raises(ValueError, match="nothing to identify"):
        ParameterSpace(jh.TABLE1_BOUNDS, fixed=jh.TABLE1_TRUE.to_dict())
    data = np.asarray(problem.data).copy()
    data[5] = np.nan
    with pytest.raises(ValueError, match="NaN or inf at samples \\[5\\]"):
        Problem(data, drive, act, problem.space)
    with pytest.raises(ValueError, match="samples but the drive observes"):
        Problem(np.asarray(problem.data)[:-3], drive, act, problem.space)
    short = jh.Drive(drive.t[: drive.run_in + 30], drive.H[: drive.run_in + 30],
                     run_in=drive.run_in)
    with pytest.raises(ValueError, match="less than one period"):
        Problem(np.ones(30), short, act, problem.space)
    with pytest.raises(ValueError, match="Unknown output"):
        Problem(problem.data, drive, act, problem.space, output="force")
    with pytest.raises(ValueError, match="Unknown solver"):
        jh.solve(problem, np.full(10, 0.5), solver="bfgs")
    with pytest.raises(ValueError, match="must lie in \\[0, 1\\]"):
        jh.solve(problem, np.full(10, 1.5))


def test_jacobian_linearized_residuals_have_the_same_derivatives(problem):
    """The custom JVP the local solvers see (one jacfwd, then J·t) is the exact
    derivative: forward, reverse and batched derivatives equal those of the plain
    residuals."""
    from jaxhyst.identify.local import jacobian_linearized

    plain = problem.residuals
    wrapped = jacobian_linearized(problem.residuals)
    z = problem.space.z_from_params(jh.Parameters.from_array(jh.TABLE1_TRUE.to_array()
                                                             * 1.03))
    np.testing.assert_array_equal(wrapped(z), plain(z))
    J = jax.jit(jax.jacfwd(plain))(z)
    scale = float(jnp.max(jnp.abs(J)))
    np.testing.assert_allclose(jax.jit(jax.jacfwd(wrapped))(z), J, rtol=0, atol=1e-12 * scale)
    np.testing.assert_allclose(jax.jit(jax.jacrev(wrapped))(z), J, rtol=0, atol=1e-12 * scale)
    t = jnp.linspace(-1.0, 1.0, z.shape[0])
    _, jt = jax.jvp(wrapped, (z,), (t,))
    np.testing.assert_allclose(jt, J @ t, rtol=0, atol=1e-12 * scale * z.shape[0])
    zs = jnp.stack([z, 0.9 * z])
    batched = jax.jit(jax.vmap(jax.jacfwd(wrapped)))(zs)
    np.testing.assert_allclose(batched[0], J, rtol=0, atol=1e-12 * scale)


def test_box_termination_stops_a_bound_optimum_sooner_at_the_requested_tolerance():
    """With the optimum on a bound (here c on its upper bound) z creeps to π/2 while u
    has long converged; the box test stops it sooner, with u and the parameters still
    accurate to the tolerance (rtol 1e-10 of the box)."""
    import equinox as eqx
    import optimistix as optx

    from jaxhyst.identify import z_from_u
    from jaxhyst.identify.local import BoxTermination, jacobian_linearized, make_solver

    H = 9e3 * np.sin(2 * np.pi * np.arange(80) / 80)
    truth = jh.TABLE1_TRUE
    x = np.asarray(truth.to_array())
    lo, hi = 0.5 * np.abs(x), 1.5 * np.abs(x)
    lo[jh.NAMES.index("alpha")], hi[jh.NAMES.index("alpha")] = -0.02, 0.0
    hi[jh.NAMES.index("c")] = x[jh.NAMES.index("c")]  # the truth on the upper bound
    bounds = jh.Bounds(jh.Parameters.from_array(lo), jh.Parameters.from_array(hi))
    fixed = {n: float(getattr(truth, n)) for n in ("lambda_s", "E", "Kz", "Mz", "Cz")}
    kw = dict(output="magnetization", fixed=fixed, substeps=4)
    data = np.asarray(jh.loop_problem(H, np.ones(80), bounds, **kw).predict(truth))
    problem = jh.loop_problem(H, data, bounds, **kw)
    z0 = z_from_u(jnp.full(problem.space.n_free, 0.3))

    def run(solver):
        sol = optx.least_squares(jacobian_linearized(problem.residuals), solver, z0,
                                 max_steps=300, throw=False)
        return sol.value, sol.stats["num_steps"], sol.result == optx.RESULTS.successful

    (z_plain, n_plain, ok_plain), (z_box, n_box, ok_box) = (
        eqx.filter_jit(run)(s) for s in (make_solver("lm"), BoxTermination(make_solver("lm"))))
    assert bool(ok_plain) and bool(ok_box)
    assert int(n_box) < int(n_plain), (int(n_box), int(n_plain))
    assert abs(float(u_from_z(z_box)[-1]) - 1.0) < 1e-9
    found = np.asarray(problem.space.theta_from_u(u_from_z(z_box)))
    free = list(problem.space.free)
    np.testing.assert_allclose(found[free], x[free], rtol=1e-8)
    assert float(jnp.sum(problem.residuals(z_box) ** 2)) < 1e-20
