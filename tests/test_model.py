"""The simulator (issue 2): accuracy against an independent solver, convergence order,
gradients against finite differences, batching, physics and input validation."""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import cases, np_langevin, reference_simulation

import jaxhyst as jh
from jaxhyst.model.langevin import langevin_and_slope
from jaxhyst.model.simulate import simulate_unchecked

CASES = cases()
FINE_SUBSTEPS = 8


@pytest.fixture(scope="module")
def references():
    return {name: reference_simulation(p, a, d)[1] for name, p, a, d in CASES}


def _rel_err(y, y_ref):
    return float(np.max(np.abs(np.asarray(y) - y_ref)) / np.max(np.abs(y_ref)))


@pytest.mark.parametrize("case", CASES, ids=[c[0] for c in CASES])
def test_agrees_with_reference(case, references):
    name, p, act, drive = case
    y_ref = references[name]
    # (the simulation unchecked: `simulate` returns its values, test_compiles; its
    # sampling check has tests of its own and would compile two more programs)
    assert _rel_err(simulate_unchecked(p, act, drive).y, y_ref) <= 1e-5
    assert _rel_err(simulate_unchecked(p, act, drive, substeps=FINE_SUBSTEPS).y,
                    y_ref) <= 1e-7


def test_convergence_order(references):
    name, p, act, drive = CASES[0]
    errs = [_rel_err(simulate_unchecked(p, act, drive, substeps=s).y, references[name])
            for s in (1, 2, 4, 8)]
    orders = np.log2(np.array(errs[:-1]) / np.array(errs[1:]))
    # RK4 with the δM switch located: 4th order (measured 4.1, 4.1, 4.0).
    assert np.all(orders > 3.5), (errs, orders)


VARIANTS = {"classic": jh.ClassicJA(), "venkataraman": jh.VenkataramanJA(), "pop": jh.PopJA()}


@pytest.mark.parametrize("name", sorted(VARIANTS))
def test_variant_agrees_with_reference_and_its_gradient_with_differences(name):
    _, p, act, drive = CASES[1]  # Actuator2 at 10 Hz: a biased major loop
    variant = VARIANTS[name]
    M_ref, y_ref = reference_simulation(p, act, drive, variant=name)
    sim = simulate_unchecked(p, act, drive, variant=variant, substeps=FINE_SUBSTEPS)
    assert _rel_err(sim.y, y_ref) <= 1e-7 and _rel_err(sim.M, M_ref) <= 1e-7
    # d(observed M)/dθ along a direction in the JA parameters vs Richardson differences
    direction = jnp.zeros(10).at[jnp.array([0, 2, 3, 4, 5])].set(
        jnp.array([0.3, -0.5, 0.4, 0.6, -0.2]))
    x0 = p.to_array()

    def f(s):
        x = x0 * (1 + s * direction)
        return drive.observed(simulate_unchecked(jh.Parameters.from_array(x), act, drive,
                                                 variant).M)

    _, jvp = jax.jit(lambda s: jax.jvp(f, (s,), (1.0,)))(0.0)
    g = jax.jit(f)
    h = 1e-4
    fd1 = (g(h) - g(-h)) / (2 * h)
    fd2 = (g(2 * h) - g(-2 * h)) / (4 * h)
    fd = (4 * fd1 - fd2) / 3
    assert float(jnp.max(jnp.abs(jvp - fd)) / jnp.max(jnp.abs(jvp))) < 1e-6


def test_pop_form_at_c_one_is_the_anhysteretic_curve_with_finite_gradients():
    # c = 1 makes the sign-continuous form purely reversible (with α̃ = 0: M = Man); at
    # H = M = 0 its irreversible term is 0/0 without the guard, poisoning every sample.
    _, p, act, drive = CASES[1]
    x = p.to_array().at[jh.NAMES.index("c")].set(1.0).at[jh.NAMES.index("alpha")].set(0.0)
    sim = simulate_unchecked(jh.Parameters.from_array(x), act, drive, variant=jh.PopJA())
    assert bool(sim.finite)
    np.testing.assert_allclose(sim.M, sim.Man, rtol=0, atol=1e-6 * float(jnp.max(sim.Man)))
    g = jax.jit(jax.grad(lambda z: jnp.sum(simulate_unchecked(
        jh.Parameters.from_array(z), act, drive, jh.PopJA()).M ** 2)))(x)
    assert bool(jnp.all(jnp.isfinite(g)))


