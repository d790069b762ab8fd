"""Leave one loop out (``identify --joint --leave-one-out``): each loop predicted from a
fit of the others, for one form or a comparison of forms, beside the baselines a skeptic
would use — the loop's own fit and the nearest measured condition's fit.

**Fair folds.** A fold sees only its training loops: its box is derived from them alone
(where the box is derived from the data at all) and widened as a single fit's is where
the fit ends on it; the held-out loop enters only when it is predicted.

**The comparison.** For each form: every loop fitted alone (its own-fit error, and the
fits the nearest-condition baseline uses) and every fold. A form's score is the
geometric mean over the folds of the held-out rms error relative to the loop's size; the
form with the lowest score predicts held-out loops best and is kept for the final fit.
The **nearest-condition baseline** is scored alike (each held-out loop predicted by the
own fit of the nearest other loop, `jaxhyst.condition_distance`: the best-scoring form's
single fits) and, in a comparison of several forms, kept where it scores lowest: the
final fit is then every loop's own fit (`jaxhyst.NearestCondition`), and a new loop is
predicted by the nearest fitted loop's.
"""

from __future__ import annotations

import math

from .candidates import candidate_spec, singles_key
from .nearest import NEAREST, choose
from .spec import note

#: Observed samples per loop at most in the comparison's fits (each loop alone, each
#: fold: 2·L fits per candidate): a longer loop is fitted on every k-th sample, and every
#: error — held out, own fit, nearest loop's — is measured on all its samples. The final
#: fit uses all of them.
FOLD_SAMPLES = 500


def _beyond(conditions, i) -> dict:
    """{condition: how far loop i lies beyond the range of the other loops'} for each
    condition (amplitude, frequency, temperature) where it does: predicting it is an
    extrapolation (a factor; kelvin for the temperature, `predictions.beyond`)."""
    from .predictions import beyond

    others = [c for j, c in enumerate(conditions) if j != i]
    out = {}
    for name in ("amplitude", "frequency", "temperature"):
        values = [c[name] for c in others if c[name] is not None]
        v = conditions[i][name]
        if v is not None and values and not min(values) <= v <= max(values):
            out[name] = beyond(v, min(values), max(values), name)
    return out


def _conditions(spec, loops):
    """Each loop's {amplitude, frequency, temperature} (the nearest baseline's metric) and
    its index in the file (``loop``)."""
    import jaxhyst as jh

    from .problems import loop_conditions

    c = loop_conditions(spec, loops, jh.Actuator(**spec["actuator"]))
    return [{"amplitude": c.amplitude[i],
             "frequency": None if c.frequency is None else c.frequency[i],
             "temperature": None if c.temperature is None else c.temperature[i],
             "loop": loops[i].index} for i in range(len(loops))]


