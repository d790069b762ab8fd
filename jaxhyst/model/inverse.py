"""The actuator model run backwards: from a displacement y(t) to the field H(t) that
produces it, one stage at a time (each the exact inverse of a forward stage).

1. **Structure** (`required_magnetostriction`): Mz·ÿ + Cz·ẏ + Kz·y = Ar·E·λ gives λ(t)
   from y(t) directly — exactly, by the discrete Fourier transform, for a periodic y
   (the trigonometric interpolant of its samples), and by second-order finite
   differences for a record.
2. **Magnetostriction** (`magnetization_for_magnetostriction`): λ = (3/2)·λs·(M/Ms)²
   gives |M|; the sign is the caller's (the branch the bias field holds M on).
3. **Jiles–Atherton** (`field_for_magnetization`): with M prescribed, the field follows
   dH/dM = 1/χ, χ = dM/dH of the form at (H, M) with the field moving the way M does
   (χ > 0). `MagnetizationDriven` wraps any form as this slope, so the inverse path *is*
   the forward time loop (`magnetization_path`) run along M: RK4 in M, the δM switch
   located, the same derivative rule and batching — as `jaxhyst.model.flux.FluxDriven`
   runs it along B.

The chain needs χ > 0 everywhere on the path. Right after a field reversal only the
reversible part c·dMan/dHe acts, so for c → 0 the inverse is singular (M stands still
while H sweeps back): there χ is floored at `CHI_FLOOR` times the anhysteretic slope
Ms/(3a), and the field found is an approximation (jaxhyst.control refines it through the
forward model).
"""

from __future__ import annotations

import jax.numpy as jnp
import numpy as np

from .._typing import Array, Float
from ..names import DEFAULT_SUBSTEPS
from ..params import Parameters
from .drivers import CHI_FLOOR, MagnetizationDriven
from .jiles_atherton import PAPER_VARIANT, AbstractJAVariant
from .paths import hysteresis_path

__all__ = ["CHI_FLOOR", "MagnetizationDriven", "field_for_magnetization",
           "magnetization_for_magnetostriction", "required_magnetostriction"]



def field_for_magnetization(p: Parameters, M: Float[Array, " T"],
                            variant: AbstractJAVariant = PAPER_VARIANT,
                            substeps: int = DEFAULT_SUBSTEPS) -> Float[Array, " T"]:
    """The field H (A/m), shape (T,), under which the form ``variant`` follows the
    magnetization ``M`` (A/m), shape (T,), piecewise linear between samples, from the
    demagnetized state: M[0] must be 0 (start with a ramp from 0). Differentiable (the
    time loop's derivative rule) and batched under ``jax.vmap``."""
    H_sub, _, _, _ = hysteresis_path(variant, p, None, M, substeps=substeps, driver="M")
    return jnp.concatenate([jnp.zeros((1,), dtype=H_sub.dtype), H_sub[:, -1]])


def magnetization_for_magnetostriction(lam, p: Parameters, sign=1.0):
    """M (A/m) with λ = (3/2)·λs·(M/Ms)² (the inverse of eq 6) on the branch ``sign``
    (±1); λ below 0 is taken as 0 (no M gives it)."""
    ratio = jnp.maximum(lam, 0.0) / (1.5 * p.lambda_s)
    return sign * p.Ms * jnp.sqrt(ratio)


def required_magnetostriction(p: Parameters, Ar, y, dt: float, periodic: bool,
                              t=None) -> np.ndarray:
    """λ(t) = (Mz·ÿ + Cz·ẏ + Kz·y)/(Ar·E) (eq 7 solved for the forcing) for displacement
    samples ``y`` (m), shape (N,); NumPy in, NumPy out (host values).

    ``periodic``: ``y`` is one period of N uniform samples ``dt`` (s) apart, and λ is
    exact for its trigonometric interpolant (each harmonic times Kz − Mz·ω² + jCz·ω).
    Otherwise ``y`` is a record at the times ``t`` (s; uniform ``dt`` if None) and the
    derivatives are second-order finite differences."""
    y = np.asarray(y, dtype=np.float64)
    Kz, Mz, Cz = float(p.Kz), float(p.Mz), float(p.Cz)
    gain = float(Ar) * float(p.E)
    if periodic:
        omega = 2.0 * np.pi * np.fft.rfftfreq(y.shape[0], dt)
        spectrum = np.fft.rfft(y) * (Kz - Mz * omega**2 + 1j * Cz * omega)
        return np.fft.irfft(spectrum, y.shape[0]) / gain
    times = dt if t is None else np.asarray(t, dtype=np.float64)
    velocity = np.gradient(y, times, edge_order=2)
    acceleration = np.gradient(velocity, times, edge_order=2)
    return (Mz * acceleration + Cz * velocity + Kz * y) / gain
