"""Leave one loop out from the command line (issue 41): forms compared and the best kept,
fair folds (a fold's box from its training loops only), each fold's outcome, the
baselines beside each held-out error, and one-line errors for comparisons that cannot
be made."""

from __future__ import annotations

import json

import jax
import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst.cli import main
from jaxhyst.identify.joint import NO_ACTUATOR

MU0 = 4e-7 * np.pi
TRUTH = jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=25.0, k=30.0, alpha=1e-5, c=0.3, E=1.0,
                      Kz=1.0, Mz=1.0, Cz=0.0)
AMPLITUDES = (40.0, 80.0, 200.0)


def _write(path, scale_last=1.0, samples=(48, 48, 48)):
    """Three B(H) loops of the play model (the last one's B times ``scale_last``), of
    ``samples`` samples per period each."""
    form = jh.PlayJA(spread=0.6, cells=8)
    lines = ["loop,H_A_per_m,B_T"]
    for i, Hm in enumerate(AMPLITUDES):
        drive = jh.sinusoidal_field(1.0, Hm, 0.0, samples_per_period=samples[i])
        # (without simulate's accuracy check: these data need no second simulation)
        sim = jh.simulate_unchecked(TRUTH, NO_ACTUATOR, drive, form, substeps=1)
        H = np.asarray(drive.observed(drive.H))
        B = MU0 * (H + np.asarray(drive.observed(sim.M)))
        B = B * (scale_last if i == len(AMPLITUDES) - 1 else 1.0)
        lines += [f"{i},{h:.10g},{b:.10g}" for h, b in zip(H, B, strict=True)]
    path.write_text("\n".join(lines) + "\n")


COMMON = ["--joint", "--leave-one-out", "--method", "lm", "--cells", "8", "--progress", "0",
          "--intervals", "linear"]  # (the intervals are not what these tests check)


@pytest.mark.extended  # (two forms' leave-one-out in full)
def test_forms_are_compared_and_the_best_predictor_is_kept(tmp_path, capsys):
    data = tmp_path / "loops.csv"
    _write(data)
    out = tmp_path / "r.json"
    rc = main(["identify", str(data), *COMMON, "--variant", "classic,play",
               "--max-steps", "100", "--starts", "2", "--out", str(out)])
    text = capsys.readouterr().out
    held = json.loads(out.read_text())["leave_one_out"]
    assert rc in (0, 3, 4)
    assert set(held["forms"]) == {"classic", "play", "nearest"}  # (and the baseline)
    for form, t in held["forms"].items():
        assert [r["loop"] for r in t["rows"]] == [0, 1, 2], form
        for r in t["rows"] if form != "nearest" else ():
            assert r["own_rms"] > 0 and r["nearest_rms"] > 0 and r["ratio"] > 0
        assert [r["outside"] for r in t["rows"]] == [True, False, True]
    assert [r["nearest_loop"] for r in held["forms"]["nearest"]["rows"]] == [1, 0, 1]
    # loops made by the play model: it predicts them better than the JA form, and is kept
    assert held["kept"] == "play"
    assert held["forms"]["play"]["score"] < held["forms"]["classic"]["score"]
    assert "kept: play" in text and json.loads(out.read_text())["problem"]["variant"] == "play"


