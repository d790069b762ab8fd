"""`simulate`: drive H(t) → M → λ → y, as one pure function of data.

Two stages:

1. `paths.hysteresis_path` — the only sequential part: the time loop of
   `jaxhyst.model.timeloop` (a ``lax.scan`` over sample intervals with a custom
   derivative rule, a linear recurrence of per-interval partial derivatives, that makes
   every JAX transformation of it cheap) with the form's interval map: for a
   Jiles–Atherton variant RK4 in H (``substeps`` pieces per interval, the δM switch
   located exactly), for a form of pinning cells their exact update.
2. Vectorized over all substeps: λ and dλ/dt at the substep points, the cubic Hermite
   forcing, and the structural response as a linear recurrence with a 2-vector state
   (`structure.linear_response`).

The initial state is demagnetized and at rest: M = 0, y = ẏ = 0 at t_0. Both stages
are 4th order, so the error falls ~16× per doubling of ``substeps``.
"""

from __future__ import annotations

import contextlib
import warnings

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .. import _traces
from .._jax_compat import under_jit, under_vmap
from .._traces import kept_jit
from .._typing import Array, Bool, Float, Signal
from ..actuator import Actuator
from ..drive import Drive, require_times
from ..names import DEFAULT_SUBSTEPS, checked_substeps
from ..params import NAMES, Parameters, check_parameters, is_concrete, physically_valid
from ..sharding import vmap_blocked
from ._batching import blocked_under_vmap
from .accuracy import (
    RATE_ACCURACY,
    SamplingWarning,
    checked_meanwhile,
    richardson_error,
    sampling_message,
    step_error,
)
from .jiles_atherton import PAPER_VARIANT, AbstractJAVariant, anhysteretic
from .losses import Losses
from .magnetostriction import magnetostriction
from .paths import FORM_TYPES, hysteresis_path
from .structure import (
    hermite_taylor_coefficients,
    periodic_structural_response,
    structural_response,
)


def _outside_jit(tree) -> bool:
    """Whether a call with the inputs ``tree`` runs outside any jit trace: with concrete
    values, or under ``jax.grad``/``jacfwd``/``vmap``… called directly. Such a call is
    best sent to the compiled simulation (one program instead of thousands of operations
    dispatched one at a time); inside a jit trace the simulation is traced inline."""
    if is_concrete(tree):
        return True
    return under_jit() is False


class Simulation(eqx.Module):
    """Every signal of one simulation, per drive sample, shape (T,) (or (P, T) batched).

    - ``t``: time, s;  ``H``: applied field, A/m; ``H_hyst``: the field the hysteresis
      model sees (H itself without loss terms; H − H_eddy − H_exc with them), A/m
    - ``M``: magnetization, A/m; ``Man``: anhysteretic, A/m; ``Mirr``: irreversible, A/m
    - ``lam``: magnetostriction λ, 1
    - ``y``: output displacement, m; ``velocity``: ẏ, m/s; ``strain``: ε = y/lr, 1
    - ``run_in``: leading samples that belong to the run-in (use ``observed``).
    """

    t: Signal
    H: Signal
    H_hyst: Signal
    M: Signal
    Man: Signal
    Mirr: Signal
    lam: Signal
    y: Signal
    velocity: Signal
    strain: Signal
    run_in: int = eqx.field(static=True, default=0)

    def observed(self, name: str = "y") -> Float[Array, "*batch T_obs"]:
        """A signal without its run-in samples, e.g. ``sim.observed("y")``."""
        return getattr(self, name)[..., self.run_in :]

    @property
    def finite(self) -> Bool[Array, "*batch"]:
        """True where every signal is finite (False flags a diverged parameter set)."""
        return jnp.isfinite(self.M).all(-1) & jnp.isfinite(self.y).all(-1)


def simulate_unchecked(
    params: Parameters,
    actuator: Actuator,
    drive: Drive,
    variant: AbstractJAVariant = PAPER_VARIANT,
    substeps: int = DEFAULT_SUBSTEPS,
    losses: Losses | None = None,
) -> Simulation:
    """`simulate` without input validation: the pure function for jit/vmap/grad inside
    solvers. Same arguments and result as `simulate`.

    Outside ``jax.jit`` (concrete values, or ``jax.grad``, ``jacfwd``, ``vmap``… called
    directly) it runs as one compiled program, like `simulate`; inside a jit trace it is
    traced into your program. Still wrap your own transformations in ``jax.jit``: the
    rest of your function otherwise runs operation by operation
    (docs/derivatives.md)."""
    if losses is not None:
        require_times(drive)
    if _outside_jit((params, actuator, drive, losses)):
        return _simulate_jit(params, actuator, drive, variant, substeps, losses)
    return _simulate(params, actuator, drive, variant, substeps, losses)


