"""Spreading a batch axis (GA population, replicate data sets, loops) over devices.

With several devices (GPUs, or CPU host devices via
``XLA_FLAGS=--xla_force_host_platform_device_count=N``) a batch whose leading axis is
divisible by the device count is placed with a `jax.sharding.NamedSharding` over a 1-D
mesh; the jitted, vmapped evaluation then runs SPMD, each device computing its share.
Each member's computation is independent, so the result is the same as unsharded (the
tests check it). On one device nothing changes. For a batch that runs the time loop (a
population), placing it is the slow way: the loop's batch-wide tests (does any member
need the located switch at this interval?) then become cross-device reductions at every
interval, several times slower on two CPU host devices than one (benchmarks/RESULTS.md).
`map_sharded` gives each device its own block and its own tests (the GA evaluates its
populations so).

`vmap_blocked` is ``jax.vmap`` for a large population on the CPU: vectorized over
hundreds of members, a simulation's intermediates (M and its slopes, the forcing, per
member and substep) no longer fit in the caches; run block by block they do (measured in
`benchmarks/RESULTS.md`). A plain ``jax.vmap`` of `simulate_unchecked` gets
part of this by itself: the simulation's work after its time loop runs in blocks under
any large vmap (`jaxhyst.model.simulate`).

`map_sharded` splits a batch axis inside a traced computation instead (`JointProblem`'s
loops axis, so that one local solve uses every device); under an outer ``vmap`` (a GA
population, jacfwd's tangents) the outer axis stays whole on each device.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec


def batch_sharding(n: int, shard: bool | None = None):
    """A sharding of a leading axis of length ``n`` over all devices, or ``None`` when
    there is one device, ``n`` is not divisible by the device count, or ``shard`` is
    False. ``shard=None`` means: shard when possible."""
    devices = jax.devices()
    if shard is False or len(devices) < 2 or n % len(devices):
        if shard is True and len(devices) >= 2:
            raise ValueError(f"Cannot shard a batch of {n} over {len(devices)} devices: "
                             "make it a multiple of the device count.")
        return None
    return NamedSharding(Mesh(np.array(devices), ("batch",)), PartitionSpec("batch"))


def shardable(n: int) -> bool:
    """True when there are several devices and a batch of ``n`` splits evenly over them."""
    count = jax.device_count()
    return count > 1 and n % count == 0


def place(x, sharding):
    """``x`` on its sharding (or unchanged when ``sharding`` is None)."""
    return x if sharding is None else jax.device_put(x, sharding)


def map_sharded(fn, n: int, shard: bool):
    """``fn`` (arguments and results with a leading batch axis of length ``n``) run with
    that axis split over all devices by `jax.shard_map`: each device applies ``fn`` to its
    own block, with no communication inside ``fn`` (rather than leaving the split of a
    time loop to the partitioner). ``fn`` itself when ``shard`` is False."""
    if not shard:
        return fn
    spec = batch_sharding(n, True).spec
    mesh = Mesh(np.array(jax.devices()), ("batch",))
    return jax.shard_map(fn, mesh=mesh, in_specs=spec, out_specs=spec, check_vma=False)


#: Members per vectorized block of a large population on the CPU (`vmap_blocked`).
CPU_BLOCK = 64


def vmap_blocked(fn, n: int, block: int | None = None):
    """``jax.vmap(fn)`` (every argument batched along its leading axis, of length ``n``)
    that, on the CPU and for ``n`` ≥ 4 blocks, runs in blocks of ``block`` members
    (default `CPU_BLOCK`) one after the other (`jax.lax.map` over blocks, the last one
    padded with copies of the last member, whose results are dropped). The values are
    those of ``jax.vmap(fn)`` to round-off (5e-15 relative on a simulation); smaller
    batches, and other backends (a GPU wants the whole batch at once), get
    ``jax.vmap(fn)`` itself."""
    block = CPU_BLOCK if block is None else int(block)
    if block < 1:
        raise ValueError(f"block must be a positive number of members; got {block}.")
    whole = jax.vmap(fn)
    if jax.default_backend() != "cpu" or n < 4 * block:
        return whole
    blocks = -(-n // block)

    def split(x):
        extra = blocks * block - n
        if extra:
            x = jnp.concatenate([x, jnp.repeat(x[-1:], extra, axis=0)])
        return x.reshape(blocks, block, *x.shape[1:])

    def blocked(*args):
        out = jax.lax.map(lambda a: whole(*a), jax.tree.map(split, args))
        return jax.tree.map(lambda y: y.reshape(blocks * block, *y.shape[2:])[:n], out)

    return blocked
