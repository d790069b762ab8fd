"""Numbers a user changes between calls are data, not structure (issue 45): after the
first call, a new current limit, frequency, tolerance or loss value compiles nothing in
`compensate`, `simulate`, `simulate_flux` and a joint fit. Counted as JAX reports
compilations (``jax.log_compiles``: one "Compiling …" line per program it lowers and
compiles, from the persistent cache or not)."""

from __future__ import annotations

import contextlib
import logging
import threading

import jax
import numpy as np
import pytest
from helpers import exponential_problem

import jaxhyst as jh
from jaxhyst.control import sinusoidal_reference
from jaxhyst.params import MU0


class _Compiles(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.names: list[str] = []
        self.threads: dict[str, set] = {}  # program → the threads that compiled it

    def emit(self, record):
        message = record.getMessage()
        if message.startswith("Compiling"):
            self.names.append(message[:100])
            program = message.split()[1]
            self.threads.setdefault(program, set()).add(threading.current_thread().name)


@contextlib.contextmanager
def counting():
    """The programs JAX compiles inside the block (their log lines)."""
    handler = _Compiles()
    log = logging.getLogger("jax")
    level = log.level
    log.addHandler(handler)
    log.setLevel(logging.DEBUG)
    try:
        with jax.log_compiles():
            yield handler
    finally:
        log.removeHandler(handler)
        log.setLevel(level)


def test_the_counter_counts():
    with counting() as compiled:
        jax.jit(lambda x: x * 3.0 + 1.0)(np.arange(3.0))
    assert len(compiled.names) == 1


MODEL = jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1)


def test_compensate_compiles_nothing_for_a_new_limit_frequency_tolerance_or_step_count():
    """… (a step count below the refinement's chunk is data too: its program runs at most
    `CHUNK` steps) and its first call compiles the refinement's program in a background thread
    while the model's compile, and the inverse path's and the settling check's while the
    reach is swept (each once: not again in the caller's), leaving no thread."""
    ref = sinusoidal_reference(100.0, 20e-6, 45e-6, samples_per_period=98)  # (its own shape)
    with counting() as first:
        jh.compensate(MODEL, ref, current_limit=2.5, max_steps=3)
    for program in ("least_squares", "_field", "_period_starts"):
        assert first.threads.get(f"jit({program})") == {"jaxhyst-compile-meanwhile"}, \
            first.threads
        assert sum(n.startswith(f"Compiling jit({program}) ") for n in first.names) == 1
    assert not [t for t in threading.enumerate() if t.name == "jaxhyst-compile-meanwhile"]
    other = sinusoidal_reference(140.0, 15e-6, 40e-6, samples_per_period=98)
    with counting() as compiled:
        jh.compensate(MODEL, ref, current_limit=2.2, max_steps=3)
        jh.compensate(MODEL, other, current_limit=(-0.5, 2.6), max_steps=3, tolerance=1e-4)
        capped = jh.compensate(MODEL, ref, current_limit=2.5, max_steps=2, tolerance=0.0)
    assert compiled.names == []
    assert capped.steps == 2 and capped.outcome == "max_steps_reached", capped.to_dict()


def test_simulate_and_simulate_flux_compile_nothing_for_a_new_frequency_or_loss_value():
    losses = jh.Losses(eddy=0.05, excess=0.5)
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=64)
    flux = jh.sinusoidal_flux(1000.0, 0.3, samples_per_period=64)
    jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive, losses=losses)
    jh.simulate_flux(jh.TABLE1_TRUE, flux, losses=losses)
    jh.simulate_flux(jh.TABLE1_TRUE, flux, losses=jh.Losses(relax=1e-4))  # (its own path)
    with counting() as compiled:
        drive2 = jh.sinusoidal_current(250.0, 0.5, 1.2, jh.ACTUATOR1, samples_per_period=64)
        jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive2,
                    losses=jh.Losses(0.02, 0.9, 1e-5, relax=2e-4))
        flux2 = jh.sinusoidal_flux(400.0, 0.25, samples_per_period=64)
        jh.simulate_flux(jh.TABLE1_TRUE, flux2, losses=jh.Losses(0.1, 0.2, 2e-5))
        jh.simulate_flux(jh.TABLE1_TRUE, flux2, losses=jh.Losses(0.1, relax=3e-4))
    assert compiled.names == []


