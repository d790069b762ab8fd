"""The drive: time samples of the applied field H(t), with an optional run-in.

Between samples H is taken as piecewise linear (that is what a sampled drive means to the
integrator, and what the reference solver in the tests integrates too). The leading
``run_in`` samples are simulated but not observed: they carry the model from the
demagnetized state (M = 0 at the first sample) to the measured regime — a ramp from
H = 0 and/or whole periods whose transient is discarded.
"""

from __future__ import annotations

import functools
import inspect

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ._typing import Array, ArrayLike, Float, Signal
from .actuator import Actuator
from .params import is_concrete

#: Largest relative deviation of a time step from the mean for a drive to count as
#: uniformly sampled (the structural step then corrects each step to second order).
UNIFORM_TOLERANCE = 1e-4

#: Largest applied field accepted, A/m (1e9 A/m ≈ 1.26 kT: beyond any laboratory field; a
#: larger value is a unit or column mistake and would overflow the model).
MAX_FIELD = 1e9
#: Highest drive frequency accepted, Hz (magnetic hysteresis is measured up to MHz).
MAX_FREQUENCY = 1e8
#: Most samples a drive builder makes (each sample of a simulation holds ~100 bytes of
#: signals, more under transformations): a larger request is a typing mistake.
MAX_SAMPLES = 50_000_000


