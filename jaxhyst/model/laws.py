"""Parameters as smooth functions of the operating condition: frequency, temperature, and
the loop's amplitude — one set of coefficients for all the records of a material, so that
the model predicts a condition it was not fitted to.

**The form.** Each record (a loop, a measured period) has a condition: frequency f (Hz),
temperature T (°C) and amplitude A (the record's peak field, A/m, or peak flux density,
T), as far as the data carry them. Its features are

    ln(f/f_ref),   (T − T_ref)/(10 K),   ln(A/A_ref)

(the references: the geometric mean of the fitted frequencies and amplitudes, the mean
temperature), and a chosen parameter θ varies with the chosen features x_j as

    θ = θ_ref · exp(Σ_j s_j·x_j [+ q_j·x_j²])   (a parameter ≥ 0: Ms, a, k, λs, E, Kz,
                                                 Mz, Cz and the loss coefficients),
    θ = θ_ref + Σ_j s_j·x_j [+ q_j·x_j²]        (α̃ and c; c kept in [0, 1]),

so that a frequency dependence is a power law θ ∝ f^s and a temperature dependence an
exponential. The others are shared. The coefficients θ_ref, s_j (and q_j with
``degree=2``) are named ``k``, ``k:log_f``, ``k:T``, ``k:log_amplitude`` (``…^2``); they
are fitted by `jaxhyst.identify.conditions.ConditionProblem` and carried by a saved
`jaxhyst.Model` (this module sits below both, so that neither imports the other).

**The amplitude form** (``{"k": ("log_amplitude",), …}``: pinning and reversibility
set by the loop's peak field, since one parameter set does not carry over between loops
of different amplitude) and how it is judged: `jaxhyst.identify.conditions`.

**No law** (`NearestCondition`): each fitted record keeps its own set and a condition
takes the set of the record nearest to it (`condition_distance`: the differences of the
same features, summed) — the baseline a law must beat on held-out records, and what a
leave-one-out comparison keeps where none does.
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping
from dataclasses import dataclass

import jax.numpy as jnp
import numpy as np

from ..names import CONDITION_FEATURES
from ..params import NAMES
from .losses import LOSS_NAMES
from .paths import OWN_NAMES

#: The features a condition provides: name → (what, unit of the raw condition).
FEATURES = CONDITION_FEATURES

#: Every name a condition model may vary: the ten, the loss coefficients and the
#: built-in forms' own parameters.
VARYING_NAMES = (*NAMES, *LOSS_NAMES, *OWN_NAMES)
#: Parameters that vary additively (the others multiplicatively: they are ≥ 0).
ADDITIVE = ("alpha", "c")
#: Default box of a coefficient s_j or q_j (per unit feature: a power of f within ±3).
SLOPE_BOX = (-3.0, 3.0)


class ConditionWarning(UserWarning):
    """A prediction asked outside the fitted conditions (an extrapolation)."""


@dataclass(frozen=True)
class Conditions:
    """The conditions of L records: ``frequency`` (Hz), ``temperature`` (°C),
    ``amplitude`` (A/m or T), each a sequence of L values or None when the data do not
    carry it."""

    frequency: tuple | None = None
    temperature: tuple | None = None
    amplitude: tuple | None = None

    def __post_init__(self):
        lengths = set()
        for name in ("frequency", "temperature", "amplitude"):
            values = getattr(self, name)
            if values is None:
                continue
            v = np.atleast_1d(np.asarray(values, dtype=np.float64))
            if v.ndim != 1 or not np.all(np.isfinite(v)):
                raise ValueError(f"Conditions.{name} must be a sequence of finite numbers; "
                                 f"got {values!r}.")
            if name != "temperature" and np.any(v <= 0):
                raise ValueError(f"Conditions.{name} must be > 0 ({FEATURES[_KEY[name]][1]}); "
                                 f"got {v[v <= 0][0]:g}.")
            object.__setattr__(self, name, tuple(float(x) for x in v))
            lengths.add(v.shape[0])
        if len(lengths) > 1:
            raise ValueError(f"Conditions: give one value per record for every condition; "
                             f"got lengths {sorted(lengths)}.")

    @property
    def n_records(self) -> int:
        for name in ("frequency", "temperature", "amplitude"):
            if getattr(self, name) is not None:
                return len(getattr(self, name))
        return 0

    def raw(self, feature: str) -> np.ndarray | None:
        values = getattr(self, FEATURES[feature][0])
        return None if values is None else np.asarray(values, dtype=np.float64)


_KEY = {"frequency": "log_f", "temperature": "T", "amplitude": "log_amplitude"}
#: Records whose features all differ by less than this are at one condition (1 % in
#: frequency or amplitude, 0.1 K in temperature).
SAME_CONDITION = 0.01


def _distinct_rows(x: np.ndarray) -> np.ndarray:
    """One row of ``x`` (L, F) per condition: a row within `SAME_CONDITION` of an earlier
    row in every column joins that row's condition."""
    group = list(range(len(x)))
    for i in range(len(x)):
        for j in range(i):
            if np.all(np.abs(x[i] - x[j]) < SAME_CONDITION):
                group[i] = group[j]
                break
    return x[sorted(set(group))]


