"""The model driven either way (issue 30): the B-driven (inverse) form and the
rate-dependent form with eddy-current and excess losses, each against an independent
solve (tests/helpers.py), their derivatives against central differences, and the
physics: no losses is the static model, loss per cycle grows with frequency, forward
then inverse returns the drive, and the inverse's loss is the forward's ∮ H dB."""

from __future__ import annotations

import json

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import reference_dynamic, reference_flux

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR

MU0 = 4e-7 * np.pi
#: A soft ferrite-like material (a, k of tens of A/m) and losses that matter at 300 Hz.
SOFT = jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=30.0, k=20.0, alpha=1e-5, c=0.3, E=1.0,
                     Kz=1.0, Mz=1.0, Cz=0.0)
LOSSES = jh.Losses(eddy=0.05, excess=0.5)
#: … and with the hysteresis field's relaxation (τ = 0.1 ms: ωτ = 0.19 at 300 Hz).
LAGGED = jh.Losses(eddy=0.05, excess=0.5, lag=1e-4)


#: The values of `simulate` and `simulate_flux` without their accuracy checks, which
#: compile each simulation again (twice the substeps, half the sample step) only to warn:
#: the checks have tests of their own (the B-driven warning below, test_measured,
#: test_compiles).
simulate, simulate_flux = jh.simulate_unchecked, jh.simulate_flux_unchecked


def _B(sim):
    return MU0 * (np.asarray(sim.H_hyst) + np.asarray(sim.M))


def test_simulate_flux_unchecked_called_directly_runs_compiled(caplog):
    """Outside any jit trace `simulate_flux_unchecked` runs as one compiled program, as
    `simulate_unchecked` does (op by op, a first call compiled each operation on its
    own: benchmarks/RESULTS.md): a new value compiles nothing, and ``jax.grad`` called
    directly compiles a few programs, not one per operation, and matches central
    differences."""
    import logging

    drive = jh.sinusoidal_flux(300.0, 0.3, samples_per_period=57)  # (shapes of their own)

    def energy(a):
        return jh.simulate_flux_unchecked(SOFT.replace(a=a), drive, losses=LOSSES).cycle_energy

    # (a float's conversion to a parameter compiles a program of its own where an earlier
    # test dropped the compiled programs, as test_jax_compat's releases do; not counted)
    SOFT.replace(a=29.0)
    with jax.log_compiles(), caplog.at_level(logging.WARNING):
        first = float(energy(30.0))
        compiled = [r.getMessage() for r in caplog.records
                    if r.getMessage().startswith("Finished XLA compilation")]
        caplog.clear()
        float(energy(31.0))
        again = [r for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
        caplog.clear()
        slope = float(jax.grad(energy)(30.0))
        by_grad = [r for r in caplog.records if "Finished XLA compilation" in r.getMessage()]
    assert len(compiled) == 1 and "_simulate_flux" in compiled[0], compiled
    assert not again
    assert len(by_grad) < 15, [r.getMessage() for r in by_grad]
    h = 1e-3
    assert slope == pytest.approx((float(energy(30.0 + h)) - float(energy(30.0 - h))) / (2 * h),
                                  rel=1e-6)
    assert np.isfinite(first)


@pytest.mark.parametrize("variant", ["energy", "classic"])
def test_the_flux_driven_form_agrees_with_an_independent_solve(variant):
    form = jh.EnergyBasedJA() if variant == "energy" else jh.ClassicJA()
    drive = jh.sinusoidal_flux(300.0, 0.35, 0.05, samples_per_period=200)
    sim = simulate_flux(SOFT, drive, form, losses=LOSSES)
    M, H, energy = reference_flux(SOFT, drive.t, drive.B, variant, 0.05, 0.5, drive.run_in,
                                  rtol=1e-13)
    # the documented accuracy at the default setting (2 substeps, 200 samples per period):
    # M to 2e-7 of Ms; H = B/μ0 − M inherits M's error times the permeability (here H is
    # ~1e-3 of B/μ0), so 1e-4 of max|H|; the energy to 1e-6
    assert np.max(np.abs(np.asarray(sim.M) - M)) <= 2e-7 * SOFT.Ms
    assert np.max(np.abs(np.asarray(sim.H) - H)) <= 1e-4 * np.max(np.abs(H))
    assert abs(float(sim.cycle_energy) / energy - 1) <= 1e-6
    # RK4 in B: four substeps more than tenfold better (the error is the scheme's)
    finer = simulate_flux(SOFT, drive, form, losses=LOSSES, substeps=8)
    assert np.max(np.abs(np.asarray(finer.H) - H)) <= 3e-6 * np.max(np.abs(H))


@pytest.mark.parametrize("losses", [LOSSES, LAGGED], ids=["eddy+excess", "with lag"])
def test_the_rate_dependent_form_agrees_with_the_ode_it_discretizes_at_second_order(losses):
    errors = []
    for spp in (200, 400):
        drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=spp)
        h, M = reference_dynamic(SOFT, drive.t, drive.H, "energy", 0.05, 0.5,
                                 lag=float(losses.lag))
        sim = simulate(SOFT, NO_ACTUATOR, drive, losses=losses)
        B = MU0 * (h + M)
        errors.append(np.max(np.abs(_B(sim) - B)) / np.max(np.abs(B)))
    assert errors[0] <= 3e-4 and errors[1] <= 7e-5, errors  # (documented: 200 spp)
    assert 3.0 < errors[0] / errors[1] < 5.0, errors  # second order in the sample step


