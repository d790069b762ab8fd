"""Structural dynamics of rod + load (paper eqs 7–13): Mz·ÿ + Cz·ẏ + Kz·y = Ar·E·λ(t).

The ODE is linear, so it is discretized *exactly* for a forcing that is a cubic polynomial
in time over each step (Van Loan's augmented matrix exponential). The magnetostriction is
represented over each integrator substep by its cubic Hermite interpolant (values and
time-derivatives at both ends, from the Jiles–Atherton slope), which is 4th-order
accurate like the RK4 integration of M. Unlike an explicit integrator this is stable for
any ratio of sample rate to resonance frequency (10 Hz drives of a 1.1 kHz resonator
sampled coarsely included).
"""

from __future__ import annotations

import jax.numpy as jnp
from jax.scipy.linalg import expm

from ..actuator import Actuator
from ..params import Parameters


def state_matrix(p: Parameters):
    """A of x' = A·x + b·u for x = [y, ẏ] (m, m/s); u = Ar·E·λ/Mz (m/s²)."""
    return jnp.array([[0.0, 1.0], [-p.Kz / p.Mz, -p.Cz / p.Mz]])


def cubic_hold_discretization(p: Parameters, h):
    """(Φ, G) with x(h) = Φ·x(0) + G·w for u(τ) = w0 + w1·τ + w2·τ²/2 + w3·τ³/6.

    Φ: shape (2, 2); G: shape (2, 4). ``h`` is the step in seconds (a scalar).
    """
    A = state_matrix(p)
    aug = jnp.zeros((6, 6), dtype=A.dtype)
    aug = aug.at[:2, :2].set(A)
    aug = aug.at[1, 2].set(1.0)  # forcing enters ÿ
    aug = aug.at[2, 3].set(1.0).at[3, 4].set(1.0).at[4, 5].set(1.0)  # w0' = w1 …
    E = expm(aug * h)
    return E[:2, :2], E[:2, 2:]


def hermite_taylor_coefficients(u0, du0, u1, du1, h):
    """Taylor coefficients w = [u, u', u'', u'''](0) of the cubic Hermite interpolant of
    (u0, du0) at τ = 0 and (u1, du1) at τ = h. Shape (..., 4)."""
    slope = (u1 - u0) / h
    c2 = (3.0 * slope - 2.0 * du0 - du1) / h
    c3 = (du0 + du1 - 2.0 * slope) / (h * h)
    return jnp.stack([u0, du0, 2.0 * c2, 6.0 * c3], axis=-1)


def frequency_response(p: Parameters, actuator: Actuator, frequency):
    """G(jω) = ε/λ = (Ar·E/lr) / (Mz·(jω)² + Cz·jω + Kz)  (eq 13), complex, dimensionless.

    ``frequency`` in Hz (any shape). ``jnp.abs`` gives A(ω) and ``jnp.angle`` the phase φ
    (radians; the paper quotes the lag −φ in degrees).
    """
    w = 2.0 * jnp.pi * jnp.asarray(frequency, dtype=jnp.float64)
    jw = 1j * w
    return (actuator.Ar * p.E / actuator.lr) / (p.Mz * jw * jw + p.Cz * jw + p.Kz)
