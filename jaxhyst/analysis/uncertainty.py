"""Uncertainty beyond the local linearisation: profile likelihood and replicate fits.

- `profile_likelihood`: for one parameter, re-fit all the others with that parameter held
  at each value of a grid — one vmapped batch of local solves — and turn the costs into
  the likelihood-ratio statistic Δχ²(v) = cost(v) − cost_min when every residual group
  declares its noise level (the cost is then a χ²), else (cost(v) − cost_min)/σ̂² with
  σ̂² = cost_min/(N − n) (Gaussian noise of unknown variance, estimated from the best
  fit). The 95 % profile
  interval is where Δχ² ≤ 3.84 (χ²₁ quantile); a side that never crosses inside the box
  is reported as unbounded (the data do not bound the parameter there). Unlike the
  Gauss–Newton interval it follows the model's nonlinearity.
- `fit_replicates`: fit many data sets of the same problem (noisy replicates, bootstrap
  resamples) in vmapped batches, each with its Gauss–Newton standard errors; `coverage`
  counts how often the 95 % intervals contain the truth.
"""

from __future__ import annotations

import time
from dataclasses import dataclass

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._driver import DONE, KEYBOARD, drive
from .._interrupt import Interrupted
from ..identify import outcome_name, solve_traced, start_z
from ..identify.problem import cost_at
from ..identify.result import bound_status, params_of, stopped_short
from ..identify.solvers import make_solver
from ..identify.space import u_from_z
from ..identify.summary import free_values_of
from ..progress import progress_meter
from ..sharding import batch_sharding, place
from .identifiability import whitened_log_jacobian
from .intervals import bound_aware_intervals, box_in_x, x_side
from .profile_intervals import LOWER
from .wording import Z95

CHI2_95 = 3.841458820694124  # 95 % quantile of χ² with one degree of freedom


@dataclass
class ProfileLikelihood:
    """Profile of one parameter: ``grid`` values (SI), the re-fitted ``cost`` and
    ``delta_chi2`` at each, the re-fitted parameters ``theta`` (G × every flat entry),
    the best ``value``, and the 95 % ``interval`` (a ``None`` end is not bounded by the
    data)."""

    name: str
    value: float
    grid: np.ndarray
    cost: np.ndarray
    delta_chi2: np.ndarray
    theta: np.ndarray
    interval: tuple[float | None, float | None]
    results: list[str]
    roundoff: bool = False  # the best cost is at round-off: noise-free data
    unresolved: bool = False  # no re-fit came within the threshold of the fit's cost
    #: the fit's Δχ² above the profile's lowest point (> `LOWER`: the fit is not the
    #: minimum, and Δχ² and the interval are taken from that lower point)
    fit_above: float = 0.0

    def _digits(self) -> int:
        """Significant digits that tell neighbouring grid values apart (at least 6)."""
        g = np.asarray(self.grid, dtype=float)
        step = np.min(np.diff(g)) if g.size > 1 else 0.0
        big = float(np.max(np.abs(g))) if g.size else 0.0
        if not (step > 0 and big > 0):
            return 6
        return int(min(17, max(6, np.ceil(np.log10(big / step)) + 2)))

    @property
    def identifiable(self) -> bool:
        return self.interval[0] is not None and self.interval[1] is not None

    def __str__(self) -> str:
        lo, hi = self.interval
        k = self._digits()
        lo_s = "unbounded" if lo is None else f"{lo:.{k}g}"
        hi_s = "unbounded" if hi is None else f"{hi:.{k}g}"
        head = (f"Profile likelihood of {self.name} (best {self.value:.{k}g}): 95 % interval "
                f"{lo_s} … {hi_s}")
        if self.unresolved:
            head = (f"Profile likelihood of {self.name} (best {self.value:.{k}g}): no 95 % "
                    f"interval — no re-fit on the grid came within Δχ² = 3.84 of the fit "
                    f"(least {float(np.min(self.delta_chi2)):.4g}): the re-fits did not "
                    "converge, or the grid steps over the interval; profile on a finer "
                    "grid around the value (more points), or with more steps")
        elif not self.identifiable:
            head += "  — not bounded by the data on that side (practically non-identifiable)"
        if self.roundoff:
            head += ("\n  the best fit is exact to round-off (noise-free data): Δχ² below "
                     "measures round-off, not information; profile noisy or measured data")
        if self.fit_above > LOWER:
            at = float(self.grid[int(np.argmin(self.delta_chi2))])
            head += (f"\n  NOT THE MINIMUM: the re-fit at {self.name} = {at:.{k}g} lies "
                     f"Δχ² = {self.fit_above:.4g} below the fit; the fit stopped short of "
                     "the minimum or in a local one (Δχ² and the interval are measured from "
                     "that lower point): fit again (identify with more --starts; --start "
                     "RESULT.json where it stopped at its step limit)")
        rows = [f"  {v:>{k + 7}.{k}g}  Δχ² = {d:.4g}"
                for v, d in zip(self.grid, self.delta_chi2, strict=True)]
        return "\n".join([head, *rows])

    def to_dict(self) -> dict:
        return {"name": self.name, "value": self.value, "grid": self.grid.tolist(),
                "cost": self.cost.tolist(), "delta_chi2": self.delta_chi2.tolist(),
                "interval": list(self.interval), "results": self.results,
                "roundoff": self.roundoff, "unresolved": self.unresolved,
                "fit_above": self.fit_above}