def test_without_loss_coefficients_both_forms_are_the_static_model():
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=100)
    static = simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive)
    dynamic = simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive, losses=jh.Losses(0.0, 0.0))
    for name in ("M", "y", "H_hyst"):
        a, b = np.asarray(getattr(dynamic, name)), np.asarray(getattr(static, name))
        assert np.max(np.abs(a - b)) <= 1e-13 * np.max(np.abs(b)), name
    flux = jh.sinusoidal_flux(50.0, 0.3, 0.0, samples_per_period=100)
    a = simulate_flux(SOFT, flux, losses=jh.Losses(0.0, 0.0))
    b = simulate_flux(SOFT, flux)
    np.testing.assert_array_equal(np.asarray(a.H), np.asarray(b.H))


def test_the_loss_per_cycle_grows_with_frequency_as_the_loss_terms_say():
    """At a fixed flux-density amplitude the energy per cycle is the static loop's plus
    k_e·2π²f·B̂² plus k_x·(2πf)^(1/2)·B̂^(3/2)·∮|cos|^(3/2) — it grows with f."""
    static = None
    energies = []
    for f in (10.0, 100.0, 1000.0):
        drive = jh.sinusoidal_flux(f, 0.3, 0.0, samples_per_period=400)
        W = float(simulate_flux(SOFT, drive, losses=LOSSES).cycle_energy)
        W0 = float(simulate_flux(SOFT, drive).cycle_energy)
        static = W0 if static is None else static
        assert W0 == pytest.approx(static, rel=1e-9)  # rate independent
        cos32 = np.mean(np.abs(np.cos(2 * np.pi * np.arange(4000) / 4000)) ** 1.5)
        # (∫|Ḃ|^{3/2}dt over a period = (2πfB̂)^{3/2}·⟨|cos|^{3/2}⟩/f)
        expected = 0.05 * 2 * np.pi**2 * f * 0.3**2 + \
            0.5 * (2 * np.pi * f * 0.3) ** 1.5 * cos32 / f
        assert W - W0 == pytest.approx(expected, rel=2e-4)
        energies.append(W)
    assert energies[0] < energies[1] < energies[2]


@pytest.mark.parametrize("losses", [LOSSES, LAGGED], ids=["eddy+excess", "with lag"])
@pytest.mark.filterwarnings("ignore::jaxhyst.identify.SamplingWarning")  # (the next test's)
def test_forward_then_inverse_returns_the_drive_and_the_loss(losses):
    drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=400)
    sim = simulate(SOFT, NO_ACTUATOR, drive, losses=losses)
    B = _B(sim)
    back = simulate_flux(SOFT, jh.FluxDrive(drive.t, B, drive.run_in, True),
                            losses=losses)
    H = np.asarray(drive.H)
    assert np.max(np.abs(np.asarray(back.H) - H)) <= 1e-2 * np.max(np.abs(H))
    assert np.max(np.abs(np.asarray(back.M) - np.asarray(sim.M))) <= 1e-6 * SOFT.Ms
    Ho, Bo = H[drive.run_in:], B[drive.run_in:]
    area = np.sum(0.5 * (Ho[1:] + Ho[:-1]) * np.diff(Bo))  # ∮ H dB of the forward model
    assert float(back.cycle_energy) == pytest.approx(area, rel=2e-4)


