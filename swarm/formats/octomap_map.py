"""Coverage maps to and from OctoMap octrees (``.bt``, see :mod:`swarm.formats.octomap_file`).

Export: the maximum-likelihood occupancy of each voxel of a coverage map.

* *unknown* (not written): sigma > ``max_sigma`` (default 0.5, half the coverage domain [0, 1]:
  the belief says little), which includes every voxel still at the prior;
* *occupied*: known and the expected coverage E[C] > 0.5 (the threshold of the project's
  occupancy F1);
* *free*: known and E[C] <= 0.5.

OctoMap anchors its voxels at the world origin (key ``floor(x / res) + 32768``), so a grid
can be written as it is only when its origin is a whole number of voxels (to a millionth of
a voxel). Otherwise :func:`coverage_to_leaves` refuses with an error naming the origin,
unless ``align="shift"``: then the map is moved by less than half a voxel per axis to the
nearest anchored position (the shift, in metres, is returned and printed by the CLI).

Import (the paper's initial belief "unless there is a previous map", section II.C.1): every
leaf-level voxel of the octree's bounding box, pruned leaves expanded, at the file's own
resolution:

* occupied node: mu = 1, sigma = ``known_sigma`` (default 0.1, in coverage units: about what
  one measurement from 1 m away gives with the default sensor, sigma_s(1 m) = 0.0975);
* free node: mu = 0, sigma = ``known_sigma``;
* unknown (no node): the uninformative prior N(0.5, 10 sigma_s(max range)), as without a map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from swarm.formats.octomap_file import KEY_ORIGIN, TREE_DEPTH, OctreeLeaves
from swarm.formats.shown_numbers import shown
from swarm.map.coverage_map import CoverageMap
from swarm.map.entropy import expected_coverage
from swarm.map.grid import Grid
from swarm.map.sensor_model import SensorModel

DEFAULT_MAX_SIGMA = 0.5
DEFAULT_KNOWN_SIGMA = 0.1
#: an imported map may expand to this many voxels at most (about 1.3 GB of float32 beliefs)
MAX_IMPORT_VOXELS = 150_000_000


@dataclass
class LeafVoxels:
    """Leaf-level voxels to write: keys (N, 3), states, and how far the map was moved (m)."""

    resolution: float
    key: np.ndarray
    occupied: np.ndarray
    shift: tuple[float, float, float]


def grid_key_offset(grid: Grid, align: str = "refuse") -> tuple[np.ndarray, np.ndarray]:
    """Key of voxel (0, 0, 0) and the shift (m) that anchors the grid at the world origin.

    Raises ValueError when the origin is not a whole number of voxels and ``align`` is
    ``"refuse"``, or when the grid does not fit in OctoMap's key range.
    """
    if align not in ("refuse", "shift"):
        raise ValueError(f"align must be 'refuse' or 'shift', got {align!r}")
    steps = np.asarray(grid.origin) / grid.voxel
    whole = np.round(steps)
    off = steps - whole
    if np.any(np.abs(off) > 1e-6) and align == "refuse":
        raise ValueError(
            f"grid origin {[shown(v) for v in grid.origin]} is not a multiple of the voxel size "
            f"{grid.voxel:g} m: "
            "OctoMap anchors voxels at the world origin; use a workspace lo that is a multiple of "
            "the voxel size, or shift the map (swarm map export --align shift; align='shift' in Python) by "
            f"{[shown(-d * grid.voxel, 6) for d in off]} m"
        )
    first = whole.astype(np.int64) + KEY_ORIGIN
    last = first + np.asarray(grid.shape) - 1
    if first.min() < 0 or last.max() >= 1 << TREE_DEPTH:
        raise ValueError(f"the grid lies beyond OctoMap's range of +-{KEY_ORIGIN * grid.voxel:g} m")
    return first, -off * grid.voxel


def coverage_to_leaves(
    cmap: CoverageMap, max_sigma: float = DEFAULT_MAX_SIGMA, align: str = "refuse"
) -> LeafVoxels:
    """The known voxels of ``cmap`` as OctoMap leaf keys and occupied/free states (module doc)."""
    if not max_sigma > 0:
        raise ValueError(f"max_sigma must be > 0, got {max_sigma!r}")
    grid = cmap.grid
    first, shift = grid_key_offset(grid, align)
    sigma = cmap.sigma()
    known = np.flatnonzero(sigma <= max_sigma)
    mu = cmap.mean(known).astype(np.float64)
    occupied = expected_coverage(mu, sigma[known].astype(np.float64)) > 0.5
    key = grid.unflat(known) + first
    return LeafVoxels(grid.voxel, key, occupied, tuple(float(s) for s in shift))


def leaves_to_states(leaves: OctreeLeaves) -> tuple[Grid, np.ndarray]:
    """The octree's bounding box as a grid at its resolution, and the state of every voxel.

    States (nx, ny, nz) uint8: 0 unknown, 1 free, 2 occupied; pruned leaves expanded.
    Raises ValueError for an empty tree or one larger than ``MAX_IMPORT_VOXELS``.
    """
    if len(leaves.key) == 0:
        raise ValueError("the octree has no known node")
    edge = leaves.edge_voxels()
    lo = leaves.key.min(axis=0)
    hi = (leaves.key + edge[:, None]).max(axis=0)
    shape = tuple(int(n) for n in hi - lo)
    if np.prod(shape, dtype=np.float64) > MAX_IMPORT_VOXELS:
        raise ValueError(f"the octree's box {shape} exceeds {MAX_IMPORT_VOXELS:,} voxels")
    states = np.zeros(shape, np.uint8)
    for n in np.unique(edge):
        pick = edge == n
        corner = leaves.key[pick] - lo
        value = np.where(leaves.occupied[pick], 2, 1).astype(np.uint8)
        if n == 1:
            states[corner[:, 0], corner[:, 1], corner[:, 2]] = value
            continue
        for (i, j, k), v in zip(corner.tolist(), value.tolist(), strict=True):
            states[i : i + n, j : j + n, k : k + n] = v
    origin = (lo - KEY_ORIGIN) * leaves.resolution
    return Grid(tuple(origin.tolist()), leaves.resolution, shape), states


def states_to_prior(
    grid: Grid,
    states: np.ndarray,
    sensor: SensorModel | None = None,
    known_sigma: float = DEFAULT_KNOWN_SIGMA,
) -> CoverageMap:
    """A coverage map whose known voxels carry a previous map's occupancy (module doc)."""
    sensor = sensor or SensorModel()
    if not 0 < known_sigma < sensor.prior_sigma():
        raise ValueError(f"known_sigma must be in (0, {sensor.prior_sigma():g}), got {known_sigma!r}")
    cmap = CoverageMap(grid, sensor)
    flat = states.reshape(-1)
    known = flat > 0
    lam = np.float32(1.0 / known_sigma**2)
    cmap.lam[known] = lam
    cmap.eta[known] = np.where(flat[known] == 2, lam, np.float32(0.0))
    return cmap


