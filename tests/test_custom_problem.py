"""A problem of one's own (issue 14): a residual function on a dict of parameters,
displacement on one drive and strain on another, a Gaussian prior on two parameters —
solved by an Optimistix minimiser object, by LM by name and inside GATR1, all to the same
optimum, with standard errors that match replicate fits."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx
import pytest

import jaxhyst as jh
from jaxhyst.analysis import fit_replicates
from jaxhyst.model.simulate import simulate_unchecked

TRUE = {"a": 7012.0, "k": 3283.0, "c": 0.18}
DRIVE_Y = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=25)
DRIVE_S = jh.sinusoidal_current(100.0, 0.5, 1.2, jh.ACTUATOR1, samples_per_period=25)
SIGMA_Y, SIGMA_S = 2e-9, 2e-7  # noise levels: m and strain (1)
PRIOR = (jh.GaussianPrior("a", 7000.0, 300.0), jh.GaussianPrior("k", 3300.0, 300.0))


def model(theta):
    """Displacement on DRIVE_Y and strain on DRIVE_S for a dict of (a, k, c)."""
    p = jh.TABLE1_TRUE.replace(a=theta["a"], k=theta["k"], c=theta["c"])
    y = DRIVE_Y.observed(simulate_unchecked(p, jh.ACTUATOR1, DRIVE_Y).y)
    s = DRIVE_S.observed(simulate_unchecked(p, jh.ACTUATOR1, DRIVE_S).strain)
    return y, s


def residuals(theta, data):
    y, s = model(theta)
    return {"displacement": y - data["y"], "strain": s - data["strain"]}


def make_problem(key=None):
    key = jax.random.PRNGKey(0) if key is None else key
    y, s = model(TRUE)
    ky, ks = jax.random.split(key)
    data = {"y": y + SIGMA_Y * jax.random.normal(ky, y.shape),
            "strain": s + SIGMA_S * jax.random.normal(ks, s.shape)}
    space = jh.ParameterSpace.for_tree(lower={"a": 5000.0, "c": 0.05, "k": 2000.0},
                                       upper={"a": 9000.0, "c": 0.3, "k": 4500.0})
    return jh.ResidualProblem(residuals, space, data,
                              groups={"displacement": {"sigma": SIGMA_Y, "unit": "m"},
                                      "strain": {"sigma": SIGMA_S}},
                              priors=PRIOR)


@pytest.fixture(scope="module")
def problem():
    return make_problem()


@pytest.fixture(scope="module")
def lm_fit(problem):
    return jh.solve(problem, np.full(3, 0.5), solver="lm")


def test_the_problem_reports_its_groups_and_its_own_cost(problem, lm_fit):
    names = [g.name for g in problem.groups]
    assert names == ["displacement", "strain"] and problem.space.names == ("a", "c", "k")
    assert lm_fit.success and lm_fit.result == "successful"
    # the cost is the problem's chi-square (data and prior terms), not a recomputed MSE
    y, s = model({k: float(v) for k, v in zip(problem.space.names, lm_fit.values,
                                              strict=True)})
    theta = dict(zip(problem.space.names, lm_fit.values, strict=True))
    chi2 = (np.sum(((np.asarray(y) - np.asarray(problem.data["y"])) / SIGMA_Y) ** 2)
            + np.sum(((np.asarray(s) - np.asarray(problem.data["strain"])) / SIGMA_S) ** 2)
            + sum(((theta[p.name] - p.mean) / p.sd) ** 2 for p in PRIOR))
    assert lm_fit.cost == pytest.approx(chi2, rel=1e-9)
    n_data = sum(g.size for g in problem.groups)
    assert 0.5 * n_data < lm_fit.cost < 1.5 * n_data  # a chi-square at the noise level
    assert set(lm_fit.groups) == {"displacement", "strain"}
    assert lm_fit.rms_error is None  # groups in different units: no pooled rms


@pytest.mark.slow  # three full fits; LM and a solver object are checked by the fast tests
def test_bfgs_object_lm_and_gatr1_reach_the_same_optimum(problem, lm_fit):
    bfgs = jh.solve(problem, np.full(3, 0.5), solver=optx.BFGS(rtol=1e-12, atol=1e-12),
                    max_steps=400, report=False)
    settings = dict(q1=24, q2=10, T1=2, T2=6, local_steps=4, check_steps=40)
    gatr1 = jh.run_hybrid(problem, "GATR1", seed=1, settings=settings, report=False)
    for other in (bfgs, gatr1):
        assert other.success, other.result
        assert other.cost == pytest.approx(lm_fit.cost, rel=1e-7)
        np.testing.assert_allclose(other.values, lm_fit.values, rtol=1e-5)


@pytest.mark.slow  # replicate fits; coverage is the default run's test_identifiability
def test_report_standard_errors_match_replicate_fits(problem, lm_fit):
    report = lm_fit.report
    assert report is not None and report.rank == 3
    assert not report.group_sigma["strain"][1]  # declared, not estimated
    R = 48
    keys = jax.random.split(jax.random.PRNGKey(7), R)
    y, s = model({k: float(v) for k, v in zip(problem.space.names, lm_fit.values,
                                              strict=True)})
    data = {"y": y + SIGMA_Y * jax.vmap(lambda k: jax.random.normal(k, y.shape))(keys),
            "strain": s + SIGMA_S * jax.vmap(lambda k: jax.random.normal(
                jax.random.fold_in(k, 1), s.shape))(keys)}
    fits = fit_replicates(problem, data, np.full(3, 0.5), batch_size=16)
    assert all(r == "successful" for r in fits["results"])
    spread = np.std(fits["values"], axis=0, ddof=1)
    se = np.array([report.std_errors[n] for n in problem.space.names])
    # sample sd of 48 replicates: relative standard error ≈ 1/√94 ≈ 10 %
    np.testing.assert_allclose(spread, se, rtol=0.35)


def test_a_prior_needs_the_noise_levels():
    space = jh.ParameterSpace.for_tree({"a": 5000.0}, {"a": 9000.0})
    with pytest.raises(ValueError, match="noise level sigma"):
        jh.ResidualProblem(lambda th, d: th["a"] - d, space, jnp.ones(3),
                           priors=[jh.GaussianPrior("a", 7000.0, 100.0)])
    with pytest.raises(ValueError, match="not free parameters"):
        jh.ResidualProblem(lambda th, d: th["a"] - d, space, jnp.ones(3),
                           groups={"residuals": {"sigma": 1.0}},
                           priors=[jh.GaussianPrior("b", 1.0, 1.0)])


def test_residuals_in_metres_without_noise_levels_still_reach_the_optimum():
    """A first try with neither sigma nor scale: displacement residuals of ~1e-6 m would
    make every LM step ~1e-12 and stop the solve at its start as "converged"; each group
    is scaled by its residuals' size in the box instead. One parameter in a dict (a
    one-key dict start is read as parameters), the truth at the centre of the box."""
    data = DRIVE_Y.observed(simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, DRIVE_Y).y)

    def fn(theta, data):
        p = jh.TABLE1_TRUE.replace(a=theta["a"])
        return {"y": DRIVE_Y.observed(simulate_unchecked(p, jh.ACTUATOR1, DRIVE_Y).y) - data}

    space = jh.ParameterSpace.for_tree(lower={"a": 5012.0}, upper={"a": 9012.0})
    problem = jh.ResidualProblem(fn, space, data)
    scale = problem.groups[0].scale
    assert 1e-7 < scale < float(np.max(np.abs(data)))  # the residuals' size, not 1 (m)
    fit = jh.solve(problem, {"a": 6000.0}, solver="lm", report=False)
    assert fit.success and abs(float(fit.params["a"]) - 7012.0) < 1e-6


def test_a_start_of_the_wrong_kind_is_refused_with_what_to_give(problem):
    with pytest.raises(ValueError, match=r"must lie in \[0, 1\].*a, c, k.*'a', 'c', 'k'"):
        jh.solve(problem, np.array([6000.0, 0.1, 3000.0]), solver="lm", report=False)
    with pytest.raises(TypeError, match=r"missing \['c'\]"):
        jh.solve(problem, {"a": 6000.0, "k": 3000.0}, solver="lm", report=False)
    import types

    from jaxhyst.identify import start_z

    flat = types.SimpleNamespace(space=jh.ParameterSpace.for_tree(np.zeros(2), np.ones(2)))
    with pytest.raises(TypeError, match=r"start must be box coordinates u in \[0, 1\]"):
        start_z(flat, {"a": 1.0})  # a space over one array takes box coordinates only


def test_solver_names_in_any_case_and_a_count_of_starts_is_explained(problem):
    from jaxhyst.identify.solvers import make_solver

    assert type(make_solver("LM")) is type(make_solver("lm"))
    with pytest.raises(ValueError, match=r"not their number.*\(8, 3\)"):
        jh.multistart(problem, 8)
