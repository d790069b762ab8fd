"""Programs compiled in a background thread while the caller's own compile and run.

A first fit compiles several programs one after another: its step, then its report's.
Programs whose shapes are known before they are needed (the report's: `jaxhyst.fit`;
`compensate`'s refinement, while its models compile) can be compiled
meanwhile in another thread: `meanwhile` runs a function that calls them once
on inputs of the right shapes, so that the compiled-program caches hold them when the
caller gets there. Values are never shared: the thread's results are dropped, and its
exceptions too (the caller meets the same error, where it can say it).

The thread starts its work once the calling thread has lowered a large program (its
tracing, which holds the GIL, is then done; XLA's compile releases it), and runs under
the caller's ``jax.log_compiles`` setting, so that compile counters see its programs.
The caller joins it (`Meanwhile.join`) before it uses what the thread compiles; on a way
out where it is not needed (an error, a report without re-fits) it drops it
(`Meanwhile.drop`: work not yet started never runs, work under way is waited for).
Where the caller traces while the thread traces (both hold the GIL) or two
compiles share two cores, each slows the other: the gain is measured per use
(`benchmarks/RESULTS.md`, issue 45).
"""

from __future__ import annotations

import threading

#: Threads (ident → events) whose background work waits for their next large lowering.
_WAITING: dict[int, set] = {}
#: A lowering that takes this long (s) is a large program's: its compile follows (a
#: simulation of a reference's length lowers in 0.05–0.1 s).
LARGE_LOWERING = 0.05
_listening = False
THREAD_NAME = "jaxhyst-compile-meanwhile"


class _Ready(threading.Event):
    """Set once the caller has lowered ``left`` more large programs."""

    def __init__(self, left: int):
        super().__init__()
        self.left = left


def _on_lowered(event, duration, **_):
    if event == "/jax/core/compile/jaxpr_to_mlir_module_duration" and \
            duration >= LARGE_LOWERING:
        for ready in tuple(_WAITING.get(threading.get_ident(), ())):
            ready.left -= 1
            if ready.left <= 0:
                ready.set()


class Meanwhile:
    """A background compilation (`meanwhile`); ``join()`` before using its programs."""

    def __init__(self, work, wait: float, lowerings: int = 1):
        import jax

        global _listening
        if not _listening:
            jax.monitoring.register_event_duration_secs_listener(_on_lowered)
            _listening = True
        log = jax.config.jax_log_compiles  # (the caller's, e.g. in jax.log_compiles())
        caller, self.ready = threading.get_ident(), _Ready(lowerings)
        self._lock, self._dropped = threading.Lock(), False
        _WAITING.setdefault(caller, set()).add(self.ready)

        def run():
            self.ready.wait(wait)
            _WAITING.get(caller, set()).discard(self.ready)
            with self._lock:
                if self._dropped:
                    return
            try:
                with jax.log_compiles(log):
                    work()
            except Exception:  # noqa: BLE001  (the caller meets it and says it)
                pass

        self.thread = threading.Thread(target=run, name=THREAD_NAME, daemon=True)
        self.thread.start()

    def start(self) -> None:
        """Start the work now if it has not started (without waiting for it)."""
        self.ready.set()

    def join(self) -> None:
        """Wait until the work is done (it starts now if it had not)."""
        self.start()
        self.thread.join()

    def drop(self) -> None:
        """Drop the work if it has not started, else wait until it is done (a caller
        that turned out not to need it, or leaves on an error)."""
        with self._lock:
            self._dropped = True
        self.join()


def meanwhile(work, *, wait: float = 20.0, lowerings: int = 1) -> Meanwhile | None:
    """Run ``work()`` (calls of compiled programs on inputs of the right shapes) in a
    background thread once the caller has lowered ``lowerings`` more large programs, or
    after ``wait`` seconds; None (nothing started) where JIT is disabled."""
    import jax

    if jax.config.jax_disable_jit:
        return None
    return Meanwhile(work, wait, lowerings)


#: Per thread: what to call once a multi-start fit run there has settled (`when_settled`,
#: `settled`).
_ON_SETTLED = threading.local()


class when_settled:
    """Within the block, ``callback(cost)`` is called once, from the first multi-start
    fit run in this thread whose best cost has settled (changed by less than
    `jaxhyst.identify._stepped.SETTLED` of itself over a chunk of steps; ``cost``: that
    cost) — while the fit goes on, so that a program its outcome decides (the profile
    check's re-fits run only where the fit is not exact) can be compiled `meanwhile`."""

    def __init__(self, callback):
        self.callback = callback

    def __enter__(self):
        self.previous = getattr(_ON_SETTLED, "callback", None)
        _ON_SETTLED.callback = self.callback
        return self

    def __exit__(self, *exc):
        _ON_SETTLED.callback = self.previous
        return False


def settled(cost: float) -> None:
    """Called by a multi-start fit whose best cost has settled: runs the callback of
    `when_settled` (once; none outside such a block)."""
    callback = getattr(_ON_SETTLED, "callback", None)
    if callback is not None:
        _ON_SETTLED.callback = None
        callback(cost)


#: Per thread: background work a later step of the caller waits for where it uses what
#: the work compiles (`awaited`, `wait_for`).
_AWAITED = threading.local()


class awaited:
    """Within the block, ``wait_for(name)`` joins ``work`` (a `Meanwhile`, or None: nothing
    to wait for), so that the caller's steps before the one that uses its programs run
    beside it; on the way out of the block it is dropped if it has not started (nothing
    in the block needed it), else joined."""

    def __init__(self, name: str, work: Meanwhile | None):
        self.name, self.work = name, work

    def __enter__(self):
        if not hasattr(_AWAITED, "works"):
            _AWAITED.works = {}
        self.previous = _AWAITED.works.get(self.name)
        _AWAITED.works[self.name] = self.work
        return self

    def __exit__(self, *exc):
        _AWAITED.works[self.name] = self.previous
        if self.work is not None:
            self.work.drop()
        return False


def wait_for(name: str) -> None:
    """Join the background work `awaited` under ``name`` in this thread, if any."""
    work = getattr(_AWAITED, "works", {}).get(name)
    if work is not None:
        work.join()
