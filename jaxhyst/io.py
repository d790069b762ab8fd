"""Files: write simulations as CSV atomically (an interrupted write never leaves a
half-written file: data go to a temporary file in the same directory, then renamed)."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import numpy as np

from .model.simulate import Simulation

#: Columns written for a simulation, with units (header names carry the unit).
SIMULATION_COLUMNS = (
    ("t", "t_s"), ("H", "H_A_per_m"), ("M", "M_A_per_m"), ("Man", "Man_A_per_m"),
    ("Mirr", "Mirr_A_per_m"), ("lam", "lambda"), ("y", "y_m"), ("strain", "strain"),
)  # fmt: skip


def atomic_write_text(path: str | os.PathLike, text: str) -> None:
    """Write ``text`` to ``path`` via a temporary file + ``os.replace`` (atomic on POSIX)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as fh:
            fh.write(text)
            fh.flush()
            os.fsync(fh.fileno())
        umask = os.umask(0)
        os.umask(umask)
        os.chmod(tmp, 0o666 & ~umask)  # mkstemp makes 0600; give the file normal permissions
        os.replace(tmp, path)
    except BaseException:
        if os.path.exists(tmp):
            os.unlink(tmp)
        raise


def write_simulation_csv(path, sim: Simulation, observed_only: bool = True) -> None:
    """Write a simulation's signals, one row per sample, SI units in the header names."""
    start = sim.run_in if observed_only else 0
    cols = [np.asarray(getattr(sim, field))[start:] for field, _ in SIMULATION_COLUMNS]
    header = ",".join(name for _, name in SIMULATION_COLUMNS)
    rows = "\n".join(",".join(f"{v:.17g}" for v in row) for row in np.column_stack(cols))
    atomic_write_text(path, header + "\n" + rows + "\n")
