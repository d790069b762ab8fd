"""The installed ``jaxhyst`` command end to end (issue 6) and sharding over two host
devices (issue 7), in subprocesses. The chains themselves are in cli_chains.py and start
in the background at collection (conftest.py); these tests wait for them and check what
they left behind."""

from __future__ import annotations

import json
import os
import time

import numpy as np
import pytest
from conftest import CLI_CHAINS, chain_pid

import jaxhyst as jh

TIMEOUT = 1800  # s, per chain (the docs chain took 1 122 s on a loaded 2-core VM)


def _finished(chain):
    """(directory, status) of a chain once it has ended (started by this process or by
    another worker of the run: conftest.py)."""
    if chain not in CLI_CHAINS:
        pytest.skip("chain not started (conftest.pytest_collection_finish)")
    d = CLI_CHAINS[chain]
    status = os.path.join(d, "status.json")
    deadline = time.monotonic() + TIMEOUT
    while not os.path.exists(status):
        pid = chain_pid(d)
        if pid is not None and not _alive(pid):
            time.sleep(1.0)  # (its status may have been written just before it ended)
            if not os.path.exists(status):
                pytest.fail(f"the {chain} chain ended without its status.json ({d})")
        if time.monotonic() > deadline:
            pytest.fail(f"the {chain} chain did not end within {TIMEOUT} s ({d})")
        time.sleep(0.5)
    with open(status) as fh:
        return d, json.load(fh)


def _alive(pid: int) -> bool:
    """Whether process ``pid`` is running (a zombie our own process has not reaped
    counts as ended)."""
    try:
        waited, _ = os.waitpid(pid, os.WNOHANG)  # (our child: reap it if it ended)
        return waited == 0
    except ChildProcessError:  # (another worker's child)
        pass
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    try:  # (Linux: a zombie of another worker's has ended)
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except (OSError, IndexError):
        return True


def _log(d, name):
    with open(os.path.join(d, name)) as fh:
        return fh.read()


def docs_step(step):
    """(directory, status) of one step of docs/generate.py as the docs chain ran it: the
    pages' own commands, run once for the pages and checked here."""
    d, status = _finished("docs")
    if status["generate"] != 0 and not os.path.exists(
            os.path.join(d, "gen", "generated", step, "status.json")):
        pytest.fail(_log(d, "generate.log"))
    step_dir = os.path.join(d, "gen", "generated", step)
    with open(os.path.join(step_dir, "status.json")) as fh:
        return step_dir, json.load(fh)


def _output(d, label):
    """What a command of a docs step printed: stdout, then stderr."""
    return _log(d, f"{label}.log") + _log(d, f"{label}.err")


@pytest.mark.docs  # (the docs chain runs the pages' commands; checked here)
def test_simulate_csv_identify_json_recovers_the_parameters():
    """The README's and the getting-started page's own commands (simulate at 50 samples
    per period, identify the CSV, report): they work and print no warning (the estimated
    error is 5e-6, inside 1e-5)."""
    d, status = docs_step("getting_started")
    for label in ("simulate", "identify", "report"):
        assert status[label] == 0, _output(d, label)
        assert "warning" not in _output(d, label).lower(), _output(d, label)
    with open(os.path.join(d, "result.json")) as fh:
        res = json.load(fh)
    truth = jh.TABLE1_TRUE.to_dict()
    for n in ("a", "k", "alpha", "c", "E", "Kz", "Cz"):
        assert res["params"][n]["free"]
        assert abs(res["params"][n]["value"] / truth[n] - 1) < 1e-6, (n, res["params"][n])
    for n in ("Ms", "lambda_s", "Mz"):
        assert not res["params"][n]["free"] and res["params"][n]["value"] == truth[n]
    assert res["params"]["E"]["unit"] == "N/m^2"
    assert res["identifiability"]["rank"] == 7
    assert res["problem"]["output"] == "y"
    for fig in ("fit.png", "report.png"):
        assert os.path.getsize(os.path.join(d, fig)) > 10_000


@pytest.mark.extended  # (a command-line chain, a background subprocess)
def test_identify_killed_midway_resumes_from_its_checkpoint():
    d, status = _finished("resume")
    assert status["killed"], "the run finished before its first checkpoint"
    assert status["first"] != 0  # SIGKILL
    assert status["second"] == 0, _log(d, "second.log")
    with open(os.path.join(d, "result.json")) as fh:
        res = json.load(fh)
    assert len(res["history"]) == 405  # --generations in all, none lost or repeated
    gens = [h["generation"] for h in res["history"]]
    assert gens == list(range(1, 406))
    second = _log(d, "second.log")
    assert "generation 1/" not in second  # it continued, not restarted
    assert "/405 " in _log(d, "first.log")  # the count asked for is the count shown
    assert np.isfinite(res["cost"])


