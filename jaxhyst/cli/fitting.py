"""The fits ``jaxhyst identify`` makes: the one its options ask for (`fit_by_options`) and
the refits after it — the data-derived box widened where the fit ended on it
(`widen_derived_box`), long loops fitted on every k-th sample first (`decimated_first`).
The leave-one-out folds are `jaxhyst.cli.heldout`'s."""

from __future__ import annotations

from .options import HYBRID
from .problems import build_problem
from .spec import CLIError, note

#: Widenings of the data-derived box a fit may ask for, and the factor of each.
WIDENINGS, WIDEN = 3, 5.0


def widen_derived_box(args, spec, given, loops, problem, result, method: str = "lm",
                      quiet: bool = False, batch: bool = True):
    """A box derived from the data is no constraint of the data: where a fit ends on one
    of its bounds (not one the user gave, not a physical limit, not a condition law's
    coefficient), widen that bound `WIDEN`-fold (within the physical range) and refit from
    the result (`refit_from`: the fit's own batch of starts, so that nothing new
    compiles; ``batch=False``: one LM solve), up to `WIDENINGS` times. The loss
    coefficients' and a form's own parameters' boxes (``spec["extra_bounds"]``) likewise,
    and a condition model's reference values (a law's fold too). Returns the last
    (result, problem)."""
    import numpy as np

    from jaxhyst.io import bounds_from_json, bounds_to_json
    from jaxhyst.names import base_name
    from jaxhyst.params import PHYSICAL_RULES, at_physical_limit

    extra_rules = {"eddy": lambda v: v >= 0, "excess": lambda v: v >= 0, "lag": lambda v: v >= 0,
                   "relax": lambda v: v >= 0,
                   "spread": lambda v: (v >= 0) & (v <= 10),
                   "a_rev": lambda v: (v >= 1e-6) & (v <= 1e9)}
    for _ in range(WIDENINGS):
        if result.result == "interrupted":
            break
        box = {**bounds_to_json(bounds_from_json(spec["bounds"])),
               **{n: list(v) for n, v in (spec.get("extra_bounds") or {}).items()}}
        widened, done = [], set()
        for name, (side, bound) in result.at_bound.items():
            base = base_name(name)  # (a law's coefficient, 'k:log_f', has no box here)
            if ":" in name or base in (given or {}) or at_physical_limit(base, bound) or \
                    base not in box or (base, side) in done:
                continue
            done.add((base, side))  # (per-loop entries of one parameter: widened once)
            lo, hi = box[base]
            if side == "upper":
                new = hi * WIDEN if lo > 0 else hi + (WIDEN - 1) * (hi - lo)
            else:
                new = lo / WIDEN if lo > 0 else lo - (WIDEN - 1) * (hi - lo)
            ok = PHYSICAL_RULES.get(base, (extra_rules.get(base, np.isfinite), ""))[0]
            while not ok(np.float64(new)) and abs(new - bound) > 1e-12 * abs(bound):
                new = 0.5 * (new + bound)  # (back inside the physical range)
            if abs(new - bound) <= 1e-9 * max(abs(bound), 1e-300):
                continue
            box[base] = [new, hi] if side == "lower" else [lo, new]
            widened.append(f"{base} {side} {bound:.4g} → {new:.4g}")
        if not widened:
            break
        if args.progress and not quiet:
            note("identify", "the fit ended on the data-derived box (no constraint of the "
                             "data): widening " + ", ".join(widened) + " and refitting")
        extra = spec.get("extra_bounds") or {}
        spec["bounds"] = {n: v for n, v in box.items() if n not in extra}
        spec["extra_bounds"] = {n: box[n] for n in extra}
        problem = build_problem(spec, loops)
        result = (refit_from(args, problem, result.params, method, quiet=quiet) if batch
                  else refine_from(args, problem, result.params, quiet=quiet))
    return result, problem


