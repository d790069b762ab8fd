"""Hysteresis compensation (issue 32): the model run backwards, periodic steady states,
inputs inside their limits by construction, compensation on the model, iterative
learning on a plant that differs from the model, unreachable references, bad input."""

from __future__ import annotations

import dataclasses
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import reference_simulation

import jaxhyst as jh
from jaxhyst.control import (
    InputLimits,
    InputMap,
    IterativeLearning,
    SimulatedPlant,
    UnreachableWarning,
    compensate,
    multitone_reference,
    reference_from_record,
    sinusoidal_reference,
)
from jaxhyst.control.compensate import rms_error
from jaxhyst.control.learning import DelayError
from jaxhyst.control.tracking import Tracking, evaluate, settling_periods
from jaxhyst.identify.joint import NO_ACTUATOR
from jaxhyst.model.inverse import field_for_magnetization

MODEL = jh.Model(jh.TABLE3[10], jh.ACTUATOR2)  # Actuator2, driven by its AC field (A/m)
LIMIT = 12e3  # A/m of AC field (the paper drives it with 8 kA/m)
SINE = sinusoidal_reference(100.0, 15e-6, 37e-6)
THREE_TONES = multitone_reference(100.0, [10e-6, 3e-6, 2e-6], 37e-6, phases=[0.0, 0.5, 1.0])


def _periodic_drive(H_period, f, run_in_periods, periodic):
    N = H_period.shape[0]
    n_ramp = N // 4
    H = jnp.concatenate([H_period[0] * jnp.arange(n_ramp) / n_ramp,
                         jnp.tile(H_period, run_in_periods + 1), H_period[:1]])
    t = (np.arange(H.shape[0]) - n_ramp - run_in_periods * N) / (f * N)
    return jh.Drive(t, H, run_in=n_ramp + run_in_periods * N, periodic=periodic)


def test_a_periodic_drive_gives_the_structure_its_steady_state():
    """At 2 kHz the structure (1.1 kHz resonance) still rings after 5 periods; with
    Drive(periodic=True) 5 run-in periods give what 60 periods from rest give, and its
    derivative matches central differences."""
    f, N = 2000.0, 200
    t = np.arange(N) / (f * N)
    H = 16e3 + 6e3 * np.sin(2 * np.pi * f * t) + 2e3 * np.sin(6 * np.pi * f * t + 0.5)
    p = jh.TABLE3[10]
    # (simulate's compiled program without its sampling check, which would simulate each
    # drive again at twice the substeps: the values here are the programs')
    settled, short, steady = (
        jh.simulate_unchecked(p, jh.ACTUATOR2, _periodic_drive(H, f, periods, periodic))
        .observed("y") for periods, periodic in ((60, False), (5, False), (5, True)))
    scale = float(np.ptp(settled))
    assert float(np.max(np.abs(short - settled))) > 1e-3 * scale  # (the transient is real)
    assert float(np.max(np.abs(steady - settled))) < 1e-8 * scale

    def loss(Hp):
        drive = _periodic_drive(Hp, f, 5, True)
        return jnp.sum(jh.simulate_unchecked(p, jh.ACTUATOR2, drive).observed("y") ** 2)

    direction = np.random.default_rng(0).standard_normal(N)
    g = jax.grad(loss)(jnp.asarray(H))
    h = 1e-2
    fd = (loss(jnp.asarray(H + h * direction)) - loss(jnp.asarray(H - h * direction))) / (2 * h)
    assert float(g @ direction) == pytest.approx(float(fd), rel=1e-6)


def test_the_inverse_jiles_atherton_path_recovers_the_field():
    """M(t) from the independent DOP853 solution of the forward model (a biased loop with
    minor loops), run backwards by the M-driven form, gives back H(t)."""
    t = np.arange(401) / 40e3
    H = np.concatenate([np.linspace(0, 16e3, 41)[:-1],
                        16e3 + 7e3 * np.sin(2 * np.pi * 100 * t[:361])
                        + 1.5e3 * np.sin(2 * np.pi * 700 * t[:361])])
    drive = jh.Drive(t, H)
    M, _ = reference_simulation(jh.TABLE3[10], jh.ACTUATOR2, drive)
    H_back = np.asarray(field_for_magnetization(jh.TABLE3[10], jnp.asarray(M), substeps=4))
    assert float(np.max(np.abs(H_back - H))) < 1e-5 * float(np.ptp(H))


