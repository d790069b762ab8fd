"""Parameters as smooth functions of the operating condition, prediction of held-out
records, and the ``predict`` / ``--leave-one-out`` workflow (issue 31)."""

from __future__ import annotations

import json
import warnings

import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst.cli import main
from jaxhyst.identify.joint import NO_ACTUATOR

FREQS = (100.0, 200.0, 400.0, 800.0, 1600.0)
HELD = 2  # 400 Hz: its nearest fitted frequencies are 200 and 800 Hz
F_REF = float(np.exp(np.mean(np.log([f for i, f in enumerate(FREQS) if i != HELD]))))
K_SLOPE, C_SLOPE = 0.3, 0.05  # k ∝ f^0.3, c = c_ref + 0.05·ln(f/f_ref)


def _truth_at(f):
    """The generating functions, written out here (not through ConditionModel)."""
    p = jh.TABLE1_TRUE
    x = np.log(f / F_REF)
    return jh.Parameters(**{**{n: float(getattr(p, n)) for n in jh.NAMES},
                            "k": float(p.k) * np.exp(K_SLOPE * x),
                            "c": float(p.c) + C_SLOPE * x})


def _loop(p, amp=12e3, n=101):
    H = amp * np.cos(2 * np.pi * np.arange(n) / (n - 1))
    drive = jh.drive_from_record(None, H)
    sim = jh.simulate_unchecked(p, NO_ACTUATOR, drive, variant=jh.ClassicJA(), substeps=4)
    return drive, np.asarray(sim.observed("M"))


def _bounds():
    p = np.asarray(jh.TABLE1_TRUE.to_array())
    lo, hi = 0.5 * p, 1.5 * p
    a, c = jh.NAMES.index("alpha"), jh.NAMES.index("c")
    lo[a], hi[a] = 0.5 * p[a], 1.5 * p[a]
    lo[c], hi[c] = 0.0, 0.6
    return jh.Bounds(jh.Parameters.from_array(np.minimum(lo, hi)),
                     jh.Parameters.from_array(np.maximum(lo, hi)))


def test_a_law_the_conditions_cannot_determine_is_refused_in_one_line():
    """A parameter's law has 1 + (its features × degree) coefficients and needs as many
    distinct conditions, spread along each feature (records within 1 % are one
    condition): otherwise the fit would return a slope the data do not fix."""
    law = jh.ConditionModel({"k": "log_amplitude"})
    assert law.undetermined(jh.Conditions(amplitude=[10.0, 20.0])) is None
    why = law.undetermined(jh.Conditions(amplitude=[20.0, 20.1, 20.05]))
    assert "2 coefficients, but the 3 records are at 1 condition" in why, why
    assert "determines only 1" in why and why.count("\n") == 0
    quadratic = jh.ConditionModel({"k": "log_amplitude"}, degree=2)
    assert "3 coefficients" in quadratic.undetermined(jh.Conditions(amplitude=[10.0, 20.0]))
    assert quadratic.undetermined(jh.Conditions(amplitude=[10.0, 20.0, 40.0])) is None
    # two features that move together: three conditions, no third direction
    f = np.array([100.0, 200.0, 400.0])
    both = jh.ConditionModel({"c": ("log_f", "T")})
    together = jh.Conditions(frequency=f, temperature=20.0 + 10.0 * np.log2(f / 100.0))
    assert "3 records are at 3 conditions" in both.undetermined(together)
    assert both.undetermined(jh.Conditions(frequency=f, temperature=[20.0, 40.0, 25.0])) \
        is None
    # the problem refuses it (the command line says it after "--vary: ")
    H = 12e3 * np.cos(2 * np.pi * np.arange(101) / 100)
    M = 5e5 * np.tanh((H + 2e3 * np.sign(np.gradient(-H))) / 4e3)
    records = jh.JointProblem([M, M], [jh.drive_from_record(None, H)] * 2, NO_ACTUATOR,
                              jh.per_record_space(_bounds(), 2), output="magnetization",
                              variant=jh.ClassicJA())
    with pytest.raises(ValueError, match="records are at 1 condition"):
        jh.ConditionProblem(records, jh.Conditions(amplitude=[12e3, 12.05e3]), law,
                            jh.condition_space(_bounds(), law))


