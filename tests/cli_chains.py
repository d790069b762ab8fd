"""Command-line chains run as subprocesses of the real ``jaxhyst`` command, started in the
background when the test session begins (conftest.py) so that their start-up and
compilation overlap the in-process tests; tests/test_cli_subprocess.py checks what they
left in their directory.

    python tests/cli_chains.py e2e|resume|reproduce DIR
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


def e2e(d):
    """simulate → CSV → identify from that CSV (7 identifiable parameters) → JSON."""
    csv = os.path.join(d, "sim.csv")
    rc1 = run(["simulate", "--samples-per-period", "50", "--csv", csv], os.path.join(d, "sim.log"))
    rc2 = run(["identify", csv, "--output", "y", "--fix", "Ms,lambda_s,Mz", "--params",
               "table1", "--method", "lm", "--starts", "1", "--max-steps", "150",
               "--out", os.path.join(d, "result.json")], os.path.join(d, "identify.log"))
    return {"simulate": rc1, "identify": rc2}


def resume(d):
    """identify with a hybrid, SIGKILLed once its first checkpoint exists, then resumed."""
    csv = os.path.join(d, "sim.csv")
    ck = os.path.join(d, "run.npz")
    run(["simulate", "--samples-per-period", "50", "--csv", csv], os.path.join(d, "sim.log"))
    args = ["identify", csv, "--output", "y", "--method", "GATR1", "--population", "24",
            "--generations", "400", "--max-steps", "20", "--checkpoint", ck,
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


def reproduce(d):
    rc = run(["reproduce", "table1", "--quick", "--out", d], os.path.join(d, "reproduce.log"))
    return {"reproduce": rc}


if __name__ == "__main__":
    chain, d = sys.argv[1], sys.argv[2]
    os.makedirs(d, exist_ok=True)
    t0 = time.time()
    status = globals()[chain](d)
    status["seconds"] = time.time() - t0
    with open(os.path.join(d, "status.json.tmp"), "w") as fh:
        json.dump(status, fh)
    os.replace(os.path.join(d, "status.json.tmp"), os.path.join(d, "status.json"))