def test_the_b_driven_warning_names_the_sampling_where_the_loss_fields_set_the_error():
    """With the lag, the error of H at 400 samples per period is the loss fields' (it
    falls with the sample step), not RK4's: the warning asks for finer sampling, by the
    factor it names, and at that sampling it is quiet."""
    import re
    import warnings

    def flux(spp):
        drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=spp)
        B = _B(jh.simulate(SOFT, NO_ACTUATOR, drive, losses=LAGGED))
        return jh.FluxDrive(drive.t, B, drive.run_in, True)

    with pytest.warns(jh.identify.SamplingWarning, match="sample B about") as caught:
        jh.simulate_flux(SOFT, flux(400), losses=LAGGED)
    factor = int(re.search(r"sample B about (\d+)×", str(caught[0].message)).group(1))
    assert 2 <= factor <= 40 and "use " not in str(caught[0].message)
    with warnings.catch_warnings():
        warnings.simplefilter("error", jh.identify.SamplingWarning)
        jh.simulate_flux(SOFT, flux(400 * factor), losses=LAGGED)


def _central(f, x, h):
    return np.array([(f(x + h * e) - f(x - h * e)) / (2 * h) for e in np.eye(len(x))]).T


def test_derivatives_of_both_forms_match_central_differences():
    flux = jh.sinusoidal_flux(300.0, 0.35, 0.05, samples_per_period=60)
    field = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=60)
    base = np.array([np.log(30.0), np.log(20.0), 0.3, np.log(0.05), np.log(0.5),
                     np.log(1e-4)])

    def parts(x):
        p = SOFT.replace(a=jnp.exp(x[0]), k=jnp.exp(x[1]), c=x[2])
        return p, jh.Losses(jnp.exp(x[3]), jnp.exp(x[4]), jnp.exp(x[5]))

    def inverse(x):
        p, L = parts(x)
        s = jh.simulate_flux_unchecked(p, flux, losses=L)
        return jnp.concatenate([s.H[flux.run_in:] / 200.0, s.cycle_energy[None] / 50.0])

    def forward(x):
        p, L = parts(x)
        s = jh.simulate_unchecked(p, NO_ACTUATOR, field, losses=L)
        return s.M[field.run_in:] / 3.5e5

    for f in (inverse, forward):
        compiled = jax.jit(f)
        J = np.asarray(jax.jit(jax.jacfwd(f))(jnp.asarray(base)))
        fd = _central(lambda x, c=compiled: np.asarray(c(jnp.asarray(x))), base, 1e-6)
        err = np.max(np.abs(J - fd), axis=0) / np.max(np.abs(fd), axis=0)
        assert np.all(err < 1e-5), (f.__name__, err)
        g = jax.jit(jax.grad(lambda x, f=f: jnp.sum(f(x) ** 2)))(jnp.asarray(base))
        np.testing.assert_allclose(np.asarray(g), 2 * J.T @ np.asarray(compiled(base)),
                                   rtol=1e-9, atol=1e-12 * np.max(np.abs(g)))


def _soft_box():
    lo = SOFT.replace(a=10.0, k=5.0, c=0.05)
    hi = SOFT.replace(a=100.0, k=60.0, c=0.9)
    return jh.Bounds(lo, hi)


FIXED = {"Ms": 3.5e5, "alpha": 1e-5, "lambda_s": 0.0, "E": 1.0, "Kz": 1.0, "Mz": 1.0,
         "Cz": 0.0}