def _described(conditions: Conditions, feature: str) -> str:
    """The distinct values of a feature's condition, e.g. "amplitude 15.1, 35.7"."""
    what = FEATURES[feature][0]
    values = sorted({float(f"{v:.3g}") for v in conditions.raw(feature)})
    shown = ", ".join(f"{v:g}" for v in values[:6]) + (" …" if len(values) > 6 else "")
    return f"{what} {shown}"


@dataclass(frozen=True)
class ConditionModel:
    """Which parameters vary with which features (module docstring): ``varying`` is
    ``{parameter name: (feature, …)}`` with features of `FEATURES`; ``degree`` 1 (linear
    in each feature) or 2 (with its square). The references are set from the fitted
    conditions (`fitted_to`). Immutable and hashable (it is static structure of a
    problem)."""

    varying: tuple = ()
    degree: int = 1
    reference: tuple = ()
    fitted_range: tuple = ()
    units: tuple = ()

    def __init__(self, varying: Mapping | tuple = (), degree: int = 1,
                 reference: Mapping | tuple = (), fitted_range: Mapping | tuple = (),
                 units: Mapping | tuple = ()):
        pairs = []
        for name, feats in dict(varying).items():
            feats = (feats,) if isinstance(feats, str) else tuple(feats)
            if name not in VARYING_NAMES:
                raise ValueError(f"ConditionModel: {name!r} is not a parameter (names: "
                                 f"{list(VARYING_NAMES)}).")
            bad = [f for f in feats if f not in FEATURES]
            if bad or not feats:
                raise ValueError(f"ConditionModel: {name} varies with {list(feats)}; the "
                                 f"features are {list(FEATURES)}.")
            pairs.append((name, feats))
        if degree not in (1, 2):
            raise ValueError(f"ConditionModel.degree must be 1 or 2; got {degree!r}.")
        object.__setattr__(self, "varying", tuple(pairs))
        object.__setattr__(self, "degree", int(degree))
        object.__setattr__(self, "reference", tuple(dict(reference).items()))
        object.__setattr__(self, "fitted_range", tuple(dict(fitted_range).items()))
        object.__setattr__(self, "units", tuple(dict(units).items()))

    @property
    def varies(self) -> dict:
        """``{name: (feature, …)}``."""
        return dict(self.varying)

    @property
    def features(self) -> tuple[str, ...]:
        """The features used, in a fixed order."""
        return tuple(f for f in FEATURES if any(f in v for v in self.varies.values()))

    def coefficient_names(self) -> list[str]:
        """Names of the coefficients beyond the reference values: ``k:log_f`` …"""
        out = []
        for name, feats in self.varying:
            for f in feats:
                out.append(f"{name}:{f}")
                if self.degree == 2:
                    out.append(f"{name}:{f}^2")
        return out

    def undetermined(self, conditions: Conditions) -> str | None:
        """Why the records' ``conditions`` cannot determine this model's coefficients (one
        line), or None. A parameter's law has 1 + (its features × degree) coefficients
        and needs as many distinct conditions, spread along each of its features
        (records whose features all differ by less than `SAME_CONDITION` are one
        condition: loops measured at the same amplitude determine no slope in it)."""
        X = self.fitted_to(conditions).feature_values(conditions)
        for name, feats in self.varying:
            x = X[:, [self.features.index(f) for f in feats]]
            distinct = _distinct_rows(x)
            design = np.concatenate([np.ones((len(distinct), 1)), distinct] +
                                    ([distinct ** 2] if self.degree == 2 else []), axis=1)
            needed, rank = design.shape[1], int(np.linalg.matrix_rank(design))
            if rank < needed:
                seen = "; ".join(_described(conditions, f) for f in feats)
                if len(distinct) < len(x):
                    seen += ": values within 1 % (0.1 K) are one condition"
                law = "+".join(feats) + (" (degree 2)" if self.degree == 2 else "")
                n = len(distinct)
                return (f"{name} varies with {law}: {needed} coefficients, but the "
                        f"{len(x)} records are at {n} condition{'s' if n > 1 else ''} "
                        f"({seen}), which determine{'s' if n == 1 else ''} only {rank}; "
                        "give records at more different conditions"
                        + (", or use degree 1" if self.degree == 2 else "") + ".")
        return None

    def fitted_to(self, conditions: Conditions) -> ConditionModel:
        """This model with its references (and the fitted range, for warnings) from the
        conditions of the records it is fitted to."""
        ref, rng = {}, {}
        for f in self.features:
            raw = conditions.raw(f)
            if raw is None:
                users = [n for n, v in self.varying if f in v]
                raise ValueError(f"{users} vary with the {FEATURES[f][0]}, but the records "
                                 f"carry no {FEATURES[f][0]} ({FEATURES[f][1]}); give it in "
                                 "Conditions or drop it from the ConditionModel.")
            ref[f] = float(np.mean(raw)) if f == "T" else float(np.exp(np.mean(np.log(raw))))
            rng[f] = (float(np.min(raw)), float(np.max(raw)))
        return ConditionModel(self.varies, self.degree, ref, rng)

    def feature_values(self, conditions: Conditions) -> np.ndarray:
        """The features of each record, shape (L, F) in the order of `features`."""
        cols = []
        for f in self.features:
            raw = conditions.raw(f)
            if raw is None:
                raise ValueError(f"the conditions lack the {FEATURES[f][0]} "
                                 f"({FEATURES[f][1]}) that the fitted model varies with.")
            ref = dict(self.reference)[f]
            cols.append((raw - ref) / 10.0 if f == "T" else np.log(raw / ref))
        return np.stack(cols, axis=-1) if cols else np.zeros((conditions.n_records, 0))

    def warn_outside(self, conditions: Conditions) -> None:
        """A `ConditionWarning` for each condition outside the fitted range, saying how far
        (a ``ValueError`` naming a condition the model needs and the records lack)."""
        _warn_outside(self.features, dict(self.fitted_range), self._unit, conditions)

    def _unit(self, feature: str) -> str:
        """The unit of a feature's condition ("A/m or T" for an amplitude: the one of the
        records fitted, A/m for fields, T for flux densities, when known)."""
        return dict(self.units).get(feature, "A/m" if feature == "log_amplitude" else
                                    FEATURES[feature][1])

    def evaluate(self, coefficients: Mapping, X):
        """Per-record values {name: (L,)} of every parameter the coefficients hold, at
        features X (L, F)."""
        X = jnp.asarray(X)
        col = {f: X[:, i] for i, f in enumerate(self.features)}
        L = X.shape[0]
        out = {}
        for name, ref in coefficients.items():
            if ":" in name:
                continue
            exponent = jnp.zeros((L,), dtype=jnp.float64)
            for f in self.varies.get(name, ()):
                exponent = exponent + coefficients[f"{name}:{f}"] * col[f]
                if self.degree == 2:
                    exponent = exponent + coefficients[f"{name}:{f}^2"] * col[f] ** 2
            if name in ADDITIVE:
                value = ref + exponent
                out[name] = jnp.clip(value, 0.0, 1.0) if name == "c" else value
            else:
                out[name] = ref * jnp.exp(exponent)
        return out


