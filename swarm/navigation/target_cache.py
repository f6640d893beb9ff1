"""Eq. 35 bookkeeping kept per tile of the map's columns and redone only where the map changed:
the coordinator's (team map) and each agent's (its own map).

Every coordinator answer ranks the eq. 35 targets of the whole team map
(``CoordinatorState.answer``), and every target an agent chooses alone reads the fields of the
whole slab. Done from scratch that is several passes over the map each time: the slab's
beliefs (known, E[C]), the entropy gradient (eq. 32) projected on the motion plane (eq. 33),
the eq. 35 score, then a standing point (``standing_cell``) for each of up to a few hundred
candidates. None of these depends on which robot asks: the slab fields depend on the map
alone (the plane of a ground robot is horizontal whatever its yaw), and a column's standing
point on the reachable cells and the opaque slab voxels within the view's far range of it.

So the map's x-y columns are cut into tiles of ``TILE`` x ``TILE`` columns.
:class:`ChangedTiles` records, as deltas are applied (under the replica's lock), which tiles
hold a changed voxel; :class:`TargetCache` keeps for each sensor layer k0 the slab fields
(:func:`swarm.navigation.exploration.slab_fields` on blocks of tiles with a column of halo,
which gives the values of the whole-slab pass exactly) and a memo of standing cells, and
before an answer redoes the fields of the changed tiles and forgets the standing cells
within one tile of a tile whose fields or reachable cells changed. The full pass
(``CoordinatorState.candidates_for``) stays the oracle: tests check the cache gives the
same candidates after random sequences of deltas.
"""

from __future__ import annotations

import math
import threading
from collections.abc import Iterator
from dataclasses import dataclass, field

import numpy as np
from numba import njit

from swarm.map.coverage_map import CoverageMap
from swarm.map.grid import Grid
from swarm.navigation.exploration import SlabFields, StandingFn, slab_fields
from swarm.navigation.search_context import SearchContext, slab_beliefs
from swarm.navigation.standing_points import ViewGeometry, standing_cell

#: Columns per side of a tile (3.2 m at 0.1 m voxels).
TILE = 32
#: Standing-cell memo values: not computed yet, and no standing cell.
UNKNOWN, NONE = -2, -1


def tiles_of(shape_xy: tuple[int, int], tile: int = TILE) -> tuple[int, int]:
    """How many tiles (tx, ty) cover columns of ``shape_xy`` (nx, ny)."""
    return math.ceil(shape_xy[0] / tile), math.ceil(shape_xy[1] / tile)


def tiles_any(mask: np.ndarray, tile: int = TILE) -> np.ndarray:
    """(tx, ty): the tiles holding a True cell of ``mask`` (nx, ny)."""
    nx, ny = mask.shape
    tx, ty = tiles_of((nx, ny), tile)
    padded = np.zeros((tx * tile, ty * tile), dtype=bool)
    padded[:nx, :ny] = mask
    return padded.reshape(tx, tile, ty, tile).any(axis=(1, 3))


def grow_tiles(tiles: np.ndarray) -> np.ndarray:
    """Tiles (tx, ty) and their 8 neighbours."""
    out = tiles.copy()
    out[1:] |= tiles[:-1]
    out[:-1] |= tiles[1:]
    row = out.copy()
    out[:, 1:] |= row[:, :-1]
    out[:, :-1] |= row[:, 1:]
    return out


def dirty_runs(tiles: np.ndarray) -> Iterator[tuple[int, int, int]]:
    """(ti, tj0, tj1) for each run of True tiles [tj0, tj1) in a row ti of ``tiles`` (tx, ty):
    the blocks of columns a cache redoes in one piece."""
    for ti in np.flatnonzero(tiles.any(axis=1)):
        edges = np.flatnonzero(np.diff(np.concatenate([[0], tiles[ti].astype(np.int8), [0]])))
        for a, b in zip(edges[::2], edges[1::2], strict=True):
            yield int(ti), int(a), int(b)


