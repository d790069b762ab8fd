"""Progress meters for long runs, in the shape of diffrax's: ``init / step / close``.

Every long host loop of jaxhyst (a local solve stepped in chunks, the generations of a
hybrid GA, its final solves) goes through one driver (`jaxhyst._driver`), which
reports to the meter the caller chose. The library is silent by default
(`NoProgressMeter`); the command line uses `TextProgressMeter`. A meter of your own
implements the three methods of `AbstractProgressMeter`.

Meters live on the host (the driver is a Python loop between compiled programs), so
their state is a plain Python object.
"""

from __future__ import annotations

import abc
import sys
import time
from dataclasses import dataclass, replace
from typing import Any

import equinox as eqx


class AbstractProgressMeter(eqx.Module):
    """What a long run reports. A run may open several meters one after the other or
    nested (a hybrid GA: its generations, then its final solves), each with its own
    state."""

    @abc.abstractmethod
    def init(self, label: str, total: int | None) -> Any:
        """Start a phase named ``label`` of ``total`` units (generations, solver steps;
        None if unknown), before its first unit (which compiles). Returns the state."""

    @abc.abstractmethod
    def step(self, state, done: int, text: str) -> Any:
        """``done`` units are complete; ``text`` describes where the run stands (cost,
        evaluations, seconds). Returns the new state."""

    @abc.abstractmethod
    def close(self, state, text: str) -> None:
        """The phase ended; ``text`` says how (done, interrupted, the result)."""


class NoProgressMeter(AbstractProgressMeter):
    """Reports nothing (the library's default)."""

    def init(self, label: str, total: int | None) -> None:
        return None

    def step(self, state, done: int, text: str) -> None:
        return state

    def close(self, state, text: str) -> None:
        del state, text


@dataclass(frozen=True)
class _TextState:
    label: str
    total: int | None
    started: float
    last_time: float
    last_done: int


class TextProgressMeter(AbstractProgressMeter):
    """Lines ``[label] text`` on stderr (or ``stream``): one when a phase starts (its
    first step compiles), after the first unit, whenever the count passes a multiple of
    ``every`` (0: never by count), whenever ``interval`` seconds have passed since the
    last line (0: never by time), after the last unit, and when the phase ends. On a
    terminal the time-driven lines overwrite each other."""

    every: int = eqx.field(static=True, default=10)
    interval: float = eqx.field(static=True, default=2.0)
    stream: Any = eqx.field(static=True, default=None)

    def __check_init__(self):
        if int(self.every) < 0 or not float(self.interval) >= 0:
            raise ValueError(f"TextProgressMeter needs every >= 0 and interval >= 0 (s); got "
                             f"every={self.every!r}, interval={self.interval!r}.")

    def _print(self, label: str, text: str, live: bool = False) -> None:
        stream = sys.stderr if self.stream is None else self.stream
        try:
            tty = bool(stream.isatty())
        except (AttributeError, ValueError):  # (a closed or minimal stream)
            tty = False
        print(f"{chr(13) + chr(27) + '[K' if tty else ''}[{label}] {text}",
              end="" if live and tty else "\n", file=stream, flush=True)

    def init(self, label: str, total: int | None) -> _TextState:
        of = f" ({total} in all)" if total else ""
        self._print(label, f"starting{of}; compiling the first step …")
        now = time.perf_counter()
        return _TextState(label, total, now, now, 0)

    def step(self, state: _TextState, done: int, text: str) -> _TextState:
        now = time.perf_counter()
        by_count = self.every > 0 and done // self.every > state.last_done // self.every
        by_time = self.interval > 0 and now - state.last_time >= self.interval
        first, last = state.last_done == 0, state.total is not None and done >= state.total
        if not (first or last or by_count or by_time):
            return state
        self._print(state.label, text, live=by_time and not (first or last or by_count))
        return replace(state, last_time=now, last_done=done)

    def close(self, state: _TextState, text: str) -> None:
        self._print(state.label, f"{text} ({time.perf_counter() - state.started:.1f} s)")


class TqdmProgressMeter(AbstractProgressMeter):
    """A tqdm progress bar per phase (needs the ``tqdm`` package: ``pip install tqdm``)."""

    def __check_init__(self):
        import importlib.util

        if importlib.util.find_spec("tqdm") is None:
            raise ImportError("TqdmProgressMeter needs tqdm: pip install tqdm (or use "
                              "TextProgressMeter).")

    def init(self, label: str, total: int | None):
        import tqdm

        return tqdm.tqdm(total=total, desc=label, leave=True)

    def step(self, state, done: int, text: str):
        state.update(done - state.n)
        state.set_postfix_str(text, refresh=True)
        return state

    def close(self, state, text: str) -> None:
        state.set_postfix_str(text, refresh=False)
        state.close()


def progress_meter(progress, every: int = 10) -> AbstractProgressMeter:
    """The meter for a ``progress`` argument: a meter as is; False/None/0 → silent; True →
    `TextProgressMeter` with a line every ``every`` units or 2 s; a positive int n → a
    line every n units (or 2 s)."""
    if isinstance(progress, AbstractProgressMeter):
        return progress
    if progress is None or progress is False or progress == 0:
        return NoProgressMeter()
    if progress is True:
        return TextProgressMeter(every=every)
    if isinstance(progress, int) and progress > 0:
        return TextProgressMeter(every=progress)
    raise TypeError(f"progress must be a bool, a positive number of steps between lines, or "
                    f"a progress meter (jaxhyst.TextProgressMeter …); got {progress!r}.")
