"""The ``amcp`` command line: ``main`` (the lazy group) and one module per command."""

from amcp_drake.cli.main import main

__all__ = ["main"]