def _crossing(grid, d, i0, direction):
    """First v beyond index i0 (moving ``direction``) where d crosses CHI2_95, linearly
    interpolated; None if it never does."""
    i = i0
    while 0 <= i + direction < len(grid):
        j = i + direction
        if d[j] > CHI2_95 >= d[i]:
            t = (CHI2_95 - d[i]) / (d[j] - d[i])
            return float(grid[i] + t * (grid[j] - grid[i]))
        i = j
    return None


def profile_likelihood(problem, params, name: str, grid=None, n: int = 21,
                       solver: str = "lm", max_steps: int = 100,
                       batch_size: int | None = None, progress=False) -> ProfileLikelihood:
    """Profile likelihood of parameter ``name`` of ``problem`` around the fit ``params``
    (its `Parameters`, or the `IdentificationResult` itself).

    **Arguments:**
    - ``grid``: values (SI) at which to hold ``name``; default ``n`` points spanning ±4
      Gauss–Newton standard errors (clipped to the box), or the whole box when the
      parameter is not identifiable by the linear analysis.
    - ``solver``/``max_steps``: the local solver of the constrained re-fits, all started
      from ``params`` and run as one vmapped batch (or batches of ``batch_size``; the
      same batch size and solver as an earlier profile or `fit_replicates` of the same
      problem reuse its compiled program, whichever parameter is profiled and whatever
      its ``max_steps``).
    - ``progress``: a progress meter (`jaxhyst.progress`) or True; silent by default.
    """
    space, params = problem.space, params_of(params)
    if name not in space.names:
        raise ValueError(f"{name!r} is not a free parameter of this problem "
                         f"(free: {list(space.names)}).")
    if space.n_free < 2:
        raise ValueError("A profile needs at least one other free parameter to re-fit.")
    i_free = space.names.index(name)
    lo, hi = float(space.lower[i_free]), float(space.upper[i_free])
    value = float(np.asarray(free_values_of(space, params))[i_free])
    if grid is None:
        from .identifiability import identifiability

        se = identifiability(problem, params).std_errors[name]
        a, b = (lo, hi) if se is None or se == 0 else (max(lo, value - 4 * se),
                                                       min(hi, value + 4 * se))
        grid = np.unique(np.append(np.linspace(a, b, n), value))
    grid = np.sort(np.asarray(grid, dtype=float))
    if grid.ndim != 1 or grid.size < 3:
        raise ValueError("The profile grid needs at least 3 values.")
    if grid[0] < lo or grid[-1] > hi:
        raise ValueError(f"The grid of {name} must lie in its bounds [{lo:g}, {hi:g}].")
    G = grid.size
    lowers = np.tile(np.asarray(space.lower), (G, 1))
    uppers = np.tile(np.asarray(space.upper), (G, 1))
    lowers[:, i_free] = uppers[:, i_free] = grid  # hold the parameter at each grid value
    data = jax.tree.map(lambda a: np.broadcast_to(np.asarray(a), (G, *np.shape(a))),
                        problem.observations)
    (x, _, results, _, costs, _, _), how = _fit_many(problem, data, lowers, uppers, params,
                                               solver, max_steps, batch_size or G,
                                               progress_meter(progress))
    if how != DONE:  # a profile needs every point of its grid
        raise KeyboardInterrupt
    theta = np.asarray(space.flat_from_free(jnp.asarray(x)))
    best = float(cost_at(problem, space.z_from_params(params)))
    c_min = min(best, float(np.nanmin(costs)))
    if all(g.sigma is not None for g in problem.groups):
        sigma2 = 1.0  # the cost is a chi-square
    else:
        sigma2 = c_min / max(problem.n_observed - space.n_free, 1)
    d = (costs - c_min) / sigma2 if sigma2 > 0 else np.where(costs > c_min, np.inf, 0.0)
    d = np.where(np.isfinite(d), d, np.inf)
    i0 = int(np.argmin(d))
    unresolved = not d[i0] <= CHI2_95  # (then no side can cross: say why, not "unbounded")
    interval = (_crossing(grid, d, i0, -1), _crossing(grid, d, i0, +1))
    # noise-free data: the unweighted cost (a mean square relative to the data's size)
    # at the level of float64 round-off
    roundoff = sigma2 != 1.0 and c_min <= 1e-20
    return ProfileLikelihood(name=name, value=value, grid=grid, cost=costs, delta_chi2=d,
                             theta=theta, interval=interval,
                             results=[str(n) for n in np.atleast_1d(outcome_name(results))],
                             roundoff=bool(roundoff), unresolved=bool(unresolved),
                             fit_above=float((best - c_min) / sigma2) if sigma2 > 0 and
                             stopped_short(best, c_min) else 0.0)