@pytest.mark.extended  # (a B-driven leave-one-out in full)
def test_loops_driven_by_b_are_left_out_and_predicted_from_their_b(tmp_path, capsys,
                                                                    monkeypatch):
    """``identify --driven-by B --joint --leave-one-out``: each loop's H predicted from
    its B(t) by a fit of the others (its peak B the amplitude of the extrapolation),
    beside its own fit and the nearest loop's; the result predicts a file of B(t) with
    the folds' expected error. Where the nearest loop's fit is kept (forced here: the
    choice is tested on H-driven loops), each loop keeps its own set and a new B(t) is
    predicted by the set of the loop nearest in peak B; ``--per-loop`` frees a parameter
    per loop. The loops differ in length (each fit pads them to the longest)."""
    form = jh.ClassicJA()
    lines = ["loop,t,H,B"]  # (loops of unequal lengths: padded to one program)
    for i, (Bm, n) in enumerate(((0.1, 80), (0.2, 64), (0.3, 100))):
        sim = jh.simulate_flux(TRUTH, jh.sinusoidal_flux(50.0, Bm, samples_per_period=n),
                               form)
        t, H, B = (np.asarray(sim.observed(q)) for q in ("t", "H", "B"))
        lines += [f"{i},{float(a - t[0])!r},{float(h)!r},{float(b)!r}"
                  for a, h, b in zip(t, H, B, strict=True)]
    data, out = tmp_path / "bh.csv", tmp_path / "r.json"
    data.write_text("\n".join(lines) + "\n")
    assert main(["identify", str(data), "--driven-by", "B", *COMMON, "--variant",
                 "classic,energy", "--starts", "2", "--out", str(out)]) == 0
    text = capsys.readouterr().out
    held = json.loads(out.read_text())["leave_one_out"]
    assert held["kept"] == "classic"
    rows = held["forms"]["classic"]["rows"]
    assert [r["outside"] for r in rows] == [True, False, True]
    assert [r["beyond"].get("amplitude") for r in rows] == [pytest.approx(2.0), None,
                                                            pytest.approx(1.5)]
    for r in rows:  # (the loops are the fitted form's: every fold predicts its loop)
        assert r["rms"] < 1e-6 * r["data_scale"] and r["nearest_rms"] >= 0, r
    assert "nearest (classic alone)" in text
    alone = tmp_path / "b.csv"
    alone.write_text("t,B\n" + "".join(f"{a},{b}\n" for a, b in zip(
        np.arange(80) / 4000.0, 0.25 * np.sin(2 * np.pi * np.arange(80) / 80), strict=True)))
    assert main(["predict", str(out), str(alone), "--json"]) == 0
    (row,) = json.loads(capsys.readouterr().out)["loops"]
    assert row["extrapolation"] == "" and row["expected_relative_error"] < 1e-3
    from jaxhyst.cli import heldout, nearest

    monkeypatch.setattr(heldout, "choose", lambda table, c, comparison: (
        nearest.NEAREST, nearest.choose(table, c, comparison)[1]))
    model = tmp_path / "m.eqx"
    assert main(["identify", str(data), "--driven-by", "B", *COMMON, "--variant", "classic",
                 "--starts", "2", "--out", str(out), "--save-model", str(model)]) == 0
    capsys.readouterr()
    assert json.loads(out.read_text())["problem"]["predict_by"] == "nearest"
    for source in (out, model):  # (0.25 T: nearest in ln B to the 0.3 T loop)
        assert main(["predict", str(source), str(alone), "--json"]) == 0
        (row,) = json.loads(capsys.readouterr().out)["loops"]
        assert row["by_fitted_loop"] == 2 and row["extrapolation"] == ""
        assert main(["predict", str(source), str(data), "--json"]) == 0
        rows = json.loads(capsys.readouterr().out)["loops"]
        assert [r["by_fitted_loop"] for r in rows] == [0, 1, 2]
        assert all(r["rms"] < 1e-6 * r["data_scale"] for r in rows), rows
    monkeypatch.undo()  # (and a parameter free per loop, driven by B: each loop's own)
    assert main(["identify", str(data), "--driven-by", "B", "--joint", "--per-loop", "k",
                 "--variant", "classic", "--starts", "2", "--intervals", "linear",
                 "--progress", "0", "--out", str(out)]) == 0
    capsys.readouterr()
    fitted = json.loads(out.read_text())["params"]
    assert fitted["k"]["value"] == [pytest.approx(30.0, rel=1e-4)] * 3


