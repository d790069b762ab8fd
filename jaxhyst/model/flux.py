"""The B-driven (inverse) model: given the flux density B(t) and the parameters, the field
H(t) — and the energy per cycle ∮ H dB.

**The scheme.** With B prescribed, the magnetization follows B alone: the hysteresis field
is H_hyst = B/μ0 − M, and along it every Jiles–Atherton form gives dM/dH, so that

    dM/dB = χ / (μ0·(1 + χ)),   χ = dM/dH at (H_hyst, M),

with the field direction δ = sign(dB) (dH_hyst/dB = 1/(μ0(1 + χ)) > 0). `FluxDriven`
wraps any form as this slope in B, so the B-driven path *is* the forward time loop
(`magnetization_path`) run along B: RK4 in B with ``substeps`` pieces per sample
interval, the δM switch located on a piece boundary, the same cheap derivative rule, the
same batching. B between samples is piecewise linear in time; the loss fields of
`jaxhyst.model.losses` are then constant over each interval (H_hyst taken linear in time
within it for H_lag), and the applied field is

    H = H_hyst + H_eddy + H_exc + H_lag,

taken at each sample with the mean of the rates of its two neighbouring intervals
(second order for a smooth B). The energy per cycle and volume is exact for that B: the
static part ∮ H_hyst dB by the cubic Hermite rule on each RK4 piece (H_hyst and its
slope dH_hyst/dB = 1/μ0 − dM/dB at both ends: 4th order, like RK4), the loss part by
`jaxhyst.model.losses.dynamic_energy` per interval.

**The after-effect** (``Losses.relax`` = τ_M, τ_M·dM/dt = M_s − M): M no longer follows B
alone, so the path is the rate-dependent model's driven by B
(`jaxhyst.model.dynamic.RateDependentPath` with ``driver="B"``: per interval the field
h_{n+1} with B_{n+1} = μ0·(h_{n+1} + M_{n+1}), M relaxed exactly for M_s linear in time,
Newton's method in h), H_hyst = h = B/μ0 − M at the samples, and the static part of
∮ H dB by the trapezoid rule per interval (h and B both linear in time there): second
order in the sample step, like the loss fields. `simulate_flux` takes that path where
relax > 0; traced, `simulate_flux_unchecked` takes it where ``after_effect=True`` (a
static choice: the parameters' values cannot pick a program), and otherwise gives NaN
for relax > 0 rather than a model without it.
"""

from __future__ import annotations

import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._traces import kept_jit
from .._typing import Array, Float, Signal
from ..drive import UNIFORM_TOLERANCE, Drive, require_times
from ..names import DEFAULT_SUBSTEPS, checked_substeps
from ..params import MU0, Parameters, check_parameters, is_concrete, physically_valid
from .accuracy import (
    FLUX_ACCURACY,
    SamplingWarning,
    checked_meanwhile,
    richardson_error,
    step_error,
    substeps_for,
)
from .drivers import FluxDriven
from .jiles_atherton import PAPER_VARIANT, AbstractJAVariant, anhysteretic
from .losses import Losses, dynamic_energy, dynamic_field
from .paths import FORM_TYPES, hysteresis_path
from .simulate import _outside_jit

__all__ = ["FluxDrive", "FluxDriven", "FluxSimulation", "flux_from_period",
           "flux_from_record", "simulate_flux", "simulate_flux_unchecked", "sinusoidal_flux"]

#: Largest flux density accepted in a B record, T: four times the highest saturation of
#: any material (Fe–Co, 2.45 T); a larger value is a unit or column mistake.
MAX_FLUX_DENSITY = 10.0


