"""The 3-D coverage map seen as a ground robot's 2-D map, and as a cloud of its occupied voxels.

**2-D projection** (what a Nav2 costmap's static layer takes; the values of
``nav_msgs/OccupancyGrid``). Column (i, j) of the map is judged over the robot's height band,
the layers [k0, k1) whose voxel centres lie in [z_lo, z_hi] (:func:`band_layers`):

* ``OCCUPIED`` (100) when any band voxel has E[C] > ``threshold`` (0.5: more likely covered than
  not);
* else ``FREE`` (0) when the band is known: with the rule ``"all"`` every band voxel holds
  information beyond the prior (as the agents' own planner requires,
  ``swarm.navigation.traversability``), with ``"any"`` at least one does (as octomap_server's
  projected map);
* else ``UNKNOWN`` (-1).

A voxel is known when its information lam exceeds ``known_lam``
(``CoverageMap.known_threshold()``). An unknown voxel is at the prior mean 0.5, so E[C] = 0.5
exactly and never counts as occupied. Cells are indexed like the map's columns, (nx, ny), cell
(i, j) covering x in origin_x + [i, i + 1) * voxel and y likewise.

**Occupied cloud**: one point per voxel with E[C] > ``threshold``, at its centre, with its
belief: ``mu`` = eta / lam, ``sigma`` = 1 / sqrt(lam) and its entropy in bits (paper eq. 17), all
float32, computed as ``swarm map export`` computes them.

E[C] is taken as the float32 array of the map file (``map.npz``'s ``expected_coverage``), so a
voxel is occupied here exactly when it is in an exported map. Pure functions over arrays.
"""

from __future__ import annotations

import numpy as np

from swarm.map.grid import Grid

OCCUPIED = 100
FREE = 0
UNKNOWN = -1
FREE_RULES = ("all", "any")

#: The point fields of the occupied cloud, each float32 (12 + 12 bytes a point).
CLOUD_FIELDS = ("x", "y", "z", "mu", "sigma", "entropy")
CLOUD_DTYPE = np.dtype([(name, "<f4") for name in CLOUD_FIELDS])


def band_layers(grid: Grid, z_lo: float, z_hi: float) -> tuple[int, int]:
    """(k0, k1): the layers whose voxel centre z lies in [z_lo, z_hi] (metres), k1 exclusive.

    Raises ValueError when no layer centre lies in the band, naming the layers' range.
    """
    z = grid.lo[2] + (np.arange(grid.shape[2]) + 0.5) * grid.voxel
    inside = np.flatnonzero((z >= z_lo - 1e-9) & (z <= z_hi + 1e-9))
    if inside.size == 0:
        raise ValueError(
            f"no map layer has its centre in the height band z = [{z_lo:g}, {z_hi:g}] m "
            f"(layer centres {z.min():.3f}..{z.max():.3f} m)"
        )
    return int(inside[0]), int(inside[-1]) + 1


def column_states(
    coverage: np.ndarray, known: np.ndarray, threshold: float = 0.5, free_rule: str = "all"
) -> np.ndarray:
    """int8 OCCUPIED / FREE / UNKNOWN per column from its band: ``coverage`` E[C] and ``known``
    (bool), both (..., band layers); the result has shape (...). ValueError for another rule."""
    if free_rule not in FREE_RULES:
        raise ValueError(f"free rule {free_rule!r} is not one of {', '.join(FREE_RULES)}")
    occupied = np.any(coverage > threshold, axis=-1)
    seen = np.all(known, axis=-1) if free_rule == "all" else np.any(known, axis=-1)
    out = np.full(occupied.shape, UNKNOWN, np.int8)
    out[seen] = FREE
    out[occupied] = OCCUPIED
    return out


def project(
    grid: Grid,
    coverage: np.ndarray,
    lam: np.ndarray,
    known_lam: float,
    layers: tuple[int, int],
    threshold: float = 0.5,
    free_rule: str = "all",
) -> np.ndarray:
    """The whole 2-D map, int8 (nx, ny), from flat ``coverage`` (E[C]) and ``lam`` (C order)."""
    k0, k1 = layers
    band = (slice(None), slice(None), slice(k0, k1))
    cov = np.asarray(coverage).reshape(grid.shape)[band]
    known = np.asarray(lam).reshape(grid.shape)[band] > known_lam
    return column_states(cov, known, threshold, free_rule)


def project_columns(
    grid: Grid,
    coverage: np.ndarray,
    lam: np.ndarray,
    known_lam: float,
    layers: tuple[int, int],
    columns: np.ndarray,
    threshold: float = 0.5,
    free_rule: str = "all",
) -> np.ndarray:
    """The cells of flat ``columns`` (i * ny + j) only, int8 (len(columns),): equal to
    ``project(...).ravel()[columns]`` at the cost of those columns."""
    k0, k1 = layers
    nz = grid.shape[2]
    idx = np.asarray(columns, np.int64)[:, None] * nz + np.arange(k0, k1)[None, :]
    return column_states(np.asarray(coverage)[idx], np.asarray(lam)[idx] > known_lam, threshold, free_rule)


def columns_of(grid: Grid, voxels: np.ndarray) -> np.ndarray:
    """The flat columns (i * ny + j), sorted and unique, holding the flat ``voxels``."""
    return np.unique(np.asarray(voxels, np.int64) // grid.shape[2])


def changed_box(before: np.ndarray, after: np.ndarray) -> tuple[slice, slice] | None:
    """The smallest box (i slice, j slice) holding every cell where two equal-shaped 2-D maps
    differ; None when they are equal."""
    diff = np.asarray(before) != np.asarray(after)
    rows = np.flatnonzero(diff.any(axis=1))
    if rows.size == 0:
        return None
    cols = np.flatnonzero(diff.any(axis=0))
    return slice(int(rows[0]), int(rows[-1]) + 1), slice(int(cols[0]), int(cols[-1]) + 1)


def occupied_cloud(
    grid: Grid,
    coverage: np.ndarray,
    lam: np.ndarray,
    eta: np.ndarray,
    entropy: np.ndarray,
    threshold: float = 0.5,
) -> np.ndarray:
    """The occupied voxels as a structured array of ``CLOUD_DTYPE`` (N,): centre x, y, z (m) and
    mu, sigma, entropy (bits), in flat index order, from flat float32 ``coverage`` (E[C]),
    ``lam``, ``eta`` and ``entropy`` arrays."""
    idx = np.flatnonzero(np.asarray(coverage) > threshold)
    points = np.empty(idx.size, CLOUD_DTYPE)
    centres = grid.centre(grid.unflat(idx))
    points["x"], points["y"], points["z"] = centres.T
    lam_i = np.asarray(lam, np.float32)[idx]
    points["mu"] = np.asarray(eta, np.float32)[idx] / lam_i
    points["sigma"] = 1.0 / np.sqrt(lam_i)
    points["entropy"] = np.asarray(entropy)[idx]
    return points
