"""A long measured-like B(H) loop through the default command (issue 33): the cost must
grow linearly with the data. A noisy synthetic loop (classic JA, 1 mT noise) of N points
is written to a CSV and fitted by ``jaxhyst identify FILE`` (every default), timed from
the start of the process; and a 2-million-row file is read.

    python benchmarks/bench_long_loop.py [--sizes 2000,10000,50000]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))


def loop_csv(path, n, seed=0):
    import jaxhyst as jh

    p = jh.Parameters(Ms=1.2e6, lambda_s=0.0, a=60.0, k=100.0, alpha=1e-4, c=0.2, E=1.0,
                      Kz=1.0, Mz=1.0, Cz=0.0)
    drive = jh.drive_from_record(None, 1000 * np.cos(2 * np.pi * np.arange(n) / n))
    sim = jh.simulate(p, jh.Actuator(1.0, 1.0), drive, jh.ClassicJA(), substeps=4)
    H, M = np.asarray(sim.observed("H")), np.asarray(sim.observed("M"))
    B = 4e-7 * np.pi * (H + M) + 1e-3 * np.random.default_rng(seed).standard_normal(n)
    np.savetxt(path, np.c_[H, B], delimiter=",", header="H [A/m],B [T]", comments="")


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--sizes", default="2000,10000,50000")
    args = ap.parse_args()
    sys.path.insert(0, HERE)
    from bench_simulate import machine

    print(machine())
    exe = [sys.executable, "-m", "jaxhyst.cli"]
    print("\n| points | wall (s), default command | exit | rms (mT) |\n|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        for n in (int(x) for x in args.sizes.split(",")):
            path, out = os.path.join(d, f"loop{n}.csv"), os.path.join(d, f"r{n}.json")
            loop_csv(path, n)
            t0 = time.perf_counter()
            rc = subprocess.run([*exe, "identify", path, "--out", out],
                                capture_output=True, text=True).returncode
            wall = time.perf_counter() - t0
            import json

            rms = json.load(open(out))["rms_error"] * 1e3 if os.path.exists(out) else None
            print(f"| {n} | {wall:.1f} | {rc} | {rms:.3f} |", flush=True)
        big = os.path.join(d, "big.csv")
        H = 1000 * np.cos(2 * np.pi * np.arange(2_000_000) / 2000)
        np.savetxt(big, np.c_[H, 1.5 * np.tanh(H / 300)], delimiter=",",
                   header="H [A/m],B [T]", comments="")
        from jaxhyst.io import read_loops

        t0 = time.perf_counter()
        read_loops(big)
        print(f"\nreading 2 000 000 rows: {time.perf_counter() - t0:.1f} s")


if __name__ == "__main__":
    main()
