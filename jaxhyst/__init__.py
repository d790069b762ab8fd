"""jaxhyst: differentiable Jiles–Atherton hysteresis of magnetostrictive actuators in JAX.

Importing the package turns on float64 for JAX and lets XLA compile CPU time loops as
single kernels (see `jaxhyst._config`) without importing JAX itself: the names below are
loaded on first use, so that ``jaxhyst --help`` answers at once. JAX's persistent
compilation cache is one call, `jaxhyst.enable_compilation_cache()`.
"""

from __future__ import annotations

import contextlib
import importlib
import sys

from ._config import (  # (first: x64, XLA flags)
    cpu_kernel_emitters,
    cpu_loop_kernels,
    enable_compilation_cache,
)

__version__ = "0.1.0"

#: Public name → the submodule that defines it (imported on first access).
_EXPORTS = {
    **dict.fromkeys(("ACTUATOR1", "ACTUATOR2", "Actuator"), ".actuator"),
    **dict.fromkeys(("Drive", "drive_from_record", "sinusoidal_current", "sinusoidal_field"),
                    ".drive"),
    **dict.fromkeys(("AbstractAnhystereticForm", "AbstractJAVariant", "ClassicJA",
                     "EnergyBasedJA", "PopJA", "VenkataramanJA", "Simulation",
                     "evaluate_by_differentiation", "frequency_response", "langevin",
                     "langevin_slope", "magnetostriction", "mirr_of_reversible_fraction",
                     "simulate", "simulate_unchecked", "FluxDrive", "FluxSimulation",
                     "Losses", "eddy_coefficient", "flux_from_period", "flux_from_record",
                     "simulate_flux", "simulate_flux_unchecked", "sinusoidal_flux", "PlayJA",
                     "PreisachJA", "AbstractPlayForm"),
                    ".model"),
    "simulate_batch": ".model.simulate",
    **dict.fromkeys(("NAMES", "TABLE1_BOUNDS", "TABLE1_TRUE", "TABLE3", "UNITS", "Bounds",
                     "Parameters"), ".params"),
    **dict.fromkeys(("multistart", "run_hybrid", "solve"), ".fit"),
    **dict.fromkeys(("ConditionModel", "ConditionProblem", "ConditionWarning", "Conditions",
                     "NearestCondition", "condition_space", "per_record_space",
                     "split_records"), ".identify"),
    **dict.fromkeys(("AbstractOutput", "AbstractProblem", "FluxProblem", "GaussianPrior",
                     "HybridGA", "IdentificationResult", "JointProblem", "JointSpace",
                     "ParameterSpace", "Problem", "RESULTS", "ResidualGroup", "ResidualProblem",
                     "loop_problem", "synthetic_problem"), ".identify"),
    **dict.fromkeys(("AbstractProgressMeter", "NoProgressMeter", "TextProgressMeter",
                     "TqdmProgressMeter"), ".progress"),
    "Interrupted": "._interrupt",
    "fit_many": ".batch",
    "times_from_frequency": ".loop_times",
    **dict.fromkeys(("Model", "load_model", "save_model"), ".saved"),
    **dict.fromkeys(("Compensation", "DelayError", "IterativeLearning", "Reference",
                     "SimulatedPlant", "compensate", "multitone_reference",
                     "reference_from_record", "sinusoidal_reference"),
                    ".control"),
}
_SUBMODULES = ("actuator", "analysis", "batch", "control", "drive", "fit", "identify", "io",
               "loop_times", "model", "names", "params", "plots", "progress", "saved", "sharding")

__all__ = ["cpu_kernel_emitters", "cpu_loop_kernels", "enable_compilation_cache", *_EXPORTS]


def _eager():
    """The context for loading a submodule: JAX's compile-time evaluation when JAX runs.
    A user's jitted function may be the first to touch ``jaxhyst.X``; the module-level
    constants imported then (TABLE1_TRUE, ACTUATOR1, …) must be concrete arrays, not
    tracers of that trace leaking into the module. (Without JAX imported, no trace runs.)"""
    if "jax" not in sys.modules:
        return contextlib.nullcontext()
    import jax

    return jax.ensure_compile_time_eval()


def __getattr__(name: str):
    if name not in _EXPORTS and name not in _SUBMODULES:
        raise AttributeError(f"module 'jaxhyst' has no attribute {name!r}")
    with _eager():
        if name in _EXPORTS:
            value = getattr(importlib.import_module(_EXPORTS[name], __name__), name)
        else:
            value = importlib.import_module(f".{name}", __name__)
    globals()[name] = value
    return value


def __dir__():
    """The public names once each (loaded or not), the submodules and the dunder names;
    not this module's own imports (contextlib, importlib, sys) or helpers."""
    return sorted({*__all__, *_SUBMODULES, "__version__",
                   *(n for n in globals() if n.startswith("__") and n.endswith("__"))})