def test_langevin_matches_numpy_and_is_smooth_at_zero():
    xs = np.concatenate([np.linspace(-40, 40, 401), np.geomspace(1e-8, 0.3, 50)])
    L, dL = jax.vmap(langevin_and_slope)(jnp.asarray(xs))
    ref = np.array([np_langevin(x) for x in xs])
    assert np.allclose(L, ref[:, 0], rtol=1e-13, atol=1e-300)
    assert np.allclose(dL, ref[:, 1], rtol=1e-12, atol=1e-300)
    g = jax.grad(jh.langevin)(0.0)
    assert np.isfinite(g) and abs(g - 1 / 3) < 1e-15
    gg = jax.grad(jax.grad(jh.langevin))(0.0)
    assert np.isfinite(gg) and abs(gg) < 1e-12


def _observed_y(x, act, drive):
    return drive.observed(simulate_unchecked(jh.Parameters.from_array(x), act, drive).y)


@pytest.mark.compat
@pytest.mark.parametrize("case", [CASES[0], CASES[2]], ids=["table1", "act2_1000Hz"])
def test_jacfwd_and_grad_match_central_differences(case):
    _, p, act, drive = case
    x0 = p.to_array()
    J = jax.jit(jax.jacfwd(lambda x: _observed_y(x, act, drive)))(x0)
    f = jax.jit(lambda x: _observed_y(x, act, drive))
    # Central differences with Richardson extrapolation (error O(h⁴)), relative step 1e-3:
    # smaller steps drown in the ~1e-11 relative round-off that the matrix exponential of
    # the structural step accumulates over the scan (Kz, Mz, Cz columns; measured worst
    # 1.2e-6 at 1e-3, 6e-5 at 1e-4). The JA columns agree to ~1e-10 at any step.
    steps = np.maximum(np.abs(np.asarray(x0)) * 1e-3, 1e-7)

    def central(i, h):
        e = np.zeros(10)
        e[i] = h
        return (np.asarray(f(x0 + e)) - np.asarray(f(x0 - e))) / (2 * h)

    for i, h in enumerate(steps):
        fd = (4 * central(i, h / 2) - central(i, h)) / 3
        scale = np.max(np.abs(fd))
        assert scale > 0
        assert np.max(np.abs(np.asarray(J[:, i]) - fd)) <= 1e-5 * scale, jh.NAMES[i]
    # reverse mode on a scalar loss agrees with forward mode
    loss = lambda x: jnp.sum(_observed_y(x, act, drive) ** 2)
    g = jax.grad(loss)(x0)
    y = f(x0)
    g_fwd = 2 * y @ J
    assert np.allclose(g, g_fwd, rtol=1e-9, atol=0)


@pytest.mark.compat
def test_vmap_equals_loop_and_jit():
    _, p, act, drive = CASES[0]
    key = jax.random.PRNGKey(1)
    lo = jh.TABLE1_BOUNDS.lower.to_array()
    hi = jh.TABLE1_BOUNDS.upper.to_array()
    X = lo + (hi - lo) * jax.random.uniform(key, (5, 10))
    batch = jh.simulate_batch(jh.Parameters.from_array(X), act, drive)
    for i in range(5):
        single = jh.simulate(jh.Parameters.from_array(X[i]), act, drive)
        np.testing.assert_allclose(batch.y[i], single.y, rtol=1e-13, atol=1e-20)
        np.testing.assert_allclose(batch.M[i], single.M, rtol=1e-13, atol=1e-9)
    jitted = jax.jit(lambda q: simulate_unchecked(q, act, drive).y)(p)
    np.testing.assert_allclose(jitted, jh.simulate(p, act, drive).y, rtol=1e-14, atol=1e-20)


