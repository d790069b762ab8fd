"""Nothing wrong accepted (issue 16): one table of malformed inputs through the command
line and the Python API, each with its exit status and one-line message; property-based
tests (hypothesis) of the reader and of `simulate` on random valid inputs."""

from __future__ import annotations

import json
import os
import sys
import tempfile

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import jaxhyst as jh
from jaxhyst.cli import main
from jaxhyst.identify.joint import NO_ACTUATOR
from jaxhyst.io import DataError, read_json, read_loops

# -- one table of malformed inputs ----------------------------------------------------------


def _files(d):
    """Files for the table: a valid B–H loop, and broken variants of every input file."""
    H = 100 * np.cos(2 * np.pi * np.arange(200) / 200)
    B = 0.3 * np.tanh((H + 10 * np.sign(np.gradient(-H))) / 30)
    ok = d / "loop.csv"
    ok.write_text("H [A/m],B [T]\n" + "".join(f"{h},{b}\n" for h, b in zip(H, B,
                                                                              strict=True)))
    files = {"ok": ok}
    # loops of one material at three peak fields, and two of them within 0.2 %
    rows = [f"{i},{s * h},{0.3 * np.tanh((s * h + 10 * np.sign(np.gradient(-H))[j]) / 30)}\n"
            for i, s in enumerate((0.5, 1.0, 1.002)) for j, h in enumerate(H)]
    for name, chosen in (("two_amplitudes", rows), ("two_loops", rows[:400])):
        (d / name).write_text("loop,H [A/m],B [T]\n" + "".join(chosen))
        files[name] = d / name
    for name, content in {
        "binary": b"\x89PNG\r\n\x1a\n\x00\x00\x00\rIHDR\xb6\xff",
        "empty": b"",
        "nan": b"H,B\n" + b"".join(b"1,2\n" for _ in range(9)) + b"nan,1\n",
        "half": b"H,B\n" + b"".join(f"{h},{0.001 * h}\n".encode() for h in H[:40]),
        "ragged": b"H,B\n1,2\n3\n",
        "nosignal": b"H,t\n" + b"".join(f"{i},{i}\n".encode() for i in range(10)),
        "huge": b"H,B\n" + b"".join(f"{h},{b}\n".encode() for h, b in zip(H, B,
                                                                          strict=True))
                + b"1,1e300\n",
        "params_list": b"[1, 2, 3]",
        "params_text": b"Ms = 7e5",
        "params_bad": json.dumps({"Ms": -1.0}).encode(),
        "params_Ms_huge": json.dumps({**jh.TABLE1_TRUE.to_dict(), "Ms": 7.65e15}).encode(),
        "bounds_swapped": json.dumps({"k": [40, 20]}).encode(),
        "bounds_unknown": json.dumps({"kk": [1, 2]}).encode(),
        "bounds_short": json.dumps({"k": [1]}).encode(),
        "checkpoint_text": b"not a checkpoint",
        "bounds_neg_a": json.dumps({"a": [-100, 1e4]}).encode(),
        "const_y": b"t [s],I [A],y [m]\n" + b"".join(
            f"{1e-4 * i},{0.77 * np.sin(i / 10) + 1.53},2e-5\n".encode() for i in range(200)),
        "ref_short": b"t [s],y [m]\n" + b"".join(f"{1e-4 * i},{1e-6 * (2 + np.sin(i))}\n"
                                                  .encode() for i in range(50)),
        "ref_nan": b"t [s],y [um]\n" + b"".join(f"{1e-4 * i},{10 + i % 3}\n".encode()
                                                 for i in range(20)) + b"2e-3,nan\n",
        "bounds_spread": json.dumps({"spread": [0.1, 2.0]}).encode(),
        "b_and_h": b"loop,t [s],H [A/m],B [T]\n" + b"".join(  # (two loops, no frequency)
            f"{j},{1e-5 * i},{30 * s * np.sin(2 * np.pi * i / 100)},"
            f"{0.1 * s * np.sin(2 * np.pi * i / 100 - 0.3)}\n".encode()
            for j, s in enumerate((1.0, 2.0)) for i in range(101)),
        "b_only": b"t [s],B [T]\n" + b"".join(  # (B(t) alone: nothing to fit driven by B)
            f"{1e-5 * i},{0.3 * np.sin(2 * np.pi * i / 100)}\n".encode() for i in range(101)),
        "utf16": "H,B\n1,2\n3\n".encode("utf-16"),  # read as text: then the ragged row
        "decimal_commas": b"H,B\n1,5,0,25\n2,5,0,5\n",
        "side_by_side": b"H1 [A/m],B1 [T],H2 [A/m],B2 [T]\n1,0.1,2,0.2\n-1,-0.1,-2,-0.2\n",
    }.items():
        f = d / name
        f.write_bytes(content)
        files[name] = f
    (d / "adir").mkdir()
    files["dir"] = d / "adir"
    files["fit_result"] = d / "fit.json"  # (a result of identify, not a model)
    files["fit_result"].write_text(json.dumps({"params": {"Ms": {"value": 7e5}}}))
    return files


