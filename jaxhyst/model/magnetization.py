"""The Jiles–Atherton magnetization path: the only sequential part of the model.

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

**Derivatives.** `magnetization_path` has a custom JVP. The scan is the definition; its
tangent is the linear recurrence dM_{n+1} = a_n·dM_n + r_n, where a_n = ∂M_{n+1}/∂M_n and
r_n = ∂M_{n+1}/∂(θ, H_n, H_{n+1})·(dθ, dH) are partial derivatives of one interval's map,
formed by forward mode in one pass of the time loop (a primal and one tangent per input,
no tangent carried from interval to interval), followed by a scalar scan for the
recurrence. JAX transposes that rule for reverse mode, so `grad` never replays the time
loop's body backwards, and the rule calls `magnetization_path` itself, so higher
derivatives use it again.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from ..params import Parameters
from .jiles_atherton import JAVariant

try:  # public since jax 0.4.3x; jax.core before
    from jax.extend.core import jaxpr_as_fun
except ImportError:  # pragma: no cover
    from jax.core import jaxpr_as_fun


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

    _, total = jax.lax.fori_loop(0, 3, stage, (k1, k1))
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
    switch distance d = δ·(Man − M) between its ends. ``start`` is `JAVariant.evaluate`
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


def _direction_of(H0, H1):
    return jnp.where(H1 >= H0, 1.0, -1.0)


def interval_map(variant: JAVariant, p: Parameters, H0, H1, M0, substeps: int):
    """Advance M over one sample interval from (H0, M0) to H1.

    **Returns:** ``(M_points, k_points)``: M (A/m) at the substep points u_1 … u_S and the
    slope dM/dH (with this interval's direction) at u_0 … u_{S−1}, each shape (S,).
    The located switch and the extra piece are ``lax.cond`` branches, taken only after
    field reversals (`interval_map_batched` is the same map for a batch).
    """
    delta = _direction_of(H0, H1)
    start = variant.evaluate(H0, M0, delta, p)
    k0, d0, _ = start
    theta = jax.lax.cond(d0 <= 0, lambda: _switch_fraction(variant, p, delta, H0, H1, M0, start),
                         lambda: jnp.ones_like(H0))
    ends, starts, b_S = _pieces(variant, p, H0, H1, M0, k0, theta, substeps)
    # the extra piece has zero length unless the switch falls inside this interval
    M_last, k_last = jax.lax.cond(b_S < 1.0,
                                  lambda M: _last_piece(variant, p, H0, H1, M, b_S),
                                  lambda M: (M, k0), ends[-1])
    return _assemble([*ends, M_last], [*starts, k_last], theta, substeps)


def interval_map_batched(variant, p, H0, H1, M0, substeps: int):
    """`interval_map` for a batch (every argument with a leading axis of the same size,
    `Parameters` leaves included), with the rare branches computed only when some member
    needs them: ``jax.vmap`` of `interval_map` would evaluate both sides of each
    ``lax.cond`` for every member at every interval (3–5× the cost)."""
    vm = jax.vmap
    delta = _direction_of(H0, H1)
    start = vm(lambda H, M, d, p: variant.evaluate(H, M, d, p))(H0, M0, delta, p)
    k0, d0, _ = start
    off = d0 <= 0

    def located():
        theta = vm(lambda *a: _switch_fraction(variant, *a))(p, delta, H0, H1, M0, start)
        return jnp.where(off, theta, 1.0)

    theta = jax.lax.cond(jnp.any(off), located, lambda: jnp.ones_like(H0))
    ends, starts, b_S = vm(lambda *a: _pieces(variant, *a, substeps))(p, H0, H1, M0, k0,
                                                                       theta)
    M_last, k_last = jax.lax.cond(
        jnp.any(b_S < 1.0),
        lambda: vm(lambda *a: _last_piece(variant, *a))(p, H0, H1, ends[-1], b_S),
        lambda: (ends[-1], k0))
    M_points, k_points = vm(lambda e, s, t: _assemble(e, s, t, substeps))(
        [*ends, M_last], [*starts, k_last], theta)
    return M_points, k_points


def _direction(H):
    """δ_n = sign(H_{n+1} − H_n) per interval along the first axis (+1 where the field
    stands still)."""
    return jnp.where(H[1:] >= H[:-1], 1.0, -1.0)


def _previous_end_slope(slope, p, H0, M0, delta, delta_prev, k_start):
    """The previous interval's end slope at (H0, M0): this interval's slope at u_0,
    ``k_start``, unless the field reversed here (δ ≠ δ_prev); then one evaluation with
    δ_prev, computed only when some member reversed."""
    same = delta == delta_prev
    return jax.lax.cond(jnp.all(same), lambda: k_start,
                        lambda: jnp.where(same, k_start, slope(H0, M0, delta_prev, p)))


def _time_loop(variant, p, H, substeps: int, batched: bool):
    """The scan over intervals, for one trajectory or (``batched``) for a batch whose
    leading axis every argument carries (H of shape (B, T), p leaves (B,))."""
    step_map = interval_map_batched if batched else interval_map
    slope = jax.vmap(variant.slope) if batched else variant.slope
    H_t = jnp.moveaxis(H, -1, 0)  # time first
    directions = _direction(H_t)

    def step(carry, interval):
        M, delta_prev = carry
        H0, H1, delta = interval
        M_points, k_points = step_map(variant, p, H0, H1, M, substeps)
        k_prev_end = _previous_end_slope(slope, p, H0, M, delta, delta_prev,
                                         k_points[..., 0])
        return (M_points[..., -1], delta), (M_points, k_points, k_prev_end)

    M0 = jnp.zeros(H_t.shape[1:], dtype=H.dtype)
    (M_last, _), (M_sub, k_start, k_prev_end) = jax.lax.scan(
        step, (M0, directions[0]), (H_t[:-1], H_t[1:], directions))
    k_last = slope(H_t[-1], M_last, directions[-1], p)
    k_end = jnp.concatenate([k_prev_end[1:], k_last[None]])
    k_sub = jnp.concatenate([k_start, k_end[..., None]], axis=-1)
    return jnp.moveaxis(M_sub, 0, -2), jnp.moveaxis(k_sub, 0, -2)


_SCANS: dict = {}


def _scan(p, H, variant, substeps):
    """The time loop: (M at substep points (N, S), dM/dH at u_0 … u_S of each interval
    with that interval's direction (N, S + 1)), starting demagnetized (M = 0). Under
    ``jax.vmap`` it runs the batch-native loop (`interval_map_batched`)."""
    if substeps not in _SCANS:
        _SCANS[substeps] = _batch_native(
            lambda variant, p, H, batched: _time_loop(variant, p, H, substeps, batched))
    return _SCANS[substeps](variant, p, H)


#: Traces kept per time loop (one per drive length and dtype in use, each a few MB).
_TRACES_KEPT = 16


def _traced_once(fn):
    """``fn`` evaluated from a jaxpr traced once per structure, shapes and dtypes of its
    arguments (a pytree of arrays), whatever transformation or program calls it. A time
    loop takes seconds to trace; JAX's jit cache would not share the trace between a
    function's primal call and its batching rule, or between the programs of a local
    solve (it also keys on the tracing context)."""
    cache: dict = {}

    def call(*args):
        leaves, treedef = jax.tree.flatten(args)
        key = (treedef, tuple((jnp.shape(x), jnp.result_type(x), _weak(x)) for x in leaves))
        if key not in cache:
            closed, shapes = jax.make_jaxpr(fn, return_shape=True)(*args)
            if len(cache) >= _TRACES_KEPT:
                del cache[next(iter(cache))]  # the oldest
            cache[key] = (jaxpr_as_fun(closed), jax.tree.structure(shapes))
        evaluate, out_tree = cache[key]
        return jax.tree.unflatten(out_tree, evaluate(*leaves))

    return call


def _weak(x) -> bool:
    """Whether x is weakly typed (a Python scalar, or an array or tracer marked so)."""
    if isinstance(x, (bool, int, float, complex)):
        return True
    aval = getattr(x, "aval", None)
    return bool(getattr(x, "weak_type", False) or getattr(aval, "weak_type", False))


def _batch_native(loop):
    """``loop(variant, p, H, batched)`` as a jitted function of (variant, p, H) (each form
    traced once, `_traced_once`) whose ``jax.vmap`` runs
    ``loop(..., batched=True)`` once on the whole batch (unbatched arguments broadcast),
    and a batch of one member the smaller unbatched program (a single-start solve)."""
    unbatched = _traced_once(lambda variant, p, H: loop(variant, p, H, False))
    batched = _traced_once(lambda variant, p, H: loop(variant, p, H, True))

    @jax.custom_batching.custom_vmap
    def single(variant, p, H):
        return unbatched(variant, p, H)

    @single.def_vmap
    def batch(axis_size, in_batched, variant, p, H):
        args, flags = (variant, p, H), tuple(in_batched)
        if not any(jax.tree.leaves(flags)):  # (jvp of the rule asks this too)
            out = unbatched(*args)
            return out, jax.tree.map(lambda _: False, out)
        if axis_size == 1:
            args = jax.tree.map(lambda x, b: x[0] if b else x, args, flags)
            out = jax.tree.map(lambda y: y[None], unbatched(*args))
        else:
            args = jax.tree.map(
                lambda x, b: x if b else jnp.broadcast_to(x, (axis_size, *jnp.shape(x))),
                args, flags)
            out = batched(*args)
        return out, jax.tree.map(lambda _: True, out)

    return jax.jit(single)


def substep_fields(H, substeps: int):
    """The field at the substep points u_0 … u_S of every interval, shape (N, S + 1)."""
    frac = jnp.arange(substeps + 1, dtype=H.dtype) / substeps
    return H[:-1, None] + frac * (H[1:] - H[:-1])[:, None]


@eqx.filter_custom_jvp
def magnetization_path(p: Parameters, H, *, variant: JAVariant, substeps: int):
    """M and dM/dH along a piecewise-linear field H (A/m), shape (T,), from M = 0.

    **Returns:** ``(M_sub, k_sub)``: M (A/m) at the substep points u_1 … u_S of each of the
    N = T − 1 intervals, shape (N, S), and dM/dH (dimensionless) at u_0 … u_S of each
    interval with that interval's field direction, shape (N, S + 1).
    """
    return _scan(p, H, variant, substeps)


def _interval_outputs(variant, p, H0, H1, M0, delta_prev, substeps, batched=False):
    """One interval's outputs as the rule differentiates them: M at u_1 … u_S, the slope
    at u_0 … u_{S−1} (this interval's direction), and the previous interval's end slope:
    the slope at u_0 with the previous direction ``delta_prev`` (the slope at u_0 itself
    unless the field reversed here, so it costs an evaluation only after reversals, as
    in `_time_loop`). Shape (2S + 1,) (or (B, 2S + 1) for a batch)."""
    step_map = interval_map_batched if batched else interval_map
    slope = jax.vmap(variant.slope) if batched else variant.slope
    M_points, k_points = step_map(variant, p, H0, H1, M0, substeps)
    k_prev_end = _previous_end_slope(slope, p, H0, M0, _direction_of(H0, H1), delta_prev,
                                     k_points[..., 0])
    return jnp.concatenate([M_points, k_points, k_prev_end[..., None]], axis=-1)


#: Tangents per SIMD register (four float64 on AVX2).
_LANES = 4


def _lanes(K: int) -> int:
    """Tangent lanes for K tangents of one trajectory: K padded with zero tangents to a
    whole number of SIMD registers where two or three would be left over beyond the
    first register (K = 6, 7: 8), else K itself (measured in benchmarks/RESULTS.md)."""
    return -(-K // _LANES) * _LANES if K > _LANES and K % _LANES >= 2 else K


def _sensitivity_loop(variant, p, H, names, with_H, substeps, batched):
    """The time loop again, now also forming each interval's partial derivatives
    ∂(outputs)/∂(M_n, θ_names, H_n, H_{n+1}) (outputs of `_interval_outputs`) by forward
    mode (one primal and K tangents per interval, inside the loop, which XLA compiles as
    one kernel).

    **Returns:** ``(outputs (..., N, 2S + 1), partials (..., N, 2S + 1, K))`` with K = 1 +
    len(names) + 2·with_H, columns in that order; ``...`` is the batch axis if
    ``batched`` (then every argument carries it)."""
    S = substeps
    K = 1 + len(names) + 2 * with_H
    H_t = jnp.moveaxis(H, -1, 0)
    directions = _direction(H_t)

    def step(carry, interval):
        M, delta_prev = carry
        H0, H1, delta = interval
        z = jnp.stack([M, *[getattr(p, n) for n in names], *((H0, H1) if with_H else ())],
                      axis=-1)

        def outputs(z):
            q = p
            if names:
                q = eqx.tree_at(lambda p: [getattr(p, n) for n in names], p,
                                [z[..., 1 + i] for i in range(len(names))])
            h0, h1 = (z[..., -2], z[..., -1]) if with_H else (H0, H1)
            return _interval_outputs(variant, q, h0, h1, z[..., 0], delta_prev, S, batched)

        # one trajectory: the K tangents are the vector axis, padded with zero tangents
        # to a whole number of SIMD registers (a batch is vectorized over its members)
        lanes = K if batched else _lanes(K)
        eye = jnp.eye(lanes, K, dtype=H.dtype)
        basis = jnp.broadcast_to(eye[:, None, :], (lanes, *z.shape)) if batched else eye
        out, partials = jax.vmap(lambda t: jax.jvp(outputs, (z,), (t,)),
                                 out_axes=(None, -1))(basis)
        partials = partials[..., :K]
        return (out[..., S - 1], delta), (out, partials)

    M0 = jnp.zeros(H_t.shape[1:], dtype=H.dtype)
    _, (out, partials) = jax.lax.scan(step, (M0, directions[0]),
                                      (H_t[:-1], H_t[1:], directions))
    return jnp.moveaxis(out, 0, -2), jnp.moveaxis(partials, 0, -3)


_SENSITIVITY: dict = {}


def _sensitivity_scan(variant, p, H, names, with_H, substeps):
    """`_sensitivity_loop` for one trajectory, batch-native under ``jax.vmap``."""
    key = (names, with_H, substeps)
    if key not in _SENSITIVITY:
        _SENSITIVITY[key] = _batch_native(
            lambda variant, p, H, batched: _sensitivity_loop(variant, p, H, names, with_H,
                                                             substeps, batched))
    return _SENSITIVITY[key](variant, p, H)


def _Ms_column(p, out, column_M, column_alpha, substeps):
    """∂(outputs)/∂Ms of each interval, shape (N, 2S + 1), for a variant with
    ``scales_with_Ms``: every output is Ms·ψ(M_n/Ms, α̃·Ms, …) of the interval's start
    M_n, so ∂/∂Ms = (output − M_n·∂/∂M_n + α̃·∂/∂α̃)/Ms."""
    M_start = jnp.concatenate([jnp.zeros_like(out[:1, substeps - 1]),
                               out[:-1, substeps - 1]])
    return (out - M_start[:, None] * column_M + p.alpha * column_alpha) / p.Ms


@magnetization_path.def_jvp
def _magnetization_path_jvp(primals, tangents, *, variant, substeps):
    p, H = primals
    p_dot, H_dot = tangents
    S = substeps
    names = tuple(n for n in variant.parameters
                  if p_dot is not None and getattr(p_dot, n) is not None)
    with_H = H_dot is not None
    if not names and not with_H:
        return magnetization_path(p, H, variant=variant, substeps=substeps), (None, None)
    # with the Ms–α̃ symmetry, ∂/∂Ms is formed from ∂/∂α̃ (one tangent fewer in the loop)
    by_symmetry = variant.scales_with_Ms and "Ms" in names
    wanted = (set(names) - {"Ms"}) | {"alpha"} if by_symmetry else set(names)
    looped = tuple(n for n in variant.parameters if n in wanted)
    out, partials = _sensitivity_scan(variant, p, H, looped, with_H, S)
    column = {n: partials[..., 1 + i] for i, n in enumerate(looped)}
    if by_symmetry:
        column["Ms"] = _Ms_column(p, out, partials[..., 0], column["alpha"], S)
    # r = (partials of the inputs other than M_n) · (their tangents), per interval
    r = sum(column[n] * getattr(p_dot, n) for n in names)
    if with_H:
        r = r + partials[..., -2] * H_dot[:-1, None] + partials[..., -1] * H_dot[1:, None]
    a = partials[..., 0]

    def recurrence(dM, ar):
        a_n, r_n = ar
        return a_n * dM + r_n, dM

    _, dM_start = jax.lax.scan(recurrence, jnp.zeros_like(r[0, S - 1]),
                               (a[:, S - 1], r[:, S - 1]))
    d_out = a * dM_start[:, None] + r
    # end slopes: the loop forms interval n's in interval n + 1 (last column), which
    # leaves the last interval's, formed here with its tangent
    delta_last = _direction_of(H[-2], H[-1])

    def last_slope(M_T, values, H_T):
        q = eqx.tree_at(lambda p: [getattr(p, n) for n in names], p, list(values)) \
            if names else p
        return variant.slope(H_T, M_T, delta_last, q)

    k_last, dk_last = jax.jvp(
        last_slope, (out[-1, S - 1], [getattr(p, n) for n in names], H[-1]),
        (d_out[-1, S - 1], [getattr(p_dot, n) for n in names],
         H_dot[-1] if with_H else jnp.zeros_like(H[-1])))

    def slopes(o, last):  # (N, S + 1): u_0 … u_{S−1} of each interval, then its end
        ends = jnp.concatenate([o[1:, 2 * S], last[None]])
        return jnp.concatenate([o[:, S:2 * S], ends[:, None]], axis=1)

    primal = (out[:, :S], slopes(out, k_last))
    return primal, (d_out[:, :S], slopes(d_out, dk_last))
