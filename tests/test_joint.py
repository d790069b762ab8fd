"""Joint multi-loop identification and magnetization-only loops (issue 7)."""

from __future__ import annotations

import os

import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst.identify.joint import NO_ACTUATOR

DATA = os.path.join(os.path.dirname(__file__), "..", "..", "shared", "data",
                    "MnZn_ferrite_BH.csv")
FREQS = (800, 1250)
PER_LOOP = ("lambda_s", "a", "k", "alpha", "c")


def _truth():
    """Table 3 columns: JA parameters per frequency; E, Kz, Mz, Cz shared (the 800 Hz
    values) — the paper's own split."""
    shared = jh.TABLE3[800]
    cols = [jh.TABLE3[f] for f in FREQS]
    theta = np.array([np.asarray(shared.to_array()) for _ in FREQS])
    for i, col in enumerate(cols):
        for n in ("Ms", *PER_LOOP):
            theta[i, jh.NAMES.index(n)] = float(getattr(col, n))
    return jh.Parameters.from_array(theta)


def _bounds(truth):
    lo = np.min(np.abs(np.asarray(truth.to_array())), axis=0) * 0.5
    hi = np.max(np.abs(np.asarray(truth.to_array())), axis=0) * 1.5
    a = jh.NAMES.index("alpha")
    lo[a], hi[a] = -0.1, 0.0
    c = jh.NAMES.index("c")
    lo[c], hi[c] = 0.0, 0.5
    return jh.Bounds(jh.Parameters.from_array(lo), jh.Parameters.from_array(hi))


def test_joint_multi_frequency_fit_recovers_shared_and_per_loop_parameters():
    truth = _truth()
    act = jh.ACTUATOR2
    drives = [jh.sinusoidal_field(f, 8e3, act.Hb, samples_per_period=60) for f in FREQS]
    data = [drives[i].observed(jh.simulate(jh.Parameters.from_array(truth.to_array()[i]),
                                           act, drives[i]).y) for i in range(len(FREQS))]
    # Ms per loop and Mz are fixed (they set the scales of the null directions α̃·Ms and
    # E·Kz·Mz·Cz); λs, a, k, α̃, c per loop; E, Kz, Cz shared. One null direction remains
    # on purpose — every λs[l] → s·λs[l] with E → E/s — and the report must find it.
    space = jh.JointSpace(_bounds(truth), len(FREQS), per_loop=PER_LOOP,
                          fixed={"Ms": np.asarray(truth.Ms), "Mz": float(truth.Mz[0])})
    problem = jh.JointProblem(data, drives, act, space)
    assert problem.space.n_free == 3 + 5 * len(FREQS)
    # at the truth the joint model reproduces the single-loop simulations to ~5e-11 (the
    # loops have different time steps, so the joint scan discretizes the structure per
    # interval instead of once: a different round-off path)
    assert float(problem.cost_u(problem.space.u_from_params(truth))) < 1e-19
    # start 10 % off in every free parameter
    start = jh.Parameters.from_array(np.asarray(truth.to_array()) * 1.1)
    res = jh.solve(problem, start, solver="lm", max_steps=100)
    assert res.cost < 1e-19, res
    rep = res.report
    assert len(rep.null_directions) == 1
    assert set(rep.null_directions[0]["exponents"]) == {"lambda_s[0]", "lambda_s[1]", "E"}
    got = np.asarray(space.free_values(res.params))
    want = np.asarray(space.free_values(truth))
    rel = dict(zip(space.names, np.abs(got / want - 1), strict=True))
    # everything the data determine is recovered, to 1e-6 or to what the data can tell
    # (c[1] = 3e-4 at 1250 Hz barely shows: its error is set by the 5e-11 model round-off,
    # which the Gauss–Newton standard error measures)
    for j, name in enumerate(space.names):
        if not name.startswith("lambda_s") and name != "E":
            err = abs(got[j] - want[j])
            assert err < max(1e-6 * abs(want[j]), 5 * rep.std_errors[name]), (name, rel)
    for i in range(len(FREQS)):  # ... including the identifiable products λs[l]·E
        c = rep.combination({f"lambda_s[{i}]": 1, "E": 1})
        assert c["identifiable"]
        assert abs(c["value"] / (float(truth.lambda_s[i]) * float(truth.E[0])) - 1) < 1e-6
    text = str(res)
    assert "(per loop)" in text and "(shared)" in text and "a[1]" in text


@pytest.mark.skipif(not os.path.exists(DATA), reason="shared/data not present")
def test_mnzn_loops_joint_fit_reaches_the_stated_rms_error():
    from jaxhyst.io import read_loops

    loops = read_loops(DATA)
    assert [lp.n_samples for lp in loops] == [129, 129, 129]
    bounds = jh.Bounds.from_dict({
        "Ms": (1e5, 5e5), "lambda_s": (0.0, 1e-3), "a": (0.5, 100.0), "k": (0.5, 100.0),
        "alpha": (0.0, 1e-3), "c": (0.0, 1.0), "E": (1e10, 5e10), "Kz": (1e7, 5e7),
        "Mz": (0.1, 1.0), "Cz": (0.0, 1e4)})  # fmt: skip
    fixed = {n: 0.5 * (float(getattr(bounds.lower, n)) + float(getattr(bounds.upper, n)))
             for n in jh.identify.joint.STRUCTURAL}
    space = jh.JointSpace(bounds, 3, fixed=fixed)
    drives = [jh.drive_from_record(None, lp.H) for lp in loops]
    problem = jh.JointProblem([lp.signals["B"] for lp in loops], drives, NO_ACTUATOR, space,
                              output="flux_density", variant=jh.ClassicJA(), substeps=4)
    res = jh.solve(problem, np.full(space.n_free, 0.5), solver="lm", max_steps=150)
    # Measured: rms 6.28 mT over the three loops (max |B| 78, 190, 345 mT); the parameters
    # quoted in the data's README give 48–75 mT per loop with the same model (docs).
    print(res)
    assert res.rms_error < 6.5e-3, res.rms_error
    for n in ("Ms", "a", "k", "c"):
        assert res.report.std_errors[n] is not None


def test_loop_problem_from_field_samples_fits_a_synthetic_bh_loop():
    p = jh.TABLE1_TRUE
    H = 2e4 * np.cos(2 * np.pi * np.arange(81) / 80)  # closed loop from the positive tip
    drive = jh.drive_from_record(None, H)
    B = 4e-7 * np.pi * (H + np.asarray(jh.simulate(p, NO_ACTUATOR, drive, substeps=8)
                                       .observed("M")))
    problem = jh.loop_problem(H, B, jh.TABLE1_BOUNDS, output="flux_density",
                              fixed={"Ms": p.Ms})
    assert problem.space.names == ("a", "k", "alpha", "c")
    res = jh.solve(problem, p, solver="lm", max_steps=50)
    for n in problem.space.names:
        assert abs(float(getattr(res.params, n)) / float(getattr(p, n)) - 1) < 1e-8
