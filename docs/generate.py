"""Every figure and measured number on the documentation site that a short run can make,
produced by running the code: the examples, the commands the pages show, the paper's
quick studies, the Fig. 8 phases, the accuracy and sampling tables and the parameter
table. (The slow benchmarks' numbers are included from their own output files.)

    python docs/generate.py OUTDIR [STEP ...]

writes ``OUTDIR/generated/<step>/`` (figures, Markdown fragments the pages include, the
logs) and ``OUTDIR/generated/<step>/status.json`` (exit status of every command, seconds).
A step whose commands all succeeded is stamped with the sources' fingerprint and kept by
the next run of the same sources: a build stopped part-way resumes at the step it was in.
The mkdocs hook (``docs/hooks.py``) runs it when the package, the examples or this file
changed since the last run; the tests run it once and check what it wrote.
Progress goes to stdout from the first second: one line per command, with its time.
"""

from __future__ import annotations

import hashlib
import json
import shutil
import subprocess
import sys
import time
import warnings
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent

#: The runnable examples (examples/<name>.py), each with a page under docs/examples/.
EXAMPLES = ("identify_actuator", "fit_bh_loop", "composability", "population",
            "unseen_frequency", "compensation")

#: The files whose content the generated output depends on.
SOURCES = ("jaxhyst", "examples", "docs/generate.py", "tests/helpers.py", "pyproject.toml")


def fingerprint() -> str:
    """SHA-256 over the sources the output depends on (paths and contents)."""
    h = hashlib.sha256()
    for entry in SOURCES:
        path = ROOT / entry
        files = sorted(path.rglob("*.py")) if path.is_dir() else [path]
        for f in files:
            if "__pycache__" in f.parts:
                continue
            h.update(str(f.relative_to(ROOT)).encode())
            h.update(f.read_bytes())
    return h.hexdigest()


def _jaxhyst() -> list[str]:
    exe = shutil.which("jaxhyst")
    return [exe] if exe else [sys.executable, "-m", "jaxhyst.cli"]


class Step:
    """One step's directory, its commands (run in order, each logged) and its status;
    a step that finished every command with exit 0 stamps its directory with the
    sources' fingerprint, so that a build stopped later resumes after it."""

    def __init__(self, out: Path, name: str):
        self.dir = out / "generated" / name
        if self.dir.exists():
            shutil.rmtree(self.dir)
        self.dir.mkdir(parents=True)
        self.name = name
        self.status: dict = {}

    @staticmethod
    def done(out: Path, name: str, stamp: str) -> bool:
        """Whether step ``name`` under ``out`` finished without a failure for the sources
        of fingerprint ``stamp`` (its output is then kept)."""
        d = out / "generated" / name
        try:
            status = json.loads((d / "status.json").read_text())
            ok = (d / "fingerprint").read_text() == stamp
        except (OSError, ValueError):
            return False
        return ok and all(rc == 0 for k, rc in status.items() if not k.endswith("_seconds"))

    def run(self, label: str, argv: list[str], *, stdout_to: str | None = None,
            here: bool = False) -> int:
        """Run ``argv`` in the repository root (``here``: in the step's directory, so that
        a command's relative file names are those its page shows); stdout to
        ``stdout_to`` (or ``<label>.log``), stderr to ``<label>.err``; record its exit
        status."""
        t0 = time.perf_counter()
        print(f"[docs] {self.name}: {label} …", flush=True)
        out_path = self.dir / (stdout_to or f"{label}.log")
        with open(out_path, "w") as out, open(self.dir / f"{label}.err", "w") as err:
            rc = subprocess.run(argv, cwd=self.dir if here else ROOT, stdout=out,
                                stderr=err).returncode
        seconds = time.perf_counter() - t0
        self.status[label] = rc
        self.status[f"{label}_seconds"] = round(seconds, 1)
        print(f"[docs] {self.name}: {label} exit {rc} in {seconds:.0f} s", flush=True)
        return rc

    def write(self, name: str, text: str) -> None:
        (self.dir / name).write_text(text)

    def finish(self) -> dict:
        self.write("status.json", json.dumps(self.status, indent=1))
        return self.status


def getting_started(step: Step) -> None:
    """The getting-started page's commands, as printed there."""
    jh = _jaxhyst()
    step.run("simulate", jh + ["simulate", "--samples-per-period", "50", "--csv", "sim.csv"],
             here=True)
    step.run("identify", jh + ["identify", "sim.csv", "--output", "y", "--fix", "Ms,lambda_s,Mz",
                               "--params", "table1", "--method", "lm", "--starts", "1",
                               "--out", "result.json", "--png", "fit.png"], here=True)
    step.run("report", jh + ["report", "result.json", "--profile", "k", "--png", "report.png"],
             here=True)


def reproduce(step: Step) -> None:
    """The paper's studies, quick (the reproducing page's tables and figures)."""
    jh = _jaxhyst()
    step.run("table1", jh + ["reproduce", "table1", "--quick", "--out", "table1", "--png"],
             here=True)
    step.run("table3", jh + ["reproduce", "table3", "--quick", "--out", "table3", "--png"],
             here=True)
    step.run("table2", jh + ["reproduce", "table2", "--quick", "--out", "table2"], here=True)
    step.run("frequency_response", jh + ["frequency-response", "--params", "table3:10",
                                         "--png", "fr.png"], here=True)
    step.run("phases", [sys.executable, __file__, "--phases", str(step.dir / "phases.md")])


