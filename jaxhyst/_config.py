"""Process-wide JAX settings that jaxhyst needs, applied once on import — and the ones it
offers but does not impose.

Applied on import (``import jaxhyst`` itself does not import JAX):

- **float64** (``jax_enable_x64``, through ``JAX_ENABLE_X64=1`` while JAX is not yet
  imported): the parameters span 1e-3 … 1e10 and identification reaches normalised
  costs of 1e-25, neither of which survives float32.
- **Time loops compiled as one kernel on the CPU.** XLA:CPU runs a loop body as a
  sequence of kernels, each with its own dispatch cost, unless the loop is "small",
  which it then compiles into a single function (its `SmallWhileLoopHoistingPass`). The
  default size limit (1 KiB of memory traffic per iteration) leaves out the
  Jiles–Atherton time loop, which then runs several times slower. jaxhyst raises the
  limit to 4 MiB (a single trajectory's loop and a population of ~100 fit under it) by
  adding
  ``--xla_backend_extra_options=xla_cpu_small_while_loop_byte_threshold=4194304`` to
  ``XLA_FLAGS``. This can only take effect before JAX creates its CPU backend (the first
  computation of the process), affects only CPU loops whose iterations touch less than
  4 MiB, and is skipped when ``XLA_FLAGS`` already sets ``xla_backend_extra_options`` or
  ``JAXHYST_XLA_FLAGS=off``. `cpu_loop_kernels` says whether it is in effect; where it
  cannot be applied (JAX already computing, or XLA_FLAGS setting other backend options)
  a `PerformanceWarning` says so once, at import.
- **XLA:CPU's earlier kernel emitters** (``--xla_cpu_use_fusion_emitters=false`` in
  ``XLA_FLAGS``): XLA:CPU emits each fused kernel either through MLIR (its "fusion
  emitters", the default of jaxlib 0.10) or through its earlier LLVM emitters. On a fit's
  step, ~190 kernels, the MLIR path costs most of the compilation; with the earlier
  emitters the programs of a fit, ``compensate`` and ``simulate`` compile in about
  30–40 % less time, for the same values (to rounding), and run 0–16 % slower (a
  population of 120 by ~6 %; `benchmarks/RESULTS.md`, issue 45). Applied under the
  same conditions as the loop setting, and independently of it: not where ``XLA_FLAGS``
  names ``xla_cpu_use_fusion_emitters`` itself (``=true`` keeps XLA's default) or
  ``JAXHYST_XLA_FLAGS=off``; `cpu_kernel_emitters` says whether it is in effect. Where
  JAX already runs, the loop setting's warning covers both.

Warned about at import: ``XLA_FLAGS`` compiling at LLVM ``-O0``
(``xla_backend_optimization_level=0``), where the pinning-cell forms compute wrong paths
on the CPU.

Offered, not imposed: JAX's persistent compilation cache (`enable_compilation_cache`),
which the ``jaxhyst`` command turns on.
"""

from __future__ import annotations

import os
import re
import sys
import warnings
from pathlib import Path

LOOP_THRESHOLD_BYTES = 4194304
_LOOP_OPTION = f"xla_cpu_small_while_loop_byte_threshold={LOOP_THRESHOLD_BYTES}"
_loop_flag_state = "not applied"
#: XLA:CPU's earlier (LLVM) kernel emitters instead of its MLIR fusion emitters: the
#: flag jaxlib 0.10 knows (pyproject pins jax < 0.11; a later jaxlib may drop it).
EMITTER_FLAG = "--xla_cpu_use_fusion_emitters=false"
_emitter_flag_state = "not applied"


def _enable_x64() -> None:
    """float64 for every JAX computation of the process: through the environment while
    JAX is not imported yet (so that importing jaxhyst does not import JAX), else
    through JAX's config."""
    if "jax" in sys.modules:
        import jax

        jax.config.update("jax_enable_x64", True)
    else:
        os.environ["JAX_ENABLE_X64"] = "1"


def _backends_initialized() -> bool:
    """Whether JAX has created its backends already (then XLA_FLAGS is not read again)."""
    if "jax" not in sys.modules:
        return False
    from ._jax_compat import backends_are_initialized

    return backends_are_initialized()


class PerformanceWarning(RuntimeWarning):
    """jaxhyst's CPU loop setting could not be applied: simulations run several times
    slower on the CPU (see `jaxhyst._config`)."""


def _flags_off() -> bool:
    """Whether the user turned jaxhyst's XLA flags off (``JAXHYST_XLA_FLAGS=off``)."""
    return os.environ.get("JAXHYST_XLA_FLAGS", "").strip().lower() in ("off", "0", "false",
                                                                        "no")