def _simulate(params, actuator, drive, variant, substeps, losses=None) -> Simulation:
    """The simulation itself (`simulate_unchecked`)."""
    S = _static_substeps(substeps)
    # rate independent, or the rate-dependent loop with losses (`jaxhyst.model.dynamic`)
    M_sub, k_sub, H_hyst, dM = hysteresis_path(variant, params, drive.t, drive.H,
                                               substeps=S, losses=losses)
    # dM/dt at the substep points u_0 … u_S: the slope along h times h's rate, and the
    # after-effect's share where it relaxes M
    rate = k_sub * ((jnp.diff(H_hyst) / S) / (jnp.diff(drive.t) / S))[:, None]
    rate = rate if dM is None else rate + dM
    args = (variant, params, actuator.Ar, drive.t, H_hyst, M_sub, rate)
    periodic_from = drive.run_in if drive.periodic else None
    if under_vmap() and not _PLAIN_VMAP:  # its batch rule in blocks
        M, Man, Mirr, lam, y, v = blocked_under_vmap(
            _after_the_loop, uniform=drive.uniform, S=S, periodic_from=periodic_from)(*args)
    else:  # (the same without the wrappers: less to trace for grad)
        M, Man, Mirr, lam, y, v = _after_the_loop(*args, drive.uniform, S, periodic_from)
    # parameters outside their physical range (only known here at run time, under jit)
    # give NaN signals, never a plausible-looking simulation
    bad = ~physically_valid(params)
    M, y, v, lam = (jnp.where(bad, jnp.nan, x) for x in (M, y, v, lam))
    return Simulation(t=drive.t, H=drive.H, H_hyst=H_hyst, M=M, Man=Man, Mirr=Mirr, lam=lam,
                      y=y, velocity=v, strain=y / actuator.lr, run_in=drive.run_in)


_simulate_jit = kept_jit(_simulate)

#: Set while `plain_vmap` is active: a vmap traces the work after the time loop plainly.
_PLAIN_VMAP: list = []
_traces.SWITCHES["plain_vmap"] = lambda: bool(_PLAIN_VMAP)  # (a kept trace's key holds it)


@contextlib.contextmanager
def plain_vmap():
    """Trace simulations under ``jax.vmap`` without the blocked batch rule of the work
    after the time loop (`_batching.blocked_under_vmap`), for the duration. JAX's
    ``custom_vmap`` refuses to be batched again when its function closes over values an
    outer ``vmap`` batches — a minimiser that vmaps the function itself (Nelder–Mead's
    simplex) inside a vmapped batch of starts does that — so such solves are traced with
    this on (`jaxhyst.identify._stepped`). Values are the same either way."""
    _PLAIN_VMAP.append(True)
    try:
        yield
    finally:
        _PLAIN_VMAP.pop()


def _after_the_loop(variant, p, Ar, t, H, M_sub, dM_dt, uniform: bool, S: int,
                    periodic_from: int | None = None):
    """Every signal but t and H from the magnetization path (M_sub (N, S) at the substep
    points u_1 … u_S and dM_dt (N, S + 1) at u_0 … u_S, A/(m·s)): (M, Man, Mirr, λ, y, ẏ)
    at the samples, shape (T,)
    each. y and ẏ come from λ and dλ/dt at the substep points, their cubic Hermite
    forcing and the structural recurrence (exact for that forcing). ``periodic_from``:
    the first observed sample of a periodic drive (`Drive.periodic`); from there on the
    structure is in its periodic steady state (before it, it starts at rest)."""
    zero = jnp.zeros((1,), dtype=H.dtype)
    M = jnp.concatenate([zero, M_sub[:, -1]])
    M_points = jnp.concatenate([M[:-1, None], M_sub], axis=1)  # u_0 … u_S, (N, S + 1)
    h = jnp.diff(t) / S  # substep length, s
    m = M_points / p.Ms
    lam = 1.5 * p.lambda_s * m * m
    dlam = 3.0 * p.lambda_s * m * (dM_dt / p.Ms)
    force_gain = Ar * p.E / p.Mz  # u = Ar·E·λ/Mz, m/s² per unit λ
    w = force_gain * hermite_taylor_coefficients(lam[:, :-1], dlam[:, :-1], lam[:, 1:],
                                                 dlam[:, 1:], h[:, None])  # (N, S, 4)
    steps, w = jnp.repeat(h, S), w.reshape(-1, 4)
    if periodic_from is None:
        x = structural_response(p, steps, w, uniform)[S - 1 :: S]  # at the samples
        x = jnp.concatenate([jnp.zeros((1, 2), dtype=H.dtype), x])
    else:  # at rest up to the observed periods, then their steady state
        J = periodic_from * S
        start, during = periodic_structural_response(p, steps[J:], w[J:], uniform)
        parts = [start[None], during[S - 1 :: S]]
        if periodic_from:  # (the run-in from rest; its last sample is the steady start)
            before = structural_response(p, steps[:J], w[:J], uniform)[S - 1 :: S]
            parts = [jnp.zeros((1, 2), dtype=H.dtype), before[:-1], *parts]
        x = jnp.concatenate(parts)
    Man, _ = anhysteretic(H, M, p)
    return (M, Man, variant.irreversible_magnetization(H, M, p),
            magnetostriction(M, p.Ms, p.lambda_s), x[:, 0], x[:, 1])


