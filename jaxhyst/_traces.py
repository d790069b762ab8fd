"""Traced programs kept on disk beside the compilation cache, so that a later process skips
tracing and lowering them.

JAX's persistent cache keeps compiled programs, not traces: a warm process still traces
and lowers every program before it finds the compiled one on disk, seconds for a fit's
step (`benchmarks/RESULTS.md`, issue 45). `kept_jit` is ``eqx.filter_jit`` that also
keeps each program it traces as an exported StableHLO module (``jax.export``) in
``<compilation cache>/jaxhyst-traces``, under a key that describes everything the trace
depends on:

- the function (module and qualified name) and a digest of jaxhyst's own source files;
- the versions of jax, jaxlib, equinox, optimistix, lineax and numpy, the platform and
  the JAX settings that change a trace;
- the traced modules' constants as they are now (`_constants`: a test or a program may
  change one) and the other trace-time switches (`SWITCHES`);
- the arguments' structure, every non-array value in it (Equinox static fields, Python
  numbers, named functions, arrays held as constants: by their bytes) and every array's
  shape, dtype and weak type.

A value the key cannot describe exactly (a closure, a lambda, an object of another kind)
makes the call an ordinary ``eqx.filter_jit`` call, as do calls inside a trace (under
``jit``, ``grad`` or ``vmap``), with JIT disabled, on more than one device, with no
compilation cache, or with ``JAXHYST_TRACE_CACHE=off``. So does a program that cannot be
exported (one with host callbacks). Values and compiled code are the same as
``eqx.filter_jit``'s: the module is the one its lowering produces, compiled by XLA (and
found in the compilation cache) as before. The files are read back with ``pickle`` (the
output's structure) like the compiled programs beside them, which are machine code: the
directory is trusted as the compilation cache is.
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import hashlib
import importlib
import importlib.util
import os
import sys
import threading
import types
from pathlib import Path

import equinox as eqx
import jax
import numpy as np

from ._kept_files import dumps, loads, singleton, write

#: Traces kept in memory per function (each a jitted exported call).
_KEPT = 32
#: The JAX settings that change a trace.
_SETTINGS = ("jax_enable_x64", "jax_default_matmul_precision", "jax_numpy_rank_promotion",
             "jax_numpy_dtype_promotion", "jax_debug_nans", "jax_enable_checks")


class _Undescribed(Exception):
    """A value the key cannot describe exactly."""


@functools.cache
def _serializable() -> bool:
    """Whether JAX can serialize exported programs here (it needs flatbuffers)."""
    return importlib.util.find_spec("flatbuffers") is not None


def _enabled() -> bool:
    return (os.environ.get("JAXHYST_TRACE_CACHE", "").strip().lower()
            not in ("0", "off", "false", "no") and bool(jax.config.jax_compilation_cache_dir)
            and not jax.config.jax_disable_jit and jax.device_count() == 1
            and _serializable())


def _directory() -> Path:
    return Path(jax.config.jax_compilation_cache_dir) / "jaxhyst-traces"


@functools.cache
def _environment() -> tuple:
    """What every key shares: jaxhyst's source, the libraries' versions, the platform."""
    root = Path(__file__).resolve().parent
    digest = hashlib.sha256()
    for path in sorted(root.rglob("*.py")):
        digest.update(str(path.relative_to(root)).encode())
        digest.update(path.read_bytes())
    versions = []
    for name in ("jax", "jaxlib", "equinox", "optimistix", "lineax", "numpy"):
        module = sys.modules.get(name) or importlib.import_module(name)
        versions.append((name, getattr(module, "__version__", "?")))
    device = jax.devices()[0]
    return (digest.hexdigest(), tuple(versions), device.platform,
            getattr(device, "device_kind", ""))


_SIMPLE = (bool, int, float, str, type(None))
#: Trace-time switches that are not module constants (name → a function that returns
#: the state, described by its repr): each module that has one registers it here.
SWITCHES: dict = {}


@functools.cache
def _traced_modules() -> tuple:
    """The modules whose code runs inside jaxhyst's programs (all but the command line's
    and the host-side helpers'), imported: the same list in every process."""
    import pkgutil

    names = ["jaxhyst.params", "jaxhyst.actuator", "jaxhyst.drive", "jaxhyst.sharding",
             "jaxhyst.saved", "jaxhyst.fit"]
    for package in ("jaxhyst.model", "jaxhyst.identify", "jaxhyst.analysis",
                    "jaxhyst.control"):
        names.append(package)
        path = importlib.import_module(package).__path__
        names += [m.name for m in pkgutil.walk_packages(path, package + ".")]
    return tuple(importlib.import_module(n) for n in sorted(set(names)))


