"""Inputs shared by the commands: presets and files of parameters, actuators and bounds,
output paths, the observed signal of a data file, and the problem a result file records
(`build_problem`, so that ``jaxhyst report`` can rebuild it)."""

from __future__ import annotations

import json
import os
import sys
from pathlib import Path

from jaxhyst._files import writes_in_place
from jaxhyst.names import CONDITION_FEATURES, DEFAULT_SUBSTEPS, VARIANT_CLASSES


class CLIError(ValueError):
    """An input problem reported as one line, exit status 2."""


def variant_from_name(name: str):
    """The `AbstractJAVariant` instance for a command-line name (one of `VARIANTS`)."""
    import jaxhyst as jh

    return getattr(jh, VARIANT_CLASSES[name])()


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
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            raise CLIError(f"{flag} {value}: cannot write in {parent}; choose a writable "
                           "location.")
    if vars(args).get("png"):
        import importlib.util

        if importlib.util.find_spec("matplotlib") is None:
            raise CLIError(f"--png {args.png}: figures need matplotlib; pip install "
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
    return bounds_changes_from_json(read_json(spec), f"--bounds {spec}")


def resolve_bounds(spec: dict, given, loops):
    """The full box of a fit (and a line saying where it came from): for M or B data the
    box derived from the ``loops`` read from ``spec["data"]``, else the paper's Table 1
    box; a bounds file's entries replace the defaults for the parameters it names; a
    preset is used as is."""
    import jaxhyst as jh
    from jaxhyst.identify.measured import loop_bounds, merge_bounds
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS

    if isinstance(given, jh.Bounds):
        return given, None
    if not spec.get("joint") and spec.get("loop") is not None:
        loops = [lp for lp in loops if lp.index == spec["loop"]] or loops
    out = loop_signal(spec, loops[0], spec.get("output"))
    kind = SIGNAL_OUTPUTS[out]
    if not output_kind(kind).magnetic_only:
        named = f" with {sorted(given)} from the bounds file" if given else ""
        return (merge_bounds(jh.TABLE1_BOUNDS, given or {}),
                f"bounds: the paper's Table 1 box{named}")
    actuator = jh.Actuator(**spec["actuator"])
    Hs = [loop_field(lp, actuator, spec["data"]) for lp in loops]
    bounds = loop_bounds(Hs, [lp.signals[out] for lp in loops], kind, given)
    lo, hi = bounds.lower.to_dict(), bounds.upper.to_dict()
    text = ", ".join(f"{n} [{lo[n]:.3g}, {hi[n]:.3g}]" for n in ("Ms", "a", "k", "alpha", "c"))
    named = f" ({sorted(given)} from the bounds file)" if given else ""
    return bounds, f"bounds derived from the data{named}: {text}"


def fixed_arg(items, params) -> dict:
    from jaxhyst.params import NAMES

    out = {}
    for item in items or []:
        for part in item.split(","):
            name, _, value = part.partition("=")
            name = name.strip()
            if name not in NAMES:
                raise CLIError(f"--fix {part!r}: unknown parameter; names are {list(NAMES)}.")
            if name in out:
                raise CLIError(f"--fix names {name} twice; give each parameter once.")
            if value:
                try:
                    out[name] = float(value)
                except ValueError:
                    raise CLIError(f"--fix {part!r}: {value!r} is not a number.") from None
            elif params is not None:
                out[name] = float(getattr(params, name))
            else:
                raise CLIError(f"--fix {name}: give a value (--fix {name}=VALUE) or --params.")
    return out


def print_result(args, summary: dict, text: str) -> None:
    if vars(args).get("json", False):
        from jaxhyst.io import _json_safe

        print(json.dumps(_json_safe(summary)))
    else:
        print(text)


def note(label: str, text: str) -> None:
    """A line ``[label] text`` on stderr: what the command decided (a derived box, the
    starts), before the progress lines of the run."""
    print(f"[{label}] {text}", file=sys.stderr, flush=True)


def warn(args, text: str) -> None:
    print(f"jaxhyst {args.command}: warning: {text}", file=sys.stderr, flush=True)


def loop_signal(spec, loop, out):
    from jaxhyst.io import SIGNAL_OUTPUTS

    signals = [q for q in loop.signals if q in SIGNAL_OUTPUTS]
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


def loop_drive(spec, loop, out, actuator):
    import jaxhyst as jh
    from jaxhyst.identify.measured import monotone_branches
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS

    H = loop_field(loop, actuator, spec["data"])
    if loop.t is None and output_kind(SIGNAL_OUTPUTS[out]).needs_time:
        raise CLIError(f"{spec['data']} has no time column t; {out} depends on the structural "
                       "dynamics, which need times (only M or B loops may omit t).")
    if output_kind(SIGNAL_OUTPUTS[out]).magnetic_only:
        H = monotone_branches(H)  # reversals below 5 % of the range are noise
    return jh.drive_from_record(loop.t, H, run_in_periods=spec.get("run_in_periods", 1))


def parse_vary(text) -> dict:
    """``--vary 'k:log_f+T,c:log_amplitude'`` → ``{"k": ("log_f", "T"), "c": (…)}``."""
    if not text:
        return {}
    from jaxhyst.params import NAMES

    out = {}
    for item in text.split(","):
        name, _, feats = item.strip().partition(":")
        name = name.strip()
        feats = tuple(f.strip() for f in feats.split("+") if f.strip())
        if name not in (*NAMES, "eddy", "excess"):
            raise CLIError(f"--vary {item!r}: {name!r} is not a parameter; names are "
                           f"{list(NAMES)}.")
        bad = [f for f in feats if f not in CONDITION_FEATURES]
        if not feats or bad:
            raise CLIError(f"--vary {item!r}: give the features after a colon, joined by "
                           f"'+', from {list(CONDITION_FEATURES)} (e.g. 'k:log_f+T').")
        out[name] = feats
    return out


def loop_conditions(spec, loops, actuator, overrides=None):
    """The `Conditions` of the loops: frequency and temperature from the file's columns
    (where it has them; ``overrides`` {name: value} replaces them for every loop),
    amplitude = the loop's peak field (A/m)."""
    import numpy as np

    import jaxhyst as jh

    def column(q):
        if (overrides or {}).get(q) is not None:
            return [float(overrides[q])] * len(loops)
        have = [lp.conditions.get(q) for lp in loops]
        if all(v is None for v in have):
            return None
        missing = [lp.index for lp, v in zip(loops, have, strict=True) if v is None]
        if missing:
            raise CLIError(f"{spec['data']}: loops {missing} have no {q}; give every loop "
                           f"its {q} (a '{q}' column).")
        return have

    amplitude = [float(np.max(np.abs(loop_field(lp, actuator, spec["data"])))) for lp in loops]
    return jh.Conditions(frequency=column("frequency"), temperature=column("temperature"),
                         amplitude=amplitude)


def load_result(path):
    """(saved JSON, its problem spec with the data path resolved, the rebuilt problem, the
    fitted parameters) of a result file of ``jaxhyst identify --out``. The parameters are
    the coefficient dict of a condition model (``--vary``), else a `Parameters`."""
    import numpy as np

    from jaxhyst.io import parameters_from_json, read_json

    saved = read_json(path)
    if "problem" not in saved:
        raise CLIError(f"{path} is not a jaxhyst identify result (no 'problem' entry).")
    spec = dict(saved["problem"])
    if not os.path.isabs(spec["data"]):  # stored relative to the result file
        spec["data"] = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)),
                                                     spec["data"]))
    problem = build_problem(spec)
    if "coefficients" in saved:
        params = {n: np.float64(v) for n, v in saved["coefficients"].items()}
    else:
        params = parameters_from_json(saved, f"parameters in {path}")
    return saved, spec, problem, params


