"""Models as data: an identified model (`Model`: parameters, form, actuator, RK4
substeps, losses, a condition law) saved to and loaded from one file, in the
ecosystem's form.

**The file** is one line of JSON — the header: format and version, the form (its class
name), the substeps, the parameters' units and leaf shape, the actuator's name and
whether it has turns per metre, the condition law (its features, references, fitted
range and coefficient names; or the fitted records' conditions of a nearest-condition
model), the versions of jaxhyst, JAX and Equinox that wrote it,
and whatever the caller adds (``meta``; ``identify --save-model`` adds the data file, its
SHA-256, the outcome, the rms error, the identifiability report, the fitted loops' range
of conditions and the error its leave-one-out folds lead one to expect) — followed by the
model's arrays as ``equinox.tree_serialise_leaves`` writes them. The header says what
the arrays are, so `load_model` builds the matching template and
``equinox.tree_deserialise_leaves`` fills it; nothing is unpickled. Written through the
package's file writer (atomically for a regular file).
"""

from __future__ import annotations

import io
import json
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._files import write_bytes
from .actuator import Actuator
from .drive import Drive
from .model.flux import FluxDrive, FluxSimulation, simulate_flux, simulate_flux_unchecked
from .model.jiles_atherton import (
    AbstractJAVariant,
    ClassicJA,
    EnergyBasedJA,
    PopJA,
    VenkataramanJA,
)
from .model.laws import ConditionModel, Conditions, NearestCondition
from .model.losses import LOSS_NAMES, Losses
from .model.paths import (
    model_parameters,
    model_values,
    own_parameters,
    split_parameters,
    unphysical,
)
from .model.play import AbstractPlayForm, PlayJA, PreisachJA
from .model.simulate import Simulation, simulate, simulate_unchecked
from .names import DEFAULT_SUBSTEPS
from .params import NAMES, TABLE1_TRUE, UNITS, Parameters, check_parameters, is_concrete

FORMAT = "jaxhyst-model"
VERSION = 1
#: The built-in forms a file can name.
FORMS = {cls.__name__: cls for cls in (EnergyBasedJA, ClassicJA, VenkataramanJA, PopJA,
                                       PlayJA, PreisachJA)}


class ModelFileError(ValueError):
    """A model file cannot be read (one line naming the file and the fix)."""


