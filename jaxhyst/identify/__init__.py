"""Identification: the problem protocol and problems, parameter spaces, local solvers
(Optimistix, the paper's LMA/TRA, or any Optimistix solver object), the hybrid GAs and
immutable results. The identifiability report is attached one level up (`jaxhyst.solve`,
`jaxhyst.multistart`, `jaxhyst.run_hybrid`)."""

from ..model.accuracy import SamplingWarning
from ._objective import jacobian_linearized
from ._stepped import solve_traced
from .checkpoint import CheckpointError
from .conditions import (
    ConditionModel,
    ConditionProblem,
    Conditions,
    ConditionWarning,
    NearestCondition,
    condition_distance,
    condition_space,
    per_record_space,
    split_records,
)
from .flux import FluxProblem
from .hybrid import HYBRIDS, GAState, HybridGA
from .joint import JointProblem, JointSpace, loop_problem
from .local import multistart, solve, start_z
from .outputs import OUTPUTS, AbstractOutput, output_kind
from .problem import AbstractProblem, GaussianPrior, ResidualGroup, ResidualProblem
from .result import OUTCOME_NAMES, RESULTS, IdentificationResult, outcome_name
from .run import hybrid_method, run_hybrid
from .signal import Problem, synthetic_problem
from .solvers import (
    SOLVERS,
    MultiplicativeDamping,
    PaperLMA,
    PaperTRA,
    PaperTrustRegion,
    TargetTermination,
    TwoDimensionalSubspaceDescent,
    make_solver,
)
from .space import ParameterSpace, u_from_z, z_from_u

__all__ = [
    "AbstractOutput",
    "AbstractProblem",
    "CheckpointError",
    "ConditionModel",
    "ConditionProblem",
    "ConditionWarning",
    "Conditions",
    "FluxProblem",
    "GAState",
    "GaussianPrior",
    "HYBRIDS",
    "HybridGA",
    "IdentificationResult",
    "JointProblem",
    "JointSpace",
    "MultiplicativeDamping",
    "NearestCondition",
    "OUTCOME_NAMES",
    "OUTPUTS",
    "PaperLMA",
    "PaperTRA",
    "PaperTrustRegion",
    "ParameterSpace",
    "Problem",
    "RESULTS",
    "ResidualGroup",
    "ResidualProblem",
    "SOLVERS",
    "SamplingWarning",
    "TargetTermination",
    "TwoDimensionalSubspaceDescent",
    "hybrid_method",
    "condition_distance",
    "condition_space",
    "jacobian_linearized",
    "loop_problem",
    "make_solver",
    "multistart",
    "outcome_name",
    "per_record_space",
    "output_kind",
    "run_hybrid",
    "solve",
    "split_records",
    "solve_traced",
    "start_z",
    "synthetic_problem",
    "u_from_z",
    "z_from_u",
]
