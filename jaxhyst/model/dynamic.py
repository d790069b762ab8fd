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

**The after-effect** (``Losses.relax`` = τ_M: τ_M·dM/dt = M_s − M, M_s the static form's
magnetization along h). Over an interval M_s is taken linear in time (slope
s = (M_s,n+1 − M_s,n)/Δt), for which the relaxation is exact: with the rate deficit
Q = (M_s − M)/τ_M carried in the state and e = exp(−Δt/τ_M),

    Q_{n+1} = s·(1 − e) + Q_n·e,   M = M_s − τ_M·Q,

free of cancellation as τ_M → 0 (e → 0, Q → s, M → M_s: the model without it, to
round-off at τ_M = 0). The balance's B is the relaxed one, so its root need not lie
between h_n and H_n + H_{n+1} − h_n: the bracket is taken from the balance's value at
h_{n+1} = h_n instead (closed form: there M changes by τ_M·Q_n·(1 − e)), which the
balance's fall with h_{n+1} makes a bracket again. Inside the interval, M at the substep
points (elapsed time θ·Δt) is M_s there minus τ_M·Q(θ), Q(θ) = s·(1 − e_θ) + Q_n·e_θ
(`relaxed`), second order in the sample step like the balance.

**Driven by B** (``RateDependentPath(inner, driver="B")``, the after-effect of
`jaxhyst.simulate_flux`): the drive is B (T) at the samples, and h_{n+1} is the root of

    B_{n+1}/μ0 − h_{n+1} − M_{n+1}(h_{n+1}) = 0,   M_{n+1} = M_s,n+1 − τ_M·Q_{n+1},

(B = μ0·(h + M), M relaxed as above) — where the form's slope is not negative it falls
with h_{n+1} at least as fast as −1, so it lies between h_n and h_n + G(h_n): a guess of
the same kind, then `FLUX_NEWTON_STEPS` Newton steps that narrow that bracket and bisect
it where a step would leave it; the loss fields are then explicit in B's rate
(`jaxhyst.model.flux`).

**The time loop** is the skeleton of `jaxhyst.model.timeloop`, with `RateDependentPath`
as its form: the state is the static form's state, the after-effect's Q and h, and its
derivative rule, batch rule and accelerator form are the skeleton's. The derivatives of
h_{n+1} are the implicit function's (at the converged root, not Newton's steps
differentiated). Any form with an interval map along the hysteresis field plugs in
(`JAPath` for the Jiles–Atherton variants).
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ..params import MU0
from .interval import on_accelerator
from .losses import LOSS_NAMES, decay, dynamic_field
from .timeloop import AbstractPathForm, Interval

#: Newton steps per sample interval after the closed-form first guess.
NEWTON_STEPS = 4
#: … of the B-driven model with the after-effect, whose first guess can be far off where
#: the static form's slope changes sharply within an interval (a reversal into a steep
#: branch): the bracket's bisection then takes over.
FLUX_NEWTON_STEPS = 12


def relaxed_deficit(tau, dt, s, Q0):
    """The after-effect's rate deficit Q = (M_s − M)/τ_M (A/(m·s)) after ``dt`` (s) from
    ``Q0``, M_s rising at ``s`` (A/(m·s)) meanwhile (module docstring)."""
    e = decay(tau, dt)
    return s * (1.0 - e) + Q0 * e


def _relaxed_ends(inner, S, batched, p, losses, dt, state, Q0, h0, h1):
    """The relaxed M (A/m) at the interval's start and end, h going from h0 to h1."""
    Ms0 = inner.magnetization(state)
    Ms1 = inner.end_magnetization(p, h0, h1, state, S, batched)
    Q1 = relaxed_deficit(losses.relax, dt, (Ms1 - Ms0) / dt, Q0)
    return Ms0 - losses.relax * Q0, Ms1 - losses.relax * Q1


def _first_slope(inner, batched, p, h0, state, direction, tau, e, dt):
    """dM/dh for a first guess: the form's slope at h0 moving in ``direction``, times the
    share of dM_s the relaxation passes on within the interval (decay ``e``)."""
    slope = jax.vmap(inner.slope) if batched else inner.slope
    chi = slope(p, h0, state, jnp.where(direction >= 0, 1.0, -1.0))
    # (a slope that is not finite or below −1 — a feedback α·Ms beyond the anhysteretic's
    # stability — gives no usable guess: start from the vacuum's)
    chi = jnp.where(jnp.isfinite(chi) & (chi > -1.0), chi, 0.0)
    return chi * (1.0 - tau * (1.0 - e) / dt)


def _balance(inner, S, batched, p, losses, H0, H1, dt, state, Q0, h0, h1):
    """The interval's field balance G(h_{n+1}) (A/m): zero at the solution."""
    M0, M1 = _relaxed_ends(inner, S, batched, p, losses, dt, state, Q0, h0, h1)
    rate = (MU0 * (h1 + M1) - MU0 * (h0 + M0)) / dt
    return 0.5 * (H0 + H1) - 0.5 * (h0 + h1) - dynamic_field(rate, losses, (h1 - h0) / dt)


