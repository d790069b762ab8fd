"""Identification problems: the protocol every solver, the GA and the analyses use, and
the built-in problems.

**The protocol** (`AbstractProblem`). A problem has a `ParameterSpace` (``space``) and
named groups of residuals: ``group_residuals(params)`` returns, per `ResidualGroup`,
model − data in that group's unit. Everything else is defined once, here:

- the problem's residual vector r (``residuals(z, args)`` in Optimistix form, or
  ``residuals_u(u)`` in box coordinates) concatenates each group divided by its
  normaliser — its noise level σ when given (then the cost is a χ²), else
  scale·√(N/weight) (scale = max|data| in the built-in problems, the residuals' size
  in the box for a `ResidualProblem`: a mean squared error relative to the data's
  size, O(1) in any units) — followed by the priors' (θ − μ)/sd;
- the **cost** (the objective every solver minimises and every result reports) is Σ r²;
- the GA's fitness is F = 1/√(c1 + cost) (`Problem` keeps the paper's eq 35 in SI units).

A problem of your own is a subclass that implements ``space``, ``groups`` and
``group_residuals`` (and ``with_data`` for replicate fits), or a `ResidualProblem` built
from a residual function.
"""

from __future__ import annotations

import abc
import warnings
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..actuator import Actuator
from ..drive import Drive
from ..model.jiles_atherton import JAVariant
from ..model.simulate import (
    DEFAULT_SUBSTEPS,
    PAPER_VARIANT,
    Simulation,
    simulate,
    simulate_unchecked,
)
from ..params import MU0, Bounds, Parameters, check_parameters
from .measured import coarse_sampling, holds_loop
from .space import ParameterSpace, u_from_z


class SamplingWarning(UserWarning):
    """The record is sampled too coarsely for the RK4 substeps asked for."""


def _caller_level() -> int:
    """The ``stacklevel`` that points a warning raised in this module at the first frame
    outside jaxhyst and equinox (the user's line that built the problem)."""
    import inspect

    frame, level = inspect.currentframe().f_back, 1  # the function that warns
    while frame is not None and frame.f_globals.get("__name__", "").split(".")[0] in (
            "jaxhyst", "equinox"):
        frame, level = frame.f_back, level + 1
    return level

#: Observable outputs: name → (unit, function of a Simulation).
OUTPUTS = {
    "displacement": ("m", lambda sim: sim.y),
    "strain": ("1", lambda sim: sim.strain),
    "magnetostriction": ("1", lambda sim: sim.lam),
    "magnetization": ("A/m", lambda sim: sim.M),
    "flux_density": ("T", lambda sim: MU0 * (sim.H + sim.M)),
}


#: Largest magnitude of each output any magnetostrictive material or actuator shows (SI):
#: data beyond it are a unit or column mistake, refused before a fit.
PLAUSIBLE = {"displacement": 1.0, "strain": 1.0, "magnetostriction": 1.0,
             "magnetization": 1e8, "flux_density": 100.0}


_TRACED = object()


def _concrete(x):
    """``x`` as a float (None stays None), or `_TRACED` when it has no value yet."""
    if x is None:
        return None
    try:
        return float(x)
    except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError,
            jax.errors.TracerBoolConversionError):
        return _TRACED


class ResidualGroup(eqx.Module):
    """Metadata of one group of residuals (static: part of a problem's structure).

    - ``name``; ``size`` (number of residuals); ``unit`` of model − data.
    - ``sigma``: known noise standard deviation (unit); ``None`` to estimate it from the
      fit (the identifiability report does, per group).
    - ``weight``: relative weight when ``sigma`` is not given.
    - ``scale``: the data's size (unit): max|data| for a `Problem`; for a
      `ResidualProblem` the largest RMS of the group's residuals at the box's centre and
      quarter points unless given. The normaliser without sigma is scale·√(size/weight).
    """

    name: str = eqx.field(static=True)
    size: int = eqx.field(static=True)
    unit: str = eqx.field(static=True, default="")
    sigma: float | jax.Array | None = None  # (data, not structure: a new data set's σ
    weight: float = eqx.field(static=True, default=1.0)
    scale: float | jax.Array = 1.0  # and scale do not recompile a fit)

    def __check_init__(self):
        sigma, scale = _concrete(self.sigma), _concrete(self.scale)
        if sigma is _TRACED or scale is _TRACED:
            return  # (built inside a traced function from checked values)
        if sigma is not None and not (np.isfinite(sigma) and sigma > 0):
            raise ValueError(f"Residual group {self.name!r}: sigma must be a finite number "
                             f"> 0 (the noise level, {self.unit or 'data units'}); got "
                             f"{self.sigma!r}.")
        if not (np.isfinite(self.weight) and self.weight > 0):
            raise ValueError(f"Residual group {self.name!r}: weight must be > 0; got "
                             f"{self.weight!r}.")
        if not (np.isfinite(scale) and scale > 0):
            raise ValueError(f"Residual group {self.name!r}: scale must be > 0; got "
                             f"{self.scale!r}.")

    @property
    def normaliser(self) -> float | jax.Array:
        """What a residual is divided by in the problem's residual vector."""
        if self.sigma is not None:
            return self.sigma
        return self.scale * np.sqrt(self.size / self.weight)