CLI_TABLE = [  # (argv with {name} for the files, exit status, message fragment)
    (["identify", "{binary}"], 2, "is not text"),
    # issues 41, 42, 44, 46: the new options, and options that do not apply
    (["simulate", "--flux-amplitude", "0.3", "--amplitude", "1"], 2,
     "drives the material by B"),
    (["simulate", "--eddy", "-1"], 2, "--eddy"),
    (["simulate", "--cells", "4"], 2, "--cells applies to the forms of pinning cells"),
    (["simulate", "--params", "table3:800", "--actuator", "actuator2"], 2,
     "is driven by its field (it has no turns per metre to carry a current): give "
     "--field-amplitude"),
    (["simulate", "--png", "x.xyz"], 2, "figures are written as"),
    (["compensate", "--current-limit", "2.5", "--gain", "7"], 2, "applies to learning"),
    (["compensate", "--current-limit", "2.5", "--periods", "0"], 2, "--periods"),
    (["compensate", "--current-limit", "2.5", "--known-delay", "2"], 2,
     "--known-delay 2 applies to learning"),
    (["compensate", "--current-limit", "2.5", "--plant", "table1", "--known-delay", "100000"],
     2, "--known-delay 100000: a delay of a whole period or more"),
    (["compensate", "--current-limit", "2.5", "--noise", "0.01"], 2,
     "--noise describes the simulated plant"),
    (["compensate", "--current-limit", "2.5", "--state", "{missing}"], 2,
     "--state carries learning"),
    (["compensate", "--current-limit", "1e9"], 2, "beyond any laboratory drive"),
    (["compensate", "--current-limit", "2.5", "--plant", "table1", "--measured", "{ok}"], 2,
     "give one of them"),
    (["compensate", "--model", "{bh_model}", "--current-limit", "2.5"], 2,
     "a model of a material alone"),
    (["compensate", "--model", "{bh_model}", "--params", "table1"], 2,
     "leave out --params"),
    (["identify", "{ok}", "--joint", "--vary-degree", "2"], 2,
     "--vary-degree 2 shapes the laws of --vary"),
    (["identify", "{ok}", "--variant", "bogus"], 2, "the forms are"),
    (["identify", "{ok}", "--variant", "play,classic"], 2, "compared only by"),
    (["identify", "{ok}", "--losses", "friction"], 2, "--losses 'friction'"),
    (["identify", "{ok}", "--losses", "eddy"], 2,
     "--losses eddy: the rate-dependent model needs times: give a t column"),
    (["identify", "{const_y}", "--output", "y", "--losses", "eddy"], 2,
     "the box of a loss coefficient is derived from M or B data; give it in a bounds file"),
    (["identify", "{ok}", "--joint", "--vary", "eddy:log_amplitude"], 2,
     "--vary eddy: a loss coefficient"),
    (["identify", "{ok}", "--joint", "--vary", "spread:log_amplitude"], 2,
     "energy has no spread"),
    (["identify", "{ok}", "--joint", "--leave-one-out"], 2, "holds 1 loop"),
    (["identify", "{two_loops}", "--joint", "--vary", "k:log_amplitude", "--vary-degree", "2"],
     2, "3 coefficients, but the 2 records are at 2 conditions"),
    (["identify", "{two_amplitudes}", "--joint", "--leave-one-out", "--vary",
      "k:log_amplitude", "--variant", "classic"], 2,
     "the fold without loop 0 cannot fit the law of classic"),
    (["identify", "{two_amplitudes}", "--joint", "--leave-one-out", "--variant",
      "play@spread:log_amplitude"], 2, "records are at 1 condition"),
    (["identify", "{ok}", "--bounds", "{bounds_spread}"], 2, "energy does not have"),
    (["simulate", "--seed", "3"], 2, "--seed goes with --noise"),
    (["simulate", "--temperature", "20"], 2, "--temperature goes with --model"),
    (["simulate", "--model", "{binary}"], 2, "not a jaxhyst model file"),
    (["simulate", "--model", "nowhere.eqx"], 2, "does not exist"),
    (["simulate", "--run-in-periods", "2"], 2, "--run-in-periods applies to a --drive"),
    (["identify", "{dir}"], 2, "is a directory"),
    (["identify", "{empty}"], 2, "is empty"),
    (["identify", "{nan}"], 2, "is not a finite number"),
    (["identify", "{ragged}"], 2, "1 values for 2 columns"),
    (["identify", "{nosignal}"], 2, "signal columns []"),
    (["identify", "{half}"], 2, "holds no hysteresis loop"),
    (["identify", "{huge}"], 2, "beyond any material"),
    (["identify", "{ok}", "--bounds", "{bounds_swapped}"], 2, "lower <= upper"),
    (["identify", "{ok}", "--bounds", "{bounds_unknown}"], 2, "unknown parameters ['kk']"),
    (["identify", "{ok}", "--bounds", "{bounds_short}"], 2, "k must be [lower, upper]"),
    (["identify", "{ok}", "--fix", "a=-5"], 2, "a must lie in [1e-6, 1e9] A/m"),
    (["identify", "{ok}", "--fix", "c=nan"], 2, "not finite"),
    (["identify", "{ok}", "--fix", "Mass=1"], 2, "unknown parameter"),
    (["identify", "{ok}", "--fix", "c", "--params", "{params_list}"], 2,
     "expected a JSON object"),
    (["identify", "{ok}", "--fix", "c", "--params", "{params_text}"], 2, "not valid JSON"),
    (["identify", "{ok}", "--start", "{params_bad}"], 2, "need the ten names"),
    (["identify", "{ok}", "--start", "{missing}"], 2, "does not exist"),
    (["identify", "{ok}", "--method", "GATR1", "--start", "{ok}"], 2,
     "--start applies to the local solvers"),
    (["identify", "{ok}", "--method", "lm", "--checkpoint", "{checkpoint_text}"], 2,
     "apply to the hybrid GAs"),
    (["identify", "{ok}", "--seed", "-1"], 2, "--seed"),
    (["identify", "{ok}", "--method", "GATR1", "--generations", "3"], 2,
     "--generations 3: a hybrid runs 5 binary-coded generations first"),
    (["identify", "{ok}", "--out", "/proc/r.json"], 2, "cannot write in /proc"),
    (["identify", "{ok}", "--method", "GATR1", "--population", "1"], 2,
     "--population 1: a hybrid's population needs at least 4"),
    (["identify", "{utf16}"], 2, "line 3: 1 values for 2 columns"),  # UTF-16 decoded
    (["identify", "{decimal_commas}"], 2, "decimal commas"),
    (["identify", "{side_by_side}"], 2, "loops side by side? put them one below the other"),
    (["identify", "{ok}", "--starts", "0"], 2, "--starts"),
    (["identify", "{ok}", "--substeps", "1.5"], 2, "--substeps"),
    (["identify", "{ok}", "--out", "{ok}/r.json"], 2, "cannot write in"),
    (["identify", "{ok}", "--out", "{dir}"], 2, "is a directory; give a file name"),
    (["identify", "{ok}", "--per-loop", "c"], 2, "--per-loop needs --joint"),
    (["identify", "{ok}", "--joint", "--per-loop", "kk,c"], 2,
     "--per-loop 'kk,c': 'kk' is not a parameter; names are"),
    (["simulate", "--amplitude", "inf"], 2, "--amplitude"),
    (["simulate", "--field-amplitude", "1e300"], 2, "beyond 1e+09 A/m"),
    (["simulate", "--params", "{params_bad}"], 2, "need the ten names"),
    (["simulate", "--frequency", "0"], 2, "--frequency"),
    (["report", "{ok}"], 2, "not valid JSON"),
    (["report", "{params_list}"], 2, "expected a JSON object"),
    (["reproduce", "table4"], 2, "invalid choice"),
    (["simulate", "--amplitude", "0.5", "--field-amplitude", "8000"], 2,
     "--field-amplitude drives with a field"),
    (["simulate", "--drive", "{ok}", "--frequency", "50"], 2, "--drive reads the drive"),
    (["simulate", "--periods", "1e7"], 2, "samples (about"),
    (["simulate", "--frequency", "1e12"], 2, "frequency must be a finite number in"),
    (["simulate", "--params", "{params_Ms_huge}"], 2, "Ms = 7650000000000000.0 must lie in"),
    (["identify", "{ok}", "--joint", "--loop", "0"], 2, "--joint fits every loop"),
    (["identify", "{ok}", "--fix", "c=0.2", "--fix", "c=0.3"], 2, "--fix names c twice"),
    (["identify", "{ok}", "--fix", "a=1e-300"], 2, "a must lie in [1e-6, 1e9] A/m"),
    (["identify", "{ok}", "--bounds", "{bounds_neg_a}"], 2, "the lower bound of a is -100"),
    (["identify", "{const_y}", "--output", "y"], 2, "data are constant"),
    (["compensate", "--current-limit", "0"], 2, "current limit must be a positive number"),
    (["compensate", "--current-limit", "-3"], 2, "current limit must be a positive number"),
    (["compensate", "--current-limit", "3,1"], 2, "lower < upper"),
    (["compensate", "--current-limit", "1", "--slew-limit", "0"], 2, "--slew-limit"),
    (["compensate"], 2, "give the reference (--amplitude and --mean"),
    (["compensate", "--reference", "{ref_nan}"], 2, "is not a finite number"),
    (["compensate", "--reference", "{ref_short}", "--frequency", "100"], 2,
     "shorter than one period"),
    (["compensate", "--reference", "{ref_short}", "--frequency", "100", "--periodic"], 2,
     "exclude each other"),
    (["compensate", "--reference", "{ref_short}", "--amplitude", "1e-6"], 2, "is a file"),
    (["compensate", "--tones", "1e-6", "--amplitude", "1e-6"], 2, "--tones and --phases"),
    # (the model's accuracy check compiles: the extended step; the default run checks
    # its one line in Python, tests/test_control.py)
    pytest.param(["compensate", "--amplitude", "1e-5", "--mean", "4e-5",
                  "--samples-per-period", "8", "--current-limit", "2.5"], 2,
                 "sampled too coarsely", marks=pytest.mark.extended),
    (["compensate", "--amplitude", "1e-5", "--mean", "4e-5", "--measured", "{ok}"], 2,
     "no displacement column y"),
    # issue 46: command-line spelling in the library's messages; report of a model file
    (["simulate", "--samples-per-period", "2"], 2, "--samples-per-period must be"),
    (["report", "{bh_model}"], 2, "without the problem it was fitted to"),
    (["identify", "{b_and_h}", "--driven-by", "B", "--joint", "--vary", "k:log_f"], 2,
     "--vary k:log_f: {b_and_h} has no frequency column"),
    (["identify", "{b_and_h}", "--driven-by", "B", "--joint", "--variant", "classic",
      "--vary", "spread:log_amplitude"], 2, "--vary spread: classic has no spread"),
    (["compensate", "--current-limit", "2.5", "--model", "{fit_result}"], 2,
     "a result of 'jaxhyst identify --out' is not one: write the model with identify "
     "--save-model"),
    (["identify", "{b_only}", "--driven-by", "B"], 2,
     "has no H column; B(t) drives the model and H is fitted"),
]


