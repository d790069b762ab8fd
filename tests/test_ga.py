"""GA operators and the hybrid driver (issue 4)."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import table1_problem

import jaxhyst as jh
from jaxhyst.identify import ga

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
    children = ga.fcga_offspring(KEY, U, fitness, 10, 300, 1.0, 1.0)
    np.testing.assert_array_equal(children[0], U[29])
    np.testing.assert_array_equal(children[1], U[28])
    genes = ga.encode(U, 16)
    kids = ga.bcga_offspring(KEY, genes, fitness, 1.0, 1.0)
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


SMALL = jh.GASettings(q1=24, q2=10, T1=2, T2=8, T3=20, local_steps=4)


@pytest.fixture(scope="module")
def problem():
    return table1_problem(spp=50)


@pytest.fixture(scope="module")
def gatr1_run(problem):
    return jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL)


def test_short_gatr1_improves_by_orders_of_magnitude(gatr1_run):
    history = gatr1_run.extra["history"]
    initial = history[0]["best_cost"]  # best of the initial (random) population
    assert gatr1_run.cost < 1e-4 * initial, (initial, gatr1_run.cost)
    assert len(history) == SMALL.T1 + SMALL.T2
    assert [h["phase"] for h in history[:3]] == ["BCGA", "BCGA", "FCGA"]
    assert history[-1]["evaluations"] == SMALL.T1 * SMALL.q1 + SMALL.T2 * SMALL.q2
    assert all(h["local"] is not None for h in history[SMALL.T1:])
    best = [h["best_cost"] for h in history]
    assert all(b2 <= b1 for b1, b2 in zip(best, best[1:], strict=False))  # elitism
    assert jh.TABLE1_BOUNDS.contains(gatr1_run.params)
    assert gatr1_run.report is not None and gatr1_run.report.rank == 7  # hybrids report too


def test_same_seed_same_result_and_different_seeds_differ(problem, gatr1_run):
    again = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL)
    np.testing.assert_array_equal(again.params.to_array(), gatr1_run.params.to_array())
    assert again.cost == gatr1_run.cost
    other = jh.run_hybrid(problem, "GA", seed=4, settings=SMALL)
    same_seed_plain = jh.run_hybrid(problem, "GA", seed=3, settings=SMALL)
    assert not np.array_equal(other.params.to_array(), same_seed_plain.params.to_array())


def test_checkpoint_resume_gives_the_uninterrupted_result(problem, gatr1_run, tmp_path):
    path = tmp_path / "run.npz"
    part = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                         checkpoint_every=2, stop_after=5)
    assert part.result == "interrupted" and path.exists()
    assert len(part.extra["history"]) == 5
    resumed = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                            resume=True)
    np.testing.assert_array_equal(resumed.params.to_array(), gatr1_run.params.to_array())
    assert len(resumed.extra["history"]) == SMALL.T1 + SMALL.T2
    with pytest.raises(ValueError, match="belongs to another run"):
        jh.run_hybrid(problem, "GATR1", seed=99, settings=SMALL, checkpoint=path, resume=True)


def test_after_placement_runs_t3_local_steps(problem):
    res = jh.run_hybrid(problem, "GALM2", seed=1, settings=SMALL)
    after = res.extra["after"]
    assert after is not None and 1 <= after["steps"] <= SMALL.T3
    assert res.cost <= after["cost_before"]


class _FlakyProblem(jh.Problem):
    """A problem whose simulation 'diverges' (NaN cost) wherever u[0] > 0.5. The model
    itself stays finite throughout the Table 1 box (test_model), so failures are injected."""

    def cost_u(self, u):
        return jnp.where(u[0] > 0.5, jnp.nan, super().cost_u(u))


def test_failed_individuals_get_zero_fitness_and_are_counted(problem):
    flaky = _FlakyProblem(problem.data, problem.drive, problem.actuator, problem.space)
    U = jax.random.uniform(KEY, (64, 10))
    costs = np.asarray(jh.identify.hybrid._evaluate(flaky, U))
    assert np.any(~np.isfinite(costs)) and np.any(np.isfinite(costs))
    fit = np.asarray(flaky.fitness_from_cost(jnp.asarray(costs)))
    assert np.all(fit[~np.isfinite(costs)] == 0) and np.all(fit[np.isfinite(costs)] > 0)
    res = jh.run_hybrid(flaky, "GA", seed=0, settings=jh.GASettings(q1=64, q2=10, T1=1, T2=2))
    history = res.extra["history"]
    assert history[0]["failures"] > 0 and res.extra["failures"] >= history[0]["failures"]
    assert np.isfinite(res.cost) and float(u_first(res, flaky)) <= 0.5


def u_first(res, problem):
    return problem.space.u_from_params(res.params)[0]


def test_ctrl_c_mid_generation_keeps_best_and_resumes_exactly(problem, gatr1_run, tmp_path,
                                                               monkeypatch):
    from jaxhyst.identify import hybrid

    real_evaluate = hybrid._evaluate
    calls = {"n": 0}

    def interrupting(prob, U):
        calls["n"] += 1
        if calls["n"] == 7:  # inside generation 7, after six complete generations
            raise KeyboardInterrupt
        return real_evaluate(prob, U)

    path = tmp_path / "ctrl_c.npz"
    monkeypatch.setattr(hybrid, "_evaluate", interrupting)
    part = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                         checkpoint_every=100)
    monkeypatch.setattr(hybrid, "_evaluate", real_evaluate)
    assert part.result == "interrupted" and np.isfinite(part.cost)
    assert len(part.extra["history"]) == 6
    resumed = jh.run_hybrid(problem, "GATR1", seed=3, settings=SMALL, checkpoint=path,
                            resume=True)
    np.testing.assert_array_equal(resumed.params.to_array(), gatr1_run.params.to_array())
    assert [h["generation"] for h in resumed.extra["history"]] == list(range(1, 11))
