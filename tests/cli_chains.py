"""Command-line chains run as subprocesses of the real ``jaxhyst`` command, started in the
background when the test session begins (conftest.py) so that their start-up and
compilation overlap the in-process tests; tests/test_cli_subprocess.py checks what they
left in their directory.

    python tests/cli_chains.py resume|reproduce|sharding|measured|compensate|docs DIR
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time


def jaxhyst_cmd() -> list[str]:
    exe = shutil.which("jaxhyst")
    return [exe] if exe else [sys.executable, "-m", "jaxhyst.cli"]


def run(args, out, **kw):
    with open(out, "w") as log:
        return subprocess.run(jaxhyst_cmd() + args, stdout=log, stderr=subprocess.STDOUT,
                              **kw).returncode


def resume(d):
    """identify with a hybrid, SIGKILLed once its first checkpoint exists, then resumed."""
    csv = os.path.join(d, "sim.csv")
    ck = os.path.join(d, "run.npz")
    run(["simulate", "--samples-per-period", "50", "--csv", csv], os.path.join(d, "sim.log"))
    args = ["identify", csv, "--output", "y", "--method", "GATR1", "--population", "24",
            "--generations", "405", "--max-steps", "20", "--checkpoint", ck,
            "--checkpoint-every", "1", "--progress", "1", "--seed", "5",
            "--out", os.path.join(d, "result.json")]
    log = open(os.path.join(d, "first.log"), "w")
    proc = subprocess.Popen(jaxhyst_cmd() + args, stdout=log, stderr=subprocess.STDOUT)
    killed_at = None
    while proc.poll() is None:
        if os.path.exists(ck):
            proc.send_signal(signal.SIGKILL)
            killed_at = time.time()
            break
        time.sleep(0.02)
    first_rc = proc.wait()
    log.close()
    rc = run(args + ["--resume"], os.path.join(d, "second.log"))
    return {"killed": killed_at is not None, "first": first_rc, "second": rc}


def sharding(d):
    """The same GA with and without its population sharded over 2 host devices (a fresh
    process: XLA_FLAGS must be set before jax starts)."""
    env = dict(os.environ, XLA_FLAGS="--xla_force_host_platform_device_count=2")
    with open(os.path.join(d, "sharding.log"), "w") as log:
        rc = subprocess.run([sys.executable, __file__, "sharding_inner", d], env=env,
                            stdout=log, stderr=subprocess.STDOUT).returncode
    return {"sharding": rc}


def sharding_inner(d):
    import jax
    import numpy as np
    from helpers import table1_problem

    import jaxhyst as jh

    jh.enable_compilation_cache()  # (as the suite and the command line do)
    out = {"devices": jax.device_count()}
    problem = table1_problem(spp=50)
    # the plain GA: sharding splits the population's evaluation, which every hybrid
    # shares; a hybrid's local search runs on one individual, on one device, and would
    # only add programs to compile (twice: sharded and not)
    small = dict(q1=24, q2=10, T1=2, T2=6, check_steps=0)
    runs = {s: jh.run_hybrid(problem, "GA", seed=2, settings={**small, "shard": s},
                             report=False) for s in (True, False)}
    a, b = runs[True], runs[False]
    out["ga_cost"] = [a.cost, b.cost]
    # (relative to the cost, floored at 1e-16)
    out["ga_history_max_rel_diff"] = max(
        abs(x["best_cost"] - y["best_cost"]) / max(y["best_cost"], 1e-16)
        for x, y in zip(a.extra["history"], b.extra["history"], strict=True))
    out["ga_params_max_rel_diff"] = float(np.max(np.abs(
        np.asarray(a.params.to_array()) / np.asarray(b.params.to_array()) - 1)))
    out.update(_sharded_loops())
    return out


def _sharded_loops():
    """A two-loop joint problem with its loops split over the two devices: residuals and
    their Jacobian (what every local solver uses) against the unsharded problem."""
    import equinox as eqx
    import jax
    import numpy as np

    import jaxhyst as jh

    act = jh.ACTUATOR2
    truth = jh.TABLE3[800]
    drives = [jh.sinusoidal_field(f, 8e3, act.Hb, samples_per_period=40) for f in (800, 1250)]
    data = [np.asarray(d.observed(jh.simulate(truth, act, d).y)) for d in drives]
    x = np.asarray(truth.to_array())
    bounds = jh.Bounds(jh.Parameters.from_array(np.minimum(0.5 * x, 1.5 * x)),
                       jh.Parameters.from_array(np.maximum(0.5 * x, 1.5 * x)))
    space = jh.JointSpace(bounds, 2, per_loop=("a", "k", "c"),
                          fixed={"Ms": float(truth.Ms), "Mz": float(truth.Mz)})
    z = space.z_from_params(jh.Parameters.from_array(
        np.tile(np.asarray(truth.to_array()) * 1.05, (2, 1))))

    @eqx.filter_jit
    def evaluate(problem, z):
        return problem.predict_loops(problem.space.params_from_z(z)), \
            problem.residuals(z), jax.jacfwd(problem.residuals)(z)

    out = {}
    for shard in (True, False):
        problem = jh.JointProblem(data, drives, act, space, shard_loops=shard)
        loops, r, J = evaluate(problem, z)
        out[shard] = (np.asarray(r), np.asarray(J))
        if shard:  # really split: one loop's rows on each device
            out["loops_split"] = problem.shard_loops and [
                s.data.shape[0] for s in loops.addressable_shards] == [1, 1]
    scale = np.max(np.abs(out[False][1]))
    return {"loops_sharded": bool(out["loops_split"]),
            "loops_residual_max_diff": float(np.max(np.abs(out[True][0] - out[False][0]))),
            "loops_jacobian_max_rel_diff": float(np.max(np.abs(out[True][1] - out[False][1]))
                                                 / scale)}


def reproduce(d):
    """reproduce table1 --quick, interrupted (SIGINT) once its first run is done: it must
    exit 130 with files that say they are partial. (The whole quick run is the docs
    chain's.)"""
    part = os.path.join(d, "partial")
    log_path = os.path.join(d, "partial.log")
    with open(log_path, "w") as log:
        proc = subprocess.Popen(jaxhyst_cmd() + ["reproduce", "table1", "--quick", "--out",
                                                 part], stdout=log, stderr=subprocess.STDOUT)
        deadline = time.time() + 600
        while proc.poll() is None and time.time() < deadline:
            with open(log_path) as fh:
                if "GATR1 seed 0:" in fh.read():
                    proc.send_signal(signal.SIGINT)
                    break
            time.sleep(0.1)
        partial_rc = proc.wait(timeout=600)
    return {"partial": partial_rc}


def measured(d):
    """A digitized-like B–H loop (noisy H, starting mid-branch, no time column) through the
    default command; then a bounds file naming only k (its box above the truth: k ends
    on its bound, exit 4), a fit stopped at its step limit (exit 3), --start from the
    first result (written to a sub-directory: the data path is stored relative to it)
    and report on that result."""
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    import numpy as np
    from test_measured import _digitized

    H, B = _digitized(seed=4)
    csv = os.path.join(d, "loop.csv")
    np.savetxt(csv, np.c_[H, 1e3 * B], delimiter=",", header="H [A/m],B [mT]", comments="")
    box = os.path.join(d, "kbox.json")
    with open(box, "w") as fh:
        json.dump({"k": [12.5, 40.0]}, fh)
    r1, r2 = os.path.join(d, "first.json"), os.path.join(d, "sub", "again.json")
    return {
        "default": run(["identify", csv, "--out", r1, "--png", os.path.join(d, "fit.png")],
                       os.path.join(d, "default.log")),
        "at_bound": run(["identify", csv, "--bounds", box, "--starts", "1", "--start", r1],
                        os.path.join(d, "at_bound.log")),
        "short": run(["identify", csv, "--max-steps", "2", "--starts", "1"],
                     os.path.join(d, "short.log")),
        "start": run(["identify", csv, "--start", r1, "--out", r2],
                     os.path.join(d, "start.log")),
        "report": run(["report", r2], os.path.join(d, "report.log"), cwd="/"),
    }


def compensate(d):
    """jaxhyst compensate: a sine on Actuator1 (CSV, PNG, JSON); then the chain a lab runs,
    on a simulated plant whose λs and k differ from the model's: ``simulate --drive`` the
    written current on the plant (a sensor with 0.3 % noise, its current column the input
    applied) → ``compensate --measured --state`` → ``simulate --drive`` the next current →
    ``compensate --measured --state`` again; a reference beyond the stroke (exit 3)."""
    import json

    import numpy as np

    import jaxhyst as jh
    from jaxhyst.control import sinusoidal_reference
    from jaxhyst.control.compensate import rms_error
    from jaxhyst.control.tracking import Tracking, evaluate

    base = ["compensate", "--current-limit", "2.5", "--amplitude", "20e-6", "--mean", "45e-6"]
    out = {"first": run([*base, "--csv", os.path.join(d, "first.csv"), "--png",
                         os.path.join(d, "first.png"), "--out", os.path.join(d, "first.json")],
                        os.path.join(d, "first.log"))}
    plant = jh.TABLE1_TRUE.replace(lambda_s=1.1e-3, k=3500.0)
    with open(os.path.join(d, "plant.json"), "w") as fh:
        json.dump(plant.to_dict(), fh)
    measure = Tracking.of(jh.Model(plant, jh.ACTUATOR1), sinusoidal_reference(
        100.0, 20e-6, 45e-6), 16)
    reference = sinusoidal_reference(100.0, 20e-6, 45e-6)
    errors, drive = [], os.path.join(d, "first.csv")
    for k in (1, 2):
        if out.get("first") != 0 or out.get(f"learn{k - 1}", 0) != 0:
            break
        table = np.loadtxt(drive, delimiter=",", skiprows=1)
        errors.append(rms_error(evaluate(measure, table[:, 1]), reference.displacement,
                                reference.scale))
        run_k = os.path.join(d, f"run{k}.csv")
        out[f"simulate{k}"] = run(["simulate", "--drive", drive, "--params",
                                   os.path.join(d, "plant.json"), "--run-in-periods", "4",
                                   "--noise", "0.003", "--seed", str(k), "--csv", run_k],
                                  os.path.join(d, f"simulate{k}.log"))
        drive = os.path.join(d, f"next{k}.csv")
        out[f"learn{k}"] = run([*base, "--measured", run_k, "--state",
                                os.path.join(d, "state.json"), "--csv", drive, "--out",
                                os.path.join(d, f"learn{k}.json")],
                               os.path.join(d, f"learn{k}.log"))
    if out.get("learn2") == 0:
        table = np.loadtxt(drive, delimiter=",", skiprows=1)
        errors.append(rms_error(evaluate(measure, table[:, 1]), reference.displacement,
                                reference.scale))
    out["plant_errors"] = errors
    out["beyond"] = run(["compensate", "--current-limit", "1", "--amplitude", "60e-6",
                         "--mean", "50e-6", "--out", os.path.join(d, "beyond.json")],
                        os.path.join(d, "beyond.log"))
    return out


def docs(d):
    """The documentation: everything docs/generate.py runs (the examples, the pages'
    commands — among them the getting-started commands and the quick Table 1, 2 and 3
    studies, which the command-line tests check here — and the accuracy table), then
    ``mkdocs build --strict`` from what it generated."""
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    gen = os.path.join(d, "gen")
    with open(os.path.join(d, "generate.log"), "w") as log:
        rc = subprocess.run([sys.executable, os.path.join(root, "docs", "generate.py"), gen],
                            cwd=root, stdout=log, stderr=subprocess.STDOUT).returncode
    status = {"generate": rc}
    try:
        import mkdocs  # noqa: F401
    except ImportError:
        return status  # (the docs tests skip where mkdocs is not installed)
    exe = shutil.which("mkdocs")
    cmd = [exe] if exe else [sys.executable, "-m", "mkdocs"]
    env = dict(os.environ, JAXHYST_DOCS_GENERATED=gen, NO_MKDOCS_2_WARNING="1")
    with open(os.path.join(d, "build.log"), "w") as log:
        status["build"] = subprocess.run(cmd + ["build", "--strict", "-d",
                                                os.path.join(d, "site")], cwd=root, env=env,
                                         stdout=log, stderr=subprocess.STDOUT).returncode
    return status


if __name__ == "__main__":
    sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))
    chain, d = sys.argv[1], sys.argv[2]
    # A session of its own (conftest.py) is an autogroup of its own where the kernel has
    # autogroups, and `nice` then acts only inside it: each chain would take as much CPU
    # as the whole in-process run. Lower the group's weight too (Linux; elsewhere nice).
    try:
        with open("/proc/self/autogroup", "w") as fh:
            fh.write("10")
    except OSError:
        pass
    os.makedirs(d, exist_ok=True)
    t0 = time.time()
    status = globals()[chain](d)
    status["seconds"] = time.time() - t0
    name = "inner.json" if chain == "sharding_inner" else "status.json"
    with open(os.path.join(d, name + ".tmp"), "w") as fh:
        json.dump(status, fh)
    os.replace(os.path.join(d, name + ".tmp"), os.path.join(d, name))
