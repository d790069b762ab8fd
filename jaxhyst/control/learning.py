"""Iterative learning control on the real actuator, with the model as its guide — and
never trusted further than the plant's measurements bear it out.

Over repeated periods (or repeated runs of a record) the displacement is measured and the
input corrected by a model-based (Newton-type) step inside a **trust region** that the
measurements steer:

    δz = γ·argmin_least-norm ‖J·δz − Q·e‖,   z_next = z + Q·δz,

with e = r − y_measured at the best input so far, J the model's Jacobian of the
displacement with respect to the input coordinates z (`jaxhyst.control.limits.InputMap`:
every input is inside the current and slew-rate limits), γ ∈ (0, 1] the step factor and
Q a zero-phase low-pass **robustness filter** that keeps learning to the band [0, f_c]
where the model is trusted (Longman, Int. J. Control 73 (2000) 930). The step is the
least-squares solution itself (singular values below `learning_step.RCOND` of the
largest cut), not a damped one: a hysteretic model's most sensitive input directions are
rough (a perturbation at one sample moves the magnetization from there on), so damping
would keep mostly those, while the exact step for a smooth error is smooth — which is why
the error is filtered first: the measurement noise beyond the band never reaches the step.

- **The measurement steers the step.** The first step learns below `FIRST_BAND` of the
  Nyquist frequency. A step whose measured error is not higher than the one before
  (beyond the noise) is accepted; when the error fell by at least 3/4 of the fall the
  model predicted, the step factor γ grows (×1.5, to 1) and the band f_c doubles (up to
  the Nyquist frequency, or half the band of the last undone step); by
  less than 1/4, γ halves. A step after which the error *rose* is undone (the next input
  is built from the best one): where the measured error departs most from the model's
  prediction at twice the reference's fundamental or above (an unmodelled mode shows
  there), the band narrows to half that frequency; where it departs most at the
  fundamental itself (the step was too large for a model that is off), γ halves and the
  band halves no lower than twice the fundamental; the report says where the model is
  no longer trusted.
- **Noise.** The measurement noise σ is estimated from repeated measurements of the same
  input (their scatter) or from the upper half of the error's spectrum (where a tracking
  error has little power); repeated measurements are averaged. Learning stops at the
  noise floor (the measured error within 1.5σ): further steps would learn the noise.
- **Delay.** The lag of the measured displacement behind the model's prediction is
  found by cross-correlation; whole samples of it are corrected (the record shifted
  back) and reported, or refused with the shift named (``delay="refuse"``). The delay
  found at the first measurement is held (an acquisition's does not change; a later lag
  is the plant's phase). A lead is the plant's phase, never a delay. A small lag is
  ambiguous: a plant 10 % off the model lags or leads it by up to ~1.5 samples at 200
  per period, and such a lag corrected as a delay leaves the plant tracking a shifted
  reference. A lag under `signals.AMBIGUOUS_PHASE` (5° at the fundamental), or under
  what the model lags by itself with its parameters 10 % off (`learning_step.own_lag`:
  several samples near a structural resonance), is taken for a
  delay only where shifting the record back explains its departure from the model
  (`signals.delay_explained`); else it is learned as the plant's phase, and the first
  report and the stop name it. Where the acquisition's delay is known, give it
  (``delay=0``, ``3`` …): it is then corrected exactly and every lag beyond it is the
  plant's phase.
- **Phase.** The lag left between plant and model (after any delay) is a phase error
  growing with frequency; learning is limited to the band where it stays below
  `PHASE_MARGIN` (π/3; learning diverges beyond π/2).
- **Step size.** A step is no larger, per unit of measured error, than `REACH_GROWTH`
  (1.25) times the largest step per unit of error after which the error fell as the
  model predicted — within `NEAR_FLOOR` (8) times the noise, no larger than that step
  itself: a linearisation is not trusted farther than the plant has followed it
  (``state.reach``; halved with an undone step). The first step is the model's own,
  held to `FIRST_REACH` (2) times the input change an error needs at the drive's mean
  gain.
- **The model checks its own step.** A hysteretic model is not smooth at its
  reversals, so a least-squares step shaped around them can undo itself on the model as
  on the plant. A step's effect is simulated on the model, not only linearised: where
  the simulated error falls by less than half the fall the linearisation predicts, the
  step is halved (up to three times; the length simulated best is taken), and the error
  predicted is the simulated one (`jaxhyst.control.learning_step`). A fall predicted
  within the noise of the error is not judged (it neither grows nor shrinks the steps).
- **Convergence and stalls.** Learning stops when the model predicts no fall larger
  than the noise (within its band: what is left lies where it is not trusted) — not
  even its linearisation, the most it promises: a step the simulation bears out only
  in part is still taken, shortened, and the plant's measurement decides; one the
  simulation says would raise the error is never taken — after
  three undone steps in a row, or with a band below the reference's fundamental, and
  says where it stopped trusting the model, and where the input sits on its limits
  (what is left may be beyond the actuator's reach).

Use: ``learner = IterativeLearning.of(model, reference, current_limit=…)``; ``state =
learner.init()``; then repeatedly apply ``state.input``, measure the displacement at the
reference's samples (steady state; several periods: shape (R, N)), ``state =
learner.step(state, measured)``; ``state.stopped`` says why it stopped, ``state.reports``
what each step did.
"""

