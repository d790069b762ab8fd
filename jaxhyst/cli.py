"""The ``jaxhyst`` command.

Units are SI everywhere unless a data file's header says otherwise: field H in A/m,
current I in A, displacement y in m, magnetization M in A/m, flux density B in T, time t in
s, frequency in Hz; strain and magnetostriction are dimensionless. Parameters: Ms, a, k in
A/m; λs, α̃, c dimensionless; E in N/m², Kz in N/m, Mz in kg, Cz in N·s/m.

Errors in the input end the command with exit status 2 and a one-line message on stderr.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path

from jaxhyst._files import writes_in_place
from jaxhyst.names import DEFAULT_SUBSTEPS, HYBRID_NAMES, SOLVER_NAMES, VARIANT_CLASSES

UNITS_HELP = ("Units: H A/m, I A, y m, M A/m, B T, t s, f Hz; Ms, a, k A/m; E N/m^2, "
              "Kz N/m, Mz kg, Cz N*s/m; lambda_s, alpha, c dimensionless.")
LOCAL = SOLVER_NAMES
VARIANTS = tuple(VARIANT_CLASSES)


def variant_from_name(name: str):
    """The `JAVariant` instance for a command-line name (one of `VARIANTS`)."""
    import jaxhyst as jh

    return getattr(jh, VARIANT_CLASSES[name])()
HYBRID = HYBRID_NAMES


def _number(kind, minimum, strict: bool, what: str):
    """An argparse type: a finite number of ``kind`` ≥ (or >) ``minimum``; the error
    names the rule (argparse adds the option and the value)."""
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not math.isfinite(value) or value < minimum or (strict and value == minimum):
            raise argparse.ArgumentTypeError(f"{text!r}: must be {what}")
        return value

    parse.__name__ = what
    return parse


POSITIVE_INT = _number(int, 0, True, "a positive integer")
COUNT = _number(int, 0, False, "an integer >= 0")
POSITIVE = _number(float, 0.0, True, "a positive number")
FINITE = _number(float, -math.inf, True, "a finite number")


class _Parser(argparse.ArgumentParser):
    """Usage errors as one line (the option, the value, the rule) instead of the usage
    block; ``--help`` has the rest."""

    def error(self, message):
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")


class CLIError(ValueError):
    """An input problem reported as one line, exit status 2."""


# -- shared resolution of presets and files -----------------------------------------------


def _check_outputs(args, *, directory: str | None = None) -> None:
    """Check the output paths before any work: each file option (``--csv``, ``--png``,
    ``--out``) must name a file whose directory exists or can be made and is writable;
    ``directory`` names the option that is a directory instead (reproduce ``--out``).
    A figure needs matplotlib."""
    for opt in ("csv", "png", "out"):
        value = getattr(args, opt, None)
        if not value or value is True:
            continue
        flag = f"--{opt}"
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
                example = Path(value) / ("result.json" if opt == "out" else f"out.{opt}")
                raise CLIError(f"{flag} {value}: is a directory; give a file name, e.g. "
                               f"{example}.")
            parent = path.parent
        while not parent.exists():  # made on writing: the nearest existing one decides
            parent = parent.parent
        if not parent.is_dir() or not os.access(parent, os.W_OK | os.X_OK):
            raise CLIError(f"{flag} {value}: cannot write in {parent}; choose a writable "
                           "location.")
    if getattr(args, "png", None):
        import importlib.util

        if importlib.util.find_spec("matplotlib") is None:
            raise CLIError(f"--png {args.png}: figures need matplotlib; pip install "
                           "'jaxhyst[plots]' or leave --png out.")


def _params(spec: str):
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


def _actuator(spec: str):
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


def _bounds(spec: str | None):
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


def _resolve_bounds(spec: dict, given, loops):
    """The full box of a fit (and a line saying where it came from): for M or B data the
    box derived from the ``loops`` read from ``spec["data"]``, else the paper's Table 1
    box; a bounds file's entries replace the defaults for the parameters it names; a
    preset is used as is."""
    import jaxhyst as jh
    from jaxhyst.identify.measured import loop_bounds, merge_bounds
    from jaxhyst.io import SIGNAL_OUTPUTS

    if isinstance(given, jh.Bounds):
        return given, None
    if not spec.get("joint") and spec.get("loop") is not None:
        loops = [lp for lp in loops if lp.index == spec["loop"]] or loops
    out = _loop_signal(spec, loops[0], spec.get("output"))
    kind = SIGNAL_OUTPUTS[out]
    if kind not in ("magnetization", "flux_density"):
        named = f" with {sorted(given)} from the bounds file" if given else ""
        return (merge_bounds(jh.TABLE1_BOUNDS, given or {}),
                f"bounds: the paper's Table 1 box{named}")
    actuator = jh.Actuator(**spec["actuator"])
    Hs = [_loop_field(lp, actuator, spec["data"]) for lp in loops]
    bounds = loop_bounds(Hs, [lp.signals[out] for lp in loops], kind, given)
    lo, hi = bounds.lower.to_dict(), bounds.upper.to_dict()
    text = ", ".join(f"{n} [{lo[n]:.3g}, {hi[n]:.3g}]" for n in ("Ms", "a", "k", "alpha", "c"))
    named = f" ({sorted(given)} from the bounds file)" if given else ""
    return bounds, f"bounds derived from the data{named}: {text}"


def _fixed(items, params) -> dict:
    from jaxhyst.params import NAMES

    out = {}
    for item in items or []:
        for part in item.split(","):
            name, _, value = part.partition("=")
            name = name.strip()
            if name not in NAMES:
                raise CLIError(f"--fix {part!r}: unknown parameter; names are {list(NAMES)}.")
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


def _print(args, summary: dict, text: str) -> None:
    if getattr(args, "json", False):
        from jaxhyst.io import _json_safe

        print(json.dumps(_json_safe(summary)))
    else:
        print(text)


# -- simulate -----------------------------------------------------------------------------


def _drive_from_args(args, actuator):
    import jaxhyst as jh
    from jaxhyst.io import read_loops

    if args.drive:
        loop = read_loops(args.drive, args.columns)[0]
        return (jh.drive_from_record(loop.t, _loop_field(loop, actuator, args.drive)),
                f"drive from {args.drive}")
    if args.field_amplitude is not None:
        d = jh.sinusoidal_field(args.frequency, args.field_amplitude, args.field_offset,
                                periods=args.periods,
                                samples_per_period=args.samples_per_period)
        return d, (f"H = {args.field_offset:g} + {args.field_amplitude:g} "
                   f"sin(2π·{args.frequency:g} t) A/m")
    d = jh.sinusoidal_current(args.frequency, args.amplitude, args.offset, actuator,
                              periods=args.periods, samples_per_period=args.samples_per_period)
    return d, f"I = {args.amplitude:.2f} sin(2π·{args.frequency:g} t) + {args.offset:.2f} A"


def _simulate(args) -> int:
    import jaxhyst as jh
    from jaxhyst.io import write_simulation_csv

    _check_outputs(args)
    params = _params(args.params or args.preset)
    actuator = _actuator(args.actuator)
    drive, what = _drive_from_args(args, actuator)
    from jaxhyst.identify.measured import coarse_sampling

    coarse = coarse_sampling(drive.observed(drive.H), args.substeps, fix="--substeps {}")
    if coarse is not None:
        _warn(args, coarse)
    sim = jh.simulate(params, actuator, drive, variant=variant_from_name(args.variant),
                      substeps=args.substeps)
    y = sim.observed("y")
    summary = {
        "params": args.params or args.preset, "actuator": actuator.name, "drive": what,
        "samples_observed": int(y.shape[0]), "y_min_m": float(y.min()),
        "y_max_m": float(y.max()), "M_over_Ms_min": float(sim.observed("M").min() / params.Ms),
        "M_over_Ms_max": float(sim.observed("M").max() / params.Ms),
    }  # fmt: skip
    if args.png:  # the figure first: if it fails, no CSV is left behind without it
        from jaxhyst.plots import plot_simulation

        plot_simulation(sim, args.png, title=f"{actuator.name}, {what}")
        summary["png"] = args.png
    if args.csv:
        write_simulation_csv(args.csv, sim)
        summary["csv"] = args.csv
    text = [f"simulated {summary['samples_observed']} observed samples ({actuator.name}, {what})",
            f"  y in [{summary['y_min_m'] * 1e6:.3f}, {summary['y_max_m'] * 1e6:.3f}] μm, "
            f"M/Ms in [{summary['M_over_Ms_min']:.3f}, {summary['M_over_Ms_max']:.3f}]"]
    text += [f"  wrote {summary[k]}" for k in ("csv", "png") if k in summary]
    _print(args, summary, "\n".join(text))
    return 0


# -- identify -----------------------------------------------------------------------------


def _loop_signal(spec, loop, out):
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


def _loop_field(loop, actuator, source):
    """The loop's field H (A/m), from its H column or as H = n·I + Hb from its current."""
    if loop.H is not None:
        return loop.H
    if actuator.n is None:
        raise CLIError(f"{source} gives a current I but {actuator.name} has no turns per "
                       "metre n; add n to the actuator or give the field H.")
    return actuator.n * loop.I + actuator.Hb


