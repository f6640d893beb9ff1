"""An unbounded voxel lattice cut into fixed blocks (the geometry of ``swarm.map.block_map``).

Voxel (i, j, k) is the half-open box origin + [i, i+1) x [j, j+1) x [k, k+1) times the voxel
edge e, for any int64 triple: index = floor((p - origin) / e), as ``swarm.map.grid.Grid``
but with no box. Blocks are cubes of B = 2^bits voxels a side: voxel (i, j, k) lies in
block (i >> bits, j >> bits, k >> bits) (floor division, also for negative indices) at
offset ((i & m) << 2 bits) | ((j & m) << bits) | (k & m), m = B - 1: C order inside the
block. A Grid is *aligned* with a lattice when it has the lattice's voxel and its origin is
the origin of a lattice voxel; its voxel (a, b, c) is then lattice voxel (a, b, c) +
``offset``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.map.grid import Grid

#: Block coordinates must lie in (-KEY_LIMIT, KEY_LIMIT) (they are packed 21 bits each into
#: one int64 key, and travel as int32): at 16 voxels of 0.1 m, +-1,677 km from the origin.
KEY_LIMIT = 1 << 20
#: Block sizes allowed: 2^1 .. 2^5 voxels a side (offsets fit uint16).
MIN_BLOCK_BITS, MAX_BLOCK_BITS = 1, 5


@dataclass(frozen=True)
class Lattice:
    """Voxels of edge ``voxel`` (m) from ``origin`` (the corner of voxel (0, 0, 0), m), in blocks
    of ``2 ** block_bits`` voxels a side. Raises ValueError for a bad origin, voxel or size."""

    origin: tuple[float, float, float]
    voxel: float
    block_bits: int = 4

    def __post_init__(self) -> None:
        origin = tuple(float(v) for v in self.origin)
        if len(origin) != 3 or not all(np.isfinite(origin)):
            raise ValueError(f"lattice origin must be 3 finite numbers, got {self.origin!r}")
        if not (np.isfinite(self.voxel) and self.voxel > 0):
            raise ValueError(f"voxel size must be a positive number, got {self.voxel!r}")
        bits = int(self.block_bits)
        if bits != self.block_bits or not MIN_BLOCK_BITS <= bits <= MAX_BLOCK_BITS:
            raise ValueError(
                f"block_bits must be an integer from {MIN_BLOCK_BITS} to {MAX_BLOCK_BITS} "
                f"(blocks of 2 to 32 voxels a side), got {self.block_bits!r}"
            )
        object.__setattr__(self, "origin", origin)
        object.__setattr__(self, "voxel", float(self.voxel))
        object.__setattr__(self, "block_bits", bits)

    @classmethod
    def of_grid(cls, grid: Grid, block_bits: int = 4) -> Lattice:
        """The lattice whose voxel (0, 0, 0) is the grid's first voxel (the grid is aligned, offset 0)."""
        return cls(grid.origin, grid.voxel, block_bits)

    # -- sizes ---------------------------------------------------------------------------
    @property
    def block_side(self) -> int:
        """B: voxels along a block's edge."""
        return 1 << self.block_bits

    @property
    def block_voxels(self) -> int:
        """B^3: voxels in a block."""
        return 1 << (3 * self.block_bits)

    @property
    def lo(self) -> np.ndarray:
        return np.asarray(self.origin, dtype=np.float64)

    # -- indices -------------------------------------------------------------------------
    def index_of(self, points: np.ndarray) -> np.ndarray:
        """Voxel index (..., 3) int64 of world points (..., 3): floor((p - origin) / voxel)."""
        points = np.asarray(points, dtype=np.float64)
        return np.floor((points - self.lo) / self.voxel).astype(np.int64)

    def block_of(self, ijk: np.ndarray) -> np.ndarray:
        """Block key (..., 3) int64 of voxel indices (..., 3)."""
        return np.asarray(ijk, dtype=np.int64) >> self.block_bits

    def offset_of(self, ijk: np.ndarray) -> np.ndarray:
        """In-block offset (...,) int64 of voxel indices (..., 3) (C order inside the block)."""
        ijk = np.asarray(ijk, dtype=np.int64)
        b, m = self.block_bits, self.block_side - 1
        return ((ijk[..., 0] & m) << (2 * b)) | ((ijk[..., 1] & m) << b) | (ijk[..., 2] & m)

    def voxel_of(self, keys: np.ndarray, offsets: np.ndarray) -> np.ndarray:
        """Voxel indices (..., 3) int64 of block keys (..., 3) and in-block offsets (...,)."""
        keys = np.asarray(keys, dtype=np.int64)
        off = np.asarray(offsets, dtype=np.int64)
        b, m = self.block_bits, self.block_side - 1
        inner = np.stack([(off >> (2 * b)) & m, (off >> b) & m, off & m], axis=-1)
        return (keys << b) + inner

    def centre(self, ijk: np.ndarray) -> np.ndarray:
        """Voxel centres (..., 3), metres, of indices (..., 3)."""
        return self.lo + (np.asarray(ijk, dtype=np.float64) + 0.5) * self.voxel

    # -- grids ---------------------------------------------------------------------------
    def offset_of_grid(self, grid: Grid) -> np.ndarray:
        """The lattice index (3,) int64 of ``grid``'s voxel (0, 0, 0).

        Raises ValueError when the grid is not aligned: another voxel size, or an origin off
        the lattice's voxel corners by more than a millionth of a voxel (``Grid.matches``).
        """
        tol = 1e-6 * self.voxel
        if abs(grid.voxel - self.voxel) > tol:
            raise ValueError(f"grid voxel {grid.voxel:g} m is not the lattice's {self.voxel:g} m")
        steps = (grid.lo - self.lo) / self.voxel
        offset = np.rint(steps)
        if np.any(np.abs(steps - offset) * self.voxel > tol):
            raise ValueError(
                f"grid origin {list(grid.origin)} is not on the lattice's voxel corners "
                f"(origin {list(self.origin)}, voxel {self.voxel:g} m)"
            )
        return offset.astype(np.int64)

    def grid(self, lo: np.ndarray, hi: np.ndarray) -> Grid:
        """The aligned Grid of lattice voxels ``lo`` (inclusive) to ``hi`` (exclusive), int triples."""
        lo = np.asarray(lo, dtype=np.int64)
        hi = np.asarray(hi, dtype=np.int64)
        return Grid(tuple(self.lo + lo * self.voxel), self.voxel, tuple(int(n) for n in hi - lo))

    def box_of_grid(self, grid: Grid) -> np.ndarray:
        """The lattice voxel box (2, 3) int64 of an aligned ``grid``: lo inclusive, hi exclusive."""
        lo = self.offset_of_grid(grid)
        return np.stack([lo, lo + np.asarray(grid.shape, dtype=np.int64)])

    def to_dict(self) -> dict:
        """Wire/file form: ``{origin, voxel, block_bits}``."""
        return {"origin": list(self.origin), "voxel": self.voxel, "block_bits": self.block_bits}

    @classmethod
    def from_dict(cls, d: dict) -> Lattice:
        return cls(tuple(d["origin"]), float(d["voxel"]), int(d["block_bits"]))


