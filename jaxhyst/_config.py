"""Process-wide JAX settings that jaxhyst needs, applied once on import.

- float64 everywhere: the parameters span 1e-3 … 1e10 and the identification reaches
  costs of 1e-25, neither of which survives float32.
- JAX's persistent compilation cache, so that a later process's first call of a jitted
  simulation or solver is loaded from disk instead of recompiled (compiles take seconds).
  The cache lives in ``$JAXHYST_CACHE_DIR`` if set, else ``$XDG_CACHE_HOME/jaxhyst/xla``,
  else ``~/.cache/jaxhyst/xla``. Set ``JAXHYST_CACHE_DIR=off`` to leave JAX's cache
  setting untouched (e.g. when your application manages it). If the user already set
  ``jax_compilation_cache_dir`` themselves, it is respected.
"""

from __future__ import annotations

import os
from pathlib import Path

import jax

jax.config.update("jax_enable_x64", True)


def cache_dir() -> Path | None:
    """The directory used for JAX's persistent compilation cache, or None when disabled."""
    env = os.environ.get("JAXHYST_CACHE_DIR")
    if env is not None:
        if env.strip().lower() in ("", "0", "off", "none", "false"):
            return None
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jaxhyst" / "xla"


def _enable_compilation_cache() -> None:
    directory = cache_dir()
    if directory is None or jax.config.jax_compilation_cache_dir:
        return
    try:
        directory.mkdir(parents=True, exist_ok=True)
    except OSError:  # read-only home etc.: run without a cache rather than fail
        return
    jax.config.update("jax_compilation_cache_dir", str(directory))
    # Cache even small/fast compilations: our scans compile in ~1-30 s each.
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.5)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)


_enable_compilation_cache()
