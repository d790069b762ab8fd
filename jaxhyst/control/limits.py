"""Limits on the drive input, and inputs that respect them by construction.

The input u is the coil current (A) of an actuator with turns per metre n (H = n·u + Hb),
or the applied AC field (A/m) of one driven by a field (H = u + Hb, Actuator2). Its
limits are a range [lower, upper] and, optionally, a slew rate |du/dt| ≤ slew (unit/s).

`InputMap` writes every input the optimiser can reach as a smooth function of
unconstrained coordinates z, so that each iterate — not just the end point — is inside
the limits (no clipping after the fact):

- range: u = mid + half·sat(w), with ``sat`` the identity on [−(1 − ε), 1 − ε] and a
  tanh-shaped approach to ±1 in a band of width ε = 0.05 (1-Lipschitz, C¹, inside ±1;
  in floating point it reaches ±1 only for |w| beyond ~20): inputs well inside the range
  are represented without distortion;
- slew: the steps of w are bounded, w_{i+1} − w_i = (slew·dt/half)·sat(v_i) — and since
  u is a 1-Lipschitz function of w times half, |u_{i+1} − u_i| ≤ slew·dt. A periodic
  input closes its period: the steps are centred, g_i = (s_i − s̄)/(1 + ‖s̄‖) with
  s = sat(v), which keeps |g_i| < 1 and Σg = 0. (The drive is piecewise linear between
  samples, so the bound on the steps is the bound on du/dt.)
"""

from __future__ import annotations

import equinox as eqx
import jax.numpy as jnp
import numpy as np

from .._typing import Array, Float

#: The largest input limit accepted (A of current or A/m of field): a larger one is a unit
#: mistake (1e6 A of coil current, or 1e6 A/m, lies beyond any laboratory drive).
MAX_INPUT = 1e6
#: Width of the band in which `sat` approaches ±1.
BAND = 0.05
#: ‖s̄‖ = √(s̄² + η²): smooth at s̄ = 0.
_ETA = 1e-9
#: Weight of the residual that pins the mean step s̄ of a periodic slew map at 0 (the one
#: direction of z that moves no input).
MEAN_STEP_WEIGHT = 1e-3


def sat(x):
    """The identity on [−(1 − ε), 1 − ε], approaching ±1 as tanh outside (ε = `BAND`)."""
    inner = 1.0 - BAND
    magnitude = jnp.abs(x)
    outer = inner + BAND * jnp.tanh((magnitude - inner) / BAND)
    return jnp.where(magnitude <= inner, x, jnp.sign(x) * outer)


def sat_inverse(y: np.ndarray) -> np.ndarray:
    """The inverse of `sat` on (−1, 1) (host values; |y| is kept below 1 − 1e-9)."""
    inner = 1.0 - BAND
    y = np.clip(np.asarray(y, dtype=np.float64), -(1.0 - 1e-9), 1.0 - 1e-9)
    magnitude = np.abs(y)
    outer = inner + BAND * np.arctanh(np.clip((magnitude - inner) / BAND, 0.0, 1.0 - 1e-9))
    return np.where(magnitude <= inner, y, np.sign(y) * outer)


class InputLimits(eqx.Module):
    """The input's range [``lower``, ``upper``] (A, or A/m for a field-driven actuator)
    and its slew-rate limit ``slew`` (unit/s; None: none). Build it with `of`. The values
    are data (another limit compiles nothing); whether there is a slew limit is
    structure."""

    lower: Float[Array, ""]
    upper: Float[Array, ""]
    slew: Float[Array, ""] | None = None
    given: bool = eqx.field(static=True, default=True)  # False: derived, not the user's

    def __init__(self, lower, upper, slew=None, given: bool = True):
        self.lower = jnp.asarray(lower, dtype=jnp.float64)
        self.upper = jnp.asarray(upper, dtype=jnp.float64)
        self.slew = None if slew is None else jnp.asarray(slew, dtype=jnp.float64)
        self.given = bool(given)

    @classmethod
    def of(cls, limit, slew=None, *, unit: str = "A", given: bool = True) -> InputLimits:
        """``limit``: a positive number L (|u| ≤ L) or a pair (lower, upper); ``slew``: a
        positive number (unit/s) or None. Each bad value gets a one-line ValueError."""
        if np.ndim(limit) == 0:
            L = _positive(limit, "current limit", unit)
            lower, upper = -L, L
        else:
            values = np.asarray(limit, dtype=np.float64).ravel()
            if values.shape != (2,) or not np.all(np.isfinite(values)) \
                    or not values[0] < values[1]:
                raise ValueError(f"current limit must be a positive number L ({unit}, "
                                 f"|input| <= L) or a pair lower < upper; got {limit!r}.")
            lower, upper = float(values[0]), float(values[1])
        if slew is not None:
            slew = _positive(slew, "slew-rate limit", f"{unit}/s")
        if max(abs(float(lower)), abs(float(upper))) > MAX_INPUT:
            raise ValueError(f"current limit {max(abs(lower), abs(upper)):g} {unit} is beyond "
                             f"any laboratory drive (|input| <= {MAX_INPUT:g}); check its unit "
                             f"({unit}).")
        return cls(float(lower), float(upper), slew, given)

    @property
    def mid(self):
        return 0.5 * (self.lower + self.upper)

    @property
    def half(self):
        return 0.5 * (self.upper - self.lower)

    def describe(self, unit: str) -> str:
        text = f"[{float(self.lower):.4g}, {float(self.upper):.4g}] {unit}"
        if self.slew is not None:
            text += f", |d/dt| <= {float(self.slew):.4g} {unit}/s"
        return text + ("" if self.given else " (no limit given: derived from the inverse)")