class FluxDrive(eqx.Module):
    """A sampled flux density: times ``t`` (s) and ``B`` (T), shape (T,), B piecewise
    linear between samples, and the leading ``run_in`` samples simulated but not observed
    (a ramp from the demagnetized state, whole periods whose transient is discarded). Build
    it from a record (`flux_from_record`, `flux_from_period`) or a sinusoid
    (`sinusoidal_flux`); its structure (length, run-in, uniform sampling) is static, the
    values are data."""

    t: Signal
    B: Signal
    run_in: int = eqx.field(static=True, default=0)
    uniform: bool = eqx.field(static=True, default=False)
    timed: bool = eqx.field(static=True, default=True)  # (`jaxhyst.Drive.timed`)

    def __init__(self, t, B, run_in: int = 0, uniform: bool | None = None,
                 timed: bool = True):
        if is_concrete(B) and np.ndim(B) == 1 and np.all(np.isfinite(np.asarray(B))) and \
                np.max(np.abs(np.asarray(B))) > MAX_FLUX_DENSITY:
            i = int(np.argmax(np.abs(np.asarray(B)) > MAX_FLUX_DENSITY))
            raise ValueError(f"B at sample {i} is {float(np.asarray(B)[i]):g} T, beyond "
                             f"{MAX_FLUX_DENSITY:g} T; check its unit (T) and column.")
        checked = Drive(t, B, run_in, uniform)  # (the same checks of t, lengths, run-in)
        self.t, self.B = checked.t, checked.H
        self.run_in, self.uniform, self.timed = checked.run_in, checked.uniform, bool(timed)

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[-1])

    @property
    def n_observed(self) -> int:
        return self.n_samples - self.run_in

    def observed(self, signal: Float[Array, "*batch T"]) -> Float[Array, "*batch T_obs"]:
        """The observed part (after the run-in) of a per-sample signal."""
        return signal[..., self.run_in:]

    @classmethod
    def of(cls, drive: Drive) -> FluxDrive:
        """The flux drive with the samples of ``drive`` read as B (T)."""
        return cls(drive.t, drive.H, drive.run_in, drive.uniform, drive.timed)


class FluxSimulation(eqx.Module):
    """Every signal of a B-driven simulation, per sample, shape (T,) (or batched):
    ``t`` (s), ``B`` (T), ``H`` applied field (A/m), ``H_hyst`` = B/μ0 − M (A/m), ``M``,
    ``Man`` (A/m); ``cycle_energy`` (J/m³): ∮ H dB over the observed samples (the loss per
    cycle and volume when they span one period; `loss_density` divides by the periods).
    ``run_in`` as in `jaxhyst.Simulation`."""

    t: Signal
    B: Signal
    H: Signal
    H_hyst: Signal
    M: Signal
    Man: Signal
    cycle_energy: Float[Array, "*batch"]
    run_in: int = eqx.field(static=True, default=0)

    def observed(self, name: str = "H") -> Float[Array, "*batch T_obs"]:
        return getattr(self, name)[..., self.run_in:]

    def loss_density(self, frequency, periods: int = 1):
        """Power loss per volume, W/m³: f·∮H dB/periods over the observed samples;
        ``frequency`` (Hz) > 0, ``periods`` (the observed periods) an integer >= 1."""
        if is_concrete(frequency) and not np.all(np.asarray(frequency) > 0):
            raise ValueError(f"loss_density: frequency must be > 0 Hz (the drive's); got "
                             f"{frequency!r}.")
        if isinstance(periods, bool) or not isinstance(periods, (int, np.integer)) or \
                periods < 1:
            raise ValueError(f"loss_density: periods must be an integer >= 1 (the observed "
                             f"periods); got {periods!r}.")
        return frequency * self.cycle_energy / periods


def _hermite_energy(B_points, H_points, dH_points):
    """∫ H dB over each RK4 piece by the cubic Hermite rule, summed per interval:
    B_points, H_points, dH_points (dH/dB) at u_0 … u_S, shape (N, S + 1) → (N,)."""
    dB = jnp.diff(B_points, axis=-1)
    piece = 0.5 * dB * (H_points[..., :-1] + H_points[..., 1:]) \
        + dB * dB / 12.0 * (dH_points[..., :-1] - dH_points[..., 1:])
    return jnp.sum(piece, axis=-1)


def _arguments(substeps, losses, what: str):
    """(substeps, losses) of a call in the order of `simulate_unchecked` (…, variant,
    substeps, losses); the earlier order (…, variant, losses, substeps) is accepted for one
    release with a ``DeprecationWarning``."""
    old = isinstance(substeps, Losses) or (
        isinstance(losses, (int, np.integer)) and not isinstance(losses, bool))
    if not old:
        return (DEFAULT_SUBSTEPS if substeps is None else substeps), losses
    warnings.warn(f"{what}(params, drive, variant, losses, substeps) is the earlier order of "
                  f"the arguments; it is now (params, drive, variant, substeps, losses), as "
                  "simulate's — pass them by keyword to be safe.", DeprecationWarning,
                  stacklevel=3)
    return (DEFAULT_SUBSTEPS if losses is None else losses), substeps


