"""Interruption, as the library sees it: a stop flag checked at safe points, and the
exception that carries a run's best point out of a Ctrl-C.

The library never installs signal handlers. Two ways a long run stops early:

- **The stop flag** (`request_stop`): the command line's signal handlers set it on the
  first Ctrl-C or SIGTERM (`jaxhyst.cli._signals`); the run's driver sees it after the
  current unit of work (a generation, a chunk of solver steps) and returns the best
  point so far with the outcome ``interrupted``.
- **KeyboardInterrupt** in a Python session: the driver catches it at the next safe
  point, writes the checkpoint if there is one, and raises `Interrupted` (a
  ``KeyboardInterrupt``) whose ``result`` is the run's best point so far, so that a
  script still stops on Ctrl-C and nothing is lost.
"""

from __future__ import annotations

import threading

_flag = threading.Event()


def request_stop() -> None:
    """Ask every running driver to stop at its next safe point."""
    _flag.set()


def clear_stop() -> None:
    """Withdraw a stop request (the command line does at the start of each command)."""
    _flag.clear()


def stop_requested() -> bool:
    """Whether a stop was requested."""
    return _flag.is_set()


class Interrupted(KeyboardInterrupt):
    """A run stopped by Ctrl-C in Python; ``result`` holds its best point so far (an
    `IdentificationResult` with the outcome ``interrupted``)."""

    def __init__(self, result):
        super().__init__("interrupted; the best point so far is in .result")
        self.result = result
