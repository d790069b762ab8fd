"""The magnetic after-effect (`Losses.relax`: τ_M·dM/dt = M_s − M, issue 41): the H-driven
model against the ODE it discretizes (an independent solve, tests/helpers.py), its
derivatives against central differences, the mechanism (B keeps rising after the field
turns; the loss per cycle grows with frequency; τ_M → 0 is the model without it),
`compensate` through it, and the B-driven model with it (its own ODE, and the H-driven
model's inverse). Its identification from the command line is in
tests/test_rate_and_flux.py, beside the lag's."""

from __future__ import annotations

import warnings

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import reference_relaxed

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR
from jaxhyst.model.jiles_atherton import PAPER_VARIANT
from jaxhyst.names import DEFAULT_SUBSTEPS

MU0 = 4e-7 * np.pi
SOFT = jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=30.0, k=20.0, alpha=1e-5, c=0.3, E=1.0,
                     Kz=1.0, Mz=1.0, Cz=0.0)
#: τ_M = 0.1 ms: ωτ_M = 0.19 at 300 Hz.
RELAXED = jh.Losses(relax=1e-4)
WITH_FIELDS = jh.Losses(eddy=0.05, excess=0.5, lag=5e-5, relax=1e-4)


def _B(sim):
    return MU0 * (np.asarray(sim.H_hyst) + np.asarray(sim.M))


def _by_flux(drive, variant=PAPER_VARIANT, losses=RELAXED):
    """`jh.simulate_flux`'s own compiled program without its accuracy checks, where a
    test reads none of their warnings (they simulate the drive again at twice the
    substeps and at half the step: programs of other shapes, compiled for nothing)."""
    return jh.simulate_flux_unchecked(SOFT, drive, variant, DEFAULT_SUBSTEPS, losses)


@pytest.mark.parametrize("losses", [RELAXED, WITH_FIELDS], ids=["relax", "with fields"])
def test_the_after_effect_agrees_with_the_ode_it_discretizes_at_second_order(losses):
    errors = []
    for spp in (200, 400):
        drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=spp)
        h, M = reference_relaxed(SOFT, drive.t, drive.H, float(losses.eddy),
                                 float(losses.excess), float(losses.lag), float(losses.relax))
        sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, losses=losses)
        B = MU0 * (h + M)
        errors.append(np.max(np.abs(_B(sim) - B)) / np.max(np.abs(B)))
    assert errors[0] <= 4e-4 and errors[1] <= 1e-4, errors
    assert 3.0 < errors[0] / errors[1] < 5.0, errors  # second order in the sample step


def test_the_after_effect_is_the_mechanism_it_names():
    """M keeps rising after the field's peak (the static model's turns with it), the
    loop's area grows with frequency, and τ_M → 0 is the model without it."""
    areas = []
    for f in (100.0, 1000.0):
        drive = jh.sinusoidal_field(f, 200.0, 0.0, samples_per_period=200)
        sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, losses=RELAXED)
        H, M = np.asarray(drive.observed(drive.H)), np.asarray(sim.observed("M"))
        peak = int(np.argmax(H))
        assert M[peak + 5] > M[peak]  # (5 samples = 1/40 of a period after the peak)
        static = np.asarray(jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, losses=jh.Losses())
                            .observed("M"))
        assert static[peak + 5] < static[peak]
        B = MU0 * (np.asarray(sim.observed("H_hyst")) + M)
        areas.append(abs(np.sum(0.5 * (H[1:] + H[:-1]) * np.diff(B))))
    assert areas[1] > 1.5 * areas[0], areas
    drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=200)
    without = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, losses=jh.Losses(eddy=0.05))
    tiny = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, losses=jh.Losses(eddy=0.05, relax=1e-12))
    for name in ("M", "H_hyst"):
        a, b = np.asarray(getattr(tiny, name)), np.asarray(getattr(without, name))
        assert np.max(np.abs(a - b)) <= 1e-7 * np.max(np.abs(b)), name


