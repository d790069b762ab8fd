"""jaxhyst: differentiable Jiles–Atherton hysteresis of magnetostrictive actuators in JAX.

Importing the package turns on float64 and compiles CPU time loops as single kernels
(see `jaxhyst._config`); JAX's persistent compilation cache is one call,
`jaxhyst.enable_compilation_cache()`.
"""

from ._config import cpu_loop_kernels, enable_compilation_cache  # (first: x64)
from .actuator import ACTUATOR1, ACTUATOR2, Actuator
from .drive import Drive, drive_from_record, sinusoidal_current, sinusoidal_field
from .model import (
    ClassicJA,
    EnergyBasedJA,
    JAVariant,
    PopJA,
    Simulation,
    VenkataramanJA,
    frequency_response,
    langevin,
    langevin_slope,
    magnetostriction,
    simulate,
    simulate_unchecked,
)
from .model.simulate import simulate_batch
from .params import NAMES, TABLE1_BOUNDS, TABLE1_TRUE, TABLE3, UNITS, Bounds, Parameters

__version__ = "0.1.0"

__all__ = [
    "cpu_loop_kernels",
    "enable_compilation_cache",
    "ACTUATOR1",
    "ACTUATOR2",
    "NAMES",
    "TABLE1_BOUNDS",
    "TABLE1_TRUE",
    "TABLE3",
    "UNITS",
    "Actuator",
    "Bounds",
    "ClassicJA",
    "VenkataramanJA",
    "PopJA",
    "Drive",
    "EnergyBasedJA",
    "JAVariant",
    "Parameters",
    "Simulation",
    "drive_from_record",
    "frequency_response",
    "langevin",
    "langevin_slope",
    "magnetostriction",
    "simulate",
    "simulate_batch",
    "simulate_unchecked",
    "sinusoidal_current",
    "sinusoidal_field",
]

from .identify import (  # noqa: E402
    GASettings,
    IdentificationResult,
    JointProblem,
    JointSpace,
    ParameterSpace,
    Problem,
    loop_problem,
    multistart,
    run_hybrid,
    solve,
    synthetic_problem,
)

__all__ += [
    "GASettings",
    "run_hybrid",
    "IdentificationResult",
    "JointProblem",
    "JointSpace",
    "ParameterSpace",
    "loop_problem",
    "Problem",
    "multistart",
    "solve",
    "synthetic_problem",
]
