"""Many fits at once (issue 47): a manifest of independent identifications on a local
two-worker Dask cluster and serially — the same table; a failing item recorded with its
reason while the others finish; a second run skips what is done; bad manifests and an
unreachable scheduler in one line."""

from __future__ import annotations

import csv

import numpy as np
import pytest

from jaxhyst.cli import main

OPTIONS = "variant,starts,max_steps\n"


def _loops(d, n=3):
    for i in range(n):
        H = (90 + 20 * i) * np.cos(2 * np.pi * np.arange(96) / 96)
        B = 0.3 * np.tanh((H + (9 + i) * np.sign(np.gradient(-H))) / 30)
        (d / f"loop{i}.csv").write_text("H [A/m],B [T]\n" + "".join(
            f"{h},{b}\n" for h, b in zip(H, B, strict=True)))


def _table(path):
    with open(path, newline="") as fh:
        return {r["id"]: r for r in csv.DictReader(fh)}


def _manifest(d, n=3):
    """``n`` loops and an item that parses but cannot be fitted (a monotone record holds
    no loop)."""
    _loops(d, n)
    (d / "bad.csv").write_text("H [A/m],B [T]\n" + "".join(
        f"{h},{0.001 * h}\n" for h in np.linspace(-50, 50, 40)))
    manifest = d / "m.csv"
    manifest.write_text("data,variant,starts,max_steps\nloop*.csv,classic,1,15\n"
                        "bad.csv,classic,1,15\n")
    return manifest


def test_a_serial_batch_records_a_failure_and_a_second_run_skips_what_is_done(tmp_path,
                                                                               capsys):
    manifest = _manifest(tmp_path)
    assert main(["identify-many", str(manifest), "--out", str(tmp_path / "s"),
                 "--scheduler", "serial", "--quiet"]) == 3  # (the failed item)
    s = _table(tmp_path / "s" / "results.csv")
    assert set(s) == {"loop0", "loop1", "loop2", "bad"}
    for i in ("loop0", "loop1", "loop2"):
        assert s[i]["outcome"] != "failed" and float(s[i]["rms_error"]) < 0.05, s[i]
    # the loops differ (coercivity 9, 10, 11 A/m): each item is its own fit
    assert len({s[i]["k"] for i in ("loop0", "loop1", "loop2")}) == 3
    # B loops: no columns for the placeholder structure (λs, E, Kz, Mz, Cz), which a
    # material's fit cannot determine (the result file marks them "unused")
    with open(tmp_path / "s" / "results.csv", newline="") as fh:
        header = next(csv.reader(fh))
    assert "Ms" in header and not {"lambda_s", "E", "Kz", "Mz", "Cz"} & set(header)
    assert s["bad"]["outcome"] == "failed"
    assert "holds no hysteresis loop" in s["bad"]["error"]
    capsys.readouterr()
    assert main(["identify-many", str(manifest), "--out", str(tmp_path / "s"),
                 "--scheduler", "serial"]) == 3
    assert "4 items, 4 already in" in capsys.readouterr().err
    assert _table(tmp_path / "s" / "results.csv") == s
    # killed between two rewrites of the table: the journal has every finished item
    (tmp_path / "s" / "results.csv").unlink()
    assert main(["identify-many", str(manifest), "--out", str(tmp_path / "s"),
                 "--scheduler", "serial"]) == 3
    assert "4 items, 4 already in" in capsys.readouterr().err
    assert _table(tmp_path / "s" / "results.csv") == s


@pytest.mark.extended  # (a local cluster's workers start)
def test_a_local_cluster_gives_the_serial_table(tmp_path):
    """Two worker processes (each compiles its own programs: one loop, kept small) and the
    failing item: the same rows as the serial run, to round-off."""
    pytest.importorskip("dask.distributed")
    manifest = _manifest(tmp_path, 1)
    dask = main(["identify-many", str(manifest), "--out", str(tmp_path / "d"),
                 "--workers", "2", "--quiet"])
    serial = main(["identify-many", str(manifest), "--out", str(tmp_path / "s"),
                   "--scheduler", "serial", "--quiet"])
    assert serial == dask == 3  # (the failed item)
    s, d = _table(tmp_path / "s" / "results.csv"), _table(tmp_path / "d" / "results.csv")
    assert set(s) == set(d) == {"loop0", "bad"}
    for name in ("Ms", "a", "k", "alpha", "c", "rms_error"):
        assert float(d["loop0"][name]) == pytest.approx(float(s["loop0"][name]), rel=1e-9)
    assert d["loop0"]["worker"].split(":")[-1] != s["loop0"]["worker"].split(":")[-1]
    assert s["bad"]["outcome"] == d["bad"]["outcome"] == "failed"
    assert "holds no hysteresis loop" in d["bad"]["error"]


def test_a_json_manifest_gives_the_items_of_the_same_csv_and_toml(tmp_path):
    from jaxhyst.batch import read_manifest

    _loops(tmp_path, 2)
    files = {"m.csv": "data,variant,starts,joint\nloop0.csv,classic,2,false\nloop1.csv,play,1,\n",
             "m.toml": '[[item]]\ndata = "loop0.csv"\nvariant = "classic"\nstarts = 2\n'
                       'joint = false\n[[item]]\ndata = "loop1.csv"\nvariant = "play"\n'
                       "starts = 1\n",
             "m.json": '[{"data": "loop0.csv", "variant": "classic", "starts": 2, '
                       '"joint": false}, {"data": "loop1.csv", "variant": "play", '
                       '"starts": 1}]'}
    items = []
    for name, text in files.items():
        (tmp_path / name).write_text(text)
        items.append(read_manifest(str(tmp_path / name)))
    assert items[0] == items[1] == items[2] and len(items[0]) == 2


@pytest.mark.parametrize("content, message", [
    ("data,variant\nmissing.csv,classic\n", "item 1: data 'missing.csv': no such file"),
    ("data,variant\nloop0.csv,classic\nloop1.csv,bogus\n", "item 2"),
    ("data,frobnicate\nloop0.csv,3\n", "unrecognized arguments: --frobnicate"),
    ("data,out\nloop0.csv,x.json\n", "--out is set by the batch"),
    ("variant\nclassic\n", "no data file"),
    ("not json", "not valid JSON"),
    ('["loop0.csv"]', "a JSON manifest is a list of objects"),
    ('[{"data": "loop0.csv", "variant": "bogus"}]', "item 1"),
])
def test_bad_manifests_are_refused_in_one_line_before_any_work(tmp_path, capsys, content,
                                                               message):
    _loops(tmp_path, 2)
    manifest = tmp_path / ("m.json" if content.startswith(("[", "{", "not")) else "m.csv")
    manifest.write_text(content)
    assert main(["identify-many", str(manifest), "--out", str(tmp_path / "o"),
                 "--scheduler", "serial"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and message in err, err
    assert not (tmp_path / "o" / "results.csv").exists()


def test_an_unreachable_scheduler_is_one_line(tmp_path, capsys, monkeypatch):
    pytest.importorskip("dask.distributed")
    monkeypatch.setattr("jaxhyst.batch.CONNECT_TIMEOUT", "1s")  # (refused at once anyway)
    _loops(tmp_path, 1)
    manifest = tmp_path / "m.csv"
    manifest.write_text("data\nloop0.csv\n")
    assert main(["identify-many", str(manifest), "--out", str(tmp_path / "o"),
                 "--scheduler", "tcp://127.0.0.1:9"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "cannot be reached" in err, err