def test_derivatives_with_the_after_effect_free_match_central_differences():
    field = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=60)
    base = np.array([np.log(30.0), np.log(20.0), 0.3, np.log(0.05), np.log(1e-4)])

    def forward(x):
        p = SOFT.replace(a=jnp.exp(x[0]), k=jnp.exp(x[1]), c=x[2])
        s = jh.simulate_unchecked(p, NO_ACTUATOR, field,
                                  losses=jh.Losses(eddy=jnp.exp(x[3]), relax=jnp.exp(x[4])))
        return s.M[field.run_in:] / 3.5e5

    compiled = jax.jit(forward)
    J = np.asarray(jax.jit(jax.jacfwd(forward))(jnp.asarray(base)))
    fd = np.array([(np.asarray(compiled(base + 1e-6 * e)) - np.asarray(compiled(base - 1e-6 * e)))
                   / 2e-6 for e in np.eye(len(base))]).T
    err = np.max(np.abs(J - fd), axis=0) / np.max(np.abs(fd), axis=0)
    assert np.all(err < 1e-5), err


def test_compensate_runs_the_after_effect_backwards():
    """On an actuator whose magnetization relaxes (τ_M = 0.3 ms at 100 Hz), the inverse
    model alone (no refinement) tracks the reference on that model as it does without an
    after-effect; the input made for the model without it does not."""
    from jaxhyst.control import compensate, sinusoidal_reference
    from jaxhyst.control.tracking import Tracking, evaluate

    reference = sinusoidal_reference(100.0, 15e-6, 37e-6)
    relaxed = jh.Model(jh.TABLE3[10], jh.ACTUATOR2, losses=jh.Losses(relax=3e-4))
    res = compensate(relaxed, reference, current_limit=12e3, refine=False)
    blind = compensate(jh.Model(jh.TABLE3[10], jh.ACTUATOR2, losses=jh.Losses()), reference,
                       current_limit=12e3, refine=False)
    assert res.reachable and res.error <= 2.0 * max(blind.error, 1e-5), (res.error,
                                                                          blind.error)
    tracking = Tracking.of(relaxed, res.reference, res.run_in_periods)
    y = evaluate(tracking, blind.input)
    stroke = float(np.ptp(res.reference.displacement))
    assert np.sqrt(np.mean((y - res.reference.displacement) ** 2)) / stroke > 30 * res.error


def test_the_b_driven_after_effect_agrees_with_its_ode_and_inverts_the_h_driven_model():
    """Driven by B, the after-effect (h from B = μ0·(h + M), M relaxed) against an
    independent solve of its ODE for a smooth B = 0.35 T·sin(ωt), over the second period
    (the first holds the initial transient, of time constant τ_M/(1 + χ), which no
    sampling resolves): second order in the sample step; H = B/μ0 − M carries M's error
    times |M|/|H| (≈ 900 here), which the sampling warning says at 200 samples — and as
    the inverse of the H-driven model: the H-driven loop's B drives it back to the same H
    (to round-off with the after-effect alone: the two solve one discrete scheme; with
    the loss fields the same M, and H as close as the B-driven model without the
    after-effect comes)."""
    from helpers import reference_relaxed_by_flux

    w = 2 * np.pi * 300.0
    errors, gaps_h = [], []
    # (B smooth between the samples: the ODE's solution does not depend on the sampling,
    # so 200 samples a period read the 400-sample solution at every other sample)
    t = np.arange(2 * 400 + 1) / 400 / 300.0
    h_ref, M_ref = reference_relaxed_by_flux(
        SOFT, t, 0.35 * np.sin(w * t), float(RELAXED.relax),
        smooth=lambda x: (0.35 * np.sin(w * x), 0.35 * w * np.cos(w * x)))
    for spp in (200, 400):
        t = np.arange(2 * spp + 1) / spp / 300.0
        B = 0.35 * np.sin(w * t)
        h, M = h_ref[::400 // spp], M_ref[::400 // spp]
        if spp == 200:  # (the public function, for its warning)
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                sim = jh.simulate_flux(SOFT, jh.FluxDrive(t, B), jh.EnergyBasedJA(),
                                       losses=RELAXED)
            assert any(issubclass(c.category, jh.identify.SamplingWarning) for c in caught)
        else:
            sim = _by_flux(jh.FluxDrive(t, B), jh.EnergyBasedJA())
        o = slice(spp, None)
        errors.append(np.max(np.abs(np.asarray(sim.M)[o] - M[o])) / np.max(np.abs(M)))
        gaps_h.append(np.max(np.abs(np.asarray(sim.H_hyst)[o] - h[o])) / np.ptp(h))
    assert errors[0] <= 5e-7 and errors[1] <= 1.5e-7, errors
    assert 2.5 < errors[0] / errors[1] < 5.0, errors  # second order in the sample step
    assert gaps_h[0] <= 4e-4 and gaps_h[1] <= 1.2e-4, gaps_h

    drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=200)
    H, o = np.asarray(drive.H), slice(drive.run_in, None)
    gaps = []
    for losses in (RELAXED, WITH_FIELDS, WITH_FIELDS.__class__(
            eddy=WITH_FIELDS.eddy, excess=WITH_FIELDS.excess, lag=WITH_FIELDS.lag)):
        sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, losses=losses)
        back = _by_flux(jh.FluxDrive(drive.t, _B(sim), drive.run_in), losses=losses)
        # (the path without the after-effect is RK4 in B, not the H-driven scheme's
        # inverse: its M agrees to that scheme's error only)
        tol = 1e-10 if float(losses.relax) > 0 else 1e-6
        assert np.max(np.abs(np.asarray(back.M) - np.asarray(sim.M))) <= \
            tol * np.max(np.abs(np.asarray(sim.M))), losses
        gaps.append(np.max(np.abs(np.asarray(back.H)[o] - H[o])) / np.ptp(H))
    assert gaps[0] <= 1e-10 and gaps[1] <= 1.5 * gaps[2], gaps
    # a form of pinning cells the same way (its cells' state through the B-driven root)
    play = jh.PlayJA(spread=0.7)
    sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, play, losses=RELAXED)
    back = _by_flux(jh.FluxDrive(drive.t, _B(sim), drive.run_in), play)
    assert np.max(np.abs(np.asarray(back.H)[o] - H[o])) <= 1e-10 * np.ptp(H)


