"""`simulate`: the one function that owns the time loop (a ``lax.scan`` over samples).

Per sample interval [t_i, t_{i+1}] the field is linear in time and its direction
δ = sign(H_{i+1} − H_i) is fixed. The interval is split into ``substeps`` equal parts;
on each, M is advanced by classic RK4 *in H* (the JA model is rate independent), and the
structural state [y, ẏ] by the exact discretization of `structure` with λ(t) as its
cubic Hermite interpolant. Both are 4th order, so the error falls ~16× per doubling of
``substeps`` except near the kink of dM/dH where δM switches on after a reversal.
The initial state is demagnetized and at rest: M = 0, y = ẏ = 0 at t_0.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from ..actuator import Actuator
from ..drive import Drive
from ..params import Parameters, check_parameters
from .jiles_atherton import EnergyBasedJA, JAVariant, anhysteretic
from .magnetostriction import magnetostriction, magnetostriction_rate
from .structure import cubic_hold_discretization, hermite_taylor_coefficients

DEFAULT_SUBSTEPS = 2
PAPER_VARIANT = EnergyBasedJA()  # immutable Module: a safe shared default


class Simulation(eqx.Module):
    """Every signal of one simulation, per drive sample, shape (T,) (or (P, T) batched).

    - ``t``: time, s;  ``H``: applied field, A/m
    - ``M``: magnetization, A/m; ``Man``: anhysteretic, A/m; ``Mirr``: irreversible, A/m
    - ``lam``: magnetostriction λ, 1
    - ``y``: output displacement, m; ``velocity``: ẏ, m/s; ``strain``: ε = y/lr, 1
    - ``run_in``: leading samples that belong to the run-in (use ``observed``).
    """

    t: jax.Array
    H: jax.Array
    M: jax.Array
    Man: jax.Array
    Mirr: jax.Array
    lam: jax.Array
    y: jax.Array
    velocity: jax.Array
    strain: jax.Array
    run_in: int = eqx.field(static=True, default=0)

    def observed(self, name: str = "y") -> jax.Array:
        """A signal without its run-in samples, e.g. ``sim.observed("y")``."""
        return getattr(self, name)[..., self.run_in :]

    @property
    def finite(self) -> jax.Array:
        """True where every signal is finite (False flags a diverged parameter set)."""
        return jnp.isfinite(self.M).all(-1) & jnp.isfinite(self.y).all(-1)


def _rk4(f, H, M, dH, k1):
    """One classic RK4 step of dM/dH = f(H, M) from (H, M) over dH, given k1 = f(H, M)."""
    k2 = f(H + 0.5 * dH, M + 0.5 * dH * k1)
    k3 = f(H + 0.5 * dH, M + 0.5 * dH * k2)
    k4 = f(H + dH, M + dH * k3)
    return M + (dH / 6.0) * (k1 + 2.0 * k2 + 2.0 * k3 + k4)


def _substep_magnetization(variant, p, delta, H, M, dH, k1):
    """Advance M over one substep, splitting it where δM switches on.

    After a field reversal the irreversible term is suppressed until Man − M changes sign;
    there dM/dH has a kink (M is only C¹) and an RK4 step across it loses three orders.
    If the plain step ends on the other side of the switch, the switch point is found by
    linear interpolation of δ·(Man − M) and the substep is redone as a purely reversible
    RK4 step up to it and a normal RK4 step after it. ``lax.cond`` keeps the redo off the
    common path for single trajectories (under vmap both branches run).
    """

    def f(H, M):
        return variant.slope(H, M, delta, p)

    M_plain = _rk4(f, H, M, dH, k1)
    d0 = variant.distance_to_switch(H, M, delta, p)
    d1 = variant.distance_to_switch(H + dH, M_plain, delta, p)
    switches = (d0 <= 0) & (d1 > 0)

    def split(_):
        theta = jnp.clip(d0 / jnp.where(switches, d0 - d1, -1.0), 0.0, 1.0)

        def reversible(H, M):
            return variant.slope(H, M, delta, p, pinning=False)

        M_mid = _rk4(reversible, H, M, theta * dH, reversible(H, M))
        H_mid = H + theta * dH
        return _rk4(f, H_mid, M_mid, (1.0 - theta) * dH, f(H_mid, M_mid))

    return jnp.where(switches, split(None), M_plain)


def _interval_step(variant, p, force_gain, substeps):
    """The scan body: advance (M, x) over one sample interval."""

    def step(carry, interval):
        M, x = carry
        H0, H1, h, Phi, G = interval
        dH = (H1 - H0) / substeps
        delta = jnp.where(H1 >= H0, 1.0, -1.0)
        dH_dt = dH / h  # A/m per s, constant over the interval

        def f(H, M):
            return variant.slope(H, M, delta, p)

        def substep(state, _):
            H, M, k1, x = state
            M_next = _substep_magnetization(variant, p, delta, H, M, dH, k1)
            H_next = H + dH
            k_end = f(H_next, M_next)
            lam0 = magnetostriction(M, p.Ms, p.lambda_s)
            lam1 = magnetostriction(M_next, p.Ms, p.lambda_s)
            dlam0 = magnetostriction_rate(M, k1 * dH_dt, p.Ms, p.lambda_s)
            dlam1 = magnetostriction_rate(M_next, k_end * dH_dt, p.Ms, p.lambda_s)
            w = force_gain * hermite_taylor_coefficients(lam0, dlam0, lam1, dlam1, h)
            # explicit 2×2 / 2×4 products: XLA:CPU calls a BLAS kernel per tiny dot
            x = (Phi * x).sum(-1) + (G * w).sum(-1)
            return (H_next, M_next, k_end, x), None

        # An inner scan rather than a Python loop keeps the traced program (and so the
        # compile time of solvers that differentiate through it) independent of substeps.
        (_, M, _, x), _ = jax.lax.scan(substep, (H0, M, f(H0, M), x), None, length=substeps)
        return (M, x), (M, x[0], x[1])

    return step


def simulate_unchecked(
    params: Parameters,
    actuator: Actuator,
    drive: Drive,
    variant: JAVariant = PAPER_VARIANT,
    substeps: int = DEFAULT_SUBSTEPS,
) -> Simulation:
    """`simulate` without input validation: the pure function for jit/vmap/grad inside
    solvers. Same arguments and result as `simulate`."""
    p = params
    force_gain = actuator.Ar * p.E / p.Mz  # u = Ar·E·λ/Mz, m/s² per unit λ
    t, H = drive.t, drive.H
    n_int = t.shape[0] - 1
    if drive.dt is not None:
        h = jnp.full((n_int,), drive.dt / substeps)
        Phi, G = cubic_hold_discretization(p, drive.dt / substeps)
        Phis = jnp.broadcast_to(Phi, (n_int, 2, 2))
        Gs = jnp.broadcast_to(G, (n_int, 2, 4))
    else:
        h = jnp.diff(t) / substeps
        Phis, Gs = jax.vmap(lambda hi: cubic_hold_discretization(p, hi))(h)
    step = _interval_step(variant, p, force_gain, substeps)
    M0 = jnp.zeros((), dtype=jnp.float64)
    x0 = jnp.zeros((2,), dtype=jnp.float64)
    _, (M, y, v) = jax.lax.scan(step, (M0, x0), (H[:-1], H[1:], h, Phis, Gs))
    zero = jnp.zeros((1,), dtype=jnp.float64)
    M = jnp.concatenate([zero, M])
    y = jnp.concatenate([zero, y])
    v = jnp.concatenate([zero, v])
    Man, _ = anhysteretic(H, M, p)
    return Simulation(
        t=t,
        H=H,
        M=M,
        Man=Man,
        Mirr=variant.irreversible_magnetization(H, M, p),
        lam=magnetostriction(M, p.Ms, p.lambda_s),
        y=y,
        velocity=v,
        strain=y / actuator.lr,
        run_in=drive.run_in,
    )


_simulate_jit = eqx.filter_jit(simulate_unchecked)


def _check_inputs(params, actuator, drive, variant, substeps) -> None:
    """The public entry points' validation: types, substeps, physical parameter values."""
    if not isinstance(params, Parameters):
        raise TypeError(f"params must be jaxhyst.Parameters; got {type(params).__name__}.")
    if not isinstance(actuator, Actuator):
        raise TypeError(f"actuator must be jaxhyst.Actuator; got {type(actuator).__name__}.")
    if not isinstance(drive, Drive):
        raise TypeError(
            f"drive must be jaxhyst.Drive (e.g. Drive(t, H)); got {type(drive).__name__}."
        )
    if not isinstance(variant, JAVariant):
        raise TypeError(f"variant must be a JAVariant (e.g. EnergyBasedJA()); got {variant!r}.")
    if not isinstance(substeps, int) or substeps < 1:
        raise ValueError(f"substeps must be an integer >= 1; got {substeps!r}.")
    check_parameters(params)


