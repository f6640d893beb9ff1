"""The block-sparse coverage map: the beliefs of docs/design.md section 3 on an unbounded lattice.

The same map as ``swarm.map.coverage_map.CoverageMap`` (float32 lam = 1/sigma^2 and
eta = mu/sigma^2 per voxel, prior + the sum of all deltas, eq. 24-25 in information form),
stored in blocks of B^3 voxels (``swarm.map.lattice``) allocated when a delta first touches
them. A voxel of no block holds the prior. Fusing the same rays, or applying the same
deltas in the same order, gives in every voxel the same float32 lam and eta as the dense
map on a grid aligned with the lattice (docs/map-core.md, "Block-sparse maps").

Storage: block ``slot`` owns entries ``slot * B^3 .. (slot + 1) * B^3`` of flat float32
arrays (``lam``, ``eta``, and the per-voxel entropy cache), its key in ``keys[slot]``; a
sorted array of packed keys finds a block's slot. Optional ``bounds`` (an aligned Grid: the
mission's workspace) makes it the dense map's twin: rays are cut at the bounds and deltas
reaching outside them refused.
"""

from __future__ import annotations

import numpy as np

from swarm.map import block_kernels as kernels
from swarm.map.block_delta import BlockDelta
from swarm.map.block_fusion import BlockBatchResult, block_batch_information
from swarm.map.coverage_map import (
    LAM_MAX,
    MEAN_SLACK,
    NONFINITE,
    OUT_OF_RANGE,
    CoverageMap,
    add_information,
    prior_information,
)
from swarm.map.delta import Delta
from swarm.map.entropy import expected_coverage, moments
from swarm.map.entropy_table import default_table
from swarm.map.gradient import entropy_gradient
from swarm.map.grid import Grid
from swarm.map.lattice import KEY_LIMIT, Lattice, pack_keys
from swarm.map.sensor_model import SensorModel


