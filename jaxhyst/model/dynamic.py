"""The rate-dependent model driven by H: the field-separation form of
`jaxhyst.model.losses` in the forward direction (applied field H(t) → M, B), so that the
whole actuator chain (current → H → M → λ → y) sees eddy-current and excess losses.

**The scheme.** Unknown per sample interval [t_n, t_{n+1}] (applied field linear in
time) is the hysteresis field at its end, h_{n+1}; over the interval M follows the static
form along h, by the same interval map as the static model (RK4 in h with ``substeps``
pieces, the δM switch located), and B = μ0·(h + M). The field balance
H = h + H_eddy + H_exc is imposed at the interval's midpoint with the interval's mean
rate of B (the implicit midpoint rule, second order in the sample step):

    (H_n + H_{n+1})/2 − (h_n + h_{n+1})/2 = k_e·r + k_x·sign(r)·|r|^(1/2) + τ·r_h,
    r = (B_{n+1} − B_n)/(t_{n+1} − t_n),   r_h = (h_{n+1} − h_n)/(t_{n+1} − t_n).

The left side falls and the right side rises with h_{n+1}, so the root is unique and
lies between h_n and H_n + H_{n+1} − h_n. It is found from the closed-form root of the
linearized equation (the start slope for dB/dh) by a fixed number of Newton steps
(`NEWTON_STEPS`), each with dB/dh from forward mode through the interval map, kept inside
that bracket. With k_e = k_x = τ = 0 the first guess is h_{n+1} = H_{n+1}: the static model,
to round-off. Where the form's slope is not finite or below −1 (a mean field α·Ms beyond
the anhysteretic's stability) the guess takes the vacuum's slope, and a Newton step is
skipped where G does not fall with h_{n+1}: the values stay finite and in the bracket.
Within an interval h is taken linear in time for the structural forcing.

**The time loop** is the skeleton of `jaxhyst.model.timeloop`, with `RateDependentPath`
as its form: the state is the static form's state and h, and its derivative rule, batch
rule and accelerator form are the skeleton's. The derivatives of h_{n+1} are the
implicit function's (at the converged root, not Newton's steps differentiated). Any form
with an interval map along the hysteresis field plugs in (`JAPath` for the Jiles–Atherton
variants).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp

from ..params import MU0
from .interval import on_accelerator
from .losses import LOSS_NAMES, dynamic_field
from .timeloop import AbstractPathForm, Interval

#: Newton steps per sample interval after the closed-form first guess.
NEWTON_STEPS = 4


def _balance(inner, S, batched, p, losses, H0, H1, dt, state, h0, h1):
    """The interval's field balance G(h_{n+1}) (A/m): zero at the solution."""
    M0 = inner.magnetization(state)
    M1 = inner.end_magnetization(p, h0, h1, state, S, batched)
    rate = (MU0 * (h1 + M1) - MU0 * (h0 + M0)) / dt
    return 0.5 * (H0 + H1) - 0.5 * (h0 + h1) - dynamic_field(rate, losses, (h1 - h0) / dt)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2))
def _end_field(inner, S, batched, p, losses, H0, H1, dt, state, h0):
    """h_{n+1}: the root of `_balance` (module docstring). Its derivative is the implicit
    function's, dh = −∂G/∂(inputs)·d(inputs) / ∂G/∂h (not Newton's steps differentiated)."""
    R = 0.5 * (H0 + H1) - h0  # the balance's left side at h_{n+1} = h_n
    lo, hi = jnp.minimum(h0, h0 + 2.0 * R), jnp.maximum(h0, h0 + 2.0 * R)
    # first guess: dB/dh frozen at its start value, the quadratic in √|Δh| solved exactly
    slope = jax.vmap(inner.slope) if batched else inner.slope
    chi = slope(p, h0, state, jnp.where(R >= 0, 1.0, -1.0))
    # (a slope that is not finite or below −1 — a feedback α·Ms beyond the anhysteretic's
    # stability — gives no usable guess: start from the vacuum's)
    chi = jnp.where(jnp.isfinite(chi) & (chi > -1.0), chi, 0.0)
    c = MU0 * (1.0 + chi) / dt
    a = 0.5 + losses.eddy * c + losses.lag / dt
    b = losses.excess * jnp.sqrt(jnp.maximum(c, 0.0))
    moving = R != 0
    absR = jnp.where(moving, jnp.abs(R), 1.0)  # (no 0/0 in values or derivatives)
    s = 2.0 * absR / (b + jnp.sqrt(b * b + 4.0 * a * absR))  # (the stable root form)
    h1 = jnp.clip(h0 + jnp.where(moving, jnp.sign(R) * s * s, 0.0), lo, hi)

    def balance(h1):
        return _balance(inner, S, batched, p, losses, H0, H1, dt, state, h0, h1)

    def newton(_, h1):
        G, dG = jax.jvp(balance, (h1,), (jnp.ones_like(h1),))
        # G falls with h1; where it does not (an unstable feedback) no step is taken
        return jnp.clip(h1 - jnp.where(dG < 0, G, 0.0) / jnp.where(dG < 0, dG, -1.0),
                        lo, hi)

    return jax.lax.fori_loop(0, NEWTON_STEPS, newton, h1, unroll=on_accelerator())


@_end_field.defjvp
def _end_field_jvp(inner, S, batched, primals, tangents):
    h1 = _end_field(inner, S, batched, *primals)

    def balance(h1, *inputs):
        return _balance(inner, S, batched, *inputs, h1)

    # ∂G/∂h and ∂G/∂(inputs)·d(inputs) by one forward pass of two tangents (one trace)
    zero = jax.tree.map(jnp.zeros_like, tangents)
    both = jax.tree.map(lambda a, b: jnp.stack([a, b]), (jnp.ones_like(h1), zero),
                        (jnp.zeros_like(h1), tangents))
    G_h, G_inputs = jax.vmap(lambda d: jax.jvp(balance, (h1, *primals), (d[0], *d[1]))[1])(
        both)
    return h1, -G_inputs / G_h


class RateDependentPath(AbstractPathForm):
    """The field-separation model in the time loop (module docstring): ``inner`` is the
    static form along the hysteresis field h (`JAPath` with its own end slopes, or any
    form with ``advance``, ``magnetization``, ``end_magnetization``, ``slope`` and
    ``n_outputs``); the state is ``inner``'s and h; the parameters are ``(inner's
    parameters, Losses)``; the outputs of an interval are ``inner``'s and h_{n+1}
    (the last)."""

    inner: AbstractPathForm

    @property
    def scales_with_Ms(self) -> bool:
        return False  # (h does not scale with Ms)

    @property
    def state_size(self) -> int:
        return self.inner.state_size + 1

    @property
    def parameters(self) -> tuple[str, ...]:
        return (*self.inner.parameters, *LOSS_NAMES)

    def initial_state(self, theta, H0):
        inner_theta, _ = theta
        return jnp.concatenate([self.inner.initial_state(inner_theta, H0), H0[..., None]],
                               axis=-1)

    def state_rows(self, substeps: int) -> tuple[int, ...]:
        return (*self.inner.state_rows(substeps), self.inner.n_outputs(substeps))

    def interval(self, theta, x: Interval, state, substeps: int, batched: bool):
        p, losses = theta  # (p: the inner form's parameters)
        inner_state, h0 = state[..., :-1], state[..., -1]
        h1 = _end_field(self.inner, substeps, batched, p, losses, x.H0, x.H1, x.dt,
                        inner_state, h0)
        out = self.inner.advance(p, h0, h1, inner_state, x.delta, substeps, batched)
        return jnp.concatenate([out, h1[..., None]], axis=-1)
