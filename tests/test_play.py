"""The forms of pinning cells (`jaxhyst.PlayJA`, `jaxhyst.PreisachJA`): against an
independent solve (tests/helpers.py), return-point memory and wiping out, loop shapes
that change with the amplitude, derivatives (the time loop's rule against plain AD and
central differences), batching, the B- and M-driven forms round trip, the losses, and
identification of their parameters from their own loops."""

from __future__ import annotations

import json

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import pytest
from helpers import reference_play

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR, fix_structural
from jaxhyst.model import timeloop
from jaxhyst.model.paths import hysteresis_path, loop_parameters, path_form

MU0 = 4e-7 * np.pi
#: A soft material (a, k of tens of A/m) with a little mean field.
SOFT = jh.Parameters(Ms=4e5, lambda_s=0.0, a=30.0, k=40.0, alpha=2e-5, c=0.3, E=1.0,
                     Kz=1.0, Mz=1.0, Cz=0.0)
FORMS = [jh.PlayJA(spread=0.8, cells=12), jh.PreisachJA(spread=0.8, a_rev=20.0, cells=12)]
IDS = ["play", "preisach"]


def _with(form, **own):
    """``form`` with some of its own parameters replaced."""
    names = list(own)
    return eqx.tree_at(lambda f: [getattr(f, n) for n in names], form,
                       [jnp.asarray(v, dtype=jnp.float64) for v in own.values()])


def _field(points, n=40):
    """A piecewise-linear field through ``points`` (A/m), n samples per leg."""
    legs = [np.linspace(a, b, n, endpoint=False) for a, b in zip(points[:-1], points[1:],
                                                                   strict=True)]
    return np.concatenate([*legs, [points[-1]]])


#: A major loop, then a minor loop inside it traversed twice.
H_MINOR = _field([0, 200, -200, 200, 50, 120, 50, 120, 50])


