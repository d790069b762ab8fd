"""One step of iterative learning from the model (`jaxhyst.control.learning`): the
least-squares step in the trusted band, held to the reach the plant has borne out, then
**checked on the model itself** — the step's effect simulated, not only linearised — and
shortened where the model does not bear out its own linear prediction. NumPy on the host
around two compiled programs (the Jacobian, the tracking simulation)."""

from __future__ import annotations

from typing import NamedTuple

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._traces import kept_jit
from ..params import Parameters
from .refine import RESIDUAL_UNIT, TrackingResiduals
from .signals import estimate_delay, low_pass
from .tracking import Tracking, evaluate

#: Singular values of J below this fraction of the largest are cut from a learning step.
RCOND = 1e-10
#: A step is kept where the model, simulated, falls by at least this fraction of the fall
#: its linearisation predicts; else it is halved (at most `HALVINGS` times) and the
#: length whose simulated error is lowest is taken.
BORNE_OUT = 0.5
HALVINGS = 3
#: The relative parameter error of a plant "a little off the model" (`own_lag`).
OFF = 0.1


class Step(NamedTuple):
    """A learning step: the next coordinates ``z``; its rms input change over the
    input's swing (``size``); the error the model predicts after it (rms over the
    peak-to-peak, ``predicted``; per sample in m, ``predicted_e``); the halvings the
    model's own check took (``halved``); whether the reach held the step before them
    (``held``); the error the linearisation predicts after the step before them
    (``linear``, rms over the peak-to-peak: the most the model promises)."""

    z: np.ndarray
    size: float
    predicted: float
    predicted_e: np.ndarray
    halved: int
    held: bool
    linear: float


@kept_jit
def _jacobian(residuals: TrackingResiduals, z):
    return jax.jacfwd(lambda z: residuals(z)[: residuals.r.shape[0]])(z)


def learning_step(residuals: TrackingResiduals, z, e, *, factor: float, band: float,
                  sigma: float, reach: float | None = None, error: float | None = None
                  ) -> Step:
    """The step from coordinates ``z`` with measured error e (m, (N,)) there, noise σ
    (m), step factor γ (``factor``) and the band (Hz) of the robustness filter: the
    least-squares solution of J·δz = Q·e (`RCOND`), times γ; no larger than ``reach``
    × the rms ``error`` (over the peak-to-peak) in input change over the swing; then
    the model simulated at z + δz: where it falls by less than `BORNE_OUT` of the fall
    J·δz predicts (a hysteretic model is not smooth at its reversals, so a step shaped
    around them can undo itself), δz is halved, up to `HALVINGS` times, and the length
    with the lowest simulated error is taken, its simulated error the prediction; the
    linear prediction of the step before the halvings is kept beside it."""
    imap, tracking = residuals.imap, residuals.tracking
    ref_scale, dt = float(residuals.scale), float(imap.dt)
    unit = ref_scale * RESIDUAL_UNIT
    J = np.asarray(_jacobian(residuals, jnp.asarray(z)))  # (residual units per z)
    target = low_pass(e, dt, band, sigma) / unit
    dz = factor * np.linalg.lstsq(J, target, rcond=RCOND)[0]
    u = imap.input_values(z)
    swing = max(float(np.ptp(u)), 1e-300)
    u_next = imap.input_values(z + dz)
    held = False
    for _ in range(2 if reach is not None else 0):  # (the map to the input bends)
        s = np.sqrt(np.mean((u_next - u) ** 2))
        if s <= reach * error * swing:
            break
        dz, held = dz * (reach * error * swing / s), True
        u_next = imap.input_values(z + dz)
    promised = float(np.sqrt(np.mean((e - unit * (J @ dz)) ** 2)))
    y0 = evaluate(tracking, u)
    now, best = float(np.sqrt(np.mean(e**2))), None
    for halved in range(HALVINGS + 1):
        linear = float(np.sqrt(np.mean((e - unit * (J @ dz)) ** 2)))
        u_next = imap.input_values(z + dz)
        simulated_e = e - (evaluate(tracking, u_next) - y0)
        simulated = float(np.sqrt(np.mean(simulated_e**2)))
        if best is None or simulated < best[0]:
            best = (simulated, z + dz, u_next, simulated_e, halved)
        if now - simulated >= BORNE_OUT * (now - linear):
            break
        dz = 0.5 * dz
    simulated, z_next, u_next, simulated_e, halved = best
    return Step(z_next, float(np.sqrt(np.mean((u_next - u) ** 2)) / swing),
                simulated / ref_scale, simulated_e, halved, held, promised / ref_scale)


def mispredicted(e, predicted_e, dt: float) -> float | None:
    """The lowest frequency (Hz) where the measured error e after a step departs from
    the model's prediction by at least half the largest departure: where the model
    failed (an unmodelled mode); None without a prediction."""
    if predicted_e is None:
        return None
    D = np.abs(np.fft.rfft(e - predicted_e))
    D[0] = 0.0
    f = np.fft.rfftfreq(e.shape[0], dt)
    if not D.max() > 0:
        return None
    return float(f[np.flatnonzero(D >= 0.5 * D.max())[0]])


def own_lag(tracking: Tracking, u, predicted, periodic: bool) -> float:
    """The lag (samples) a plant whose parameters are all `OFF` off the model's may show
    behind the model's displacement ``predicted`` (m, (N,): `evaluate` of ``tracking``
    for the input u, which the caller has) by itself, to first order: the sum
    over the model's ten parameters of the lag of its record with that one parameter
    `OFF` higher. Ten simulations (parameters are data: nothing compiles); large near a
    structural resonance, ~1.5 samples at 200 a period far below it."""
    model = tracking.model
    x = np.asarray(model.params.to_array())
    total = 0.0
    for j in range(x.shape[-1]):
        off = x.copy()
        off[..., j] *= 1.0 + OFF
        moved = eqx.tree_at(lambda t: t.model.params, tracking, Parameters.from_array(off))
        total += abs(estimate_delay(evaluate(moved, u), predicted, periodic))
    return total