class GaussianPrior(eqx.Module):
    """A Gaussian prior θ_name ~ N(mean, sd²) on a free parameter (SI units): adds the
    residual (θ − mean)/sd to the problem."""

    name: str = eqx.field(static=True)
    mean: float = eqx.field(static=True)
    sd: float = eqx.field(static=True)

    def __check_init__(self):
        if not (np.isfinite(self.mean) and np.isfinite(self.sd) and self.sd > 0):
            raise ValueError(f"Prior on {self.name}: mean must be finite and sd > 0; got "
                             f"mean={self.mean!r}, sd={self.sd!r}.")


class AbstractProblem(eqx.Module):
    """The protocol of an identification problem (see the module docstring).

    Subclasses provide ``space`` (a `ParameterSpace`), ``priors`` (a tuple of
    `GaussianPrior`, possibly empty), the property ``groups`` (tuple of `ResidualGroup`)
    and ``group_residuals(params)`` (tuple of arrays, one per group, model − data in the
    group's unit). ``with_data(data)`` returns the problem with other observations (same
    shapes; used by replicate fits).
    """

    space: eqx.AbstractVar[ParameterSpace]
    priors: eqx.AbstractVar[tuple]

    @property
    @abc.abstractmethod
    def groups(self) -> tuple[ResidualGroup, ...]:
        """The residual groups, in the order of `group_residuals`."""

    @abc.abstractmethod
    def group_residuals(self, params) -> tuple:
        """model − data of each group (its unit), at the parameter pytree ``params``."""

    def with_data(self, data) -> AbstractProblem:
        """This problem with other observations (the pytree ``data`` has the structure of
        `observations`)."""
        raise NotImplementedError(f"{type(self).__name__} does not support other data.")

    @property
    def observations(self):
        """The observed data (a pytree; `with_data` takes the same structure)."""
        raise NotImplementedError(f"{type(self).__name__} does not expose its data.")

    # -- defined once for every problem ------------------------------------------------------
    def _check_priors(self):
        unknown = [pr.name for pr in self.priors if pr.name not in self.space.names]
        if unknown:
            raise ValueError(f"Priors on {unknown}: not free parameters of this problem "
                             f"(free: {list(self.space.names)}).")
        if self.priors and any(g.sigma is None for g in self.groups):
            missing = [g.name for g in self.groups if g.sigma is None]
            raise ValueError(f"A problem with priors needs the noise level sigma of every "
                             f"residual group (missing for {missing}): the cost is then a "
                             "chi-square in which the prior's weight is defined.")

    @property
    def n_residuals(self) -> int:
        return sum(g.size for g in self.groups) + len(self.priors)

    def residuals_params(self, params) -> jax.Array:
        """The problem's residual vector at a parameter pytree (see the module doc)."""
        parts = [jnp.ravel(r) / g.normaliser
                 for r, g in zip(self.group_residuals(params), self.groups, strict=True)]
        if self.priors:
            x = self.space.free_values(params)
            idx = np.array([self.space.names.index(pr.name) for pr in self.priors])
            mean = np.array([pr.mean for pr in self.priors])
            sd = np.array([pr.sd for pr in self.priors])
            parts.append((x[idx] - mean) / sd)
        return jnp.concatenate(parts)

    def groups_from_residuals(self, r) -> tuple:
        """The inverse of `residuals_params` for the groups: each group's residuals (its
        unit, flattened) from the residual vector ``r`` (the priors' entries dropped)."""
        out, i = [], 0
        for g in self.groups:
            out.append(r[i:i + g.size] * g.normaliser)
            i += g.size
        return tuple(out)

    def residuals_u(self, u) -> jax.Array:
        """The residual vector at box coordinates u ∈ [0, 1]ⁿ (the GA's)."""
        return self.residuals_params(self.space.params_from_u(u))

    def residuals(self, z, args=None) -> jax.Array:
        """The residual vector at solver coordinates z: Optimistix's ``fn(y, args)``."""
        del args
        return self.residuals_u(u_from_z(z))

    def cost_u(self, u) -> jax.Array:
        """The cost Σ r² at box coordinates u."""
        return jnp.sum(self.residuals_u(u) ** 2)

    def cost(self, z, args=None) -> jax.Array:
        """The cost Σ r² at solver coordinates z (Optimistix minimiser form)."""
        del args
        return self.cost_u(u_from_z(z))

    def fitness_from_cost(self, cost, c1: float = 1e-30) -> jax.Array:
        """GA fitness F = 1/√(c1 + cost); non-finite costs get F = 0."""
        return jnp.where(jnp.isfinite(cost), 1.0 / jnp.sqrt(c1 + cost), 0.0)


