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
- `release_compiled` — ``jax._src.pjit`` (its C++ executable caches and ``_pjit_lower``)
  and ``jax._src.interpreters.pxla._cached_compilation``: drop the compiled programs
  (which hold the memory mappings, `jaxhyst._mappings`) but keep the traced ones, so a
  function called again is lowered and loaded from the persistent cache without being
  traced again. Fallback: ``jax.clear_caches()`` (the traces go too).
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


try:
    from jax._src import pjit as _pjit
    from jax._src.interpreters import pxla as _pxla

    _EXECUTABLE_CACHES = (_pjit._cpp_pjit_cache_fun_only,
                          _pjit._cpp_pjit_cache_explicit_attributes)
    _LOWERINGS = (_pjit._pjit_lower, _pxla._cached_compilation)
    if not all(hasattr(c, "clear") for c in _EXECUTABLE_CACHES) or \
            not all(hasattr(c, "cache_clear") for c in _LOWERINGS) or \
            not hasattr(type(_EXECUTABLE_CACHES[0]), "clear_all"):
        raise AttributeError
except (ImportError, AttributeError):  # pragma: no cover - outside the tested range
    _EXECUTABLE_CACHES = _LOWERINGS = None
    FALLBACKS.add("release_compiled")


def release_compiled() -> None:
    """Drop JAX's compiled programs (every jitted function's executables and the lowerings
    that hold them), keeping the traced programs: a function called again with the same
    shapes is lowered and compiled (or loaded from the persistent cache) but not traced
    again."""
    if _EXECUTABLE_CACHES is None:  # pragma: no cover - outside the tested range
        jax.clear_caches()
        return
    for cache in _EXECUTABLE_CACHES:
        cache.clear()
    type(_EXECUTABLE_CACHES[0]).clear_all()  # (every jitted function's own cache)
    for cache in _LOWERINGS:
        cache.cache_clear()
