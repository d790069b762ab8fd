"""Many independent identifications at once — a material database, a replicate study,
leave-one-out over many materials — on one machine or a cluster (`fit_many`, ``jaxhyst
identify-many``).

**The manifest** lists the items: a CSV file with a ``data`` column (a data file, or a
glob that expands to several) and any options of ``jaxhyst identify`` as further columns
(``loop``, ``variant``, ``method``, ``starts``, ``fix``, ``losses`` …; empty cells and
flags with ``false`` are left out, ``true`` gives a flag), or a TOML file with one
``[[item]]`` table per item of the same keys, a JSON file of a list of such objects, or a
list of such dicts. Every item is
checked — its file exists, its options parse — before any work starts; a bad item is one
line naming it.

**The work** of an item is exactly ``jaxhyst identify`` with its options: its result JSON
and saved model go to ``<out>/items/<id>.json`` and ``.eqx``. Items run on **Dask**
(``dask.distributed``) where it is installed (``pip install -e ".[cluster]"``): a local
cluster with one process per core by default (each with its own JAX, all sharing the
persistent compilation cache, so that a program compiles once per machine), or any
cluster by its scheduler's address. Without Dask — or with ``scheduler="serial"`` — they
run one after the other in this process, with the same table.

**The table** (``<out>/results.csv``): one row per item — its id, data, loop, outcome,
exit status, rms error, cost, seconds, worker, every parameter's value and 95 % interval,
the leave-one-out's kept form and mean held-out error where it ran, and the reason of a
failure. Every finished item is appended at once to ``<out>/results.jsonl`` (one JSON
line, flushed: an interrupted run loses no finished item) and the table is rewritten
(atomically) from it at most every `TABLE_EVERY` seconds and at the end — so that the
cost of recording stays flat for 1e5 items; a run over the same manifest skips the items
already in either (resume).
An item that raises, or whose worker is lost, is tried once more and then recorded as
failed with its reason; the batch never stops for one item.
"""

from __future__ import annotations

import csv
import glob
import io
import json
import os
import socket
import time
from collections.abc import Callable, Sequence
from contextlib import redirect_stderr, redirect_stdout

from ._files import write_text
from ._interrupt import stop_requested

#: The table's leading columns (each parameter's value and interval follow).
COLUMNS = ("id", "data", "loop", "status", "outcome", "rms_error", "cost", "seconds",
           "worker", "kept_form", "held_out_rms", "error")
#: An item is tried this many times more after an exception or a lost worker.
RETRIES = 1
#: The table is rewritten from the journal at most this often (seconds) during a run.
TABLE_EVERY = 5.0


class ManifestError(ValueError):
    """A manifest or one of its items cannot be used (one line naming it)."""


def _argv_of(row: dict) -> list[str]:
    """The ``jaxhyst identify`` options of a manifest row (its data file aside)."""
    argv = []
    for key, value in row.items():
        if key in ("data", "id") or value is None or str(value).strip() == "":
            continue
        flag = "--" + key.replace("_", "-")
        text = str(value).strip()
        if text.lower() == "true":
            argv.append(flag)
        elif text.lower() != "false":
            argv += [flag, text]
    return argv


def _json_items(path: str) -> list[dict]:
    """The items of a JSON manifest: a list of objects, or ``{"item": [...]}`` as in TOML."""
    try:
        with open(path, encoding="utf-8") as fh:
            rows = json.load(fh)
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise ManifestError(f"manifest {path}: not valid JSON ({err}).") from None
    rows = rows.get("item", []) if isinstance(rows, dict) else rows
    if not isinstance(rows, list) or not all(isinstance(r, dict) for r in rows):
        raise ManifestError(f"manifest {path}: a JSON manifest is a list of objects, one an "
                            'item ({"data": "loops.csv", "joint": true, …}).')
    return rows


