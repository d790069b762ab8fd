"""Every hysteresis path of the package, in one place: a form (a Jiles–Atherton variant or
a form of pinning cells) driven by H, by B or by M, with or without the loss terms, run
through the one time loop of `jaxhyst.model.timeloop`.

`hysteresis_path` is what `simulate`, `simulate_flux`, the inverse model and the reach
of a compensation call. A form of your own plugs in as a Jiles–Atherton variant
(`jaxhyst.AbstractJAVariant`: a slope dM/dH, integrated by RK4) or as a form that builds
its own time-loop form (like `jaxhyst.model.play.AbstractPlayForm`: ``path_form``,
``loop_parameters``, ``irreversible_magnetization``, ``parameters``).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp

from ..params import MU0, NAMES, PHYSICAL_RULES, UNITS, Parameters
from .drivers import FluxDriven, MagnetizationDriven
from .dynamic import RateDependentPath, relaxed
from .jiles_atherton import AbstractJAVariant
from .losses import LOSS_NAMES, LOSS_UNITS, Losses
from .magnetization import JAPath
from .play import AbstractPlayForm, PlayJA, PreisachJA
from .timeloop import AbstractPathForm, run_path

#: The kinds of form the model accepts.
FORM_TYPES = (AbstractJAVariant, AbstractPlayForm)

#: The unit of every parameter name a model may have: the ten, the loss coefficients,
#: the built-in forms' own.
PARAMETER_UNITS = {**UNITS, **LOSS_UNITS, **PlayJA.own_parameters,
                   **PreisachJA.own_parameters}
#: The built-in forms' own parameters (`own_parameters`).
OWN_NAMES = tuple(dict.fromkeys([*PlayJA.own_parameters, *PreisachJA.own_parameters]))

#: A condition feature's variable in a coefficient's unit.
_FEATURE_WORDS = {"log_f": "ln f", "log_amplitude": "ln amplitude", "T": "10 K"}


def parameter_unit(name: str) -> str:
    """A parameter's unit; for a coefficient of a condition law
    (``k:log_f``, ``c:T^2``: `jaxhyst.ConditionModel`) the unit of its slope — a
    dimensionless exponent for a parameter that varies multiplicatively (θ ∝ f^s: "1,
    power of f"), the parameter's unit per feature unit for α̃ and c."""
    if ":" not in name:
        return PARAMETER_UNITS.get(name, "")
    param, _, feature = name.partition(":")
    square = feature.endswith("^2")
    feature = feature.removesuffix("^2")
    word = _FEATURE_WORDS.get(feature, feature)
    per = f"({word})²" if square else word
    if param in ("alpha", "c"):  # (additive: jaxhyst.model.laws.ADDITIVE)
        return f"{PARAMETER_UNITS.get(param, '1')} per {per}"
    if feature == "T":
        return f"1 per {per} (exponent)"
    return f"1 (power of {word[3:]})" if not square else f"1 per {per} (exponent)"


#: What drives a path: the field H, the flux density B or the magnetization M.
DRIVERS = ("H", "B", "M")


def path_form(form, driver: str = "H", end_slope_here: bool = False) -> AbstractPathForm:
    """The time-loop form of ``form`` driven by ``driver`` (`DRIVERS`)."""
    if isinstance(form, AbstractJAVariant):
        along = {"H": form, "B": FluxDriven(form), "M": MagnetizationDriven(form)}[driver]
        return JAPath(along, end_slope_here)
    return form.path_form(driver, end_slope_here)


def loop_parameters(form, p):
    """The parameters the time loop of ``form`` sees: the `Parameters` ``p`` (and the
    form itself where it has parameters of its own)."""
    return p if isinstance(form, AbstractJAVariant) else form.loop_parameters(p)


def own_parameters(form) -> dict:
    """``{name: unit}`` of the parameters a form has of its own (fields of the form, such
    as the ``spread`` of `jaxhyst.PlayJA`); empty for the Jiles–Atherton variants."""
    return dict(getattr(form, "own_parameters", {}))


def model_values(params) -> dict:
    """``{name: value}`` (arrays) of every parameter of a model's parameter pytree: the
    ten, then the loss coefficients and the form's own parameters where it has them."""
    p, losses, form = split_parameters(params)
    out = {n: getattr(p, n) for n in Parameters.names}
    if losses is not None:
        out.update({n: getattr(losses, n) for n in LOSS_NAMES})
    if form is not None:
        out.update({n: getattr(form, n) for n in own_parameters(form)})
    return out


def split_parameters(params):
    """``(Parameters, Losses or None, form or None)`` of a model's parameter pytree:
    `Parameters` alone, or a tuple of `Parameters` with `Losses` (the rate-dependent
    model) and/or a form with parameters of its own (in any order)."""
    if not isinstance(params, tuple):
        return params, None, None
    found = {"p": None, "losses": None, "form": None}
    for member in params:
        key = ("p" if isinstance(member, Parameters) else "losses"
               if isinstance(member, Losses) else "form" if isinstance(member, FORM_TYPES)
               else None)
        if key is None or found[key] is not None:
            raise TypeError("a model's parameters are Parameters, or a tuple of Parameters "
                            "with jaxhyst.Losses and/or a form with parameters of its own "
                            f"(e.g. PlayJA); got a tuple holding {type(member).__name__}.")
        found[key] = member
    if found["p"] is None:
        raise TypeError("a tuple of model parameters must hold jaxhyst.Parameters.")
    return found["p"], found["losses"], found["form"]


def model_parameters(values: dict, form, losses: bool):
    """A model's parameter pytree from a law's values (`ConditionModel.evaluate`):
    `Parameters`, `Losses` where ``losses``, ``form`` with its own parameters set."""
    members = [Parameters(**{n: values[n] for n in NAMES})]
    if losses:
        members.append(Losses(*[values[n] for n in LOSS_NAMES]))
    own = list(own_parameters(form))
    if own and own[0] in values:
        members.append(eqx.tree_at(lambda f: [getattr(f, n) for n in own], form,
                                   [values[n] for n in own]))
    return members[0] if len(members) == 1 else tuple(members)


def hysteresis_path(form, p, t, drive, *, substeps: int, losses=None, driver: str = "H"):
    """The path of ``form`` at the parameters ``p`` along ``drive`` (shape (T,): H in
    A/m, B in T or M in A/m by ``driver``; ``t`` in s, needed with ``losses``), from the
    demagnetized state.

    **Returns:** ``(Y_sub, k_sub, h, dY)``: the response at the substep points u_1 … u_S
    of each interval, shape (N, S) (M for the drivers H and B, H for M), its slope along
    the driver at u_0 … u_S with the interval's direction, shape (N, S + 1), the field
    the hysteresis sees at the samples, shape (T,) (the drive itself without losses; the
    field h of the rate-dependent model with them, `jaxhyst.model.dynamic`), and None —
    or, with losses, what the after-effect adds to the rate k_sub·dh/dt at u_0 … u_S
    (A/(m·s), shape (N, S + 1); ``Y_sub`` is then the relaxed M, `dynamic.relaxed`).
    With losses and the driver B, ``k_sub`` is dM_s/dh along h (the path is the
    rate-dependent model's, `dynamic.RateDependentPath` driven by B: the after-effect
    in; the loss fields are the caller's, explicit in B's rate).
    """
    S = int(substeps)
    theta = loop_parameters(form, p)
    if losses is None:
        loop = path_form(form, driver)
        out = run_path(theta, t, drive, form=loop, substeps=S)
        Y_sub, k_sub = loop.split(out, theta, drive, S)
        return Y_sub, k_sub, drive, None
    if driver not in ("H", "B"):
        raise ValueError(f"the rate-dependent path is driven by H or B, not {driver!r}.")
    inner = path_form(form, "H", end_slope_here=True)
    out = run_path((theta, losses), t, drive, form=RateDependentPath(inner, driver),
                   substeps=S)
    h = jnp.concatenate([drive[:1] / MU0 if driver == "B" else drive[:1], out[:, -1]])
    Q = jnp.concatenate([jnp.zeros_like(drive[:1]), out[:, -2]])
    Y_sub, k_sub = inner.split(out[:, :-2], theta, h, S)
    M0 = inner.magnetization(inner.initial_state(theta, drive[0]))
    Y_sub, dY = relaxed(losses.relax, t, Y_sub, Q, S, M0)
    return Y_sub, k_sub, h, dY


def _unit_text(name: str) -> str:
    unit = PARAMETER_UNITS.get(name, "1")
    return "" if unit == "1" else f" {unit}"


def unphysical(params) -> str | None:
    """Why a model's parameter pytree (`split_parameters`; values that can be read, one
    set) is no material's — the first parameter outside its physical range
    (`jaxhyst.params.PHYSICAL_RULES`), loss coefficient or built-in form's own parameter
    out of range, e.g. "spread = 64.3 (spread must lie in [0, 10] …)" — or None. For
    what a condition law gives far from its fitted conditions (`jaxhyst.Model.at`, the
    command line's predictions), which no constructor checks."""
    import numpy as np

    p, losses, form = split_parameters(params)
    for name in NAMES:
        v = float(np.asarray(getattr(p, name)))
        rule, words = PHYSICAL_RULES.get(name, (None, ""))
        if not np.isfinite(v) or (rule is not None and not rule(np.float64(v))):
            cut = words.rfind(" (")  # (the rule without its explanation, if it has one)
            rule_only = words[:cut] if words.endswith(")") and cut > words.find("]") \
                else words
            return f"{name} = {v:.4g}{_unit_text(name)} ({name} {rule_only})"
    own = [(n, lambda v, n=n: Losses(**{n: v})) for n in LOSS_NAMES if losses is not None]
    if type(form) in (PlayJA, PreisachJA):
        own += [(n, lambda v, n=n: type(form)(**{n: v})) for n in form.own_parameters]
    for name, build in own:  # (each built alone: the constructors check the ranges)
        value = getattr(losses if name in LOSS_NAMES else form, name)
        try:
            build(value)
        except ValueError as err:
            rule = str(err).partition("; got")[0].rstrip(".")
            return f"{name} = {float(np.asarray(value)):.4g}{_unit_text(name)} ({rule})"
    return None