def test_a_simulations_accuracy_check_compiles_beside_it():
    """`simulate` and `simulate_flux` decide their accuracy check's simulations from the
    drive alone, so the first (twice the substeps) compiles in a background thread while
    the simulation's own program compiles, the second (with losses: the drive at half
    the sample step) in the caller's thread after it — each program once, no thread left
    behind, the same signals and the same warning as the check gives."""
    from jaxhyst.model.accuracy import SamplingWarning

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=27)
    with counting() as compiled, pytest.warns(SamplingWarning, match="2 RK4 substeps"):
        sim = jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive)  # (shapes of their own)
    assert sum(n.startswith("Compiling jit(_simulate) ") for n in compiled.names) == 2
    assert compiled.threads["jit(_simulate)"] == {"MainThread", "jaxhyst-compile-meanwhile"}
    np.testing.assert_array_equal(
        sim.y, jh.simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, drive).y)
    flux = jh.sinusoidal_flux(400.0, 0.3, samples_per_period=23)
    losses = jh.Losses(eddy=0.05, excess=0.5)
    with counting() as compiled, pytest.warns(SamplingWarning, match="B-driven"):
        jh.simulate_flux(SOFT, flux, losses=losses)
    names = [n for n in compiled.names if n.startswith("Compiling jit(_simulate_flux) ")]
    assert len(names) == 3, compiled.names
    assert compiled.threads["jit(_simulate_flux)"] == {
        "MainThread", "jaxhyst-compile-meanwhile"}
    assert not [t for t in threading.enumerate() if t.name == "jaxhyst-compile-meanwhile"]


SOFT = jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=30.0, k=20.0, alpha=1e-5, c=0.3, E=1.0,
                     Kz=1.0, Mz=1.0, Cz=0.0)
FIXED = {"Ms": 3.5e5, "alpha": 1e-5, "lambda_s": 0.0, "E": 1.0, "Kz": 1.0, "Mz": 1.0,
         "Cz": 0.0}


def _fit(frequency, amplitude, box, loss_box, sigma=None):
    """A joint fit of three B(H) loops of the rate-dependent classic form at
    ``frequency`` (Hz) and three amplitudes around ``amplitude`` (A/m), the loops' noise
    level ``sigma`` (T) declared or (None) estimated. (The loops are made without
    `simulate`'s accuracy check: it would compile two more programs.)"""
    from jaxhyst.identify.joint import NO_ACTUATOR

    drives, data = [], []
    for scale in (0.6, 1.0, 1.6):
        d = jh.sinusoidal_field(frequency, scale * amplitude, 0.0, samples_per_period=48)
        sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, d, jh.ClassicJA(),
                                    losses=jh.Losses(0.05, 0.5))
        drives.append(d)
        data.append(np.asarray(d.observed(MU0 * (sim.H + sim.M))))
    space = jh.ParameterSpace.for_model(box, fixed=FIXED, losses=loss_box, n_loops=3)
    problem = jh.JointProblem(data, drives, NO_ACTUATOR, space, output="flux_density",
                              variant=jh.ClassicJA(), sigma=sigma)
    start = space.u_from_params((SOFT.replace(a=40.0, k=15.0, c=0.4), jh.Losses(0.08, 0.3)))
    return jh.solve(problem, start, max_steps=4)