class Model(eqx.Module):
    """An identified model, ready to simulate new drives.

    - ``params``: `Parameters` (leaves of shape () — or (L,) for one set per loop of a
      joint fit);
    - ``actuator``: the `Actuator` (geometry, turns per metre, bias);
    - ``variant``: the model form (a Jiles–Atherton variant, or a form of pinning cells
      such as `jaxhyst.PlayJA`, whose own parameters it carries); ``substeps``: RK4
      substeps per sample;
    - ``losses``: `jaxhyst.Losses` of the rate-dependent model, or None (rate
      independent);
    - ``law`` and ``coefficients``: for a fit of a condition law (``identify --vary``,
      `jaxhyst.ConditionProblem`), its `jaxhyst.ConditionModel` (with the references and
      fitted range) and its coefficients ``{name: value}``; ``params`` then hold the
      fitted records' sets (leaves (L,)) and `at` gives the model at a new condition;
      or, for the nearest-condition model (`jaxhyst.NearestCondition`, kept by
      ``identify --joint --leave-one-out`` where it predicts the held-out loops best),
      that and no coefficients: ``params`` (and the losses' and the form's own
      parameters) hold one set per fitted loop, and `at` gives the nearest loop's set.
    """

    params: Parameters
    actuator: Actuator
    variant: eqx.Module = EnergyBasedJA()
    substeps: int = eqx.field(static=True, default=DEFAULT_SUBSTEPS)
    losses: Losses | None = None
    law: object = eqx.field(static=True, default=None)
    coefficients: dict | None = None

    def __check_init__(self):
        for name, value, kind, example in (
                ("params", self.params, Parameters, "jaxhyst.TABLE1_TRUE"),
                ("actuator", self.actuator, Actuator, "jaxhyst.ACTUATOR1")):
            if not isinstance(value, kind):
                raise TypeError(f"Model's {name} must be a jaxhyst.{kind.__name__} (e.g. "
                                f"{example}); got {type(value).__name__}.")
        check_parameters(self.params)  # (values it can read: not inside a trace)
        if self.losses is not None and not isinstance(self.losses, Losses):
            raise TypeError(f"Model's losses must be a jaxhyst.Losses or None; got "
                            f"{type(self.losses).__name__}.")

    def at(self, frequency: float | None = None, temperature: float | None = None,
           amplitude: float | None = None) -> Model:
        """The model at one condition (frequency in Hz, temperature in °C, amplitude: the
        peak field in A/m, or the peak flux density in T for a B-driven fit), from its
        condition law (or the nearest fitted loop's set, for a `NearestCondition`): one
        parameter set (leaves of shape ()) and no law. A condition outside the fitted
        range warns (`jaxhyst.ConditionWarning`); one the law needs
        and not given is a one-line ``ValueError``."""
        if self.law is None:
            raise ValueError("this model has no condition law (it was not fitted with "
                             "identify --vary / a ConditionProblem): it has no condition "
                             "to be evaluated at.")
        given = {"frequency": frequency, "temperature": temperature, "amplitude": amplitude}
        conditions = Conditions(**{k: None if v is None else (float(v),)
                                   for k, v in given.items()})
        self.law.warn_outside(conditions)
        if isinstance(self.law, NearestCondition):  # (the nearest fitted loop's set)
            sets = np.shape(self.params.Ms)
            if sets != (self.law.n_records,):
                raise ValueError(f"this model holds parameters of shape {sets} and a "
                                 f"NearestCondition of {self.law.n_records} records: give "
                                 "one parameter set (leaves of shape (L,)) per record.")
            i = int(self.law.nearest(conditions)[0])
            pick = lambda x: x[i] if np.ndim(x) else x  # noqa: E731
            return Model(jax.tree.map(pick, self.params), self.actuator,
                         jax.tree.map(pick, self.variant), self.substeps,
                         None if self.losses is None else jax.tree.map(pick, self.losses))
        values = self.law.evaluate(self.coefficients, self.law.feature_values(conditions))
        tree = model_parameters({n: v[0] for n, v in values.items()}, self.variant,
                                self.losses is not None)
        why = unphysical(tree) if is_concrete(tree) else None
        if why is not None:
            units = {"frequency": "Hz", "temperature": "°C",
                     "amplitude": self.law._unit("log_amplitude")}
            where = ", ".join(f"{k} {v:g} {units[k]}" for k, v in given.items()
                              if v is not None)
            raise ValueError(f"the model's condition law does not reach {where}: there it "
                             f"gives {why}; evaluate it nearer the fitted conditions.")
        params, losses, form = split_parameters(tree)
        return Model(params, self.actuator, self.variant if form is None else form,
                     self.substeps, losses)

    def simulate(self, drive: Drive) -> Simulation:
        """Every signal for ``drive`` (`jaxhyst.simulate`; one parameter set)."""
        return simulate(self.params, self.actuator, drive, self.variant, self.substeps,
                        self.losses)

    def simulate_unchecked(self, drive: Drive) -> Simulation:
        """`simulate` without input checks, for use under jit/vmap/grad."""
        return simulate_unchecked(self.params, self.actuator, drive, self.variant,
                                  self.substeps, self.losses)

    def simulate_flux(self, drive: FluxDrive) -> FluxSimulation:
        """The B-driven model for the flux density of ``drive`` (`jaxhyst.simulate_flux`:
        H(t) and the energy per cycle)."""
        return simulate_flux(self.params, drive, self.variant, self.substeps, self.losses)

    def simulate_flux_unchecked(self, drive: FluxDrive) -> FluxSimulation:
        """`simulate_flux` without input checks, for use under jit/vmap/grad."""
        return simulate_flux_unchecked(self.params, drive, self.variant, self.substeps,
                                       self.losses)

    def __repr__(self) -> str:
        """The model with its values (not the arrays' shapes)."""
        values = model_values(self.parameter_tree())
        if not is_concrete(self.params):
            shown = "traced values"
        elif all(np.ndim(v) == 0 for v in values.values()):
            shown = ", ".join(f"{n}={float(v):.6g}" for n, v in values.items())
        else:
            shown = f"{np.shape(self.params.Ms)[0]} parameter sets (one per loop)"
        losses = "" if self.losses is None else ", rate-dependent"
        law = "" if self.law is None else \
            f"; the nearest of {self.law.n_records} fitted loops (.at(…))" \
            if isinstance(self.law, NearestCondition) else \
            f"; condition law {', '.join(self.law.coefficient_names())} (.at(…))"
        return (f"Model({type(self.variant).__name__}: {shown}; {self.actuator.name}; "
                f"{self.substeps} substeps{losses}{law})")

    def parameter_tree(self):
        """The model's parameter pytree (`jaxhyst.model.paths.split_parameters`)."""
        members = [self.params]
        if self.losses is not None:
            members.append(self.losses)
        if own_parameters(self.variant):
            members.append(self.variant)
        return members[0] if len(members) == 1 else tuple(members)


