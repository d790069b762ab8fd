"""Condition problems: the coefficients of a condition law (`jaxhyst.model.laws`: a
parameter as a smooth function of frequency, temperature and the loop's amplitude, the
others shared) as the free parameters of a `ConditionProblem` over the records of a
material, identified jointly with every solver and reported with their intervals by the
identifiability report; `condition_space`, `per_record_space` and `split_records` for
building and leave-one-out. `Conditions`, `ConditionModel` and the law's constants are
re-exported from `jaxhyst.model.laws`.

**The amplitude form** (`ConditionModel` with ``{"k": ("log_amplitude",), …}``) is the
remedy for the Jiles–Atherton minor-loop problem that parametrises the pinning and
reversibility by the loop's peak field. It is judged only by held-out loops:
`benchmarks/bench_amplitude.py`, with its results in benchmarks/RESULTS.md — it
interpolates between amplitudes, it does not extrapolate beyond them.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..model.laws import (  # (the law sits below the problems and Model; re-exported)
    ADDITIVE,
    FEATURES,
    SLOPE_BOX,
    VARYING_NAMES,
    ConditionModel,
    Conditions,
    ConditionWarning,
    NearestCondition,
    condition_distance,
)
from ..model.losses import LOSS_LIMITS, LOSS_NAMES
from ..model.paths import OWN_NAMES, model_parameters, own_parameters, unphysical
from ..params import NAMES, Bounds
from .flux import FluxProblem
from .problem import AbstractProblem, ResidualGroup
from .space import ParameterSpace

__all__ = ["ADDITIVE", "FEATURES", "SLOPE_BOX", "VARYING_NAMES", "ConditionModel",
           "ConditionProblem", "ConditionWarning", "Conditions", "NearestCondition",
           "condition_distance", "condition_space",
           "per_record_space", "split_records"]


def condition_space(bounds: Bounds, model: ConditionModel, fixed: Mapping | None = None,
                    losses: Mapping | None = None, slope_bounds: Mapping | None = None,
                    form=None, own: Mapping | None = None) -> ParameterSpace:
    """The space of a `ConditionProblem`'s coefficients: the reference values of the ten
    parameters in ``bounds`` (and of the loss coefficients in the box ``losses``
    ``{name: (lower, upper)}``, a coefficient left out held at 0, when given; and of the
    parameters of its own of a ``form`` such as `jaxhyst.PlayJA`, in the box ``own`` or
    the form's default), and each coefficient of ``model.coefficient_names()`` in
    `SLOPE_BOX` unless ``slope_bounds`` names it. ``fixed``: ``{name: value}`` of any of
    them held fixed."""
    base = ParameterSpace.for_model(bounds, losses=losses, form=form, own=own)
    names = list(base.flat_names)
    lo = {n: v for n, v in zip(base.flat_names, np.asarray(base.base).tolist(), strict=True)}
    hi = dict(lo)
    for n, a, b in zip(base.names, np.asarray(base.lower).tolist(),
                       np.asarray(base.upper).tolist(), strict=True):
        lo[n], hi[n] = a, b
    fixed = {**base.fixed, **dict(fixed or {})}  # (a loss coefficient not in losses: 0)
    for n in model.varies:
        if n not in names:
            raise ValueError(f"{n} varies in the ConditionModel but is not a parameter of "
                             "this space (pass losses= for the loss coefficients, form= "
                             "for a form's own parameters).")
    for c in model.coefficient_names():
        names.append(c)
        lo[c], hi[c] = (slope_bounds or {}).get(c, SLOPE_BOX)
    unknown = sorted(set(fixed) - set(names))
    if unknown:
        raise ValueError(f"Cannot fix unknown parameter(s) {unknown}; names are {names}.")
    lower = {n: np.float64(lo[n]) for n in names}
    upper = {n: np.float64(hi[n]) for n in names}
    return ParameterSpace.for_tree(lower, upper, fixed=fixed)


class ConditionProblem(AbstractProblem):
    """A problem over L records (a `JointProblem` or a `FluxProblem`, whose parameters
    have one value per record) whose parameters are the smooth functions of the records'
    conditions of a `ConditionModel` (module docstring). Its parameter pytree is the
    coefficient dict of `condition_space`; residual groups, data and output are the
    records problem's.

    **Arguments:** ``records``: the problem over the records; ``conditions``: their
    `Conditions`; ``model``: the `ConditionModel` (its references are set from these
    conditions); ``space``: from `condition_space`.
    """

    records: AbstractProblem
    space: ParameterSpace
    form: ConditionModel = eqx.field(static=True)  # (without its references)
    reference: jax.Array  # (F,) the features' references (data: no recompile per fold)
    fitted_range: jax.Array  # (F, 2) the fitted conditions' range, raw units
    features: jax.Array  # (L, F) the fitted records' features
    losses: bool = eqx.field(static=True)
    priors: tuple = eqx.field(static=True, default=())

    def __init__(self, records: AbstractProblem, conditions: Conditions,
                 model: ConditionModel, space: ParameterSpace):
        if not isinstance(conditions, Conditions):
            raise TypeError("conditions must be jaxhyst.Conditions(frequency=…, "
                            "temperature=…, amplitude=…).")
        L = conditions.n_records
        n_records = records.n_records if isinstance(records, FluxProblem) else \
            len(records.groups)
        if L != n_records:
            raise ValueError(f"{L} conditions for {n_records} records: give one per record.")
        fitted = model.fitted_to(conditions)
        undetermined = model.undetermined(conditions)
        if undetermined:
            raise ValueError(undetermined)
        self.form = ConditionModel(model.varies, model.degree)
        ref, rng = dict(fitted.reference), dict(fitted.fitted_range)
        self.reference = jnp.asarray([ref[f] for f in fitted.features], dtype=jnp.float64)
        self.fitted_range = jnp.asarray([rng[f] for f in fitted.features],
                                        dtype=jnp.float64).reshape(-1, 2)
        self.features = jnp.asarray(fitted.feature_values(conditions))
        self.records, self.space = records, space
        self.losses = any(n in space.flat_names for n in LOSS_NAMES)
        self.priors = ()
        own = [n for n in space.flat_names if n in OWN_NAMES]
        if own and not own_parameters(records.variant):
            raise ValueError(f"{own} are parameters of a form of pinning cells, but the "
                             f"records are fitted with {type(records.variant).__name__}.")

    @property
    def condition_model(self) -> ConditionModel:
        """The `ConditionModel` with the references and range of the fitted conditions."""
        feats = self.form.features
        ref = np.asarray(self.reference).tolist()
        rng = [tuple(r) for r in np.asarray(self.fitted_range).tolist()]
        amplitude = "T" if isinstance(self.records, FluxProblem) else "A/m"
        return ConditionModel(self.form.varies, self.form.degree,
                              dict(zip(feats, ref, strict=True)),
                              dict(zip(feats, rng, strict=True)),
                              {"log_amplitude": amplitude})

    @property
    def output(self) -> str:
        return self.records.output

    @property
    def groups(self) -> tuple[ResidualGroup, ...]:
        return self.records.groups

    def parameters_at(self, coefficients, X):
        """The records problem's parameter pytree (leaves (L,)) at features X (L, F)."""
        return model_parameters(self.form.evaluate(coefficients, X), self.records.variant,
                                self.losses)

    def per_record(self, coefficients):
        """The parameters of every fitted record."""
        return self.parameters_at(coefficients, self.features)

    def model(self, coefficients):
        """The identified model with its condition law (`jaxhyst.Model`: the fitted
        records' parameter sets, the law and its ``coefficients``; ``Model.at`` evaluates
        it at a new condition), to save (`jaxhyst.save_model`)."""
        from ..saved import Model

        m = self.records.model(self.per_record(coefficients))
        return Model(m.params, m.actuator, m.variant, m.substeps, m.losses,
                     self.condition_model, {n: jnp.asarray(v) for n, v in
                                            dict(coefficients).items()})

    def at(self, coefficients, conditions: Conditions):
        """The parameters at other ``conditions`` (a prediction; a `ConditionWarning` when
        they lie outside the fitted range)."""
        model = self.condition_model
        model.warn_outside(conditions)
        return self.parameters_at(coefficients, model.feature_values(conditions))

    def held_out_errors(self, coefficients, records: AbstractProblem,
                        conditions: Conditions) -> list[float]:
        """The rms error (model − data, each record's unit) of every record of ``records``
        (a problem of the same kind over records that were not fitted: their data and
        drives) predicted at their ``conditions``: the held-out error of a prediction. A
        record where the law gives no material (a parameter outside its physical range:
        `unphysical`) has no prediction: inf, and a `ConditionWarning` naming it and the
        value."""
        params = self.at(coefficients, conditions)
        residuals = records.group_residuals(params)
        errors = [float(np.sqrt(np.mean(g.observed(r) ** 2)))  # (the padding dropped)
                  for g, r in zip(records.groups, residuals, strict=True)]
        for i in range(len(errors)):
            why = unphysical(jax.tree.map(lambda x, i=i: np.asarray(x)[i], params))
            if why is not None:
                warnings.warn(f"held-out record {i}: the condition law gives {why} there "
                              "— no prediction (error inf)", ConditionWarning, stacklevel=2)
                errors[i] = np.inf
        return errors

    def group_residuals(self, params) -> tuple:
        return self.records.group_residuals(self.per_record(params))

    @property
    def observations(self):
        return self.records.observations

    def with_data(self, data) -> ConditionProblem:
        return eqx.tree_at(lambda q: q.records, self, self.records.with_data(data))


def per_record_space(bounds: Bounds, n_records: int, losses: Mapping | None = None,
                     form=None) -> ParameterSpace:
    """A space over one parameter set per record (leaves (L,)), every entry free: what a
    records problem is built with before a `ConditionProblem` replaces its parameters
    (with ``losses``: the loss coefficients too; with a ``form`` that has parameters of
    its own, those too)."""
    box = None if losses is None else {n: (0.0, LOSS_LIMITS[n]) for n in LOSS_NAMES}
    names = [*NAMES, *(LOSS_NAMES if losses is not None else ()),
             *(own_parameters(form) if form is not None else ())]
    return ParameterSpace.for_model(bounds, losses=box, form=form, n_loops=n_records,
                                    per_loop=names)


def split_records(n: int, held_out: int | Sequence[int]) -> tuple[list[int], list[int]]:
    """(fitted, held-out) record indices of ``n`` records; ``held_out`` an index or several.
    One-line error for an index that is not a record."""
    out = [held_out] if isinstance(held_out, (int, np.integer)) else list(held_out)
    bad = [i for i in out if not 0 <= int(i) < n]
    if bad:
        raise ValueError(f"held-out record(s) {bad} are not among the {n} records "
                         f"(0 … {n - 1}).")
    if not set(range(n)) - {int(i) for i in out}:
        raise ValueError(f"every one of the {n} records is held out; leave at least one to "
                         "fit.")
    return [i for i in range(n) if i not in out], [int(i) for i in out]