def test_a_population_in_blocks_equals_the_whole_vmap():
    """`vmap_blocked` (large populations on the CPU run block by block, the last block
    padded with copies of the last member) gives jax.vmap's values and shapes."""
    from jaxhyst.sharding import vmap_blocked

    _, _, act, drive = CASES[0]
    lo = jh.TABLE1_BOUNDS.lower.to_array()
    hi = jh.TABLE1_BOUNDS.upper.to_array()
    X = lo + (hi - lo) * jax.random.uniform(jax.random.PRNGKey(3), (18, 10))

    def one(x):
        sim = simulate_unchecked(jh.Parameters.from_array(x), act, drive)
        return sim.y, {"M": sim.M}

    whole = jax.jit(jax.vmap(one))(X)
    blocked = jax.jit(vmap_blocked(one, 18, block=4))(X)  # 5 blocks, 2 padding members
    for a, b in zip(jax.tree.leaves(whole), jax.tree.leaves(blocked), strict=True):
        assert a.shape == b.shape == (18, drive.n_samples)
        np.testing.assert_allclose(b, a, rtol=1e-13, atol=1e-13 * float(jnp.max(jnp.abs(a))))
    # on the CPU the blocks are one loop more than the whole vmap's; elsewhere (a GPU
    # wants the whole batch at once) and below 4 blocks they are the whole vmap
    on_cpu = jax.default_backend() == "cpu"
    loops = str(jax.make_jaxpr(jax.vmap(one))(X)).count("scan")
    jaxpr = str(jax.make_jaxpr(vmap_blocked(one, 18, block=4))(X))
    assert jaxpr.count("scan") == loops + on_cpu
    small = str(jax.make_jaxpr(vmap_blocked(one, 15, block=4))(X[:15]))  # < 4 blocks
    assert small.count("scan") == loops
    with pytest.raises(ValueError, match="block"):
        vmap_blocked(one, 18, block=0)


def test_a_drive_stepping_over_the_materials_knee_is_warned_of_not_silently_beyond_ms():
    """The accuracy screen looks at the field's steps against its range: 1 MA/m at 200
    samples a period moves < 1 % of it per substep, but steps over the whole knee of a
    material with a = 14 A/m in one sample, and M overshoots saturation hundreds of
    times (the CLI printed max |M|/Ms 337 without a word). Beyond Ms the check runs."""
    from jaxhyst.model.accuracy import SamplingWarning

    p = jh.Parameters(Ms=3.2e5, lambda_s=0.0, a=14.4, k=12.0, alpha=1.2e-5, c=0.5, E=1.0,
                      Kz=1.0, Mz=1.0, Cz=0.0)
    drive = jh.sinusoidal_field(100.0, 1e6, samples_per_period=200)
    with pytest.warns(SamplingWarning, match="too large to say how many substeps"):
        sim = jh.simulate(p, jh.Actuator(1.0, 1.0), drive, jh.ClassicJA())
    assert float(jnp.max(jnp.abs(sim.M))) > 1.001 * 3.2e5  # (what it warns of)


def test_no_nan_anywhere_in_table1_box():
    _, _, act, drive = CASES[0]
    lo = jh.TABLE1_BOUNDS.lower.to_array()
    hi = jh.TABLE1_BOUNDS.upper.to_array()
    u = jax.random.uniform(jax.random.PRNGKey(7), (64, 10))
    u = u.at[:4].set(jnp.array([0.0, 1.0, 0.0, 1.0])[:, None])  # corners too
    sims = jh.simulate_batch(jh.Parameters.from_array(lo + (hi - lo) * u), act, drive)
    assert bool(jnp.all(sims.finite))
    for field in ("M", "Man", "Mirr", "lam", "y", "velocity", "strain"):
        assert bool(jnp.all(jnp.isfinite(getattr(sims, field)))), field


def test_steady_state_loop_closes_and_physics_holds():
    p, act = jh.TABLE1_TRUE, jh.ACTUATOR1
    spp = 200
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, act, periods=2, samples_per_period=spp)
    sim = simulate_unchecked(p, act, drive)
    y = np.asarray(sim.observed("y"))
    first, second = y[:spp + 1], y[spp:]
    assert np.max(np.abs(first - second)) <= 1e-8 * np.max(np.abs(y))
    assert np.all(np.asarray(sim.lam) >= 0)
    # δM rule: the irreversible magnetization never moves against the field
    dMirr = np.diff(np.asarray(sim.Mirr))
    dH = np.diff(np.asarray(sim.H))
    assert np.all(dMirr * np.sign(dH) >= -1e-9 * float(p.Ms))
    # and the loop is a real hysteresis loop: M differs on the up and down branches
    M = np.asarray(sim.observed("M"))
    assert np.ptp(M) > 0.1 * float(p.Ms) * 0.1