class Drive(eqx.Module):
    """Sampled applied field.

    **Arguments:**
    - ``t``: sample times, s, shape (T,), strictly increasing.
    - ``H``: applied field at those times, A/m, shape (T,) (already including any bias).
    - ``run_in``: number of leading samples that are simulated but not observed.
    - ``uniform``: whether the samples are uniformly spaced (every step within 1e-4 of
      the mean step). ``None`` (default) detects it from a concrete ``t`` (also when the
      drive is built inside ``jit``/``grad`` from NumPy times); a traced ``t`` counts as
      non-uniform unless you say ``uniform=True``. The drive builders set it.
    - ``periodic``: the observed samples are whole periods of a drive repeated forever
      (their last sample closes the period: the same field as the first). The structural
      response over them is then the exact periodic steady state (solved for, not reached
      by waiting: `jaxhyst.model.structure.periodic_structural_response`); the
      magnetization still starts demagnetized and needs its run-in (a ramp and one or two
      periods settle it). Default False: everything starts at rest at the first sample.
    - ``timed``: whether ``t`` is real time (s). False for a rate-independent record given
      without times (`drive_from_record` with ``t=None``, which counts samples): the
      rate-dependent terms (`jaxhyst.Losses`) refuse such a drive (`require_times`).

    ``t`` and ``H`` are data: a new frequency, amplitude or jitter in ``t`` does not
    recompile a jitted simulation, and drives of equal length stack for ``vmap``. Only
    the length, ``run_in``, ``uniform``, ``periodic`` and ``timed`` are compile-time
    structure. Uniform drives
    share one structural discretization (one matrix exponential) instead of one per
    step.
    """

    t: Signal
    H: Signal
    run_in: int = eqx.field(static=True, default=0)
    uniform: bool = eqx.field(static=True, default=False)
    periodic: bool = eqx.field(static=True, default=False)
    timed: bool = eqx.field(static=True, default=True)

    def __init__(self, t, H, run_in: int = 0, uniform: bool | None = None,
                 periodic: bool = False, timed: bool = True):
        # inspect the values as given: inside a trace jnp.asarray turns even a NumPy
        # array into a tracer, and a drive built there from concrete times would lose
        # its uniform sampling (and its checks)
        t_given, H_given = t, H
        t, H = _samples(t, "t", "times in s"), _samples(H, "H", "fields in A/m")
        if t.ndim != 1 or H.ndim != 1:
            raise ValueError(
                f"Drive needs 1-D t and H (one sample per entry); got shapes {t.shape}, "
                f"{H.shape}. (A batch of drives: build each, then stack them with "
                "jax.tree.map(jnp.stack, ...).)"
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
        if is_concrete(H_given):
            Hn = np.asarray(H_given, dtype=np.float64)
            if not np.all(np.isfinite(Hn)):
                bad = np.flatnonzero(~np.isfinite(Hn))[:5]
                raise ValueError(
                    f"Drive field H contains NaN or inf at samples {bad.tolist()}; "
                    "remove or interpolate those samples."
                )
            _check_field_range(Hn, "Drive field H")
            span = float(np.ptp(Hn[run_in:])) or 1.0
            if periodic and abs(Hn[-1] - Hn[run_in]) > 1e-9 * span:
                raise ValueError(
                    f"Drive(periodic=True): the observed samples must close the period "
                    f"(H[-1] = {Hn[-1]:g} A/m, the first observed H[{run_in}] = "
                    f"{Hn[run_in]:g} A/m); end the record with its first sample repeated.")
        if is_concrete(t_given):
            tn = np.asarray(t_given, dtype=np.float64)
            if not np.all(np.isfinite(tn)):
                raise ValueError(
                    "Drive time t contains NaN or inf; remove or repair those samples."
                )
            steps = np.diff(tn)
            if np.any(steps <= 0):
                i = int(np.flatnonzero(steps <= 0)[0])
                raise ValueError(
                    f"Drive time must be strictly increasing; t[{i + 1}] = {tn[i + 1]} <= "
                    f"t[{i}] = {tn[i]}. Sort the samples or drop duplicates."
                )
            mean = (tn[-1] - tn[0]) / (len(tn) - 1)
            is_uniform = bool(np.max(np.abs(steps - mean)) <= UNIFORM_TOLERANCE * mean)
            if uniform is None:
                uniform = is_uniform
            elif uniform and not is_uniform:
                raise ValueError(
                    "Drive(uniform=True): the time steps deviate from their mean by more "
                    f"than {UNIFORM_TOLERANCE:g} relative; leave uniform unset."
                )
        self.t = t
        self.H = H
        self.run_in = run_in
        self.uniform = bool(uniform)
        self.periodic = bool(periodic)
        self.timed = bool(timed)

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[-1])

    @property
    def n_observed(self) -> int:
        return self.n_samples - self.run_in

    @property
    def dt(self) -> jax.Array:
        """Mean time step (t[-1] − t[0])/(T − 1), s."""
        return (self.t[..., -1] - self.t[..., 0]) / (self.n_samples - 1)

    def observed(self, signal: Float[Array, "*batch T"]) -> Float[Array, "*batch T_obs"]:
        """The observed part (after the run-in) of a per-sample signal, along axis -1."""
        return signal[..., self.run_in :]

    @classmethod
    def from_current(cls, t, current, actuator: Actuator, run_in: int = 0,
                     uniform: bool | None = None) -> Drive:
        """H = n·I + Hb from a coil current I (A), using the actuator's n (1/m) and Hb (A/m)."""
        if actuator.n is None:
            raise ValueError(
                f"{actuator.name} has no turns-per-metre n; give the drive as a field "
                "(Drive(t, H)) or set Actuator.n."
            )
        if not isinstance(current, jax.Array):  # (a list would reach jit as T scalars)
            current = np.asarray(current, dtype=np.float64)
        H = _field_from_current(_strong(actuator.n), _strong(actuator.Hb), current)
        return cls(t, H, run_in=run_in, uniform=uniform)


def _samples(x, name: str, what: str):
    """A drive's samples as a float64 array; a one-line error for anything that is not
    numbers."""
    try:
        return jnp.asarray(x, dtype=jnp.float64)
    except (TypeError, ValueError):
        shown = repr(x) if len(repr(x)) <= 60 else repr(x)[:57] + "..."
        raise ValueError(f"Drive {name} must be a sequence of numbers ({what}); got "
                         f"{shown}.") from None


@jax.jit
def _field_from_current(n, Hb, current):
    """H = n·I + Hb (A/m), one compiled program."""
    return _as_float(n) * _as_float(current) + _as_float(Hb)


