"""Known actuator constants (paper §2 and §5) and the paper's two actuators."""

from __future__ import annotations

import math

import equinox as eqx


class Actuator(eqx.Module):
    """Geometry and drive constants of a magnetostrictive actuator (all SI).

    **Arguments:**
    - ``Ar``: rod cross-section, m².
    - ``lr``: rod length, m.
    - ``n``: solenoid turns per metre, 1/m (H = n·I + Hb). ``None`` when drives are
      given as fields directly (Actuator2).
    - ``Hb``: DC bias field (permanent magnets), A/m.
    - ``name``: free text for reports.
    """

    Ar: float = eqx.field(static=True)
    lr: float = eqx.field(static=True)
    n: float | None = eqx.field(static=True, default=None)
    Hb: float = eqx.field(static=True, default=0.0)
    name: str = eqx.field(static=True, default="actuator")

    def __check_init__(self):
        for field, value in (("Ar", self.Ar), ("lr", self.lr)):
            if not (isinstance(value, (int, float)) and math.isfinite(value) and value > 0):
                raise ValueError(
                    f"Actuator.{field} must be a finite number > 0 (SI); got {value!r}."
                )
        if self.n is not None and not (math.isfinite(self.n) and self.n > 0):
            raise ValueError(f"Actuator.n (turns per metre) must be > 0 or None; got {self.n!r}.")
        if not math.isfinite(self.Hb):
            raise ValueError(f"Actuator.Hb (bias field, A/m) must be finite; got {self.Hb!r}.")


#: Hebei University of Technology actuator (paper §5.1); also used for the Table 1 study.
ACTUATOR1 = Actuator(Ar=7.85e-5, lr=0.085, n=48471.0, Hb=0.0, name="Actuator1 (Hebei)")

#: Iowa State University actuator (paper §5.2): drive given as H = Hb + H_AC.
ACTUATOR2 = Actuator(Ar=1.2668e-4, lr=0.115, n=None, Hb=16e3, name="Actuator2 (Iowa State)")
