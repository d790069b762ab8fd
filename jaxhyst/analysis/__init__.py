"""What the data determine: Jacobian SVD, null directions, standard errors, identifiable
combinations, profile likelihood and replicate fits."""

from .identifiability import PREFER_FIX, IdentifiabilityReport, identifiability
from .uncertainty import (
    ProfileLikelihood,
    coverage,
    fit_replicates,
    interval_coverage,
    profile_likelihood,
)

__all__ = [
    "PREFER_FIX",
    "IdentifiabilityReport",
    "ProfileLikelihood",
    "coverage",
    "interval_coverage",
    "fit_replicates",
    "identifiability",
    "profile_likelihood",
]
