"""Iterative learning control on the real actuator, with the model as its guide.

The model is never exact: the input `compensate` finds for it leaves a tracking error on
the real actuator. Over repeated periods (or repeated runs of a record) the error is
measured and the input corrected:

    z_{k+1} = z_k + γ·δ,   δ = the least-norm minimiser of ‖J_k·δ − e_k‖,

with e_k = r − y_measured,k, J_k the model's Jacobian of the displacement with respect to
the input coordinates z at the input just applied (the model-based, Newton-type update
of iterative learning control) and γ the learning gain. The step is the least-squares
solution itself (singular values below `RCOND` of the largest are cut), not a damped
one: a hysteretic model's most sensitive input directions are rough (a perturbation at
one sample moves the magnetization from there on), so damping would keep mostly those
and the update would create reversals the real actuator answers differently; the exact
step for a smooth error is smooth. The input is a function of z inside the current and
slew-rate limits
(`jaxhyst.control.limits.InputMap`), so every input it proposes is within them.

Use: ``learner = IterativeLearning.of(model, reference, current_limit=…)``; ``state =
learner.init()``; then repeatedly apply ``state.input``, measure the displacement at the
reference's samples (in the steady state, for a periodic reference) and call ``state =
learner.step(state, measured)``.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from ..saved import Model
from .compensate import RESIDUAL_UNIT, Compensation, _TrackingResiduals, compensate, rms_error
from .limits import InputMap
from .reference import Reference
from .tracking import Tracking

#: Singular values of J below this fraction of the largest are cut from a learning step.
RCOND = 1e-10


@dataclasses.dataclass(frozen=True)
class LearningState:
    """Where the learning stands: ``z`` the input coordinates, ``input`` (shape (N,), A
    or A/m) to apply next, ``iteration`` (0 before the first measurement), and
    ``errors``: the rms tracking error / peak-to-peak of each measurement so far."""

    z: np.ndarray
    input: np.ndarray
    iteration: int
    errors: tuple[float, ...]


@eqx.filter_jit
def _learning_step(residuals: _TrackingResiduals, z, e, gain):
    """z + γ·δ of the module docstring for the measured error e (residual units)."""
    J = jax.jacfwd(residuals)(z)
    target = jnp.concatenate([e, -residuals.imap.extra_residuals(z)])  # (map's own → 0)
    delta, _, _, _ = jnp.linalg.lstsq(J, target, rcond=RCOND)
    return z + gain * delta


class IterativeLearning(eqx.Module):
    """Model-based iterative learning control (see the module docstring).

    Build it with `of` (which runs `compensate` on the model for the first input).
    ``gain``: the learning gain γ in (0, 1] (1: a full Newton step on the model's
    linearization; lower it for a noisy measurement or a poor model)."""

    compensation: Compensation
    residuals: _TrackingResiduals
    gain: float = eqx.field(static=True, default=1.0)

    @classmethod
    def of(cls, model: Model, reference: Reference, *, current_limit=None,
           slew_limit=None, gain: float = 1.0, **options) -> IterativeLearning:
        """The learning controller of ``model`` for ``reference``; the limits and
        ``options`` are those of `compensate`."""
        g = float(gain)
        if not (np.isfinite(g) and 0 < g <= 1):
            raise ValueError(f"the learning gain must lie in (0, 1]; got {gain!r}.")
        comp = compensate(model, reference, current_limit=current_limit,
                          slew_limit=slew_limit, **options)
        tracking = Tracking.of(model, reference, comp.run_in_periods)
        imap = InputMap(comp.limits, reference.n_samples, reference.dt, reference.periodic)
        residuals = _TrackingResiduals(tracking, imap, jnp.asarray(reference.displacement),
                                       jnp.asarray(reference.scale))
        return cls(comp, residuals, g)

    @property
    def reference(self) -> Reference:
        return self.compensation.reference

    def init(self) -> LearningState:
        """The state before the first measurement: the model's compensating input."""
        imap = self.residuals.imap
        z = imap.coordinates(self.compensation.input)
        return LearningState(z=z, input=np.asarray(imap.input(jnp.asarray(z))),
                             iteration=0, errors=())

    def state_for(self, applied) -> LearningState:
        """The state of an input already applied (A or A/m, shape (N,): a run that was
        measured), e.g. one written by an earlier session; it is taken into the limits."""
        u = np.asarray(applied, dtype=np.float64)
        N = self.reference.n_samples
        if u.shape != (N,) or not np.all(np.isfinite(u)):
            raise ValueError(f"the applied input must be {N} finite values (one per reference "
                             f"sample); got shape {u.shape}.")
        imap = self.residuals.imap
        z = imap.coordinates(u)
        return LearningState(z=z, input=np.asarray(imap.input(jnp.asarray(z))), iteration=0,
                             errors=())

    def step(self, state: LearningState, measured) -> LearningState:
        """The next state, from the displacement ``measured`` (m, shape (N,): at the
        reference's samples, with ``state.input`` applied)."""
        y = np.asarray(measured, dtype=np.float64)
        N = self.reference.n_samples
        if y.shape != (N,):
            raise ValueError(f"the measured displacement must have one value per reference "
                             f"sample ({N}); got shape {y.shape}.")
        if not np.all(np.isfinite(y)):
            bad = np.flatnonzero(~np.isfinite(y))[:5].tolist()
            raise ValueError(f"the measured displacement is NaN or infinite at samples "
                             f"{bad}; repair the measurement.")
        r = np.asarray(self.reference.displacement)
        e = (r - y) / (self.reference.scale * RESIDUAL_UNIT)
        z = _learning_step(self.residuals, jnp.asarray(state.z), jnp.asarray(e), self.gain)
        z = np.asarray(z)
        error = rms_error(y, r, self.reference.scale)
        return LearningState(z=z, input=np.asarray(self.residuals.imap.input(jnp.asarray(z))),
                             iteration=state.iteration + 1, errors=(*state.errors, error))