def comparison_shape(spec, loops) -> list | None:
    """[run-in, observed samples] of the file's longest loops: every problem of a
    comparison (each loop alone, each fold) is padded to it, so that one program serves
    them all however unequal the loops' lengths (driven by B: of the loops' B(t))."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import common_shape

    from .predictions import flux_drive
    from .spec import loop_drive, loop_signal

    if spec.get("driven_by") == "B":
        return list(common_shape([flux_drive(spec, lp, None) for lp in loops]))
    actuator = jh.Actuator(**spec["actuator"])
    return list(common_shape([loop_drive(spec, lp, loop_signal(spec, lp, spec.get("output")),
                                         actuator) for lp in loops]))


def _fit(args, spec, given, loops, method, seeds=()):
    """A fit of ``loops`` as ``spec`` says, its box from these loops alone (widened
    where the fit ends on a derived bound), its first starts ``seeds`` (parameters):
    (result, problem, spec as fitted)."""
    from jaxhyst.io import bounds_to_json

    from .fitting import fit_by_options, widen_derived_box
    from .problems import build_problem, resolve_bounds

    spec = dict(spec)
    bounds, extra, where = resolve_bounds(spec, given, loops)
    spec["bounds"] = bounds_to_json(bounds)
    spec["extra_bounds"] = {n: list(v) for n, v in extra.items()}
    problem = build_problem(spec, loops)
    result = fit_by_options(args, problem, method, None, quiet=True, seeds=seeds)
    if where and where.startswith("bounds derived"):
        result, problem = widen_derived_box(args, spec, given, loops, problem, result,
                                            method, quiet=True)
    return result, problem, spec


def _own_best(args, own, loops, method, label: str):
    """Each loop's own fit as its best fit: where another loop's own fit predicts the loop
    better than the loop's own (its search stopped in a higher valley), the loop is
    fitted again from that one — with the same number of starts, the rest random, so
    that nothing new compiles — and the better fit kept. ``own``: [(result, problem,
    spec)] per loop, in the order of ``loops``, of the candidate ``label``; returns it,
    improved, and for each loop the index of the loop whose fit its kept fit started
    from (None: its own)."""
    import numpy as np

    out, sources = list(own), [None] * len(own)
    for i, (result, _, _) in enumerate(own):
        tries = [(_predict(spec_j, problem_j, result_j.params, loops[i])["rms"], j)
                 for j, (result_j, problem_j, spec_j) in enumerate(own) if j != i]
        rms, j = min(tries, default=(np.inf, None))
        if rms < result.rms_error * (1.0 - 1e-3):
            out[i] = _again(args, out[i], own[j][0].params, method,
                            f"from loop {loops[j].index}'s fit", rms,
                            f"{label}: loop {loops[i].index}")
            sources[i] = j if out[i] is not own[i] else None
    return out, sources


def _again(args, fit, params, method, source: str, rms: float, what: str):
    """``fit`` = (result, problem, spec) of one loop alone, fitted again from ``params``
    (which predict the loop at ``rms``, better than the fit) — with the same number of
    starts, the rest random, so that nothing new compiles; the better of the two.
    ``what``: the candidate and the loop, for the note."""
    import jax
    import numpy as np

    from .fitting import refit_from

    result, problem, spec = fit
    note("leave-one-out", f"{what} alone again, {source} (it "
         f"predicts the loop better: {rms:.4g} against {result.rms_error:.4g})")
    params = jax.tree.map(lambda x: x[0] if np.ndim(x) else x, params)  # (shared values)
    again = refit_from(args, problem, params, method, quiet=True)
    return (again, problem, spec) if again.rms_error < result.rms_error else fit


def _continued(args, fit, method, what: str):
    """``fit`` = (result, problem, spec) of one loop alone or a fold (``what`` it is, for
    the note); where it stopped at its step limit, fitted once more from where
    it stopped (the same batch: nothing compiles) and the better kept — an own fit cut
    short flatters every ratio to it, a fold's held-out error is not final."""
    import jax
    import numpy as np

    from .fitting import refit_from

    result, problem, spec = fit
    if result.result != "max_steps_reached":
        return fit
    note("leave-one-out", f"{what} stopped at its step limit: once more "
         "from there")
    params = jax.tree.map(lambda x: x[0] if np.ndim(x) else x, result.params)
    again = refit_from(args, problem, params, method, quiet=True)
    return (again, problem, spec) if again.cost <= result.cost else fit


def _unseen(own, alone, seen, i, j):
    """Loop j's best fit that loop i did not shape: its own fit (``own[j]``, perhaps
    re-fitted from another loop's or a fold's fit) where loop i is not among the loops
    whose data led to it (``seen[j]``), else its fit from its own data alone."""
    return own[j][0] if j < len(own) and i not in seen[j] else alone[j]


def _fitted_data(spec, loop):
    """The samples a fit of ``loop`` fits: its signal, or its field H where the fit is
    driven by B."""
    from .spec import loop_signal

    if spec.get("driven_by") == "B":
        return loop.H
    return loop.signals[loop_signal(spec, loop, spec.get("output"))]


def _data_scale(spec, loop) -> float:
    """max |data| of what a fit of ``loop`` fits (its size, for relative errors)."""
    import numpy as np

    return float(np.max(np.abs(_fitted_data(spec, loop))))


