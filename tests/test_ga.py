"""GA operators and the hybrid driver (issue 4)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import exponential_problem, table1_problem

import jaxhyst as jh
from jaxhyst._interrupt import clear_stop
from jaxhyst.identify import ga, hybrid

KEY = jax.random.PRNGKey(42)


def test_binary_decoding_is_exact_at_the_ends_and_inside_the_box():
    for bits in (4, 16):
        levels = 2**bits - 1
        b = ga.encode(jnp.array([0.0, 1.0]), bits)
        assert b.shape == (2, bits)
        np.testing.assert_array_equal(ga.decode(b), [0.0, 1.0])
        assert int(b[1].sum()) == bits  # 2^p − 1 is all ones
        random_bits = jax.random.bernoulli(KEY, 0.5, (500, 10, bits)).astype(jnp.uint8)
        u = ga.decode(random_bits)
        assert bool(jnp.all((u >= 0) & (u <= 1)))
        # round trip through the grid v/(2^p − 1)
        v = jnp.arange(levels + 1) if bits == 4 else jnp.array([0, 1, 12345, levels])
        np.testing.assert_array_equal(ga.decode(ga.encode(v / levels, bits)), v / levels)


def test_single_point_crossover_swaps_tails_and_bit_flip_flips_one_bit():
    a = jnp.zeros(32, jnp.uint8)
    b = jnp.ones(32, jnp.uint8)
    ca, cb = ga.single_point_crossover(KEY, a, b)
    point = int(jnp.argmax(ca))
    assert 1 <= point <= 31
    assert bool(jnp.all(ca[:point] == 0) & jnp.all(ca[point:] == 1))
    assert bool(jnp.all(ca + cb == 1))
    genes = jnp.zeros((10, 16), jnp.uint8)
    mutated = ga.bit_flip_mutation(KEY, genes, 1.0)
    np.testing.assert_array_equal(mutated.sum(axis=1), np.ones(10))
    np.testing.assert_array_equal(ga.bit_flip_mutation(KEY, genes, 0.0), genes)


def test_arithmetic_crossover_children_inside_parents_box():
    keys = jax.random.split(KEY, 1000)
    x = jax.random.uniform(jax.random.PRNGKey(1), (1000, 10))
    z = jax.random.uniform(jax.random.PRNGKey(2), (1000, 10))
    cx, cz = jax.vmap(ga.arithmetic_crossover)(keys, x, z)
    lo, hi = jnp.minimum(x, z), jnp.maximum(x, z)
    for c in (cx, cz):
        assert bool(jnp.all((c >= lo - 1e-15) & (c <= hi + 1e-15)))
    np.testing.assert_allclose(cx + cz, x + z, atol=1e-14)


def test_non_uniform_mutation_stays_in_bounds_and_shrinks():
    x = jax.random.uniform(jax.random.PRNGKey(3), (4000, 10))
    keys = jax.random.split(KEY, 4000)
    steps = []
    for gen in (1, 150, 290):
        m = jax.vmap(ga.non_uniform_mutation, in_axes=(0, 0, None, None, None))(
            keys, x, gen, 300, 1.0)
        assert bool(jnp.all((m >= 0) & (m <= 1)))
        steps.append(float(jnp.mean(jnp.abs(m - x))))
    assert steps[0] > steps[1] > steps[2] and steps[2] < 1e-3 * steps[0]
    m = jax.vmap(ga.non_uniform_mutation, in_axes=(0, 0, None, None, None))(keys, x, 300, 300, 1.0)
    np.testing.assert_array_equal(m, x)  # no movement at i = T


def test_elites_survive_unchanged():
    U = jax.random.uniform(KEY, (30, 10))
    fitness = jnp.arange(30.0)
    # (jitted, as in the generations: op by op each operation compiles on its own)
    children = jax.jit(ga.fcga_offspring)(KEY, U, fitness, 10, 300, 1.0, 1.0)
    np.testing.assert_array_equal(children[0], U[29])
    np.testing.assert_array_equal(children[1], U[28])
    genes = jax.jit(ga.encode, static_argnums=1)(U, 16)
    kids = jax.jit(ga.bcga_offspring)(KEY, genes, fitness, 1.0, 1.0)
    np.testing.assert_array_equal(kids[0], genes[29])
    np.testing.assert_array_equal(kids[1], genes[28])


def test_roulette_frequency_is_proportional_to_fitness():
    fitness = jnp.array([1.0, 2.0, 3.0, 4.0, 0.0])
    n = 200_000
    idx = ga.roulette_wheel(jax.random.PRNGKey(7), fitness, n)
    freq = np.bincount(np.asarray(idx), minlength=5) / n
    expected = np.asarray(fitness) / 10.0
    # 5 binomial standard deviations at most (≈ 0.0055 for p = 0.4)
    sd = np.sqrt(expected * (1 - expected) / n)
    assert np.all(np.abs(freq - expected) <= 5 * sd + 1e-12), freq
    assert freq[4] == 0.0


SMALL = dict(q1=24, q2=10, T1=2, T2=8, T3=20, local_steps=4, check_steps=30)
TINY = dict(q1=8, q2=4, T1=1, T2=2, T3=3, local_steps=2, check_steps=5)


@pytest.fixture(scope="module")
def problem():
    return table1_problem(spp=25)


@pytest.fixture(scope="module")
def small():
    """y = exp(b·t) + m, two parameters (tests/helpers.py): the hybrids' machinery on a
    problem whose programs compile in a second or two (the Table 1 problem's hybrids run
    in the extended step)."""
    return exponential_problem(0.5)[0]


def _values(problem, params) -> np.ndarray:
    return np.asarray(problem.space.free_values(params))


@pytest.fixture(scope="module")
def gatr1_run(problem):
    return jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL)


@pytest.mark.extended  # (GATR1 in full; every hybrid runs short below)
def test_short_gatr1_improves_by_orders_of_magnitude(gatr1_run):
    history = gatr1_run.extra["history"]
    initial = history[0]["best_cost"]  # best of the initial (random) population
    assert gatr1_run.cost < 1e-4 * initial, (initial, gatr1_run.cost)
    assert len(history) == SMALL["T1"] + SMALL["T2"]
    assert [h["phase"] for h in history[:3]] == ["BCGA", "BCGA", "FCGA"]
    assert history[-1]["evaluations"] == SMALL["T1"] * SMALL["q1"] + SMALL["T2"] * SMALL["q2"]
    assert all(h["local"] is not None for h in history[SMALL["T1"]:])
    best = [h["best_cost"] for h in history]
    assert all(b2 <= b1 for b1, b2 in zip(best, best[1:], strict=False))  # elitism
    assert jh.TABLE1_BOUNDS.contains(gatr1_run.params)
    assert gatr1_run.report is not None and gatr1_run.report.rank == 7  # hybrids report too
    check = gatr1_run.extra["convergence_check"]
    assert check is not None and gatr1_run.result == check["result"]


# GATR1 runs in full in the gatr1_run fixture's tests; GALM1 differs from GALM2 only in
# its local solver's placement, which GATR1/GATR2 check: both in the slow run.
@pytest.mark.parametrize("method", [
    pytest.param(m, marks=pytest.mark.slow) if m in ("GATR1", "GALM1") else m
    for m in jh.names.HYBRID_NAMES])
def test_every_hybrid_runs_and_ends_with_a_convergence_check(small, method):
    res = jh.run_hybrid(small, method, seed=0, settings=TINY, report=False)
    history = res.extra["history"]
    assert len(history) == TINY["T1"] + TINY["T2"] and np.isfinite(res.cost)
    check = res.extra["convergence_check"]
    assert check["steps"] <= TINY["check_steps"] and res.result == check["result"]
    assert res.cost <= history[-1]["best_cost"] * (1 + 1e-12)
    assert (res.extra["after"] is not None) == (method in ("GATR2", "GALM2"))
    # 5 LM steps from a tiny GA's best cannot converge: the run says it stopped short
    assert res.result == "max_steps_reached" and not res.success


def test_a_solver_object_plugs_into_the_ga():
    import optimistix as optx

    # (on a small problem: the solver's program is new, the plumbing is the same)
    small, _ = exponential_problem(0.5)
    method = jh.HybridGA(optx.Dogleg(rtol=1e-10, atol=1e-12), "after", "GA+dogleg")
    res = jh.run_hybrid(small, method, seed=0, settings=TINY, report=False)
    assert res.extra["after"] is not None and res.solver == "GA+dogleg"
    assert np.isfinite(res.cost)


@pytest.mark.extended  # (GATR1 in full twice)
def test_same_seed_same_result_and_different_seeds_differ(problem, gatr1_run):
    again = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, report=False)
    np.testing.assert_array_equal(again.params.to_array(), gatr1_run.params.to_array())
    assert again.cost == gatr1_run.cost
    other = jh.run_hybrid(problem, "GA", seed=4, settings=TINY, report=False)
    same_seed_plain = jh.run_hybrid(problem, "GA", seed=3, settings=TINY, report=False)
    assert not np.array_equal(other.params.to_array(), same_seed_plain.params.to_array())


@pytest.mark.extended  # (GATR1 in full; also in the compat step)
@pytest.mark.compat
def test_checkpoint_resume_gives_the_uninterrupted_result(problem, gatr1_run, tmp_path):
    path = tmp_path / "run.npz"
    part = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                         checkpoint_every=2, stop_after=5, report=False)
    assert part.result == "interrupted" and path.exists() and not part.success
    assert len(part.extra["history"]) == 5
    resumed = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                            resume=True, report=False)
    np.testing.assert_array_equal(resumed.params.to_array(), gatr1_run.params.to_array())
    assert len(resumed.extra["history"]) == SMALL["T1"] + SMALL["T2"]
    with pytest.raises(ValueError, match="belongs to another run"):
        jh.run_hybrid(problem, "GATR1", seed=99, settings=SMALL, checkpoint=path, resume=True)


@pytest.mark.parametrize("content, fragment", [
    (None, "does not exist"),
    (b"", "not a readable jaxhyst checkpoint"),
    (b"PK\x03\x04 truncated zip", "not a readable jaxhyst checkpoint"),
    (b"generation,cost\n1,2\n", "not a readable jaxhyst checkpoint"),
])
def test_bad_checkpoints_are_refused_in_one_line(small, tmp_path, content, fragment):
    path = tmp_path / "bad.npz"
    if content is not None:
        path.write_bytes(content)
    with pytest.raises(jh.identify.CheckpointError, match=fragment) as err:
        jh.run_hybrid(small, "GA", seed=0, settings=TINY, checkpoint=path, resume=True)
    assert "\n" not in str(err.value)


def test_a_checkpoint_of_another_shape_is_refused(small, tmp_path):
    path = tmp_path / "other.npz"
    jh.run_hybrid(small, "GA", seed=0, settings=TINY, checkpoint=path, stop_after=1,
                  report=False)
    other = {**TINY, "q1": 12}
    with pytest.raises(jh.identify.CheckpointError, match="does not match this run"):
        jh.run_hybrid(small, "GA", seed=0, settings=other, checkpoint=path, resume=True)


def test_after_placement_runs_t3_local_steps(small):
    res = jh.run_hybrid(small, "GALM2", seed=1, settings=SMALL, report=False)
    after = res.extra["after"]
    assert after is not None and 1 <= after["steps"] <= SMALL["T3"]
    assert res.cost <= after["cost_before"]


def test_an_interruption_in_the_after_solve_returns_the_point_reached(small, monkeypatch,
                                                                     tmp_path):
    from jaxhyst._interrupt import request_stop
    from jaxhyst.identify import hybrid

    real = hybrid._final_solve

    def interrupted(*args, **kwargs):
        request_stop()  # as a Ctrl-C of the command line when the final local solve starts
        return real(*args, **kwargs)

    path = tmp_path / "after.npz"
    monkeypatch.setattr(hybrid, "_final_solve", interrupted)
    res = jh.run_hybrid(small, "GALM2", seed=1, settings=SMALL, report=False,
                        checkpoint=path, checkpoint_every=100)
    monkeypatch.setattr(hybrid, "_final_solve", real)
    clear_stop()
    after = res.extra["after"]
    assert res.result == "interrupted" and after["result"] == "interrupted"
    assert after["steps"] == 1 and res.extra["convergence_check"] is None
    assert np.isfinite(res.cost) and res.cost <= after["cost_before"]
    assert len(res.extra["history"]) == SMALL["T1"] + SMALL["T2"]  # the GA itself ran to its end
    # the completed GA was saved: a resume runs only the final solves, and ends as an
    # uninterrupted run does
    resumed = jh.run_hybrid(small, "GALM2", seed=1, settings=SMALL, report=False,
                            checkpoint=path, resume=True)
    whole = jh.run_hybrid(small, "GALM2", seed=1, settings=SMALL, report=False)
    assert resumed.extra["history"][-1]["generation"] == SMALL["T1"] + SMALL["T2"]
    np.testing.assert_array_equal(_values(small, resumed.params), _values(small, whole.params))


def test_an_interruption_before_the_convergence_check_saves_and_says_so(small, monkeypatch,
                                                                       tmp_path, capsys):
    from jaxhyst._interrupt import request_stop
    from jaxhyst.identify import hybrid

    real = hybrid._final_solve

    def then_interrupted(*args, **kwargs):
        out = real(*args, **kwargs)
        request_stop()  # as a Ctrl-C right after the final local solve ended
        return out

    path = tmp_path / "check.npz"
    monkeypatch.setattr(hybrid, "_final_solve", then_interrupted)
    res = jh.run_hybrid(small, "GALM2", seed=1, settings=SMALL, report=False,
                        checkpoint=path, checkpoint_every=100, progress=100)
    clear_stop()
    assert res.result == "interrupted" and res.extra["convergence_check"] is None
    assert res.extra["after"]["result"] != "interrupted"
    assert path.exists()
    err = capsys.readouterr().err
    assert "interrupted before the convergence check" in err and "done:" not in err


class _FlakyProblem(jh.AbstractProblem):
    """A problem whose simulation 'diverges' (NaN residuals) wherever u[0] > 0.5. The
    JA model stays finite throughout the Table 1 box (test_model), so failures are
    injected around another problem."""

    inner: jh.AbstractProblem

    @property
    def output(self):
        return self.inner.output

    @property
    def space(self):
        return self.inner.space

    @property
    def priors(self):
        return self.inner.priors

    @property
    def groups(self):
        return self.inner.groups

    def group_residuals(self, params):
        bad = self.space.u_from_params(params)[0] > 0.5
        return tuple(jnp.where(bad, jnp.nan, r) for r in self.inner.group_residuals(params))

    @property
    def observations(self):
        return self.inner.observations

    def with_data(self, data):
        return _FlakyProblem(self.inner.with_data(data))


def test_failed_individuals_get_zero_fitness_and_are_counted():
    # (the GA's handling is the problem's business only through its residuals: a small
    # problem of two parameters, wrapped as the Table 1 problem would be)
    flaky = _FlakyProblem(exponential_problem(0.5)[0])
    U = jax.random.uniform(KEY, (64, 2))
    costs = np.asarray(hybrid._evaluate(flaky, U))
    assert np.any(~np.isfinite(costs)) and np.any(np.isfinite(costs))
    fit = np.asarray(flaky.fitness_from_cost(jnp.asarray(costs)))
    assert np.all(fit[~np.isfinite(costs)] == 0) and np.all(fit[np.isfinite(costs)] > 0)
    res = jh.run_hybrid(flaky, "GA", seed=0, report=False,
                        settings=dict(q1=64, q2=10, T1=1, T2=2, check_steps=0))
    history = res.extra["history"]
    assert history[0]["failures"] > 0 and res.extra["failures"] >= history[0]["failures"]
    assert np.isfinite(res.cost) and float(flaky.space.u_from_params(res.params)[0]) <= 0.5
    assert res.result == "max_steps_reached"  # no convergence check: never "successful"


@pytest.mark.extended  # (GATR1 in full)
def test_ctrl_c_stops_at_the_generation_keeps_best_and_resumes_exactly(
        problem, gatr1_run, tmp_path, monkeypatch):
    """Ctrl-C in Python (no handler installed by jaxhyst) ends the run at the last
    complete generation: `jaxhyst.Interrupted` carries the best point so far, the
    checkpoint is written, and a resume gives the uninterrupted result."""
    import os
    import signal

    from jaxhyst.identify import hybrid

    real = hybrid._fcga_generation
    calls = {"n": 0}

    def interrupting(*args):
        calls["n"] += 1
        if calls["n"] == 4:  # during generation 6 (two BCGA generations first)
            os.kill(os.getpid(), signal.SIGINT)
        return real(*args)

    path = tmp_path / "ctrl_c.npz"
    monkeypatch.setattr(hybrid, "_fcga_generation", interrupting)
    # Python's own Ctrl-C handler, as in a terminal: a background job of a shell
    # (`pytest … &`) starts with SIGINT ignored, and the signal would then do nothing
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)
    try:
        with pytest.raises(jh.Interrupted) as caught:
            jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                          checkpoint_every=100, report=False)
    finally:
        signal.signal(signal.SIGINT, previous)
    monkeypatch.setattr(hybrid, "_fcga_generation", real)
    part = caught.value.result
    assert isinstance(caught.value, KeyboardInterrupt)
    assert part.result == "interrupted" and np.isfinite(part.cost)
    assert len(part.extra["history"]) == 5  # the generation under way is not kept
    resumed = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                            resume=True, report=False)
    np.testing.assert_array_equal(resumed.params.to_array(), gatr1_run.params.to_array())
    assert [h["generation"] for h in resumed.extra["history"]] == list(range(1, 11))


def test_hybrids_share_their_generations_and_the_local_solvers_programs(caplog):
    """The generation programs leave out the local solver, its placement and the name,
    so the plain GA after GATR1 compiles nothing; GATR1's inside search runs the
    programs of a stepped solve of one start, which GATR2's ``after`` solve (the same
    solver) shares: GATR2 then compiles nothing, nor does a renamed GATR1. (A small
    problem of its own, so that no other test has compiled these programs.)"""
    import logging

    t = jnp.linspace(0.0, 1.0, 13)

    def residuals(theta, data):
        return {"y": theta["a"] * jnp.tanh(theta["w"] * t) - data["y"]}

    space = jh.ParameterSpace.for_tree(lower={"a": 0.1, "w": 0.1}, upper={"a": 10.0, "w": 10.0})
    problem = jh.ResidualProblem(residuals, space, {"y": 2.0 * jnp.tanh(3.0 * t)})
    settings = {**TINY, "check_steps": 0}

    def compiled(method):
        caplog.clear()
        with jax.log_compiles(), caplog.at_level(logging.WARNING):
            jh.run_hybrid(problem, method, seed=1, settings=settings, report=False)
        return [r.getMessage()[:80] for r in caplog.records
                if r.getMessage().startswith("Compiling")
                and "jit(_ended)" not in r.getMessage()]  # (the driver's stop test:
        # a handful of operations, which the inside search does not run)

    first = " ".join(compiled("GATR1"))
    assert all(p in first for p in ("_bcga_generation", "_fcga_costs", "_fcga_generation",
                                    "_advance_batch"))
    assert compiled("GA") == []
    assert compiled("GATR2") == []
    assert compiled(jh.HybridGA("tra", "inside", "my GATR1", **settings)) == []


def test_new_generation_counts_step_limits_and_probabilities_compile_nothing(
        small, caplog):
    import logging

    first = {**TINY, "T1": 2}  # two BCGA generations: the second reuses too
    jh.run_hybrid(small, "GATR1", seed=0, settings=first, report=False)
    other = {**first, "T1": 3, "T2": 4, "pc": 0.5, "pm": 0.3, "beta": 2.0, "c1": 1e-20,
             "check_steps": 7}
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        res = jh.run_hybrid(small, "GATR1", seed=0, settings=other, report=False)
    compiled = [r.getMessage()[:80] for r in caplog.records
                if r.getMessage().startswith("Compiling")]
    assert compiled == []
    history = res.extra["history"]
    assert [h["phase"] for h in history] == ["BCGA"] * 3 + ["FCGA"] * 4
    # the traced probabilities take effect: the same seed and generation counts with the
    # default pc and pm breed another second generation
    same_counts = {**first, "T1": 3, "T2": 4}
    base = jh.run_hybrid(small, "GATR1", seed=0, settings=same_counts, report=False)
    assert base.extra["history"][1]["mean_fitness"] != history[1]["mean_fitness"]
