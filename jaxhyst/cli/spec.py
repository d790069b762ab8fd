"""Inputs shared by the commands: presets and files of parameters, actuators and bounds,
output paths, the observed signal of a data file, and the problem a result file records
(`build_problem`, so that ``jaxhyst report`` can rebuild it)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from jaxhyst._files import writes_in_place
from jaxhyst.names import FORM_PARAMETER_NAMES, LOSS_PARAMETER_NAMES, VARIANT_CLASSES


class CLIError(ValueError):
    """An input problem reported as one line, exit status 2."""


def variant_from_name(name: str, cells: int | None = None):
    """The model form for a command-line name (one of `VARIANTS`; ``cells``: the pinning
    cells of a form that has them, its default if None)."""
    import jaxhyst as jh

    cls = getattr(jh, VARIANT_CLASSES[name])
    if issubclass(cls, jh.AbstractPlayForm) and cells is not None:
        return cls(cells=int(cells))
    return cls()


def _can_create_in(directory: Path) -> bool:
    """Whether a file can really be made there: the permission bits alone say yes for
    root on /proc."""
    import tempfile

    try:
        with tempfile.NamedTemporaryFile(dir=directory, prefix=".jaxhyst-probe-"):
            return True
    except OSError:
        return False


def check_outputs(args, *, directory: str | None = None) -> None:
    """Check the output paths before any work: each file option (``--csv``, ``--png``,
    ``--out``, ``--save-model``) must name a file whose directory exists or can be made
    and is writable (or a writable device); ``directory`` names the option that is a
    directory instead (reproduce ``--out``). A figure needs matplotlib."""
    for opt in ("csv", "png", "out", "save_model"):
        value = vars(args).get(opt)
        if not value or value is True:
            continue
        flag = f"--{opt.replace('_', '-')}"
        if opt != directory and writes_in_place(Path(value).expanduser()):
            # a device, FIFO or /dev/stdout: written in place, so it must be writable
            if not os.access(Path(value).expanduser(), os.W_OK):
                raise CLIError(f"{flag} {value}: is not writable; choose a writable file.")
            continue
        path = Path(value).expanduser().resolve()
        if opt == directory:
            if path.exists() and not path.is_dir():
                raise CLIError(f"{flag} {value}: exists and is not a directory; name a "
                               "directory for the outputs.")
            parent = path
        else:
            if path.is_dir():
                name = {"out": "result.json", "save_model": "model.eqx"}.get(opt, f"out.{opt}")
                example = Path(value) / name
                raise CLIError(f"{flag} {value}: is a directory; give a file name, e.g. "
                               f"{example}.")
            parent = path.parent
        while not parent.exists():  # made on writing: the nearest existing one decides
            parent = parent.parent
        if not parent.is_dir() or not _can_create_in(parent):
            raise CLIError(f"{flag} {value}: cannot write in {parent}; choose a writable "
                           "location.")
    if vars(args).get("png"):
        import importlib.util

        from jaxhyst.plots import FIGURE_FORMATS, figure_format

        if args.png is not True and not writes_in_place(Path(args.png).expanduser()) \
                and figure_format(args.png) is None:  # (reproduce's --png is a flag)
            raise CLIError(f"--png {args.png}: figures are written as "
                           f"{', '.join('.' + f for f in FIGURE_FORMATS)}; give a file name "
                           "with one of those extensions.")

        if importlib.util.find_spec("matplotlib") is None:
            raise CLIError("--png: figures need matplotlib; pip install "
                           "'jaxhyst[plots]' or leave --png out.")


def parameters_arg(spec: str):
    import jaxhyst as jh
    from jaxhyst.io import parameters_from_json, read_json

    if spec == "table1":
        return jh.TABLE1_TRUE
    if spec.startswith("table3:"):
        f = spec.split(":", 1)[1]
        if not f.isdigit() or int(f) not in jh.TABLE3:
            raise CLIError(f"--params {spec}: Table 3 has frequencies {sorted(jh.TABLE3)} Hz.")
        return jh.TABLE3[int(f)]
    if not os.path.exists(spec):
        raise CLIError(f"--params {spec!r}: not a preset (table1, table3:<Hz>) nor a file.")
    return parameters_from_json(read_json(spec), f"parameters in {spec}")


def actuator_arg(spec: str):
    import jaxhyst as jh
    from jaxhyst.io import read_json

    presets = {"actuator1": jh.ACTUATOR1, "actuator2": jh.ACTUATOR2}
    if spec.lower() in presets:
        return presets[spec.lower()]
    if not os.path.exists(spec):
        raise CLIError(f"--actuator {spec!r}: not a preset (actuator1, actuator2) nor a JSON "
                       "file with Ar (m^2), lr (m), n (1/m, optional), Hb (A/m, optional).")
    d = read_json(spec)
    unknown = sorted(set(d) - {"Ar", "lr", "n", "Hb", "name"})
    if unknown or "Ar" not in d or "lr" not in d:
        raise CLIError(f"actuator file {spec}: needs Ar and lr (n, Hb, name optional); "
                       f"unknown keys {unknown}.")
    return jh.Actuator(**{k: (v if k == "name" else (None if v is None else float(v)))
                          for k, v in d.items()})


def bounds_arg(spec: str | None):
    """--bounds: None (the default box), the table1 preset, or the changes a JSON file
    names ({name: [lower, upper]}, any subset of the parameters)."""
    import jaxhyst as jh
    from jaxhyst.io import bounds_changes_from_json, read_json

    if spec is None:
        return None
    if spec == "table1":
        return jh.TABLE1_BOUNDS
    if not os.path.exists(spec):
        raise CLIError(f"--bounds {spec!r}: not a preset (table1) nor a JSON file "
                       "{name: [lower, upper]}.")
    return bounds_changes_from_json(read_json(spec), f"--bounds {spec}",
                                    extra=(*LOSS_PARAMETER_NAMES, *FORM_PARAMETER_NAMES))


def _parameter_names() -> tuple:
    """The names --fix and --per-loop take: the ten, the loss coefficients, the forms'."""
    from jaxhyst.params import NAMES

    return (*NAMES, *LOSS_PARAMETER_NAMES, *FORM_PARAMETER_NAMES)


