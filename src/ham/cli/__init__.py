"""The ``ham`` command line (``ham --help``): the last layer, it only parses and calls the others."""

from ham.cli.main import main

__all__ = ["main"]