class Problem(AbstractProblem):
    """Identify `Parameters` from one observed signal of one drive.

    **Arguments:**
    - ``data``: observed samples, shape (T_obs,), in the unit of ``output``; aligned with
      the drive's observed samples (after its run-in).
    - ``drive``: the `Drive` that produced the data (t in s, H in A/m).
    - ``actuator``: known `Actuator` constants.
    - ``space``: a `ParameterSpace` (bounds, free and fixed parameters).
    - ``output``: one of ``displacement`` (m), ``strain``, ``magnetostriction``,
      ``magnetization`` (A/m), ``flux_density`` (T, B = μ0(H + M)).
    - ``variant``, ``substeps``: model settings, as in `simulate`.
    - ``sigma``: the data's noise level (unit of ``output``) if known; ``priors``: a
      sequence of `GaussianPrior` (needs ``sigma``).
    - ``require_full_period``: refuse data whose field holds no loop (the turning-point
      rule of `jaxhyst.identify.measured`: noise reversals below 5 % of the range do not
      count), which cannot determine a hysteresis loop.

    Warns (`SamplingWarning`) when the field moves more than 1 % of its range per RK4
    substep, where the documented accuracy no longer holds.
    """

    data: jax.Array
    drive: Drive
    actuator: Actuator
    space: ParameterSpace
    scale: jax.Array  # max|data| (0-d; data, so a new data set does not recompile)
    output: str = eqx.field(static=True, default="displacement")
    variant: JAVariant = PAPER_VARIANT
    substeps: int = eqx.field(static=True, default=DEFAULT_SUBSTEPS)
    sigma: jax.Array | None = None  # the noise level (0-d), if known
    priors: tuple = eqx.field(static=True, default=())

    def __init__(self, data, drive: Drive, actuator: Actuator, space: ParameterSpace,
                 output: str = "displacement", variant: JAVariant = PAPER_VARIANT,
                 substeps: int = DEFAULT_SUBSTEPS, require_full_period: bool = True,
                 sigma: float | None = None, priors: Sequence[GaussianPrior] = ()):
        if output not in OUTPUTS:
            raise ValueError(f"Unknown output {output!r}; choose one of {list(OUTPUTS)}.")
        if not isinstance(drive, Drive):
            raise TypeError(f"drive must be a jaxhyst.Drive; got {type(drive).__name__}.")
        if not isinstance(space, ParameterSpace):
            raise TypeError("space must be a jaxhyst.ParameterSpace (bounds + fixed values).")
        data = np.asarray(data, dtype=np.float64)
        if data.ndim != 1:
            raise ValueError(f"data must be 1-D (one observed signal); got shape {data.shape}.")
        if data.shape[0] != drive.n_observed:
            raise ValueError(
                f"data has {data.shape[0]} samples but the drive observes {drive.n_observed} "
                f"(it has {drive.n_samples} samples, {drive.run_in} of them run-in); give one "
                "data sample per observed drive sample."
            )
        if not np.all(np.isfinite(data)):
            bad = np.flatnonzero(~np.isfinite(data))[:5].tolist()
            raise ValueError(f"data contain NaN or inf at samples {bad}; remove or repair them.")
        H_obs = np.asarray(drive.observed(drive.H))
        if require_full_period and not holds_loop(H_obs):
            raise ValueError(
                "The observed field holds no hysteresis loop: after its first turning point "
                "(a reversal larger than 5 % of its range) it must sweep back over 90 % of "
                "its range. Observe a whole period or loop (or pass "
                "require_full_period=False)."
            )
        coarse = coarse_sampling(H_obs, int(substeps))
        if coarse is not None:
            warnings.warn(coarse, SamplingWarning, stacklevel=_caller_level())
        big = np.flatnonzero(np.abs(data) > PLAUSIBLE[output])
        if big.size:
            i = int(big[0])
            raise ValueError(
                f"data[{i}] = {data[i]:g} {OUTPUTS[output][0]} is beyond any {output} "
                f"(|value| <= {PLAUSIBLE[output]:g} {OUTPUTS[output][0]}); check the unit "
                "and the column of that sample.")
        scale = float(np.max(np.abs(data)))
        if scale == 0.0:
            raise ValueError("data are identically zero; nothing to fit.")
        self.data = jnp.asarray(data)
        self.drive = drive
        self.actuator = actuator
        self.space = space
        self.scale = jnp.asarray(scale, dtype=jnp.float64)
        self.output = output
        self.variant = variant
        self.substeps = int(substeps)
        self.sigma = None if sigma is None else jnp.asarray(float(sigma), dtype=jnp.float64)
        self.priors = tuple(priors)
        self._check_priors()

    # -- model ----------------------------------------------------------------------
    def simulate(self, params: Parameters) -> Simulation:
        return simulate_unchecked(params, self.actuator, self.drive, self.variant,
                                  self.substeps)

    def predict(self, params: Parameters) -> jax.Array:
        """The model's observed output at ``params`` (unit of ``output``)."""
        return self.drive.observed(OUTPUTS[self.output][1](self.simulate(params)))

    @property
    def unit(self) -> str:
        """Unit of the observed output."""
        return OUTPUTS[self.output][0]

    @property
    def groups(self) -> tuple[ResidualGroup, ...]:
        return (ResidualGroup(self.output, int(self.data.shape[0]), self.unit, self.sigma,
                              scale=self.scale),)

    def group_residuals(self, params) -> tuple:
        return (self.predict(params) - self.data,)

    @property
    def observations(self):
        return self.data

    def with_data(self, data) -> Problem:
        return eqx.tree_at(lambda q: q.data, self, jnp.asarray(data, dtype=jnp.float64))

    def with_fixed(self, fixed: dict[str, float]) -> Problem:
        """The same problem with the parameters in ``fixed`` ({name: SI value}) held fixed:
        the reparameterisation an `IdentifiabilityReport.suggest_fixed` asks for."""
        return eqx.tree_at(lambda q: q.space, self,
                           self.space.with_fixed({n: float(v) for n, v in fixed.items()}))

    def objective(self, params: Parameters) -> jax.Array:
        """The paper's E(θ) = Σ_k (y(k) − ỹ(k, θ))² (eq 15), in the output's unit squared."""
        return jnp.sum((self.predict(params) - self.data) ** 2)

    def fitness_from_cost(self, cost, c1: float = 1e-30) -> jax.Array:
        """The paper's F = 1/√(c1 + E) (eq 35), E in SI units recovered from the cost
        (E = cost·normaliser² without priors). Non-finite costs get F = 0."""
        if self.priors:
            return super().fitness_from_cost(cost, c1)
        E = cost * self.groups[0].normaliser ** 2
        return jnp.where(jnp.isfinite(E), 1.0 / jnp.sqrt(c1 + E), 0.0)


