"""The files of `jaxhyst._traces`: a kept trace's output structure pickled so that it loads
equal to the live one, written by the package's one writer (`jaxhyst._files`).

An object whose class compares by identity and that is an attribute of its class's module
(a sentinel; lineax's operator tags, ``lx.positive_semidefinite_tag`` …) is pickled by
that name and loaded as the same object. Pickled plainly, it would load as a new object
unequal to the live one; a frozenset of such tags is part of an operator's structure
(the inverse Hessian of a BFGS state), so no live state would combine with a loaded one.
"""

from __future__ import annotations

import enum
import importlib
import io
import pickle
import sys
import types
from pathlib import Path

from ._files import write_bytes


def singleton(value) -> tuple[str, str] | None:
    """(module, name) where ``value`` is an attribute of its class's module, else None."""
    module = sys.modules.get(type(value).__module__)
    for name, member in vars(module).items() if module is not None else ():
        if member is value:
            return type(value).__module__, name
    return None


class _Pickler(pickle.Pickler):
    def persistent_id(self, obj):
        if (obj is None or type(obj).__eq__ is not object.__eq__
                or isinstance(obj, (type, types.FunctionType, enum.Enum))):
            return None  # (pickled as usual: by value, or by reference already)
        return singleton(obj)


class _Unpickler(pickle.Unpickler):
    def persistent_load(self, pid):
        module, name = pid
        return getattr(importlib.import_module(module), name)


def dumps(obj) -> bytes:
    """``pickle.dumps``, module-level singletons by name (module docstring)."""
    buffer = io.BytesIO()
    _Pickler(buffer).dump(obj)
    return buffer.getvalue()


def loads(data: bytes):
    """The object `dumps` pickled, its module-level singletons the live ones."""
    return _Unpickler(io.BytesIO(data)).load()


def write(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` by the package's writer (atomically: processes writing
    the same key agree); on a read-only or full disk, nothing (the trace stays kept in
    memory only)."""
    try:
        write_bytes(path, data)
    except OSError:
        pass
