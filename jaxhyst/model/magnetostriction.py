"""Quadratic magnetostriction (paper eq 6)."""

from __future__ import annotations


def magnetostriction(M, Ms, lambda_s):
    """λ = (3/2)·(λs/Ms²)·M² (dimensionless strain); M and Ms in A/m."""
    return 1.5 * lambda_s * (M / Ms) ** 2

