"""The time loop: one skeleton that every model form runs in.

A model form (`AbstractPathForm`) says what is carried from sample to sample (its
**state**, a vector of ``state_size`` numbers) and how one sample interval maps it
(``interval``: a row of outputs, some of which are the next state). `run_path` is the
rest, once for every form:

- **the loop**: a ``lax.scan`` over the intervals of the drive (t, H), from the form's
  initial state;
- **its derivative rule** (a custom JVP): each interval's partial derivatives of its
  outputs with respect to the state at its start, the parameters the form names and the
  drive at its two ends are formed by forward mode in one pass of the loop (a primal and
  one tangent per input, no tangent carried from interval to interval); the tangents of
  the outputs then follow the linear recurrence ds_{n+1} = A_n·ds_n + r_n in the state
  (A_n = ∂s_{n+1}/∂s_n, r_n the other inputs' partials times their tangents). JAX
  transposes that rule for reverse mode, so ``grad`` never replays the loop's body
  backwards; the rule calls `run_path` itself, so higher derivatives use it again;
- **its batch rule** (`jaxhyst.model._batching.batch_native`): under ``jax.vmap`` the
  whole batch runs in one loop, with the form's batched interval (rare branches taken
  only where a member needs them), and each loop is traced once per structure;
- **its accelerator form**: on a GPU or TPU (`jaxhyst.model.interval.on_accelerator`)
  the recurrences are unrolled and the forms select between branches instead of
  branching.

The parameters are a pytree ``theta`` of Modules with named scalar fields (`Parameters`;
``(Parameters, Losses)``; any form's own): the rule differentiates with respect to the
fields the form names in ``parameters`` only. Times are data and are not differentiated.
"""

from __future__ import annotations

import abc
from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp

from ._batching import batch_native
from .interval import compact, on_accelerator


class Interval(NamedTuple):
    """The inputs of one sample interval (or of all, stacked along a leading time axis):
    the drive at its start and end ``H0``, ``H1``, its duration ``dt`` (s; None for a
    drive without times), its direction ``delta`` = sign(H1 − H0) (+1 where the drive
    stands still) and the previous interval's ``delta_prev`` (its own for the first)."""

    H0: jax.Array
    H1: jax.Array
    dt: jax.Array | None
    delta: jax.Array
    delta_prev: jax.Array


class AbstractPathForm(eqx.Module):
    """A model form as the time loop runs it (abstract).

    - ``state_size``: the number of entries of the state (a property or a field).
    - ``parameters``: names of the fields of ``theta`` the intervals depend on (class
      constant or property); the derivative rule differentiates with respect to those.
    - ``scales_with_Ms``: True only if every output and every state entry is Ms times a
      function of (state/Ms, α̃·Ms, the rest) (the rule then forms ∂/∂Ms from ∂/∂α̃).
    - ``initial_state(theta, H0)``: the state at the first sample, shape (state_size,)
      (or (B, state_size) for a batch); it may depend on the drive's first value, not on
      the parameters.
    - ``interval(theta, x, state, substeps, batched)``: the outputs of one interval (an
      `Interval` ``x``) from ``state``, shape (O,) (or (B, O) for a batch when
      ``batched``: every argument then carries the leading batch axis).
    - ``state_rows(substeps)``: the indices of the outputs that are the next state.
    """

    @property
    @abc.abstractmethod
    def scales_with_Ms(self) -> bool:
        """Whether ∂/∂Ms may be formed from ∂/∂α̃ (see the class)."""

    @property
    @abc.abstractmethod
    def state_size(self) -> int:
        """Entries of the state."""

    @property
    @abc.abstractmethod
    def parameters(self) -> tuple[str, ...]:
        """Names of the fields of theta the intervals depend on."""

    @abc.abstractmethod
    def initial_state(self, theta, H0):
        """The state at the first sample (shape (state_size,), or batched)."""

    @abc.abstractmethod
    def interval(self, theta, x: Interval, state, substeps: int, batched: bool):
        """One interval's outputs (shape (O,), or (B, O) when batched)."""

    @abc.abstractmethod
    def state_rows(self, substeps: int) -> tuple[int, ...]:
        """Indices of the outputs that form the next state."""


# -- named fields of a parameter pytree ------------------------------------------------------
def _members(theta) -> tuple:
    """The Modules of a parameter pytree (nested tuples flattened)."""
    if isinstance(theta, tuple):
        return tuple(m for member in theta for m in _members(member))
    return (theta,)


