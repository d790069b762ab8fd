"""The refinement of `jaxhyst.compensate`: Levenberg–Marquardt on the tracking error
through the forward model, in coordinates where every input is inside the limits
(`TrackingResiduals`), in chunks that are looked at for progress and Ctrl-C
(`refine_input`); and the two-coordinate fit of the uncompensated input (`AffineResiduals`)."""

from __future__ import annotations

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np
import optimistix as optx

from .._interrupt import stop_requested
from ..identify import TargetTermination, jacobian_linearized
from .limits import InputMap
from .tracking import Tracking

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


@eqx.filter_jit
def least_squares(residuals, z0, max_steps, rtol, atol, target):
    """Levenberg–Marquardt from z0, stopped also once Σr² ≤ ``target``: (z, whether it
    converged, steps)."""
    fn = jacobian_linearized(residuals)
    solver = TargetTermination(optx.LevenbergMarquardt(rtol=rtol, atol=atol), target)
    sol = optx.least_squares(fn, solver, z0, max_steps=max_steps, throw=False,
                             options={"jac": "fwd"})
    return sol.value, sol.result == optx.RESULTS.successful, sol.stats["num_steps"]


class AffineResiduals(eqx.Module):
    """u = mid + half·(a + b·shape): the uncompensated input's two coordinates."""

    tracking: Tracking
    shape: jax.Array
    mid: jax.Array  # (data: another limit compiles nothing)
    half: jax.Array
    r: jax.Array
    scale: jax.Array

    def input(self, z):
        return self.mid + self.half * (z[0] + z[1] * self.shape)

    def __call__(self, z, args=None):
        y = self.tracking.displacement(self.input(z))
        return (y - self.r) / (self.scale * RESIDUAL_UNIT)


#: Levenberg–Marquardt steps of the refinement between two looks at its progress, and
#: the least relative fall of the rms error per look that counts as progress.
CHUNK, PROGRESS = 10, 0.01


def refine_input(residuals: TrackingResiduals, z0, max_steps: int, target: float):
    """Levenberg–Marquardt on the tracking error from z0, looked at every `CHUNK` steps:
    it ends when it reaches the ``target`` Σr² or converges (``successful``), when a
    look finds the rms error fallen by less than `PROGRESS` (``stalled``: the reference
    is followed as far as the actuator can, the rest is beyond it), after ``max_steps``
    (``max_steps_reached``) or on Ctrl-C (``interrupted``). Returns (z, steps,
    outcome)."""
    z, steps = jnp.asarray(z0), 0
    cost = float(jnp.sum(residuals(z) ** 2))
    target = jnp.asarray(target, dtype=jnp.float64)  # (data: a new tolerance compiles nothing)
    while True:
        z_new, ok, n = least_squares(residuals, z, min(CHUNK, max_steps - steps), RTOL,
                                      ATOL, target)
        steps += int(n)
        new_cost = float(jnp.sum(residuals(z_new) ** 2))
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
