"""sim2d: the pymunk floor-plan simulator, stereo/depth renderer and ground truth (docs/sim2d.md)."""

import swarm  # noqa: F401  (first: where Numba's cache goes, swarm.compiled_cache)
