"""The nearest-condition baseline of a leave-one-out comparison (`jaxhyst.cli.heldout`):
its row of the table — each held-out loop predicted by the own fit of the nearest other
loop (`jaxhyst.condition_distance`) — the choice between it and the forms, and the final
fit where it is kept: every loop's own fit, a new loop predicted by the nearest fitted
loop's (`jaxhyst.NearestCondition`)."""

from __future__ import annotations

from .candidates import candidate_spec

#: The name of the nearest-condition baseline in a comparison's table (and as the kept
#: candidate: each loop's own fit, a loop predicted by the nearest fitted loop's).
NEAREST = "nearest"


def choose(table: dict, conditions, comparison: bool) -> tuple[str | None, str | None]:
    """(the kept candidate, the candidate whose single fits the baseline uses) of a
    comparison's ``table`` ({candidate: {rows, score, complete, nearest_score}}), with
    the nearest-condition baseline's entry added to it as `NEAREST` (`_baseline`): the
    lowest score wins; the baseline is among the candidates only in a ``comparison``
    (several forms) — one form named is fitted as named, the baseline shown beside it."""
    base, source = _baseline(table, conditions)
    scored = {f: t["score"] for f, t in table.items() if t["score"] is not None}
    if base is not None:
        table[NEAREST] = base
        if comparison:
            scored[NEAREST] = base["score"]
    return (min(scored, key=scored.get) if scored else None), source


def _baseline(table, conditions) -> tuple[dict | None, str | None]:
    """(the nearest-condition baseline's entry of the comparison's table, the candidate
    whose single fits it uses): the complete candidate whose loops' own fits predict
    the held-out loops best as the nearest other loop's (the entry's ``form``: that
    candidate's form and loss coefficients, without a law — the single fits carry
    none), one row per held-out loop, the loops' ``conditions``; (None, None) where no
    candidate's folds are complete."""
    scored = [(t["nearest_score"], f) for f, t in table.items()
              if t["complete"] and t.get("nearest_score") is not None]
    if not scored:
        return None, None
    score, form = min(scored)
    rows = [{"loop": r["loop"], "rms": r["nearest_rms"], "data_scale": r["data_scale"],
             "nearest_loop": r["nearest_loop"], "outcome": r["nearest_outcome"],
             "outside": r["outside"], "beyond": r["beyond"]}
            for r in table[form]["rows"]]
    return {"rows": rows, "score": score, "complete": True, "nearest_score": None,
            "form": form.partition("@")[0], "conditions": conditions}, form


def nearest_fit(args, spec, given, loops, held: dict, own):
    """The final fit where the comparison kept the nearest-condition baseline: every loop
    its own parameter set (a joint problem with each free parameter per loop, ``spec``'s
    ``predict_by`` "nearest" and the loops' conditions), in a box that holds the derived
    one and each loop's own fit's (widened where that fit ended on a bound), polished by
    one LM solve from the loops' own fits ``own`` ([(result, problem, spec)]): (spec,
    problem, result)."""
    import jax
    import numpy as np

    from jaxhyst.io import bounds_to_json

    from .fitting import refine_from
    from .problems import build_problem, resolve_bounds

    base = held["forms"][NEAREST]
    spec = {**spec, **candidate_spec(args, base["form"]), "vary": None,
            "predict_by": "nearest", "nearest_conditions": base["conditions"]}
    bounds, extra, _ = resolve_bounds(spec, given, loops)
    box = bounds_to_json(bounds)
    extra = {n: list(v) for n, v in extra.items()}
    for _, _, fitted in own:
        for mine, theirs in ((box, fitted["bounds"]), (extra, fitted["extra_bounds"])):
            for n, (lo, hi) in theirs.items():
                a, b = mine.get(n, (lo, hi))
                mine[n] = [min(a, lo), max(b, hi)]
    spec["bounds"], spec["extra_bounds"] = box, extra
    problem = build_problem(spec, loops)
    start = jax.tree.map(lambda *x: np.asarray([np.ravel(v)[0] for v in x]),
                         *[result.params for result, _, _ in own])
    result = refine_from(args, problem, start, what="from each loop's own fit")
    return spec, problem, result
