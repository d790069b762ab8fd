"""The drive: time samples of the applied field H(t), with an optional run-in.

Between samples H is taken as piecewise linear (that is what a sampled drive means to the
integrator, and what the reference solver in the tests integrates too). The leading
``run_in`` samples are simulated but not observed: they carry the model from the
demagnetized state (M = 0 at the first sample) to the measured regime — a ramp from
H = 0 and/or whole periods whose transient is discarded.
"""

from __future__ import annotations

import math

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .actuator import Actuator


def _concrete(x) -> bool:
    return not isinstance(x, jax.core.Tracer)


class Drive(eqx.Module):
    """Sampled applied field.

    **Arguments:**
    - ``t``: sample times, s, shape (T,), strictly increasing.
    - ``H``: applied field at those times, A/m, shape (T,) (already including any bias).
    - ``run_in``: number of leading samples that are simulated but not observed.

    ``dt`` (static) is the common time step when the samples are uniformly spaced (to a
    relative 1e-9), else ``None``; uniform drives let the structural discretization be
    computed once instead of per interval. ``detect_uniform=False`` keeps ``dt = None``
    (drives stacked for a vmap over loops must share this static field).
    """

    t: jax.Array
    H: jax.Array
    run_in: int = eqx.field(static=True, default=0)
    dt: float | None = eqx.field(static=True, default=None)

    def __init__(self, t, H, run_in: int = 0, dt: float | None = None,
                 detect_uniform: bool = True):
        t = jnp.asarray(t, dtype=jnp.float64)
        H = jnp.asarray(H, dtype=jnp.float64)
        if t.ndim != 1 or H.ndim != 1:
            raise ValueError(
                f"Drive needs 1-D t and H (one sample per entry); got shapes {t.shape}, {H.shape}."
            )
        if t.shape != H.shape:
            raise ValueError(
                f"Drive t and H have mismatched lengths {t.shape[0]} and {H.shape[0]}; "
                "give one field value per time sample."
            )
        if t.shape[0] < 2:
            raise ValueError(f"Drive needs at least 2 samples; got {t.shape[0]}.")
        run_in = int(run_in)
        if not 0 <= run_in < t.shape[0] - 1:
            raise ValueError(
                f"Drive run_in={run_in} must be in [0, {t.shape[0] - 2}] so that at least "
                "two samples are observed."
            )
        if _concrete(t) and _concrete(H):
            tn, Hn = np.asarray(t), np.asarray(H)
            if not np.all(np.isfinite(tn)):
                raise ValueError(
                    "Drive time t contains NaN or inf; remove or repair those samples."
                )
            if not np.all(np.isfinite(Hn)):
                bad = np.flatnonzero(~np.isfinite(Hn))[:5]
                raise ValueError(
                    f"Drive field H contains NaN or inf at samples {bad.tolist()}; "
                    "remove or interpolate those samples."
                )
            steps = np.diff(tn)
            if np.any(steps <= 0):
                i = int(np.flatnonzero(steps <= 0)[0])
                raise ValueError(
                    f"Drive time must be strictly increasing; t[{i + 1}] = {tn[i + 1]} <= "
                    f"t[{i}] = {tn[i]}. Sort the samples or drop duplicates."
                )
            if dt is None and detect_uniform:
                mean = (tn[-1] - tn[0]) / (len(tn) - 1)
                if np.max(np.abs(steps - mean)) <= 1e-9 * mean:
                    dt = float(mean)
        self.t = t
        self.H = H
        self.run_in = run_in
        self.dt = None if dt is None else float(dt)

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def n_observed(self) -> int:
        return self.n_samples - self.run_in

    def observed(self, signal: jax.Array) -> jax.Array:
        """The observed part (after the run-in) of a per-sample signal, along axis -1."""
        return signal[..., self.run_in :]

    @classmethod
    def from_current(cls, t, current, actuator: Actuator, run_in: int = 0) -> Drive:
        """H = n·I + Hb from a coil current I (A), using the actuator's n (1/m) and Hb (A/m)."""
        if actuator.n is None:
            raise ValueError(
                f"{actuator.name} has no turns-per-metre n; give the drive as a field "
                "(Drive(t, H)) or set Actuator.n."
            )
        current = jnp.asarray(current, dtype=jnp.float64)
        return cls(t, actuator.n * current + actuator.Hb, run_in=run_in)


