"""Swarm mapping: shared core (map maths, wire schema, config, CLI)."""

from swarm.compiled_cache import use_user_cache_when_installed

__version__ = "0.1.0"

# Before any of our modules imports Numba: an installed copy compiles into the user's cache.
use_user_cache_when_installed()
