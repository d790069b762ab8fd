"""Model parameters θ of the paper's eq 14, their box bounds, and the paper's presets.

Parameters are an ``equinox.Module`` with one named field per physical quantity, so a
batch of parameter sets is the same Module with array leaves of shape ``(P,)`` and
``jax.vmap`` over it is natural.

| field    | symbol | unit  | meaning                                                        |
|----------|--------|-------|----------------------------------------------------------------|
| Ms       | Ms     | A/m   | saturation magnetization                                       |
| lambda_s | λs     | 1     | saturation magnetostriction                                    |
| a        | a      | A/m   | anhysteretic shape parameter (Langevin width)                  |
| k        | k      | A/m   | pinning (irreversible loss) parameter                          |
| alpha    | α̃      | 1     | effective interdomain + stress coupling (negative in compression)|
| c        | c      | 1     | reversibility coefficient, 0 ≤ c ≤ 1                           |
| E        | E      | N/m²  | Young's modulus of the rod                                     |
| Kz       | Kz     | N/m   | effective stiffness of rod + load                              |
| Mz       | Mz     | kg    | effective moving mass                                          |
| Cz       | Cz     | N·s/m | effective damping                                              |
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._jax_compat import concrete_value
from ._typing import Array, ArrayLike, Float, Real
from .names import base_name

NAMES: tuple[str, ...] = ("Ms", "lambda_s", "a", "k", "alpha", "c", "E", "Kz", "Mz", "Cz")
#: Parameters only the magnetostriction and the structure see: they cannot affect M or B.
STRUCTURAL: tuple[str, ...] = ("lambda_s", "E", "Kz", "Mz", "Cz")
#: Vacuum permeability, H/m (B = μ0·(H + M)).
MU0 = 4e-7 * np.pi

UNITS: dict[str, str] = {
    "Ms": "A/m",
    "lambda_s": "1",
    "a": "A/m",
    "k": "A/m",
    "alpha": "1",
    "c": "1",
    "E": "N/m^2",
    "Kz": "N/m",
    "Mz": "kg",
    "Cz": "N*s/m",
}


class Parameters(eqx.Module):
    """The ten unknowns θ = [Ms, λs, a, k, α̃, c, E, Kz, Mz, Cz] (SI units, see module doc).

    Leaves may be scalars (one parameter set) or arrays with a leading batch axis.
    """

    Ms: Real
    lambda_s: Real
    a: Real
    k: Real
    alpha: Real
    c: Real
    E: Real
    Kz: Real
    Mz: Real
    Cz: Real

    names: ClassVar[tuple[str, ...]] = NAMES

    def __init__(self, Ms, lambda_s, a, k, alpha, c, E, Kz, Mz, Cz):
        self.Ms = jnp.asarray(Ms, dtype=jnp.float64)
        self.lambda_s = jnp.asarray(lambda_s, dtype=jnp.float64)
        self.a = jnp.asarray(a, dtype=jnp.float64)
        self.k = jnp.asarray(k, dtype=jnp.float64)
        self.alpha = jnp.asarray(alpha, dtype=jnp.float64)
        self.c = jnp.asarray(c, dtype=jnp.float64)
        self.E = jnp.asarray(E, dtype=jnp.float64)
        self.Kz = jnp.asarray(Kz, dtype=jnp.float64)
        self.Mz = jnp.asarray(Mz, dtype=jnp.float64)
        self.Cz = jnp.asarray(Cz, dtype=jnp.float64)

    # -- conversions --------------------------------------------------------------
    def to_array(self) -> Float[Array, "*batch 10"]:
        """Stack the fields along a new last axis, in the order of `NAMES`: shape (..., 10)."""
        return jnp.stack([getattr(self, n) for n in NAMES], axis=-1)

    @classmethod
    def from_array(cls, x: Float[ArrayLike, "*batch 10"]) -> Parameters:
        """Inverse of `to_array`: ``x`` has shape (..., 10) in the order of `NAMES`."""
        # host values are split on the host (indexing a device array eagerly compiles
        # a small program per kind of index at the first call)
        on_host = not any(isinstance(leaf, jax.Array) for leaf in jax.tree.leaves(x))
        x = np.asarray(x, dtype=np.float64) if on_host else jnp.asarray(x, dtype=jnp.float64)
        if x.shape[-1:] != (len(NAMES),):
            raise ValueError(
                f"Parameters.from_array needs a last axis of length {len(NAMES)} "
                f"(ordered {', '.join(NAMES)}); got shape {x.shape}."
            )
        return cls(*[x[..., i] for i in range(len(NAMES))])

    def to_dict(self) -> dict[str, float]:
        """Plain ``{name: float}`` of a single (unbatched) parameter set."""
        return {n: float(getattr(self, n)) for n in NAMES}

    @classmethod
    def from_dict(cls, d: dict) -> Parameters:
        missing = [n for n in NAMES if n not in d]
        unknown = [n for n in d if n not in NAMES]
        if missing or unknown:
            raise ValueError(
                f"Parameters need exactly the keys {list(NAMES)}; missing {missing}, "
                f"unknown {unknown}."
            )
        return cls(**{n: d[n] for n in NAMES})

    def replace(self, **changes) -> Parameters:
        """A copy with some fields changed, e.g. ``p.replace(Mz=0.6)``."""
        unknown = [n for n in changes if n not in NAMES]
        if unknown:
            raise ValueError(f"Unknown parameter name(s) {unknown}; valid names: {list(NAMES)}.")
        d = {n: getattr(self, n) for n in NAMES}
        d.update(changes)
        return Parameters(**d)

    def __str__(self) -> str:  # pragma: no cover - cosmetic
        if jnp.ndim(self.Ms) != 0:
            return f"Parameters(batch of {jnp.shape(self.Ms)})"
        rows = [f"  {n:<9}= {float(getattr(self, n)):.6g} {UNITS[n]}" for n in NAMES]
        return "Parameters(\n" + "\n".join(rows) + "\n)"


def is_concrete(x) -> bool:
    """Whether ``x`` (a number, an array, or any pytree of them) holds no tracer: its
    values can be inspected (they cannot inside jit/grad/vmap)."""
    return not any(isinstance(leaf, jax.core.Tracer) for leaf in jax.tree.leaves(x))


#: Physical range of each parameter: name → (test on a numpy value, the rule in words).
#: Beyond the signs, the ranges are those of any material or actuator, with a wide margin:
#: a value outside is a unit or typing mistake (the message says why).
PHYSICAL_RULES = {
    "Ms": (lambda v: (v > 0) & (v <= 1e7),
           "must lie in (0, 1e7] A/m (saturation magnetization; the highest of any material, "
           "Fe–Co, is 1.95e6 A/m)"),
    "a": (lambda v: (v >= 1e-6) & (v <= 1e9),
          "must lie in [1e-6, 1e9] A/m (Langevin width: below it the anhysteretic is a step, "
          "above it beyond any laboratory field)"),
    "k": (lambda v: (v >= 1e-6) & (v <= 1e9),
          "must lie in [1e-6, 1e9] A/m (pinning parameter, of the order of the coercive "
          "field: 0.1 A/m for the softest alloys, 1e6 A/m for the hardest magnets)"),
    "alpha": (lambda v: (v >= -10.0) & (v <= 10.0),
              "must lie in [-10, 10] (mean-field coupling; identified values are 1e-5–0.1)"),
    "c": (lambda v: (v >= 0) & (v <= 1), "must lie in [0, 1] (reversibility)"),
    "lambda_s": (lambda v: (v >= 0) & (v <= 0.1),
                 "must lie in [0, 0.1] (saturation magnetostriction: Terfenol-D's is 2e-3)"),
    "E": (lambda v: (v >= 0) & (v <= 1e13),
          "must lie in [0, 1e13] N/m^2 (Young's modulus: diamond's is 1.2e12)"),
    "Kz": (lambda v: (v > 0) & (v <= 1e13), "must lie in (0, 1e13] N/m (stiffness)"),
    "Mz": (lambda v: (v > 0) & (v <= 1e6), "must lie in (0, 1e6] kg (moving mass)"),
    "Cz": (lambda v: (v >= 0) & (v <= 1e13), "must lie in [0, 1e13] N*s/m (damping)"),
}


def physically_valid(p: Parameters):
    """True (a traced boolean, shape of the leaves) where every parameter lies in its
    physical range (`PHYSICAL_RULES`): usable inside jit, where values cannot be
    checked, to turn the signals of an impossible parameter set into NaN."""
    ok = True
    for n, (rule, _) in PHYSICAL_RULES.items():
        ok = ok & rule(getattr(p, n))
    return ok


def at_physical_limit(name: str, value: float) -> bool:
    """True if ``value`` is valid for ``name`` (`PHYSICAL_RULES`; a per-loop name such as
    ``c[1]`` counts as ``c``) but a step outward is not: the end of its physical range
    (c = 0 or 1, λs = E = Cz = 0)."""
    base = base_name(name)
    if base not in PHYSICAL_RULES:
        return False
    ok = PHYSICAL_RULES[base][0]
    v = np.float64(value)
    step = 1e-12 * max(abs(float(v)), 1.0)
    return bool(ok(v)) and not (bool(ok(v + step)) and bool(ok(v - step)))


def check_value(name: str, value, what: str) -> float:
    """``value`` as a float if it is finite and physically valid for the parameter
    ``name`` (`PHYSICAL_RULES`); else ``ValueError`` naming ``what`` (where it came from)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{what} must be a number; got {value!r}.") from None
    if not np.isfinite(v):
        raise ValueError(f"{what} is not finite ({value!r}); give a finite value.")
    if name in PHYSICAL_RULES and not PHYSICAL_RULES[name][0](np.float64(v)):
        raise ValueError(f"{what} = {v:g}: {name} {PHYSICAL_RULES[name][1]}.")
    return v


