"""A stand-in for the real actuator, to rehearse learning control before the laboratory:
another model (its parameters off), measurement noise, an acquisition delay and a
structural mode the model does not have.

`SimulatedPlant.measure` runs the plant's model on an input through a reference's
samples (in its periodic steady state, for a periodic reference: `Tracking`), passes the
displacement through the unmodelled mode (a second-order resonance between the actuator
and the sensor, y_sensed(ω) = y(ω)·ωm²/(ωm² − ω² + 2j·ζ·ωm·ω), applied to the period's
harmonics), delays it by whole samples (circularly for a period) and adds Gaussian noise.
"""

from __future__ import annotations

import numpy as np

from ..saved import Model
from .reference import Reference
from .tracking import Tracking, evaluate, settling_periods


class SimulatedPlant:
    """A simulated actuator for ``reference`` (see the module docstring).

    **Arguments:** ``model``: the plant's own `jaxhyst.Model`; ``noise``: σ of the
    measurement noise, relative to the reference's peak-to-peak (0.005: a 0.5 % sensor);
    ``delay``: acquisition delay in whole samples (≥ 0); ``mode``: an unmodelled mode as
    ``(frequency in Hz, damping ratio)`` or None; ``seed``: of the noise."""

    def __init__(self, model: Model, reference: Reference, *, noise: float = 0.0,
                 delay: int = 0, mode: tuple[float, float] | None = None, seed: int = 0):
        if not (np.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be a number >= 0 (σ over the reference's "
                             f"peak-to-peak); got {noise!r}.")
        if isinstance(delay, bool) or int(delay) != delay or delay < 0 or \
                delay >= reference.n_samples:
            raise ValueError(f"delay must be a whole number of samples in [0, "
                             f"{reference.n_samples}); got {delay!r}.")
        if mode is not None:
            f, zeta = (float(v) for v in mode)
            if not (f > 0 and np.isfinite(f) and zeta > 0 and np.isfinite(zeta)):
                raise ValueError(f"mode must be (frequency > 0 Hz, damping ratio > 0); got "
                                 f"{mode!r}.")
        self.reference, self.noise, self.delay, self.mode = reference, noise, int(delay), mode
        self.tracking = Tracking.of(model, reference)
        self.rng = np.random.default_rng(seed)
        self._settled = False

    def response(self, u) -> np.ndarray:
        """The plant's displacement (m) at the reference's samples for the input u,
        through the mode and the delay, without noise."""
        u = np.asarray(u, dtype=np.float64)
        ref = self.reference
        if ref.periodic and not self._settled:
            periods, _ = settling_periods(self.tracking, u)
            self.tracking, self._settled = self.tracking.with_run_in(periods), True
        y = evaluate(self.tracking, u)
        if self.mode is not None:
            f, zeta = self.mode
            wm = 2.0 * np.pi * f
            w = 2.0 * np.pi * np.fft.rfftfreq(y.shape[0], ref.dt)
            gain = wm**2 / (wm**2 - w**2 + 2j * zeta * wm * w)
            y = np.fft.irfft(np.fft.rfft(y) * gain, y.shape[0])
        if self.delay:
            y = np.roll(y, self.delay) if ref.periodic else \
                np.concatenate([np.full(self.delay, y[0]), y[:-self.delay]])
        return y

    def measure(self, u, repeats: int = 1) -> np.ndarray:
        """A measurement of the displacement (m) for the input u: shape (N,), or
        (``repeats``, N) for that many periods of it, each with its own noise."""
        y = self.response(u)
        n = int(repeats)
        noise = self.noise * self.reference.scale * self.rng.standard_normal((n, y.shape[0]))
        out = y + noise
        return out[0] if n == 1 else out