@pytest.mark.filterwarnings("ignore::jaxhyst.identify.SamplingWarning")
def test_a_joint_fit_compiles_nothing_for_new_data_a_new_frequency_box_or_noise_level():
    box = jh.Bounds(SOFT.replace(a=10.0, k=5.0, c=0.05), SOFT.replace(a=100.0, k=60.0, c=0.9))
    _fit(300.0, 200.0, box, {"eddy": (0.0, 0.2), "excess": (0.0, 2.0)}, sigma=1e-3)
    wider = jh.Bounds(SOFT.replace(a=5.0, k=2.0, c=0.0), SOFT.replace(a=150.0, k=90.0, c=1.0))
    with counting() as compiled:
        _fit(500.0, 150.0, wider, {"eddy": (0.0, 0.4), "excess": (0.0, 1.0)},
             sigma=[2e-3, 3e-3, 2e-3])
    assert compiled.names == []


@pytest.mark.filterwarnings("ignore::jaxhyst.identify.SamplingWarning")
def test_loops_of_other_lengths_padded_alike_share_a_program_and_cost_what_they_did():
    """A joint problem's observed samples are data (`JointProblem.valid`): two problems
    over loops of other lengths, padded to one shape (``pad_to``, as a leave-one-out
    pads its folds), evaluate by one compiled program — and the padding changes no
    number: the cost is the two loops' single-loop costs summed (each normalised by its
    own observed samples), and every statistic counts the observed samples only."""
    import equinox as eqx

    from jaxhyst.identify.joint import NO_ACTUATOR

    box = jh.Bounds(SOFT.replace(a=10.0, k=5.0, c=0.05), SOFT.replace(a=100.0, k=60.0, c=0.9))
    fixed = {n: v for n, v in FIXED.items() if n != "Ms"}

    def loops(samples):
        out = []
        for n, amplitude in zip(samples, (60.0, 150.0), strict=True):
            d = jh.sinusoidal_field(1.0, amplitude, 0.0, samples_per_period=n)
            sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, d, jh.ClassicJA(), substeps=2)
            out.append((d, np.asarray(d.observed(MU0 * (sim.H + sim.M)))))
        return out

    first, second = loops((30, 40)), loops((36, 44))
    every = [d for d, _ in first + second]
    pad_to = (max(d.run_in for d in every), max(d.n_observed for d in every))

    def joint(pairs, pad=None):
        return jh.JointProblem([y for _, y in pairs], [d for d, _ in pairs], NO_ACTUATOR,
                               jh.ParameterSpace.for_loops(box, 2, fixed=fixed),
                               output="flux_density", variant=jh.ClassicJA(), substeps=2,
                               pad_to=pad)

    cost = eqx.filter_jit(lambda problem, z: problem.cost(z))
    a, b = joint(first, pad_to), joint(second, pad_to)
    z = np.full(a.space.n_free, 0.3)
    value = float(cost(a, z))
    with counting() as compiled:
        cost(b, z)
    assert compiled.names == []
    # the padding changes no number: against each loop as a single-loop problem
    singles = [jh.Problem(y, d, NO_ACTUATOR, jh.ParameterSpace(box, fixed), substeps=2,
                          output="flux_density", variant=jh.ClassicJA()) for d, y in first]
    assert value == pytest.approx(sum(float(p.cost(z)) for p in singles), rel=1e-12)
    assert value == pytest.approx(float(joint(first).cost(z)), rel=1e-12)
    assert a.n_observed == sum(d.n_observed for d, _ in first) < a.n_residuals
    assert [int(g.count) for g in a.groups] == [d.n_observed for d, _ in first]
    with pytest.raises(ValueError, match=r"pad_to=\(12, -3\): give \(run-in, observed"):
        joint(first, (12, -3))


