"""``python -m jaxhyst.cli``: the ``jaxhyst`` command."""

from .main import command

command()