def _flux_balance(inner, S, batched, p, losses, B1, dt, state, Q0, h0, h1):
    """B_{n+1}/μ0 − h_{n+1} − M_{n+1} (A/m): zero at the B-driven solution."""
    _, M1 = _relaxed_ends(inner, S, batched, p, losses, dt, state, Q0, h0, h1)
    return B1 / MU0 - h1 - M1


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2))
def _end_field_by_flux(inner, S, batched, p, losses, B1, dt, state, Q0, h0):
    """h_{n+1} of the B-driven model: the root of `_flux_balance` (module docstring), with
    the implicit function's derivative (`_implicit_jvp`)."""
    tau = losses.relax
    e = decay(tau, dt)
    G0 = B1 / MU0 - h0 - (inner.magnetization(state) - tau * Q0 * e)  # (at h_{n+1} = h_n)
    lo, hi = jnp.minimum(h0, h0 + G0), jnp.maximum(h0, h0 + G0)
    chi = _first_slope(inner, batched, p, h0, state, G0, tau, e, dt)
    h1 = jnp.clip(h0 + G0 / (1.0 + chi), lo, hi)

    def balance(h1):
        return _flux_balance(inner, S, batched, p, losses, B1, dt, state, Q0, h0, h1)

    return _bracketed_newton(balance, h1, lo, hi)


def _newton(balance, h1, lo, hi):
    """`NEWTON_STEPS` safeguarded Newton steps on a balance that falls with h1."""
    def newton(_, h1):
        G, dG = jax.jvp(balance, (h1,), (jnp.ones_like(h1),))
        # G falls with h1; where it does not (an unstable feedback) no step is taken
        return jnp.clip(h1 - jnp.where(dG < 0, G, 0.0) / jnp.where(dG < 0, dG, -1.0),
                        lo, hi)

    return jax.lax.fori_loop(0, NEWTON_STEPS, newton, h1, unroll=on_accelerator())


def _bracketed_newton(balance, h1, lo, hi):
    """`FLUX_NEWTON_STEPS` Newton steps on a balance that falls with h1, its root in
    [lo, hi]: each evaluation narrows the bracket (G > 0: the root lies above), and a
    step that would leave it bisects it instead."""
    def newton(_, carry):
        h1, lo, hi = carry
        G, dG = jax.jvp(balance, (h1,), (jnp.ones_like(h1),))
        lo, hi = jnp.where(G > 0, h1, lo), jnp.where(G < 0, h1, hi)
        step = h1 - G / jnp.where(dG < 0, dG, -1.0)
        inside = (step >= lo) & (step <= hi)  # (at the root the step is an end of it)
        return jnp.where(G == 0, h1, jnp.where(inside, step, 0.5 * (lo + hi))), lo, hi

    return jax.lax.fori_loop(0, FLUX_NEWTON_STEPS, newton, (h1, lo, hi),
                             unroll=on_accelerator())[0]


def _implicit_jvp(root, balance_of, inner, S, batched, primals, tangents):
    """(h, dh) of a root h of ``balance_of(inner, S, batched, *primals, h)``: ∂G/∂h and
    ∂G/∂(inputs)·d(inputs) by one forward pass of two tangents (one trace)."""
    h1 = root(inner, S, batched, *primals)

    def balance(h1, *inputs):
        return balance_of(inner, S, batched, *inputs, h1)

    zero = jax.tree.map(jnp.zeros_like, tangents)
    both = jax.tree.map(lambda a, b: jnp.stack([a, b]), (jnp.ones_like(h1), zero),
                        (jnp.zeros_like(h1), tangents))
    G_h, G_inputs = jax.vmap(lambda d: jax.jvp(balance, (h1, *primals), (d[0], *d[1]))[1])(
        both)
    return h1, -G_inputs / G_h


@_end_field_by_flux.defjvp
def _end_field_by_flux_jvp(inner, S, batched, primals, tangents):
    return _implicit_jvp(_end_field_by_flux, _flux_balance, inner, S, batched, primals,
                         tangents)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1, 2))
