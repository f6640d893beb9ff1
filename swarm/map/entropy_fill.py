"""Every voxel's entropy from a whole map, a chunk at a time (no whole-map temporaries).

``EntropyCache.from_information`` and ``refill_information`` compute the moments and the
table's entropy of the whole map at once: on the campus floor (8.4e6 voxels) that is about
100 MB of float32 temporaries (mu, sigma, the square root, the table's output and the cache's
copy of it) on top of the map, the largest transient of an agent's life. The functions here
write the same float32 values (the moments and the table are elementwise) chunk by chunk into
the cache's own array.
"""

from __future__ import annotations

import numpy as np

from swarm.map.entropy import moments
from swarm.map.entropy_cache import EntropyCache
from swarm.map.entropy_table import EntropyTable, default_table

#: voxels per chunk: 1 MB of float32 per temporary
CHUNK = 1 << 18


def fill_entropy(out: np.ndarray, lam: np.ndarray, eta: np.ndarray, table: EntropyTable) -> None:
    """``out[i] = table(*moments(lam[i], eta[i]))`` for every voxel i, a chunk at a time.

    ``out`` float32 (N,), written in place; ``lam``, ``eta`` (N,) information form, lam > 0.
    Raises ValueError when the sizes differ."""
    lam, eta = np.ravel(lam), np.ravel(eta)
    if not (out.size == lam.size == eta.size) or out.ndim != 1:
        raise ValueError(f"sizes differ: out {out.shape}, lam {lam.shape}, eta {eta.shape}")
    for i in range(0, out.size, CHUNK):
        j = min(i + CHUNK, out.size)
        out[i:j] = table(*moments(lam[i:j], eta[i:j]))


def entropy_cache(lam: np.ndarray, eta: np.ndarray, table: EntropyTable | None = None, **kw) -> EntropyCache:
    """``EntropyCache.from_information(lam, eta, table, **kw)``, the same values and total,
    without its whole-map temporaries (``on_change`` is not told, as there)."""
    table = table or default_table()
    cache = EntropyCache(np.zeros(np.size(lam), dtype=np.float32), table=table, **kw)
    fill_entropy(cache.values, lam, eta, table)
    cache.resum()
    return cache


def refill_entropy(cache: EntropyCache, lam: np.ndarray, eta: np.ndarray) -> float:
    """``cache.refill_information(lam, eta)`` a chunk at a time: every voxel's entropy again in
    place, ``on_change(None)`` told, the total summed again and returned."""
    fill_entropy(cache.values, lam, eta, cache.table or default_table())
    if cache.on_change is not None:
        cache.on_change(None)
    return cache.resum()
