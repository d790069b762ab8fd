"""An identification problem: data + model + parameter space → residuals in scaled
coordinates (Optimistix form ``fn(z, args)``), the paper's objective E(θ) and fitness F.

Coordinates. The GA and users think in u ∈ [0, 1]ⁿ (θ = d + (b − d)·u, the box of eq 15);
the unconstrained Optimistix solvers work in z ∈ ℝⁿ with the periodic map

    u = (1 + sin z) / 2,

as in MINUIT and lmfit. Every z maps inside the box, so bounds hold by construction for
every solver, and unlike a sigmoid the map never saturates: a solver pushed against a
bound oscillates in z instead of drifting to ±∞ (SPEC §5 measured sigmoid runs stuck at a
bound). Parameters not listed as free are held at fixed values, exactly.

Normalisation. r = (model − data) / (scale·√N) with scale = max|data|, so the cost
Σr² is the mean squared error relative to the data's magnitude: O(1) in any units.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..actuator import Actuator
from ..drive import Drive
from ..model.jiles_atherton import JAVariant
from ..model.simulate import DEFAULT_SUBSTEPS, PAPER_VARIANT, Simulation, simulate_unchecked
from ..params import NAMES, Bounds, Parameters, check_parameters

MU0 = 4e-7 * np.pi  # vacuum permeability, H/m

#: Observable outputs: name → (unit, function of a Simulation).
OUTPUTS = {
    "displacement": ("m", lambda sim: sim.y),
    "strain": ("1", lambda sim: sim.strain),
    "magnetostriction": ("1", lambda sim: sim.lam),
    "magnetization": ("A/m", lambda sim: sim.M),
    "flux_density": ("T", lambda sim: MU0 * (sim.H + sim.M)),
}


def u_from_z(z):
    """Box coordinate u ∈ [0, 1] from the unconstrained z (periodic sine map)."""
    return 0.5 * (1.0 + jnp.sin(z))


def z_from_u(u):
    """The z ∈ [−π/2, π/2] that maps to u (inverse of `u_from_z` on its principal branch)."""
    return jnp.arcsin(jnp.clip(2.0 * jnp.asarray(u) - 1.0, -1.0, 1.0))


class ParameterSpace(eqx.Module):
    """Which parameters are free, their bounds, and the values of the fixed ones.

    **Arguments:**
    - ``bounds``: `Bounds` for all ten parameters (only the free ones' are used).
    - ``fixed``: ``{name: value}`` of parameters held fixed (SI units); default none.
    """

    lower: jax.Array
    upper: jax.Array
    base: jax.Array  # all ten values; free entries are overwritten
    free: tuple[int, ...] = eqx.field(static=True)

    def __init__(self, bounds: Bounds, fixed: dict[str, float] | None = None):
        fixed = dict(fixed or {})
        unknown = [n for n in fixed if n not in NAMES]
        if unknown:
            raise ValueError(f"Cannot fix unknown parameter(s) {unknown}; names are {list(NAMES)}.")
        self.free = tuple(i for i, n in enumerate(NAMES) if n not in fixed)
        if not self.free:
            raise ValueError(
                "All ten parameters are fixed: there is nothing to identify. Free at least "
                "one parameter (remove it from `fixed`)."
            )
        lo = np.asarray(bounds.lower.to_array())
        hi = np.asarray(bounds.upper.to_array())
        base = 0.5 * (lo + hi)
        for n, v in fixed.items():
            if not np.isfinite(v):
                raise ValueError(f"Fixed value of {n} is not finite ({v!r}).")
            base[NAMES.index(n)] = float(v)
        self.lower = jnp.asarray(lo[list(self.free)])
        self.upper = jnp.asarray(hi[list(self.free)])
        self.base = jnp.asarray(base)

    @property
    def fixed(self) -> dict[str, float]:
        """``{name: value}`` of the parameters held fixed."""
        base = np.asarray(self.base)
        return {n: float(base[i]) for i, n in enumerate(NAMES) if i not in self.free}

    def bounds(self) -> Bounds:
        """`Bounds` of all ten parameters (a fixed one's lower = upper = its value)."""
        lo, hi = np.array(self.base), np.array(self.base)
        lo[list(self.free)] = np.asarray(self.lower)
        hi[list(self.free)] = np.asarray(self.upper)
        return Bounds(Parameters.from_array(jnp.asarray(lo)),
                      Parameters.from_array(jnp.asarray(hi)))

    def with_fixed(self, fixed: dict[str, float]) -> ParameterSpace:
        """This space with the parameters in ``fixed`` also held fixed (at those values)."""
        return ParameterSpace(self.bounds(), {**self.fixed, **fixed})

    @property
    def names(self) -> tuple[str, ...]:
        """Names of the free parameters, in the order of z and u."""
        return tuple(NAMES[i] for i in self.free)

    @property
    def n_free(self) -> int:
        return len(self.free)

    def theta_from_u(self, u) -> jax.Array:
        """All ten SI values (shape (..., 10)) from box coordinates u of the free ones."""
        free = self.lower + (self.upper - self.lower) * u
        full = jnp.broadcast_to(self.base, free.shape[:-1] + (len(NAMES),))
        return full.at[..., jnp.array(self.free)].set(free)

    def params_from_free(self, x) -> Parameters:
        """`Parameters` with the free entries set to ``x`` (SI values, shape (..., n_free))."""
        x = jnp.asarray(x)
        full = jnp.broadcast_to(self.base, x.shape[:-1] + (len(NAMES),))
        return Parameters.from_array(full.at[..., jnp.array(self.free)].set(x))

    def free_values(self, params: Parameters) -> jax.Array:
        """The free entries of ``params`` (SI values), in the order of `names`."""
        return params.to_array()[..., jnp.array(self.free)]

    def params_from_u(self, u) -> Parameters:
        return Parameters.from_array(self.theta_from_u(u))

    def params_from_z(self, z) -> Parameters:
        return self.params_from_u(u_from_z(z))

    def u_from_params(self, params: Parameters) -> jax.Array:
        """Box coordinates of the free parameters of ``params`` (clipped into [0, 1])."""
        x = params.to_array()[..., jnp.array(self.free)]
        width = jnp.where(self.upper > self.lower, self.upper - self.lower, 1.0)
        return jnp.clip((x - self.lower) / width, 0.0, 1.0)

    def z_from_params(self, params: Parameters) -> jax.Array:
        return z_from_u(self.u_from_params(params))


def _sweeps_a_loop(H) -> bool:
    """True if, after its first reversal, the field sweeps back over at least 90 % of its
    observed range: a closed loop, whether it starts at a tip or mid-branch (a window
    that merely turns round near a tip does not determine a loop)."""
    H = np.asarray(H)
    dH = np.diff(H)
    moving = np.flatnonzero(dH != 0)
    if moving.size == 0:
        return False
    s = np.sign(dH[moving])
    turns = np.flatnonzero(s[1:] != s[:-1])
    if turns.size == 0:
        return False
    r = moving[turns[0] + 1]  # sample index where the field turned
    span = float(np.max(H) - np.min(H))
    return float(np.max(np.abs(H[r:] - H[r]))) >= 0.9 * span


class Problem(eqx.Module):
    """Identify parameters from one observed signal.

    **Arguments:**
    - ``data``: observed samples, shape (T_obs,), in the unit of ``output``; aligned with
      the drive's observed samples (after its run-in).
    - ``drive``: the `Drive` that produced the data (t in s, H in A/m).
    - ``actuator``: known `Actuator` constants.
    - ``space``: a `ParameterSpace` (bounds, free and fixed parameters).
    - ``output``: one of ``displacement`` (m), ``strain``, ``magnetostriction``,
      ``magnetization`` (A/m), ``flux_density`` (T, B = μ0(H + M)).
    - ``variant``, ``substeps``: model settings, as in `simulate`.
    - ``require_full_period``: refuse data whose field does not rise and fall (less than
      one period of a periodic drive), which cannot determine a hysteresis loop.
    """

    data: jax.Array
    drive: Drive
    actuator: Actuator
    space: ParameterSpace
    scale: float = eqx.field(static=True)
    output: str = eqx.field(static=True, default="displacement")
    variant: JAVariant = PAPER_VARIANT
    substeps: int = eqx.field(static=True, default=DEFAULT_SUBSTEPS)

    def __init__(self, data, drive: Drive, actuator: Actuator, space: ParameterSpace,
                 output: str = "displacement", variant: JAVariant = PAPER_VARIANT,
                 substeps: int = DEFAULT_SUBSTEPS, require_full_period: bool = True):
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
        if require_full_period and not _sweeps_a_loop(drive.observed(drive.H)):
            raise ValueError(
                "The observed data cover less than one period of the drive: the field must "
                "rise and fall within the observed window to determine a hysteresis loop. "
                "Observe a whole period (or pass require_full_period=False)."
            )
        scale = float(np.max(np.abs(data)))
        if scale == 0.0:
            raise ValueError("data are identically zero; nothing to fit.")
        self.data = jnp.asarray(data)
        self.drive = drive
        self.actuator = actuator
        self.space = space
        self.scale = scale
        self.output = output
        self.variant = variant
        self.substeps = int(substeps)

    # -- model ----------------------------------------------------------------------
    def simulate(self, params: Parameters) -> Simulation:
        return simulate_unchecked(params, self.actuator, self.drive, self.variant, self.substeps)

    def predict(self, params: Parameters) -> jax.Array:
        """The model's observed output at ``params`` (unit of ``output``)."""
        return self.drive.observed(OUTPUTS[self.output][1](self.simulate(params)))

    def predict_free(self, x) -> jax.Array:
        """`predict` as a function of the free parameters' SI values ``x`` (n_free,)."""
        return self.predict(self.space.params_from_free(x))

    @property
    def unit(self) -> str:
        """Unit of the observed output."""
        return OUTPUTS[self.output][0]

    @property
    def sample_scale(self) -> float:
        """Normalisation of each residual (max|data|; per loop in a `JointProblem`)."""
        return self.scale

    def with_fixed(self, fixed: dict[str, float]) -> Problem:
        """The same problem with the parameters in ``fixed`` ({name: SI value}) held fixed:
        the reparameterisation an `IdentifiabilityReport.suggest_fixed` asks for, e.g.
        ``problem.with_fixed({n: getattr(result.params, n) for n in report.suggest_fixed()})``.
        """
        return eqx.tree_at(lambda q: q.space, self,
                           self.space.with_fixed({n: float(v) for n, v in fixed.items()}))

    # -- what the solvers see ---------------------------------------------------------
    def residuals(self, z, args=None) -> jax.Array:
        """Normalised residuals r(z) = (model − data)/(scale·√N), shape (N,): Optimistix's
        ``fn(y, args)`` for least squares in the unconstrained coordinates z."""
        del args
        return self.residuals_u(u_from_z(z))

    def residuals_u(self, u) -> jax.Array:
        """As `residuals`, in box coordinates u ∈ [0, 1]ⁿ (the GA's)."""
        r = self.predict(self.space.params_from_u(u)) - self.data
        return r / (self.scale * np.sqrt(self.data.shape[0]))

    def cost_u(self, u) -> jax.Array:
        """Normalised cost Σ r² at box coordinates u (the GA's fitness input)."""
        return jnp.sum(self.residuals_u(u) ** 2)

    def cost(self, z) -> jax.Array:
        """Normalised cost Σ r² (dimensionless; 0 at a perfect fit)."""
        return self.cost_u(u_from_z(z))

    def objective(self, params: Parameters) -> jax.Array:
        """The paper's E(θ) = Σ_k (y(k) − ỹ(k, θ))² (eq 15), in the output's unit squared."""
        return jnp.sum((self.predict(params) - self.data) ** 2)

    def fitness_from_cost(self, cost, c1: float = 1e-30) -> jax.Array:
        """The paper's F = 1/√(c1 + E) (eq 35) computed from the normalised cost, with E in
        SI units (E = cost·scale²·N). Non-finite costs get F = 0."""
        E = cost * self.scale**2 * self.data.shape[0]
        return jnp.where(jnp.isfinite(E), 1.0 / jnp.sqrt(c1 + E), 0.0)


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
    sim = simulate_unchecked(params, actuator, drive, kwargs.get("variant", PAPER_VARIANT),
                             kwargs.get("substeps", DEFAULT_SUBSTEPS))
    data = drive.observed(OUTPUTS[output][1](sim))
    if noise:
        if key is None:
            raise ValueError("noise > 0 needs a jax.random key for reproducibility.")
        data = data + noise * jax.random.normal(key, data.shape)
    return Problem(data, drive, actuator, space, output=output, **kwargs)
