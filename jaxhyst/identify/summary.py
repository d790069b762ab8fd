"""An `IdentificationResult` at a point: the end of every solve and hybrid."""

from __future__ import annotations

import dataclasses

import equinox as eqx
import numpy as np

from ._stepped import evaluate_at
from .problem import AbstractProblem, content_digest
from .result import RESULTS, IdentificationResult, as_result, bound_status, outcome_name
from .space import u_from_z


def _stats(groups, residuals):
    """Per-group rms and max |e|, and the overall ones when all groups share a unit."""
    out = {}
    residuals = [g.observed(np.asarray(e, dtype=float)) for g, e in
                 zip(groups, residuals, strict=True)]  # (padding dropped)
    for g, e in zip(groups, residuals, strict=True):
        out[g.name] = {"rms": float(np.sqrt(np.mean(e**2))), "max_abs": float(np.max(np.abs(e))),
                       "unit": g.unit,
                       "sigma": None if g.sigma is None else float(g.sigma), "size": e.size}
        if g.data_size is not None:  # max|data|: how far the fit is from its data
            out[g.name]["data_scale"] = float(g.data_size)
    units = {g.unit for g in groups}
    if len(units) != 1:
        return out, None, None, None
    e = np.concatenate(residuals)
    return out, float(np.sqrt(np.mean(e**2))), float(np.max(np.abs(e))), float(np.sum(e**2))


def u_from_z_host(z) -> np.ndarray:
    """`jaxhyst.identify.space.u_from_z` of host values, by NumPy (no program: op by op,
    each JAX operation on a new shape compiles one of its own)."""
    return 0.5 * (1.0 + np.sin(np.asarray(z, dtype=np.float64)))


def z_from_u_host(u) -> np.ndarray:
    """`jaxhyst.identify.space.z_from_u` of host values, by NumPy (`u_from_z_host`)."""
    return np.arcsin(np.clip(2.0 * np.asarray(u, dtype=np.float64) - 1.0, -1.0, 1.0))


@eqx.filter_jit
def point_of(space, z):
    """(free values in SI, parameter pytree) at the solver coordinate z."""
    return space.free_from_u(u_from_z(z)), space.params_from_z(z)


@eqx.filter_jit
def free_values_of(space, params):
    """``space.free_values(params)`` as one compiled program (run op by op on concrete
    arrays, it compiles a dozen tiny ones in every fresh process)."""
    return space.free_values(params)


def summarize(problem: AbstractProblem, z, steps, outcome, solver: str, wall: float,
              extra: dict | None = None, evaluated=None) -> IdentificationResult:
    """An `IdentificationResult` at the solver coordinate ``z`` (without report).
    ``evaluated``: (cost, group residuals) at ``z`` when the caller has them already."""
    cost, residuals = evaluated if evaluated is not None else evaluate_at(
        problem, np.asarray(z))
    cost = float(cost)
    outcome = as_result(outcome)
    if not np.isfinite(cost) and outcome_name(outcome) != "interrupted":
        outcome = RESULTS.nonfinite
    groups, rms, max_abs, sse = _stats(problem.groups, residuals)
    space = problem.space
    values, params = point_of(space, np.asarray(z))  # (jnp.asarray would compile a copy)
    values = np.asarray(values, dtype=float)
    lower, upper = np.asarray(space.lower), np.asarray(space.upper)
    at_bound = {space.names[i]: (side, float(lower[i] if side == "lower" else upper[i]))
                for i, side in bound_status(values, lower, upper).items()}
    return IdentificationResult(
        params=params, free=space.names,
        values=tuple(float(v) for v in values), cost=cost, outcome=outcome, steps=int(steps),
        solver=solver, wall_time=wall, groups=groups, rms_error=rms, max_abs_error=max_abs,
        sse=sse, output=problem.output, extra=extra or {},
        at_bound=at_bound,
    )  # fmt: skip


def with_linearization(result: IdentificationResult, problem: AbstractProblem, z,
                       linear) -> IdentificationResult:
    """``result`` (at the solver coordinate ``z`` of ``problem``) with the solver's
    linearization there, ``linear`` = (∂r/∂z (R, n), r (R,)) of the residual vector of
    `AbstractProblem.residuals_params`, or None, carried to the groups' residuals (their
    units) and the free values x (``IdentificationResult.linearization``): rows times
    their group's normaliser, the priors' rows dropped, columns over dx/dz with x = lower
    + (upper − lower)·(1 + sin z)/2 coordinate by coordinate. Left out where it is not
    finite or where dx/dz is 0."""
    if linear is None:
        return result
    J, r = (np.asarray(a, dtype=float) for a in linear)
    space, groups = problem.space, problem.groups
    sizes = [int(g.size) for g in groups]
    N = sum(sizes)
    z = np.asarray(z, dtype=float)
    dxdz = 0.5 * (np.asarray(space.upper, float) - np.asarray(space.lower, float)) * np.cos(z)
    if not (np.all(np.isfinite(J)) and np.all(np.isfinite(r)) and np.all(dxdz != 0)
            and J.shape == (r.size, z.size) and r.size >= N):
        return result
    per_row = np.repeat([float(g.normaliser) for g in groups], sizes)
    return dataclasses.replace(result, linearization=(
        np.asarray(result.values, float), J[:N] * per_row[:, None] / dxdz, r[:N] * per_row,
        content_digest(problem)))


def fitted_output(result: IdentificationResult, problem: AbstractProblem) -> np.ndarray:
    """The observed output of a single-signal ``problem`` (its unit, shape of its data) at
    ``result``'s values: data + residuals from the solver's last linearization where it
    was made of this problem at those values (nothing simulated, nothing compiled), else
    ``problem.predict``."""
    lin, data = result.linearization, np.asarray(problem.data, dtype=float)
    if lin is not None and len(problem.groups) == 1 and lin[2].shape == data.shape \
            and np.array_equal(lin[0], np.asarray(result.values, float)) \
            and lin[3] == content_digest(problem):
        return data + lin[2]
    return np.asarray(problem.predict(result.params))
