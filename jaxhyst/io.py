"""Files: measured loops in, simulations and results out.

Reading. `read_loops` reads CSV/TSV/semicolon/whitespace-separated text with a header
(or without, given ``columns``; ``-`` there skips a column, e.g. a text column). A header
name is a quantity and optionally a unit:
``H``, ``H [kA/m]``, ``H (A/m)`` or ``H_A_per_m``; units are converted to SI. Several
loops in one file are told apart by a ``loop`` column. Every problem is reported as a
`DataError` whose message names the column, row or loop and the fix.

Writing. Every file goes through `jaxhyst._files`: a regular file is written atomically
(temporary file in the same directory, fsync, rename), so an interrupted write never
leaves a half-written file; a device, FIFO or ``/dev/stdout`` is written in place.
"""

from __future__ import annotations

import csv
import io
import json
import os
import re
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ._files import write_text
from .columns import QUANTITIES, DataError, parse_column  # noqa: F401  (jaxhyst.io's names)
from .model.simulate import Simulation
from .params import NAMES, Bounds, Parameters

#: Columns written for a simulation, with units (header names carry the unit).
SIMULATION_COLUMNS = (
    ("t", "t_s"), ("H", "H_A_per_m"), ("M", "M_A_per_m"), ("Man", "Man_A_per_m"),
    ("Mirr", "Mirr_A_per_m"), ("lam", "lambda"), ("y", "y_m"), ("strain", "strain"),
)  # fmt: skip

#: Per-loop conditions (constant within a loop; `Loop.conditions`).
CONDITION_COLUMNS = ("frequency", "temperature")

#: Signal columns → the `Problem` output they observe.
SIGNAL_OUTPUTS = {"y": "displacement", "strain": "strain", "lambda": "magnetostriction",
                  "M": "magnetization", "B": "flux_density"}

MIN_SAMPLES = 8


@dataclass
class Loop:
    """One measured loop, SI units: ``t`` (s) or ``None``, ``H`` (A/m) or ``None``, ``I``
    (A) or ``None``, the observed ``signals`` {quantity: samples} and its
    ``conditions`` {frequency (Hz), temperature (°C)} where the file has those columns."""

    index: int
    t: np.ndarray | None
    H: np.ndarray | None
    I: np.ndarray | None  # noqa: E741
    signals: dict = field(default_factory=dict)
    conditions: dict = field(default_factory=dict)

    @property
    def n_samples(self) -> int:
        for a in (self.t, self.H, self.I, *self.signals.values()):
            if a is not None:
                return int(a.shape[0])
        return 0


def _fast_table(body, delim, n_columns: int) -> np.ndarray | None:
    """The rows of ``body`` as a float array by NumPy's C parser when every cell is a
    finite number (a 2-million-row file in about a second); None when any row is not —
    the row-by-row reader then names the row and the column."""
    if delim is None or delim == '"':
        return None
    try:
        table = np.loadtxt(io.StringIO("\n".join(ln for _, ln in body)), delimiter=delim,
                           dtype=np.float64, ndmin=2, comments=None)
    except (ValueError, IndexError):
        return None
    if table.shape != (len(body), n_columns) or not np.all(np.isfinite(table)):
        return None
    return table


def _sniff_delimiter(line: str) -> str | None:
    for d in ("\t", ";", ","):
        if d in line:
            return d
    return None  # whitespace


def _split(line: str, delim: str | None) -> list[str]:
    if delim is None:
        return line.split()
    return [c.strip() for c in next(csv.reader([line], delimiter=delim))]


def _is_number(s: str) -> bool:
    try:
        float(s)
    except ValueError:
        return False
    return True