def test_loss_coefficients_are_identified_from_the_energy_per_cycle():
    """Energies per cycle of B-driven records at five frequencies determine k and both
    loss coefficients (the static loop's area fixes k, its growth with f the rest); a
    fit with another declared noise level compiles nothing."""
    from test_compiles import counting

    drives = [jh.sinusoidal_flux(f, 0.3, 0.0, samples_per_period=80)
              for f in (20.0, 100.0, 300.0, 1000.0, 3000.0)]
    energies = [float(simulate_flux(SOFT, d, losses=LOSSES).cycle_energy) for d in drives]
    space = jh.ParameterSpace.with_losses(_soft_box(), {"eddy": (0.0, 0.2),
                                                        "excess": (0.0, 2.0)},
                                          fixed={**FIXED, "a": 30.0, "c": 0.3})
    starts = np.random.default_rng(1).uniform(0, 1, (4, 3))
    problem = jh.FluxProblem(energies, drives, space, output="cycle_energy", sigma=1e-3)
    result = jh.multistart(problem, starts, report=False)
    assert result.success and result.cost < 1e-14, (result.result, result.cost)
    np.testing.assert_allclose(result.values, [20.0, 0.05, 0.5], rtol=1e-6)
    assert result.free == ("k", "eddy", "excess")
    with counting() as compiled:
        again = jh.multistart(jh.FluxProblem(energies, drives, space, output="cycle_energy",
                                             sigma=2e-3), starts, report=False)
    assert compiled.names == []
    np.testing.assert_allclose(again.values, result.values, rtol=1e-6)


@pytest.mark.slow  # a rate-dependent fit; the energy-per-cycle fit stays in the default run
@pytest.mark.filterwarnings("ignore::jaxhyst.identify.SamplingWarning")
def test_the_rate_dependent_model_is_identified_from_an_h_driven_loop():
    """B(t) measured under a sinusoidal field at 300 Hz: the H-driven rate-dependent
    model, its loss coefficients free beside a, k, c, recovers them (the identification
    machinery is unchanged: a `Problem` over the pair (Parameters, Losses))."""
    drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=80)
    B = _B(jh.simulate(SOFT, NO_ACTUATOR, drive, losses=LOSSES))[drive.run_in:]
    space = jh.ParameterSpace.with_losses(_soft_box(), {"eddy": (0.0, 0.2),
                                                        "excess": (0.0, 2.0)}, fixed=FIXED)
    problem = jh.Problem(B, drive, NO_ACTUATOR, space, output="flux_density")
    start = space.u_from_params((SOFT.replace(a=40.0, k=15.0, c=0.4), jh.Losses(0.08, 0.3)))
    result = jh.solve(problem, start)
    assert result.success and result.cost < 1e-20, (result.result, result.cost)
    np.testing.assert_allclose(result.values, [30.0, 20.0, 0.3, 0.05, 0.5], rtol=1e-6)
    assert result.report is not None and result.report.rank == 5
    model = problem.model(result.params)
    assert float(model.losses.eddy) == pytest.approx(0.05, rel=1e-6)


def _b_driven_file(tmp_path, params, samples: int, substeps: int):
    """A file ``bh.csv`` of one period of the classic model driven by B = 0.3 T at 50 Hz
    (columns t, H, B): (its path, t, H, B)."""
    drive = jh.sinusoidal_flux(50.0, 0.3, samples_per_period=samples)
    sim = jh.simulate_flux(params, drive, jh.ClassicJA(), substeps=substeps)
    t, H, B = (np.asarray(sim.observed(q)) for q in ("t", "H", "B"))
    data = tmp_path / "bh.csv"
    data.write_text("t [s],H [A/m],B [T]\n" + "".join(
        f"{float(a - t[0])!r},{float(h)!r},{float(b)!r}\n" for a, h, b in zip(t, H, B,
                                                                               strict=True)))
    return data, t, H, B