from __future__ import annotations

import dataclasses

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from ..saved import Model
from .compensate import Compensation, compensate, rms_error
from .learning_state import LearningReport, LearningState
from .learning_step import learning_step, mispredicted, own_lag
from .limits import InputMap
from .reference import Reference
from .refine import TrackingResiduals
from .signals import (
    DELAY_THRESHOLD,
    ambiguous,
    automatic_delay,
    delay_note,
    estimate_delay,
    noise_level,
    shift_back,
)
from .tracking import Tracking, evaluate

#: The step factor γ's smallest value (a step is shortened no further).
MIN_FACTOR = 1.0 / 64
#: Undone steps in a row after which learning stops.
MAX_REJECTED = 3
#: Learning stops once the measured error is within this multiple of the noise.
NOISE_FLOOR = 1.5
#: A step whose error fell as predicted lets the next steps be this many times as large
#: per unit of error (`LearningState.reach`).
REACH_GROWTH = 1.25
#: … but not within this multiple of the noise (there a step that outgrew what the
#: plant followed made the measured error rise by more than σ: benchmarks/RESULTS.md).
NEAR_FLOOR = 8.0
#: The largest first step per unit of error (its rms input change over the input's
#: swing, over the rms error over the stroke): a drive of gain stroke/swing needs 1; the
#: model's own first steps on plants 10 % off lie at 0.6–0.95 (benchmarks/RESULTS.md).
FIRST_REACH = 2.0
#: The first step's band over the Nyquist frequency (Nyquist-wide first steps raised the
#: error of plants 10 % off by more than the noise: benchmarks/RESULTS.md).
FIRST_BAND = 0.25
#: The phase error (radians) the model may have at the top of the learning band: the
#: band ends where the lag between plant and model found at the fundamental would turn
#: the phase by this much (learning diverges beyond π/2).
PHASE_MARGIN = np.pi / 3


def _borne_out(reach, ratio, growth):
    """The step per unit of error borne out once a step of ``ratio`` (None: unknown, a
    state written before it was kept) was followed: the larger of ``reach`` (None: none
    yet) and ``growth`` × ``ratio``."""
    if ratio is None:
        return reach
    return growth * ratio if reach is None else max(reach, growth * ratio)


class DelayError(ValueError):
    """The measured record is shifted against the input (``delay="refuse"``)."""


