"""The core under JAX transformations (issue 13): drives and actuators as data (no
recompilation), vmap over drives, derivatives through the drive builders and the
geometry, and the custom derivative rule and batch rule checked against the scan."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst.model import magnetization as mag
from jaxhyst.model import timeloop
from jaxhyst.model.simulate import simulate_unchecked

SPP = 50  # coarse drives keep the compilations short


def _drive(f=100.0, amplitude=0.77, offset=1.53, actuator=jh.ACTUATOR1):
    return jh.sinusoidal_current(f, amplitude, offset, actuator, samples_per_period=SPP)


def test_no_recompilation_for_new_values_frequency_jitter_or_actuator():
    traces = []

    @jax.jit
    def y(p, actuator, drive):
        traces.append(1)  # runs only while tracing, i.e. once per compilation
        return simulate_unchecked(p, actuator, drive).y

    base = _drive()
    y(jh.TABLE1_TRUE, jh.ACTUATOR1, base)
    y(jh.TABLE1_TRUE.replace(a=6500.0, k=3000.0), jh.ACTUATOR1, base)  # new parameters
    y(jh.TABLE1_TRUE, jh.ACTUATOR1, _drive(f=137.0, amplitude=0.5))  # new frequency
    jitter = 1e-12 * np.random.default_rng(0).standard_normal(base.n_samples)
    jittered = jh.Drive(np.asarray(base.t) + jitter, base.H, run_in=base.run_in)
    assert jittered.uniform
    y(jh.TABLE1_TRUE, jh.ACTUATOR1, jittered)
    other = jh.Actuator(Ar=9e-5, lr=0.1, n=40000.0, name="other")
    y(jh.TABLE1_TRUE, other, _drive(actuator=other))  # new actuator
    assert len(traces) == 1


def test_the_drive_builders_compile_one_program_and_nothing_for_new_values(caplog):
    """A first sinusoidal drive compiles one program (op by op, each operation would
    compile on its own: ~0.5 s at the first call); a new frequency, amplitude, offset or
    actuator of the same length compiles nothing, and nor does a second coil current."""
    import logging

    spp = 37  # a length no other test builds
    other = jh.Actuator(Ar=9e-5, lr=0.1, n=40000.0, Hb=1000.0, name="other")
    current = np.sin(np.linspace(0.0, 6.0, 53))
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=spp)
        first = [r.getMessage() for r in caplog.records
                 if r.getMessage().startswith("Finished XLA compilation")]
        caplog.clear()
        jh.sinusoidal_current(137.0, 0.5, 1.0, other, samples_per_period=spp)
        jh.sinusoidal_field(20.0, 8e3, -3e3, samples_per_period=spp)
        jh.Drive.from_current(np.arange(53.0), current, jh.ACTUATOR1)
        jh.Drive.from_current(np.arange(53.0), 2 * current, other)
        listed = jh.Drive.from_current(np.arange(53.0), current.tolist(), other)  # a list
        again = [r.getMessage() for r in caplog.records
                 if r.getMessage().startswith("Finished XLA compilation")]
    assert len(first) == 1 and "_sinusoid" in first[0], first
    assert len(again) == 1 and "_field_from_current" in again[0], again
    np.testing.assert_allclose(listed.H, other.n * current + other.Hb, rtol=1e-15)


def test_a_drive_built_inside_jit_from_numpy_times_keeps_its_uniform_sampling():
    """Inside a trace jnp.asarray turns even NumPy times into a tracer; the drive must
    still be recognised as uniform from the times given (not fall back silently to the
    slower exact path), and give the values of the drive built outside."""
    base = _drive()
    t = np.asarray(base.t)
    current = (np.asarray(base.H) - float(jh.ACTUATOR1.Hb)) / float(jh.ACTUATOR1.n)
    seen = []

    @jax.jit
    def y(current):
        drive = jh.Drive.from_current(t, current, jh.ACTUATOR1, run_in=base.run_in)
        seen.append(drive.uniform)
        return simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, drive).y

    inside = y(jnp.asarray(current))
    outside = jh.Drive.from_current(t, current, jh.ACTUATOR1, run_in=base.run_in)
    assert seen == [True] and outside.uniform
    expected = simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, outside).y
    np.testing.assert_allclose(inside, expected, rtol=1e-13,
                               atol=1e-13 * float(jnp.max(jnp.abs(expected))))
    # NumPy times given with a traced field are still checked
    with pytest.raises(ValueError, match="strictly increasing"):
        jax.jit(lambda H: jh.Drive(t[::-1], H).H)(jnp.asarray(base.H))


def test_a_traced_substeps_count_is_refused_with_the_fix():
    with pytest.raises(TypeError, match="static_argnames='substeps'"):
        jax.jit(simulate_unchecked)(jh.TABLE1_TRUE, jh.ACTUATOR1, _drive(), substeps=4)


def test_jaxhyst_first_touched_inside_a_jitted_function_leaks_no_tracer():
    """A fresh process whose first use of jaxhyst's names is inside ``jax.jit``: the
    module constants imported then (TABLE1_TRUE, ACTUATOR1, TABLE1_BOUNDS) are concrete
    and usable afterwards."""
    import subprocess
    import sys
    import textwrap

    script = textwrap.dedent("""
        import jax
        import jax.numpy as jnp
        import jaxhyst as jh

        @jax.jit
        def loss(a):
            p = jh.TABLE1_TRUE.replace(a=a)
            d = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=8)
            return jnp.sum(jh.simulate_unchecked(p, jh.ACTUATOR1, d).y ** 2)

        assert jnp.isfinite(loss(7000.0))
        print(float(jh.TABLE1_TRUE.a), float(jh.ACTUATOR1.Ar),
              float(jh.TABLE1_BOUNDS.upper.a), jh.TABLE1_BOUNDS.contains(jh.TABLE1_TRUE))
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["7012.0", "7.85e-05", "10518.0", "True"]


