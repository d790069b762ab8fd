"""The ``jaxhyst`` command: parse, run the command in a worker thread (so that Ctrl-C is
honoured even while XLA compiles), and turn every error into one line and an exit
status."""

from __future__ import annotations

import sys

from .parser import build_parser
from .spec import cli_wording


def main(argv=None) -> int:
    try:
        args = build_parser().parse_args(argv)
    except SystemExit as done:  # --help, or a usage error already reported in one line
        return done.code if isinstance(done.code, int) else 2
    import warnings

    from jaxhyst import enable_compilation_cache

    from ._signals import run_interruptibly

    def one_line(message, category, filename, lineno, file=None, line=None):
        print(f"jaxhyst {args.command}: warning: {cli_wording(message, args)}",
              file=sys.stderr, flush=True)

    shown = warnings.showwarning
    warnings.showwarning = one_line  # Python warnings (coarse sampling …) as one line
    enable_compilation_cache()  # a second run loads its compiled programs from disk
    try:
        # the work runs in a worker thread: Ctrl-C is honoured even while XLA compiles
        return run_interruptibly(args.func, args)
    except KeyboardInterrupt:
        print(f"jaxhyst {args.command}: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:  # output piped into e.g. `head`: not an error of the input
        sys.stderr.close()
        return 0
    except (ValueError, TypeError, ImportError, OSError, FloatingPointError) as err:
        print(f"jaxhyst {args.command}: error: {cli_wording(err, args)}", file=sys.stderr)
        return 2
    finally:
        warnings.showwarning = shown


def command() -> None:
    """The console script (``jaxhyst``, ``python -m jaxhyst.cli``): `main`, then the
    process ends without the interpreter's teardown — freeing every compiled program and
    module, 0.5–1 s of every command — once its output is flushed, JAX's pending effects
    are done and nothing it started still runs (only daemon threads, no child process);
    otherwise, or where flushing fails (a closed pipe), it exits as usual."""
    import multiprocessing
    import os
    import threading

    code = main()
    try:
        if "jax" in sys.modules:
            sys.modules["jax"].effects_barrier()
        sys.stdout.flush()
        sys.stderr.flush()
    except (OSError, ValueError):  # (a closed pipe or stream: the usual exit says it)
        sys.exit(code)
    alone = all(t.daemon or t is threading.main_thread() for t in threading.enumerate())
    if alone and not multiprocessing.active_children():
        os._exit(0 if code is None else code if isinstance(code, int) else 1)  # (as sys.exit)
    sys.exit(code)
