"""``python -m jaxhyst.cli``: the ``jaxhyst`` command."""

import sys

from .main import main

sys.exit(main())
