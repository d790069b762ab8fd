"""The JAX batching machinery of the time loops, apart from the physics.

A time loop takes seconds to trace. `batch_native` turns a loop written for one
trajectory *and* for a batch (``loop(*args, batched)``) into one jitted function
whose ``jax.vmap`` runs the batch-native form once on the whole batch (a ``custom_vmap``),
each form traced once per structure and shapes (`traced_once`) whatever transformation or
program calls it. `blocked_under_vmap` runs the work after the loop in blocks under a
large ``jax.vmap``.
"""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp

from .._jax_compat import jaxpr_as_fun
from ..sharding import vmap_blocked

#: Traces kept per time loop (one per drive length and dtype in use, each a few MB).
_TRACES_KEPT = 16


def traced_once(fn):
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
    return bool(jax.typeof(x).weak_type)


def batch_native(loop):
    """``loop(*args, batched)`` as a jitted function of ``args`` (each form traced once,
    `traced_once`) whose ``jax.vmap`` runs ``loop(*args, batched=True)`` once on the whole
    batch (unbatched arguments broadcast, so every array argument then carries the batch
    axis first), and a batch of one member the smaller unbatched program (a
    single-start solve)."""
    unbatched = traced_once(lambda *args: loop(*args, False))
    batched = _merging(traced_once(lambda *args: loop(*args, True)))

    @jax.custom_batching.custom_vmap
    def single(*args):
        return unbatched(*args)

    @single.def_vmap
    def batch(axis_size, in_batched, *args):
        flags = tuple(in_batched)
        if not any(jax.tree.leaves(flags)):  # (jvp of the rule asks this too)
            return _as_unbatched(unbatched(*args))
        if axis_size == 1:
            args = jax.tree.map(lambda x, b: x[0] if b else x, args, flags)
            return _as_batched(jax.tree.map(lambda y: y[None], unbatched(*args)))
        return _as_batched(batched(*_broadcast(args, flags, axis_size)))

    return jax.jit(single)


def _merging(batched):
    """``batched`` (a function of arguments that all carry one batch axis first) whose
    ``jax.vmap`` merges the new batch axis into that one: nested vmaps (starts × loops of
    a joint fit) run one batch-native loop on the product batch, not JAX's generic
    batching of the batched loop (its branches both taken, its loops' conditions
    batched: slower to compile and to run). Depth does not matter: the merged call is
    itself merged by a further vmap."""

    @jax.custom_batching.custom_vmap
    def merged(*args):
        return batched(*args)

    @merged.def_vmap
    def again(axis_size, in_batched, *args):
        flags = tuple(in_batched)
        if not any(jax.tree.leaves(flags)):  # (jvp of the rule asks this too)
            return _as_unbatched(merged(*args))
        args = _broadcast(args, flags, axis_size)
        out = merged(*jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), args))
        return _as_batched(jax.tree.map(lambda y: y.reshape(axis_size, -1, *y.shape[1:]),
                                        out))

    return merged


def _broadcast(args, flags, axis_size):
    """``args`` with every leaf that ``flags`` marks unbatched broadcast to carry the
    batch axis (of ``axis_size``) first, as the batched ones do."""
    return jax.tree.map(
        lambda x, b: x if b else jnp.broadcast_to(x, (axis_size, *jnp.shape(x))),
        args, flags)


def _as_unbatched(out):
    """A batch rule's answer: ``out`` with no batch axis."""
    return out, jax.tree.map(lambda _: False, out)


def _as_batched(out):
    """A batch rule's answer: every leaf of ``out`` with the batch axis first."""
    return out, jax.tree.map(lambda _: True, out)


def _splice(leaves, positions, values):
    """``leaves`` with the entries at ``positions`` replaced by ``values``."""
    leaves = list(leaves)
    for i, value in zip(positions, values, strict=True):
        leaves[i] = value
    return leaves


_BLOCKED: dict = {}


def blocked_under_vmap(fn, **static):
    """``fn(*args, **static)`` as a function of ``args`` whose ``jax.vmap`` runs in
    blocks (`jaxhyst.sharding.vmap_blocked`: a batch of hundreds on the CPU, 64 members
    at a time, so that its intermediates fit the caches; other batches and backends as
    ``jax.vmap`` would). Its derivatives are ``fn``'s own: JAX does not differentiate a
    custom batching rule in reverse mode, so the rule stays out of every derivative.
    One wrapper per ``fn`` and value of ``static``."""
    key = (fn, tuple(sorted(static.items())))
    if key in _BLOCKED:
        return _BLOCKED[key]

    def call(*args):
        return fn(*args, **static)

    @jax.custom_batching.custom_vmap
    def single(*args):
        return call(*args)

    @single.def_vmap
    def batch(axis_size, in_batched, *args):
        leaves, tree = jax.tree.flatten(args)
        flags = jax.tree.leaves(in_batched)
        batched = [i for i, b in enumerate(flags) if b]
        if not batched:  # (jvp of the rule asks this too)
            return _as_unbatched(call(*args))

        def one(*values):
            return call(*jax.tree.unflatten(tree, _splice(leaves, batched, values)))

        return _as_batched(vmap_blocked(one, axis_size)(*[leaves[i] for i in batched]))

    @eqx.filter_custom_jvp
    def blocked(args):
        return single(*args)

    @blocked.def_jvp
    def blocked_jvp(primals, tangents):
        (args,), (dots,) = primals, tangents
        leaves, tree = jax.tree.flatten(args, is_leaf=lambda x: x is None)
        dots = jax.tree.leaves(dots, is_leaf=lambda x: x is None)  # (None: no tangent)
        moving = [i for i, d in enumerate(dots) if d is not None]
        if not moving:
            out = blocked(args)
            return out, jax.tree.map(lambda _: None, out)

        def moved(*values):
            return call(*jax.tree.unflatten(tree, _splice(leaves, moving, values)))

        return jax.jvp(moved, [leaves[i] for i in moving], [dots[i] for i in moving])

    _BLOCKED[key] = lambda *args: blocked(args)
    return _BLOCKED[key]
