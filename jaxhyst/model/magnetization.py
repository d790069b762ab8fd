"""The Jiles–Atherton magnetization path: the only sequential part of the model.

The time loop (`magnetization_path`) is a ``lax.scan`` over sample intervals, each
advanced by `jaxhyst.model.interval.interval_map` (RK4 in H, the δM switch located).

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
from ._batching import batch_native
from .interval import branch, direction_of, interval_map, interval_map_batched, on_accelerator
from .jiles_atherton import AbstractJAVariant


def _direction(H):
    """δ_n = sign(H_{n+1} − H_n) per interval along the first axis (+1 where the field
    stands still)."""
    return jnp.where(H[1:] >= H[:-1], 1.0, -1.0)


def _previous_end_slope(slope, p, H0, M0, delta, delta_prev, k_start):
    """The previous interval's end slope at (H0, M0): this interval's slope at u_0,
    ``k_start``, unless the field reversed here (δ ≠ δ_prev); then one evaluation with
    δ_prev, computed only when some member reversed."""
    same = delta == delta_prev
    return branch(jnp.all(same), lambda: k_start,
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
        _SCANS[substeps] = batch_native(
            lambda variant, p, H, batched: _time_loop(variant, p, H, substeps, batched))
    return _SCANS[substeps](variant, p, H)


@eqx.filter_custom_jvp
def magnetization_path(p: Parameters, H, *, variant: AbstractJAVariant, substeps: int):
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
    k_prev_end = _previous_end_slope(slope, p, H0, M0, direction_of(H0, H1), delta_prev,
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
        _SENSITIVITY[key] = batch_native(
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
                               (a[:, S - 1], r[:, S - 1]), unroll=8 if on_accelerator() else 1)
    d_out = a * dM_start[:, None] + r
    # end slopes: the loop forms interval n's in interval n + 1 (last column), which
    # leaves the last interval's, formed here with its tangent
    delta_last = direction_of(H[-2], H[-1])

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
