"""What the actuator can do, and where a reference asks for more.

`reach` sweeps the input slowly over its whole range (the major loop: the largest |M| the
limits allow) and gives the range of magnetization, magnetostriction and static
displacement y = Ar·E·λ/Kz. Without input limits the physical range is used: |M| < Ms,
0 ≤ λ < (3/2)·λs. `unreachable` then names the samples of a reference the actuator cannot
follow, with the reason:

- **beyond the stroke**: the displacement itself lies outside the static range;
- **faster than the structure can follow**: the displacement lies inside it, but moving
  the mass and the damper along it needs a magnetostriction (Mz·ÿ + Cz·ẏ + Kz·y)/(Ar·E)
  outside the range;
- **faster than the slew limit**: the input that would produce it changes faster than
  the slew-rate limit allows;
- **starts in motion**: a record whose displacement moves at its first sample, while the
  actuator starts at rest (it moves by more than `SLACK` of the reference's stroke in
  the structure's settling time 2·Mz/Cz).
"""

from __future__ import annotations

import equinox as eqx
import jax
import numpy as np

from .._traces import kept_jit
from ..model.paths import hysteresis_path
from ..saved import Model
from .limits import InputLimits

#: Relative slack before a sample counts as unreachable (the inverse's own accuracy).
SLACK = 1e-4


class Reach(eqx.Module):
    """The ranges an actuator reaches within its input limits (host floats):
    ``M`` (A/m), ``lam`` (magnetostriction) and ``y`` (static displacement, m), each a
    (low, high) pair, and ``sign``: the branch of M the bias holds (+1 or −1), on which
    the inverse places the magnetization."""

    M: tuple = eqx.field(static=True)
    lam: tuple = eqx.field(static=True)
    y: tuple = eqx.field(static=True)
    sign: float = eqx.field(static=True)


@kept_jit
def _sweep_magnetization(p, H, variant, substeps):
    M_sub, _, _, _ = hysteresis_path(variant, p, None, H, substeps=substeps)
    return M_sub[:, -1]


def reach(model: Model, limits: InputLimits | None, gain: float) -> Reach:
    """The `Reach` of ``model`` with input ``limits`` (None: the physical range) and
    input gain (H = gain·u + Hb)."""
    p = model.params
    Ms, lambda_s = float(p.Ms), float(p.lambda_s)
    if limits is None:
        M_range = (-Ms, Ms)
    else:
        Hb = float(model.actuator.Hb)
        lo, hi = gain * limits.lower + Hb, gain * limits.upper + Hb
        n = 400  # samples per half cycle of the slow sweep, three cycles onto the loop
        up, down = np.linspace(lo, hi, n + 1)[1:], np.linspace(hi, lo, n + 1)[1:]
        ramp = np.linspace(0.0, lo, n + 1)
        H = np.concatenate([ramp, *([up, down] * 3)])
        M = np.asarray(_sweep_magnetization(p, jax.numpy.asarray(H), model.variant,
                                            model.substeps))[-2 * n:]
        M_range = (float(M.min()), float(M.max()))
    lam_of = lambda M: 1.5 * lambda_s * (M / Ms) ** 2
    ends = (lam_of(M_range[0]), lam_of(M_range[1]))
    lam_range = (0.0 if M_range[0] <= 0.0 <= M_range[1] else min(ends), max(ends))
    static_gain = float(model.actuator.Ar) * float(p.E) / float(p.Kz)
    sign = 1.0 if M_range[1] >= -M_range[0] else -1.0
    return Reach(M=M_range, lam=lam_range,
                 y=(static_gain * lam_range[0], static_gain * lam_range[1]), sign=sign)


