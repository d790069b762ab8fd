"""Saved models: a JSON header and Equinox's serialised leaves, loaded back as a model
that simulates exactly as the one saved."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst.saved import ModelFileError, read_header


def test_a_saved_model_loads_and_simulates_bit_for_bit(tmp_path):
    p = jh.TABLE3[1000]
    model = jh.Model(p, jh.ACTUATOR2, jh.ClassicJA(), substeps=3)
    path = tmp_path / "act2.eqx"
    jh.save_model(path, model, data="act2.csv", rms_error=1.5e-7)
    header = read_header(path)
    assert header["variant"] == "ClassicJA" and header["substeps"] == 3
    assert header["units"]["Ms"] == "A/m" and header["meta"]["data"] == "act2.csv"
    assert {"jaxhyst", "jax", "equinox"} <= set(header["versions"])
    assert header["actuator"] == {"name": "Actuator2 (Iowa State)", "has_turns": False}
    back = jh.load_model(path)
    assert isinstance(back.variant, jh.ClassicJA) and back.substeps == 3
    np.testing.assert_array_equal(back.params.to_array(), p.to_array())
    assert back.actuator.n is None and float(back.actuator.Hb) == float(jh.ACTUATOR2.Hb)
    drive = jh.sinusoidal_field(1000.0, 8e3, 16e3, samples_per_period=40)
    np.testing.assert_array_equal(back.simulate(drive).y, model.simulate(drive).y)


def test_one_parameter_set_per_loop_round_trips(tmp_path):
    x = np.stack([jh.TABLE1_TRUE.to_array(), jh.TABLE1_TRUE.replace(k=4000.0).to_array()])
    model = jh.Model(jh.Parameters.from_array(x), jh.ACTUATOR1)
    jh.save_model(tmp_path / "joint.eqx", model)
    back = jh.load_model(tmp_path / "joint.eqx")
    np.testing.assert_array_equal(back.params.to_array(), x)
    assert float(back.actuator.n) == float(jh.ACTUATOR1.n)


def test_bad_model_files_are_refused_in_one_line(tmp_path):
    path = tmp_path / "m.eqx"
    with pytest.raises(ModelFileError, match="does not exist"):
        jh.load_model(path)
    path.write_text("t,H\n1,2\n")
    with pytest.raises(ModelFileError, match="not a jaxhyst model file"):
        jh.load_model(path)
    jh.save_model(path, jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1))
    whole = path.read_bytes()
    path.write_bytes(whole[: len(whole) - 40])  # truncated arrays
    with pytest.raises(ModelFileError, match="truncated or damaged"):
        jh.load_model(path)
    header = json.loads(whole.split(b"\n", 1)[0])
    path.write_bytes(json.dumps({**header, "variant": "MyForm"}).encode() + b"\n"
                     + whole.split(b"\n", 1)[1])
    with pytest.raises(ModelFileError, match="not built in; pass variant=MyForm"):
        jh.load_model(path)
    with pytest.raises(ModelFileError, match="variant= is a PopJA"):
        jh.load_model(path, variant=jh.PopJA())
    with pytest.raises(TypeError, match="needs a jaxhyst.Model"):
        jh.save_model(path, jh.TABLE1_TRUE)


def test_a_model_of_the_wrong_pieces_is_refused_in_one_line():
    # (a dict of values used to fail later, deep in a simulation, with an AttributeError)
    with pytest.raises(TypeError, match="Model's params must be a jaxhyst.Parameters"):
        jh.Model({"a": 7012.0}, jh.ACTUATOR1)
    with pytest.raises(TypeError, match="Model's actuator must be a jaxhyst.Actuator"):
        jh.Model(jh.TABLE1_TRUE, "Actuator1")
    with pytest.raises(TypeError, match="Model's losses must be a jaxhyst.Losses or None"):
        jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1, losses=(0.05, 0.5))


def test_a_model_written_to_a_device_leaves_the_device(tmp_path):
    jh.save_model(os.devnull, jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1))
    assert stat.S_ISCHR(os.stat(os.devnull).st_mode)


def test_a_fitted_problem_gives_its_model(tmp_path):
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=40)
    problem = jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS,
                                   variant=jh.VenkataramanJA())
    model = problem.model(jh.TABLE1_TRUE)
    assert isinstance(model.variant, jh.VenkataramanJA)
    np.testing.assert_array_equal(drive.observed(model.simulate(drive).y), problem.data)


def test_a_rate_dependent_model_keeps_its_loss_coefficients(tmp_path):
    model = jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1, losses=jh.Losses(0.02, 0.1, 3e-5, 4e-4))
    jh.save_model(tmp_path / "dyn.eqx", model)
    back = jh.load_model(tmp_path / "dyn.eqx")
    assert float(back.losses.eddy) == 0.02 and float(back.losses.excess) == 0.1
    assert float(back.losses.lag) == 3e-5 and float(back.losses.relax) == 4e-4
    jh.save_model(tmp_path / "static.eqx", jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1))
    assert jh.load_model(tmp_path / "static.eqx").losses is None


def test_a_model_file_from_before_the_lag_loads_with_no_lag(tmp_path):
    """A file written when Losses held eddy and excess only (its header without
    loss_names) loads, its lag 0."""
    import io
    import json

    import equinox as eqx

    model = jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1, losses=jh.Losses(0.02, 0.1))
    jh.save_model(tmp_path / "new.eqx", model)
    header = json.loads((tmp_path / "new.eqx").read_bytes().split(b"\n", 1)[0])
    del header["loss_names"]
    old = eqx.tree_at(lambda m: m.losses, model, (model.losses.eddy, model.losses.excess))
    buf = io.BytesIO()
    buf.write(json.dumps(header).encode() + b"\n")
    eqx.tree_serialise_leaves(buf, old)
    (tmp_path / "old.eqx").write_bytes(buf.getvalue())
    back = jh.load_model(tmp_path / "old.eqx")
    assert (float(back.losses.eddy), float(back.losses.excess), float(back.losses.lag),
            float(back.losses.relax)) == (0.02, 0.1, 0.0, 0.0)


def test_a_condition_law_is_saved_and_evaluated_at_a_new_amplitude(tmp_path):
    """A ``--vary`` fit's model keeps its law: saved, loaded and evaluated at an amplitude
    between the fitted ones it gives the parameters the problem's own law gives there; a
    law-less model and a missing condition are one-line errors."""
    from jaxhyst.identify.joint import NO_ACTUATOR

    amplitudes = (6e3, 12e3, 24e3)
    drives = [jh.drive_from_record(None, A * np.cos(2 * np.pi * np.arange(41) / 40))
              for A in amplitudes]
    p = jh.TABLE1_TRUE
    bounds = jh.Bounds(p.replace(k=0.5 * float(p.k), a=0.5 * float(p.a)),
                       p.replace(k=2 * float(p.k), a=2 * float(p.a)))
    records = jh.JointProblem([np.sin(np.arange(41.0))] * 3, drives, NO_ACTUATOR,
                              jh.per_record_space(bounds, 3), output="magnetization",
                              variant=jh.ClassicJA(), substeps=2)
    law = jh.ConditionModel({"k": ("log_amplitude",), "a": ("log_amplitude",)})
    problem = jh.ConditionProblem(records, jh.Conditions(amplitude=amplitudes), law,
                                  jh.condition_space(bounds, law))
    coefficients = {**{n: float(getattr(p, n)) for n in jh.NAMES},
                    "k:log_amplitude": 0.4, "a:log_amplitude": -0.2}
    model = problem.model(coefficients)
    assert "condition law" in repr(model)
    jh.save_model(tmp_path / "law.eqx", model)
    back = jh.load_model(tmp_path / "law.eqx")
    assert back.law == model.law and np.shape(back.params.Ms) == (3,)
    at = back.at(amplitude=9e3)
    want = problem.at(coefficients, jh.Conditions(amplitude=[9e3]))
    for name in jh.NAMES:
        assert float(getattr(at.params, name)) == pytest.approx(
            float(getattr(want, name)[0]), rel=1e-12), name
    assert float(at.params.k) != pytest.approx(float(p.k))  # the law moved it
    assert at.law is None and np.ndim(at.params.Ms) == 0
    with pytest.warns(jh.ConditionWarning, match="outside the fitted range"):
        back.at(amplitude=50e3)
    with pytest.raises(ValueError, match="carry none"):
        back.at(frequency=50.0)
    with pytest.raises(ValueError, match="has no condition law"):
        jh.Model(p, jh.ACTUATOR1).at(amplitude=9e3)
    # far enough out a law gives no material (a ∝ A^-8: at 1 A/m far beyond 1e9 A/m):
    # one line naming the condition and the value, not a model of nonsense
    steep = problem.model({**coefficients, "a:log_amplitude": -8.0})
    with pytest.warns(jh.ConditionWarning), \
            pytest.raises(ValueError, match=r"does not reach amplitude 1 A/m: there it "
                                            r"gives a = .* \(a must lie in \[1e-6, 1e9\]"):
        steep.at(amplitude=1.0)


def test_a_nearest_condition_model_is_saved_and_gives_the_nearest_loops_set(tmp_path,
                                                                              capsys):
    """The nearest-condition model (the baseline a leave-one-out comparison may keep):
    one set per fitted loop, saved with the loops' conditions, and at a condition it
    gives the set of the loop nearest to it — by amplitude and frequency, the conditions
    the loops differ in (the temperature, the same for all, is not asked for)."""
    x = np.stack([jh.TABLE1_TRUE.replace(k=k).to_array() for k in (1e3, 2e3, 3e3, 4e3)])
    form = jh.PlayJA(spread=np.array([0.1, 0.2, 0.3, 0.4]), cells=6)
    nearest = jh.NearestCondition(jh.Conditions(amplitude=(10e3, 20e3, 10e3, 20e3),
                                                frequency=(50.0, 50.0, 400.0, 400.0),
                                                temperature=(25.0,) * 4))
    assert nearest.features == ("log_f", "log_amplitude")
    model = jh.Model(jh.Parameters.from_array(x), jh.ACTUATOR1, form, law=nearest)
    assert "the nearest of 4 fitted loops" in repr(model)
    jh.save_model(tmp_path / "near.eqx", model)
    back = jh.load_model(tmp_path / "near.eqx")
    assert back.law == nearest and read_header(tmp_path / "near.eqx")["law"]["kind"] == \
        "nearest"
    # ln-distances: 12e3 A/m at 60 Hz is nearest loop 0, 17e3 A/m at 300 Hz loop 3
    for (A, f), i in (((12e3, 60.0), 0), ((17e3, 60.0), 1), ((11e3, 300.0), 2),
                      ((17e3, 300.0), 3)):
        at = back.at(amplitude=A, frequency=f)
        assert float(at.params.k) == x[i, jh.NAMES.index("k")], (A, f)
        assert float(at.variant.spread) == pytest.approx(0.1 * (i + 1)) and at.law is None
    with pytest.warns(jh.ConditionWarning, match="outside the fitted range"):
        back.at(amplitude=50e3, frequency=50.0)
    with pytest.raises(ValueError, match="carry none"):
        back.at(amplitude=12e3)  # (the loops differ in frequency: it is needed)
    np.testing.assert_array_equal(nearest.nearest(jh.Conditions(
        amplitude=(10e3, 20e3), frequency=(400.0, 50.0))), [2, 1])
    with pytest.raises(ValueError, match="one parameter set .* per record"):
        jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1, law=nearest).at(amplitude=1e4, frequency=50.0)
    from jaxhyst.cli import main  # (compensate evaluates laws of the frequency only)

    assert main(["compensate", "--model", str(tmp_path / "near.eqx"), "--current-limit",
                 "2.5"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "picks the nearest of its fitted loops by log_amplitude" in err


def test_a_saved_material_model_predicts_a_file_of_fields_or_of_several_signals(tmp_path,
                                                                                capsys):
    """``predict MODEL.eqx DATA`` predicts the signal the model was fitted to: compared
    where the file has it (among others), written without comparison where the file
    has fields only (both used to stop with advice to pass an --output that predict
    does not have); a model fitted driven by B, driven by each loop's B(t), asks in one
    line for the t column a file of B without times lacks."""
    from jaxhyst.cli import main
    from jaxhyst.identify.joint import NO_ACTUATOR

    material = jh.Model(jh.Parameters(Ms=3.2e5, lambda_s=0.0, a=14.0, k=11.0, alpha=1.2e-5,
                                      c=0.6, E=1.0, Kz=1.0, Mz=1.0, Cz=0.0), NO_ACTUATOR,
                        jh.ClassicJA(), 4)
    H = 60.0 * np.cos(2 * np.pi * np.arange(128) / 128)
    sim = material.simulate(jh.drive_from_record(None, H, run_in_periods=1))
    M = np.asarray(sim.M)[sim.run_in:]
    B = 4e-7 * np.pi * (H + M)
    model, both, fields = (tmp_path / n for n in ("m.eqx", "both.csv", "fields.csv"))
    jh.save_model(model, material, output="flux_density")
    np.savetxt(both, np.c_[H, M, B], delimiter=",", header="H,M,B", comments="")
    np.savetxt(fields, H[:, None], delimiter=",", header="H", comments="")
    assert main(["predict", str(model), str(both), "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["loops"][0]
    assert row["output"] == "flux_density" and row["rms"] < 1e-6 * np.max(np.abs(B))
    out = tmp_path / "pred.csv"
    assert main(["predict", str(model), str(fields), "--out", str(out), "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["loops"][0]
    assert row["output"] == "flux_density" and "rms" not in row
    got = np.genfromtxt(out, delimiter=",", names=True)
    np.testing.assert_allclose(got["predicted"], B, rtol=0, atol=1e-9)
    assert np.all(np.isnan(got["data"]))
    by_B = tmp_path / "b.eqx"
    jh.save_model(by_B, material, output="field")
    assert main(["predict", str(by_B), str(both)]) == 2
    err = capsys.readouterr().err
    assert "has no t column" in err and "driven by its B(t)" in err