def _start_params(args, p, problem):
    """The parameters ``p`` of --start for ``problem`` (per loop for a joint one)."""
    import jax.numpy as jnp

    from jaxhyst.identify import JointProblem
    from jaxhyst.model.paths import split_parameters

    p, losses, _ = split_parameters(p)  # (a form's own parameters: from the box)

    if isinstance(problem, JointProblem):  # per-loop leaves
        L = problem.n_loops
        p = type(p).from_array(jnp.broadcast_to(jnp.atleast_2d(p.to_array()),
                                                (L, p.to_array().shape[-1])))
    elif p.to_array().ndim != 1:
        raise CLIError(f"--start {args.start}: a joint (per-loop) result cannot start a "
                       "single-loop fit.")
    return _with_the_rest(p, losses, problem)


def _with_the_rest(p, losses, problem):
    """The start ``p`` (`Parameters`, and ``losses`` where the start file has them) as
    the problem's whole parameter pytree: loss coefficients it does not give and the
    form's own parameters at the centre of their box."""
    import numpy as np

    from jaxhyst.model.losses import Losses

    centre = problem.space.params_from_u(np.full(problem.space.n_free, 0.5))
    if not isinstance(centre, tuple):
        return p
    rest = [losses if isinstance(m, Losses) and losses is not None
            and np.ndim(m.eddy) == np.ndim(losses.eddy) else m for m in centre[1:]]
    return (p, *rest)


def _report(args, quiet: bool):
    """The identifiability report a fit of the command line gets: none for a quiet
    (leave-one-out) fit, else profile-checked intervals unless ``--intervals linear``."""
    if quiet:
        return False
    return "profile" if getattr(args, "intervals", "profile") == "profile" else True


def check_hybrid_options(args) -> None:
    """The hybrid GAs' options (``--population``, ``--generations``, ``--start``), refused
    in one line with the other option checks (`jaxhyst.cli.identify.check_options`)."""
    if args.method not in HYBRID:
        return
    if args.population is not None and args.population < 4:
        raise CLIError(f"--population {args.population}: a hybrid's population needs at "
                       "least 4 members (its second stage keeps max(4, population/4) and "
                       "two elites); give 4 or more (the paper: 120).")
    if args.generations is not None:  # (in all: the binary-coded T1 first)
        from jaxhyst.identify import hybrid_method

        T1 = int(hybrid_method(args.method).T1)
        if args.generations <= T1:
            raise CLIError(f"--generations {args.generations}: a hybrid runs {T1} "
                           "binary-coded generations first; give more than that (the "
                           "generations in all).")
    if args.start:
        raise CLIError("--start applies to the local solvers (e.g. --method lm); a hybrid GA "
                       "searches the whole box.")