class Unreachable(eqx.Module):
    """A stretch of the reference the actuator cannot follow: ``reason`` (see the
    module docstring), samples ``start`` … ``stop`` (inclusive), their times ``t_start``,
    ``t_stop`` (s), and ``excess``: how far the worst sample lies outside what is
    reachable, in ``unit``."""

    reason: str = eqx.field(static=True)
    start: int = eqx.field(static=True)
    stop: int = eqx.field(static=True)
    t_start: float = eqx.field(static=True)
    t_stop: float = eqx.field(static=True)
    excess: float = eqx.field(static=True)
    unit: str = eqx.field(static=True)

    def __str__(self) -> str:
        where = (f"t = {self.t_start * 1e3:.4g} ms" if self.start == self.stop else
                 f"t = {self.t_start * 1e3:.4g}–{self.t_stop * 1e3:.4g} ms")
        samples = (f"sample {self.start}" if self.start == self.stop else
                   f"samples {self.start}–{self.stop}")
        return f"{self.reason} at {where} ({samples}), by up to {self.excess:.3g} {self.unit}"


def _runs(bad: np.ndarray) -> list[tuple[int, int]]:
    """(first, last) of each run of True in ``bad``."""
    edges = np.diff(np.concatenate([[0], bad.astype(np.int8), [0]]))
    return list(zip(np.flatnonzero(edges == 1), np.flatnonzero(edges == -1) - 1, strict=True))


def _segments(excess: np.ndarray, t: np.ndarray, reason: str, unit: str) -> list:
    """One `Unreachable` per run of samples with ``excess`` > 0."""
    return [Unreachable(reason, int(i), int(j), float(t[i]), float(t[j]),
                        float(excess[i:j + 1].max()), unit) for i, j in _runs(excess > 0)]


def unreachable(reach_: Reach, t, y, lam, u=None, limits: InputLimits | None = None,
                dt: float = 1.0, unit: str = "A", periodic: bool = True,
                settling: float = 0.0) -> list:
    """The `Unreachable` stretches of a reference: times ``t`` (s), displacement ``y``
    (m), the magnetostriction ``lam`` its motion needs, and (for the slew check) the input
    ``u`` of the inverse model, samples ``dt`` apart (s); ``settling``: the structure's
    settling time 2·Mz/Cz (s), for the start of a record."""
    t, y, lam = (np.asarray(x, dtype=np.float64) for x in (t, y, lam))
    y_lo, y_hi = reach_.y
    lam_lo, lam_hi = reach_.lam
    y_slack, lam_slack = SLACK * max(abs(y_hi), abs(y_lo)), SLACK * lam_hi
    stroke = np.maximum(y - y_hi, y_lo - y)  # m beyond the static range
    static_gain = y_hi / lam_hi if lam_hi > 0 else 0.0  # m per unit λ
    force = np.maximum(lam - lam_hi, lam_lo - lam)  # beyond the range of λ
    out_of_stroke, out_of_force = stroke > y_slack, force > lam_slack
    force = force * static_gain
    found = []
    for i, j in _runs(out_of_stroke | out_of_force):  # a run that leaves the stroke is
        beyond = bool(out_of_stroke[i:j + 1].any())   # beyond it (its edges need force too)
        found.append(Unreachable(
            "beyond the stroke" if beyond else "faster than the structure can follow",
            int(i), int(j), float(t[i]), float(t[j]),
            float((stroke if beyond else force)[i:j + 1].max()),
            "m" if beyond else "m of static stroke"))
    if u is not None and limits is not None and limits.slew is not None:
        steps = np.diff(np.append(u, u[0]) if periodic else u) / dt
        over = np.abs(steps) - limits.slew * (1.0 + SLACK)
        if not periodic:
            over = np.append(over, 0.0)
        found += _segments(np.maximum(over, 0.0), t, "faster than the slew limit",
                           f"{unit}/s")
    if not periodic and t.shape[0] > 2:
        speed = abs(float(np.gradient(y[:3], t[:3], edge_order=2)[0]))
        if speed * settling > SLACK * (float(np.ptp(y)) or 1.0):
            found.append(Unreachable("starts in motion (the actuator starts at rest)", 0, 0,
                                     float(t[0]), float(t[0]), speed, "m/s"))
    return sorted(found, key=lambda s: s.start)