def test_parameters_from_a_host_array_compile_nothing(caplog):
    import logging

    X = np.stack([np.asarray(jh.TABLE1_TRUE.to_array())] * 3) * np.array([[1.0], [1.1], [0.9]])
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        p = jh.Parameters.from_array(X)
    assert not [r for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
    np.testing.assert_array_equal(np.asarray(p.to_array()), X)
    # a list holding a traced value still goes through JAX
    row = X[0].tolist()
    doubled = jax.jit(lambda a: jh.Parameters.from_array([*row[:2], a, *row[3:]]).a * 2)
    assert float(doubled(7000.0)) == 14000.0


def test_simulate_unchecked_called_directly_runs_compiled(caplog):
    """Outside any transformation simulate_unchecked runs as one compiled program (op by
    op each operation compiled on its own at the first call: 5.4 against 1.9 s), and new
    values compile nothing; under jit it is traced into the caller's program."""
    import logging

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=29)
    p = jh.TABLE1_TRUE.replace(a=6900.0)
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        first = simulate_unchecked(p, jh.ACTUATOR1, drive).y
        compiled = [r.getMessage() for r in caplog.records
                    if r.getMessage().startswith("Finished XLA compilation")]
        caplog.clear()
        simulate_unchecked(p.replace(k=3000.0), jh.ACTUATOR1, drive)
        again = [r for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
    assert len(compiled) == 1 and "_simulate" in compiled[0], compiled
    assert not again
    inside = jax.jit(lambda a: simulate_unchecked(p.replace(a=a), jh.ACTUATOR1, drive).y)(
        p.a)
    np.testing.assert_allclose(first, inside, rtol=1e-13, atol=1e-25)


@pytest.mark.compat
def test_transformations_called_without_jit_run_the_compiled_simulation(caplog):
    """jax.grad / jacfwd / vmap of a function of simulate_unchecked, called directly
    (no jax.jit), send the simulation to its compiled program: a few dozen programs
    compiled at the first call instead of ~100–300 one-operation programs, and the same
    values as under jit (jacfwd; grad and vmap agree with it and with the plain runs)."""
    import logging

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=31)
    x = jh.TABLE1_TRUE.to_array()

    def y(x):
        return simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive).y

    def loss(x):
        return jnp.sum(y(x) ** 2) * 1e12

    batch = jnp.stack([x, x.at[2].multiply(1.1)])
    cases = [(jax.grad(loss), x), (jax.jacfwd(y), x), (jax.vmap(y), batch)]
    eager = []
    for transformed, arg in cases:
        caplog.clear()
        with jax.log_compiles(), caplog.at_level(logging.WARNING):
            eager.append(transformed(arg))
        compiled = [r.getMessage() for r in caplog.records
                    if r.getMessage().startswith("Finished XLA compilation")]
        assert any("_simulate" in m for m in compiled), compiled
        assert len(compiled) < 60, len(compiled)
    grad, jac, batched = eager
    # (one program compiled under jit as the reference: the others are checked against
    # it and against the plain runs, each program a few seconds to compile)
    np.testing.assert_allclose(jac, jax.jit(jax.jacfwd(y))(x), rtol=1e-12, atol=0)
    plain = [y(v) for v in batch]
    np.testing.assert_allclose(batched, jnp.stack(plain), rtol=1e-12, atol=0)
    np.testing.assert_allclose(grad, 2e12 * jac.T @ plain[0], rtol=1e-12,
                               atol=1e-12 * float(jnp.max(jnp.abs(grad))))


