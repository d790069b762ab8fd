"""Signal handling, which belongs to the command line alone.

The first Ctrl-C (SIGINT) or SIGTERM asks the running work to stop at its next safe
point (`jaxhyst._interrupt.request_stop`: a GA generation, a chunk of solver steps, a
batch of fits), which then returns its best point so far; the second ends the process at
once (status 130). Python runs a signal's handler only when the main thread executes
Python code, so a signal that arrived while XLA compiles (seconds to minutes in C++)
would wait for the compile to end: `run_interruptibly` runs the work in a worker thread
while the main thread only waits, so the first signal is acknowledged at once.
"""

from __future__ import annotations

import os
import signal
import sys
import threading

from jaxhyst._interrupt import clear_stop, request_stop, stop_requested


def run_interruptibly(fn, *args, message: str = "stopping at the next safe point (again "
                      "to abort now)"):
    """``fn(*args)`` in a worker thread with the two-stage handlers installed (main thread
    only; elsewhere ``fn`` runs as is). Returns ``fn``'s value (or raises its exception)."""
    if threading.current_thread() is not threading.main_thread():
        return fn(*args)
    box: dict = {}

    def work():
        try:
            box["value"] = fn(*args)
        except BaseException as err:  # noqa: BLE001 - re-raised in the main thread
            box["error"] = err

    def handler(signum, frame):
        if stop_requested():
            raise KeyboardInterrupt
        request_stop()
        print(f"\njaxhyst: interrupted — {message}", file=sys.stderr, flush=True)

    sigs = (signal.SIGINT, signal.SIGTERM)
    previous = {sig: signal.getsignal(sig) for sig in sigs}
    clear_stop()
    try:
        for sig in sigs:
            signal.signal(sig, handler)
        worker = threading.Thread(target=work, name="jaxhyst-work", daemon=True)
        worker.start()
        try:
            while worker.is_alive():
                worker.join(0.1)
        except KeyboardInterrupt:
            print("jaxhyst: aborted", file=sys.stderr, flush=True)
            sys.stderr.flush()
            os._exit(130)
    finally:
        for sig, h in previous.items():
            signal.signal(sig, h)
    if "error" in box:
        raise box["error"]
    return box["value"]