@functools.cache
def _constant_names() -> tuple:
    """(module, its constants' names): upper-case names of numbers, strings, switches."""
    return tuple((m, tuple(k for k, v in vars(m).items()
                           if k.lstrip("_").isupper() and isinstance(v, _SIMPLE)))
                 for m in _traced_modules())


#: (the constants' values last described, their description): `_constants`.
_LAST_CONSTANTS: tuple = (None, None)


def _constants() -> str:
    """A digest of those modules' constants as they are now: a trace reads some of them,
    and a program or a test may change one. (Described again only where a value is not
    the one last described: a call's key does not walk through every module.)"""
    values = [getattr(m, k, None) for m, names in _constant_names() for k in names]
    global _LAST_CONSTANTS
    last, described = _LAST_CONSTANTS
    if last is None or len(last) != len(values) or \
            any(a is not b for a, b in zip(values, last, strict=True)):
        described = hashlib.sha256(repr(tuple(
            (m.__name__, tuple((k, repr(getattr(m, k, None))) for k in names))
            for m, names in _constant_names())).encode()).hexdigest()
        _LAST_CONSTANTS = (values, described)
    return described


def _named(obj) -> tuple:
    """A module-level function or class by its module and qualified name; refused where
    that name does not lead back to the object (a closure, a lambda, a local class)."""
    module, qualname = getattr(obj, "__module__", None), getattr(obj, "__qualname__", None)
    if not module or not qualname or "<" in qualname:
        raise _Undescribed(repr(obj))
    target = sys.modules.get(module)
    for part in qualname.split("."):
        target = getattr(target, part, None)
    seen = [target, getattr(target, "__func__", None), getattr(target, "__wrapped__", None)]
    if not any(t is obj for t in seen):
        raise _Undescribed(repr(obj))
    return ("named", module, qualname)


def _describe(value) -> object:
    """An exact, process-independent description of a non-array value (`_Undescribed`
    where there is none)."""
    if value is None or isinstance(value, (bool, int, float, complex, str, bytes)):
        return (type(value).__name__, repr(value))
    if isinstance(value, (tuple, list)):
        return (type(value).__name__, tuple(_describe(v) for v in value))
    if isinstance(value, dict):
        return ("dict", tuple(sorted((repr(k), _describe(v)) for k, v in value.items())))
    if isinstance(value, (frozenset, set)):
        return ("set", tuple(sorted(repr(_describe(v)) for v in value)))
    if isinstance(value, (np.ndarray, np.generic, jax.Array)):
        x = np.asarray(value)
        return ("const", x.dtype.str, x.shape, hashlib.sha256(x.tobytes()).hexdigest())
    if isinstance(value, jax.tree_util.PyTreeDef):
        return ("treedef", _structure(value))
    if isinstance(value, jax.ShapeDtypeStruct):
        return ("sds", value.shape, np.dtype(value.dtype).str, bool(value.weak_type))
    if isinstance(value, np.dtype):
        return ("dtype", value.str)
    if isinstance(value, enum.Enum):
        return ("enum", _named(type(value)), value.name)
    if isinstance(value, functools.partial):
        return ("partial", _describe(value.func), _describe(value.args),
                _describe(value.keywords))
    if isinstance(value, type):
        return _named(value)
    if isinstance(value, eqx.Module) or (dataclasses.is_dataclass(value)
                                         and not isinstance(value, type)):
        attrs = vars(value) if hasattr(value, "__dict__") else {
            f.name: getattr(value, f.name, None) for f in dataclasses.fields(value)}
        return (_named(type(value)), tuple((k, _describe(v)) for k, v in sorted(attrs.items())))
    if isinstance(value, (types.FunctionType, types.BuiltinFunctionType)) or callable(value):
        return _named(value)
    found = singleton(value)  # (a module-level singleton: a sentinel, lineax's tags)
    if found is None:
        raise _Undescribed(type(value).__name__)
    return ("singleton", *found)