@pytest.mark.parametrize("periodic", [True, False])
def test_every_input_of_the_map_is_inside_its_limits(periodic):
    limits = InputLimits.of((-2.0, 3.0), slew=400.0)
    imap = InputMap(limits, 64, 1e-3, periodic)
    z = 30.0 * np.random.default_rng(1).standard_normal((50, imap.size))
    u = np.asarray(jax.vmap(imap.input)(jnp.asarray(z)))
    assert np.all(u >= -2.0) and np.all(u <= 3.0)
    closed = np.concatenate([u, u[:, :1]], axis=1) if periodic else u
    assert np.max(np.abs(np.diff(closed, axis=1))) <= 400.0 * 1e-3 * (1 + 1e-12)
    feasible = 0.5 + 1.5 * np.sin(2 * np.pi * np.arange(64) / 64)  # slew 0.15 per sample
    back = np.asarray(imap.input(jnp.asarray(imap.coordinates(feasible))))
    assert np.max(np.abs(back - feasible)) < 1e-6


@pytest.mark.parametrize("periodic", [True, False])
def test_the_refinements_host_cost_is_the_sum_of_its_squared_residuals(periodic):
    """`TrackingResiduals.cost` (the forward program and the map's own) against the
    residuals traced whole, with the slew map's extra residual where it has one."""
    from jaxhyst.control.refine import TrackingResiduals

    tracking = Tracking.of(MODEL, SINE, 2)
    imap = InputMap(InputLimits.of(LIMIT, slew=3e7), SINE.n_samples, SINE.dt, periodic)
    residuals = TrackingResiduals(tracking, imap, jnp.asarray(SINE.displacement),
                                  jnp.asarray(SINE.scale))
    z = 0.3 * np.random.default_rng(2).standard_normal(imap.size)
    traced = eqx.filter_jit(lambda res, z: res(z))
    r = np.asarray(traced(residuals, jnp.asarray(z)))
    assert r.shape[0] == SINE.n_samples + periodic  # (the periodic map's extra residual)
    assert residuals.cost(z) == pytest.approx(float(r @ r), rel=1e-12)
    # the model's own output as the reference: what is left is the map's extra residual
    own = dataclasses.replace(residuals, r=jnp.asarray(evaluate(tracking, imap.input_values(z))))
    r = np.asarray(traced(own, jnp.asarray(z)))
    assert own.cost(z) == pytest.approx(float(r @ r), rel=1e-6, abs=1e-20)
    assert (r[-1] ** 2 > 0.99 * (r @ r) > 0) if periodic else (r @ r < 1e-20)


@pytest.fixture(scope="module")
def on_the_model():
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a reachable reference: no warning at all
        return {name: compensate(MODEL, ref, current_limit=LIMIT, slew_limit=3e7)
                for name, ref in (("sine", SINE), ("three tones", THREE_TONES))}


@pytest.mark.parametrize("name,factor", [("sine", 20.0), ("three tones", 10.0)])
def test_compensation_on_the_model_tracks_within_the_limits(on_the_model, name, factor):
    res = on_the_model[name]
    assert res.error * factor <= res.uncompensated_error
    assert res.uncompensated_error > 0.05  # hysteresis matters here
    assert res.error <= 1e-6 and res.reachable
    u = res.input
    assert np.all(np.abs(u) <= LIMIT)
    assert np.max(np.abs(np.diff(np.append(u, u[0])))) <= 3e7 * SINE.dt
    # the predicted displacement is the model's own for that input
    tracking = Tracking.of(MODEL, res.reference, res.run_in_periods)
    assert np.max(np.abs(evaluate(tracking, u) - res.displacement)) < 1e-15