@pytest.fixture(scope="module")
def files(tmp_path_factory):
    found = _files(tmp_path_factory.mktemp("malformed"))

    found["bh_model"] = found["ok"].parent / "bh.eqx"  # a model of a material alone
    jh.save_model(found["bh_model"], jh.Model(jh.TABLE1_TRUE, NO_ACTUATOR))
    return found


@pytest.mark.parametrize("argv,status,fragment", CLI_TABLE,
                         ids=[" ".join(getattr(c, "values", c)[0])[:60] for c in CLI_TABLE])
def test_malformed_command_line_inputs(files, argv, status, fragment, capsys):
    names = {k: str(v) for k, v in files.items()}
    names["missing"] = str(files["ok"].parent / "missing.json")
    argv, fragment = [a.format(**names) for a in argv], fragment.format(**names)
    assert main(argv) == status, argv
    cap = capsys.readouterr()
    err = cap.err.strip()
    assert "Traceback" not in err and err.count("\n") == 0, err
    assert fragment in err, (argv, err)
    assert not any(python in err for python in ("np.float64(", "array(", "_per_")), err


def _api_table(files):
    H = 100 * np.cos(2 * np.pi * np.arange(200) / 200)
    B = 1e-3 * H
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=50)
    bad = jh.TABLE1_TRUE.to_dict()

    def problem():
        return jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1, jh.TABLE1_BOUNDS)

    return [  # (call, exception type, fragment)
        (lambda: read_loops(files["binary"]), DataError, "is not text"),
        (lambda: read_loops(files["dir"]), DataError, "is a directory"),
        (lambda: read_json(files["params_list"]), DataError, "expected a JSON object"),
        (lambda: jh.loop_problem(H[:40], B[:40]), ValueError, "holds no hysteresis loop"),
        (lambda: jh.loop_problem(H, B[:-1]), ValueError, "equal length"),
        (lambda: jh.loop_problem(H, B, {"kk": (1, 2)}), ValueError, "unknown parameters"),
        (lambda: jh.loop_problem(H, B, output="displacement"), ValueError,
         "magnetization or flux_density"),
        (lambda: jh.loop_problem(H, np.where(H > 0, np.nan, B)), ValueError, "NaN or inf"),
        (lambda: jh.simulate(jh.Parameters.from_dict({**bad, "c": 2.0}), jh.ACTUATOR1,
                             drive), ValueError, "c = 2.0 must lie in [0, 1]"),
        (lambda: jh.sinusoidal_current(100.0, float("nan"), 1.53, jh.ACTUATOR1), ValueError,
         "finite number"),
        (lambda: jh.sinusoidal_field(100.0, 1e300), ValueError, "beyond 1e+09 A/m"),
        (lambda: jh.Bounds.from_dict({**{n: (1.0, 2.0) for n in jh.NAMES}, "k": (3.0, 1.0)}),
         ValueError, "lower > upper"),
        (lambda: jh.synthetic_problem(jh.TABLE1_TRUE, drive, jh.ACTUATOR1,
                                      jh.TABLE1_BOUNDS, fixed=["Ms", "ms"]), ValueError,
         "Cannot fix unknown parameter(s) ['ms']"),
        (lambda: jh.JointProblem(B, jh.drive_from_record(None, H), NO_ACTUATOR,
                                 jh.ParameterSpace.for_loops(jh.TABLE1_BOUNDS, 1),
                                 output="flux_density"), TypeError,
         "give the loops' drives as a list"),
        (lambda: jh.FluxProblem(H, jh.sinusoidal_flux(100.0, 0.3),
                                jh.ParameterSpace(jh.TABLE1_BOUNDS)), TypeError,
         "give the records' drives as a list"),
        (lambda: jh.Bounds(jh.TABLE1_TRUE, {"a": 1e4}), TypeError,
         "Bounds' upper must be a jaxhyst.Parameters"),
        (lambda: jh.Bounds(), TypeError, "Bounds needs lower and upper"),
        (lambda: jh.Bounds(**{**{n: (1.0, 2.0) for n in jh.NAMES}, "Ms": 7e5}), TypeError,
         "the bounds of Ms must be a pair (lower, upper) of numbers; got 700000.0"),
        (lambda: jh.Model({"a": 7012.0}, jh.ACTUATOR1), TypeError,
         "Model's params must be a jaxhyst.Parameters"),
        (lambda: jh.Losses(eddy=1e12), ValueError, "Losses.eddy must lie in [0, 1e+06]"),
        (lambda: jh.Losses(lag=-1e-3), ValueError, "Losses.lag must lie in [0, 3600]"),
        (lambda: jh.sinusoidal_flux(50.0, 100.0), ValueError, "beyond 10 T"),
        (lambda: jh.PlayJA(spread=-1.0), ValueError, "spread must lie in [0, 10]"),
        (lambda: jh.PlayJA(cells=0), ValueError, "cells must be an integer in [1, 256]"),
        (lambda: jh.PreisachJA(a_rev=0.0), ValueError, "a_rev must lie in [1e-6, 1e9]"),
        (lambda: jh.drive_from_record(None, H[None]), ValueError,
         "in one dimension (one value per sample); got shape (1, "),
        (lambda: jh.sinusoidal_flux(50.0, float("nan")), ValueError,
         "amplitude must be a finite number (T)"),
        (lambda: jh.flux_from_record(np.arange(10.0), np.r_[np.zeros(9), np.nan]), ValueError,
         "The flux-density record contains NaN or inf at samples [9]"),
        (lambda: jh.flux_from_record(np.arange(10.0), np.zeros(9)), ValueError,
         "t and B of a record differ in length"),
        (lambda: jh.Losses(excess="0.5 A"), ValueError, "Losses.excess must lie in"),
        (lambda: jh.multistart(problem(), np.zeros((0, 10))), ValueError,
         "needs at least one start"),
        (lambda: jh.multistart(problem(), np.where(np.eye(10)[:2] > 0, np.nan, 0.5)),
         ValueError, "got nan for Ms of start 0"),
        (lambda: jh.solve(problem(), jh.TABLE1_TRUE.replace(k=float("nan"))), ValueError,
         "the start's k is not a finite number"),
        (lambda: jh.Model(jh.TABLE1_TRUE.replace(a=float("nan")), jh.ACTUATOR1), ValueError,
         "Parameter a is not finite (nan)"),
        (lambda: jh.frequency_response(jh.TABLE1_TRUE, jh.ACTUATOR1, [10.0, float("nan")]),
         ValueError, "frequency must be finite (Hz); got [10.0, nan]"),
        (lambda: jh.simulate_batch(jh.Parameters.from_array(np.tile(
            jh.TABLE1_TRUE.to_array(), (3, 1))).replace(a=np.full(2, 7e3)), jh.ACTUATOR1,
            drive), ValueError, "a (2,), k (3,)"),
        (lambda: jh.loop_problem(H, B, substeps=0), ValueError,
         "substeps must be an integer >= 1; got 0"),
        (lambda: jh.split_records(3, [0, 1, 2]), ValueError, "leave at least one to fit"),
        (lambda: jh.save_model(files["ok"] / "m.eqx", jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1)),
         OSError, f"cannot write {files['ok'] / 'm.eqx'} ("),
        (lambda: jh.sinusoidal_current(100.0, 0.77, 1.53, "Actuator1"), TypeError,
         "actuator must be a jaxhyst.Actuator"),
    ]


