"""The ``jaxhyst`` command line, one module per command (``jaxhyst <command> --help``).

Units are SI everywhere unless a data file's header says otherwise: field H in A/m,
current I in A, displacement y in m, magnetization M in A/m, flux density B in T, time t in
s, frequency in Hz; strain and magnetostriction are dimensionless. Parameters: Ms, a, k in
A/m; λs, α̃, c dimensionless; E in N/m², Kz in N/m, Mz in kg, Cz in N·s/m.

Errors in the input end the command with exit status 2 and a one-line message on stderr.
Only the command line installs signal handlers (`jaxhyst.cli._signals`).
"""

from .main import main
from .options import VARIANTS
from .parser import build_parser
from .problems import build_problem
from .spec import CLIError, variant_from_name

__all__ = ["CLIError", "VARIANTS", "build_parser", "build_problem", "main",
           "variant_from_name"]