def per_loop_arg(text) -> list:
    """--per-loop ``'a,k,c'`` → ``["a", "k", "c"]`` (the names --fix takes)."""
    names = _parameter_names()
    out = [n.strip() for n in (text or "").split(",") if n.strip()]
    unknown = [n for n in out if n not in names]
    if unknown:
        raise CLIError(f"--per-loop {text!r}: {unknown[0]!r} is not a parameter; names are "
                       f"{list(names)}.")
    return out


def fixed_arg(items, params) -> dict:
    """--fix: ``{name: value}`` (the ten, the loss coefficients, a form's spread)."""
    from jaxhyst.params import NAMES

    names = _parameter_names()
    out = {}
    for item in items or []:
        for part in item.split(","):
            name, _, value = part.partition("=")
            name = name.strip()
            if name not in names:
                raise CLIError(f"--fix {part!r}: unknown parameter; names are {list(names)}.")
            if name in out:
                raise CLIError(f"--fix names {name} twice; give each parameter once.")
            if value:
                try:
                    out[name] = float(value)
                except ValueError:
                    raise CLIError(f"--fix {part!r}: {value!r} is not a number.") from None
            elif params is not None and name in NAMES:
                out[name] = float(getattr(params, name))
            else:
                raise CLIError(f"--fix {name}: give a value (--fix {name}=VALUE) or --params.")
    return out


def print_result(args, summary: dict, text: str) -> None:
    if vars(args).get("json", False):
        from jaxhyst.io import json_safe

        print(json.dumps(json_safe(summary)))
    else:
        print(text)


def note(label: str, text: str) -> None:
    """A line ``[label] text`` on stderr: what the command decided (a derived box, the
    starts), before the progress lines of the run."""
    print(f"[{label}] {text}", file=sys.stderr, flush=True)


def read_data(path, columns=None, *, said: list | None = None, drive: bool = True) -> list:
    """The loops of a data file (`jaxhyst.io.read_loops`), each loop with a frequency and
    no t column given times from it where its samples are a sinusoid's, uniform in time
    (`jaxhyst.loop_times.times_from_frequency`): every command that reads loops reads
    them alike. The line saying so (or why not) is appended to ``said`` where given — for
    the command to note once its input is checked (an error stays one line). ``drive``
    False: a file without H or I (the B(t) of a B-driven model's loops) is read too."""
    from jaxhyst.io import read_loops
    from jaxhyst.loop_times import times_from_frequency

    loops, text = times_from_frequency(read_loops(path, columns, drive=drive))
    if text and said is not None:
        said.append(text)
    return loops


def warn(args, text: str) -> None:
    print(f"jaxhyst {args.command}: warning: {cli_wording(text, args)}", file=sys.stderr,
          flush=True)


def cli_wording(text: str, args=None) -> str:
    """``text`` (a library's error or warning) in command-line spelling, on one line:
    NumPy/JAX reprs as plain numbers (``np.float64(2.5)``, ``array(inf)`` → ``2.5``,
    ``inf``; not where quoted, as a file's cell is) and the Python name of each of the
    command's options (``samples_per_period``) as the option (``--samples-per-period``)."""
    import re

    text = " ".join(str(text).split())
    # (not in quotes: a quoted value is what a file holds, and is shown as it is)
    text = re.sub(r"(?<!')\bnp\.(?:float|int)\d+\(([^()]*)\)", r"\1", text)
    text = re.sub(r"(?<!')\b[Aa]rray\(([^(),]*)(?:, dtype=\w+)?\)", r"\1", text)
    for dest in sorted(vars(args) if args is not None else (), key=len, reverse=True):
        if "_" in dest and not dest.startswith("_"):
            pattern = rf"(?<![-\w./\\]){dest}(?![\w/\\]|\.\w)"
            text = re.sub(pattern, "--" + dest.replace("_", "-"), text)
    return text


