"""Intervals from the profile likelihood where the quadratic approximation fails, decided
by the profile itself.

The linear (Wald or bound-aware) interval of a parameter assumes that the cost rises
quadratically along its profile. `refine_intervals` tests that at each end of the linear
interval (a quantity of one sign: the same half-width on ln|θ|): it re-fits every other
parameter with this one held at the end (a round of local solves of all ends, each
warm-started on the linearised profile path: `_chunk` says how they are batched) and reads the
profile's Δχ² there. Where it lies within `TOLERANCE` of the threshold c (3.84, or the
bound-aware one), the linear end stands — the quadratic describes the profile.
Elsewhere the end is moved to where the profile crosses c:
successive batches of re-fits, each end's next value from the crossing of √Δχ², which is
linear in the parameter where the cost is quadratic, bracketed once the crossing is
passed (false position with the Illinois rule: the end kept twice running has its value
halved, so that a strongly curved profile does not stall the bracket at one side; a
bisection where two batches did not halve the bracket; an end whose bracket is within
`BRACKET` of its distance from the optimum is the tested value beyond it: a wall, where
Δχ² jumps past the tolerance within that distance); each
re-fit starts from that end's previous one, moved along the linearised path by the change
of the held value (so a batch's re-fits continue where the last ended, and an end
already settled costs a few steps). Quantities of one sign by construction (a box
that does not reach 0) are profiled in ln|θ|, so that their intervals never cross 0; every
end stays inside the box — an end the profile does not reach inside it is the box's, and
the report says the data do not bound the parameter there.

Δχ² is the cost difference when every residual group declares its noise level (the cost
is then a χ²), else the cost difference over σ̂² = cost/(N − n) (and times the variance
inflation of correlated residuals where the report found them: `misspecification`).

A re-fit that ends *below* the fit's cost (by more than `LOWER`, in Δχ²) shows that the
fit is not the minimum — it stopped short, or in a local minimum — and its intervals
describe that point: the lowest such re-fit is kept in ``report.lower_cost`` (the held
parameter, its value, −Δχ², every free value) for the report to say so and for
`jaxhyst.fit.attach_report` to continue the fit from there.
"""

from __future__ import annotations

import concurrent.futures
import functools
import os

import equinox as eqx
import jax
import jax.numpy as jnp
import numpy as np

from .._background import wait_for
from .._traces import kept_jit
from ..identify import solve_traced
from ..identify.problem import cost_at
from ..identify.result import stopped_short
from ..identify.solvers import make_solver
from ..identify.summary import free_values_of, u_from_z_host, z_from_u_host
from .intervals import critical_value, held_at_bounds, path_point
from .wording import Z95

#: A linear end stands where the profile's Δχ² there is within this fraction of c (an
#: end at 0.8·c would miss 4 % of the time on its side instead of 2.5 %).
TOLERANCE = 0.05
#: A bracketed end is also found where the bracket is this narrow relative to the end's
#: distance from the optimum (a wall in the profile, where Δχ² jumps past TOLERANCE).
BRACKET = 0.01
#: Batches of re-fits at most (the first tests the linear ends).
ROUNDS = 8
#: Levenberg–Marquardt steps of each constrained re-fit (warm-started).
STEPS = 40
#: The re-fits' Cauchy termination (rtol at most, atol): looser than a fit's (1e-10) — a
#: re-fit needs its cost only to `PRECISION` in Δχ², so rtol is PRECISION over the fit's
#: χ² (cost/σ²) where that is smaller (long records), a value passed to the program (one
#: program whatever the rtol).
RE_FIT_TOLERANCES = (1e-5, 1e-12)
#: The precision (in Δχ²) a re-fit's cost is wanted to: far below `TOLERANCE`·3.84.
PRECISION = 0.01
#: The name under which a fit's background compile of the re-fit program is awaited
#: (`jaxhyst._background.awaited`): the check waits for it before its first re-fit.
REFITS = "profile re-fits"
#: A re-fit this far below the fit's cost (in Δχ²; and by more than `stopped_short`'s
#: 1e-6 of the cost) shows that the fit is not the minimum.
LOWER = 0.1


def _chunk(ends: int) -> int:
    """Re-fits per batch: on a CPU one (a vmapped batch of Levenberg–Marquardt solves runs
    as long as its slowest member, every member computing every step: one at a time, on
    the cores side by side, is several times faster — `benchmarks/RESULTS.md`, issue 43),
    elsewhere every end of a round in one batch (an accelerator's batch costs about what
    one re-fit does)."""
    return 1 if jax.default_backend() == "cpu" else ends


