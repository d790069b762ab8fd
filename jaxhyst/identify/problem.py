"""Identification problems: the protocol every solver, the GA and the analyses use, and
a problem from your own residual function (`ResidualProblem`). The built-in problems are
`jaxhyst.identify.signal.Problem` (one signal of one drive) and
`jaxhyst.identify.joint.JointProblem` (several loops).

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
- the GA's fitness is F = 1/√(c1 + E) with E the sum of squared residuals in the data's
  unit for a problem of one group without priors (the paper's eq 35), else the cost.

A problem of your own is a final subclass of `AbstractProblem` that implements ``space``,
``priors``, ``output``, ``groups``, ``group_residuals``, ``observations`` and
``with_data`` (the last two for replicate fits: ``raise NotImplementedError`` if yours
has no data to replace), or a `ResidualProblem` built from a residual function.
"""

import abc
from collections.abc import Callable, Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._traces import kept_jit
from .._typing import Array, Float
from .space import ParameterSpace, u_from_z

_TRACED = object()


def _host_float(x):
    """A static number as a Python float (a NumPy or JAX scalar kept as structure would
    be an array set as static); anything else is left for the checks to name."""
    try:
        return float(x)
    except (TypeError, ValueError, jax.errors.ConcretizationTypeError):
        return x


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

    - ``name``; ``size`` (number of residuals: the length of the group's entry in the
      residual vector); ``unit`` of model − data.
    - ``valid``: None (every residual observed), or a boolean array of shape (size,)
      marking the observed ones (data, not structure: padding for a common shape, so that
      problems whose groups observe different numbers of samples share one program). The
      group's residuals must be 0 where it is False; every statistic counts only the
      observed ones (``count``; `observed`).
    - ``sigma``: known noise standard deviation (unit); ``None`` to estimate it from the
      fit (the identifiability report does, per group).
    - ``weight``: relative weight when ``sigma`` is not given.
    - ``scale``: the data's size (unit): max|data| for a `Problem`; for a
      `ResidualProblem` the largest RMS of the group's residuals at the box's centre and
      quarter points unless given. The normaliser without sigma is scale·√(count/weight).
    - ``data_size``: max|data| of the group (unit) where the problem knows it (the
      built-in problems), else None: results say how far a fit is from its data.
    """

    name: str = eqx.field(static=True)
    size: int = eqx.field(static=True)
    unit: str = eqx.field(static=True, default="")
    sigma: float | jax.Array | None = None  # (data, not structure: a new data set's σ
    weight: float = eqx.field(static=True, default=1.0, converter=_host_float)
    scale: float | jax.Array = 1.0  # and scale do not recompile a fit)
    data_size: float | jax.Array | None = None
    valid: jax.Array | None = None

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
    def count(self) -> int | jax.Array:
        """The number of observed residuals (``size`` unless ``valid`` marks padding; a
        traced number inside a traced function)."""
        if self.valid is None:
            return self.size
        try:
            return int(np.sum(np.asarray(self.valid)))
        except (jax.errors.ConcretizationTypeError, jax.errors.TracerArrayConversionError):
            return jnp.sum(self.valid)

    def observed(self, r):
        """The observed entries of this group's residuals ``r`` (host arrays: NumPy)."""
        r = np.asarray(r).ravel()
        return r if self.valid is None else r[np.asarray(self.valid, bool).ravel()]

    @property
    def normaliser(self) -> float | jax.Array:
        """What a residual is divided by in the problem's residual vector."""
        if self.sigma is not None:
            return self.sigma
        count = self.count
        root = np.sqrt if isinstance(count, int) else jnp.sqrt
        return self.scale * root(count / self.weight)


class GaussianPrior(eqx.Module):
    """A Gaussian prior θ_name ~ N(mean, sd²) on a free parameter (SI units): adds the
    residual (θ − mean)/sd to the problem."""

    name: str = eqx.field(static=True)
    mean: float = eqx.field(static=True, converter=_host_float)
    sd: float = eqx.field(static=True, converter=_host_float)

    def __check_init__(self):
        if not all(isinstance(v, float) for v in (self.mean, self.sd)) or not (
                np.isfinite(self.mean) and np.isfinite(self.sd) and self.sd > 0):
            raise ValueError(f"Prior on {self.name}: mean must be finite and sd > 0; got "
                             f"mean={self.mean!r}, sd={self.sd!r}.")


#: What the solvers, the GA and the analyses use of a problem (`AbstractProblem`).
PROTOCOL = ("space", "priors", "groups", "group_residuals", "residuals", "residuals_u",
            "cost", "observations", "with_data")