def read_loops(path, columns: list[str] | str | None = None, *,
               drive: bool = True) -> list[Loop]:
    """Read measured loops from a delimited text file (see the module docstring).

    **Arguments:**
    - ``path``: CSV (``,``), TSV (tab), ``;`` or whitespace separated; lines starting
      with ``#`` are comments.
    - ``columns``: column names for a file without a header (``["t", "H", "y [um]"]`` or
      ``"t,H,y [um]"``), or to override the file's header.
    - ``drive``: whether the file must give the drive (H or I); False for a file of a
      signal alone (a reference displacement to follow).

    **Returns:** one `Loop` per value of the ``loop`` column (or one loop). Raises
    `DataError` for: a missing or empty file, unknown columns, unit mismatches, NaN or
    non-numeric values, non-increasing time within a loop, fewer than 8 samples in a
    loop, a file with neither H nor I (where ``drive``).
    """
    path = Path(path)
    if path.is_dir() or not path.exists():  # (a pipe, e.g. bash's <(…), is read as a file)
        raise DataError(f"data file {str(path)!r} " + ("is a directory; give the file inside "
                        "it." if path.is_dir() else "does not exist."))
    raw = path.read_bytes()
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):  # UTF-16 with its byte-order mark
        try:
            raw = raw.decode("utf-16").encode("utf-8")
        except UnicodeDecodeError:
            raise DataError(f"data file {str(path)!r} starts as UTF-16 text but does not "
                            "decode as it; save it as UTF-8 CSV/TSV text.") from None
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as err:
        raise DataError(f"data file {str(path)!r} is not text (byte {err.start} is not "
                        "UTF-8); export it as CSV/TSV text.") from None
    if "\x00" in text:
        raise DataError(f"data file {str(path)!r} is not text (it holds NUL bytes); export "
                        "it as CSV/TSV text.")
    lines = [(i + 1, ln.strip()) for i, ln in enumerate(text.splitlines())]
    lines = [(i, ln) for i, ln in lines if ln and not ln.startswith("#")]
    if not lines:
        raise DataError(f"data file {str(path)!r} is empty.")
    delim = _sniff_delimiter(lines[0][1])
    first = _split(lines[0][1], delim)
    has_header = not all(_is_number(c) for c in first if c)
    if isinstance(columns, str):
        columns = [c for c in re.split(r",(?![^\[(]*[\])])", columns) if c.strip()]
    if columns is None:
        if not has_header:
            raise DataError(f"{path.name} has no header line; name its columns, e.g. "
                            "--columns 't,H,y' (units in brackets: 'y [um]').")
        columns = first
    body = lines[1:] if has_header else lines
    kept = [j for j, c in enumerate(columns) if c.strip() != "-"]  # ('-': skipped)
    parsed = [parse_column(columns[j]) for j in kept]
    names = [q for q, _ in parsed]
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:  # (a polarization J is read as M: J and M columns are one quantity)
        where = ", ".join(repr(columns[j].strip()) for j, q in zip(kept, names, strict=True)
                          if q == dup[0])
        raise DataError(f"{path.name}: quantity {dup[0]} appears in more than one column "
                        f"({where}); keep one (name the others '-' with --columns).")
    if drive and "H" not in names and "I" not in names:
        raise DataError(f"{path.name} has neither a field column H [A/m] nor a current column "
                        "I [A]; the drive must be given.")
    if len(body) == 0:
        raise DataError(f"{path.name} has a header but no data rows.")
    table = _fast_table(body, delim, len(columns))
    for r, (lineno, ln) in enumerate(body if table is None else ()):
        if r == 0:
            table = np.empty((len(body), len(columns)))
        cells = _split(ln, delim)
        if len(cells) != len(columns):
            hint = ("; the numbers seem to use decimal commas: write them with points, or "
                    "separate the columns by ';' or tabs" if delim == "," and
                    len(cells) == 2 * len(columns) else "")
            raise DataError(f"{path.name} line {lineno}: {len(cells)} values for "
                            f"{len(columns)} columns{hint}.")
        for c, cell in ((c, cells[c]) for c in kept):
            try:
                v = float(cell)
            except ValueError:
                v = float("nan")
            if not np.isfinite(v):
                fix = ("write the number itself (a NumPy repr: float(x), not repr of x)"
                       if re.fullmatch(r"(np|numpy)\.\w+\(.*\)", cell) else
                       "remove or repair that row")
                raise DataError(f"{path.name} line {lineno}, column {columns[c]!r}: value "
                                f"{cell!r} is not a finite number (NaN, inf, empty or text); "
                                f"{fix}.")
            table[r, c] = v
    data = {q: table[:, j] * f for j, (q, f) in zip(kept, parsed, strict=True)}
    ids = data.pop("loop", np.zeros(len(body)))
    loops = []
    for k in dict.fromkeys(ids.tolist()):  # in order of first appearance
        sel = ids == k
        cols = {q: a[sel] for q, a in data.items()}
        n = int(sel.sum())
        if n < MIN_SAMPLES:
            raise DataError(f"{path.name}: loop {k:g} has {n} samples; at least {MIN_SAMPLES} "
                            "are needed to fit a loop.")
        t = cols.pop("t", None)
        if t is not None and np.any(np.diff(t) <= 0):
            i = int(np.flatnonzero(np.diff(t) <= 0)[0])
            raise DataError(f"{path.name}: time is not increasing in loop {k:g} at sample "
                            f"{i + 1} (t = {t[i + 1]:g} s after {t[i]:g} s); sort the rows or "
                            "split the loops with a 'loop' column.")
        conditions = {}
        for q in CONDITION_COLUMNS:
            if q in cols:
                values = cols.pop(q)
                if np.ptp(values) > 1e-9 * max(abs(float(values[0])), 1.0):
                    raise DataError(f"{path.name}: the {q} of loop {k:g} changes within the "
                                    f"loop ({values.min():g} … {values.max():g}); a loop has "
                                    "one condition (split it with the 'loop' column).")
                conditions[q] = float(values[0])
        loops.append(Loop(index=int(k), t=t, H=cols.pop("H", None), I=cols.pop("I", None),
                          signals=cols, conditions=conditions))
    return loops


