"""The displacement an actuator should follow: `Reference` and its builders.

A reference is either **periodic** — one period of N uniform samples, to be repeated
forever (the compensating current is then periodic too, and tracking is judged in the
steady state) — or a **record**: samples at increasing times, started from rest. Every
builder checks its input and says in one line what is wrong and how to fix it.
"""

from __future__ import annotations

from collections.abc import Sequence

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._typing import Array, Float
from ..actuator import Actuator
from ..drive import MAX_SAMPLES

#: Fewest samples a reference may have (per period for a periodic one).
MIN_SAMPLES = 8
#: Largest displacement magnitude accepted, m (beyond any magnetostrictive actuator: a
#: unit mistake).
LARGEST_DISPLACEMENT = 0.1
#: Relative deviation of a time step from the mean step that still counts as uniform.
UNIFORM_TOLERANCE = 1e-4


class Reference(eqx.Module):
    """The desired displacement.

    - ``t``: sample times, s, shape (N,); uniform for a periodic reference, whose period
      is N·dt (the samples do not repeat the first one at the end).
    - ``displacement``: desired y at those times, m, shape (N,).
    - ``periodic``: one period of a periodic reference (True) or a record (False).

    Build one with `sinusoidal_reference`, `multitone_reference` or
    `reference_from_record` (which check their input).
    """

    t: Float[Array, " N"]
    displacement: Float[Array, " N"]
    periodic: bool = eqx.field(static=True, default=True)

    @property
    def n_samples(self) -> int:
        return int(self.t.shape[0])

    @property
    def dt(self) -> float:
        """The mean time step, s."""
        t = np.asarray(self.t)
        return float((t[-1] - t[0]) / (t.shape[0] - 1))

    @property
    def period(self) -> float | None:
        """N·dt (s) of a periodic reference; None for a record."""
        return self.n_samples * self.dt if self.periodic else None

    @property
    def scale(self) -> float:
        """What tracking errors are relative to: the reference's peak-to-peak (its
        stroke), m; for a constant reference its magnitude."""
        y = np.asarray(self.displacement)
        return float(np.ptp(y)) or float(np.max(np.abs(y)))


def _as_samples(x, name: str, unit: str, per: str = "sample") -> np.ndarray:
    """``x`` as a 1-D float64 array of finite values, one per ``per`` (a one-line
    ``ValueError`` naming ``name`` otherwise)."""
    try:
        x = np.asarray(x, dtype=np.float64)
    except (TypeError, ValueError):
        raise ValueError(f"reference {name} must be numbers ({unit}); got "
                         f"{str(x)[:40]!r}.") from None
    if x.ndim != 1:
        raise ValueError(f"reference {name} must be a 1-D sequence (one value per {per}); "
                         f"got shape {x.shape}.")
    bad = np.flatnonzero(~np.isfinite(x))
    if bad.size:
        raise ValueError(f"reference {name} is NaN or infinite at {per}s "
                         f"{bad[:5].tolist()} (of {x.shape[0]}); remove or interpolate them.")
    return x


def _check_displacement(y: np.ndarray) -> None:
    big = np.flatnonzero(np.abs(y) > LARGEST_DISPLACEMENT)
    if big.size:
        i = int(big[0])
        raise ValueError(f"reference displacement[{i}] = {y[i]:g} m is beyond any "
                         f"magnetostrictive actuator (|y| <= {LARGEST_DISPLACEMENT:g} m); "
                         "give the displacement in metres (or strain with strain=).")
    if not np.any(y):
        raise ValueError("the reference displacement is zero everywhere: nothing to track "
                         "(the current that holds y = 0 is not a compensation problem).")


def _check_sampling(samples_per_period) -> int:
    if int(samples_per_period) != samples_per_period or not \
            MIN_SAMPLES <= samples_per_period <= MAX_SAMPLES:
        raise ValueError(f"samples_per_period must be an integer in [{MIN_SAMPLES}, "
                         f"{MAX_SAMPLES:.0e}]; got {samples_per_period!r}.")
    return int(samples_per_period)


def _check_frequency(frequency) -> float:
    try:
        f = float(frequency)
    except (TypeError, ValueError):
        raise ValueError(f"frequency must be a number in Hz; got {frequency!r}.") from None
    if not (np.isfinite(f) and 0 < f <= 1e6):
        raise ValueError(f"frequency must be in (0, 1e6] Hz (a magnetostrictive actuator "
                         f"follows kHz at most); got {frequency!r}.")
    return f