def test_learning_reaches_the_matched_model_error_on_a_mismatched_plant(on_the_model):
    """The plant's ten parameters differ from the model's by 10 % (random signs, fixed
    seed). Learning from the plant's measured displacement, noise-free and said to be
    (``noise=0``), reaches twice the error of a compensation computed on the plant itself
    within 10 iterations."""
    signs = np.random.default_rng(0).choice([-1.0, 1.0], size=10)
    plant = jh.Model(jh.Parameters.from_array(np.asarray(jh.TABLE3[10].to_array())
                                              * (1.0 + 0.1 * signs)), jh.ACTUATOR2)
    matched = compensate(plant, SINE, current_limit=LIMIT)
    learner = IterativeLearning.of(MODEL, SINE, current_limit=LIMIT, noise=0.0)
    measure = Tracking.of(plant, SINE)
    measure = measure.with_run_in(settling_periods(measure, learner.init().input)[0])
    state = learner.init()
    errors = []
    for _ in range(10):
        y = evaluate(measure, state.input)  # the plant, "measured"
        errors.append(rms_error(y, SINE.displacement, SINE.scale))
        if errors[-1] <= 2 * matched.error:
            break
        state = learner.step(state, y)
        assert np.all(np.abs(state.input) <= LIMIT)
    assert errors[0] > 100 * matched.error  # the model alone is far from the plant's best
    assert errors[-1] <= 2 * matched.error, errors
    assert state.errors == tuple(errors[:len(state.errors)])


def _plant(draw, **options):
    """A plant whose ten parameters are the model's 10 % off (random signs of ``draw``)."""
    signs = np.random.default_rng(draw).choice([-1.0, 1.0], size=10)
    model = jh.Model(jh.Parameters.from_array(np.asarray(jh.TABLE3[10].to_array())
                                              * (1.0 + 0.1 * signs)), jh.ACTUATOR2)
    return SimulatedPlant(model, SINE, **options)


@pytest.fixture(scope="module")
def learner():
    return IterativeLearning.of(MODEL, SINE, current_limit=LIMIT)


def test_the_first_step_is_held_to_twice_the_input_an_error_needs(learner):
    """An error the actuator can only follow with a large input (at 0.2 of the Nyquist
    frequency — inside the first step's band — and above its structural resonance,
    1.1 kHz): the model's own step would be many times
    the input swing's share of the error; the first step is held to FIRST_REACH of it,
    and the report says so. The model itself, simulated, does not bear out its
    linearisation over that step (a fall below half the linear one): the step is
    shortened until it does or the simulated error is lowest, the report says so, and
    the error it predicts is the simulated one."""
    from jaxhyst.control.learning import FIRST_REACH

    state = learner.init()
    t = np.arange(SINE.n_samples) * SINE.dt
    y = learner.predict(state) + 0.02 * SINE.scale * np.sin(2 * np.pi * 0.1 / SINE.dt * t)
    after = learner.step(state, y)
    report = after.reports[-1]
    assert report.step <= FIRST_REACH * after.errors[-1] * (1 + 1e-6), report
    assert f"held to {FIRST_REACH:.3g}× the error" in report.reason, report
    assert "the model itself, simulated, did not bear out" in report.reason, report
    e = np.asarray(SINE.displacement) - y
    simulated = e - (learner.predict(after) - learner.predict(state))
    assert report.predicted == pytest.approx(
        np.sqrt(np.mean(simulated**2)) / SINE.scale, rel=1e-9)
    assert report.predicted < after.errors[-1]  # (the step taken falls, on the model)


def test_learning_on_a_noisy_mismatched_plant_never_makes_it_worse(learner):
    """A 0.5 % sensor on a plant 10 % off: every measured error within the noise of the
    one before, the true error after learning within twice the noise, and learning
    stops at the noise floor and says so."""
    sigma = 0.005
    plant = _plant(1, noise=sigma, seed=1)
    state = learner.init()
    measured = []
    for _ in range(10):
        state = learner.step(state, plant.measure(state.input))
        measured.append(state.errors[-1])
        if state.stopped:
            break
    r = np.asarray(SINE.displacement)
    true = np.sqrt(np.mean((plant.response(state.input) - r) ** 2)) / SINE.scale
    slack = 2 * sigma / np.sqrt(SINE.n_samples)
    assert all(b <= a + slack for a, b in zip(measured, measured[1:], strict=False)), measured
    assert measured[0] > 5 * sigma and true <= 2 * sigma, (measured, true)
    assert state.stopped and state.stopped.startswith("at the noise floor")
    assert all(r.action == "accepted" for r in state.reports[:-1])
    assert np.all(np.abs(state.input) <= LIMIT)


