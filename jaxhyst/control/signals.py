"""What a measurement says, for learning control: its noise level, its delay against the
model's prediction, and the part of an error worth learning (zero-phase low pass, without
the frequencies the noise could explain). NumPy, on the host."""

from __future__ import annotations

import numpy as np

#: Largest acquisition delay searched, as a fraction of the reference's samples.
MAX_DELAY = 0.1


def noise_level(measured: np.ndarray, e: np.ndarray) -> float:
    """σ of a measurement (its unit): from the scatter of repeated measurements (R, N)
    of one input (σ of one of them), else from the upper half of the spectrum of the
    error e (white noise puts as much power there as anywhere)."""
    if measured.ndim == 2 and measured.shape[0] >= 2:
        return float(np.sqrt(np.mean(np.var(measured, axis=0, ddof=1))))
    E = np.fft.rfft(e - np.mean(e))
    N = e.shape[0]
    top = E[max(1, E.shape[0] // 2):]
    return float(np.sqrt(np.mean(np.abs(top) ** 2) / N)) if top.size else 0.0


def estimate_delay(measured: np.ndarray, predicted: np.ndarray, periodic: bool) -> float:
    """The lag in samples (> 0: the measurement comes late) that best aligns
    ``measured`` with ``predicted``: the peak of their cross-correlation (circular for a
    period), searched within `MAX_DELAY` of the record, refined between samples by a
    parabola through the peak and its neighbours."""
    a, b = measured - measured.mean(), predicted - predicted.mean()
    N = a.shape[0]
    reach = max(1, int(MAX_DELAY * N))
    lags = np.arange(-reach, reach + 1)
    if periodic:
        full = np.fft.irfft(np.fft.rfft(a) * np.conj(np.fft.rfft(b)), N)
        corr = full[lags % N]
    else:
        corr = np.array([np.dot(a[k:], b[:N - k]) / (N - k) if k >= 0 else
                         np.dot(a[:N + k], b[-k:]) / (N + k) for k in lags])
    i = int(np.argmax(corr))
    if 0 < i < lags.shape[0] - 1:
        c0, c1, c2 = corr[i - 1], corr[i], corr[i + 1]
        curvature = c0 - 2.0 * c1 + c2
        if curvature < 0:
            return float(lags[i] + 0.5 * (c0 - c2) / curvature)
    return float(lags[i])


#: A late measurement may be an acquisition delay (corrected by whole samples) from
#: where it rounds to one sample on; whether a lag this small is taken for one is
#: `automatic_delay`'s question (a plant 10 % off the model lags or leads it by up to
#: ~1.5 samples at 200 per period by itself). The lag found is reported either way.
DELAY_THRESHOLD = 0.5


def shift_back(measured: np.ndarray, lag: int, periodic: bool) -> np.ndarray:
    """``measured`` (last axis) moved ``lag`` samples earlier (a record's end repeats its
    last sample)."""
    if lag == 0:
        return measured
    if periodic:
        return np.roll(measured, -lag, axis=-1)
    if lag > 0:
        return np.concatenate([measured[..., lag:], np.repeat(measured[..., -1:], lag, -1)], -1)
    return np.concatenate([np.repeat(measured[..., :1], -lag, -1), measured[..., :lag]], -1)


def low_pass(x: np.ndarray, dt: float, cutoff: float, sigma: float = 0.0) -> np.ndarray:
    """x without its content above ``cutoff`` (Hz) and, with ``sigma`` (x's noise σ),
    without the frequencies where it holds less than the noise could (an amplitude below
    `SIGNIFICANT`·σ·√N: white noise puts that much in a frequency with probability
    e^-9): zero-phase, by its spectrum."""
    X = np.fft.rfft(x)
    f = np.fft.rfftfreq(x.shape[-1], dt)
    keep = f <= cutoff
    if sigma > 0:
        keep &= np.abs(X) >= SIGNIFICANT * sigma * np.sqrt(x.shape[-1])
        keep[0] = f[0] <= cutoff  # (the mean error is learned: it is no noise)
    X[..., ~keep] = 0.0
    return np.fft.irfft(X, x.shape[-1])


#: The amplitude of a frequency of the error, in noise σ·√N, below which it is not
#: learned (it may be noise).
SIGNIFICANT = 3.0


#: A lag whose phase at the fundamental is below this (radians, 5°) may be the plant's
#: own: a plant 10 % off the model lags or leads it by up to ~1.5 samples at 200 samples
#: per period (benchmarks/RESULTS.md).
AMBIGUOUS_PHASE = np.deg2rad(5.0)
#: Such a lag is taken for an acquisition delay only where shifting the record back
#: leaves at most this fraction of its rms departure from the model (beyond the noise).
EXPLAINED = 0.5


def ambiguous(found: float, n: int, own: float = 0.0) -> bool:
    """Whether a lag of ``found`` samples (of ``n`` a period) is one a plant a little off
    the model could show by itself: below `AMBIGUOUS_PHASE`, or at most ``own`` samples
    (the lag the model itself shows with its parameters 10 % off:
    `jaxhyst.control.learning_step.own_lag`)."""
    return 2 * np.pi * found / n < AMBIGUOUS_PHASE or found <= own


def delay_explained(measured: np.ndarray, predicted: np.ndarray, lag: int, sigma: float,
                    periodic: bool) -> bool:
    """Whether shifting ``measured`` back by ``lag`` samples explains its departure from
    ``predicted``: the mean square departure beyond the noise σ² left after the shift at
    most `EXPLAINED`² of what it was — a model right but for the acquisition's delay; a
    plant off the model that lags it by itself keeps most of its departure."""
    before = float(np.mean((measured - predicted) ** 2)) - sigma**2
    after = float(np.mean((shift_back(measured, lag, periodic) - predicted) ** 2)) - sigma**2
    return before > 0 and after <= EXPLAINED**2 * before


def automatic_delay(measured: np.ndarray, predicted: np.ndarray, found: float, sigma: float,
                    periodic: bool, own: float = 0.0) -> int:
    """The acquisition's delay (whole samples) taken from the lag ``found`` of a record
    ``measured`` (σ: its noise) behind the model's ``predicted``: none below
    `DELAY_THRESHOLD`; a lag a plant off the model could show by itself (`ambiguous`,
    ``own``) only where shifting the record back explains its departure
    (`delay_explained`); a larger one rounded."""
    lag = int(np.round(found)) if found >= DELAY_THRESHOLD else 0
    if lag and ambiguous(found, measured.shape[-1], own) and \
            not delay_explained(measured, predicted, lag, sigma, periodic):
        return 0
    return lag


def delay_note(lag: int, found: float, n: int, stop: bool, own: float = 0.0) -> str:
    """What learning's first report (``stop`` False) or a stop says of the first
    measurement's lag ``found`` (samples, of ``n`` a period) where a plant a little off
    the model could show it by itself, ``lag`` the delay taken; empty otherwise."""
    if found < DELAY_THRESHOLD or not ambiguous(found, n, own):
        return ""
    k = int(np.round(found))
    count = f"{k} sample" + ("s" if k != 1 else "")
    if lag and stop:
        return (f"; the record was aligned by a delay of {count} found automatically, as "
                "much as a plant a little off the model lags by itself: if the acquisition "
                f"has no delay, the actuator follows the reference {count} late (give the "
                "delay: delay=0, --known-delay 0)")
    if lag:
        return (f"; shifting the record back {count} explains its departure from the "
                f"model, but a plant a little off the model may lag it by {found:.2g} "
                "samples by itself: give the acquisition's delay where it is known "
                "(delay=, --known-delay)")
    if stop:
        return (f"; the record lagged the model by {found:.2g} samples, not taken for an "
                f"acquisition delay: if the acquisition delays it by {count}, the actuator "
                f"leads the reference by as much (give the delay: delay={k}, "
                f"--known-delay {k})")
    return (f"; the record lags the model by {found:.2g} samples, as a plant a little off "
            "the model can by itself, and shifting it back does not explain its departure "
            "from the model: not taken for an acquisition delay (give the acquisition's "
            f"delay where it is known: delay={k}, --known-delay {k})")