def test_bounds_by_name_are_the_dicts():
    pairs = {n: (float(lo), float(hi)) for n, lo, hi in zip(
        jh.NAMES, jh.TABLE1_BOUNDS.lower.to_array(), jh.TABLE1_BOUNDS.upper.to_array(),
        strict=True)}
    by_name = jh.Bounds(**pairs)
    np.testing.assert_array_equal(by_name.lower.to_array(), jh.TABLE1_BOUNDS.lower.to_array())
    np.testing.assert_array_equal(by_name.upper.to_array(), jh.TABLE1_BOUNDS.upper.to_array())
    with pytest.raises(TypeError, match="not both"):
        jh.Bounds(jh.TABLE1_BOUNDS.lower, **pairs)


def test_malformed_python_api_inputs(files):
    for i, (call, exc, fragment) in enumerate(_api_table(files)):
        with pytest.raises(exc) as info:
            call()
        msg = str(info.value)
        assert fragment in msg and "\n" not in msg, (i, msg)


def test_a_numpy_integer_is_a_number_of_substeps_everywhere():
    """One check of the substeps for simulate, simulate_flux and the problems: a NumPy
    integer (what an array's element or np.int64(…) gives) is accepted by each, as the
    problems already accepted it, and a bool or a fraction refused by each."""
    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=50)
    flux = jh.sinusoidal_flux(100.0, 0.3, samples_per_period=50)
    for run in (lambda s: jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive, substeps=s).y,
                lambda s: jh.simulate_flux(jh.TABLE1_TRUE, flux, substeps=s).H):
        np.testing.assert_array_equal(run(np.int64(2)), run(2))
        for bad in (True, 1.5, 0):
            with pytest.raises(ValueError, match="substeps must be an integer >= 1"):
                run(bad)


