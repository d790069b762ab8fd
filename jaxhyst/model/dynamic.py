"""The rate-dependent model driven by H: the field-separation form of
`jaxhyst.model.losses` in the forward direction (applied field H(t) → M, B), so that the
whole actuator chain (current → H → M → λ → y) sees eddy-current and excess losses.

**The scheme.** Unknown per sample interval [t_n, t_{n+1}] (applied field linear in
time) is the hysteresis field at its end, h_{n+1}; over the interval M follows the static
form along h, by the same interval map as the static model (RK4 in h with ``substeps``
pieces, the δM switch located), and B = μ0·(h + M). The field balance
H = h + H_eddy + H_exc is imposed at the interval's midpoint with the interval's mean
rate of B (the implicit midpoint rule, second order in the sample step):

    (H_n + H_{n+1})/2 − (h_n + h_{n+1})/2 = k_e·r + k_x·sign(r)·|r|^(1/2),
    r = (B_{n+1} − B_n)/(t_{n+1} − t_n).

The left side falls and the right side rises with h_{n+1}, so the root is unique and
lies between h_n and H_n + H_{n+1} − h_n. It is found from the closed-form root of the
linearized equation (the start slope for dB/dh) by a fixed number of Newton steps
(`NEWTON_STEPS`), each with dB/dh from forward mode through the interval map, kept inside
that bracket. With k_e = k_x = 0 the first guess is h_{n+1} = H_{n+1}: the static model,
to round-off. Within an interval h is taken linear in time for the structural forcing.

**Derivatives** have a rule of the static loop's kind: each interval's partial
derivatives with respect to its start state (M_n, h_n), the parameters, the loss
coefficients and the field are formed by forward mode in one pass of the loop (through
the implicit function theorem at the converged root, not Newton's steps), then
propagated by a linear recurrence in (M, h); reverse
mode transposes that recurrence and never replays the loop's body.
"""

from __future__ import annotations

import functools

import equinox as eqx
import jax
import jax.numpy as jnp

from ..params import MU0, Parameters
from .interval import direction_of, interval_map, on_accelerator
from .jiles_atherton import AbstractJAVariant
from .losses import Losses, dynamic_field

#: Newton steps per sample interval after the closed-form first guess.
NEWTON_STEPS = 4


def _balance(variant, S, p, losses, H0, H1, dt, M0, h0, h1):
    """The interval's field balance G(h_{n+1}) (A/m): zero at the solution."""
    M_points, _ = interval_map(variant, p, h0, h1, M0, S)
    rate = (MU0 * (h1 + M_points[-1]) - MU0 * (h0 + M0)) / dt
    return 0.5 * (H0 + H1) - 0.5 * (h0 + h1) - dynamic_field(rate, losses)


@functools.partial(jax.custom_jvp, nondiff_argnums=(0, 1))
def _end_field(variant, S, p, losses, H0, H1, dt, M0, h0):
    """h_{n+1}: the root of `_balance` (module docstring). Its derivative is the implicit
    function's, dh = −∂G/∂(inputs)·d(inputs) / ∂G/∂h (not Newton's steps differentiated)."""
    R = 0.5 * (H0 + H1) - h0  # the balance's left side at h_{n+1} = h_n
    lo, hi = jnp.minimum(h0, h0 + 2.0 * R), jnp.maximum(h0, h0 + 2.0 * R)
    # first guess: dB/dh frozen at its start value, the quadratic in √|Δh| solved exactly
    chi = variant.slope(h0, M0, jnp.where(R >= 0, 1.0, -1.0), p)
    c = MU0 * (1.0 + chi) / dt
    a = 0.5 + losses.eddy * c
    b = losses.excess * jnp.sqrt(jnp.maximum(c, 0.0))
    moving = R != 0
    absR = jnp.where(moving, jnp.abs(R), 1.0)  # (no 0/0 in values or derivatives)
    s = 2.0 * absR / (b + jnp.sqrt(b * b + 4.0 * a * absR))  # (the stable root form)
    h1 = jnp.clip(h0 + jnp.where(moving, jnp.sign(R) * s * s, 0.0), lo, hi)

    def balance(h1):
        return _balance(variant, S, p, losses, H0, H1, dt, M0, h0, h1)

    def newton(_, h1):
        G, dG = jax.jvp(balance, (h1,), (jnp.ones_like(h1),))
        return jnp.clip(h1 - G / dG, lo, hi)

    return jax.lax.fori_loop(0, NEWTON_STEPS, newton, h1, unroll=on_accelerator())


@_end_field.defjvp
def _end_field_jvp(variant, S, primals, tangents):
    h1 = _end_field(variant, S, *primals)

    def balance(h1, *inputs):
        return _balance(variant, S, *inputs, h1)

    G_h = jax.jvp(lambda h: balance(h, *primals), (h1,), (jnp.ones_like(h1),))[1]
    G_inputs = jax.jvp(lambda *x: balance(h1, *x), primals, tangents)[1]
    return h1, -G_inputs / G_h


def _interval(variant, p, losses, H0, H1, dt, M0, h0, S):
    """One sample interval: (M at the S substep points, the slope at u_0 … u_{S−1} with
    this interval's direction, h_{n+1})."""
    h1 = _end_field(variant, S, p, losses, H0, H1, dt, M0, h0)
    M_points, k_points = interval_map(variant, p, h0, h1, M0, S)
    return M_points, k_points, h1