def read_manifest(manifest, root: str | None = None) -> list[dict]:
    """The items of a manifest (a CSV or TOML path, or a list of dicts): each a dict
    with ``id``, ``data`` (an absolute path) and ``argv`` (its identify options), every
    one checked (module docstring)."""
    if isinstance(manifest, (str, os.PathLike)):
        path = os.fspath(manifest)
        if not os.path.isfile(path):
            raise ManifestError(f"manifest {path}: no such file.")
        root = root or os.path.dirname(os.path.abspath(path))
        if path.endswith(".toml"):
            try:
                import tomllib
            except ImportError:  # (Python 3.10)
                raise ManifestError(f"manifest {path}: TOML manifests need Python 3.11; "
                                    "give a CSV manifest.") from None
            try:
                with open(path, "rb") as fh:
                    rows = tomllib.load(fh).get("item", [])
            except tomllib.TOMLDecodeError as err:
                raise ManifestError(f"manifest {path}: not valid TOML ({err}).") from None
        elif path.endswith(".json"):
            rows = _json_items(path)
        else:
            with open(path, encoding="utf-8", newline="") as fh:
                rows = list(csv.DictReader(fh))
        where = path
    else:
        rows, where, root = list(manifest), "the manifest", root or os.getcwd()
    if not rows:
        raise ManifestError(f"{where}: no items (a CSV with a 'data' column, TOML "
                            "[[item]] tables or a JSON list of objects).")
    from .cli.identify import check_options, identify_parser

    parser = identify_parser()
    items, seen = [], set()
    for k, row in enumerate(rows, start=1):
        row = {str(a).strip(): b for a, b in dict(row).items() if a is not None}
        label = f"{where}, item {k}"
        if not row.get("data"):
            raise ManifestError(f"{label}: no data file (the 'data' column).")
        pattern = os.path.join(root, str(row["data"]).strip())
        files = sorted(glob.glob(pattern)) if glob.has_magic(pattern) else [pattern]
        if not files or not all(os.path.isfile(f) for f in files):
            raise ManifestError(f"{label}: data {row['data']!r}: no such file.")
        argv = _argv_of(row)
        for bad in ("--out", "--save-model", "--png", "--json", "--progress"):
            if bad in argv:
                raise ManifestError(f"{label}: {bad} is set by the batch (each item's files "
                                    "go to the output folder); leave it out.")
        for f in files:
            try:
                with redirect_stderr(io.StringIO()) as err:
                    check_options(parser.parse_args(["identify", f, *argv]))
            except SystemExit:
                message = " ".join(err.getvalue().split()) or "bad options"
                raise ManifestError(f"{label}: {message.removeprefix('jaxhyst identify: ')}"
                                    ) from None
            except ValueError as problem:  # (the command's one-line refusals)
                raise ManifestError(f"{label}: {problem}") from None
            ident = str(row.get("id") or "").strip() or (
                os.path.splitext(os.path.basename(f))[0]
                + (f"-loop{row['loop']}" if str(row.get("loop") or "").strip() else ""))
            if ident in seen:
                ident = f"{ident}-{k}"
            seen.add(ident)
            items.append({"id": ident, "data": os.path.abspath(f), "argv": argv})
    return items


def run_item(item: dict, out: str) -> dict:
    """One item, as ``jaxhyst identify`` runs it (in this process): its table row."""
    from . import enable_compilation_cache
    from .cli.identify import identify_parser

    enable_compilation_cache()  # (every worker: a program compiles once per machine)
    os.makedirs(os.path.join(out, "items"), exist_ok=True)
    base = os.path.join(out, "items", item["id"])
    argv = ["identify", item["data"], *item["argv"], "--out", base + ".json",
            "--save-model", base + ".eqx", "--progress", "0"]
    row = {"id": item["id"], "data": item["data"], "worker": socket.gethostname()
           + f":{os.getpid()}"}
    loop = next((item["argv"][i + 1] for i, a in enumerate(item["argv"][:-1])
                 if a == "--loop"), "")
    row["loop"] = loop
    t0 = time.perf_counter()
    sink = io.StringIO()
    with redirect_stdout(sink), redirect_stderr(sink):
        args = identify_parser().parse_args(argv)
        status = args.func(args)
    row["seconds"] = round(time.perf_counter() - t0, 3)
    row["status"] = status
    with open(base + ".json", encoding="utf-8") as fh:
        result = json.load(fh)
    row.update(outcome=result.get("outcome"), rms_error=result.get("rms_error"),
               cost=result.get("cost"))
    report = (result.get("identifiability") or {}).get("parameters", {})
    for name, p in (result.get("params") or {}).items():
        if p.get("unused"):  # (a material fit's placeholder structure: no column)
            continue
        row[name] = p["value"] if not isinstance(p["value"], list) else p["value"][0]
        interval = (report.get(name) or {}).get("interval")
        if interval:
            row[f"{name}_lo"], row[f"{name}_hi"] = interval
    held = result.get("leave_one_out")
    if isinstance(held, dict) and held.get("kept"):
        rows = held["forms"][held["kept"]]["rows"]
        row["kept_form"] = held["kept"]
        rms = [r["rms"] for r in rows]  # (None: a fold without a prediction)
        row["held_out_rms"] = sum(rms) / len(rms) if rms and None not in rms else None
    return row


def _guarded(item: dict, out: str) -> dict:
    """`run_item`, with an exception recorded as the row's error instead of raised (the
    batch never stops for one item); tried `RETRIES` more times first."""
    from ._mappings import release_if_crowded

    release_if_crowded()  # (a worker runs item after item, each may compile anew)
    last = None
    for _ in range(1 + RETRIES):
        try:
            return run_item(item, out)
        except (Exception, SystemExit) as err:  # noqa: BLE001 - any failure of one item
            last = f"{type(err).__name__}: {' '.join(str(err).split())}"
    return {"id": item["id"], "data": item["data"], "outcome": "failed", "status": 1,
            "error": last, "worker": socket.gethostname() + f":{os.getpid()}"}


def read_table(path: str) -> list[dict]:
    """The rows of a results table (empty where there is none yet)."""
    if not os.path.isfile(path):
        return []
    with open(path, encoding="utf-8", newline="") as fh:
        return list(csv.DictReader(fh))