def _loop_drive(spec, loop, out, actuator):
    import jaxhyst as jh
    from jaxhyst.identify.measured import monotone_branches
    from jaxhyst.io import SIGNAL_OUTPUTS

    H = _loop_field(loop, actuator, spec["data"])
    if loop.t is None and SIGNAL_OUTPUTS[out] in ("displacement", "strain"):
        raise CLIError(f"{spec['data']} has no time column t; {out} depends on the structural "
                       "dynamics, which need times (only M or B loops may omit t).")
    if SIGNAL_OUTPUTS[out] in ("magnetization", "flux_density"):
        H = monotone_branches(H)  # reversals below 5 % of the range are noise
    return jh.drive_from_record(loop.t, H, run_in_periods=spec.get("run_in_periods", 1))


def build_problem(spec: dict, loops=None):
    """A `Problem` (or `JointProblem` when ``spec["joint"]``) from the JSON-able ``spec``
    stored with every CLI result (so that ``jaxhyst report`` can rebuild it); ``loops``:
    the loops of ``spec["data"]`` if already read."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import fix_structural
    from jaxhyst.io import SIGNAL_OUTPUTS, bounds_from_json, read_loops

    if loops is None:
        loops = read_loops(spec["data"], spec.get("columns"))
    ids = [lp.index for lp in loops]
    bounds = bounds_from_json(spec["bounds"])
    actuator = jh.Actuator(**spec["actuator"])
    variant = variant_from_name(spec.get("variant", "energy"))
    fixed = dict(spec.get("fixed") or {})
    if spec.get("joint"):
        out = _loop_signal(spec, loops[0], spec.get("output"))
        if SIGNAL_OUTPUTS[out] in ("magnetization", "flux_density"):
            fixed = fix_structural(bounds, fixed)
        space = jh.JointSpace(bounds, len(loops), per_loop=spec.get("per_loop") or (),
                              fixed=fixed)
        return jh.JointProblem([lp.signals[out] for lp in loops],
                               [_loop_drive(spec, lp, out, actuator) for lp in loops],
                               actuator, space, output=SIGNAL_OUTPUTS[out], variant=variant,
                               substeps=spec.get("substeps", DEFAULT_SUBSTEPS))
    if spec.get("loop") is None:
        if len(loops) > 1:
            raise CLIError(f"{spec['data']} holds loops {ids}; choose one with --loop, or fit "
                           "them together with --joint.")
        loop = loops[0]
    else:
        if spec["loop"] not in ids:
            raise CLIError(f"--loop {spec['loop']}: {spec['data']} holds loops {ids}.")
        loop = loops[ids.index(spec["loop"])]
    out = _loop_signal(spec, loop, spec.get("output"))
    if SIGNAL_OUTPUTS[out] in ("magnetization", "flux_density"):
        fixed = fix_structural(bounds, fixed)
    space = jh.ParameterSpace(bounds, fixed or None)
    return jh.Problem(loop.signals[out], _loop_drive(spec, loop, out, actuator), actuator,
                      space, output=SIGNAL_OUTPUTS[out], variant=variant,
                      substeps=spec.get("substeps", DEFAULT_SUBSTEPS))


def _warn(args, text: str) -> None:
    print(f"jaxhyst {args.command}: warning: {text}", file=sys.stderr, flush=True)


def _method(args, problem) -> str:
    """--method auto: GATR1 (the paper) for actuator outputs, multi-start LM for M/B."""
    if args.method != "auto":
        return args.method
    return "lm" if problem.output in ("magnetization", "flux_density") else "GATR1"


def _read_start(args):
    """The parameters of an earlier result (--start), or None."""
    from jaxhyst.io import parameters_from_json, read_json

    if not args.start:
        return None
    return parameters_from_json(read_json(args.start), f"parameters in --start {args.start}")


def _start_params(args, p, problem):
    """The parameters ``p`` of --start for ``problem`` (per loop for a joint one)."""
    L = getattr(problem, "n_loops", None)
    if L is not None:  # a joint problem: per-loop leaves
        import jax.numpy as jnp

        p = type(p).from_array(jnp.broadcast_to(jnp.atleast_2d(p.to_array()),
                                                (L, p.to_array().shape[-1])))
    elif p.to_array().ndim != 1:
        raise CLIError(f"--start {args.start}: a joint (per-loop) result cannot start a "
                       "single-loop fit.")
    return p


def _identify(args) -> int:
    import numpy as np

    import jaxhyst as jh
    from jaxhyst._interrupt import stop_requested
    from jaxhyst.io import bounds_to_json, read_loops, write_json

    _check_outputs(args)
    known = _params(args.params) if args.params else None
    given = _bounds(args.bounds)
    actuator = _actuator(args.actuator)
    spec = {"data": os.path.abspath(args.data), "columns": args.columns, "loop": args.loop,
            "output": args.output, "actuator": actuator.to_dict(),
            "fixed": _fixed(args.fix, known),
            "run_in_periods": args.run_in_periods, "substeps": args.substeps,
            "variant": args.variant, "joint": args.joint,
            "per_loop": [n.strip() for n in (args.per_loop or "").split(",") if n.strip()]}
    if spec["per_loop"] and not args.joint:
        raise CLIError("--per-loop needs --joint (several loops fitted together).")
    if args.method in HYBRID and args.start:
        raise CLIError("--start applies to the local solvers (e.g. --method lm); a hybrid GA "
                       "searches the whole box.")
    start = _read_start(args)
    loops = read_loops(spec["data"], spec["columns"])
    bounds, where = _resolve_bounds(spec, given, loops)
    spec["bounds"] = bounds_to_json(bounds)
    problem = build_problem(spec, loops)  # (its warnings: one line each, see main)
    method = _method(args, problem)
    if args.start and method in HYBRID:  # (only with --method auto) a start means a local solve
        method = "lm"
    if method not in HYBRID and (args.checkpoint or args.resume):
        raise CLIError(f"--checkpoint/--resume apply to the hybrid GAs; --method {method} is a "
                       "local solve (not checkpointed: rerun it).")
    if where and args.progress:  # (after every check of the input: errors stay one line)
        print(f"[identify] {where}", file=sys.stderr, flush=True)
    n = problem.space.n_free
    if method in HYBRID:
        settings = jh.GASettings()
        overrides = {k: v for k, v in (("T2", args.generations), ("q1", args.population),
                                       ("T3", args.max_steps)) if v is not None}
        if args.population is not None:
            overrides["q2"] = max(4, args.population // 4)
        settings = jh.GASettings(**{**settings.__dict__, **overrides})
        if args.checkpoint is None and args.resume:
            raise CLIError("--resume needs --checkpoint FILE.")
        result = jh.run_hybrid(problem, method, seed=args.seed, settings=settings,
                               progress=args.progress, checkpoint=args.checkpoint,
                               checkpoint_every=args.checkpoint_every, resume=args.resume)
    elif args.start or args.starts <= 1:  # one start: an earlier result, or the box centre
        start = _start_params(args, start, problem) if args.start else np.full(n, 0.5)
        if args.progress:
            where = f"from {args.start}" if args.start else "at the centre of the box"
            print(f"[{method}] one start {where}", file=sys.stderr, flush=True)
        result = jh.solve(problem, start, solver=method, max_steps=args.max_steps or 200,
                          progress=bool(args.progress))
    else:
        starts = np.random.default_rng(args.seed).uniform(0.0, 1.0, (args.starts, n))
        if args.progress:
            print(f"[{method}] {len(starts)} random starts in one vmapped batch",
                  file=sys.stderr, flush=True)
        result = jh.multistart(problem, starts, solver=method,
                               max_steps=args.max_steps or 200, progress=bool(args.progress))
    if stop_requested() and result.result != "interrupted":  # Ctrl-C during a local solve
        result = result.with_outcome("interrupted")
    d = result.to_dict()
    d["problem"] = {**spec, "data": _portable_path(spec["data"], args.out)}
    if "history" in result.extra:
        d["history"] = result.extra["history"]
    if args.png:
        _identify_figure(args, problem, result, has_t=loops[0].t is not None)
    if args.out:
        write_json(args.out, d)
    text = str(result) + (f"\n  wrote {args.out}" if args.out else "")
    _print(args, d, text)
    for w in result.warnings:
        _warn(args, w)
    return _exit_status(result)


def _portable_path(path: str, out: str | None) -> str:
    """``path`` relative to the directory of the result file ``out`` (so that a result
    moved together with its data still finds them); absolute when on another drive."""
    base = os.path.dirname(os.path.abspath(out)) if out else os.getcwd()
    try:
        return os.path.relpath(path, base)
    except ValueError:
        return path


def _identify_figure(args, problem, result, has_t: bool) -> None:
    import numpy as np

    from jaxhyst.plots import plot_fit, plot_history

    flags = (" — at bound: " + ", ".join(result.at_bound)) if result.at_bound else ""
    if args.joint:
        pred = np.asarray(problem.predict_loops(result.params))
        mask = np.asarray(problem.mask)
        H = np.asarray(problem.drive.H)[:, problem.drive.run_in:]
        plot_fit([H[i][mask[i]] for i in range(problem.n_loops)],
                 [np.asarray(problem.padded)[i][mask[i]] for i in range(problem.n_loops)],
                 [pred[i][mask[i]] for i in range(problem.n_loops)], problem.output, args.png,
                 title=f"{result.solver}: {problem.n_loops} loops fitted jointly{flags}")
        return
    pred = np.asarray(problem.predict(result.params))
    plot_fit(problem.drive.observed(problem.drive.H), problem.data, pred, problem.output,
             args.png, t=problem.drive.observed(problem.drive.t) if has_t else None,
             title=f"{result.solver}: measured and fitted ({os.path.basename(args.data)})"
             + flags)
    # (the history beside the figure; not beside a device or FIFO: /dev/null_history.png)
    if result.extra.get("history") and not writes_in_place(args.png):
        hist_png = str(Path(args.png).with_name(Path(args.png).stem + "_history.png"))
        plot_history(result.extra["history"], problem.space.names, problem.space.lower,
                     problem.space.upper, hist_png, title=result.solver + flags)


EXIT_HELP = ("Exit status: 0 success; 2 bad input (one-line message); 3 the fit stopped "
             "short (step limit reached, non-finite cost or solver failure) or ended far from "
             "its data (a loop's rms error above 20 % of its size, or far above the other "
             "loops'): the result is written and says so; 4 converged with a parameter at a "
             "bound (a constrained optimum: widen the bounds); 130 interrupted "
             "(Ctrl-C/SIGTERM: the best point so far and the checkpoint are written).")


def _exit_status(result) -> int:
    """0 for a converged fit, 130 for an interrupted run, 3 for one that stopped short,
    failed (max steps, non-finite cost, solver failure) or ended far from its data, 4 for
    a converged fit with a parameter at a bound."""
    if result.result == "interrupted":
        return 130
    if not result.success or result.far_from_data:
        return 3
    return 4 if result.at_bound else 0


# -- report -------------------------------------------------------------------------------


def _report(args) -> int:
    from jaxhyst.analysis import identifiability, profile_likelihood
    from jaxhyst.io import parameters_from_json, read_json

    _check_outputs(args)

    saved = read_json(args.result)
    if "problem" not in saved:
        raise CLIError(f"{args.result} is not a jaxhyst identify result (no 'problem' entry).")
    spec = dict(saved["problem"])
    if not os.path.isabs(spec["data"]):  # stored relative to the result file
        spec["data"] = os.path.join(os.path.dirname(os.path.abspath(args.result)),
                                    spec["data"])
    problem = build_problem(spec)
    params = parameters_from_json(saved, f"parameters in {args.result}")
    rep = identifiability(problem, params, max_rel_se=args.max_rel_se)
    summary = {"identifiability": rep.to_dict(), "suggest_fixed": list(rep.suggest_fixed())}
    text = [str(rep), f"  to make the rest identifiable and determined to "
                      f"{100 * rep.max_rel_se:g} %: fix {', '.join(rep.suggest_fixed()) or '—'}"]
    profiles = []
    for name in args.profile or []:
        prof = profile_likelihood(problem, params, name, n=args.profile_points)
        profiles.append(prof.to_dict())
        text.append(str(prof))
    summary["profiles"] = profiles
    if args.png:
        from jaxhyst.plots import plot_identifiability

        plot_identifiability(rep, args.png, title=os.path.basename(args.result))
        text.append(f"  wrote {args.png}")
    _print(args, summary, "\n".join(text))
    return 0


# -- reproduce ----------------------------------------------------------------------------


def _reproduce(args) -> int:
    from jaxhyst.io import atomic_write_text, write_json

    _check_outputs(args, directory="out")
    out = Path(args.out) if args.out else None
    if args.study != "table1":
        return _reproduce_experiment(args, out)
    from jaxhyst.study import METHODS, table1_study

    methods = args.methods.split(",") if args.methods else list(METHODS)
    bad = [m for m in methods if m not in HYBRID]
    if bad:
        raise CLIError(f"--methods {bad}: choose from {list(HYBRID)}.")
    study = table1_study(quick=args.quick, methods=methods, seeds=tuple(args.seeds),
                         progress=not args.json)
    problem = study.pop("problem")
    if out:
        out.mkdir(parents=True, exist_ok=True)
        if args.png:  # figures first: a failure leaves no partial set of files
            from jaxhyst.plots import plot_history

            for r in study["runs"]:
                plot_history(r["history"], problem.space.names, problem.space.lower,
                             problem.space.upper, out / f"{r['method']}_s{r['seed']}.png",
                             title=f"{r['method']}, seed {r['seed']}")
        write_json(out / "table1.json", study)
        atomic_write_text(out / "table1.md", study["markdown"] + "\n")
    summary = {k: v for k, v in study.items() if k != "runs"}
    summary["runs"] = [{k: v for k, v in r.items() if k != "history"} for r in study["runs"]]
    text = study["markdown"] + (f"\n\nwrote {out}/table1.md, table1.json" if out else "")
    _print(args, summary, text)
    return 0


def _reproduce_experiment(args, out) -> int:
    """``reproduce table3`` / ``table2``: GATR1 on noisy synthetic strain of the paper's
    experiments (jaxhyst.study)."""
    import numpy as np

    from jaxhyst.io import atomic_write_text, write_json
    from jaxhyst.study import table2_study, table3_study

    if args.methods:
        raise CLIError(f"--methods: {args.study} is identified by GATR1 only (as in the "
                       "paper); leave --methods out.")
    if args.study == "table3":
        study = table3_study(quick=args.quick, seed=args.seeds[0], progress=not args.json)
    else:
        seeds = tuple(args.seeds) if len(args.seeds) > 1 else (0, 1, 2)
        study = table2_study(quick=args.quick, seeds=seeds, progress=not args.json)
    name = args.study
    figures = []
    if out:
        out.mkdir(parents=True, exist_ok=True)
    if out and args.png:
        from jaxhyst.plots import plot_frequency_response, plot_table3_loops

        if name == "table3":
            import jaxhyst as jh
            from jaxhyst.study import TABLE3_FREQUENCIES

            plot_table3_loops(study["loops"], out / "fig7_loops.png",
                              title="Actuator2, Hb = 16 kA/m, H_AC = 8 kA/m (Table 3 values)")
            p = jh.TABLE3[1000]
            dense = np.logspace(0, 4, 300)
            fm = np.array(TABLE3_FREQUENCIES, dtype=float)
            plot_frequency_response(
                dense, np.asarray(jh.frequency_response(p, jh.ACTUATOR2, dense)),
                out / "fig8_frequency_response.png",
                title="ε/λ of Actuator2 (Table 3, 1000 Hz column), drive frequencies marked",
                marks=(fm, np.asarray(jh.frequency_response(p, jh.ACTUATOR2, fm))))
            figures = ["fig7_loops.png", "fig8_frequency_response.png"]
    if out:
        write_json(out / f"{name}.json", study)
        atomic_write_text(out / f"{name}.md", study["markdown"] + "\n")
    summary = {k: v for k, v in study.items() if k != "loops"}
    wrote = ", ".join([f"{name}.md", f"{name}.json", *figures])
    text = (f"{name}: GATR1 on synthetic strain with noise σ = {study['noise']:g}·max|ε| "
            f"(✗: the truth outside the 95 % interval)\n\n" + study["markdown"]
            + (f"\n\nwrote {out}/: {wrote}" if out else ""))
    _print(args, summary, text)
    return 0


# -- frequency-response -------------------------------------------------------------------


def _frequency_response(args) -> int:
    import numpy as np

    import jaxhyst as jh

    _check_outputs(args)

    params = _params(args.params)
    actuator = _actuator(args.actuator)
    if args.frequencies:
        try:
            f = np.array([float(x) for x in args.frequencies.split(",")])
        except ValueError:
            raise CLIError("--frequencies must be comma-separated numbers (Hz).") from None
    else:
        if not (0 < args.fmin < args.fmax):
            raise CLIError("need 0 < --fmin < --fmax (Hz).")
        f = np.geomspace(args.fmin, args.fmax, args.points)
    if np.any(~np.isfinite(f)) or np.any(f <= 0):
        raise CLIError("frequencies must be finite and > 0 Hz.")
    G = np.asarray(jh.frequency_response(params, actuator, f))
    rows = [{"frequency_Hz": float(fi), "magnitude": float(abs(g)),
             "phase_lag_deg": float(-np.degrees(np.angle(g)))} for fi, g in zip(f, G, strict=True)]
    if args.png:
        from jaxhyst.plots import plot_frequency_response

        lo, hi = (f.min() / 2, f.max() * 2) if args.frequencies else (f.min(), f.max())
        dense = np.geomspace(lo, hi, 400)
        plot_frequency_response(dense, np.asarray(jh.frequency_response(params, actuator,
                                                                        dense)),
                                args.png, title=f"{actuator.name}, eq 13",
                                marks=(f, G) if args.frequencies else None)
    wn = float(np.sqrt(params.Kz / params.Mz) / (2 * np.pi))
    text = [f"natural frequency fn = {wn:.1f} Hz, ε/λ at 0 Hz = "
            f"{actuator.Ar * params.E / actuator.lr / params.Kz:.4g}",
            f"{'f (Hz)':>12} {'|ε/λ|':>12} {'lag (°)':>10}"]
    text += [f"{r['frequency_Hz']:>12.5g} {r['magnitude']:>12.5g} {r['phase_lag_deg']:>10.3f}"
             for r in rows]
    _print(args, {"natural_frequency_Hz": wn, "response": rows}, "\n".join(text))
    return 0


# -- parser -------------------------------------------------------------------------------


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="jaxhyst",
        description="Jiles–Atherton hysteresis of magnetostrictive actuators: simulate, "
        "identify parameters from measured loops, report what the data determine. "
        + UNITS_HELP,
        epilog=EXIT_HELP,
    )
    sub = parser.add_subparsers(dest="command", required=True)

    sim = sub.add_parser(
        "simulate", help="simulate an actuator and write its loop (CSV, PNG)",
        description="Simulate an actuator. The drive is a current I = offset + amplitude·"
        "sin(2πft) (A) by default, a field with --field-amplitude (A/m), or a measured "
        "record with --drive FILE (columns t and H or I). Starts demagnetized, ramps to the "
        "drive, discards one run-in period. " + UNITS_HELP)  # fmt: skip
    sim.add_argument("--preset", choices=("table1",), default="table1",
                     help="parameters when --params is not given")
    sim.add_argument("--params", help="table1, table3:<Hz> or a JSON file {name: value} "
                     "(a result JSON also works)")
    sim.add_argument("--actuator", default="actuator1",
                     help="actuator1, actuator2 or a JSON file {Ar, lr, n, Hb}")
    sim.add_argument("--frequency", type=POSITIVE, default=100.0, help="drive frequency, Hz")
    sim.add_argument("--amplitude", type=FINITE, default=0.77, help="current amplitude, A")
    sim.add_argument("--offset", type=FINITE, default=1.53, help="current offset (bias), A")
    sim.add_argument("--field-amplitude", type=FINITE, help="field amplitude, A/m (instead "
                     "of a current)")
    sim.add_argument("--field-offset", type=FINITE, default=0.0, help="field offset, A/m")
    sim.add_argument("--drive", help="CSV/TSV with t and H (or I) columns")
    sim.add_argument("--columns", help="column names for a file without a header")
    sim.add_argument("--periods", type=POSITIVE, default=1.0, help="observed periods")
    sim.add_argument("--samples-per-period", type=POSITIVE_INT, default=200,
                     help="samples per drive period")
    sim.add_argument("--substeps", type=POSITIVE_INT, default=DEFAULT_SUBSTEPS,
                     help="RK4 substeps per sample")
    sim.add_argument("--variant", choices=VARIANTS, default="energy",
                     help="Jiles–Atherton form (energy: the paper's)")
    sim.add_argument("--csv", help="write the signals here (SI units in the header)")
    sim.add_argument("--png", help="write a figure here (needs matplotlib)")
    sim.add_argument("--json", action="store_true", help="print a JSON summary")
    sim.set_defaults(func=_simulate)

    ide = sub.add_parser(
        "identify", help="identify parameters from a measured loop",
        description="Identify the free parameters from a data file (CSV/TSV; columns t, H "
        "or I, and the observed signal y, strain, lambda, M or B; a 'loop' column separates "
        "loops; units in the header as 'y [um]' or 'y_um'). " + UNITS_HELP,
        epilog=EXIT_HELP)  # fmt: skip
    ide.add_argument("data", help="data file")
    ide.add_argument("--output", choices=("y", "strain", "lambda", "M", "B"),
                     help="observed column (needed when the file has several)")
    ide.add_argument("--loop", type=COUNT, help="which loop of a multi-loop file")
    ide.add_argument("--joint", action="store_true", help="fit all loops of the file as one "
                     "problem (parameters shared unless listed in --per-loop)")
    ide.add_argument("--per-loop", help="with --joint: parameters free per loop, e.g. "
                     "'a,k,c'")
    ide.add_argument("--variant", choices=VARIANTS, default="energy",
                     help="Jiles–Atherton form (energy: the paper's)")
    ide.add_argument("--columns", help="column names for a file without a header, "
                     "e.g. 't,H,y [um]'")
    ide.add_argument("--actuator", default="actuator1",
                     help="actuator1, actuator2 or a JSON file {Ar, lr, n, Hb}")
    ide.add_argument("--bounds", help="search box: table1, or a JSON file {name: [lower, "
                     "upper]} (SI) naming only the parameters it changes. Default: for M or "
                     "B data a box derived from the loops (field and magnetization "
                     "amplitudes, coercive field; printed), else the paper's Table 1 box")
    ide.add_argument("--fix", action="append", help="hold parameters fixed: 'Ms=7.65e5' or "
                     "'Ms,lambda_s' with --params; repeatable")
    ide.add_argument("--params", help="known values for --fix without a value")
    ide.add_argument("--method", default="auto", choices=("auto",) + HYBRID + LOCAL,
                     help="a hybrid GA (paper §3.4) or a local solver (multi-start); auto: "
                     "GATR1 for y/strain/lambda data, lm for M or B loops")
    ide.add_argument("--start", help="local solvers: start from the parameters of an "
                     "earlier result JSON (identify --out)")
    ide.add_argument("--starts", type=POSITIVE_INT, default=8, help="local solvers: random starts, "
                     "solved in one vmapped batch (1: one start at the centre of the box)")
    ide.add_argument("--max-steps", type=POSITIVE_INT, help="local solver iterations (hybrids: T3)")
    ide.add_argument("--generations", type=POSITIVE_INT, help="hybrids: FCGA generations T2 "
                     "(paper 295)")
    ide.add_argument("--population", type=POSITIVE_INT, help="hybrids: BCGA population q1 (paper "
                     "120; q2 = q1/4)")
    ide.add_argument("--seed", type=COUNT, default=0,
                     help="random seed (integer >= 0): GA, random starts")
    ide.add_argument("--checkpoint", help="hybrids: checkpoint file (.npz), written "
                     "atomically every --checkpoint-every generations and on Ctrl-C")
    ide.add_argument("--checkpoint-every", type=POSITIVE_INT, default=10,
                     help="hybrids: generations between checkpoints")
    ide.add_argument("--resume", action="store_true", help="continue from --checkpoint")
    ide.add_argument("--run-in-periods", type=COUNT, default=1,
                     help="copies of the record simulated before it (transient)")
    ide.add_argument("--substeps", type=POSITIVE_INT, default=DEFAULT_SUBSTEPS,
                     help="RK4 substeps per sample (a warning says when the record is too "
                     "coarse for it)")
    ide.add_argument("--progress", type=COUNT, default=10,
                     help="progress on stderr: a line every N generations of a hybrid, every "
                     "2 s of a local solve (0: quiet)")
    ide.add_argument("--out", help="write the result (JSON, names and units) here")
    ide.add_argument("--png", help="measured vs fitted loop with the error (and, for "
                     "hybrids, <name>_history.png)")
    ide.add_argument("--json", action="store_true", help="print the result as JSON")
    ide.set_defaults(func=_identify)

    rep = sub.add_parser(
        "report", help="identifiability of an identify result",
        description="Singular values, null directions, standard errors, identifiable "
        "combinations and (optionally) profile likelihoods of a result written by "
        "'jaxhyst identify --out'.")  # fmt: skip
    rep.add_argument("result", help="result JSON from identify --out")
    rep.add_argument("--profile", action="append", help="profile likelihood of this "
                     "parameter (repeatable)")
    rep.add_argument("--profile-points", type=POSITIVE_INT, default=21,
                     help="grid points of each profile")
    rep.add_argument("--max-rel-se", type=POSITIVE, default=0.5,
                     help="relative standard error above which a parameter is poorly "
                     "determined")
    rep.add_argument("--png", help="singular values and correlation matrix figure")
    rep.add_argument("--json", action="store_true",
                    help="print the result as one JSON object on stdout")
    rep.set_defaults(func=_report)

    rp = sub.add_parser("reproduce", help="reproduce a study of the paper",
                        description="Reproduce a study of the paper: table1, the simulation "
                        "study with the four hybrids (GATR1, GALM1, GATR2, GALM2); table3, "
                        "Actuator2 at 10-2000 Hz identified by GATR1 from noisy synthetic "
                        "strain (Figs 7, 8 with --png); table2, the quasi-static Actuator1 "
                        "identified three times by GATR1. Progress on stderr.")
    rp.add_argument("study", choices=("table1", "table2", "table3"),
                    help="which study: table1, table2 or table3")
    rp.add_argument("--quick", action="store_true", help="small GA, coarse record (a few "
                    "minutes on 2 cores, mostly compiling)")
    rp.add_argument("--seeds", type=COUNT, nargs="+", default=[0],
                    help="GA seeds (integers >= 0), one run per method and seed")
    rp.add_argument("--methods", help="comma-separated subset of the hybrids")
    rp.add_argument("--out", help="directory for <study>.md, <study>.json (and figures)")
    rp.add_argument("--png", action="store_true", help="with --out: figures (table1: GA "
                    "histories; table3: Figs 7 and 8)")
    rp.add_argument("--json", action="store_true",
                    help="print the result as one JSON object on stdout")
    rp.set_defaults(func=_reproduce)

    fr = sub.add_parser("frequency-response", help="structural response ε/λ (eq 13)",
                        description="Magnitude and phase lag of G(jω) = (Ar·E/lr)/(Mz(jω)² + "
                        "Cz·jω + Kz). " + UNITS_HELP)
    fr.add_argument("--params", default="table1", help="table1, table3:<Hz> or a JSON file")
    fr.add_argument("--actuator", default="actuator1",
                    help="actuator1, actuator2 or a JSON file {Ar, lr, n, Hb}")
    fr.add_argument("--frequencies", help="comma-separated, Hz")
    fr.add_argument("--fmin", type=POSITIVE, default=1.0, help="lowest frequency, Hz")
    fr.add_argument("--fmax", type=POSITIVE, default=1e4, help="highest frequency, Hz")
    fr.add_argument("--points", type=POSITIVE_INT, default=25,
                    help="log-spaced frequencies between --fmin and --fmax")
    fr.add_argument("--png", help="magnitude and phase figure (Fig 8)")
    fr.add_argument("--json", action="store_true",
                    help="print the result as one JSON object on stdout")
    fr.set_defaults(func=_frequency_response)
    return parser


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as done:  # --help, or a usage error already reported in one line
        return done.code if isinstance(done.code, int) else 2
    import warnings

    from jaxhyst import enable_compilation_cache
    from jaxhyst._interrupt import run_interruptibly

    def one_line(message, category, filename, lineno, file=None, line=None):
        print(f"jaxhyst {args.command}: warning: {' '.join(str(message).split())}",
              file=sys.stderr, flush=True)

    shown = warnings.showwarning
    warnings.showwarning = one_line  # Python warnings (coarse sampling …) as one line
    enable_compilation_cache()  # a second run loads its compiled programs from disk
    try:
        # the work runs in a worker thread: Ctrl-C is honoured even while XLA compiles
        return run_interruptibly(args.func, args)
    except KeyboardInterrupt:
        print(f"jaxhyst {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`: not an error of the input
        sys.stderr.close()
        return 0
    except (ValueError, TypeError, ImportError, OSError, FloatingPointError) as err:
        msg = " ".join(str(err).split())  # one line
        print(f"jaxhyst {args.command}: error: {msg}", file=sys.stderr)
        return 2
    finally:
        warnings.showwarning = shown


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