@pytest.mark.extended  # (end to end: a B-driven fit by the command line, saved, reloaded)
def test_a_b_driven_fit_from_the_command_line_saves_a_model_driven_by_b(tmp_path, capsys):
    """``identify --driven-by B``: a file's B(t) drives the model and H is fitted (the
    parameters that made it come back); the saved model, a material without actuator, is
    simulated by B from the command line and gives the file's H; what a B-driven fit does
    not do is one line."""
    import json

    from jaxhyst.cli import main

    p = jh.Parameters(Ms=3.8e5, lambda_s=0.0, a=30.0, k=25.0, alpha=3e-5, c=0.4, E=1.0,
                      Kz=1.0, Mz=1.0, Cz=0.0)
    data, t, H, B = _b_driven_file(tmp_path, p, 80, 4)
    model = tmp_path / "m.eqx"
    assert main(["identify", str(data), "--driven-by", "B", "--variant", "classic",
                 "--substeps", "4", "--starts", "2", "--save-model", str(model),
                 "--json", "--progress", "0"]) == 0
    fit = json.loads(capsys.readouterr().out)
    for name in ("Ms", "a", "k", "alpha", "c"):
        assert fit["params"][name]["value"] == pytest.approx(float(getattr(p, name)),
                                                             rel=1e-3), name
    saved = jh.load_model(model)
    assert saved.actuator.name == NO_ACTUATOR.name and isinstance(saved.variant, jh.ClassicJA)
    from jaxhyst.saved import read_header

    meta = read_header(model)["meta"]  # (a B-driven fit's amplitude: its peak flux density)
    assert meta["fitted_conditions"]["amplitude"] == [pytest.approx(float(np.max(np.abs(B))))] * 2
    assert meta["amplitude_unit"] == "T"
    assert main(["simulate", "--model", str(model), "--flux-amplitude", "0.3", "--frequency",
                 "50", "--samples-per-period", "80", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    assert out["H_max_A_per_m"] == pytest.approx(float(H.max()), rel=1e-3)
    for argv, message in (
            (["--driven-by", "B", "--output", "M"], "leave it out"),
            (["--driven-by", "B", "--joint", "--per-loop", "k", "--vary", "a:log_amplitude"],
             "use one of them")):
        assert main(["identify", str(data), *argv]) == 2
        assert message in capsys.readouterr().err
    data.write_text("H [A/m],B [T]\n1,0.1\n2,0.2\n")
    assert main(["identify", str(data), "--driven-by", "B"]) == 2


def test_a_b_driven_fit_predicts_each_loops_field_from_its_b(tmp_path, capsys):
    """``predict`` of a B-driven fit (result file and saved model alike): each loop of a
    file driven by its B(t) — the fitted model's H, as `simulate_flux` gives it, compared
    with the loop's H where the file has one; a file of B(t) alone predicted too; the
    amplitude of the fitted range in teslas; --amplitude (a field's) refused in one line."""
    import json

    from jaxhyst.cli import main

    data, t, H, B = _b_driven_file(tmp_path, SOFT, 60, 2)
    result, model = tmp_path / "r.json", tmp_path / "m.eqx"
    assert main(["identify", str(data), "--driven-by", "B", "--variant", "classic",
                 "--starts", "1", "--max-steps", "2", "--intervals", "linear", "--out", str(result),
                 "--save-model", str(model), "--progress", "0"]) in (0, 3)
    capsys.readouterr()
    fitted = json.loads(result.read_text())["params"]
    p = SOFT.replace(**{n: fitted[n]["value"] for n in ("Ms", "a", "k", "alpha", "c")})
    again = jh.flux_from_record(t - t[0], B, run_in_periods=1)
    expected = np.asarray(jh.simulate_flux(p, again, jh.ClassicJA()).H)[again.run_in:]
    rms = float(np.sqrt(np.mean((expected - H) ** 2)))
    for source in (result, model):
        out = tmp_path / f"{source.suffix[1:]}.csv"
        assert main(["predict", str(source), str(data), "--out", str(out), "--json"]) == 0
        (row,) = json.loads(capsys.readouterr().out)["loops"]
        assert row["rms"] == pytest.approx(rms, rel=1e-9) and row["extrapolation"] == ""
        assert row["unit"] == "A/m"  # (the error is of H)
        table = np.genfromtxt(out, delimiter=",", names=True)
        np.testing.assert_allclose(table["B_T"], B)
        np.testing.assert_allclose(table["predicted"], expected, rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(table["data"], H)
    alone = tmp_path / "b.csv"  # (B(t) at a higher peak, no H: predicted, not compared)
    alone.write_text("t,B\n" + "".join(f"{float(a - t[0])!r},{1.2 * float(b)!r}\n"
                                       for a, b in zip(t, B, strict=True)))
    assert main(["predict", str(model), str(alone), "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)["loops"]
    assert "rms" not in row and row["extrapolation"].startswith("amplitude (0.36 T")
    assert main(["predict", str(result), str(data), "--amplitude", "50"]) == 2
    assert "a B-driven fit (--driven-by B)" in capsys.readouterr().err


@pytest.mark.parametrize("name, value, driven_by", [  # (command-line fits: the extended
    # step; the default run fits the loss coefficients in Python and a B-driven loop from
    # the command line)
    pytest.param("lag", 1e-4, "H", marks=pytest.mark.extended),
    pytest.param("relax", 2e-4, "H", marks=pytest.mark.extended),
    pytest.param("relax", 2e-4, "B", marks=pytest.mark.extended)])
def test_a_time_constant_is_identified_from_the_command_line(tmp_path, capsys, name, value,
                                                             driven_by):
    """A B(H) loop of the H-driven model with the hysteresis field's relaxation time (lag,
    0.1 ms) or the magnetization's (relax, the after-effect, 0.2 ms): ``identify --losses
    NAME`` with the rest held at the truth finds it (its box from the data's dH/dt), and
    the saved model keeps it — the after-effect also driven by B (``--driven-by B``: the
    field fitted from the loop's B)."""
    import json

    from jaxhyst.cli import main

    drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=150)
    # (the data without simulate's accuracy check: one program fewer to compile)
    sim = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, losses=jh.Losses(**{name: value}))
    t, H, B = (np.asarray(drive.observed(x)) for x in (drive.t, drive.H, _B(sim)))
    data = tmp_path / "bh.csv"
    data.write_text("t [s],H [A/m],B [T]\n" + "".join(
        f"{float(a - t[0])!r},{float(h)!r},{float(b)!r}\n"
        for a, h, b in zip(t, H, B, strict=True)))
    start = tmp_path / "p.json"
    start.write_text(json.dumps(SOFT.to_dict()))
    model = tmp_path / "m.eqx"
    # (driven by B, the box's upper half of τ_M needs fields of tens of kA/m for this
    # loop's B, where the time loop's two substeps per sample do not hold: a start at the
    # box's centre stalls there, the default's random starts do not all)
    starts = "1" if driven_by == "H" else "4"
    assert main(["identify", str(data), "--variant", "energy", "--losses", name,
                 "--driven-by", driven_by,
                 "--params", str(start), "--fix", ",".join(jh.NAMES), "--starts", starts,
                 "--intervals", "linear", "--save-model", str(model), "--json",
                 "--progress", "0"]) in (0, 4)
    fit = json.loads(capsys.readouterr().out)
    assert fit["params"][name]["value"] == pytest.approx(value, rel=1e-4)
    assert float(getattr(jh.load_model(model).losses, name)) == pytest.approx(value, rel=1e-4)


def test_losses_refuse_a_record_given_without_times_in_every_entry_point():
    """drive_from_record(None, H) counts samples, not seconds (a rate-independent B–H
    loop): a rate-dependent term on it would be computed with 1 s steps and be silently
    wrong, so every entry point that takes losses refuses it in one line, while the
    rate-independent model runs on it as before and padding keeps the mark."""
    from jaxhyst.identify.flux import stack_flux_drives
    from jaxhyst.identify.joint import pad_drives

    phase = np.linspace(0.0, 2.0 * np.pi, 41)
    H, B = 80.0 * np.sin(phase), 0.3 * np.sin(phase)
    untimed, timed = jh.drive_from_record(None, H), jh.drive_from_record(phase / 300.0, H)
    assert not untimed.timed and timed.timed
    flux = jh.flux_from_record(None, B)
    assert not flux.timed and jh.flux_from_record(phase / 300.0, B).timed
    losses = jh.Losses(eddy=1e-3)
    with_losses = jh.ParameterSpace.with_losses(jh.TABLE1_BOUNDS, {"eddy": (0.0, 1e-2)})
    joint_losses = jh.ParameterSpace.for_model(jh.TABLE1_BOUNDS, losses={"eddy": (0.0, 1e-2)},
                                               n_loops=2)
    refused = [
        lambda: jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, untimed, losses=losses),
        lambda: jh.simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, untimed, losses=losses),
        lambda: jh.simulate_flux(jh.TABLE1_TRUE, flux, losses=losses),
        lambda: jh.simulate_flux_unchecked(jh.TABLE1_TRUE, flux, losses=losses),
        lambda: jh.Problem(np.zeros(untimed.n_observed), untimed, jh.ACTUATOR1, with_losses),
        lambda: jh.JointProblem([np.zeros(timed.n_observed), np.zeros(untimed.n_observed)],
                                [timed, untimed], jh.ACTUATOR1, joint_losses),
        lambda: jh.FluxProblem(np.ones((1, flux.n_observed)), [flux], with_losses),
    ]
    for call in refused:
        with pytest.raises(ValueError, match="need the record's times") as err:
            call()
        assert "\n" not in str(err.value) and "drive_from_record(t, H)" in str(err.value)
    # (the rate-independent model: untimed as before; a joint problem pads and keeps it)
    assert np.all(np.isfinite(jh.simulate_unchecked(jh.TABLE1_TRUE, jh.ACTUATOR1, untimed).y))
    padded, _ = pad_drives([untimed, jh.drive_from_record(None, H[:-8])])
    assert not padded.timed
    mixed, _ = pad_drives([untimed, timed])
    assert not mixed.timed
    timed_flux = jh.flux_from_record(phase / 300.0, B)
    assert not stack_flux_drives([timed_flux, flux]).timed
    assert stack_flux_drives([timed_flux, timed_flux]).timed


def test_records_of_unequal_length_are_padded_and_fitted_as_each_alone():
    """A `FluxProblem` of records of different lengths pads them to the longest (B = 0 in
    front, the last B held): each record's residuals are those of its problem alone, 0 in
    its padding, and count only its own samples; data of the wrong length name the
    record; a record that does not start at B = 0 cannot be padded in front."""
    form, space = jh.ClassicJA(), jh.ParameterSpace(jh.TABLE1_BOUNDS)
    drives = [jh.sinusoidal_flux(50.0, 0.2, samples_per_period=n) for n in (40, 56)]
    H = [np.asarray(jh.simulate_flux(SOFT, d, form).observed("H")) for d in drives]
    both = jh.FluxProblem(H, drives, space, variant=form)
    alone = [jh.FluxProblem([h], [d], space, variant=form) for h, d in zip(H, drives,
                                                                           strict=True)]
    assert both.data.shape == (2, drives[1].n_observed)
    assert [int(g.count) for g in both.groups] == [d.n_observed for d in drives]
    off = SOFT.replace(k=1.3 * float(SOFT.k), a=0.8 * float(SOFT.a))
    for params, exact in ((SOFT, True), (off, False)):
        together = both.group_residuals(params)
        for i, problem in enumerate(alone):
            n = drives[i].n_observed
            (own,) = problem.group_residuals(params)
            np.testing.assert_allclose(np.asarray(together[i])[:n], np.asarray(own),
                                       rtol=1e-9, atol=1e-9 * float(np.max(np.abs(H[i]))))
            assert not np.any(np.asarray(together[i])[n:])
            assert (float(np.max(np.abs(own))) < 1e-6 * float(np.max(np.abs(H[i])))) == exact
    n = drives[1].n_observed
    with pytest.raises(ValueError, match=rf"record 1: its field data .* shape \({n},\)"):
        jh.FluxProblem([H[0], H[1][:-3]], drives, space, variant=form)
    phase = np.linspace(0.0, 2.0 * np.pi, 41)
    shifted = jh.FluxDrive(phase / 300.0, 0.2 * np.cos(phase))  # (no run-in from B = 0)
    with pytest.raises(ValueError, match="record 0: its drive must start at B = 0"):
        jh.FluxProblem([np.ones(41), H[1]], [shifted, drives[1]], space)


def test_a_model_of_equal_sets_per_loop_is_one_material():
    """`jaxhyst.cli.models.one_set`: a joint fit's per-loop sets that are all equal (every
    parameter shared) become one set — parameters, form and losses — and sets that
    differ (``--per-loop``) or a condition law stay as they are."""
    from jaxhyst.cli.models import one_set

    def stacked(*sets):
        return jax.tree.map(lambda *x: jnp.stack(x), *sets)

    form = jh.PlayJA(spread=0.8, cells=8)
    same = jh.Model(stacked(SOFT, SOFT), NO_ACTUATOR, stacked(form, form), 1,
                    stacked(LOSSES, LOSSES))
    one = one_set(same)
    assert np.ndim(one.params.Ms) == 0 and np.ndim(one.variant.spread) == 0
    assert float(one.losses.excess) == float(LOSSES.excess) and one.variant.cells == 8
    differ = jh.Model(stacked(SOFT, SOFT.replace(k=25.0)), NO_ACTUATOR, jh.ClassicJA())
    assert one_set(differ) is differ
    assert one_set(one) is one


@pytest.mark.extended  # (a rate-dependent joint fit and its predictions by the command line)
def test_a_shared_joint_fit_is_saved_as_one_set_and_a_rate_model_predicts_another_frequency(
        tmp_path, capsys):
    """A joint fit that shared every parameter saves one material's set (``predict`` and
    ``simulate --model`` take it; it used to be refused as "one set per loop"), and
    ``predict --frequency`` runs each loop's waveform at that frequency with a
    rate-dependent model — its times scaled, not only its label changed — from the
    result and the saved model alike; without a frequency column, one line."""
    from jaxhyst.cli import main

    losses = jh.Losses(relax=2e-4)
    lines = ["loop,t,H,B,frequency"]
    for i, f in enumerate((50.0, 100.0)):
        d = jh.sinusoidal_field(f, 120.0, 0.0, samples_per_period=160)
        sim = jh.simulate(SOFT, NO_ACTUATOR, d, jh.ClassicJA(), 4, losses)
        t, H, B = (np.asarray(d.observed(x)) for x in (d.t, d.H, _B(sim)))
        lines += [f"{i},{float(a - t[0])!r},{float(h)!r},{float(b)!r},{f!r}"
                  for a, h, b in zip(t, H, B, strict=True)]
    data, out, model = tmp_path / "bh.csv", tmp_path / "r.json", tmp_path / "m.eqx"
    data.write_text("\n".join(lines) + "\n")
    assert main(["identify", str(data), "--joint", "--variant", "classic", "--substeps", "4",
                 "--losses", "relax", "--method", "lm", "--starts", "1", "--max-steps", "3",
                 "--intervals", "linear", "--progress", "0", "--out", str(out),
                 "--save-model", str(model)]) in (0, 3, 4)
    capsys.readouterr()
    saved = jh.load_model(model)
    assert np.ndim(saved.params.Ms) == 0 and np.ndim(saved.losses.relax) == 0
    predicted = {}
    for source in (out, model):
        for f in (None, 50.0, 400.0):
            csv = tmp_path / f"p{f}.csv"
            assert main(["predict", str(source), str(data), "--loop", "0", "--out", str(csv),
                         "--json", *(["--frequency", str(f)] if f else [])]) == 0
            (row,) = json.loads(capsys.readouterr().out)["loops"]
            assert ("not_compared" in row) == (f == 400.0), row
            predicted[source, f] = np.genfromtxt(csv, delimiter=",", names=True)["predicted"]
        np.testing.assert_allclose(predicted[source, 50.0], predicted[source, None], rtol=1e-9)
        lag = np.max(np.abs(predicted[source, 400.0] - predicted[source, None]))
        assert lag > 0.05 * np.max(np.abs(predicted[source, None])), lag
    np.testing.assert_allclose(predicted[model, 400.0], predicted[out, 400.0], rtol=1e-7,
                               atol=1e-9)
    bare = tmp_path / "bare.csv"  # (times, no frequency column)
    bare.write_text("\n".join(",".join(x.split(",")[:4]) for x in lines) + "\n")
    assert main(["predict", str(out), str(bare), "--loop", "0", "--frequency", "400"]) == 2
    assert "give the file a 'frequency' column" in capsys.readouterr().err
    assert main(["simulate", "--model", str(model), "--field-amplitude", "100",
                 "--frequency", "200", "--json"]) == 0