def _static_substeps(substeps) -> int:
    """``substeps`` as a Python int: it is the loop's structure, not data."""
    if isinstance(substeps, jax.core.Tracer):
        raise TypeError(
            "substeps is traced here, but it is structure (RK4 pieces per interval): pass "
            "a Python int, and under jax.jit mark it static, e.g. "
            "jax.jit(simulate_unchecked, static_argnames='substeps').")
    return int(substeps)


def _check_inputs(params, actuator, drive, variant, substeps, losses=None) -> int:
    """The public entry points' validation: types, substeps, physical parameter values;
    the substeps as a Python int (a NumPy integer is one too)."""
    if not isinstance(params, Parameters):
        raise TypeError(f"params must be jaxhyst.Parameters; got {type(params).__name__}.")
    if not isinstance(actuator, Actuator):
        raise TypeError(f"actuator must be jaxhyst.Actuator; got {type(actuator).__name__}.")
    if not isinstance(drive, Drive):
        raise TypeError(
            f"drive must be jaxhyst.Drive (e.g. Drive(t, H)); got {type(drive).__name__}."
        )
    if not isinstance(variant, FORM_TYPES):
        raise TypeError(f"variant must be a model form (a Jiles–Atherton variant such as "
                        f"EnergyBasedJA(), or a form of pinning cells such as PlayJA()); got "
                        f"{variant!r}.")
    n = checked_substeps(substeps)
    if losses is not None and not isinstance(losses, Losses):
        raise TypeError(f"losses must be jaxhyst.Losses(eddy, excess, lag, relax) or None; got "
                        f"{losses!r}.")
    if losses is not None:
        require_times(drive)
    check_parameters(params)
    return n


def _check_single(params, drive) -> None:
    """`simulate` takes one parameter set and one drive."""
    shapes = {n: jnp.shape(getattr(params, n)) for n in params.names}
    batched = {n: s for n, s in shapes.items() if s != ()}
    if batched:
        n, s = next(iter(batched.items()))
        raise ValueError(
            f"simulate takes one parameter set, but params.{n} has shape {s}; for a batch "
            "of parameter sets use jaxhyst.simulate_batch (or jax.vmap(simulate_unchecked))."
        )
    if jnp.ndim(drive.H) != 1:
        raise ValueError(
            f"simulate takes one drive, but drive.H has shape {jnp.shape(drive.H)}; for a "
            "batch of drives use jax.vmap(simulate_unchecked, in_axes=(None, None, 0))."
        )