def _predict(spec, problem, params, loop):
    """(rms, max |error|, max |data|, extrapolated-warnings) of ``loop`` predicted."""
    import warnings

    import numpy as np

    from jaxhyst.identify import ConditionWarning

    from .predictions import BeyondLaw, error_summary, predict_loops

    with warnings.catch_warnings(record=True) as caught:  # (an extrapolation is part of
        warnings.simplefilter("always", ConditionWarning)  # the row instead)
        try:
            predicted, data = predict_loops(spec, problem, params, [loop])[0]
        except BeyondLaw as err:  # (the fold's law gives no material there: no prediction)
            data = np.asarray(_fitted_data(spec, loop))
            return {"rms": math.inf, "max_abs": math.inf,
                    "data_scale": float(np.max(np.abs(data))), "extrapolated": [],
                    "no_prediction": err.reason, "_curve": (np.full(data.shape, np.nan), data)}
    beyond = [" ".join(str(w.message).split()) for w in caught
              if issubclass(w.category, ConditionWarning)]
    for w in caught:
        if not issubclass(w.category, ConditionWarning):
            warnings.warn_explicit(w.message, w.category, w.filename, w.lineno)
    return {**error_summary(predicted, data), "extrapolated": beyond,
            "_curve": (predicted, data)}


def leave_one_out(args, spec, given, loops, method, forms) -> dict:
    """The folds (and own fits) of every form in ``forms``; the kept form's name, every
    form's rows and score, and whether the run was interrupted or a fit stopped short
    (``_curves``, ``_folds``: the kept form's predictions and its folds' free values,
    [(names, values)])."""
    from jaxhyst._interrupt import stop_requested
    from jaxhyst.identify import condition_distance

    from .fitting import thinned

    conditions = _conditions(spec, loops)
    table, partial, short, curves, singles, folds, alone_short = {}, False, [], {}, {}, {}, {}
    near_curves, owns = {}, {}
    longest = max(lp.n_samples for lp in loops)
    every = -(-longest // FOLD_SAMPLES)
    fit_loops = thinned(loops, every)  # (what the comparison's fits see)
    if every > 1:
        note("leave-one-out", f"{longest} samples in a loop: each loop alone and each fold "
                              f"fitted on one sample in {every}, every error measured on "
                              "all of them; the final fit on all")
    pad_to = comparison_shape(spec, fit_loops)
    pad_all = pad_to if every == 1 else comparison_shape(spec, loops)

    def on_all(fitted, problem, params, lp):  # (a prediction of all of lp's samples)
        return _predict({**fitted, "pad_to": pad_all}, problem, params, lp)

    def own_rms(fit, lp):  # (an own fit's error on all of its loop's samples)
        result, problem, fitted = fit
        return result.rms_error if every == 1 else \
            on_all(fitted, problem, result.params, lp)["rms"]
    scale = [_data_scale(spec, lp) for lp in loops]  # (each loop's size, for its fits)
    for form in forms:
        spec_f = {**spec, **candidate_spec(args, form), "pad_to": pad_to}
        # (a fold's parameters of the same kind as a single loop's: shared, no law)
        shared = not (spec_f.get("vary") or spec_f.get("per_loop"))
        # (a candidate that differs from an earlier one only by its law has its loops
        # alone fitted already: the same single-loop problems)
        same = singles_key(form)
        alone, own, seen = singles.get(same, ([], [], []))
        # (seen[j]: the loops whose data shaped own[j], its starts included — a loop's
        # fit predicts a held-out loop for the baseline only where it never saw it)
        own, reused, seen = list(own), len(own), [set(x) for x in seen]
        for lp in fit_loops[len(own):]:
            if stop_requested():
                partial = True
                break
            # (a joint problem of one loop, padded as the folds are: one program for all)
            single = {**spec_f, "joint": pad_to is not None, "loop": lp.index,
                      "vary": None, "per_loop": []}
            note("leave-one-out", f"{form}: loop {lp.index} alone …")
            own.append(_continued(args, _fit(args, single, given, [lp], method), method,
                                  f"{form}: loop {lp.index} alone"))
            seen.append({len(own) - 1})
        # (each loop's fit from its own data alone: what a fold starts from, and the
        # baseline predicts by, where a re-fit from a neighbour's fit saw the held-out
        # loop — `_unseen`)
        alone = alone or [r for r, _, _ in own]
        if not partial and not stop_requested():
            own, sources = _own_best(args, own, fit_loops, method, form)
            seen = [s | seen[j] if j is not None else s for s, j in zip(seen, sources,
                                                                       strict=True)]
        rows = []
        for i, held in enumerate(loops):
            if partial or stop_requested():
                partial = True
                break
            rest = [lp for j, lp in enumerate(fit_loops) if j != i]
            # (the starts: the training loops' own fits that never saw loop i — a fit
            # re-fitted from one that did, only as the loop alone fitted it — the
            # closest first: a batch takes as many as its starts allow)
            train = [j for j in range(len(alone)) if j != i]
            fits = {j: _unseen(own, alone, seen, i, j) for j in train}
            seeds = [fits[j].params for j in sorted(train, key=lambda j: fits[j].rms_error /
                                                    scale[j])
                     if not isinstance(fits[j].params, dict)] if shared else []
            note("leave-one-out", f"{form}: fitting without loop {held.index} …")
            result, problem, fitted = _fit(args, spec_f, given, rest, method, seeds)
            result, problem, fitted = _continued(args, (result, problem, fitted), method,
                                                 f"{form}: the fold without loop "
                                                 f"{held.index}")
            if result.result == "interrupted":
                partial = True
                break
            folds.setdefault(form, []).append(  # (by name: a fold has fewer loops)
                (tuple(problem.space.names), problem.space.free_values(result.params)))
            predicted = on_all(fitted, problem, result.params, held)
            curves.setdefault(form, []).append((held, *predicted.pop("_curve")))
            far = _beyond(conditions, i)
            row = {"loop": held.index, **predicted,
                   "rms_fitted": result.rms_error, "outcome": result.result,
                   "outside": bool(far), "beyond": far, "bounds": fitted["bounds"],
                   "extra_bounds": fitted["extra_bounds"]}
            if not result.success:
                short.append(f"{form}, fold without loop {held.index}: {result.result}")
            mine = own_rms(own[i], held) if i < len(own) else None  # (one simulation)
            if mine is not None and shared and row["rms"] < mine * (1.0 - 1e-3):
                # (the fold, which never saw the loop, predicts it better than its own fit:
                # the own fit stopped in a higher valley)
                again = _again(args, own[i], result.params, method, "from the fold's fit",
                               row["rms"], f"{form}: loop {held.index}")
                if again is not own[i]:  # (the fold saw every loop but this one)
                    own[i], seen[i] = again, set(range(len(loops)))
                    mine = own_rms(own[i], held)
            if mine is not None:
                row["own_rms"] = mine
                row["ratio"] = row["rms"] / max(row["own_rms"], 1e-300)
                others = [j for j in range(len(own)) if j != i]
                if others:
                    j = min(others, key=lambda j: condition_distance(conditions[i],
                                                                     conditions[j]))
                    _, problem_j, spec_j = own[j]
                    result_j = _unseen(own, alone, seen, i, j)
                    near = on_all(spec_j, problem_j, result_j.params, held)
                    near_curves.setdefault(form, []).append((held, *near.pop("_curve")))
                    row["nearest_loop"], row["nearest_rms"] = loops[j].index, near["rms"]
                    row["nearest_outcome"] = result_j.result
            note("leave-one-out", f"{form}: loop {held.index} predicted, rms "
                 f"{row['rms']:.4g} ({row['outcome']})")
            rows.append(row)
        alone_short.setdefault(same, []).extend(
            f"{form}, loop {lp.index} alone: {r.result}" for (r, _, _), lp in
            zip(own[reused:], loops[reused:], strict=False) if not r.success)
        done = len(rows) == len(loops)
        score = math.exp(sum(math.log(r["rms"] / r["data_scale"]) for r in rows) /
                         len(rows)) if done else None
        near = [r["nearest_rms"] / r["data_scale"] for r in rows if "nearest_rms" in r]
        near_score = (math.exp(sum(math.log(x) for x in near) / len(near))
                      if done and len(near) == len(rows) else None)
        table[form] = {"rows": rows, "score": score, "complete": done,
                       "nearest_score": near_score}
        owns[form] = own
        if done:
            singles.setdefault(same, (alone, list(own), seen))
        if partial:
            break
    kept, source = choose(table, conditions, comparison=len(forms) > 1)
    counted, elsewhere = counted_short(alone_short, kept, source)
    out = {"forms": table, "kept": kept, "partial": partial,
           "stopped_short": short + counted, "stopped_short_elsewhere": elsewhere,
           "fitted_every": every, "_curves": curves.get(kept, []), "_folds": folds.get(kept, [])}
    if kept == NEAREST:  # (its curves and fits: the source form's single fits)
        out["_curves"], out["_own"] = near_curves[source], owns[source]
    return out


def counted_short(alone_short: dict, kept, source) -> tuple[list, list]:
    """(the own fits cut short that make the exit status 3, the others) of ``alone_short``
    ({(form, losses): [text]}): an own fit sets only its candidate's ratios (a fold, its
    score) and the baseline's predictions: those of ``kept`` and ``source`` count."""
    used = {singles_key(f) for f in (kept, source) if f not in (None, NEAREST)}
    return ([s for key in used for s in alone_short.get(key, [])],
            [s for key, v in alone_short.items() if key not in used for s in v])


def held_out_text(held: dict) -> str:
    """The table of a leave-one-out run, for the terminal."""
    every = held.get("fitted_every", 1)
    lines = ["\n  leave one loop out: each loop predicted from a fit of the others (rms; × "
             "its own fit's rms; the nearest measured loop's fit)" +
             (f"; every fit on one sample in {every}, every error on all" if every > 1
              else "")]
    for form, t in held["forms"].items():
        cells = []
        for r in t["rows"]:
            ratio = f", {r['ratio']:.3g}× own" if "ratio" in r else ""
            ratio += " (extrapolated)" if r.get("outside") else ""
            near = (f", nearest (loop {r['nearest_loop']}) {r['nearest_rms']:.4g}"
                    if "nearest_rms" in r else
                    f" (loop {r['nearest_loop']}'s fit)" if form == NEAREST else "")
            flag = "" if r["outcome"] == "successful" else f" [{r['outcome']}]"
            if r.get("no_prediction"):  # (its law gives no material there)
                flag += f" [NO PREDICTION: {r['no_prediction']}]"
            cells.append(f"loop {r['loop']}: {r['rms']:.4g}{near}{ratio}{flag}")
        score = (f"score {t['score']:.4g}" if t["score"] is not None else
                 "incomplete")
        label = form if form != NEAREST else f"{NEAREST} ({t['form']} alone)"
        lines.append(f"    {label:<10} {score} — " + "; ".join(cells))
    kept = held["kept"]
    compared = [f for f in held["forms"] if f != NEAREST]
    if kept == NEAREST:
        lines.append(f"    kept: the nearest-condition baseline — each loop's own "
                     f"{held['forms'][NEAREST]['form']} fit, a new loop predicted by the "
                     "nearest fitted loop's (the lowest geometric-mean held-out error "
                     "relative to each loop's size): no form here carries across these "
                     "conditions better")
    elif kept and len(compared) > 1:
        lines.append(f"    kept: {kept} (the lowest geometric-mean held-out error "
                     "relative to each loop's size)")
    near = held["forms"].get(kept, {}).get("nearest_score") if kept else None
    if near is not None and near < held["forms"][kept]["score"]:
        lines.append(f"    BASELINE BETTER: the nearest measured loop's own fit predicts the "
                     f"held-out loops better (score {near:.4g} against {kept}'s "
                     f"{held['forms'][kept]['score']:.4g}): no form here carries across "
                     "these conditions" + (" (name several forms, or none, to let the "
                                           "comparison keep it)" if len(compared) == 1
                                           else ""))
    for s in held["stopped_short"]:
        lines.append(f"    STOPPED SHORT: {s}")
    for s in held.get("stopped_short_elsewhere", ()):
        lines.append(f"    stopped short (a candidate not kept: its ratios only): {s}")
    if held["partial"]:
        lines.append("    PARTIAL: interrupted; the folds above are the ones that finished")
    return "\n".join(lines)
