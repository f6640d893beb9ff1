"""Which map server shard owns which voxels: slabs of the grid along x (docs/sharding.md).

A sharded map service splits the mission's grid into ``N`` slabs ``[b_k, b_k+1)`` of x
indices, ``0 = b_0 < b_1 < ... < b_N = nx``. The flat index is C order over
``(nx, ny, nz)`` (swarm.map.grid), so a slab is one contiguous range of flat indices,
``[b_k * ny * nz, b_k+1 * ny * nz)``: shard ``k``'s own grid is the slab (origin moved by
``b_k`` voxels along x, shape ``(b_k+1 - b_k, ny, nz)``), and its local index of a voxel is
the global one minus the slab's offset. Every voxel has exactly one owner, so the team map
is the slabs side by side and fusion stays a sum per voxel (paper eq. 24-25): a delta split
by owner and merged on each shard gives the same map as merging it whole.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.map.delta import Delta
from swarm.map.grid import Grid


@dataclass(frozen=True)
class ShardLayout:
    """The slabs of ``grid`` owned by each shard: ``bounds`` are the x-index cuts (N+1 ints)."""

    grid: Grid
    bounds: tuple[int, ...]

    def __post_init__(self) -> None:
        bounds = tuple(int(b) for b in self.bounds)
        nx = self.grid.shape[0]
        if len(bounds) < 2 or bounds[0] != 0 or bounds[-1] != nx:
            raise ValueError(f"shard bounds must run from 0 to nx={nx}, got {list(bounds)}")
        if any(b >= a for a, b in zip(bounds[1:], bounds[:-1], strict=True)):
            raise ValueError(
                f"shard bounds must increase (every slab at least one voxel), got {list(bounds)}"
            )
        object.__setattr__(self, "bounds", bounds)

    # -- making one -------------------------------------------------------------------------
    @classmethod
    def single(cls, grid: Grid) -> ShardLayout:
        """One shard owning the whole grid (an unsharded map service)."""
        return cls(grid, (0, grid.shape[0]))

    @classmethod
    def even(cls, grid: Grid, shards: int) -> ShardLayout:
        """``shards`` slabs of (nearly) equal width. ValueError when ``shards`` is not in 1..nx."""
        nx = grid.shape[0]
        if not 1 <= int(shards) <= nx:
            raise ValueError(f"shards must be between 1 and the grid's nx={nx}, got {shards}")
        return cls(grid, tuple(int(round(k * nx / shards)) for k in range(int(shards) + 1)))

    @classmethod
    def at(cls, grid: Grid, cuts_x: list[float]) -> ShardLayout:
        """Slabs cut at world x coordinates ``cuts_x`` (metres, increasing), each rounded to the
        nearest voxel boundary. ValueError when a cut falls outside the grid or two meet."""
        x0, e = grid.lo[0], grid.voxel
        inner = [int(round((float(x) - x0) / e)) for x in cuts_x]
        try:
            return cls(grid, (0, *inner, grid.shape[0]))
        except ValueError:
            raise ValueError(
                f"cuts_x {list(cuts_x)} must increase strictly inside the workspace's x range "
                f"({grid.lo[0]:g} .. {grid.hi[0]:g} m), at least one voxel ({e:g} m) apart"
            ) from None

    # -- what a shard owns ------------------------------------------------------------------
    @property
    def count(self) -> int:
        return len(self.bounds) - 1

    @property
    def _plane(self) -> int:
        return self.grid.shape[1] * self.grid.shape[2]

    def span(self, shard: int) -> tuple[int, int]:
        """The flat global indices ``[start, stop)`` shard ``shard`` owns."""
        self._check(shard)
        return self.bounds[shard] * self._plane, self.bounds[shard + 1] * self._plane

    def offset(self, shard: int) -> int:
        """The global flat index of shard ``shard``'s local index 0."""
        return self.span(shard)[0]

    def grid_of(self, shard: int) -> Grid:
        """Shard ``shard``'s own grid: its slab, with the mission grid's voxel and y, z extent."""
        self._check(shard)
        nx0, nx1 = self.bounds[shard], self.bounds[shard + 1]
        ox, oy, oz = self.grid.origin
        _, ny, nz = self.grid.shape
        return Grid((ox + nx0 * self.grid.voxel, oy, oz), self.grid.voxel, (nx1 - nx0, ny, nz))

    def owner(self, idx: np.ndarray) -> np.ndarray:
        """The owning shard (int64) of each global flat index in ``idx`` (any shape)."""
        starts = np.asarray(self.bounds[1:-1], dtype=np.int64) * self._plane
        return np.searchsorted(starts, np.asarray(idx, dtype=np.int64), side="right")

    def split(self, delta: Delta) -> dict[int, Delta]:
        """``delta`` (global indices, sorted) cut into each owner's part, in the owner's local
        indices (sorted, uint32); shards owning none of its voxels are absent."""
        if len(delta) == 0:
            return {}
        idx = np.asarray(delta.idx, dtype=np.int64)
        cuts = np.searchsorted(idx, np.asarray(self.bounds, dtype=np.int64) * self._plane)
        parts = {}
        for shard in range(self.count):
            a, b = int(cuts[shard]), int(cuts[shard + 1])
            if b > a:
                local = (idx[a:b] - self.offset(shard)).astype(np.uint32)
                parts[shard] = Delta(local, delta.dlam[a:b], delta.deta[a:b])
        return parts

    def to_global(self, shard: int, idx: np.ndarray) -> np.ndarray:
        """Shard ``shard``'s local flat indices as global ones (int64). ValueError when one is
        outside the shard's slab."""
        local = np.asarray(idx, dtype=np.int64)
        start, stop = self.span(shard)
        if local.size and (local.min() < 0 or local.max() >= stop - start):
            raise ValueError(f"a voxel index outside shard {shard}'s {stop - start} voxels")
        return local + start

    def _check(self, shard: int) -> None:
        if not 0 <= shard < self.count:
            raise ValueError(f"no shard {shard}: the map service has shards 0..{self.count - 1}")