def fit_by_options(args, problem, method, start, quiet: bool = False, seeds=()):
    """The fit the options ask for: a hybrid, one local solve, or a multi-start batch —
    whose first starts are ``seeds`` (parameters of earlier fits, projected into the box;
    at least one start stays random)."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.progress import TextProgressMeter

    progress = 0 if quiet else args.progress
    n = problem.space.n_free
    if method in HYBRID:
        settings = {k: v for k, v in (("q1", args.population), ("T3", args.max_steps))
                    if v is not None}
        if args.generations is not None:  # in all: the binary-coded T1 first (checked
            from jaxhyst.identify import hybrid_method  # by identify.check_options)

            settings["T2"] = args.generations - int(hybrid_method(method).T1)
        if args.population is not None:
            settings["q2"] = max(4, args.population // 4)
        if args.checkpoint is None and args.resume:
            raise CLIError("--resume needs --checkpoint FILE.")
        meter = TextProgressMeter(every=progress) if progress else False
        return jh.run_hybrid(problem, method, seed=args.seed, settings=settings,
                             progress=meter, checkpoint=None if quiet else args.checkpoint,
                             checkpoint_every=args.checkpoint_every,
                             resume=args.resume and not quiet,
                             report=_report(args, quiet))
    meter = TextProgressMeter(every=0, interval=2.0) if progress else False
    if args.start or args.starts <= 1:  # one start: an earlier result, or the box centre
        start = _start_params(args, start, problem) if args.start else np.full(n, 0.5)
        if progress:
            note(method, "one start " + (f"from {args.start}" if args.start
                                         else "at the centre of the box"))
        return jh.solve(problem, start, solver=method, max_steps=args.max_steps or 200,
                        progress=meter, report=_report(args, quiet))
    starts = np.random.default_rng(args.seed).uniform(0.0, 1.0, (args.starts, n))
    for k, params in enumerate(list(seeds)[:args.starts - 1]):
        starts[k] = np.asarray(problem.space.u_from_params(params))
    return _batch(args, problem, method, starts, quiet,
                  f"{len(starts)} random starts in one vmapped batch")


def _batch(args, problem, method, starts, quiet: bool, what: str):
    """The multi-start fit of ``starts`` (box coordinates, one row each) that the options
    ask for, said as ``what`` where progress is shown."""
    import jaxhyst as jh
    from jaxhyst.progress import TextProgressMeter

    progress = 0 if quiet else args.progress
    if progress:
        note(method, what)
    meter = TextProgressMeter(every=0, interval=2.0) if progress else False
    return jh.multistart(problem, starts, solver=method, max_steps=args.max_steps or 200,
                         progress=meter, report=_report(args, quiet))


def refit_from(args, problem, params, method: str, quiet: bool = False):
    """``problem`` fitted again from ``params`` (which another fit reached) by the batch
    the options' fit used — ``params`` as its first start, the rest random in the box —
    so that the program compiled for that fit serves (the box is data); a hybrid or a
    single start: one LM solve (`refine_from`)."""
    import numpy as np

    if method in HYBRID or args.start or args.starts <= 1:
        return refine_from(args, problem, params, quiet=quiet)
    u = np.asarray(problem.space.u_from_params(params))
    rest = np.random.default_rng(args.seed + 1).uniform(0.0, 1.0,
                                                      (args.starts - 1, u.shape[-1]))
    return _batch(args, problem, method, np.vstack([u[None], rest]), quiet,
                  f"{args.starts} starts in one batch: the previous fit and "
                  f"{args.starts - 1} random")


def refine_from(args, problem, params, what: str = "from the previous fit",
                quiet: bool = False):
    """One LM solve of ``problem`` from ``params`` (a fit's result)."""
    import jaxhyst as jh
    from jaxhyst.progress import TextProgressMeter

    if args.progress and not quiet:
        note("lm", f"one start {what}")
    meter = TextProgressMeter(every=0, interval=2.0) if args.progress and not quiet else \
        False
    return jh.solve(problem, params, solver="lm", max_steps=args.max_steps or 200,
                    progress=meter, report=_report(args, quiet))


def thinned(loops, k: int) -> list:
    """Every k-th sample of each loop (its times, drive and signals; conditions kept)."""
    import dataclasses

    if k <= 1:
        return list(loops)
    return [dataclasses.replace(
        lp, t=None if lp.t is None else lp.t[::k], H=None if lp.H is None else lp.H[::k],
        I=None if lp.I is None else lp.I[::k],
        signals={q: a[::k] for q, a in lp.signals.items()}) for lp in loops]


#: Observed samples per loop above which a multi-start local fit first runs on every
#: k-th sample (rate-independent M or B loops) and is then polished on all of them.
DECIMATE_ABOVE = 4000
DECIMATED = 2000


def decimated_first(args, spec, loops, problem, method):
    """For long M or B loops (more than `DECIMATE_ABOVE` samples in a loop) and a
    multi-start local fit: the starts on every k-th sample (at most `DECIMATED` per loop;
    the loop's shape is what the parameters are fitted to, and the starts' work grows
    with the samples), then one LM solve on all samples from the best — so that the
    cost grows linearly with the data. None where it does not apply."""
    from jaxhyst.identify.outputs import OUTPUTS as OUTPUT_NAMES
    from jaxhyst.identify.outputs import output_kind

    longest = max(lp.n_samples for lp in loops)
    if (longest <= DECIMATE_ABOVE or method in HYBRID or args.start or args.starts <= 1
            or problem.output not in OUTPUT_NAMES
            or not output_kind(problem.output).magnetic_only):
        return None
    k = -(-longest // DECIMATED)
    thin = thinned(loops, k)
    if args.progress:
        note("identify", f"{longest} samples in a loop: the starts on every {k}th sample, "
                         "then one solve on all of them")
    coarse = fit_by_options(args, build_problem(spec, thin), method, None)
    return refine_from(args, problem, coarse.params, "from the best on the thinned loops")