class BlockMap:
    """Beliefs of a lattice's voxels, in blocks allocated on first touch; the prior elsewhere.

    ``entropy``: keep the per-voxel entropy (eq. 16-17, through ``default_table``) of every
    allocated voxel and its per-block sums, updated on the voxels each delta touches (as a
    role's ``EntropyCache`` beside a dense map); without it entropies are computed when asked.
    """

    def __init__(
        self,
        lattice: Lattice,
        sensor: SensorModel | None = None,
        bounds: Grid | None = None,
        *,
        entropy: bool = True,
    ) -> None:
        self.lattice = lattice
        self.sensor = sensor or SensorModel()
        self.bounds = bounds
        self._box = None if bounds is None else lattice.box_of_grid(bounds)
        lam0, eta0 = prior_information(self.sensor)
        self.prior = (np.float32(lam0), np.float32(eta0))
        #: Entropy (bits, float32) of a voxel at the prior, as the dense map's cache holds it.
        self.prior_bits = np.float32(default_table()(*moments(*(np.array([v]) for v in self.prior)))[0])
        self.tracks_entropy = entropy
        self._bv = lattice.block_voxels
        self._shift = 3 * lattice.block_bits
        self.n_blocks = 0
        self._grow(0)
        self._packed = np.zeros(0, np.int64)  # sorted packed keys of the allocated blocks
        self._slot_of_packed = np.zeros(0, np.int64)

    @classmethod
    def for_grid(cls, grid: Grid, sensor: SensorModel | None = None, block_bits: int = 4, **kw) -> BlockMap:
        """The twin of ``CoverageMap(grid, sensor)``: lattice from the grid's corner, bounded by it."""
        return cls(Lattice.of_grid(grid, block_bits), sensor, bounds=grid, **kw)

    @classmethod
    def from_dense(cls, cmap: CoverageMap, block_bits: int = 4, bounded: bool = True, **kw) -> BlockMap:
        """A block map holding ``cmap``'s beliefs exactly: blocks where any voxel differs from the prior."""
        out = cls(Lattice.of_grid(cmap.grid, block_bits), cmap.sensor, cmap.grid if bounded else None, **kw)
        lam0, eta0 = out.prior
        flat = np.flatnonzero((cmap.lam != lam0) | (cmap.eta != eta0))
        ijk = cmap.grid.unflat(flat)
        lat = out.lattice
        slots = out._slots(lat.block_of(ijk), allocate=True)
        positions = slots * out._bv + lat.offset_of(ijk)
        out._lam[positions] = cmap.lam[flat]
        out._eta[positions] = cmap.eta[flat]
        if out.tracks_entropy:
            out._refresh_entropy(positions)
        return out

    def copy(self) -> BlockMap:
        """An independent copy (its own arrays)."""
        other = BlockMap(self.lattice, self.sensor, self.bounds, entropy=self.tracks_entropy)
        other._grow(self.n_blocks)
        n, used = self.n_blocks, self.n_blocks * self._bv
        other.n_blocks = n
        other._keys[:n] = self._keys[:n]
        other._lam[:used], other._eta[:used] = self._lam[:used], self._eta[:used]
        other._ent[:used], other._block_entropy[:n] = self._ent[:used], self._block_entropy[:n]
        other._packed, other._slot_of_packed = self._packed.copy(), self._slot_of_packed.copy()
        return other

    # -- blocks ------------------------------------------------------------------------
    @property
    def keys(self) -> np.ndarray:
        """Keys (n_blocks, 3) int64 of the allocated blocks, in allocation (slot) order."""
        return self._keys[: self.n_blocks]

    @property
    def allocated_voxels(self) -> int:
        return self.n_blocks * self._bv

    def nbytes(self) -> int:
        """Bytes the allocated blocks and their index hold: 12 per voxel with the entropy cache
        (lam, eta, entropy float32), 8 without, plus 48 per block (key, sum, index)."""
        per_voxel = 12 if self.tracks_entropy else 8
        return self.n_blocks * (self._bv * per_voxel + 48)

    def block(self, key) -> tuple[np.ndarray, np.ndarray] | None:
        """(lam, eta) of block ``key`` (3 ints) as (B, B, B) views, or None when it is not allocated."""
        slot = self._slots(np.asarray(key, dtype=np.int64).reshape(1, 3), allocate=False)[0]
        if slot < 0:
            return None
        b = self.lattice.block_side
        rows = slice(slot * self._bv, (slot + 1) * self._bv)
        return self._lam[rows].reshape(b, b, b), self._eta[rows].reshape(b, b, b)

    def extent(self) -> np.ndarray | None:
        """Voxel box (2, 3) int64 (lo inclusive, hi exclusive) of the allocated blocks, None if none."""
        if self.n_blocks == 0:
            return None
        return np.stack([self.keys.min(axis=0), self.keys.max(axis=0) + 1]) << self.lattice.block_bits

    def _grow(self, blocks: int) -> None:
        """Room for at least ``blocks`` blocks: the capacity doubles, the used part is copied (pages
        of the new arrays never written are not resident)."""
        cap = len(self._keys) if hasattr(self, "_keys") else 0
        if cap and blocks <= cap:
            return
        cap = max(blocks, 2 * cap, 64)
        n, used = self.n_blocks, self.n_blocks * self._bv
        voxel_arrays = ["_lam", "_eta"] + (["_ent"] if self.tracks_entropy else [])
        for name in voxel_arrays:
            arr = np.empty(cap * self._bv, np.float32)
            if hasattr(self, name):
                arr[:used] = getattr(self, name)[:used]
            setattr(self, name, arr)
        if not self.tracks_entropy:
            self._ent = np.zeros(0, np.float32)
        for name, shape, dtype in (("_keys", (cap, 3), np.int64), ("_block_entropy", (cap,), np.float64)):
            arr = np.empty(shape, dtype)
            if hasattr(self, name):
                arr[:n] = getattr(self, name)[:n]
            setattr(self, name, arr)

    def _slots(self, keys: np.ndarray, allocate: bool) -> np.ndarray:
        """Slot (K,) int64 of each block key (K, 3); -1 for one not allocated, unless ``allocate``."""
        slots, ok = kernels.find_slots(keys, self._packed, self._slot_of_packed, KEY_LIMIT)
        if not ok:
            pack_keys(keys)  # raises, naming the range
        hit = slots >= 0
        if allocate and not hit.all():
            packed = pack_keys(keys[~hit])
            if np.all(packed[1:] > packed[:-1]):  # sorted and unique, as in a canonical delta
                new, first, inverse = packed, slice(None), slice(None)
            else:
                new, first, inverse = np.unique(packed, return_index=True, return_inverse=True)
            fresh = self._allocate(np.asarray(keys, dtype=np.int64)[~hit][first])
            slots[~hit] = fresh[inverse]
            at = np.searchsorted(self._packed, new)
            self._packed = np.insert(self._packed, at, new)
            self._slot_of_packed = np.insert(self._slot_of_packed, at, fresh)
        return slots

    def _allocate(self, keys: np.ndarray) -> np.ndarray:
        """New blocks at the prior for ``keys`` (k, 3); their slots."""
        k, n = len(keys), self.n_blocks
        self._grow(n + k)
        rows = slice(n * self._bv, (n + k) * self._bv)
        self._lam[rows], self._eta[rows] = self.prior
        if self.tracks_entropy:
            self._ent[rows] = self.prior_bits
        self._block_entropy[n : n + k] = float(self.prior_bits) * self._bv
        self._keys[n : n + k] = keys
        self.n_blocks = n + k
        return np.arange(n, n + k, dtype=np.int64)

    def _forget_from(self, n: int) -> None:
        """Drop the blocks of slots n and later (allocated by a delta then refused)."""
        keep = self._slot_of_packed < n
        self._packed, self._slot_of_packed = self._packed[keep], self._slot_of_packed[keep]
        self.n_blocks = n

    # -- updates -----------------------------------------------------------------------
    def apply(self, delta: BlockDelta) -> None:
        """Add a block delta's information (eq. 24-25), allocating the blocks it touches.

        Raises ValueError, the map unchanged, for another block size, an offset beyond a block,
        a voxel outside ``bounds``, a key beyond the lattice's range, or NaN/inf increments.
        Entries listed twice add twice.
        """
        self._add(delta, check_range=False)

    def apply_received(self, delta: BlockDelta) -> None:
        """:meth:`apply`, also refused (map unchanged) when a touched voxel would end with
        information outside (0, LAM_MAX] or a mean outside [0, 1] (``CoverageMap.apply_received``)."""
        self._add(delta, check_range=True)

    def apply_flat(self, delta: Delta, grid: Grid, received: bool = False) -> None:
        """Apply a flat ``Delta`` over ``grid`` (aligned with the lattice), as ``CoverageMap.apply``."""
        block = BlockDelta.from_flat(delta, grid, self.lattice)
        self.apply_received(block) if received else self.apply(block)

    def _add(self, delta: BlockDelta, check_range: bool) -> None:
        if delta.block_bits != self.lattice.block_bits:
            raise ValueError(
                f"delta in blocks of {1 << delta.block_bits} voxels, "
                f"map in blocks of {self.lattice.block_side}"
            )
        n_before = self.n_blocks
        slots = self._slots(delta.keys, allocate=True)
        box = self._box if self._box is not None else np.zeros((2, 3), np.int64)
        positions, status = kernels.global_index(
            delta.keys,
            delta.counts,
            delta.offsets,
            slots,
            self.lattice.block_bits,
            box,
            self._box is not None,
        )
        reason = _INDEX_REFUSALS.get(status)
        if reason is None:
            status = add_information(
                self._lam, self._eta, positions, delta.dlam, delta.deta, check_range, LAM_MAX, MEAN_SLACK
            )
            reason = _VALUE_REFUSALS.get(status)
        if reason is not None:
            self._forget_from(n_before)
            raise ValueError(reason)
        if self.tracks_entropy:
            self._refresh_entropy(positions)

    def _refresh_entropy(self, positions: np.ndarray) -> None:
        """Recompute the cached entropy of the voxels at ``positions`` (each once) and their blocks' sums."""
        touched = kernels.take_touched(self._ent, positions, self._block_entropy, self._shift)
        new = default_table()(*moments(self._lam[touched], self._eta[touched]))
        kernels.put_touched(self._ent, touched, new, self._block_entropy, self._shift)

    def integrate(self, origin: np.ndarray, points: np.ndarray, **options) -> BlockBatchResult:
        """Fuse one batch of hit points seen from ``origin``; returns the batch and its block delta.

        ``options``: ``hit_precedence``, ``discretize``, ``weighted`` of ``block_batch_information``.
        """
        result = block_batch_information(self.lattice, self.sensor, origin, points, self.bounds, **options)
        self.apply(result.delta)
        return result

    def delta_from_prior(self) -> BlockDelta:
        """Everything this map knows beyond the prior, as one block delta: the voxels whose lam or
        eta differ from the prior's float32, each with (lam - lam0, eta - eta0) as the dense map."""
        lam0, eta0 = prior_information(self.sensor)
        used = self.allocated_voxels
        lam, eta = self._lam[:used], self._eta[:used]
        changed = np.flatnonzero((lam != self.prior[0]) | (eta != self.prior[1]))
        dlam = (lam[changed].astype(np.float64) - lam0).astype(np.float32)
        deta = (eta[changed].astype(np.float64) - eta0).astype(np.float32)
        keys = self.keys[changed // self._bv]
        return BlockDelta.from_entries(self.lattice.block_bits, keys, changed % self._bv, dlam, deta)

    # -- beliefs of a region --------------------------------------------------------------
    def _region_lo(self, region: Grid) -> np.ndarray:
        return self.lattice.offset_of_grid(region)

    def _gather(self, values: np.ndarray, region: Grid, fill) -> np.ndarray:
        return self._gather_box(values, self._region_lo(region), region.shape, fill)

    def _gather_box(self, values: np.ndarray, lo: np.ndarray, shape, fill) -> np.ndarray:
        """``values`` of the box of ``shape`` from lattice voxel ``lo``; ``fill`` where unallocated."""
        out = np.full(tuple(int(n) for n in shape), fill, dtype=values.dtype)
        kernels.gather(values, self.keys, self.lattice.block_bits, np.asarray(lo, np.int64), out)
        return out

    def beliefs(self, region: Grid) -> tuple[np.ndarray, np.ndarray]:
        """(lam, eta) float32 (nx, ny, nz) of ``region`` (an aligned Grid); the prior where unallocated."""
        return self._gather(self._lam, region, self.prior[0]), self._gather(self._eta, region, self.prior[1])

    def to_dense(self, region: Grid | None = None) -> CoverageMap:
        """The dense map of ``region`` (default ``bounds``): equal, voxel for voxel, to this map there."""
        region = self._region(region)
        lam, eta = self.beliefs(region)
        return CoverageMap(region, self.sensor, lam, eta)

    def expected_coverage(self, region: Grid) -> np.ndarray:
        """E[C] (float64, nx x ny x nz) of the region's voxels: the truncated belief's mean."""
        return expected_coverage(*moments(*self.beliefs(region)))

    def known_threshold(self) -> np.float32:
        """The float32 lam above which a voxel counts as known (``CoverageMap.known_threshold``)."""
        return self.prior[0] * np.float32(1.0 + 1e-5)

    def known_voxels(self) -> int:
        """How many voxels hold information beyond the prior (lam above ``known_threshold``)."""
        return int(np.count_nonzero(self._lam[: self.allocated_voxels] > self.known_threshold()))

    def known_mask(self, region: Grid) -> np.ndarray:
        """Voxels of ``region`` with information beyond the prior (nx, ny, nz) bool."""
        return self._gather(self._lam, region, self.prior[0]) > self.known_threshold()

    # -- entropy --------------------------------------------------------------------------
    def _entropies(self) -> tuple[np.ndarray, np.ndarray]:
        """Per-voxel entropies of the allocated blocks (flat) and their per-block sums."""
        if self.tracks_entropy:
            return self._ent, self._block_entropy
        used = self.allocated_voxels
        values = default_table()(*moments(self._lam[:used], self._eta[:used]))
        return values, values.reshape(-1, self._bv).sum(axis=1, dtype=np.float64)

    def entropy(self, region: Grid) -> np.ndarray:
        """Per-voxel entropy (bits, float32, nx x ny x nz) of ``region``; the prior's where unallocated."""
        return self._gather(self._entropies()[0], region, self.prior_bits)

    def entropy_bits(self, region: Grid | None = None) -> float:
        """Map entropy (eq. 31) over ``region`` (default ``bounds``): the allocated voxels' entropies
        inside it plus its unallocated voxels times the prior's. Raises ValueError with no region."""
        region = self._region(region)
        lo = self._region_lo(region)
        values, sums = self._entropies()
        total, voxels = kernels.region_sums(
            values, sums, self.keys, self.lattice.block_bits, lo, lo + region.shape
        )
        return float(total) + (region.size - int(voxels)) * float(self.prior_bits)

    def allocated_entropy_bits(self) -> float:
        """Entropy of the allocated voxels alone (no box needed)."""
        return float(np.sum(self._entropies()[1][: self.n_blocks]))

    def entropy_removed_bits(self) -> float:
        """Prior entropy less entropy over any region holding every allocated block: what the map
        has learnt, in bits, with no box (eq. 31 of a region, subtracted from its prior's)."""
        return self.allocated_voxels * float(self.prior_bits) - self.allocated_entropy_bits()

    def entropy_gradient(self, region: Grid) -> np.ndarray:
        """Eq. 32's backward-difference gradient (float32, nx x ny x nz x 3) of ``region``'s entropy.

        Equal to ``gradient.entropy_gradient`` of the dense map's entropy field taken on its whole
        grid, then cut to ``region``: the differences at the region's lower faces use the voxels
        just below them (allocated or prior), except at the lower faces of ``bounds``, where the
        component is 0 as at a grid's boundary. Project it with ``gradient.project_on_plane`` (eq. 33).
        """
        lo = self._region_lo(region)
        below = np.ones(3, np.int64)
        if self._box is not None:
            below = np.where(lo > self._box[0], 1, 0)
        H = self._gather_box(self._entropies()[0], lo - below, np.add(region.shape, below), self.prior_bits)
        G = entropy_gradient(H, self.lattice.voxel)
        return G[below[0] :, below[1] :, below[2] :]

    def _region(self, region: Grid | None) -> Grid:
        if region is not None:
            return region
        if self.bounds is None:
            raise ValueError("an unbounded map needs a region (an aligned Grid) for this")
        return self.bounds


_INDEX_REFUSALS = {
    kernels.BAD_OFFSET: "delta offset beyond its block's voxels",
    kernels.OUTSIDE_BOUNDS: "delta reaches a voxel outside the map's bounds",
}
_VALUE_REFUSALS = {
    NONFINITE: "delta holds NaN or inf information",
    OUT_OF_RANGE: f"delta would leave a voxel's information outside (0, {LAM_MAX:g}] "
    "or its mean outside [0, 1]",
}


def warm_up() -> None:
    """Load (or, on a first run, compile and cache) the block map's kernels now, as
    ``swarm.map.fusion.warm_up`` does for the dense map: fusion under each information model,
    deltas in and out of blocks, entropies and gradients of a region."""
    grid = Grid((0.0, 0.0, 0.0), 1.0, (4, 4, 4))
    for bits in (1, 4):  # blocks smaller than the kernel's bricks, and not
        for discretize, weighted in ((False, False), (True, False), (True, True)):
            cmap = BlockMap(
                Lattice.of_grid(grid, bits), SensorModel(discretize=discretize, weighted=weighted)
            )
            result = cmap.integrate(np.full(3, 0.5), np.full((1, 3), 2.5))
    cmap.apply_flat(result.delta.to_flat(grid, cmap.lattice), grid, received=True)
    far = SensorModel(max_range=1e3)  # a reach too long for a cube: the box from the rays' ends
    BlockMap(cmap.lattice, far).integrate(np.full(3, 0.5), np.full((1, 3), 2.5))
    cmap.entropy_bits(grid)
    cmap.entropy_gradient(grid)
    cmap.beliefs(grid)
