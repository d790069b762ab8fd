"""Spreading a batch axis (GA population, replicate data sets) over devices.

With several devices (GPUs, or CPU host devices via
``XLA_FLAGS=--xla_force_host_platform_device_count=N``) a batch whose leading axis is
divisible by the device count is placed with a `jax.sharding.NamedSharding` over a 1-D
mesh; the jitted, vmapped evaluation then runs SPMD, each device computing its share.
Each member's computation is independent, so the result is the same as unsharded (the
tests check it). On one device nothing changes.
"""

from __future__ import annotations

import jax
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


def place(x, sharding):
    """``x`` on its sharding (or unchanged when ``sharding`` is None)."""
    return x if sharding is None else jax.device_put(x, sharding)
