"""What the data determine: Jacobian SVD, null directions, standard errors."""

from .identifiability import IdentifiabilityReport, identifiability

__all__ = ["IdentifiabilityReport", "identifiability"]