def _versions() -> dict:
    from . import __version__

    return {"jaxhyst": __version__, "jax": jax.__version__, "equinox": eqx.__version__}


def save_model(path: str | os.PathLike, model: Model, **meta) -> None:
    """Write ``model`` to ``path`` (see the module docstring); ``meta``: JSON-able
    entries added to the header (the data it was fitted to, its error …)."""
    if not isinstance(model, Model):
        raise TypeError(f"save_model needs a jaxhyst.Model; got {type(model).__name__}.")
    if not is_concrete(model):
        raise TypeError("save_model writes values: call it outside jax.jit, jax.grad and "
                        "vmap (here the model holds traced arrays).")
    header = {"format": FORMAT, "version": VERSION, "variant": type(model.variant).__name__,
              "substeps": model.substeps, "units": UNITS,
              "parameter_shape": list(np.shape(model.params.Ms)),
              "actuator": {"name": str(model.actuator.name),
                           "has_turns": model.actuator.n is not None},
              "has_losses": model.losses is not None,
              "loss_names": list(LOSS_NAMES) if model.losses is not None else None,
              "form_settings": _form_settings(model.variant),
              "law": _law_header(model),
              "versions": _versions(), "meta": meta}
    buf = io.BytesIO()
    buf.write(json.dumps(header).encode("utf-8") + b"\n")
    eqx.tree_serialise_leaves(buf, model)
    write_bytes(path, buf.getvalue())


def _law_header(model: Model) -> dict | None:
    """The condition law of ``model`` as JSON (its coefficients' names; their values go
    with the arrays), or None."""
    law = model.law
    if law is None:
        return None
    if isinstance(law, NearestCondition):
        r = law.records
        return {"kind": "nearest", "units": dict(law.units),
                "records": {n: None if getattr(r, n) is None else list(getattr(r, n))
                            for n in ("frequency", "temperature", "amplitude")}}
    return {"varying": {n: list(f) for n, f in law.varying}, "degree": law.degree,
            "reference": dict(law.reference),
            "fitted_range": {f: list(r) for f, r in law.fitted_range},
            "units": dict(law.units), "coefficients": sorted(model.coefficients)}


def _law_of(header: dict):
    """(the `ConditionModel`, a template of its coefficients) of a file's header, or
    (None, None)."""
    law = header.get("law")
    if not law:
        return None, None
    if law.get("kind") == "nearest":
        return NearestCondition(Conditions(**law["records"]), law.get("units", {})), None
    model = ConditionModel(law["varying"], law["degree"], law["reference"],
                           {f: tuple(r) for f, r in law["fitted_range"].items()},
                           law.get("units", {}))
    return model, {n: jnp.zeros(()) for n in law["coefficients"]}


def _form_settings(form) -> dict:
    """The static settings a form is rebuilt with (the number of cells of a form of
    pinning cells)."""
    return {"cells": form.cells} if isinstance(form, AbstractPlayForm) else {}


