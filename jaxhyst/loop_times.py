"""Times of measured loops recorded without them.

A loop tracer samples its record uniformly in time; a file may keep only the samples and
each loop's drive frequency (a ``frequency`` column, no ``t``). The rate-dependent model
needs the times. Where a loop's drive (H or I) or its flux density (B or M) is a
sinusoid sampled uniformly — which a tracer's sinusoidal drive gives and a digitized
curve, spaced along its length, does not — the sample spacing is one period over the
samples per period, and the loop's times follow from its frequency:

    t_i = i / (P · f)      (P: samples per period of the fitted sinusoid, f in Hz)

`sinusoid_fit` finds P and how well a sinusoid fits; `times_from_frequency` gives every
loop that has a frequency but no times its times, or none where any such loop is not a
uniformly sampled sinusoid (mixed times would compare loops unlike each other), and says
which in one line.
"""

from __future__ import annotations

import dataclasses

import numpy as np

#: A sinusoid "fits" where the rms of what it leaves is at most this fraction of its
#: amplitude: noise of a few per mille passes; a triangle wave leaves 6.6 %, and the
#: samples of a curve digitized at equal steps of its length 1.8 % and more (the H and B
#: of tanh-shaped loops, `tests/test_loop_times.py`).
TOLERANCE = 0.01
#: Samples of a loop below which no period is estimated.
MIN_SAMPLES = 16
#: Signals tried, in order: the drive, then the flux density (a tracer that controls B
#: sinusoidally records a distorted H).
SIGNALS = ("H", "I", "B", "M")


def _residual(x: np.ndarray, cycles: float) -> tuple[float, float]:
    """(rms residual, amplitude) of the least-squares sinusoid c + a·cos + b·sin making
    ``cycles`` periods over the record ``x`` (N samples)."""
    phase = (2.0 * np.pi * cycles / x.shape[0]) * np.arange(x.shape[0])
    basis = np.stack([np.ones_like(phase), np.cos(phase), np.sin(phase)], axis=1)
    coef = np.linalg.lstsq(basis, x, rcond=None)[0]
    return float(np.sqrt(np.mean((x - basis @ coef) ** 2))), float(np.hypot(*coef[1:]))


def _search(x: np.ndarray, lo: float, hi: float, rounds: int, points: int) -> float:
    """The number of cycles over ``x`` in [lo, hi] whose sinusoid leaves least: a grid of
    ``points``, narrowed around its best ``rounds`` times."""
    best = 0.5 * (lo + hi)
    for _ in range(rounds):
        grid = np.linspace(lo, hi, points)
        best = float(grid[int(np.argmin([_residual(x, c)[0] for c in grid]))])
        step = grid[1] - grid[0]
        lo, hi = max(0.5, best - 2.0 * step), best + 2.0 * step
    return best


