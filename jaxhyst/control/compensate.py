"""`compensate`: the input that makes the actuator model follow a desired displacement.

1. **Reach** (`jaxhyst.control.reach`): what the actuator can do within the limits; the
   samples of the reference it cannot follow are reported, with where and why.
2. **Inverse model** (`jaxhyst.control.inverse`): each stage of the model run backwards
   gives a first input.
3. **Refinement**: Optimistix's Levenberg–Marquardt on the tracking error through the
   forward model, over coordinates in which every input respects the current and
   slew-rate limits (`jaxhyst.control.limits.InputMap`), with the Jacobian of the
   displacement with respect to all N input samples by one forward-mode pass per step.

The result says how well the best input that ignores hysteresis ("uncompensated": the
reference scaled and shifted, u = a + b·(r − r̄), a and b fitted through the model), the
inverse model alone and the refined input track the reference: rms error relative to the
reference's peak-to-peak.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._background import meanwhile
from ..drive import Drive
from ..model.accuracy import richardson_error
from ..progress import progress_meter
from ..saved import Model
from .inverse import compile_field, inverse_input
from .limits import InputLimits, InputMap
from .reach import Reach, Unreachable, reach, unreachable
from .reference import Reference
from .refine import (
    ATOL,
    CHUNK,
    RESIDUAL_UNIT,
    RTOL,
    TrackingResiduals,
    affine_input,
    fit_affine,
    least_squares,
    refine_input,
)
from .tracking import Tracking, compile_settling, evaluate, input_gain, settling_periods

#: Largest estimated model error at the reference's sampling, relative to its stroke.
COARSE = 1e-3
#: Most input samples refined at once (the Jacobian is N × N, dense).
MAX_REFINED = 4096
class UnreachableWarning(UserWarning):
    """Part of a reference lies beyond what the actuator can do (`Compensation.unreachable`
    says where and why)."""


class SettlingWarning(UserWarning):
    """The model's magnetization had not settled onto its periodic loop within the
    run-in periods (a small loop with large pinning settles slowly)."""


def rms_error(y, r, scale: float) -> float:
    """rms(y − r)/scale."""
    return float(np.sqrt(np.mean((np.asarray(y) - np.asarray(r)) ** 2)) / scale)


@dataclasses.dataclass(frozen=True)
class Compensation:
    """The result of `compensate` (host arrays of shape (N,), the reference's samples).

    - ``input``: the compensating input u (``unit``: A of coil current, or A/m of AC
      field for an actuator driven by a field); periodic for a periodic reference;
      ``displacement``: what the model predicts for it, m.
    - ``inverse_input``/``inverse_displacement``: the inverse model alone;
      ``uncompensated_input``/``uncompensated_displacement``: the best input that
      ignores hysteresis (the reference scaled and shifted).
    - ``limits`` (`InputLimits`), ``reach`` (`jaxhyst.control.reach.Reach`),
      ``unreachable``: the stretches of the reference beyond the actuator
      (`jaxhyst.control.reach.Unreachable`, empty if it is all reachable).
    - ``fine_error``: the rms tracking error of ``input`` on the model at twice the
      substeps (the error of the discretised model it was refined on is ``error``; this
      is the one to expect from the model's equations);
    - ``steps`` of the refinement, its ``outcome`` (``successful``, ``stalled``: the
      error stopped falling — what is left is beyond the actuator —,
      ``max_steps_reached``, ``interrupted`` or ``not refined``), ``seconds``: the wall
      time of the call (the first call for a
      reference of a new length compiles its programs, seconds on a CPU; later ones reuse them),
      ``run_in_periods`` of a periodic reference.
    """

    reference: Reference
    input: np.ndarray
    displacement: np.ndarray
    unit: str
    limits: InputLimits
    inverse_input: np.ndarray
    inverse_displacement: np.ndarray
    uncompensated_input: np.ndarray
    uncompensated_displacement: np.ndarray
    reach: Reach
    unreachable: tuple[Unreachable, ...]
    steps: int
    outcome: str
    seconds: float
    run_in_periods: int
    settled: float
    gain: float
    bias: float
    fine_error: float = float("nan")

    @property
    def t(self) -> np.ndarray:
        return np.asarray(self.reference.t)

    def _error(self, y) -> float:
        return rms_error(y, self.reference.displacement, self.reference.scale)

    @property
    def error(self) -> float:
        """rms tracking error of the compensated input, relative to the reference's
        peak-to-peak."""
        return self._error(self.displacement)

    @property
    def inverse_error(self) -> float:
        return self._error(self.inverse_displacement)

    @property
    def uncompensated_error(self) -> float:
        return self._error(self.uncompensated_displacement)

    @property
    def max_error(self) -> float:
        """Largest |y − r| relative to the reference's peak-to-peak."""
        r = np.asarray(self.reference.displacement)
        return float(np.max(np.abs(self.displacement - r)) / self.reference.scale)

    @property
    def reachable(self) -> bool:
        return not self.unreachable

    def drive(self, periods: int = 1) -> Drive:
        """A `Drive` (H = gain·u + Hb, A/m) that applies the input: ``periods``
        repetitions of a periodic input, closed by its first sample, or the record. It
        has no run-in: simulate it after your own, or take `Compensation.displacement`
        as the model's steady state."""
        u = self.input
        if self.reference.periodic:
            u = np.append(np.tile(u, int(periods)), u[0])
            t = self.t[0] + self.reference.dt * np.arange(u.shape[0])
        else:
            t = self.t
        return Drive(t, self.gain * u + self.bias)

    def summary(self) -> str:
        r = self.reference
        kind = (f"one period of {r.n_samples} samples, {1.0 / r.period:g} Hz" if r.periodic
                else f"a record of {r.n_samples} samples")
        lines = [f"compensation of {kind}; input limits {self.limits.describe(self.unit)}",
                 f"  rms tracking error / peak-to-peak: uncompensated "
                 f"{self.uncompensated_error:.3e}, inverse model {self.inverse_error:.3e}, "
                 f"refined {self.error:.3e} ({self.uncompensated_error / self.error:.3g}x "
                 f"better than uncompensated); on a finer model (twice the substeps) "
                 f"{self.fine_error:.3e}",
                 f"  refinement: {self.steps} steps, {self.outcome}; {self.seconds:.3g} s"]
        if self.unreachable:
            shown = self.unreachable[:5]
            lines.append(f"  unreachable ({len(self.unreachable)} stretches"
                         + (f", the first {len(shown)}" if len(shown) < len(self.unreachable)
                            else "") + "):")
            lines += [f"    {u}" for u in shown]
        if self.settled > 1e-6:
            lines.append(f"  the magnetization had not settled: it still moved by "
                         f"{self.settled:.2g}·Ms per period after {self.run_in_periods} "
                         "periods")
        return "\n".join(lines)

    def to_dict(self) -> dict:
        """JSON-able summary (numbers and the unreachable stretches, no arrays)."""
        lim = self.limits
        return {"periodic": self.reference.periodic, "samples": self.reference.n_samples,
                "unit": self.unit, "limits": {"lower": float(lim.lower),
                                              "upper": float(lim.upper),
                                              "slew": None if lim.slew is None else
                                              float(lim.slew), "given": lim.given},
                "error": self.error, "max_error": self.max_error,
                "fine_error": self.fine_error,
                "inverse_error": self.inverse_error,
                "uncompensated_error": self.uncompensated_error, "steps": self.steps,
                "outcome": self.outcome, "seconds": self.seconds,
                "run_in_periods": self.run_in_periods,
                "stroke_m": list(self.reach.y),
                "unreachable": [{"reason": u.reason, "start": u.start, "stop": u.stop,
                                 "t_start_s": u.t_start, "t_stop_s": u.t_stop,
                                 "excess": u.excess, "unit": u.unit}
                                for u in self.unreachable]}


def _uncompensated(tracking: Tracking, reference: Reference, limits: InputLimits,
                   u_start: np.ndarray) -> np.ndarray:
    """The best input that ignores hysteresis: u = a + b·(r − r̄)/(ptp(r)/2), a and b
    fitted through the model (from the mean and swing of ``u_start``), then clipped into
    the limits."""
    r = np.asarray(reference.displacement)
    span = float(np.ptp(r)) or 1.0
    shape = (r - r.mean()) / (0.5 * span)
    mid, half = float(limits.mid), float(limits.half)
    z0 = np.array([(u_start.mean() - mid) / half, 0.5 * np.ptp(u_start) / half])
    z = fit_affine(tracking, shape, mid, half, r, z0)
    # within the same limits as the compensated input: the range and the slew rate
    imap = InputMap(limits, reference.n_samples, reference.dt, reference.periodic)
    return imap.input_values(imap.coordinates(affine_input(z, shape, mid, half)))


def _finer(tracking: Tracking) -> Tracking:
    """The same tracking on the model at twice the substeps."""
    model = tracking.model
    return eqx.tree_at(lambda t: t.model, tracking,
                       Model(model.params, model.actuator, model.variant,
                             2 * model.substeps, model.losses))


def _check_accuracy(tracking: Tracking, u: np.ndarray, scale: float) -> float:
    """A one-line error if the model's discretization error at the reference's sampling
    (estimated from the same drive at twice the substeps: RK4's error falls 16×) is
    above `COARSE` of the reference's stroke; the estimate (relative to the stroke)
    otherwise. The samples asked for assume the error falls only with the square of the
    step (a reference with kinks, a triangle, does no better), so that one answer
    suffices."""
    model = tracking.model
    finer = _finer(tracking)
    error = richardson_error(evaluate(tracking, u), evaluate(finer, u), size=scale)
    if not np.isfinite(error) or error <= COARSE:
        return error
    N = tracking.n
    factor = 2 ** math.ceil(math.log2((error / COARSE) ** 0.5 * 1.05))
    what = "per period" if tracking.periodic else "in the record"
    raise ValueError(
        f"the reference is sampled too coarsely for the model's accuracy: at {N} samples "
        f"{what} its displacement error is estimated at {error:.2g} of the reference's "
        f"stroke (above {COARSE:g}); give at least {N * factor} samples {what} (or more "
        f"substeps than {model.substeps}).")


#: The inverse model's usual tracking error (a fraction of the stroke: 3e-5 … 1e-4 on
#: the benchmark's references): a tolerance below it will be refined, so the
#: refinement's program is compiled while the model's are (`_compile_refinement`).
INVERSE_TYPICAL = 1e-4


def _compile_refinement(residuals: TrackingResiduals, z0, max_steps: int):
    """The refinement's Levenberg–Marquardt program compiled in a background thread
    (`jaxhyst._background`) once this one has lowered its next large program (the
    model's, for the accuracy check or the uncompensated input): its trace follows this
    one's, its compile runs beside the model's and the work up to the refinement, which
    joins it. Called as `refine_input` first calls it, with the target ∞ (data: the same
    program) so that it stops after a step; the result is dropped."""
    z0 = jnp.asarray(z0)
    return meanwhile(lambda: least_squares(residuals, z0, np.int64(min(CHUNK, int(max_steps))),
                                           RTOL, ATOL, jnp.asarray(np.inf, dtype=jnp.float64)))


def _model_of(model) -> Model:
    if isinstance(model, Model):
        if model.actuator.magnetization_only:
            raise ValueError("this model is a material's (fitted to M or B, saved without "
                             "an actuator): it has no structure whose displacement could "
                             "follow a reference; give it an actuator, e.g. jaxhyst.Model("
                             "model.params, jaxhyst.ACTUATOR1, model.variant), with the "
                             "actuator's own magnetostriction and structural parameters.")
        if jnp.ndim(model.params.Ms) != 0:
            raise ValueError("compensate needs one parameter set; this model holds one per "
                             "loop (a joint fit): pick one, e.g. with jaxhyst.Model(params="
                             "jax.tree.map(lambda x: x[0], model.params), …).")
        return model
    raise TypeError(f"model must be a jaxhyst.Model (parameters, actuator, form); got "
                    f"{type(model).__name__}. Build one: jaxhyst.Model(params, actuator).")


def compensate(model: Model, reference: Reference, *, current_limit=None,
               slew_limit=None, refine: bool = True, tolerance: float = 1e-6,
               max_steps: int = 100, progress=False) -> Compensation:
    """The input that makes ``model`` follow ``reference``.

    **Arguments:**
    - ``model``: a `jaxhyst.Model` (identified parameters, actuator, Jiles–Atherton form,
      substeps, losses) — e.g. ``jaxhyst.Model(jh.TABLE3[800], jh.ACTUATOR2)``.
    - ``reference``: a `jaxhyst.control.Reference` (`sinusoidal_reference`,
      `multitone_reference`, `reference_from_record`).
    - ``current_limit``: a positive number L (|u| ≤ L) or a pair (lower, upper), in A of
      coil current — or A/m of AC field for an actuator without turns per metre
      (Actuator2). None: no limit (the range the refinement may use is derived from the
      inverse model and said so).
    - ``slew_limit``: the largest |du/dt| (A/s, or A/m per s), or None.
    - ``refine``: refine the inverse model's input through the forward model (default).
    - ``tolerance``: the refinement stops once the rms tracking error is at most this
      fraction of the reference's peak-to-peak (default 1e-6, below the model's own
      accuracy; 0: until Levenberg–Marquardt converges), or after ``max_steps``.
    - ``progress``: True or a `jaxhyst.progress` meter: a line per stage.

    A new value of a limit, the frequency, ``tolerance`` or ``max_steps`` is data:
    nothing compiles again. A reference of a new length, a slew limit added or removed,
    or a model of another form or substeps compiles its programs.

    **Returns:** a `Compensation`. Every input sample lies inside the limits. Warns
    (`UnreachableWarning`) where the reference asks for more than the actuator can do:
    ``result.unreachable`` says where and why; the input there is the best the limits
    allow. Raises ``ValueError`` (one line) for a reference sampled too coarsely for the
    model's accuracy or bad limits.
    """
    started = time.perf_counter()
    model = _model_of(model)
    if not (isinstance(tolerance, (int, float)) and np.isfinite(tolerance)
            and tolerance >= 0):
        raise ValueError(f"tolerance must be a number >= 0 (an rms error relative to the "
                         f"reference's peak-to-peak); got {tolerance!r}.")
    if isinstance(max_steps, bool) or not isinstance(max_steps, (int, np.integer)) \
            or max_steps < 1:
        raise ValueError(f"max_steps must be an integer >= 1; got {max_steps!r}.")
    if not isinstance(reference, Reference):
        raise TypeError(f"reference must be a jaxhyst.control.Reference (from "
                        f"sinusoidal_reference, multitone_reference or reference_from_record); "
                        f"got {type(reference).__name__}.")
    gain, unit = input_gain(model)
    limits = None if current_limit is None else InputLimits.of(current_limit, slew_limit,
                                                                unit=unit)
    if current_limit is None and slew_limit is not None:
        InputLimits.of(1.0, slew_limit, unit=unit)  # (checks the slew limit alone)
    if refine and reference.n_samples > MAX_REFINED:
        raise ValueError(f"the reference has {reference.n_samples} samples; the refinement "
                         f"takes at most {MAX_REFINED} at once (split the record, or pass "
                         "refine=False for the inverse model alone).")
    tracking = Tracking.of(model, reference)
    # (the inverse path's and the settling check's programs compile in threads of their
    # own while the reach is swept: their shapes are the reference's)
    early = [meanwhile(lambda: compile_field(tracking, reference), wait=0.0)]
    if reference.periodic:
        early.append(meanwhile(lambda: compile_settling(tracking), wait=0.0))
    try:
        reach_ = reach(model, limits, gain)
    finally:
        for job in early:
            if job is not None:
                job.join()
    inverse = inverse_input(tracking, reference, reach_)
    if limits is None:  # the range the optimiser may use: the inverse's, widened
        lo, hi = float(inverse.u.min()), float(inverse.u.max())
        pad = 0.5 * max(hi - lo, abs(hi), abs(lo), 1e-12)
        limits = InputLimits(lo - pad, hi + pad, None if slew_limit is None else
                             float(slew_limit), given=False)
    imap = InputMap(limits, reference.n_samples, reference.dt, reference.periodic)
    u_inverse = imap.input_values(imap.coordinates(inverse.u))
    settled = 0.0
    if reference.periodic:
        periods, settled = settling_periods(tracking, u_inverse)
        tracking = tracking.with_run_in(periods)
    p = model.params
    found = unreachable(reach_, reference.t, reference.displacement, inverse.lam,
                        inverse.u, limits, reference.dt, unit, reference.periodic,
                        2.0 * float(p.Mz) / max(float(p.Cz), 1e-300))
    r = np.asarray(reference.displacement)
    residuals = TrackingResiduals(tracking, imap, jnp.asarray(r), jnp.asarray(reference.scale))
    background = _compile_refinement(residuals, imap.coordinates(u_inverse), max_steps) \
        if refine and tolerance < INVERSE_TYPICAL else None
    try:  # (the refinement's program compiles meanwhile, until it is needed)
        if not found:  # (beyond the actuator, the inverse input is no test of the sampling)
            _check_accuracy(tracking, u_inverse, reference.scale)
        meter = progress_meter(progress)  # (after the checks: a bad input gets one line)
        state = meter.init("compensate", None)
        if found:
            warnings.warn(f"part of the reference is beyond the actuator: {found[0]}"
                          + (f" (and {len(found) - 1} more)" if len(found) > 1 else ""),
                          UnreachableWarning, stacklevel=2)
        state = meter.step(state, 1, f"inverse model done ({len(found)} unreachable "
                                     f"stretches); run-in {tracking.run_in_periods} periods")
        u_plain = _uncompensated(tracking, reference, limits, u_inverse)
        y_inverse = evaluate(tracking, u_inverse)
    finally:
        if background is not None:
            background.join()
    steps, outcome, u = 0, "not refined", u_inverse
    if refine and rms_error(y_inverse, r, reference.scale) <= tolerance:
        outcome = "successful"  # (the inverse model alone is within the tolerance)
    elif refine:
        state = meter.step(state, 2, f"refining {reference.n_samples} input samples")
        target = r.shape[0] * (tolerance / RESIDUAL_UNIT) ** 2
        z, steps, outcome = refine_input(residuals, imap.coordinates(u_inverse),
                                         int(max_steps), float(target))
        u = imap.input_values(z)
    y, y_plain = evaluate(tracking, u), evaluate(tracking, u_plain)
    if settled > 1e-6:
        warnings.warn(f"the model's magnetization still moves by {settled:.2g}·Ms per "
                      f"period after {tracking.run_in_periods} run-in periods; the "
                      "predicted steady state is that far from settled.", SettlingWarning,
                      stacklevel=2)
    result = Compensation(
        reference=reference, input=u, displacement=y, unit=unit, limits=limits,
        inverse_input=u_inverse, inverse_displacement=y_inverse,
        uncompensated_input=u_plain, uncompensated_displacement=y_plain, reach=reach_,
        unreachable=tuple(found), steps=steps, outcome=outcome,
        seconds=time.perf_counter() - started, run_in_periods=tracking.run_in_periods,
        settled=settled, gain=gain, bias=float(model.actuator.Hb),
        fine_error=rms_error(evaluate(_finer(tracking), u), r, reference.scale))
    meter.close(state, f"rms error {result.error:.3e} of the peak-to-peak "
                       f"(uncompensated {result.uncompensated_error:.3e})")
    return result