def test_condition_model_evaluates_power_laws_and_rejects_bad_input():
    m = jh.ConditionModel({"k": "log_f", "c": ("log_f", "T")}, degree=2)
    assert m.coefficient_names() == ["k:log_f", "k:log_f^2", "c:log_f", "c:log_f^2",
                                     "c:T", "c:T^2"]
    cond = jh.Conditions(frequency=[100.0, 400.0], temperature=[20.0, 40.0])
    fm = m.fitted_to(cond)
    assert dict(fm.reference) == {"log_f": pytest.approx(200.0), "T": 30.0}
    X = fm.feature_values(cond)
    np.testing.assert_allclose(X, [[np.log(0.5), -1.0], [np.log(2.0), 1.0]])
    coef = {"k": 10.0, "k:log_f": 0.5, "k:log_f^2": 0.1, "c": 0.2, "c:log_f": 0.01,
            "c:log_f^2": 0.0, "c:T": 0.03, "c:T^2": 0.002, "Ms": 1e6}
    v = fm.evaluate(coef, X)
    x = np.log(2.0)
    np.testing.assert_allclose(v["k"], [10 * np.exp(-0.5 * x + 0.1 * x * x),
                                        10 * np.exp(0.5 * x + 0.1 * x * x)])
    np.testing.assert_allclose(v["c"], [0.2 - 0.01 * x - 0.03 + 0.002,
                                        0.2 + 0.01 * x + 0.03 + 0.002])
    np.testing.assert_allclose(v["Ms"], [1e6, 1e6])  # shared: constant
    with pytest.raises(ValueError, match="is not a parameter"):
        jh.ConditionModel({"kk": "log_f"})
    with pytest.raises(ValueError, match="the features are"):
        jh.ConditionModel({"k": "pressure"})
    with pytest.raises(ValueError, match="degree must be 1 or 2"):
        jh.ConditionModel({"k": "log_f"}, degree=3)
    with pytest.raises(ValueError, match="carry no temperature"):
        m.fitted_to(jh.Conditions(frequency=[100.0, 400.0]))
    with pytest.raises(ValueError, match="must be > 0"):
        jh.Conditions(frequency=[100.0, -1.0])
    with pytest.raises(ValueError, match="one value per record"):
        jh.Conditions(frequency=[100.0, 200.0], temperature=[20.0])
    with pytest.raises(ValueError, match=r"\[5\] are not among the 3 records"):
        jh.split_records(3, 5)
    # far outside the fitted range: allowed, with a warning that says how far
    with pytest.warns(jh.ConditionWarning, match="a factor 10 beyond"):
        fm.warn_outside(jh.Conditions(frequency=[4000.0], temperature=[30.0]))
    with pytest.warns(jh.ConditionWarning, match="5 K beyond"):
        fm.warn_outside(jh.Conditions(frequency=[200.0], temperature=[45.0]))
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        fm.warn_outside(cond)  # inside: silent


