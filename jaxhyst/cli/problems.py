"""The model a command builds from its options or from a result file: the form, the box
(derived from the data where none is given, the loss coefficients' and the form's own
parameters' included), the parameter space, the problem (`build_problem`, so that
``jaxhyst report`` and ``predict`` can rebuild it from the JSON-able spec a result
records) and the fitted parameters of a result file (`load_result`)."""

from __future__ import annotations

import os

from jaxhyst.names import (
    CONDITION_FEATURES,
    DEFAULT_SUBSTEPS,
    FORM_PARAMETER_NAMES,
    LOSS_PARAMETER_NAMES,
    VARIANT_CLASSES,
)

from .spec import CLIError, data_changed, flux_of, loop_drive, loop_field, loop_signal, read_data

#: Loss coefficients (`jaxhyst.Losses`) and the built-in forms' own parameters: the names
#: beyond the ten a box, --fix or --vary may give.
LOSS_NAMES = LOSS_PARAMETER_NAMES
OWN_NAMES = FORM_PARAMETER_NAMES
#: The default number of pinning cells of a form that has them.
DEFAULT_CELLS = 16


def form_from_spec(spec: dict):
    """The model form a spec names (``variant``; ``cells`` for a form of pinning cells)."""
    import jaxhyst as jh

    cls = getattr(jh, VARIANT_CLASSES[spec.get("variant") or "energy"])
    if issubclass(cls, jh.AbstractPlayForm):
        return cls(cells=int(spec.get("cells") or DEFAULT_CELLS))
    return cls()


def split_given(given) -> tuple:
    """(the ten's changes or a `Bounds` preset, the other names' changes) of --bounds."""
    if not isinstance(given, dict):
        return given, {}
    extra = {n: v for n, v in given.items() if n in (*LOSS_NAMES, *OWN_NAMES)}
    return ({n: v for n, v in given.items() if n not in extra} or None), extra


def _flux_rate(loops, out, actuator, source) -> float:
    """The largest |dB/dt| (T/s) of the loops (B observed, or μ0·(H + M))."""
    import numpy as np

    from jaxhyst.params import MU0
    rates = []
    for lp in loops:
        H, data = loop_field(lp, actuator, source), lp.signals[out]
        B = data if out == "B" else MU0 * (H + data)
        rates.append(float(np.max(np.abs(np.diff(B) / np.diff(lp.t)))))
    return max(rates)


def _field_rate(loops, actuator, source) -> float:
    """The applied field's rate (A/(m·s)) of the loops: the 95th percentile of |dH/dt|
    (a digitized record's noise does not set it)."""
    import numpy as np

    return max(float(np.percentile(np.abs(np.diff(loop_field(lp, actuator, source))
                                          / np.diff(lp.t)), 95)) for lp in loops)