def examples(step: Step) -> None:
    """Each example run as a user would (``python examples/NAME.py OUTDIR``), its printed
    output kept for its page; the compilation cache on, as the command line has it."""
    runner = ("import runpy, sys, jaxhyst; jaxhyst.enable_compilation_cache(); "
              "sys.argv = sys.argv[1:]; runpy.run_path(sys.argv[0], run_name='__main__')")
    for name in EXAMPLES:
        step.run(name, [sys.executable, "-c", runner, str(ROOT / "examples" / f"{name}.py"),
                        str(step.dir)], stdout_to=f"{name}.txt")


def accuracy(step: Step) -> None:
    """The theory page's accuracy table (against the independent DOP853 solution) and the
    loops page's sampling table."""
    step.run("table", [sys.executable, __file__, "--accuracy", str(step.dir / "table.md")])
    step.run("sampling", [sys.executable, __file__, "--sampling",
                          str(step.dir / "sampling.md")])


def reference(step: Step) -> None:
    """The API page's table of the ten parameters (from the package's own constants)."""
    step.run("parameters", [sys.executable, __file__, "--parameters",
                            str(step.dir / "parameters.md")])


STEPS = {"reference": reference, "getting_started": getting_started, "examples": examples,
         "reproduce": reproduce, "accuracy": accuracy}


# -- the two computed fragments ------------------------------------------------------------

def write_phases(path: str) -> None:
    """Phase lag of eq 13 at the paper's five frequencies — with the structural values its
    Fig. 8 caption prints and with Table 3's 10 Hz column — next to the phases it quotes."""
    import numpy as np

    import jaxhyst as jh

    freqs = (10.0, 800.0, 1000.0, 1250.0, 2000.0)
    quoted = (0.16, 42.76, 62.59, 114.38, 157.16)
    caption = jh.Parameters(**{**jh.TABLE3[10].to_dict(), "E": 2.22e10, "Mz": 0.54,
                               "Cz": 2010.0, "Kz": 2.64e7})

    def lags(p):
        G = np.asarray(jh.frequency_response(p, jh.ACTUATOR2, freqs))
        return " | ".join(f"{x:.2f}" for x in -np.degrees(np.angle(G)))

    rows = ["| phase lag (°) at f (Hz) = | " + " | ".join(f"{f:g}" for f in freqs) + " |",
            "|---" * (len(freqs) + 1) + "|",
            "| quoted by the paper for its Fig. 8 | " + " | ".join(f"{q:g}" for q in quoted)
            + " |",
            f"| eq 13, the caption's E = 2.22e10, Mz = 0.54, Cz = 2010, Kz = 2.64e7 | "
            f"{lags(caption)} |",
            f"| eq 13, Table 3's 10 Hz column | {lags(jh.TABLE3[10])} |"]
    Path(path).write_text("\n".join(rows) + "\n\n(Actuator2's Ar and lr; "
                          "`docs/generate.py --phases`.)\n")


def write_accuracy(path: str) -> None:
    """max|Δy|/max|y| against the DOP853 reference for the five cases of the tests."""
    import numpy as np

    sys.path.insert(0, str(ROOT / "tests"))
    from helpers import cases, reference_simulation

    import jaxhyst as jh

    labels = {"table1_100Hz": "Table 1, 100 Hz, 200 samples/period",
              "act2_10Hz": "Actuator2, Table 3 10 Hz column",
              "act2_1000Hz": "Actuator2, Table 3 1000 Hz column",
              "minor_loop": "minor loop inside a biased major loop",
              "reversing": "13th harmonic ripple (reverses every ~7 samples)"}
    substeps = (1, 2, 4, 8, 16)
    # (1 substep is coarse on purpose here: the warning it gives is the table's subject)
    warnings.simplefilter("ignore", jh.model.accuracy.SamplingWarning)
    rows = ["| case | 1 | 2 (default) | 4 | 8 (fine) | 16 substeps |", "|---|---|---|---|---|---|"]
    for name, p, act, drive in cases():
        y_ref = reference_simulation(p, act, drive)[1]
        errs = [float(np.max(np.abs(np.asarray(jh.simulate(p, act, drive, substeps=s).y)
                                    - y_ref)) / np.max(np.abs(y_ref))) for s in substeps]
        rows.append(f"| {labels[name]} | " + " | ".join(f"{e:.1e}" for e in errs) + " |")
    Path(path).write_text("\n".join(rows) + "\n")