def signal_columns(loop) -> list[str]:
    """The loop's columns of an observed signal (y, strain, lambda, M, B)."""
    from jaxhyst.io import SIGNAL_OUTPUTS

    return [q for q in loop.signals if q in SIGNAL_OUTPUTS]


def signal_column(kind: str) -> str | None:
    """The data column of an output kind (``"flux_density"`` → ``"B"``), or None."""
    from jaxhyst.io import SIGNAL_OUTPUTS

    return next((q for q, k in SIGNAL_OUTPUTS.items() if k == kind), None)


def loop_signal(spec, loop, out):
    signals = signal_columns(loop)
    if out is None:
        if len(signals) != 1:
            raise CLIError(f"{spec['data']} has signal columns {signals}; choose the observed "
                           "one with --output (y, strain, lambda, M or B).")
        out = signals[0]
    if out not in loop.signals:
        raise CLIError(f"--output {out}: {spec['data']} has no such column (signals: "
                       f"{signals}).")
    return out


def loop_field(loop, actuator, source):
    """The loop's field H (A/m), from its H column or as H = n·I + Hb from its current."""
    if loop.H is not None:
        return loop.H
    if actuator.n is None:
        raise CLIError(f"{source} gives a current I but {actuator.name} has no turns per "
                       "metre n; add n to the actuator or give the field H.")
    return actuator.n * loop.I + actuator.Hb


def flux_of(lp, data):
    """The B(t) samples of a loop that drive a B-driven model (T); its t and B columns
    are needed (a `CLIError` naming the loop and the file otherwise)."""
    missing = [q for q, v in (("t", lp.t), ("B", lp.signals.get("B"))) if v is None]
    if missing:
        raise CLIError(f"loop {lp.index} of {data} has no {', '.join(missing)} column: a "
                       "B-driven model (--driven-by B) is driven by its B(t) (columns t and "
                       "B, and H to fit or compare with).")
    return lp.signals["B"]


def check_flux_loops(loops, data) -> None:
    """A `CLIError` (one line, naming the loop and the file) unless every loop has the
    columns a B-driven fit needs: t and B (its drive) and H (its data)."""
    for lp in loops:
        flux_of(lp, data)
        if lp.H is None:
            raise CLIError(f"--driven-by B: loop {lp.index} of {data} has no H column; "
                           "B(t) drives the model and H is fitted (columns t, H and B). "
                           "Records of B(t) with a measured core loss and no H are fitted "
                           "in Python: jaxhyst.FluxProblem(energies, drives, space, "
                           "output='cycle_energy').")


def loop_drive(spec, loop, out, actuator, source=None):
    """The drive of a loop (``source``: the file it was read from; the spec's data file
    by default)."""
    import jaxhyst as jh
    from jaxhyst.identify.measured import monotone_branches
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS

    source = source or spec["data"]
    H = loop_field(loop, actuator, source)
    if loop.t is None and output_kind(SIGNAL_OUTPUTS[out]).needs_time:
        raise CLIError(f"{source} has no time column t; {out} depends on the structural "
                       "dynamics, which need times (only M or B loops may omit t).")
    if output_kind(SIGNAL_OUTPUTS[out]).magnetic_only:
        H = monotone_branches(H)  # reversals below 5 % of the range are noise
    return jh.drive_from_record(loop.t, H, run_in_periods=spec.get("run_in_periods", 1))


def select_loops(loops, wanted, source) -> list:
    """The loops of ``loops`` (of the file ``source``) whose index is in ``wanted``
    (``--loop``; all where it is not given); one line naming a loop the file lacks."""
    if not wanted:
        return loops
    ids = [lp.index for lp in loops]
    missing = [i for i in wanted if i not in ids]
    if missing:
        raise CLIError(f"--loop {missing}: {source} holds loops {ids}.")
    return [lp for lp in loops if lp.index in wanted]


def float_list(text: str, option: str) -> list[float]:
    """The comma-separated numbers of ``option``'s value ``text`` (one line if not)."""
    import math

    try:
        values = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        raise CLIError(f"{option} {text!r}: give comma-separated numbers.") from None
    if not values or not all(math.isfinite(v) for v in values):
        raise CLIError(f"{option} {text!r}: give finite comma-separated numbers.")
    return values


def file_sha256(path: str) -> str:
    """The SHA-256 of a data file (a saved model names what it was fitted to)."""
    import hashlib

    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def data_changed(data: str, sha256: str | None, fitted: str) -> str:
    """Why the data file ``data`` is not the one ``fitted`` (a result or model file) was
    fitted to (its SHA-256 differs from ``sha256``), in one line; '' where it is, or
    where either is unknown."""
    if not sha256 or not os.path.isfile(data) or file_sha256(data) == sha256:
        return ""
    return (f"{data} changed since {fitted} was fitted to it (its SHA-256 differs): refit, "
            "or restore the file it was fitted to.")
