"""The model chain: Jiles–Atherton magnetization → magnetostriction → structural dynamics."""

from .flux import (
    FluxDrive,
    FluxDriven,
    FluxSimulation,
    flux_from_period,
    flux_from_record,
    simulate_flux,
    simulate_flux_unchecked,
    sinusoidal_flux,
)
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
from .losses import Losses, eddy_coefficient
from .magnetostriction import magnetostriction
from .play import AbstractPlayForm, PlayJA, PreisachJA
from .simulate import Simulation, simulate, simulate_unchecked
from .structure import frequency_response

__all__ = [
    "AbstractAnhystereticForm",
    "AbstractJAVariant",
    "AbstractPlayForm",
    "ClassicJA",
    "EnergyBasedJA",
    "FluxDrive",
    "FluxDriven",
    "FluxSimulation",
    "Losses",
    "PlayJA",
    "PopJA",
    "PreisachJA",
    "Simulation",
    "VenkataramanJA",
    "eddy_coefficient",
    "evaluate_by_differentiation",
    "flux_from_period",
    "flux_from_record",
    "frequency_response",
    "langevin",
    "langevin_slope",
    "magnetostriction",
    "mirr_of_reversible_fraction",
    "simulate",
    "simulate_flux",
    "simulate_flux_unchecked",
    "simulate_unchecked",
    "sinusoidal_flux",
]
