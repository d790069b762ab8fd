"""The names the command line and the API accept, in one place (no JAX import here, so
that ``jaxhyst --help`` stays fast). `jaxhyst.identify` maps each name to its object and
the tests check that the tables agree."""

import operator

#: Local solvers by name (`jaxhyst.identify.SOLVERS` holds their factories).
SOLVER_NAMES = ("lm", "indirect_lm", "dogleg", "lma", "tra", "bfgs")

#: The paper's hybrid GAs and the plain GA (`jaxhyst.identify.HYBRIDS`).
HYBRID_NAMES = ("GATR1", "GALM1", "GATR2", "GALM2", "GA")

#: The loss coefficients of the rate-dependent model (`jaxhyst.Losses`), and the
#: parameters the built-in forms of pinning cells have of their own: the names beyond the
#: ten that a box, --fix or --vary may give.
LOSS_PARAMETER_NAMES = ("eddy", "excess", "lag", "relax")
FORM_PARAMETER_NAMES = ("spread", "a_rev")

#: Model forms: command-line name → class name in `jaxhyst` (the Jiles–Atherton variants,
#: then the forms of pinning cells, which have return-point memory).
VARIANT_CLASSES = {"energy": "EnergyBasedJA", "classic": "ClassicJA",
                   "venkataraman": "VenkataramanJA", "pop": "PopJA",
                   "play": "PlayJA", "preisach": "PreisachJA"}

#: RK4 substeps per sample everywhere (simulate, problems, the command line): the setting
#: whose accuracy docs/theory.md documents.
DEFAULT_SUBSTEPS = 2


def checked_substeps(substeps) -> int:
    """``substeps`` as an int (a whole number >= 1: a Python or NumPy integer), else a
    one-line ``ValueError``."""
    try:
        n = None if isinstance(substeps, bool) else operator.index(substeps)
    except TypeError:
        n = None
    if n is None or n < 1:
        raise ValueError(f"substeps must be an integer >= 1; got {substeps!r}.")
    return n


#: Output kinds that see the magnetization only (`jaxhyst.identify.outputs`: their
#: ``magnetic_only``), for the command line, which decides before JAX is imported.
MAGNETIC_OUTPUT_NAMES = ("magnetization", "flux_density")

#: Features of a record's condition that parameters may vary with: name → (the condition
#: it comes from, that condition's unit) (`jaxhyst.model.laws.FEATURES`).
CONDITION_FEATURES = {"log_f": ("frequency", "Hz"), "T": ("temperature", "°C"),
                      "log_amplitude": ("amplitude", "A/m or T")}


def base_name(name: str) -> str:
    """A parameter's name without a loop or record index (``k[2]`` → ``k``)."""
    return name.split("[")[0]