def test_a_loss_density_needs_a_positive_frequency_and_whole_periods():
    sim = jh.simulate_flux(jh.TABLE1_TRUE, jh.sinusoidal_flux(1000.0, 0.3,
                                                             samples_per_period=100))
    for call, fragment in ((lambda: sim.loss_density(-1000.0), "frequency must be > 0"),
                           (lambda: sim.loss_density(1000.0, periods=0), "periods must be")):
        with pytest.raises(ValueError, match=fragment) as info:
            call()
        assert "\n" not in str(info.value)
    assert float(sim.loss_density(1000.0)) > 0


def test_impossible_parameters_under_jit_give_nan_not_a_simulation():
    """Under jit the values cannot be read to refuse them; the signals of a parameter set
    outside its physical range (c = 2) are NaN instead of a plausible displacement."""
    import jax

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=50)

    @jax.jit
    def run(c):
        return jh.simulate_unchecked(jh.TABLE1_TRUE.replace(c=c), jh.ACTUATOR1, drive).y

    assert np.all(np.isnan(np.asarray(run(2.0))))
    assert np.all(np.isfinite(np.asarray(run(0.18))))


def test_simulate_under_a_transformation_called_directly_still_checks_parameters():
    """jax.grad called without jit can read its input's value: an invalid parameter is
    named as for a direct call, not turned into a silent NaN; under jit the values are
    abstract and the check is skipped."""
    import jax
    import jax.numpy as jnp

    drive = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=30)

    def loss(a):
        return jnp.sum(jh.simulate(jh.TABLE1_TRUE.replace(a=a), jh.ACTUATOR1, drive).y)

    with pytest.raises(ValueError, match=r"Parameter a = -1.0 must lie in \[1e-6, 1e9\]"):
        jax.grad(loss)(-1.0)
    assert np.isfinite(float(jax.grad(loss)(7012.0)))
    assert np.isfinite(float(jax.jit(jax.grad(loss))(7012.0)))


