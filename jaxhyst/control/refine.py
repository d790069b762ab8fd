"""The refinement of `jaxhyst.compensate`: Levenberg–Marquardt on the tracking error
through the forward model, in coordinates where every input is inside the limits
(`TrackingResiduals`), in chunks that are looked at for progress and Ctrl-C
(`refine_input`); and the two-coordinate fit of the uncompensated input (`fit_affine`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._interrupt import stop_requested
from .._traces import kept_jit
from ..identify import TargetTermination, jacobian_linearized
from .limits import InputMap
from .tracking import Tracking, evaluate

#: The refinement's residuals are (y − r) in this fraction of the reference's stroke, so
#: that Levenberg–Marquardt's first damping (1) is small against JᵀJ: its first steps are
#: Gauss–Newton steps, which reach a reachable reference in a few.
RESIDUAL_UNIT = 1e-4
#: Levenberg–Marquardt's Cauchy tolerances (on z and on Σr²) when the target is not met.
RTOL, ATOL = 1e-8, 1e-12


class TrackingResiduals(eqx.Module):
    """The refinement's residuals: (y(u(z)) − r)/(scale·`RESIDUAL_UNIT`), then the
    map's own."""

    tracking: Tracking
    imap: InputMap
    r: jax.Array
    scale: jax.Array

    def __call__(self, z, args=None):
        y = self.tracking.displacement(self.imap.input(z))
        e = (y - self.r) / (self.scale * RESIDUAL_UNIT)
        return jnp.concatenate([e, self.imap.extra_residuals(z)])

    def cost(self, z) -> float:
        """Σr² of these residuals at z (host values), the model run by the tracking's
        compiled forward program (`evaluate`, which compensate runs anyway) and the map by
        its own small one (`InputMap.values`): called op by op, the residuals would compile
        a simulation program of their own and a few dozen single operations."""
        u, extra = self.imap.values(z)
        e = (evaluate(self.tracking, u) - np.asarray(self.r)) / (
            float(self.scale) * RESIDUAL_UNIT)
        return float(e @ e + extra @ extra)


@kept_jit
def least_squares(residuals, z0, steps, rtol, atol, target):
    """Levenberg–Marquardt from z0 for at most ``steps`` (an integer array, ≤ `CHUNK`:
    data, one program for every count), stopped also once Σr² ≤ ``target``: (z, whether
    it converged, steps taken)."""
    fn = jacobian_linearized(residuals)
    solver = TargetTermination(optx.LevenbergMarquardt(rtol=rtol, atol=atol), target, steps)
    sol = optx.least_squares(fn, solver, z0, max_steps=CHUNK, throw=False,
                             options={"jac": "fwd"})
    return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]


def affine_input(z, shape, mid: float, half: float) -> np.ndarray:
    """u = mid + half·(a + b·shape), z = (a, b): the uncompensated input (A or A/m)."""
    return mid + half * (z[0] + z[1] * np.asarray(shape))


def fit_affine(tracking: Tracking, shape, mid: float, half: float, r, z0,
               max_steps: int = 40) -> np.ndarray:
    """The two coordinates z = (a, b) of the uncompensated input `affine_input` that
    minimise Σ(y(u(z)) − r)²: Levenberg–Marquardt with a forward-difference Jacobian,
    every evaluation the tracking's one compiled forward program (`evaluate`), so that
    this two-parameter fit compiles nothing of its own. It ends when a step lowers the
    cost by less than 1e-10 of it, the damping grows past 1e10, or after ``max_steps``;
    returns z (shape (2,))."""
    r = np.asarray(r, dtype=np.float64)

    def residual(z):
        return evaluate(tracking, affine_input(z, shape, mid, half)) - r

    z = np.asarray(z0, dtype=np.float64).copy()
    e = residual(z)
    cost, damping = float(e @ e), 1e-3
    for _ in range(max_steps):
        h = 1e-7 * np.maximum(np.abs(z), 1e-2)
        J = np.stack([(residual(z + h[j] * np.eye(2)[j]) - e) / h[j] for j in range(2)], 1)
        A, g = J.T @ J, J.T @ e
        while damping < 1e10:
            try:
                dz = np.linalg.solve(A + damping * np.diag(np.diag(A) + 1e-300), -g)
            except np.linalg.LinAlgError:
                damping *= 10.0
                continue
            e_new = residual(z + dz)
            cost_new = float(e_new @ e_new)
            if np.isfinite(cost_new) and cost_new < cost:
                break
            damping *= 10.0
        else:
            return z
        z, e, fell = z + dz, e_new, cost - cost_new
        cost, damping = cost_new, max(damping / 10.0, 1e-12)
        if fell <= 1e-10 * cost:
            break
    return z


#: Levenberg–Marquardt steps of the refinement between two looks at its progress, and
#: the least relative fall of the rms error per look that counts as progress. Each look
#: restarts the solver (its damping too): with 10 steps a look, a 2000 Hz three-tone
#: reference "stalled" at 4× the uncompensated error where 25 reach 225×
#: (benchmarks/RESULTS.md).
CHUNK, PROGRESS = 25, 0.01


def refine_input(residuals: TrackingResiduals, z0, max_steps: int, target: float):
    """Levenberg–Marquardt on the tracking error from z0, looked at every `CHUNK` steps:
    it ends when it reaches the ``target`` Σr² or converges (``successful``), when a
    look finds the rms error fallen by less than `PROGRESS` (``stalled``: the reference
    is followed as far as the actuator can, the rest is beyond it), after ``max_steps``
    (``max_steps_reached``) or on Ctrl-C (``interrupted``). Returns (z, steps,
    outcome)."""
    z, steps = jnp.asarray(z0), 0
    cost = residuals.cost(z)
    target = jnp.asarray(target, dtype=jnp.float64)  # (data: a new tolerance compiles nothing)
    while True:
        z_new, ok, n = least_squares(residuals, z, np.int64(min(CHUNK, max_steps - steps)),
                                      RTOL, ATOL, target)
        steps += int(n)
        new_cost = residuals.cost(z_new)
        if new_cost <= cost:
            z = z_new
        if bool(ok):
            return np.asarray(z), steps, "successful"
        if stop_requested():
            return np.asarray(z), steps, "interrupted"
        if steps >= max_steps:
            return np.asarray(z), steps, "max_steps_reached"
        if not new_cost < (1.0 - PROGRESS) ** 2 * cost:
            return np.asarray(z), steps, "stalled"
        cost = new_cost
