"""Known actuator constants (paper §2 and §5) and the paper's two actuators."""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ._typing import Array, Float
from .params import is_concrete


class _Label(str):
    """A name that is metadata only: all labels compare equal and hash alike, so that
    actuators differing only in name share compiled programs."""

    def __eq__(self, other):
        return isinstance(other, _Label)

    def __ne__(self, other):
        return not self.__eq__(other)

    def __hash__(self):
        return 0


#: The name of the actuator of a material sample (`jaxhyst.identify.joint.NO_ACTUATOR`):
#: no structure, so its displacement and strain are placeholders.
MAGNETIZATION_ONLY = "none (magnetization only)"


class Actuator(eqx.Module):
    """Geometry and drive constants of a magnetostrictive actuator (all SI).

    **Arguments:**
    - ``Ar``: rod cross-section, m².
    - ``lr``: rod length, m.
    - ``n``: solenoid turns per metre, 1/m (H = n·I + Hb). ``None`` when drives are
      given as fields directly (Actuator2).
    - ``Hb``: DC bias field (permanent magnets), A/m.
    - ``name``: free text for reports.

    The numbers are JAX arrays (data, not compile-time constants): a new actuator does
    not recompile a jitted simulation, and ``jax.grad`` works with respect to them.
    Concrete values are checked on construction.
    """

    Ar: Float[Array, ""]
    lr: Float[Array, ""]
    n: Float[Array, ""] | None
    Hb: Float[Array, ""]
    name: str = eqx.field(static=True)

    def __init__(self, Ar, lr, n=None, Hb=0.0, name: str = "actuator"):
        for field, value, rule in (("Ar", Ar, "> 0 (m^2)"), ("lr", lr, "> 0 (m)"),
                                   ("n", n, "> 0 (1/m) or None"), ("Hb", Hb, "finite (A/m)")):
            if value is None or not is_concrete(value):
                continue
            try:
                v = np.asarray(value, dtype=np.float64)
            except (TypeError, ValueError):
                raise ValueError(f"Actuator.{field} must be a number {rule}; got "
                                 f"{value!r}.") from None
            ok = np.all(np.isfinite(v)) and (field == "Hb" or np.all(v > 0))
            if not ok:
                raise ValueError(f"Actuator.{field} must be a finite number {rule}; got "
                                 f"{value!r}.")
        self.Ar = jnp.asarray(Ar, dtype=jnp.float64)
        self.lr = jnp.asarray(lr, dtype=jnp.float64)
        self.n = None if n is None else jnp.asarray(n, dtype=jnp.float64)
        self.Hb = jnp.asarray(Hb, dtype=jnp.float64)
        self.name = _Label(name)

    @property
    def magnetization_only(self) -> bool:
        """Whether this stands for a material sample, not an actuator (its name is
        `MAGNETIZATION_ONLY`): only the magnetic signals of its simulations mean
        anything."""
        return str(self.name) == MAGNETIZATION_ONLY

    def to_dict(self) -> dict:
        """Plain ``{Ar, lr, n, Hb, name}`` (floats) of a concrete actuator."""
        return {"Ar": float(self.Ar), "lr": float(self.lr),
                "n": None if self.n is None else float(self.n), "Hb": float(self.Hb),
                "name": str(self.name)}


#: Hebei University of Technology actuator (paper §5.1); also used for the Table 1 study.
ACTUATOR1 = Actuator(Ar=7.85e-5, lr=0.085, n=48471.0, Hb=0.0, name="Actuator1 (Hebei)")

#: Iowa State University actuator (paper §5.2): drive given as H = Hb + H_AC.
ACTUATOR2 = Actuator(Ar=1.2668e-4, lr=0.115, n=None, Hb=16e3, name="Actuator2 (Iowa State)")