# -- writing ------------------------------------------------------------------------------


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path``: atomically for a regular file, in place for a device,
    FIFO or ``/dev/stdout`` (`jaxhyst._files.write_text`)."""
    write_text(path, text)


def write_columns_csv(path, columns: dict) -> None:
    """Write ``{header: 1-D array}`` as CSV (full float64 precision), atomically."""
    cols = [np.asarray(v, dtype=float) for v in columns.values()]
    rows = "\n".join(",".join(f"{v:.17g}" for v in row) for row in np.column_stack(cols))
    atomic_write_text(path, ",".join(columns) + "\n" + rows + "\n")


def write_simulation_csv(path, sim: Simulation, observed_only: bool = True, current=None,
                         y=None) -> None:
    """Write a simulation's signals, one row per sample, SI units in the header names;
    ``current``: the coil current (A) of the written samples, a column after t; ``y``:
    displacement values to write instead of the simulation's (a simulated sensor's)."""
    start = sim.run_in if observed_only else 0
    columns = {name: np.asarray(getattr(sim, f))[start:] for f, name in SIMULATION_COLUMNS}
    if y is not None:
        name = next(n for f, n in SIMULATION_COLUMNS if f == "y")
        columns[name] = np.asarray(y)
    if current is not None:
        first = next(iter(columns))
        columns = {first: columns[first], "I_A": np.asarray(current),
                   **{k: v for k, v in columns.items() if k != first}}
    write_columns_csv(path, columns)


def write_json(path, obj) -> None:
    """Write ``obj`` as indented JSON, atomically (NaN/inf are written as null)."""
    atomic_write_text(path, json.dumps(json_safe(obj), indent=2) + "\n")


def json_safe(obj):
    """``obj`` with NumPy arrays and scalars, tuples and non-string keys made JSON-able."""
    if isinstance(obj, dict):
        return {str(k): json_safe(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_safe(v) for v in obj]
    if isinstance(obj, (np.ndarray,)):
        return json_safe(obj.tolist())
    if isinstance(obj, (np.floating, float)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.integer):
        return int(obj)
    return obj


def read_json(path) -> dict:
    path = Path(path)
    if path.is_dir() or not path.exists():
        raise DataError(f"{str(path)!r} is a directory; give the JSON file inside it."
                        if path.is_dir() else f"file {str(path)!r} does not exist.")
    try:
        obj = json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise DataError(f"{path.name} is not a text (JSON) file.") from None
    except json.JSONDecodeError as err:
        raise DataError(f"{path.name} is not valid JSON ({err.msg} at line {err.lineno}).") \
            from None
    if not isinstance(obj, dict):
        raise DataError(f"{path.name}: expected a JSON object {{name: value, ...}}; got a "
                        f"{type(obj).__name__}.")
    return obj


# -- parameter, bounds and actuator files ------------------------------------------------


def _require_names(obj: dict, what: str) -> None:
    """Refuse a mapping that lacks one of the ten names or has an unknown one."""
    missing = [n for n in NAMES if n not in obj]
    unknown = [n for n in obj if n not in NAMES]
    if missing or unknown:
        raise DataError(f"{what} need the ten names {list(NAMES)} (SI units); missing "
                        f"{missing}, unknown {unknown}.")


def parameters_from_json(obj: dict, what: str = "parameters") -> Parameters:
    """`Parameters` from ``{name: value}`` or a result's ``{"params": {name: {"value":
    v}}}``."""
    if "params" in obj and isinstance(obj["params"], dict):
        obj = {n: (v["value"] if isinstance(v, dict) else v) for n, v in obj["params"].items()}
    _require_names(obj, what)
    try:
        vals = {n: np.asarray(obj[n], dtype=float) for n in NAMES}
        if all(v.ndim == 0 for v in vals.values()):
            return Parameters.from_dict({n: float(v) for n, v in vals.items()})
        L = max(v.size for v in vals.values())  # a joint result: values per loop
        return Parameters.from_array(np.stack([np.broadcast_to(vals[n], (L,))
                                               for n in NAMES], axis=-1))
    except (TypeError, ValueError) as err:
        raise DataError(f"{what}: every value must be a number ({err}).") from None


def bounds_from_json(obj: dict) -> Bounds:
    """`Bounds` from ``{name: [lower, upper]}`` for all ten parameters (SI)."""
    _require_names(obj, "bounds ([lower, upper] per parameter)")
    try:
        pairs = {n: (float(obj[n][0]), float(obj[n][1])) for n in NAMES}
    except (TypeError, ValueError, IndexError):
        raise DataError("bounds: each entry must be [lower, upper] numbers.") from None
    return Bounds.from_dict(pairs)


def bounds_changes_from_json(obj: dict, what: str = "bounds", extra=()) -> dict:
    """``{name: (lower, upper)}`` (SI) for the parameters a bounds file names (any subset
    of the ten and of the ``extra`` names: the others keep their default box)."""
    if not isinstance(obj, dict) or not obj:
        raise DataError(f"{what}: expected an object {{name: [lower, upper]}} naming at least "
                        "one parameter.")
    names = (*NAMES, *extra)
    unknown = [n for n in obj if n not in names]
    if unknown:
        raise DataError(f"{what}: unknown parameters {unknown}; the names are {list(names)}.")
    out = {}
    for n, pair in obj.items():
        try:
            lo, hi = float(pair[0]), float(pair[1])
            if len(pair) != 2:
                raise ValueError
        except (TypeError, ValueError, IndexError, KeyError):
            raise DataError(f"{what}: {n} must be [lower, upper] (two numbers, SI); got "
                            f"{pair!r}.") from None
        if not (np.isfinite(lo) and np.isfinite(hi) and lo <= hi):
            raise DataError(f"{what}: {n} = [{lo:g}, {hi:g}] needs finite lower <= upper.")
        out[n] = (lo, hi)
    return out


def bounds_to_json(bounds: Bounds) -> dict:
    lo, hi = bounds.lower.to_dict(), bounds.upper.to_dict()
    return {n: [lo[n], hi[n]] for n in NAMES}
