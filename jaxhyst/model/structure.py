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

import jax
import jax.numpy as jnp

from ..actuator import Actuator
from ..params import Parameters


def state_matrix(p: Parameters):
    """A of x' = A·x + b·u for x = [y, ẏ] (m, m/s); u = Ar·E·λ/Mz (m/s²)."""
    return jnp.array([[0.0, 1.0], [-p.Kz / p.Mz, -p.Cz / p.Mz]])


_TAYLOR_ORDER = 14  # ‖X/2^s‖₁ ≤ 1/2: truncation ≤ 0.5^15/15!·e^0.5 ≈ 4e-17
_MAX_SQUARINGS = 48  # enough for ‖X‖₁ up to ~7e13


def expm_small(X):
    """exp(X) of a small square matrix by scaling and squaring with a Taylor polynomial.

    Only matrix products: no LAPACK call. (`jax.scipy.linalg.expm` solves a Padé system
    with an LU factorisation; its batched triangular solve, inside jacfwd of a program
    sharded over CPU host devices, deadlocked the XLA:CPU runtime.) The number of
    squarings s is chosen from ‖X‖₁ at run time and applied as a fixed-length loop with
    a select, so the function is differentiable in forward and reverse mode.
    """
    norm = jnp.max(jnp.sum(jnp.abs(X), axis=0))
    s = jnp.clip(jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-300) / 0.5)), 0, _MAX_SQUARINGS)
    Y = X * jnp.exp2(-s)
    eye = jnp.eye(X.shape[-1], dtype=X.dtype)
    E = eye
    for k in range(_TAYLOR_ORDER, 0, -1):  # Horner: I + Y/1·(I + Y/2·(I + …))
        E = eye + (Y @ E) / k

    def square(i, E):
        return jnp.where(i < s, E @ E, E)

    return jax.lax.fori_loop(0, _MAX_SQUARINGS, square, E)


def cubic_hold_discretization(p: Parameters, h):
    """(Φ, G) with x(h) = Φ·x(0) + G·w for u(τ) = w0 + w1·τ + w2·τ²/2 + w3·τ³/6.

    Φ: shape (2, 2); G: shape (2, 4). ``h`` is the step in seconds (a scalar).
    """
    A = state_matrix(p)
    aug = jnp.zeros((6, 6), dtype=A.dtype)
    aug = aug.at[:2, :2].set(A)
    aug = aug.at[1, 2].set(1.0)  # forcing enters ÿ
    aug = aug.at[2, 3].set(1.0).at[3, 4].set(1.0).at[4, 5].set(1.0)  # w0' = w1 …
    E = expm_small(aug * h)
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