def simulate(
    params: Parameters,
    actuator: Actuator,
    drive: Drive,
    variant: AbstractJAVariant = PAPER_VARIANT,
    substeps: int = DEFAULT_SUBSTEPS,
    losses: Losses | None = None,
) -> Simulation:
    """Simulate the actuator: drive H(t) → M, Man, Mirr → λ → y, ε.

    **Arguments:**
    - ``params``: `Parameters` (SI units). Checked for physical validity wherever their
      values can be read (also under ``jax.grad`` & co. called directly; not in jit/vmap).
    - ``actuator``: `Actuator` constants (Ar, lr used here; n, Hb by the drive builders).
    - ``drive``: `Drive` with times t (s) and applied field H (A/m), shape (T,).
    - ``variant``: Jiles–Atherton form; the paper's `EnergyBasedJA` by default.
    - ``substeps``: RK4 substeps per sample interval (static). The default 2 keeps the
      error below 1e-5 of max|y| at ≥ 200 samples per period; see docs/theory.md.
    - ``losses``: `jaxhyst.Losses` (eddy-current and excess loss coefficients) for the
      rate-dependent model (`jaxhyst.model.dynamic`); None (default): rate independent.

    Warns (`jaxhyst.model.accuracy.SamplingWarning`) where the error at this sampling,
    estimated from the same simulation at twice the substeps, exceeds the documented
    1e-5 of max|y| (or of max|M|; of max|M| alone for a material sample, an actuator
    that is `Actuator.magnetization_only`), naming the signal: only drives whose field
    moves more than 1 % of its range per substep are checked (one more simulation;
    with ``losses`` another at half the sample step). The first of them compiles in a
    background thread while this one's program compiles, the second after it
    (`jaxhyst.model.accuracy.checked_meanwhile`).

    **Returns:** a `Simulation` with every signal, shape (T,); raises
    ``FloatingPointError`` (naming the first bad sample) if the simulation diverged
    (`simulate_unchecked` returns the NaN instead). Jit-compiled; to batch
    over parameter sets use ``jax.vmap(simulate_unchecked, in_axes=(0, None, None))``
    or `jaxhyst.simulate_batch`.
    """
    substeps = _check_inputs(params, actuator, drive, variant, substeps, losses)
    _check_single(params, drive)
    if not is_concrete((params, actuator, drive, variant, losses)):  # (traced: no check)
        return _simulate_jit(params, actuator, drive, variant, substeps, losses)
    sim, finite, fine, finer = checked_meanwhile(
        lambda d, s: _simulate_jit(params, actuator, d, variant, s, losses),
        lambda: _simulate_jit(params, actuator, drive, variant, substeps, losses),
        lambda sim: np.isfinite(np.asarray(sim.M)) & np.isfinite(np.asarray(sim.y)),
        drive, np.asarray(drive.observed(drive.H)), substeps, losses,
        lambda t2, H2, run_in2: Drive(t2, H2, run_in2, drive.uniform, drive.periodic,
                                      drive.timed))
    if not finite.all():
        bad = np.flatnonzero(~finite)
        i = int(bad[0])
        raise FloatingPointError(
            f"The simulation diverged: its signals are not finite from sample {i} (t = "
            f"{float(drive.t[i]):g} s, H = {float(drive.H[i]):g} A/m) on; the parameters or "
            "the drive lie outside the model's range. (simulate_unchecked returns the NaN "
            "instead of raising.)")
    # (a material sample's y is a placeholder: its error is nobody's)
    signals = ("M",) if actuator.magnetization_only else ("M", "y")
    if fine is None and np.max(np.abs(np.asarray(sim.M))) > 1.001 * float(params.Ms):
        # (beyond saturation, which no form reaches: a material far sharper than the
        # drive's steps, which the screen on the field's range alone let through)
        fine = _simulate_jit(params, actuator, drive, variant, 2 * substeps, losses)
    if fine is not None:  # (at twice the substeps)
        name, error = _worst(signals, lambda n: richardson_error(sim.observed(n),
                                                                 fine.observed(n)))
        message = sampling_message(error, substeps, f"the simulation's {name}")
        if message is not None:
            warnings.warn(message, SamplingWarning, stacklevel=2)
    if finer is not None:  # the field balance: second order in the sample step
        name, error = _worst(signals, lambda n: step_error(sim.observed(n),
                                                           finer.observed(n)[..., ::2]))
        if error > RATE_ACCURACY:
            warnings.warn(f"the sampling is too coarse for the rate-dependent model: the "
                          f"error of the simulation's {name} is estimated at {error:.2g} of "
                          f"its size (documented: <= {RATE_ACCURACY:g}); sample the drive "
                          f"at least {int(np.ceil(np.sqrt(error / RATE_ACCURACY) * 1.05))}"
                          "× more finely.", SamplingWarning, stacklevel=2)
    return sim


def _worst(signals, error_of) -> tuple[str, float]:
    """(the signal, its estimated error) of the signal with the largest error."""
    return max(((name, error_of(name)) for name in signals), key=lambda pair: pair[1])


@eqx.filter_jit
def _simulate_batch(params, actuator, drive, variant, substeps, losses):
    return vmap_blocked(lambda p: simulate_unchecked(p, actuator, drive, variant, substeps,
                                                     losses),
                        jnp.shape(params.Ms)[0])(params)


def simulate_batch(
    params: Parameters,
    actuator: Actuator,
    drive: Drive,
    variant: AbstractJAVariant = PAPER_VARIANT,
    substeps: int = DEFAULT_SUBSTEPS,
    losses: Losses | None = None,
) -> Simulation:
    """`simulate` for a batch of parameter sets (leaves of shape (P,)) in one vmapped,
    jitted call: signals of shape (P, T), evaluated as the GA evaluates populations: on the
    CPU a batch of hundreds runs in blocks of 64 members (`jaxhyst.sharding.vmap_blocked`:
    the same values to round-off; timings in benchmarks/RESULTS.md)."""
    _check_inputs(params, actuator, drive, variant, substeps, losses)
    shapes = {name: jnp.shape(getattr(params, name)) for name in NAMES}
    if len(set(shapes.values())) != 1 or jnp.ndim(params.Ms) != 1:
        raise ValueError(
            "simulate_batch needs Parameters with 1-D leaves of one shape (P,); got "
            f"{', '.join(f'{n} {s}' for n, s in shapes.items())}; use simulate for a "
            "single parameter set.")
    return _simulate_batch(params, actuator, drive, variant, substeps, losses)
