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

**Code size.** On the CPU the pieces of a single trajectory's interval are one loop of
S + 1 iterations, the last computed only where the switch falls inside the interval, so
the slope is traced and compiled once for all pieces, however many ``substeps``; a
batch's are too in the time loop's partials pass (`compact`: its code is multiplied by
the tangents, and again by a second derivative). Programs compile faster, for a few per
cent more run time than straight-line code (benchmarks/RESULTS.md); a batch's values
pass (a population, where run time counts) keeps its pieces straight-line. The RK4
stages are a loop throughout.

`interval_map` is one interval for one trajectory, `interval_map_batched` the same map
for a batch, with the rare branches computed only when some member needs them.

**On an accelerator** (`on_accelerator`: JAX's default backend is a GPU or TPU) every
``lax.cond`` and small loop inside the time loop costs a round trip to the host per
interval, which dominates there: the branches are then computed always and selected, and
the pieces and RK4 stages unrolled — the same values, more arithmetic, fewer launches.
"""

from __future__ import annotations

import contextlib

import jax
import jax.numpy as jnp
import numpy as np

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
    if isinstance(pred, (bool, np.bool_)):  # (known while tracing)
        return true_fn(*operands) if pred else false_fn(*operands)
    if not on_accelerator():
        return jax.lax.cond(pred, true_fn, false_fn, *operands)
    return jax.tree.map(lambda a, b: jnp.where(pred, a, b), true_fn(*operands),
                        false_fn(*operands))


def _rk4(f, H, M, dH, k1, end: bool = False):
    """One classic RK4 step of dM/dH = k from (H, M) over dH, given k1 = k at (H, M),
    where ``f(H, M)`` returns a tuple whose first entry is k. ``end``: also evaluate
    ``f`` at the end of the step (H + dH, M at H + dH).

    **Returns:** (M at H + dH, ``f`` at the end of the step or None).

    Stages 2–4 (and the end) are a loop around one evaluation of ``f`` rather than copies
    of it: the same arithmetic, a fraction of the code to trace and compile."""
    out = jax.tree.map(lambda x: jnp.zeros(x.shape, x.dtype), jax.eval_shape(f, H, M)) \
        if end else ()

    def stage(i, state):
        # i = 1, 2: the midpoint (weight 2); 3: the step's end (weight 1); 4 (``end``
        # only): f at the step's result, which adds nothing to it
        k, total, _ = state
        h = jnp.where(i == 3, dH, 0.5 * dH)
        if end:
            result = i == 4
            out = f(H + jnp.where(result, dH, h),
                    jnp.where(result, M + (dH / 6.0) * total, M + h * k))
            k = out[0]
            added = total + jnp.where(i == 3, k, 2.0 * k)
            return k, jnp.where(result, total, added), out
        k = f(H + h, M + h * k)[0]
        return k, total + jnp.where(i == 3, k, 2.0 * k), ()

    _, total, out = jax.lax.fori_loop(1, 5 if end else 4, stage, (k1, k1, out),
                                      unroll=on_accelerator())
    return M + (dH / 6.0) * total, out if end else None


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
    k0, d0, s0 = start
    _, (_, d1, s1) = _rk4(
        lambda H, M: variant.evaluate(H, M, delta, p, pinning=False), H0, M0, dH, k0,
        end=True)
    switches = d1 > 0
    theta = _hermite_root(d0, jnp.where(switches, d1, 1.0), s0 * dH, s1 * dH)
    return jnp.where(switches, theta, 1.0)


def _boundary(i, m, theta, S):
    """b_i, the start of piece i (0 … S + 1): the uniform substep points with θ inserted
    after the last one below it (b_{S+1} = 1)."""
    i = jnp.asarray(i, dtype=theta.dtype)
    return jnp.where(i <= m, i / S, jnp.where(i == m + 1, theta, (i - 1) / S))


#: Set while the partials pass of the time loop traces its intervals (`compact`).
_COMPACT: list = []


@contextlib.contextmanager
def compact():
    """Trace batches of intervals (`interval_map_batched`) with their pieces as one loop
    (a single copy of the slope to compile) for the duration, on the CPU, as a single
    trajectory's always are. The time loop's partials pass traces under it: there the
    code is multiplied by the tangents and their derivatives, and compile time counts for
    more than the few per cent of run time a loop costs. A batch's values pass (a
    population, where run time counts) keeps its pieces straight-line. Values are the
    same either way."""
    _COMPACT.append(True)
    try:
        yield
    finally:
        _COMPACT.pop()


def _repeat(n: int, body, carry, loop: bool):
    """``body(i, carry)`` for i = 0 … n − 1: a loop (one copy of the body to compile)
    where ``loop`` and on the CPU, else unrolled with static i."""
    if loop and not on_accelerator():
        return jax.lax.fori_loop(0, n, body, carry)
    for i in range(n):
        carry = body(i, carry)
    return carry


def _needed(i, S: int, extra):
    """Whether piece i is computed: the S uniform pieces always, the extra one (i = S)
    where ``extra``; known while tracing where i is."""
    if isinstance(i, int):
        return True if i < S else extra
    return (i < S) | extra


def _piece(variant, p, H0, H1, M0, k0, theta, substeps, i, M):
    """Piece i from b_i to b_{i+1} from M at b_i: (M at b_{i+1}, the slope at b_i)."""
    S = substeps
    dH = H1 - H0
    delta = jnp.where(dH >= 0, 1.0, -1.0)
    m = jnp.floor(theta * S)
    b0, b1 = _boundary(i, m, theta, S), _boundary(i + 1, m, theta, S)
    Ha = H0 + b0 * dH
    k = branch(i == 0, lambda: k0, lambda: variant.slope(Ha, M, delta, p))
    M1, _ = _rk4(lambda H, M: (variant.slope(H, M, delta, p),), Ha, M, (b1 - b0) * dH, k)
    return M1, k


def _assemble(ends, starts, theta, substeps):
    """M at u_1 … u_S and the slope at u_0 … u_{S−1} from the S + 1 pieces (``ends``,
    ``starts``: shape (S + 1,) each, M after and the slope at the start of each)."""
    S = substeps
    m = jnp.floor(theta * S)
    j = jnp.arange(S)
    M_points = jnp.where(j + 1 <= m, ends[:S], ends[1:])
    k_points = jnp.where(j <= m, starts[:S], starts[1:])
    return M_points, k_points


def direction_of(H0, H1):
    return jnp.where(H1 >= H0, 1.0, -1.0)


def interval_map(variant: AbstractJAVariant, p: Parameters, H0, H1, M0, substeps: int):
    """Advance M over one sample interval from (H0, M0) to H1.

    **Returns:** ``(M_points, k_points)``: M (A/m) at the substep points u_1 … u_S and the
    slope dM/dH (with this interval's direction) at u_0 … u_{S−1}, each shape (S,).
    The located switch and the extra piece are ``lax.cond`` branches, taken only after
    field reversals; on the CPU the pieces are one loop (`interval_map_batched` is the
    same map for a batch).
    """
    delta = direction_of(H0, H1)
    start = variant.evaluate(H0, M0, delta, p)
    k0, d0, _ = start
    theta = branch(d0 <= 0, lambda: _switch_fraction(variant, p, delta, H0, H1, M0, start),
                   lambda: jnp.ones_like(H0))
    S = substeps
    b_S = _boundary(S, jnp.floor(theta * S), theta, S)

    def body(i, carry):
        M, ends, starts = carry
        # the extra piece (i = S) has zero length unless the switch falls inside
        M, k = branch(_needed(i, S, b_S < 1.0),
                      lambda: _piece(variant, p, H0, H1, M0, k0, theta, S, i, M),
                      lambda: (M, k0))
        return M, ends.at[i].set(M), starts.at[i].set(k)

    empty = jnp.zeros((S + 1,), dtype=jnp.result_type(M0))
    _, ends, starts = _repeat(S + 1, body, (M0, empty, empty), loop=True)
    return _assemble(ends, starts, theta, S)


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
    S = substeps
    b_S = _boundary(S, jnp.floor(theta * S), theta, S)

    def body(i, carry):
        M, ends, starts = carry

        def piece():
            M1, k = vm(lambda p, H0, H1, M0, k0, theta, M: _piece(
                variant, p, H0, H1, M0, k0, theta, S, i, M))(p, H0, H1, M0, k0, theta, M)
            needed = _needed(i, S, b_S < 1.0)
            if needed is True:  # (a uniform piece, known while tracing: no select)
                return M1, k
            return jnp.where(needed, M1, M), jnp.where(needed, k, k0)

        # the extra piece (i = S) only where some member's switch falls inside
        M, k = branch(_needed(i, S, jnp.any(b_S < 1.0)), piece, lambda: (M, k0))
        return M, ends.at[:, i].set(M), starts.at[:, i].set(k)

    empty = jnp.zeros((*jnp.shape(M0), S + 1), dtype=jnp.result_type(M0))
    _, ends, starts = _repeat(S + 1, body, (M0, empty, empty), loop=bool(_COMPACT))
    M_points, k_points = vm(lambda e, s, t: _assemble(e, s, t, S))(ends, starts, theta)
    return M_points, k_points
