"""How accurate a simulation is at its sampling: an estimate of the error, not a rule.

The time loop integrates the Jiles–Atherton slope by RK4 with ``substeps`` pieces per
sample interval, so its error falls 16× per doubling of the substeps. The same
simulation at twice the substeps therefore gives the error of the first (Richardson):
error ≈ (16/15)·|s_S − s_2S|. That costs one more simulation, so it is only run where
the field moves far per substep (more than `SCREEN_STEP` of its range, where the error
*can* exceed the documented accuracy); finer drives are accurate whatever the material.

`SamplingWarning` is raised where the estimate exceeds `ACCURACY` (the documented
1e-5 of the signal's size), with the substeps that bring it below. The check's
simulations are decided from the drive alone, so the first one's program compiles in a
background thread while the caller's own compiles (`checked_meanwhile`).
"""

from __future__ import annotations

import math

import numpy as np

#: The documented accuracy: error of a signal relative to its size.
ACCURACY = 1e-5
#: The rate-dependent model's documented accuracy (its field balance is second order in
#: the sample step: ~3e-4 of max|B| at 200 samples per period; docs/theory.md).
RATE_ACCURACY = 1e-3
#: The B-driven model's documented accuracy: H relative to its range.
FLUX_ACCURACY = 1e-4
#: Field step per RK4 substep (fraction of the field's range) below which the error is
#: far below `ACCURACY` for any material (measured: ~1e-5 at 1 % for a sharp ferrite
#: loop, ~1e-6 for the Table 1 material): no estimate is run there.
SCREEN_STEP = 0.01


#: An estimated error above this (relative) is beyond RK4's asymptotic range: the
#: substeps that would bring it within `ACCURACY` cannot be sized from it.
ROUGH = 0.1


class SamplingWarning(UserWarning):
    """The record is sampled too coarsely for the RK4 substeps asked for: the estimated
    error exceeds the documented accuracy."""


def max_field_step(H) -> float:
    """Largest field step between consecutive samples relative to the record's range
    (the 95th percentile of |ΔH|, so that a few noise jumps do not count)."""
    H = np.asarray(H, float)
    span = float(np.ptp(H)) if H.size else 0.0
    if not span > 0 or H.size < 2:
        return 0.0
    return float(np.percentile(np.abs(np.diff(H)), 95)) / span


def may_be_coarse(H, substeps: int) -> bool:
    """Whether the field ``H`` (A/m) moves more than `SCREEN_STEP` of its range per
    substep somewhere: only then can the error exceed `ACCURACY` (and is estimated)."""
    return max_field_step(H) / max(int(substeps), 1) > SCREEN_STEP


def richardson_error(coarse, fine, size: float | None = None) -> float:
    """(16/15)·max|coarse − fine| relative to ``size`` (default max|fine|): the error of
    the simulation at S substeps from the same at 2S."""
    coarse, fine = np.asarray(coarse, float), np.asarray(fine, float)
    size = float(np.max(np.abs(fine))) if size is None else float(size)
    if not size > 0:
        return 0.0
    return 16.0 / 15.0 * float(np.max(np.abs(coarse - fine))) / size


def step_error(coarse, fine, size: float | None = None) -> float:
    """(4/3)·max|coarse − fine| relative to ``size`` (default max|fine|): the error of a
    second-order scheme at a sample step from the same at half the step."""
    return richardson_error(coarse, fine, size) * (4.0 / 3.0) * (15.0 / 16.0)


def refined(drive):
    """``drive`` (a `jaxhyst.Drive` or `jaxhyst.FluxDrive`) with a sample inserted in the
    middle of each interval (the same piecewise-linear drive at half the step): its
    samples are every other one of the result's, which observes twice as many."""
    t, x = np.asarray(drive.t), np.asarray(getattr(drive, "H", getattr(drive, "B", None)))
    t2 = np.empty(2 * t.shape[0] - 1)
    x2 = np.empty_like(t2)
    t2[::2], x2[::2] = t, x
    t2[1::2], x2[1::2] = 0.5 * (t[1:] + t[:-1]), 0.5 * (x[1:] + x[:-1])
    return t2, x2, 2 * drive.run_in


def checked_meanwhile(run, simulation, finite, drive, signal, substeps: int, losses,
                      rebuild) -> tuple:
    """A simulation and its accuracy check's simulations, the check's programs compiled
    beside the simulation's own: ``(sim, mask, more_substeps, finer)``.

    ``simulation()`` runs the simulation, ``run(drive, substeps)`` a check's; ``finite(sim)``
    is the per-sample mask of its finite signals (``mask``). The check's simulations are
    decided from the drive alone: ``more_substeps`` at twice the substeps where ``signal``
    (the drive's observed driving samples) moves far per substep (`may_be_coarse`), and
    with ``losses`` ``finer``, at half the sample step (`refined`; ``rebuild(t2, x2,
    run_in2)`` makes that drive); each None where not simulated, both None where ``mask``
    is not all true. The first one's program compiles in a background thread
    (`jaxhyst._background.meanwhile`, from the caller's first large lowering on), the
    other's in the caller's thread after the simulation; the thread is joined on every
    way out."""
    from .._background import meanwhile

    coarse = may_be_coarse(signal, substeps)
    finer = None if losses is None else rebuild(*refined(drive))
    cases = ([(drive, 2 * substeps)] if coarse else []) + \
        ([(finer, substeps)] if finer is not None else [])
    background = meanwhile(lambda: run(*cases[0])) if cases else None
    try:
        sim = simulation()
        mask = finite(sim)
        if not mask.all():
            return sim, mask, None, None
        later = [run(*case) for case in cases[1:]]
    finally:
        if background is not None:
            background.join()
    checks = ([run(*cases[0])] if cases else []) + later
    return (sim, mask, checks.pop(0) if coarse else None,
            checks.pop(0) if finer is not None else None)


def substeps_for(error: float, substeps: int) -> int:
    """The substeps that bring an estimated ``error`` at ``substeps`` below `ACCURACY`
    (RK4: the error falls with the 4th power of the substep)."""
    if not error > ACCURACY:
        return int(substeps)
    return int(math.ceil(substeps * (error / ACCURACY) ** 0.25 * 1.05))


def sampling_message(error: float, substeps: int, what: str = "the signal") -> str | None:
    """The warning text for an estimated relative ``error`` at ``substeps``, or None if
    it is within `ACCURACY`."""
    if not error > ACCURACY:
        return None
    if error > ROUGH:
        return (f"the sampling is too coarse for {int(substeps)} RK4 substeps: the error of "
                f"{what} is estimated at {error:.2g} of its size (documented: <= "
                f"{ACCURACY:g}), too large to say how many substeps would do: sample the drive "
                "much more finely, or raise the substeps (substeps=, --substeps) many times "
                "and check again.")
    need = substeps_for(error, substeps)
    return (f"the sampling is too coarse for {int(substeps)} RK4 substeps: the error of "
            f"{what} is estimated at {error:.2g} of its size (documented: <= {ACCURACY:g}); "
            f"use {need} substeps or more (substeps={need}, --substeps {need}), or sample "
            "the drive more finely.")