def _apply_loop_flag() -> None:
    """Add jaxhyst's loop option to XLA_FLAGS if JAX has not started; warn once (a
    `PerformanceWarning`) where it cannot take effect and the user did not turn it off."""
    global _loop_flag_state
    if _flags_off():
        _loop_flag_state = "disabled by JAXHYST_XLA_FLAGS"
        return
    flags = os.environ.get("XLA_FLAGS", "")
    fix = (f"set XLA_FLAGS=--xla_backend_extra_options={_LOOP_OPTION} before starting "
           "Python (JAXHYST_XLA_FLAGS=off silences this)")
    if "xla_backend_extra_options" in flags:
        if _LOOP_OPTION.split("=")[0] in flags:
            _loop_flag_state = "in effect (set by the user)"
            return
        _loop_flag_state = "not applied: XLA_FLAGS sets xla_backend_extra_options"
        warnings.warn("jaxhyst's CPU loop setting was not applied because XLA_FLAGS already "
                      "sets xla_backend_extra_options, so simulations run several times "
                      f"slower on the CPU; add {_LOOP_OPTION} to those options, or {fix}.",
                      PerformanceWarning, stacklevel=3)
        return
    if _backends_initialized():
        _loop_flag_state = "not applied: JAX was already running when jaxhyst was imported"
        both = (f"set XLA_FLAGS='--xla_backend_extra_options={_LOOP_OPTION} {EMITTER_FLAG}' "
                "before starting Python (JAXHYST_XLA_FLAGS=off silences this)")
        warnings.warn("jaxhyst was imported after JAX started computing, so its CPU loop "
                      "and emitter settings could not be applied: simulations run several "
                      "times slower on the CPU and compile ~40 % slower; import jaxhyst "
                      f"before the first JAX computation, or {both}.", PerformanceWarning,
                      stacklevel=3)
        return
    os.environ["XLA_FLAGS"] = (flags + " --xla_backend_extra_options=" + _LOOP_OPTION).strip()
    _loop_flag_state = "in effect"


def _apply_emitter_flag() -> None:
    """Add `EMITTER_FLAG` to XLA_FLAGS if JAX has not started, the user has not turned
    jaxhyst's flags off, and XLA_FLAGS does not choose the emitters itself (no warning of
    its own: where JAX already runs, `_apply_loop_flag`'s warning is the one)."""
    global _emitter_flag_state
    if _flags_off():
        _emitter_flag_state = "disabled by JAXHYST_XLA_FLAGS"
        return
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_cpu_use_fusion_emitters" in flags:
        _emitter_flag_state = ("in effect (set by the user)" if EMITTER_FLAG in flags.split()
                               else "not applied: XLA_FLAGS chooses the emitters")
        return
    if _backends_initialized():
        _emitter_flag_state = "not applied: JAX was already running when jaxhyst was imported"
        return
    os.environ["XLA_FLAGS"] = (flags + " " + EMITTER_FLAG).strip()
    _emitter_flag_state = "in effect"


def _check_optimization_level() -> None:
    """Warn once, at import, where XLA_FLAGS compiles at LLVM -O0: compiled so on the CPU,
    the pinning-cell forms' paths come out wrong (benchmarks/RESULTS.md, issue 45)."""
    if re.search(r"xla_backend_optimization_level\s*=\s*0(\s|$)",
                 os.environ.get("XLA_FLAGS", "")):
        warnings.warn("XLA_FLAGS sets --xla_backend_optimization_level=0: compiled at that "
                      "level on the CPU, the pinning-cell forms (play, preisach) compute "
                      "wrong magnetization paths and derivatives (off by about 40 % of Ms "
                      "in a test of jaxhyst's); remove that flag.", RuntimeWarning, stacklevel=3)


def cpu_loop_kernels() -> str:
    """Whether jaxhyst's XLA:CPU loop setting is in effect (see the module docstring)."""
    return _loop_flag_state


def cpu_kernel_emitters() -> str:
    """Whether jaxhyst's XLA:CPU emitter setting (`EMITTER_FLAG`) is in effect (see the
    module docstring)."""
    return _emitter_flag_state


_enable_x64()
_apply_loop_flag()
_apply_emitter_flag()
_check_optimization_level()


def cache_dir() -> Path | None:
    """The directory for JAX's persistent compilation cache: ``$JAXHYST_CACHE_DIR`` if set
    (``off`` disables it), else ``$XDG_CACHE_HOME/jaxhyst/xla``, else
    ``~/.cache/jaxhyst/xla``."""
    env = os.environ.get("JAXHYST_CACHE_DIR")
    if env is not None:
        if env.strip().lower() in ("", "0", "off", "none", "false"):
            return None
        return Path(env).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "jaxhyst" / "xla"


def enable_compilation_cache(directory: str | os.PathLike | None = None) -> Path | None:
    """Turn on JAX's persistent compilation cache, so that a later process's first call
    of a jitted simulation or solver is loaded from disk instead of recompiled (compiles
    take seconds). ``directory`` defaults to `cache_dir` (``JAXHYST_CACHE_DIR=off``:
    nothing is done). A cache directory the user already configured in JAX is respected.
    Affects every JAX program of the process. Returns the directory in use, or None."""
    import jax

    if jax.config.jax_compilation_cache_dir:
        return Path(jax.config.jax_compilation_cache_dir)
    target = Path(directory).expanduser() if directory is not None else cache_dir()
    if target is None:
        return None
    try:
        target.mkdir(parents=True, exist_ok=True)
    except OSError:  # read-only home etc.: run without a cache rather than fail
        return None
    jax.config.update("jax_compilation_cache_dir", str(target))
    # Cache even small compilations: a time loop takes seconds to compile; programs of
    # 0.1–0.5 s (a report's cost, a batch's parameter values) are loaded faster than
    # compiled, the ~0.05 s single operations are not (benchmarks/RESULTS.md, issue 45).
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.1)
    jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    return target