@functools.cache
def _pool() -> concurrent.futures.ThreadPoolExecutor:
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else \
        (os.cpu_count() or 1)  # (the cores this process may use)
    return concurrent.futures.ThreadPoolExecutor(max(1, min(cores, 4)),
                                                 thread_name_prefix="jaxhyst-profile")


def _side_by_side(fn, items):
    """``[fn(x) for x in items]``, on the pool's threads (XLA releases the GIL while a
    compiled program runs)."""
    if len(items) <= 1:
        return [fn(x) for x in items]
    return list(_pool().map(fn, items))


def _refit(problem, solver, lowers, uppers, z0s, max_steps, size, idx):
    """The re-fits of the ends ``idx`` (of the round's (B, n) boxes and starts) in one
    batch of ``size``: (idx, their costs, their solver coordinates)."""
    fill = np.concatenate([idx, np.full(size - idx.size, idx[0])])
    c_, z_ = _held_costs(problem, solver, jnp.asarray(lowers[fill]), jnp.asarray(uppers[fill]),
                         jnp.asarray(z0s[fill]), np.int64(max_steps))
    return idx, np.asarray(c_)[:idx.size], np.asarray(z_)[:idx.size]


def _z_in_box(x, lower, upper) -> np.ndarray:
    """The solver coordinate of the values ``x`` in the box [lower, upper] (clipped into
    it; a side held at one value has width 1), by NumPy: `ParameterSpace.u_from_free`'s
    arithmetic and the sine map without a program."""
    width = np.where(upper > lower, upper - lower, 1.0)
    return z_from_u_host(np.clip((x - lower) / width, 0.0, 1.0))


def _refit_solver(solver: str, rtol: float):
    """The re-fits' solver, its rtol a value of their program (one program whatever the
    rtol)."""
    return make_solver(solver, jnp.asarray(rtol), RE_FIT_TOLERANCES[1])


def compile_refits(problem, solver: str = "lm", max_steps: int = STEPS) -> None:
    """Compile (not run) the re-fit program `refine_intervals` runs for ``problem``, and
    its cost at the estimate, on inputs of their shapes, so that they are compiled before
    the check needs them: `jaxhyst.fit` does this in a background thread once a fit's
    cost has settled above an exact fit's."""
    size = _chunk(2 * problem.space.n_free)
    lower, upper = (jnp.asarray(np.tile(np.asarray(b, float), (size, 1)))
                    for b in (problem.space.lower, problem.space.upper))
    _held_costs.lower(problem, _refit_solver(solver, RE_FIT_TOLERANCES[0]), lower, upper,
                      jnp.zeros_like(lower), np.int64(max_steps)).compile()
    cost_at.lower(problem, np.zeros(problem.space.n_free)).compile()  # (the check's first)


@kept_jit
def _held_costs(problem, solver, lowers, uppers, z0s, max_steps):
    """``problem`` re-fitted in each member's box (a held parameter has lower = upper),
    from each member's start: (costs (B,), the solutions' solver coordinates (B, n))."""

    def one(lo, hi, z0):
        p = eqx.tree_at(lambda q: q.space, problem, problem.space.with_box(lo, hi))
        z, _, _, cost, _ = solve_traced(p, solver, z0, max_steps)
        return cost, z

    return jax.vmap(one)(lowers, uppers, z0s)


def _noise_variance(problem, cost: float, inflation: float) -> float:
    """σ² in cost units: 1 where every group declares its noise (a χ²), else the cost per
    degree of freedom; times the inflation for correlated residuals."""
    if all(g.sigma is not None for g in problem.groups):
        return inflation
    dof = max(problem.n_observed - problem.space.n_free, 1)
    return max(cost / dof, 1e-300) * inflation