def test_learning_at_the_plants_reach_stops_and_says_the_input_is_on_its_limits(learner):
    """A plant 10 % off (signs fixed) that cannot follow the reference within ±12 kA/m:
    compensation computed on the plant itself stalls at several times the noise with the
    input on its limit. Learning ends near that reach — not at the noise floor, which
    does not exist for it — and its stop says that the input sits on its limits."""
    signs = np.array([-1, -1, 1, 1, 1, -1, -1, 1, 1, 1])
    p = jh.Parameters.from_array(np.asarray(jh.TABLE3[10].to_array()) * (1 + 0.1 * signs))
    matched = compensate(jh.Model(p, jh.ACTUATOR2), SINE, current_limit=LIMIT)
    sigma = 0.005
    assert matched.error > 5 * sigma  # (beyond the plant's reach)
    plant = SimulatedPlant(jh.Model(p, jh.ACTUATOR2), SINE, noise=sigma, seed=5)
    state = learner.init()
    for _ in range(10):
        state = learner.step(state, plant.measure(state.input))
        if state.stopped:
            break
    r = np.asarray(SINE.displacement)
    true = np.sqrt(np.mean((plant.response(state.input) - r) ** 2)) / SINE.scale
    assert true < 1.5 * matched.error, (true, matched.error)
    assert state.stopped and "the input sits on its limits [-1.2e+04, 1.2e+04]" in \
        state.stopped and "beyond the actuator's reach" in state.stopped, state.stopped


def test_a_step_that_makes_it_worse_is_undone_and_the_band_narrowed(learner):
    """A plant with a lightly damped mode at 1.2 kHz the model lacks: the step that
    excites it is caught — undone, the band the model is trusted in narrowed below the
    frequency where the plant departed from the prediction, all in the report — and
    learning then converges in that band and says what it left."""
    plant = _plant(2, noise=0.001, seed=2, mode=(1200.0, 0.01))
    state = learner.init()
    for _ in range(8):
        state = learner.step(state, plant.measure(state.input))
        if state.stopped:
            break
    undone = [r for r in state.reports if r.action == "undone"]
    assert len(undone) == 1, [str(r) for r in state.reports]
    assert "the error rose" in undone[0].reason and "mispredicted the plant most at 1200 Hz" \
        in undone[0].reason
    assert state.band <= 600.0 and state.errors[-1] < state.errors[0] / 4
    assert state.stopped.startswith("converged in the band below 600 Hz")
    r = np.asarray(SINE.displacement)
    true = np.sqrt(np.mean((plant.response(state.input) - r) ** 2)) / SINE.scale
    assert true < state.errors[0] / 4


@pytest.mark.parametrize("delay", [2, 5])
def test_a_shifted_record_is_detected_and_corrected_or_refused(learner, delay):
    plant = SimulatedPlant(MODEL, SINE, delay=delay)  # the exact model, late by `delay`
    state = learner.step(learner.init(), plant.measure(learner.init().input))
    report = state.reports[-1]
    assert report.delay == delay and abs(report.lag - delay) < 0.3
    assert report.error < 1e-5  # corrected: the model's own error is what is left
    # (2 samples of 200 are 3.6° at the fundamental: as much as a plant a little off the
    # model lags by itself, which the report says; 5 samples, 9°, are not)
    assert ("give the acquisition's delay where it is known" in report.reason) == (delay == 2)
    strict = IterativeLearning(learner.compensation, learner.residuals, delay="refuse")
    with pytest.raises(DelayError, match=f"lags the input by {delay} samples"):
        strict.step(strict.init(), plant.measure(learner.init().input))


def test_a_one_sample_delay_found_a_little_under_one_sample_is_corrected(learner):
    """With noise the exact model's record, late by one sample, is found lagging by a
    little less (0.99 here): it rounds to one sample, and the shift explains the record
    (the departure left is the noise), so it is corrected."""
    plant = SimulatedPlant(MODEL, SINE, delay=1, noise=0.005, seed=1)
    state = learner.step(learner.init(), plant.measure(learner.init().input))
    report = state.reports[-1]
    assert 0.5 < report.lag < 1.0 and report.delay == 1, report