def simulate_flux_unchecked(params: Parameters, drive: FluxDrive,
                            variant: AbstractJAVariant = PAPER_VARIANT,
                            substeps: int = DEFAULT_SUBSTEPS, losses: Losses | None = None,
                            after_effect: bool | None = None) -> FluxSimulation:
    """`simulate_flux` without input checks: the pure function for jit/vmap/grad (the
    arguments in the order of `jaxhyst.simulate_unchecked`). ``after_effect`` (static):
    True for the path with the magnetization's relaxation (module docstring), False for
    the path without it; None: with it where ``losses.relax`` is a concrete value > 0.

    Outside ``jax.jit`` (concrete values, or ``jax.grad``, ``jacfwd``, ``vmap``… called
    directly) it runs as one compiled program, like `simulate_flux`; inside a jit trace it
    is traced into your program (as `jaxhyst.simulate_unchecked` does)."""
    substeps, losses = _arguments(substeps, losses, "simulate_flux_unchecked")
    if losses is not None:
        require_times(drive)
    if after_effect is None:
        after_effect = _relaxes(losses)
    if _outside_jit((params, drive, losses)):
        return _simulate_flux_jit(params, drive, variant, substeps, losses, bool(after_effect))
    return _simulate_flux(params, drive, variant, substeps, losses, after_effect)


def _simulate_flux(params, drive, variant, substeps, losses, after_effect) -> FluxSimulation:
    """The B-driven simulation itself (`simulate_flux_unchecked`)."""
    S = int(substeps)
    losses = Losses() if losses is None else losses
    B, t = drive.B, drive.t
    if after_effect:
        return _with_after_effect(params, drive, variant, S, losses)
    M_sub, k_sub, _, _ = hysteresis_path(variant, params, None, B, substeps=S, driver="B")
    zero = jnp.zeros((1,), dtype=B.dtype)
    M = jnp.concatenate([zero, M_sub[:, -1]])
    H_hyst = B / MU0 - M
    H = _applied(B, t, H_hyst, losses)
    # energy per interval of the observed part: static (Hermite on the RK4 pieces) + loss
    frac = jnp.arange(S + 1, dtype=B.dtype) / S
    B_points = B[:-1, None] + frac * jnp.diff(B)[:, None]
    M_points = jnp.concatenate([M[:-1, None], M_sub], axis=1)
    per_interval = _hermite_energy(B_points, B_points / MU0 - M_points, 1.0 / MU0 - k_sub) \
        + dynamic_energy(jnp.diff(B), jnp.diff(t), losses, jnp.diff(H_hyst))
    # (NaN for the after-effect, which this path does not have: never a plausible-looking
    # answer without it)
    return _simulation(params, drive, H, H_hyst, M, per_interval, losses.relax > 0)


def _relaxes(losses) -> bool:
    """Whether ``losses`` hold an after-effect that can be read: relax a value > 0."""
    return losses is not None and is_concrete(losses.relax) and bool(
        np.any(np.asarray(losses.relax) > 0))


def _applied(B, t, H_hyst, losses):
    """The applied field at the samples: H_hyst plus the loss fields, each sample with the
    mean of the rates of its two neighbouring intervals."""
    def at_samples(rate):
        return jnp.concatenate([rate[:1], 0.5 * (rate[:-1] + rate[1:]), rate[-1:]])

    return H_hyst + dynamic_field(at_samples(jnp.diff(B) / jnp.diff(t)), losses,
                                  at_samples(jnp.diff(H_hyst) / jnp.diff(t)))


def _with_after_effect(params, drive, variant, S: int, losses) -> FluxSimulation:
    """`simulate_flux_unchecked` with the after-effect (module docstring)."""
    B, t = drive.B, drive.t
    M_sub, _, h, _ = hysteresis_path(variant, params, t, B, substeps=S, losses=losses,
                                     driver="B")
    M = jnp.concatenate([B[:1] / MU0 - h[:1], M_sub[:, -1]])
    H_hyst = B / MU0 - M
    per_interval = 0.5 * jnp.diff(B) * (H_hyst[:-1] + H_hyst[1:]) \
        + dynamic_energy(jnp.diff(B), jnp.diff(t), losses, jnp.diff(H_hyst))
    return _simulation(params, drive, _applied(B, t, H_hyst, losses), H_hyst, M,
                       per_interval, False)