def _warn_outside(features, fitted_range: dict, unit, conditions: Conditions) -> None:
    """A `ConditionWarning` for each of ``conditions`` outside ``fitted_range`` ({feature:
    (lowest, highest)}) in one of ``features``, saying how far (``unit(feature)``: the
    unit shown); a ``ValueError`` where the conditions lack one of the features."""
    for f in features:
        raw, (lo, hi) = conditions.raw(f), fitted_range[f]
        if raw is None:
            what, u = FEATURES[f]
            raise ValueError(f"the fitted model varies with the {what}, and the records "
                             f"to predict carry none ({u}); give it.")
        for v in raw:
            if lo <= v <= hi:
                continue
            what = FEATURES[f][0]
            far = (f"{min(abs(v - lo), abs(v - hi)):.3g} K" if f == "T" else
                   f"a factor {max(v / hi, lo / v):.3g}")
            warnings.warn(f"a prediction at {what} {v:g} {unit(f)} lies outside the fitted "
                          f"range {lo:g}–{hi:g} {unit(f)} ({far} beyond it): an "
                          "extrapolation.", ConditionWarning, stacklevel=4)


def _feature(f: str, raw: np.ndarray) -> np.ndarray:
    """A condition's raw values on the scale of its feature (ln for the frequency and the
    amplitude, tens of kelvin for the temperature), without a reference."""
    return raw / 10.0 if f == "T" else np.log(raw)