def shown_value(x) -> str:
    """``x`` for a message: a number as a number (``64294.2``, not ``Array(…)``), the
    first three of an array's, anything else as its repr."""
    try:
        v = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        return repr(x)
    return f"{float(v):g}" if v.ndim == 0 else repr([float(f"{e:.6g}") for e in
                                                    v.ravel()[:3]])


def readable_value(x) -> np.ndarray | None:
    """``x`` as a NumPy array where its value can be read: a concrete value, or the value
    under a transformation called directly (``jax.grad(f)(x)`` without ``jax.jit``); None
    inside jit or vmap, where it is abstract."""
    if not isinstance(x, jax.core.Tracer):
        return np.asarray(x)
    value = concrete_value(x)
    return None if value is None else np.asarray(value)


def check_parameters(p: Parameters) -> None:
    """Raise ``ValueError`` naming the parameter if ``p`` is physically invalid.

    Checks (all values, batched or not): every value finite; Ms, a, k, Mz, Kz > 0;
    λs, E ≥ 0; Cz ≥ 0; 0 ≤ c ≤ 1. Values that cannot be read (traced inside jit/vmap)
    are skipped; under ``jax.grad`` & co. called directly they are checked too.
    """
    rules = PHYSICAL_RULES
    for name in NAMES:
        v = readable_value(getattr(p, name))
        if v is None:
            continue
        if not np.all(np.isfinite(v)):
            shown = v[~np.isfinite(v)].ravel()[:3].tolist() if v.ndim else float(v)
            raise ValueError(f"Parameter {name} is not finite ({shown}); give a finite value.")
        if name in rules:
            ok, msg = rules[name]
            bad = ~ok(v)
            if np.any(bad):
                shown = v[bad].ravel()[:3].tolist() if v.ndim else float(v)
                raise ValueError(f"Parameter {name} = {shown} {msg}.")


