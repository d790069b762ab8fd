"""The model driven through a reference's samples: input u (shape (N,)) → displacement
at the reference's times (shape (N,)), one pure function for the optimiser, the learning
controller and the reports.

- **Periodic reference**: the drive is a ramp from the demagnetized state (H = 0) to the
  first input, ``run_in_periods`` periods of u for the magnetization to settle onto its
  periodic loop, and the observed period; the structure is in its exact periodic steady
  state there (`Drive.periodic`). The run-in periods are chosen by `settling_periods`.
- **Record**: a ramp to the first input, a hold there until the structure is at rest,
  then the record.

The input is the coil current (A) when the actuator has turns per metre n, else the AC
field (A/m): H = gain·u + Hb with gain = n or 1.
"""

from __future__ import annotations

import dataclasses
import math

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._traces import kept_jit
from .._typing import Array, Float
from ..drive import Drive
from ..model.simulate import Simulation
from ..saved import Model
from .reference import Reference

#: Most run-in periods the magnetization is given to settle.
MAX_RUN_IN_PERIODS = 64
#: Change of M per period (relative to Ms) below which it counts as settled.
SETTLED = 1e-10
#: e-folds of the structure's decay waited at rest before a record (e^-14 ≈ 1e-6).
REST_EFOLDS = 14.0
#: Most samples of that wait.
MAX_HOLD = 20000


def input_gain(model: Model) -> tuple[float, str]:
    """(gain, unit) of the input: (n, "A") for an actuator with turns per metre, else
    (1, "A/m") (the input is the AC field)."""
    n = model.actuator.n
    return (1.0, "A/m") if n is None else (float(n), "A")


class Tracking(eqx.Module):
    """The model (``model``) driven by an input through the samples of ``reference``
    (see the module docstring). ``run_in_periods`` (periodic) and ``hold`` (record:
    samples at rest before it) are structure."""

    model: Model
    t: Float[Array, " N"]
    gain: float = eqx.field(static=True)
    periodic: bool = eqx.field(static=True)
    uniform: bool = eqx.field(static=True)
    n_ramp: int = eqx.field(static=True)
    run_in_periods: int = eqx.field(static=True, default=2)
    hold: int = eqx.field(static=True, default=0)

    @classmethod
    def of(cls, model: Model, reference: Reference, run_in_periods: int = 2) -> Tracking:
        gain, _ = input_gain(model)
        t = np.asarray(reference.t)
        dt = float((t[-1] - t[0]) / (t.shape[0] - 1))
        uniform = bool(np.max(np.abs(np.diff(t) - dt)) <= 1e-4 * dt)
        N = t.shape[0]
        hold = 0
        if not reference.periodic:
            p = model.params
            decay = 2.0 * float(p.Mz) / max(float(p.Cz), 1e-300)  # 1/(ζω), s
            hold = int(min(MAX_HOLD, math.ceil(REST_EFOLDS * decay / dt)))
        return cls(model, jnp.asarray(t), gain, reference.periodic, uniform,
                   max(4, N // 4), int(run_in_periods), hold)

    @property
    def n(self) -> int:
        return int(self.t.shape[0])

    @property
    def run_in(self) -> int:
        return self.n_ramp + (self.run_in_periods * self.n if self.periodic else self.hold)

    def with_run_in(self, periods: int) -> Tracking:
        return dataclasses.replace(self, run_in_periods=int(periods))

    def field(self, u) -> Float[Array, " N"]:
        """H (A/m) of the input u."""
        return self.gain * u + self.model.actuator.Hb

    def drive(self, u: Float[Array, " N"]) -> Drive:
        """The whole drive (run-in and observed samples) of the input u."""
        H = self.field(u)
        ramp = H[0] * jnp.arange(self.n_ramp, dtype=H.dtype) / self.n_ramp
        dt = (self.t[-1] - self.t[0]) / (self.n - 1)
        if self.periodic:
            H_all = jnp.concatenate([ramp, jnp.tile(H, self.run_in_periods + 1), H[:1]])
            k = jnp.arange(H_all.shape[0], dtype=H.dtype) - self.run_in
            return Drive(self.t[0] + dt * k, H_all, run_in=self.run_in, uniform=True,
                         periodic=True)
        H_all = jnp.concatenate([ramp, jnp.full((self.hold,), H[0]), H])
        before = self.t[0] + dt * jnp.arange(-self.run_in, 0, dtype=H.dtype)
        return Drive(jnp.concatenate([before, self.t]), H_all, run_in=self.run_in,
                     uniform=self.uniform)

    def simulation(self, u) -> Simulation:
        """Every signal of the model driven by u (`jaxhyst.simulate_unchecked`)."""
        return self.model.simulate_unchecked(self.drive(u))

    def displacement(self, u: Float[Array, " N"]) -> Float[Array, " N"]:
        """y (m) at the reference's samples for the input u."""
        y = self.simulation(u).y
        return y[self.run_in: self.run_in + self.n]


@kept_jit
def _period_starts(tracking: Tracking, u):
    sim = tracking.simulation(u)
    starts = tracking.n_ramp + tracking.n * jnp.arange(tracking.run_in_periods + 1)
    return sim.M[starts]


def settling_periods(tracking: Tracking, u) -> tuple[int, float]:
    """(run-in periods, the change of M per period left, relative to Ms) for the
    periodic input ``u``: the magnetization after the ramp approaches its periodic loop
    geometrically (fast where the input saturates it, slowly for a small loop with large
    pinning); enough periods that the change per period is below `SETTLED`, plus one,
    rounded up to a power of two (the count is compiled structure: a few counts serve
    every reference)."""
    long = tracking.with_run_in(MAX_RUN_IN_PERIODS)
    M = np.asarray(_period_starts(long, jnp.asarray(u)))
    change = np.abs(np.diff(M)) / float(tracking.model.params.Ms)
    settled = np.flatnonzero(change <= SETTLED)
    if settled.size == 0:
        return MAX_RUN_IN_PERIODS, float(change[-1])
    k = int(settled[0]) + 1
    periods = min(MAX_RUN_IN_PERIODS, 2 ** max(1, math.ceil(math.log2(k + 1))))
    return periods, float(change[min(periods, change.shape[0]) - 1])


def compile_settling(tracking: Tracking) -> None:
    """Compile (and run once, on a zero input) the program `settling_periods` will run
    for this tracking's shape (a background compile)."""
    _period_starts(tracking.with_run_in(MAX_RUN_IN_PERIODS), jnp.asarray(np.zeros(tracking.n)))


def evaluate(tracking: Tracking, u) -> np.ndarray:
    """`Tracking.displacement` of u as host values (one compiled program)."""
    return np.asarray(_displacement(tracking, jnp.asarray(u)))


@kept_jit
def _displacement(tracking, u):
    return tracking.displacement(u)

