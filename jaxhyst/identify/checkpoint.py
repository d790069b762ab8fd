"""Checkpoints of a hybrid GA run: the `GAState` with its history, written through the
package's one file writer (`jaxhyst._files`: atomically for a regular file), and read
back only into a state of the same shapes (never unpickling)."""

from __future__ import annotations

import dataclasses
import hashlib
import io
import json
import os
import zipfile

import jax
import jax.numpy as jnp
import numpy as np

from .._files import write_bytes
from .hybrid import GAState, HybridGA
from .problem import AbstractProblem
from .solvers import solver_name

#: The format of the file; a checkpoint of another version is refused.
CHECKPOINT_VERSION = 3


class CheckpointError(ValueError):
    """A checkpoint file cannot be used (one-line message naming the file and the fix)."""


def fingerprint(problem: AbstractProblem, method: HybridGA, seed: int) -> str:
    """A hash of everything a run's result depends on: the data, the box, the fixed
    values, the method with its settings, the seed."""
    h = hashlib.sha256()
    for leaf in jax.tree.leaves(problem.observations):
        h.update(np.asarray(leaf, dtype=np.float64).tobytes())
    h.update(np.asarray(problem.space.lower).tobytes() + np.asarray(problem.space.upper).tobytes())
    h.update(np.asarray(problem.space.base).tobytes())
    solver = None if method.local_solver is None else solver_name(method.local_solver)
    h.update(repr((solver, method.placement, sorted(method.settings().items()), int(seed),
                   problem.space.names, [g.name for g in problem.groups])).encode())
    return h.hexdigest()[:16]


def save_checkpoint(path, state: GAState, history: list, meta: dict) -> None:
    """Write the state, history and meta data (one ``.npz``)."""
    arrays = {name: np.asarray(value) for name, value in _fields(state).items()}
    buf = io.BytesIO()
    np.savez(buf, meta=np.array(json.dumps({**meta, "history": history,
                                            "version": CHECKPOINT_VERSION})), **arrays)
    write_bytes(path, buf.getvalue())


def _fields(state: GAState) -> dict:
    return {f.name: getattr(state, f.name) for f in dataclasses.fields(state)}


def load_checkpoint(path, template: GAState) -> tuple[GAState, list, dict]:
    """Read a checkpoint written by `save_checkpoint`, checking every array against
    ``template``. Raises `CheckpointError` with one line."""
    path = os.fspath(path)
    if not os.path.exists(path):
        raise CheckpointError(f"checkpoint {path} does not exist; run without resume to "
                              "start a new run.")
    if os.path.isdir(path):
        raise CheckpointError(f"checkpoint {path} is a directory; give a file.")
    try:
        with np.load(path, allow_pickle=False) as z:
            files = set(z.files)
            meta = json.loads(str(z["meta"]))
            arrays = {k: z[k] for k in files if k != "meta"}
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile,
            json.JSONDecodeError) as err:
        raise CheckpointError(f"checkpoint {path} is not a readable jaxhyst checkpoint "
                              f"({type(err).__name__}: {' '.join(str(err).split())[:120]}); "
                              "delete it or run without resume.") from None
    if not isinstance(meta, dict) or meta.get("version") != CHECKPOINT_VERSION:
        raise CheckpointError(f"checkpoint {path} was written by another jaxhyst version; "
                              "delete it or run without resume.")
    values = {}
    for name, ref in _fields(template).items():
        ref = np.asarray(ref)
        a = arrays.get(name)
        if a is None or a.shape != ref.shape or a.dtype != ref.dtype:
            raise CheckpointError(f"checkpoint {path} does not match this run (entry "
                                  f"{name!r}); delete it or run without resume.")
        values[name] = jnp.asarray(a)
    history = meta.pop("history", [])
    if not isinstance(history, list):
        raise CheckpointError(f"checkpoint {path} has a malformed history.")
    return GAState(**values), history, meta
