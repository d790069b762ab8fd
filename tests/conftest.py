import os
import sys

# Tests import the shared problems in tests/helpers.py.
sys.path.insert(0, os.path.dirname(__file__))

import jaxhyst  # noqa: E402,F401  (float64 on import)
