"""What a problem observes: output kinds as types.

Each kind is a final ``equinox.Module`` with its name (as problems, result files and the
command line write it), its unit, the largest magnitude any magnetostrictive material
or actuator shows (data beyond it are a unit or column mistake, refused before a fit),
whether it sees the magnetization only (then the structural parameters cannot affect
it), whether it depends on the sample times (the structural dynamics do; the
rate-independent magnetization does not), and ``of(sim)``, the signal of a
`Simulation`.
"""

from __future__ import annotations

import abc
from typing import ClassVar

import equinox as eqx
import jax

from ..model.simulate import Simulation
from ..names import MAGNETIC_OUTPUT_NAMES
from ..params import MU0


class AbstractOutput(eqx.Module):
    """An observable of the simulation (see the module docstring)."""

    name: ClassVar[str]
    unit: ClassVar[str]
    largest: ClassVar[float]
    magnetic_only: ClassVar[bool]
    needs_time: ClassVar[bool]

    @abc.abstractmethod
    def of(self, sim: Simulation) -> jax.Array:
        """The signal (unit `unit`, shape of ``sim.t``)."""


class Displacement(AbstractOutput):
    """Output displacement y, m."""

    name: ClassVar[str] = "displacement"
    unit: ClassVar[str] = "m"
    largest: ClassVar[float] = 1.0
    magnetic_only: ClassVar[bool] = False
    needs_time: ClassVar[bool] = True

    def of(self, sim: Simulation) -> jax.Array:
        return sim.y


class Strain(AbstractOutput):
    """Strain ε = y/lr, dimensionless."""

    name: ClassVar[str] = "strain"
    unit: ClassVar[str] = "1"
    largest: ClassVar[float] = 1.0
    magnetic_only: ClassVar[bool] = False
    needs_time: ClassVar[bool] = True

    def of(self, sim: Simulation) -> jax.Array:
        return sim.strain


class Magnetostriction(AbstractOutput):
    """Magnetostriction λ, dimensionless (no structural dynamics)."""

    name: ClassVar[str] = "magnetostriction"
    unit: ClassVar[str] = "1"
    largest: ClassVar[float] = 1.0
    magnetic_only: ClassVar[bool] = False
    needs_time: ClassVar[bool] = False

    def of(self, sim: Simulation) -> jax.Array:
        return sim.lam


class Magnetization(AbstractOutput):
    """Magnetization M, A/m."""

    name: ClassVar[str] = "magnetization"
    unit: ClassVar[str] = "A/m"
    largest: ClassVar[float] = 1e8
    magnetic_only: ClassVar[bool] = True
    needs_time: ClassVar[bool] = False

    def of(self, sim: Simulation) -> jax.Array:
        return sim.M


class FluxDensity(AbstractOutput):
    """Flux density B = μ0·(H_hyst + M), T (H_hyst = H without loss terms)."""

    name: ClassVar[str] = "flux_density"
    unit: ClassVar[str] = "T"
    largest: ClassVar[float] = 100.0
    magnetic_only: ClassVar[bool] = True
    needs_time: ClassVar[bool] = False

    def of(self, sim: Simulation) -> jax.Array:
        return MU0 * (sim.H_hyst + sim.M)


#: Every output kind by name.
OUTPUTS: dict[str, AbstractOutput] = {
    kind.name: kind for kind in (Displacement(), Strain(), Magnetostriction(),
                                 Magnetization(), FluxDensity())}

#: Names of the kinds that see the magnetization only (also `jaxhyst.names`, for the
#: command line before JAX is imported).
MAGNETIC_OUTPUTS = frozenset(n for n, k in OUTPUTS.items() if k.magnetic_only)
assert MAGNETIC_OUTPUTS == set(MAGNETIC_OUTPUT_NAMES)


def output_kind(output: str | AbstractOutput) -> AbstractOutput:
    """The output kind for a name of `OUTPUTS` (or a kind itself); ``ValueError`` naming
    the choices otherwise."""
    if isinstance(output, AbstractOutput):
        return output
    if output not in OUTPUTS:
        raise ValueError(f"Unknown output {output!r}; choose one of {list(OUTPUTS)}.")
    return OUTPUTS[output]