def _end_field(inner, S, batched, p, losses, H0, H1, dt, state, Q0, h0):
    """h_{n+1}: the root of `_balance` (module docstring). Its derivative is the implicit
    function's, dh = −∂G/∂(inputs)·d(inputs) / ∂G/∂h (not Newton's steps differentiated)."""
    # the balance at h_{n+1} = h_n (where only the after-effect moves M)
    tau = losses.relax
    e = decay(tau, dt)
    drift = MU0 * tau * Q0 * (1.0 - e) / dt
    R = 0.5 * (H0 + H1) - h0 - dynamic_field(drift, losses)
    lo, hi = jnp.minimum(h0, h0 + 2.0 * R), jnp.maximum(h0, h0 + 2.0 * R)
    # first guess: dB/dh frozen at its start value, the quadratic in √|Δh| solved exactly
    chi = _first_slope(inner, batched, p, h0, state, R, tau, e, dt)
    c = MU0 * (1.0 + chi) / dt
    a = 0.5 + losses.eddy * c + losses.lag / dt
    b = losses.excess * jnp.sqrt(jnp.maximum(c, 0.0))
    moving = R != 0
    absR = jnp.where(moving, jnp.abs(R), 1.0)  # (no 0/0 in values or derivatives)
    s = 2.0 * absR / (b + jnp.sqrt(b * b + 4.0 * a * absR))  # (the stable root form)
    h1 = jnp.clip(h0 + jnp.where(moving, jnp.sign(R) * s * s, 0.0), lo, hi)

    def balance(h1):
        return _balance(inner, S, batched, p, losses, H0, H1, dt, state, Q0, h0, h1)

    return _newton(balance, h1, lo, hi)


@_end_field.defjvp
def _end_field_jvp(inner, S, batched, primals, tangents):
    return _implicit_jvp(_end_field, _balance, inner, S, batched, primals, tangents)


class RateDependentPath(AbstractPathForm):
    """The field-separation model in the time loop (module docstring): ``inner`` is the
    static form along the hysteresis field h (`JAPath` with its own end slopes, or any
    form with ``advance``, ``magnetization``, ``end_magnetization``, ``slope`` and
    ``n_outputs``); the state is ``inner``'s, Q (the after-effect's rate deficit) and h;
    the parameters are ``(inner's parameters, Losses)``; the outputs of an interval are
    ``inner``'s, Q_{n+1} and h_{n+1} (the last). ``driver``: "H" (the applied field, A/m:
    the field balance) or "B" (T: h from B = μ0·(h + M), the loss fields left to the
    caller)."""

    inner: AbstractPathForm
    driver: str = eqx.field(static=True, default="H")

    @property
    def scales_with_Ms(self) -> bool:
        return False  # (h does not scale with Ms)

    @property
    def state_size(self) -> int:
        return self.inner.state_size + 2

    @property
    def parameters(self) -> tuple[str, ...]:
        return (*self.inner.parameters, *LOSS_NAMES)

    def initial_state(self, theta, H0):
        inner_theta, _ = theta
        h0 = H0 / MU0 if self.driver == "B" else H0  # (demagnetized: M = 0)
        return jnp.concatenate([self.inner.initial_state(inner_theta, h0),
                                jnp.zeros_like(h0)[..., None], h0[..., None]], axis=-1)

    def state_rows(self, substeps: int) -> tuple[int, ...]:
        n = self.inner.n_outputs(substeps)
        return (*self.inner.state_rows(substeps), n, n + 1)

    def interval(self, theta, x: Interval, state, substeps: int, batched: bool):
        p, losses = theta  # (p: the inner form's parameters)
        inner_state, Q0, h0 = state[..., :-2], state[..., -2], state[..., -1]
        if self.driver == "B":
            h1 = _end_field_by_flux(self.inner, substeps, batched, p, losses, x.H1, x.dt,
                                    inner_state, Q0, h0)
        else:
            h1 = _end_field(self.inner, substeps, batched, p, losses, x.H0, x.H1, x.dt,
                            inner_state, Q0, h0)
        out = self.inner.advance(p, h0, h1, inner_state, x.delta, substeps, batched)
        following = out[..., jnp.asarray(self.inner.state_rows(substeps))]
        slope = (self.inner.magnetization(following) - self.inner.magnetization(
            inner_state)) / x.dt
        Q1 = relaxed_deficit(losses.relax, x.dt, slope, Q0)
        return jnp.concatenate([out, Q1[..., None], h1[..., None]], axis=-1)


def relaxed(tau, t, Y_sub, Q, S: int, M0):
    """The after-effect inside each interval (module docstring): from the static form's
    M_s at the substep points u_1 … u_S, ``Y_sub`` (N, S), M_s = ``M0`` at the first
    sample, and the rate deficit ``Q`` at the samples (N + 1,), ``(M_sub (N, S), dM (N,
    S + 1))``: the relaxed M at u_1 … u_S, and what to add to dM_s/dt at u_0 … u_S for
    dM/dt (−e_θ·(s − Q_n); zero at τ_M = 0)."""
    dt = jnp.diff(t)
    ends = jnp.concatenate([jnp.reshape(M0, (1,)), Y_sub[:, -1]])
    s = jnp.diff(ends) / dt
    theta = jnp.arange(S + 1, dtype=Y_sub.dtype) / S
    e = decay(tau, theta * dt[:, None])  # (N, S + 1)
    deficit = s[:, None] * (1.0 - e[:, 1:]) + Q[:-1, None] * e[:, 1:]
    return Y_sub - tau * deficit, -e * (s - Q[:-1])[:, None]
