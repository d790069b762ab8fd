"""The one host loop: every long run of jaxhyst is driven here.

A run — a local solve stepped in chunks, the generations of a hybrid GA — is a state and
three questions the driver asks of it between compiled programs: is it ``done``, what is
the next state (``advance``: one chunk of solver steps, one generation), and where does
it stand (``describe``: a count and a line for the progress meter). Between units the
driver reports progress, writes the checkpoint when one is due, and stops early when

- a stop was requested (`jaxhyst._interrupt.request_stop`: the command line's first
  Ctrl-C or SIGTERM) or ``stop_after`` units are complete — it returns the state reached,
  ``how = "stopped"``;
- a KeyboardInterrupt arrives (Ctrl-C in Python) — it returns the last complete state,
  ``how = "keyboard"``; the caller builds its result from it and raises
  `jaxhyst._interrupt.Interrupted` carrying it.

Either way an interrupted run writes its checkpoint before it returns.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from ._interrupt import stop_requested
from .progress import AbstractProgressMeter

DONE, STOPPED, KEYBOARD = "done", "stopped", "keyboard"


def drive(state: Any, *, advance: Callable, done: Callable, describe: Callable,
          meter: AbstractProgressMeter, meter_state, save: Callable | None = None,
          save_every: int = 0, stop_after: int | None = None) -> tuple[Any, str, Any]:
    """Run ``state = advance(state)`` until ``done(state)`` or an interruption (see the
    module docstring). ``describe(state) -> (count, text)``: the units complete (the
    generation, the solver steps) and a line for ``meter``; ``save(state)`` writes the
    checkpoint every ``save_every`` units of the count and on interruption;
    ``stop_after``: stop once the count reaches it. Returns (state, how, meter state) with
    how one of ``"done"``, ``"stopped"``, ``"keyboard"``."""
    how = DONE
    try:
        while not done(state):
            state = advance(state)
            count, text = describe(state)
            meter_state = meter.step(meter_state, count, text)
            if save is not None and save_every and count % save_every == 0:
                save(state)
            if stop_requested() or (stop_after is not None and count >= stop_after
                                    and not done(state)):
                how = STOPPED
                break
    except KeyboardInterrupt:
        how = KEYBOARD
    if how != DONE and save is not None:
        save(state)
    return state, how, meter_state