def _M(form, p, H, substeps=2, driver="H"):
    Y, _, _, _ = hysteresis_path(form, p, None, jnp.asarray(H), substeps=substeps, driver=driver)
    return np.concatenate([[0.0], np.asarray(Y[:, -1])])


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_the_path_agrees_with_an_independent_solve(form):
    M = _M(form, SOFT, H_MINOR)
    ref = reference_play(SOFT, float(form.spread), form.cells, H_MINOR,
                         getattr(form, "a_rev", None))
    assert np.max(np.abs(M - ref)) <= 1e-9 * SOFT.Ms


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_minor_loops_close_on_themselves_and_a_larger_excursion_wipes_them_out(form):
    M = _M(form, SOFT, H_MINOR)
    visits = lambda h: [M[i] for i in range(len(H_MINOR)) if abs(H_MINOR[i] - h) < 1e-9]  # noqa
    at_120, at_50 = visits(120.0), visits(50.0)
    # the second traversal of the minor loop repeats the first (return-point memory)
    np.testing.assert_allclose(at_120[-1], at_120[-2], rtol=1e-12)
    np.testing.assert_allclose(at_50[-1], at_50[-2], rtol=1e-12)
    # and a return to the major loop's tip wipes the minor loop out: the descending
    # branch from +200 is the same before and after it
    n = 40
    M2 = _M(form, SOFT, _field([0, 200, -200, 200, 50, 120, 50, 200, -200], n=n))
    first, again = M2[n:2 * n + 1], M2[7 * n:8 * n + 1]  # the two legs from +200 to −200
    np.testing.assert_allclose(again, first, rtol=0, atol=1e-9 * SOFT.Ms)


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_the_loop_shape_changes_with_the_amplitude(form):
    """From the demagnetized state a small loop moves only the cells with small pinning
    fields: the loop's area grows faster than Hm² at small amplitudes (the Rayleigh
    region, ~Hm³) and slower than Hm² near saturation, and its shape — area over
    2·Hm·Mm — changes with the amplitude (a Jiles–Atherton loop's scale of it does not
    follow from one parameter set)."""
    p = SOFT.replace(alpha=0.0)
    areas, shapes = [], []
    for Hm in (15.0, 30.0, 80.0, 400.0):
        H = _field([0, Hm, -Hm, Hm, -Hm, Hm], n=200)
        M = _M(form, p, H)
        last = slice(-401, None)  # the last full cycle
        areas.append(abs(np.trapezoid(M[last], H[last])))
        shapes.append(areas[-1] / (2 * Hm * np.max(M[last])))
    assert areas[1] / areas[0] > 2.0 ** 2.5
    assert areas[3] / areas[2] < (400 / 80) ** 2
    assert shapes[2] > 2 * shapes[0] and shapes[2] > 1.5 * shapes[3]


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_the_derivative_rule_equals_plain_ad_and_central_differences(form):
    H = jnp.asarray(_field([0, 150, -150, 150, 40, 90], n=12))
    loop = path_form(form)

    def path(x, H, plain=False):
        p = SOFT.replace(Ms=x[0], a=x[1], k=x[2], alpha=x[3], c=x[4])
        f = _with(form, spread=x[5], **({"a_rev": x[6]} if hasattr(form, "a_rev") else {}))
        theta = loop_parameters(f, p)
        run = timeloop.run_path_plain if plain else timeloop.run_path
        return run(theta, None, H, form=loop, substeps=2)

    x = jnp.array([4e5, 30.0, 40.0, 2e-5, 0.3, 0.8, 20.0])
    J = jax.jit(jax.jacfwd(path))(x, H)
    J_plain = jax.jit(jax.jacfwd(lambda x, H: path(x, H, True)))(x, H)
    n = 7 if hasattr(form, "a_rev") else 6
    J, J_plain = J[..., :n], J_plain[..., :n]
    scale = jnp.max(jnp.abs(J_plain), axis=(0, 1))
    assert float(jnp.max(jnp.max(jnp.abs(J - J_plain), axis=(0, 1)) / scale)) < 1e-10
    JH = jax.jit(jax.jacfwd(path, argnums=1))(x, H)
    JH_plain = jax.jit(jax.jacfwd(lambda x, H: path(x, H, True), argnums=1))(x, H)
    assert float(jnp.max(jnp.abs(JH - JH_plain)) / jnp.max(jnp.abs(JH_plain))) < 1e-10
    f = jax.jit(path)
    for i in range(7 if hasattr(form, "a_rev") else 6):  # central differences, Richardson
        h = 1e-4 * float(abs(x[i]))

        def d(h, i=i):
            return (f(x.at[i].add(h), H) - f(x.at[i].add(-h), H)) / (2 * h)

        fd = (4 * d(h / 2) - d(h)) / 3
        assert float(jnp.max(jnp.abs(J[..., i] - fd)) / jnp.max(jnp.abs(fd))) < 1e-6, i


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_a_batch_equals_single_runs(form):
    X = jnp.asarray([[30.0, 40.0, 0.8], [20.0, 60.0, 0.4], [45.0, 25.0, 1.5]])

    def M(x):
        f = _with(form, spread=x[2])
        Y, _, _, _ = hysteresis_path(f, SOFT.replace(a=x[0], k=x[1]), None,
                                  jnp.asarray(H_MINOR), substeps=2)
        return Y

    batch = jax.jit(jax.vmap(M))(X)
    for i in range(3):
        np.testing.assert_allclose(batch[i], jax.jit(M)(X[i]), rtol=0, atol=1e-9 * SOFT.Ms)


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_the_b_and_m_driven_forms_return_the_field(form):
    M = _M(form, SOFT, H_MINOR)
    B = MU0 * (H_MINOR + M)
    M_of_B = _M(form, SOFT, B, driver="B")
    np.testing.assert_allclose(B / MU0 - M_of_B, H_MINOR, rtol=0, atol=1e-8 * 200)
    H_of_M = _M(form, SOFT, M, driver="M")
    np.testing.assert_allclose(H_of_M, H_MINOR, rtol=0, atol=1e-6 * 200)
    # and through the public B-driven simulation, the energy per cycle is ∮ H dB
    drive = jh.sinusoidal_flux(50.0, 0.4, 0.0, samples_per_period=400)
    sim = jh.simulate_flux(SOFT, drive, form)
    H_obs, B_obs = np.asarray(drive.observed(sim.H)), np.asarray(drive.observed(sim.B))
    area = np.sum(0.5 * (H_obs[1:] + H_obs[:-1]) * np.diff(B_obs))
    assert abs(float(sim.cycle_energy) / area - 1) < 1e-3


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_the_losses_widen_the_loop_and_vanish_without_coefficients(form):
    drive = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=200)
    static = jh.simulate(SOFT, NO_ACTUATOR, drive, form)
    # (with losses, simulate's accuracy check would compile the drive at half the step)
    zero = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, form, losses=jh.Losses(0.0, 0.0))
    np.testing.assert_allclose(np.asarray(zero.M), np.asarray(static.M), rtol=0,
                               atol=1e-12 * SOFT.Ms)
    lossy = jh.simulate_unchecked(SOFT, NO_ACTUATOR, drive, form, losses=jh.Losses(0.05, 0.5))

    def area(sim):
        H, B = np.asarray(drive.observed(sim.H)), MU0 * np.asarray(drive.observed(
            sim.H_hyst + sim.M))
        return abs(np.sum(0.5 * (H[1:] + H[:-1]) * np.diff(B)))

    assert area(lossy) > 1.2 * area(static)