def test_the_delay_found_at_the_first_measurement_is_held(learner):
    """An acquisition delay does not change between trials: found at the first
    measurement (2 samples), it is held for the next, where a record that lags by a
    different amount (here none) shows the plant's phase at that input — not a new
    delay, which would compare the two errors under two alignments."""
    late = SimulatedPlant(MODEL, SINE, delay=2)
    state = learner.step(learner.init(), late.measure(learner.init().input))
    assert state.reports[-1].delay == 2
    aligned = SimulatedPlant(MODEL, SINE)
    state = learner.step(state, aligned.measure(state.input))
    report = state.reports[-1]
    assert report.delay == 2 and abs(report.lag) < 0.3  # (held, though it found none)
    assert "give the acquisition's delay" not in report.reason  # (said once, at the first)


def test_a_stop_on_an_automatic_small_delay_says_what_it_assumed(learner):
    """An exact model whose record is late by 2 samples, noise-free: learning stops once
    it predicts no fall above the noise it estimates (the model's own error, 5e-8 of the
    stroke, learned to a few 1e-9: the first band's step, then the upper band's steps,
    held to twice the error), and — the alignment resting on a delay found
    automatically, as small as a plant's own lag — the stop says what follows if the
    acquisition has none. Given (``delay=2``), nothing is assumed and nothing said."""
    plant = SimulatedPlant(MODEL, SINE, delay=2)
    state = learner.init()
    for _ in range(10):
        state = learner.step(state, plant.measure(state.input))
        if state.stopped:
            break
    assert state.stopped and "aligned by a delay of 2 samples found automatically" in \
        state.stopped and "--known-delay 0" in state.stopped
    given = IterativeLearning(learner.compensation, learner.residuals, delay=2)
    state = given.init()
    for _ in range(10):
        state = given.step(state, plant.measure(state.input))
        if state.stopped:
            break
    assert state.stopped and "found automatically" not in state.stopped


def test_a_lag_a_plant_off_the_model_shows_by_itself_is_not_taken_for_a_delay(learner):
    """A plant with every parameter 10 % off (signs fixed) whose record comes 1 sample
    late lags the model by ~1.2 samples — as much as such a plant may lag by itself, and
    shifting the record back leaves most of its departure from the model: no delay is
    taken (nor refused, with ``delay="refuse"``), the first report names the lag and how
    to give a delay, and the stop says what follows if there was one. (The exact model
    late by 2 samples is corrected, above: there the shift explains the record.)"""
    signs = np.array([1, 1, 1, -1, -1, -1, -1, -1, -1, 1])
    p = jh.Parameters.from_array(np.asarray(jh.TABLE3[10].to_array()) * (1 + 0.1 * signs))
    plant = SimulatedPlant(jh.Model(p, jh.ACTUATOR2), SINE, delay=1, noise=0.005, seed=0)
    state = learner.step(learner.init(), plant.measure(learner.init().input))
    report = state.reports[-1]
    assert report.delay == 0 and 1.0 <= report.lag < 1.5, report
    assert "not taken for an acquisition delay" in report.reason
    assert "delay=1, --known-delay 1" in report.reason
    # (refusing shifted records, it does not refuse this one: it names it)
    strict = IterativeLearning(learner.compensation, learner.residuals, delay="refuse")
    first = strict.step(strict.init(), plant.measure(strict.init().input)).reports[-1]
    assert first.delay == 0 and "not taken for an acquisition delay" in first.reason
    for _ in range(15):
        state = learner.step(state, plant.measure(state.input))
        if state.stopped:
            break
    assert state.stopped and "not taken for an acquisition delay" in state.stopped, state


