"""Every name jaxhyst takes from JAX's extension or private API, in one place.

JAX marks these as unstable (``jax.extend``, ``jax._src``) or unsafe (``…_DO_NOT_USE``).
Each is imported here once; where an import fails (a JAX outside the range that
``pyproject.toml`` allows) a fallback keeps jaxhyst correct but slower or less helpful,
and its name is added to `FALLBACKS`. ``tests/test_jax_compat.py`` fails when any
fallback is taken, so a JAX that moves one of them is noticed at once.

- `under_jit` — ``jax.extend.core.unsafe_am_i_under_a_jit_DO_NOT_USE``: send ``grad``,
  ``vmap``… called without jit to the compiled simulation. Fallback: trace inline
  (eager transformations run operation by operation, much slower).
- `under_vmap` — ``jax.extend.core.unsafe_am_i_under_a_vmap_DO_NOT_USE``: run the work
  after the time loop in blocks under a large vmap. Fallback: the blocked form always.
- `concrete_value` — ``jax.extend.core.concrete_or_error``: read parameter values under
  an eager ``grad`` to check them. Fallback: values not read there (no check).
- `jaxpr_as_fun` — ``jax.extend.core.jaxpr_as_fun``: evaluate a time loop traced once.
  Fallback: ``jax.core.jaxpr_as_fun``.
- `backends_are_initialized` — ``jax._src.xla_bridge``: whether the XLA loop flag can
  still take effect. Fallback: assume JAX has not started.
"""

from __future__ import annotations

import jax

#: Names whose fallback is in use (empty on the tested JAX versions).
FALLBACKS: set[str] = set()

try:
    from jax.extend.core import unsafe_am_i_under_a_jit_DO_NOT_USE as _under_jit
except ImportError:  # pragma: no cover - outside the tested range
    _under_jit = None
    FALLBACKS.add("under_jit")

try:
    from jax.extend.core import unsafe_am_i_under_a_vmap_DO_NOT_USE as _under_vmap
except ImportError:  # pragma: no cover - outside the tested range
    _under_vmap = None
    FALLBACKS.add("under_vmap")

try:
    from jax.extend.core import concrete_or_error as _concrete_or_error
except ImportError:  # pragma: no cover - outside the tested range
    _concrete_or_error = None
    FALLBACKS.add("concrete_or_error")

try:
    from jax.extend.core import jaxpr_as_fun
except ImportError:  # pragma: no cover - outside the tested range
    from jax.core import jaxpr_as_fun  # noqa: F401

    FALLBACKS.add("jaxpr_as_fun")


def under_jit() -> bool | None:
    """Whether the current trace is inside ``jax.jit`` (None: cannot tell)."""
    return None if _under_jit is None else bool(_under_jit())


def under_vmap() -> bool:
    """Whether the current trace is inside ``jax.vmap`` (True when it cannot tell: the
    batch-aware form is correct either way)."""
    return True if _under_vmap is None else bool(_under_vmap())


def concrete_value(x):
    """The value of the tracer ``x`` where JAX knows it (a transformation called without
    jit), else None."""
    if _concrete_or_error is None:  # pragma: no cover - outside the tested range
        return None
    try:
        return _concrete_or_error(None, x)
    except jax.errors.ConcretizationTypeError:
        return None


def backends_are_initialized() -> bool:
    """Whether JAX has created its backends (after which XLA_FLAGS is no longer read)."""
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except (ImportError, AttributeError):  # pragma: no cover - outside the tested range
        FALLBACKS.add("backends_are_initialized")
        return False
