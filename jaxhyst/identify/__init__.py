"""Identification: the problem protocol and problems, parameter spaces, local solvers
(Optimistix, the paper's LMA/TRA, or any Optimistix solver object), the hybrid GAs and
immutable results. The identifiability report is attached one level up (`jaxhyst.solve`,
`jaxhyst.multistart`, `jaxhyst.run_hybrid`)."""

from .hybrid import (
    HYBRIDS,
    CheckpointError,
    GASettings,
    GAState,
    HybridGA,
    bcga_generation,
    fcga_generation,
    run_hybrid,
)
from .joint import JointProblem, JointSpace, loop_problem
from .local import jacobian_linearized, multistart, run_local, solve
from .problem import (
    OUTPUTS,
    AbstractProblem,
    GaussianPrior,
    Problem,
    ResidualGroup,
    ResidualProblem,
    synthetic_problem,
)
from .result import IdentificationResult, Outcome
from .solvers import (
    SOLVERS,
    MultiplicativeDamping,
    PaperLMA,
    PaperTRA,
    PaperTrustRegion,
    TwoDimensionalSubspaceDescent,
    make_solver,
)
from .space import ParameterSpace, u_from_z, z_from_u

__all__ = [
    "AbstractProblem",
    "CheckpointError",
    "GASettings",
    "GAState",
    "GaussianPrior",
    "HYBRIDS",
    "HybridGA",
    "IdentificationResult",
    "JointProblem",
    "JointSpace",
    "MultiplicativeDamping",
    "OUTPUTS",
    "Outcome",
    "PaperLMA",
    "PaperTRA",
    "PaperTrustRegion",
    "ParameterSpace",
    "Problem",
    "ResidualGroup",
    "ResidualProblem",
    "SOLVERS",
    "TwoDimensionalSubspaceDescent",
    "bcga_generation",
    "fcga_generation",
    "jacobian_linearized",
    "loop_problem",
    "make_solver",
    "multistart",
    "run_hybrid",
    "run_local",
    "solve",
    "synthetic_problem",
    "u_from_z",
    "z_from_u",
]
