"""What iterative learning carries from one measurement to the next, and what each step
reports (`jaxhyst.control.learning`): the state, its JSON form for the command line, and
the per-step report."""

from __future__ import annotations

import dataclasses

import numpy as np


@dataclasses.dataclass(frozen=True)
class LearningReport:
    """What one learning step did: the ``iteration``; the measured rms ``error`` and the
    noise σ estimated (both relative to the reference's peak-to-peak); the ``delay``
    corrected (whole samples) and the ``lag`` found (samples, > 0: the measurement late
    against the model's prediction); the ``action`` (``accepted``, ``undone``,
    ``stopped``) and why; the error the model ``predicted`` for the next input (its
    simulation of the step, not the linearisation); the ``step`` taken (rms change of
    the input over its swing); the step ``factor`` γ and the learning ``band`` (Hz) it
    used; at the first measurement, the lag (samples) a plant 10 % off the model may show
    by itself where it was needed to judge a lag beyond 5° (``own_lag``, else 0)."""

    iteration: int
    error: float
    noise: float
    delay: int
    lag: float
    action: str
    reason: str
    predicted: float | None
    step: float
    factor: float
    band: float
    own_lag: float = 0.0

    def __str__(self) -> str:
        pred = "" if self.predicted is None else f", predicted next {self.predicted:.3e}"
        delay = (f", delay {self.delay:+d} samples corrected" if self.delay else
                 f", the plant leads the model by {-self.lag:.2f} samples (its phase: "
                 "not an acquisition delay)" if self.lag <= -0.25 else
                 f", lag {self.lag:+.2f} samples" if self.lag >= 0.25 else "")
        return (f"iteration {self.iteration}: measured error {self.error:.3e} (noise "
                f"{self.noise:.2e}){delay}; {self.action}: {self.reason}; step "
                f"{self.step:.2e}{pred}; factor {self.factor:.3g}, band {self.band:.4g} Hz")


@dataclasses.dataclass(frozen=True)
class LearningState:
    """Where the learning stands: ``z`` the input coordinates and ``input`` (shape (N,),
    A or A/m) to apply next; ``iteration`` (0 before the first measurement); ``errors``:
    the measured rms error / peak-to-peak of each measurement; ``reports``: a
    `LearningReport` per step; ``stopped``: why learning stopped (None while it goes
    on). The rest is the trust region: the best input's coordinates ``best_z``, its
    error ``best_error`` and measured error signal ``best_e``, the step ``factor``, the
    learning ``band`` (Hz) and the band it may grow to (``band_limit``: half the band of
    the last undone step), the undone steps in a row ``rejected``, the largest step per
    unit of error the measurements have borne out (``reach``: the step's rms input change
    over its swing divided by the rms error it corrected; None before the first step was
    measured: unlimited) and that ratio of the step awaiting its measurement
    (``step_ratio``)."""

    z: np.ndarray
    input: np.ndarray
    iteration: int
    errors: tuple[float, ...]
    reports: tuple[LearningReport, ...] = ()
    stopped: str | None = None
    best_z: np.ndarray | None = None
    best_error: float | None = None
    best_e: np.ndarray | None = None
    factor: float = 1.0
    band: float = np.inf
    rejected: int = 0
    predicted: float | None = None
    band_limit: float = np.inf
    predicted_e: np.ndarray | None = None
    reach: float | None = None
    step_ratio: float | None = None


def state_to_dict(state: LearningState) -> dict:
    """A JSON-able form of ``state`` (to carry learning across runs of the command line)."""
    out = {}
    for f in dataclasses.fields(state):
        v = getattr(state, f.name)
        if isinstance(v, np.ndarray):
            v = v.tolist()
        elif f.name == "reports":
            v = [dataclasses.asdict(r) for r in v]
        elif isinstance(v, tuple):
            v = list(v)
        out[f.name] = v
    return out


def state_from_dict(d: dict, n: int) -> LearningState:
    """The `LearningState` written by `state_to_dict` (``n``: the reference's samples; a
    state of another reference is refused in one line)."""
    try:
        arrays = {k: None if d.get(k) is None else np.asarray(d[k], dtype=np.float64)
                  for k in ("z", "input", "best_z", "best_e", "predicted_e")}
        state = LearningState(
            z=arrays["z"], input=arrays["input"], iteration=int(d["iteration"]),
            errors=tuple(float(e) for e in d["errors"]),
            reports=tuple(LearningReport(**r) for r in d.get("reports", [])),
            stopped=d.get("stopped"), best_z=arrays["best_z"],
            best_error=None if d.get("best_error") is None else float(d["best_error"]),
            best_e=arrays["best_e"], factor=float(d["factor"]),
            band=np.inf if d.get("band") is None else float(d["band"]),
            rejected=int(d["rejected"]),
            predicted=None if d.get("predicted") is None else float(d["predicted"]),
            band_limit=np.inf if d.get("band_limit") is None else float(d["band_limit"]),
            predicted_e=arrays["predicted_e"],
            reach=None if d.get("reach") is None else float(d["reach"]),
            step_ratio=None if d.get("step_ratio") is None else float(d["step_ratio"]))
    except (KeyError, TypeError, ValueError) as err:
        raise ValueError(f"not a learning state ({type(err).__name__}: {err}).") from None
    if state.input.shape != (n,):
        raise ValueError(f"a learning state of {state.input.shape[0]} samples; the reference "
                         f"has {n}: it belongs to another reference.")
    return state