@pytest.mark.extended  # (~25 s: the 800 Hz programs and the model's ten lags)
def test_a_lag_a_plant_shows_by_itself_near_resonance_is_not_taken_for_a_delay():
    """At 800 Hz, below Actuator2's 1.1 kHz resonance, a plant 10 % off the model
    (noise-free, no delay) lags it by ~4.4 samples of 200 — beyond the 5° (2.8 samples)
    a plant lags by itself far below resonance. The model says what a plant 10 % off may
    lag here (`own_lag`, ~7 samples), so that lag is not taken for an acquisition delay
    (learning it as one left the actuator 4 % off the reference while the aligned error
    fell) and learning lowers the true error; the exact model late by 5 samples — whose
    shift explains the record — is still corrected."""
    model = jh.Model(jh.TABLE3[800], jh.ACTUATOR2)
    ref = sinusoidal_reference(800.0, 15e-6, 37e-6)
    signs = np.random.default_rng(0).choice([-1.0, 1.0], size=10)
    plant = SimulatedPlant(jh.Model(jh.Parameters.from_array(
        np.asarray(jh.TABLE3[800].to_array()) * (1 + 0.1 * signs)), jh.ACTUATOR2), ref)
    learner = IterativeLearning.of(model, ref, current_limit=LIMIT)
    state = learner.step(learner.init(), plant.measure(learner.init().input))
    report = state.reports[-1]
    assert report.delay == 0 and 3.5 < report.lag <= report.own_lag, report
    assert "not taken for an acquisition delay" in report.reason
    state = learner.step(state, plant.measure(state.input))
    r = np.asarray(ref.displacement)
    assert np.sqrt(np.mean((plant.response(state.input) - r) ** 2)) / ref.scale < \
        report.error / 5
    late = SimulatedPlant(model, ref, delay=5)
    report = learner.step(learner.init(), late.measure(learner.init().input)).reports[-1]
    assert report.delay == 5 and report.error < 1e-5, report


def test_a_known_delay_is_taken_as_given_and_the_lag_left_limits_the_band(learner):
    """The acquisition's delay given: a record late by 3 samples with ``delay=3`` is
    corrected by exactly 3; with ``delay=0`` (none, known) a record late by 2 samples is
    not shifted, and the lag left (a phase error that grows with frequency) limits the
    learning band to where it turns the phase by at most π/3."""
    plant = SimulatedPlant(MODEL, SINE, delay=3)
    given = IterativeLearning(learner.compensation, learner.residuals, delay=3)
    report = given.step(given.init(), plant.measure(given.init().input)).reports[-1]
    assert report.delay == 3 and report.error < 1e-5
    plant = SimulatedPlant(MODEL, SINE, delay=2)
    none = IterativeLearning(learner.compensation, learner.residuals, delay=0)
    state = none.step(none.init(), plant.measure(none.init().input))
    report = state.reports[-1]
    assert report.delay == 0 and abs(report.lag - 2) < 0.3
    assert state.band == pytest.approx(1.0 / (6.0 * report.lag * SINE.dt), rel=1e-9)
    assert "the plant's lag against the model (+2" in report.reason


def test_a_step_is_held_to_what_the_plant_has_borne_out(learner):
    """A step no larger per unit of measured error than the state's ``reach``, and the
    report says so."""
    start = dataclasses.replace(learner.init(), reach=0.01)
    plant = _plant(3)
    state = learner.step(start, plant.measure(start.input))
    report = state.reports[-1]
    assert report.step == pytest.approx(0.01 * report.error, rel=1e-3)
    assert "the step held to 0.01× the error" in report.reason
    free = learner.step(learner.init(), plant.measure(start.input)).reports[-1]
    assert free.step > 10 * report.step


def test_a_state_written_before_reach_was_kept_goes_on(learner):
    """A learning state from a file without ``reach`` and ``step_ratio`` (written before
    they were kept) is read and stepped on: the step limit starts afresh."""
    from jaxhyst.control.learning_state import state_from_dict, state_to_dict

    plant = _plant(4, noise=0.001, seed=4)
    state = learner.step(learner.init(), plant.measure(learner.init().input))
    old = {k: v for k, v in state_to_dict(state).items() if k not in ("reach", "step_ratio")}
    state = state_from_dict(old, SINE.n_samples)
    assert state.reach is None and state.step_ratio is None
    state = learner.step(state, plant.measure(state.input))
    assert state.reports[-1].action == "accepted" and len(state.errors) == 2


