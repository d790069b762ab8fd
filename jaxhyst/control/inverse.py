"""The inverse model as a feedforward: the input that makes the model follow a reference,
by running each stage of the model backwards (`jaxhyst.model.inverse`).

displacement y(t) → magnetostriction λ(t) (structure inverted) → magnetization M(t) on
the bias's branch (magnetostriction inverted) → field H(t) (Jiles–Atherton driven by M —
by M + τ_M·dM/dt, the static magnetization it relaxes from, with the after-effect — then
the loss field of a conducting core, H_eddy + H_exc + H_lag at the rates of B =
μ0·(H_hyst + M) and H_hyst, added) → input u = (H − Hb)/gain.

Where the reference asks for more than the actuator reaches, λ is held inside the
reachable range first (the unreachable samples are reported by `jaxhyst.control.reach`).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._traces import kept_jit
from ..model.inverse import (
    field_for_magnetization,
    magnetization_for_magnetostriction,
    required_magnetostriction,
)
from ..model.losses import dynamic_field
from ..params import MU0
from .reach import Reach
from .reference import Reference
from .tracking import Tracking

#: Periods the inverse path runs before the one it returns (its field settles onto the
#: periodic loop geometrically, as the forward path's magnetization does).
INVERSE_RUN_IN_PERIODS = 30


class InverseInput(eqx.Module):
    """The inverse model's answer (host arrays, shape (N,)): ``u`` the input (A or A/m),
    ``lam`` the magnetostriction the reference's motion needs (before it is held inside
    the reachable range), ``M`` the magnetization placed on the bias's branch (A/m)."""

    u: np.ndarray
    lam: np.ndarray
    M: np.ndarray


#: (one small program, not five operations run one by one)
_magnetization = eqx.filter_jit(magnetization_for_magnetostriction)


@kept_jit
def _field(p, M, variant, substeps):
    return field_for_magnetization(p, M, variant, substeps)


def _rate(x: np.ndarray, t: np.ndarray, dt: float, periodic: bool) -> np.ndarray:
    """dx/dt: spectral for one period, second-order differences for a record."""
    if periodic:
        omega = 2.0 * np.pi * np.fft.rfftfreq(x.shape[0], dt)
        return np.fft.irfft(np.fft.rfft(x) * 1j * omega, x.shape[0])
    return np.gradient(x, t, edge_order=2)


def path_length(tracking: Tracking, reference: Reference) -> tuple[int, int]:
    """(samples of the inverse path, the first sample of the returned stretch): the ramp,
    then `INVERSE_RUN_IN_PERIODS` + 1 periods (a periodic reference) or a hold and the
    record."""
    if reference.periodic:
        start = tracking.n_ramp + INVERSE_RUN_IN_PERIODS * reference.n_samples
    else:
        start = tracking.n_ramp + tracking.hold
    return start + reference.n_samples, start


def compile_field(tracking: Tracking, reference: Reference) -> None:
    """Compile (and run once, on a path of zeros) the inverse path's program for this
    reference's shape: what `inverse_input` will run (a background compile)."""
    model = tracking.model
    zeros = np.zeros(path_length(tracking, reference)[0])  # (a transfer, not a program)
    _field(model.params, jnp.asarray(zeros), model.variant, model.substeps)


def inverse_input(tracking: Tracking, reference: Reference, reach: Reach) -> InverseInput:
    """The inverse model's input for ``reference`` (see the module docstring)."""
    model = tracking.model
    p = model.params
    y = np.asarray(reference.displacement, dtype=np.float64)
    t = np.asarray(reference.t, dtype=np.float64)
    dt = reference.dt
    lam = required_magnetostriction(p, model.actuator.Ar, y, dt, reference.periodic,
                                    None if reference.periodic else t)
    lam_lo, lam_hi = reach.lam
    held = np.clip(lam, lam_lo, lam_lo + (lam_hi - lam_lo) * (1.0 - 1e-6))
    M = np.asarray(_magnetization(jnp.asarray(held), p, reach.sign))
    # the static model's magnetization that M relaxes from (the after-effect,
    # τ_M·dM/dt = M_s − M): M itself without it
    tau = 0.0 if model.losses is None else float(model.losses.relax)
    Ms = M + tau * _rate(M, t, dt, reference.periodic) if tau > 0 else M
    ramp = Ms[0] * np.arange(tracking.n_ramp) / tracking.n_ramp
    if reference.periodic:
        path = np.concatenate([ramp, np.tile(Ms, INVERSE_RUN_IN_PERIODS + 1)])
    else:
        path = np.concatenate([ramp, np.full(tracking.hold, Ms[0]), Ms])
    start = path_length(tracking, reference)[1]
    H = np.asarray(_field(p, jnp.asarray(path), model.variant, model.substeps))[start:]
    if model.losses is not None:
        B = MU0 * (H + M)
        H = H + np.asarray(dynamic_field(jnp.asarray(_rate(B, t, dt, reference.periodic)),
                                         model.losses,
                                         jnp.asarray(_rate(H, t, dt, reference.periodic))))
    u = (H - float(model.actuator.Hb)) / tracking.gain
    return InverseInput(u=u, lam=lam, M=M)