def _fundamental(signal, periods):
    spectrum = np.fft.rfft(signal - np.mean(signal))
    return spectrum[periods]


@pytest.mark.parametrize("f", [10.0, 800.0, 1250.0, 2000.0])
def test_frequency_response_matches_simulated_steady_state(f):
    # c = 1: purely reversible magnetization, so λ(t) is exactly periodic (no slow drift of
    # minor loops to leak into the spectrum) and the ratio of fundamentals is exact.
    p, act = jh.TABLE3[1000].replace(c=1.0), jh.ACTUATOR2
    # At 10 Hz the sample rate must sit far above the 1.1 kHz resonance: the kinks of a
    # piecewise-linear drive excite it, and that response aliases back onto bin 1.
    spp, periods = (256, 4) if f > 100 else (2048, 2)
    run_in = 30 if f > 100 else 2  # structural transients die out (ζ ≈ 0.27)
    drive = jh.sinusoidal_field(f, 500.0, act.Hb, periods=periods, samples_per_period=spp,
                                run_in_periods=run_in)
    sim = simulate_unchecked(p, act, drive, substeps=4)
    lam = np.asarray(sim.observed("lam"))[:-1]
    strain = np.asarray(sim.observed("strain"))[:-1]
    # The drive is piecewise linear between samples; the fundamental of that continuous
    # λ(t) is the sampled one times sinc²(π/N) (N samples per period), to O(amplitude²).
    hold = (np.sin(np.pi / spp) / (np.pi / spp)) ** 2
    ratio = _fundamental(strain, periods) / (_fundamental(lam, periods) * hold)
    G = complex(jh.frequency_response(p, act, f))
    assert abs(ratio - G) <= 1e-6 * abs(G), (ratio, G)


@pytest.mark.parametrize(
    "change, fragment",
    [
        (dict(a=0.0), "a ="), (dict(a=-5.0), "a ="), (dict(k=0.0), "k ="),
        (dict(Ms=-1.0), "Ms ="), (dict(c=1.5), "c ="), (dict(c=-0.1), "c ="),
        (dict(Mz=0.0), "Mz ="), (dict(Kz=-1.0), "Kz ="), (dict(E=float("nan")), "E"),
    ],
)
def test_bad_parameters_are_refused(change, fragment):
    _, p, act, drive = CASES[0]
    with pytest.raises(ValueError, match=fragment):
        jh.simulate(p.replace(**change), act, drive)


def test_bad_drives_are_refused():
    t = np.linspace(0, 1e-2, 11)
    H = np.sin(t)
    with pytest.raises(ValueError, match="NaN or inf"):
        jh.Drive(t, np.where(t > 5e-3, np.nan, H))
    with pytest.raises(ValueError, match="strictly increasing"):
        jh.Drive(t[::-1], H)
    with pytest.raises(ValueError, match="mismatched lengths"):
        jh.Drive(t, H[:-1])
    with pytest.raises(ValueError, match="NaN or inf"):
        jh.Drive(np.where(t > 5e-3, np.inf, t), H)
    with pytest.raises(ValueError, match=r"Drive t must be a sequence of numbers"):
        jh.Drive(None, H)
    with pytest.raises(ValueError, match=r"Drive H must be a sequence of numbers"):
        jh.Drive(t, ["a"] * len(t))
    with pytest.raises(ValueError, match="turns-per-metre"):
        jh.Drive.from_current(t, H, jh.ACTUATOR2)
    with pytest.raises(TypeError, match="drive must be"):
        jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, (t, H))
    batch = jh.Parameters.from_array(np.stack([jh.TABLE1_TRUE.to_array()] * 2))
    with pytest.raises(TypeError, match="drive must be"):
        jh.simulate_batch(batch, jh.ACTUATOR1, (t, H))
    with pytest.raises(ValueError, match="substeps"):
        jh.simulate_batch(batch, jh.ACTUATOR1, jh.Drive(t, H), substeps=0)


