"""The parser of the ``jaxhyst`` command: one subcommand per module, each registering
its own options (``add_parser``) and its ``run(args) -> exit status``."""

from __future__ import annotations

import argparse

from . import (
    compensate,
    frequency_response,
    identify,
    identify_many,
    predict,
    report,
    reproduce,
    simulate,
)
from .options import EXIT_HELP, UNITS_HELP, Parser

COMMANDS = (simulate, identify, identify_many, predict, report, reproduce, frequency_response,
            compensate)


def build_parser() -> argparse.ArgumentParser:
    parser = Parser(
        prog="jaxhyst",
        description="Jiles–Atherton hysteresis of magnetostrictive actuators: simulate, "
        "identify parameters from measured loops, report what the data determine. "
        + UNITS_HELP,
        epilog=EXIT_HELP,
    )
    sub = parser.add_subparsers(dest="command", required=True)
    for command in COMMANDS:
        command.add_parser(sub)
    return parser
