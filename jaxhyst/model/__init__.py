"""The model chain: Jiles–Atherton magnetization → magnetostriction → structural dynamics."""

from .jiles_atherton import (
    AbstractAnhystereticForm,
    AbstractJAVariant,
    ClassicJA,
    EnergyBasedJA,
    PopJA,
    VenkataramanJA,
    evaluate_by_differentiation,
    mirr_of_reversible_fraction,
)
from .langevin import langevin, langevin_slope
from .magnetostriction import magnetostriction
from .simulate import Simulation, simulate, simulate_unchecked
from .structure import frequency_response

__all__ = [
    "AbstractAnhystereticForm",
    "AbstractJAVariant",
    "ClassicJA",
    "EnergyBasedJA",
    "PopJA",
    "Simulation",
    "VenkataramanJA",
    "evaluate_by_differentiation",
    "frequency_response",
    "langevin",
    "langevin_slope",
    "magnetostriction",
    "mirr_of_reversible_fraction",
    "simulate",
    "simulate_unchecked",
]