def _outputs(variant, p, losses, H0, H1, dt, M0, h0, S):
    """One interval's outputs as the derivative rule differentiates them: M at u_1 … u_S,
    the slope at u_0 … u_S (this interval's direction), h_{n+1}: shape (2S + 2,)."""
    M_points, k_points, h1 = _interval(variant, p, losses, H0, H1, dt, M0, h0, S)
    k_end = variant.slope(h1, M_points[-1], direction_of(h0, h1), p)
    return jnp.concatenate([M_points, k_points, k_end[None], h1[None]])


def _loop(variant, p, losses, t, H, S):
    """The time loop: outputs of every interval (N, 2S + 2)."""

    def step(carry, interval):
        M0, h0 = carry
        H0, H1, dt = interval
        out = _outputs(variant, p, losses, H0, H1, dt, M0, h0, S)
        return (out[S - 1], out[-1]), out

    zero = jnp.zeros((), dtype=H.dtype)
    _, out = jax.lax.scan(step, (zero, H[0]), (H[:-1], H[1:], jnp.diff(t)))
    return out


def _split(out, H, S):
    """(M_sub (N, S), k_sub (N, S + 1), h at the samples (T,)) from the loop's outputs."""
    return out[:, :S], out[:, S:2 * S + 1], jnp.concatenate([H[:1], out[:, -1]])


def dynamic_path(p: Parameters, losses: Losses, t, H, *, variant: AbstractJAVariant,
                 substeps: int):
    """The rate-dependent magnetization path from the demagnetized state at rest:
    (M at the substep points u_1 … u_S of each interval (N, S), dM/dh at u_0 … u_S with
    the interval's direction (N, S + 1), the hysteresis field h at the samples (T,)).
    ``t`` (s) and ``H`` (A/m) of shape (T,). Its derivative rule forms each interval's
    partial derivatives by forward mode in one pass of the loop and propagates them by
    a linear recurrence in the state (M, h), as the static loop's rule does
    (`jaxhyst.model.magnetization`); times are not differentiated."""
    S = int(substeps)
    return _split(_path(p, losses, t, H, variant=variant, substeps=S), H, S)


@eqx.filter_custom_jvp
def _path(p, losses, t, H, *, variant, substeps):
    return _loop(variant, p, losses, t, H, substeps)


@_path.def_jvp
def _path_jvp(primals, tangents, *, variant, substeps):
    p, losses, t, H = primals
    p_dot, losses_dot, _, H_dot = tangents
    S = substeps
    names = tuple(n for n in variant.parameters
                  if p_dot is not None and getattr(p_dot, n) is not None)
    coefficients = tuple(n for n in ("eddy", "excess")
                         if losses_dot is not None and getattr(losses_dot, n) is not None)
    with_H = H_dot is not None
    if not (names or coefficients or with_H):
        return _path(p, losses, t, H, variant=variant, substeps=S), None
    K = 2 + len(names) + len(coefficients) + 2 * with_H

    def step(carry, interval):
        M0, h0 = carry
        H0, H1, dt = interval
        z = jnp.stack([M0, h0, *[getattr(p, n) for n in names],
                       *[getattr(losses, n) for n in coefficients],
                       *((H0, H1) if with_H else ())])

        def outputs(z):
            q = eqx.tree_at(lambda p: [getattr(p, n) for n in names], p,
                            [z[2 + i] for i in range(len(names))]) if names else p
            off = 2 + len(names)
            L = eqx.tree_at(lambda L: [getattr(L, n) for n in coefficients], losses,
                            [z[off + i] for i in range(len(coefficients))]) \
                if coefficients else losses
            h_start, h_end = (z[-2], z[-1]) if with_H else (H0, H1)
            return _outputs(variant, q, L, h_start, h_end, dt, z[0], z[1], S)

        out, partials = jax.vmap(lambda v: jax.jvp(outputs, (z,), (v,)),
                                 out_axes=(None, -1))(jnp.eye(K, dtype=H.dtype))
        return (out[S - 1], out[-1]), (out, partials)

    zero = jnp.zeros((), dtype=H.dtype)
    _, (out, partials) = jax.lax.scan(step, (zero, H[0]), (H[:-1], H[1:], jnp.diff(t)))
    # r_n: the partials of the inputs other than the state, times their tangents
    columns = [getattr(p_dot, n) for n in names] + [getattr(losses_dot, n)
                                                   for n in coefficients]
    r = sum((partials[..., 2 + i] * c for i, c in enumerate(columns)),
            jnp.zeros_like(out))
    if with_H:
        r = r + partials[..., -2] * H_dot[:-1, None] + partials[..., -1] * H_dot[1:, None]
    state_rows = jnp.array([S - 1, 2 * S + 1])  # (M, h) at an interval's end
    A = partials[:, state_rows][:, :, :2]  # (N, 2, 2)
    r_state = r[:, state_rows]

    def recurrence(ds, ar):
        A_n, r_n = ar
        return A_n @ ds + r_n, ds

    ds0 = jnp.stack([jnp.zeros_like(H[0]), H_dot[0] if with_H else jnp.zeros_like(H[0])])
    _, ds_start = jax.lax.scan(recurrence, ds0, (A, r_state))
    d_out = jnp.einsum("nok,nk->no", partials[..., :2], ds_start) + r
    return out, d_out