def test_jittered_time_stamps_give_the_exact_nonuniform_result():
    base = _drive()
    t = np.asarray(base.t) + 4e-5 * float(base.dt) * np.sin(np.arange(base.n_samples))
    jittered = jh.Drive(t, base.H, run_in=base.run_in)
    exact = jh.Drive(t, base.H, run_in=base.run_in, uniform=False)
    assert jittered.uniform and not exact.uniform
    y1 = simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, jittered).y
    y2 = simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, exact).y
    assert float(jnp.max(jnp.abs(y1 - y2)) / jnp.max(jnp.abs(y2))) < 1e-11


def test_vmap_over_drives_of_different_frequencies_equals_single_runs():
    freqs = jnp.array([10.0, 100.0, 800.0])
    drives = [jh.sinusoidal_field(float(f), 8e3, 16e3, samples_per_period=SPP) for f in freqs]
    stacked = jax.tree.map(lambda *xs: jnp.stack(xs), *drives)
    p, act = jh.TABLE3[800], jh.ACTUATOR2
    batch = jax.jit(jax.vmap(lambda d: simulate_unchecked(p, act, d).y))(stacked)
    for i, d in enumerate(drives):
        np.testing.assert_allclose(batch[i], simulate_unchecked(p, act, d).y, rtol=1e-12,
                                   atol=1e-12 * float(jnp.max(jnp.abs(batch[i]))))
    # the drive builder itself vmaps over a traced frequency
    built = jax.jit(jax.vmap(lambda f: simulate_unchecked(
        p, act, jh.sinusoidal_field(f, 8e3, 16e3, samples_per_period=SPP)).y))(freqs)
    np.testing.assert_allclose(built, batch, rtol=1e-12, atol=1e-20)


def _central(f, x, h):
    return (f(x + h) - f(x - h)) / (2 * h)


#: The drive builder's and the geometry's values: one loss of all five, so that the five
#: cases below share its two compiled programs (the loss and its gradient).
_GEOMETRY = ("amplitude", "offset", "frequency", "Ar", "lr")
_GEOMETRY_BASE = np.array([0.77, 1.53, 100.0, 7.85e-5, 0.085])


def _geometry_loss(v):
    act = jh.Actuator(Ar=v[3], lr=v[4], n=48471.0)
    d = jh.sinusoidal_current(v[2], v[0], v[1], act, samples_per_period=SPP)
    return jnp.sum(simulate_unchecked(jh.TABLE1_TRUE, act, d).strain ** 2) * 1e12


_geometry_loss_jit = jax.jit(_geometry_loss)
_geometry_grad_jit = jax.jit(jax.grad(_geometry_loss))


@pytest.mark.parametrize("name", _GEOMETRY)
def test_grad_through_the_drive_builder_and_the_geometry_matches_differences(name):
    i = _GEOMETRY.index(name)
    e = np.eye(len(_GEOMETRY))[i]
    g = float(_geometry_grad_jit(_GEOMETRY_BASE)[i])

    def f(value):  # (the loss along this one value)
        return _geometry_loss_jit(_GEOMETRY_BASE + (value - _GEOMETRY_BASE[i]) * e)

    x = float(_GEOMETRY_BASE[i])
    h = 1e-4 * abs(x)
    fd = (4 * _central(f, x, h / 2) - _central(f, x, h)) / 3  # Richardson, O(h⁴)
    assert abs(g - float(fd)) <= 1e-6 * abs(float(fd)), (g, float(fd))


