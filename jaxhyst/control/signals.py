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


#: A late measurement is taken for an acquisition delay (and corrected by whole samples)
#: from this many samples on; smaller lags may be the model's own phase error (plants
#: 10 % off the model differ from it by −1.4 … +0.9 samples at 200 samples per period:
#: benchmarks/RESULTS.md), which learning absorbs. The lag found is reported either way.
DELAY_THRESHOLD = 1.0


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