def simulate(
    params: Parameters,
    actuator: Actuator,
    drive: Drive,
    variant: JAVariant = PAPER_VARIANT,
    substeps: int = DEFAULT_SUBSTEPS,
) -> Simulation:
    """Simulate the actuator: drive H(t) → M, Man, Mirr → λ → y, ε.

    **Arguments:**
    - ``params``: `Parameters` (SI units). Checked for physical validity when concrete.
    - ``actuator``: `Actuator` constants (Ar, lr used here; n, Hb by the drive builders).
    - ``drive``: `Drive` with times t (s) and applied field H (A/m), shape (T,).
    - ``variant``: Jiles–Atherton form; the paper's `EnergyBasedJA` by default.
    - ``substeps``: RK4 substeps per sample interval (static). The default 2 keeps the
      error below 1e-5 of max|y| at ≥ 200 samples per period; see docs/theory.md.

    **Returns:** a `Simulation` with every signal, shape (T,). Jit-compiled; to batch
    over parameter sets use ``jax.vmap(simulate_unchecked, in_axes=(0, None, None))``
    or `jaxhyst.simulate_batch`.
    """
    _check_inputs(params, actuator, drive, variant, substeps)
    return _simulate_jit(params, actuator, drive, variant, substeps)


@eqx.filter_jit
def _simulate_batch(params, actuator, drive, variant, substeps):
    return jax.vmap(simulate_unchecked, in_axes=(0, None, None, None, None))(
        params, actuator, drive, variant, substeps
    )


def simulate_batch(
    params: Parameters,
    actuator: Actuator,
    drive: Drive,
    variant: JAVariant = PAPER_VARIANT,
    substeps: int = DEFAULT_SUBSTEPS,
) -> Simulation:
    """`simulate` for a batch of parameter sets (leaves of shape (P,)) in one vmapped,
    jitted call: signals of shape (P, T). This is the GA's population evaluation."""
    _check_inputs(params, actuator, drive, variant, substeps)
    if jnp.ndim(params.Ms) != 1:
        raise ValueError(
            "simulate_batch needs Parameters with 1-D leaves of shape (P,); use simulate "
            "for a single parameter set."
        )
    return _simulate_batch(params, actuator, drive, variant, substeps)