def _structure(treedef) -> object:
    """The description of a pytree structure: its node types and auxiliary data."""
    if treedef.num_nodes == 1 and treedef.num_leaves == 1:
        return "*"
    kind, aux = treedef.node_data()
    return (_named(kind) if kind not in (tuple, list, dict, type(None)) else kind.__name__,
            _describe(aux), tuple(_structure(c) for c in treedef.children()))


#: Structures described (`_structure_of`): (treedef, its text) → description.
_STRUCTURES: dict = {}


def _structure_of(treedef) -> object:
    """`_structure`, remembered for a structure seen before: equal treedefs whose text
    (their auxiliary data's reprs: 1 and 1.0 differ there) is equal too."""
    try:
        memo = (treedef, str(treedef))
        known = _STRUCTURES.get(memo)
    except Exception:  # noqa: BLE001  (auxiliary data that cannot be hashed or compared)
        return _structure(treedef)
    if known is None:
        known = _structure(treedef)
        if len(_STRUCTURES) >= 256:
            _STRUCTURES.clear()
        _STRUCTURES[memo] = known
    return known


def _key(name: str, leaves, treedef) -> str:
    """The key of the call ``name(*args)`` (``leaves``, ``treedef``: the arguments)."""
    parts = [_environment(), _constants(), name,
             tuple((s, repr(getattr(jax.config, s, None))) for s in _SETTINGS),
             tuple((n, repr(state())) for n, state in sorted(SWITCHES.items())),
             _structure_of(treedef)]
    for x in leaves:
        if eqx.is_array(x):
            aval = jax.typeof(x) if isinstance(x, jax.Array) else None
            parts.append(("array", np.shape(x), np.dtype(x.dtype).str,
                          bool(aval.weak_type) if aval is not None else False))
        else:
            parts.append(_describe(x))
    return hashlib.sha256(repr(parts).encode()).hexdigest()


class _Slot:
    """The place of an output array in a kept output structure."""

    def __init__(self, index: int):
        self.index = index


class _Kept(eqx.Module):
    call: object = eqx.field(static=True)  # the jitted exported call: arrays → arrays
    skeleton: object = eqx.field(static=True)  # the output, arrays replaced by _Slot


def _load(path: Path):
    """The exported program and output skeleton saved under ``path``; the arrays' weak
    types, which serialization drops, restored (a weakly typed output stays so, and the
    next call's key with it)."""
    blob, skeleton, weak_in, weak_out = loads(path.read_bytes())
    exported = jax.export.deserialize(blob)
    return dataclasses.replace(
        exported,
        in_avals=tuple(a.update(weak_type=w) for a, w in zip(exported.in_avals, weak_in,
                                                              strict=True)),
        out_avals=tuple(a.update(weak_type=w) for a, w in zip(exported.out_avals, weak_out,
                                                               strict=True))), skeleton


def _export(fn, is_arr, leaves, treedef, path: Path):
    """Trace and lower ``fn`` once by exporting it; save it under ``path``."""
    fixed = [None if a else x for x, a in zip(leaves, is_arr, strict=True)]
    shapes = {}

    def flat(*arrays):
        it = iter(arrays)
        full = [next(it) if a else x for x, a in zip(fixed, is_arr, strict=True)]
        out = fn(*jax.tree.unflatten(treedef, full))
        out_leaves, out_def = jax.tree.flatten(out)
        shapes["def"] = out_def
        shapes["static"] = [None if eqx.is_array(y) else y for y in out_leaves]
        return [y for y in out_leaves if eqx.is_array(y)]

    flat.__name__ = f"{fn.__name__}_exported"  # (its lowering is not the program run)
    arrays = [x for x, a in zip(leaves, is_arr, strict=True) if a]
    checks = [jax.export.DisabledSafetyCheck.custom_call(n) for n in _CUSTOM_CALLS]
    exported = jax.export.export(jax.jit(flat), disabled_checks=checks)(*arrays)
    count = iter(range(len(exported.out_avals)))
    skeleton = jax.tree.unflatten(shapes["def"], [
        _Slot(next(count)) if s is None else s for s in shapes["static"]])
    data = dumps((exported.serialize(), skeleton, [a.weak_type for a in exported.in_avals],
                  [a.weak_type for a in exported.out_avals]))
    if _outline(loads(data)[1]) != _outline(skeleton):  # (an output that loads unequal)
        raise _Undescribed("the output's structure does not survive pickling")
    write(path, data)
    return exported, skeleton


def _outline(skeleton):
    return jax.tree.structure(skeleton, is_leaf=lambda s: isinstance(s, _Slot))