def read_header(path: str | os.PathLike) -> dict:
    """The JSON header of a model file."""
    path = os.fspath(path)
    if not os.path.isfile(path):
        raise ModelFileError(f"model file {path} does not exist (or is not a file).")
    with open(path, "rb") as fh:
        line = fh.readline()
    try:
        header = json.loads(line.decode("utf-8"))
    except (UnicodeDecodeError, json.JSONDecodeError):
        header = None
    if not isinstance(header, dict) or header.get("format") != FORMAT:
        hint = ("; a result of 'jaxhyst identify --out' is not one: write the model with "
                "identify --save-model FILE.eqx") if path.lower().endswith(".json") else ""
        raise ModelFileError(f"{path} is not a jaxhyst model file (written by "
                             f"jaxhyst.save_model){hint}.")
    if header.get("version") != VERSION:
        raise ModelFileError(f"{path} is a model file of version {header.get('version')}; "
                             f"this jaxhyst reads version {VERSION}.")
    return header


def load_model(path: str | os.PathLike, variant: AbstractJAVariant | None = None) -> Model:
    """The `Model` saved in ``path``. ``variant``: the form, needed only when the file
    names one that is not built in (your own form: pass an instance of it)."""
    header = read_header(path)
    name = header["variant"]
    if variant is None:
        if name not in FORMS:
            raise ModelFileError(f"{path} was saved with the form {name}, which is not built "
                                 f"in; pass variant={name}(…) to load_model.")
        variant = FORMS[name](**header.get("form_settings", {}))
    elif type(variant).__name__ != name:
        raise ModelFileError(f"{path} was saved with the form {name}; variant= is a "
                             f"{type(variant).__name__}.")
    shape = tuple(header["parameter_shape"])
    params = Parameters(*[jnp.full(shape, getattr(TABLE1_TRUE, n)) for n in NAMES])  # (valid)
    if isinstance(variant, AbstractPlayForm):  # (its own parameters: one per set)
        own = list(variant.own_parameters)
        variant = eqx.tree_at(lambda f: [getattr(f, n) for n in own], variant,
                              [jnp.zeros(shape) for _ in own])
    act = header["actuator"]
    actuator = Actuator(1.0, 1.0, 1.0 if act["has_turns"] else None, 0.0, name=act["name"])
    losses = Losses(*[jnp.zeros(shape) for _ in LOSS_NAMES]) if header.get("has_losses") \
        else None
    # (a file written before the lag existed holds eddy and excess only)
    stored = header.get("loss_names") or ["eddy", "excess"]
    law, coefficients = _law_of(header)
    like = Model(params, actuator, variant, int(header["substeps"]), losses, law,
                 coefficients)
    if losses is not None and tuple(stored) != LOSS_NAMES:
        like = eqx.tree_at(lambda m: m.losses, like, tuple(jnp.zeros(shape) for _ in stored))
    with open(os.fspath(path), "rb") as fh:
        fh.readline()
        try:
            model = eqx.tree_deserialise_leaves(fh, like)
        except Exception as err:  # noqa: BLE001 - any failure to parse: a damaged file
            raise ModelFileError(f"{path}: its arrays cannot be read ({type(err).__name__}); "
                                 "the file is truncated or damaged.") from None
    leaves, like_leaves = jax.tree.leaves(model), jax.tree.leaves(like)
    if any(np.shape(a) != np.shape(b) for a, b in zip(leaves, like_leaves, strict=True)):
        raise ModelFileError(f"{path}: its arrays do not match its header; the file is "
                             "damaged.")
    try:
        check_parameters(model.params)
    except ValueError as err:
        raise ModelFileError(f"{path}: {err}") from None
    if isinstance(model.losses, tuple):
        values = dict(zip(stored, model.losses, strict=True))
        model = eqx.tree_at(lambda m: m.losses, model, Losses(
            *[values.get(n, jnp.zeros(shape)) for n in LOSS_NAMES]))
    return model
