"""The Jiles–Atherton magnetization path: a JA form as the time loop runs it.

`JAPath` is the form of `jaxhyst.model.timeloop` for every Jiles–Atherton variant (and
the variants driven by B or by M, `jaxhyst.model.flux.FluxDriven`,
`jaxhyst.model.inverse.MagnetizationDriven`): its state is M, and each sample interval is
advanced by `jaxhyst.model.interval.interval_map` (RK4 in the drive, the δM switch
located). The loop, its derivative rule (a linear recurrence of per-interval partial
derivatives, formed by forward mode in one pass), its batch rule and its accelerator
form are the skeleton's.

The slope at the end of an interval is the slope at the start of the next one when the
field keeps its direction; so each interval reports the *previous* interval's end slope
(one more evaluation only after a reversal), and the last one is evaluated after the loop
(`magnetization_path`). Where the previous direction is not known beforehand (the
rate-dependent model, whose hysteresis field is solved for), ``end_slope_here`` makes
each interval evaluate its own end slope instead.
"""

from __future__ import annotations

from typing import ClassVar

import equinox as eqx
import jax
import jax.numpy as jnp

from ..params import Parameters
from .interval import branch, direction_of, interval_map, interval_map_batched
from .jiles_atherton import AbstractJAVariant
from .timeloop import AbstractPathForm, Interval, run_path


def _previous_end_slope(slope, p, H0, M0, delta, delta_prev, k_start):
    """The previous interval's end slope at (H0, M0): this interval's slope at u_0,
    ``k_start``, unless the field reversed here (δ ≠ δ_prev); then one evaluation with
    δ_prev, computed only when some member reversed."""
    same = delta == delta_prev
    return branch(jnp.all(same), lambda: k_start,
                  lambda: jnp.where(same, k_start, slope(H0, M0, delta_prev, p)))


class JAPath(AbstractPathForm):
    """A Jiles–Atherton form (`AbstractJAVariant`) in the time loop: state M (A/m); the
    outputs of an interval are M at its substep points u_1 … u_S, the slope at u_0 …
    u_{S−1} (its direction) and one more slope: the previous interval's end slope, or its
    own (``end_slope_here``). Shape (2S + 1,)."""

    variant: AbstractJAVariant
    end_slope_here: bool = eqx.field(static=True, default=False)
    state_size: ClassVar[int] = 1

    @property
    def parameters(self) -> tuple[str, ...]:
        return tuple(self.variant.parameters)

    @property
    def scales_with_Ms(self) -> bool:
        return self.variant.scales_with_Ms

    def initial_state(self, theta, H0):
        return jnp.zeros((*jnp.shape(H0), 1), dtype=jnp.result_type(H0))

    def state_rows(self, substeps: int) -> tuple[int, ...]:
        return (substeps - 1,)

    def interval(self, theta, x: Interval, state, substeps: int, batched: bool):
        return self.advance(theta, x.H0, x.H1, state, x.delta_prev, substeps, batched)

    def n_outputs(self, substeps: int) -> int:
        return 2 * substeps + 1

    def advance(self, p: Parameters, H0, H1, state, delta_prev, substeps: int,
                batched: bool):
        """One interval's outputs from ``state`` (M) at H0 to H1 (see the class)."""
        variant, M0 = self.variant, state[..., 0]
        step_map = interval_map_batched if batched else interval_map
        slope = jax.vmap(variant.slope) if batched else variant.slope
        M_points, k_points = step_map(variant, p, H0, H1, M0, substeps)
        if self.end_slope_here:
            k_extra = slope(H1, M_points[..., -1], direction_of(H0, H1), p)
        else:
            k_extra = _previous_end_slope(slope, p, H0, M0, direction_of(H0, H1),
                                          delta_prev, k_points[..., 0])
        return jnp.concatenate([M_points, k_points, k_extra[..., None]], axis=-1)

    def magnetization(self, state):
        """M (A/m) of a state."""
        return state[..., 0]

    def end_magnetization(self, p, H0, H1, state, substeps: int, batched: bool):
        """M (A/m) at the end of the interval from ``state`` at H0 to H1."""
        step_map = interval_map_batched if batched else interval_map
        return step_map(self.variant, p, H0, H1, state[..., 0], substeps)[0][..., -1]

    def slope(self, p, H, state, delta):
        """dM/dH at (H, state) moving in direction ``delta`` (one trajectory)."""
        return self.variant.slope(H, state[..., 0], delta, p)

    def split(self, out, theta, H, substeps: int):
        """(M_sub (N, S), k_sub (N, S + 1)) from the loop's outputs (N, 2S + 1); the
        last interval's end slope is evaluated here unless each interval has its own."""
        S = substeps
        M_sub, k_points = out[:, :S], out[:, S:2 * S]
        if self.end_slope_here:
            ends = out[:, 2 * S]
        else:
            delta_last = direction_of(H[-2], H[-1])
            k_last = self.variant.slope(H[-1], M_sub[-1, -1], delta_last, theta)
            ends = jnp.concatenate([out[1:, 2 * S], k_last[None]])
        return M_sub, jnp.concatenate([k_points, ends[:, None]], axis=1)


def magnetization_path(p: Parameters, H, *, variant: AbstractJAVariant, substeps: int):
    """M and dM/dH along a piecewise-linear field H (A/m), shape (T,), from M = 0.

    **Returns:** ``(M_sub, k_sub)``: M (A/m) at the substep points u_1 … u_S of each of the
    N = T − 1 intervals, shape (N, S), and dM/dH (dimensionless) at u_0 … u_S of each
    interval with that interval's field direction, shape (N, S + 1).
    """
    form = JAPath(variant)
    out = run_path(p, None, H, form=form, substeps=int(substeps))
    return form.split(out, p, H, int(substeps))
