"""The model chain: Jiles–Atherton magnetization → magnetostriction → structural dynamics."""

from .jiles_atherton import ClassicJA, EnergyBasedJA, JAVariant, PopJA, VenkataramanJA
from .langevin import langevin, langevin_slope
from .magnetostriction import magnetostriction
from .simulate import Simulation, simulate, simulate_unchecked
from .structure import frequency_response

__all__ = [
    "ClassicJA",
    "VenkataramanJA",
    "PopJA",
    "EnergyBasedJA",
    "JAVariant",
    "Simulation",
    "frequency_response",
    "langevin",
    "langevin_slope",
    "magnetostriction",
    "simulate",
    "simulate_unchecked",
]
