"""The Langevin function L(x) = coth(x) − 1/x and its slope, finite and smooth everywhere.

Near x = 0 both closed forms cancel catastrophically (coth x and 1/x are each ~1/x), so
for |x| < 0.1 the odd/even Taylor series are used instead, behind a "double where" so that
neither the values nor the gradients of the unused branch can become 0/0. For the
closed form a single exp(−2|x|) gives both coth and 1/sinh², which is cheaper than
tanh + sinh in compiled code and overflows nowhere (the exponent is never positive).

`langevin_and_slope` carries its own derivative rule (L' and L'' from the same
exponential): differentiating the two branches and the selects op by op made the
derivative code of every Jiles–Atherton slope three times longer, and compiling the
model's derivative correspondingly slower.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

_SMALL = 0.1


def _series(x):
    x2 = x * x
    # L(x) = x/3 − x³/45 + 2x⁵/945 − x⁷/4725 + 2x⁹/93555 − …   (next term ~1e-17 at 0.1)
    L = x * (1 / 3 + x2 * (-1 / 45 + x2 * (2 / 945 + x2 * (-1 / 4725 + x2 * (2 / 93555)))))
    # L'(x) = 1/3 − x²/15 + 2x⁴/189 − x⁶/675 + 2x⁸/10395 − …
    dL = 1 / 3 + x2 * (-1 / 15 + x2 * (2 / 189 + x2 * (-1 / 675 + x2 * (2 / 10395))))
    return L, dL


def _series_second(x):
    """L''(x) = −2x/15 + 8x³/189 − 6x⁵/675 + 16x⁷/10395 − …"""
    x2 = x * x
    return x * (-2 / 15 + x2 * (8 / 189 + x2 * (-6 / 675 + x2 * (16 / 10395))))


def _closed(x):
    ax = jnp.abs(x)
    e = jnp.exp(-2.0 * ax)
    one_minus = 1.0 - e
    coth_abs = (1.0 + e) / one_minus
    L = jnp.sign(x) * (coth_abs - 1.0 / ax)
    csch2 = 4.0 * e / (one_minus * one_minus)  # 1/sinh²x
    dL = 1.0 / (x * x) - csch2
    # L'' = −2/x³ + 2·coth(x)/sinh²(x)
    ddL = jnp.sign(x) * (2.0 * coth_abs * csch2 - 2.0 / (ax * ax * ax))
    return L, dL, ddL


def _split(x):
    small = jnp.abs(x) < _SMALL
    return small, jnp.where(small, x, 0.0), jnp.where(small, 1.0, x)


@jax.custom_jvp
def langevin_and_slope(x):
    """(L(x), L'(x)) for any real x, elementwise; smooth through 0, exact to ~1e-15."""
    small, x_small, x_big = _split(x)
    Ls, dLs = _series(x_small)
    Lb, dLb, _ = _closed(x_big)
    return jnp.where(small, Ls, Lb), jnp.where(small, dLs, dLb)


def _langevin3(x):
    """(L, L', L'') with one exponential and one branch selection."""
    small, x_small, x_big = _split(x)
    Ls, dLs = _series(x_small)
    Lb, dLb, ddLb = _closed(x_big)
    return (jnp.where(small, Ls, Lb), jnp.where(small, dLs, dLb),
            jnp.where(small, _series_second(x_small), ddLb))


@langevin_and_slope.defjvp
def _langevin_jvp(primals, tangents):
    (x,), (t,) = primals, tangents
    L, dL, ddL = _langevin3(x)
    return (L, dL), (dL * t, ddL * t)


def langevin(x):
    """L(x) = coth(x) − 1/x, elementwise."""
    return langevin_and_slope(x)[0]


def langevin_slope(x):
    """L'(x) = 1/x² − 1/sinh²(x), elementwise (→ 1/3 at x = 0)."""
    return langevin_and_slope(x)[1]