# -- files -----------------------------------------------------------------------------------


def export_bt(path, cmap: CoverageMap, max_sigma: float = DEFAULT_MAX_SIGMA, align: str = "refuse") -> str:
    """Write ``cmap`` as an OctoMap ``.bt``; returns a one-line summary. Raises ValueError."""
    from swarm.formats.octomap_file import write_bt

    leaves = coverage_to_leaves(cmap, max_sigma, align)
    nodes = write_bt(path, leaves.resolution, leaves.key, leaves.occupied)
    occupied = int(leaves.occupied.sum())
    shift = [shown(s, 6) for s in leaves.shift]  # metres, without float noise or -0.0
    moved = f", moved by {shift} m to OctoMap's lattice" if any(s != 0 for s in shift) else ""
    return (
        f"{path}: OctoMap tree at {leaves.resolution:g} m, {occupied:,} occupied and "
        f"{len(leaves.key) - occupied:,} free voxels ({nodes:,} nodes after pruning){moved}"
    )


def import_bt(path, out, known_sigma: float = DEFAULT_KNOWN_SIGMA, sensor: SensorModel | None = None) -> str:
    """Turn an OctoMap ``.bt`` or ``.ot`` into a coverage ``map.npz`` (beliefs: module doc); returns a
    summary. Raises OctomapFileError naming the file."""
    from swarm.formats.map_file import save_map
    from swarm.formats.octomap_file import OctomapFileError, read_octree

    leaves = read_octree(path)
    try:
        grid, states = leaves_to_states(leaves)
    except ValueError as exc:  # an empty tree (size 0) or one too large to expand
        raise OctomapFileError(f"{path}: {exc}") from None
    save_map(out, states_to_prior(grid, states, sensor, known_sigma))
    occupied, free = int(np.count_nonzero(states == 2)), int(np.count_nonzero(states == 1))
    pruned = int(np.count_nonzero(leaves.depth < TREE_DEPTH))
    return (
        f"{out}: {grid.shape[0]} x {grid.shape[1]} x {grid.shape[2]} voxels of {grid.voxel:g} m from "
        f"{path} (origin {[round(v, 6) for v in grid.origin]}): {occupied:,} occupied, {free:,} free "
        f"({pruned:,} pruned nodes expanded), the rest unknown"
    )