def _bound_pairs(d: dict, where: str) -> tuple[dict, dict]:
    """({name: lower}, {name: upper}) of ``{name: (lower, upper)}``; TypeError (one line,
    naming the entry) for a value that is not a pair of numbers."""
    lo, hi = {}, {}
    for n, v in d.items():
        try:
            lo[n], hi[n] = (float(x) for x in v)
        except (TypeError, ValueError):
            raise TypeError(f"{where}: the bounds of {n} must be a pair (lower, upper) of "
                            f"numbers; got {v!r}.") from None
    return lo, hi


class Bounds(eqx.Module):
    """Box bounds d_r ≤ θ_r ≤ b_r (paper eq 15), as two `Parameters`:
    ``Bounds(lower, upper)``, or every parameter by name, ``Bounds(Ms=(lower, upper), …,
    Cz=(lower, upper))`` (as `from_dict`)."""

    lower: Parameters
    upper: Parameters

    def __init__(self, lower=None, upper=None, **named):
        if named:
            if lower is not None or upper is not None:
                raise TypeError("Bounds: give lower and upper (two jaxhyst.Parameters) or "
                                "every parameter by name, Bounds(Ms=(lower, upper), …), "
                                "not both.")
            lo, hi = _bound_pairs(named, "Bounds")
            lower, upper = Parameters.from_dict(lo), Parameters.from_dict(hi)
        elif lower is None or upper is None:
            raise TypeError("Bounds needs lower and upper (two jaxhyst.Parameters), or "
                            "every parameter by name: Bounds(Ms=(lower, upper), …, "
                            "Cz=(lower, upper)).")
        self.lower, self.upper = lower, upper

    def __check_init__(self):
        for which in ("lower", "upper"):
            if not isinstance(getattr(self, which), Parameters):
                raise TypeError(f"Bounds' {which} must be a jaxhyst.Parameters (or use "
                                "Bounds.from_dict({name: (lower, upper)})); got "
                                f"{type(getattr(self, which)).__name__}.")
        if not is_concrete(self):
            return  # bounds built inside a trace: nothing to inspect
        lo = np.array([np.asarray(getattr(self.lower, n), dtype=np.float64) for n in NAMES])
        hi = np.array([np.asarray(getattr(self.upper, n), dtype=np.float64) for n in NAMES])
        if not (np.all(np.isfinite(lo)) and np.all(np.isfinite(hi))):
            raise ValueError("Bounds must be finite for every parameter.")
        bad = [n for n, l_, h_ in zip(NAMES, lo, hi, strict=True) if not l_ <= h_]
        if bad:
            raise ValueError(f"Bounds have lower > upper for {bad}; swap or fix them.")
        for n, l_, h_ in zip(NAMES, lo, hi, strict=True):
            ok, rule = PHYSICAL_RULES[n]
            for which, v in (("lower", l_), ("upper", h_)):
                if not np.all(ok(v)):
                    raise ValueError(f"Bounds: the {which} bound of {n} is {float(v):g}; {n} "
                                     f"{rule}.")

    @classmethod
    def from_dict(cls, d: dict[str, tuple[float, float]]) -> Bounds:
        """``{name: (lower, upper)}`` for all ten parameters."""
        lo, hi = _bound_pairs(d, "Bounds.from_dict")
        return cls(Parameters.from_dict(lo), Parameters.from_dict(hi))

    def width(self) -> jax.Array:
        return self.upper.to_array() - self.lower.to_array()

    def contains(self, p: Parameters) -> bool:
        x = np.asarray(p.to_array())
        return bool(
            np.all(x >= np.asarray(self.lower.to_array()))
            and np.all(x <= np.asarray(self.upper.to_array()))
        )