def read_journal(path: str) -> list[dict]:
    """The rows appended to a journal (``results.jsonl``); a last line cut off by an
    interruption is left out."""
    if not os.path.isfile(path):
        return []
    rows = []
    with open(path, encoding="utf-8") as fh:
        for line in fh:
            try:
                rows.append(json.loads(line))
            except json.JSONDecodeError:
                continue
    return rows


def append_journal(path: str, row: dict) -> None:
    """Append one row to the journal, flushed to disk."""
    with open(path, "a", encoding="utf-8") as fh:
        fh.write(json.dumps(row, default=str) + "\n")
        fh.flush()
        os.fsync(fh.fileno())


def write_table(path: str, rows: Sequence[dict]) -> None:
    """Write the rows (atomically): `COLUMNS`, then every other key in first-seen order."""
    keys = list(COLUMNS)
    for r in rows:
        keys += [k for k in r if k not in keys]
    buf = io.StringIO()
    writer = csv.DictWriter(buf, fieldnames=keys, extrasaction="ignore", lineterminator="\n")
    writer.writeheader()
    for r in rows:
        writer.writerow({k: ("" if r.get(k) is None else r.get(k)) for k in keys})
    write_text(path, buf.getvalue())


#: How long a scheduler given by address may take to answer.
CONNECT_TIMEOUT = "10s"


def _client(scheduler, workers: int | None):
    """A Dask client: on ``scheduler`` (an address) or a new local cluster of
    ``workers`` processes (one thread each)."""
    try:
        from dask.distributed import Client, LocalCluster
    except ImportError:
        return None
    if scheduler not in (None, "local"):
        try:
            return Client(scheduler, timeout=CONNECT_TIMEOUT)
        except (OSError, TimeoutError) as err:
            raise ManifestError(f"scheduler {scheduler}: cannot be reached ({err}); give "
                                "the address of a running dask scheduler "
                                "(tcp://HOST:8786), or leave it out for a local "
                                "cluster.") from None
    import logging

    logging.getLogger("distributed").setLevel(logging.ERROR)  # (its shutdown chatter)
    n = workers or os.cpu_count() or 1
    cluster = LocalCluster(n_workers=n, threads_per_worker=1, processes=True,
                           dashboard_address=None, silence_logs=logging.ERROR)
    return Client(cluster)


def fit_many(manifest, out: str, *, scheduler: str | None = None, workers: int | None = None,
             progress: Callable[[str], None] | None = None) -> list[dict]:
    """Fit every item of ``manifest`` (see the module docstring) and write the table
    ``<out>/results.csv``; return its rows. ``scheduler``: None or ``"local"`` (a local
    Dask cluster of ``workers`` processes, one per core by default), an address
    (``tcp://host:8786``) or ``"serial"`` (this process, one item after another — also
    what happens without Dask). Items already in the table are skipped; ``progress``
    (a callable taking a line) hears of each item as it ends."""
    items = read_manifest(manifest)
    os.makedirs(out, exist_ok=True)
    table, journal = os.path.join(out, "results.csv"), os.path.join(out, "results.jsonl")
    known = {r["id"]: r for r in read_table(table) if r.get("outcome") not in ("", None)}
    known.update({r["id"]: r for r in read_journal(journal)})  # (newer than the table)
    rows = list(known.values())
    done = set(known)
    todo = [it for it in items if it["id"] not in done]
    say = progress or (lambda line: None)
    remote = scheduler not in (None, "local", "serial")
    client = _client(scheduler, workers) if remote else None  # (refused before a word)
    say(f"{len(items)} items, {len(items) - len(todo)} already in {table}")
    if scheduler in (None, "local"):
        client = _client(scheduler, workers)
    finished, written = 0, time.monotonic()

    def record(row):
        nonlocal finished, written
        rows.append(row)
        append_journal(journal, row)
        if time.monotonic() - written >= TABLE_EVERY:
            write_table(table, rows)
            written = time.monotonic()
        finished += 1
        say(f"{finished}/{len(todo)}: {row['id']} {row.get('outcome')}"
            + (f" ({row['error']})" if row.get("error") else ""))

    try:
        _run(client, todo, out, record)
    finally:
        write_table(table, rows)
    return rows


def _run(client, todo, out, record) -> None:
    """Run the items ``todo`` (in this process where ``client`` is None), each row to
    ``record`` as it ends."""
    if client is None:
        for it in todo:
            if stop_requested():
                break
            record(_guarded(it, out))
        return
    from dask.distributed import as_completed

    try:
        futures = {client.submit(_guarded, it, out, key=f"jaxhyst-{it['id']}-{time.time()}",
                                 retries=RETRIES, pure=False): it for it in todo}
        for future in as_completed(futures):
            it = futures[future]
            try:
                record(future.result())
            except Exception as err:  # noqa: BLE001 - a lost worker, after its retry
                record({"id": it["id"], "data": it["data"], "outcome": "failed",
                        "status": 1, "error": f"worker lost ({type(err).__name__}: "
                                              f"{' '.join(str(err).split())})"})
    finally:
        cluster = getattr(client, "cluster", None)
        client.close()
        if cluster is not None:
            cluster.close()


__all__ = ["ManifestError", "fit_many", "read_journal", "read_manifest", "read_table",
           "run_item"]
