"""Files and the command line (the README demo)."""

from __future__ import annotations

import json
import os
import stat

import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst.cli import main
from jaxhyst.io import atomic_write_text


def test_cli_simulate_writes_csv_and_png(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    csv, png = tmp_path / "loop.csv", tmp_path / "loop.png"
    assert main(["simulate", "--csv", str(csv), "--png", str(png), "--json"]) == 0
    out = capsys.readouterr().out
    assert '"samples_observed": 201' in out
    data = np.genfromtxt(csv, delimiter=",", names=True)
    # the current first (a file that drives the next simulate or a rig), then the field
    assert data.dtype.names[:4] == ("t_s", "I_A", "H_A_per_m", "M_A_per_m")
    assert len(data) == 201 and np.all(np.isfinite(data["y_m"]))
    assert 60e-6 < data["y_m"].min() < data["y_m"].max() < 100e-6
    assert png.stat().st_size > 10_000


def test_cli_simulate_drives_by_flux_density_and_with_losses(tmp_path, capsys):
    csv = tmp_path / "flux.csv"
    assert main(["simulate", "--flux-amplitude", "0.5", "--frequency", "1000", "--eddy",
                 "0.05", "--excess", "0.5", "--samples-per-period", "100", "--csv", str(csv),
                 "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    drive = jh.sinusoidal_flux(1000.0, 0.5, samples_per_period=100)
    sim = jh.simulate_flux_unchecked(jh.TABLE1_TRUE, drive, losses=jh.Losses(0.05, 0.5))
    assert summary["loss_W_per_m3"] == pytest.approx(float(sim.loss_density(1000.0)),
                                                     rel=1e-12)
    data = np.genfromtxt(csv, delimiter=",", names=True)
    np.testing.assert_allclose(data["H_A_per_m"], np.asarray(sim.observed("H")), rtol=1e-12)
    # the H-driven actuator with the same losses: its loop is wider than without
    assert main(["simulate", "--eddy", "0.05", "--json"]) == 0
    lossy = json.loads(capsys.readouterr().out)
    assert main(["simulate", "--json"]) == 0
    static = json.loads(capsys.readouterr().out)
    assert lossy["y_max_m"] != static["y_max_m"]


def test_cli_bad_input_is_one_line_without_traceback(capsys):
    assert main(["simulate", "--frequency", "-5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err
    assert "--frequency" in err and "must be a positive number" in err, err


def test_atomic_write_leaves_old_file_on_failure_and_normal_permissions(tmp_path):
    target = tmp_path / "out.txt"
    atomic_write_text(target, "first\n")
    mode = stat.S_IMODE(os.stat(target).st_mode)
    assert mode & 0o044  # readable by group/others under a normal umask (not 0600)

    with pytest.raises(TypeError):
        atomic_write_text(target, None)  # fails mid-write
    assert target.read_text() == "first\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]  # no temp file left


def test_writer_keeps_devices_fifos_and_links(tmp_path):
    """A device, a FIFO or a link through /dev is written in place, never replaced by a
    regular file; a link to a regular file stays a link (its target is replaced); an
    existing file keeps its permission bits."""
    import threading

    from jaxhyst._files import write_bytes, write_text, writes_in_place

    # /dev/null: still the character device afterwards (a rename would replace it)
    write_text("/dev/null", "nothing\n")
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)

    fifo = tmp_path / "pipe"
    os.mkfifo(fifo)
    got = {}

    def reader():
        with open(fifo, "rb") as fh:
            got["data"] = fh.read()

    thread = threading.Thread(target=reader)
    thread.start()
    write_bytes(fifo, b"through the pipe")
    thread.join(10)
    assert got["data"] == b"through the pipe"
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)

    target = tmp_path / "real.txt"
    target.write_text("old")
    os.chmod(target, 0o640)
    link = tmp_path / "link.txt"
    link.symlink_to(target)
    write_text(link, "new")
    assert link.is_symlink() and target.read_text() == "new"
    assert stat.S_IMODE(os.stat(target).st_mode) == 0o640

    through_dev = tmp_path / "out"
    through_dev.symlink_to("/dev/null")
    assert writes_in_place(through_dev) and writes_in_place("/dev/null")
    write_text(through_dev, "x")
    assert through_dev.is_symlink() and stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert not writes_in_place(target) and not writes_in_place(tmp_path / "new.txt")
    with pytest.raises(IsADirectoryError):
        write_text(tmp_path, "x")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link.txt", "out", "pipe",
                                                          "real.txt"]


def test_cli_writes_to_a_device_in_place(tmp_path, capsys):
    """``--csv /dev/null`` and ``--png`` into a FIFO: the command succeeds and the device
    and the FIFO are still what they were."""
    import threading

    pytest.importorskip("matplotlib")
    fifo = tmp_path / "figure"
    os.mkfifo(fifo)
    got = {}

    def reader():
        with open(fifo, "rb") as fh:
            got["data"] = fh.read()

    thread = threading.Thread(target=reader, daemon=True)
    thread.start()
    assert main(["simulate", "--csv", "/dev/null", "--png", str(fifo),
                 "--samples-per-period", "100"]) == 0
    thread.join(30)
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert got["data"][:8] == b"\x89PNG\r\n\x1a\n"
    assert [p.name for p in tmp_path.iterdir()] == ["figure"]


# -- reading measured loops ------------------------------------------------------------------


def _loop_rows(n=20, loops=(0,)):
    rows = []
    for k in loops:
        for i in range(n):
            t = i * 1e-4
            rows.append((k, t, 1e3 * np.sin(2 * np.pi * i / (n - 1)), 0.5 + 0.1 * i))
    return rows


def test_read_loops_units_headers_delimiters_and_loop_column(tmp_path):
    from jaxhyst.io import DataError, read_loops

    f = tmp_path / "loops.tsv"
    f.write_text("# measured\nloop\tt [ms]\tH [kA/m]\ty [um]\n"
                 + "".join(f"{k}\t{t * 1e3}\t{h / 1e3}\t{y}\n" for k, t, h, y in
                           _loop_rows(loops=(3, 1))))
    loops = read_loops(f)
    assert [lp.index for lp in loops] == [3, 1]
    lp = loops[0]
    assert lp.n_samples == 20 and lp.I is None
    np.testing.assert_allclose(lp.t[1], 1e-4)
    np.testing.assert_allclose(np.max(lp.H), 1e3 * np.max(np.sin(2 * np.pi * np.arange(20) / 19)))
    np.testing.assert_allclose(lp.signals["y"][0], 0.5e-6)
    # headerless, whitespace separated, names given
    g = tmp_path / "plain.txt"
    g.write_text("".join(f"{t} {h} {y}\n" for _, t, h, y in _loop_rows()))
    (lp,) = read_loops(g, columns="t,H,B (mT)")
    np.testing.assert_allclose(lp.signals["B"][0], 0.5e-3)
    # columns of no use named '-' (a text column, a sample id): skipped, on either path
    h = tmp_path / "extra.csv"
    h.write_text("sample,t,H,material,B\n" + "".join(f"{i},{t},{h},3C90,{y}\n" for i, (
        _, t, h, y) in enumerate(_loop_rows())))
    (lp,) = read_loops(h, columns="-,t,H,-,B [mT]")
    np.testing.assert_allclose(lp.signals["B"], 1e-3 * np.array([y for *_, y in _loop_rows()]))
    assert list(lp.signals) == ["B"] and lp.n_samples == 20
    h.write_text(h.read_text().replace(",3C90,", ",7,"))  # (all numbers: the fast path)
    (fast,) = read_loops(h, columns="-,t,H,-,B [mT]")
    np.testing.assert_array_equal(fast.signals["B"], lp.signals["B"])
    with pytest.raises(DataError, match="'-' for one to skip"):
        read_loops(h)


def test_cgs_units_and_a_polarization_column_are_read_in_si(tmp_path):
    """Literature loops often come in oersteds and gauss, or as the polarization J = μ0·M
    of an Epstein frame: each is read in SI, J as the magnetization it is."""
    from jaxhyst.io import DataError, parse_column, read_loops

    mu0 = 4e-7 * np.pi
    rows = [(h, b) for h, b in zip(np.linspace(-1, 1, 12), np.linspace(-0.5, 0.5, 12),
                                   strict=True)]
    f = tmp_path / "cgs.csv"
    f.write_text("H_Oe,B [kG]\n" + "".join(f"{h},{b}\n" for h, b in rows))
    (lp,) = read_loops(f)
    np.testing.assert_allclose(lp.H, [h * 1e3 / (4 * np.pi) for h, _ in rows])
    np.testing.assert_allclose(lp.signals["B"], [0.1 * b for _, b in rows])
    g = tmp_path / "epstein.csv"
    g.write_text("H [A/m],J [T]\n" + "".join(f"{h},{b}\n" for h, b in rows))
    (lp,) = read_loops(g)
    assert list(lp.signals) == ["M"]
    np.testing.assert_allclose(lp.signals["M"] * mu0, [b for _, b in rows])
    assert parse_column("M_emu_per_cm3") == ("M", 1e3)
    assert parse_column("polarization (mT)") == ("M", pytest.approx(1e-3 / mu0))
    with pytest.raises(DataError, match="not a unit of polarization J; use one of T, mT"):
        parse_column("J_G")
    h = tmp_path / "both.csv"  # (J and M are one quantity: named as a duplicate)
    h.write_text("H,J_T,M\n" + "".join(f"{a},{b},{b}\n" for a, b in rows))
    with pytest.raises(DataError, match="quantity M appears in more than one column"):
        read_loops(h)


def test_a_pipe_is_read_like_a_file_and_a_device_is_not_called_missing(tmp_path):
    """bash's ``<(…)`` hands a pipe (/dev/fd/N): it is read like a file; /dev/null is
    empty, not "does not exist"; a directory given as a result file is named so."""
    import threading

    from jaxhyst.io import DataError, read_json, read_loops

    fifo = tmp_path / "loops.fifo"
    os.mkfifo(fifo)
    text = "t,H,y\n" + "".join(f"{t},{h},{y}\n" for _, t, h, y in _loop_rows())
    writer = threading.Thread(target=fifo.write_text, args=(text,), daemon=True)
    writer.start()
    (lp,) = read_loops(fifo)
    writer.join()
    assert lp.n_samples == 20
    with pytest.raises(DataError, match="is empty"):
        read_loops("/dev/null")
    with pytest.raises(DataError, match="is a directory"):
        read_json(tmp_path)
    with pytest.raises(DataError, match="does not exist"):
        read_json(tmp_path / "nowhere.json")


MALFORMED = {
    "nan": ("t_s,H_A_per_m,y_m\n" + "".join(f"{t},{h},{'nan' if i == 7 else y}\n" for i, (
        _, t, h, y) in enumerate(_loop_rows())), "line 9, column 'y_m'"),
    "time": ("t,H,y\n" + "".join(f"{0.5 if i == 4 else t},{h},{y}\n" for i, (_, t, h, y) in
                                 enumerate(_loop_rows())), "time is not increasing"),
    "few": ("t,H,y\n" + "".join(f"{t},{h},{y}\n" for _, t, h, y in _loop_rows(n=5)),
            "at least 8"),
    "column": ("t,H,displacment\n" + "".join(f"{t},{h},{y}\n" for _, t, h, y in _loop_rows()),
               "'displacment' is not a known quantity"),
    "unit": ("t,H [T],y\n" + "".join(f"{t},{h},{y}\n" for _, t, h, y in _loop_rows()),
             "unit 'T' is not a unit of applied field"),
    "header": ("".join(f"{t},{h},{y}\n" for _, t, h, y in _loop_rows()), "no header line"),
    "text": ("t,H,y\n" + "".join(f"{t},{'abc' if i == 2 else h},{y}\n" for i, (_, t, h, y) in
                                 enumerate(_loop_rows())), "'abc' is not a finite number"),
    # (a NumPy scalar's repr written as a cell: shown as the file holds it, and why)
    "repr": ("t,H,y\n" + "".join(f"{t},{f'np.float64({h})' if i == 2 else h},{y}\n" for i, (
        _, t, h, y) in enumerate(_loop_rows())), "value 'np.float64("),
}


@pytest.mark.parametrize("case", sorted(MALFORMED))
def test_malformed_data_exits_nonzero_with_one_line_naming_the_problem(case, tmp_path, capsys):
    text, expect = MALFORMED[case]
    f = tmp_path / f"{case}.csv"
    f.write_text(text)
    assert main(["identify", str(f), "--method", "lm"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "Traceback" not in err, err
    assert expect in err, err


def test_other_bad_arguments_are_one_line_errors(tmp_path, capsys):
    f = tmp_path / "ok.csv"
    f.write_text("t,H,y,M\n" + "".join(f"{t},{h},{y},{y}\n" for _, t, h, y in _loop_rows()))
    bad = tmp_path / "bounds.json"
    bad.write_text('{"Ms": [2, 1]}')
    unknown = tmp_path / "unknown.json"
    unknown.write_text('{"Mass": [1, 2]}')
    cases = [
        (["identify", str(tmp_path / "missing.csv")], "does not exist"),
        (["identify", str(f)], "choose the observed one with --output"),
        (["identify", str(f), "--output", "y", "--fix", "Mass=1"], "unknown parameter"),
        (["identify", str(f), "--output", "y", "--bounds", str(bad)], "lower <= upper"),
        (["identify", str(f), "--output", "y", "--bounds", str(unknown)],
         "unknown parameters ['Mass']"),
        (["identify", str(f), "--output", "y", "--actuator", "nope"], "not a preset"),
        (["simulate", "--params", "table3:7"], "Table 3 has frequencies"),
        (["frequency-response", "--frequencies", "10,-1"], "> 0 Hz"),
    ]
    for argv, expect in cases:
        assert main(argv) == 2, argv
        err = capsys.readouterr().err.strip()
        assert err.count("\n") == 0 and expect in err, (argv, err)


def test_frequency_response_and_result_json_round_trip(tmp_path, capsys):
    from jaxhyst.io import parameters_from_json, read_json, write_json

    assert main(["frequency-response", "--params", "table3:10", "--frequencies",
                 "10,1000", "--json"]) == 0
    out = json.loads(capsys.readouterr().out)
    lag = [r["phase_lag_deg"] for r in out["response"]]
    assert 0.2 < lag[0] < 0.35 and 60 < lag[1] < 75  # Cz·ω/Kz at 10 Hz; near resonance
    path = tmp_path / "p.json"
    write_json(path, {"params": {n: {"value": v, "unit": "x"}
                                 for n, v in jh.TABLE1_TRUE.to_dict().items()}})
    assert parameters_from_json(read_json(path)).to_dict() == jh.TABLE1_TRUE.to_dict()


def test_joint_bh_problem_from_a_multi_loop_file(tmp_path):
    """`identify --joint` on a file of B(H) loops without time: the problem the CLI builds
    (and `report` rebuilds from the result JSON) reproduces the generating model."""
    from jaxhyst.cli import build_problem
    from jaxhyst.identify.joint import NO_ACTUATOR
    from jaxhyst.io import bounds_to_json

    p = jh.TABLE1_TRUE
    rows = ["loop,H [kA/m],B [mT]"]
    for k, amp in enumerate((15e3, 30e3)):
        H = amp * np.cos(2 * np.pi * np.arange(41) / 40)
        sim = jh.simulate_unchecked(p, NO_ACTUATOR, jh.drive_from_record(None, H),
                                    variant=jh.ClassicJA(), substeps=4)
        B = 4e-7 * np.pi * (H + np.asarray(sim.observed("M")))
        rows += [f"{k},{float(h) / 1e3!r},{float(b) * 1e3!r}" for h, b in zip(H, B, strict=True)]
    f = tmp_path / "bh.csv"
    f.write_text("\n".join(rows) + "\n")
    spec = {"data": str(f), "columns": None, "loop": None, "output": None,
            "actuator": NO_ACTUATOR.to_dict(), "bounds": bounds_to_json(jh.TABLE1_BOUNDS),
            "fixed": {"Ms": p.Ms}, "run_in_periods": 1, "substeps": 4, "variant": "classic",
            "joint": True, "per_loop": ["c"]}
    problem = build_problem(spec)
    assert problem.space.names == ("a", "k", "alpha", "c[0]", "c[1]")  # structure fixed
    u = problem.space.u_from_params(p)
    assert float(problem.cost_u(u)) < 1e-24
    with pytest.raises(ValueError, match="choose one with --loop"):
        build_problem({**spec, "joint": False})


@pytest.mark.extended  # (exit 3 of a fold: test_heldout)
def test_the_report_says_what_to_fix_or_that_nothing_needs_it():
    from types import SimpleNamespace

    from jaxhyst.cli.report import fix_line

    for fix, want in ((["alpha", "c"], "determined to 10 %: fix alpha, c"),
                      ([], "every free parameter is identifiable and determined to 10 %: "
                           "nothing to fix")):
        rep = SimpleNamespace(suggest_fixed=lambda fix=fix: fix, max_rel_se=0.1)
        assert fix_line(rep).strip().endswith(want) and "—" not in fix_line(rep)


def test_identify_that_stops_short_says_so_and_exits_3(tmp_path, capsys):
    """A fit cut off at its step limit is not a success: the result says
    ``max_steps_reached`` and the command exits 3 (documented in ``--help``)."""
    from jaxhyst.cli import build_parser
    from jaxhyst.identify.joint import NO_ACTUATOR

    H = 20e3 * np.cos(2 * np.pi * np.arange(41) / 40)
    sim = jh.simulate(jh.TABLE1_TRUE, NO_ACTUATOR, jh.drive_from_record(None, H),
                      variant=jh.ClassicJA(), substeps=2)
    B = 4e-7 * np.pi * (H + np.asarray(sim.observed("M")))
    f = tmp_path / "bh.csv"
    f.write_text("H,B\n" + "".join(f"{float(h)!r},{float(b)!r}\n"
                                    for h, b in zip(H, B, strict=True)))
    out = tmp_path / "r.json"
    argv = ["identify", str(f), "--variant", "classic", "--method", "lm", "--starts", "1",
            "--max-steps", "2", "--fix", f"Ms={jh.TABLE1_TRUE.Ms}", "--out", str(out),
            "--json", "--progress", "0", "--save-model", str(tmp_path / "m.eqx")]
    assert main(argv) == 3
    res = json.loads(out.read_text())
    assert res["outcome"] == "max_steps_reached" and res["success"] is False
    # the model as written: its parameters are the result's, its form the one fitted
    model = jh.load_model(tmp_path / "m.eqx")
    assert isinstance(model.variant, jh.ClassicJA)
    assert float(model.params.k) == res["params"]["k"]["value"]
    assert model.actuator.name == NO_ACTUATOR.name  # (a material's B loop: no actuator)
    import hashlib

    from jaxhyst.saved import read_header

    meta = read_header(tmp_path / "m.eqx")["meta"]  # what it was fitted to, and the report
    assert meta["data_sha256"] == hashlib.sha256(f.read_bytes()).hexdigest()
    assert meta["identifiability"]["rank"] == res["identifiability"]["rank"]
    assert meta["fitted_conditions"] == {"amplitude": [pytest.approx(20e3)] * 2}
    assert meta["expected_error"] is None  # (no leave-one-out folds)
    assert json.loads(capsys.readouterr().out)["outcome"] == "max_steps_reached"
    # predict with the model says whether each loop lies within the fitted conditions
    big = tmp_path / "big.csv"
    big.write_text("H,B\n" + "".join(f"{3 * float(h)!r},{float(b)!r}\n"
                                      for h, b in zip(H, B, strict=True)))
    for data, beyond in ((f, ""), (big, "amplitude (6e+04 A/m; fitted 2e+04–2e+04)")):
        assert main(["predict", str(tmp_path / "m.eqx"), str(data), "--json"]) == 0
        row = json.loads(capsys.readouterr().out)["loops"][0]
        assert row["extrapolation"] == beyond and "expected_relative_error" not in row
    assert main(["predict", str(tmp_path / "m.eqx"), str(big)]) == 0
    assert "an extrapolation beyond the fitted loops' amplitude" in capsys.readouterr().out
    # --amplitude scales the file's loops: the same prediction, not compared with data
    assert main(["predict", str(tmp_path / "m.eqx"), str(f), "--amplitude", "60000",
                 "--json"]) == 0
    row = json.loads(capsys.readouterr().out)["loops"][0]
    assert row["extrapolation"] == beyond and "rms" not in row and "60000" in row[
        "not_compared"]
    # report reads the model file as it reads the result (the problem rebuilt from its
    # header, the data checked against the SHA-256 it was fitted to)
    assert main(["report", str(tmp_path / "m.eqx"), "--json"]) == 0
    again = json.loads(capsys.readouterr().out)["identifiability"]
    assert again["singular_values"] == pytest.approx(
        res["identifiability"]["singular_values"], rel=1e-9)
    for loose in ((), ("--max-rel-se", "1e6")):  # (its last line: what to fix)
        assert main(["report", str(tmp_path / "m.eqx"), *loose, "--json"]) == 0
        suggested = json.loads(capsys.readouterr().out)["suggest_fixed"]
        assert main(["report", str(tmp_path / "m.eqx"), *loose]) == 0
        last = capsys.readouterr().out.strip().splitlines()[-1]
        assert last.endswith(f"fix {', '.join(suggested)}" if suggested else
                             "nothing to fix"), last
    f.write_text(f.read_text() + "0.0,0.0\n")
    assert main(["report", str(tmp_path / "m.eqx")]) == 2
    assert "changed since" in capsys.readouterr().err
    assert main(["report", str(out)]) == 2  # (the result file too)
    assert "changed since" in capsys.readouterr().err
    helps = build_parser()._subparsers._group_actions[0].choices["identify"].format_help()
    assert "3 the fit stopped" in " ".join(helps.split())


def test_the_console_command_flushes_its_output_and_keeps_its_exit_status(tmp_path):
    """``python -m jaxhyst.cli`` (the console script's entry, `jaxhyst.cli.main.command`)
    ends without the interpreter's teardown: what it printed and wrote is all there, and
    its status is main's — 0 done, 2 for a bad input with its one line."""
    import subprocess
    import sys

    def run(*argv):  # (the compilation cache of this run, as the command-line chains')
        return subprocess.run([sys.executable, "-m", "jaxhyst.cli", *argv], cwd=tmp_path,
                              capture_output=True, text=True)

    done = run("simulate", "--samples-per-period", "20", "--substeps", "8", "--csv",
               "sim.csv")
    assert done.returncode == 0, done.stderr
    assert done.stdout.rstrip().endswith("wrote sim.csv"), done.stdout
    rows = (tmp_path / "sim.csv").read_text().splitlines()
    assert len(rows) > 20 and rows[-1].count(",") == rows[0].count(",")
    bad = run("identify", "missing.csv")
    assert bad.returncode == 2 and bad.stdout == ""
    assert bad.stderr.count("\n") == 1 and "does not exist" in bad.stderr, bad.stderr
    # a command's unflushed output (print buffers a pipe's) and a status of its own
    stub = subprocess.run([sys.executable, "-c", "import sys, jaxhyst.cli.main; "
                           "m = sys.modules['jaxhyst.cli.main']; "
                           "m.main = lambda: (print('x' * 1000, end=''), 3)[1]; "
                           "m.command()"], capture_output=True, text=True,
                          env={k: v for k, v in os.environ.items()  # (stdout buffered)
                               if k != "PYTHONUNBUFFERED"})
    assert stub.returncode == 3 and stub.stdout == "x" * 1000


def test_ctrl_c_twice_during_compilation_exits_at_once(tmp_path):
    """The first SIGINT is acknowledged even while XLA compiles (the CLI's work runs in a
    worker thread), the second ends the process at once with status 130."""
    import signal
    import subprocess
    import sys
    import time

    csv = tmp_path / "sim.csv"
    assert main(["simulate", "--samples-per-period", "50", "--csv", str(csv)]) == 0
    proc = subprocess.Popen([sys.executable, "-m", "jaxhyst.cli", "identify", str(csv),
                             "--output", "y", "--method", "GATR1", "--progress", "1"],
                            stderr=subprocess.PIPE, text=True,
                            env={**os.environ, "JAXHYST_CACHE_DIR": "off"})
    deadline = time.monotonic() + 60
    line = ""
    while "compiling" not in line and time.monotonic() < deadline:  # the GA is compiling
        line = proc.stderr.readline()
    proc.send_signal(signal.SIGINT)
    time.sleep(0.5)
    t0 = time.monotonic()
    proc.send_signal(signal.SIGINT)
    rc = proc.wait(timeout=30)
    took = time.monotonic() - t0
    err = proc.stderr.read()
    assert rc == 130, err
    assert "interrupted" in err and "aborted" in err, err
    assert took < 5.0, took


@pytest.mark.slow  # (a rate-dependent displacement fit and a compensation: minutes)
def test_a_rate_dependent_fit_is_saved_predicted_and_compensated_from_the_command_line(
        tmp_path, capsys):
    """The chain of issue 46 from a fresh file: identify with losses → save → predict →
    compensate with the saved model (its loss coefficients kept at every door)."""
    csv = tmp_path / "run.csv"
    assert main(["simulate", "--frequency", "1000", "--samples-per-period", "100",
                 "--substeps", "4", "--eddy", "0.02", "--excess", "0.1", "--csv",
                 str(csv)]) == 0
    bounds, start = tmp_path / "b.json", tmp_path / "known.json"
    bounds.write_text(json.dumps({"eddy": [0.0, 0.1], "excess": [0.0, 1.0]}))
    start.write_text(json.dumps(jh.TABLE1_TRUE.to_dict()))
    out, model = tmp_path / "r.json", tmp_path / "m.eqx"
    rc = main(["identify", str(csv), "--output", "y", "--method", "lm", "--starts", "1",
               "--max-steps", "60", "--substeps", "4", "--losses", "eddy,excess",
               "--bounds", str(bounds),
               "--params", str(start), "--fix", ",".join(jh.NAMES),  # (the losses free)
               "--out", str(out), "--save-model", str(model), "--progress", "0"])
    assert rc in (0, 4), capsys.readouterr()
    fit = json.loads(out.read_text())
    assert fit["params"]["eddy"]["value"] == pytest.approx(0.02, rel=1e-3)
    saved = jh.load_model(model)
    assert saved.losses is not None and float(saved.losses.eddy) == pytest.approx(0.02,
                                                                                 rel=1e-3)
    # --start from that result: its loss coefficients start at the centre of their box
    assert main(["identify", str(csv), "--output", "y", "--method", "lm", "--max-steps",
                 "60", "--substeps", "4", "--losses", "eddy,excess", "--bounds",
                 str(bounds), "--params", str(start), "--fix", ",".join(jh.NAMES),
                 "--start", str(out), "--progress", "0"]) in (0, 4)
    capsys.readouterr()
    assert main(["predict", str(out), "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)["loops"]
    assert rows[0]["rms"] < 1e-3 * rows[0]["data_scale"]
    comp = tmp_path / "comp.csv"
    assert main(["compensate", "--model", str(model), "--current-limit", "2.5", "--csv",
                 str(comp), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["error"] < 1e-4 and summary["error"] < summary["uncompensated_error"] / 100


def test_a_result_whose_data_changed_since_the_fit_is_refused(tmp_path):
    """A result file records its data's SHA-256 (as a saved model does): report and
    predict refuse a data file changed since the fit in one line (they rebuilt the
    problem from the new data without a word); a result without it is read as before."""
    from jaxhyst.cli.problems import load_result
    from jaxhyst.cli.spec import CLIError, file_sha256

    data, result = tmp_path / "loop.csv", tmp_path / "r.json"
    data.write_text("H,B\n1,0.1\n")
    result.write_text(json.dumps({"problem": {"data": "loop.csv"},
                                  "data_sha256": file_sha256(str(data))}))
    data.write_text("H,B\n1,0.2\n")
    with pytest.raises(CLIError, match=r"loop.csv changed since .*r.json was fitted to it"):
        load_result(result)
