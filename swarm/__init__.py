"""Swarm mapping: shared core (map maths, wire schema, config, CLI)."""

__version__ = "0.1.0"
