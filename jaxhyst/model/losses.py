"""Rate-dependent loss terms of the field-separation model (Bertotti's loss separation on
a static Jiles–Atherton hysteresis), shared by the H-driven and the B-driven forms.

The applied field is the sum of the field the static hysteresis model sees and dynamic
fields set by the rate of change of the flux density B and of that field itself:

    H = H_hyst + H_eddy + H_exc + H_lag,
    H_eddy = k_e·dB/dt                      (classical eddy currents),
    H_exc  = k_x·sign(dB/dt)·|dB/dt|^(1/2)  (excess, or anomalous, loss),
    H_lag  = τ·dH_hyst/dt                   (relaxation: the hysteresis field follows the
                                             applied field with a time constant τ),

with M_s = JA(H_hyst history) the static model's magnetization and B = μ0·(H_hyst + M),
where M = M_s without ``relax``; with it (τ_M > 0) the magnetization relaxes towards the
static one, a magnetic after-effect:

    τ_M·dM/dt = M_s − M                     (M lags M_s with the time constant τ_M),

so that B keeps rising after the field turns and a loop widens with frequency, without a
field of its own. The energy per cycle and volume ∮ H dB is then the static loop's area
plus k_e·∫(dB/dt)² dt plus k_x·∫|dB/dt|^(3/2) dt plus τ·∫(dH_hyst/dt)(dB/dt) dt (with
relax, ∮ H_hyst dB along the relaxed B: the after-effect's loss is in that area).

The eddy field is proportional to the rate of B, so it is large where the permeability
is (the steep part of a loop); the lag field is proportional to the rate of the
hysteresis field, so it is large where the permeability is small (the tips of a loop,
where B keeps rising after H turned): it is the viscous, after-effect-like dynamics of
Chua and Stromsmoe's lumped model (IEEE Trans. Circuit Theory 17 (1970) 564: dM/dt
proportional to the field in excess of the static one, here with the rate constant
χ/τ), a first-order relaxation of H_hyst towards the applied field.
For a lamination of thickness d and conductivity σ the classical coefficient is
k_e = σd²/12, for a round rod of radius r it is σr²/8 (`eddy_coefficient`); k_x is
√(σ·G·V0·S) in Bertotti's statistical theory (S the cross-section, G ≈ 0.1356, V0 a
material constant) and is in practice identified from data. With k_e = k_x = τ = τ_M = 0
both forms are the static model itself.

This is the field-separation form of the dynamic Jiles–Atherton model (Jiles, J. Appl.
Phys. 76 (1994) 5849 adds the same two energy terms to the JA energy balance; written in
fields it is the form used with B-driven hysteresis models for core loss).
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._typing import Real
from ..params import is_concrete, shown_value

#: The loss coefficients by name, in the order of `Losses`' fields.
LOSS_NAMES = ("eddy", "excess", "lag", "relax")
#: Their units.
LOSS_UNITS = {"eddy": "A*s/(m*T)", "excess": "A*s^0.5/(m*T^0.5)", "lag": "s", "relax": "s"}


#: The largest loss coefficient accepted (SI): a lamination of copper 0.1 m thick has
#: k_e = σd²/12 ≈ 5e4; a larger value is a unit mistake.
MAX_COEFFICIENT = 1e6
#: The largest relaxation time accepted (s): a lag of an hour is a unit mistake.
MAX_LAG = 3600.0
#: The largest value of each coefficient (SI).
LOSS_LIMITS = {"eddy": MAX_COEFFICIENT, "excess": MAX_COEFFICIENT, "lag": MAX_LAG,
               "relax": MAX_LAG}


class Losses(eqx.Module):
    """The loss coefficients (SI):

    - ``eddy``: k_e, A/m per T/s (H_eddy = k_e·dB/dt); ≥ 0;
    - ``excess``: k_x, A/m per (T/s)^(1/2) (H_exc = k_x·sign(Ḃ)·|Ḃ|^(1/2)); ≥ 0;
    - ``lag``: τ, s (H_lag = τ·dH_hyst/dt: the hysteresis field relaxes towards the
      applied field with time constant τ); ≥ 0;
    - ``relax``: τ_M, s (τ_M·dM/dt = M_s − M: the magnetization relaxes towards the
      static model's with time constant τ_M, a magnetic after-effect); ≥ 0. In the
      H-driven model, the B-driven one (`jaxhyst.simulate_flux`: its own path, second
      order in the sample step) and `compensate`'s inverse.

    Arrays (data, differentiable); leaves of shape (P,) for a batch. The pair
    ``(Parameters, Losses)`` is the parameter pytree of the rate-dependent model in
    identification (`jaxhyst.ParameterSpace.with_losses`).
    """

    eddy: Real
    excess: Real
    lag: Real
    relax: Real

    def __init__(self, eddy=0.0, excess=0.0, lag=0.0, relax=0.0):
        for name, value in (("eddy", eddy), ("excess", excess), ("lag", lag),
                            ("relax", relax)):
            if is_concrete(value):
                try:
                    v = np.asarray(value, dtype=np.float64)
                except (TypeError, ValueError):  # (text, None: reported below)
                    v = np.array(np.nan)
                top = LOSS_LIMITS[name]
                if not (np.all(np.isfinite(v)) and np.all(v >= 0) and np.all(v <= top)):
                    hint = ("an hour is a unit mistake" if name in ("lag", "relax") else
                            "a 0.1 m copper lamination's eddy coefficient is 5e4")
                    raise ValueError(f"Losses.{name} must lie in [0, {top:g}] "
                                     f"({LOSS_UNITS[name]}; {hint}); got {shown_value(value)}.")
        self.eddy = jnp.asarray(eddy, dtype=jnp.float64)
        self.excess = jnp.asarray(excess, dtype=jnp.float64)
        self.lag = jnp.asarray(lag, dtype=jnp.float64)
        self.relax = jnp.asarray(relax, dtype=jnp.float64)


def _signed_sqrt(rate):
    """sign(r)·|r|^(1/2), with a zero derivative at r = 0 instead of an infinite one."""
    nonzero = rate != 0
    safe = jnp.where(nonzero, jnp.abs(rate), 1.0)
    return jnp.where(nonzero, jnp.sign(rate) * jnp.sqrt(safe), 0.0)


def decay(tau, dt):
    """exp(−dt/τ) (dt ≥ 0 and τ ≥ 0 in s): 1 at dt = 0 for τ > 0, and 0 for τ = 0 at
    every dt (also where exp(−dt/τ) underflows, τ < dt/700), with finite derivatives
    everywhere (zero where it underflows)."""
    live = tau > dt / 700.0
    return jnp.where(live, jnp.exp(-dt / jnp.where(live, tau, 1.0)), 0.0)


def dynamic_field(rate, losses: Losses, field_rate=0.0):
    """H_eddy + H_exc + H_lag (A/m) at the flux-density rate ``rate`` (T/s) and the
    hysteresis field's rate ``field_rate`` (A/(m·s))."""
    return losses.eddy * rate + losses.excess * _signed_sqrt(rate) + losses.lag * field_rate


def dynamic_energy(dB, dt, losses: Losses, dH=0.0):
    """∫ (H_eddy + H_exc + H_lag) dB (J/m³) over a step in which B changes by ``dB`` (T)
    and the hysteresis field by ``dH`` (A/m) at constant rates during ``dt`` (s):
    k_e·dB²/dt + k_x·|dB|^(3/2)/dt^(1/2) + τ·dH·dB/dt."""
    return losses.eddy * dB * dB / dt + losses.excess * _signed_sqrt(dB) * dB / jnp.sqrt(dt) \
        + losses.lag * dH * dB / dt


def eddy_coefficient(conductivity: float, *, thickness: float | None = None,
                     radius: float | None = None) -> float:
    """The classical k_e (A/m per T/s) of a lamination of ``thickness`` d (m), σd²/12, or
    of a round rod of ``radius`` r (m), σr²/8, for a ``conductivity`` σ (S/m)."""
    if (thickness is None) == (radius is None):
        raise ValueError("give the lamination thickness or the rod radius (m), one of them.")
    if not (np.isfinite(conductivity) and conductivity > 0):
        raise ValueError(f"conductivity must be a finite number > 0 (S/m); got "
                         f"{conductivity!r}.")
    size = thickness if thickness is not None else radius
    if not (np.isfinite(size) and size > 0):
        raise ValueError(f"the thickness or radius must be > 0 (m); got {size!r}.")
    return float(conductivity * size**2 / (12.0 if thickness is not None else 8.0))
