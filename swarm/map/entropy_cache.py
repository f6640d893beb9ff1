"""Per-voxel entropies of one map, updated only where voxels changed (paper eq. 31: the map's sum)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from swarm.map.entropy import moments
from swarm.map.entropy_table import EntropyTable, default_table

#: voxels a whole-map fill computes at a time (1 MB of float32 per temporary)
FILL_CHUNK = 1 << 18


# ---------------------------------------------------------------------------------------
# Per-voxel cache
# ---------------------------------------------------------------------------------------
class EntropyCache:
    """Per-voxel entropies of one map (float32, flat) and their total (float64).

    ``update`` recomputes only the given voxels and adjusts the total by (new - old);
    after ``resum_every`` recomputed voxels in all (by default the map size) the total is
    summed again from scratch, so rounding drift stays bounded. ``on_change(idx)`` is told
    the voxels (flat int64) each update recomputed, and ``None`` when every voxel was
    (``refill_information``): a cache of what derives from the map (the eq. 35 fields of
    swarm.navigation.target_cache) learns where to redo its work.
    """

    def __init__(
        self,
        values,
        table: EntropyTable | None = None,
        resum_every: int | None = None,
        on_change: Callable[[np.ndarray | None], None] | None = None,
    ) -> None:
        self.values = np.array(values, dtype=np.float32).ravel()
        self.table = table
        self.on_change = on_change
        self.resum_every = int(resum_every) if resum_every else max(self.values.size, 1)
        self._since = 0
        self.total = self.resum()

    @classmethod
    def from_information(cls, lam, eta, table=None, **kw) -> EntropyCache:
        """The cache of a map given in information form (flat or not; lam > 0), filled a chunk
        of FILL_CHUNK voxels at a time (:meth:`refill_information`)."""
        cache = cls(np.zeros(np.size(lam), dtype=np.float32), table=table or default_table(), **kw)
        cache._fill(lam, eta)
        cache.resum()
        return cache

    def resum(self) -> float:
        """Recompute the total exactly from the cached values and return it."""
        self.total = float(np.sum(self.values, dtype=np.float64))
        self._since = 0
        return self.total

    def update(self, flat_idx, mu, sigma) -> float:
        """Recompute the entropy of voxels ``flat_idx`` from their new beliefs; return the total.

        A voxel listed twice takes its last belief (as numpy assignment does).
        """
        idx = np.asarray(flat_idx, dtype=np.int64).ravel()
        if idx.size == 0:
            return self.total
        mu = np.broadcast_to(np.asarray(mu), idx.shape)
        sigma = np.broadcast_to(np.asarray(sigma), idx.shape)
        if idx.size > 1:
            order = np.argsort(idx, kind="stable")
            sidx = idx[order]
            last = np.ones(sidx.size, dtype=bool)
            last[:-1] = sidx[1:] != sidx[:-1]
            if not last.all():
                keep = order[last]
                idx, mu, sigma = idx[keep], mu[keep], sigma[keep]
        if idx.min() < 0 or idx.max() >= self.values.size:
            raise IndexError(f"voxel index out of range for a cache of {self.values.size} voxels")
        new = (self.table or default_table())(mu, sigma)
        old = self.values[idx]
        self.total += float(np.sum(new, dtype=np.float64) - np.sum(old, dtype=np.float64))
        self.values[idx] = new
        if self.on_change is not None:
            self.on_change(idx)
        self._since += idx.size
        if self._since >= self.resum_every:
            self.resum()
        return self.total

    def update_information(self, flat_idx, lam, eta) -> float:
        """:meth:`update` from information-form beliefs."""
        mu, sigma = moments(lam, eta)
        return self.update(flat_idx, mu, sigma)

    def refill_information(self, lam, eta) -> float:
        """Recompute every voxel's entropy in place from information-form beliefs (of the
        cache's size) and return the total: holders of this cache keep seeing it. A chunk of
        FILL_CHUNK voxels at a time: the moments and the table are elementwise, so the values
        are those of one whole-map pass, without its temporaries (about 100 MB of float32 on
        the 8.4 M-voxel campus floor, the largest transient of an agent's life). Raises
        ValueError when the sizes differ."""
        self._fill(lam, eta)
        if self.on_change is not None:
            self.on_change(None)
        return self.resum()

    def _fill(self, lam, eta) -> None:
        lam, eta = np.ravel(lam), np.ravel(eta)
        if not (self.values.size == lam.size == eta.size):
            raise ValueError(f"sizes differ: cache {self.values.size}, lam {lam.size}, eta {eta.size}")
        table = self.table or default_table()
        for i in range(0, lam.size, FILL_CHUNK):
            j = min(i + FILL_CHUNK, lam.size)
            self.values[i:j] = table(*moments(lam[i:j], eta[i:j]))

    def __len__(self) -> int:
        return self.values.size
