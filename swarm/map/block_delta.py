"""Deltas in blocks: the information (dlam, deta) a robot gathered, per voxel of a block-sparse lattice.

The block form of ``swarm.map.delta.Delta`` (docs/design.md section 3; docs/map-core.md,
"Block-sparse maps"): no grid, no box. A delta names the blocks it touches by their key (an
int32 triple, ``swarm.map.lattice``) and, per block, the in-block offsets of its voxels
(uint16, C order inside the block) with their float32 increments. Entries are grouped by
block: block n owns entries ``starts[n]:starts[n + 1]``. The canonical form, which fusion
and the conversions produce, has keys sorted (lexicographic) and unique, and offsets sorted
and unique within a block; any other order adds the same information (an entry listed twice
adds twice, as in ``Delta``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.map import block_kernels as kernels
from swarm.map.delta import Delta
from swarm.map.grid import Grid
from swarm.map.lattice import MAX_BLOCK_BITS, MIN_BLOCK_BITS, Lattice, check_box, pack_keys


@dataclass(frozen=True)
class BlockDelta:
    """Sparse information increments by block.

    ``block_bits``: blocks of 2^bits voxels a side; ``keys`` (K, 3) int32 block keys;
    ``counts`` (K,) uint32 entries per block; ``offsets`` (N,) uint16 in-block offsets;
    ``dlam``, ``deta`` (N,) float32. Raises ValueError when the arrays disagree in shape.
    """

    block_bits: int
    keys: np.ndarray
    counts: np.ndarray
    offsets: np.ndarray
    dlam: np.ndarray
    deta: np.ndarray

    def __post_init__(self) -> None:
        if not MIN_BLOCK_BITS <= self.block_bits <= MAX_BLOCK_BITS:
            raise ValueError(
                f"block delta: block_bits {self.block_bits} outside {MIN_BLOCK_BITS}..{MAX_BLOCK_BITS}"
            )
        shape = np.shape(self.keys)
        if len(shape) != 2 or shape[1] != 3:
            raise ValueError(f"block delta: keys must be (K, 3), got shape {shape}")
        if len(self.counts) != shape[0]:
            raise ValueError(f"block delta: {shape[0]} keys but {len(self.counts)} counts")
        n = len(self.offsets)
        if not (n == len(self.dlam) == len(self.deta)):
            raise ValueError(
                f"block delta arrays differ in length: offsets {n}, dlam {len(self.dlam)}, "
                f"deta {len(self.deta)}"
            )
        total = int(np.add.reduce(self.counts, dtype=np.int64))
        if total != n:
            raise ValueError(f"block delta: counts add up to {total}, but there are {n} entries")

    def __len__(self) -> int:
        return len(self.offsets)

    @property
    def block_count(self) -> int:
        return len(self.keys)

    @property
    def starts(self) -> np.ndarray:
        """(K + 1,) int64: block n owns entries ``starts[n]:starts[n + 1]``."""
        out = np.zeros(len(self.counts) + 1, dtype=np.int64)
        np.cumsum(self.counts, out=out[1:])
        return out

    @classmethod
    def empty(cls, block_bits: int = 4) -> BlockDelta:
        return cls(
            block_bits,
            np.zeros((0, 3), np.int32),
            np.zeros(0, np.uint32),
            np.zeros(0, np.uint16),
            np.zeros(0, np.float32),
            np.zeros(0, np.float32),
        )

    def is_finite(self) -> bool:
        return bool(np.all(np.isfinite(self.dlam)) and np.all(np.isfinite(self.deta)))

    def nbytes(self) -> int:
        """Bytes of its arrays as they travel: keys 12 per block, counts 2, offsets 2 and 8 per entry."""
        return 14 * self.block_count + 10 * len(self)

    def voxels(self) -> np.ndarray:
        """Lattice voxel indices (N, 3) int64 of the entries."""
        keys = np.repeat(self.keys.astype(np.int64), self.counts.astype(np.int64), axis=0)
        b, m = self.block_bits, (1 << self.block_bits) - 1
        off = self.offsets.astype(np.int64)
        inner = np.stack([(off >> (2 * b)) & m, (off >> b) & m, off & m], axis=-1)
        return (keys << b) + inner

    # -- conversions -----------------------------------------------------------------------
    @classmethod
    def from_box(
        cls, idx: np.ndarray, dlam: np.ndarray, deta: np.ndarray, box: np.ndarray, block_bits: int
    ) -> BlockDelta:
        """The canonical block delta of flat C-order indices ``idx`` over the lattice voxel box
        ``box`` (2, 3) (lo inclusive, hi exclusive): the output of the fusion kernel, or of a
        Delta over an aligned grid. ``idx`` sorted (as a Delta's) gives sorted offsets.
        Raises ValueError for an index outside the box or a key outside the lattice's range.
        """
        box = np.asarray(box, dtype=np.int64)
        shape = box[1] - box[0]
        b = int(block_bits)
        check_box(box, b)
        keys, counts, offsets, lam, eta, ok = kernels.scatter_box(
            idx, np.asarray(dlam, dtype=np.float32), np.asarray(deta, dtype=np.float32), box[0], shape, b
        )
        if not ok:
            size = int(np.prod(shape))
            raise ValueError(
                f"voxel index out of grid: range [{np.min(idx)}, {np.max(idx)}] for {size} voxels"
            )
        return cls(b, keys.astype(np.int32), counts.astype(np.uint32), offsets, lam, eta)

    @classmethod
    def from_entries(
        cls, block_bits: int, keys: np.ndarray, offsets: np.ndarray, dlam: np.ndarray, deta: np.ndarray
    ) -> BlockDelta:
        """The canonical block delta of entries given one by one: block key (N, 3) and in-block
        offset (N,) of each, with its increments. Repeated voxels stay repeated, in input order."""
        keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
        offsets = np.asarray(offsets, dtype=np.int64)
        if len(offsets) and (offsets.min() < 0 or offsets.max() >= 1 << (3 * int(block_bits))):
            raise ValueError(f"offsets must lie in [0, {1 << (3 * int(block_bits))})")
        packed = pack_keys(keys)
        order = np.lexsort((offsets, packed))
        packed = packed[order]
        first = np.flatnonzero(np.r_[True, packed[1:] != packed[:-1]]) if len(packed) else np.zeros(0, int)
        counts = np.diff(np.r_[first, len(packed)])
        return cls(
            int(block_bits),
            keys[order][first].astype(np.int32),
            counts.astype(np.uint32),
            offsets[order].astype(np.uint16),
            np.asarray(dlam, dtype=np.float32)[order],
            np.asarray(deta, dtype=np.float32)[order],
        )

    @classmethod
    def from_flat(cls, delta: Delta, grid: Grid, lattice: Lattice) -> BlockDelta:
        """The block form of a flat ``delta`` over ``grid`` (aligned with ``lattice``).

        Raises ValueError for an index outside the grid or a grid not on the lattice.
        """
        box = lattice.box_of_grid(grid)
        return cls.from_box(delta.idx, delta.dlam, delta.deta, box, lattice.block_bits)

    def to_flat(self, grid: Grid, lattice: Lattice) -> Delta:
        """The flat Delta over ``grid`` (aligned with ``lattice``) of this delta, indices sorted.

        Raises ValueError when an entry lies outside the grid (cut it first with :meth:`within`)
        or the grid is not on the lattice.
        """
        self._check_lattice(lattice)
        ijk = self.voxels() - lattice.offset_of_grid(grid)
        inside = grid.contains_index(ijk)
        if not np.all(inside):
            raise ValueError(f"{int(np.count_nonzero(~inside))} of the delta's voxels lie outside the grid")
        flat = grid.flat(ijk)
        order = np.argsort(flat, kind="stable")
        return Delta(flat[order].astype(np.uint32), self.dlam[order], self.deta[order])

    def within(self, grid: Grid, lattice: Lattice) -> BlockDelta:
        """The entries whose voxels lie inside ``grid`` (aligned with ``lattice``), block order kept."""
        self._check_lattice(lattice)
        ijk = self.voxels() - lattice.offset_of_grid(grid)
        keep = grid.contains_index(ijk)
        if np.all(keep):
            return self
        block = np.repeat(np.arange(self.block_count), self.counts.astype(np.int64))
        counts = np.bincount(block[keep], minlength=self.block_count)
        blocks = counts > 0
        return BlockDelta(
            self.block_bits,
            self.keys[blocks],
            counts[blocks].astype(np.uint32),
            self.offsets[keep],
            self.dlam[keep],
            self.deta[keep],
        )

    def _check_lattice(self, lattice: Lattice) -> None:
        if lattice.block_bits != self.block_bits:
            raise ValueError(
                f"delta in blocks of {1 << self.block_bits} voxels, lattice in blocks of {lattice.block_side}"
            )