def sinusoid_fit(x) -> tuple[float, float]:
    """The sinusoid c + a·cos(2πi/P) + b·sin(2πi/P) nearest to the samples ``x`` (shape
    (N,), any unit): ``(P, rms residual / amplitude)``, P in samples per period: the
    nearest whole number where it leaves no significantly more (its extra sum of squares
    within 4 of the residual variance's, an F-test at about 95 %), else a float.
    ``(nan, inf)`` for fewer than `MIN_SAMPLES` samples or a constant record. Long
    records are searched on every s-th sample (at most 4 096), then refined on all."""
    x = np.asarray(x, dtype=np.float64)
    n = x.shape[0] if x.ndim == 1 else 0
    if n < MIN_SAMPLES or not np.all(np.isfinite(x)) or np.ptp(x) == 0:
        return float("nan"), float("inf")
    s = -(-n // 4096)
    few = x[::s]
    spectrum = np.abs(np.fft.rfft(few - np.mean(few)))
    k = int(np.argmax(spectrum[1:])) + 1
    cycles = _search(few, max(0.5, k - 1.0), k + 1.0, 6, 41) * n / (few.shape[0] * s)
    if s > 1:  # (the decimated search's bracket is ~s/n⁶ cycles wide: refine on all)
        cycles = _search(x, max(0.5, cycles - 0.01), cycles + 0.01, 3, 11)
    period, (rms, amp) = n / cycles, _residual(x, cycles)
    whole = float(max(round(period), 1))  # (a tracer's samples a period: a whole number
    rms_whole, amp_whole = _residual(x, n / whole)  # unless the data say otherwise)
    if n > 4 and (rms_whole**2 - rms**2) * (n - 4) <= 4.0 * rms**2:
        period, rms, amp = whole, rms_whole, amp_whole
    return period, rms / amp if amp > 0 else float("inf")


def _loop_period(loop, tolerance: float) -> tuple[float, str, float]:
    """(samples per period, the signal that gave it, what its sinusoid leaves) of a
    loop: the first of `SIGNALS` that is a sinusoid sampled uniformly (within
    ``tolerance``) over a period at least; else (nan, why not in words, inf)."""
    why = "it has too few samples to tell its sampling"
    best = float("inf")
    for name in SIGNALS:
        x = getattr(loop, name, None) if name in ("H", "I") else loop.signals.get(name)
        if x is None:
            continue
        period, residual = sinusoid_fit(x)
        if residual <= tolerance and period <= 1.05 * x.shape[0]:
            return period, name, residual
        if residual <= tolerance:
            why, best = f"its {name} holds less than one period of its sinusoid", 0.0
        elif residual < best:
            why, best = (f"its {name} is not a sinusoid sampled uniformly (what a sinusoid "
                         f"leaves: {100 * residual:.3g} % of its amplitude)"), residual
    return float("nan"), why, float("inf")


def times_from_frequency(loops, tolerance: float = TOLERANCE):
    """``(loops, text)``: every loop of ``loops`` (`jaxhyst.io.Loop`) that has a
    ``frequency`` condition (Hz) and no times, given times t_i = i/(P·f) (s) — where each
    such loop's drive or flux density is a uniformly sampled sinusoid (rms residual at
    most ``tolerance`` of its amplitude, one period or more). Where any such loop is not,
    none is given times. ``text`` says what was done or why not, in one line; None where
    no loop has a frequency without times. The loops are new objects; ``loops`` is not
    changed."""
    from .io import Loop

    loops = list(loops) if not isinstance(loops, Loop) else [loops]
    if not all(isinstance(lp, Loop) for lp in loops):
        raise TypeError("times_from_frequency takes loops as jaxhyst.io.read_loops gives them "
                        "(jaxhyst.io.Loop, with a frequency condition); got "
                        f"{type(next(lp for lp in loops if not isinstance(lp, Loop))).__name__}.")
    untimed = [lp for lp in loops if lp.t is None and
               np.isfinite(lp.conditions.get("frequency", np.nan)) and
               lp.conditions["frequency"] > 0]
    if not untimed:
        return list(loops), None
    found = {}
    for lp in untimed:
        period, name, residual = _loop_period(lp, tolerance)
        if not np.isfinite(period):
            return list(loops), (
                f"loop {lp.index} has a frequency and no t column, and {name}: no loop's "
                "times were taken from its frequency (give a t column, s)")
        found[lp.index] = (period, name, residual)
    out = []
    for lp in loops:
        if lp.index in found:
            period = found[lp.index][0]
            t = np.arange(lp.n_samples, dtype=np.float64) / (period * lp.conditions["frequency"])
            lp = dataclasses.replace(lp, t=t)
        out.append(lp)
    periods = sorted({v[0] for v in found.values()})
    names = sorted({v[1] for v in found.values()})
    span = (f"{periods[0]:.6g}" if len(periods) == 1 else
            f"{periods[0]:.6g}–{periods[-1]:.6g}")
    worst = max(v[2] for v in found.values())
    return out, (f"times from the loops' frequencies: the {'/'.join(names)} of "
                 f"{'each of the ' + str(len(found)) + ' loops' if len(found) > 1 else 'loop'}"
                 f" without a t column is a sinusoid sampled uniformly ({span} samples a "
                 f"period; what a sinusoid leaves: at most {100 * worst:.2g} % of its "
                 "amplitude), so t_i = i/(samples a period · frequency); give a t column if "
                 "the samples are not uniform in time")