def test_the_losses_stay_finite_where_the_feedback_is_beyond_the_anhysteretics_stability():
    # α·Ms/(3a) = 1.5 lies inside a box a user may give (α̃ ≤ 1e-3): the field balance's
    # first guess and Newton steps used a slope that is not finite there (H_hyst NaN)
    p = SOFT.replace(Ms=8.08e5, a=100.0, k=51.8, alpha=5.56e-4, c=0.84)
    drive = jh.sinusoidal_field(50.0, 200.0, 0.0, samples_per_period=100)
    sim = jh.simulate_unchecked(p, NO_ACTUATOR, drive, jh.PlayJA(2.46),
                                losses=jh.Losses(0.87, 3.9), substeps=1)
    for name in ("H_hyst", "M"):
        assert np.all(np.isfinite(np.asarray(getattr(sim, name)))), name


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_its_parameters_are_recovered_from_its_own_loops(form):
    truth = SOFT.replace(Ms=3.5e5, a=25.0, k=30.0, alpha=1e-5, c=0.25)
    own = {"spread": 0.6, **({"a_rev": 15.0} if hasattr(form, "a_rev") else {})}
    true_form = _with(form, **own)
    drives, data = [], []
    for Hm in (60.0, 120.0, 400.0):  # three amplitudes, fitted jointly
        d = jh.sinusoidal_field(10.0, Hm, 0.0, samples_per_period=120)
        drives.append(d)
        sim = jh.simulate_unchecked(truth, NO_ACTUATOR, d, true_form, substeps=1)
        data.append(np.asarray(d.observed(MU0 * (sim.H + sim.M))))
    box = {"Ms": (2e5, 6e5), "a": (5.0, 100.0), "k": (5.0, 100.0), "alpha": (-1e-4, 1e-4),
           "c": (0.0, 1.0), "lambda_s": (0, 1e-3), "E": (1, 2), "Kz": (1, 2), "Mz": (1, 2),
           "Cz": (0, 1)}
    bounds = jh.Bounds.from_dict(box)
    space = jh.ParameterSpace.for_model(bounds, form=form, n_loops=3,
                                        fixed=fix_structural(bounds))
    problem = jh.JointProblem(data, drives, NO_ACTUATOR, space, output="flux_density",
                              variant=form, substeps=1)
    start = space.u_from_params((truth.replace(a=35.0, k=20.0, c=0.4),
                                 _with(form, **{n: 1.3 * v for n, v in own.items()})))
    result = jh.solve(problem, start, max_steps=100, report=False)
    p, f = result.params
    for name, want in (("Ms", 3.5e5), ("a", 25.0), ("k", 30.0), ("c", 0.25)):
        assert abs(float(getattr(p, name)[0]) / want - 1) < 1e-5, name
    for name, want in own.items():
        assert abs(float(getattr(f, name)[0]) / want - 1) < 1e-5, name