def _plain_path(p, H, variant, substeps):
    """The time loop differentiated by plain JAX AD (no custom rule): the reference."""
    form = mag.JAPath(variant)
    out = timeloop.run_path_plain(p, None, H, form=form, substeps=substeps)
    return form.split(out, p, H, substeps)


@pytest.mark.compat
@pytest.mark.parametrize("variant", [
    jh.EnergyBasedJA(),
    pytest.param(jh.ClassicJA(), marks=pytest.mark.slow),
    pytest.param(jh.VenkataramanJA(), marks=pytest.mark.slow),
    pytest.param(jh.PopJA(), marks=pytest.mark.slow),
], ids=["energy", "classic", "venkataraman", "pop"])
def test_custom_rule_equals_plain_ad_of_the_scan_in_every_mode(variant):
    # plain AD of the scan compiles slowly: a short drive with reversals and switches
    drive = jh.sinusoidal_field(100.0, 3e4, 5e3, samples_per_period=16)
    H = drive.H
    p0 = jh.TABLE3[10]

    def params(x):  # Ms with α̃: the rule forms ∂/∂Ms from ∂/∂α̃ where the form allows
        return p0.replace(a=x[0], k=x[1], alpha=x[2], c=x[3], Ms=x[4])

    x = jnp.array([7012.0, 3283.0, -0.01, 0.18, 7.65e5])

    def loss(path, x, H):
        M, k = path(params(x), H, variant, 2)
        return jnp.sum((M / 1e5) ** 2) + jnp.sum(k**2)

    def custom(p, H, v, S):
        return mag.magnetization_path(p, H, variant=v, substeps=S)

    g1 = jax.jit(jax.grad(lambda x, H: loss(custom, x, H), argnums=(0, 1)))(x, H)
    g2 = jax.jit(jax.grad(lambda x, H: loss(_plain_path, x, H), argnums=(0, 1)))(x, H)
    for a, b in zip(g1, g2, strict=True):
        assert float(jnp.max(jnp.abs(a - b)) / jnp.max(jnp.abs(b))) < 1e-11
    J1 = jax.jit(jax.jacfwd(lambda x: custom(params(x), H, variant, 2)[0]))(x)
    J2 = jax.jit(jax.jacfwd(lambda x: _plain_path(params(x), H, variant, 2)[0]))(x)
    # column by column: each parameter's derivative on its own scale
    error = jnp.max(jnp.abs(J1 - J2), axis=(0, 1)) / jnp.max(jnp.abs(J2), axis=(0, 1))
    assert float(jnp.max(error)) < 1e-11, error


@pytest.mark.parametrize("form", [jh.EnergyBasedJA, jh.ClassicJA, jh.VenkataramanJA])
def test_the_Ms_derivative_from_the_scaling_symmetry_equals_its_own_tangent(form):
    class WithoutSymmetry(jh.AbstractJAVariant):  # the same form, claim not made
        inner: jh.AbstractJAVariant

        def slope(self, H, M, delta, p, pinning=True):
            return self.inner.slope(H, M, delta, p, pinning)

        def evaluate(self, H, M, delta, p, pinning=True):
            return self.inner.evaluate(H, M, delta, p, pinning)

        def irreversible_magnetization(self, H, M, p):
            return self.inner.irreversible_magnetization(H, M, p)

    class Own(jh.AbstractAnhystereticForm):  # a user's own form does not make the claim
        def slope_from_anhysteretic(self, M, delta, p, Man, dMan, pinning=True):
            return form().slope_from_anhysteretic(M, delta, p, Man, dMan, pinning)

        def irreversible_magnetization(self, H, M, p):
            return M

    assert form.scales_with_Ms and not jh.PopJA.scales_with_Ms
    assert not Own.scales_with_Ms and not WithoutSymmetry.scales_with_Ms
    drive = jh.sinusoidal_field(100.0, 3e4, 5e3, samples_per_period=24)
    x = jh.TABLE3[10].to_array()

    def jacobian(variant):
        def outputs(x):
            M, k = mag.magnetization_path(jh.Parameters.from_array(x), drive.H,
                                          variant=variant, substeps=2)
            return jnp.concatenate([M.ravel(), k.ravel()])
        return jax.jit(jax.jacfwd(outputs))(x)

    J1, J2 = jacobian(form()), jacobian(WithoutSymmetry(form()))
    i = jh.Parameters.names.index("Ms")
    assert float(jnp.max(jnp.abs(J2[:, i]))) > 0
    assert float(jnp.max(jnp.abs(J1[:, i] - J2[:, i])) / jnp.max(jnp.abs(J2[:, i]))) < 1e-12
    assert float(jnp.max(jnp.abs(J1 - J2)) / jnp.max(jnp.abs(J2))) < 1e-12


