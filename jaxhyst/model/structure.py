"""Structural dynamics of rod + load (paper eqs 7–13): Mz·ÿ + Cz·ẏ + Kz·y = Ar·E·λ(t).

The ODE is linear, so it is discretized *exactly* for a forcing that is a cubic polynomial
in time over each step (Van Loan's augmented matrix exponential). The magnetostriction is
represented over each integrator substep by its cubic Hermite interpolant (values and
time-derivatives at both ends, from the Jiles–Atherton slope), which is 4th-order
accurate like the RK4 integration of M. Unlike an explicit integrator this is stable for
any ratio of sample rate to resonance frequency (10 Hz drives of a 1.1 kHz resonator
sampled coarsely included).

The response is the linear recurrence x_{j+1} = Φ_j·x_j + G_j·w_j over all substeps, a
``lax.scan`` with a 2-vector state (cheap to run and to differentiate in either mode).
For a uniformly sampled drive one matrix exponential at the mean step h̄ serves every
step; small deviations δ_j = h_j − h̄ (jitter in measured time stamps, |δ| ≤ 1e-4·h̄) are
applied as E(h̄ + δ) = E(h̄)·(I + X·δ + X²·δ²/2), exact to O((‖X‖·δ)³). A non-uniform
drive takes one exponential per step (inside the same loop).
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from .._typing import Array, ArrayLike, Complex, Float
from ..actuator import Actuator
from ..params import Parameters, is_concrete
from .interval import on_accelerator


def state_matrix(p: Parameters):
    """A of x' = A·x + b·u for x = [y, ẏ] (m, m/s); u = Ar·E·λ/Mz (m/s²)."""
    return jnp.array([[0.0, 1.0], [-p.Kz / p.Mz, -p.Cz / p.Mz]])


def _matmul(A, B):
    """A @ B for small matrices as broadcast products (XLA:CPU calls a BLAS kernel per
    tiny dot otherwise)."""
    return (A[..., :, :, None] * B[..., None, :, :]).sum(-2)


_TAYLOR_ORDER = 14  # ‖X/2^s‖₁ ≤ 1/2: truncation ≤ 0.5^15/15!·e^0.5 ≈ 4e-17
_MAX_SQUARINGS = 32  # ‖X‖₁ up to ~2e9 (beyond it the result is NaN)


def expm_small(X):
    """exp(X) of a small square matrix (or a batch, shape (..., n, n)) by scaling and
    squaring with a Taylor polynomial.

    Only elementwise products: no LAPACK call. (`jax.scipy.linalg.expm` solves a Padé
    system with an LU factorisation; its batched triangular solve, inside jacfwd of a
    program sharded over CPU host devices, deadlocked the XLA:CPU runtime.) The number of
    squarings s is chosen from ‖X‖₁ at run time and applied as a fixed-length loop with
    a select, so the function is differentiable in forward and reverse mode. Where
    ‖X‖₁ > 2^31 the result is NaN.
    """
    norm = jnp.max(jnp.sum(jnp.abs(X), axis=-2), axis=-1)
    s = jnp.clip(jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-300) / 0.5)), 0, None)
    Y = X * jnp.exp2(-s)[..., None, None]
    eye = jnp.eye(X.shape[-1], dtype=X.dtype)

    def horner(i, E):  # I + Y/1·(I + Y/2·(I + …)), from the innermost term out
        return eye + _matmul(Y, E) / (_TAYLOR_ORDER - i).astype(X.dtype)

    def square(i, E):
        return jnp.where((i < s)[..., None, None], _matmul(E, E), E)

    # loops rather than unrolled code: XLA:CPU compiles each as one kernel
    E = jax.lax.fori_loop(0, _TAYLOR_ORDER, horner, jnp.broadcast_to(eye, X.shape))
    E = jax.lax.fori_loop(0, _MAX_SQUARINGS, square, E)
    return jnp.where((s <= _MAX_SQUARINGS)[..., None, None], E, jnp.nan)


def _toeplitz(l):
    """The upper triangular Toeplitz 4×4 matrix with first row ``l``."""
    k = jnp.arange(4)
    d = k[None, :] - k[:, None]
    return jnp.where(d >= 0, l[jnp.clip(d, 0, 3)], 0.0)