def test_a_reference_beyond_the_stroke_is_reported_with_where():
    """15–75 µm, where ±8 kA/m reach about 19–57 µm: two stretches beyond the stroke, one
    at the top and one at the bottom, each covering the samples outside the static range
    (and the neighbours whose motion needs more than the range), with the largest
    excess."""
    ref = sinusoidal_reference(100.0, 30e-6, 45e-6)
    with pytest.warns(UnreachableWarning, match="beyond the stroke at t ="):
        res = compensate(MODEL, ref, current_limit=8e3)
    beyond = [u for u in res.unreachable if u.reason == "beyond the stroke"]
    assert len(beyond) == 2 and not res.reachable
    r = np.asarray(ref.displacement)
    lo, hi = res.reach.y
    for stretch, outside, excess in ((beyond[0], r > hi * (1 + 1e-4), r.max() - hi),
                                     (beyond[1], r < lo - 1e-4 * hi, lo - r.min())):
        samples = np.flatnonzero(outside)
        assert stretch.start <= samples[0] and samples[-1] <= stretch.stop
        assert stretch.stop - stretch.start < 1.2 * samples.size
        assert stretch.excess == pytest.approx(excess, rel=1e-3)
        assert stretch.t_start == pytest.approx(float(ref.t[stretch.start]))
    assert np.all(np.abs(res.input) <= 8e3)
    assert "beyond the stroke" in res.summary()


@pytest.mark.parametrize("call,fragment", [
    (lambda: reference_from_record(np.arange(20) * 1e-4, np.where(np.arange(20) == 7,
                                                                   np.nan, 1e-6)),
     "NaN or infinite at samples [7]"),
    (lambda: reference_from_record(np.arange(50) * 1e-4, 1e-6 * np.ones(50), frequency=100.0),
     "shorter than one period"),
    (lambda: compensate(MODEL, SINE, current_limit=0.0), "current limit must be a positive"),
    (lambda: compensate(MODEL, SINE, current_limit=-5.0), "current limit must be a positive"),
    (lambda: compensate(MODEL, SINE, current_limit=(3.0, 1.0)), "lower < upper"),
    (lambda: compensate(MODEL, SINE, current_limit=LIMIT, slew_limit=0), "slew-rate limit"),
    (lambda: compensate(MODEL, sinusoidal_reference(100.0, 15e-6, 37e-6,
                                                    samples_per_period=8),
                        current_limit=LIMIT), "sampled too coarsely"),
    (lambda: sinusoidal_reference(100.0, 15e-6, 37e-6, samples_per_period=4),
     "samples_per_period must be an integer in [8, 5e+07]"),
    (lambda: sinusoidal_reference(100.0, 15e-6, 37e-6, samples_per_period=10**9),
     "got 1000000000"),  # (refused before 7 GB are allocated)
    (lambda: sinusoidal_reference(-1.0, 15e-6, 37e-6), "frequency must be in"),
    (lambda: multitone_reference(100.0, [10e-6], 37e-6, harmonics=3),
     "harmonics must be a 1-D sequence (one value per tone)"),
    (lambda: multitone_reference(100.0, [[10e-6, 0.0]], 37e-6),
     "amplitudes must be a 1-D sequence (one value per tone)"),
    (lambda: multitone_reference(100.0, [10e-6], 37e-6, harmonics=["first"]),
     "harmonics must be numbers"),
    (lambda: compensate(jh.TABLE3[10], SINE), "must be a jaxhyst.Model"),
    (lambda: compensate(jh.Model(jh.TABLE1_TRUE, NO_ACTUATOR), SINE, current_limit=LIMIT),
     "this model is a material's"),
    (lambda: IterativeLearning.of(MODEL, SINE, current_limit=LIMIT, delay=-1),
     "delay = -1: a known acquisition delay is a whole number of samples"),
    (lambda: IterativeLearning.of(MODEL, SINE, current_limit=LIMIT, delay="sometimes"),
     "delay must be 'correct', 'refuse' or the acquisition's delay"),
    (lambda: IterativeLearning.of(MODEL, SINE, current_limit=LIMIT, delay=True),
     "delay must be 'correct', 'refuse' or the acquisition's delay"),
])
def test_bad_input_gets_one_line(call, fragment):
    with pytest.raises((ValueError, TypeError)) as info:
        call()
    message = str(info.value)
    assert fragment in message and "\n" not in message, message