def _repeat_lag(H, span) -> int | None:
    """The period (samples) of a record that repeats but does not end where it began (a
    capture of 1.5 periods from any phase): the lag, after the record has moved 20 % of
    its range away from itself, at which it first matches itself best within 1 % of its
    range (rms, over at least 5 % of it and 8 samples), or None. Its run-in is then
    whole periods ending in the phase the record starts in (copies of the whole record
    would jump, and leave the model off its steady loop)."""
    n, x = H.shape[0], H - np.mean(H)
    f = np.fft.rfft(x, 2 * n)
    r = np.fft.irfft(f * np.conj(f), 2 * n)[:n]  # Σ_i x[i + lag]·x[i]
    c = np.concatenate([[0.0], np.cumsum(x * x)])
    lags = np.arange(n)
    msd = (c[n] - c[lags] + c[n - lags] - 2.0 * r) / (n - lags)  # mean (x[i+lag] − x[i])²
    apart = np.flatnonzero(msd > (0.2 * span) ** 2)  # (first it must differ from itself)
    ok = (lags > (apart[0] if apart.size else n)) & (n - lags >= max(8, n // 20)) & \
        (msd <= (0.01 * span) ** 2)
    if not np.any(ok):
        return None
    first = int(np.argmax(ok))  # (then the bottom of the first valley it matches in)
    end = first + int(np.argmin(ok[first:])) if not np.all(ok[first:]) else n
    return first + int(np.argmin(msd[first:end]))


def checked_record(t, x, quantity: str, name: str) -> np.ndarray:
    """A record's samples ``x`` (named ``name``, a ``quantity`` record) as a float64
    vector: one dimension, at least 4 samples, finite, and as many as ``t`` (unless None);
    ValueError (one line) otherwise."""
    x = np.asarray(x, dtype=np.float64)
    if x.ndim != 1 or x.shape[0] < 4:
        raise ValueError(f"A record needs at least 4 {quantity} samples in one dimension (one "
                         f"value per sample); got shape {x.shape}.")
    if not np.all(np.isfinite(x)):
        bad = np.flatnonzero(~np.isfinite(x))[:5].tolist()
        raise ValueError(f"The {quantity} record contains NaN or inf at samples {bad}.")
    if t is not None and np.shape(t) != x.shape:
        raise ValueError(f"t and {name} of a record differ in length ({np.size(t)} vs "
                         f"{x.shape[0]})." if np.ndim(t) == 1 else f"t must be one value "
                         f"per sample of {name}, in one dimension; got shape {np.shape(t)}.")
    return x


def drive_from_record(t: Float[ArrayLike, " T"] | None, H: Float[ArrayLike, " T"], *,
                      run_in_periods: int = 1, ramp_fraction: float = 0.25) -> Drive:
    """A `Drive` whose observed part is a measured record H(t) (A/m; t in s, or ``None``
    for a rate-independent B–H loop given as field samples only: its steps then count
    samples, ``Drive.timed`` is False, and the rate-dependent model refuses it).

    The record should span a whole number of periods of a periodic drive (a closed loop).
    In front of it, as run-in: a linear ramp from H = 0 to H[0] lasting ``ramp_fraction``
    of the record (the model starts demagnetized and follows its initial curve), then
    ``run_in_periods`` copies of the record (the transient after the ramp is discarded),
    with the record's mean time step. If the record is closed (last H within 1e-6 of the
    range of the first), each copy omits the repeated end point; if it is not but
    repeats (1.5 periods from any phase), each copy is its first period (`_repeat_lag`).
    """
    H = checked_record(t, H, "field", "H")
    _check_field_range(H, "The field record", "check its unit (A/m) and the column it "
                       "was read from")
    timed = t is not None
    if not timed:
        t = np.arange(H.shape[0], dtype=np.float64)  # rate-independent: any time scale
    t = np.asarray(t, dtype=np.float64)
    steps = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(steps <= 0):
        i = int(np.flatnonzero(~(steps > 0))[0]) if np.any(~(steps > 0)) else 0
        raise ValueError(f"Time must be finite and strictly increasing; it is not at sample "
                         f"{i + 1} (t = {t[i + 1]!r} after {t[i]!r}).")
    dt = float((t[-1] - t[0]) / (t.shape[0] - 1))
    span = float(np.ptp(H)) or 1.0
    closed = abs(H[-1] - H[0]) <= 1e-6 * span
    lag = None if closed else _repeat_lag(H, span)
    period_H = H[:-1] if closed else H if lag is None else H[:lag]
    n_ramp = max(2, int(round(ramp_fraction * H.shape[0]))) if ramp_fraction > 0 else 0
    pre = [H[0] * np.arange(n_ramp) / n_ramp] if n_ramp else []
    pre += [period_H] * int(run_in_periods)
    Hpre = np.concatenate(pre) if pre else np.zeros(0)
    n_pre = Hpre.shape[0]
    t_all = np.concatenate([t[0] + dt * np.arange(-n_pre, 0), t])
    H_all = np.concatenate([Hpre, H])
    return Drive(t_all, H_all, run_in=n_pre, timed=timed)


def require_times_for(space, drives) -> None:
    """`require_times` for each of ``drives`` where the parameter space ``space`` holds
    loss coefficients (`jaxhyst.ParameterSpace.with_losses`: the rate-dependent model)."""
    from .names import LOSS_PARAMETER_NAMES, base_name

    if any(base_name(name) in LOSS_PARAMETER_NAMES for name in space.flat_names):
        for drive in drives:
            require_times(drive, "loss coefficients (a space with losses)")


def require_times(drive, what: str = "losses") -> None:
    """Refuse rate-dependent terms (``what``) on a drive built without times
    (``drive.timed`` False: its steps count samples, so a rate dB/dt means nothing)."""
    if not getattr(drive, "timed", True):
        raise ValueError(f"{what} need the record's times: this drive was built without "
                         "them (drive_from_record(None, …) counts samples, not seconds), so "
                         "its rates mean nothing; give the times in s, e.g. "
                         "drive_from_record(t, H).")


def _check_field_range(H, what: str, fix: str = "check its unit (A/m)") -> None:
    big = np.flatnonzero(np.abs(H) > MAX_FIELD)
    if big.size:
        i = int(big[0])
        raise ValueError(f"{what} at sample {i} is {H[i]:g} A/m, beyond {MAX_FIELD:g} A/m "
                         f"(no laboratory field); {fix}.")


def _check_number(name, value, rule, unit):
    """One-line error for a concrete non-finite (or out-of-range) builder argument."""
    if not is_concrete(value):
        return
    v = np.asarray(value, dtype=np.float64)
    if v.ndim or not np.isfinite(v) or not rule(float(v)):
        raise ValueError(f"{name} must be a finite number{unit}; got {value!r}.")


def sinusoidal_field(
    frequency,
    amplitude,
    offset=0.0,
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
    ``frequency`` (Hz), ``amplitude`` and ``offset`` (A/m) may be traced (differentiate
    through them, vmap over them); the sample counts are structure.
    """
    return _sinusoidal(frequency, amplitude, offset, 1.0, 0.0, periods, samples_per_period,
                       run_in_periods, ramp_periods)


def _sinusoidal(frequency, amplitude, offset, scale, shift, periods, samples_per_period,
                run_in_periods, ramp_periods) -> Drive:
    """`sinusoidal_field` of H = scale·(offset + amplitude·sin) + shift, scale·offset +
    shift and scale·amplitude formed as `sinusoidal_current` forms them."""
    _check_number("frequency", frequency, lambda v: 0 < v <= MAX_FREQUENCY,
                  f" in (0, {MAX_FREQUENCY:g}] Hz (magnetic hysteresis is measured up to MHz)")
    _check_number("amplitude", amplitude, lambda v: True, " (A/m)")
    _check_number("offset", offset, lambda v: True, " (A/m)")
    if int(samples_per_period) != samples_per_period or int(samples_per_period) < 4:
        raise ValueError(f"samples_per_period must be an integer >= 4; got "
                         f"{samples_per_period!r}.")
    if not (periods > 0 and run_in_periods >= 0 and ramp_periods >= 0):
        raise ValueError("periods must be > 0, run_in_periods and ramp_periods >= 0; got "
                         f"{periods!r}, {run_in_periods!r}, {ramp_periods!r}.")
    spp = int(samples_per_period)
    total = (periods + run_in_periods + ramp_periods) * spp
    if total > MAX_SAMPLES:
        raise ValueError(f"the drive would have {total:.3g} samples ({periods:g} periods of "
                         f"{spp}, with the run-in), about {total * 1e-7:.2g} GB simulated; at "
                         f"most {MAX_SAMPLES:.0e}: observe fewer periods or samples.")
    n_ramp = int(round(ramp_periods * spp))
    n_run = int(run_in_periods) * spp
    n_obs = int(round(periods * spp)) + 1  # closed loop: include the end point
    k = np.arange(-(n_ramp + n_run), n_obs, dtype=np.float64)
    phase = 2 * np.pi * k / spp  # 2π f t, exact in the sample index
    t, H = _sinusoid(*map(_strong, (frequency, amplitude, offset, scale, shift)), k, phase,
                     spp, n_ramp)
    return Drive(t, H, run_in=n_ramp + n_run, uniform=True)


def _strong(x):
    """A Python or NumPy number as a float64 scalar (a weakly typed Python float would
    key another compilation than the actuator's float64 arrays); arrays unchanged."""
    return x if isinstance(x, jax.Array) else np.float64(x)


def _as_float(x):
    return jnp.asarray(x, dtype=jnp.float64)


@functools.partial(jax.jit, static_argnums=(7, 8))
def _sinusoid(frequency, amplitude, offset, scale, shift, k, phase, spp: int, n_ramp: int):
    """(t, H) of `_sinusoidal` at sample indices k and phases 2πk/spp, one compiled
    program (run op by op, each operation would compile on its own at the first call)."""
    scale = _as_float(scale)
    t = k / (_as_float(frequency) * spp)
    H = (scale * offset + shift) + (scale * amplitude) * jnp.sin(phase)
    if n_ramp:  # whole run-in periods: the sinusoid there starts at phase 0, H = offset
        H = H.at[:n_ramp].set(H[n_ramp] * jnp.arange(n_ramp) / n_ramp)
    return t, H


def sinusoidal_current(
    frequency,
    amplitude,
    offset,
    actuator: Actuator,
    **kwargs,
) -> Drive:
    """I(t) = offset + amplitude·sin(2π f t) (A) through the actuator's coil: H = n·I + Hb.

    Keyword arguments are those of `sinusoidal_field`. The paper's Table 1 drive is
    ``sinusoidal_current(100.0, 0.77, 1.53, ACTUATOR1)``. Traceable like it.
    """
    if not isinstance(actuator, Actuator):
        raise TypeError(f"sinusoidal_current's actuator must be a jaxhyst.Actuator (e.g. "
                        f"jaxhyst.ACTUATOR1); got {type(actuator).__name__}.")
    if actuator.n is None:
        raise ValueError(f"{actuator.name} has no turns-per-metre n; use sinusoidal_field.")
    _check_number("amplitude", amplitude, lambda v: True, " (A)")
    _check_number("offset", offset, lambda v: True, " (A)")
    options = {name: q.default for name, q in
               inspect.signature(sinusoidal_field).parameters.items()
               if q.kind is q.KEYWORD_ONLY}
    unknown = set(kwargs) - set(options)
    if unknown:
        raise TypeError(f"sinusoidal_current got unexpected keyword arguments "
                        f"{sorted(unknown)}; it takes those of sinusoidal_field: "
                        f"{list(options)}.")
    options.update(kwargs)
    return _sinusoidal(frequency, amplitude, offset, actuator.n, actuator.Hb, **options)