@pytest.mark.docs  # (the docs chain runs the pages' commands; checked here)
def test_reproduce_table1_quick_runs():
    d, status = docs_step("reproduce")
    assert status["table1"] == 0, _output(d, "table1")
    assert "warning" not in _output(d, "table1").lower()  # (a README command)
    with open(os.path.join(d, "table1", "table1.json")) as fh:
        study = json.load(fh)
    assert [r["method"] for r in study["runs"]] == ["GATR1", "GALM1", "GATR2", "GALM2"]
    for r in study["runs"]:
        assert r["cost"] < 1e-12 and r["combination_error"] < 1e-4, r["method"]
    assert "| Ms |" in open(os.path.join(d, "table1", "table1.md")).read()
    print(f"reproduce table1 --quick: {status['table1_seconds']:.0f} s")


@pytest.mark.extended  # (a command-line chain, a background subprocess)
def test_reproduce_interrupted_leaves_partial_files():
    d, status = _finished("reproduce")
    # interrupted after its first run: exit 130, and every file says it is partial
    assert status["partial"] == 130, _log(d, "partial.log")
    with open(os.path.join(d, "partial", "table1.json")) as fh:
        partial = json.load(fh)
    assert partial["partial"] and len(partial["runs"]) < partial["planned_runs"] == 4
    md = open(os.path.join(d, "partial", "table1.md")).read()
    assert md.startswith("**PARTIAL: interrupted**")


@pytest.mark.extended  # (a command-line chain, a background subprocess)
def test_sharded_population_matches_unsharded():
    d, status = _finished("sharding")
    assert status["sharding"] == 0, _log(d, "sharding.log")
    with open(os.path.join(d, "inner.json")) as fh:
        out = json.load(fh)
    assert out["devices"] == 2
    # each member's result is independent of the others up to round-off; the batch rule of
    # the time loop takes its switch branch when any member of a device's share needs it,
    # so how the population is split changes the round-off (measured 2.9e-11 relative)
    assert out["ga_history_max_rel_diff"] <= 1e-9, out
    assert out["ga_params_max_rel_diff"] <= 1e-9, out
    # a joint problem's loops split over the devices: the same residuals and Jacobian
    assert out["loops_sharded"], out
    assert out["loops_residual_max_diff"] <= 1e-14, out
    assert out["loops_jacobian_max_rel_diff"] <= 1e-12, out


def _covered(study):
    """Every identifiable, determined combination of every run: (label, truth, value,
    half-width of the 95 % interval)."""
    from jaxhyst.cli.studies import undetermined

    out = []
    for r in study["runs"]:
        skip = set(undetermined(r))
        for label, c in r["combinations"].items():
            if label not in skip:
                lo, hi = c["interval"]
                out.append((f"{r['label']} {label}", c["truth"], c["value"], (hi - lo) / 2))
    return out


def _check_experiment(study, outcomes=("successful",)):
    assert all(r["outcome"] in outcomes for r in study["runs"]), study["markdown"]
    for r in study["runs"]:  # a χ² at the declared noise level: the optimum, not a stall
        assert r["cost"] < 2.0 * r["n_data"], (r["label"], r["cost"], r["n_data"])
    rows = _covered(study)
    inside = [abs(v - t) <= h for _, t, v, h in rows]
    # 95 % intervals: most hold the truth, none misses it by more than twice its width
    # (≈ 3.9 standard errors, p ≈ 1e-4)
    assert np.mean(inside) >= 0.85, [r for r, ok in zip(rows, inside, strict=True) if not ok]
    assert all(abs(v - t) <= 2 * h for _, t, v, h in rows), rows
    return rows


@pytest.mark.docs  # (the docs chain runs the pages' commands; checked here)
def test_reproduce_table3_and_table2_quick():
    d, status = docs_step("reproduce")
    assert status["table3"] == 0, _output(d, "table3")
    assert status["table2"] == 0, _output(d, "table2")
    with open(os.path.join(d, "table3", "table3.json")) as fh:
        t3 = json.load(fh)
    assert [r["frequency_hz"] for r in t3["runs"]] == [10, 800, 1000, 1250, 2000]
    rows = _check_experiment(t3)
    determined = {r for r, *_ in rows}
    # the structural ratios are determined at 800 Hz and above (dynamics), not at 10 Hz
    assert {"800 Hz Kz/Mz", "800 Hz Cz/Mz", "2000 Hz Kz/Mz"} <= determined
    assert not {"10 Hz Kz/Mz", "10 Hz Cz/Mz"} & determined
    for fig in ("fig7_loops.png", "fig8_frequency_response.png"):
        assert os.path.getsize(os.path.join(d, "table3", fig)) > 10_000
    with open(os.path.join(d, "table2", "table2.json")) as fh:
        t2 = json.load(fh)
    assert len(t2["runs"]) == 3
    # at 2 Hz the cost is flat along Kz/Mz, Cz/Mz: the convergence check may end at its
    # step limit with χ² already at the noise level (checked in _check_experiment)
    rows = _check_experiment(t2, ("successful", "max_steps_reached"))
    # at 2 Hz the runs agree on a, k, c but cannot determine Cz/Mz
    assert {"run 0 k", "run 1 k", "run 2 k"} <= {r for r, *_ in rows}
    assert not any(r.endswith("Cz/Mz") for r, *_ in rows)
    print(f"reproduce table3 + table2 --quick: "
          f"{status['table3_seconds'] + status['table2_seconds']:.0f} s")