def condition_distance(a: Mapping, b: Mapping) -> float:
    """How far two records' conditions lie apart, over the conditions both carry
    (``{"amplitude": …, "frequency": …, "temperature": …}``, a value or None each):
    |ln of the amplitude ratio| + |ln of the frequency ratio| + |ΔT|/10 K — the sum of
    the differences of the features a condition law reads."""
    d = 0.0
    for f in FEATURES:
        what = FEATURES[f][0]
        x, y = a.get(what), b.get(what)
        if x is not None and y is not None:
            d += abs(float(_feature(f, np.float64(x)) - _feature(f, np.float64(y))))
    return d


@dataclass(frozen=True)
class NearestCondition:
    """The nearest-condition model: no law between the fitted records, one parameter set
    per record, and a condition predicted by the set of the record whose condition lies
    nearest to it (`condition_distance`). The baseline a skeptic uses for a law; kept by
    ``identify --joint --leave-one-out`` where its folds predict the held-out loops best.

    ``records``: the fitted records' `Conditions`; ``units``: ``{"log_amplitude": "A/m"
    or "T"}``. Its ``features`` are the conditions that differ between the records (by
    more than `SAME_CONDITION` on a feature's scale); a prediction needs those.
    Immutable and hashable (static structure of a saved `jaxhyst.Model`)."""

    records: Conditions
    units: tuple = ()

    def __init__(self, records: Conditions, units: Mapping | tuple = ()):
        if not isinstance(records, Conditions) or records.n_records < 1:
            raise ValueError("NearestCondition needs the fitted records' Conditions (one "
                             "value per record of at least one condition).")
        object.__setattr__(self, "records", records)
        object.__setattr__(self, "units", tuple(dict(units).items()))

    @property
    def n_records(self) -> int:
        return self.records.n_records

    @property
    def features(self) -> tuple[str, ...]:
        """The features whose conditions differ between the records, in `FEATURES`'s
        order."""
        out = []
        for f in FEATURES:
            raw = self.records.raw(f)
            if raw is not None and np.ptp(_feature(f, raw)) > SAME_CONDITION:
                out.append(f)
        return tuple(out)

    @property
    def fitted_range(self) -> tuple:
        """``((feature, (lowest, highest)), …)`` of the records' conditions."""
        return tuple((f, (float(np.min(self.records.raw(f))),
                          float(np.max(self.records.raw(f))))) for f in self.features)

    def nearest(self, conditions: Conditions) -> np.ndarray:
        """The index of the nearest fitted record for each of ``conditions``' records,
        shape (L,) (a ``ValueError`` where they lack a condition the records differ in;
        the first of equally near records)."""
        cols = []
        for f in self.features:
            raw = conditions.raw(f)
            if raw is None:
                what, unit = FEATURES[f]
                unit = dict(self.units).get(f, unit)
                raise ValueError(f"the model picks the nearest of its {self.n_records} "
                                 f"fitted records by {what}, and the records to predict "
                                 f"carry none ({unit}); give it.")
            cols.append(np.abs(_feature(f, raw)[:, None] -
                               _feature(f, self.records.raw(f))[None, :]))
        if not cols:
            return np.zeros(max(conditions.n_records, 1), dtype=int)
        return np.argmin(np.sum(cols, axis=0), axis=1)

    def warn_outside(self, conditions: Conditions) -> None:
        """As `ConditionModel.warn_outside`: a `ConditionWarning` per condition beyond the
        fitted records' range (a ``ValueError`` for one the records differ in and the
        conditions lack)."""
        self.nearest(conditions)  # (a condition it needs and is not given: its own line)
        _warn_outside(self.features, dict(self.fitted_range),
                      lambda f: dict(self.units).get(f, "A/m" if f == "log_amplitude" else
                                                     FEATURES[f][1]), conditions)