@pytest.mark.compat
def test_second_derivatives_match_differences_of_the_gradient():
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=20)
    p0 = jh.TABLE1_TRUE

    def loss(z):  # log a, log k, c
        p = p0.replace(a=jnp.exp(z[0]), k=jnp.exp(z[1]), c=z[2])
        return jnp.sum(simulate_unchecked(p, jh.ACTUATOR1, drive).y ** 2) * 1e12

    z = jnp.array([np.log(7012.0), np.log(3283.0), 0.18])
    Hs = jax.jit(jax.hessian(loss))(z)
    g = jax.jit(jax.grad(loss))
    h = 1e-4
    rows = []
    for i in range(3):
        def along(s, i=i):
            return g(z.at[i].add(s))

        rows.append((4 * _central(along, 0.0, h / 2) - _central(along, 0.0, h)) / 3)
    fd = np.stack(rows)
    np.testing.assert_allclose(Hs, fd, rtol=0, atol=1e-6 * float(jnp.max(jnp.abs(Hs))))


def test_vmapped_time_loop_equals_single_runs():
    # members differ in where their δM switches fall: the inner piece loop runs while any
    # member needs it, each member's own pieces only
    drive = _drive()
    lo, hi = jh.TABLE1_BOUNDS.lower.to_array(), jh.TABLE1_BOUNDS.upper.to_array()
    X = lo + (hi - lo) * jax.random.uniform(jax.random.PRNGKey(3), (6, 10))

    def path(x):
        return mag.magnetization_path(jh.Parameters.from_array(x), drive.H,
                                      variant=jh.EnergyBasedJA(), substeps=2)

    batch = jax.jit(jax.vmap(path))(X)
    single = jax.jit(path)
    for i in range(6):
        for a, b in zip(batch, single(X[i]), strict=True):
            np.testing.assert_allclose(a[i], b, rtol=1e-13, atol=1e-9)


def test_nested_vmaps_run_one_loop_on_the_product_batch_with_the_same_values():
    # starts × loops of a joint fit: the outer vmap merges into the inner batch (one
    # batch-native loop on 2·3 members) instead of batching the batched loop generically
    drive = _drive()
    lo, hi = jh.TABLE1_BOUNDS.lower.to_array(), jh.TABLE1_BOUNDS.upper.to_array()
    X = lo + (hi - lo) * jax.random.uniform(jax.random.PRNGKey(5), (2, 3, 10))

    def path(x):
        return mag.magnetization_path(jh.Parameters.from_array(x), drive.H,
                                      variant=jh.ClassicJA(), substeps=2)[0]

    nested = jax.vmap(jax.vmap(path))
    text = str(jax.make_jaxpr(nested)(X))
    n = drive.H.shape[-1] - 1
    assert f"f64[6,{n}" in text or f"f64[{n},6" in text  # the product batch
    out = jax.jit(nested)(X)
    single = jax.jit(path)
    for i in range(2):
        for j in range(3):
            np.testing.assert_allclose(out[i, j], single(X[i, j]), rtol=1e-13, atol=1e-9)
    # derivatives through both vmaps: each member's own
    g = jax.jit(jax.vmap(jax.vmap(jax.grad(lambda x: jnp.sum(path(x) ** 2) * 1e-12))))(X)
    g1 = jax.jit(jax.grad(lambda x: jnp.sum(path(x) ** 2) * 1e-12))
    for i in range(2):
        np.testing.assert_allclose(g[i, 1], g1(X[i, 1]), rtol=1e-10,
                                   atol=1e-12 * float(jnp.max(jnp.abs(g))))