def field_of(theta, name: str):
    """The field ``name`` of the parameter pytree ``theta`` (a Module or a tuple of
    Modules with named fields); None if none has it."""
    for member in _members(theta):
        if member is not None and name in getattr(type(member), "__dataclass_fields__", {}):
            return getattr(member, name)
    return None


def with_fields(theta, values: dict):
    """``theta`` with the named fields replaced by ``values`` ({name: array})."""
    if not values:
        return theta
    names = list(values)
    return eqx.tree_at(lambda q: [field_of(q, n) for n in names], theta,
                       [values[n] for n in names])


# -- the loop ------------------------------------------------------------------------------
def intervals(t, H) -> Interval:
    """The `Interval` inputs of a drive (t may be None), time first: H of shape (..., T)
    gives fields of shape (T − 1, ...)."""
    H_t = jnp.moveaxis(H, -1, 0)
    delta = jnp.where(H_t[1:] >= H_t[:-1], 1.0, -1.0)
    dt = None if t is None else jnp.diff(jnp.moveaxis(t, -1, 0), axis=0)
    return Interval(H_t[:-1], H_t[1:], dt, delta, jnp.concatenate([delta[:1], delta[:-1]]))


def _loop(form, theta, t, H, substeps: int, batched: bool):
    """The scan over intervals: every interval's outputs, shape (..., N, O)."""
    xs = intervals(t, H)
    rows = jnp.asarray(form.state_rows(substeps))

    def step(state, x):
        out = form.interval(theta, x, state, substeps, batched)
        return out[..., rows], out

    _, out = jax.lax.scan(step, form.initial_state(theta, xs.H0[0]), xs)
    return jnp.moveaxis(out, 0, -2)


#: Tangents per SIMD register (four float64 on AVX2).
_LANES = 4


