"""robot_agent package."""

import swarm  # noqa: F401  (first: where Numba's cache goes, swarm.compiled_cache)
