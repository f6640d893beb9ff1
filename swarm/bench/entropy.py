"""``swarm bench entropy``: map entropy of a large map through the lookup table.

docs/design.md asks for the entropy of a 1,000,000-voxel map in under 50 ms; the exact
formula is timed on a sample beside it for scale.
"""

from __future__ import annotations

import time

import numpy as np

from swarm.bench import best_seconds
from swarm.map.entropy import entropy_exact
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import EntropyTable

#: Voxels timed with the exact formula, and updated in the cache (``swarm bench entropy --voxels``
#: must be at least this).
SAMPLE = 20_000


def run(voxels: int = 1_000_000, repeat: int = 5, seed: int = 0) -> dict:
    """Seconds for: building the table, table entropy of ``voxels`` beliefs, exact entropy per voxel,
    and an incremental cache update of 20,000 voxels (one stereo frame's worth)."""
    rng = np.random.default_rng(seed)
    mu = rng.uniform(-0.5, 1.5, voxels).astype(np.float32)
    sigma = np.exp(rng.uniform(np.log(1e-3), np.log(3.0), voxels)).astype(np.float32)

    t0 = time.perf_counter()
    table = EntropyTable()
    build = time.perf_counter() - t0

    def map_entropy() -> float:
        return float(np.sum(table(mu, sigma), dtype=np.float64))

    table_s = best_seconds(map_entropy, repeat)
    sample = SAMPLE
    exact_s = best_seconds(lambda: entropy_exact(mu[:sample], sigma[:sample]), 1) / sample * voxels

    cache = EntropyCache(table(mu, sigma))
    idx = rng.choice(voxels, SAMPLE, replace=False)
    update_s = best_seconds(lambda: cache.update(idx, mu[idx] * 0.9, sigma[idx] * 0.9), repeat)
    return {
        "voxels": voxels,
        "table_build_s": build,
        "table_entropy_s": table_s,
        "exact_entropy_s_extrapolated": exact_s,
        "cache_update_20k_s": update_s,
        "map_entropy_bits": map_entropy(),
    }


def format_figures(figures: dict) -> str:
    n = figures["voxels"]
    return "\n".join(
        [
            f"entropy of a {n:,}-voxel map:",
            f"  lookup table:          {figures['table_entropy_s'] * 1e3:8.2f} ms "
            f"(target < 50 ms; H = {figures['map_entropy_bits']:,.0f} bits)",
            f"  exact formula:         {figures['exact_entropy_s_extrapolated'] * 1e3:8.0f} ms "
            "(extrapolated from 20,000 voxels)",
            f"  table build:           {figures['table_build_s'] * 1e3:8.1f} ms (once per process)",
            f"  cache update 20k vox:  {figures['cache_update_20k_s'] * 1e3:8.2f} ms",
        ]
    )