def test_a_fits_report_compiles_in_a_thread_of_its_own_while_the_fit_runs():
    """`jaxhyst.solve` & co. compile the report's programs (the model's error at the
    data's sampling) in a background thread while the fit compiles and runs: they are
    compiled there, counted by ``jax.log_compiles`` like the caller's, not compiled again
    for the report, no thread is left behind, the report is the one made afterwards in
    the caller's thread. The report's Jacobian is the Levenberg–Marquardt solver's last
    one: no program differentiates the model for it (a minimiser's fit compiles that in
    the thread). A second fit of the same structure starts no thread."""
    from jaxhyst.identify.joint import NO_ACTUATOR

    d = jh.sinusoidal_field(1.0, 90.0, 0.0, samples_per_period=38)  # (a shape of its own)
    sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, d, jh.ClassicJA(), substeps=2)
    box = jh.Bounds(SOFT.replace(a=10.0, k=5.0, c=0.05), SOFT.replace(a=100.0, k=60.0, c=0.9))
    problem = jh.Problem(np.asarray(d.observed(MU0 * (sim.H + sim.M))), d, NO_ACTUATOR,
                         jh.ParameterSpace(box, FIXED), output="flux_density",
                         variant=jh.ClassicJA(), substeps=2)
    start = SOFT.replace(a=40.0, k=15.0, c=0.4)
    with counting() as compiled:
        res = jh.solve(problem, start, max_steps=30, report="profile")
    assert "jit(whitened_log_jacobian)" not in compiled.threads, compiled.threads
    assert compiled.threads.get("jit(_predictions)") == {"jaxhyst-compile-meanwhile"}, \
        compiled.threads
    assert not [t for t in threading.enumerate() if t.name == "jaxhyst-compile-meanwhile"]
    again = jh.fit.attach_report(res, problem, "profile").report
    assert again.intervals == res.report.intervals and again.names == res.report.names
    # the same report as from the model differentiated again
    fresh = jh.analysis.identifiability(problem, res.params)
    for name in fresh.names:
        assert res.report.std_errors[name] == pytest.approx(fresh.std_errors[name], rel=1e-9)
        assert res.report.intervals[name] == pytest.approx(fresh.intervals[name], rel=1e-9)
    # which fits leave their solver's Jacobian (a minimiser's does not: the report's own
    # is compiled in that thread instead)
    assert jh.fit._linearized((start,), {}) and jh.fit._linearized((start, "dogleg"), {})
    assert not jh.fit._linearized((start,), {"solver": "bfgs"})
    # once per problem structure: a second fit of these data starts no thread
    assert jh.fit._compile_report_meanwhile(problem, True, linearized=True) is None


def _loop_problem(samples_per_period, noise):
    from jaxhyst.identify.joint import NO_ACTUATOR

    d = jh.sinusoidal_field(1.0, 90.0, 0.0, samples_per_period=samples_per_period)
    sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, d, jh.ClassicJA(), substeps=2)
    B = np.asarray(d.observed(MU0 * (sim.H + sim.M)))
    B = B + noise * np.max(np.abs(B)) * np.random.default_rng(3).standard_normal(B.shape)
    box = jh.Bounds(SOFT.replace(a=10.0, k=5.0, c=0.05), SOFT.replace(a=100.0, k=60.0, c=0.9))
    return jh.Problem(B, d, NO_ACTUATOR, jh.ParameterSpace(box, FIXED),
                      output="flux_density", variant=jh.ClassicJA(), substeps=2)


def _refits_compile_meanwhile_once(problem, starts):
    """A profile-checked multi-start fit of ``problem`` compiles its re-fit program in
    the background thread, once, and its report is the one computed afterwards."""
    from jaxhyst.analysis import identifiability

    with counting() as compiled:
        res = jh.multistart(problem, starts, max_steps=60, report="profile")
    assert compiled.threads.get("jit(_held_costs)") == {"jaxhyst-compile-meanwhile"}, \
        compiled.threads
    assert sum(n.startswith("Compiling jit(_held_costs) ") for n in compiled.names) == 1
    assert not [t for t in threading.enumerate() if t.name == "jaxhyst-compile-meanwhile"]
    # (equal to rounding: the solver's Jacobian is a batch's partials pass, the fresh
    # one a single trajectory's — the same arithmetic compiled as two programs)
    fresh = identifiability(problem, res.params).intervals
    assert res.report.intervals.keys() == fresh.keys()
    for name, bounds in fresh.items():
        assert res.report.intervals[name] == pytest.approx(bounds, rel=1e-12, abs=0)