@pytest.mark.slow  # a study (~4 min cold); benchmarks/bench_heldout_frequency.py reports it
def test_smooth_in_frequency_recovers_its_generating_functions_and_predicts_a_held_out_frequency():
    """Loops at four frequencies made with k ∝ f^0.3 and c linear in ln f (small noise):
    the condition problem recovers both slopes within their intervals, and predicts the
    fifth frequency (400 Hz, held out) far better than the fit at the nearest frequency."""
    rng = np.random.default_rng(3)
    loops = [_loop(_truth_at(f)) for f in FREQS]
    fit_idx = [i for i in range(len(FREQS)) if i != HELD]
    data = []
    for i in fit_idx:
        M = loops[i][1]
        data.append(M + 1e-5 * np.max(np.abs(M)) * rng.standard_normal(M.shape))
    bounds = _bounds()
    fixed = {n: float(getattr(jh.TABLE1_TRUE, n))
             for n in ("Ms", "lambda_s", "E", "Kz", "Mz", "Cz")}
    records = jh.JointProblem(data, [loops[i][0] for i in fit_idx], NO_ACTUATOR,
                              jh.per_record_space(bounds, len(fit_idx)), output="magnetization",
                              variant=jh.ClassicJA(), substeps=4)
    model = jh.ConditionModel({"k": "log_f", "c": "log_f"})
    problem = jh.ConditionProblem(records, jh.Conditions(frequency=[FREQS[i] for i in fit_idx]),
                                  model, jh.condition_space(bounds, model, fixed=fixed))
    assert dict(problem.condition_model.reference)["log_f"] == pytest.approx(F_REF)
    p0 = jh.TABLE1_TRUE
    truth = {**{n: float(getattr(p0, n)) for n in jh.NAMES}, "k:log_f": K_SLOPE,
             "c:log_f": C_SLOPE}
    start = {n: v * (1.1 if n != "c:log_f" else 0.5) for n, v in truth.items()}
    res = jh.solve(problem, start, solver="lm", max_steps=100)
    rep = res.report
    for name in ("k", "k:log_f", "c", "c:log_f", "a", "alpha"):
        z = abs(float(res.params[name]) - truth[name]) / rep.std_errors[name]
        assert z < 4, (name, float(res.params[name]), truth[name], rep.std_errors[name])
    assert rep.std_errors["k:log_f"] < 0.01 and rep.std_errors["c:log_f"] < 0.005

    # predict the held-out frequency from the fitted functions …
    f_held = FREQS[HELD]
    p_held = problem.at(res.params, jh.Conditions(frequency=[f_held]))
    p_held = jh.Parameters.from_array(np.asarray(p_held.to_array())[0])
    drive, M_held = loops[HELD]
    err_smooth = np.sqrt(np.mean((np.asarray(jh.simulate(
        p_held, NO_ACTUATOR, drive, variant=jh.ClassicJA(), substeps=4).observed("M"))
        - M_held) ** 2))
    held_records = jh.JointProblem([M_held], [drive], NO_ACTUATOR,
                                   jh.per_record_space(bounds, 1), output="magnetization",
                                   variant=jh.ClassicJA(), substeps=4)
    assert problem.held_out_errors(res.params, held_records, jh.Conditions(
        frequency=[f_held])) == [pytest.approx(err_smooth, rel=1e-9)]
    padded = jh.JointProblem([M_held], [drive], NO_ACTUATOR, jh.per_record_space(bounds, 1),
                             output="magnetization", variant=jh.ClassicJA(), substeps=4,
                             pad_to=(drive.run_in + 3, drive.n_observed + 5))
    assert problem.held_out_errors(res.params, padded, jh.Conditions(  # (padding: no sample)
        frequency=[f_held])) == [pytest.approx(err_smooth, rel=1e-9)]
    far = {**dict(res.params), "k": 1e12}  # (k beyond any material's at every frequency)
    with pytest.warns(jh.ConditionWarning, match="held-out record 0: the condition law "
                                                 "gives k = .* no prediction"):
        assert problem.held_out_errors(far, held_records, jh.Conditions(
            frequency=[f_held])) == [np.inf]
    # … against a fit at the nearest measured frequency (200 Hz), used as it is
    near = 1
    single = jh.Problem(data[fit_idx.index(near)], loops[near][0], NO_ACTUATOR,
                        jh.ParameterSpace(bounds, fixed), output="magnetization",
                        variant=jh.ClassicJA(), substeps=4)
    r_near = jh.solve(single, jh.Parameters(**{**{n: float(getattr(p0, n)) for n in jh.NAMES},
                                               "k": 1.1 * float(p0.k)}),
                      solver="lm", max_steps=100, report=False)
    err_near = np.sqrt(np.mean((np.asarray(jh.simulate(
        r_near.params, NO_ACTUATOR, drive, variant=jh.ClassicJA(), substeps=4).observed("M"))
        - M_held) ** 2))
    scale = np.max(np.abs(M_held))
    assert err_smooth < 1e-4 * scale, err_smooth / scale  # the noise level: 1e-5
    assert err_smooth < err_near / 20, (err_smooth, err_near)


def _write_conditions_file(path):
    """Three B(H) loops at 100, 400 and 1600 Hz made with k ∝ f^0.3, a frequency column."""
    rows = ["loop,frequency [kHz],H [A/m],B [T]"]
    for i, f in enumerate((100.0, 400.0, 1600.0)):
        drive, M = _loop(_truth_at(f))
        H = np.asarray(drive.observed(drive.H))
        B = 4e-7 * np.pi * (H + M)
        rows += [f"{i},{f / 1e3!r},{float(h)!r},{float(b)!r}" for h, b in zip(H, B, strict=True)]
    path.write_text("\n".join(rows) + "\n")


