"""Times of loops recorded without them (`jaxhyst.loop_times`): taken from each loop's
frequency where its samples are a sinusoid's, uniform in time, and from nothing else."""

from __future__ import annotations

import numpy as np
import pytest

import jaxhyst as jh
from jaxhyst.cli.candidates import CANDIDATES, RATE_CANDIDATES, candidates
from jaxhyst.cli.parser import build_parser
from jaxhyst.cli.spec import read_data
from jaxhyst.loop_times import TOLERANCE, sinusoid_fit


@pytest.mark.parametrize("closed", [True, False])
@pytest.mark.parametrize("per_period", [128, 200, 1000])
def test_a_uniformly_sampled_sinusoid_gives_its_whole_samples_a_period(per_period, closed):
    rng = np.random.default_rng(per_period)
    i = np.arange(per_period + closed)
    x = 5.0 + 120.0 * np.sin(2 * np.pi * i / per_period + 0.4)
    period, residual = sinusoid_fit(x + 0.5 * rng.standard_normal(i.shape))  # 0.4 % noise
    assert period == per_period and residual < 0.006
    period, residual = sinusoid_fit(x)
    assert period == per_period and residual < 1e-12
    # two periods in the record, and a period of no whole number of samples
    assert sinusoid_fit(np.sin(2 * np.pi * np.arange(2 * per_period) / per_period))[0] == \
        per_period
    p, r = sinusoid_fit(np.sin(2 * np.pi * np.arange(400) / 333.3))
    assert abs(p - 333.3) < 1e-3 and r < 1e-6


def test_what_is_not_a_uniformly_sampled_sinusoid_is_told_apart():
    i = np.arange(201)
    triangle = 2 / np.pi * np.arcsin(np.sin(2 * np.pi * i / 200))
    assert sinusoid_fit(triangle)[1] > 2 * TOLERANCE  # (a triangle leaves 6.6 %)
    # a loop digitized along its length: equal steps of arc length on H, B
    s = np.linspace(0.0, 2 * np.pi, 4001)
    H, B = 100 * np.sin(s), np.tanh(3 * np.sin(s - 0.3))
    arc = np.concatenate([[0], np.cumsum(np.hypot(np.diff(H) / 200, np.diff(B) / 2))])
    at = np.interp(np.linspace(0, arc[-1], 150), arc, s)
    assert sinusoid_fit(100 * np.sin(at))[1] > TOLERANCE
    assert sinusoid_fit(np.tanh(3 * np.sin(at - 0.3)))[1] > TOLERANCE
    assert np.isinf(sinusoid_fit(np.ones(50))[1]) and np.isinf(sinusoid_fit(np.ones(5))[1])


def _write(path, loops, with_t=True, triangle=None):
    cols = ["loop", "frequency", *(["t_s"] if with_t else []), "H_A_per_m", "B_T"]
    rows = []
    for k, (f, n) in enumerate(loops):
        t = np.arange(n + 1) / (n * f)
        H = 120 * np.sin(2 * np.pi * f * t)
        if k == triangle:
            H = 120 * 2 / np.pi * np.arcsin(np.sin(2 * np.pi * f * t))
        B = 0.4 * np.tanh(H / 60 + 0.3 * np.cos(2 * np.pi * f * t))
        rows += [(k, f, *([tt] if with_t else []), h, b) for tt, h, b in
                 zip(t, H, B, strict=True)]
    with open(path, "w", encoding="utf-8") as fh:
        fh.write(",".join(cols) + "\n")
        fh.writelines(",".join(f"{v:.17g}" for v in r) + "\n" for r in rows)
    return path


def test_loops_with_a_frequency_and_no_times_get_the_times_they_were_sampled_at(tmp_path):
    family = [(50.0, 200), (100.0, 200), (400.0, 128)]
    timed = read_data(_write(tmp_path / "t.csv", family))
    untimed = jh.io.read_loops(_write(tmp_path / "u.csv", family, with_t=False))
    assert all(lp.t is None for lp in untimed)
    loops, text = jh.times_from_frequency(untimed)
    for lp, ref in zip(loops, timed, strict=True):
        np.testing.assert_allclose(lp.t, ref.t, rtol=0, atol=1e-12 * ref.t[-1])
    assert "200–128" not in text and "128–200 samples a period" in text
    assert all(lp.t is None for lp in untimed)  # (the loops given are not changed)
    # the command line reads them alike, says so, and compares the rate mechanisms
    said = []
    loops = read_data(tmp_path / "u.csv", said=said)
    assert said[0].startswith("times from the loops' frequencies")
    args = build_parser().parse_args(["identify", str(tmp_path / "u.csv"), "--joint",
                                      "--leave-one-out"])
    assert tuple(candidates(args, loops)) == RATE_CANDIDATES


def test_one_loop_that_is_not_a_sinusoid_leaves_every_loop_without_times(tmp_path):
    path = _write(tmp_path / "u.csv", [(50.0, 200), (100.0, 200), (200.0, 200)],
                  with_t=False, triangle=1)
    loops, text = jh.times_from_frequency(jh.io.read_loops(path))
    assert all(lp.t is None for lp in loops)
    assert text.startswith("loop 1 has a frequency and no t column") and "give a t column" \
        in text and "\n" not in text
    args = build_parser().parse_args(["identify", str(path), "--joint", "--leave-one-out"])
    assert tuple(candidates(args, loops)) == CANDIDATES
    # no frequency column: nothing to say
    plain = [lp for lp in jh.io.read_loops(path)]
    for lp in plain:
        lp.conditions.clear()
    assert jh.times_from_frequency(plain) == (plain, None)


def test_identify_says_how_the_loops_got_times_only_once_its_input_is_checked(tmp_path,
                                                                               capsys):
    from jaxhyst.cli import main

    path = _write(tmp_path / "u.csv", [(50.0, 64), (100.0, 64)], with_t=False)
    assert main(["identify", str(path), "--joint", "--vary", "k:pressure"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "--vary 'k:pressure'" in err  # (bad input: one line)


def test_half_a_period_is_not_taken_for_a_period():
    from jaxhyst.io import Loop

    half = Loop(0, None, 120 * np.sin(np.linspace(0, np.pi, 100)), None, {},
                {"frequency": 50.0})
    loops, text = jh.times_from_frequency([half])
    assert loops[0].t is None and "holds less than one period" in text


def test_arrays_instead_of_loops_are_refused_in_one_line():
    # (a NumPy array used to fail with "'numpy.float64' object has no attribute 't'")
    with pytest.raises(TypeError, match=r"takes loops as jaxhyst.io.read_loops gives them"):
        jh.times_from_frequency(np.sin(np.arange(200) * 2 * np.pi / 100))