#: Custom calls of the CPU's LAPACK bindings: their compatibility across jax versions is
#: irrelevant here (the key holds jaxlib's version).
_CUSTOM_CALLS = ("lapack_dormqr_ffi", "lapack_dgeqrf_ffi", "lapack_dorgqr_ffi",
                 "lapack_dgetrf_ffi", "lapack_dpotrf_ffi", "lapack_dtrsm_ffi",
                 "lapack_dsyevd_ffi", "lapack_dgesdd_ffi", "lapack_dtrtrs_ffi",
                 "lapack_dgeqp3_ffi", "lapack_dorgqr", "lapack_dormqr")


#: Every `kept_jit` function's traces in memory (`forget`).
_MEMORIES: list = []


def forget() -> None:
    """Drop the traces kept in memory (a later call loads them from disk, as a new
    process would)."""
    for memory in _MEMORIES:
        memory.clear()


def kept_jit(fn):
    """``eqx.filter_jit(fn)`` whose traces are kept on disk (module docstring). Call it
    with positional arguments."""
    jitted = eqx.filter_jit(fn)
    memory: dict = {}
    _MEMORIES.append(memory)
    lock, locks = threading.Lock(), {}

    def kept_of(args):
        """(the kept trace for these arguments or None, the arguments' leaves)."""
        if not _enabled():
            return None, None
        leaves, treedef = jax.tree.flatten(args)
        if any(isinstance(x, jax.core.Tracer) for x in leaves):
            return None, None
        if not fn.__module__.startswith("jaxhyst."):  # (its code is not in the digest)
            return None, None
        try:
            _named(fn)  # (module-level: its name says which function)
            key = _key(f"{fn.__module__}.{fn.__qualname__}", leaves, treedef)
        except _Undescribed:
            return None, None
        with lock:
            one = locks.setdefault(key, threading.Lock())
        with one:  # (a background compile and the caller may ask for one key at once)
            kept = memory.get(key)
            if kept is None:
                kept = _kept(fn, leaves, treedef, key)
                with lock:
                    memory[key] = kept
                    while len(memory) > _KEPT:  # (its lock goes with it: a later call
                        old = next(iter(memory))  # of that key makes a new one)
                        del memory[old]
                        locks.pop(old, None)
        return (kept or None), leaves

    @functools.wraps(fn)
    def call(*args, **kwargs):
        kept, leaves = (None, None) if kwargs else kept_of(args)
        if kept is None:
            return jitted(*args, **kwargs)
        outs = kept.call(*[x for x in leaves if eqx.is_array(x)])
        return jax.tree.map(lambda s: outs[s.index] if isinstance(s, _Slot) else s,
                            kept.skeleton, is_leaf=lambda s: isinstance(s, _Slot))

    def lower(*args):
        """As ``eqx.filter_jit``'s: ``lower(*args).compile()`` compiles the program a
        call with these arguments runs (a background compile)."""
        kept, leaves = kept_of(args)
        if kept is None:
            return jitted.lower(*args)
        return kept.call.lower(*[x for x in leaves if eqx.is_array(x)])

    call.lower = lower
    return call


def _kept(fn, leaves, treedef, key):
    """The kept trace of this call (loaded, or exported and saved), or False where it
    cannot be kept (the call then goes to ``eqx.filter_jit``)."""
    path = _directory() / key[:2] / key
    refused = path.with_name(key + ".not-kept")
    if refused.exists():  # (an earlier process found it cannot be exported)
        return False
    is_arr = [eqx.is_array(x) for x in leaves]
    exported = None
    if path.exists():
        try:
            exported, skeleton = _load(path)
        except Exception:  # noqa: BLE001  (a damaged or foreign file: trace again)
            exported = None
    if exported is None:
        try:
            exported, skeleton = _export(fn, is_arr, leaves, treedef, path)
        except Exception:  # noqa: BLE001  (not exportable: a host callback, …)
            try:
                refused.parent.mkdir(parents=True, exist_ok=True)
                refused.touch()
            except OSError:
                pass
            return False

    def named(*arrays):
        return exported.call(*arrays)

    named.__name__ = fn.__name__
    # (an exported call's outputs are committed to the device: with the inputs' placement
    # said, a call on them is the same program as the first call on fresh arrays)
    device = jax.sharding.SingleDeviceSharding(jax.devices()[0])
    return _Kept(jax.jit(named, in_shardings=device), skeleton)
