"""What every command of the command line shares: argument types whose errors name the
rule, the one-line usage errors, and the help texts on units and exit statuses."""

from __future__ import annotations

import argparse
import math

from jaxhyst.names import HYBRID_NAMES, SOLVER_NAMES, VARIANT_CLASSES

UNITS_HELP = ("Units: H A/m, I A, y m, M A/m, B T, t s, f Hz; Ms, a, k A/m; E N/m^2, "
              "Kz N/m, Mz kg, Cz N*s/m; lambda_s, alpha, c dimensionless.")

EXIT_HELP = ("Exit status: 0 success; 2 bad input (one-line message); 3 the fit stopped "
             "short (step limit reached, non-finite cost or solver failure) or ended far from "
             "its data (a loop's rms error above 20 % of its size, or far above the other "
             "loops'): the result is written and says so; 4 converged with a parameter at a "
             "bound of its box that is not a physical limit (a box derived from the data is "
             "widened and the fit redone first; a bound you gave: widen it); a parameter at "
             "its physical limit (c = 0 or 1 …) is reported but exits 0; 130 interrupted "
             "(Ctrl-C/SIGTERM: the best point so far and the checkpoint are written).")

LOCAL = SOLVER_NAMES
HYBRID = HYBRID_NAMES
VARIANTS = tuple(VARIANT_CLASSES)


def number(kind, minimum, strict: bool, what: str):
    """An argparse type: a finite number of ``kind`` ≥ (or >) ``minimum``; the error
    names the rule (argparse adds the option and the value)."""
    def parse(text):
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {what}") from None
        if not math.isfinite(value) or value < minimum or (strict and value == minimum):
            raise argparse.ArgumentTypeError(f"{text!r}: must be {what}")
        return value

    parse.__name__ = what
    return parse


POSITIVE_INT = number(int, 0, True, "a positive integer")
COUNT = number(int, 0, False, "an integer >= 0")
POSITIVE = number(float, 0.0, True, "a positive number")
NON_NEGATIVE = number(float, 0.0, False, "a number >= 0")
FINITE = number(float, -math.inf, True, "a finite number")


class Parser(argparse.ArgumentParser):
    """Usage errors as one line (the option, the value, the rule) instead of the usage
    block; ``--help`` has the rest."""

    def error(self, message):
        import re
        import sys

        if message.endswith("expected one argument"):  # a value such as -5,10 looks
            # like an option to argparse: say how to give it
            opt = re.search(r"argument (--?[\w-]+)", message)
            argv = sys.argv[1:]
            if opt and opt.group(1) in argv:
                i = argv.index(opt.group(1))
                nxt = argv[i + 1] if i + 1 < len(argv) else ""
                if re.match(r"-[\d.]", nxt):
                    message += (f" (a value that starts with '-' is written with '=': "
                                f"{opt.group(1)}={nxt})")
        self.exit(2, f"{self.prog}: error: {message} (see '{self.prog} --help')\n")
