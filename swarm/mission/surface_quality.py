"""Surface accuracy and completeness: map quality as 3-D reconstruction measures it.

Occupancy F1 compares voxels with the truth voxel by voxel, so a wall that does not sit on
the voxel grid costs it whatever the map does: a voxel half inside the wall is "free" in the
truth and may well be "occupied" in the map. The reconstruction measures ask instead how far
the map's surface is from the true one (docs/design.md section 7; one implementation for the
mission metrics and ``swarm bench fusion`` alike, which calls them precision and recall):

- **accuracy**: the share of mapped occupied voxels (E[C] > 0.5) whose centre lies within
  ``tolerance`` (1.5 voxel edges) of the true surface;
- **completeness**: the share of the true surface (points sampled on it) within
  ``tolerance`` of a mapped occupied voxel's centre.

For a floor plan (:func:`plan_accuracy_completeness`) accuracy takes each mapped centre's
exact distance to the obstacles' sides and tops and to the floor plane z = 0
(:mod:`swarm.mission.plan_distance`; a voxel mapped on the floor is where a surface is);
completeness samples the obstacles' sides and tops every half voxel edge
(:func:`plan_surface_points`; not the floor, which the robots are not asked to map as
occupied). Accuracy must not be measured against sampled points: they overstate every
distance by up to the sampling's half-diagonal, which turns a centre exactly 1.5 edges from
a wall (every second voxel layer of a grid-aligned thick wall) from accurate to inaccurate.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from swarm.mission.plan_distance import surface_distance

#: Default tolerance in voxel edges.
TOLERANCE_EDGES = 1.5


def surface_accuracy_completeness(
    mapped_centres: np.ndarray,
    surface_points: np.ndarray,
    tolerance: float,
    floor_z: float | None = None,
) -> dict[str, float | int | None]:
    """Accuracy and completeness of mapped occupied voxel centres (M, 3) against true surface
    points (S, 3), both in metres, with ``tolerance`` in metres.

    ``floor_z``: when given, the plane z = floor_z is true surface too for accuracy.
    Returns ``accuracy, completeness, mapped, surface`` (the counts); a share with nothing to
    count (no mapped voxel, no surface point) is None.
    """
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    mapped = np.asarray(mapped_centres, dtype=np.float64).reshape(-1, 3)
    surface = np.asarray(surface_points, dtype=np.float64).reshape(-1, 3)
    accuracy = completeness = None
    if len(mapped):
        near = np.zeros(len(mapped), dtype=bool)
        if len(surface):
            d, _ = cKDTree(surface).query(mapped, distance_upper_bound=tolerance * (1 + 1e-9))
            near = d <= tolerance
        if floor_z is not None:
            near |= np.abs(mapped[:, 2] - floor_z) <= tolerance
        accuracy = float(np.mean(near))
    if len(surface):
        if len(mapped):
            d, _ = cKDTree(mapped).query(surface, distance_upper_bound=tolerance * (1 + 1e-9))
            completeness = float(np.mean(d <= tolerance))
        else:
            completeness = 0.0
    return {
        "accuracy": accuracy,
        "completeness": completeness,
        "mapped": len(mapped),
        "surface": len(surface),
    }


def plan_accuracy_completeness(
    plan, mapped_centres: np.ndarray, surface_points: np.ndarray, tolerance: float
) -> dict[str, float | int | None]:
    """Accuracy and completeness of mapped occupied voxel centres (M, 3) against a floor plan
    (``swarm.formats.floor_plan.FloorPlan``), ``tolerance`` in metres.

    Accuracy: the share of centres whose exact distance to the plan's surface (sides, tops,
    the floor z = 0) is at most ``tolerance``. Completeness: the share of ``surface_points``
    (S, 3; :func:`plan_surface_points`, or the part of them a mission's sensors can observe)
    within ``tolerance`` of a centre. Returns ``accuracy, completeness, mapped, surface``
    as :func:`surface_accuracy_completeness`; raises ValueError for a tolerance not > 0.
    """
    if not tolerance > 0:
        raise ValueError(f"tolerance must be > 0, got {tolerance}")
    mapped = np.asarray(mapped_centres, dtype=np.float64).reshape(-1, 3)
    out = surface_accuracy_completeness(mapped, surface_points, tolerance)
    if len(mapped):
        distance = surface_distance(plan, mapped, cap=2 * tolerance)
        out["accuracy"] = float(np.mean(distance <= tolerance * (1 + 1e-9)))
    return out


@dataclass(frozen=True)
class SurfaceQuality:
    """Precision (= accuracy) and recall (= completeness) of a map's occupied voxels against a
    true surface, as ``swarm bench fusion`` prints them (NaN when undefined)."""

    precision: float
    recall: float
    occupied: int  # mapped occupied voxels
    surface: int  # true surface points


def surface_quality(
    occupied_centres: np.ndarray,
    surface_points: np.ndarray,
    voxel: float,
    tolerance_edges: float = TOLERANCE_EDGES,
) -> SurfaceQuality:
    """:func:`surface_accuracy_completeness` with the tolerance in voxel edges of ``voxel`` (metres),
    and NaN for a share with nothing to count. Raises ValueError for a voxel that is not > 0."""
    if not voxel > 0:
        raise ValueError(f"voxel must be > 0, got {voxel!r}")
    out = surface_accuracy_completeness(occupied_centres, surface_points, tolerance_edges * voxel)
    nan = float("nan")
    precision = nan if out["accuracy"] is None else out["accuracy"]
    recall = nan if out["completeness"] is None else out["completeness"]
    return SurfaceQuality(precision, recall, out["mapped"], out["surface"])


def plan_surface_points(
    plan, lo: np.ndarray, hi: np.ndarray, step: float, raster: float | None = None
) -> tuple[np.ndarray, np.ndarray]:
    """Points every ``step`` m on the exposed sides and tops of a floor plan's obstacles in
    the box [lo, hi] (x, y, z), and for each the point a hair outside the surface, in the air
    in front of it (to ask whether that air could be seen). Both (S, 3).

    ``plan``: a ``swarm.formats.floor_plan.FloorPlan``. Sides shared by touching obstacles
    (a ROS map's merged cells) are inside the solid and left out: a side point is kept when
    the obstacles' height field just outside it (a ``raster`` lattice, step / 2 by default)
    is below the point.
    """
    lo = np.asarray(lo, dtype=np.float64)
    hi = np.asarray(hi, dtype=np.float64)
    raster = raster or step / 2
    n = np.maximum(np.ceil((hi[:2] - lo[:2]) / raster).astype(int) + 2, 1)
    xs = lo[0] - raster + (np.arange(n[0]) + 0.5) * raster
    ys = lo[1] - raster + (np.arange(n[1]) + 0.5) * raster
    top = plan.height_field(xs, ys)

    def height(xy: np.ndarray) -> np.ndarray:
        i = np.clip(np.floor((xy[:, 0] - xs[0] + 0.5 * raster) / raster).astype(int), 0, len(xs) - 1)
        j = np.clip(np.floor((xy[:, 1] - ys[0] + 0.5 * raster) / raster).astype(int), 0, len(ys) - 1)
        return top[i, j]

    eps = 0.25 * raster
    # sides: every edge of every obstacle near the box, sampled every step along and up
    qlo, qhi = plan.quad_bounds()
    near = np.flatnonzero(np.all((qhi >= lo[:2]) & (qlo <= hi[:2]), axis=1))
    starts, normals = plan.edge_normals()
    a = starts[near].reshape(-1, 2)
    b = np.roll(plan.quads[near], -1, axis=1).reshape(-1, 2)
    nrm = normals[near].reshape(-1, 2)
    h_edge = np.repeat(plan.heights[near], 4)
    counts = np.maximum(np.ceil(np.linalg.norm(b - a, axis=1) / step).astype(np.int64), 1)
    edge = np.repeat(np.arange(len(a)), counts)
    rank = np.arange(edge.size) - np.repeat(np.cumsum(counts) - counts, counts)
    t = (rank + 0.5) / counts[edge]
    xy = a[edge] + t[:, None] * (b - a)[edge]
    out = xy + eps * nrm[edge]
    keep = np.all((xy >= lo[:2]) & (xy <= hi[:2]), axis=1)
    xy, out, h_side = xy[keep], out[keep], h_edge[edge][keep]
    h_out = height(out)
    zs = np.arange(max(lo[2], 0.0) + 0.5 * step, hi[2], step)
    exposed = (zs[None, :] < h_side[:, None]) & (h_out[:, None] < zs[None, :])
    p_i, z_i = np.nonzero(exposed)
    pts = [np.column_stack([xy[p_i], zs[z_i]])]
    air = [np.column_stack([out[p_i], zs[z_i]])]
    # tops: the height field on a step lattice, where an obstacle ends inside the box
    gx = np.arange(lo[0] + 0.5 * step, hi[0], step)
    gy = np.arange(lo[1] + 0.5 * step, hi[1], step)
    tops = plan.height_field(gx, gy)
    ti, tj = np.nonzero((tops > 0) & (tops >= lo[2]) & (tops < hi[2]))
    z_top = tops[ti, tj]
    pts.append(np.column_stack([gx[ti], gy[tj], z_top]))
    air.append(np.column_stack([gx[ti], gy[tj], z_top + eps]))
    return np.concatenate(pts), np.concatenate(air)


def voxel_of(points: np.ndarray, lo: np.ndarray, voxel: float, shape: tuple[int, int, int]) -> np.ndarray:
    """Flat C-order voxel index of each point (P, 3), -1 for points outside the grid."""
    ijk = np.floor((np.asarray(points, dtype=np.float64) - np.asarray(lo)) / voxel).astype(np.int64)
    inside = np.all((ijk >= 0) & (ijk < np.asarray(shape)), axis=1)
    flat = np.full(len(ijk), -1, dtype=np.int64)
    flat[inside] = np.ravel_multi_index(ijk[inside].T, shape)
    return flat