def _positive(value, name: str, unit: str) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a positive number ({unit}); got {value!r}.") from None
    if not (np.isfinite(v) and v > 0):
        raise ValueError(f"{name} must be a positive number ({unit}); got {value!r}.")
    return v


class InputMap(eqx.Module):
    """The inputs u (shape (N,)) of N samples ``dt`` apart as a function of coordinates
    z (shape (`size`,)) that keeps every u inside ``limits`` (see the module docstring).
    ``periodic``: u is one period (its step from the last sample back to the first is
    bounded too)."""

    limits: InputLimits
    n: int = eqx.field(static=True)
    dt: Float[Array, ""]  # (data: a reference of another frequency compiles nothing)
    periodic: bool = eqx.field(static=True)

    def __init__(self, limits: InputLimits, n: int, dt, periodic: bool):
        self.limits, self.n, self.periodic = limits, int(n), bool(periodic)
        self.dt = jnp.asarray(dt, dtype=jnp.float64)

    @property
    def step(self):
        """The largest step of w per sample (slew·dt/half), or None without a slew limit."""
        if self.limits.slew is None:
            return None
        return self.limits.slew * self.dt / self.limits.half

    @property
    def size(self) -> int:
        if self.limits.slew is None:
            return self.n
        return self.n + 1 if self.periodic else self.n

    def _steps(self, z):
        """(w_0, the N − 1 steps of w (or N for a period), s̄)."""
        s = sat(z[1:])
        if not self.periodic:
            return z[0], self.step * s, jnp.zeros(())
        mean = jnp.mean(s)
        return z[0], self.step * (s - mean) / (1.0 + jnp.sqrt(mean**2 + _ETA**2)), mean

    def input(self, z: Float[Array, " n"]) -> Float[Array, " N"]:
        """u (A or A/m), shape (N,), at the coordinates z."""
        if self.step is None:
            w = z
        else:
            w0, steps, _ = self._steps(z)
            w = w0 + jnp.concatenate([jnp.zeros((1,), z.dtype), jnp.cumsum(steps)[: self.n - 1]])
        return self.limits.mid + self.limits.half * sat(w)

    def values(self, z) -> tuple[np.ndarray, np.ndarray]:
        """`input` and `extra_residuals` at z as host values, by one compiled program
        (called op by op, the map compiles a dozen single operations in each process)."""
        u, extra = _input_and_extra(self, jnp.asarray(z))
        return np.asarray(u), np.asarray(extra)

    def input_values(self, z) -> np.ndarray:
        """`input` at z as host values (`values`)."""
        return self.values(z)[0]

    def extra_residuals(self, z) -> Float[Array, " k"]:
        """Residuals the map adds to a least-squares problem: MEAN_STEP_WEIGHT·s̄ for a
        periodic slew map (pins the one direction of z that moves no input); none else."""
        if self.step is None or not self.periodic:
            return jnp.zeros((0,), z.dtype)
        return MEAN_STEP_WEIGHT * self._steps(z)[2][None]

    def feasible(self, u) -> np.ndarray:
        """``u`` (host values) made to satisfy the limits with a small margin: clipped into
        the range, then its steps limited sample by sample (over three passes of a period,
        so that its closing step is limited too). For a start, not a result."""
        lim = self.limits
        lower, upper, half = float(lim.lower), float(lim.upper), float(lim.half)
        margin = 1e-4 * half
        u = np.clip(np.asarray(u, dtype=np.float64), lower + margin, upper - margin)
        if lim.slew is None:
            return u
        d = float(lim.slew) * float(self.dt) * (1.0 - 1e-4)
        passes = 3 if self.periodic else 1
        target = np.tile(u, passes)
        out = np.empty_like(target)
        out[0] = target[0]
        for i in range(1, target.shape[0]):
            out[i] = min(max(target[i], out[i - 1] - d), out[i - 1] + d)
        return out[-self.n:]

    def coordinates(self, u) -> np.ndarray:
        """Coordinates z whose input is close to ``u`` (exact for a `feasible` u away from
        the band at the edges of the range)."""
        lim = self.limits
        w = sat_inverse((self.feasible(u) - float(lim.mid)) / float(lim.half))
        if self.step is None:
            return w
        closed = np.append(w, w[0]) if self.periodic else w
        v = sat_inverse(np.diff(closed) / float(self.step))
        return np.concatenate([w[:1], v])


@eqx.filter_jit
def _input_and_extra(imap: InputMap, z):
    return imap.input(z), imap.extra_residuals(z)