@pytest.mark.extended  # (a leave-one-out through the command line)
def test_predict_reproduces_the_fit_and_leave_one_out_reports_each_loop(tmp_path, capsys):
    data = tmp_path / "loops.csv"
    _write_conditions_file(data)
    out = tmp_path / "fit.json"
    common = ["--joint", "--method", "lm", "--variant", "classic", "--substeps", "4",
              "--max-steps", "15", "--fix", f"Ms={float(jh.TABLE1_TRUE.Ms)!r}",
              "--intervals", "linear"]  # (the intervals are not what this test checks)
    law = tmp_path / "law.eqx"
    rc = main(["identify", str(data), *common, "--vary", "k:log_f", "--leave-one-out",
               "--out", str(out), "--save-model", str(law), "--json"])
    assert rc in (0, 3, 4)
    printed = json.loads(capsys.readouterr().out)
    saved = json.loads(out.read_text())
    assert set(saved["coefficients"]) >= {"k", "k:log_f", "a", "alpha", "c"}
    held = saved["leave_one_out"]["forms"]["classic"]["rows"]
    assert saved["leave_one_out"]["kept"] == "classic"
    assert [r["loop"] for r in held] == [0, 1, 2] == [r["loop"] for r in printed[
        "leave_one_out"]["forms"]["classic"]["rows"]]
    for r in held:
        assert np.isfinite(r["rms"]) and r["rms"] > 0 and r["data_scale"] > 0
        assert r["own_rms"] > 0 and r["nearest_rms"] > 0 and "outside" in r
    # how far each fold extrapolated: 100 and 1600 Hz lie a factor 4 beyond the others
    assert [r["beyond"] for r in held] == [{"frequency": pytest.approx(4.0)}, {},
                                            {"frequency": pytest.approx(4.0)}]

    # predict from the result file: exactly the fit's own prediction of each loop
    pred_csv = tmp_path / "pred.csv"
    assert main(["predict", str(out), "--out", str(pred_csv), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["loops"]
    from jaxhyst.cli.problems import load_result

    _, _, problem, coef = load_result(out)
    want = np.asarray(problem.records.predict_loops(problem.per_record(coef)))
    mask = np.asarray(problem.records.mask)
    got = np.genfromtxt(pred_csv, delimiter=",", names=True)
    for i in range(3):
        mine = got["predicted"][got["loop"] == i]
        np.testing.assert_array_equal(mine, want[i][mask[i]])
        B = got["data"][got["loop"] == i]
        assert rows[i]["rms"] == pytest.approx(np.sqrt(np.mean((mine - B) ** 2)), rel=1e-12)
        assert rows[i]["unit"] == "T"

    # the saved model predicts as the result does: each loop within the fitted
    # conditions, with the error the folds lead one to expect
    assert main(["predict", str(law), str(data), "--json"]) == 0
    from_model = json.loads(capsys.readouterr().out)["loops"]
    for r, m in zip(rows, from_model, strict=True):
        assert m["extrapolation"] == r["extrapolation"] == ""
        assert m["expected_relative_error"] == r["expected_relative_error"] > 0
        assert m["rms"] == pytest.approx(r["rms"], rel=1e-6)
    # at 3200 Hz (a factor 2 beyond the fitted 100–1600 Hz, less than the folds' 4) the
    # folds' extrapolation error is expected; at 16 kHz (×10) no number is given
    for f, within_reach in ((3200.0, True), (16000.0, False)):
        assert main(["predict", str(law), str(data), "--loop", "1", "--frequency", str(f),
                     "--json"]) == 0
        row = json.loads(capsys.readouterr().out)["loops"][0]
        assert row["extrapolation"].startswith("frequency")
        assert ("expected_relative_error" in row) == within_reach == ("beyond_folds" not in row)
        if not within_reach:
            assert row["beyond_folds"]["frequency"] == [pytest.approx(10.0), pytest.approx(4.0)]

    # the saved model keeps the law: at 400 Hz it is the fit's loop 1, from Python and
    # from the command line (a sinusoid of the loop's amplitude: its B within 1 %)
    model = jh.load_model(law)
    at = model.at(frequency=400.0)
    want = problem.at(coef, jh.Conditions(frequency=[400.0]))
    np.testing.assert_array_equal(np.asarray(at.params.to_array()),
                                  np.asarray(want.to_array())[0])
    sim_csv = tmp_path / "sim.csv"
    assert main(["simulate", "--model", str(law), "--frequency", "400", "--field-amplitude",
                 "12000", "--csv", str(sim_csv), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    loop1 = got["data"][got["loop"] == 1]
    assert summary["B_max_T"] == pytest.approx(np.max(loop1), rel=0.01)
    assert main(["simulate", "--model", str(law), "--field-amplitude", "12000"]) == 2
    assert "varies with the frequency; give --frequency" in capsys.readouterr().err
    # a recorded drive: the law at its peak field and the frequency given
    H1 = got["H_A_per_m"][got["loop"] == 1]
    record = tmp_path / "drive.csv"
    record.write_text("t [s],H [A/m]\n" + "".join(f"{1e-5 * i!r},{float(h)!r}\n"
                                                   for i, h in enumerate(H1)))
    assert main(["simulate", "--model", str(law), "--drive", str(record), "--frequency",
                 "400", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["B_max_T"] == pytest.approx(np.max(loop1),
                                                                          rel=0.01)

    # predict from the saved model: each loop at its file's frequency, as the result does
    assert main(["predict", str(law), str(data), "--json"]) == 0
    from_model = json.loads(capsys.readouterr().out)["loops"]
    for mine, theirs in zip(from_model, rows, strict=True):
        assert mine["rms"] == pytest.approx(theirs["rms"], rel=1e-6)
    assert main(["predict", str(law)]) == 2
    assert "give the data file" in capsys.readouterr().err
    # report from the saved law: the identifiability the fit reported (same problem,
    # rebuilt from the model file's header, same coefficients)
    assert main(["report", str(law), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)["identifiability"]
    assert again["names"] == saved["identifiability"]["names"]
    assert again["singular_values"] == pytest.approx(
        saved["identifiability"]["singular_values"], rel=1e-9)

    # at another amplitude: the loops' fields scaled, the data not compared, a figure
    fig = tmp_path / "pred.svg"
    assert main(["predict", str(out), "--amplitude", "1234", "--png", str(fig),
                 "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["loops"]
    assert all("rms" not in r and "1234" in r["not_compared"] for r in rows)
    assert fig.read_text().lstrip().startswith("<?xml")

    capsys.readouterr()
    # bad input: one line each
    for argv, msg in (
        (["predict", str(out), "--loop", "7"], "holds loops [0, 1, 2]"),
        (["predict", str(out), "--amplitude", "1e9"], "--amplitude 1e+09"),
        (["predict", str(out), "--png", str(tmp_path / "p.xyz")], "figures are written as"),
        (["identify", str(data), "--vary", "k:log_f"], "--vary needs --joint"),
        (["identify", str(data), "--joint", "--vary", "k:pressure"], "give the features"),
        (["identify", str(data), "--joint", "--vary", "k:T"], "has no temperature column"),
    ):
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert "\n" not in err and msg in err, (argv, err)
    # far outside the fitted frequencies: predicted, with a warning that says how far
    assert main(["predict", str(out), "--frequency", "1e5"]) == 0
    err = capsys.readouterr().err
    assert "outside the fitted range 100–1600 Hz" in err and "a factor 62.5" in err


def test_condition_columns_are_read_per_loop_and_must_be_constant_within_it(tmp_path):
    from jaxhyst.io import DataError, read_loops

    H = 1e3 * np.sin(2 * np.pi * np.arange(20) / 19)
    rows = ["loop,f [kHz],temp,H,B"]
    rows += [f"{k},{0.5 * (k + 1)},{25 + 10 * k},{h},{1e-4 * h}" for k in (0, 1) for h in H]
    good = tmp_path / "good.csv"
    good.write_text("\n".join(rows) + "\n")
    loops = read_loops(good)
    assert [lp.conditions for lp in loops] == [{"frequency": 500.0, "temperature": 25.0},
                                               {"frequency": 1000.0, "temperature": 35.0}]
    assert set(loops[0].signals) == {"B"}  # conditions are not signals
    bad = tmp_path / "bad.csv"
    bad.write_text("\n".join(rows[:5] + [rows[5].replace(",25,", ",26,")] + rows[6:]) + "\n")
    with pytest.raises(DataError, match="the temperature of loop 0 changes within the loop"):
        read_loops(bad)


def test_every_coefficient_of_a_law_is_printed_with_its_unit():
    from jaxhyst.analysis.wording import unit_of

    assert unit_of("k") == "A/m" and unit_of("k[1]") == "A/m"
    assert unit_of("k:log_f") == "1 (power of f)"  # k ∝ f^s
    assert unit_of("c:log_amplitude") == "1 per ln amplitude"  # c additive
    assert unit_of("a:T") == "1 per 10 K (exponent)"
    assert unit_of("alpha:T^2") == "1 per (10 K)²"


def test_loops_at_several_frequencies_fitted_rate_independent_get_a_note(tmp_path):
    from jaxhyst.cli.candidates import rate_note
    from jaxhyst.io import read_loops

    data = tmp_path / "loops.csv"
    _write_conditions_file(data)
    loops = read_loops(str(data), None)
    text = rate_note({"data": str(data)}, loops)
    assert "100–1600 Hz" in text and "--losses eddy,excess" in text
    assert "the file needs times" in text  # (read without them) …
    from jaxhyst.cli.spec import read_data  # … and with them, from the loops' frequencies

    assert "needs times" not in rate_note({"data": str(data)}, read_data(str(data)))
    assert rate_note({"losses": ["eddy"]}, loops) is None  # (rate dependent)
    assert rate_note({"vary": "k:log_f"}, loops) is None  # (a law in the frequency)
    assert rate_note({}, loops[:1]) is None
