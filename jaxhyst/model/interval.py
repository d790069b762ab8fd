"""One sample interval of the Jiles–Atherton path: M advanced by RK4 in H.

Per sample interval [H_n, H_{n+1}] the field is linear in time and its direction
δ_n = sign(H_{n+1} − H_n) is fixed. The interval is divided into ``substeps`` equal
parts (the substep points u_j = H_n + j·ΔH/S, j = 0 … S); M is advanced by classic RK4
*in H* (the model is rate independent) over those parts.

**The δM switch.** After a field reversal the irreversible term is off (δ·(Man − M) ≤ 0)
until Man − M changes sign; there dM/dH has a kink (M is only C¹) and an RK4 step across
it loses three orders. When an interval starts with the switch off, a reversible RK4
step over the whole interval predicts where it switches on: the root of the cubic Hermite
interpolant of d = δ·(Man − M) (values and dd/dH at both ends). That point becomes one
extra piece boundary, so the interval is integrated in S + 1 RK4 pieces with the kink on
a boundary (in S pieces otherwise). The uniform substep points stay piece boundaries: the
structural dynamics are driven from them.

`interval_map` is one interval for one trajectory, `interval_map_batched` the same map
for a batch, with the rare branches computed only when some member needs them.

**On an accelerator** (`on_accelerator`: JAX's default backend is a GPU or TPU) every
``lax.cond`` and small loop inside the time loop costs a round trip to the host per
interval, which dominates there: the branches are then computed always and selected, and
the RK4 stages unrolled — the same values, more arithmetic, fewer launches.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from ..params import Parameters
from .jiles_atherton import AbstractJAVariant

#: Test and benchmark hook: True takes the accelerator's branch-free path on the CPU
#: too, False the branching path on an accelerator; None (default) decides by backend.
FORCE_BRANCH_FREE: bool | None = None


def on_accelerator() -> bool:
    """Whether the time loops are traced for an accelerator (module docstring): JAX's
    default backend is not the CPU (unless `FORCE_BRANCH_FREE` says otherwise)."""
    if FORCE_BRANCH_FREE is not None:
        return FORCE_BRANCH_FREE
    return jax.default_backend() != "cpu"


def branch(pred, true_fn, false_fn, *operands):
    """``lax.cond(pred, true_fn, false_fn, *operands)`` on the CPU; on an accelerator both
    branches, selected by ``pred`` (a scalar)."""
    if not on_accelerator():
        return jax.lax.cond(pred, true_fn, false_fn, *operands)
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), true_fn(*operands),
                        false_fn(*operands))


def _rk4(f, H, M, dH, k1):
    """One classic RK4 step of dM/dH = f(H, M) from (H, M) over dH, given k1 = f(H, M).

    Stages 2–4 are a three-iteration loop around one evaluation of f rather than three
    copies of it: the same arithmetic, a third of the code to trace and compile."""

    def stage(i, state):
        k, total = state
        last = i == 2  # stages 2 and 3 at the midpoint, weight 2; stage 4 at the end
        h = jnp.where(last, dH, 0.5 * dH)
        k = f(H + h, M + h * k)
        return k, total + jnp.where(last, k, 2.0 * k)

    _, total = jax.lax.fori_loop(0, 3, stage, (k1, k1), unroll=on_accelerator())
    return M + (dH / 6.0) * total


def _hermite_root(d0, d1, s0, s1, iterations: int = 2):
    """Root in [0, 1] of the cubic Hermite interpolant with values d0 ≤ 0 < d1 and slopes
    s0, s1 (per unit of the interval) at 0 and 1: Newton from the secant estimate."""
    t = d0 / (d0 - d1)
    for _ in range(iterations):
        t2, t3 = t * t, t * t * t
        value = ((2 * t3 - 3 * t2 + 1) * d0 + (t3 - 2 * t2 + t) * s0
                 + (3 * t2 - 2 * t3) * d1 + (t3 - t2) * s1)
        slope = ((6 * t2 - 6 * t) * (d0 - d1) + (3 * t2 - 4 * t + 1) * s0
                 + (3 * t2 - 2 * t) * s1)
        step = value / jnp.where(slope > 0, slope, 1.0)
        t = jnp.clip(t - jnp.where(slope > 0, step, 0.0), 0.0, 1.0)
    return t


def _switch_fraction(variant, p, delta, H0, H1, M0, start):
    """Fraction θ ∈ [0, 1] of the interval at which δM switches on (1: it does not), from
    a reversible RK4 step over the interval and the cubic Hermite interpolant of the
    switch distance d = δ·(Man − M) between its ends. ``start`` is `AbstractJAVariant.evaluate`
    at (H0, M0): called where d ≤ 0 there, so the irreversible term is off and that slope
    is the reversible one."""
    dH = H1 - H0

    def reversible(H, M):
        return variant.slope(H, M, delta, p, pinning=False)

    k0, d0, s0 = start
    M1 = _rk4(reversible, H0, M0, dH, k0)
    _, d1, s1 = variant.evaluate(H1, M1, delta, p, pinning=False)
    switches = d1 > 0
    theta = _hermite_root(d0, jnp.where(switches, d1, 1.0), s0 * dH, s1 * dH)
    return jnp.where(switches, theta, 1.0)


def _pieces(variant, p, H0, H1, M0, k0, theta, substeps):
    """The S pieces up to b_S (uniform substep points, with θ inserted after the last
    one below it). Returns (ends, starts, b_S): M after and the slope at the start of
    each piece, and where the S-th piece ended (the extra piece covers [b_S, 1])."""
    S = substeps
    dH = H1 - H0
    delta = jnp.where(dH >= 0, 1.0, -1.0)
    m = jnp.floor(theta * S)  # substep points below the switch: u_0 … u_m
    b = [jnp.where(i <= m, i / S, jnp.where(i == m + 1, theta, (i - 1) / S))
         for i in range(S + 1)]
    ends, starts = [], []
    M, k = M0, k0
    for i in range(S):
        if i > 0:
            k = variant.slope(H0 + b[i] * dH, M, delta, p)
        starts.append(k)
        M = _rk4(lambda H, M: variant.slope(H, M, delta, p), H0 + b[i] * dH, M,
                 (b[i + 1] - b[i]) * dH, k)
        ends.append(M)
    return ends, starts, b[S]


def _last_piece(variant, p, H0, H1, M, b_S):
    """The extra piece from b_S to the end of the interval: (M at H1, slope at b_S)."""
    dH = H1 - H0
    delta = jnp.where(dH >= 0, 1.0, -1.0)
    Ha = H0 + b_S * dH
    k = variant.slope(Ha, M, delta, p)
    return _rk4(lambda H, M: variant.slope(H, M, delta, p), Ha, M, (1.0 - b_S) * dH, k), k


def _assemble(ends, starts, theta, substeps):
    """M at u_1 … u_S and the slope at u_0 … u_{S−1} from the S + 1 pieces."""
    S = substeps
    m = jnp.floor(theta * S)
    M_points = jnp.stack([jnp.where(j <= m, ends[j - 1], ends[j]) for j in range(1, S + 1)])
    k_points = jnp.stack([jnp.where(j <= m, starts[j], starts[j + 1]) for j in range(S)])
    return M_points, k_points


def direction_of(H0, H1):
    return jnp.where(H1 >= H0, 1.0, -1.0)


def interval_map(variant: AbstractJAVariant, p: Parameters, H0, H1, M0, substeps: int):
    """Advance M over one sample interval from (H0, M0) to H1.

    **Returns:** ``(M_points, k_points)``: M (A/m) at the substep points u_1 … u_S and the
    slope dM/dH (with this interval's direction) at u_0 … u_{S−1}, each shape (S,).
    The located switch and the extra piece are ``lax.cond`` branches, taken only after
    field reversals (`interval_map_batched` is the same map for a batch).
    """
    delta = direction_of(H0, H1)
    start = variant.evaluate(H0, M0, delta, p)
    k0, d0, _ = start
    theta = branch(d0 <= 0, lambda: _switch_fraction(variant, p, delta, H0, H1, M0, start),
                   lambda: jnp.ones_like(H0))
    ends, starts, b_S = _pieces(variant, p, H0, H1, M0, k0, theta, substeps)
    # the extra piece has zero length unless the switch falls inside this interval
    M_last, k_last = branch(b_S < 1.0, lambda M: _last_piece(variant, p, H0, H1, M, b_S),
                            lambda M: (M, k0), ends[-1])
    return _assemble([*ends, M_last], [*starts, k_last], theta, substeps)


def interval_map_batched(variant, p, H0, H1, M0, substeps: int):
    """`interval_map` for a batch (every argument with a leading axis of the same size,
    `Parameters` leaves included), with the rare branches computed only when some member
    needs them: ``jax.vmap`` of `interval_map` would evaluate both sides of each
    ``lax.cond`` for every member at every interval, several times the cost."""
    vm = jax.vmap
    delta = direction_of(H0, H1)
    start = vm(lambda H, M, d, p: variant.evaluate(H, M, d, p))(H0, M0, delta, p)
    k0, d0, _ = start
    off = d0 <= 0

    def located():
        theta = vm(lambda *a: _switch_fraction(variant, *a))(p, delta, H0, H1, M0, start)
        return jnp.where(off, theta, 1.0)

    theta = branch(jnp.any(off), located, lambda: jnp.ones_like(H0))
    ends, starts, b_S = vm(lambda *a: _pieces(variant, *a, substeps))(p, H0, H1, M0, k0,
                                                                       theta)
    M_last, k_last = branch(
        jnp.any(b_S < 1.0),
        lambda: vm(lambda *a: _last_piece(variant, *a))(p, H0, H1, ends[-1], b_S),
        lambda: (ends[-1], k0))
    M_points, k_points = vm(lambda e, s, t: _assemble(e, s, t, substeps))(
        [*ends, M_last], [*starts, k_last], theta)
    return M_points, k_points