# -- property-based tests -------------------------------------------------------------------

QUANTITY_UNITS = {  # quantity → [(unit as written, factor to SI)], value range in SI
    "H": ([("A/m", 1.0), ("kA/m", 1e3), ("Oe", 1e3 / (4 * np.pi))], 1e5),
    "B": ([("T", 1.0), ("mT", 1e-3)], 2.0),
    "y": ([("m", 1.0), ("um", 1e-6), ("mm", 1e-3)], 1e-4),
    "M": ([("A/m", 1.0), ("kA/m", 1e3)], 1e6),
}


@st.composite
def tables(draw):
    n = draw(st.integers(8, 30))
    cols = ["H", *draw(st.lists(st.sampled_from(["B", "y", "M"]), min_size=1, max_size=3,
                                unique=True))]
    with_t = draw(st.booleans())
    header, data = [], {}
    if with_t:
        dt = draw(st.lists(st.floats(1e-6, 1e-2), min_size=n, max_size=n))
        data["t"] = (np.cumsum(dt), 1.0)
        header.append("t [s]")
    for q in cols:
        units, size = QUANTITY_UNITS[q]
        unit, factor = draw(st.sampled_from(units))
        style = draw(st.sampled_from(["{q} [{u}]", "{q} ({u})"]))
        value = st.floats(-size, size, allow_nan=False).filter(
            lambda v: v == 0 or abs(v) > 1e-200)  # (a unit factor must not underflow it)
        vals = draw(st.lists(value, min_size=n, max_size=n))
        data[q] = (np.asarray(vals) / factor, factor)  # the file holds them in `unit`
        header.append(style.format(q=q, u=unit))
    delim = draw(st.sampled_from([",", "\t", ";"]))
    return header, data, delim


