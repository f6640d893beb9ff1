"""A short summary of a coverage map (``swarm map info``)."""

from __future__ import annotations

import numpy as np

from swarm.map.coverage_map import CoverageMap, prior_entropy_bits
from swarm.map.entropy import expected_coverage
from swarm.map.entropy_table import default_table


def summarize(cmap: CoverageMap) -> dict:
    """Shape, voxel size, known fraction, entropy (now and of the prior) and occupied voxels."""
    mu, sigma = cmap.mean(), cmap.sigma()
    table = default_table()
    entropy = float(np.sum(table(mu, sigma), dtype=np.float64))
    initial = prior_entropy_bits(cmap.grid, cmap.sensor)
    occupied = int(np.count_nonzero(expected_coverage(mu, sigma) > 0.5))
    return {
        "shape": list(cmap.grid.shape),
        "voxels": cmap.grid.size,
        "voxel_size": cmap.grid.voxel,
        "origin": [round(v, 6) + 0.0 for v in cmap.grid.origin],  # + 0.0: never -0.0
        "known_fraction": round(float(np.mean(cmap.known_mask())), 6),
        "entropy_bits": round(entropy, 1),
        "initial_entropy_bits": round(initial, 1),
        "occupied_voxels": occupied,
    }
