"""Ground navigation shared by the agent and the coordinator.

Traversability from the coverage map, shortest paths on it, exploration targets (eq. 30-35
and the two baselines) and the path follower. Pure numpy/scipy over a map; no transport.
"""