@pytest.mark.parametrize("form", FORMS, ids=IDS)
def test_a_fit_of_magnetic_loops_skips_the_substep_error_it_cannot_have(form):
    """The cells are exact along each interval: the flux density at the samples is the
    same at 1 and 2 substeps (to round-off), so `sampling_error` does not estimate it
    (None) on a drive coarse enough that it would for the Jiles–Atherton form."""
    from jaxhyst.identify.signal import _predictions, sampling_error

    d = jh.sinusoidal_field(10.0, 150.0, 0.0, samples_per_period=24)  # (coarse: 8 % steps)
    sim = jh.simulate(SOFT, NO_ACTUATOR, d, form, substeps=1)
    data = np.asarray(d.observed(MU0 * (sim.H + sim.M)))
    bounds = jh.Bounds(SOFT.replace(a=5.0, k=5.0), SOFT.replace(a=100.0, k=100.0))
    problems = {}
    for name, variant, S in (("cells", form, 1), ("finer", form, 2),
                             ("classic", jh.ClassicJA(), 1)):
        space = jh.ParameterSpace.for_model(bounds, form=variant, n_loops=1,
                                            fixed=fix_structural(bounds))
        problems[name] = (jh.JointProblem([data], [d], NO_ACTUATOR, space,
                                          output="flux_density", variant=variant,
                                          substeps=S), space)
    problem, space = problems["cells"]
    params = space.params_from_u(space.u_from_params((SOFT, form)))
    coarse, fine = _predictions(problem, problems["finer"][0], params)
    assert np.max(np.abs(np.asarray(coarse) - np.asarray(fine))) <= 1e-12 * np.max(np.abs(data))
    assert sampling_error(problem, params) is None
    problem, space = problems["classic"]
    assert sampling_error(problem, space.params_from_u(space.u_from_params(SOFT))) > 0
    # a B-driven fit of the same form (its output, the field, is not a magnetic output
    # of the H-driven kind): estimated as before, not refused
    fd = jh.sinusoidal_flux(10.0, 0.3, 0.0, samples_per_period=24)
    H = np.asarray(fd.observed(jh.simulate_flux(SOFT, fd, form, substeps=1).H))
    space = jh.ParameterSpace.for_model(bounds, form=form, fixed=fix_structural(bounds))
    flux = jh.FluxProblem([H], [fd], space, output="field", variant=form, substeps=1)
    error = sampling_error(flux, space.params_from_u(space.u_from_params((SOFT, form))))
    assert error is None or np.isfinite(error)



def test_predicting_a_materials_loop_checks_its_magnetization_not_a_displacement(
        tmp_path, capsys, monkeypatch):
    """`predict` (and the leave-one-out, which predicts through the same function) of a
    B(H) loop simulates a material: `simulate` checks the sampling of its M alone, not
    of the placeholder displacement of the actuator a magnetic fit carries (whose
    structure, resonating at ~1 kHz, warned of an error in y on loops of a few hundred
    samples a period that the prediction never shows), and the prediction is the same."""
    from jaxhyst.cli import main

    d = jh.sinusoidal_field(10.0, 150.0, 0.0, samples_per_period=24)
    form = jh.PlayJA(spread=0.8, cells=12)
    sim = jh.simulate(SOFT, NO_ACTUATOR, d, form, substeps=1)
    H, B = np.asarray(d.observed(d.H)), np.asarray(d.observed(MU0 * (sim.H + sim.M)))
    data, out = tmp_path / "bh.csv", tmp_path / "r.json"
    data.write_text("H,B\n" + "".join(f"{float(h)!r},{float(b)!r}\n"
                                       for h, b in zip(H, B, strict=True)))
    assert main(["identify", str(data), "--variant", "play", "--cells", "12", "--method",
                 "lm", "--starts", "1", "--max-steps", "2", "--intervals", "linear",
                 "--progress", "0", "--out", str(out)]) in (0, 3, 4)
    capsys.readouterr()
    plain = jh.simulate
    seen = []

    def simulate(params, actuator, *args, **kwargs):
        seen.append(actuator)
        return plain(params, actuator, *args, **kwargs)

    monkeypatch.setattr(jh, "simulate", simulate)
    assert main(["predict", str(out), "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)["loops"]
    assert seen and all(a.magnetization_only for a in seen)
    monkeypatch.undo()
    assert main(["predict", str(out), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["loops"][0]["rms"] == row["rms"]