def multitone_reference(frequency: float, amplitudes: Sequence[float], mean: float, *,
                        harmonics: Sequence[int] | None = None,
                        phases: Sequence[float] | None = None,
                        samples_per_period: int = 200) -> Reference:
    """y(t) = mean + Σ_k A_k·sin(2π·h_k·f·t + φ_k) (m): tones at harmonics h_k of the
    fundamental ``frequency`` f (Hz), so that the reference repeats with period 1/f.

    ``amplitudes`` A_k (m); ``harmonics`` h_k (positive integers, default 1, 2, 3 …);
    ``phases`` φ_k (rad, default 0). ``samples_per_period`` uniform samples from t = 0.
    """
    f = _check_frequency(frequency)
    N = _check_sampling(samples_per_period)
    amplitudes = _as_samples(amplitudes, "amplitudes", "m", per="tone")
    K = amplitudes.shape[0]
    harmonics = np.arange(1, K + 1) if harmonics is None else \
        _as_samples(harmonics, "harmonics", "multiples of the fundamental", per="tone")
    phases = np.zeros(K) if phases is None else _as_samples(phases, "phases", "rad",
                                                            per="tone")
    if harmonics.shape != (K,) or phases.shape != (K,):
        raise ValueError(f"give one harmonic and one phase per amplitude ({K}); got "
                         f"{harmonics.shape[0]} harmonics and {phases.shape[0]} phases.")
    if np.any(harmonics < 1) or np.any(harmonics != np.round(harmonics)):
        raise ValueError(f"harmonics must be positive integers (multiples of the "
                         f"fundamental); got {harmonics.tolist()}.")
    if 2 * int(np.max(harmonics)) >= N:
        raise ValueError(f"harmonic {int(np.max(harmonics))} needs more than {N} samples "
                         f"per period (at least {2 * int(np.max(harmonics)) + 1}; 20 per "
                         "period of the highest tone for the model's accuracy).")
    t = np.arange(N) / (f * N)
    phase = 2.0 * np.pi * np.outer(t * f, harmonics) + phases
    y = float(mean) + np.sin(phase) @ amplitudes
    _check_displacement(y)
    return Reference(jnp.asarray(t), jnp.asarray(y), periodic=True)


def sinusoidal_reference(frequency: float, amplitude: float, mean: float, *,
                         samples_per_period: int = 200) -> Reference:
    """y(t) = mean + amplitude·sin(2π·f·t) (m), one period of ``samples_per_period``
    uniform samples (f = ``frequency`` in Hz)."""
    return multitone_reference(frequency, [amplitude], mean,
                               samples_per_period=samples_per_period)


def reference_from_record(t, displacement=None, *, strain=None,
                          actuator: Actuator | None = None, periodic: bool = False,
                          frequency: float | None = None) -> Reference:
    """A reference from samples: times ``t`` (s) and ``displacement`` (m) — or ``strain``
    (dimensionless, with the ``actuator`` whose rod length lr turns it into y = ε·lr).

    - ``periodic=False`` (default): a record, tracked from rest.
    - ``periodic=True``: the samples are one period (uniform; a last sample that repeats
      the first closes the period and is dropped).
    - ``frequency`` (Hz): a periodic reference with period 1/f taken from a longer
      record: it must span at least one period, uniformly sampled with a whole number of
      samples per period; the whole periods it holds are averaged.
    """
    if (displacement is None) == (strain is None):
        raise ValueError("give the reference as displacement (m) or as strain, one of them.")
    t = _as_samples(t, "t", "s")
    if strain is not None:
        if not isinstance(actuator, Actuator):
            raise ValueError("a strain reference needs the actuator (its rod length lr "
                             "turns strain into displacement).")
        y = _as_samples(strain, "strain", "1") * float(actuator.lr)
    else:
        y = _as_samples(displacement, "displacement", "m")
    if t.shape != y.shape:
        raise ValueError(f"reference t and displacement differ in length ({t.shape[0]} vs "
                         f"{y.shape[0]}).")
    if t.shape[0] < MIN_SAMPLES:
        raise ValueError(f"a reference needs at least {MIN_SAMPLES} samples; got "
                         f"{t.shape[0]}.")
    steps = np.diff(t)
    if np.any(steps <= 0):
        i = int(np.flatnonzero(steps <= 0)[0])
        raise ValueError(f"reference times must increase; t[{i + 1}] = {t[i + 1]:g} s "
                         f"follows t[{i}] = {t[i]:g} s. Sort the samples or drop duplicates.")
    dt = float((t[-1] - t[0]) / (t.shape[0] - 1))
    uniform = bool(np.max(np.abs(steps - dt)) <= UNIFORM_TOLERANCE * dt)
    if frequency is not None:
        f = _check_frequency(frequency)
        per_period = 1.0 / (f * dt)
        N = int(round(per_period))
        span = t[-1] - t[0] + dt
        if span < (1.0 - 1e-6) / f:
            raise ValueError(f"the reference spans {span:g} s, shorter than one period "
                             f"(1/{f:g} Hz = {1.0 / f:g} s); give at least one whole period.")
        if not uniform or abs(per_period - N) > 1e-3 * max(N, 1):
            raise ValueError(f"a periodic reference needs uniform samples, a whole number "
                             f"per period; these give {per_period:.4g} per period of "
                             f"1/{f:g} Hz. Resample it.")
        whole = t.shape[0] // N
        y = y[: whole * N].reshape(whole, N).mean(axis=0)
        t = t[0] + dt * np.arange(N)
        periodic = True
    elif periodic:
        if not uniform:
            raise ValueError("a periodic reference needs uniformly sampled times (each step "
                             f"within {UNIFORM_TOLERANCE:g} of the mean); resample it.")
        scale = float(np.ptp(y)) or 1.0
        if abs(y[-1] - y[0]) <= 1e-9 * scale and y.shape[0] > MIN_SAMPLES:
            t, y = t[:-1], y[:-1]  # the closing sample
    _check_displacement(y)
    return Reference(jnp.asarray(t), jnp.asarray(y), periodic=bool(periodic))
