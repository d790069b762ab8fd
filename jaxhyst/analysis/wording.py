"""How the analysis writes about parameters: their base names and units, cleaned
exponents, the words for a null direction; the 95 % normal quantile."""

from __future__ import annotations

import numpy as np

from ..model.paths import parameter_unit
from ..names import base_name

#: The two-sided 95 % quantile of a standard normal.
Z95 = 1.959963984540054


def clean(v, tol=1e-6):
    """Exponents rounded to 3 decimals, those below ``tol`` set to 0."""
    v = np.where(np.abs(v) < tol, 0.0, v)
    return np.round(v, 3) + 0.0


def transform_text(exponents: dict) -> str:
    """A null direction in words: the scaling that leaves the output unchanged."""
    def move(n, p):
        if p == 1:
            return f"{n} → s·{n}"
        if p == -1:
            return f"{n} → {n}/s"
        return f"{n} → s^{p:g}·{n}"

    return ("the output is unchanged under "
            + ", ".join(move(n, p) for n, p in exponents.items()) + " for any s > 0")


def unit_of(name: str) -> str:
    """A parameter's unit (its base name's; a condition law's coefficient: see
    `jaxhyst.model.paths.parameter_unit`)."""
    return parameter_unit(base_name(name))