def _exp_hold(A, coupling, chain):
    """The first two rows [Φ | G] (shape (2, 6)) of exp(Y) for the augmented generator
    Y = [[A, B], [0, N]], A 2×2, B = coupling·e₁e₀ᵀ (2×4), N = chain·(shift) (4×4), by
    Taylor scaling and squaring on the blocks. E = [[P, Q], [0, L]] keeps that form, and
    L (a polynomial in N) is upper triangular Toeplitz, carried as its first row l:
    ~4× fewer products than `expm_small` of the 6×6 matrix. NaN where ‖Y‖₁ > 2^31."""
    norm = jnp.maximum(jnp.max(jnp.sum(jnp.abs(A), axis=-2), axis=-1),
                       jnp.maximum(jnp.abs(coupling), jnp.abs(chain)))
    s = jnp.clip(jnp.ceil(jnp.log2(jnp.maximum(norm, 1e-300) / 0.5)), 0, None)
    scale = jnp.exp2(-s)
    A, coupling, chain = A * scale, coupling * scale, chain * scale
    eye2 = jnp.eye(2, dtype=A.dtype)
    first = jnp.array([1.0, 0.0, 0.0, 0.0], dtype=A.dtype)

    def horner(i, E):  # E ← I + Y·E/j for j = order … 1
        P, Q, l = E
        j = (_TAYLOR_ORDER - i).astype(A.dtype)
        BL = jnp.zeros_like(Q).at[1].set(coupling * l)  # B·L: row 1 is coupling·(row 0 of L)
        NL = jnp.concatenate([jnp.zeros((1,), A.dtype), chain * l[:3]])  # row 0 of N·L
        return eye2 + _matmul(A, P) / j, (_matmul(A, Q) + BL) / j, first + NL / j

    P, Q, l = jax.lax.fori_loop(0, _TAYLOR_ORDER, horner,
                                (eye2, jnp.zeros((2, 4), A.dtype), first))

    def square(i, E):  # E ← E·E
        P, Q, l = E
        L = _toeplitz(l)
        on = i < s
        return (jnp.where(on, _matmul(P, P), P),
                jnp.where(on, _matmul(P, Q) + _matmul(Q, L), Q),
                jnp.where(on, (l[:, None] * L).sum(0), l))  # row 0 of L·L

    P, Q, _ = jax.lax.fori_loop(0, _MAX_SQUARINGS, square, (P, Q, l))
    return jnp.where(s <= _MAX_SQUARINGS, jnp.concatenate([P, Q], axis=-1), jnp.nan)


def augmented_matrix(p: Parameters):
    """Van Loan's 6×6 generator (1/s) of [y, ẏ, w0, w1, w2, w3] for the cubic forcing
    u(τ) = w0 + w1·τ + w2·τ²/2 + w3·τ³/6 (u in m/s²)."""
    A = state_matrix(p)
    X = jnp.zeros((6, 6), dtype=A.dtype)
    X = X.at[:2, :2].set(A)
    X = X.at[1, 2].set(1.0)  # forcing enters ÿ
    return X.at[2, 3].set(1.0).at[3, 4].set(1.0).at[4, 5].set(1.0)  # w0' = w1 …


def cubic_hold_discretization(p: Parameters, h):
    """(Φ, G) with x(h) = Φ·x(0) + G·w for u(τ) = w0 + w1·τ + w2·τ²/2 + w3·τ³/6.

    Φ: shape (2, 2); G: shape (2, 4). ``h`` is the step in seconds (a scalar, traced).
    The exponential is taken of the balanced generator D·X·h·D⁻¹ (D scales y by the
    natural frequency ω and w_k by ω^-k), whose entries are all of order ω·h.
    """
    omega = jnp.sqrt(p.Kz / p.Mz)
    wh = omega * h
    A = jnp.array([[0.0, 1.0], [-1.0, -p.Cz / (p.Mz * omega)]]) * wh
    top = _exp_hold(A, wh, wh)
    d = omega ** jnp.array([1.0, 0.0, -1.0, -2.0, -3.0, -4.0])
    top = top * d[None, :] / d[:2, None]
    return top[:, :2], top[:, 2:]


def hermite_taylor_coefficients(u0, du0, u1, du1, h):
    """Taylor coefficients w = [u, u', u'', u'''](0) of the cubic Hermite interpolant of
    (u0, du0) at τ = 0 and (u1, du1) at τ = h. Shape (..., 4)."""
    slope = (u1 - u0) / h
    c2 = (3.0 * slope - 2.0 * du0 - du1) / h
    c3 = (du0 + du1 - 2.0 * slope) / (h * h)
    return jnp.stack([u0, du0, 2.0 * c2, 6.0 * c3], axis=-1)