class ResidualProblem(AbstractProblem):
    """A problem from your own residual function.

    **Arguments:**
    - ``fn``: ``fn(params, data) -> {group name: residuals}`` (or one array, the group
      ``"residuals"``): model − data in each group's unit; ``params`` is the pytree the
      ``space`` describes, ``data`` whatever you pass (a pytree of arrays).
    - ``space``: a `ParameterSpace` (`ParameterSpace(bounds, fixed)` for `Parameters`,
      `ParameterSpace.for_tree` for any pytree).
    - ``data``: passed to ``fn``; replicate fits replace it.
    - ``groups``: ``{name: {"sigma": …, "weight": …, "unit": …, "scale": …}}`` (all
      optional; sizes come from ``fn``). A group given neither ``sigma`` nor ``scale``
      is scaled by the largest RMS of its residuals at the centre and the quarter
      points of the box (``fn`` evaluated there on construction), so that residuals in
      any unit reach the solvers at order one.
    - ``priors``: `GaussianPrior` terms (need every group's sigma).
    """

    fn: Callable = eqx.field(static=True)
    space: ParameterSpace
    data: object
    group_spec: tuple = eqx.field(static=True)
    priors: tuple = eqx.field(static=True, default=())
    single: bool = eqx.field(static=True, default=False)

    def __init__(self, fn: Callable, space: ParameterSpace, data=None,
                 groups: dict | None = None, priors: Sequence[GaussianPrior] = ()):
        if not callable(fn):
            raise TypeError("fn must be a function fn(params, data) -> residuals.")
        if not isinstance(space, ParameterSpace):
            raise TypeError("space must be a jaxhyst.ParameterSpace.")
        self.fn = fn
        self.space = space
        self.data = data
        probe = space.params_from_u(jnp.full(space.n_free, 0.5))
        try:
            out = jax.eval_shape(fn, probe, data)
        except Exception as err:  # noqa: BLE001 - report the user's error in one line
            raise ValueError(f"fn(params, data) failed at the centre of the box: "
                             f"{type(err).__name__}: {err}") from None
        single = not isinstance(out, dict)
        shapes = {"residuals": out} if single else dict(out)
        spec = dict(groups or {})
        unknown = sorted(set(spec) - set(shapes))
        if unknown:
            raise ValueError(f"groups {unknown} are not returned by fn (it returns "
                             f"{sorted(shapes)}).")
        for name in shapes:
            bad = sorted(set(spec.get(name, {})) - {"sigma", "weight", "unit", "scale"})
            if bad:
                raise ValueError(f"group {name!r}: unknown options {bad} (use sigma, "
                                 "weight, unit, scale).")
        unscaled = [n for n in shapes if not {"sigma", "scale"} & set(spec.get(n, {}))]
        sizes = _residual_sizes(fn, space, data, single, unscaled) if unscaled else {}
        built = []
        for name, s in shapes.items():
            opts = dict(spec.get(name, {}))
            if name in sizes:
                opts["scale"] = sizes[name]
            built.append(ResidualGroup(name, int(np.prod(s.shape)), **opts))
        self.group_spec = tuple(built)
        self.priors = tuple(priors)
        self.single = single
        self._check_priors()

    @property
    def groups(self) -> tuple[ResidualGroup, ...]:
        return self.group_spec

    def group_residuals(self, params) -> tuple:
        out = self.fn(params, self.data)
        if self.single:
            return (out,)
        return tuple(out[g.name] for g in self.group_spec)

    @property
    def observations(self):
        return self.data

    def with_data(self, data) -> ResidualProblem:
        return eqx.tree_at(lambda q: q.data, self, data, is_leaf=lambda x: x is None)