def refine_intervals(problem, params, report, *, inflation: float = 1.0,
                     threshold: float = Z95**2, solver: str = "lm",
                     max_steps: int = STEPS) -> dict:
    """Profile-checked 95 % intervals of the report's identifiable parameters (see the
    module docstring). Updates ``report.intervals``, ``report.interval_methods``
    (``profile`` where an end moved) and ``report.linearity`` (the profile's Δχ² at each
    linear end over c); returns {name: "unbounded below/above …"} for ends the data do
    not bound inside the box."""
    space = problem.space
    names = list(report.names)
    x_hat = np.asarray(free_values_of(space, params), dtype=float)
    lower, upper = np.asarray(space.lower, float), np.asarray(space.upper, float)
    scale = np.asarray(report.scale, float)
    cost0 = float(cost_at(problem, _z_in_box(x_hat, lower, upper)))
    sigma2 = _noise_variance(problem, cost0, inflation)
    held = [names.index(n) for n in (report.at_bound or {})]
    C = held_at_bounds(np.asarray(report.cov_log, float), held)
    ends = []  # (parameter index, side ±1, log coordinates?)
    methods_now = report.interval_methods or {}
    for i, n in enumerate(names):
        iv = report.intervals.get(n)
        # (the bound-aware intervals keep their own construction: Feldman–Cousins
        # thresholds on the linearised profile with the active bounds)
        if iv is None or not C[i, i] > 0 or methods_now.get(n) not in ("wald", "near-bound"):
            continue
        for side, end in ((-1, iv[0]), (1, iv[1])):
            if (side < 0 and end <= lower[i]) or (side > 0 and end >= upper[i]):
                continue  # (an end on the box: nothing beyond it to profile)
            ends.append((i, side, bool((lower[i] > 0 or upper[i] < 0) and x_hat[i] != 0)))
    if not ends:
        return {}
    wait_for(REFITS)  # (the re-fit program, where a fit compiles it in the background)
    se = np.sqrt(np.diag(C)) * np.abs(scale)  # (SI)
    positive = ((lower > 0) | (upper < 0)) & (x_hat != 0)

    def coordinate(i, logs, v):
        return np.log(v / x_hat[i]) if logs else v - x_hat[i]

    def value(i, logs, s):
        v = x_hat[i] * np.exp(s) if logs else x_hat[i] + s
        return float(np.clip(v, lower[i], upper[i]))

    # the linear ends, in each end's coordinate (a positive quantity's on the log scale)
    s_now = []
    for i, side, logs in ends:
        width = Z95 * se[i]
        s_now.append(side * width / x_hat[i] if logs else side * width)
    s_now = np.array(s_now)
    below = np.zeros(len(ends))  # the largest |s| known under c (0: the optimum)
    above = np.full(len(ends), np.inf)  # the smallest |s| known over c
    # √Δχ² − √c at those two (f_below < 0 < f_above), the retained one's halved when the
    # same side moves twice running (Illinois: regula falsi would stall against it)
    f_below, f_above = np.full(len(ends), np.nan), np.full(len(ends), np.nan)
    moved = np.zeros(len(ends), int)  # the side that moved last: −1 below, +1 above
    widths = [[] for _ in ends]  # each end's bracket width after every round
    done = np.zeros(len(ends), bool)
    ratio_first = np.full(len(ends), np.nan)
    unbounded = {}
    solver_ = _refit_solver(solver, min(RE_FIT_TOLERANCES[0],
                                        PRECISION / max(cost0 / sigma2, 1.0)))
    B = len(ends)

    def on_path(i, logs, v):
        """The linearised profile path at θ_i = v, straight in ln θ for the positive
        parameters (SI, shape (n,))."""
        dx = C[:, i] / C[i, i] * (np.log(v / x_hat[i]) if logs else (v - x_hat[i]) / scale[i])
        return path_point(x_hat, scale, positive, dx)

    n = lower.size
    last_x, last_v = np.full((B, n), np.nan), np.full(B, np.nan)
    costs, zs = np.full(B, np.nan), np.zeros((B, n))  # (each end's last re-fit)
    for round_ in range(ROUNDS):
        todo = np.flatnonzero(~done)
        if todo.size == 0:
            break
        run = todo if round_ else np.arange(B)  # (the ends re-fitted this round: below)
        lowers, uppers, z0s = np.tile(lower, (B, 1)), np.tile(upper, (B, 1)), np.zeros((B, n))
        values = np.zeros(B)
        for k in run:
            i, _, logs = ends[k]
            v = value(i, logs, s_now[k])
            values[k] = v
            lowers[k, i] = uppers[k, i] = v
            # from the last re-fit of this end moved along the path by the change of the
            # held value; the first time, from the linearised path (an end already found
            # is not re-fitted: below)
            x0 = on_path(i, logs, v)
            if np.all(np.isfinite(last_x[k])):
                x0 = last_x[k] + x0 - on_path(i, logs, last_v[k])
            x0 = np.clip(x0, lowers[k], uppers[k])
            z0s[k] = _z_in_box(x0, lowers[k], uppers[k])
        # only the ends not yet found are re-fitted (a round that has one end left runs
        # one re-fit, not every end again), `_chunk()` at a time (the rest copies of the
        # first: one program whatever the number of ends), side by side on the CPU's
        # cores — after the first batch of the first round, which compiles the program
        # in this thread (compile counters and configuration contexts are the caller's)
        size = _chunk(2 * len(names))

        refit = functools.partial(_refit, problem, solver_, lowers, uppers, z0s, max_steps,
                                  size)
        chunks = [run[c0:c0 + size] for c0 in range(0, run.size, size)]
        first = 0 if round_ else 1  # (the program compiles in this thread, once)
        for idx, c_, z_ in [*map(refit, chunks[:first]), *_side_by_side(refit, chunks[first:])]:
            costs[idx], zs[idx] = c_, z_
        x_run = lowers[run] + (uppers[run] - lowers[run]) * u_from_z_host(zs[run])
        x_run[~np.isfinite(costs[run])] = np.nan  # (a failed re-fit: the path again)
        last_x[run], last_v[run] = x_run, values[run]
        drop = (cost0 - costs) / sigma2
        k_low = int(np.nanargmax(np.where(np.isfinite(costs), drop, -np.inf)))
        if drop[k_low] > LOWER and stopped_short(cost0, float(costs[k_low])) and \
                drop[k_low] > report.lower_cost.get("delta_chi2", 0.0):
            report.lower_cost = {"held": names[ends[k_low][0]], "value": float(last_v[k_low]),
                                 "delta_chi2": float(drop[k_low]),
                                 "values": [float(v) for v in last_x[k_low]]}
        delta = np.maximum(-drop, 0.0)
        for k in todo:
            i, side, logs = ends[k]
            s, d = abs(s_now[k]), float(delta[k])
            # the threshold there: Feldman–Cousins' near the box's end, else 3.84
            c = float(critical_value(min(values[k] - lower[i], upper[i] - values[k]) / se[i])) \
                * threshold / Z95**2
            if round_ == 0:
                ratio_first[k] = d / c
            if not np.isfinite(d):
                d = np.inf
            if abs(d / c - 1.0) <= TOLERANCE:
                done[k] = True
                continue
            f = np.sqrt(d) - np.sqrt(c)
            if d < c:
                below[k], f_below[k] = s, f
                if moved[k] < 0:
                    f_above[k] *= 0.5
                moved[k] = -1
            else:
                above[k], f_above[k] = s, f
                if moved[k] > 0:
                    f_below[k] *= 0.5
                moved[k] = 1
            at_box = values[k] in (lower[i], upper[i])
            if at_box and d < c:  # the data do not bound it inside the box
                done[k] = True
                unbounded[names[i]] = ("below" if side < 0 else "above")
                continue
            # the next value: where √Δχ² (linear in s for a quadratic cost) reaches √c
            if np.isfinite(above[k]):
                width = above[k] - below[k]
                if width <= BRACKET * above[k]:
                    # a wall: the crossing is located to BRACKET of its distance from
                    # the optimum, though Δχ² changes too fast there to meet TOLERANCE;
                    # the end is the tested value beyond it (never narrower)
                    s_now[k] = side * above[k]
                    done[k] = True
                    continue
                widths[k].append(width)
                f0 = f_below[k] if np.isfinite(f_below[k]) else -np.sqrt(c)  # (0: optimum)
                # (a re-fit that failed beyond: the bracket halved)
                t = -f0 / max(f_above[k] - f0, 1e-300) if np.isfinite(f_above[k]) else 0.5
                if len(widths[k]) >= 3 and widths[k][-1] > 0.5 * widths[k][-3]:
                    t = 0.5  # (false position creeping along a wall: bisect instead)
                s_next = below[k] + t * (above[k] - below[k])
            else:
                s_next = s * min(np.sqrt(c / max(d, 1e-12)), 4.0)
            s_now[k] = side * s_next
    lo = dict(report.intervals)
    methods = dict(report.interval_methods or {})
    first, unsettled = {}, {}
    for k, (i, side, logs) in enumerate(ends):
        n = names[i]
        v = value(i, logs, s_now[k])
        if not done[k]:  # (the last bracket's interpolation, or beyond every re-fit)
            bracketed = bool(np.isfinite(above[k]))
            unsettled[n] = {"side": "below" if side < 0 else "above",
                            "between": (value(i, logs, side * below[k]),
                                        v if not bracketed else value(i, logs, side * above[k])),
                            "bracketed": bracketed}
        a, b = lo[n]
        lo[n] = (min(v, b), b) if side < 0 else (a, max(v, a))
        first.setdefault(n, [1.0, 1.0])[0 if side < 0 else 1] = float(ratio_first[k])
        if abs(ratio_first[k] - 1.0) > TOLERANCE:
            methods[n] = "profile"
    report.intervals = lo
    report.interval_methods = methods
    report.unsettled = unsettled
    report.linearity.update({n: tuple(r) for n, r in first.items()})
    return unbounded
