"""Where a test run's time goes: JAX's tracing, lowering and compiling (or loading from
the persistent cache) per test, from JAX's own duration events (``jax.monitoring``).

    JAXHYST_TEST_PROFILE=DIR python -m pytest …     # each process writes DIR/<worker>.json
    python tests/compile_profile.py DIR [N]         # totals, the N costliest tests and programs

Seconds are per process (with ``-n 2``, two workers' sums); "compile" includes the
programs loaded from the cache ("load" is that part), so compile − load is compiling.
The command-line chains' subprocesses are not counted.
"""

from __future__ import annotations

import collections
import json
import os
import sys
import time

import pytest

#: JAX's event name → ours.
EVENTS = {"/jax/core/compile/jaxpr_trace_duration": "trace",
          "/jax/core/compile/jaxpr_to_mlir_module_duration": "lower",
          "/jax/core/compile/backend_compile_duration": "compile",
          "/jax/compilation_cache/cache_retrieval_time_sec": "load"}
KINDS = ("wall", "trace", "lower", "compile", "load")


class Profile:
    """A pytest plugin (conftest.py registers it where ``JAXHYST_TEST_PROFILE`` is set)."""

    def __init__(self, directory: str):
        from jax import monitoring

        self.directory, self.current = directory, "<outside tests>"
        self.seconds = collections.defaultdict(collections.Counter)
        #: program name → [seconds compiling or loading, programs, tests that compiled it]
        self.programs: dict = collections.defaultdict(lambda: [0.0, 0, set()])
        monitoring.register_event_duration_secs_listener(self._event)

    def _event(self, event, duration, fun_name=None, **_):
        kind = EVENTS.get(event)
        if kind:
            self.seconds[self.current][kind] += duration
            self.seconds[self.current][kind + "_n"] += 1
        if kind == "compile" and fun_name:
            entry = self.programs[fun_name]
            entry[0] += duration
            entry[1] += 1
            entry[2].add(self.current)

    @pytest.hookimpl(hookwrapper=True)
    def pytest_runtest_protocol(self, item, nextitem):
        self.current, start = item.nodeid, time.perf_counter()
        yield
        self.seconds[item.nodeid]["wall"] += time.perf_counter() - start
        self.current = "<outside tests>"

    def pytest_sessionfinish(self, session):
        if not self.seconds:  # (xdist's controller runs no test)
            return
        os.makedirs(self.directory, exist_ok=True)
        name = os.environ.get("PYTEST_XDIST_WORKER", "main")
        with open(os.path.join(self.directory, f"{name}.json"), "w") as fh:
            json.dump(self.seconds, fh, indent=0)
        with open(os.path.join(self.directory, f"{name}.programs"), "w") as fh:
            json.dump({k: [s, n, sorted(t)] for k, (s, n, t) in self.programs.items()}, fh,
                      indent=0)


def summary(directory: str, top: int = 15) -> str:
    tests: dict = collections.defaultdict(collections.Counter)
    for name in sorted(os.listdir(directory)):
        if name.endswith(".json"):
            with open(os.path.join(directory, name)) as fh:
                data = json.load(fh)
            if not isinstance(data, dict) or not all(
                    isinstance(v, dict) and all(isinstance(x, (int, float)) for x in v.values())
                    for v in data.values()):
                continue  # (another file in the directory, not a worker's profile)
            for test, seconds in data.items():
                tests[test].update(seconds)
    total = sum(tests.values(), collections.Counter())
    lines = ["all tests: " + ", ".join(f"{k} {total[k]:.0f} s" for k in KINDS)
             + f" ({total['compile_n']:.0f} programs compiled or loaded)"]
    for test, s in sorted(tests.items(), key=lambda kv: -kv[1]["wall"])[:top]:
        lines.append(f"{s['wall']:7.1f} s  trace {s['trace']:5.1f}  lower {s['lower']:5.1f}  "
                     f"compile {s['compile']:5.1f} (load {s['load']:4.1f})  {test}")
    programs: dict = collections.defaultdict(lambda: [0.0, 0, set()])
    for name in sorted(os.listdir(directory)):
        if name.endswith(".programs"):
            with open(os.path.join(directory, name)) as fh:
                for fun, (s, n, t) in json.load(fh).items():
                    programs[fun][0] += s
                    programs[fun][1] += n
                    programs[fun][2].update(t)
    if programs:
        lines.append("programs by name (compiling or loading, how many, in how many tests):")
        for fun, (s, n, t) in sorted(programs.items(), key=lambda kv: -kv[1][0])[:top]:
            lines.append(f"{s:7.1f} s  {n:5d}  {len(t):4d}  {fun}")
    return "\n".join(lines)


if __name__ == "__main__":
    print(summary(sys.argv[1], int(sys.argv[2]) if len(sys.argv) > 2 else 15))