@pytest.mark.extended  # (a leave-one-out of long loops)
def test_long_loops_are_compared_on_every_kth_sample_and_measured_on_all(tmp_path, capsys):
    """Loops of 1 100 samples: every fit of the comparison sees every 3rd sample (at most
    `FOLD_SAMPLES`); every error is measured on all. The samples in between carry an
    offset a fit on them would have to absorb: the folds' fits stay near the noise-free
    model (on what they see) while every held-out and own-fit error includes it."""
    from jaxhyst.cli.heldout import FOLD_SAMPLES

    data = tmp_path / "loops.csv"
    _write(data, samples=(1100, 1100, 1100))
    lines = data.read_text().splitlines()
    offset = 0.05  # (T; the loops' B reaches 0.1–0.3 T)
    per_loop = {}
    for n, line in enumerate(lines[1:], start=1):
        i, h, b = line.split(",")
        k = per_loop[i] = per_loop.get(i, -1) + 1
        lines[n] = f"{i},{h},{float(b) + (offset if k % 3 else 0.0):.10g}"
    data.write_text("\n".join(lines) + "\n")
    out = tmp_path / "r.json"
    main(["identify", str(data), *COMMON, "--variant", "play", "--max-steps", "60",
          "--starts", "2", "--out", str(out)])
    assert "each loop alone and each fold fitted on one sample in 3" in capsys.readouterr().err
    held = json.loads(out.read_text())["leave_one_out"]
    assert held["fitted_every"] == 3 == -(-1101 // FOLD_SAMPLES)
    floor = offset * np.sqrt(2 / 3) * 0.9  # (the offset's rms over all samples, nearly)
    for r in held["forms"]["play"]["rows"]:
        assert r["rms_fitted"] < 0.2 * floor, r  # (the fits did not see the offset)
        assert r["rms"] > floor and r["own_rms"] > floor and r["nearest_rms"] > floor


@pytest.mark.extended  # (two leave-one-out runs)
def test_a_folds_box_does_not_depend_on_the_loop_it_holds_out(tmp_path):
    boxes = []
    for scale in (1.0, 1.5):  # only the held-out loop (the last) differs
        data = tmp_path / f"loops{scale}.csv"
        _write(data, scale_last=scale)
        out = tmp_path / f"r{scale}.json"
        main(["identify", str(data), *COMMON, "--variant", "play", "--max-steps", "3",
              "--starts", "2", "--out", str(out)])
        rows = json.loads(out.read_text())["leave_one_out"]["forms"]["play"]["rows"]
        boxes.append({r["loop"]: r["bounds"] for r in rows})
    assert boxes[0][2] == boxes[1][2]  # the fold without loop 2
    assert boxes[0][0] != boxes[1][0]  # a fold that trains on loop 2 sees it


@pytest.mark.extended  # (a leave-one-out run)
def test_a_fold_that_stops_short_sets_exit_3_and_is_named(tmp_path, capsys):
    """(On loops of unequal lengths: every fit and prediction is padded to the longest,
    here of the other tests' length, so it shares their programs.)"""
    data = tmp_path / "loops.csv"
    _write(data, samples=(40, 48, 44))
    out = tmp_path / "r.json"
    rc = main(["identify", str(data), *COMMON, "--variant", "play", "--max-steps", "1",
               "--starts", "2", "--out", str(out)])
    captured = capsys.readouterr()
    held = json.loads(out.read_text())["leave_one_out"]
    assert rc == 3
    assert all(r["outcome"] == "max_steps_reached"
               for r in held["forms"]["play"]["rows"])
    assert any("fold without loop" in s for s in held["stopped_short"])
    assert "STOPPED SHORT" in captured.out


@pytest.mark.parametrize("argv, message", [
    (["--variant", "play", "--loop", "0"], "give one of them"),
    (["--vary", "spread:log_amplitude", "--variant", "classic,play"],
     "only the forms of pinning cells"),
    (["--vary", "k:log_amplitude", "--vary-degree", "2", "--variant", "play"],
     "give at least 4 loops"),
    (["--variant", "play,nonsense"], "the forms are"),
    (["--variant", "play+nonsense"], "the forms are"),
    (["--variant", "classic,play+relax"], "loss coefficients need times"),
])
def test_comparisons_that_cannot_be_made_get_one_line(tmp_path, capsys, argv, message):
    data = tmp_path / "loops.csv"
    _write(data)
    assert main(["identify", str(data), *COMMON, *argv]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err, err


def test_one_loop_cannot_be_left_out(tmp_path, capsys):
    data = tmp_path / "one.csv"
    _write(data)
    lines = data.read_text().splitlines()
    data.write_text("\n".join([lines[0]] + [x for x in lines[1:] if x.startswith("0,")]))
    assert main(["identify", str(data), *COMMON, "--variant", "play"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "holds 1 loop" in err, err


def test_the_summary_says_when_the_nearest_loops_fit_predicts_better():
    from jaxhyst.cli.heldout import held_out_text

    row = {"loop": 0, "rms": 0.02, "data_scale": 1.0, "outcome": "successful",
           "own_rms": 0.01, "ratio": 2.0, "nearest_loop": 1, "nearest_rms": 0.005}
    held = {"forms": {"classic": {"rows": [row], "score": 0.02, "complete": True,
                                  "nearest_score": 0.005}},
            "kept": "classic", "partial": False, "stopped_short": []}
    assert "BASELINE BETTER" in held_out_text(held)
    held["forms"]["classic"]["nearest_score"] = 0.05
    assert "BASELINE BETTER" not in held_out_text(held)


def test_a_prediction_expects_the_folds_error_only_as_far_as_the_folds_extrapolated():
    from jaxhyst.cli.predictions import beyond, expect, expected_error, where_text

    assert beyond(50.0, 10.0, 20.0, "amplitude") == 2.5 == beyond(4.0, 10.0, 20.0, "frequency")
    assert beyond(15.0, 10.0, 20.0, "amplitude") == 1.0
    assert beyond(35.0, 20.0, 30.0, "temperature") == 5.0
    rows = [{"rms": 1.0, "data_scale": 100.0, "outside": True, "beyond": {"amplitude": 3.0}},
            {"rms": 0.5, "data_scale": 100.0, "outside": False, "beyond": {}}]
    expected = expected_error({"leave_one_out": {"kept": "play", "forms": {"play": {
        "rows": rows}}}})
    assert expected == {"interpolated": 0.005, "extrapolated": 0.01,
                        "reach": {"amplitude": 3.0}}
    inside, near, far, other = ({"extrapolation": w} for w in ("", "amplitude …",
                                                               "amplitude …", "frequency …"))
    expect(inside, {}, expected)
    expect(near, {"amplitude": 2.0}, expected)
    expect(far, {"amplitude": 6.0}, expected)
    expect(other, {"frequency": 1.5}, expected)  # (the folds never left the frequencies)
    assert inside["expected_relative_error"] == 0.005 and near["expected_relative_error"] == 0.01
    assert far["beyond_folds"] == {"amplitude": [6.0, 3.0]} and \
        "expected_relative_error" not in far
    assert "than any leave-one-out fold reached (×3)" in where_text(far)
    assert other["beyond_folds"] == {"frequency": [1.5, None]}
    assert "than any leave-one-out fold went" in where_text(other)
    for r in rows:  # (a result written before the folds recorded how far they went)
        del r["beyond"]
    old = expected_error({"leave_one_out": {"kept": "play", "forms": {"play": {
        "rows": rows}}}})
    assert old["reach"] is None
    expect(far := {"extrapolation": "amplitude …"}, {"amplitude": 6.0}, old)
    assert far["expected_relative_error"] == 0.01


@pytest.mark.extended  # (a rate-dependent leave-one-out)
def test_a_candidate_carries_its_own_loss_terms_into_the_folds_and_the_final_fit(
        tmp_path, capsys):
    """``--variant classic+relax``: every fold and the final fit are the rate-dependent
    model with the after-effect free (its quality on a family made by an after-effect is
    measured in benchmarks/bench_heldout_forms.py, not here: a few steps only)."""
    lines = ["loop,t_s,H_A_per_m,B_T"]
    for i, f in enumerate((50.0, 200.0)):
        drive = jh.sinusoidal_field(f, 120.0, 0.0, samples_per_period=40)
        with pytest.warns(jh.identify.SamplingWarning):  # (coarse: the plumbing is tested)
            sim = jh.simulate(TRUTH, NO_ACTUATOR, drive, jh.ClassicJA(),
                              losses=jh.Losses(relax=3e-4))
        t, H = (np.asarray(drive.observed(x)) for x in (drive.t, drive.H))
        B = MU0 * (np.asarray(sim.observed("H_hyst")) + np.asarray(sim.observed("M")))
        lines += [f"{i},{a - t[0]:.10g},{h:.10g},{b:.10g}"
                  for a, h, b in zip(t, H, B, strict=True)]
    data = tmp_path / "freq.csv"
    data.write_text("\n".join(lines) + "\n")
    out = tmp_path / "r.json"
    main(["identify", str(data), *COMMON, "--variant", "classic+relax", "--starts", "2",
          "--max-steps", "3", "--out", str(out)])
    result = json.loads(out.read_text())
    held = result["leave_one_out"]
    assert list(held["forms"]) == ["classic+relax", "nearest"]  # (the baseline: shown)
    assert held["kept"] == "classic+relax"  # (one form named: fitted as named)
    assert [r["loop"] for r in held["forms"]["classic+relax"]["rows"]] == [0, 1]
    assert all("relax" in r["extra_bounds"] for r in held["forms"]["classic+relax"]["rows"])
    assert result["problem"]["variant"] == "classic"
    assert result["problem"]["losses"] == ["relax"]
    assert np.all(np.asarray(result["params"]["relax"]["value"]) > 0)


@pytest.mark.extended  # (a leave-one-out of a condition model)
def test_a_candidate_carries_its_own_law_into_the_folds_and_the_final_fit(tmp_path,
                                                                          monkeypatch):
    """``--variant play,play@spread:log_amplitude``: the second candidate's folds and its
    final fit are condition models with the cells' width a power of the amplitude (the
    first's are not); whichever is kept, the result says which, and the kept form's three
    folds are among the final fit's starts (a few steps only: the plumbing, not the
    quality, which benchmarks/RESULTS.md measures)."""
    from jaxhyst.cli import identify

    data, out = tmp_path / "loops.csv", tmp_path / "r.json"
    _write(data)
    final, fit = [], identify.fit_by_options

    def recorded(args, problem, method, start, quiet=False, seeds=()):
        final.append(list(seeds))
        return fit(args, problem, method, start, quiet=quiet, seeds=seeds)

    monkeypatch.setattr(identify, "fit_by_options", recorded)
    main(["identify", str(data), *COMMON, "--variant", "play,play@spread:log_amplitude",
          "--starts", "4", "--max-steps", "3", "--out", str(out)])
    assert len(final) == 1 and len(final[0]) == 3  # (one per fold of the kept form)
    result = json.loads(out.read_text())
    held = result["leave_one_out"]
    assert list(held["forms"]) == ["play", "play@spread:log_amplitude", "nearest"]
    for form, t in held["forms"].items():  # (three steps: a fold's law may give no
        # material at its held-out loop — that row says so and the score is inf)
        unmade = any(r.get("no_prediction") for r in t["rows"])
        assert [r["loop"] for r in t["rows"]] == [0, 1, 2], form
        assert (t["score"] is None) if unmade else (t["score"] > 0), form
    lawful = held["kept"] == "play@spread:log_amplitude"
    assert result["problem"]["variant"] == "play"
    assert result["problem"]["vary"] == ("spread:log_amplitude" if lawful else None)
    assert ("spread:log_amplitude" in result.get("coefficients", {})) == lawful


def test_a_loops_own_fit_is_never_worse_than_another_loops_fit_inside_its_box(tmp_path):
    """Own fits cut short (two steps): where another loop's fit, inside this loop's box,
    predicts it better than its own fit, the loop is fitted again from it and ends no
    worse than that prediction (so no ratio rests on a fit a neighbour beats)."""
    from jaxhyst.cli import heldout
    from jaxhyst.cli.identify import check_options
    from jaxhyst.cli.parser import build_parser
    from jaxhyst.io import read_loops

    data = tmp_path / "loops.csv"
    _write(data)
    args = build_parser().parse_args(["identify", str(data), *COMMON, "--variant", "play",
                                      "--max-steps", "2", "--starts", "2"])
    spec = {**check_options(args), **heldout.candidate_spec(args, "play"), "joint": False,
            "vary": None, "per_loop": []}
    loops = read_loops(spec["data"], spec["columns"])
    own = [heldout._fit(args, {**spec, "loop": lp.index}, None, [lp], "lm") for lp in loops]
    better, _ = heldout._own_best(args, own, loops, "lm", "play")
    improved = 0
    for i, (result, problem, _) in enumerate(own):
        for j, (result_j, problem_j, spec_j) in enumerate(own):
            u = np.asarray(problem.space.u_from_params(result_j.params))
            if j == i or not np.all((u > 0) & (u < 1)):
                continue
            rms = heldout._predict(spec_j, problem_j, result_j.params, loops[i])["rms"]
            assert better[i][0].rms_error <= rms * (1 + 1e-9), (i, j)
            improved += rms < result.rms_error
    assert improved  # (the case arises here: loop 2's two-step fit is beaten)


def test_loops_at_several_frequencies_get_rate_dependent_candidates_by_default():
    """No form named: the static candidates, unless the loops span frequencies with times
    (then two static forms beside the two rate mechanisms); a named loss coefficient or a
    law in the frequency keeps the static candidates (the user chose the rate model).
    Three loops or more of different amplitudes add the play form with its cells' width
    a power of the amplitude; a named candidate's own law is checked before any work."""
    from types import SimpleNamespace

    from jaxhyst.cli.candidates import (
        AMPLITUDE_CANDIDATE,
        CANDIDATES,
        RATE_CANDIDATES,
        candidates,
    )
    from jaxhyst.cli.parser import build_parser
    from jaxhyst.cli.spec import CLIError

    def loops(freqs, timed=True):
        return [SimpleNamespace(conditions={"frequency": f}, t=np.zeros(3) if timed else None,
                                H=None, I=None) for f in freqs]

    def chosen(extra, lps):
        args = build_parser().parse_args(["identify", "x.csv", "--joint", "--leave-one-out",
                                          *extra])
        return tuple(candidates(args, lps))

    assert chosen([], loops((50.0, 100.0, 400.0))) == RATE_CANDIDATES
    assert chosen([], loops((100.0, 105.0))) == CANDIDATES  # (within 10 %: one frequency)
    assert chosen([], loops((50.0, 400.0), timed=False)) == CANDIDATES
    assert chosen([], loops((None, None))) == CANDIDATES
    assert chosen([], None) == CANDIDATES  # (before the file is read: the options' check)
    assert chosen(["--losses", "eddy"], loops((50.0, 400.0))) == CANDIDATES
    assert chosen(["--vary", "k:log_f"], loops((50.0, 400.0))) == CANDIDATES
    assert chosen(["--variant", "play"], loops((50.0, 400.0))) == ("play",)
    # loops of different amplitudes (three or more): the pinning cells' width may follow
    # the amplitude too, as a candidate of its own
    def peaks(*amplitudes):
        return [SimpleNamespace(conditions={}, t=None, H=a * np.sin(np.arange(9.0)), I=None)
                for a in amplitudes]

    assert chosen([], peaks(15.0, 36.0, 107.0)) == (*CANDIDATES, AMPLITUDE_CANDIDATE)
    assert chosen([], peaks(15.0, 107.0)) == CANDIDATES  # (a fold's law needs two loops)
    assert chosen([], peaks(100.0, 102.0, 104.0)) == CANDIDATES  # (one amplitude)
    # (without the 15 A/m loop a fold's two are at one amplitude: it fixes no slope)
    assert chosen([], peaks(15.0, 100.0, 104.0)) == CANDIDATES
    assert chosen([], peaks(15.0, 15.5, 100.0, 104.0)) == (*CANDIDATES, AMPLITUDE_CANDIDATE)
    assert chosen(["--vary", "k:log_amplitude"], peaks(15.0, 36.0, 107.0)) == CANDIDATES
    # a B-driven fit's law reads the peak flux density: loops near saturation, whose peak
    # fields span amplitudes but whose peak B do not, give its folds no slope to fit
    def saturated(*fields_and_B):
        return [SimpleNamespace(conditions={}, t=None, H=h * np.sin(np.arange(9.0)), I=None,
                                signals={"B": b * np.sin(np.arange(9.0))})
                for h, b in fields_and_B]

    near = saturated((300.0, 1.50), (900.0, 1.52), (2700.0, 1.54))
    assert chosen([], near) == (*CANDIDATES, AMPLITUDE_CANDIDATE)
    assert chosen(["--driven-by", "B"], near) == CANDIDATES
    assert chosen(["--driven-by", "B"], saturated((15.0, 0.08), (36.0, 0.19), (107.0, 0.34))) \
        == (*CANDIDATES, AMPLITUDE_CANDIDATE)
    # a candidate's own law: one parameter, of its form, not also in --vary
    assert chosen(["--variant", "classic,play@spread:log_amplitude"], None) == \
        ("classic", "play@spread:log_amplitude")
    for bad in ("classic@spread:log_amplitude", "play@", "play@k:log_f,c:log_f",
                "play@spread:nonsense"):
        with pytest.raises(CLIError):
            chosen(["--variant", f"play,{bad}"], None)
    with pytest.raises(CLIError):
        chosen(["--variant", "play@k:log_amplitude", "--vary", "k:log_f"], None)
    # each candidate once, one law after '@', each parameter of --vary once
    with pytest.raises(CLIError, match="named twice"):
        chosen(["--variant", "play,classic,play"], None)
    with pytest.raises(CLIError, match="one condition law"):
        chosen(["--variant", "play@spread:log_amplitude@k:log_amplitude"], None)
    with pytest.raises(CLIError, match="named twice"):
        chosen(["--vary", "k:log_f,k:T"], loops((50.0, 400.0)))
    args = build_parser().parse_args(["identify", "x.csv", "--variant",
                                      "play@spread:log_amplitude"])
    with pytest.raises(CLIError, match="needs --joint"):  # (one loop: no law to fit)
        candidates(args, None)


def test_a_comparison_keeps_the_nearest_condition_baseline_where_it_predicts_best():
    """The baseline is scored from the best form's single fits (its rows: the nearest
    other loop's fit predicting each held-out loop) and kept where it beats every form —
    in a comparison; one form named is fitted as named and the baseline only shown."""
    from jaxhyst.cli.heldout import held_out_text
    from jaxhyst.cli.nearest import NEAREST, choose

    def form(score, near):
        rows = [{"loop": i, "rms": score, "data_scale": 1.0, "outcome": "successful",
                 "own_rms": 0.001, "ratio": score / 0.001, "nearest_loop": 1 - i,
                 "nearest_rms": near[i], "nearest_outcome": "successful", "outside": False,
                 "beyond": {}} for i in range(2)]
        return {"rows": rows, "score": score, "complete": True,
                "nearest_score": float(np.sqrt(near[0] * near[1]))}

    conditions = [{"amplitude": 40.0, "frequency": None, "temperature": None},
                  {"amplitude": 44.0, "frequency": None, "temperature": None}]
    table = {"classic": form(0.03, (0.004, 0.009)), "play@spread:log_amplitude":
             form(0.02, (0.002, 0.008))}
    kept, source = choose(table, conditions, comparison=True)
    assert kept == NEAREST and source == "play@spread:log_amplitude"
    base = table[NEAREST]
    assert base["form"] == "play" and base["score"] == pytest.approx(0.004)
    assert [r["rms"] for r in base["rows"]] == [0.002, 0.008]
    assert [r["nearest_loop"] for r in base["rows"]] == [1, 0]
    text = held_out_text({"forms": table, "kept": kept, "partial": False,
                          "stopped_short": []})
    assert "kept: the nearest-condition baseline" in text and "BASELINE BETTER" not in text
    # a form that predicts better than its neighbours' fits is kept over the baseline
    table = {"classic": form(0.003, (0.004, 0.009))}
    assert choose(dict(table), conditions, comparison=True)[0] == "classic"
    # one form named: fitted as named, the baseline only said to be better
    table = {"classic": form(0.03, (0.004, 0.009))}
    kept, _ = choose(table, conditions, comparison=False)
    assert kept == "classic" and NEAREST in table
    text = held_out_text({"forms": table, "kept": kept, "partial": False,
                          "stopped_short": []})
    assert "BASELINE BETTER" in text and "to let the comparison keep it" in text


@pytest.mark.extended  # (two forms' leave-one-out in full, then predictions of new loops)
def test_loops_no_form_carries_across_keep_the_nearest_loops_fit_and_predict_by_it(
        tmp_path, capsys):
    """Two materials, two loops each at neighbouring amplitudes: no shared form predicts
    a held-out loop as well as the other loop of its pair does, so the comparison keeps
    the nearest-condition baseline; the result and the saved model then predict a new
    loop by the fitted loop nearest to it (the same prediction from both), better than
    the best form's fold predicted that loop."""
    from jaxhyst.identify.joint import NO_ACTUATOR

    other = TRUTH.replace(Ms=5.0e5, a=60.0, k=80.0, c=0.1)
    form = jh.PlayJA(spread=0.6, cells=8)

    def write(path, loops):
        lines = ["loop,H_A_per_m,B_T"]
        for i, (p, Hm) in enumerate(loops):
            drive = jh.sinusoidal_field(1.0, Hm, 0.0, samples_per_period=48)
            sim = jh.simulate_unchecked(p, NO_ACTUATOR, drive, form, substeps=1)
            H = np.asarray(drive.observed(drive.H))
            B = MU0 * (H + np.asarray(drive.observed(sim.M)))
            lines += [f"{i},{h:.10g},{b:.10g}" for h, b in zip(H, B, strict=True)]
        path.write_text("\n".join(lines) + "\n")

    data, new = tmp_path / "loops.csv", tmp_path / "new.csv"
    write(data, [(TRUTH, 40.0), (TRUTH, 44.0), (other, 200.0), (other, 220.0)])
    write(new, [(TRUTH, 42.0), (other, 210.0)])
    out, saved = tmp_path / "r.json", tmp_path / "m.eqx"
    main(["identify", str(data), *COMMON, "--variant", "classic,play", "--max-steps",
          "100", "--starts", "2", "--out", str(out), "--save-model", str(saved)])
    assert "kept: the nearest-condition baseline" in capsys.readouterr().out
    result = json.loads(out.read_text())
    held = result["leave_one_out"]
    assert held["kept"] == "nearest" and held["forms"]["nearest"]["form"] in ("classic",
                                                                              "play")
    assert result["problem"]["predict_by"] == "nearest"
    assert np.ptp(result["params"]["k"]["value"]) > 0  # (one set per loop)
    predicted = []
    for source in (out, saved):
        assert main(["predict", str(source), str(new), "--json"]) == 0
        predicted.append(json.loads(capsys.readouterr().out)["loops"])
    assert [r["rms"] for r in predicted[0]] == pytest.approx([r["rms"] for r in predicted[1]],
                                                             rel=1e-9)
    for rows in predicted:  # (each says whose parameters: 42 → 44 A/m, 210 → 220 A/m)
        assert [r["by_fitted_loop"] for r in rows] == [1, 3]
    from jaxhyst.cli.models import load_model_fit  # (report's reading of the model file)

    params = load_model_fit(str(saved))[3]
    assert np.shape(jax.tree.leaves(params)[0]) == (4,)
    best = min((f for f in held["forms"] if f != "nearest"),
               key=lambda f: held["forms"][f]["score"])
    for row, fitted in zip(predicted[0], (1, 3), strict=True):  # (44 and 220 A/m nearest)
        fold = held["forms"][best]["rows"][fitted]["rms"]
        assert row["rms"] < fold, (row, fold)


def test_a_law_that_gives_no_material_at_a_held_out_loop_is_a_row_not_an_error(tmp_path):
    """A fold's condition law extrapolated to its held-out loop may give parameters no
    material has (here the cells' spread far beyond [0, 10]): that row has no prediction
    (inf, said in the table, None in the result file), the comparison goes on, and
    `predict` at such a loop stops with one line naming the loop and the value —
    it used to end the whole command with the simulator's "Parameter … must lie in",
    as if the user had typed the value."""
    from jaxhyst.cli import build_problem
    from jaxhyst.cli.heldout import _predict, held_out_text
    from jaxhyst.cli.predictions import BeyondLaw, expected_error, predict_loops, where_text
    from jaxhyst.cli.spec import read_data
    from jaxhyst.io import bounds_to_json

    data = tmp_path / "loops.csv"
    _write(data)
    loops = read_data(str(data))
    spec = {"data": str(data), "columns": None, "loop": None, "output": None,
            "actuator": NO_ACTUATOR.to_dict(), "bounds": bounds_to_json(jh.TABLE1_BOUNDS),
            "fixed": {}, "run_in_periods": 1, "substeps": 1, "variant": "play",
            "cells": 8, "joint": True, "per_loop": [], "vary": "spread:log_amplitude"}
    problem = build_problem(spec, loops)
    names = problem.space.names
    assert "spread:log_amplitude" in names
    values = {"Ms": 3.5e5, "a": 25.0, "k": 30.0, "alpha": 1e-5, "c": 0.3, "spread": 2.0,
              "spread:log_amplitude": -3.0}  # (spread ∝ Hm^-3: 20 at 40 A/m)
    params = problem.space.params_from_free(np.array([values[n] for n in names]))
    with pytest.raises(BeyondLaw, match=r"loop 0 \(peak field 40 A/m\): .*spread") as err:
        predict_loops(spec, problem, params, [loops[0]])
    assert "\n" not in str(err.value) and "Parameter" not in str(err.value)
    row = _predict(spec, problem, params, loops[0])
    assert row["rms"] == np.inf and "spread" in row["no_prediction"]
    assert np.all(np.isnan(row["_curve"][0])) and row["data_scale"] > 0
    row = {**{k: v for k, v in row.items() if k != "_curve"}, "loop": 0,
           "outcome": "successful"}
    held = {"forms": {"play": {"rows": [row], "score": np.inf, "complete": True,
                               "nearest_score": None}},
            "kept": "play", "partial": False, "stopped_short": []}
    assert "NO PREDICTION: the law gives spread" in held_out_text(held)
    saved = json.loads(json.dumps(jh.io.json_safe({"leave_one_out": held})))
    assert saved["leave_one_out"]["forms"]["play"]["rows"][0]["rms"] is None
    expected = expected_error(saved)
    assert expected["interpolated"] == np.inf
    assert "no error to expect" in where_text({"extrapolation": "",
                                               "expected_relative_error": np.inf})


def test_an_own_fit_cut_at_its_step_limit_is_continued_once(monkeypatch):
    """An own fit that stopped at its step limit is the denominator of its loop's ratio:
    cut short, it flatters the form (a fold so cut: its held-out error is not final). It
    is fitted once more from where it stopped (the same batch) and the better kept; a
    converged one is left alone."""
    from types import SimpleNamespace

    from jaxhyst.cli import fitting, heldout

    calls = []

    def refit(args, problem, params, method, quiet=False):
        calls.append((params, method))
        return SimpleNamespace(result="successful", cost=1.0, params=params)

    monkeypatch.setattr(fitting, "refit_from", refit)
    cut = SimpleNamespace(result="max_steps_reached", cost=2.0, params={"k": np.array([3.0])})
    fit = (cut, "problem", {"variant": "play"})
    again = heldout._continued(SimpleNamespace(), fit, "lm", "loop 0 alone")
    assert again[0].result == "successful" and again[1:] == fit[1:]
    assert calls == [({"k": 3.0}, "lm")]  # (from where it stopped, by the same method)
    done = (SimpleNamespace(result="successful", cost=2.0, params={}), "p", {"variant": "x"})
    assert heldout._continued(SimpleNamespace(), done, "lm", "x") is done and len(calls) == 1
    worse = SimpleNamespace(result="max_steps_reached", cost=0.5, params={"k": 3.0})
    assert heldout._continued(SimpleNamespace(), (worse, "p", {"variant": "x"}), "lm",
                              "x")[0] is worse  # (the better of the two)


def test_an_own_fit_cut_short_fails_the_comparison_only_where_the_choice_rests_on_it():
    """A loop's own fit that stopped short sets its candidate's ratios and, for the
    candidate whose single fits the baseline uses, the baseline's predictions: it makes
    the exit status 3 for the kept candidate and that one (a law's candidate by its
    form's single fits), and is only listed for the others (whose folds' score decides)."""
    from jaxhyst.cli.heldout import counted_short
    from jaxhyst.cli.nearest import NEAREST

    classic, relax, play = ("classic, loop 3 alone: max_steps_reached",
                            "play+relax, loop 0 alone: max_steps_reached",
                            "play, loop 1 alone: max_steps_reached")
    alone = {("classic", ()): [classic], ("play", ("relax",)): [relax], ("play", ()): [play]}
    assert counted_short(alone, "play+relax", "play+relax") == ([relax], [classic, play])
    counted, other = counted_short(alone, "play@spread:log_amplitude", "classic")
    assert sorted(counted) == sorted([classic, play]) and other == [relax]
    assert counted_short(alone, NEAREST, "classic") == ([classic], [relax, play])
    assert counted_short({}, "classic", None) == ([], [])
