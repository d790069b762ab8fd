"""Saved models on the command line (``--model FILE`` of ``simulate`` and ``compensate``):
read, and a condition law (an ``identify --vary`` fit) evaluated at the run's conditions."""

from __future__ import annotations

import os

from .spec import CLIError, data_changed, warn

#: A law's feature → (the condition, the option that gives it).
FEATURE_OPTIONS = {"log_f": ("frequency", "--frequency"),
                   "T": ("temperature", "--temperature"),
                   "log_amplitude": ("amplitude", None)}


def read_model(path: str):
    """The `jaxhyst.Model` saved in ``path`` (one line where it cannot be read)."""
    import jaxhyst as jh

    try:
        return jh.load_model(path)
    except FileNotFoundError:
        raise CLIError(f"--model {path}: no such file.") from None


def is_model_file(path: str) -> bool:
    """Whether ``path`` is a model file (``identify --save-model``), not a result JSON."""
    from jaxhyst.saved import FORMAT

    try:
        with open(path, "rb") as fh:
            return f'"format": "{FORMAT}"'.encode() in fh.readline(4096)
    except OSError:
        return False


def load_model_fit(path: str):
    """As `load_result` for a model file: (its header's meta, the problem spec with the
    data path resolved, the rebuilt problem, the fitted parameters — the law's
    coefficients of a ``--vary`` fit), the data checked against the SHA-256 it was
    fitted to."""

    import numpy as np

    import jaxhyst as jh
    from jaxhyst.saved import read_header

    from .problems import build_problem

    meta = read_header(path).get("meta", {})
    spec, missing = fitted_data(path, meta)
    if missing:
        raise CLIError(missing)
    model = jh.load_model(path)
    params = ({n: np.float64(v) for n, v in model.coefficients.items()}
              if model.coefficients is not None else model.parameter_tree())
    return meta, spec, build_problem(spec), params


def fitted_data(path: str, meta: dict):
    """(the problem spec a model file's header ``meta`` names, its data path resolved
    relative to the file at ``path``; '' — or, where that data cannot be used, why, in
    one line: no problem in the header, the file gone, or changed since the fit)."""

    if "problem" not in meta:
        return None, (f"{path} holds a model without the problem it was fitted to (saved "
                      "by Python or an older jaxhyst): report needs identify's --out result "
                      "or a model saved by identify --save-model.")
    spec = dict(meta["problem"])
    if not os.path.isabs(spec["data"]):  # stored relative to the model file
        spec["data"] = os.path.normpath(os.path.join(os.path.dirname(os.path.abspath(path)),
                                                     spec["data"]))
    if not os.path.isfile(spec["data"]):
        return spec, (f"{path} was fitted to {spec['data']}, which is not there: put the "
                      "data file back beside the model (same relative path).")
    return spec, data_changed(spec["data"], meta.get("data_sha256"), path)


def equal_sets(tree):
    """``tree`` (a joint fit's parameters: leaves (L,) per loop, or () where not per loop)
    as one set where every loop's set is the same; None where they differ."""
    import jax
    import numpy as np

    if any(np.ndim(x) and np.ptp(np.asarray(x)) > 0 for x in jax.tree.leaves(tree)):
        return None
    return jax.tree.map(lambda x: x[0] if np.ndim(x) else x, tree)


def one_set(model):
    """``model`` with one parameter set where it holds a joint fit's per-loop sets (leaves
    (L,)) that are all equal — every parameter was shared: one material — else as it is."""
    import numpy as np

    import jaxhyst as jh

    if model.law is not None or np.ndim(model.params.Ms) != 1:
        return model
    one = equal_sets((model.params, model.variant, model.losses))
    return model if one is None else jh.Model(one[0], model.actuator, one[1],
                                              model.substeps, one[2])


def model_at(args, model, path: str, *, frequency=None, temperature=None, amplitude=None,
             amplitude_option: str = "--field-amplitude", amplitude_unit: str = "A/m"):
    """``model`` ready for one drive: a condition law evaluated at the conditions the
    options give (frequency in Hz, temperature in °C, ``amplitude`` in ``amplitude_unit``
    from ``amplitude_option``), each condition it varies with required and the others
    refused; a model of one parameter set per loop (a joint fit without a law) refused,
    unless it picks the nearest loop's set (`jaxhyst.NearestCondition`).
    Extrapolations are warned on stderr."""
    import warnings

    import numpy as np

    import jaxhyst as jh

    given = {"frequency": frequency, "temperature": temperature, "amplitude": amplitude}
    model = one_set(model)  # (a joint fit that shared every parameter, saved as sets)
    if model.law is None:
        if np.ndim(model.params.Ms) != 0:
            raise CLIError(f"--model {path} holds {np.shape(model.params.Ms)[0]} parameter "
                           "sets, one per loop of a joint fit, and no law between them: fit "
                           "with --vary to carry one, or fit the loop you mean alone.")
        if temperature is not None:
            raise CLIError(f"--temperature: the model in {path} has no condition law "
                           "(identify --vary … :T); it would have no effect.")
        return model
    needed = {}
    for feature in model.law.features:
        name, option = FEATURE_OPTIONS[feature]
        option = option or amplitude_option
        unit = dict(model.law.units).get("log_amplitude", "A/m")
        if feature == "log_amplitude" and unit != amplitude_unit:
            by = "by B (--flux-amplitude)" if unit == "T" else "by a field (--field-amplitude)"
            raise CLIError(f"--model {path}: its law varies with the peak "
                           f"{'flux density' if unit == 'T' else 'field'} ({unit}), this "
                           f"run's {amplitude_option} is in {amplitude_unit}: drive it {by}.")
        if given[name] is None:
            what = (f"picks the nearest of its {model.law.n_records} fitted loops by the "
                    f"{name}" if isinstance(model.law, jh.NearestCondition) else
                    f"its condition law varies with the {name}")
            raise CLIError(f"--model {path}: {what}; give {option}.")
        needed[name] = given[name]
    if temperature is not None and "temperature" not in needed:
        raise CLIError(f"--temperature: the law of {path} does not vary with the "
                       "temperature; it would have no effect.")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", jh.ConditionWarning)
        evaluated = model.at(**needed)
    for w in caught:
        if issubclass(w.category, jh.ConditionWarning):
            warn(args, str(w.message))
    return evaluated
