"""The ``swarm`` command: a thin shell, one module per command group."""

from swarm.cli.main import build_parser, main

__all__ = ["build_parser", "main"]