def check_box(box: np.ndarray, block_bits: int) -> None:
    """Raise ValueError when the voxel box (2, 3) (lo inclusive, hi exclusive) reaches blocks
    beyond the lattice's keys, (-KEY_LIMIT, KEY_LIMIT) from the origin."""
    lo, hi = np.asarray(box).tolist()
    if min(v >> block_bits for v in lo) <= -KEY_LIMIT or max((v - 1) >> block_bits for v in hi) >= KEY_LIMIT:
        raise ValueError(
            f"voxels {lo}..{hi} lie beyond the lattice's block keys (+-{KEY_LIMIT} blocks from its origin)"
        )


def pack_keys(keys: np.ndarray) -> np.ndarray:
    """Block keys (N, 3) as one sortable int64 each (lexicographic order kept).

    Raises ValueError for a coordinate outside (-KEY_LIMIT, KEY_LIMIT).
    """
    keys = np.asarray(keys, dtype=np.int64).reshape(-1, 3)
    if keys.size and (keys.min() <= -KEY_LIMIT or keys.max() >= KEY_LIMIT):
        raise ValueError(
            f"block key out of range: coordinates [{keys.min()}, {keys.max()}], the lattice holds "
            f"(-{KEY_LIMIT}, {KEY_LIMIT}) blocks from its origin"
        )
    biased = keys + KEY_LIMIT
    return (biased[:, 0] << 42) | (biased[:, 1] << 21) | biased[:, 2]


def unpack_keys(packed: np.ndarray) -> np.ndarray:
    """Inverse of :func:`pack_keys`: (N,) int64 -> (N, 3) int64."""
    packed = np.asarray(packed, dtype=np.int64)
    mask = (1 << 21) - 1
    return np.stack([packed >> 42, (packed >> 21) & mask, packed & mask], axis=-1) - KEY_LIMIT
