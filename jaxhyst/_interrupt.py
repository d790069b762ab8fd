"""Interruption honoured at safe points: the first Ctrl-C (SIGINT) or SIGTERM sets a flag
that long-running loops check after each unit of work (a GA generation, a batch of
fits); a second one raises KeyboardInterrupt. Signal handlers can only be installed in
the main thread; elsewhere the context does nothing.

Python runs a signal's handler only when the main thread executes Python code, so a
signal that arrives while XLA compiles (seconds to minutes in C++) waits for the compile
to end. `run_interruptibly` (used by the command line) therefore runs the work in a
worker thread while the main thread only waits: the first signal is acknowledged at
once and the work stops at its next safe point; the second exits the process at once
(status 130)."""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

_depth = 0
_flag = {"stop": False}


def stop_requested() -> bool:
    """Whether an interruption was requested inside the current `interruptible` block."""
    return _flag["stop"]


@contextlib.contextmanager
def interruptible(message: str = "stopping after the current step (again to abort now)"):
    """Install the two-stage handlers for the duration of the block; yields a function
    that says whether to stop. Nested blocks share the outer handlers."""
    global _depth
    if threading.current_thread() is not threading.main_thread() or _depth:
        _depth += 1
        try:
            yield stop_requested
        finally:
            _depth -= 1
        return

    def handler(signum, frame):
        if _flag["stop"]:
            raise KeyboardInterrupt
        _flag["stop"] = True
        print(f"\njaxhyst: interrupted — {message}", file=sys.stderr, flush=True)

    previous = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    _flag["stop"] = False
    _depth += 1
    try:
        for sig in previous:
            signal.signal(sig, handler)
        yield stop_requested
    finally:
        _depth -= 1
        for sig, h in previous.items():
            signal.signal(sig, h)
        _flag["stop"] = False


def run_interruptibly(fn, *args, message: str = "stopping at the next safe point (again "
                      "to abort now)"):
    """``fn(*args)`` in a worker thread inside an `interruptible` block held by the main
    thread: the first SIGINT/SIGTERM sets the stop flag (`stop_requested`, which ``fn``'s
    loops check) and is acknowledged at once, even during a compile; the second ends the
    process at once with status 130. Returns ``fn``'s value (or raises its exception)."""
    if threading.current_thread() is not threading.main_thread():
        return fn(*args)
    box: dict = {}

    def work():
        try:
            box["value"] = fn(*args)
        except BaseException as err:  # noqa: BLE001 - re-raised in the main thread
            box["error"] = err

    with interruptible(message):
        worker = threading.Thread(target=work, name="jaxhyst-work", daemon=True)
        worker.start()
        try:
            while worker.is_alive():
                worker.join(0.1)
        except KeyboardInterrupt:
            print("jaxhyst: aborted", file=sys.stderr, flush=True)
            sys.stderr.flush()
            os._exit(130)
    if "error" in box:
        raise box["error"]
    return box["value"]