@njit(cache=True, nogil=True)
def mark_columns(tiles, idx, nx, ny, nz, tile):  # pragma: no cover - compiled
    """tiles[ti, tj] = True for the tile of each voxel ``idx`` (flat, C order, of a grid
    (nx, ny, nz)) and the tiles of the columns (i + 1, j) and (i, j + 1) beside it; returns
    how many indices were outside the grid (those mark nothing)."""
    outside = 0
    for n in range(idx.shape[0]):
        if idx[n] < 0 or idx[n] >= nx * ny * nz:
            outside += 1
            continue
        col = idx[n] // nz
        i, j = col // ny, col % ny
        ti, tj = i // tile, j // tile
        tiles[ti, tj] = True
        tiles[min(i + 1, nx - 1) // tile, tj] = True
        tiles[ti, min(j + 1, ny - 1) // tile] = True
    return outside


class ChangedTiles:
    """Which tiles of the map's columns changed since each reader last took them.

    ``shape`` is the grid's (nx, ny, nz); voxel indices are flat in C order. A changed voxel
    of column (i, j) also marks the tiles of (i + 1, j) and (i, j + 1), whose backward
    differences (eq. 32) read it. Thread-safe: marks come from the replica's thread, takes
    from the answering one.
    """

    def __init__(self, shape, tile: int = TILE) -> None:
        self.nx, self.ny, self.nz = (int(n) for n in shape)
        self.tile = int(tile)
        self.tiles = tiles_of((self.nx, self.ny), self.tile)
        self._readers: dict[str, np.ndarray] = {}
        self._lock = threading.Lock()

    def take(self, reader: str) -> np.ndarray:
        """(tx, ty) bool: the tiles changed since ``reader`` last took them (all of them the
        first time), and forget them for ``reader``."""
        with self._lock:
            seen = self._readers.get(reader)
            self._readers[reader] = np.zeros(self.tiles, dtype=bool)
        return np.ones(self.tiles, dtype=bool) if seen is None else seen

    def mark(self, idx: np.ndarray) -> None:
        """Voxels ``idx`` (flat, int64) changed. Raises IndexError for a voxel outside the grid
        (nothing marked)."""
        changed = np.zeros(self.tiles, dtype=bool)
        idx = np.ascontiguousarray(idx, dtype=np.int64).reshape(-1)
        if mark_columns(changed, idx, self.nx, self.ny, self.nz, self.tile):
            raise IndexError(f"voxel index outside a grid of {(self.nx, self.ny, self.nz)}")
        with self._lock:
            for seen in self._readers.values():
                seen |= changed

    def note(self, idx: np.ndarray | None) -> None:
        """``EntropyCache.on_change``: voxels ``idx`` changed, or every voxel (None)."""
        if idx is None:
            self.mark_all()
        else:
            self.mark(idx)

    def mark_all(self) -> None:
        """Everything changed (a snapshot was loaded)."""
        with self._lock:
            for seen in self._readers.values():
                seen[:] = True


@dataclass(eq=False)
class SlabCache:
    """The eq. 32-35 fields of one sensor layer ``k0`` (all (nx, ny)) and its standing-cell memo.

    ``known``/``cov``: the slab voxels' beliefs (known, E[C]); ``G``, ``gnorm``, ``score``:
    :func:`slab_fields`; ``stands``: flat cell i * ny + j of each column's standing cell,
    NONE (none fits) or UNKNOWN (not computed since its neighbourhood changed);
    ``stand_reach``: the reachable cells the memo holds for; ``changed``: tiles whose fields
    changed since the memo was last brought up to date.
    """

    k0: int
    known: np.ndarray
    cov: np.ndarray
    G: np.ndarray
    gnorm: np.ndarray
    score: np.ndarray
    stands: np.ndarray
    stand_reach: np.ndarray
    changed: np.ndarray
    view: ViewGeometry | None = None
    counts: dict = field(default_factory=lambda: {"tiles": 0, "stands": 0, "memo": 0})

    @property
    def beliefs(self) -> tuple[np.ndarray, np.ndarray]:
        """(known, E[C]) for ``SearchContext.build(slab=...)``."""
        return self.known, self.cov

    @property
    def fields(self) -> SlabFields:
        """(G, |G|, score) for ``rank_entropy_targets(slab=...)``."""
        return self.G, self.gnorm, self.score


class TargetCache:
    """Per sensor layer, a :class:`SlabCache` brought up to date from :class:`ChangedTiles`.

    Call :meth:`slab` with the replica's lock held (it reads the map's voxels of the changed
    tiles) and :meth:`standing` from one thread at a time (the coordinator's answers).
    """

    def __init__(self, grid: Grid, changes: ChangedTiles) -> None:
        self.grid = grid
        self.changes = changes
        self.tile = changes.tile
        self._slabs: dict[int, SlabCache] = {}

    def slab(self, cmap: CoverageMap, entropy: np.ndarray, k0: int) -> SlabCache:
        """Layer ``k0``'s fields with every changed tile redone; ``entropy`` (flat, bits) is
        the map's per-voxel entropy."""
        nx, ny, nz = self.grid.shape
        dirty = self.changes.take(f"slab{k0}")
        cache = self._slabs.get(k0)
        if cache is None:
            empty = np.zeros((nx, ny))
            cache = self._slabs[k0] = SlabCache(
                k0,
                np.zeros((nx, ny), dtype=bool),
                empty.copy(),
                np.zeros((nx, ny, 3), dtype=np.float32),
                np.zeros((nx, ny), dtype=np.float32),
                empty.copy(),
                np.full((nx, ny), UNKNOWN, dtype=np.int64),
                np.zeros((nx, ny), dtype=bool),
                np.ones(self.changes.tiles, dtype=bool),
            )
            dirty = np.ones(self.changes.tiles, dtype=bool)
        H = entropy.reshape(nx, ny, nz)
        for ti, a, b in dirty_runs(dirty):
            self._redo(cache, cmap, H, ti * self.tile, a * self.tile, b * self.tile)
            cache.counts["tiles"] += b - a
        cache.changed |= dirty
        return cache

    def _redo(self, cache: SlabCache, cmap: CoverageMap, H: np.ndarray, i0: int, j0: int, j1: int) -> None:
        """Recompute the fields of columns [i0, i0 + tile) x [j0, j1), with one column of halo."""
        nx, ny, _ = self.grid.shape
        i1, j1 = min(i0 + self.tile, nx), min(j1, ny)
        h0, g0 = max(i0 - 1, 0), max(j0 - 1, 0)  # the halo's first column (none at the map's edge)
        k0 = cache.k0
        cols = np.arange(h0, i1)[:, None] * ny + np.arange(g0, j1)[None, :]
        known, cov = slab_beliefs(cmap, k0, cols)
        G, gnorm, score = slab_fields(H[h0:i1, g0:j1, max(k0 - 1, 0) : k0 + 1], self.grid.voxel, cov)
        inner = (slice(i0 - h0, None), slice(j0 - g0, None))
        block = (slice(i0, i1), slice(j0, j1))
        cache.known[block] = known[inner]
        cache.cov[block] = cov[inner]
        cache.G[block] = G[inner]
        cache.gnorm[block] = gnorm[inner]
        cache.score[block] = score[inner]

    def standing(self, cache: SlabCache, reach: np.ndarray, view: ViewGeometry) -> StandingFn:
        """``standing_cell`` memoised for ``reach`` (the context's reachable cells) and ``view``.

        The memo forgets the columns within one tile of a tile whose fields changed (opaque
        voxels, gradient) or whose reachable cells differ from the memo's; a view whose far
        range exceeds a tile, or another view than the memo's, forgets it all.
        """
        ny = reach.shape[1]
        whole = cache.view != view or math.ceil(view.far / self.grid.voxel) > self.tile
        if whole:
            stale = np.ones_like(cache.changed)
        else:
            stale = grow_tiles(cache.changed | tiles_any(reach != cache.stand_reach, self.tile))
        if stale.all():
            cache.stands[:] = UNKNOWN
        else:
            for ti, tj in np.argwhere(stale):
                i0, j0 = ti * self.tile, tj * self.tile
                cache.stands[i0 : i0 + self.tile, j0 : j0 + self.tile] = UNKNOWN
        cache.stand_reach = reach.copy()
        cache.changed[:] = False
        cache.view = view
        stands, counts = cache.stands, cache.counts

        def stand(ctx: SearchContext, i: int, j: int, g: np.ndarray, v: ViewGeometry):
            memo = int(stands[i, j])
            if v != view or memo == UNKNOWN:
                cell = standing_cell(ctx, i, j, g, v)
                counts["stands"] += 1
                if v == view:
                    stands[i, j] = NONE if cell is None else cell[0] * ny + cell[1]
                return cell
            counts["memo"] += 1
            return None if memo == NONE else divmod(memo, ny)

        return stand
