"""A Jiles–Atherton form driven by something other than H: by the flux density B
(`FluxDriven`, the B-driven model of `jaxhyst.model.flux`) or by the magnetization M
(`MagnetizationDriven`, the inverse model of `jaxhyst.model.inverse`). Each wraps a form
as a form of the same kind (a slope along its driver), so it runs through the same time
loop (`jaxhyst.model.magnetization.JAPath`), derivative rule and batching.
"""

from __future__ import annotations

from typing import ClassVar

import jax.numpy as jnp

from ..params import MU0, Parameters
from .jiles_atherton import AbstractJAVariant

#: Smallest dM/dH the inverse uses, relative to the anhysteretic slope Ms/(3a) at H = 0.
CHI_FLOOR = 1e-3


class FluxDriven(AbstractJAVariant):
    """A Jiles–Atherton form driven by B: its slope is dM/dB at (B, M) and its switch
    distance is the form's own at H_hyst = B/μ0 − M (see the module docstring)."""

    form: AbstractJAVariant
    scales_with_Ms: ClassVar[bool] = False  # (B/μ0 − M does not scale with Ms)

    @property
    def parameters(self) -> tuple[str, ...]:
        return self.form.parameters

    def slope(self, B, M, delta, p: Parameters, pinning=True):
        chi = self.form.slope(B / MU0 - M, M, delta, p, pinning)
        return chi / (MU0 * (1.0 + chi))

    def evaluate(self, B, M, delta, p: Parameters, pinning=True):
        chi, d, rate = self.form.evaluate(B / MU0 - M, M, delta, p, pinning)
        per_B = 1.0 / (MU0 * (1.0 + chi))  # dH_hyst/dB along the path
        return chi * per_B, d, rate * per_B

    def irreversible_magnetization(self, B, M, p: Parameters):
        return self.form.irreversible_magnetization(B / MU0 - M, M, p)


class MagnetizationDriven(AbstractJAVariant):
    """A Jiles–Atherton form driven by M: its "slope" is dH/dM = 1/χ at (M, H) and its
    switch distance is the form's own (see the module docstring). The driver argument
    of each method is M (A/m), the state is the field H (A/m)."""

    form: AbstractJAVariant
    scales_with_Ms: ClassVar[bool] = False  # (the state H does not scale with Ms)

    @property
    def parameters(self) -> tuple[str, ...]:
        return self.form.parameters

    def _floored(self, chi, p: Parameters):
        return jnp.maximum(chi, CHI_FLOOR * p.Ms / (3.0 * p.a))

    def slope(self, M, H, delta, p: Parameters, pinning=True):
        return 1.0 / self._floored(self.form.slope(H, M, delta, p, pinning), p)

    def evaluate(self, M, H, delta, p: Parameters, pinning=True):
        chi, d, rate = self.form.evaluate(H, M, delta, p, pinning)
        per_M = 1.0 / self._floored(chi, p)  # dH/dM along the path
        return per_M, d, rate * per_M

    def irreversible_magnetization(self, M, H, p: Parameters):
        return self.form.irreversible_magnetization(H, M, p)