def resolve_bounds(spec: dict, given, loops):
    """``(Bounds, {name: (lower, upper)} of ``spec["losses"]`` and the form's own
    parameters, a line saying where the box came from)``: for M or B data derived from the
    ``loops``, else the paper's Table 1 box; a bounds file's entries replace the defaults
    it names; a preset is used as is. Loss coefficients (they need times, and M or B data
    or a bounds file): [0, 2·Hmax/max|dB/dt|], [0, 2·Hmax/max|dB/dt|^(1/2)] (a loss field
    up to twice the applied field's amplitude), lag and relax [0, 2·Hmax/|dH/dt|] (its
    95th percentile: about a third of a sine's period); a form's own: its default box."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.identify.measured import loop_bounds, merge_bounds
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS

    given, given_extra = split_given(given)
    if not spec.get("joint") and spec.get("loop") is not None:
        loops = [lp for lp in loops if lp.index == spec["loop"]] or loops
    out = loop_signal(spec, loops[0], spec.get("output"))
    kind = SIGNAL_OUTPUTS[out]
    actuator = jh.Actuator(**spec["actuator"])
    form = form_from_spec(spec)
    extra = {}
    for n in spec.get("losses") or []:
        if any(lp.t is None for lp in loops):  # (else each sample would count as 1 s)
            raise CLIError(f"--losses {n}: the rate-dependent model needs times: give a t "
                           "column (s), or a frequency column (Hz) of whole periods.")
        if n in given_extra:
            continue
        if not output_kind(kind).magnetic_only:
            raise CLIError(f"--losses {n}: the box of a loss coefficient is derived from M or "
                           f"B data; give it in a bounds file (--bounds, \"{n}\": [lower, "
                           "upper], SI).")
        Hmax = max(float(np.max(np.abs(loop_field(lp, actuator, spec["data"]))))
                   for lp in loops)
        if n in ("lag", "relax"):
            extra[n] = (0.0, 2.0 * Hmax / _field_rate(loops, actuator, spec["data"]))
            continue
        rate = _flux_rate(loops, out, actuator, spec["data"])
        extra[n] = (0.0, 2.0 * Hmax / (rate if n == "eddy" else np.sqrt(rate)))
    own = list(getattr(form, "own_parameters", {}))
    unknown = sorted(set(given_extra) - set(own) - set(spec.get("losses") or []))
    if unknown:
        raise CLIError(f"--bounds names {unknown}, which {spec.get('variant') or 'energy'} "
                       "does not have (loss coefficients need --losses; spread and a_rev "
                       "are parameters of the forms play and preisach).")
    if isinstance(given, jh.Bounds):
        bounds, text = given, None
    elif not output_kind(kind).magnetic_only:
        named = f" with {sorted(given)} from the bounds file" if given else ""
        bounds, text = (merge_bounds(jh.TABLE1_BOUNDS, given or {}),
                        f"bounds: the paper's Table 1 box{named}")
    else:
        Hs = [loop_field(lp, actuator, spec["data"]) for lp in loops]
        bounds, text = loop_bounds(Hs, [lp.signals[out] for lp in loops], kind, given), ""
    if isinstance(form, jh.AbstractPlayForm):
        extra.update({n: tuple(v) for n, v in form.own_bounds(bounds).items()})
    extra.update({n: tuple(v) for n, v in given_extra.items()})
    extra_text = "".join(f", {n} [{lo:.3g}, {hi:.3g}]" for n, (lo, hi) in extra.items())
    if text is None or text:
        return bounds, extra, text and text + extra_text
    lo, hi = bounds.lower.to_dict(), bounds.upper.to_dict()
    text = ", ".join(f"{n} [{lo[n]:.3g}, {hi[n]:.3g}]" for n in ("Ms", "a", "k", "alpha", "c"))
    named = f" ({sorted(given)} from the bounds file)" if given else ""
    return bounds, extra, f"bounds derived from the data{named}: {text}{extra_text}"


def _substeps(spec, form, loops) -> int:
    """The spec's substeps; 1 for a form of pinning cells on M or B data (it is exact
    between samples: substeps only place the points the structure is driven from)."""
    import jaxhyst as jh
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS

    out = loop_signal(spec, loops[0], spec.get("output"))
    if isinstance(form, jh.AbstractPlayForm) and output_kind(SIGNAL_OUTPUTS[out]).magnetic_only:
        return 1
    return int(spec.get("substeps", DEFAULT_SUBSTEPS))


def model_space(spec: dict, bounds, fixed: dict, n_loops=None, per_loop=()):
    """The `ParameterSpace` of the spec's model: the ten in ``bounds``, the free loss
    coefficients (``spec["losses"]``) and the form's own parameters in the spec's boxes."""
    import jaxhyst as jh
    from jaxhyst.model.paths import own_parameters

    form = form_from_spec(spec)
    extra = {n: tuple(v) for n, v in (spec.get("extra_bounds") or {}).items()}
    losses = {n: extra[n] for n in spec.get("losses") or []} or None
    own = {n: extra[n] for n in own_parameters(form) if n in extra}
    return jh.ParameterSpace.for_model(bounds, fixed=fixed, losses=losses,
                                       form=form if own_parameters(form) else None, own=own,
                                       n_loops=n_loops, per_loop=per_loop)


def per_loop_names(spec: dict, bounds, fixed: dict) -> list:
    """The parameters free per loop: ``--per-loop``'s, or every one where the fit keeps the
    nearest-condition model (``predict_by`` "nearest": each loop its own set)."""
    if spec.get("predict_by") == "nearest":
        return list(model_space(spec, bounds, fixed).names)
    return list(spec.get("per_loop") or ())


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
        if name not in (*NAMES, *LOSS_NAMES, *OWN_NAMES):
            raise CLIError(f"--vary {item!r}: {name!r} is not a parameter; names are "
                           f"{list(NAMES) + list(LOSS_NAMES) + list(OWN_NAMES)}.")
        bad = [f for f in feats if f not in CONDITION_FEATURES]
        if not feats or bad:
            raise CLIError(f"--vary {item!r}: give the features after a colon, joined by "
                           f"'+', from {list(CONDITION_FEATURES)} (e.g. 'k:log_f+T').")
        if name in out:
            raise CLIError(f"--vary {text!r}: {name!r} is named twice; give each parameter "
                           "one law (its features joined by '+', e.g. 'k:log_f+T').")
        out[name] = feats
    return out


def loop_conditions(spec, loops, actuator, overrides=None):
    """The loops' `Conditions` as a fit's law sees them: frequency and temperature from the
    file's columns (``overrides`` {name: value} replaces them for every loop); amplitude:
    the loop's peak field (A/m), or peak flux density (T) where driven by B."""
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

    if spec.get("driven_by") == "B":
        amplitude = [float(np.max(np.abs(flux_of(lp, spec["data"])))) for lp in loops]
    else:
        amplitude = [float(np.max(np.abs(loop_field(lp, actuator, spec["data"]))))
                     for lp in loops]
    return jh.Conditions(frequency=column("frequency"), temperature=column("temperature"),
                         amplitude=amplitude)