def _simulation(params, drive, H, H_hyst, M, per_interval, bad) -> FluxSimulation:
    """The `FluxSimulation` of a path: the energy per cycle summed over the intervals
    after the run-in, H and that energy NaN where ``bad`` or for an impossible parameter
    set (under jit too)."""
    energy = jnp.sum(per_interval[drive.run_in:])
    Man, _ = anhysteretic(H_hyst, M, params)
    bad = ~physically_valid(params) | bad
    H, energy = jnp.where(bad, jnp.nan, H), jnp.where(bad, jnp.nan, energy)
    return FluxSimulation(t=drive.t, B=drive.B, H=H, H_hyst=H_hyst, M=M, Man=Man,
                          cycle_energy=energy, run_in=drive.run_in)


_simulate_flux_jit = kept_jit(_simulate_flux)


def simulate_flux(params: Parameters, drive: FluxDrive,
                  variant: AbstractJAVariant = PAPER_VARIANT, substeps: int = DEFAULT_SUBSTEPS,
                  losses: Losses | None = None, after_effect: bool | None = None
                  ) -> FluxSimulation:
    """The B-driven model (module docstring): H(t) and ∮ H dB for the flux density of
    ``drive`` (a `FluxDrive`), any model form, RK4 ``substeps``, loss coefficients
    ``losses`` (`jaxhyst.Losses`; none by default: the static inverse model) — the
    arguments in the order of `jaxhyst.simulate`. Only the magnetic parameters (Ms, a,
    k, α̃, c and a form's own) enter. ``after_effect``: the path with the magnetization's
    relaxation (None: where ``losses.relax`` > 0; give True where the losses are traced,
    e.g. differentiated, and relax may be > 0). Raises ``FloatingPointError`` naming the
    first bad sample if the result is not finite. Traced (under ``jax.jit``,
    ``eqx.filter_grad`` …) it is `simulate_flux_unchecked`."""
    substeps, losses = _arguments(substeps, losses, "simulate_flux")
    if not isinstance(drive, FluxDrive):
        raise TypeError(f"drive must be a jaxhyst.FluxDrive (flux_from_record, "
                        f"sinusoidal_flux …); got {type(drive).__name__}.")
    if not isinstance(variant, FORM_TYPES):
        raise TypeError(f"variant must be a model form (EnergyBasedJA(), PlayJA() …); got "
                        f"{variant!r}.")
    if losses is not None and not isinstance(losses, Losses):
        raise TypeError(f"losses must be jaxhyst.Losses(eddy, excess, lag, relax); got {losses!r}.")
    if losses is not None:
        require_times(drive)
    substeps = checked_substeps(substeps)
    if jnp.ndim(drive.B) != 1:
        raise ValueError(f"simulate_flux takes one drive, but drive.B has shape "
                         f"{jnp.shape(drive.B)}; for a batch of drives use jax.vmap("
                         "simulate_flux_unchecked, in_axes=(None, 0)).")
    if any(jnp.ndim(getattr(params, n)) != 0 for n in params.names):
        raise ValueError("simulate_flux takes one parameter set; for a batch use jax.vmap("
                         "simulate_flux_unchecked).")
    check_parameters(params)
    if after_effect is None:  # (decided here, where relax is a value: under jit it is not)
        after_effect = _relaxes(losses)
    after_effect = bool(after_effect)
    if not is_concrete((params, drive, variant, losses)):  # (traced: nothing to check)
        return _simulate_flux_jit(params, drive, variant, substeps, losses, after_effect)
    sim, finite, more_substeps, finer = checked_meanwhile(
        lambda d, s: _simulate_flux_jit(params, d, variant, s, losses, after_effect),
        lambda: _simulate_flux_jit(params, drive, variant, substeps, losses, after_effect),
        lambda sim: np.isfinite(np.asarray(sim.H)),
        drive, np.asarray(drive.observed(drive.B)), substeps, losses,
        lambda t2, B2, run_in2: FluxDrive(t2, B2, run_in2, drive.uniform, drive.timed))
    if not finite.all():
        i = int(np.flatnonzero(~finite)[0])
        raise FloatingPointError(
            f"The B-driven simulation diverged from sample {i} (t = {float(drive.t[i]):g} s, "
            f"B = {float(drive.B[i]):g} T) on: the parameters or the flux density lie "
            "outside the model's range (a B above μ0·(H + Ms) cannot be reached).")
    _check_accuracy(substeps, sim, more_substeps, finer)
    return sim


