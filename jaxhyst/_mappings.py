"""Compiled programs and the kernel's limit on memory mappings.

XLA:CPU maps the code of every compiled program into memory in many small regions: a
time loop's program takes about 360 of them, and they stay mapped while the program is
cached, i.e. for the life of the process. Linux limits a process to
``vm.max_map_count`` mappings (65 530 by default); a process that compiles a few hundred
distinct programs (a long test session, a batch of fits of different lengths, a study
over many shapes) reaches it, and XLA then aborts the whole process inside a compilation
— "Fatal Python error: Aborted", no Python exception to catch.

`release_if_crowded` is called between units of work that may each compile (the items
of `jaxhyst.batch`, the tests): where more than half of the limit is in use it drops
JAX's compiled programs (`jaxhyst._jax_compat.release_compiled`), which unmaps them, and
keeps the traced ones: a program needed again is lowered and recompiled (or loaded from
the persistent cache) without being traced again. Elsewhere than Linux, or where the
counts cannot be read, it does nothing.
"""

from __future__ import annotations

import gc

#: The share of ``vm.max_map_count`` above which compiled programs are released.
SHARE = 0.5


def _limit() -> int | None:
    try:
        with open("/proc/sys/vm/max_map_count", encoding="ascii") as fh:
            return int(fh.read().strip())
    except (OSError, ValueError):
        return None


def mappings_in_use() -> int | None:
    """The number of memory mappings of this process (Linux), else None."""
    try:
        with open("/proc/self/maps", "rb") as fh:
            return sum(1 for _ in fh)
    except OSError:
        return None


def release_if_crowded(share: float = SHARE) -> bool:
    """Drop JAX's compiled programs where this process uses more than ``share`` of its
    mapping limit; returns whether it did."""
    limit, used = _limit(), mappings_in_use()
    if limit is None or used is None or used <= share * limit:
        return False
    from ._jax_compat import release_compiled

    release_compiled()
    gc.collect()
    return True
