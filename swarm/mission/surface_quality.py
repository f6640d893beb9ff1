"""Surface precision and recall of a map against a true surface (the one implementation).

Real walls do not sit on the voxel grid, so a map's surface is judged by distance:

- precision: the share of mapped occupied voxels (E[C] > 0.5) whose centre lies within
  ``tolerance`` (1.5 voxel edges) of the true surface;
- recall (completeness): the share of the true surface (points, or truly covered voxel
  centres) within ``tolerance`` of a mapped occupied voxel's centre.

Used by ``swarm bench fusion`` (ours and OctoMap's maps against the cloud itself) and meant
for the mission metrics. Pure numpy and scipy (cKDTree).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

#: The distance that counts as "on the surface", in voxel edges.
TOLERANCE_VOXELS = 1.5


@dataclass(frozen=True)
class SurfaceQuality:
    """Precision and recall of a map's occupied voxels against a true surface (NaN when undefined)."""

    precision: float
    recall: float
    occupied: int  # mapped occupied voxels
    surface: int  # true surface points


def surface_quality(
    occupied_centres: np.ndarray,
    surface_points: np.ndarray,
    voxel: float,
    tolerance_voxels: float = TOLERANCE_VOXELS,
) -> SurfaceQuality:
    """Precision and recall of occupied voxel centres (M, 3) against surface points (P, 3), metres.

    ``voxel`` is the map's voxel edge; a distance of at most ``tolerance_voxels * voxel``
    counts. Precision is NaN for an empty map, recall NaN for an empty surface.
    Raises ValueError for arrays that are not (n, 3) or a voxel that is not > 0.
    """
    occupied_centres = _points(occupied_centres, "occupied_centres")
    surface_points = _points(surface_points, "surface_points")
    if not voxel > 0:
        raise ValueError(f"voxel must be > 0, got {voxel!r}")
    radius = tolerance_voxels * voxel
    precision = recall = float("nan")
    if len(occupied_centres) and len(surface_points):
        near_surface, _ = cKDTree(surface_points).query(
            occupied_centres, distance_upper_bound=radius * (1 + 1e-9)
        )
        precision = float(np.mean(np.isfinite(near_surface)))
        near_map, _ = cKDTree(occupied_centres).query(
            surface_points, distance_upper_bound=radius * (1 + 1e-9)
        )
        recall = float(np.mean(np.isfinite(near_map)))
    elif len(surface_points):
        recall = 0.0
    elif len(occupied_centres):
        precision = 0.0
    return SurfaceQuality(precision, recall, len(occupied_centres), len(surface_points))


def _points(values: np.ndarray, name: str) -> np.ndarray:
    values = np.asarray(values, dtype=np.float64)
    if values.ndim != 2 or values.shape[1] != 3:
        raise ValueError(f"{name} must have shape (n, 3), got {values.shape}")
    return values