@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(tables())
def test_reader_reads_any_valid_table_exactly(table):
    header, data, delim = table
    names = list(data)
    rows = zip(*(data[q][0] for q in names), strict=True)
    text = delim.join(header) + "\n" + "".join(delim.join(repr(float(v)) for v in r) + "\n"
                                               for r in rows)
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "t.csv")
        with open(path, "w") as fh:
            fh.write(text)
        (loop,) = read_loops(path)
    for q in names:
        values, factor = data[q]
        got = {"t": loop.t, "H": loop.H}.get(q, loop.signals.get(q))
        assert got is not None and np.all(np.isfinite(got))
        np.testing.assert_allclose(got, values * factor, rtol=1e-12, atol=0)


@settings(max_examples=60, deadline=None)
@given(st.one_of(st.binary(max_size=300), st.text(max_size=300)))
def test_reader_never_fails_other_than_with_a_data_error(content):
    with tempfile.TemporaryDirectory() as d:
        path = os.path.join(d, "x.csv")
        with open(path, "wb") as fh:
            fh.write(content.encode("utf-8", "surrogatepass") if isinstance(content, str)
                     else content)
        try:
            loops = read_loops(path)
        except DataError as err:
            assert "\n" not in str(err)
            return
    for lp in loops:  # whatever it accepted is finite and of the promised size
        assert lp.n_samples >= 8
        for a in (lp.t, lp.H, lp.I, *lp.signals.values()):
            assert a is None or np.all(np.isfinite(a))


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(scale=st.lists(st.floats(0.5, 2.0), min_size=10, max_size=10),
       c=st.floats(0.0, 1.0), alpha=st.floats(-0.05, 0.0),
       frequency=st.floats(1.0, 2000.0), amplitude=st.floats(0.0, 2.0),
       offset=st.floats(-2.0, 2.0))
def test_simulate_on_random_valid_inputs_is_finite_or_says_it_diverged(
        scale, c, alpha, frequency, amplitude, offset):
    x = np.asarray(jh.TABLE1_TRUE.to_array()) * np.asarray(scale)
    p = jh.Parameters.from_dict({**dict(zip(jh.NAMES, x.tolist(), strict=True)),
                                 "c": c, "alpha": alpha})
    drive = jh.sinusoidal_current(frequency, amplitude, offset, jh.ACTUATOR1,
                                  samples_per_period=40)
    try:
        sim = jh.simulate(p, jh.ACTUATOR1, drive)
    except FloatingPointError as err:  # the checked alternative to a silent NaN
        assert "\n" not in str(err)
        return
    for name in ("M", "Man", "lam", "y", "strain"):
        assert np.all(np.isfinite(np.asarray(getattr(sim, name)))), name


def test_a_negative_value_read_as_an_option_is_explained(monkeypatch, capsys):
    argv = ["frequency-response", "--frequencies", "-5,10"]
    monkeypatch.setattr(sys, "argv", ["jaxhyst", *argv])
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--frequencies=-5,10" in err, err
