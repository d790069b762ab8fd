"""Files and the command line (the README demo)."""

from __future__ import annotations

import os
import stat

import numpy as np
import pytest

from jaxhyst.cli import main
from jaxhyst.io import atomic_write_text


def test_cli_simulate_writes_csv_and_png(tmp_path, capsys):
    pytest.importorskip("matplotlib")
    csv, png = tmp_path / "loop.csv", tmp_path / "loop.png"
    assert main(["simulate", "--csv", str(csv), "--png", str(png), "--json"]) == 0
    out = capsys.readouterr().out
    assert '"samples_observed": 201' in out
    data = np.genfromtxt(csv, delimiter=",", names=True)
    assert data.dtype.names[:3] == ("t_s", "H_A_per_m", "M_A_per_m")
    assert len(data) == 201 and np.all(np.isfinite(data["y_m"]))
    assert 60e-6 < data["y_m"].min() < data["y_m"].max() < 100e-6
    assert png.stat().st_size > 10_000


def test_cli_bad_input_is_one_line_without_traceback(capsys):
    assert main(["simulate", "--frequency", "-5"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "frequency must be" in err and "Traceback" not in err


def test_atomic_write_leaves_old_file_on_failure_and_normal_permissions(tmp_path):
    target = tmp_path / "out.txt"
    atomic_write_text(target, "first\n")
    mode = stat.S_IMODE(os.stat(target).st_mode)
    assert mode & 0o044  # readable by group/others under a normal umask (not 0600)

    with pytest.raises(TypeError):
        atomic_write_text(target, None)  # fails mid-write
    assert target.read_text() == "first\n"
    assert [p.name for p in tmp_path.iterdir()] == ["out.txt"]  # no temp file left