def model_parameters_from_json(obj: dict, form, what: str):
    """A model's parameters from ``{name: value}`` or a result's ``{"params": {name:
    {"value": v}}}``: `Parameters`, with `Losses` where the loss coefficients are given
    and the form (``form`` with its own parameters set) where they are."""
    import jax.numpy as jnp
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.io import parameters_from_json
    from jaxhyst.model.paths import own_parameters

    flat = obj.get("params", obj) if isinstance(obj.get("params"), dict) else obj
    flat = {n: (v["value"] if isinstance(v, dict) else v) for n, v in flat.items()}
    extra = {n: flat.pop(n) for n in (*LOSS_NAMES, *OWN_NAMES) if n in flat}
    members = [parameters_from_json(flat, what)]
    if any(n in extra for n in LOSS_NAMES):
        members.append(jh.Losses(*[np.asarray(extra.get(n, 0.0), float) for n in LOSS_NAMES]))
    own = list(own_parameters(form))
    if own and all(n in extra for n in own):
        members.append(type(form)(**{n: jnp.asarray(extra[n], float) for n in own},
                                  cells=form.cells))
    return members[0] if len(members) == 1 else tuple(members)


def load_result(path):
    """(saved JSON, its spec with the data path resolved, the rebuilt problem, the fitted
    parameters: a condition model's coefficients (``--vary``), else `Parameters` with
    `Losses` and the form's own) of an ``identify --out`` file; a changed data file refused."""
    import numpy as np

    from jaxhyst.io import read_json

    saved = read_json(path)
    if "problem" not in saved:
        raise CLIError(f"{path} is not a jaxhyst identify result (no 'problem' entry).")
    spec = dict(saved["problem"])
    if not os.path.isabs(spec["data"]):  # stored relative to the result file
        spec["data"] = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)),
                                                     spec["data"]))
    if changed := data_changed(spec["data"], saved.get("data_sha256"), path):
        raise CLIError(changed)
    try:
        problem = build_problem(spec)
    except CLIError as e:  # (an option stored in the file: say which file)
        raise CLIError(f"{path} (its problem entry): {e}") from None
    if "coefficients" in saved:
        params = {n: np.float64(v) for n, v in saved["coefficients"].items()}
    else:
        params = model_parameters_from_json(saved, form_from_spec(spec),
                                            f"parameters in {path}")
    return saved, spec, problem, params