def _lanes(K: int) -> int:
    """Tangent lanes for K tangents of one trajectory: K padded with zero tangents to a
    whole number of SIMD registers where two or three would be left over beyond the
    first register (K = 6, 7: 8), else K itself (measured in benchmarks/RESULTS.md)."""
    return -(-K // _LANES) * _LANES if K > _LANES and K % _LANES >= 2 else K


def _sensitivity_loop(form, theta, t, H, substeps, names, with_H, batched):
    """The loop again, now also forming each interval's partial derivatives of its
    outputs with respect to (state at its start, the fields ``names``, H0, H1) by forward
    mode (one primal and K tangents per interval, inside the loop, which XLA compiles as
    one kernel). Returns ``(outputs (..., N, O), partials (..., N, O, K))`` with
    K = state_size + len(names) + 2·with_H, columns in that order."""
    xs = intervals(t, H)
    rows = jnp.asarray(form.state_rows(substeps))
    n_s = form.state_size
    K = n_s + len(names) + 2 * with_H

    def step(state, x):
        z = jnp.concatenate([state, jnp.stack([*[field_of(theta, n) for n in names],
                                               *((x.H0, x.H1) if with_H else ())],
                                              axis=-1)], axis=-1)

        def outputs(z):
            q = with_fields(theta, {n: z[..., n_s + i] for i, n in enumerate(names)})
            y = x._replace(H0=z[..., -2], H1=z[..., -1]) if with_H else x
            return form.interval(q, y, z[..., :n_s], substeps, batched)

        # one trajectory: the K tangents are the vector axis, padded with zero tangents
        # to a whole number of SIMD registers (a batch is vectorized over its members)
        lanes = K if batched else _lanes(K)
        eye = jnp.eye(lanes, K, dtype=H.dtype)
        basis = jnp.broadcast_to(eye[:, None, :], (lanes, *z.shape)) if batched else eye
        out, partials = jax.vmap(lambda v: jax.jvp(outputs, (z,), (v,)),
                                 out_axes=(None, -1))(basis)
        return out[..., rows], (out, partials[..., :K])

    with compact():  # (the interval's code, times K tangents: compact code compiles faster)
        _, (out, partials) = jax.lax.scan(step, form.initial_state(theta, xs.H0[0]), xs)
    return jnp.moveaxis(out, 0, -2), jnp.moveaxis(partials, 0, -3)


_LOOPS: dict = {}


def _compiled(kind: str, key: tuple, build):
    """The batch-native, traced-once form of a loop, one per kind and static key."""
    if (kind, key) not in _LOOPS:
        _LOOPS[kind, key] = batch_native(build)
    return _LOOPS[kind, key]


def _values(form, theta, t, H, substeps):
    return _compiled("values", (substeps,), lambda form, theta, t, H, batched: _loop(
        form, theta, t, H, substeps, batched))(form, theta, t, H)


def _sensitivities(form, theta, t, H, substeps, names, with_H):
    return _compiled("partials", (substeps, names, with_H),
                     lambda form, theta, t, H, batched: _sensitivity_loop(
                         form, theta, t, H, substeps, names, with_H, batched))(
        form, theta, t, H)


@eqx.filter_custom_jvp
def run_path(theta, t, H, *, form: AbstractPathForm, substeps: int):
    """The outputs of every interval of the drive (``t`` in s or None, ``H`` the drive,
    shape (T,)) from the form's initial state: shape (T − 1, O). Differentiable with
    respect to ``theta`` (the fields the form names) and ``H`` (module docstring); batched
    under ``jax.vmap`` by the batch-native loop."""
    return _values(form, theta, t, H, substeps)


def _recurrence(A, r, ds0):
    """ds_{n+1} = A_n·ds_n + r_n from ds0: the state tangents at each interval's start,
    shape (N, n_s). A (N, n_s, n_s), r (N, n_s)."""
    unroll = 8 if on_accelerator() else 1
    if A.shape[-1] == 1:  # (a scalar recurrence)
        def scalar(ds, ar):
            a_n, r_n = ar
            return a_n * ds + r_n, ds

        _, ds = jax.lax.scan(scalar, ds0[0], (A[:, 0, 0], r[:, 0]), unroll=unroll)
        return ds[:, None]

    def vector(ds, ar):
        A_n, r_n = ar
        return A_n @ ds + r_n, ds

    _, ds = jax.lax.scan(vector, ds0, (A, r), unroll=unroll)
    return ds


@run_path.def_jvp
def _run_path_jvp(primals, tangents, *, form, substeps):
    theta, t, H = primals
    theta_dot, _, H_dot = tangents  # (times are data: not differentiated)
    dots = {n: field_of(theta_dot, n) for n in form.parameters} if theta_dot is not None \
        else {}
    names = tuple(n for n in form.parameters if dots.get(n) is not None)
    with_H = H_dot is not None
    if not names and not with_H:
        return run_path(theta, t, H, form=form, substeps=substeps), None
    n_s = form.state_size
    # with the Ms–α̃ symmetry, ∂/∂Ms is formed from ∂/∂α̃ (one tangent fewer in the loop)
    by_symmetry = form.scales_with_Ms and "Ms" in names
    wanted = (set(names) - {"Ms"}) | {"alpha"} if by_symmetry else set(names)
    looped = tuple(n for n in form.parameters if n in wanted)
    out, partials = _sensitivities(form, theta, t, H, substeps, looped, with_H)
    column = {n: partials[..., n_s + i] for i, n in enumerate(looped)}
    rows = jnp.asarray(form.state_rows(substeps))
    s0 = form.initial_state(theta, H[0])
    starts = jnp.concatenate([s0[None], out[:-1][:, rows]])  # the state at each start
    if by_symmetry:  # every output is Ms·ψ(state/Ms, α̃·Ms, …)
        scaled = out - sum(starts[:, j, None] * partials[..., j] for j in range(n_s))
        column["Ms"] = (scaled + field_of(theta, "alpha") * column["alpha"]) / \
            field_of(theta, "Ms")
    # r = (partials of the inputs other than the state) · (their tangents), per interval
    r = sum(column[n] * dots[n] for n in names)
    if with_H:
        r = r + partials[..., -2] * H_dot[:-1, None] + partials[..., -1] * H_dot[1:, None]
    ds0 = jax.jvp(lambda h: form.initial_state(theta, h), (H[0],),
                  (H_dot[0] if with_H else jnp.zeros_like(H[0]),))[1]
    ds_start = _recurrence(partials[:, rows][:, :, :n_s], r[:, rows], ds0)
    if n_s == 1:
        d_out = partials[..., 0] * ds_start + r
    else:
        d_out = jnp.einsum("nok,nk->no", partials[..., :n_s], ds_start) + r
    return out, d_out


def run_path_plain(theta, t, H, *, form: AbstractPathForm, substeps: int):
    """`run_path` without its derivative rule and batch rule: the same scan as JAX
    differentiates and batches it by itself — the reference that the tests and
    benchmarks compare the rule with (slow to compile and to differentiate)."""
    return _loop(form, theta, t, H, int(substeps), False)


def clear_traces() -> None:
    """Forget the loops traced so far (they are kept per structure and shapes): the next
    call traces them again, e.g. after `jaxhyst.model.interval.FORCE_BRANCH_FREE`
    changed."""
    _LOOPS.clear()