def write_sampling(path: str) -> None:
    """max|ΔM|/max|M| of a closed B–H loop sampled N times, at the default 2 substeps,
    against 64 substeps, for two materials (classic JA form, no actuator)."""
    import numpy as np

    import jaxhyst as jh
    from jaxhyst.identify.joint import NO_ACTUATOR

    warnings.simplefilter("ignore", jh.model.accuracy.SamplingWarning)
    materials = {
        "Table 1 material, ±20 kA/m": (jh.TABLE1_TRUE, 20e3),
        "ferrite-like (a = 14 A/m), ±100 A/m": (jh.Parameters(
            Ms=3.2e5, lambda_s=0.0, a=14.0, k=11.0, alpha=1.2e-5, c=0.5, E=1.0, Kz=1.0,
            Mz=1.0, Cz=1.0), 100.0),
    }
    sizes = (20, 40, 80, 160, 320)
    rows = ["| samples per loop | " + " | ".join(str(n) for n in sizes) + " |",
            "|---" * (len(sizes) + 1) + "|",
            "| field step per substep at 2 substeps (of the range) | "
            + " | ".join(f"{100 * np.pi / (2 * n):.1f} %" for n in sizes) + " |"]
    for label, (p, amplitude) in materials.items():
        errs = []
        for n in sizes:
            H = amplitude * np.cos(2 * np.pi * np.arange(n + 1) / n)
            drive = jh.drive_from_record(None, H)
            M = [np.asarray(jh.simulate(p, NO_ACTUATOR, drive, variant=jh.ClassicJA(),
                                        substeps=s).observed("M")) for s in (2, 64)]
            errs.append(float(np.max(np.abs(M[0] - M[1])) / np.max(np.abs(M[1]))))
        rows.append(f"| {label}, 2 substeps | " + " | ".join(f"{e:.1e}" for e in errs) + " |")
    Path(path).write_text("\n".join(rows) + "\n")


def write_parameters(path: str) -> None:
    """The ten parameters: symbol, unit, the paper's Table 1 values and search box, and
    the plausible range the input checks allow (`jaxhyst.params.PHYSICAL_RULES`)."""
    import jaxhyst as jh
    from jaxhyst.params import STRUCTURAL, UNITS

    meaning = {"Ms": ("M_s", "saturation magnetization"),
               "lambda_s": ("\\lambda_s", "saturation magnetostriction"),
               "a": ("a", "anhysteretic shape parameter"),
               "k": ("k", "pinning (coercivity) parameter"),
               "alpha": ("\\tilde\\alpha", "interdomain (mean-field) coupling"),
               "c": ("c", "reversible fraction"),
               "E": ("E", "Young's modulus of the rod"),
               "Kz": ("K_z", "equivalent stiffness"),
               "Mz": ("M_z", "equivalent mass"),
               "Cz": ("C_z", "equivalent damping")}
    enters = {n: "y" for n in STRUCTURAL} | {"lambda_s": "λ, y"}
    rows = ["| name | symbol | meaning | unit | Table 1 value | Table 1 box | enters |",
            "|---|---|---|---|---|---|---|"]
    lo, hi = jh.TABLE1_BOUNDS.lower, jh.TABLE1_BOUNDS.upper
    for n in jh.NAMES:
        sym, what = meaning[n]
        rows.append(f"| `{n}` | ${sym}$ | {what} | {UNITS[n]} | "
                    f"{float(getattr(jh.TABLE1_TRUE, n)):.4g} | "
                    f"[{float(getattr(lo, n)):.4g}, {float(getattr(hi, n)):.4g}] | "
                    f"{enters.get(n, 'M, B, λ, y')} |")
    Path(path).write_text("\n".join(rows) + "\n")


#: The computed fragments, each written by ``generate.py --NAME PATH`` (a step runs it).
FRAGMENTS = {"--parameters": write_parameters, "--sampling": write_sampling,
             "--phases": write_phases, "--accuracy": write_accuracy}


def main(argv: list[str]) -> int:
    if argv[:1] and argv[0] in FRAGMENTS:
        FRAGMENTS[argv[0]](argv[1])
        return 0
    if not argv or argv[0].startswith("-"):
        usage = next(line for line in __doc__.splitlines() if "docs/generate.py OUTDIR" in line)
        print(f"usage: {usage.strip()}", file=sys.stderr)
        return 2
    out, names = Path(argv[0]), argv[1:] or list(STEPS)
    unknown = [n for n in names if n not in STEPS]
    if unknown:
        print(f"generate.py: unknown step {unknown[0]!r}; the steps are "
              f"{', '.join(STEPS)}.", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    failed, stamp = [], fingerprint()
    for name in names:
        if Step.done(out, name, stamp):  # (an interrupted build resumes after it)
            print(f"[docs] {name}: kept from an earlier run of these sources", flush=True)
            continue
        step = Step(out, name)
        STEPS[name](step)
        status = step.finish()
        bad = [f"{name}/{label}" for label, rc in status.items()
               if not label.endswith("_seconds") and rc != 0]
        if not bad:
            (step.dir / "fingerprint").write_text(stamp)
        failed += bad
    if set(names) == set(STEPS) and not failed:
        (out / "generated" / "fingerprint").write_text(stamp)
    print(f"[docs] generated in {time.perf_counter() - t0:.0f} s"
          + (f"; FAILED: {', '.join(failed)} (see their .err files in {out}/generated)"
             if failed else ""), flush=True)
    return 1 if failed else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
