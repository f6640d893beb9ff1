"""The replay role: recorded stereo (ASL/EuRoC folders, ROS 1/2 bags) published as robot frames."""

import swarm  # noqa: F401  (first: where Numba's cache goes, swarm.compiled_cache)
