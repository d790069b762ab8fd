"""The columns a data file may hold: each quantity's names and units (`QUANTITIES`),
and `parse_column`, which reads one header entry into a quantity and the factor to SI."""

from __future__ import annotations

import re

import numpy as np

from .params import MU0


class DataError(ValueError):
    """A data or parameter file cannot be used; the message says why and how to fix it."""


_PER_M = {"A/m": 1.0, "A_per_m": 1.0, "kA/m": 1e3, "kA_per_m": 1e3, "Oe": 1e3 / (4 * np.pi),
          "kOe": 1e6 / (4 * np.pi)}
#: Magnetization's units: a field's, and CGS emu/cm³ (1 emu/cm³ = 10³ A/m).
_MAGNETIZATION = {**_PER_M, "emu/cm3": 1e3, "emu/cm^3": 1e3, "emu_per_cm3": 1e3}
#: A polarization J = μ0·M in teslas, read as the magnetization M it is (A/m).
_POLARIZATION = {"T": 1.0 / MU0, "mT": 1e-3 / MU0}
_DIMLESS = {"": 1.0, "1": 1.0, "ppm": 1e-6}

#: Quantities a data file may hold: name → (aliases, description, SI unit, {unit: factor}).
QUANTITIES = {
    "loop": ((), "loop index", "", {"": 1.0}),
    "t": (("time",), "time", "s", {"s": 1.0, "ms": 1e-3, "us": 1e-6, "μs": 1e-6}),
    "H": (("field",), "applied field", "A/m", _PER_M),
    "I": (("current",), "coil current", "A", {"A": 1.0, "mA": 1e-3}),
    "y": (("displacement",), "displacement", "m",
          {"m": 1.0, "mm": 1e-3, "um": 1e-6, "μm": 1e-6, "nm": 1e-9}),
    "strain": ((), "strain", "1", _DIMLESS),
    "lambda": (("magnetostriction", "lam"), "magnetostriction", "1", _DIMLESS),
    "M": (("magnetization",), "magnetization", "A/m", _MAGNETIZATION),
    "Man": ((), "anhysteretic magnetization", "A/m", _PER_M),
    "Mirr": ((), "irreversible magnetization", "A/m", _PER_M),
    "B": (("flux_density",), "flux density", "T",
          {"T": 1.0, "mT": 1e-3, "G": 1e-4, "kG": 0.1}),
    "frequency": (("f", "freq"), "drive frequency of the loop", "Hz",
                  {"Hz": 1.0, "kHz": 1e3}),
    "temperature": (("temp",), "temperature of the loop", "°C", {"°C": 1.0, "C": 1.0}),
}  # fmt: skip


def parse_column(name: str) -> tuple[str, float]:
    """Quantity and SI factor of a header entry (``H [kA/m]``, ``y_um``, ``B (T)``, ``t``);
    a polarization ``J`` (T) is the magnetization M = J/μ0 (A/m)."""
    raw = name.strip()
    m = re.fullmatch(r"(.+?)\s*[\[(]\s*(.*?)\s*[\])]", raw)
    if m:
        qname, unit = m.group(1).strip(), m.group(2)
    else:
        qname, unit = raw, None
        if raw not in QUANTITIES and "_" in raw:
            head, tail = raw.split("_", 1)
            if _lookup(head) is not None or _polarization(head):
                qname, unit = head, tail
    if _polarization(qname):  # (J = μ0·M: the magnetization, in A/m)
        if unit is not None and unit not in _POLARIZATION:
            raise DataError(f"column {raw!r}: unit {unit!r} is not a unit of polarization J; "
                            f"use one of {', '.join(_POLARIZATION)}.")
        return "M", _POLARIZATION[unit or "T"]
    q = _lookup(qname)
    if q is None:
        known = ", ".join(f"{n} [{v[2] or '1'}]" for n, v in QUANTITIES.items()) + \
            ", J [T] (polarization μ0·M, read as M)"
        paired = _lookup(re.sub(r"[\s_]*\d+$", "", qname)) is not None  # (H1, B_2 …)
        raise DataError(f"column {raw!r} is not a known quantity; known columns: {known} " +
                        ("(loops side by side? put them one below the other, with a 'loop' "
                         "column: loop,H,B) " if paired else "") + "(rename the column, or "
                        "name the columns with --columns, '-' for one to skip).")
    _, desc, si, units = QUANTITIES[q]
    if unit is None:
        return q, 1.0
    if unit not in units:
        raise DataError(f"column {raw!r}: unit {unit!r} is not a unit of {desc} {q}; use one of "
                        f"{', '.join(u for u in units if u) or 'none (dimensionless)'}.")
    return q, units[unit]


def _polarization(name: str) -> bool:
    """Whether a column names the polarization J = μ0·M (T): read as M."""
    return name == "J" or name.lower() == "polarization"


def _lookup(name: str) -> str | None:
    if name in QUANTITIES:
        return name
    for q, (aliases, *_rest) in QUANTITIES.items():
        if name.lower() in aliases or name.lower() == q.lower() and q not in ("M", "B", "H"):
            return q
    return None