@pytest.mark.extended  # (four multi-start fits with profile-checked reports)
def test_the_profile_refits_compile_meanwhile_once_the_fits_cost_has_settled_inexactly():
    """A multi-start fit with the profile-checked report compiles the check's re-fit
    program in the background thread once its best cost has settled above an exact
    fit's — once, not again for the report, which is the one the caller's thread makes
    afterwards; a noise-free fit (exact: its report re-fits nothing) compiles no re-fit
    program at all."""

    near, far = SOFT.replace(a=31.0, k=19.0, c=0.31), SOFT.replace(a=90.0, k=55.0, c=0.8)
    starts = jh.Parameters.from_array(np.stack([near.to_array(), far.to_array()]))
    exact = _loop_problem(41, 0.0)  # (shapes of their own)
    with counting() as compiled:
        res = jh.multistart(exact, starts, max_steps=60, report="profile")
    assert res.cost < jh.fit.NOT_EXACT and res.report is not None
    assert "jit(_held_costs)" not in compiled.threads, compiled.threads
    problem = _loop_problem(41, 1e-3)  # (the same shapes, noisy data)
    first = jh.multistart(problem, starts, max_steps=60, report=False)
    # from its optimum (settled at once) and from afar (a batch that goes on)
    starts = jh.Parameters.from_array(np.stack([first.params.to_array(), far.to_array()]))
    _refits_compile_meanwhile_once(problem, starts)


def test_a_reports_profile_refits_compile_beside_its_jacobian():
    """What ``jaxhyst report`` does for a fit that is not exact: the profile check's
    re-fit program compiles in the background thread (`fit.refits_meanwhile`, started at
    the report's first large lowering) while the report's Jacobian compiles, and the
    check waits for it (`_background.awaited`): compiled once, there; the same report."""
    from jaxhyst._background import awaited
    from jaxhyst.analysis import identifiability
    from jaxhyst.analysis.profile_intervals import REFITS

    problem, _ = exponential_problem(0.7)  # (a residual function of its own: new programs)
    fit = jh.solve(problem, {"b": 0.4, "m": 0.1}, solver="lm", report=False)
    with counting() as compiled:
        with awaited(REFITS, jh.fit.refits_meanwhile(problem, fit.cost, lowerings=1)):
            report = identifiability(problem, fit.params)
    assert compiled.threads.get("jit(_held_costs)") == {"jaxhyst-compile-meanwhile"}, \
        compiled.threads
    assert sum(n.startswith("Compiling jit(_held_costs) ") for n in compiled.names) == 1
    assert not [t for t in threading.enumerate() if t.name == "jaxhyst-compile-meanwhile"]
    assert report.intervals == identifiability(problem, fit.params).intervals


def test_the_profile_checks_refits_take_their_tolerance_as_a_value(monkeypatch):
    """The profile check's re-fits stop at rtol = `profile_intervals.PRECISION` over the
    fit's χ² (at most ``RE_FIT_TOLERANCES[0]``), a value passed to their program: a second
    check of the same problem with a far tighter rtol compiles no re-fit program."""
    from jaxhyst.analysis import identifiability, profile_intervals

    problem, _ = exponential_problem(0.5)
    fit = jh.solve(problem, {"b": 0.4, "m": 0.1}, solver="lm", report=False)
    chi2 = float(fit.cost)  # (σ declared: the cost is the χ²)
    rtols, make = [], profile_intervals.make_solver

    def recorded(solver, rtol, atol):
        rtols.append(float(rtol))
        return make(solver, rtol, atol)

    monkeypatch.setattr(profile_intervals, "make_solver", recorded)
    first = identifiability(problem, fit.params)
    monkeypatch.setattr(profile_intervals, "PRECISION", profile_intervals.PRECISION * 1e-4)
    with counting() as compiled:
        second = identifiability(problem, fit.params)
    loosest = profile_intervals.RE_FIT_TOLERANCES[0]
    assert rtols == pytest.approx([min(loosest, 0.01 / max(chi2, 1.0)),
                                   min(loosest, 1e-6 / max(chi2, 1.0))], rel=1e-9)
    assert rtols[1] < 0.1 * rtols[0]
    assert not [n for n in compiled.names if "_held_costs" in n], compiled.names
    assert first.interval_methods == second.interval_methods
    for name, (lo, hi) in first.intervals.items():
        assert second.intervals[name] == pytest.approx((lo, hi), rel=1e-6), name