def build_problem(spec: dict, loops=None):
    """A `Problem` (or `JointProblem` when ``spec["joint"]``) from the JSON-able ``spec``
    stored with every CLI result (so that ``jaxhyst report`` can rebuild it); ``loops``:
    the loops of ``spec["data"]`` if already read."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import fix_structural
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS, bounds_from_json, read_loops

    if loops is None:
        loops = read_loops(spec["data"], spec.get("columns"))
    ids = [lp.index for lp in loops]
    bounds = bounds_from_json(spec["bounds"])
    actuator = jh.Actuator(**spec["actuator"])
    variant = variant_from_name(spec.get("variant", "energy"))
    fixed = dict(spec.get("fixed") or {})
    if spec.get("joint"):
        out = loop_signal(spec, loops[0], spec.get("output"))
        if output_kind(SIGNAL_OUTPUTS[out]).magnetic_only:
            fixed = fix_structural(bounds, fixed)
        vary = parse_vary(spec.get("vary"))
        per_loop = spec.get("per_loop") or ()
        if vary and per_loop:
            raise CLIError("--vary and --per-loop both say how parameters differ between "
                           "loops; use one of them.")
        if vary:  # (checked before the records: a missing column is the one message)
            conditions = loop_conditions(spec, loops, actuator)
            for name, feats in vary.items():
                for f in feats:
                    what, unit = CONDITION_FEATURES[f]  # (amplitude: from the field)
                    if what != "amplitude" and getattr(conditions, what) is None:
                        raise CLIError(f"--vary {name}:{f}: {spec['data']} has no {what} "
                                       f"column; add a '{what}' column ({unit}) or drop "
                                       f"{f} from --vary.")
        space = (jh.per_record_space(bounds, len(loops)) if vary else
                 jh.JointSpace(bounds, len(loops), per_loop=per_loop, fixed=fixed))
        records = jh.JointProblem([lp.signals[out] for lp in loops],
                                  [loop_drive(spec, lp, out, actuator) for lp in loops],
                                  actuator, space, output=SIGNAL_OUTPUTS[out],
                                  variant=variant,
                                  substeps=spec.get("substeps", DEFAULT_SUBSTEPS))
        if not vary:
            return records
        model = jh.ConditionModel(vary, int(spec.get("vary_degree", 1)))
        try:
            cspace = jh.condition_space(bounds, model, fixed=fixed)
            return jh.ConditionProblem(records, conditions, model, cspace)
        except ValueError as err:
            raise CLIError(f"--vary: {err}") from None
    if spec.get("loop") is None:
        if len(loops) > 1:
            raise CLIError(f"{spec['data']} holds loops {ids}; choose one with --loop, or fit "
                           "them together with --joint.")
        loop = loops[0]
    else:
        if spec["loop"] not in ids:
            raise CLIError(f"--loop {spec['loop']}: {spec['data']} holds loops {ids}.")
        loop = loops[ids.index(spec["loop"])]
    out = loop_signal(spec, loop, spec.get("output"))
    if output_kind(SIGNAL_OUTPUTS[out]).magnetic_only:
        fixed = fix_structural(bounds, fixed)
    space = jh.ParameterSpace(bounds, fixed or None)
    return jh.Problem(loop.signals[out], loop_drive(spec, loop, out, actuator), actuator,
                      space, output=SIGNAL_OUTPUTS[out], variant=variant,
                      substeps=spec.get("substeps", DEFAULT_SUBSTEPS))