def test_a_batch_of_one_runs_the_unbatched_loops_with_the_same_values():
    # vmap over a single member (one start of a local solve) takes the unbatched programs
    drive = _drive()
    x = jh.TABLE1_TRUE.to_array()

    def y(x):
        return simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive).y

    np.testing.assert_allclose(jax.jit(jax.vmap(y))(x[None])[0], jax.jit(y)(x),
                               rtol=1e-14, atol=1e-20)
    J1 = jax.jit(jax.vmap(jax.jacfwd(y)))(x[None])[0]
    J = jax.jit(jax.jacfwd(y))(x)
    np.testing.assert_allclose(J1, J, rtol=0, atol=1e-13 * float(jnp.max(jnp.abs(J))))


@pytest.mark.slow  # a 4096-population vmap; blocks are checked small in test_model
def test_a_large_vmap_runs_after_the_loop_in_blocks_with_the_same_values():
    # P = 260 members (≥ 4 blocks of 64): a plain jax.vmap runs the work after the time
    # loop block by block; the values, and derivatives through the vmap, are those of the
    # same members in batches too small to be split (130 each)
    drive = _drive()
    lo, hi = jh.TABLE1_BOUNDS.lower.to_array(), jh.TABLE1_BOUNDS.upper.to_array()
    X = lo + (hi - lo) * jax.random.uniform(jax.random.PRNGKey(5), (260, 10))

    def y(x):
        return simulate_unchecked(jh.Parameters.from_array(x), jh.ACTUATOR1, drive).y

    batched = jax.jit(jax.vmap(y))
    assert "length=5" in str(jax.make_jaxpr(jax.vmap(y))(X))  # a map over 5 blocks
    whole = batched(X)
    halves = jnp.concatenate([batched(X[:130]), batched(X[130:])])
    np.testing.assert_allclose(whole, halves, rtol=1e-13, atol=1e-13 * float(
        jnp.max(jnp.abs(halves))))

    def total(X):
        return jnp.sum(jax.vmap(y)(X) ** 2) * 1e12

    g = jax.jit(jax.grad(total))
    np.testing.assert_allclose(g(X), jnp.concatenate([g(X[:130]), g(X[130:])]),
                               rtol=1e-10, atol=0)


def test_batched_parameters_given_to_simulate_are_refused_with_the_fix():
    batch = jh.Parameters.from_array(jnp.stack([jh.TABLE1_TRUE.to_array()] * 3))
    with pytest.raises(ValueError, match="simulate_batch"):
        jh.simulate(batch, jh.ACTUATOR1, _drive())


@pytest.mark.filterwarnings("ignore::jaxhyst.identify.SamplingWarning")
def test_a_local_solve_traces_each_time_loop_once(monkeypatch):
    # the loops take seconds to trace: the forward loop (data, final evaluation) and the
    # partials pass (linearized in the solver's init and again in its step, under vmap)
    # are each traced once; a drive length no other test uses keeps the count fresh. (The
    # sampling check of a coarse drive runs the loop at twice the substeps: another loop.)
    # (Without the traces kept on disk, which would skip tracing the solve's programs.)
    monkeypatch.setenv("JAXHYST_TRACE_CACHE", "off")
    calls = []
    for name, at in (("_loop", 4), ("_sensitivity_loop", 4)):
        original = getattr(timeloop, name)

        def counted(*args, _original=original, _name=name, _at=at, **kwargs):
            if args[_at] == 2:  # the problem's substeps
                calls.append(_name)
            return _original(*args, **kwargs)

        monkeypatch.setattr(timeloop, name, counted)
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=37)
    problem = jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS,
                                   fixed=["Ms", "lambda_s", "alpha", "E", "Kz", "Mz", "Cz"])
    jh.solve(problem, np.full(3, 0.5), solver="lm", max_steps=3, report=False)
    assert sorted(calls) == ["_loop", "_sensitivity_loop"]