def _gn_std_errors(problem, x):
    """Gauss–Newton standard errors (SI) of the free parameters at their values x, from
    the whitened Jacobian (full-rank problems), with that Jacobian and the whitened
    residuals (for `bound_aware_intervals`)."""
    scale = jnp.where(x != 0, x, 1.0)
    J, e, _ = whitened_log_jacobian(problem, x, scale)
    _, s, Vt = jnp.linalg.svd(J, full_matrices=False)
    var = jnp.sum((Vt / s[:, None]) ** 2, axis=0)
    return jnp.sqrt(var) * jnp.abs(scale), J, e


@eqx.filter_jit
def _fit_batch(problem, solver, datas, lowers, uppers, z0, max_steps):
    """One vmapped batch of local fits of ``problem`` with per-member data and box
    (a profile holds a parameter by lower = upper = v, which keeps the free set — and so
    the compiled program — the same for every profiled parameter and for replicates);
    ``max_steps`` is a value of the program (an int64 array), not part of it."""

    def one(d, lo, hi):
        p = eqx.tree_at(lambda q: q.space, problem.with_data(d),
                        problem.space.with_box(lo, hi))
        z, result, steps, cost, _ = solve_traced(p, solver, z0, max_steps)
        x = p.space.free_from_u(u_from_z(z))
        se, J, e = _gn_std_errors(p, x)
        return x, se, result, steps, cost, J, e

    return jax.vmap(one)(datas, lowers, uppers)


def _fit_many(problem, datas, lowers, uppers, start, solver, max_steps, batch_size,
              meter, shard=None):
    """`_fit_batch` over any number of members in batches of ``batch_size`` (the last one
    padded, so that one compiled program serves every batch), driven batch by batch by
    the one driver (progress, interruption). Returns (NumPy outputs of the members
    fitted, how the loop ended). ``datas``: a pytree whose leaves have a leading member
    axis."""
    z0 = start_z(problem, start)
    solver_ = make_solver(solver)
    R = len(lowers)
    t0 = time.perf_counter()
    # only on request: placed on a sharding, the batched time loop's batch-wide tests
    # become cross-device reductions at every interval (benchmarks/RESULTS.md)
    sharding = batch_sharding(batch_size, True) if shard else None

    def advance(done):
        b, out = done
        chunk = [jax.tree.map(lambda a: np.asarray(a)[b:b + batch_size], x)
                 for x in (datas, lowers, uppers)]
        pad = batch_size - len(chunk[1])
        if pad:
            chunk = [jax.tree.map(lambda a: np.concatenate(
                [a, np.repeat(a[-1:], pad, axis=0)]), x) for x in chunk]
        args = [jax.tree.map(lambda a: place(jnp.asarray(a), sharding), x) for x in chunk]
        res = jax.device_get(_fit_batch(problem, solver_, *args, z0, np.int64(max_steps)))
        res = jax.tree.map(lambda r: np.asarray(r)[: batch_size - pad], res)
        return b + batch_size, [*out, res]

    def describe(done):
        fitted = min(done[0], R)
        return fitted, f"{fitted}/{R} fitted, {time.perf_counter() - t0:.1f} s"

    meter_state = meter.init("fits", R)
    (b, out), how, meter_state = drive(
        (0, []), advance=advance, done=lambda done: done[0] >= R, describe=describe,
        meter=meter, meter_state=meter_state)
    meter.close(meter_state, f"{min(b, R)}/{R} fitted" + ("" if how == DONE else
                                                          ", interrupted"))
    if not out:
        raise KeyboardInterrupt
    return jax.tree.map(lambda *rs: np.concatenate(rs), *out), how