class IterativeLearning(eqx.Module):
    """Iterative learning control guided by the model (see the module docstring).

    Build it with `of` (which runs `compensate` on the model for the first input).
    ``gain``: a factor (0, 1] on every step (1: the full step; the trust region shortens
    steps by itself). ``delay``: ``"correct"`` (default) or ``"refuse"`` a measured record
    shifted against the input, or the acquisition's delay in whole samples where it is
    known (0: none; then no other shift is made). ``noise``: the sensor's noise σ over
    the reference's peak-to-peak where it is known (0: a noise-free measurement), else
    None: estimated from each measurement."""

    compensation: Compensation
    residuals: TrackingResiduals
    gain: float = eqx.field(static=True, default=1.0)
    delay: str | int = eqx.field(static=True, default="correct")
    noise: float | None = eqx.field(static=True, default=None)

    @classmethod
    def of(cls, model: Model, reference: Reference, *, current_limit=None,
           slew_limit=None, gain: float = 1.0, delay: str | int = "correct",
           noise: float | None = None, **options) -> IterativeLearning:
        """The learning controller of ``model`` for ``reference``; the limits and
        ``options`` are those of `compensate`."""
        g = float(gain)
        if not (np.isfinite(g) and 0 < g <= 1):
            raise ValueError(f"the learning gain must lie in (0, 1]; got {gain!r}.")
        if isinstance(delay, (int, np.integer)) and not isinstance(delay, bool):
            if not 0 <= int(delay) < reference.n_samples:
                raise ValueError(f"delay = {delay}: a known acquisition delay is a whole "
                                 f"number of samples in [0, {reference.n_samples}).")
            delay = int(delay)
        elif delay not in ("correct", "refuse"):
            raise ValueError(f"delay must be 'correct', 'refuse' or the acquisition's delay "
                             f"in whole samples (0: none); got {delay!r}.")
        if noise is not None and not (np.isfinite(noise) and noise >= 0):
            raise ValueError(f"noise must be None (estimated) or a number >= 0 (σ over the "
                             f"reference's peak-to-peak); got {noise!r}.")
        comp = compensate(model, reference, current_limit=current_limit,
                          slew_limit=slew_limit, **options)
        tracking = Tracking.of(model, reference, comp.run_in_periods)
        imap = InputMap(comp.limits, reference.n_samples, reference.dt, reference.periodic)
        residuals = TrackingResiduals(tracking, imap, jnp.asarray(reference.displacement),
                                      jnp.asarray(reference.scale))
        return cls(comp, residuals, g, delay, None if noise is None else float(noise))

    @property
    def reference(self) -> Reference:
        return self.compensation.reference

    def initial_band(self) -> float:
        """f_c of the first step (Hz): `FIRST_BAND` of the Nyquist frequency."""
        return FIRST_BAND * 0.5 / self.reference.dt

    def init(self) -> LearningState:
        """The state before the first measurement: the model's compensating input."""
        return self.state_for(self.compensation.input)

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
        return LearningState(z=z, input=imap.input_values(z), iteration=0,
                             errors=(), band=self.initial_band())

    def predict(self, state: LearningState) -> np.ndarray:
        """The model's displacement (m) for ``state.input``."""
        return evaluate(self.residuals.tracking, state.input)

    def _measurement(self, state, measured):
        """(the measurement averaged over repeats and shifted back by its delay, the
        delay corrected, σ (m), the lag found, the lag the plant may show by itself where
        it was needed: `learning_step.own_lag`, else 0)."""
        y = np.asarray(measured, dtype=np.float64)
        N = self.reference.n_samples
        if y.shape[-1:] != (N,) or y.ndim not in (1, 2):
            raise ValueError(f"the measured displacement must have one value per reference "
                             f"sample ({N}), or repeats of it (R, {N}); got shape {y.shape}.")
        if not np.all(np.isfinite(y)):
            bad = np.flatnonzero(~np.isfinite(y.reshape(-1)))[:5].tolist()
            raise ValueError(f"the measured displacement is NaN or infinite at samples "
                             f"{bad}; repair the measurement.")
        periodic, r = self.reference.periodic, np.asarray(self.reference.displacement)

        def mean_and_sigma(y):  # (σ of the measurements' average)
            mean = y.mean(axis=0) if y.ndim == 2 else y
            sigma = self.noise * self.reference.scale if self.noise is not None else \
                noise_level(y, r - mean)
            return mean, sigma / np.sqrt(y.shape[0] if y.ndim == 2 else 1)

        mean, sigma = mean_and_sigma(y)
        predicted, own = self.predict(state), 0.0
        found = estimate_delay(mean, predicted, periodic)
        # (a measurement can only be late: one that leads the prediction shows the
        # plant's phase differing from the model's, which learning absorbs)
        if isinstance(self.delay, int):  # (the acquisition's delay, known)
            lag = self.delay
        elif self.delay == "correct" and state.reports:
            # (a delay is the acquisition's, the same at every measurement: the one found
            # at the first is held; a lag found later is the plant's phase at that input)
            lag = state.reports[0].delay
        else:  # (the first measurement: a lag beyond 5° may still be the plant's own)
            own = own_lag(self.residuals.tracking, state.input, predicted, periodic) if \
                found >= DELAY_THRESHOLD and not ambiguous(found, N) else 0.0
            lag = automatic_delay(mean, predicted, found, sigma, periodic, own)
        if lag and self.delay == "refuse":
            raise DelayError(f"the measured displacement lags the input by {lag} samples "
                             f"({lag * self.reference.dt:.3g} s): shift it back (or let "
                             "learning correct it: delay='correct').")
        if lag:
            y = shift_back(y, lag, periodic)
            mean, sigma = mean_and_sigma(y)
        return mean, lag, sigma, found, own

    def _limit_note(self, z) -> str:
        """What a stop adds where the input of ``z`` sits on its limits (within 0.1 %
        of their range): the error left may be beyond the actuator's reach."""
        u = self.residuals.imap.input_values(z)
        lo, hi = (float(v) for v in (self.compensation.limits.lower,
                                      self.compensation.limits.upper))
        at = int(np.sum((u <= lo + 1e-3 * (hi - lo)) | (u >= hi - 1e-3 * (hi - lo))))
        if not at:
            return ""
        return (f"; the input sits on its limits [{lo:.4g}, {hi:.4g}] at {at} of its "
                f"{u.shape[0]} samples: what is left may be beyond the actuator's reach "
                "(compensate on a model of it says how far)")

    def _alignment_note(self, state: LearningState, lag: int, found: float,
                        own: float) -> str:
        """What a stop adds where the first measurement's lag was one a plant a little
        off the model could show by itself (empty otherwise)."""
        if isinstance(self.delay, int):  # (given: nothing was assumed)
            return ""
        first = state.reports[0] if state.reports else None
        return delay_note(*((lag, found) if first is None else (first.delay, first.lag)),
                          self.reference.n_samples, stop=True,
                          own=own if first is None else first.own_lag)

    def step(self, state: LearningState, measured) -> LearningState:
        """The next state, from the displacement ``measured`` (m, shape (N,) or (R, N):
        at the reference's samples, with ``state.input`` applied)."""
        if state.stopped is not None:
            raise ValueError(f"learning has stopped ({state.stopped}); start again with "
                             "init() or state_for(input) to go on.")
        y, lag, sigma, found, own = self._measurement(state, measured)
        ref = self.reference
        r, scale = np.asarray(ref.displacement), ref.scale
        e = r - y
        error, noise = rms_error(y, r, scale), sigma / scale
        factor, band, rejected, limit = state.factor, state.band, state.rejected, \
            state.band_limit
        reach = state.reach
        nyquist = 0.5 / ref.dt
        fundamental = 1.0 / (ref.n_samples * ref.dt)
        margin = 2.0 * noise / np.sqrt(ref.n_samples) + 1e-3 * (state.best_error or error)
        if state.best_error is None or error <= state.best_error + margin:
            action = "accepted"
            fell = None if state.best_error is None else state.best_error - error
            expected = None if state.predicted is None or state.best_error is None else \
                state.best_error - state.predicted
            ratio = None if fell is None or not expected else fell / expected
            if ratio is None:
                why = "the first measurement" if fell is None else "no change predicted"
            elif expected <= margin and fell <= margin:  # (the noise hides the fall)
                why = "the fall predicted lay within the noise of the error: not judged"
            elif ratio >= 0.75:
                why = f"the error fell as predicted ({ratio:.2g} of the predicted fall)"
                factor, band = min(1.5 * factor, 1.0), min(2.0 * band, limit, nyquist)
                # (near the noise floor a step is not let outgrow what the plant followed)
                reach = _borne_out(reach, state.step_ratio, REACH_GROWTH
                                   if error > NEAR_FLOOR * noise else 1.0)
            elif ratio >= 0.25:
                why = f"the error fell {ratio:.2g} of the predicted fall"
                reach = _borne_out(reach, state.step_ratio, 1.0)
            else:
                factor = max(0.5 * factor, MIN_FACTOR)
                reach = reach if state.step_ratio is None else 0.5 * state.step_ratio
                why = (f"the error fell only {ratio:.2g} of the predicted fall: steps "
                       "halved")
            best_z, best_error, best_e, rejected = state.z, error, e, 0
        else:
            action, rejected = "undone", rejected + 1
            if state.step_ratio is not None:
                reach = 0.5 * state.step_ratio
            failed = mispredicted(e, state.predicted_e, ref.dt)
            if failed is not None and failed >= 2.0 * fundamental and 0.5 * failed < band:
                band = 0.5 * failed
                where = (f"it mispredicted the plant most at {failed:.4g} Hz: the model "
                         f"trusted only below {band:.4g} Hz")
            else:  # (mispredicted at the reference's own frequency: a step too large)
                factor = max(0.5 * factor, MIN_FACTOR)
                band = min(band, max(0.5 * band, 2.0 * fundamental))
                where = f"steps halved, the model trusted only below {band:.4g} Hz"
            limit = band
            why = (f"the error rose from {state.best_error:.3e} to {error:.3e}: back to the "
                   f"best input; {where}")
            best_z, best_error, best_e = state.best_z, state.best_error, state.best_e
        if not isinstance(self.delay, int) and not state.reports:
            why += delay_note(lag, found, ref.n_samples, stop=False, own=own)
        errors = (*state.errors, error)
        stop = None
        if best_error <= NOISE_FLOOR * noise or best_error == 0:
            stop = f"at the noise floor (error {best_error:.3e}, noise {noise:.2e})"
        elif rejected >= MAX_REJECTED:
            stop = (f"stalled: {rejected} steps in a row made it worse; the model is not "
                    f"trusted above {band:.4g} Hz")
        elif band < fundamental:
            stop = (f"stalled: the model is trusted only below {band:.4g} Hz, under the "
                    f"reference's fundamental {fundamental:.4g} Hz")
        iteration = state.iteration + 1
        if stop is not None:
            if stop.startswith("stalled"):
                stop += self._limit_note(best_z)
            stop += self._alignment_note(state, lag, found, own)
            report = LearningReport(iteration, error, noise, lag, found, "stopped", stop, None,
                                    0.0, factor, band, own)
            imap = self.residuals.imap
            return dataclasses.replace(
                state, z=best_z, input=imap.input_values(best_z),
                iteration=iteration, errors=errors, reports=(*state.reports, report),
                stopped=stop, best_z=best_z, best_error=best_error, best_e=best_e,
                factor=factor, band=band, rejected=rejected, predicted=None, band_limit=limit)
        if abs(found - lag) >= 0.25:  # (the phase the model misses, as a time lag)
            phased = PHASE_MARGIN / (2 * np.pi * abs(found - lag) * ref.dt)
            if phased < band:
                band, limit = phased, min(limit, phased)
                why += (f"; the plant's lag against the model ({found - lag:+.2f} samples) "
                        f"limits learning to {band:.4g} Hz")
        cap = FIRST_REACH if reach is None else reach
        z, step, predicted, predicted_e, halved, held, linear = learning_step(
            self.residuals, best_z, best_e, factor=factor * self.gain, band=band,
            sigma=noise * ref.scale, reach=cap, error=best_error)
        if held:
            why += (f"; the step held to {reach:.3g}× the error (the largest step per unit "
                    "of error the plant has borne out)" if reach is not None else
                    f"; the step held to {FIRST_REACH:.3g}× the error (before any step was "
                    "measured: twice the input change an error needs at the drive's mean "
                    "gain)")
        if halved:
            why += (f"; the step shortened to 1/{2**halved}: the model itself, simulated, "
                    "did not bear out its linear prediction for a longer one")
        # (stop where not even the linearisation promises a fall above the noise, or
        # where the model, simulated, says the step would raise the error)
        if action == "accepted" and best_error - linear <= margin or predicted >= best_error:
            stop = (f"converged in the band below {band:.4g} Hz: the model predicts no fall "
                    f"of the error larger than the noise"
                    + ("" if band >= nyquist else " (what is left lies where it is not "
                       "trusted)") + self._limit_note(best_z)
                    + self._alignment_note(state, lag, found, own))
            report = LearningReport(iteration, error, noise, lag, found, "stopped", stop,
                                    None, 0.0, factor, band, own)
            return dataclasses.replace(
                state, z=best_z, input=self.residuals.imap.input_values(best_z),
                iteration=iteration, errors=errors,
                reports=(*state.reports, report), stopped=stop, best_z=best_z,
                best_error=best_error, best_e=best_e, factor=factor, band=band,
                rejected=rejected, predicted=None, band_limit=limit)
        report = LearningReport(iteration, error, noise, lag, found, action, why, predicted,
                                step, factor, band, own)
        return LearningState(z=z, input=self.residuals.imap.input_values(z),
                             iteration=iteration, errors=errors,
                             reports=(*state.reports, report), stopped=None, best_z=best_z,
                             best_error=best_error, best_e=best_e, factor=factor,
                             band=band, rejected=rejected, predicted=predicted,
                             band_limit=limit, predicted_e=predicted_e, reach=reach,
                             step_ratio=step / max(best_error, 1e-300))
