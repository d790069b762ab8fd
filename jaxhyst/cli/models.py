"""Saved models on the command line (``--model FILE`` of ``simulate`` and ``compensate``):
read, and a condition law (an ``identify --vary`` fit) evaluated at the run's conditions."""

from __future__ import annotations

from .spec import CLIError, warn

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


def model_at(args, model, path: str, *, frequency=None, temperature=None, amplitude=None,
             amplitude_option: str = "--field-amplitude", amplitude_unit: str = "A/m"):
    """``model`` ready for one drive: a condition law evaluated at the conditions the
    options give (frequency in Hz, temperature in °C, ``amplitude`` in ``amplitude_unit``
    from ``amplitude_option``), each condition it varies with required and the others
    refused; a model of one parameter set per loop (a joint fit without a law) refused.
    Extrapolations are warned on stderr."""
    import warnings

    import numpy as np

    import jaxhyst as jh

    given = {"frequency": frequency, "temperature": temperature, "amplitude": amplitude}
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
            raise CLIError(f"--model {path}: its condition law varies with the {name}; give "
                           f"{option}.")
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