def _residual_sizes(fn, space, data, single: bool, names) -> dict:
    """The largest RMS of each named group's residuals at the centre of the box and at
    its quarter points (u = 0.5, 0.25, 0.75 in every coordinate): the scale of a group
    given neither sigma nor scale, so that the solvers see residuals of order one
    whatever their unit (residuals in metres, ~1e-6, would make an LM step ~1e-12 and
    end the solve at its start as "converged"). 1 where no point gives a finite
    positive value."""
    sizes = dict.fromkeys(names, 0.0)
    evaluate = jax.jit(fn)
    for u in (0.5, 0.25, 0.75):
        try:
            out = evaluate(space.params_from_u(jnp.full(space.n_free, u)), data)
            out = {"residuals": out} if single else out
            values = {name: np.asarray(out[name], dtype=np.float64) for name in names}
        except Exception:  # noqa: BLE001 - the solve will report the user's error (or,
            continue  # built inside a trace, the values are not known: scale 1)
        for name, r in values.items():
            rms = float(np.sqrt(np.mean(np.square(r)))) if r.size else 0.0
            if np.isfinite(rms):
                sizes[name] = max(sizes[name], rms)
    return {name: size if size > 0 else 1.0 for name, size in sizes.items()}


def synthetic_problem(params: Parameters, drive: Drive, actuator: Actuator, bounds: Bounds,
                      fixed: Sequence[str] | dict | None = None, output: str = "displacement",
                      noise: float = 0.0, key=None, **kwargs) -> Problem:
    """A problem whose data are simulated at ``params`` (plus Gaussian noise of standard
    deviation ``noise``, in the output's unit). ``fixed`` lists parameter names to hold at
    their values in ``params`` (or gives ``{name: value}``)."""
    check_parameters(params)
    if fixed is not None and not isinstance(fixed, dict):
        fixed = {n: float(getattr(params, n)) for n in fixed}
    space = ParameterSpace(bounds, fixed)
    # compiled as one program (op by op, the first call compiled ~150 small programs)
    sim = simulate(params, actuator, drive, kwargs.get("variant", PAPER_VARIANT),
                   kwargs.get("substeps", DEFAULT_SUBSTEPS))
    # the observed part sliced in NumPy (eagerly, JAX would compile the slice on its own)
    data = np.asarray(OUTPUTS[output][1](sim))[drive.run_in:]
    if noise:
        if key is None:
            raise ValueError("noise > 0 needs a jax.random key for reproducibility.")
        data = data + noise * jax.random.normal(key, data.shape)
    return Problem(data, drive, actuator, space, output=output, **kwargs)