def drive_from_record(t, H, *, run_in_periods: int = 1, ramp_fraction: float = 0.25) -> Drive:
    """A `Drive` whose observed part is a measured record H(t) (A/m; t in s, or ``None``
    for a rate-independent B–H loop given as field samples only).

    The record should span a whole number of periods of a periodic drive (a closed loop).
    In front of it, as run-in: a linear ramp from H = 0 to H[0] lasting ``ramp_fraction``
    of the record (the model starts demagnetized and follows its initial curve), then
    ``run_in_periods`` copies of the record (the transient after the ramp is discarded),
    with the record's mean time step. If the record is closed (last H within 1e-6 of the
    range of the first), each copy omits the repeated end point.
    """
    H = np.asarray(H, dtype=np.float64)
    if H.ndim != 1 or H.shape[0] < 4:
        raise ValueError(f"A record needs at least 4 field samples; got shape {H.shape}.")
    if not np.all(np.isfinite(H)):
        bad = np.flatnonzero(~np.isfinite(H))[:5].tolist()
        raise ValueError(f"The field record contains NaN or inf at samples {bad}.")
    if t is None:
        t = np.arange(H.shape[0], dtype=np.float64)  # rate-independent: any time scale
    t = np.asarray(t, dtype=np.float64)
    if t.shape != H.shape:
        raise ValueError(f"t and H of a record differ in length ({t.shape[0]} vs {H.shape[0]}).")
    steps = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(steps <= 0):
        i = int(np.flatnonzero(~(steps > 0))[0]) if np.any(~(steps > 0)) else 0
        raise ValueError(f"Time must be finite and strictly increasing; it is not at sample "
                         f"{i + 1} (t = {t[i + 1]!r} after {t[i]!r}).")
    dt = float((t[-1] - t[0]) / (t.shape[0] - 1))
    span = float(np.ptp(H)) or 1.0
    closed = abs(H[-1] - H[0]) <= 1e-6 * span
    period_H = H[:-1] if closed else H
    n_ramp = max(2, int(round(ramp_fraction * H.shape[0]))) if ramp_fraction > 0 else 0
    pre = [H[0] * np.arange(n_ramp) / n_ramp] if n_ramp else []
    pre += [period_H] * int(run_in_periods)
    Hpre = np.concatenate(pre) if pre else np.zeros(0)
    n_pre = Hpre.shape[0]
    t_all = np.concatenate([t[0] + dt * np.arange(-n_pre, 0), t])
    H_all = np.concatenate([Hpre, H])
    return Drive(t_all, H_all, run_in=n_pre)


def sinusoidal_field(
    frequency: float,
    amplitude: float,
    offset: float = 0.0,
    *,
    periods: float = 1.0,
    samples_per_period: int = 200,
    run_in_periods: int = 1,
    ramp_periods: float = 0.25,
) -> Drive:
    """H(t) = offset + amplitude·sin(2π f t) (A/m), observed for ``periods`` periods.

    The observed window starts at t = 0 and is preceded (t < 0) by

    1. a linear ramp of H from 0 to H(0) lasting ``ramp_periods`` periods, so that the
       model starts demagnetized (M = 0 at H = 0) and follows its initial curve, and
    2. ``run_in_periods`` whole periods whose transient is discarded (the first period
       after a ramp differs from the steady state; later periods agree to ~1e-11).

    Both form the drive's ``run_in``. Samples are uniform with dt = 1/(f·samples_per_period).
    """
    if not (math.isfinite(frequency) and frequency > 0):
        raise ValueError(f"frequency must be a finite number > 0 Hz; got {frequency!r}.")
    if not (math.isfinite(amplitude) and math.isfinite(offset)):
        raise ValueError("amplitude and offset must be finite.")
    if int(samples_per_period) < 4:
        raise ValueError(f"samples_per_period must be >= 4; got {samples_per_period!r}.")
    if periods <= 0 or run_in_periods < 0 or ramp_periods < 0:
        raise ValueError("periods must be > 0, run_in_periods and ramp_periods >= 0.")
    spp = int(samples_per_period)
    dt = 1.0 / (frequency * spp)
    n_ramp = int(round(ramp_periods * spp))
    n_run = int(run_in_periods) * spp
    n_obs = int(round(periods * spp)) + 1  # closed loop: include the end point
    k = np.arange(-(n_ramp + n_run), n_obs)
    t = k * dt
    H = offset + amplitude * np.sin(2 * np.pi * frequency * t)
    if n_ramp:  # whole run-in periods: the sinusoid there starts at phase 0, H = offset
        H[:n_ramp] = H[n_ramp] * np.arange(n_ramp) / n_ramp
    return Drive(t, H, run_in=n_ramp + n_run, dt=dt)


def sinusoidal_current(
    frequency: float,
    amplitude: float,
    offset: float,
    actuator: Actuator,
    **kwargs,
) -> Drive:
    """I(t) = offset + amplitude·sin(2π f t) (A) through the actuator's coil: H = n·I + Hb.

    Keyword arguments are those of `sinusoidal_field`. The paper's Table 1 drive is
    ``sinusoidal_current(100.0, 0.77, 1.53, ACTUATOR1)``.
    """
    if actuator.n is None:
        raise ValueError(f"{actuator.name} has no turns-per-metre n; use sinusoidal_field.")
    return sinusoidal_field(
        frequency,
        actuator.n * amplitude,
        actuator.n * offset + actuator.Hb,
        **kwargs,
    )