def _check_accuracy(substeps, sim, more_substeps, finer) -> None:
    """A `SamplingWarning` where the error of H in ``sim`` — estimated from the same
    drive at twice the substeps (RK4 in B: ``more_substeps``) and, with losses, at half
    the sample step (``finer``), each None where not simulated — exceeds
    `FLUX_ACCURACY` of H's range (simulated only for drives whose B moves more than 1 %
    of its range per substep, or with losses)."""
    H = np.asarray(sim.observed("H"))
    size = float(np.ptp(H)) or 1.0
    in_substeps = in_samples = 0.0
    if more_substeps is not None:
        in_substeps = richardson_error(H, more_substeps.observed("H"), size)
    if finer is not None:
        in_samples = step_error(H, np.asarray(finer.observed("H"))[::2], size)
    error = max(in_substeps, in_samples)
    if error > FLUX_ACCURACY:
        # (the loss fields' error is the sample step's: more substeps do not reduce it;
        # near a reversal, where |dB/dt|^(1/2) and dH_hyst/dt turn, it falls only in
        # proportion to the step)
        fix = (f"sample B about {int(np.ceil(in_samples / (0.5 * FLUX_ACCURACY)))}× more "
               "finely (the loss fields' error falls with the sample step, not with the "
               "substeps)" if in_samples >= in_substeps else
               f"use {substeps_for(error * 0.1, substeps)} substeps or more, or sample B more "
               "finely")
        warnings.warn(f"the sampling is too coarse for the B-driven model: the error of H is "
                      f"estimated at {error:.2g} of its range (documented: <= "
                      f"{FLUX_ACCURACY:g}); {fix}.", SamplingWarning, stacklevel=3)


def sinusoidal_flux(frequency, amplitude, offset=0.0, **kwargs) -> FluxDrive:
    """B(t) = offset + amplitude·sin(2πft) (T); keyword arguments (periods,
    samples_per_period, run-in and ramp periods) as `jaxhyst.sinusoidal_field`."""
    from ..drive import _check_number, sinusoidal_field

    for name, value in (("amplitude", amplitude), ("offset", offset)):  # (in T, not A/m)
        _check_number(name, value, lambda v: True, " (T)")
    return FluxDrive.of(sinusoidal_field(frequency, amplitude, offset, **kwargs))


def flux_from_record(t, B, *, run_in_periods: int = 1, ramp_fraction: float = 0.25
                     ) -> FluxDrive:
    """A `FluxDrive` whose observed part is a measured record B(t) (T; t in s) spanning
    whole periods, preceded by a ramp from B = 0 and ``run_in_periods`` copies of it
    (`jaxhyst.drive_from_record`)."""
    from ..drive import checked_record, drive_from_record

    B = checked_record(t, B, "flux-density", "B")  # (in its own words: B, not the field)
    return FluxDrive.of(drive_from_record(t, B, run_in_periods=run_in_periods,
                                          ramp_fraction=ramp_fraction))


def flux_from_period(t, B, *, run_in_periods: int = 1) -> FluxDrive:
    """A `FluxDrive` for one period sampled without its end point (``t`` from 0 to T − dt,
    as the MagNet data): the period is closed with its first sample at T, so that its
    observed part is exactly one cycle."""
    t, B = np.asarray(t, dtype=np.float64), np.asarray(B, dtype=np.float64)
    if t.ndim != 1 or t.shape != B.shape or t.shape[0] < 4:
        raise ValueError(f"a period needs 1-D t and B of equal length (>= 4); got shapes "
                         f"{t.shape} and {B.shape}.")
    dt = (t[-1] - t[0]) / (t.shape[0] - 1)
    if not np.all(np.abs(np.diff(t) - dt) <= UNIFORM_TOLERANCE * dt):
        raise ValueError("the samples of a period must be uniform in time.")
    return flux_from_record(np.append(t, t[-1] + dt), np.append(B, B[0]),
                            run_in_periods=run_in_periods)