def fit_replicates(problem, datasets, start, solver: str = "lm", max_steps: int = 100,
                   batch_size: int = 64, progress: bool = False,
                   shard: bool | None = None) -> dict:
    """Fit each replicate of ``datasets`` (the problem's observations stacked along a new
    first axis: R × N for a single-signal problem, R × loops × padded samples for a joint
    one — or R × N, its observed samples concatenated) from ``start``, in vmapped batches of
    ``batch_size``. ``shard=True`` spreads each batch over the devices (``batch_size`` a
    multiple of the device count, see `jaxhyst.sharding`); the default (None or False)
    does not: on CPU host devices the sharded batch is slower (benchmarks/RESULTS.md).

    Returns a dict of NumPy arrays: ``values`` and ``std_errors`` (R × n_free, SI, in the
    order of ``problem.space.names``; standard errors assume every free parameter is
    identifiable), ``intervals`` (R × n_free × 2, SI): the 95 % intervals the
    identifiability report gives — Wald, or the linearised profile with the bounds a fit
    ended on (`jaxhyst.analysis.intervals`) — and ``interval_methods`` (R lists),
    ``cost`` (R,), ``steps`` (R,), ``results`` (names), ``names``, and
    ``interrupted``: True when a stop request ended the fits early (then only the
    replicates fitted so far, in order). Ctrl-C raises `jaxhyst.Interrupted` carrying
    that dict. ``progress``: a progress meter or True (a line per batch)."""
    mask = getattr(getattr(problem, "records", problem), "mask", None)
    if isinstance(mask, np.ndarray) and np.ndim(datasets) == 2 and \
            np.shape(datasets)[1] == int(mask.sum()):  # (the observed samples)
        padded = np.zeros((np.shape(datasets)[0], *mask.shape))
        padded[:, mask] = np.asarray(datasets, dtype=float)
        datasets = padded
    leaves = jax.tree.leaves(datasets)
    ref = jax.tree.leaves(problem.observations)
    if len(leaves) != len(ref) or any(np.shape(a)[1:] != np.shape(r)
                                       for a, r in zip(leaves, ref, strict=True)):
        raise ValueError(f"datasets must stack R replicates of the problem's observations "
                         f"(shapes {[np.shape(r) for r in ref]}) along a new first axis.")
    if not all(np.all(np.isfinite(a)) for a in leaves):
        raise ValueError("datasets contain NaN or inf.")
    R = len(leaves[0])
    lowers = np.broadcast_to(np.asarray(problem.space.lower), (R, problem.space.n_free))
    uppers = np.broadcast_to(np.asarray(problem.space.upper), (R, problem.space.n_free))
    (values, se, results, steps, cost, J, e), how = _fit_many(
        problem, datasets, lowers, uppers, start, solver, max_steps, min(batch_size, R),
        progress_meter(progress, every=1), shard)
    intervals, methods = _replicate_intervals(values, J, e, np.asarray(problem.space.lower),
                                              np.asarray(problem.space.upper))
    out = {"names": problem.space.names, "values": values, "std_errors": se, "cost": cost,
           "steps": steps, "results": [str(n) for n in np.atleast_1d(outcome_name(results))],
           "intervals": intervals, "interval_methods": methods,
           "interrupted": how != DONE}
    if how == KEYBOARD:
        raise Interrupted(out)
    return out


def _replicate_intervals(values, J, e, lower, upper):
    """The report's 95 % intervals of each replicate fit (R × n × 2, SI) and their
    methods."""
    R, n = values.shape
    out, methods = np.full((R, n, 2), np.nan), []
    for r in range(R):
        x = values[r]
        scale = np.where(x != 0, x, 1.0)
        status = bound_status(x, lower, upper)
        sides = {i: x_side(b, scale[i]) for i, b in status.items()}
        lo, hi, how = bound_aware_intervals(J[r], e[r], box_in_x(x, scale, lower, upper),
                                            sides, np.ones(n, bool))
        ends = np.sort(np.stack([x + lo * scale, x + hi * scale]), axis=0)
        out[r] = ends.T
        methods.append(how)
    return out, methods


def interval_coverage(intervals, truth) -> np.ndarray:
    """Fraction of replicates whose interval (R × n × 2, from `fit_replicates`) contains
    ``truth`` (n,), per parameter."""
    intervals, truth = np.asarray(intervals), np.asarray(truth)
    return np.mean((intervals[..., 0] <= truth) & (truth <= intervals[..., 1]), axis=0)


def coverage(values, std_errors, truth, level_z: float = Z95) -> np.ndarray:
    """Fraction of replicates whose interval value ± z·se contains ``truth``, per
    parameter (``truth``: the free parameters' true values, same order as ``values``)."""
    values, se, truth = np.asarray(values), np.asarray(std_errors), np.asarray(truth)
    return np.mean(np.abs(values - truth) <= level_z * se, axis=0)
