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