# -- the paper's numbers ---------------------------------------------------------------

#: Table 1 "true" values of the simulation study (α̃ negative, see SPEC §3).
TABLE1_TRUE = Parameters(
    Ms=7.65e5, lambda_s=1.005e-3, a=7012.0, k=3283.0, alpha=-0.01, c=0.18,
    E=3.0e10, Kz=3.36e7, Mz=0.55, Cz=4300.0,
)  # fmt: skip

#: Table 1 search ranges.
TABLE1_BOUNDS = Bounds.from_dict(
    {
        "Ms": (7.4e5, 8.0e5),
        "lambda_s": (1.0e-3, 1.2e-3),
        "a": (3506.0, 10518.0),
        "k": (1642.0, 4925.0),
        "alpha": (-0.1, 0.0),
        "c": (0.0, 0.3),
        "E": (2.5e10, 3.5e10),
        "Kz": (3.0e7, 4.0e7),
        "Mz": (0.46, 0.62),
        "Cz": (3650.0, 4950.0),
    }
)


def _table3(Ms, lambda_s, a, k, alpha, c, Mz, Cz, E=2.22e10, Kz=2.6454e7):
    return Parameters(Ms, lambda_s, a, k, alpha, c, E, Kz, Mz, Cz)


#: Paper Table 3 (Actuator2), keyed by drive frequency in Hz. α̃ signs are lost in the
#: extracted text; negative is used (Calkins et al.). At 10 Hz the paper gives no Mz, Cz
#: (not identifiable quasi-statically); the 800 Hz values are used there.
TABLE3: dict[int, Parameters] = {
    10: _table3(7.65e5, 1.005e-3, 7012.0, 3283.0, -0.010, 0.180, 0.5443, 2011.1, E=2.220e10,
                Kz=2.6454e7),
    800: _table3(7.61e5, 1.067e-3, 7156.8, 7495.7, -0.0001, 0.172, 0.5443, 2011.1,
                 E=2.221e10, Kz=2.6455e7),
    1000: _table3(7.66e5, 1.500e-3, 8975.6, 4799.6, -0.013, 0.038, 0.5439, 2009.9,
                  E=2.220e10, Kz=2.6454e7),
    1250: _table3(7.67e5, 1.892e-3, 3458.2, 10217.0, -0.0001, 0.0003, 0.5445, 2010.0,
                  E=2.219e10, Kz=2.644e7),
    2000: _table3(7.68e5, 2.002e-3, 6771.2, 15740.0, -0.058, 0.1989, 0.5441, 2010.0,
                  E=2.222e10, Kz=2.647e7),
}
