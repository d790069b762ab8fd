import os
import shutil
import subprocess
import sys
import tempfile

# Tests import the shared problems in tests/helpers.py.
sys.path.insert(0, os.path.dirname(__file__))

import pytest  # noqa: E402

import jaxhyst  # noqa: E402  (float64 on import)
from jaxhyst._interrupt import clear_stop  # noqa: E402
from jaxhyst._mappings import release_if_crowded  # noqa: E402

# as the command line does: the CLI chains (subprocesses) and the in-process tests share
# compiled programs, and a second run of the suite loads them from disk
jaxhyst.enable_compilation_cache()

#: Background command-line chains (tests/cli_chains.py): name → directory. The chains
#: live in one directory per test run (``JAXHYST_TEST_CHAINS``, made by the first process
#: of the run: the only one, or pytest-xdist's controller before its workers start), so
#: that with workers (``-n 2``) each chain runs once, started by whichever worker
#: collects first, and any worker can wait for it: ``chain/pid`` names its process
#: (group), ``chain/status.json`` is written when it ends.
CLI_CHAINS: dict = {}

#: The test modules that check the chains' results.
CHAIN_MODULES = ("test_cli_subprocess", "test_docs_site")
_ROOT = "JAXHYST_TEST_CHAINS"


def pytest_configure(config):
    if not hasattr(config, "workerinput"):  # (one process, or xdist's controller)
        os.environ[_ROOT] = tempfile.mkdtemp(prefix="jaxhyst-cli-")
    if os.environ.get("JAXHYST_TEST_PROFILE"):  # (where the time goes: compile_profile.py)
        from compile_profile import Profile

        config.pluginmanager.register(Profile(os.environ["JAXHYST_TEST_PROFILE"]),
                                      "jaxhyst-compile-profile")


def pytest_collection_modifyitems(session, config, items):
    """Check the background chains last, so that they run alongside everything else."""
    items.sort(key=lambda item: item.module.__name__ in CHAIN_MODULES)


def pytest_collection_finish(session):
    """Start the subprocess CLI chains as soon as the tests that check them are selected,
    so that they run alongside the in-process tests instead of after them: the docs chain
    for the tests marked ``docs``, the others for the other tests of the chain modules.
    A chain already started by another worker of this run is only recorded."""
    chained = [item for item in session.items if item.module.__name__ in CHAIN_MODULES]
    if not chained:
        return
    docs = any(item.get_closest_marker("docs") for item in chained)
    others = any(not item.get_closest_marker("docs") for item in chained)
    chains = (("docs",) if docs else ()) + (("reproduce", "sharding", "resume", "measured",
                                             "compensate") if others else ())
    root = os.environ[_ROOT]
    script = os.path.join(os.path.dirname(__file__), "cli_chains.py")
    nice = ["nice", "-n", "10"] if shutil.which("nice") else []
    for chain in chains:
        d = os.path.join(root, chain)
        CLI_CHAINS[chain] = d
        try:
            os.mkdir(d)  # (atomic: one process of the run starts each chain)
        except FileExistsError:
            continue
        # niced (the `nice` command: a preexec_fn would fork the multithreaded JAX
        # process): the in-process tests keep their core, the chains use what is left
        # (a session of its own: an aborted run ends the chain with the commands it ran)
        proc = subprocess.Popen([*nice, sys.executable, script, chain, d],
                                stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                                start_new_session=True)
        with open(os.path.join(d, "pid.tmp"), "w") as fh:
            fh.write(str(proc.pid))
        os.replace(os.path.join(d, "pid.tmp"), os.path.join(d, "pid"))


def chain_pid(d: str) -> int | None:
    """The process (group) of the chain in ``d``, None until its starter wrote it."""
    try:
        with open(os.path.join(d, "pid")) as fh:
            return int(fh.read())
    except (OSError, ValueError):
        return None


def pytest_sessionfinish(session, exitstatus):
    """The run's first process ends what is left of the chains (a worker leaves them to
    the others), and removes their directory after a run that passed (after a failure
    it stays, with the chains' logs, and its path is printed)."""
    import signal

    if hasattr(session.config, "workerinput"):  # (a worker: its releases to the controller)
        session.config.workeroutput["released"] = RELEASED
        return
    if not os.environ.get(_ROOT):
        return
    root = os.environ[_ROOT]
    for chain in os.listdir(root):
        pid = chain_pid(os.path.join(root, chain))
        if pid is not None and not os.path.exists(os.path.join(root, chain, "status.json")):
            try:
                os.killpg(pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
    if exitstatus == 0 or not os.listdir(root):
        shutil.rmtree(root, ignore_errors=True)
    else:
        print(f"\nthe command-line chains' logs: {root}")


#: The tests after which the compiled programs were dropped (`release_if_crowded`): the
#: tests after them trace and load again what they share with earlier ones.
RELEASED: list = []


@pytest.hookimpl(optionalhook=True)
def pytest_testnodedown(node, error):
    """(pytest-xdist's controller: a worker's releases, for the summary)"""
    RELEASED.extend(getattr(node, "workeroutput", {}).get("released", []))


def pytest_terminal_summary(terminalreporter):
    if RELEASED:
        more = " …" if len(RELEASED) > 3 else ""
        terminalreporter.write_line(f"compiled programs released {len(RELEASED)} times near "
                                    "the kernel's mapping limit (after "
                                    f"{', '.join(RELEASED[:3])}{more})")


@pytest.fixture(autouse=True)
def _no_stop_request_left(request):
    """A test that requests a stop (as the command line's Ctrl-C does) leaves none for
    the next; and the compiled programs are dropped before the session's memory mappings
    near the kernel's limit (XLA aborts the process there: see jaxhyst._mappings)."""
    yield
    clear_stop()
    if release_if_crowded():
        RELEASED.append(request.node.nodeid)
