"""Identification: problems, local solvers (Optimistix + the paper's LMA/TRA), results."""

from .hybrid import HYBRIDS, GASettings, HybridGA, run_hybrid
from .joint import JointProblem, JointSpace, loop_problem
from .local import SOLVERS, make_solver, multistart, solve
from .paper_solvers import (
    MultiplicativeDamping,
    PaperLMA,
    PaperTRA,
    TwoDimensionalSubspaceDescent,
)
from .problem import OUTPUTS, ParameterSpace, Problem, synthetic_problem, u_from_z, z_from_u
from .result import IdentificationResult

__all__ = [
    "GASettings",
    "HYBRIDS",
    "HybridGA",
    "OUTPUTS",
    "SOLVERS",
    "IdentificationResult",
    "JointProblem",
    "JointSpace",
    "loop_problem",
    "MultiplicativeDamping",
    "PaperLMA",
    "PaperTRA",
    "ParameterSpace",
    "Problem",
    "TwoDimensionalSubspaceDescent",
    "make_solver",
    "run_hybrid",
    "multistart",
    "solve",
    "synthetic_problem",
    "u_from_z",
    "z_from_u",
]