def build_problem(spec: dict, loops=None):
    """A `Problem` (or `JointProblem` when ``spec["joint"]``, or a `ConditionProblem` over
    one with ``spec["vary"]``) from the JSON-able ``spec`` stored with every CLI result
    (so that ``jaxhyst report`` can rebuild it); ``loops``: the loops of ``spec["data"]``
    if already read."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import fix_structural
    from jaxhyst.identify.outputs import output_kind
    from jaxhyst.io import SIGNAL_OUTPUTS, bounds_from_json
    from jaxhyst.model.paths import own_parameters

    if loops is None:
        loops = read_data(spec["data"], spec.get("columns"))
    ids = [lp.index for lp in loops]
    bounds = bounds_from_json(spec["bounds"])
    actuator = jh.Actuator(**spec["actuator"])
    form = form_from_spec(spec)
    fixed = dict(spec.get("fixed") or {})
    substeps = _substeps(spec, form, loops)
    if spec.get("vary") and spec.get("per_loop"):
        raise CLIError("--vary and --per-loop both say how parameters differ between "
                       "loops; use one of them.")
    vary = parse_vary(spec.get("vary"))
    if vary:  # (checked before the records: a missing column is the one message)
        conditions = _checked_vary(spec, vary, loops, actuator, form)
    if spec.get("driven_by") == "B":
        if not spec.get("joint"):
            loops = _chosen_loop(spec, loops, ids)
        return flux_problem(spec, loops, bounds, fixed, form, substeps,
                            conditions if vary else None)
    if spec.get("joint"):
        out = loop_signal(spec, loops[0], spec.get("output"))
        if output_kind(SIGNAL_OUTPUTS[out]).magnetic_only:
            fixed = fix_structural(bounds, fixed)
        per_loop = per_loop_names(spec, bounds, fixed)
        extra = {n: tuple(v) for n, v in (spec.get("extra_bounds") or {}).items()}
        losses = {n: extra[n] for n in spec.get("losses") or []} or None
        own_form = form if own_parameters(form) else None
        space = (jh.per_record_space(bounds, len(loops), losses, own_form) if vary else
                 model_space(spec, bounds, fixed, n_loops=len(loops), per_loop=per_loop))
        records = jh.JointProblem([lp.signals[out] for lp in loops],
                                  [loop_drive(spec, lp, out, actuator) for lp in loops],
                                  actuator, space, output=SIGNAL_OUTPUTS[out],
                                  variant=form, substeps=substeps, pad_to=spec.get("pad_to"))
        if not vary:
            return records
        model = jh.ConditionModel(vary, int(spec.get("vary_degree", 1)))
        try:
            own = {n: extra[n] for n in own_parameters(form) if n in extra}
            cspace = jh.condition_space(bounds, model, fixed=fixed, losses=losses,
                                        form=own_form, own=own)
            return jh.ConditionProblem(records, conditions, model, cspace)
        except ValueError as err:
            raise CLIError(f"--vary: {err}") from None
    loop = _chosen_loop(spec, loops, ids)[0]
    out = loop_signal(spec, loop, spec.get("output"))
    if output_kind(SIGNAL_OUTPUTS[out]).magnetic_only:
        fixed = fix_structural(bounds, fixed)
    return jh.Problem(loop.signals[out], loop_drive(spec, loop, out, actuator), actuator,
                      model_space(spec, bounds, fixed), output=SIGNAL_OUTPUTS[out],
                      variant=form, substeps=substeps)


def _checked_vary(spec: dict, vary: dict, loops, actuator, form):
    """The loops' `Conditions`, once each parameter of ``vary`` can vary as asked (its
    loss identified too, of this form, its condition in the file): else a `CLIError`."""
    from jaxhyst.model.paths import own_parameters

    for name in vary:
        if name in LOSS_NAMES and name not in (spec.get("losses") or []):
            raise CLIError(f"--vary {name}: a loss coefficient of the rate-dependent "
                           f"model; identify it too with --losses {name} (the file "
                           "needs times).")
        if name in OWN_NAMES and name not in own_parameters(form):
            raise CLIError(f"--vary {name}: {spec.get('variant') or 'energy'} has no "
                           f"{name}; it is a parameter of the forms play (spread) "
                           "and preisach (spread, a_rev).")
    conditions = loop_conditions(spec, loops, actuator)
    for name, feats in vary.items():
        for f in feats:
            what, unit = CONDITION_FEATURES[f]  # (amplitude: from the loop's peak)
            if what != "amplitude" and getattr(conditions, what) is None:
                raise CLIError(f"--vary {name}:{f}: {spec['data']} has no {what} "
                               f"column; add a '{what}' column ({unit}) or drop "
                               f"{f} from --vary.")
    return conditions


def _chosen_loop(spec, loops, ids) -> list:
    """[the loop a single-loop fit is of] (``--loop``, or the file's only loop)."""
    if spec.get("loop") is None:
        if len(loops) > 1:
            raise CLIError(f"{spec['data']} holds loops {ids}; choose one with --loop, or fit "
                           "them together with --joint.")
        return [loops[0]]
    if spec["loop"] not in ids:
        raise CLIError(f"--loop {spec['loop']}: {spec['data']} holds loops {ids}.")
    return [loops[ids.index(spec["loop"])]]


def flux_problem(spec: dict, loops, bounds, fixed: dict, form, substeps: int, conditions):
    """The `FluxProblem` (with ``--vary``: its `ConditionProblem` on the checked loops'
    ``conditions``) of the spec's loops: each loop's B(t) drives the model, its H is the
    data (columns t, B, H; unequal lengths padded to the longest, or the spec's ``pad_to``)."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.identify.joint import fix_structural

    from .spec import check_flux_loops

    data = spec["data"]
    check_flux_loops(loops, data)
    fixed = fix_structural(bounds, fixed)
    run_in = spec.get("run_in_periods") or 1
    try:
        drives = [jh.flux_from_record(lp.t, lp.signals["B"], run_in_periods=run_in)
                  for lp in loops]
    except ValueError as err:
        raise CLIError(f"--driven-by B: {data}: {err}") from None
    H = [np.asarray(lp.H, dtype=np.float64) for lp in loops]
    pad_to = spec.get("pad_to")  # (a comparison's common shape; else the longest loop)
    vary = parse_vary(spec.get("vary"))
    losses_box = {n: tuple(v) for n, v in (spec.get("extra_bounds") or {}).items()
                  if n in (spec.get("losses") or [])} or None
    if not vary:  # (per loop: --per-loop's, or every parameter for the nearest model)
        per_loop = per_loop_names(spec, bounds, fixed)
        space = model_space(spec, bounds, fixed, len(loops), per_loop) if per_loop else \
            model_space(spec, bounds, fixed)
        return jh.FluxProblem(H, drives, space, output="field", variant=form, substeps=substeps,
                              pad_to=pad_to)
    own_form = form if isinstance(form, jh.AbstractPlayForm) else None
    records = jh.FluxProblem(H, drives, jh.per_record_space(bounds, len(loops), losses_box,
                                                            own_form),
                             output="field", variant=form, substeps=substeps, pad_to=pad_to)
    law = jh.ConditionModel(vary, int(spec.get("vary_degree", 1)))
    try:
        space = jh.condition_space(bounds, law, fixed=fixed, losses=losses_box,
                                   form=own_form)
        return jh.ConditionProblem(records, conditions, law, space)
    except ValueError as err:
        raise CLIError(f"--vary: {err}") from None