def test_nonuniform_time_matches_reference():
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.5, 1.5, 300)) * 2.5e-5
    t -= t[0]
    H = 7.4e4 * np.sin(2 * np.pi * 100.0 * t) ** 2
    drive = jh.Drive(t, H)
    assert not drive.uniform
    _, y_ref = reference_simulation(jh.TABLE1_TRUE, jh.ACTUATOR1, drive)
    y = simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, drive).y
    assert _rel_err(y, y_ref) <= 1e-5


@pytest.mark.slow  # the accelerator's path, compiled for the CPU (~30 s cold)
def test_the_branch_free_path_of_an_accelerator_gives_the_same_values():
    """On a GPU the time loop computes both sides of its rare branches and selects
    (interval.on_accelerator); forced on the CPU it gives the same signals and
    derivatives as the branching loop (a drive of a length no other test traces)."""
    import jax

    from jaxhyst.model import interval, timeloop

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=77)
    x = jh.TABLE1_TRUE.to_array()

    def run():
        jax.clear_caches()  # (and the time loops' own traces)
        timeloop.clear_traces()

        def f(x):
            return jh.simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive).y

        conds = str(jax.make_jaxpr(f)(x)).count("cond[")
        return np.asarray(jax.jit(f)(x)), np.asarray(jax.jit(jax.jacfwd(f))(x)), conds

    y, J, conds = run()
    interval.FORCE_BRANCH_FREE = True
    try:
        y_free, J_free, conds_free = run()
    finally:
        interval.FORCE_BRANCH_FREE = None
        run()
    assert conds > 0 and conds_free == 0
    assert np.max(np.abs(y_free - y)) <= 1e-12 * np.max(np.abs(y))
    assert np.max(np.abs(J_free - J)) <= 1e-9 * np.max(np.abs(J))


def test_an_intervals_pieces_as_one_loop_give_the_straight_line_values():
    """A single trajectory's interval, and a batch's in the partials pass
    (interval.compact), trace their pieces as one loop; a batch's values pass as
    straight-line code: the same M and slopes for every substeps count, with the switch
    inside the interval (the extra piece); and the looped trace does not grow with the
    substeps."""
    from jaxhyst.model import interval

    variant, p = jh.EnergyBasedJA(), jh.TABLE1_TRUE
    # moving up from below the anhysteretic after a reversal: δM switches on inside
    H0, H1 = jnp.array([2.0e4, 2.0e4, 3.0e4]), jnp.array([2.6e4, 3.4e4, 3.3e4])
    M0 = jnp.array([1.0e5, 2.5e5, 4.0e5])
    P = jax.tree.map(lambda x: jnp.full(3, x), p)

    def batch(S):  # (a new function each time: traced under the caller's setting)
        return jax.jit(lambda: interval.interval_map_batched(variant, P, H0, H1, M0, S))()

    def loops(S):
        return str(jax.make_jaxpr(lambda m: interval.interval_map_batched(
            variant, P, H0, H1, m, S))(M0)).count("scan[")

    switched = jax.vmap(lambda a, b, m: interval._switch_fraction(
        variant, p, 1.0, a, b, m, variant.evaluate(a, m, 1.0, p)))(H0, H1, M0)
    assert np.all(np.asarray(switched) < 1.0), switched  # (the extra piece is computed)
    for S in (1, 2, 4):
        one = jax.jit(jax.vmap(functools.partial(interval.interval_map, variant, p),
                               in_axes=(0, 0, 0, None)), static_argnums=3)(H0, H1, M0, S)
        straight, straight_loops = batch(S), loops(S)
        with interval.compact():
            looped, looped_loops = batch(S), loops(S)
        # loops: the switch's RK4 stages, then one per piece (S + 1) or one loop of
        # pieces around one of stages
        assert (straight_loops, looped_loops) == (S + 2, 3)
        for case in (one, looped):
            for a, b in zip(jax.tree.leaves(straight), jax.tree.leaves(case), strict=True):
                np.testing.assert_allclose(np.asarray(b), np.asarray(a), rtol=1e-14, atol=0)
