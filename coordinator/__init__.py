"""The coordinator role: a replica of the team map and eq. 35 targets spread over the team."""

import swarm  # noqa: F401  (first: where Numba's cache goes, swarm.compiled_cache)
