"""What a user waits for (issue 45): first calls in fresh processes, the README's
commands, and the compilations a changed number costs — with the figures issue 45
quoted beside them.

    python benchmarks/bench_latency.py [--parts commands,python,compiles]
                                       [--out benchmarks/bench_latency_output.md]

- ``commands``: each README command in a fresh process, wall clock from start to exit,
  with an empty compilation cache (cold) and again with the cache the cold run filled
  (warm): ``identify … --method lm`` on the README's simulated file, ``compensate``,
  ``reproduce table1 --quick`` (cold only), the default ``identify`` on a 2 000-point
  digitized loop (as `bench_measured.py` makes it: the same optimum is checked).
- ``python``: first calls in fresh processes without a persistent cache: a cold LM solve
  and ``jax.hessian`` of the Table 1 loss (``bench_transforms.py --compile-child``), and a
  three-loop rate-dependent multi-start (classic and play forms, 8 starts, eddy and
  excess losses) until its first batched step is compiled.
- ``compiles``: in one process, after a first call, the programs compiled by a second
  call with a new current limit / frequency / tolerance (``compensate``), a new
  frequency and loss value (``simulate``, ``simulate_flux``), new data, frequency and box
  (a joint fit): counted from ``jax.log_compiles``, with the seconds the call took.

Machine and date are written with the table. Run on a quiet machine.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, HERE)
sys.path.insert(0, os.path.join(HERE, "..", "tests"))

#: Issue 45's figures (2-core VMs; "busy" where the issue says so).
BEFORE = {
    "identify --method lm (README file)": "101 s cold (busy)",
    "compensate (README)": "88 s cold (busy)",
    "reproduce table1 --quick": "334 s cold (busy)",
    "identify, 2 000-point loop": "30 s cold, 23 s warm",
    "cold LM solve": "9.1–13.5 s",
    "hessian, first call": "11.7–17.2 s",
    "three-loop rate-dependent multi-start ready": "> 600 s (busy)",
    "compensate: new current limit": "2 compilations, 54 s",
    "compensate: new frequency": "1 compilation, 29 s",
}
TARGETS = {
    "identify --method lm (README file)": "≤ 10 s",
    "compensate (README)": "≤ 8 s",
    "reproduce table1 --quick": "≤ 60 s",
    "identify, 2 000-point loop": "≤ 10 s cold, ≤ 5 s warm",
    "cold LM solve": "≤ 4 s",
    "hessian, first call": "≤ 6 s",
    "three-loop rate-dependent multi-start ready": "≤ 60 s",
}


def _cli(argv, cache, cwd):
    env = {**os.environ, "JAXHYST_CACHE_DIR": cache}
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, "-m", "jaxhyst.cli", *argv], env=env, cwd=cwd,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode not in (0, 3, 4):
        raise RuntimeError(f"{argv}: exit {p.returncode}\n{p.stderr[-2000:]}")
    return wall


def commands() -> list[tuple[str, str]]:
    from bench_measured import loops

    rows = []
    with tempfile.TemporaryDirectory() as d:
        _cli(["simulate", "--samples-per-period", "50", "--csv", "sim.csv"], "off", d)
        cases = [
            ("identify --method lm (README file)",
             ["identify", "sim.csv", "--output", "y", "--fix", "Ms,lambda_s,Mz", "--params",
              "table1", "--method", "lm", "--out", "r.json"], True),
            ("compensate (README)", ["compensate", "--current-limit", "2.5", "--csv",
                                     "comp.csv"], True),
            ("reproduce table1 --quick", ["reproduce", "table1", "--quick", "--out", "t1"],
             False),
        ]
        big = loops(d)["ferrite-digitized"]
        cases.append(("identify, 2 000-point loop", ["identify", big, "--out", "big.json",
                                                     "--progress", "0"], True))
        for name, argv, warm in cases:
            cache = tempfile.mkdtemp(prefix="jaxhyst-cache-")
            cold = _cli(argv, cache, d)
            text = f"{cold:.1f} s cold"
            if warm:
                text += f", {_cli(argv, cache, d):.1f} s warm"
            if name.startswith("identify, 2"):
                with open(os.path.join(d, "big.json")) as fh:
                    text += f" (cost {json.load(fh)['cost']:.6g})"
            rows.append((name, text))
            print(name, text, flush=True)
    return rows


def _child(what):
    """Run in a fresh process: the seconds until ``what`` is ready."""
    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR

    if what.startswith("simulate:"):  # a first call whose accuracy is checked
        import warnings

        warnings.simplefilter("ignore")
        t0 = time.perf_counter()
        if what == "simulate:rate":
            d = jh.sinusoidal_field(300.0, 200.0, 0.0, samples_per_period=48)
            sim = jh.simulate(jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=30.0, k=20.0,
                                            alpha=1e-5, c=0.3, E=1.0, Kz=1.0, Mz=1.0,
                                            Cz=0.0),
                              NO_ACTUATOR, d, jh.ClassicJA(), losses=jh.Losses(0.05, 0.5))
        else:
            d = jh.sinusoidal_current(100.0, 0.77, 1.53, jh.ACTUATOR1, samples_per_period=60)
            sim = jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, d)
        np.asarray(sim.M)
        print(json.dumps({"ready_s": time.perf_counter() - t0}))
        return
    form = {"classic": jh.ClassicJA(), "play": jh.PlayJA(1.0)}[what.split(":")[1]]
    p = jh.Parameters(Ms=3.5e5, lambda_s=0.0, a=30.0, k=20.0, alpha=1e-5, c=0.3, E=1.0,
                      Kz=1.0, Mz=1.0, Cz=0.0)
    t0 = time.perf_counter()
    drives, data = [], []
    for f in (50.0, 200.0, 800.0):
        d = jh.sinusoidal_field(f, 200.0, 0.0, samples_per_period=100)
        sim = jh.simulate(p, NO_ACTUATOR, d, form, losses=jh.Losses(0.05, 0.5))
        drives.append(d)
        data.append(4e-7 * np.pi * np.asarray(sim.observed("H") + sim.observed("M")))
    box = jh.Bounds(p.replace(Ms=1e5, a=5.0, k=2.0, alpha=0.0, c=0.0),
                    p.replace(Ms=1e6, a=150.0, k=90.0, alpha=1e-3, c=1.0))
    fixed = {"lambda_s": 0.0, "E": 1.0, "Kz": 1.0, "Mz": 1.0, "Cz": 0.0}
    space = jh.ParameterSpace.for_model(box, fixed=fixed,
                                        losses={"eddy": (0.0, 1.0), "excess": (0.0, 5.0)},
                                        form=form, n_loops=3)
    problem = jh.JointProblem(data, drives, NO_ACTUATOR, space, output="flux_density",
                              variant=form, substeps=1 if what.endswith("play") else 2)
    starts = np.random.default_rng(0).uniform(0.1, 0.9, (8, space.n_free))
    t_setup = time.perf_counter() - t0
    jh.multistart(problem, starts, max_steps=1, report=False)
    print(json.dumps({"ready_s": time.perf_counter() - t0, "setup_s": t_setup}))


def python_first_calls() -> list[tuple[str, str]]:
    env = dict(os.environ, JAXHYST_CACHE_DIR="off")
    rows = []
    for what, name in (("lm_solve", "cold LM solve"), ("hessian", "hessian, first call")):
        r = subprocess.run([sys.executable, os.path.join(HERE, "bench_transforms.py"),
                            "--compile-child", what, "--spp", "200"], env=env,
                           capture_output=True, text=True, check=True)
        s = json.loads(r.stdout.strip().splitlines()[-1])["first_call_s"]
        rows.append((name, f"{s:.1f} s"))
        print(name, rows[-1][1], flush=True)
    for what, name in (("simulate:coarse", "first simulate, checked (Table 1, 60 samples "
                                           "a period: two programs)"),
                       ("simulate:rate", "first simulate, checked (rate dependent, 48 "
                                         "samples a period: three programs)")):
        r = subprocess.run([sys.executable, __file__, "--child", what], env=env,
                           capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(r.stderr[-2000:])
        rows.append((name, f"{json.loads(r.stdout.strip().splitlines()[-1])['ready_s']:.1f} s"))
        print(rows[-1], flush=True)
    for form in ("classic", "play"):
        r = subprocess.run([sys.executable, __file__, "--child", f"multistart:{form}"],
                           env=env, capture_output=True, text=True)
        if r.returncode:
            raise RuntimeError(r.stderr[-2000:])
        s = json.loads(r.stdout.strip().splitlines()[-1])["ready_s"]
        rows.append((f"three-loop rate-dependent multi-start ready ({form})", f"{s:.1f} s"))
        print(rows[-1], flush=True)
    return rows


def compiles() -> list[tuple[str, str]]:
    """Second calls with changed numbers, counted (tests/test_compiles.py's counter)."""
    from test_compiles import SOFT, _fit, counting

    import jaxhyst as jh
    from jaxhyst.control import sinusoidal_reference

    model = jh.Model(jh.TABLE1_TRUE, jh.ACTUATOR1)
    ref = sinusoidal_reference(100.0, 20e-6, 45e-6)
    rows = []

    def second(name, first, again):
        first()
        t0 = time.perf_counter()
        with counting() as names:
            again()
        rows.append((name, f"{len(names.names)} compilations, "
                           f"{time.perf_counter() - t0:.2f} s"))
        print(rows[-1], flush=True)

    second("compensate: new current limit",
           lambda: jh.compensate(model, ref, current_limit=2.5),
           lambda: jh.compensate(model, ref, current_limit=2.2))
    second("compensate: new frequency",
           lambda: None,
           lambda: jh.compensate(model, sinusoidal_reference(140.0, 20e-6, 45e-6),
                                 current_limit=2.5))
    second("compensate: new tolerance", lambda: None,
           lambda: jh.compensate(model, ref, current_limit=2.5, tolerance=1e-4))
    second("compensate: new step limit (max_steps 7)", lambda: None,
           lambda: jh.compensate(model, ref, current_limit=2.5, max_steps=7))
    drive = lambda f: jh.sinusoidal_current(f, 0.77, 1.53, jh.ACTUATOR1)  # noqa: E731
    second("simulate (rate-dependent): new frequency and loss value",
           lambda: jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive(100.0),
                               losses=jh.Losses(0.05, 0.5)),
           lambda: jh.simulate(jh.TABLE1_TRUE, jh.ACTUATOR1, drive(300.0),
                               losses=jh.Losses(0.02, 0.9)))
    second("simulate_flux: new frequency and loss value",
           lambda: jh.simulate_flux(SOFT, jh.sinusoidal_flux(1000.0, 0.3),
                                    losses=jh.Losses(0.05, 0.5)),
           lambda: jh.simulate_flux(SOFT, jh.sinusoidal_flux(400.0, 0.25),
                                    losses=jh.Losses(0.1, 0.2)))
    box = jh.Bounds(SOFT.replace(a=10.0, k=5.0, c=0.05), SOFT.replace(a=100.0, k=60.0, c=0.9))
    wide = jh.Bounds(SOFT.replace(a=5.0, k=2.0, c=0.0), SOFT.replace(a=150.0, k=90.0, c=1.0))
    second("joint fit: new data, frequency and box",
           lambda: _fit(300.0, 200.0, box, {"eddy": (0.0, 0.2), "excess": (0.0, 2.0)}),
           lambda: _fit(500.0, 150.0, wide, {"eddy": (0.0, 0.4), "excess": (0.0, 1.0)}))
    return rows


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--parts", default="commands,python,compiles")
    ap.add_argument("--out", default=os.path.join(HERE, "bench_latency_output.md"))
    ap.add_argument("--child")
    args = ap.parse_args()
    if args.child:
        return _child(args.child)
    parts = args.parts.split(",")
    rows = []
    if "commands" in parts:
        rows += commands()
    if "python" in parts:
        rows += python_first_calls()
    if "compiles" in parts:
        rows += compiles()
    from bench_simulate import machine

    lines = [f"`python benchmarks/bench_latency.py --parts {args.parts}` — {machine()}", "",
             "| what | now | issue 45 said | target |", "|---|---|---|---|"]
    for name, now in rows:
        key = name.split(" (")[0] if name.startswith("three-loop") else name
        lines.append(f"| {name} | {now} | {BEFORE.get(key, '')} | {TARGETS.get(key, '')} |")
    text = "\n".join(lines) + "\n"
    print(text)
    with open(args.out, "w", encoding="utf-8") as fh:
        fh.write(text)


if __name__ == "__main__":
    main()
