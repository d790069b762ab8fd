"""Hysteresis compensation: the drive input that makes an actuator follow a desired
displacement — from the model (`compensate`: inverse model, then refinement through the
forward model within current and slew-rate limits) and, on the real actuator, from what
it measured (`IterativeLearning`: model-based iterative learning control)."""

from .compensate import (
    Compensation,
    SettlingWarning,
    UnreachableWarning,
    compensate,
)
from .learning import DelayError, IterativeLearning, LearningReport, LearningState
from .limits import InputLimits, InputMap
from .plant import SimulatedPlant
from .reach import Reach, Unreachable
from .reference import (
    Reference,
    multitone_reference,
    reference_from_record,
    sinusoidal_reference,
)
from .tracking import Tracking

__all__ = [
    "Compensation",
    "DelayError",
    "InputLimits",
    "InputMap",
    "IterativeLearning",
    "LearningReport",
    "LearningState",
    "SimulatedPlant",
    "Reach",
    "Reference",
    "SettlingWarning",
    "Tracking",
    "Unreachable",
    "UnreachableWarning",
    "compensate",
    "multitone_reference",
    "reference_from_record",
    "sinusoidal_reference",
]