def test_replicate_fits_and_profiles_take_their_step_limit_as_a_value():
    """`fit_replicates` and `profile_likelihood` pass ``max_steps`` to their program as a
    value: a new step limit compiles no fit program, and the limit still binds."""
    from jaxhyst.analysis import fit_replicates, profile_likelihood

    problem, y = exponential_problem(0.5)
    fit = jh.solve(problem, {"b": 0.4, "m": 0.1}, solver="lm", report=False)
    data = {"y": y + 0.5 * np.random.default_rng(2).standard_normal((3, y.size))}
    first = fit_replicates(problem, data, fit.params, max_steps=20, batch_size=3)
    with counting() as compiled:
        one = fit_replicates(problem, data, fit.params, max_steps=1, batch_size=3)
        prof = profile_likelihood(problem, fit.params, "b", n=3, max_steps=40, batch_size=3)
    assert not [n for n in compiled.names if "_fit_batch" in n], compiled.names
    assert np.all(one["steps"] <= 1) and np.all(first["steps"] > 1), (one["steps"],
                                                                     first["steps"])
    assert np.all(np.isfinite(prof.cost)) and prof.delta_chi2.min() < 1e-6


def test_a_fit_of_noisy_data_compiles_its_refits_once_its_step_is_lowered():
    """Data with noise (`fit._noisy`: the 4th differences' robust scale above 1e-4 of the
    range) are never fitted exactly, so a profile-checked fit starts compiling its
    re-fit program as soon as its own step is lowered (the caller's second large
    lowering: `meanwhile(…, lowerings=2)`), beside the step's compile, instead of once
    its cost has settled. A noise-free model loop (60 or 200 samples a period) is not
    noisy; a series under 64 samples is not judged."""
    from jaxhyst import _background

    assert jh.fit._noisy(_loop_problem(200, 1e-3))
    assert not jh.fit._noisy(_loop_problem(200, 0.0))
    assert not jh.fit._noisy(_loop_problem(60, 0.0))
    assert not jh.fit._noisy(_loop_problem(41, 1e-2))
    started = threading.Event()
    job = _background.meanwhile(started.set, lowerings=2)
    for _ in range(2):
        assert not started.wait(0.2)
        _background._on_lowered("/jax/core/compile/jaxpr_to_mlir_module_duration", 1.0)
    assert started.wait(10.0)
    job.join()
    # work not started is dropped, not run, by a caller that leaves (an error, or a
    # report that needed no re-fits): a fit that fails at its input waits for no compile
    ran = threading.Event()
    job = _background.meanwhile(ran.set, lowerings=2)
    job.drop()
    assert not ran.is_set() and not job.thread.is_alive()
    with counting() as compiled:
        with pytest.raises(ValueError):
            jh.multistart(_loop_problem(200, 1e-3), np.full((2, 7), 0.5), report="profile")
    assert "jaxhyst-compile-meanwhile" not in set().union(*compiled.threads.values()), \
        compiled.threads


@pytest.mark.extended  # (a multi-start fit with its profile-checked report)
def test_a_profile_checked_fit_of_noisy_data_compiles_its_refits_beside_its_step():
    """End to end: the re-fit program of a noisy loop's profile-checked fit compiles in
    the background thread, once, and the report is the one computed afterwards."""

    problem = _loop_problem(200, 1e-3)
    starts = jh.Parameters.from_array(np.stack([SOFT.replace(a=31.0, k=19.0, c=0.31)
                                                .to_array()] * 2))
    _refits_compile_meanwhile_once(problem, starts)