@pytest.mark.extended  # (a command-line chain, a background subprocess)
def test_measured_loop_default_command_bounds_stops_and_start():
    """Issue 15 through the command: a digitized-like B–H loop (mT, no t) with every
    default; a parameter on its bound exits 4 and says so; a fit stopped at its step
    limit exits 3 and says so; --start continues from a result; report finds the data
    through the relative path stored in the result."""
    d, status = _finished("measured")
    log = _log(d, "default.log")
    assert status["default"] == 0, log
    assert "bounds derived from the data: Ms [" in log
    assert "compiling the first step" in log and "best cost" in log  # progress
    assert "lambda_s" not in log and "(fixed)" not in log  # only what affects B is printed
    with open(os.path.join(d, "first.json")) as fh:
        first = json.load(fh)
    assert first["success"] and first["at_bound"] == {} and first["warnings"] == []
    assert first["problem"]["data"] == "loop.csv"  # relative to the result file
    assert os.path.getsize(os.path.join(d, "fit.png")) > 0
    assert f"wrote {os.path.join(d, 'fit.png')}" in log  # every file written is announced
    log = _log(d, "at_bound.log")
    assert status["at_bound"] == 4, log
    assert "warning: k ended at its lower bound 12.5" in log and "AT LOWER BOUND" in log
    assert "null direction" not in log.lower().replace("no null", "")
    log = _log(d, "short.log")
    assert status["short"] == 3, log
    assert "warning: the fit stopped at its step limit" in log
    assert status["start"] == 0, _log(d, "start.log")
    assert "one start from" in _log(d, "start.log")
    with open(os.path.join(d, "sub", "again.json")) as fh:
        again = json.load(fh)
    assert again["problem"]["data"] == os.path.join("..", "loop.csv")
    assert abs(again["cost"] / first["cost"] - 1) < 1e-6
    assert status["report"] == 0, _log(d, "report.log")


@pytest.mark.extended  # (a command-line chain, a background subprocess)
def test_compensate_writes_its_files_learns_from_a_plant_and_reports_the_unreachable():
    d, status = _finished("compensate")
    assert status["first"] == 0, _log(d, "first.log")
    with open(os.path.join(d, "first.json")) as fh:
        first = json.load(fh)
    assert first["error"] < 1e-6 < 0.05 < first["uncompensated_error"]
    assert first["unreachable"] == [] and first["limits"]["lower"] == -2.5
    table = np.loadtxt(os.path.join(d, "first.csv"), delimiter=",", skiprows=1)
    with open(os.path.join(d, "first.csv")) as fh:
        assert fh.readline().strip() == "t [s],I [A],H [A/m],y [m]"
    assert table.shape == (200, 4) and np.all(np.abs(table[:, 1]) <= 2.5)
    assert os.path.getsize(os.path.join(d, "first.png")) > 10_000
    for k in (1, 2):  # the lab's chain: simulate (a plant) → compensate --measured
        assert status[f"simulate{k}"] == 0, _log(d, f"simulate{k}.log")
        assert status[f"learn{k}"] == 0, _log(d, f"learn{k}.log")
    with open(os.path.join(d, "run1.csv")) as fh:
        assert fh.readline().startswith("t_s,I_A,H_A_per_m")  # the current applied
    with open(os.path.join(d, "state.json")) as fh:
        state = json.load(fh)
    assert state["iteration"] == 2 and len(state["reports"]) == 2
    assert "iteration 2: measured error" in _log(d, "learn2.log")
    before, after_one, after_two = status["plant_errors"]
    assert before > 0.02 and after_two < after_one < before / 4, status["plant_errors"]
    assert status["beyond"] == 3, _log(d, "beyond.log")
    with open(os.path.join(d, "beyond.json")) as fh:
        beyond = json.load(fh)
    assert any(u["reason"] == "beyond the stroke" for u in beyond["unreachable"])
    assert "beyond the stroke at t =" in _log(d, "beyond.log")
