"""The magnetic after-effect (`Losses.relax`: τ_M·dM/dt = M_s − M, issue 41): the H-driven
model against the ODE it discretizes (an independent solve, tests/helpers.py), its
derivatives against central differences, the mechanism (B keeps rising after the field
turns; the loss per cycle grows with frequency; τ_M → 0 is the model without it),
`compensate` through it, and what does not have it (the B-driven model) saying so. Its
identification from the command line is in tests/test_rate_and_flux.py, beside the
lag's."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import reference_relaxed

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR

MU0 = 4e-7 * np.pi
SOFT = jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=30.0, k=20.0, alpha=1e-5, c=0.3, E=1.0,
                     Kz=1.0, Mz=1.0, Cz=0.0)
#: τ_M = 0.1 ms: ωτ_M = 0.19 at 300 Hz.
RELAXED = jh.Losses(relax=1e-4)
WITH_FIELDS = jh.Losses(eddy=0.05, excess=0.5, lag=5e-5, relax=1e-4)


def _B(sim):
    return MU0 * (np.asarray(sim.H_hyst) + np.asarray(sim.M))


@pytest.mark.parametrize("losses", [RELAXED, WITH_FIELDS], ids=["relax", "with fields"])
def test_the_after_effect_agrees_with_the_ode_it_discretizes_at_second_order(losses):
    errors = []
    for spp in (200, 400):
        drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=spp)
        h, M = reference_relaxed(SOFT, drive.t, drive.H, float(losses.eddy),
                                 float(losses.excess), float(losses.lag), float(losses.relax))
        sim = jh.simulate(SOFT, NO_ACTUATOR, drive, losses=losses)
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
        sim = jh.simulate(SOFT, NO_ACTUATOR, drive, losses=RELAXED)
        H, M = np.asarray(drive.observed(drive.H)), np.asarray(sim.observed("M"))
        peak = int(np.argmax(H))
        assert M[peak + 5] > M[peak]  # (5 samples = 1/40 of a period after the peak)
        static = np.asarray(jh.simulate(SOFT, NO_ACTUATOR, drive, losses=jh.Losses())
                            .observed("M"))
        assert static[peak + 5] < static[peak]
        B = MU0 * (np.asarray(sim.observed("H_hyst")) + M)
        areas.append(abs(np.sum(0.5 * (H[1:] + H[:-1]) * np.diff(B))))
    assert areas[1] > 1.5 * areas[0], areas
    drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=200)
    without = jh.simulate(SOFT, NO_ACTUATOR, drive, losses=jh.Losses(eddy=0.05))
    tiny = jh.simulate(SOFT, NO_ACTUATOR, drive, losses=jh.Losses(eddy=0.05, relax=1e-12))
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


def test_what_has_no_after_effect_says_so(tmp_path):
    from jaxhyst.cli import main

    flux = jh.sinusoidal_flux(50.0, 0.3, 0.0, samples_per_period=40)
    with pytest.raises(ValueError, match="B-driven model has no after-effect"):
        jh.simulate_flux(SOFT, flux, losses=RELAXED)
    # traced, a plausible-looking answer is never given: NaN
    H = jax.jit(lambda L: jh.simulate_flux_unchecked(SOFT, flux, losses=L).H)(RELAXED)
    assert np.all(np.isnan(np.asarray(H)))
    with pytest.raises(ValueError, match="Losses.relax must lie in"):
        jh.Losses(relax=-1e-3)
    data = tmp_path / "bh.csv"
    data.write_text("t,H,B\n0,0,0\n1e-3,10,0.1\n2e-3,0,0\n")
    assert main(["identify", str(data), "--driven-by", "B", "--losses", "relax"]) == 2