def check_problem(problem, what: str = "problem") -> None:
    """A one-line ``TypeError`` before any work if ``problem`` lacks part of the protocol
    (a problem written by hand without subclassing `AbstractProblem`)."""
    if isinstance(problem, AbstractProblem):
        return
    missing = [name for name in PROTOCOL if not hasattr(problem, name)]
    if missing:
        raise TypeError(f"{what} is a {type(problem).__name__}, which lacks {missing} of the "
                        "problem protocol: subclass jaxhyst.identify.AbstractProblem (it "
                        "defines everything but space, priors, output, groups, "
                        "group_residuals, observations and with_data), or build a "
                        "jaxhyst.ResidualProblem from your residual function.")


def content_digest(problem) -> str:
    """A digest of everything ``problem`` holds (its tree structure, every array's bytes,
    every other leaf's repr): equal for the same problem, different where its data, drive,
    box or settings differ — what a fit's `IdentificationResult.linearization` is tied
    to."""
    import hashlib

    leaves, treedef = jax.tree_util.tree_flatten(problem)
    h = hashlib.sha1(str(treedef).encode())
    for leaf in leaves:
        if isinstance(leaf, (np.ndarray, jax.Array)):
            a = np.asarray(leaf)
            h.update(f"{a.dtype}{a.shape}".encode())
            h.update(np.ascontiguousarray(a).tobytes())
        else:
            h.update(repr(leaf).encode())
    return h.hexdigest()


@kept_jit
def cost_at(problem, z) -> jax.Array:
    """``problem.cost(z)`` by one compiled program, for host code that needs a cost at a
    point (called op by op, a cost compiles a simulation program and a few dozen single
    operations in every process)."""
    return problem.cost(z)


class AbstractProblem(eqx.Module):
    """The protocol of an identification problem (see the module docstring).

    A final subclass provides ``space`` (a `ParameterSpace`), ``priors`` (a tuple of
    `GaussianPrior`, possibly empty), ``output`` (what it observes, in words: a name of
    `jaxhyst.identify.outputs.OUTPUTS` for the built-in problems), the property
    ``groups`` (tuple of `ResidualGroup`), ``group_residuals(params)`` (tuple of arrays,
    one per group, model − data in the group's unit), ``observations`` (the data, a
    pytree) and ``with_data(data)`` (the problem with other observations of the same
    shapes; used by replicate fits). The rest is defined here, once.
    """

    space: eqx.AbstractVar[ParameterSpace]
    priors: eqx.AbstractVar[tuple]
    output: eqx.AbstractVar[str]

    @property
    @abc.abstractmethod
    def groups(self) -> tuple[ResidualGroup, ...]:
        """The residual groups, in the order of `group_residuals`."""

    @abc.abstractmethod
    def group_residuals(self, params) -> tuple:
        """model − data of each group (its unit), at the parameter pytree ``params``."""

    @property
    @abc.abstractmethod
    def observations(self):
        """The observed data (a pytree; `with_data` takes the same structure)."""

    @abc.abstractmethod
    def with_data(self, data) -> "AbstractProblem":
        """This problem with other observations (the pytree ``data`` has the structure of
        `observations`)."""

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
        """The length of the residual vector (padding included)."""
        return sum(g.size for g in self.groups) + len(self.priors)

    @property
    def n_observed(self) -> int:
        """The number of observed residuals (the statistics' N: padding excluded)."""
        return sum(int(g.count) for g in self.groups) + len(self.priors)

    def residuals_params(self, params) -> Float[Array, " R"]:
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

    def residuals_u(self, u: Float[Array, " n"]) -> Float[Array, " R"]:
        """The residual vector at box coordinates u ∈ [0, 1]ⁿ (the GA's)."""
        return self.residuals_params(self.space.params_from_u(u))

    def residuals(self, z: Float[Array, " n"], args=None) -> Float[Array, " R"]:
        """The residual vector at solver coordinates z: Optimistix's ``fn(y, args)``."""
        del args
        return self.residuals_u(u_from_z(z))

    def cost_u(self, u: Float[Array, " n"]) -> Float[Array, ""]:
        """The cost Σ r² at box coordinates u."""
        return jnp.sum(self.residuals_u(u) ** 2)

    def cost(self, z: Float[Array, " n"], args=None) -> Float[Array, ""]:
        """The cost Σ r² at solver coordinates z (Optimistix minimiser form)."""
        del args
        return self.cost_u(u_from_z(z))

    def fitness_from_cost(self, cost, c1: float = 1e-30) -> jax.Array:
        """GA fitness F = 1/√(c1 + E); non-finite costs get F = 0. E is the paper's
        E(θ) = Σ(y − ỹ)² in the data's unit (eq 35; recovered from the cost as
        cost·normaliser²) for a problem of one residual group without priors, else the
        cost itself."""
        E = cost
        if len(self.groups) == 1 and not self.priors:
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
    output: str = eqx.field(static=True, default="residuals")

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

    def with_data(self, data) -> "ResidualProblem":
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