@pytest.mark.extended  # (the B-driven after-effect's agreement stays in the default run)
def test_the_b_driven_after_effect_is_chosen_statically_and_differentiated():
    """Traced, the path is a static choice: ``after_effect=True`` gives the eager values
    (and derivatives that match central differences), left out it gives NaN for relax > 0
    — never a model without the after-effect that looks plausible."""
    flux = jh.sinusoidal_flux(300.0, 0.35, 0.0, samples_per_period=60)
    eager = jh.simulate_flux(SOFT, flux, losses=RELAXED)
    H = jax.jit(lambda L: jh.simulate_flux_unchecked(SOFT, flux, losses=L).H)(RELAXED)
    assert np.all(np.isnan(np.asarray(H)))

    def energy(x):
        p = SOFT.replace(a=jnp.exp(x[0]), k=jnp.exp(x[1]))
        return jh.simulate_flux_unchecked(p, flux, losses=jh.Losses(relax=jnp.exp(x[2])),
                                          after_effect=True).cycle_energy

    base = np.log(np.array([30.0, 20.0, 1e-4]))
    assert float(jax.jit(energy)(base)) == pytest.approx(float(eager.cycle_energy), rel=1e-12)
    g = np.asarray(jax.jit(jax.grad(energy))(jnp.asarray(base)))
    fd = np.array([(float(energy(base + 1e-6 * e)) - float(energy(base - 1e-6 * e))) / 2e-6
                   for e in np.eye(3)])
    assert np.max(np.abs(g - fd)) <= 1e-5 * np.max(np.abs(fd)), (g, fd)
    with pytest.raises(ValueError, match="Losses.relax must lie in"):
        jh.Losses(relax=-1e-3)
    # a B-driven problem takes the path where its space has relax (shared or per record)
    drives = [flux, flux]
    data = np.stack([np.asarray(eager.observed("H"))] * 2)
    shared = jh.ParameterSpace.with_losses(jh.TABLE1_BOUNDS, {"relax": (0.0, 1e-3)})
    per_record = jh.per_record_space(jh.TABLE1_BOUNDS, 2, {"relax": (0.0, 1e-3)}, None)
    without = jh.ParameterSpace.with_losses(jh.TABLE1_BOUNDS, {"eddy": (0.0, 1.0)})
    assert jh.FluxProblem(data, drives, shared).after_effect
    assert jh.FluxProblem(data, drives, per_record).after_effect
    assert not jh.FluxProblem(data, drives, without).after_effect
    problem = jh.FluxProblem(data, drives, shared)
    H = np.asarray(problem.predict((SOFT, RELAXED)))
    assert np.max(np.abs(H - data)) <= 1e-9 * np.max(np.abs(data))