def structural_response(p: Parameters, h, forcing, uniform: bool, x0=None):
    """The state [y, ẏ] (m, m/s) after each step of x_{j+1} = Φ_j·x_j + G_j·w_j from
    x_0 (default 0: at rest), shape (J, 2), for steps ``h`` (s, shape (J,)) and forcing
    Taylor coefficients ``forcing`` w (shape (J, 4), `hermite_taylor_coefficients` of
    u = Ar·E·λ/Mz).

    ``uniform``: one exponential at the mean step h̄, each step's [Φ_j | G_j] corrected
    to second order in h_j − h̄ inside the loop (valid for |h_j − h̄| ≤ 1e-4·h̄);
    otherwise one exponential per step."""
    if uniform:
        h_mean = jnp.mean(h)
        Phi, G = cubic_hold_discretization(p, h_mean)
        top = jnp.concatenate([Phi, G], axis=-1)  # first two rows of E(h̄)
        X = augmented_matrix(p)
        top_X = _matmul(top, X)
        top_XX = _matmul(top_X, X)

        def matrices(delta):
            return top + delta * top_X + (0.5 * delta * delta) * top_XX

        per_step = h - h_mean
    else:
        def matrices(hj):
            return jnp.concatenate(cubic_hold_discretization(p, hj), axis=-1)

        per_step = h

    def body(x, step):
        s, w = step
        m = matrices(s)
        # the 2×2 and 2×4 products column by column: no BLAS call per step, and no
        # reduction over a short axis (slow for a population, whose members lead)
        x = m[:, 0] * x[0] + m[:, 1] * x[1] + sum(m[:, 2 + k] * w[k] for k in range(4))
        return x, x

    start = jnp.zeros((2,), dtype=forcing.dtype) if x0 is None else x0
    # (a tiny body: on an accelerator each iteration's launch is what costs, so unroll)
    _, xs = jax.lax.scan(body, start, (per_step, forcing), unroll=8 if on_accelerator() else 1)
    return xs


def periodic_structural_response(p: Parameters, h, forcing, uniform: bool):
    """The periodic steady state of the structure for a forcing that repeats with period
    Σh: ``(x_start, xs)``, the state [y, ẏ] at the start of the period (shape (2,)) and
    after each step (shape (J, 2), the last equal to ``x_start``). Arguments as in
    `structural_response`.

    The structure is linear, so its steady state is solved for instead of waiting for the
    transient to decay: with x_J = F·x_0 + x_J(from rest) over one period (F the product
    of the Φ_j), the periodic start is x* = (I − F)⁻¹·x_J(from rest), and each state is
    the response from rest plus the free response from x*. The three recurrences (from
    rest with the forcing, free from e₀ and from e₁) run as one batched scan. A structure
    without damping driven at a harmonic of its resonance has no steady state (I − F is
    singular); the result is then not finite."""
    forcings = jnp.stack([forcing, jnp.zeros_like(forcing), jnp.zeros_like(forcing)])
    starts = jnp.array([[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]], dtype=forcing.dtype)
    xs = jax.vmap(lambda w, x0: structural_response(p, h, w, uniform, x0))(forcings, starts)
    from_rest, free = xs[0], xs[1:]  # free[i, j]: state after step j from e_i
    (f00, f10), (f01, f11) = free[0, -1], free[1, -1]  # F = [[f00, f01], [f10, f11]]
    a, b, c, d = 1.0 - f00, -f01, -f10, 1.0 - f11  # I − F, inverted in closed form
    det = a * d - b * c
    r = from_rest[-1]
    x_start = jnp.stack([d * r[0] - b * r[1], a * r[1] - c * r[0]]) / det
    return x_start, from_rest + x_start[0] * free[0] + x_start[1] * free[1]


def frequency_response(p: Parameters, actuator: Actuator,
                       frequency: Float[ArrayLike, "*shape"]) -> Complex[Array, "*shape"]:
    """G(jω) = ε/λ = (Ar·E/lr) / (Mz·(jω)² + Cz·jω + Kz)  (eq 13), complex, dimensionless.

    ``frequency`` in Hz (any shape; at −f the result is the conjugate of that at f).
    ``jnp.abs`` gives A(ω) and ``jnp.angle`` the phase φ (radians; the paper quotes the
    lag −φ in degrees).
    """
    if is_concrete(frequency) and not np.all(np.isfinite(np.asarray(frequency, float))):
        raise ValueError(f"frequency must be finite (Hz); got {np.asarray(frequency).tolist()}.")
    w = 2.0 * jnp.pi * jnp.asarray(frequency, dtype=jnp.float64)
    jw = 1j * w
    return (actuator.Ar * p.E / actuator.lr) / (p.Mz * jw * jw + p.Cz * jw + p.Kz)
